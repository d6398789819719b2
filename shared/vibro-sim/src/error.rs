//! Errors of the simulator.

/// What can go wrong building or running a simulation.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scenario or run parameter breaks its rule.
    #[error("{key} = {value}: {rule}")]
    Invalid {
        key: String,
        value: String,
        rule: String,
    },
    /// An effect refused its parameters or its mean formula failed (the effects
    /// library's message, unchanged).
    #[error(transparent)]
    Effects(#[from] vibro_effects::Error),
    /// The physics core refused an input.
    #[error(transparent)]
    Physics(#[from] vibro_physics::Error),
    /// A scenario file breaks its rules; every problem is listed, each naming the key
    /// path, the value and the rule.
    #[error("{file}: {}", problems.join("; "))]
    Scenario { file: String, problems: Vec<String> },
    /// A file a scenario refers to (passport, triad, PSD table) could not be loaded.
    #[error(transparent)]
    Config(#[from] vibro_config::ConfigError),
    /// A scenario file that does not parse, or has unknown keys (every one of them).
    #[error(transparent)]
    Toml(#[from] vibro_toml::Error),
    /// A file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    /// The section-8 measurement of a campaign condition failed.
    #[error("condition {condition}: VE measurement (MODEL.md section 8): {source}")]
    Measurement {
        condition: String,
        source: vibro_ident::Error,
    },
    /// Writing a CSV summary failed.
    #[error("writing CSV: {0}")]
    Csv(#[from] csv::Error),
    /// An FFT was handed buffers of the wrong size (cannot happen with the buffers the
    /// simulator allocates; kept so that no path panics).
    #[error("FFT of {what} failed: {message}")]
    Fft { what: &'static str, message: String },
    /// A request the simulator cannot honour for this input (e.g. a positions CSV for
    /// a condition without a tone).
    #[error("{what}: {reason}")]
    Unsupported { what: String, reason: String },
    /// An `--effect` whose kind is not in the effects library.
    #[error("--effect {text:?}: unknown kind {kind:?}; known: {known}")]
    UnknownEffect {
        text: String,
        kind: String,
        known: String,
    },
    /// An `--effect` parameter that is not `key=value`.
    #[error("--effect {text:?}: {item:?} is not key=value")]
    EffectItem { text: String, item: String },
    /// An `--effect` parameter whose value is not TOML (boxed: the error is large).
    #[error("--effect {text:?}: {item:?}: the value must be TOML (a number, a string in quotes, an array)")]
    EffectValue {
        text: String,
        item: String,
        #[source]
        source: Box<toml::de::Error>,
    },
    /// An `--effect` that does not make an effect table (a bad `enabled` or `units`).
    #[error("--effect {text:?}")]
    EffectSpec {
        text: String,
        #[source]
        source: Box<toml::de::Error>,
    },
}

impl Error {
    /// The file, and the line and key where known (a scenario's or a referenced
    /// file's TOML errors).
    pub fn location(&self) -> Option<vibro_toml::Location> {
        match self {
            Error::Toml(e) => Some(e.location()),
            Error::Config(e) => e.location(),
            Error::Effects(e) => e.location(),
            Error::Scenario { file, .. } | Error::Io { file, .. } => Some(vibro_toml::Location {
                file: file.clone(),
                ..Default::default()
            }),
            _ => None,
        }
    }
}

/// Result of the simulator.
pub type Result<T> = std::result::Result<T, Error>;
