//! Bad input at the process boundary (docs/reliability.md, "Bad input"), through the
//! `vibrocomp` binary:
//!
//! - publishers of another version of the message contracts, or with other
//!   quality of service, meet our services: each side refuses with the service, its own
//!   payload (type name, size, alignment) and what it found;
//! - processes of another user meet a running system, in both directions: refused,
//!   naming the owner, the user and what to do (README, "Who can publish and read");
//! - logs that cannot be replayed (not MCAP, truncated, empty, foreign, inconsistent,
//!   damaged part-way): refused before anything is published, or stopped where the
//!   damage is, never a panic or a hang; foreign channels are skipped and listed;
//! - a recording whose file cannot be created or written (missing folder, a device
//!   such as `/dev/full`, a file-size limit reached mid-recording): refused at once, or
//!   the recorder stops at once, with the path and the reason, and the services and
//!   publishers carry on;
//! - malformed files at `log info`, `log recover`, `log import`, and bad service
//!   configurations (unknown keys, wrong units, non-finite values).
//!
//! Every test that opens iceoryx2 services uses its own prefix (`processes::prefix`).

use crate::common::{bin, repo_path, run_json};
use crate::processes::{flight_log, prefix, Dir};
use iceoryx2::prelude::ZeroCopySend;
use std::collections::{BTreeMap, HashMap};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, stream_config, StreamPublisher};
use vibro_msgs::{MessageKind, ServiceId, ServiceNames, Stream, VibEstimate};
use vibro_service::supervise::{wait_for_heartbeats, Process};
use vibro_system::{Role, SystemSpec};

// ---------------------------------------------------------------------------------
// Helpers

/// Runs `cmd` to its end and returns its output; a run longer than `limit` is a hang
/// and fails the test (the process is killed first).
fn run_within(cmd: &mut Command, limit: Duration) -> Output {
    let start = Instant::now();
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "{cmd:?} still running after {limit:?} (a hang); stderr:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.wait_with_output().unwrap()
}

/// Asserts a refusal: exit status 1 (an error, not a crash or a usage error), no
/// panic, and every `wanted` text on stderr. Returns stderr.
fn assert_refused(what: &str, out: &Output, wanted: &[&str]) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{what}: exit status {}, stderr:\n{err}",
        out.status
    );
    assert!(!err.contains("panicked"), "{what}: a panic:\n{err}");
    for w in wanted {
        assert!(err.contains(w), "{what}: {w:?} not on stderr:\n{err}");
    }
    err
}

fn assert_ok(what: &str, out: &Output) -> String {
    assert!(
        out.status.success(),
        "{what}: exit status {}, stderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The estimator and the compensator as processes under `prefix` (default iceoryx2
/// root), up once both have published a heartbeat.
fn services(prefix: &str, log: &Path) -> (Process, Process) {
    let spec = SystemSpec {
        prefix: prefix.to_string(),
        estimator_config: Some(repo_path("config/services/estimator.toml")),
        compensator_config: Some(repo_path("config/services/compensator.toml")),
        json: true,
        exe: Some(PathBuf::from(env!("CARGO_BIN_EXE_vibrocomp"))),
        ..SystemSpec::default()
    };
    let mut est = spec.spawn(Role::Estimator, Some(log)).unwrap();
    let mut cmp = spec.spawn(Role::Compensator, Some(log)).unwrap();
    let names = ServiceNames::new(prefix).unwrap();
    let up = wait_for_heartbeats(
        &names,
        &[ServiceId::Estimator, ServiceId::Compensator],
        Duration::from_secs(30),
        || {
            est.check_alive()?;
            cmp.check_alive()
        },
    );
    if let Err(e) = up {
        panic!(
            "{e:#}\nservices log:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
    }
    (est, cmp)
}

/// Stops both services and checks they exit 0 (they ran through whatever the test
/// threw at them).
fn stop_cleanly((est, cmp): (Process, Process), log: &Path) {
    for p in [est, cmp] {
        let exit = p.stop(Duration::from_secs(10)).unwrap();
        assert_eq!(
            exit.code,
            Some(0),
            "the {} did not stop cleanly; services log:\n{}",
            exit.name,
            std::fs::read_to_string(log).unwrap_or_default()
        );
    }
}

/// `vibrocomp replay LOG --prefix P --json EXTRA...`, expected to succeed.
fn replay_ok(prefix: &str, log: &Path, extra: &[&str]) -> serde_json::Value {
    let out = run_within(
        bin()
            .arg("replay")
            .arg(log)
            .args(["--prefix", prefix, "--json"])
            .args(extra),
        Duration::from_secs(60),
    );
    let stdout = assert_ok(&format!("replay {}", log.display()), &out);
    serde_json::from_str(&stdout).unwrap()
}

// ---------------------------------------------------------------------------------
// Logs that are wrong in one way each

/// Writes `out` with the messages of the MCAP file `src` whose topic `topic_of` maps
/// to a topic (schema, encoding, sequence and times kept), then `camera` messages on
/// `/camera`, a channel with a JSON schema that is not vibrocomp's. Written with the
/// `mcap` crate, as another program would.
fn derived_log(
    src: &Path,
    out: &Path,
    topic_of: impl Fn(&str) -> Option<&'static str>,
    camera: u32,
) {
    let bytes = std::fs::read(src).unwrap();
    let file = std::io::BufWriter::new(std::fs::File::create(out).unwrap());
    let mut w = mcap::Writer::new(file).unwrap();
    let mut ids: HashMap<u16, u16> = HashMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let Some(topic) = topic_of(&m.channel.topic) else {
            continue;
        };
        let id = match ids.get(&m.channel.id) {
            Some(&id) => id,
            None => {
                let schema_id = match &m.channel.schema {
                    Some(sc) => w.add_schema(&sc.name, &sc.encoding, &sc.data).unwrap(),
                    None => 0,
                };
                let id = w
                    .add_channel(
                        schema_id,
                        topic,
                        &m.channel.message_encoding,
                        &m.channel.metadata,
                    )
                    .unwrap();
                ids.insert(m.channel.id, id);
                id
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: m.sequence,
            log_time: m.log_time,
            publish_time: m.publish_time,
        };
        w.write_to_known_channel(&header, &m.data).unwrap();
    }
    if camera > 0 {
        let schema = w
            .add_schema("acme.CameraFrame", "jsonschema", br#"{"type":"object"}"#)
            .unwrap();
        let id = w
            .add_channel(schema, "/camera", "json", &BTreeMap::new())
            .unwrap();
        for k in 0..camera {
            let t = u64::from(k) * 40_000_000;
            let header = mcap::records::MessageHeader {
                channel_id: id,
                sequence: k,
                log_time: t,
                publish_time: t,
            };
            w.write_to_known_channel(&header, format!(r#"{{"frame":{k}}}"#).as_bytes())
                .unwrap();
        }
    }
    w.finish().unwrap();
}

/// A finished log with `/vib` and `/accel` channels and no message (a recorder stopped
/// before anything came), written by vibro-mcap's own recorder.
fn log_without_messages(out: &Path) {
    let mut r = vibro_mcap::Recorder::create(out, vibro_mcap::RecorderOptions::default()).unwrap();
    r.add_channel("/vib", MessageKind::VibBlock).unwrap();
    r.add_channel("/accel", MessageKind::AccelBlock).unwrap();
    r.finish().unwrap();
}

/// The offsets of the chunk records of an MCAP file (walking its records from the
/// magic: opcode u8, length u64 LE, body).
fn chunk_offsets(bytes: &[u8]) -> Vec<usize> {
    let mut offsets = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let op = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        match op {
            0x06 => offsets.push(at),
            0x0F => break, // data end
            _ => {}
        }
        at += 9 + len;
    }
    offsets
}

/// A copy of `src` whose last chunk's stored CRC (body offset 24: after the start
/// time, end time and uncompressed size) is flipped: a finished file with one damaged
/// chunk, the others intact.
fn crc_damaged(src: &Path, out: &Path) {
    let mut bytes = std::fs::read(src).unwrap();
    let chunks = chunk_offsets(&bytes);
    assert!(
        chunks.len() >= 2,
        "{} has {} chunks; the test needs at least 2",
        src.display(),
        chunks.len()
    );
    let crc = chunks[chunks.len() - 1] + 9 + 24;
    for b in &mut bytes[crc..crc + 4] {
        *b ^= 0x5A;
    }
    std::fs::write(out, bytes).unwrap();
}

// ---------------------------------------------------------------------------------
// 1a. Publishers of another version of the message contracts

/// `AccelBlock` as a build of schema version 1 declares it: the v1 type name and a
/// shorter layout (816 bytes, not 824). Only its layout matters: iceoryx2 compares
/// type name, size and alignment when a service is opened, so it is never built.
#[allow(dead_code)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("vibrocomp::AccelBlock::v1")]
#[repr(C)]
struct AccelBlockV1 {
    seq: u64,
    first_sample_index: u64,
    t0_ns: u64,
    sample_period_ns: u64,
    publish_ns: u64,
    output_v: [[f64; 3]; 32],
    count: u32,
    source_id: u32,
}

/// A payload that claims today's `VibBlock` type name with another size: a contract
/// edited without the version bump docs/messages.md asks for. Never built, as above.
#[allow(dead_code)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("vibrocomp::VibBlock::v5")]
#[repr(C)]
struct VibBlockEdited {
    seq: u64,
    count: u32,
    flags: u32,
}

/// Streams created first by a foreign publisher (another version, another size under
/// our type name, iceoryx2's default quality of service): our services and the replay
/// refuse to start, naming the service, their own payload and the one they found.
#[test]
fn services_finding_a_stream_of_another_version_refuse_naming_both_payloads() {
    let dir = Dir::new("bad-ver");
    let flight = flight_log(&dir, "1");
    let p = prefix("ver");
    let names = ServiceNames::new(&p).unwrap();
    let node = create_node("vct-bad-ver").unwrap();
    let open = |s: Stream| (names.stream(s), names.event(s), stream_config(s));

    let (data, event, config) = open(Stream::Accel);
    let _v1 = StreamPublisher::<AccelBlockV1>::create(&node, &data, &event, &config).unwrap();
    let out = run_within(
        bin().args(["service", "compensator", "--prefix", &p]),
        Duration::from_secs(20),
    );
    assert_refused(
        "compensator on a v1 /accel",
        &out,
        &[
            &format!("subscribing to {p}accel"),
            &format!("\"{p}accel\" carries vibrocomp::AccelBlock::v1 (816 bytes, alignment 8), but this process uses vibrocomp::AccelBlock::v5 (824 bytes, alignment 8)"),
            "incompatible version of the message contracts (this build's is version 5",
        ],
    );

    let (data, event, config) = open(Stream::Vib);
    let _edited = StreamPublisher::<VibBlockEdited>::create(&node, &data, &event, &config).unwrap();
    let same_name = format!("\"{p}vib\" carries vibrocomp::VibBlock::v5 (16 bytes, alignment 8), but this process uses vibrocomp::VibBlock::v5 (12344 bytes, alignment 8)");
    let out = run_within(
        bin().args(["service", "estimator", "--prefix", &p]),
        Duration::from_secs(20),
    );
    assert_refused(
        "estimator on an edited /vib",
        &out,
        &[&format!("subscribing to {p}vib"), &same_name],
    );
    let out = run_within(
        bin()
            .arg("replay")
            .arg(&flight)
            .args(["--prefix", &p, "--wait-s", "1"]),
        Duration::from_secs(20),
    );
    assert_refused("replay into an edited /vib", &out, &[&same_name]);

    // A client that leaves iceoryx2's defaults (safe overflow on, a buffer of 2)
    // and creates /estimate first: the compensator says what is there and what it needs.
    let q = prefix("qos");
    let qos_names = ServiceNames::new(&q).unwrap();
    let name = iceoryx2::prelude::ServiceName::new(&qos_names.stream(Stream::Estimate)).unwrap();
    let _defaults = node
        .service_builder(&name)
        .publish_subscribe::<VibEstimate>()
        .create()
        .unwrap();
    let out = run_within(
        bin().args(["service", "compensator", "--prefix", &q]),
        Duration::from_secs(20),
    );
    assert_refused(
        "compensator on a default-QoS /estimate",
        &out,
        &[
            &format!("subscribing to {q}estimate"),
            &format!("\"{q}estimate\" exists with other settings than this process needs"),
            "safe overflow on",
            "this process needs subscriber buffer >= 256, history >= 1, safe overflow off",
        ],
    );
}

/// The system running, a publisher of another version (or an edited contract) is
/// refused at open with both payloads named; the services notice nothing and go on.
#[test]
fn a_running_system_refuses_a_publisher_of_another_version() {
    let dir = Dir::new("bad-ver-run");
    let flight = flight_log(&dir, "1");
    let log = dir.path("services.log");
    let p = prefix("verrun");
    let system = services(&p, &log);
    let names = ServiceNames::new(&p).unwrap();
    let node = create_node("vct-bad-verrun").unwrap();

    let s = Stream::Accel;
    let err = StreamPublisher::<AccelBlockV1>::create(
        &node,
        &names.stream(s),
        &names.event(s),
        &stream_config(s),
    )
    .err()
    .expect("a v1 publisher is refused");
    assert!(
        matches!(err, vibro_ipc::Error::IncompatibleType { .. }),
        "{err}"
    );
    let text = err.to_string();
    let wanted = format!("\"{p}accel\" carries vibrocomp::AccelBlock::v5 (824 bytes, alignment 8), but this process uses vibrocomp::AccelBlock::v1 (816 bytes, alignment 8): one of the two was built against an incompatible version of the message contracts");
    assert!(text.contains(&wanted), "{text}");

    let s = Stream::Vib;
    let err = StreamPublisher::<VibBlockEdited>::create(
        &node,
        &names.stream(s),
        &names.event(s),
        &stream_config(s),
    )
    .err()
    .expect("an edited publisher is refused")
    .to_string();
    assert!(
        err.contains("carries vibrocomp::VibBlock::v5 (12344 bytes, alignment 8), but this process uses vibrocomp::VibBlock::v5 (16 bytes, alignment 8)"),
        "{err}"
    );

    // The services still take a replay, lock-stepped, and lose nothing.
    let summary = replay_ok(&p, &flight, &[]);
    assert_eq!(summary["undelivered"], 0, "{summary}");
    assert_eq!(summary["topics"]["/vib"], 50, "{summary}");
    stop_cleanly(system, &log);
}

// ---------------------------------------------------------------------------------
// 1b. Processes of another user

/// The throwaway user the permission test runs processes as.
struct OtherUser {
    name: &'static str,
    uid: u32,
    gid: u32,
}

fn id_of(flag: &str, user: &str) -> Option<u32> {
    let out = Command::new("id").args([flag, user]).output().ok()?;
    String::from_utf8_lossy(&out.stdout).trim().parse().ok()
}

/// `vctuser` (created with `useradd -M -r` if missing), or why the test cannot run.
fn other_user() -> Result<OtherUser, String> {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        return Err("not running as root: cannot run a process as another user".into());
    }
    let name = "vctuser";
    if id_of("-u", name).is_none() {
        let made = Command::new("useradd")
            .args(["-M", "-r", "-s", "/usr/sbin/nologin", name])
            .output()
            .map_err(|e| format!("useradd unavailable ({e})"))?;
        if !made.status.success() {
            return Err(format!(
                "useradd -M -r {name} failed: {}",
                String::from_utf8_lossy(&made.stderr).trim()
            ));
        }
    }
    let (Some(uid), Some(gid)) = (id_of("-u", name), id_of("-g", name)) else {
        return Err(format!("no uid/gid for {name}"));
    };
    let user = OtherUser { name, uid, gid };
    // The binary must be reachable for that user (a private target dir is not).
    let probe = as_user(&user, Path::new("/")).arg("--version").output();
    match probe {
        Ok(o) if o.status.success() => Ok(user),
        Ok(o) => Err(format!(
            "{name} cannot run {}: {}",
            env!("CARGO_BIN_EXE_vibrocomp"),
            String::from_utf8_lossy(&o.stderr).trim()
        )),
        Err(e) => Err(format!("setpriv unavailable ({e})")),
    }
}

/// `vibrocomp` as `user` (no supplementary groups), started in `cwd`.
fn as_user(user: &OtherUser, cwd: &Path) -> Command {
    let mut c = Command::new("setpriv");
    c.arg(format!("--reuid={}", user.uid))
        .arg(format!("--regid={}", user.gid))
        .arg("--clear-groups")
        .arg(env!("CARGO_BIN_EXE_vibrocomp"))
        .current_dir(cwd);
    c
}

/// `vibrocomp` as this (root) process's user, started in `cwd`.
fn as_root(cwd: &Path) -> Command {
    let mut c = bin();
    c.current_dir(cwd);
    c
}

/// A folder whose `config/iceoryx2.toml` gives every process started in it the
/// iceoryx2 root `root` and the shared-memory file prefix `files`: it meets no other
/// test's system, and whoever starts first owns `root`, deterministically.
fn iceoryx_home(dir: &Dir, name: &str, root: &Path, files: &str) -> PathBuf {
    let home = dir.path(name);
    std::fs::create_dir_all(home.join("config")).unwrap();
    std::fs::write(
        home.join("config/iceoryx2.toml"),
        format!(
            "[global]\nroot-path = \"{}/\"\nprefix = \"{files}\"\n",
            root.display()
        ),
    )
    .unwrap();
    home
}

/// A child process stopped with SIGTERM (then SIGKILL) when dropped.
struct Kid(Child);

impl Kid {
    fn spawn(cmd: &mut Command, log: &Path) -> Kid {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
            .unwrap();
        Kid(cmd
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap())
    }

    fn alive(&mut self) -> bool {
        self.0.try_wait().unwrap().is_none()
    }

    /// SIGTERM and the exit code.
    fn stop(mut self) -> Option<i32> {
        terminate(&self.0);
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            if let Some(status) = self.0.try_wait().unwrap() {
                return status.code();
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        None
    }
}

fn terminate(child: &Child) {
    // SAFETY: signalling our own child by its pid.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
    }
}

impl Drop for Kid {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            terminate(&self.0);
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(3) {
                if let Ok(Some(_)) = self.0.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Starts the estimator and the compensator with `cmd` (as one user, in one iceoryx2
/// home) and waits until both say they run.
fn start_system(cmd: impl Fn() -> Command, prefix: &str, log: &Path) -> (Kid, Kid) {
    let mut kids = ["estimator", "compensator"]
        .map(|service| Kid::spawn(cmd().args(["service", service, "--prefix", prefix]), log));
    let start = Instant::now();
    loop {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        if text.contains("estimator running") && text.contains("compensator running") {
            break;
        }
        assert!(
            kids.iter_mut().all(Kid::alive) && start.elapsed() < Duration::from_secs(30),
            "the services did not start; their log:\n{text}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let [est, cmp] = kids;
    (est, cmp)
}

/// The shared-memory files of an iceoryx2 file prefix, removed when dropped (also
/// when the test fails): iceoryx2 keeps some after its last process, e.g. the
/// node-management segment.
struct ShmFiles(String);

impl Drop for ShmFiles {
    fn drop(&mut self) {
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(&self.0) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}

/// A system of root refuses a replay (a publisher) and a recorder (a reader) of
/// another user, and a system of that user refuses root's replay: each refusal names
/// the iceoryx2 folder, its owner, the user that was refused and what to do. Without
/// our check, iceoryx2 0.10 refuses the other user's node with a bare
/// `InternalError`, and lets root in, whose messages the owner's services then never
/// receive while root's publisher counts them delivered (measured; README).
#[test]
fn processes_of_another_user_are_refused_by_a_running_system_both_ways() {
    let user = match other_user() {
        Ok(u) => u,
        Err(reason) => {
            eprintln!("SKIPPED processes_of_another_user_are_refused_by_a_running_system_both_ways: {reason}");
            return;
        }
    };
    let dir = Dir::new("bad-user");
    let flight = flight_log(&dir, "1");
    // Every folder the other user passes through is world-readable; its own folder
    // for direction 2 belongs to it.
    let top = dir.path("");
    std::fs::set_permissions(&top, std::fs::Permissions::from_mode(0o755)).unwrap();
    std::fs::set_permissions(&flight, std::fs::Permissions::from_mode(0o644)).unwrap();
    let p = prefix("usr");
    let tag = p.trim_end_matches('/').replace('-', "");
    let me = format!("runs as {} (uid {})", user.name, user.uid);
    let owner = format!("belong to {} (uid {})", user.name, user.uid);

    // Direction 1: root's system, the other user's replay and recorder.
    let files = format!("{tag}r_");
    let _root_shm = ShmFiles(files.clone());
    let root_dir = dir.path("root-iox2");
    let home = iceoryx_home(&dir, "home-root", &root_dir, &files);
    let log = dir.path("root-services.log");
    let system = start_system(|| as_root(&home), &p, &log);
    let root_path = format!("{}/", root_dir.display());
    // The recording goes where that user may write (README, "Files": a device such as
    // /dev/null is refused before the recorder reaches iceoryx2).
    let writable = dir.path("user-rec");
    std::fs::create_dir(&writable).unwrap();
    std::fs::set_permissions(&writable, std::fs::Permissions::from_mode(0o777)).unwrap();
    let rec = writable.join("rec.mcap");
    for (what, args) in [
        (
            "replay (publisher)",
            vec![
                "replay",
                s(&flight),
                "--prefix",
                p.as_str(),
                "--wait-s",
                "2",
            ],
        ),
        (
            "record (reader)",
            vec![
                "record",
                s(&rec),
                "--prefix",
                p.as_str(),
                "--duration-s",
                "2",
            ],
        ),
    ] {
        let out = run_within(as_user(&user, &home).args(&args), Duration::from_secs(20));
        assert_refused(
            &format!("{}'s {what} into root's system", user.name),
            &out,
            &[
                &format!("{root_path}: the iceoryx2 resources here belong to root (uid 0)"),
                &me,
                "Run it as root (uid 0), or give each user an iceoryx2 root of its own",
                "Who can publish and read",
            ],
        );
    }
    // Root's own replay goes through: the system is intact and the refusal was the user.
    let out = run_within(
        as_root(&home)
            .arg("replay")
            .arg(&flight)
            .args(["--prefix", &p, "--json"]),
        Duration::from_secs(60),
    );
    let summary: serde_json::Value =
        serde_json::from_str(&assert_ok("root's replay", &out)).unwrap();
    assert_eq!(summary["topics"]["/accel"], 25, "{summary}");
    let (est, cmp) = system;
    assert_eq!((est.stop(), cmp.stop()), (Some(0), Some(0)));

    // Direction 2: the other user's system (its iceoryx2 root in a folder it owns),
    // root's replay.
    let files = format!("{tag}u_");
    let _user_shm = ShmFiles(files.clone());
    let own = dir.path("user-owned");
    std::fs::create_dir_all(&own).unwrap();
    std::os::unix::fs::chown(&own, Some(user.uid), Some(user.gid)).unwrap();
    let user_root = own.join("iox2");
    let home = iceoryx_home(&dir, "home-user", &user_root, &files);
    let log = dir.path("user-services.log");
    let system = start_system(|| as_user(&user, &home), &p, &log);
    let out = run_within(
        as_root(&home)
            .arg("replay")
            .arg(&flight)
            .args(["--prefix", &p, "--wait-s", "2"]),
        Duration::from_secs(20),
    );
    assert_refused(
        "root's replay into the user's system",
        &out,
        &[
            &format!(
                "{}/: the iceoryx2 resources here {owner}",
                user_root.display()
            ),
            "runs as root (uid 0)",
            &format!("Run it as {} (uid {})", user.name, user.uid),
        ],
    );
    let out = run_within(
        as_user(&user, &home)
            .arg("replay")
            .arg(&flight)
            .args(["--prefix", &p, "--json"]),
        Duration::from_secs(60),
    );
    let summary: serde_json::Value =
        serde_json::from_str(&assert_ok("the user's own replay", &out)).unwrap();
    assert_eq!(summary["topics"]["/vib"], 50, "{summary}");
    let (est, cmp) = system;
    assert_eq!((est.stop(), cmp.stop()), (Some(0), Some(0)));
}

// ---------------------------------------------------------------------------------
// 2. Replay of bad logs

/// Logs a replay cannot use are refused before any service is opened: exit 1 within
/// a few seconds (no wait for subscribers), the file and the problem named.
#[test]
fn replay_refuses_logs_it_cannot_use_before_publishing_anything() {
    let dir = Dir::new("bad-logs");
    let flight = flight_log(&dir, "1");
    let bytes = std::fs::read(&flight).unwrap();
    let file = |name: &str, data: &[u8]| {
        let p = dir.path(name);
        std::fs::write(&p, data).unwrap();
        p
    };
    let empty = file("empty.mcap", b"");
    let text = file("notes.mcap", b"time_s,u1_v\n0,1\n");
    let magic = file("magic.mcap", &bytes[..8]);
    let truncated = file("truncated.mcap", &bytes[..bytes.len() / 2]);
    let no_messages = dir.path("no-messages.mcap");
    log_without_messages(&no_messages);
    let nothing = dir.path("nothing.mcap");
    derived_log(&flight, &nothing, |_| None, 0);
    let camera = dir.path("camera.mcap");
    derived_log(&flight, &camera, |_| None, 3);
    let accel_only = dir.path("accel-only.mcap");
    derived_log(
        &flight,
        &accel_only,
        |t| match t {
            "/accel" => Some("/accel"),
            "/truth" => Some("/truth"),
            _ => None,
        },
        0,
    );
    let wrong_type = dir.path("wrong-type.mcap");
    derived_log(
        &flight,
        &wrong_type,
        |t| (t == "/vib").then_some("/accel"),
        0,
    );
    let folder = dir.path("a-folder.mcap");
    std::fs::create_dir_all(&folder).unwrap();
    let missing = dir.path("missing.mcap");

    let recover = "vibrocomp log recover";
    let cases: [(&Path, &[&str]); 11] = [
        (&empty, &["empty file (0 bytes), not an MCAP log"]),
        (&text, &["not an MCAP log: it does not start with the MCAP magic bytes"]),
        (&magic, &["damaged: 8 bytes, too short for a finished MCAP log", recover]),
        (&truncated, &["damaged: not finished (no footer)", "a crash, a full disk, or a copy still in progress", recover]),
        (&no_messages, &["no messages: a valid MCAP log, but its channels (/accel, /vib) hold nothing to replay"]),
        (&nothing, &["nothing to replay: no /vib or /accel channel"]),
        (&camera, &["nothing to replay: no /vib or /accel channel", "not replayable: /camera (not a vibrocomp.v1 schema)"]),
        (&accel_only, &["has /accel but no /vib", "ESTIMATE_MISSING", "--topics /accel"]),
        (&wrong_type, &["topic /accel carries VibBlock messages, but the system's /accel carries AccelBlock"]),
        (&folder, &["is a directory, not a log file"]),
        (&missing, &["cannot open it: No such file or directory (os error 2)"]),
    ];
    let p = prefix("logs");
    for (path, wanted) in cases {
        let start = Instant::now();
        let out = run_within(
            bin()
                .arg("replay")
                .arg(path)
                .args(["--prefix", &p, "--wait-s", "5"]),
            Duration::from_secs(20),
        );
        let named = format!("{}: ", path.display());
        let mut all = vec![named.as_str()];
        all.extend_from_slice(wanted);
        assert_refused(&format!("replay {}", path.display()), &out, &all);
        // Refused before any wait for subscribers (--wait-s 5).
        assert!(
            start.elapsed() < Duration::from_secs(4),
            "replay {} took {:?}",
            path.display(),
            start.elapsed()
        );
    }
}

/// Into running services: a log with foreign channels replays what is vibrocomp's and
/// lists what it skipped; `--topics /accel` overrides the /accel-without-/vib refusal;
/// a chunk damaged in the middle of a finished log stops the replay there with the
/// file, the damage, how far it got and the way out; a window with nothing in it is
/// an error even with `--loop` (which would otherwise spin for ever). The services run
/// through all of it and stop cleanly.
#[test]
fn replay_into_running_services_skips_foreign_channels_and_stops_at_damage() {
    let dir = Dir::new("bad-replay");
    let flight = flight_log(&dir, "3");
    let mixed = dir.path("mixed.mcap");
    derived_log(
        &flight,
        &mixed,
        |t| match t {
            "/vib" => Some("/vib"),
            "/accel" => Some("/accel"),
            "/truth" => Some("/truth-b"),
            _ => None,
        },
        5,
    );
    let accel_only = dir.path("accel-only.mcap");
    derived_log(
        &flight,
        &accel_only,
        |t| (t == "/accel").then_some("/accel"),
        0,
    );
    let damaged = dir.path("damaged.mcap");
    crc_damaged(&flight, &damaged);
    let log = dir.path("services.log");
    let p = prefix("rpl");
    let system = services(&p, &log);

    let out = run_within(
        bin().arg("replay").arg(&damaged).args(["--prefix", &p]),
        Duration::from_secs(60),
    );
    let err = assert_refused(
        "replay of a log with a damaged chunk",
        &out,
        &[
            &format!(
                "{}: damaged: a chunk fails its CRC (expected",
                damaged.display()
            ),
            "messages had been published (log time",
            "the replay stopped there",
            &format!("vibrocomp log recover {} OUT.mcap", damaged.display()),
        ],
    );
    assert!(
        !err.contains("after 0 messages"),
        "the damage is in the last chunk: {err}"
    );

    let summary = replay_ok(&p, &mixed, &[]);
    assert_eq!(summary["topics"]["/vib"], 150, "{summary}");
    assert_eq!(summary["topics"]["/accel"], 75, "{summary}");
    assert_eq!(summary["undelivered"], 0, "{summary}");
    let skipped = summary["skipped_topics"].to_string();
    assert!(
        skipped.contains("/camera (not a vibrocomp.v1 schema)")
            && skipped.contains("/truth-b (TruthBlock, not a stream of the system)"),
        "{summary}"
    );

    let summary = replay_ok(&p, &accel_only, &["--topics", "/accel"]);
    assert_eq!(summary["topics"]["/accel"], 75, "{summary}");

    let out = run_within(
        bin()
            .arg("replay")
            .arg(&flight)
            .args(["--prefix", &p, "--start-s", "100", "--loop"]),
        Duration::from_secs(30),
    );
    assert_refused(
        "replay --start-s past the end --loop",
        &out,
        &[&format!(
            "{}: no message of /accel, /truth, /vib from 100 s into the log (the log has 300 messages in all)",
            flight.display()
        )],
    );
    stop_cleanly(system, &log);
}

// ---------------------------------------------------------------------------------
// 3. A recording that cannot be written

/// No system needed: a missing folder, a path through a regular file, a folder and a
/// device (`/dev/full`: README, "Files", refused as not a regular file) fail at once
/// with the path and the reason.
#[test]
fn recording_where_it_cannot_write_fails_at_once_naming_path_and_reason() {
    let dir = Dir::new("bad-rec");
    let plain = dir.path("plain.txt");
    std::fs::write(&plain, "x").unwrap();
    let missing = dir.path("missing");
    let missing_folder = format!("its folder {} does not exist", missing.display());
    let cases = [
        (missing.join("out.mcap"), "output", missing_folder.as_str()),
        (
            plain.join("out.mcap"),
            "output",
            "Not a directory (os error 20)",
        ),
        (dir.path(""), "output", "is a directory, not a file"),
        (
            PathBuf::from("/dev/full"),
            "output",
            "is a character device, not a regular file: refused even with --force",
        ),
    ];
    let p = prefix("rec");
    for (path, action, reason) in cases {
        let out = run_within(
            bin()
                .arg("record")
                .arg(&path)
                .args(["--prefix", &p, "--duration-s", "30"]),
            Duration::from_secs(10),
        );
        let shown = path.display().to_string();
        let shown = shown.trim_end_matches('/');
        assert_refused(
            &format!("record {shown}"),
            &out,
            &[&format!("{action} {shown}"), reason],
        );
    }
}

/// The system running: a recorder on `/dev/full` stops at once; a recorder whose file
/// reaches the file-size limit mid-recording (RLIMIT_FSIZE, the way to fill a disk
/// without a disk: writes fail with EFBIG) stops with the path and the reason while a
/// paced replay goes on undisturbed, and its file keeps complete chunks that `log
/// recover` restores. The services run on and take a lock-stepped replay afterwards.
#[test]
fn a_full_disk_stops_the_recorder_and_the_system_runs_on() {
    let dir = Dir::new("bad-full");
    let flight = flight_log(&dir, "4");
    let log = dir.path("services.log");
    let p = prefix("full");
    let system = services(&p, &log);

    // A device is refused before the recorder starts (README, "Files"); the full
    // disk is the file-size limit below (and /dev/full in vibro-mcap's recorder tests).
    let out = run_within(
        bin().args(["record", "/dev/full", "--prefix", &p, "--duration-s", "30"]),
        Duration::from_secs(10),
    );
    assert_refused(
        "record /dev/full",
        &out,
        &["output /dev/full: is a character device, not a regular file"],
    );

    const LIMIT_BYTES: u64 = 700_000;
    let rec = dir.path("limited.mcap");
    let mut cmd = bin();
    cmd.arg("record")
        .arg(&rec)
        .args(["--prefix", &p, "--duration-s", "30"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: runs in the child between fork and exec and only calls setrlimit and
    // signal, which are async-signal-safe; it allocates nothing.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: LIMIT_BYTES,
                rlim_max: LIMIT_BYTES,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // A write past the limit then fails with EFBIG instead of killing.
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let mut recorder = cmd.spawn().unwrap();
    // Its heartbeat says it has subscribed.
    let names = ServiceNames::new(&p).unwrap();
    wait_for_heartbeats(
        &names,
        &[ServiceId::Recorder],
        Duration::from_secs(20),
        || match recorder.try_wait()? {
            Some(status) => anyhow::bail!("the recorder ended early ({status})"),
            None => Ok(()),
        },
    )
    .unwrap();
    let summary = replay_ok(&p, &flight, &["--rate", "4"]);
    assert_eq!(summary["undelivered"], 0, "{summary}");
    assert_eq!(summary["topics"]["/vib"], 200, "{summary}");
    // 1 s of pacing; a recorder that held its publishers up would cost them up to the
    // 1 s back-pressure timeout per message.
    assert!(
        summary["elapsed_s"].as_f64().unwrap() < 5.0,
        "the replay was held up: {summary}"
    );
    let start = Instant::now();
    while recorder.try_wait().unwrap().is_none() {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "the recorder did not stop on its write error"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = recorder.wait_with_output().unwrap();
    assert_refused(
        "record past the file-size limit",
        &out,
        &[
            &format!(
                "cannot write the recording {}: File too large (os error 27)",
                rec.display()
            ),
            &format!("vibrocomp log recover {} OUT.mcap", rec.display()),
        ],
    );
    assert_eq!(std::fs::metadata(&rec).unwrap().len(), LIMIT_BYTES);
    let recovered = dir.path("recovered.mcap");
    let out = run_within(
        bin().args(["log", "recover", s(&rec), s(&recovered)]),
        Duration::from_secs(30),
    );
    assert_ok("log recover of the cut recording", &out);
    let info = run_json(&["log", "info", s(&recovered), "--json"]);
    assert!(info["messages"].as_u64().unwrap() > 0, "{info}");

    let summary = replay_ok(&p, &flight, &["--duration-s", "1"]);
    assert_eq!(summary["undelivered"], 0, "{summary}");
    stop_cleanly(system, &log);
}

// ---------------------------------------------------------------------------------
// 4. Malformed files at `log info`, `log recover`, `log import`; bad configurations

/// The binary, not only the library: exit 1 and the file and the problem named.
#[test]
fn log_commands_refuse_malformed_files_naming_file_and_problem() {
    let dir = Dir::new("bad-files");
    let flight = flight_log(&dir, "3");
    let bytes = std::fs::read(&flight).unwrap();
    let file = |name: &str, data: &[u8]| {
        let p = dir.path(name);
        std::fs::write(&p, data).unwrap();
        p
    };
    let empty = file("empty.mcap", b"");
    let text = file("notes.mcap", b"not a log\n");
    let magic = file("magic.mcap", &bytes[..8]);
    let truncated = file("truncated.mcap", &bytes[..bytes.len() / 2]);
    let damaged = dir.path("damaged.mcap");
    crc_damaged(&flight, &damaged);
    let missing = dir.path("missing.mcap");
    let fail = |args: &[&str]| run_within(bin().args(args), Duration::from_secs(30));

    let info: [(&Path, &[&str]); 6] = [
        (&empty, &["empty file (0 bytes), not an MCAP log"]),
        (
            &text,
            &["not an MCAP log: it does not start with the MCAP magic bytes"],
        ),
        (&magic, &["is damaged", "vibrocomp log recover"]),
        (&truncated, &["is damaged", "vibrocomp log recover"]),
        (&damaged, &["is damaged", "chunk CRC failed (expected"]),
        (&missing, &["cannot open it", "No such file or directory"]),
    ];
    for (path, wanted) in info {
        let named = path.display().to_string();
        let mut all = vec![named.as_str()];
        all.extend_from_slice(wanted);
        assert_refused(
            &format!("log info {named}"),
            &fail(&["log", "info", s(path)]),
            &all,
        );
    }

    let out_path = dir.path("out.mcap");
    let out = s(&out_path);
    assert_refused(
        "log recover of a text file",
        &fail(&["log", "recover", s(&text), out]),
        &[&format!("{}: not an MCAP log", text.display())],
    );
    assert_refused(
        "log recover of a file without a complete header",
        &fail(&["log", "recover", s(&magic), out]),
        &[&format!(
            "{}: nothing to recover: it ends before its MCAP header record is complete (8 bytes)",
            magic.display()
        )],
    );
    // The lab reads a log as `log info` does: a text file is not a damaged log.
    assert_refused(
        "lab diagnose of a text file named .mcap",
        &fail(&["lab", "diagnose", s(&text)]),
        &[&format!(
            "{}: not an MCAP log: it does not start with the MCAP magic bytes",
            text.display()
        )],
    );
    let nowhere = dir.path("missing/out.mcap");
    assert_refused(
        "log recover into a missing folder",
        &fail(&["log", "recover", s(&truncated), s(&nowhere)]),
        &[&format!(
            "output {}: its folder {} does not exist",
            nowhere.display(),
            dir.path("missing").display()
        )],
    );
    assert!(!out_path.exists());
    // A finished file with one bad chunk: the others are kept, and the exit status
    // (3: written, with losses) and the last line say that some were not.
    let recovered = fail(&["log", "recover", s(&damaged), out]);
    assert_eq!(
        recovered.status.code(),
        Some(3),
        "log recover of a damaged chunk: {}",
        String::from_utf8_lossy(&recovered.stderr)
    );
    let report = String::from_utf8_lossy(&recovered.stdout);
    assert!(
        report
            .lines()
            .last()
            .is_some_and(|l| l.starts_with("  result: recovered with losses (exit status 3)")),
        "{report}"
    );
    let whole = run_json(&["log", "info", s(&flight), "--json"]);
    let kept = run_json(&["log", "info", out, "--json"]);
    let (whole, kept) = (
        whole["messages"].as_u64().unwrap(),
        kept["messages"].as_u64().unwrap(),
    );
    assert!(0 < kept && kept < whole, "kept {kept} of {whole}");

    let csv_empty = file("empty.csv", b"");
    let csv_header = file("header.csv", b"time_s,u1_v,u2_v,u3_v\n");
    let csv_missing = dir.path("missing.csv");
    let imported = dir.path("imported.mcap");
    for (csv, wanted) in [
        (&csv_empty, "no header"),
        (&csv_header, "no data rows"),
        (&csv_missing, "No such file or directory"),
    ] {
        assert_refused(
            &format!("log import {}", csv.display()),
            &fail(&["log", "import", "--accel", s(csv), "--out", s(&imported)]),
            &[&csv.display().to_string(), wanted],
        );
        assert!(!imported.exists());
    }
}

/// `vibrocomp service estimator|compensator --config F` with an unknown key, a key in
/// the wrong unit, a value in the wrong unit, a non-finite value or coefficient: exit 1
/// before any shared memory is opened, with the file, key, value and rule.
#[test]
fn services_refuse_bad_configurations_naming_file_key_value_and_rule() {
    let dir = Dir::new("bad-cfg");
    let p = prefix("cfg");
    let shipped = |name: &str| {
        std::fs::read_to_string(repo_path(&format!("config/services/{name}.toml")))
            .unwrap()
            .replace("prefix = \"vibrocomp/\"", &format!("prefix = \"{p}\""))
    };
    let edit = |file: &str, base: &str, from: &str, to: &str| {
        let text = shipped(base);
        assert!(
            text.contains(from),
            "{from:?} not in the shipped {base}.toml"
        );
        let path = dir.path(file);
        std::fs::write(&path, text.replace(from, to)).unwrap();
        path
    };
    let passport = dir.path("bad-passport.toml");
    std::fs::write(
        &passport,
        std::fs::read_to_string(repo_path("config/accelerometers/al-15.toml"))
            .unwrap()
            .replace("id = \"AL-15\"", "id = \"BAD-1\"")
            .replace("k2_ppm_per_g = 105.0", "k2_ppm_per_g = inf"),
    )
    .unwrap();
    let cases: Vec<(&str, PathBuf, Vec<String>)> = vec![
        (
            "estimator",
            edit("est-unknown.toml", "estimator", "max_tones = 4", "max_tones = 4\nmax_tone = 4"),
            vec!["max_tone: unknown key (did you mean max_tones?)".into()],
        ),
        (
            "estimator",
            edit("est-unit-key.toml", "estimator", "window_s = 1.0", "window_ms = 1000"),
            vec!["window_ms: unknown key (did you mean window_s?)".into()],
        ),
        (
            "estimator",
            edit("est-unit-value.toml", "estimator", "sample_rate_hz = 25600.0", "sample_rate_hz = 25.6"),
            vec![
                "estimator.window_s = 1: must be finite and hold 256..=16777216 samples (it holds 26)".into(),
                "estimator.broadband_band_hz = [20, 2000]: must satisfy 0 < lo < hi <= 12.8 Hz (Nyquist)".into(),
            ],
        ),
        (
            "estimator",
            edit("est-nan.toml", "estimator", "window_s = 1.0", "window_s = nan"),
            vec!["estimator.window_s = NaN: must be finite".into()],
        ),
        (
            "compensator",
            edit("cmp-unit-key.toml", "compensator", "max_estimate_age_s = 2.0", "max_estimate_age_ms = 2000"),
            vec!["max_estimate_age_ms: unknown key (did you mean max_estimate_age_s?)".into()],
        ),
        (
            "compensator",
            edit("cmp-inf.toml", "compensator", "max_estimate_age_s = 2.0", "max_estimate_age_s = inf"),
            vec!["max_estimate_age_s = inf: must be finite and 0 < s <= 3600".into()],
        ),
        (
            "compensator",
            edit(
                "cmp-passport.toml",
                "compensator",
                "triad = \"default\"",
                &format!("triad = \"default\"\npassports = [\"{}\", \"AL-15\", \"AL-15\"]", passport.display()),
            ),
            vec![
                format!("passports[0] = \"{}\"", passport.display()),
                "k2_ppm_per_g = inf: must be finite and |k2| <= 1e4 ppm/g".into(),
            ],
        ),
    ];
    for (service, path, wanted) in cases {
        let out = run_within(
            bin().args(["service", service, "--config", s(&path)]),
            Duration::from_secs(20),
        );
        let named = path.display().to_string();
        let mut all: Vec<&str> = vec![&named];
        all.extend(wanted.iter().map(String::as_str));
        assert_refused(&format!("{service} --config {named}"), &out, &all);
    }
}
