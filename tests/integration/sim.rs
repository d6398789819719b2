//! The rig simulator end to end: each effect switched on alone moves the simulated
//! mean by its documented formula; `vibrocomp sim` logs are bit-identical for a seed
//! and pass the independent Python MCAP reader; campaigns reproduce the paper's
//! compensation experiment.

use crate::common::{bin, num, repo_path, run_failing, run_json, TempDir};
use std::path::PathBuf;
use std::process::Command;
use vibro_effects::{build_for_rig, EffectSpec, Rig};
use vibro_sim::{parse_scenario, Scenario, Simulator};

/// A steady flight for the effect tests: flight acceleration on every body axis (so
/// every unit has cross-axis terms), three tones with phases on every axis, and
/// band-shaped random vibration with cross-axis coherence. 6 s at 25.6 kHz.
const EFFECT_FLIGHT: &str = r#"
name = "effect-check"
seed = 11
[rates]
sensor_hz = 25600
internal_hz = 25600
output_hz = 800
[sensor]
sensitivity_v_per_g = 0.1
ac_corner_hz = 0.5
noise_g_rms = 1e-3
adc_bits = 24
full_scale_v = 10.0
[flight]
duration_s = 6.0
triad = "default"
[[flight.profile]]
t_s = 0.0
accel_body_g = [3.0, 0.8, -0.6]
[[flight.tone]]
freq_hz = 44.0
amplitude_g = [2.0, 1.5, 1.2]
phase_deg = [0.0, 40.0, -70.0]
[[flight.tone]]
freq_hz = 211.0
amplitude_g = [1.0, 1.4, 0.8]
phase_deg = [10.0, -20.0, 90.0]
[flight.random]
psd_table = "p1-table3"
band_gain = [1.6, 1.8, 0.4, 0.1, 0.05]
rms_g = [2.0, 1.8, 1.6]
coherence = [[1.0, 0.5, 0.3], [0.5, 1.0, 0.4], [0.3, 0.4, 1.0]]
# Short mixture segments (the non-Gaussian effect): 120 bursts in 6 s instead of 24.
kurtosis_segment_s = 0.05
"#;

fn flight(duration_s: f64) -> Scenario {
    let mut s = parse_scenario(
        EFFECT_FLIGHT,
        "effect-check.toml",
        Some(&repo_path("config/scenarios")),
    )
    .expect("the test flight is valid");
    if let vibro_sim::ScenarioKind::Flight(f) = &mut s.kind {
        f.duration_s = duration_s;
    }
    s
}

/// Per unit and output sample, the error `U/K1 - a_mean` against the acceleration the
/// unit sensed (so the vibration's own zero-mean motion is not noise in the
/// comparison), and the sensor mean square along IA, V^2.
struct Run {
    error_g: Vec<[f64; 3]>,
    sensor_ms_v2: [f64; 3],
}

fn run(scenario: &Scenario, effect: Option<&EffectSpec>) -> Run {
    let flight = scenario.flight().expect("a flight");
    let rig = Rig {
        triad: flight.triad.axes,
        passports: Some(flight.triad.passports),
    };
    let effects = match effect {
        Some(spec) => vec![build_for_rig(spec, &rig).expect("the effect builds")],
        None => Vec::new(),
    };
    let k1 = flight.triad.passports.map(|p| p.k1_v_per_g);
    let mut sim = Simulator::new(scenario, effects).expect("simulator");
    let mut out = Run {
        error_g: Vec::new(),
        sensor_ms_v2: [0.0; 3],
    };
    let mut n_sensor = 0usize;
    while let Some(chunk) = sim.next_chunk().expect("chunk") {
        for (row, truth) in chunk.accel_v().iter().zip(chunk.truth()) {
            out.error_g
                .push([0, 1, 2].map(|u| row[u] / k1[u] - truth.a_mean_unit_g[u][2]));
        }
        for row in chunk.sensor_v() {
            for (ms, x) in out.sensor_ms_v2.iter_mut().zip(row) {
                *ms += x * x;
            }
            n_sensor += 1;
        }
    }
    for u in 0..3 {
        out.sensor_ms_v2[u] /= n_sensor as f64;
    }
    out
}

/// Mean of `on - off` per unit and its standard error from 20 batch means.
fn paired_shift(on: &Run, off: &Run, unit: usize) -> (f64, f64) {
    let d: Vec<f64> = on
        .error_g
        .iter()
        .zip(&off.error_g)
        .map(|(a, b)| a[unit] - b[unit])
        .collect();
    let batches = 20;
    let len = d.len() / batches;
    let means: Vec<f64> = (0..batches)
        .map(|b| d[b * len..(b + 1) * len].iter().sum::<f64>() / len as f64)
        .collect();
    let mean = means.iter().sum::<f64>() / batches as f64;
    let var = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (batches - 1) as f64;
    (mean, (var / batches as f64).sqrt())
}

fn spec(text: &str) -> EffectSpec {
    let mut table: toml::Table = toml::from_str(text).expect("effect TOML");
    let effect = table.remove("effect").expect("[[effect]]");
    let first = effect
        .as_array()
        .and_then(|a| a.first())
        .cloned()
        .expect("one table");
    first.try_into().expect("an effect spec")
}

/// Every effect of the library, switched on alone in the simulator (common random
/// numbers: the same draws with and without it), changes each unit's mean output by
/// what its `mean_shift_g` formula says, within the run's statistical error; the
/// sensor-only effect leaves the accelerometers alone and scales the sensor RMS by its
/// documented factor. Parameters are chosen so that each shift is at least 5 standard
/// errors of the 6 s run.
#[test]
fn every_effect_moves_the_simulated_mean_by_its_formula() {
    let scenario = flight(6.0);
    let off = run(&scenario, None);
    // The non-Gaussian effect's shift rides on the number of high-variance bursts
    // drawn, so it gets a 60 s flight (1200 bursts) of its own.
    let long = flight(60.0);
    let long_off = run(&long, None);
    // The frequency-dependent scale factor acts through the asymmetry d1A (15 ppm for
    // AL-15, a micro-g effect): its check exaggerates d1A to 10 % (the validation limit).
    let mut asymmetric = flight(6.0);
    if let vibro_sim::ScenarioKind::Flight(f) = &mut asymmetric.kind {
        for p in &mut f.triad.passports {
            p.d1a = 0.1;
        }
    }
    let asymmetric_off = run(&asymmetric, None);
    let cases = [
        "kind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 4.0",
        "kind = \"unit_response\"\nnatural_freq_hz = 150.0\ndamping_ratio = 0.3",
        "kind = \"axis_phase\"\nphase_x_deg = 0.0\nphase_y_deg = 180.0\nphase_z_deg = 180.0",
        "kind = \"vibropendulous\"\nc_rad_per_g = 5.0e-3\ntau_s = 0.002",
        "kind = \"anisoelastic\"\nk_ae_per_g = 2.0e-4",
        "kind = \"non_gaussian\"\nkurtosis = 9.0",
        "kind = \"saturation\"\nrange_g = 6.0",
        "kind = \"high_order_nonlinearity\"\nk6_ppm_per_g5 = 5.0\nk7_ppm_per_g6 = 1.0",
        "kind = \"heating\"\nc_g_per_g2 = 2.0e-5\ntau_s = 2.0",
        "kind = \"scale_factor_frequency\"\ncorner_hz = 100.0\nlambda_hf = 1.5",
    ];
    let flight_def = scenario.flight().expect("a flight");
    let mut report = Vec::new();
    for case in cases {
        let spec = spec(&format!("[[effect]]\n{case}\n"));
        let (scenario, off) = match spec.kind.as_str() {
            "non_gaussian" => (&long, &long_off),
            "scale_factor_frequency" => (&asymmetric, &asymmetric_off),
            _ => (&scenario, &off),
        };
        let on = run(scenario, Some(&spec));
        let this = scenario.flight().expect("a flight");
        let rig = Rig {
            triad: this.triad.axes,
            passports: Some(this.triad.passports),
        };
        let effect = build_for_rig(&spec, &rig).expect("builds");
        let sim = Simulator::new(scenario, Vec::new()).expect("simulator");
        for unit in 0..3 {
            let a_l = flight_def.triad.axes.units[unit].to_unit(&[3.0, 0.8, -0.6]);
            let ctx = sim.mean_context(unit, a_l).expect("a unit");
            let formula = effect.mean_shift_g(&ctx).expect("a formula");
            let (shift, sigma) = paired_shift(&on, off, unit);
            let z = (shift - formula) / sigma.max(1e-12);
            report.push(format!(
                "{:<24} unit {unit}: sim {shift:+.4e} +- {sigma:.1e} g, formula {formula:+.4e} g, z {z:+.2}",
                spec.kind
            ));
            assert!(z.abs() < 4.0, "{}", report.join("\n"));
        }
        // Not a vacuous comparison: the effect stands out of the statistical error.
        let largest = (0..3)
            .map(|u| {
                let (s, e) = paired_shift(&on, off, u);
                s.abs() / e.max(1e-15)
            })
            .fold(0.0, f64::max);
        assert!(
            largest > 5.0,
            "{}: shift only {largest:.1} standard errors\n{}",
            spec.kind,
            report.join("\n")
        );
    }
    // The sensor-only effect.
    let spec = spec("[[effect]]\nkind = \"sensor_error\"\ngain_error = 0.05\nmisalignment_oa_rad = 0.05\nmisalignment_pa_rad = -0.03\n");
    let on = run(&scenario, Some(&spec));
    let rig = Rig {
        triad: flight_def.triad.axes,
        passports: Some(flight_def.triad.passports),
    };
    let effect = build_for_rig(&spec, &rig).expect("builds");
    let sim = Simulator::new(&scenario, Vec::new()).expect("simulator");
    for unit in 0..3 {
        let (shift, _) = paired_shift(&on, &off, unit);
        assert_eq!(
            shift, 0.0,
            "the sensor error must not touch accelerometer {unit}"
        );
        let a_l = flight_def.triad.axes.units[unit].to_unit(&[3.0, 0.8, -0.6]);
        let factor = effect
            .sensor_rms_factor(&sim.mean_context(unit, a_l).expect("a unit"))
            .expect("a sensor effect has a factor");
        let measured = (on.sensor_ms_v2[unit] / off.sensor_ms_v2[unit]).sqrt();
        report.push(format!(
            "sensor_error unit {unit}: RMS ratio {measured:.5}, formula {factor:.5}"
        ));
        // The sensor's own noise (1 mg) and the AC coupling barely move the ratio.
        assert!((measured - factor).abs() < 2e-3, "{}", report.join("\n"));
    }
    println!("{}", report.join("\n"));
}

/// A flight log: counts as the simulator says, bit-identical for the same seed,
/// different for another, and every message of every channel decoded by the Python
/// `mcap` reader with its protobuf decoder, chunk CRCs checked.
#[test]
fn flight_logs_are_reproducible_and_readable_by_python_mcap() {
    let dir = TempDir::new("sim", "flight-logs");
    let a = dir.0.join("a.mcap");
    let b = dir.0.join("b.mcap");
    let c = dir.0.join("c.mcap");
    let args = |out: &PathBuf, seed: &str| {
        vec![
            "sim".to_string(),
            "cyclone-4-short".into(),
            "--duration-s".into(),
            "1.5".into(),
            "--seed".into(),
            seed.into(),
            "--out".into(),
            out.display().to_string(),
            "--json".into(),
        ]
    };
    let run = |out: &PathBuf, seed: &str| {
        let a: Vec<String> = args(out, seed);
        run_json(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let report = run(&a, "7");
    run(&b, "7");
    run(&c, "8");
    let bytes = |p: &PathBuf| std::fs::read(p).expect("log exists");
    assert_eq!(bytes(&a), bytes(&b), "same seed, same bytes");
    assert_ne!(bytes(&a), bytes(&c), "another seed, other bytes");
    // 1.5 s at 25.6 kHz in blocks of 512; at 800 Hz in blocks of 32.
    assert_eq!(num(&report, "sensor_samples"), 38_400.0);
    assert_eq!(num(&report, "output_samples"), 1_200.0);
    assert_eq!(num(&report, "vib_blocks"), 75.0);
    assert_eq!(num(&report, "accel_blocks"), 38.0);
    let out = Command::new("python3")
        .arg(repo_path("tests/python/mcap_check.py"))
        .arg(&a)
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "the Python reader rejected the log:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let py: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("JSON from mcap_check.py");
    let count = |topic: &str| {
        py["channels"][topic]["count"]
            .as_f64()
            .unwrap_or_else(|| panic!("no count for topic {topic}"))
    };
    assert_eq!(count("/vib"), 75.0);
    assert_eq!(count("/accel"), 38.0);
    assert_eq!(count("/truth"), 38.0);
    // The simulator stamps each block with its data time (docs/logs.md, "Time"): the
    // log time a recording gives it, `vibro_mcap::Message::data_ns`, is the same.
    let mut n = 0;
    for r in vibro_mcap::Reader::open(&a).unwrap() {
        let r = r.unwrap();
        assert_eq!(
            Some(r.log_time_ns),
            r.message.data_ns(),
            "{} {}",
            r.topic,
            n
        );
        n += 1;
    }
    assert_eq!(n, 75 + 38 + 38);
}

/// MODEL.md section 7's experiment, through the command line: gravity along IA, 2 g
/// at 30 Hz: the error before compensation is of order 1e-3 g for AL-1M and 1e-4 g
/// for AKS-05, and the simulated VE agrees with the exact model.
#[test]
fn compensation_experiment_has_the_papers_orders_of_magnitude() {
    for (id, lo, hi) in [
        ("compensation-experiment-al1m", 3e-4, 3e-3),
        ("compensation-experiment-aks05", 3e-5, 3e-4),
    ] {
        let v = run_json(&["sim", id, "--json"]);
        let c = &v["conditions"][0];
        let measured = num(c, "measured_ve_g");
        let exact = num(c, "exact_ve_g");
        assert!((lo..hi).contains(&measured.abs()), "{id}: VE {measured}");
        assert!(num(c, "z_exact").abs() < 4.0, "{id}: {c}");
        assert!(
            (measured - exact).abs() < 0.05 * exact.abs(),
            "{id}: {measured} vs {exact}"
        );
    }
}

#[test]
fn effects_are_listed_and_bad_parameters_are_named() {
    let v = run_json(&["sim", "--list-effects", "--json"]);
    let kinds: Vec<&str> = v
        .as_array()
        .expect("a list")
        .iter()
        .filter_map(|e| e["kind"].as_str())
        .collect();
    assert_eq!(kinds.len(), 11, "{kinds:?}");
    for k in [
        "mount_resonance",
        "vibropendulous",
        "heating",
        "sensor_error",
    ] {
        assert!(kinds.contains(&k), "{k}");
    }
    let out = run_failing(&[
        "sim",
        "cyclone-4-short",
        "--effect",
        "mount_resonance:freq_hz=-5,q=2",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("mount_resonance") && err.contains("freq_hz") && err.contains("-5"),
        "{err}"
    );
    let out = run_failing(&["sim", "cyclone-4-short", "--effect", "warp_drive"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("warp_drive") && err.contains("mount_resonance"),
        "{err}"
    );
    let _ = bin();
}

/// `sim --live` publishes the rig streams over iceoryx2: a subscriber attached before
/// the start receives every block, in order, with continuous sequence numbers, and the
/// same samples as the log of the same scenario and seed.
#[test]
fn live_publishing_delivers_every_block_in_order() {
    use vibro_msgs::{AccelBlock, ServiceNames, Stream, TruthBlock, VibBlock};
    let prefix = format!("vct-simlive-{}/", std::process::id());
    let names = ServiceNames::new(&prefix).expect("prefix");
    let node = vibro_ipc::create_node("it-sim-live").expect("node");
    let config = vibro_ipc::StreamConfig {
        subscriber_buffer: 1024,
        ..vibro_ipc::StreamConfig::default()
    };
    let vib = vibro_ipc::StreamSubscriber::<VibBlock>::create(
        &node,
        &names.stream(Stream::Vib),
        &names.event(Stream::Vib),
        &config,
    )
    .expect("vib subscriber");
    let accel = vibro_ipc::StreamSubscriber::<AccelBlock>::create(
        &node,
        &names.stream(Stream::Accel),
        &names.event(Stream::Accel),
        &config,
    )
    .expect("accel subscriber");
    let truth = vibro_ipc::StreamSubscriber::<TruthBlock>::create(
        &node,
        &names.stream(Stream::Truth),
        &names.event(Stream::Truth),
        &config,
    )
    .expect("truth subscriber");
    let dir = TempDir::new("sim", "live");
    let log = dir.0.join("live.mcap");
    let log_arg = log.display().to_string();
    let mut child = bin()
        .args([
            "sim",
            "cyclone-4-short",
            "--duration-s",
            "0.5",
            "--seed",
            "3",
            "--live",
            "--rate",
            "5",
            "--prefix",
            &prefix,
            "--out",
            &log_arg,
            "--json",
        ])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("vibrocomp sim starts");
    let (mut vib_seq, mut accel_seq, mut truth_n) = (Vec::new(), Vec::new(), 0);
    let mut first_vib = None;
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    let mut drain = || {
        while let Some(s) = vib.receive().expect("receive") {
            if first_vib.is_none() {
                first_vib = Some(*s);
            }
            vib_seq.push(s.seq);
        }
        while let Some(s) = accel.receive().expect("receive") {
            accel_seq.push(s.seq);
        }
        while truth.receive().expect("receive").is_some() {
            truth_n += 1;
        }
    };
    while child.try_wait().expect("wait").is_none() && std::time::Instant::now() < deadline {
        drain();
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    drain();
    let out = child.wait_with_output().expect("sim ends");
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(num(&v, "vib_blocks"), 25.0);
    assert_eq!(num(&v, "accel_blocks"), 13.0);
    assert_eq!(vib_seq, (0..25).collect::<Vec<u64>>());
    assert_eq!(accel_seq, (0..13).collect::<Vec<u64>>());
    assert_eq!(truth_n, 13);
    // The live samples are the logged ones (the publish stamps differ: live uses the
    // monotonic clock, the log the simulated time).
    let logged = vibro_mcap::Reader::open(&log)
        .expect("log")
        .filter_map(Result::ok)
        .find_map(|r| match r.message {
            vibro_mcap::Message::VibBlock(b) if b.seq == 0 => Some(b),
            _ => None,
        })
        .expect("vib block 0 in the log");
    let live = first_vib.expect("a live vib block");
    assert_eq!(live.sample_v, logged.sample_v);
    assert!(
        live.publish_ns > 1_000_000_000,
        "monotonic stamp: {}",
        live.publish_ns
    );
}

/// `vibrocomp sim` on the 20 s Cyclone-4 flight: with no effect the simulated mean
/// error of every unit is the exact model's within the run's statistical error; with a
/// mount resonance switched on, what the model does not explain stands out.
#[test]
fn flight_report_shows_what_the_model_does_not_explain() {
    let z = |v: &serde_json::Value| -> Vec<f64> {
        v["units"]
            .as_array()
            .expect("units")
            .iter()
            .map(|u| num(u, "unexplained_g") / num(u, "unexplained_sigma_g"))
            .collect()
    };
    let plain = run_json(&["sim", "cyclone-4-short", "--json"]);
    for (u, z) in z(&plain).iter().enumerate() {
        assert!(z.abs() < 4.0, "unit {u}: z = {z} without effects: {plain}");
    }
    for u in plain["units"].as_array().expect("units") {
        // The VE is a real part of the error the model explains.
        assert!(num(u, "exact_ve_g") > 4e-4, "{u}");
    }
    let resonant = run_json(&[
        "sim",
        "cyclone-4-short",
        "--effect",
        "mount_resonance:freq_hz=48,q=1.56",
        "--json",
    ]);
    let largest = z(&resonant).into_iter().fold(0.0, f64::max);
    assert!(largest > 4.0, "the resonance should stand out: {resonant}");
}
