//! Rewriting a damaged recording (a crash: no summary, no footer, perhaps half a chunk;
//! or bytes garbled anywhere) into a valid file holding every intact chunk.
//!
//! The damaged file is framed record by record (opcode, length, body) here, with chunks
//! kept whole. A chunk is copied only if it is complete and its CRC checks out: its
//! schemas, channels and messages are then written to the new file (same IDs, same
//! bytes, new chunks). Attachments and metadata outside chunks are copied too. A chunk
//! that is framed but corrupt (CRC or decompression error) is skipped and counted, with
//! the messages its message-index records list. A record that cannot be parsed (a
//! garbled message index, attachment or header), or one that claims to run past the end
//! of the file, makes the reader *resynchronise*: it scans forward, byte by byte, for
//! the next record that proves itself intact (a chunk whose frame, header and records
//! parse and whose CRC checks out, or an attachment with a CRC that checks out), and
//! carries on from there, reading the records that follow it (metadata among them) as
//! usual; the bytes in between are reported as a damaged region. Records without a CRC
//! of their own (metadata, message indexes) cannot prove themselves, so the scan never
//! stops on one: those between the damage and the next intact chunk or attachment are
//! lost with the region. Reading stops at the data-end record of a complete file, or
//! where nothing intact follows the damage.

use crate::{guard, Error, Result};
use mcap::records::Record as McapRecord;
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// What [`recover`] found and wrote.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RecoverReport {
    pub input: PathBuf,
    pub output: PathBuf,
    /// Size of the damaged file.
    pub input_bytes: u64,
    /// Bytes of the damaged file up to the end of the last record read whole.
    pub valid_prefix_bytes: u64,
    /// The input reached its data-end record: it was not damaged at the end.
    pub input_complete: bool,
    /// Why reading stopped early, if it did.
    pub stop_reason: Option<String>,
    /// Chunks copied.
    pub chunks_recovered: u64,
    /// Complete chunks skipped because their CRC or compression was broken.
    pub chunks_skipped: u64,
    /// Messages copied, in total and per topic.
    pub messages_recovered: u64,
    pub messages_per_topic: BTreeMap<String, u64>,
    /// Messages in the skipped chunks, as listed by their message-index records (a
    /// lower bound: a skipped chunk without readable index records counts 0).
    pub messages_in_skipped_chunks: u64,
    /// Messages dropped because their channel was defined only in a skipped chunk.
    pub messages_orphaned: u64,
    /// Every stretch of the input that was not copied, in file order, with the reason;
    /// the file's end after the last record read is in [`RecoverReport::stop_reason`].
    pub damage: Vec<Damage>,
    pub attachments: u64,
    pub metadata: u64,
    /// Size of the recovered file.
    pub output_bytes: u64,
}

/// A stretch of the damaged file that was not copied.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Damage {
    /// First byte of the stretch.
    pub start_byte: u64,
    /// First byte after it (where reading resumed).
    pub end_byte: u64,
    /// What was there: "chunk CRC failed (...)", "unreadable record at byte ...".
    pub what: String,
    /// Messages known to be lost in it (a skipped chunk's message-index count), if
    /// known.
    pub messages: Option<u64>,
}

struct Copier<W: Write + Seek> {
    out_path: PathBuf,
    writer: mcap::Writer<W>,
    schemas: HashMap<u16, u16>,
    channels: HashMap<u16, String>,
    report: RecoverReport,
}

impl<W: Write + Seek> Copier<W> {
    fn new(
        input: &Path,
        input_bytes: u64,
        out_path: &Path,
        out: W,
        profile: String,
    ) -> Result<Copier<W>> {
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_threads(0)
            .profile(profile)
            .create(out)
            .map_err(|e| Error::mcap(out_path, e))?;
        Ok(Copier {
            out_path: out_path.to_path_buf(),
            writer,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            report: RecoverReport {
                input: input.to_path_buf(),
                output: out_path.to_path_buf(),
                input_bytes,
                valid_prefix_bytes: 0,
                input_complete: false,
                stop_reason: None,
                chunks_recovered: 0,
                chunks_skipped: 0,
                messages_recovered: 0,
                messages_per_topic: BTreeMap::new(),
                messages_in_skipped_chunks: 0,
                messages_orphaned: 0,
                damage: Vec::new(),
                attachments: 0,
                metadata: 0,
                output_bytes: 0,
            },
        })
    }

    fn mcap(&self, e: mcap::McapError) -> Error {
        Error::mcap(&self.out_path, e)
    }

    /// Copies one record of the data section (or of a chunk). Returns false at data end.
    fn copy(&mut self, record: McapRecord<'_>) -> Result<bool> {
        match record {
            McapRecord::Schema { header, data } => {
                let id = self
                    .writer
                    .add_schema_with_id(header.id, &header.name, &header.encoding, &data)
                    .map_err(|e| self.mcap(e))?;
                self.schemas.insert(header.id, id);
            }
            McapRecord::Channel(c) => {
                if c.schema_id != 0 && !self.schemas.contains_key(&c.schema_id) {
                    return Ok(true);
                }
                self.writer
                    .add_channel_with_id(
                        c.id,
                        c.schema_id,
                        &c.topic,
                        &c.message_encoding,
                        &c.metadata,
                    )
                    .map_err(|e| self.mcap(e))?;
                self.channels.insert(c.id, c.topic);
            }
            McapRecord::Message { header, data } => {
                let Some(topic) = self.channels.get(&header.channel_id) else {
                    self.report.messages_orphaned += 1;
                    return Ok(true);
                };
                *self
                    .report
                    .messages_per_topic
                    .entry(topic.clone())
                    .or_insert(0) += 1;
                self.report.messages_recovered += 1;
                self.writer
                    .write_to_known_channel(&header, &data)
                    .map_err(|e| self.mcap(e))?;
            }
            McapRecord::Attachment { header, data, .. } => {
                self.writer
                    .attach(&mcap::Attachment {
                        log_time: header.log_time,
                        create_time: header.create_time,
                        name: header.name,
                        media_type: header.media_type,
                        data: Cow::Borrowed(&data),
                    })
                    .map_err(|e| self.mcap(e))?;
                self.report.attachments += 1;
            }
            McapRecord::Metadata(m) => {
                self.writer.write_metadata(&m).map_err(|e| self.mcap(e))?;
                self.report.metadata += 1;
            }
            McapRecord::DataEnd(_) => return Ok(false),
            _ => {}
        }
        Ok(true)
    }

    /// Copies a whole chunk if it decompresses, its CRC checks out and its records
    /// parse (cut into records by `guard::chunk`, not by mcap); otherwise counts it as
    /// skipped and says why.
    fn copy_chunk(
        &mut self,
        header: mcap::records::ChunkHeader,
        data: &[u8],
    ) -> Result<Option<(String, Option<u64>)>> {
        let mut buf = Vec::new();
        match chunk_records(&header, data, &mut buf) {
            Ok(records) => {
                for record in records {
                    self.copy(record)?;
                }
                self.report.chunks_recovered += 1;
                Ok(None)
            }
            Err(why) => {
                self.report.chunks_skipped += 1;
                // Its messages, if its records can still be framed despite the CRC.
                let mut unchecked = header.clone();
                unchecked.uncompressed_crc = 0;
                let mut buf = Vec::new();
                let messages = guard::chunk(&unchecked, data, &mut buf)
                    .ok()
                    .map(|records| {
                        records
                            .iter()
                            .filter(|(opcode, _)| *opcode == mcap::records::op::MESSAGE)
                            .count() as u64
                    });
                Ok(Some((why, messages)))
            }
        }
    }
}

/// The parsed records of a chunk, or why it is unusable.
fn chunk_records<'b>(
    header: &mcap::records::ChunkHeader,
    data: &'b [u8],
    buf: &'b mut Vec<u8>,
) -> std::result::Result<Vec<McapRecord<'b>>, String> {
    let records = guard::chunk(header, data, buf).map_err(|e| match e {
        guard::ChunkError::Crc { saved, calculated } => {
            format!("chunk CRC failed (expected {saved:08X}, got {calculated:08X})")
        }
        guard::ChunkError::Invalid(reason) => reason,
    })?;
    records
        .into_iter()
        .map(|(opcode, body)| {
            mcap::parse_record(opcode, body)
                .map_err(|e| format!("in a chunk: record 0x{opcode:02X}: {e}"))
        })
        .collect()
}

/// Reads `buf.len()` bytes at `pos`; false if the input ends first.
fn read_at(input: &mut (impl Read + Seek), pos: u64, buf: &mut [u8]) -> std::io::Result<bool> {
    input.seek(SeekFrom::Start(pos))?;
    match input.read_exact(buf) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

/// Opcode, 8-byte length.
const FRAME_BYTES: u64 = 9;
/// A chunk body's fields before its compression string: start and end times,
/// uncompressed size, CRC.
const CHUNK_FIXED_BYTES: u64 = 8 + 8 + 8 + 4;

/// Where an attachment body's name length lies (after its log and create times), and
/// the fixed fields of an attachment body: times, name and media-type lengths, data
/// length, CRC.
const ATTACHMENT_NAME_AT: u64 = 8 + 8;
const ATTACHMENT_FIXED_BYTES: u64 = 8 + 8 + 4 + 4 + 8 + 4;

/// One record read at a position of the input.
enum Framed {
    /// The file ends there.
    End,
    /// A record whose body is in the buffer; it ends at the given byte.
    Record { opcode: u8, end: u64 },
    /// A record that cannot be framed or parsed, and why.
    Bad(String),
}

/// Frames the record at `pos` into `body` (its length is at most what is left of the
/// file, so a garbled length never becomes a large allocation).
fn frame(
    input: &mut (impl Read + Seek),
    path: &Path,
    pos: u64,
    input_bytes: u64,
    body: &mut Vec<u8>,
) -> Result<Framed> {
    if pos >= input_bytes {
        return Ok(Framed::End);
    }
    let mut head = [0u8; FRAME_BYTES as usize];
    let io = |e| Error::io("read", path, e);
    if !read_at(input, pos, &mut head).map_err(io)? {
        return Ok(Framed::Bad(format!(
            "the file ends inside a record that starts at byte {pos}"
        )));
    }
    let mut len = [0u8; 8];
    len.copy_from_slice(&head[1..]);
    let len = u64::from_le_bytes(len);
    let left = input_bytes - pos - FRAME_BYTES;
    if len > left {
        return Ok(Framed::Bad(format!(
            "the file ends inside a record that starts at byte {pos} (record 0x{:02X} claims {len} bytes, {left} are left)",
            head[0]
        )));
    }
    // len <= left < input_bytes, which is the size of a file that exists.
    body.resize(usize::try_from(len).unwrap_or(usize::MAX), 0);
    if !read_at(input, pos + FRAME_BYTES, body).map_err(io)? {
        return Ok(Framed::Bad(format!(
            "the file ends inside a record that starts at byte {pos}"
        )));
    }
    Ok(Framed::Record {
        opcode: head[0],
        end: pos + FRAME_BYTES + len,
    })
}

/// The record's length and the u32 at byte `field_at` of its body, if the bytes at
/// `pos` start a record with `opcode` whose length fits in the file (`input_bytes`):
/// the first, cheap test of a candidate while resynchronising.
fn peek(
    input: &mut (impl Read + Seek),
    path: &Path,
    (pos, input_bytes): (u64, u64),
    opcode: u8,
    field_at: u64,
) -> Result<Option<(u64, u64)>> {
    // The longest head asked for is a chunk's (its compression length).
    debug_assert!(field_at <= CHUNK_FIXED_BYTES);
    let mut head = [0u8; (FRAME_BYTES + CHUNK_FIXED_BYTES + 4) as usize];
    let head = &mut head[..(FRAME_BYTES + field_at + 4) as usize];
    if !read_at(input, pos, head).map_err(|e| Error::io("read", path, e))? || head[0] != opcode {
        return Ok(None);
    }
    let mut n = [0u8; 8];
    n.copy_from_slice(&head[1..9]);
    let len = u64::from_le_bytes(n);
    let mut c = [0u8; 4];
    c.copy_from_slice(&head[head.len() - 4..]);
    let field = u64::from(u32::from_le_bytes(c));
    Ok((len <= input_bytes - pos - FRAME_BYTES).then_some((len, field)))
}

/// Whether the bytes at `pos` are a chunk record whose frame, header and records parse
/// and whose CRC checks out. Cheap tests first (opcode, a length within the file, a
/// known compression, a records length that fills the rest of the record), so that a
/// scan over compressed data rarely decompresses anything.
fn intact_chunk_at(
    input: &mut (impl Read + Seek),
    path: &Path,
    pos: u64,
    input_bytes: u64,
    body: &mut Vec<u8>,
) -> Result<bool> {
    let io = |e| Error::io("read", path, e);
    let Some((len, compression_len)) = peek(
        input,
        path,
        (pos, input_bytes),
        mcap::records::op::CHUNK,
        CHUNK_FIXED_BYTES,
    )?
    else {
        return Ok(false);
    };
    if compression_len > 4 || len < CHUNK_FIXED_BYTES + 4 + compression_len + 8 {
        return Ok(false);
    }
    let mut rest = [0u8; 4 + 8];
    let rest = &mut rest[..compression_len as usize + 8];
    let at = pos + FRAME_BYTES + CHUNK_FIXED_BYTES + 4;
    if !read_at(input, at, rest).map_err(io)? {
        return Ok(false);
    }
    let compression = &rest[..compression_len as usize];
    if !matches!(compression, b"" | b"zstd" | b"lz4") {
        return Ok(false);
    }
    let mut r = [0u8; 8];
    r.copy_from_slice(&rest[compression_len as usize..]);
    if u64::from_le_bytes(r) != len - (CHUNK_FIXED_BYTES + 4 + compression_len + 8) {
        return Ok(false);
    }
    let Framed::Record { opcode, .. } = frame(input, path, pos, input_bytes, body)? else {
        return Ok(false);
    };
    if guard::record(opcode, body).is_err() {
        return Ok(false);
    }
    let Ok(McapRecord::Chunk { header, data }) = mcap::parse_record(opcode, body) else {
        return Ok(false);
    };
    let mut buf = Vec::new();
    Ok(chunk_records(&header, &data, &mut buf).is_ok())
}

/// Whether the bytes at `pos` are an attachment record that frames, parses, and carries
/// a CRC (not 0, which means "none") that checks out (`mcap::parse_record` checks it).
fn intact_attachment_at(
    input: &mut (impl Read + Seek),
    path: &Path,
    pos: u64,
    input_bytes: u64,
    body: &mut Vec<u8>,
) -> Result<bool> {
    // Cheap tests first: the opcode, a length within the file and long enough for the
    // fixed fields (log and create time, name and media-type lengths, data length, CRC),
    // and a name that fits in it.
    let Some((len, name_len)) = peek(
        input,
        path,
        (pos, input_bytes),
        mcap::records::op::ATTACHMENT,
        ATTACHMENT_NAME_AT,
    )?
    else {
        return Ok(false);
    };
    if len < ATTACHMENT_FIXED_BYTES || name_len > len - ATTACHMENT_FIXED_BYTES {
        return Ok(false);
    }
    let Framed::Record { opcode, .. } = frame(input, path, pos, input_bytes, body)? else {
        return Ok(false);
    };
    if opcode != mcap::records::op::ATTACHMENT || guard::record(opcode, body).is_err() {
        return Ok(false);
    }
    Ok(matches!(
        mcap::parse_record(opcode, body),
        Ok(McapRecord::Attachment { crc, .. }) if crc != 0
    ))
}

/// The start of the next intact chunk or attachment at or after `from`, if any.
fn resync(
    input: &mut (impl Read + Seek),
    path: &Path,
    from: u64,
    input_bytes: u64,
) -> Result<Option<u64>> {
    let io = |e| Error::io("read", path, e);
    let mut block = vec![0u8; 64 * 1024];
    let mut body = Vec::new();
    let mut at = from;
    while at < input_bytes {
        let n = usize::try_from((input_bytes - at).min(block.len() as u64)).unwrap_or(0);
        let block = &mut block[..n];
        if !read_at(input, at, block).map_err(io)? {
            return Ok(None);
        }
        let candidates: Vec<u64> = block
            .iter()
            .enumerate()
            .filter(|(_, &b)| b == mcap::records::op::CHUNK || b == mcap::records::op::ATTACHMENT)
            .map(|(i, _)| at + i as u64)
            .collect();
        for pos in candidates {
            if intact_chunk_at(input, path, pos, input_bytes, &mut body)?
                || intact_attachment_at(input, path, pos, input_bytes, &mut body)?
            {
                return Ok(Some(pos));
            }
        }
        at += n as u64;
    }
    Ok(None)
}

/// Recovers `damaged` into a new file `out` (created or truncated; zstd chunks).
pub fn recover(damaged: impl AsRef<Path>, out: impl AsRef<Path>) -> Result<RecoverReport> {
    let input = damaged.as_ref();
    let out_path = out.as_ref();
    let file = File::open(input).map_err(|e| Error::io("open", input, e))?;
    let input_bytes = file
        .metadata()
        .map_err(|e| Error::io("stat", input, e))?
        .len();
    let out_file = File::create(out_path).map_err(|e| Error::io("create", out_path, e))?;
    let (report, out) =
        recover_from_reader(file, input, input_bytes, BufWriter::new(out_file), out_path)?;
    let file = out
        .into_inner()
        .map_err(|e| Error::io("write", out_path, e.into_error()))?;
    file.sync_all()
        .map_err(|e| Error::io("sync", out_path, e))?;
    Ok(report)
}

/// [`recover`] from `damaged` (a file, or bytes in memory) of `input_bytes` bytes into
/// `out`, which is returned after the new file's footer; `input` and `out_path` stand
/// for the files in the report and in errors.
pub fn recover_from_reader<W: Write + Seek>(
    mut damaged: impl Read + Seek,
    input: &Path,
    input_bytes: u64,
    out: W,
    out_path: &Path,
) -> Result<(RecoverReport, W)> {
    let mut out = Some(out);
    let bad_magic = || Error::Mcap {
        path: input.to_path_buf(),
        source: mcap::McapError::BadMagic,
    };
    let mut magic = [0u8; 8];
    let whole_magic =
        read_at(&mut damaged, 0, &mut magic).map_err(|e| Error::io("read", input, e))?;
    let magic_len = usize::try_from(input_bytes.min(8)).unwrap_or(8);
    if magic[..magic_len] != mcap::MAGIC[..magic_len] {
        return Err(bad_magic());
    }
    if !whole_magic {
        return Err(Error::Truncated {
            path: input.to_path_buf(),
        });
    }

    // The header comes first; the new file's header copies its profile.
    let mut copier: Option<Copier<W>> = None;
    // Why the header could not be read, once a chunk after it was found.
    let mut header_damage: Option<Damage> = None;
    let mut pos = mcap::MAGIC.len() as u64;
    let mut valid_prefix_bytes = pos;
    let mut input_complete = false;
    let mut stop_reason = None;
    let mut damage = Vec::new();
    // A skipped chunk, and whether the message-index records right after it count its
    // messages (when its own records do not frame).
    let mut skipped: Option<(Damage, bool)> = None;
    let mut body = Vec::new();
    loop {
        let problem = match frame(&mut damaged, input, pos, input_bytes, &mut body)? {
            Framed::End => break,
            Framed::Bad(why) => why,
            Framed::Record { opcode, end } => match guard::record(opcode, &body)
                .and_then(|()| mcap::parse_record(opcode, &body).map_err(|e| e.to_string()))
            {
                Err(e) => format!("unreadable record at byte {pos}: {e}"),
                Ok(record) => {
                    let start = pos;
                    pos = end;
                    valid_prefix_bytes = end;
                    if let McapRecord::MessageIndex(index) = &record {
                        if let Some((d, from_index)) = skipped.as_mut() {
                            if *from_index {
                                *d.messages.get_or_insert(0) += index.records.len() as u64;
                            }
                            continue;
                        }
                    } else if let Some((d, _)) = skipped.take() {
                        damage.push(d);
                    }
                    let Some(c) = copier.as_mut() else {
                        let McapRecord::Header(h) = record else {
                            return Err(bad_magic());
                        };
                        // Taken once: there is no copier only until the header.
                        let Some(out) = out.take() else {
                            continue;
                        };
                        copier = Some(Copier::new(input, input_bytes, out_path, out, h.profile)?);
                        continue;
                    };
                    if let McapRecord::Chunk { header, data } = record {
                        if let Some((what, messages)) = c.copy_chunk(header, &data)? {
                            // Counted from the chunk's records if they still frame,
                            // else from the message-index records that follow it.
                            let damage = Damage {
                                start_byte: start,
                                end_byte: end,
                                what,
                                messages,
                            };
                            skipped = Some((damage, messages.is_none()));
                        }
                    } else if !c.copy(record)? {
                        input_complete = true;
                        break;
                    }
                    continue;
                }
            },
        };
        if let Some((d, _)) = skipped.take() {
            damage.push(d);
        }
        // Damage at `pos`: carry on at the next intact chunk or attachment, if any.
        let Some(next) = resync(&mut damaged, input, pos + 1, input_bytes)? else {
            if copier.is_none() {
                return Err(if problem.starts_with("the file ends") {
                    Error::Truncated {
                        path: input.to_path_buf(),
                    }
                } else {
                    Error::Malformed {
                        path: input.to_path_buf(),
                        reason: format!(
                            "nothing to recover: its MCAP header record is unreadable ({problem}) and no intact chunk follows it"
                        ),
                    }
                });
            }
            stop_reason = Some(problem);
            break;
        };
        let region = Damage {
            start_byte: pos,
            end_byte: next,
            what: problem,
            messages: None,
        };
        if copier.is_none() {
            // The header is lost, the chunks after it are not: the new file gets an
            // empty profile.
            let Some(o) = out.take() else {
                return Err(bad_magic());
            };
            copier = Some(Copier::new(input, input_bytes, out_path, o, String::new())?);
            header_damage = Some(Damage {
                what: format!(
                    "the MCAP header record (its profile is not kept): {}",
                    region.what
                ),
                ..region
            });
        } else {
            damage.push(region);
        }
        pos = next;
    }
    if let Some((d, _)) = skipped.take() {
        damage.push(d);
    }
    if !input_complete && stop_reason.is_none() {
        stop_reason = Some(format!(
            "the file ends after the record ending at byte {valid_prefix_bytes}, before its data-end record"
        ));
    }

    let Some(mut copier) = copier else {
        return Err(Error::Truncated {
            path: input.to_path_buf(),
        });
    };
    copier
        .writer
        .finish()
        .map_err(|e| Error::mcap(out_path, e))?;
    let mut out = copier.writer.into_inner();
    let mut report = copier.report;
    report.output_bytes = out
        .seek(SeekFrom::End(0))
        .map_err(|e| Error::io("seek in", out_path, e))?;
    report.valid_prefix_bytes = valid_prefix_bytes;
    report.input_complete = input_complete;
    report.stop_reason = stop_reason;
    report.messages_in_skipped_chunks = damage.iter().filter_map(|d| d.messages).sum();
    report.damage = header_damage.into_iter().chain(damage).collect();
    Ok((report, out))
}
