//! Command-line values under the rules of the files (issue "Reliability, round two",
//! item 10): every numeric flag of `sim`, `model`, `identify`, `estimate`, `up`,
//! `replay`, `record` and `demo` given an extreme value (1e300, 5e-324, NaN, a huge
//! integer) is refused with exit status 1 (never a panic's 101, never a hang: each run
//! is killed after a time limit and the test fails), the error naming the flag, the
//! value and the rule, and a value on the rule's boundary still gets through.
//! Commands that open iceoryx2 services or start processes refuse before they do:
//! no service of the test's prefix exists afterwards.

use crate::common::{bin, repo_path};
use crate::processes::{flight_log, prefix, Dir};
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

/// Longest any probe may run: the refusals take well under a second.
const LIMIT: Duration = Duration::from_secs(60);

/// Runs `vibrocomp ARGS` from the workspace root, killed (and the test failed) after
/// [`LIMIT`].
fn run(args: &[&str]) -> Output {
    let mut child = bin()
        .args(args)
        .current_dir(repo_path(""))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("vibrocomp starts");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("waiting for vibrocomp").is_some() {
            return child.wait_with_output().expect("vibrocomp's output");
        }
        if start.elapsed() > LIMIT {
            let _ = child.kill();
            let out = child.wait_with_output().expect("killed vibrocomp's output");
            panic!(
                "vibrocomp {args:?} still running after {LIMIT:?} (killed):\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Asserts exit status 1 (a refusal, not a panic) and every `needle` in stderr;
/// returns stderr.
fn refused(args: &[&str], needles: &[&str]) -> String {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(
        out.status.code(),
        Some(1),
        "vibrocomp {args:?}: expected exit 1\n{err}"
    );
    for n in needles {
        assert!(
            err.contains(n),
            "vibrocomp {args:?}: stderr lacks {n:?}:\n{err}"
        );
    }
    err
}

/// Asserts success.
fn accepted(args: &[&str]) {
    let out = run(args);
    assert!(
        out.status.success(),
        "vibrocomp {args:?}: expected success, got {:?}\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// iceoryx2 services whose static description names `prefix` (iceoryx2's default
/// root, /tmp/iceoryx2/services; each service's file holds its name).
fn services_of(prefix: &str) -> Vec<String> {
    let Ok(dir) = std::fs::read_dir("/tmp/iceoryx2/services") else {
        return Vec::new();
    };
    dir.flatten()
        .filter(|e| {
            std::fs::read(e.path())
                .map(|b| String::from_utf8_lossy(&b).contains(prefix))
                .unwrap_or(false)
        })
        .map(|e| e.path().display().to_string())
        .collect()
}

fn assert_nothing_left(prefix: &str) {
    let left = services_of(prefix);
    assert!(
        left.is_empty(),
        "iceoryx2 services of {prefix} left: {left:?}"
    );
    assert!(
        !vibro_service::supervise::prefix_lock_path(prefix).exists(),
        "up's lock file of {prefix} left"
    );
}

#[test]
fn sim_rate_follows_the_paced_replay_rule() {
    let p = prefix("fr1");
    // Before: waited u64::MAX ns before the first message (a hang).
    let args = [
        "sim",
        "cyclone-4-short",
        "--duration-s",
        "0.1",
        "--live",
        "--prefix",
        &p,
        "--rate",
        "5e-324",
    ];
    refused(
        &args,
        &["--rate = 5e-324", "must be finite and 1e-3 <= rate <= 1e6"],
    );
    assert_nothing_left(&p);
    // The fastest allowed pace: 0.1 s of flight at once.
    let mut ok = args;
    ok[8] = "1e6";
    accepted(&ok);
    assert_nothing_left(&p);
}

#[test]
fn sim_ve_resolution_is_checked_before_the_campaign_runs() {
    let dir = Dir::new("fr2");
    let csv = dir.path("lab.csv");
    let csv_s = csv.to_str().unwrap();
    // Before: accepted, the 30 s campaign ran and wrote uncertainties of 1e300 g that
    // `vibrocomp lab` then refused.
    refused(
        &[
            "sim",
            "lab-walkthrough",
            "--ve-resolution-g",
            "1e300",
            "--lab-csv",
            csv_s,
        ],
        &["--ve-resolution-g = 1e300", "0 <= resolution <= 10 g"],
    );
    assert!(!csv.exists(), "{csv_s} written despite the refusal");
    // The boundary (the lab table's largest uncertainty) passes the check; on a
    // flight the value is not used, so the run stays short.
    accepted(&[
        "sim",
        "cyclone-4-short",
        "--duration-s",
        "0.1",
        "--ve-resolution-g",
        "10",
    ]);
}

#[test]
fn model_check_samples_are_bounded() {
    let base = [
        "model",
        "check",
        "--passport",
        "AL-15",
        "--aL3-g",
        "1",
        "--aB3-g",
        "1",
        "--freq-hz",
        "10",
        "--samples",
    ];
    // Before: 1.8e19 Monte Carlo evaluations (no end).
    let mut args = base.to_vec();
    args.push("18446744073709551615");
    refused(
        &args,
        &[
            "--samples = 18446744073709551615",
            "at most 1e9 Monte Carlo samples",
        ],
    );
    let mut args = base.to_vec();
    args.push("4");
    accepted(&args);
}

#[test]
fn model_vibration_flags_use_the_physics_rules() {
    let base = ["model", "ve", "--passport", "AL-15", "--aL3-g", "1"];
    // `Vibration::validate`'s rule on sigma^2, through vibro_physics::vibration::rules.
    let mut args = base.to_vec();
    args.extend(["--sigma3-g", "1000.001", "--kurtosis3", "30.5"]);
    refused(
        &args,
        &[
            "2 bad values",
            "--sigma3-g = 1000.001: must be finite and 0 <= sigma^2 <= 1e6 g^2",
            "--kurtosis3 = 30.5: must be finite and 1 <= kurtosis <= 30",
        ],
    );
    let mut args = base.to_vec();
    args.extend([
        "--sigma3-g",
        "1000",
        "--sigma1-g",
        "1000",
        "--cov31-g2",
        "1e6",
    ]);
    args.extend(["--kurtosis3", "30", "--aB3-g", "1000", "--freq-hz", "10"]);
    accepted(&args);
}

#[test]
fn identify_prediction_points_follow_the_flight_and_tone_rules() {
    let file = "config/campaigns/ten-positions-al15.csv";
    let base = ["identify", "positions", file, "--passport", "AL-15"];
    // Before: exit 0, a 301-digit aL in the table of (23).
    let mut args = base.to_vec();
    args.extend(["--at-g", "1e300", "--at-ab3-g", "1e300"]);
    refused(
        &args,
        &[
            "2 bad values",
            "--at-g = 1e300: must be finite and within +-1000 g",
            "--at-ab3-g = 1e300: must be finite and 0 <= aB <= 1000 g",
        ],
    );
    let mut args = base.to_vec();
    args.extend(["--at-g", "1000", "--at-ab3-g", "1000"]);
    accepted(&args);
}

#[test]
fn estimate_names_the_flags_and_prints_numbers_short() {
    let dir = Dir::new("fr6");
    let csv = dir.path("vib.csv");
    // 1 s at 4096 Hz: one default window.
    let text: String = (0..4096)
        .map(|i| format!("{},0.1,0.2\n", (i as f64 * 0.3).sin()))
        .collect();
    std::fs::write(&csv, text).unwrap();
    let csv = csv.to_str().unwrap();
    let base = ["estimate", csv, "--rate-hz", "4096"];
    // Before: the configuration keys only, and window_s as a 301-digit number.
    let mut args = base.to_vec();
    args.extend(["--window-s", "1e300", "--overlap", "NaN"]);
    let err = refused(
        &args,
        &[
            "2 bad values",
            "--window-s: window_s = 1e300: must be finite and hold 256..=16777216 samples",
            "--overlap: overlap_fraction = NaN: must be finite and 0 <= overlap < 1",
        ],
    );
    assert!(!err.contains("0000000000"), "a number in full:\n{err}");
    let mut args = base.to_vec();
    args.extend(["--overlap", "0"]);
    accepted(&args);
}

#[test]
fn up_refuses_bad_durations_before_starting_anything() {
    let p = prefix("fr7");
    // Before: the services started and `up` panicked (exit 101) converting 1e300 s.
    let err = refused(
        &[
            "up",
            "--prefix",
            &p,
            "--restart-window-s",
            "1e300",
            "--stop-timeout-s",
            "5e-324",
        ],
        &[
            "2 bad values",
            "--restart-window-s = 1e300: must be finite and 0.1 <= s <= 86400",
            "--stop-timeout-s = 5e-324: must be finite and 0.01 <= s <= 3600",
        ],
    );
    assert!(!err.contains("panicked"), "{err}");
    assert_nothing_left(&p);
    // The boundaries pass: only the bad value is named.
    let err = refused(
        &[
            "up",
            "--prefix",
            &p,
            "--restart-window-s",
            "86400",
            "--stop-timeout-s",
            "NaN",
        ],
        &["--stop-timeout-s = NaN"],
    );
    assert!(!err.contains("--restart-window-s"), "{err}");
    assert_nothing_left(&p);
}

#[test]
fn replay_refuses_every_bad_value_at_once_before_opening_a_port() {
    let dir = Dir::new("fr8");
    let log = flight_log(&dir, "0.2");
    let log = log.to_str().unwrap();
    let p = prefix("fr8");
    // Before: a panic (exit 101) on --wait-s 1e300; a 5e-324 rate waited for ever.
    refused(
        &[
            "replay",
            log,
            "--prefix",
            &p,
            "--rate",
            "5e-324",
            "--start-s",
            "1e300",
            "--duration-s",
            "5e-324",
            "--wait-s",
            "1e300",
        ],
        &[
            "4 bad values",
            "--rate = 5e-324: must be finite and 1e-3 <= rate <= 1e6",
            "--start-s = 1e300: must be finite and 0 <= s <= 1e9",
            "--duration-s = 5e-324: must be finite and 1e-9 <= s <= 1e9",
            "--wait-s = 1e300: must be finite and 0.001 <= s <= 86400",
        ],
    );
    assert_nothing_left(&p);
    // On the boundaries the options pass and the replay looks for its system: nobody
    // is there.
    let err = refused(
        &[
            "replay",
            log,
            "--prefix",
            &p,
            "--rate",
            "1e6",
            "--start-s",
            "0",
            "--duration-s",
            "1e9",
            "--wait-s",
            "0.001",
        ],
        &["nobody subscribed"],
    );
    assert!(!err.contains("bad value"), "{err}");
    assert_nothing_left(&p);
}

#[test]
fn record_refuses_a_duration_beyond_the_rule() {
    let dir = Dir::new("fr9");
    let out = dir.path("rec.mcap");
    let out_s = out.to_str().unwrap();
    let p = prefix("fr9");
    // Before: a panic (exit 101) converting 1e300 s into a Duration.
    refused(
        &["record", out_s, "--prefix", &p, "--duration-s", "1e300"],
        &["--duration-s = 1e300: must be finite and 0.001 <= s <= 1e9"],
    );
    assert!(!out.exists(), "{out_s} created despite the refusal");
    assert_nothing_left(&p);
    // The shortest recording allowed: 1 ms of an idle prefix.
    accepted(&["record", out_s, "--prefix", &p, "--duration-s", "0.001"]);
    assert_nothing_left(&p);
}

#[test]
fn demo_window_follows_its_scenario() {
    let dir = Dir::new("fr10");
    let out = dir.path("demo");
    let out_s = out.to_str().unwrap();
    // Before: the flight and the services ran, and the demo failed at the end with
    // "no window of 1000...0 s (301 digits) was compensated".
    for (value, needle) in [
        ("1e300", "--window-s = 1e300"),
        ("5e-324", "--window-s = 5e-324"),
    ] {
        refused(
            &["demo", "--out-dir", out_s, "--window-s", value],
            &[needle, "must be finite and 0.00125 <= s <= 20"],
        );
        assert!(!out.exists(), "{out_s} created despite the refusal");
    }
}
