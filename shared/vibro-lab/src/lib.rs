//! # vibro-lab
//!
//! The model lab: compare the vibration-error model (MODEL.md sections 5-6) with
//! measured vibration errors (a shake-table campaign, MODEL.md section 8), see where it
//! fails, find which physical effect of MODEL.md section 11 is missing, fit it, and add
//! it to an extended model file that the rest of vibrocomp reads.
//!
//! - [`table`]: the campaign table (CSV, one row per test condition, docs/lab.md).
//! - [`model`]: the extended model file (`MODEL.toml`): base mode plus effects.
//! - [`flight`]: conditions from a record with a reference (a flight cut into
//!   windows): the VE measured per window, the prediction's uncertainty.
//! - [`predict`]: the extended model's VE for one condition.
//! - [`library`]: the candidate effects the lab can fit.
//! - [`fit`]: weighted nonlinear least squares (Levenberg-Marquardt).
//! - [`diagnose`]: `compare`, `diagnose` (where the model fails and which effect is
//!   missing, with a verdict that says "noise", "effect", "confounded" or
//!   "unexplained"), `add_effect`, `error_ladder`.
//!
//! The effects are the simulator's (`vibro_sim::effects`): one physics, one mean
//! formula (`Effect::mean_shift_g`), used to simulate a campaign and to explain one.

// Per-axis and per-row index loops mirror the formulas' subscripts.
#![allow(clippy::needless_range_loop)]

pub mod diagnose;
pub mod fit;
pub mod flight;
pub mod library;
pub mod model;
pub mod predict;
pub mod table;

pub use diagnose::{
    add_effect, compare, diagnose, error_ladder, fit_effect, Comparison, DiagnoseOptions,
    Diagnosis, LadderStep, Verdict,
};
pub use fit::EffectFit;
pub use model::{BaseMode, FitRecord, LabModel};
pub use predict::{predict_ve, Prediction};
pub use table::{CampaignTable, Condition, REQUIRED_COLUMNS};

/// Errors of the lab. Every message names the file (and row, column, key) concerned.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A campaign table with problems: every problem, one per line.
    #[error("{path}: {}", problems.join("\n  "))]
    Table { path: String, problems: Vec<String> },
    /// A model file with problems.
    #[error("{path}: {}", problems.join("\n  "))]
    Model { path: String, problems: Vec<String> },
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
    /// A request that does not make sense (an unknown candidate, too few conditions).
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T> = std::result::Result<T, Error>;
