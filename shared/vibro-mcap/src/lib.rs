//! # vibro-mcap: recording vibrocomp streams in MCAP files
//!
//! The MCAP codec of vibrocomp: it knows the wire types of `vibro-msgs` and MCAP files,
//! and nothing about services. It provides
//!
//! - protobuf schemas for every wire type (`proto/vibrocomp/v1/*.proto`, package
//!   `vibrocomp.v1`), compiled at build time without `protoc` (`protox` + `prost-build`),
//!   and lossless conversions wire type <-> protobuf ([`Message`], [`proto`]);
//! - [`Recorder`]: a writer whose `write` only validates and copies the fixed-size wire
//!   struct into a bounded queue; its own thread encodes, compresses (zstd chunks) and
//!   writes, and closes the current chunk at least every `flush_interval_s`, so a crash
//!   loses about that much. A full queue is an error returned to the caller
//!   ([`Error::QueueFull`]), counted, and visible later as a sequence gap;
//! - [`Reader`]: messages of a finished file in log-time order, decoded into [`Message`],
//!   with every chunk's CRC checked;
//! - [`info`]: channels, counts, time span, sequence gaps, metadata and attachments;
//! - [`recover`]: a file left by a crash (no summary, a truncated last chunk) rewritten
//!   up to its last complete chunk.
//!
//! Every channel follows the Foxglove protobuf convention, so the files open in Foxglove
//! and decode with the Python `mcap` + `mcap-protobuf-support` packages
//! (`tests/python/mcap_check.py` does that in the tests).
//!
//! ## Example
//!
//! ```no_run
//! use vibro_mcap::{Reader, Recorder, RecorderOptions, Message};
//! use vibro_msgs::{AccelBlock, MessageKind};
//!
//! # fn main() -> vibro_mcap::Result<()> {
//! let mut recorder = Recorder::create("flight.mcap", RecorderOptions::default())?;
//! recorder.add_channel("/accel", MessageKind::AccelBlock)?;
//! recorder.add_attachment("triad.toml", "application/toml", b"[triad]\n".to_vec())?;
//!
//! let mut block = AccelBlock::ZEROED;
//! block.count = 1;
//! block.output_v[0] = [-1.6698, -1.6701, -1.6695];
//! recorder.write("/accel", 1_000_000, 1_000_000, 0, &block)?;
//! let summary = recorder.finish()?; // finish() reports the error that Drop would lose
//! assert_eq!(summary.messages, 1);
//!
//! for record in Reader::open("flight.mcap")? {
//!     let record = record?;
//!     if let Message::AccelBlock(b) = record.message {
//!         println!("{} {} {:?}", record.topic, record.log_time_ns, b.samples_v());
//!     }
//! }
//! # Ok(())
//! # }
//! ```
//!
//! ## References
//!
//! - MCAP format specification: <https://mcap.dev/spec> (records, chunks, CRCs, summary).
//! - Well-known encodings, protobuf: <https://mcap.dev/spec/registry#protobuf>; Foxglove's
//!   guide to protobuf schemas: <https://docs.foxglove.dev/docs/visualization/message-schemas/protobuf>.
//! - `docs/messages.md`: the wire types, their fields and units.

mod convert;
mod guard;
mod info;
mod reader;
mod recorder;
mod recover;
mod schema;

/// The Rust types generated from `proto/vibrocomp/v1/*.proto` by `prost-build`.
#[allow(clippy::all, clippy::pedantic, missing_docs, rustdoc::all)]
pub mod proto {
    // Generated code: lints are the generator's business.
    include!(concat!(env!("OUT_DIR"), "/vibrocomp.v1.rs"));
}

pub use convert::Message;
pub use info::{
    info, info_from_reader, AttachmentInfo, ChannelInfo, InputGap, LogInfo, MetadataInfo,
    MAX_LOST_MESSAGES,
};
pub use reader::{Reader, Record};
pub use recorder::{
    ChannelId, Compression, Recorder, RecorderOptions, RecorderStats, RecordingSummary,
};
pub use recover::{recover, recover_from_reader, Damage, RecoverReport};
pub use schema::{
    kind_of_schema, schema, Schema, MESSAGE_ENCODING, PROTO_PACKAGE, SCHEMA_ENCODING,
};

use std::path::PathBuf;
use std::sync::Arc;
use vibro_msgs::MessageKind;

/// Errors of the MCAP codec. Messages carry the values involved.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An I/O operation on a file failed.
    #[error("cannot {action} {path}: {source}")]
    Io {
        action: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A chunk's decompressed records do not match the CRC stored in its header.
    #[error("{path}: chunk CRC failed (expected {saved:08X}, got {calculated:08X})")]
    ChunkCrc {
        path: PathBuf,
        saved: u32,
        calculated: u32,
    },
    /// A record or chunk is malformed: a length beyond its record, a record beyond its
    /// chunk, a chunk too large or not decompressible (see `guard.rs`).
    #[error("{path}: {reason}")]
    Malformed { path: PathBuf, reason: String },
    /// The file ends in the middle of a record (a crash, or a copy in progress).
    #[error("{path}: file ends in the middle of a record; `vibro_mcap::recover` rewrites it up to its last complete chunk")]
    Truncated { path: PathBuf },
    /// The file has no footer: its writer stopped before finishing it (killed, out of
    /// disk), so its last record is cut short or its summary is missing. Found by
    /// [`info`]; the complete chunks before the cut can be recovered.
    #[error("{path}: unfinished MCAP file (no footer: the writer stopped before finishing it, e.g. killed or out of disk): {chunks} complete chunk(s) readable; `vibro_mcap::recover` keeps them")]
    Unfinished { path: PathBuf, chunks: u64 },
    /// The `mcap` library reported an error reading or writing a file.
    #[error("{path}: {source}")]
    Mcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    /// The file has no summary section or no chunk index, so it cannot be read in
    /// log-time order.
    #[error(
        "{path}: {what} (the file was not finished); `vibro_mcap::recover` rewrites it with one"
    )]
    NotFinished { path: PathBuf, what: &'static str },
    /// A message's counts exceed its arrays.
    #[error("invalid message: {0}")]
    Invalid(#[source] vibro_msgs::Error),
    /// A protobuf field has the wrong number of values.
    #[error("{message}.{field} has {len} values, expected {expected}")]
    FieldLength {
        message: MessageKind,
        field: &'static str,
        len: usize,
        expected: String,
    },
    /// A protobuf field's value does not fit the wire field.
    #[error("{message}.{field} = {value}: out of range (at most {max})")]
    ValueOutOfRange {
        message: MessageKind,
        field: &'static str,
        value: u64,
        max: u64,
    },
    /// Protobuf bytes could not be parsed.
    #[error("cannot decode a {kind} message: {reason}")]
    Decode { kind: MessageKind, reason: String },
    /// A message could not be serialised.
    #[error("cannot encode a {kind} message: {reason}")]
    Encode { kind: MessageKind, reason: String },
    /// A recorder option is out of range.
    #[error("recorder option {name} = {value}: {rule}")]
    InvalidOption {
        name: &'static str,
        value: String,
        rule: &'static str,
    },
    /// `write` named a topic that `add_channel` has not registered.
    #[error("topic {topic:?} is not registered (call add_channel first)")]
    UnknownTopic { topic: String },
    /// `add_channel` named a topic that is already registered with another type.
    #[error("topic {topic:?} is already registered for {existing}, cannot add it for {requested}")]
    TopicExists {
        topic: String,
        existing: MessageKind,
        requested: MessageKind,
    },
    /// `write` passed a message of another type than the channel's.
    #[error("topic {topic:?} carries {expected}, not {got}")]
    WrongMessageType {
        topic: Arc<str>,
        expected: MessageKind,
        got: MessageKind,
    },
    /// More channels than an MCAP file can hold.
    #[error("cannot add topic {topic:?}: all {max} channel IDs are used")]
    TooManyChannels { topic: String, max: u16 },
    /// The recorder's queue is full: the message was not recorded (see [`Recorder::write`]).
    #[error("recorder queue full ({capacity} messages waiting): {topic:?} sequence {sequence} not recorded")]
    QueueFull {
        topic: Arc<str>,
        sequence: u32,
        capacity: usize,
    },
    /// The recorder's writer thread has stopped after an error: `cause` is that error
    /// (the operating system's reason for a full disk), which `finish()` returns.
    #[error("recorder for {path} has stopped writing: {cause}")]
    RecorderStopped { path: PathBuf, cause: String },
    /// The recorder's writer thread panicked.
    #[error("recorder writer thread for {path} panicked")]
    WriterPanicked { path: PathBuf },
}

/// `Result` with this crate's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// Wraps an `mcap` error for `path`, giving CRC failures and truncation their own
    /// variants.
    pub(crate) fn mcap(path: &std::path::Path, source: mcap::McapError) -> Error {
        match source {
            mcap::McapError::BadChunkCrc { saved, calculated } => Error::ChunkCrc {
                path: path.to_path_buf(),
                saved,
                calculated,
            },
            mcap::McapError::UnexpectedEof => Error::Truncated {
                path: path.to_path_buf(),
            },
            source => Error::Mcap {
                path: path.to_path_buf(),
                source,
            },
        }
    }

    /// A chunk that [`guard::chunk`] refused.
    pub(crate) fn chunk(path: &std::path::Path, e: guard::ChunkError) -> Error {
        match e {
            guard::ChunkError::Crc { saved, calculated } => Error::ChunkCrc {
                path: path.to_path_buf(),
                saved,
                calculated,
            },
            guard::ChunkError::Invalid(reason) => Error::Malformed {
                path: path.to_path_buf(),
                reason,
            },
        }
    }

    pub(crate) fn io(
        action: &'static str,
        path: &std::path::Path,
        source: std::io::Error,
    ) -> Error {
        Error::Io {
            action,
            path: path.to_path_buf(),
            source,
        }
    }
}
