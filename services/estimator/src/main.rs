//! `vibro-estimator`: the estimator service (see the library's documentation).

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use vibro_estimator::{common, Config, LoopMode};

#[derive(Parser)]
#[command(
    name = "vibro-estimator",
    version,
    about = "Vibration estimates from the vibration-sensor stream"
)]
struct Args {
    /// Configuration file [default: config/services/estimator.toml, else the shipped copy].
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Service-name prefix, overriding the configuration's (e.g. `vibrocomp/`).
    #[arg(long, value_name = "PREFIX")]
    prefix: Option<String>,
    /// How the hot loop waits: `event` (WaitSet) or `spin` (busy-poll).
    #[arg(long, value_name = "event|spin")]
    mode: Option<LoopMode>,
    /// Print the final summary as JSON on stdout when stopping.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    common::init_tracing();
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vibro-estimator: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::load_default()?,
    };
    if let Some(prefix) = &args.prefix {
        config = config.with_prefix(prefix)?;
    }
    if let Some(mode) = args.mode {
        config.service.loop_mode = mode;
    }
    let summary = common::run_service(|shutdown| vibro_estimator::run_async(config, shutdown))?;
    if args.json {
        println!("{}", summary.to_json());
    }
    Ok(())
}
