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
//!   sample is dropped and the outputs are bit-identical from run to run. It waits only
//!   where an estimate can come out: the estimator's progress messages say how many
//!   samples its window still needs (`Heartbeat::input_samples_to_output`), so the
//!   replay waits about twice per estimate instead of at every switch.
//!
//! Bad input fails cleanly, naming the file and the problem. A log that is not MCAP,
//! not finished (a crash), empty, or whose rig topics carry other message types is
//! refused before anything is published ([`Error::BadLog`], [`Error::Empty`]); a log
//! with `/accel` but no `/vib` too, unless its topics are chosen explicitly; channels
//! with foreign schemas or topics are skipped and listed
//! ([`ReplaySummary::skipped_topics`]); a chunk found damaged part-way stops the replay
//! there ([`Error::DamagedPartWay`]). A recording whose file cannot be created or
//! written stops at once with the operating system's reason ([`Error::Output`]),
//! after releasing its subscribers.
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
    /// The log cannot be replayed as it is: not an MCAP file, damaged, or its topics
    /// do not make a replay. Found before anything is published.
    #[error("{path}: {problem}")]
    BadLog { path: PathBuf, problem: String },
    /// The log turned out damaged part-way through: the replay stopped there.
    #[error("{path}: {problem}, after {published} messages had been published (log time {log_time_s:.3} s from the start); the replay stopped there{hint}")]
    DamagedPartWay {
        path: PathBuf,
        problem: String,
        published: u64,
        log_time_s: f64,
        /// What to do about it, if anything helps (starts with "; ").
        hint: String,
    },
    /// The recording cannot be written (a missing or read-only folder, a full disk).
    #[error("cannot {action} the recording {path}: {reason}{what_is_kept}")]
    Output {
        action: &'static str,
        path: PathBuf,
        /// The operating system's error, e.g. "No space left on device (os error 28)".
        reason: String,
        /// What the file keeps, if anything was written (starts with "; ").
        what_is_kept: String,
    },
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

/// An error and its sources in one line, each source added only where the text
/// before does not already end with it (`vibro_mcap` errors show their source in their
/// own message, `mcap`'s I/O error only in its source).
pub(crate) fn describe(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let part = s.to_string();
        if !text.ends_with(&part) {
            text.push_str(": ");
            text.push_str(&part);
        }
        source = s.source();
    }
    text
}

/// The operating system's error inside `e`, if any (the innermost one).
pub(crate) fn io_cause<'a>(e: &'a (dyn std::error::Error + 'static)) -> Option<&'a std::io::Error> {
    let mut found = None;
    let mut next: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(err) = next {
        if let Some(io) = err.downcast_ref::<std::io::Error>() {
            found = Some(io);
        }
        next = err.source();
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    /// vibro-mcap's I/O errors show their source in their message: it is not repeated.
    #[test]
    fn describe_adds_each_source_once_and_io_cause_finds_the_os_error() {
        let e = vibro_mcap::Error::Io {
            action: "create",
            path: PathBuf::from("/nowhere/x.mcap"),
            source: std::io::Error::from_raw_os_error(ENOENT),
        };
        let text = describe(&e);
        assert_eq!(
            text.matches("No such file or directory").count(),
            1,
            "{text}"
        );
        assert!(
            text.starts_with("cannot create /nowhere/x.mcap: "),
            "{text}"
        );
        let io = io_cause(&e).map(|io| io.raw_os_error());
        assert_eq!(io, Some(Some(ENOENT)));
    }

    /// "No such file or directory" on Linux.
    const ENOENT: i32 = 2;
}
