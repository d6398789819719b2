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
