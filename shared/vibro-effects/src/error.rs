//! Errors of the effects library and the extended model.
//!
//! The messages are the ones the simulator (`vibro_sim::Error`) and the lab
//! (`vibro_lab::Error`) printed before the effects moved here, byte for byte: both wrap
//! this enum transparently.

/// What can go wrong building an effect, evaluating its mean formula, or reading,
/// writing and using an extended model file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An effect parameter (or an input of a mean formula) breaks its rule. The key
    /// and the value are quoted by their excerpt: either can be as long as the file.
    #[error(
        "{} = {}: {rule}",
        vibro_toml::echo::excerpt(key),
        vibro_toml::echo::excerpt(value)
    )]
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
    /// A model file with problems: every problem, one per line. `line` and `key`
    /// locate the first problem whose key is known (`effect[0].foo`), where the file
    /// has it.
    #[error("{path}: {}", problems.join("\n  "))]
    Model {
        path: String,
        problems: Vec<String>,
        line: Option<usize>,
        key: Option<String>,
    },
    /// A model file that does not parse, or has unknown keys (every one of them).
    #[error(transparent)]
    Toml(#[from] vibro_toml::Error),
    /// A model file refused by the file rule, or that cannot be written
    /// ([`LabModel::save`](crate::LabModel::save)).
    #[error(transparent)]
    Files(#[from] vibro_files::Error),
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

impl Error {
    /// The file, and the line and key where known (a model file's TOML errors).
    pub fn location(&self) -> Option<vibro_toml::Location> {
        match self {
            Error::Toml(e) => Some(e.location()),
            Error::Model {
                path, line, key, ..
            } => Some(vibro_toml::Location {
                file: path.clone(),
                line: *line,
                column: None,
                key: key.clone(),
            }),
            Error::Io { path, .. } => Some(vibro_toml::Location {
                file: path.clone(),
                ..Default::default()
            }),
            _ => None,
        }
    }
}

/// Result of the effects library.
pub type Result<T> = std::result::Result<T, Error>;
