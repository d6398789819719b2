//! The vibration *within* one accelerometer output interval.
//!
//! MODEL.md section 7 compensates the mean `U` of the output over an averaging interval
//! with the VE of the whole vibration: that is right when the interval spans many
//! vibration periods, so that the vibration averages out inside it. A stream
//! compensator works on every output sample (800 Hz in the Cyclone-4 rig), and the
//! output samples *resolve* the slow part of the vibration (the 8..16 Hz tones): the
//! main-error stage (18), evaluated at each sample's reading, already removes what that
//! part rectifies (`k2 (aL + v)^2` at the sampled `v`). Only the motion inside an
//! interval is rectified unseen. Applying the full VE on top counts the slow part
//! twice (the demo measured 3.3 mg left on AK1 instead of 0.16 mg).
//!
//! For an output that is the mean over an interval `T` (a boxcar), a component at
//! frequency `f` keeps the fraction `sinc^2(pi f T)` of its variance in the interval
//! means, and leaves `r(f) = 1 - sinc^2(pi f T)` inside the interval:
//!
//! - a tone `A sin(2 pi f t + phi)` deviates from its interval mean with variance
//!   `A^2/2 r(f)` (averaged over the phase): it enters the model as a tone of amplitude
//!   `A sqrt(r(f))`, same phases (cross moments scale alike);
//! - random vibration with PSD `S(f)` leaves `int S(f) r(f) df`: per sensor axis the
//!   band PSDs of the estimate give the spectral shape (the rest of the broadband
//!   variance is spread over the part of the broadband band above the last band), and
//!   the covariance `K_jk` scales by `sqrt(w_j w_k)`, `w_j` the axis' fraction.
//!
//! With `T` long against every period (`r -> 1`) this is the papers' case; with `T` short
//! (`r -> 0`) nothing is left to rectify. The within-interval deviation of a slow tone is
//! nearly a ramp, not a sinusoid: the amplitude matches its variance, which is what the
//! quadratic terms (the leading ones) see.

use std::f64::consts::PI;
use vibro_msgs::VibEstimate;

/// `1 - sinc^2(pi f T)`: the fraction of a component's variance at `f_hz` that stays
/// inside output intervals of `interval_s` (boxcar means).
pub fn within_fraction(f_hz: f64, interval_s: f64) -> f64 {
    let x = PI * f_hz * interval_s;
    if x.abs() < 1e-4 {
        // 1 - (1 - x^2/6)^2 to the first order.
        return x * x / 3.0;
    }
    let s = x.sin() / x;
    (1.0 - s * s).clamp(0.0, 1.0)
}

/// The mean of [`within_fraction`] over `[f_lo, f_hi]` (a flat PSD over the band),
/// by Simpson's rule on 128 panels.
pub fn band_within_fraction(f_lo_hz: f64, f_hi_hz: f64, interval_s: f64) -> f64 {
    if f_hi_hz.partial_cmp(&f_lo_hz) != Some(std::cmp::Ordering::Greater) {
        return within_fraction(f_lo_hz.max(0.0), interval_s);
    }
    simpson_within(f_lo_hz, f_hi_hz, interval_s, 128)
}

/// Most pieces [`within_spectrum`] cuts one piece of a spectrum into.
const MAX_SUBPIECES: usize = 256;

/// A spectrum's part *within* output intervals of `interval_s`: each piece cut into
/// sub-pieces (1 Hz wide, or 1/64 of the piece's lower edge above 64 Hz, at most
/// [`MAX_SUBPIECES`]), each scaled by the mean of [`within_fraction`] over it (Simpson's
/// rule, 8 panels). The filtering effects (a mount resonance) weigh this spectrum by
/// their response: with sub-pieces this narrow, `r(f)` is close to linear across each,
/// and the weighting of `r(f) |H(f)|^2 S(f)` is within 1e-3 of the exact integral for
/// resonances of half-power width above 10 Hz. `interval_s <= 0` (the whole
/// vibration): the spectrum as it is.
pub fn within_spectrum(
    spectrum: &[vibro_physics::vibration::PsdBand],
    interval_s: f64,
) -> Vec<vibro_physics::vibration::PsdBand> {
    if !(interval_s.is_finite() && interval_s > 0.0) {
        return spectrum.to_vec();
    }
    let mut out = Vec::new();
    for b in spectrum {
        let width = b.f_hi_hz - b.f_lo_hz;
        if !(width.is_finite() && width > 0.0 && b.f_lo_hz >= 0.0) {
            continue;
        }
        let step = (b.f_lo_hz / 64.0).max(1.0);
        let n = ((width / step).ceil() as usize).clamp(1, MAX_SUBPIECES);
        let h = width / n as f64;
        for k in 0..n {
            let lo = b.f_lo_hz + k as f64 * h;
            let hi = if k + 1 == n { b.f_hi_hz } else { lo + h };
            let r = simpson_within(lo, hi, interval_s, 8);
            out.push(vibro_physics::vibration::PsdBand {
                f_lo_hz: lo,
                f_hi_hz: hi,
                psd_g2_per_hz: b.psd_g2_per_hz.map(|s| s * r),
            });
        }
    }
    out
}

/// The mean of [`within_fraction`] over `[lo, hi]` (`hi > lo`) by Simpson's rule on
/// `panels` (even) panels.
fn simpson_within(lo: f64, hi: f64, interval_s: f64, panels: usize) -> f64 {
    let h = (hi - lo) / panels as f64;
    let mut sum = within_fraction(lo, interval_s) + within_fraction(hi, interval_s);
    for k in 1..panels {
        let w = if k % 2 == 1 { 4.0 } else { 2.0 };
        sum += w * within_fraction(lo + k as f64 * h, interval_s);
    }
    sum / (3.0 * panels as f64)
}

/// Per sensor axis, the fraction of the broadband variance left inside an interval.
fn random_fractions(est: &VibEstimate, interval_s: f64) -> [f64; 3] {
    let (lo, hi) = (est.broadband_f_lo_hz, est.broadband_f_hi_hz);
    if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo) {
        // No spectrum to weigh with: keep the whole variance (the papers' setting).
        return [1.0; 3];
    }
    let flat = band_within_fraction(lo, hi, interval_s);
    let bands = (est.band_count as usize).min(vibro_msgs::MAX_BANDS);
    let mut out = [flat; 3];
    for (j, w) in out.iter_mut().enumerate() {
        let total = est.broadband_covariance_g2[j][j];
        if !(total.is_finite() && total > 0.0) {
            continue;
        }
        let (mut var, mut weighted, mut top) = (0.0, 0.0, lo);
        let mut usable = bands > 0;
        for b in 0..bands {
            let (f1, f2, rms) = (
                est.band_f_lo_hz[b],
                est.band_f_hi_hz[b],
                est.band_rms_g[b][j],
            );
            if !(rms.is_finite() && f1.is_finite() && f2.is_finite() && f2 > f1) {
                usable = false;
                break;
            }
            // Only the part of the band inside the broadband band counts.
            let (a, z) = (f1.max(lo), f2.min(hi));
            if z <= a {
                continue;
            }
            let v = rms * rms * (z - a) / (f2 - f1);
            var += v;
            weighted += v * band_within_fraction(a, z, interval_s);
            top = top.max(z);
        }
        if !usable {
            continue;
        }
        let rest = (total - var).max(0.0);
        if rest > 0.0 {
            let (a, z) = if hi > top { (top, hi) } else { (lo, hi) };
            weighted += rest * band_within_fraction(a, z, interval_s);
        }
        *w = (weighted / (var + rest).max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
    }
    out
}

/// The estimate as the vibration inside output intervals of `interval_s`: tone
/// amplitudes times `sqrt(r(f))`, broadband covariance times `sqrt(w_j w_k)` (see the
/// module docs). `interval_s <= 0` (not known yet) returns the estimate unchanged.
/// Values that are not finite stay as they are (the mapping rejects them).
pub fn within_output_interval(est: &VibEstimate, interval_s: f64) -> VibEstimate {
    let mut out = *est;
    if !(interval_s.is_finite() && interval_s > 0.0) {
        return out;
    }
    let tones = (est.tone_count as usize).min(vibro_msgs::MAX_TONES);
    for k in 0..tones {
        let scale = within_fraction(est.tone_frequency_hz[k], interval_s).sqrt();
        for j in 0..3 {
            out.tone_amplitude_g[k][j] *= scale;
        }
    }
    let w = random_fractions(est, interval_s);
    for j in 0..3 {
        for k in 0..3 {
            out.broadband_covariance_g2[j][k] *= (w[j] * w[k]).sqrt();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Interval means of a sampled signal and the variance left inside the intervals.
    fn inside_variance(x: &[f64], per_interval: usize) -> f64 {
        let mut sum = 0.0;
        let mut n = 0usize;
        for w in x.chunks_exact(per_interval) {
            let m = w.iter().sum::<f64>() / w.len() as f64;
            sum += w.iter().map(|v| (v - m) * (v - m)).sum::<f64>();
            n += w.len();
        }
        sum / n as f64
    }

    /// A tone sampled finely, cut into boxcar intervals: the variance left inside the
    /// intervals is `A^2/2 r(f)`, for slow, medium and fast tones.
    #[test]
    fn a_tone_leaves_its_fraction_inside_the_intervals() {
        let fs_hz = 1_024_000.0;
        let per_interval = 1280; // 1.25 ms, an 800 Hz output
        let interval_s = per_interval as f64 / fs_hz;
        for (f_hz, a_g) in [(12.0, 1.2), (300.0, 0.7), (1234.5, 0.5), (5000.0, 1.0)] {
            let n = per_interval * 4000;
            let x: Vec<f64> = (0..n)
                .map(|i| a_g * (2.0 * PI * f_hz * i as f64 / fs_hz + 0.3).sin())
                .collect();
            let measured = inside_variance(&x, per_interval);
            let expected = a_g * a_g / 2.0 * within_fraction(f_hz, interval_s);
            assert!(
                (measured - expected).abs() <= 2e-3 * expected + 1e-12,
                "{f_hz} Hz: {measured} vs {expected}"
            );
        }
    }

    /// Random vibration with a flat PSD over a band (a multisine with random phases,
    /// 2000 components): inside variance = sigma^2 times the band fraction.
    #[test]
    fn a_flat_band_leaves_its_mean_fraction_inside_the_intervals() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let fs_hz = 64_000.0;
        let per_interval = 80; // 1.25 ms
        let interval_s = per_interval as f64 / fs_hz;
        let (f1, f2) = (20.0, 2000.0);
        let comps = 2000;
        let n = 64_000 * 4;
        let mut x = vec![0.0f64; n];
        let amp = (2.0 / comps as f64).sqrt(); // total variance 1
        for c in 0..comps {
            let f = f1 + (f2 - f1) * (c as f64 + 0.5) / comps as f64;
            let phase = rng.random::<f64>() * 2.0 * PI;
            let step = 2.0 * PI * f / fs_hz;
            for (i, v) in x.iter_mut().enumerate() {
                *v += amp * (step * i as f64 + phase).sin();
            }
        }
        let measured = inside_variance(&x, per_interval);
        let expected = band_within_fraction(f1, f2, interval_s);
        assert!(
            (measured - expected).abs() < 0.02 * expected,
            "{measured} vs {expected}"
        );
        // And the band fraction is well inside (0, 1) here: the check is not trivial.
        assert!(expected > 0.3 && expected < 0.9, "{expected}");
    }

    #[test]
    fn long_intervals_keep_everything_and_unknown_intervals_change_nothing() {
        assert!((within_fraction(12.0, 10.0) - 1.0).abs() < 1e-4);
        assert!(within_fraction(12.0, 1e-6) < 1e-8);
        let mut e = VibEstimate::ZEROED;
        e.tone_count = 1;
        e.tone_frequency_hz[0] = 12.0;
        e.tone_amplitude_g[0] = [1.2, 1.2, 0.5];
        e.broadband_f_lo_hz = 20.0;
        e.broadband_f_hi_hz = 2000.0;
        e.broadband_covariance_g2 = [[1.96, 0.1, 0.0], [0.1, 1.96, 0.0], [0.0, 0.0, 1.96]];
        assert_eq!(within_output_interval(&e, 0.0), e);
        let slow = within_output_interval(&e, 1.25e-3);
        assert!(slow.tone_amplitude_g[0][0] < 0.05 * 1.2);
        assert!(slow.broadband_covariance_g2[0][0] < 1.96);
        let long = within_output_interval(&e, 100.0);
        assert!((long.tone_amplitude_g[0][0] - 1.2).abs() < 1e-3);
    }
}

#[cfg(test)]
mod within_spectrum_tests {
    use super::*;
    use vibro_physics::vibration::PsdBand;

    /// `int_lo^hi g` by Simpson's rule on `n` (even) panels.
    fn simpson(lo: f64, hi: f64, n: usize, g: impl Fn(f64) -> f64) -> f64 {
        let h = (hi - lo) / n as f64;
        let mut s = g(lo) + g(hi);
        for k in 1..n {
            s += if k % 2 == 1 { 4.0 } else { 2.0 } * g(lo + k as f64 * h);
        }
        s * h / 3.0
    }

    /// `|T(j 2 pi f)|^2` of a suspension (`filter::Analog::transmissibility`, written
    /// out): `(1 + (f/q f0)^2) / ((1 - (f/f0)^2)^2 + (f/q f0)^2)`.
    fn gain2(f: f64, f0: f64, q: f64) -> f64 {
        let (x, d) = (f / f0, f / (q * f0));
        (1.0 + d * d) / ((1.0 - x * x).powi(2) + d * d)
    }

    /// The piecewise-flat within-interval spectrum, weighed by a resonance's response,
    /// against the exact `int r(f) |H(f)|^2 S(f) df` by brute force: within 1e-3 for a
    /// resonance 10 Hz wide (Q 10 at 100 Hz) and 60 Hz wide (Q 2.5 at 150 Hz), at the
    /// output intervals of 800 Hz and 100 Hz rigs, on octave bands of unequal levels.
    #[test]
    fn the_within_interval_spectrum_weighs_like_the_exact_integral() {
        let edges = [20.0, 40.0, 80.0, 160.0, 320.0, 640.0, 2000.0];
        let level = [0.02, 0.05, 0.01, 0.003, 0.001, 0.0];
        let spectrum: Vec<PsdBand> = (0..6)
            .map(|b| PsdBand {
                f_lo_hz: edges[b],
                f_hi_hz: edges[b + 1],
                psd_g2_per_hz: [level[b], 2.0 * level[b], 0.5 * level[b]],
            })
            .collect();
        for t_s in [1.25e-3, 1e-2] {
            let pieces = within_spectrum(&spectrum, t_s);
            assert!(pieces.len() <= 6 * MAX_SUBPIECES);
            for (f0, q) in [(100.0, 10.0), (150.0, 2.5)] {
                let (mut approx, mut exact) = (0.0, 0.0);
                for p in &pieces {
                    let n = 2 * ((p.f_hi_hz - p.f_lo_hz) * 20.0).ceil() as usize;
                    approx += p.psd_g2_per_hz[1]
                        * simpson(p.f_lo_hz, p.f_hi_hz, n.max(2), |f| gain2(f, f0, q));
                }
                for b in &spectrum {
                    let n = 2 * ((b.f_hi_hz - b.f_lo_hz) * 50.0).ceil() as usize;
                    exact += b.psd_g2_per_hz[1]
                        * simpson(b.f_lo_hz, b.f_hi_hz, n, |f| {
                            within_fraction(f, t_s) * gain2(f, f0, q)
                        });
                }
                let rel = (approx / exact - 1.0).abs();
                assert!(rel < 1e-3, "T {t_s} s, f0 {f0} Hz, Q {q}: {rel:e}");
            }
            // Without a filter the pieces hold the band's within-interval variance.
            let kept: f64 = pieces
                .iter()
                .map(|p| p.psd_g2_per_hz[0] * (p.f_hi_hz - p.f_lo_hz))
                .sum();
            let want: f64 = spectrum
                .iter()
                .map(|b| {
                    b.psd_g2_per_hz[0]
                        * (b.f_hi_hz - b.f_lo_hz)
                        * band_within_fraction(b.f_lo_hz, b.f_hi_hz, t_s)
                })
                .sum();
            assert!((kept / want - 1.0).abs() < 1e-6, "{kept} {want}");
        }
        // The whole vibration: the spectrum as it is.
        assert_eq!(within_spectrum(&spectrum, 0.0), spectrum);
    }
}
