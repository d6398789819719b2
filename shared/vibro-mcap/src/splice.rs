//! The splice writer: a small MCAP writer that can also take a chunk copied as it is from
//! another MCAP file, its compressed bytes neither decoded nor re-encoded.
//!
//! An offline session that rewrites a log copies its input's chunks still compressed
//! wherever the records it would write are the same bytes: decoding and re-compressing
//! them was most of the session's cost. Its own messages go through
//! [`SpliceWriter::write_message`] into chunks of its own; a copied chunk brings its
//! message index records along, and its chunk index is the source's, moved to where the
//! chunk now lies.
//!
//! The records follow the MCAP specification (<https://mcap.dev/spec>: records are an
//! opcode u8, a length u64 and a body, all little-endian; strings and byte arrays carry a
//! u32 length, maps a u32 length in bytes) and the layouts of the `mcap` crate's writer
//! (0.26, `write.rs` and `records.rs`), serialised by hand. The file position is counted
//! rather than asked of a `Seek`, and the data section CRC is hashed as bytes are written,
//! copied bytes included. Departures from `mcap::Writer`:
//!
//! - schemas and channels are top-level records, written when they are added and so
//!   before the chunks that use them, not inside the first chunk that uses them: a copied
//!   chunk cannot be given them. The spec allows both places; a chunk copied from a file of
//!   `mcap::Writer` may still hold its own copies, identical, which readers accept;
//! - a chunk is compressed whole when it is closed (one `zstd::bulk::Compressor`, reused),
//!   not streamed through an encoder as messages arrive: its uncompressed records are held
//!   in memory, `chunk_size_bytes` plus one message at most;
//! - [`SpliceWriter::copy_chunk`] does not close the open chunk, so the summary's chunk
//!   indexes are sorted by file offset before they are written.

use mcap::records::{op, ChunkIndex, MessageHeader, Metadata, Statistics};
use std::collections::BTreeMap;
use std::io::{self, Write};

/// How a [`SpliceWriter`] writes.
#[derive(Clone, Debug)]
pub(crate) struct SpliceOptions {
    /// The Header record's profile.
    pub profile: String,
    /// The Header record's library.
    pub library: String,
    /// zstd's level for the writer's own chunks. None: chunks uncompressed ("" compression)
    pub zstd_level: Option<i32>,
    /// An own chunk is closed once its uncompressed records reach this many bytes.
    pub chunk_size_bytes: u64,
}

/// A chunk of another MCAP file, to be copied as it is.
pub(crate) struct CopiedChunk<'a> {
    /// The whole chunk record as in the source file: opcode 0x06, u64 length, body.
    pub record: &'a [u8],
    /// The message index records that follow it in the source file, as they are (may be empty).
    pub message_indexes: &'a [u8],
    /// The source file's chunk index for it (times, sizes, compression; offsets are the
    /// SOURCE file's).
    pub index: &'a ChunkIndex,
    /// Messages per channel ID in the chunk (for the statistics).
    pub channel_counts: &'a BTreeMap<u16, u64>,
}

/// The chunk that `write_message` fills.
#[derive(Default)]
struct OpenChunk {
    records: Vec<u8>,
    message_bounds: Option<(u64, u64)>,
    /// Per channel: (log time, offset in `records`) of its messages.
    indexes: BTreeMap<u16, Vec<(u64, u64)>>,
}

#[derive(Clone, Copy, PartialEq)]
enum State {
    Open,
    Finished,
    Failed,
}

/// The output: counts the bytes written and hashes them for the DataEnd record.
struct Sink<W> {
    out: W,
    position: u64,
    data_crc: crc32fast::Hasher,
    state: State,
}

impl<W: Write> Sink<W> {
    fn write(&mut self, bytes: &[u8]) -> io::Result<()> {
        if let Err(e) = self.out.write_all(bytes) {
            // Part of `bytes` may be out: the position is lost, the file unfinishable.
            self.state = State::Failed;
            return Err(e);
        }
        self.data_crc.update(bytes);
        self.position += bytes.len() as u64;
        Ok(())
    }
}

/// An MCAP writer of its own messages and of chunks copied from other files.
pub(crate) struct SpliceWriter<W: Write> {
    sink: Sink<W>,
    chunk_size_bytes: u64,
    compressor: Option<zstd::bulk::Compressor<'static>>,
    compressed: Vec<u8>,
    /// Records being serialised before they are written.
    scratch: Vec<u8>,
    chunk: OpenChunk,
    /// The summary's records, serialised when they are known: Schema and Channel records
    /// by ID, ChunkIndex records by chunk offset, AttachmentIndex and MetadataIndex records
    /// in file order.
    schemas: BTreeMap<u16, Vec<u8>>,
    channels: BTreeMap<u16, Vec<u8>>,
    chunk_indexes: BTreeMap<u64, Vec<u8>>,
    attachment_indexes: Vec<u8>,
    metadata_indexes: Vec<u8>,
    /// Statistics but for the counts of schemas, channels and chunks, and the time span.
    stats: Statistics,
    message_bounds: Option<(u64, u64)>,
}

impl<W: Write> SpliceWriter<W> {
    /// Writes the magic and the Header record.
    pub(crate) fn new(w: W, options: SpliceOptions) -> io::Result<Self> {
        let compressor = match options.zstd_level {
            Some(level) => Some(zstd::bulk::Compressor::new(level)?),
            None => None,
        };
        let mut header = mcap::MAGIC.to_vec();
        record(&mut header, op::HEADER, |b| {
            put_str(b, &options.profile, "header profile")?;
            put_str(b, &options.library, "header library")
        })?;
        let sink = Sink {
            out: w,
            position: 0,
            data_crc: crc32fast::Hasher::new(),
            state: State::Open,
        };
        let mut writer = SpliceWriter {
            sink,
            chunk_size_bytes: options.chunk_size_bytes,
            compressor,
            compressed: Vec::new(),
            scratch: Vec::new(),
            chunk: OpenChunk::default(),
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            chunk_indexes: BTreeMap::new(),
            attachment_indexes: Vec::new(),
            metadata_indexes: Vec::new(),
            stats: Statistics::default(),
            message_bounds: None,
        };
        writer.sink.write(&header)?;
        Ok(writer)
    }

    fn check_open(&self) -> io::Result<()> {
        match self.sink.state {
            State::Open => Ok(()),
            State::Finished => Err(io::Error::other(
                "MCAP splice writer already finished: nothing can follow the footer",
            )),
            State::Failed => Err(io::Error::other(
                "MCAP splice writer: an earlier write to the output failed, the file cannot be finished",
            )),
        }
    }

    /// A top-level Schema record. The same ID again with the same content is a no-op.
    pub(crate) fn add_schema(
        &mut self,
        id: u16,
        name: &str,
        encoding: &str,
        data: &[u8],
    ) -> io::Result<()> {
        self.check_open()?;
        if id == 0 {
            return Err(invalid_input(format!(
                "schema {name:?}: ID 0 is reserved by the MCAP spec (a channel's schema ID 0 means no schema)"
            )));
        }
        let mut schema = Vec::new();
        record(&mut schema, op::SCHEMA, |b| {
            put(b, id.to_le_bytes());
            put_str(b, name, "schema name")?;
            put_str(b, encoding, "schema encoding")?;
            put(b, len_u32(data.len(), "schema data")?.to_le_bytes());
            b.extend_from_slice(data);
            Ok(())
        })?;
        match self.schemas.get(&id) {
            Some(old) if *old == schema => return Ok(()),
            Some(_) => return Err(invalid_input(format!(
                "schema ID {id} is already added with another name, encoding or data, cannot be {name:?} ({encoding:?}, {} bytes): an ID names one schema",
                data.len()
            ))),
            None => {}
        }
        self.sink.write(&schema)?;
        self.schemas.insert(id, schema);
        Ok(())
    }

    /// A top-level Channel record. The same ID again with the same content is a no-op.
    pub(crate) fn add_channel(
        &mut self,
        id: u16,
        schema_id: u16,
        topic: &str,
        message_encoding: &str,
        metadata: &BTreeMap<String, String>,
    ) -> io::Result<()> {
        self.check_open()?;
        if schema_id != 0 && !self.schemas.contains_key(&schema_id) {
            return Err(invalid_input(format!(
                "channel {id} ({topic:?}): schema ID {schema_id} has not been added (add_schema first; 0 means no schema)"
            )));
        }
        let mut channel = Vec::new();
        record(&mut channel, op::CHANNEL, |b| {
            put(b, id.to_le_bytes());
            put(b, schema_id.to_le_bytes());
            put_str(b, topic, "channel topic")?;
            put_str(b, message_encoding, "channel message encoding")?;
            put_str_map(b, metadata, "channel metadata")
        })?;
        match self.channels.get(&id) {
            Some(old) if *old == channel => return Ok(()),
            Some(_) => return Err(invalid_input(format!(
                "channel ID {id} is already added with another schema, topic, encoding or metadata, cannot be {topic:?} (schema {schema_id}, {message_encoding:?}): an ID names one channel"
            ))),
            None => {}
        }
        self.sink.write(&channel)?;
        self.channels.insert(id, channel);
        Ok(())
    }

    /// Appends a Message record to the open chunk, and closes the chunk once its
    /// uncompressed size reaches `chunk_size_bytes`.
    pub(crate) fn write_message(&mut self, header: &MessageHeader, data: &[u8]) -> io::Result<()> {
        self.check_open()?;
        let channel = header.channel_id;
        if !self.channels.contains_key(&channel) {
            return Err(invalid_input(format!(
                "message sequence {} on channel {channel}: channel {channel} has not been added (add_channel first)",
                header.sequence
            )));
        }
        let c = &mut self.chunk;
        let entry = (header.log_time, c.records.len() as u64);
        c.indexes.entry(channel).or_default().push(entry);
        record(&mut c.records, op::MESSAGE, |b| {
            put(b, channel.to_le_bytes());
            put(b, header.sequence.to_le_bytes());
            put(b, header.log_time.to_le_bytes());
            put(b, header.publish_time.to_le_bytes());
            b.extend_from_slice(data);
            Ok(())
        })?;
        c.message_bounds = widen(c.message_bounds, header.log_time, header.log_time);
        let full = c.records.len() as u64 >= self.chunk_size_bytes;
        self.count(channel, 1, header.log_time, header.log_time);
        if full {
            self.close_chunk()?;
        }
        Ok(())
    }

    /// Counts `n` messages on `channel`, logged between `start` and `end`.
    fn count(&mut self, channel: u16, n: u64, start: u64, end: u64) {
        if n > 0 {
            let counts = &mut self.stats.channel_message_counts;
            *counts.entry(channel).or_default() += n;
            self.stats.message_count += n;
            self.message_bounds = widen(self.message_bounds, start, end);
        }
    }

    /// Writes the open chunk (if any) and its message indexes, and keeps its chunk index.
    pub(crate) fn close_chunk(&mut self) -> io::Result<()> {
        self.check_open()?;
        if self.chunk.records.is_empty() {
            return Ok(());
        }
        let records = &self.chunk.records;
        let (compression, data) = match &mut self.compressor {
            Some(compressor) => {
                self.compressed.clear();
                let bound = zstd::zstd_safe::compress_bound(records.len());
                self.compressed.reserve(bound);
                compressor.compress_to_buffer(records.as_slice(), &mut self.compressed)?;
                ("zstd", self.compressed.as_slice())
            }
            None => ("", records.as_slice()),
        };
        let (start, end_time) = self.chunk.message_bounds.unwrap_or((0, 0));
        let b = &mut self.scratch;
        b.clear();
        let body = begin(b, op::CHUNK);
        put(b, start.to_le_bytes());
        put(b, end_time.to_le_bytes());
        put(b, (records.len() as u64).to_le_bytes());
        put(b, crc32fast::hash(records).to_le_bytes());
        put_str(b, compression, "chunk compression")?;
        put(b, (data.len() as u64).to_le_bytes());
        end(b, body, data.len());
        let chunk_start_offset = self.sink.position;
        let chunk_length = (b.len() + data.len()) as u64;
        self.sink.write(&self.scratch)?;
        self.sink.write(data)?;

        let indexes_start = self.sink.position;
        let mut message_index_offsets = BTreeMap::new();
        let b = &mut self.scratch;
        b.clear();
        for (&channel, entries) in &self.chunk.indexes {
            message_index_offsets.insert(channel, indexes_start + b.len() as u64);
            record(b, op::MESSAGE_INDEX, |b| {
                put(b, channel.to_le_bytes());
                put(
                    b,
                    len_u32(entries.len() * 16, "message index")?.to_le_bytes(),
                );
                for &(log_time, offset) in entries {
                    put(b, log_time.to_le_bytes());
                    put(b, offset.to_le_bytes());
                }
                Ok(())
            })?;
        }
        self.sink.write(&self.scratch)?;
        let index = ChunkIndex {
            message_start_time: start,
            message_end_time: end_time,
            chunk_start_offset,
            chunk_length,
            message_index_offsets,
            message_index_length: self.scratch.len() as u64,
            compression: compression.to_owned(),
            compressed_size: data.len() as u64,
            uncompressed_size: records.len() as u64,
        };
        self.keep_chunk_index(&index)?;
        let c = &mut self.chunk;
        c.records.clear();
        c.indexes.clear();
        c.message_bounds = None;
        Ok(())
    }

    fn keep_chunk_index(&mut self, ix: &ChunkIndex) -> io::Result<()> {
        let mut b = Vec::new();
        record(&mut b, op::CHUNK_INDEX, |b| {
            put(b, ix.message_start_time.to_le_bytes());
            put(b, ix.message_end_time.to_le_bytes());
            put(b, ix.chunk_start_offset.to_le_bytes());
            put(b, ix.chunk_length.to_le_bytes());
            put_int_map(b, &ix.message_index_offsets, "chunk message index offsets")?;
            put(b, ix.message_index_length.to_le_bytes());
            put_str(b, &ix.compression, "chunk compression")?;
            put(b, ix.compressed_size.to_le_bytes());
            put(b, ix.uncompressed_size.to_le_bytes());
            Ok(())
        })?;
        self.chunk_indexes.insert(ix.chunk_start_offset, b);
        Ok(())
    }

    /// Writes a chunk record and its message indexes as they are in their source file
    /// (the open chunk stays open), after checking that they agree with the source's index.
    pub(crate) fn copy_chunk(&mut self, chunk: &CopiedChunk<'_>) -> io::Result<()> {
        self.check_open()?;
        let (record, ix, indexes) = (chunk.record, chunk.index, chunk.message_indexes);
        let length_field = read_u64(record, 1);
        if record.first() != Some(&op::CHUNK) || length_field.is_none() {
            return Err(invalid_data(format!(
                "copied chunk record of {} bytes starting with {:02x?}: a chunk record starts with opcode 0x06 and a u64 length",
                record.len(),
                &record[..record.len().min(9)]
            )));
        }
        let body_length = record.len() as u64 - 9;
        if length_field != Some(body_length) {
            return Err(invalid_data(format!(
                "copied chunk record length field = {}: must be the record's length less its opcode and length field, {body_length}",
                length_field.unwrap_or(0)
            )));
        }
        if ix.chunk_length != record.len() as u64 {
            return Err(invalid_data(format!(
                "copied chunk's index chunk_length = {}: must be the record's length, {}",
                ix.chunk_length,
                record.len()
            )));
        }
        // Readers take the chunk's times, sizes and the place of its compressed records
        // from the index: they must be the record's own.
        let head = chunk_head(record);
        let expected = (
            ix.message_start_time,
            ix.message_end_time,
            ix.uncompressed_size,
            ix.compression.as_str(),
            ix.compressed_size,
        );
        if head != Some(expected) {
            return Err(invalid_data(format!(
                "copied chunk record's (start, end, uncompressed size, compression, compressed size) = {head:?}: must be its index's, {expected:?}, with the compressed records filling the record"
            )));
        }
        let source_start = ix.chunk_start_offset;
        let low = source_start.saturating_add(ix.chunk_length);
        let high = low.saturating_add(indexes.len() as u64);
        for (&channel, &offset) in &ix.message_index_offsets {
            // Inside, and on a message index record's opcode.
            if !(low..high).contains(&offset)
                || indexes[(offset - low) as usize] != op::MESSAGE_INDEX
            {
                return Err(invalid_data(format!(
                    "copied chunk's message index offset for channel {channel} = {offset}: must lie inside the message index records that follow the chunk, [{low}, {high}), on an opcode 0x07"
                )));
            }
        }
        let mut channels = chunk
            .channel_counts
            .keys()
            .chain(ix.message_index_offsets.keys());
        if let Some(channel) = channels.find(|c| !self.channels.contains_key(*c)) {
            return Err(invalid_input(format!(
                "copied chunk has messages on channel {channel}: channel {channel} has not been added (add_channel first)"
            )));
        }

        let new_start = self.sink.position;
        self.sink.write(record)?;
        self.sink.write(indexes)?;
        let offsets = ix.message_index_offsets.iter();
        self.keep_chunk_index(&ChunkIndex {
            chunk_start_offset: new_start,
            message_index_offsets: offsets
                .map(|(&channel, &offset)| (channel, offset - source_start + new_start))
                .collect(),
            message_index_length: indexes.len() as u64,
            ..ix.clone()
        })?;
        let (start, end) = (ix.message_start_time, ix.message_end_time);
        for (&channel, &n) in chunk.channel_counts {
            self.count(channel, n, start, end);
        }
        Ok(())
    }

    /// Closes the open chunk, then writes an Attachment record (with its CRC).
    pub(crate) fn attach(&mut self, a: &mcap::Attachment<'_>) -> io::Result<()> {
        self.close_chunk()?;
        let b = &mut self.scratch;
        b.clear();
        let body = begin(b, op::ATTACHMENT);
        put(b, a.log_time.to_le_bytes());
        put(b, a.create_time.to_le_bytes());
        put_str(b, &a.name, "attachment name")?;
        put_str(b, &a.media_type, "attachment media type")?;
        put(b, (a.data.len() as u64).to_le_bytes());
        end(b, body, a.data.len() + 4);
        let mut crc = crc32fast::Hasher::new();
        crc.update(&b[body..]);
        crc.update(&a.data);
        let offset = self.sink.position;
        let length = (b.len() + a.data.len() + 4) as u64;
        self.sink.write(&self.scratch)?;
        self.sink.write(&a.data)?;
        self.sink.write(&crc.finalize().to_le_bytes())?;
        record(&mut self.attachment_indexes, op::ATTACHMENT_INDEX, |b| {
            put(b, offset.to_le_bytes());
            put(b, length.to_le_bytes());
            put(b, a.log_time.to_le_bytes());
            put(b, a.create_time.to_le_bytes());
            put(b, (a.data.len() as u64).to_le_bytes());
            put_str(b, &a.name, "attachment name")?;
            put_str(b, &a.media_type, "attachment media type")
        })?;
        self.stats.attachment_count += 1;
        Ok(())
    }

    /// Closes the open chunk, then writes a Metadata record.
    pub(crate) fn write_metadata(&mut self, m: &Metadata) -> io::Result<()> {
        self.close_chunk()?;
        let b = &mut self.scratch;
        b.clear();
        record(b, op::METADATA, |b| {
            put_str(b, &m.name, "metadata name")?;
            put_str_map(b, &m.metadata, "metadata")
        })?;
        let offset = self.sink.position;
        let length = b.len() as u64;
        self.sink.write(&self.scratch)?;
        record(&mut self.metadata_indexes, op::METADATA_INDEX, |b| {
            put(b, offset.to_le_bytes());
            put(b, length.to_le_bytes());
            put_str(b, &m.name, "metadata name")
        })?;
        self.stats.metadata_count += 1;
        Ok(())
    }

    /// Closes the open chunk and flushes the output.
    pub(crate) fn flush(&mut self) -> io::Result<()> {
        self.close_chunk()?;
        self.sink.out.flush()
    }

    /// Closes the open chunk, writes DataEnd, the summary section, the footer and the
    /// closing magic, and flushes. Returns the statistics written.
    pub(crate) fn finish(&mut self) -> io::Result<Statistics> {
        self.close_chunk()?;
        let mut b = Vec::new();
        let data_crc = self.sink.data_crc.clone().finalize();
        record(&mut b, op::DATA_END, |b| {
            put(b, data_crc.to_le_bytes());
            Ok(())
        })?;
        self.sink.write(&b)?;

        let (start_time, end_time) = self.message_bounds.unwrap_or((0, 0));
        let stats = Statistics {
            schema_count: self.schemas.len() as u16, // IDs 1..=u16::MAX
            channel_count: self.channels.len() as u32,
            chunk_count: self.chunk_indexes.len() as u32,
            message_start_time: start_time,
            message_end_time: end_time,
            ..self.stats.clone()
        };
        let mut statistics = Vec::new();
        record(&mut statistics, op::STATISTICS, |b| {
            put(b, stats.message_count.to_le_bytes());
            put(b, stats.schema_count.to_le_bytes());
            for count in [
                stats.channel_count,
                stats.attachment_count,
                stats.metadata_count,
            ] {
                put(b, count.to_le_bytes());
            }
            put(b, stats.chunk_count.to_le_bytes());
            put(b, stats.message_start_time.to_le_bytes());
            put(b, stats.message_end_time.to_le_bytes());
            put_int_map(b, &stats.channel_message_counts, "channel message counts")
        })?;

        // The summary section, built in memory: its CRC runs from its start through the
        // footer's summary_offset_start field.
        let summary_start = self.sink.position;
        let groups = [
            (op::SCHEMA, cat(&self.schemas)),
            (op::CHANNEL, cat(&self.channels)),
            (op::STATISTICS, statistics),
            (op::CHUNK_INDEX, cat(&self.chunk_indexes)),
            (
                op::ATTACHMENT_INDEX,
                std::mem::take(&mut self.attachment_indexes),
            ),
            (
                op::METADATA_INDEX,
                std::mem::take(&mut self.metadata_indexes),
            ),
        ];
        let mut offsets = Vec::new();
        b.clear();
        for (opcode, group) in groups.iter().filter(|(_, g)| !g.is_empty()) {
            let group_start = summary_start + b.len() as u64;
            record(&mut offsets, op::SUMMARY_OFFSET, |o| {
                o.push(*opcode);
                put(o, group_start.to_le_bytes());
                put(o, (group.len() as u64).to_le_bytes());
                Ok(())
            })?;
            b.extend_from_slice(group);
        }
        let summary_offset_start = summary_start + b.len() as u64;
        b.extend_from_slice(&offsets);
        let body = begin(&mut b, op::FOOTER);
        put(&mut b, summary_start.to_le_bytes());
        put(&mut b, summary_offset_start.to_le_bytes());
        end(&mut b, body, 4); // the length is hashed: set it before the CRC is computed
        let summary_crc = crc32fast::hash(&b);
        put(&mut b, summary_crc.to_le_bytes());
        b.extend_from_slice(mcap::MAGIC);
        self.sink.write(&b)?;
        self.sink.out.flush()?;
        self.sink.state = State::Finished;
        Ok(stats)
    }

    /// The output. Unless [`Self::finish`] was called, it does not hold a complete MCAP file.
    pub(crate) fn into_inner(self) -> W {
        self.sink.out
    }
}

fn invalid_input(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

fn invalid_data(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, message)
}

/// A map's records, in key order.
fn cat<K>(records: &BTreeMap<K, Vec<u8>>) -> Vec<u8> {
    records.values().flatten().copied().collect()
}

fn widen(bounds: Option<(u64, u64)>, start: u64, end: u64) -> Option<(u64, u64)> {
    Some(bounds.map_or((start, end), |(s, e)| (s.min(start), e.max(end))))
}

/// Appends a number's little-endian bytes.
fn put<const N: usize>(b: &mut Vec<u8>, bytes: [u8; N]) {
    b.extend_from_slice(&bytes);
}

fn len_u32(len: usize, what: &str) -> io::Result<u32> {
    u32::try_from(len).map_err(|_| {
        invalid_input(format!(
            "{what} of {len} bytes: more than its u32 length field can say, {}",
            u32::MAX
        ))
    })
}

fn put_str(b: &mut Vec<u8>, s: &str, what: &str) -> io::Result<()> {
    put(b, len_u32(s.len(), what)?.to_le_bytes());
    b.extend_from_slice(s.as_bytes());
    Ok(())
}

/// A string map: its length in bytes, then key, value, key, value...
fn put_str_map(b: &mut Vec<u8>, m: &BTreeMap<String, String>, what: &str) -> io::Result<()> {
    let bytes: usize = m.iter().map(|(k, v)| 8 + k.len() + v.len()).sum();
    put(b, len_u32(bytes, what)?.to_le_bytes());
    for (k, v) in m {
        put_str(b, k, what)?;
        put_str(b, v, what)?;
    }
    Ok(())
}

/// A u16 -> u64 map: its length in bytes, then its entries.
fn put_int_map(b: &mut Vec<u8>, m: &BTreeMap<u16, u64>, what: &str) -> io::Result<()> {
    put(b, len_u32(m.len() * 10, what)?.to_le_bytes());
    for (&k, &v) in m {
        put(b, k.to_le_bytes());
        put(b, v.to_le_bytes());
    }
    Ok(())
}

/// Starts a record: its opcode and a length for [`end`] to set; returns where its body
/// starts.
fn begin(b: &mut Vec<u8>, opcode: u8) -> usize {
    b.push(opcode);
    b.extend_from_slice(&[0; 8]);
    b.len()
}

/// Sets the length of the record whose body starts at `body`: the bytes after it in `b`,
/// plus `after` bytes to be written after `b`.
fn end(b: &mut [u8], body: usize, after: usize) {
    let length = (b.len() - body + after) as u64;
    b[body - 8..body].copy_from_slice(&length.to_le_bytes());
}

/// Appends a record whose body `fill` writes.
fn record(
    b: &mut Vec<u8>,
    opcode: u8,
    fill: impl FnOnce(&mut Vec<u8>) -> io::Result<()>,
) -> io::Result<()> {
    let body = begin(b, opcode);
    fill(b)?;
    end(b, body, 0);
    Ok(())
}

fn read_u64(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

/// A chunk record's (start, end, uncompressed size, compression, compressed size), if its
/// compressed records fill the rest of it exactly.
fn chunk_head(record: &[u8]) -> Option<(u64, u64, u64, &str, u64)> {
    let len = u32::from_le_bytes(record.get(37..41)?.try_into().ok()?) as usize;
    let compression = std::str::from_utf8(record.get(41..41 + len)?).ok()?;
    let compressed_size = read_u64(record, 41 + len)?;
    let fills = (record.len() - (49 + len)) as u64 == compressed_size;
    let size = read_u64(record, 25)?;
    fills.then_some((
        read_u64(record, 9)?,
        read_u64(record, 17)?,
        size,
        compression,
        compressed_size,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcap::read::Options;
    use mcap::sans_io::indexed_reader::{IndexedReadEvent, IndexedReader};
    use mcap::{McapError, MessageStream, Summary};
    use std::borrow::Cow;
    use std::io::Cursor;

    /// (topic, sequence, log time, publish time, data)
    type Msg = (String, u32, u64, u64, Vec<u8>);

    const OWN: u16 = 9;

    fn options(zstd_level: Option<i32>, chunk_size_bytes: u64) -> SpliceOptions {
        let (profile, library) = ("vibrocomp".to_owned(), "vibro-mcap splice".to_owned());
        SpliceOptions {
            profile,
            library,
            zstd_level,
            chunk_size_bytes,
        }
    }

    /// Message `i`'s payload: 0 to 299 bytes, a pattern with noise in it.
    fn payload(i: u64) -> Vec<u8> {
        let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let len = (x % 300) as usize;
        let mut noise = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        };
        (0..len)
            .map(|k| if k % 4 == 0 { noise() } else { (k / 4) as u8 })
            .collect()
    }

    /// A file of `mcap::Writer`: 600 messages on 2 channels in zstd chunks of 4 KiB, every
    /// seventh logged 5 ms early.
    fn source() -> Vec<u8> {
        let options = mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd));
        let mut w = options
            .chunk_size(Some(4096))
            .create(Cursor::new(Vec::new()))
            .unwrap();
        let schema = w
            .add_schema("test.Sample", "protobuf", b"\x0a\x04test")
            .unwrap();
        let rate = BTreeMap::from([("rate_hz".to_owned(), "100".to_owned())]);
        let a = w
            .add_channel(schema, "/a", "protobuf", &BTreeMap::new())
            .unwrap();
        let b = w.add_channel(schema, "/b", "protobuf", &rate).unwrap();
        let mut sequence = [0u32; 2];
        for i in 0..600u64 {
            let k = usize::from(i % 3 == 0);
            sequence[k] += 1;
            let log_time = 1_000_000 + i * 1000 - if i % 7 == 3 { 5000 } else { 0 };
            let (channel_id, publish_time) = ([a, b][k], log_time + 17);
            let header = MessageHeader {
                channel_id,
                sequence: sequence[k],
                log_time,
                publish_time,
            };
            w.write_to_known_channel(&header, &payload(i)).unwrap();
        }
        w.finish().unwrap();
        w.into_inner().into_inner()
    }

    fn add_source_channels(w: &mut SpliceWriter<Vec<u8>>, summary: &Summary) {
        for (&id, s) in summary.schemas.iter().collect::<BTreeMap<_, _>>() {
            w.add_schema(id, &s.name, &s.encoding, &s.data).unwrap();
        }
        for (&id, c) in summary.channels.iter().collect::<BTreeMap<_, _>>() {
            let schema = c.schema.as_ref().map_or(0, |s| s.id);
            w.add_channel(id, schema, &c.topic, &c.message_encoding, &c.metadata)
                .unwrap();
        }
    }

    fn msg(m: &mcap::Message) -> Msg {
        let topic = m.channel.topic.clone();
        (
            topic,
            m.sequence,
            m.log_time,
            m.publish_time,
            m.data.to_vec(),
        )
    }

    /// Messages in file order, chunk CRCs checked.
    fn stream(file: &[u8]) -> Vec<Msg> {
        let stream = MessageStream::new_with_options(file, Options::ValidateChunkCrcs.into());
        stream.unwrap().map(|m| msg(&m.unwrap())).collect()
    }

    /// Messages in log-time order through the summary's chunk indexes.
    fn indexed(file: &[u8], summary: &Summary) -> Vec<Msg> {
        let mut reader = IndexedReader::new(summary).unwrap();
        let mut messages = Vec::new();
        while let Some(event) = reader.next_event() {
            match event.unwrap() {
                IndexedReadEvent::ReadChunkRequest { offset, length } => {
                    let data = &file[offset as usize..offset as usize + length];
                    reader.insert_chunk_record_data(offset, data).unwrap();
                }
                IndexedReadEvent::Message { header, data } => {
                    let topic = summary.channels[&header.channel_id].topic.clone();
                    let (log, publish) = (header.log_time, header.publish_time);
                    messages.push((topic, header.sequence, log, publish, data.to_vec()));
                }
            }
        }
        messages
    }

    fn attachment() -> mcap::Attachment<'static> {
        let (name, media_type) = ("triad.toml".to_owned(), "application/toml".to_owned());
        let data = Cow::Borrowed(&b"[triad]\nk2_ppm_per_g = 3.5\n"[..]);
        mcap::Attachment {
            log_time: 5,
            create_time: 6,
            name,
            media_type,
            data,
        }
    }

    fn metadata() -> Metadata {
        let metadata = BTreeMap::from([("input".to_owned(), "flight.mcap".to_owned())]);
        Metadata {
            name: "session".to_owned(),
            metadata,
        }
    }

    /// The source's chunks copied between own messages on channel OWN ("/own"), with an
    /// attachment and a metadata record: the file, the own messages, `finish`'s statistics.
    fn splice(src: &[u8]) -> (Vec<u8>, Vec<Msg>, Statistics) {
        let summary = Summary::read(src).unwrap().unwrap();
        let mut w = SpliceWriter::new(Vec::new(), options(Some(3), 1500)).unwrap();
        add_source_channels(&mut w, &summary);
        w.add_schema(7, "own", "jsonschema", b"{}").unwrap();
        w.add_channel(OWN, 7, "/own", "json", &BTreeMap::new())
            .unwrap();
        let mut own = Vec::new();
        for (i, ix) in summary.chunk_indexes.iter().enumerate() {
            for k in 0..12 {
                let (sequence, log_time) = (own.len() as u32, ix.message_start_time + k * 333);
                let data = payload(10_000 + k + 12 * i as u64);
                let header = MessageHeader {
                    channel_id: OWN,
                    sequence,
                    log_time,
                    publish_time: log_time + 1,
                };
                w.write_message(&header, &data).unwrap();
                own.push(("/own".to_owned(), sequence, log_time, log_time + 1, data));
            }
            let indexes = summary.read_message_indexes(src, ix).unwrap();
            let counts = indexes
                .iter()
                .map(|(c, e)| (c.id, e.len() as u64))
                .collect();
            let start = ix.chunk_start_offset as usize;
            let end = start + ix.chunk_length as usize;
            w.copy_chunk(&CopiedChunk {
                record: &src[start..end],
                message_indexes: &src[end..end + ix.message_index_length as usize],
                index: ix,
                channel_counts: &counts,
            })
            .unwrap();
            match i {
                1 => w.attach(&attachment()).unwrap(),
                2 => w.write_metadata(&metadata()).unwrap(),
                _ => {}
            }
        }
        let stats = w.finish().unwrap();
        (w.into_inner(), own, stats)
    }

    fn sorted(mut messages: Vec<Msg>) -> Vec<Msg> {
        messages.sort();
        messages
    }

    fn le_u64(file: &[u8], at: u64) -> u64 {
        u64::from_le_bytes(file[at as usize..at as usize + 8].try_into().unwrap())
    }

    /// Checks DataEnd's CRC (every byte before it) and the footer's (the summary section
    /// through the footer's summary_offset_start field, [spec, Footer]).
    fn check_crcs(file: &[u8]) -> mcap::records::Footer {
        let footer = mcap::read::footer(file).unwrap();
        let data_end = footer.summary_start as usize - 13;
        let record = &file[data_end..data_end + 13];
        assert_eq!(record[..9], [op::DATA_END, 4, 0, 0, 0, 0, 0, 0, 0]);
        let data_crc = crc32fast::hash(&file[..data_end]).to_le_bytes();
        assert_eq!(record[9..], data_crc, "data section CRC");
        let summary = &file[footer.summary_start as usize..file.len() - 8 - 4];
        assert_eq!(footer.summary_crc, crc32fast::hash(summary), "summary CRC");
        footer
    }

    #[test]
    fn copied_chunks_and_own_messages_read_back_through_stream_and_indexes() {
        let src = source();
        let source_chunks = Summary::read(&src).unwrap().unwrap().chunk_indexes.len();
        assert!(source_chunks >= 5, "{source_chunks} source chunks");
        let (out, own, stats) = splice(&src);
        let mut expected = stream(&src);
        expected.extend(own.iter().cloned());
        let expected = sorted(expected);
        assert_eq!(sorted(stream(&out)), expected);

        let summary = Summary::read(&out).unwrap().unwrap();
        let by_log_time = indexed(&out, &summary);
        assert!(
            by_log_time.windows(2).all(|w| w[0].2 <= w[1].2),
            "not in log-time order"
        );
        assert_eq!(sorted(by_log_time), expected);

        // Statistics, against the messages themselves.
        let count = |t: &str| expected.iter().filter(|m| m.0 == t).count() as u64;
        let topics = summary
            .channels
            .iter()
            .map(|(&id, c)| (c.topic.as_str(), id));
        let topics: BTreeMap<_, _> = topics.collect();
        assert_eq!(
            topics.keys().copied().collect::<Vec<_>>(),
            ["/a", "/b", "/own"]
        );
        assert_eq!(topics["/own"], OWN);
        let own_chunks = summary.chunk_indexes.len() - source_chunks;
        assert!(own_chunks >= source_chunks, "{own_chunks} own chunks");
        let expected_stats = Statistics {
            message_count: expected.len() as u64,
            schema_count: 2,
            channel_count: 3,
            attachment_count: 1,
            metadata_count: 1,
            chunk_count: summary.chunk_indexes.len() as u32,
            message_start_time: expected.iter().map(|m| m.2).min().unwrap(),
            message_end_time: expected.iter().map(|m| m.2).max().unwrap(),
            channel_message_counts: topics.iter().map(|(t, &id)| (id, count(t))).collect(),
        };
        assert_eq!(stats, expected_stats);
        assert_eq!(summary.stats, Some(expected_stats));

        // Chunk and message indexes point at their records, and each entry at its message.
        let expected_set: std::collections::BTreeSet<_> = expected.iter().collect();
        let mut entries = 0;
        let offsets = summary.chunk_indexes.iter().map(|ix| ix.chunk_start_offset);
        assert!(offsets.clone().zip(offsets.skip(1)).all(|(a, b)| a < b));
        for ix in &summary.chunk_indexes {
            assert_eq!(out[ix.chunk_start_offset as usize], op::CHUNK);
            assert!(ix
                .message_index_offsets
                .values()
                .all(|&o| out[o as usize] == 0x07));
            for (_, index) in summary.read_message_indexes(&out, ix).unwrap() {
                for entry in index {
                    let m = msg(&summary.seek_message(&out, ix, &entry).unwrap());
                    assert_eq!(m.2, entry.log_time);
                    assert!(expected_set.contains(&m), "{m:?}");
                    entries += 1;
                }
            }
        }
        assert_eq!(entries, expected.len());

        // The attachment (and its CRC) and the metadata.
        let ai = &summary.attachment_indexes[..];
        assert_eq!(mcap::read::attachment(&out, &ai[0]).unwrap(), attachment());
        let record = &out[ai[0].offset as usize..(ai[0].offset + ai[0].length) as usize];
        let (body, crc) = record[9..].split_at(record.len() - 13);
        assert_eq!(crc32fast::hash(body).to_le_bytes(), crc);
        let mi = &summary.metadata_indexes[..];
        assert_eq!(mcap::read::metadata(&out, &mi[0]).unwrap(), metadata());

        // The CRCs, computed here as for the file of mcap::Writer; each summary offset
        // points at a group of its opcode.
        check_crcs(&src);
        let footer = check_crcs(&out);
        let footer_at = (out.len() - 8 - 29) as u64;
        assert_eq!(out[footer_at as usize], op::FOOTER);
        let mut groups = Vec::new();
        let mut at = footer.summary_offset_start;
        while at < footer_at {
            assert_eq!(out[at as usize], op::SUMMARY_OFFSET);
            let (opcode, start) = (out[at as usize + 9], le_u64(&out, at + 10));
            assert_eq!(out[start as usize], opcode);
            assert!(le_u64(&out, at + 18) > 0, "an empty group");
            groups.push(opcode);
            at += 9 + le_u64(&out, at + 1);
        }
        assert_eq!(groups, [0x03, 0x04, 0x0B, 0x08, 0x0A, 0x0D]);
    }

    #[test]
    fn own_messages_read_back_as_mcap_writer_wrote_them() {
        let src = source();
        let summary = Summary::read(&src).unwrap().unwrap();
        let expected = stream(&src);
        for level in [Some(1), None] {
            let mut w = SpliceWriter::new(Vec::new(), options(level, 4096)).unwrap();
            add_source_channels(&mut w, &summary);
            for m in MessageStream::new(&src).unwrap() {
                let m = m.unwrap();
                let header = MessageHeader {
                    channel_id: m.channel.id,
                    sequence: m.sequence,
                    log_time: m.log_time,
                    publish_time: m.publish_time,
                };
                w.write_message(&header, &m.data).unwrap();
            }
            let stats = w.finish().unwrap();
            let mut out = w.into_inner();
            assert_eq!(stream(&out), expected, "zstd level {level:?}");
            let out_summary = Summary::read(&out).unwrap().unwrap();
            assert_eq!(indexed(&out, &out_summary), indexed(&src, &summary));
            let chunk_count = stats.chunk_count;
            assert!(chunk_count > 5, "{chunk_count} chunks");
            let source_stats = summary.stats.clone().unwrap();
            assert_eq!(
                stats,
                Statistics {
                    chunk_count,
                    ..source_stats
                }
            );
            assert_eq!(out_summary.stats, Some(stats));
            let compression = level.map_or("", |_| "zstd");
            assert!(out_summary
                .chunk_indexes
                .iter()
                .all(|ix| ix.compression == compression));

            // mcap's reader checks the chunk CRC: a changed byte in a chunk fails it.
            let at = out_summary.chunk_indexes[3]
                .compressed_data_offset()
                .unwrap()
                + 30;
            out[at as usize] ^= 0x40;
            let error = MessageStream::new_with_options(&out, Options::ValidateChunkCrcs.into())
                .unwrap()
                .find_map(Result::err);
            if level.is_none() {
                assert!(
                    matches!(error, Some(McapError::BadChunkCrc { .. })),
                    "{error:?}"
                );
            } else {
                assert!(error.is_some(), "a changed zstd frame read back");
            }
        }
    }

    #[test]
    fn refuses_inconsistent_chunks_unknown_ids_and_conflicting_schemas() {
        let src = source();
        let summary = Summary::read(&src).unwrap().unwrap();
        let ix = &summary.chunk_indexes[0];
        let start = ix.chunk_start_offset as usize;
        let end = start + ix.chunk_length as usize;
        let indexes = &src[end..end + ix.message_index_length as usize];
        let counts = BTreeMap::new();
        let copied = |record, index| CopiedChunk {
            record,
            message_indexes: indexes,
            index,
            channel_counts: &counts,
        };
        let mut w = SpliceWriter::new(Vec::new(), options(Some(1), 4096)).unwrap();
        add_source_channels(&mut w, &summary);
        let written = w.sink.position;
        let refused = |e: io::Error, kind, parts: &[&str]| {
            assert_eq!(e.kind(), kind, "{e}");
            assert!(parts.iter().all(|p| e.to_string().contains(p)), "{e}");
        };

        let mut record = src[start..end].to_vec();
        let length = record.len() as u64 - 9 + 1;
        record[1..9].copy_from_slice(&length.to_le_bytes());
        let e = w.copy_chunk(&copied(&record, ix)).unwrap_err();
        let rule = format!("length field = {length}: must be the record's length less");
        refused(e, io::ErrorKind::InvalidData, &[&rule]);

        let mut moved = ix.clone();
        // One past the end of the message indexes (the chunk is at the same place here).
        let past = (end + indexes.len()) as u64;
        let (&channel, offset) = moved.message_index_offsets.iter_mut().next().unwrap();
        *offset = past;
        let value = format!("channel {channel} = {past}: must lie inside");
        let e = w.copy_chunk(&copied(&src[start..end], &moved)).unwrap_err();
        refused(
            e,
            io::ErrorKind::InvalidData,
            &[&value, &format!("[{end}, {past})")],
        );
        assert_eq!(w.sink.position, written, "a refused chunk wrote something");
        w.copy_chunk(&copied(&src[start..end], ix)).unwrap();

        let header = MessageHeader {
            channel_id: 42,
            sequence: 5,
            log_time: 1,
            publish_time: 1,
        };
        let e = w.write_message(&header, b"x").unwrap_err();
        refused(
            e,
            io::ErrorKind::InvalidInput,
            &["channel 42 has not been added"],
        );
        let e = w
            .add_channel(3, 5, "/c", "json", &BTreeMap::new())
            .unwrap_err();
        refused(
            e,
            io::ErrorKind::InvalidInput,
            &["\"/c\"", "schema ID 5 has not been added"],
        );
        let (&id, s) = summary.schemas.iter().next().unwrap();
        w.add_schema(id, &s.name, &s.encoding, &s.data).unwrap(); // the same: a no-op
        let e = w
            .add_schema(id, &s.name, &s.encoding, b"other")
            .unwrap_err();
        let value = format!("schema ID {id} is already added");
        refused(
            e,
            io::ErrorKind::InvalidInput,
            &[&value, "an ID names one schema"],
        );

        w.finish().unwrap();
        let header = MessageHeader {
            channel_id: 0,
            ..header
        };
        assert!(w.write_message(&header, b"x").is_err());
        assert!(w.finish().is_err());
    }

    #[test]
    fn python_mcap_reads_spliced_file() {
        let python = std::process::Command::new("python3")
            .args(["-c", "import mcap"])
            .output();
        if !python.is_ok_and(|o| o.status.success()) {
            eprintln!("skipped: python3 with the mcap package is not available");
            return;
        }
        let src = source();
        let (out, own, stats) = splice(&src);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("spliced.mcap");
        std::fs::write(&path, &out).unwrap();
        let script = r#"
import collections, json, sys
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.records import Message
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f, validate_crcs=True)
    counts = collections.Counter(c.topic for _, c, _ in reader.iter_messages())
    summary = reader.get_summary()
with open(sys.argv[1], "rb") as f:
    streamed = sum(isinstance(r, Message) for r in StreamReader(f, validate_crcs=True).records)
print(json.dumps({"counts": counts, "streamed": streamed,
    "message_count": summary.statistics.message_count,
    "chunks": len(summary.chunk_indexes), "attachments": len(summary.attachment_indexes),
    "metadata": len(summary.metadata_indexes)}))
"#;
        let output = std::process::Command::new("python3")
            .args(["-c", script])
            .arg(&path)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "python: {stderr}");
        let got: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        let source = stream(&src);
        let count = |t: &str| source.iter().filter(|m| m.0 == t).count();
        let total = source.len() + own.len();
        let expected = serde_json::json!({
            "counts": {"/a": count("/a"), "/b": count("/b"), "/own": own.len()},
            "streamed": total, "message_count": total, "chunks": stats.chunk_count,
            "attachments": 1, "metadata": 1,
        });
        assert_eq!(got, expected);
    }
}
