//! The running system as child processes of this executable: the estimator, the
//! compensator and the recorder, started as `vibrocomp service ...` / `vibrocomp
//! record ...` so that one built binary is all a user needs. Used by `up` (which
//! supervises them) and `demo`.

use anyhow::{bail, Context};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, StreamSubscriber};
use vibro_msgs::{Heartbeat, ServiceId, ServiceNames, Stream};

/// One process of the system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    Estimator,
    Compensator,
    Recorder,
}

impl Role {
    pub fn name(self) -> &'static str {
        match self {
            Role::Estimator => "estimator",
            Role::Compensator => "compensator",
            Role::Recorder => "recorder",
        }
    }

    pub fn service_id(self) -> ServiceId {
        match self {
            Role::Estimator => ServiceId::Estimator,
            Role::Compensator => ServiceId::Compensator,
            Role::Recorder => ServiceId::Recorder,
        }
    }
}

/// How to start the system's processes.
#[derive(Debug, Clone, Default)]
pub struct SystemSpec {
    pub prefix: String,
    pub estimator_config: Option<PathBuf>,
    pub compensator_config: Option<PathBuf>,
    /// `event` or `spin` for both services.
    pub mode: Option<String>,
    /// Record everything into this log.
    pub record: Option<PathBuf>,
    /// Ask the services (and the recorder) for their JSON summaries at exit.
    pub json: bool,
    /// The `vibrocomp` executable [default: this process's own].
    pub exe: Option<PathBuf>,
}

impl SystemSpec {
    /// The roles to start, in order.
    pub fn roles(&self) -> Vec<Role> {
        let mut roles = vec![Role::Estimator, Role::Compensator];
        if self.record.is_some() {
            roles.push(Role::Recorder);
        }
        roles
    }

    /// The arguments of `vibrocomp` that start `role`.
    pub fn args(&self, role: Role) -> Vec<OsString> {
        let mut a: Vec<OsString> = Vec::new();
        let mut push = |s: &str| a.push(s.into());
        match role {
            Role::Estimator | Role::Compensator => {
                push("service");
                push(role.name());
                push("--prefix");
                push(&self.prefix);
                if let Some(m) = &self.mode {
                    push("--mode");
                    push(m);
                }
                let config = if role == Role::Estimator {
                    &self.estimator_config
                } else {
                    &self.compensator_config
                };
                if let Some(c) = config {
                    a.push("--config".into());
                    a.push(c.clone().into_os_string());
                }
            }
            Role::Recorder => {
                push("record");
                if let Some(out) = &self.record {
                    a.push(out.clone().into_os_string());
                }
                a.push("--prefix".into());
                a.push(self.prefix.clone().into());
                for (flag, c) in [
                    ("--estimator-config", &self.estimator_config),
                    ("--compensator-config", &self.compensator_config),
                ] {
                    if let Some(c) = c {
                        a.push(flag.into());
                        a.push(c.clone().into_os_string());
                    }
                }
            }
        }
        if self.json {
            a.push("--json".into());
        }
        a
    }

    /// A `Command` for `role`: this executable with its arguments.
    pub fn command(&self, role: Role) -> anyhow::Result<Command> {
        let exe = match &self.exe {
            Some(exe) => exe.clone(),
            None => std::env::current_exe().context("locating the vibrocomp executable")?,
        };
        let mut c = Command::new(exe);
        c.args(self.args(role));
        stop_with_parent(&mut c);
        Ok(c)
    }
}

/// Makes the child receive SIGTERM when the thread that starts it ends, so that a
/// supervisor killed with SIGKILL (which cannot clean up) does not leave its services
/// running: they stop as on Ctrl-C, releasing their ports (Linux
/// `PR_SET_PDEATHSIG`). The signal follows the *thread* that forked: `up` starts its
/// children from tokio worker threads, which live as long as the runtime, and `demo`
/// and `latency` from the main thread. A parent that died before the child set the
/// signal is caught by comparing the parent's pid.
fn stop_with_parent(c: &mut Command) {
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

/// Waits until each of `services` has published a heartbeat under `names` (their
/// ports then exist), or fails after `timeout` naming the ones that did not.
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

/// A child process that is stopped (SIGTERM, then SIGKILL) when dropped.
pub struct Process {
    pub role: Role,
    child: Option<Child>,
}

/// What a stopped process left.
#[derive(Debug)]
pub struct Exit {
    pub role: Role,
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
            self.role.name(),
            self.code
        );
        let start = self
            .stdout
            .find('{')
            .with_context(|| format!("the {} printed no JSON summary", self.role.name()))?;
        serde_json::from_str(&self.stdout[start..])
            .with_context(|| format!("the {}'s summary", self.role.name()))
    }
}

impl Process {
    /// Starts `role` with its stdout captured (the JSON summary) and its log (stderr)
    /// appended to `log` (inherited without one).
    pub fn spawn(spec: &SystemSpec, role: Role, log: Option<&Path>) -> anyhow::Result<Self> {
        let stderr = match log {
            Some(p) => Stdio::from(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(p)
                    .with_context(|| format!("opening the log {}", p.display()))?,
            ),
            None => Stdio::inherit(),
        };
        let child = spec
            .command(role)?
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .with_context(|| format!("starting the {}", role.name()))?;
        Ok(Self {
            role,
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
                bail!(
                    "the {} exited early ({status}); see its log",
                    self.role.name()
                );
            }
        }
        Ok(())
    }

    /// SIGTERM, then waits up to `timeout` (SIGKILL after it) and collects the output.
    pub fn stop(mut self, timeout: Duration) -> anyhow::Result<Exit> {
        let Some(child) = self.child.take() else {
            bail!("{} already stopped", self.role.name());
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
            role: self.role,
            code: out.status.code(),
            stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        })
    }
}

/// Sends SIGTERM to `child`.
pub fn terminate(child: &Child) {
    // SAFETY: signalling our own child by its pid.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
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
