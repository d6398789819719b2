//! The command line every service takes, shared by the standalone binaries
//! (`vibro-estimator`, `vibro-compensator`) and `vibrocomp service ...`, so a service
//! started either way behaves the same.

use crate::LoopMode;
use std::path::PathBuf;

/// `[--config FILE] [--prefix PREFIX] [--mode event|spin] [--realtime-priority N] [--json]`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ServiceArgs {
    /// Configuration file [default: config/services/<service>.toml if it exists, else
    /// the shipped copy].
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Service-name prefix, overriding the configuration's (e.g. `vibrocomp/`).
    #[arg(long, value_name = "PREFIX")]
    pub prefix: Option<String>,
    /// How the hot loop waits: `event` (WaitSet) or `spin` (busy-poll).
    #[arg(long, value_name = "event|spin")]
    pub mode: Option<LoopMode>,
    /// Run the hot loop under SCHED_FIFO at this priority (1..=99), overriding
    /// `[service] realtime_priority`; needs CAP_SYS_NICE or `ulimit -r`.
    #[arg(long, value_name = "1..99", value_parser = clap::value_parser!(u8).range(1..=99))]
    pub realtime_priority: Option<u8>,
    /// Print the final summary as JSON on stdout when stopping.
    #[arg(long)]
    pub json: bool,
}
