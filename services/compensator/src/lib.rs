//! # vibro-compensator
//!
//! The compensator service: the in-flight compensation algorithm of MODEL.md section 7
//! ([P2 (17)-(20)]) on the live streams. It subscribes to the accelerometer blocks
//! (`{prefix}accel`, [`vibro_msgs::AccelBlock`]) and the vibration estimates
//! (`{prefix}estimate`, [`vibro_msgs::VibEstimate`]), and publishes one
//! [`vibro_msgs::CompensatedBlock`] per input block on `{prefix}compensated` with every
//! stage `a(1)..a(4)`, the corrections, the mode and the estimate's age, plus a
//! heartbeat on `{prefix}heartbeat/compensator`.
//!
//! - Readings are `U / K1` per unit (each unit's passport), compensated per sample by
//!   [`vibro_physics::compensation::TriadCompensator::compensate`] (the tracking stream
//!   kernel).
//! - The vibration is the latest estimate's, mapped from the sensors to each unit's
//!   axes ([`mapping`]) and given to the compensator once per estimate. An estimate
//!   whose window ended more than `max_estimate_age_s` before a block's last sample is
//!   stale: that block is compensated for the main error only and flagged, as are
//!   blocks before the first estimate and blocks the estimate is dated more than
//!   `max_estimate_lead_s` ahead of (`ESTIMATE_AHEAD`: the streams' clocks disagree).
//! - Bad input is flagged on the block concerned and never stops the service: lost
//!   data (`INPUT_GAP`), non-finite readings, a producer's `SATURATED` block
//!   (`INPUT_SATURATED`), a timestamp off the stream's timing by more than half a
//!   sample period (`TIME_JUMP`), a new `sample_period_ns` (`RATE_CHANGE`: the
//!   estimate is mapped to the new output interval, the kernel starts afresh).
//! - The model files are reloaded while running (a tokio task polls them).
//! - **The waveform stage** (`stage = "waveform"`, the default; MODEL.md section 12,
//!   `vibro_waveform`): the compensator also subscribes to `{prefix}vib`, holds each
//!   accelerometer block until the sensors' samples cover its readings, and solves
//!   each reading for its interval-mean acceleration (flag `WAVEFORM`); blocks the
//!   samples do not cover in time get the estimate stage's answer, made on arrival
//!   (flag `WAVEFORM_FALLBACK`) ([`waveform`]).
//!
//! ```no_run
//! use vibro_compensator::{run, Config};
//! use vibro_service::{ServiceConfig, Shutdown};
//! # fn main() -> anyhow::Result<()> {
//! let config = Config::load(std::path::Path::new("config/services/compensator.toml"))?;
//! let shutdown = Shutdown::new();
//! let summary = run(config, shutdown)?; // until shutdown.trigger() from elsewhere
//! println!("{}", summary.to_json());
//! # Ok(())
//! # }
//! ```
//!
//! References: MODEL.md sections 3 and 7, RIG.md (the accelerometer block),
//! `docs/services.md` (streams, flags, staleness, loss accounting, hot reload).

// Without the feature `ipc` (the Python package's build) the service is left out, and
// what only it uses (the model reload, a few accessors) with it.
#![cfg_attr(not(feature = "ipc"), allow(dead_code))]
// Per-axis and per-unit index loops mirror the formulas' subscripts (and index several
// arrays at once); iterator chains would hide the indices.
#![allow(clippy::needless_range_loop)]

mod config;
mod core;
#[cfg(feature = "ipc")]
mod reload;
#[cfg(feature = "ipc")]
mod service;
pub mod waveform;

pub use self::core::{InProcess, OutputSink, Summary, MAX_ABS_READING_G};
pub use config::{
    wire_mode, Config, EstimateMappingRaw, Model, RawConfig, SensorsRaw, Stage, WaveformSettings,
    DEFAULT_CONFIG_PATH,
};
pub use mapping::{unit_vibrations, EstimateMapping, KurtosisUse, MappingError, UnitVibrations};
#[cfg(feature = "ipc")]
pub use service::{run, run_async};
/// From an estimate to each unit's vibration, shared with the lab (`vibro_effects`).
pub use vibro_effects::{interval, mapping, spectrum};
