//! The model lab (`vibro_lab`, docs/lab.md): `compare`, `diagnose` and `add` on
//! campaign tables (files or CSV text), shake-table manifests and logs with a
//! reference, each result as the JSON `vibrocomp lab ... --json` prints.

use std::path::PathBuf;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::Context;
use pyo3::prelude::*;
use serde::Serialize;
use vibro_lab::diagnose::Progress;
use vibro_lab::inputs::{Input, Loaded};
use vibro_lab::log_table::LogOptions;
use vibro_lab::{BaseMode, DiagnoseOptions, LabModel, Stop};
use vibro_service::ServiceConfig;

use crate::errors::IntoPy;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_model, m)?)?;
    m.add_function(wrap_pyfunction!(save_model, m)?)?;
    m.add_function(wrap_pyfunction!(model_effects, m)?)?;
    m.add_function(wrap_pyfunction!(lab_table, m)?)?;
    m.add_function(wrap_pyfunction!(lab_compare, m)?)?;
    m.add_function(wrap_pyfunction!(lab_diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(lab_add, m)?)?;
    Ok(())
}

/// The options of a log input (the command line's `--triad`, `--estimator-config`,
/// `--batches`, `--max-al-span-g`, `--pool-windows`).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct LogArgs {
    triad: String,
    estimator_config: Option<PathBuf>,
    batches: usize,
    max_al_span_g: f64,
    pool_windows: usize,
}

impl LogArgs {
    fn options(&self) -> anyhow::Result<LogOptions> {
        let triad = vibro_config::resolve_triad(&self.triad)
            .with_context(|| format!("triad={}", self.triad))?;
        let estimator = match &self.estimator_config {
            Some(p) => vibro_estimator::Config::load(p)?,
            None => vibro_estimator::Config::shipped()?,
        }
        .estimator;
        Ok(LogOptions {
            triad,
            estimator,
            batches: self.batches,
            max_al_span_g: self.max_al_span_g,
            pool_windows: self.pool_windows,
        })
    }
}

/// One input from Python: `("path", path)` or `("table", csv_text, name, dir)`.
#[derive(FromPyObject)]
enum PyInput {
    Path((String, PathBuf)),
    Table((String, String, String, PathBuf)),
}

impl PyInput {
    fn into_input(self) -> Input {
        match self {
            PyInput::Path((_, path)) => Input::Path(path),
            PyInput::Table((_, text, name, dir)) => Input::Table { text, name, dir },
        }
    }
}

/// The model to compare: an extended model's TOML text and the name it is known by,
/// or the base model in `mode`.
fn lab_model(model: Option<(String, String)>, mode: &str) -> anyhow::Result<LabModel> {
    Ok(match model {
        Some((text, name)) => LabModel::parse(&text, &name)?,
        None => LabModel::base(match mode {
            "exact" => BaseMode::Exact,
            "paper" => BaseMode::Paper,
            "as-published" => BaseMode::AsPublished,
            other => {
                anyhow::bail!("mode = {other:?}: must be \"exact\", \"paper\" or \"as-published\"")
            }
        }),
    })
}

/// An extended model file's text, checked, and the name it is known by (its path).
#[pyfunction]
fn read_model(path: PathBuf) -> PyResult<(String, String)> {
    let run = || -> anyhow::Result<(String, String)> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(&path).map_err(|source| vibro_lab::Error::Io {
            path: name.clone(),
            source,
        })?;
        LabModel::parse(&text, &name)?;
        Ok((text, name))
    };
    run().py_err()
}

/// Writes a model's text to `path` by the command line's file rule (README, "Files";
/// `vibro_files::write_bytes`): complete or not at all, never through a link, into a
/// FIFO or a device; an existing file only with `overwrite`, else `FileExistsError`.
#[pyfunction]
fn save_model(path: PathBuf, text: &str, overwrite: bool) -> PyResult<()> {
    match vibro_files::write_bytes(&path, overwrite, text.as_bytes()) {
        Ok(()) => Ok(()),
        Err(e @ vibro_files::Error::Exists { .. }) => Err(
            pyo3::exceptions::PyFileExistsError::new_err(format!("{e} (here: overwrite=True)")),
        ),
        Err(e) => Err(anyhow::Error::from(e)).py_err(),
    }
}

/// An extended model's base mode and effect kinds.
#[pyfunction]
fn model_effects(text: &str, name: &str) -> PyResult<(String, Vec<String>)> {
    let m = LabModel::parse(text, name)
        .map_err(anyhow::Error::from)
        .py_err()?;
    Ok((m.mode.name().to_string(), m.effect_kinds()))
}

/// Reads the inputs for `model`, the command's name leading the errors as on the
/// command line (a text file named `.mcap` is "not an MCAP log" there too:
/// `vibro_lab::inputs::load` checks a log first).
fn load(
    inputs: Vec<PyInput>,
    model: &LabModel,
    log: &LogArgs,
    progress: &Progress,
) -> anyhow::Result<Loaded> {
    let inputs: Vec<Input> = inputs.into_iter().map(PyInput::into_input).collect();
    vibro_lab::inputs::load(&inputs, model, &mut || log.options(), &mut |done, of| {
        if let Some(f) = &progress.0 {
            f(done, of, "run measured");
        }
    })
}

/// A result's JSON with what became of its inputs beside it (`log`, `logs`,
/// `manifests`), as the command line prints it (`vibro_lab::inputs::WithInputs`).
fn with_inputs<T: Serialize>(inner: &T, loaded: &Loaded) -> anyhow::Result<String> {
    let with = vibro_lab::inputs::WithInputs::new(inner, &loaded.logs, &loaded.manifests);
    Ok(serde_json::to_string(&with)?)
}

/// Runs `command` on the loaded inputs on a thread of its own ([`stoppable`]: Ctrl-C
/// and a failing `progress` stop it); its errors lead with `lab NAME`, as the command
/// line's do.
fn with_loaded<T: Send + 'static>(
    py: Python<'_>,
    name: &str,
    (inputs, model, mode, log): (Vec<PyInput>, Option<(String, String)>, &str, LogArgs),
    progress: Option<Py<PyAny>>,
    command: impl FnOnce(&LabModel, Loaded, &Progress, &Stop) -> anyhow::Result<T> + Send + 'static,
) -> PyResult<T> {
    let (name, mode) = (name.to_string(), mode.to_string());
    stoppable(py, progress, move |p, stop| {
        let run = || -> anyhow::Result<T> {
            let model = lab_model(model, &mode)?;
            let loaded = load(inputs, &model, &log, p)?;
            command(&model, loaded, p, stop)
        };
        run().with_context(|| format!("lab {name}"))
    })
}

/// `lab --table-out`: the inputs as the lab's CSV table.
#[pyfunction]
#[pyo3(signature = (inputs, model, mode, log, progress=None))]
fn lab_table(
    py: Python<'_>,
    inputs: Vec<PyInput>,
    model: Option<(String, String)>,
    mode: &str,
    log: LogArgs,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    with_loaded(
        py,
        "table",
        (inputs, model, mode, log),
        progress,
        |_, loaded, _, _| {
            let mut bytes = Vec::new();
            loaded.table.write_csv(&mut bytes)?;
            Ok(String::from_utf8(bytes)?)
        },
    )
}

/// `lab compare --json`.
#[pyfunction]
#[pyo3(signature = (inputs, model, mode, log, path="waveform", progress=None))]
#[allow(clippy::too_many_arguments)]
fn lab_compare(
    py: Python<'_>,
    inputs: Vec<PyInput>,
    model: Option<(String, String)>,
    mode: &str,
    log: LogArgs,
    path: &str,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    // `lab compare --path windows`: the logs' windows predicted as the compensator
    // evaluates them (the waveform stage over their samples), or from the estimates'
    // statistics. ("waveform" is the package's earlier name for it; the command line's
    // `--path waveform`, every reading fitted, is not in the package yet.)
    let waveform = match path {
        "waveform" | "windows" => true,
        "statistics" => false,
        other => {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "path = {other:?}: must be \"windows\" (or \"waveform\") or \"statistics\""
            )))
        }
    };
    with_loaded(
        py,
        "compare",
        (inputs, model, mode, log),
        progress,
        move |model, loaded, _, _| {
            let c = if waveform {
                vibro_lab::compare_evaluated(model, &loaded.table, &loaded.logs)?
            } else {
                vibro_lab::compare(model, &loaded.table)?
            };
            with_inputs(&c, &loaded)
        },
    )
}

/// `lab diagnose --json`: only the `effects` candidates when given, at most
/// `max_effects` added by the stepwise search.
#[pyfunction]
#[pyo3(signature = (inputs, model, mode, log, effects, max_effects, progress=None))]
#[allow(clippy::too_many_arguments)]
fn lab_diagnose(
    py: Python<'_>,
    inputs: Vec<PyInput>,
    model: Option<(String, String)>,
    mode: &str,
    log: LogArgs,
    effects: Vec<String>,
    max_effects: usize,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    with_loaded(
        py,
        "diagnose",
        (inputs, model, mode, log),
        progress,
        move |model, loaded, p, stop| {
            let opts = DiagnoseOptions {
                candidates: effects,
                max_effects,
                progress: p.clone(),
                stop: stop.clone(),
                ..DiagnoseOptions::default()
            };
            let d = vibro_lab::diagnose(model, &loaded.table, &opts)?;
            with_inputs(&d, &loaded)
        },
    )
}

/// What `lab add --json` prints, but the file written (`out`): the Python package
/// writes the model where and when asked.
#[derive(Serialize)]
struct AddReport<'a> {
    effects: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    fit: Option<&'a vibro_lab::EffectFit>,
    #[serde(skip_serializing_if = "Option::is_none")]
    empirical: Option<&'a vibro_lab::EmpiricalFit>,
}

/// `lab add --json` (`effects` named, or `diagnosed`): the report's JSON and the
/// extended model's TOML text.
#[pyfunction]
#[pyo3(signature = (inputs, model, log, effects, diagnosed, freeze, progress=None))]
#[allow(clippy::too_many_arguments)]
fn lab_add(
    py: Python<'_>,
    inputs: Vec<PyInput>,
    model: Option<(String, String)>,
    log: LogArgs,
    effects: Vec<String>,
    diagnosed: bool,
    freeze: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<(String, String)> {
    let setup = (inputs, model, "exact", log);
    with_loaded(py, "add", setup, progress, move |model, loaded, p, stop| {
        let request = if diagnosed {
            vibro_lab::add::Effects::Diagnosed
        } else {
            vibro_lab::add::Effects::Kinds(effects)
        };
        let opts = DiagnoseOptions {
            progress: p.clone(),
            stop: stop.clone(),
            ..DiagnoseOptions::default()
        };
        let added = vibro_lab::add::add(model, &loaded.table, &request, freeze, &opts)?;
        let report = AddReport {
            effects: added.model.effect_kinds(),
            fit: added.fit.as_ref(),
            empirical: added.empirical.as_ref(),
        };
        Ok((with_inputs(&report, &loaded)?, added.model.to_toml()))
    })
}

// ---------------------------------------------------------------------------------
// Long calls: stopped by Ctrl-C and by a failing progress callback

/// How often the calling thread checks for signals (Ctrl-C) while a long call runs.
const SIGNAL_TICK: Duration = Duration::from_millis(100);

/// Most time between two calls of a `progress` callback while a long call runs (the
/// last count repeated when the work has not moved): a progress bar stays alive, and
/// its exception stops the work within this.
const PROGRESS_TICK: Duration = Duration::from_millis(250);

/// How long a stopped call waits for its work to end before it returns anyway: the
/// lab's fits end within one model evaluation (`vibro_lab::Stop`); a stage that does
/// not poll the stop (reading one log) finishes on its own, its result dropped.
const STOP_GRACE: Duration = Duration::from_millis(200);

/// Runs `work` on a thread of its own while the calling thread, the GIL released
/// between ticks, keeps Python responsive: every [`SIGNAL_TICK`] it checks for
/// signals (Ctrl-C raises `KeyboardInterrupt` here), and when the lab's count moved,
/// or [`PROGRESS_TICK`] after its last call, it calls `progress(done, of, what)` with
/// the latest count (`(0, 0, "starting")` before the first; the count at the end
/// before the result). An exception from either
/// stops the work ([`Stop`], polled by the lab's fits) and is raised as it is, no
/// result returned. The work never touches Python, so it cannot wait for the GIL.
///
/// Called from a thread other than the main one, Ctrl-C is not seen there (Python
/// delivers signals to the main thread); a failing `progress` still stops the call.
pub(crate) fn stoppable<T: Send + 'static>(
    py: Python<'_>,
    progress: Option<Py<PyAny>>,
    work: impl FnOnce(&Progress, &Stop) -> anyhow::Result<T> + Send + 'static,
) -> PyResult<T> {
    type Count = Option<(usize, usize, String)>;
    let latest: Arc<Mutex<Count>> = Arc::default();
    let seen = latest.clone();
    let lab_progress = Progress(Some(Arc::new(move |done: usize, of: usize, what: &str| {
        *seen.lock().unwrap_or_else(PoisonError::into_inner) = Some((done, of, what.to_string()));
    }) as Arc<vibro_lab::diagnose::ProgressFn>));
    let stop = Stop::new();
    let worker_stop = stop.clone();
    let (tx, rx) = mpsc::channel();
    // Waited on with the GIL released, which needs it shared (`Sync`); only this
    // thread takes it.
    let rx = Mutex::new(rx);
    let wait = |timeout: Duration| {
        rx.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .recv_timeout(timeout)
    };
    std::thread::Builder::new()
        .name("vibrocomp-work".into())
        .spawn(move || {
            // The receiver gone (the call stopped and returned): nothing to tell.
            let _ = tx.send(work(&lab_progress, &worker_stop));
        })
        .map_err(|e| {
            pyo3::exceptions::PyRuntimeError::new_err(format!(
                "cannot start the work's thread: {e}"
            ))
        })?;
    let mut reported: Count = None;
    let mut last_call = Instant::now();
    let mut tell = |py: Python<'_>| -> PyResult<()> {
        let Some(f) = &progress else { return Ok(()) };
        let now = latest
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        let moved = now.is_some() && now != reported;
        if !(moved || last_call.elapsed() >= PROGRESS_TICK) {
            return Ok(());
        }
        let (done, of, what) = now.clone().unwrap_or((0, 0, "starting".to_string()));
        reported = now;
        last_call = Instant::now();
        f.call1(py, (done, of, what)).map(drop)
    };
    let mut checked = Ok(());
    loop {
        if let Err(e) = checked {
            stop.request();
            // Give the work a moment to see the stop, so that it does not run on behind
            // the exception; its result, if any, is dropped.
            let _ = py.detach(|| wait(STOP_GRACE));
            return Err(e);
        }
        match py.detach(|| wait(SIGNAL_TICK)) {
            Ok(result) => {
                // The last count (the candidates all fitted) before the result.
                tell(py)?;
                return result.py_err();
            }
            Err(RecvTimeoutError::Timeout) => {
                checked = py.check_signals().and_then(|()| tell(py));
            }
            Err(RecvTimeoutError::Disconnected) => {
                return Err(pyo3::exceptions::PyRuntimeError::new_err(
                    "the work's thread ended without a result (a panic in vibrocomp: please report it)",
                ));
            }
        }
    }
}
