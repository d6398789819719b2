//! Conditions from a record with a reference: a flight (or any vibrating run) cut into
//! windows, each window of each unit one condition of a [`CampaignTable`].
//!
//! A shake-table campaign measures the VE as the vibrating record against still ones
//! (MODEL.md section 8). A flight has no still record: a reference takes its place. Per
//! accelerometer sample it gives the flight acceleration `aL` (the slow part, MODEL.md
//! section 3) and the whole acceleration `a` the unit sensed, both as means over the
//! sample's interval, in the unit's axes. Per sample ([`sample_ve_g`]):
//!
//! ```text
//! r = aF_read - FP(aL) - J(aL) . (a - aL)
//! ```
//!
//! - `aF_read = U/K1`, the reading;
//! - `FP(aL)`, the output at the flight acceleration without vibration (MODEL.md
//!   section 2: `aL3 + a0 + dO(aL)` of section 4, with `k1` and the cross terms);
//! - `J(aL)`, the gradient of (FP) at `aL`: the unit's linear response to the
//!   vibration's own motion, which a window's mean does not remove (a window holds a
//!   fractional number of periods of a slow tone: a 0.5 g tone at 8 Hz leaves up to
//!   20 mg in a 1 s mean, ten times the VE). At `aL3 = 0` the asymmetry's slope
//!   `0.5 k1 d1A sign(aL3)` is taken as 0: there all of `0.5 k1 d1A |a3|` is rectified.
//!
//! What is left is the rectified part, the VE of MODEL.md section 3 (`<aF> - a3` minus
//! the main error without vibration) to second order in the interval-mean vibration.
//! Over a window ([`window_ve`]) the mean of `r` is the measured VE; its standard
//! uncertainty comes from batch means (contiguous batches of the window: the
//! rectified signal is correlated sample to sample).
//!
//! The prediction is made from the vibration estimated over the same window, so its
//! uncertainty is part of the comparison: [`prediction_u_g`] propagates the estimates'
//! own standard uncertainties (tone amplitudes and band RMS per axis) through the base
//! model to first order, and [`condition`] states
//! `ve_uncertainty_g = sqrt(u_measured^2 + u_prediction^2)`.

use crate::table::{Condition, RandomCondition, ToneCondition};
use crate::Result;
use std::collections::BTreeMap;
use vibro_effects::model::BaseMode;
use vibro_effects::predict::base_ve_g;
use vibro_physics::passport::Passport;
use vibro_physics::vibration::{PsdBand, Vibration};

/// One accelerometer sample of one unit with its reference, in the unit's axes
/// `[OA, PA, IA]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceSample {
    /// The reading `U/K1`, g.
    pub reading_g: f64,
    /// Flight acceleration `aL`, mean over the sample's interval, g.
    pub a_l_unit_g: [f64; 3],
    /// Whole acceleration the unit sensed (flight plus the vibration's own motion),
    /// mean over the sample's interval, g.
    pub a_sensed_unit_g: [f64; 3],
    /// The unit's linear response to the vibration over the sample's interval, g, when
    /// it was fitted (a rig's log: the readings regressed on the vibration sensors,
    /// `crate::log_table`); it then replaces `J(aL) (a_sensed - aL)`.
    pub linear_g: Option<f64>,
}

/// The rectified part of one sample's reading (module doc), g.
pub fn sample_ve_g(p: &Passport, s: &ReferenceSample) -> f64 {
    let [l1, l2, l3] = s.a_l_unit_g;
    let linear = s.linear_g.unwrap_or_else(|| {
        let grad = vibro_physics::fp::gradient_g(p, l1, l2, l3);
        (0..3)
            .map(|i| grad[i] * (s.a_sensed_unit_g[i] - s.a_l_unit_g[i]))
            .sum()
    });
    s.reading_g - vibro_physics::fp::output_g(p, l1, l2, l3) - linear
}

/// The VE measured over one window of one unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowVe {
    /// Mean of [`sample_ve_g`] over the window, g.
    pub ve_g: f64,
    /// Its standard uncertainty by batch means, g.
    pub u_g: f64,
    /// Mean flight acceleration over the window, unit axes, g.
    pub a_l_unit_g: [f64; 3],
    /// Largest change of any flight-acceleration component within the window
    /// (max - min), g: the model is evaluated at the mean.
    pub a_l_span_g: f64,
    /// Variance of `aL3` over the window's samples, g^2 ([`prediction_u_g`]).
    pub a_l3_var_g2: f64,
    /// Samples in the window.
    pub samples: usize,
}

/// The measured VE over `samples` (one window of one unit), with `batches` contiguous
/// batch means for its uncertainty. `None` with fewer than 2 batches or fewer samples
/// than batches.
///
/// With `taper_samples > 0` the window's mean and its uncertainty are
/// `vibro_ident::measure::RecordMean::tapered`'s (a raised-cosine taper of that many
/// samples at each end, Hann-weighted batch means). Why: a unit's linear
/// response that the model does not remove exactly (a rig's fitted response through a
/// mount, `crate::log_table`) has no power at 0 Hz, so its mean over an interval is
/// the difference of its integral at the interval's two ends: a boxcar window's mean
/// holds those end terms, neighbouring windows share an end (their errors correlate
/// at -0.5) and each batch mean holds two, so the batch means state the whole window
/// several times its own scatter. A taper longer than the response's slowest period
/// (20 Hz: 50 ms) leaves them out; `crate::log_table` takes half the estimator's Welch
/// segment, which also weights the window's ends as the estimate's spectrum does, on
/// a rig's logs (a simulated log's sensed acceleration removes the response exactly).
/// Measured on the rig generator's 60 s logs through a 150 Hz, Q 2.5 mount with the
/// true model: residual RMS 94/50/63 ug -> 72/23/38 ug, neighbouring windows'
/// residual correlation -0.32/-0.39/-0.22 -> -0.06/-0.04/+0.15.
pub fn window_ve(
    p: &Passport,
    samples: &[ReferenceSample],
    batches: usize,
    taper_samples: usize,
) -> Option<WindowVe> {
    let n = samples.len();
    if batches < 2 || n < batches {
        return None;
    }
    let r: Vec<f64> = samples.iter().map(|s| sample_ve_g(p, s)).collect();
    let w = vibro_ident::measure::taper_weights(n, taper_samples);
    let sum_w: f64 = w.iter().sum();
    let (ve_g, u_g) = if taper_samples == 0 {
        // Equal batches over the first `batches * m` samples; the mean uses all of them.
        let m = n / batches;
        let means: Vec<f64> = r
            .chunks_exact(m)
            .take(batches)
            .map(|b| b.iter().sum::<f64>() / m as f64)
            .collect();
        let grand = means.iter().sum::<f64>() / batches as f64;
        let var = means.iter().map(|x| (x - grand).powi(2)).sum::<f64>() / (batches - 1) as f64;
        (
            r.iter().sum::<f64>() / n as f64,
            (var / batches as f64).sqrt(),
        )
    } else {
        let t = vibro_ident::measure::RecordMean::tapered(
            vibro_ident::measure::Phase::Vib,
            &r,
            batches,
            taper_samples,
        )
        .ok()?;
        (t.mean_v, t.std_error_v)
    };
    let mut a_l = [0.0; 3];
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for (s, w) in samples.iter().zip(&w) {
        for i in 0..3 {
            a_l[i] += s.a_l_unit_g[i] * w / sum_w;
            lo[i] = lo[i].min(s.a_l_unit_g[i]);
            hi[i] = hi[i].max(s.a_l_unit_g[i]);
        }
    }
    let a_l_span_g = (0..3).map(|i| hi[i] - lo[i]).fold(0.0, f64::max);
    let a_l3_var_g2 = samples
        .iter()
        .map(|s| (s.a_l_unit_g[2] - a_l[2]).powi(2))
        .sum::<f64>()
        / n as f64;
    Some(WindowVe {
        ve_g,
        u_g,
        a_l_unit_g: a_l,
        a_l_span_g,
        a_l3_var_g2,
        samples: n,
    })
}

/// Second differences each unit of a log needs for its own scale in [`data_scales`]:
/// the scale's relative standard error is about `1 / sqrt(2 n)`, 13 % at 30. Below,
/// one scale pooled over the log's units (a 20 s log has about 17 per unit). The
/// units' scales differ (the correlation of the measured and the predicted VE's errors
/// depends on the unit's coefficients: 0.6 against 1.2 times the pooled scale on a
/// 600 s `cyclone-4`).
pub const PER_UNIT_SCALE_MIN_DIFFERENCES: usize = 30;

/// Consecutive windows' `(residual_g, stated u_g)` ([`residual_scale`]).
type Run = Vec<(f64, f64)>;

/// The scale of one log's unit ([`data_scales`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GroupScale {
    /// The input of a joint table ([`crate::table::ScaleGroup::source`]).
    pub source: u32,
    /// The unit, 0-based.
    pub unit: u32,
    /// The factor on the rows' stated uncertainties (1 when too few differences).
    pub scale: f64,
    /// Second differences it was estimated from (the log's, when pooled).
    pub differences: usize,
    /// Of those, left out as beyond 3 sigma.
    pub clipped: usize,
    /// One scale for all of the log's units (too few differences for each its own).
    pub pooled: bool,
    /// The evaluation path of the rows it scales, when `lab compare` evaluated the log
    /// on the waveform (`crate::diagnose::compare_evaluated`: the log's rows on each
    /// path have their own scale).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<&'static str>,
}

/// Per row, the factor on its stated uncertainty `stated_u_g` (the residual's, through
/// the model under test) from the scatter of its group's residuals `residual_g`
/// (measured minus the model under test's VE) about the stated uncertainties
/// ([`residual_scale`]): rows of a log's unit
/// ([`crate::table::ScaleGroup`]), in their runs, each unit its own when every unit of
/// the log has [`PER_UNIT_SCALE_MIN_DIFFERENCES`], else one pooled over the log's
/// units; 1 for rows without a group. Against the model under test, not the base
/// model: a hidden effect that changes from window to window with the vibration (a
/// resonance with the spectrum) adds to the base model's residuals a scatter that is
/// not noise and that the model with the effect predicts (measured on `cyclone-4-short`
/// with RIG.md's resonance: 0.92 to 0.98 against the base model, 0.52 to 0.67 on the
/// same flights without the effect). Also the scales per log and unit.
pub fn data_scales(
    rows: &[Condition],
    residual_g: &[f64],
    stated_u_g: &[f64],
) -> (Vec<f64>, Vec<GroupScale>) {
    // (source, unit) -> (the last run seen, runs of (residual, stated u)), in row order.
    let mut series: BTreeMap<(u32, u32), (u32, Vec<Run>)> = BTreeMap::new();
    for ((c, r), u) in rows.iter().zip(residual_g).zip(stated_u_g) {
        let Some(g) = c.scale_group else { continue };
        let (last_run, runs) = series
            .entry((g.source, g.unit))
            .or_insert_with(|| (g.run, Vec::new()));
        if runs.is_empty() || *last_run != g.run {
            runs.push(Vec::new());
            *last_run = g.run;
        }
        if let Some(run) = runs.last_mut() {
            run.push((*r, *u));
        }
    }
    let mut scales: Vec<GroupScale> = Vec::with_capacity(series.len());
    let sources: std::collections::BTreeSet<u32> = series.keys().map(|k| k.0).collect();
    for source in sources {
        let units: Vec<(&(u32, u32), &Vec<Run>)> = series
            .iter()
            .filter(|(k, _)| k.0 == source)
            .map(|(k, (_, runs))| (k, runs))
            .collect();
        let own: Vec<Option<ResidualScale>> =
            units.iter().map(|(_, runs)| residual_scale(runs)).collect();
        let each = own
            .iter()
            .all(|s| s.is_some_and(|s| s.differences >= PER_UNIT_SCALE_MIN_DIFFERENCES));
        let pooled = if each {
            None
        } else {
            let all: Vec<Vec<(f64, f64)>> = units
                .iter()
                .flat_map(|(_, runs)| runs.iter().cloned())
                .collect();
            Some(residual_scale(&all))
        };
        for ((key, _), s) in units.iter().zip(own) {
            let s = match pooled {
                Some(p) => p,
                None => s,
            };
            scales.push(GroupScale {
                source: key.0,
                unit: key.1,
                scale: s.map_or(1.0, |s| s.scale),
                differences: s.map_or(0, |s| s.differences),
                clipped: s.map_or(0, |s| s.clipped),
                pooled: pooled.is_some(),
                path: None,
            });
        }
    }
    let factor = rows
        .iter()
        .map(|c| {
            c.scale_group.map_or(1.0, |g| {
                scales
                    .iter()
                    .find(|s| s.source == g.source && s.unit == g.unit)
                    .map_or(1.0, |s| s.scale)
            })
        })
        .collect();
    (factor, scales)
}

/// A run of consecutive windows' measured-VE uncertainties `u_g` (batch means, each
/// from [`window_ve`]) with each window's variance pooled over its neighbours: the mean
/// of `u^2` over the windows at most `half_width` away within the run.
///
/// Batch means give a window's variance from `batches - 1` degrees of freedom (7 by
/// default), so one window's `u` scatters by about 27 % about its true value, and a
/// least-squares fit weighted by it leans on the windows that happen to state a small
/// one: their `z = r/u` follows Student's t with 7 degrees of freedom (2 % beyond 3,
/// against 0.27 %). Measured on 30 `cyclone-4-short` flights at the true model: windows
/// whose `u` was under 0.8 of their neighbours' had a mean `z^2` of 1.49 and every
/// `|z| > 3`, those above 1.05 of their neighbours' 0.6. Neighbouring windows of a run
/// see nearly the same vibration, so their variances are pooled: 5 windows, 35 degrees
/// of freedom. A change of the vibration within `half_width` windows is smoothed over.
pub fn neighbour_pooled_u(u_g: &[f64], half_width: usize) -> Vec<f64> {
    (0..u_g.len())
        .map(|j| {
            let lo = j.saturating_sub(half_width);
            let hi = (j + half_width + 1).min(u_g.len());
            let near = &u_g[lo..hi];
            (near.iter().map(|u| u * u).sum::<f64>() / near.len() as f64).sqrt()
        })
        .collect()
}

/// Standard uncertainties of an estimated vibration, in the unit's axes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VibrationU {
    /// Per tone of the vibration (its order), per axis: the amplitude's, g.
    pub tone_amplitude_u_g: Vec<[f64; 3]>,
    /// Per axis: the broadband RMS's, g.
    pub sigma_u_g: [f64; 3],
}

/// `vib` with tone `k`'s amplitude on `axis` moved by `h` (never below 0).
fn with_amplitude(vib: &Vibration, k: usize, axis: usize, h: f64) -> Vibration {
    let mut out = *vib;
    out.clear_tones();
    for (j, t) in vib.tones().iter().enumerate() {
        let mut t = *t;
        if j == k {
            t.amplitude_g[axis] = (t.amplitude_g[axis] + h).max(0.0);
        }
        // The same tones as before: they fit.
        let _ = out.push_tone(t);
    }
    out
}

/// `vib` with the RMS on `axis` moved by `h` (correlations kept).
fn with_sigma(vib: &Vibration, axis: usize, h: f64) -> Vibration {
    let mut out = *vib;
    let sigma = vib.covariance_g2[axis][axis].max(0.0).sqrt();
    if sigma <= 0.0 {
        return out;
    }
    let f = ((sigma + h).max(0.0)) / sigma;
    for j in 0..3 {
        out.covariance_g2[axis][j] *= f;
        out.covariance_g2[j][axis] *= f;
    }
    out
}

/// Standard uncertainty of the base model's VE for a window, g:
///
/// - from the vibration's uncertainties, to first order (central differences of
///   `base_ve_g` with steps of one uncertainty; the parameters taken as independent);
/// - from evaluating the model at the window's mean `aL3` while `aL3` varies over it
///   with variance `a_l3_var_g2`: the mean of a smooth VE over the window differs from
///   the VE at the mean by `VE''(aL3) var / 2` (the VE depends on `aL1`, `aL2` only
///   through terms that do not change with the vibration, MODEL.md sections 4-6),
///   taken whole as an uncertainty.
pub fn prediction_u_g(
    mode: BaseMode,
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    a_l3_var_g2: f64,
    vib: &Vibration,
    u: &VibrationU,
) -> Result<f64> {
    let ve = |v: &Vibration| base_ve_g(mode, passport, a_l_unit_g, v);
    let mut var = 0.0;
    if a_l3_var_g2 > 0.0 {
        let h = a_l3_var_g2.sqrt().max(1e-3);
        let at = |d: f64| {
            let mut a = a_l_unit_g;
            a[2] += d;
            base_ve_g(mode, passport, a, vib)
        };
        let curvature = (at(h)? - 2.0 * at(0.0)? + at(-h)?) / (h * h);
        var += (0.5 * curvature * a_l3_var_g2).powi(2);
    }
    // `h_plus` is the parameter's uncertainty; the step below may be shorter (a value
    // cannot go below 0), which changes the slope's estimate, not the uncertainty.
    let mut add = |plus: Vibration, minus: Vibration, h_plus: f64, h_minus: f64| -> Result<()> {
        let span = h_plus + h_minus;
        if span > 0.0 {
            let slope = (ve(&plus)? - ve(&minus)?) / span;
            var += (slope * h_plus).powi(2);
        }
        Ok(())
    };
    for (k, t) in vib.tones().iter().enumerate() {
        let Some(u_k) = u.tone_amplitude_u_g.get(k) else {
            break;
        };
        for axis in 0..3 {
            let h = u_k[axis];
            if !(h.is_finite() && h > 0.0) {
                continue;
            }
            let h_minus = h.min(t.amplitude_g[axis]);
            add(
                with_amplitude(vib, k, axis, h),
                with_amplitude(vib, k, axis, -h_minus),
                h,
                h_minus,
            )?;
        }
    }
    for axis in 0..3 {
        let h = u.sigma_u_g[axis];
        let sigma = vib.covariance_g2[axis][axis].max(0.0).sqrt();
        if !(h.is_finite() && h > 0.0 && sigma > 0.0) {
            continue;
        }
        let h_minus = h.min(sigma);
        add(
            with_sigma(vib, axis, h),
            with_sigma(vib, axis, -h_minus),
            h,
            h_minus,
        )?;
    }
    Ok(var.sqrt())
}

/// Mean of a chi-square variable with one degree of freedom given that it is below 9
/// (3 sigma): `P(chi2_3 < 9) / P(chi2_1 < 9) = 0.970709 / 0.997300`.
const CLIPPED_CHI2_1_MEAN: f64 = 0.970_709 / 0.997_300;

/// How the residual's scatter compares with the stated uncertainties
/// ([`residual_scale`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidualScale {
    /// Factor on the stated (conservative) uncertainties, in `(0, 1]`.
    pub scale: f64,
    /// Second differences it was estimated from.
    pub differences: usize,
    /// Of those, left out as beyond 3 sigma (jumps of a missing effect).
    pub clipped: usize,
}

/// The scatter of a log's residuals against the base model, relative to the stated
/// uncertainties `u_j = sqrt(u_measured^2 + u_prediction^2)`, from the data itself.
///
/// `series`: per unit, runs of consecutive windows (no window left out between them) in
/// time order, each window `(residual_g, u_g)` (measured minus the base model's VE).
/// The rectified random vibration of a window and its estimated RMS come from the same
/// realisation, so their errors are positively correlated and the residual's variance
/// `u_m^2 + u_p^2 - 2 rho u_m u_p` is below `u_j^2`; how far below depends on the
/// vibration, the estimator and the unit. Non-overlapping windows have independent
/// errors, so the second difference `D = r_{j-1} - 2 r_j + r_{j+1}` of a run has the
/// variance `s^2 (u_{j-1}^2 + 4 u_j^2 + u_{j+1}^2)` for errors of `s u_j`, while a
/// missing effect that changes smoothly with the flight (linearly over three windows)
/// cancels in it (the von Neumann successive-difference idea, to second order). The
/// estimate of `s^2` is the mean of `D^2 / V` with values beyond 3 sigma left out
/// (iteratively: a missing effect that jumps at staging), divided by the mean of a
/// chi-square with one degree of freedom clipped at 9. The scale is at most 1 (the
/// correlation is not negative: a larger scatter is a missing effect, not noise).
/// `None` with fewer than 8 differences.
pub fn residual_scale(series: &[Vec<(f64, f64)>]) -> Option<ResidualScale> {
    let mut x = Vec::new();
    for run in series {
        for w in run.windows(3) {
            let d = w[0].0 - 2.0 * w[1].0 + w[2].0;
            let v = w[0].1.powi(2) + 4.0 * w[1].1.powi(2) + w[2].1.powi(2);
            if d.is_finite() && v.is_finite() && v > 0.0 {
                x.push(d * d / v);
            }
        }
    }
    if x.len() < 8 {
        return None;
    }
    let mut s2 = x.iter().sum::<f64>() / x.len() as f64;
    let mut clipped = 0;
    for _ in 0..20 {
        let kept: Vec<f64> = x.iter().copied().filter(|&v| v <= 9.0 * s2).collect();
        if kept.is_empty() {
            break;
        }
        let next = kept.iter().sum::<f64>() / kept.len() as f64 / CLIPPED_CHI2_1_MEAN;
        clipped = x.len() - kept.len();
        if (next - s2).abs() <= 1e-12 * s2 {
            s2 = next;
            break;
        }
        s2 = next;
    }
    // The rows are then weighted by 1 / (scale u)^2 with `s2` estimated from their own
    // residuals, and the chi-square over them is biased high (`E[1/s2] > 1/s2`,
    // Jensen, lessened by `s2` and the residuals moving together): for `n` second
    // differences of independent errors its mean is about `1 + 2 / n` times the truth's
    // (Monte Carlo, 20,000 series each: 1 + 2.6/n at n = 8, 2.1/n at 18, 2.0/n at 30,
    // 1.9/n at 98), so `s2` takes that factor. Measured without it on the rig
    // generator's campaigns with the right model (18 and 30 differences per unit):
    // chi2/dof 0.90..1.57, 1.29 on average over seven.
    let kept = (x.len() - clipped) as f64;
    if kept > 0.0 {
        s2 *= 1.0 + 2.0 / kept;
    }
    Some(ResidualScale {
        scale: s2.sqrt().min(1.0),
        differences: x.len(),
        clipped,
    })
}

/// The vibration of consecutive windows pooled into one lab window, or `None` when
/// they differ in their tones' count (the pool then ends before the window).
///
/// The base model is quadratic in the vibration to leading order (MODEL.md section
/// 6), so the pool keeps the mean second moments: the covariance is the windows' mean,
/// each tone's amplitude per axis the RMS of its amplitudes, its frequency the mean;
/// its phases relative to IA (the only phases the model uses) the circular mean,
/// anchored at the first window's IA phase. The kurtosis is the mean weighted by
/// `sigma^4` (the fourth moment's mean over the pool).
pub fn pooled_vibration(vibs: &[Vibration]) -> Option<Vibration> {
    let first = vibs.first()?;
    let n_tones = first.tones().len();
    if vibs.iter().any(|v| v.tones().len() != n_tones) {
        return None;
    }
    let k = vibs.len() as f64;
    let mut out = *first;
    out.clear_tones();
    for t in 0..n_tones {
        let mut tone = first.tones()[t];
        tone.freq_hz = vibs.iter().map(|v| v.tones()[t].freq_hz).sum::<f64>() / k;
        for axis in 0..3 {
            let a2 = vibs
                .iter()
                .map(|v| v.tones()[t].amplitude_g[axis].powi(2))
                .sum::<f64>();
            tone.amplitude_g[axis] = (a2 / k).sqrt();
            let (c, s) = vibs.iter().fold((0.0, 0.0), |(c, s), v| {
                let ph = v.tones()[t].phase_rad;
                let d = ph[axis] - ph[2];
                (c + d.cos(), s + d.sin())
            });
            if axis != 2 && (c != 0.0 || s != 0.0) {
                tone.phase_rad[axis] = first.tones()[t].phase_rad[2] + s.atan2(c);
            }
        }
        // The same count as the first window's: it fits.
        let _ = out.push_tone(tone);
    }
    for i in 0..3 {
        for j in 0..3 {
            out.covariance_g2[i][j] = vibs.iter().map(|v| v.covariance_g2[i][j]).sum::<f64>() / k;
        }
        let w: f64 = vibs.iter().map(|v| v.covariance_g2[i][i].powi(2)).sum();
        if w > 0.0 {
            out.kurtosis[i] = vibs
                .iter()
                .map(|v| v.kurtosis[i] * v.covariance_g2[i][i].powi(2))
                .sum::<f64>()
                / w;
        }
    }
    Some(out)
}

/// The random part's spectra of consecutive windows pooled (the mean PSD per band),
/// or `None` when their bands' edges differ.
pub fn pooled_bands(bands: &[Vec<PsdBand>]) -> Option<Vec<PsdBand>> {
    let first = bands.first()?;
    let same_edges = |b: &Vec<PsdBand>| {
        b.len() == first.len()
            && b.iter()
                .zip(first)
                .all(|(x, y)| x.f_lo_hz == y.f_lo_hz && x.f_hi_hz == y.f_hi_hz)
    };
    if !bands.iter().all(same_edges) {
        return None;
    }
    let k = bands.len() as f64;
    Some(
        first
            .iter()
            .enumerate()
            .map(|(i, b)| PsdBand {
                psd_g2_per_hz: std::array::from_fn(|axis| {
                    bands.iter().map(|w| w[i].psd_g2_per_hz[axis]).sum::<f64>() / k
                }),
                ..*b
            })
            .collect(),
    )
}

/// The standard uncertainties of [`pooled_bands`]' PSDs from the windows' own
/// (`bands_u`, same edges): `sqrt(sum u^2) / k` per band and axis, the windows'
/// estimates being independent. `None` when the windows' edges differ.
pub fn pooled_bands_u(bands_u: &[Vec<PsdBand>]) -> Option<Vec<PsdBand>> {
    let mut out = pooled_bands(bands_u)?;
    let k = bands_u.len() as f64;
    for (i, b) in out.iter_mut().enumerate() {
        b.psd_g2_per_hz = std::array::from_fn(|axis| {
            bands_u
                .iter()
                .map(|w| w[i].psd_g2_per_hz[axis].powi(2))
                .sum::<f64>()
                .sqrt()
                / k
        });
    }
    Some(out)
}

/// Phase difference `a - b` in degrees, wrapped to `(-180, 180]`.
fn phase_difference_deg(a_rad: f64, b_rad: f64) -> f64 {
    let d = (a_rad - b_rad).to_degrees();
    let w = d - 360.0 * ((d + 180.0) / 360.0).floor();
    if w <= -180.0 {
        w + 360.0
    } else {
        w
    }
}

/// What [`condition`] needs of one window of one unit.
#[derive(Debug, Clone)]
pub struct WindowInput {
    pub run_id: String,
    /// Order in the table, for messages (in place of a line number).
    pub line: usize,
    pub passport_ref: String,
    /// The unit's passport, flat (`predict::flat_passport`).
    pub passport: Passport,
    /// The vibration estimated over the window, unit axes, strongest tone first.
    pub vibration: Vibration,
    /// Its random part's spectrum, unit axes (may be empty).
    pub bands: Vec<PsdBand>,
    /// The standard uncertainties of `bands`' PSDs, same edges (empty: none stated).
    pub bands_u: Vec<PsdBand>,
    pub measured: WindowVe,
    /// [`prediction_u_g`] of the window, g.
    pub prediction_u_g: f64,
    /// Its log's unit and run, for the scale of its uncertainty ([`data_scales`]).
    pub scale_group: Option<crate::table::ScaleGroup>,
    /// Extra numeric variables (time, unit, ...).
    pub extra: BTreeMap<String, f64>,
}

/// The table row of one window of one unit: the window's mean flight acceleration,
/// its estimated vibration, the measured VE and the combined uncertainty.
pub fn condition(w: WindowInput) -> Condition {
    let v = &w.vibration;
    let mut tones = v.tones().iter().map(|t| ToneCondition {
        freq_hz: t.freq_hz,
        a_b_g: t.amplitude_g,
        phase31_deg: phase_difference_deg(t.phase_rad[2], t.phase_rad[0]),
        phase32_deg: phase_difference_deg(t.phase_rad[2], t.phase_rad[1]),
    });
    let tone = tones.next();
    let more_tones: Vec<ToneCondition> = tones.collect();
    let variances = [0, 1, 2].map(|i| v.covariance_g2[i][i].max(0.0));
    let random = variances.iter().any(|&x| x > 0.0).then(|| RandomCondition {
        sigma_g: variances.map(f64::sqrt),
        cov31_g2: v.covariance_g2[2][0],
        cov32_g2: v.covariance_g2[2][1],
        cov12_g2: v.covariance_g2[0][1],
        kurtosis3: v.kurtosis[2],
    });
    Condition {
        run_id: w.run_id,
        line: w.line,
        passport_ref: w.passport_ref,
        passport: std::sync::Arc::new(w.passport),
        a_l_g: w.measured.a_l_unit_g,
        tone,
        more_tones,
        random,
        bands: w.bands,
        bands_u: w.bands_u,
        scale_group: w.scale_group,
        ve_measured_g: w.measured.ve_g,
        ve_uncertainty_g: w.measured.u_g.hypot(w.prediction_u_g),
        extra: w.extra,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_effects::predict::flat_passport;
    use vibro_physics::exact::exact_ve;
    use vibro_physics::fp::output_g;

    fn al15() -> Passport {
        flat_passport(&vibro_config::resolve_passport("AL-15").unwrap()).unwrap()
    }

    fn tone_with_phases(freq_hz: f64, amplitude_g: [f64; 3], phase_rad: [f64; 3]) -> Vibration {
        let mut v = Vibration::none();
        v.push_tone(vibro_physics::vibration::Tone {
            freq_hz,
            amplitude_g,
            phase_rad,
        })
        .unwrap();
        v
    }

    /// A unit under `aL` plus a tone, read as interval means of (FP) at 64 internal
    /// samples per output sample; the reference as the same interval means.
    fn tone_window(
        p: &Passport,
        a_l: [f64; 3],
        amp_g: [f64; 3],
        phase_rad: [f64; 3],
        freq_hz: f64,
        out_hz: f64,
        seconds: f64,
    ) -> Vec<ReferenceSample> {
        let sub = 64;
        let n = (seconds * out_hz).round() as usize;
        let dt = 1.0 / (out_hz * sub as f64);
        (0..n)
            .map(|i| {
                let mut reading = 0.0;
                let mut sensed = [0.0; 3];
                for k in 0..sub {
                    let t = (i * sub + k) as f64 * dt;
                    let a: [f64; 3] = std::array::from_fn(|j| {
                        a_l[j]
                            + amp_g[j]
                                * (2.0 * std::f64::consts::PI * freq_hz * t + phase_rad[j]).sin()
                    });
                    reading += output_g(p, a[0], a[1], a[2]) / sub as f64;
                    for j in 0..3 {
                        sensed[j] += a[j] / sub as f64;
                    }
                }
                ReferenceSample {
                    reading_g: reading,
                    a_l_unit_g: a_l,
                    a_sensed_unit_g: sensed,
                    linear_g: None,
                }
            })
            .collect()
    }

    /// A window holding whole periods of a tone: the measured VE is the exact model's
    /// (MODEL.md section 6: moments `E[sin^2] = 1/2`, ..., the asymmetry's `E|aL + aB
    /// sin|` in closed form), as long as the tone is slow against the output rate (the
    /// interval means then carry the whole vibration).
    #[test]
    fn a_tone_over_whole_periods_measures_the_exact_ve() {
        let p = al15();
        for (a_l, amp, phase) in [
            ([0.3, -0.2, 2.0], [1.2, 0.8, 0.5], [0.0, 0.3, 0.0]),
            ([0.0, 0.0, 0.2], [0.0, 0.0, 1.5], [0.0; 3]),
            ([0.5, 0.5, -3.0], [0.0, 1.0, 2.0], [0.0, 1.0, -0.5]),
        ] {
            let samples = tone_window(&p, a_l, amp, phase, 8.0, 800.0, 1.0);
            let w = window_ve(&p, &samples, 8, 0).unwrap();
            let vib = tone_with_phases(8.0, amp, phase);
            let want = exact_ve(&p, a_l, &vib).unwrap().total_g;
            assert!(
                (w.ve_g - want).abs() < 1e-4 * want.abs() + 1e-9,
                "aL {a_l:?}: measured {} vs exact {want}",
                w.ve_g
            );
            assert_eq!(w.samples, 800);
            for i in 0..3 {
                assert!((w.a_l_unit_g[i] - a_l[i]).abs() < 1e-12);
            }
        }
    }

    /// Without the linear response to the interval-mean vibration, a fractional number
    /// of periods leaves the tone's own mean in the window: the term is needed, and
    /// with it the VE comes out within the residual of the fractional period.
    #[test]
    fn the_linear_response_removes_a_fractional_periods_mean() {
        let p = al15();
        let (a_l, amp) = ([0.0, 0.0, 2.0], [0.0, 0.0, 0.5]);
        let samples = tone_window(&p, a_l, amp, [0.0; 3], 8.3, 800.0, 1.0);
        let vib = Vibration::single_tone(8.3, amp);
        let want = exact_ve(&p, a_l, &vib).unwrap().total_g;
        let w = window_ve(&p, &samples, 8, 0).unwrap();
        let naive: f64 = samples
            .iter()
            .map(|s| s.reading_g - output_g(&p, 0.0, 0.0, 2.0))
            .sum::<f64>()
            / samples.len() as f64;
        // The tone's mean over 8.3 periods: 0.5 g (1 - cos(2 pi 0.3)) / (2 pi 8.3).
        let tone_mean = 0.5 * (1.0 - (2.0 * std::f64::consts::PI * 0.3).cos())
            / (2.0 * std::f64::consts::PI * 8.3);
        assert!((naive - want - p.k1 * tone_mean).abs() < 0.02 * p.k1 * tone_mean);
        // What is left: the rectified terms' own fractional period, k2 aB^2 / 2 over
        // 2 omega, a few ug at most.
        assert!((w.ve_g - want).abs() < 3e-6, "{} vs {want}", w.ve_g);
    }

    /// Batch means: for independent noise of RMS s on every sample, the uncertainty is
    /// about s / sqrt(n), and the mean over it follows Student's t.
    #[test]
    fn batch_means_give_the_standard_error_of_white_noise() {
        let p = al15();
        let n = 8000;
        let s = 1e-5;
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            // xorshift64*: a reproducible, well-mixed stream.
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut z2 = 0.0;
        let runs = 2000;
        for _ in 0..runs {
            let samples: Vec<ReferenceSample> = (0..n)
                .map(|_| ReferenceSample {
                    reading_g: output_g(&p, 0.0, 0.0, 1.0) + s * 12f64.sqrt() * (next() - 0.5),
                    a_l_unit_g: [0.0, 0.0, 1.0],
                    a_sensed_unit_g: [0.0, 0.0, 1.0],
                    linear_g: None,
                })
                .collect();
            let w = window_ve(&p, &samples, 10, 0).unwrap();
            let expected = s / (n as f64).sqrt();
            assert!(w.u_g > 0.2 * expected && w.u_g < 2.5 * expected);
            z2 += (w.ve_g / w.u_g).powi(2);
        }
        // z = mean / u follows Student's t with 9 dof: E[z^2] = 9/7, and z^2 has the
        // variance E[t^4] - (9/7)^2 = 243/35 - 81/49, so the mean over the runs has a
        // standard error of 0.051: 4 of them allowed.
        let mean_z2 = z2 / runs as f64;
        assert!((mean_z2 - 9.0 / 7.0).abs() < 0.21, "E[z^2] = {mean_z2}");
    }

    /// AL-15 with only its k2 term (set to `k2_ppm_per_g` when given) among the
    /// rectifying ones: VE = k2 (aB3^2 / 2 + sigma3^2) (MODEL.md 6).
    fn k2_only(k2_ppm_per_g: Option<f64>) -> Passport {
        let mut spec = al15().to_spec();
        if let Some(k2) = k2_ppm_per_g {
            spec.k2_ppm_per_g = k2;
        }
        spec.k3_ppm_per_g2 = 0.0;
        spec.k4_ppm_per_g3 = 0.0;
        spec.k5_ppm_per_g4 = 0.0;
        spec.d1a_ppm = 0.0;
        spec.m31_ppm_per_g = 0.0;
        spec.m32_ppm_per_g = 0.0;
        Passport::try_from_spec(&spec).unwrap()
    }

    /// The propagated uncertainty against the closed form: with only k2 and the tone on
    /// IA, VE = 0.5 k2 aB3^2 (MODEL.md 6), so u = k2 aB3 u(aB3); with only k2 and random
    /// IA vibration, VE = k2 sigma3^2, so u = 2 k2 sigma3 u(sigma3).
    #[test]
    fn the_prediction_uncertainty_matches_the_closed_form() {
        let p = k2_only(Some(105.0));
        let k2 = p.k[2];
        let vib = Vibration::single_tone(40.0, [0.0, 0.0, 2.0]);
        let u = VibrationU {
            tone_amplitude_u_g: vec![[0.0, 0.0, 0.01]],
            sigma_u_g: [0.0; 3],
        };
        let got = prediction_u_g(BaseMode::Exact, &p, [0.0, 0.0, 1.0], 0.0, &vib, &u).unwrap();
        let want = k2 * 2.0 * 0.01;
        assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");

        let mut vib = Vibration::none();
        vib.covariance_g2[2][2] = 1.4f64.powi(2);
        let u = VibrationU {
            tone_amplitude_u_g: vec![],
            sigma_u_g: [0.0, 0.0, 0.02],
        };
        let got = prediction_u_g(BaseMode::Exact, &p, [0.0, 0.0, 1.0], 0.0, &vib, &u).unwrap();
        let want = 2.0 * k2 * 1.4 * 0.02;
        assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");

        // aL3 varying over the window: with k3 alone and a tone, VE = 1.5 k3 aB3^2 aL3
        // (linear in aL3: no curvature term), with k4 alone VE = 3 k4 aB3^2 aL3^2 + ...,
        // VE'' = 6 k4 aB3^2, so u = 3 k4 aB3^2 var.
        let mut spec = p.to_spec();
        spec.k2_ppm_per_g = 0.0;
        spec.k4_ppm_per_g3 = 10.0;
        let p = Passport::try_from_spec(&spec).unwrap();
        let vib = Vibration::single_tone(40.0, [0.0, 0.0, 2.0]);
        let none = VibrationU::default();
        let var = 0.04;
        let got = prediction_u_g(BaseMode::Exact, &p, [0.0, 0.0, 3.0], var, &vib, &none).unwrap();
        let want = 3.0 * p.k[4] * 4.0 * var;
        assert!((got - want).abs() < 1e-6 * want, "{got} vs {want}");
    }

    /// Monte Carlo: residuals of independent normal errors `s u_j` (u_j varying over
    /// the flight) on top of a missing effect that ramps with time and jumps twice (at
    /// staging): the estimated scale recovers `s` (its relative standard error over
    /// 600 differences is about sqrt(2/600)/2 = 3 %), and is capped at 1.
    #[test]
    fn the_residual_scale_recovers_the_noise_under_a_smooth_effect_with_jumps() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut uniform = || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            ((state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut normal = move || {
            // Box-Muller.
            let (a, b) = (uniform(), uniform());
            (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
        };
        for s_true in [0.3, 0.5, 0.8] {
            let series: Vec<Vec<(f64, f64)>> = (0..3)
                .map(|unit| {
                    (0..200)
                        .map(|j| {
                            let t = j as f64;
                            let u = 1e-4 * (1.0 + 0.5 * (t / 30.0 + unit as f64).sin().abs());
                            let effect = 2e-3 * t / 200.0
                                + if j >= 70 { 1e-3 } else { 0.0 }
                                + if j >= 140 { -2e-3 } else { 0.0 };
                            (effect + s_true * u * normal(), u)
                        })
                        .collect()
                })
                .collect();
            let got = residual_scale(&series).unwrap();
            assert_eq!(got.differences, 3 * 198);
            // Each jump gives 2 second differences per unit of the jump's size (5 to
            // 30 sigma): the 2 mg jump's 6 are always left out, few others.
            assert!(got.clipped >= 6 && got.clipped <= 30, "{got:?}");
            assert!(
                (got.scale - s_true).abs() < 0.1 * s_true,
                "{s_true}: {got:?}"
            );
        }
        // Wider scatter than stated: a missing effect, not noise.
        let wide: Vec<Vec<(f64, f64)>> = vec![(0..50)
            .map(|j| (if j % 2 == 0 { 3.0 } else { -3.0 }, 1.0))
            .collect()];
        assert_eq!(residual_scale(&wide).unwrap().scale, 1.0);
        assert!(residual_scale(&[vec![(0.0, 1.0); 9]]).is_none());
    }

    /// With only k2 (VE = k2 (aB3^2 / 2 + sigma3^2), MODEL.md 6) the pooled vibration
    /// predicts the mean of the windows' VEs exactly: the pool keeps the second moments.
    /// Rows of a log's unit, in runs: a residual scatter of 0.6 of the stated
    /// uncertainty comes back as the scale (1,000 rows per unit: to 5 %), a jump of
    /// 100 between two runs is not a difference, a unit with too few differences makes
    /// the log pool its units, and rows without a group keep their uncertainty.
    /// Rows weighted by the scale estimated from their own second differences have a
    /// chi2/dof of 1 on average: 4,000 series of 20 independent errors of 0.5 times
    /// the stated uncertainty (Monte Carlo), chi2/dof with the estimated scale within
    /// 4 % of 1 (1.09 without the factor `1 + 2/n`).
    #[test]
    fn rows_weighted_by_their_own_scale_have_a_chi2_per_dof_of_one_on_average() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0, 0.5).unwrap();
        let draws = 4000;
        let mut mean_chi2 = 0.0;
        for _ in 0..draws {
            let run: Vec<(f64, f64)> = (0..20).map(|_| (noise.sample(&mut rng), 1.0)).collect();
            let scale = residual_scale(std::slice::from_ref(&run)).unwrap().scale;
            let chi2 = run
                .iter()
                .map(|(r, u)| (r / (scale * u)).powi(2))
                .sum::<f64>();
            mean_chi2 += chi2 / 20.0 / draws as f64;
        }
        assert!((mean_chi2 - 1.0).abs() < 0.04, "mean chi2/dof {mean_chi2}");
    }

    #[test]
    fn a_log_s_scale_comes_from_its_own_runs() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.6).unwrap();
        let template = condition(WindowInput {
            run_id: "w".into(),
            line: 1,
            passport_ref: "AL-15".into(),
            passport: al15(),
            vibration: Vibration::none(),
            bands: vec![],
            bands_u: vec![],
            measured: WindowVe {
                ve_g: 0.0,
                u_g: 1.0,
                a_l_unit_g: [0.0, 0.0, 1.0],
                a_l_span_g: 0.0,
                a_l3_var_g2: 0.0,
                samples: 800,
            },
            prediction_u_g: 0.0,
            scale_group: None,
            extra: BTreeMap::new(),
        });
        let mut rows = Vec::new();
        let mut residual = Vec::new();
        // Log 0: two units of 1,000 windows in two runs, the second 100 higher.
        for j in 0..1000u32 {
            for unit in 0..2 {
                let mut c = template.clone();
                let run = u32::from(j >= 500);
                c.scale_group = Some(crate::table::ScaleGroup {
                    source: 0,
                    unit,
                    run,
                });
                rows.push(c);
                residual.push(noise.sample(&mut rng) + 100.0 * f64::from(run));
            }
        }
        // Log 1: one unit with 20 windows at 0.6, one with 1,000 at 0.3.
        for (unit, n, sd) in [(0u32, 20, 0.6), (1, 1000, 0.3)] {
            let d = Normal::new(0.0, sd).unwrap();
            for _ in 0..n {
                let mut c = template.clone();
                c.scale_group = Some(crate::table::ScaleGroup {
                    source: 1,
                    unit,
                    run: 0,
                });
                rows.push(c);
                residual.push(d.sample(&mut rng));
            }
        }
        rows.push(template.clone());
        residual.push(50.0);
        let stated: Vec<f64> = rows.iter().map(|c| c.ve_uncertainty_g).collect();
        let (factor, scales) = data_scales(&rows, &residual, &stated);
        assert_eq!(scales.len(), 4);
        for s in &scales[..2] {
            assert!(!s.pooled && s.differences == 996, "{s:?}");
            assert!((s.scale / 0.6 - 1.0).abs() < 0.05, "{s:?}");
        }
        // Log 1 pools: one scale for both units, from all their differences.
        assert!(scales[2].pooled && scales[3].pooled);
        assert_eq!(scales[2].scale, scales[3].scale);
        assert_eq!(scales[2].differences, 18 + 998);
        assert!((0.28..0.36).contains(&scales[2].scale), "{:?}", scales[2]);
        assert_eq!(factor[0], scales[0].scale);
        assert_eq!(factor[1], scales[1].scale);
        assert_eq!(factor[2000], scales[2].scale);
        assert_eq!(*factor.last().unwrap(), 1.0);
    }

    /// Pooled over the neighbours: the mean of `u^2` within the run's reach (2 each
    /// side: 5 in the middle, 3 at the ends), and one window alone unchanged.
    #[test]
    fn a_window_s_variance_pools_its_neighbours() {
        let u = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let got = neighbour_pooled_u(&u, 2);
        let want = |s: &[f64]| (s.iter().map(|x| x * x).sum::<f64>() / s.len() as f64).sqrt();
        assert_eq!(got[0], want(&u[0..3]));
        assert_eq!(got[2], want(&u[0..5]));
        assert_eq!(got[5], want(&u[3..6]));
        assert_eq!(neighbour_pooled_u(&[3.0], 2), vec![3.0]);
        assert_eq!(neighbour_pooled_u(&u, 0), u.to_vec());
    }

    /// The pooled PSDs' uncertainties are those of a mean of independent estimates:
    /// `sqrt(u1^2 + u2^2) / 2` (3 and 4 give 2.5); differing edges pool nothing.
    #[test]
    fn pooled_band_uncertainties_add_in_quadrature() {
        let band = |lo: f64, u: f64| PsdBand {
            f_lo_hz: lo,
            f_hi_hz: 80.0,
            psd_g2_per_hz: [u, 2.0 * u, 0.0],
        };
        let got = pooled_bands_u(&[vec![band(20.0, 3.0)], vec![band(20.0, 4.0)]]).unwrap();
        assert_eq!(got[0].psd_g2_per_hz, [2.5, 5.0, 0.0]);
        assert!(pooled_bands_u(&[vec![band(20.0, 3.0)], vec![band(30.0, 4.0)]]).is_none());
    }

    #[test]
    fn a_pooled_vibration_keeps_the_mean_second_moments() {
        let p = k2_only(None);
        let vibs: Vec<Vibration> = [(0.4, 1.3, 12.0), (0.6, 1.5, 12.5), (0.5, 1.1, 13.0)]
            .iter()
            .map(|&(a, s, f)| {
                let mut v = tone_with_phases(f, [1.0, 1.2, a], [0.3, 0.1, 0.5]);
                v.covariance_g2[2][2] = s * s;
                v.covariance_g2[0][0] = 1.0;
                v.kurtosis = [3.0; 3];
                v
            })
            .collect();
        let ve = |v: &Vibration| exact_ve(&p, [0.0, 0.0, 2.0], v).unwrap().total_g;
        let mean = vibs.iter().map(ve).sum::<f64>() / 3.0;
        let pooled = pooled_vibration(&vibs).unwrap();
        assert!(
            (ve(&pooled) - mean).abs() < 1e-12 * mean,
            "{} vs {mean}",
            ve(&pooled)
        );
        let t = pooled.tones()[0];
        assert!((t.freq_hz - 12.5).abs() < 1e-12);
        assert!((t.phase_rad[0] - t.phase_rad[2] + 0.2).abs() < 1e-12);
        // Different tone counts do not pool.
        assert!(pooled_vibration(&[vibs[0], Vibration::none()]).is_none());
    }

    #[test]
    fn a_condition_keeps_every_tone_and_the_relative_phases() {
        let p = al15();
        let mut vib = tone_with_phases(12.0, [1.2, 1.2, 0.5], [0.1, -0.2, 0.4]);
        vib.push_tone(vibro_physics::vibration::Tone {
            freq_hz: 30.0,
            amplitude_g: [0.0, 0.0, 0.1],
            phase_rad: [0.0; 3],
        })
        .unwrap();
        vib.covariance_g2[2][2] = 1.0;
        vib.covariance_g2[0][0] = 0.5;
        let c = condition(WindowInput {
            run_id: "AK1@1.0s".into(),
            line: 1,
            passport_ref: "AL-15".into(),
            passport: p,
            vibration: vib,
            bands: vec![],
            bands_u: vec![],
            measured: WindowVe {
                ve_g: 1e-3,
                u_g: 3e-6,
                a_l_unit_g: [0.0, 0.0, 2.0],
                a_l_span_g: 0.0,
                a_l3_var_g2: 0.0,
                samples: 800,
            },
            prediction_u_g: 4e-6,
            scale_group: None,
            extra: BTreeMap::new(),
        });
        assert!((c.ve_uncertainty_g - 5e-6).abs() < 1e-18);
        let t = c.tone.unwrap();
        assert!((t.phase31_deg - 0.3f64.to_degrees()).abs() < 1e-12);
        assert!((t.phase32_deg - 0.6f64.to_degrees()).abs() < 1e-12);
        assert_eq!(c.more_tones.len(), 1);
        // The condition's vibration has the same moments the model uses.
        let back = c.vibration();
        let a = exact_ve(&p, [0.0, 0.0, 2.0], &vib).unwrap().total_g;
        let b = exact_ve(&p, [0.0, 0.0, 2.0], &back).unwrap().total_g;
        assert!((a - b).abs() < 1e-15 * a.abs().max(1e-12), "{a} vs {b}");
    }
}
