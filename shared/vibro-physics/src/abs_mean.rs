//! The exact mean `E|m + v|` of the asymmetry term (MODEL.md section 6), where `v` is
//! the vibration along the input axis: independent tones (uniform random phases) plus
//! broadband random vibration.
//!
//! - One tone alone: the closed form `E|m + A sin| = (2/pi)(m asin(m/A) + sqrt(A^2 - m^2))`
//!   for `|m| < A`, `|m|` otherwise (MODEL.md section 6).
//! - Random alone: the folded-normal mean
//!   `E|mu + x| = sigma sqrt(2/pi) exp(-mu^2/(2 sigma^2)) + mu (1 - 2 Phi(-mu/sigma))`,
//!   or a mixture of two such terms for non-Gaussian vibration ([`ScaleMixture`]).
//! - One tone and random vibration, for a one-shot evaluation ([`AbsMean::set_direct`],
//!   used by [`crate::exact::exact_ve`]): the folded-normal mean averaged over the
//!   tone's phase, `E|m + v| = (1/N) sum_k F(m + A sin(theta_k))` at `N` equally
//!   spaced phases. The integrand is periodic and analytic in `theta` (the Gaussian
//!   smooths the fold), so this trapezoid rule converges geometrically; `N` grows
//!   with `A/sigma` (the fold's sharpness on the tone's scale), and past
//!   [`MAX_DIRECT_POINTS`] the table below is used instead. No table is built: a
//!   one-shot evaluation costs a few microseconds instead of a convolution, but each
//!   `eval` costs `N` folded-normal means, so the compensation kernel keeps the table.
//! - Anything else: the distribution of `v` is built on a grid of 2048 points by
//!   convolving the exact bin probabilities of each component (FFT, allocated once),
//!   and `E|m + v| = sum_i p_i |m + u_i|` is read in O(1) from prefix sums. The result
//!   is exact for the binned distribution and piecewise linear in `m`; its error from
//!   binning is below `p_bin * h / 2` (about 1e-4 of the vibration amplitude), far
//!   below what the `d1A` term can show (MODEL.md's `d1A` is 15..25 ppm).
//!
//!   The random component's bins are not evaluated one by one when they are wider
//!   than half a bin (`sigma >= h/2`): their DFT has a closed form. The bin
//!   probabilities are the Gaussian convolved with the unit-area box of width `h`,
//!   sampled every `h`, so by Poisson's summation their DFT at bin `k` of `N` is
//!   `P_k = sum_m exp(-2 s^2 (t + pi m)^2) (-1)^m sin(t) / (t + pi m)`, with
//!   `t = pi k / N` and `s = sigma / h` (the Gaussian's characteristic function times
//!   the box's `sinc`, over the aliases `m`). Aliases whose Gaussian factor stays
//!   below `e^-40` are left out. It replaces about 4,000 `erfc` calls and a forward
//!   FFT per update by a few hundred `exp` calls; the two agree to rounding
//!   (`closed_form_spectrum_matches_the_bins_cdf`). Narrower components (a tone's
//!   fold sharper than half a bin) keep the bins' CDF, which then needs few bins.
//!
//! [`AbsMean::eval`] also returns the slope `dE|m + v|/dm = P(v > -m) - P(v < -m)`,
//! which the exact compensation uses for its Newton steps.

use crate::{Error, Result};
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use std::f64::consts::{FRAC_2_PI, PI, SQRT_2};
use std::sync::Arc;

/// Grid size of the convolution table.
const TABLE_POINTS: usize = 2048;
/// Index of `u = 0` on the grid.
const CENTRE: usize = TABLE_POINTS / 2;
/// Half-width of the support in bins, leaving a margin below `CENTRE`.
const HALF_WIDTH_BINS: f64 = 1016.0;
/// Gaussian components are cut at this many standard deviations (tail mass ~1e-17).
const GAUSS_CUT_SIGMAS: f64 = 8.5;
/// Smallest `sigma / h` whose bins are taken through their DFT's closed form (module
/// doc); below it, the bins' CDF.
const SPECTRAL_MIN_SIGMA_BINS: f64 = 0.5;
/// Aliases of the closed-form DFT are summed while their Gaussian factor can exceed
/// `e^-ALIAS_EXPONENT` (4e-18 of the DC term, which is 1).
const ALIAS_EXPONENT: f64 = 40.0;
/// Below `e^-745` an `f64` exponential is 0.
const EXP_UNDERFLOW: f64 = 745.0;
/// Phases of the direct tone-and-random average per unit of `A / sigma` (at least one
/// unit): 64 points per unit keep the trapezoid rule's error at rounding level, below
/// 1e-12 of the scale (`direct_phase_average_converges`).
const DIRECT_POINTS_PER_RATIO: f64 = 64.0;
/// Most phases of the direct average; sharper folds use the table.
pub const MAX_DIRECT_POINTS: usize = 4096;

/// Standard normal CDF `Phi(x)`.
#[inline]
pub fn normal_cdf(x: f64) -> f64 {
    0.5 * libm::erfc(-x / SQRT_2)
}

/// `E|m + A sin(theta)|` for theta uniform (MODEL.md section 6), and its slope in `m`.
#[inline]
pub fn sine_abs_mean(m: f64, a: f64) -> (f64, f64) {
    let a = a.abs();
    if m.abs() >= a {
        return (m.abs(), m.signum());
    }
    let r = m / a;
    let asin = r.asin();
    (
        FRAC_2_PI * (m * asin + (a * a - m * m).sqrt()),
        FRAC_2_PI * asin,
    )
}

/// Folded-normal mean `E|mu + x|`, `x ~ N(0, sigma^2)` (MODEL.md section 6), and its
/// slope `1 - 2 Phi(-mu/sigma)`.
#[inline]
pub fn folded_normal_mean(mu: f64, sigma: f64) -> (f64, f64) {
    if sigma <= 0.0 {
        return (mu.abs(), mu.signum());
    }
    let z = mu / sigma;
    let slope = 1.0 - 2.0 * normal_cdf(-z);
    let value = sigma * (2.0 / PI).sqrt() * (-0.5 * z * z).exp() + mu * slope;
    (value, slope)
}

/// `E|m + A sin(theta) + x|` and its slope, `x` the mixture of `prob` and `sigma_g`, by
/// the trapezoid rule over `points` phases (module doc).
fn sine_random_abs_mean(
    m: f64,
    amplitude_g: f64,
    sigma_g: [f64; 2],
    prob: [f64; 2],
    points: usize,
) -> (f64, f64) {
    let (mut value, mut slope) = (0.0, 0.0);
    let step = 2.0 * PI / points as f64;
    for k in 0..points {
        let mu = m + amplitude_g * ((k as f64 + 0.5) * step).sin();
        for (sigma, p) in sigma_g.into_iter().zip(prob) {
            if p > 0.0 {
                let (v, s) = folded_normal_mean(mu, sigma);
                value += p * v;
                slope += p * s;
            }
        }
    }
    (value / points as f64, slope / points as f64)
}

/// The non-Gaussian random vibration of the project: a Gaussian scale mixture
/// `x = sqrt(w) * sigma * z`, `w` taking two values, which has the requested kurtosis
/// `E[x^4]/sigma^4 = 3 E[w^2]` and the same variance (`E[w] = 1`). The larger scale is
/// taken with probability [`ScaleMixture::P_HIGH`]: bursts of stronger vibration, as in
/// a flight with transients. The simulator draws from the same family, so its mean
/// output and the exact model agree. Kurtosis below 3 (sub-Gaussian) has no scale
/// mixture: the family is then Gaussian, and only the fourth-moment terms of the
/// model see the kurtosis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaleMixture {
    /// The two variance scales `w`.
    pub scale: [f64; 2],
    /// Their probabilities.
    pub prob: [f64; 2],
}

impl ScaleMixture {
    /// Probability of the high-variance state.
    pub const P_HIGH: f64 = 0.1;
    /// Largest kurtosis the family reaches with `w >= 0`: `3 (1 + (1-p)/p) = 30`.
    pub const MAX_KURTOSIS: f64 = 30.0;

    /// The mixture with kurtosis `k` (clamped into `[3, 30]`).
    pub fn for_kurtosis(k: f64) -> Self {
        let p = Self::P_HIGH;
        let excess = (k.clamp(3.0, Self::MAX_KURTOSIS) / 3.0 - 1.0).max(0.0);
        // E[w] = (1-p) w_lo + p w_hi = 1, E[w^2] = 1 + a^2 p/(1-p) = k/3.
        let a = (excess * (1.0 - p) / p).sqrt();
        let w_hi = 1.0 + a;
        let w_lo = (1.0 - a * p / (1.0 - p)).max(0.0);
        Self {
            scale: [w_lo, w_hi],
            prob: [1.0 - p, p],
        }
    }

    /// Whether this is the plain Gaussian (both scales 1).
    pub fn is_gaussian(&self) -> bool {
        self.scale == [1.0, 1.0]
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Zero,
    Sine {
        amplitude_g: f64,
    },
    Random {
        sigma_g: [f64; 2],
        prob: [f64; 2],
    },
    /// One tone and random vibration, averaged directly over `points` phases.
    SineRandom {
        amplitude_g: f64,
        sigma_g: [f64; 2],
        prob: [f64; 2],
        points: usize,
    },
    Table,
}

/// `E|m + v|` for a vibration `v` set with [`AbsMean::set`]; buffers are allocated in
/// [`AbsMean::new`] only, so `set` and `eval` never allocate.
#[derive(Clone)]
pub struct AbsMean {
    kind: Kind,
    step_g: f64,
    inv_step_per_g: f64,
    /// `prefix_p[j] = sum_{i<j} p_i`, length `TABLE_POINTS + 1`.
    prefix_p: Vec<f64>,
    /// `prefix_pu[j] = sum_{i<j} p_i u_i`, g.
    prefix_pu: Vec<f64>,
    /// `sin(pi k / N)` for the DFT's bins `k = 0..=N/2` (the box's `sinc`).
    sin_bin: Vec<f64>,
    fft: FftBuffers,
}

#[derive(Clone)]
struct FftBuffers {
    forward: Arc<dyn RealToComplex<f64>>,
    inverse: Arc<dyn ComplexToReal<f64>>,
    real: Vec<f64>,
    spectrum: Vec<Complex<f64>>,
    product: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
}

impl FftBuffers {
    /// `real`'s DFT into `spectrum`.
    fn forward_real(&mut self) -> Result<()> {
        self.forward
            .process_with_scratch(&mut self.real, &mut self.spectrum, &mut self.scratch)
            .map_err(|e| Error::InvalidVibration(format!("FFT of the vibration distribution: {e}")))
    }

    /// Multiplies `spectrum` into the product of the components' spectra (the first
    /// one is copied).
    fn fold_in(&mut self, first: &mut bool) {
        if *first {
            self.product.copy_from_slice(&self.spectrum);
            *first = false;
        } else {
            for (acc, s) in self.product.iter_mut().zip(&self.spectrum) {
                *acc *= *s;
            }
        }
    }
}

/// The DFT over [`TABLE_POINTS`] bins of the bin probabilities of the Gaussian scale
/// mixture (`prob`, `sigmas_g`; a zero scale is a point mass at 0), bins of `h` g, in
/// closed form (module doc): `P_k = sum_c prob_c sum_m exp(-2 s_c^2 x^2) (-1)^m sin(t)/x`
/// with `t = pi k / N`, `x = t + pi m`, `s_c = sigma_c / h`. `sin_bin[k] = sin(t)`.
fn gaussian_bins_spectrum(
    sin_bin: &[f64],
    sigmas_g: [f64; 2],
    prob: [f64; 2],
    h: f64,
    out: &mut [Complex<f64>],
) {
    out.fill(Complex::default());
    let n = TABLE_POINTS as f64;
    for (sigma, p) in sigmas_g.into_iter().zip(prob) {
        if p <= 0.0 {
            continue;
        }
        if sigma <= 0.0 {
            out.iter_mut().for_each(|o| o.re += p);
            continue;
        }
        let s = sigma / h;
        let a = 2.0 * s * s;
        // Alias m's |x| is at least pi m (m > 0) or pi (|m| - 1/2) (m < 0) over
        // t in [0, pi/2]: it counts while a x^2 can stay below ALIAS_EXPONENT.
        let reach = (ALIAS_EXPONENT / a).sqrt() / PI;
        let (m_lo, m_hi) = (-((reach + 0.5).floor() as i64), reach.floor() as i64);
        for m in m_lo..=m_hi {
            let sign = if m % 2 == 0 { p } else { -p };
            let shift = PI * m as f64;
            // The factor falls away from x = 0: run k away from it and stop at underflow.
            let term = |k: usize| -> Option<f64> {
                let t = PI * k as f64 / n;
                let x = t + shift;
                let e = a * x * x;
                (e < EXP_UNDERFLOW).then(|| {
                    let sinc = if x == 0.0 { 1.0 } else { sin_bin[k] / x };
                    (-e).exp() * sinc
                })
            };
            if m >= 0 {
                for (k, o) in out.iter_mut().enumerate() {
                    let Some(v) = term(k) else { break };
                    o.re += sign * v;
                }
            } else {
                for (k, o) in out.iter_mut().enumerate().rev() {
                    let Some(v) = term(k) else { break };
                    o.re += sign * v;
                }
            }
        }
    }
}

impl std::fmt::Debug for AbsMean {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AbsMean")
            .field("kind", &self.kind)
            .field("step_g", &self.step_g)
            .finish()
    }
}

impl Default for AbsMean {
    fn default() -> Self {
        Self::new()
    }
}

impl AbsMean {
    /// Allocates the table (about 100 kB); starts with no vibration.
    pub fn new() -> Self {
        let mut planner = RealFftPlanner::<f64>::new();
        let forward = planner.plan_fft_forward(TABLE_POINTS);
        let inverse = planner.plan_fft_inverse(TABLE_POINTS);
        let scratch_len = forward.get_scratch_len().max(inverse.get_scratch_len());
        let spectrum = forward.make_output_vec();
        Self {
            kind: Kind::Zero,
            step_g: 0.0,
            inv_step_per_g: 0.0,
            prefix_p: vec![0.0; TABLE_POINTS + 1],
            prefix_pu: vec![0.0; TABLE_POINTS + 1],
            sin_bin: (0..spectrum.len())
                .map(|k| (PI * k as f64 / TABLE_POINTS as f64).sin())
                .collect(),
            fft: FftBuffers {
                real: forward.make_input_vec(),
                product: spectrum.clone(),
                spectrum,
                scratch: vec![Complex::default(); scratch_len],
                forward,
                inverse,
            },
        }
    }

    /// Sets the vibration: tones of the given amplitudes (independent phases) plus
    /// random vibration of RMS `sigma_g` and kurtosis `kurtosis` ([`ScaleMixture`]).
    pub fn set(&mut self, tone_amplitudes_g: &[f64], sigma_g: f64, kurtosis: f64) -> Result<()> {
        let mixture = ScaleMixture::for_kurtosis(kurtosis);
        let sigmas = mixture.scale.map(|w| sigma_g * w.sqrt());
        let n_tones = tone_amplitudes_g.iter().filter(|a| **a > 0.0).count();
        let has_random = sigma_g > 0.0;
        self.kind = match (n_tones, has_random) {
            (0, false) => Kind::Zero,
            (0, true) => Kind::Random {
                sigma_g: sigmas,
                prob: mixture.prob,
            },
            (1, false) => Kind::Sine {
                amplitude_g: tone_amplitudes_g.iter().copied().fold(0.0, f64::max),
            },
            _ => {
                self.build_table(tone_amplitudes_g, sigmas, mixture.prob)?;
                Kind::Table
            }
        };
        Ok(())
    }

    /// As [`AbsMean::set`], but one tone with random vibration is averaged directly over
    /// the tone's phase instead of tabulated (module doc): for few evaluations of one
    /// vibration state, such as [`crate::exact::exact_ve`].
    pub fn set_direct(
        &mut self,
        tone_amplitudes_g: &[f64],
        sigma_g: f64,
        kurtosis: f64,
    ) -> Result<()> {
        let mut tones = tone_amplitudes_g.iter().copied().filter(|a| *a > 0.0);
        let (first, second) = (tones.next(), tones.next());
        if let (Some(amplitude_g), None, true) = (first, second, sigma_g > 0.0) {
            let mixture = ScaleMixture::for_kurtosis(kurtosis);
            let sigmas = mixture.scale.map(|w| sigma_g * w.sqrt());
            let sigma_min = sigmas
                .iter()
                .zip(mixture.prob)
                .filter(|(_, p)| *p > 0.0)
                .map(|(s, _)| *s)
                .fold(f64::INFINITY, f64::min);
            let ratio = (amplitude_g / sigma_min).max(1.0);
            let points = (DIRECT_POINTS_PER_RATIO * ratio.ceil()).min(f64::MAX);
            if points <= MAX_DIRECT_POINTS as f64 {
                self.kind = Kind::SineRandom {
                    amplitude_g,
                    sigma_g: sigmas,
                    prob: mixture.prob,
                    points: points as usize,
                };
                return Ok(());
            }
        }
        self.set(tone_amplitudes_g, sigma_g, kurtosis)
    }

    /// `(E|m + v|, dE|m + v|/dm)`.
    #[inline(always)]
    pub fn eval(&self, m: f64) -> (f64, f64) {
        match self.kind {
            Kind::Zero => (m.abs(), m.signum()),
            Kind::Sine { amplitude_g } => sine_abs_mean(m, amplitude_g),
            Kind::Random { sigma_g, prob } => {
                let (v0, s0) = folded_normal_mean(m, sigma_g[0]);
                let (v1, s1) = folded_normal_mean(m, sigma_g[1]);
                (prob[0] * v0 + prob[1] * v1, prob[0] * s0 + prob[1] * s1)
            }
            Kind::SineRandom {
                amplitude_g,
                sigma_g,
                prob,
                points,
            } => sine_random_abs_mean(m, amplitude_g, sigma_g, prob, points),
            Kind::Table => {
                let j = self.table_index(m);
                let p_tot = self.prefix_p[TABLE_POINTS];
                let pu_tot = self.prefix_pu[TABLE_POINTS];
                let slope = p_tot - 2.0 * self.prefix_p[j];
                (m * slope + pu_tot - 2.0 * self.prefix_pu[j], slope)
            }
        }
    }

    /// A bound on `|slope(m + s) - slope(m)|` of [`AbsMean::eval`]'s slope, without
    /// evaluating it at `m + s`. `E|m + v|` is convex in `m`, so after a Newton step
    /// `s` taken with the slope at `m`, its linearisation error is at most
    /// `|s| * slope_change_bound(m, s)`: the compensation's stopping rule uses this.
    ///
    /// - no vibration: the slope jumps by 2 at `m = 0`;
    /// - one tone: the second derivative `(2/pi)/sqrt(A^2 - m^2)` grows with `|m|`
    ///   inside `(-A, A)` and is 0 outside, so its value at the end farther from 0
    ///   bounds it on the segment (the bound is 2 if the segment reaches `|m| = A`);
    /// - random: the second derivative `2 pdf(-m)` is at most
    ///   `sum_k prob_k * 2/(sqrt(2 pi) sigma_k)`;
    /// - table: the slope is piecewise constant, and the change is read exactly.
    #[inline(always)]
    pub fn slope_change_bound(&self, m: f64, s: f64) -> f64 {
        self.slope_change_bound_from(m, self.eval(m).1, s)
    }

    /// [`Self::slope_change_bound`] with the slope at `m`, `slope_m = eval(m).1`,
    /// already known (the kernel has it from the evaluation that took the step): the
    /// table's change is then read at one bin, `end`'s, instead of two.
    #[inline(always)]
    pub fn slope_change_bound_from(&self, m: f64, slope_m: f64, s: f64) -> f64 {
        let end = m + s;
        match self.kind {
            Kind::Zero => {
                if m * end <= 0.0 {
                    2.0
                } else {
                    0.0
                }
            }
            Kind::Sine { amplitude_g } => {
                let far = m.abs().max(end.abs());
                if m.abs() >= amplitude_g && end.abs() >= amplitude_g && m * end > 0.0 {
                    0.0
                } else if far >= amplitude_g {
                    2.0
                } else {
                    let curvature = FRAC_2_PI / ((amplitude_g - far) * (amplitude_g + far)).sqrt();
                    (curvature * s.abs()).min(2.0)
                }
            }
            // A sine added to the random part only spreads its density: the random
            // part's density bound holds.
            Kind::Random { sigma_g, prob } | Kind::SineRandom { sigma_g, prob, .. } => {
                let mut bound = 0.0;
                for (sigma, p) in sigma_g.into_iter().zip(prob) {
                    bound += p * if sigma > 0.0 {
                        // 2 * pdf(0) = sqrt(2/pi) / sigma.
                        ((2.0 / PI).sqrt() / sigma * s.abs()).min(2.0)
                    } else if m * end <= 0.0 {
                        2.0
                    } else {
                        0.0
                    };
                }
                bound
            }
            // eval's slope is `p_tot - 2 prefix_p[j]`, computed the same way at both
            // ends: 0 exactly when both are in one bin.
            Kind::Table => {
                let slope_end =
                    self.prefix_p[TABLE_POINTS] - 2.0 * self.prefix_p[self.table_index(end)];
                (slope_end - slope_m).abs()
            }
        }
    }

    /// `j` with `u_i < -m` exactly for `i < j`: the prefix sums up to `j` hold the
    /// vibration values below `-m`.
    #[inline(always)]
    fn table_index(&self, m: f64) -> usize {
        // u_i = (i - CENTRE) h < -m  <=>  i < CENTRE - m/h.
        let x = CENTRE as f64 - m * self.inv_step_per_g;
        // ceil(x), clamped; written with a truncation because `f64::ceil` is
        // a library call on baseline x86-64 (no SSE4.1), the slowest step here.
        if x <= 0.0 {
            0
        } else if x >= TABLE_POINTS as f64 {
            TABLE_POINTS
        } else {
            // 0 < x < TABLE_POINTS here: the conversion to i32 is exact and one
            // instruction, where one to usize takes a dozen.
            let t = x as i32;
            (t + i32::from(f64::from(t) < x)) as usize
        }
    }

    fn build_table(&mut self, tones_g: &[f64], sigmas_g: [f64; 2], prob: [f64; 2]) -> Result<()> {
        self.build_table_with(tones_g, sigmas_g, prob, true)
    }

    /// [`Self::build_table`]; `closed_form`: the random component's DFT from its closed
    /// form when every positive scale is at least [`SPECTRAL_MIN_SIGMA_BINS`] bins
    /// (module doc), else from its bins' CDF (the tests compare the two).
    fn build_table_with(
        &mut self,
        tones_g: &[f64],
        sigmas_g: [f64; 2],
        prob: [f64; 2],
        closed_form: bool,
    ) -> Result<()> {
        let sigma_max = sigmas_g[0].max(sigmas_g[1]);
        let reach_g: f64 =
            tones_g.iter().map(|a| a.max(0.0)).sum::<f64>() + GAUSS_CUT_SIGMAS * sigma_max;
        let h = reach_g / HALF_WIDTH_BINS;
        self.step_g = h;
        self.inv_step_per_g = 1.0 / h;
        let sin_bin = &self.sin_bin;
        let fft = &mut self.fft;
        let mut first = true;
        // Each component's bin probabilities, wrapped so that u = 0 is index 0.
        for &a in tones_g.iter().filter(|a| **a > 0.0) {
            fft.real.fill(0.0);
            let cdf = |u: f64| 0.5 + (u / a).clamp(-1.0, 1.0).asin() / PI;
            let half = (a / h).ceil() as isize + 1;
            // Bin j holds (j - 1/2) h..(j + 1/2) h: each edge's CDF is evaluated once.
            let mut below = cdf((-half as f64 - 0.5) * h);
            for j in -half..=half {
                let above = cdf((j as f64 + 0.5) * h);
                fft.real[j.rem_euclid(TABLE_POINTS as isize) as usize] = above - below;
                below = above;
            }
            fft.forward_real()?;
            fft.fold_in(&mut first);
        }
        if sigma_max > 0.0 {
            let wide = sigmas_g
                .iter()
                .zip(prob)
                .all(|(s, p)| p <= 0.0 || *s <= 0.0 || *s >= SPECTRAL_MIN_SIGMA_BINS * h);
            if closed_form && wide {
                gaussian_bins_spectrum(sin_bin, sigmas_g, prob, h, &mut fft.spectrum);
            } else {
                fft.real.fill(0.0);
                let half = (GAUSS_CUT_SIGMAS * sigma_max / h).ceil() as isize + 1;
                // Each edge's CDF once per component, as for the tones.
                // Gaussian vibration has two equal scales: one evaluation serves both.
                let same = sigmas_g[0] == sigmas_g[1];
                let cdf = |x: f64, s: f64| if s > 0.0 { normal_cdf(x / s) } else { 0.0 };
                let edge_cdf = |j: isize| -> [f64; 2] {
                    let x = (j as f64 + 0.5) * h;
                    let c0 = cdf(x, sigmas_g[0]);
                    [c0, if same { c0 } else { cdf(x, sigmas_g[1]) }]
                };
                let mut below = edge_cdf(-half - 1);
                for j in -half..=half {
                    let above = edge_cdf(j);
                    let mut p = 0.0;
                    for k in 0..2 {
                        if sigmas_g[k] > 0.0 {
                            p += prob[k] * (above[k] - below[k]);
                        } else if j == 0 {
                            p += prob[k];
                        }
                    }
                    fft.real[j.rem_euclid(TABLE_POINTS as isize) as usize] = p;
                    below = above;
                }
                fft.forward_real()?;
            }
            fft.fold_in(&mut first);
        }
        // The product of real spectra is real at DC and Nyquist; clear round-off.
        fft.product[0].im = 0.0;
        if let Some(last) = fft.product.last_mut() {
            last.im = 0.0;
        }
        fft.inverse
            .process_with_scratch(&mut fft.product, &mut fft.real, &mut fft.scratch)
            .map_err(|e| {
                Error::InvalidVibration(format!("inverse FFT of the vibration distribution: {e}"))
            })?;
        let norm = 1.0 / TABLE_POINTS as f64;
        let (mut acc_p, mut acc_pu) = (0.0, 0.0);
        self.prefix_p[0] = 0.0;
        self.prefix_pu[0] = 0.0;
        for i in 0..TABLE_POINTS {
            let wrapped = (i + TABLE_POINTS - CENTRE) % TABLE_POINTS;
            let p = fft.real[wrapped] * norm;
            let u = (i as f64 - CENTRE as f64) * h;
            acc_p += p;
            acc_pu += p * u;
            self.prefix_p[i + 1] = acc_p;
            self.prefix_pu[i + 1] = acc_pu;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Midpoint rule over one period of a phase, `n` points (spectrally accurate for
    /// smooth periodic integrands, O(1/n^2) at a kink).
    fn phase_mean(n: usize, f: impl Fn(f64) -> f64) -> f64 {
        (0..n)
            .map(|i| f((i as f64 + 0.5) / n as f64 * 2.0 * PI))
            .sum::<f64>()
            / n as f64
    }

    #[test]
    fn closed_forms_match_quadrature() {
        for &(m, a) in &[(0.0, 2.0), (1.0, 2.0), (-1.5, 2.0), (3.0, 2.0)] {
            let want = phase_mean(200_000, |t| (m + a * t.sin()).abs());
            assert!((sine_abs_mean(m, a).0 - want).abs() < 1e-9, "m={m} a={a}");
        }
        for &(mu, s) in &[(0.0, 1.0), (10.0, 6.1968), (-0.3, 0.5)] {
            // Midpoint rule over z in [-10, 10] with a node at the kink's neighbourhood fine enough.
            let n = 400_001;
            let (mut num, mut den) = (0.0, 0.0);
            for k in 0..n {
                let z = -10.0 + 20.0 * (k as f64 + 0.5) / n as f64;
                let w = (-0.5 * z * z).exp();
                num += w * (mu + s * z).abs();
                den += w;
            }
            assert!(
                (folded_normal_mean(mu, s).0 - num / den).abs() < 1e-8 * s,
                "mu={mu} s={s}"
            );
        }
        // A pure sine with aB < |aL| has no asymmetry VE (MODEL.md section 6).
        assert_eq!(sine_abs_mean(1.0, 0.42).0, 1.0);
    }

    /// The table against phase averages of the closed forms verified above.
    #[test]
    fn table_matches_phase_averages_of_closed_forms() {
        let mut t = AbsMean::new();
        let ms = [-2.5, -1.0, 0.0, 0.4, 1.3, 2.9];
        t.set(&[2.0, 0.7], 0.0, 3.0).unwrap();
        for m in ms {
            let want = phase_mean(20_000, |th| sine_abs_mean(m + 0.7 * th.sin(), 2.0).0);
            assert!((t.eval(m).0 - want).abs() < 1e-4, "two tones, m={m}");
        }
        t.set(&[2.0], 0.5, 3.0).unwrap();
        for m in ms {
            let want = phase_mean(20_000, |th| folded_normal_mean(m + 2.0 * th.sin(), 0.5).0);
            assert!((t.eval(m).0 - want).abs() < 1e-4, "tone and noise, m={m}");
        }
        t.set(&[1.0, 0.5], 0.3, 3.0).unwrap();
        for m in ms {
            let want = phase_mean(1000, |t1| {
                phase_mean(1000, |t2| {
                    folded_normal_mean(m + t1.sin() + 0.5 * t2.sin(), 0.3).0
                })
            });
            assert!(
                (t.eval(m).0 - want).abs() < 1e-4,
                "two tones and noise, m={m}"
            );
        }
        // Non-Gaussian random alone: the mixture of two folded normals.
        t.set(&[], 1.0, 9.0).unwrap();
        let mix = ScaleMixture::for_kurtosis(9.0);
        let want = mix.prob[0] * folded_normal_mean(0.5, mix.scale[0].sqrt()).0
            + mix.prob[1] * folded_normal_mean(0.5, mix.scale[1].sqrt()).0;
        assert!((t.eval(0.5).0 - want).abs() < 1e-15);
    }

    /// The direct phase average against a brute-force one with 200,000 phases and
    /// against the table, over tone-to-noise ratios from 0.1 to 50, Gaussian and
    /// kurtosis 6, inside and outside the tone's reach.
    #[test]
    fn direct_phase_average_converges() {
        let mut direct = AbsMean::new();
        let mut table = AbsMean::new();
        for (a, sigma, kurt) in [
            (0.5, 1.4, 3.0),
            (1.2, 1.4, 3.0),
            (2.0, 0.2, 3.0),
            (2.0, 0.04, 3.0),
            (0.1, 1.0, 6.0),
            (3.0, 0.5, 6.0),
        ] {
            direct.set_direct(&[a], sigma, kurt).unwrap();
            assert!(
                matches!(direct.kind, Kind::SineRandom { .. }),
                "{a} {sigma}"
            );
            table.set(&[a], sigma, kurt).unwrap();
            let mixture = ScaleMixture::for_kurtosis(kurt);
            let sigmas = mixture.scale.map(|w| sigma * w.sqrt());
            for m in [-4.0, -1.3, -0.3, 0.0, 0.07, 0.5, 1.9, 6.0] {
                let (v, s) = direct.eval(m);
                let (vb, sb) = sine_random_abs_mean(m, a, sigmas, mixture.prob, 200_000);
                // Rounding of 200,000 terms against a few hundred: 1e-12 of the scale.
                assert!(
                    (v - vb).abs() < 1e-12 * (a + sigma + m.abs()),
                    "{a} {sigma} {m}: {v} vs {vb}"
                );
                assert!((s - sb).abs() < 1e-11, "{a} {sigma} {m}: slope {s} vs {sb}");
                // The table's binning error is about 1e-4 of the reach.
                let (vt, _) = table.eval(m);
                assert!(
                    (v - vt).abs() < 2e-4 * (a + 8.5 * sigma),
                    "{v} vs table {vt}"
                );
            }
        }
        // A fold too sharp for the direct average goes to the table.
        direct.set_direct(&[2.0], 1e-4, 3.0).unwrap();
        assert!(matches!(direct.kind, Kind::Table));
        // Two tones, or no random part, as `set`.
        direct.set_direct(&[2.0, 1.0], 0.5, 3.0).unwrap();
        assert!(matches!(direct.kind, Kind::Table));
        direct.set_direct(&[2.0], 0.0, 3.0).unwrap();
        assert!(matches!(direct.kind, Kind::Sine { .. }));
    }

    /// The random component's DFT in closed form against the DFT of its bins' CDF
    /// (`erfc` at each bin's edges, then the FFT): the same table to rounding, from
    /// half a bin (where the aliases count) to the widest scale the grid allows, for
    /// Gaussian and scale-mixture vibration (kurtosis 30 has a point mass at 0).
    #[test]
    fn closed_form_spectrum_matches_the_bins_cdf() {
        let mut closed = AbsMean::new();
        let mut bins = AbsMean::new();
        let mut smallest_s = f64::INFINITY;
        for (tones, sigma, kurtosis) in [
            (&[10.0][..], 0.005, 3.0),
            (&[10.0], 0.0075, 3.0),
            (&[10.0], 0.02, 3.0),
            (&[2.0], 0.5, 3.0),
            (&[0.3], 3.0, 3.0),
            (&[1.5, 0.4], 1.0, 9.0),
            (&[0.8], 2.0, 30.0),
            (&[10.0], 0.03, 6.0),
        ] {
            let mixture = ScaleMixture::for_kurtosis(kurtosis);
            let sigmas = mixture.scale.map(|w| sigma * w.sqrt());
            closed
                .build_table_with(tones, sigmas, mixture.prob, true)
                .unwrap();
            bins.build_table_with(tones, sigmas, mixture.prob, false)
                .unwrap();
            let positive = sigmas.iter().filter(|s| **s > 0.0);
            let s_min = positive.fold(f64::INFINITY, |a, s| a.min(s / closed.step_g));
            assert!(
                s_min >= SPECTRAL_MIN_SIGMA_BINS,
                "{tones:?} {sigma}: {s_min}"
            );
            smallest_s = smallest_s.min(s_min);
            let reach = tones.iter().sum::<f64>() + 8.5 * sigma;
            for j in 0..=TABLE_POINTS {
                let (a, b) = (closed.prefix_p[j], bins.prefix_p[j]);
                assert!(
                    (a - b).abs() < 1e-14,
                    "{tones:?} {sigma} {kurtosis}: p[{j}] {a} vs {b}"
                );
                let (a, b) = (closed.prefix_pu[j], bins.prefix_pu[j]);
                assert!(
                    (a - b).abs() < 1e-14 * reach,
                    "{tones:?} {sigma} {kurtosis}: pu[{j}] {a} vs {b}"
                );
            }
        }
        // The cases reach down to the smallest scale the closed form takes.
        assert!(smallest_s < 0.75, "{smallest_s}");
    }

    #[test]
    fn slope_is_the_derivative() {
        let mut t = AbsMean::new();
        t.set(&[1.2, 0.4], 0.2, 3.0).unwrap();
        for m in [-1.0, 0.1, 0.9] {
            let d = 1e-3;
            let numeric = (t.eval(m + d).0 - t.eval(m - d).0) / (2.0 * d);
            assert!((numeric - t.eval(m).1).abs() < 2e-3);
        }
        let (_, s) = sine_abs_mean(0.5, 1.0);
        let numeric = (sine_abs_mean(0.5 + 1e-6, 1.0).0 - sine_abs_mean(0.5 - 1e-6, 1.0).0) / 2e-6;
        assert!((s - numeric).abs() < 1e-8);
    }

    #[test]
    fn scale_mixture_has_unit_mean_and_the_kurtosis() {
        for k in [3.0, 4.5, 9.0, 30.0] {
            let m = ScaleMixture::for_kurtosis(k);
            let e_w = m.prob[0] * m.scale[0] + m.prob[1] * m.scale[1];
            let e_w2 = m.prob[0] * m.scale[0].powi(2) + m.prob[1] * m.scale[1].powi(2);
            assert!(
                (e_w - 1.0).abs() < 1e-14 && (3.0 * e_w2 - k).abs() < 1e-12,
                "k={k}"
            );
        }
    }

    /// The slope-change bound holds against the slope actually evaluated at both ends
    /// of the step, for every kind of vibration, over steps from 1e-9 g to 3 g.
    #[test]
    fn slope_change_bound_covers_the_actual_change() {
        let cases: [(&[f64], f64, f64); 6] = [
            (&[], 0.0, 3.0),
            (&[0.5], 0.0, 3.0),
            (&[], 1.4, 3.0),
            (&[], 1.4, 30.0),
            (&[0.5, 1.2], 0.0, 3.0),
            (&[0.5], 1.4, 9.0),
        ];
        let (mut tight, mut moved) = (0, 0);
        for (tones, sigma, kurtosis) in cases {
            let mut a = AbsMean::new();
            a.set(tones, sigma, kurtosis).unwrap();
            for k in 0..4000 {
                let m = -3.0 + 6.0 * ((k * 7919) % 4000) as f64 / 4000.0;
                let s = 10f64.powf(-9.0 + 9.5 * ((k * 104_729) % 997) as f64 / 997.0)
                    * if k % 2 == 0 { 1.0 } else { -1.0 };
                let actual = (a.eval(m + s).1 - a.eval(m).1).abs();
                let bound = a.slope_change_bound(m, s);
                assert!(
                    bound >= actual * (1.0 - 1e-9) - 1e-15,
                    "{tones:?} sigma {sigma} k {kurtosis}: m {m} s {s}: {bound} < {actual}"
                );
                if actual > 0.0 {
                    moved += 1;
                    tight += usize::from(bound < 3.0 * actual);
                }
            }
        }
        // Not a vacuous bound: within 3x of the actual change in most cases.
        assert!(tight * 10 > moved * 8, "{tight} of {moved}");
    }
}
