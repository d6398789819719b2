//! Two "hosts" on one machine (`demo --hosts 2`, `latency --hosts 2`, the tests): two
//! iceoryx2 roots with their own shared-memory file prefixes, so that nothing is shared
//! in memory, joined only by two Zenoh bridges over a Unix socket in a directory only
//! this user can enter (docs/bridge.md, "Who may connect": plain TCP would let in any
//! local user).
//!
//! Host A is the rig's (replay, recorder), host B the compute host (estimator,
//! compensator). A process joins a host by running in its folder, where
//! `config/iceoryx2.toml` names the host's root; this process joins host A with
//! `vibro_ipc::use_config_file`.

use anyhow::Context;
use std::path::{Path, PathBuf};
use vibro_msgs::{ServiceId, Stream};

/// What the rig's host sends to the compute host.
pub const RIG_TO_COMPUTE: [Stream; 2] = [Stream::Vib, Stream::Accel];

/// What the compute host sends back: the outputs, and the heartbeats, progress and log
/// lines of its services (so that the rig's host can wait for them, lock-step a replay
/// and record them).
pub fn compute_to_rig() -> Vec<Stream> {
    let mut s = vec![Stream::Estimate, Stream::Compensated];
    for id in [ServiceId::Estimator, ServiceId::Compensator] {
        s.push(Stream::Heartbeat(id));
        s.push(Stream::Progress(id));
        s.push(Stream::Log(id));
    }
    s
}

/// One host: its folder (the working directory of its processes) and its root.
#[derive(Debug, Clone)]
pub struct Host {
    pub dir: PathBuf,
    /// The prefix of its files in /dev/shm (iceoryx2's `global.prefix`).
    pub shm_prefix: String,
    /// The iceoryx2 root (`root-path`), removed when the hosts are dropped.
    pub root: PathBuf,
    /// `{dir}/config/iceoryx2.toml`.
    pub iceoryx_config: PathBuf,
    /// Its bridge's configuration.
    pub bridge_config: PathBuf,
}

/// Host A (rig) and host B (compute), their bridges' files written.
#[derive(Debug)]
pub struct TwoHosts {
    pub a: Host,
    pub b: Host,
    /// The endpoint host B's bridge listens on: `unixsock-stream/{socket_dir}/b.sock`.
    pub endpoint_b: String,
    /// The directory of that socket (made mode 0700 by the bridges, removed when the
    /// hosts are dropped).
    pub socket_dir: PathBuf,
}

/// A TCP port on 127.0.0.1 that nothing listens on now.
pub fn free_port() -> anyhow::Result<u16> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").context("finding a free port")?;
    Ok(l.local_addr()?.port())
}

fn quoted(streams: &[Stream]) -> String {
    streams
        .iter()
        .map(|s| format!("{:?}", s.suffix()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// A bridge configuration file's text.
pub fn bridge_toml(
    prefix: &str,
    key_prefix: &str,
    endpoint: (&str, &str),
    export: &[Stream],
    import: &[Stream],
) -> String {
    let (which, ep) = endpoint;
    format!(
        "prefix = {prefix:?}\nkey_prefix = {key_prefix:?}\n\n[zenoh]\nmode = \"peer\"\n{which} = [{ep:?}]\nconnect_timeout_s = 10.0\n\n[export]\nstreams = [{}]\n\n[import]\nstreams = [{}]\nqueue_depth = 1024\n",
        quoted(export),
        quoted(import)
    )
}

impl TwoHosts {
    /// Creates the two folders under `base` (absolute), their iceoryx2 configs (roots
    /// under /tmp named by `tag`, which must be short and unique) and bridge files for
    /// the system `prefix`.
    pub fn create(base: &Path, tag: &str, prefix: &str) -> anyhow::Result<Self> {
        // Short, under /tmp: a socket's path holds at most 107 bytes.
        let socket_dir = std::env::temp_dir().join(format!("zenoh-{tag}"));
        let endpoint_b = format!("unixsock-stream/{}/b.sock", socket_dir.display());
        let key_prefix = format!("vibrocomp/{}", tag.trim_end_matches('/'));
        let back = compute_to_rig();
        let make = |name: &str, export: &[Stream], import: &[Stream], ep: (&str, &str)| {
            let dir = base.join(format!("host-{name}"));
            vibro_files::create_dir(&dir.join("config"))
                .with_context(|| format!("creating {}", dir.display()))?;
            let root = std::env::temp_dir().join(format!("iox2-{tag}-{name}"));
            let iceoryx_config = dir.join("config/iceoryx2.toml");
            let shm_prefix = format!("{tag}{name}_");
            vibro_files::write_bytes(
                &iceoryx_config,
                true,
                format!(
                    "[global]\nroot-path = \"{}/\"\nprefix = \"{shm_prefix}\"\n",
                    root.display()
                )
                .as_bytes(),
            )
            .with_context(|| format!("writing {}", iceoryx_config.display()))?;
            let bridge_config = dir.join("bridge.toml");
            vibro_files::write_bytes(
                &bridge_config,
                true,
                bridge_toml(prefix, &key_prefix, ep, export, import).as_bytes(),
            )
            .with_context(|| format!("writing {}", bridge_config.display()))?;
            anyhow::Ok(Host {
                dir,
                shm_prefix,
                root,
                iceoryx_config,
                bridge_config,
            })
        };
        let b = make("b", &back, &RIG_TO_COMPUTE, ("listen", &endpoint_b))?;
        let a = make("a", &RIG_TO_COMPUTE, &back, ("connect", &endpoint_b))?;
        Ok(Self {
            a,
            b,
            endpoint_b,
            socket_dir,
        })
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        // The roots hold only the files of nodes and services that are gone by now,
        // and /dev/shm iceoryx2's management segment of each prefix (which it keeps
        // for the next process of that prefix: there is none). The socket's directory
        // holds the socket and Zenoh's lock file.
        let _ = std::fs::remove_dir_all(&self.socket_dir);
        for h in [&self.a, &self.b] {
            let _ = std::fs::remove_dir_all(&h.root);
            if let Ok(entries) = std::fs::read_dir("/dev/shm") {
                for e in entries.flatten() {
                    if e.file_name().to_string_lossy().starts_with(&h.shm_prefix) {
                        let _ = std::fs::remove_file(e.path());
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bridge_configuration_names_its_endpoint_and_streams() {
        let text = bridge_toml(
            "p/",
            "vibrocomp/t",
            ("listen", "unixsock-stream//tmp/zenoh-t/b.sock"),
            &RIG_TO_COMPUTE,
            &[Stream::Estimate],
        );
        assert_eq!(
            text,
            "prefix = \"p/\"\nkey_prefix = \"vibrocomp/t\"\n\n[zenoh]\nmode = \"peer\"\n\
             listen = [\"unixsock-stream//tmp/zenoh-t/b.sock\"]\nconnect_timeout_s = 10.0\n\n[export]\n\
             streams = [\"vib\", \"accel\"]\n\n[import]\nstreams = [\"estimate\"]\n\
             queue_depth = 1024\n"
        );
    }

    #[test]
    fn the_compute_host_sends_back_outputs_and_each_service_s_status() {
        let back = compute_to_rig();
        assert_eq!(back.len(), 2 + 2 * 3);
        assert!(back.contains(&Stream::Heartbeat(ServiceId::Compensator)));
        assert!(!back.contains(&Stream::Accel));
    }
}
