//! `vibrocomp lab` on extreme but finite tables (issue "Reliability, round two",
//! item 1): `freq_hz = 1e308`, `ve_measured_g = 1e308`, `aL3_g = 1e50`, every
//! uncertainty `5e-324` or `1e-200`, an extra column of `1e308` on every other row.
//! These made `diagnose`, `add` and `report` panic in nalgebra's SVD (exit 101) or
//! run for minutes; `compare` accepted them. Every command must now exit 1 with the
//! line, column, value and rule on stderr, and never hang (each run is killed after
//! 60 s and the test fails).

use crate::common::bin;
use crate::processes::Dir;
use std::process::Stdio;
use std::time::{Duration, Instant};

/// The first 14 conditions of the walkthrough campaign: `vibrocomp sim
/// lab-walkthrough --threads 2 --lab-csv campaign.csv --ve-resolution-g 1e-6 &&
/// sed -n 2,16p campaign.csv`, shared with vibro-lab's tests/extreme_input.rs.
const SMALL: &str = include_str!("../../shared/vibro-lab/tests/data/walkthrough-14-rows.csv");

/// `SMALL` with `column` = `value` on the data rows `rows` picks (0-based).
fn with_cell(column: &str, value: &str, rows: impl Fn(usize) -> bool) -> String {
    let mut lines = SMALL.lines();
    let header = lines.next().unwrap_or_default();
    let j = header.split(',').position(|h| h == column).expect("column");
    let mut out = format!("{header}\n");
    for (i, l) in lines.enumerate() {
        let mut cells: Vec<&str> = l.split(',').collect();
        if rows(i) {
            cells[j] = value;
        }
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

/// Runs `vibrocomp ARGS`, killing it after 60 s (a failure); returns code and stderr.
fn run_bounded(args: &[&str]) -> (Option<i32>, String) {
    let mut child = bin()
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("vibrocomp starts");
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            let out = child.wait_with_output().expect("output");
            return (
                status.code(),
                String::from_utf8_lossy(&out.stderr).into_owned(),
            );
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("vibrocomp {args:?}: still running after 60 s (killed)");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn every_lab_command_refuses_each_extreme_table_with_exit_1_naming_the_cell() {
    let dir = Dir::new("extreme-lab");
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "freq",
            with_cell("freq_hz", "1e308", |i| i == 2),
            "line 4, column freq_hz = 1e308: must be <= 10000 Hz",
        ),
        (
            "ve",
            with_cell("ve_measured_g", "1e308", |i| i == 2),
            "line 4, column ve_measured_g = 1e308: must be within +-10 g",
        ),
        (
            "al3",
            with_cell("aL3_g", "1e50", |i| i == 2),
            "line 4, column aL3_g = 1e50: must be within +-500 g",
        ),
        (
            "u-denormal",
            with_cell("ve_uncertainty_g", "5e-324", |_| true),
            "line 15, column ve_uncertainty_g = 5e-324: must be within 1e-15 g",
        ),
        (
            "u-tiny",
            with_cell("ve_uncertainty_g", "1e-200", |_| true),
            "line 2, column ve_uncertainty_g = 1e-200: must be within 1e-15 g",
        ),
        (
            "extra",
            {
                let mut lines = SMALL.lines();
                let mut t = format!("{},x_extra\n", lines.next().unwrap_or_default());
                for (i, l) in lines.enumerate() {
                    let x = ["1", "1e308", "2", "1e308", "3"][i % 5];
                    t.push_str(&format!("{l},{x}\n"));
                }
                t
            },
            "line 3, column x_extra = 1e308: must be within +-1e12",
        ),
    ];
    for (name, text, needle) in cases {
        let table = dir.path(&format!("{name}.csv"));
        std::fs::write(&table, text).expect("write table");
        let t = table.to_str().expect("utf-8");
        let out_model = dir.path(&format!("{name}-model.toml"));
        let out_dir = dir.path(&format!("{name}-report"));
        let runs: [Vec<&str>; 4] = [
            vec!["lab", "compare", t],
            vec!["lab", "diagnose", t],
            vec![
                "lab",
                "add",
                "mount_resonance",
                "--from",
                t,
                "--out",
                out_model.to_str().expect("utf-8"),
            ],
            vec![
                "lab",
                "report",
                t,
                "--out",
                out_dir.to_str().expect("utf-8"),
            ],
        ];
        for args in runs {
            let (code, stderr) = run_bounded(&args);
            assert_eq!(
                code,
                Some(1),
                "{name}: vibrocomp {args:?} exited {code:?}:\n{stderr}"
            );
            assert!(
                stderr.contains(needle),
                "{name}: {needle:?} missing from:\n{stderr}"
            );
            assert!(
                stderr.contains(t),
                "{name}: the file is not named:\n{stderr}"
            );
        }
        assert!(!out_model.exists(), "{name}: lab add wrote a model");
    }
}
