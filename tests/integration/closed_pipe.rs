//! A closed pipe (`vibrocomp ... | head -1`) and unchecked command-line values
//! (issue "Reliability, round two", items 2, 5 and 10): every command ends quietly with
//! exit 0 when its reader goes away, and a flag value outside the rules of the files
//! is refused naming the flag, the value and the rule.

use crate::common::{bin, repo_path, run_failing};
use crate::processes::Dir;
use std::io::Read;
use std::process::Stdio;

const HEADER: &str = "run_id,passport,aL1_g,aL2_g,aL3_g,freq_hz,aB1_g,aB2_g,aB3_g,phase31_deg,phase32_deg,sigma1_g,sigma2_g,sigma3_g,cov31_g2,cov32_g2,kurtosis3,ve_measured_g,ve_uncertainty_g";

/// Runs `vibrocomp ARGS` with stdout on a pipe whose read end is closed before the
/// command prints (`read_line`: after reading its first line), and asserts a quiet
/// exit 0.
fn closes_quietly(args: &[&str], read_line: bool) {
    let mut child = bin()
        .args(args)
        .current_dir(repo_path(""))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("vibrocomp starts");
    let mut stdout = child.stdout.take().expect("piped stdout");
    if read_line {
        let mut byte = [0u8; 1];
        while stdout.read(&mut byte).map(|n| n == 1).unwrap_or(false) && byte[0] != b'\n' {}
    }
    drop(stdout);
    let out = child.wait_with_output().expect("vibrocomp ends");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "vibrocomp {args:?}:\n{stderr}");
    assert!(
        stderr.trim().is_empty(),
        "vibrocomp {args:?} wrote on stderr:\n{stderr}"
    );
}

/// Every printing command, at once and after one line.
fn both(args: &[&str]) {
    closes_quietly(args, false);
    closes_quietly(args, true);
}

#[test]
fn require_ends_quietly_on_a_closed_pipe() {
    both(&["require", "--dstar-g", "1e-4", "--aL3-g", "1"]);
    both(&["require", "--dstar-g", "1e-4", "--aL3-g", "1", "--json"]);
}

#[test]
fn sim_ends_quietly_on_a_closed_pipe() {
    both(&["sim", "cyclone-4-short", "--duration-s", "0.1"]);
    both(&["sim", "cyclone-4-short", "--duration-s", "0.1", "--json"]);
    both(&["sim", "--list-effects"]);
}

#[test]
fn model_ends_quietly_on_a_closed_pipe() {
    let ve = [
        "model",
        "ve",
        "--passport",
        "AL-15",
        "--aL3-g",
        "1",
        "--aB3-g",
        "1",
        "--freq-hz",
        "100",
    ];
    both(&ve);
    both(&[&ve[..], &["--json"]].concat());
    let check = [
        "model",
        "check",
        "--passport",
        "AL-15",
        "--aL3-g",
        "1",
        "--aB3-g",
        "1",
        "--samples",
        "1000",
    ];
    both(&check);
    both(&[
        "model",
        "compensate",
        "--passport",
        "AL-15",
        "--reading-g",
        "1",
        "--aB3-g",
        "1",
    ]);
    both(&["model", "flight"]);
}

#[test]
fn identify_ends_quietly_on_a_closed_pipe() {
    let args = [
        "identify",
        "positions",
        "config/campaigns/ten-positions-al15.csv",
        "--passport",
        "AL-15",
    ];
    both(&args);
    both(&[&args[..], &["--json"]].concat());
}

#[test]
fn lab_ends_quietly_on_a_closed_pipe() {
    let dir = Dir::new("closed-pipe-lab");
    let table = dir.path("t.csv");
    std::fs::write(
        &table,
        format!("{HEADER}\nT4,AL-15,0,0,10,30,0,0,0.42,,,,,,,,,1.5671e-3,1e-6\n"),
    )
    .expect("table written");
    let t = table.to_str().expect("utf-8 path");
    both(&["lab", "compare", t]);
    both(&["lab", "compare", t, "--json"]);
}

fn refused(args: &[&str], wanted: &[&str]) -> String {
    let out = run_failing(args);
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "vibrocomp {args:?}:\n{stderr}");
    for w in wanted {
        assert!(
            stderr.contains(w),
            "vibrocomp {args:?}: no {w:?} in\n{stderr}"
        );
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

#[test]
fn a_huge_duration_is_refused_with_the_scenario_files_rule() {
    refused(
        &["sim", "cyclone-4-short", "--duration-s", "1e300"],
        &["--duration-s = 1e300: must be finite and 0 < length <= 1e6 s"],
    );
    refused(
        &["sim", "cyclone-4-short", "--duration-s", "NaN"],
        &["--duration-s = NaN: must be finite"],
    );
    refused(
        &["sim", "cyclone-4-short", "--duration-s=-1"],
        &["--duration-s = -1: must be finite"],
    );
}

#[test]
fn model_flags_outside_the_rules_are_refused_all_at_once() {
    let e = refused(
        &[
            "model",
            "ve",
            "--passport",
            "AL-15",
            "--aL3-g",
            "1e300",
            "--aL1-g",
            "NaN",
            "--aB3-g",
            "NaN",
        ],
        &[
            "3 bad values",
            "--aL3-g = 1e300: must be finite and within +-1000 g",
            "--aL1-g = NaN: must be finite and within +-1000 g",
            "--aB3-g = NaN: must be finite and 0 <= aB <= 1000 g",
        ],
    );
    assert!(!e.contains("0000000000"), "{e}");
    refused(
        &[
            "model",
            "ve",
            "--passport",
            "AL-15",
            "--aL3-g",
            "1",
            "--aB3-g",
            "-1",
        ],
        &["--aB3-g = -1: must be finite and 0 <= aB <= 1000 g"],
    );
    refused(
        &[
            "require",
            "--dstar-g",
            "1e-4",
            "--aL3-g",
            "1e300",
            "--aB3-g",
            "-1",
        ],
        &[
            "--aL3-g = 1e300: must be finite and within +-1000 g",
            "--aB3-g = -1: must be finite and 0 <= aB <= 1000 g",
        ],
    );
}

#[test]
fn huge_finite_values_print_in_engineering_form() {
    let out = bin()
        .args(["require", "--dstar-g", "1e300", "--aL3-g", "1"])
        .output()
        .expect("vibrocomp runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("D* = 1e300 g"), "{text}");
    assert!(!text.contains("0000000000"), "{text}");
}

#[test]
fn lab_errors_name_the_command() {
    let out = run_failing(&["lab", "diagnose", "/dev/null"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.starts_with("error: lab diagnose: /dev/null: "), "{e}");
    let out = run_failing(&["lab", "compare", "/dev/null"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.starts_with("error: lab compare: /dev/null: "), "{e}");
}
