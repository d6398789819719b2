//! `vibro-estimator`: the estimator service (see the library's documentation).

use clap::Parser;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "vibro-estimator",
    version,
    about = "Vibration estimates from the vibration-sensor stream"
)]
struct Args {
    #[command(flatten)]
    service: vibro_estimator::ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    vibro_estimator::common::init_tracing();
    match vibro_estimator::main_with(&args.service) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vibro-estimator: {e:#}");
            ExitCode::FAILURE
        }
    }
}
