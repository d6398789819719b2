//! The generated random vibration against its description: band variances against
//! the PSD table (periodogram), the coherence matrix (sample correlations) and the
//! kurtosis (sample fourth moments), each within its statistical error.

use crate::common::*;
use realfft::RealFftPlanner;
use std::f64::consts::TAU;
use vibro_sim::Simulator;

/// A flight with random vibration only (no tones), `duration_s` long.
fn random_flight(duration_s: f64, random: &str) -> vibro_sim::Scenario {
    parse(&format!(
        r#"
name = "random"
seed = 11
[rates]
output_hz = 800
[sensor]
sensitivity_v_per_g = 0.1
ac_corner_hz = 0.5
noise_g_rms = 1e-3
adc_bits = 24
full_scale_v = 10.0
[flight]
duration_s = {duration_s}
triad = "default"
[[flight.profile]]
t_s = 0.0
accel_body_g = [1.0, 0.0, 0.0]
[flight.random]
{random}
"#
    ))
}

/// Band variances of `x` (sampled at `fs_hz`) by averaged Hann periodograms of
/// `n`-sample segments: per band, the mean over segments and its standard error.
fn band_variances(x: &[f64], fs_hz: f64, n: usize, bands: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut planner = RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(n);
    let window: Vec<f64> = (0..n)
        .map(|i| 0.5 - 0.5 * (TAU * i as f64 / n as f64).cos())
        .collect();
    let w2: f64 = window.iter().map(|w| w * w).sum();
    let df = fs_hz / n as f64;
    let segments = x.len() / n;
    let mut per_segment = vec![vec![0.0; segments]; bands.len()];
    let mut input = fft.make_input_vec();
    let mut spectrum = fft.make_output_vec();
    for s in 0..segments {
        for (i, v) in input.iter_mut().enumerate() {
            *v = x[s * n + i] * window[i];
        }
        fft.process(&mut input, &mut spectrum).unwrap();
        for (b, &(lo, hi)) in bands.iter().enumerate() {
            // One-sided PSD 2|X|^2/(fs sum w^2), integrated over the band.
            per_segment[b][s] = spectrum
                .iter()
                .enumerate()
                .filter(|(k, _)| (*k as f64 * df) >= lo && (*k as f64 * df) < hi)
                .map(|(_, c)| 2.0 * c.norm_sqr() / (fs_hz * w2) * df)
                .sum();
        }
    }
    per_segment
        .iter()
        .map(|v| {
            let m = v.iter().sum::<f64>() / segments as f64;
            let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (segments - 1) as f64;
            (m, (var / segments as f64).sqrt())
        })
        .collect()
}

#[test]
fn band_variance_matches_the_psd_table() {
    // [P1 Table 3] as it stands (sigma = 8.02 g) on x, scaled on y and z.
    let s = random_flight(41.0, "psd_table = \"p1-table3\"\nscale = [1.0, 0.5, 0.25]");
    let mut sim = Simulator::new(&s, Vec::new()).unwrap();
    let r = record(&mut sim);
    let table = [
        (20.0, 40.0, 0.017),
        (40.0, 80.0, 0.020),
        (80.0, 160.0, 0.070),
        (160.0, 320.0, 0.120),
        (320.0, 640.0, 0.120),
    ];
    let bands: Vec<(f64, f64)> = table.iter().map(|b| (b.0, b.1)).collect();
    let mut worst = 0.0f64;
    for (axis, scale) in [(0, 1.0), (1, 0.5), (2, 0.25)] {
        let x: Vec<f64> = r.body_g.iter().map(|v| v[axis]).collect();
        let got = band_variances(&x, 25_600.0, 1 << 16, &bands);
        for ((lo, hi, psd), (m, se)) in table.iter().zip(&got) {
            let want = psd * (hi - lo) * scale * scale;
            let z = (m - want) / se;
            println!("axis {axis} band {lo}..{hi} Hz: {m:.5} +- {se:.5} g^2 (table {want:.5}), z = {z:+.2}");
            worst = worst.max(z.abs());
            assert!(z.abs() < 4.0, "axis {axis} band {lo}..{hi}: z = {z}");
        }
        // Nothing outside the table (below 20 Hz and 640..2000 Hz).
        let out = band_variances(&x, 25_600.0, 1 << 16, &[(1.0, 18.0), (660.0, 2000.0)]);
        let total = 64.34 * scale * scale;
        assert!(
            out[0].0 < 1e-3 * total && out[1].0 < 1e-3 * total,
            "leakage {out:?}"
        );
    }
    println!("largest |z| over 15 bands: {worst:.2}");
}

/// Sample statistics with batch-means standard errors.
fn batch_stat(x: &[f64], batches: usize, f: impl Fn(&[f64]) -> f64) -> (f64, f64) {
    let n = x.len();
    let v: Vec<f64> = (0..batches)
        .map(|b| f(&x[b * n / batches..(b + 1) * n / batches]))
        .collect();
    let m = v.iter().sum::<f64>() / batches as f64;
    let var = v.iter().map(|y| (y - m) * (y - m)).sum::<f64>() / (batches - 1) as f64;
    (m, (var / batches as f64).sqrt())
}

#[test]
fn coherence_matrix_is_reproduced() {
    let r_want = [[1.0, 0.6, 0.2], [0.6, 1.0, -0.3], [0.2, -0.3, 1.0]];
    let s = random_flight(
        20.0,
        "psd_table = \"p1-table3\"\nrms_g = [2.0, 1.0, 3.0]\ncoherence = [[1.0, 0.6, 0.2], [0.6, 1.0, -0.3], [0.2, -0.3, 1.0]]",
    );
    let mut sim = Simulator::new(&s, Vec::new()).unwrap();
    // Same PSD shape on every axis: the covariance is R_ij sigma_i sigma_j.
    let k = sim.body_vibration_scenario().covariance_g2;
    let sigma = [2.0, 1.0, 3.0];
    for i in 0..3 {
        for j in 0..3 {
            assert!(
                (k[i][j] - r_want[i][j] * sigma[i] * sigma[j]).abs() < 1e-9,
                "K{i}{j} = {}",
                k[i][j]
            );
        }
    }
    let r = record(&mut sim);
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let pairs: Vec<f64> = r.body_g.iter().flat_map(|v| [v[i], v[j]]).collect();
        let corr = |s: &[f64]| {
            let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
            for p in s.chunks(2) {
                sxy += p[0] * p[1];
                sxx += p[0] * p[0];
                syy += p[1] * p[1];
            }
            sxy / (sxx * syy).sqrt()
        };
        let (m, se) = batch_stat(&pairs, 20, corr);
        let z = (m - r_want[i][j]) / se;
        println!(
            "coherence {i}{j}: {m:.4} +- {se:.4} (want {}), z = {z:+.2}",
            r_want[i][j]
        );
        assert!(
            z.abs() < 4.0 && (m - r_want[i][j]).abs() < 0.05,
            "R{i}{j} = {m} +- {se}"
        );
    }
}

/// Kurtosis `M4/M2^2` of the whole record, with its standard error by the delta
/// method over batch means (the ratio of batch-wise ratios would be biased).
fn kurtosis_with_se(x: &[f64], batches: usize) -> (f64, f64) {
    let n = x.len();
    let moments: Vec<(f64, f64)> = (0..batches)
        .map(|b| {
            let s = &x[b * n / batches..(b + 1) * n / batches];
            let l = s.len() as f64;
            (
                s.iter().map(|v| v * v).sum::<f64>() / l,
                s.iter().map(|v| v.powi(4)).sum::<f64>() / l,
            )
        })
        .collect();
    let m2 = moments.iter().map(|m| m.0).sum::<f64>() / batches as f64;
    let m4 = moments.iter().map(|m| m.1).sum::<f64>() / batches as f64;
    let k = m4 / (m2 * m2);
    // Linearisation: dK = dM4/M2^2 - 2 M4 dM2/M2^3.
    let lin: Vec<f64> = moments
        .iter()
        .map(|(a, b)| b / (m2 * m2) - 2.0 * m4 * a / m2.powi(3))
        .collect();
    let lm = lin.iter().sum::<f64>() / batches as f64;
    let var = lin.iter().map(|v| (v - lm) * (v - lm)).sum::<f64>() / (batches - 1) as f64;
    (k, (var / batches as f64).sqrt())
}

#[test]
fn kurtosis_is_reproduced_at_the_same_psd() {
    // Different kurtoses on correlated axes 0 and 2: the covariance shrinks by
    // E[sqrt(w0 w2)] (vibro_sim::random docs), which the description reports.
    let s = random_flight(
        30.0,
        "rms_g = [2.0, 2.0, 2.0]\nkurtosis = [6.0, 3.0, 12.0]\nkurtosis_segment_s = 0.02\n\
         coherence = [[1.0, 0.0, 0.5], [0.0, 1.0, 0.0], [0.5, 0.0, 1.0]]\n\
         [[flight.random.band]]\nf_lo_hz = 320.0\nf_hi_hz = 640.0\npsd_g2_per_hz = 0.12",
    );
    let mut sim = Simulator::new(&s, Vec::new()).unwrap();
    let k02 = sim.body_vibration_scenario().covariance_g2[0][2];
    let r = record(&mut sim);
    for (axis, want) in [(0, 6.0), (1, 3.0), (2, 12.0)] {
        let x: Vec<f64> = r.body_g.iter().map(|v| v[axis]).collect();
        let (k, se) = kurtosis_with_se(&x, 20);
        let (var, var_se) = batch_stat(&x, 20, |s| {
            s.iter().map(|v| v * v).sum::<f64>() / s.len() as f64
        });
        let (zk, zv) = ((k - want) / se, (var - 4.0) / var_se);
        println!("axis {axis}: kurtosis {k:.3} +- {se:.3} (want {want}), z = {zk:+.2}; variance {var:.4} +- {var_se:.4} g^2 (want 4), z = {zv:+.2}");
        assert!(zk.abs() < 4.0, "axis {axis}: kurtosis {k} +- {se}");
        assert!(zv.abs() < 4.0, "axis {axis}: variance {var} +- {var_se}");
    }
    let pairs: Vec<f64> = r.body_g.iter().flat_map(|v| [v[0], v[2]]).collect();
    let (c, se) = batch_stat(&pairs, 20, |s| {
        s.chunks(2).map(|p| p[0] * p[1]).sum::<f64>() / (s.len() / 2) as f64
    });
    // E[sqrt(w0 w2)] for the two mixtures, from their definition.
    let m0 = vibro_physics::abs_mean::ScaleMixture::for_kurtosis(6.0);
    let m2 = vibro_physics::abs_mean::ScaleMixture::for_kurtosis(12.0);
    let factor = m0.prob[0] * (m0.scale[0] * m2.scale[0]).sqrt()
        + m0.prob[1] * (m0.scale[1] * m2.scale[1]).sqrt();
    assert!(
        (k02 - 0.5 * 4.0 * factor).abs() < 1e-9,
        "description K02 = {k02}, factor {factor}"
    );
    let z = (c - k02) / se;
    println!("K02 = {c:.4} +- {se:.4} g^2 (want 2 x {factor:.4} = {k02:.4}), z = {z:+.2}");
    assert!(z.abs() < 4.0);
}
