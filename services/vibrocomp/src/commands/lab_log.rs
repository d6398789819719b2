//! The lab's options for an MCAP log input (`--triad`, `--estimator-config`, ...):
//! flags resolved into `vibro_lab::log_table::LogOptions`, the log read by the lab; and
//! a shake-table campaign's manifest measured into the lab's table.

use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use vibro_lab::log_table::LogOptions;
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
    /// Write the table the inputs make (a shake-table manifest measured, tables joined)
    /// as the lab's CSV (docs/lab.md), to read back or edit; refused for a table a CSV
    /// row cannot hold (a log's windows: several tones, a spectrum of bands) and for an
    /// existing file. Nothing is written when the command fails before the table exists.
    #[arg(long, value_name = "CSV")]
    pub table_out: Option<PathBuf>,
}

impl LogArgs {
    /// The estimator's configuration `--estimator-config` names (default the shipped one).
    pub fn estimator(&self) -> anyhow::Result<vibro_dsp::EstimatorConfig> {
        Ok(match &self.estimator_config {
            Some(p) => vibro_estimator::Config::load(p)?,
            None => vibro_estimator::Config::shipped()?,
        }
        .estimator)
    }

    /// The triad and the estimator's configuration the flags name, resolved.
    pub fn options(&self) -> anyhow::Result<LogOptions> {
        let triad = vibro_config::resolve_triad(&self.triad)
            .with_context(|| format!("--triad {}", self.triad))?;
        let estimator = self.estimator()?;
        Ok(LogOptions {
            triad,
            estimator,
            batches: self.batches,
            max_al_span_g: self.max_al_span_g,
            pool_windows: self.pool_windows,
        })
    }
}

/// Measures the shake-table campaign a manifest lists into the lab's table
/// (`vibro_lab::campaign`), with a progress bar over its runs on a terminal.
pub fn table_from_manifest(
    path: &Path,
    estimator: &vibro_dsp::EstimatorConfig,
) -> anyhow::Result<vibro_lab::campaign::CampaignResult> {
    let manifest = vibro_lab::campaign::Manifest::load(path)?;
    let bar = crate::output::progress_bar(
        manifest.runs.len() as u64,
        "measuring runs {bar:30} {pos}/{len} (reference, VE, estimator)",
    );
    let result = vibro_lab::campaign::measure_campaign(&manifest, estimator, &mut |done, _| {
        bar.set_position(done as u64)
    });
    bar.finish_and_clear();
    Ok(result?)
}
