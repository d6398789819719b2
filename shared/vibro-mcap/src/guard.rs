//! Checks that `mcap` 0.26 leaves out, run on bytes before `mcap` parses them.
//!
//! The fuzz target `mcap_read` (fuzz/README.md) found three ways in which a corrupt
//! file of a few hundred bytes takes the process down inside `mcap` 0.26:
//!
//! - a length prefix (string, byte array, map) larger than its record: `mcap`'s binrw
//!   parser allocates the claimed length (up to 4 GiB) before it finds the record too
//!   short;
//! - a record inside a chunk that runs past the end of the chunk: the chunk reader's
//!   `compressed_remaining -= len` underflows (a panic with overflow checks, a misframed
//!   read without), or `OPCODE_LEN_SIZE + len` overflows;
//! - a record length or uncompressed chunk size that is allocated before it is read.
//!
//! So every record body is checked by [`record`] before `mcap::parse_record` sees it,
//! and chunks are decompressed, CRC-checked and cut into records here ([`chunk`]),
//! never by `mcap`'s chunk reader.

use crate::Error;
use mcap::records::{op, ChunkHeader, Record as McapRecord};
use std::path::Path;

/// The largest uncompressed chunk accepted: a corrupt size must not become an
/// allocation of gigabytes. vibrocomp's recorder writes 1 MiB chunks; the `mcap`
/// library's writer defaults to 768 KiB.
pub(crate) const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// Reads the fixed-size fields and length prefixes of one record body.
struct Fields<'a> {
    body: &'a [u8],
    at: usize,
}

impl<'a> Fields<'a> {
    fn take(&mut self, n: u64, what: &str) -> Result<&'a [u8], String> {
        let left = self.body.len() - self.at;
        match usize::try_from(n) {
            Ok(n) if n <= left => {
                self.at += n;
                Ok(&self.body[self.at - n..self.at])
            }
            _ => Err(format!(
                "{what} claims {n} bytes at byte {} of a {}-byte record",
                self.at,
                self.body.len()
            )),
        }
    }

    fn skip(&mut self, n: u64) -> Result<(), String> {
        self.take(n, "a fixed field").map(|_| ())
    }

    fn u32(&mut self, what: &str) -> Result<u64, String> {
        let b = self.take(4, what)?;
        Ok(u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
    }

    fn u64(&mut self, what: &str) -> Result<u64, String> {
        let b = self.take(8, what)?;
        let mut a = [0; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    /// A string or byte array with a 4-byte length.
    fn bytes32(&mut self, what: &str) -> Result<(), String> {
        let n = self.u32(what)?;
        self.take(n, what).map(|_| ())
    }

    /// A byte array with an 8-byte length.
    fn bytes64(&mut self, what: &str) -> Result<(), String> {
        let n = self.u64(what)?;
        self.take(n, what).map(|_| ())
    }

    /// A map of strings to strings: its byte length, then its entries, each checked.
    fn string_map(&mut self, what: &str) -> Result<(), String> {
        let n = self.u32(what)?;
        let mut entries = Fields {
            body: self.take(n, what)?,
            at: 0,
        };
        while entries.at < entries.body.len() {
            entries.bytes32(what)?;
            entries.bytes32(what)?;
        }
        Ok(())
    }
}

/// Checks that every length prefix of a record body fits in the body. Records of other
/// opcodes (and trailing fields that a later MCAP version may add) are left to `mcap`.
pub(crate) fn record(opcode: u8, body: &[u8]) -> Result<(), String> {
    let mut f = Fields { body, at: 0 };
    let checked = match opcode {
        op::HEADER => f.bytes32("profile").and_then(|_| f.bytes32("library")),
        op::SCHEMA => f
            .skip(2)
            .and_then(|_| f.bytes32("schema name"))
            .and_then(|_| f.bytes32("schema encoding"))
            .and_then(|_| f.bytes32("schema data")),
        op::CHANNEL => f
            .skip(4)
            .and_then(|_| f.bytes32("topic"))
            .and_then(|_| f.bytes32("message encoding"))
            .and_then(|_| f.string_map("channel metadata")),
        op::CHUNK => f
            .skip(8 + 8 + 8 + 4)
            .and_then(|_| f.bytes32("compression"))
            .and_then(|_| f.bytes64("chunk records")),
        op::MESSAGE_INDEX => f.skip(2).and_then(|_| f.bytes32("message index entries")),
        op::CHUNK_INDEX => f
            .skip(8 * 4)
            .and_then(|_| f.bytes32("message index offsets"))
            .and_then(|_| f.skip(8))
            .and_then(|_| f.bytes32("compression")),
        op::ATTACHMENT => f
            .skip(8 + 8)
            .and_then(|_| f.bytes32("attachment name"))
            .and_then(|_| f.bytes32("media type"))
            .and_then(|_| f.bytes64("attachment data")),
        op::ATTACHMENT_INDEX => f
            .skip(8 * 5)
            .and_then(|_| f.bytes32("attachment name"))
            .and_then(|_| f.bytes32("media type")),
        op::STATISTICS => f
            .skip(8 + 2 + 4 * 4 + 8 + 8)
            .and_then(|_| f.bytes32("channel message counts")),
        op::METADATA => f
            .bytes32("metadata name")
            .and_then(|_| f.string_map("metadata")),
        op::METADATA_INDEX => f.skip(8 + 8).and_then(|_| f.bytes32("metadata name")),
        _ => Ok(()),
    };
    checked.map_err(|e| format!("record 0x{opcode:02X}: {e}"))
}

/// `mcap::parse_record` after [`record`]'s checks; errors name `path`.
pub(crate) fn parse<'a>(path: &Path, opcode: u8, body: &'a [u8]) -> crate::Result<McapRecord<'a>> {
    record(opcode, body).map_err(|reason| Error::Malformed {
        path: path.to_path_buf(),
        reason,
    })?;
    mcap::parse_record(opcode, body).map_err(|e| Error::mcap(path, e))
}

/// Walks a sequence of records (`opcode`, 8-byte length, body), each checked.
pub(crate) fn records(mut bytes: &[u8]) -> Result<Vec<(u8, &[u8])>, String> {
    let mut out = Vec::new();
    while !bytes.is_empty() {
        let mut f = Fields { body: bytes, at: 0 };
        let opcode = f.take(1, "an opcode")?[0];
        let len = f.u64("a record length")?;
        let body = f.take(len, "a record")?;
        record(opcode, body)?;
        out.push((opcode, body));
        bytes = &bytes[f.at..];
    }
    Ok(out)
}

/// What is wrong with a chunk.
pub(crate) enum ChunkError {
    Crc { saved: u32, calculated: u32 },
    Invalid(String),
}

/// The records of a chunk: decompressed into `buf` (zstd, or none), the CRC of the
/// uncompressed records checked (unless it is 0: not computed), every record framed
/// within the chunk and checked by [`record`].
pub(crate) fn chunk<'b>(
    header: &ChunkHeader,
    data: &'b [u8],
    buf: &'b mut Vec<u8>,
) -> Result<Vec<(u8, &'b [u8])>, ChunkError> {
    let size = header.uncompressed_size;
    if size > MAX_CHUNK_BYTES {
        return Err(ChunkError::Invalid(format!(
            "chunk claims {size} bytes uncompressed, more than the {MAX_CHUNK_BYTES} accepted"
        )));
    }
    let uncompressed: &[u8] = match header.compression.as_str() {
        "" => data,
        "zstd" => {
            // `size` <= MAX_CHUNK_BYTES fits a usize.
            let capacity = usize::try_from(size).unwrap_or(usize::MAX);
            buf.clear();
            buf.reserve(capacity);
            zstd::bulk::Decompressor::new()
                .and_then(|mut d| d.decompress_to_buffer(data, buf))
                .map_err(|e| ChunkError::Invalid(format!("chunk does not decompress: {e}")))?;
            buf
        }
        other => {
            return Err(ChunkError::Invalid(format!(
                "chunk compression {other:?} is not supported (only zstd or none)"
            )))
        }
    };
    if uncompressed.len() as u64 != size {
        return Err(ChunkError::Invalid(format!(
            "chunk holds {} bytes uncompressed, its header says {size}",
            uncompressed.len()
        )));
    }
    if header.uncompressed_crc != 0 {
        let calculated = crc32fast::hash(uncompressed);
        if calculated != header.uncompressed_crc {
            return Err(ChunkError::Crc {
                saved: header.uncompressed_crc,
                calculated,
            });
        }
    }
    records(uncompressed).map_err(|e| ChunkError::Invalid(format!("in a chunk: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &str) -> Vec<u8> {
        let mut b = (s.len() as u32).to_le_bytes().to_vec();
        b.extend_from_slice(s.as_bytes());
        b
    }

    #[test]
    fn lengths_beyond_the_record_are_refused_before_mcap_allocates_them() {
        let mut header = string("vibrocomp");
        header.extend(string("x"));
        assert!(record(op::HEADER, &header).is_ok());
        // A profile of 0xFFFF_FFFF bytes in a 9-byte record, which binrw would allocate
        // (fuzz/regressions/mcap_read/string-length-*).
        let mut bad = u32::MAX.to_le_bytes().to_vec();
        bad.extend_from_slice(b"vibro");
        let e = record(op::HEADER, &bad).unwrap_err();
        assert_eq!(
            e,
            "record 0x01: profile claims 4294967295 bytes at byte 4 of a 9-byte record"
        );
        // A metadata map whose second string runs past the map.
        let mut map = string("k");
        map.extend_from_slice(&100u32.to_le_bytes());
        let mut meta = string("run");
        meta.extend_from_slice(&(map.len() as u32).to_le_bytes());
        meta.extend(map);
        assert!(record(op::METADATA, &meta)
            .unwrap_err()
            .contains("metadata claims 100"));
    }

    #[test]
    fn a_record_running_past_its_chunk_is_refused() {
        // Opcode 0x0F (data end), length 4 but 2 bytes left: mcap's chunk reader would
        // subtract 13 from the 11 bytes remaining
        // (fuzz/regressions/mcap_read/chunk-record-past-chunk-end).
        let bytes = [0x0F, 4, 0, 0, 0, 0, 0, 0, 0, 1, 2];
        assert!(records(&bytes)
            .unwrap_err()
            .contains("a record claims 4 bytes"));
        let header = ChunkHeader {
            message_start_time: 0,
            message_end_time: 0,
            uncompressed_size: bytes.len() as u64,
            uncompressed_crc: 0,
            compression: String::new(),
            compressed_size: bytes.len() as u64,
        };
        assert!(matches!(
            chunk(&header, &bytes, &mut Vec::new()),
            Err(ChunkError::Invalid(_))
        ));
        let huge = ChunkHeader {
            uncompressed_size: 3 << 30,
            compression: "zstd".into(),
            ..header
        };
        assert!(matches!(
            chunk(&huge, &bytes, &mut Vec::new()),
            Err(ChunkError::Invalid(e)) if e.contains("claims 3221225472 bytes")
        ));
    }
}
