//! # vibro-log: the log format of vibrocomp
//!
//! One home for what a vibrocomp log is and how it is made and used: MCAP files
//! (`vibro-mcap`) whose topics are the system's streams without the prefix, written
//! from the live streams (`vibro-ipc`), from the simulator or from CSV, and played
//! back into them. The library under `vibrocomp record`, `replay`, `sim --out`,
//! `log import`, `log errors` and `lab` on a log:
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
//! - [`import`]: rig data recorded as CSV into a log with the simulator's topics and
//!   wire types, every problem of the input reported at once before anything is
//!   written; the caller draws the progress ([`import::ImportProgress`]).
//! - [`rig`]: the rig packetizer, which cuts a producer's sample streams into wire
//!   blocks with continuous sequence numbers and sample indices (the simulator's
//!   chunks, handed over as slices).
//! - [`flight`]: a simulated flight (`vibro-sim`) into a log, live, or both, with each
//!   unit's mean error against the exact model: the one module that knows the
//!   simulator.
//! - [`inspect`]: a log's summary and the repair of a damaged log, each refusal with
//!   its reason and, for a damaged log, the command that recovers it.
//! - [`samples`]: a recorded vibration-sensor stream as CSV through the estimator
//!   (`vibro-dsp`) in blocks, and the frequency-response table it divides out.
//! - [`attachments`]: the names, writing and reading of every attachment and metadata
//!   record a log carries (passports, scenario, service configurations, effects, CSV
//!   headers), in one place; [`output`]: writing a file under a temporary name that
//!   replaces its destination only when complete.
//!
//! Bad input fails cleanly, naming the file and the problem. A log that is not MCAP,
//! not finished (a crash), empty, or whose rig topics carry other message types is
//! refused before anything is published ([`Error::BadLog`], [`Error::Empty`]); a log
//! with `/accel` but no `/vib` too, unless its topics are chosen explicitly; channels
//! with foreign schemas or topics are skipped and listed
//! ([`ReplaySummary::skipped_topics`]); a chunk found damaged part-way stops the replay
//! there ([`Error::DamagedPartWay`]). A recording whose file cannot be created or
//! written stops at once with the operating system's reason ([`Error::Output`]),
//! after releasing its subscribers. A CSV import lists every bad option
//! ([`Error::ImportOptions`]) and every bad row, by file, line, column, value and rule
//! ([`Error::CsvInput`]).
//!
//! A recorded session is measured against its reference by [`session::log_errors`]
//! (each compensation stage's error against what each unit should read: the
//! simulator's truth), the table `vibrocomp demo` and `vibrocomp log errors` print
//! ([`session::SessionErrors::write_table`]; numbers as people read them: [`text`]).
//!
//! Topics in a log are the stream names without the prefix (`/accel`, `/vib`,
//! `/estimate`, `/compensated`, `/truth`, `/heartbeat/estimator`, ...), so a log
//! replays under any prefix.
//!
//! ```no_run
//! use std::sync::atomic::AtomicBool;
//! use vibro_log::{replay, Pace, ReplayOptions};
//! use vibro_msgs::ServiceNames;
//! # fn main() -> vibro_log::Result<()> {
//! let stop = AtomicBool::new(false);
//! let options = ReplayOptions::new(ServiceNames::new("rig-a/")?, Pace::AsFastAsPossible);
//! let summary = replay("flight.mcap".as_ref(), &options, &stop, |_done, _total| {})?;
//! println!("{} messages, {:.0}x real time", summary.messages, summary.real_time_factor);
//!
//! // The passports a log carries, as TOML, by unit.
//! let mut reader = vibro_mcap::Reader::open("flight.mcap")?;
//! for p in vibro_log::attachments::read_passports(&mut reader)? {
//!     println!("unit {}: {} ({} bytes)", p.index, p.attachment, p.toml.len());
//! }
//! # Ok(())
//! # }
//! ```
//!
//! References: docs/logs.md (log info, recover, import, errors, attachments and metadata),
//! docs/services.md (streams, loss accounting), docs/messages.md (wire types, progress
//! messages, MCAP conventions), the MCAP specification (log time, publish time,
//! sequence).

pub mod attachments;
pub mod flight;
pub mod import;
pub mod inspect;
pub mod linear;
pub mod output;
#[cfg(feature = "ipc")]
mod record;
#[cfg(feature = "ipc")]
mod replay;
pub mod rig;
pub mod samples;
pub mod session;
pub mod text;
mod timeline;
mod topics;

#[cfg(feature = "ipc")]
pub use record::{record, RecordOptions, RecordSummary, TopicCounts};
#[cfg(feature = "ipc")]
pub use replay::{replay, Pace, ReplayOptions, ReplaySummary};
pub use timeline::{Placement, Timeline, MAX_TIMELINE_STEP_NS, TIMELINE_RESYNC_AFTER};
pub use topics::{rig_streams, stream_of_topic, topic, DEFAULT_RECORD_STREAMS};

use std::borrow::Cow;
use std::path::PathBuf;

/// Errors of recording, replaying, importing and reading logs. Each names what it
/// concerns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Ipc(#[from] vibro_ipc::Error),
    #[error(transparent)]
    Mcap(#[from] vibro_mcap::Error),
    #[error(transparent)]
    Names(#[from] vibro_msgs::Error),
    /// The simulator refused the scenario or failed while running it.
    #[error(transparent)]
    Sim(#[from] vibro_sim::Error),
    /// The simulator of a flight cannot be built.
    #[error("simulator")]
    Simulator(#[source] vibro_sim::Error),
    /// A passport a log carries that does not read (`session`): the message names
    /// the log and the attachment.
    #[error(transparent)]
    Passport(#[from] vibro_config::ConfigError),
    /// A passport that cannot be written as TOML into a flight log.
    #[error("passport as TOML")]
    PassportToml(#[source] toml::ser::Error),
    /// A service-name prefix that makes no valid service names.
    #[error("--prefix {prefix:?}")]
    Prefix {
        prefix: String,
        #[source]
        source: vibro_msgs::Error,
    },
    /// The iceoryx2 node of the live publishers cannot be created.
    #[error("iceoryx2 node")]
    Node(#[source] vibro_ipc::Error),
    /// A flight stopped by a signal; its log, if any, is finished (`log` says so,
    /// starting with "; ").
    #[error(
        "interrupted by {signal} at simulated time {reached_s:.3} s of {duration_s:.3} s{log}"
    )]
    Interrupted {
        signal: &'static str,
        reached_s: f64,
        duration_s: f64,
        log: String,
    },
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
        rule: Cow<'static, str>,
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
    /// Another process already publishes a stream a lock-stepped replay would feed:
    /// the services would take both feeders' blocks as one stream, and the lock-step
    /// would count the other's messages as this replay's.
    #[error("another process already publishes on {stream} (pid {pids}): a replay needs to be the only feeder of the services' inputs; wait for it to finish, or replay into another prefix")]
    SecondFeeder { stream: String, pids: String },
    /// A consumer's process went away during a replay (stopped, killed, or, in a
    /// lock-stepped replay, restarted).
    #[error("{service} (pid {pids}) is gone ({how}): it has taken {taken} of the {sent} messages sent on {stream}; {unprocessed} not processed")]
    Vanished {
        service: &'static str,
        pids: String,
        stream: String,
        how: String,
        taken: u64,
        sent: u64,
        unprocessed: u64,
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
    /// The options of an import, every problem at once.
    #[error("log import options:\n  {}", .problems.join("\n  "))]
    ImportOptions { problems: Vec<String> },
    /// Problems in the CSV input of an import, every one at once (up to
    /// [`import::MAX_PROBLEMS`] per file), each naming the file, line, column, value
    /// and rule. Nothing was written.
    #[error("{} problem(s) in the CSV input, nothing written:\n  {}", .problems.len(), .problems.join("\n  "))]
    CsvInput { problems: Vec<String> },
    /// Problems with a rig's reference in an import (the stream's file, a reference
    /// that does not cover the readings), every one at once.
    #[error("the rig's reference, nothing written:\n  {}", .problems.join("\n  "))]
    Reference { problems: Vec<String> },
    /// Problems in a CSV file read by [`import::read_csv_blocks`].
    #[error("problem(s) in the CSV input:\n  {}", .problems.join("\n  "))]
    CsvBlocks { problems: Vec<String> },
    /// An input file that cannot be opened or read.
    #[error("{path}: {action}")]
    ReadInput {
        path: PathBuf,
        /// What failed: "cannot open", "cannot read line 12".
        action: String,
        source: std::io::Error,
    },
    /// A line longer than the cap of [`import::LineReader`]: the file is not a CSV file
    /// of rows (a binary file, `/dev/zero`, a never-ending line). Reading stops there.
    #[error("{path} line {line}: longer than {cap} bytes, the cap on a line (a row of a CSV file read here is under 200 bytes): is it a CSV file? It starts \"{head}\"")]
    LineTooLong {
        path: PathBuf,
        line: u64,
        cap: usize,
        /// Its first bytes, escaped.
        head: String,
    },
    /// A log whose writer stopped before finishing it (no footer); `keep` says what
    /// `vibrocomp log recover` keeps.
    #[error("{path} is damaged: unfinished MCAP file (no footer: the writer stopped before finishing it, e.g. killed or out of disk): {keep}")]
    Unfinished { path: PathBuf, keep: String },
    /// A log that cannot be read or repaired: `context` names it (and, when damaged,
    /// the command that recovers it).
    #[error("{context}")]
    ReadLog {
        context: String,
        source: vibro_mcap::Error,
    },
    /// The log given to `recover` is not an MCAP log at all.
    #[error("the damaged log to recover")]
    RecoverInput(#[source] Box<Error>),
    /// A repaired log that cannot be read back.
    #[error("reading back the recovered log")]
    ReadBack(#[source] Box<Error>),
    /// A block of a recorded stream the estimator refused.
    #[error("{path}: estimating the block from data row {first_row}")]
    Estimate {
        path: PathBuf,
        first_row: u64,
        source: vibro_dsp::Error,
    },
    /// An input file that cannot be imported as a whole.
    #[error("{path}: {problem}")]
    Input { path: PathBuf, problem: String },
    /// An output refused by the file rule (README, "Files"), or that cannot be
    /// written ([`vibro_files`]).
    #[error(transparent)]
    Files(#[from] vibro_files::Error),
    /// A log that cannot be created.
    #[error("{path}: cannot create the log")]
    CreateLog {
        path: PathBuf,
        source: vibro_mcap::Error,
    },
    /// A message that cannot be written into a log.
    #[error("writing {topic} to the log")]
    WriteLog {
        topic: String,
        source: vibro_mcap::Error,
    },
    /// A log that cannot be finished.
    #[error("finishing the log")]
    FinishLog(#[source] vibro_mcap::Error),
    /// An attachment that should be text and is not.
    #[error("attachment {name}: not UTF-8 text")]
    AttachmentText {
        name: String,
        source: std::string::FromUtf8Error,
    },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// The file the error is about, where it names one (for the front ends' `file`
    /// field); an MCAP error's own file where it wraps one.
    pub fn file(&self) -> Option<&std::path::Path> {
        match self {
            Error::Empty { path, .. }
            | Error::BadLog { path, .. }
            | Error::DamagedPartWay { path, .. }
            | Error::Output { path, .. }
            | Error::ReadInput { path, .. }
            | Error::LineTooLong { path, .. }
            | Error::Unfinished { path, .. }
            | Error::Estimate { path, .. }
            | Error::Input { path, .. }
            | Error::CreateLog { path, .. } => Some(path),
            Error::Mcap(e) | Error::ReadLog { source: e, .. } | Error::FinishLog(e) => e.file(),
            Error::RecoverInput(e) | Error::ReadBack(e) => e.file(),
            _ => None,
        }
    }
}

#[cfg(feature = "ipc")]
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

/// A number rounded to 10 significant digits, shortest form: a measured rate of
/// 999.9999999999998 Hz reads 1000.
pub(crate) fn fmt_sig(x: f64) -> String {
    format!("{x:.9e}")
        .parse::<f64>()
        .map_or_else(|_| x.to_string(), |r| r.to_string())
}

#[cfg(feature = "ipc")]
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
/// For the tests: a file named like `name` holding `bytes`, removed when dropped.
pub(crate) fn test_file(name: &str, bytes: &[u8]) -> tempfile::TempPath {
    let name = std::path::Path::new(name);
    let mut f = tempfile::Builder::new()
        .prefix(&name.file_stem().unwrap_or_default())
        .suffix(
            &name
                .extension()
                .map_or(String::new(), |e| format!(".{}", e.to_string_lossy())),
        )
        .tempfile()
        .unwrap();
    std::io::Write::write_all(&mut f, bytes).unwrap();
    f.into_temp_path()
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
