//! `identify measure` on a rig's own time-stamped records (readings `time_s,u1_v,..`
//! and a reference accelerometer `time_s,ax_g,ay_g,az_g`), on data vibrocomp did not
//! make: the independent rig generator (`tests/python/rig_generator.py`, written from
//! MODEL.md and RIG.md: an AL-15 triad on a shaker in 8 orientations, a 40 Hz tone of
//! 0.5..2 g per body axis and 20..640 Hz Gaussian random vibration at 0.002 g^2/Hz per
//! axis, readings as exact interval means; `--repeat` re-draws the random parts). The
//! command lines are written as a rig engineer writes them, from the run plan (4 s
//! still, 4 s vibrating with 0.1 s ramps, 4 s still) and the triad's axes; the
//! generator's truth is only read to compare.

use crate::common::{bin, rig_campaign, run_failing, run_json, TempDir};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

/// The run plan's windows on the files' time, s: the ramps and a margin left out.
const WINDOWS: [(&str, &str); 3] = [
    ("--still-before-s", "0,4"),
    ("--vibrating-s", "4.2,7.9"),
    ("--still-after-s", "8.1,12"),
];

/// `identify measure` of unit `k` (0-based) of the run in `folder`: the readings'
/// column `u{k+1}_v`, with the reference and the unit's axes when `axes` is given.
fn measure(folder: &Path, k: usize, axes: Option<[&str; 3]>) -> Value {
    let accel = folder.join("accel.csv");
    let column = format!("u{}_v", k + 1);
    let mut args: Vec<String> = vec![
        "identify".into(),
        "measure".into(),
        accel.display().to_string(),
        "--passport".into(),
        "AL-15".into(),
        "--column".into(),
        column,
        "--json".into(),
    ];
    for (flag, value) in WINDOWS {
        args.push(format!("{flag}={value}"));
    }
    if let Some([ia, oa, pa]) = axes {
        args.push("--reference".into());
        args.push(folder.join("reference.csv").display().to_string());
        args.push(format!("--ia={ia}"));
        args.push(format!("--oa={oa}"));
        args.push(format!("--pa={pa}"));
    }
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    run_json(&refs)
}

fn num(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} is not a number in {v}"))
}

/// Pooled over the conditions: the RMS of the stated uncertainty over the RMS of the
/// scatter (the unbiased variance over each condition's repeats, pooled by degrees of
/// freedom).
fn stated_over_scatter(rows: &BTreeMap<(String, usize), Vec<(f64, f64)>>) -> (f64, f64, f64) {
    let (mut ss, mut dof, mut u2, mut n) = (0.0, 0usize, 0.0, 0usize);
    for r in rows.values() {
        let mean = r.iter().map(|x| x.0).sum::<f64>() / r.len() as f64;
        ss += r.iter().map(|x| (x.0 - mean).powi(2)).sum::<f64>();
        dof += r.len() - 1;
        u2 += r.iter().map(|x| x.1 * x.1).sum::<f64>();
        n += r.len();
    }
    let (stated, scatter) = ((u2 / n as f64).sqrt(), (ss / dof as f64).sqrt());
    (stated / scatter, stated, scatter)
}

/// Over 5 repeats of 24 unit-run conditions (8 orientations x 3 units), `identify
/// measure` with the reference states the VE's scatter over the repeats (the pooled
/// stated uncertainty within a factor 1.5 of the pooled scatter), and every VE agrees
/// with the generator's within 4 stated sigma; without `--reference` the batch means of
/// the raw records state more than 5 times the scatter (they carry the unit's linear
/// response to the vibration), and the raw measurement beside the response-removed one
/// in `--json` is that one exactly.
#[test]
fn a_rigs_own_records_with_a_reference_state_the_scatter_of_their_repeats() {
    let dir = TempDir::new("measure-timed", "repeats");
    let repeats = 5;
    let runs = rig_campaign(
        &dir.0,
        &[
            "--sensor-rate-hz",
            "1600",
            "--still-s",
            "4",
            "--vib-s",
            "4",
            "--tone-freqs-hz",
            "40",
            "--repeat",
            &repeats.to_string(),
        ],
    );
    assert_eq!(runs.len(), 8 * repeats);
    let mut removed: BTreeMap<(String, usize), Vec<(f64, f64)>> = BTreeMap::new();
    let mut raw: BTreeMap<(String, usize), Vec<(f64, f64)>> = BTreeMap::new();
    let mut worst_pull = (0.0f64, String::new());
    let mut fitted = 0;
    for run in &runs {
        let folder = dir.0.join(&run["folder"]);
        let truth: Value =
            serde_json::from_str(&std::fs::read_to_string(folder.join("truth.json")).unwrap())
                .unwrap();
        for k in 0..3 {
            // The triad's axes, as the rig engineer knows them.
            let unit = &truth["triad"][k];
            let axes = ["ia", "oa", "pa"].map(|a| unit[a].as_str().expect(a));
            let with = measure(&folder, k, Some(axes));
            let without = measure(&folder, k, None);
            assert_eq!(with["linear_response_removed"], true);
            assert_eq!(without["linear_response_removed"], false);
            assert_eq!(with["raw"]["ve_g"], without["ve_g"], "the same raw records");
            assert_eq!(with["raw"]["ve_sigma_g"], without["ve_sigma_g"]);
            if with["linear_response_source"] == "fitted" {
                let fit = &with["linear_response"];
                let knots = fit["knots_hz"].as_array().unwrap().len();
                assert!(knots > 10 && fit["gain"].as_array().unwrap().len() == knots);
                fitted += 1;
            }
            let (ve, sigma) = (num(&with, "ve_g"), num(&with, "ve_sigma_g"));
            let ve_truth = num(&truth["units"][k], "ve_time_domain_g");
            let pull = (ve - ve_truth) / sigma;
            if pull.abs() > worst_pull.0 {
                worst_pull = (
                    pull.abs(),
                    format!(
                        "{} {}: {ve:e} +- {sigma:e} vs {ve_truth:e}",
                        run["folder"], k
                    ),
                );
            }
            let key = (run["run_id"].clone(), k);
            removed.entry(key.clone()).or_default().push((ve, sigma));
            raw.entry(key)
                .or_default()
                .push((num(&without, "ve_g"), num(&without, "ve_sigma_g")));
        }
    }
    let (ratio, stated, scatter) = stated_over_scatter(&removed);
    let (raw_ratio, raw_stated, _) = stated_over_scatter(&raw);
    println!(
        "FIGURES measure_timed: {} conditions x {repeats} repeats ({fitted} fits): stated / \
         scatter {ratio:.3} ({:.2} ug vs {:.2} ug); raw records {raw_ratio:.2} ({:.1} ug); \
         largest pull {:.2} ({})",
        removed.len(),
        stated * 1e6,
        scatter * 1e6,
        raw_stated * 1e6,
        worst_pull.0,
        worst_pull.1
    );
    assert_eq!(removed.len(), 24);
    assert_eq!(fitted, 24 * repeats, "every unit-run's response fitted");
    assert!(
        (1.0 / 1.5..=1.5).contains(&ratio),
        "stated / scatter with the linear response removed: {ratio:.3}"
    );
    assert!(
        raw_ratio > 5.0,
        "the raw records state {raw_ratio:.2} x the scatter"
    );
    assert!(
        worst_pull.0 < 4.0,
        "largest pull against the generator's VE: {:.2} ({})",
        worst_pull.0,
        worst_pull.1
    );
}

/// Bad input to `identify measure` on a rig's records: each a clear error naming the
/// file or flag, the value and the rule, with a nonzero exit code; the flags are
/// checked before any file is read (every problem at once).
#[test]
fn bad_rig_input_names_the_file_or_flag_the_value_and_the_rule() {
    let dir = TempDir::new("measure-timed", "bad");
    let runs = rig_campaign(
        &dir.0,
        &[
            "--sensor-rate-hz",
            "1600",
            "--still-s",
            "1",
            "--vib-s",
            "1",
            "--tone-freqs-hz",
            "40",
            "--orientations",
            "+z",
        ],
    );
    let folder = dir.0.join(&runs[0]["folder"]);
    let accel = folder.join("accel.csv").display().to_string();
    let reference = folder.join("reference.csv");
    let text = std::fs::read_to_string(&reference).unwrap();
    let base = |file: &str| -> Vec<String> {
        [
            "identify",
            "measure",
            file,
            "--passport",
            "AL-15",
            "--column",
            "u3_v",
            "--still-before-s",
            "0,1",
            "--vibrating-s",
            "1.2,1.9",
            "--still-after-s",
            "2.1,3",
        ]
        .map(String::from)
        .to_vec()
    };
    let failing = |args: &[String], needles: &[&str]| {
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = run_failing(&refs);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let e = String::from_utf8_lossy(&out.stderr);
        for n in needles {
            assert!(e.contains(n), "{n:?} missing in:\n{e}");
        }
        e.into_owned()
    };
    // The readings' file works with its reference (the unit AK3 has IA along +z).
    let mut good = base(&accel);
    good.extend(["--reference".into(), reference.display().to_string()]);
    good.extend(["--ia", "+z", "--oa", "+x", "--pa", "+y", "--json"].map(String::from));
    let refs: Vec<&str> = good.iter().map(String::as_str).collect();
    assert_eq!(run_json(&refs)["linear_response_source"], "fitted");

    // A reference without its z column: the file, the line, the column and what it has.
    let no_z = folder.join("reference-no-z.csv");
    let cut: String = text
        .lines()
        .map(|l| match l.starts_with('#') {
            true => format!("{l}\n"),
            false => format!("{}\n", l.rsplit_once(',').map_or(l, |(a, _)| a)),
        })
        .collect();
    std::fs::write(&no_z, cut).unwrap();
    let mut args = base(&accel);
    args.extend(["--reference".into(), no_z.display().to_string()]);
    args.extend(["--ia", "z"].map(String::from));
    failing(
        &args,
        &[
            &no_z.display().to_string(),
            "header (line 3): missing column \"az_g\" (the file has: time_s, ax_g, ay_g)",
        ],
    );
    // With --json the error object names the file.
    args.push("--json".into());
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = run_failing(&refs);
    let json: Value = serde_json::from_slice(&out.stdout).expect("a JSON error object");
    assert_eq!(json["error"]["file"], no_z.display().to_string());

    // A reference that stops before the readings' last window ends.
    let short = folder.join("reference-short.csv");
    let kept: String = text
        .lines()
        .filter(|l| {
            l.starts_with('#')
                || l.starts_with("time_s")
                || l.split(',').next().and_then(|t| t.parse::<f64>().ok()) < Some(2.5)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&short, kept).unwrap();
    let mut args = base(&accel);
    args.extend(["--reference".into(), short.display().to_string()]);
    args.extend(["--ia=-z"].map(String::from));
    failing(
        &args,
        &[
            &short.display().to_string(),
            "the segments span 0..3 s, the reference 0..2.499375 s: the reference must cover \
             every segment",
        ],
    );

    // Bad flags: every problem at once, before any file is read (the readings' file
    // does not exist).
    let missing = dir.0.join("no-such-readings.csv").display().to_string();
    let mut args = base(&missing);
    let at = args.iter().position(|a| a == "--vibrating-s").unwrap();
    args[at + 1] = "0.5,1.5".into();
    args.extend(["--reference", "no-such-reference.csv", "--ia", "0,0,0.9"].map(String::from));
    args.extend(["--oa", "x"].map(String::from));
    let e = failing(
        &args,
        &[
            "3 bad values",
            "--vibrating-s = [0.5, 1.5]: must start at or after --still-before-s's end (1): \
             still, vibrating, still, in that order",
            "--ia = \"0,0,0.9\": must be a unit vector (its norm is 0.900000, allowed 1 +- 0.001)",
            "--pa: missing: give OA and PA both or neither",
        ],
    );
    assert!(!e.contains("cannot read"), "a file was read:\n{e}");
    // Rig flags on the records' layout, and a window of three values.
    let out = bin()
        .args(["identify", "measure", &missing, "--passport", "AL-15"])
        .args(["--reference", "r.csv", "--still-before-s", "0,1,2"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let e = String::from_utf8_lossy(&out.stderr);
    for n in [
        "--still-before-s = 0,1,2: must be two times FROM,TO in s",
        "--column: missing",
        "--vibrating-s: missing",
        "--ia: missing",
    ] {
        assert!(e.contains(n), "{n:?} missing in:\n{e}");
    }
}
