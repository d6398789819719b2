//! Plumbing shared by the vibrocomp services (the compensator reuses it): the clock,
//! the shutdown token, stream continuity, latency histograms, heartbeats, the
//! `[service]` configuration table, JSON summaries and the runtime of `main`.

mod cli;
mod clock;
mod continuity;
mod heartbeat;
mod json;
mod latency;
mod runtime;
mod settings;
mod shutdown;

pub use cli::ServiceArgs;
pub use clock::now_ns;
pub use continuity::{Arrival, Continuity, StreamCounters};
pub use heartbeat::{HeartbeatPublisher, HeartbeatReport};
pub use json::JsonObject;
pub use latency::{Latency, Quantiles};
pub use runtime::{init_tracing, run_service};
pub use settings::{
    check_prefix, check_seconds, data_stream_config, default_prefix, estimate_stream_config,
    parse_toml, read_config_file, ConfigError, ConfigSource, LoopMode, ServiceSettings,
    ServiceSettingsRaw,
};
pub use shutdown::Shutdown;

/// Counts an event and tells whether it is the first of its kind, so the hot loop logs
/// a problem once and leaves the rest to the periodic summary.
#[inline]
pub fn count_first(counter: &mut u64) -> bool {
    *counter += 1;
    *counter == 1
}
