//! Reading a finished recording in log-time order.
//!
//! The summary section gives the channels and the chunk index. Chunks are read from the
//! file one at a time, in order of their first log time, and their messages are merged
//! through a min-heap keyed by (log time, position in the file): a chunk is loaded as
//! soon as it could hold the next message, so overlapping chunks (several writers'
//! messages interleaved out of order) still come out sorted, and memory holds only the
//! chunks that overlap. Each chunk's CRC is checked when it is read (`mcap`'s chunk
//! reader), before any of its messages is yielded.

use crate::guard;
use crate::schema::{is_view_schema, kind_of_schema, MESSAGE_ENCODING, SCHEMA_ENCODING};
use crate::{Error, Message, Result};
use mcap::records::{op, ChunkIndex, Record as McapRecord};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use std::cmp::{Ordering, Reverse};
use std::collections::{BTreeMap, BinaryHeap, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vibro_msgs::MessageKind;

/// What a [`Reader`] reads from: a file, or a recording held in memory.
trait Source: Read + Seek + Send + Sync {}
impl<T: Read + Seek + Send + Sync> Source for T {}

/// One decoded message with its MCAP header fields.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// The channel's topic.
    pub topic: Arc<str>,
    /// The MCAP channel ID.
    pub channel_id: u16,
    /// The publisher's sequence number (32 bits in MCAP).
    pub sequence: u32,
    /// When the message was received (the order of iteration).
    pub log_time_ns: u64,
    /// When the message was published.
    pub publish_time_ns: u64,
    /// The decoded message.
    pub message: Message,
}

/// A message waiting in the merge heap: still protobuf bytes, so that the heap moves
/// small values and holds the chunk's compact form, not 12 KiB wire structs.
struct Pending {
    log_time_ns: u64,
    order: u64,
    /// The chunk it came from: its place in `Reader::chunks`.
    chunk: u32,
    channel_id: u16,
    sequence: u32,
    publish_time_ns: u64,
    data: Vec<u8>,
}

impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Pending {
    fn cmp(&self, other: &Self) -> Ordering {
        (self.log_time_ns, self.order).cmp(&(other.log_time_ns, other.order))
    }
}

#[derive(Clone)]
struct ChannelEntry {
    topic: Arc<str>,
    kind: MessageKind,
}

/// One message of a selected channel as its bytes, undecoded: a view channel's
/// (`vibrocomp.view.v1`, `foxglove.Log`), whose types are not wire types, or a wire
/// channel's read by [`Reader::next_raw`].
#[derive(Clone, Debug, PartialEq)]
pub struct RawRecord {
    /// The channel's topic.
    pub topic: Arc<str>,
    /// The channel's schema name (`vibrocomp.v1.AccelBlock`, `vibrocomp.view.v1.UnitStages`).
    pub schema: Arc<str>,
    /// The publisher's sequence number (32 bits in MCAP).
    pub sequence: u32,
    /// When the message was received (the order of iteration).
    pub log_time_ns: u64,
    /// When the message was published.
    pub publish_time_ns: u64,
    /// The message's protobuf bytes.
    pub data: Vec<u8>,
}

/// What a chunk held when it was read, for copying it into another file as it is
/// ([`Reader::keep_chunk_facts`]): its messages as found in its records, not as its
/// index says.
#[derive(Clone, Debug, PartialEq)]
pub struct ChunkFacts {
    /// Where the chunk record starts in the file.
    pub start: u64,
    /// The chunk record's length, opcode and length prefix included.
    pub length: u64,
    /// CRC32 of the chunk record's bytes as they were read (checked again when they
    /// are read for copying: [`Reader::read_chunk_record`]).
    pub record_crc: u32,
    /// The chunk header's compression (`""` or `"zstd"`).
    pub compression: String,
    /// The chunk header's sizes.
    pub compressed_bytes: u64,
    pub uncompressed_bytes: u64,
    /// First and last log time of its messages (0 and 0 without messages).
    pub message_start_ns: u64,
    pub message_end_ns: u64,
    /// The chunk header's times equal them.
    pub header_times_agree: bool,
    /// Every record of the chunk is a message (no schema, channel or other record).
    pub only_messages: bool,
    /// Message records in the chunk.
    pub messages: u64,
    /// Those of a channel this reader yields (queued).
    pub queued: u64,
    /// Messages per channel ID.
    pub channel_counts: BTreeMap<u16, u64>,
    /// The chunk's message index records (MCAP opcode 0x07, one per channel in ID
    /// order), made from its records: the file's own are neither read nor trusted.
    pub message_indexes: Vec<u8>,
    /// Where each channel's record starts in `message_indexes`.
    pub message_index_offsets: BTreeMap<u16, u64>,
}

/// Iterates over the messages of a finished MCAP file in log-time order (ties in file
/// order), decoded into [`Message`]s. Channels whose schema is not a `vibrocomp.v1`
/// message are skipped (see [`Reader::foreign_topics`]).
pub struct Reader {
    path: PathBuf,
    file: Box<dyn Source>,
    file_bytes: u64,
    channels: HashMap<u16, ChannelEntry>,
    /// The view channels by ID: topic and schema name, read raw once selected.
    views: HashMap<u16, (Arc<str>, Arc<str>)>,
    /// The channels [`Reader::select_topics`] kept (`None`: every wire channel).
    selected: Option<std::collections::HashSet<u16>>,
    foreign_topics: Vec<String>,
    view_topics: Vec<String>,
    chunks: Vec<ChunkIndex>,
    next_chunk: usize,
    pending: BinaryHeap<Reverse<Pending>>,
    next_order: u64,
    chunk_buf: Vec<u8>,
    /// A zstd chunk's records.
    decompressed: Vec<u8>,
    summary: mcap::Summary,
    failed: bool,
    /// Per chunk (as `chunks`), once read, when [`Reader::keep_chunk_facts`] asked.
    facts: Option<Vec<Option<ChunkFacts>>>,
    /// The chunk and protobuf bytes of the last message yielded by `next`.
    last: Option<(u32, Vec<u8>)>,
}

impl Reader {
    /// Opens `path` and reads its summary section. A file without one (a crash, see
    /// [`crate::recover`]) is [`Error::NotFinished`].
    pub fn open(path: impl AsRef<Path>) -> Result<Reader> {
        let path = path.as_ref();
        let file = File::open(path).map_err(|e| Error::io("open", path, e))?;
        Reader::from_reader(file, path)
    }

    /// Reads a recording from `source` (a file, or a `Cursor` over bytes in memory);
    /// `name` stands for the file in errors. As [`Reader::open`] otherwise.
    pub fn from_reader(
        source: impl Read + Seek + Send + Sync + 'static,
        name: impl AsRef<Path>,
    ) -> Result<Reader> {
        let path = name.as_ref().to_path_buf();
        let mut file: Box<dyn Source> = Box::new(source);
        let file_bytes = file
            .seek(SeekFrom::End(0))
            .map_err(|e| Error::io("seek in", &path, e))?;
        check_summary(&path, &mut file, file_bytes)?;
        let summary =
            read_summary(&path, &mut file, file_bytes)?.ok_or_else(|| Error::NotFinished {
                path: path.clone(),
                what: "no summary section",
            })?;
        let message_count = summary.stats.as_ref().map_or(0, |s| s.message_count);
        if summary.chunk_indexes.is_empty() && message_count > 0 {
            return Err(Error::NotFinished {
                path,
                what: "no chunk index",
            });
        }
        let mut channels = HashMap::new();
        let mut views = HashMap::new();
        let mut foreign_topics = Vec::new();
        let mut view_topics = Vec::new();
        for (&id, channel) in &summary.channels {
            let kind = channel
                .schema
                .as_ref()
                .filter(|s| s.encoding == SCHEMA_ENCODING)
                .filter(|_| channel.message_encoding == MESSAGE_ENCODING)
                .and_then(|s| kind_of_schema(&s.name));
            match kind {
                Some(kind) => {
                    channels.insert(
                        id,
                        ChannelEntry {
                            topic: Arc::from(channel.topic.as_str()),
                            kind,
                        },
                    );
                }
                None if channel
                    .schema
                    .as_ref()
                    .is_some_and(|s| is_view_schema(&s.name)) =>
                {
                    let schema = channel.schema.as_ref().map_or("", |s| s.name.as_str());
                    views.insert(id, (Arc::from(channel.topic.as_str()), Arc::from(schema)));
                    view_topics.push(channel.topic.clone())
                }
                None => foreign_topics.push(channel.topic.clone()),
            }
        }
        foreign_topics.sort();
        view_topics.sort();
        let mut chunks = summary.chunk_indexes.clone();
        chunks.sort_by_key(|c| (c.message_start_time, c.chunk_start_offset));
        Ok(Reader {
            path,
            file,
            file_bytes,
            channels,
            views,
            selected: None,
            foreign_topics,
            view_topics,
            chunks,
            next_chunk: 0,
            pending: BinaryHeap::new(),
            next_order: 0,
            chunk_buf: Vec::new(),
            decompressed: Vec::new(),
            summary,
            failed: false,
            facts: None,
            last: None,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Reads only the channels on `topics` (wire or view channels) from here on: the
    /// other channels' messages are neither decoded nor queued, and a chunk whose index
    /// lists none of the selected channels is not read at all. A topic the log does not
    /// have is [`Error::NoSuchTopic`]. Call it before the first message is read.
    pub fn select_topics(&mut self, topics: &[&str]) -> Result<()> {
        let mut ids = std::collections::HashSet::new();
        for topic in topics {
            let wire = self.channels.iter().map(|(id, c)| (id, &c.topic));
            let view = self.views.iter().map(|(id, (t, _))| (id, t));
            let found: Vec<u16> = wire
                .chain(view)
                .filter(|(_, t)| &***t == *topic)
                .map(|(id, _)| *id)
                .collect();
            if found.is_empty() {
                return Err(Error::NoSuchTopic {
                    path: self.path.clone(),
                    topic: (*topic).to_string(),
                });
            }
            ids.extend(found);
        }
        // A chunk index lists the channels its chunk holds (its message index offsets);
        // one that lists none at all says nothing and is read.
        self.chunks.retain(|c| {
            c.message_index_offsets.is_empty()
                || c.message_index_offsets.keys().any(|id| ids.contains(id))
        });
        self.selected = Some(ids);
        Ok(())
    }

    /// Keeps, for every chunk read from here on, what it held ([`ChunkFacts`]): for
    /// copying a chunk as it is ([`Reader::read_chunk_record`]) once every one of its
    /// messages was taken through [`Reader::last_raw`]. Call it before the first
    /// message is read.
    pub fn keep_chunk_facts(&mut self) {
        self.facts = Some(vec![None; self.chunks.len()]);
    }

    /// What chunk `chunk` (as [`Reader::last_raw`] numbers it) held, once read with
    /// [`Reader::keep_chunk_facts`] on.
    pub fn chunk_facts(&self, chunk: u32) -> Option<&ChunkFacts> {
        self.facts.as_ref()?.get(chunk as usize)?.as_ref()
    }

    /// The chunk and the protobuf bytes of the last message the iteration yielded.
    pub fn last_raw(&self) -> Option<(u32, &[u8])> {
        self.last.as_ref().map(|(c, d)| (*c, d.as_slice()))
    }

    /// The bytes of chunk `chunk`'s record (opcode and length prefix included) into
    /// `buf`, read again from the file and checked against the CRC taken when it was
    /// first read: a file changed since is [`Error::ChangedWhileRead`].
    pub fn read_chunk_record(&mut self, chunk: u32, buf: &mut Vec<u8>) -> Result<()> {
        let facts = self.chunk_facts(chunk).ok_or_else(|| Error::Mcap {
            path: self.path.clone(),
            source: mcap::McapError::BadIndex,
        })?;
        let (start, length, crc) = (facts.start, facts.length, facts.record_crc);
        read_record(
            &self.path,
            &mut self.file,
            self.file_bytes,
            buf,
            start,
            length,
            op::CHUNK,
        )?;
        if crc32fast::hash(buf) != crc {
            return Err(Error::ChangedWhileRead {
                path: self.path.clone(),
                offset: start,
            });
        }
        Ok(())
    }

    /// The next message of a selected channel in log-time order, undecoded (view
    /// channels too). After an error it returns `None`.
    pub fn next_raw(&mut self) -> Option<Result<RawRecord>> {
        if self.failed {
            return None;
        }
        loop {
            let p = match self.next_pending() {
                Ok(p) => p?,
                Err(e) => {
                    self.failed = true;
                    return Some(Err(e));
                }
            };
            // Only known channels are queued (`queued`).
            let (topic, schema) = match (
                self.channels.get(&p.channel_id),
                self.views.get(&p.channel_id),
            ) {
                (Some(c), _) => (Arc::clone(&c.topic), Arc::from(crate::schema(c.kind).name)),
                (None, Some((t, s))) => (Arc::clone(t), Arc::clone(s)),
                (None, None) => continue,
            };
            return Some(Ok(RawRecord {
                topic,
                schema,
                sequence: p.sequence,
                log_time_ns: p.log_time_ns,
                publish_time_ns: p.publish_time_ns,
                data: p.data,
            }));
        }
    }

    /// Whether messages of channel `id` are queued: a selected channel, or without a
    /// selection every wire channel.
    fn queued(&self, id: u16) -> bool {
        match &self.selected {
            Some(ids) => ids.contains(&id),
            None => self.channels.contains_key(&id),
        }
    }

    /// `(topic, message kind)` of every channel that will be decoded, sorted by topic.
    pub fn channels(&self) -> Vec<(String, MessageKind)> {
        let mut out: Vec<_> = self
            .channels
            .values()
            .map(|c| (c.topic.to_string(), c.kind))
            .collect();
        out.sort();
        out
    }

    /// `(topic, schema name)` of every channel in the summary (foreign ones too), in
    /// channel ID order; a channel without a schema has an empty name.
    pub fn topics(&self) -> Vec<(String, String)> {
        self.summary
            .channels
            .values()
            .map(|c| {
                let schema = c.schema.as_ref().map_or("", |s| s.name.as_str());
                (c.topic.clone(), schema.to_string())
            })
            .collect()
    }

    /// The ID of the first channel on `topic`, if the file has one.
    pub fn channel_id(&self, topic: &str) -> Option<u16> {
        self.summary
            .channels
            .values()
            .find(|c| c.topic == topic)
            .map(|c| c.id)
    }

    /// The topic of channel `id`, if the file has it.
    pub fn channel_topic(&self, id: u16) -> Option<&str> {
        self.summary.channels.get(&id).map(|c| c.topic.as_str())
    }

    /// Topics of channels that are not `vibrocomp.v1` messages; their messages are skipped.
    pub fn foreign_topics(&self) -> &[String] {
        &self.foreign_topics
    }

    /// Topics of the view channels (`vibrocomp.view.v1` schemas, docs/view.md): made
    /// from the wire streams to be plotted, skipped like foreign ones.
    pub fn view_topics(&self) -> &[String] {
        &self.view_topics
    }

    /// Messages on `topic` according to the file's statistics record, if it has one.
    pub fn topic_message_count(&self, topic: &str) -> Option<u64> {
        let stats = self.summary.stats.as_ref()?;
        let ids = self.summary.channels.values().filter(|c| c.topic == topic);
        Some(
            ids.map(|c| {
                stats
                    .channel_message_counts
                    .get(&c.id)
                    .copied()
                    .unwrap_or(0)
            })
            .sum(),
        )
    }

    /// Messages in the file according to its statistics record, if it has one.
    pub fn message_count(&self) -> Option<u64> {
        self.summary.stats.as_ref().map(|s| s.message_count)
    }

    /// Names of the attachments, in file order.
    pub fn attachment_names(&self) -> Vec<String> {
        self.summary
            .attachment_indexes
            .iter()
            .map(|a| a.name.clone())
            .collect()
    }

    /// `(name, media type)` of every attachment, in file order.
    pub fn attachment_types(&self) -> Vec<(String, String)> {
        self.summary
            .attachment_indexes
            .iter()
            .map(|a| (a.name.clone(), a.media_type.clone()))
            .collect()
    }

    /// The content of the first attachment called `name`, if any.
    pub fn read_attachment(&mut self, name: &str) -> Result<Option<Vec<u8>>> {
        let Some(index) = self
            .summary
            .attachment_indexes
            .iter()
            .find(|a| a.name == name)
            .cloned()
        else {
            return Ok(None);
        };
        let mut buf = std::mem::take(&mut self.chunk_buf);
        let read = read_record(
            &self.path,
            &mut self.file,
            self.file_bytes,
            &mut buf,
            index.offset,
            index.length,
            op::ATTACHMENT,
        );
        let parsed = read
            .and_then(|body| guard::parse(&self.path, op::ATTACHMENT, body))
            .map(McapRecord::into_owned);
        self.chunk_buf = buf;
        match parsed? {
            McapRecord::Attachment { data, .. } => Ok(Some(data.into_owned())),
            _ => Ok(None),
        }
    }

    /// Every metadata record, `(name, entries)`, in file order.
    pub fn metadata(&mut self) -> Result<Vec<(String, BTreeMap<String, String>)>> {
        let indexes = self.summary.metadata_indexes.clone();
        let mut out = Vec::with_capacity(indexes.len());
        let mut buf = std::mem::take(&mut self.chunk_buf);
        for index in indexes {
            let read = read_record(
                &self.path,
                &mut self.file,
                self.file_bytes,
                &mut buf,
                index.offset,
                index.length,
                op::METADATA,
            );
            let parsed = read
                .and_then(|body| guard::parse(&self.path, op::METADATA, body))
                .map(McapRecord::into_owned);
            match parsed {
                Ok(McapRecord::Metadata(m)) => out.push((m.name, m.metadata)),
                Ok(_) => {}
                Err(e) => {
                    self.chunk_buf = buf;
                    return Err(e);
                }
            }
        }
        self.chunk_buf = buf;
        Ok(out)
    }

    /// Reads the next chunk, checks its CRC, and queues its messages.
    fn load_next_chunk(&mut self) -> Result<()> {
        let Some(index) = self.chunks.get(self.next_chunk).cloned() else {
            return Ok(());
        };
        self.next_chunk += 1;
        let mut buf = std::mem::take(&mut self.chunk_buf);
        let loaded = self.queue_chunk(&index, &mut buf);
        self.chunk_buf = buf;
        loaded
    }

    fn queue_chunk(&mut self, index: &ChunkIndex, buf: &mut Vec<u8>) -> Result<()> {
        let path = self.path.clone();
        read_record(
            &path,
            &mut self.file,
            self.file_bytes,
            buf,
            index.chunk_start_offset,
            index.chunk_length,
            op::CHUNK,
        )?;
        let keep_facts = self.facts.is_some();
        let record_crc = if keep_facts { crc32fast::hash(buf) } else { 0 };
        let (header, data) = match guard::parse(&path, op::CHUNK, &buf[9..])? {
            McapRecord::Chunk { header, data } => (header, data),
            _ => {
                return Err(Error::Mcap {
                    path,
                    source: mcap::McapError::BadIndex,
                })
            }
        };
        // The whole chunk is checked first (CRC, framing: `guard::chunk`), and nothing
        // of a corrupt chunk may be yielded.
        let mut facts = keep_facts.then(|| ChunkFacts {
            start: index.chunk_start_offset,
            length: index.chunk_length,
            record_crc,
            compression: header.compression.clone(),
            compressed_bytes: header.compressed_size,
            uncompressed_bytes: header.uncompressed_size,
            message_start_ns: u64::MAX,
            message_end_ns: 0,
            header_times_agree: false,
            only_messages: true,
            messages: 0,
            queued: 0,
            channel_counts: BTreeMap::new(),
            message_indexes: Vec::new(),
            message_index_offsets: BTreeMap::new(),
        });
        let mut entries: BTreeMap<u16, Vec<(u64, u64)>> = BTreeMap::new();
        let mut messages = Vec::new();
        let mut decompressed = std::mem::take(&mut self.decompressed);
        let records =
            guard::chunk(&header, &data, &mut decompressed).map_err(|e| Error::chunk(&path, e))?;
        // The records lie end to end from the start of the uncompressed chunk, each
        // body 9 bytes (opcode, length) after its record's start.
        let base = records.first().map_or(0, |(_, b)| b.as_ptr() as usize - 9);
        for (opcode, body) in records {
            if opcode != op::MESSAGE {
                if let Some(f) = facts.as_mut() {
                    f.only_messages = false;
                }
                continue;
            }
            if let McapRecord::Message { header, data } = guard::parse(&path, opcode, body)? {
                if let Some(f) = facts.as_mut() {
                    // The record starts 9 bytes (opcode, length) before its body.
                    let offset = (body.as_ptr() as usize - 9 - base) as u64;
                    entries
                        .entry(header.channel_id)
                        .or_default()
                        .push((header.log_time, offset));
                    f.messages += 1;
                    *f.channel_counts.entry(header.channel_id).or_insert(0) += 1;
                    f.message_start_ns = f.message_start_ns.min(header.log_time);
                    f.message_end_ns = f.message_end_ns.max(header.log_time);
                    f.queued += u64::from(self.queued(header.channel_id));
                }
                if self.queued(header.channel_id) {
                    messages.push((header, data.into_owned()));
                }
            }
        }
        self.decompressed = decompressed;
        if let Some(mut f) = facts {
            if f.messages == 0 {
                (f.message_start_ns, f.message_end_ns) = (0, 0);
            }
            f.header_times_agree = (header.message_start_time, header.message_end_time)
                == (f.message_start_ns, f.message_end_ns);
            (f.message_indexes, f.message_index_offsets) = message_index_records(&entries);
            if let Some(slot) = self
                .facts
                .as_mut()
                .and_then(|v| v.get_mut(self.next_chunk - 1))
            {
                *slot = Some(f);
            }
        }
        let chunk = (self.next_chunk - 1) as u32;
        for (header, data) in messages {
            self.pending.push(Reverse(Pending {
                log_time_ns: header.log_time,
                order: self.next_order,
                chunk,
                channel_id: header.channel_id,
                sequence: header.sequence,
                publish_time_ns: header.publish_time,
                data,
            }));
            self.next_order += 1;
        }
        Ok(())
    }

    /// The next queued message in log-time order, loading chunks as needed.
    fn next_pending(&mut self) -> Result<Option<Pending>> {
        loop {
            let next_chunk_start = self
                .chunks
                .get(self.next_chunk)
                .map(|c| c.message_start_time);
            let load = match (self.pending.peek(), next_chunk_start) {
                (_, None) => false,
                (None, Some(_)) => true,
                // A chunk starting no later than the earliest pending message may hold
                // messages that come first.
                (Some(Reverse(top)), Some(start)) => start <= top.log_time_ns,
            };
            if load {
                self.load_next_chunk()?;
                continue;
            }
            return Ok(self.pending.pop().map(|Reverse(p)| p));
        }
    }

    fn next_record(&mut self) -> Result<Option<Record>> {
        // Selected view channels are queued too; the decoded iteration skips them.
        while let Some(p) = self.next_pending()? {
            let Some(channel) = self.channels.get(&p.channel_id) else {
                continue;
            };
            let record = Some(Record {
                topic: Arc::clone(&channel.topic),
                channel_id: p.channel_id,
                sequence: p.sequence,
                log_time_ns: p.log_time_ns,
                publish_time_ns: p.publish_time_ns,
                message: Message::decode(channel.kind, &p.data)?,
            });
            self.last = Some((p.chunk, p.data));
            return Ok(record);
        }
        Ok(None)
    }
}

impl Iterator for Reader {
    type Item = Result<Record>;

    /// The next message in log-time order. After an error the iterator ends.
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        match self.next_record() {
            Ok(record) => record.map(Ok),
            Err(e) => {
                self.failed = true;
                Some(Err(e))
            }
        }
    }
}

/// MCAP message index records (opcode 0x07: channel ID, then the byte length and the
/// `(log time, offset in the uncompressed chunk)` pairs), one per channel in ID order,
/// and where each channel's record starts among them.
fn message_index_records(
    entries: &BTreeMap<u16, Vec<(u64, u64)>>,
) -> (Vec<u8>, BTreeMap<u16, u64>) {
    let mut out = Vec::with_capacity(entries.values().map(|e| 15 + 16 * e.len()).sum());
    let mut offsets = BTreeMap::new();
    for (channel_id, pairs) in entries {
        offsets.insert(*channel_id, out.len() as u64);
        let array_bytes = 16 * pairs.len() as u64;
        out.push(op::MESSAGE_INDEX);
        out.extend_from_slice(&(2 + 4 + array_bytes).to_le_bytes());
        out.extend_from_slice(&channel_id.to_le_bytes());
        out.extend_from_slice(&(array_bytes as u32).to_le_bytes());
        for (log_time, offset) in pairs {
            out.extend_from_slice(&log_time.to_le_bytes());
            out.extend_from_slice(&offset.to_le_bytes());
        }
    }
    (out, offsets)
}

/// Reads the record of `length` bytes (opcode and length prefix included) at `offset`
/// into `buf`, checks its opcode, and returns its body.
fn read_record<'b>(
    path: &Path,
    file: &mut dyn Source,
    file_bytes: u64,
    buf: &'b mut Vec<u8>,
    offset: u64,
    length: u64,
    opcode: u8,
) -> Result<&'b [u8]> {
    let bad_index = || Error::Mcap {
        path: path.to_path_buf(),
        source: mcap::McapError::BadIndex,
    };
    let len = usize::try_from(length).map_err(|_| bad_index())?;
    if len < 9 {
        return Err(bad_index());
    }
    // A corrupt index must not become an allocation: nothing lies past the end.
    if offset
        .checked_add(length)
        .is_none_or(|end| end > file_bytes)
    {
        return Err(Error::Truncated {
            path: path.to_path_buf(),
        });
    }
    buf.resize(len, 0);
    file.seek(SeekFrom::Start(offset))
        .map_err(|e| Error::io("seek in", path, e))?;
    file.read_exact(buf).map_err(|e| match e.kind() {
        std::io::ErrorKind::UnexpectedEof => Error::Truncated {
            path: path.to_path_buf(),
        },
        _ => Error::io("read", path, e),
    })?;
    if buf[0] != opcode {
        return Err(bad_index());
    }
    Ok(&buf[9..])
}

/// Reads the summary section through `mcap`'s sans-io summary reader.
fn read_summary(
    path: &Path,
    file: &mut dyn Source,
    file_bytes: u64,
) -> Result<Option<mcap::Summary>> {
    // With the file size, mcap clamps every read to the bytes that can still exist.
    let mut reader =
        SummaryReader::new_with_options(SummaryReaderOptions::default().with_file_size(file_bytes));
    while let Some(event) = reader.next_event() {
        let event = event.map_err(|e| match e {
            // No footer at the end: the writer never finished.
            mcap::McapError::BadMagic | mcap::McapError::BadFooter => Error::NotFinished {
                path: path.to_path_buf(),
                what: "no footer",
            },
            e => Error::mcap(path, e),
        })?;
        match event {
            SummaryReadEvent::ReadRequest(need) => {
                let n = file
                    .read(reader.insert(need))
                    .map_err(|e| Error::io("read", path, e))?;
                reader.notify_read(n);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let pos = file.seek(to).map_err(|e| Error::io("seek in", path, e))?;
                reader.notify_seeked(pos);
            }
        }
    }
    Ok(reader.finish())
}

/// Checks the records of the summary section (`guard::records`) before mcap's summary
/// reader parses them. A file without a readable footer is left to that reader, which
/// says what is missing.
fn check_summary(path: &Path, file: &mut dyn Source, file_bytes: u64) -> Result<()> {
    // Footer record: opcode, length (20), summary start, summary offset start, CRC;
    // then the closing magic.
    const FOOTER_BYTES: u64 = 1 + 8 + 20;
    let Some(footer_at) = file_bytes.checked_sub(FOOTER_BYTES + mcap::MAGIC.len() as u64) else {
        return Ok(());
    };
    let mut footer = [0u8; FOOTER_BYTES as usize];
    file.seek(SeekFrom::Start(footer_at))
        .and_then(|_| file.read_exact(&mut footer))
        .map_err(|e| Error::io("read", path, e))?;
    let summary_start = u64::from_le_bytes(footer[9..17].try_into().unwrap_or([0; 8]));
    if footer[0] != op::FOOTER || summary_start == 0 || summary_start >= footer_at {
        return Ok(());
    }
    // Within the file: summary_start < footer_at.
    let mut summary = vec![0u8; usize::try_from(footer_at - summary_start).unwrap_or(0)];
    file.seek(SeekFrom::Start(summary_start))
        .and_then(|_| file.read_exact(&mut summary))
        .map_err(|e| Error::io("read", path, e))?;
    crate::guard::records(&summary).map_err(|reason| Error::Malformed {
        path: path.to_path_buf(),
        reason: format!("summary section: {reason}"),
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    #[test]
    fn an_index_past_the_end_of_the_file_is_truncation_not_an_allocation() {
        // Found by the fuzz target mcap_read: a chunk index whose length claims
        // exabytes; the record was allocated before it was read.
        let mut file = Cursor::new(vec![0u8; 100]);
        let mut buf = Vec::new();
        for (offset, length) in [(10, 1 << 60), (u64::MAX - 5, 20), (90, 11)] {
            let e = read_record(
                Path::new("x.mcap"),
                &mut file,
                100,
                &mut buf,
                offset,
                length,
                op::CHUNK,
            )
            .unwrap_err();
            assert!(matches!(e, Error::Truncated { .. }), "{e}");
        }
        assert!(buf.capacity() < 100);
        file.get_mut()[10] = op::CHUNK;
        let body = read_record(
            Path::new("x.mcap"),
            &mut file,
            100,
            &mut buf,
            10,
            90,
            op::CHUNK,
        );
        assert_eq!(body.unwrap().len(), 81);
    }

    /// What `keep_chunk_facts` records of each chunk, against the index and message
    /// index records `mcap`'s writer made for it (an independent writer); and a chunk
    /// changed in the file after it was read is refused when read again for a copy.
    #[test]
    fn chunk_facts_match_what_mcaps_writer_indexed_and_a_changed_chunk_is_refused() {
        let path = tempfile::NamedTempFile::new()
            .expect("temp file")
            .into_temp_path();
        let options = crate::RecorderOptions {
            chunk_size_bytes: 2000,
            writer_thread: false,
            ..Default::default()
        };
        let mut rec = crate::Recorder::create(&path, options).expect("create");
        rec.add_channel("/accel", MessageKind::AccelBlock)
            .expect("channel");
        rec.add_channel("/heartbeat", MessageKind::Heartbeat)
            .expect("channel");
        for i in 0..200u32 {
            let block = vibro_msgs::AccelBlock {
                seq: u64::from(i),
                count: 1 + i % 7,
                ..Default::default()
            };
            // Log times not in file order within a chunk.
            let t = u64::from(i) * 10 + u64::from(i % 3) * 25;
            rec.write("/accel", t, t + 1, i, &block).expect("accel");
            if i % 3 == 0 {
                let beat = vibro_msgs::Heartbeat {
                    seq: u64::from(i),
                    ..Default::default()
                };
                rec.write("/heartbeat", t + 2, t + 2, i, &beat)
                    .expect("heartbeat");
            }
        }
        rec.finish().expect("finish");
        let bytes = std::fs::read(&path).expect("read");
        let mut reader = Reader::open(&path).expect("open");
        reader.keep_chunk_facts();
        let mut taken: BTreeMap<u32, u64> = BTreeMap::new();
        while let Some(r) = reader.next() {
            r.expect("record");
            let (chunk, _) = reader.last_raw().expect("last raw");
            *taken.entry(chunk).or_insert(0) += 1;
        }
        let chunks = reader.chunks.clone();
        assert!(chunks.len() > 5, "{}", chunks.len());
        let mut record = Vec::new();
        for (k, index) in chunks.iter().enumerate() {
            let f = reader.chunk_facts(k as u32).expect("facts").clone();
            let start = index.chunk_start_offset as usize;
            let end = start + index.chunk_length as usize;
            let mi_end = end + index.message_index_length as usize;
            assert_eq!(f.message_indexes, bytes[end..mi_end], "chunk {k}");
            let offsets: BTreeMap<u16, u64> = index
                .message_index_offsets
                .iter()
                .map(|(id, at)| (*id, at - end as u64))
                .collect();
            assert_eq!(f.message_index_offsets, offsets, "chunk {k}");
            assert_eq!(
                (f.start, f.length),
                (index.chunk_start_offset, index.chunk_length)
            );
            assert_eq!(
                (f.message_start_ns, f.message_end_ns),
                (index.message_start_time, index.message_end_time)
            );
            assert!(f.header_times_agree, "chunk {k}");
            assert_eq!(f.compression, index.compression);
            assert_eq!(f.compressed_bytes, index.compressed_size);
            assert_eq!(f.uncompressed_bytes, index.uncompressed_size);
            assert_eq!(
                f.channel_counts.keys().collect::<Vec<_>>(),
                index.message_index_offsets.keys().collect::<Vec<_>>()
            );
            assert_eq!(f.queued, f.messages);
            assert_eq!(taken.get(&(k as u32)).copied().unwrap_or(0), f.messages);
            reader
                .read_chunk_record(k as u32, &mut record)
                .expect("record");
            assert_eq!(record, bytes[start..end], "chunk {k}");
        }
        // mcap's writer puts the schema and channel records in the first chunk.
        assert!(!reader.chunk_facts(0).expect("facts").only_messages);
        assert!(reader.chunk_facts(3).expect("facts").only_messages);
        // One byte of chunk 3's compressed data changed in the file.
        let f = reader.chunk_facts(3).expect("facts").clone();
        let mut changed = bytes.clone();
        changed[(f.start + f.length - 1) as usize] ^= 0x40;
        std::fs::write(&path, &changed).expect("write");
        let e = reader.read_chunk_record(3, &mut record).unwrap_err();
        assert!(
            matches!(e, Error::ChangedWhileRead { offset, .. } if offset == f.start),
            "{e}"
        );
        assert!(
            e.to_string()
                .contains("changed while the file was being read"),
            "{e}"
        );
    }

    /// A recording in a temporary file with one message per chunk: accelerometer
    /// blocks on `/accel`, heartbeats on `/heartbeat` and a view message on `/view/x`.
    fn three_channel_log() -> tempfile::TempPath {
        let path = tempfile::NamedTempFile::new()
            .expect("temp file")
            .into_temp_path();
        let options = crate::RecorderOptions {
            chunk_size_bytes: 1,
            ..Default::default()
        };
        let mut rec = crate::Recorder::create(&path, options).expect("create");
        rec.add_channel("/accel", MessageKind::AccelBlock)
            .expect("channel");
        rec.add_channel("/heartbeat", MessageKind::Heartbeat)
            .expect("channel");
        let view = rec
            .add_view_channel("/view/x", crate::schema::VIEW_UNIT_STAGES)
            .expect("view channel");
        for i in 0..4u32 {
            let block = vibro_msgs::AccelBlock {
                seq: u64::from(i),
                count: 1,
                ..Default::default()
            };
            let t = u64::from(i) * 10;
            rec.write("/accel", t, t, i, &block).expect("accel");
            let beat = vibro_msgs::Heartbeat {
                seq: u64::from(i),
                ..Default::default()
            };
            rec.write("/heartbeat", t + 1, t + 1, i, &beat)
                .expect("heartbeat");
        }
        rec.write_view(&view, 5, 5, 0, vec![0x10, 0x07])
            .expect("view");
        rec.finish().expect("finish");
        path
    }

    #[test]
    fn a_selected_topic_reads_only_its_chunks_and_view_channels_come_raw() {
        let path = three_channel_log();
        let all: Vec<Record> = Reader::open(&path).unwrap().map(Result::unwrap).collect();
        assert_eq!(all.len(), 8, "the view message is not decoded");
        // Corrupt every chunk that holds no accelerometer block: reading everything
        // fails, reading `/accel` alone never touches them.
        let reader = Reader::open(&path).unwrap();
        let accel_id = reader
            .channels
            .iter()
            .find(|(_, c)| &*c.topic == "/accel")
            .map(|(id, _)| *id)
            .unwrap();
        let others: Vec<(u64, u64)> = reader
            .chunks
            .iter()
            .filter(|c| !c.message_index_offsets.is_empty())
            .filter(|c| !c.message_index_offsets.contains_key(&accel_id))
            .map(|c| (c.chunk_start_offset, c.chunk_length))
            .collect();
        assert_eq!(others.len(), 5, "4 heartbeat chunks and 1 view chunk");
        let mut bytes = std::fs::read(&path).unwrap();
        for (start, len) in &others {
            let last = usize::try_from(start + len - 1).unwrap();
            bytes[last] ^= 0xFF;
        }
        std::fs::write(&path, &bytes).unwrap();
        assert!(Reader::open(&path).unwrap().any(|r| r.is_err()));
        let mut accel = Reader::open(&path).unwrap();
        accel.select_topics(&["/accel"]).unwrap();
        let got: Vec<Record> = accel.map(Result::unwrap).collect();
        let want: Vec<&Record> = all.iter().filter(|r| &*r.topic == "/accel").collect();
        assert_eq!(got.iter().collect::<Vec<_>>(), want);
        // Raw reading of the same channel gives its bytes and schema.
        let mut raw = Reader::open(&path).unwrap();
        raw.select_topics(&["/accel"]).unwrap();
        let first = raw.next_raw().unwrap().unwrap();
        assert_eq!(&*first.schema, "vibrocomp.v1.AccelBlock");
        assert_eq!(
            Message::decode(MessageKind::AccelBlock, &first.data).unwrap(),
            want[0].message
        );
        let e = Reader::open(&path)
            .unwrap()
            .select_topics(&["/nope"])
            .unwrap_err();
        assert!(matches!(e, Error::NoSuchTopic { .. }), "{e}");
    }

    #[test]
    fn a_view_channel_is_read_raw_and_skipped_by_the_decoded_iteration() {
        let path = three_channel_log();
        let mut reader = Reader::open(&path).unwrap();
        reader.select_topics(&["/view/x", "/heartbeat"]).unwrap();
        let raw: Vec<RawRecord> = std::iter::from_fn(|| reader.next_raw())
            .map(Result::unwrap)
            .collect();
        let topics: Vec<&str> = raw.iter().map(|r| &*r.topic).collect();
        assert_eq!(
            topics,
            [
                "/heartbeat",
                "/view/x",
                "/heartbeat",
                "/heartbeat",
                "/heartbeat"
            ]
        );
        assert_eq!(raw[1].schema.as_ref(), "vibrocomp.view.v1.UnitStages");
        assert_eq!(raw[1].data, [0x10, 0x07]);
        let mut decoded = Reader::open(&path).unwrap();
        decoded.select_topics(&["/view/x", "/heartbeat"]).unwrap();
        assert_eq!(decoded.map(Result::unwrap).count(), 4);
    }
}
