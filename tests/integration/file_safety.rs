//! Files `vibrocomp` must not harm or be harmed by (README, "Files"; "Reliability",
//! rounds two and four): one table of every command that writes, each fed a link, a
//! dangling link, a FIFO, a device, a directory, an existing file without `--force`
//! and another user's planted link; `--force` never replaces what is not a regular
//! file; an input is never an output. (Recovery after damage in the middle of a file
//! is tested in vibro-mcap's tests/mcap/recover.rs.)

use crate::common::{bin, run_failing};
use crate::processes::Dir;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

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

/// How a writing command's output is named: a file, or a folder of results.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Writes {
    File,
    /// A folder; the file a previous run leaves in it.
    Folder(&'static str),
}

/// One command that writes: its arguments, `OUT` standing for the output.
struct Writer {
    args: Vec<String>,
    writes: Writes,
    /// Whether it takes `--force` (`lab ... --table-out` does not: never replaced).
    force: bool,
}

/// The inputs the writers read: each command, given an output the rule accepts, would
/// write it.
struct Inputs {
    csv: PathBuf,
    log: PathBuf,
    table: PathBuf,
}

/// EVERY command that writes a file a user names (README, "Files"), in one table: a
/// new writing command is added here, and the rule is then checked for it too.
fn writers(inputs: &Inputs) -> Vec<Writer> {
    let (csv, log, table) = (s(&inputs.csv), s(&inputs.log), s(&inputs.table));
    let prefix = crate::processes::prefix("rule");
    let file = |args: &[&str]| Writer {
        args: args.iter().map(|a| a.to_string()).collect(),
        writes: Writes::File,
        force: true,
    };
    vec![
        file(&["record", "OUT", "--prefix", &prefix, "--duration-s", "1"]),
        file(&["up", "--prefix", &prefix, "--record", "OUT"]),
        file(&["log", "import", "--accel", csv, "--out", "OUT"]),
        file(&["log", "recover", log, "OUT"]),
        file(&["log", "compensate", log, "--out", "OUT"]),
        file(&[
            "sim",
            "cyclone-4-short",
            "--duration-s",
            "0.1",
            "--out",
            "OUT",
        ]),
        file(&["sim", "lab-walkthrough", "--summary-csv", "OUT"]),
        file(&["sim", "lab-walkthrough", "--lab-csv", "OUT"]),
        file(&["sim", "lab-walkthrough", "--positions-csv", "OUT"]),
        // The manifest is not read: the output is checked first.
        file(&[
            "identify",
            "campaign",
            "/no/such/manifest.toml",
            "--table-out",
            "OUT",
        ]),
        file(&["lab", "add", "resonance", "--from", table, "--out", "OUT"]),
        Writer {
            force: false,
            ..file(&["lab", "compare", table, "--table-out", "OUT"])
        },
        Writer {
            writes: Writes::Folder("index.html"),
            ..file(&["lab", "report", table, "--out", "OUT"])
        },
        Writer {
            writes: Writes::Folder("session.mcap"),
            ..file(&["demo", "--out-dir", "OUT"])
        },
    ]
}

/// What the output is, in each case fed to every writer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Case {
    /// A symbolic link to an existing file (a folder for a folder's writer).
    Link,
    /// A symbolic link to nothing: its target must not be created.
    Dangling,
    /// A FIFO with no reader: the command must not block in `open()`.
    Fifo,
    /// A device (`/dev/null`).
    Device,
    /// A directory, for a file's writer.
    Directory,
    /// An existing regular file (a previous run's folder for a folder's writer).
    Existing,
    /// Another user's (uid 65534) link in a sticky 01777 folder to a root-only file
    /// (0600) or folder (0700): the planted link of the issue. Root only.
    Planted,
}

/// Runs `cmd` for at most `limit`, killing it then; returns its output and whether it
/// had to be killed.
fn run_killed_after(cmd: &mut Command, limit: Duration) -> (Output, bool) {
    let start = Instant::now();
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("vibrocomp starts");
    let mut killed = false;
    while child.try_wait().expect("wait").is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            killed = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    (child.wait_with_output().expect("output"), killed)
}

/// The binary checked: `VIBROCOMP_FILE_RULE_BIN` if set (to run the same table on
/// another build, e.g. the one before the rule's helper), else the one built here.
fn writer_bin() -> Command {
    match std::env::var_os("VIBROCOMP_FILE_RULE_BIN") {
        Some(p) => Command::new(p),
        None => bin(),
    }
}

/// The user this test runs as, from a file it creates (no libc in these tests).
fn my_uid(dir: &Path) -> u32 {
    use std::os::unix::fs::MetadataExt;
    let probe = dir.join("uid-probe");
    std::fs::write(&probe, "").expect("write");
    let uid = std::fs::metadata(&probe).expect("stat").uid();
    std::fs::remove_file(&probe).expect("remove");
    uid
}

/// A file's bytes, or what stands there instead (for the figures of a failure).
fn describe(path: &Path) -> String {
    match std::fs::symlink_metadata(path) {
        Err(_) => "nothing".into(),
        Ok(m) if m.is_dir() => format!(
            "a folder of {} entries",
            std::fs::read_dir(path).map_or(0, |d| d.count())
        ),
        Ok(m) if m.file_type().is_symlink() => "a link".into(),
        Ok(m) => format!("{} bytes", m.len()),
    }
}

/// README, "Files", for every writing command of [`writers`]: an output that is a
/// symbolic link (to a file, or dangling), a FIFO, a device, a directory, an existing
/// file without `--force`, or another user's link planted in a sticky folder is
/// refused, within seconds (a FIFO never blocks), with a message naming the output and
/// why; the link's target keeps its bytes (a dangling one is not created), and nothing
/// is left behind. Every failure is listed at once, with the target's size before and
/// after.
#[cfg(unix)]
#[test]
fn every_writing_command_keeps_the_file_rule() {
    use std::os::unix::fs::{symlink, PermissionsExt};
    let dir = Dir::new("file-rule");
    let inputs_dir = dir.path("inputs");
    std::fs::create_dir(&inputs_dir).expect("mkdir");
    let csv = inputs_dir.join("accel.csv");
    accel_csv(&csv);
    let log = inputs_dir.join("log.mcap");
    let made = bin()
        .args(["log", "import", "--accel", s(&csv), "--out", s(&log)])
        .output()
        .expect("runs");
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let inputs = Inputs {
        csv,
        log,
        table: crate::common::repo_path("examples/python/data/campaign-mount-k6.csv"),
    };
    let root = my_uid(&inputs_dir) == 0;
    if !root {
        eprintln!(
            "not root: another user's planted link cannot be made (lchown); that case is skipped"
        );
    }
    let limit = Duration::from_secs(10);
    let mut failures = Vec::new();
    let mut runs = 0;
    for (n, w) in writers(&inputs).iter().enumerate() {
        for case in [
            Case::Link,
            Case::Dangling,
            Case::Fifo,
            Case::Device,
            Case::Directory,
            Case::Existing,
            Case::Planted,
        ] {
            let folder = matches!(w.writes, Writes::Folder(_));
            if (case == Case::Directory && folder) || (case == Case::Planted && !root) {
                continue;
            }
            // Each case in a folder of its own, sticky and open to all like /tmp.
            let d = dir.path(&format!("w{n}-{case:?}"));
            std::fs::create_dir(&d).expect("mkdir");
            std::fs::set_permissions(&d, std::fs::Permissions::from_mode(0o1777)).expect("chmod");
            let out = d.join(if folder { "results" } else { "out.mcap" });
            // What must not change: the link's target, the existing output.
            let target = d.join(if case == Case::Planted {
                "secret"
            } else {
                "target"
            });
            let mut force = w.force;
            match case {
                Case::Link | Case::Planted => {
                    if folder {
                        std::fs::create_dir(&target).expect("mkdir");
                    } else {
                        std::fs::write(&target, "kept: 12 by").expect("write");
                    }
                    if case == Case::Planted {
                        let mode = if folder { 0o700 } else { 0o600 };
                        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(mode))
                            .expect("chmod");
                    }
                    symlink(&target, &out).expect("symlink");
                    if case == Case::Planted {
                        std::os::unix::fs::lchown(&out, Some(65534), Some(65534)).expect("lchown");
                    }
                    // As the user: no --force.
                    force = false;
                }
                Case::Dangling => {
                    symlink(&target, &out).expect("symlink");
                    force = false;
                }
                Case::Fifo => {
                    mkfifo(&out);
                    force = false;
                }
                Case::Directory => std::fs::create_dir(&out).expect("mkdir"),
                Case::Device => {}
                Case::Existing => {
                    let kept = match w.writes {
                        Writes::File => out.clone(),
                        Writes::Folder(previous) => {
                            std::fs::create_dir(&out).expect("mkdir");
                            out.join(previous)
                        }
                    };
                    std::fs::write(&kept, "kept: 12 by").expect("write");
                    force = false;
                }
            }
            let out_arg = if case == Case::Device {
                PathBuf::from("/dev/null")
            } else {
                out.clone()
            };
            let mut args: Vec<String> = w
                .args
                .iter()
                .map(|a| {
                    if a == "OUT" {
                        s(&out_arg).to_string()
                    } else {
                        a.clone()
                    }
                })
                .collect();
            if force {
                args.push("--force".into());
            }
            let before = describe(&target);
            let started = Instant::now();
            let (output, killed) = run_killed_after(writer_bin().args(&args), limit);
            let took_s = started.elapsed().as_secs_f64();
            runs += 1;
            let err = String::from_utf8_lossy(&output.stderr);
            let last = err.lines().last().unwrap_or("").to_string();
            let why = match (case, w.writes) {
                (Case::Link | Case::Dangling | Case::Planted, _) => "is a symbolic link to",
                (Case::Fifo, _) => "is a FIFO (named pipe)",
                (Case::Device, _) => "is a character device",
                (Case::Directory, _) => "is a directory, not a file",
                (Case::Existing, _) => "pass --force to overwrite it",
            };
            let mut problems = Vec::new();
            if killed {
                problems.push(format!("still running after {limit:?} (killed)"));
            } else if output.status.code() != Some(1) {
                problems.push(format!("exit {:?}, not a refusal", output.status.code()));
            }
            if !err.contains(s(&out_arg)) || !err.contains(why) {
                problems.push(format!("message without the output or {why:?}: {last:?}"));
            }
            let after = describe(&target);
            if after != before {
                problems.push(format!("target {}: {before} -> {after}", target.display()));
            }
            if case == Case::Existing {
                let kept = match w.writes {
                    Writes::File => out.clone(),
                    Writes::Folder(previous) => out.join(previous),
                };
                if std::fs::read(&kept).ok().as_deref() != Some(&b"kept: 12 by"[..]) {
                    problems.push(format!("the existing output is now {}", describe(&kept)));
                }
            }
            // What stands at the output is what the case made, and nothing else was
            // made in the folder (no part file, no probe).
            let kind = std::fs::symlink_metadata(&out).map(|m| m.file_type());
            let kept_kind = match case {
                Case::Link | Case::Dangling | Case::Planted => kind.is_ok_and(|t| t.is_symlink()),
                Case::Fifo => {
                    use std::os::unix::fs::FileTypeExt;
                    kind.is_ok_and(|t| t.is_fifo())
                }
                Case::Directory => kind.is_ok_and(|t| t.is_dir()),
                Case::Device => kind.is_err(),
                Case::Existing => kind.is_ok(),
            };
            if !kept_kind {
                problems.push(format!("the output is now {}", describe(&out)));
            }
            let mut left: Vec<String> = std::fs::read_dir(&d)
                .expect("read dir")
                .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
                .filter(|n| !["out.mcap", "results", "target", "secret"].contains(&n.as_str()))
                .collect();
            left.sort();
            if !left.is_empty() {
                problems.push(format!("left behind: {left:?}"));
            }
            if !problems.is_empty() {
                failures.push(format!(
                    "vibrocomp {} [{case:?}, {took_s:.2} s]: {}",
                    args.join(" "),
                    problems.join("; ")
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {runs} runs broke the file rule:\n{}",
        failures.len(),
        failures.join("\n")
    );

    // With --force a regular file is replaced, with a complete log.
    let old = dir.path("old.mcap");
    std::fs::write(&old, "the previous output").expect("write");
    let o = s(&old);
    let v = crate::common::run_json(&[
        "sim",
        "cyclone-4-short",
        "--duration-s",
        "0.1",
        "--out",
        o,
        "--force",
        "--json",
    ]);
    assert_eq!(v["out"], o);
    let info = crate::common::run_json(&["log", "info", o, "--json"]);
    assert!(info["messages"].as_u64().expect("messages") > 0, "{info}");
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
