//! Crash recovery: a recording cut anywhere recovers exactly the messages of its
//! complete chunks, into a file that reads back like any finished recording.

use crate::common::{accel, scratch, vib};
use vibro_mcap::{info, recover, Compression, Error, Reader, Recorder, RecorderOptions};
use vibro_msgs::MessageKind;

/// A chunk of the test file: where its record starts and ends, and its messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Chunk {
    start: u64,
    end: u64,
    messages: u64,
}

/// `whole.mcap` in `dir`, in chunks of 8 KiB: the channels `/accel` and `/vib`, what
/// `before` adds (attachments, metadata), then 30 messages on each channel; its bytes.
fn recorded(
    dir: &std::path::Path,
    compression: Compression,
    before: impl FnOnce(&mut Recorder),
) -> Vec<u8> {
    let path = dir.join("whole.mcap");
    let options = RecorderOptions {
        compression,
        chunk_size_bytes: 8 * 1024,
        ..RecorderOptions::default()
    };
    let mut recorder = Recorder::create(&path, options).unwrap();
    recorder
        .add_channel("/accel", MessageKind::AccelBlock)
        .unwrap();
    recorder.add_channel("/vib", MessageKind::VibBlock).unwrap();
    before(&mut recorder);
    for seq in 0..30u32 {
        let t = u64::from(seq) * 10_000_000;
        recorder
            .write("/accel", t, t, seq, &accel(seq.into()))
            .unwrap();
        recorder
            .write("/vib", t + 1, t, seq, &vib(seq.into()))
            .unwrap();
    }
    recorder.finish().unwrap();
    std::fs::read(&path).unwrap()
}

/// Writes a finished file of many small chunks and returns its bytes, its chunks in file
/// order, and where its summary section starts (just after the data-end record).
fn chunked_file(dir: &std::path::Path, compression: Compression) -> (Vec<u8>, Vec<Chunk>, u64) {
    let bytes = recorded(dir, compression, |_| {});

    // Independent of the code under test: the mcap crate's in-memory summary reader.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut chunks: Vec<Chunk> = summary
        .chunk_indexes
        .iter()
        .map(|c| Chunk {
            start: c.chunk_start_offset,
            end: c.chunk_start_offset + c.chunk_length,
            messages: summary.stream_chunk(&bytes, c).unwrap().count() as u64,
        })
        .collect();
    chunks.sort();
    let summary_start = mcap::read::footer(&bytes).unwrap().summary_start;
    (bytes, chunks, summary_start)
}

#[test]
fn truncated_files_recover_exactly_their_complete_chunks() {
    let dir = scratch("truncate");
    let (bytes, chunks, summary_start) = chunked_file(&dir, Compression::Zstd);
    assert!(chunks.len() >= 6, "{} chunks", chunks.len());
    assert_eq!(chunks.iter().map(|c| c.messages).sum::<u64>(), 60);
    let data_end = chunks.last().unwrap().end;

    let mut cuts = vec![
        (
            mcap::MAGIC.len() as u64 + 40,
            "inside the header or first chunk",
        ),
        (chunks[0].end, "right after the first chunk"),
        (chunks[2].end - 100, "in the middle of the third chunk"),
        (chunks[2].end, "right after the third chunk"),
        (chunks[2].end + 3, "in the record after the third chunk"),
        (data_end, "after the last chunk, no summary or footer"),
        (summary_start, "right after the data-end record"),
        (bytes.len() as u64 - 1, "inside the end magic"),
    ];
    cuts.push((bytes.len() as u64, "the whole file"));
    let n_cuts = cuts.len();
    let mut checked = 0;
    for (cut, what) in cuts {
        let damaged = dir.join(format!("cut-{cut}.mcap"));
        std::fs::write(&damaged, &bytes[..cut as usize]).unwrap();
        let out = dir.join(format!("recovered-{cut}.mcap"));
        let complete_chunks = chunks.iter().filter(|c| c.end <= cut);
        let expected: u64 = complete_chunks.clone().map(|c| c.messages).sum();
        let expected_chunks = complete_chunks.count() as u64;
        let report = match recover(&damaged, &out) {
            Ok(r) => r,
            Err(Error::Truncated { .. }) if cut < chunks[0].start => continue,
            Err(e) => panic!("cut at {cut} ({what}): {e}"),
        };
        assert_eq!(report.messages_recovered, expected, "cut at {cut} ({what})");
        assert_eq!(
            report.chunks_recovered, expected_chunks,
            "cut at {cut} ({what})"
        );
        assert_eq!(report.chunks_skipped, 0);
        assert_eq!(report.input_bytes, cut);
        assert!(report.valid_prefix_bytes <= cut);
        let last_end = chunks.iter().map(|c| c.end).filter(|&e| e <= cut).max();
        assert!(report.valid_prefix_bytes >= last_end.unwrap_or(0));
        let complete = cut >= summary_start; // the data-end record was read
        assert_eq!(report.input_complete, complete, "cut at {cut} ({what})");
        assert_eq!(
            report.stop_reason.is_none(),
            complete,
            "{:?}",
            report.stop_reason
        );

        // The result is a finished file: info and the reader agree, and the messages are
        // the first `expected` ones written, unchanged.
        let i = info(&out).unwrap();
        assert_eq!(i.messages, expected);
        assert_eq!(i.lost, 0);
        let read: Vec<_> = Reader::open(&out).unwrap().map(Result::unwrap).collect();
        assert_eq!(read.len() as u64, expected);
        for r in &read {
            let original = match r.message.kind() {
                MessageKind::AccelBlock => vibro_mcap::Message::from(accel(r.sequence.into())),
                _ => vib(r.sequence.into()).into(),
            };
            assert_eq!(r.message.wire_bytes(), original.wire_bytes());
        }
        assert_eq!(report.output_bytes, std::fs::metadata(&out).unwrap().len());
        checked += 1;
    }
    // Only a cut inside the header may be unrecoverable.
    assert!(
        checked >= n_cuts - 1,
        "{checked} of {n_cuts} cuts recovered"
    );
}

#[test]
fn a_corrupt_chunk_is_skipped_and_the_rest_recovered() {
    let dir = scratch("skip");
    let (mut bytes, chunks, _) = chunked_file(&dir, Compression::None);
    // Flip a byte in the middle of the second chunk's records.
    let second = chunks[1];
    bytes[((second.start + second.end) / 2) as usize] ^= 0x01;
    // And cut the file inside the last chunk, as a crash would.
    let last = chunks[chunks.len() - 1];
    let last_start = last.start;
    let cut = (last.start + last.end) / 2;
    let damaged = dir.join("damaged.mcap");
    std::fs::write(&damaged, &bytes[..cut as usize]).unwrap();
    let report = recover(&damaged, dir.join("out.mcap")).unwrap();
    let all_but_last: u64 = chunks[..chunks.len() - 1].iter().map(|c| c.messages).sum();
    assert_eq!(report.chunks_skipped, 1);
    assert_eq!(report.chunks_recovered, chunks.len() as u64 - 2);
    assert_eq!(report.messages_recovered, all_but_last - second.messages);
    assert!(report.stop_reason.as_deref().unwrap().starts_with(&format!(
        "the file ends inside a record that starts at byte {last_start}"
    )));
    assert_eq!(report.valid_prefix_bytes, last_start);
}

#[test]
fn a_file_without_a_complete_header_cannot_be_recovered() {
    let dir = scratch("header");
    let (bytes, _, _) = chunked_file(&dir, Compression::Zstd);
    let damaged = dir.join("stub.mcap");
    std::fs::write(&damaged, &bytes[..12]).unwrap();
    let e = recover(&damaged, dir.join("out.mcap")).unwrap_err();
    assert!(
        matches!(&e, Error::Truncated { path } if path == &damaged),
        "{e}"
    );
    std::fs::write(&damaged, b"not an mcap file at all").unwrap();
    assert!(recover(&damaged, dir.join("out.mcap")).is_err());
}

/// A finished file of many small zstd chunks with an attachment written before the
/// messages; its bytes, its chunks (from the `mcap` crate's summary reader, independent
/// of the code under test), and the offsets of the attachment and of the message-index
/// records after the second chunk.
fn file_with_attachment(dir: &std::path::Path) -> (Vec<u8>, Vec<Chunk>, u64, u64) {
    let bytes = recorded(dir, Compression::Zstd, |recorder| {
        recorder
            .add_attachment("rig.toml", "text/plain", b"rig = 3\n".to_vec())
            .unwrap();
    });
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut indexes = summary.chunk_indexes.clone();
    indexes.sort_by_key(|c| c.chunk_start_offset);
    let chunks: Vec<Chunk> = indexes
        .iter()
        .map(|c| Chunk {
            start: c.chunk_start_offset,
            end: c.chunk_start_offset + c.chunk_length,
            messages: summary.stream_chunk(&bytes, c).unwrap().count() as u64,
        })
        .collect();
    let message_index = *indexes[1].message_index_offsets.values().min().unwrap();
    let attachment = summary.attachment_indexes[0].offset;
    (bytes, chunks, attachment, message_index)
}

/// Recovers `bytes` written to `name` in `dir`.
fn recover_bytes(dir: &std::path::Path, name: &str, bytes: &[u8]) -> vibro_mcap::RecoverReport {
    let damaged = dir.join(format!("{name}.mcap"));
    std::fs::write(&damaged, bytes).unwrap();
    let out = dir.join(format!("{name}-out.mcap"));
    let report = recover(&damaged, &out).unwrap_or_else(|e| panic!("{name}: {e}"));
    // The result reads back whole, with as many messages as reported.
    assert_eq!(info(&out).unwrap().messages, report.messages_recovered);
    let read = Reader::open(&out).unwrap().map(Result::unwrap).count() as u64;
    assert_eq!(read, report.messages_recovered, "{name}");
    report
}

/// Writes a u32 of all ones at `at`: a length prefix far beyond its record.
fn garble_length(bytes: &mut [u8], at: u64) {
    bytes[at as usize..at as usize + 4].copy_from_slice(&[0xFF; 4]);
}

/// A garbled message index, attachment or header loses that record only: every chunk
/// after it is found again (resynchronisation) and all 60 messages are kept; the
/// damaged region is reported with what it was.
#[test]
fn damage_outside_chunks_loses_only_the_damaged_record() {
    let dir = scratch("resync");
    let (bytes, chunks, attachment, message_index) = file_with_attachment(&dir);
    let all: u64 = chunks.iter().map(|c| c.messages).sum();
    assert_eq!(all, 60);
    assert!(chunks.len() >= 6, "{} chunks", chunks.len());
    // Where reading must resume after damage at `at`: the next chunk.
    let next_chunk = |at: u64| chunks.iter().map(|c| c.start).find(|&s| s > at).unwrap();
    assert!(
        attachment < chunks[chunks.len() - 1].start,
        "a chunk follows the attachment"
    );

    // Message index: channel id (2 bytes), then the length of its entries.
    let mut b = bytes.clone();
    garble_length(&mut b, message_index + 9 + 2);
    let r = recover_bytes(&dir, "message-index", &b);
    assert_eq!(r.messages_recovered, all, "{r:?}");
    assert_eq!(r.chunks_recovered, chunks.len() as u64);
    assert!(r.input_complete, "{r:?}");
    assert_eq!(r.damage.len(), 1, "{:?}", r.damage);
    assert_eq!(r.damage[0].start_byte, message_index);
    assert_eq!(r.damage[0].end_byte, next_chunk(message_index));
    assert!(
        r.damage[0].what.contains("unreadable record"),
        "{:?}",
        r.damage
    );

    // Attachment: two times (16 bytes), then the length of its name.
    let mut b = bytes.clone();
    garble_length(&mut b, attachment + 9 + 16);
    let r = recover_bytes(&dir, "attachment", &b);
    assert_eq!(r.messages_recovered, all, "{r:?}");
    assert_eq!(r.attachments, 0);
    assert_eq!(r.damage.len(), 1, "{:?}", r.damage);
    assert_eq!(r.damage[0].start_byte, attachment);
    assert_eq!(r.damage[0].end_byte, next_chunk(attachment));

    // Header: the length of its profile string, first field of the first record.
    let mut b = bytes.clone();
    garble_length(&mut b, mcap::MAGIC.len() as u64 + 9);
    let r = recover_bytes(&dir, "header", &b);
    assert_eq!(r.messages_recovered, all, "{r:?}");
    assert!(
        r.damage[0].what.starts_with("the MCAP header record")
            && r.damage[0].what.contains("profile claims 4294967295 bytes"),
        "{:?}",
        r.damage
    );

    // A header garbled in a file with no chunk after it is described as such, not as
    // a file that ends early.
    let mut b = bytes[..chunks[0].start as usize].to_vec();
    garble_length(&mut b, mcap::MAGIC.len() as u64 + 9);
    let damaged = dir.join("header-only.mcap");
    std::fs::write(&damaged, &b).unwrap();
    let e = recover(&damaged, dir.join("header-only-out.mcap")).unwrap_err();
    assert!(matches!(e, Error::Malformed { .. }), "{e}");
    assert!(
        e.to_string().contains("MCAP header record is unreadable"),
        "{e}"
    );
}

/// A chunk whose CRC fails is a loss: its messages, counted from its message-index
/// records, are reported against the count of the undamaged original.
#[test]
fn a_crc_failed_chunk_is_reported_with_its_messages() {
    let dir = scratch("crc-loss");
    let (mut bytes, chunks, _, _) = file_with_attachment(&dir);
    let third = chunks[2];
    // The last byte of the chunk's compressed records: it still decompresses (zstd
    // checks no checksum here), to different bytes.
    let at = third.end as usize - 1;
    bytes[at] ^= 0x01;
    let r = recover_bytes(&dir, "crc", &bytes);
    assert_eq!(r.chunks_skipped, 1, "{r:?}");
    assert_eq!(r.messages_in_skipped_chunks, third.messages);
    assert_eq!(r.messages_recovered, 60 - third.messages);
    assert_eq!(r.damage.len(), 1, "{:?}", r.damage);
    assert_eq!(r.damage[0].messages, Some(third.messages));
    assert_eq!(
        (r.damage[0].start_byte, r.damage[0].end_byte),
        (third.start, third.end)
    );
}

/// Damage in the first of several attachments loses that attachment only: reading
/// resumes at the next attachment whose CRC checks out, and the records after it (the
/// other attachments, the metadata) are copied. The counts come from the `mcap` crate's
/// summary of the undamaged original.
#[test]
fn damage_in_one_attachment_keeps_the_attachments_and_metadata_after_it() {
    let dir = scratch("resync-attachments");
    let bytes = recorded(&dir, Compression::Zstd, |recorder| {
        for name in ["a.toml", "b.toml", "c.toml"] {
            let text = format!("name = {name:?}\n").into_bytes();
            recorder.add_attachment(name, "text/plain", text).unwrap();
        }
        let entries = std::collections::BTreeMap::from([("rig".to_string(), "3".to_string())]);
        recorder.add_metadata("session", entries).unwrap();
    });
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut attachments: Vec<u64> = summary
        .attachment_indexes
        .iter()
        .map(|a| a.offset)
        .collect();
    attachments.sort_unstable();
    assert_eq!(attachments.len(), 3);
    let metadata = summary.metadata_indexes.len() as u64;
    assert!(metadata >= 1);
    let messages: u64 = summary.stats.as_ref().unwrap().message_count;

    // The first attachment's name length, after its two times.
    let mut b = bytes.clone();
    garble_length(&mut b, attachments[0] + 9 + 16);
    let r = recover_bytes(&dir, "first-attachment", &b);
    assert_eq!(r.messages_recovered, messages, "{r:?}");
    assert_eq!(r.attachments, 2, "{r:?}");
    assert_eq!(r.metadata, metadata, "{r:?}");
    assert_eq!(r.damage.len(), 1, "{:?}", r.damage);
    assert_eq!(
        (r.damage[0].start_byte, r.damage[0].end_byte),
        (attachments[0], attachments[1])
    );
    let names: Vec<String> =
        mcap::Summary::read(&std::fs::read(dir.join("first-attachment-out.mcap")).unwrap())
            .unwrap()
            .unwrap()
            .attachment_indexes
            .iter()
            .map(|a| a.name.clone())
            .collect();
    assert_eq!(names, ["b.toml", "c.toml"]);

    // A byte of the second attachment's data: its CRC fails, the third is kept.
    let mut b = bytes.clone();
    let data_end = attachments[2] - 4 - 1;
    b[data_end as usize] ^= 0x20;
    let r = recover_bytes(&dir, "second-attachment", &b);
    assert_eq!(r.attachments, 2, "{r:?}");
    assert_eq!(r.metadata, metadata, "{r:?}");
    assert_eq!(r.messages_recovered, messages, "{r:?}");
}

// ---------------------------------------------------------------------------------
// Issue 46, item 5: schemas and channels from wherever they survive; losses recorded.

/// The file of issue 46: channels on `/accel` and `/vib`, then an attachment (which
/// closes the first chunk, so that it holds the schemas and channels only, as
/// `vibrocomp record`'s first chunk does), then 1000 messages on each channel in
/// chunks of 64 KiB. Its bytes, and its chunks in file order (from the `mcap` crate's
/// summary reader, independent of the code under test).
fn issue_file(dir: &std::path::Path) -> (Vec<u8>, Vec<Chunk>) {
    let path = dir.join("issue46.mcap");
    let options = RecorderOptions {
        chunk_size_bytes: 64 * 1024,
        // Every message fits in the queue: the test writes faster than zstd.
        queue_capacity: 2048,
        ..RecorderOptions::default()
    };
    let mut recorder = Recorder::create(&path, options).unwrap();
    recorder
        .add_channel("/accel", MessageKind::AccelBlock)
        .unwrap();
    recorder.add_channel("/vib", MessageKind::VibBlock).unwrap();
    recorder
        .add_attachment("triad.toml", "application/toml", b"id = \"t\"\n".to_vec())
        .unwrap();
    for seq in 0..1000u32 {
        let t = u64::from(seq) * 10_000_000;
        recorder
            .write("/accel", t, t, seq, &accel(seq.into()))
            .unwrap();
        recorder
            .write("/vib", t + 1, t, seq, &vib(seq.into()))
            .unwrap();
    }
    recorder.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut chunks: Vec<Chunk> = summary
        .chunk_indexes
        .iter()
        .map(|c| Chunk {
            start: c.chunk_start_offset,
            end: c.chunk_start_offset + c.chunk_length,
            messages: summary.stream_chunk(&bytes, c).unwrap().count() as u64,
        })
        .collect();
    chunks.sort();
    (bytes, chunks)
}

fn le64(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
}

/// Where the footer record starts (before the closing magic).
fn footer_at(bytes: &[u8]) -> usize {
    bytes.len() - mcap::MAGIC.len() - (9 + 20)
}

/// Sets the first chunk's uncompressed size to 2^40. With `consistent`, also in its
/// chunk index, and the data-section CRC (data-end record) and summary CRC (footer)
/// computed again, so that every CRC of the file checks out: a crafted file rather
/// than a damaged one.
fn claim_2_pow_40(bytes: &mut [u8], first: Chunk, consistent: bool) {
    let huge = (1u64 << 40).to_le_bytes();
    // Chunk record: opcode, length, start time, end time, uncompressed size.
    let at = first.start as usize + 9 + 16;
    bytes[at..at + 8].copy_from_slice(&huge);
    if !consistent {
        return;
    }
    let footer = footer_at(bytes);
    let summary_start = le64(bytes, footer + 9) as usize;
    let mut pos = summary_start;
    let mut patched = false;
    while pos < footer {
        let len = le64(bytes, pos + 1) as usize;
        // Chunk index: two times, then the chunk's start; its last field is the
        // uncompressed size.
        if bytes[pos] == 0x08 && le64(bytes, pos + 9 + 16) == first.start {
            let end = pos + 9 + len;
            bytes[end - 8..end].copy_from_slice(&huge);
            patched = true;
        }
        pos += 9 + len;
    }
    assert!(patched, "no chunk index for the first chunk");
    // Data end: opcode, length 4, CRC of every byte before it.
    let data_end = summary_start - 13;
    let crc = crc32fast::hash(&bytes[..data_end]);
    bytes[summary_start - 4..summary_start].copy_from_slice(&crc.to_le_bytes());
    let crc = crc32fast::hash(&bytes[summary_start..footer + 25]);
    bytes[footer + 25..footer + 29].copy_from_slice(&crc.to_le_bytes());
}

/// Whether the `mcap` crate's linear reader finds the data section's and the summary
/// section's CRCs correct (chunks are not decompressed: the first one claims 1 TiB).
fn every_crc_checks_out(bytes: &[u8]) -> bool {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true)
            .with_emit_chunks(true)
            .with_record_length_limit(bytes.len()),
    );
    let mut at = 0;
    while let Some(event) = reader.next_event() {
        match event {
            Ok(LinearReadEvent::ReadRequest(n)) => {
                let n = n.min(bytes.len() - at);
                reader.insert(n).copy_from_slice(&bytes[at..at + n]);
                reader.notify_read(n);
                at += n;
            }
            Ok(LinearReadEvent::Record { .. }) => {}
            Err(_) => return false,
        }
    }
    true
}

/// Every message of a file as the `mcap` crate reads it (CRCs checked), in a
/// canonical order: topic, schema, sequence, log time, publish time, bytes.
fn messages_of(bytes: &[u8]) -> Vec<(String, String, u32, u64, u64, Vec<u8>)> {
    let mut out: Vec<_> = mcap::MessageStream::new(bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
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
        })
        .collect();
    out.sort();
    out
}

/// The PyPI `mcap` reader's comparison of two files' messages
/// (`tests/python/mcap_same_messages.py`, CRCs checked). Fails, never skips, without
/// Python.
fn python_messages_equal(
    original: &std::path::Path,
    recovered: &std::path::Path,
) -> serde_json::Value {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/python/mcap_same_messages.py");
    let out = std::process::Command::new("python3")
        .arg(&script)
        .arg(original)
        .arg(recovered)
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "the Python mcap reader failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Issue 46: a first chunk that claims 2^40 uncompressed bytes lost all 2000 messages
/// ("dropped: 2000 messages whose channel was defined only in a skipped chunk"),
/// although the summary section held every schema and channel, and the recovery said
/// nothing was wrong. Now the chunk is read all the same (its CRC proves its records;
/// the size is only a hint) and every message is kept, whether the size was garbled
/// alone or the file crafted so that every CRC checks out.
#[test]
fn a_first_chunk_claiming_2_pow_40_bytes_loses_no_message() {
    let dir = scratch("issue46-size");
    let (bytes, chunks) = issue_file(&dir);
    assert_eq!(
        chunks[0].messages, 0,
        "the first chunk holds the definitions only"
    );
    assert_eq!(chunks.iter().map(|c| c.messages).sum::<u64>(), 2000);
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    let original = messages_of(&bytes);
    assert_eq!(original.len(), 2000);
    std::fs::write(dir.join("original.mcap"), &bytes).unwrap();
    for consistent in [false, true] {
        let mut b = bytes.clone();
        claim_2_pow_40(&mut b, chunks[0], consistent);
        assert_eq!(every_crc_checks_out(&b), consistent);
        let name = if consistent { "crafted" } else { "garbled" };
        let damaged = dir.join(format!("{name}.mcap"));
        std::fs::write(&damaged, &b).unwrap();
        let out = dir.join(format!("{name}-out.mcap"));
        let r = recover(&damaged, &out).unwrap();
        assert_eq!(r.messages_recovered, 2000, "{name}: {r:?}");
        assert_eq!(r.messages_orphaned, 0, "{name}");
        assert_eq!((r.messages_dropped, r.messages_dropped_exact), (0, true));
        assert_eq!(r.expected.map(|e| e.messages), Some(2000));
        assert_eq!(r.chunks_recovered, chunks.len() as u64, "{name}");
        assert_eq!((r.chunks_skipped, r.chunks_repaired), (0, 1), "{name}");
        assert!(!r.losses, "{name}: {r:?}");
        assert_eq!(r.attachments, 1);
        // The messages are the original's, bit for bit, as the `mcap` crate and the
        // Python reader see them.
        let recovered = std::fs::read(&out).unwrap();
        assert_eq!(messages_of(&recovered), original, "{name}");
        let py = python_messages_equal(&dir.join("original.mcap"), &out);
        assert_eq!(py["a"], 2000, "{name}: {py}");
        assert_eq!(py["equal"], true, "{name}: {py}");
        // `info` of the result: a recovery that lost nothing.
        let i = info(&out).unwrap();
        assert_eq!(i.messages, 2000);
        assert_eq!(i.recoveries.len(), 1, "{name}");
        assert_eq!(i.recoveries[0].messages_kept, 2000);
        assert_eq!(i.recoveries[0].messages_dropped, 0);
        assert!(!i.recoveries[0].losses);
    }
}

/// A damaged chunk whose messages start the streams: the sequences of what is left
/// begin later and show no gap, so the loss is invisible to a sequence count. The
/// recovery counts it exactly (the input's statistics record is intact), says so
/// (`losses`) and writes it into the new file, where `info` finds it.
#[test]
fn a_recovery_that_drops_messages_says_so_and_records_it_in_the_file() {
    let dir = scratch("issue46-record");
    let (mut bytes, chunks) = issue_file(&dir);
    let first = chunks.iter().find(|c| c.messages > 0).copied().unwrap();
    // The last byte of its compressed records: it still decompresses, to other bytes.
    bytes[first.end as usize - 1] ^= 0x01;
    let damaged = dir.join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = dir.join("out.mcap");
    let r = recover(&damaged, &out).unwrap();
    assert_eq!(r.messages_recovered, 2000 - first.messages, "{r:?}");
    assert_eq!(r.messages_dropped, first.messages);
    assert!(r.messages_dropped_exact);
    assert!(r.losses);
    assert_eq!(r.chunks_skipped, 1);
    let i = info(&out).unwrap();
    assert_eq!(i.lost, 0, "the sequences show nothing: {i:?}");
    assert_eq!(i.recoveries.len(), 1);
    let rec = &i.recoveries[0];
    assert_eq!(rec.messages_dropped, first.messages);
    assert_eq!(rec.messages_expected, Some(2000));
    assert_eq!(rec.messages_kept, 2000 - first.messages);
    assert_eq!(rec.chunks_skipped, 1);
    assert_eq!(
        rec.skipped_ranges,
        format!("{}..{}", first.start, first.end)
    );
    assert_eq!(rec.bytes_skipped, first.end - first.start);
    assert!(rec.losses);
    assert_eq!(rec.input, "damaged.mcap");
    // Recovering the result again keeps the first record and adds one that lost
    // nothing.
    let again = recover(&out, dir.join("again.mcap")).unwrap();
    assert!(!again.losses, "{again:?}");
    let i = info(dir.join("again.mcap")).unwrap();
    let dropped: Vec<u64> = i.recoveries.iter().map(|r| r.messages_dropped).collect();
    assert_eq!(dropped, [first.messages, 0]);
}

/// Issue 46: MCAP magic followed by zeros. `recover` said "Bad magic number"; now it
/// says that nothing can be recovered and why, quickly (the scan for an intact chunk
/// reads the file in windows).
#[test]
fn magic_and_zeros_is_nothing_to_recover() {
    let dir = scratch("zeros");
    let damaged = dir.join("zeros.mcap");
    let mut bytes = mcap::MAGIC.to_vec();
    bytes.resize(8 << 20, 0);
    std::fs::write(&damaged, &bytes).unwrap();
    let started = std::time::Instant::now();
    let e = recover(&damaged, dir.join("out.mcap")).unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, Error::Malformed { .. }), "{text}");
    assert!(text.contains("nothing to recover"), "{text}");
    assert!(text.contains("opcode 0x00 at byte 8"), "{text}");
    assert!(!text.contains("Bad magic"), "{text}");
    assert!(
        started.elapsed().as_secs_f64() < 10.0,
        "{:?}",
        started.elapsed()
    );
}
