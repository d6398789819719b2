//! What a recording holds: one pass over every record, chunk CRCs checked.
//!
//! **Losses** (`crate::losses`), each counted once, by the services' rule
//! (`vibro_msgs::continuity`). Each channel's MCAP sequence numbers give the messages
//! the recorder missed; a forward step that skips more than
//! [`MAX_LOST_MESSAGES`](crate::MAX_LOST_MESSAGES) (2^20: hours of any vibrocomp
//! stream, while a subscriber loses at most its buffer at a time) is a *jump* (a
//! corrupt, crafted or renumbered counter), counted apart and never summed into
//! `lost`; a loss counted at a message ahead of its stream (a forged `seq`) is taken
//! back when the stream resumes. On a `CompensatedBlock` channel, the `input_seq` of
//! each output against the `seq` of each block of the accelerometer channel beside it
//! (`P/accel` for `P/compensated`) tells the blocks in the file that got no output,
//! even across a restart of the compensator (whose own `seq` starts again at 0):
//! counted (as lost for the compensated stream) and listed as ranges of `seq`.

use crate::guard;
use crate::losses::ChannelLosses;
use crate::schema::{kind_of_schema, MESSAGE_ENCODING};
use crate::{Error, Result};
use mcap::records::{op, Record as McapRecord};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// One channel of a recording.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ChannelInfo {
    /// MCAP channel ID.
    pub id: u16,
    /// Topic.
    pub topic: String,
    /// Schema name, e.g. `vibrocomp.v1.AccelBlock` (empty without a schema).
    pub message_type: String,
    /// The wire type, if the schema is a `vibrocomp.v1` message.
    pub kind: Option<String>,
    /// Message encoding (`protobuf`).
    pub message_encoding: String,
    /// Messages on the channel.
    pub messages: u64,
    /// Earliest and latest log time.
    pub first_log_time_ns: Option<u64>,
    pub last_log_time_ns: Option<u64>,
    /// `last - first` log time, in seconds.
    pub span_s: f64,
    /// Earliest and latest publish time (in a recording: the recorder's receive time;
    /// docs/logs.md, "Time"), and the span between them in seconds.
    pub first_publish_time_ns: Option<u64>,
    pub last_publish_time_ns: Option<u64>,
    pub publish_span_s: f64,
    /// First and last sequence number, in file order.
    pub first_sequence: Option<u32>,
    pub last_sequence: Option<u32>,
    /// Messages missing according to the sequence numbers, by the services' rule
    /// (`vibro_msgs::continuity`; 32-bit sequence numbers unwrapped by
    /// [`crate::unwrap_sequence`]): `step - 1` for a forward step of up to
    /// [`MAX_LOST_MESSAGES`](crate::MAX_LOST_MESSAGES) + 1, net of what was taken back
    /// ([`Self::retracted`]).
    pub lost: u64,
    /// Forward steps counted as losses when they came (some perhaps taken back since).
    pub gaps: u64,
    /// Forward steps that skip more than
    /// [`MAX_LOST_MESSAGES`](crate::MAX_LOST_MESSAGES): not losses (not in `lost`), a
    /// corrupt or renumbered sequence.
    pub jumps: u64,
    /// Messages the rule puts out of order (repeated, or behind the stream), recorded
    /// all the same.
    pub out_of_order: u64,
    /// Times the sequence went back to 0 (its producer restarted).
    pub restarts: u64,
    /// Times the stream was taken up again after out-of-order messages, or back where
    /// it was before a discontinuity (the rule's resync).
    pub resyncs: u64,
    /// Messages counted lost and then taken back at a resync: what a `seq` ahead of the
    /// stream (a forged one, 500,000 after 10) had counted. Not in `lost`.
    pub retracted: u64,
    /// `CompensatedBlock` channels: accelerometer blocks in the file (on
    /// [`Self::inputs_topic`]) without a compensated output here, `unanswered.count`.
    /// Not counted: blocks before the first one answered or after the last (the
    /// compensator not yet running, or stopped), and blocks whose output the log lost
    /// (this channel's `lost` counts those). 0 on other channels.
    pub inputs_without_output: u64,
    /// Those blocks, as ranges of `seq` (the first
    /// [`MAX_LISTED_UNANSWERED`](crate::MAX_LISTED_UNANSWERED) listed, all counted).
    pub unanswered: crate::SeqRanges,
    /// `CompensatedBlock` channels: the accelerometer channel whose blocks were matched
    /// (`P/accel` for `P/compensated`); none: none in the file, nothing matched.
    pub inputs_topic: Option<String>,
    /// Messages of an accelerometer or a compensated channel whose `seq` or
    /// `input_seq` could not be decoded: not matched.
    pub undecodable: u64,
}

/// One metadata record.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MetadataInfo {
    pub name: String,
    pub entries: BTreeMap<String, String>,
}

/// One attachment.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct AttachmentInfo {
    pub name: String,
    pub media_type: String,
    pub bytes: u64,
    pub log_time_ns: u64,
}

/// Summary of a recording, serialisable for `--json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LogInfo {
    pub path: PathBuf,
    /// File size.
    pub file_bytes: u64,
    /// The header's profile and writing library.
    pub profile: String,
    pub library: String,
    /// Messages over all channels.
    pub messages: u64,
    /// Chunks (from the statistics record; `None` if the file has none).
    pub chunks: Option<u64>,
    /// Earliest and latest log time over all channels, and the span in seconds.
    pub first_log_time_ns: Option<u64>,
    pub last_log_time_ns: Option<u64>,
    pub duration_s: f64,
    /// Earliest and latest publish time over all channels (a recording: receive time),
    /// and the span in seconds.
    pub first_publish_time_ns: Option<u64>,
    pub last_publish_time_ns: Option<u64>,
    pub publish_span_s: f64,
    /// Messages lost over all channels, each once: the sum of [`ChannelInfo::lost`]
    /// and of [`ChannelInfo::inputs_without_output`] (accelerometer blocks that reached
    /// the recorder but got no compensated output: lost for the compensated stream; a
    /// block the recorder missed is in `/accel`'s `lost` only, an output it missed in
    /// `/compensated`'s only).
    pub lost: u64,
    /// Accelerometer blocks without compensated output, over all channels (sum of
    /// [`ChannelInfo::inputs_without_output`], included in `lost`).
    pub inputs_without_output: u64,
    /// Sequence jumps too big to be losses, over all channels (sum of
    /// [`ChannelInfo::jumps`]; not in `lost`).
    pub jumps: u64,
    /// Losses taken back over all channels (sum of [`ChannelInfo::retracted`]; not in
    /// `lost`).
    pub retracted: u64,
    /// Channels, by ID.
    pub channels: Vec<ChannelInfo>,
    pub metadata: Vec<MetadataInfo>,
    pub attachments: Vec<AttachmentInfo>,
    /// What the recoveries that made this file lost, one per
    /// [`RECOVERY_METADATA`](crate::RECOVERY_METADATA) metadata record, in file order
    /// (none: not a recovered file).
    pub recoveries: Vec<crate::RecoveryRecord>,
}

fn span_s(first: Option<u64>, last: Option<u64>) -> f64 {
    match (first, last) {
        (Some(a), Some(b)) => b.saturating_sub(a) as f64 * 1e-9,
        _ => 0.0,
    }
}

/// Reads every record of `path` (checking every chunk's CRC) and summarises it.
/// A file its writer did not finish (no footer: cut short by a kill or a full disk)
/// is [`Error::Unfinished`], with the number of complete chunks: recover it first.
pub fn info(path: impl AsRef<Path>) -> Result<LogInfo> {
    let path = path.as_ref();
    let mut file = File::open(path).map_err(|e| Error::io("open", path, e))?;
    let file_bytes = file
        .metadata()
        .map_err(|e| Error::io("stat", path, e))?
        .len();
    let finished =
        ends_with_magic(&mut file, file_bytes).map_err(|e| Error::io("read", path, e))?;
    read_info(file, path, file_bytes, Some(finished))
}

/// Whether the file ends with the MCAP magic, as a finished file does (after its
/// footer); leaves the file at its start.
fn ends_with_magic(file: &mut File, file_bytes: u64) -> std::io::Result<bool> {
    let n = mcap::MAGIC.len() as u64;
    if file_bytes < 2 * n {
        return Ok(false);
    }
    let mut tail = [0u8; 8];
    file.seek(SeekFrom::Start(file_bytes - n))?;
    file.read_exact(&mut tail[..mcap::MAGIC.len()])?;
    file.seek(SeekFrom::Start(0))?;
    Ok(tail[..mcap::MAGIC.len()] == *mcap::MAGIC)
}

/// [`info`] of a recording read from `source` (a file, or bytes in memory) of
/// `file_bytes` bytes; `name` stands for the file in the summary and in errors.
pub fn info_from_reader(
    source: impl Read,
    name: impl AsRef<Path>,
    file_bytes: u64,
) -> Result<LogInfo> {
    read_info(source, name.as_ref(), file_bytes, None)
}

/// [`info_from_reader`], knowing whether the file ends with the magic (`finished`),
/// if that is known: a file cut short, or one whose record claims more bytes than the
/// file has, is [`Error::Unfinished`] unless it ends as a finished file does (then its
/// damage is something else, reported as it is).
fn read_info(
    source: impl Read,
    path: &Path,
    file_bytes: u64,
    finished: Option<bool>,
) -> Result<LogInfo> {
    let mut source = buffered(source);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true)
            // No record is longer than the file: without a limit, a corrupt length
            // field makes mcap 0.26 allocate that many bytes (up to 2^64) and abort.
            .with_record_length_limit(usize::try_from(file_bytes).unwrap_or(usize::MAX)),
    );
    let mut chunk_buf = Vec::new();
    let out = LogInfo {
        path: path.to_path_buf(),
        file_bytes,
        profile: String::new(),
        library: String::new(),
        messages: 0,
        chunks: None,
        first_log_time_ns: None,
        last_log_time_ns: None,
        first_publish_time_ns: None,
        last_publish_time_ns: None,
        publish_span_s: 0.0,
        duration_s: 0.0,
        lost: 0,
        inputs_without_output: 0,
        jumps: 0,
        retracted: 0,
        channels: Vec::new(),
        metadata: Vec::new(),
        attachments: Vec::new(),
        recoveries: Vec::new(),
    };
    let mut summary = Summary {
        path,
        schemas: HashMap::new(),
        channels: BTreeMap::new(),
        losses: ChannelLosses::default(),
        out,
    };
    // Chunks read whole with their CRC checked: what a recovery keeps of a cut file.
    let mut complete_chunks = 0u64;
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(event) => event,
            Err(mcap::McapError::UnexpectedEof | mcap::McapError::RecordTooLarge { .. })
                if finished != Some(true) =>
            {
                return Err(Error::Unfinished {
                    path: path.to_path_buf(),
                    chunks: complete_chunks,
                })
            }
            Err(e) => return Err(Error::mcap(path, e)),
        };
        match event {
            LinearReadEvent::ReadRequest(need) => {
                let n = source
                    .read(reader.insert(need))
                    .map_err(|e| Error::io("read", path, e))?;
                reader.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => {
                if opcode != op::CHUNK {
                    summarise(guard::parse(path, opcode, data)?, &mut summary)?;
                    continue;
                }
                // Chunks are cut into records here, not by mcap (see `guard`).
                let McapRecord::Chunk { header, data } = guard::parse(path, opcode, data)? else {
                    continue;
                };
                let records = guard::chunk(&header, &data, &mut chunk_buf)
                    .map_err(|e| Error::chunk(path, e))?;
                complete_chunks += 1;
                for (opcode, body) in records {
                    summarise(guard::parse(path, opcode, body)?, &mut summary)?;
                }
            }
        }
    }
    let Summary {
        mut out,
        mut channels,
        losses,
        ..
    } = summary;
    for c in channels.values_mut() {
        losses.fill(c);
        c.span_s = span_s(c.first_log_time_ns, c.last_log_time_ns);
        c.publish_span_s = span_s(c.first_publish_time_ns, c.last_publish_time_ns);
    }
    out.channels = channels.into_values().collect();
    out.messages = out.channels.iter().map(|c| c.messages).sum();
    out.inputs_without_output = out.channels.iter().map(|c| c.inputs_without_output).sum();
    out.lost = out.channels.iter().map(|c| c.lost).sum::<u64>() + out.inputs_without_output;
    out.jumps = out.channels.iter().map(|c| c.jumps).sum();
    out.retracted = out.channels.iter().map(|c| c.retracted).sum();
    out.first_log_time_ns = out
        .channels
        .iter()
        .filter_map(|c| c.first_log_time_ns)
        .min();
    out.last_log_time_ns = out.channels.iter().filter_map(|c| c.last_log_time_ns).max();
    out.duration_s = span_s(out.first_log_time_ns, out.last_log_time_ns);
    out.first_publish_time_ns = out
        .channels
        .iter()
        .filter_map(|c| c.first_publish_time_ns)
        .min();
    out.last_publish_time_ns = out
        .channels
        .iter()
        .filter_map(|c| c.last_publish_time_ns)
        .max();
    out.publish_span_s = span_s(out.first_publish_time_ns, out.last_publish_time_ns);
    out.recoveries = recoveries(&out.metadata);
    Ok(out)
}

/// The bytes read from the file at a time. mcap's linear reader asks for one record
/// head (9 bytes) at a time: unbuffered, a file of small records cost a `read()` per
/// record (issue 46: 11.65 M system calls for 100 MiB of 9-byte records, 93 s for
/// 2 GiB).
const READ_BUFFER_BYTES: usize = 1 << 20;

/// `source` behind a buffer of [`READ_BUFFER_BYTES`].
fn buffered<R: Read>(source: R) -> std::io::BufReader<R> {
    std::io::BufReader::with_capacity(READ_BUFFER_BYTES, source)
}

/// The losses that recoveries recorded in the file: one per
/// [`RECOVERY_METADATA`](crate::RECOVERY_METADATA) metadata record (a file recovered
/// twice has two), read by [`crate::RecoveryRecord::from_entries`].
fn recoveries(metadata: &[MetadataInfo]) -> Vec<crate::RecoveryRecord> {
    metadata
        .iter()
        .filter(|m| m.name == crate::RECOVERY_METADATA)
        .map(|m| crate::RecoveryRecord::from_entries(&m.entries))
        .collect()
}

/// What [`info`] has gathered so far.
struct Summary<'p> {
    path: &'p Path,
    schemas: HashMap<u16, String>,
    channels: BTreeMap<u16, ChannelInfo>,
    /// The losses of every channel (`crate::losses`).
    losses: ChannelLosses,
    out: LogInfo,
}

/// Adds one record to the summary.
fn summarise(record: McapRecord<'_>, summary: &mut Summary<'_>) -> Result<()> {
    let Summary {
        path,
        schemas,
        channels,
        losses,
        out,
    } = summary;
    match record {
        McapRecord::Header(h) => {
            out.profile = h.profile;
            out.library = h.library;
        }
        McapRecord::Schema { header, .. } => {
            schemas.insert(header.id, header.name);
        }
        McapRecord::Channel(c) => {
            let message_type = schemas.get(&c.schema_id).cloned().unwrap_or_default();
            let kind = kind_of_schema(&message_type);
            losses.channel(c.id, &c.topic, kind, c.message_encoding == MESSAGE_ENCODING);
            let kind = kind.map(|k| k.name().to_string());
            channels.entry(c.id).or_insert(ChannelInfo {
                id: c.id,
                topic: c.topic,
                message_type,
                kind,
                message_encoding: c.message_encoding,
                messages: 0,
                first_log_time_ns: None,
                last_log_time_ns: None,
                first_publish_time_ns: None,
                last_publish_time_ns: None,
                publish_span_s: 0.0,
                span_s: 0.0,
                first_sequence: None,
                last_sequence: None,
                lost: 0,
                gaps: 0,
                jumps: 0,
                out_of_order: 0,
                restarts: 0,
                resyncs: 0,
                retracted: 0,
                inputs_without_output: 0,
                unanswered: crate::SeqRanges::default(),
                inputs_topic: None,
                undecodable: 0,
            });
        }
        McapRecord::Message { header, data } => {
            let Some(c) = channels.get_mut(&header.channel_id) else {
                return Err(Error::Mcap {
                    path: path.to_path_buf(),
                    source: mcap::McapError::UnknownChannel(header.sequence, header.channel_id),
                });
            };
            c.messages += 1;
            let t = header.log_time;
            c.first_log_time_ns = Some(c.first_log_time_ns.map_or(t, |f| f.min(t)));
            c.last_log_time_ns = Some(c.last_log_time_ns.map_or(t, |l| l.max(t)));
            let p = header.publish_time;
            c.first_publish_time_ns = Some(c.first_publish_time_ns.map_or(p, |f| f.min(p)));
            c.last_publish_time_ns = Some(c.last_publish_time_ns.map_or(p, |l| l.max(p)));
            if c.first_sequence.is_none() {
                c.first_sequence = Some(header.sequence);
            }
            c.last_sequence = Some(header.sequence);
            losses.message(header.channel_id, header.sequence, &data);
        }
        McapRecord::Attachment { header, data, .. } => {
            out.attachments.push(AttachmentInfo {
                name: header.name,
                media_type: header.media_type,
                bytes: data.len() as u64,
                log_time_ns: header.log_time,
            });
        }
        McapRecord::Metadata(m) => out.metadata.push(MetadataInfo {
            name: m.name,
            entries: m.metadata,
        }),
        McapRecord::Statistics(s) => out.chunks = Some(s.chunk_count.into()),
        _ => {}
    }
    Ok(())
}

/// The text `vibrocomp log info` prints of a log's losses and recoveries.
impl LogInfo {
    /// The whole text `vibrocomp log info` prints: the file, its messages and times,
    /// its losses and recoveries, a line per channel, the metadata and the attachments.
    pub fn write_text(&self, out: &mut impl std::fmt::Write) -> std::fmt::Result {
        let info = self;
        writeln!(
            out,
            "{}: {} bytes, profile {:?}, written by {:?}",
            info.path.display(),
            info.file_bytes,
            info.profile,
            info.library
        )?;
        let chunks = info.chunks.map_or_else(
            || "no statistics record".to_string(),
            |c| format!("{c} chunks"),
        );
        writeln!(
            out,
            "  {} messages on {} channels, {chunks}; log time {} .. {} ({:.3} s)",
            info.messages,
            info.channels.len(),
            fmt_opt_log_ns(info.first_log_time_ns),
            fmt_opt_log_ns(info.last_log_time_ns),
            info.duration_s
        )?;
        // The two clocks (docs/logs.md, "Time"): the data's (log time) and, in a recording,
        // the recorder's receive time (publish time), which a replay compresses.
        writeln!(
            out,
            "  publish time {} .. {} ({:.3} s; in a recording the receive time, the log time \
             the data's)",
            fmt_opt_log_ns(info.first_publish_time_ns),
            fmt_opt_log_ns(info.last_publish_time_ns),
            info.publish_span_s
        )?;
        let gaps: u64 = info.channels.iter().map(|c| c.gaps).sum();
        let out_of_order: u64 = info.channels.iter().map(|c| c.out_of_order).sum();
        let resyncs: u64 = info.channels.iter().map(|c| c.resyncs).sum();
        let restarts: u64 = info.channels.iter().map(|c| c.restarts).sum();
        if info.lost == 0 && out_of_order == 0 && info.jumps == 0 && resyncs == 0 && restarts == 0 {
            self.write_no_losses(out)?;
        } else {
            // Each loss once (vibro_mcap::LogInfo::lost): by sequence, and the blocks in
            // the file that got no output.
            let by_sequence = info.lost.saturating_sub(info.inputs_without_output);
            write!(
                out,
                "  losses: {by_sequence} messages lost in {gaps} sequence gaps, {out_of_order} out of order"
            )?;
            if restarts > 0 {
                write!(out, "; {restarts} restarts (a sequence back to 0)")?;
            }
            if resyncs > 0 {
                write!(
                    out,
                    "; {resyncs} resyncs, {} counted lost at a seq ahead of its stream and taken back when it resumed",
                    info.retracted
                )?;
            }
            // Which blocks: every compensated channel's, by seq (all are in --json).
            for c in info.channels.iter().filter(|c| c.inputs_without_output > 0) {
                write!(
                    out,
                    "; {} accelerometer blocks without compensated output on {} ({}{})",
                    c.inputs_without_output,
                    c.topic,
                    c.unanswered,
                    c.inputs_topic
                        .as_deref()
                        .map_or_else(String::new, |t| format!(" on {t}"))
                )?;
            }
            if info.jumps > 0 {
                write!(
                    out,
                    "; {} sequence jumps too big to be losses (over {} messages skipped: a corrupt or renumbered sequence, not counted)",
                    info.jumps,
                    crate::MAX_LOST_MESSAGES
                )?;
            }
            if info.inputs_without_output > 0 {
                write!(out, "; {} lost in all", info.lost)?;
            }
            writeln!(out)?;
        }
        self.write_recoveries(out)?;
        // Topics as wide as the longest (`/heartbeat/compensator` is 22 characters).
        let tw = info
            .channels
            .iter()
            .map(|c| c.topic.len())
            .max()
            .unwrap_or(0)
            .max(6);
        let kind_of = |c: &ChannelInfo| {
            c.kind.clone().unwrap_or_else(|| {
                // A view channel's schema without its package (docs/view.md).
                c.message_type
                    .strip_prefix("vibrocomp.view.v1.")
                    .map_or_else(|| c.message_type.clone(), |t| format!("view {t}"))
            })
        };
        let kw = info
            .channels
            .iter()
            .map(|c| kind_of(c).len())
            .max()
            .unwrap_or(0)
            .max(17);
        if !info.channels.is_empty() {
            writeln!(
                out,
                "  {:<tw$} {:<kw$} {:>9}  {:>21}  {:>21}  {:>11}  {:>21}  {:>6}  {:>5}  {:>12}",
                "topic",
                "type",
                "messages",
                "first log time, s",
                "last log time, s",
                "span, s",
                "sequence",
                "lost",
                "gaps",
                "out of order"
            )?;
        }
        for c in &info.channels {
            let kind = kind_of(c);
            let sequence = match (c.first_sequence, c.last_sequence) {
                (Some(a), Some(b)) => format!("{a}..{b}"),
                _ => "-".to_string(),
            };
            writeln!(
                out,
                "  {:<tw$} {:<kw$} {:>9}  {:>21}  {:>21}  {:>11.3}  {:>21}  {:>6}  {:>5}  {:>12}",
                c.topic,
                kind,
                c.messages,
                c.first_log_time_ns
                    .map_or_else(|| "-".to_string(), fmt_log_ns),
                c.last_log_time_ns
                    .map_or_else(|| "-".to_string(), fmt_log_ns),
                c.span_s,
                sequence,
                c.lost,
                c.gaps,
                c.out_of_order
            )?;
        }
        if info.metadata.is_empty() {
            writeln!(out, "  metadata: none")?;
        } else {
            writeln!(out, "  metadata:")?;
            for m in &info.metadata {
                writeln!(out, "    {} ({} entries)", m.name, m.entries.len())?;
                for (k, v) in &m.entries {
                    writeln!(out, "      {k} = {v}")?;
                }
            }
        }
        if info.attachments.is_empty() {
            writeln!(out, "  attachments: none")?;
        } else {
            writeln!(out, "  attachments:")?;
            for a in &info.attachments {
                writeln!(out, "    {} ({}, {} bytes)", a.name, a.media_type, a.bytes)?;
            }
        }
        Ok(())
    }

    /// The losses line of a file whose sequences show none: a recovered file's losses are
    /// in its recovery records, not in its sequences (a chunk dropped at the start of the
    /// streams leaves no gap).
    pub fn write_no_losses(&self, out: &mut impl std::fmt::Write) -> std::fmt::Result {
        let info = self;
        let dropped: u64 = info.recoveries.iter().map(|r| r.messages_dropped).sum();
        if info.recoveries.iter().any(|r| r.losses) {
            let counted = if dropped > 0 {
                format!("{dropped} messages dropped")
            } else {
                "parts of the input not copied".to_string()
            };
            writeln!(
                out,
                "  losses: none in the sequences (every sequence advances by 1), but {counted} when it was recovered (below)"
            )
        } else {
            writeln!(out, "  losses: none (every sequence advances by 1)")
        }
    }

    /// One line per recovery that made the file (its `vibrocomp.recovery` records).
    pub fn write_recoveries(&self, out: &mut impl std::fmt::Write) -> std::fmt::Result {
        let info = self;
        for r in &info.recoveries {
            let kept = match r.messages_expected {
                Some(n) => format!("{} of {n} messages kept", r.messages_kept),
                None => format!("{} messages kept", r.messages_kept),
            };
            let mut lost = Vec::new();
            if r.messages_dropped > 0 {
                let exact = if r.messages_expected.is_some() {
                    ""
                } else {
                    "at least "
                };
                lost.push(format!("{exact}{} messages dropped", r.messages_dropped));
            }
            if r.chunks_skipped > 0 {
                lost.push(format!("{} chunk(s) skipped", r.chunks_skipped));
            }
            if r.regions_skipped > 0 {
                lost.push(format!(
                    "{} region(s) of {} bytes not copied (bytes {})",
                    r.regions_skipped, r.bytes_skipped, r.skipped_ranges
                ));
            }
            if r.bytes_cut > 0 {
                lost.push(format!(
                    "the last {} bytes cut short (a crash)",
                    r.bytes_cut
                ));
            }
            let lost = if lost.is_empty() {
                "nothing lost".to_string()
            } else {
                lost.join(", ")
            };
            writeln!(
                out,
                "  recovered from {} ({} bytes; {}): {kept}, {lost}",
                r.input,
                r.input_bytes,
                crate::RECOVERY_METADATA
            )?;
        }
        Ok(())
    }
}

/// A time on the data time base, in seconds with every nanosecond shown.
pub fn fmt_log_ns(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// [`fmt_log_ns`] with its unit, or `-` when there is no time.
pub fn fmt_opt_log_ns(ns: Option<u64>) -> String {
    ns.map_or_else(|| "-".to_string(), |t| format!("{} s", fmt_log_ns(t)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_msgs::MessageKind;

    #[test]
    fn a_record_longer_than_the_file_is_an_error_not_an_abort() {
        // fuzz/regressions/mcap_read/info-record-length-7e17: the magic, then a record
        // (opcode 0) whose length field claims 0x0A0D_0000_0000_0000 bytes.
        let mut bytes = mcap::MAGIC.to_vec();
        bytes.push(0);
        bytes.extend_from_slice(&0x0A0D_0000_0000_0000u64.to_le_bytes());
        let e = info_from_reader(bytes.as_slice(), "huge.mcap", bytes.len() as u64).unwrap_err();
        assert!(e.to_string().starts_with("huge.mcap: "), "{e}");
    }

    /// A finished file of `chunks` chunks of one message each, written by `mcap`, and
    /// where each chunk ends.
    fn finished_file(chunks: u64) -> (Vec<u8>, Vec<usize>) {
        let mut w = mcap::WriteOptions::new()
            .chunk_size(Some(1))
            .create(std::io::Cursor::new(Vec::new()))
            .unwrap();
        let channel = w.add_channel(0, "/t", "raw", &BTreeMap::new()).unwrap();
        for i in 0..chunks {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, &[1, 2, 3]).unwrap();
        }
        w.finish().unwrap();
        let bytes = w.into_inner().into_inner();
        // Walk the records: opcode, u64 length, body.
        let mut ends = Vec::new();
        let mut at = mcap::MAGIC.len();
        while at + 9 <= bytes.len() - mcap::MAGIC.len() {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            if bytes[at] == op::CHUNK {
                ends.push(at + 9 + len);
            }
            at += 9 + len;
        }
        (bytes, ends)
    }

    #[test]
    fn a_file_cut_short_is_unfinished_with_its_complete_chunks() {
        let (bytes, ends) = finished_file(4);
        // A chunk per message, and the channel's own, first.
        assert_eq!(ends.len(), 5, "{ends:?}");
        let whole = info_from_reader(bytes.as_slice(), "f.mcap", bytes.len() as u64).unwrap();
        assert_eq!(whole.messages, 4);
        // Mid-chunk, right after a chunk, just before the end (in the footer), and
        // inside the first chunk (its length then exceeds the file).
        for (cut, chunks) in [
            ((ends[1] + ends[2]) / 2, 2),
            (ends[2], 3),
            (bytes.len() - mcap::MAGIC.len() - 1, 5),
            (ends[0] - 2, 0),
        ] {
            let part = &bytes[..cut];
            let e = read_info(part, "f.mcap".as_ref(), part.len() as u64, Some(false))
                .unwrap_err()
                .to_string();
            assert!(
                e.starts_with("f.mcap: unfinished MCAP file (no footer"),
                "cut at {cut}: {e}"
            );
            assert!(
                e.contains(&format!(": {chunks} complete chunk(s) readable")),
                "cut at {cut}: {e}"
            );
            assert!(!e.contains("opcode"), "cut at {cut}: {e}");
        }
    }

    /// A finished file of one channel whose messages carry the sequence numbers
    /// `sequences`.
    fn sequenced_file(sequences: impl IntoIterator<Item = u32>) -> Vec<u8> {
        let mut w = mcap::WriteOptions::new()
            .create(std::io::Cursor::new(Vec::new()))
            .unwrap();
        let channel = w.add_channel(0, "/t", "raw", &BTreeMap::new()).unwrap();
        for (i, sequence) in sequences.into_iter().enumerate() {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence,
                log_time: i as u64,
                publish_time: i as u64,
            };
            w.write_to_known_channel(&header, &[1, 2, 3]).unwrap();
        }
        w.finish().unwrap();
        w.into_inner().into_inner()
    }

    #[test]
    fn sequence_gaps_count_lost_messages_across_the_wrap() {
        let m = u32::MAX;
        let bytes = sequenced_file([m - 2, m - 1, m, 0, 1, 3, 4, 4, 2, 5, 0, 1]);
        let info = info_from_reader(bytes.as_slice(), "w.mcap", bytes.len() as u64).unwrap();
        let c = &info.channels[0];
        // MAX -> 0 -> 1 goes on across the wrap; 1 -> 3 loses 2; 4 repeats and 2 is
        // behind (out of order); 5 goes on; 0 out of step is a restart.
        assert_eq!((c.first_sequence, c.last_sequence), (Some(m - 2), Some(1)));
        assert_eq!((c.lost, c.gaps, c.out_of_order, c.restarts), (1, 1, 2, 1));
        assert_eq!((c.jumps, c.resyncs, c.retracted), (0, 0, 0));
    }

    /// Issue 46, item 6: sequence 0..=10, a forged 500,000, then 11..=60 (the rule's
    /// unit test in vibro_msgs::continuity has the same): no loss once the stream
    /// resumed, 499,989 taken back, one resync, 11..=13 out of order.
    #[test]
    fn a_forged_sequence_ahead_counts_no_loss_once_the_stream_resumes() {
        let bytes = sequenced_file((0..=10).chain([500_000]).chain(11..=60));
        let info = info_from_reader(bytes.as_slice(), "f.mcap", bytes.len() as u64).unwrap();
        let c = &info.channels[0];
        assert_eq!(
            (
                c.lost,
                c.gaps,
                c.jumps,
                c.out_of_order,
                c.resyncs,
                c.retracted
            ),
            (0, 1, 0, 3, 1, 499_989),
            "{c:?}"
        );
        assert_eq!((info.lost, info.retracted), (0, 499_989));
    }

    #[test]
    fn random_sequence_numbers_are_jumps_not_losses() {
        // A crafted log: 1000 messages with random 32-bit sequence numbers.
        let mut w = mcap::WriteOptions::new()
            .create(std::io::Cursor::new(Vec::new()))
            .unwrap();
        let channel = w.add_channel(0, "/t", "raw", &BTreeMap::new()).unwrap();
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        for i in 0..1000u64 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: (x >> 32) as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, &[1, 2, 3]).unwrap();
        }
        w.finish().unwrap();
        let bytes = w.into_inner().into_inner();
        let info = info_from_reader(bytes.as_slice(), "r.mcap", bytes.len() as u64).unwrap();
        let c = &info.channels[0];
        // Each forward step is below 2^31; summed as losses they came to ~2^39.
        assert!(c.lost <= c.gaps * crate::MAX_LOST_MESSAGES, "{c:?}");
        // Each message but the first counts once at most (a gap, a jump, out of order,
        // a resync or a restart).
        assert!(
            c.gaps + c.jumps + c.out_of_order + c.resyncs + c.restarts <= 999,
            "{c:?}"
        );
        // About half the steps go forward (binomial, 999 draws: 400 is 6 sigma below),
        // half back.
        assert!(c.jumps > 400 && c.out_of_order > 400, "{c:?}");
        assert_eq!((info.lost, info.jumps), (c.lost, c.jumps));
    }

    /// A temporary file name for a test.
    fn temp_path(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("vibro-mcap-info-{}-{name}", std::process::id()))
    }

    /// What a test log holds, in file order.
    #[derive(Clone, Copy)]
    enum Rec {
        /// An accelerometer block (its seq, also its sequence number).
        A(u64),
        /// A compensated block: the compensator's seq (the sequence number), input_seq.
        C(u64, u64),
    }
    use Rec::{A, C};

    /// A log of `records` on `/accel` and `/compensated`, written by [`Recorder`].
    fn compensated_log(name: &str, records: &[Rec]) -> PathBuf {
        use crate::{Recorder, RecorderOptions};
        let path = temp_path(name);
        let mut r = Recorder::create(&path, RecorderOptions::default()).unwrap();
        let a = r.add_channel("/accel", MessageKind::AccelBlock).unwrap();
        let c = r
            .add_channel("/compensated", MessageKind::CompensatedBlock)
            .unwrap();
        for (t, rec) in records.iter().enumerate() {
            let t = t as u64 + 1;
            match *rec {
                A(seq) => {
                    let mut b = vibro_msgs::AccelBlock::ZEROED;
                    (b.seq, b.count) = (seq, 1);
                    r.write_to(&a, t, t, seq as u32, b.into()).unwrap();
                }
                C(seq, input_seq) => {
                    let mut b = vibro_msgs::CompensatedBlock::ZEROED;
                    (b.seq, b.input_seq, b.count) = (seq, input_seq, 1);
                    r.write_to(&c, t, t, seq as u32, b.into()).unwrap();
                }
            }
        }
        r.finish().unwrap();
        path
    }

    fn info_of(name: &str, records: &[Rec]) -> LogInfo {
        let path = compensated_log(name, records);
        let info = info(&path);
        let _ = std::fs::remove_file(&path);
        info.unwrap()
    }

    fn topic<'a>(info: &'a LogInfo, topic: &str) -> &'a ChannelInfo {
        info.channels.iter().find(|c| c.topic == topic).unwrap()
    }

    #[test]
    fn accel_blocks_without_output_are_losses_across_a_compensator_restart() {
        // The compensator answered blocks 0..=269 (its seq 0..=269), was restarted and
        // answered 276..=300 (its seq 0..=24 again): blocks 270..=275 got no output.
        // Every block is written first, then every output.
        let records: Vec<Rec> = (0..=300)
            .map(A)
            .chain((0..=269).map(|i| C(i, i)))
            .chain((276..=300).map(|i| C(i - 276, i)))
            .collect();
        let info = info_of("restart.mcap", &records);
        let accel = topic(&info, "/accel");
        assert_eq!((accel.lost, accel.inputs_without_output), (0, 0));
        let c = topic(&info, "/compensated");
        // Its own numbering shows a restart and nothing lost.
        assert_eq!(
            (c.messages, c.lost, c.gaps, c.out_of_order, c.restarts),
            (295, 0, 0, 0, 1)
        );
        assert_eq!(c.inputs_without_output, 6, "{c:?}");
        assert_eq!(
            c.unanswered.listed,
            [crate::SeqRange {
                first: 270,
                last: 275
            }]
        );
        assert_eq!(c.inputs_topic.as_deref(), Some("/accel"));
        assert_eq!(c.undecodable, 0);
        assert_eq!(
            (info.lost, info.inputs_without_output, info.jumps),
            (6, 6, 0)
        );
    }

    /// Issue 46, item 6: blocks 0..=10, a forged 500,000, then 11..=60, each output
    /// right after its block; the compensator dropped 11..=13 while it resynced. Also
    /// the recorder missed block 30 (answered all the same) and the output of block 40.
    /// Each of these 5 losses counts once: before, `lost` said 999,978.
    #[test]
    fn a_forged_seq_and_the_blocks_it_cost_are_each_counted_once() {
        let mut records = Vec::new();
        let mut out_seq = 0;
        for s in (0..=10).chain([500_000]).chain(11..=60) {
            if s != 30 {
                records.push(A(s));
            }
            if !(11..=13).contains(&s) {
                if s != 40 {
                    records.push(C(out_seq, s));
                }
                out_seq += 1;
            }
        }
        let info = info_of("forged.mcap", &records);
        let a = topic(&info, "/accel");
        assert_eq!(
            (
                a.lost,
                a.gaps,
                a.out_of_order,
                a.resyncs,
                a.retracted,
                a.jumps
            ),
            (1, 2, 3, 1, 499_989, 0),
            "{a:?}"
        );
        let c = topic(&info, "/compensated");
        assert_eq!((c.lost, c.gaps, c.out_of_order), (1, 1, 0), "{c:?}");
        assert_eq!(c.inputs_without_output, 3, "{c:?}");
        assert_eq!(
            c.unanswered.listed,
            [crate::SeqRange {
                first: 11,
                last: 13
            }]
        );
        let by_channel: u64 = info
            .channels
            .iter()
            .map(|c| c.lost + c.inputs_without_output)
            .sum();
        assert_eq!((info.lost, by_channel), (5, 5));
        assert_eq!((info.inputs_without_output, info.retracted), (3, 499_989));
    }
}
