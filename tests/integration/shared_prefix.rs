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
use crate::processes::{children, flight_log, prefix, Dir};
use std::io::Read;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};
use vibro_msgs::{ServiceId, ServiceNames};
use vibro_service::supervise::wait_for_heartbeats;

/// A child of the test, stopped (SIGTERM, then SIGKILL) when dropped.
struct Proc(Option<Child>);

impl Proc {
    fn spawn(mut cmd: Command) -> Proc {
        Proc(Some(
            cmd.stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
        ))
    }

    fn pid(&self) -> u32 {
        self.0.as_ref().map_or(0, Child::id)
    }

    fn signal(&self, sig: libc::c_int) {
        // SAFETY: signalling a child this test started and has not reaped.
        unsafe { libc::kill(self.pid() as libc::pid_t, sig) };
    }

    fn running(&mut self) -> bool {
        self.0
            .as_mut()
            .is_some_and(|c| c.try_wait().ok().flatten().is_none())
    }

    /// Waits up to `timeout` for the exit; `None` if still running (it is then left
    /// for the drop to stop).
    fn wait(&mut self, timeout: Duration) -> Option<(ExitStatus, String, String)> {
        let start = Instant::now();
        while start.elapsed() < timeout {
            if !self.running() {
                let mut c = self.0.take().unwrap();
                let status = c.wait().unwrap();
                let (mut out, mut err) = (String::new(), String::new());
                let _ = c.stdout.take().unwrap().read_to_string(&mut out);
                let _ = c.stderr.take().unwrap().read_to_string(&mut err);
                return Some((status, out, err));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Some(mut c) = self.0.take() {
            // SAFETY: as in `signal`.
            unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGTERM) };
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(10) {
                if let Ok(Some(_)) = c.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn up(prefix: &str, extra: &[&str]) -> Proc {
    let mut cmd = bin();
    cmd.args(["up", "--json", "--prefix", prefix])
        .arg("--estimator-config")
        .arg(repo_path("config/services/estimator.toml"))
        .arg("--compensator-config")
        .arg(repo_path("config/services/compensator.toml"))
        .args(extra);
    Proc::spawn(cmd)
}

fn both_up(prefix: &str) {
    let names = ServiceNames::new(prefix).unwrap();
    let both = [ServiceId::Estimator, ServiceId::Compensator];
    wait_for_heartbeats(&names, &both, Duration::from_secs(30), || Ok(())).unwrap();
}

/// Stops `up` with SIGINT and checks it and its services exited cleanly (ports
/// released); returns its JSON report.
fn stop_up(mut up: Proc) -> serde_json::Value {
    up.signal(libc::SIGINT);
    let (status, out, err) = up.wait(Duration::from_secs(30)).expect("up stops");
    assert!(status.success(), "up exited with {status}\n{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for r in v["processes"].as_array().unwrap() {
        assert_eq!(r["last_exit"], "exit status: 0", "{v}");
    }
    v
}

fn replay(prefix: &str, log: &Path, extra: &[&str]) -> Proc {
    let mut cmd = bin();
    cmd.arg("replay")
        .arg(log)
        .args(["--prefix", prefix, "--json"])
        .args(extra);
    Proc::spawn(cmd)
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
    let Some((status, _, err)) = second.wait(Duration::from_secs(15)) else {
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
        let Some((status, _, err)) = u.wait(Duration::from_secs(15)) else {
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
    let p = prefix("sp3");
    let dir = Dir::new("sp3");
    let log = flight_log(&dir, "20");
    let mut u = up(&p, &[]);
    both_up(&p);
    let mut r = replay(&p, &log, &[]);
    replay_under_way(&p);
    // The whole system goes: `up` and its services stop (SIGTERM via SIGINT to up).
    u.signal(libc::SIGINT);
    let (status, _, err) = u.wait(Duration::from_secs(30)).expect("up stops");
    assert!(status.success(), "{err}");
    let Some((status, out, err)) = r.wait(Duration::from_secs(40)) else {
        panic!("the replay did not end after its system died");
    };
    println!("replay into a dead system: {status}\n{}", err.trim());
    assert!(
        !status.success(),
        "the replay exited 0 though its system died:\n{out}\n{err}"
    );
    assert!(err.contains("has taken") && err.contains("of the"), "{err}");
}

#[test]
fn a_second_lockstepped_replay_into_a_fed_system_is_refused() {
    let p = prefix("sp4");
    let dir = Dir::new("sp4");
    let log = flight_log(&dir, "20");
    let u = up(&p, &[]);
    both_up(&p);
    // The first replay loops until stopped, so it is surely feeding.
    let mut first = replay(&p, &log, &["--loop"]);
    replay_under_way(&p);
    let mut second = replay(&p, &log, &[]);
    let Some((status, out, err)) = second.wait(Duration::from_secs(60)) else {
        panic!("the second replay neither ended nor was refused");
    };
    println!("second replay: {status}\n{}", err.trim());
    assert!(
        !status.success(),
        "a second lock-stepped replay was accepted:\n{out}\n{err}"
    );
    assert!(err.contains("another process already publishes"), "{err}");
    assert!(err.contains(&first.pid().to_string()), "{err}");
    // The first replay is unharmed: still running, and stops cleanly (exit 0).
    assert!(first.running(), "the first replay ended");
    first.signal(libc::SIGTERM);
    let (status, _, err) = first.wait(Duration::from_secs(30)).expect("replay stops");
    assert!(status.success(), "{err}");
    stop_up(u);
}
