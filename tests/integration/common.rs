//! Helpers shared by the integration tests: running the real `vibrocomp` binary.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Held by the tests that keep both cores busy for a minute or more (the lab on the
/// waveform's rigs and battery) and by the test that compares two timed runs of the
/// services (the two-host demo, whose compensator's wall-clock rules see the load):
/// they do not run beside each other. A test that panicked while holding it leaves it
/// usable.
pub fn heavy() -> std::sync::MutexGuard<'static, ()> {
    static HEAVY: std::sync::Mutex<()> = std::sync::Mutex::new(());
    HEAVY.lock().unwrap_or_else(|e| e.into_inner())
}

/// The `vibrocomp` binary built for these tests.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_vibrocomp"))
}

/// A path under the workspace root.
pub fn repo_path(rel: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join(rel)
}

/// Runs `vibrocomp ARGS`, asserts success, and parses stdout as JSON.
pub fn run_json(args: &[&str]) -> serde_json::Value {
    let out = bin().args(args).output().expect("vibrocomp runs");
    assert!(
        out.status.success(),
        "vibrocomp {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "vibrocomp {args:?}: stdout is not JSON ({e}):\n{}",
            String::from_utf8_lossy(&out.stdout)
        )
    })
}

/// Runs `vibrocomp ARGS` expecting failure; returns the output.
pub fn run_failing(args: &[&str]) -> Output {
    let out = bin().args(args).output().expect("vibrocomp runs");
    assert!(
        !out.status.success(),
        "vibrocomp {args:?} unexpectedly succeeded"
    );
    out
}

/// A number from a JSON object.
pub fn num(v: &serde_json::Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("key {key:?} is not a number in {v}"))
}

/// A directory of its own per test (`vibrocomp-{group}-{test}-{pid}-{nanos}` under the
/// system's temporary folder), removed when the test ends.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(group: &str, test: &str) -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!(
            "vibrocomp-{group}-{test}-{}-{nanos}",
            std::process::id()
        ));
        std::fs::create_dir_all(&dir).expect("temp dir");
        Self(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs the independent rig generator's `campaign` (`tests/python/rig_generator.py`,
/// written from MODEL.md, not from vibrocomp) into `dir` with `args`; returns the rows of
/// its `runs.csv` as maps of column to cell.
pub fn rig_campaign(dir: &Path, args: &[&str]) -> Vec<BTreeMap<String, String>> {
    let out = Command::new("python3")
        .arg(repo_path("tests/python/rig_generator.py"))
        .args(["campaign", "--out"])
        .arg(dir)
        .args(args)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "the rig generator failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.join("runs.csv")).expect("runs.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    lines
        .map(|l| {
            header
                .iter()
                .zip(l.split(','))
                .map(|(h, c)| (h.to_string(), c.to_string()))
                .collect()
        })
        .collect()
}

/// The browser of the reports' screenshot tests: Debian's `chromium` (installed by
/// `.ci/run`), or `VIBROCOMP_CHROMIUM`.
fn chromium() -> PathBuf {
    if let Some(p) = std::env::var_os("VIBROCOMP_CHROMIUM") {
        return p.into();
    }
    for p in [
        "/usr/bin/chromium",
        "/usr/bin/chromium-browser",
        "/usr/bin/google-chrome",
    ] {
        if Path::new(p).exists() {
            return p.into();
        }
    }
    panic!(
        "no Chromium for the report's browser test: install Debian's `chromium` \
         (.ci/run does) or set VIBROCOMP_CHROMIUM"
    );
}

/// A headless-Chromium screenshot of the page `html` in a 1400 x 2600 window, written
/// to `png` and decoded: its pixels row by row, and the samples per pixel.
pub fn screenshot(html: &Path, png: &Path) -> (Vec<u8>, usize) {
    let profile = png.with_extension("profile");
    let out = Command::new(chromium())
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--window-size=1400,2600")
        .arg(format!("--screenshot={}", png.display()))
        .arg(format!("file://{}", html.display()))
        .output()
        .expect("chromium runs");
    assert!(
        out.status.success() && png.exists(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(png).expect("the screenshot opens"),
    ));
    let mut reader = decoder.read_info().expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("a frame");
    assert_eq!((info.width, info.height), (1400, 2600));
    buf.truncate(info.buffer_size());
    (buf, info.color_type.samples())
}

/// Whether pixel `px` is within 30 of colour `c` in each channel.
pub fn near(px: &[u8], c: [u8; 3]) -> bool {
    (0..3).all(|i| (i32::from(px[i]) - i32::from(c[i])).abs() <= 30)
}

/// What the Python MCAP reader makes of `file`: `script` (Python, `sys.argv[1]` the
/// file) run with `python3 -c`, its standard output read as JSON.
pub fn python_mcap_json(script: &str, file: &Path) -> serde_json::Value {
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(file)
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "the Python mcap reader cannot read {}:\n{}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON")
}
