//! The lab's table reader on hostile input ("Reliability, round four", item 2, and the
//! echo of item 8): `/dev/zero`, a line over the cap, too many columns, too many rows,
//! a CR-only file, and a hundred thousand identical rows, which the fits pool. Each run is in an address space of at most 2 GiB (`ulimit -v`: a reader that
//! slurps its input dies there instead of swapping) and killed after 120 s (a failure).
//!
//! `VIBROCOMP_BIN=/path/to/vibrocomp` runs these against another build (they fail on
//! the one before the bounds).

use crate::processes::Dir;
use std::fmt::Write as _;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const HEADER: &str = "run_id,passport,aL1_g,aL2_g,aL3_g,freq_hz,aB1_g,aB2_g,aB3_g,phase31_deg,phase32_deg,sigma1_g,sigma2_g,sigma3_g,cov31_g2,cov32_g2,kurtosis3,ve_measured_g,ve_uncertainty_g";

/// One condition: an AL-15 with IA up (1 g), a 0.42 g IA tone at 30 Hz, a measured VE
/// of 1.3e-5 g +- 1e-7 g (the model says 3.85e-5 g: far from it, so that the
/// diagnosis fits the candidates).
fn row(i: usize) -> String {
    format!("R{i},AL-15,0,0,1,30,0,0,0.42,,,,,,,,,1.3e-5,1e-7")
}

/// A table of `n` rows of [`row`], lines joined by `eol`.
fn table(n: usize, eol: &str) -> String {
    let mut t = String::with_capacity(50 * (n + 1));
    t.push_str(HEADER);
    t.push_str(eol);
    for i in 0..n {
        let _ = write!(t, "{}{eol}", row(i));
    }
    t
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

/// Runs `vibrocomp ARGS` in an address space of at most 2 GiB, killed after 120 s.
fn run_limited(args: &[&str]) -> Output {
    let vibrocomp = std::env::var("VIBROCOMP_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_vibrocomp").to_string());
    let mut child = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 2097152 && exec \"$0\" \"$@\"")
        .arg(vibrocomp)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sh runs");
    // Drained as it runs: a diagnosis's JSON is larger than a pipe holds.
    let (mut stdout, mut stderr) = (child.stdout.take(), child.stderr.take());
    let out_reader = std::thread::spawn(move || {
        let mut v = Vec::new();
        if let Some(o) = stdout.as_mut() {
            let _ = std::io::Read::read_to_end(o, &mut v);
        }
        v
    });
    let err_reader = std::thread::spawn(move || {
        let mut v = Vec::new();
        if let Some(e) = stderr.as_mut() {
            let _ = std::io::Read::read_to_end(e, &mut v);
        }
        v
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("vibrocomp {args:?} still running after 120 s: killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        status,
        stdout: out_reader.join().expect("stdout"),
        stderr: err_reader.join().expect("stderr"),
    }
}

/// Exit 1 with a short message (under `max_bytes`) holding every one of `parts`.
fn assert_refused(out: &Output, max_bytes: usize, parts: &[&str]) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{err:.3000}");
    assert!(
        err.len() < max_bytes,
        "{} bytes of error: {err:.3000}",
        err.len()
    );
    for part in parts {
        assert!(err.contains(part), "no {part:?} in: {err:.3000}");
    }
    err
}

#[test]
fn dev_zero_is_refused_at_the_cap_on_a_line_in_a_small_address_space() {
    let dir = Dir::new("lab-bounds-zero");
    let (report, model) = (dir.path("report"), dir.path("model.toml"));
    for args in [
        vec!["lab", "diagnose", "/dev/zero"],
        vec!["lab", "compare", "/dev/zero"],
        vec!["lab", "report", "/dev/zero", "--out", s(&report)],
        vec![
            "lab",
            "add",
            "heating",
            "--from",
            "/dev/zero",
            "--out",
            s(&model),
        ],
    ] {
        let out = run_limited(&args);
        let err = assert_refused(
            &out,
            1024,
            &[
                "/dev/zero: line 1: longer than 65536 bytes (the cap on a line",
                &format!("It starts \"{}… (more than ", "\\u{0}".repeat(120)),
                " bytes cut)\"",
            ],
        );
        assert!(!err.contains("out of memory"), "{err}");
    }
    assert!(!report.exists() && !model.exists(), "nothing written");
}

#[test]
fn a_line_over_the_cap_is_refused_by_its_number_its_start_cut() {
    let dir = Dir::new("lab-bounds-line");
    let path = dir.path("t.csv");
    let long = "7".repeat(1 << 20);
    std::fs::write(&path, format!("{}{long},{}\n", table(1, "\n"), row(2))).expect("write");
    assert_refused(
        &run_limited(&["lab", "diagnose", s(&path)]),
        1024,
        &[
            &format!("{}: line 3: longer than 65536 bytes", s(&path)),
            &format!("It starts \"{}… (more than ", "7".repeat(120)),
        ],
    );
}

#[test]
fn columns_over_the_cap_are_refused() {
    let dir = Dir::new("lab-bounds-columns");
    // The 19 required and 46 extras: one over 64.
    let path = dir.path("wide.csv");
    let extras: String = (0..46).map(|j| format!(",x{j}")).collect();
    let cells: String = (0..46).map(|_| ",0").collect();
    std::fs::write(&path, format!("{HEADER}{extras}\n{}{cells}\n", row(0))).expect("write");
    assert_refused(
        &run_limited(&["lab", "compare", s(&path)]),
        1024,
        &[&format!(
            "{}: line 1 (header): 65 columns: at most 64 (the 19 required and up to 45 extra variables)",
            s(&path)
        )],
    );
    // A million columns: the header is past the cap on a line long before.
    let path = dir.path("million.csv");
    let extras: String = (0..1_000_000).map(|j| format!(",x{j}")).collect();
    std::fs::write(&path, format!("{HEADER}{extras}\n{}\n", row(0))).expect("write");
    assert_refused(
        &run_limited(&["lab", "diagnose", s(&path)]),
        1024,
        &[&format!("{}: line 1: longer than 65536 bytes", s(&path))],
    );
}

#[test]
fn rows_over_the_limit_are_refused_at_the_first_row_past_it() {
    let dir = Dir::new("lab-bounds-rows");
    let path = dir.path("rows.csv");
    std::fs::write(&path, table(1_000_001, "\n")).expect("write");
    assert_refused(
        &run_limited(&["lab", "compare", s(&path)]),
        1024,
        &[&format!(
            "{}: line 1000002: row 1000001: at most 1000000 rows in a table",
            s(&path)
        )],
    );
}

#[test]
fn a_cr_only_table_is_read_by_its_lines_and_its_problems_are_listed_short() {
    let dir = Dir::new("lab-bounds-cr");
    // Old Mac line endings: every row at its own line.
    let path = dir.path("cr.csv");
    std::fs::write(&path, table(1000, "\r")).expect("write");
    let out = run_limited(&["lab", "compare", "--json", s(&path)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let rows = v["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 1000);
    assert_eq!(rows[999]["line"], 1001);
    // A thousand bad rows: twenty listed by their own lines, the rest counted.
    let bad = dir.path("bad.csv");
    std::fs::write(&bad, table(1000, "\r").replace(",0,0,1,30,", ",0,0,x,30,")).expect("write");
    let err = assert_refused(
        &run_limited(&["lab", "compare", s(&bad)]),
        3000,
        &[
            "line 2, column aL3_g = \"x\": must be a finite number",
            "line 21, column aL3_g = \"x\"",
            "... and 980 more problems (the first 20 are listed)",
        ],
    );
    assert!(!err.contains("line 22,"), "{err}");
    // Fifty thousand carriage returns and nothing else: no table.
    let empty = dir.path("empty.csv");
    std::fs::write(&empty, "\r".repeat(50_000)).expect("write");
    assert_refused(
        &run_limited(&["lab", "compare", s(&empty)]),
        300,
        &["empty: a table is a header line, then one row per condition"],
    );
}

#[test]
fn a_cr_only_rig_csv_is_quoted_by_a_line_s_worth_marked_cut() {
    // `log import` and `estimate` read lines ending in `\n`: a CR-only file is one line
    // of 30 KB, quoted whole in their error before.
    let dir = Dir::new("lab-bounds-cr-rig");
    let path = dir.path("accel.csv");
    let mut text = String::from("time_s,u1_v,u2_v,u3_v\r");
    for i in 0..3000 {
        let _ = write!(text, "{},1,2,3\r", i as f64 * 1e-3);
    }
    std::fs::write(&path, &text).expect("write");
    let mcap = dir.path("out.mcap");
    let out = run_limited(&["log", "import", "--accel", s(&path), "--out", s(&mcap)]);
    assert_refused(
        &out,
        1024,
        &[
            &format!(
                "{} line 1 (header) = \"time_s,u1_v,u2_v,u3_v\\r0,1,2,3\\r",
                s(&path)
            ),
            " more bytes cut)\": missing column(s)",
        ],
    );
    let out = run_limited(&["estimate", s(&path), "--rate-hz", "5000"]);
    assert_refused(
        &out,
        1024,
        &["line 1: header has 9004 columns (", " more bytes cut)"],
    );
}

#[test]
fn a_hundred_thousand_identical_rows_are_one_condition_to_the_fits() {
    let dir = Dir::new("lab-bounds-pool");
    let small = dir.path("small.csv");
    let big = dir.path("big.csv");
    std::fs::write(&small, table(10, "\n")).expect("write");
    std::fs::write(&big, table(100_000, "\n")).expect("write");
    let diagnose = |path: &Path| -> serde_json::Value {
        // Every candidate: before the rows were pooled this took over 120 s.
        let out = run_limited(&["lab", "diagnose", "--json", s(path)]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).expect("JSON")
    };
    let (d10, d) = (diagnose(&small), diagnose(&big));
    let summary = &d["comparison"]["summary"];
    assert_eq!(summary["n"], 100_000);
    assert_eq!(summary["distinct_conditions"], 1);
    assert_eq!(d10["comparison"]["summary"]["distinct_conditions"], 1);
    // N identical rows: chi2 = N z^2, so the big table's is 10^4 times the small one's.
    let chi2 = |v: &serde_json::Value| v["comparison"]["summary"]["chi2"].as_f64().expect("chi2");
    let ratio = chi2(&d) / chi2(&d10);
    assert!((ratio / 1e4 - 1.0).abs() < 1e-12, "chi2 ratio {ratio}");
    // Heating is linear in its one parameter: on one condition its least-squares fit
    // is exact whatever the rows' count (the residual left is rounding), and its value
    // is the small table's.
    let heating = |v: &serde_json::Value| -> (f64, f64, f64) {
        let c = v["candidates"]
            .as_array()
            .expect("candidates")
            .iter()
            .find(|c| c["kind"] == "heating")
            .expect("heating ranked")
            .clone();
        let f = &c["fit"];
        (
            f["params"][0]["value"].as_f64().expect("value"),
            f["rms_residual_after_g"].as_f64().expect("after"),
            f["rms_residual_before_g"].as_f64().expect("before"),
        )
    };
    let ((c10, after10, before10), (c, after, before)) = (heating(&d10), heating(&d));
    assert!((c / c10 - 1.0).abs() < 1e-9, "{c} against {c10}");
    assert!(
        after <= 1e-9 * before && after10 <= 1e-9 * before10,
        "{after} of {before}"
    );
}
