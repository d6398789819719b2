//! # vibro-archive
//!
//! A batch over an archive of logs and campaign tables: every log compensated with every
//! model and its errors measured against the log's reference (`vibro_offline`, then
//! `vibro_log::session::log_errors`, what `vibrocomp log errors` prints), and every
//! unit's data diagnosed by the lab (`vibro_lab::inputs::load` + `vibro_lab::diagnose`).
//! The results go into one Parquet table and a self-contained HTML report
//! (docs/archive.md).
//!
//! - [`Manifest`]: the batch's TOML file (`format = "vibrocomp-archive/1"`), every
//!   problem reported at once with its line and key;
//! - [`Job`]: one unit of work with a stable id (`compensate/<log>/<model>`,
//!   `lab/<unit>`), self-contained JSON that a process on another machine (with a
//!   shared file system) runs with [`run_job`], which never fails: an error becomes a
//!   row with its `problem`;
//! - [`Archive`]: an opened output folder, whose journal (`journal.jsonl`, one line per
//!   finished job, fsynced) makes a killed batch resumable without counting a job
//!   twice; [`Archive::finish`] writes `results.parquet` and `report.html` from it;
//! - [`run_local`]: the local engine, worker *processes* (`vibrocomp archive worker`,
//!   [`serve_worker`]) fed one job at a time over their stdin.
//!
//! ```no_run
//! # fn main() -> Result<(), vibro_archive::Error> {
//! use std::path::Path;
//! let archive = vibro_archive::Archive::open(Path::new("batch.toml"), Path::new("out"), false)?;
//! let summary = vibro_archive::run_local(archive, Path::new("vibrocomp"), 2, &mut |_, _| {})?;
//! println!("{} rows in {}", summary.rows, summary.results.display());
//! # Ok(()) }
//! ```
//!
//! The table is the same whatever the number of workers or the order in which jobs
//! finish (apart from the timing columns `elapsed_s` and `worker`): rows are ordered by
//! the plan, and each job's result is what its journal line says.

mod archive;
mod engine;
mod journal;
pub mod manifest;
mod parquet_out;
pub mod plan;
mod report;
mod run;

use std::path::PathBuf;

pub use archive::{
    Archive, ArchiveSummary, JOURNAL_FILE, LOCK_FILE, REPORT_FILE, RESULTS_FILE, SESSIONS_DIR,
};
pub use engine::{run_dask, run_local, serve_worker};
pub use manifest::{Manifest, Problem};
pub use parquet_out::{parquet_bytes, COLUMNS};
pub use plan::{Job, Task};
pub use report::render_report;
pub use run::{run_job, JobResult, Row};

/// Errors of the archive: its manifest, its output folder and journal, the workers.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The manifest is not TOML of its format, or has unknown keys (each with its line).
    #[error("manifest {file}: {}", source.detail())]
    Toml {
        file: PathBuf,
        /// Boxed: the TOML error is large, and every result of the crate carries it.
        source: Box<vibro_toml::Error>,
    },
    /// Every problem of a manifest, each with its line and key.
    #[error("manifest {file}: {}", problems_text(problems))]
    Invalid {
        file: PathBuf,
        problems: Vec<Problem>,
    },
    /// A file that cannot be read.
    #[error("cannot read {path}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// An output refused by the file rule, or that cannot be written.
    #[error(transparent)]
    Files(#[from] vibro_files::Error),
    /// The output folder's journal was written for another manifest.
    #[error("journal {path}: written for another manifest (hash {found}, this manifest's is {expected}); pass --restart to start the batch over in this folder, or name another --out")]
    OtherManifest {
        path: PathBuf,
        found: String,
        expected: String,
    },
    /// A journal line (not the last: a torn last line is cut off) that is not a job's
    /// result.
    #[error("journal {path} line {line}: {problem}")]
    Journal {
        path: PathBuf,
        line: usize,
        problem: String,
    },
    /// A write of the journal that failed.
    #[error("journal {path}: cannot {action}")]
    JournalIo {
        path: PathBuf,
        action: &'static str,
        source: std::io::Error,
    },
    /// Another run holds the output folder.
    #[error("output folder lock {path}: another `archive run` is using this folder")]
    Busy { path: PathBuf },
    /// A result for a job the plan does not have.
    #[error("result for job {job:?}, which is not in this batch's plan")]
    UnknownJob { job: String },
    /// The Parquet table cannot be encoded.
    #[error("results table {path}: {message}")]
    Parquet { path: PathBuf, message: String },
    /// A plot of the report cannot be drawn.
    #[error("report: {0}")]
    Report(String),
    /// A worker process that cannot be started or talked to.
    #[error("worker {exe}: {problem}")]
    Worker { exe: PathBuf, problem: String },
    /// The Python side of `--dask` cannot be run.
    #[error("--dask: {problem}")]
    Python { problem: String },
}

fn problems_text(problems: &[Problem]) -> String {
    let lines: Vec<String> = problems.iter().map(ToString::to_string).collect();
    match lines.len() {
        1 => lines[0].clone(),
        n => format!("{n} problems:\n  {}", lines.join("\n  ")),
    }
}

impl Error {
    /// The file, and the line and key of the (first) problem of a manifest error.
    pub fn location(&self) -> Option<vibro_toml::Location> {
        match self {
            Error::Toml { source, .. } => Some(source.location()),
            Error::Invalid { file, problems } => {
                let first = problems.first();
                Some(vibro_toml::Location {
                    file: file.display().to_string(),
                    line: first.and_then(|p| p.line),
                    column: None,
                    key: first.map(|p| p.key.clone()),
                })
            }
            _ => None,
        }
    }
}

impl<E: std::error::Error + Send + Sync> From<plotters::drawing::DrawingAreaErrorKind<E>>
    for Error
{
    fn from(e: plotters::drawing::DrawingAreaErrorKind<E>) -> Self {
        Error::Report(e.to_string())
    }
}

/// Tests that take an output folder's lock, and tests that fork worker processes,
/// one at a time: a child forked while another test's lock is open holds that lock
/// until it execs (`flock` belongs to the open file, which the fork shares).
#[cfg(test)]
pub(crate) fn serial() -> std::sync::MutexGuard<'static, ()> {
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// Result of the archive's functions.
pub type Result<T> = std::result::Result<T, Error>;
