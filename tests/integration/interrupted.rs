//! A flight into a log (`vibrocomp sim --out`) stopped by SIGINT or SIGTERM finishes
//! its file (footer and summary: readable by the Python `mcap` reader and `log info`),
//! says on stderr the simulated time it reached, and exits with status 1; and a log
//! that cannot be written (a full disk) says why (the operating system's reason).

use crate::common::{bin, run_failing};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "vibrocomp-it-interrupted-{name}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// The messages of `file` as the Python reference reader counts them, and its
/// summary's message count (`None`: no summary, an unfinished file).
fn python_counts(file: &Path) -> (u64, Option<u64>) {
    let script = r#"
import json, sys
from mcap.reader import make_reader
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    counted = sum(1 for _ in reader.iter_messages())
stats = summary.statistics.message_count if summary and summary.statistics else None
print(json.dumps({"counted": counted, "summary": stats}))
"#;
    let v = crate::common::python_mcap_json(script, file);
    (
        v["counted"].as_u64().expect("counted"),
        v["summary"].as_u64(),
    )
}

/// The temporary files (`.NAME.PID.part`) in `dir`.
fn part_files(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "part"))
        .collect()
}

fn interrupt_flight(signal: libc::c_int, name: &str) {
    let dir = scratch(name);
    let file = dir.join("flight.mcap");
    // A long flight: it must still be running when the signal comes.
    let child = bin()
        .args(["sim", "cyclone-4", "--duration-s", "36000", "--out"])
        .arg(&file)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("vibrocomp runs");
    // The recorder (created after the handlers) has written its header into the
    // temporary file beside the log: then wait a little more so that some messages are
    // on their way. The log itself appears only when finished (README, "Files").
    let deadline = Instant::now() + Duration::from_secs(30);
    while part_files(&dir)
        .iter()
        .all(|p| std::fs::metadata(p).map_or(0, |m| m.len()) == 0)
    {
        assert!(
            Instant::now() < deadline,
            "the temporary file of {} never appeared",
            file.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    assert!(!file.exists(), "the log appeared before it was finished");
    let pid = i32::try_from(child.id()).expect("pid");
    // SAFETY: a plain kill(2) of the child we started.
    assert_eq!(unsafe { libc::kill(pid, signal) }, 0);
    let started = Instant::now();
    let out = child.wait_with_output().expect("vibrocomp ends");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "took {:?} to stop",
        started.elapsed()
    );
    assert_eq!(
        out.status.code(),
        Some(1),
        "exit status after {name}: {:?}; stderr:\n{stderr}",
        out.status
    );
    assert!(
        stderr.contains(&format!("interrupted by {name} at simulated time"))
            && stderr.contains("of 36000.000 s"),
        "stderr does not say where the flight stopped:\n{stderr}"
    );
    let (counted, summary) = python_counts(&file);
    assert!(counted > 0, "no messages in the interrupted log");
    assert_eq!(summary, Some(counted), "summary of the interrupted log");
    assert!(
        stderr.contains(&format!("the {counted} messages written so far")),
        "stderr does not give the {counted} messages:\n{stderr}"
    );
    // Our own reader agrees, and finds no losses.
    let info = crate::common::run_json(&["log", "info", "--json", file.to_str().expect("utf-8")]);
    assert_eq!(info["messages"].as_u64(), Some(counted), "log info: {info}");
    assert_eq!(info["lost"].as_u64(), Some(0), "log info: {info}");
    assert!(part_files(&dir).is_empty(), "a temporary file was left");
    println!("{name}: {stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sigint_finishes_the_log_of_an_interrupted_flight() {
    interrupt_flight(libc::SIGINT, "SIGINT");
}

#[test]
fn sigterm_finishes_the_log_of_an_interrupted_flight() {
    interrupt_flight(libc::SIGTERM, "SIGTERM");
}

/// A log that cannot be written (a full disk, here the file-size limit RLIMIT_FSIZE:
/// writes fail with EFBIG as they would with ENOSPC) says why, and leaves nothing: not
/// a half-written log, not its temporary file, not the previous log it would have
/// replaced (README, "Files"). A device such as /dev/full is refused as an output.
#[test]
fn a_full_disk_under_sim_out_names_the_cause_and_leaves_nothing() {
    use std::os::unix::process::CommandExt as _;
    let dir = scratch("full");
    let file = dir.join("flight.mcap");
    std::fs::write(&file, "the previous log").expect("write");
    let mut cmd = bin();
    cmd.args([
        "sim",
        "cyclone-4-short",
        "--duration-s",
        "2",
        "--force",
        "--out",
    ])
    .arg(&file);
    // SAFETY: runs in the child between fork and exec and only calls setrlimit and
    // signal, which are async-signal-safe; it allocates nothing.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 300_000,
                rlim_max: 300_000,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let out = cmd.output().expect("vibrocomp runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("File too large (os error 27)"),
        "the cause is missing:\n{stderr}"
    );
    assert_eq!(
        std::fs::read_to_string(&file).expect("the previous log"),
        "the previous log"
    );
    assert!(part_files(&dir).is_empty(), "a temporary file was left");

    let out = run_failing(&["sim", "cyclone-4-short", "--out", "/dev/full", "--force"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("output /dev/full: is a character device, not a regular file"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
