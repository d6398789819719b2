//! Signal generation and stream feeding shared by the integration tests of vibro-dsp.
// Per-axis index loops mirror the formulas and index several arrays at once.
#![allow(clippy::needless_range_loop)]
#![allow(dead_code)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::f64::consts::TAU;
use vibro_dsp::{Estimate, Estimator, EstimatorConfig, EstimatorConfigRaw, SampleBlock};

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

pub fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    rng.random::<f64>()
}

/// A tone `amplitude_g[a] * sin(2 pi f t + phase_rad[a])`, `t = k / fs` from the first sample.
#[derive(Debug, Clone, Copy)]
pub struct Tone {
    pub frequency_hz: f64,
    pub amplitude_g: [f64; 3],
    pub phase_rad: [f64; 3],
}

impl Tone {
    pub fn at(&self, k: usize, fs_hz: f64) -> [f64; 3] {
        let arg = TAU * self.frequency_hz * k as f64 / fs_hz;
        std::array::from_fn(|a| self.amplitude_g[a] * (arg + self.phase_rad[a]).sin())
    }

    /// Phase of axis `a` at time `t_s` after the first sample.
    pub fn phase_at(&self, a: usize, t_s: f64) -> f64 {
        self.phase_rad[a] + TAU * self.frequency_hz * t_s
    }
}

/// White Gaussian noise with per-axis standard deviation `sigma_g`.
pub fn white_noise(rng: &mut ChaCha8Rng, samples: usize, sigma_g: [f64; 3]) -> Vec<[f64; 3]> {
    (0..samples)
        .map(|_| std::array::from_fn(|a| sigma_g[a] * gauss(rng)))
        .collect()
}

pub fn add_tone(x: &mut [[f64; 3]], tone: &Tone, fs_hz: f64) {
    for (k, s) in x.iter_mut().enumerate() {
        let t = tone.at(k, fs_hz);
        for a in 0..3 {
            s[a] += t[a];
        }
    }
}

pub fn estimator(raw: EstimatorConfigRaw) -> Estimator {
    Estimator::new(EstimatorConfig::try_from(raw).expect("valid test configuration"))
}

/// Feeds `samples` in blocks of `block_len` with consecutive sequence numbers and
/// timestamps from 0 ns, and collects every estimate.
pub fn feed(est: &mut Estimator, samples: &[[f64; 3]], block_len: usize) -> Vec<Estimate> {
    let fs_hz = est.config().sample_rate_hz();
    let mut out = Vec::new();
    for (seq, chunk) in samples.chunks(block_len).enumerate() {
        let t0_ns = (seq as f64 * block_len as f64 * 1e9 / fs_hz).round() as u64;
        let block = SampleBlock {
            seq: seq as u64,
            t0_ns,
            samples_raw: chunk,
        };
        est.push_block(&block, |e| out.push(*e))
            .expect("no internal error");
    }
    out
}

/// RMS of `errors`.
pub fn rms(errors: &[f64]) -> f64 {
    (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt()
}

pub fn wrap_pi(x: f64) -> f64 {
    let y = (x + std::f64::consts::PI).rem_euclid(TAU) - std::f64::consts::PI;
    if y <= -std::f64::consts::PI {
        y + TAU
    } else {
        y
    }
}
