//! The lab on the waveform (issue 44): `lab diagnose` and `lab add` on logs with
//! vibration samples predict every reading from the samples through the model and fit
//! the effects to the readings. On rigs we did not make: the independent generator
//! (`tests/python/rig_generator.py`, numpy, from MODEL.md) writes shaker runs (still,
//! vibrating, still) with AC-coupled sensors at 6.4 kHz (0.1 V/g, 2 Hz corner, 1 mg
//! noise), 800 Hz readings with 2 ug noise, every tone at 150 Hz (the design whose
//! window means see only `|T(150 Hz)|`) and random vibration 20..640 Hz, behind a
//! hidden 150 Hz, Q 2.5 mount or none; `log import --rig` makes the logs.
//!
//! Checked: the mount alone is named, its `f0` within 0.3 Hz and `Q` within 0.03 of
//! the truth and each within 3 standard uncertainties; the window residual within 2x
//! the quiet windows' (the rig's own noise through the prediction); the same seeds
//! without the mount give "noise"; an unstated DAQ delay is found within 20 us; and
//! the model `lab add --diagnosed` writes takes the compensator to at most 2 ug.

use crate::common::{repo_path, run_json, TempDir};
use std::path::{Path, PathBuf};
use std::process::Command;
use vibro_compensator::{Config, InProcess, Stage};
use vibro_mcap::{Message, Reader};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{CompensatedBlock, VibEstimate};
use vibro_service::ServiceConfig;

/// One generator run into `dir/name` (still 3 s, vibrating 4 s, still 3 s), its rig
/// file (the shipped triad, 0.1 V/g, 2 Hz AC corner, `delay_s` when `stated_delay_s`)
/// and its import into `dir/name.mcap`.
fn rig(
    dir: &Path,
    name: &str,
    seed: u32,
    orientation: &str,
    extra: &[&str],
    stated_delay_s: Option<f64>,
) -> PathBuf {
    let run = dir.join(name);
    let out = Command::new("python3")
        .arg(repo_path("tests/python/rig_generator.py"))
        .args(["run", "--out"])
        .arg(&run)
        .args(["--seed", &seed.to_string()])
        .arg(format!("--orientation={orientation}"))
        .args(["--still-s", "3", "--vib-s", "4", "--sensor-rate-hz", "6400"])
        .args(["--oversample", "4", "--unit-noise-ug", "2"])
        .args(extra)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "rig generator: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("truth.json")).unwrap()).unwrap();
    let up: Vec<f64> = truth["orientation"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let delay = stated_delay_s.map_or(String::new(), |d| format!("delay_s = {d:?}\n"));
    let rig = run.join("rig.toml");
    std::fs::write(
        &rig,
        format!(
            "format = \"vibrocomp-rig/1\"\ntriad = \"default\"\n[sensors]\n\
             sensitivity_v_per_g = 0.1\nac_corner_hz = 2.0\n{delay}[reference]\n\
             kind = \"static\"\n[[reference.segment]]\nfrom_s = 0.0\nto_s = 3600.0\n\
             up = [{:?}, {:?}, {:?}]\n",
            up[0], up[1], up[2]
        ),
    )
    .unwrap();
    let log = dir.join(format!("{name}.mcap"));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    run_json(&[
        "log",
        "import",
        "--accel",
        &s(&run.join("accel.csv")),
        "--vib",
        &s(&run.join("vib.csv")),
        "--rig",
        &s(&rig),
        "--out",
        &s(&log),
        "--json",
    ]);
    log
}

const MOUNT: [&str; 4] = ["--resonance-f0-hz", "150", "--resonance-q", "2.5"];
const TONES_150: [&str; 2] = ["--tone-hz", "150"];

fn diagnose(logs: &[PathBuf]) -> serde_json::Value {
    let mut args = vec!["lab".to_string(), "diagnose".to_string()];
    args.extend(logs.iter().map(|p| p.to_str().unwrap().to_string()));
    args.push("--json".into());
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    run_json(&args)
}

/// The fitted parameter `kind.name`: (value, sigma).
fn param(d: &serde_json::Value, kind: &str, name: &str) -> (f64, f64) {
    let p = d["params"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["kind"] == kind && p["name"] == name)
        .unwrap_or_else(|| panic!("{kind}.{name} not in {}", d["params"]));
    (p["value"].as_f64().unwrap(), p["sigma"].as_f64().unwrap())
}

/// Within `tol` of `truth` and within 3 standard uncertainties.
fn assert_found(d: &serde_json::Value, kind: &str, name: &str, truth: f64, tol: f64) {
    let (v, s) = param(d, kind, name);
    println!(
        "FIGURES {kind}.{name} = {v} +- {s:.3e} (truth {truth}, pull {:.2})",
        (v - truth) / s
    );
    assert!(
        (v - truth).abs() <= tol,
        "{kind}.{name} = {v}, truth {truth}"
    );
    assert!(
        (v - truth).abs() <= 3.0 * s,
        "{kind}.{name} = {v} +- {s}, truth {truth}"
    );
}

fn mount_logs(dir: &Path, mount: bool) -> Vec<PathBuf> {
    let extra: Vec<&str> = if mount {
        TONES_150.iter().chain(&MOUNT).copied().collect()
    } else {
        TONES_150.to_vec()
    };
    // Seeds of the pull study (docs/lab.md, "The lab on the waveform"): over 7 seed
    // pairs of this design f0's pulls have RMS 1.5 (one of 7, seeds 501/502, at -3.2)
    // and Q's 1.0.
    [(601, "+x"), (602, "oblique1")]
        .iter()
        .map(|(seed, o)| {
            let name = format!("{}{seed}", if mount { "m" } else { "n" });
            rig(dir, &name, *seed, o, &extra, Some(0.0))
        })
        .collect()
}

/// The hidden mount behind every tone at its resonance: named alone (not "confounded"
/// with a unit response, whose fingerprint is on IA alone), its parameters within the
/// issue's tolerances and 3 sigma, the window residual within 2x the noise; the same
/// seeds without it are "noise".
#[test]
fn a_hidden_mount_is_found_alone_from_every_reading_and_nothing_without_it() {
    let _heavy = crate::common::heavy();
    let dir = TempDir::new("labwv", "mount");
    let logs = mount_logs(&dir.0, true);
    let d = diagnose(&logs);
    println!(
        "FIGURES waveform diagnosis: {} {} in {} s; windows {} vs {} g",
        d["verdict"],
        d["found"],
        d["elapsed_s"],
        d["window_residual_rms_g"],
        d["window_noise_rms_g"]
    );
    assert_eq!(d["path"], "waveform");
    assert_eq!(d["verdict"], "effect", "{}", d["steps"]);
    assert_eq!(d["found"], serde_json::json!(["mount_resonance"]));
    assert_found(&d, "mount_resonance", "freq_hz", 150.0, 0.3);
    assert_found(&d, "mount_resonance", "q", 2.5, 0.03);
    let (w, n) = (
        d["window_residual_rms_g"].as_f64().unwrap(),
        d["window_noise_rms_g"].as_f64().unwrap(),
    );
    assert!(
        w <= 2.0 * n,
        "window residual {w} g against the noise's {n} g"
    );
    let chi2 = d["chi2_per_dof"].as_f64().unwrap();
    assert!((0.9..1.1).contains(&chi2), "{chi2}");

    let plain = diagnose(&mount_logs(&dir.0, false));
    println!(
        "FIGURES waveform diagnosis without the mount: {} z {}",
        plain["verdict"], plain["lack_of_fit"]["z"]
    );
    assert_eq!(plain["verdict"], "noise", "{}", plain["steps"]);
}

/// A DAQ delay the rig file does not state (1.56 ms, a linear-phase anti-alias
/// filter's): fitted within 20 us and 3 sigma, beside the mount.
#[test]
fn an_unstated_delay_is_fitted_beside_the_mount() {
    let _heavy = crate::common::heavy();
    let dir = TempDir::new("labwv", "delay");
    let extra: Vec<&str> = ["--tone-hz", "30,60,120", "--daq-delay-s", "0.00156"]
        .into_iter()
        .chain(MOUNT)
        .collect();
    let logs: Vec<PathBuf> = [(511, "+y"), (512, "oblique2")]
        .iter()
        .map(|(seed, o)| rig(&dir.0, &format!("d{seed}"), *seed, o, &extra, None))
        .collect();
    let d = diagnose(&logs);
    assert_eq!(d["verdict"], "effect", "{}", d["steps"]);
    assert_eq!(d["found"], serde_json::json!(["mount_resonance"]));
    assert_found(&d, "sensor_chain", "delay_s", 1.56e-3, 20e-6);
    assert_found(&d, "mount_resonance", "freq_hz", 150.0, 0.3);
    assert_found(&d, "mount_resonance", "q", 2.5, 0.03);
    for r in d["runs"].as_array().unwrap() {
        assert_eq!(r["delay_stated"], false);
    }
}

/// Per 1600-reading window and unit over the log's readings, the mean of the
/// compensator's output `a4` less what the unit sensed (the generator's
/// `readings_truth.csv`), with `model`: the RMS over windows and units, g.
fn compensated_rms(log: &Path, truth_csv: &Path, model: Option<&Path>) -> f64 {
    let mut raw = vibro_dsp::EstimatorConfigRaw::new(6400.0, [0.1; 3]);
    raw.ac_corner_hz = Some(2.0);
    raw.broadband_band_hz = [20.0, 640.0];
    let mut est =
        vibro_estimator::InProcess::new(&vibro_dsp::EstimatorConfig::try_from(raw).unwrap())
            .unwrap();
    let mut text = Config::shipped_text().replacen("ac_corner_hz = 0.5 ", "ac_corner_hz = 2.0 ", 1);
    if let Some(m) = model {
        text = format!("model = {:?}\n{text}", m.display().to_string());
    }
    let mut config = Config::parse(&text, vibro_service::ConfigSource::Inline).unwrap();
    config.model.waveform.stage = Stage::Waveform;
    let mut comp = InProcess::new(&config).unwrap();
    let mut blocks: Vec<CompensatedBlock> = Vec::new();
    let mut estimates: Vec<VibEstimate> = Vec::new();
    let mut msgs = Vec::new();
    for record in Reader::open(log).unwrap() {
        match record.unwrap().message {
            Message::VibBlock(b) => {
                let end = b.t0_ns + (u64::from(b.count) - 1) * b.sample_period_ns;
                msgs.push((end, 0, Some(b), None));
            }
            Message::AccelBlock(b) => {
                let end = b.t0_ns + (u64::from(b.count) - 1) * b.sample_period_ns;
                msgs.push((end, 1, None, Some(b)));
            }
            _ => {}
        }
    }
    msgs.sort_by_key(|m| (m.0, m.1));
    for (t, _, v, a) in msgs {
        if let Some(b) = v {
            est.on_block(&b, t, &mut estimates).unwrap();
            for e in estimates.drain(..) {
                comp.on_estimate(&e);
            }
            comp.on_vib(&b, t, &mut blocks);
        }
        if let Some(b) = a {
            comp.on_accel(&b, t, &mut blocks);
        }
    }
    comp.finish(&mut blocks);
    let sensed: Vec<[f64; 3]> = std::fs::read_to_string(truth_csv)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.trim().parse().unwrap()).collect();
            [v[1], v[2], v[3]]
        })
        .collect();
    let n = 1600;
    let mut sums = vec![([0.0; 3], 0usize, true); sensed.len() / n];
    for b in &blocks {
        for k in 0..b.count as usize {
            let i = b.first_sample_index as usize + k;
            let Some(w) = sums.get_mut(i / n) else {
                continue;
            };
            for (sum, (a4, s)) in w.0.iter_mut().zip(b.a4_g[k].iter().zip(&sensed[i])) {
                *sum += a4 - s;
            }
            w.1 += 1;
            w.2 &= b.flags & cf::WAVEFORM != 0;
        }
    }
    let errs: Vec<f64> = sums
        .iter()
        .filter(|w| w.1 == n && w.2)
        .flat_map(|w| w.0.map(|x| x / n as f64))
        .collect();
    assert!(!errs.is_empty(), "no window made by the waveform stage");
    (errs.iter().map(|x| x * x).sum::<f64>() / errs.len() as f64).sqrt()
}

/// The model `lab add --diagnosed` writes from the mount rig's logs takes the
/// compensator's waveform stage to at most 2 ug per 2 s window on them; without the
/// mount in the model it leaves far more (the test can fail).
#[test]
fn the_diagnosed_model_takes_the_compensator_to_the_rigs_noise() {
    let _heavy = crate::common::heavy();
    let dir = TempDir::new("labwv", "add");
    let logs = mount_logs(&dir.0, true);
    let model = dir.0.join("model.toml");
    let mut args = vec!["lab", "add", "--diagnosed", "--from"];
    args.extend(logs.iter().map(|p| p.to_str().unwrap()));
    args.extend(["--out", model.to_str().unwrap(), "--json"]);
    let a = run_json(&args);
    assert_eq!(a["effects"], serde_json::json!(["mount_resonance"]), "{a}");
    let text = std::fs::read_to_string(&model).unwrap();
    assert!(text.contains("waveform: "), "{text}");
    for (log, name) in logs.iter().zip(["m601", "m602"]) {
        let truth = dir.0.join(name).join("readings_truth.csv");
        let with = compensated_rms(log, &truth, Some(&model));
        let without = compensated_rms(log, &truth, None);
        println!(
            "FIGURES compensator on {name}: {:.3} ug with the lab's mount, {:.1} ug without",
            with * 1e6,
            without * 1e6
        );
        assert!(with <= 2e-6, "{name}: {with} g");
        assert!(without > 5.0 * with, "{name}: {without} g against {with} g");
    }
}
