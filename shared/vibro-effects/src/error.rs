//! Errors of the effects library and the extended model.
//!
//! The messages are the ones the simulator (`vibro_sim::Error`) and the lab
//! (`vibro_lab::Error`) printed before the effects moved here, byte for byte: both wrap
//! this enum transparently.

/// What can go wrong building an effect, evaluating its mean formula, or reading,
/// writing and using an extended model file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An effect parameter (or an input of a mean formula) breaks its rule.
    #[error("{key} = {value}: {rule}")]
    Invalid {
        key: String,
        value: String,
        rule: String,
    },
    /// Several parameters break their rules, all reported at once (each an
    /// [`Error::Invalid`]).
    #[error("{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("; "))]
    Several(Vec<Error>),
    /// The physics core refused an input.
    #[error(transparent)]
    Physics(#[from] vibro_physics::Error),
    /// A model file with problems: every problem, one per line.
    #[error("{path}: {}", problems.join("\n  "))]
    Model { path: String, problems: Vec<String> },
    /// Reading or writing a model file.
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
}

/// Result of the effects library.
pub type Result<T> = std::result::Result<T, Error>;
