//! The extended model (`model = ...`, docs/lab.md) in the compensator: its effects'
//! VE is removed after stage (20). Two compensators run in-process on the same
//! readings and estimate, one with the shipped configuration and one with an extended
//! model; their outputs must differ by exactly the effects' VE computed here in
//! closed form (docs/effects.md), sample by sample:
//!
//! - `anisoelastic`: `k_ae E[v1 v2]`, `E[v1 v2] = sum 0.5 aB1 aB2 cos(phi1 - phi2) +
//!   K_12`, independent of the flight acceleration;
//! - `high_order_nonlinearity`: `k6 (E[(aL + v)^6] - aL^6)` with MODEL.md section 6's
//!   moments of one tone and a Gaussian part, a quartic in `aL`: the compensator's
//!   tabulation over `a(1)` and its interpolation are checked along a flight from 1 to
//!   5 g (the grid is built again as the reading leaves it).

use crate::support::*;
use vibro_compensator::{Config, InProcess};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{AccelBlock, CompensatedBlock};
use vibro_physics::vibration::Vibration;
use vibro_service::ServiceConfig;

const T_NS: u64 = 1_250_000;
const BLOCK: u64 = 32;
const START_NS: u64 = 10_000_000_000_000;

/// 1 g to 5 g along body z over 0.64 s, a little on x and y.
fn body_g(n: u64) -> [f64; 3] {
    let t = n as f64 * 1e-3;
    [
        0.3 + 0.05 * (3.0 * t).sin(),
        -0.2 + 0.01 * t,
        1.0 + 4.0 * t / 0.64,
    ]
}

/// One tone and a Gaussian random part: the closed forms below hold for it.
fn vibration() -> BodyVibration {
    BodyVibration {
        tones: vec![(31.0, [1.2, 0.9, 1.5], [0.4, -0.3, 0.1])],
        covariance_g2: [[1.0, 0.2, 0.3], [0.2, 1.44, -0.1], [0.3, -0.1, 1.96]],
        kurtosis: [3.0; 3],
    }
}

/// The estimate of [`vibration`], broadband over 20..2000 Hz.
fn estimate(
    axes: &vibro_physics::triad::TriadAxes,
    seq: u64,
    end_ns: u64,
) -> vibro_msgs::VibEstimate {
    let mut e = vibration().estimate(axes, seq, end_ns);
    e.broadband_f_lo_hz = 20.0;
    e.broadband_f_hi_hz = 2000.0;
    e
}

fn config(model: Option<&str>) -> Config {
    let mut c = Config::shipped().unwrap();
    // The whole vibration (no reduction to the output interval), so that the closed
    // forms take the estimate as it is.
    c.model.estimate.within_output_interval = false;
    c.model.effects = model.map(|text| {
        (
            "m.toml".into(),
            vibro_effects::LabModel::parse(text, "m.toml").unwrap(),
        )
    });
    c
}

fn run(c: &Config, blocks: &[AccelBlock]) -> Vec<CompensatedBlock> {
    let axes = c.model.triad.axes;
    let mut p = InProcess::new(c).unwrap();
    let mut out = Vec::new();
    p.on_estimate(&estimate(&axes, 1, START_NS));
    for b in blocks {
        p.on_accel(b, 0, &mut out);
    }
    out
}

fn blocks(c: &Config) -> Vec<AccelBlock> {
    let axes = c.model.triad.axes;
    let k1 = c.model.k1_v_per_g();
    (0..20)
        .map(|seq| {
            let v: Vec<[f64; 3]> = (0..BLOCK)
                .map(|k| {
                    let body = body_g(seq * BLOCK + k);
                    [0, 1, 2].map(|u| (axes.units[u].ia.project(&body) + 3e-3) * k1[u])
                })
                .collect();
            accel_block(seq, START_NS + (seq * BLOCK + 1) * T_NS, &v)
        })
        .collect()
}

/// Checks `with` = `without` moved by `effect(unit, vibration, a1)` in a4 and rand,
/// the other stages bit for bit; returns the largest deviation, g.
fn check(
    without: &[CompensatedBlock],
    with: &[CompensatedBlock],
    c: &Config,
    effect: impl Fn(&Vibration, f64) -> f64,
) -> f64 {
    let units = c.model.triad.axes.units.map(|u| vibration().at_unit(&u));
    let mut worst = 0.0f64;
    for (a, b) in without.iter().zip(with) {
        assert_eq!(a.flags & cf::MAIN_ONLY, 0);
        assert_eq!(
            b.flags,
            a.flags | cf::MODEL_EFFECTS,
            "block {}",
            b.input_seq
        );
        for k in 0..a.count as usize {
            for u in 0..3 {
                assert_eq!(a.a1_g[k][u].to_bits(), b.a1_g[k][u].to_bits());
                assert_eq!(a.a3_g[k][u].to_bits(), b.a3_g[k][u].to_bits());
                let e = effect(&units[u], a.a1_g[k][u]);
                worst = worst.max((b.a4_g[k][u] - (a.a4_g[k][u] - e)).abs());
                worst = worst.max((b.rand_g[k][u] - (a.rand_g[k][u] + e)).abs());
                // a4 = a3 - rand still holds.
                assert!((b.a3_g[k][u] - b.rand_g[k][u] - b.a4_g[k][u]).abs() < 1e-15);
            }
        }
    }
    worst
}

#[test]
fn an_acceleration_independent_effect_is_removed_exactly() {
    let plain = config(None);
    let ext = config(Some(
        "mode = \"exact\"\n[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 2.0e-5\n",
    ));
    let b = blocks(&plain);
    let worst = check(&run(&plain, &b), &run(&ext, &b), &plain, |v, _| {
        let t = &v.tones()[0];
        2.0e-5
            * (0.5 * t.amplitude_g[0] * t.amplitude_g[1] * (t.phase_rad[0] - t.phase_rad[1]).cos()
                + v.covariance_g2[0][1])
    });
    println!("FIGURES anisoelastic: largest deviation {worst:.3e} g");
    assert!(worst < 1e-15, "{worst:e}");
}

#[test]
fn an_acceleration_dependent_effect_is_tabulated_and_interpolated_along_the_flight() {
    let plain = config(None);
    let k6 = 0.05e-6; // 0.05 ppm/g^5
    let ext = config(Some(
        "mode = \"exact\"\n[[effect]]\nkind = \"high_order_nonlinearity\"\nk6_ppm_per_g5 = 0.05\n",
    ));
    let b = blocks(&plain);
    let worst = check(&run(&plain, &b), &run(&ext, &b), &plain, |v, a| {
        // IA (axis 3): one tone of amplitude A and a Gaussian part of variance s2.
        let a_t = v.tones()[0].amplitude_g[2];
        let s2 = v.covariance_g2[2][2];
        let (t2, t4, t6) = (
            a_t.powi(2) / 2.0,
            3.0 * a_t.powi(4) / 8.0,
            5.0 * a_t.powi(6) / 16.0,
        );
        let (g2, g4, g6) = (s2, 3.0 * s2 * s2, 15.0 * s2 * s2 * s2);
        // Moments of the sum of two independent zero-mean parts.
        let m2 = t2 + g2;
        let m4 = t4 + 6.0 * t2 * g2 + g4;
        let m6 = t6 + 15.0 * t4 * g2 + 15.0 * t2 * g4 + g6;
        k6 * (15.0 * a.powi(4) * m2 + 15.0 * a.powi(2) * m4 + m6)
    });
    println!("FIGURES high_order: largest deviation {worst:.3e} g along 1..5 g");
    // A 4-point cubic interpolation of a quartic on 0.25 g steps: at most
    // |E''''| h^4 9/384 with E'''' = 360 k6 m2 (m2 = 1.125 + 1.96 g^2 on the IA that
    // sees the largest vibration): 0.25^4 * 360 * 0.05e-6 * 3.085 * 9/384 = 5.1e-9 g
    // (the largest deviation seen is that bound: 5.08e-9 g).
    let bound = 0.25f64.powi(4) * 360.0 * k6 * 3.085 * 9.0 / 384.0;
    assert!(worst < 1.5 * bound, "{worst:e} > 1.5 x {bound:e}");
}

/// An empirical correction (not physical, docs/lab.md "Beyond the library") is removed
/// like an effect: `c_p3 P3 + c_p3_al3 P3 a(1)` with `P3 = aB3^2 / 2 + K_33` on each
/// unit's IA, linear in the reading, so the tabulation along 1..5 g reproduces it to
/// rounding.
#[test]
fn an_empirical_correction_is_removed_like_an_effect() {
    let plain = config(None);
    let ext = config(Some(
        "mode = \"exact\"\n[[effect]]\nkind = \"empirical\"\nc_p3_per_g = 2.0e-6\n\
         c_p3_al3_per_g2 = -5.0e-7\n",
    ));
    let b = blocks(&plain);
    let worst = check(&run(&plain, &b), &run(&ext, &b), &plain, |v, a| {
        let p3 = 0.5 * v.tones()[0].amplitude_g[2].powi(2) + v.covariance_g2[2][2];
        2.0e-6 * p3 - 5.0e-7 * p3 * a
    });
    println!("FIGURES empirical: largest deviation {worst:.3e} g along 1..5 g");
    assert!(worst < 1e-14, "{worst:e}");
}

#[test]
fn a_model_file_is_checked_watched_and_its_mode_must_match() {
    let dir = TempDir::new();
    let model = dir.path("model.toml");
    std::fs::write(&model, "mode = \"paper\"\n").unwrap();
    let text = config_text("p/", "exact", "default", "event").replacen(
        "triad = \"default\"\n",
        &format!(
            "triad = \"default\"\nmodel = {:?}\n",
            model.display().to_string()
        ),
        1,
    );
    let src = || vibro_service::ConfigSource::File("c.toml".into());
    let e = Config::parse(&text, src()).unwrap_err().to_string();
    assert!(
        e.contains("its mode \"paper\" is not this file's mode = \"exact\""),
        "{e}"
    );
    std::fs::write(
        &model,
        "mode = \"exact\"\n[[effect]]\nkind = \"saturation\"\nrange_g = -1.0\n",
    )
    .unwrap();
    let e = Config::parse(&text, src()).unwrap_err().to_string();
    assert!(e.contains("model.toml") && e.contains("range_g"), "{e}");
    std::fs::write(
        &model,
        "mode = \"exact\"\n[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 1e-5\n",
    )
    .unwrap();
    let c = Config::parse(&text, src()).unwrap();
    assert!(c.watched_files.contains(&model), "{:?}", c.watched_files);
    assert!(c.model.effects.is_some());
}

/// Not a test: the cost of taking an estimate with and without an extended model
/// (`cargo test --release -p vibro-compensator --test integration measure -- --ignored
/// --nocapture`); the figures are in docs/services.md.
#[test]
#[ignore]
fn measure_the_cost_of_an_extended_model() {
    let plain = config(None);
    let ext = config(Some(
        "mode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56\n",
    ));
    let b = blocks(&plain);
    for (name, c) in [("base model", &plain), ("with mount_resonance", &ext)] {
        let axes = c.model.triad.axes;
        let mut p = InProcess::new(c).unwrap();
        let mut out = Vec::new();
        let t = std::time::Instant::now();
        for seq in 0..b.len() as u64 {
            p.on_estimate(&rig_band_estimate(
                &axes,
                [20.0, 2000.0],
                seq + 1,
                START_NS + seq,
            ));
            p.on_accel(&b[seq as usize], 0, &mut out);
        }
        assert_eq!(out.len(), b.len());
        assert_eq!(p.summary().model_effect_errors, 0);
        println!(
            "FIGURES {name}: an estimate taken and a block of 32 compensated: {:?}",
            t.elapsed() / b.len() as u32
        );
    }
}

/// An effect the estimate does not let the compensator evaluate (a filtering effect
/// on random vibration without a band: the estimate states none) falls back to the
/// base model: the outputs are bit for bit those without the extended model, without
/// `MODEL_EFFECTS`, and the failures are counted.
#[test]
fn effects_that_cannot_be_evaluated_fall_back_to_the_base_model_and_are_counted() {
    let plain = config(None);
    let ext = config(Some(
        "mode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56\n",
    ));
    let b = blocks(&plain);
    let run_without_band = |c: &Config| {
        let mut p = InProcess::new(c).unwrap();
        let mut out = Vec::new();
        p.on_estimate(&vibration().estimate(&c.model.triad.axes, 1, START_NS));
        for blk in &b {
            p.on_accel(blk, 0, &mut out);
        }
        (out, p.summary())
    };
    let (a, _) = run_without_band(&plain);
    let (x, summary) = run_without_band(&ext);
    assert_eq!(summary.model_effect_errors, 1, "{}", summary.to_json());
    for (p, q) in a.iter().zip(&x) {
        assert_eq!(p.flags, q.flags);
        assert_eq!(q.flags & cf::MODEL_EFFECTS, 0);
        for k in 0..p.count as usize {
            for u in 0..3 {
                assert_eq!(p.a4_g[k][u].to_bits(), q.a4_g[k][u].to_bits());
                assert_eq!(p.rand_g[k][u].to_bits(), q.rand_g[k][u].to_bits());
            }
        }
    }
}

/// A flat random spectrum over 20..640 Hz on every axis (a rig with no power above
/// 640 Hz), a tone near the resonance, and the estimate of it that an estimator set to
/// `broadband_hz` with octave bands up to its top reports (levels exact, no Welch
/// leakage stated: `welch_segment_samples = 0`).
fn rig_band_vibration() -> BodyVibration {
    BodyVibration {
        tones: vec![(120.0, [0.6, 0.4, 0.9], [0.2, -0.5, 0.0])],
        covariance_g2: [[1.0, 0.2, 0.3], [0.2, 1.44, -0.1], [0.3, -0.1, 1.96]],
        kurtosis: [3.0; 3],
    }
}

const RIG_BAND_HZ: [f64; 2] = [20.0, 640.0];

fn rig_band_estimate(
    axes: &vibro_physics::triad::TriadAxes,
    broadband_hz: [f64; 2],
    seq: u64,
    end_ns: u64,
) -> vibro_msgs::VibEstimate {
    let mut e = rig_band_vibration().estimate(axes, seq, end_ns);
    e.broadband_f_lo_hz = broadband_hz[0];
    e.broadband_f_hi_hz = broadband_hz[1];
    let mut edges = vec![20.0];
    while *edges.last().unwrap() < broadband_hz[1] {
        edges.push((edges.last().unwrap() * 2.0f64).min(broadband_hz[1]));
    }
    e.band_count = (edges.len() - 1) as u32;
    let width = RIG_BAND_HZ[1] - RIG_BAND_HZ[0];
    for b in 0..edges.len() - 1 {
        e.band_f_lo_hz[b] = edges[b];
        e.band_f_hi_hz[b] = edges[b + 1];
        for j in 0..3 {
            // The flat level inside 20..640 Hz, nothing above.
            let level = if edges[b] < RIG_BAND_HZ[1] {
                e.broadband_covariance_g2[j][j] / width
            } else {
                0.0
            };
            e.band_psd_g2_per_hz[b][j] = level;
            e.band_rms_g[b][j] = (level * (edges[b + 1] - edges[b])).sqrt();
        }
    }
    e
}

/// The suspension's response at `f_hz` as the effect realises it (`kind =
/// "mount_resonance"`, docs/effects.md): the transmissibility `T(s) = (wn^2 + wn/q s) /
/// (s^2 + wn/q s + wn^2)` through the bilinear transform prewarped at `f0` at 25.6 kHz,
/// i.e. `T(j k tan(pi f / fs))` with `k = wn / tan(pi f0 / fs)`; written here from the
/// textbook formulas, not from the effect's code.
fn suspension(f_hz: f64, f0_hz: f64, q: f64) -> (f64, f64) {
    use std::f64::consts::PI;
    let fs = 25_600.0;
    let wn = 2.0 * PI * f0_hz;
    let w = wn / (PI * f0_hz / fs).tan() * (PI * f_hz / fs).tan();
    // (wn^2 + j w wn/q) / (wn^2 - w^2 + j w wn/q)
    let (nr, ni) = (wn * wn, w * wn / q);
    let (dr, di) = (wn * wn - w * w, w * wn / q);
    let d2 = dr * dr + di * di;
    ((nr * dr + ni * di) / d2, (ni * dr - nr * di) / d2)
}

/// `1 - sinc^2(pi f T)`: the part of a component's variance inside output intervals
/// of `t_s` (MODEL.md section 7 on boxcar means; docs/services.md).
fn within(f_hz: f64, t_s: f64) -> f64 {
    let x = std::f64::consts::PI * f_hz * t_s;
    if x == 0.0 {
        return 0.0;
    }
    1.0 - (x.sin() / x).powi(2)
}

/// Inside an interval of `w T` rad, a tone `sin(theta + w tau)` (`theta` its phase at the
/// interval's middle) deviates from the interval's mean by the variance
/// `E[sin^2] - E[sin]^2 = (1 - cos(2 theta) sin(w T) / (w T)) / 2 - sin^2(theta)
/// (sin(w T / 2) / (w T / 2))^2`; over its mean over `theta`,
/// `(1 - (sin(w T / 2) / (w T / 2))^2) / 2`.
fn phase_factor(theta: f64, wt: f64) -> f64 {
    let s1 = wt.sin() / wt;
    let s2 = (wt / 2.0).sin() / (wt / 2.0);
    let v = 0.5 * (1.0 - (2.0 * theta).cos() * s1) - theta.sin().powi(2) * s2 * s2;
    v / (0.5 * (1.0 - s2 * s2))
}

/// `int_lo^hi g(f) df` by Simpson's rule on 200 000 panels.
fn simpson(lo: f64, hi: f64, g: impl Fn(f64) -> f64) -> f64 {
    let n = 200_000;
    let h = (hi - lo) / n as f64;
    let mut s = g(lo) + g(hi);
    for k in 1..n {
        s += if k % 2 == 1 { 4.0 } else { 2.0 } * g(lo + k as f64 * h);
    }
    s * h / 3.0
}

fn b_period_s() -> f64 {
    accel_block(0, START_NS, &[[0.0; 3]]).sample_period_ns as f64 * 1e-9
}

/// A mount resonance (150 Hz, Q 2.5) under a tone and random vibration with no power
/// above 640 Hz: the compensator removes the exact model's VE change through the
/// suspension (MODEL.md section 6 at the transmitted vibration minus at the measured
/// one), computed here from the suspension's response by brute-force quadrature over
/// the true spectrum: the same whether the estimator looks over 20..640 Hz or
/// 20..2000 Hz, with the whole vibration and with the part inside each 1 ms output
/// interval (the tone's part then taken at each sample's phase through the
/// suspension, `phase_factor`). Before the compensator read the estimate's bands it
/// spread the random part flat over the broadband band, and the 20..2000 Hz setting
/// removed a change 3x off.
#[test]
fn a_resonance_under_random_vibration_is_removed_from_the_estimates_spectrum_whatever_the_band_setting(
) {
    let (f0, q) = (150.0, 2.5);
    let center_ns = START_NS - 500_000_000;
    let model = format!(
        "mode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = {f0}\nq = {q}\n"
    );
    // The output interval: the blocks' sample period (`support::accel_block`).
    let t_s = b_period_s();
    for within_interval in [false, true] {
        let r = |f: f64| if within_interval { within(f, t_s) } else { 1.0 };
        // The random part's variance kept (by the base model's reduction) and passed by
        // the suspension, per unit of the whole variance: the spectrum is flat, the
        // same shape on every axis, so every K_ij scales alike.
        let width = RIG_BAND_HZ[1] - RIG_BAND_HZ[0];
        let kept = simpson(RIG_BAND_HZ[0], RIG_BAND_HZ[1], r) / width;
        let passed = simpson(RIG_BAND_HZ[0], RIG_BAND_HZ[1], |f| {
            let (re, im) = suspension(f, f0, q);
            r(f) * (re * re + im * im)
        }) / width;
        let expected = |v: &Vibration, a_g: f64, p: &vibro_physics::passport::Passport| {
            let mut base = Vibration::none();
            let mut through = Vibration::none();
            for t in v.tones() {
                let keep = r(t.freq_hz).sqrt();
                let (re, im) = suspension(t.freq_hz, f0, q);
                let mut tb = *t;
                tb.amplitude_g = t.amplitude_g.map(|x| x * keep);
                let mut tt = tb;
                tt.amplitude_g = tb.amplitude_g.map(|x| x * re.hypot(im));
                tt.phase_rad = tb.phase_rad.map(|x| x + im.atan2(re));
                base.push_tone(tb).unwrap();
                through.push_tone(tt).unwrap();
            }
            for i in 0..3 {
                for j in 0..3 {
                    base.covariance_g2[i][j] = v.covariance_g2[i][j] * kept;
                    through.covariance_g2[i][j] = v.covariance_g2[i][j] * passed;
                }
            }
            base.kurtosis = v.kurtosis;
            through.kurtosis = v.kurtosis;
            let ve = |x: &Vibration| {
                vibro_physics::exact::exact_ve(p, [0.0, 0.0, a_g], x)
                    .unwrap()
                    .total_g
            };
            ve(&through) - ve(&base)
        };
        for broadband_hz in [[20.0, 640.0], [20.0, 2000.0]] {
            let mut plain = config(None);
            let mut ext = config(Some(&model));
            plain.model.estimate.within_output_interval = within_interval;
            ext.model.estimate.within_output_interval = within_interval;
            let b = blocks(&plain);
            let run_with = |c: &Config| {
                let axes = c.model.triad.axes;
                let mut p = InProcess::new(c).unwrap();
                let mut out = Vec::new();
                p.on_estimate(&rig_band_estimate(&axes, broadband_hz, 1, START_NS));
                // (support::BodyVibration::estimate: centre half a second before the end)
                for blk in &b {
                    p.on_accel(blk, 0, &mut out);
                }
                assert_eq!(p.summary().model_effect_errors, 0);
                out
            };
            let (without, with) = (run_with(&plain), run_with(&ext));
            let units = plain
                .model
                .triad
                .axes
                .units
                .map(|u| rig_band_vibration().at_unit(&u));
            let passports = plain
                .model
                .triad
                .passports
                .map(|p| vibro_effects::predict::flat_passport(&p).unwrap());
            let (mut worst_rel, mut largest) = (0.0f64, 0.0f64);
            for (a, x) in without.iter().zip(&with) {
                assert_eq!(x.flags, a.flags | cf::MODEL_EFFECTS);
                for k in 0..a.count as usize {
                    for u in 0..3 {
                        let full = expected(&units[u], a.a1_g[k][u], &passports[u]);
                        let want = if within_interval {
                            // The tone's part at this sample's phase: the unit's IA phase
                            // through the suspension, at the middle of the sample's
                            // interval, against the estimate's centre.
                            let mut random = units[u];
                            random.clear_tones();
                            let without = expected(&random, a.a1_g[k][u], &passports[u]);
                            let t = units[u].tones()[0];
                            let (re, im) = suspension(t.freq_hz, f0, q);
                            let mid_ns =
                                a.t0_ns + k as u64 * a.sample_period_ns - a.sample_period_ns / 2;
                            let dt_s = (mid_ns as f64 - center_ns as f64) * 1e-9;
                            let w = 2.0 * std::f64::consts::PI * t.freq_hz;
                            let theta = w * dt_s + t.phase_rad[2] + im.atan2(re);
                            without + phase_factor(theta, w * t_s) * (full - without)
                        } else {
                            full
                        };
                        // What the model removes beyond the base: its effects, and the
                        // difference of stage (19) taken at the tone's phase through the
                        // suspension rather than at the sensors'.
                        let got = (a.a4_g[k][u] - x.a4_g[k][u]) - (x.det_g[k][u] - a.det_g[k][u]);
                        largest = largest.max(want.abs());
                        worst_rel = worst_rel.max((got - want).abs() / want.abs());
                    }
                }
            }
            println!(
                "FIGURES mount_resonance within={within_interval} broadband {broadband_hz:?}: \
                 largest change {largest:.3e} g, worst relative deviation {worst_rel:.2e}"
            );
            assert!(largest > 1e-5, "{largest:e}");
            assert!(worst_rel < 2e-3, "{worst_rel:e}");
        }
    }
}
