//! The built `vibro-estimator` binary as a separate process: it starts, publishes its
//! heartbeat, stops with exit code 0 on SIGTERM and prints its JSON summary.

use crate::support::{prefix, wait_until};
use std::io::Read;
use std::process::{Command, Stdio};
use std::time::Duration;
use vibro_ipc::{create_node, StreamSubscriber};
use vibro_msgs::{Heartbeat, ServiceId, ServiceNames, Stream};
use vibro_service::data_stream_config;

#[test]
fn the_binary_stops_cleanly_on_sigterm_and_prints_its_summary() {
    let prefix = prefix();
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vct-est-test").unwrap();
    let hb = Stream::Heartbeat(ServiceId::Estimator);
    let heartbeats = StreamSubscriber::<Heartbeat>::create(
        &node,
        &names.stream(hb),
        &names.event(hb),
        &data_stream_config(),
    )
    .unwrap();
    let config = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/services/estimator.toml"
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_vibro-estimator"))
        .args(["--config", config, "--prefix", &prefix, "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Running once its first heartbeat arrives (signal handlers are in place by then).
    let up = wait_until(Duration::from_secs(10), || {
        heartbeats.receive().unwrap().is_some()
    });
    if !up {
        let _ = child.kill();
        let out = child.wait_with_output().unwrap();
        panic!(
            "no heartbeat; stderr: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let pid = child.id() as libc::pid_t;
    // SAFETY: sending a signal to our own child process.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0);
    let mut status = None;
    assert!(
        wait_until(Duration::from_secs(5), || {
            status = child.try_wait().unwrap();
            status.is_some()
        }),
        "still running 5 s after SIGTERM"
    );
    let mut stdout = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert!(
        status.unwrap().success(),
        "exit {:?}; stderr: {stderr}",
        status
    );
    let json = stdout.trim();
    assert!(json.starts_with('{') && json.ends_with('}'), "{json}");
    assert!(json.contains("\"service\":\"estimator\""), "{json}");
    assert!(json.contains("\"heartbeats\":"), "{json}");
    assert!(stderr.contains("estimator running"), "{stderr}");
}
