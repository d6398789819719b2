//! Copying the log's chunks into the session as they are, still compressed
//! (`OutputOptions::copy_chunks`): a session holds its inputs' records, and for a log
//! written as a session writes them (the simulator's, a session's) those are the
//! log's own bytes. Decoding a chunk is needed to run it through the cores;
//! compressing it again was most of what writing the session cost.
//!
//! Each input is held, with what the cores made after it, until its chunk of the log
//! is decided. A chunk is copied (`vibro_mcap::Recorder::copy_chunk`) once every one
//! of its records was taken and each is the bytes the session would have written: the
//! same channel ID, sequence, both times and protobuf bytes, on one of the session's
//! input channels, and nothing else in the chunk. It is given up at its first record
//! that is not. Held records are then written in the order they came, the copied
//! chunks' inputs skipped: each channel's records are the session written record by
//! record, only the chunking differs. Records of different channels at the same log
//! time (a block's `/truth` and `/compensated`) may be met in another order by a
//! reader that merges chunks by log time: MCAP leaves that order open, and the
//! services' recorder takes it from two processes as they run.
//!
//! A log's chunks overlap in time (a chunk of `/vib` blocks dated by their last sample
//! ends after the next chunk's first `/accel` block), so the reader yields two chunks'
//! records interleaved and more than one chunk can be undecided. What is held is
//! bounded ([`MAX_HELD_BYTES`]): beyond it the undecided chunks are written record by
//! record.

use std::collections::{BTreeMap, HashMap, VecDeque};
use vibro_mcap::{ChannelId, Message, Reader, Record, Recorder, ViewChannelId};

/// The most protobuf bytes held while chunks are undecided (about 64 of the
/// recorder's 1 MiB chunks).
pub(crate) const MAX_HELD_BYTES: usize = 64 << 20;

#[cfg(test)]
thread_local! {
    /// A smaller bound for this thread's copiers, for a test.
    pub(crate) static HELD_LIMIT: std::cell::Cell<usize> =
        const { std::cell::Cell::new(MAX_HELD_BYTES) };
}

/// The bound on held bytes ([`MAX_HELD_BYTES`], or a test's).
fn held_limit() -> usize {
    #[cfg(test)]
    return HELD_LIMIT.with(std::cell::Cell::get);
    #[cfg(not(test))]
    MAX_HELD_BYTES
}

/// Where held records go: the session's recorder and its counts.
pub(crate) struct Sink<'a> {
    pub recorder: &'a Recorder,
    /// The session's wire channels; the first three are its inputs'.
    pub channels: &'a [ChannelId],
    pub counts: &'a mut [u64],
    pub view_counts: &'a mut BTreeMap<String, u64>,
}

/// A record held until the chunks before it are decided.
enum Held {
    Wire {
        at: usize,
        log_time_ns: u64,
        seq: u32,
        data: Vec<u8>,
        /// The log's chunk of an input.
        chunk: Option<u32>,
    },
    View {
        channel: ViewChannelId,
        log_time_ns: u64,
        publish_ns: u64,
        seq: u32,
        data: Vec<u8>,
    },
}

/// One of the log's chunks with inputs taken.
struct ChunkState {
    /// Every record taken so far is what the session would write.
    copyable: bool,
    inputs: u64,
    messages: u64,
    /// Copied (true) or written record by record (false).
    decided: Option<bool>,
}

pub(crate) struct Copier {
    /// The session's chunk compression, as a chunk header names it.
    compression: &'static str,
    /// The session's input channels (`/vib`, `/accel`, `/truth`): how many.
    inputs: usize,
    chunks: HashMap<u32, ChunkState>,
    held: VecDeque<Held>,
    held_bytes: usize,
    max_held_bytes: usize,
    /// Buffers of written records, for the next held ones.
    spare: Vec<Vec<u8>>,
    encoded: Vec<u8>,
    record: Vec<u8>,
    pub(crate) copied_chunks: u64,
    /// Chunks written record by record because too much was held.
    pub(crate) given_up_held: u64,
}

impl Copier {
    /// `inputs`: how many of the session's first channels are inputs.
    pub(crate) fn new(compressed: bool, inputs: usize) -> Self {
        Self {
            compression: if compressed { "zstd" } else { "" },
            inputs,
            chunks: HashMap::new(),
            held: VecDeque::new(),
            held_bytes: 0,
            max_held_bytes: held_limit(),
            spare: Vec::new(),
            encoded: Vec::new(),
            record: Vec::new(),
            copied_chunks: 0,
            given_up_held: 0,
        }
    }

    /// An input: `record`, the last one `reader` yielded, to be written on channel
    /// `at` at `log_time_ns` with sequence `seq` (both times the log time).
    pub(crate) fn input(
        &mut self,
        sink: &mut Sink<'_>,
        reader: &mut Reader,
        record: &Record,
        at: usize,
        log_time_ns: u64,
        seq: u32,
    ) -> anyhow::Result<()> {
        let Some((chunk, raw)) = reader.last_raw() else {
            return self.output(sink, at, log_time_ns, seq, &record.message);
        };
        // As `Recorder::write_to` checks it.
        record.message.validate()?;
        record.message.encode(&mut self.encoded)?;
        let same = record.channel_id == sink.channels[at].id()
            && record.sequence == seq
            && record.log_time_ns == log_time_ns
            && record.publish_time_ns == log_time_ns
            && self.encoded == raw;
        if !self.chunks.contains_key(&chunk) {
            let state = self.first_sight(sink, reader, chunk);
            self.chunks.insert(chunk, state);
        }
        let data = self.take_buffer();
        self.hold(Held::Wire {
            at,
            log_time_ns,
            seq,
            data,
            chunk: Some(chunk),
        });
        let Some(state) = self.chunks.get_mut(&chunk) else {
            anyhow::bail!("chunk {chunk} has no state");
        };
        state.inputs += 1;
        state.copyable &= same;
        if state.decided.is_none() {
            if !state.copyable {
                state.decided = Some(false);
            } else if state.inputs == state.messages {
                state.decided = Some(true);
                reader.read_chunk_record(chunk, &mut self.record)?;
                let facts = reader
                    .chunk_facts(chunk)
                    .ok_or_else(|| anyhow::anyhow!("chunk {chunk}: its facts were kept"))?;
                sink.recorder.copy_chunk(facts, &self.record)?;
                for (id, n) in &facts.channel_counts {
                    if let Some(at) = sink.channels.iter().position(|c| c.id() == *id) {
                        sink.counts[at] += n;
                    }
                }
                self.copied_chunks += 1;
            }
        }
        if self.held_bytes > self.max_held_bytes {
            for state in self.chunks.values_mut() {
                if state.decided.is_none() {
                    state.decided = Some(false);
                    self.given_up_held += 1;
                }
            }
        }
        self.drain(sink)
    }

    /// Whether `chunk`, seen for the first time, may be copied at all: only messages,
    /// on the log's channels that are the session's inputs with the same IDs, as the
    /// session compresses, its header's times its messages'.
    fn first_sight(&self, sink: &Sink<'_>, reader: &Reader, chunk: u32) -> ChunkState {
        let Some(f) = reader.chunk_facts(chunk) else {
            return ChunkState {
                copyable: false,
                inputs: 0,
                messages: 0,
                decided: Some(false),
            };
        };
        let inputs = &sink.channels[..self.inputs];
        let copyable = f.only_messages
            && f.header_times_agree
            && f.queued == f.messages
            && f.compression == self.compression
            && f.channel_counts.keys().all(|id| {
                inputs
                    .iter()
                    .any(|c| c.id() == *id && reader.channel_topic(*id) == Some(c.topic()))
            });
        ChunkState {
            copyable,
            inputs: 0,
            messages: f.messages,
            decided: (!copyable).then_some(false),
        }
    }

    /// What the cores made: written at once when nothing is held, else held.
    pub(crate) fn output(
        &mut self,
        sink: &mut Sink<'_>,
        at: usize,
        log_time_ns: u64,
        seq: u32,
        message: &Message,
    ) -> anyhow::Result<()> {
        if self.held.is_empty() {
            sink.recorder
                .write_to(&sink.channels[at], log_time_ns, log_time_ns, seq, *message)?;
            sink.counts[at] += 1;
            return Ok(());
        }
        message.validate()?;
        message.encode(&mut self.encoded)?;
        let data = self.take_buffer();
        self.hold(Held::Wire {
            at,
            log_time_ns,
            seq,
            data,
            chunk: None,
        });
        Ok(())
    }

    /// A view message: written at once when nothing is held, else held.
    pub(crate) fn view(
        &mut self,
        sink: &mut Sink<'_>,
        channel: &ViewChannelId,
        log_time_ns: u64,
        publish_ns: u64,
        seq: u32,
        data: Vec<u8>,
    ) -> anyhow::Result<()> {
        if self.held.is_empty() {
            return write_view(sink, channel, log_time_ns, publish_ns, seq, data);
        }
        self.held_bytes += data.len();
        self.held.push_back(Held::View {
            channel: channel.clone(),
            log_time_ns,
            publish_ns,
            seq,
            data,
        });
        Ok(())
    }

    /// The log is read: every undecided chunk is written record by record.
    pub(crate) fn end(&mut self, sink: &mut Sink<'_>) -> anyhow::Result<()> {
        for state in self.chunks.values_mut() {
            state.decided.get_or_insert(false);
        }
        self.drain(sink)?;
        anyhow::ensure!(self.held.is_empty(), "records held after the log's end");
        Ok(())
    }

    /// Whether nothing is held.
    pub(crate) fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// `self.encoded` in a buffer of its own (a spare one when there is).
    fn take_buffer(&mut self) -> Vec<u8> {
        let mut data = self.spare.pop().unwrap_or_default();
        data.clear();
        data.extend_from_slice(&self.encoded);
        data
    }

    fn hold(&mut self, held: Held) {
        if let Held::Wire { data, .. } = &held {
            self.held_bytes += data.len();
        }
        self.held.push_back(held);
    }

    /// Writes the held records from the front up to the first input of an undecided
    /// chunk; a copied chunk's inputs are dropped.
    fn drain(&mut self, sink: &mut Sink<'_>) -> anyhow::Result<()> {
        while let Some(front) = self.held.front() {
            let decided = match front {
                Held::Wire {
                    chunk: Some(chunk), ..
                } => self.chunks.get(chunk).and_then(|s| s.decided),
                _ => Some(false),
            };
            let Some(copied) = decided else {
                break;
            };
            let Some(held) = self.held.pop_front() else {
                break;
            };
            match held {
                Held::Wire {
                    at,
                    log_time_ns,
                    seq,
                    data,
                    ..
                } => {
                    self.held_bytes -= data.len();
                    if !copied {
                        sink.recorder.write_encoded(
                            &sink.channels[at],
                            log_time_ns,
                            log_time_ns,
                            seq,
                            &data,
                        )?;
                        sink.counts[at] += 1;
                    }
                    self.spare.push(data);
                }
                Held::View {
                    channel,
                    log_time_ns,
                    publish_ns,
                    seq,
                    data,
                } => {
                    self.held_bytes -= data.len();
                    write_view(sink, &channel, log_time_ns, publish_ns, seq, data)?;
                }
            }
        }
        // The spare buffers stay within what was held at most.
        self.spare.truncate(self.held.len().max(64));
        Ok(())
    }
}

/// Writes a view message and counts it.
pub(crate) fn write_view(
    sink: &mut Sink<'_>,
    channel: &ViewChannelId,
    log_time_ns: u64,
    publish_ns: u64,
    seq: u32,
    data: Vec<u8>,
) -> anyhow::Result<()> {
    sink.recorder
        .write_view(channel, log_time_ns, publish_ns, seq, data)?;
    match sink.view_counts.get_mut(channel.topic()) {
        Some(n) => *n += 1,
        None => {
            sink.view_counts.insert(channel.topic().to_string(), 1);
        }
    }
    Ok(())
}
