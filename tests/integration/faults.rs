//! Faults and load through the real processes (`vibrocomp up`, `vibrocomp service ...`,
//! `vibrocomp record`, `vibrocomp replay`), each test on its own service prefix:
//!
//! - the estimator killed (SIGKILL) under `up` during a paced replay: the compensator
//!   goes on with one output per input, flags it stale and main-only once the last
//!   estimate is older than `max_estimate_age_s`, and compensates fully again once `up`
//!   has restarted the estimator; the dead process's iceoryx2 node is gone;
//! - the compensator killed under `up --record`: restarted, and the recording shows
//!   the accelerometer blocks that have no output, by `input_seq`;
//! - the recorder killed: `vibro_mcap::recover` keeps everything but the last second,
//!   a clean stop (SIGTERM) loses nothing, and the replay is not stalled by the dead
//!   subscriber;
//! - a subscriber of `compensated` that never reads: bounded back-pressure, counted
//!   `undelivered`, reported, and the recorder still gets every block;
//! - a soak at 10x real time (`VIBROCOMP_SOAK_S` seconds, default 12): nothing lost,
//!   resident memory flat, the latency histogram filled.
//!
//! The figures each test measured are printed (`--nocapture`) and kept in
//! docs/reliability.md.

use crate::common::{bin, repo_path};
use crate::processes::{children, flight_log, kill, poll, prefix, Dir, Kid};
use iceoryx2::node::NodeView;
use iceoryx2::prelude::{CallbackProgression, Config, Node, NodeState};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, now_ns, stream_config, Ipc, StreamSubscriber};
use vibro_mcap::{Message, Reader, Record};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{
    CompensatedBlock, Heartbeat, ServiceId, ServiceNames, ServiceState, Stream, VibEstimate,
};
use vibro_service::supervise::wait_for_heartbeats;
use vibro_service::ServiceConfig;
use vibro_system::{Role, SystemSpec};

/// The soak needs both cores to itself: it takes this lock for writing, the other
/// tests of this module for reading (they may run two at a time).
static LOAD: RwLock<()> = RwLock::new(());

fn shared_load() -> RwLockReadGuard<'static, ()> {
    LOAD.read().unwrap_or_else(|e| e.into_inner())
}

fn exclusive_load() -> RwLockWriteGuard<'static, ()> {
    LOAD.write().unwrap_or_else(|e| e.into_inner())
}

/// A compensator configuration: the shipped model, with `max_estimate_age_s` and the
/// summary period (the heartbeat's `degraded` looks back to the last summary) given.
fn compensator_config(dir: &Dir, max_estimate_age_s: f64, summary_period_s: f64) -> PathBuf {
    compensator_config_stage(dir, max_estimate_age_s, summary_period_s, "waveform")
}

/// The same with `stage` (`waveform`, the default, or `estimate`: the paper's stages,
/// whose staleness rules a killed estimator shows).
fn compensator_config_stage(
    dir: &Dir,
    max_estimate_age_s: f64,
    summary_period_s: f64,
    stage: &str,
) -> PathBuf {
    let path = dir.path("compensator.toml");
    std::fs::write(
        &path,
        format!(
            "prefix = \"vibrocomp/\"\nmode = \"exact\"\ntriad = \"default\"\n\
             max_estimate_age_s = {max_estimate_age_s:?}\nreload_poll_s = 0.0\n\
             stage = \"{stage}\"\n\n\
             [service]\nsummary_period_s = {summary_period_s:?}\n"
        ),
    )
    .unwrap();
    // Fails here, naming the problem, rather than in a restart loop of the service.
    vibro_compensator::Config::load(&path).unwrap();
    path
}

fn spec(prefix: &str, record: Option<PathBuf>, compensator: Option<PathBuf>) -> SystemSpec {
    SystemSpec {
        prefix: prefix.to_string(),
        estimator_config: Some(repo_path("config/services/estimator.toml")),
        compensator_config: Some(
            compensator.unwrap_or_else(|| repo_path("config/services/compensator.toml")),
        ),
        record,
        json: true,
        exe: Some(PathBuf::from(env!("CARGO_BIN_EXE_vibrocomp"))),
        ..SystemSpec::default()
    }
}

/// `role` of the system, as `up` would start it, its stderr appended to `log`.
fn start_role(spec: &SystemSpec, role: Role, log: &Path) -> Kid {
    Kid::spawn_logging(spec.command(role).unwrap(), role.name(), log)
}

/// Stops `kid` with SIGTERM and returns the JSON summary it printed (exit 0).
fn summary(mut kid: Kid) -> serde_json::Value {
    let (status, stdout, log) = kid.stop(libc::SIGTERM, Duration::from_secs(30));
    assert!(status.success(), "it exited with {status}\nlog:\n{log}");
    json_in(&stdout)
}

/// The first JSON value in `text` (`up` prints the recorder's text summary first).
fn json_in(text: &str) -> serde_json::Value {
    let start = text
        .find('{')
        .unwrap_or_else(|| panic!("no JSON in {text:?}"));
    serde_json::Deserializer::from_str(&text[start..])
        .into_iter::<serde_json::Value>()
        .next()
        .unwrap()
        .unwrap()
}

/// `vibrocomp up` on `prefix`, recording into `record`.
fn up(prefix: &str, record: &Path, compensator: &Path, log: &Path) -> Kid {
    let mut cmd = bin();
    cmd.args(["up", "--json", "--prefix", prefix, "--record"])
        .arg(record)
        .arg("--estimator-config")
        .arg(repo_path("config/services/estimator.toml"))
        .arg("--compensator-config")
        .arg(compensator);
    Kid::spawn_logging(cmd, "up", log)
}

/// `vibrocomp replay LOG --prefix P --json EXTRA...`, running in the background.
fn replay(prefix: &str, log: &Path, extra: &[&str], services_log: &Path) -> Kid {
    let mut cmd = bin();
    cmd.arg("replay")
        .arg(log)
        .args(["--prefix", prefix, "--json"])
        .args(extra);
    Kid::spawn_logging(cmd, "replay", services_log)
}

/// Waits for the replay to end (exit 0) and returns its JSON summary.
fn replay_done(mut replay: Kid, timeout: Duration) -> serde_json::Value {
    let (status, stdout, log) = replay.wait(timeout);
    assert!(status.success(), "replay failed ({status})\nlog:\n{log}");
    json_in(&stdout)
}

fn wait_up(prefix: &str, services: &[ServiceId], kids: &mut [&mut Kid]) {
    let names = ServiceNames::new(prefix).unwrap();
    let log = kids.first().map(|k| k.stderr()).unwrap_or_default();
    if let Err(e) = wait_for_heartbeats(&names, services, Duration::from_secs(30), || {
        for k in kids.iter_mut() {
            k.check_alive()?;
        }
        Ok(())
    }) {
        panic!("{e:#}\nservices log:\n{log}");
    }
}

/// The pid of `up`'s child whose command line contains `what`, other than `not`.
fn child_of(up: u32, what: &str, not: u32) -> Option<u32> {
    children(up)
        .into_iter()
        .find(|(pid, cmd)| *pid != not && cmd.contains(what))
        .map(|(pid, _)| pid)
}

/// The iceoryx2 nodes of process `pid`: (alive, dead) node names.
fn nodes_of(pid: u32) -> (Vec<String>, Vec<String>) {
    let (mut alive, mut dead) = (Vec::new(), Vec::new());
    let of_pid = |d: &Option<iceoryx2::node::NodeDetails>| {
        d.as_ref()
            .filter(|d| d.process_id().value() as u32 == pid)
            .map(|d| d.name().to_string())
    };
    Node::<Ipc>::list(Config::global_config(), |state| {
        match &state {
            NodeState::Alive(v) => alive.extend(of_pid(v.details())),
            NodeState::Dead(v) => dead.extend(of_pid(v.details())),
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => {}
        }
        CallbackProgression::Continue
    })
    .unwrap();
    (alive, dead)
}

/// The killed process `victim` has no iceoryx2 node left, dead or alive, while its
/// replacement's node is listed (so the listing does find nodes by pid). Polled for
/// 2 s in case another process's clean-up of it is still under way.
fn assert_nodes_cleaned(victim: u32, replacement: u32) {
    let mut left = (Vec::new(), Vec::new());
    let cleaned = poll(Duration::from_secs(2), || {
        left = nodes_of(victim);
        left.0.is_empty() && left.1.is_empty()
    });
    assert!(
        cleaned,
        "nodes of the killed process (pid {victim}) left: alive {:?}, dead {:?}",
        left.0, left.1
    );
    let (alive, _) = nodes_of(replacement);
    assert!(
        !alive.is_empty(),
        "the node listing does not show the replacement (pid {replacement})"
    );
}

/// A service's heartbeats, read by the test.
struct Heartbeats {
    // Declared before the node it belongs to, so it is dropped first.
    sub: StreamSubscriber<Heartbeat>,
    _node: vibro_ipc::IpcNode,
}

impl Heartbeats {
    fn new(prefix: &str, service: ServiceId) -> Self {
        let names = ServiceNames::new(prefix).unwrap();
        let node = create_node("vct-faults-hb").unwrap();
        let s = Stream::Heartbeat(service);
        let sub =
            StreamSubscriber::create(&node, &names.stream(s), &names.event(s), &stream_config(s))
                .unwrap();
        Self { sub, _node: node }
    }

    /// Waits for a heartbeat that satisfies `want` and returns it.
    fn wait_for(&self, timeout: Duration, mut want: impl FnMut(&Heartbeat) -> bool) -> Heartbeat {
        let mut last = None;
        let mut found = None;
        poll(timeout, || {
            while let Some(h) = self.sub.receive().unwrap() {
                last = Some(*h);
                if found.is_none() && want(&h) {
                    found = Some(*h);
                }
            }
            found.is_some()
        });
        found.unwrap_or_else(|| panic!("no such heartbeat within {timeout:?}; last: {last:?}"))
    }

    /// Waits for the second heartbeat published after `after_ns`: the loop that
    /// published it drained its inputs after the first one, so after `after_ns`
    /// (each wake-up drains every input, then looks at the heartbeat timer).
    fn wait_drained(&self, after_ns: u64, timeout: Duration) -> Heartbeat {
        let mut after = 0;
        self.wait_for(timeout, |h| {
            after += u32::from(h.publish_ns > after_ns);
            after >= 2
        })
    }
}

/// Every record of a log, in file order.
fn records(path: &Path) -> Vec<Record> {
    Reader::open(path)
        .unwrap()
        .map(|r| r.unwrap())
        .collect::<Vec<_>>()
}

/// The `/compensated` blocks of a log with the recorder's receive times (the MCAP
/// publish time; docs/logs.md, "Time"), in file order.
fn compensated(recs: &[Record]) -> Vec<(u64, CompensatedBlock)> {
    recs.iter()
        .filter_map(|r| match &r.message {
            Message::CompensatedBlock(b) if &*r.topic == "/compensated" => {
                Some((r.publish_time_ns, *b))
            }
            _ => None,
        })
        .collect()
}

/// End of a block's last sample interval, ns (the staleness rule's `end`).
fn block_end_ns(b: &CompensatedBlock) -> u64 {
    b.t0_ns + u64::from(b.count.saturating_sub(1)) * b.sample_period_ns
}

/// The window end of the estimate a block used (`end - age`), ns.
fn estimate_end_ns(b: &CompensatedBlock) -> i128 {
    i128::from(block_end_ns(b)) - i128::from(b.estimate_age_ns)
}

fn channel<'a>(info: &'a vibro_mcap::LogInfo, topic: &str) -> &'a vibro_mcap::ChannelInfo {
    info.channels
        .iter()
        .find(|c| c.topic == topic)
        .unwrap_or_else(|| panic!("no channel {topic} in {info:?}"))
}

fn u64_at(v: &serde_json::Value, path: &[&str]) -> u64 {
    let mut x = v;
    for k in path {
        x = &x[*k];
    }
    x.as_u64()
        .unwrap_or_else(|| panic!("{path:?} is not a count in {v}"))
}

/// CPU time (user + system) a process has used, s (/proc/PID/stat).
fn cpu_s(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces), from field 3 on.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: u64 = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    Some(ticks as f64 / hz.max(1) as f64)
}

/// Resident memory of a process, KiB (`VmRSS` in /proc/PID/status).
fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// The estimator is killed while a paced replay streams into `up`: the compensator
/// keeps one output per input block, turns stale (and main-only) once its last
/// estimate is older than `max_estimate_age_s` of data, and compensates fully again
/// with the restarted estimator's estimates. The dead node is cleaned up.
#[test]
fn a_killed_estimator_turns_the_compensation_stale_until_up_restarts_it() {
    let _load = shared_load();
    let dir = Dir::new("est");
    let log = flight_log(&dir, "10");
    // One estimate window (1 s) of data: half the shipped limit, so that a restart of
    // the estimator, which needs a whole new window before its first estimate, shows
    // a stale stretch even when it is quick.
    let max_age_s = 1.0;
    // The estimate stage: its staleness is what a killed estimator shows (the
    // waveform stage does not need the estimator).
    let comp_config = compensator_config_stage(&dir, max_age_s, 10.0, "estimate");
    let p = prefix("e");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let mut up = up(&p, &session, &comp_config, &services_log);
    wait_up(
        &p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut up],
    );
    let victim = child_of(up.pid(), "service estimator", 0).expect("an estimator under up");
    let comp_hb = Heartbeats::new(&p, ServiceId::Compensator);

    let names = ServiceNames::new(&p).unwrap();
    let node = create_node("vct-faults-est").unwrap();
    let estimates = StreamSubscriber::<VibEstimate>::create(
        &node,
        &names.estimate(),
        &names.event(Stream::Estimate),
        &stream_config(Stream::Estimate),
    )
    .unwrap();
    let replay = replay(&p, &log, &["--rate", "2"], &services_log);
    // Kill once the estimator is well into the flight (4 estimates: 2.5 s of data).
    let mut seen = 0;
    assert!(
        poll(Duration::from_secs(30), || {
            while estimates.receive().unwrap().is_some() {
                seen += 1;
            }
            seen >= 4
        }),
        "no estimates\n{}",
        up.stderr()
    );
    drop(estimates);
    drop(node);

    let killed = Instant::now();
    let killed_ns = now_ns();
    kill(victim, libc::SIGKILL);
    // Until `up` restarts it (after 200 ms), its node may be seen dead.
    let mut seen_dead = false;
    poll(Duration::from_millis(150), || {
        seen_dead = !nodes_of(victim).1.is_empty();
        seen_dead
    });
    let mut replacement = 0;
    assert!(
        poll(Duration::from_secs(20), || {
            replacement = child_of(up.pid(), "service estimator", victim).unwrap_or(0);
            replacement != 0
        }),
        "up did not restart the estimator"
    );
    let respawn_s = killed.elapsed().as_secs_f64();
    wait_up(&p, &[ServiceId::Estimator], &mut [&mut up]);
    let restart_s = killed.elapsed().as_secs_f64();
    // The new estimator removed the dead node's resources before it opened its ports
    // (or another process's start-up clean-up did: either way they are gone).
    assert_nodes_cleaned(victim, replacement);

    let r = replay_done(replay, Duration::from_secs(60));
    let accel_sent = u64_at(&r, &["topics", "/accel"]);
    assert_eq!(accel_sent, 250, "{r}");
    comp_hb.wait_for(Duration::from_secs(20), |h| h.received >= accel_sent);
    let (status, out, _) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {status}");
    let report = json_in(&out);
    let role = |name: &str| {
        report["processes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["role"] == name)
            .unwrap()
            .clone()
    };
    assert_eq!(role("estimator")["starts"], 2, "{report}");
    assert_eq!(role("estimator")["crashes"], 1, "{report}");
    assert_eq!(role("compensator")["starts"], 1, "{report}");

    // One output per input block, in order, none lost.
    let recs = records(&session);
    let comp = compensated(&recs);
    let seqs: Vec<u64> = comp.iter().map(|(_, b)| b.input_seq).collect();
    assert_eq!(seqs, (0..accel_sent).collect::<Vec<_>>());
    let info = vibro_mcap::info(&session).unwrap();
    assert_eq!(channel(&info, "/compensated").lost, 0);
    // The restarted estimator counts its estimates from 0 again: a restart.
    assert_eq!(channel(&info, "/estimate").restarts, 1, "{info:?}");

    // The kill on the data time base: the last /vib block received before it.
    let kill_data_ns = recs
        .iter()
        .filter(|r| &*r.topic == "/vib" && r.publish_time_ns <= killed_ns)
        .filter_map(|r| match &r.message {
            Message::VibBlock(v) => Some(v.t0_ns),
            _ => None,
        })
        .max()
        .unwrap();
    let max_age_ns = (max_age_s * 1e9) as i64;
    let is_stale = |k: usize| comp[k].1.flags & cf::VIBRATION_ESTIMATE_STALE != 0;
    // The stale stretch the kill caused. (An estimator held up by a loaded machine
    // may give stale blocks before it too: counted, not failed.)
    let s = (0..comp.len())
        .find(|&k| is_stale(k) && block_end_ns(&comp[k].1) > kill_data_ns)
        .expect("no stale block after the kill");
    let e = (s..comp.len())
        .find(|&k| !is_stale(k))
        .unwrap_or(comp.len());
    let stale_before_kill = (0..s).filter(|&k| is_stale(k)).count();
    assert!(e < comp.len(), "the compensation never recovered");
    let before = &comp[s - 1].1;
    let first = &comp[s].1;
    assert_eq!(
        before.flags & cf::MAIN_ONLY,
        0,
        "the block before the stale stretch had an estimate"
    );
    assert!(before.estimate_age_ns <= max_age_ns);
    // Detected on the first block past the limit: within one block (40 ms) of data
    // after the limit, and within two estimate windows (2 s) after the last estimate.
    let block_ns = i64::from(first.count) * first.sample_period_ns as i64;
    assert!(
        first.estimate_age_ns > max_age_ns && first.estimate_age_ns <= max_age_ns + block_ns,
        "first stale block's estimate age {} ns",
        first.estimate_age_ns
    );
    assert!(first.estimate_age_ns <= 2_000_000_000);
    let last_estimate_end = estimate_end_ns(before);
    for (_, b) in &comp[s..e] {
        assert_eq!(
            b.flags & (cf::MAIN_ONLY | cf::ESTIMATE_MISSING),
            cf::MAIN_ONLY,
            "input {}",
            b.input_seq
        );
        assert_eq!(
            estimate_end_ns(b),
            last_estimate_end,
            "the last estimate held"
        );
        for k in 0..b.count as usize {
            assert_eq!(b.a4_g[k], b.a2_g[k], "main error only: a4 = a2");
            assert_eq!((b.det_g[k], b.rand_g[k]), ([0.0; 3], [0.0; 3]));
        }
    }
    // Full compensation again, with the new estimator's (newer) estimates, to the end.
    for (_, b) in &comp[e..] {
        assert_eq!(
            b.flags & (cf::MAIN_ONLY | cf::VIBRATION_ESTIMATE_STALE | cf::ESTIMATE_MISSING),
            0,
            "input {} after the recovery: flags {:#x}",
            b.input_seq,
            b.flags
        );
        assert!(estimate_end_ns(b) > last_estimate_end);
    }
    assert!(
        comp.len() - e >= 25,
        "at least 1 s of data compensated after the recovery"
    );

    let t0 = comp[0].1.t0_ns as f64;
    let data_s = |ns: f64| (ns - t0) * 1e-9;
    eprintln!(
        "FIGURES estimator-kill: rate 2x, max_estimate_age_s {max_age_s}; kill at data {:.2} s, \
         last estimate ends at {:.2} s; first stale block ends at {:.2} s (age {:.3} s, \
         {:.0} ms of data after the limit); stale blocks {} ({:.2} s of data); full \
         compensation again at data {:.2} s; up respawned the estimator after {:.3} s, its \
         first heartbeat after {:.3} s (wall); dead node seen before the restart: {seen_dead}; \
         stale blocks before the kill: {stale_before_kill}",
        data_s(kill_data_ns as f64),
        data_s(last_estimate_end as f64),
        data_s(block_end_ns(first) as f64),
        first.estimate_age_ns as f64 * 1e-9,
        (first.estimate_age_ns - max_age_ns) as f64 * 1e-6,
        e - s,
        (e - s) as f64 * block_ns as f64 * 1e-9,
        data_s(block_end_ns(&comp[e].1) as f64),
        respawn_s,
        restart_s,
    );
}

/// The compensator is killed under `up --record` during a paced replay: `up` restarts
/// it; the recording shows the accelerometer blocks sent while no compensator ran as
/// missing `input_seq`s of /compensated, whose own `seq` starts again at 0.
#[test]
fn a_killed_compensator_leaves_a_visible_gap_in_the_recording() {
    let _load = shared_load();
    let dir = Dir::new("cmp");
    let log = flight_log(&dir, "8");
    let p = prefix("c");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let mut up = up(
        &p,
        &session,
        &repo_path("config/services/compensator.toml"),
        &services_log,
    );
    wait_up(
        &p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut up],
    );
    let victim = child_of(up.pid(), "service compensator", 0).expect("a compensator under up");
    let hb = Heartbeats::new(&p, ServiceId::Compensator);
    let replay = replay(&p, &log, &["--rate", "2"], &services_log);
    // Kill once the compensator has taken 2 s of data (heartbeats from the killed
    // process: its `received` counts this replay's blocks).
    hb.wait_for(Duration::from_secs(30), |h| h.received >= 50);
    let killed = Instant::now();
    let killed_ns = now_ns();
    kill(victim, libc::SIGKILL);
    let mut replacement = 0;
    assert!(
        poll(Duration::from_secs(20), || {
            replacement = child_of(up.pid(), "service compensator", victim).unwrap_or(0);
            replacement != 0
        }),
        "up did not restart the compensator"
    );
    // The new process's first heartbeat: stamped after `up` had reaped the killed one.
    let dead_ns = now_ns();
    hb.wait_for(Duration::from_secs(30), |h| h.publish_ns > dead_ns);
    let restart_s = killed.elapsed().as_secs_f64();
    let restarted_ns = now_ns();
    assert_nodes_cleaned(victim, replacement);

    let r = replay_done(replay, Duration::from_secs(60));
    let (accel_sent, vib_sent) = (
        u64_at(&r, &["topics", "/accel"]),
        u64_at(&r, &["topics", "/vib"]),
    );
    assert_eq!((accel_sent, vib_sent), (200, 400), "{r}");
    assert_eq!(r["undelivered"], 0, "{r}");
    // The restarted compensator has taken the last block.
    hb.wait_drained(now_ns(), Duration::from_secs(20));
    let (status, out, _) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {status}");
    let report = json_in(&out);
    let comp_role = report["processes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["role"] == "compensator")
        .unwrap()
        .clone();
    assert_eq!(
        (&comp_role["starts"], &comp_role["crashes"]),
        (&2.into(), &1.into()),
        "{report}"
    );

    // What `vibro_mcap::info` says: the inputs are continuous; /compensated restarted
    // (its `seq` went back to 0: a restart), no forward gap in its own numbering.
    let info = vibro_mcap::info(&session).unwrap();
    for (topic, n) in [("/accel", accel_sent), ("/vib", vib_sent)] {
        let c = channel(&info, topic);
        assert_eq!(
            (c.messages, c.lost, c.gaps, c.out_of_order),
            (n, 0, 0, 0),
            "{c:?}"
        );
    }
    let c = channel(&info, "/compensated");
    assert_eq!(
        (c.lost, c.gaps, c.out_of_order, c.restarts),
        (0, 0, 0, 1),
        "{c:?}"
    );
    let hb_channel = channel(&info, "/heartbeat/compensator");
    assert_eq!(hb_channel.restarts, 1, "{hb_channel:?}");

    // The gap itself, by `input_seq`: one jump, the blocks in it have no output.
    let recs = records(&session);
    let comp = compensated(&recs);
    assert_eq!(comp.len() as u64, c.messages);
    let jumps: Vec<usize> = (1..comp.len())
        .filter(|&k| comp[k].1.input_seq != comp[k - 1].1.input_seq + 1)
        .collect();
    assert_eq!(jumps.len(), 1, "one gap in input_seq: {jumps:?}");
    let k = jumps[0];
    assert_eq!(comp[0].1.input_seq, 0);
    assert_eq!(comp[comp.len() - 1].1.input_seq, accel_sent - 1);
    let (last_old, first_new) = (&comp[k - 1].1, &comp[k].1);
    assert_eq!(
        last_old.seq,
        k as u64 - 1,
        "the old process numbered from 0"
    );
    assert_eq!(
        first_new.seq, 0,
        "the restarted compensator numbers from 0 again"
    );
    let missing: Vec<u64> = (last_old.input_seq + 1..first_new.input_seq).collect();
    assert!(!missing.is_empty());
    assert_eq!(comp.len() as u64 + missing.len() as u64, accel_sent);
    // `log info` counts and lists them (issue 46, item 6).
    assert_eq!(c.inputs_without_output, missing.len() as u64, "{c:?}");
    assert_eq!(
        c.unanswered.listed,
        [vibro_mcap::SeqRange {
            first: missing[0],
            last: missing[missing.len() - 1]
        }],
        "{c:?}"
    );
    // The blocks without output were published between the kill (or just before it,
    // still queued for the dead process) and the new process's subscription.
    let accel_publish_ns = |seq: u64| {
        recs.iter()
            .find_map(|r| match &r.message {
                Message::AccelBlock(b) if &*r.topic == "/accel" && b.seq == seq => {
                    Some(b.publish_ns)
                }
                _ => None,
            })
            .unwrap()
    };
    for &m in &missing {
        let t = accel_publish_ns(m);
        assert!(
            t + 1_000_000_000 > killed_ns && t < restarted_ns,
            "block {m} published {:.3} s after the kill",
            (t as f64 - killed_ns as f64) * 1e-9
        );
    }
    // The new process has no estimate until the estimator's next publish (history 1
    // on the estimate stream): at most one hop (0.5 s of data) plus its latency.
    let new_blocks = &comp[k..];
    let waiting = new_blocks
        .iter()
        .take_while(|(_, b)| b.flags & cf::ESTIMATE_MISSING != 0)
        .count();
    assert!(
        waiting <= 25,
        "{waiting} blocks without an estimate after the restart"
    );
    assert!(new_blocks[waiting..]
        .iter()
        .all(|(_, b)| b.flags & cf::MAIN_ONLY == 0));
    eprintln!(
        "FIGURES compensator-kill: rate 2x; up restarted it, first heartbeat {restart_s:.3} s \
         after the kill; accel blocks without output: {} (input_seq {}..={}, {:.2} s of \
         data); /compensated: {} messages, info lost {} gaps {} out_of_order {}; first block \
         of the new process: flags {:#x}; blocks before its first estimate: {waiting}",
        missing.len(),
        missing[0],
        missing[missing.len() - 1],
        missing.len() as f64 * 0.04,
        c.messages,
        c.lost,
        c.gaps,
        c.out_of_order,
        first_new.flags,
    );
}

/// The recorder is killed mid-recording: the recovered log holds every message up to
/// its last flushed chunk, at most about one flush interval (1 s) before the kill is
/// missing; a second recorder stopped with SIGTERM lost nothing; the replay went on
/// at its pace although a subscriber of its streams died.
#[test]
fn a_killed_recorder_loses_at_most_the_last_second() {
    let _load = shared_load();
    let dir = Dir::new("rec");
    let log = flight_log(&dir, "10");
    let p = prefix("r");
    let services_log = dir.path("services.log");
    let (killed_path, clean_path) = (dir.path("killed.mcap"), dir.path("clean.mcap"));
    // Two recorders of the rig streams; no services: the recorders are the replay's
    // subscribers. Each is up once it has published a heartbeat (after subscribing),
    // told apart by its uptime.
    let hb = Heartbeats::new(&p, ServiceId::Recorder);
    let recorder = |path: &Path| {
        let mut cmd = spec(&p, Some(path.to_path_buf()), None)
            .command(Role::Recorder)
            .unwrap();
        cmd.args(["--topics", "/vib,/accel,/truth"]);
        let spawned = Instant::now();
        let kid = Kid::spawn_logging(cmd, "recorder", &services_log);
        hb.wait_for(Duration::from_secs(30), |h| {
            h.uptime_ns < spawned.elapsed().as_nanos() as u64
        });
        kid
    };
    let mut victim = recorder(&killed_path);
    let clean = recorder(&clean_path);
    drop(hb);
    // Real time: about 0.7 MB/s, so chunks are closed by the 1 s flush timer rather
    // than by their 1 MiB size.
    let started = Instant::now();
    let replay = replay(&p, &log, &["--rate", "1"], &services_log);
    std::thread::sleep(Duration::from_millis(3500));
    victim.check_alive().unwrap();
    let killed_at_s = started.elapsed().as_secs_f64();
    let killed_ns = now_ns();
    victim.signal(libc::SIGKILL);
    let (status, _, _) = victim.wait(Duration::from_secs(10));
    assert_eq!(status.code(), None, "killed by a signal");
    let r = replay_done(replay, Duration::from_secs(60));
    let replay_s = started.elapsed().as_secs_f64();
    let clean_summary = summary(clean);
    assert_eq!(clean_summary["lost"], 0, "{clean_summary}");

    // The clean stop has every message the replay published.
    let published = |t: &str| u64_at(&r, &["topics", t]);
    for t in ["/vib", "/accel", "/truth"] {
        assert_eq!(
            u64_at(&clean_summary, &["topics", t, "recorded"]),
            published(t),
            "{t}: {clean_summary}"
        );
    }
    let clean_info = vibro_mcap::info(&clean_path).unwrap();
    assert_eq!(clean_info.lost, 0);
    // The dead subscriber's full buffer made the replay wait once (1 s), then the
    // replay removed the dead node and went on at its pace.
    // (Without that clean-up every later /vib message waited 1 s: 70 s here.)
    let undelivered = u64_at(&r, &["undelivered"]);
    assert!(undelivered <= 1, "{r}");
    let span = r["log_span_s"].as_f64().unwrap();
    assert!(
        r["elapsed_s"].as_f64().unwrap() < span + 2.0,
        "the replay was held up by the dead recorder: {r}"
    );

    // The killed recorder's log has no footer; `recover` keeps its complete chunks.
    let damaged = vibro_mcap::info(&killed_path);
    assert!(damaged.is_err(), "a killed recording reads as complete");
    let recovered_path = dir.path("recovered.mcap");
    let rep = vibro_mcap::recover(&killed_path, &recovered_path).unwrap();
    assert!(!rep.input_complete, "{rep:?}");
    assert_eq!(rep.chunks_skipped, 0, "{rep:?}");
    assert!(rep.messages_recovered > 0, "{rep:?}");

    // Every recovered message is one the clean recorder has, and per topic they are a
    // prefix of the stream (nothing missing in the middle).
    let key = |r: &Record| (r.topic.to_string(), r.sequence);
    let reference: std::collections::BTreeMap<(String, u32), u64> = records(&clean_path)
        .iter()
        .map(|r| (key(r), r.publish_time_ns))
        .collect();
    let recovered: std::collections::BTreeSet<(String, u32)> =
        records(&recovered_path).iter().map(key).collect();
    assert_eq!(recovered.len() as u64, rep.messages_recovered);
    for k in &recovered {
        assert!(reference.contains_key(k), "{k:?} is not in the clean log");
    }
    for t in ["/vib", "/accel", "/truth"] {
        let seqs: Vec<u32> = recovered
            .iter()
            .filter(|(topic, _)| topic == t)
            .map(|(_, s)| *s)
            .collect();
        assert!(!seqs.is_empty(), "nothing of {t} recovered");
        assert_eq!(seqs, (0..seqs.len() as u32).collect::<Vec<_>>(), "{t}");
    }
    // What the kill cost: the messages received before it that did not make it.
    let lost_before: Vec<u64> = reference
        .iter()
        .filter(|(k, &t)| t < killed_ns && !recovered.contains(*k))
        .map(|(_, &t)| t)
        .collect();
    let lost_span_s = lost_before
        .iter()
        .min()
        .map_or(0.0, |&t| (killed_ns - t) as f64 * 1e-9);
    let received_before = reference.values().filter(|&&t| t < killed_ns).count();
    assert!(
        lost_span_s <= 1.5,
        "{} messages of the last {lost_span_s:.3} s before the kill are missing",
        lost_before.len()
    );
    eprintln!(
        "FIGURES recorder-kill: rate 1x, killed {killed_at_s:.1} s into the replay; recovered {} \
         messages in {} chunks ({} of {} input bytes valid, {:?}); missing from before the kill: {} \
         of {} messages, the last {lost_span_s:.3} s; clean stop: {} messages, lost 0; replay \
         undelivered {undelivered}, took {replay_s:.2} s for {span:.2} s of log",
        rep.messages_recovered,
        rep.chunks_recovered,
        rep.valid_prefix_bytes,
        rep.input_bytes,
        rep.stop_reason,
        lost_before.len(),
        received_before,
        clean_info.messages,
    );
}

/// A subscriber of `compensated` that never reads: once its buffer (256 blocks) is
/// full, each further block waits the back-pressure timeout (1 s) for it, is counted
/// `undelivered` and reported; the recorder still gets every block, and nothing
/// upstream is lost.
#[test]
fn a_subscriber_that_does_not_read_costs_one_timeout_per_block_and_is_reported() {
    let _load = shared_load();
    let dir = Dir::new("slow");
    // 10.4 s: 260 accelerometer blocks, 4 more than the stuck subscriber's buffer.
    let log = flight_log(&dir, "10.4");
    // Summaries every 0.5 s: the heartbeat's `degraded` looks back to the last one, so
    // the start (no estimate yet) is forgotten before the buffer fills.
    let comp_config = compensator_config(&dir, 2.0, 0.5);
    let p = prefix("s");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let s = spec(&p, Some(session.clone()), Some(comp_config));
    let mut est = start_role(&s, Role::Estimator, &services_log);
    let mut comp = start_role(&s, Role::Compensator, &services_log);
    let mut rec = start_role(&s, Role::Recorder, &services_log);
    wait_up(
        &p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut est, &mut comp, &mut rec],
    );
    let names = ServiceNames::new(&p).unwrap();
    let node = create_node("vct-faults-slow").unwrap();
    let stuck = StreamSubscriber::<CompensatedBlock>::create(
        &node,
        &names.compensated(),
        &names.event(Stream::Compensated),
        &stream_config(Stream::Compensated),
    )
    .unwrap();
    let hb = Heartbeats::new(&p, ServiceId::Compensator);
    let r = replay_done(
        replay(&p, &log, &["--rate", "4"], &services_log),
        Duration::from_secs(60),
    );
    let accel_sent = u64_at(&r, &["topics", "/accel"]);
    assert_eq!(accel_sent, 260, "{r}");
    assert_eq!(
        r["undelivered"], 0,
        "the back-pressure did not reach the replay: {r}"
    );
    let buffer = stream_config(Stream::Compensated).subscriber_buffer as u64;
    let expected_undelivered = accel_sent - buffer;
    // 4 blocks at 1 s each after the replay: wait for the compensator to finish.
    hb.wait_for(Duration::from_secs(30), |h| h.published >= accel_sent);
    // The stuck subscriber holds exactly the first 256 blocks, in order, none
    // overwritten.
    let mut held = Vec::new();
    while let Some(b) = stuck.receive().unwrap() {
        held.push(b.input_seq);
    }
    drop(stuck);
    assert_eq!(held, (0..buffer).collect::<Vec<_>>());

    let rec_s = summary(rec);
    let comp_s = summary(comp);
    let est_s = summary(est);
    assert_eq!(comp_s["undelivered"], expected_undelivered, "{comp_s}");
    assert_eq!(comp_s["published"], accel_sent, "{comp_s}");
    assert_eq!(comp_s["accel"]["received"], accel_sent, "{comp_s}");
    assert_eq!(comp_s["accel"]["lost_messages"], 0, "{comp_s}");
    assert_eq!(est_s["vib"]["lost_messages"], 0, "{est_s}");
    assert_eq!(rec_s["lost"], 0, "{rec_s}");
    assert_eq!(
        rec_s["topics"]["/compensated"]["recorded"], accel_sent,
        "{rec_s}"
    );
    // Reported, not silent: one WARN naming the stream, and the heartbeat after the
    // stall says degraded with no loss or staleness to explain it.
    let log_text = std::fs::read_to_string(&services_log).unwrap();
    assert!(
        log_text.contains("not delivered to it"),
        "no warning in the log:\n{log_text}"
    );

    let recs = records(&session);
    let comp_blocks = compensated(&recs);
    let seqs: Vec<u64> = comp_blocks.iter().map(|(_, b)| b.input_seq).collect();
    assert_eq!(
        seqs,
        (0..accel_sent).collect::<Vec<_>>(),
        "the recorder got every block"
    );
    // Each block past the full buffer waited the timeout (1 s), no more.
    let waits_s: Vec<f64> = comp_blocks[buffer as usize - 1..]
        .windows(2)
        .skip(1)
        .map(|w| (w[1].1.publish_ns - w[0].1.publish_ns) as f64 * 1e-9)
        .collect();
    assert_eq!(waits_s.len() as u64, expected_undelivered - 1);
    for w in &waits_s {
        assert!(*w > 0.95 && *w < 1.5, "waits {waits_s:?}");
    }
    let beats: Vec<Heartbeat> = recs
        .iter()
        .filter_map(|r| match &r.message {
            Message::Heartbeat(h) if &*r.topic == "/heartbeat/compensator" => Some(*h),
            _ => None,
        })
        .collect();
    let stall_start = comp_blocks[buffer as usize].1.publish_ns;
    let after = beats
        .iter()
        .position(|h| h.publish_ns > stall_start)
        .expect("a heartbeat after the stall");
    let (prev, next) = (&beats[after - 1], &beats[after]);
    assert_eq!(next.state, ServiceState::Degraded.code(), "{next:?}");
    assert_eq!((prev.stale, prev.lost), (next.stale, next.lost));
    assert!(
        prev.state != ServiceState::Degraded.code(),
        "running before the stall: {prev:?}"
    );
    let heartbeat_gap_s = (next.publish_ns - prev.publish_ns) as f64 * 1e-9;
    eprintln!(
        "FIGURES slow-consumer: {accel_sent} blocks at 4x, stuck subscriber holds {}; \
         undelivered {}; waits per undelivered block {waits_s:.3?} s; compensator latency \
         p99 {} us (its clock stops before the send); heartbeat silent for {heartbeat_gap_s:.2} s \
         during the stall, then degraded; recorder got {} of {accel_sent}",
        held.len(),
        comp_s["undelivered"],
        u64_at(&comp_s, &["latency", "p99_ns"]) / 1000,
        seqs.len(),
    );
}

/// 10x real time through estimator, compensator and recorder for `VIBROCOMP_SOAK_S`
/// seconds (default 12): nothing lost anywhere, resident memory flat after warm-up,
/// and the compensator's latency histogram filled.
#[test]
fn soak_at_ten_times_real_time_loses_nothing_and_memory_stays_flat() {
    let _load = exclusive_load();
    let soak_s: f64 = std::env::var("VIBROCOMP_SOAK_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(12.0);
    let dir = Dir::new("soak");
    // One pass is 4 s of data (0.4 s at 10x); --loop continues seq and time.
    let log = flight_log(&dir, "4");
    let p = prefix("k");
    let services_log = dir.path("services.log");
    let session = dir.path("session.mcap");
    let s = spec(&p, Some(session.clone()), None);
    let mut est = start_role(&s, Role::Estimator, &services_log);
    let mut comp = start_role(&s, Role::Compensator, &services_log);
    let mut rec = start_role(&s, Role::Recorder, &services_log);
    wait_up(
        &p,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        &mut [&mut est, &mut comp, &mut rec],
    );
    let pids = [est.pid(), comp.pid(), rec.pid()];
    let stop = Arc::new(AtomicBool::new(false));
    let sampler = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let start = Instant::now();
            let mut samples: Vec<(f64, [u64; 3])> = Vec::new();
            while !stop.load(Ordering::Acquire) {
                let rss = pids.map(|pid| rss_kib(pid).unwrap_or(0));
                samples.push((start.elapsed().as_secs_f64(), rss));
                let next = Duration::from_secs(samples.len() as u64);
                while start.elapsed() < next && !stop.load(Ordering::Acquire) {
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
            samples
        })
    };
    let replay = replay(&p, &log, &["--rate", "10", "--loop"], &services_log);
    let t = Instant::now();
    while t.elapsed().as_secs_f64() < soak_s {
        std::thread::sleep(Duration::from_millis(100));
        est.check_alive().unwrap();
        comp.check_alive().unwrap();
        rec.check_alive().unwrap();
    }
    stop.store(true, Ordering::Release);
    let samples = sampler.join().unwrap();
    let cpu = pids.map(|pid| cpu_s(pid).unwrap_or(0.0));
    replay.signal(libc::SIGINT);
    let r = replay_done(replay, Duration::from_secs(30));
    let (accel_sent, vib_sent) = (
        u64_at(&r, &["topics", "/accel"]),
        u64_at(&r, &["topics", "/vib"]),
    );
    assert_eq!(r["undelivered"], 0, "{r}");
    assert!(
        accel_sent as f64 > 0.8 * soak_s * 250.0,
        "not 10x real time: {r}"
    );
    let comp_hb = Heartbeats::new(&p, ServiceId::Compensator);
    comp_hb.wait_for(Duration::from_secs(20), |h| h.received >= accel_sent);
    let est_hb = Heartbeats::new(&p, ServiceId::Estimator);
    est_hb.wait_for(Duration::from_secs(20), |h| h.received >= vib_sent);
    drop((comp_hb, est_hb));
    let rec_s = summary(rec);
    let comp_s = summary(comp);
    let est_s = summary(est);

    for (s, k, sent) in [(&comp_s, "accel", accel_sent), (&est_s, "vib", vib_sent)] {
        assert_eq!(s[k]["received"], sent, "{s}");
        for c in [
            "lost_messages",
            "lost_samples",
            "out_of_order",
            "restarts",
            "malformed",
        ] {
            assert_eq!(s[k][c], 0, "{k}.{c}: {s}");
        }
        assert_eq!(s["undelivered"], 0, "{s}");
    }
    assert_eq!(comp_s["published"], accel_sent, "{comp_s}");
    assert_eq!(rec_s["lost"], 0, "{rec_s}");
    let info = vibro_mcap::info(&session).unwrap();
    assert_eq!(info.lost, 0);
    for (topic, n) in [
        ("/accel", accel_sent),
        ("/vib", vib_sent),
        ("/compensated", accel_sent),
    ] {
        let c = channel(&info, topic);
        assert_eq!((c.messages, c.lost, c.out_of_order), (n, 0, 0), "{c:?}");
    }
    // The latency histogram: every published block recorded, quantiles ordered.
    let lat = &comp_s["latency"];
    let q = |k: &str| u64_at(lat, &[k]);
    assert_eq!(q("count"), accel_sent, "{lat}");
    assert!(
        0 < q("p50_ns") && q("p50_ns") <= q("p99_ns") && q("p99_ns") <= q("max_ns"),
        "{lat}"
    );

    // Memory: the sample after warm-up (3 s: the estimator's windows, the recorder's
    // chunk buffers and zstd contexts, iceoryx2's segments all allocated) against the
    // last one. Allowed: +5 % or +2 MiB, whichever is larger: one chunk the recorder
    // has not yet compressed is up to 1 MiB, and the allocator keeps freed pages.
    let warm = samples
        .iter()
        .position(|(t, _)| *t >= 3.0)
        .expect("a sample after warm-up");
    let (t_warm, rss_warm) = samples[warm];
    let (t_last, rss_last) = samples[samples.len() - 1];
    assert!(t_last > t_warm, "{samples:?}");
    let names = ["estimator", "compensator", "recorder"];
    let mut figures = Vec::new();
    for i in 0..3 {
        let (a, b) = (rss_warm[i], rss_last[i]);
        let allowed = (a / 20).max(2048);
        figures.push(format!(
            "{} {:.1} -> {:.1} MiB (max {:.1})",
            names[i],
            a as f64 / 1024.0,
            b as f64 / 1024.0,
            samples.iter().map(|(_, r)| r[i]).max().unwrap_or(0) as f64 / 1024.0
        ));
        assert!(
            b <= a + allowed,
            "{} grew from {a} KiB at {t_warm:.0} s to {b} KiB at {t_last:.0} s: {samples:?}",
            names[i]
        );
    }
    eprintln!(
        "FIGURES soak: {soak_s} s at 10x ({} passes, {accel_sent} accel + {vib_sent} vib \
         blocks, real-time factor {:.2}); lost 0; RSS at {t_warm:.0} s -> {t_last:.0} s: {}; \
         compensator latency p50 {} us, p99 {} us, max {} us; estimator latency p50 {} us, \
         p99 {} us; recording {} MB; CPU s (estimator, compensator, recorder) {cpu:.1?}",
        r["passes"],
        r["real_time_factor"].as_f64().unwrap_or(0.0),
        figures.join(", "),
        q("p50_ns") / 1000,
        q("p99_ns") / 1000,
        q("max_ns") / 1000,
        u64_at(&est_s, &["latency", "p50_ns"]) / 1000,
        u64_at(&est_s, &["latency", "p99_ns"]) / 1000,
        info.file_bytes / 1_000_000,
    );
}

/// `text` without its terminal colour codes (`ESC [ ... m`).
fn strip_ansi(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for c in chars.by_ref() {
                if c == 'm' {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// Whether process `pid` has ended (gone, or a zombie waiting for its new parent).
fn ended(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Err(_) => true,
        // The state follows the command name in parentheses, which may contain spaces.
        Ok(stat) => stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state == "Z" || state == "X"),
    }
}

/// `vibrocomp up --record` killed with SIGKILL cannot stop its children itself; the
/// kernel sends them SIGTERM as their parent dies (`PR_SET_PDEATHSIG`), so they stop as on
/// Ctrl-C (their log shows the signal taken and their final summary, the recording is
/// finished) instead of running on without a supervisor.
#[test]
fn a_supervisor_killed_with_sigkill_takes_its_services_with_it() {
    let _load = shared_load();
    let dir = Dir::new("fk");
    let p = prefix("fk");
    let rec = dir.path("session.mcap");
    let mut up = bin()
        .args(["up", "--json", "--prefix", &p, "--record"])
        .arg(&rec)
        .arg("--estimator-config")
        .arg(repo_path("config/services/estimator.toml"))
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.path("up.log")).unwrap())
        .spawn()
        .unwrap();
    let names = ServiceNames::new(&p).unwrap();
    let all = [
        ServiceId::Estimator,
        ServiceId::Compensator,
        ServiceId::Recorder,
    ];
    wait_for_heartbeats(&names, &all, Duration::from_secs(30), || Ok(())).unwrap();
    let kids = children(up.id());
    assert_eq!(
        kids.len(),
        3,
        "{kids:?}\nup: {}",
        std::fs::read_to_string(dir.path("up.log")).unwrap_or_default()
    );
    kill(up.id(), libc::SIGKILL);
    up.wait().unwrap();
    // A killed `up` cannot remove its claim file on the prefix (the kernel dropped the
    // lock itself); the test removes the file so that nothing is left behind.
    let claim = vibro_service::supervise::prefix_lock_path(&p);
    assert!(claim.exists(), "{}", claim.display());
    std::fs::remove_file(&claim).unwrap();
    let all_ended = poll(Duration::from_secs(10), || {
        kids.iter().all(|(pid, _)| ended(*pid))
    });
    if !all_ended {
        for (pid, _) in &kids {
            kill(*pid, libc::SIGKILL);
        }
        panic!("children still running 10 s after their supervisor was killed: {kids:?}");
    }
    // Their clean shutdown, in the log they inherited: the signal taken, the final
    // summary line of each.
    let log = std::fs::read_to_string(dir.path("up.log")).unwrap();
    for line in [
        "estimator stopped",
        "compensator stopped",
        "shutting down (a second signal exits at once) signal=15",
    ] {
        assert!(
            strip_ansi(&log).contains(line),
            "no {line:?} in the log:\n{log}"
        );
    }
    // The recorder finished its log (`info` refuses a log without its footer).
    let info = vibro_mcap::info(&rec).unwrap_or_else(|e| panic!("{e}\nlog:\n{log}"));
    assert!(info
        .channels
        .iter()
        .any(|c| c.topic == "/heartbeat/estimator"));
    for (pid, cmd) in &kids {
        let (alive, dead) = nodes_of(*pid);
        assert!(
            alive.is_empty() && dead.is_empty(),
            "{cmd}: nodes left {alive:?} {dead:?}"
        );
    }
}

/// Ctrl-C in a terminal sends SIGINT to the whole process group: `up` and its
/// children; `up` then sends its own SIGTERM to each child. The children take the two
/// as one request (not as "a second signal: exit at once") and stop cleanly.
#[test]
fn ctrl_c_to_the_process_group_stops_every_process_cleanly() {
    use std::os::unix::process::CommandExt;
    let _load = shared_load();
    let p = prefix("fg");
    let up = bin()
        .args(["up", "--json", "--prefix", &p])
        .arg("--estimator-config")
        .arg(repo_path("config/services/estimator.toml"))
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"))
        .process_group(0)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let names = ServiceNames::new(&p).unwrap();
    let both = [ServiceId::Estimator, ServiceId::Compensator];
    wait_for_heartbeats(&names, &both, Duration::from_secs(30), || Ok(())).unwrap();
    // SAFETY: signalling the process group this test created (`up` and its children).
    unsafe { libc::kill(-(up.id() as libc::pid_t), libc::SIGINT) };
    let out = up.wait_with_output().unwrap();
    assert!(out.status.success(), "up exited with {}", out.status);
    let v = json_in(&String::from_utf8_lossy(&out.stdout));
    for r in v["processes"].as_array().unwrap() {
        assert_eq!(r["last_exit"], "exit status: 0", "{v}");
        assert_eq!(r["crashes"], 0, "{v}");
    }
}
