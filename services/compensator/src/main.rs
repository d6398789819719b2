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
    service: vibro_service::ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    vibro_service::init_tracing();
    match vibro_service::main_with(&args.service, vibro_compensator::run_async) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vibro-compensator: {e:#}");
            ExitCode::FAILURE
        }
    }
}
