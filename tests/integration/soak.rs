//! `vibrocomp latency --soak --json`: a few seconds of the soak of issue 18, with the
//! estimator at ten times the vibration rate (256 kHz) and `lab diagnose` looping
//! beside the services. Nothing timed is asserted (the latency target lives in
//! BENCHMARKS.md); the counts, the losses, the load's start and stop, the memory
//! figures and the histogram's total are, each against a count known by construction.

use crate::common::{bin, repo_path, run_json};
use crate::processes::{prefix, Dir};
use serde_json::Value;

/// Processes whose command line holds `needle` (from /proc).
fn processes_mentioning(needle: &str) -> Vec<(u32, String)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let cmd = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
        let cmd = String::from_utf8_lossy(&cmd).replace('\0', " ");
        if cmd.contains(needle) {
            out.push((pid, cmd));
        }
    }
    out
}

fn u(v: &Value, path: &[&str]) -> u64 {
    let mut x = v;
    for k in path {
        x = &x[*k];
    }
    x.as_u64()
        .unwrap_or_else(|| panic!("{path:?} is not a count in {v}"))
}

#[test]
fn a_short_soak_under_load_answers_every_block_and_leaves_nothing_running() {
    let dir = Dir::new("soak");
    // A private copy of the campaign: its path tells this test's load processes apart.
    let campaign = dir.path("walkthrough.csv");
    std::fs::copy(
        repo_path("shared/vibro-lab/tests/data/walkthrough-14-rows.csv"),
        &campaign,
    )
    .unwrap();
    let p = prefix("sk1");
    let v: Value = run_json(&[
        "latency",
        "--soak",
        "--json",
        "--duration-s",
        "4",
        "--warmup-s",
        "1",
        "--vib-rate-hz",
        "256000",
        "--prefix",
        &p,
        "--load",
        campaign.to_str().unwrap(),
    ]);

    // 4 s at 800 Hz in blocks of 32 (40 ms each): 100 blocks; 256 kHz in blocks of 512
    // (2 ms each): 2,000 blocks, and one more past the last accelerometer block (the
    // sensors go on, so that the waveform stage covers the last readings).
    assert_eq!(u(&v, &["run", "accel_blocks_sent"]), 100, "{v}");
    assert_eq!(u(&v, &["run", "vib_blocks_sent"]), 2001, "{v}");
    // Every accelerometer block answered once, in order, by the rig's own count...
    assert_eq!(u(&v, &["run", "compensated_received"]), 100, "{v}");
    let a = &v["accel"];
    assert_eq!(u(a, &["answered"]), 100, "{a}");
    for k in ["missing", "duplicates", "out_of_order", "unknown"] {
        assert_eq!(u(a, &[k]), 0, "{k}: {a}");
    }
    assert_eq!(a["continuous"], true, "{a}");
    // ... and by the services' counters: nothing lost on either stream, every
    // vibration block taken at the rate the estimator was configured for.
    let s = &v["services"];
    assert_eq!(u(s, &["compensator_accel_received"]), 100, "{s}");
    assert_eq!(u(s, &["compensator_lost"]), 0, "{s}");
    assert_eq!(u(s, &["estimator_vib_received"]), 2001, "{s}");
    assert_eq!(u(s, &["estimator_lost"]), 0, "{s}");
    assert_eq!(u(s, &["estimator_rate_mismatches"]), 0, "{s}");
    assert!(u(s, &["estimates_published"]) >= 1, "{s}");
    assert_eq!(v["vib_blocks_taken"], true, "{v}");
    assert_eq!(u(&v, &["lost"]), 0, "{v}");
    assert_eq!(u(&v, &["run", "lost_samples"]), 0, "{v}");

    // The histogram holds the blocks after the 1 s warm-up: t0 = (32 k + 1) 1.25 ms
    // >= 1 s for k = 25..99, 75 blocks; its buckets and its top percentile count them
    // all, as does the hop table.
    let h = &v["end_to_end_histogram"];
    assert_eq!(u(h, &["count"]), 75, "{h}");
    assert_eq!(u(&v, &["run", "end_to_end", "count"]), 75, "{v}");
    let buckets: u64 = h["buckets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| u(b, &["blocks"]))
        .sum();
    assert_eq!(buckets, 75, "{h}");
    let pct = h["percentiles"].as_array().unwrap();
    assert_eq!(pct.last().unwrap()["percentile"], 100.0, "{h}");
    assert_eq!(u(pct.last().unwrap(), &["blocks_at_or_below"]), 75, "{h}");
    assert!(
        pct.windows(2).all(|w| {
            w[0]["value_us"].as_f64() <= w[1]["value_us"].as_f64()
                && u(&w[0], &["blocks_at_or_below"]) <= u(&w[1], &["blocks_at_or_below"])
        }),
        "{h}"
    );
    // The target is one accelerometer sample period: 1 / 800 Hz. Met or not is
    // reported, not asserted.
    assert_eq!(v["target_p999_us"], 1250.0, "{v}");
    assert!(v["p999_met"].is_boolean(), "{v}");

    // The services' memory, sampled every second over 4 s: present and finite.
    let mem = v["memory"].as_array().unwrap();
    let names: Vec<&str> = mem.iter().map(|m| m["process"].as_str().unwrap()).collect();
    assert_eq!(names, ["estimator", "compensator"], "{v}");
    for m in mem {
        assert!(u(m, &["samples"]) >= 4, "{m}");
        assert_eq!(
            m["series_kib"].as_array().unwrap().len() as u64,
            u(m, &["samples"]),
            "{m}"
        );
        for k in ["first_kib", "last_kib", "max_kib", "after_warmup_kib"] {
            assert!(u(m, &[k]) > 0, "{k}: {m}");
        }
        assert!(u(m, &["max_kib"]) >= u(m, &["last_kib"]), "{m}");
        assert!(m["slope_kib_per_min"].as_f64().unwrap().is_finite(), "{m}");
        assert!(m["flat"].is_boolean(), "{m}");
    }

    // The load ran, was stopped by the rig, and left nothing behind: no process names
    // the campaign's private path or the services' prefix.
    let l = &v["load"];
    assert!(u(l, &["runs_started"]) >= 1, "{l}");
    assert_eq!(u(l, &["failures"]), 0, "{l}");
    assert_eq!(l["stopped"], true, "{l}");
    assert!(l["cpu_percent"].as_f64().unwrap() > 0.0, "{l}");
    // The loop's command line and its diagnose runs' hold the campaign's path.
    assert!(u(l, &["pid"]) > 0, "{l}");
    assert_eq!(
        processes_mentioning(campaign.to_str().unwrap()),
        vec![],
        "load processes left behind"
    );
    assert_eq!(
        processes_mentioning(&p),
        vec![],
        "services left behind on {p}"
    );
}

/// The load's input is checked before anything starts: the error names the flag, the
/// value and the rule.
#[test]
fn a_soak_with_a_missing_load_input_fails_before_starting() {
    let out = bin()
        .args([
            "latency",
            "--soak",
            "--duration-s",
            "2",
            "--load",
            "/nonexistent/campaign.csv",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--load /nonexistent/campaign.csv: not a file"),
        "{err}"
    );
}

/// A thread's scheduling policy and real-time priority, as the kernel reports them in
/// `/proc/PID/task/TID/stat` (fields 41 and 40), and its name.
fn threads_scheduling(pid: u32) -> Vec<(String, i64, i64)> {
    let mut out = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return out;
    };
    for t in tasks.flatten() {
        let Ok(stat) = std::fs::read_to_string(t.path().join("stat")) else {
            continue;
        };
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        let name = stat[open + 1..close].to_string();
        // After the name: field 3 onwards.
        let f: Vec<&str> = stat[close + 1..].split_whitespace().collect();
        let field = |n: usize| {
            f.get(n - 3)
                .and_then(|s| s.parse::<i64>().ok())
                .unwrap_or(-1)
        };
        out.push((name, field(41), field(40)));
    }
    out
}

/// Whether this process may put a thread under SCHED_FIFO (the machine's permission,
/// not the code under test): tried on a thread of its own.
fn may_use_fifo() -> bool {
    std::thread::spawn(|| {
        let param = libc::sched_param { sched_priority: 1 };
        // SAFETY: a valid sched_param; pid 0 is this short-lived thread.
        unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0 }
    })
    .join()
    .unwrap()
}

/// `up --realtime-priority 10`: the kernel reports the compensator's hot-loop thread
/// under SCHED_FIFO at 10 and the estimator's at 9, and their other threads under the
/// normal policy; where the machine does not allow SCHED_FIFO, `up` fails and says why.
#[test]
fn up_runs_the_hot_loops_under_sched_fifo_when_asked() {
    use std::time::{Duration, Instant};
    let p = prefix("sk3");
    let mut cmd = bin();
    cmd.args(["up", "--prefix", &p, "--realtime-priority", "10"]);
    // Stopped by its drop if an assertion fails first.
    let mut up = crate::processes::Kid::spawn(cmd, "up");
    let fifo = may_use_fifo();
    let t = Instant::now();
    let mut found: Vec<(String, i64, i64)> = Vec::new();
    while fifo && t.elapsed() < Duration::from_secs(30) {
        found = crate::processes::children(up.pid())
            .iter()
            .flat_map(|(pid, _)| threads_scheduling(*pid))
            .filter(|(name, _, _)| name.starts_with("vibro-"))
            .collect();
        let loops = found
            .iter()
            .filter(|(n, _, _)| n == "vibro-estimator" || n.starts_with("vibro-compens"))
            .count();
        if loops == 2 {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    // With FIFO allowed, stopped here; without, the services fail at start and `up`
    // gives up once its restart limit is spent.
    let (status, _, stderr) = if fifo {
        up.stop(libc::SIGTERM, Duration::from_secs(30))
    } else {
        up.wait(Duration::from_secs(90))
    };
    if !fifo {
        assert!(!status.success(), "{stderr}");
        assert!(
            stderr.contains("cannot run the hot loop at SCHED_FIFO priority"),
            "{stderr}"
        );
        return;
    }
    assert!(status.success(), "{stderr}");
    const SCHED_OTHER: i64 = 0;
    const SCHED_FIFO: i64 = 1;
    let policy = |prefix: &str| {
        found
            .iter()
            .find(|(n, _, _)| n.starts_with(prefix))
            .map(|(_, policy, prio)| (*policy, *prio))
    };
    assert_eq!(policy("vibro-compens"), Some((SCHED_FIFO, 10)), "{found:?}");
    assert_eq!(
        policy("vibro-estimator"),
        Some((SCHED_FIFO, 9)),
        "{found:?}"
    );
    // The tokio workers stay under the normal policy.
    let workers: Vec<_> = found
        .iter()
        .filter(|(n, _, _)| n == "vibro-tokio")
        .collect();
    assert!(!workers.is_empty(), "{found:?}");
    assert!(
        workers.iter().all(|(_, policy, _)| *policy == SCHED_OTHER),
        "{found:?}"
    );
}

/// Without the right to SCHED_FIFO (CAP_SYS_NICE dropped by util-linux's `setpriv`,
/// and no `ulimit -r`), `up --realtime-priority` fails, each service saying what it
/// needs, instead of running with a priority it was not given.
#[test]
fn realtime_priority_without_the_right_fails_and_says_why() {
    use std::time::Duration;
    let p = prefix("sk4");
    let mut cmd = std::process::Command::new("setpriv");
    cmd.args(["--inh-caps=-sys_nice", "--bounding-set=-sys_nice"])
        .arg(bin().get_program())
        .args(["up", "--prefix", &p, "--realtime-priority", "10"]);
    let mut up = crate::processes::Kid::spawn(cmd, "up under setpriv");
    let (status, _, stderr) = up.wait(Duration::from_secs(90));
    assert_eq!(status.code(), Some(1), "{stderr}");
    for (service, priority) in [("compensator", 10), ("estimator", 9)] {
        let want = format!(
            "cannot run the hot loop at SCHED_FIFO priority {priority} (it needs CAP_SYS_NICE"
        );
        assert!(
            stderr.contains(&want),
            "{service}: {want:?} not in\n{stderr}"
        );
    }
    assert!(stderr.contains("a service crashed too often"), "{stderr}");
}
