//! Log replay through the real service processes (`vibrocomp service estimator`,
//! `vibrocomp service compensator`, `vibrocomp record`, `vibrocomp replay`):
//!
//! - as fast as possible, lock-stepped, the compensated output recorded from the
//!   processes equals bit for bit what the estimator library and the compensator's
//!   in-process handler give for the same log, and again on a second replay into the
//!   same running services;
//! - paced at 10x real time, nothing is lost (sequence numbers of every recorded
//!   channel, the services' own counters);
//! - the recordings decode with the Python `mcap` reader (CRCs checked).

use crate::common::{bin, repo_path};
use crate::processes::{children, flight_log, free_port, poll, prefix, Dir, Kid};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;
use vibro_dsp::{Estimator, SampleBlock};
use vibro_mcap::{Message, Reader};
use vibro_msgs::compensation_flags::INPUT_GAP;
use vibro_msgs::{CompensatedBlock, ServiceId, ServiceNames, VibEstimate};
use vibro_service::supervise::{wait_for_heartbeats, Process};
use vibro_service::ServiceConfig;
use vibro_system::{Role, SystemSpec};

fn spec(prefix: &str, record: Option<PathBuf>) -> SystemSpec {
    SystemSpec {
        prefix: prefix.to_string(),
        // The shipped configurations, as a user in the repository gets them.
        estimator_config: Some(repo_path("config/services/estimator.toml")),
        compensator_config: Some(repo_path("config/services/compensator.toml")),
        record,
        json: true,
        exe: Some(PathBuf::from(env!("CARGO_BIN_EXE_vibrocomp"))),
        ..SystemSpec::default()
    }
}

fn start(spec: &SystemSpec, role: Role, log: &Path) -> Process {
    spec.spawn(role, Some(log)).unwrap()
}

pub(crate) fn wait_up(
    prefix: &str,
    services: &[ServiceId],
    procs: &mut [&mut Process],
    log: &Path,
) {
    let names = ServiceNames::new(prefix).unwrap();
    if let Err(e) = wait_for_heartbeats(&names, services, Duration::from_secs(30), || {
        for p in procs.iter_mut() {
            p.check_alive()?;
        }
        Ok(())
    }) {
        panic!(
            "{e:#}\nservices log:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
    }
}

pub(crate) fn replay(prefix: &str, log: &Path, extra: &[&str]) -> serde_json::Value {
    let out = bin()
        .arg("replay")
        .arg(log)
        .args(["--prefix", prefix, "--json"])
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "replay failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The /compensated blocks of a recording, in order.
pub(crate) fn compensated(path: &Path) -> Vec<CompensatedBlock> {
    Reader::open(path)
        .unwrap()
        .map(|r| r.unwrap())
        .filter_map(|r| match r.message {
            Message::CompensatedBlock(b) if &*r.topic == "/compensated" => Some(b),
            _ => None,
        })
        .collect()
}

/// The reference: the log in order through the estimator library and the compensator's
/// in-process handler, with the shipped configurations.
fn in_process(log: &Path) -> Vec<CompensatedBlock> {
    let est_config =
        vibro_estimator::Config::load(&repo_path("config/services/estimator.toml")).unwrap();
    let comp_config =
        vibro_compensator::Config::load(&repo_path("config/services/compensator.toml")).unwrap();
    let mut estimator = Estimator::new(est_config.estimator.clone());
    let mut compensator = vibro_compensator::InProcess::new(&comp_config).unwrap();
    let mut out = Vec::new();
    let mut estimate_seq = 0u64;
    let mut pending: Vec<VibEstimate> = Vec::new();
    for r in Reader::open(log).unwrap() {
        let r = r.unwrap();
        match (&*r.topic, &r.message) {
            ("/vib", Message::VibBlock(b)) => {
                let input = SampleBlock {
                    seq: b.seq,
                    t0_ns: b.t0_ns,
                    samples_raw: b.samples_v(),
                };
                estimator
                    .push_block(&input, |e| {
                        let mut m = VibEstimate::ZEROED;
                        vibro_estimator::mirror_estimate(e, &mut m);
                        m.seq = estimate_seq;
                        m.source_seq = b.seq;
                        estimate_seq += 1;
                        pending.push(m);
                    })
                    .unwrap();
                for e in pending.drain(..) {
                    compensator.on_estimate(&e);
                }
                // The waveform stage's samples (the shipped stage).
                compensator.on_vib(b, 0, &mut out);
            }
            ("/accel", Message::AccelBlock(b)) => compensator.on_accel(b, 0, &mut out),
            _ => {}
        }
    }
    compensator.finish(&mut out);
    out
}

fn bits(rows: &[[f64; 3]], n: u32) -> Vec<u64> {
    rows[..n as usize]
        .iter()
        .flatten()
        .map(|v| v.to_bits())
        .collect()
}

/// Compares everything a compensated block carries but the timestamps of its trip
/// (publish/receive times) and the counters that continue across replays, which are
/// compared relative to the run's first.
pub(crate) fn assert_same(
    run: &[CompensatedBlock],
    reference: &[CompensatedBlock],
    what: &str,
    restarted: bool,
) {
    assert_eq!(run.len(), reference.len(), "{what}: block count");
    let base = |v: &[CompensatedBlock]| {
        (
            v[0].seq,
            v.iter()
                .filter(|b| b.flags & vibro_msgs::compensation_flags::ESTIMATE_MISSING == 0)
                .map(|b| b.estimate_seq)
                .min()
                .unwrap_or(0),
        )
    };
    let ((s0, e0), (r0, f0)) = (base(run), base(reference));
    let mut estimated = 0;
    for (k, (a, b)) in run.iter().zip(reference).enumerate() {
        let ctx = format!("{what}: block {k} (input seq {})", b.input_seq);
        assert_eq!(a.seq - s0, b.seq - r0, "{ctx}: seq");
        assert_eq!(a.input_seq, b.input_seq, "{ctx}");
        assert_eq!(a.first_sample_index, b.first_sample_index, "{ctx}");
        assert_eq!(a.t0_ns, b.t0_ns, "{ctx}");
        assert_eq!(a.sample_period_ns, b.sample_period_ns, "{ctx}");
        assert_eq!(a.count, b.count, "{ctx}");
        if restarted && k == 0 {
            // The producer started again (seq back to 0): the stream's discontinuity
            // is flagged on the first block, and nothing else differs.
            assert_eq!(a.flags, b.flags | INPUT_GAP, "{ctx}: flags");
        } else {
            assert_eq!(a.flags, b.flags, "{ctx}: flags");
        }
        assert_eq!(a.mode, b.mode, "{ctx}");
        assert_eq!(a.estimate_age_ns, b.estimate_age_ns, "{ctx}: estimate age");
        if b.flags & vibro_msgs::compensation_flags::ESTIMATE_MISSING == 0 {
            estimated += 1;
            assert_eq!(a.estimate_seq - e0, b.estimate_seq - f0, "{ctx}: estimate");
        }
        for (name, x, y) in [
            ("a1", &a.a1_g, &b.a1_g),
            ("a2", &a.a2_g, &b.a2_g),
            ("a3", &a.a3_g, &b.a3_g),
            ("a4", &a.a4_g, &b.a4_g),
            ("main", &a.main_g, &b.main_g),
            ("det", &a.det_g, &b.det_g),
            ("rand", &a.rand_g, &b.rand_g),
        ] {
            assert_eq!(bits(x, a.count), bits(y, b.count), "{ctx}: {name}");
        }
    }
    // The comparison covers compensation with estimates, not only the main error.
    assert!(
        estimated > run.len() / 2,
        "{what}: only {estimated} of {} blocks had an estimate",
        run.len()
    );
}

/// The estimator, the compensator and a recorder into `session` on prefix `p`, up.
fn start_recorded(p: &str, session: &Path, services_log: &Path) -> [Process; 3] {
    let s = spec(p, Some(session.to_path_buf()));
    let mut est = start(&s, Role::Estimator, services_log);
    let mut comp = start(&s, Role::Compensator, services_log);
    let mut rec = start(&s, Role::Recorder, services_log);
    wait_up(
        p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut est, &mut comp, &mut rec],
        services_log,
    );
    [est, comp, rec]
}

pub(crate) fn stop_all(procs: Vec<Process>) -> Vec<serde_json::Value> {
    procs
        .into_iter()
        .map(|p| p.stop(Duration::from_secs(20)).unwrap().summary().unwrap())
        .collect()
}

#[test]
fn lockstepped_replay_through_the_processes_equals_the_library_twice() {
    let dir = Dir::new("bit");
    let log = flight_log(&dir, "4");
    let reference = in_process(&log);
    assert_eq!(reference.len(), 100, "4 s at 800 Hz in 32-sample blocks");

    let p = prefix("b");
    let services_log = dir.path("services.log");
    let first = dir.path("session-1.mcap");
    let second = dir.path("session-2.mcap");
    let s = spec(&p, Some(first.clone()));
    let mut est = start(&s, Role::Estimator, &services_log);
    let mut comp = start(&s, Role::Compensator, &services_log);
    let mut rec = start(&s, Role::Recorder, &services_log);
    wait_up(
        &p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut est, &mut comp, &mut rec],
        &services_log,
    );
    let r1 = replay(&p, &log, &["--as-fast-as-possible"]);
    assert_eq!(r1["lockstepped"], true);
    assert_eq!(r1["undelivered"], 0);
    let rec1 = rec
        .stop(Duration::from_secs(20))
        .unwrap()
        .summary()
        .unwrap();
    assert_eq!(rec1["lost"], 0, "{rec1}");

    // Second replay into the same running services, a new recorder.
    let s2 = spec(&p, Some(second.clone()));
    let mut rec = start(&s2, Role::Recorder, &services_log);
    wait_up(&p, &[ServiceId::Recorder], &mut [&mut rec], &services_log);
    let r2 = replay(&p, &log, &["--as-fast-as-possible"]);
    assert_eq!(r2["messages"], r1["messages"]);
    let summaries = stop_all(vec![rec, comp, est]);

    assert_same(&compensated(&first), &reference, "first replay", false);
    assert_same(&compensated(&second), &reference, "second replay", true);
    // The services saw two producer restarts' worth of data and lost none of it.
    let (comp_s, est_s) = (&summaries[1], &summaries[2]);
    assert_eq!(comp_s["accel"]["received"], 200, "{comp_s}");
    assert_eq!(comp_s["accel"]["lost_messages"], 0, "{comp_s}");
    assert_eq!(comp_s["accel"]["restarts"], 1, "{comp_s}");
    assert_eq!(comp_s["undelivered"], 0, "{comp_s}");
    assert_eq!(est_s["vib"]["lost_messages"], 0, "{est_s}");
    assert_eq!(est_s["vib"]["received"], 400, "{est_s}");
    // The replays waited only where an estimate could come out (docs/messages.md,
    // "progress"): at most twice per estimate, plus the first blocks; a wait at every
    // switch between /vib and /accel would be 200 per replay.
    let estimates = est_s["estimates_published"].as_u64().unwrap();
    assert_eq!(
        estimates, 14,
        "7 windows of 1 s sliding by 0.5 s per replay: {est_s}"
    );
    for r in [&r1, &r2] {
        let waits = r["lockstep_waits"].as_u64().unwrap();
        assert!(waits <= 2 * 7 + 4, "{waits} waits for 7 estimates: {r}");
    }
}

/// Python's reader decodes every message of a recording made from the processes,
/// with the same count per channel as the Rust reader.
fn python_check(path: &Path) -> serde_json::Value {
    let info = vibro_mcap::info(path).unwrap();
    let counts: serde_json::Map<String, serde_json::Value> = info
        .channels
        .iter()
        .map(|c| (c.topic.clone(), c.messages.into()))
        .collect();
    let out = Command::new("python3")
        .arg(repo_path("tests/python/mcap_check.py"))
        .arg(path)
        .arg("--expect-counts")
        .arg(serde_json::Value::Object(counts).to_string())
        .output()
        .expect("python3 runs; run `pip install -r tests/python/requirements.txt`");
    assert!(
        out.status.success(),
        "mcap_check.py failed ({}): {}\n(run `pip install -r tests/python/requirements.txt`)",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn ten_times_real_time_loses_nothing_and_the_recording_reads_in_python() {
    let dir = Dir::new("rate");
    let log = flight_log(&dir, "5");
    let p = prefix("r");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let [est, comp, rec] = start_recorded(&p, &session, &services_log);
    let r = replay(&p, &log, &["--rate", "10"]);
    assert_eq!(r["lockstepped"], false);
    assert_eq!(r["undelivered"], 0, "{r}");
    let span = r["log_span_s"].as_f64().unwrap();
    let elapsed = r["elapsed_s"].as_f64().unwrap();
    // Paced, not as fast as possible: 5 s of log at 10x takes about 0.5 s.
    assert!(elapsed > 0.9 * span / 10.0, "{r}");
    // Give the compensator a moment to take the last block, and its waveform stage the
    // sensors' silence after which it answers the last readings (1 s; the log's samples
    // do not cover them), then stop all.
    std::thread::sleep(Duration::from_millis(1500));
    let summaries = stop_all(vec![rec, comp, est]);
    let (rec_s, comp_s, est_s) = (&summaries[0], &summaries[1], &summaries[2]);
    assert_eq!(rec_s["lost"], 0, "{rec_s}");
    for (s, k) in [(comp_s, "accel"), (est_s, "vib")] {
        assert_eq!(s[k]["lost_messages"], 0, "{s}");
        assert_eq!(s[k]["lost_samples"], 0, "{s}");
        assert_eq!(s["undelivered"], 0, "{s}");
    }
    assert_eq!(comp_s["accel"]["received"], 125, "{comp_s}");
    assert_eq!(est_s["vib"]["received"], 250, "{est_s}");

    // Every channel is continuous by its producer's sequence numbers.
    let info = vibro_mcap::info(&session).unwrap();
    assert_eq!(info.lost, 0, "{info:?}");
    let count = |topic: &str| {
        info.channels
            .iter()
            .find(|c| c.topic == topic)
            .map_or(0, |c| c.messages)
    };
    assert_eq!(count("/accel"), 125);
    assert_eq!(count("/vib"), 250);
    assert_eq!(count("/truth"), 125);
    assert_eq!(count("/compensated"), 125);
    assert!(count("/estimate") >= 8, "{info:?}");
    assert!(count("/heartbeat/compensator") >= 1);
    // The recording carries the configurations and passports it ran with.
    let names: Vec<&str> = info.attachments.iter().map(|a| a.name.as_str()).collect();
    assert!(
        names.iter().any(|n| n.starts_with("compensator.toml")),
        "{names:?}"
    );
    assert!(
        names.iter().any(|n| n.starts_with("passport-0-AL-15")),
        "{names:?}"
    );

    let py = python_check(&session);
    assert!(py.to_string().contains("/compensated"), "{py}");

    // The data's timeline (docs/logs.md, "Time"), read by the Python reader: the
    // recording's data channels span the flight's own time, log time for log time as
    // the simulator wrote them, though they arrived over a tenth of it; heartbeats sit
    // within the data's span.
    let flight = vibro_mcap::info(&log).unwrap();
    let ch = |i: &vibro_mcap::LogInfo, t: &str| {
        i.channels.iter().find(|c| c.topic == t).cloned().unwrap()
    };
    for topic in ["/accel", "/vib", "/truth"] {
        let (f, r) = (ch(&flight, topic), &py["channels"][topic]);
        println!(
            "FIGURES timeline {topic}: flight {:.6} s; recording: log time {} s, receive {} s",
            f.span_s, r["span_s"], r["publish_span_s"]
        );
        assert_eq!(
            r["first_log_time_ns"],
            f.first_log_time_ns.unwrap(),
            "{topic}"
        );
        assert_eq!(
            r["last_log_time_ns"],
            f.last_log_time_ns.unwrap(),
            "{topic}"
        );
        let receive_s = r["publish_span_s"].as_f64().unwrap();
        assert!(
            receive_s < 0.5 * f.span_s,
            "{topic}: received over {receive_s} s"
        );
    }
    let comp = &py["channels"]["/compensated"];
    assert_eq!(
        comp["last_log_time_ns"],
        ch(&flight, "/accel").last_log_time_ns.unwrap()
    );
    // Within the data the recording holds (an estimate's window may end a sample
    // after the flight's last block).
    let data: Vec<&serde_json::Value> = py["channels"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(t, _)| !t.starts_with("/heartbeat"))
        .map(|(_, c)| c)
        .collect();
    let bound = |k: &str| -> Vec<u64> { data.iter().map(|c| c[k].as_u64().unwrap()).collect() };
    let (lo, hi) = (
        bound("first_log_time_ns").into_iter().min().unwrap(),
        bound("last_log_time_ns").into_iter().max().unwrap(),
    );
    let hb = &py["channels"]["/heartbeat/compensator"];
    for k in ["first_log_time_ns", "last_log_time_ns"] {
        let t = hb[k].as_u64().unwrap();
        assert!((lo..=hi).contains(&t), "{k} {t} outside {lo}..{hi}: {hb}");
    }
    let info = vibro_mcap::info(&session).unwrap();
    assert!(
        (info.duration_s - flight.duration_s).abs() < 0.1,
        "{info:?}"
    );
    assert!(info.publish_span_s < 0.5 * flight.duration_s, "{info:?}");
}

/// `vibrocomp demo` as a user runs it: the flight through the processes, recorded, and
/// an error reduction of at least 10x against the simulator's truth, nothing lost.
#[test]
fn the_demo_cuts_the_error_tenfold_and_loses_nothing() {
    let dir = Dir::new("demo");
    let out = bin()
        .args(["demo", "--json", "--out-dir"])
        .arg(dir.path("demo"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "demo failed: {}\nservices log: {}",
        String::from_utf8_lossy(&out.stderr),
        std::fs::read_to_string(dir.path("demo/services.log")).unwrap_or_default()
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let e = &v["errors"];
    let all = &e["all_units"];
    let f = |x: &serde_json::Value| x.as_f64().unwrap();
    assert!(f(&all["reduction"]) >= 10.0, "{v}");
    // The vibration-error stage itself helps, on every unit (not only the bias).
    for u in e["units"].as_array().unwrap() {
        assert!(
            f(&u["vibration_removed_rms_g"]) < 0.5 * f(&u["main_removed_rms_g"]),
            "{u}"
        );
    }
    assert_eq!(v["lost_messages"], 0, "{v}");
    assert_eq!(
        v["replay"]["messages"], 2000,
        "20 s: 1000 vib + 500 accel + 500 truth"
    );
    assert!(
        f(&e["compensated_windows"]) >= 0.9 * f(&e["windows"]),
        "{v}"
    );
    // The shipped compensator runs the waveform stage: every block of the flight is
    // recorded (the last, held until the samples stop, too), nearly all of them the
    // waveform stage's, and the estimate stage's answer is reported beside it.
    assert_eq!(e["blocks"], 500, "{v}");
    assert!(f(&e["waveform_blocks"]) >= 490.0, "{v}");
    for u in e["units"].as_array().unwrap() {
        assert!(
            f(&u["estimate_stage_rms_g"]) < 0.5 * f(&u["main_removed_rms_g"]),
            "{u}"
        );
    }
    // `log errors` on the demo's recording: the same figures, bit for bit (one
    // computation, docs/logs.md "log errors").
    let session = dir.path("demo/session.mcap");
    let measured = crate::common::run_json(&["log", "errors", "--json", session.to_str().unwrap()]);
    assert_eq!(measured["errors"], *e, "{measured}");
    // Everything recorded reads back in Python.
    python_check(&session);
    // The services' log is a file: plain text, no terminal colour codes.
    let services_log = std::fs::read(dir.path("demo/services.log")).unwrap();
    assert!(!services_log.is_empty());
    assert!(
        !services_log.contains(&0x1b),
        "ANSI escapes in services.log: {}",
        String::from_utf8_lossy(&services_log[..services_log.len().min(400)])
    );
}

/// `vibrocomp up`: a killed compensator is started again, and Ctrl-C stops everything
/// cleanly (exit 0, a summary of starts and crashes).
#[test]
fn up_restarts_a_killed_service_and_stops_on_sigint() {
    let p = prefix("u");
    let up = bin()
        .args(["up", "--json", "--prefix", &p])
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let names = ServiceNames::new(&p).unwrap();
    let both = [ServiceId::Estimator, ServiceId::Compensator];
    wait_for_heartbeats(&names, &both, Duration::from_secs(30), || Ok(())).unwrap();
    let kids = children(up.id());
    assert_eq!(kids.len(), 2, "{kids:?}");
    let (victim, _) = kids
        .iter()
        .find(|(_, cmd)| cmd.contains("service compensator"))
        .unwrap_or_else(|| panic!("no compensator among {kids:?}"))
        .clone();
    // SAFETY: signalling a process this test started (through `up`).
    unsafe { libc::kill(victim as libc::pid_t, libc::SIGKILL) };
    // A new compensator comes up (a new pid) and publishes heartbeats again.
    let mut replaced = false;
    for _ in 0..200 {
        std::thread::sleep(Duration::from_millis(50));
        let now = children(up.id());
        if now
            .iter()
            .any(|(pid, cmd)| *pid != victim && cmd.contains("service compensator"))
        {
            replaced = true;
            break;
        }
    }
    assert!(replaced, "the compensator was not restarted");
    wait_for_heartbeats(
        &names,
        &[ServiceId::Compensator],
        Duration::from_secs(30),
        || Ok(()),
    )
    .unwrap();
    unsafe { libc::kill(up.id() as libc::pid_t, libc::SIGINT) };
    let out = up.wait_with_output().unwrap();
    assert!(out.status.success(), "up exited with {}", out.status);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let procs = v["processes"].as_array().unwrap();
    let comp = procs.iter().find(|r| r["role"] == "compensator").unwrap();
    assert_eq!(comp["starts"], 2, "{v}");
    assert_eq!(comp["crashes"], 1, "{v}");
    let est = procs.iter().find(|r| r["role"] == "estimator").unwrap();
    assert_eq!(est["starts"], 1, "{v}");
    assert_eq!(est["crashes"], 0, "{v}");
    // Stopped by their signal handlers: exit status 0.
    assert_eq!(est["last_exit"], "exit status: 0", "{v}");
}

/// `replay --loop`: each pass continues the sequence numbers, sample indices and data
/// times of the one before, so the services see one continuous stream (no restart, no
/// gap) until Ctrl-C.
#[test]
fn a_looped_replay_is_one_continuous_stream() {
    let dir = Dir::new("loop");
    let log = flight_log(&dir, "2");
    let p = prefix("l");
    let services_log = dir.path("services.log");
    let s = spec(&p, None);
    let mut est = start(&s, Role::Estimator, &services_log);
    let mut comp = start(&s, Role::Compensator, &services_log);
    wait_up(
        &p,
        &[ServiceId::Estimator, ServiceId::Compensator],
        &mut [&mut est, &mut comp],
        &services_log,
    );
    let replay = bin()
        .arg("replay")
        .arg(&log)
        .args(["--prefix", &p, "--json", "--loop", "--rate", "4"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Three passes of 2 s at 4x take 1.5 s; stop during the fourth or later.
    std::thread::sleep(Duration::from_millis(1800));
    // SAFETY: signalling a child this test started.
    unsafe { libc::kill(replay.id() as libc::pid_t, libc::SIGINT) };
    let out = replay.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(r["passes"].as_u64().unwrap() >= 3, "{r}");
    std::thread::sleep(Duration::from_millis(300));
    let summaries = stop_all(vec![comp, est]);
    let (comp_s, est_s) = (&summaries[0], &summaries[1]);
    let accel_sent = r["topics"]["/accel"].as_u64().unwrap();
    assert!(accel_sent > 150, "{r}");
    assert_eq!(comp_s["accel"]["received"], accel_sent, "{comp_s}");
    for (s, k) in [(comp_s, "accel"), (est_s, "vib")] {
        for c in [
            "lost_messages",
            "lost_samples",
            "restarts",
            "index_backwards",
            "out_of_order",
        ] {
            assert_eq!(s[k][c], 0, "{k}.{c}: {s}");
        }
    }
    // Continuous data times: the estimator never saw a gap or a step back.
    assert_eq!(est_s["dsp"]["sequence_gaps"], 0, "{est_s}");
    assert_eq!(est_s["dsp"]["blocks_dropped"], 0, "{est_s}");
    assert_eq!(est_s["dsp"]["restarts"], 0, "{est_s}");
    assert_eq!(comp_s["input_gap_blocks"], 0, "{comp_s}");
}

/// `vibrocomp view` on system `p`, listening on a free port of 127.0.0.1: the process
/// and its address, once it accepts connections.
fn start_view(p: &str) -> (Kid, String) {
    let listen = format!("127.0.0.1:{}", free_port());
    let mut view_cmd = bin();
    view_cmd.args(["view", "--prefix", p, "--listen", &listen, "--json"]);
    let view = Kid::spawn(view_cmd, "view");
    assert!(
        poll(Duration::from_secs(20), || std::net::TcpStream::connect(
            &listen
        )
        .is_ok()),
        "the view does not listen on {listen}: {}",
        view.stderr()
    );
    (view, listen)
}

/// Issue 46, item 8 (and item 3's pings): `vibrocomp view` serves a client offering
/// `foxglove.websocket.v1` alone (Lichtblick before lichtblick-suite/lichtblick#819,
/// Foxglove Studio 1.x: today's view answered 400), naming that subprotocol back and
/// advertising every view channel, and one offering Lichtblick's two names gets
/// `foxglove.sdk.v1`. The client (`tests/python/foxglove_client.py`, the `websockets`
/// package) stays 12 s, past the view's 10 s pong timeout: it answers the pings, as a
/// browser does, and none is counted unanswered.
#[test]
fn a_client_offering_foxglove_websocket_v1_is_served_and_answers_the_pings() {
    let p = prefix("vw1");
    let (mut view, listen) = start_view(&p);
    for (offers, chosen, stay_s) in [
        (
            &["foxglove.websocket.v1"][..],
            "foxglove.websocket.v1",
            "12",
        ),
        (
            &["foxglove.websocket.v1", "foxglove.sdk.v1"][..],
            "foxglove.sdk.v1",
            "1",
        ),
    ] {
        let mut cmd = Command::new("python3");
        cmd.arg(repo_path("tests/python/foxglove_client.py"))
            .arg(format!("ws://{listen}"))
            .args(["--max-s", stay_s]);
        for o in offers {
            cmd.args(["--subprotocol", o]);
        }
        let mut client = Kid::spawn(cmd, "Foxglove client");
        let (status, out, err) = client.wait(Duration::from_secs(60));
        assert!(status.success(), "client offering {offers:?}: {err}");
        let py: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(py["protocol"], chosen, "{py}");
        let topics: Vec<&str> = py["channels"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|c| c["topic"].as_str())
            .collect();
        for (topic, _) in vibro_view::topics(vibro_view::UNIT_NAMES) {
            assert!(topics.contains(&topic.as_str()), "{topic}: {py}");
        }
    }
    let (status, view_out, view_err) = view.stop(libc::SIGTERM, Duration::from_secs(20));
    assert!(status.success(), "view: {view_err}");
    let v: serde_json::Value = serde_json::from_str(&view_out).unwrap();
    let c = &v["clients"];
    let count = |k: &str| c[k].as_u64();
    assert_eq!(
        (
            count("served"),
            count("websocket_v1_requests"),
            count("unanswered_pings")
        ),
        (Some(2), Some(1), Some(0)),
        "{v}"
    );
}

/// A Foxglove client (`tests/python/foxglove_client.py`) subscribed to the view on
/// `listen` while `log` is replayed at 5x into the system `p`: what it decoded, once
/// the unit channels have been quiet for 2 s.
fn watch_replay(dir: &Dir, listen: &str, p: &str, log: &Path) -> serde_json::Value {
    let ready = dir.path("ready");
    let mut client_cmd = Command::new("python3");
    client_cmd
        .arg(repo_path("tests/python/foxglove_client.py"))
        .arg(format!("ws://{listen}"))
        .arg("--ready")
        .arg(&ready)
        .args([
            "--prefix",
            "/",
            "--quiet-s",
            "2",
            "--quiet-prefix",
            "/view/AK",
            "--max-s",
            "60",
        ]);
    let mut client = Kid::spawn(client_cmd, "Foxglove client");
    assert!(
        poll(Duration::from_secs(20), || ready.exists()),
        "the client did not subscribe: {}",
        client.stderr()
    );
    let r = replay(p, log, &["--rate", "5"]);
    assert_eq!(r["undelivered"], 0, "{r}");
    let (status, out, err) = client.wait(Duration::from_secs(90));
    assert!(status.success(), "client: {err}");
    serde_json::from_str(&out).unwrap()
}

/// The mean, minimum and maximum of unit `u`'s column of `rows[..n]`.
fn mean_min_max(rows: &[[f64; 3]], n: u32, u: usize) -> [f64; 3] {
    let col: Vec<f64> = rows[..n as usize].iter().map(|r| r[u]).collect();
    [
        col.iter().sum::<f64>() / col.len() as f64,
        col.iter().copied().fold(f64::INFINITY, f64::min),
        col.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    ]
}

/// The live view (docs/view.md) seen by a real client of Foxglove's WebSocket protocol
/// (`tests/python/foxglove_client.py`: the `websockets` package, subprotocol
/// `foxglove.sdk.v1`, decoding with the schemas the server advertises) during a paced
/// replay: every view channel advertised with its schema, one `/view/{unit}` message per
/// compensated block, each stage's mean, minimum and maximum and its error against the
/// reference equal to what the recording of the same run holds (computed here from the
/// recorded `/compensated` and `/truth` blocks), placed on the data's time, and the
/// services' health with named states.
#[test]
fn a_foxglove_client_sees_the_live_view_as_the_recording_holds_it() {
    let dir = Dir::new("view");
    let log = flight_log(&dir, "3");
    let p = prefix("v");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let [est, comp, rec] = start_recorded(&p, &session, &services_log);
    let (mut view, listen) = start_view(&p);
    let py = watch_replay(&dir, &listen, &p, &log);
    std::thread::sleep(Duration::from_millis(300));
    let (status, view_out, view_err) = view.stop(libc::SIGTERM, Duration::from_secs(20));
    assert!(status.success(), "view: {view_err}");
    let summaries = stop_all(vec![rec, comp, est]);
    assert_eq!(summaries[0]["lost"], 0, "{}", summaries[0]);

    assert_eq!(py["protocol"], "foxglove.sdk.v1");
    let advertised: Vec<(String, String)> = py["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            assert_eq!(c["encoding"], "protobuf");
            (
                c["topic"].as_str().unwrap().to_string(),
                c["schemaName"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    for (topic, schema) in vibro_view::topics(vibro_view::UNIT_NAMES) {
        assert!(
            advertised.contains(&(topic.clone(), schema.name.to_string())),
            "{topic} not advertised: {advertised:?}"
        );
    }
    let messages = py["messages"].as_array().unwrap();
    let recorded = compensated(&session);
    let truth: std::collections::BTreeMap<u64, vibro_msgs::TruthBlock> = Reader::open(&session)
        .unwrap()
        .map(|r| r.unwrap())
        .filter_map(|r| match r.message {
            Message::TruthBlock(t) => Some((t.first_sample_index, t)),
            _ => None,
        })
        .collect();
    let near = |a: f64, b: f64| a == b || (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
    let mut compared = 0;
    for (u, unit) in vibro_view::UNIT_NAMES.iter().enumerate() {
        let topic = format!("/view/{unit}");
        let live: Vec<&serde_json::Value> = messages
            .iter()
            .filter(|m| m["topic"] == topic.as_str())
            .collect();
        assert_eq!(live.len(), recorded.len(), "{topic}: one message per block");
        for (m, b) in live.iter().zip(&recorded) {
            let f = &m["fields"];
            let last_ns = b.t0_ns + u64::from(b.count - 1) * b.sample_period_ns;
            assert_eq!(m["log_time_ns"], last_ns, "{topic} on the data's time");
            assert_eq!(
                f["first_sample_index"].as_str(),
                Some(b.first_sample_index.to_string().as_str())
            );
            let t = truth
                .get(&b.first_sample_index)
                .expect("the block's reference");
            let errors: Vec<[f64; 3]> = (0..b.count as usize)
                .map(|k| std::array::from_fn(|i| b.a4_g[k][i] - t.a_sensed_ia_g[k][i]))
                .collect();
            for (field, rows) in [
                ("uncompensated_g", &b.a1_g[..]),
                ("main_removed_g", &b.a2_g[..]),
                ("compensated_g", &b.a4_g[..]),
                ("reference_g", &t.a_sensed_ia_g[..]),
                ("compensated_error_g", &errors[..]),
            ] {
                let want = mean_min_max(rows, b.count, u);
                let num = |k: &str| {
                    f[field][k]
                        .as_f64()
                        .unwrap_or_else(|| panic!("{topic} {field}.{k} in {f}"))
                };
                let got = [num("mean"), num("min"), num("max")];
                for k in 0..3 {
                    assert!(
                        near(got[k], want[k]),
                        "{topic} {field}: {got:?} vs {want:?}"
                    );
                }
            }
            compared += 1;
        }
    }
    let states: std::collections::BTreeSet<&str> = messages
        .iter()
        .filter(|m| m["topic"] == "/view/health/compensator")
        .filter_map(|m| m["fields"]["state"].as_str())
        .collect();
    // Named by the schema's enum (the wire's codes 1..4).
    assert!(!states.is_empty());
    for st in &states {
        assert!(
            ["STARTING", "RUNNING", "DEGRADED", "STOPPING"].contains(st),
            "{states:?}"
        );
    }
    let axes = messages
        .iter()
        .filter(|m| m["topic"] == "/view/vibration/z")
        .count();
    assert!(axes >= 2, "{axes} vibration messages");
    // The services' log lines as `foxglove.Log` (the view attached after they started:
    // their start-up lines came as the log streams' history), each the line the
    // service wrote to stderr (`tracing_subscriber::fmt`, in services.log) after its
    // time and level.
    let stderr = std::fs::read_to_string(&services_log).unwrap();
    let logs: Vec<&serde_json::Value> = messages.iter().filter(|m| m["topic"] == "/log").collect();
    for service in ["estimator", "compensator"] {
        let theirs: Vec<&&serde_json::Value> = logs
            .iter()
            .filter(|m| m["fields"]["name"] == service)
            .collect();
        assert!(!theirs.is_empty(), "no log line of the {service}: {logs:?}");
        for m in theirs {
            let f = &m["fields"];
            let text = f["message"].as_str().unwrap();
            let level = match f["level"].as_str().unwrap() {
                "WARNING" => "WARN",
                "DEBUG" => "DEBUG",
                other => other,
            };
            assert!(
                stderr
                    .lines()
                    .any(|l| l.ends_with(&format!("{level} {text}"))),
                "{service}: {level} {text:?} is not a line of services.log:\n{stderr}"
            );
        }
    }
    // The recorder wrote the same view channels into the session's MCAP (docs/view.md):
    // read by the PyPI `mcap` reader, decoded with the schemas the file embeds, each
    // unit message equal to the live one (time, stages' mean, minimum and maximum).
    let out = Command::new("python3")
        .arg(repo_path("tests/python/mcap_check.py"))
        .arg(&session)
        .arg("--all-messages")
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "mcap_check.py: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rec: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let mut recorded_view = 0;
    for (topic, schema) in vibro_view::topics(vibro_view::UNIT_NAMES) {
        let Some(c) = rec["channels"].get(&topic) else {
            // A channel with no message (a service that is not running) has no
            // decoded message to list.
            assert!(topic.starts_with("/view/health/"), "{topic} not recorded");
            continue;
        };
        assert_eq!(c["schema"], schema.name, "{topic}");
        assert_eq!(c["sequence_gaps"], 0, "{topic}");
        if !topic.starts_with("/view/AK") {
            continue;
        }
        let live: Vec<&serde_json::Value> = messages
            .iter()
            .filter(|m| m["topic"] == topic.as_str())
            .collect();
        let file = c["messages"].as_array().unwrap();
        assert_eq!(file.len(), live.len(), "{topic}: recorded vs live");
        for (r, l) in file.iter().zip(&live) {
            assert_eq!(r["log_time_ns"], l["log_time_ns"], "{topic}");
            for field in [
                "uncompensated_g",
                "main_removed_g",
                "compensated_g",
                "reference_g",
                "compensated_error_g",
            ] {
                for k in ["mean", "min", "max"] {
                    let (a, b) = (&r["fields"][field][k], &l["fields"][field][k]);
                    assert!(
                        a.as_f64().is_some() && a.as_f64() == b.as_f64(),
                        "{topic} {field}.{k}: recorded {a} vs live {b}"
                    );
                }
            }
            recorded_view += 1;
        }
    }
    assert_eq!(recorded_view, compared);
    println!(
        "FIGURES view: {compared} unit messages compared with the recording, {} messages in \
         all; view summary {view_out}",
        messages.len()
    );
}

/// `up --foxglove ADDR` starts the live view with the services: a Foxglove client is
/// served the view channels while a flight is replayed, and Ctrl-C stops the view with
/// the rest (exit 0, no process left).
#[test]
fn up_with_foxglove_serves_the_live_view_and_stops_it_on_sigint() {
    let dir = Dir::new("up-view");
    let log = flight_log(&dir, "2");
    let p = prefix("uv");
    let listen = format!("127.0.0.1:{}", free_port());
    let mut up_cmd = bin();
    up_cmd
        .args(["up", "--json", "--prefix", &p, "--foxglove", &listen])
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"));
    let mut up = Kid::spawn(up_cmd, "up");
    let names = ServiceNames::new(&p).unwrap();
    let both = [ServiceId::Estimator, ServiceId::Compensator];
    wait_for_heartbeats(&names, &both, Duration::from_secs(30), || up.check_alive()).unwrap();
    assert!(
        poll(Duration::from_secs(20), || std::net::TcpStream::connect(
            &listen
        )
        .is_ok()),
        "no view on {listen}: {}",
        up.stderr()
    );
    let kids = children(up.pid());
    assert!(
        kids.iter()
            .any(|(_, c)| c.contains("view") && c.contains(&listen)),
        "{kids:?}"
    );
    let py = watch_replay(&dir, &listen, &p, &log);
    let units = py["messages"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["topic"] == "/view/AK2")
        .count();
    // 2 s at 800 Hz in blocks of 32: 50 blocks.
    assert_eq!(units, 50, "{}", py["messages"].as_array().unwrap().len());
    let pid = up.pid();
    let (status, out, err) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {err}");
    let v: serde_json::Value =
        serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out:?}\n{err}"));
    let view = v["processes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["role"] == "view")
        .unwrap_or_else(|| panic!("{v}"));
    assert_eq!(view["last_exit"], "exit status: 0", "{v}");
    assert!(children(pid).is_empty());
}

/// A viewer that stops reading (a stalled Foxglove client: one-frame receive queue,
/// 4 KiB socket buffer) while a 300 s flight is replayed at 100x never holds up the
/// system: the replay delivers every message, the recorder loses none, the compensator
/// sees no input gap; the view stops on SIGTERM with its summary. What the client got
/// against what the view served is the Foxglove SDK's drop-oldest toward it.
#[test]
fn a_stalled_foxglove_client_never_holds_up_the_system() {
    let dir = Dir::new("view-stall");
    let log = flight_log(&dir, "300");
    let p = prefix("vs");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let [est, comp, rec] = start_recorded(&p, &session, &services_log);
    let (mut view, listen) = start_view(&p);
    let ready = dir.path("ready");
    let mut client_cmd = Command::new("python3");
    client_cmd
        .arg(repo_path("tests/python/foxglove_client.py"))
        .arg(format!("ws://{listen}"))
        .arg("--ready")
        .arg(&ready)
        .args([
            "--stall-s",
            "5",
            "--quiet-s",
            "1",
            "--max-s",
            "90",
            "--count-only",
        ])
        .args(["--quiet-prefix", "/view/AK"]);
    let mut client = Kid::spawn(client_cmd, "stalled Foxglove client");
    assert!(
        poll(Duration::from_secs(20), || ready.exists()),
        "the client did not subscribe: {}",
        client.stderr()
    );
    let t0 = std::time::Instant::now();
    let r = replay(&p, &log, &["--rate", "100"]);
    let replay_s = t0.elapsed().as_secs_f64();
    assert_eq!(r["undelivered"], 0, "{r}");
    let (status, out, err) = client.wait(Duration::from_secs(120));
    assert!(status.success(), "client: {err}");
    let py: serde_json::Value = serde_json::from_str(&out).unwrap();
    let (status, view_out, view_err) = view.stop(libc::SIGTERM, Duration::from_secs(20));
    assert!(status.success(), "view: {view_err}");
    let summaries = stop_all(vec![rec, comp, est]);
    assert_eq!(summaries[0]["lost"], 0, "recorder: {}", summaries[0]);
    assert_eq!(
        summaries[1]["input_gap_blocks"], 0,
        "compensator: {}",
        summaries[1]
    );
    let v: serde_json::Value = serde_json::from_str(&view_out).unwrap();
    let served: u64 = v["published"]
        .as_object()
        .unwrap()
        .values()
        .map(|x| x.as_u64().unwrap())
        .sum();
    let blocks = compensated(&session).len() as u64;
    assert_eq!(v["published"]["/view/AK1"], blocks, "{v}");
    let got: u64 = py["counts"]
        .as_object()
        .unwrap()
        .values()
        .map(|x| x.as_u64().unwrap())
        .sum();
    assert!(got <= served, "{got} > {served}");
    println!(
        "FIGURES view stalled client: replay {replay_s:.1} s, {blocks} blocks, served \
         {served}, the stalled client got {got} (the SDK dropped {} toward it), the view's \
         own drops {}, status messages {}",
        served - got,
        v["dropped"],
        py["status"]
    );
}
