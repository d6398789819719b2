//! `vibrocomp estimate` end to end: the real binary on CSV files written here, its band
//! PSD, RMS and covariance checked against scipy.signal.welch/csd
//! (tests/python/welch_reference.py), units and sensitivities, and bad input.

use crate::common::{bin, repo_path, run_failing, run_json};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A directory of its own per test, removed when the test ends.
struct TempDir(PathBuf);

impl TempDir {
    fn new(test: &str) -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!(
            "vibrocomp-estimate-{test}-{}-{nanos}",
            std::process::id()
        ));
        std::fs::create_dir_all(&dir).expect("temp dir");
        Self(dir)
    }
    fn file(&self, name: &str, text: &str) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, text).expect("write temp file");
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn csv_text(header: Option<&str>, rows: &[[f64; 3]]) -> String {
    let mut s = String::new();
    if let Some(h) = header {
        s.push_str(h);
        s.push('\n');
    }
    for r in rows {
        // Rust's shortest round-trip formatting: the file holds the exact values.
        let _ = writeln!(s, "{},{},{}", r[0], r[1], r[2]);
    }
    s
}

/// Broadband noise with a shape in frequency and a known correlation: axis 0 white,
/// axis 1 a first-order low-pass of its own noise plus half of axis 0, axis 2 white
/// plus a slowly varying part.
fn colored_noise(samples: usize) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
    let (mut y, mut z) = (0.0, 0.0);
    (0..samples)
        .map(|_| {
            let x = g();
            y = 0.8 * y + g();
            z = 0.99 * z + 0.1 * g();
            [x, y + 0.5 * x, 0.3 * g() + z]
        })
        .collect()
}

fn python_with_scipy() -> Command {
    let check = Command::new("python3")
        .args(["-c", "import numpy, scipy.signal"])
        .output();
    match check {
        Ok(out) if out.status.success() => Command::new("python3"),
        Ok(out) => panic!(
            "python3 cannot import numpy/scipy ({}); install them with \
             `pip install -r tests/python/requirements.txt`",
            String::from_utf8_lossy(&out.stderr).trim()
        ),
        Err(e) => panic!(
            "python3 is not available ({e}); install Python 3 and \
             `pip install -r tests/python/requirements.txt`"
        ),
    }
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn assert_close(what: &str, got: f64, want: f64, scale: f64) {
    let rel = (got - want).abs() / scale;
    assert!(
        rel < 0.01,
        "{what}: vibrocomp {got} vs scipy {want} ({rel:.2e} of {scale})"
    );
}

#[test]
fn estimate_band_psd_rms_and_covariance_agree_with_scipy_welch() {
    let dir = TempDir::new("scipy");
    let fs = 8192.0;
    let data = colored_noise(4 * fs as usize);
    let csv = dir.file("noise.csv", &csv_text(Some("x_g,y_g,z_g"), &data));
    let csv_arg = csv.to_str().expect("utf-8 temp path");

    let ours = run_json(&["estimate", csv_arg, "--rate-hz", "8192", "--json"]);
    let script = repo_path("tests/python/welch_reference.py");
    let out = python_with_scipy()
        .arg(&script)
        .args([csv_arg, "--rate-hz", "8192"])
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "{} failed:\n{}",
        script.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let reference: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");

    let estimates = ours["estimates"].as_array().expect("estimates");
    let windows = reference["windows"].as_array().expect("windows");
    assert_eq!(estimates.len(), 7);
    assert_eq!(estimates.len(), windows.len());
    let mut worst: f64 = 0.0;
    for (e, w) in estimates.iter().zip(windows) {
        // The same span: windows of 8192 samples every 4096.
        let start = (f(&e["start_ns"]) * 1e-9 * fs).round();
        assert_eq!(start, f(&w["start_sample"]));
        assert!(e["tones"].as_array().expect("tones").is_empty());
        for a in 0..3 {
            let (got, want) = (f(&e["broadband"]["rms_g"][a]), f(&w["rms_g"][a]));
            assert_close(&format!("rms axis {a}"), got, want, want);
            worst = worst.max((got / want - 1.0).abs());
            for (b, band) in e["bands"].as_array().expect("bands").iter().enumerate() {
                let (got, want) = (
                    f(&band["psd_g2_per_hz"][a]),
                    f(&w["band_psd_g2_per_hz"][b][a]),
                );
                assert_close(&format!("band {b} PSD axis {a}"), got, want, want);
                worst = worst.max((got / want - 1.0).abs());
                let (got, want) = (f(&band["rms_g"][a]), f(&w["band_rms_g"][b][a]));
                assert_close(&format!("band {b} RMS axis {a}"), got, want, want);
            }
            for b in 0..3 {
                let got = f(&e["broadband"]["covariance_g2"][a][b]);
                let want = f(&w["covariance_g2"][a][b]);
                // Off-diagonal terms are compared on the scale of the variances.
                let scale = (f(&w["covariance_g2"][a][a]) * f(&w["covariance_g2"][b][b])).sqrt();
                assert_close(&format!("covariance [{a}][{b}]"), got, want, scale);
            }
        }
    }
    eprintln!("vibrocomp vs scipy.signal.welch: worst relative difference {worst:.2e}");
}

#[test]
fn estimate_converts_volts_with_the_sensitivities_and_finds_the_tone() {
    let dir = TempDir::new("volts");
    let fs = 4096.0;
    let sens = [0.1, -0.2, 0.05];
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    // 2 g at 30 Hz on z [P2 Table 5], 0.05 g of noise, written in volts.
    let rows: Vec<[f64; 3]> = (0..3 * fs as usize)
        .map(|k| {
            let t = k as f64 / fs;
            let g: [f64; 3] = std::array::from_fn(|a| {
                let n: f64 = StandardNormal.sample(&mut rng);
                0.05 * n
                    + if a == 2 {
                        2.0 * (std::f64::consts::TAU * 30.0 * t).sin()
                    } else {
                        0.0
                    }
            });
            std::array::from_fn(|a| g[a] * sens[a])
        })
        .collect();
    let csv = dir.file("volts.csv", &csv_text(None, &rows));
    let csv_arg = csv.to_str().expect("utf-8 temp path");
    let args = [
        "estimate",
        csv_arg,
        "--rate-hz",
        "4096",
        "--units",
        "v",
        "--sensitivity-v-per-g",
        "0.1,-0.2,0.05",
        "--band-hz",
        "20,1500",
    ];
    let mut json_args = args.to_vec();
    json_args.push("--json");
    let report = run_json(&json_args);
    assert_eq!(report["units"], "v");
    let estimates = report["estimates"].as_array().expect("estimates");
    assert_eq!(estimates.len(), 5);
    // 0.05 g white at 4096 Hz over 20..1500 Hz.
    let expected_rms = 0.05 * (2.0 * 1480.0 / fs).sqrt();
    for e in estimates {
        let tones = e["tones"].as_array().expect("tones");
        assert_eq!(tones.len(), 1, "{tones:?}");
        assert!((f(&tones[0]["frequency_hz"]) - 30.0).abs() < 1e-3);
        assert!((f(&tones[0]["amplitude_g"][2]) - 2.0).abs() < 2e-3);
        for a in 0..3 {
            let rms = f(&e["broadband"]["rms_g"][a]);
            assert!((rms / expected_rms - 1.0).abs() < 0.1, "axis {a}: {rms}");
        }
    }

    // The table: a title, a header, then one row per window.
    let out = bin().args(args).output().expect("vibrocomp runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2 + 5, "{text}");
    assert!(
        lines[2].contains("30.00") && lines[2].contains("2.00"),
        "{text}"
    );
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn estimate_divides_out_the_ac_coupling_and_the_response_table() {
    let dir = TempDir::new("response");
    let fs = 4096.0;
    let (f0, fc) = (100.0, 5.0);
    // The chain: first-order high-pass at 5 Hz, then gain 2 and +10 degrees (table).
    let u: f64 = f0 / fc;
    let gain = 2.0 * u / (1.0 + u * u).sqrt();
    let phase = std::f64::consts::FRAC_PI_2 - u.atan() + 10f64.to_radians();
    let truth = [1.0, 0.5, 0.25];
    let rows: Vec<[f64; 3]> = (0..2 * fs as usize)
        .map(|k| {
            let arg = std::f64::consts::TAU * f0 * k as f64 / fs;
            std::array::from_fn(|a| gain * truth[a] * (arg + phase + a as f64).sin())
        })
        .collect();
    let csv = dir.file("measured.csv", &csv_text(None, &rows));
    let table = dir.file(
        "response.csv",
        "frequency_hz,gain_x,gain_y,gain_z,phase_x_deg,phase_y_deg,phase_z_deg\n\
         0,2,2,2,10,10,10\n\
         1000,2,2,2,10,10,10\n",
    );
    let report = run_json(&[
        "estimate",
        csv.to_str().expect("utf-8 temp path"),
        "--rate-hz",
        "4096",
        "--band-hz",
        "20,1500",
        "--ac-corner-hz",
        "5",
        "--response",
        table.to_str().expect("utf-8 temp path"),
        "--json",
    ]);
    for e in report["estimates"].as_array().expect("estimates") {
        let t = &e["tones"][0];
        let centre_s = f(&e["center_ns"]) * 1e-9;
        for a in 0..3 {
            assert!(
                (f(&t["amplitude_g"][a]) / truth[a] - 1.0).abs() < 1e-6,
                "{t}"
            );
            // True phase at the window centre: sin(2 pi f t + a).
            let want = std::f64::consts::TAU * f0 * centre_s + a as f64;
            let d = (f(&t["phase_rad"][a]) - want).rem_euclid(std::f64::consts::TAU);
            assert!(d.min(std::f64::consts::TAU - d) < 1e-6, "axis {a}: {t}");
        }
    }

    let bad = dir.file("bad-response.csv", "frequency_hz,gain\n0,1\n");
    let e = stderr_of(&[
        "estimate",
        csv.to_str().expect("utf-8 temp path"),
        "--rate-hz",
        "4096",
        "--response",
        bad.to_str().expect("utf-8 temp path"),
    ]);
    assert_mentions(
        &e,
        &[
            "bad-response.csv",
            "line 1",
            "expected frequency_hz, gain_x",
        ],
    );
}

fn stderr_of(args: &[&str]) -> String {
    String::from_utf8_lossy(&run_failing(args).stderr).into_owned()
}

fn assert_mentions(text: &str, parts: &[&str]) {
    for p in parts {
        assert!(text.contains(p), "{p:?} missing from:\n{text}");
    }
}

#[test]
fn estimate_reports_bad_input_with_file_line_column_value_and_rule() {
    let dir = TempDir::new("bad");
    let ok_rows: Vec<[f64; 3]> = (0..3000).map(|k| [k as f64 * 1e-3, 0.0, 1.0]).collect();
    let path = |p: &Path| p.to_str().expect("utf-8 temp path").to_string();

    let missing = dir.0.join("missing.csv");
    let e = stderr_of(&["estimate", &path(&missing), "--rate-hz", "4096"]);
    assert_mentions(&e, &["missing.csv", "cannot open"]);

    let mut text = csv_text(Some("x,y,z"), &ok_rows[..3]);
    text.push_str("0.1,abc,0.3\n");
    text.push_str(&csv_text(None, &ok_rows[..3]));
    let bad_value = dir.file("value.csv", &text);
    let e = stderr_of(&["estimate", &path(&bad_value), "--rate-hz", "4096"]);
    assert_mentions(
        &e,
        &[
            "value.csv",
            "line 5",
            "column 2",
            "\"y\"",
            "\"abc\"",
            "not a number",
        ],
    );

    let mut text = csv_text(None, &ok_rows[..2]);
    text.push_str("# a comment line\n0.1,0.2\n0.1,,0.3\n");
    let bad_shape = dir.file("shape.csv", &text);
    let e = stderr_of(&["estimate", &path(&bad_shape), "--rate-hz", "4096"]);
    assert_mentions(
        &e,
        &[
            "shape.csv",
            "line 4: 2 columns; expected 3",
            "line 5, column 2",
            "empty cell",
        ],
    );

    let header = dir.file("header.csv", "time,x,y,z\n0,1,2,3\n");
    let e = stderr_of(&["estimate", &path(&header), "--rate-hz", "4096"]);
    assert_mentions(
        &e,
        &["header.csv", "line 1", "header has 4 columns", "expected 3"],
    );

    let short = dir.file("short.csv", &csv_text(None, &ok_rows[..500]));
    let e = stderr_of(&["estimate", &path(&short), "--rate-hz", "4096"]);
    assert_mentions(&e, &["short.csv", "500 rows", "shorter than one window"]);

    let good = dir.file("good.csv", &csv_text(None, &ok_rows));
    let e = stderr_of(&[
        "estimate",
        &path(&good),
        "--rate-hz",
        "4096",
        "--units",
        "v",
    ]);
    assert_mentions(&e, &["--units v needs --sensitivity-v-per-g"]);
    let e = stderr_of(&[
        "estimate",
        &path(&good),
        "--rate-hz",
        "1000",
        "--sensitivity-v-per-g",
        "0.1,0.1,0.1",
    ]);
    assert_mentions(&e, &["--sensitivity-v-per-g", "--units g"]);
    let e = stderr_of(&[
        "estimate",
        &path(&good),
        "--rate-hz",
        "1000",
        "--overlap",
        "1.5",
        "--band-hz",
        "20,900",
    ]);
    // Every problem at once, each with its value and rule.
    assert_mentions(
        &e,
        &[
            "overlap_fraction = 1.5",
            "0 <= overlap < 1",
            "broadband_band_hz = [20, 900]",
            "Nyquist",
        ],
    );
    let e = stderr_of(&[
        "estimate",
        &path(&good),
        "--rate-hz",
        "4096",
        "--psd-bands-hz",
        "20..40",
    ]);
    assert_mentions(&e, &["--psd-bands-hz", "\"20..40\"", "LO-HI"]);
}

/// The rig's own format, from data vibrocomp did not make: the independent rig
/// generator (`tests/python/rig_generator.py`, written from MODEL.md and RIG.md) writes
/// a shaker run's vibration sensors as `time_s,vd1_v,vd2_v,vd3_v` (0.1 V/g, AC-coupled
/// at 2 Hz). `estimate` reads the time column, finds the 60 Hz tone with each sensor's
/// body-axis amplitude and the 20..640 Hz random RMS within its stated uncertainties,
/// and gives the same estimates as the file without the time column, stamped on the
/// file's time.
#[test]
fn estimate_reads_a_rigs_time_column_on_independent_data() {
    let dir = TempDir::new("rig");
    let gen = python_with_scipy()
        .arg(repo_path("tests/python/rig_generator.py"))
        .args([
            "run",
            "--sensor-rate-hz",
            "6400",
            "--vibrate-throughout",
            "--duration-s",
            "8",
            "--tone-hz",
            "60",
            "--tone-amp-g",
            "1.5,1.0,0.5",
            "--tone-phase-deg",
            "10,20,30",
            "--random-psd",
            "0.002",
            "--out",
        ])
        .arg(&dir.0)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("python3 runs");
    assert!(
        gen.status.success(),
        "{}",
        String::from_utf8_lossy(&gen.stderr)
    );
    let timed = dir.0.join("vib.csv");
    let text = std::fs::read_to_string(&timed).unwrap();
    let plain: String = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| format!("{}\n", l.split_once(',').unwrap().1))
        .collect();
    let plain = dir.file("vib-plain.csv", &plain);
    let estimate = |file: &Path| {
        run_json(&[
            "estimate",
            file.to_str().unwrap(),
            "--rate-hz",
            "6400",
            "--units",
            "v",
            "--sensitivity-v-per-g",
            "0.1",
            "--band-hz",
            "20,640",
            "--ac-corner-hz",
            "2",
            "--json",
        ])
    };
    let (a, b) = (estimate(&timed), estimate(&plain));
    let (wa, wb) = (
        a["estimates"].as_array().unwrap(),
        b["estimates"].as_array().unwrap(),
    );
    assert_eq!(wa.len(), wb.len());
    assert!(wa.len() >= 10, "{}", wa.len());
    // The generator's first sample is at 0 s: the same windows, the same stamps.
    for (x, y) in wa.iter().zip(wb) {
        assert_eq!(x["tones"], y["tones"]);
        assert_eq!(x["broadband"], y["broadband"]);
        assert_eq!(x["start_ns"], y["start_ns"]);
    }
    // VD1..VD3 measure along the IAs of the default triad: body x, y, z.
    let amplitude_g = [1.5, 1.0, 0.5];
    let rms_g = (0.002f64 * 620.0).sqrt();
    let (mut z2, mut n) = (0.0, 0);
    for w in wa {
        let tone = &w["tones"][0];
        let f_hz = f(&tone["frequency_hz"]);
        assert!(
            (f_hz - 60.0).abs() < 4.0 * f(&tone["frequency_u_hz"]) + 1e-3,
            "{f_hz}"
        );
        for j in 0..3 {
            let z = (f(&tone["amplitude_g"][j]) - amplitude_g[j]) / f(&tone["amplitude_u_g"][j]);
            assert!(
                z.abs() < 4.0,
                "window {}, axis {j}: tone z = {z}",
                w["index"]
            );
            let zr = (f(&w["broadband"]["rms_g"][j]) - rms_g) / f(&w["broadband"]["rms_u_g"][j]);
            assert!(
                zr.abs() < 4.0,
                "window {}, axis {j}: rms z = {zr}",
                w["index"]
            );
            z2 += z * z + zr * zr;
            n += 2;
        }
    }
    // Overlapping windows are not independent; the pulls' mean square still near 1.
    let chi2_per_n = z2 / n as f64;
    assert!((0.3..2.0).contains(&chi2_per_n), "{chi2_per_n}");
}
