//! Helpers of the tests that run the system as processes (`replay`, `faults`,
//! `counts`, `shared_prefix`): unique service prefixes, scratch folders, simulated
//! flight logs, a process's children, a child process stopped when dropped, and a
//! recorded session of a log replayed through the services.

use crate::common::bin;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

static NEXT: AtomicU32 = AtomicU32::new(0);

fn next() -> u32 {
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A unique, short service prefix per test (tests run in parallel): `vct-{tag}-{pid}-{n}/`.
pub fn prefix(tag: &str) -> String {
    format!("vct-{tag}-{}-{}/", std::process::id(), next())
}

/// A scratch folder, removed when dropped.
pub struct Dir(PathBuf);

impl Dir {
    pub fn new(tag: &str) -> Self {
        let d =
            std::env::temp_dir().join(format!("vibrocomp-{tag}-{}-{}", std::process::id(), next()));
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Dir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A short simulated flight log (the demo's scenario, `seconds` long): 50 vibration
/// blocks (512 samples at 25.6 kHz) and 25 accelerometer blocks (32 samples at 800 Hz)
/// per second of data.
pub fn flight_log(dir: &Dir, seconds: &str) -> PathBuf {
    let out = dir.path("flight.mcap");
    let status = bin()
        .args(["sim", "cyclone-4-short", "--duration-s", seconds, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    out
}

/// The children of a process, with their command lines (from /proc).
/// A free TCP port on 127.0.0.1 (bound, then released for a server to take).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

pub fn children(pid: u32) -> Vec<(u32, String)> {
    let mut out = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return out;
    };
    for t in tasks.flatten() {
        let list = std::fs::read_to_string(t.path().join("children")).unwrap_or_default();
        for c in list
            .split_whitespace()
            .filter_map(|s| s.parse::<u32>().ok())
        {
            let cmd = std::fs::read(format!("/proc/{c}/cmdline")).unwrap_or_default();
            let cmd = String::from_utf8_lossy(&cmd).replace('\0', " ");
            out.push((c, cmd));
        }
    }
    out
}

/// Sends `sig` to `pid`.
pub fn kill(pid: u32, sig: libc::c_int) {
    // SAFETY: signalling a process the test started (directly or through `up`), or
    // its child, still unreaped by its parent at worst.
    unsafe { libc::kill(pid as libc::pid_t, sig) };
}

/// Polls `done` every 10 ms until it holds or `timeout` passes; returns whether it held.
pub fn poll(timeout: Duration, mut done: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    loop {
        if done() {
            return true;
        }
        if start.elapsed() > timeout {
            return false;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// How a [`Kid`] ended: its exit status, stdout and stderr.
pub type Ended = (ExitStatus, String, String);

/// A child process of the test: stdin from /dev/null, stdout to a file, stderr to a
/// file (or appended to a log several processes share). Files, not pipes: a talkative
/// process, or a grandchild holding its stdout, never blocks the test. Dropping it
/// stops it (SIGTERM, then SIGKILL after 10 s), so a failing test leaves nothing
/// running.
pub struct Kid {
    what: String,
    child: Option<Child>,
    stdout: PathBuf,
    stderr: PathBuf,
    _files: Dir,
}

impl Kid {
    /// Starts `cmd` (`what` names it in messages), its stderr to a file of its own.
    pub fn spawn(cmd: Command, what: &str) -> Kid {
        Self::start(cmd, what, None)
    }

    /// Starts `cmd`, its stderr appended to `log`.
    pub fn spawn_logging(cmd: Command, what: &str, log: &Path) -> Kid {
        Self::start(cmd, what, Some(log))
    }

    fn start(mut cmd: Command, what: &str, log: Option<&Path>) -> Kid {
        let files = Dir::new("kid");
        let stdout = files.path("stdout");
        let stderr = log.map_or_else(|| files.path("stderr"), Path::to_path_buf);
        let err = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&stderr)
            .unwrap();
        let child = cmd
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&stdout).unwrap())
            .stderr(err)
            .spawn()
            .unwrap_or_else(|e| panic!("starting the {what}: {e}"));
        Kid {
            what: what.to_string(),
            child: Some(child),
            stdout,
            stderr,
            _files: files,
        }
    }

    /// Its pid (0 once reaped).
    pub fn pid(&self) -> u32 {
        self.child.as_ref().map_or(0, Child::id)
    }

    /// Sends `sig` (unless already reaped).
    pub fn signal(&self, sig: libc::c_int) {
        if let Some(c) = &self.child {
            kill(c.id(), sig);
        }
    }

    /// Still running (not exited, not reaped by [`Kid::wait_for`]).
    pub fn running(&mut self) -> bool {
        self.child
            .as_mut()
            .is_some_and(|c| c.try_wait().ok().flatten().is_none())
    }

    /// Whether [`Kid::wait_for`] (or [`Kid::wait`]) has taken its exit.
    pub fn reaped(&self) -> bool {
        self.child.is_none()
    }

    /// An error if it has exited (for `wait_for_heartbeats`).
    pub fn check_alive(&mut self) -> anyhow::Result<()> {
        if let Some(c) = &mut self.child {
            if let Some(status) = c.try_wait()? {
                anyhow::bail!("the {} exited early ({status})", self.what);
            }
        }
        Ok(())
    }

    /// What it wrote to stderr so far (the whole shared log for
    /// [`Kid::spawn_logging`]).
    pub fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    /// Waits up to `timeout` for the exit; `None` if still running (it is then left
    /// for the drop to stop).
    pub fn wait_for(&mut self, timeout: Duration) -> Option<Ended> {
        assert!(
            self.child.is_some(),
            "the {} was waited for already",
            self.what
        );
        let start = Instant::now();
        while start.elapsed() < timeout {
            if let Some(mut c) = self
                .child
                .take_if(|c| c.try_wait().ok().flatten().is_some())
            {
                let status = c.wait().unwrap();
                let out = std::fs::read_to_string(&self.stdout).unwrap_or_default();
                return Some((status, out, self.stderr()));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        None
    }

    /// Waits up to `timeout` for the exit; after it, kills the process and fails the
    /// test.
    pub fn wait(&mut self, timeout: Duration) -> Ended {
        if let Some(ended) = self.wait_for(timeout) {
            return ended;
        }
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        panic!(
            "the {} did not end within {:.0} s\nstderr:\n{}",
            self.what,
            timeout.as_secs_f64(),
            self.stderr()
        );
    }

    /// Sends `sig`, then [`Kid::wait`]s.
    pub fn stop(&mut self, sig: libc::c_int, timeout: Duration) -> Ended {
        self.signal(sig);
        self.wait(timeout)
    }
}

impl Drop for Kid {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            kill(c.id(), libc::SIGTERM);
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

/// A session: `vibrocomp up --record session` with the services' configurations
/// `estimator` and `compensator`, the log replayed into them (as fast as possible,
/// lock-stepped), and Ctrl-C to `up` to finish the recording.
pub fn recorded_replay(
    log: &Path,
    session: &Path,
    tag: &str,
    estimator: &Path,
    compensator: &Path,
) {
    use vibro_msgs::{ServiceId, ServiceNames};
    let p = prefix(tag);
    let mut cmd = bin();
    cmd.args(["up", "--json", "--prefix", &p, "--record"])
        .arg(session)
        .arg("--estimator-config")
        .arg(estimator)
        .arg("--compensator-config")
        .arg(compensator);
    let mut up = Kid::spawn(cmd, "up");
    let names = ServiceNames::new(&p).unwrap();
    let services = [
        ServiceId::Estimator,
        ServiceId::Compensator,
        ServiceId::Recorder,
    ];
    if let Err(e) = vibro_service::supervise::wait_for_heartbeats(
        &names,
        &services,
        Duration::from_secs(30),
        || up.check_alive(),
    ) {
        panic!("{e:#}\nup stderr:\n{}", up.stderr());
    }
    let replay = bin()
        .arg("replay")
        .arg(log)
        .args(["--prefix", &p, "--json"])
        .output()
        .unwrap();
    assert!(
        replay.status.success(),
        "replay: {}",
        String::from_utf8_lossy(&replay.stderr)
    );
    let (status, _, stderr) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {status}\n{stderr}");
}
