//! [`SystemSpec`]: how to start each [`Role`] of the system as a child process.

use anyhow::Context;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;
use vibro_msgs::ServiceId;
use vibro_service::supervise::{stop_with_parent, Process};

/// One process of the system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    Estimator,
    Compensator,
    Recorder,
    /// The live view (`vibrocomp view`, Foxglove's WebSocket protocol).
    View,
    /// The Zenoh bridge to other hosts (`vibrocomp bridge`, docs/bridge.md).
    Bridge,
}

impl Role {
    pub fn name(self) -> &'static str {
        match self {
            Role::Estimator => "estimator",
            Role::Compensator => "compensator",
            Role::Recorder => "recorder",
            Role::View => "view",
            Role::Bridge => "bridge",
        }
    }

    pub fn service_id(self) -> ServiceId {
        match self {
            Role::Estimator => ServiceId::Estimator,
            Role::Compensator => ServiceId::Compensator,
            Role::Recorder => ServiceId::Recorder,
            // A user interface and a transport: no heartbeat of their own.
            Role::View | Role::Bridge => ServiceId::Monitor,
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
    /// `SCHED_FIFO` priority of the compensator's hot loop (`--realtime-priority`); the
    /// estimator's is one below (at least 1).
    pub realtime_priority: Option<u8>,
    /// Record everything into this log.
    pub record: Option<PathBuf>,
    /// The recorder may replace an existing log (`--force`).
    pub force_record: bool,
    /// Serve the live view to Foxglove on this address.
    pub foxglove: Option<std::net::SocketAddr>,
    /// Ask the services (and the recorder) for their JSON summaries at exit.
    pub json: bool,
    /// The `vibrocomp` executable [default: this process's own].
    pub exe: Option<PathBuf>,
    /// Bridge streams to other hosts with this configuration (`vibrocomp bridge`).
    pub bridge: Option<PathBuf>,
    /// The working directory of the processes [default: this process's]: where they
    /// find `config/iceoryx2.toml`, i.e. which iceoryx2 root ("host") they join.
    pub cwd: Option<PathBuf>,
}

impl SystemSpec {
    /// The roles to start, in order.
    pub fn roles(&self) -> Vec<Role> {
        let mut roles = vec![Role::Estimator, Role::Compensator];
        if self.record.is_some() {
            roles.push(Role::Recorder);
        }
        if self.foxglove.is_some() {
            roles.push(Role::View);
        }
        if self.bridge.is_some() {
            roles.push(Role::Bridge);
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
                if let Some(p) = self.realtime_priority {
                    // The compensator's blocks are due within a sample period; the
                    // estimator's windows take tens of ms and are due in the hop
                    // (0.5 s): one below, so that it never holds a core a block of
                    // the compensator (or its reader, at the same priority) waits for.
                    let p = if role == Role::Estimator {
                        p.saturating_sub(1).max(1)
                    } else {
                        p
                    };
                    push("--realtime-priority");
                    push(&p.to_string());
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
                if self.force_record {
                    a.push("--force".into());
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
            Role::Bridge => {
                push("bridge");
                if let Some(c) = &self.bridge {
                    a.push("--config".into());
                    a.push(c.clone().into_os_string());
                }
                a.push("--prefix".into());
                a.push(self.prefix.clone().into());
            }
            Role::View => {
                push("view");
                push("--prefix");
                push(&self.prefix);
                if let Some(addr) = self.foxglove {
                    push("--listen");
                    push(&addr.to_string());
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
        if let Some(dir) = &self.cwd {
            c.current_dir(dir);
        }
        stop_with_parent(&mut c);
        Ok(c)
    }

    /// Starts `role` as a [`Process`] with its log (stderr) appended to `log`.
    pub fn spawn(&self, role: Role, log: Option<&Path>) -> anyhow::Result<Process> {
        Process::spawn(self.command(role)?, role.name(), log)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strings(a: Vec<OsString>) -> Vec<String> {
        a.into_iter()
            .map(|s| s.to_string_lossy().into_owned())
            .collect()
    }

    #[test]
    fn the_estimator_runs_one_priority_below_the_compensator() {
        let spec = SystemSpec {
            prefix: "p/".into(),
            mode: Some("spin".into()),
            realtime_priority: Some(1),
            json: true,
            ..SystemSpec::default()
        };
        assert_eq!(
            strings(spec.args(Role::Compensator)),
            [
                "service",
                "compensator",
                "--prefix",
                "p/",
                "--mode",
                "spin",
                "--realtime-priority",
                "1",
                "--json"
            ]
        );
        // One below 1 is still 1, the lowest SCHED_FIFO priority.
        assert_eq!(
            strings(spec.args(Role::Estimator))[6..8],
            ["--realtime-priority", "1"]
        );
        let spec = SystemSpec {
            realtime_priority: Some(50),
            ..spec
        };
        assert_eq!(strings(spec.args(Role::Estimator))[7], "49");
    }

    #[test]
    fn the_roles_follow_what_is_asked() {
        let mut spec = SystemSpec {
            prefix: "p/".into(),
            record: Some("out.mcap".into()),
            force_record: true,
            estimator_config: Some("e.toml".into()),
            ..SystemSpec::default()
        };
        assert_eq!(
            spec.roles(),
            [Role::Estimator, Role::Compensator, Role::Recorder]
        );
        assert_eq!(
            strings(spec.args(Role::Recorder)),
            [
                "record",
                "out.mcap",
                "--force",
                "--prefix",
                "p/",
                "--estimator-config",
                "e.toml"
            ]
        );
        spec.record = None;
        spec.bridge = Some("bridge.toml".into());
        assert_eq!(
            spec.roles(),
            [Role::Estimator, Role::Compensator, Role::Bridge]
        );
        assert_eq!(
            strings(spec.args(Role::Bridge)),
            ["bridge", "--config", "bridge.toml", "--prefix", "p/"]
        );
    }
}
