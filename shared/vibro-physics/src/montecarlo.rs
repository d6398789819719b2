//! Seeded Monte Carlo of the conversion function (FP) over the vibration: the
//! independent check of the exact model (MODEL.md section 6, last point).
//!
//! Each draw takes every tone's phase uniform on `[0, 2 pi)`, the random part as a
//! correlated Gaussian (Cholesky factor of the covariance) scaled by `sqrt(w)` with `w`
//! from the [`ScaleMixture`] of the IA kurtosis (common to all axes, so the covariance
//! is kept), and evaluates (FP) sample by sample. Draws come in antithetic pairs
//! (`v` and `-v`): the odd terms of (FP), whose vibration mean is zero but whose
//! variance would swamp the small VE, cancel exactly within a pair. The standard error
//! is the spread of the pair means over `sqrt(pairs)`.

use crate::abs_mean::ScaleMixture;
use crate::fp::output_g;
use crate::passport::Passport;
use crate::vibration::Vibration;
use crate::{Error, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Serialize;
use std::f64::consts::TAU;

/// A Monte Carlo estimate of the VE.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MonteCarloVe {
    /// Mean of (FP) under vibration minus (FP) at the flight acceleration, g.
    pub ve_g: f64,
    /// Its standard error, g.
    pub std_error_g: f64,
    /// Number of (FP) evaluations under vibration.
    pub samples: u64,
    pub seed: u64,
}

/// Lower-triangular `L` with `L L^T = c` for a positive semi-definite 3x3 `c`
/// (a zero pivot leaves its column zero).
fn cholesky3(c: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut l = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let mut s = c[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                l[i][i] = s.max(0.0).sqrt();
            } else if l[j][j] > 0.0 {
                l[i][j] = s / l[j][j];
            }
        }
    }
    l
}

/// Most Monte Carlo evaluations [`monte_carlo_ve`] takes: about a minute of an
/// optimised build; beyond, a call (`--samples 18446744073709551615`) does not end.
pub const MAX_SAMPLES: u64 = 1_000_000_000;

/// The rule of [`monte_carlo_ve`]'s `samples`: `None` when `samples` keeps it.
pub fn samples_problem(samples: u64) -> Option<&'static str> {
    if samples < 4 {
        Some("at least 4 Monte Carlo samples are needed for a standard error")
    } else if samples > MAX_SAMPLES {
        Some("at most 1e9 Monte Carlo samples (a run of about a minute; more does not end)")
    } else {
        None
    }
}

/// Monte Carlo VE of unit `p` at flight acceleration `a_l_g = [aL1, aL2, aL3]` with
/// `samples` evaluations (rounded up to an even number), reproducible from `seed`.
/// `lambda(f)` scales each tone inside the asymmetry term, as in [`crate::exact`].
pub fn monte_carlo_ve(
    p: &Passport,
    a_l_g: [f64; 3],
    vib: &Vibration,
    samples: u64,
    seed: u64,
) -> Result<MonteCarloVe> {
    vib.validate()?;
    if let Some(rule) = samples_problem(samples) {
        return Err(Error::InvalidArgument {
            name: "samples",
            value: samples as f64,
            rule,
        });
    }
    let pairs = samples.div_ceil(2);
    let l = cholesky3(&vib.covariance_g2);
    let mixture = ScaleMixture::for_kurtosis(vib.kurtosis[2]);
    let lambdas: Vec<f64> = vib.tones().iter().map(|t| p.lambda_at(t.freq_hz)).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let still = output_g(p, a_l_g[0], a_l_g[1], a_l_g[2]);
    // FP with the asymmetry seeing lambda-scaled tones: FP(a) + 0.5 k1 d1A (|a_lambda| - |a3|).
    let fp = |v: &[f64; 3], v3_lambda: f64| {
        let a3 = a_l_g[2] + v[2];
        output_g(p, a_l_g[0] + v[0], a_l_g[1] + v[1], a3)
            + 0.5 * p.k1 * p.d1a * ((a_l_g[2] + v3_lambda).abs() - a3.abs())
    };
    // Welford's running mean and variance of the pair means.
    let (mut mean, mut m2) = (0.0, 0.0);
    for n in 1..=pairs {
        let mut v = [0.0; 3];
        let mut v3_lambda = 0.0;
        for (t, lambda) in vib.tones().iter().zip(&lambdas) {
            let theta: f64 = rng.random::<f64>() * TAU;
            for (i, vi) in v.iter_mut().enumerate() {
                *vi += t.amplitude_g[i] * (theta + t.phase_rad[i]).sin();
            }
            v3_lambda += lambda * t.amplitude_g[2] * (theta + t.phase_rad[2]).sin();
        }
        let z: [f64; 3] = [
            rng.sample(StandardNormal),
            rng.sample(StandardNormal),
            rng.sample(StandardNormal),
        ];
        let w = if rng.random::<f64>() < mixture.prob[1] {
            mixture.scale[1]
        } else {
            mixture.scale[0]
        };
        let sw = w.sqrt();
        for i in 0..3 {
            let x = sw * (l[i][0] * z[0] + l[i][1] * z[1] + l[i][2] * z[2]);
            v[i] += x;
            if i == 2 {
                v3_lambda += x;
            }
        }
        let neg = [-v[0], -v[1], -v[2]];
        let y = 0.5 * (fp(&v, v3_lambda) + fp(&neg, -v3_lambda)) - still;
        let d = y - mean;
        mean += d / n as f64;
        m2 += d * (y - mean);
    }
    let var = if pairs > 1 {
        m2 / (pairs - 1) as f64
    } else {
        0.0
    };
    Ok(MonteCarloVe {
        ve_g: mean,
        std_error_g: (var / pairs as f64).sqrt(),
        samples: 2 * pairs,
        seed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_rule_bounds_both_ends() {
        assert!(samples_problem(3).is_some());
        assert!(samples_problem(4).is_none());
        assert!(samples_problem(MAX_SAMPLES).is_none());
        assert!(samples_problem(MAX_SAMPLES + 1).is_some());
        assert!(samples_problem(u64::MAX).is_some());
    }
    use crate::exact::exact_ve;
    use crate::testutil::{aks05, al15};
    use crate::ve::{published, Constants};
    use crate::vibration::Tone;

    fn tone(freq_hz: f64, amplitude_g: [f64; 3], phase_deg: [f64; 3]) -> Tone {
        Tone {
            freq_hz,
            amplitude_g,
            phase_rad: phase_deg.map(f64::to_radians),
        }
    }

    /// The exact model agrees with a seeded Monte Carlo of (FP) within 4.5 standard
    /// errors on a grid of sinusoid, random, both, several tones, phases, non-Gaussian
    /// vibration and nonzero flight acceleration (MODEL.md section 6).
    #[test]
    fn exact_matches_monte_carlo_on_a_wide_grid() {
        let mut cases: Vec<(&str, Passport, [f64; 3], Vibration)> = Vec::new();
        let p = al15();
        cases.push((
            "P1 Table 4 sinusoid",
            p,
            [0.0, 0.0, 10.0],
            Vibration::single_tone(12.0, [0.8, 0.8, 0.42]),
        ));
        cases.push((
            "sinusoid at aL3 = 0 (asymmetry)",
            p,
            [0.0, 0.0, 0.0],
            Vibration::single_tone(30.0, [0.0, 0.0, 2.0]),
        ));
        cases.push((
            "sinusoid crossing zero, aL3 = 1",
            p,
            [0.3, 0.0, 1.0],
            Vibration::single_tone(30.0, [1.0, 0.5, 2.0]),
        ));
        let mut band = Vibration::none();
        band.covariance_g2[2][2] = 38.4;
        cases.push((
            "random 320..640 Hz band, aL3 = 10",
            p,
            [0.0, 0.0, 10.0],
            band,
        ));
        let mut both = Vibration::single_tone(12.0, [1.2, 1.2, 0.5]);
        both.covariance_g2 = [[1.0, 0.1, 0.5], [0.1, 1.0, -0.3], [0.5, -0.3, 1.96]];
        cases.push((
            "tone + correlated random, Cyclone-4",
            p,
            [0.4, -0.2, 2.0],
            both,
        ));
        let mut tones = Vibration::none();
        tones
            .push_tone(tone(11.0, [1.0, 0.5, 2.0], [0.0, 40.0, 90.0]))
            .unwrap();
        tones
            .push_tone(tone(47.3, [0.3, 0.9, 0.7], [10.0, 0.0, -60.0]))
            .unwrap();
        tones
            .push_tone(tone(123.9, [0.2, 0.2, 1.1], [0.0, 180.0, 0.0]))
            .unwrap();
        tones.covariance_g2[2][2] = 0.25;
        cases.push((
            "three tones with phases + random",
            p,
            [0.0, 0.5, -3.0],
            tones,
        ));
        let mut kurtotic = Vibration::random_rms([1.0, 1.0, 1.4]);
        kurtotic.kurtosis[2] = 6.0;
        cases.push((
            "non-Gaussian random, kurtosis 6",
            p,
            [0.0, 0.0, 2.0],
            kurtotic,
        ));
        let mut missile = Vibration::single_tone(17.0, [2.0, 2.0, 2.0]);
        missile.covariance_g2[2][2] = 25.0;
        missile.kurtosis[2] = 4.0;
        cases.push((
            "tactical missile, AKS-05",
            aks05(),
            [0.0, 0.0, 5.1],
            missile,
        ));

        let mut published_outside = 0;
        for (i, (name, p, a_l, vib)) in cases.iter().enumerate() {
            let e = exact_ve(p, *a_l, vib).unwrap();
            let mc = monte_carlo_ve(p, *a_l, vib, 2_000_000, 1000 + i as u64).unwrap();
            let z = (e.total_g - mc.ve_g) / mc.std_error_g;
            eprintln!(
                "{name}: exact {:.6e} g, MC {:.6e} +- {:.1e} g, z = {z:.2}",
                e.total_g, mc.ve_g, mc.std_error_g
            );
            assert!(
                z.abs() < 4.5,
                "{name}: exact {:.6e} g, Monte Carlo {:.6e} +- {:.1e} g (z = {z:.2})",
                e.total_g,
                mc.ve_g,
                mc.std_error_g
            );
            // The test has the power to see the papers' approximations.
            let q = published(p, *a_l, vib, Constants::PAPER);
            if ((q.total_g - mc.ve_g) / mc.std_error_g).abs() > 10.0 {
                published_outside += 1;
            }
        }
        assert!(
            published_outside >= 5,
            "only {published_outside} cases told the published model apart"
        );
    }

    #[test]
    fn cholesky_reproduces_the_covariance() {
        let c = [[4.0, 0.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 2.0]];
        let l = cholesky3(&c);
        for i in 0..3 {
            for j in 0..3 {
                let s: f64 = (0..3).map(|k| l[i][k] * l[j][k]).sum();
                assert!((s - c[i][j]).abs() < 1e-14);
            }
        }
    }
}
