//! The `vibrocomp` command line: parses arguments, validates them into ready-to-use
//! inputs, calls the libraries in `shared/`, and prints a table or `--json`.
//!
//! Each command lives in its own module under [`commands`]; `main.rs` only turns the
//! result into an exit code.

#[macro_use]
pub mod output;
pub mod commands;
pub mod files;
pub mod flags;

use clap::{Parser, Subcommand};
use std::ffi::OsString;
use std::process::ExitCode;

/// Removes the vibration error of navigation accelerometers, and helps find what the
/// error model is missing.
#[derive(Debug, Parser)]
#[command(name = "vibrocomp", version, about, long_about = None)]
pub struct Cli {
    /// Log lines at `error` only, no progress bars (every command).
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// More log lines: `-v` debug, `-vv` trace (every command; `RUST_LOG` otherwise).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// The main job: the simulated Cyclone-4 flight through the estimator and
    /// compensator processes, recorded, with the error before and after compensation.
    Demo(commands::demo::DemoArgs),
    /// The vibration-error model: VE components, compensation, model check.
    #[command(subcommand)]
    Model(commands::model::ModelCommand),
    /// Identify the VE components from shake-table test positions (MODEL.md section 9).
    #[command(subcommand)]
    Identify(commands::identify::IdentifyCommand),
    /// Allowed moduli of the passport coefficients for a VE budget (MODEL.md section 10).
    Require(commands::require::RequireArgs),
    /// The model lab: compare the VE model with a campaign, find the missing physical
    /// effect, fit it and add it to the model (docs/lab.md).
    #[command(subcommand)]
    Lab(commands::lab::LabCommand),
    /// A batch over an archive: every log with every model, every unit through the lab,
    /// resumable, into one Parquet table and a report (docs/archive.md).
    #[command(subcommand)]
    Archive(commands::archive::ArchiveCommand),
    /// Estimate vibration parameters (tones, band RMS, covariance) from a recorded stream.
    Estimate(commands::estimate::EstimateArgs),
    /// Simulate a rig: flights to MCAP or live over iceoryx2, shake-table campaigns to CSV.
    Sim(commands::sim::SimArgs),
    /// Inspect, repair, import and measure MCAP logs (`log errors`: the demo's error table).
    #[command(subcommand)]
    Log(commands::log::LogCommand),
    /// Start the estimator and compensator (and a recorder), restart them on a crash,
    /// stop them on Ctrl-C.
    Up(commands::up::UpArgs),
    /// Forward streams between this host's services and other hosts over Zenoh
    /// (docs/bridge.md).
    Bridge(commands::bridge::BridgeArgs),
    /// Record the live streams into an MCAP log.
    Record(commands::record::RecordArgs),
    /// Replay the rig streams of an MCAP log into the services.
    Replay(commands::replay::ReplayArgs),
    /// Watch a running system live in Foxglove (WebSocket, 127.0.0.1:8765 by default).
    View(commands::view::ViewArgs),
    /// Latency of each hop and end to end through the services, against bare iceoryx2
    /// and Unix sockets.
    Latency(commands::latency::LatencyArgs),
    /// The baselines' peers of `latency` (internal).
    #[command(subcommand, hide = true)]
    LatencyPeer(commands::latency::PeerCommand),
    /// Run one service in this process (what `up` and `demo` start as child processes).
    #[command(subcommand)]
    Service(commands::service::ServiceCommand),
}

/// Runs the command line with the given arguments and returns the process exit code:
/// 0 on success, 1 on a failed command (the error chain is printed on stderr),
/// 2 on bad usage (clap's own convention), 3 when `log recover` wrote its file but
/// lost part of the damaged one (`output::ExitStatus`).
pub fn main_with_args<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let args: Vec<T> = args.into_iter().collect();
    let json = args.iter().any(|a| a.clone().into() == "--json");
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            // clap prints help/version on stdout with exit 0, usage errors on stderr with 2.
            let _ = e.print();
            return ExitCode::from(e.exit_code().clamp(0, 255) as u8);
        }
    };
    output::set_verbosity(cli.quiet, cli.verbose);
    // A closed stdout (`vibrocomp ... | head -1`) is how the reader says it has seen
    // enough: every printing path returns `output::StdoutClosed`, ending quietly here.
    match run(cli).and_then(|()| output::flush_stdout()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if output::is_stdout_closed(&e) => ExitCode::SUCCESS,
        Err(e) if output::exit_status(&e).is_some() => {
            ExitCode::from(output::exit_status(&e).unwrap_or(1))
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            if json {
                // With --json, the failure as JSON too (on stdout, where the result
                // would have been): the whole message and each cause on its own.
                println!("{}", error_json(&e));
            }
            ExitCode::FAILURE
        }
    }
}

/// The JSON error object of `--json` (README, "Conventions"): the whole message, each
/// cause on its own, and where a file is concerned its `file`, and where known the
/// `line` (1-based) and `key` (dotted path) of the problem; those three are absent
/// when the error has none.
pub fn error_json(e: &anyhow::Error) -> serde_json::Value {
    let chain: Vec<String> = e.chain().map(ToString::to_string).collect();
    let mut error = serde_json::json!({
        "message": format!("{e:#}"),
        "chain": chain,
        "exit_code": 1,
    });
    if let Some(l) = error_location(e) {
        error["file"] = l.file.into();
        if let Some(line) = l.line {
            error["line"] = line.into();
        }
        if let Some(column) = l.column {
            error["column"] = column.into();
        }
        if let Some(key) = l.key {
            error["key"] = key.into();
        }
    }
    serde_json::json!({ "error": error })
}

/// The file, line and key of an error, from the first cause in its chain whose
/// library error type carries them: the libraries' inputs (`vibro_lab::errors`) and
/// the bridge's file.
pub fn error_location(e: &anyhow::Error) -> Option<vibro_toml::Location> {
    e.chain().find_map(|cause| {
        // The bridge's file: at load, or its socket directory found wrong at start.
        match cause.downcast_ref::<vibro_bridge::Error>() {
            Some(vibro_bridge::Error::Config(x)) => return Some(x.location()),
            Some(
                vibro_bridge::Error::Open { file, .. }
                | vibro_bridge::Error::ZenohConfig { file, .. },
            ) => return Some(vibro_lab::errors::file_only(file.clone())),
            _ => {}
        }
        let archive = cause.downcast_ref::<vibro_archive::Error>();
        if let Some(l) = archive.and_then(vibro_archive::Error::location) {
            return Some(l);
        }
        vibro_lab::errors::cause_location(cause)
    })
}

/// Dispatches a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Demo(args) => commands::demo::run(args),
        Command::Model(cmd) => commands::model::run(cmd),
        Command::Identify(cmd) => commands::identify::run(cmd),
        Command::Require(args) => commands::require::run(args),
        Command::Estimate(args) => commands::estimate::run(args),
        Command::Lab(cmd) => commands::lab::run(&cmd),
        Command::Archive(cmd) => commands::archive::run(&cmd),
        Command::Sim(args) => commands::sim::run(&args),
        Command::Log(cmd) => commands::log::run(cmd),
        Command::Service(cmd) => commands::service::run(&cmd),
        Command::Up(args) => commands::up::run(&args),
        Command::Latency(args) => commands::latency::run(&args),
        Command::LatencyPeer(cmd) => commands::latency::run_peer(&cmd),
        Command::Bridge(args) => commands::bridge::run(&args),
        Command::Record(args) => commands::record::run(&args),
        Command::Replay(args) => commands::replay::run(&args),
        Command::View(args) => commands::view::run(&args),
    }
}
