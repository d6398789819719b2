//! # vibro-wavefit
//!
//! The lab on the waveform (issue 44, MODEL.md section 12): a model's parameters
//! fitted to a log's readings themselves, each reading predicted from the vibration
//! sensors' samples over its own interval, instead of windows' VE predicted from the
//! statistics of an estimate.
//!
//! Per reading, the prediction is the mean of the conversion function with the model's
//! effects under the vibration that actually happened ([`eval`]): the sensors' chain
//! undone and their delay applied ([`prepare`]), mapped to each unit, through the path
//! effects' transfers, plus the reference (gravity, the flight acceleration). The
//! unit's linear response to the table's motion is then part of the prediction, not a
//! separate regression: a mount, which moves all three axes of every unit through its
//! resonance, and a unit's own response, on IA alone, leave different fingerprints in
//! every reading, where window means see `|T(f)|` at the tones' frequencies only.
//!
//! [`fit`] fits free parameters (of effects, and the sensors' delay) by
//! Levenberg-Marquardt with each run's and unit's bias and drift projected out, and
//! states uncertainties that hold when the residual's noise is correlated.
//!
//! One physics: the effects are the library's own (`vibro_effects`), their output
//! hooks run as the simulator and the compensator run them; path filters use their
//! continuous-time form (`Effect::path_transfer`), of which the hooks run the
//! discretisation.

// Per-unit and per-axis index loops mirror the formulas' subscripts.
#![allow(clippy::needless_range_loop)]

pub mod eval;
pub mod fit;
pub mod prepare;

pub use eval::Role;
pub use fit::{
    fit, lack_of_fit, noise_of, Fit, FitSettings, FreeParam, LackOfFit, Noise, Problem, Rest,
};
pub use prepare::{prepare, PrepareCounts, PrepareOptions, PreparedRun, RunInput, VibSegment};

/// Errors of the waveform fit; every message names the run or effect concerned.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A run that cannot be fitted: its data (named) and why.
    #[error("{run}: {reason}")]
    Input { run: String, reason: String },
    /// An effect the waveform cannot evaluate.
    #[error(
        "effect {0}: not evaluated on the waveform (a description's phases, a kurtosis or a \
         mean correction: the samples carry the vibration itself); use the statistics path"
    )]
    NotOnWaveform(String),
    /// The model's effects (a table that does not build), unchanged.
    #[error(transparent)]
    Effects(#[from] vibro_effects::Error),
    /// A fit that has no numerical meaning.
    #[error("numerically meaningless: {0}")]
    Numeric(String),
}

pub type Result<T> = std::result::Result<T, Error>;
