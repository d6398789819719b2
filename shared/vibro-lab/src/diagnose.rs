//! Where the model fails and which effect is missing.
//!
//! - [`compare`]: per condition the measured and predicted VE, the residual and its
//!   normalised value `z = r/u`; the summary (RMS and largest residual, `chi2` with
//!   `n` degrees of freedom, its p-value, the noise floor = RMS of the
//!   uncertainties), and the residual grouped by each condition variable.
//! - [`diagnose`]: the comparison; the residual against each variable (a weighted fit
//!   of `r` on `1, x, x^2` against the constant, F-test); the lack-of-fit test where
//!   conditions repeat (lack-of-fit against pure-error mean squares, F-test); every
//!   candidate of the library fitted ([`crate::fit`]) and ranked by `delta_bic`; and a
//!   verdict ([`Verdict`]):
//!   1. `noise`: the model as is passes the chi-square test (p >= `alpha_noise`,
//!      default 0.01): nothing is attributed;
//!   2. otherwise a candidate is *supported* when `delta_bic <= -10` (very strong
//!      evidence, Kass & Raftery 1995) and it *explains* the residual when its fit
//!      passes the chi-square test (p >= `alpha_fit`, default 0.001), or when it
//!      leaves at most `model_tolerance` (default 1 %) of the residual's RMS: an
//!      effect's mean formula is a model too, and a large effect's last per-mille
//!      is not evidence of another effect;
//!   3. `confounded`: two or more candidates explain it, within 10 of each other in
//!      BIC, with fitted VE changes nearly collinear over the table (weighted
//!      correlation >= 0.98): the table cannot tell them apart; the conditions where
//!      their fitted predictions differ most are suggested;
//!   4. `effect`: exactly one candidate explains it, or the best one is more than 10
//!      below every other that does;
//!   5. `unexplained`: no candidate explains it: the structure, the variables it
//!      follows, and how much the best candidate would explain.

use crate::fit::{
    chi2_sf, fit_joint, fit_prepared, fit_reweighted, fit_screen, fit_set, Budget, BudgetUsed,
    EffectFit, Meter, NotApplicable, Prepared, Stop,
};
use crate::library::{self, Candidate, LIBRARY};
use crate::table::{CampaignTable, Condition, RandomCondition, ToneCondition};
use crate::{Error, Result};
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};
use std::collections::BTreeMap;
use vibro_effects::model::{FitRecord, LabModel};

/// Most starts of the refit that checks a new effect against the set refitted from
/// other starts (the product of its effects' grids).
const MAX_REFIT_STARTS: usize = 400;

/// Options of [`diagnose`].
#[derive(Debug, Clone, Serialize)]
pub struct DiagnoseOptions {
    /// The model as is is "noise" when its chi2 p-value is at least this.
    pub alpha_noise: f64,
    /// A fit explains the residual when its chi2 p-value is at least this.
    pub alpha_fit: f64,
    /// A candidate is supported when its `delta_bic` is at most this.
    pub bic_support: f64,
    /// A fit explains the residual when it leaves at most this fraction of its RMS.
    pub model_tolerance: f64,
    /// Candidates within this BIC of the best are not told apart by the table.
    pub bic_tie: f64,
    /// Fitted VE changes with a weighted correlation at least this are collinear.
    pub collinear: f64,
    /// The candidates to try (all of the library when empty).
    pub candidates: Vec<String>,
    /// Most effects the stepwise search adds.
    pub max_effects: usize,
    /// Fit and rank the candidates even when the model as is is noise (nothing will
    /// be attributed then; on a flight log the fits of eleven candidates to noise take
    /// minutes). Default false: `candidates` is then empty.
    pub rank_when_noise: bool,
    /// Threads fitting candidates at once.
    pub threads: usize,
    /// Limits on the fits' work: evaluations per candidate, time for all of them. A
    /// candidate the budget stops is reported as not fitted, and
    /// [`Diagnosis::budget`] says so.
    pub budget: Budget,
    /// Told after each candidate's fit (for a progress display).
    #[serde(skip)]
    pub progress: Progress,
    /// Polled by the fits: once requested, the call ends within one model evaluation
    /// with a partial result (the caller who stopped it discards it).
    #[serde(skip)]
    pub stop: Stop,
}

/// What [`Progress`] calls: `(fitted, of, kind)`.
pub type ProgressFn = dyn Fn(usize, usize, &str) + Send + Sync;

/// A callback told `(fitted, of, kind)` after each candidate's fit; none by default.
#[derive(Clone, Default)]
pub struct Progress(pub Option<std::sync::Arc<ProgressFn>>);

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Progress(set)"
        } else {
            "Progress(none)"
        })
    }
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            alpha_noise: 0.01,
            alpha_fit: 1e-3,
            bic_support: -10.0,
            model_tolerance: 0.01,
            bic_tie: 10.0,
            collinear: 0.98,
            candidates: Vec::new(),
            max_effects: 4,
            rank_when_noise: false,
            threads: crate::parallel::available(),
            budget: Budget::default(),
            progress: Progress::default(),
            stop: Stop::default(),
        }
    }
}

/// One condition compared.
#[derive(Debug, Clone, Serialize)]
pub struct RowComparison {
    pub run_id: String,
    pub line: usize,
    pub measured_g: f64,
    pub uncertainty_g: f64,
    pub predicted_g: f64,
    pub residual_g: f64,
    pub z: f64,
    /// Where `predicted_g` came from: `waveform` (the compensator's waveform stage over a
    /// log's samples, [`crate::waveform`]) or `statistics` (`vibro_effects::predict`).
    pub path: &'static str,
    /// On the waveform path, the readings the prediction is the mean of.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub window: Option<crate::waveform::WindowSpan>,
}

/// The whole table compared.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub n: usize,
    /// How many distinct conditions the `n` rows hold (a condition repeated is one):
    /// the model and each effect fitted are evaluated once per distinct condition
    /// (`fit::Prepared`), the statistics are the rows'.
    pub distinct_conditions: usize,
    pub rms_residual_g: f64,
    pub max_abs_residual_g: f64,
    pub rms_measured_g: f64,
    pub chi2: f64,
    pub dof: usize,
    pub chi2_per_dof: f64,
    pub p_value: f64,
    /// RMS of the uncertainties: the smallest RMS residual a right model can have.
    pub noise_floor_g: f64,
}

/// The residual over one group of conditions.
#[derive(Debug, Clone, Serialize)]
pub struct Group {
    pub label: String,
    pub n: usize,
    pub mean_residual_g: f64,
    pub rms_residual_g: f64,
    pub chi2_per_dof: f64,
}

/// The residual grouped by one variable.
#[derive(Debug, Clone, Serialize)]
pub struct ByVariable {
    pub variable: String,
    pub groups: Vec<Group>,
}

/// [`compare`]'s result.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub table: String,
    pub mode: String,
    pub effects: Vec<String>,
    pub rows: Vec<RowComparison>,
    pub summary: Summary,
    pub by_variable: Vec<ByVariable>,
    /// A log's scales per unit on its stated uncertainties, from the residuals against
    /// this model (`flight::data_scales`); empty for campaign tables.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub residual_scales: Vec<crate::flight::GroupScale>,
    /// How many rows each evaluation path predicted.
    pub paths: PathCounts,
    /// Per log evaluated on the waveform path, what became of its readings.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub waveform: Vec<crate::waveform::WaveformCounts>,
}

/// Rows per evaluation path ([`RowComparison::path`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct PathCounts {
    pub waveform: usize,
    pub statistics: usize,
}

/// The residual against one variable.
#[derive(Debug, Clone, Serialize)]
pub struct Trend {
    pub variable: String,
    pub distinct_values: usize,
    /// Fraction of the residual's chi2 (about its weighted mean) that a weighted
    /// quadratic in the variable explains.
    pub explained_fraction: f64,
    /// F-test of the quadratic against the constant.
    pub p_value: f64,
}

/// The lack-of-fit test over repeated conditions.
#[derive(Debug, Clone, Serialize)]
pub struct LackOfFit {
    pub repeated_groups: usize,
    pub lack_of_fit_chi2: f64,
    pub lack_of_fit_dof: usize,
    pub pure_error_chi2: f64,
    pub pure_error_dof: usize,
    /// `(chi2_lof/dof_lof) / (chi2_pe/dof_pe)`.
    pub f: f64,
    pub p_value: f64,
    /// Pure-error chi2 per dof: about 1 when the stated uncertainties are right.
    pub pure_error_chi2_per_dof: f64,
}

/// A candidate's place in the ranking.
#[derive(Debug, Clone, Serialize)]
pub struct RankedCandidate {
    pub kind: String,
    pub physics: String,
    pub signature: String,
    /// The fit, or why the candidate could not be fitted to this table.
    pub fit: Option<EffectFit>,
    pub not_applicable: Option<String>,
    pub supported: bool,
    pub explains: bool,
}

/// A condition to add to tell confounded candidates apart.
#[derive(Debug, Clone, Serialize)]
pub struct Suggestion {
    pub description: String,
    /// Each candidate's fitted VE change there, g.
    pub predictions_g: Vec<(String, f64)>,
    /// Largest difference between two of them over the table's median uncertainty.
    pub separation_sigma: f64,
}

/// The conclusion.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "verdict", rename_all = "snake_case")]
pub enum Verdict {
    Noise {
        p_value: f64,
        chi2_per_dof: f64,
    },
    /// The effects found explain the residual (one or several, fitted jointly).
    Effect {
        /// The first effect found (the largest step).
        kind: String,
        /// Every effect found, in the order added.
        kinds: Vec<String>,
        params: Vec<crate::fit::FittedParam>,
        /// Correlation coefficients between `params`.
        correlation: Vec<Vec<f64>>,
        delta_bic: f64,
        rms_residual_before_g: f64,
        rms_residual_after_g: f64,
        chi2_per_dof_after: f64,
        /// `kind: physics` of each effect.
        physics: Vec<String>,
    },
    /// The table cannot tell `kinds` apart (after the effects `found` before).
    Confounded {
        kinds: Vec<String>,
        correlation: f64,
        suggestions: Vec<Suggestion>,
        found: Vec<String>,
    },
    /// Structure no candidate explains: nothing found, or the effects `found` explain
    /// part of it (`found_explained_fraction` of the chi2) and the rest follows
    /// `variables`.
    Unexplained {
        /// After the effects found.
        chi2_per_dof: f64,
        variables: Vec<String>,
        /// The best candidate left (not supported), and the fraction of the chi2
        /// left that it would remove.
        best: Option<String>,
        best_explained_fraction: f64,
        found: Vec<String>,
        found_explained_fraction: f64,
    },
}

/// [`diagnose`]'s result.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    pub comparison: Comparison,
    /// The residual of the model as is against each variable.
    pub trends: Vec<Trend>,
    /// The same after the effects found (empty when none was).
    pub trends_after: Vec<Trend>,
    pub lack_of_fit: Option<LackOfFit>,
    /// The first round: every candidate alone against the model as is, best first.
    pub candidates: Vec<RankedCandidate>,
    /// The stepwise search: the model as is, then each addition and removal.
    pub steps: Vec<Step>,
    /// The joint fit of the effects found (none: nothing was supported).
    pub selected: Option<EffectFit>,
    /// The model's own effects that could not act on some rows (left out there).
    pub not_applicable: Vec<NotApplicable>,
    pub verdict: Verdict,
    pub options: DiagnoseOptions,
    /// How much of `options.budget` the fits used, and whether it ran out.
    pub budget: BudgetUsed,
    /// Beyond the library (verdict `unexplained` only): an empirical correction of
    /// the residual left, not physical, chosen by cross-validation
    /// ([`crate::empirical`]).
    pub empirical: Option<crate::empirical::EmpiricalFit>,
    /// Why no empirical correction is offered where the verdict is `unexplained`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub empirical_none: Option<String>,
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (s / n.max(1) as f64).sqrt()
}

/// A label for a value in a group: 4 significant digits (a measured amplitude of
/// 2.99998 g is the 3 g condition).
fn label(x: f64) -> String {
    if x.is_nan() {
        "-".into()
    } else if x == 0.0 {
        "0".into()
    } else {
        let digits = 3 - x.abs().log10().floor() as i32;
        let scale = 10f64.powi(digits);
        format!("{}", (x * scale).round() / scale)
    }
}

/// Numeric order of group labels (`-` last, ranges by their lower end).
fn label_order(a: &str, b: &str) -> std::cmp::Ordering {
    let v = |s: &str| {
        s.split("..")
            .next()
            .and_then(|x| x.parse::<f64>().ok())
            .unwrap_or(f64::INFINITY)
    };
    v(a).total_cmp(&v(b)).then_with(|| a.cmp(b))
}

fn groups_of(rows: &[RowComparison], keys: &[String]) -> Vec<Group> {
    let mut by: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, k) in keys.iter().enumerate() {
        by.entry(k.as_str()).or_default().push(i);
    }
    let mut by: Vec<(&str, Vec<usize>)> = by.into_iter().collect();
    by.sort_by(|a, b| label_order(a.0, b.0));
    by.into_iter()
        .map(|(k, idx)| {
            let n = idx.len();
            Group {
                label: k.to_string(),
                n,
                mean_residual_g: idx.iter().map(|&i| rows[i].residual_g).sum::<f64>() / n as f64,
                rms_residual_g: rms(idx.iter().map(|&i| rows[i].residual_g)),
                chi2_per_dof: idx.iter().map(|&i| rows[i].z * rows[i].z).sum::<f64>() / n as f64,
            }
        })
        .collect()
}

/// Compares `model` with `table` on the statistics path (every row's VE predicted from
/// its stated vibration, `vibro_effects::predict`): what the fits of `diagnose` and
/// `add` use.
pub fn compare(model: &LabModel, table: &CampaignTable) -> Result<Comparison> {
    let prep = Prepared::new(model, table)?;
    let mut c = comparison_of(model, table, &prep, &[]);
    c.residual_scales = prep.scales;
    Ok(c)
}

/// Compares `model` with `table` as the compensator evaluates it (`lab compare`): the
/// windows of the logs in `logs` (their summaries from `inputs::load`) predicted by the
/// waveform stage over the logs' samples ([`crate::waveform`]), the other rows (tables,
/// manifests, windows the samples do not cover) on the statistics path. The stated
/// uncertainties and the logs' scales are as [`compare`]'s, the scales from the
/// residuals against these predictions.
pub fn compare_evaluated(
    model: &LabModel,
    table: &CampaignTable,
    logs: &[crate::log_table::LogTableSummary],
) -> Result<Comparison> {
    let n = table.conditions.len();
    let mut given: Vec<Option<crate::waveform::WaveformPrediction>> = vec![None; n];
    let mut counts = Vec::new();
    for log in logs {
        let Some(w) = &log.waveform else {
            continue;
        };
        let (predicted, c) = crate::waveform::predict_log(model, w, log.conditions)?;
        counts.push(c);
        for (i, p) in predicted.into_iter().enumerate() {
            if let (Some(p), Some(slot)) = (p, given.get_mut(log.first_row + i)) {
                *slot = Some(p);
            }
        }
    }
    let given_g: Vec<Option<f64>> = given.iter().map(|g| g.map(|g| g.ve_g)).collect();
    // The rows of a log on each path have their own scales (`flight::data_scales`):
    // a waveform row's residual scatters far less than a statistics row's, and one
    // scale over both would state the statistics rows' uncertainty by the waveform's.
    let waveform_sources: std::collections::BTreeSet<u32> = table
        .conditions
        .iter()
        .zip(&given)
        .filter(|(_, g)| g.is_some())
        .filter_map(|(c, _)| c.scale_group.map(|g| g.source))
        .collect();
    let mut split = table.clone();
    for (c, g) in split.conditions.iter_mut().zip(&given) {
        if let (Some(s), None) = (c.scale_group.as_mut(), g) {
            if waveform_sources.contains(&s.source) {
                s.source += STATISTICS_SOURCE;
            }
        }
    }
    let prep = Prepared::with_predictions(model, &split, &given_g)?;
    let mut c = comparison_of(model, &split, &prep, &given);
    c.residual_scales = prep.scales;
    for s in &mut c.residual_scales {
        if s.source >= STATISTICS_SOURCE {
            s.source -= STATISTICS_SOURCE;
            s.path = Some(crate::waveform::PATH_STATISTICS);
        } else if waveform_sources.contains(&s.source) {
            s.path = Some(crate::waveform::PATH_WAVEFORM);
        }
    }
    c.waveform = counts;
    Ok(c)
}

/// Added to the scale group's source of a log's rows left on the statistics path
/// ([`compare_evaluated`]); a joint table's inputs are numbered from 0.
const STATISTICS_SOURCE: u32 = 1 << 24;

/// The comparison; `u_g` the rows' standard uncertainties of the residual (the
/// measured VE's with the stated vibration's propagated through the model).
/// `given[i]`: row `i`'s prediction came from the waveform stage (none: every row's
/// from the statistics).
fn comparison_of(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    given: &[Option<crate::waveform::WaveformPrediction>],
) -> Comparison {
    let (predicted_g, u_g) = (&prep.predicted_g, &prep.uncertainty_g);
    let rows: Vec<RowComparison> = table
        .conditions
        .iter()
        .zip(predicted_g)
        .zip(u_g)
        .enumerate()
        .map(|(i, ((c, p), u))| {
            let window = given.get(i).copied().flatten().map(|g| g.span);
            let r = c.ve_measured_g - p;
            RowComparison {
                run_id: c.run_id.clone(),
                line: c.line,
                measured_g: c.ve_measured_g,
                uncertainty_g: *u,
                predicted_g: *p,
                residual_g: r,
                z: r / u,
                path: if window.is_some() {
                    crate::waveform::PATH_WAVEFORM
                } else {
                    crate::waveform::PATH_STATISTICS
                },
                window,
            }
        })
        .collect();
    let n = rows.len();
    let waveform_rows = rows.iter().filter(|r| r.window.is_some()).count();
    let chi2: f64 = rows.iter().map(|r| r.z * r.z).sum();
    let summary = Summary {
        n,
        distinct_conditions: prep.classes(),
        rms_residual_g: rms(rows.iter().map(|r| r.residual_g)),
        max_abs_residual_g: rows.iter().map(|r| r.residual_g.abs()).fold(0.0, f64::max),
        rms_measured_g: rms(rows.iter().map(|r| r.measured_g)),
        chi2,
        dof: n,
        chi2_per_dof: chi2 / n.max(1) as f64,
        p_value: chi2_sf(chi2, n),
        noise_floor_g: rms(rows.iter().map(|r| r.uncertainty_g)),
    };
    let mut by_variable = Vec::new();
    let direction: Vec<String> = table.conditions.iter().map(Condition::direction).collect();
    by_variable.push(ByVariable {
        variable: "direction".into(),
        groups: groups_of(&rows, &direction),
    });
    for (name, xs) in table.variable_columns() {
        let keys: Vec<String> = xs.iter().map(|x| label(*x)).collect();
        let distinct = keys.iter().collect::<std::collections::BTreeSet<_>>().len();
        if distinct < 2 {
            continue;
        }
        let keys = if distinct > 8 {
            // Quantile bins of the finite values.
            let mut sorted: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
            sorted.sort_by(f64::total_cmp);
            let edges: Vec<f64> = (1..6).map(|q| sorted[q * (sorted.len() - 1) / 6]).collect();
            xs.iter()
                .map(|x| {
                    if !x.is_finite() {
                        return "-".to_string();
                    }
                    let b = edges.iter().filter(|e| *x > **e).count();
                    let lo = if b == 0 { sorted[0] } else { edges[b - 1] };
                    let hi = if b == edges.len() {
                        sorted[sorted.len() - 1]
                    } else {
                        edges[b]
                    };
                    format!("{}..{}", label(lo), label(hi))
                })
                .collect()
        } else {
            keys
        };
        by_variable.push(ByVariable {
            variable: name.clone(),
            groups: groups_of(&rows, &keys),
        });
    }
    Comparison {
        table: table.path.display().to_string(),
        mode: model.mode.name().into(),
        effects: model.effect_kinds(),
        rows,
        summary,
        by_variable,
        residual_scales: Vec::new(),
        paths: PathCounts {
            waveform: waveform_rows,
            statistics: n - waveform_rows,
        },
        waveform: Vec::new(),
    }
}

/// Weighted least squares of `y` on the columns of `x` (weights `w`): the chi2 left.
fn wls_chi2(x: &[Vec<f64>], y: &[f64], w: &[f64]) -> Option<f64> {
    let n = y.len();
    let k = x.len();
    let a = nalgebra::DMatrix::from_fn(n, k, |i, j| x[j][i] * w[i].sqrt());
    let b = nalgebra::DVector::from_fn(n, |i, _| y[i] * w[i].sqrt());
    // nalgebra's SVD panics (or iterates without end) on NaN and infinities.
    if !(a.iter().chain(b.iter()).all(|x| x.is_finite())
        && (a.transpose() * &a).iter().all(|x| x.is_finite()))
    {
        return None;
    }
    let sol = a.clone().svd(true, true).solve(&b, 1e-12).ok()?;
    Some((a * sol - b).norm_squared())
}

fn trends(table: &CampaignTable, residual_g: &[f64], u_g: &[f64]) -> Vec<Trend> {
    let mut out = Vec::new();
    for (name, xs) in table.variable_columns() {
        let pts: Vec<(f64, f64, f64)> = xs
            .iter()
            .zip(residual_g)
            .zip(u_g)
            .map(|((x, r), u)| (*x, *r, *u))
            .filter(|(x, _, _)| x.is_finite())
            .collect();
        let distinct = pts
            .iter()
            .map(|p| label(p.0))
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        if distinct < 3 || pts.len() < 5 {
            continue;
        }
        let (mean, sd) = {
            let m = pts.iter().map(|p| p.0).sum::<f64>() / pts.len() as f64;
            let s = (pts.iter().map(|p| (p.0 - m).powi(2)).sum::<f64>() / pts.len() as f64).sqrt();
            (m, s.max(1e-300))
        };
        let xs: Vec<f64> = pts.iter().map(|p| (p.0 - mean) / sd).collect();
        let y: Vec<f64> = pts.iter().map(|p| p.1).collect();
        let w: Vec<f64> = pts.iter().map(|p| 1.0 / (p.2 * p.2)).collect();
        let ones = vec![1.0; xs.len()];
        let sq: Vec<f64> = xs.iter().map(|x| x * x).collect();
        let (Some(c0), Some(c2)) = (
            wls_chi2(std::slice::from_ref(&ones), &y, &w),
            wls_chi2(&[ones.clone(), xs.clone(), sq], &y, &w),
        ) else {
            continue;
        };
        let dof2 = pts.len() - 3;
        let f = ((c0 - c2) / 2.0) / (c2 / dof2 as f64).max(1e-300);
        let p = FisherSnedecor::new(2.0, dof2 as f64).map_or(f64::NAN, |d| d.sf(f.max(0.0)));
        out.push(Trend {
            variable: name.clone(),
            distinct_values: distinct,
            explained_fraction: if c0 > 0.0 { (c0 - c2) / c0 } else { 0.0 },
            p_value: p,
        });
    }
    out.sort_by(|a, b| a.p_value.total_cmp(&b.p_value));
    out
}

/// The key of a condition for repeats: everything but the measurement.
fn condition_key(c: &Condition) -> String {
    let mut k = format!(
        "{}|{:?}|{:?}|{:?}|{:?}|{:?}",
        c.passport_ref, c.a_l_g, c.tone, c.more_tones, c.random, c.bands
    );
    for (n, x) in &c.extra {
        if n != "tp" && n != crate::table::A_B3_U_COLUMN && n != crate::table::SIGMA3_U_COLUMN {
            k.push_str(&format!("|{n}={x}"));
        }
    }
    k
}

fn lack_of_fit(table: &CampaignTable, residual_g: &[f64], u_g: &[f64]) -> Option<LackOfFit> {
    let mut groups: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (i, c) in table.conditions.iter().enumerate() {
        groups.entry(condition_key(c)).or_default().push(i);
    }
    let repeated = groups.values().filter(|g| g.len() > 1).count();
    if repeated == 0 {
        return None;
    }
    let (mut lof, mut pe, mut pe_dof) = (0.0, 0.0, 0usize);
    for idx in groups.values() {
        let w: f64 = idx.iter().map(|&i| 1.0 / (u_g[i] * u_g[i])).sum();
        let mean = idx
            .iter()
            .map(|&i| residual_g[i] / (u_g[i] * u_g[i]))
            .sum::<f64>()
            / w;
        lof += w * mean * mean;
        pe += idx
            .iter()
            .map(|&i| ((residual_g[i] - mean) / u_g[i]).powi(2))
            .sum::<f64>();
        pe_dof += idx.len() - 1;
    }
    let lof_dof = groups.len();
    let f = (lof / lof_dof as f64) / (pe / pe_dof as f64).max(1e-300);
    Some(LackOfFit {
        repeated_groups: repeated,
        lack_of_fit_chi2: lof,
        lack_of_fit_dof: lof_dof,
        pure_error_chi2: pe,
        pure_error_dof: pe_dof,
        f,
        p_value: FisherSnedecor::new(lof_dof as f64, pe_dof as f64).map_or(f64::NAN, |d| d.sf(f)),
        pure_error_chi2_per_dof: pe / pe_dof as f64,
    })
}

fn selected(opts: &DiagnoseOptions) -> Result<Vec<&'static Candidate>> {
    if opts.candidates.is_empty() {
        return Ok(LIBRARY.iter().collect());
    }
    opts.candidates
        .iter()
        .map(|k| {
            library::candidate(k).ok_or_else(|| {
                Error::Invalid(format!(
                    "effect {k:?}: not in the lab's library ({})",
                    library::kinds().join(", ")
                ))
            })
        })
        .collect()
}

/// The effects chosen so far and their fitted values (the starts of the next fits).
struct Chosen {
    terms: Vec<&'static Candidate>,
    values: Vec<Vec<f64>>,
}

/// Candidates of a round refitted with every parameter free after the screening.
const FULL_REFITS: usize = 3;

/// Every candidate of `cands` fitted jointly with the `chosen` effects, `threads` at
/// once. With effects chosen, each candidate is screened first ([`fit_screen`]: the
/// chosen effects' nonlinear parameters held at their values, every linear one
/// solved), and the [`FULL_REFITS`] best by BIC and every candidate that acts on the
/// others' inputs (`Candidate::acts_on_inputs`) are refitted with every parameter
/// free from there: the others' screening fits stand (their BIC an upper bound).
#[allow(clippy::too_many_arguments)]
fn fit_round(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    chosen: &Chosen,
    cands: &[&'static Candidate],
    threads: usize,
    progress: &Progress,
    meter: &Meter,
) -> Vec<(&'static Candidate, Result<EffectFit>)> {
    let screened = fit_each(model, table, prep, chosen, cands, threads, progress, meter);
    if chosen.terms.is_empty() {
        return screened;
    }
    let mut order: Vec<usize> = (0..screened.len())
        .filter(|&i| screened[i].1.is_ok())
        .collect();
    let bic = |i: usize| {
        screened[i]
            .1
            .as_ref()
            .map_or(f64::INFINITY, |f| f.bic_after)
    };
    order.sort_by(|a, b| bic(*a).total_cmp(&bic(*b)));
    // The best by screening, and every candidate that changes what the chosen
    // effects see: its screening (their nonlinear parameters held) understates it.
    // Seen on a saturation + sensor gain member: the sensor ranked fifth by
    // screening, k6, a unit response and more were added and removed first (40 s).
    let mut k = 0;
    order.retain(|&i| {
        k += 1;
        k <= FULL_REFITS || screened[i].0.acts_on_inputs
    });
    let refits = crate::parallel::in_parallel(&order, threads, |_, &i| {
        let f = screened[i].1.as_ref().ok()?;
        let terms: Vec<&'static Candidate> = f
            .kinds
            .iter()
            .filter_map(|k| library::candidate(k))
            .collect();
        let known: Vec<Option<Vec<f64>>> = f.kinds.iter().map(|k| Some(f.values_of(k))).collect();
        Some((i, fit_joint(model, table, prep, &terms, &known, meter)))
    });
    let mut out = screened;
    for (i, r) in refits.into_iter().flatten() {
        match (&out[i].1, r) {
            (Ok(old), Ok(new)) if new.chi2_after <= old.chi2_after => out[i].1 = Ok(new),
            (_, Err(e @ Error::Budget { .. })) => out[i].1 = Err(e),
            _ => {}
        }
    }
    out
}

/// Every candidate of `cands` screened with the `chosen` effects ([`fit_screen`]),
/// `threads` at once.
#[allow(clippy::too_many_arguments)]
fn fit_each(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    chosen: &Chosen,
    cands: &[&'static Candidate],
    threads: usize,
    progress: &Progress,
    meter: &Meter,
) -> Vec<(&'static Candidate, Result<EffectFit>)> {
    let fitted = std::sync::atomic::AtomicUsize::new(0);
    crate::parallel::in_parallel(cands, threads, |_, c| {
        let mut terms = chosen.terms.clone();
        terms.push(c);
        let mut known: Vec<Option<Vec<f64>>> = chosen.values.iter().cloned().map(Some).collect();
        known.push(None);
        let r = fit_screen(model, table, prep, &terms, &known, meter);
        if let Some(f) = &progress.0 {
            let done = fitted.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            f(done, cands.len(), c.kind);
        }
        (*c, r)
    })
}

/// First-round fits whose VE changes correlate at least this with an earlier effect's
/// are its twins, tried in its place ([`best_swap`]).
const SWAP_TWIN: f64 = 0.9;

/// The best replacement of an earlier chosen effect (not the last added) by a twin
/// ([`SWAP_TWIN`]): the set with the twin in its place fitted jointly (the others
/// from their values, the twin from its grid); `(position, fit)` when it lowers the
/// BIC of `cur` by more than `-bic_support`.
#[allow(clippy::too_many_arguments)]
fn best_swap(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    chosen: &Chosen,
    cur: &EffectFit,
    candidates: &[RankedCandidate],
    opts: &DiagnoseOptions,
    meter: &Meter,
) -> Option<(usize, EffectFit)> {
    let first = |kind: &str| {
        candidates
            .iter()
            .find(|c| c.kind == kind)
            .and_then(|c| c.fit.as_ref())
            .and_then(|f| f.effect_shift_g.last().cloned())
    };
    // Every (position, twin) pair, fitted side by side, then taken in order.
    let mut swaps: Vec<(usize, &'static Candidate)> = Vec::new();
    for at in 0..chosen.terms.len() - 1 {
        let Some(own) = first(chosen.terms[at].kind) else {
            continue;
        };
        for c in candidates {
            if chosen.terms.iter().any(|t| t.kind == c.kind) {
                continue;
            }
            let Some(twin) = first(&c.kind) else { continue };
            if correlation(&own, &twin, &prep.uncertainty_g).abs() < SWAP_TWIN {
                continue;
            }
            if let Some(cand) = library::candidate(&c.kind) {
                swaps.push((at, cand));
            }
        }
    }
    let fits = crate::parallel::in_parallel(&swaps, opts.threads, |_, &(at, cand)| {
        let mut terms = chosen.terms.clone();
        let mut known: Vec<Option<Vec<f64>>> = chosen.values.iter().cloned().map(Some).collect();
        terms[at] = cand;
        known[at] = None;
        fit_joint(model, table, prep, &terms, &known, meter).ok()
    });
    let mut best: Option<(usize, EffectFit)> = None;
    for ((at, _), g) in swaps.iter().zip(fits) {
        let Some(g) = g else { continue };
        let bar = best
            .as_ref()
            .map_or(cur.bic_after + opts.bic_support, |b| b.1.bic_after);
        if g.bic_after < bar {
            best = Some((*at, g));
        }
    }
    best
}

/// The round of every candidate of `cands` not chosen yet ([`fit_round`]).
fn next_round(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    chosen: &Chosen,
    cands: &[&'static Candidate],
    opts: &DiagnoseOptions,
    meter: &Meter,
) -> Vec<(&'static Candidate, Result<EffectFit>)> {
    let rest: Vec<&'static Candidate> = cands
        .iter()
        .copied()
        .filter(|c| !chosen.terms.iter().any(|t| t.kind == c.kind))
        .collect();
    fit_round(
        model,
        table,
        prep,
        chosen,
        &rest,
        opts.threads,
        &opts.progress,
        meter,
    )
}

/// `step`'s figures set to those of `fit` (the set's fit after a refit).
fn restate(step: Option<&mut Step>, fit: &EffectFit) {
    if let Some(st) = step {
        st.chi2 = fit.chi2_after;
        st.chi2_per_dof = fit.chi2_per_dof_after;
        st.p_value = fit.p_value_after;
        st.bic = fit.bic_after;
        st.rms_residual_g = fit.rms_residual_after_g;
    }
}

/// Weighted correlation of two fitted VE changes (weights `1/u^2`, about zero: the
/// changes are compared as shapes through the origin).
fn correlation(a: &[f64], b: &[f64], u: &[f64]) -> f64 {
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for i in 0..a.len() {
        let w = 1.0 / (u[i] * u[i]);
        ab += w * a[i] * b[i];
        aa += w * a[i] * a[i];
        bb += w * b[i] * b[i];
    }
    ab / (aa * bb).sqrt().max(1e-300)
}

/// Conditions not in the table where the fitted candidates differ most: every tested
/// condition with the tone frequency x 0.25, 0.5, 2, 4, the amplitudes x 0.5, 2, the
/// flight acceleration on IA at -1, 0, +1 g (the unit turned), and the vibration on
/// IA alone or with OA and PA at the IA amplitude.
fn suggestions(model: &LabModel, table: &CampaignTable, fits: &[&EffectFit]) -> Vec<Suggestion> {
    let mut u: Vec<f64> = table
        .conditions
        .iter()
        .map(|c| c.ve_uncertainty_g)
        .collect();
    u.sort_by(f64::total_cmp);
    let u_med = u[u.len() / 2];
    let mut variants: Vec<(String, Condition)> = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for c in &table.conditions {
        let mut push = |what: String, v: Condition| {
            if seen.insert(condition_key(&v)) {
                variants.push((what, v));
            }
        };
        if let Some(t) = c.tone {
            for f in [0.25, 0.5, 2.0, 4.0] {
                let mut v = c.clone();
                v.tone = Some(ToneCondition {
                    freq_hz: t.freq_hz * f,
                    ..t
                });
                push(
                    format!("as {} with the tone at {:.4} Hz", c.run_id, t.freq_hz * f),
                    v,
                );
            }
            for f in [0.5, 2.0] {
                let mut v = c.clone();
                v.tone = Some(ToneCondition {
                    a_b_g: t.a_b_g.map(|a| a * f),
                    ..t
                });
                push(format!("as {} with the tone amplitudes x {f}", c.run_id), v);
            }
            let mut v = c.clone();
            v.tone = Some(ToneCondition {
                a_b_g: [t.a_b_g[2]; 3],
                ..t
            });
            push(
                format!("as {} with {:.3} g on OA, PA and IA", c.run_id, t.a_b_g[2]),
                v,
            );
        }
        if let Some(r) = c.random {
            for f in [0.5, 2.0] {
                let mut v = c.clone();
                v.random = Some(RandomCondition {
                    sigma_g: r.sigma_g.map(|s| s * f),
                    cov31_g2: r.cov31_g2 * f * f,
                    cov32_g2: r.cov32_g2 * f * f,
                    cov12_g2: r.cov12_g2 * f * f,
                    ..r
                });
                for b in &mut v.bands {
                    b.psd_g2_per_hz = b.psd_g2_per_hz.map(|x| x * f * f);
                }
                push(format!("as {} with the random RMS x {f}", c.run_id), v);
            }
        }
        for a in [-1.0, 0.0, 1.0] {
            let mut v = c.clone();
            v.a_l_g = [0.0, 0.0, a];
            push(
                format!(
                    "as {} with aL3 = {a} g (IA along gravity: TP turned)",
                    c.run_id
                ),
                v,
            );
        }
    }
    let mut out = Vec::new();
    for (what, v) in variants {
        let probe = CampaignTable {
            path: table.path.clone(),
            conditions: vec![v],
            extra_columns: table.extra_columns.clone(),
        };
        let Ok(prep) = Prepared::new(model, &probe) else {
            continue;
        };
        let mut preds = Vec::new();
        for f in fits {
            let Some(terms) = f
                .kinds
                .iter()
                .map(|k| library::candidate(k))
                .collect::<Option<Vec<&'static Candidate>>>()
            else {
                continue;
            };
            let theta: Vec<f64> = f.params.iter().map(|p| p.value).collect();
            if let Ok(s) = crate::fit::term_shifts_g(model, &probe, &prep, &terms, &theta) {
                preds.push((f.kind.clone(), s.iter().map(|e| e[0]).sum()));
            }
        }
        if preds.len() != fits.len() {
            continue;
        }
        let max = preds.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        let min = preds.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        out.push(Suggestion {
            description: what,
            predictions_g: preds,
            separation_sigma: (max - min) / u_med,
        });
    }
    out.sort_by(|a, b| b.separation_sigma.total_cmp(&a.separation_sigma));
    out.truncate(5);
    out
}

/// Whether a fit explains the residual it was fitted to (module doc, rule 2).
/// Whether a fit explains the residual it was fitted to (module doc, rule 2): its
/// chi-square passes (p >= `alpha_fit`) once each row's uncertainty includes the
/// effects' own model uncertainty, `model_tolerance` times the VE change they make
/// there (a mean formula is a model too: a saturation's 60 mg met to 40 ug is not
/// evidence of another effect, while an effect where the found ones change nothing
/// still counts in full).
fn explains(f: &EffectFit, u_g: &[f64], opts: &DiagnoseOptions) -> bool {
    tolerant_p(f, u_g, opts) >= opts.alpha_fit
}

/// The p-value of `f`'s residual with the effects' model uncertainty added to `u_g`.
fn tolerant_p(f: &EffectFit, u_g: &[f64], opts: &DiagnoseOptions) -> f64 {
    let chi2: f64 = f
        .residual_after_g
        .iter()
        .zip(&f.shift_g)
        .zip(u_g)
        .map(|((r, s), u)| r * r / (u * u + (opts.model_tolerance * s).powi(2)))
        .sum();
    chi2_sf(chi2, f.n.saturating_sub(f.k).max(1))
}

/// One step of the stepwise search ([`Diagnosis::steps`]).
#[derive(Debug, Clone, Serialize)]
pub struct Step {
    /// What the step did: `model as is`, `add KIND`, `remove KIND`.
    pub action: String,
    /// The effects chosen after the step, in the order added.
    pub effects: Vec<String>,
    /// BIC after the step minus BIC before it (0 for the model as is).
    pub delta_bic: f64,
    pub bic: f64,
    pub chi2: f64,
    pub chi2_per_dof: f64,
    pub p_value: f64,
    pub rms_residual_g: f64,
    /// At an addition, the other candidates of the round, `(kind, delta BIC against
    /// the set before the step)`, best first (at most four); at a removal, the BIC
    /// cost of removing each other chosen effect.
    pub runners_up: Vec<(String, f64)>,
}

fn step_from(action: String, f: &EffectFit, bic_before: f64) -> Step {
    Step {
        action,
        effects: f.kinds.clone(),
        delta_bic: f.bic_after - bic_before,
        bic: f.bic_after,
        chi2: f.chi2_after,
        chi2_per_dof: f.chi2_per_dof_after,
        p_value: f.p_value_after,
        rms_residual_g: f.rms_residual_after_g,
        runners_up: Vec::new(),
    }
}

/// Where `model` fails on `table` and which effects are missing (module doc).
pub fn diagnose(
    model: &LabModel,
    table: &CampaignTable,
    opts: &DiagnoseOptions,
) -> Result<Diagnosis> {
    let cands = selected(opts)?;
    let mut prep = Prepared::new(model, table)?;
    let comparison = comparison_of(model, table, &prep, &[]);
    let residual_g = prep.residual_g();
    let trends_before = trends(table, &residual_g, &prep.uncertainty_g);
    let lack_of_fit = lack_of_fit(table, &residual_g, &prep.uncertainty_g);
    let meter = Meter::stoppable(opts.budget, opts.stop.clone());
    let mut cut_short = Vec::new();
    let s = comparison.summary.clone();
    let rms0 = s.rms_residual_g;
    let mut chosen = Chosen {
        terms: Vec::new(),
        values: Vec::new(),
    };
    let mut steps = vec![Step {
        action: "model as is".into(),
        effects: Vec::new(),
        delta_bic: 0.0,
        bic: s.chi2,
        chi2: s.chi2,
        chi2_per_dof: s.chi2_per_dof,
        p_value: s.p_value,
        rms_residual_g: rms0,
        runners_up: Vec::new(),
    }];
    // Round 1: every candidate alone, against the model as is (the ranking shown);
    // none when the model as is is noise, unless asked for.
    let noise = s.p_value >= opts.alpha_noise;
    let mut round = if noise && !opts.rank_when_noise {
        Vec::new()
    } else {
        fit_round(
            model,
            table,
            &prep,
            &chosen,
            &cands,
            opts.threads,
            &opts.progress,
            &meter,
        )
    };
    let note_cut = |r: &[(&'static Candidate, Result<EffectFit>)], cut: &mut Vec<String>| {
        for (c, f) in r {
            if matches!(f, Err(Error::Budget { .. })) && !cut.iter().any(|k| k == c.kind) {
                cut.push(c.kind.to_string());
            }
        }
    };
    note_cut(&round, &mut cut_short);
    meter.close_stage("first round");
    let mut candidates: Vec<RankedCandidate> = round
        .iter()
        .map(|(c, r)| {
            let (fit, not_applicable) = match r {
                Ok(f) => (Some(f.clone()), None),
                Err(e) => (None, Some(e.to_string())),
            };
            let supported = fit
                .as_ref()
                .is_some_and(|f| f.delta_bic <= opts.bic_support);
            let explains = supported
                && fit
                    .as_ref()
                    .is_some_and(|f| explains(f, &prep.uncertainty_g, opts));
            RankedCandidate {
                kind: c.kind.into(),
                physics: c.physics.into(),
                signature: c.signature.into(),
                fit,
                not_applicable,
                supported,
                explains,
            }
        })
        .collect();
    candidates.sort_by(|a, b| {
        let key = |c: &RankedCandidate| c.fit.as_ref().map_or(f64::INFINITY, |f| f.delta_bic);
        key(a).total_cmp(&key(b))
    });

    let mut current: Option<EffectFit> = None;
    let mut confounded: Option<(Vec<EffectFit>, f64)> = None;
    let mut best_left: Option<EffectFit> = None;
    // The set sizes whose set was refitted from every start already.
    let mut refitted: Vec<usize> = Vec::new();
    // Once the set explains the residual to `model_tolerance`: its chi2 and the part
    // of it above its degrees of freedom.
    let mut tolerated: Option<(f64, f64)> = None;
    if s.p_value < opts.alpha_noise {
        let max_steps = opts.max_effects + 2;
        for _ in 0..max_steps {
            let bic_now = current.as_ref().map_or(s.chi2, |f| f.bic_after);
            let mut ok: Vec<&EffectFit> =
                round.iter().filter_map(|(_, r)| r.as_ref().ok()).collect();
            ok.sort_by(|a, b| a.bic_after.total_cmp(&b.bic_after));
            let Some(best) = ok.first().copied() else {
                break;
            };
            let too_little =
                tolerated.is_some_and(|(chi2, excess)| chi2 - best.chi2_after < 0.5 * excess);
            if best.bic_after - bic_now > opts.bic_support || too_little {
                best_left = Some(best.clone());
                break;
            }
            // The alternative to a new effect: the set as it is, refitted from other
            // starts (every start of its effects' grids, where that stays affordable).
            // A strong effect stuck beside its minimum leaves a residual any flexible
            // candidate can take; the addition must beat the set's best fit, not its
            // first one.
            if chosen.terms.len() >= 2
                && !refitted.contains(&chosen.terms.len())
                && crate::fit::start_count(&chosen.terms, table) <= MAX_REFIT_STARTS
            {
                refitted.push(chosen.terms.len());
                let none = vec![None; chosen.terms.len()];
                let alt = fit_joint(model, table, &prep, &chosen.terms, &none, &meter);
                meter.close_stage("refit from every start");
                match alt {
                    Ok(alt) if alt.bic_after < bic_now - 1e-9 * bic_now.abs() => {
                        chosen.values = alt.kinds.iter().map(|k| alt.values_of(k)).collect();
                        restate(steps.last_mut(), &alt);
                        current = Some(alt);
                        // The round again, from the better fit.
                        round = next_round(model, table, &prep, &chosen, &cands, opts, &meter);
                        note_cut(&round, &mut cut_short);
                        meter.close_stage("later rounds");
                        continue;
                    }
                    Err(Error::Budget { .. }) => {
                        cut_short.push(format!("refit of {}", chosen.terms.len()))
                    }
                    _ => {}
                }
            }
            // Candidates the table cannot tell from the best: supported too, within
            // `bic_tie`, their own shares nearly collinear with the best's.
            let share = |f: &EffectFit| f.effect_shift_g.last().cloned().unwrap_or_default();
            let best_share = share(best);
            let tied: Vec<&EffectFit> = ok[1..]
                .iter()
                .copied()
                .filter(|f| {
                    f.bic_after - bic_now <= opts.bic_support
                        && f.bic_after - best.bic_after <= opts.bic_tie
                        && correlation(&share(f), &best_share, &prep.uncertainty_g)
                            >= opts.collinear
                })
                .collect();
            if !tied.is_empty() {
                let corr = tied
                    .iter()
                    .map(|f| correlation(&share(f), &best_share, &prep.uncertainty_g))
                    .fold(1.0, f64::min);
                let mut all = vec![best.clone()];
                all.extend(tied.into_iter().cloned());
                confounded = Some((all, corr));
                break;
            }
            let mut step = step_from(format!("add {}", best.kind), best, bic_now);
            step.runners_up = ok[1..]
                .iter()
                .take(4)
                .map(|f| (f.kind.clone(), f.bic_after - bic_now))
                .collect();
            steps.push(step);
            chosen.terms = best
                .kinds
                .iter()
                .filter_map(|k| library::candidate(k))
                .collect();
            chosen.values = best.kinds.iter().map(|k| best.values_of(k)).collect();
            current = Some(best.clone());
            // Swap check: an earlier effect may stand in for a twin (a
            // `unit_response` for a `mount_resonance`: both filter the vibration, and
            // alone they fit the first residual almost equally). With the effects
            // added since, each earlier one is replaced by each candidate whose
            // first-round fit looked like its own (weighted correlation of their VE
            // changes >= `SWAP_TWIN`); a replacement that lowers the BIC by more than
            // `bic_support` is taken. The backward check (next) removes, this replaces;
            // an effect the replacement makes needless goes there.
            if chosen.terms.len() >= 2 {
                if let Some(cur) = current.clone() {
                    if let Some((at, g)) = best_swap(
                        model,
                        table,
                        &prep,
                        &chosen,
                        &cur,
                        &candidates,
                        opts,
                        &meter,
                    ) {
                        let mut step = step_from(
                            format!(
                                "replace {} by {}",
                                chosen.terms[at].kind,
                                g.kinds.get(at).map_or("?", String::as_str)
                            ),
                            &g,
                            cur.bic_after,
                        );
                        step.runners_up = Vec::new();
                        steps.push(step);
                        chosen.terms = g
                            .kinds
                            .iter()
                            .filter_map(|k| library::candidate(k))
                            .collect();
                        chosen.values = g.kinds.iter().map(|k| g.values_of(k)).collect();
                        current = Some(g);
                    }
                }
                meter.close_stage("swap check");
            }
            // Backward check: an earlier effect the new set no longer needs (removing
            // it costs less than `-bic_support` in BIC) is dropped, the cheapest first,
            // and again until every earlier one is needed (a 6th-order term and a
            // heating taken for what a sensor gain explains both go).
            while chosen.terms.len() >= 2 {
                let Some(cur) = current.clone() else { break };
                let mut removed = false;
                let mut costs: Vec<(usize, EffectFit)> = Vec::new();
                for drop in 0..chosen.terms.len() - 1 {
                    let terms: Vec<&'static Candidate> = chosen
                        .terms
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| *i != drop)
                        .map(|(_, c)| *c)
                        .collect();
                    let known: Vec<Option<Vec<f64>>> = chosen
                        .values
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| *i != drop)
                        .map(|(_, v)| Some(v.clone()))
                        .collect();
                    match fit_joint(model, table, &prep, &terms, &known, &meter) {
                        Ok(f) => costs.push((drop, f)),
                        Err(Error::Budget { .. }) => {
                            cut_short.push(format!("without {}", chosen.terms[drop].kind))
                        }
                        Err(_) => {}
                    }
                }
                costs.sort_by(|a, b| a.1.bic_after.total_cmp(&b.1.bic_after));
                if let Some((drop, f)) = costs.first() {
                    if f.bic_after - cur.bic_after < -opts.bic_support {
                        let mut step = step_from(
                            format!("remove {}", chosen.terms[*drop].kind),
                            f,
                            cur.bic_after,
                        );
                        step.runners_up = costs[1..]
                            .iter()
                            .map(|(d, g)| {
                                (
                                    chosen.terms[*d].kind.to_string(),
                                    g.bic_after - cur.bic_after,
                                )
                            })
                            .collect();
                        steps.push(step);
                        chosen.terms.remove(*drop);
                        chosen.values = f.kinds.iter().map(|k| f.values_of(k)).collect();
                        current = Some(f.clone());
                        removed = true;
                    }
                }
                meter.close_stage("backward check");
                if !removed {
                    break;
                }
            }
            // The stated vibration's uncertainty through the model with the effects
            // found (near a resonance the VE rises faster with the amplitude than the
            // model as is says), and the set refitted under those weights.
            if let Some(f) = current.clone() {
                if table.weights_follow_model() {
                    let g = fit_reweighted(model, table, &mut prep, &chosen.terms, f, &meter)?;
                    meter.close_stage("reweighted fit");
                    restate(steps.last_mut(), &g);
                    chosen.values = g.kinds.iter().map(|k| g.values_of(k)).collect();
                    current = Some(g);
                }
            }
            let cur = current.as_ref().unwrap_or(best);
            // Stop when the residual is noise. Once the effects' mean formulas
            // explain it to `model_tolerance` ([`explains`]) the search goes on, but a
            // further effect must take at least half of the chi-square left above its
            // degrees of freedom (`tolerated`): a weak effect a thousand times below a
            // strong one does, a formula's last per-mille spread over every candidate
            // does not.
            if cur.p_value_after >= opts.alpha_noise || chosen.terms.len() >= opts.max_effects {
                break;
            }
            tolerated = explains(cur, &prep.uncertainty_g, opts).then(|| {
                let dof = cur.n.saturating_sub(cur.k).max(1) as f64;
                (cur.chi2_after, (cur.chi2_after - dof).max(0.0))
            });
            // Every candidate not chosen yet is tried again: one effect can hide
            // another (axis phases under a 6th-order term are not supported alone).
            if cands
                .iter()
                .all(|c| chosen.terms.iter().any(|t| t.kind == c.kind))
            {
                break;
            }
            round = next_round(model, table, &prep, &chosen, &cands, opts, &meter);
            note_cut(&round, &mut cut_short);
            meter.close_stage("later rounds");
        }
    }
    // The set found, fitted as `lab add` and `lab report` fit it ([`final_fit`], on
    // the weights of the model as is): the path (the order of the steps, the weights
    // after each) does not change the fit reported.
    if let Some(f) = current.as_ref() {
        let terms: Vec<&'static Candidate> = f
            .kinds
            .iter()
            .filter_map(|k| library::candidate(k))
            .collect();
        let none = vec![None; terms.len()];
        let mut fresh = Prepared::new(model, table)?;
        // The first round's fits were made on these weights, from no known values.
        let singles: Vec<&EffectFit> = candidates.iter().filter_map(|c| c.fit.as_ref()).collect();
        let fitted = final_fit(model, table, &mut fresh, &terms, &none, &singles, &meter);
        meter.close_stage("final fit");
        match fitted {
            Ok((g, _)) => {
                // The last step states the fit reported (its path's fit may differ).
                restate(steps.last_mut(), &g);
                chosen.values = g.kinds.iter().map(|k| g.values_of(k)).collect();
                chosen.terms = g
                    .kinds
                    .iter()
                    .filter_map(|k| library::candidate(k))
                    .collect();
                current = Some(g);
                prep = fresh;
            }
            Err(Error::Budget { .. }) => {
                cut_short.push(format!("final fit of {}", f.kinds.join("+")))
            }
            Err(e) => return Err(e),
        }
    }
    // The final set's nonlinear parameters get their profile-likelihood reach (a
    // resonance's f0 and q from one random spectrum lie along a curved valley).
    let mut profile_evaluations = 0;
    if let Some(f) = current.as_mut() {
        let terms: Vec<&'static Candidate> = f
            .kinds
            .iter()
            .filter_map(|k| library::candidate(k))
            .collect();
        if terms.len() == f.kinds.len() {
            let before = meter.total();
            // Profiling only widens what the linearised sigma states; a budget run
            // out leaves the linearised reach (and says so).
            if let Err(Error::Budget { .. }) =
                crate::fit::profile(model, table, &prep, &terms, f, &meter)
            {
                cut_short.push(format!("profile of {}", f.kinds.join("+")));
            }
            profile_evaluations = meter.total() - before;
            meter.close_stage("profile intervals");
        }
    }
    let residual_after: Vec<f64> = current
        .as_ref()
        .map_or(residual_g.clone(), |f| f.residual_after_g.clone());
    let trends_after = trends(table, &residual_after, &prep.uncertainty_g);
    let found: Vec<String> = current.as_ref().map_or(Vec::new(), |f| f.kinds.clone());
    let verdict = if s.p_value >= opts.alpha_noise {
        Verdict::Noise {
            p_value: s.p_value,
            chi2_per_dof: s.chi2_per_dof,
        }
    } else if let Some((tied, corr)) = confounded {
        let refs: Vec<&EffectFit> = tied.iter().collect();
        Verdict::Confounded {
            kinds: tied.iter().map(|f| f.kind.clone()).collect(),
            correlation: corr,
            suggestions: suggestions(model, table, &refs),
            found,
        }
    } else {
        match &current {
            Some(f) if explains(f, &prep.uncertainty_g, opts) => Verdict::Effect {
                kind: f.kinds.first().cloned().unwrap_or_default(),
                kinds: f.kinds.clone(),
                params: f.params.clone(),
                correlation: f.correlation.clone(),
                delta_bic: f.delta_bic,
                rms_residual_before_g: f.rms_residual_before_g,
                rms_residual_after_g: f.rms_residual_after_g,
                chi2_per_dof_after: f.chi2_per_dof_after,
                physics: f
                    .kinds
                    .iter()
                    .filter_map(|k| library::candidate(k))
                    .map(|c| format!("{}: {}", c.kind, c.physics))
                    .collect(),
            },
            _ => {
                let chi2_after = current.as_ref().map_or(s.chi2, |f| f.chi2_after);
                let bic_now = current.as_ref().map_or(s.chi2, |f| f.bic_after);
                // Only an effect that lowers the BIC is named as the best one.
                let best = best_left
                    .as_ref()
                    .or(candidates
                        .first()
                        .and_then(|c| c.fit.as_ref())
                        .filter(|_| current.is_none()))
                    .filter(|b| b.bic_after < bic_now);
                Verdict::Unexplained {
                    chi2_per_dof: current
                        .as_ref()
                        .map_or(s.chi2_per_dof, |f| f.chi2_per_dof_after),
                    variables: trends_after
                        .iter()
                        .filter(|t| t.p_value < 1e-3)
                        .map(|t| t.variable.clone())
                        .collect(),
                    best: best.map(|b| b.kind.clone()),
                    best_explained_fraction: best
                        .map_or(0.0, |b| 1.0 - b.chi2_after / chi2_after.max(1e-300)),
                    found: found.clone(),
                    found_explained_fraction: 1.0 - chi2_after / s.chi2.max(1e-300),
                }
            }
        }
    };
    // Beyond the library: only where no physical effect explains the data.
    let (empirical, empirical_none) = if matches!(verdict, Verdict::Unexplained { .. }) {
        let params = current.as_ref().map_or(&[][..], |f| &f.params[..]);
        match crate::empirical::backfit(model, table, &chosen.terms, &chosen.values, params, &meter)
        {
            Ok(Some(e)) => (Some(e), None),
            Ok(None) => (
                None,
                Some(format!(
                    "no smooth function of the vibration and the flight acceleration predicts \
                     the residual out of sample (no set of terms, each lowering the \
                     leave-one-out chi-square by {}, brings it below {} of its value)",
                    crate::empirical::CV_SUPPORT,
                    crate::empirical::OFFER_FRACTION
                )),
            ),
            Err(e) => (None, Some(format!("no empirical correction: {e}"))),
        }
    } else {
        (None, None)
    };
    Ok(Diagnosis {
        comparison,
        trends: trends_before,
        trends_after: if current.is_some() {
            trends_after
        } else {
            Vec::new()
        },
        lack_of_fit,
        candidates,
        steps,
        selected: current,
        not_applicable: prep.skipped.clone(),
        verdict,
        options: opts.clone(),
        budget: BudgetUsed {
            budget: opts.budget,
            evaluations: meter.total(),
            profile_evaluations,
            elapsed_s: meter.elapsed_s(),
            exhausted: !cut_short.is_empty(),
            cut_short,
            stages: meter.stages(),
        },
        empirical,
        empirical_none,
    })
}

/// Fits one candidate of the library to the residual of `model` on `table`.
pub fn fit_effect(model: &LabModel, table: &CampaignTable, kind: &str) -> Result<EffectFit> {
    let cand = candidate_of(kind)?;
    let prep = Prepared::new(model, table)?;
    fit_prepared(model, table, &prep, cand, &Meter::new(Budget::default()))
}

fn candidate_of(kind: &str) -> Result<&'static Candidate> {
    library::candidate(kind).ok_or_else(|| {
        Error::Invalid(format!(
            "effect {kind:?}: not in the lab's library ({})",
            library::kinds().join(", ")
        ))
    })
}

/// The numbers of an effect table's parameters `cand` fits, if all are there.
fn values_in(cand: &Candidate, t: &toml::Table) -> Option<Vec<f64>> {
    cand.params
        .iter()
        .map(|p| {
            t.get(p.name)
                .and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)))
        })
        .collect()
}

/// `model` with the effects `kinds` fitted to `table` added, and the fit.
///
/// The model's own effects of the library are refitted jointly with the new ones
/// (all parameters free, starting at their values) unless `freeze`; then they stay
/// as they are and only the new ones are fitted. A kind the model already has is
/// refitted, not added twice. Effects outside the library stay as they are.
pub fn add_effects(
    model: &LabModel,
    table: &CampaignTable,
    kinds: &[&str],
    freeze: bool,
) -> Result<(LabModel, EffectFit)> {
    add_effects_stoppable(model, table, kinds, freeze, &Stop::default())
}

/// [`add_effects`], its fits ending once `stop` is requested (an error then).
pub fn add_effects_stoppable(
    model: &LabModel,
    table: &CampaignTable,
    kinds: &[&str],
    freeze: bool,
    stop: &Stop,
) -> Result<(LabModel, EffectFit)> {
    if kinds.is_empty() {
        return Err(Error::Invalid("no effect to add".into()));
    }
    let new: Vec<&'static Candidate> = kinds
        .iter()
        .map(|k| candidate_of(k))
        .collect::<Result<_>>()?;
    let mut frozen = LabModel {
        effects: Vec::new(),
        fits: Vec::new(),
        ..model.clone()
    };
    let mut terms: Vec<&'static Candidate> = Vec::new();
    let mut known: Vec<Option<Vec<f64>>> = Vec::new();
    for t in &model.effects {
        let kind = t.get("kind").and_then(|k| k.as_str()).unwrap_or("");
        let cand = library::candidate(kind);
        let refit = cand.is_some_and(|c| !freeze || new.iter().any(|n| n.kind == c.kind));
        match cand.filter(|_| refit) {
            Some(c) if !terms.iter().any(|x| x.kind == c.kind) => {
                terms.push(c);
                known.push(values_in(c, t));
            }
            _ => frozen.effects.push(t.clone()),
        }
    }
    frozen.fits = model
        .fits
        .iter()
        .filter(|r| !terms.iter().any(|c| c.kind == r.kind))
        .cloned()
        .collect();
    for c in new {
        if !terms.iter().any(|x| x.kind == c.kind) {
            terms.push(c);
            known.push(None);
        }
    }
    let before = compare(model, table)?;
    let mut prep = Prepared::new(&frozen, table)?;
    let meter = Meter::stoppable(Budget::default(), stop.clone());
    let (fit, terms) = final_fit(&frozen, table, &mut prep, &terms, &known, &[], &meter)?;
    let mut fit = fit;
    crate::fit::profile(&frozen, table, &prep, &terms, &mut fit, &meter)?;
    let mut out = frozen.clone();
    for (c, t) in terms.iter().zip(&fit.tables) {
        let params = fit.params_of(c.kind);
        let record = FitRecord {
            kind: c.kind.to_string(),
            table: table.path.display().to_string(),
            params: params.iter().map(|p| (p.name.clone(), p.value)).collect(),
            sigma: params
                .iter()
                .map(|p| {
                    (
                        p.name.clone(),
                        if p.sigma.is_finite() {
                            p.sigma
                        } else {
                            f64::MAX
                        },
                    )
                })
                .collect(),
            interval: params
                .iter()
                .filter(|p| p.sigma_minus != p.sigma || p.sigma_plus != p.sigma)
                .filter(|p| p.sigma_minus.is_finite() && p.sigma_plus.is_finite())
                .map(|p| {
                    (
                        p.name.clone(),
                        [p.value - p.sigma_minus, p.value + p.sigma_plus],
                    )
                })
                .collect(),
            rms_residual_before_g: before.summary.rms_residual_g,
            rms_residual_after_g: fit.rms_residual_after_g,
            delta_bic: fit.delta_bic,
        };
        out = out.with_effect(t.clone(), Some(record));
    }
    Ok((out, fit))
}

/// The joint fit of the set `terms` ([`fit_set`]: the same whatever the path), then
/// under weights that follow it ([`fit_reweighted`]); with the effects in the fit's
/// order.
fn final_fit(
    model: &LabModel,
    table: &CampaignTable,
    prep: &mut Prepared,
    terms: &[&'static Candidate],
    known: &[Option<Vec<f64>>],
    singles: &[&EffectFit],
    meter: &Meter,
) -> Result<(EffectFit, Vec<&'static Candidate>)> {
    let fit = fit_set(model, table, prep, terms, known, singles, meter)?;
    let ordered: Vec<&'static Candidate> = fit
        .kinds
        .iter()
        .filter_map(|k| library::candidate(k))
        .collect();
    // The stated vibration's uncertainty through the model with the fitted effects,
    // and the effects refitted under it.
    let fit = fit_reweighted(model, table, prep, &ordered, fit, meter)?;
    Ok((fit, ordered))
}

/// `model` with `kind` fitted to `table` added (the model's own effects of the library
/// refitted jointly with it), and the fit.
pub fn add_effect(
    model: &LabModel,
    table: &CampaignTable,
    kind: &str,
) -> Result<(LabModel, EffectFit)> {
    add_effects(model, table, &[kind], false)
}

/// `model` with an empirical correction (not physical, [`crate::empirical`]) fitted to
/// what it leaves on `table`, its effects of the library refitted jointly with the
/// correction; `None` when no term is supported by cross-validation. A correction the
/// model already has is replaced.
pub fn add_empirical(
    model: &LabModel,
    table: &CampaignTable,
) -> Result<Option<(LabModel, crate::empirical::EmpiricalFit)>> {
    let kind = vibro_effects::empirical::KIND;
    let mut frozen = LabModel {
        effects: Vec::new(),
        fits: model
            .fits
            .iter()
            .filter(|r| r.kind != kind)
            .cloned()
            .collect(),
        ..model.clone()
    };
    let mut terms: Vec<&'static Candidate> = Vec::new();
    let mut values: Vec<Vec<f64>> = Vec::new();
    for t in &model.effects {
        let k = t.get("kind").and_then(|k| k.as_str()).unwrap_or("");
        if k == kind {
            continue;
        }
        match library::candidate(k).and_then(|c| values_in(c, t).map(|v| (c, v))) {
            Some((c, v)) if !terms.iter().any(|x| x.kind == c.kind) => {
                terms.push(c);
                values.push(v);
            }
            _ => frozen.effects.push(t.clone()),
        }
    }
    let meter = Meter::new(Budget::default());
    // The model's effects as its file states them (their uncertainty from its records).
    let params: Vec<crate::fit::FittedParam> = terms
        .iter()
        .zip(&values)
        .flat_map(|(c, v)| {
            let record = model.fits.iter().find(|r| r.kind == c.kind);
            c.params.iter().zip(v).map(move |(p, x)| {
                let sigma = record
                    .and_then(|r| r.sigma.get(p.name).copied())
                    .unwrap_or(f64::NAN);
                let interval = record.and_then(|r| r.interval.get(p.name));
                crate::fit::FittedParam {
                    effect: c.kind.to_string(),
                    name: p.name.to_string(),
                    value: *x,
                    sigma,
                    sigma_minus: interval.map_or(sigma, |i| *x - i[0]),
                    sigma_plus: interval.map_or(sigma, |i| i[1] - *x),
                    three_sigma_minus: 3.0 * interval.map_or(sigma, |i| *x - i[0]),
                    three_sigma_plus: 3.0 * interval.map_or(sigma, |i| i[1] - *x),
                }
            })
        })
        .collect();
    let Some(e) = crate::empirical::backfit(&frozen, table, &terms, &values, &params, &meter)?
    else {
        return Ok(None);
    };
    let before = compare(model, table)?;
    let mut out = frozen;
    // The library's effects as refitted beside the correction, their provenance kept.
    for t in &e.found_tables {
        let k = t.get("kind").and_then(|k| k.as_str()).unwrap_or("");
        let record = model.fits.iter().find(|r| r.kind == k).cloned();
        out.fits.retain(|r| r.kind != k);
        out = out.with_effect(t.clone(), record);
    }
    let record = FitRecord {
        kind: kind.to_string(),
        table: table.path.display().to_string(),
        params: e.terms.iter().map(|t| (t.key.clone(), t.value)).collect(),
        sigma: e.terms.iter().map(|t| (t.key.clone(), t.sigma)).collect(),
        interval: Default::default(),
        rms_residual_before_g: before.summary.rms_residual_g,
        rms_residual_after_g: e.rms_residual_after_g,
        // No information criterion: the terms were chosen by cross-validation; the
        // drop of the cross-validated chi-square stands here.
        delta_bic: e.cv_chi2_after - e.cv_chi2_before,
    };
    out = out.with_effect(e.table.clone(), Some(record));
    Ok(Some((out, e)))
}

/// One step of [`error_ladder`].
#[derive(Debug, Clone, Serialize)]
pub struct LadderStep {
    /// The effects of the model at this step.
    pub effects: Vec<String>,
    pub rms_residual_g: f64,
    pub chi2_per_dof: f64,
}

/// The effects the diagnosis found (its final joint fit), added to `model`: the
/// verdict's effects, or those found before the structure left was unexplained or
/// confounded; none when the residual is noise.
pub fn next_effects(d: &Diagnosis) -> Vec<String> {
    match &d.verdict {
        Verdict::Noise { .. } => Vec::new(),
        _ => d.selected.as_ref().map_or(Vec::new(), |f| f.kinds.clone()),
    }
}

/// The model as is, then each step of the diagnosis's stepwise search; and the model
/// with the effects found ([`next_effects`]) fitted jointly. `first` is the diagnosis
/// of `model` when already made; `max_steps` bounds the effects added.
pub fn ladder_from(
    model: &LabModel,
    table: &CampaignTable,
    opts: &DiagnoseOptions,
    max_steps: usize,
    first: Option<&Diagnosis>,
) -> Result<(Vec<LadderStep>, LabModel)> {
    let d = match first {
        Some(d) => d.clone(),
        None => diagnose(model, table, opts)?,
    };
    let steps = ladder_steps(&d.steps, &model.effect_kinds(), max_steps);
    let mut kinds = next_effects(&d);
    kinds.truncate(max_steps);
    if kinds.is_empty() {
        return Ok((steps, model.clone()));
    }
    let refs: Vec<&str> = kinds.iter().map(String::as_str).collect();
    let (m, _) = add_effects(model, table, &refs, true)?;
    Ok((steps, m))
}

/// The ladder of a search's steps after the model's own effects `base`: every step up
/// to the `max_steps`-th addition, and the replacements and removals after it (a
/// search whose last step removes an effect ends on the set it found, not on the one
/// before the removal).
fn ladder_steps(steps: &[Step], base: &[String], max_steps: usize) -> Vec<LadderStep> {
    let mut adds = 0;
    steps
        .iter()
        .take_while(|s| {
            if s.action.starts_with("add ") {
                adds += 1;
            }
            adds <= max_steps
        })
        .map(|s| LadderStep {
            effects: base.iter().chain(&s.effects).cloned().collect(),
            rms_residual_g: s.rms_residual_g,
            chi2_per_dof: s.chi2_per_dof,
        })
        .collect()
}

/// [`ladder_from`]'s steps.
pub fn error_ladder(
    model: &LabModel,
    table: &CampaignTable,
    opts: &DiagnoseOptions,
    max_steps: usize,
) -> Result<Vec<LadderStep>> {
    Ok(ladder_from(model, table, opts, max_steps, None)?.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(action: &str, effects: &[&str], chi2_per_dof: f64) -> Step {
        Step {
            action: action.into(),
            effects: effects.iter().map(|e| e.to_string()).collect(),
            delta_bic: 0.0,
            bic: 0.0,
            chi2: 0.0,
            chi2_per_dof,
            p_value: 0.0,
            rms_residual_g: 0.0,
            runners_up: Vec::new(),
        }
    }

    /// A search that adds three effects, replaces one and removes another ends its
    /// ladder on the set it found (the report's ladder stopped before the removal,
    /// at a set with a lower chi2 than the one written to the model); a bound on the
    /// additions still cuts at the addition past it.
    #[test]
    fn the_ladder_ends_on_the_set_found() {
        let steps = [
            step("model as is", &[], 1e9),
            step("add heating", &["heating"], 8e8),
            step("add unit_response", &["heating", "unit_response"], 3e8),
            step("add k6", &["heating", "unit_response", "k6"], 4e5),
            step(
                "replace unit_response by mount",
                &["heating", "mount", "k6"],
                0.993,
            ),
            step("remove heating", &["mount", "k6"], 0.994),
        ];
        let base = vec!["sensor_error".to_string()];
        let all = ladder_steps(&steps, &base, 4);
        assert_eq!(all.len(), 6);
        assert_eq!(all[5].effects, ["sensor_error", "mount", "k6"]);
        assert_eq!(all[5].chi2_per_dof, 0.994);
        let two = ladder_steps(&steps, &base, 2);
        assert_eq!(two.len(), 3);
        assert_eq!(two[2].effects, ["sensor_error", "heating", "unit_response"]);
    }
}
