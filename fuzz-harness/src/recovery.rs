//! The promise of `vibro_mcap::recover`, checked against damage: every message whose
//! bytes are intact is kept, with exactly its original content, and no message is
//! invented or altered; recovery never panics and never reads outside the file.
//!
//! The damaged files all come from one small valid file, [`fixture`]: a few zstd
//! chunks, four channels (two sharing a schema, one without a schema, one first
//! defined in a later chunk), an attachment, metadata and a summary section, written
//! by the `mcap` crate. Its layout (where each chunk's records, CRC and framing fields
//! lie, which chunk defines which channel and schema, where the summary section and
//! footer lie) is read from the undamaged file with the `mcap` crate, not with the code
//! under test, and the damage is what differs between the damaged bytes and the
//! original (a truncated file: every byte after its end). A message is *intact*
//! (`vibro_mcap::recover`'s module doc has the reasons) when
//!
//! 1. its chunk's compressed records and its CRC field are undamaged;
//! 2. its chunk can be found: its opcode, length, compression and records-length
//!    fields are undamaged, or the summary section and footer are (the chunk index
//!    then places it);
//! 3. its channel's record and its schema's record each lie in a chunk intact by 1 and
//!    2, or the summary section and footer are undamaged.
//!
//! [`check_recovery`] asserts that the messages of the recovered file (read back by the
//! `mcap` crate, CRCs checked) include every intact message and are all messages of the
//! original (as a multiset: topic, schema, sequence, times, bytes).

use std::collections::{BTreeMap, HashMap};
use std::io::{Cursor, Read, Seek, SeekFrom};
use std::ops::Range;
use std::path::Path;
use std::sync::OnceLock;

/// A message as the `mcap` crate reads it: topic, schema name, sequence, log time,
/// publish time, bytes.
pub type MessageKey = (String, String, u32, u64, u64, Vec<u8>);

/// One chunk of the fixture.
#[derive(Clone, Debug)]
struct ChunkLayout {
    /// The whole record.
    record: Range<usize>,
    /// Its compressed records.
    records: Range<usize>,
    /// Its CRC field.
    crc: Range<usize>,
    /// The fields that frame it and locate its records: opcode and length;
    /// compression length, compression and records length.
    locate: [Range<usize>; 2],
    /// Channel and schema IDs whose records it holds.
    channels: Vec<u16>,
    schemas: Vec<u16>,
}

/// The undamaged file and its layout.
pub struct Fixture {
    pub bytes: Vec<u8>,
    chunks: Vec<ChunkLayout>,
    /// The summary section and the footer, up to its CRC's end.
    summary: Range<usize>,
    /// Each message, its chunk, and its channel's ID and schema ID.
    messages: Vec<(MessageKey, usize, u16, u16)>,
}

/// The fixture, built once.
pub fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(build_fixture)
}

fn build_fixture() -> Fixture {
    let bytes = write_fixture();
    let layout = read_layout(&bytes);
    match layout {
        Ok(f) => f,
        Err(e) => panic!("the fixture does not read back: {e}"),
    }
}

/// The small valid file: channels `/a` and `/b` (schemas A and B), `/c` on schema A
/// and `/d` without a schema added after the first messages (so that their records
/// lie in a later chunk), 36 messages with bytes that compress a little, an
/// attachment and a metadata record, chunks of about 300 uncompressed bytes, zstd.
fn write_fixture() -> Vec<u8> {
    let built = (|| -> mcap::McapResult<Vec<u8>> {
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(300))
            .profile("fixture")
            .create(Cursor::new(Vec::new()))?;
        let schema_a = w.add_schema("test.A", "raw", b"schema A")?;
        let schema_b = w.add_schema("test.B", "raw", b"schema B, longer")?;
        let none = BTreeMap::new();
        let a = w.add_channel(schema_a, "/a", "raw", &none)?;
        let b = w.add_channel(schema_b, "/b", "raw", &none)?;
        let mut channels = vec![a, b];
        for i in 0..36u32 {
            if i == 12 {
                channels.push(w.add_channel(schema_a, "/c", "raw", &none)?);
                let meta = BTreeMap::from([("k".to_string(), "v".to_string())]);
                channels.push(w.add_channel(0, "/d", "raw", &meta)?);
            }
            if i == 20 {
                w.attach(&mcap::Attachment {
                    log_time: 5,
                    create_time: 6,
                    name: "note.txt".into(),
                    media_type: "text/plain".into(),
                    data: std::borrow::Cow::Borrowed(b"an attachment"),
                })?;
                w.write_metadata(&mcap::records::Metadata {
                    name: "run".into(),
                    metadata: BTreeMap::from([("rig".to_string(), "3".to_string())]),
                })?;
            }
            let channel = channels[i as usize % channels.len()];
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i,
                log_time: 1_000 + u64::from(i) * 10,
                publish_time: 2_000 + u64::from(i) * 10,
            };
            let data: Vec<u8> = (0..24u32).map(|k| ((i * 7 + k * k) % 251) as u8).collect();
            w.write_to_known_channel(&header, &data)?;
        }
        w.finish()?;
        Ok(w.into_inner().into_inner())
    })();
    match built {
        Ok(bytes) => bytes,
        Err(e) => panic!("the fixture cannot be written: {e}"),
    }
}

/// The layout of the undamaged fixture, read with the `mcap` crate.
fn read_layout(bytes: &[u8]) -> Result<Fixture, String> {
    let e = |e: mcap::McapError| e.to_string();
    let footer = mcap::read::footer(bytes).map_err(e)?;
    let footer_at = bytes.len() - mcap::MAGIC.len() - (9 + 20);
    // The summary CRC covers the section and the footer up to its CRC field; the
    // recovery needs the CRC too.
    let summary =
        usize::try_from(footer.summary_start).map_err(|e| e.to_string())?..footer_at + 9 + 20;
    let index = mcap::Summary::read(bytes).map_err(e)?.ok_or("no summary")?;
    let mut chunks = Vec::new();
    let mut messages = Vec::new();
    let mut indexes = index.chunk_indexes.clone();
    indexes.sort_by_key(|c| c.chunk_start_offset);
    for c in &indexes {
        let start = c.chunk_start_offset as usize;
        let end = start + c.chunk_length as usize;
        let records = end - c.compressed_size as usize;
        let (header, data) = match mcap::parse_record(bytes[start], &bytes[start + 9..end]) {
            Ok(mcap::records::Record::Chunk { header, data }) => (header, data),
            _ => return Err(format!("no chunk at byte {start}")),
        };
        let mut layout = ChunkLayout {
            record: start..end,
            records: records..end,
            crc: start + 33..start + 37,
            locate: [start..start + 9, start + 37..records],
            channels: Vec::new(),
            schemas: Vec::new(),
        };
        for record in mcap::read::ChunkReader::new(header, &data).map_err(e)? {
            match record.map_err(e)? {
                mcap::records::Record::Channel(ch) => layout.channels.push(ch.id),
                mcap::records::Record::Schema { header, .. } => layout.schemas.push(header.id),
                _ => {}
            }
        }
        for m in index.stream_chunk(bytes, c).map_err(e)? {
            let m = m.map_err(e)?;
            let schema_id = m.channel.schema.as_ref().map_or(0, |s| s.id);
            messages.push((key(&m), chunks.len(), m.channel.id, schema_id));
        }
        chunks.push(layout);
    }
    Ok(Fixture {
        bytes: bytes.to_vec(),
        chunks,
        summary,
        messages,
    })
}

fn key(m: &mcap::Message<'_>) -> MessageKey {
    let schema = m
        .channel
        .schema
        .as_ref()
        .map_or(String::new(), |s| s.name.clone());
    (
        m.channel.topic.clone(),
        schema,
        m.sequence,
        m.log_time,
        m.publish_time,
        m.data.to_vec(),
    )
}

impl Fixture {
    /// The messages intact in `damaged` (see the module doc).
    pub fn intact_messages(&self, damaged: &[u8]) -> Vec<MessageKey> {
        let changed = |i: usize| i >= damaged.len() || damaged[i] != self.bytes[i];
        let undamaged = |r: &Range<usize>| !r.clone().any(changed);
        let summary_ok = damaged.len() == self.bytes.len() && undamaged(&self.summary);
        let chunk_ok: Vec<bool> = self
            .chunks
            .iter()
            .map(|c| {
                undamaged(&c.records)
                    && undamaged(&c.crc)
                    && (summary_ok || c.locate.iter().all(undamaged))
            })
            .collect();
        let defined = |found: &dyn Fn(&ChunkLayout) -> bool| {
            summary_ok
                || self
                    .chunks
                    .iter()
                    .zip(&chunk_ok)
                    .any(|(c, &ok)| ok && found(c))
        };
        self.messages
            .iter()
            .filter(|(_, chunk, channel, schema)| {
                chunk_ok[*chunk]
                    && defined(&|c| c.channels.contains(channel))
                    && (*schema == 0 || defined(&|c| c.schemas.contains(schema)))
            })
            .map(|(k, ..)| k.clone())
            .collect()
    }

    /// Byte ranges of the file's chunks, for a test's report.
    pub fn chunk_records(&self) -> Vec<Range<usize>> {
        self.chunks.iter().map(|c| c.record.clone()).collect()
    }
}

/// The input of a recovery: reads and seeks are checked to stay within the file.
struct Bounded<'a> {
    inner: Cursor<&'a [u8]>,
}

impl Read for Bounded<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let len = self.inner.get_ref().len() as u64;
        let pos = self.inner.position();
        assert!(
            pos + buf.len() as u64 <= len,
            "recover reads {} bytes at byte {pos} of a {len}-byte file",
            buf.len()
        );
        self.inner.read(buf)
    }
}

impl Seek for Bounded<'_> {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let len = self.inner.get_ref().len() as u64;
        let pos = self.inner.seek(to)?;
        assert!(
            pos <= len,
            "recover seeks to byte {pos} of a {len}-byte file"
        );
        Ok(pos)
    }
}

/// Multiset inclusion: the first element of `a` missing from `b`, if any.
fn missing_from<'k>(a: &'k [MessageKey], b: &[MessageKey]) -> Option<&'k MessageKey> {
    let mut count: HashMap<&MessageKey, i64> = HashMap::new();
    for k in b {
        *count.entry(k).or_insert(0) += 1;
    }
    a.iter().find(|k| {
        let n = count.entry(k).or_insert(0);
        *n -= 1;
        *n < 0
    })
}

/// Recovers `damaged` (a damaged copy of the [`fixture`]) and checks the promise:
/// every intact message kept, every message kept one of the original's, the new file
/// readable with CRCs that check out, the report's count right. A broken promise is a
/// panic that says which.
pub fn check_recovery(damaged: &[u8], what: &str) {
    let f = fixture();
    let intact = f.intact_messages(damaged);
    let result = vibro_mcap::recover_from_reader(
        Bounded {
            inner: Cursor::new(damaged),
        },
        Path::new("damaged.mcap"),
        damaged.len() as u64,
        Cursor::new(Vec::new()),
        Path::new("recovered.mcap"),
    );
    let (report, out) = match result {
        Ok(r) => r,
        Err(e) => {
            assert!(
                intact.is_empty(),
                "{what}: recover failed ({e}) with {} intact messages",
                intact.len()
            );
            return;
        }
    };
    let out = out.into_inner();
    let recovered: Vec<MessageKey> = match mcap::MessageStream::new(&out) {
        Ok(stream) => stream
            .map(|m| match m {
                Ok(m) => key(&m),
                Err(e) => panic!("{what}: the recovered file does not read back: {e}"),
            })
            .collect(),
        Err(e) => panic!("{what}: the recovered file does not open: {e}"),
    };
    assert_eq!(
        report.messages_recovered,
        recovered.len() as u64,
        "{what}: the report counts other messages than the file holds"
    );
    if let Some(k) = missing_from(&intact, &recovered) {
        panic!(
            "{what}: an intact message was not kept: {k:?} ({} intact, {} kept; report {report:?})",
            intact.len(),
            recovered.len()
        );
    }
    let original: Vec<MessageKey> = f.messages.iter().map(|(k, ..)| k.clone()).collect();
    if let Some(k) = missing_from(&recovered, &original) {
        panic!("{what}: a message kept is not one of the original's (invented or altered): {k:?}");
    }
}

/// The body of the fuzz target `mcap_recover`: `data` is a list of damage operations
/// on the [`fixture`], 4 bytes each (kind, offset high and low byte, argument), at most
/// 16: kind 0 flips the bits `argument | 1` of a byte, 1 zeroes a run of
/// `argument % 64 + 1` bytes, 2 fills such a run with `argument`, 3 cuts the file
/// there. Offsets are taken modulo the file's size.
pub fn mcap_recover(data: &[u8]) {
    let f = fixture();
    let mut bytes = f.bytes.clone();
    let mut cut = bytes.len();
    for op in data.chunks_exact(4).take(16) {
        let at = usize::from(u16::from_be_bytes([op[1], op[2]])) % f.bytes.len();
        let run = at..(at + usize::from(op[3] % 64) + 1).min(bytes.len());
        match op[0] % 4 {
            0 => bytes[at] ^= op[3] | 1,
            1 => bytes[run].fill(0),
            2 => bytes[run].fill(op[3]),
            _ => cut = cut.min(at),
        }
    }
    bytes.truncate(cut);
    check_recovery(&bytes, "fuzz input");
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fixture is what the checks assume: several chunks, messages in most,
    /// channels defined in more than one chunk.
    #[test]
    fn the_fixture_has_several_chunks_channels_and_a_summary() {
        let f = fixture();
        assert!(f.chunks.len() >= 4, "{} chunks", f.chunks.len());
        assert_eq!(f.messages.len(), 36);
        let defining: Vec<usize> = (0..f.chunks.len())
            .filter(|&k| !f.chunks[k].channels.is_empty())
            .collect();
        assert!(
            defining.len() >= 2,
            "channels defined in chunks {defining:?}"
        );
        assert_eq!(f.intact_messages(&f.bytes).len(), 36);
        assert!(f.bytes.len() < 8192, "{} bytes", f.bytes.len());
    }

    /// Damage at every byte of the fixture, three ways: one byte's bits flipped, the
    /// file cut there, a run of 16 bytes zeroed. Every recovery keeps every intact
    /// message and nothing else of its own making (`check_recovery`).
    #[test]
    fn damage_at_every_offset_keeps_every_intact_message() {
        let f = fixture();
        let started = std::time::Instant::now();
        let (mut kept_all, mut kept_some) = (0, 0);
        for at in 0..f.bytes.len() {
            let mut flipped = f.bytes.clone();
            flipped[at] ^= 0xFF;
            check_recovery(&flipped, &format!("byte {at} flipped"));
            check_recovery(&f.bytes[..at], &format!("cut at byte {at}"));
            let mut zeroed = f.bytes.clone();
            let end = (at + 16).min(zeroed.len());
            zeroed[at..end].fill(0);
            check_recovery(&zeroed, &format!("bytes {at}..{end} zeroed"));
            match f.intact_messages(&flipped).len() {
                36 => kept_all += 1,
                _ => kept_some += 1,
            }
        }
        eprintln!(
            "{} bytes x 3 kinds of damage in {:.2} s; a flipped byte left all 36 messages intact at {kept_all} offsets, fewer at {kept_some}",
            f.bytes.len(),
            started.elapsed().as_secs_f64()
        );
        // The fixture's chunks hold most of it: a flip loses messages at many offsets.
        assert!(kept_some > f.bytes.len() / 3, "{kept_some}");
    }

    /// The fuzz target's body on seeded random inputs: one to eight damage operations
    /// at once, as `mcap_recover` reads them.
    #[test]
    fn random_damage_keeps_every_intact_message() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..3000 {
            let ops = (next() % 8 + 1) as usize;
            let data: Vec<u8> = (0..ops)
                .flat_map(|_| next().to_le_bytes()[..4].to_vec())
                .collect();
            mcap_recover(&data);
        }
    }
}
