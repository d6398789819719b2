//! Failures as Python exceptions: `vibrocomp.errors.VibrocompError` with the message,
//! the chain of causes, and the file, line, column and key of the command line's JSON
//! error object (README, "Conventions"; `vibro_lab::errors`).

use pyo3::prelude::*;
use std::error::Error as StdError;

/// The Python exception of `e`. When the exception class itself cannot be had (the
/// package's Python half missing), the import error says so instead.
pub fn to_py(e: &anyhow::Error) -> PyErr {
    let chain: Vec<String> = e.chain().map(ToString::to_string).collect();
    let location = vibro_lab::errors::location(e.chain().map(|c| c as &(dyn StdError + 'static)));
    let (file, line, column, key) = match location {
        Some(l) => (Some(l.file), l.line, l.column, l.key),
        None => (None, None, None, None),
    };
    let message = format!("{e:#}");
    Python::attach(|py| {
        let made = py
            .import("vibrocomp.errors")
            .and_then(|m| m.getattr("VibrocompError"))
            .and_then(|class| class.call1((message, chain, file, line, column, key)));
        match made {
            Ok(exception) => PyErr::from_value(exception),
            Err(import_failed) => import_failed,
        }
    })
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
