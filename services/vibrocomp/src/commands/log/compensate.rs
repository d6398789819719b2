//! `vibrocomp log compensate LOG --out SESSION.mcap`: the log through the estimator's
//! and the compensator's cores in-process, no service and no shared memory, into the
//! session a lock-stepped replay through the services records (docs/logs.md). The run
//! and its summary are `vibro_offline`; this is its command line.

use std::path::PathBuf;

use clap::Args;
use vibro_offline::{compensate_log, OutputOptions, Setup};

use super::print_text;
use crate::output::print_json;

#[derive(Debug, Args)]
pub struct CompensateArgs {
    /// The log: a simulated flight (`sim --out`) or an imported rig log.
    pub log: PathBuf,
    /// The session log to write (`log errors` measures it).
    #[arg(long, value_name = "SESSION.mcap")]
    pub out: PathBuf,
    /// An extended model (`vibrocomp lab add --out`), as `up --model` gives it.
    #[arg(long, value_name = "MODEL.toml")]
    pub model: Option<PathBuf>,
    /// A rig file: its vibration-sensor chain, as `up --rig` gives it to both services.
    #[arg(long, value_name = "RIG.toml")]
    pub rig: Option<PathBuf>,
    /// The estimator's configuration [default: the services' rule].
    #[arg(long, value_name = "FILE")]
    pub estimator_config: Option<PathBuf>,
    /// The compensator's configuration [default: the services' rule].
    #[arg(long, value_name = "FILE")]
    pub compensator_config: Option<PathBuf>,
    /// Write the wire streams only, without the view channels (`/view/...`).
    #[arg(long)]
    pub no_view: bool,
    /// Write uncompressed chunks (larger, less CPU) instead of zstd.
    #[arg(long)]
    pub no_compression: bool,
    /// Write every record, instead of copying the log's chunks as they are (still
    /// compressed) where their records are what the session holds. The same messages
    /// either way.
    #[arg(long)]
    pub no_chunk_copy: bool,
    /// Overwrite OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub(super) fn run(args: &CompensateArgs) -> anyhow::Result<()> {
    let setup = Setup::derive(
        args.estimator_config.as_deref(),
        args.compensator_config.as_deref(),
        args.rig.as_deref(),
        args.model.as_deref(),
    )?;
    let options = OutputOptions {
        force: args.force,
        view: !args.no_view,
        compress: !args.no_compression,
        copy_chunks: !args.no_chunk_copy,
    };
    // Ctrl-C or SIGTERM stops the run between messages; nothing is written then.
    let signal = vibro_service::StopSignal::install();
    let bar = crate::commands::replay::progress_bar("compensating");
    let (log, out, stop) = (&args.log, &args.out, || signal.caught());
    let summary = compensate_log(log, &setup, out, &options, &stop, &mut |n, of| {
        bar.set_length(of);
        bar.set_position(n);
    });
    bar.finish_and_clear();
    let summary = summary?;
    if args.json {
        return print_json(&summary);
    }
    print_text(|out| summary.write_text(out))
}
