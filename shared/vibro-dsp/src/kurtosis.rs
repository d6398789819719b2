//! Kurtosis of the band-limited broadband part.
//!
//! The tone-free residual of the window is band-limited to the broadband band by an
//! FFT mask over the whole window (with the response correction applied on the way),
//! then `kurtosis = m4 / m2^2` is taken over its samples. MODEL.md section 6 needs
//! `E[x^4]` of the vibration in the band; out-of-band content (sensor noise, the AC
//! coupling's low-frequency tail) would pull the value towards that content's own.
//!
//! The mask is circular: the window's ends meet, and the step there rings into the
//! first and last few milliseconds. For stationary broadband vibration this moves the
//! kurtosis by far less than its sampling error. Around invalid (zeroed) samples the
//! ringing is worse, so samples within one period of the band's lower edge of an
//! invalid sample are left out of the moments.
//!
//! Uncertainty: for a Gaussian process, `kurtosis - 3 ~ mean(He4(x/sigma))` and
//! `cov(He4(X), He4(Y)) = 24 rho^4`, so `var = 24 sum_tau rho(tau)^4 / N` (Isserlis'
//! theorem); `rho` comes from the Welch PSD of the band ([`crate::welch`]).
//!
//! A window without invalid samples takes a shorter road to the same moments:
//! - **No forward FFT of the residual.** The residual is the window less the fitted
//!   model (a constant and the kept tones). In the band (DC excluded) its DFT is the
//!   window's own plain DFT, which the detector takes anyway ([`crate::detect`]), less
//!   each tone's DFT in closed form. The DFT of `exp(i w (n - c))`, `c = (N - 1) / 2`,
//!   at bin `k` is `(-1)^k exp(i pi k / N) sin(N x) / sin(x)` with
//!   `x = w / 2 - pi k / N` (a geometric series). Away from the tone `sin(N x)` is
//!   `(-1)^k sin(N w / 2)`, one value per tone, and `sin(x)` comes from a table of
//!   `pi k / N`: a division per bin and tone. Within `NEAR_SIN` of a zero of `sin(x)`
//!   the ratio is the fit's Dirichlet kernel `D(2 x)` ([`crate::sinefit`]), both sines
//!   taken directly; there the shared `sin(N w / 2)`, whose argument is large, would
//!   lose digits against a small `sin(x)`.
//! - **A shorter inverse.** The band-limited signal `y` has no content above bin
//!   `hi`, so `y^4` has none above `4 hi`. The mean of a trigonometric polynomial of
//!   degree `D` over `M` equally spaced points is its constant term whenever `M > D`:
//!   the moments over `M > 4 hi` points of `y` equal those over the window's `N`
//!   (exactly, up to rounding). With the 20-2000 Hz band of a 1 s window that is an
//!   inverse FFT of 8,100 points instead of 25,600. The uncertainty still counts the
//!   window's `N` samples: they are what was measured.
//!
//! Windows with invalid samples keep the long road: their moments leave out the
//! samples near a gap, which needs the signal at every sample.

use crate::response::Response;
use crate::sinefit::{Dirichlet, FitState};
use crate::Result;
use realfft::num_complex::Complex64;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use std::f64::consts::{PI, TAU};
use std::sync::Arc;

/// `|sin(x)|` below which a tone's closed-form DFT takes both sines directly.
const NEAR_SIN: f64 = 1.0 / 64.0;

/// The clean road's inverse FFT: over the fewest `M > 4 hi` points (see the module
/// doc), or over the window's when that is not fewer.
struct BandInverse {
    ifft: Arc<dyn ComplexToReal<f64>>,
    spectrum: Vec<Complex64>,
    output: Vec<f64>,
    scratch: Vec<Complex64>,
}

pub(crate) struct Kurtosis {
    samples: usize,
    band_inverse: BandInverse,
    dirichlet: Dirichlet,
    /// `(cos, sin)(pi k / N)` over the band's bins.
    half_turn: Vec<(f64, f64)>,
    /// Per axis over the band's bins: the residual's DFT, then the tones' model.
    band: [Vec<Complex64>; 3],
    model: [Vec<Complex64>; 3],
    fft: Arc<dyn RealToComplex<f64>>,
    ifft: Arc<dyn ComplexToReal<f64>>,
    input: Vec<f64>,
    spectrum: Vec<Complex64>,
    output: Vec<f64>,
    scratch: Vec<Complex64>,
    iscratch: Vec<Complex64>,
    /// First and last bin of the band.
    bins: [usize; 2],
    /// `1/H` per axis over `bins`.
    inverse_gain: [Vec<Complex64>; 3],
    guard: usize,
}

impl Kurtosis {
    pub(crate) fn new(
        samples: usize,
        sample_rate_hz: f64,
        band_hz: [f64; 2],
        response: &Response,
        planner: &mut RealFftPlanner<f64>,
    ) -> Self {
        let fft = planner.plan_fft_forward(samples);
        let ifft = planner.plan_fft_inverse(samples);
        let df = sample_rate_hz / samples as f64;
        let last = samples / 2;
        // Bins whose centre lies in the band; DC never (the mean is not vibration).
        let lo = ((band_hz[0] / df).ceil() as usize).clamp(1, last);
        let hi = ((band_hz[1] / df).floor() as usize).clamp(lo, last);
        let inverse_gain = std::array::from_fn(|a| {
            (lo..=hi)
                .map(|k| response.inverse_gain(a, k as f64 * df))
                .collect()
        });
        let band_inverse = {
            let points = alias_free_points(hi, samples).unwrap_or(samples);
            let ifft = planner.plan_fft_inverse(points);
            BandInverse {
                spectrum: ifft.make_input_vec(),
                output: ifft.make_output_vec(),
                scratch: ifft.make_scratch_vec(),
                ifft,
            }
        };
        let half_turn = (lo..=hi)
            .map(|k| {
                let (s, c) = (PI * k as f64 / samples as f64).sin_cos();
                (c, s)
            })
            .collect();
        let width = hi - lo + 1;
        Self {
            samples,
            band_inverse,
            dirichlet: Dirichlet::new(samples),
            half_turn,
            band: std::array::from_fn(|_| vec![Complex64::new(0.0, 0.0); width]),
            model: std::array::from_fn(|_| vec![Complex64::new(0.0, 0.0); width]),
            input: fft.make_input_vec(),
            spectrum: fft.make_output_vec(),
            output: ifft.make_output_vec(),
            scratch: fft.make_scratch_vec(),
            iscratch: ifft.make_scratch_vec(),
            fft,
            ifft,
            bins: [lo, hi],
            inverse_gain,
            guard: (sample_rate_hz / band_hz[0]).ceil() as usize,
        }
    }

    /// Kurtosis per axis of a window without invalid samples, from the window's plain
    /// DFT per axis (`plain`, of the samples less any constant) and the fitted tones
    /// the residual removes (`fit`'s, those `keep` marks); each with the number of
    /// samples it stands for (the window's). Equal, up to rounding, to [`Self::run`] on
    /// the residual (see the module doc).
    pub(crate) fn run_clean(
        &mut self,
        plain: [&[Complex64]; 3],
        fit: &FitState,
        keep: &[bool],
        out: &mut [(f64, usize); 3],
    ) -> Result<()> {
        let n = self.samples;
        let [lo, hi] = self.bins;
        self.tone_model(fit, keep);
        for a in 0..3 {
            let band = &mut self.band[a];
            for (j, b) in band.iter_mut().enumerate() {
                let (c, s) = self.half_turn[j];
                let m = self.model[a][j];
                // exp(i pi k / N) times the tones' sum; (-1)^k is in the model.
                let tone = Complex64::new(c * m.re - s * m.im, c * m.im + s * m.re);
                *b = (plain[a][lo + j] - tone) * self.inverse_gain[a][j];
            }
            let inverse = &mut self.band_inverse;
            inverse.spectrum.fill(Complex64::new(0.0, 0.0));
            inverse.spectrum[lo..=hi].copy_from_slice(band);
            inverse.ifft.process_with_scratch(
                &mut inverse.spectrum,
                &mut inverse.output,
                &mut inverse.scratch,
            )?;
            out[a] = (kurtosis_of(&inverse.output), n);
        }
        Ok(())
    }

    /// `self.model[a][j]`: the DFT of the kept tones on axis `a` at band bin `lo + j`,
    /// divided by `exp(i pi k / N)`.
    fn tone_model(&mut self, fit: &FitState, keep: &[bool]) {
        for m in &mut self.model {
            m.fill(Complex64::new(0.0, 0.0));
        }
        let n = self.samples as f64;
        let lo = self.bins[0];
        let dirichlet = self.dirichlet;
        // `(-1)^k D(2 x)` with both sines taken directly (Taylor's series at x ~ 0).
        let near = |half: f64, k: usize| {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            sign * dirichlet.value(2.0 * half - TAU * k as f64 / n)
        };
        let kept = (0..fit.tones).filter(|&i| keep.get(i).copied().unwrap_or(false));
        for i in kept {
            let half = 0.5 * fit.omega[i];
            let (sh, ch) = half.sin_cos();
            // sin(N x) away from the zeros, times (-1)^k: the same for every bin.
            let far_num = (n * half).sin();
            let amp = fit.amplitudes(i).map(|(ca, cb)| (0.5 * ca, 0.5 * cb));
            for (j, &(c, s)) in self.half_turn.iter().enumerate() {
                let k = lo + j;
                // x = +-w/2 - pi k / N for the tone's two phasors.
                let den_plus = sh * c - ch * s;
                let den_minus = -sh * c - ch * s;
                let plus = if den_plus.abs() >= NEAR_SIN {
                    far_num / den_plus
                } else {
                    near(half, k)
                };
                let minus = if den_minus.abs() >= NEAR_SIN {
                    -far_num / den_minus
                } else {
                    near(-half, k)
                };
                let (sum, diff) = (plus + minus, minus - plus);
                for (m, &(ca2, cb2)) in self.model.iter_mut().zip(&amp) {
                    m[j].re += ca2 * sum;
                    m[j].im += cb2 * diff;
                }
            }
        }
    }

    /// Kurtosis of `residual` (the tone-free window of `axis`, invalid samples zeroed)
    /// band-limited, and the number of samples it was taken over. `invalid_prefix[k]`
    /// counts the invalid samples before `k`. NaN if fewer than a quarter of the window
    /// is usable or the band holds no power.
    pub(crate) fn run(
        &mut self,
        axis: usize,
        residual: &[f64],
        invalid_prefix: &[u32],
    ) -> Result<(f64, usize)> {
        let n = self.samples;
        self.input.copy_from_slice(&residual[..n]);
        self.fft
            .process_with_scratch(&mut self.input, &mut self.spectrum, &mut self.scratch)?;
        let [lo, hi] = self.bins;
        for (k, c) in self.spectrum.iter_mut().enumerate() {
            if k < lo || k > hi {
                *c = Complex64::new(0.0, 0.0);
            } else {
                *c *= self.inverse_gain[axis][k - lo];
            }
        }
        // A real signal's DC and Nyquist bins are real; the mask keeps them so.
        let last = self.spectrum.len() - 1;
        self.spectrum[0].im = 0.0;
        if n % 2 == 0 {
            self.spectrum[last].im = 0.0;
        }
        self.ifft
            .process_with_scratch(&mut self.spectrum, &mut self.output, &mut self.iscratch)?;

        if invalid_prefix[n] == 0 {
            return Ok((kurtosis_of(&self.output[..n]), n));
        }
        let g = self.guard;
        let usable =
            |k: usize| invalid_prefix[(k + g + 1).min(n)] == invalid_prefix[k.saturating_sub(g)];
        let (mut count, mut sum) = (0usize, 0.0);
        for (k, y) in self.output.iter().enumerate() {
            if usable(k) {
                count += 1;
                sum += y;
            }
        }
        if count < n / 4 || count == 0 {
            return Ok((f64::NAN, count));
        }
        let mean = sum / count as f64;
        let (mut m2, mut m4) = (0.0, 0.0);
        for (k, y) in self.output.iter().enumerate() {
            if usable(k) {
                let d = y - mean;
                let d2 = d * d;
                m2 += d2;
                m4 += d2 * d2;
            }
        }
        m2 /= count as f64;
        m4 /= count as f64;
        if m2 <= 0.0 || !m2.is_finite() {
            return Ok((f64::NAN, count));
        }
        Ok((m4 / (m2 * m2), count))
    }
}

/// The fewest points `M` (even and 5-smooth, for a fast FFT) with `M > 4 top`, if fewer
/// than `samples`: over `M` equally spaced points, the mean of the fourth power of a
/// signal with no content above bin `top` is its mean over any finer grid (see the
/// module doc). Used here and for the Welch autocorrelation's `sum rho^4`.
pub(crate) fn alias_free_points(top: usize, samples: usize) -> Option<usize> {
    let smooth = |mut m: usize| {
        for p in [2, 3, 5] {
            while m % p == 0 {
                m /= p;
            }
        }
        m == 1
    };
    let mut m = 4 * top + 1;
    while m < samples {
        if m % 2 == 0 && smooth(m) {
            return Some(m);
        }
        m += 1;
    }
    None
}

/// `m4 / m2^2` of `y` about its mean; NaN without power.
fn kurtosis_of(y: &[f64]) -> f64 {
    let count = y.len() as f64;
    let mean = crate::sums::sum(y) / count;
    let (m2, m4) = crate::sums::central_2_4(y, mean);
    let (m2, m4) = (m2 / count, m4 / count);
    if m2 <= 0.0 || !m2.is_finite() {
        return f64::NAN;
    }
    m4 / (m2 * m2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The short road (plain DFT less the tones in closed form, the shorter inverse)
    /// against the long one (the residual taken sample by sample, FFT and inverse over
    /// the window), with tones on a bin, half a bin off, a hair off, below the band,
    /// at its top and near Nyquist; with the shorter inverse and without it.
    #[test]
    fn the_short_road_gives_the_residuals_kurtosis() {
        let cases: [(usize, f64, [f64; 2]); 3] = [
            (25_600, 25_600.0, [20.0, 2000.0]),
            (4_999, 5_000.0, [20.0, 2000.0]),
            (10_000, 12_345.0, [10.0, 600.0]),
        ];
        for (n, fs_hz, band_hz) in cases {
            let response = Response::new(Some(5.0), &[]);
            let mut planner = RealFftPlanner::<f64>::new();
            let mut k = Kurtosis::new(n, fs_hz, band_hz, &response, &mut planner);
            let short = k.band_inverse.output.len() < n;
            let df = fs_hz / n as f64;
            let top = (band_hz[1] / df).floor();
            assert_eq!(short, n > 4 * top as usize + 1, "n {n}");
            let tone_bins = [
                vec![],
                vec![200.0],
                vec![200.5],
                vec![200.0 + 1e-9, 8.3],
                vec![top, top - 0.25, n as f64 / 2.0 - 0.3],
                vec![3.0, 51.7, 120.0, 333.25],
            ];
            for (case, bins) in tone_bins.iter().enumerate() {
                // Every other slot a tone the residual keeps, the rest dropped.
                let mut fit = FitState {
                    tones: 2 * bins.len(),
                    ..FitState::default()
                };
                let mut keep = vec![false; fit.tones];
                for (i, b) in bins.iter().enumerate() {
                    let slot = 2 * i + 1;
                    keep[slot] = true;
                    fit.omega[slot] = TAU * b / n as f64;
                    fit.omega[slot - 1] = TAU * (b + 37.0) / n as f64;
                    for a in 0..3 {
                        fit.lin[a][1 + 2 * slot] = 0.7 + 0.3 * (a + i) as f64;
                        fit.lin[a][2 + 2 * slot] = -0.4 + 0.5 * a as f64;
                        fit.lin[a][1 + 2 * (slot - 1)] = 5.0;
                    }
                }
                let kept: Vec<usize> = (0..fit.tones).filter(|&i| keep[i]).collect();
                let mut state = 0x2545_f491_4f6c_dd1du64 ^ (n * 31 + case) as u64;
                let mut uniform = || crate::test_rng::uniform(&mut state) - 0.5;
                let centre = (n as f64 - 1.0) / 2.0;
                let mut residual: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; n]);
                let mut plain: [Vec<Complex64>; 3] = std::array::from_fn(|_| Vec::new());
                for a in 0..3 {
                    // Non-Gaussian noise (a sum of two uniforms, cubed in part).
                    let noise: Vec<f64> = (0..n)
                        .map(|_| {
                            let u = uniform() + uniform();
                            u + 2.0 * u * u * u
                        })
                        .collect();
                    let x: Vec<f64> = (0..n)
                        .map(|s| {
                            let t = s as f64 - centre;
                            let tone: f64 = kept
                                .iter()
                                .map(|&i| {
                                    let (ca, cb) = fit.amplitudes(i)[a];
                                    let w = fit.omega[i];
                                    ca * (w * t).cos() + cb * (w * t).sin()
                                })
                                .sum();
                            0.25 + noise[s] + tone
                        })
                        .collect();
                    residual[a] = (0..n).map(|s| noise[s]).collect();
                    let mean = x.iter().sum::<f64>() / n as f64;
                    let fft = planner.plan_fft_forward(n);
                    let mut input: Vec<f64> = x.iter().map(|v| v - mean).collect();
                    plain[a] = fft.make_output_vec();
                    fft.process(&mut input, &mut plain[a]).unwrap();
                }
                let prefix = vec![0u32; n + 1];
                let mut got = [(0.0, 0); 3];
                let plain_ref = std::array::from_fn(|a| &plain[a][..]);
                k.run_clean(plain_ref, &fit, &keep, &mut got).unwrap();
                for (a, r) in residual.iter().enumerate() {
                    let want = k.run(a, r, &prefix).unwrap();
                    assert_eq!(got[a].1, n);
                    assert!(
                        (got[a].0 - want.0).abs() <= 1e-12 * want.0,
                        "n {n} tones {bins:?} axis {a}: {} vs {}",
                        got[a].0,
                        want.0
                    );
                }
            }
        }
    }

    /// The shortest inverse is the first even 5-smooth length above `4 hi`, and none
    /// when that is not below the window.
    #[test]
    fn alias_free_points_are_the_first_fast_length_above_four_times_the_band() {
        assert_eq!(alias_free_points(2000, 25_600), Some(8_100));
        assert_eq!(alias_free_points(2048, 25_600), Some(8_640));
        assert_eq!(alias_free_points(1999, 5_000), None);
        assert_eq!(alias_free_points(6_400, 25_600), None);
        assert_eq!(alias_free_points(1, 100), Some(6));
    }
}
