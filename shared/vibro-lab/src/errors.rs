//! Where an error of the libraries' inputs points, for every front end (the command
//! line's `--json` error object, README "Conventions"; the Python package's
//! exceptions): the file, and where known the line, column and key of the problem,
//! from the first cause in an error's chain whose library error type carries them.
//!
//! Covers the files the lab and the model read: configurations (TOML), scenarios,
//! extended models, campaign tables and manifests, rig records, logs' attachments and
//! the services' configurations. The bridge's file is the command line's own case.

use std::error::Error as StdError;
use vibro_toml::Location;

/// The location one cause carries, if its type is one of the libraries' errors that
/// name a file.
pub fn cause_location(cause: &(dyn StdError + 'static)) -> Option<Location> {
    if let Some(x) = cause.downcast_ref::<vibro_toml::Error>() {
        return Some(x.location());
    }
    if let Some(x) = cause.downcast_ref::<vibro_config::ConfigError>() {
        return x.location();
    }
    if let Some(x) = cause.downcast_ref::<vibro_service::ConfigError>() {
        return Some(x.location());
    }
    if let Some(x) = cause.downcast_ref::<vibro_sim::Error>() {
        return x.location();
    }
    // A simulated flight's errors from the simulator (`vibro_log::flight`); a log's
    // errors name their file.
    if let Some(x) = cause.downcast_ref::<vibro_log::Error>() {
        if let vibro_log::Error::Sim(x) = x {
            return x.location();
        }
        return x.file().map(path_only);
    }
    if let Some(x) = cause.downcast_ref::<vibro_mcap::Error>() {
        return x.file().map(path_only);
    }
    if let Some(x) = cause.downcast_ref::<vibro_effects::Error>() {
        return x.location();
    }
    // A file of `identify` (a table, a rig's record, a reference not covering it).
    if let Some(file) = cause
        .downcast_ref::<vibro_ident::Error>()
        .and_then(|x| x.file())
    {
        return Some(file_only(file.to_string()));
    }
    match cause.downcast_ref::<crate::Error>()? {
        crate::Error::Effects(x) => x.location(),
        // A log's attached passport (`crate::log_table`).
        crate::Error::Config(x) => x.location(),
        crate::Error::Table { path, .. } | crate::Error::Io { path, .. } => {
            Some(file_only(path.clone()))
        }
        // Transparent: the inner error is not a cause of its own in the chain.
        crate::Error::Log(x) => cause_location(x.as_ref()),
        crate::Error::Mcap(x) => cause_location(x.as_ref()),
        _ => None,
    }
}

/// The location of the first cause in `chain` (outermost first) that carries one.
pub fn location<'a>(
    chain: impl IntoIterator<Item = &'a (dyn StdError + 'static)>,
) -> Option<Location> {
    chain.into_iter().find_map(cause_location)
}

/// [`file_only`] for a path.
fn path_only(path: &std::path::Path) -> Location {
    file_only(path.display().to_string())
}

/// A location naming only a file.
pub fn file_only(file: String) -> Location {
    Location {
        file,
        ..Default::default()
    }
}
