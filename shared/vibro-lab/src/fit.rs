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

use crate::library::{Candidate, ParamSpec, Search};
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
    /// candidate's fit may take (its start scores and each of its three refinements,
    /// which run side by side, count their own). The walkthrough's fits take at most
    /// about 200.
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
    /// Of those, the final set's profile-likelihood intervals' ([`profile`]).
    pub profile_evaluations: usize,
    /// Wall-clock time of the fits, s.
    pub elapsed_s: f64,
    /// Whether a fit was stopped by the budget.
    pub exhausted: bool,
    /// The candidates whose fit the budget stopped.
    pub cut_short: Vec<String>,
    /// Where the evaluations and the time went, by stage of the search, in the order
    /// the stages first ran (a stage that runs again adds to its entry).
    pub stages: Vec<StageUse>,
}

/// One stage's share of a [`BudgetUsed`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageUse {
    pub stage: String,
    pub evaluations: usize,
    pub elapsed_s: f64,
}

/// A request to stop a long call from outside (a front end's Ctrl-C, a Python
/// progress callback that raised): once [`Stop::request`]ed, every model evaluation
/// fails as if the budget ran out (`Error::Budget`, "stopped"), so that the fits in
/// flight end within one evaluation and the search runs out of work at once. The
/// call's result is then partial: the one who asked discards it. None by default.
#[derive(Debug, Clone, Default)]
pub struct Stop(pub Option<std::sync::Arc<std::sync::atomic::AtomicBool>>);

impl Stop {
    /// A stop that can be requested (by this value or a clone of it).
    pub fn new() -> Self {
        Self(Some(std::sync::Arc::default()))
    }

    /// Asks the calls polling this stop (and its clones) to stop.
    pub fn request(&self) {
        if let Some(flag) = &self.0 {
            flag.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// Whether a stop was requested.
    pub fn requested(&self) -> bool {
        self.0
            .as_ref()
            .is_some_and(|flag| flag.load(std::sync::atomic::Ordering::Relaxed))
    }
}

/// A [`Budget`] running: the deadline and the evaluations over all fits.
pub(crate) struct Meter {
    pub(crate) budget: Budget,
    /// The caller's request to stop ([`Stop`]), polled before every evaluation.
    pub(crate) stop: Stop,
    pub(crate) start: std::time::Instant,
    pub(crate) evaluations: std::sync::atomic::AtomicUsize,
    /// The stages closed so far and where the last one ended (evaluations, s).
    stages: std::sync::Mutex<(Vec<StageUse>, usize, f64)>,
}

impl Meter {
    pub(crate) fn new(budget: Budget) -> Self {
        Self::stoppable(budget, Stop::default())
    }

    /// A meter whose evaluations fail once `stop` is requested.
    pub(crate) fn stoppable(budget: Budget, stop: Stop) -> Self {
        Self {
            budget,
            stop,
            start: std::time::Instant::now(),
            evaluations: std::sync::atomic::AtomicUsize::new(0),
            stages: std::sync::Mutex::new((Vec::new(), 0, 0.0)),
        }
    }

    /// Books the evaluations and time since the last stage ended to `stage`.
    pub(crate) fn close_stage(&self, stage: &str) {
        let (total, now) = (self.total(), self.elapsed_s());
        let mut guard = self
            .stages
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let (list, evals, secs) = &mut *guard;
        let (de, ds) = (total - *evals, now - *secs);
        *evals = total;
        *secs = now;
        match list.iter_mut().find(|s| s.stage == stage) {
            Some(s) => {
                s.evaluations += de;
                s.elapsed_s += ds;
            }
            None => list.push(StageUse {
                stage: stage.to_string(),
                evaluations: de,
                elapsed_s: ds,
            }),
        }
    }

    /// The stages closed so far.
    pub(crate) fn stages(&self) -> Vec<StageUse> {
        self.stages
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .0
            .clone()
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
    /// The effect it belongs to.
    pub effect: String,
    pub name: String,
    pub value: f64,
    /// Standard uncertainty (infinite: the table does not determine it), from
    /// `J^T J` at the minimum (linearised).
    pub sigma: f64,
    /// The 68 % interval's reach below and above `value`: the profile likelihood's
    /// (`chi2` up by the Birge ratio squared, every other parameter refitted:
    /// [`profile`]) for a parameter that enters nonlinearly, `sigma` for the others
    /// and before profiling. Along a curved valley (a resonance's `freq_hz` and `q`
    /// from one random spectrum) they differ from `sigma` and from each other.
    pub sigma_minus: f64,
    pub sigma_plus: f64,
    /// The 99.73 % interval's reach below and above `value` (`chi2` up by 9 times the
    /// Birge ratio squared), `3 sigma` where not profiled: "within 3 standard
    /// uncertainties" of a curved valley means inside it.
    pub three_sigma_minus: f64,
    pub three_sigma_plus: f64,
}

/// Whether `p`'s profile-likelihood reach differs from its linearised `sigma` by more
/// than 5 % on either side (then both are worth stating).
pub fn asymmetric(p: &FittedParam) -> bool {
    let off = |r: f64| r.is_finite() && (r - p.sigma).abs() > 0.05 * p.sigma;
    p.sigma.is_finite() && (off(p.sigma_minus) || off(p.sigma_plus))
}

impl FittedParam {
    /// The standard uncertainty on the side of `truth`: `sigma_minus` below the value,
    /// `sigma_plus` above it.
    pub fn sigma_toward(&self, truth: f64) -> f64 {
        if truth < self.value {
            self.sigma_minus
        } else {
            self.sigma_plus
        }
    }

    /// `(truth - value)` in standard uncertainties on the side of `truth`.
    pub fn pull(&self, truth: f64) -> f64 {
        (truth - self.value) / self.sigma_toward(truth)
    }

    /// Whether `truth` lies inside the 99.73 % interval (3 standard uncertainties).
    pub fn within_three_sigma(&self, truth: f64) -> bool {
        (self.value - self.three_sigma_minus..=self.value + self.three_sigma_plus).contains(&truth)
    }
}

/// Rows on which an effect could not be evaluated, and why: it was fitted (or, for
/// an effect of the model, predicted) on the other rows only.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NotApplicable {
    pub effect: String,
    /// `(line, run_id)` of each row left out.
    pub rows: Vec<(usize, String)>,
    pub reason: String,
}

/// Why a filtering effect cannot act on a random row without a spectrum (no default
/// spectrum is assumed: docs/lab.md, "Mixed tables").
pub const NO_SPECTRUM: &str = "random vibration without a spectrum (no band_lo_hz/band_hi_hz, no \
     band PSDs): the effect filters the vibration over frequency, and no default spectrum is \
     assumed";

/// Whether effect `kind` can be evaluated on condition `c`: an effect that filters the
/// vibration over frequency (`Candidate::needs_spectrum`) cannot act on a random part
/// whose spectrum the row does not give.
pub fn applies(kind: &str, c: &crate::table::Condition) -> bool {
    let needs = crate::library::candidate(kind).is_some_and(|k| k.needs_spectrum);
    !(needs && c.random.is_some() && c.psd().is_empty())
}

/// A set of effects fitted jointly to a campaign (one effect: `kinds.len() == 1`).
#[derive(Debug, Clone, Serialize)]
pub struct EffectFit {
    /// The effect this fit ranks: the last of `kinds` (the one a stepwise search adds).
    pub kind: String,
    /// Every effect of the fit, in order; all their parameters were free.
    pub kinds: Vec<String>,
    /// Every parameter, effect by effect.
    pub params: Vec<FittedParam>,
    /// Correlation coefficients between the parameters, in `params` order (NaN for a
    /// parameter the table does not determine).
    pub correlation: Vec<Vec<f64>>,
    /// The `[[effect]]` tables with the fitted values, one per effect (what `lab add`
    /// writes).
    #[serde(skip)]
    pub tables: Vec<toml::Table>,
    pub n: usize,
    /// Parameters fitted, over all effects.
    pub k: usize,
    pub chi2_before: f64,
    pub chi2_after: f64,
    /// `chi2_after / (n - k)`.
    pub chi2_per_dof_after: f64,
    /// Probability of a chi2 at least this large if the extended model were right.
    pub p_value_after: f64,
    pub bic_before: f64,
    pub bic_after: f64,
    /// `bic_after - bic_before`: against the model the effects were fitted to.
    pub delta_bic: f64,
    pub rms_residual_before_g: f64,
    pub rms_residual_after_g: f64,
    /// The fitted effects' VE change per condition, g.
    pub shift_g: Vec<f64>,
    /// Each effect's share of `shift_g`, in `kinds` order.
    #[serde(skip)]
    pub effect_shift_g: Vec<Vec<f64>>,
    /// Residual per condition after the fit, g.
    pub residual_after_g: Vec<f64>,
    /// Rows some effect of the fit could not act on.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub not_applicable: Vec<NotApplicable>,
    /// Model evaluations the fit took.
    pub evaluations: usize,
}

impl EffectFit {
    /// The fitted values of effect `kind`, in its parameters' order.
    pub fn values_of(&self, kind: &str) -> Vec<f64> {
        self.params
            .iter()
            .filter(|p| p.effect == kind)
            .map(|p| p.value)
            .collect()
    }

    /// The parameters of effect `kind`.
    pub fn params_of(&self, kind: &str) -> Vec<FittedParam> {
        self.params
            .iter()
            .filter(|p| p.effect == kind)
            .cloned()
            .collect()
    }
}

/// What a fit needs per condition, computed once: the model's prediction and the
/// true vibration under the model's own sensor effects.
///
/// Rows of one condition (equal [`crate::table::Condition::prediction_key`] and
/// passport: a campaign's repeats, a table of a million identical rows) are one
/// *class*: the model and every effect fitted give them the same VE, so it is computed
/// once per class (here, in [`term_shifts_g`] at each of a fit's evaluations, in
/// [`Prepared::reweight`]) and copied to its rows. Each row keeps its own measured VE
/// and uncertainty, so the fits, their chi2 and every statistic are those of the rows,
/// bit for bit: only the work and the memory of the predictions scale with the classes
/// instead of the rows.
pub(crate) struct Prepared {
    pub(crate) measured_g: Vec<f64>,
    pub(crate) uncertainty_g: Vec<f64>,
    pub(crate) predicted_g: Vec<f64>,
    /// Per row, its class (an index into the per-class vectors below).
    pub(crate) class: Vec<usize>,
    /// Per class, the first of its rows (the one it is evaluated on and errors name).
    pub(crate) first_row: Vec<usize>,
    /// Per class, the true vibration under the model's sensor effects.
    truth: Vec<predict::TrueVibration>,
    /// Per class, the vibration and band PSD reaching the unit: the truth through the
    /// model's effects on the vibration path (what a new effect off that path sees).
    seen: Vec<(
        vibro_physics::vibration::Vibration,
        Vec<vibro_physics::vibration::PsdBand>,
    )>,
    /// Per class, the model's effect tables that act there.
    model_tables: Vec<Vec<toml::Table>>,
    /// The model's effects that could not act on some rows.
    pub(crate) skipped: Vec<NotApplicable>,
    /// The logs' scales per unit under the weights as they are
    /// ([`crate::flight::data_scales`]).
    pub(crate) scales: Vec<crate::flight::GroupScale>,
}

/// Each row's class ([`Prepared`]) and each class's first row.
fn classes(table: &CampaignTable) -> (Vec<usize>, Vec<usize>) {
    let mut index: std::collections::HashMap<crate::table::PredictionKey, usize> =
        std::collections::HashMap::new();
    let mut class = Vec::with_capacity(table.conditions.len());
    let mut first_row: Vec<usize> = Vec::new();
    for (i, c) in table.conditions.iter().enumerate() {
        let key = c.prediction_key();
        let k = match index.get(&key) {
            // The passport as resolved too (two tables' `my.toml` may differ).
            Some(&k) if table.conditions[first_row[k]].passport == c.passport => k,
            Some(_) => {
                first_row.push(i);
                first_row.len() - 1
            }
            None => {
                first_row.push(i);
                index.insert(key, first_row.len() - 1);
                first_row.len() - 1
            }
        };
        class.push(k);
    }
    (class, first_row)
}

/// Adds `(line, run_id)` to the rows `kind` skipped.
fn note_skipped(out: &mut Vec<NotApplicable>, kind: &str, c: &crate::table::Condition) {
    let row = (c.line, c.run_id.clone());
    match out.iter_mut().find(|n| n.effect == kind) {
        Some(n) => n.rows.push(row),
        None => out.push(NotApplicable {
            effect: kind.to_string(),
            rows: vec![row],
            reason: NO_SPECTRUM.to_string(),
        }),
    }
}

fn kind_of(t: &toml::Table) -> &str {
    t.get("kind").and_then(|k| k.as_str()).unwrap_or("?")
}

impl Prepared {
    pub(crate) fn new(model: &LabModel, table: &CampaignTable) -> Result<Self> {
        Self::with_classes(model, table, classes(table), None)
    }

    /// [`Self::new`] with some rows' predictions given (`predicted_g[i]`, a log's windows
    /// predicted by the waveform stage, `crate::waveform`); the others', the stated
    /// uncertainties and the logs' scales as `new` makes them, the scales from the
    /// residuals against the given predictions.
    pub(crate) fn with_predictions(
        model: &LabModel,
        table: &CampaignTable,
        predicted_g: &[Option<f64>],
    ) -> Result<Self> {
        Self::with_classes(model, table, classes(table), Some(predicted_g))
    }

    /// Without pooling: every row its own class (the tests hold the pooled fits
    /// against it).
    #[cfg(test)]
    pub(crate) fn one_class_per_row(model: &LabModel, table: &CampaignTable) -> Result<Self> {
        let rows: Vec<usize> = (0..table.conditions.len()).collect();
        Self::with_classes(model, table, (rows.clone(), rows), None)
    }

    fn with_classes(
        model: &LabModel,
        table: &CampaignTable,
        (class, first_row): (Vec<usize>, Vec<usize>),
        given_g: Option<&[Option<f64>]>,
    ) -> Result<Self> {
        let mut p = Prepared {
            measured_g: Vec::with_capacity(class.len()),
            uncertainty_g: Vec::with_capacity(class.len()),
            predicted_g: Vec::with_capacity(class.len()),
            class,
            first_row,
            truth: Vec::new(),
            seen: Vec::new(),
            model_tables: Vec::new(),
            skipped: Vec::new(),
            scales: Vec::new(),
        };
        // Per class: the prediction, and the stated vibration's variance terms
        // (`vibration_var_terms_g2`), which read the condition only.
        let mut class_pred_g = Vec::with_capacity(p.first_row.len());
        let mut class_var_terms = Vec::with_capacity(p.first_row.len());
        for &i in &p.first_row {
            let c = &table.conditions[i];
            let tables: Vec<toml::Table> = model
                .effects
                .iter()
                .filter(|t| applies(kind_of(t), c))
                .cloned()
                .collect();
            let effects = build_effects(&tables, &c.passport)?;
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
            class_pred_g.push(pred.ve_g);
            p.seen.push(
                predict::unit_vibration(
                    &effects,
                    &c.passport,
                    c.a_l_g,
                    &truth.vibration,
                    &truth.psd,
                )
                .map_err(row)?,
            );
            p.truth.push(truth);
            p.model_tables.push(tables);
            class_var_terms.push(vibration_var_terms_g2(model.mode, &effects, c)?);
        }
        for (i, (c, &k)) in table.conditions.iter().zip(&p.class).enumerate() {
            let given = given_g.and_then(|g| g.get(i).copied().flatten());
            for t in &model.effects {
                if given.is_none() && !applies(kind_of(t), c) {
                    note_skipped(&mut p.skipped, kind_of(t), c);
                }
            }
            p.measured_g.push(c.ve_measured_g);
            p.predicted_g.push(given.unwrap_or(class_pred_g[k]));
        }
        let stated: Vec<f64> = table
            .conditions
            .iter()
            .zip(&p.class)
            .map(|(c, &k)| stated_u_g(c, &class_var_terms[k]))
            .collect();
        let (factor, scales) =
            crate::flight::data_scales(&table.conditions, &p.residual_g(), &stated);
        p.scales = scales;
        for ((c, u0_g), f) in table.conditions.iter().zip(&stated).zip(&factor) {
            let u_g = f * u0_g;
            let i = p.uncertainty_g.len();
            // Residuals and weights must stay finite: `(r/u)^2` summed over the
            // table is the fits' cost.
            let (m, pred) = (p.measured_g[i], p.predicted_g[i]);
            let z = (m - pred) / u_g;
            if !(pred.is_finite() && (z * z).is_finite() && u_g > 0.0) {
                return Err(Error::Numeric {
                    what: format!("{} (line {}, {})", table.path.display(), c.line, c.run_id),
                    reason: format!(
                        "measured {m:e} g, predicted {pred:e} g, uncertainty {:e} g: the \
                         predicted VE and (residual/uncertainty)^2 must be finite",
                        c.ve_uncertainty_g
                    ),
                });
            }
            p.uncertainty_g.push(u_g);
        }
        Ok(p)
    }

    /// How many classes (distinct conditions) the rows fall into.
    pub(crate) fn classes(&self) -> usize {
        self.first_row.len()
    }

    /// The vibration and band PSD reaching the unit on row `i` (`seen`, per class).
    pub(crate) fn seen_of(
        &self,
        i: usize,
    ) -> &(
        vibro_physics::vibration::Vibration,
        Vec<vibro_physics::vibration::PsdBand>,
    ) {
        &self.seen[self.class[i]]
    }

    /// The rows' uncertainties again with `extra` (fitted effects) added to `model`:
    /// the stated vibration's propagated through it, and a log's scale from the
    /// residuals against it ([`crate::flight::data_scales`]): the weights of the next
    /// fits. The effects and the stated vibration's terms are evaluated once per class.
    pub(crate) fn reweight(
        &mut self,
        model: &LabModel,
        table: &CampaignTable,
        extra: &[toml::Table],
    ) -> Result<()> {
        let moves = |c: &crate::table::Condition| c.states_vibration_u() || c.scale_group.is_some();
        // Which classes hold rows whose weights move, and rows of a log (whose scale
        // needs the VE the extended model predicts); a log's window and a table's row
        // may be one class, the scale group being no part of the condition.
        let mut needs = vec![(false, false); self.classes()];
        for (c, &k) in table.conditions.iter().zip(&self.class) {
            needs[k].0 |= moves(c);
            needs[k].1 |= c.scale_group.is_some();
        }
        // Per such class: the stated vibration's variance terms, and the VE.
        let mut per_class: Vec<Option<(Vec<f64>, Option<f64>)>> = vec![None; self.classes()];
        for (k, &i) in self.first_row.iter().enumerate() {
            let (weights_move, log_row) = needs[k];
            if !weights_move {
                continue;
            }
            let c = &table.conditions[i];
            let mut tables = self.model_tables[k].clone();
            tables.extend(extra.iter().filter(|t| applies(kind_of(t), c)).cloned());
            let effects = build_effects(&tables, &c.passport)?;
            let ve_g = if log_row {
                Some(row_ve_g(model.mode, &effects, c, c)?)
            } else {
                None
            };
            per_class[k] = Some((vibration_var_terms_g2(model.mode, &effects, c)?, ve_g));
        }
        let mut residual_g = Vec::with_capacity(table.conditions.len());
        let mut stated = Vec::with_capacity(table.conditions.len());
        for (i, c) in table.conditions.iter().enumerate() {
            // Rows whose weights do not move keep theirs (a scale of 1: no group).
            match &per_class[self.class[i]] {
                Some((terms, ve_g)) if moves(c) => {
                    residual_g.push(match (ve_g, c.scale_group) {
                        (Some(ve_g), Some(_)) => c.ve_measured_g - ve_g,
                        _ => self.measured_g[i] - self.predicted_g[i],
                    });
                    stated.push(stated_u_g(c, terms));
                }
                _ => {
                    residual_g.push(self.measured_g[i] - self.predicted_g[i]);
                    stated.push(self.uncertainty_g[i]);
                }
            }
        }
        let (factor, scales) = crate::flight::data_scales(&table.conditions, &residual_g, &stated);
        self.scales = scales;
        for (i, c) in table.conditions.iter().enumerate() {
            if moves(c) {
                self.uncertainty_g[i] = factor[i] * stated[i];
            }
        }
        Ok(())
    }

    pub(crate) fn residual_g(&self) -> Vec<f64> {
        self.measured_g
            .iter()
            .zip(&self.predicted_g)
            .map(|(m, p)| m - p)
            .collect()
    }
}

/// The VE `effects` predict at `row`'s stated conditions (`of`: the row the messages
/// name).
fn row_ve_g(
    mode: vibro_effects::model::BaseMode,
    effects: &[Box<dyn vibro_effects::Effect>],
    row: &crate::table::Condition,
    of: &crate::table::Condition,
) -> Result<f64> {
    predict::predict_ve(
        mode,
        effects,
        &row.passport,
        row.a_l_g,
        &row.vibration(),
        &row.psd(),
        row.vibrating_s(),
    )
    .map(|p| p.ve_g)
    .map_err(|e| Error::Predict {
        what: format!(
            "line {} ({}): the stated vibration's uncertainty",
            of.line, of.run_id
        ),
        reason: e.to_string(),
    })
}

/// A row's standard uncertainty of the residual: the measured VE's
/// (`ve_uncertainty_g`) and the stated IA vibration's (`aB3_u_g`, `sigma3_u_g`)
/// through the model with `effects`, `dVE/daB3` and `dVE/dsigma3` by central
/// differences (the effective-variance method: the model is evaluated at the stated
/// vibration, so the sensor's error moves the prediction, by how much the model says),
/// and the stated band PSDs' through the effects that read them. A log's rows take it
/// times their data scale ([`crate::flight::data_scales`]) as a whole: the measured VE
/// and the spectrum a window states come from the same realised vibration, so every
/// part of it overlaps the measured VE's scatter (a mount's band term left unscaled
/// put chi2/dof at 0.54 with the generator's true mount on its rig logs).
// The one-call form, which the tests check; the fits use its two parts, the second
// once per class (`Prepared`).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn effective_u_g(
    mode: vibro_effects::model::BaseMode,
    effects: &[Box<dyn vibro_effects::Effect>],
    c: &crate::table::Condition,
) -> Result<f64> {
    Ok(stated_u_g(c, &vibration_var_terms_g2(mode, effects, c)?))
}

/// [`effective_u_g`] from the row's stated VE uncertainty and the terms of its stated
/// vibration's variance ([`vibration_var_terms_g2`]), added in order.
fn stated_u_g(c: &crate::table::Condition, terms_g2: &[f64]) -> f64 {
    let mut var = c.ve_uncertainty_g.powi(2);
    for t in terms_g2 {
        var += t;
    }
    var.sqrt()
}

/// The terms [`effective_u_g`] adds to the measured VE's variance, in order: the
/// stated IA amplitude's, the stated IA RMS's and each stated band PSD's through the
/// model (g^2). They read the row's condition only (not its measured VE or its
/// uncertainty): one computation serves every row of a class ([`Prepared`]).
fn vibration_var_terms_g2(
    mode: vibro_effects::model::BaseMode,
    effects: &[Box<dyn vibro_effects::Effect>],
    c: &crate::table::Condition,
) -> Result<Vec<f64>> {
    let (ua_g, us_g) = c.ia_u_g();
    let mut terms = Vec::new();
    let ve = |row: &crate::table::Condition| row_ve_g(mode, effects, row, c);
    if let (Some(t), true) = (c.tone, ua_g > 0.0) {
        let h = 1e-3 * t.a_b_g[2].abs().max(ua_g);
        let mut up = c.clone();
        let mut down = c.clone();
        if let (Some(a), Some(b)) = (up.tone.as_mut(), down.tone.as_mut()) {
            a.a_b_g[2] += h;
            b.a_b_g[2] = (b.a_b_g[2] - h).max(0.0);
        }
        let span = up.tone.map_or(0.0, |t| t.a_b_g[2]) - down.tone.map_or(0.0, |t| t.a_b_g[2]);
        let d = (ve(&up)? - ve(&down)?) / span;
        terms.push((d * ua_g).powi(2));
    }
    if let (Some(r), true) = (c.random, us_g > 0.0) {
        let s3 = r.sigma_g[2];
        if s3 > 0.0 {
            let k = 1e-3;
            let scaled = |f: f64| {
                let mut row = c.clone();
                if let Some(x) = row.random.as_mut() {
                    x.sigma_g[2] *= f;
                    x.cov31_g2 *= f;
                    x.cov32_g2 *= f;
                }
                for b in &mut row.bands {
                    b.psd_g2_per_hz[2] *= f * f;
                }
                row
            };
            let d = (ve(&scaled(1.0 + k))? - ve(&scaled(1.0 - k))?) / (2.0 * k * s3);
            terms.push((d * us_g).powi(2));
        }
    }
    // The stated band PSDs' uncertainties (a flight window's), each band and axis on
    // its own: `dVE/dS_b,j` by central differences with the broadband variance held
    // (the base model's share of the vibration's uncertainty is already in
    // `ve_uncertainty_g`, `flight::prediction_u_g`, and the base model reads no band),
    // so this is the spectrum's uncertainty through the effects that read it: 0 for a
    // model without them. The bands' errors are taken as independent.
    if c.bands_u.len() == c.bands.len() {
        for (b, bu) in c.bands_u.iter().enumerate() {
            for axis in 0..3 {
                let u = bu.psd_g2_per_hz[axis];
                let s = c.bands[b].psd_g2_per_hz[axis];
                if !(u > 0.0 && u.is_finite() && s.is_finite()) {
                    continue;
                }
                let h = 1e-3 * s.max(u);
                let with = |d: f64| {
                    let mut row = c.clone();
                    row.bands[b].psd_g2_per_hz[axis] = (s + d).max(0.0);
                    row
                };
                let span = (s + h) - (s - h).max(0.0);
                let d = (ve(&with(h))? - ve(&with(-h))?) / span;
                terms.push((d * u).powi(2));
            }
        }
    }
    Ok(terms)
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

/// `theta` (all effects' parameters, effect by effect) cut into each effect's.
fn split<'t>(terms: &[&Candidate], theta: &'t [f64]) -> Vec<&'t [f64]> {
    let mut out = Vec::with_capacity(terms.len());
    let mut at = 0;
    for t in terms {
        let k = t.params.len().min(theta.len().saturating_sub(at));
        out.push(&theta[at..at + k]);
        at += k;
    }
    out
}

/// Each effect's VE change on every condition when `terms` with parameters `theta`
/// (effect by effect) are added to the model together: `[effect][row]`. An effect
/// that cannot act on a row ([`applies`]) changes nothing there.
///
/// The effects' mean contributions add (`vibro_effects::predict`); a sensor effect
/// changes the vibration every other effect sees, so with one the whole prediction
/// is redone: its share is the model's change with the sensor effects, the others'
/// their contributions under the vibration so corrected (the shares add up to the
/// extended model's prediction exactly).
pub(crate) fn term_shifts_g(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&Candidate],
    theta: &[f64],
) -> Result<Vec<Vec<f64>>> {
    let tables: Vec<toml::Table> = terms
        .iter()
        .zip(split(terms, theta))
        .map(|(c, th)| effect_table(c, th))
        .collect();
    // The effects built once per passport of the table (most tables have one), not
    // once per row: building parses and validates each effect's table.
    type Built<'a> = (&'a str, Vec<Vec<Box<dyn vibro_effects::Effect>>>);
    let mut built: Vec<Built> = Vec::new();
    // Per class ([`Prepared`]): evaluated on its first row, copied to the others.
    let n = prep.classes();
    let mut out = vec![vec![0.0; n]; terms.len()];
    /// The effects of a whole prediction, for the rows that need one.
    struct ComposedBuilt<'a> {
        passport: usize,
        acts: Vec<bool>,
        sensor: Vec<bool>,
        model: &'a Vec<toml::Table>,
        all: Vec<Box<dyn vibro_effects::Effect>>,
        slot: Vec<Option<usize>>,
    }
    let mut composed_built: Vec<ComposedBuilt> = Vec::new();
    for (i, &row_i) in prep.first_row.iter().enumerate() {
        let c = &table.conditions[row_i];
        let k = match built.iter().position(|(r, _)| *r == c.passport_ref) {
            Some(k) => k,
            None => {
                let mut per = Vec::with_capacity(tables.len());
                for t in &tables {
                    per.push(build_effects(std::slice::from_ref(t), &c.passport)?);
                }
                built.push((&c.passport_ref, per));
                built.len() - 1
            }
        };
        let row = |kind: &str, e: vibro_effects::Error| Error::Predict {
            what: format!("{kind} on line {} ({})", c.line, c.run_id),
            reason: e.to_string(),
        };
        let truth = &prep.truth[i];
        let acts: Vec<bool> = terms.iter().map(|t| applies(t.kind, c)).collect();
        let sensor: Vec<bool> = built[k]
            .1
            .iter()
            .zip(&acts)
            .map(|(e, a)| {
                *a && predict::sensor_rms_factor(
                    e,
                    &c.passport,
                    c.a_l_g,
                    &truth.vibration,
                    &truth.psd,
                ) != 1.0
            })
            .collect();
        let path: Vec<bool> = built[k]
            .1
            .iter()
            .zip(&acts)
            .map(|(e, a)| *a && e.iter().any(|x| x.on_vibration_path()))
            .collect();
        // A clip (saturation) clips the other effects' output terms too
        // (`predict::effect_shifts_g`): its share depends on them.
        let clips = built[k]
            .1
            .iter()
            .zip(&acts)
            .any(|(e, a)| *a && e.iter().any(|x| x.clips_output()));
        let composed =
            clips && (acts.iter().filter(|a| **a).count() > 1 || !prep.model_tables[i].is_empty());
        if composed || sensor.iter().chain(&path).any(|s| *s) {
            // A sensor effect changes the vibration every effect sees, one on the
            // vibration path what every effect after it sees, a clip what the others
            // output: the whole prediction with the model's effects and these, each
            // effect's share its own entry (what is left, the base's change, to the
            // first sensor or path effect).
            // Built once per passport, model and mask of the terms that act (rows
            // share them): building parses each effect's table, and a filter's band
            // integrals are kept per instance (`vibro_effects`' caches).
            let at = composed_built.iter().position(|b| {
                b.passport == k
                    && b.acts == acts
                    && b.sensor == sensor
                    && *b.model == prep.model_tables[i]
            });
            let at = match at {
                Some(at) => at,
                None => {
                    let mut all = build_effects(&prep.model_tables[i], &c.passport)?;
                    let mut slot: Vec<Option<usize>> = vec![None; terms.len()];
                    let probe = predict::true_vibration(
                        &[],
                        &c.passport,
                        c.a_l_g,
                        &c.vibration(),
                        &c.psd(),
                    )
                    .map_err(|e| row(terms[0].kind, e))?;
                    let ctx = vibro_effects::MeanContext {
                        unit: 0,
                        passport: &c.passport,
                        a_l_unit_g: c.a_l_g,
                        vibration_unit: &probe.vibration,
                        psd_unit: &probe.psd,
                        internal_rate_hz: predict::INTERNAL_RATE_HZ,
                        duration_s: f64::INFINITY,
                    };
                    // As `effect_shifts_g` tells them apart: its entries skip these.
                    let is_sensor =
                        |e: &dyn vibro_effects::Effect| e.sensor_rms_factor(&ctx).is_some();
                    let mut entry = all.iter().filter(|e| !is_sensor(e.as_ref())).count();
                    for (t, tab) in tables.iter().enumerate() {
                        if !acts[t] {
                            continue;
                        }
                        let mut one = build_effects(std::slice::from_ref(tab), &c.passport)?;
                        if !sensor[t] {
                            slot[t] = Some(entry);
                            entry += one.iter().filter(|e| !is_sensor(e.as_ref())).count();
                        }
                        all.append(&mut one);
                    }
                    composed_built.push(ComposedBuilt {
                        passport: k,
                        acts: acts.clone(),
                        sensor: sensor.clone(),
                        model: &prep.model_tables[i],
                        all,
                        slot,
                    });
                    composed_built.len() - 1
                }
            };
            let (all, slot) = (&composed_built[at].all, &composed_built[at].slot);
            let first = (0..terms.len())
                .find(|&t| sensor[t])
                .or_else(|| (0..terms.len()).find(|&t| path[t]))
                .unwrap_or(0);
            let pred = predict::predict_ve(
                model.mode,
                all,
                &c.passport,
                c.a_l_g,
                &c.vibration(),
                &c.psd(),
                c.vibrating_s(),
            )
            .map_err(|e| row(terms[first].kind, e))?;
            let mut assigned = 0.0;
            for t in 0..terms.len() {
                if let Some(sh) = slot[t].and_then(|s| pred.effects.get(s)) {
                    out[t][i] = sh.1;
                    assigned += sh.1;
                }
            }
            out[first][i] += pred.ve_g - prep.predicted_g[row_i] - assigned;
            continue;
        }
        let seen = &prep.seen[i];
        for (t, e) in built[k].1.iter().enumerate() {
            if !acts[t] {
                continue;
            }
            out[t][i] = effect_shifts_g(e, &c.passport, c.a_l_g, &seen.0, &seen.1, c.vibrating_s())
                .map_err(|err| row(terms[t].kind, err))?
                .iter()
                .map(|(_, s)| s)
                .sum();
        }
    }
    // Each row the value of its class.
    Ok(out
        .iter()
        .map(|per_class| prep.class.iter().map(|&k| per_class[k]).collect())
        .collect())
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
    product(grids)
}

/// How many starts a joint fit of `terms` from their own grids takes (the product).
pub(crate) fn start_count(terms: &[&Candidate], table: &CampaignTable) -> usize {
    terms
        .iter()
        .map(|c| starts(c, table).len().max(1))
        .fold(1usize, |a, b| a.saturating_mul(b))
}

/// Every combination of one value from each grid, in order.
fn product(grids: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
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
    terms: &'a [&'static Candidate],
    /// Every parameter's spec, effect by effect (the order of `theta`).
    specs: Vec<&'static ParamSpec>,
    /// Which of them enter linearly ([`Search::Linear`]): solved exactly at every
    /// point of a reduced search ([`Self::solve_linear`]).
    linear: Vec<bool>,
    /// The effects' kinds joined, for messages.
    what: String,
    residual_g: Vec<f64>,
    evaluations: usize,
    meter: &'a Meter,
    /// Variable projection (Golub & Pereyra 1973): an orthonormal basis `Q` of the
    /// weighted columns of a linear correction fitted beside the effects; the weighted
    /// residual is replaced by `(I - Q Q^T) w`, the correction's best coefficients
    /// profiled out at every `theta`.
    project: Option<&'a DMatrix<f64>>,
}

impl<'a> Problem<'a> {
    fn new(
        model: &'a LabModel,
        table: &'a CampaignTable,
        prep: &'a Prepared,
        terms: &'a [&'static Candidate],
        what: String,
        meter: &'a Meter,
        project: Option<&'a DMatrix<f64>>,
    ) -> Self {
        Self {
            model,
            table,
            prep,
            terms,
            specs: terms.iter().flat_map(|c| c.params.iter()).collect(),
            linear: terms
                .iter()
                .flat_map(|c| c.params.iter())
                .map(|p| matches!(p.search, Search::Linear))
                .collect(),
            what,
            residual_g: prep.residual_g(),
            evaluations: 0,
            meter,
            project,
        }
    }

    /// Weighted residuals `(r_i - s_i(theta))/u_i`, or an error.
    fn weighted(&mut self, theta: &[f64]) -> Result<DVector<f64>> {
        let b = self.meter.budget;
        if self.evaluations >= b.max_evaluations {
            return Err(Error::Budget {
                what: self.what.clone(),
                reason: format!(
                    "{} model evaluations used of max_evaluations = {}",
                    self.evaluations, b.max_evaluations
                ),
            });
        }
        if self.meter.stop.requested() {
            return Err(Error::Budget {
                what: self.what.clone(),
                reason: "stopped by the caller".into(),
            });
        }
        let elapsed_s = self.meter.elapsed_s();
        if elapsed_s >= b.time_s {
            return Err(Error::Budget {
                what: self.what.clone(),
                reason: format!("{elapsed_s:.1} s used of time_s = {} s", b.time_s),
            });
        }
        self.evaluations += 1;
        self.meter
            .evaluations
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let per = term_shifts_g(self.model, self.table, self.prep, self.terms, theta)?;
        let n = self.residual_g.len();
        let mut w = DVector::from_iterator(
            n,
            (0..n).map(|i| {
                let s: f64 = per.iter().map(|p| p[i]).sum();
                (self.residual_g[i] - s) / self.prep.uncertainty_g[i]
            }),
        );
        if let Some(q) = self.project {
            let along = q * (q.transpose() * &w);
            w -= along;
        }
        // The cost is the sum of squares: it, not only each term, must be finite.
        if !w.norm_squared().is_finite() {
            let k = w.iter().position(|x| !(x * x).is_finite()).unwrap_or(0);
            let c = &self.table.conditions[k.min(self.table.conditions.len().saturating_sub(1))];
            return Err(Error::Numeric {
                what: format!("{} on line {} ({})", self.what, c.line, c.run_id),
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
        for (x, p) in theta.iter_mut().zip(&self.specs) {
            *x = x.clamp(p.bounds.0, p.bounds.1);
        }
    }

    fn jacobian(&mut self, theta: &[f64], r: &DVector<f64>, free: &[bool]) -> Result<DMatrix<f64>> {
        self.jacobian_with(theta, r, free, false)
    }

    /// The Jacobian of the weighted residual over the `free` parameters by forward
    /// differences; with `reduce`, of the reduced residual (the linear parameters
    /// solved at each point).
    fn jacobian_with(
        &mut self,
        theta: &[f64],
        r: &DVector<f64>,
        free: &[bool],
        reduce: bool,
    ) -> Result<DMatrix<f64>> {
        let mut j = DMatrix::zeros(r.len(), theta.len());
        for k in 0..theta.len() {
            if !free[k] {
                continue;
            }
            let p = self.specs[k];
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
            let rk = self.eval(&mut t, reduce)?;
            j.set_column(k, &((rk - r) / h));
        }
        // nalgebra's SVD panics on NaN and LU steps from infinities are meaningless.
        if !(j.transpose() * &j).iter().all(|x| x.is_finite()) {
            return Err(Error::Numeric {
                what: self.what.clone(),
                reason: format!("the Jacobian or J^T J over the table is not finite at {theta:?}"),
            });
        }
        Ok(j)
    }

    /// Variable projection (Golub & Pereyra 1973; the separable problem of Kaufman
    /// 1975): the linear parameters ([`Search::Linear`]: k6 and k7, gains, coupling
    /// constants) solved by weighted least squares at `theta`'s nonlinear values,
    /// written into `theta`; the weighted residual there. Each linear parameter's
    /// column is the change of the weighted residual per unit of it (a difference over
    /// its `scale`: exact for a parameter that enters exactly linearly), the system
    /// solved by SVD with the columns scaled to unit norm (a column of zeros, an
    /// effect that acts on no row, keeps its value). A parameter that enters only
    /// nearly linearly (a sensor gain) gets Gauss-Newton steps, at most 3, each kept
    /// only when it lowers the cost; when the cost after a step is the one the
    /// linear model predicted (to 1e-9), the parameters enter linearly and the step
    /// was the solution. So a weak effect's linear parameters never stay
    /// at their start beside a strong effect already at its minimum.
    fn solve_linear(&mut self, theta: &mut [f64]) -> Result<DVector<f64>> {
        let lin: Vec<usize> = (0..theta.len()).filter(|&k| self.linear[k]).collect();
        let mut r = self.weighted(theta)?;
        if lin.is_empty() {
            return Ok(r);
        }
        let mut cost = r.norm_squared();
        for _ in 0..3 {
            let n = r.len();
            let mut b = DMatrix::zeros(n, lin.len());
            for (c, &k) in lin.iter().enumerate() {
                let p = self.specs[k];
                let mut h = p.scale.max(1e-3 * theta[k].abs());
                if theta[k] + h > p.bounds.1 {
                    h = -h;
                }
                let mut t = theta.to_vec();
                t[k] += h;
                let rk = self.weighted(&t)?;
                b.set_column(c, &((rk - &r) / h));
            }
            let norms: Vec<f64> = (0..lin.len()).map(|c| b.column(c).norm()).collect();
            for (c, nrm) in norms.iter().enumerate() {
                let f = if *nrm > 0.0 && nrm.is_finite() {
                    1.0 / nrm
                } else {
                    0.0
                };
                b.column_mut(c).scale_mut(f);
            }
            if !b.iter().all(|x| x.is_finite()) {
                break;
            }
            let svd = b.clone().svd(true, true);
            let smax = svd.singular_values.max();
            if smax <= 0.0 {
                break;
            }
            let Ok(step) = svd.solve(&(-&r), 1e-12 * smax) else {
                break;
            };
            // The cost the step gives if the parameters enter linearly.
            let predicted = (&r + &b * &step).norm_squared();
            let before: Vec<f64> = lin.iter().map(|&k| theta[k]).collect();
            for (c, &k) in lin.iter().enumerate() {
                let d = if norms[c] > 0.0 {
                    step[c] / norms[c]
                } else {
                    0.0
                };
                let p = self.specs[k];
                theta[k] = (theta[k] + d).clamp(p.bounds.0, p.bounds.1);
            }
            let rn = match self.weighted(theta) {
                Ok(rn) => rn,
                Err(e @ Error::Budget { .. }) => return Err(e),
                Err(_) => {
                    for (c, &k) in lin.iter().enumerate() {
                        theta[k] = before[c];
                    }
                    break;
                }
            };
            let cn = rn.norm_squared();
            if cn.partial_cmp(&cost) != Some(std::cmp::Ordering::Less) {
                for (c, &k) in lin.iter().enumerate() {
                    theta[k] = before[c];
                }
                break;
            }
            let rel = (cost - cn) / cost.max(1e-300);
            // The cost came out as the linear model said: the parameters enter
            // linearly here, the step solved them, and another costs evaluations
            // for nothing.
            let linear_here = (cn - predicted).abs() <= 1e-9 * cost.max(1e-300);
            r = rn;
            cost = cn;
            if rel < 1e-9 || linear_here {
                break;
            }
        }
        Ok(r)
    }

    /// The weighted residual at `theta`; with `reduce`, at `theta` with its linear
    /// parameters solved first ([`Self::solve_linear`], written into `theta`).
    fn eval(&mut self, theta: &mut [f64], reduce: bool) -> Result<DVector<f64>> {
        if reduce {
            self.solve_linear(theta)
        } else {
            self.weighted(theta)
        }
    }

    /// Levenberg-Marquardt over the free parameters from `theta`.
    fn minimise(
        &mut self,
        theta: Vec<f64>,
        free: &[bool],
        max_iter: usize,
    ) -> Result<(Vec<f64>, f64)> {
        self.minimise_with(theta, free, max_iter, false)
    }

    /// Levenberg-Marquardt over the free nonlinear parameters from `theta`, the linear
    /// ones solved at every point (variable projection, [`Self::solve_linear`]).
    fn minimise_reduced(
        &mut self,
        theta: Vec<f64>,
        free: &[bool],
        max_iter: usize,
    ) -> Result<(Vec<f64>, f64)> {
        let free: Vec<bool> = free
            .iter()
            .zip(&self.linear)
            .map(|(f, l)| *f && !*l)
            .collect();
        self.minimise_with(theta, &free, max_iter, true)
    }

    fn minimise_with(
        &mut self,
        mut theta: Vec<f64>,
        free: &[bool],
        max_iter: usize,
        reduce: bool,
    ) -> Result<(Vec<f64>, f64)> {
        let mut r = self.eval(&mut theta, reduce)?;
        if !free.iter().any(|f| *f) {
            let cost = r.norm_squared();
            return Ok((theta, cost));
        }
        let mut cost = r.norm_squared();
        let mut lambda = 1e-3;
        for _ in 0..max_iter {
            let j = self.jacobian_with(&theta, &r, free, reduce)?;
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
                let rn = match self.eval(&mut next, reduce) {
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
                    // Converged when chi2 falls by less than 1e-10 of itself or by
                    // less than `CHI2_STILL` (a parameter move of a hundredth of its
                    // sigma or less: nothing a test or an interval can see).
                    improved = rel > 1e-10 && cost - cn > CHI2_STILL;
                    theta = next;
                    r = rn;
                    cost = cn;
                    lambda = (lambda / 3.0).max(1e-12);
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

/// The fall of chi2 below which a Levenberg-Marquardt step counts as converged: a
/// parameter moved by `d` sigma lowers chi2 by about `d^2`, so 1e-4 is a hundredth of
/// a sigma, far inside every interval and test.
const CHI2_STILL: f64 = 1e-4;

/// Fits `cand` to the residual of `model` on `table`.
pub fn fit_candidate(
    model: &LabModel,
    table: &CampaignTable,
    cand: &'static Candidate,
) -> Result<EffectFit> {
    let prep = Prepared::new(model, table)?;
    fit_prepared(model, table, &prep, cand, &Meter::new(Budget::default()))
}

pub(crate) fn fit_prepared(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    cand: &'static Candidate,
    meter: &Meter,
) -> Result<EffectFit> {
    fit_joint(model, table, prep, &[cand], &[None], meter)
}

/// Parameter covariance from `J^T J` at the minimum: each column of `J` scaled to
/// unit norm first (the parameters' units differ by many decades), the scaled matrix
/// inverted by SVD. A parameter with a share above 1e-3 in a direction the table does
/// not determine (singular value below 1e-10 of the largest) gets an infinite
/// variance, the others their part of the pseudo-inverse.
fn covariance(a: &DMatrix<f64>) -> (DMatrix<f64>, Vec<bool>) {
    let k = a.nrows();
    let d: Vec<f64> = (0..k).map(|i| a[(i, i)].max(0.0).sqrt()).collect();
    let scaled = DMatrix::from_fn(k, k, |i, j| {
        if d[i] > 0.0 && d[j] > 0.0 {
            a[(i, j)] / (d[i] * d[j])
        } else {
            0.0
        }
    });
    let svd = scaled.svd(true, true);
    let smax = svd.singular_values.max().max(1e-300);
    let mut determined: Vec<bool> = d.iter().map(|x| *x > 0.0).collect();
    if let Some(v_t) = &svd.v_t {
        for (s, row) in svd.singular_values.iter().zip(v_t.row_iter()) {
            if *s <= 1e-10 * smax {
                for i in 0..k {
                    if row[i].abs() > 1e-3 {
                        determined[i] = false;
                    }
                }
            }
        }
    }
    let pinv = svd
        .pseudo_inverse(1e-10 * smax)
        .unwrap_or_else(|_| DMatrix::zeros(k, k));
    let cov = DMatrix::from_fn(k, k, |i, j| {
        if determined[i] && determined[j] {
            pinv[(i, j)] / (d[i] * d[j])
        } else if i == j {
            f64::INFINITY
        } else {
            f64::NAN
        }
    });
    (cov, determined)
}

/// Fits the effects `terms` jointly (all parameters free) to the residual of `model`
/// on `table`. `known[t]`: where effect `t` starts (its values in an earlier fit);
/// `None`: its own start grid. At each start the linear parameters are solved
/// ([`Problem::solve_linear`]); the three best distinct starts are refined: the
/// unknown effects' nonlinear parameters first (when some effects are known), then
/// every nonlinear one with the linear ones solved at each point (60 iterations),
/// then every parameter at once (60).
pub(crate) fn fit_joint(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&'static Candidate],
    known: &[Option<Vec<f64>>],
    meter: &Meter,
) -> Result<EffectFit> {
    fit_joint_projected(model, table, prep, terms, known, meter, None)
}

/// The joint fit of the set `terms`, the same whatever the path that led to it
/// (`lab add A,B`, `lab add --diagnosed`, `lab report` and `lab diagnose` call it on
/// the same set and get the same fit): the set in the library's order, built up
/// greedily. Each effect not in the set yet is fitted jointly with those already in
/// it (they start at their values, it from its own grid, fitted first to what they
/// leave; [`fit_joint`]), the one with the lowest BIC joins, until all have. A joint
/// fit from the product of the effects' own grids would take their product of starts
/// (a resonance's 48 times a saturation's 19), and one from a strong effect at its
/// minimum and a weak one at its start stops there; the greedy build-up starts each
/// effect where it explains what the others leave. `known` values (a model's own
/// effects) are one more start for the whole set; the lower chi2 wins.
///
/// `singles`: fits of one effect alone made on the same `prep` by [`fit_joint`] with
/// no known values (a diagnosis's first round), used instead of fitting again: the
/// same computation, so the same fit.
pub(crate) fn fit_set(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&'static Candidate],
    known: &[Option<Vec<f64>>],
    singles: &[&EffectFit],
    meter: &Meter,
) -> Result<EffectFit> {
    let order = |c: &Candidate| {
        crate::library::LIBRARY
            .iter()
            .position(|l| l.kind == c.kind)
    };
    let mut set: Vec<(&'static Candidate, Option<Vec<f64>>)> = terms
        .iter()
        .enumerate()
        .map(|(i, c)| (*c, known.get(i).cloned().flatten()))
        .collect();
    set.sort_by_key(|(c, _)| order(c));
    let mut chosen: Vec<&'static Candidate> = Vec::new();
    let mut values: Vec<Option<Vec<f64>>> = Vec::new();
    let mut fit: Option<EffectFit> = None;
    while chosen.len() < set.len() {
        let mut best: Option<(usize, EffectFit)> = None;
        for (i, (c, _)) in set.iter().enumerate() {
            if chosen.iter().any(|x| x.kind == c.kind) {
                continue;
            }
            let cached = singles
                .iter()
                .find(|f| chosen.is_empty() && f.kinds.len() == 1 && f.kinds[0] == c.kind);
            let f = match cached {
                Some(f) => (*f).clone(),
                None => {
                    let mut t = chosen.clone();
                    t.push(c);
                    let mut v = values.clone();
                    v.push(None);
                    fit_joint(model, table, prep, &t, &v, meter)?
                }
            };
            if best.as_ref().is_none_or(|(_, b)| f.bic_after < b.bic_after) {
                best = Some((i, f));
            }
        }
        let Some((i, f)) = best else { break };
        chosen.push(set[i].0);
        values = chosen.iter().map(|c| Some(f.values_of(c.kind))).collect();
        fit = Some(f);
    }
    let mut fit = fit.ok_or_else(|| Error::Invalid("no effect to fit".into()))?;
    if set
        .iter()
        .all(|(c, v)| v.as_ref().is_some_and(|v| v.len() == c.params.len()))
    {
        let t: Vec<&'static Candidate> = set.iter().map(|(c, _)| *c).collect();
        let v: Vec<Option<Vec<f64>>> = set.iter().map(|(_, v)| v.clone()).collect();
        if let Ok(g) = fit_joint(model, table, prep, &t, &v, meter) {
            if g.chi2_after < fit.chi2_after {
                fit = g;
            }
        }
    }
    Ok(fit)
}

/// Passes of [`fit_reweighted`] at most.
const REWEIGHT_PASSES: usize = 4;

/// The fit `fit` of `terms` again under weights that follow it (the effective-variance
/// method, [`effective_u_g`]): the rows' uncertainties with the stated vibration's
/// propagated through `model` plus the fitted effects, the effects refitted from their
/// values, until no row's uncertainty moves by more than 0.1 % (at most
/// [`REWEIGHT_PASSES`] passes), so the chi-square reported is the one at the values
/// reported. `fit` as it is when no row states its vibration's uncertainty; the last
/// good fit when a refit fails.
pub(crate) fn fit_reweighted(
    model: &LabModel,
    table: &CampaignTable,
    prep: &mut Prepared,
    terms: &[&'static Candidate],
    mut fit: EffectFit,
    meter: &Meter,
) -> Result<EffectFit> {
    if !table.weights_follow_model() {
        return Ok(fit);
    }
    for _ in 0..REWEIGHT_PASSES {
        let before = prep.uncertainty_g.clone();
        prep.reweight(model, table, &fit.tables)?;
        let moved = before
            .iter()
            .zip(&prep.uncertainty_g)
            .map(|(a, b)| ((b - a) / a).abs())
            .fold(0.0, f64::max);
        if moved <= 1e-3 {
            break;
        }
        let known: Vec<Option<Vec<f64>>> =
            terms.iter().map(|c| Some(fit.values_of(c.kind))).collect();
        match fit_joint(model, table, prep, terms, &known, meter) {
            Ok(g) => fit = g,
            Err(_) => break,
        }
    }
    Ok(fit)
}

/// [`fit_joint`] with a linear correction beside the effects, profiled out by
/// variable projection (`project`: an orthonormal basis of its weighted columns).
/// The fit's chi-square, uncertainties and correlations are then those with the
/// correction's coefficients free; its `shift_g` and residuals are the effects' alone.
pub(crate) fn fit_joint_projected(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&'static Candidate],
    known: &[Option<Vec<f64>>],
    meter: &Meter,
    project: Option<&DMatrix<f64>>,
) -> Result<EffectFit> {
    fit_joint_inner(model, table, prep, terms, known, meter, project, false)
}

/// A screening fit of `terms` for a stepwise round: like [`fit_joint`], but the
/// effects whose values are `known` keep their nonlinear parameters (every linear
/// parameter is still solved): the new effects fitted to what the known ones leave.
/// Its chi2 bounds the full joint fit's from above; a round refits the best of them
/// with everything free.
pub(crate) fn fit_screen(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&'static Candidate],
    known: &[Option<Vec<f64>>],
    meter: &Meter,
) -> Result<EffectFit> {
    fit_joint_inner(model, table, prep, terms, known, meter, None, true)
}

#[allow(clippy::too_many_arguments)]
fn fit_joint_inner(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&'static Candidate],
    known: &[Option<Vec<f64>>],
    meter: &Meter,
    project: Option<&DMatrix<f64>>,
    screen: bool,
) -> Result<EffectFit> {
    let what = terms.iter().map(|c| c.kind).collect::<Vec<_>>().join("+");
    let residual_g = prep.residual_g();
    let n = residual_g.len();
    let specs: Vec<&'static ParamSpec> = terms.iter().flat_map(|c| c.params.iter()).collect();
    let k = specs.len();
    let chi2_before: f64 = residual_g
        .iter()
        .zip(&prep.uncertainty_g)
        .map(|(r, u)| (r / u).powi(2))
        .sum();
    if !chi2_before.is_finite() {
        return Err(Error::Numeric {
            what: format!("{what} on {}", table.path.display()),
            reason: format!(
                "the residual's chi2 = sum((r/u)^2) = {chi2_before:e} overflows: uncertainties \
                 too small for the residuals"
            ),
        });
    }
    let mut pb = Problem::new(model, table, prep, terms, what.clone(), meter, project);
    let linear: Vec<bool> = specs
        .iter()
        .map(|p| matches!(p.search, Search::Linear))
        .collect();
    let all = vec![true; k];
    // Starts: the product of each effect's own (a known effect: its earlier values).
    let mut per_term: Vec<Vec<Vec<f64>>> = Vec::with_capacity(terms.len());
    for (t, c) in terms.iter().enumerate() {
        match known.get(t).and_then(|x| x.as_ref()) {
            Some(v) if v.len() == c.params.len() => per_term.push(vec![v.clone()]),
            _ => per_term.push(starts(c, table)),
        }
    }
    let mut all_starts: Vec<Vec<f64>> = vec![Vec::new()];
    for options in per_term {
        all_starts = all_starts
            .into_iter()
            .flat_map(|s| {
                options.iter().map(move |o| {
                    let mut s = s.clone();
                    s.extend_from_slice(o);
                    s
                })
            })
            .collect();
    }
    // Each start scored with its linear parameters solved (variable projection).
    let any_linear = linear.iter().any(|l| *l);
    let any_nonlinear = linear.iter().any(|l| !*l);
    // Many starts (a set refitted from every start of its effects' grids) are scored
    // side by side, in contiguous chunks each on its own problem; the scores come
    // back in the starts' order, so the fit is the same as one after the other.
    let threads = if all_starts.len() >= 16 {
        crate::parallel::available()
    } else {
        1
    };
    let chunk = all_starts.len().div_ceil(threads.max(1)).max(1);
    let chunks: Vec<Vec<Vec<f64>>> = all_starts.chunks(chunk).map(<[_]>::to_vec).collect();
    let results = crate::parallel::in_parallel(&chunks, threads, |_, starts| {
        let mut own = Problem::new(model, table, prep, terms, what.clone(), meter, project);
        let out: Vec<(Vec<f64>, Result<f64>)> = starts
            .iter()
            .map(|s| {
                let mut s = s.clone();
                let c = own.eval(&mut s, any_linear).map(|r| r.norm_squared());
                (s, c)
            })
            .collect();
        (out, own.evaluations)
    });
    let mut scored = Vec::new();
    let mut last_error = None;
    for (out, evaluations) in results {
        pb.evaluations += evaluations;
        for (s, c) in out {
            match c {
                Ok(c) => scored.push((s, c)),
                Err(e @ Error::Budget { .. }) => return Err(e),
                Err(e) => last_error = Some(e),
            }
        }
    }
    if scored.is_empty() {
        return Err(last_error.unwrap_or_else(|| Error::Invalid(format!("{what}: no start point"))));
    }
    scored.sort_by(|a, b| a.1.total_cmp(&b.1));
    // Starts on a plateau (e.g. a saturation range above every peak: no change at all)
    // tie; keep one of each cost so that the refinement starts from distinct places.
    scored.dedup_by(|b, a| (a.1 - b.1).abs() <= 1e-12 * a.1.abs());
    // The effects whose values are known (an earlier fit's) hold their nonlinear
    // parameters while the others' are searched (the new effect fitted to what the
    // known ones leave), then everything is freed: the nonlinear parameters by the
    // reduced search (the linear ones solved at every point), then all of them
    // together (a parameter that enters only nearly linearly).
    let mut searched = vec![true; k];
    {
        let mut at = 0;
        for (t, c) in terms.iter().enumerate() {
            let is_known = known
                .get(t)
                .and_then(|x| x.as_ref())
                .is_some_and(|v| v.len() == c.params.len());
            for _ in c.params {
                searched[at] = !is_known;
                at += 1;
            }
        }
    }
    let partly_known =
        searched.iter().any(|h| !*h) && searched.iter().zip(&linear).any(|(h, l)| *h && !*l);
    let screening = screen && searched.iter().any(|s| !*s);
    // The three best starts refined side by side, each on its own problem (the same
    // computation as one after the other: the same fit).
    let tops: Vec<Vec<f64>> = scored.into_iter().take(3).map(|(t, _)| t).collect();
    let refined = crate::parallel::in_parallel(&tops, crate::parallel::available(), |_, start| {
        let mut own = Problem::new(model, table, prep, terms, what.clone(), meter, project);
        let mut theta = start.clone();
        let c = if screening {
            let (t, c) = own.minimise_reduced(theta, &searched, 30)?;
            theta = t;
            c
        } else {
            if any_linear && any_nonlinear {
                if partly_known {
                    theta = own.minimise_reduced(theta, &searched, 30)?.0;
                }
                theta = own.minimise_reduced(theta, &all, 60)?.0;
            }
            let (t, c) = own.minimise(theta, &all, 60)?;
            theta = t;
            c
        };
        Ok::<_, Error>((theta, c, own.evaluations))
    });
    let mut best: Option<(Vec<f64>, f64)> = None;
    for r in refined {
        let (theta, c, evaluations) = r?;
        pb.evaluations += evaluations;
        if best.as_ref().is_none_or(|b| c < b.1) {
            best = Some((theta, c));
        }
    }
    let Some((theta, chi2_after)) = best else {
        return Err(Error::Invalid(format!("{what}: the fit found no minimum")));
    };
    // Uncertainties from J^T J at the minimum.
    let r = pb.weighted(&theta)?;
    let j = pb.jacobian(&theta, &r, &all)?;
    let a = j.transpose() * &j;
    if !a.iter().all(|x| x.is_finite()) || !chi2_after.is_finite() {
        return Err(Error::Numeric {
            what: format!("{what} on {}", table.path.display()),
            reason: format!("J^T J or chi2 = {chi2_after:e} at the minimum is not finite"),
        });
    }
    let dof = n
        .saturating_sub(k + project.map_or(0, |q| q.ncols()))
        .max(1);
    let birge = (chi2_after / dof as f64).sqrt().max(1.0);
    let (cov, determined) = covariance(&a);
    let mut params = Vec::with_capacity(k);
    let mut at = 0;
    for c in terms {
        for p in c.params {
            let sigma = if determined[at] {
                cov[(at, at)].max(0.0).sqrt() * birge
            } else {
                f64::INFINITY
            };
            params.push(FittedParam {
                effect: c.kind.to_string(),
                name: p.name.to_string(),
                value: theta[at],
                sigma,
                sigma_minus: sigma,
                sigma_plus: sigma,
                three_sigma_minus: 3.0 * sigma,
                three_sigma_plus: 3.0 * sigma,
            });
            at += 1;
        }
    }
    let correlation = (0..k)
        .map(|i| {
            (0..k)
                .map(|j| {
                    if determined[i] && determined[j] {
                        cov[(i, j)] / (cov[(i, i)] * cov[(j, j)]).sqrt().max(1e-300)
                    } else {
                        f64::NAN
                    }
                })
                .collect()
        })
        .collect();
    let effect_shift_g = term_shifts_g(model, table, prep, terms, &theta)?;
    let shift_g: Vec<f64> = (0..n)
        .map(|i| effect_shift_g.iter().map(|s| s[i]).sum())
        .collect();
    let residual_after_g: Vec<f64> = residual_g
        .iter()
        .zip(&shift_g)
        .map(|(r, s)| r - s)
        .collect();
    let mut not_applicable = Vec::new();
    for c in terms {
        for row in &table.conditions {
            if !applies(c.kind, row) {
                note_skipped(&mut not_applicable, c.kind, row);
            }
        }
    }
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let ln_n = (n as f64).ln();
    let tables = terms
        .iter()
        .zip(split(terms, &theta))
        .map(|(c, th)| effect_table(c, th))
        .collect();
    Ok(EffectFit {
        kind: terms.last().map_or(String::new(), |c| c.kind.to_string()),
        kinds: terms.iter().map(|c| c.kind.to_string()).collect(),
        params,
        correlation,
        tables,
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
        effect_shift_g,
        residual_after_g,
        not_applicable,
        evaluations: pb.evaluations,
    })
}

/// Profile-likelihood intervals for the parameters of `fit` (the joint fit of `terms`
/// by [`fit_joint`] on the same `prep`) that enter nonlinearly (a search other than
/// [`Search::Linear`]): for each side, the parameter is moved and held while every
/// other one is refitted, until `chi2` has risen by `b^2` (68.27 %) and by `9 b^2`
/// (99.73 %), `b` the Birge ratio `max(1, sqrt(chi2/dof))` as for `sigma`: Venzon &
/// Moolgavkar (1988), Press et al., Numerical Recipes 3rd ed. 15.6.5 (the MINOS
/// intervals of particle physics). Each crossing is bracketed by doubling the step
/// (from the linearised `sigma`, then from the last crossing), then found by false
/// position on `sqrt(delta chi2)` (linear in the step where the valley is quadratic),
/// safeguarded by bisection, to 1 % of the reach.
/// An interval never passes a bound of the parameter's range: it stops there when
/// chi2 has not risen enough by then, or when a refit fails first (the data then
/// bound it no closer than the range, as far as the profile can tell). A parameter
/// the table does not determine keeps its linearised reach.
pub(crate) fn profile(
    model: &LabModel,
    table: &CampaignTable,
    prep: &Prepared,
    terms: &[&'static Candidate],
    fit: &mut EffectFit,
    meter: &Meter,
) -> Result<()> {
    let specs: Vec<&'static ParamSpec> = terms.iter().flat_map(|c| c.params.iter()).collect();
    if specs.len() != fit.params.len() {
        return Err(Error::Invalid(format!(
            "profile: {} parameters in the fit, {} in its effects",
            fit.params.len(),
            specs.len()
        )));
    }
    let theta0: Vec<f64> = fit.params.iter().map(|p| p.value).collect();
    let what = format!("{} (profile)", fit.kinds.join("+"));
    let mut pb = Problem::new(model, table, prep, terms, what, meter, None);
    // The fit's minimum, on the same weights.
    let chi2_min = fit.chi2_after;
    let dof = fit.n.saturating_sub(fit.k).max(1);
    let b2 = (chi2_min / dof as f64).max(1.0);
    for k in 0..specs.len() {
        let sigma = fit.params[k].sigma;
        if matches!(specs[k].search, Search::Linear) || !(sigma.is_finite() && sigma > 0.0) {
            continue;
        }
        let mut free = vec![true; specs.len()];
        free[k] = false;
        let mut reach = [[sigma, 3.0 * sigma], [sigma, 3.0 * sigma]];
        for (side, dir) in [-1.0_f64, 1.0].into_iter().enumerate() {
            let bound = if dir < 0.0 {
                theta0[k] - specs[k].bounds.0
            } else {
                specs[k].bounds.1 - theta0[k]
            };
            // The last point below the target: (step, delta chi2, the others' values).
            let mut lo = (0.0, 0.0, theta0.clone());
            let mut d = sigma.min(bound);
            for (level, target) in [b2, 9.0 * b2].into_iter().enumerate() {
                match crossing(&mut pb, k, &free, dir, chi2_min, target, bound, d, &mut lo) {
                    Some(r) => {
                        reach[side][level] = r;
                        d = (2.0 * r).min(bound);
                    }
                    None => {
                        // A refit failed before chi2 rose by the target: the data
                        // bound it no closer than the range does, as far as the
                        // profile can tell (this level and the next).
                        for r in &mut reach[side][level..] {
                            *r = bound;
                        }
                        break;
                    }
                }
            }
        }
        // Never past the parameter's range (a linearised reach can be: q >= 0.05).
        let bounds = [theta0[k] - specs[k].bounds.0, specs[k].bounds.1 - theta0[k]];
        for (side, b) in bounds.into_iter().enumerate() {
            for r in &mut reach[side] {
                *r = r.min(b.max(0.0));
            }
        }
        let p = &mut fit.params[k];
        p.sigma_minus = reach[0][0];
        p.sigma_plus = reach[1][0];
        p.three_sigma_minus = reach[0][1];
        p.three_sigma_plus = reach[1][1];
    }
    fit.evaluations += pb.evaluations;
    Ok(())
}

/// Where the profile of parameter `k` (held at `theta0[k] + dir d`, `free` refitted
/// from `lo`'s values) crosses `chi2_min + target`, as a step `d >= 0` from the
/// minimum; `bound` when it never does before the range ends; `None` when a refit
/// fails. `lo` is kept at the last point below the target (the next level starts
/// there); `d`: the first step to try.
#[allow(clippy::too_many_arguments)]
fn crossing(
    pb: &mut Problem<'_>,
    k: usize,
    free: &[bool],
    dir: f64,
    chi2_min: f64,
    target: f64,
    bound: f64,
    mut d: f64,
    lo: &mut (f64, f64, Vec<f64>),
) -> Option<f64> {
    let theta_k = lo.2[k] - dir * lo.0;
    let mut at = |d: f64, start: &[f64]| -> Option<(f64, Vec<f64>)> {
        let mut t = start.to_vec();
        t[k] = theta_k + dir * d;
        let (t, c) = pb.minimise(t, free, 40).ok()?;
        Some(((c - chi2_min).max(0.0), t))
    };
    let mut hi = None;
    for _ in 0..16 {
        let (dc, t) = at(d, &lo.2)?;
        if dc >= target {
            hi = Some((d, dc));
            break;
        }
        *lo = (d, dc, t);
        if d >= bound {
            return Some(bound);
        }
        d = (2.0 * d).min(bound);
    }
    let mut hi = hi?;
    let root = |lo: &(f64, f64, Vec<f64>), hi: (f64, f64)| {
        let (a, b) = (lo.1.sqrt(), hi.1.sqrt());
        lo.0 + (hi.0 - lo.0) * (target.sqrt() - a) / (b - a).max(1e-300)
    };
    // False position, safeguarded: a point within a tenth of the bracket's ends
    // (where plain false position stalls on a curved profile) becomes the midpoint.
    for _ in 0..10 {
        if hi.0 - lo.0 <= 0.01 * hi.0 {
            break;
        }
        let w = hi.0 - lo.0;
        let mut x = root(lo, hi);
        if !(x > lo.0 + 0.1 * w && x < hi.0 - 0.1 * w) {
            x = lo.0 + 0.5 * w;
        }
        let (dc, t) = at(x, &lo.2)?;
        if dc >= target {
            hi = (x, dc);
        } else {
            *lo = (x, dc, t);
        }
    }
    Some(root(lo, hi))
}

/// `P(X >= x)` for `X ~ chi2(dof)`.
pub fn chi2_sf(x: f64, dof: usize) -> f64 {
    match ChiSquared::new(dof.max(1) as f64) {
        Ok(d) => d.sf(x.max(0.0)),
        Err(_) => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;
    use vibro_effects::model::BaseMode;

    fn table() -> (LabModel, CampaignTable) {
        let model = LabModel::base(BaseMode::Exact);
        let text = include_str!("../tests/data/walkthrough-14-rows.csv");
        let t = CampaignTable::parse(text, Path::new("c.csv"), Path::new("."), &model)
            .expect("the 14-row walkthrough table parses");
        (model, t)
    }

    fn cand(kind: &str) -> &'static Candidate {
        crate::library::candidate(kind).expect("a candidate of the library")
    }

    /// The walkthrough's 14 conditions, each measured three times (other VEs, other
    /// uncertainties), every other one stating its IA amplitude's uncertainty (whose
    /// weight follows the model: the reweighted fits).
    fn repeated() -> (LabModel, CampaignTable) {
        let (model, t) = table();
        let mut conditions = Vec::new();
        for (k, c) in t.conditions.iter().enumerate() {
            for r in 0..3 {
                let mut c = c.clone();
                c.run_id = format!("{}-{r}", c.run_id);
                c.line = conditions.len() + 2;
                c.ve_measured_g *= 1.0 + 1e-3 * (r as f64 - 1.0);
                c.ve_uncertainty_g *= 1.0 + 0.5 * r as f64;
                let u = if k % 2 == 0 { 1e-3 } else { f64::NAN };
                c.extra.insert(crate::table::A_B3_U_COLUMN.into(), u);
                conditions.push(c);
            }
        }
        let mut extra_columns = t.extra_columns.clone();
        extra_columns.push(crate::table::A_B3_U_COLUMN.into());
        let t = CampaignTable {
            path: t.path.clone(),
            conditions,
            extra_columns,
        };
        (model, t)
    }

    /// Pooling (`Prepared`'s classes) changes the work, not one bit of a result: the
    /// predictions, the weights, every fit and its reweighting are those of the rows
    /// evaluated one by one.
    #[test]
    fn rows_pooled_by_condition_fit_bit_for_bit_as_one_by_one() {
        let (model, t) = repeated();
        let mut pooled = Prepared::new(&model, &t).unwrap();
        let mut single = Prepared::one_class_per_row(&model, &t).unwrap();
        assert_eq!((pooled.classes(), single.classes()), (14, 42));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&pooled.predicted_g), bits(&single.predicted_g));
        assert_eq!(bits(&pooled.uncertainty_g), bits(&single.uncertainty_g));
        for kind in ["mount_resonance", "heating", "sensor_error", "saturation"] {
            let meter = Meter::new(Budget::default());
            let a = fit_prepared(&model, &t, &pooled, cand(kind), &meter).unwrap();
            let b = fit_prepared(&model, &t, &single, cand(kind), &meter).unwrap();
            assert_eq!(a.chi2_after.to_bits(), b.chi2_after.to_bits(), "{kind}");
            let values =
                |f: &EffectFit| bits(&f.params.iter().map(|p| p.value).collect::<Vec<_>>());
            assert_eq!(values(&a), values(&b), "{kind}");
            assert_eq!(bits(&a.shift_g), bits(&b.shift_g), "{kind}");
            assert_eq!(a.evaluations, b.evaluations, "{kind}");
            assert!(a.evaluations > 0 && a.n == 42, "{kind}: {}", a.evaluations);
            if kind == "mount_resonance" {
                let terms = [cand(kind)];
                let a = fit_reweighted(&model, &t, &mut pooled, &terms, a, &meter).unwrap();
                let b = fit_reweighted(&model, &t, &mut single, &terms, b, &meter).unwrap();
                assert_eq!(bits(&pooled.uncertainty_g), bits(&single.uncertainty_g));
                assert_eq!(a.chi2_after.to_bits(), b.chi2_after.to_bits());
                assert_eq!(values(&a), values(&b));
            }
        }
    }

    fn problem<'a>(
        model: &'a LabModel,
        t: &'a CampaignTable,
        prep: &'a Prepared,
        terms: &'a [&'static Candidate],
        meter: &'a Meter,
    ) -> Problem<'a> {
        Problem::new(model, t, prep, terms, "test".into(), meter, None)
    }

    /// A flight window's stated band-PSD uncertainties reach the row's uncertainty only
    /// through an effect that reads the spectrum: 0 through the base model (which reads
    /// the variance alone), and through a mount resonance the scatter of the prediction
    /// over band PSDs drawn about the stated ones (Monte Carlo, 4,000 draws) to 5 %.
    #[test]
    fn band_psd_uncertainties_reach_the_row_through_the_effects_that_read_the_spectrum() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        use vibro_physics::vibration::PsdBand;
        let (model, t) = table();
        let mut c = t.conditions[0].clone();
        c.tone = None;
        c.ve_uncertainty_g = 0.0;
        c.extra.clear();
        let edges = [(20.0, 80.0), (80.0, 320.0), (320.0, 1000.0)];
        let levels = [
            [0.004, 0.003, 0.01],
            [0.002, 0.002, 0.006],
            [5e-4, 5e-4, 1e-3],
        ];
        c.bands = edges
            .iter()
            .zip(levels)
            .map(|(&(lo, hi), s)| PsdBand {
                f_lo_hz: lo,
                f_hi_hz: hi,
                psd_g2_per_hz: s,
            })
            .collect();
        c.bands_u = c
            .bands
            .iter()
            .map(|b| PsdBand {
                psd_g2_per_hz: b.psd_g2_per_hz.map(|s| 0.12 * s),
                ..*b
            })
            .collect();
        let var: [f64; 3] = std::array::from_fn(|j| {
            c.bands
                .iter()
                .map(|b| b.psd_g2_per_hz[j] * (b.f_hi_hz - b.f_lo_hz))
                .sum()
        });
        c.random = Some(crate::table::RandomCondition {
            sigma_g: var.map(f64::sqrt),
            cov31_g2: 0.0,
            cov32_g2: 0.0,
            cov12_g2: 0.0,
            kurtosis3: 3.0,
        });
        assert!(c.states_vibration_u());

        let base = build_effects(&[], &c.passport).expect("no effects");
        assert_eq!(
            effective_u_g(model.mode, &base, &c).expect("propagates"),
            0.0
        );

        let resonance: toml::Table =
            toml::from_str("kind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56")
                .expect("an effect table");
        let effects = build_effects(&[resonance], &c.passport).expect("the resonance builds");
        let stated = effective_u_g(model.mode, &effects, &c).expect("propagates");
        let ve = |row: &crate::table::Condition| {
            predict::predict_ve(
                model.mode,
                &effects,
                &row.passport,
                row.a_l_g,
                &row.vibration(),
                &row.psd(),
                row.vibrating_s(),
            )
            .expect("predicts")
            .ve_g
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
        let n = 4000;
        let draws: Vec<f64> = (0..n)
            .map(|_| {
                let mut row = c.clone();
                for (b, bu) in row.bands.iter_mut().zip(&c.bands_u) {
                    for j in 0..3 {
                        let d = Normal::new(0.0, bu.psd_g2_per_hz[j]).expect("a normal");
                        b.psd_g2_per_hz[j] += d.sample(&mut rng);
                    }
                }
                ve(&row)
            })
            .collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let sd = (draws.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        assert!(stated > 0.0);
        assert!(
            (stated / sd - 1.0).abs() < 0.05,
            "propagated {stated:e} g against the Monte Carlo's {sd:e} g"
        );
    }

    /// `high_order_nonlinearity` enters the exact mean output linearly in k6 and k7,
    /// so chi2 is exactly quadratic: the profile's 68 % reach of k6 (k7 refitted) is
    /// the linearised `sigma` (Birge-scaled) and its 99.73 % reach 3 `sigma`, on both
    /// sides (closed form of linear least squares).
    #[test]
    fn a_linear_parameter_s_profile_reach_is_its_linearised_sigma() {
        let (model, t) = table();
        let prep = Prepared::new(&model, &t).expect("prepared");
        let meter = Meter::new(Budget::default());
        let terms = [cand("high_order_nonlinearity")];
        let fit = fit_joint(&model, &t, &prep, &terms, &[None], &meter).expect("fit");
        let mut pb = problem(&model, &t, &prep, &terms, &meter);
        let theta0: Vec<f64> = fit.params.iter().map(|p| p.value).collect();
        let chi2_min = pb.weighted(&theta0).expect("chi2").norm_squared();
        let b2 = (chi2_min / fit.n.saturating_sub(fit.k).max(1) as f64).max(1.0);
        let sigma = fit.params[0].sigma;
        assert!(sigma.is_finite() && sigma > 0.0, "{fit:?}");
        let free = [false, true];
        for dir in [-1.0, 1.0] {
            let mut lo = (0.0, 0.0, theta0.clone());
            let r1 = crossing(
                &mut pb,
                0,
                &free,
                dir,
                chi2_min,
                b2,
                1e3,
                0.3 * sigma,
                &mut lo,
            )
            .expect("68 %");
            let r3 = crossing(
                &mut pb,
                0,
                &free,
                dir,
                chi2_min,
                9.0 * b2,
                1e3,
                2.0 * r1,
                &mut lo,
            )
            .expect("99.73 %");
            assert!((r1 / sigma - 1.0).abs() < 0.01, "{dir}: {r1} vs {sigma}");
            assert!(
                (r3 / (3.0 * sigma) - 1.0).abs() < 0.01,
                "{dir}: {r3} vs 3 x {sigma}"
            );
        }
    }

    /// A resonance's interval: at each end the chi2 minimised over the other
    /// parameter from a fresh grid of starts (not the profile's path) is up by the
    /// target, 1 and 9 times the Birge ratio squared, to within the 1 % tolerance of
    /// the reach; and the interval contains the best fit.
    #[test]
    fn a_resonance_s_profile_ends_where_chi2_is_up_by_the_target() {
        let (model, t) = table();
        let prep = Prepared::new(&model, &t).expect("prepared");
        let meter = Meter::new(Budget::default());
        let terms = [cand("mount_resonance")];
        let mut fit = fit_joint(&model, &t, &prep, &terms, &[None], &meter).expect("fit");
        profile(&model, &t, &prep, &terms, &mut fit, &meter).expect("profile");
        let mut pb = problem(&model, &t, &prep, &terms, &meter);
        let theta0: Vec<f64> = fit.params.iter().map(|p| p.value).collect();
        let chi2_min = pb.weighted(&theta0).expect("chi2").norm_squared();
        let b2 = (chi2_min / fit.n.saturating_sub(fit.k).max(1) as f64).max(1.0);
        let q_spec = terms[0].params[1];
        for (k, p) in fit.params.iter().enumerate() {
            println!(
                "FIGURES profile {}: {:.6} -{:.4} +{:.4} (linearised {:.4}), 3 sigma -{:.4} +{:.4}",
                p.name,
                p.value,
                p.sigma_minus,
                p.sigma_plus,
                p.sigma,
                p.three_sigma_minus,
                p.three_sigma_plus
            );
            assert!(p.sigma_minus > 0.0 && p.sigma_plus > 0.0, "{p:?}");
            assert!(p.three_sigma_minus > p.sigma_minus, "{p:?}");
            assert!(p.three_sigma_plus > p.sigma_plus, "{p:?}");
            if k != 0 {
                continue;
            }
            for (reach, target) in [
                (-p.sigma_minus, b2),
                (p.sigma_plus, b2),
                (-p.three_sigma_minus, 9.0 * b2),
                (p.three_sigma_plus, 9.0 * b2),
            ] {
                let f0 = p.value + reach;
                if f0 <= terms[0].params[0].bounds.0 || f0 >= terms[0].params[0].bounds.1 {
                    continue;
                }
                // q from a fresh log grid over its range, then polished.
                let mut best = f64::INFINITY;
                for i in 0..24 {
                    let (lo, hi) = (q_spec.bounds.0.max(0.3), q_spec.bounds.1.min(30.0));
                    let q = lo * (hi / lo).powf(i as f64 / 23.0);
                    let Ok((_, c)) = pb.minimise(vec![f0, q], &[false, true], 60) else {
                        continue;
                    };
                    best = best.min(c);
                }
                let rise = best - chi2_min;
                // 1 % of the reach in f0 moves sqrt(rise) by about 1 % (x 2 margin).
                assert!(
                    (rise / target - 1.0).abs() < 0.05,
                    "f0 = {f0}: chi2 up {rise} against {target}"
                );
            }
        }
    }
}
