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
            p.on_estimate(&estimate(&axes, seq + 1, START_NS + seq));
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
