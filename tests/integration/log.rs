//! `vibrocomp log` end to end: `import` of CSV files written here (tones, a gap, odd
//! values), read back by `vibro_mcap::Reader` and by the independent Python `mcap`
//! reader and compared bit for bit with the CSV's numbers and with block layouts
//! worked out here from the rows; `info` on a log with a known sequence gap; `recover`
//! on a log truncated just after a chunk seen on disk; and bad CSV input.

use crate::common::{bin, num, repo_path, run_failing, run_json};
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use vibro_mcap::{Message, Reader, Recorder, RecorderOptions};
use vibro_msgs::{accel_flags, vib_flags, AccelBlock, MessageKind, VibBlock};

/// A directory of its own per test, removed when the test ends.
struct TempDir(PathBuf);

impl TempDir {
    fn new(test: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("vibrocomp-log-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        Self(dir)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn file(&self, name: &str, text: &str) -> PathBuf {
        let path = self.path(name);
        std::fs::write(&path, text).expect("write temp file");
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

/// One CSV row as the test wrote it: its sample index, time and unit values.
#[derive(Clone, Copy, Debug)]
struct Sample {
    index: u64,
    time_s: f64,
    values: [f64; 3],
}

/// What a block must hold, worked out from the rows alone: runs of consecutive indices
/// cut into blocks of `per_block`; the first block after a gap flagged.
#[derive(Debug, PartialEq)]
struct ExpectedBlock {
    seq: u64,
    first_sample_index: u64,
    t0_ns: u64,
    count: u32,
    gap_before: bool,
    values: Vec<[f64; 3]>,
}

fn expected_blocks(samples: &[Sample], per_block: usize) -> Vec<ExpectedBlock> {
    let mut out: Vec<ExpectedBlock> = Vec::new();
    let mut prev: Option<u64> = None;
    for s in samples {
        let contiguous = prev.is_some_and(|p| s.index == p + 1);
        let start_new = match out.last() {
            None => true,
            Some(b) => !contiguous || b.values.len() == per_block,
        };
        if start_new {
            out.push(ExpectedBlock {
                seq: out.len() as u64,
                first_sample_index: s.index,
                // The test's times are whole nanoseconds.
                t0_ns: (s.time_s * 1e9).round() as u64,
                count: 0,
                gap_before: prev.is_some() && !contiguous,
                values: Vec::new(),
            });
        }
        let b = out.last_mut().expect("a block");
        b.values.push(s.values);
        b.count += 1;
        prev = Some(s.index);
    }
    out
}

/// Writes `samples` as CSV: `preamble` (comments and header), then one row per sample
/// with the values in `order` of the unit columns, and `extra` cells appended.
fn write_csv(samples: &[Sample], preamble: &str, order: [usize; 3], extra: &str) -> String {
    let mut text = preamble.to_string();
    for (k, s) in samples.iter().enumerate() {
        // Rust's `{}` for f64 is the shortest text that parses back to the same bits.
        let v = s.values;
        writeln!(
            text,
            "{},{},{},{}{extra}",
            s.time_s, v[order[0]], v[order[1]], v[order[2]]
        )
        .expect("write to string");
        if k == 10 {
            text.push_str("# a comment between rows\n\n");
        }
    }
    text
}

/// Accelerometer outputs: three 12 Hz tones around -1.67 V at `rate_hz`, indices
/// `0..n` minus `skip`, plus values that lossy code would change.
fn accel_samples(n: u64, rate_hz: f64, t_first_s: f64, skip: std::ops::Range<u64>) -> Vec<Sample> {
    (0..n)
        .filter(|i| !skip.contains(i))
        .map(|i| {
            // Whole microseconds: exact nanoseconds after parsing and scaling.
            let time_s = t_first_s + (i as f64 * 1e6 / rate_hz).round() * 1e-6;
            let phase = 2.0 * std::f64::consts::PI * 12.0 * i as f64 / rate_hz;
            let mut values = [
                -1.6698 + 0.0123 * phase.sin(),
                -1.6701 + 0.0456 * (phase + 2.0).sin(),
                -1.6695 + 0.0789 * (phase + 4.0).sin(),
            ];
            match i {
                3 => values[0] = -0.0,
                4 => values[1] = 5e-324,
                5 => values[2] = -1.797_693_134_862_315_7e308,
                _ => {}
            }
            Sample {
                index: i,
                time_s,
                values,
            }
        })
        .collect()
}

/// Vibration-sensor outputs: 100 Hz, 333 Hz and 1.7 kHz tones at a power-of-two rate
/// (times exact in binary).
fn vib_samples(n: u64, rate_hz: f64, skip: std::ops::Range<u64>) -> Vec<Sample> {
    (0..n)
        .filter(|i| !skip.contains(i))
        .map(|i| {
            let t = i as f64 / rate_hz;
            let w = 2.0 * std::f64::consts::PI * t;
            Sample {
                index: i,
                time_s: t,
                values: [
                    0.12 * (w * 100.0).sin(),
                    0.34 * (w * 333.0 + 1.0).sin(),
                    0.05 * (w * 1700.0 + 2.0).sin() + 1e-3,
                ],
            }
        })
        .collect()
}

/// Runs tests/python/mcap_check.py with every message listed.
fn python_check(file: &Path) -> Value {
    let out = Command::new("python3")
        .arg(repo_path("tests/python/mcap_check.py"))
        .arg(file)
        .arg("--all-messages")
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert_ne!(
        out.status.code(),
        Some(3),
        "Python packages missing: {}; run `pip install -r tests/python/requirements.txt`",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "the Python reader rejected {}:\n{}{}",
        file.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON from mcap_check.py")
}

fn bits(rows: &[[f64; 3]]) -> Vec<u64> {
    rows.iter().flatten().map(|v| v.to_bits()).collect()
}

fn u64_of(v: &Value) -> u64 {
    v.as_u64()
        .unwrap_or_else(|| panic!("not an unsigned integer: {v}"))
}

/// Checks one stream of an imported log, read by both readers, against the blocks
/// expected from its rows.
fn check_stream(
    topic: &str,
    expected: &[ExpectedBlock],
    period_ns: u64,
    rust: &[(u32, u64, u64, Message)],
    python: &Value,
) {
    assert_eq!(
        rust.len(),
        expected.len(),
        "{topic}: blocks read by vibro_mcap"
    );
    let py_messages = python["messages"]
        .as_array()
        .unwrap_or_else(|| panic!("{topic}: no messages from Python"));
    assert_eq!(
        py_messages.len(),
        expected.len(),
        "{topic}: blocks read by Python"
    );
    for ((e, (sequence, log_time_ns, publish_time_ns, message)), py) in
        expected.iter().zip(rust).zip(py_messages)
    {
        let (seq, first, t0_ns, period, count, flags, samples, publish_ns) = match message {
            Message::AccelBlock(b) => (
                b.seq,
                b.first_sample_index,
                b.t0_ns,
                b.sample_period_ns,
                b.count,
                b.flags,
                b.samples_v().to_vec(),
                b.publish_ns,
            ),
            Message::VibBlock(b) => (
                b.seq,
                b.first_sample_index,
                b.t0_ns,
                b.sample_period_ns,
                b.count,
                b.flags,
                b.samples_v().to_vec(),
                b.publish_ns,
            ),
            other => panic!("{topic}: unexpected {:?}", other.kind()),
        };
        let gap_bit = if topic == "/accel" {
            accel_flags::GAP_BEFORE
        } else {
            vib_flags::GAP_BEFORE
        };
        let at = format!("{topic} block {}", e.seq);
        assert_eq!(seq, e.seq, "{at}: seq");
        assert_eq!(u64::from(*sequence), e.seq, "{at}: MCAP sequence = seq");
        assert_eq!(first, e.first_sample_index, "{at}: first_sample_index");
        assert_eq!(t0_ns, e.t0_ns, "{at}: t0_ns");
        assert_eq!(period, period_ns, "{at}: sample_period_ns");
        assert_eq!(count, e.count, "{at}: count");
        assert_eq!(flags, if e.gap_before { gap_bit } else { 0 }, "{at}: flags");
        assert_eq!(
            bits(&samples),
            bits(&e.values),
            "{at}: samples, bit for bit"
        );
        // The block's data time: its last sample's, as the simulator stamps it.
        let last_ns = e.t0_ns + u64::from(e.count - 1) * period_ns;
        assert_eq!(
            (*log_time_ns, *publish_time_ns, publish_ns),
            (last_ns, last_ns, last_ns),
            "{at}: times"
        );

        // The same through Python's reader and protobuf decoder.
        let f = &py["fields"];
        assert_eq!(u64_of(&py["sequence"]), e.seq, "{at} (Python): sequence");
        assert_eq!(
            u64_of(&py["log_time_ns"]),
            last_ns,
            "{at} (Python): log time"
        );
        assert_eq!(
            u64_of(&py["publish_time_ns"]),
            last_ns,
            "{at} (Python): publish time"
        );
        assert_eq!(u64_of(&f["seq"]), e.seq, "{at} (Python): seq");
        assert_eq!(
            u64_of(&f["first_sample_index"]),
            e.first_sample_index,
            "{at} (Python)"
        );
        assert_eq!(u64_of(&f["t0_ns"]), e.t0_ns, "{at} (Python): t0_ns");
        assert_eq!(u64_of(&f["sample_period_ns"]), period_ns, "{at} (Python)");
        assert_eq!(u64_of(&f["source_id"]), 9, "{at} (Python): source_id");
        assert_eq!(
            u64_of(&f["flags"]),
            u64::from(if e.gap_before { gap_bit } else { 0 }),
            "{at} (Python): flags"
        );
        let field = if topic == "/accel" {
            "output_v"
        } else {
            "sample_v"
        };
        let py_bits: Vec<u64> = py["f64_bits"][field]
            .as_array()
            .unwrap_or_else(|| panic!("{at} (Python): no {field}"))
            .iter()
            .map(u64_of)
            .collect();
        assert_eq!(
            py_bits,
            bits(&e.values),
            "{at} (Python): samples, bit for bit"
        );
    }
}

/// Rows of tones with a gap in each stream become the blocks the Packetizer's rules
/// give, every sample bit-identical to the CSV's number, through both readers.
#[test]
fn import_keeps_every_csv_sample_bit_for_bit_across_a_gap() {
    let dir = TempDir::new("import");
    // 1 kHz from 0.25 s; rows 70..75 missing (5 samples): blocks of 32 at 0, 32, then
    // 64..70 (6 rows), then 75.. flagged.
    let accel = accel_samples(300, 1000.0, 0.25, 70..75);
    let accel_preamble = "# rig 3, run 17: AL-15 triad outputs\ntime_s,u1_v,u2_v,u3_v\n";
    let accel_csv = dir.file(
        "accel.csv",
        &write_csv(&accel, accel_preamble, [0, 1, 2], ""),
    );
    // 4096 Hz; rows 1500..1503 missing (blocks of 512 at 0, 512, then 1024..1500,
    // then 1503.. flagged); columns in another order, plus one to ignore, CRLF line ends.
    let vib = vib_samples(2000, 4096.0, 1500..1503);
    let vib_text = write_csv(
        &vib,
        "time_s, vd3_v, vd1_v, \"vd2_v\", temp_c\n",
        [2, 0, 1],
        ",21.5",
    )
    .replace('\n', "\r\n");
    let vib_csv = dir.file("vib.csv", &vib_text);
    let out = dir.path("rig.mcap");

    let report = run_json(&[
        "log",
        "import",
        "--accel",
        s(&accel_csv),
        "--vib",
        s(&vib_csv),
        "--out",
        s(&out),
        "--source-id",
        "9",
        "--json",
    ]);
    let streams = report["streams"].as_array().expect("streams");
    let stream = |name: &str| {
        streams
            .iter()
            .find(|s| s["stream"] == name)
            .unwrap_or_else(|| panic!("no {name} in {report}"))
    };
    let accel_expected = expected_blocks(&accel, 32);
    let vib_expected = expected_blocks(&vib, 512);
    for (name, samples, expected, rate_hz) in [
        ("accel", &accel, &accel_expected, 1000.0),
        ("vib", &vib, &vib_expected, 4096.0),
    ] {
        let st = stream(name);
        assert_eq!(num(st, "rows"), samples.len() as f64, "{name}");
        assert_eq!(num(st, "gaps"), 1.0, "{name}");
        assert_eq!(num(st, "blocks"), expected.len() as f64, "{name}");
        assert!(
            (num(st, "rate_hz") / rate_hz - 1.0).abs() < 1e-9,
            "{name}: {st}"
        );
    }
    assert_eq!(num(stream("accel"), "missing_samples"), 5.0);
    assert_eq!(num(stream("vib"), "missing_samples"), 3.0);
    assert_eq!(
        stream("vib")["ignored_columns"],
        serde_json::json!(["temp_c"])
    );
    assert_eq!(stream("vib")["columns"]["vd2_v"], 4);
    // The expected layouts hold what the rows promise.
    assert_eq!(accel_expected.len(), 11);
    assert_eq!(accel_expected[2].count, 6);
    assert!(accel_expected[3].gap_before && accel_expected[3].first_sample_index == 75);
    assert_eq!(vib_expected.len(), 4);
    assert_eq!(vib_expected[2].count, 476);
    assert!(vib_expected[3].gap_before && vib_expected[3].first_sample_index == 1503);

    // vibro_mcap's reader.
    let mut reader = Reader::open(&out).expect("the log opens");
    assert_eq!(
        reader.channels(),
        vec![
            ("/accel".to_string(), MessageKind::AccelBlock),
            ("/vib".to_string(), MessageKind::VibBlock)
        ]
    );
    let header = reader
        .read_attachment("accel-header.csv")
        .expect("attachment reads")
        .expect("accel-header.csv attached");
    assert_eq!(String::from_utf8(header).expect("utf-8"), accel_preamble);
    let meta: BTreeMap<String, BTreeMap<String, String>> = reader
        .metadata()
        .expect("metadata reads")
        .into_iter()
        .collect();
    let import = &meta["import"];
    assert_eq!(import["accel.file"], s(&accel_csv));
    assert_eq!(import["vib.rows"], vib.len().to_string());
    assert!(import["vib.columns"].contains("vd2_v = column 4 -> sample_v[sample][1] (VD2)"));
    let mut by_topic: BTreeMap<String, Vec<(u32, u64, u64, Message)>> = BTreeMap::new();
    let mut last_log_time = 0;
    for record in reader {
        let r = record.expect("a message");
        assert!(r.log_time_ns >= last_log_time, "log-time order");
        last_log_time = r.log_time_ns;
        by_topic.entry(r.topic.to_string()).or_default().push((
            r.sequence,
            r.log_time_ns,
            r.publish_time_ns,
            r.message,
        ));
    }

    // The Python reference reader.
    let py = python_check(&out);
    assert_eq!(
        py["attachments"],
        serde_json::json!(["vib-header.csv", "accel-header.csv"])
    );
    assert_eq!(py["metadata"]["import"]["accel.gaps"], "1");
    check_stream(
        "/accel",
        &accel_expected,
        1_000_000,
        &by_topic["/accel"],
        &py["channels"]["/accel"],
    );
    // 1e9 / 4096 = 244140.625 ns, rounded as the Packetizer does.
    check_stream(
        "/vib",
        &vib_expected,
        244_141,
        &by_topic["/vib"],
        &py["channels"]["/vib"],
    );

    // Sample gaps are not message losses.
    let info = run_json(&["log", "info", s(&out), "--json"]);
    assert_eq!(
        num(&info, "messages"),
        (accel_expected.len() + vib_expected.len()) as f64
    );
    assert_eq!(num(&info, "lost"), 0.0);

    // The output exists now: no overwriting without --force.
    let again = run_failing(&["log", "import", "--accel", s(&accel_csv), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains("exists") && err.contains("--force"), "{err}");
}

/// `--*-rate-hz` replaces the measured rate; one that disagrees with the time column is
/// refused with the rate the column gives.
#[test]
fn a_given_rate_must_agree_with_the_time_column() {
    let dir = TempDir::new("rate");
    let vib = vib_samples(600, 2048.0, 0..0);
    let csv = dir.file(
        "vib.csv",
        &write_csv(&vib, "time_s,vd1_v,vd2_v,vd3_v\n", [0, 1, 2], ""),
    );
    let out = dir.path("vib.mcap");
    let report = run_json(&[
        "log",
        "import",
        "--vib",
        s(&csv),
        "--vib-rate-hz",
        "2048",
        "--vib-block-samples",
        "100",
        "--out",
        s(&out),
        "--json",
    ]);
    let st = &report["streams"][0];
    assert_eq!(num(st, "rate_hz"), 2048.0);
    assert_eq!(st["rate_from"], "--vib-rate-hz");
    assert_eq!(num(st, "blocks"), 6.0);

    let bad = run_failing(&[
        "log",
        "import",
        "--vib",
        s(&csv),
        "--vib-rate-hz",
        "2000",
        "--out",
        s(&dir.path("bad.mcap")),
    ]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("off the uniform grid") && err.contains("gives 2048 Hz"),
        "{err}"
    );
    assert!(!dir.path("bad.mcap").exists(), "nothing written");
}

/// Every kind of bad row is refused with the file, line, column, value and rule, all
/// at once, and no log is written.
#[test]
fn bad_csv_rows_are_named_by_file_line_column_and_value() {
    let dir = TempDir::new("bad");
    let out = dir.path("never.mcap");
    let cases: [(&str, &str, &[&str]); 6] = [
        (
            "missing-column.csv",
            "time_s,u1_v,u3_v\n0,1,2\n",
            &[
                "missing-column.csv line 1",
                "missing column(s) u2_v",
                "time_s,u1_v,u3_v",
            ],
        ),
        (
            "nan.csv",
            "time_s,u1_v,u2_v,u3_v\n0,1,2,3\n0.001,1,NaN,3\n0.002,1,2,3\n",
            &["nan.csv line 3, column u2_v = \"NaN\"", "finite"],
        ),
        (
            "text.csv",
            "# comment\ntime_s,u1_v,u2_v,u3_v\n0,1,2,3\n0.001,1,2,3\n0.002,one,2,3\n",
            &["text.csv line 5, column u1_v = \"one\"", "not a number"],
        ),
        (
            "backwards.csv",
            "time_s,u1_v,u2_v,u3_v\n0,1,2,3\n0.001,1,2,3\n0.0005,1,2,3\n0.002,1,2,3\n",
            &[
                "backwards.csv line 4, column time_s = 0.0005",
                "not after line 3's 0.001",
                "increase",
            ],
        ),
        (
            "columns.csv",
            "time_s,u1_v,u2_v,u3_v\n0,1,2,3\n0.001,1,2\n0.002,1,2,3\n",
            &[
                "columns.csv line 3 = \"0.001,1,2\"",
                "3 columns, the header (line 1) has 4",
            ],
        ),
        (
            "several.csv",
            "time_s,u1_v,u2_v,u3_v\n0,1,2,3\n0.001,inf,2,3\n0.002,1,2,x\n0.003,1,2,3\n",
            &[
                "2 problem(s)",
                "several.csv line 3, column u1_v = \"inf\"",
                "several.csv line 4, column u3_v = \"x\"",
            ],
        ),
    ];
    for (name, text, wanted) in cases {
        let csv = dir.file(name, text);
        let run = run_failing(&["log", "import", "--accel", s(&csv), "--out", s(&out)]);
        let err = String::from_utf8_lossy(&run.stderr);
        for w in wanted {
            assert!(err.contains(w), "{name}: {w:?} not in:\n{err}");
        }
        assert!(!out.exists(), "{name}: nothing written");
    }
    // A vibration file given as accelerometer data names the columns it lacks.
    let vib = dir.file("vib.csv", "time_s,vd1_v,vd2_v,vd3_v\n0,1,2,3\n");
    let run = run_failing(&["log", "import", "--accel", s(&vib), "--out", s(&out)]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("missing column(s) u1_v, u2_v, u3_v"), "{err}");
}

/// A recorder-written log with /accel sequence 4 and 5 skipped: counts, losses, times,
/// metadata and attachments as written.
#[test]
fn info_reports_counts_and_the_losses_of_a_known_gap() {
    let dir = TempDir::new("info");
    let path = dir.path("gap.mcap");
    let mut rec = Recorder::create(&path, RecorderOptions::default()).expect("recorder");
    rec.add_channel("/accel", MessageKind::AccelBlock)
        .expect("channel");
    rec.add_channel("/vib", MessageKind::VibBlock)
        .expect("channel");
    rec.add_metadata(
        "run",
        BTreeMap::from([("rig".to_string(), "3".to_string())]),
    )
    .expect("metadata");
    rec.add_attachment_at("notes.txt", "text/plain", b"shaker at 40 Hz\n".to_vec(), 0)
        .expect("attachment");
    let mut a = AccelBlock::ZEROED;
    a.count = 1;
    for seq in (0..10u64).filter(|s| !(4..6).contains(s)) {
        a.seq = seq;
        rec.write("/accel", 1_000_000_000 + seq * 1_000_000, 0, seq as u32, &a)
            .expect("write");
    }
    let mut v = VibBlock::ZEROED;
    v.count = 1;
    for seq in 0..6u64 {
        v.seq = seq;
        rec.write("/vib", 2_000_000_000 + seq * 500_000, 0, seq as u32, &v)
            .expect("write");
    }
    rec.finish().expect("finish");

    let info = run_json(&["log", "info", s(&path), "--json"]);
    assert_eq!(num(&info, "messages"), 14.0);
    assert_eq!(num(&info, "lost"), 2.0);
    assert_eq!(num(&info, "first_log_time_ns"), 1_000_000_000.0);
    assert_eq!(num(&info, "last_log_time_ns"), 2_002_500_000.0);
    let channel = |topic: &str| {
        info["channels"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["topic"] == topic))
            .unwrap_or_else(|| panic!("no {topic} in {info}"))
            .clone()
    };
    let accel = channel("/accel");
    assert_eq!(accel["kind"], "AccelBlock");
    assert_eq!(accel["message_type"], "vibrocomp.v1.AccelBlock");
    assert_eq!(
        [
            num(&accel, "messages"),
            num(&accel, "lost"),
            num(&accel, "gaps"),
            num(&accel, "out_of_order")
        ],
        [8.0, 2.0, 1.0, 0.0]
    );
    assert_eq!(
        (num(&accel, "first_sequence"), num(&accel, "last_sequence")),
        (0.0, 9.0)
    );
    assert!((num(&accel, "span_s") - 0.009).abs() < 1e-12);
    let vib = channel("/vib");
    assert_eq!(
        [num(&vib, "messages"), num(&vib, "lost"), num(&vib, "gaps")],
        [6.0, 0.0, 0.0]
    );
    assert_eq!(info["metadata"][0]["name"], "run");
    assert_eq!(info["metadata"][0]["entries"]["rig"], "3");
    assert_eq!(info["attachments"][0]["name"], "notes.txt");
    assert_eq!(num(&info["attachments"][0], "bytes"), 16.0);

    let text = bin()
        .args(["log", "info", s(&path)])
        .output()
        .expect("runs");
    assert!(text.status.success());
    let text = String::from_utf8_lossy(&text.stdout);
    for w in [
        "14 messages on 2 channels",
        "2 messages lost in 1 sequence gaps",
        "notes.txt",
        "rig = 3",
    ] {
        assert!(text.contains(w), "{w:?} not in:\n{text}");
    }

    // A missing file and a file that is not a log fail, named.
    let missing = dir.path("missing.mcap");
    let err = run_failing(&["log", "info", s(&missing)]);
    let err = String::from_utf8_lossy(&err.stderr);
    assert!(
        err.contains("missing.mcap") && err.contains("No such file"),
        "{err}"
    );
    let junk = dir.file("junk.mcap", "time_s,u1_v\n");
    let err = run_failing(&["log", "info", s(&junk)]);
    assert!(String::from_utf8_lossy(&err.stderr).contains("junk.mcap"));
}

fn accel_block(seq: u64) -> AccelBlock {
    let mut b = AccelBlock::ZEROED;
    b.seq = seq;
    b.first_sample_index = seq * 32;
    b.t0_ns = 1_000_000 * (seq * 32 + 1);
    b.sample_period_ns = 1_000_000;
    b.count = 32;
    for (i, row) in b.output_v.iter_mut().enumerate() {
        *row = [
            seq as f64 + i as f64 * 1e-3,
            -1.67 - i as f64 * 1e-6,
            0.1 * seq as f64,
        ];
    }
    b
}

/// Waits until `path` is longer than `than` and has stopped growing: the recorder's
/// writer thread has closed and flushed a chunk.
fn settled_size(path: &Path, than: u64) -> u64 {
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut last = 0;
    loop {
        std::thread::sleep(Duration::from_millis(150));
        let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
        if size > than && size == last {
            return size;
        }
        assert!(
            Instant::now() < deadline,
            "{} stays at {size} bytes",
            path.display()
        );
        last = size;
    }
}

/// A log cut inside its third chunk gives back exactly the first two chunks'
/// messages; the chunk ends are the file sizes seen on disk while recording.
#[test]
fn recover_keeps_every_message_of_the_complete_chunks() {
    let dir = TempDir::new("recover");
    let whole = dir.path("whole.mcap");
    let options = RecorderOptions {
        flush_interval_s: 0.02,
        ..RecorderOptions::default()
    };
    let mut rec = Recorder::create(&whole, options).expect("recorder");
    rec.add_channel("/accel", MessageKind::AccelBlock)
        .expect("channel");
    rec.add_metadata(
        "run",
        BTreeMap::from([("rig".to_string(), "3".to_string())]),
    )
    .expect("metadata");
    let mut sizes = Vec::new();
    for batch in 0..3u64 {
        for seq in batch * 10..batch * 10 + 10 {
            let b = accel_block(seq);
            let t = b.t0_ns + 31 * 1_000_000;
            rec.write("/accel", t, t, seq as u32, &b).expect("write");
        }
        let size = settled_size(&whole, sizes.last().copied().unwrap_or(0));
        sizes.push(size);
    }
    rec.finish().expect("finish");

    // Cut 20 bytes into the record after the second chunk (the third chunk's): a
    // chunk record is longer than that.
    let bytes = std::fs::read(&whole).expect("read");
    let cut = sizes[1] + 20;
    let damaged = dir.file("damaged.mcap", "");
    std::fs::write(&damaged, &bytes[..cut as usize]).expect("write");
    let out = dir.path("recovered.mcap");

    // info refuses the damaged file and points at recover.
    let err = run_failing(&["log", "info", s(&damaged)]);
    let err = String::from_utf8_lossy(&err.stderr);
    assert!(
        err.contains("damaged.mcap") && err.contains("log recover"),
        "{err}"
    );

    let report = run_json(&["log", "recover", s(&damaged), s(&out), "--json"]);
    assert_eq!(num(&report, "messages_recovered"), 20.0, "{report}");
    assert_eq!(report["messages_per_topic"]["/accel"], 20);
    assert!(num(&report, "chunks_recovered") >= 2.0, "{report}");
    assert_eq!(num(&report, "chunks_skipped"), 0.0);
    assert_eq!(report["input_complete"], false);
    assert_eq!(num(&report, "input_bytes"), cut as f64);
    let lost = num(&report, "lost_bytes");
    assert_eq!(lost, cut as f64 - num(&report, "valid_prefix_bytes"));
    assert!(lost > 0.0 && lost <= 20.0, "{report}");
    assert_eq!(report["output"], s(&out));
    assert_eq!(report["channels"][0]["last_sequence"], 19);
    assert_eq!(num(&report, "metadata"), 1.0);

    let mut seqs = Vec::new();
    for record in Reader::open(&out).expect("the recovered log opens") {
        let r = record.expect("a message");
        let Message::AccelBlock(b) = r.message else {
            panic!("unexpected {:?}", r.message.kind());
        };
        let want = accel_block(b.seq);
        assert_eq!(bits(b.samples_v()), bits(want.samples_v()), "seq {}", b.seq);
        assert_eq!(
            (b.first_sample_index, b.t0_ns),
            (want.first_sample_index, want.t0_ns)
        );
        assert_eq!(u64::from(r.sequence), b.seq);
        seqs.push(b.seq);
    }
    assert_eq!(seqs, (0..20).collect::<Vec<_>>());

    // The human report says what was kept and lost.
    let again = bin()
        .args(["log", "recover", s(&damaged), s(&out), "--force"])
        .output()
        .expect("runs");
    assert!(again.status.success());
    let text = String::from_utf8_lossy(&again.stdout);
    assert!(
        text.contains("kept: 20 messages") && text.contains("lost:"),
        "{text}"
    );

    // No overwriting without --force, never the input itself.
    let err = run_failing(&["log", "recover", s(&damaged), s(&out)]);
    assert!(String::from_utf8_lossy(&err.stderr).contains("--force"));
    let err = run_failing(&["log", "recover", s(&damaged), s(&damaged), "--force"]);
    let err = String::from_utf8_lossy(&err.stderr);
    assert!(err.contains("is the input"), "{err}");
    assert_eq!(
        std::fs::read(&damaged).expect("read").len() as u64,
        cut,
        "input untouched"
    );
}
