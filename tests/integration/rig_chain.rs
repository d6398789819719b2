//! A rig's vibration-sensor chain from its rig file: `[sensors] delay_s` (and the
//! optional `rate_hz`) imported into a log's `rig` metadata, bad values refused with
//! file, key, value and rule and nothing written; and `vibrocomp up --rig RIG.toml
//! --model MODEL.toml`, which gives both services the chain and the compensator the
//! model, refusing a bad rig file or model before anything starts.

use crate::common::{bin, run_failing, run_json, TempDir};
use crate::processes::{prefix, Kid};
use std::path::{Path, PathBuf};
use std::time::Duration;
use vibro_mcap::Reader;
use vibro_msgs::{ServiceId, ServiceNames};

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// A rig file in `dir` with the given `[sensors]` lines after the sensitivity, a static
/// reference over 0..10 s.
fn rig_file(dir: &Path, name: &str, sensors: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(
        &path,
        format!(
            "format = \"vibrocomp-rig/1\"\ntriad = \"default\"\n[sensors]\n\
             sensitivity_v_per_g = 0.05\nac_corner_hz = 2.0\n{sensors}\
             [reference]\nkind = \"static\"\n[[reference.segment]]\nfrom_s = 0.0\n\
             to_s = 10.0\nup = \"+z\"\n"
        ),
    )
    .unwrap();
    path
}

/// One second of readings at 100 Hz and vibration samples at 1 kHz.
fn csvs(dir: &Path) -> (PathBuf, PathBuf) {
    let accel = dir.join("accel.csv");
    let vib = dir.join("vib.csv");
    let mut a = String::from("time_s,u1_v,u2_v,u3_v\n");
    for i in 1..=100 {
        a.push_str(&format!("{:.6},0.1,0.2,-1.6\n", f64::from(i) * 0.01));
    }
    let mut v = String::from("time_s,vd1_v,vd2_v,vd3_v\n");
    for i in 0..1000 {
        let t = f64::from(i) * 0.001;
        let x = (std::f64::consts::TAU * 40.0 * t).sin() * 0.05;
        v.push_str(&format!("{t:.6},{x},{x},{x}\n"));
    }
    std::fs::write(&accel, a).unwrap();
    std::fs::write(&vib, v).unwrap();
    (accel, vib)
}

fn import_args(accel: &Path, vib: &Path, rig: &Path, out: &Path) -> Vec<String> {
    ["log", "import", "--accel"]
        .iter()
        .map(|x| x.to_string())
        .chain([s(accel), "--vib".into(), s(vib), "--rig".into(), s(rig)])
        .chain(["--out".into(), s(out), "--json".into()])
        .collect()
}

/// `delay_s = 0.00156` travels into the log's `rig` metadata (`sensor_delay_s`); a
/// negative delay, one over 1 s, and a `rate_hz` the vibration CSV contradicts are
/// refused naming the rig file, the key, the value and the rule, and nothing is written.
#[test]
fn a_rig_files_chain_delay_is_imported_and_bad_ones_are_refused() {
    let dir = TempDir::new("rigchain", "import");
    let (accel, vib) = csvs(&dir.0);
    let out = dir.0.join("out.mcap");
    let rig = rig_file(&dir.0, "rig.toml", "delay_s = 0.00156\nrate_hz = 1000.0\n");
    let args = import_args(&accel, &vib, &rig, &out);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    run_json(&args);
    let meta = Reader::open(&out).unwrap().metadata().unwrap();
    let rig_meta = &meta
        .iter()
        .find(|(n, _)| n == "rig")
        .expect("rig metadata")
        .1;
    assert_eq!(rig_meta["sensor_delay_s"], "0.00156", "{rig_meta:?}");
    assert_eq!(rig_meta["sensor_ac_corner_hz"], "2");
    assert_eq!(rig_meta["sensor_hz"], "1000");
    std::fs::remove_file(&out).unwrap();

    for (name, sensors, want) in [
        (
            "negative.toml",
            "delay_s = -0.001\n",
            "sensors.delay_s = -0.001: must be finite and 0 <= delay <= 1 s",
        ),
        (
            "long.toml",
            "delay_s = 2\n",
            "sensors.delay_s = 2: must be finite and 0 <= delay <= 1 s",
        ),
        (
            "nan.toml",
            "delay_s = nan\n",
            "sensors.delay_s = NaN: must be finite and 0 <= delay <= 1 s",
        ),
    ] {
        let rig = rig_file(&dir.0, name, sensors);
        let args = import_args(&accel, &vib, &rig, &out);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let e = String::from_utf8_lossy(&run_failing(&args).stderr).to_string();
        assert!(
            e.contains(&s(&rig)) && e.contains(want),
            "{want:?} not in {e}"
        );
        assert!(!out.exists(), "{} written", out.display());
        println!("refused: {}", e.trim());
    }
    // Every problem of the options at once: the bad delay beside a bad flag.
    let rig = rig_file(&dir.0, "both.toml", "delay_s = -1.0\n");
    let mut args = import_args(&accel, &vib, &rig, &out);
    args.extend(["--period-tolerance".into(), "0.7".into()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let e = String::from_utf8_lossy(&run_failing(&args).stderr).to_string();
    assert!(
        e.contains("sensors.delay_s = -1") && e.contains("--period-tolerance = 0.7"),
        "{e}"
    );
    assert!(!out.exists());

    let rig = rig_file(&dir.0, "rate.toml", "rate_hz = 1024.0\n");
    let args = import_args(&accel, &vib, &rig, &out);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let e = String::from_utf8_lossy(&run_failing(&args).stderr).to_string();
    for want in [
        s(&rig).as_str(),
        "sensors.rate_hz = 1024",
        "vib.csv is at 1000",
        "the CSV must be at the rig's sensor rate (within 1e-6 relative)",
    ] {
        assert!(e.contains(want), "{want:?} not in {e}");
    }
    assert!(!out.exists(), "{} written", out.display());
}

/// `up` with a bad rig file (a delay over 1 s; an AC corner the compensator refuses)
/// or a bad model exits 1, naming file, key, value and rule (a bad rig file and a bad
/// model both at once), and starts nothing.
#[test]
fn up_with_a_bad_rig_file_or_model_starts_nothing() {
    let dir = TempDir::new("rigchain", "badup");
    let good = rig_file(&dir.0, "good.toml", "");
    let long = rig_file(&dir.0, "long.toml", "delay_s = 2.0\n");
    let corner = rig_file(&dir.0, "corner.toml", "delay_s = 0.001\n");
    std::fs::write(
        &corner,
        std::fs::read_to_string(&corner)
            .unwrap()
            .replace("ac_corner_hz = 2.0", "ac_corner_hz = 5000.0"),
    )
    .unwrap();
    let model = dir.0.join("model.toml");
    std::fs::write(
        &model,
        "mode = \"exact\"\n[[effect]]\nkind = \"no_such_effect\"\n",
    )
    .unwrap();
    let missing = dir.0.join("missing.toml");
    let cases: [(&[&str], Vec<&str>); 4] = [
        (
            &["--rig", &s(&long)],
            vec![
                "long.toml",
                "sensors.delay_s = 2: must be finite and 0 <= delay <= 1 s",
            ],
        ),
        (
            &["--rig", &s(&corner)],
            vec![
                "corner.toml",
                "sensors.ac_corner_hz = 5000: must be a finite corner",
            ],
        ),
        (
            &["--rig", &s(&good), "--model", &s(&model)],
            vec!["--model", "model.toml", "no_such_effect"],
        ),
        (
            &["--rig", &s(&long), "--model", &s(&missing)],
            vec![
                "long.toml",
                "sensors.delay_s = 2",
                "--model",
                "missing.toml",
            ],
        ),
    ];
    for (extra, wants) in cases {
        let p = prefix("rc1");
        let mut cmd = bin();
        cmd.args(["up", "--json", "--prefix", &p]).args(extra);
        let mut up = Kid::spawn(cmd, "up");
        let Some((status, _, err)) = up.wait_for(Duration::from_secs(15)) else {
            panic!("`up {extra:?}` started the system");
        };
        assert_eq!(status.code(), Some(1), "{err}");
        for want in wants {
            assert!(err.contains(want), "{want:?} not in {err}");
        }
        assert!(!err.contains("system up"), "services were started:\n{err}");
        println!("refused: {}", err.trim());
    }
}

/// `up --rig RIG --model MODEL --record OUT`: both services run on configurations that
/// carry the rig's chain (and the estimator the rig's rate) and the model, which the
/// recorder attaches to the log; the compensator says it loaded that configuration;
/// the derived configurations are removed when `up` stops.
#[test]
fn up_with_a_rig_and_a_model_runs_the_services_on_them() {
    let dir = TempDir::new("rigchain", "up");
    let rig = rig_file(&dir.0, "rig.toml", "delay_s = 0.00156\nrate_hz = 6400.0\n");
    let model = dir.0.join("mount.toml");
    std::fs::write(
        &model,
        "mode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 150.0\nq = 2.5\n",
    )
    .unwrap();
    let out = dir.0.join("session.mcap");
    let p = prefix("rc2");
    let mut cmd = bin();
    cmd.args(["up", "--json", "--prefix", &p, "--rig"])
        .arg(&rig)
        .arg("--model")
        .arg(&model)
        .arg("--record")
        .arg(&out);
    let mut up = Kid::spawn(cmd, "up");
    let names = ServiceNames::new(&p).unwrap();
    let services = [
        ServiceId::Estimator,
        ServiceId::Compensator,
        ServiceId::Recorder,
    ];
    if let Err(e) = vibro_service::supervise::wait_for_heartbeats(
        &names,
        &services,
        Duration::from_secs(30),
        || up.check_alive(),
    ) {
        panic!("{e:#}\nup stderr:\n{}", up.stderr());
    }
    let (status, stdout, stderr) = up.stop(libc::SIGINT, Duration::from_secs(30));
    assert!(status.success(), "up: {status}\n{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["rig"], s(&rig), "{report}");
    assert_eq!(report["model"], s(&model), "{report}");
    for r in report["processes"].as_array().unwrap() {
        assert_eq!(r["last_exit"], "exit status: 0", "{report}");
    }

    // What the services were started with, as the recorder attached it.
    let mut reader = Reader::open(&out).unwrap();
    let attached = |reader: &mut Reader, name: &str| -> toml::Table {
        let bytes = reader
            .read_attachment(name)
            .unwrap()
            .unwrap_or_else(|| panic!("{name} not attached"));
        toml::from_str(std::str::from_utf8(&bytes).unwrap()).unwrap()
    };
    let est = attached(&mut reader, "estimator.toml");
    let e = est["estimator"].as_table().unwrap();
    assert_eq!(e["delay_s"].as_float(), Some(0.00156));
    assert_eq!(e["ac_corner_hz"].as_float(), Some(2.0));
    assert_eq!(e["sample_rate_hz"].as_float(), Some(6400.0));
    assert_eq!(
        e["sensitivity_raw_per_g"].as_array().unwrap(),
        &vec![toml::Value::Float(0.05); 3]
    );
    let comp = attached(&mut reader, "compensator.toml");
    let sensors = comp["sensors"].as_table().unwrap();
    assert_eq!(sensors["delay_s"].as_float(), Some(0.00156));
    assert_eq!(sensors["ac_corner_hz"].as_float(), Some(2.0));
    assert_eq!(
        sensors["sensitivity_v_per_g"].as_array().unwrap(),
        &vec![toml::Value::Float(0.05); 3]
    );
    let model_abs = std::path::absolute(&model).unwrap();
    assert_eq!(comp["model"].as_str(), Some(s(&model_abs).as_str()));

    // The compensator loaded the derived configuration (its start-up line names it),
    // which is gone once `up` has stopped.
    let line = stderr
        .lines()
        .find(|l| l.contains("compensator running"))
        .unwrap_or_else(|| panic!("no start-up line:\n{stderr}"));
    let source = line
        .split_whitespace()
        .find_map(|w| w.strip_prefix("source="))
        .unwrap_or_else(|| panic!("no source in {line}"));
    assert!(
        source.contains("vibrocomp-up-") && source.ends_with("compensator.toml"),
        "{line}"
    );
    assert!(!Path::new(source).exists(), "{source} left behind");
}
