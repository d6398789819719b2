//! Two systems, or two feeders, on one service prefix (issue "Reliability, round two",
//! item 8), through the real processes, each test on its own prefix:
//!
//! - a second `vibrocomp up` on a live prefix is refused (exit 1, naming the running
//!   services and their pids), and the running system goes on untouched;
//! - `up --record` to a path that cannot be written is refused before anything starts;
//! - a lock-stepped replay whose system dies mid-way fails, saying how much the
//!   services did not take;
//! - a second lock-stepped replay into a system another replay is feeding is refused.
//!
//! Every process is stopped by the test (SIGINT / SIGTERM, SIGKILL on drop after
//! 10 s), so nothing is left running and every port is released.

use crate::common::{bin, repo_path};
use crate::processes::{children, flight_log, kill, poll, prefix, Dir, Kid};
use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::time::{Duration, Instant};
use vibro_msgs::{ServiceId, ServiceNames};
use vibro_service::supervise::wait_for_heartbeats;

fn up(prefix: &str, extra: &[&str]) -> Kid {
    let mut cmd = bin();
    cmd.args(["up", "--json", "--prefix", prefix])
        .arg("--estimator-config")
        .arg(repo_path("config/services/estimator.toml"))
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"))
        .args(extra);
    Kid::spawn(cmd, "up")
}

fn both_up(prefix: &str) {
    let names = ServiceNames::new(prefix).unwrap();
    let both = [ServiceId::Estimator, ServiceId::Compensator];
    wait_for_heartbeats(&names, &both, Duration::from_secs(30), || Ok(())).unwrap();
}

/// A scratch folder `tag`, a simulated flight log of `seconds` in it, and `up` on the
/// prefix `tag` with both services up: (prefix, folder, log, up).
fn system_and_log(tag: &str, seconds: &str) -> (String, Dir, PathBuf, Kid) {
    let p = prefix(tag);
    let dir = Dir::new(tag);
    let log = flight_log(&dir, seconds);
    let up = up(&p, &[]);
    both_up(&p);
    (p, dir, log, up)
}

/// Stops `up` with SIGINT and checks that it exited 0; returns its stdout.
fn sigint_up(up: &mut Kid) -> String {
    let (status, out, err) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up exited with {status}\n{err}");
    out
}

/// Stops `up` with SIGINT and checks it and its services exited cleanly (ports
/// released); returns its JSON report.
fn stop_up(mut up: Kid) -> serde_json::Value {
    let out = sigint_up(&mut up);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for r in v["processes"].as_array().unwrap() {
        assert_eq!(r["last_exit"], "exit status: 0", "{v}");
    }
    v
}

fn replay(prefix: &str, log: &Path, extra: &[&str]) -> Kid {
    let mut cmd = bin();
    cmd.arg("replay")
        .arg(log)
        .args(["--prefix", prefix, "--json"])
        .args(extra);
    Kid::spawn(cmd, "replay")
}

/// Waits until the estimator has taken at least one block (the replay is under way).
fn replay_under_way(prefix: &str) {
    let names = ServiceNames::new(prefix).unwrap();
    let node = vibro_ipc::create_node("vct-sp-watch").unwrap();
    let sub = vibro_ipc::StreamSubscriber::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        vibro_msgs::Stream::Progress(ServiceId::Estimator),
    )
    .unwrap();
    let start = Instant::now();
    loop {
        if let Some(h) = sub.receive().unwrap() {
            if h.received > 0 {
                return;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "replay did not start"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_second_up_on_a_live_prefix_is_refused_and_the_first_goes_on() {
    let p = prefix("sp1");
    let first = up(&p, &[]);
    both_up(&p);
    let before = children(first.pid());
    assert_eq!(before.len(), 2, "{before:?}");
    let mut second = up(&p, &[]);
    let Some((status, _, err)) = second.wait_for(Duration::from_secs(15)) else {
        drop(second);
        stop_up(first);
        panic!("a second `up` on a live prefix started (still running after 15 s)");
    };
    assert_eq!(status.code(), Some(1), "{err}");
    assert!(err.contains("already running on prefix"), "{err}");
    // Names the running services by pid.
    for (pid, _) in &before {
        assert!(
            err.contains(&pid.to_string()),
            "pid {pid} not named:\n{err}"
        );
    }
    println!("second up refused: {}", err.trim());
    // The running system is untouched: the same two services, no restart.
    assert_eq!(children(first.pid()), before);
    let v = stop_up(first);
    for r in v["processes"].as_array().unwrap() {
        assert_eq!(r["starts"], 1, "{v}");
    }
}

#[test]
fn up_refuses_a_recording_path_it_cannot_write_before_starting() {
    let p = prefix("sp2");
    let dir = Dir::new("sp2");
    for bad in [
        dir.path("no-such-folder/out.mcap"),
        dir.path(""), // a directory
    ] {
        let mut u = up(&p, &["--record", bad.to_str().unwrap()]);
        let Some((status, _, err)) = u.wait_for(Duration::from_secs(15)) else {
            panic!("`up --record {}` started the system", bad.display());
        };
        assert_eq!(status.code(), Some(1), "{err}");
        assert!(err.contains("--record"), "{err}");
        assert!(!err.contains("system up"), "services were started:\n{err}");
        println!("refused: {}", err.trim());
    }
}

#[test]
fn a_lockstepped_replay_whose_system_dies_fails_with_what_was_not_taken() {
    let (p, _dir, log, mut u) = system_and_log("sp3", "20");
    let mut r = replay(&p, &log, &[]);
    replay_under_way(&p);
    // The whole system goes: `up` and its services stop (SIGTERM via SIGINT to up).
    let stopped = Instant::now();
    sigint_up(&mut u);
    let (status, out, err, _) =
        replay_end(&mut r, Duration::from_secs(40), stopped, "its system died");
    assert!(
        !status.success(),
        "the replay exited 0 though its system died:\n{out}\n{err}"
    );
    assert!(err.contains("has taken") && err.contains("of the"), "{err}");
}

#[test]
fn a_second_lockstepped_replay_into_a_fed_system_is_refused() {
    let (p, _dir, log, u) = system_and_log("sp4", "20");
    // The first replay loops until stopped, so it is surely feeding.
    let mut first = replay(&p, &log, &["--loop"]);
    replay_under_way(&p);
    let mut second = replay(&p, &log, &[]);
    let (status, out, err) = refused_beside(&mut second, &first, Duration::from_secs(60));
    assert!(
        !status.success(),
        "a second lock-stepped replay was accepted:\n{out}\n{err}"
    );
    still_feeding_then_stops(&mut first);
    stop_up(u);
}

/// The `vibrocomp up` children of `pid` that are services (not a `sim` or such).
fn services_of(pid: u32) -> Vec<u32> {
    children(pid)
        .into_iter()
        .filter(|(_, cmd)| cmd.contains("service"))
        .map(|(c, _)| c)
        .collect()
}

fn gone(pid: u32) -> bool {
    // Not there, or a zombie.
    std::fs::read_to_string(format!("/proc/{pid}/stat")).map_or(true, |s| {
        s.rsplit(')')
            .next()
            .is_some_and(|r| r.trim_start().starts_with('Z'))
    })
}

/// Kills `up` and its services with SIGKILL (no clean-up of any kind), then removes
/// what they left: their dead iceoryx2 nodes and `up`'s prefix lock file.
fn kill_system_hard(up: &mut Kid, services: &[u32], prefix: &str) {
    kill(up.pid(), libc::SIGKILL);
    for &s in services {
        kill(s, libc::SIGKILL);
    }
    let _ = up.wait_for(Duration::from_secs(10)).expect("up dies");
    all_gone(
        services,
        Duration::from_secs(10),
        "services survive SIGKILL",
    );
    let node = vibro_ipc::create_node("vct-sp-cleanup").unwrap();
    vibro_ipc::cleanup_dead_nodes(&node);
    let _ = std::fs::remove_file(vibro_service::supervise::prefix_lock_path(prefix));
}

/// Kills the system hard ([`kill_system_hard`]) under the lock-stepped replay `r`,
/// which must then fail with the count ([`replay_fails_with_count`], the seconds from
/// the kill).
fn kill_system_under(
    r: &mut Kid,
    up: &mut Kid,
    services: &[u32],
    prefix: &str,
    what: &str,
) -> (String, f64, (String, u64, u64, u64)) {
    let killed = Instant::now();
    kill_system_hard(up, services, prefix);
    replay_fails_with_count(r, killed, what)
}

/// A test's own subscriber on a service's progress stream (drained often: the
/// service's progress publisher would otherwise wait for it).
struct Progress {
    sub: vibro_ipc::StreamSubscriber<vibro_msgs::Heartbeat>,
    _node: vibro_ipc::IpcNode,
}

impl Progress {
    fn open(prefix: &str, service: ServiceId) -> Self {
        let names = ServiceNames::new(prefix).unwrap();
        let node = vibro_ipc::create_node("vct-sp-progress").unwrap();
        let sub =
            vibro_ipc::StreamSubscriber::open(&node, &names, vibro_msgs::Stream::Progress(service))
                .unwrap();
        Self { sub, _node: node }
    }

    /// Drains; returns the largest `received` seen (0 if none).
    fn drain(&self, mut latest: u64) -> u64 {
        while let Some(h) = self.sub.receive().unwrap() {
            latest = latest.max(h.received);
        }
        latest
    }
}

/// Parses "{service} (pid ...) is gone (...): it has taken T of the S messages sent on
/// X; U not processed" into (service, T, S, U).
fn vanished(err: &str) -> (String, u64, u64, u64) {
    let line = err
        .lines()
        .find(|l| l.contains("is gone (") && l.contains("not processed"))
        .unwrap_or_else(|| panic!("no `is gone` error:\n{err}"));
    let at = line.find(" (pid ").unwrap();
    let service = line[..at].rsplit(' ').next().unwrap().to_string();
    let num_after = |key: &str| -> u64 {
        let i = line.rfind(key).unwrap_or_else(|| panic!("{key} in {line}")) + key.len();
        line[i..]
            .split(|c: char| !c.is_ascii_digit())
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let taken = num_after("it has taken ");
    let sent = num_after(&format!("has taken {taken} of the "));
    let unprocessed = line[line.rfind("; ").unwrap() + 2..line.rfind(" not processed").unwrap()]
        .parse()
        .unwrap();
    (service, taken, sent, unprocessed)
}

/// Waits up to `timeout` for the replay `r` to end after its system went (`what`, at
/// `since`); prints how it ended; returns (status, stdout, stderr, seconds since).
fn replay_end(
    r: &mut Kid,
    timeout: Duration,
    since: Instant,
    what: &str,
) -> (ExitStatus, String, String, f64) {
    let Some((status, out, err)) = r.wait_for(timeout) else {
        panic!("the replay did not end after {what}");
    };
    let after_s = since.elapsed().as_secs_f64();
    println!(
        "replay after {what} ({after_s:.2} s): {status}\n{}",
        err.trim()
    );
    (status, out, err, after_s)
}

/// As [`replay_end`] (30 s), for a replay that must fail (exit 1) saying what its gone
/// service did not take: returns its stderr, the seconds, and [`vanished`]'s figures.
fn replay_fails_with_count(
    r: &mut Kid,
    since: Instant,
    what: &str,
) -> (String, f64, (String, u64, u64, u64)) {
    let (status, out, err, after_s) = replay_end(r, Duration::from_secs(30), since, what);
    assert_eq!(status.code(), Some(1), "exited {status}\n{out}\n{err}");
    let figures = vanished(&err);
    (err, after_s, figures)
}

/// Waits up to `timeout` for a second replay started beside the feeding replay
/// `first`; checks that it was refused naming `first`'s pid; returns how it ended.
fn refused_beside(
    second: &mut Kid,
    first: &Kid,
    timeout: Duration,
) -> (ExitStatus, String, String) {
    let Some((status, out, err)) = second.wait_for(timeout) else {
        panic!("a second replay beside another feeder neither ended nor was refused within {timeout:?}");
    };
    println!("second replay: {status}\n{}", err.trim());
    assert!(err.contains("another process already publishes"), "{err}");
    assert!(err.contains(&first.pid().to_string()), "{err}");
    (status, out, err)
}

/// The replay `first` is unharmed: still running, and stops cleanly (exit 0) on
/// SIGTERM.
fn still_feeding_then_stops(first: &mut Kid) {
    assert!(first.running(), "the first replay ended");
    let (status, _, err) = first.stop(libc::SIGTERM, Duration::from_secs(30));
    assert!(status.success(), "{err}");
}

/// Waits up to `timeout` for every one of `services` to be gone; fails saying `what`.
fn all_gone(services: &[u32], timeout: Duration, what: &str) {
    assert!(
        poll(timeout, || services.iter().all(|&s| gone(s))),
        "{what}"
    );
}

#[test]
fn racing_ups_on_one_prefix_start_one_system() {
    for round in 0..3 {
        let p = prefix("sp5");
        // Three at once: all pass their checks before any service is up.
        let mut ups: Vec<Kid> = (0..3).map(|_| up(&p, &[])).collect();
        let mut refused = Vec::new();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(20) && refused.len() < 2 {
            for u in ups.iter_mut() {
                if !u.reaped() && !u.running() {
                    refused.push(u.wait_for(Duration::from_secs(1)).unwrap());
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let running: Vec<usize> = (0..3).filter(|&i| !ups[i].reaped()).collect();
        assert_eq!(
            running.len(),
            1,
            "round {round}: {} `up`s running on one prefix; refused: {refused:?}",
            running.len()
        );
        for (status, _, err) in &refused {
            assert_eq!(status.code(), Some(1), "{err}");
            assert!(
                err.contains("already running on prefix")
                    || err.contains("another `vibrocomp up` (pid"),
                "{err}"
            );
            println!(
                "round {round}: refused: {}",
                err.lines().last().unwrap_or("")
            );
        }
        let winner = ups.remove(running[0]);
        both_up(&p);
        let pid = winner.pid();
        assert_eq!(services_of(pid).len(), 2);
        let lock = vibro_service::supervise::prefix_lock_path(&p);
        assert!(lock.exists(), "{} missing while up runs", lock.display());
        let v = stop_up(winner);
        for r in v["processes"].as_array().unwrap() {
            assert_eq!(r["starts"], 1, "{v}");
        }
        assert!(!lock.exists(), "{} left behind", lock.display());
    }
}

#[test]
fn an_up_killed_hard_leaves_no_claim_on_its_prefix() {
    let p = prefix("sp6");
    let mut first = up(&p, &[]);
    both_up(&p);
    let services = services_of(first.pid());
    assert_eq!(services.len(), 2);
    kill(first.pid(), libc::SIGKILL);
    let _ = first.wait_for(Duration::from_secs(10)).expect("up dies");
    // Its services stop with it (SIGTERM from the kernel on their parent's death).
    all_gone(&services, Duration::from_secs(15), "services outlive up");
    // The lock file may be left; its lock is not: a new `up` starts.
    let second = up(&p, &[]);
    both_up(&p);
    let v = stop_up(second);
    assert_eq!(v["processes"].as_array().unwrap().len(), 2, "{v}");
    assert!(!vibro_service::supervise::prefix_lock_path(&p).exists());
}

#[test]
fn a_paced_replay_beside_another_feeder_is_refused() {
    let (p, _dir, log, u) = system_and_log("sp7", "20");
    let mut first = replay(&p, &log, &["--loop"]);
    replay_under_way(&p);
    let mut second = replay(&p, &log, &["--rate", "1"]);
    let (status, out, err) = refused_beside(&mut second, &first, Duration::from_secs(30));
    assert_eq!(status.code(), Some(1), "{out}\n{err}");
    still_feeding_then_stops(&mut first);
    stop_up(u);
}

/// The services are frozen (SIGSTOP) to read exactly what they have taken, then the
/// whole system is killed with SIGKILL under a lock-stepped replay.
#[test]
fn a_lockstepped_replay_whose_services_are_killed_fails_at_once_with_the_count() {
    let (p, _dir, log, mut u) = system_and_log("sp8", "20");
    let services = services_of(u.pid());
    let est = Progress::open(&p, ServiceId::Estimator);
    let comp = Progress::open(&p, ServiceId::Compensator);
    let mut r = replay(&p, &log, &[]);
    replay_under_way(&p);
    for &s in &services {
        kill(s, libc::SIGSTOP);
    }
    // Frozen: their counters no longer move. A frozen process is alive: the replay
    // must not take it for gone (it waits).
    let (mut e, mut c) = (0, 0);
    let start = Instant::now();
    while start.elapsed() < Duration::from_millis(1500) {
        (e, c) = (est.drain(e), comp.drain(c));
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        r.running(),
        "the replay ended while the services were only frozen"
    );
    let (err, after_s, (service, taken, sent, unprocessed)) = kill_system_under(
        &mut r,
        &mut u,
        &services,
        &p,
        "its services were killed (SIGKILL)",
    );
    assert!(err.contains("no live process publishes"), "{err}");
    let expected = if service == "estimator" { e } else { c };
    assert_eq!(
        taken, expected,
        "{service}: taken, by its own progress\n{err}"
    );
    assert_eq!(unprocessed, sent - taken, "{err}");
    let total = if service == "estimator" { 1000 } else { 500 };
    assert!(sent > taken && sent <= total, "{err}");
    // Two looks 0.25 s apart, plus a publish's back-pressure (1 s), not the 10 s stall.
    assert!(after_s < 5.0, "took {after_s:.2} s");
}

/// The estimator is frozen, then killed, while a lock-stepped replay of `/vib` alone
/// (200 blocks: fit in its buffer of 256) has sent everything and waits for it.
#[test]
fn a_replay_in_its_final_wait_fails_when_its_service_is_killed() {
    let (p, _dir, log, mut u) = system_and_log("sp9", "4");
    let services = services_of(u.pid());
    let estimator = children(u.pid())
        .into_iter()
        .find(|(_, cmd)| cmd.contains("service estimator"))
        .expect("an estimator")
        .0;
    let names = ServiceNames::new(&p).unwrap();
    let node = vibro_ipc::create_node("vct-sp9-vib").unwrap();
    let vib = vibro_ipc::StreamSubscriber::<vibro_msgs::VibBlock>::open(
        &node,
        &names,
        vibro_msgs::Stream::Vib,
    )
    .unwrap();
    let est = Progress::open(&p, ServiceId::Estimator);
    let mut r = replay(&p, &log, &["--topics", "/vib"]);
    // Freeze the estimator at the first block; count all 200 through.
    let mut seen = 0u64;
    let start = Instant::now();
    while seen < 200 {
        while vib.receive().unwrap().is_some() {
            if seen == 0 {
                kill(estimator, libc::SIGSTOP);
            }
            seen += 1;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "{seen} blocks seen"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    std::thread::sleep(Duration::from_millis(500));
    let taken_by_estimator = est.drain(0);
    assert!(
        r.running(),
        "the replay ended before its estimator took everything"
    );
    let (err, after_s, (service, taken, sent, unprocessed)) = kill_system_under(
        &mut r,
        &mut u,
        &services,
        &p,
        "its service was killed in the final wait",
    );
    assert_eq!(service, "estimator", "{err}");
    assert_eq!(sent, 200, "4 s of 50 blocks/s\n{err}");
    assert_eq!(taken, taken_by_estimator, "{err}");
    assert_eq!(unprocessed, 200 - taken_by_estimator, "{err}");
    assert!(after_s < 2.0, "took {after_s:.2} s");
}

/// A paced replay (real time, 20 s) whose system stops after it began: it fails
/// within the stall timeout (10 s) once nobody replaced the services.
#[test]
fn a_paced_replay_whose_system_stops_fails_with_the_count() {
    let (p, _dir, log, mut u) = system_and_log("sp10", "20");
    let mut r = replay(&p, &log, &["--rate", "1"]);
    replay_under_way(&p);
    std::thread::sleep(Duration::from_secs(1));
    let stopped = Instant::now();
    sigint_up(&mut u);
    let (err, after_s, (_, taken, sent, unprocessed)) =
        replay_fails_with_count(&mut r, stopped, "its system stopped");
    assert!(err.contains("none replaced it within 10 s"), "{err}");
    assert!(taken >= 1 && sent > taken, "{err}");
    assert_eq!(unprocessed, sent - taken, "{err}");
    // Within the stall timeout, well before the 20 s of the log are through.
    assert!(after_s < 14.0, "took {after_s:.2} s");
}
