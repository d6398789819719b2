//! What the band powers of an estimate hold of a known spectrum: the leakage of the
//! Welch average through its window, for consumers that model the spectrum from the
//! band PSDs (the lab's filtering effects, docs/lab.md "Logs as input").
//!
//! A Welch bin does not measure the PSD at its frequency but the PSD smoothed by the
//! segment window's spectral kernel: for a one-sided PSD `S` and a periodic Hann
//! segment of `N` samples,
//!
//! ```text
//! E[S_k] = int_0 S(f) [K(f - f_k) + K(f + f_k)] df,   K(f) = |W(f)|^2 / (fs sum w^2)
//! ```
//!
//! (Welch 1967, eq. 4; the second term is the negative-frequency image, which the DC
//! and Nyquist bins, not doubled, do not have), `W` the window's DTFT. The kernel has
//! unit area and a main lobe of +-2 bins, so where the PSD steps at a band edge the
//! lower band lends power to the higher one: at the default 4 Hz bins, the 40-80 Hz
//! band of RIG.md's flight spectrum (P1 Table 3 with the amplification) reports 3 %
//! below its power and the 80-160 Hz band 6 % above its own, whatever the window's
//! length or count. [`BandLeakage::band_power_g2`] is the expected band power the
//! estimator reports (its bins, each taking the fraction of its interval inside the
//! band, as `welch` integrates) for a unit PSD over one source interval, so a
//! consumer can solve for the piecewise-flat spectrum behind the reported band powers.
//!
//! Left out: the per-segment mean removal (it touches the bins within two of DC), the
//! response correction of each bin (a first-order AC coupling changes by far less than
//! a percent over the kernel's +-2 bins above a few times its corner) and the kernel
//! beyond 64 bins (under 1e-10 of its area).
//!
//! Reference: P. D. Welch, IEEE Trans. Audio Electroacoust. AU-15(2), 1967, 70-73;
//! F. J. Harris, Proc. IEEE 66(1), 1978, 51-83 (the Hann window's kernel).

use realfft::num_complex::Complex64;
use std::f64::consts::PI;

/// Kernel table step, bins.
const STEP_BINS: f64 = 1.0 / 16.0;
/// Largest kernel reach tabulated, bins.
const MAX_REACH_BINS: f64 = 64.0;

/// The estimator's Welch leakage between frequency intervals (module doc).
#[derive(Debug, Clone)]
pub struct BandLeakage {
    /// Bin width, Hz.
    df_hz: f64,
    /// Highest bin (Nyquist for an even segment).
    last_bin: usize,
    nyquist_is_a_bin: bool,
    /// The kernel's reach either side, bins: the table spans `[-reach, reach]`.
    reach_bins: f64,
    /// At the nodes `x_i = -reach + i STEP_BINS`: the kernel's integral from `-reach`,
    /// and the kernel (per bin), for cubic Hermite interpolation of the integral.
    cdf: Vec<f64>,
    pdf: Vec<f64>,
}

impl BandLeakage {
    /// The leakage of an estimator with this configuration.
    pub fn new(config: &crate::EstimatorConfig) -> Self {
        Self::with_segment(config.sample_rate_hz(), config.segment_samples())
    }

    /// The leakage of Welch segments of `segment_samples` at `sample_rate_hz`.
    pub fn with_segment(sample_rate_hz: f64, segment_samples: usize) -> Self {
        let n = segment_samples.max(2);
        let window = crate::welch::periodic_hann(n);
        let sq_sum: f64 = window.iter().map(|w| w * w).sum();
        let reach_bins = MAX_REACH_BINS.min((n / 2) as f64);
        let kernel = |x: f64| hann_gain(n, x).norm_sqr() / (n as f64 * sq_sum);
        let nodes = (2.0 * reach_bins / STEP_BINS).round() as usize + 1;
        let mut cdf = Vec::with_capacity(nodes);
        let mut pdf = Vec::with_capacity(nodes);
        let mut acc = 0.0;
        for i in 0..nodes {
            let x = -reach_bins + i as f64 * STEP_BINS;
            if i > 0 {
                acc += gauss_legendre4(&kernel, x - STEP_BINS, x);
            }
            cdf.push(acc);
            pdf.push(kernel(x));
        }
        Self {
            df_hz: sample_rate_hz / n as f64,
            last_bin: n / 2,
            nyquist_is_a_bin: n % 2 == 0,
            reach_bins,
            cdf,
            pdf,
        }
    }

    /// Bin width, Hz.
    pub fn df_hz(&self) -> f64 {
        self.df_hz
    }

    /// The kernel's integral from `-inf` to `x` bins.
    fn kernel_cdf(&self, x: f64) -> f64 {
        let last = self.cdf.len() - 1;
        let u = (x + self.reach_bins) / STEP_BINS;
        if u.is_nan() || u <= 0.0 {
            return 0.0;
        }
        if u >= last as f64 {
            return self.cdf[last];
        }
        let i = (u.floor() as usize).min(last - 1);
        let t = u - i as f64;
        // Cubic Hermite on [x_i, x_i+1] with the kernel as the derivative.
        let (t2, t3) = (t * t, t * t * t);
        let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
        let h10 = t3 - 2.0 * t2 + t;
        let h01 = -2.0 * t3 + 3.0 * t2;
        let h11 = t3 - t2;
        h00 * self.cdf[i]
            + h10 * STEP_BINS * self.pdf[i]
            + h01 * self.cdf[i + 1]
            + h11 * STEP_BINS * self.pdf[i + 1]
    }

    /// The power the estimator's band `band_hz` reports, in expectation, of a
    /// one-sided PSD of 1 g^2/Hz over `source_hz` and none elsewhere, g^2 (the bins
    /// of the band each with the fraction of `[k df - df/2, k df + df/2]` inside it,
    /// as the estimator integrates). A flat PSD over `[0, fs/2]` gives the band's width
    /// (less `df/4` for a band from 0 Hz: the DC bin is not doubled).
    pub fn band_power_g2(&self, band_hz: [f64; 2], source_hz: [f64; 2]) -> f64 {
        let df = self.df_hz;
        let ([lo, hi], [a, b]) = (band_hz, source_hz);
        if !(hi > lo && b > a && df > 0.0) {
            return 0.0;
        }
        let first = ((lo / df - 0.5).floor().max(0.0) as usize).min(self.last_bin);
        let end = ((hi / df + 0.5).ceil().max(0.0) as usize).min(self.last_bin);
        let (a_bins, b_bins) = (a / df, b / df);
        let mut sum = 0.0;
        for k in first..=end {
            let centre = k as f64 * df;
            let w = ((hi.min(centre + df / 2.0) - lo.max(centre - df / 2.0)) / df).clamp(0.0, 1.0);
            if w <= 0.0 {
                continue;
            }
            let kf = k as f64;
            let mut e = self.kernel_cdf(b_bins - kf) - self.kernel_cdf(a_bins - kf);
            let not_doubled = k == 0 || (k == self.last_bin && self.nyquist_is_a_bin);
            if !not_doubled {
                e += self.kernel_cdf(b_bins + kf) - self.kernel_cdf(a_bins + kf);
            }
            sum += w * e * df;
        }
        sum
    }
}

/// `W` of the periodic Hann window of `n` samples at `x` bins:
/// `sum_m w[m] e^(-i theta m)`, `theta = 2 pi x / n`, from the window's three
/// exponentials `0.5 - 0.25 e^(i 2 pi m/n) - 0.25 e^(-i 2 pi m/n)` and the closed form
/// of the geometric sum `D`.
fn hann_gain(n: usize, x: f64) -> Complex64 {
    let theta = 2.0 * PI * x / n as f64;
    let step = 2.0 * PI / n as f64;
    dirichlet(n, theta) * 0.5
        - dirichlet(n, theta - step) * 0.25
        - dirichlet(n, theta + step) * 0.25
}

/// `D(phi) = sum_{m < n} e^(-i phi m) = e^(-i phi (n-1)/2) sin(n phi/2) / sin(phi/2)`.
fn dirichlet(n: usize, phi: f64) -> Complex64 {
    let nf = n as f64;
    let s = (phi / 2.0).sin();
    let ratio = if s == 0.0 {
        nf
    } else {
        (nf * phi / 2.0).sin() / s
    };
    Complex64::from_polar(ratio, -phi * (nf - 1.0) / 2.0)
}

/// 4-point Gauss–Legendre rule over `[a, b]`.
fn gauss_legendre4(f: &impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    const X: [f64; 2] = [0.339_981_043_584_856_3, 0.861_136_311_594_052_6];
    const W: [f64; 2] = [0.652_145_154_862_546_1, 0.347_854_845_137_453_9];
    let (m, h) = ((a + b) / 2.0, (b - a) / 2.0);
    let mut s = 0.0;
    for j in 0..2 {
        s += W[j] * (f(m - h * X[j]) + f(m + h * X[j]));
    }
    s * h
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The expected one-sided Welch PSD at bin `k` in the time domain, independent of
    /// the kernel: `2 / (fs sum w^2) sum_tau c_w(tau) r(tau) cos(2 pi k tau / n)`,
    /// with `c_w` the window's autocorrelation and `r` the autocorrelation of a unit
    /// one-sided PSD over `[a, b]` (`int_a^b cos(2 pi f tau / fs) df`).
    fn time_domain_bin(fs: f64, n: usize, k: usize, a: f64, b: f64) -> f64 {
        let w = crate::welch::periodic_hann(n);
        let sq: f64 = w.iter().map(|v| v * v).sum();
        let r = |tau: f64| {
            if tau == 0.0 {
                b - a
            } else {
                fs / (2.0 * PI * tau)
                    * ((2.0 * PI * b * tau / fs).sin() - (2.0 * PI * a * tau / fs).sin())
            }
        };
        let mut s = 0.0;
        for tau in 0..n {
            let c: f64 = (0..n - tau).map(|m| w[m] * w[m + tau]).sum();
            let term = c * r(tau as f64) * (2.0 * PI * (k * tau) as f64 / n as f64).cos();
            s += if tau == 0 { term } else { 2.0 * term };
        }
        let one_sided = if k == 0 || 2 * k == n { 1.0 } else { 2.0 };
        one_sided * s / (fs * sq)
    }

    /// Against the time-domain expectation, bin by bin summed over bands that cut bins
    /// (fractional edges), for sources near, across and far from the band; and a flat
    /// PSD gives each band its width.
    #[test]
    fn band_power_matches_the_time_domain_expectation() {
        let (fs, n) = (1000.0, 100); // 10 Hz bins
        let leak = BandLeakage::with_segment(fs, n);
        let df = fs / n as f64;
        for band in [[20.0, 40.0], [40.0, 80.0], [83.0, 157.0], [0.0, 30.0]] {
            for source in [
                [20.0, 40.0],
                [40.0, 80.0],
                [80.0, 160.0],
                [5.0, 500.0],
                [300.0, 400.0],
            ] {
                let got = leak.band_power_g2(band, source);
                let mut want = 0.0;
                for k in 0..=n / 2 {
                    let c = k as f64 * df;
                    let w = ((band[1].min(c + df / 2.0) - band[0].max(c - df / 2.0)) / df)
                        .clamp(0.0, 1.0);
                    want += w * df * time_domain_bin(fs, n, k, source[0], source[1]);
                }
                assert!(
                    (got - want).abs() < 1e-6 * (band[1] - band[0]),
                    "band {band:?} source {source:?}: {got} vs {want}"
                );
            }
            // (The DC bin, not doubled, takes half of its half-interval: the estimator's
            // convention, so a band from 0 Hz holds df/4 less.)
            let flat = leak.band_power_g2(band, [0.0, fs / 2.0]);
            let width = band[1] - band[0] - if band[0] < df / 2.0 { df / 4.0 } else { 0.0 };
            assert!((flat - width).abs() < 1e-6, "{band:?}: {flat}");
        }
        // The step of RIG.md's spectrum at 80 Hz, 4 Hz bins: the band above gains
        // about 1.2 Hz worth of the PSD below (the kernel's mean reach past an edge).
        let leak = BandLeakage::with_segment(25_600.0, 6_400);
        let lent = leak.band_power_g2([80.0, 160.0], [40.0, 80.0]);
        assert!((1.0..1.4).contains(&lent), "{lent}");
    }
}
