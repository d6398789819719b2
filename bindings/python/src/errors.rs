//! Failures as Python exceptions: `vibrocomp.errors.VibrocompError` with the message,
//! the chain of causes, and the file, line, column and key of the command line's JSON
//! error object (README, "Conventions"; `vibro_lab::errors`), as the subclass a
//! caller would catch: `MissingFileError` (a `FileNotFoundError`), `ConfigError` (a
//! `ValueError`), ... (`vibrocomp/errors.py` lists them).

use pyo3::prelude::*;
use std::io::ErrorKind;

/// Where an error points (`vibro_toml::Location`'s fields: `file`, 1-based `line` and
/// `column`, the `key`'s dotted path).
type Where = (String, Option<usize>, Option<usize>, Option<String>);

/// The Python exception of `e`. When the exception class itself cannot be had (the
/// package's Python half missing), the import error says so instead.
pub fn to_py(e: &anyhow::Error) -> PyErr {
    let chain: Vec<String> = e.chain().map(ToString::to_string).collect();
    let location = location(e);
    let class = class_of(e, location.as_ref());
    let (file, line, column, key) = match location {
        Some((file, line, column, key)) => (Some(file), line, column, key),
        None => (None, None, None, None),
    };
    let message = message_of(&chain);
    Python::attach(|py| {
        let made = py
            .import("vibrocomp.errors")
            .and_then(|m| m.getattr(class))
            .and_then(|class| class.call1((message, chain, file, line, column, key)));
        match made {
            Ok(exception) => PyErr::from_value(exception),
            Err(import_failed) => import_failed,
        }
    })
}

/// `{e:#}` without a cause repeated: an error whose message already ends with its
/// source's (`"x.csv: No such file (os error 2)"` over the I/O error) is not followed
/// by it again.
fn message_of(chain: &[String]) -> String {
    let mut message = String::new();
    let mut last: Option<&str> = None;
    for cause in chain {
        if last.is_some_and(|l| l.ends_with(cause.as_str())) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(cause);
        last = Some(cause);
    }
    message
}

/// Where `e` points, as `vibrocomp ... --json` finds it: `vibro_lab::errors` (the
/// libraries' inputs and logs) and an archive's manifest.
pub fn location(e: &anyhow::Error) -> Option<Where> {
    e.chain().find_map(|cause| {
        let archive = cause.downcast_ref::<vibro_archive::Error>();
        archive
            .and_then(vibro_archive::Error::location)
            .or_else(|| vibro_lab::errors::cause_location(cause))
            .map(|l| (l.file, l.line, l.column, l.key))
    })
}

/// The name of the exception class of `e` in `vibrocomp.errors`: an operating system's
/// refusal by its kind, else by the library whose error it is.
fn class_of(e: &anyhow::Error, location: Option<&Where>) -> &'static str {
    for cause in e.chain() {
        if let Some(io) = cause.downcast_ref::<std::io::Error>() {
            match io.kind() {
                ErrorKind::NotFound => return "MissingFileError",
                ErrorKind::PermissionDenied => return "FilePermissionError",
                // Bytes that are not what was expected: the content is wrong, not
                // the file system.
                ErrorKind::InvalidData | ErrorKind::InvalidInput | ErrorKind::UnexpectedEof => {}
                _ => return "FileSystemError",
            }
        }
    }
    for cause in e.chain() {
        if cause.downcast_ref::<vibro_mcap::Error>().is_some() {
            return "LogFormatError";
        }
        if let Some(l) = cause.downcast_ref::<vibro_log::Error>() {
            use vibro_log::Error as L;
            match l {
                L::Mcap(_) | L::Empty { .. } | L::BadLog { .. } | L::Unfinished { .. } => {
                    return "LogFormatError"
                }
                L::Input { .. } | L::ReadInput { .. } => return "LogFormatError",
                _ => {}
            }
        }
        if cause.downcast_ref::<vibro_config::ConfigError>().is_some()
            || cause.downcast_ref::<vibro_service::ConfigError>().is_some()
        {
            return "ConfigError";
        }
        if let Some(x) = cause.downcast_ref::<vibro_effects::Error>() {
            return effects_class(x);
        }
        if let Some(x) = cause.downcast_ref::<vibro_lab::Error>() {
            use vibro_lab::Error as E;
            match x {
                E::Effects(x) => return effects_class(x),
                E::Config(_) => return "ConfigError",
                E::Table { .. } | E::Invalid(_) => return "InvalidInputError",
                E::Mcap(_) | E::Log(_) => return "LogFormatError",
                _ => {}
            }
        }
        if cause.downcast_ref::<vibro_physics::Error>().is_some() {
            return "InvalidInputError";
        }
    }
    // A key the command line points at: a configuration's (a TOML file's unknown key,
    // `vibro_toml::Error`, under another library's error); a line only: a file's content.
    match location {
        Some((_, _, _, Some(_))) => return "ConfigError",
        Some((_, Some(_), _, None)) => return "InvalidInputError",
        _ => {}
    }
    "VibrocompError"
}

/// The class of an effects library's error: a model file's or an effect's parameter's
/// problem is the configuration's; a prediction the physics cannot make is neither.
fn effects_class(e: &vibro_effects::Error) -> &'static str {
    use vibro_effects::Error as E;
    match e {
        E::Invalid { .. } | E::Several(_) | E::Model { .. } | E::Toml(_) => "ConfigError",
        E::Physics(_) => "InvalidInputError",
        _ => "VibrocompError",
    }
}

/// `anyhow::Result` into `PyResult`.
pub trait IntoPy<T> {
    fn py_err(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for anyhow::Result<T> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(|e| to_py(&e))
    }
}
