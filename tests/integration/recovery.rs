//! `vibrocomp log recover` and `log info` on damaged logs (issue 46): a first chunk
//! that claims 2^40 bytes loses nothing; a recovery that drops messages exits 3, says
//! so in its last line and in `--json`, and leaves a record in the new file that `log
//! info` reports; MCAP magic followed by zeros is refused once, clearly, with no file
//! written. The messages are compared with the original's by the Python `mcap`
//! reader (`tests/python/mcap_same_messages.py`), which shares no code with vibrocomp.

use crate::common::{bin, repo_path};
use crate::processes::Dir;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// A 5 s simulated flight (500 messages), written by `vibrocomp sim`.
fn flight(dir: &Dir) -> std::path::PathBuf {
    let path = dir.path("flight.mcap");
    let out = bin()
        .args(["sim", "cyclone-4-short", "--duration-s", "5", "-q", "--out"])
        .arg(&path)
        .output()
        .expect("vibrocomp runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    path
}

/// Where each chunk record starts and ends, walking the records after the magic.
fn chunks(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut pos = 8;
    while pos + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        match bytes[pos] {
            0x06 => out.push((pos, pos + 9 + len)),
            0x0F => break,
            _ => {}
        }
        pos += 9 + len;
    }
    out
}

fn same_messages(a: &Path, b: &Path) -> Value {
    let out = Command::new("python3")
        .arg(repo_path("tests/python/mcap_same_messages.py"))
        .args([a, b])
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON")
}

fn recover(damaged: &Path, out: &Path, json: bool) -> Output {
    let mut cmd = bin();
    cmd.args(["log", "recover", s(damaged), s(out), "--force"]);
    if json {
        cmd.arg("--json");
    }
    cmd.output().expect("vibrocomp runs")
}

/// The file: the first chunk's uncompressed size set to 2^40. Before: exit 0
/// with 0 of the messages kept ("dropped: ... whose channel was defined only in a
/// skipped chunk"), and `log info` of the result said "losses: none".
#[test]
fn a_first_chunk_claiming_2_pow_40_bytes_is_recovered_whole() {
    let dir = Dir::new("recover-2e40");
    let original = flight(&dir);
    let mut bytes = std::fs::read(&original).unwrap();
    let (first, _) = chunks(&bytes)[0];
    bytes[first + 9 + 16..first + 9 + 24].copy_from_slice(&(1u64 << 40).to_le_bytes());
    let damaged = dir.path("huge.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = dir.path("out.mcap");
    let run = recover(&damaged, &out, true);
    assert_eq!(
        run.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON");
    assert_eq!(report["messages_recovered"], 500, "{report}");
    assert_eq!(report["expected"]["messages"], 500, "{report}");
    assert_eq!(report["losses"], false);
    assert_eq!(report["exit_code"], 0);
    assert_eq!(report["chunks_repaired"], 1);
    let py = same_messages(&original, &out);
    assert_eq!(
        (py["a"].as_u64(), py["equal"].as_bool()),
        (Some(500), Some(true)),
        "{py}"
    );
}

/// A damaged chunk at the start of the streams: the recovery exits 3, ends with a line
/// that says what was lost, puts the same in `--json`, and `log info` of the result
/// reports it (its sequences alone show nothing).
#[test]
fn a_recovery_with_losses_exits_3_and_log_info_reports_them() {
    let dir = Dir::new("recover-losses");
    let original = flight(&dir);
    let mut bytes = std::fs::read(&original).unwrap();
    // The second chunk: the first holds the schemas and channels only.
    let (start, end) = chunks(&bytes)[1];
    bytes[end - 1] ^= 0x01;
    let damaged = dir.path("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = dir.path("out.mcap");

    let run = recover(&damaged, &out, false);
    assert_eq!(
        run.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        run.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let text = String::from_utf8_lossy(&run.stdout);
    let last = text.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("  result: recovered with losses (exit status 3): "),
        "{text}"
    );
    let py = same_messages(&original, &out);
    let dropped = py["only_in_a"].as_u64().unwrap();
    assert!(dropped > 0 && py["only_in_b"] == 0, "{py}");
    assert!(
        last.contains(&format!(
            "{} of 500 messages kept, {dropped} messages dropped",
            500 - dropped
        )),
        "{last}"
    );

    let run = recover(&damaged, &out, true);
    assert_eq!(run.status.code(), Some(3));
    let report: Value =
        serde_json::from_slice(&run.stdout).expect("one JSON object, no error object");
    assert_eq!(report["exit_code"], 3);
    assert_eq!(report["losses"], true);
    assert_eq!(report["messages_dropped"], dropped);
    assert_eq!(report["messages_dropped_exact"], true);
    assert_eq!(report["result"].as_str(), last.strip_prefix("  result: "));
    assert_eq!(report["damage"][0]["start_byte"], start);

    let info = bin().args(["log", "info", s(&out)]).output().unwrap();
    assert!(info.status.success());
    let info = String::from_utf8_lossy(&info.stdout);
    assert!(!info.contains("losses: none ("), "{info}");
    assert!(
        info.contains(&format!(
            "but {dropped} messages dropped when it was recovered"
        )),
        "{info}"
    );
    assert!(
        info.contains(&format!("recovered from damaged.mcap ({} bytes; vibrocomp.recovery): {} of 500 messages kept, {dropped} messages dropped, 1 chunk(s) skipped", bytes.len(), 500 - dropped)),
        "{info}"
    );
    let json = bin()
        .args(["log", "info", s(&out), "--json"])
        .output()
        .unwrap();
    let json: Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(json["recoveries"][0]["messages_dropped"], dropped);
    assert_eq!(
        json["recoveries"][0]["skipped_ranges"],
        format!("{start}..{end}")
    );
}

/// MCAP magic and then zeros: `log info` points at `log recover`, which says once
/// that there is nothing to recover (it said "Bad magic number: Bad magic number") and
/// writes nothing.
#[test]
fn magic_and_zeros_is_refused_once_with_no_file_written() {
    let dir = Dir::new("recover-zeros");
    let damaged = dir.path("zeros.mcap");
    let mut bytes = b"\x89MCAP0\r\n".to_vec();
    bytes.resize(4 << 20, 0);
    std::fs::write(&damaged, &bytes).unwrap();
    let info = bin().args(["log", "info", s(&damaged)]).output().unwrap();
    assert_eq!(info.status.code(), Some(1));
    let info = String::from_utf8_lossy(&info.stderr);
    assert!(
        info.contains(&format!("vibrocomp log recover {} OUT.mcap", s(&damaged))),
        "{info}"
    );
    let out = dir.path("out.mcap");
    let run = recover(&damaged, &out, false);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("nothing to recover"), "{err}");
    assert!(err.contains("record opcode 0x00 at byte 8"), "{err}");
    assert!(!err.contains("Bad magic"), "{err}");
    assert_eq!(err.matches("nothing to recover").count(), 1, "{err}");
    assert!(!out.exists());
    let leftovers: Vec<_> = std::fs::read_dir(dir.path(".")).unwrap().collect();
    assert_eq!(leftovers.len(), 1, "only the input: {leftovers:?}");
}
