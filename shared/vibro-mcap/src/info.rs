//! What a recording holds: one pass over every record, chunk CRCs checked.
//!
//! **Losses.** Each channel's MCAP sequence numbers give the messages the recorder
//! missed; a forward step that skips more than [`MAX_LOST_MESSAGES`] (2^20, the rule of
//! `vibro_service::continuity`: hours of any vibrocomp stream, while a subscriber loses
//! at most its buffer at a time) is a *jump* (a corrupt, crafted or renumbered counter),
//! counted apart and never summed into `lost`. On a `CompensatedBlock` channel the
//! `input_seq` of each message (the accelerometer block it answers, read from the
//! message) tells the accelerometer blocks that got no compensated output, even across
//! a restart of the compensator (whose own `seq` starts again at 0): they count as lost.

use crate::guard;
use crate::schema::{kind_of_schema, MESSAGE_ENCODING};
use crate::{Error, Result};
use mcap::records::{op, Record as McapRecord};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use prost::Message as _;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use vibro_msgs::MessageKind;

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
    /// Messages missing according to the sequence numbers: the sum of `step - 1` over
    /// every forward step of 2 to [`MAX_LOST_MESSAGES`] + 1 (with 32-bit wrap-around).
    pub lost: u64,
    /// Number of those forward steps (gaps).
    pub gaps: u64,
    /// Forward steps that skip more than [`MAX_LOST_MESSAGES`]: not losses (not in
    /// `lost`), a corrupt or renumbered sequence.
    pub jumps: u64,
    /// Messages whose sequence did not advance (repeated or went back).
    pub out_of_order: u64,
    /// `CompensatedBlock` channels: accelerometer blocks without a compensated output,
    /// by `input_seq` in file order: a forward step of `k` (from 2 to
    /// [`MAX_LOST_MESSAGES`] plus one) counts `k - 1`. Blocks before the channel's first
    /// output or after its last are not counted (the channel does not see them); `input_seq` going back (the
    /// accelerometer's producer restarted) starts the count afresh. 0 on other channels.
    pub inputs_without_output: u64,
    /// The forward `input_seq` steps counted in `inputs_without_output`, the first
    /// [`MAX_LISTED_INPUT_GAPS`] of them.
    pub input_gaps: Vec<InputGap>,
    /// `input_seq` steps that skip more than [`MAX_LOST_MESSAGES`]: not counted.
    pub input_jumps: u64,
    /// `CompensatedBlock` messages whose `input_seq` could not be decoded: not tracked.
    pub undecodable: u64,
}

/// Accelerometer blocks without compensated output: `input_seq` stepped from `from`
/// to `to` between two consecutive messages of a `CompensatedBlock` channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct InputGap {
    pub from: u64,
    pub to: u64,
    /// `to - from - 1`.
    pub missing: u64,
}

/// The most messages one forward step of a sequence counts as lost; a bigger step is a
/// jump (see the module doc).
pub const MAX_LOST_MESSAGES: u64 = 1 << 20;

/// How many [`InputGap`]s a channel lists (all are counted).
pub const MAX_LISTED_INPUT_GAPS: usize = 16;

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
    /// Messages lost over all channels: the sum of [`ChannelInfo::lost`] and of
    /// [`ChannelInfo::inputs_without_output`] (accelerometer blocks that reached the
    /// recorder but no compensator: lost for the compensated stream).
    pub lost: u64,
    /// Accelerometer blocks without compensated output, over all channels (sum of
    /// [`ChannelInfo::inputs_without_output`], included in `lost`).
    pub inputs_without_output: u64,
    /// Sequence jumps too big to be losses, over all channels (sum of
    /// [`ChannelInfo::jumps`] and [`ChannelInfo::input_jumps`]; not in `lost`).
    pub jumps: u64,
    /// Channels, by ID.
    pub channels: Vec<ChannelInfo>,
    pub metadata: Vec<MetadataInfo>,
    pub attachments: Vec<AttachmentInfo>,
}

/// Sequence numbers advance by one; a forward step of less than half the 32-bit range is
/// a gap (or a jump, beyond [`MAX_LOST_MESSAGES`]), anything else a repeat or a step back.
fn track_sequence(c: &mut ChannelInfo, sequence: u32) {
    match c.last_sequence {
        None => c.first_sequence = Some(sequence),
        Some(last) => {
            let step = sequence.wrapping_sub(last);
            if step == 1 {
            } else if step != 0 && step < (1 << 31) {
                if u64::from(step - 1) > MAX_LOST_MESSAGES {
                    c.jumps += 1;
                } else {
                    c.gaps += 1;
                    c.lost += u64::from(step - 1);
                }
            } else {
                c.out_of_order += 1;
            }
        }
    }
    c.last_sequence = Some(sequence);
}

/// The accelerometer blocks a compensated block's `input_seq` shows without output,
/// given the previous message's `input_seq` (`last`) on the same channel.
fn track_input_seq(c: &mut ChannelInfo, last: Option<u64>, input_seq: u64) {
    let Some(last) = last else { return };
    if input_seq <= last.saturating_add(1) {
        // Consecutive, repeated, or back (the accelerometer's producer restarted).
        return;
    }
    let missing = input_seq - last - 1;
    if missing > MAX_LOST_MESSAGES {
        c.input_jumps += 1;
        return;
    }
    c.inputs_without_output += missing;
    if c.input_gaps.len() < MAX_LISTED_INPUT_GAPS {
        c.input_gaps.push(InputGap {
            from: last,
            to: input_seq,
            missing,
        });
    }
}

/// The one field of a `vibrocomp.v1.CompensatedBlock` that `info` reads: decoding the
/// whole message would allocate its seven sample arrays for nothing (prost skips the
/// other fields by their length). The tag is the one of [`crate::proto::CompensatedBlock`]
/// (checked by a test).
#[derive(Clone, PartialEq, prost::Message)]
struct InputSeqOnly {
    #[prost(uint64, tag = "2")]
    input_seq: u64,
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
    mut source: impl Read,
    path: &Path,
    file_bytes: u64,
    finished: Option<bool>,
) -> Result<LogInfo> {
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
        channels: Vec::new(),
        metadata: Vec::new(),
        attachments: Vec::new(),
    };
    let mut summary = Summary {
        path,
        schemas: HashMap::new(),
        channels: BTreeMap::new(),
        last_input_seq: HashMap::new(),
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
        ..
    } = summary;
    for c in channels.values_mut() {
        c.span_s = span_s(c.first_log_time_ns, c.last_log_time_ns);
        c.publish_span_s = span_s(c.first_publish_time_ns, c.last_publish_time_ns);
    }
    out.channels = channels.into_values().collect();
    out.messages = out.channels.iter().map(|c| c.messages).sum();
    out.inputs_without_output = out.channels.iter().map(|c| c.inputs_without_output).sum();
    out.lost = out.channels.iter().map(|c| c.lost).sum::<u64>() + out.inputs_without_output;
    out.jumps = out.channels.iter().map(|c| c.jumps + c.input_jumps).sum();
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
    Ok(out)
}

/// What [`info`] has gathered so far.
struct Summary<'p> {
    path: &'p Path,
    schemas: HashMap<u16, String>,
    channels: BTreeMap<u16, ChannelInfo>,
    /// `CompensatedBlock` channels (protobuf-encoded): the last `input_seq` read, if any.
    last_input_seq: HashMap<u16, Option<u64>>,
    out: LogInfo,
}

/// Adds one record to the summary.
fn summarise(record: McapRecord<'_>, summary: &mut Summary<'_>) -> Result<()> {
    let Summary {
        path,
        schemas,
        channels,
        last_input_seq,
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
            if kind == Some(MessageKind::CompensatedBlock) && c.message_encoding == MESSAGE_ENCODING
            {
                last_input_seq.entry(c.id).or_insert(None);
            }
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
                inputs_without_output: 0,
                input_gaps: Vec::new(),
                input_jumps: 0,
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
            track_sequence(c, header.sequence);
            if let Some(last) = last_input_seq.get_mut(&header.channel_id) {
                match InputSeqOnly::decode(&*data) {
                    Ok(m) => {
                        track_input_seq(c, *last, m.input_seq);
                        *last = Some(m.input_seq);
                    }
                    Err(_) => c.undecodable += 1,
                }
            }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn channel() -> ChannelInfo {
        ChannelInfo {
            id: 1,
            topic: "/t".into(),
            message_type: String::new(),
            kind: None,
            message_encoding: String::new(),
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
            inputs_without_output: 0,
            input_gaps: Vec::new(),
            input_jumps: 0,
            undecodable: 0,
        }
    }

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

    #[test]
    fn sequence_gaps_count_lost_messages_across_the_wrap() {
        let mut c = channel();
        for s in [5, 6, 9, 10, 10, 4, u32::MAX - 1, u32::MAX, 1] {
            track_sequence(&mut c, s);
        }
        // 6 -> 9 loses 7, 8; 10 -> 10 repeats; 10 -> 4 goes back; 4 -> MAX-1 is a
        // jump of more than half the range: back; MAX -> 1 wraps, losing 0.
        assert_eq!(c.first_sequence, Some(5));
        assert_eq!(c.last_sequence, Some(1));
        assert_eq!(c.gaps, 2);
        assert_eq!(c.lost, 2 + 1);
        assert_eq!(c.out_of_order, 3);
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
        assert!(c.lost <= c.gaps * MAX_LOST_MESSAGES, "{c:?}");
        assert_eq!(c.gaps + c.jumps + c.out_of_order, 999, "{c:?}");
        // About half the steps go forward (binomial, 999 draws: 400 is 6 sigma below).
        assert!(c.jumps > 400, "{c:?}");
        assert_eq!((info.lost, info.jumps), (c.lost, c.jumps));
    }

    #[test]
    fn the_input_seq_field_is_read_as_the_schema_has_it() {
        let mut b = vibro_msgs::CompensatedBlock::ZEROED;
        (b.seq, b.input_seq, b.estimate_seq, b.count) = (7, 123_456_789_012, 99, 32);
        b.a1_g[31] = [1.0, 2.0, 3.0];
        let bytes = crate::proto::CompensatedBlock::try_from(&b)
            .unwrap()
            .encode_to_vec();
        let m = InputSeqOnly::decode(bytes.as_slice()).unwrap();
        assert_eq!(m.input_seq, 123_456_789_012);
    }

    /// A temporary file name for a test.
    fn temp_path(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("vibro-mcap-info-{}-{name}", std::process::id()))
    }

    /// A log of `accel` accelerometer blocks (seq 0..accel) and the compensated blocks
    /// `outputs` (each: the compensator's seq, the input_seq), written by [`Recorder`].
    fn compensated_log(name: &str, accel: u64, outputs: &[(u64, u64)]) -> PathBuf {
        use crate::{Recorder, RecorderOptions};
        let path = temp_path(name);
        let mut r = Recorder::create(&path, RecorderOptions::default()).unwrap();
        let a = r.add_channel("/accel", MessageKind::AccelBlock).unwrap();
        let c = r
            .add_channel("/compensated", MessageKind::CompensatedBlock)
            .unwrap();
        let mut t = 0;
        for seq in 0..accel {
            let mut b = vibro_msgs::AccelBlock::ZEROED;
            (b.seq, b.count) = (seq, 1);
            t += 1;
            r.write_to(&a, t, t, seq as u32, b.into()).unwrap();
        }
        for &(seq, input_seq) in outputs {
            let mut b = vibro_msgs::CompensatedBlock::ZEROED;
            (b.seq, b.input_seq, b.count) = (seq, input_seq, 1);
            t += 1;
            r.write_to(&c, t, t, seq as u32, b.into()).unwrap();
        }
        r.finish().unwrap();
        path
    }

    #[test]
    fn accel_blocks_without_output_are_losses_across_a_compensator_restart() {
        // The compensator answered blocks 0..=269 (its seq 0..=269), was restarted and
        // answered 276..=300 (its seq 0..=24 again): blocks 270..=275 got no output.
        let outputs: Vec<(u64, u64)> = (0..=269)
            .map(|i| (i, i))
            .chain((276..=300).map(|i| (i - 276, i)))
            .collect();
        let path = compensated_log("restart.mcap", 301, &outputs);
        let info = info(&path);
        let _ = std::fs::remove_file(&path);
        let info = info.unwrap();
        let accel = info.channels.iter().find(|c| c.topic == "/accel").unwrap();
        assert_eq!((accel.lost, accel.inputs_without_output), (0, 0));
        let c = info
            .channels
            .iter()
            .find(|c| c.topic == "/compensated")
            .unwrap();
        // Its own numbering shows one step back and nothing lost.
        assert_eq!((c.messages, c.lost, c.gaps, c.out_of_order), (295, 0, 0, 1));
        assert_eq!(c.inputs_without_output, 6, "{c:?}");
        assert_eq!(
            c.input_gaps,
            vec![InputGap {
                from: 269,
                to: 276,
                missing: 6
            }]
        );
        assert_eq!((c.input_jumps, c.undecodable), (0, 0));
        assert_eq!(
            (info.lost, info.inputs_without_output, info.jumps),
            (6, 6, 0)
        );
    }

    #[test]
    fn a_restarted_accel_producer_is_not_a_loss_and_a_random_input_seq_is_a_jump() {
        // input_seq 0..=9, back to 0..=9 (a new replay), then a random one, then 3 lost.
        let outputs: Vec<(u64, u64)> = (0..10)
            .chain(0..10)
            .chain([0xDEAD_BEEF_0000, 0xDEAD_BEEF_0004])
            .enumerate()
            .map(|(i, s)| (i as u64, s))
            .collect();
        let path = compensated_log("accel-restart.mcap", 10, &outputs);
        let info = info(&path);
        let _ = std::fs::remove_file(&path);
        let info = info.unwrap();
        let c = &info.channels[1];
        assert_eq!(
            (c.inputs_without_output, c.input_jumps, c.out_of_order),
            (3, 1, 0),
            "{c:?}"
        );
        assert_eq!((info.lost, info.jumps), (3, 1));
    }
}
