//! Recorder -> file -> Reader and info: what goes in comes out, in log-time order, bit
//! for bit; losses, full queues, flushes and corruption are reported with their values.

use crate::common::{accel, heartbeat, scratch, topics, vib};
use std::collections::BTreeMap;
use vibro_mcap::{info, Compression, Error, Message, Reader, Recorder, RecorderOptions};
use vibro_msgs::MessageKind;

struct Written {
    topic: &'static str,
    sequence: u32,
    log_time_ns: u64,
    publish_time_ns: u64,
    message: Message,
}

fn small_chunks() -> RecorderOptions {
    RecorderOptions {
        chunk_size_bytes: 16 * 1024,
        ..RecorderOptions::default()
    }
}

#[test]
fn every_type_reads_back_in_log_time_order_bit_identical() {
    let dir = scratch("roundtrip");
    let path = dir.join("all.mcap");
    let mut recorder = Recorder::create(&path, small_chunks()).unwrap();
    for (topic, kind, _) in topics() {
        recorder.add_channel(topic, kind).unwrap();
    }
    let passport = b"[accelerometer]\nk2_ppm_per_g = 105.5\n".to_vec();
    recorder
        .add_attachment("al15.toml", "application/toml", passport.clone())
        .unwrap();
    let run = BTreeMap::from([
        ("flight".to_string(), "cyclone-4".to_string()),
        ("mode".to_string(), "exact".to_string()),
    ]);
    recorder.add_metadata("run", run.clone()).unwrap();

    // Written in one order, logged in another: the heartbeat of step s is logged 15 ms
    // before the accel block of step s, i.e. before blocks written earlier.
    let mut written = Vec::new();
    for seq in 0..40u64 {
        for (i, (topic, _, make)) in topics().into_iter().enumerate() {
            let message = make(seq);
            let base = 1_000_000_000 + seq * 10_000_000;
            let log_time_ns = if topic.starts_with("/heartbeat") {
                base - 15_000_000 + i as u64
            } else {
                base + i as u64 * 1_000
            };
            let sequence = u32::try_from(seq).unwrap();
            recorder
                .write(topic, log_time_ns, base + 7, sequence, &message)
                .unwrap();
            written.push(Written {
                topic,
                sequence,
                log_time_ns,
                publish_time_ns: base + 7,
                message,
            });
        }
    }
    let summary = recorder.finish().unwrap();
    assert_eq!(summary.messages, 280);
    assert_eq!(summary.messages_per_topic.len(), 7);
    assert!(summary.messages_per_topic.values().all(|&n| n == 40));
    assert_eq!(summary.rejected_full, 0);
    assert_eq!((summary.attachments, summary.metadata), (1, 1));
    assert!(summary.chunks > 10, "{} chunks", summary.chunks);
    assert_eq!(summary.bytes, std::fs::metadata(&path).unwrap().len());

    // The expected order: by log time, ties in the order written (stable sort).
    written.sort_by_key(|w| w.log_time_ns);
    let mut reader = Reader::open(&path).unwrap();
    assert_eq!(reader.message_count(), Some(280));
    assert_eq!(
        reader.channels(),
        vec![
            ("/accel".to_string(), MessageKind::AccelBlock),
            ("/compensated".to_string(), MessageKind::CompensatedBlock),
            ("/estimate".to_string(), MessageKind::VibEstimate),
            ("/heartbeat/compensator".to_string(), MessageKind::Heartbeat),
            ("/log/compensator".to_string(), MessageKind::LogLine),
            ("/truth".to_string(), MessageKind::TruthBlock),
            ("/vib".to_string(), MessageKind::VibBlock),
        ]
    );
    assert!(reader.foreign_topics().is_empty());
    assert_eq!(reader.attachment_names(), ["al15.toml"]);
    assert_eq!(reader.read_attachment("al15.toml").unwrap(), Some(passport));
    assert_eq!(reader.read_attachment("nope").unwrap(), None);
    assert_eq!(reader.metadata().unwrap(), vec![("run".to_string(), run)]);

    let read: Vec<_> = reader.map(Result::unwrap).collect();
    assert_eq!(read.len(), written.len());
    for (r, w) in read.iter().zip(&written) {
        assert_eq!(&*r.topic, w.topic);
        assert_eq!(r.sequence, w.sequence);
        assert_eq!(r.log_time_ns, w.log_time_ns);
        assert_eq!(r.publish_time_ns, w.publish_time_ns);
        assert_eq!(r.message.kind(), w.message.kind());
        assert_eq!(
            r.message.wire_bytes(),
            w.message.wire_bytes(),
            "{} sequence {} changed",
            w.topic,
            w.sequence
        );
    }
    assert!(read
        .windows(2)
        .all(|p| p[0].log_time_ns <= p[1].log_time_ns));
}

#[test]
fn info_reports_counts_span_gaps_metadata_and_attachments() {
    let dir = scratch("info");
    let path = dir.join("gaps.mcap");
    let mut recorder = Recorder::create(&path, RecorderOptions::default()).unwrap();
    recorder
        .add_channel("/accel", MessageKind::AccelBlock)
        .unwrap();
    recorder
        .add_channel("/heartbeat/sim", MessageKind::Heartbeat)
        .unwrap();
    recorder
        .add_metadata(
            "versions",
            BTreeMap::from([("vibrocomp".into(), "0.1.0".into())]),
        )
        .unwrap();
    recorder
        .add_attachment("triad.toml", "application/toml", vec![b'x'; 300])
        .unwrap();
    // Sequences 0 1 2 5 6 9: two gaps, four messages lost.
    for (i, seq) in [0u32, 1, 2, 5, 6, 9].into_iter().enumerate() {
        let t = 2_000_000_000 + i as u64 * 250_000_000;
        recorder
            .write("/accel", t, t, seq, &accel(seq.into()))
            .unwrap();
    }
    recorder
        .write(
            "/heartbeat/sim",
            1_500_000_000,
            1_500_000_000,
            0,
            &heartbeat(0),
        )
        .unwrap();
    recorder.finish().unwrap();

    let info = info(&path).unwrap();
    assert_eq!(info.profile, "vibrocomp");
    assert!(info.library.starts_with("mcap-rust/"), "{}", info.library);
    assert_eq!(info.messages, 7);
    assert_eq!(info.lost, 4);
    assert_eq!(info.first_log_time_ns, Some(1_500_000_000));
    assert_eq!(info.last_log_time_ns, Some(3_250_000_000));
    assert!((info.duration_s - 1.75).abs() < 1e-12);
    assert_eq!(
        info.chunks,
        Some(2),
        "the attachment closed the first chunk"
    );
    let accel = &info.channels[0];
    assert_eq!(accel.topic, "/accel");
    assert_eq!(accel.message_type, "vibrocomp.v1.AccelBlock");
    assert_eq!(accel.kind.as_deref(), Some("AccelBlock"));
    assert_eq!(accel.message_encoding, "protobuf");
    assert_eq!(accel.messages, 6);
    assert_eq!(
        (accel.first_sequence, accel.last_sequence),
        (Some(0), Some(9))
    );
    assert_eq!((accel.gaps, accel.lost, accel.out_of_order), (2, 4, 0));
    assert!((accel.span_s - 1.25).abs() < 1e-12);
    let hb = &info.channels[1];
    assert_eq!(
        (hb.topic.as_str(), hb.messages, hb.lost),
        ("/heartbeat/sim", 1, 0)
    );
    assert_eq!(info.metadata.len(), 1);
    assert_eq!(info.metadata[0].name, "versions");
    assert_eq!(info.metadata[0].entries["vibrocomp"], "0.1.0");
    assert_eq!(info.attachments.len(), 1);
    assert_eq!(info.attachments[0].name, "triad.toml");
    assert_eq!(info.attachments[0].media_type, "application/toml");
    assert_eq!(info.attachments[0].bytes, 300);

    let json = serde_json::to_value(&info).unwrap();
    assert_eq!(json["channels"][0]["lost"], 4);
    assert_eq!(json["attachments"][0]["name"], "triad.toml");
}

#[test]
fn a_full_queue_is_an_error_counted_and_visible_as_a_loss() {
    let dir = scratch("full");
    let path = dir.join("full.mcap");
    let options = RecorderOptions {
        queue_capacity: 1,
        ..RecorderOptions::default()
    };
    let mut recorder = Recorder::create(&path, options).unwrap();
    recorder.add_channel("/vib", MessageKind::VibBlock).unwrap();
    // Encoding and compressing a 256-sample block takes the writer far longer than
    // copying it into the one-slot queue, so most writes find the queue full.
    let block = vib(1);
    let mut accepted = Vec::new();
    let mut rejected = 0u64;
    // Write as fast as possible until both outcomes were seen (bounded, in case the
    // machine is so loaded that the writer thread hardly runs).
    for seq in 0..50_000_000u32 {
        match recorder.write("/vib", u64::from(seq), 0, seq, &block) {
            Ok(()) => accepted.push(seq),
            Err(Error::QueueFull {
                topic,
                sequence,
                capacity,
            }) => {
                assert_eq!((&*topic, sequence, capacity), ("/vib", seq, 1));
                rejected += 1;
            }
            Err(e) => panic!("{e}"),
        }
        if accepted.len() >= 20 && rejected > 0 {
            break;
        }
    }
    let stats = recorder.stats();
    assert!(rejected > 0, "the queue never filled");
    assert!(accepted.len() >= 20, "the writer never drained the queue");
    assert_eq!(stats.rejected_full, rejected);
    assert_eq!(stats.accepted, accepted.len() as u64);
    let summary = recorder.finish().unwrap();
    assert_eq!(summary.rejected_full, rejected);
    assert_eq!(summary.messages, accepted.len() as u64);

    let info = info(&path).unwrap();
    let c = &info.channels[0];
    assert_eq!(c.messages, accepted.len() as u64);
    let first = accepted[0];
    let last = accepted[accepted.len() - 1];
    assert_eq!(c.lost, u64::from(last - first + 1) - accepted.len() as u64);
    let e = Error::QueueFull {
        topic: "/vib".into(),
        sequence: 5,
        capacity: 1,
    };
    assert_eq!(
        e.to_string(),
        "recorder queue full (1 messages waiting): \"/vib\" sequence 5 not recorded"
    );
}

#[test]
fn chunks_reach_the_file_within_the_flush_interval() {
    let dir = scratch("flush");
    let path = dir.join("live.mcap");
    let options = RecorderOptions {
        flush_interval_s: 0.05,
        ..RecorderOptions::default()
    };
    let mut recorder = Recorder::create(&path, options).unwrap();
    recorder
        .add_channel("/accel", MessageKind::AccelBlock)
        .unwrap();
    for seq in 0..10u32 {
        recorder
            .write("/accel", u64::from(seq), 0, seq, &accel(seq.into()))
            .unwrap();
    }
    // Well past the interval, with the recorder still running: what a crash now leaves.
    std::thread::sleep(std::time::Duration::from_millis(400));
    let crash = dir.join("crash.mcap");
    std::fs::copy(&path, &crash).unwrap();
    assert!(matches!(
        Reader::open(&crash),
        Err(Error::NotFinished { .. })
    ));
    let report = vibro_mcap::recover(&crash, dir.join("recovered.mcap")).unwrap();
    assert_eq!(report.messages_recovered, 10);
    assert!(!report.input_complete);
    assert_eq!(recorder.stats().written, 10);
    recorder.finish().unwrap();
}

#[test]
fn a_corrupt_chunk_fails_its_crc_with_both_values() {
    let dir = scratch("crc");
    let path = dir.join("raw.mcap");
    let options = RecorderOptions {
        compression: Compression::None,
        ..RecorderOptions::default()
    };
    let mut recorder = Recorder::create(&path, options).unwrap();
    recorder
        .add_channel("/accel", MessageKind::AccelBlock)
        .unwrap();
    recorder.write("/accel", 1, 1, 0, &accel(0)).unwrap();
    recorder.finish().unwrap();

    // Flip one bit inside a sample value (uncompressed, so the framing stays intact).
    let mut bytes = std::fs::read(&path).unwrap();
    let needle = accel(0).output_v[1][1].to_le_bytes();
    let at = bytes
        .windows(8)
        .position(|w| w == needle)
        .expect("the sample is stored as little-endian f64");
    bytes[at + 3] ^= 0x10;
    let bad = dir.join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();

    let err = Reader::open(&bad).unwrap().next().unwrap().unwrap_err();
    let Error::ChunkCrc {
        path: p,
        saved,
        calculated,
    } = &err
    else {
        panic!("expected a CRC error, got {err}");
    };
    assert_eq!(p, &bad);
    assert_ne!(saved, calculated);
    assert_eq!(
        err.to_string(),
        format!(
            "{}: chunk CRC failed (expected {saved:08X}, got {calculated:08X})",
            bad.display()
        )
    );
    assert!(matches!(info(&bad), Err(Error::ChunkCrc { .. })));
}

#[test]
fn misuse_is_reported_with_the_values_involved() {
    let dir = scratch("misuse");
    let path = dir.join("m.mcap");
    let mut recorder = Recorder::create(&path, RecorderOptions::default()).unwrap();
    let ch = recorder
        .add_channel("/accel", MessageKind::AccelBlock)
        .unwrap();
    assert_eq!(ch.id(), 1);
    assert_eq!(
        recorder
            .add_channel("/accel", MessageKind::AccelBlock)
            .unwrap(),
        ch
    );
    assert_eq!(
        recorder
            .add_channel("/accel", MessageKind::VibBlock)
            .unwrap_err()
            .to_string(),
        "topic \"/accel\" is already registered for AccelBlock, cannot add it for VibBlock"
    );
    assert_eq!(
        recorder
            .write("/vib", 0, 0, 0, &vib(0))
            .unwrap_err()
            .to_string(),
        "topic \"/vib\" is not registered (call add_channel first)"
    );
    assert_eq!(
        recorder
            .write("/accel", 0, 0, 0, &vib(0))
            .unwrap_err()
            .to_string(),
        "topic \"/accel\" carries AccelBlock, not VibBlock"
    );
    let mut too_many = accel(0);
    too_many.count = 33;
    assert_eq!(
        recorder
            .write("/accel", 0, 0, 0, &too_many)
            .unwrap_err()
            .to_string(),
        "invalid message: AccelBlock.count = 33: must be at most 32"
    );
    recorder.write_to(&ch, 5, 5, 0, accel(0).into()).unwrap();
    let summary = recorder.finish().unwrap();
    assert_eq!(summary.messages, 1);

    for (options, text) in [
        (
            RecorderOptions {
                flush_interval_s: f64::NAN,
                ..RecorderOptions::default()
            },
            "recorder option flush_interval_s = NaN: must be finite and > 0",
        ),
        (
            RecorderOptions {
                queue_capacity: 0,
                ..RecorderOptions::default()
            },
            "recorder option queue_capacity = 0: must be > 0",
        ),
        (
            RecorderOptions {
                chunk_size_bytes: 0,
                ..RecorderOptions::default()
            },
            "recorder option chunk_size_bytes = 0: must be > 0",
        ),
        (
            RecorderOptions {
                zstd_level: 0,
                ..RecorderOptions::default()
            },
            "recorder option zstd_level = 0: must be 1..=22",
        ),
        (
            RecorderOptions {
                zstd_level: 23,
                ..RecorderOptions::default()
            },
            "recorder option zstd_level = 23: must be 1..=22",
        ),
    ] {
        let e = Recorder::create(dir.join("x.mcap"), options).err().unwrap();
        assert_eq!(e.to_string(), text);
    }
    let missing = dir.join("no/such/dir/x.mcap");
    let e = Recorder::create(&missing, RecorderOptions::default())
        .err()
        .unwrap();
    assert_eq!(
        e.to_string(),
        format!(
            "output {}: its folder {} does not exist",
            missing.display(),
            dir.join("no/such/dir").display()
        )
    );
    let e = Reader::open(dir.join("absent.mcap")).err().unwrap();
    assert!(e.to_string().starts_with("cannot open "), "{e}");
}

#[test]
fn foreign_channels_are_listed_and_skipped() {
    // A file written by another program with the plain `mcap` writer: one of our
    // channels (schema from `vibro_mcap::schema`) and a JSON log channel.
    let dir = scratch("foreign");
    let path = dir.join("mixed.mcap");
    let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    let mut w = mcap::Writer::new(file).unwrap();
    let s = vibro_mcap::schema(MessageKind::AccelBlock);
    let ours = w.add_schema(s.name, "protobuf", s.data).unwrap();
    let ours = w
        .add_channel(ours, "/accel", "protobuf", &BTreeMap::new())
        .unwrap();
    let log = w.add_schema("Log", "jsonschema", b"{}").unwrap();
    let log = w
        .add_channel(log, "/log", "json", &BTreeMap::new())
        .unwrap();
    let mut buf = Vec::new();
    Message::from(accel(3)).encode(&mut buf).unwrap();
    for (channel_id, t, data) in [
        (log, 1, &b"{\"x\":1}"[..]),
        (ours, 2, &buf),
        (log, 3, b"{}"),
    ] {
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: 0,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header, data).unwrap();
    }
    w.finish().unwrap();
    drop(w);

    let reader = Reader::open(&path).unwrap();
    assert_eq!(reader.foreign_topics(), ["/log"]);
    assert_eq!(
        reader.channels(),
        [("/accel".to_string(), MessageKind::AccelBlock)]
    );
    let read: Vec<_> = reader.map(Result::unwrap).collect();
    assert_eq!(read.len(), 1);
    assert_eq!(read[0].log_time_ns, 2);
    assert_eq!(
        read[0].message.wire_bytes(),
        Message::from(accel(3)).wire_bytes()
    );
    let i = info(&path).unwrap();
    assert_eq!(i.messages, 3);
    assert_eq!(i.channels[1].kind, None);
    assert_eq!(i.channels[1].message_type, "Log");
}
