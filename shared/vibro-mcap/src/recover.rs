//! Rewriting a damaged recording (a crash: no summary, no footer, perhaps half a chunk;
//! or bytes garbled anywhere) into a valid file that holds every message whose bytes
//! are intact, and says what it could not keep.
//!
//! **What "intact" means.** Nothing in an MCAP file proves a single message: the proof
//! is its chunk's CRC, over the chunk's uncompressed records. A message is *intact*,
//! and kept, when
//!
//! 1. its chunk's compressed records and its CRC field are undamaged (the CRC then
//!    checks out over the decompressed records, and proves every one of them);
//! 2. its chunk can be found: either its own frame and header fields that locate the
//!    records (opcode, length, compression, records length) are undamaged, or the
//!    file's summary section is intact (its CRC in the footer checks out) and its chunk
//!    index says where the chunk's records are. The header's times and its
//!    uncompressed size are not needed: a size that disagrees with the records is
//!    ignored when the CRC checks out (issue 46: a first chunk claiming 2^40 bytes);
//! 3. its channel and that channel's schema survive somewhere intact: in any chunk that
//!    is intact by 1 and 2, in the summary section if its CRC checks out, or (with no
//!    proof either way) in a chunk without a CRC, in records outside chunks, or in a
//!    summary section without a CRC.
//!
//! A chunk whose CRC fails is dropped whole: the CRC does not say which of its records
//! changed, and keeping the others could keep an altered one. A CRC of 0 means "not
//! computed"; in a file where one chunk's CRC (not 0) checks out, the writer computes
//! them, so a chunk with 0 had its CRC zeroed by damage and proves nothing: it is
//! skipped, and so are definitions found only in such chunks, or in a summary section
//! whose CRC is 0. Definitions outside chunks count only when a record of the data
//! section follows them (not the summary's, read by a walk that missed the data end). A message is never
//! invented: in a file with chunks, a record outside them that frames as a message is
//! kept only on a channel that is itself defined outside chunks (a damaged chunk's
//! opcode can read as a message's, with a known channel ID in its first bytes).
//!
//! **How.** The summary section is read first, through the footer, and used only if
//! its CRC checks out (or it has none). Then the data section is walked record by
//! record, twice: once for the schemas and channels (skipped when the summary defines
//! every channel), once to copy. A chunk is copied if it decompresses, its CRC checks
//! out and its records parse (cut into records by `guard`, not by mcap); one that does
//! not is skipped and counted, with the messages its records or the message-index
//! records after it list. A chunk that the summary's index places at the walk's
//! position is read through the index when its own header is damaged. A record that
//! cannot be parsed, or one that claims to run past the end of the data, makes the walk
//! *resynchronise*: it scans forward for the next record that proves itself intact (a
//! chunk whose records parse and whose CRC checks out, an attachment with a CRC that
//! checks out, or a chunk the summary's index lists) and carries on there; the bytes in
//! between are a damaged region. A record without a proof of its own (a message index,
//! metadata, a chunk whose CRC failed) that contains the start of an intact chunk is
//! damage too (a garbled length that swallowed the chunk), and the walk resumes at the
//! chunk. Reading stops at the data-end record, at the summary section when it is
//! known, or where nothing intact follows the damage.
//!
//! **What was lost** is in [`RecoverReport`] and, in the new file, in a metadata record
//! named [`RECOVERY_METADATA`] ([`RecoveryRecord`]), so that `vibro_mcap::info` of the
//! result reports the losses instead of a clean file. With an intact statistics record
//! the count of dropped messages is exact (the statistics' count less the messages
//! kept); otherwise it is a lower bound.

use crate::{guard, Error, Result};
use mcap::records::{op, ChunkIndex, Record as McapRecord};
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// The name of the metadata record in which a recovered file says what was lost
/// ([`RecoveryRecord`]).
pub const RECOVERY_METADATA: &str = "vibrocomp.recovery";

/// How many skipped byte ranges a [`RecoveryRecord`] lists (all are counted).
pub const MAX_LISTED_RANGES: usize = 32;

/// What [`recover`] found and wrote.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RecoverReport {
    pub input: PathBuf,
    pub output: PathBuf,
    /// Size of the damaged file.
    pub input_bytes: u64,
    /// Bytes of the damaged file up to the end of the last record read whole.
    pub valid_prefix_bytes: u64,
    /// The input reached the end of its data section (its data-end record, or the
    /// summary section an intact footer points at).
    pub input_complete: bool,
    /// Why reading stopped early, if it did.
    pub stop_reason: Option<String>,
    /// The input ends inside a record (what a crash leaves): the bytes after
    /// `valid_prefix_bytes` are a record cut short, not damage found in the file.
    pub cut_short: bool,
    /// How the input's summary section was used (see [`SummaryUse`]).
    pub summary_section: SummaryUse,
    /// Chunks copied.
    pub chunks_recovered: u64,
    /// Of them, chunks whose header was damaged (a wrong uncompressed size, a garbled
    /// frame or compression field) but whose records were read all the same, their CRC
    /// checking out: through the summary's chunk index, or despite the wrong size.
    pub chunks_repaired: u64,
    /// Complete chunks skipped because their CRC or compression was broken.
    pub chunks_skipped: u64,
    /// Messages copied, in total and per topic.
    pub messages_recovered: u64,
    pub messages_per_topic: BTreeMap<String, u64>,
    /// What the input's statistics record says it held, if its summary section's CRC
    /// checks out: the losses are then counted exactly.
    pub expected: Option<Expected>,
    /// Messages dropped: exactly `expected.messages - messages_recovered` when the
    /// statistics are known (`messages_dropped_exact`), else those known to be lost
    /// (in skipped chunks and without a channel), a lower bound.
    pub messages_dropped: u64,
    pub messages_dropped_exact: bool,
    /// Messages in the skipped chunks, as listed by their records or message-index
    /// records (a lower bound: a skipped chunk with neither readable counts 0).
    pub messages_in_skipped_chunks: u64,
    /// Messages of intact chunks dropped because their channel, or its schema,
    /// survives nowhere intact.
    pub messages_orphaned: u64,
    /// Schema or channel IDs defined twice with different content by sources of the
    /// same standing; the first definition is kept.
    pub conflicting_definitions: u64,
    /// Every stretch of the input that was not copied, in file order, with the reason;
    /// the file's end after the last record read is in [`RecoverReport::stop_reason`].
    pub damage: Vec<Damage>,
    /// Bytes of the input not copied: the damaged regions, the skipped chunks, and
    /// after the last record read, the rest of the file.
    pub bytes_skipped: u64,
    pub attachments: u64,
    pub metadata: u64,
    /// Whether something the input holds is not in the output: with the statistics,
    /// fewer messages, attachments or metadata records than they count; without them,
    /// a skipped chunk, a damaged region, a message without its channel, or damage
    /// at the end that is not a record cut short. A file that merely ends early (a
    /// crash) loses its last, unfinished record: that is `cut_short`, not a loss here.
    /// `vibrocomp log recover` exits with status 3 when this is true.
    pub losses: bool,
    /// Size of the recovered file.
    pub output_bytes: u64,
}

/// What an input's statistics record counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Expected {
    pub messages: u64,
    pub attachments: u64,
    pub metadata: u64,
}

/// How [`recover`] used the input's summary section.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SummaryUse {
    /// No footer at the end of the file (a crash), or a footer without a summary.
    Absent,
    /// Its CRC checks out: its schemas, channels, chunk index and statistics were used.
    Verified,
    /// It has no CRC (0): its schemas and channels were used where nothing intact
    /// defines them, its index and statistics were not.
    Unverified,
    /// Its CRC fails: not used.
    CrcFailed,
    /// The footer points outside the file, or its records do not parse: not used.
    Unreadable,
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
    /// Messages known to be lost in it (a skipped chunk's message count), if known.
    pub messages: Option<u64>,
}

/// What a recovered file says it lost: the entries of its [`RECOVERY_METADATA`]
/// metadata record, written by [`recover`] and read back by `vibro_mcap::info`.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RecoveryRecord {
    /// The damaged file's name.
    pub input: String,
    pub input_bytes: u64,
    pub messages_kept: u64,
    /// Exact when `messages_expected` is known, else a lower bound.
    pub messages_dropped: u64,
    pub messages_expected: Option<u64>,
    pub messages_in_skipped_chunks: u64,
    pub messages_orphaned: u64,
    pub chunks_kept: u64,
    pub chunks_skipped: u64,
    /// Damaged regions and skipped chunks, and their bytes.
    pub regions_skipped: u64,
    pub bytes_skipped: u64,
    /// The first [`MAX_LISTED_RANGES`] of them, `start..end` in bytes of the damaged
    /// file, comma-separated.
    pub skipped_ranges: String,
    /// Bytes of a last record cut short (a crash).
    pub bytes_cut: u64,
    /// [`RecoverReport::losses`].
    pub losses: bool,
}

impl RecoveryRecord {
    fn from_report(r: &RecoverReport) -> RecoveryRecord {
        let listed: Vec<String> = r
            .damage
            .iter()
            .take(MAX_LISTED_RANGES)
            .map(|d| format!("{}..{}", d.start_byte, d.end_byte))
            .collect();
        let mut skipped_ranges = listed.join(",");
        if r.damage.len() > MAX_LISTED_RANGES {
            skipped_ranges += &format!(",+{}", r.damage.len() - MAX_LISTED_RANGES);
        }
        let input = r.input.file_name().map_or_else(
            || r.input.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        RecoveryRecord {
            input: input.chars().take(120).collect(),
            input_bytes: r.input_bytes,
            messages_kept: r.messages_recovered,
            messages_dropped: r.messages_dropped,
            messages_expected: r.expected.map(|e| e.messages),
            messages_in_skipped_chunks: r.messages_in_skipped_chunks,
            messages_orphaned: r.messages_orphaned,
            chunks_kept: r.chunks_recovered,
            chunks_skipped: r.chunks_skipped,
            regions_skipped: r.damage.len() as u64,
            bytes_skipped: r.damage.iter().map(|d| d.end_byte - d.start_byte).sum(),
            skipped_ranges,
            bytes_cut: if r.cut_short {
                r.input_bytes.saturating_sub(r.valid_prefix_bytes)
            } else {
                0
            },
            losses: r.losses,
        }
    }

    /// The metadata entries.
    pub fn to_entries(&self) -> BTreeMap<String, String> {
        let mut e = BTreeMap::new();
        let mut put = |k: &str, v: String| {
            e.insert(k.to_string(), v);
        };
        put("input", self.input.clone());
        put("input_bytes", self.input_bytes.to_string());
        put("messages_kept", self.messages_kept.to_string());
        put("messages_dropped", self.messages_dropped.to_string());
        if let Some(n) = self.messages_expected {
            put("messages_expected", n.to_string());
        }
        put(
            "messages_in_skipped_chunks",
            self.messages_in_skipped_chunks.to_string(),
        );
        put("messages_orphaned", self.messages_orphaned.to_string());
        put("chunks_kept", self.chunks_kept.to_string());
        put("chunks_skipped", self.chunks_skipped.to_string());
        put("regions_skipped", self.regions_skipped.to_string());
        put("bytes_skipped", self.bytes_skipped.to_string());
        put("skipped_ranges", self.skipped_ranges.clone());
        put("bytes_cut", self.bytes_cut.to_string());
        put("losses", self.losses.to_string());
        e
    }

    /// Reads the entries of a [`RECOVERY_METADATA`] record; a missing or unreadable
    /// count is 0 (the record may come from another version or another program).
    pub fn from_entries(entries: &BTreeMap<String, String>) -> RecoveryRecord {
        let n = |k: &str| entries.get(k).and_then(|v| v.parse().ok()).unwrap_or(0);
        let text = |k: &str| {
            entries
                .get(k)
                .map(|v| v.chars().take(1000).collect())
                .unwrap_or_default()
        };
        RecoveryRecord {
            input: text("input"),
            input_bytes: n("input_bytes"),
            messages_kept: n("messages_kept"),
            messages_dropped: n("messages_dropped"),
            messages_expected: entries
                .get("messages_expected")
                .and_then(|v| v.parse().ok()),
            messages_in_skipped_chunks: n("messages_in_skipped_chunks"),
            messages_orphaned: n("messages_orphaned"),
            chunks_kept: n("chunks_kept"),
            chunks_skipped: n("chunks_skipped"),
            regions_skipped: n("regions_skipped"),
            bytes_skipped: n("bytes_skipped"),
            skipped_ranges: text("skipped_ranges"),
            bytes_cut: n("bytes_cut"),
            losses: entries.get("losses").is_some_and(|v| v == "true"),
        }
    }
}

// ---------------------------------------------------------------------------------
// Reading the input

/// Opcode, 8-byte length.
const FRAME_BYTES: u64 = 9;
/// Why a chunk without a CRC is skipped in a file whose chunks carry one.
const ZEROED_CRC: &str =
    "chunk without a CRC (0) in a file whose chunks carry one: a zeroed CRC proves nothing";
/// A chunk body's fields before its compression string: start and end times,
/// uncompressed size, CRC.
const CHUNK_FIXED_BYTES: u64 = 8 + 8 + 8 + 4;
/// Where a chunk's CRC field lies in its record (after the frame and three u64).
const CHUNK_CRC_AT: u64 = FRAME_BYTES + 8 + 8 + 8;
/// The smallest chunk record: the fixed fields, an empty compression string and a
/// records length.
const MIN_CHUNK_BYTES: u64 = FRAME_BYTES + CHUNK_FIXED_BYTES + 4 + 8;

/// Where an attachment body's name length lies (after its log and create times), and
/// the fixed fields of an attachment body: times, name and media-type lengths, data
/// length, CRC.
const ATTACHMENT_NAME_AT: u64 = 8 + 8;
const ATTACHMENT_FIXED_BYTES: u64 = 8 + 8 + 4 + 4 + 8 + 4;

/// The largest record read whole: a chunk of `guard::MAX_CHUNK_BYTES` that did not
/// compress, with room for its header. A length beyond it is damage, not an
/// allocation.
const MAX_RECORD_BYTES: u64 = guard::MAX_CHUNK_BYTES + (1 << 20);
/// The largest summary section read (a summary is indexes: a 100 GB recording's is a
/// few MB).
const MAX_SUMMARY_BYTES: u64 = 256 << 20;
/// Footer record (opcode, length, summary start, summary offset start, CRC), then the
/// closing magic.
const FOOTER_BYTES: u64 = FRAME_BYTES + 8 + 8 + 4;
/// The bytes read from the input at a time: a walk over small records costs one read
/// per window, not a seek and a read per record (issue 46: 11.65 M system calls for
/// 100 MiB of 9-byte records).
const WINDOW_BYTES: usize = 1 << 20;
/// The bytes scanned at a time while resynchronising.
const SCAN_BYTES: u64 = 64 * 1024;

/// Reads `buf.len()` bytes at `pos`; false if the input ends first.
fn read_exact_at(
    inner: &mut (impl Read + Seek),
    pos: u64,
    buf: &mut [u8],
) -> std::io::Result<bool> {
    inner.seek(SeekFrom::Start(pos))?;
    match inner.read_exact(buf) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

/// The damaged file, read through a window of [`WINDOW_BYTES`].
struct Input<R> {
    inner: R,
    path: PathBuf,
    /// Its size: nothing at or after it is read.
    len: u64,
    window: Vec<u8>,
    window_at: u64,
}

impl<R: Read + Seek> Input<R> {
    fn new(inner: R, path: &Path, len: u64) -> Input<R> {
        Input {
            inner,
            path: path.to_path_buf(),
            len,
            window: Vec::new(),
            window_at: 0,
        }
    }

    /// Fills `buf` with the bytes at `pos`; false if the input ends first.
    fn read_at(&mut self, pos: u64, buf: &mut [u8]) -> Result<bool> {
        let n = buf.len() as u64;
        if pos.checked_add(n).is_none_or(|end| end > self.len) {
            return Ok(false);
        }
        let io = |path: &Path, e| Error::io("read", path, e);
        if buf.len() > WINDOW_BYTES / 4 {
            return read_exact_at(&mut self.inner, pos, buf).map_err(|e| io(&self.path, e));
        }
        let window_end = self.window_at + self.window.len() as u64;
        if pos < self.window_at || pos + n > window_end {
            // pos + n <= len, so the window holds at least n bytes.
            let fill = (self.len - pos).min(WINDOW_BYTES as u64);
            self.window
                .resize(usize::try_from(fill).unwrap_or(WINDOW_BYTES), 0);
            self.window_at = pos;
            let whole = read_exact_at(&mut self.inner, pos, &mut self.window)
                .map_err(|e| io(&self.path, e))?;
            if !whole {
                self.window.clear();
                return Ok(false);
            }
        }
        let at = usize::try_from(pos - self.window_at).unwrap_or(0);
        buf.copy_from_slice(&self.window[at..at + buf.len()]);
        Ok(true)
    }

    fn u32_at(&mut self, pos: u64) -> Result<Option<u32>> {
        let mut b = [0u8; 4];
        Ok(self.read_at(pos, &mut b)?.then(|| u32::from_le_bytes(b)))
    }
}

/// One record read at a position of the input.
enum Framed {
    /// The data ends there.
    End,
    /// A record whose body is in the buffer; it ends at the given byte.
    Record { opcode: u8, end: u64 },
    /// The file ends inside the record (what a crash leaves), and why.
    Cut(String),
    /// A record that cannot be framed, and why.
    Bad(String),
}

/// Frames the record at `pos` into `body`: it must end by `limit` (the end of the data
/// section if known, else of the file) and be at most [`MAX_RECORD_BYTES`] long, so a
/// garbled length never becomes a large allocation.
fn frame<R: Read + Seek>(
    input: &mut Input<R>,
    pos: u64,
    limit: u64,
    body: &mut Vec<u8>,
) -> Result<Framed> {
    if pos >= limit {
        return Ok(Framed::End);
    }
    let cut = || format!("the file ends inside a record that starts at byte {pos}");
    let mut head = [0u8; FRAME_BYTES as usize];
    if pos + FRAME_BYTES > limit || !input.read_at(pos, &mut head)? {
        return Ok(if limit == input.len {
            Framed::Cut(cut())
        } else {
            Framed::Bad(format!(
                "a record at byte {pos} runs past the end of the data section (byte {limit})"
            ))
        });
    }
    let opcode = head[0];
    let mut len = [0u8; 8];
    len.copy_from_slice(&head[1..]);
    let len = u64::from_le_bytes(len);
    let left = limit - pos - FRAME_BYTES;
    if len > left {
        let claim = format!("record 0x{opcode:02X} claims {len} bytes, {left} are left");
        return Ok(if limit == input.len {
            Framed::Cut(format!("{} ({claim})", cut()))
        } else {
            Framed::Bad(format!(
                "a record at byte {pos} runs past the end of the data section at byte {limit} ({claim})"
            ))
        });
    }
    if len > MAX_RECORD_BYTES {
        return Ok(Framed::Bad(format!(
            "record 0x{opcode:02X} at byte {pos} claims {len} bytes, more than the {MAX_RECORD_BYTES} a record may have here"
        )));
    }
    body.resize(usize::try_from(len).unwrap_or(0), 0);
    if !input.read_at(pos + FRAME_BYTES, body)? {
        return Ok(Framed::Cut(cut()));
    }
    Ok(Framed::Record {
        opcode,
        end: pos + FRAME_BYTES + len,
    })
}

/// Decompresses a zstd chunk's records into `buf`. `size` (the header's) is tried
/// first; if the records do not fit it, they are decompressed as a stream, at most
/// `guard::MAX_CHUNK_BYTES` of them: a garbled size is a hint that failed, not a reason
/// to lose the chunk or to allocate what it claims.
fn decompress(data: &[u8], size: u64, buf: &mut Vec<u8>) -> std::result::Result<(), String> {
    buf.clear();
    if size <= guard::MAX_CHUNK_BYTES {
        buf.reserve(usize::try_from(size).unwrap_or(0));
        let bulk =
            zstd::bulk::Decompressor::new().and_then(|mut d| d.decompress_to_buffer(data, buf));
        if bulk.is_ok() {
            return Ok(());
        }
        buf.clear();
    }
    let decoder = zstd::stream::read::Decoder::with_buffer(data)
        .map_err(|e| format!("chunk does not decompress: {e}"))?;
    decoder
        .take(guard::MAX_CHUNK_BYTES + 1)
        .read_to_end(buf)
        .map_err(|e| format!("chunk does not decompress: {e}"))?;
    if buf.len() as u64 > guard::MAX_CHUNK_BYTES {
        return Err(format!(
            "chunk decompresses to more than the {} bytes accepted",
            guard::MAX_CHUNK_BYTES
        ));
    }
    Ok(())
}

/// A chunk's uncompressed records, checked against its CRC (`crc`, 0: none) and
/// returned with whether their length is the `size` its header claims. A size that
/// disagrees is accepted when the CRC proves the records, and refused without a CRC.
fn chunk_bytes<'b>(
    compression: &str,
    crc: u32,
    size: u64,
    data: &'b [u8],
    buf: &'b mut Vec<u8>,
) -> std::result::Result<(&'b [u8], bool), String> {
    let records: &[u8] = match compression {
        "" => data,
        "zstd" => {
            decompress(data, size, buf)?;
            buf
        }
        other => {
            return Err(format!(
                "chunk compression {:?} is not supported (only zstd or none)",
                other.chars().take(16).collect::<String>()
            ))
        }
    };
    let size_ok = records.len() as u64 == size;
    if crc == 0 {
        if !size_ok {
            return Err(format!(
                "chunk holds {} bytes uncompressed, its header says {size}, and it has no CRC to tell which is right",
                records.len()
            ));
        }
    } else {
        let calculated = crc32fast::hash(records);
        if calculated != crc {
            return Err(format!(
                "chunk CRC failed (expected {crc:08X}, got {calculated:08X})"
            ));
        }
    }
    Ok((records, size_ok))
}

/// The parsed records of a chunk's uncompressed bytes, or why they do not parse.
fn parse_records(bytes: &[u8]) -> std::result::Result<Vec<McapRecord<'_>>, String> {
    guard::records(bytes)
        .map_err(|e| format!("in a chunk: {e}"))?
        .into_iter()
        .map(|(opcode, body)| {
            mcap::parse_record(opcode, body)
                .map_err(|e| format!("in a chunk: record 0x{opcode:02X}: {e}"))
        })
        .collect()
}

/// Messages in a chunk that could not be read, if its records still frame without
/// the CRC.
fn count_messages(compression: &str, size: u64, data: &[u8]) -> Option<u64> {
    let mut buf = Vec::new();
    let bytes = match compression {
        "" => data,
        "zstd" => {
            decompress(data, size, &mut buf).ok()?;
            &buf
        }
        _ => return None,
    };
    let records = guard::records(bytes).ok()?;
    Some(
        records
            .iter()
            .filter(|(opcode, _)| *opcode == op::MESSAGE)
            .count() as u64,
    )
}

/// The record's length and the u32 at byte `field_at` of its body, if the bytes at
/// `pos` start a record with `opcode` whose length fits before `limit`: the first,
/// cheap test of a candidate while resynchronising.
fn peek<R: Read + Seek>(
    input: &mut Input<R>,
    (pos, limit): (u64, u64),
    opcode: u8,
    field_at: u64,
) -> Result<Option<(u64, u64)>> {
    // The longest head asked for is a chunk's (its compression length).
    let mut head = [0u8; (FRAME_BYTES + CHUNK_FIXED_BYTES + 4) as usize];
    let want = usize::try_from(FRAME_BYTES + field_at.min(CHUNK_FIXED_BYTES) + 4).unwrap_or(0);
    let head = &mut head[..want];
    if pos + want as u64 > limit || !input.read_at(pos, head)? || head[0] != opcode {
        return Ok(None);
    }
    let mut n = [0u8; 8];
    n.copy_from_slice(&head[1..9]);
    let len = u64::from_le_bytes(n);
    let mut c = [0u8; 4];
    c.copy_from_slice(&head[want - 4..]);
    let field = u64::from(u32::from_le_bytes(c));
    Ok((len <= limit - pos - FRAME_BYTES).then_some((len, field)))
}

// ---------------------------------------------------------------------------------
// Schemas and channels, wherever they survive

#[derive(Clone, Debug, PartialEq)]
struct SchemaDef {
    name: String,
    encoding: String,
    data: Vec<u8>,
}

#[derive(Clone, Debug, PartialEq)]
struct ChannelDef {
    schema_id: u16,
    topic: String,
    message_encoding: String,
    metadata: BTreeMap<String, String>,
}

/// Where a definition was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Place {
    /// A chunk whose CRC checks out, or a summary section whose CRC checks out.
    Proven,
    /// A chunk without a CRC (0).
    UncheckedChunk,
    /// A record outside chunks.
    OutsideChunks,
    /// A summary section without a CRC.
    UnverifiedSummary,
}

/// A definition and where it was found.
#[derive(Clone, Debug)]
struct Found<T> {
    def: T,
    /// Somewhere [`Place::Proven`].
    proven: bool,
    /// Somewhere outside chunks.
    outside_chunks: bool,
    /// Only in chunks without a CRC: dropped when the file's chunks carry CRCs (a
    /// CRC of 0 is then a zeroed one, which proves nothing).
    unchecked_only: bool,
}

impl<T> Found<T> {
    fn new(def: T, place: Place) -> Found<T> {
        Found {
            def,
            proven: place == Place::Proven,
            outside_chunks: place == Place::OutsideChunks,
            unchecked_only: place == Place::UncheckedChunk,
        }
    }
}

/// The schemas and channels of the input, by ID: a proven definition wins over an
/// unproven one; between two of the same standing, the first.
#[derive(Default)]
struct Defs {
    schemas: HashMap<u16, Found<SchemaDef>>,
    channels: HashMap<u16, Found<ChannelDef>>,
    conflicts: u64,
}

fn add_def<T: PartialEq>(
    map: &mut HashMap<u16, Found<T>>,
    conflicts: &mut u64,
    id: u16,
    def: T,
    place: Place,
) {
    match map.entry(id) {
        std::collections::hash_map::Entry::Vacant(e) => {
            e.insert(Found::new(def, place));
        }
        std::collections::hash_map::Entry::Occupied(mut e) => {
            let found = e.get_mut();
            if found.def == def {
                let other = Found::new((), place);
                found.proven |= other.proven;
                found.outside_chunks |= other.outside_chunks;
                found.unchecked_only &= other.unchecked_only;
            } else if place == Place::Proven && !found.proven {
                *found = Found::new(def, place);
            } else {
                *conflicts += 1;
            }
        }
    }
}

impl Defs {
    fn add(&mut self, record: &McapRecord<'_>, place: Place) {
        match record {
            // Schema ID 0 means "no schema": a record with it is damage.
            McapRecord::Schema { header, data } if header.id != 0 => {
                let def = SchemaDef {
                    name: header.name.clone(),
                    encoding: header.encoding.clone(),
                    data: data.to_vec(),
                };
                add_def(
                    &mut self.schemas,
                    &mut self.conflicts,
                    header.id,
                    def,
                    place,
                );
            }
            McapRecord::Channel(c) => {
                let def = ChannelDef {
                    schema_id: c.schema_id,
                    topic: c.topic.clone(),
                    message_encoding: c.message_encoding.clone(),
                    metadata: c.metadata.clone(),
                };
                add_def(&mut self.channels, &mut self.conflicts, c.id, def, place);
            }
            _ => {}
        }
    }

    /// Drops what was found only in chunks without a CRC.
    fn drop_unchecked(&mut self) {
        self.schemas.retain(|_, f| !f.unchecked_only);
        self.channels.retain(|_, f| !f.unchecked_only);
    }
}

/// The input's summary section, as far as it can be trusted.
struct SummarySection {
    state: SummaryUse,
    /// Where it starts: the end of the data section.
    start: u64,
    records: Vec<McapRecord<'static>>,
    /// Chunk indexes by chunk start (a verified summary's only).
    chunks: BTreeMap<u64, ChunkIndex>,
    stats: Option<mcap::records::Statistics>,
}

impl SummarySection {
    fn unusable(state: SummaryUse) -> SummarySection {
        SummarySection {
            state,
            start: 0,
            records: Vec::new(),
            chunks: BTreeMap::new(),
            stats: None,
        }
    }

    /// Whether it defines every channel its statistics and chunk indexes mention, with
    /// their schemas: then the data section need not be walked for definitions.
    fn defines_every_channel(&self, defs: &Defs) -> bool {
        if defs.channels.is_empty() {
            return false;
        }
        let counted = self
            .stats
            .iter()
            .flat_map(|s| s.channel_message_counts.keys());
        let indexed = self
            .chunks
            .values()
            .flat_map(|c| c.message_index_offsets.keys());
        counted.chain(indexed).all(|id| {
            defs.channels.get(id).is_some_and(|c| {
                c.def.schema_id == 0 || defs.schemas.contains_key(&c.def.schema_id)
            })
        })
    }
}

/// Reads the summary section through the footer at the end of the file, if there is
/// one; its CRC (over the section and the footer up to the CRC) decides whether it is
/// used.
fn read_summary<R: Read + Seek>(input: &mut Input<R>) -> Result<SummarySection> {
    let magic = mcap::MAGIC.len() as u64;
    let Some(footer_at) = input.len.checked_sub(FOOTER_BYTES + magic) else {
        return Ok(SummarySection::unusable(SummaryUse::Absent));
    };
    let mut footer = [0u8; FOOTER_BYTES as usize];
    if footer_at < magic || !input.read_at(footer_at, &mut footer)? {
        return Ok(SummarySection::unusable(SummaryUse::Absent));
    }
    let word = |at: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&footer[at..at + 8]);
        u64::from_le_bytes(b)
    };
    if footer[0] != op::FOOTER || word(1) != FOOTER_BYTES - FRAME_BYTES {
        return Ok(SummarySection::unusable(SummaryUse::Absent));
    }
    let start = word(9);
    let saved = u32::from_le_bytes([footer[25], footer[26], footer[27], footer[28]]);
    if start == 0 {
        return Ok(SummarySection::unusable(SummaryUse::Absent));
    }
    if start < magic || start > footer_at || footer_at - start > MAX_SUMMARY_BYTES {
        return Ok(SummarySection::unusable(SummaryUse::Unreadable));
    }
    // The section and the footer's fields before the CRC.
    let size = usize::try_from(footer_at - start).unwrap_or(0);
    let mut bytes = vec![0u8; size + (FOOTER_BYTES as usize - 4)];
    if !input.read_at(start, &mut bytes)? {
        return Ok(SummarySection::unusable(SummaryUse::Unreadable));
    }
    if saved != 0 && crc32fast::hash(&bytes) != saved {
        return Ok(SummarySection::unusable(SummaryUse::CrcFailed));
    }
    let Ok(framed) = guard::records(&bytes[..size]) else {
        return Ok(SummarySection::unusable(SummaryUse::Unreadable));
    };
    let mut out = SummarySection::unusable(if saved != 0 {
        SummaryUse::Verified
    } else {
        SummaryUse::Unverified
    });
    out.start = start;
    for (opcode, body) in framed {
        let Ok(record) = mcap::parse_record(opcode, body) else {
            return Ok(SummarySection::unusable(SummaryUse::Unreadable));
        };
        match record {
            McapRecord::ChunkIndex(c) if out.state == SummaryUse::Verified => {
                // Only an index that fits the data section can place a chunk.
                let fits = c.chunk_start_offset >= magic
                    && c.chunk_length >= MIN_CHUNK_BYTES
                    && c.chunk_start_offset
                        .checked_add(c.chunk_length)
                        .is_some_and(|end| end <= start);
                if fits {
                    out.chunks.insert(c.chunk_start_offset, c);
                }
            }
            McapRecord::Statistics(s) if out.state == SummaryUse::Verified => out.stats = Some(s),
            r @ (McapRecord::Schema { .. } | McapRecord::Channel(_)) => {
                out.records.push(r.into_owned())
            }
            _ => {}
        }
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------
// The walk over the data section

/// What a walk gives its visitor: the records of the chunks it reads and the records
/// outside chunks, in file order.
trait Visit {
    /// The records of a chunk read whole; `proven`: its CRC checked out.
    fn chunk(&mut self, proven: bool, records: &[McapRecord<'_>]) -> Result<()>;
    /// A record outside chunks (not the header or the data end), at `start..end`.
    fn record(&mut self, start: u64, end: u64, record: McapRecord<'_>) -> Result<()>;
}

/// What a walk found, besides what it gave its visitor.
#[derive(Default)]
struct Walked {
    header: Option<mcap::records::Header>,
    damage: Vec<Damage>,
    valid_prefix_bytes: u64,
    input_complete: bool,
    stop_reason: Option<String>,
    cut_short: bool,
    chunks_recovered: u64,
    chunks_repaired: u64,
    chunks_skipped: u64,
    /// Chunks read whose CRC (not 0) checked out: the file's writer computes CRCs.
    chunks_with_crc: u64,
    /// Any record read whole, or anything intact found after damage.
    found_anything: bool,
}

/// One step of the walk.
enum Step {
    /// The next record starts here.
    Next(u64),
    /// The data ends (`true`: where it should, at its data-end record or the summary).
    End(bool),
    /// Damage at the position: why, and whether it is a record cut short by the end of
    /// the file.
    Damage(String, bool),
}

struct Walker<'a, R> {
    input: &'a mut Input<R>,
    /// Chunk indexes by chunk start, from a verified summary.
    known_chunks: &'a BTreeMap<u64, ChunkIndex>,
    /// The end of the data section: the summary's start if verified, else the file's
    /// end.
    limit: u64,
    body: Vec<u8>,
    probe: Vec<u8>,
    chunk_buf: Vec<u8>,
    block: Vec<u8>,
    /// The file's chunks carry CRCs: one of 0 was zeroed by damage, and a chunk
    /// without one proves nothing (it is skipped, and no resync stops at it).
    require_crc: bool,
}

impl<'a, R: Read + Seek> Walker<'a, R> {
    fn new(
        input: &'a mut Input<R>,
        known_chunks: &'a BTreeMap<u64, ChunkIndex>,
        limit: u64,
        require_crc: bool,
    ) -> Walker<'a, R> {
        Walker {
            input,
            known_chunks,
            limit,
            body: Vec::new(),
            probe: Vec::new(),
            chunk_buf: Vec::new(),
            block: Vec::new(),
            require_crc,
        }
    }

    fn limit_known(&self) -> bool {
        self.limit < self.input.len
    }

    /// Walks the data section from the start, giving what it reads to `visit`.
    fn walk(&mut self, visit: &mut impl Visit) -> Result<Walked> {
        let mut out = Walked::default();
        // A skipped chunk, and whether the message-index records right after it count
        // its messages (when its own records do not frame).
        let mut skipped: Option<(Damage, bool)> = None;
        let mut magic = [0u8; 8];
        let magic_ok = self.input.read_at(0, &mut magic)? && magic == *mcap::MAGIC;
        let mut pos = mcap::MAGIC.len() as u64;
        out.valid_prefix_bytes = pos;
        // Whether the record at `pos` should be the header.
        let mut first = true;
        let mut pending = (!magic_ok).then(|| {
            pos = 0;
            out.valid_prefix_bytes = 0;
            (
                "the file does not start with the MCAP magic".to_string(),
                false,
            )
        });
        loop {
            let (why, cut) = match pending.take() {
                Some(p) => p,
                None => match self.step(pos, first, visit, &mut out, &mut skipped)? {
                    Step::Next(next) => {
                        pos = next;
                        first = false;
                        continue;
                    }
                    Step::End(complete) => {
                        out.input_complete = complete;
                        break;
                    }
                    Step::Damage(why, cut) => (why, cut),
                },
            };
            if let Some((d, _)) = skipped.take() {
                out.damage.push(d);
            }
            let Some(next) = self.resync(pos + 1)? else {
                out.stop_reason = Some(why);
                out.cut_short = cut;
                break;
            };
            out.found_anything |= next < self.limit;
            let what = if first && pos > 0 {
                format!("the MCAP header record (its profile is not kept): {why}")
            } else {
                why
            };
            first = false;
            out.damage.push(Damage {
                start_byte: pos,
                end_byte: next,
                what,
                messages: None,
            });
            pos = next;
        }
        if let Some((d, _)) = skipped.take() {
            out.damage.push(d);
        }
        if !out.input_complete && out.stop_reason.is_none() {
            out.stop_reason = Some(format!(
                "the file ends after the record ending at byte {}, before its data-end record",
                out.valid_prefix_bytes
            ));
        }
        Ok(out)
    }

    /// Reads the record at `pos`.
    fn step(
        &mut self,
        pos: u64,
        first: bool,
        visit: &mut impl Visit,
        out: &mut Walked,
        skipped: &mut Option<(Damage, bool)>,
    ) -> Result<Step> {
        if pos >= self.limit {
            // The summary section (known) or the end of the file.
            return Ok(Step::End(self.limit_known()));
        }
        if let Some(index) = self.known_chunks.get(&pos).cloned() {
            if let Some((d, _)) = skipped.take() {
                out.damage.push(d);
            }
            let end = pos + index.chunk_length;
            self.indexed_chunk(pos, &index, visit, out, skipped)?;
            out.valid_prefix_bytes = end;
            out.found_anything = true;
            return Ok(Step::Next(end));
        }
        let mut body = std::mem::take(&mut self.body);
        let step = self.record_at(pos, first, &mut body, visit, out, skipped);
        self.body = body;
        step
    }

    fn record_at(
        &mut self,
        pos: u64,
        first: bool,
        body: &mut Vec<u8>,
        visit: &mut impl Visit,
        out: &mut Walked,
        skipped: &mut Option<(Damage, bool)>,
    ) -> Result<Step> {
        let (opcode, mut end) = match frame(self.input, pos, self.limit, body)? {
            Framed::End => return Ok(Step::End(self.limit_known())),
            Framed::Cut(why) => return Ok(Step::Damage(why, true)),
            Framed::Bad(why) => return Ok(Step::Damage(why, false)),
            Framed::Record { opcode, end } => (opcode, end),
        };
        if opcode == 0 {
            return Ok(Step::Damage(
                format!("record opcode 0x00 at byte {pos}: no MCAP record has it (zeroed or garbled bytes)"),
                false,
            ));
        }
        let record = match guard::record(opcode, body)
            .and_then(|()| mcap::parse_record(opcode, body).map_err(|e| e.to_string()))
        {
            Ok(record) => record,
            Err(e) => {
                return Ok(Step::Damage(
                    format!("unreadable record at byte {pos}: {e}"),
                    false,
                ))
            }
        };
        if first && !matches!(record, McapRecord::Header(_)) {
            return Ok(Step::Damage(
                format!("the record at byte {pos} (opcode 0x{opcode:02X}) is not the header"),
                false,
            ));
        }
        // The extent of a record that proves itself (a chunk, an attachment) is what its
        // fields say: a longer frame is a garbled length, and what follows the fields
        // is read as the next record (mcap ignores the excess).
        let used = match &record {
            McapRecord::Chunk { header, .. } => Some(
                CHUNK_FIXED_BYTES
                    + 4
                    + header.compression.len() as u64
                    + 8
                    + header.compressed_size,
            ),
            McapRecord::Attachment { header, data, .. } => Some(
                ATTACHMENT_FIXED_BYTES
                    + header.name.len() as u64
                    + header.media_type.len() as u64
                    + data.len() as u64,
            ),
            _ => None,
        };
        if let Some(used) = used {
            end = end.min(pos + FRAME_BYTES + used);
        }
        // A record without a proof of its own that holds the start of an intact chunk
        // (or of one the index places) is a garbled length that swallowed it. A chunk
        // with a CRC proves itself, or is looked into when it fails.
        let unproven = match &record {
            McapRecord::Attachment { crc, .. } => *crc == 0,
            McapRecord::Chunk { header, .. } => header.uncompressed_crc == 0,
            _ => true,
        };
        if unproven && end - pos > FRAME_BYTES {
            if let Some(inner) = self.intact_within(pos + 1, end)? {
                return Ok(Step::Damage(swallowed(opcode, pos, end, inner), false));
            }
        }
        match record {
            McapRecord::Header(h) => {
                if first {
                    out.header = Some(h);
                }
            }
            McapRecord::Chunk { header, data } => {
                if let Some((d, _)) = skipped.take() {
                    out.damage.push(d);
                }
                if let Err(why) = self.own_chunk(&header, &data, visit, out)? {
                    if let Some(inner) = self.intact_within(pos + 1, end)? {
                        let swallowed = swallowed(opcode, pos, end, inner);
                        return Ok(Step::Damage(format!("{why}; {swallowed}"), false));
                    }
                    out.chunks_skipped += 1;
                    let messages =
                        count_messages(&header.compression, header.uncompressed_size, &data);
                    let damage = Damage {
                        start_byte: pos,
                        end_byte: end,
                        what: why,
                        messages,
                    };
                    *skipped = Some((damage, messages.is_none()));
                }
            }
            McapRecord::DataEnd(_) => {
                // A data end proves nothing by itself: one that is not 4 bytes long,
                // not where a verified summary says the data ends, or followed by an
                // intact chunk or attachment, is a garbled opcode (a chunk's 0x06 read
                // as 0x0F), not the end.
                let misplaced = end - pos != FRAME_BYTES + 4
                    || (self.limit_known() && end != self.limit)
                    || (!self.limit_known() && self.intact_within(end, self.limit)?.is_some());
                if misplaced {
                    return Ok(Step::Damage(
                        format!(
                            "a data-end record at byte {pos} where the data section does not end"
                        ),
                        false,
                    ));
                }
                if let Some((d, _)) = skipped.take() {
                    out.damage.push(d);
                }
                out.valid_prefix_bytes = end;
                out.found_anything = true;
                return Ok(Step::End(true));
            }
            McapRecord::MessageIndex(index) => {
                if let Some((d, from_index)) = skipped.as_mut() {
                    if *from_index {
                        *d.messages.get_or_insert(0) += index.records.len() as u64;
                    }
                }
            }
            other => {
                if let Some((d, _)) = skipped.take() {
                    out.damage.push(d);
                }
                visit.record(pos, end, other)?;
            }
        }
        out.valid_prefix_bytes = end;
        out.found_anything = true;
        Ok(Step::Next(end))
    }

    /// Gives the records of a chunk read by its own header to `visit`, or says why it
    /// cannot be read.
    fn own_chunk(
        &mut self,
        header: &mcap::records::ChunkHeader,
        data: &[u8],
        visit: &mut impl Visit,
        out: &mut Walked,
    ) -> Result<std::result::Result<(), String>> {
        if self.require_crc && header.uncompressed_crc == 0 {
            return Ok(Err(ZEROED_CRC.to_string()));
        }
        let mut buf = std::mem::take(&mut self.chunk_buf);
        let read = chunk_bytes(
            &header.compression,
            header.uncompressed_crc,
            header.uncompressed_size,
            data,
            &mut buf,
        )
        .and_then(|(bytes, size_ok)| parse_records(bytes).map(|r| (r, size_ok)));
        let result = match read {
            Ok((records, size_ok)) => {
                visit.chunk(header.uncompressed_crc != 0, &records)?;
                out.chunks_recovered += 1;
                out.chunks_repaired += u64::from(!size_ok);
                out.chunks_with_crc += u64::from(header.uncompressed_crc != 0);
                Ok(())
            }
            Err(why) => Err(why),
        };
        self.chunk_buf = buf;
        Ok(result)
    }

    /// Reads the chunk that the summary's index places at `pos`: by its own header if
    /// that frames and reads, else through the index (its records are the last
    /// `compressed_size` bytes of the record, its CRC at its usual place), which needs a
    /// CRC to prove them.
    fn indexed_chunk(
        &mut self,
        pos: u64,
        index: &ChunkIndex,
        visit: &mut impl Visit,
        out: &mut Walked,
        skipped: &mut Option<(Damage, bool)>,
    ) -> Result<()> {
        let end = pos + index.chunk_length;
        let mut body = std::mem::take(&mut self.body);
        let mut own_why = None;
        if let Framed::Record {
            opcode: op::CHUNK,
            end: e,
        } = frame(self.input, pos, self.limit, &mut body)?
        {
            let parsed = guard::record(op::CHUNK, &body)
                .and_then(|()| mcap::parse_record(op::CHUNK, &body).map_err(|e| e.to_string()));
            if let (true, Ok(McapRecord::Chunk { header, data })) = (e == end, parsed) {
                match self.own_chunk(&header, &data, visit, out)? {
                    Ok(()) => {
                        self.body = body;
                        return Ok(());
                    }
                    Err(why) => own_why = Some(why),
                }
            }
        }
        self.body = body;
        // Within the record, and no larger than a record read whole may be.
        let at_records = end
            .checked_sub(index.compressed_size)
            .filter(|&a| a >= pos + MIN_CHUNK_BYTES)
            .filter(|_| index.compressed_size <= MAX_RECORD_BYTES);
        let why = match (at_records, self.input.u32_at(pos + CHUNK_CRC_AT)?) {
            (None, _) => format!(
                "the chunk the summary's index places at byte {pos} has a compressed size ({}) that does not fit its length ({}) or exceeds the {MAX_RECORD_BYTES} bytes a record may have here",
                index.compressed_size, index.chunk_length
            ),
            (_, None) | (_, Some(0)) => own_why.clone().unwrap_or_else(|| {
                format!("the chunk at byte {pos} does not frame, and without a CRC its records cannot be proven through the summary's index")
            }),
            (Some(at), Some(crc)) => {
                let mut data = vec![0u8; usize::try_from(index.compressed_size).unwrap_or(0)];
                if !self.input.read_at(at, &mut data)? {
                    format!("the file ends inside the chunk at byte {pos}")
                } else {
                    let mut buf = std::mem::take(&mut self.chunk_buf);
                    let read = chunk_bytes(&index.compression, crc, index.uncompressed_size, &data, &mut buf)
                        .and_then(|(bytes, _)| parse_records(bytes));
                    let result = match read {
                        Ok(records) => {
                            visit.chunk(true, &records)?;
                            out.chunks_recovered += 1;
                            out.chunks_repaired += 1;
                            out.chunks_with_crc += 1;
                            Ok(())
                        }
                        Err(why) => Err(why),
                    };
                    self.chunk_buf = buf;
                    match result {
                        Ok(()) => return Ok(()),
                        Err(why) => own_why.clone().unwrap_or(why),
                    }
                }
            }
        };
        out.chunks_skipped += 1;
        let messages = match at_records {
            Some(at) => {
                let mut data = vec![0u8; usize::try_from(index.compressed_size).unwrap_or(0)];
                if self.input.read_at(at, &mut data)? {
                    count_messages(&index.compression, index.uncompressed_size, &data)
                } else {
                    None
                }
            }
            None => None,
        };
        *skipped = Some((
            Damage {
                start_byte: pos,
                end_byte: end,
                what: why,
                messages,
            },
            messages.is_none(),
        ));
        Ok(())
    }

    /// Whether a chunk the summary's index places has a CRC (not 0) that checks out.
    fn an_indexed_crc_checks_out(&mut self) -> Result<bool> {
        let indexes: Vec<ChunkIndex> = self.known_chunks.values().cloned().collect();
        for index in indexes {
            let pos = index.chunk_start_offset;
            let end = pos + index.chunk_length;
            let Some(crc) = self.input.u32_at(pos + CHUNK_CRC_AT)?.filter(|&c| c != 0) else {
                continue;
            };
            let Some(at) = end
                .checked_sub(index.compressed_size)
                .filter(|&a| a >= pos + MIN_CHUNK_BYTES)
                .filter(|_| index.compressed_size <= MAX_RECORD_BYTES)
            else {
                continue;
            };
            let mut data = vec![0u8; usize::try_from(index.compressed_size).unwrap_or(0)];
            if !self.input.read_at(at, &mut data)? {
                continue;
            }
            let mut buf = std::mem::take(&mut self.chunk_buf);
            let checks_out = chunk_bytes(
                &index.compression,
                crc,
                index.uncompressed_size,
                &data,
                &mut buf,
            )
            .is_ok();
            self.chunk_buf = buf;
            if checks_out {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The first byte in `from..to` where an intact chunk or attachment starts, or a
    /// chunk that the summary's index places.
    fn intact_within(&mut self, from: u64, to: u64) -> Result<Option<u64>> {
        let to = to.min(self.limit);
        let known = self.known_chunks.range(from..to).next().map(|(&s, _)| s);
        let scan_to = known.unwrap_or(to);
        if let Some(p) = self.scan(from, scan_to)? {
            return Ok(Some(p));
        }
        Ok(known)
    }

    /// Where reading resumes after damage at `from - 1`: the next intact chunk or
    /// attachment, a chunk the index places, or the end of a known data section.
    fn resync(&mut self, from: u64) -> Result<Option<u64>> {
        if let Some(p) = self.intact_within(from, self.limit)? {
            return Ok(Some(p));
        }
        Ok(self.limit_known().then_some(self.limit))
    }

    /// The first byte in `from..to` where an intact chunk or attachment starts.
    fn scan(&mut self, from: u64, to: u64) -> Result<Option<u64>> {
        let mut block = std::mem::take(&mut self.block);
        let found = self.scan_with(from, to, &mut block);
        self.block = block;
        found
    }

    fn scan_with(&mut self, from: u64, to: u64, block: &mut Vec<u8>) -> Result<Option<u64>> {
        let mut at = from;
        while at < to {
            let n = usize::try_from((to - at).min(SCAN_BYTES)).unwrap_or(0);
            block.resize(n, 0);
            if !self.input.read_at(at, block)? {
                return Ok(None);
            }
            let candidates: Vec<u64> = block
                .iter()
                .enumerate()
                .filter(|(_, &b)| b == op::CHUNK || b == op::ATTACHMENT)
                .map(|(i, _)| at + i as u64)
                .collect();
            for pos in candidates {
                if self.intact_chunk_at(pos)? || self.intact_attachment_at(pos)? {
                    return Ok(Some(pos));
                }
            }
            at += n as u64;
        }
        Ok(None)
    }

    /// Whether the bytes at `pos` are a chunk record whose frame, header and records
    /// parse and whose CRC checks out. Cheap tests first (opcode, a length within the
    /// data, a known compression, a records length that fills the rest of the record),
    /// so that a scan over compressed data rarely decompresses anything.
    fn intact_chunk_at(&mut self, pos: u64) -> Result<bool> {
        let Some((len, compression_len)) =
            peek(self.input, (pos, self.limit), op::CHUNK, CHUNK_FIXED_BYTES)?
        else {
            return Ok(false);
        };
        if compression_len > 4 || len < CHUNK_FIXED_BYTES + 4 + compression_len + 8 {
            return Ok(false);
        }
        let mut rest = [0u8; 4 + 8];
        let rest = &mut rest[..compression_len as usize + 8];
        if !self
            .input
            .read_at(pos + FRAME_BYTES + CHUNK_FIXED_BYTES + 4, rest)?
        {
            return Ok(false);
        }
        if !matches!(&rest[..compression_len as usize], b"" | b"zstd") {
            return Ok(false);
        }
        let mut r = [0u8; 8];
        r.copy_from_slice(&rest[compression_len as usize..]);
        if u64::from_le_bytes(r) != len - (CHUNK_FIXED_BYTES + 4 + compression_len + 8) {
            return Ok(false);
        }
        let mut body = std::mem::take(&mut self.probe);
        let intact = match frame(self.input, pos, self.limit, &mut body)? {
            Framed::Record { opcode, .. } => {
                guard::record(opcode, &body).is_ok()
                    && match mcap::parse_record(opcode, &body) {
                        Ok(McapRecord::Chunk { header, data })
                            if !(self.require_crc && header.uncompressed_crc == 0) =>
                        {
                            let mut buf = Vec::new();
                            chunk_bytes(
                                &header.compression,
                                header.uncompressed_crc,
                                header.uncompressed_size,
                                &data,
                                &mut buf,
                            )
                            .and_then(|(bytes, _)| parse_records(bytes).map(|_| ()))
                            .is_ok()
                        }
                        _ => false,
                    }
            }
            _ => false,
        };
        self.probe = body;
        Ok(intact)
    }

    /// Whether the bytes at `pos` are an attachment record that frames, parses, and
    /// carries a CRC (not 0, which means "none") that checks out (`mcap::parse_record`
    /// checks it).
    fn intact_attachment_at(&mut self, pos: u64) -> Result<bool> {
        // Cheap tests first: the opcode, a length within the data and long enough for
        // the fixed fields, and a name that fits in it.
        let Some((len, name_len)) = peek(
            self.input,
            (pos, self.limit),
            op::ATTACHMENT,
            ATTACHMENT_NAME_AT,
        )?
        else {
            return Ok(false);
        };
        if len < ATTACHMENT_FIXED_BYTES || name_len > len - ATTACHMENT_FIXED_BYTES {
            return Ok(false);
        }
        let mut body = std::mem::take(&mut self.probe);
        let intact = match frame(self.input, pos, self.limit, &mut body)? {
            Framed::Record { opcode, .. } => {
                opcode == op::ATTACHMENT
                    && guard::record(opcode, &body).is_ok()
                    && matches!(
                        mcap::parse_record(opcode, &body),
                        Ok(McapRecord::Attachment { crc, .. }) if crc != 0
                    )
            }
            _ => false,
        };
        self.probe = body;
        Ok(intact)
    }
}

// ---------------------------------------------------------------------------------
// The two passes

/// The first pass: the schemas and channels of the data section.
struct Survey<'d> {
    defs: &'d mut Defs,
    /// Definitions outside chunks, kept once a record of the data section follows them
    /// (a message, a chunk, an attachment, metadata), dropped if a record of the
    /// summary section does: a walk that missed the data end (its opcode garbled) reads
    /// on into the summary, whose definitions prove nothing without its CRC.
    pending: Vec<McapRecord<'static>>,
}

impl Survey<'_> {
    fn commit(&mut self) {
        for r in std::mem::take(&mut self.pending) {
            self.defs.add(&r, Place::OutsideChunks);
        }
    }
}

impl Visit for Survey<'_> {
    fn chunk(&mut self, proven: bool, records: &[McapRecord<'_>]) -> Result<()> {
        self.commit();
        for r in records {
            let place = if proven {
                Place::Proven
            } else {
                Place::UncheckedChunk
            };
            self.defs.add(r, place);
        }
        Ok(())
    }

    fn record(&mut self, _: u64, _: u64, record: McapRecord<'_>) -> Result<()> {
        match record {
            McapRecord::Schema { .. } | McapRecord::Channel(_) => {
                self.pending.push(record.into_owned());
            }
            McapRecord::Message { .. }
            | McapRecord::Attachment { .. }
            | McapRecord::Metadata(_) => {
                self.commit();
            }
            McapRecord::ChunkIndex(_)
            | McapRecord::AttachmentIndex(_)
            | McapRecord::MetadataIndex(_)
            | McapRecord::Statistics(_)
            | McapRecord::SummaryOffset(_)
            | McapRecord::Footer(_) => self.pending.clear(),
            _ => {}
        }
        Ok(())
    }
}

/// The second pass: copies into the new file.
struct Copier<W: Write + Seek> {
    out_path: PathBuf,
    writer: mcap::Writer<W>,
    defs: Defs,
    /// The input has chunks: a message outside them is kept only on a channel defined
    /// outside them.
    chunked: bool,
    schemas_written: HashSet<u16>,
    /// Channels written, with their topics.
    channels_written: HashMap<u16, String>,
    /// Records outside chunks refused as damage.
    refused: Vec<Damage>,
    messages_recovered: u64,
    messages_per_topic: BTreeMap<String, u64>,
    messages_orphaned: u64,
    attachments: u64,
    metadata: u64,
}

impl<W: Write + Seek> Copier<W> {
    fn mcap(&self, e: mcap::McapError) -> Error {
        Error::mcap(&self.out_path, e)
    }

    /// Writes channel `id` (and its schema) into the new file if it is not there yet;
    /// `None` if it, or its schema, survives nowhere.
    fn channel(&mut self, id: u16) -> Result<Option<&str>> {
        if !self.channels_written.contains_key(&id) {
            let Some(c) = self.defs.channels.get(&id) else {
                return Ok(None);
            };
            let c = c.def.clone();
            if c.schema_id != 0 && !self.schemas_written.contains(&c.schema_id) {
                let Some(s) = self.defs.schemas.get(&c.schema_id) else {
                    return Ok(None);
                };
                let s = &s.def;
                self.writer
                    .add_schema_with_id(c.schema_id, &s.name, &s.encoding, &s.data)
                    .map_err(|e| Error::mcap(&self.out_path, e))?;
                self.schemas_written.insert(c.schema_id);
            }
            self.writer
                .add_channel_with_id(id, c.schema_id, &c.topic, &c.message_encoding, &c.metadata)
                .map_err(|e| self.mcap(e))?;
            self.channels_written.insert(id, c.topic);
        }
        Ok(self.channels_written.get(&id).map(String::as_str))
    }

    fn message(&mut self, header: &mcap::records::MessageHeader, data: &[u8]) -> Result<()> {
        let Some(topic) = self.channel(header.channel_id)?.map(str::to_string) else {
            self.messages_orphaned += 1;
            return Ok(());
        };
        *self.messages_per_topic.entry(topic).or_insert(0) += 1;
        self.messages_recovered += 1;
        self.writer
            .write_to_known_channel(header, data)
            .map_err(|e| self.mcap(e))
    }
}

impl<W: Write + Seek> Visit for Copier<W> {
    fn chunk(&mut self, _: bool, records: &[McapRecord<'_>]) -> Result<()> {
        for r in records {
            if let McapRecord::Message { header, data } = r {
                self.message(header, data)?;
            }
        }
        Ok(())
    }

    fn record(&mut self, start: u64, end: u64, record: McapRecord<'_>) -> Result<()> {
        match record {
            McapRecord::Message { header, data } => {
                let id = header.channel_id;
                let refused = self.chunked
                    && self
                        .defs
                        .channels
                        .get(&id)
                        .is_some_and(|c| !c.outside_chunks);
                if refused {
                    self.refused.push(Damage {
                        start_byte: start,
                        end_byte: end,
                        what: format!(
                            "a record outside the chunks that frames as a message on channel {id}, which is defined only inside chunks or in the summary: damaged bytes, not copied"
                        ),
                        messages: None,
                    });
                    return Ok(());
                }
                self.message(&header, &data)?;
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
                self.attachments += 1;
            }
            McapRecord::Metadata(m) => {
                self.writer.write_metadata(&m).map_err(|e| self.mcap(e))?;
                self.metadata += 1;
            }
            _ => {}
        }
        Ok(())
    }
}

/// Recovers `damaged` into a new file `out` (created, or a regular file emptied; never
/// through a link, into a FIFO or a device: `vibro_files::create_in_place`; zstd chunks).
pub fn recover(damaged: impl AsRef<Path>, out: impl AsRef<Path>) -> Result<RecoverReport> {
    let input = damaged.as_ref();
    let out_path = out.as_ref();
    let file = File::open(input).map_err(|e| Error::io("open", input, e))?;
    let input_bytes = file
        .metadata()
        .map_err(|e| Error::io("stat", input, e))?
        .len();
    let out_file = vibro_files::create_in_place(out_path, true)?;
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
    damaged: impl Read + Seek,
    input: &Path,
    input_bytes: u64,
    out: W,
    out_path: &Path,
) -> Result<(RecoverReport, W)> {
    let mut source = Input::new(damaged, input, input_bytes);
    // A file that ends before its magic does: nothing was ever written.
    let magic = mcap::MAGIC.len() as u64;
    if input_bytes <= magic {
        let mut head = [0u8; 8];
        let head = &mut head[..usize::try_from(input_bytes).unwrap_or(0)];
        if source.read_at(0, head)? && mcap::MAGIC.starts_with(head) {
            return Err(Error::Truncated {
                path: input.to_path_buf(),
            });
        }
    }

    let summary = read_summary(&mut source)?;
    let verified = summary.state == SummaryUse::Verified;
    let mut defs = Defs::default();
    if verified {
        for r in &summary.records {
            defs.add(r, Place::Proven);
        }
    }
    let no_chunks = BTreeMap::new();
    let (known_chunks, limit) = if verified {
        (&summary.chunks, summary.start)
    } else {
        (&no_chunks, input_bytes)
    };

    // First pass: the schemas and channels, unless the summary has them all. It also
    // tells whether there is anything to recover.
    let mut chunked = !known_chunks.is_empty();
    // Whether the file's chunks carry CRCs: one chunk whose CRC (not 0) checks out
    // shows that its writer computes them (a CRC that damage made up does not check
    // out), and then a CRC of 0 is a zeroed one.
    let mut walker = Walker::new(&mut source, known_chunks, limit, false);
    let require_crc = if verified && summary.defines_every_channel(&defs) {
        walker.an_indexed_crc_checks_out()?
    } else {
        let walked = walker.walk(&mut Survey {
            defs: &mut defs,
            pending: Vec::new(),
        })?;
        chunked |= walked.chunks_recovered + walked.chunks_skipped > 0;
        if walked.header.is_none() && !walked.found_anything {
            return Err(nothing_to_recover(input, input_bytes, &walked));
        }
        walked.chunks_with_crc > 0
    };
    if require_crc {
        defs.drop_unchecked();
    }
    // A summary without a CRC, in a file whose chunks carry CRCs, had its CRC zeroed by
    // damage: it proves nothing, and its definitions are not used.
    if summary.state == SummaryUse::Unverified && !require_crc {
        for r in &summary.records {
            defs.add(r, Place::UnverifiedSummary);
        }
    }

    // Second pass: the copy.
    let mut walker = Walker::new(&mut source, known_chunks, limit, require_crc);
    let profile = match frame(walker.input, magic, limit, &mut walker.body)? {
        Framed::Record {
            opcode: op::HEADER, ..
        } => match mcap::parse_record(op::HEADER, &walker.body) {
            Ok(McapRecord::Header(h)) if guard::record(op::HEADER, &walker.body).is_ok() => {
                h.profile
            }
            _ => String::new(),
        },
        _ => String::new(),
    };
    let writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(0)
        .profile(profile)
        .create(out)
        .map_err(|e| Error::mcap(out_path, e))?;
    let mut copier = Copier {
        out_path: out_path.to_path_buf(),
        writer,
        defs,
        chunked,
        schemas_written: HashSet::new(),
        channels_written: HashMap::new(),
        refused: Vec::new(),
        messages_recovered: 0,
        messages_per_topic: BTreeMap::new(),
        messages_orphaned: 0,
        attachments: 0,
        metadata: 0,
    };
    // Every proven channel is in the new file, with messages or without.
    let mut proven: Vec<u16> = copier
        .defs
        .channels
        .iter()
        .filter(|(_, c)| c.proven)
        .map(|(&id, _)| id)
        .collect();
    proven.sort_unstable();
    for id in proven {
        copier.channel(id)?;
    }
    let walked = walker.walk(&mut copier)?;

    let mut damage = walked.damage;
    damage.append(&mut copier.refused);
    damage.sort_by_key(|d| d.start_byte);
    let expected = summary.stats.as_ref().map(|s| Expected {
        messages: s.message_count,
        attachments: u64::from(s.attachment_count),
        metadata: u64::from(s.metadata_count),
    });
    let messages_in_skipped_chunks = damage.iter().filter_map(|d| d.messages).sum();
    let tail = if walked.input_complete {
        0
    } else {
        input_bytes.saturating_sub(walked.valid_prefix_bytes)
    };
    let losses = match expected {
        Some(e) => {
            copier.messages_recovered < e.messages
                || copier.attachments < e.attachments
                || copier.metadata < e.metadata
        }
        None => {
            walked.chunks_skipped > 0
                || copier.messages_orphaned > 0
                || !damage.is_empty()
                || (tail > 0 && !walked.cut_short)
        }
    };
    let mut report = RecoverReport {
        input: input.to_path_buf(),
        output: out_path.to_path_buf(),
        input_bytes,
        valid_prefix_bytes: walked.valid_prefix_bytes,
        input_complete: walked.input_complete,
        stop_reason: walked.stop_reason,
        cut_short: walked.cut_short && !walked.input_complete,
        summary_section: summary.state,
        chunks_recovered: walked.chunks_recovered,
        chunks_repaired: walked.chunks_repaired,
        chunks_skipped: walked.chunks_skipped,
        messages_recovered: copier.messages_recovered,
        messages_per_topic: std::mem::take(&mut copier.messages_per_topic),
        expected,
        messages_dropped: match expected {
            Some(e) => e.messages.saturating_sub(copier.messages_recovered),
            None => messages_in_skipped_chunks + copier.messages_orphaned,
        },
        messages_dropped_exact: expected.is_some(),
        messages_in_skipped_chunks,
        messages_orphaned: copier.messages_orphaned,
        conflicting_definitions: copier.defs.conflicts,
        bytes_skipped: damage
            .iter()
            .map(|d| d.end_byte - d.start_byte)
            .sum::<u64>()
            + tail,
        damage,
        attachments: copier.attachments,
        metadata: copier.metadata,
        losses,
        output_bytes: 0,
    };

    let record = mcap::records::Metadata {
        name: RECOVERY_METADATA.to_string(),
        metadata: RecoveryRecord::from_report(&report).to_entries(),
    };
    copier
        .writer
        .write_metadata(&record)
        .map_err(|e| Error::mcap(out_path, e))?;
    copier
        .writer
        .finish()
        .map_err(|e| Error::mcap(out_path, e))?;
    let mut out = copier.writer.into_inner();
    report.output_bytes = out
        .seek(SeekFrom::End(0))
        .map_err(|e| Error::io("seek in", out_path, e))?;
    Ok((report, out))
}

/// The reason given for a record that swallowed an intact one.
fn swallowed(opcode: u8, pos: u64, end: u64, inner: u64) -> String {
    format!(
        "record 0x{opcode:02X} at byte {pos} claims {} bytes, but an intact chunk or attachment starts inside it at byte {inner}",
        end - pos - FRAME_BYTES
    )
}

/// Why a file with no readable header and nothing intact after it cannot be recovered.
fn nothing_to_recover(input: &Path, input_bytes: u64, walked: &Walked) -> Error {
    let problem = walked.stop_reason.clone().unwrap_or_default();
    if walked.cut_short {
        return Error::Truncated {
            path: input.to_path_buf(),
        };
    }
    let magic = mcap::MAGIC.len() as u64;
    Error::Malformed {
        path: input.to_path_buf(),
        reason: if problem.starts_with("the file does not start with the MCAP magic") {
            format!(
                "not an MCAP log: it does not start with the MCAP magic, and none of its {input_bytes} bytes starts an intact MCAP chunk or attachment: nothing to recover"
            )
        } else {
            format!(
                "nothing to recover: its MCAP header record is unreadable ({problem}), and no intact chunk or attachment follows it (bytes {}..{input_bytes} scanned)",
                magic + 1
            )
        },
    }
}
