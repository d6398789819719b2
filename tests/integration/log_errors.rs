//! `vibrocomp log errors`: the stage-error table of a recorded session.
//!
//! - A simulated flight replayed into `vibrocomp up --record` (the way the command's
//!   own hint tells a user to make a session): `log errors --json` agrees with an
//!   independent computation from the raw messages (`tests/python/stage_errors.py`:
//!   the PyPI `mcap` reader and numpy) to 1e-9 relative, at the default window and
//!   another; the text prints the JSON's figures (to the digits it shows). With the
//!   shipped compensator (the waveform stage) both stages and the blocks per stage;
//!   with `stage = "estimate"` the one-stage table of older logs.
//! - Bad input fails with exit 1 and a message naming the file and what is missing:
//!   no compensated stream, no reference, no passports, not MCAP, truncated.
//!
//! That the demo prints the same figures as `log errors` on its recording is checked
//! in `replay::the_demo_cuts_the_error_tenfold_and_loses_nothing`.

use crate::common::{bin, repo_path, run_failing, run_json};
use crate::processes::{flight_log, recorded_replay, Dir};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use vibro_mcap::{Recorder, RecorderOptions};
use vibro_msgs::{AccelBlock, CompensatedBlock, MessageKind, TruthBlock};

/// A session: `sim` flies `seconds` of the demo's scenario, `up --record` runs the
/// shipped services and a recorder, `replay` feeds them the flight (as fast as
/// possible, lock-stepped), and Ctrl-C to `up` finishes the recording.
fn recorded_session(dir: &Dir, seconds: &str) -> PathBuf {
    let flight = flight_log(dir, seconds);
    let session = dir.path("session.mcap");
    recorded_replay(
        &flight,
        &session,
        "le",
        &repo_path("config/services/estimator.toml"),
        &repo_path("config/services/compensator.toml"),
    );
    session
}

/// [`recorded_session`]'s flight (`dir`'s `flight.mcap`) through the shipped
/// compensator configuration set to `stage = "estimate"` (the estimate stage alone, as
/// before the waveform stage), recorded into `name` in `dir`.
fn estimate_stage_session(dir: &Dir, name: &str) -> PathBuf {
    let flight = dir.path("flight.mcap");
    let shipped = std::fs::read_to_string(repo_path("config/services/compensator.toml")).unwrap();
    let mut table: toml::Table = toml::from_str(&shipped).unwrap();
    table.insert("stage".into(), toml::Value::String("estimate".into()));
    let config = dir.path("compensator-estimate.toml");
    std::fs::write(&config, toml::to_string(&table).unwrap()).unwrap();
    let session = dir.path(name);
    recorded_replay(
        &flight,
        &session,
        "les",
        &repo_path("config/services/estimator.toml"),
        &config,
    );
    session
}

/// `stage_errors.py SESSION --window-s W`: the independent figures.
fn python_errors(session: &Path, window_s: f64) -> Value {
    let out = Command::new("python3")
        .arg(repo_path("tests/python/stage_errors.py"))
        .arg(session)
        .arg("--window-s")
        .arg(window_s.to_string())
        .output()
        .expect("python3 runs; run `pip install -r tests/python/requirements.txt`");
    assert!(
        out.status.success(),
        "stage_errors.py failed ({}): {}\n(run `pip install -r tests/python/requirements.txt`)",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

const STAGES: [&str; 4] = [
    "uncompensated_rms_g",
    "main_removed_rms_g",
    "vibration_removed_rms_g",
    "reduction",
];

/// Every figure of `ours` against `reference`: counts exactly, the RMS figures and
/// the reductions to 1e-9 relative (the estimate stage's column too, where the
/// waveform stage ran). Returns the largest relative difference.
fn assert_agree(ours: &Value, reference: &Value) -> f64 {
    for key in [
        "window_samples",
        "samples",
        "windows",
        "compensated_windows",
        "blocks",
        "main_only_blocks",
        "waveform_blocks",
        "fallback_blocks",
        "estimate_only_blocks",
        "estimate_stage",
        "k1_v_per_g",
    ] {
        assert_eq!(ours[key], reference[key], "{key}: {ours}\n{reference}");
    }
    let two_stages = !ours["estimate_stage"].is_null();
    let mut worst = 0.0f64;
    let rows = |v: &Value| {
        let mut r = vec![v["all_units"].clone()];
        r.extend(v["units"].as_array().unwrap().iter().cloned());
        r
    };
    for (a, b) in rows(ours).iter().zip(rows(reference).iter()) {
        assert_eq!(a["unit"], b["unit"]);
        assert_eq!(a.get("estimate_stage_rms_g").is_some(), two_stages, "{a}");
        for s in STAGES
            .into_iter()
            .chain(two_stages.then_some("estimate_stage_rms_g"))
        {
            let (x, y) = (a[s].as_f64().unwrap(), b[s].as_f64().unwrap());
            let rel = (x - y).abs() / y.abs();
            assert!(
                rel <= 1e-9,
                "{s}: {x} against Python's {y} ({rel:e} relative)"
            );
            worst = worst.max(rel);
        }
    }
    worst
}

/// An acceleration as the table prints it (`11.1409 mg`), in g.
fn printed_g(number: &str, unit: &str) -> f64 {
    let x: f64 = number.parse().unwrap();
    x * match unit {
        "g" => 1.0,
        "mg" => 1e-3,
        "ug" => 1e-6,
        other => panic!("unit {other:?}"),
    }
}

/// The text of `log errors` prints the JSON's figures: the counts exactly, each RMS
/// to its four printed decimals, each reduction to its one; where the waveform stage
/// ran, the blocks per stage and the estimate stage's column and windows.
fn assert_text_shows(text: &str, errors: &Value) {
    let n = |k: &str| errors[k].as_u64().unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let est = &errors["estimate_stage"];
    if !est.is_null() {
        return assert_two_stage_text_shows(&lines, errors);
    }
    assert_eq!(lines.len(), 8, "{text}");
    assert!(
        lines[0].contains(&format!(": {} samples with a reading", n("samples")))
            && lines[0].ends_with(&format!(
                "; {} windows of {} samples",
                n("windows"),
                n("window_samples")
            )),
        "{text}"
    );
    assert!(
        lines[2].contains(&format!(
            "mean over {} s windows ({} of {} windows compensated with a vibration estimate; {} blocks compensated for the main error only",
            errors["window_s"].as_f64().unwrap(),
            n("compensated_windows"),
            n("windows"),
            n("main_only_blocks")
        )),
        "{text}"
    );
    let units = errors["units"].as_array().unwrap();
    let expected = units
        .iter()
        .map(|u| (format!("AK{}", u["unit"]), u))
        .chain([("all".to_string(), &errors["all_units"])]);
    for (line, (name, figures)) in lines[4..].iter().zip(expected) {
        let t: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(t.len(), 8, "{line}");
        assert_eq!(t[0], name, "{line}");
        for (k, stage) in STAGES[..3].iter().enumerate() {
            let json = figures[stage].as_f64().unwrap();
            let shown = printed_g(t[1 + 2 * k], t[2 + 2 * k]);
            let half_digit = printed_g("0.00005", t[2 + 2 * k]);
            assert!(
                (shown - json).abs() <= half_digit * (1.0 + 1e-9),
                "{name} {stage}: printed {} {}, JSON {json}",
                t[1 + 2 * k],
                t[2 + 2 * k]
            );
        }
        let shown: f64 = t[7].trim_end_matches('x').parse().unwrap();
        let json = figures["reduction"].as_f64().unwrap();
        assert!(
            (shown - json).abs() <= 0.05 * (1.0 + 1e-9),
            "{line}: {json}"
        );
    }
}

/// [`assert_text_shows`] for a log with waveform-stage blocks: 9 lines, the estimate
/// stage's column before the published output.
fn assert_two_stage_text_shows(lines: &[&str], errors: &Value) {
    let text = lines.join("\n");
    let n = |k: &str| errors[k].as_u64().unwrap();
    let est = &errors["estimate_stage"];
    assert_eq!(lines.len(), 9, "{text}");
    assert!(
        lines[2].ends_with(&format!(
            "; blocks: {} made by the waveform stage, {} by the estimate stage where the samples did not cover them, {} by the estimate stage alone:",
            n("waveform_blocks"),
            n("fallback_blocks"),
            n("estimate_only_blocks")
        )),
        "{text}"
    );
    assert_eq!(
        lines[3],
        format!(
            "  vibration removed (published a4): {} of {} windows compensated ({} blocks main error only); estimate stage (its answer, a3 of waveform blocks): {} of {} windows compensated with a vibration estimate ({} blocks without one)",
            n("compensated_windows"),
            n("windows"),
            n("main_only_blocks"),
            est["compensated_windows"],
            n("windows"),
            est["main_only_blocks"]
        ),
        "{text}"
    );
    let units = errors["units"].as_array().unwrap();
    let expected = units
        .iter()
        .map(|u| (format!("AK{}", u["unit"]), u))
        .chain([("all".to_string(), &errors["all_units"])]);
    let columns = [
        "uncompensated_rms_g",
        "main_removed_rms_g",
        "estimate_stage_rms_g",
        "vibration_removed_rms_g",
    ];
    for (line, (name, figures)) in lines[5..].iter().zip(expected) {
        let t: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(t.len(), 10, "{line}");
        assert_eq!(t[0], name, "{line}");
        for (k, stage) in columns.iter().enumerate() {
            let json = figures[stage].as_f64().unwrap();
            let shown = printed_g(t[1 + 2 * k], t[2 + 2 * k]);
            let half_digit = printed_g("0.00005", t[2 + 2 * k]);
            assert!(
                (shown - json).abs() <= half_digit * (1.0 + 1e-9),
                "{name} {stage}: printed {} {}, JSON {json}",
                t[1 + 2 * k],
                t[2 + 2 * k]
            );
        }
        let shown: f64 = t[9].trim_end_matches('x').parse().unwrap();
        let json = figures["reduction"].as_f64().unwrap();
        assert!(
            (shown - json).abs() <= 0.05 * (1.0 + 1e-9),
            "{line}: {json}"
        );
    }
}

#[test]
fn log_errors_agrees_with_python_and_prints_its_json_figures() {
    let dir = Dir::new("lerr");
    let session = recorded_session(&dir, "6");
    let s = session.to_str().unwrap();
    let mut worst = 0.0f64;
    for window in [None, Some("0.3")] {
        let mut args = vec!["log", "errors", s, "--json"];
        args.extend(window.map(|w| ["--window-s", w]).into_iter().flatten());
        let report = run_json(&args);
        let errors = &report["errors"];
        assert_eq!(report["log"], s);
        let window_s = window.map_or(0.5, |w| w.parse().unwrap());
        assert_eq!(errors["window_s"], window_s);
        assert_eq!(errors["reference_topic"], "/truth");
        // 6 s at 800 Hz; the first windows before the first estimate are main-only.
        assert!(errors["samples"].as_u64().unwrap() >= 4000, "{report}");
        assert!(
            errors["compensated_windows"].as_u64().unwrap() >= 5,
            "{report}"
        );
        worst = worst.max(assert_agree(errors, &python_errors(&session, window_s)));
        assert!(
            errors["all_units"]["reduction"].as_f64().unwrap() > 10.0,
            "{report}"
        );
        // The shipped compensator runs the waveform stage: it made most blocks, and
        // the estimate stage's own answer is in the table beside the published one.
        let n = |k: &str| errors[k].as_u64().unwrap();
        assert!(n("waveform_blocks") >= n("blocks") / 2, "{report}");
        assert_eq!(
            n("waveform_blocks") + n("fallback_blocks") + n("estimate_only_blocks"),
            n("blocks")
        );
        assert_eq!(n("estimate_only_blocks"), 0, "{report}");
        let est = &errors["estimate_stage"];
        assert!(
            est["compensated_windows"].as_u64().unwrap() <= n("compensated_windows")
                && est["compensated_windows"].as_u64().unwrap() >= 5,
            "{report}"
        );

        let mut text_args = vec!["log", "errors", s];
        text_args.extend(window.map(|w| ["--window-s", w]).into_iter().flatten());
        let out = bin().args(&text_args).output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_text_shows(&String::from_utf8(out.stdout).unwrap(), errors);
    }

    // The estimate stage alone: no waveform blocks, the one-stage table, and Python
    // agrees on it too.
    let older = estimate_stage_session(&dir, "estimate-session.mcap");
    let o = older.to_str().unwrap();
    let report = run_json(&["log", "errors", o, "--json"]);
    let errors = &report["errors"];
    assert_eq!(
        (
            &errors["waveform_blocks"],
            &errors["fallback_blocks"],
            &errors["estimate_only_blocks"]
        ),
        (&Value::from(0), &Value::from(0), &errors["blocks"]),
        "{report}"
    );
    assert!(errors.get("estimate_stage").is_none(), "{report}");
    assert!(
        errors["all_units"].get("estimate_stage_rms_g").is_none(),
        "{report}"
    );
    worst = worst.max(assert_agree(errors, &python_errors(&older, 0.5)));
    let out = bin().args(["log", "errors", o]).output().unwrap();
    assert!(out.status.success());
    assert_text_shows(&String::from_utf8(out.stdout).unwrap(), errors);
    eprintln!("log errors against stage_errors.py: largest relative difference {worst:e}");
}

/// Runs `log errors FILE`, expecting exit 1; returns stderr.
fn refused(file: &Path) -> String {
    let out = run_failing(&["log", "errors", file.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    String::from_utf8(out.stderr).unwrap()
}

/// A log written here: 20 accelerometer blocks (800 Hz, 32 samples) and their
/// compensated output, with the truth only if `truth`, and no passports.
fn crafted_log(path: &Path, truth: bool) {
    let mut rec = Recorder::create(path, RecorderOptions::default()).unwrap();
    rec.add_channel("/accel", MessageKind::AccelBlock).unwrap();
    rec.add_channel("/compensated", MessageKind::CompensatedBlock)
        .unwrap();
    if truth {
        rec.add_channel("/truth", MessageKind::TruthBlock).unwrap();
    }
    let period_ns = 1_250_000;
    for seq in 0..20u64 {
        let mut a = AccelBlock::ZEROED;
        let mut c = CompensatedBlock::ZEROED;
        let mut t = TruthBlock::ZEROED;
        (a.seq, c.seq, c.input_seq, t.seq) = (seq, seq, seq, seq);
        let first = 32 * seq;
        let t0_ns = 1_000_000_000 + first * period_ns;
        (
            a.first_sample_index,
            c.first_sample_index,
            t.first_sample_index,
        ) = (first, first, first);
        (a.t0_ns, c.t0_ns, t.t0_ns) = (t0_ns, t0_ns, t0_ns);
        (a.sample_period_ns, c.sample_period_ns, t.sample_period_ns) =
            (period_ns, period_ns, period_ns);
        (a.count, c.count, t.count) = (32, 32, 32);
        let log_ns = t0_ns + 31 * period_ns;
        rec.write("/accel", log_ns, log_ns, seq as u32, &a).unwrap();
        rec.write("/compensated", log_ns, log_ns, seq as u32, &c)
            .unwrap();
        if truth {
            rec.write("/truth", log_ns, log_ns, seq as u32, &t).unwrap();
        }
    }
    rec.finish().unwrap();
}

#[test]
fn a_log_without_what_the_errors_need_is_refused_by_name() {
    let dir = Dir::new("lerrbad");
    let s = |p: &Path| p.display().to_string();

    // A simulated flight, not yet through the services.
    let flight = flight_log(&dir, "1");
    let e = refused(&flight);
    assert!(
        e.contains(&format!(
            "{}: no compensated output (/compensated, CompensatedBlock): it has none (topics: /accel, /truth, /vib)",
            s(&flight)
        )),
        "{e}"
    );
    assert!(e.contains("`vibrocomp up --record session.mcap`"), "{e}");
    assert!(
        e.contains(&format!("`vibrocomp replay {}`", s(&flight))),
        "{e}"
    );

    let no_truth = dir.path("no-truth.mcap");
    crafted_log(&no_truth, false);
    let e = refused(&no_truth);
    assert!(
        e.contains(&format!(
            "{}: no reference to measure the errors against: they need, per accelerometer sample, the acceleration each unit should read, from /truth (TruthBlock.a_sensed_ia_g); topics: /accel, /compensated",
            s(&no_truth)
        )),
        "{e}"
    );

    let no_passports = dir.path("no-passports.mcap");
    crafted_log(&no_passports, true);
    let e = refused(&no_passports);
    assert!(
        e.contains(&format!(
            "{}: no passport of AK1 (passport-0-*.toml), AK2 (passport-1-*.toml), AK3 (passport-2-*.toml)",
            s(&no_passports)
        )),
        "{e}"
    );

    let text = dir.path("notes.mcap");
    std::fs::write(&text, "time_s,u1_v\n0,1\n").unwrap();
    let e = refused(&text);
    assert!(e.contains(&format!("{}: not an MCAP log", s(&text))), "{e}");

    // The flight log cut in half: no summary, no footer.
    let bytes = std::fs::read(&flight).unwrap();
    let cut = dir.path("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = refused(&cut);
    assert!(
        e.contains(&format!(
            "{} is damaged (`vibrocomp log recover {} OUT.mcap`",
            s(&cut),
            s(&cut)
        )),
        "{e}"
    );

    // With --json, the failure is a JSON error object naming the file too.
    let out = run_failing(&["log", "errors", "--json", &s(&no_truth)]);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let message = v["error"]["message"].as_str().unwrap();
    assert!(
        message.starts_with(&format!("{}: no reference", s(&no_truth))),
        "{v}"
    );
}
