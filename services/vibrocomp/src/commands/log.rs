//! `vibrocomp log`: inspect, repair, import and measure MCAP logs (docs/logs.md).
//!
//! - `info` summarises a log with `vibro_log::inspect::read_info`: channels, counts,
//!   time span, sequence losses, metadata and attachments.
//! - `recover` rewrites a log left by a crash up to its last complete chunk
//!   (`vibro_log::inspect::recover_log`) and says what was kept and what was lost.
//! - `import` (module [`import`]) turns rig data recorded as CSV into a log with the
//!   simulator's topics and wire types, so that it replays like a simulated flight
//!   (`vibro_log::import`).
//! - `errors` (module [`errors`]) measures a recorded session against its reference:
//!   the stage-error table of `vibrocomp demo` (`vibro_log::session`).
//! - `compensate` (module [`compensate`]) runs a log through the estimator's and the
//!   compensator's cores in-process into a session log (`vibro_offline`).

mod compensate;
mod errors;
mod import;

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use vibro_log::inspect::{read_info, recover_log};

use crate::output::print_json;
pub use compensate::CompensateArgs;
pub use errors::ErrorsArgs;
pub use import::ImportArgs;

/// Inspect, repair, import and measure MCAP logs.
#[derive(Debug, Subcommand)]
pub enum LogCommand {
    /// Channels, message counts, time span, sequence losses, metadata and attachments.
    Info(InfoArgs),
    /// Rewrite a log left by a crash up to its last complete chunk.
    Recover(RecoverArgs),
    /// Turn rig data recorded as CSV into a log with the simulator's topics and types.
    Import(ImportArgs),
    /// Each compensation stage's error in a recorded session against its reference
    /// (the simulator's truth), mean over windows: the table `demo` prints.
    Errors(ErrorsArgs),
    /// A log through the estimator's and the compensator's cores in-process (no
    /// services): the session a lock-stepped replay through the services records.
    Compensate(CompensateArgs),
}

pub fn run(cmd: LogCommand) -> anyhow::Result<()> {
    match cmd {
        LogCommand::Info(args) => info(&args),
        LogCommand::Recover(args) => recover(&args),
        LogCommand::Import(args) => import::run(&args),
        LogCommand::Errors(args) => errors::run(&args),
        LogCommand::Compensate(args) => compensate::run(&args),
    }
}

// ---------------------------------------------------------------------------------
// Shared helpers

/// A number rounded to 10 significant digits, shortest form: a measured rate of
/// 999.9999999999998 Hz reads 1000.
fn fmt_sig(x: f64) -> String {
    format!("{x:.9e}")
        .parse::<f64>()
        .map_or_else(|_| x.to_string(), |r| r.to_string())
}

/// Prints what `write` produced on stdout; a closed pipe (`| head`) ends it quietly.
fn print_text(write: impl FnOnce(&mut String) -> std::fmt::Result) -> anyhow::Result<()> {
    let mut text = String::new();
    write(&mut text).context("formatting the output")?;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("writing to stdout"),
    }
}

// ---------------------------------------------------------------------------------
// log info

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The MCAP log.
    pub file: PathBuf,
    /// Print the summary as JSON (`vibro_mcap::LogInfo`).
    #[arg(long)]
    pub json: bool,
}

fn info(args: &InfoArgs) -> anyhow::Result<()> {
    let info = read_info(&args.file)?;
    if args.json {
        return print_json(&info);
    }
    print_text(|out| info.write_text(out))
}

// ---------------------------------------------------------------------------------
// log recover

#[derive(Debug, Args)]
pub struct RecoverArgs {
    /// The damaged log (a crash: no summary, a truncated last chunk).
    pub damaged: PathBuf,
    /// Where to write the repaired log (not DAMAGED itself).
    pub out: PathBuf,
    /// Overwrite OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

fn recover(args: &RecoverArgs) -> anyhow::Result<()> {
    let output = recover_log(&args.damaged, &args.out, args.force)?;
    if args.json {
        print_json(&output)?;
    } else {
        print_text(|out| output.write_text(out))?;
    }
    // Written, but with losses: its own exit status (docs/logs.md), after the report.
    match output.exit_code {
        0 => Ok(()),
        code => Err(crate::output::ExitStatus(code).into()),
    }
}
