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
/// sed -n 2,16p campaign.csv` (the same rows as vibro-lab's tests/extreme_input.rs).
const SMALL: &str = "\
run_id,passport,aL1_g,aL2_g,aL3_g,freq_hz,aB1_g,aB2_g,aB3_g,phase31_deg,phase32_deg,sigma1_g,sigma2_g,sigma3_g,cov31_g2,cov32_g2,kurtosis3,ve_measured_g,ve_uncertainty_g,tp,angle_deg,vibrating_s
C001,AL-15,0e0,0e0,1e0,2e1,0e0,0e0,9.99980651519183e-1,0e0,0e0,,,,,,,3.202516954835498e-4,1e-6,1e0,0e0,5e0
C002,AL-15,0e0,0e0,1e0,3e1,0e0,0e0,1.0000029680452949e0,0e0,0e0,,,,,,,5.017162083116443e-4,1e-6,2e0,0e0,5e0
C003,AL-15,0e0,0e0,1e0,4e1,0e0,0e0,1.000003440408764e0,0e0,0e0,,,,,,,8.034393088758113e-4,1e-6,3e0,0e0,5e0
C004,AL-15,0e0,0e0,1e0,6e1,0e0,0e0,9.999966794748001e-1,0e0,0e0,,,,,,,3.8925808388661214e-4,1e-6,4e0,0e0,5e0
C005,AL-15,0e0,0e0,1e0,8e1,0e0,0e0,1.0000001758868302e0,0e0,0e0,,,,,,,1.0960611009239708e-4,1e-6,5e0,0e0,5e0
C006,AL-15,0e0,0e0,1e0,1.2e2,0e0,0e0,9.999935992697868e-1,0e0,0e0,,,,,,,2.582870967782483e-5,1e-6,6e0,0e0,5e0
C007,AL-15,0e0,0e0,1e0,1.6e2,0e0,0e0,1.000004976934076e0,0e0,0e0,,,,,,,1.1345874375756981e-5,1e-6,7e0,0e0,5e0
C008,AL-15,0e0,0e0,1e0,2e1,0e0,0e0,1.9999721464116311e0,0e0,0e0,,,,,,,1.4161481696767e-3,1e-6,8e0,0e0,5e0
C009,AL-15,0e0,0e0,1e0,3e1,0e0,0e0,1.9999973472054635e0,0e0,0e0,,,,,,,2.319984674849029e-3,1e-6,9e0,0e0,5e0
C010,AL-15,0e0,0e0,1e0,4e1,0e0,0e0,2.0000046849223474e0,0e0,0e0,,,,,,,3.965590818067524e-3,1e-6,1e1,0e0,5e0
C011,AL-15,0e0,0e0,1e0,6e1,0e0,0e0,1.999999199359481e0,0e0,0e0,,,,,,,1.7517263717164678e-3,1e-6,1.1e1,0e0,5e0
C012,AL-15,0e0,0e0,1e0,8e1,0e0,0e0,1.9999946373670887e0,0e0,0e0,,,,,,,4.5560385144730807e-4,1e-6,1.2e1,0e0,5e0
C013,AL-15,0e0,0e0,1e0,1.2e2,0e0,0e0,2.000000224127965e0,0e0,0e0,,,,,,,1.0422958398860191e-4,1e-6,1.3e1,0e0,5e0
C014,AL-15,0e0,0e0,1e0,1.6e2,0e0,0e0,1.9999973517830212e0,0e0,0e0,,,,,,,4.556059293547633e-5,1e-6,1.4e1,0e0,5e0
";

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
