//! The built `vibro-compensator` binary as a separate process: it starts, publishes its
//! heartbeat, exits 0 within a few seconds of SIGTERM and prints its JSON summary.

use crate::support::*;
use std::io::Read;
use std::process::{Command, Stdio};
use std::time::Duration;
use vibro_ipc::{create_node, StreamSubscriber};
use vibro_msgs::{Heartbeat, ServiceId, ServiceNames, Stream};
use vibro_service::data_stream_config;

#[test]
fn the_binary_exits_cleanly_on_sigterm_and_prints_its_summary() {
    let dir = TempDir::new();
    let prefix = prefix();
    let path = dir.path("compensator.toml");
    std::fs::write(&path, config_text("unused/", "paper", "default", "event")).unwrap();
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vct-cmp-test").unwrap();
    let hb = Stream::Heartbeat(ServiceId::Compensator);
    let heartbeats = StreamSubscriber::<Heartbeat>::create(
        &node,
        &names.stream(hb),
        &names.event(hb),
        &data_stream_config(),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_vibro-compensator"))
        .arg("--config")
        .arg(&path)
        .args(["--prefix", &prefix, "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
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
    // SAFETY: sending a signal to our own child process.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) },
        0
    );
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
        "exit {status:?}; stderr: {stderr}"
    );
    let json = stdout.trim();
    assert!(json.starts_with('{') && json.ends_with('}'), "{json}");
    assert!(json.contains("\"service\":\"compensator\""), "{json}");
    assert!(json.contains("\"mode\":\"paper\""), "{json}");
    assert!(json.contains("\"reload_errors\":0"), "{json}");
    assert!(stderr.contains("compensator running"), "{stderr}");
}

#[test]
fn a_bad_configuration_fails_at_start_naming_file_key_and_value() {
    let dir = TempDir::new();
    let path = dir.path("compensator.toml");
    std::fs::write(
        &path,
        config_text("vct-bad/", "exact", "default", "event")
            .replace("max_estimate_age_s = 2.0", "max_estimate_age_s = -3.0"),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_vibro-compensator"))
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!(
            "{}: max_estimate_age_s = -3: must be finite and 0 < s <= 3600",
            path.display()
        )),
        "{stderr}"
    );
}
