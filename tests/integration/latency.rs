//! `vibrocomp latency --json`: runs the three pipelines briefly on real processes and
//! reports every hop of each with zero losses. Timings are not asserted here (they
//! belong to BENCHMARKS.md); the structure, the counts and the losses are.

use crate::common::run_json;

#[test]
fn latency_reports_every_hop_of_three_pipelines_without_loss() {
    let v = run_json(&[
        "latency",
        "--json",
        "--duration-s",
        "2",
        "--warmup-s",
        "0.5",
    ]);
    let runs = v["runs"].as_array().unwrap();
    let names: Vec<&str> = runs
        .iter()
        .map(|r| r["pipeline"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        ["vibrocomp (iceoryx2)", "bare iceoryx2", "Unix sockets"],
        "{v}"
    );
    for r in runs {
        // 2 s at 800 Hz in blocks of 32: 50 blocks, every one answered; 100 vibration
        // blocks of 20 ms and one past the last accelerometer block (the sensors go on,
        // so that the waveform stage covers the last readings).
        assert_eq!(r["accel_blocks_sent"], 50, "{r}");
        assert_eq!(r["vib_blocks_sent"], 101, "{r}");
        assert_eq!(r["compensated_received"], 50, "{r}");
        assert_eq!(r["lost_samples"], 0, "{r}");
        assert_eq!(r["losses"], serde_json::json!([]), "{r}");
        for hop in [
            "rig_to_service",
            "processing",
            "service_to_subscriber",
            "end_to_end",
        ] {
            let h = &r[hop];
            // Blocks whose first sample ends at or after 0.5 s: t0 = (32 k + 1) 1.25 ms,
            // k = 13..49.
            assert_eq!(h["count"], 37, "{hop}: {r}");
            let q: Vec<f64> = ["p50_us", "p90_us", "p99_us", "p999_us", "max_us"]
                .iter()
                .map(|k| h[k].as_f64().unwrap())
                .collect();
            assert!(q[0] > 0.0, "{hop}: {h}");
            assert!(
                q.windows(2).all(|w| w[0] <= w[1]),
                "{hop}: percentiles not ordered: {h}"
            );
        }
        // End to end is at least as long as each of its hops' medians.
        let p50 = |k: &str| r[k]["p50_us"].as_f64().unwrap();
        assert!(p50("end_to_end") >= p50("processing"), "{r}");
        assert!(!r["cpu_percent"].as_array().unwrap().is_empty(), "{r}");
    }
    // The bare baseline moves both streams, as the services do: a forwarder for the
    // accelerometer blocks and a sink for the vibration blocks.
    let bare: Vec<&str> = runs[1]["cpu_percent"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p[0].as_str().unwrap())
        .collect();
    assert_eq!(bare, ["vibration sink", "forwarder", "rig"], "{v}");
    for k in [
        "vs_bare_p50",
        "vs_bare_p99",
        "vs_sockets_p50",
        "vs_sockets_p99",
    ] {
        let x = v["ratios"][k].as_f64().unwrap();
        assert!(x.is_finite() && x > 0.0, "{k}: {v}");
    }
}

/// `latency --view`: the vibrocomp pipeline with the live view and a Foxglove client
/// attached (the synchronous `tungstenite` client, subprotocol `foxglove.sdk.v1`): the
/// client subscribes to every view channel and receives each unit's message for every
/// compensated block, the view drops nothing, and the services still lose nothing.
/// The latency itself belongs to BENCHMARKS.md.
#[test]
fn latency_with_a_connected_viewer_reports_what_the_viewer_got() {
    let v = run_json(&[
        "latency",
        "--json",
        "--no-baselines",
        "--view",
        "--duration-s",
        "2",
        "--warmup-s",
        "0.5",
    ]);
    let r = &v["runs"][0];
    assert_eq!(
        r["pipeline"], "vibrocomp (iceoryx2), live view + 1 client",
        "{v}"
    );
    assert_eq!(r["compensated_received"], 50, "{r}");
    assert_eq!(r["lost_samples"], 0, "{r}");
    assert_eq!(r["losses"], serde_json::json!([]), "{r}");
    let view = &r["view"];
    let units = vibro_view::UNIT_NAMES.len() as u64;
    assert_eq!(
        view["client_channels"],
        vibro_view::topics(vibro_view::UNIT_NAMES).len(),
        "{view}"
    );
    assert!(
        view["client_messages"].as_u64().unwrap() >= 50 * units,
        "{view}"
    );
    let s = &view["view_summary"];
    assert_eq!(s["dropped"], 0, "{s}");
    for unit in vibro_view::UNIT_NAMES {
        assert_eq!(s["published"][format!("/view/{unit}")], 50, "{s}");
    }
    let processes: Vec<&str> = r["cpu_percent"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p[0].as_str().unwrap())
        .collect();
    assert!(processes.contains(&"view"), "{processes:?}");
}

/// `latency --hosts 2`: besides the local pipeline, the services on a second "host"
/// (another iceoryx2 root, two Zenoh bridges over loopback) and the bare Zenoh pair;
/// every accelerometer block answered through both, nothing lost (bridges included).
#[test]
fn latency_across_two_hosts_answers_every_block_through_the_bridges() {
    let v = run_json(&[
        "latency",
        "--json",
        "--duration-s",
        "1",
        "--warmup-s",
        "0.2",
        "--hosts",
        "2",
    ]);
    let runs = v["runs"].as_array().unwrap();
    let names: Vec<&str> = runs
        .iter()
        .map(|r| r["pipeline"].as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 5, "{v}");
    assert_eq!(
        &names[3..],
        [
            "vibrocomp, 2 hosts (iceoryx2 + Zenoh bridges over a Unix socket)",
            "bare Zenoh (2 processes, loopback TCP)"
        ],
        "{v}"
    );
    for r in &runs[3..] {
        // 1 s at 800 Hz in blocks of 32: 25 blocks; those whose first sample ends at
        // or after 0.2 s, t0 = (32 k + 1) 1.25 ms, are k = 5..24.
        assert_eq!(r["accel_blocks_sent"], 25, "{r}");
        assert_eq!(r["compensated_received"], 25, "{r}");
        assert_eq!(r["lost_samples"], 0, "{r}");
        assert_eq!(r["losses"], serde_json::json!([]), "{r}");
        assert_eq!(r["end_to_end"]["count"], 20, "{r}");
    }
    // The bridged pipeline's processes: the services and a bridge on each host.
    let procs: Vec<&str> = runs[3]["cpu_percent"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p[0].as_str().unwrap())
        .collect();
    assert_eq!(
        procs,
        ["estimator", "compensator", "bridge A", "bridge B", "rig"],
        "{v}"
    );
    // The bare Zenoh pair is two processes too, as the bridged hops are.
    let procs: Vec<&str> = runs[4]["cpu_percent"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p[0].as_str().unwrap())
        .collect();
    assert_eq!(procs, ["peer", "rig"], "{v}");
}

/// Issue 31, item 7: absurd values are refused at once, named with their flag and the
/// value in engineering form. Before: `--rate-hz 1e300` hung (no output, over 40 s),
/// `--duration-s 1e300` was accepted, `--warmup-s 1e300` and `--vib-rate-hz 1e-300`
/// printed some 300 digits.
#[test]
fn absurd_latency_values_are_refused_at_once_and_briefly() {
    use std::time::{Duration, Instant};
    for (flag, value) in [
        ("--rate-hz", "1e300"),
        ("--rate-hz", "1e6"),
        ("--duration-s", "1e300"),
        ("--warmup-s", "1e300"),
        ("--vib-rate-hz", "1e-300"),
        ("--vib-rate-hz", "inf"),
    ] {
        let mut child = crate::common::bin()
            .args(["latency", flag, value])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("vibrocomp runs");
        let started = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if started.elapsed() > Duration::from_secs(20) {
                child.kill().unwrap();
                child.wait().unwrap();
                panic!("latency {flag} {value}: still running after 20 s");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!status.success(), "latency {flag} {value} was accepted");
        assert!(err.contains(flag), "{flag} {value}: {err}");
        assert!(
            err.lines().all(|l| l.len() < 120),
            "{flag} {value}: a line of hundreds of characters:\n{err}"
        );
    }
}
