//! `lab diagnose` on the waveform (issue 44): the effects of the library fitted to a
//! set of logs' readings themselves, each reading predicted from the vibration
//! sensors' samples through the model (`vibro_wavefit`), instead of windows' VE from
//! the statistics of an estimate ([`crate::diagnose`], which stays for tables and for
//! logs without samples).
//!
//! The search:
//!
//! 1. **The model as is**, with the sensors' delay free when no log states it: its
//!    start from the cross-correlation of the readings with the predicted linear
//!    response (`vibro_wavefit::eval::delay_cross_correlation`), then least squares.
//! 2. **The noise**: each unit's residual over the runs' quiet readings (the sensors'
//!    and the readings' own noise, which no effect explains); the vibrating readings'
//!    residual against it is the lack of fit (`vibro_wavefit::lack_of_fit`: a z from
//!    block means). Below [`WaveOptions::z_noise`], the verdict is "noise". Logs with
//!    no quiet readings (vibrating throughout) have no such reference: the noise is the
//!    fit's own residual, every round is run, and the candidates' delta BIC alone
//!    decides (the report says the lack of fit was not testable).
//! 3. **Rounds**: every candidate of the library that the waveform can evaluate
//!    (`non_gaussian` and `axis_phase` describe statistics and phases the samples carry
//!    themselves), and `sensor_error` per unit, is fitted beside the effects found so
//!    far (all their parameters free): starts from the library's grids, screened by the
//!    cheap objective (a path effect's linear response alone, over the vibration's
//!    bins; an output effect's grid pass with the signals reused), then
//!    Levenberg-Marquardt from the best. Its `delta_bic` is against the model of the
//!    round, with the chi2 divided by the residual's correlation inflation (the
//!    quiet readings' block variance over the white one) and `ln(n / inflation)` per
//!    parameter. The best supported candidate is added; two of different kinds within
//!    [`WaveOptions::bic_tie`] make the verdict "confounded".
//! 4. **Verdict**: "effect" (the effects found leave the noise), "unexplained" (they do
//!    not, or none is supported where the lack of fit remains), "confounded", or
//!    "noise" (no candidate supported and no lack of fit). A round runs first and
//!    after every round that added an effect, whatever the lack-of-fit test says: a
//!    candidate's signature can be supported below the omnibus test's reach.
//!
//! The uncertainties are the fit's sandwich covariance (`vibro_wavefit::fit`), tested
//! against the scatter over repeated draws (tests/python/waveform_battery.py).

use crate::diagnose::Progress;
use crate::library::{self, Candidate, ParamSpec, Search};
use crate::log_table::LogOptions;
use crate::wave_input::{read_log, WaveLog};
use crate::{Error, LabModel, Result};
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;
use vibro_wavefit::eval::{self, Built};
use vibro_wavefit::fit::{evaluate, project, Projected};
use vibro_wavefit::{
    fit, lack_of_fit, noise_of, prepare, FitSettings, FreeParam, LackOfFit, Noise, PrepareCounts,
    PrepareOptions, PreparedRun, Problem, Rest, Role,
};

/// Options of [`diagnose_logs`].
#[derive(Debug, Clone, Serialize)]
pub struct WaveOptions {
    pub prepare: PrepareOptions,
    pub fit: FitSettings,
    /// The candidates to try (all the waveform can evaluate when empty).
    pub candidates: Vec<String>,
    /// Most effects added.
    pub max_effects: usize,
    /// The lack of fit's z below which the model explains the readings.
    pub z_noise: f64,
    /// A candidate is supported when its `delta_bic` is at most this.
    pub bic_support: f64,
    /// Two supported candidates of different kinds within this are not told apart.
    pub bic_tie: f64,
    /// The delay's search runs from 0 to this, s.
    pub max_delay_s: f64,
    /// Windows of the residual report, s.
    pub window_s: f64,
    /// Most starts a candidate's multi-start screens.
    pub max_starts: usize,
    #[serde(skip)]
    pub progress: Progress,
}

impl WaveOptions {
    /// Options that fit `kinds` whatever their support (`lab add KIND...`): each round
    /// adds the best of them until all are in.
    pub fn adding(kinds: &[String]) -> Self {
        Self {
            candidates: kinds.to_vec(),
            max_effects: kinds.len(),
            z_noise: f64::NEG_INFINITY,
            bic_support: f64::INFINITY,
            bic_tie: f64::NEG_INFINITY,
            ..Self::default()
        }
    }
}

impl Default for WaveOptions {
    fn default() -> Self {
        Self {
            prepare: PrepareOptions::default(),
            fit: FitSettings::default(),
            candidates: Vec::new(),
            max_effects: 3,
            z_noise: 3.0,
            bic_support: -10.0,
            bic_tie: 10.0,
            max_delay_s: 0.02,
            window_s: 1.0,
            max_starts: 48,
            progress: Progress::default(),
        }
    }
}

/// A fitted parameter.
#[derive(Debug, Clone, Serialize)]
pub struct ParamOut {
    pub kind: String,
    pub name: String,
    /// The unit the effect acts on, when only one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit: Option<usize>,
    pub value: f64,
    /// From the sandwich covariance.
    pub sigma: f64,
    /// From the white-noise covariance at the stated noise.
    pub sigma_white: f64,
}

/// A candidate's fit in a round.
#[derive(Debug, Clone, Serialize)]
pub struct CandidateOut {
    pub kind: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit: Option<usize>,
    pub delta_bic: f64,
    pub chi2: f64,
    pub params: Vec<ParamOut>,
    pub supported: bool,
    /// Why it could not be fitted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    pub starts: usize,
    pub evaluations: usize,
    pub elapsed_s: f64,
}

/// One round of the search.
#[derive(Debug, Clone, Serialize)]
pub struct StepOut {
    /// What the round added (none: the model as is).
    pub added: Option<String>,
    pub chi2: f64,
    /// The RMS of the vibrating readings' residual, g.
    pub rms_vibrating_g: f64,
    pub lack_of_fit: LackOfFit,
    pub candidates: Vec<CandidateOut>,
}

/// A run (log) of the diagnosis.
#[derive(Debug, Clone, Serialize)]
pub struct RunOut {
    pub log: String,
    pub counts: PrepareCounts,
    pub delay_stated: bool,
    pub delay_s: f64,
    pub band_hz: (f64, f64),
    pub grid_points_per_reading: usize,
    pub passports_from: String,
    pub vib_blocks_refused: u64,
    pub vib_breaks: u64,
}

/// [`WaveDiagnosis::timings`], s.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Timings {
    pub read_s: f64,
    pub model_as_is_s: f64,
    pub rounds_s: Vec<f64>,
}

/// A window of the residual along a run.
#[derive(Debug, Clone, Serialize)]
pub struct WindowOut {
    pub run: usize,
    /// Its centre from the run's first reading, s.
    pub t_s: f64,
    /// Quiet (all its readings at the sensors' noise) or vibrating.
    pub quiet: bool,
    pub readings: usize,
    /// Per unit, the mean residual, g.
    pub residual_g: [f64; 3],
}

/// Per run, the residual of every reading (for the report's residual along time).
#[derive(Debug, Clone)]
pub struct RunResidual {
    pub log: String,
    pub t_s: Vec<f64>,
    pub quiet: Vec<bool>,
    pub residual_g: Vec<[f64; 3]>,
}

/// [`diagnose_logs`]'s result.
#[derive(Debug, Clone, Serialize)]
pub struct WaveDiagnosis {
    /// `"waveform"`: every reading predicted from the samples.
    pub path: &'static str,
    /// `noise`, `effect`, `confounded` or `unexplained`.
    pub verdict: String,
    /// The effects found, in the order added.
    pub found: Vec<String>,
    /// Every fitted parameter of the final model: the effects found and the sensors'
    /// delay when no log states it (kind `sensor_chain`).
    pub params: Vec<ParamOut>,
    pub correlation: Vec<Vec<f64>>,
    /// The confounded candidates (verdict `confounded`).
    pub confounded: Vec<String>,
    /// The vibrating readings' mean `(r / sigma)^2` under the final model, the noise
    /// from the quiet readings: 1 for a right model.
    pub chi2_per_dof: f64,
    pub lack_of_fit_before: LackOfFit,
    pub lack_of_fit: LackOfFit,
    pub noise: Noise,
    pub steps: Vec<StepOut>,
    pub runs: Vec<RunOut>,
    pub windows: Vec<WindowOut>,
    /// The RMS over vibrating windows of their mean residual, and over quiet windows
    /// (the noise's own level at the window's length), g.
    pub window_residual_rms_g: f64,
    pub window_noise_rms_g: f64,
    pub options: WaveOptions,
    pub elapsed_s: f64,
    /// Where the time went: reading and preparing the logs, the model as is (with the
    /// delay's search), each round of candidates.
    pub timings: Timings,
    /// The final model: the input's with the effects found (for `lab add`).
    #[serde(skip)]
    pub model: LabModel,
    /// Per run, every reading's residual under the final model.
    #[serde(skip)]
    pub residuals: Vec<RunResidual>,
    /// The same under the model as is (its delay fitted when not stated).
    #[serde(skip)]
    pub residuals_before: Vec<RunResidual>,
}

fn run_residuals(runs: &[PreparedRun], residual_g: &[Vec<[f64; 3]>]) -> Vec<RunResidual> {
    runs.iter()
        .zip(residual_g)
        .map(|(r, res)| RunResidual {
            log: r.name.clone(),
            t_s: r.t_s.clone(),
            quiet: r.quiet.clone(),
            residual_g: res.clone(),
        })
        .collect()
}

/// The candidates the waveform evaluates (module doc), `sensor_error` per unit too.
fn waveform_candidates(wanted: &[String]) -> Vec<(&'static Candidate, Option<usize>)> {
    let mut out = Vec::new();
    for c in library::kinds().into_iter().filter_map(library::candidate) {
        if matches!(c.kind, "non_gaussian" | "axis_phase") {
            continue;
        }
        if !wanted.is_empty() && !wanted.iter().any(|w| w == c.kind) {
            continue;
        }
        out.push((c, None));
        if c.kind == "sensor_error" {
            out.extend((0..3).map(|u| (c, Some(u))));
        }
    }
    out
}

/// Heating's time constant is seen on the waveform (the bias follows the vibration's
/// power through it): free there, fixed at 1 us on tables (`library`).
const HEATING_TAU: ParamSpec = ParamSpec {
    name: "tau_s",
    scale: 0.1,
    bounds: (1e-6, 1e3),
    search: Search::Grid(&[0.01, 0.3, 3.0, 30.0]),
};

fn params_of(c: &Candidate) -> Vec<ParamSpec> {
    let mut p = c.params.to_vec();
    if c.kind == "heating" {
        p.push(HEATING_TAU);
    }
    p
}

/// The candidate's table: its kind, its fixed keys (not heating's time constant), its
/// unit, its parameters at `values`.
fn table_of(
    c: &Candidate,
    unit: Option<usize>,
    params: &[ParamSpec],
    values: &[f64],
) -> toml::Table {
    let mut t: toml::Table = if c.kind == "heating" {
        toml::Table::new()
    } else {
        c.fixed.parse().unwrap_or_default()
    };
    t.insert("kind".into(), c.kind.into());
    if let Some(u) = unit {
        t.insert(
            "units".into(),
            toml::Value::Array(vec![toml::Value::Integer(u as i64)]),
        );
    }
    for (p, v) in params.iter().zip(values) {
        t.insert(p.name.into(), toml::Value::Float(*v));
    }
    t
}

/// Per parameter, its starts; a frequency's from the sensors' band.
fn starts_of(params: &[ParamSpec], band_hz: (f64, f64), max: usize) -> Vec<Vec<f64>> {
    let lists: Vec<Vec<f64>> = params
        .iter()
        .map(|p| {
            let v: Vec<f64> = match p.search {
                // Nonzero: with its coefficient at 0 an effect's other parameters would
                // not act (vibropendulous's time constant).
                Search::Linear => vec![p.scale],
                Search::Grid(g) => g.to_vec(),
                Search::AroundVariable { lo, hi, points, .. } => {
                    let (a, b) = (band_hz.0.max(1.0) * lo, band_hz.1.max(2.0) * hi);
                    (0..points)
                        .map(|i| a * (b / a).powf(i as f64 / (points.max(2) - 1) as f64))
                        .collect()
                }
            };
            v.into_iter()
                .map(|x| x.clamp(p.bounds.0, p.bounds.1))
                .collect()
        })
        .collect();
    let mut out: Vec<Vec<f64>> = vec![Vec::new()];
    for l in &lists {
        out = out
            .into_iter()
            .flat_map(|prefix| {
                l.iter().map(move |x| {
                    let mut p = prefix.clone();
                    p.push(*x);
                    p
                })
            })
            .collect();
    }
    if out.len() > max && max > 0 {
        let step = out.len() as f64 / max as f64;
        out = (0..max)
            .map(|i| out[(i as f64 * step) as usize].clone())
            .collect();
    }
    out
}

/// The model of a round: its problem, its fit's values and rectified parts.
#[derive(Clone)]
struct State {
    problem: Problem,
    x: Vec<f64>,
    chi2: f64,
    rest: Vec<Vec<[f64; 3]>>,
    fit: Option<vibro_wavefit::Fit>,
    /// Per effect of the problem's tables: its kind and unit (for the report).
    labels: Vec<(String, Option<usize>)>,
}

fn err(e: vibro_wavefit::Error) -> Error {
    Error::Invalid(e.to_string())
}

/// Diagnoses the logs `paths` against `model` on the waveform (module doc).
pub fn diagnose_logs(
    paths: &[PathBuf],
    model: &LabModel,
    log_options: &LogOptions,
    options: &WaveOptions,
) -> Result<WaveDiagnosis> {
    let start = Instant::now();
    if paths.is_empty() {
        return Err(Error::Invalid("no logs to diagnose".into()));
    }
    let settings = options.fit;
    // Read and prepare, the logs on the fit's threads.
    let logs = read_all(paths, log_options, options)?;
    let runs: Vec<PreparedRun> = logs.iter().map(|(_, r)| r.clone()).collect();
    let mut timings = Timings {
        read_s: start.elapsed().as_secs_f64(),
        ..Timings::default()
    };
    drop_duplicates(&runs)?;
    let band_hz = runs.iter().fold((f64::INFINITY, 0.0f64), |(a, b), r| {
        (a.min(r.band_hz.0), b.max(r.band_hz.1))
    });
    let delay_free = runs.iter().any(|r| !r.delay_stated);
    // The model as is.
    let mut problem = Problem {
        tables: model.effects.clone(),
        delay_s: 0.0,
        free: Vec::new(),
    };
    let mut labels: Vec<(String, Option<usize>)> = model
        .effects
        .iter()
        .map(|t| {
            (
                t.get("kind")
                    .and_then(|k| k.as_str())
                    .unwrap_or("?")
                    .to_string(),
                None,
            )
        })
        .collect();
    let noise0 = Noise {
        sigma_g: [1e-4; 3],
        from_quiet: false,
    };
    let (_, pr0, rest0) =
        evaluate(&runs, &problem, &[], &noise0, &settings, Rest::Compute).map_err(err)?;
    let mut noise = noise_of(&runs, &pr0.residual_g);
    if delay_free {
        let d0 = delay_start(&runs, &problem, &[], &rest0, &noise, options.max_delay_s)?;
        problem.delay_s = d0;
        problem.free.push(FreeParam {
            kind: "sensor_chain".into(),
            name: "delay_s".into(),
            effect: None,
            scale: 1e-4,
            bounds: (0.0, options.max_delay_s.max(1e-6)),
            role: Role::Path,
        });
    }
    let x0 = problem.values();
    let base_fit = fit(&runs, &problem, &x0, &noise, &settings, Rest::Compute).map_err(err)?;
    noise = noise_of(&runs, &base_fit.residual_g);
    let (chi2_base, pr_base, rest_base) = evaluate(
        &runs,
        &problem,
        &base_fit.x,
        &noise,
        &settings,
        Rest::Compute,
    )
    .map_err(err)?;
    let lof_before = lack_of_fit(&runs, &pr_base.residual_g, &noise, settings.block_readings);
    timings.model_as_is_s = start.elapsed().as_secs_f64() - timings.read_s;
    let mut state = State {
        problem: problem.clone(),
        x: base_fit.x.clone(),
        chi2: chi2_base,
        rest: rest_base,
        fit: Some(base_fit),
        labels: labels.clone(),
    };
    let mut rms_now = rms_vibrating(&runs, &pr_base.residual_g);
    let mut steps = vec![StepOut {
        added: None,
        chi2: chi2_base,
        rms_vibrating_g: rms_now,
        lack_of_fit: lof_before,
        candidates: Vec::new(),
    }];
    let mut found: Vec<String> = Vec::new();
    let mut confounded: Vec<String> = Vec::new();
    let mut lof = lof_before;
    let candidates = waveform_candidates(&options.candidates);
    let n_total = runs.iter().map(|r| 3 * r.counts.used).sum::<usize>().max(1) as f64;
    // Without quiet readings (a flight: vibrating throughout) the noise is the fit's own
    // residual and the lack of fit cannot be tested: the candidates decide by their
    // delta BIC alone.
    let testable = noise.from_quiet;
    // A round runs first, and again after every round that added an effect: a
    // candidate's own signature (a slow bias that follows the vibration's power, a term
    // that only OA and PA vibration together excite) can be supported where the
    // omnibus test, summed over every reading's noise, does not see it. The search ends
    // when a round supports nothing.
    while found.len() < options.max_effects {
        let round_start = Instant::now();
        let inflation = lof.inflation.max(1.0);
        let mut outs: Vec<(CandidateOut, Option<State>)> = Vec::new();
        let round_of = candidates.len();
        for (i, (c, unit)) in candidates.iter().enumerate() {
            if state
                .labels
                .iter()
                .any(|(k, u)| k == c.kind && (*u == *unit || u.is_none()))
            {
                continue;
            }
            let t0 = Instant::now();
            let r = fit_candidate(&runs, &state, c, *unit, band_hz, &noise, options);
            let elapsed_s = t0.elapsed().as_secs_f64();
            if let Some(p) = &options.progress.0 {
                p(i + 1, round_of, c.kind);
            }
            match r {
                Ok((s, starts, evaluations)) => {
                    let k = s.x.len() - state.x.len();
                    let delta_bic =
                        (s.chi2 - state.chi2) / inflation + k as f64 * (n_total / inflation).ln();
                    let params = params_out(&s, state.problem.tables.len());
                    outs.push((
                        CandidateOut {
                            kind: c.kind.into(),
                            unit: *unit,
                            delta_bic,
                            chi2: s.chi2,
                            params,
                            supported: delta_bic <= options.bic_support,
                            error: None,
                            starts,
                            evaluations,
                            elapsed_s,
                        },
                        Some(s),
                    ));
                }
                Err(e) => outs.push((
                    CandidateOut {
                        kind: c.kind.into(),
                        unit: *unit,
                        delta_bic: f64::INFINITY,
                        chi2: f64::NAN,
                        params: Vec::new(),
                        supported: false,
                        error: Some(e.to_string()),
                        starts: 0,
                        evaluations: 0,
                        elapsed_s,
                    },
                    None,
                )),
            }
        }
        outs.sort_by(|a, b| a.0.delta_bic.total_cmp(&b.0.delta_bic));
        timings.rounds_s.push(round_start.elapsed().as_secs_f64());
        let best = outs.first().filter(|o| o.0.supported).map(|o| o.0.clone());
        let tie: Vec<String> = match &best {
            Some(b) => outs
                .iter()
                .skip(1)
                .filter(|o| {
                    o.0.supported
                        && o.0.kind != b.kind
                        && o.0.delta_bic - b.delta_bic < options.bic_tie
                })
                .map(|o| o.0.kind.clone())
                .collect(),
            None => Vec::new(),
        };
        let round: Vec<CandidateOut> = outs.iter().map(|o| o.0.clone()).collect();
        let Some(best) = best else {
            steps.push(StepOut {
                added: None,
                chi2: state.chi2,
                rms_vibrating_g: rms_now,
                lack_of_fit: lof,
                candidates: round,
            });
            break;
        };
        if !tie.is_empty() {
            confounded = std::iter::once(best.kind.clone()).chain(tie).collect();
            steps.push(StepOut {
                added: None,
                chi2: state.chi2,
                rms_vibrating_g: rms_now,
                lack_of_fit: lof,
                candidates: round,
            });
            break;
        }
        let Some(next) = outs.into_iter().next().and_then(|o| o.1) else {
            break;
        };
        state = next;
        // Every parameter free with everything evaluated: the effects found so far
        // and the new one together.
        let joint = fit(
            &runs,
            &state.problem,
            &state.x,
            &noise,
            &settings,
            Rest::Compute,
        )
        .map_err(err)?;
        noise = noise_of(&runs, &joint.residual_g);
        // Refitted under the noise it leaves (its weights per unit): the next round's
        // candidates are measured against this minimum, not against a re-weighting.
        let joint = fit(
            &runs,
            &state.problem,
            &joint.x,
            &noise,
            &settings,
            Rest::Compute,
        )
        .map_err(err)?;
        state.x = joint.x.clone();
        state.fit = Some(joint);
        let (chi2, pr, rest) = evaluate(
            &runs,
            &state.problem,
            &state.x,
            &noise,
            &settings,
            Rest::Compute,
        )
        .map_err(err)?;
        state.chi2 = chi2;
        state.rest = rest;
        lof = lack_of_fit(&runs, &pr.residual_g, &noise, settings.block_readings);
        rms_now = rms_vibrating(&runs, &pr.residual_g);
        found.push(best.kind.clone());
        labels = state.labels.clone();
        steps.push(StepOut {
            added: Some(best.kind.clone()),
            chi2,
            rms_vibrating_g: rms_now,
            lack_of_fit: lof,
            candidates: round,
        });
    }
    // The final model and its residual.
    let (_, pr, _) = evaluate(
        &runs,
        &state.problem,
        &state.x,
        &noise,
        &settings,
        Rest::Compute,
    )
    .map_err(err)?;
    let verdict = if !confounded.is_empty() {
        "confounded"
    } else if lof.z < options.z_noise || !testable {
        if found.is_empty() {
            "noise"
        } else {
            "effect"
        }
    } else {
        "unexplained"
    };
    let params = state
        .fit
        .as_ref()
        .map(|f| {
            let base = model.effects.len();
            all_params(f, &state.labels, base)
        })
        .unwrap_or_default();
    let correlation = state
        .fit
        .as_ref()
        .map_or(Vec::new(), |f| f.correlation.clone());
    let (windows, win_res, win_noise) = windows_of(&runs, &pr, options.window_s);
    let final_delay = state.problem.at(&state.x).1;
    let final_model = model_with_fits(model, &state, &steps, paths);
    let _ = labels;
    Ok(WaveDiagnosis {
        path: "waveform",
        verdict: verdict.into(),
        found,
        params,
        correlation,
        confounded,
        chi2_per_dof: lof.chi2_per_reading_vibrating,
        lack_of_fit_before: lof_before,
        lack_of_fit: lof,
        noise,
        steps,
        runs: logs
            .iter()
            .map(|(l, r)| RunOut {
                log: l.input.name.clone(),
                counts: r.counts,
                delay_stated: r.delay_stated,
                delay_s: if r.delay_stated {
                    r.delay0_s
                } else {
                    final_delay
                },
                band_hz: r.band_hz,
                grid_points_per_reading: r.m,
                passports_from: l.passports_from.clone(),
                vib_blocks_refused: l.vib_blocks_refused,
                vib_breaks: l.vib_breaks,
            })
            .collect(),
        windows,
        window_residual_rms_g: win_res,
        window_noise_rms_g: win_noise,
        options: options.clone(),
        elapsed_s: start.elapsed().as_secs_f64(),
        timings,
        model: final_model,
        residuals: run_residuals(&runs, &pr.residual_g),
        residuals_before: run_residuals(&runs, &pr_base.residual_g),
    })
}

/// `model` with the effects the search added, each with its provenance (the logs, the
/// fitted values and uncertainties, the residual RMS before and after its round, its
/// `delta_bic`).
fn model_with_fits(
    model: &LabModel,
    state: &State,
    steps: &[StepOut],
    paths: &[PathBuf],
) -> LabModel {
    let (tables, _) = state.problem.at(&state.x);
    let mut out = model.clone();
    let source: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    let added: Vec<&StepOut> = steps.iter().filter(|s| s.added.is_some()).collect();
    for (i, t) in tables.iter().enumerate().skip(model.effects.len()) {
        let kind = t
            .get("kind")
            .and_then(|k| k.as_str())
            .unwrap_or("?")
            .to_string();
        let mut params = std::collections::BTreeMap::new();
        let mut sigma = std::collections::BTreeMap::new();
        if let Some(f) = &state.fit {
            for (q, p) in f.params.iter().enumerate() {
                if p.effect == Some(i) {
                    params.insert(p.name.clone(), f.x[q]);
                    sigma.insert(p.name.clone(), f.sigma[q]);
                }
            }
        }
        let k = i - model.effects.len();
        let rms = |s: Option<&&StepOut>| s.map_or(f64::NAN, |s| s.rms_vibrating_g);
        let record = vibro_effects::model::FitRecord {
            kind,
            table: format!("waveform: {}", source.join(", ")),
            params,
            sigma,
            interval: Default::default(),
            // The vibrating readings' residual RMS before and after the round that
            // added it (per reading: the waveform's residual).
            rms_residual_before_g: if k == 0 {
                rms(steps.first().as_ref())
            } else {
                rms(added.get(k - 1))
            },
            rms_residual_after_g: rms(added.get(k)),
            delta_bic: added
                .get(k)
                .and_then(|s| s.candidates.first())
                .map_or(f64::NAN, |c| c.delta_bic),
        };
        out = out.with_effect(t.clone(), Some(record));
    }
    out
}

/// The RMS of the residual over the vibrating used readings, g.
fn rms_vibrating(runs: &[PreparedRun], residual_g: &[Vec<[f64; 3]>]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (run, res) in runs.iter().zip(residual_g) {
        for r in 0..run.j {
            if run.used[r] && !run.quiet[r] {
                for x in res[r] {
                    if x.is_finite() {
                        s += x * x;
                        n += 1;
                    }
                }
            }
        }
    }
    (s / n.max(1) as f64).sqrt()
}

/// Reads and prepares every log, on the fit's threads.
fn read_all(
    paths: &[PathBuf],
    log_options: &LogOptions,
    options: &WaveOptions,
) -> Result<Vec<(WaveLog, PreparedRun)>> {
    let threads = options.fit.threads.clamp(1, paths.len());
    let mut out: Vec<Option<Result<(WaveLog, PreparedRun)>>> =
        (0..paths.len()).map(|_| None).collect();
    std::thread::scope(|scope| {
        for (t, chunk) in out.chunks_mut(paths.len().div_ceil(threads)).enumerate() {
            let first = t * paths.len().div_ceil(threads);
            scope.spawn(move || {
                for (k, slot) in chunk.iter_mut().enumerate() {
                    let path = &paths[first + k];
                    *slot = Some(read_log(path, log_options).and_then(|l| {
                        let r = prepare(&l.input, &options.prepare).map_err(err)?;
                        Ok((l, r))
                    }));
                }
            });
        }
    });
    out.into_iter()
        .map(|o| o.unwrap_or_else(|| Err(Error::Invalid("a log was not read".into()))))
        .collect()
}

/// The same log given twice would count its noise twice.
fn drop_duplicates(runs: &[PreparedRun]) -> Result<()> {
    for (i, a) in runs.iter().enumerate() {
        if let Some(b) = runs[..i].iter().find(|b| b.name == a.name) {
            return Err(Error::Invalid(format!("{}: given twice", b.name)));
        }
    }
    Ok(())
}

/// The delay's start: the peak of the readings' cross-correlation with the linear
/// response predicted under `problem` at `x` over `0..max_delay_s` (parabolic between
/// lags), summed over the runs whose delay is not stated.
fn delay_start(
    runs: &[PreparedRun],
    problem: &Problem,
    x: &[f64],
    rest: &[Vec<[f64; 3]>],
    noise: &Noise,
    max_delay_s: f64,
) -> Result<f64> {
    let mut total: Vec<f64> = Vec::new();
    let mut lag = 0.0;
    let (tables, delay) = problem.at(x);
    for (i, run) in runs.iter().enumerate() {
        if run.delay_stated {
            continue;
        }
        // Correlated at the delay the runs were prepared at.
        let built = Built::new(&tables, &run.passports, run.delay0_s).map_err(err)?;
        let stat = eval::static_part(run);
        // d = readings less the static and rectified parts, demeaned per unit.
        let mut d: Vec<[f64; 3]> = (0..run.j)
            .map(|r| {
                std::array::from_fn(|u| {
                    if run.used[r] {
                        run.readings_g[r][u] - stat[r][u] - rest[i][r][u]
                    } else {
                        f64::NAN
                    }
                })
            })
            .collect();
        for u in 0..3 {
            let (s, n) = d
                .iter()
                .filter(|x| x[u].is_finite())
                .fold((0.0, 0usize), |(s, n), x| (s + x[u], n + 1));
            let m = s / n.max(1) as f64;
            for x in d.iter_mut() {
                x[u] = if x[u].is_finite() { x[u] - m } else { 0.0 };
            }
        }
        let w = noise.sigma_g.map(|s| 1.0 / (s * s));
        let (cc, lag_s) = eval::delay_cross_correlation(run, &built, &d, w).map_err(err)?;
        lag = lag_s;
        let q_max = ((max_delay_s / lag_s).ceil() as usize + 1).min(cc.len());
        if total.is_empty() {
            total = vec![0.0; q_max];
        }
        for (t, c) in total.iter_mut().zip(&cc) {
            *t += c;
        }
    }
    let _ = delay;
    let Some((q, _)) = total.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else {
        return Ok(0.0);
    };
    // A parabola through the peak and its neighbours.
    let frac = if q > 0 && q + 1 < total.len() {
        let (a, b, c) = (total[q - 1], total[q], total[q + 1]);
        let den = a - 2.0 * b + c;
        if den < 0.0 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    } else {
        0.0
    };
    let out = ((q as f64 + frac) * lag).clamp(0.0, max_delay_s);
    Ok(out)
}

/// Fits candidate `c` (on `unit`, or all) beside the state's model: multi-start, then
/// least squares with every parameter free. Returns the new state, the starts screened
/// and the evaluations of its fits.
fn fit_candidate(
    runs: &[PreparedRun],
    state: &State,
    c: &Candidate,
    unit: Option<usize>,
    band_hz: (f64, f64),
    noise: &Noise,
    options: &WaveOptions,
) -> Result<(State, usize, usize)> {
    let specs = params_of(c);
    let starts = starts_of(&specs, band_hz, options.max_starts);
    let first = starts.first().cloned().unwrap_or_default();
    let table = table_of(c, unit, &specs, &first);
    // Its role: through the vibration (path, sensor) or the output.
    let role = {
        let b = Built::new(std::slice::from_ref(&table), &runs[0].passports, 0.0).map_err(err)?;
        let _ = &b;
        let probe = vibro_effects::model::build_effects(
            std::slice::from_ref(&table),
            &runs[0].passports[0],
        )?;
        if probe
            .iter()
            .any(|e| e.path_transfer(0, 1.0).is_some() || e.sensor_response(0).is_some())
        {
            Role::Path
        } else {
            Role::Output
        }
    };
    let index = state.problem.tables.len();
    let own: Vec<FreeParam> = specs
        .iter()
        .map(|p| FreeParam {
            kind: c.kind.into(),
            name: p.name.into(),
            effect: Some(index),
            scale: p.scale,
            bounds: p.bounds,
            role,
        })
        .collect();
    // The candidate is fitted beside the effects found so far at their values (the
    // joint refit with everything free follows for the one added); a path candidate
    // with the delay, which its phase trades with.
    let (tables_now, delay_now) = state.problem.at(&state.x);
    let delay_q = state.problem.free.iter().position(|p| p.effect.is_none());
    let mut problem = Problem {
        tables: tables_now,
        delay_s: delay_now,
        free: Vec::new(),
    };
    problem.tables.push(table.clone());
    let with_delay = role == Role::Path && delay_q.is_some();
    if let (true, Some(q)) = (with_delay, delay_q) {
        problem.free.push(state.problem.free[q].clone());
    }
    let lead = problem.free.len();
    problem.free.extend(own.iter().cloned());
    // A candidate's rank needs its fit's chi2 to a few percent of its step, not to the
    // last digit: at most 8 steps here (the one added is refitted jointly to
    // convergence).
    let settings = FitSettings {
        max_iterations: options.fit.max_iterations.min(8),
        ..options.fit
    };
    let x_with = |s: &[f64]| -> Vec<f64> {
        let mut x = if with_delay {
            vec![delay_now]
        } else {
            Vec::new()
        };
        x.extend_from_slice(s);
        x
    };
    // Screen the starts by the cheap objective: a path effect's linear response over
    // every run, an output effect's grid pass over the runs with the most vibrating
    // readings (two; a start's rank does not need all of them).
    let screen_runs: Vec<PreparedRun>;
    let screen: &[PreparedRun] = match role {
        Role::Output if runs.len() > 2 => {
            let mut order: Vec<usize> = (0..runs.len()).collect();
            order.sort_by_key(|&i| std::cmp::Reverse(runs[i].counts.used - runs[i].counts.quiet));
            screen_runs = order.iter().take(2).map(|&i| runs[i].clone()).collect();
            &screen_runs
        }
        _ => runs,
    };
    let mut screened: Vec<(f64, Vec<f64>)> = Vec::new();
    let mut evaluations = 0;
    let delay_at = problem.free.iter().position(|p| p.effect.is_none());
    for s in &starts {
        let mut x = x_with(s);
        // A path effect moves the readings' phase as a delay does: with the delay free,
        // each start takes the delay its own linear response correlates best at.
        if let (Role::Path, Some(q)) = (role, delay_at) {
            if let Ok(d) = delay_start(runs, &problem, &x, &state.rest, noise, options.max_delay_s)
            {
                x[q] = d;
            }
        }
        let rest = match role {
            Role::Path => Rest::Fixed(&state.rest),
            Role::Output => Rest::Compute,
        };
        let chi2 = match evaluate(screen, &problem, &x, noise, &settings, rest) {
            Ok((c2, _, _)) => c2,
            Err(_) => f64::INFINITY,
        };
        evaluations += 1;
        screened.push((chi2, x));
    }
    screened.sort_by(|a, b| a.0.total_cmp(&b.0));
    let x = screened
        .first()
        .map(|s| s.1.clone())
        .ok_or_else(|| Error::Invalid(format!("{}: no start", c.kind)))?;
    let f = match role {
        // A path effect moves the rectified part by 1e-4 of what it moves the linear
        // response: least squares on the linear response with the rectified part held,
        // the rectified part evaluated again there, and least squares once more (two
        // grid passes instead of one per step).
        Role::Path => {
            let f = fit(
                runs,
                &problem,
                &x,
                noise,
                &settings,
                Rest::Fixed(&state.rest),
            )
            .map_err(err)?;
            evaluations += f.evaluations;
            let (_, _, rest) =
                evaluate(runs, &problem, &f.x, noise, &settings, Rest::Compute).map_err(err)?;
            let f = fit(runs, &problem, &f.x, noise, &settings, Rest::Fixed(&rest)).map_err(err)?;
            evaluations += f.evaluations + 1;
            f
        }
        Role::Output => {
            let f = fit(runs, &problem, &x, noise, &settings, Rest::Compute).map_err(err)?;
            evaluations += f.evaluations;
            f
        }
    };
    let (chi2, _, rest) =
        evaluate(runs, &problem, &f.x, noise, &settings, Rest::Compute).map_err(err)?;
    // The state with every parameter free again, at these values.
    let mut full = state.problem.clone();
    full.tables.push(table);
    full.free.extend(own);
    let mut x_full = state.x.clone();
    if let (true, Some(q)) = (with_delay, delay_q) {
        x_full[q] = f.x[0];
    }
    x_full.extend_from_slice(&f.x[lead..]);
    let mut labels = state.labels.clone();
    labels.push((c.kind.into(), unit));
    Ok((
        State {
            problem: full,
            x: x_full,
            chi2,
            rest,
            fit: Some(f),
            labels,
        },
        starts.len(),
        evaluations,
    ))
}

/// The parameters of the state's effects from `first` on, and of the delay.
fn params_out(s: &State, first: usize) -> Vec<ParamOut> {
    s.fit
        .as_ref()
        .map_or(Vec::new(), |f| all_params(f, &s.labels, first))
}

fn all_params(
    f: &vibro_wavefit::Fit,
    labels: &[(String, Option<usize>)],
    first: usize,
) -> Vec<ParamOut> {
    f.params
        .iter()
        .enumerate()
        .filter(|(_, p)| p.effect.is_none_or(|e| e >= first))
        .map(|(i, p)| ParamOut {
            kind: p.kind.clone(),
            name: p.name.clone(),
            unit: p.effect.and_then(|e| labels.get(e)).and_then(|l| l.1),
            value: f.x[i],
            sigma: f.sigma[i],
            sigma_white: f.sigma_white[i],
        })
        .collect()
}

/// Windows of `window_s` along each run: their mean residual, quiet or vibrating, and
/// the RMS over each kind.
fn windows_of(runs: &[PreparedRun], pr: &Projected, window_s: f64) -> (Vec<WindowOut>, f64, f64) {
    let mut out = Vec::new();
    let (mut sv, mut nv, mut sq, mut nq) = (0.0, 0usize, 0.0, 0usize);
    for (ri, run) in runs.iter().enumerate() {
        let per = ((window_s / run.period_s).round() as usize).max(1);
        for w in 0..run.j / per {
            let range = w * per..(w + 1) * per;
            let used: Vec<usize> = range.clone().filter(|&r| run.used[r]).collect();
            if used.len() < per / 2 {
                continue;
            }
            let quiet = used.iter().all(|&r| run.quiet[r]);
            let residual_g: [f64; 3] = std::array::from_fn(|u| {
                used.iter().map(|&r| pr.residual_g[ri][r][u]).sum::<f64>() / used.len() as f64
            });
            for x in residual_g {
                if quiet {
                    sq += x * x;
                    nq += 1;
                } else {
                    sv += x * x;
                    nv += 1;
                }
            }
            out.push(WindowOut {
                run: ri,
                t_s: (range.start as f64 + 0.5 * per as f64) * run.period_s,
                quiet,
                readings: used.len(),
                residual_g,
            });
        }
    }
    let rms = |s: f64, n: usize| {
        if n > 0 {
            (s / n as f64).sqrt()
        } else {
            f64::NAN
        }
    };
    (out, rms(sv, nv), rms(sq, nq))
}

#[allow(dead_code)]
fn unused(_: Projected) {
    let _ = project;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn starts_span_the_band_and_are_capped() {
        let c = library::candidate("mount_resonance").unwrap();
        let s = starts_of(&params_of(c), (20.0, 640.0), 1000);
        assert_eq!(s.len(), 12 * 4);
        assert!(s.iter().any(|x| (x[0] - 10.0).abs() < 1e-9));
        assert!(s.iter().any(|x| (x[0] - 1280.0).abs() < 1e-6));
        assert_eq!(starts_of(&params_of(c), (20.0, 640.0), 10).len(), 10);
    }

    #[test]
    fn the_waveform_leaves_out_statistics_and_phases() {
        let all = waveform_candidates(&[]);
        assert!(all
            .iter()
            .all(|(c, _)| c.kind != "non_gaussian" && c.kind != "axis_phase"));
        assert_eq!(
            all.iter().filter(|(c, _)| c.kind == "sensor_error").count(),
            4
        );
        let heating = library::candidate("heating").unwrap();
        let t = table_of(heating, None, &params_of(heating), &[1e-7, 3.0]);
        assert_eq!(t.get("tau_s").and_then(|v| v.as_float()), Some(3.0));
    }
}
