//! # vibro-estimator
//!
//! The estimator service: it subscribes to the vibration-sensor blocks
//! (`{prefix}vib`, [`vibro_msgs::VibBlock`]), runs [`vibro_dsp::Estimator`] on them and
//! publishes one [`vibro_msgs::VibEstimate`] per window on `{prefix}estimate` (history
//! 1, so a late compensator gets the latest), plus a heartbeat on
//! `{prefix}heartbeat/estimator`.
//!
//! The receive → estimate → publish loop runs on its own thread and never awaits
//! (iceoryx2 has no async API); tokio owns signals and supervision. Every input gap
//! (by `seq` and by `first_sample_index`) is counted; the estimates it affects carry
//! the estimator's `GAP` flag. A block whose `sample_period_ns` disagrees with the
//! configured `sample_rate_hz` is kept out (its samples become a gap) and the estimates
//! whose windows overlap it carry `RATE_MISMATCH`; an empty block only advances `seq`.
//!
//! The crate also holds [`common`], the plumbing the compensator shares.
//!
//! ```no_run
//! use vibro_estimator::{common::Shutdown, run, Config};
//! # fn main() -> anyhow::Result<()> {
//! let config = Config::shipped()?.with_prefix("rig-a/")?;
//! let shutdown = Shutdown::new();
//! let stopper = shutdown.clone();
//! std::thread::spawn(move || {
//!     std::thread::sleep(std::time::Duration::from_secs(5));
//!     stopper.trigger();
//! });
//! let summary = run(config, shutdown)?;
//! println!("{}", summary.to_json());
//! # Ok(())
//! # }
//! ```
//!
//! References: `docs/services.md` (streams, flags, loss accounting), `docs/estimation.md`
//! (the estimator), MODEL.md section 7 (what the compensator does with the estimates).

pub mod common;
mod config;
mod service;

pub use common::{LoopMode, ServiceArgs, Shutdown};
pub use config::{Config, RawConfig, DEFAULT_CONFIG_PATH};
pub use service::{mirror_estimate, run, run_async, Summary};

/// What `vibro-estimator` and `vibrocomp service estimator` do: load the configuration
/// (file, prefix and loop-mode overrides), run until SIGINT/SIGTERM, print the JSON
/// summary with `--json`.
pub fn main_with(args: &common::ServiceArgs) -> anyhow::Result<()> {
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
    let summary = common::run_service(|shutdown| run_async(config, shutdown))?;
    if args.json {
        println!("{}", summary.to_json());
    }
    Ok(())
}
