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
