//! The archive batch (`vibro_archive`, README "Replaying an archive"): the journal and
//! the result table stay with one `Archive` in the process that drives the run; the
//! jobs travel as the library's self-contained JSON (`Job`, `JobResult`) to whichever
//! process runs them (`archive_job`: a local process pool, a Dask worker), so that the
//! Python half schedules with `concurrent.futures` or Dask and the rows are the
//! library's, whoever ran them.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;
use pyo3::prelude::*;
use vibro_archive::{Job, JobResult};

use crate::errors::IntoPy;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Archive>()?;
    m.add_function(wrap_pyfunction!(archive_job, m)?)?;
    m.add_function(wrap_pyfunction!(archive_failed, m)?)?;
    Ok(())
}

/// An archive run's state: the manifest's jobs, those the journal already holds, and
/// the table being written. `finish` consumes it; any call after that is an error.
/// Behind a mutex (a Python object may be shared between threads; the journal is
/// written by one at a time), which is only ever taken with the GIL released: a
/// thread waiting for it while holding the GIL would block the one that holds it from
/// coming back to Python.
#[pyclass(module = "vibrocomp._vibrocomp", frozen)]
struct Archive {
    inner: Mutex<Option<vibro_archive::Archive>>,
    manifest: PathBuf,
}

impl Archive {
    fn name(&self) -> String {
        format!("archive {}", self.manifest.display())
    }

    /// Runs `f` on the open archive, the GIL released (errors lead with `archive
    /// MANIFEST`).
    fn with<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut vibro_archive::Archive) -> anyhow::Result<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| {
            let name = self.name();
            let mut guard = self
                .inner
                .lock()
                .map_err(|_| anyhow::anyhow!("{name}: a previous call panicked"))?;
            let archive = guard
                .as_mut()
                .with_context(|| format!("{name}: already finished"))?;
            f(archive).context(name)
        })
        .py_err()
    }
}

#[pymethods]
impl Archive {
    /// Opens the run of `manifest` into `out` (made if missing): the jobs its journal
    /// holds are not run again. A journal of another manifest there is refused, unless
    /// `restart` (its results are dropped and the batch starts over).
    #[new]
    #[pyo3(signature = (manifest, out, restart = false))]
    fn new(py: Python<'_>, manifest: PathBuf, out: PathBuf, restart: bool) -> PyResult<Self> {
        let opened = py
            .detach(|| vibro_archive::Archive::open(&manifest, &out, restart))
            .map_err(|e| archive_error(e, &manifest))?;
        Ok(Archive {
            inner: Mutex::new(Some(opened)),
            manifest,
        })
    }

    /// Jobs in the manifest (done or not).
    fn total(&self, py: Python<'_>) -> PyResult<usize> {
        self.with(py, |a| Ok(a.total()))
    }

    /// The jobs the journal does not hold yet, in the plan's order, each as the
    /// library's JSON.
    fn pending(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        self.with(py, |a| {
            a.pending()
                .iter()
                .map(|job| serde_json::to_string(job).context("a job as JSON"))
                .collect()
        })
    }

    /// Records a result (`archive_job`'s JSON) in the journal: true when it is new,
    /// false when the journal held that job already (a task run twice: the first
    /// result stays).
    fn record(&self, py: Python<'_>, result: &str) -> PyResult<bool> {
        self.with(py, |a| {
            let result: JobResult = serde_json::from_str(result)
                .context("a job result that is not the library's JSON")?;
            a.record(&result)
                .map_err(anyhow::Error::from)
                .with_context(|| format!("recording job {}", result.job))
        })
    }

    /// Writes the table and the report from the journal; returns the summary's JSON.
    fn finish(&self, py: Python<'_>) -> PyResult<String> {
        py.detach(|| -> anyhow::Result<String> {
            let name = self.name();
            let taken = self
                .inner
                .lock()
                .map_err(|_| anyhow::anyhow!("{name}: a previous call panicked"))?
                .take();
            let archive = taken.with_context(|| format!("{name}: already finished"))?;
            let summary = archive
                .finish()
                .map_err(anyhow::Error::from)
                .context(name)?;
            serde_json::to_string(&summary).context("the archive's summary as JSON")
        })
        .py_err()
    }
}

/// An error of opening an archive as `VibrocompError`: a manifest's problems carry
/// their file, line and key (`vibro_archive::Error::location`, which
/// `errors::location` finds in the chain as the command line does).
fn archive_error(e: vibro_archive::Error, manifest: &Path) -> PyErr {
    crate::errors::to_py(&anyhow::Error::from(e).context(format!("archive {}", manifest.display())))
}

/// Runs one job (`Archive.pending`'s JSON), the GIL released; returns its result's
/// JSON for `Archive.record`. A log the job cannot read is a result with `problem`
/// rows, not an error: only JSON that is not a job is refused.
#[pyfunction]
fn archive_job(py: Python<'_>, job: &str) -> PyResult<String> {
    let job: Job = serde_json::from_str(job)
        .context("archive job: not the library's job JSON")
        .py_err()?;
    // On a thread of its own: Ctrl-C raises `KeyboardInterrupt` at once in the process
    // running the job (a local run's own), the job's work dropped.
    let result = crate::lab::stoppable(py, None, move |_, _| Ok(vibro_archive::run_job(&job)))?;
    serde_json::to_string(&result)
        .context("archive job: its result as JSON")
        .py_err()
}

/// The result of a job that could not run at all (Dask gave up on its task: its
/// worker kept dying): one `failed` row with `problem`, as the library's local engine
/// records a job whose worker died twice.
#[pyfunction]
fn archive_failed(job: &str, problem: String, worker: String) -> PyResult<String> {
    let job: Job = serde_json::from_str(job)
        .context("archive job: not the library's job JSON")
        .py_err()?;
    serde_json::to_string(&JobResult::failed_job(&job, problem, worker))
        .context("archive job: its result as JSON")
        .py_err()
}
