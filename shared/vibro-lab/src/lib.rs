//! # vibro-lab
//!
//! The model lab: compare the vibration-error model (MODEL.md sections 5-6) with
//! measured vibration errors (a shake-table campaign, MODEL.md section 8), see where it
//! fails, find which physical effect of MODEL.md section 11 is missing, fit it, and add
//! it to an extended model file that the rest of vibrocomp reads.
//!
//! - [`table`]: the campaign table (CSV, one row per test condition, docs/lab.md),
//!   read within bounds by [`table_input`] (a line's length, columns, rows, encoding).
//! - [`flight`]: conditions from a record with a reference (a flight cut into
//!   windows): the VE measured per window, the prediction's uncertainty.
//! - [`library`]: the candidate effects the lab can fit.
//! - [`fit`]: weighted nonlinear least squares (Levenberg-Marquardt).
//! - [`diagnose`]: `compare`, `diagnose` (where the model fails and which effect is
//!   missing, with a verdict that says "noise", "effect", "confounded" or
//!   "unexplained"), `add_effect`, `error_ladder`.
//! - [`empirical`]: beyond the library, a cross-validated empirical correction
//!   (not physical) offered when the verdict is "unexplained".
//! - [`log_table`]: an MCAP log with a reference turned into the lab's table (the
//!   estimator's core run offline over its vibration stream, windows measured and
//!   pooled); [`spectrum`]: the spectrum behind an estimate's band powers.
//! - [`waveform`]: a log's windows predicted by the compensator's waveform stage over
//!   the log's own samples (`lab compare`: one evaluation everywhere, MODEL.md 12).
//! - [`report`]: the self-contained HTML report of a diagnosis, with its SVG plots;
//!   [`text`]: the lab's results as the command line prints them.
//!
//! The effects, the extended model file (`MODEL.toml`: base mode plus effects,
//! [`LabModel`]) and its prediction are the effects library's (`vibro_effects`),
//! shared with the simulator and the compensator: one physics, one mean formula
//! (`Effect::mean_shift_g`), used to simulate a campaign, to explain one and to
//! compensate.

// Per-axis and per-row index loops mirror the formulas' subscripts.
#![allow(clippy::needless_range_loop)]

pub mod add;
pub mod campaign;
pub mod diagnose;
pub mod empirical;
pub mod errors;
pub mod fit;
pub mod flight;
pub mod inputs;
pub mod library;
pub mod log_table;
mod parallel;
pub use parallel::{limit_threads, thread_limit};
pub mod report;
/// The spectrum behind an estimate's band powers (moved to `vibro_effects`, shared with the
/// compensator).
pub use vibro_effects::spectrum;
pub mod table;
pub mod table_input;
pub mod text;
pub mod wave_diagnose;
pub mod wave_input;
pub mod wave_report;
pub mod wave_text;
pub mod waveform;

pub use diagnose::{
    add_effect, add_effects, add_empirical, compare, compare_evaluated, diagnose, error_ladder,
    fit_effect, Comparison, DiagnoseOptions, Diagnosis, LadderStep, Verdict,
};
pub use empirical::{fit_empirical, EmpiricalFit};
pub use fit::{Budget, BudgetUsed, EffectFit, Stop};
pub use table::{CampaignTable, Condition, REQUIRED_COLUMNS};
// The extended model file the lab writes and its prediction live in the effects
// library (the compensator reads them too); the lab's API hands them out.
pub use vibro_effects::model::{BaseMode, FitRecord, LabModel};
pub use vibro_effects::predict::{predict_ve, Prediction};

/// Errors of the lab. Every message names the file (and row, column, key) concerned.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A campaign table with problems: every problem, one per line.
    #[error("{path}: {}", problems.join("\n  "))]
    Table { path: String, problems: Vec<String> },
    /// Reading or writing a file.
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// A prediction the physics cannot make (an effect without a formula for the
    /// condition, an invalid vibration).
    #[error("{what}: {reason}")]
    Predict { what: String, reason: String },
    /// A problem with no numerical meaning: a residual, Jacobian or normal matrix
    /// that is not finite or overflows (extreme values in a table built in code).
    #[error("{what}: numerically meaningless: {reason}")]
    Numeric { what: String, reason: String },
    /// A fit stopped by its budget (`fit::Budget`): how much it used and the limit.
    #[error("{what}: the fit's budget ran out: {reason}")]
    Budget { what: String, reason: String },
    /// A request that does not make sense (an unknown candidate, too few conditions).
    #[error("{0}")]
    Invalid(String),
    /// The effects library or the extended model (a model file with problems, an
    /// effect that cannot be built or evaluated), its message unchanged.
    #[error(transparent)]
    Effects(#[from] vibro_effects::Error),
    /// An MCAP log the lab reads (`log_table`), its message unchanged (boxed: the
    /// reader's errors are large, and every `Result` of the lab carries this enum).
    #[error(transparent)]
    Mcap(Box<vibro_mcap::Error>),
    /// A log's attachments (`vibro_log`), its message unchanged.
    #[error(transparent)]
    Log(Box<vibro_log::Error>),
    /// A passport or triad (a log's attached passport), its message unchanged.
    #[error(transparent)]
    Config(Box<vibro_config::ConfigError>),
    /// Drawing one of the report's plots (`report`), the plotting library's message.
    #[error("{0}")]
    Render(String),
    /// What the lab was doing when a step below it failed: `what: cause`.
    #[error("{what}")]
    Context {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
}

impl From<vibro_mcap::Error> for Error {
    fn from(e: vibro_mcap::Error) -> Self {
        Error::Mcap(Box::new(e))
    }
}

impl From<vibro_log::Error> for Error {
    fn from(e: vibro_log::Error) -> Self {
        Error::Log(Box::new(e))
    }
}

impl From<vibro_config::ConfigError> for Error {
    fn from(e: vibro_config::ConfigError) -> Self {
        Error::Config(Box::new(e))
    }
}

impl<E: std::error::Error + Send + Sync> From<plotters::drawing::DrawingAreaErrorKind<E>>
    for Error
{
    fn from(e: plotters::drawing::DrawingAreaErrorKind<E>) -> Self {
        Error::Render(e.to_string())
    }
}

impl Error {
    /// This error as the cause of `what` (`what: self`).
    pub fn context(self, what: impl Into<String>) -> Self {
        Error::Context {
            what: what.into(),
            source: Box::new(self),
        }
    }
}

pub type Result<T> = std::result::Result<T, Error>;
