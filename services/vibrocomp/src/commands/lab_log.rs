//! The lab's options for an MCAP log input (`--triad`, `--estimator-config`, ...):
//! flags resolved into `vibro_lab::log_table::LogOptions`, the log read by the lab.

use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use vibro_lab::log_table::{LogOptions, LogTableSummary};
use vibro_lab::{CampaignTable, LabModel};
use vibro_service::ServiceConfig;

/// Options of the lab's commands that apply to an MCAP log.
#[derive(Debug, Args, Clone)]
pub struct LogArgs {
    /// With an MCAP log: the triad (a file, or `default`) whose geometry the log's units
    /// have, and its passports; passports the log carries (a simulator's log) win.
    #[arg(long, default_value = "default")]
    pub triad: String,
    /// With an MCAP log: the estimator's configuration (default: the shipped
    /// `config/services/estimator.toml`); the sensor rate, sensitivity and AC corner the
    /// log's metadata states win.
    #[arg(long)]
    pub estimator_config: Option<PathBuf>,
    /// With an MCAP log: contiguous batches per window for the measured VE's
    /// uncertainty (batch means).
    #[arg(long, default_value_t = 8)]
    pub batches: usize,
    /// With an MCAP log: windows over which a flight-acceleration component changes by
    /// more than this are left out (the model is evaluated at the window's mean, with
    /// the curvature over the window's aL3 in the uncertainty), g.
    #[arg(long, default_value_t = 1.0)]
    pub max_al_span_g: f64,
    /// With an MCAP log: most consecutive estimator windows pooled into one lab window
    /// (0: one per 60th of the log's windows, 1 to 10); a pool also ends where the
    /// windows' tones or bands differ or the flight acceleration spans more than
    /// `--max-al-span-g`.
    #[arg(long, default_value_t = 0)]
    pub pool_windows: usize,
}

impl LogArgs {
    /// The triad and the estimator's configuration the flags name, resolved.
    fn options(&self) -> anyhow::Result<LogOptions> {
        let triad = vibro_config::resolve_triad(&self.triad)
            .with_context(|| format!("--triad {}", self.triad))?;
        let estimator = match &self.estimator_config {
            Some(p) => vibro_estimator::Config::load(p)?,
            None => vibro_estimator::Config::shipped()?,
        }
        .estimator;
        Ok(LogOptions {
            triad,
            estimator,
            batches: self.batches,
            max_al_span_g: self.max_al_span_g,
            pool_windows: self.pool_windows,
        })
    }
}

/// Reads the log at `path` into the lab's table (`vibro_lab::log_table`).
pub fn table_from_log(
    path: &Path,
    model: &LabModel,
    args: &LogArgs,
) -> anyhow::Result<(CampaignTable, LogTableSummary)> {
    Ok(vibro_lab::log_table::table_from_log(
        path,
        model,
        &args.options()?,
    )?)
}
