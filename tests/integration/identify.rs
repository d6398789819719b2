//! `vibrocomp identify`: the real binary on the shipped ten-position campaign and on
//! bad input. Expected values are computed here from MODEL.md section 5's formulas,
//! independently of vibro-ident.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde_json::Value;
use std::path::PathBuf;
use std::process::{Command, Output};

const FIXTURE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../config/campaigns/ten-positions-al15.csv"
);

fn vibrocomp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vibrocomp"))
        .args(args)
        .output()
        .expect("run vibrocomp")
}

/// A temporary file unique to this process and test.
fn temp_file(name: &str, contents: &str) -> PathBuf {
    let path =
        std::env::temp_dir().join(format!("vibrocomp-identify-{}-{name}", std::process::id()));
    std::fs::write(&path, contents).expect("write temp file");
    path
}

/// Section 5 [P1 (15)-(16)] for the AL-15 passport at aB3 = aB1 = aB2 = 0.42 g
/// (lambda = k1 = 1), in the order d01, d02, d03, delta1, delta2, delta3.
fn al15_components() -> [f64; 6] {
    let (d1a, k2, k3, k4, k5, m31, m32) = (15e-6, 105e-6, 87e-6, 10e-6, 0.9e-6, 11.6e-6, 11.6e-6);
    let a: f64 = 0.42;
    [
        0.637 * d1a * a + 0.5 * k2 * a.powi(2) + 0.375 * k4 * a.powi(4),
        0.5 * m31 * a * a,
        0.5 * m32 * a * a,
        1.5 * k3 * a.powi(2) + 1.875 * k5 * a.powi(4),
        3.0 * k4 * a.powi(2),
        5.0 * k5 * a.powi(2),
    ]
}

const NAMES: [&str; 6] = [
    "d01_g",
    "d02_g",
    "d03_g",
    "delta1",
    "delta2_per_g",
    "delta3_per_g2",
];

fn close(got: f64, want: f64) -> bool {
    // The CSV holds u_still and u_vib (~1.7 V), so dU carries ~1e-16 V of rounding.
    (got - want).abs() <= 1e-9 * want.abs() + 1e-14
}

#[test]
fn positions_fixture_gives_the_section_5_components() {
    let out = vibrocomp(&[
        "identify",
        "positions",
        FIXTURE,
        "--passport",
        "AL-15",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    assert_eq!(json["passport"], "AL-15");
    assert_eq!(json["n_positions"], 10);
    let want = al15_components();
    // The closed form's uncertainty is sigma/|K1| times the L2 norm of its
    // coefficients in (22), u_sigma_v = 2 uV: d0(1) = (dU3 + dU7)/2 has sqrt(0.5).
    let unit_g = 2e-6 / 1.6698;
    for method in ["closed_form", "wls"] {
        let est = &json[method]["estimate"];
        for (name, want) in NAMES.iter().zip(want) {
            let got = est["components"][name].as_f64().unwrap();
            assert!(
                close(got, want),
                "{method} {name}: got {got:e}, want {want:e}"
            );
        }
        assert_eq!(est["basis"]["kind"], "given");
        // VE by (23) at the default 1 g and 10 g.
        for (k, a_l) in [1.0f64, 10.0].iter().enumerate() {
            let p = &json[method]["predictions"][k];
            let ve = want[0]
                + want[1]
                + want[2]
                + want[3] * a_l
                + want[4] * a_l.powi(2)
                + want[5] * a_l.powi(3);
            assert_eq!(p["a_l_g"].as_f64().unwrap(), *a_l);
            assert!(
                close(p["ve_g"].as_f64().unwrap(), ve),
                "{method} VE({a_l} g)"
            );
            assert!(p["sigma_g"].as_f64().unwrap() > 0.0);
        }
    }
    let s = json["closed_form"]["estimate"]["sigma"]["d01_g"]
        .as_f64()
        .unwrap();
    assert!((s - unit_g * 0.5f64.sqrt()).abs() < 1e-12 * s);
    // Least squares over the eight positions: variance 0.375 (sigma/K1)^2.
    let s = json["wls"]["estimate"]["sigma"]["d01_g"].as_f64().unwrap();
    assert!((s - unit_g * 0.375f64.sqrt()).abs() < 1e-9 * s);
    assert_eq!(json["skipped"].as_array().unwrap().len(), 0);
}

#[test]
fn positions_table_shows_components_in_readable_units() {
    let out = vibrocomp(&["identify", "positions", FIXTURE, "--passport", "AL-15"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in [
        "d0(1)",
        "13.3908 ug",
        "5.2920 ug/g^2",
        "closed form (22)",
        "WLS",
    ] {
        assert!(text.contains(needle), "{needle:?} missing in:\n{text}");
    }
}

#[test]
fn bad_csv_cell_names_file_line_column_value_and_rule() {
    let path = temp_file(
        "bad-cell.csv",
        "# one comment line\n\
         tp,angle_deg,aB3_g,aB1_g,aB2_g,u_still_v,u_vib_v\n\
         1,0,0.42,0,0,-1.67,abc\n",
    );
    let path_str = path.to_str().unwrap();
    let out = vibrocomp(&["identify", "positions", path_str, "--passport", "AL-15"]);
    let _ = std::fs::remove_file(&path);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    for needle in [
        path_str,
        "line 3",
        "column u_vib_v",
        "\"abc\"",
        "must be a finite number",
    ] {
        assert!(err.contains(needle), "{needle:?} missing in: {err}");
    }
}

#[test]
fn missing_column_is_named() {
    let path = temp_file(
        "missing-column.csv",
        "tp,angle_deg,aB3_g,aB1_g,u_still_v,u_vib_v\n1,0,0.42,0,-1.67,-1.6701\n",
    );
    let out = vibrocomp(&[
        "identify",
        "positions",
        path.to_str().unwrap(),
        "--passport",
        "AL-15",
    ]);
    let _ = std::fs::remove_file(&path);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("missing column \"aB2_g\""), "{err}");
}

/// Still / vibrating / still records of `n` samples each with AR(1) output noise.
fn records_csv(still_v: f64, ve_g: f64, drift_g: f64, seed: u64) -> String {
    let k1_v_per_g = -1.6698;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (phi, sd_v) = (0.9f64, 20e-6);
    let innovation = Normal::new(0.0, sd_v * (1.0 - phi * phi).sqrt()).unwrap();
    let mut csv = String::from("phase,u_v\n");
    let mut x = 0.0;
    for (phase, level_v) in [
        ("still1", still_v),
        ("vib", still_v + k1_v_per_g * ve_g),
        ("still2", still_v + k1_v_per_g * drift_g),
    ] {
        for _ in 0..6000 {
            x = phi * x + innovation.sample(&mut rng);
            csv += &format!("{phase},{}\n", level_v + x);
        }
    }
    csv
}

#[test]
fn measure_recovers_a_known_ve_and_rejects_a_tilted_run() {
    let path = temp_file("good-run.csv", &records_csv(-1.17, 40e-6, 0.0, 7));
    let out = vibrocomp(&[
        "identify",
        "measure",
        path.to_str().unwrap(),
        "--passport",
        "AL-15",
        "--json",
    ]);
    let _ = std::fs::remove_file(&path);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    let ve = json["ve_g"].as_f64().unwrap();
    let sigma = json["ve_sigma_g"].as_f64().unwrap();
    // AR(1), phi = 0.9: the standard error of a 6000-sample mean is about
    // 20 uV*sqrt(19/6000) = 1.1 uV, so sigma(dV) ~ 1.4 uV/1.6698 ~ 0.8 ug.
    assert!((0.4e-6..1.6e-6).contains(&sigma), "{sigma:e}");
    assert!((ve - 40e-6).abs() < 4.0 * sigma, "{ve:e} +- {sigma:e}");

    let path = temp_file("tilted-run.csv", &records_csv(-1.17, 40e-6, 2.5e-4, 8));
    let out = vibrocomp(&[
        "identify",
        "measure",
        path.to_str().unwrap(),
        "--passport",
        "AL-15",
    ]);
    let _ = std::fs::remove_file(&path);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("input axis moved") && err.contains("exceeds 1e-4 g"),
        "{err}"
    );
}

#[test]
fn measure_fixture_gives_d01_within_its_uncertainty() {
    let run = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/campaigns/shake-run-al15.csv"
    );
    let out = vibrocomp(&["identify", "measure", run, "--passport", "AL-15", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    let (ve, sigma) = (
        json["ve_g"].as_f64().unwrap(),
        json["ve_sigma_g"].as_f64().unwrap(),
    );
    // The run is TP3 (no gravity on IA), so the VE is d0(1) of section 5.
    let d01 = al15_components()[0];
    assert!(
        (ve - d01).abs() < 4.0 * sigma,
        "{ve:e} +- {sigma:e} vs {d01:e}"
    );
    assert_eq!(json["still1"]["n_samples"], 600);
}
