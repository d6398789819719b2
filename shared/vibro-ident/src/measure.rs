//! Measuring the vibration error on a shake table, MODEL.md section 8 [P2 (16)].
//!
//! The unit's output is recorded still (`U1`), under vibration (`U2`) and still again
//! (`U3`), 5 min each in \[P2\]. Then
//!
//! ```text
//! dV_measured = (<U2> - 0.5*(<U1> + <U3>)) / K1                       [P2 (16)]
//! ```
//!
//! and the run is valid only if the input axis did not move: `|<U1> - <U3>|/|K1|`,
//! the change of the still reading in g, must not exceed the tilt limit (1e-4 rad in
//! \[P2\], i.e. 1e-4 g of gravity on an IA near horizontal, where a tilt `theta` changes
//! the projection by `g*sin(theta) ~ theta*g`).
//!
//! **Uncertainty by batch means.** The output noise of a real unit is correlated
//! (servo loop, flicker, thermal drift), so `std/sqrt(n)` of the raw samples
//! underestimates the uncertainty of a mean, by the square root of the correlation
//! time in samples. Each record is split into `n_batches` contiguous batches (sizes
//! differ by at most one sample); when the batches are much longer than the
//! correlation time their means are nearly independent, and the standard error of the
//! record mean is `std(batch means)/sqrt(n_batches)` (sample std, `n_batches - 1`
//! degrees of freedom). With the default 20 batches the uncertainty itself is known to
//! about `1/sqrt(2*19) = 16 %`. Then `sigma(dV) = sqrt(se2^2 + 0.25*(se1^2 + se3^2))/|K1|`
//! (the three records are independent).

use crate::{Error, Result};
use serde::Serialize;
use std::fmt;

/// `n` weights: 1 but for a raised-cosine rise over the first `taper` and fall over
/// the last `taper` samples (at the samples' centres; a Hann window when
/// `2 taper >= n`). [`RecordMean::tapered`].
pub fn taper_weights(n: usize, taper: usize) -> Vec<f64> {
    if taper == 0 || n == 0 {
        return vec![1.0; n];
    }
    let taper = taper.min(n / 2).max(1);
    (0..n)
        .map(|i| {
            let edge = i.min(n - 1 - i);
            if edge >= taper {
                1.0
            } else {
                let x = std::f64::consts::PI * (edge as f64 + 0.5) / (taper as f64);
                0.5 - 0.5 * x.cos()
            }
        })
        .collect()
}

/// The Hann-weighted means of `n_batches` equal batches over the first
/// `n_batches * (n / n_batches)` of `values` ([`RecordMean::tapered`]).
pub fn hann_batch_means(values: &[f64], n_batches: usize) -> Vec<f64> {
    let m = values.len() / n_batches.max(1);
    if m == 0 {
        return Vec::new();
    }
    let h = taper_weights(m, m);
    let sum_h: f64 = h.iter().sum();
    values
        .chunks_exact(m)
        .take(n_batches)
        .map(|b| b.iter().zip(&h).map(|(x, h)| x * h).sum::<f64>() / sum_h)
        .collect()
}

/// The three records of a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Still, before vibration (`U1`).
    Still1,
    /// Under vibration (`U2`).
    Vib,
    /// Still, after vibration (`U3`).
    Still2,
}

impl fmt::Display for Phase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Phase::Still1 => "still1",
            Phase::Vib => "vib",
            Phase::Still2 => "still2",
        })
    }
}

/// The mean of one output record with its standard error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RecordMean {
    /// `<U>`, V.
    pub mean_v: f64,
    /// Standard error of `mean_v`, V.
    pub std_error_v: f64,
    /// Number of samples (0 when built from a mean).
    pub n_samples: usize,
    /// Number of batches the standard error comes from (0 when built from a mean).
    pub n_batches: usize,
}

impl RecordMean {
    /// Mean and batch-means standard error of a record (see the module docs).
    pub fn from_samples(phase: Phase, samples_v: &[f64], n_batches: usize) -> Result<Self> {
        if n_batches < 2 || samples_v.len() < n_batches {
            return Err(Error::TooFewSamples {
                phase,
                n_samples: samples_v.len(),
                n_batches,
            });
        }
        if let Some((index, &value)) = samples_v.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(Error::NonFiniteSample {
                phase,
                index,
                value,
            });
        }
        let n = samples_v.len();
        let mean_v = samples_v.iter().sum::<f64>() / n as f64;
        let batch_means: Vec<f64> = (0..n_batches)
            .map(|b| {
                let batch = &samples_v[b * n / n_batches..(b + 1) * n / n_batches];
                batch.iter().sum::<f64>() / batch.len() as f64
            })
            .collect();
        let grand_v = batch_means.iter().sum::<f64>() / n_batches as f64;
        let variance_v2 = batch_means
            .iter()
            .map(|m| (m - grand_v) * (m - grand_v))
            .sum::<f64>()
            / (n_batches - 1) as f64;
        Ok(Self {
            mean_v,
            std_error_v: (variance_v2 / n_batches as f64).sqrt(),
            n_samples: n,
            n_batches,
        })
    }

    /// Mean and standard error of a record that holds, beside its rectified part, a
    /// remainder with no power at 0 Hz (a linear response removed by a fit, whose
    /// misfit stays; [`taper_weights`]): the mean weighted by a raised-cosine taper of
    /// `taper_samples` at each end, the batch means each by a Hann window, and the
    /// standard error the Hann batch means' scaled to the record's weighting,
    /// `sqrt(var / B) eff_w / eff_h` (`eff^2 = n sum w^2 / (sum w)^2`: white noise's
    /// variance of a weighted mean relative to the plain one). `taper_samples = 0`:
    /// [`Self::from_samples`].
    ///
    /// Why: such a remainder's mean over an interval is the difference of its integral
    /// at the interval's two ends, so a plain mean holds those end terms, each plain
    /// batch mean two, and neighbouring intervals share one (their errors correlate at
    /// -0.5): the batch means state the record several times its scatter. A taper longer
    /// than the remainder's slowest period (20 Hz: 50 ms) leaves them out.
    pub fn tapered(
        phase: Phase,
        samples_v: &[f64],
        n_batches: usize,
        taper_samples: usize,
    ) -> Result<Self> {
        if taper_samples == 0 {
            return Self::from_samples(phase, samples_v, n_batches);
        }
        let plain = Self::from_samples(phase, samples_v, n_batches)?;
        let n = samples_v.len();
        let w = taper_weights(n, taper_samples);
        let sum_w: f64 = w.iter().sum();
        let mean_v = samples_v.iter().zip(&w).map(|(x, w)| x * w).sum::<f64>() / sum_w;
        let means = hann_batch_means(samples_v, n_batches);
        let grand_v = means.iter().sum::<f64>() / n_batches as f64;
        let variance_v2 =
            means.iter().map(|m| (m - grand_v).powi(2)).sum::<f64>() / (n_batches - 1) as f64;
        let m = n / n_batches;
        let h = taper_weights(m, m);
        let efficiency = |w: &[f64]| {
            (w.len() as f64 * w.iter().map(|x| x * x).sum::<f64>()).sqrt() / w.iter().sum::<f64>()
        };
        Ok(Self {
            mean_v,
            std_error_v: (variance_v2 / n_batches as f64).sqrt() * efficiency(&w) / efficiency(&h),
            ..plain
        })
    }

    /// A record summarised elsewhere: its mean and standard error.
    pub fn from_mean(mean_v: f64, std_error_v: f64) -> Result<Self> {
        if !mean_v.is_finite() {
            return Err(Error::InvalidArgument {
                name: "mean_v",
                value: mean_v,
                rule: "must be finite",
            });
        }
        if !(std_error_v.is_finite() && std_error_v >= 0.0) {
            return Err(Error::InvalidArgument {
                name: "std_error_v",
                value: std_error_v,
                rule: "must be a finite standard error >= 0 V",
            });
        }
        Ok(Self {
            mean_v,
            std_error_v,
            n_samples: 0,
            n_batches: 0,
        })
    }
}

/// Options of the measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasureOptions {
    /// Number of batches per record for the batch-means standard error; default 20.
    pub n_batches: usize,
    /// Largest accepted tilt of the input axis, rad; default 1e-4 as in \[P2\].
    pub tilt_limit_rad: f64,
}

impl MeasureOptions {
    /// Every broken rule as `key = value: rule` (`batches`, `tilt_limit_rad`): at least
    /// 2 batches, a finite tilt limit > 0.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.n_batches < 2 {
            out.push(format!(
                "batches = {}: must be at least 2 (batch means)",
                self.n_batches
            ));
        }
        let tilt = self.tilt_limit_rad;
        if !(tilt.is_finite() && tilt > 0.0) {
            out.push(format!(
                "tilt_limit_rad = {tilt}: must be a finite angle > 0 rad"
            ));
        }
        out
    }
}

impl Default for MeasureOptions {
    fn default() -> Self {
        Self {
            n_batches: 20,
            tilt_limit_rad: 1e-4,
        }
    }
}

/// A vibration error measured by [P2 (16)], with the tilt check passed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct VeMeasurement {
    /// `dV_measured = (<U2> - 0.5*(<U1> + <U3>))/K1`, g.
    pub ve_g: f64,
    /// Standard uncertainty of `ve_g`, g.
    pub ve_sigma_g: f64,
    /// `|<U1> - <U3>|/|K1|`, g: how far the still reading moved.
    pub drift_g: f64,
    /// Standard uncertainty of `<U1> - <U3>` over `|K1|`, g.
    pub drift_sigma_g: f64,
    /// The tilt limit applied, rad (= the drift limit in g, with g = 1 g).
    pub tilt_limit_rad: f64,
    pub k1_v_per_g: f64,
    pub still1: RecordMean,
    pub vib: RecordMean,
    pub still2: RecordMean,
}

/// The VE from the three record means [P2 (16)], after the tilt check of MODEL.md
/// section 8: rejected with [`Error::InputAxisMoved`] when
/// `|<U1> - <U3>|/|K1| > tilt_limit_rad * 1 g`.
pub fn measure_ve(
    still1: &RecordMean,
    vib: &RecordMean,
    still2: &RecordMean,
    k1_v_per_g: f64,
    tilt_limit_rad: f64,
) -> Result<VeMeasurement> {
    crate::positions::validate_k1(k1_v_per_g)?;
    if !(tilt_limit_rad.is_finite() && tilt_limit_rad > 0.0) {
        return Err(Error::InvalidArgument {
            name: "tilt_limit_rad",
            value: tilt_limit_rad,
            rule: "must be a finite angle > 0 rad",
        });
    }
    let k1_abs = k1_v_per_g.abs();
    let drift_g = (still1.mean_v - still2.mean_v).abs() / k1_abs;
    // g = 1 g: a tilt of theta rad moves the reading by at most theta g.
    let limit_g = tilt_limit_rad;
    if drift_g > limit_g {
        return Err(Error::InputAxisMoved {
            drift_g,
            limit_g,
            limit_rad: tilt_limit_rad,
        });
    }
    let se1 = still1.std_error_v;
    let se2 = vib.std_error_v;
    let se3 = still2.std_error_v;
    let ve_g = (vib.mean_v - 0.5 * (still1.mean_v + still2.mean_v)) / k1_v_per_g;
    let ve_sigma_g = (se2 * se2 + 0.25 * (se1 * se1 + se3 * se3)).sqrt() / k1_abs;
    Ok(VeMeasurement {
        ve_g,
        ve_sigma_g,
        drift_g,
        drift_sigma_g: (se1 * se1 + se3 * se3).sqrt() / k1_abs,
        tilt_limit_rad,
        k1_v_per_g,
        still1: *still1,
        vib: *vib,
        still2: *still2,
    })
}

/// [`measure_ve`] from the raw records (V), with batch-means standard errors.
pub fn measure_ve_from_samples(
    still1_v: &[f64],
    vib_v: &[f64],
    still2_v: &[f64],
    k1_v_per_g: f64,
    options: &MeasureOptions,
) -> Result<VeMeasurement> {
    let b = options.n_batches;
    measure_ve(
        &RecordMean::from_samples(Phase::Still1, still1_v, b)?,
        &RecordMean::from_samples(Phase::Vib, vib_v, b)?,
        &RecordMean::from_samples(Phase::Still2, still2_v, b)?,
        k1_v_per_g,
        options.tilt_limit_rad,
    )
}

/// The three windows of a run on a rig's time axis, s: each `[from, to]`. A reading
/// belongs to a window when its whole interval `(t - T, t]` lies inside it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Segments {
    pub still_before_s: [f64; 2],
    pub vibrating_s: [f64; 2],
    pub still_after_s: [f64; 2],
}

impl Segments {
    /// Every broken rule, each as `key = value: rule` (empty when valid): finite times,
    /// each window from < to, the three in order without overlap.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        let windows = [
            ("still_before_s", self.still_before_s),
            ("vibrating_s", self.vibrating_s),
            ("still_after_s", self.still_after_s),
        ];
        for (name, [a, b]) in windows {
            if !(a.is_finite() && b.is_finite() && a < b) {
                out.push(format!(
                    "{name} = [{a}, {b}]: must be two finite times, the first before the second"
                ));
            }
        }
        for pair in windows.windows(2) {
            let ((n1, w1), (n2, w2)) = (pair[0], pair[1]);
            if w1[1] > w2[0] {
                out.push(format!(
                    "{n2} = [{}, {}]: must start at or after {n1}'s end ({}): still, \
                     vibrating, still, in that order",
                    w2[0], w2[1], w1[1]
                ));
            }
        }
        out
    }

    /// The window of each phase, in the order still1, vib, still2.
    pub fn windows(&self) -> [(Phase, [f64; 2]); 3] {
        [
            (Phase::Still1, self.still_before_s),
            (Phase::Vib, self.vibrating_s),
            (Phase::Still2, self.still_after_s),
        ]
    }
}

/// A VE measured from a rig's time-stamped readings ([`measure_ve_timed`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TimedMeasurement {
    /// With the linear response removed when one was given, else the raw records.
    pub measurement: VeMeasurement,
    /// The raw records' measurement (the linear response left in), for comparison;
    /// `None` when no linear response was given (it is `measurement`).
    pub raw: Option<VeMeasurement>,
    /// Whether `measurement` has the linear response removed.
    pub linear_response_removed: bool,
}

/// The taper at each end of a vibrating record whose linear response was removed
/// ([`RecordMean::tapered`]), s: half the estimator's default Welch segment (0.25 s),
/// longer than the slowest period of a shake table's random vibration (20 Hz: 50 ms).
pub const REMAINDER_TAPER_S: f64 = 0.125;

/// [`REMAINDER_TAPER_S`] in readings of `interval_s`.
fn remainder_taper_samples(interval_s: f64) -> usize {
    if interval_s > 0.0 && interval_s.is_finite() {
        (REMAINDER_TAPER_S / interval_s).round() as usize
    } else {
        0
    }
}

/// [P2 (16)] from a rig's readings: `times_s` the latch times (s), each reading the
/// mean over `(t - interval_s, t]`, `u_v` the outputs (V), and optionally `linear_v`,
/// the unit's linear response to the table's motion over each reading's interval (V;
/// NaN where not known: [`crate::reference`]), which is removed before the batch means.
/// A reading belongs to a segment when its interval lies inside it (and, with
/// `linear_v`, its linear response is known).
pub fn measure_ve_timed(
    times_s: &[f64],
    interval_s: f64,
    u_v: &[f64],
    linear_v: Option<&[f64]>,
    segments: &Segments,
    k1_v_per_g: f64,
    options: &MeasureOptions,
) -> Result<TimedMeasurement> {
    if let Some(p) = segments.problems().into_iter().next() {
        return Err(Error::Segments { problem: p });
    }
    let n = times_s.len().min(u_v.len());
    let records = |with_linear: bool| -> Result<[RecordMean; 3]> {
        let mut out = Vec::with_capacity(3);
        for (phase, [lo, hi]) in segments.windows() {
            let samples: Vec<f64> = (0..n)
                .filter(|&i| times_s[i] - interval_s >= lo - 1e-9 && times_s[i] <= hi + 1e-9)
                .filter_map(|i| match (with_linear, linear_v) {
                    (true, Some(lin)) => {
                        let l = *lin.get(i)?;
                        l.is_finite().then(|| u_v[i] - l)
                    }
                    _ => Some(u_v[i]),
                })
                .collect();
            // A removed linear response leaves its misfit in the vibrating record.
            let taper = if with_linear && linear_v.is_some() && phase == Phase::Vib {
                remainder_taper_samples(interval_s)
            } else {
                0
            };
            out.push(RecordMean::tapered(
                phase,
                &samples,
                options.n_batches,
                taper,
            )?);
        }
        Ok([out[0], out[1], out[2]])
    };
    let measure =
        |r: [RecordMean; 3]| measure_ve(&r[0], &r[1], &r[2], k1_v_per_g, options.tilt_limit_rad);
    match linear_v {
        Some(_) => Ok(TimedMeasurement {
            measurement: measure(records(true)?)?,
            raw: Some(measure(records(false)?)?),
            linear_response_removed: true,
        }),
        None => Ok(TimedMeasurement {
            measurement: measure(records(false)?)?,
            raw: None,
            linear_response_removed: false,
        }),
    }
}

#[cfg(test)]
mod taper_tests {
    use super::{Phase, RecordMean};
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// A remainder with no power at 0 Hz (ten sines between 20 and 300 Hz of random
    /// phase, 0.1 g each, as a fitted linear response's misfit) beside white noise of
    /// 1 mg, 7.7 s at 800 Hz, over 1,000 draws (Monte Carlo): the plain mean holds the
    /// sines' end terms (its scatter well above the noise's `sigma / sqrt(n)`) and its
    /// batch means state several times its scatter; the tapered mean scatters as the
    /// noise does (within 15 %) and states it within 20 %.
    #[test]
    fn a_taper_leaves_out_the_end_terms_of_a_remainder_without_dc() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (rate_hz, n, batches, taper) = (800.0, 6160usize, 20usize, 100usize);
        let noise = Normal::new(0.0, 1e-3).unwrap();
        let draws = 1000;
        let (mut plain, mut tapered) = (Vec::new(), Vec::new());
        let (mut plain_u2, mut tapered_u2) = (0.0, 0.0);
        for _ in 0..draws {
            let sines: Vec<(f64, f64)> = (0..10)
                .map(|_| {
                    (
                        rng.random_range(20.0..300.0),
                        rng.random_range(0.0..std::f64::consts::TAU),
                    )
                })
                .collect();
            let x: Vec<f64> = (0..n)
                .map(|i| {
                    let t = i as f64 / rate_hz;
                    let s: f64 = sines
                        .iter()
                        .map(|(f, p)| 0.1 * (std::f64::consts::TAU * f * t + p).cos())
                        .sum();
                    s + noise.sample(&mut rng)
                })
                .collect();
            let a = RecordMean::from_samples(Phase::Vib, &x, batches).unwrap();
            let b = RecordMean::tapered(Phase::Vib, &x, batches, taper).unwrap();
            plain.push(a.mean_v);
            tapered.push(b.mean_v);
            plain_u2 += a.std_error_v.powi(2) / draws as f64;
            tapered_u2 += b.std_error_v.powi(2) / draws as f64;
        }
        let sd = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
        };
        let floor = 1e-3 / (n as f64).sqrt();
        let (sd_plain, sd_tapered) = (sd(&plain), sd(&tapered));
        assert!(sd_plain > 3.0 * floor, "{sd_plain} vs {floor}");
        assert!(
            plain_u2.sqrt() > 3.0 * sd_plain,
            "{} vs {sd_plain}",
            plain_u2.sqrt()
        );
        // The taper's weights lose a little: eff^2 = n sum w^2 / (sum w)^2 ~ 1.01.
        assert!(
            (sd_tapered / floor - 1.0).abs() < 0.15,
            "{sd_tapered} vs {floor}"
        );
        let ratio = tapered_u2.sqrt() / sd_tapered;
        assert!((ratio - 1.0).abs() < 0.2, "stated / scatter {ratio}");
        // No taper: the plain record mean.
        let x: Vec<f64> = (0..100).map(f64::from).collect();
        assert_eq!(
            RecordMean::tapered(Phase::Vib, &x, 4, 0).unwrap(),
            RecordMean::from_samples(Phase::Vib, &x, 4).unwrap()
        );
    }
}
