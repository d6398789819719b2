//! What a recording holds: one pass over every record, chunk CRCs checked.

use crate::guard;
use crate::schema::kind_of_schema;
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
    /// First and last sequence number, in file order.
    pub first_sequence: Option<u32>,
    pub last_sequence: Option<u32>,
    /// Messages missing according to the sequence numbers: the sum of `jump - 1` over
    /// every forward jump (with 32-bit wrap-around).
    pub lost: u64,
    /// Number of forward jumps (gaps).
    pub gaps: u64,
    /// Messages whose sequence did not advance (repeated or went back).
    pub out_of_order: u64,
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
    /// Messages lost over all channels (sum of [`ChannelInfo::lost`]).
    pub lost: u64,
    /// Channels, by ID.
    pub channels: Vec<ChannelInfo>,
    pub metadata: Vec<MetadataInfo>,
    pub attachments: Vec<AttachmentInfo>,
}

/// Sequence numbers advance by one; a forward jump of less than half the 32-bit range is
/// a gap, anything else a repeat or a step back.
fn track_sequence(c: &mut ChannelInfo, sequence: u32) {
    match c.last_sequence {
        None => c.first_sequence = Some(sequence),
        Some(last) => {
            let step = sequence.wrapping_sub(last);
            if step == 1 {
            } else if step != 0 && step < (1 << 31) {
                c.gaps += 1;
                c.lost += u64::from(step - 1);
            } else {
                c.out_of_order += 1;
            }
        }
    }
    c.last_sequence = Some(sequence);
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
        duration_s: 0.0,
        lost: 0,
        channels: Vec::new(),
        metadata: Vec::new(),
        attachments: Vec::new(),
    };
    let mut summary = Summary {
        path,
        schemas: HashMap::new(),
        channels: BTreeMap::new(),
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
    }
    out.channels = channels.into_values().collect();
    out.messages = out.channels.iter().map(|c| c.messages).sum();
    out.lost = out.channels.iter().map(|c| c.lost).sum();
    out.first_log_time_ns = out
        .channels
        .iter()
        .filter_map(|c| c.first_log_time_ns)
        .min();
    out.last_log_time_ns = out.channels.iter().filter_map(|c| c.last_log_time_ns).max();
    out.duration_s = span_s(out.first_log_time_ns, out.last_log_time_ns);
    Ok(out)
}

/// What [`info`] has gathered so far.
struct Summary<'p> {
    path: &'p Path,
    schemas: HashMap<u16, String>,
    channels: BTreeMap<u16, ChannelInfo>,
    out: LogInfo,
}

/// Adds one record to the summary.
fn summarise(record: McapRecord<'_>, summary: &mut Summary<'_>) -> Result<()> {
    let Summary {
        path,
        schemas,
        channels,
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
            let kind = kind_of_schema(&message_type).map(|k| k.name().to_string());
            channels.entry(c.id).or_insert(ChannelInfo {
                id: c.id,
                topic: c.topic,
                message_type,
                kind,
                message_encoding: c.message_encoding,
                messages: 0,
                first_log_time_ns: None,
                last_log_time_ns: None,
                span_s: 0.0,
                first_sequence: None,
                last_sequence: None,
                lost: 0,
                gaps: 0,
                out_of_order: 0,
            });
        }
        McapRecord::Message { header, .. } => {
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
            track_sequence(c, header.sequence);
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
            span_s: 0.0,
            first_sequence: None,
            last_sequence: None,
            lost: 0,
            gaps: 0,
            out_of_order: 0,
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
}
