//! `vibrocomp archive run` (docs/archive.md): a small archive of simulated flights, a
//! campaign table written by the independent generator, a damaged log and a file that is
//! no log, through two models. The table is read back by pyarrow (not our reader); the
//! compensation errors are held against `log compensate` + `log errors`, the lab's
//! parameters against the campaign's hidden truth; a run killed with SIGKILL leaves no
//! worker and goes on where it stopped; 1 and 2 workers give the same table; the report
//! opens in headless Chromium with its plots.

use crate::common::{bin, heavy, repo_path};
use crate::processes::{children, poll, Dir};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

/// A simulated short flight (the demo's scenario) with its own seed.
fn flight(dir: &Dir, name: &str, seconds: &str, seed: &str) -> PathBuf {
    let out = dir.path(name);
    let o = bin()
        .args([
            "sim",
            "cyclone-4-short",
            "--duration-s",
            seconds,
            "--seed",
            seed,
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// The archive: two flights, a damaged copy of one (cut at 60 %), a text file listed as
/// a log, the independent generator's campaign for two units; models `shipped` and
/// `estimate` (the compensator's estimate stage alone).
fn archive(dir: &Dir) -> PathBuf {
    let a = flight(dir, "run-001.mcap", "6", "11");
    flight(dir, "run-002.mcap", "6", "12");
    let bytes = std::fs::read(&a).unwrap();
    std::fs::write(
        dir.path("run-003-damaged.mcap"),
        &bytes[..bytes.len() * 6 / 10],
    )
    .unwrap();
    std::fs::write(dir.path("notes.txt"), "not a log\n").unwrap();
    std::fs::copy(
        repo_path("examples/python/data/campaign-mount-k6.csv"),
        dir.path("campaign.csv"),
    )
    .unwrap();
    let shipped = std::fs::read_to_string(repo_path("config/services/compensator.toml")).unwrap();
    let estimate = shipped.replace("stage = \"waveform\"", "stage = \"estimate\"");
    assert_ne!(estimate, shipped);
    std::fs::write(dir.path("compensator-estimate.toml"), estimate).unwrap();
    let manifest = dir.path("batch.toml");
    std::fs::write(
        &manifest,
        r#"format = "vibrocomp-archive/1"
window_s = 0.5
[lab]
max_effects = 2
[[model]]
name = "shipped"
[[model]]
name = "estimate"
compensator_config = "compensator-estimate.toml"
[[log]]
path = "run-001.mcap"
units = ["SN-1001", "SN-1002", "SN-1003"]
[[log]]
path = "run-002.mcap"
units = ["SN-1001", "SN-2002", "SN-2003"]
[[log]]
path = "run-003-damaged.mcap"
units = ["SN-3001"]
[[log]]
path = "notes.txt"
units = ["SN-4001"]
[[table]]
path = "campaign.csv"
unit = "SN-T1"
[[table]]
path = "campaign.csv"
unit = "SN-T2"
"#,
    )
    .unwrap();
    manifest
}

/// `archive run MANIFEST --out OUT --workers N --json`: the summary, and the seconds.
fn run(manifest: &Path, out: &Path, workers: &str) -> (serde_json::Value, f64) {
    let start = Instant::now();
    let o = bin()
        .args([
            "archive",
            "run",
            s(manifest),
            "--out",
            s(out),
            "--workers",
            workers,
            "--json",
        ])
        .output()
        .unwrap();
    let secs = start.elapsed().as_secs_f64();
    assert!(
        o.status.success(),
        "archive run: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    (serde_json::from_slice(&o.stdout).unwrap(), secs)
}

/// A table's rows, column to value.
type Rows = Vec<BTreeMap<String, serde_json::Value>>;

/// The table as pyarrow reads it: its columns with their Arrow types, and its rows.
fn read_parquet(path: &Path) -> (Vec<(String, String)>, Rows) {
    let script = "import json, sys, math\nimport pyarrow.parquet as pq\nt = pq.read_table(sys.argv[1])\n\
                  rows = t.to_pylist()\n\
                  print(json.dumps({'schema': [[f.name, str(f.type)] for f in t.schema], 'rows': rows}))\n";
    let o = Command::new("python3")
        .args(["-c", script, s(path)])
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt: pyarrow)");
    assert!(
        o.status.success(),
        "pyarrow cannot read {}: {}",
        path.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let schema = v["schema"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f[0].as_str().unwrap().to_string(),
                f[1].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let rows = serde_json::from_value(v["rows"].clone()).unwrap();
    (schema, rows)
}

/// The rows without the timing columns.
fn untimed(rows: &[BTreeMap<String, serde_json::Value>]) -> Rows {
    rows.iter()
        .map(|r| {
            let mut r = r.clone();
            r.remove("elapsed_s");
            r.remove("worker");
            r
        })
        .collect()
}

fn text<'a>(r: &'a BTreeMap<String, serde_json::Value>, key: &str) -> &'a str {
    r[key].as_str().unwrap_or("")
}

/// `log compensate` then `log errors --json`: the errors the archive must report.
fn reference_errors(dir: &Dir, log: &Path, args: &[&str], name: &str) -> serde_json::Value {
    let session = dir.path(name);
    let o = bin()
        .args(["log", "compensate", s(log), "--out", s(&session)])
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "log compensate: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = bin()
        .args(["log", "errors", s(&session), "--json"])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "log errors: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()["errors"].clone()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

#[test]
fn an_archive_runs_every_log_with_every_model_resumes_after_a_kill_and_reports() {
    let _heavy = heavy();
    let dir = Dir::new("archive");
    let manifest = archive(&dir);
    let out2 = dir.path("out-2");
    let (summary, secs2) = run(&manifest, &out2, "2");
    // 4 logs x 2 models, and 9 units (SN-1001 in two logs).
    assert_eq!(summary["jobs_total"], 17, "{summary}");
    assert_eq!(summary["done_now"], 17, "{summary}");
    assert_eq!(summary["pending"], 0, "{summary}");
    // The damaged log and the text file with each model, and their units' lab jobs.
    assert_eq!(summary["failed"], 6, "{summary}");
    let (schema, rows) = read_parquet(&out2.join("results.parquet"));
    let types: BTreeMap<&str, &str> = schema
        .iter()
        .map(|(n, t)| (n.as_str(), t.as_str()))
        .collect();
    for (col, ty) in [
        ("job", "string"),
        ("error_g", "double"),
        ("windows", "int64"),
        ("value", "double"),
        ("problem", "string"),
        ("elapsed_s", "double"),
    ] {
        assert_eq!(types.get(col), Some(&ty), "{schema:?}");
    }
    assert_eq!(rows.len() as u64, summary["rows"].as_u64().unwrap());

    // One failed row per bad log and model, naming the file.
    for (i, file) in [(2, "run-003-damaged.mcap"), (3, "notes.txt")] {
        for model in ["shipped", "estimate"] {
            let job = format!("compensate/{i}/{model}");
            let of: Vec<_> = rows.iter().filter(|r| text(r, "job") == job).collect();
            assert_eq!(of.len(), 1, "{job}: {of:?}");
            assert_eq!(text(of[0], "verdict"), "failed");
            assert!(text(of[0], "problem").contains(file), "{:?}", of[0]);
            assert_eq!(text(of[0], "log"), file);
        }
    }

    // The compensation errors are `log compensate` + `log errors`'s, unit by unit.
    for (i, log, units) in [
        (0, "run-001.mcap", ["SN-1001", "SN-1002", "SN-1003"]),
        (1, "run-002.mcap", ["SN-1001", "SN-2002", "SN-2003"]),
    ] {
        for (model, args) in [
            ("shipped", vec![]),
            (
                "estimate",
                vec![
                    "--compensator-config",
                    s(&dir.path("compensator-estimate.toml")),
                ],
            ),
        ] {
            let expected = reference_errors(
                &dir,
                &dir.path(log),
                &args,
                &format!("ref-{i}-{model}.mcap"),
            );
            let job = format!("compensate/{i}/{model}");
            for u in expected["units"].as_array().unwrap() {
                let unit = units[u["unit"].as_u64().unwrap() as usize - 1];
                for stage in [
                    "uncompensated",
                    "main_removed",
                    "vibration_removed",
                    "estimate_stage",
                ] {
                    let want = u[format!("{stage}_rms_g")].as_f64();
                    let got: Vec<_> = rows
                        .iter()
                        .filter(|r| {
                            text(r, "job") == job
                                && text(r, "unit") == unit
                                && text(r, "stage") == stage
                        })
                        .collect();
                    match want {
                        Some(w) => {
                            assert_eq!(got.len(), 1, "{job} {unit} {stage}");
                            let g = got[0]["error_g"].as_f64().unwrap();
                            assert!(
                                close(g, w),
                                "{job} {unit} {stage}: {g} against log errors' {w}"
                            );
                            assert_eq!(text(got[0], "verdict"), "ok");
                            assert_eq!(got[0]["window_s"], 0.5);
                            assert!(got[0]["windows"].as_i64().unwrap() >= 5, "{:?}", got[0]);
                        }
                        None => assert!(got.is_empty(), "{job} {unit} {stage}: {got:?}"),
                    }
                }
            }
        }
    }

    // The campaign's units: the lab finds the generator's hidden effects and values.
    let truth: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(repo_path(
            "examples/python/data/campaign-mount-k6.truth.json",
        ))
        .unwrap(),
    )
    .unwrap();
    for unit in ["SN-T1", "SN-T2"] {
        let of: Vec<_> = rows
            .iter()
            .filter(|r| text(r, "job") == format!("lab/{unit}"))
            .collect();
        assert_eq!(text(of[0], "verdict"), "effect", "{of:?}");
        assert_eq!(
            text(of[0], "effect"),
            "mount_resonance+high_order_nonlinearity"
        );
        for (effect, param) in [("mount_resonance", "freq_hz"), ("mount_resonance", "q")] {
            let r = of
                .iter()
                .find(|r| text(r, "effect") == effect && text(r, "param") == param)
                .unwrap_or_else(|| panic!("no {effect}.{param} in {of:?}"));
            let (v, sigma) = (r["value"].as_f64().unwrap(), r["sigma"].as_f64().unwrap());
            let t = truth["params"][effect][param].as_f64().unwrap();
            assert!(
                (v - t).abs() <= 5.0 * sigma + 1e-6 * t.abs(),
                "{effect}.{param} = {v} +/- {sigma}, truth {t}"
            );
        }
    }
    // A unit of two logs is diagnosed from both; a unit of a bad log only, failed.
    let sn1001: Vec<_> = rows
        .iter()
        .filter(|r| text(r, "job") == "lab/SN-1001")
        .collect();
    assert!(sn1001[0]["windows"].as_i64().unwrap() > 0, "{sn1001:?}");
    assert_ne!(text(sn1001[0], "verdict"), "failed", "{sn1001:?}");
    let sn3001: Vec<_> = rows
        .iter()
        .filter(|r| text(r, "job") == "lab/SN-3001")
        .collect();
    assert_eq!(text(sn3001[0], "verdict"), "failed");
    assert!(
        text(sn3001[0], "problem").contains("run-003-damaged.mcap"),
        "{sn3001:?}"
    );

    // One worker: the same table.
    let out1 = dir.path("out-1");
    let (_, secs1) = run(&manifest, &out1, "1");
    let (_, rows1) = read_parquet(&out1.join("results.parquet"));
    assert_eq!(untimed(&rows1), untimed(&rows), "1 and 2 workers");
    eprintln!(
        "archive: 17 jobs in {secs1:.1} s with 1 worker ({:.2} jobs/s), {secs2:.1} s with 2 ({:.2} jobs/s)",
        17.0 / secs1,
        17.0 / secs2
    );

    // Killed mid-run with SIGKILL after a few results: no worker left behind.
    let out3 = dir.path("out-3");
    let mut child = bin()
        .args([
            "archive",
            "run",
            s(&manifest),
            "--out",
            s(&out3),
            "--workers",
            "2",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let journal = out3.join("journal.jsonl");
    let lines = || std::fs::read_to_string(&journal).map_or(0, |t| t.lines().count());
    let mut workers = Vec::new();
    assert!(
        poll(Duration::from_secs(300), || {
            for (pid, cmd) in children(child.id()) {
                if cmd.contains("archive worker") && !workers.contains(&pid) {
                    workers.push(pid);
                }
            }
            lines() >= 4
        }),
        "no results in the journal"
    );
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!workers.is_empty());
    let gone = |pid: &u32| {
        std::fs::read_to_string(format!("/proc/{pid}/stat")).map_or(true, |st| {
            st.split(") ").nth(1).is_some_and(|x| x.starts_with('Z'))
        })
    };
    assert!(
        poll(Duration::from_secs(10), || workers.iter().all(gone)),
        "workers left running after the batch was killed: {workers:?}"
    );
    let before = lines();
    assert!(
        before < 18,
        "the kill came too late to test a resume ({before} lines)"
    );
    // And a torn last line, as a kill mid-write leaves it.
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&journal)
        .unwrap();
    std::io::Write::write_all(&mut f, b"{\"job\":\"compensate/1/shi").unwrap();
    drop(f);
    let (resumed, _) = run(&manifest, &out3, "2");
    assert_eq!(
        resumed["skipped"].as_u64().unwrap(),
        before as u64 - 1,
        "{resumed}"
    );
    assert_eq!(
        resumed["done_now"].as_u64().unwrap(),
        18 - before as u64,
        "{resumed}"
    );
    assert!(resumed["torn_bytes"].as_u64().unwrap() > 0, "{resumed}");
    assert_eq!(resumed["duplicates"], 0, "{resumed}");
    // Every job exactly once in the journal and the table, which is the clean run's.
    let text3 = std::fs::read_to_string(&journal).unwrap();
    let mut ids: Vec<String> = text3
        .lines()
        .skip(1)
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["job"]
                .as_str()
                .unwrap()
                .to_string()
        })
        .collect();
    assert_eq!(ids.len(), 17);
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 17);
    let (_, rows3) = read_parquet(&out3.join("results.parquet"));
    assert_eq!(untimed(&rows3), untimed(&rows), "resumed against clean");
    // Nothing left to do: a third run runs nothing and writes the same table.
    let (again, _) = run(&manifest, &out3, "2");
    assert_eq!(
        (again["done_now"].as_u64(), again["skipped"].as_u64()),
        (Some(0), Some(17))
    );
    assert!(
        std::fs::read_dir(out3.join("sessions"))
            .unwrap()
            .next()
            .is_none(),
        "sessions removed"
    );

    report_shows_its_plots(&out2.join("report.html"), &dir.path("report.png"));
    let html = std::fs::read_to_string(out2.join("report.html")).unwrap();
    for part in [
        "The worst runs",
        "mount_resonance",
        "run-003-damaged.mcap",
        "notes.txt",
        "SN-T2",
    ] {
        assert!(html.contains(part), "no {part} in the report");
    }
}

/// A headless-Chromium screenshot of the report: the plots' colours (the models' blue
/// and orange points, the effects' green bars) cover thousands of pixels; the page's
/// text is black on white, so an empty plot fails.
fn report_shows_its_plots(html: &Path, png: &Path) {
    let (pixels, channels) = crate::common::screenshot(html, png);
    let near = crate::common::near;
    let (mut blue, mut orange, mut green) = (0usize, 0usize, 0usize);
    for px in pixels.chunks(channels) {
        blue += usize::from(near(px, [31, 119, 180]));
        orange += usize::from(near(px, [255, 127, 14]));
        green += usize::from(near(px, [44, 160, 44]));
    }
    assert!(
        blue > 500 && orange > 500 && green > 2000,
        "blue {blue}, orange {orange}, green {green}"
    );
}

#[test]
fn manifest_problems_are_reported_at_once_with_file_line_and_key() {
    let dir = Dir::new("archive-manifest");
    std::fs::write(dir.path("a.mcap"), "x").unwrap();
    let manifest = dir.path("m.toml");
    std::fs::write(
        &manifest,
        "format = \"vibrocomp-archive/1\"\n[[model]]\nname = \"m\"\n[[model]]\nname = \"m\"\n\
         [[log]]\npath = \"missing.mcap\"\nunits = [\"A\"]\n",
    )
    .unwrap();
    let out = dir.path("out");
    let o = bin()
        .args(["archive", "run", s(&manifest), "--out", s(&out), "--json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&format!("manifest {}: 2 problems", manifest.display())),
        "{err}"
    );
    assert!(
        err.contains("line 5: model[1].name: \"m\": a second model of this name"),
        "{err}"
    );
    assert!(
        err.contains("line 7: log[0].path: \"missing.mcap\": no such file"),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["error"]["file"], s(&manifest));
    assert_eq!(v["error"]["line"], 5);
    assert_eq!(v["error"]["key"], "model[1].name");
    assert!(!out.exists(), "nothing made for a refused manifest");

    // Unknown keys: every one, with a suggestion (before the other rules).
    std::fs::write(
        &manifest,
        "format = \"vibrocomp-archive/1\"\nwindw_s = 1.0\n[[model]]\nname = \"m\"\nestimator = \"e.toml\"\n\
         [[log]]\npath = \"a.mcap\"\nunits = [\"A\"]\n",
    )
    .unwrap();
    let o = bin()
        .args(["archive", "run", s(&manifest), "--out", s(&out)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("line 2, column 1: windw_s: unknown key (did you mean window_s?)"),
        "{err}"
    );
    assert!(
        err.contains("line 5, column 1: model[0].estimator: unknown key"),
        "{err}"
    );
}

#[test]
fn an_output_folder_or_table_that_is_a_link_is_refused() {
    let dir = Dir::new("archive-links");
    std::fs::copy(
        repo_path("examples/python/data/campaign-mount-k6.csv"),
        dir.path("t.csv"),
    )
    .unwrap();
    let manifest = dir.path("m.toml");
    std::fs::write(
        &manifest,
        "format = \"vibrocomp-archive/1\"\n[lab]\nmax_effects = 1\n[[model]]\nname = \"m\"\n[[table]]\npath = \"t.csv\"\nunit = \"U\"\n",
    )
    .unwrap();
    let elsewhere = dir.path("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let link = dir.path("out-link");
    std::os::unix::fs::symlink(&elsewhere, &link).unwrap();
    let o = bin()
        .args(["archive", "run", s(&manifest), "--out", s(&link)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("is a symbolic link"), "{err}");
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);

    let out = dir.path("out");
    std::fs::create_dir(&out).unwrap();
    let victim = dir.path("victim.parquet");
    std::fs::write(&victim, "precious").unwrap();
    std::os::unix::fs::symlink(&victim, out.join("results.parquet")).unwrap();
    let o = bin()
        .args(["archive", "run", s(&manifest), "--out", s(&out)])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("results.parquet") && err.contains("symbolic link"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    assert!(
        !out.join("journal.jsonl").exists(),
        "refused before any work"
    );

    // The lab alone on one table, in the folder once the link is gone.
    std::fs::remove_file(out.join("results.parquet")).unwrap();
    let o = bin()
        .args(["archive", "run", s(&manifest), "--out", s(&out), "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (v["jobs_total"].as_u64(), v["failed"].as_u64()),
        (Some(1), Some(0)),
        "{v}"
    );

    // --dask without the Python package: a clear error.
    let o = bin()
        .args([
            "archive",
            "run",
            s(&manifest),
            "--out",
            s(&out),
            "--dask",
            "tcp://127.0.0.1:1",
        ])
        .env("VIBROCOMP_PYTHON", dir.path("no-python"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--dask: cannot run the Python interpreter")
            && err.contains("VIBROCOMP_PYTHON"),
        "{err}"
    );
}
