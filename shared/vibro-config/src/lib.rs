//! # vibro-config
//!
//! Loads vibrocomp's configuration files and turns them into the validated types of
//! the physics core: accelerometer passports (`config/accelerometers/*.toml`), triad
//! geometries (`config/triads/*.toml`) and vibration band tables
//! (`config/vibration/*.csv`). Every error names the file, the key (or row and
//! column), the offending value and the rule, and all problems of a file are reported
//! at once.
//!
//! The passports and the triad shipped in `config/` are also embedded in the binary,
//! so `--passport AL-15` works from any directory.
//!
//! ```
//! let p = vibro_config::resolve_passport("AL-15").unwrap();
//! assert_eq!(p.k1_v_per_g, -1.6698);
//! ```

mod passport;
mod psd;
pub mod rig;
mod triad;

pub use passport::{load_passport, parse_passport, resolve_passport, EMBEDDED_PASSPORTS};
pub use psd::{load_psd_table, parse_psd_table};
pub use rig::{load_rig, parse_rig, RigConfig};
pub use triad::{default_triad, load_triad, parse_triad, resolve_triad, TriadConfig};

/// Errors of configuration loading. Each carries the file (or embedded name) it is about.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: cannot read: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: {message}")]
    Parse { file: String, message: String },
    /// A TOML file that does not parse, or has unknown keys (every one of them).
    #[error(transparent)]
    Toml(#[from] vibro_toml::Error),
    #[error("{file}: {}", problems.join("; "))]
    Invalid { file: String, problems: Vec<String> },
    #[error(
        "{} is neither a readable file nor a known {kind} id (known: {known})",
        vibro_toml::bounds::quote(arg)
    )]
    Unknown {
        arg: String,
        kind: &'static str,
        known: String,
    },
}

/// Result of configuration loading.
pub type Result<T> = std::result::Result<T, ConfigError>;

/// Reads a configuration file: at most [`vibro_toml::bounds::MAX_FILE_BYTES`], a bigger
/// one refused before it is read.
fn read(path: &std::path::Path) -> Result<String> {
    vibro_toml::bounds::read_file(path).map_err(|source| ConfigError::Io {
        file: path.display().to_string(),
        source,
    })
}

impl ConfigError {
    /// The file, line and key of the problem, where known.
    pub fn location(&self) -> Option<vibro_toml::Location> {
        match self {
            ConfigError::Toml(e) => Some(e.location()),
            ConfigError::Io { file, .. }
            | ConfigError::Parse { file, .. }
            | ConfigError::Invalid { file, .. } => Some(vibro_toml::Location {
                file: file.clone(),
                ..Default::default()
            }),
            ConfigError::Unknown { .. } => None,
        }
    }
}
