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
//! What happens to each block (validation, continuity, flags, the estimator, the
//! estimates' numbering) is [`InProcess`], the transport-free core: the service's hot
//! loop feeds it from `{prefix}vib`, offline users (the lab, replays) feed it
//! directly. The runtime it shares with the compensator (shutdown, heartbeats,
//! continuity, configuration loading, `main`) is `vibro-service`.
//!
//! ```no_run
//! use vibro_estimator::{run, Config};
//! use vibro_service::{ServiceConfig, Shutdown};
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

mod config;
#[cfg(feature = "ipc")]
mod service;

pub use config::{Config, RawConfig, DEFAULT_CONFIG_PATH};
#[cfg(feature = "ipc")]
pub use service::{run, run_async};
/// The transport-free core, shared with offline users (`shared/vibro-estimator-core`).
pub use vibro_estimator_core::{mirror_estimate, Counters, EstimateSink, InProcess, Summary};
