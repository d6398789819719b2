//! Counts that do not lie (issue 18, item 9), through the real processes:
//!
//! - the compensator killed under `vibrocomp up --record` during a paced replay: `up`
//!   restarts it, and `vibrocomp log info --json` on the recording counts the
//!   accelerometer blocks that got no compensated output as lost, as many as an
//!   independent count from the file's `/accel` and `/compensated` channels says;
//! - a crafted log whose accelerometer blocks carry random `seq`s, replayed into
//!   `vibrocomp up --record`: the compensator's and the recorder's counters stay
//!   bounded and the jumps are flagged (before: `lost_blocks=18366207225729211778`).

use crate::common::{bin, repo_path, run_json};
use crate::processes::{children, flight_log, kill, poll, prefix, Dir, Kid};
use std::collections::BTreeSet;
use std::path::Path;
use std::time::Duration;
use vibro_mcap::{Message, Reader, Recorder, RecorderOptions};
use vibro_msgs::{MessageKind, ServiceId, ServiceNames};
use vibro_service::supervise::wait_for_heartbeats;

/// `vibrocomp up --json --prefix P --record SESSION` with the shipped services.
fn up(prefix: &str, session: &Path) -> Kid {
    let mut cmd = bin();
    cmd.args(["up", "--json", "--prefix", prefix, "--record"])
        .arg(session)
        .arg("--estimator-config")
        .arg(repo_path("config/services/estimator.toml"))
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"));
    let mut kid = Kid::spawn(cmd, "up");
    let names = ServiceNames::new(prefix).unwrap();
    let services = [
        ServiceId::Estimator,
        ServiceId::Compensator,
        ServiceId::Recorder,
    ];
    if let Err(e) = wait_for_heartbeats(&names, &services, Duration::from_secs(30), || {
        kid.check_alive()
    }) {
        panic!("{e:#}\nup stderr:\n{}", kid.stderr());
    }
    kid
}

/// `vibrocomp replay LOG --prefix P --rate 2`, run to its end.
fn replay(prefix: &str, log: &Path) -> Kid {
    let mut cmd = bin();
    cmd.arg("replay")
        .arg(log)
        .args(["--prefix", prefix, "--rate", "2"]);
    Kid::spawn(cmd, "replay")
}

fn compensator_of(up: u32, not: u32) -> Option<u32> {
    children(up)
        .into_iter()
        .find(|(pid, cmd)| *pid != not && cmd.contains("service compensator"))
        .map(|(pid, _)| pid)
}

fn log_info_json(session: &Path) -> serde_json::Value {
    run_json(&["log", "info", "--json", session.to_str().unwrap()])
}

fn channel<'a>(info: &'a serde_json::Value, topic: &str) -> &'a serde_json::Value {
    info["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == topic)
        .unwrap_or_else(|| panic!("no {topic} in {info}"))
}

/// The compensator is killed under `up --record` while a replay streams: `log info`
/// reports the accelerometer blocks without compensated output, as lost, and their
/// number is the one the file's two channels give by themselves.
#[test]
fn a_compensator_restart_shows_as_lost_blocks_in_log_info() {
    let dir = Dir::new("cnt");
    let log = flight_log(&dir, "8");
    let p = prefix("cn");
    let session = dir.path("session.mcap");
    let mut up = up(&p, &session);
    let victim = compensator_of(up.pid(), 0).expect("a compensator under up");
    let mut replay = replay(&p, &log);
    // 1.5 s of wall time: 3 s of the 8 s of data at rate 2.
    std::thread::sleep(Duration::from_millis(1500));
    kill(victim, libc::SIGKILL);
    assert!(
        poll(Duration::from_secs(20), || compensator_of(up.pid(), victim)
            .is_some()),
        "up did not restart the compensator\n{}",
        up.stderr()
    );
    let (status, _, err) = replay.wait(Duration::from_secs(60));
    assert!(status.success(), "replay: {status}\n{err}");
    // Let the restarted compensator and the recorder take the last blocks.
    std::thread::sleep(Duration::from_secs(2));
    let (status, _, err) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {status}\n{err}");

    // The independent count: accelerometer blocks (by seq, on /accel) between the
    // first and the last answered one that no /compensated block answers (by
    // input_seq), read with vibro_mcap's reader.
    let (mut accel, mut answered) = (BTreeSet::new(), BTreeSet::new());
    for r in Reader::open(&session).unwrap() {
        let r = r.unwrap();
        match (&*r.topic, &r.message) {
            ("/accel", Message::AccelBlock(b)) => {
                accel.insert(b.seq);
            }
            ("/compensated", Message::CompensatedBlock(b)) => {
                answered.insert(b.input_seq);
            }
            _ => {}
        }
    }
    let (first, last) = (*answered.first().unwrap(), *answered.last().unwrap());
    let unanswered = accel
        .range(first..=last)
        .filter(|s| !answered.contains(s))
        .count() as u64;
    assert!(unanswered > 0, "the kill left no block without output");

    let info = log_info_json(&session);
    let c = channel(&info, "/compensated");
    assert_eq!(c["inputs_without_output"], unanswered, "{c}");
    assert_eq!(c["restarts"], 1, "its seq restarted once: {c}");
    assert_eq!(info["inputs_without_output"], unanswered, "{info}");
    let by_sequence: u64 = info["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["lost"].as_u64().unwrap())
        .sum();
    assert_eq!(info["lost"], by_sequence + unanswered, "{info}");
    // The text names it.
    let out = bin().args(["log", "info"]).arg(&session).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let gap = &c["unanswered"]["listed"][0];
    let want = format!(
        "{unanswered} accelerometer blocks without compensated output on /compensated (seq {}..={}",
        gap["first"], gap["last"]
    );
    assert!(text.contains(&want), "{want:?} not in\n{text}");
    eprintln!(
        "FIGURES counts-restart: {unanswered} accel blocks without output, seq {}..={}",
        gap["first"], gap["last"]
    );
}

/// `log` rewritten to `out`, each message through `edit` (same channels, times and
/// sequence numbers).
fn rewrite_log(log: &Path, out: &Path, mut edit: impl FnMut(&mut Message)) {
    let mut w = Recorder::create(out, RecorderOptions::default()).unwrap();
    let mut channels = std::collections::HashMap::new();
    for r in Reader::open(log).unwrap() {
        let r = r.unwrap();
        let kind = r.message.kind();
        let ch = channels
            .entry(r.topic.to_string())
            .or_insert_with(|| w.add_channel(&r.topic, kind).unwrap())
            .clone();
        let mut m = r.message;
        edit(&mut m);
        assert_eq!(kind, m.kind());
        while let Err(e) = w.write_to(&ch, r.log_time_ns, r.publish_time_ns, r.sequence, m) {
            assert!(matches!(e, vibro_mcap::Error::QueueFull { .. }), "{e}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    w.finish().unwrap();
    assert!(channels
        .values()
        .any(|c| c.kind() == MessageKind::AccelBlock));
}

/// A crafted log: `log`'s accelerometer blocks with random `seq`s (xorshift64), the
/// rest as it was.
fn random_seq_log(log: &Path, out: &Path) -> u64 {
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let mut n = 0;
    rewrite_log(log, out, |m| {
        if let Message::AccelBlock(b) = m {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            b.seq = x;
            n += 1;
        }
    });
    n
}

/// The value of `key=` (a tracing field) on the first line of `text` holding `what`.
fn field(text: &str, what: &str, key: &str) -> u64 {
    let text = strip_ansi(text);
    let line = text
        .lines()
        .find(|l| l.contains(what))
        .unwrap_or_else(|| panic!("no {what:?} in\n{text}"));
    let at = line
        .find(&format!(" {key}="))
        .unwrap_or_else(|| panic!("no {key} in {line}"));
    line[at + key.len() + 2..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{key} is not a count in {line}"))
}

/// `text` without its ANSI colour sequences (`ESC [ ... m`).
fn strip_ansi(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// `log` replayed (rate 2) into `up --record session` on `prefix`, `up` stopped by
/// SIGINT 2 s after the replay's end: `up`'s stdout and stderr.
fn replay_recorded(prefix: &str, log: &Path, session: &Path) -> (String, String) {
    let mut up = up(prefix, session);
    let mut replay = replay(prefix, log);
    let (status, _, err) = replay.wait(Duration::from_secs(60));
    assert!(status.success(), "replay: {status}\n{err}");
    std::thread::sleep(Duration::from_secs(2));
    let (status, out, err) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {status}\n{err}");
    (out, err)
}

/// Random accelerometer `seq`s through `replay` into `up --record`: no absurd loss
/// count anywhere, the jumps are flagged.
#[test]
fn random_seqs_through_the_services_are_flagged_jumps_not_losses() {
    let dir = Dir::new("cnr");
    let log = flight_log(&dir, "4");
    let crafted = dir.path("random-seq.mcap");
    let blocks = random_seq_log(&log, &crafted);
    let session = dir.path("session.mcap");
    let (out, err) = replay_recorded(&prefix("cr"), &crafted, &session);
    // Each of the `blocks` random seqs is, against the one accepted before it, either
    // a jump (forward) or out of order (back): never a loss of 2^63 blocks.
    let lost = field(&err, "compensator stopped", "lost_blocks");
    let jumps = field(&err, "compensator stopped", "seq_jumps");
    let received = field(&err, "compensator stopped", "received");
    assert_eq!(received, blocks, "{err}");
    assert_eq!(lost, 0, "{err}");
    assert!(jumps > 0 && jumps < blocks, "{jumps} of {blocks}\n{err}");
    // The recorder: its text summary (on up's stderr: up's stdout is its own JSON)
    // flags the jumps on /accel.
    assert!(strip_ansi(&err).contains("seq jumps"), "{err}");
    assert!(
        serde_json::from_str::<serde_json::Value>(&out).is_ok(),
        "{out}"
    );
    // The compensator's heartbeats carry its out-of-order and resync counts (schema
    // v5): the last one recorded (2 s after the replay's end) says what its stop line
    // says, over both inputs. Random seqs are about half behind the last accepted one.
    let ooo = field(&err, "compensator stopped", "out_of_order")
        + field(&err, "compensator stopped", "estimates_out_of_order");
    let resyncs = field(&err, "compensator stopped", "resyncs")
        + field(&err, "compensator stopped", "estimate_resyncs");
    let beat = Reader::open(&session)
        .unwrap()
        .filter_map(|r| match r.unwrap().message {
            Message::Heartbeat(h) if h.service == ServiceId::Compensator.code() => Some(h),
            _ => None,
        })
        .last()
        .expect("a compensator heartbeat in the recording");
    assert!(ooo > blocks / 4, "{ooo} of {blocks} out of order\n{err}");
    assert_eq!(
        (beat.out_of_order, beat.resyncs),
        (ooo, resyncs),
        "{beat:?}"
    );
    // The recording: MCAP keeps 32 bits of the random seqs; info flags them as jumps.
    let info = log_info_json(&session);
    let a = channel(&info, "/accel");
    let info_lost = a["lost"].as_u64().unwrap();
    assert!(
        info_lost <= a["gaps"].as_u64().unwrap() * vibro_mcap::MAX_LOST_MESSAGES,
        "{a}"
    );
    assert!(a["jumps"].as_u64().unwrap() > 0, "{a}");
    eprintln!(
        "FIGURES counts-random: {blocks} blocks, compensator lost_blocks={lost} seq_jumps={jumps} \
         out_of_order={ooo} resyncs={resyncs}; info /accel lost {} gaps {} jumps {} out_of_order {}",
        a["lost"], a["gaps"], a["jumps"], a["out_of_order"]
    );
}

/// `log` with its `k`-th accelerometer block's `t0_ns` set to `u64::MAX`, the rest as it
/// was; returns the latest data time of the real blocks.
fn forged_time_log(log: &Path, out: &Path, k: usize) -> u64 {
    let (mut n, mut latest_ns) = (0, 0u64);
    rewrite_log(log, out, |m| {
        if let Some(t) = m.data_ns() {
            latest_ns = latest_ns.max(t);
        }
        if let Message::AccelBlock(b) = m {
            if n == k {
                b.t0_ns = u64::MAX;
            }
            n += 1;
        }
    });
    assert!(n > k, "{n} accelerometer blocks");
    latest_ns
}

/// Issue 31, item 6: one block with `t0_ns = u64::MAX` stamped every later heartbeat
/// and log line of the recording at 18,446,744,073.7 s. Now it is counted off the
/// timeline, and every message of the recording keeps a log time on the data's own.
#[test]
fn one_forged_block_time_does_not_move_the_recordings_timeline() {
    let dir = Dir::new("cnt");
    let log = flight_log(&dir, "4");
    let crafted = dir.path("forged-time.mcap");
    let latest_ns = forged_time_log(&log, &crafted, 20);
    let session = dir.path("session.mcap");
    let (_, err) = replay_recorded(&prefix("ct"), &crafted, &session);
    let (mut beyond, mut heartbeats, mut max_ns) = (0, 0, 0u64);
    for r in Reader::open(&session).unwrap() {
        let r = r.unwrap();
        heartbeats += usize::from(matches!(r.message, Message::Heartbeat(_)));
        max_ns = max_ns.max(r.log_time_ns);
        beyond += usize::from(r.log_time_ns > latest_ns + 60_000_000_000);
    }
    assert!(heartbeats > 0);
    assert_eq!(
        beyond, 0,
        "messages stamped beyond the data (latest log time {max_ns} ns)"
    );
    // The forged block (and the compensator's output for it) counted off the timeline.
    let info = log_info_json(&session);
    let off = field(&err, "recording finished", "off_timeline");
    assert!((1..=2).contains(&off), "off_timeline={off}\n{err}");
    eprintln!(
        "FIGURES counts-forged-time: latest log time {:.3} s (data up to {:.3} s), {heartbeats} heartbeats, {off} messages off the timeline; /accel {}",
        max_ns as f64 * 1e-9,
        latest_ns as f64 * 1e-9,
        channel(&info, "/accel")
    );
}

/// `log` rewritten to `out` with its accelerometer blocks numbered 0..=10, then a
/// forged copy of block 11 numbered 500,000 (issue 46, item 6), then 11..=60 (the later
/// ones left out); the rest as it was.
fn forged_seq_log(log: &Path, out: &Path) {
    let mut w = Recorder::create(out, RecorderOptions::default()).unwrap();
    let mut channels = std::collections::HashMap::new();
    for r in Reader::open(log).unwrap() {
        let r = r.unwrap();
        let kind = r.message.kind();
        let ch = channels
            .entry(r.topic.to_string())
            .or_insert_with(|| w.add_channel(&r.topic, kind).unwrap())
            .clone();
        let put = |sequence: u32, m: Message| {
            while let Err(e) = w.write_to(&ch, r.log_time_ns, r.publish_time_ns, sequence, m) {
                assert!(matches!(e, vibro_mcap::Error::QueueFull { .. }), "{e}");
                std::thread::sleep(Duration::from_millis(1));
            }
        };
        match r.message {
            Message::AccelBlock(b) if b.seq > 60 => {}
            Message::AccelBlock(b) if b.seq == 11 => {
                let mut forged = b;
                forged.seq = 500_000;
                put(500_000, Message::AccelBlock(forged));
                put(r.sequence, r.message);
            }
            m => put(r.sequence, m),
        }
    }
    w.finish().unwrap();
}

/// Issue 46, item 6: accelerometer blocks 0..=10, a forged 500,000, then 11..=60 into
/// `up --record`. Before: the recorder said `/accel lost 499989` with `seq_jumps=0`,
/// `log info` 499,989 lost and its JSON `lost` 999,978 (counted twice), and blocks
/// 11..=13 (which the compensator drops while it takes the stream up again) were
/// reported nowhere. Now the recorder, `log info` and its JSON count the forged step as
/// a loss taken back (no loss), add each loss once, and list 11..=13; the reference is
/// an independent count in Python from the recording against the published log.
#[test]
fn a_forged_seq_counts_no_loss_and_the_blocks_without_output_are_listed() {
    let dir = Dir::new("cnf");
    let log = flight_log(&dir, "4");
    let crafted = dir.path("forged-seq.mcap");
    forged_seq_log(&log, &crafted);
    let session = dir.path("session.mcap");
    let (_, err) = replay_recorded(&prefix("cf"), &crafted, &session);

    // The reference: tests/python/loss_reference.py, from the files alone.
    let out = std::process::Command::new("python3")
        .arg(repo_path("tests/python/loss_reference.py"))
        .arg(&session)
        .arg("--published")
        .arg(&crafted)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "loss_reference.py failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let reference: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // The compensator dropped 11..=13 (out of order behind the forged block, until the
    // fourth of them resynced its stream: vibro_msgs::continuity) and answered the rest.
    assert_eq!(
        reference["unanswered"]["ranges"],
        serde_json::json!([[11, 13]]),
        "{reference}"
    );
    assert_eq!(
        field(&err, "compensator stopped", "out_of_order"),
        3,
        "{err}"
    );
    let total = reference["lost"].as_u64().unwrap();

    // The recorder's summary (on up's stderr): what it lost (the blocks without an
    // output are listed apart: it has them).
    let line = |key| field(&err, "recording finished", key);
    let recorder_lost = reference["accel"]["lost"].as_u64().unwrap()
        + reference["compensated"]["lost"].as_u64().unwrap();
    assert_eq!(line("lost"), recorder_lost, "{err}");
    assert_eq!(line("seq_jumps"), 0, "{err}");
    assert_eq!(line("resyncs"), 1, "{err}");
    assert_eq!(line("retracted"), 499_989, "{err}");
    assert_eq!(line("inputs_without_output"), 3, "{err}");
    let text = strip_ansi(&err);
    let accel_line = text
        .lines()
        .find(|l| l.trim_start().starts_with("/accel "))
        .unwrap_or_else(|| panic!("no /accel line in\n{text}"));
    assert!(
        accel_line.contains(&format!(
            "lost {:>4}",
            reference["accel"]["lost"].as_u64().unwrap()
        )) && accel_line.contains("resyncs 1 (499989 taken back)"),
        "{accel_line}"
    );
    assert!(
        text.contains("3 accelerometer blocks without compensated output: seq 11..=13"),
        "{text}"
    );

    // log info --json: each loss once, the top-level total the sum over the channels.
    let info = log_info_json(&session);
    let a = channel(&info, "/accel");
    assert_eq!(a["lost"], reference["accel"]["lost"], "{a}");
    assert_eq!(
        (
            &a["resyncs"],
            &a["retracted"],
            &a["jumps"],
            &a["out_of_order"]
        ),
        (&1.into(), &499_989.into(), &0.into(), &3.into()),
        "{a}"
    );
    let c = channel(&info, "/compensated");
    assert_eq!(c["lost"], reference["compensated"]["lost"], "{c}");
    assert_eq!(c["inputs_without_output"], 3, "{c}");
    assert_eq!(
        c["unanswered"]["listed"],
        serde_json::json!([{"first": 11, "last": 13}]),
        "{c}"
    );
    let by_channel: u64 = info["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["lost"].as_u64().unwrap() + c["inputs_without_output"].as_u64().unwrap())
        .sum();
    assert_eq!(info["lost"], total, "{info}");
    assert_eq!(by_channel, total, "{info}");
    // The text lists them.
    let out = bin().args(["log", "info"]).arg(&session).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains(
            "3 accelerometer blocks without compensated output on /compensated (seq 11..=13 on /accel)"
        ),
        "{text}"
    );
    assert!(
        text.contains("1 resyncs, 499989 counted lost at a seq ahead of its stream and taken back"),
        "{text}"
    );
    eprintln!(
        "FIGURES counts-forged-seq: reference {reference}; recorder lost={} resyncs={} retracted={} \
         inputs_without_output={}; info lost {} (/accel lost {} retracted {}; /compensated {} without output {})",
        line("lost"),
        line("resyncs"),
        line("retracted"),
        line("inputs_without_output"),
        info["lost"],
        a["lost"],
        a["retracted"],
        c["inputs_without_output"],
        c["unanswered"]["listed"]
    );
}
