//! Input that is not what it claims to be ("Reliability, round two", docs/reliability.md):
//! a CSV line far over the 64 KiB cap (`estimate`, `log import`), `/dev/zero` as a CSV
//! file (a quick exit naming the cap, within a small address space), and `log info` on
//! an MCAP file its writer did not finish (cut mid-chunk, after a chunk, before the
//! footer, inside its first chunk).

use crate::common::bin;
use crate::processes::Dir;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

/// Runs `vibrocomp ARGS` in an address space of at most 1 GiB (`ulimit -v`: the
/// unbounded reader died there of a failed allocation), killed after 20 s.
fn run_limited(args: &[&str]) -> (Output, Duration) {
    let vibrocomp = env!("CARGO_BIN_EXE_vibrocomp");
    let mut child = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 1048576 && exec \"$0\" \"$@\"")
        .arg(vibrocomp)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sh runs");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            break;
        }
        if start.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("vibrocomp {args:?} still running after 20 s: killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let elapsed = start.elapsed();
    (child.wait_with_output().expect("output"), elapsed)
}

/// Exit 1 with a short error naming the file, the line, the cap and the first bytes.
fn assert_capped(out: &Output, file: &str, line: u64, head: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err:.2000}");
    assert!(
        err.len() < 1024,
        "{} bytes of error: {err:.2000}",
        err.len()
    );
    for part in [
        format!("{file} line {line}: longer than 65536 bytes"),
        "the cap on a line".to_string(),
        format!("It starts \"{head}\""),
    ] {
        assert!(err.contains(&part), "no {part:?} in: {err}");
    }
}

#[test]
fn a_1_mb_line_is_refused_at_the_cap_with_a_short_error() {
    let dir = Dir::new("line-cap-mb");
    let long = "a".repeat(1 << 20);
    let est = dir.path("est.csv");
    std::fs::write(&est, format!("x,y,z\n1,2,3\n{long},1,2\n4,5,6\n")).expect("write");
    let out = bin()
        .args(["estimate", s(&est), "--rate-hz", "5000"])
        .output()
        .expect("runs");
    assert_capped(&out, s(&est), 3, &"a".repeat(60));

    let vib = dir.path("vib.csv");
    std::fs::write(
        &vib,
        format!("# rig\ntime_s,vd1_v,vd2_v,vd3_v\n0,1,2,3\n0.001,1,2,3\n{long}\n"),
    )
    .expect("write");
    let mcap = dir.path("out.mcap");
    let out = bin()
        .args(["log", "import", "--vib", s(&vib), "--out", s(&mcap)])
        .output()
        .expect("runs");
    assert_capped(&out, s(&vib), 5, &"a".repeat(60));
    assert!(!mcap.exists(), "nothing written");
}

#[test]
fn dev_zero_is_refused_quickly_in_a_small_address_space() {
    let zeros = "\\x00".repeat(60);
    let (out, took) = run_limited(&["estimate", "/dev/zero", "--rate-hz", "5000"]);
    assert_capped(&out, "/dev/zero", 1, &zeros);
    assert!(took < Duration::from_secs(5), "estimate took {took:?}");

    let dir = Dir::new("line-cap-zero");
    let mcap = dir.path("out.mcap");
    let (out, took) = run_limited(&["log", "import", "--vib", "/dev/zero", "--out", s(&mcap)]);
    assert_capped(&out, "/dev/zero", 1, &zeros);
    assert!(took < Duration::from_secs(5), "log import took {took:?}");
}

/// The ends of the chunk records of an MCAP file (opcode, u64 length, body).
fn chunk_ends(bytes: &[u8]) -> Vec<usize> {
    let mut ends = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().expect("8 bytes")) as usize;
        if bytes[at] == 0x06 {
            ends.push(at + 9 + len);
        }
        if bytes[at] == 0x02 {
            break;
        }
        at += 9 + len;
    }
    ends
}

#[test]
fn log_info_on_an_unfinished_file_says_so_once_with_the_chunks_to_recover() {
    let dir = Dir::new("line-cap-cut");
    let log = dir.path("sim.mcap");
    let out = bin()
        .args(["sim", "cyclone-4-short", "--out", s(&log)])
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bytes = std::fs::read(&log).expect("read the log");
    let ends = chunk_ends(&bytes);
    assert!(ends.len() >= 4, "{ends:?}");
    let footer = bytes.len() - 8 - 29;
    // Mid-chunk, right after a chunk, before the footer, inside the first data chunk
    // (whose length then exceeds the file: the "opcode 06" message of the issue).
    for (name, cut, chunks) in [
        ("mid", (ends[2] + ends[3]) / 2, 3),
        ("after", ends[2], 3),
        ("footer", footer, ends.len()),
        ("first", (ends[0] + ends[1]) / 2, 1),
    ] {
        let cut_log = dir.path(&format!("{name}.mcap"));
        std::fs::write(&cut_log, &bytes[..cut]).expect("write");
        let out = bin()
            .args(["log", "info", s(&cut_log)])
            .output()
            .expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{name}: {err}");
        let want = format!(
            "{} is damaged: unfinished MCAP file (no footer: the writer stopped before finishing it, e.g. killed or out of disk): {chunks} complete chunk(s) readable; recover them with: vibrocomp log recover {} OUT.mcap",
            s(&cut_log),
            s(&cut_log)
        );
        assert_eq!(err.matches(&want).count(), 1, "{name}: {err}");
        assert_eq!(err.matches("unfinished").count(), 1, "{name}: {err}");
        assert!(!err.contains("opcode"), "{name}: {err}");
    }
}
