//! `vibrocomp service estimator|compensator`: runs one service in this process, exactly
//! as its standalone binary does. `vibrocomp up` and `vibrocomp demo` start the services
//! this way (as child processes of the one `vibrocomp` executable), so a fresh
//! `cargo run -p vibrocomp` has everything it needs.

use vibro_service::{init_tracing, main_with, ServiceArgs};

#[derive(Debug, clap::Subcommand)]
pub enum ServiceCommand {
    /// The estimator: `{prefix}vib` in, `{prefix}estimate` out (docs/services.md).
    Estimator(ServiceArgs),
    /// The compensator: `{prefix}accel` + `{prefix}estimate` in, `{prefix}compensated` out.
    Compensator(ServiceArgs),
}

pub fn run(cmd: &ServiceCommand) -> anyhow::Result<()> {
    init_tracing();
    match cmd {
        ServiceCommand::Estimator(args) => main_with(args, vibro_estimator::run_async),
        ServiceCommand::Compensator(args) => main_with(args, vibro_compensator::run_async),
    }
}
