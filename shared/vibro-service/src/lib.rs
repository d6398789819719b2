//! # vibro-service
//!
//! The runtime every vibrocomp service shares, so that the estimator and the
//! compensator start, run, report and stop the same way:
//!
//! - the command line ([`ServiceArgs`]) and [`main_with`], what a service's `main`
//!   does (load the configuration, apply `--prefix` and `--mode`, run until
//!   SIGINT/SIGTERM, print the JSON summary with `--json`);
//! - the runtime of `main`: [`init_tracing`], [`run_service`] (a tokio runtime that
//!   turns SIGINT/SIGTERM into the [`Shutdown`] signal `run(config, shutdown)` takes);
//! - configuration: the [`ServiceConfig`] loader (a file, the default path, the copy
//!   compiled in, the `--prefix` override), [`ConfigError`] (file, key, value and rule,
//!   all problems at once), the `[service]` table ([`ServiceSettings`], [`LoopMode`]) and
//!   the streams' quality of service;
//! - what the hot loop keeps: the clock ([`now_ns`]), stream [`Continuity`] and its
//!   [`StreamCounters`] (the rule's home is `vibro_msgs::continuity`; the JSON of its
//!   totals is [`CountersJson`]), [`Latency`] histograms, [`HeartbeatPublisher`], [`count_first`]
//!   (log a problem once, count the rest), [`Recurring`] and [`DisorderLog`] (log a
//!   recurring problem, such as out-of-order messages, at once after a quiet period,
//!   then once per summary period with its count), and [`JsonObject`] for the
//!   summaries;
//! - [`realtime`]: the hot-loop thread under `SCHED_FIFO` when asked for;
//! - [`supervise`]: a system of services as child processes (stopped with their parent,
//!   watched until their heartbeats come, restarted within limits);
//! - with the `testing` feature, [`testing`]: a service running in-process for tests,
//!   and [`adversary`]: adversarial input sequences and what no consumer may do with
//!   them (silence a stream, count a jump as a loss).
//!
//! Nothing here allocates, logs or locks per sample: the hot loop keeps counters and
//! logs a summary per period.
//!
//! ```no_run
//! use vibro_service::{main_with, ServiceArgs, ServiceConfig, ServiceSummary, Shutdown};
//! # use vibro_service::{ConfigError, ConfigSource, ServiceSettings};
//! # use vibro_msgs::ServiceNames;
//! # #[derive(Clone)]
//! # struct MyConfig { names: ServiceNames, service: ServiceSettings }
//! # impl ServiceConfig for MyConfig {
//! #     const DEFAULT_CONFIG_PATH: &'static str = "config/services/mine.toml";
//! #     const EMBEDDED: &'static str = "";
//! #     fn parse(_: &str, _: ConfigSource) -> Result<Self, ConfigError> { unimplemented!() }
//! #     fn set_names(&mut self, names: ServiceNames) { self.names = names; }
//! #     fn service_mut(&mut self) -> &mut ServiceSettings { &mut self.service }
//! # }
//! # struct MySummary;
//! # impl ServiceSummary for MySummary { fn to_json(&self) -> String { "{}".into() } }
//! // The service's library: `run_async(config, shutdown)` runs until `shutdown`.
//! async fn run_async(config: MyConfig, shutdown: Shutdown) -> anyhow::Result<MySummary> {
//!     shutdown.triggered().await;
//!     Ok(MySummary)
//! }
//!
//! // Its `main`: parse the command line, then everything else is shared.
//! fn main() -> anyhow::Result<()> {
//!     vibro_service::init_tracing();
//!     let args = ServiceArgs { prefix: Some("rig-a/".into()), ..ServiceArgs::default() };
//!     main_with(&args, run_async)
//! }
//! ```
//!
//! References: `docs/services.md` (command line, signals and shutdown, heartbeats and
//! summaries, loss accounting), `docs/architecture.md` (where this crate sits).

/// Adversarial input sequences (`vibro_msgs::adversary`, with the `testing` feature).
#[cfg(feature = "testing")]
pub use vibro_msgs::adversary;
#[cfg(feature = "ipc")]
mod cli;
mod clock;
mod config;
mod continuity;
mod heartbeat;
mod json;
mod latency;
#[cfg(feature = "ipc")]
pub mod logstream;
pub mod realtime;
mod recurring;
#[cfg(feature = "ipc")]
mod runtime;
mod settings;
mod shutdown;
mod stop;
pub mod supervise;
#[cfg(all(feature = "testing", feature = "ipc"))]
pub mod testing;

#[cfg(feature = "ipc")]
pub use cli::ServiceArgs;
pub use clock::now_ns;
pub use config::ServiceConfig;
pub use continuity::{
    Arrival, Continuity, CountersJson, StreamCounters, MAX_LOST_MESSAGES, MAX_LOST_SAMPLES,
    RESYNC_AFTER,
};
#[cfg(feature = "ipc")]
pub use heartbeat::HeartbeatPublisher;
pub use heartbeat::HeartbeatReport;
pub use json::JsonObject;
pub use latency::{Latency, Quantiles};
pub use recurring::{DisorderLog, Recurring};
#[cfg(feature = "ipc")]
pub use runtime::{
    init_tracing, main_with, on_own_thread, run_service, ServiceSummary, SAME_REQUEST,
};
pub use settings::{
    check_prefix, check_seconds, data_stream_config, default_prefix, estimate_stream_config,
    parse_toml, read_config_file, ConfigError, ConfigSource, LoopMode, ServiceSettings,
    ServiceSettingsRaw,
};
pub use shutdown::Shutdown;
pub use stop::StopSignal;

/// Counts an event and tells whether it is the first of its kind, so the hot loop logs
/// a problem once and leaves the rest to the periodic summary.
#[inline]
pub fn count_first(counter: &mut u64) -> bool {
    *counter += 1;
    *counter == 1
}
