//! A system of services as child processes: started so that they stop with their
//! parent, stopped with SIGTERM and then SIGKILL, watched until their heartbeats show
//! their ports exist, and restarted within limits when they crash. `vibrocomp up`,
//! `demo` and `latency` run the estimator, the compensator and the recorder this way;
//! what to start (the executable and its arguments) is theirs.

#[cfg(feature = "ipc")]
use crate::Shutdown;
use anyhow::{bail, Context};
use serde::Serialize;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
#[cfg(feature = "ipc")]
use tracing::{error, info, warn};
#[cfg(feature = "ipc")]
use vibro_ipc::{cleanup_dead_nodes, create_node, StreamSubscriber};
#[cfg(feature = "ipc")]
use vibro_msgs::{Heartbeat, ServiceId, ServiceNames, Stream};

/// Makes the child receive SIGTERM when the thread that starts it ends, so that a
/// supervisor killed with SIGKILL (which cannot clean up) does not leave its services
/// running: they stop as on Ctrl-C, releasing their ports (Linux
/// `PR_SET_PDEATHSIG`). The signal follows the *thread* that forked: `up` starts its
/// children from tokio worker threads, which live as long as the runtime, and `demo`
/// and `latency` from the main thread. A parent that died before the child set the
/// signal is caught by comparing the parent's pid.
pub fn stop_with_parent(c: &mut Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: the closure runs in the child between fork and exec and calls only
    // async-signal-safe functions (prctl, getppid, _exit); it allocates nothing.
    unsafe {
        c.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() != parent {
                libc::_exit(0);
            }
            Ok(())
        });
    }
}

#[cfg(feature = "ipc")]
/// Waits until `service`'s heartbeat says it has published `count` messages (the
/// compensator: one block per accelerometer block, the ones its waveform stage held
/// included), at most `timeout`: past it the caller goes on, and what is missing shows
/// in its counts. `alive` is asked between looks.
pub fn wait_for_published(
    names: &ServiceNames,
    service: ServiceId,
    count: u64,
    timeout: Duration,
    mut alive: impl FnMut() -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let node = create_node("vibrocomp-wait").context("iceoryx2 node")?;
    let stream = Stream::Heartbeat(service);
    let heartbeats = StreamSubscriber::<Heartbeat>::open(&node, names, stream)
        .with_context(|| format!("subscribing to {}", names.stream(stream)))?;
    let start = Instant::now();
    while start.elapsed() < timeout {
        while let Some(h) = heartbeats.receive()? {
            if h.published >= count {
                return Ok(());
            }
        }
        alive()?;
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

#[cfg(feature = "ipc")]
/// Waits until each of `services` has published a heartbeat under `names` (their
/// ports then exist), or fails after `timeout` naming the ones that did not.
/// `alive` is asked between looks (to fail early when a child has died).
pub fn wait_for_heartbeats(
    names: &ServiceNames,
    services: &[ServiceId],
    timeout: Duration,
    mut alive: impl FnMut() -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let node = create_node("vibrocomp-watch").context("iceoryx2 node")?;
    let subs = services
        .iter()
        .map(|&s| {
            let stream = Stream::Heartbeat(s);
            StreamSubscriber::<Heartbeat>::open(&node, names, stream)
                .with_context(|| format!("subscribing to {}", names.stream(stream)))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut seen = vec![false; services.len()];
    let start = Instant::now();
    while !seen.iter().all(|&s| s) {
        for (i, sub) in subs.iter().enumerate() {
            while sub.receive()?.is_some() {
                seen[i] = true;
            }
        }
        alive()?;
        if start.elapsed() > timeout {
            let missing: Vec<String> = services
                .iter()
                .zip(&seen)
                .filter(|(_, &s)| !s)
                .map(|(s, _)| names.stream(Stream::Heartbeat(*s)))
                .collect();
            bail!(
                "no heartbeat on {} within {:.0} s",
                missing.join(", "),
                timeout.as_secs_f64()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

#[cfg(feature = "ipc")]
/// A service found running under a prefix by [`running_on`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Running {
    pub service: ServiceId,
    /// The heartbeat stream it was found on.
    pub stream: String,
    /// The process ids of its heartbeat's publishers (alive iceoryx2 nodes).
    pub pids: Vec<u32>,
    /// Whether a heartbeat arrived within the wait (a publisher may also be a hung
    /// process: it still holds the names).
    pub heartbeat_seen: bool,
}

#[cfg(feature = "ipc")]
impl std::fmt::Display for Running {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pids: Vec<String> = self.pids.iter().map(u32::to_string).collect();
        write!(
            f,
            "{} on {} (pid {}{})",
            self.service,
            self.stream,
            if pids.is_empty() {
                "unknown".to_string()
            } else {
                pids.join(", ")
            },
            if self.heartbeat_seen {
                ", heartbeat seen"
            } else {
                ", no heartbeat yet"
            }
        )
    }
}

#[cfg(feature = "ipc")]
/// Which of `services` already run under `names`: a heartbeat publisher of an alive
/// process (dead nodes are cleaned up first), or a heartbeat within `wait`. Returns
/// at once when nobody publishes there; otherwise waits up to `wait` for a heartbeat
/// of each service found.
pub fn running_on(
    names: &ServiceNames,
    services: &[ServiceId],
    wait: Duration,
) -> anyhow::Result<Vec<Running>> {
    let node = create_node("vibrocomp-probe").context("iceoryx2 node")?;
    let cleaned = cleanup_dead_nodes(&node);
    if cleaned > 0 {
        info!(cleaned, "removed the resources of dead iceoryx2 nodes");
    }
    let subs = services
        .iter()
        .map(|&s| {
            let stream = Stream::Heartbeat(s);
            StreamSubscriber::<Heartbeat>::open(&node, names, stream)
                .with_context(|| format!("subscribing to {}", names.stream(stream)))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut found: Vec<Running> = services
        .iter()
        .zip(&subs)
        .map(|(&service, sub)| Running {
            service,
            stream: sub.name().to_string(),
            pids: sub.publisher_pids(),
            heartbeat_seen: false,
        })
        .collect();
    let publishers =
        |subs: &[StreamSubscriber<Heartbeat>]| subs.iter().any(|s| s.publisher_count() > 0);
    if publishers(&subs) {
        let start = Instant::now();
        loop {
            for (r, sub) in found.iter_mut().zip(&subs) {
                while sub.receive()?.is_some() {
                    r.heartbeat_seen = true;
                }
            }
            let waiting = found
                .iter()
                .zip(&subs)
                .any(|(r, s)| !r.heartbeat_seen && s.publisher_count() > 0);
            if !waiting || start.elapsed() > wait {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    Ok(found
        .into_iter()
        .filter(|r| r.heartbeat_seen || !r.pids.is_empty())
        .collect())
}

/// The claim of one `vibrocomp up` on a prefix ([`claim_prefix`]): an exclusive
/// advisory lock (`flock`) on a file named from the prefix, held while this value
/// lives. The kernel releases it when the process dies, so an `up` killed with
/// SIGKILL leaves no stale claim (at most the file, which the next claim reuses).
/// Dropping it removes the file.
#[derive(Debug)]
pub struct PrefixClaim {
    path: std::path::PathBuf,
    // Kept open: the lock lives as long as this descriptor (opened close-on-exec, so
    // the services started meanwhile do not inherit it).
    _file: std::fs::File,
}

/// Another process holds the claim on a prefix ([`claim_prefix`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Claimed {
    pub path: std::path::PathBuf,
    /// The holder's process id, as it wrote it in the file (`None`: not written yet).
    pub pid: Option<u32>,
}

impl PrefixClaim {
    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for PrefixClaim {
    fn drop(&mut self) {
        // Removed while still locked: a process waiting on this file then sees, once
        // it gets the lock, that the path no longer names it, and claims afresh.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// The file that claims `prefix`: `vibrocomp-up-{prefix, / and other non-alphanumerics
/// as _}-{FNV-1a hash of the prefix}.lock` in `$XDG_RUNTIME_DIR` (a per-user tmpfs),
/// else the temporary folder. The hash keeps `a/b` and `a_b` apart.
pub fn prefix_lock_path(prefix: &str) -> std::path::PathBuf {
    let dir = std::env::var_os("XDG_RUNTIME_DIR")
        .map(std::path::PathBuf::from)
        .filter(|d| d.is_absolute() && d.is_dir())
        .unwrap_or_else(std::env::temp_dir);
    let readable: String = prefix
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    // FNV-1a, 64 bit.
    let hash = prefix.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    dir.join(format!("vibrocomp-up-{readable}-{hash:016x}.lock"))
}

/// Claims `prefix` for one system: takes the exclusive lock on
/// [`prefix_lock_path`] without waiting, and writes our pid into the file. `Ok(Err)`
/// when another process holds it (a racing `up`, or one already running), with its
/// pid; `Err` when the file cannot be made or locked at all. Two `up`s started at the
/// same instant both find no system running; only one of them gets the claim.
pub fn claim_prefix(prefix: &str) -> anyhow::Result<std::result::Result<PrefixClaim, Claimed>> {
    use std::io::{Read, Seek, Write};
    use std::os::unix::fs::MetadataExt;
    use std::os::unix::io::AsRawFd;
    let path = prefix_lock_path(prefix);
    // A holder that removes the file on exit may do so between our open and our lock:
    // we would then hold a lock on a file nobody else can find. Checked after locking
    // (the path must still name the locked file), retried if not.
    for _ in 0..100 {
        // Its name is guessable and may be in the shared temporary folder: a link or
        // FIFO planted there is refused, never followed or blocked on (`vibro_files`).
        let mut file = vibro_files::open_lock(&path)
            .with_context(|| format!("opening the prefix lock {}", path.display()))?;
        // SAFETY: flock on a descriptor we own.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            let e = std::io::Error::last_os_error();
            if e.raw_os_error() != Some(libc::EWOULDBLOCK) {
                return Err(e).with_context(|| format!("locking {}", path.display()));
            }
            let mut text = String::new();
            let _ = file.read_to_string(&mut text);
            return Ok(Err(Claimed {
                path,
                pid: text.trim().parse().ok(),
            }));
        }
        let ours = file.metadata()?;
        match std::fs::metadata(&path) {
            Ok(m) if m.ino() == ours.ino() && m.dev() == ours.dev() => {}
            _ => continue, // removed or replaced since we opened it: start again
        }
        file.set_len(0)?;
        file.rewind()?;
        write!(file, "{}", std::process::id())?;
        return Ok(Ok(PrefixClaim { path, _file: file }));
    }
    bail!(
        "could not claim the prefix lock {}: it kept being replaced",
        path.display()
    )
}

/// A child process that is stopped (SIGTERM, then SIGKILL) when dropped.
pub struct Process {
    /// What it is, for messages (`estimator`, `compensator`, `recorder`).
    pub name: &'static str,
    child: Option<Child>,
}

/// What a stopped process left.
#[derive(Debug)]
pub struct Exit {
    pub name: &'static str,
    pub code: Option<i32>,
    /// What it printed on stdout (its `--json` summary).
    pub stdout: String,
}

impl Exit {
    /// The JSON summary it printed, after checking it exited 0.
    pub fn summary(&self) -> anyhow::Result<serde_json::Value> {
        anyhow::ensure!(
            self.code == Some(0),
            "the {} exited with {:?}; see its log",
            self.name,
            self.code
        );
        let start = self
            .stdout
            .find('{')
            .with_context(|| format!("the {} printed no JSON summary", self.name))?;
        serde_json::from_str(&self.stdout[start..])
            .with_context(|| format!("the {}'s summary", self.name))
    }
}

impl Process {
    /// Starts `command` as `name` with its stdout captured (the JSON summary) and its
    /// log (stderr) appended to `log` (inherited without one).
    pub fn spawn(
        mut command: Command,
        name: &'static str,
        log: Option<&Path>,
    ) -> anyhow::Result<Self> {
        let stderr = match log {
            Some(p) => Stdio::from(
                vibro_files::open_append(p)
                    .with_context(|| format!("opening the log {}", p.display()))?,
            ),
            None => Stdio::inherit(),
        };
        let child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .with_context(|| format!("starting the {name}"))?;
        Ok(Self {
            name,
            child: Some(child),
        })
    }

    /// The child's process id (0 once stopped).
    pub fn pid(&self) -> u32 {
        self.child.as_ref().map_or(0, |c| c.id())
    }

    /// Fails if the process has exited.
    pub fn check_alive(&mut self) -> anyhow::Result<()> {
        if let Some(c) = &mut self.child {
            if let Some(status) = c.try_wait()? {
                bail!("the {} exited early ({status}); see its log", self.name);
            }
        }
        Ok(())
    }

    /// SIGTERM, then waits up to `timeout` (SIGKILL after it) and collects the output.
    pub fn stop(mut self, timeout: Duration) -> anyhow::Result<Exit> {
        let Some(child) = self.child.take() else {
            bail!("{} already stopped", self.name);
        };
        terminate(&child);
        let start = Instant::now();
        let mut child = child;
        loop {
            if child.try_wait()?.is_some() {
                break;
            }
            if start.elapsed() > timeout {
                let _ = child.kill();
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let out = child.wait_with_output()?;
        Ok(Exit {
            name: self.name,
            code: out.status.code(),
            stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        })
    }
}

/// Sends SIGTERM to `child`.
pub fn terminate(child: &Child) {
    signal(Some(child.id()), libc::SIGTERM);
}

/// Sends `sig` to our child `pid` (nothing without one).
fn signal(pid: Option<u32>, sig: libc::c_int) {
    if let Some(pid) = pid {
        // SAFETY: signalling our own child by its pid.
        unsafe {
            libc::kill(pid as libc::pid_t, sig);
        }
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            terminate(&c);
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(3) {
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

/// A unique, short prefix for a system that must not meet another (the demo's).
pub fn private_prefix(what: &str) -> String {
    format!("{what}-{}/", std::process::id())
}

/// How often a supervised process may crash before the system is stopped, and how
/// long a stopping one gets.
#[derive(Debug, Clone, Copy)]
pub struct RestartLimits {
    /// Restarts allowed within `window`.
    pub max_restarts: u32,
    pub window: Duration,
    /// Time a stopping process gets before it is killed.
    pub stop_timeout: Duration,
}

/// What happened to one supervised process.
#[derive(Debug, Clone, Serialize)]
pub struct ProcessReport {
    pub role: &'static str,
    pub starts: u32,
    pub crashes: u32,
    pub last_exit: Option<String>,
    pub gave_up: bool,
}

#[cfg(feature = "ipc")]
/// Runs the process `command()` makes until `shutdown`, restarting it when it dies
/// (with a back-off of 0.2 s per crash in the window) unless `restart` is false; too
/// many crashes within the window trigger `shutdown` for the whole system. On
/// shutdown the process gets SIGTERM and `limits.stop_timeout`, then SIGKILL.
pub async fn supervise(
    name: &'static str,
    restart: bool,
    command: impl Fn() -> anyhow::Result<Command>,
    limits: RestartLimits,
    shutdown: Shutdown,
) -> anyhow::Result<ProcessReport> {
    let mut report = ProcessReport {
        role: name,
        starts: 0,
        crashes: 0,
        last_exit: None,
        gave_up: false,
    };
    let mut recent: Vec<Instant> = Vec::new();
    loop {
        // A service's own summary goes to the supervisor's stderr, beside its log:
        // the supervisor's stdout is its own (`up --json` prints one JSON object).
        let mut child = tokio::process::Command::from(command()?)
            .stdout(Stdio::from(std::io::stderr()))
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("starting the {name}"))?;
        report.starts += 1;
        let pid = child.id();
        info!(process = name, pid, "started");
        tokio::select! {
            status = child.wait() => {
                let status = status.with_context(|| format!("waiting for the {name}"))?;
                report.last_exit = Some(status.to_string());
                if shutdown.is_triggered() {
                    break;
                }
                report.crashes += 1;
                warn!(process = name, %status, "exited unexpectedly");
                if !restart {
                    error!("the {name} is not restarted (a new one would replace the log); the services keep running");
                    break;
                }
                let now = Instant::now();
                recent.retain(|t| now.duration_since(*t) < limits.window);
                recent.push(now);
                if recent.len() as u32 > limits.max_restarts {
                    error!(
                        process = name,
                        crashes = recent.len(),
                        window_s = limits.window.as_secs_f64(),
                        "too many crashes: giving up and stopping the system"
                    );
                    report.gave_up = true;
                    shutdown.trigger();
                    break;
                }
                // Backs off a little more after each crash in the window.
                tokio::time::sleep(Duration::from_millis(200 * recent.len() as u64)).await;
            }
            _ = shutdown.triggered() => {
                signal(pid, libc::SIGTERM);
                match tokio::time::timeout(limits.stop_timeout, child.wait()).await {
                    Ok(status) => report.last_exit = status.ok().map(|s| s.to_string()),
                    Err(_) => {
                        warn!(process = name, "did not stop in time: killed");
                        let _ = child.kill().await;
                        report.last_exit = Some("killed".into());
                    }
                }
                break;
            }
        }
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The prefix lock's name is guessable and may be in the shared temporary folder:
    /// a link planted there (by another user, in the issue) is refused, not followed,
    /// and the file it points to keeps its bytes (before: emptied, then our pid).
    #[test]
    fn a_link_planted_at_the_prefix_lock_is_not_followed() {
        let prefix = format!("vct-lock-{}/", std::process::id());
        let lock = prefix_lock_path(&prefix);
        let target = lock.with_extension("target");
        std::fs::write(&target, "root secret.").unwrap();
        let _ = std::fs::remove_file(&lock);
        std::os::unix::fs::symlink(&target, &lock).unwrap();
        let e = claim_prefix(&prefix).err().map(|e| format!("{e:#}"));
        let kept = std::fs::read_to_string(&target).unwrap();
        let _ = std::fs::remove_file(&lock);
        let _ = std::fs::remove_file(&target);
        let e = e.expect("the link was followed");
        assert!(e.contains("is a symbolic link to"), "{e}");
        assert_eq!(kept, "root secret.");
    }
}
