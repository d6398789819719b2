//! A rig's reference as rigs have it (issue "round two", item 9): a piezoelectric
//! reference recorded AC-coupled in V through its chain (sensitivity, first-order AC
//! corner, delay), gravity gone, its orientation stated by the rig file or the
//! manifest. On data vibrocomp did not make: the independent rig generator
//! (`tests/python/rig_generator.py`, written from MODEL.md and RIG.md), which records
//! the same run's reference either DC-coupled in g or through the stated chain in V
//! (`--ref-sens-v-per-g`, `--ref-hp-hz`, `--ref-delay-s`) and writes the rig file that
//! states that chain and the orientation (`--write-rig`). The same seed makes the same
//! run both ways: the unit readings are the same file, only the reference differs.

use crate::common::{bin, rig_campaign, run_failing, run_json, TempDir};
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The AC-coupled reference's chain: 0.01 V/g, a 0.5 Hz corner, a 1.3 ms delay.
const CHAIN: [&str; 6] = [
    "--ref-sens-v-per-g",
    "0.01",
    "--ref-hp-hz",
    "0.5",
    "--ref-delay-s",
    "0.0013",
];

type Runs = Vec<BTreeMap<String, String>>;

/// The generator's campaign twice with the same seed: the reference DC-coupled in g
/// (`dc`) and through [`CHAIN`] in V with the rig files (`ac`).
fn twins(dir: &Path, args: &[&str]) -> (PathBuf, PathBuf, Runs) {
    let (dc, ac) = (dir.join("dc"), dir.join("ac"));
    let runs = rig_campaign(&dc, args);
    let mut with_chain = args.to_vec();
    with_chain.extend_from_slice(&CHAIN);
    with_chain.push("--write-rig");
    let runs_ac = rig_campaign(&ac, &with_chain);
    assert_eq!(runs.len(), runs_ac.len());
    for r in &runs {
        let same = |f: &str| std::fs::read(dc.join(&r["folder"]).join(f)).unwrap();
        let other = |f: &str| std::fs::read(ac.join(&r["folder"]).join(f)).unwrap();
        assert_eq!(
            same("accel.csv"),
            other("accel.csv"),
            "one run, two references"
        );
    }
    (dc, ac, runs)
}

/// The run plan's windows on the files' time, s (4 s still, 4 s vibrating, 4 s still;
/// the reference's delay taken off its time stamps, it ends 1.3 ms before the readings).
const WINDOWS: [&str; 3] = [
    "--still-before-s=0,4",
    "--vibrating-s=4.2,7.9",
    "--still-after-s=8.1,11.9",
];

/// `identify measure` of unit `k` (0-based) in `folder` through its reference, with the
/// rig file when `rig` (the reference then in V).
fn measure(folder: &Path, k: usize, axes: [&str; 3], rig: bool) -> Value {
    let mut args: Vec<String> = vec![
        "identify".into(),
        "measure".into(),
        folder.join("accel.csv").display().to_string(),
        "--passport=AL-15".into(),
        format!("--column=u{}_v", k + 1),
        "--reference".into(),
        folder.join("reference.csv").display().to_string(),
        format!("--ia={}", axes[0]),
        format!("--oa={}", axes[1]),
        format!("--pa={}", axes[2]),
        "--json".into(),
    ];
    args.extend(WINDOWS.iter().map(|w| w.to_string()));
    if rig {
        args.push("--rig".into());
        args.push(folder.join("rig.toml").display().to_string());
    }
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    run_json(&refs)
}

fn truth(folder: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(folder.join("truth.json")).unwrap()).unwrap()
}

/// Pooled over the conditions: the RMS stated uncertainty over the RMS scatter of the
/// repeats (unbiased variances pooled by degrees of freedom).
fn stated_over_scatter(rows: &BTreeMap<(String, usize), Vec<(f64, f64)>>) -> f64 {
    let (mut ss, mut dof, mut u2, mut n) = (0.0, 0usize, 0.0, 0usize);
    for r in rows.values() {
        let mean = r.iter().map(|x| x.0).sum::<f64>() / r.len() as f64;
        ss += r.iter().map(|x| (x.0 - mean).powi(2)).sum::<f64>();
        dof += r.len() - 1;
        u2 += r.iter().map(|x| x.1 * x.1).sum::<f64>();
        n += r.len();
    }
    (u2 / n as f64).sqrt() / (ss / dof as f64).sqrt()
}

/// (1) `identify measure` with an AC-coupled 0.01 V/g reference in V at 5 kHz (a rate
/// 800 Hz readings do not divide), its chain and orientation from the rig file, gives
/// the DC-coupled g reference's result within the stated uncertainty; its pulls against
/// the generator's VE are within 3 and its stated uncertainty is the scatter over the
/// repeats (within 1.5).
#[test]
fn measure_with_an_ac_coupled_reference_from_the_rig_file() {
    let dir = TempDir::new("reference-chain", "measure");
    let (dc, ac, runs) = twins(
        &dir.0,
        &[
            "--sensor-rate-hz",
            "5000",
            "--still-s",
            "4",
            "--vib-s",
            "4",
            "--tone-freqs-hz",
            "40",
            "--orientations",
            "+z,-x,+y,-z",
            "--repeat",
            "6",
            "--seed",
            "91",
        ],
    );
    let mut rows: BTreeMap<(String, usize), Vec<(f64, f64)>> = BTreeMap::new();
    let (mut worst_pull, mut worst_diff) = (0.0f64, 0.0f64);
    for run in &runs {
        let (f_dc, f_ac) = (dc.join(&run["folder"]), ac.join(&run["folder"]));
        let t = truth(&f_ac);
        for k in 0..3 {
            let unit = &t["triad"][k];
            let axes = ["ia", "oa", "pa"].map(|a| unit[a].as_str().expect(a));
            let with_dc = measure(&f_dc, k, axes, false);
            let with_ac = measure(&f_ac, k, axes, true);
            let chain = &with_ac["reference"]["chain"];
            assert_eq!(chain["sensitivity_v_per_g"][0], 0.01, "{chain}");
            assert_eq!(
                (chain["ac_corner_hz"].as_f64(), chain["delay_s"].as_f64()),
                (Some(0.5), Some(0.0013))
            );
            assert_eq!(with_dc["reference"]["chain"], Value::Null);
            assert_eq!(with_ac["linear_response_source"], "fitted");
            let v = |x: &Value, key: &str| x[key].as_f64().expect(key);
            let (ve, sigma) = (v(&with_ac, "ve_g"), v(&with_ac, "ve_sigma_g"));
            worst_diff = worst_diff.max((ve - v(&with_dc, "ve_g")).abs() / sigma);
            let pull = (ve - v(&t["units"][k], "ve_time_domain_g")) / sigma;
            worst_pull = worst_pull.max(pull.abs());
            rows.entry((run["run_id"].clone(), k))
                .or_default()
                .push((ve, sigma));
        }
    }
    let ratio = stated_over_scatter(&rows);
    println!(
        "FIGURES reference_chain measure: {} conditions x 6 repeats: AC vs DC within \
         {worst_diff:.3} sigma, largest pull {worst_pull:.2}, stated / scatter {ratio:.3}",
        rows.len()
    );
    assert_eq!(rows.len(), 12);
    assert!(
        worst_diff < 1.0,
        "AC-coupled vs DC-coupled: {worst_diff:.3} sigma"
    );
    assert!(worst_pull < 3.0, "largest pull {worst_pull:.2}");
    assert!(
        (1.0 / 1.5..=1.5).contains(&ratio),
        "stated / scatter {ratio:.3}"
    );
}

/// A manifest of one repeat's runs; `chain`: the reference through [`CHAIN`] in V.
fn manifest(dir: &Path, runs: &Runs, repeat: &str, still_s: f64, chain: bool) -> PathBuf {
    // The last 0.1 s left out: the delayed reference ends before the readings.
    let (vib_from, vib_to, end) = (still_s + 0.2, 2.0 * still_s - 0.1, 3.0 * still_s - 0.1);
    let mut text = format!(
        "format = \"vibrocomp-campaign/1\"\ntriad = \"default\"\n\n[segments]\n\
         still_before_s = [0.0, {still_s}]\nvibrating_s = [{vib_from}, {vib_to}]\n\
         still_after_s = [{}, {end}]\n",
        2.0 * still_s + 0.1
    );
    if chain {
        text.push_str(
            "\n[reference_chain]\nsensitivity_v_per_g = 0.01\nac_corner_hz = 0.5\ndelay_s = 0.0013\n",
        );
    }
    for r in runs.iter().filter(|r| r["repeat"] == repeat) {
        let folder = &r["folder"];
        let _ = write!(
            text,
            "\n[[run]]\nid = \"{}\"\naccel = \"{folder}/accel.csv\"\n\
             reference = \"{folder}/reference.csv\"\nup = [{}, {}, {}]\n",
            r["run_id"], r["gx"], r["gy"], r["gz"]
        );
    }
    let path = dir.join(format!("campaign-{repeat}.toml"));
    std::fs::write(&path, text).expect("manifest");
    path
}

/// (2) `identify campaign` with the manifest's `[reference_chain]` and the runs'
/// orientation: the DC-coupled reference's result within the stated uncertainty, pulls
/// within 3, stated uncertainty the scatter over repeats.
#[test]
fn campaign_with_an_ac_coupled_reference_from_the_manifest() {
    let dir = TempDir::new("reference-chain", "campaign");
    let (dc, ac, runs) = twins(
        &dir.0,
        &[
            "--sensor-rate-hz",
            "5000",
            "--still-s",
            "4",
            "--vib-s",
            "4",
            "--tone-freqs-hz",
            "40",
            "--orientations",
            "+z,-x,+y,-z",
            "--repeat",
            "4",
            "--seed",
            "92",
        ],
    );
    let mut rows: BTreeMap<(String, usize), Vec<(f64, f64)>> = BTreeMap::new();
    let (mut worst_pull, mut worst_diff) = (0.0f64, 0.0f64);
    for repeat in ["0", "1", "2", "3"] {
        let m_dc = manifest(&dc, &runs, repeat, 4.0, false);
        let m_ac = manifest(&ac, &runs, repeat, 4.0, true);
        let out_dc = run_json(&["identify", "campaign", m_dc.to_str().unwrap(), "--json"]);
        let out_ac = run_json(&["identify", "campaign", m_ac.to_str().unwrap(), "--json"]);
        let (u_dc, u_ac) = (
            out_dc["units"].as_array().unwrap(),
            out_ac["units"].as_array().unwrap(),
        );
        assert_eq!((u_dc.len(), u_ac.len()), (12, 12));
        for (a, d) in u_ac.iter().zip(u_dc) {
            assert_eq!((&a["run_id"], &a["unit"]), (&d["run_id"], &d["unit"]));
            let v = |x: &Value, key: &str| x["measurement"]["measurement"][key].as_f64().unwrap();
            let (ve, sigma) = (v(a, "ve_g"), v(a, "ve_sigma_g"));
            worst_diff = worst_diff.max((ve - v(d, "ve_g")).abs() / sigma);
            let run = runs
                .iter()
                .find(|r| r["run_id"] == a["run_id"].as_str().unwrap() && r["repeat"] == repeat)
                .unwrap();
            let k = ["AK1", "AK2", "AK3"]
                .iter()
                .position(|n| *n == a["unit"])
                .unwrap();
            let t = truth(&ac.join(&run["folder"]));
            let pull = (ve - t["units"][k]["ve_time_domain_g"].as_f64().unwrap()) / sigma;
            worst_pull = worst_pull.max(pull.abs());
            rows.entry((run["run_id"].clone(), k))
                .or_default()
                .push((ve, sigma));
        }
    }
    let ratio = stated_over_scatter(&rows);
    println!(
        "FIGURES reference_chain campaign: {} conditions x 4 repeats: AC vs DC within \
         {worst_diff:.3} sigma, largest pull {worst_pull:.2}, stated / scatter {ratio:.3}",
        rows.len()
    );
    assert!(
        worst_diff < 1.0,
        "AC-coupled vs DC-coupled: {worst_diff:.3} sigma"
    );
    assert!(worst_pull < 3.0, "largest pull {worst_pull:.2}");
    assert!(
        (1.0 / 1.5..=1.5).contains(&ratio),
        "stated / scatter {ratio:.3}"
    );
}

/// (3) A manifest whose AC-coupled reference runs at 3.2 kHz goes to `lab diagnose`
/// without an estimator file: the shipped band (20..2000 Hz) passes its Nyquist
/// frequency and is clipped to 0.45 of its rate (1440 Hz), said in the text and the
/// JSON; the hidden mount resonance (150 Hz, Q 2.5) comes out within 3 sigma.
#[test]
fn a_manifest_at_3200_hz_is_diagnosed_with_its_band_clipped() {
    let dir = TempDir::new("reference-chain", "lab");
    let mut args = vec![
        "--sensor-rate-hz",
        "3200",
        "--tone-freqs-hz",
        "40,100,160,240",
        "--resonance-f0-hz",
        "150",
        "--resonance-q",
        "2.5",
        "--write-rig",
    ];
    args.extend_from_slice(&CHAIN);
    let runs = rig_campaign(&dir.0, &args);
    let m = manifest(&dir.0, &runs, "0", 8.0, true);
    let table = dir.0.join("table.csv");
    let d = run_json(&[
        "lab",
        "diagnose",
        m.to_str().unwrap(),
        "--json",
        "--table-out",
        table.to_str().unwrap(),
    ]);
    let clip = &d["manifests"][0]["band_clipped"];
    assert_eq!(clip["reference_rate_hz"], 3200.0, "{}", d["manifests"]);
    assert_eq!(clip["broadband_stated_hz"][1], 2000.0);
    assert!((clip["broadband_used_hz"][1].as_f64().unwrap() - 1440.0).abs() < 1e-9);
    assert_eq!(d["manifests"][0]["runs_band_clipped"], runs.len());
    let v = &d["verdict"];
    println!("FIGURES reference_chain lab at 3.2 kHz: {v}");
    assert_eq!(v["kind"], "mount_resonance", "{v}");
    for (name, truth) in [("freq_hz", 150.0), ("q", 2.5)] {
        let p = v["params"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .expect(name);
        let (value, sigma) = (p["value"].as_f64().unwrap(), p["sigma"].as_f64().unwrap());
        println!("FIGURES reference_chain lab at 3.2 kHz: {name} = {value} +- {sigma}");
        assert!(
            (value - truth).abs() <= 3.0 * sigma,
            "{name} = {value} +- {sigma}, the generator's {truth}"
        );
    }
    // The text says so too (the table's compare: the manifest read again is slow).
    let out = bin()
        .args(["lab", "compare", m.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("the estimator's broadband band 20..2000 Hz clipped to 20..1440 Hz (0.45 of the reference's 3200 Hz)"),
        "{text}"
    );
}

/// (4) Bad chain values in a rig file or a manifest: every problem at once, each with
/// the file, the key, the value and the rule; nothing measured.
#[test]
fn bad_chain_values_are_refused_with_file_field_value_and_rule() {
    let dir = TempDir::new("reference-chain", "bad");
    let mut args = vec![
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
        "--write-rig",
    ];
    args.extend_from_slice(&CHAIN);
    let runs = rig_campaign(&dir.0, &args);
    let folder = dir.0.join(&runs[0]["folder"]);
    let rig = std::fs::read_to_string(folder.join("rig.toml")).unwrap();
    let bad = rig
        .replace(
            "sensitivity_v_per_g = 0.01",
            "sensitivity_v_per_g = [0.01, 0.0, 0.01]",
        )
        .replace("ac_corner_hz = 0.5", "ac_corner_hz = -1.0")
        .replace("delay_s = 0.0013", "delay_s = 2.0");
    let bad_rig = folder.join("bad-rig.toml");
    std::fs::write(&bad_rig, bad).unwrap();
    let out = run_failing(&[
        "identify",
        "measure",
        folder.join("accel.csv").to_str().unwrap(),
        "--passport=AL-15",
        "--column=u3_v",
        "--still-before-s=0,1",
        "--vibrating-s=1.2,1.9",
        "--still-after-s=2.1,2.9",
        "--reference",
        folder.join("reference.csv").to_str().unwrap(),
        "--ia=z",
        "--rig",
        bad_rig.to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&out.stderr);
    for want in [
        "bad-rig.toml",
        "reference.chain.sensitivity_v_per_g = [0.01, 0.0, 0.01]: must be one or three finite non-zero numbers",
        "reference.chain.ac_corner_hz = -1: must be finite, > 0",
        "reference.chain.delay_s = 2: must be finite and 0 <= delay <= 1 s",
    ] {
        assert!(e.contains(want), "{want:?} not in {e}");
    }
    // A manifest's [reference_chain]: the same rules, with the manifest named.
    let m = manifest(&dir.0, &runs, "0", 1.0, true);
    let text = std::fs::read_to_string(&m)
        .unwrap()
        .replace("sensitivity_v_per_g = 0.01", "sensitivity_v_per_g = nan")
        .replace("ac_corner_hz = 0.5", "ac_corner_hz = 5000.0")
        .replace("delay_s = 0.0013", "delay_s = -0.1");
    std::fs::write(&m, text).unwrap();
    let out = run_failing(&["identify", "campaign", m.to_str().unwrap()]);
    let e = String::from_utf8_lossy(&out.stderr);
    for want in [
        "campaign-0.toml",
        "reference_chain.sensitivity_v_per_g = NaN: must be one or three finite non-zero numbers",
        "reference_chain.ac_corner_hz = 5000: must be finite, > 0 and <= 1000 Hz",
        "reference_chain.delay_s = -0.1: must be finite and 0 <= delay <= 1 s",
    ] {
        assert!(e.contains(want), "{want:?} not in {e}");
    }
    // A rig file without a chain: --rig says what it is for.
    let plain = folder.join("plain-rig.toml");
    let cut = rig.find("[reference.chain]").unwrap();
    std::fs::write(&plain, &rig[..cut]).unwrap();
    let out = run_failing(&[
        "identify",
        "measure",
        folder.join("accel.csv").to_str().unwrap(),
        "--passport=AL-15",
        "--column=u3_v",
        "--still-before-s=0,1",
        "--vibrating-s=1.2,1.9",
        "--still-after-s=2.1,2.9",
        "--reference",
        folder.join("reference.csv").to_str().unwrap(),
        "--ia=z",
        "--rig",
        plain.to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("states no [reference.chain]"), "{e}");
}
