//! `vibro-compensator`: the compensator service (see the library's documentation).

use clap::Parser;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "vibro-compensator",
    version,
    about = "Vibration-error compensation of the accelerometer stream"
)]
struct Args {
    #[command(flatten)]
    service: vibro_compensator::ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    vibro_estimator::common::init_tracing();
    match vibro_compensator::main_with(&args.service) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vibro-compensator: {e:#}");
            ExitCode::FAILURE
        }
    }
}
