//! One evaluation everywhere (issue 43, item 5): `lab compare` of a log with vibration
//! samples predicts each window's VE with the compensator's waveform stage
//! (`vibro_lab::waveform`), on rigs we did not make: the independent generator
//! (`tests/python/rig_generator.py`, numpy, from MODEL.md) writes a shaker's AC-coupled
//! sensors at 6.4 kHz (0.1 V/g, 2 Hz corner), 800 Hz readings with 2 ug noise, tones at
//! 30, 60 and 120 Hz with random vibration 20..640 Hz, optionally behind a hidden
//! 150 Hz, Q 2.5 mount; `log import --rig` makes the log.
//!
//! Checked: every window takes the waveform path; on the mount rig with the mount in
//! the model, the waveform path's residual RMS is far below the statistics path's (the
//! same windows, `lab compare --path statistics`); and the stage's part of each window's
//! prediction (`window.stage_ve_g`) agrees, over the same readings and weights, within
//! 1 % with what the compensator leaves in each reading at its own solution (`R -
//! FP(a4)` of its WAVEFORM blocks) and within 3 % with its correction beyond the main
//! error (`a2_g - a4_g`; `a2` is the paper's first-order inverse, 1.2 % measured), the
//! compensator's and the estimator's cores run in-process over the log's blocks.

use crate::common::{run_json, TempDir};
use std::path::{Path, PathBuf};
use vibro_compensator::{Config, InProcess, Stage};
use vibro_mcap::{Message, Reader};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{AccelBlock, CompensatedBlock, VibBlock, VibEstimate};
use vibro_service::ServiceConfig;

const MOUNT_MODEL: &str = "format = \"vibrocomp-model/1\"\nmode = \"exact\"\n\
                           [[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 150.0\nq = 2.5\n";

/// One generator run (`--vibrate-throughout`, 8 s, tones 30/60/120 Hz, 6.4 kHz sensors)
/// into `dir/name`, its rig file (the shipped triad, 0.1 V/g, 2 Hz AC corner, the run's
/// orientation as the static reference) and its import into `dir/name.mcap`.
fn rig_log(dir: &Path, name: &str, seed: u32, mount: bool) -> PathBuf {
    let extra = ["--oversample", "8", "--unit-noise-ug", "2"];
    crate::rig_log::rig_log_with(dir, name, seed, "+z", "30,60,120", mount, &extra)
}

/// `lab COMMAND LOG [--model MODEL] --path statistics|windows --json`.
fn lab(command: &str, log: &Path, model: Option<&Path>, statistics: bool) -> serde_json::Value {
    let mut args = vec![
        "lab".to_string(),
        command.to_string(),
        log.to_str().unwrap().to_string(),
    ];
    if let Some(m) = model {
        args.extend(["--model".to_string(), m.to_str().unwrap().to_string()]);
    }
    // `windows`: the windows by the compensator's stage (issue 43); the waveform path
    // (every reading, issue 44) is tests/integration/lab_wave.rs's.
    let path = if statistics { "statistics" } else { "windows" };
    args.extend(["--path".to_string(), path.to_string()]);
    args.push("--json".into());
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    run_json(&args)
}

fn rms_residual(c: &serde_json::Value) -> f64 {
    c["summary"]["rms_residual_g"].as_f64().unwrap()
}

/// Every row of a comparison on the waveform path.
fn assert_waveform(c: &serde_json::Value, what: &str) {
    let rows = c["rows"].as_array().unwrap();
    assert!(rows.len() >= 9, "{what}: {} rows", rows.len());
    for r in rows {
        assert_eq!(r["path"], "waveform", "{what}: {r}");
        assert!(
            r["window"]["readings"].as_u64().unwrap() >= 400,
            "{what}: {r}"
        );
    }
    assert_eq!(c["paths"]["waveform"].as_u64().unwrap(), rows.len() as u64);
    assert_eq!(c["paths"]["statistics"], 0, "{what}");
}

/// A sensor block or an accelerometer block of a log.
enum Block {
    Vib(Box<VibBlock>),
    Accel(Box<AccelBlock>),
}

/// Per reading: the compensator's `a2 - a4` and `R - FP(a4)`, per unit, g.
type Corrections = ([f64; 3], [f64; 3]);

/// The log's sensor and accelerometer blocks, each at its last sample's time (a sensor
/// block first on a tie), as they arrive live.
fn log_blocks(log: &Path) -> Vec<(u64, Block)> {
    let mut out = Vec::new();
    for record in Reader::open(log).unwrap() {
        let record = record.unwrap();
        match record.message {
            Message::VibBlock(b) => {
                let end = b.t0_ns + (u64::from(b.count) - 1) * b.sample_period_ns;
                out.push((end, 0, Block::Vib(Box::new(b))));
            }
            Message::AccelBlock(b) => {
                let end = b.t0_ns + (u64::from(b.count) - 1) * b.sample_period_ns;
                out.push((end, 1, Block::Accel(Box::new(b))));
            }
            _ => {}
        }
    }
    out.sort_by_key(|(t, kind, _)| (*t, *kind));
    out.into_iter().map(|(t, _, m)| (t, m)).collect()
}

/// Per reading of the compensator's WAVEFORM blocks (by latch time): its correction
/// beyond the main error, `a2_g - a4_g`, and the error its solution leaves in the
/// reading, `R - FP(a4)` (the lab's `ve_g` at the compensator's `m = a4`, the triad's
/// passports flat as the lab's). Its and the estimator's cores run in-process over the
/// log's blocks, with the rig's chain (`[sensors] ac_corner_hz = 2.0`) and `model`.
fn compensator_corrections(
    log: &Path,
    model: &Path,
) -> std::collections::BTreeMap<u64, Corrections> {
    let triad = vibro_config::resolve_triad("default").unwrap();
    let passports = triad
        .passports
        .map(|p| vibro_effects::predict::flat_passport(&p).unwrap());
    let mut raw = vibro_dsp::EstimatorConfigRaw::new(6400.0, [0.1; 3]);
    raw.ac_corner_hz = Some(2.0);
    raw.broadband_band_hz = [20.0, 640.0];
    let mut est =
        vibro_estimator::InProcess::new(&vibro_dsp::EstimatorConfig::try_from(raw).unwrap())
            .unwrap();
    let text = Config::shipped_text().replacen("ac_corner_hz = 0.5 ", "ac_corner_hz = 2.0 ", 1);
    let text = format!("model = {:?}\n{text}", model.display().to_string());
    let mut config = Config::parse(&text, vibro_service::ConfigSource::Inline).unwrap();
    config.model.waveform.stage = Stage::Waveform;
    let mut comp = InProcess::new(&config).unwrap();
    let mut blocks: Vec<CompensatedBlock> = Vec::new();
    let mut estimates: Vec<VibEstimate> = Vec::new();
    let mut readings_g = std::collections::BTreeMap::new();
    for (t_ns, m) in log_blocks(log) {
        match m {
            Block::Vib(b) => {
                est.on_block(&b, t_ns, &mut estimates).unwrap();
                for e in estimates.drain(..) {
                    comp.on_estimate(&e);
                }
                comp.on_vib(&b, t_ns, &mut blocks);
            }
            Block::Accel(b) => {
                for (k, u) in b.samples_v().iter().enumerate() {
                    let r = [0, 1, 2].map(|i| u[i] / passports[i].k1_v_per_g);
                    readings_g.insert(b.t0_ns + k as u64 * b.sample_period_ns, r);
                }
                comp.on_accel(&b, t_ns, &mut blocks)
            }
        }
    }
    comp.finish(&mut blocks);
    let axes = &triad.axes;
    let mut out = std::collections::BTreeMap::new();
    for b in blocks.iter().filter(|b| b.flags & cf::WAVEFORM != 0) {
        for k in 0..b.count as usize {
            let latch = b.t0_ns + k as u64 * b.sample_period_ns;
            let (a2, a4, r) = (b.a2_g[k], b.a4_g[k], readings_g[&latch]);
            let body = axes.body_from_ia(&a4);
            let left = [0, 1, 2].map(|u| {
                let a = axes.units[u].to_unit(&body);
                r[u] - vibro_physics::fp::output_g(&passports[u], a[0], a[1], a[2])
            });
            out.insert(latch, ([0, 1, 2].map(|u| a2[u] - a4[u]), left));
        }
    }
    out
}

#[test]
fn lab_compare_evaluates_a_logs_windows_as_the_compensator_does() {
    let dir = TempDir::new("labwave", "compare");
    let model = dir.0.join("mount.toml");
    std::fs::write(&model, MOUNT_MODEL).unwrap();

    // Nothing hidden, the base model.
    let base = rig_log(&dir.0, "base", 4301, false);
    let wave = lab("compare", &base, None, false);
    assert_waveform(&wave, "base rig, base model");
    let stat = &lab("compare", &base, None, true);
    for r in stat["rows"].as_array().unwrap() {
        assert_eq!(r["path"], "statistics", "{r}");
    }
    println!(
        "FIGURES base rig, base model: residual RMS waveform {:.2} ug, statistics {:.2} ug",
        rms_residual(&wave) * 1e6,
        rms_residual(stat) * 1e6
    );
    assert!(rms_residual(&wave) < rms_residual(stat), "{wave}");

    // The hidden mount: the base model misses it on both paths; with the mount in the
    // model the waveform path's residual is far below the statistics path's.
    let mount = rig_log(&dir.0, "mount", 4302, true);
    let wave_base = lab("compare", &mount, None, false);
    assert_waveform(&wave_base, "mount rig, base model");
    let wave = lab("compare", &mount, Some(&model), false);
    assert_waveform(&wave, "mount rig, mount model");
    let stat = &lab("compare", &mount, Some(&model), true);
    let stat_base = &lab("compare", &mount, None, true);
    let (w, s) = (rms_residual(&wave), rms_residual(stat));
    println!(
        "FIGURES mount rig, mount model: residual RMS waveform {:.2} ug, statistics {:.2} ug; \
         base model: waveform {:.1} ug, statistics {:.1} ug",
        w * 1e6,
        s * 1e6,
        rms_residual(&wave_base) * 1e6,
        rms_residual(stat_base) * 1e6
    );
    assert!(w < s / 3.0, "waveform {w} g against statistics {s} g");
    assert!(rms_residual(&wave_base) > 5.0 * w, "{wave_base}");

    // The stage's part of the lab's prediction against the compensator's corrections.
    let det = compensator_corrections(&mount, &model);
    let (mut worst, mut worst_a2): (f64, f64) = (0.0, 0.0);
    for r in wave["rows"].as_array().unwrap() {
        let w = &r["window"];
        let (first, last) = (
            w["first_latch_ns"].as_u64().unwrap(),
            w["last_latch_ns"].as_u64().unwrap(),
        );
        let n = w["readings"].as_u64().unwrap() as usize;
        let unit = r["run_id"].as_str().unwrap();
        let u = ["AK1", "AK2", "AK3"]
            .iter()
            .position(|name| unit.contains(name))
            .unwrap_or_else(|| panic!("{unit}"));
        let readings: Vec<_> = det.range(first..=last).map(|(_, d)| *d).collect();
        assert_eq!(
            readings.len(),
            n,
            "{r}: the compensator's WAVEFORM readings"
        );
        let weights =
            vibro_ident::measure::taper_weights(n, w["taper_readings"].as_u64().unwrap() as usize);
        let mean = |f: &dyn Fn(&Corrections) -> f64| {
            readings
                .iter()
                .zip(&weights)
                .map(|(d, w)| f(d) * w)
                .sum::<f64>()
                / weights.iter().sum::<f64>()
        };
        let (comp_a2, comp) = (mean(&|d| d.0[u]), mean(&|d| d.1[u]));
        let lab = w["stage_ve_g"].as_f64().unwrap();
        let rel = (lab - comp).abs() / comp.abs();
        let rel_a2 = (lab - comp_a2).abs() / comp_a2.abs();
        worst = worst.max(rel);
        worst_a2 = worst_a2.max(rel_a2);
        assert!(
            rel < 0.01,
            "{r}: compensator R - FP(a4) {comp:e} g, lab {lab:e} g"
        );
        // `a2` is the paper's first-order inverse of the main error [P2 (18)], evaluated
        // per reading at `a(1)`, the vibration's interval mean included: its
        // second-order error (k2^2 a^3, about 0.1 ug) is 1 % of a 30 ug window.
        assert!(
            rel_a2 < 0.03,
            "{r}: compensator a2 - a4 {comp_a2:e} g, lab {lab:e} g"
        );
    }
    println!(
        "FIGURES lab's stage VE against the compensator over the same readings, worst window: \
         R - FP(a4) {:.1e} %, a2 - a4 {:.2} %",
        worst * 100.0,
        worst_a2 * 100.0
    );
}
