//! The vibration-sensor model: the AC coupling's gain and phase, the ADC step and
//! clipping, the noise level; and its stream feeds vibro-dsp's estimator.

use crate::common::*;
use std::f64::consts::{PI, TAU};
use vibro_sim::scenario::SensorSpec;
use vibro_sim::sensor::{ac_coupling_response, SensorChain};
use vibro_sim::Simulator;

#[test]
fn ac_coupling_has_its_documented_gain_and_phase() {
    let fs = 1000.0;
    let spec = SensorSpec {
        sensitivity_v_per_g: 1.0,
        ac_corner_hz: 2.0,
        noise_g_rms: 0.0,
        adc_bits: 32,
        full_scale_v: 10.0,
    };
    for f in [0.5, 2.0, 3.0, 50.0] {
        let mut s = SensorChain::new(&spec, fs, 1, 0, 0);
        // 40 s; fit the last 20 s (the transient decays with tau = 80 ms).
        let n = 40_000;
        let (mut c, mut sn, mut cc, mut ss, mut cs) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for k in 0..n {
            let th = TAU * f * k as f64 / fs;
            let y = s.process(th.sin());
            if k >= n / 2 {
                let (si, co) = th.sin_cos();
                sn += y * si;
                c += y * co;
                ss += si * si;
                cc += co * co;
                cs += si * co;
            }
        }
        // Least squares y = a sin + b cos.
        let det = ss * cc - cs * cs;
        let a = (sn * cc - c * cs) / det;
        let b = (c * ss - sn * cs) / det;
        let (gain, phase) = (a.hypot(b), b.atan2(a));
        let (g_want, p_want) = ac_coupling_response(f, 2.0, fs);
        // The documented formula: H = j u / (1 + j u), u = tan(pi f/fs)/tan(pi fc/fs).
        let u = (PI * f / fs).tan() / (PI * 2.0 / fs).tan();
        assert!((g_want - u / (1.0 + u * u).sqrt()).abs() < 1e-15);
        println!(
            "{f} Hz: gain {gain:.9} (formula {g_want:.9}), phase {:.6} deg (formula {:.6} deg)",
            phase.to_degrees(),
            p_want.to_degrees()
        );
        assert!(
            (gain - g_want).abs() < 1e-7,
            "{f} Hz: gain {gain} vs {g_want}"
        );
        assert!(
            (phase - p_want).abs() < 1e-7,
            "{f} Hz: phase {phase} vs {p_want}"
        );
    }
    // At the corner: 1/sqrt(2) and 45 deg exactly (pre-warped bilinear transform).
    let (g, p) = ac_coupling_response(2.0, 2.0, fs);
    assert!((g - 0.5f64.sqrt()).abs() < 1e-15 && (p - PI / 4.0).abs() < 1e-15);
}

#[test]
fn adc_step_is_full_scale_over_2_to_bits_minus_1_and_clips() {
    let spec = SensorSpec {
        sensitivity_v_per_g: 1.0,
        ac_corner_hz: 0.0,
        noise_g_rms: 0.0,
        adc_bits: 8,
        full_scale_v: 1.0,
    };
    let mut s = SensorChain::new(&spec, 1000.0, 1, 0, 0);
    let q = 1.0 / 128.0;
    assert_eq!(s.step_v(), q);
    let inputs: Vec<f64> = (0..30_001)
        .map(|k| -1.5 + 3.0 * k as f64 / 30_000.0)
        .collect();
    let out: Vec<f64> = inputs.iter().map(|x| s.process(*x)).collect();
    let mut levels: Vec<f64> = out.clone();
    levels.dedup();
    assert_eq!(levels.len(), 256, "2^8 codes");
    assert_eq!(levels[0], -1.0);
    assert_eq!(*levels.last().unwrap(), 1.0 - q);
    for w in levels.windows(2) {
        assert_eq!(w[1] - w[0], q);
    }
    for (x, y) in inputs.iter().zip(&out) {
        if (-1.0..1.0 - q).contains(x) {
            assert!((x - y).abs() <= 0.5 * q + 1e-15, "{x} -> {y}");
        }
    }
    // Clipped: beyond the end codes by more than half a step.
    let want = inputs
        .iter()
        .filter(|x| **x / q < -128.5 || **x / q >= 127.5)
        .count() as u64;
    assert_eq!(s.clipped_samples(), want);
    assert!(want > 9000);
    // The noise: 2 mg RMS referred to the input at 0.1 V/g, 24 bits.
    let noisy = SensorSpec {
        sensitivity_v_per_g: 0.1,
        noise_g_rms: 2e-3,
        adc_bits: 24,
        full_scale_v: 10.0,
        ac_corner_hz: 0.0,
    };
    let mut s = SensorChain::new(&noisy, 1000.0, 3, 0, 0);
    let n = 200_000;
    let rms = ((0..n).map(|_| s.process(0.0).powi(2)).sum::<f64>() / n as f64).sqrt() / 0.1;
    // Standard error of an RMS of n Gaussian samples: rms/sqrt(2n) = 3.2e-6 g.
    assert!(
        (rms - 2e-3).abs() < 4.0 * 2e-3 / (2.0 * n as f64).sqrt(),
        "{rms}"
    );
}

/// The estimates of vibro-dsp's estimator over a 4 s run of `text` (2 s windows).
fn estimate(text: &str) -> Vec<vibro_dsp::Estimate> {
    let s = parse(text);
    let mut sim = Simulator::new(&s, Vec::new()).unwrap();
    let sens = s.sensor.sensitivity_v_per_g;
    let mut raw = vibro_dsp::EstimatorConfigRaw::new(s.rates.sensor_hz, [sens; 3]);
    raw.ac_corner_hz = Some(s.sensor.ac_corner_hz);
    raw.window_s = 2.0;
    raw.tone_snr_threshold_db = 10.0;
    let mut est = vibro_dsp::Estimator::new(vibro_dsp::EstimatorConfig::try_from(raw).unwrap());
    let mut estimates = Vec::new();
    let r = record(&mut sim);
    for (seq, block) in r.sensor_v.chunks(2560).enumerate() {
        let b = vibro_dsp::SampleBlock {
            seq: seq as u64,
            t0_ns: r.sensor_time_ns[seq * 2560],
            samples_raw: block,
        };
        est.push_block(&b, |e| estimates.push(*e)).unwrap();
    }
    estimates
}

#[test]
fn sensor_stream_feeds_the_vibro_dsp_estimator() {
    // Cyclone-4's vibration with the tones held at 8 Hz, 4 s: three 2 s windows. At
    // 8 Hz the 0.5 g tone stands about 14 dB over the floor the estimator takes from
    // the 20..64 Hz random vibration next to it: the detection threshold is lowered
    // from its default 20 dB to 10 dB.
    let text = shipped_text("cyclone-4-short")
        .replace("duration_s = 20.0", "duration_s = 4.0")
        .replace("sweep_to_hz = 16.0\n", "");
    // Tones alone: the estimator recovers them within its own uncertainty (plus the
    // 0.2 % of the ADC and sensor noise), through the sensitivity and AC coupling.
    let tones_only = estimate(&text.replace("rms_g = [1.4, 1.4, 1.4]", "scale = [0.0, 0.0, 0.0]"));
    assert_eq!(tones_only.len(), 3);
    for e in &tones_only {
        let tone = e
            .tones
            .iter()
            .find(|t| (t.frequency_hz - 8.0).abs() < 0.01)
            .expect("the 8 Hz tone");
        // Sensor u measures along unit u's IA: body x, y, z = 0.5, 1.2, 1.2 g.
        for ((got, u), want) in tone
            .amplitude_g
            .iter()
            .zip(tone.amplitude_u_g)
            .zip([0.5, 1.2, 1.2])
        {
            assert!(
                (got - want).abs() < 4.0 * u + 1e-3 * want,
                "tone {:?} +- {:?}",
                tone.amplitude_g,
                tone.amplitude_u_g
            );
        }
    }
    // With the random vibration: the broadband RMS is the scenario's 1.4 g within the
    // estimator's uncertainty (about 5 % in a 2 s window: the Cyclone-4 shape puts
    // most of the power in 20..80 Hz). The tones
    // move by up to 2 %: the 20..40 Hz random vibration leaks into a 2 s rectangular
    // sine fit at 8 Hz (a lock-in of the noise-free body vibration sees the same),
    // which the estimator's stated uncertainty does not include.
    let full = estimate(&text);
    assert_eq!(full.len(), 3);
    for e in &full {
        let tone = e
            .tones
            .iter()
            .find(|t| (t.frequency_hz - 8.0).abs() < 0.1)
            .expect("the 8 Hz tone");
        for (got, want) in tone.amplitude_g.iter().zip([0.5, 1.2, 1.2]) {
            assert!(
                (got - want).abs() < 0.03 * want,
                "tone {:?}",
                tone.amplitude_g
            );
        }
        for (rms, u) in e.broadband.rms_g.iter().zip(e.broadband.rms_u_g) {
            let z = (rms - 1.4) / u;
            assert!(
                z.abs() < 4.0,
                "broadband {:?} +- {:?}",
                e.broadband.rms_g,
                e.broadband.rms_u_g
            );
        }
        assert!(!e.flags.saturated.iter().any(|s| *s) && !e.flags.gap);
    }
    println!(
        "estimator, first window: tones alone {:?} g; with random {:?} g, broadband RMS {:?} +- {:?} g",
        tones_only[0].tones[0].amplitude_g, full[0].tones[0].amplitude_g, full[0].broadband.rms_g, full[0].broadband.rms_u_g
    );
}
