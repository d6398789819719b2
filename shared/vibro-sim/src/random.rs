//! Band-shaped, optionally non-Gaussian and cross-correlated random vibration,
//! generated sample by sample with bounded memory (MODEL.md section 3: `x_i(t)`,
//! zero-mean, stationary, `<x_i^2> = sigma_i^2 = sum S_i df`).
//!
//! **Shape.** Unit white Gaussian noise (one sample has variance 1, so its one-sided
//! PSD is `2/fs`) is filtered by a linear-phase FIR whose amplitude response is
//! `|H(f)| = sqrt(S(f) fs / 2)`, so the output's one-sided PSD is `S(f)`. The FIR is
//! designed by frequency sampling on an `n`-point grid (`n` a power of two, at least
//! `fs / filter_resolution_hz`): each grid point takes the PSD table's mean over its
//! bin (so the grid carries exactly the table's variance per band), the inverse real
//! FFT gives the zero-phase response, which is centred and tapered with a periodic
//! Hann window (smoothing the response over +-1 bin, about +-0.8 Hz at 25.6 kHz with
//! the default 1 Hz resolution). The taps are then scaled so that `sum h^2`, the
//! output variance, equals the table's `sigma^2` exactly; the smoothing moves a little
//! power across band edges (below 2 % of a 20 Hz band next to a silent one).
//!
//! **Streaming.** The FIR is applied by overlap-save with FFTs of `2n` (`realfft`): each
//! block draws `n` new white samples per axis and yields `n` filtered ones, from
//! buffers allocated at construction. The history is primed with white noise, so the
//! output is stationary from its first sample, and any duration runs in bounded memory.
//!
//! **Cross-correlation.** The white noises of the three axes are mixed with the
//! Cholesky factor `L` of the coherence matrix `R` (unit diagonal) before filtering, so
//! the cross-spectrum of axes `i`, `j` is `R_ij H_i H_j*`: `R_ij` is the coherence at
//! every frequency, and the covariance is `K_ij = R_ij sum_m h_i[m] h_j[m]`, which is
//! `R_ij sigma_i sigma_j` when the two axes have the same PSD shape.
//!
//! **Non-Gaussian (kurtosis).** Each axis is multiplied by `sqrt(w)`, where `w` is drawn
//! once per segment (default 0.25 s, long against the correlation time of the band) from
//! the scale mixture that the exact model uses,
//! [`vibro_physics::abs_mean::ScaleMixture::for_kurtosis`]: `E[w] = 1` keeps the variance,
//! `E[w^2] = kurtosis/3` gives the kurtosis. One uniform draw per segment decides the
//! state for all axes (every axis's mixture has the same `P_HIGH`), so bursts are
//! simultaneous. The PSD is kept up to a smoothing by the spectrum of the piecewise-
//! constant scale (width about `1/segment`, 4 Hz for 0.25 s). Across axes with
//! different kurtoses the covariance is multiplied by
//! `c_ij = E[sqrt(w_i w_j)] <= 1` (1 for equal kurtoses); [`RandomGenerator::covariance_g2`]
//! includes it.

use crate::streams::{rng, Source};
use crate::{Error, Result};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use std::f64::consts::TAU;
use std::sync::Arc;
use vibro_physics::abs_mean::ScaleMixture;
use vibro_physics::vibration::PsdBand;

/// Largest FIR length (and overlap-save block), samples: 4 Mi taps, i.e. 0.16 Hz at
/// 655 kHz; beyond this the design would need more memory than a simulation should.
pub const MAX_FILTER_LEN: usize = 1 << 22;

/// What to generate: the PSD of each axis, their coherence and kurtosis.
#[derive(Debug, Clone, PartialEq)]
pub struct RandomSetup {
    /// Piecewise-constant one-sided PSD per axis (`psd_g2_per_hz[i]` is axis `i`).
    pub bands: Vec<PsdBand>,
    /// Coherence (correlation) matrix of the axes: symmetric, unit diagonal, positive
    /// semi-definite.
    pub coherence: [[f64; 3]; 3],
    /// Kurtosis per axis, 3 (Gaussian) to 30.
    pub kurtosis: [f64; 3],
    /// Length of a mixture segment, s.
    pub segment_s: f64,
    /// Largest FIR bin width, Hz (the filter has at least `fs / resolution` taps).
    pub filter_resolution_hz: f64,
}

impl RandomSetup {
    /// `sigma_i^2 = sum S_i df` per axis, g^2 (MODEL.md section 3).
    pub fn variance_g2(&self) -> [f64; 3] {
        let mut v = [0.0; 3];
        for b in &self.bands {
            for (vi, s) in v.iter_mut().zip(b.psd_g2_per_hz) {
                *vi += s * (b.f_hi_hz - b.f_lo_hz);
            }
        }
        v
    }
}

/// The FIR length for a rate and resolution: the next power of two of `fs/resolution`.
pub fn filter_len(fs_hz: f64, filter_resolution_hz: f64) -> usize {
    let want = (fs_hz / filter_resolution_hz).ceil();
    if !(want.is_finite() && want >= 1.0) {
        return 16;
    }
    (want as usize)
        .clamp(16, MAX_FILTER_LEN)
        .next_power_of_two()
}

/// Lower-triangular `L` with `L L^T = c` for a positive semi-definite `c`; a zero
/// (or round-off negative) pivot leaves its column zero.
pub(crate) fn cholesky3(c: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut l = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..=i {
            let mut s = c[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                l[i][i] = s.max(0.0).sqrt();
            } else if l[j][j] > 1e-12 {
                l[i][j] = s / l[j][j];
            }
        }
    }
    l
}

/// `max |L L^T - c|`: how far `c` is from positive semi-definite (0 when it is).
pub(crate) fn cholesky_residual(c: &[[f64; 3]; 3]) -> f64 {
    let l = cholesky3(c);
    let mut worst = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let p: f64 = (0..3).map(|k| l[i][k] * l[j][k]).sum();
            worst = worst.max((p - c[i][j]).abs());
        }
    }
    worst
}

fn fft_error(what: &'static str) -> impl Fn(realfft::FftError) -> Error {
    move |e| Error::Fft {
        what,
        message: e.to_string(),
    }
}

/// Designs the taps of axis `axis` (length `n`), scaled so that `sum h^2` equals the
/// table's variance; all zero when the axis has no random vibration.
fn design_taps(
    bands: &[PsdBand],
    axis: usize,
    fs_hz: f64,
    n: usize,
    planner: &mut RealFftPlanner<f64>,
) -> Result<Vec<f64>> {
    let variance_g2: f64 = bands
        .iter()
        .map(|b| b.psd_g2_per_hz[axis] * (b.f_hi_hz - b.f_lo_hz))
        .sum();
    if variance_g2 <= 0.0 {
        return Ok(vec![0.0; n]);
    }
    let df_hz = fs_hz / n as f64;
    let nyquist_hz = 0.5 * fs_hz;
    let inverse = planner.plan_fft_inverse(n);
    let mut spectrum = inverse.make_input_vec();
    for (k, s) in spectrum.iter_mut().enumerate() {
        let lo = ((k as f64 - 0.5) * df_hz).max(0.0);
        let hi = ((k as f64 + 0.5) * df_hz).min(nyquist_hz);
        let width = hi - lo;
        let power: f64 = bands
            .iter()
            .map(|b| {
                let overlap = (b.f_hi_hz.min(hi) - b.f_lo_hz.max(lo)).max(0.0);
                overlap * b.psd_g2_per_hz[axis]
            })
            .sum();
        let mean_psd = if width > 0.0 { power / width } else { 0.0 };
        *s = Complex::new((mean_psd * fs_hz / 2.0).sqrt(), 0.0);
    }
    let mut zero_phase = inverse.make_output_vec();
    let mut scratch = inverse.make_scratch_vec();
    inverse
        .process_with_scratch(&mut spectrum, &mut zero_phase, &mut scratch)
        .map_err(fft_error("the random-vibration filter design"))?;
    let half = n / 2;
    let mut taps: Vec<f64> = (0..n)
        .map(|m| {
            let hann = 0.5 - 0.5 * (TAU * m as f64 / n as f64).cos();
            zero_phase[(m + half) % n] / n as f64 * hann
        })
        .collect();
    let energy: f64 = taps.iter().map(|h| h * h).sum();
    if energy > 0.0 {
        let scale = (variance_g2 / energy).sqrt();
        taps.iter_mut().for_each(|h| *h *= scale);
    }
    Ok(taps)
}

/// Streaming generator of three-axis random vibration (see the module docs). All
/// buffers are allocated when it is built; [`RandomGenerator::fill`] does
/// not allocate.
pub struct RandomGenerator {
    /// FIR length = new samples per overlap-save block.
    n: usize,
    forward: Arc<dyn RealToComplex<f64>>,
    inverse: Arc<dyn ComplexToReal<f64>>,
    taps: [Vec<f64>; 3],
    /// FFT of the zero-padded taps divided by `2n` (realfft does not normalise).
    filter: [Vec<Complex<f64>>; 3],
    active: [bool; 3],
    chol: [[f64; 3]; 3],
    noise: [ChaCha8Rng; 3],
    mixture_rng: ChaCha8Rng,
    /// `sqrt(w)` per axis in the low and high state.
    sqrt_scale: [[f64; 2]; 3],
    p_high: f64,
    kurtosis: [f64; 3],
    amplitude_gain: [f64; 3],
    segment_samples: u64,
    segment_left: u64,
    current_scale: [f64; 3],
    history: [Vec<f64>; 3],
    fresh: [Vec<f64>; 3],
    work: Vec<f64>,
    spectrum: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    out: [Vec<f64>; 3],
    pos: usize,
    coherence: [[f64; 3]; 3],
}

impl std::fmt::Debug for RandomGenerator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RandomGenerator")
            .field("filter_len", &self.n)
            .field("active", &self.active)
            .field("kurtosis", &self.kurtosis)
            .field("segment_samples", &self.segment_samples)
            .finish()
    }
}

impl RandomGenerator {
    /// Designs the filters and primes the streams of run `(seed, base)` at `fs_hz`.
    pub(crate) fn new(setup: &RandomSetup, fs_hz: f64, seed: u64, base: u64) -> Result<Self> {
        let n = filter_len(fs_hz, setup.filter_resolution_hz);
        let mut planner = RealFftPlanner::<f64>::new();
        let forward = planner.plan_fft_forward(2 * n);
        let inverse = planner.plan_fft_inverse(2 * n);
        let mut taps: [Vec<f64>; 3] = Default::default();
        let mut filter: [Vec<Complex<f64>>; 3] = Default::default();
        let mut active = [false; 3];
        let mut work = forward.make_input_vec();
        let mut spectrum = forward.make_output_vec();
        let scratch_len = forward.get_scratch_len().max(inverse.get_scratch_len());
        let mut scratch = vec![Complex::default(); scratch_len];
        for axis in 0..3 {
            taps[axis] = design_taps(&setup.bands, axis, fs_hz, n, &mut planner)?;
            active[axis] = taps[axis].iter().any(|h| *h != 0.0);
            if active[axis] {
                work.fill(0.0);
                work[..n].copy_from_slice(&taps[axis]);
                forward
                    .process_with_scratch(&mut work, &mut spectrum, &mut scratch)
                    .map_err(fft_error("the random-vibration filter"))?;
                let norm = 1.0 / (2 * n) as f64;
                filter[axis] = spectrum.iter().map(|c| c * norm).collect();
            }
        }
        let segment_samples = ((setup.segment_s * fs_hz).round() as u64).max(1);
        let mut g = Self {
            n,
            forward,
            inverse,
            taps,
            filter,
            active,
            chol: cholesky3(&setup.coherence),
            noise: [
                rng(seed, base, Source::VibrationNoise(0)),
                rng(seed, base, Source::VibrationNoise(1)),
                rng(seed, base, Source::VibrationNoise(2)),
            ],
            mixture_rng: rng(seed, base, Source::Mixture),
            sqrt_scale: [[1.0; 2]; 3],
            p_high: ScaleMixture::P_HIGH,
            kurtosis: [3.0; 3],
            amplitude_gain: [1.0; 3],
            segment_samples,
            segment_left: 0,
            current_scale: [1.0; 3],
            history: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            fresh: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            work,
            spectrum,
            scratch,
            out: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            pos: n,
            coherence: setup.coherence,
        };
        g.set_kurtosis(setup.kurtosis);
        // Prime the history so that the first output sample is already stationary.
        g.draw_white();
        std::mem::swap(&mut g.history, &mut g.fresh);
        Ok(g)
    }

    /// FIR length (= overlap-save block), samples.
    pub fn filter_len(&self) -> usize {
        self.n
    }

    /// The taps of `axis` (all zero when it has no random vibration).
    pub fn taps(&self, axis: usize) -> &[f64] {
        &self.taps[axis]
    }

    /// Sets the kurtosis per axis (3..30; values below 3 give Gaussian vibration, as
    /// [`ScaleMixture::for_kurtosis`] does).
    pub fn set_kurtosis(&mut self, kurtosis: [f64; 3]) {
        self.kurtosis = kurtosis;
        for (s, k) in self.sqrt_scale.iter_mut().zip(kurtosis) {
            let m = ScaleMixture::for_kurtosis(k);
            *s = [m.scale[0].sqrt(), m.scale[1].sqrt()];
        }
    }

    /// Multiplies axis `i` by `gain[i]` (an effect rescaling the random part).
    pub fn set_amplitude_gain(&mut self, gain: [f64; 3]) {
        self.amplitude_gain = gain;
    }

    /// The covariance `K_ij` of the generated vibration, g^2: `R_ij (h_i . h_j)` times the
    /// mixture factor `E[sqrt(w_i w_j)]` and the amplitude gains (module docs).
    pub fn covariance_g2(&self) -> [[f64; 3]; 3] {
        let mut k = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                let dot: f64 = self.taps[i]
                    .iter()
                    .zip(&self.taps[j])
                    .map(|(a, b)| a * b)
                    .sum();
                let s = &self.sqrt_scale;
                let mix = (1.0 - self.p_high) * s[i][0] * s[j][0] + self.p_high * s[i][1] * s[j][1];
                k[i][j] = self.coherence[i][j]
                    * dot
                    * mix
                    * self.amplitude_gain[i]
                    * self.amplitude_gain[j];
            }
        }
        k
    }

    /// The realised variance of `axis` in `[f_lo_hz, f_hi_hz)` from the designed filter
    /// (before the mixture and gains), g^2: `(2/N) sum |H_k|^2` over the `2n`-point grid.
    pub fn design_band_variance_g2(
        &self,
        axis: usize,
        f_lo_hz: f64,
        f_hi_hz: f64,
        fs_hz: f64,
    ) -> f64 {
        if !self.active[axis] {
            return 0.0;
        }
        let big_n = 2 * self.n;
        let df = fs_hz / big_n as f64;
        let mut sum = 0.0;
        for (k, c) in self.filter[axis].iter().enumerate() {
            let f = k as f64 * df;
            if f >= f_lo_hz && f < f_hi_hz {
                // `filter` holds H_k / N.
                let h2 = c.norm_sqr() * (big_n as f64) * (big_n as f64);
                let edge = k == 0 || k == big_n / 2;
                sum += if edge { h2 } else { 2.0 * h2 };
            }
        }
        sum / big_n as f64
    }

    fn draw_white(&mut self) {
        for (noise, fresh) in self.noise.iter_mut().zip(self.fresh.iter_mut()) {
            for x in fresh.iter_mut() {
                *x = noise.sample(StandardNormal);
            }
        }
        let l = self.chol;
        let [f0, f1, f2] = &mut self.fresh;
        for ((a, b), c) in f0.iter_mut().zip(f1.iter_mut()).zip(f2.iter_mut()) {
            let w = [*a, *b, *c];
            *a = l[0][0] * w[0];
            *b = l[1][0] * w[0] + l[1][1] * w[1];
            *c = l[2][0] * w[0] + l[2][1] * w[1] + l[2][2] * w[2];
        }
    }

    fn next_block(&mut self) -> Result<()> {
        self.draw_white();
        let n = self.n;
        for axis in 0..3 {
            if !self.active[axis] {
                self.out[axis].fill(0.0);
            } else {
                self.work[..n].copy_from_slice(&self.history[axis]);
                self.work[n..].copy_from_slice(&self.fresh[axis]);
                self.forward
                    .process_with_scratch(&mut self.work, &mut self.spectrum, &mut self.scratch)
                    .map_err(fft_error("the random vibration"))?;
                for (s, h) in self.spectrum.iter_mut().zip(&self.filter[axis]) {
                    *s *= h;
                }
                // Real signals: the DC and Nyquist bins are real up to round-off.
                self.spectrum[0].im = 0.0;
                if let Some(last) = self.spectrum.last_mut() {
                    last.im = 0.0;
                }
                self.inverse
                    .process_with_scratch(&mut self.spectrum, &mut self.work, &mut self.scratch)
                    .map_err(fft_error("the random vibration"))?;
                // Overlap-save: the last n outputs hold the linear convolution.
                self.out[axis].copy_from_slice(&self.work[n..]);
            }
            std::mem::swap(&mut self.history[axis], &mut self.fresh[axis]);
        }
        self.pos = 0;
        Ok(())
    }

    /// Writes the next `dst.len()` samples (g, per axis). The sequence does not depend
    /// on how the calls split it.
    pub fn fill(&mut self, dst: &mut [[f64; 3]]) -> Result<()> {
        for d in dst.iter_mut() {
            if self.pos == self.n {
                self.next_block()?;
            }
            if self.segment_left == 0 {
                let high = self.mixture_rng.random::<f64>() < self.p_high;
                let state = usize::from(high);
                for i in 0..3 {
                    self.current_scale[i] = self.sqrt_scale[i][state] * self.amplitude_gain[i];
                }
                self.segment_left = self.segment_samples;
            }
            self.segment_left -= 1;
            let p = self.pos;
            *d = [
                self.out[0][p] * self.current_scale[0],
                self.out[1][p] * self.current_scale[1],
                self.out[2][p] * self.current_scale[2],
            ];
            self.pos += 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn band(lo: f64, hi: f64, s: [f64; 3]) -> PsdBand {
        PsdBand {
            f_lo_hz: lo,
            f_hi_hz: hi,
            psd_g2_per_hz: s,
        }
    }

    #[test]
    fn design_keeps_the_table_variance_and_band_shape() {
        let setup = RandomSetup {
            bands: vec![
                band(20.0, 40.0, [0.017, 0.0, 0.017]),
                band(40.0, 80.0, [0.020, 0.0, 0.020]),
                band(320.0, 640.0, [0.120, 0.0, 0.0]),
            ],
            coherence: [[1.0, 0.0, 0.5], [0.0, 1.0, 0.0], [0.5, 0.0, 1.0]],
            kurtosis: [3.0; 3],
            segment_s: 0.25,
            filter_resolution_hz: 1.0,
        };
        let fs = 25_600.0;
        let g = RandomGenerator::new(&setup, fs, 1, 0).unwrap();
        assert_eq!(g.filter_len(), 32_768);
        let k = g.covariance_g2();
        let v = setup.variance_g2();
        assert!((k[0][0] - v[0]).abs() < 1e-12 * v[0]);
        assert_eq!(k[1][1], 0.0);
        // Band by band, the realised filter is within 2 % of the table.
        for (lo, hi, want) in [(20.0, 40.0, 0.34), (40.0, 80.0, 0.8), (320.0, 640.0, 38.4)] {
            let got = g.design_band_variance_g2(0, lo, hi, fs);
            assert!(
                (got / want - 1.0).abs() < 0.02,
                "{lo}..{hi} Hz: {got} vs {want}"
            );
        }
        // Axis 2 has the 20..80 Hz part of axis 0's shape only: the covariance is
        // R * h0.h2, below R * sigma0 * sigma2.
        assert!(k[0][2] > 0.0 && k[0][2] < 0.5 * (v[0] * v[2]).sqrt());
        assert!((k[0][2] - 0.5 * 1.14).abs() < 0.02 * 0.57, "{}", k[0][2]);
    }

    #[test]
    fn chunking_does_not_change_the_sequence() {
        let setup = RandomSetup {
            bands: vec![band(100.0, 400.0, [1e-3, 2e-3, 3e-3])],
            coherence: [[1.0, 0.3, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 1.0]],
            kurtosis: [6.0, 6.0, 3.0],
            segment_s: 0.01,
            filter_resolution_hz: 20.0,
        };
        let mut a = RandomGenerator::new(&setup, 4096.0, 3, 0).unwrap();
        let mut b = RandomGenerator::new(&setup, 4096.0, 3, 0).unwrap();
        let mut whole = vec![[0.0; 3]; 3000];
        a.fill(&mut whole).unwrap();
        let mut parts = vec![[0.0; 3]; 3000];
        for c in parts.chunks_mut(37) {
            b.fill(c).unwrap();
        }
        assert_eq!(whole, parts);
    }

    #[test]
    fn cholesky_reproduces_semidefinite_matrices() {
        let r = [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(cholesky_residual(&r) < 1e-12);
        let bad = [[1.0, 0.9, -0.9], [0.9, 1.0, 0.9], [-0.9, 0.9, 1.0]];
        assert!(cholesky_residual(&bad) > 0.1);
    }
}
