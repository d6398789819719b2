//! Welch averaging [Welch 1967, IEEE Trans. AU-15(2) 70-73] of the auto- and
//! cross-spectra of the three axes over one window, band integration, and the
//! statistical uncertainty of the band powers.
//!
//! Segments: periodic Hann, 50% overlap, mean removed per segment, one-sided density
//! scaling: the conventions of `scipy.signal.welch` / `csd` with their defaults
//! (`window="hann"`, `noverlap=nperseg//2`, `detrend="constant"`), so that the two can
//! be compared bin for bin. Segments holding an invalid sample are skipped.
//!
//! Band integration: bin `k` stands for `[k df - df/2, k df + df/2]`; a band
//! `[lo, hi]` takes each bin with the fraction of that interval it covers, so the
//! integrated width is exactly `hi - lo` whatever the grid.
//!
//! Only the bins that the bands asked for at construction touch are averaged and
//! scaled (the estimator's bands end at 2 kHz: 501 of a 0.25 s segment's 3,201 bins).
//!
//! `sum rho^4` takes its inverse FFT over the fewest points `M > 4 top` (`top` the last
//! bin averaged): the mean of `rho^4` over them is its mean over the segment's points
//! (see [`crate::kurtosis`]), so the sum over the segment is `segment / M` times theirs.
//!
//! Uncertainty: for Gaussian data a Welch bin estimate has relative variance `1/K_eff`
//! with `K_eff = K / (1 + 2 sum_j (1 - j/K) c_j^2)` and `c_j` the window's overlap
//! correlation (Welch 1967, eq. 9; Hann at 50%: c_1 = 1/6, Harris 1978 Table 1);
//! neighbouring bins of one segment are correlated through the window by
//! `rho_d = |sum w^2 e^(-2 pi i d n/M)|^2 / (sum w^2)^2` (Hann: 4/9, 1/36, 0 for
//! d = 1, 2, 3), which the band-power variance sums over.

use crate::response::Response;
use crate::Result;
use realfft::num_complex::Complex64;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use std::f64::consts::PI;
use std::sync::Arc;

/// Axis pairs of the three cross-spectra.
pub(crate) const PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];
/// Bin-to-bin correlations kept in the band-power variance (beyond this they are < 1e-3
/// for the windows in use).
const CORRELATED_BINS: usize = 3;

/// Integrated power in one band.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct BandPower {
    /// Per axis, g^2.
    pub(crate) auto_g2: [f64; 3],
    /// Real part of the cross power of `PAIRS`, g^2.
    pub(crate) cross_g2: [f64; 3],
    /// Variance of `auto_g2`, g^4.
    pub(crate) auto_var_g4: [f64; 3],
}

pub(crate) struct Welch {
    segment: usize,
    hop: usize,
    sample_rate_hz: f64,
    fft: Arc<dyn RealToComplex<f64>>,
    input: Vec<f64>,
    scratch: Vec<Complex64>,
    window: Vec<f64>,
    window_sq_sum: f64,
    spectrum: [Vec<Complex64>; 3],
    /// Response-corrected one-sided PSD (g^2/Hz) after `run`.
    auto: [Vec<f64>; 3],
    /// Response-corrected one-sided CSD of `PAIRS` (g^2/Hz) after `run`.
    cross: [Vec<Complex64>; 3],
    inverse_gain: [Vec<Complex64>; 3],
    bin_rho: [f64; CORRELATED_BINS],
    overlap_c2: Vec<f64>,
    segments: usize,
    /// The bins averaged: those touching any of the bands given to `new`.
    first_bin: usize,
    end_bin: usize,
    ifft: Arc<dyn ComplexToReal<f64>>,
    acf_spectrum: Vec<Complex64>,
    acf: Vec<f64>,
    iscratch: Vec<Complex64>,
}

impl Welch {
    /// Welch averaging over segments of `segment` samples, for the bands `bands_hz`
    /// (the only ones [`Self::band_power`] and [`Self::rho4_sum`] may be asked for).
    pub(crate) fn new(
        segment: usize,
        sample_rate_hz: f64,
        response: &Response,
        bands_hz: &[[f64; 2]],
        planner: &mut RealFftPlanner<f64>,
    ) -> Self {
        let fft = planner.plan_fft_forward(segment);
        let df = sample_rate_hz / segment as f64;
        let bins = segment / 2 + 1;
        let (first_bin, end_bin) = bands_hz
            .iter()
            .map(|&[lo, hi]| band_bins(df, bins - 1, lo, hi))
            .fold((bins, 0), |(f, e), r| (f.min(*r.start()), e.max(*r.end())));
        let acf_points = crate::kurtosis::alias_free_points(end_bin, segment).unwrap_or(segment);
        let ifft = planner.plan_fft_inverse(acf_points);
        let window = periodic_hann(segment);
        let window_sq_sum: f64 = window.iter().map(|w| w * w).sum();
        let hop = segment - segment / 2;
        let bin_rho = std::array::from_fn(|d| {
            let (mut re, mut im) = (0.0, 0.0);
            for (n, w) in window.iter().enumerate() {
                let ph = 2.0 * PI * (d * n) as f64 / segment as f64;
                re += w * w * ph.cos();
                im -= w * w * ph.sin();
            }
            (re * re + im * im) / (window_sq_sum * window_sq_sum)
        });
        let overlap_c2 = (1..)
            .map(|j| j * hop)
            .take_while(|shift| *shift < segment)
            .map(|shift| {
                let c: f64 = (0..segment - shift)
                    .map(|n| window[n] * window[n + shift])
                    .sum();
                (c / window_sq_sum).powi(2)
            })
            .collect();
        let inverse_gain = std::array::from_fn(|a| {
            (0..bins)
                .map(|k| response.inverse_gain(a, k as f64 * df))
                .collect()
        });
        Self {
            first_bin,
            end_bin,
            segment,
            hop,
            sample_rate_hz,
            input: fft.make_input_vec(),
            scratch: fft.make_scratch_vec(),
            spectrum: std::array::from_fn(|_| fft.make_output_vec()),
            fft,
            window,
            window_sq_sum,
            auto: std::array::from_fn(|_| vec![0.0; bins]),
            cross: std::array::from_fn(|_| vec![Complex64::new(0.0, 0.0); bins]),
            inverse_gain,
            bin_rho,
            overlap_c2,
            segments: 0,
            acf_spectrum: ifft.make_input_vec(),
            acf: ifft.make_output_vec(),
            iscratch: ifft.make_scratch_vec(),
            ifft,
        }
    }

    /// Averages the segments of `x[..samples]` that hold no invalid sample
    /// (`invalid_prefix[k]` counts the invalid samples before `k`); returns how many.
    pub(crate) fn run(
        &mut self,
        x: [&[f64]; 3],
        samples: usize,
        invalid_prefix: &[u32],
    ) -> Result<usize> {
        for a in 0..3 {
            self.auto[a].fill(0.0);
            self.cross[a].fill(Complex64::new(0.0, 0.0));
        }
        self.segments = 0;
        let m = self.segment;
        let mut start = 0;
        while start + m <= samples {
            if invalid_prefix[start + m] != invalid_prefix[start] {
                start += self.hop;
                continue;
            }
            for a in 0..3 {
                let seg = &x[a][start..start + m];
                let mean = crate::sums::sum(seg) / m as f64;
                for ((inp, v), w) in self.input.iter_mut().zip(seg).zip(&self.window) {
                    *inp = (v - mean) * w;
                }
                self.fft.process_with_scratch(
                    &mut self.input,
                    &mut self.spectrum[a],
                    &mut self.scratch,
                )?;
                let bins = self.first_bin..=self.end_bin;
                for (p, c) in self.auto[a][bins.clone()]
                    .iter_mut()
                    .zip(&self.spectrum[a][bins])
                {
                    *p += c.norm_sqr();
                }
            }
            for (p, &(i, j)) in PAIRS.iter().enumerate() {
                let bins = self.first_bin..=self.end_bin;
                for ((acc, xi), xj) in self.cross[p][bins.clone()]
                    .iter_mut()
                    .zip(&self.spectrum[i][bins.clone()])
                    .zip(&self.spectrum[j][bins])
                {
                    *acc += xi * xj.conj();
                }
            }
            self.segments += 1;
            start += self.hop;
        }
        if self.segments == 0 {
            return Ok(0);
        }
        let base = 1.0 / (self.sample_rate_hz * self.window_sq_sum * self.segments as f64);
        let last = self.auto[0].len() - 1;
        let nyquist_is_a_bin = m % 2 == 0;
        for k in self.first_bin..=self.end_bin {
            // One-sided: every bin but DC (and Nyquist, for an even segment) doubled.
            let one_sided = if k == 0 || (k == last && nyquist_is_a_bin) {
                1.0
            } else {
                2.0
            };
            let s = base * one_sided;
            let h: [Complex64; 3] = std::array::from_fn(|a| self.inverse_gain[a][k]);
            for a in 0..3 {
                self.auto[a][k] *= s * h[a].norm_sqr();
            }
            for (p, &(i, j)) in PAIRS.iter().enumerate() {
                self.cross[p][k] *= s * h[i] * h[j].conj();
            }
        }
        Ok(self.segments)
    }

    /// Bin width.
    fn df_hz(&self) -> f64 {
        self.sample_rate_hz / self.segment as f64
    }

    /// Fraction of bin `k`'s interval `[k df - df/2, k df + df/2]` inside `[lo, hi]`.
    fn bin_weight(&self, k: usize, lo_hz: f64, hi_hz: f64) -> f64 {
        let df = self.df_hz();
        let centre = k as f64 * df;
        ((hi_hz.min(centre + df / 2.0) - lo_hz.max(centre - df / 2.0)) / df).clamp(0.0, 1.0)
    }

    /// Bins that touch `[lo, hi]`.
    fn band_range(&self, lo_hz: f64, hi_hz: f64) -> std::ops::RangeInclusive<usize> {
        let range = band_bins(self.df_hz(), self.auto[0].len() - 1, lo_hz, hi_hz);
        debug_assert!(
            range.is_empty() || (*range.start() >= self.first_bin && *range.end() <= self.end_bin),
            "band [{lo_hz}, {hi_hz}] Hz was not given to Welch::new"
        );
        range
    }

    /// Integrated power in `[lo, hi]` with its variance (see the module docs).
    pub(crate) fn band_power(&self, lo_hz: f64, hi_hz: f64) -> BandPower {
        let df = self.df_hz();
        let range = self.band_range(lo_hz, hi_hz);
        let end = *range.end();
        let k_eff = self.effective_averages();
        let mut out = BandPower::default();
        for k in range {
            let wk = self.bin_weight(k, lo_hz, hi_hz);
            if wk <= 0.0 {
                continue;
            }
            for a in 0..3 {
                out.auto_g2[a] += wk * self.auto[a][k] * df;
                // Covariance with this bin and the next correlated ones (both sides).
                for d in 0..CORRELATED_BINS {
                    let l = k + d;
                    if l > end {
                        break;
                    }
                    let wl = self.bin_weight(l, lo_hz, hi_hz);
                    let both_sides = if d == 0 { 1.0 } else { 2.0 };
                    out.auto_var_g4[a] +=
                        both_sides * wk * wl * self.auto[a][k] * self.auto[a][l] * self.bin_rho[d];
                }
            }
            for p in 0..3 {
                out.cross_g2[p] += wk * self.cross[p][k].re * df;
            }
        }
        for v in out.auto_var_g4.iter_mut() {
            *v *= df * df / k_eff;
        }
        out
    }

    /// `K_eff` of the module docs, for the segments averaged in the last `run`.
    fn effective_averages(&self) -> f64 {
        let k = self.segments as f64;
        let spread: f64 = self
            .overlap_c2
            .iter()
            .enumerate()
            .map(|(j, c2)| (1.0 - (j + 1) as f64 / k).max(0.0) * c2)
            .sum();
        k / (1.0 + 2.0 * spread)
    }

    /// `sum_tau rho(tau)^4` of the band-limited process of `axis`, with `rho` the
    /// autocorrelation coefficient from the Welch PSD restricted to `[lo, hi]`
    /// (inverse FFT of the PSD; Wiener-Khinchin). NaN if there is no power.
    pub(crate) fn rho4_sum(&mut self, axis: usize, lo_hz: f64, hi_hz: f64) -> Result<f64> {
        self.acf_spectrum.fill(Complex64::new(0.0, 0.0));
        let df = self.df_hz();
        let last = self.auto[axis].len() - 1;
        let range = self.band_range(lo_hz, hi_hz);
        for k in range {
            let f = k as f64 * df;
            if f >= lo_hz && f <= hi_hz && k != 0 && !(k == last && self.segment % 2 == 0) {
                self.acf_spectrum[k] = Complex64::new(self.auto[axis][k], 0.0);
            }
        }
        self.ifft.process_with_scratch(
            &mut self.acf_spectrum,
            &mut self.acf,
            &mut self.iscratch,
        )?;
        let r0 = self.acf[0];
        if r0 <= 0.0 || !r0.is_finite() {
            return Ok(f64::NAN);
        }
        let points = self.acf.len();
        let sum: f64 = self.acf.iter().map(|r| (r / r0).powi(4)).sum();
        Ok(sum * (self.segment as f64 / points as f64))
    }

    /// Response-corrected one-sided PSD of `axis` after `run`.
    #[cfg(test)]
    pub(crate) fn psd(&self, axis: usize) -> &[f64] {
        &self.auto[axis]
    }
}

/// Bins (of width `df`, up to `last`) that touch `[lo, hi]`.
fn band_bins(df: f64, last: usize, lo_hz: f64, hi_hz: f64) -> std::ops::RangeInclusive<usize> {
    let first = ((lo_hz / df - 0.5).floor().max(0.0) as usize).min(last);
    let end = ((hi_hz / df + 0.5).ceil().max(0.0) as usize).min(last);
    first..=end
}

/// The periodic (DFT-even) Hann window of `samples` points: `0.5 - 0.5 cos(2 pi k / N)`.
/// Both the tone detector (Grandke's interpolation assumes this form) and the Welch
/// segments (scipy's `get_window('hann')` default) use it.
pub(crate) fn periodic_hann(samples: usize) -> Vec<f64> {
    (0..samples)
        .map(|k| 0.5 - 0.5 * (2.0 * PI * k as f64 / samples as f64).cos())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hann_overlap_and_bin_correlations_have_their_textbook_values() {
        let mut planner = RealFftPlanner::new();
        let w = Welch::new(
            1024,
            1024.0,
            &Response::new(None, &[]),
            &[[0.0, 512.0]],
            &mut planner,
        );
        assert!((w.bin_rho[0] - 1.0).abs() < 1e-12);
        assert!((w.bin_rho[1] - 4.0 / 9.0).abs() < 1e-12);
        assert!((w.bin_rho[2] - 1.0 / 36.0).abs() < 1e-12);
        assert_eq!(w.overlap_c2.len(), 1);
        // Harris 1978, Table 1: Hann overlap correlation 16.7% at 50%.
        assert!((w.overlap_c2[0] - 1.0 / 36.0).abs() < 1e-12);
    }

    /// `sum rho^4` over the fewer alias-free points against the sum over every lag of
    /// the segment, the autocorrelation summed from the PSD's cosines directly.
    #[test]
    fn rho4_sum_over_fewer_points_is_the_sum_over_every_lag() {
        for (segment, fs, band) in [
            (6400usize, 25_600.0, [20.0, 2000.0]),
            (1000, 1000.0, [10.0, 60.0]),
            (64, 1000.0, [10.0, 400.0]),
        ] {
            let n = 4 * segment;
            let mut state = 0x3c6e_f372_fe94_f82bu64 ^ segment as u64;
            let x: Vec<f64> = (0..n)
                .map(|k| crate::test_rng::uniform(&mut state) - 0.5 + (0.05 * k as f64).sin())
                .collect();
            let prefix = vec![0; n + 1];
            let mut planner = RealFftPlanner::new();
            let mut w = Welch::new(
                segment,
                fs,
                &Response::new(None, &[]),
                &[band],
                &mut planner,
            );
            let fewer = w.acf.len();
            assert_eq!(fewer < segment, segment != 64, "{segment}: {fewer}");
            w.run([&x, &x, &x], n, &prefix).unwrap();
            let got = w.rho4_sum(0, band[0], band[1]).unwrap();
            let df = fs / segment as f64;
            let bins: Vec<usize> = (1..segment / 2)
                .filter(|&k| k as f64 * df >= band[0] && k as f64 * df <= band[1])
                .collect();
            let r = |tau: usize| -> f64 {
                bins.iter()
                    .map(|&k| {
                        let ph = 2.0 * PI * ((k * tau) % segment) as f64 / segment as f64;
                        w.psd(0)[k] * ph.cos()
                    })
                    .sum()
            };
            let r0 = r(0);
            let want: f64 = (0..segment).map(|tau| (r(tau) / r0).powi(4)).sum();
            assert!(
                (got - want).abs() < 1e-12 * want,
                "{segment}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn band_weights_cover_exactly_the_band_width() {
        let mut planner = RealFftPlanner::new();
        let w = Welch::new(
            100,
            400.0,
            &Response::new(None, &[]),
            &[[21.0, 39.5]],
            &mut planner,
        );
        // df = 4 Hz; [21, 39.5] covers 18.5 Hz of bins.
        let width: f64 = w
            .band_range(21.0, 39.5)
            .map(|k| w.bin_weight(k, 21.0, 39.5) * 4.0)
            .sum();
        assert!((width - 18.5).abs() < 1e-12, "{width}");
    }

    #[test]
    fn sine_power_lands_in_its_band_by_parseval() {
        let fs = 1000.0;
        let n = 4000;
        let x: Vec<f64> = (0..n)
            .map(|k| 2.0 * (2.0 * PI * 101.3 * k as f64 / fs).sin())
            .collect();
        let zero = vec![0.0; n];
        let prefix = vec![0; n + 1];
        let mut planner = RealFftPlanner::new();
        let mut w = Welch::new(
            500,
            fs,
            &Response::new(None, &[]),
            &[[80.0, 120.0]],
            &mut planner,
        );
        assert_eq!(w.run([&x, &zero, &zero], n, &prefix).unwrap(), 15);
        let p = w.band_power(80.0, 120.0);
        // A sine of amplitude 2 has power 2 g^2.
        assert!((p.auto_g2[0] - 2.0).abs() < 2e-3, "{}", p.auto_g2[0]);
        assert!(w.psd(1).iter().all(|v| *v == 0.0));
    }
}
