//! `vibrocomp log compensate LOG --out SESSION.mcap` (`vibro_offline`): the estimator's
//! and the compensator's cores in-process give, bit for bit, the `/compensated` stream
//! (and the `/estimate` stream) that the real service processes record in a
//! lock-stepped replay of the same log, and `log errors` gives the same figures on
//! both sessions: on the demo's simulated flight, and on an imported rig log with the
//! rig's sensor chain (`--rig`, as `up --rig` gives it to the services). Bad input (a
//! missing log, a truncated one, an output that is a link) is refused naming the file,
//! nothing written through the link. A session with the log's chunks copied as they
//! are holds, for the Python MCAP reader, the records of one written record by record.

use crate::common::{bin, repo_path, TempDir};
use crate::processes::{flight_log, prefix, Dir};
use crate::replay::{assert_same, compensated, replay, stop_all, wait_up};
use std::path::{Path, PathBuf};
use vibro_mcap::{Message, Reader};
use vibro_msgs::{ServiceId, VibEstimate};
use vibro_system::{Role, SystemSpec};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The services with `estimator` and `compensator` as their configurations (the files
/// `up` would give them), a recorder into `session`; `log` replayed lock-stepped
/// through them, then all stopped. Returns the services' summaries (recorder,
/// compensator, estimator).
fn services_session(
    tag: &str,
    estimator: &Path,
    compensator: &Path,
    log: &Path,
    session: &Path,
    services_log: &Path,
) -> Vec<serde_json::Value> {
    let p = prefix(tag);
    let spec = SystemSpec {
        prefix: p.clone(),
        estimator_config: Some(estimator.to_path_buf()),
        compensator_config: Some(compensator.to_path_buf()),
        record: Some(session.to_path_buf()),
        json: true,
        exe: Some(PathBuf::from(env!("CARGO_BIN_EXE_vibrocomp"))),
        ..SystemSpec::default()
    };
    let mut est = spec.spawn(Role::Estimator, Some(services_log)).unwrap();
    let mut comp = spec.spawn(Role::Compensator, Some(services_log)).unwrap();
    let mut rec = spec.spawn(Role::Recorder, Some(services_log)).unwrap();
    wait_up(
        &p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut est, &mut comp, &mut rec],
        services_log,
    );
    let r = replay(&p, log, &["--as-fast-as-possible"]);
    assert_eq!(r["lockstepped"], true, "{r}");
    assert_eq!(r["undelivered"], 0, "{r}");
    // A lock-stepped replay ends once the compensator has released the blocks its
    // waveform stage held (after the sensors' silence): the recorder has them all.
    let summaries = stop_all(vec![rec, comp, est]);
    assert_eq!(summaries[0]["lost"], 0, "recorder: {}", summaries[0]);
    summaries
}

/// `log compensate` with `args`; its JSON summary.
fn compensate(log: &Path, out: &Path, args: &[&str]) -> serde_json::Value {
    let o = bin()
        .args(["log", "compensate", s(log), "--out", s(out), "--json"])
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "log compensate: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// `log errors --json` on a session, without the session's own path.
fn errors(session: &Path) -> serde_json::Value {
    let o = bin()
        .args(["log", "errors", s(session), "--json"])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "log errors {}: {}",
        session.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    let mut v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    v.as_object_mut().unwrap().remove("log");
    v
}

/// Per topic of `file`, as the Python reference reader (CRCs checked) gives them: the
/// message count and a SHA-256 over each message's sequence, times and bytes, in its
/// order.
fn python_topic_digests(file: &Path) -> serde_json::Value {
    let script = r#"
import hashlib, json, sys
from mcap.reader import make_reader
out = {}
with open(sys.argv[1], "rb") as f:
    for _, channel, m in make_reader(f, validate_crcs=True).iter_messages():
        d = out.setdefault(channel.topic, [0, hashlib.sha256()])
        d[0] += 1
        d[1].update(b"%d %d %d " % (m.sequence, m.log_time, m.publish_time))
        d[1].update(m.data)
print(json.dumps({t: [n, h.hexdigest()] for t, (n, h) in out.items()}))
"#;
    crate::common::python_mcap_json(script, file)
}

/// The /estimate messages of a session, in order.
fn estimates(path: &Path) -> Vec<VibEstimate> {
    Reader::open(path)
        .unwrap()
        .map(|r| r.unwrap())
        .filter_map(|r| match r.message {
            Message::VibEstimate(e) if &*r.topic == "/estimate" => Some(e),
            _ => None,
        })
        .collect()
}

/// Every estimate the same, bit for bit, but its publish time.
fn assert_same_estimates(offline: &[VibEstimate], services: &[VibEstimate], what: &str) {
    assert_eq!(offline.len(), services.len(), "{what}: estimates");
    assert!(!offline.is_empty(), "{what}: no estimate");
    for (k, (a, b)) in offline.iter().zip(services).enumerate() {
        let (mut a, mut b) = (*a, *b);
        a.publish_ns = 0;
        b.publish_ns = 0;
        assert_eq!(
            format!("{a:?}"),
            format!("{b:?}"),
            "{what}: estimate {k} differs"
        );
    }
}

/// Both sessions' streams and figures compared; the offline summary's counts against
/// the services' own.
fn compare(
    what: &str,
    offline: &Path,
    services: &Path,
    summary: &serde_json::Value,
    service_summaries: &[serde_json::Value],
) {
    let (ours, theirs) = (compensated(offline), compensated(services));
    assert_same(&ours, &theirs, what, false);
    assert_same_estimates(&estimates(offline), &estimates(services), what);
    let (comp_s, est_s) = (&service_summaries[1], &service_summaries[2]);
    assert_eq!(
        summary["estimates"], est_s["estimates_published"],
        "{what}: {summary}\n{est_s}"
    );
    assert_eq!(
        summary["compensated_blocks"], comp_s["published"],
        "{what}: {summary}\n{comp_s}"
    );
    assert_eq!(
        summary["waveform_blocks"], comp_s["waveform_blocks"],
        "{what}: {summary}\n{comp_s}"
    );
    let (e_off, e_srv) = (errors(offline), errors(services));
    assert_eq!(e_off, e_srv, "{what}: log errors differ");
    println!(
        "FIGURES log compensate {what}: {} blocks, {} estimates, {:.0}x real time; errors {e_off}",
        ours.len(),
        summary["estimates"],
        summary["real_time_factor"].as_f64().unwrap_or(0.0)
    );
}

#[test]
fn offline_compensation_of_the_demo_flight_equals_the_services() {
    let dir = Dir::new("offline");
    let log = flight_log(&dir, "6");
    let (est, comp) = (
        repo_path("config/services/estimator.toml"),
        repo_path("config/services/compensator.toml"),
    );
    let session = dir.path("services.mcap");
    let summaries = services_session("lc", &est, &comp, &log, &session, &dir.path("services.log"));
    let offline = dir.path("offline.mcap");
    let config = [
        "--estimator-config",
        s(&est),
        "--compensator-config",
        s(&comp),
    ];
    let summary = compensate(&log, &offline, &config);
    assert_eq!(
        summary["compensated_blocks"], 150,
        "6 s at 800 Hz in blocks of 32"
    );
    compare("demo flight", &offline, &session, &summary, &summaries);
    // The session carries what `record` attaches, and the view channels.
    let info = vibro_mcap::info(&offline).unwrap();
    let names: Vec<&str> = info.attachments.iter().map(|a| a.name.as_str()).collect();
    for want in ["estimator.toml", "compensator.toml", "passport-0-"] {
        assert!(names.iter().any(|n| n.starts_with(want)), "{names:?}");
    }
    assert_eq!(info.lost, 0, "{info:?}");
    let view = info.channels.iter().find(|c| c.topic == "/view/AK1");
    assert_eq!(view.map(|c| c.messages), Some(150), "{info:?}");
    // No wall clock: the same log gives the same file, byte for byte.
    let again = dir.path("again.mcap");
    compensate(&log, &again, &config);
    assert!(
        std::fs::read(&offline).unwrap() == std::fs::read(&again).unwrap(),
        "two offline runs differ"
    );
    // The simulator's log is written as a session writes its records: its chunks are
    // copied as they are. For the Python reader, every topic holds what a session
    // written record by record holds.
    let copied = summary["copied_chunks"].as_u64().unwrap_or(0);
    assert!(copied >= 4, "{summary}");
    let plain = dir.path("plain.mcap");
    let plain_summary = compensate(&log, &plain, &[&config[..], &["--no-chunk-copy"]].concat());
    assert_eq!(plain_summary["copied_chunks"], 0, "{plain_summary}");
    let (ours, theirs) = (python_topic_digests(&offline), python_topic_digests(&plain));
    assert_eq!(ours, theirs);
    for (topic, n) in summary["messages_out"].as_object().unwrap() {
        assert_eq!(&ours[topic][0], n, "{topic}: {ours}");
    }
}

#[test]
fn offline_compensation_of_an_imported_rig_log_equals_the_services_with_the_rig() {
    let dir = TempDir::new("offline", "rig");
    let log = crate::rig_log::rig_log_with(&dir.0, "rig", 5101, "+z", "90", true, &[]);
    // The rig file the import used, with the sensors' rate stated, as a user starting
    // `up --rig` on a 6.4 kHz rig gives it (the estimator then runs at that rate).
    let imported = std::fs::read_to_string(dir.0.join("rig/rig.toml")).unwrap();
    let rig = dir.0.join("rig-up.toml");
    std::fs::write(
        &rig,
        imported.replacen("[sensors]\n", "[sensors]\nrate_hz = 6400.0\n", 1),
    )
    .unwrap();
    let (est, comp) = (
        repo_path("config/services/estimator.toml"),
        repo_path("config/services/compensator.toml"),
    );
    // What `up --rig` starts the services with.
    let derived = vibro_system::derived::derive(Some(&est), Some(&comp), Some(&rig), None)
        .unwrap()
        .expect("derived configurations");
    let session = dir.0.join("services.mcap");
    let summaries = services_session(
        "lr",
        derived.estimator().unwrap(),
        derived.compensator().unwrap(),
        &log,
        &session,
        &dir.0.join("services.log"),
    );
    let offline = dir.0.join("offline.mcap");
    let summary = compensate(
        &log,
        &offline,
        &[
            "--rig",
            s(&rig),
            "--estimator-config",
            s(&est),
            "--compensator-config",
            s(&comp),
        ],
    );
    let rate_mismatches = &summary["estimator"]["rate_mismatches"];
    assert_eq!(rate_mismatches, 0, "{summary}");
    compare("rig log", &offline, &session, &summary, &summaries);
    // `log import` opens /truth, /vib, /accel as channels 1, 2, 3: the session opens
    // its inputs in that order, and the log's chunks are copied as they are.
    let copied = summary["copied_chunks"].as_u64().unwrap_or(0);
    assert!(copied >= 1, "{summary}");
    println!("FIGURES log compensate rig log: {copied} of the log's chunks copied");
}

#[test]
fn bad_input_is_refused_naming_the_file_and_nothing_is_written_through_a_link() {
    let dir = Dir::new("offline-bad");
    let log = flight_log(&dir, "2");
    let fail = |log: &Path, out: &Path, extra: &[&str]| -> String {
        let o = bin()
            .args(["log", "compensate", s(log), "--out", s(out)])
            .args(extra)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{} accepted", log.display());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let out = dir.path("out.mcap");
    let missing = dir.path("missing.mcap");
    let e = fail(&missing, &out, &[]);
    assert!(e.contains(s(&missing)), "{e}");
    assert!(!out.exists());

    // A log cut in the middle (a crash): refused, with the command that recovers it.
    let bytes = std::fs::read(&log).unwrap();
    let cut = dir.path("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = fail(&cut, &out, &[]);
    assert!(e.contains(s(&cut)), "{e}");
    assert!(e.contains("recover"), "{e}");
    assert!(!out.exists(), "a session was left for a damaged log");

    // --out a symbolic link to a file: refused, even with --force; the file untouched.
    let target = dir.path("target.txt");
    std::fs::write(&target, "keep me").unwrap();
    let link = dir.path("link.mcap");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    for extra in [&[][..], &["--force"][..]] {
        let e = fail(&log, &link, extra);
        assert!(e.contains(s(&link)), "{e}");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep me");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
    }
    // The log itself as the output.
    let e = fail(&log, &log, &["--force"]);
    assert!(e.contains(s(&log)), "{e}");
    assert_eq!(std::fs::read(&log).unwrap(), bytes);
    // An existing output without --force.
    std::fs::write(&out, "old").unwrap();
    let e = fail(&log, &out, &[]);
    assert!(e.contains("--force"), "{e}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old");
    println!("refused: {}", e.trim());
}
