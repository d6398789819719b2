//! The independent rig generator (`tests/python/rig_generator.py`: an AL-15 triad on a
//! shaker, written from MODEL.md and RIG.md alone, not from vibrocomp's simulator) is
//! itself checked against closed forms before any test trusts its data: its own
//! pytest suite (still readings against the conversion function, tone and random VE
//! against MODEL.md sections 5-6, Welch RMS, the resonance's gain, the sensors' AC
//! coupling, repeat draws) runs here so that CI runs it.

use crate::common::TempDir;
use std::path::Path;
use std::process::Command;

#[test]
fn the_independent_rig_generator_agrees_with_the_closed_forms() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    // pytest's temporary folders in one of this test's own, removed after it (by
    // default pytest keeps its last three runs' under /tmp/pytest-of-USER).
    let scratch = TempDir::new("rig-generator", "pytest");
    let out = Command::new("python3")
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .arg(format!("--basetemp={}", scratch.0.join("t").display()))
        .arg(root.join("tests/python/test_rig_generator.py"))
        .current_dir(&root)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    assert!(
        out.status.success(),
        "the rig generator's checks failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
