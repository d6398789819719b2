//! The recorder: a cheap `write` on the caller's thread, and a writer thread of its own
//! that owns the `mcap::Writer`.
//!
//! `write` looks the topic up, checks the message's type and counts, and copies the
//! fixed-size wire struct into a bounded queue (`std::sync::mpsc::sync_channel`, whose
//! slots are allocated once, up front): no heap allocation, no encoding, no I/O, and it
//! never blocks. When the queue is full it returns [`Error::QueueFull`] at once and counts
//! the rejection: a real-time caller must not be held up by a slow disk, and a silent drop
//! is never an option. The rejected message's `sequence` is then missing from the file,
//! which [`crate::info`] reports as a loss.
//!
//! The writer thread encodes each message as protobuf, writes it into a zstd chunk, and
//! closes the chunk (and flushes it to the operating system) no later than
//! `flush_interval_s` after the first message written into it, so a crash of the process
//! loses at most about that much: [`crate::recover`] restores everything up to the last
//! closed chunk. Control calls (`add_channel`, `add_attachment`, `add_metadata`) are
//! rare and must not be lost, so they wait for room in the queue instead.
//!
//! An offline run on one core (`log compensate`) has no real-time caller to protect
//! and pays for the hand-over between the two threads: with
//! [`RecorderOptions::writer_thread`] off, the same writer runs on the caller's thread
//! and writes the same file, byte for byte.
//!
//! Such a run can also copy its input's chunks into the file as they are, still
//! compressed, when the records it would write are the same bytes
//! ([`RecorderOptions::splice`], [`Recorder::copy_chunk`]): decoding a chunk is
//! needed to run it through the cores, compressing it again is not. The file is then
//! written by this crate's own writer (`splice.rs`) instead of `mcap`'s, which has no
//! way to take a chunk as it is.

use crate::schema::{schema, schema_id, ViewSchema, MESSAGE_ENCODING, SCHEMA_ENCODING};
use crate::splice::{CopiedChunk, SpliceOptions, SpliceWriter};
use crate::{Error, Message, Result};
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use vibro_msgs::MessageKind;

/// Chunk compression.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Compression {
    /// zstd (the default): the usual choice for MCAP, fast to decompress.
    Zstd,
    /// No compression (largest files, least CPU).
    None,
}

/// How a [`Recorder`] writes.
#[derive(Clone, Debug, PartialEq)]
pub struct RecorderOptions {
    /// Chunk compression (default zstd).
    pub compression: Compression,
    /// zstd's level, 1..=22 (default 1). On the recorded streams (f64 samples) level 1
    /// compresses as well as zstd's own default, 3 (x1.85 against x1.84 on a session of
    /// the 600 s flight), at 1.6 times its speed (407 against 249 MB/s on one core;
    /// BENCHMARKS.md): less CPU next to the real-time services, and the most of an
    /// offline run's time.
    pub zstd_level: u32,
    /// A chunk is closed once its uncompressed size exceeds this (default 1 MiB).
    pub chunk_size_bytes: u64,
    /// A chunk is closed and flushed at most this long after its first message
    /// (default 1 s): the most a crash can lose.
    pub flush_interval_s: f64,
    /// Messages the queue holds before `write` returns [`Error::QueueFull`] (default
    /// 1024). Each slot is the size of the largest wire type, about 12 KiB, allocated
    /// when the recorder is created.
    pub queue_capacity: usize,
    /// zstd worker threads (default 0: the writer thread compresses by itself, so a
    /// recorder takes one core at most, next to the real-time services).
    pub compression_threads: u32,
    /// The MCAP header's profile (default `vibrocomp`).
    pub profile: String,
    /// Whether the writer runs on a thread of its own behind the queue (default), or on
    /// the caller's thread: each call then encodes, compresses and writes before it
    /// returns, and never fails with [`Error::QueueFull`]. For an offline run on one
    /// core, where the hand-over between two threads (a wake-up per message, each
    /// message copied in and out of the queue) costs more than it frees. The flush
    /// rule is then checked at each call: a chunk stays open while no call comes.
    pub writer_thread: bool,
    /// Write with this crate's own MCAP writer (`splice.rs`), which can also take a
    /// chunk copied as it is ([`Recorder::copy_chunk`]), instead of `mcap`'s (default
    /// false). Only with `writer_thread` off: the copy is made on the caller's thread.
    pub splice: bool,
}

impl Default for RecorderOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Zstd,
            zstd_level: 1,
            chunk_size_bytes: 1 << 20,
            flush_interval_s: 1.0,
            queue_capacity: 1024,
            compression_threads: 0,
            profile: "vibrocomp".to_string(),
            writer_thread: true,
            splice: false,
        }
    }
}

impl RecorderOptions {
    fn flush_interval(&self) -> Result<Duration> {
        let s = self.flush_interval_s;
        if !(s.is_finite() && s > 0.0) {
            return Err(Error::InvalidOption {
                name: "flush_interval_s",
                value: s.to_string(),
                rule: "must be finite and > 0",
            });
        }
        Duration::try_from_secs_f64(s).map_err(|_| Error::InvalidOption {
            name: "flush_interval_s",
            value: s.to_string(),
            rule: "must fit a Duration",
        })
    }

    fn check(&self) -> Result<Duration> {
        if !(1..=22).contains(&self.zstd_level) {
            return Err(Error::InvalidOption {
                name: "zstd_level",
                value: self.zstd_level.to_string(),
                rule: "must be 1..=22",
            });
        }
        if self.chunk_size_bytes == 0 {
            return Err(Error::InvalidOption {
                name: "chunk_size_bytes",
                value: "0".to_string(),
                rule: "must be > 0",
            });
        }
        if self.splice && self.writer_thread {
            return Err(Error::InvalidOption {
                name: "splice",
                value: "true".to_string(),
                rule: "needs writer_thread = false (chunks are copied on the caller's thread)",
            });
        }
        if self.queue_capacity == 0 {
            return Err(Error::InvalidOption {
                name: "queue_capacity",
                value: "0".to_string(),
                rule: "must be > 0",
            });
        }
        self.flush_interval()
    }
}

/// A registered channel, for [`Recorder::write_to`] (skips the topic lookup).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelId {
    id: u16,
    kind: MessageKind,
    topic: Arc<str>,
}

impl ChannelId {
    /// The MCAP channel ID.
    pub fn id(&self) -> u16 {
        self.id
    }
    /// The message type of the channel.
    pub fn kind(&self) -> MessageKind {
        self.kind
    }
    /// The topic.
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// A registered view channel (docs/view.md), for [`Recorder::write_view`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewChannelId {
    id: u16,
    topic: Arc<str>,
}

impl ViewChannelId {
    /// The MCAP channel ID.
    pub fn id(&self) -> u16 {
        self.id
    }
    /// The topic.
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// Counters of a running recorder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RecorderStats {
    /// Messages accepted into the queue.
    pub accepted: u64,
    /// Messages rejected because the queue was full.
    pub rejected_full: u64,
    /// Messages the writer thread has written into the file so far.
    pub written: u64,
}

/// What [`Recorder::finish`] wrote.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub path: PathBuf,
    /// Messages written per topic.
    pub messages_per_topic: BTreeMap<String, u64>,
    /// Messages written in total.
    pub messages: u64,
    /// Messages rejected by `write` because the queue was full.
    pub rejected_full: u64,
    /// Chunks in the file.
    pub chunks: u64,
    /// Attachments in the file.
    pub attachments: u64,
    /// Metadata records in the file.
    pub metadata: u64,
    /// File size in bytes.
    pub bytes: u64,
}

#[derive(Default)]
struct Counters {
    accepted: AtomicU64,
    rejected_full: AtomicU64,
    written: AtomicU64,
    /// Why the writer thread stopped, set before it lets go of the queue: every later
    /// `write` and control call sees [`Error::RecorderStopped`] with it, so a caller
    /// that never reaches `finish()` (a loop that returns on the first error) still
    /// shows the operating system's reason (a full disk), not only that writing stopped.
    cause: OnceLock<String>,
}

/// What travels to the writer thread. Messages are copied in by value (see [`Message`]).
#[allow(clippy::large_enum_variant)]
enum Command {
    Channel {
        id: u16,
        topic: String,
        kind: MessageKind,
    },
    ViewChannel {
        id: u16,
        topic: String,
        schema: ViewSchema,
    },
    /// A view message: protobuf bytes encoded by the caller.
    View {
        channel_id: u16,
        sequence: u32,
        log_time_ns: u64,
        publish_time_ns: u64,
        data: Vec<u8>,
    },
    Message {
        channel_id: u16,
        sequence: u32,
        log_time_ns: u64,
        publish_time_ns: u64,
        message: Message,
    },
    Attachment {
        name: String,
        media_type: String,
        data: Vec<u8>,
        /// `None`: the wall clock when written.
        time_ns: Option<u64>,
    },
    Metadata {
        name: String,
        entries: BTreeMap<String, String>,
    },
}

/// Where the commands go: the writer thread's queue, or the writer itself on the
/// caller's thread ([`RecorderOptions::writer_thread`]).
enum Sink {
    Thread {
        tx: Option<SyncSender<Command>>,
        thread: Option<JoinHandle<Result<RecordingSummary>>>,
    },
    Inline(Box<std::sync::Mutex<Inline>>),
}

/// The writer on the caller's thread.
struct Inline {
    /// `None` once finished or failed.
    writer: Option<Writer>,
    /// The writer's error, returned by `finish` (later calls see
    /// [`Error::RecorderStopped`] with its cause).
    failed: Option<Error>,
}

/// Records wire messages into an MCAP file from any thread; see the module docs for the
/// threading, back-pressure and flush rules.
///
/// Call [`Recorder::finish`] to close the file and get its errors. Dropping a recorder
/// also finishes the file (waiting for the writer thread) but loses any error.
pub struct Recorder {
    path: PathBuf,
    sink: Sink,
    channels: HashMap<String, ChannelId>,
    view_channels: HashMap<String, (ViewChannelId, &'static str)>,
    next_channel_id: u16,
    capacity: usize,
    counters: Arc<Counters>,
}

impl Recorder {
    /// Creates `path`, or empties it if it is a regular file, and starts the writer
    /// thread. A symbolic link (dangling or not), a FIFO, a device or a directory is
    /// refused ([`Error::Files`]), never followed, blocked on or truncated
    /// (`vibro_files::create_in_place` with `force`).
    pub fn create(path: impl AsRef<Path>, options: RecorderOptions) -> Result<Recorder> {
        Self::open(path.as_ref(), options, true)
    }

    /// [`Recorder::create`] for a file that must not exist: an existing one is refused
    /// (`O_EXCL`; an output without `--force`).
    pub fn create_new(path: impl AsRef<Path>, options: RecorderOptions) -> Result<Recorder> {
        Self::open(path.as_ref(), options, false)
    }

    fn open(path: &Path, options: RecorderOptions, force: bool) -> Result<Recorder> {
        options.check()?;
        let file = vibro_files::create_in_place(path, force)?;
        Self::start(file, path.to_path_buf(), options)
    }

    /// Starts recording into `file`, already open for writing, named `path` in errors.
    fn start(file: std::fs::File, path: PathBuf, options: RecorderOptions) -> Result<Recorder> {
        let flush_interval = options.check()?;
        let writer = if options.splice {
            let splice_options = SpliceOptions {
                profile: options.profile.clone(),
                library: format!("vibrocomp-mcap {}", env!("CARGO_PKG_VERSION")),
                zstd_level: match options.compression {
                    // 1..=22, checked.
                    Compression::Zstd => Some(options.zstd_level as i32),
                    Compression::None => None,
                },
                chunk_size_bytes: options.chunk_size_bytes,
            };
            Backend::Splice(Box::new(
                SpliceWriter::new(BufWriter::new(file), splice_options)
                    .map_err(|e| Error::io("write", &path, e))?,
            ))
        } else {
            let write_options = mcap::WriteOptions::new()
                .compression(match options.compression {
                    Compression::Zstd => Some(mcap::Compression::Zstd),
                    Compression::None => None,
                })
                .chunk_size(Some(options.chunk_size_bytes))
                .compression_level(options.zstd_level)
                .compression_threads(options.compression_threads)
                .profile(options.profile.clone());
            Backend::Mcap(Box::new(
                write_options
                    .create(BufWriter::new(file))
                    .map_err(|e| write_error(&path, e))?,
            ))
        };

        let counters = Arc::new(Counters::default());
        let state = Writer {
            path: path.clone(),
            writer,
            flush_interval,
            counters: Arc::clone(&counters),
            topics: BTreeMap::new(),
            view_schemas: BTreeMap::new(),
            buf: Vec::with_capacity(16 * 1024),
            attachments: 0,
            metadata: 0,
            open_since: None,
        };
        let sink = if options.writer_thread {
            let (tx, rx) = std::sync::mpsc::sync_channel(options.queue_capacity);
            let counters = Arc::clone(&counters);
            let thread = std::thread::Builder::new()
                .name("mcap-recorder".to_string())
                .spawn(move || {
                    let result = state.run(&rx);
                    if let Err(e) = &result {
                        let _ = counters.cause.set(describe_cause(e));
                    }
                    // Only now may senders see the queue disconnected: the cause is set.
                    drop(rx);
                    result
                })
                .map_err(|e| Error::io("start the writer thread for", &path, e))?;
            Sink::Thread {
                tx: Some(tx),
                thread: Some(thread),
            }
        } else {
            Sink::Inline(Box::new(std::sync::Mutex::new(Inline {
                writer: Some(state),
                failed: None,
            })))
        };
        Ok(Recorder {
            path,
            sink,
            channels: HashMap::new(),
            view_channels: HashMap::new(),
            next_channel_id: 1,
            capacity: options.queue_capacity,
            counters,
        })
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Registers `topic` for messages of `kind` (its schema is added with the first
    /// channel of that kind). Registering the same topic and kind again returns the same
    /// channel.
    pub fn add_channel(&mut self, topic: &str, kind: MessageKind) -> Result<ChannelId> {
        if let Some((_, name)) = self.view_channels.get(topic) {
            return Err(Error::ViewTopicExists {
                topic: topic.to_string(),
                existing: name,
                requested: kind.type_name(),
            });
        }
        if let Some(existing) = self.channels.get(topic) {
            if existing.kind == kind {
                return Ok(existing.clone());
            }
            return Err(Error::TopicExists {
                topic: topic.to_string(),
                existing: existing.kind,
                requested: kind,
            });
        }
        let id = self.take_channel_id(topic)?;
        self.send_control(Command::Channel {
            id,
            topic: topic.to_string(),
            kind,
        })?;
        let channel = ChannelId {
            id,
            kind,
            topic: Arc::from(topic),
        };
        self.channels.insert(topic.to_string(), channel.clone());
        Ok(channel)
    }

    /// The next free MCAP channel ID, for `topic` (named in the error when none is left).
    fn take_channel_id(&mut self, topic: &str) -> Result<u16> {
        let id = self.next_channel_id;
        self.next_channel_id = id.checked_add(1).ok_or(Error::TooManyChannels {
            topic: topic.to_string(),
            max: u16::MAX,
        })?;
        Ok(id)
    }

    /// Registers a view channel `topic` (docs/view.md) with its protobuf `schema`:
    /// messages made to be plotted, which readers of the wire streams skip. The same
    /// topic and schema again return the same channel.
    pub fn add_view_channel(&mut self, topic: &str, schema: ViewSchema) -> Result<ViewChannelId> {
        if let Some((existing, name)) = self.view_channels.get(topic) {
            if *name == schema.name {
                return Ok(existing.clone());
            }
            return Err(Error::ViewTopicExists {
                topic: topic.to_string(),
                existing: name,
                requested: schema.name,
            });
        }
        if let Some(wire) = self.channels.get(topic) {
            return Err(Error::ViewTopicExists {
                topic: topic.to_string(),
                existing: wire.kind.type_name(),
                requested: schema.name,
            });
        }
        let id = self.take_channel_id(topic)?;
        self.send_control(Command::ViewChannel {
            id,
            topic: topic.to_string(),
            schema,
        })?;
        let channel = ViewChannelId {
            id,
            topic: Arc::from(topic),
        };
        self.view_channels
            .insert(topic.to_string(), (channel.clone(), schema.name));
        Ok(channel)
    }

    /// Queues one view message (`data`: its protobuf bytes) on `channel`, waiting for
    /// room in the queue when it is full (as the control calls do: the caller is a
    /// recorder's own thread, which waits for the wire messages too); returns whether
    /// it had to wait.
    pub fn write_view(
        &self,
        channel: &ViewChannelId,
        log_time_ns: u64,
        publish_time_ns: u64,
        sequence: u32,
        data: Vec<u8>,
    ) -> Result<bool> {
        let command = Command::View {
            channel_id: channel.id,
            sequence,
            log_time_ns,
            publish_time_ns,
            data,
        };
        let waited = match &self.sink {
            Sink::Thread { tx, .. } => {
                let tx = tx.as_ref().ok_or_else(|| self.stopped())?;
                match tx.try_send(command) {
                    Ok(()) => false,
                    Err(TrySendError::Full(command)) => {
                        tx.send(command).map_err(|_| self.stopped())?;
                        true
                    }
                    Err(TrySendError::Disconnected(_)) => return Err(self.stopped()),
                }
            }
            Sink::Inline(_) => {
                self.inline(command)?;
                false
            }
        };
        self.counters.accepted.fetch_add(1, Ordering::Relaxed);
        Ok(waited)
    }

    /// Queues one message for `topic` (registered with [`Recorder::add_channel`]).
    /// `log_time_ns` is when it was received, `publish_time_ns` when it was published,
    /// `sequence` the publisher's counter (MCAP keeps 32 bits; gaps show losses).
    ///
    /// Never blocks: a full queue returns [`Error::QueueFull`] and the message is not
    /// recorded (counted in [`RecorderStats::rejected_full`]).
    pub fn write<M: Copy + Into<Message>>(
        &self,
        topic: &str,
        log_time_ns: u64,
        publish_time_ns: u64,
        sequence: u32,
        message: &M,
    ) -> Result<()> {
        let channel = self
            .channels
            .get(topic)
            .ok_or_else(|| Error::UnknownTopic {
                topic: topic.to_string(),
            })?;
        self.write_to(
            channel,
            log_time_ns,
            publish_time_ns,
            sequence,
            (*message).into(),
        )
    }

    /// [`Recorder::write`] for a channel already looked up.
    pub fn write_to(
        &self,
        channel: &ChannelId,
        log_time_ns: u64,
        publish_time_ns: u64,
        sequence: u32,
        message: Message,
    ) -> Result<()> {
        if message.kind() != channel.kind {
            return Err(Error::WrongMessageType {
                topic: Arc::clone(&channel.topic),
                expected: channel.kind,
                got: message.kind(),
            });
        }
        message.validate()?;
        let command = Command::Message {
            channel_id: channel.id,
            sequence,
            log_time_ns,
            publish_time_ns,
            message,
        };
        let tx = match &self.sink {
            Sink::Thread { tx, .. } => tx.as_ref().ok_or_else(|| self.stopped())?,
            Sink::Inline(_) => {
                self.inline(command)?;
                self.counters.accepted.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
        };
        match tx.try_send(command) {
            Ok(()) => {
                self.counters.accepted.fetch_add(1, Ordering::Relaxed);
                Ok(())
            }
            Err(TrySendError::Full(_)) => {
                self.counters.rejected_full.fetch_add(1, Ordering::Relaxed);
                Err(Error::QueueFull {
                    topic: Arc::clone(&channel.topic),
                    sequence,
                    capacity: self.capacity,
                })
            }
            Err(TrySendError::Disconnected(_)) => Err(self.stopped()),
        }
    }

    /// [`Recorder::write_to`] for a message already encoded (`data`: its protobuf
    /// bytes, which the caller checked). Waits for room in the queue, as the control
    /// calls do.
    pub fn write_encoded(
        &self,
        channel: &ChannelId,
        log_time_ns: u64,
        publish_time_ns: u64,
        sequence: u32,
        data: &[u8],
    ) -> Result<()> {
        let header = mcap::records::MessageHeader {
            channel_id: channel.id,
            sequence,
            log_time: log_time_ns,
            publish_time: publish_time_ns,
        };
        match &self.sink {
            Sink::Inline(_) => self.with_inline(|w| {
                w.write_record(&header, data)?;
                w.opened()
            })?,
            Sink::Thread { .. } => self.send_control(Command::View {
                channel_id: channel.id,
                sequence,
                log_time_ns,
                publish_time_ns,
                data: data.to_vec(),
            })?,
        }
        self.counters.accepted.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }

    /// Copies a chunk of another MCAP file into the recording as it is: `record`, its
    /// bytes (opcode and length prefix included; [`crate::Reader::read_chunk_record`]),
    /// and what it holds, `facts`. Its channels must be this recording's, with the same
    /// IDs: the caller checked that the records are the bytes it would write. Needs
    /// [`RecorderOptions::splice`].
    pub fn copy_chunk(&self, facts: &crate::ChunkFacts, record: &[u8]) -> Result<()> {
        self.with_inline(|w| w.copy_chunk(facts, record))?;
        let n: u64 = facts.channel_counts.values().sum();
        self.counters.accepted.fetch_add(n, Ordering::Relaxed);
        Ok(())
    }

    /// Closes the open chunk now, without flushing the file. Needs the writer on the
    /// caller's thread.
    pub fn close_chunk(&self) -> Result<()> {
        self.with_inline(Writer::close_chunk)
    }

    /// `f` on the writer on this thread ([`Sink::Inline`]); its error stops the
    /// recorder as a writer's error does.
    fn with_inline(&self, f: impl FnOnce(&mut Writer) -> Result<()>) -> Result<()> {
        let Sink::Inline(inline) = &self.sink else {
            return Err(Error::InvalidOption {
                name: "writer_thread",
                value: "true".to_string(),
                rule: "copying chunks and closing them on demand need the writer on the caller's thread",
            });
        };
        let mut inline = inline
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let writer = inline.writer.as_mut().ok_or_else(|| self.stopped())?;
        if let Err(e) = f(writer) {
            let _ = self.counters.cause.set(describe_cause(&e));
            inline.writer = None;
            inline.failed = Some(e);
            return Err(self.stopped());
        }
        Ok(())
    }

    /// Adds a file (a configuration or passport) to the recording. Waits for room in the
    /// queue.
    pub fn add_attachment(&self, name: &str, media_type: &str, data: Vec<u8>) -> Result<()> {
        self.send_control(Command::Attachment {
            name: name.to_string(),
            media_type: media_type.to_string(),
            data,
            time_ns: None,
        })
    }

    /// [`Recorder::add_attachment`] with its log and creation time given (ns) instead
    /// of the wall clock: a generated log (the simulator's) stays a function of its
    /// inputs, bit-identical from run to run.
    pub fn add_attachment_at(
        &self,
        name: &str,
        media_type: &str,
        data: Vec<u8>,
        time_ns: u64,
    ) -> Result<()> {
        self.send_control(Command::Attachment {
            name: name.to_string(),
            media_type: media_type.to_string(),
            data,
            time_ns: Some(time_ns),
        })
    }

    /// Adds a named set of key-value pairs (run parameters, versions). Waits for room in
    /// the queue.
    pub fn add_metadata(&self, name: &str, entries: BTreeMap<String, String>) -> Result<()> {
        self.send_control(Command::Metadata {
            name: name.to_string(),
            entries,
        })
    }

    /// Counters so far.
    pub fn stats(&self) -> RecorderStats {
        RecorderStats {
            accepted: self.counters.accepted.load(Ordering::Relaxed),
            rejected_full: self.counters.rejected_full.load(Ordering::Relaxed),
            written: self.counters.written.load(Ordering::Relaxed),
        }
    }

    /// Writes everything queued, the summary and the footer, syncs the file to disk and
    /// reports what was written, or the first error the writer thread met.
    pub fn finish(mut self) -> Result<RecordingSummary> {
        self.close()
    }

    fn close(&mut self) -> Result<RecordingSummary> {
        let mut summary = match &mut self.sink {
            Sink::Thread { tx, thread } => {
                // Dropping the sender lets the writer thread drain the queue and finish.
                *tx = None;
                let thread = thread.take().ok_or_else(|| self.stopped())?;
                thread.join().map_err(|_| Error::WriterPanicked {
                    path: self.path.clone(),
                })??
            }
            Sink::Inline(inline) => {
                let inline = inline
                    .get_mut()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                if let Some(e) = inline.failed.take() {
                    return Err(e);
                }
                let writer = inline.writer.take().ok_or_else(|| self.stopped())?;
                writer.finish()?
            }
        };
        summary.rejected_full = self.counters.rejected_full.load(Ordering::Relaxed);
        Ok(summary)
    }

    /// Whether the file is still to be finished (by `finish` or on drop).
    fn unfinished(&self) -> bool {
        match &self.sink {
            Sink::Thread { thread, .. } => thread.is_some(),
            Sink::Inline(inline) => inline
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .writer
                .is_some(),
        }
    }

    /// `command` written on this thread ([`Sink::Inline`]).
    fn inline(&self, command: Command) -> Result<()> {
        // As the writer thread ends on an error: the cause first, for every later call.
        self.with_inline(|w| w.take(command))
    }

    fn send_control(&self, command: Command) -> Result<()> {
        match &self.sink {
            Sink::Thread { tx, .. } => {
                let tx = tx.as_ref().ok_or_else(|| self.stopped())?;
                tx.send(command).map_err(|_| self.stopped())
            }
            Sink::Inline(_) => self.inline(command),
        }
    }

    fn stopped(&self) -> Error {
        let cause = self.counters.cause.get().map_or_else(
            || "its writer thread ended without an error (it panicked)".to_string(),
            Clone::clone,
        );
        Error::RecorderStopped {
            path: self.path.clone(),
            cause,
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if self.unfinished() {
            // Best effort: the file is finished, but an error has nobody to go to.
            // `finish()` is the way to see it.
            let _ = self.close();
        }
    }
}

/// The first schema ID of the view schemas (the wire types take 1..=6).
const VIEW_SCHEMA_ID_BASE: u16 = 32;

/// The MCAP writer underneath: `mcap`'s, or this crate's, which can copy chunks.
enum Backend {
    Mcap(Box<mcap::Writer<BufWriter<std::fs::File>>>),
    Splice(Box<SpliceWriter<BufWriter<std::fs::File>>>),
}

impl Backend {
    fn add_schema(&mut self, path: &Path, id: u16, name: &str, data: &[u8]) -> Result<u16> {
        match self {
            Backend::Mcap(w) => w
                .add_schema_with_id(id, name, SCHEMA_ENCODING, data)
                .map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w
                .add_schema(id, name, SCHEMA_ENCODING, data)
                .map(|()| id)
                .map_err(|e| Error::io("write", path, e)),
        }
    }

    fn add_channel(
        &mut self,
        path: &Path,
        id: u16,
        schema_id: u16,
        topic: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<()> {
        match self {
            Backend::Mcap(w) => w
                .add_channel_with_id(id, schema_id, topic, MESSAGE_ENCODING, metadata)
                .map(|_| ())
                .map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w
                .add_channel(id, schema_id, topic, MESSAGE_ENCODING, metadata)
                .map_err(|e| Error::io("write", path, e)),
        }
    }

    fn write(
        &mut self,
        path: &Path,
        header: &mcap::records::MessageHeader,
        data: &[u8],
    ) -> Result<()> {
        match self {
            Backend::Mcap(w) => w
                .write_to_known_channel(header, data)
                .map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w
                .write_message(header, data)
                .map_err(|e| Error::io("write", path, e)),
        }
    }

    fn attach(&mut self, path: &Path, a: &mcap::Attachment<'_>) -> Result<()> {
        match self {
            Backend::Mcap(w) => w.attach(a).map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w.attach(a).map_err(|e| Error::io("write", path, e)),
        }
    }

    fn metadata(&mut self, path: &Path, m: &mcap::records::Metadata) -> Result<()> {
        match self {
            Backend::Mcap(w) => w.write_metadata(m).map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w.write_metadata(m).map_err(|e| Error::io("write", path, e)),
        }
    }

    fn flush(&mut self, path: &Path) -> Result<()> {
        match self {
            Backend::Mcap(w) => w.flush().map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w.flush().map_err(|e| Error::io("write", path, e)),
        }
    }

    /// Writes the summary; returns the chunk count.
    fn finish(&mut self, path: &Path) -> Result<u64> {
        match self {
            Backend::Mcap(w) => w
                .finish()
                .map(|s| s.stats.as_ref().map_or(0, |s| s.chunk_count.into()))
                .map_err(|e| write_error(path, e)),
            Backend::Splice(w) => w
                .finish()
                .map(|s| s.chunk_count.into())
                .map_err(|e| Error::io("write", path, e)),
        }
    }

    fn into_inner(self) -> BufWriter<std::fs::File> {
        match self {
            Backend::Mcap(w) => (*w).into_inner(),
            Backend::Splice(w) => (*w).into_inner(),
        }
    }
}

/// The MCAP writer and what goes with it: on the writer thread, or on the caller's.
struct Writer {
    path: PathBuf,
    writer: Backend,
    flush_interval: Duration,
    counters: Arc<Counters>,
    topics: BTreeMap<u16, (String, u64)>,
    /// The view schemas written: name -> schema ID.
    view_schemas: BTreeMap<&'static str, u16>,
    buf: Vec<u8>,
    attachments: u64,
    metadata: u64,
    /// When the open chunk got its first message: it is closed by then + interval.
    open_since: Option<Instant>,
}

impl Writer {
    /// The writer thread's loop: takes the queue's commands until every sender is gone,
    /// and closes an open chunk when its interval ends while nothing comes.
    fn run(mut self, rx: &Receiver<Command>) -> Result<RecordingSummary> {
        loop {
            let command = match self.open_since {
                None => match rx.recv() {
                    Ok(c) => c,
                    Err(_) => break,
                },
                Some(since) => {
                    let left =
                        (since + self.flush_interval).saturating_duration_since(Instant::now());
                    match rx.recv_timeout(left) {
                        Ok(c) => c,
                        Err(RecvTimeoutError::Timeout) => {
                            self.flush()?;
                            continue;
                        }
                        Err(RecvTimeoutError::Disconnected) => break,
                    }
                }
            };
            self.take(command)?;
        }
        self.finish()
    }

    /// One command written, and the open chunk closed once its interval is over.
    fn take(&mut self, command: Command) -> Result<()> {
        let writes_chunk = self.handle(command)?;
        if writes_chunk && self.open_since.is_none() {
            self.open_since = Some(Instant::now());
        }
        if self
            .open_since
            .is_some_and(|since| since.elapsed() >= self.flush_interval)
        {
            self.flush()?;
        }
        Ok(())
    }

    /// Returns whether the command wrote into the open chunk.
    fn handle(&mut self, command: Command) -> Result<bool> {
        let path = &self.path;
        match command {
            Command::Channel { id, topic, kind } => {
                let s = schema(kind);
                let schema_id = self
                    .writer
                    .add_schema(path, schema_id(kind), s.name, s.data)?;
                let metadata = BTreeMap::from([(
                    "vibrocomp.type_name".to_string(),
                    kind.type_name().to_string(),
                )]);
                self.writer
                    .add_channel(path, id, schema_id, &topic, &metadata)?;
                self.topics.insert(id, (topic, 0));
                Ok(true)
            }
            Command::ViewChannel { id, topic, schema } => {
                // After the wire types' fixed IDs (1..=6), one per view schema.
                let next = VIEW_SCHEMA_ID_BASE + self.view_schemas.len() as u16;
                let wanted = *self.view_schemas.entry(schema.name).or_insert(next);
                let schema_id = self
                    .writer
                    .add_schema(path, wanted, schema.name, schema.data)?;
                let metadata = BTreeMap::from([(
                    "vibrocomp.view".to_string(),
                    "made to be plotted (docs/view.md)".to_string(),
                )]);
                self.writer
                    .add_channel(path, id, schema_id, &topic, &metadata)?;
                self.topics.insert(id, (topic, 0));
                Ok(true)
            }
            Command::View {
                channel_id,
                sequence,
                log_time_ns,
                publish_time_ns,
                data,
            } => {
                let header = mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: log_time_ns,
                    publish_time: publish_time_ns,
                };
                self.write_record(&header, &data)
            }
            Command::Message {
                channel_id,
                sequence,
                log_time_ns,
                publish_time_ns,
                message,
            } => {
                message.encode(&mut self.buf)?;
                let header = mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: log_time_ns,
                    publish_time: publish_time_ns,
                };
                // The encoding buffer is kept (lent out while it is written).
                let buf = std::mem::take(&mut self.buf);
                let written = self.write_record(&header, &buf);
                self.buf = buf;
                written
            }
            Command::Attachment {
                name,
                media_type,
                data,
                time_ns,
            } => {
                let now_ns = time_ns.unwrap_or_else(unix_time_ns);
                self.writer.attach(
                    path,
                    &mcap::Attachment {
                        log_time: now_ns,
                        create_time: now_ns,
                        name,
                        media_type,
                        data: Cow::Owned(data),
                    },
                )?;
                self.attachments += 1;
                // Attachments live outside chunks: the open chunk was closed first.
                Ok(false)
            }
            Command::Metadata { name, entries } => {
                self.writer.metadata(
                    path,
                    &mcap::records::Metadata {
                        name,
                        metadata: entries,
                    },
                )?;
                self.metadata += 1;
                Ok(false)
            }
        }
    }

    /// Writes one message record into the open chunk and counts it.
    fn write_record(&mut self, header: &mcap::records::MessageHeader, data: &[u8]) -> Result<bool> {
        self.writer.write(&self.path, header, data)?;
        if let Some((_, n)) = self.topics.get_mut(&header.channel_id) {
            *n += 1;
        }
        self.counters.written.fetch_add(1, Ordering::Relaxed);
        Ok(true)
    }

    /// After a message written outside `take`: starts the open chunk's interval and
    /// applies the flush rule, as `take` does.
    fn opened(&mut self) -> Result<()> {
        if self.open_since.is_none() {
            self.open_since = Some(Instant::now());
        }
        if self
            .open_since
            .is_some_and(|since| since.elapsed() >= self.flush_interval)
        {
            self.flush()?;
        }
        Ok(())
    }

    /// Copies a chunk as it is ([`Recorder::copy_chunk`]) and counts its messages.
    fn copy_chunk(&mut self, facts: &crate::ChunkFacts, record: &[u8]) -> Result<()> {
        let Backend::Splice(w) = &mut self.writer else {
            return Err(Error::InvalidOption {
                name: "splice",
                value: "false".to_string(),
                rule: "copying a chunk needs this crate's writer (splice = true)",
            });
        };
        let index = mcap::records::ChunkIndex {
            message_start_time: facts.message_start_ns,
            message_end_time: facts.message_end_ns,
            chunk_start_offset: facts.start,
            chunk_length: facts.length,
            // As if the records followed the chunk in the source file.
            message_index_offsets: facts
                .message_index_offsets
                .iter()
                .map(|(id, at)| (*id, facts.start + facts.length + at))
                .collect(),
            message_index_length: facts.message_indexes.len() as u64,
            compression: facts.compression.clone(),
            compressed_size: facts.compressed_bytes,
            uncompressed_size: facts.uncompressed_bytes,
        };
        w.copy_chunk(&CopiedChunk {
            record,
            message_indexes: &facts.message_indexes,
            index: &index,
            channel_counts: &facts.channel_counts,
        })
        .map_err(|e| Error::io("write", &self.path, e))?;
        let mut n = 0;
        for (id, count) in &facts.channel_counts {
            if let Some((_, written)) = self.topics.get_mut(id) {
                *written += count;
            }
            n += count;
        }
        self.counters.written.fetch_add(n, Ordering::Relaxed);
        Ok(())
    }

    /// Closes the open chunk without flushing the file ([`Recorder::close_chunk`]).
    fn close_chunk(&mut self) -> Result<()> {
        self.open_since = None;
        match &mut self.writer {
            Backend::Splice(w) => w
                .close_chunk()
                .map_err(|e| Error::io("write", &self.path, e)),
            Backend::Mcap(w) => w.flush().map_err(|e| write_error(&self.path, e)),
        }
    }

    /// Closes the open chunk (and hands it to the operating system).
    fn flush(&mut self) -> Result<()> {
        self.open_since = None;
        self.writer.flush(&self.path)
    }

    fn finish(mut self) -> Result<RecordingSummary> {
        let path = self.path.clone();
        let chunks = self.writer.finish(&path)?;
        let file = self
            .writer
            .into_inner()
            .into_inner()
            .map_err(|e| Error::io("write", &path, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io("sync", &path, e))?;
        let bytes = file
            .metadata()
            .map_err(|e| Error::io("stat", &path, e))?
            .len();
        let mut messages_per_topic = BTreeMap::new();
        for (topic, n) in self.topics.into_values() {
            *messages_per_topic.entry(topic).or_insert(0) += n;
        }
        Ok(RecordingSummary {
            path,
            messages: messages_per_topic.values().sum(),
            messages_per_topic,
            rejected_full: 0,
            chunks,
            attachments: self.attachments,
            metadata: self.metadata,
            bytes,
        })
    }
}

/// An error of the `mcap` writer for `path`. Its I/O errors become [`Error::Io`], whose
/// message carries the operating system's reason: `mcap`'s own message for them ("I/O
/// error from writing, or reading a compression stream") leaves it to the source chain,
/// which a caller printing with `{}` never shows.
fn write_error(path: &Path, e: mcap::McapError) -> Error {
    match e {
        mcap::McapError::Io(source) => Error::io("write", path, source),
        e => Error::mcap(path, e),
    }
}

/// The writer thread's error as [`Error::RecorderStopped`] repeats it: without the path,
/// which that message names already.
fn describe_cause(e: &Error) -> String {
    match e {
        Error::Io { action, source, .. } => format!("cannot {action} it: {source}"),
        e => e.to_string(),
    }
}

fn unix_time_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_msgs::AccelBlock;

    /// `/dev/full` fails every write with ENOSPC, as a full disk does. It is opened for
    /// writing only (no truncation, no replacement), so the device itself is untouched.
    /// The recorder's three ways of writing: `mcap`'s writer on its own thread or on
    /// the caller's, and this crate's (`splice`) on the caller's.
    const MODES: [(bool, bool); 3] = [(true, false), (false, false), (false, true)];

    fn full_disk((writer_thread, splice): (bool, bool)) -> Recorder {
        let path = PathBuf::from("/dev/full");
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .expect("/dev/full opens for writing");
        let options = RecorderOptions {
            chunk_size_bytes: 4096,
            flush_interval_s: 0.01,
            writer_thread,
            splice,
            ..RecorderOptions::default()
        };
        Recorder::start(file, path, options).expect("the recorder starts")
    }

    /// The operating system's reason for ENOSPC, as `io::Error` prints it.
    const ENOSPC: &str = "(os error 28)";

    /// With the writer on its own thread and on the caller's alike, and with this
    /// crate's writer.
    #[test]
    fn a_full_disk_is_reported_with_its_cause_by_write_control_calls_and_finish() {
        for mode in MODES {
            full_disk_reported(mode);
        }
    }

    fn full_disk_reported(mode: (bool, bool)) {
        let writer_thread = mode.0;
        let mut rec = full_disk(mode);
        // On the caller's thread the first write to the disk may be the channel's.
        let stopped = match rec.add_channel("accel", MessageKind::AccelBlock) {
            Ok(accel) => first_failed_write(&rec, &accel),
            Err(e) if !writer_thread => e,
            Err(e) => panic!("channel: {e}"),
        };
        let text = stopped.to_string();
        assert!(
            matches!(stopped, Error::RecorderStopped { .. }),
            "write: {text}"
        );
        assert!(text.contains("/dev/full"), "write names no file: {text}");
        assert!(text.contains(ENOSPC), "write hides the cause: {text}");
        assert_eq!(
            text.matches(ENOSPC).count(),
            1,
            "write repeats the cause: {text}"
        );

        let control = rec
            .add_metadata("run", BTreeMap::new())
            .expect_err("a control call after the stop fails");
        assert!(
            control.to_string().contains(ENOSPC),
            "add_metadata hides the cause: {control}"
        );

        let finished = rec.finish().expect_err("finish reports the full disk");
        let text = finished.to_string();
        assert!(text.contains("/dev/full"), "finish names no file: {text}");
        assert!(text.contains(ENOSPC), "finish hides the cause: {text}");
        match &finished {
            Error::Io { source, .. } => {
                // ENOSPC on Linux, the platform with `/dev/full`.
                assert_eq!(source.raw_os_error(), Some(28), "{text}")
            }
            other => panic!("finish: not an I/O error: {other:?}"),
        }
    }

    /// Writes until a write fails; that error.
    fn first_failed_write(rec: &Recorder, accel: &ChannelId) -> Error {
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut seq = 0u32;
        loop {
            assert!(Instant::now() < deadline, "no write failed on /dev/full");
            let mut m = AccelBlock::ZEROED;
            m.seq = u64::from(seq);
            match rec.write_to(accel, u64::from(seq), 0, seq, m.into()) {
                Ok(()) | Err(Error::QueueFull { .. }) => {
                    std::thread::sleep(Duration::from_micros(100));
                    seq += 1;
                }
                Err(e) => break e,
            }
        }
    }

    #[test]
    fn finish_alone_reports_a_full_disk_with_its_cause() {
        for mode in MODES {
            let writer_thread = mode.0;
            // Nothing but the header and a channel: the first write to the disk is
            // finish's.
            let mut rec = full_disk(mode);
            if let Err(e) = rec.add_channel("accel", MessageKind::AccelBlock) {
                // On the caller's thread the channel may meet the full disk first.
                assert!(!writer_thread && e.to_string().contains(ENOSPC), "{e}");
            }
            let text = rec
                .finish()
                .expect_err("finish reports the full disk")
                .to_string();
            assert!(
                text.contains("/dev/full") && text.contains(ENOSPC),
                "finish ({writer_thread}): {text}"
            );
        }
    }

    /// View channels go into the file with their schema (one schema record for two
    /// channels of the same schema, after the wire types' IDs), their bytes as given;
    /// the wire readers pass over them and list them apart; a topic cannot be both.
    /// The writer on the caller's thread writes the file the writer thread writes, byte
    /// for byte (chunks closed by size: the test is over long before the flush
    /// interval).
    #[test]
    fn the_writer_on_the_callers_thread_writes_the_same_file() {
        use crate::schema::VIEW_UNIT_STAGES;
        let write = |writer_thread: bool| {
            let path = std::env::temp_dir().join(format!(
                "vibro-mcap-inline-{}-{writer_thread}.mcap",
                std::process::id()
            ));
            let options = RecorderOptions {
                compression: Compression::None,
                chunk_size_bytes: 64 * 1024,
                flush_interval_s: 600.0,
                writer_thread,
                ..RecorderOptions::default()
            };
            let mut rec = Recorder::create(&path, options).expect("create");
            let accel = rec
                .add_channel("/accel", MessageKind::AccelBlock)
                .expect("channel");
            let view = rec
                .add_view_channel("/view/AK1", VIEW_UNIT_STAGES)
                .expect("view channel");
            rec.add_metadata("run", BTreeMap::from([("k".to_string(), "v".to_string())]))
                .expect("metadata");
            rec.add_attachment_at("a.toml", "text/plain", b"x = 1".to_vec(), 5)
                .expect("attachment");
            for seq in 0..500u32 {
                let mut m = AccelBlock::ZEROED;
                m.seq = u64::from(seq);
                m.count = 32;
                m.sample_period_ns = 1_250_000;
                m.t0_ns = u64::from(seq) * 40_000_000;
                m.output_v[3][1] = f64::from(seq) * 1e-3;
                loop {
                    match rec.write_to(&accel, m.t0_ns, m.t0_ns, seq, m.into()) {
                        Ok(()) => break,
                        Err(Error::QueueFull { .. }) => {
                            std::thread::sleep(Duration::from_micros(50))
                        }
                        Err(e) => panic!("write: {e}"),
                    }
                }
                if seq % 100 == 0 {
                    rec.write_view(&view, m.t0_ns, m.t0_ns, seq / 100, vec![8, seq as u8])
                        .expect("view");
                }
            }
            let summary = rec.finish().expect("finish");
            assert_eq!(summary.messages, 505, "{summary:?}");
            assert!(summary.chunks > 1, "{summary:?}");
            let bytes = std::fs::read(&path).expect("read back");
            let _ = std::fs::remove_file(&path);
            bytes
        };
        let (threaded, inline) = (write(true), write(false));
        assert!(threaded.len() > 100_000);
        assert!(threaded == inline, "the two files differ");
    }

    /// This crate's writer (`splice`) records what `mcap`'s does: every record,
    /// attachment and metadata read back the same (the chunking may differ), through
    /// `write_to` and `write_encoded` alike. It needs the writer on the caller's
    /// thread, and copying a chunk needs it.
    #[test]
    fn the_splice_writer_records_what_mcaps_writer_records() {
        use crate::schema::VIEW_UNIT_STAGES;
        let dir = tempfile::TempDir::new().expect("temp dir");
        let write = |splice: bool, compression: Compression| {
            let path = dir.path().join(format!("{splice}-{compression:?}.mcap"));
            let options = RecorderOptions {
                compression,
                chunk_size_bytes: 16 * 1024,
                writer_thread: false,
                splice,
                ..RecorderOptions::default()
            };
            let mut rec = Recorder::create(&path, options).expect("create");
            let accel = rec
                .add_channel("/accel", MessageKind::AccelBlock)
                .expect("channel");
            let view = rec
                .add_view_channel("/view/AK1", VIEW_UNIT_STAGES)
                .expect("view channel");
            rec.add_metadata("run", BTreeMap::from([("k".to_string(), "v".to_string())]))
                .expect("metadata");
            rec.add_attachment_at("a.toml", "text/plain", b"x = 1".to_vec(), 5)
                .expect("attachment");
            let mut encoded = Vec::new();
            for seq in 0..300u32 {
                let mut m = AccelBlock::ZEROED;
                m.seq = u64::from(seq);
                m.count = 32;
                m.sample_period_ns = 1_250_000;
                m.t0_ns = u64::from(seq) * 40_000_000;
                m.output_v[3][1] = f64::from(seq) * 1e-3;
                let message: Message = m.into();
                if seq % 2 == 0 {
                    rec.write_to(&accel, m.t0_ns, m.t0_ns + 7, seq, message)
                        .expect("write");
                } else {
                    message.encode(&mut encoded).expect("encode");
                    rec.write_encoded(&accel, m.t0_ns, m.t0_ns + 7, seq, &encoded)
                        .expect("write encoded");
                }
                if seq % 50 == 0 {
                    rec.write_view(&view, m.t0_ns, m.t0_ns, seq / 50, vec![8, seq as u8])
                        .expect("view");
                }
            }
            let summary = rec.finish().expect("finish");
            assert_eq!(summary.messages, 306, "{summary:?}");
            assert!(summary.chunks > 3, "{summary:?}");
            let mut reader = crate::Reader::open(&path).expect("open");
            reader
                .select_topics(&["/accel", "/view/AK1"])
                .expect("select");
            let mut records = Vec::new();
            while let Some(r) = reader.next_raw() {
                records.push(r.expect("record"));
            }
            let attachment = reader.read_attachment("a.toml").expect("attachment");
            (records, attachment, reader.metadata().expect("metadata"))
        };
        for compression in [Compression::Zstd, Compression::None] {
            let ours = write(true, compression);
            assert_eq!(ours.0.len(), 306);
            assert!(ours == write(false, compression), "{compression:?}");
        }
        let threaded = RecorderOptions {
            splice: true,
            ..RecorderOptions::default()
        };
        let Err(e) = Recorder::create(dir.path().join("t.mcap"), threaded) else {
            panic!("splice with the writer thread was accepted");
        };
        assert!(
            e.to_string()
                .contains("splice = true: needs writer_thread = false"),
            "{e}"
        );
        let rec = Recorder::create(dir.path().join("m.mcap"), RecorderOptions::default())
            .expect("create");
        let e = rec.close_chunk().unwrap_err();
        assert!(e.to_string().contains("writer_thread = true"), "{e}");
    }

    #[test]
    fn view_channels_are_written_beside_the_wire_ones_and_read_apart() {
        use crate::schema::{VIEW_SERVICE_HEALTH, VIEW_UNIT_STAGES};
        let path =
            std::env::temp_dir().join(format!("vibro-mcap-view-{}.mcap", std::process::id()));
        let mut rec = Recorder::create(&path, RecorderOptions::default()).expect("create");
        let accel = rec
            .add_channel("/accel", MessageKind::AccelBlock)
            .expect("wire channel");
        let a = rec
            .add_view_channel("/view/AK1", VIEW_UNIT_STAGES)
            .expect("view");
        let b = rec
            .add_view_channel("/view/AK2", VIEW_UNIT_STAGES)
            .expect("view");
        let h = rec
            .add_view_channel("/view/health/estimator", VIEW_SERVICE_HEALTH)
            .expect("view");
        assert_eq!(
            rec.add_view_channel("/view/AK1", VIEW_UNIT_STAGES).ok(),
            Some(a.clone())
        );
        assert!(matches!(
            rec.add_view_channel("/view/AK1", VIEW_SERVICE_HEALTH),
            Err(Error::ViewTopicExists { .. })
        ));
        assert!(matches!(
            rec.add_view_channel("/accel", VIEW_UNIT_STAGES),
            Err(Error::ViewTopicExists { .. })
        ));
        assert!(matches!(
            rec.add_channel("/view/AK2", MessageKind::AccelBlock),
            Err(Error::ViewTopicExists { .. })
        ));
        let mut m = AccelBlock::ZEROED;
        m.count = 1;
        m.sample_period_ns = 1_250_000;
        rec.write_to(&accel, 10, 11, 0, m.into()).expect("wire");
        for (i, ch) in [&a, &b, &h].into_iter().enumerate() {
            let waited = rec
                .write_view(ch, 20 + i as u64, 21, 0, vec![8, i as u8])
                .expect("view message");
            assert!(!waited);
        }
        let summary = rec.finish().expect("finish");
        assert_eq!(summary.messages, 4);
        let bytes = std::fs::read(&path).expect("read back");
        let reader = crate::Reader::open(&path).expect("the wire reader opens it");
        assert_eq!(
            reader.view_topics(),
            ["/view/AK1", "/view/AK2", "/view/health/estimator"]
        );
        assert!(reader.foreign_topics().is_empty());
        let wire: Vec<_> = reader
            .map(|r| r.expect("record").topic.to_string())
            .collect();
        assert_eq!(wire, ["/accel"]);
        let _ = std::fs::remove_file(&path);
        let file = mcap::Summary::read(&bytes).expect("summary").expect("some");
        let schemas: Vec<(u16, &str)> = file
            .schemas
            .values()
            .map(|s| (s.id, s.name.as_str()))
            .collect();
        assert_eq!(schemas.len(), 3, "{schemas:?}");
        assert!(schemas.contains(&(VIEW_SCHEMA_ID_BASE, VIEW_UNIT_STAGES.name)));
        assert!(schemas.contains(&(VIEW_SCHEMA_ID_BASE + 1, VIEW_SERVICE_HEALTH.name)));
        let mut payloads: Vec<(String, u64, Vec<u8>)> = mcap::MessageStream::new(&bytes)
            .expect("messages")
            .map(|m| m.expect("message"))
            .filter(|m| m.channel.topic.starts_with("/view/"))
            .map(|m| (m.channel.topic.clone(), m.log_time, m.data.to_vec()))
            .collect();
        payloads.sort();
        assert_eq!(
            payloads,
            [
                ("/view/AK1".to_string(), 20, vec![8, 0]),
                ("/view/AK2".to_string(), 21, vec![8, 1]),
                ("/view/health/estimator".to_string(), 22, vec![8, 2]),
            ]
        );
    }
}
