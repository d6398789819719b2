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
    service: vibro_service::ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    vibro_service::init_tracing();
    match vibro_service::main_with(&args.service, vibro_estimator::run_async) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vibro-estimator: {e:#}");
            ExitCode::FAILURE
        }
    }
}
