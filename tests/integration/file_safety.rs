//! Files `vibrocomp` must not harm or be harmed by ("Reliability, round two"):
//! `--force` never replaces what is not a regular file (a FIFO, a directory, a symbolic
//! link made here: never a real device such as /dev/full). (Recovery after damage in
//! the middle of a file is tested in vibro-mcap's tests/mcap/recover.rs.)

use crate::common::{bin, run_failing};
use crate::processes::Dir;
use std::path::Path;
use std::process::Command;

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

fn mkfifo(path: &Path) {
    let ok = Command::new("mkfifo")
        .arg(path)
        .status()
        .expect("mkfifo runs");
    assert!(ok.success(), "mkfifo {}", path.display());
}

/// A small valid accelerometer CSV: 100 rows at 1 kHz.
fn accel_csv(path: &Path) {
    let mut text = String::from("time_s,u1_v,u2_v,u3_v\n");
    for i in 0..100 {
        text.push_str(&format!("{},-1.67,-1.66,-1.65\n", f64::from(i) * 1e-3));
    }
    std::fs::write(path, text).expect("write csv");
}

#[cfg(unix)]
fn is_fifo(path: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::symlink_metadata(path)
        .map(|m| m.file_type().is_fifo())
        .unwrap_or(false)
}

/// `log import --out X --force` and `log recover IN X --force` refuse a FIFO, a
/// directory and a symbolic link, say what X is, and leave it as it was.
#[cfg(unix)]
#[test]
fn force_refuses_outputs_that_are_not_regular_files() {
    let dir = Dir::new("file-safety-force");
    let csv = dir.path("accel.csv");
    accel_csv(&csv);
    let log = dir.path("log.mcap");
    let made = bin()
        .args(["log", "import", "--accel", s(&csv), "--out", s(&log)])
        .output()
        .expect("runs");
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let fifo = dir.path("fifo.mcap");
    mkfifo(&fifo);
    let folder = dir.path("folder.mcap");
    std::fs::create_dir(&folder).expect("mkdir");
    let target = dir.path("target.mcap");
    std::fs::write(&target, "kept").expect("write");
    let link = dir.path("link.mcap");
    std::os::unix::fs::symlink(&target, &link).expect("symlink");

    for (out, says) in [
        (
            &fifo,
            "is a FIFO (named pipe), not a regular file: refused even with --force",
        ),
        (&folder, "is a directory, not a file"),
        (&link, "is a symbolic link to"),
    ] {
        for args in [
            vec![
                "log",
                "import",
                "--accel",
                s(&csv),
                "--out",
                s(out),
                "--force",
            ],
            vec!["log", "recover", s(&log), s(out), "--force"],
        ] {
            let err = run_failing(&args);
            let err = String::from_utf8_lossy(&err.stderr);
            assert!(
                err.contains(says) && err.contains(s(out)),
                "{args:?}: {err}"
            );
        }
    }
    assert!(is_fifo(&fifo), "the FIFO was replaced");
    assert!(folder.is_dir());
    assert!(std::fs::symlink_metadata(&link)
        .expect("link")
        .file_type()
        .is_symlink());
    assert_eq!(std::fs::read_to_string(&target).expect("target"), "kept");
    // Nothing left behind: only the files made here.
    let mut names: Vec<String> = std::fs::read_dir(dir.path(""))
        .expect("read dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "accel.csv",
            "fifo.mcap",
            "folder.mcap",
            "link.mcap",
            "log.mcap",
            "target.mcap"
        ]
    );
}

/// Runs `vibrocomp ARGS`, expecting a refusal of `out` (an existing file, or a folder
/// of a previous run): the message names it and says `--force`, and `out` keeps its
/// content.
fn refused_without_force(args: &[&str], out: &Path, kept: &Path) {
    let before = std::fs::read(kept).expect("the existing output");
    let err = run_failing(args);
    let err = String::from_utf8_lossy(&err.stderr);
    assert!(
        err.contains(s(out)) && err.contains("pass --force to overwrite it"),
        "{args:?}: {err}"
    );
    assert_eq!(
        std::fs::read(kept).expect("the existing output"),
        before,
        "{args:?} changed {}",
        kept.display()
    );
}

/// README, "Files": every command that writes a file refuses to replace an existing
/// one without `--force`, before doing any work, naming the file and the flag.
#[test]
fn every_command_refuses_an_existing_output_without_force() {
    let dir = Dir::new("file-safety-rule");
    let old = dir.path("old.out");
    std::fs::write(&old, "the previous output").expect("write");
    let o = s(&old);
    // A flight log, and each of a campaign's tables (refused before the campaign runs).
    let flight = ["sim", "cyclone-4-short", "--duration-s", "0.1", "--out", o];
    refused_without_force(&flight, &old, &old);
    for flag in ["--summary-csv", "--lab-csv", "--positions-csv"] {
        refused_without_force(&["sim", "lab-walkthrough", flag, o], &old, &old);
    }
    // The lab's extended model (refused before the inputs are read or the fit runs).
    refused_without_force(
        &[
            "lab",
            "add",
            "resonance",
            "--from",
            "/no/such.csv",
            "--out",
            o,
        ],
        &old,
        &old,
    );
    // Recordings: before any port opens or any service starts.
    let p = crate::processes::prefix("force");
    refused_without_force(
        &["record", o, "--prefix", &p, "--duration-s", "1"],
        &old,
        &old,
    );
    refused_without_force(&["up", "--prefix", &p, "--record", o], &old, &old);
    // Folders of results holding a previous run.
    let demo = dir.path("demo");
    std::fs::create_dir(&demo).expect("mkdir");
    std::fs::write(demo.join("session.mcap"), "a previous session").expect("write");
    refused_without_force(
        &["demo", "--out-dir", s(&demo)],
        &demo,
        &demo.join("session.mcap"),
    );
    let report = dir.path("report");
    std::fs::create_dir(&report).expect("mkdir");
    std::fs::write(report.join("index.html"), "a previous report").expect("write");
    refused_without_force(
        &["lab", "report", "/no/such.csv", "--out", s(&report)],
        &report,
        &report.join("index.html"),
    );

    // With --force the flight replaces the file, with a complete log.
    let mut forced = flight.to_vec();
    forced.push("--force");
    let v = crate::common::run_json(&[forced.as_slice(), &["--json"]].concat());
    assert_eq!(v["out"], o);
    let info = crate::common::run_json(&["log", "info", o, "--json"]);
    assert!(info["messages"].as_u64().unwrap() > 0, "{info}");
    // Nothing else left behind (no temporary file).
    let mut names: Vec<String> = std::fs::read_dir(dir.path(""))
        .expect("read dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["demo", "old.out", "report"]);
}

/// README, "Files": an output that is one of the command's inputs is refused, even
/// with `--force` (the model lab's inputs, a scenario file, a recording's attachment).
#[test]
fn an_output_that_is_an_input_is_refused_even_with_force() {
    let dir = Dir::new("file-safety-input");
    let table = dir.path("campaign.csv");
    std::fs::write(&table, "kept").expect("write");
    let t = s(&table);
    let scenario = crate::common::repo_path("config/scenarios/cyclone-4-short.toml");
    let copy = dir.path("scenario.toml");
    std::fs::copy(&scenario, &copy).expect("copy the scenario");
    let cases: Vec<Vec<&str>> = vec![
        vec![
            "lab",
            "add",
            "resonance",
            "--from",
            t,
            "--out",
            t,
            "--force",
        ],
        vec![
            "lab",
            "add",
            "resonance",
            "--from",
            "x.csv",
            "--model",
            t,
            "--out",
            t,
            "--force",
        ],
        vec!["record", t, "--attach", t, "--force", "--duration-s", "1"],
        vec!["sim", s(&copy), "--out", s(&copy), "--force"],
    ];
    for args in cases {
        let err = run_failing(&args);
        let err = String::from_utf8_lossy(&err.stderr);
        assert!(err.contains("is the input"), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read_to_string(&table).expect("table"), "kept");
}
