//! Running one job: its rows of the results table. [`run_job`] never fails: an error
//! (a damaged log, a missing passport, a panic) becomes a row with its `problem`, so
//! that the batch goes on and the table says what happened to every job.

use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

use crate::plan::{CompensateTask, Job, LabTask, Task};

/// One row of the results table (docs/archive.md, "The table"): nullable where it does
/// not apply. Non-finite numbers are stored as null (JSON has no NaN).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Row {
    pub job: String,
    /// `compensate` or `lab`.
    pub kind: String,
    /// The log as the manifest names it.
    pub log: Option<String>,
    pub unit: Option<String>,
    pub model: Option<String>,
    /// `uncompensated`, `main_removed`, `estimate_stage`, `vibration_removed`; `lab`.
    pub stage: Option<String>,
    pub window_s: Option<f64>,
    pub windows: Option<i64>,
    pub error_g: Option<f64>,
    /// Compensation: `ok` or `failed`; lab: `noise`, `effect`, `unexplained`,
    /// `confounded`, or `failed`.
    pub verdict: Option<String>,
    pub effect: Option<String>,
    pub param: Option<String>,
    pub value: Option<f64>,
    pub sigma: Option<f64>,
    pub problem: Option<String>,
}

/// A job's result: its rows, how long it took and where it ran.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobResult {
    pub job: String,
    pub rows: Vec<Row>,
    pub elapsed_s: f64,
    /// The host and process that ran it (`host/pid`), or the local engine's note.
    pub worker: String,
}

impl JobResult {
    /// Whether the job failed (a row says `failed`).
    pub fn failed(&self) -> bool {
        self.rows
            .iter()
            .any(|r| r.verdict.as_deref() == Some("failed"))
    }

    /// A job that could not run at all (its worker died twice): one `failed` row.
    pub fn failed_job(job: &Job, problem: String, worker: String) -> JobResult {
        JobResult {
            job: job.id.clone(),
            rows: vec![failed_row(job, problem)],
            elapsed_s: 0.0,
            worker,
        }
    }
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The one row of a job that failed.
fn failed_row(job: &Job, problem: String) -> Row {
    let mut row = Row {
        job: job.id.clone(),
        kind: job.kind().into(),
        verdict: Some("failed".into()),
        problem: Some(problem),
        ..Row::default()
    };
    match &job.task {
        Task::Compensate(c) => {
            row.log = Some(c.log_label.clone());
            row.model = Some(c.model.name.clone());
        }
        Task::Lab(l) => {
            row.unit = Some(l.unit.clone());
            row.stage = Some("lab".into());
        }
    }
    row
}

/// This process, as the `worker` column names it: `host/pid`.
pub fn worker_name() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "localhost".into());
    format!("{host}/{}", std::process::id())
}

/// Runs `job`: never fails (module docs), deterministic apart from `elapsed_s` and
/// `worker`.
pub fn run_job(job: &Job) -> JobResult {
    let started = Instant::now();
    // One job, one core: a batch's parallelism is its processes (the local workers, a
    // Dask cluster's), and a lab fit spread over every core would compete with them.
    // Put back afterwards: a job may run in a caller's own process (a Python session),
    // whose later fits must not stay capped.
    let cap_before = vibro_lab::limit_threads(1);
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match &job.task {
        Task::Compensate(c) => compensate(&job.id, c),
        Task::Lab(l) => lab(&job.id, l),
    }));
    let rows = match outcome {
        Ok(Ok(rows)) => rows,
        Ok(Err(problem)) => vec![failed_row(job, problem)],
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic".into());
            vec![failed_row(job, format!("internal error (panic): {what}"))]
        }
    };
    vibro_lab::limit_threads(cap_before);
    JobResult {
        job: job.id.clone(),
        rows,
        elapsed_s: started.elapsed().as_secs_f64(),
        worker: worker_name(),
    }
}

/// An error's chain, naming `file` if the error itself does not.
fn problem_of(file: &Path, e: &anyhow::Error) -> String {
    let text = format!("{e:#}");
    let name = file.display().to_string();
    if text.contains(&name) {
        text
    } else {
        format!("{name}: {text}")
    }
}

fn compensate(id: &str, c: &CompensateTask) -> Result<Vec<Row>, String> {
    let result = compensate_errors(c);
    if !c.keep_session {
        // Removed whether or not it was complete; a missing one is fine.
        let _ = std::fs::remove_file(&c.session);
    }
    let errors = result.map_err(|e| problem_of(&c.log, &e))?;
    let e = &errors.errors;
    let mut rows = Vec::new();
    for unit in &e.units {
        let Some(name) = unit.unit.checked_sub(1).and_then(|i| c.units.get(i)) else {
            // A position the manifest names no unit for: not the batch's.
            continue;
        };
        let s = &unit.errors;
        let mut stages = vec![
            (
                "uncompensated",
                s.uncompensated_rms_g,
                e.compensated_windows,
            ),
            ("main_removed", s.main_removed_rms_g, e.compensated_windows),
        ];
        if let (Some(x), Some(est)) = (s.estimate_stage_rms_g, &e.estimate_stage) {
            stages.push(("estimate_stage", x, est.compensated_windows));
        }
        stages.push((
            "vibration_removed",
            s.vibration_removed_rms_g,
            e.compensated_windows,
        ));
        for (stage, error_g, windows) in stages {
            rows.push(Row {
                job: id.into(),
                kind: "compensate".into(),
                log: Some(c.log_label.clone()),
                unit: Some(name.clone()),
                model: Some(c.model.name.clone()),
                stage: Some(stage.into()),
                window_s: finite(e.window_s),
                windows: i64::try_from(windows).ok(),
                error_g: finite(error_g),
                verdict: Some("ok".into()),
                ..Row::default()
            });
        }
    }
    if rows.is_empty() {
        return Err(format!(
            "{}: no unit of the manifest's ({}) among the log's measured units",
            c.log.display(),
            c.units.join(", ")
        ));
    }
    Ok(rows)
}

fn compensate_errors(c: &CompensateTask) -> anyhow::Result<vibro_log::session::LogErrors> {
    let m = &c.model;
    let setup = vibro_offline::Setup::derive(
        m.estimator_config.as_deref(),
        m.compensator_config.as_deref(),
        c.rig.as_deref(),
        m.model.as_deref(),
    )?;
    let options = vibro_offline::OutputOptions {
        // A session a killed run left half-written is replaced.
        force: true,
        view: false,
        ..vibro_offline::OutputOptions::default()
    };
    // A worker is stopped by its parent (EOF, or SIGKILL with it): no stop signal here.
    vibro_offline::compensate_log(
        &c.log,
        &setup,
        &c.session,
        &options,
        &|| None,
        &mut |_, _| {},
    )?;
    let triad = vibro_config::resolve_triad(&c.triad)?;
    Ok(vibro_log::session::log_errors(
        &c.session, c.window_s, &triad,
    )?)
}

fn lab(id: &str, l: &LabTask) -> Result<Vec<Row>, String> {
    use vibro_service::ServiceConfig;
    let setup = || -> anyhow::Result<_> {
        let triad = vibro_config::resolve_triad(&l.triad)?;
        let estimator = match &l.lab.estimator_config {
            Some(p) => vibro_estimator::Config::load(p)?,
            None => vibro_estimator::Config::shipped()?,
        }
        .estimator;
        let model = match &l.lab.model {
            Some(p) => vibro_lab::LabModel::load(p)?,
            None => vibro_lab::LabModel::base(vibro_lab::BaseMode::Exact),
        };
        let options = vibro_lab::log_table::LogOptions {
            triad,
            estimator,
            batches: 8,
            max_al_span_g: 1.0,
            pool_windows: 0,
        };
        Ok((model, options))
    };
    let (model, options) = setup().map_err(|e| format!("{e:#}"))?;
    let mut tables = Vec::new();
    let mut problems = Vec::new();
    let inputs = l
        .logs
        .iter()
        .map(|g| (g.path.as_path(), Some(g.position)))
        .chain(l.tables.iter().map(|t| (t.path.as_path(), None)));
    for (path, position) in inputs {
        // A `[[log]]` is read as a log whatever its name says; a table as the lab
        // reads its inputs.
        let loaded = match position {
            Some(_) => {
                vibro_lab::log_table::table_from_log(path, &model, &options).map(|(table, _)| table)
            }
            None => vibro_lab::inputs::load::<vibro_lab::Error>(
                &[vibro_lab::inputs::Input::Path(path.to_path_buf())],
                &model,
                &mut || Ok(options.clone()),
                &mut |_, _| {},
            )
            .map(|loaded| loaded.table),
        };
        match loaded {
            Ok(mut table) => {
                if let Some(position) = position {
                    table.conditions.retain(|c| at_position(c, position));
                }
                if table.conditions.is_empty() {
                    problems.push(format!("{}: no usable window of this unit", path.display()));
                } else {
                    tables.push(table);
                }
            }
            Err(e) => problems.push(problem_of(path, &anyhow::Error::new(e))),
        }
    }
    let problem = (!problems.is_empty()).then(|| problems.join("; "));
    if tables.is_empty() {
        return Err(problem.unwrap_or_else(|| "no data for this unit".into()));
    }
    let table = vibro_lab::CampaignTable::joined(tables).map_err(|e| format!("{e:#}"))?;
    let opts = vibro_lab::DiagnoseOptions {
        candidates: l.lab.effects.clone(),
        max_effects: l.lab.max_effects,
        threads: 1,
        ..vibro_lab::DiagnoseOptions::default()
    };
    let d = vibro_lab::diagnose(&model, &table, &opts).map_err(|e| {
        let e = format!("{e:#}");
        match &problem {
            Some(p) => format!("{e}; {p}"),
            None => e,
        }
    })?;
    Ok(lab_rows(id, &l.unit, &d, problem))
}

/// Whether a log's window belongs to the triad position `position` (0-based).
fn at_position(c: &vibro_lab::Condition, position: usize) -> bool {
    match c.scale_group {
        Some(g) => g.unit as usize == position,
        None => c
            .extra
            .get("unit")
            .is_some_and(|u| *u == (position + 1) as f64),
    }
}

/// The rows of a unit's diagnosis: one summary row (the verdict, the residual RMS of
/// the model as is, the effects found), then one row per parameter fitted.
fn lab_rows(id: &str, unit: &str, d: &vibro_lab::Diagnosis, problem: Option<String>) -> Vec<Row> {
    use vibro_lab::diagnose::Verdict;
    let (verdict, effects, params): (&str, Vec<String>, &[vibro_lab::fit::FittedParam]) =
        match &d.verdict {
            Verdict::Noise { .. } => ("noise", Vec::new(), &[]),
            Verdict::Effect { kinds, params, .. } => ("effect", kinds.clone(), params),
            Verdict::Confounded { kinds, .. } => ("confounded", kinds.clone(), &[]),
            Verdict::Unexplained { found, .. } => ("unexplained", found.clone(), &[]),
        };
    let base = Row {
        job: id.into(),
        kind: "lab".into(),
        unit: Some(unit.into()),
        stage: Some("lab".into()),
        verdict: Some(verdict.into()),
        ..Row::default()
    };
    let mut rows = vec![Row {
        windows: i64::try_from(d.comparison.summary.n).ok(),
        error_g: finite(d.comparison.summary.rms_residual_g),
        effect: (!effects.is_empty()).then(|| effects.join("+")),
        problem,
        ..base.clone()
    }];
    for p in params {
        rows.push(Row {
            effect: Some(p.effect.clone()),
            param: Some(p.name.clone()),
            value: finite(p.value),
            sigma: finite(p.sigma),
            ..base.clone()
        });
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::plan;
    use crate::Manifest;

    /// A job caps the lab's threads at one while it runs and puts the caller's cap back:
    /// a Python session that ran an archive in its own process (`workers=1`) must not
    /// have its later diagnoses capped (they echo their thread count, and took one
    /// where the command line took every core).
    #[test]
    fn a_job_leaves_the_callers_thread_cap_as_it_was() {
        let dir = tempfile::TempDir::new().unwrap();
        std::fs::write(dir.path().join("a.mcap"), "not a log").unwrap();
        std::fs::write(dir.path().join("t.csv"), "not a table").unwrap();
        let text = "format = \"vibrocomp-archive/1\"\n[[model]]\nname = \"one\"\n\
                    [[log]]\npath = \"a.mcap\"\nunits = [\"U1\"]\n\
                    [[table]]\npath = \"t.csv\"\nunit = \"U1\"\n";
        let m = Manifest::parse(text, &dir.path().join("m.toml")).unwrap();
        let before = vibro_lab::limit_threads(0);
        for job in plan(&m, &dir.path().join("sessions")) {
            let r = run_job(&job);
            assert!(r.failed(), "{}: {:?}", job.id, r.rows);
            assert_eq!(vibro_lab::thread_limit(), 0, "{}", job.id);
        }
        vibro_lab::limit_threads(before);
    }
}
