//! The Python package's build (bindings/python/Cargo.toml).
//!
//! - A user's wheel (`pip install .`) links only what the package calls: no iceoryx2
//!   (the package neither publishes nor subscribes, docs/python.md), no service runtime
//!   (clap, tracing-subscriber, tokio's scheduler) and no live view's server (the
//!   Foxglove SDK's WebSocket server).
//! - CI's wheel (.ci/wheel.py) is built within the test build, so it links what the
//!   workspace links: the check below sees each of those libraries there.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

/// `cargo tree` of `selection` as package -> features (`name vX.Y.Z` -> the features
/// of all its builds).
fn features(selection: &[&str], edges: &str) -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out = Command::new(cargo)
        .current_dir(&root)
        .args(["tree", "--locked", "--offline", "--prefix", "none"])
        .args(["-f", "{p}|{f}", "-e", edges])
        .args(selection)
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree {selection:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut map: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let Some((package, feats)) = line.split_once('|') else {
            continue;
        };
        // `name vX.Y.Z (path or registry)`: the name and version name the library.
        let key = package
            .split_whitespace()
            .take(2)
            .collect::<Vec<_>>()
            .join(" ");
        let feats = feats
            .trim_end_matches(" (*)")
            .trim_end_matches(" (proc-macro)");
        map.entry(key)
            .or_default()
            .extend(feats.split(',').filter(|f| !f.is_empty()).map(String::from));
    }
    map
}

/// Libraries of a running service or of the live view, which the package never calls.
const SERVICE_ONLY: [&str; 6] = [
    "iceoryx2",
    "clap ",
    "tracing-subscriber ",
    "foxglove ",
    "tungstenite ",
    "mio ",
];

/// The service-only libraries `wheel` links, and tokio's features beyond the
/// shutdown token's `sync`.
fn service_only(wheel: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let mut found: Vec<String> = wheel
        .keys()
        .filter(|l| SERVICE_ONLY.iter().any(|s| l.starts_with(s)))
        .cloned()
        .collect();
    for (lib, f) in wheel.iter().filter(|(l, _)| l.starts_with("tokio ")) {
        let runtime: Vec<&String> = f
            .iter()
            .filter(|f| !["default", "sync"].contains(&f.as_str()))
            .collect();
        if !runtime.is_empty() {
            found.push(format!("{lib} with {runtime:?}"));
        }
    }
    found
}

#[test]
fn a_users_wheel_links_only_what_the_package_calls() {
    let wheel = features(&["-p", "vibrocomp-python"], "normal");
    assert!(
        wheel.len() > 100,
        "cargo tree listed {} libraries",
        wheel.len()
    );
    let extra = service_only(&wheel);
    assert!(
        extra.is_empty(),
        "the Python package's own build links {extra:?}: a library it depends on asks for \
         the feature `ipc` of a vibro crate, or `live` of vibro-view \
         (bindings/python/Cargo.toml)"
    );
    // And the workspace's build (CI's wheel is built within it) does bring each of
    // them in: the check can fail.
    let ci = features(&["--workspace"], "normal");
    let in_ci = service_only(&ci);
    for lib in SERVICE_ONLY {
        assert!(
            in_ci.iter().any(|l| l.starts_with(lib)),
            "{lib} not in CI's build: {in_ci:?}"
        );
    }
    assert!(in_ci.iter().any(|l| l.starts_with("tokio ")), "{in_ci:?}");
}
