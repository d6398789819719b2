//! # vibro-replay: recording the live streams, and replaying logs into them
//!
//! The bridge between the iceoryx2 streams of a running system (`vibro-ipc`) and MCAP
//! files (`vibro-mcap`), as a library under the `vibrocomp record` and `vibrocomp
//! replay` commands:
//!
//! - [`record()`]: subscribes to the chosen streams under a prefix and writes every
//!   message into an MCAP file with `log_time` = when it was received, `publish_time`
//!   = the producer's `publish_ns`, `sequence` = the producer's `seq` (low 32 bits), so
//!   a gap in a channel's sequence is a loss. The MCAP writer runs on its own thread
//!   (zstd chunks, flushed at least every second); a full writer queue makes the
//!   recording loop wait, which back-pressures the publishers (bounded, counted) rather
//!   than dropping anything silently. On shutdown it drains what is queued and calls
//!   `finish()` itself.
//! - [`replay()`]: publishes the rig streams of a log (`/vib`, `/accel`, `/truth`) into
//!   the services, paced at a multiple of real time, or as fast as possible
//!   **lock-stepped** with the services: before switching from one input stream to the
//!   other it waits on the services' progress messages (`{prefix}progress/{service}`,
//!   docs/messages.md) until the consumer of the other stream has taken everything
//!   sent. The compensator then sees exactly the estimates of the vibration blocks that
//!   precede each accelerometer block in the log, whatever the machine's load: no
//!   sample is dropped and the outputs are bit-identical from run to run.
//!
//! Topics in a log are the stream names without the prefix (`/accel`, `/vib`,
//! `/estimate`, `/compensated`, `/truth`, `/heartbeat/estimator`, ...), so a log
//! replays under any prefix.
//!
//! ```no_run
//! use std::sync::atomic::AtomicBool;
//! use vibro_replay::{replay, Pace, ReplayOptions};
//! use vibro_msgs::ServiceNames;
//! # fn main() -> vibro_replay::Result<()> {
//! let stop = AtomicBool::new(false);
//! let options = ReplayOptions::new(ServiceNames::new("rig-a/")?, Pace::AsFastAsPossible);
//! let summary = replay("flight.mcap".as_ref(), &options, &stop, |_done, _total| {})?;
//! println!("{} messages, {:.0}x real time", summary.messages, summary.real_time_factor);
//! # Ok(())
//! # }
//! ```
//!
//! References: docs/services.md (streams, loss accounting), docs/messages.md (wire
//! types, progress messages, MCAP conventions), the MCAP specification (log time,
//! publish time, sequence).

mod record;
mod replay;
mod topics;

pub use record::{record, RecordOptions, RecordSummary, TopicCounts};
pub use replay::{replay, Pace, ReplayOptions, ReplaySummary};
pub use topics::{rig_streams, stream_of_topic, topic, DEFAULT_RECORD_STREAMS};

use std::path::PathBuf;

/// Errors of recording and replaying. Each names what it concerns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Ipc(#[from] vibro_ipc::Error),
    #[error(transparent)]
    Mcap(#[from] vibro_mcap::Error),
    #[error(transparent)]
    Names(#[from] vibro_msgs::Error),
    /// A topic that is not one of the system's streams, or not one this operation
    /// can publish.
    #[error("topic {topic:?}: {rule} (known: {known})")]
    Topic {
        topic: String,
        rule: &'static str,
        known: String,
    },
    /// An option out of range.
    #[error("{name} = {value}: {rule}")]
    Option {
        name: &'static str,
        value: String,
        rule: &'static str,
    },
    /// The log has nothing to replay.
    #[error("{path}: {what}")]
    Empty { path: PathBuf, what: String },
    /// Nobody subscribed to a stream the replay publishes.
    #[error("nobody subscribed to {stream} within {waited_s} s: start the services (vibrocomp up) with the same prefix")]
    NoSubscriber { stream: String, waited_s: f64 },
    /// A lock-stepped replay needs the progress messages of the service that consumes
    /// a stream.
    #[error("lock-stepped replay needs {service}'s progress messages on {stream}, and none came within {waited_s} s: is vibro-{service} running under this prefix? (Or replay with --rate, which does not wait for the consumers.)")]
    NoProgress {
        service: &'static str,
        stream: String,
        waited_s: f64,
    },
    /// A consumer stopped taking messages during a lock-stepped replay.
    #[error("lock-step: {service} has taken {taken} of the {sent} messages sent on {stream} and made no progress for {waited_s} s (did it stop or restart?)")]
    Stalled {
        service: &'static str,
        stream: String,
        taken: u64,
        sent: u64,
        waited_s: f64,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
