//! `vibrocomp._vibrocomp`: the native half of the Python package `vibrocomp`
//! (bindings/python/python/vibrocomp). It calls the shared libraries, as the command
//! line does, and hands back numpy arrays and the command line's JSON; the Python half
//! turns those into dataclasses and DataFrames. No numerics of its own.
//!
//! - [`model`]: passports, triads, the VE and the compensation stages over arrays of
//!   conditions, the requirements (`vibro_physics`, `vibro_effects`).
//! - [`lab`]: compare, diagnose and add on tables, manifests and logs (`vibro_lab`).
//! - [`logs`]: an MCAP log read per stream into arrays (`vibro_mcap`, `vibro_log`).
//! - [`archive`]: an archive's batch, its journal here and its jobs as JSON for any
//!   process to run (`vibro_archive`).
//! - [`errors`]: every failure as `vibrocomp.errors.VibrocompError`, with the command
//!   line's message, file, line and key.

mod archive;
mod arrays;
mod errors;
mod lab;
mod logs;
mod model;

use pyo3::prelude::*;

#[pymodule]
fn _vibrocomp(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    model::register(m)?;
    lab::register(m)?;
    logs::register(m)?;
    archive::register(m)?;
    Ok(())
}
