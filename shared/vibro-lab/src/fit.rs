//! Fitting a candidate effect to a campaign: weighted nonlinear least squares.
//!
//! The model's residual `r_i = VE_measured_i - VE_model_i` has standard uncertainty
//! `u_i` (the table's `ve_uncertainty_g`). A candidate with parameters `theta` changes
//! the prediction by `s_i(theta)`; the fit minimises
//! `chi2(theta) = sum_i ((r_i - s_i(theta)) / u_i)^2` by Levenberg-Marquardt
//! (Marquardt 1963; damping on the diagonal of `J^T J`) with a forward-difference
//! Jacobian, from every start of the candidate's grid (the linear parameters solved
//! first at each start), keeping the best. Standard uncertainties are
//! `sqrt(diag((J^T J)^-1))` at the minimum, inflated by `sqrt(chi2/dof)` when that
//! exceeds 1 (the Birge ratio: the uncertainties of the table under-state the
//! scatter); a parameter the table cannot determine (a singular `J^T J`) gets an
//! infinite uncertainty.
//!
//! The comparison between candidates uses the Bayesian information criterion
//! (Schwarz 1978) for Gaussian errors of known variance: `BIC = chi2 + k ln n`, `k`
//! the parameters fitted, `n` the conditions; `delta_bic` is the candidate's BIC minus
//! the model's as is (`chi2_0`, no parameter). Kass & Raftery (1995): a difference
//! beyond 10 is very strong evidence.

use crate::library::{Candidate, Search};
use crate::table::CampaignTable;
use crate::{Error, Result};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use vibro_effects::model::{build_effects, LabModel};
use vibro_effects::predict::{self, effect_shifts_g};

/// Limits on the work of fitting (each candidate's fit, and a whole diagnosis).
///
/// Levenberg-Marquardt is bounded by its iteration counts (6 per start for the
/// linear parameters, 60 per refinement, 12 damping tries each); the budget bounds
/// the model evaluations of one candidate's fit and the wall-clock time of all of
/// them, so that a table of many rows or a slow effect cannot run without end.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Budget {
    /// Model evaluations (one evaluation: the candidate's VE change on every row) one
    /// candidate's fit may take. The walkthrough's fits take at most about 200.
    pub max_evaluations: usize,
    /// Wall-clock time all fits of one call may take, s.
    pub time_s: f64,
}

impl Default for Budget {
    fn default() -> Self {
        Self {
            max_evaluations: 20_000,
            time_s: 600.0,
        }
    }
}

/// How much of a [`Budget`] a call used.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BudgetUsed {
    pub budget: Budget,
    /// Model evaluations over all fits.
    pub evaluations: usize,
    /// Wall-clock time of the fits, s.
    pub elapsed_s: f64,
    /// Whether a fit was stopped by the budget.
    pub exhausted: bool,
    /// The candidates whose fit the budget stopped.
    pub cut_short: Vec<String>,
}

/// A [`Budget`] running: the deadline and the evaluations over all fits.
pub(crate) struct Meter {
    pub(crate) budget: Budget,
    pub(crate) start: std::time::Instant,
    pub(crate) evaluations: std::sync::atomic::AtomicUsize,
}

impl Meter {
    pub(crate) fn new(budget: Budget) -> Self {
        Self {
            budget,
            start: std::time::Instant::now(),
            evaluations: std::sync::atomic::AtomicUsize::new(0),
        }
    }

    pub(crate) fn elapsed_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    pub(crate) fn total(&self) -> usize {
        self.evaluations.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// One fitted parameter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FittedParam {
    pub name: String,
    pub value: f64,
    /// Standard uncertainty (infinite: the table does not determine it).
    pub sigma: f64,
}

/// A candidate fitted to a campaign.
#[derive(Debug, Clone, Serialize)]
pub struct EffectFit {
    pub kind: String,
    pub params: Vec<FittedParam>,
    /// The `[[effect]]` table with the fitted values (what `lab add` writes).
    #[serde(skip)]
    pub table: toml::Table,
    pub n: usize,
    pub k: usize,
    pub chi2_before: f64,
    pub chi2_after: f64,
    /// `chi2_after / (n - k)`.
    pub chi2_per_dof_after: f64,
    /// Probability of a chi2 at least this large if the extended model were right.
    pub p_value_after: f64,
    pub bic_before: f64,
    pub bic_after: f64,
    pub delta_bic: f64,
    pub rms_residual_before_g: f64,
    pub rms_residual_after_g: f64,
    /// The fitted effect's VE change per condition, g.
    pub shift_g: Vec<f64>,
    /// Residual per condition after the fit, g.
    pub residual_after_g: Vec<f64>,
    /// Model evaluations the fit took.
    pub evaluations: usize,
}

/// What a fit needs per condition, computed once: the model's prediction and the
/// true vibration under the model's own sensor effects.
pub(crate) struct Prepared {
    pub(crate) measured_g: Vec<f64>,
    pub(crate) uncertainty_g: Vec<f64>,
    pub(crate) predicted_g: Vec<f64>,
    truth: Vec<predict::TrueVibration>,
}

impl Prepared {
    pub(crate) fn new(model: &LabModel, table: &CampaignTable) -> Result<Self> {
        let mut p = Prepared {
            measured_g: Vec::new(),
            uncertainty_g: Vec::new(),
            predicted_g: Vec::new(),
            truth: Vec::new(),
        };
        for c in &table.conditions {
            let effects = build_effects(&model.effects, &c.passport)?;
            let row = |e: vibro_effects::Error| Error::Predict {
                what: format!("{} (line {}, {})", table.path.display(), c.line, c.run_id),
                reason: e.to_string(),
            };
            let truth =
                predict::true_vibration(&effects, &c.passport, c.a_l_g, &c.vibration(), &c.psd())
                    .map_err(row)?;
            let pred = predict::predict_ve_true(
                model.mode,
                &effects,
                &c.passport,
                c.a_l_g,
                &truth,
                c.vibrating_s(),
            )
            .map_err(row)?;
            // Residuals and weights must stay finite: `(r/u)^2` summed over the
            // table is the fits' cost.
            let z = (c.ve_measured_g - pred.ve_g) / c.ve_uncertainty_g;
            if !(pred.ve_g.is_finite() && (z * z).is_finite() && c.ve_uncertainty_g > 0.0) {
                return Err(Error::Numeric {
                    what: format!("{} (line {}, {})", table.path.display(), c.line, c.run_id),
                    reason: format!(
                        "measured {:e} g, predicted {:e} g, uncertainty {:e} g: the predicted VE \
                         and (residual/uncertainty)^2 must be finite",
                        c.ve_measured_g, pred.ve_g, c.ve_uncertainty_g
                    ),
                });
            }
            p.measured_g.push(c.ve_measured_g);
            p.uncertainty_g.push(c.ve_uncertainty_g);
            p.predicted_g.push(pred.ve_g);
            p.truth.push(truth);
        }
        Ok(p)
    }

    pub(crate) fn residual_g(&self) -> Vec<f64> {
        self.measured_g
            .iter()
            .zip(&self.predicted_g)
            .map(|(m, p)| m - p)
            .collect()
    }
}

/// The effect table of `cand` with parameter values `theta`.
pub(crate) fn effect_table(cand: &Candidate, theta: &[f64]) -> toml::Table {
    let mut t: toml::Table = toml::from_str(cand.fixed).unwrap_or_default();
    t.insert("kind".into(), toml::Value::String(cand.kind.into()));
    for (p, v) in cand.params.iter().zip(theta) {
        t.insert(p.name.into(), toml::Value::Float(*v));
    }
    t
}

/// The VE change of `cand(theta)` on every condition, added to the model.
pub(crate) fn shifts_g(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    cand: &Candidate,
    theta: &[f64],
) -> Result<Vec<f64>> {
    let t = effect_table(cand, theta);
    // The candidate built once per passport of the table (most tables have one), not
    // once per row: building parses and validates the effect's table.
    let mut built: Vec<(&str, Vec<Box<dyn vibro_effects::Effect>>)> = Vec::new();
    let mut out = Vec::with_capacity(table.conditions.len());
    for (i, c) in table.conditions.iter().enumerate() {
        let k = match built.iter().position(|(r, _)| *r == c.passport_ref) {
            Some(k) => k,
            None => {
                built.push((
                    &c.passport_ref,
                    build_effects(std::slice::from_ref(&t), &c.passport)?,
                ));
                built.len() - 1
            }
        };
        let one = &built[k].1;
        let row = |e: vibro_effects::Error| Error::Predict {
            what: format!("{} on line {} ({})", cand.kind, c.line, c.run_id),
            reason: e.to_string(),
        };
        let f = predict::sensor_rms_factor(
            one,
            &c.passport,
            c.a_l_g,
            &prep.truth[i].vibration,
            &prep.truth[i].psd,
        );
        let shift = if f != 1.0 {
            // A sensor effect changes the vibration the whole model sees.
            let mut all = build_effects(&model.effects, &c.passport)?;
            all.extend(build_effects(std::slice::from_ref(&t), &c.passport)?);
            predict::predict_ve(
                model.mode,
                &all,
                &c.passport,
                c.a_l_g,
                &c.vibration(),
                &c.psd(),
                c.vibrating_s(),
            )
            .map_err(row)?
            .ve_g
                - prep.predicted_g[i]
        } else {
            effect_shifts_g(
                one,
                &c.passport,
                c.a_l_g,
                &prep.truth[i].vibration,
                &prep.truth[i].psd,
                c.vibrating_s(),
            )
            .map_err(row)?
            .iter()
            .map(|(_, s)| s)
            .sum()
        };
        out.push(shift);
    }
    Ok(out)
}

/// The starting points of a candidate's search.
fn starts(cand: &Candidate, table: &CampaignTable) -> Vec<Vec<f64>> {
    let mut grids: Vec<Vec<f64>> = Vec::new();
    for p in cand.params {
        grids.push(match p.search {
            Search::Linear => vec![0.0],
            Search::Grid(g) => g.to_vec(),
            Search::AroundVariable {
                variable,
                lo,
                hi,
                points,
            } => {
                let xs: Vec<f64> = table
                    .variable_column(variable)
                    .unwrap_or_default()
                    .into_iter()
                    .filter(|x| x.is_finite() && *x > 0.0)
                    .collect();
                let min = xs.iter().copied().fold(f64::INFINITY, f64::min);
                let max = xs.iter().copied().fold(0.0, f64::max);
                // The grid stays within the parameter's bounds (a table built in code
                // may hold a variable far outside them).
                let (g_lo, g_hi) = (
                    (min * lo).max(p.bounds.0).max(f64::MIN_POSITIVE),
                    (max * hi).min(p.bounds.1),
                );
                if !min.is_finite()
                    || max <= 0.0
                    || !(g_lo.is_finite() && g_hi.is_finite())
                    || g_hi < g_lo
                {
                    vec![p.bounds.0.max(1.0)]
                } else {
                    let (a, b) = (g_lo.ln(), g_hi.ln());
                    (0..points)
                        .map(|j| {
                            (a + (b - a) * j as f64 / (points.max(2) - 1) as f64)
                                .exp()
                                .clamp(p.bounds.0, p.bounds.1)
                        })
                        .collect()
                }
            }
        });
    }
    let mut out = vec![Vec::new()];
    for g in grids {
        out = out
            .into_iter()
            .flat_map(|s| {
                g.iter().map(move |x| {
                    let mut s = s.clone();
                    s.push(*x);
                    s
                })
            })
            .collect();
    }
    out
}

struct Problem<'a> {
    model: &'a LabModel,
    table: &'a CampaignTable,
    prep: &'a Prepared,
    cand: &'a Candidate,
    residual_g: Vec<f64>,
    evaluations: usize,
    meter: &'a Meter,
}

impl Problem<'_> {
    /// Weighted residuals `(r_i - s_i(theta))/u_i`, or an error.
    fn weighted(&mut self, theta: &[f64]) -> Result<DVector<f64>> {
        let b = self.meter.budget;
        if self.evaluations >= b.max_evaluations {
            return Err(Error::Budget {
                what: self.cand.kind.to_string(),
                reason: format!(
                    "{} model evaluations used of max_evaluations = {}",
                    self.evaluations, b.max_evaluations
                ),
            });
        }
        let elapsed_s = self.meter.elapsed_s();
        if elapsed_s >= b.time_s {
            return Err(Error::Budget {
                what: self.cand.kind.to_string(),
                reason: format!("{elapsed_s:.1} s used of time_s = {} s", b.time_s),
            });
        }
        self.evaluations += 1;
        self.meter
            .evaluations
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let s = shifts_g(self.model, self.table, self.prep, self.cand, theta)?;
        let w = DVector::from_iterator(
            s.len(),
            s.iter()
                .zip(&self.residual_g)
                .zip(&self.prep.uncertainty_g)
                .map(|((s, r), u)| (r - s) / u),
        );
        // The cost is the sum of squares: it, not only each term, must be finite.
        if !w.norm_squared().is_finite() {
            let k = w.iter().position(|x| !(x * x).is_finite()).unwrap_or(0);
            let c = &self.table.conditions[k.min(self.table.conditions.len().saturating_sub(1))];
            return Err(Error::Numeric {
                what: format!("{} on line {} ({})", self.cand.kind, c.line, c.run_id),
                reason: format!(
                    "the weighted residual {:e} (or its sum of squares) is not finite at {:?}",
                    w.get(k).copied().unwrap_or(f64::NAN),
                    theta
                ),
            });
        }
        Ok(w)
    }

    fn clamp(&self, theta: &mut [f64]) {
        for (x, p) in theta.iter_mut().zip(self.cand.params) {
            *x = x.clamp(p.bounds.0, p.bounds.1);
        }
    }

    fn jacobian(&mut self, theta: &[f64], r: &DVector<f64>, free: &[bool]) -> Result<DMatrix<f64>> {
        let mut j = DMatrix::zeros(r.len(), theta.len());
        for k in 0..theta.len() {
            if !free[k] {
                continue;
            }
            let p = &self.cand.params[k];
            let mut h = if theta[k] != 0.0 {
                1e-4 * theta[k].abs()
            } else {
                1e-2 * p.scale
            };
            h = h.max(1e-6 * p.scale);
            let mut t = theta.to_vec();
            if t[k] + h > p.bounds.1 {
                h = -h;
            }
            t[k] += h;
            let rk = self.weighted(&t)?;
            j.set_column(k, &((rk - r) / h));
        }
        // nalgebra's SVD panics on NaN and LU steps from infinities are meaningless.
        if !(j.transpose() * &j).iter().all(|x| x.is_finite()) {
            return Err(Error::Numeric {
                what: self.cand.kind.to_string(),
                reason: format!("the Jacobian or J^T J over the table is not finite at {theta:?}"),
            });
        }
        Ok(j)
    }

    /// Levenberg-Marquardt over the free parameters from `theta`.
    fn minimise(
        &mut self,
        mut theta: Vec<f64>,
        free: &[bool],
        max_iter: usize,
    ) -> Result<(Vec<f64>, f64)> {
        let mut r = self.weighted(&theta)?;
        let mut cost = r.norm_squared();
        let mut lambda = 1e-3;
        for _ in 0..max_iter {
            let j = self.jacobian(&theta, &r, free)?;
            let a = j.transpose() * &j;
            let g = j.transpose() * &r;
            let max_diag = a.diagonal().max().max(1e-300);
            let mut improved = false;
            for _ in 0..12 {
                let mut m = a.clone();
                for k in 0..theta.len() {
                    let d = if free[k] {
                        a[(k, k)].max(1e-12 * max_diag)
                    } else {
                        1.0
                    };
                    m[(k, k)] += lambda * d;
                    if !free[k] {
                        m[(k, k)] = 1.0;
                    }
                }
                let rhs = -&g;
                let Some(step) = m.lu().solve(&rhs) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut next: Vec<f64> =
                    theta.iter().zip(step.iter()).map(|(t, s)| t + s).collect();
                for k in 0..next.len() {
                    if !free[k] {
                        next[k] = theta[k];
                    }
                }
                self.clamp(&mut next);
                let rn = match self.weighted(&next) {
                    Ok(rn) => rn,
                    Err(e @ Error::Budget { .. }) => return Err(e),
                    Err(_) => {
                        lambda *= 4.0;
                        continue;
                    }
                };
                let cn = rn.norm_squared();
                if cn < cost {
                    let rel = (cost - cn) / cost.max(1e-300);
                    theta = next;
                    r = rn;
                    cost = cn;
                    lambda = (lambda / 3.0).max(1e-12);
                    improved = rel > 1e-10;
                    break;
                }
                lambda *= 4.0;
            }
            if !improved {
                break;
            }
        }
        Ok((theta, cost))
    }
}

/// Fits `cand` to the residual of `model` on `table`.
pub fn fit_candidate(
    model: &LabModel,
    table: &CampaignTable,
    cand: &Candidate,
) -> Result<EffectFit> {
    let prep = Prepared::new(model, table)?;
    fit_prepared(model, table, &prep, cand, &Meter::new(Budget::default()))
}

pub(crate) fn fit_prepared(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    cand: &Candidate,
    meter: &Meter,
) -> Result<EffectFit> {
    let residual_g = prep.residual_g();
    let n = residual_g.len();
    let k = cand.params.len();
    let chi2_before: f64 = residual_g
        .iter()
        .zip(&prep.uncertainty_g)
        .map(|(r, u)| (r / u).powi(2))
        .sum();
    if !chi2_before.is_finite() {
        return Err(Error::Numeric {
            what: format!("{} on {}", cand.kind, table.path.display()),
            reason: format!(
                "the residual's chi2 = sum((r/u)^2) = {chi2_before:e} overflows: uncertainties \
                 too small for the residuals"
            ),
        });
    }
    let mut pb = Problem {
        model,
        table,
        prep,
        cand,
        residual_g: residual_g.clone(),
        evaluations: 0,
        meter,
    };
    let linear: Vec<bool> = cand
        .params
        .iter()
        .map(|p| matches!(p.search, Search::Linear))
        .collect();
    let all = vec![true; k];
    let mut scored = Vec::new();
    let mut last_error = None;
    for s in starts(cand, table) {
        let r = if linear.iter().any(|l| *l) && linear.iter().any(|l| !*l) {
            pb.minimise(s, &linear, 6)
        } else {
            pb.weighted(&s).map(|r| (s, r.norm_squared()))
        };
        match r {
            Ok(x) => scored.push(x),
            Err(e @ Error::Budget { .. }) => return Err(e),
            Err(e) => last_error = Some(e),
        }
    }
    if scored.is_empty() {
        return Err(
            last_error.unwrap_or_else(|| Error::Invalid(format!("{}: no start point", cand.kind)))
        );
    }
    scored.sort_by(|a, b| a.1.total_cmp(&b.1));
    // Starts on a plateau (e.g. a saturation range above every peak: no change at all)
    // tie; keep one of each cost so that the refinement starts from distinct places.
    scored.dedup_by(|b, a| (a.1 - b.1).abs() <= 1e-12 * a.1.abs());
    let mut best: Option<(Vec<f64>, f64)> = None;
    for (theta, _) in scored.into_iter().take(3) {
        let (t, c) = pb.minimise(theta, &all, 60)?;
        if best.as_ref().is_none_or(|b| c < b.1) {
            best = Some((t, c));
        }
    }
    let Some((theta, chi2_after)) = best else {
        return Err(Error::Invalid(format!(
            "{}: the fit found no minimum",
            cand.kind
        )));
    };
    // Uncertainties from J^T J at the minimum.
    let r = pb.weighted(&theta)?;
    let j = pb.jacobian(&theta, &r, &all)?;
    let a = j.transpose() * &j;
    if !a.iter().all(|x| x.is_finite()) || !chi2_after.is_finite() {
        return Err(Error::Numeric {
            what: format!("{} on {}", cand.kind, table.path.display()),
            reason: format!("J^T J or chi2 = {chi2_after:e} at the minimum is not finite"),
        });
    }
    let dof = n.saturating_sub(k).max(1);
    let birge = (chi2_after / dof as f64).sqrt().max(1.0);
    let svd = a.clone().svd(true, true);
    let smax = svd.singular_values.max();
    let smin = svd.singular_values.min();
    let cov = svd.pseudo_inverse(1e-12 * smax.max(1e-300)).ok();
    let params = cand
        .params
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let identifiable = a[(i, i)] > 0.0 && smin > 1e-12 * smax;
            let sigma = match (&cov, identifiable) {
                (Some(c), true) => c[(i, i)].max(0.0).sqrt() * birge,
                _ => f64::INFINITY,
            };
            FittedParam {
                name: p.name.to_string(),
                value: theta[i],
                sigma,
            }
        })
        .collect();
    let shift_g = shifts_g(model, table, prep, cand, &theta)?;
    let residual_after_g: Vec<f64> = residual_g
        .iter()
        .zip(&shift_g)
        .map(|(r, s)| r - s)
        .collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let ln_n = (n as f64).ln();
    Ok(EffectFit {
        kind: cand.kind.to_string(),
        params,
        table: effect_table(cand, &theta),
        n,
        k,
        chi2_before,
        chi2_after,
        chi2_per_dof_after: chi2_after / dof as f64,
        p_value_after: chi2_sf(chi2_after, dof),
        bic_before: chi2_before,
        bic_after: chi2_after + k as f64 * ln_n,
        delta_bic: chi2_after + k as f64 * ln_n - chi2_before,
        rms_residual_before_g: rms(&residual_g),
        rms_residual_after_g: rms(&residual_after_g),
        shift_g,
        residual_after_g,
        evaluations: pb.evaluations,
    })
}

/// `P(X >= x)` for `X ~ chi2(dof)`.
pub fn chi2_sf(x: f64, dof: usize) -> f64 {
    match ChiSquared::new(dof.max(1) as f64) {
        Ok(d) => d.sf(x.max(0.0)),
        Err(_) => f64::NAN,
    }
}
