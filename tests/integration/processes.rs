//! Helpers of the tests that run the system as processes (`replay`, `faults`):
//! unique service prefixes, scratch folders, simulated flight logs, a process's
//! children.

use crate::common::bin;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};

static NEXT: AtomicU32 = AtomicU32::new(0);

fn next() -> u32 {
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A unique, short service prefix per test (tests run in parallel): `vct-{tag}-{pid}-{n}/`.
pub fn prefix(tag: &str) -> String {
    format!("vct-{tag}-{}-{}/", std::process::id(), next())
}

/// A scratch folder, removed when dropped.
pub struct Dir(PathBuf);

impl Dir {
    pub fn new(tag: &str) -> Self {
        let d =
            std::env::temp_dir().join(format!("vibrocomp-{tag}-{}-{}", std::process::id(), next()));
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Dir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A short simulated flight log (the demo's scenario, `seconds` long): 50 vibration
/// blocks (512 samples at 25.6 kHz) and 25 accelerometer blocks (32 samples at 800 Hz)
/// per second of data.
pub fn flight_log(dir: &Dir, seconds: &str) -> PathBuf {
    let out = dir.path("flight.mcap");
    let status = bin()
        .args(["sim", "cyclone-4-short", "--duration-s", seconds, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    out
}

/// The children of a process, with their command lines (from /proc).
pub fn children(pid: u32) -> Vec<(u32, String)> {
    let mut out = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return out;
    };
    for t in tasks.flatten() {
        let list = std::fs::read_to_string(t.path().join("children")).unwrap_or_default();
        for c in list
            .split_whitespace()
            .filter_map(|s| s.parse::<u32>().ok())
        {
            let cmd = std::fs::read(format!("/proc/{c}/cmdline")).unwrap_or_default();
            let cmd = String::from_utf8_lossy(&cmd).replace('\0', " ");
            out.push((c, cmd));
        }
    }
    out
}
