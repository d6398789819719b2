//! The Python package's build (bindings/python/Cargo.toml).
//!
//! - A user's wheel (`pip install .`) links only what the package calls: no iceoryx2
//!   (the package neither publishes nor subscribes, docs/python.md), no service runtime
//!   (clap, tracing-subscriber, tokio's scheduler) and no live view's server (the
//!   Foxglove SDK's WebSocket server).
//! - CI's wheel (.ci/wheel.py: the test profile, the feature `test-build`) reuses the
//!   libraries `cargo test --workspace` compiled only when cargo resolves the same
//!   features for them in both builds. A feature that only the tests' build turns on (a
//!   dev-dependency's, another member's) makes the wheel compile that library and
//!   everything above it again: minutes on CI's 2 cores.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

/// `cargo tree` of `selection` as package -> features (`name vX.Y.Z` -> set).
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

#[test]
fn wheel_shares_the_test_build() {
    let wheel = features(
        &["-p", "vibrocomp-python", "--features", "test-build"],
        "normal,build",
    );
    let tests = features(&["--workspace"], "normal,build,dev");
    assert!(
        wheel.len() > 100,
        "cargo tree listed {} libraries",
        wheel.len()
    );
    let drift: Vec<String> = wheel
        .iter()
        .filter_map(|(lib, f)| {
            let t = tests
                .get(lib)
                .filter(|_| !lib.starts_with("vibrocomp-python "))?;
            (t != f).then(|| {
                format!(
                    "{lib}: the tests' build adds {:?}, the wheel's adds {:?}",
                    t.difference(f).collect::<Vec<_>>(),
                    f.difference(t).collect::<Vec<_>>()
                )
            })
        })
        .collect();
    assert!(
        drift.is_empty(),
        "the wheel's build resolves other features than `cargo test --workspace`: ask for \
         the same in bindings/python/Cargo.toml (its feature `test-build`), or CI compiles these \
         again for the wheel:\n{}",
        drift.join("\n")
    );
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
    // And the feature CI builds with does bring each of them in (the check can fail).
    let ci = features(
        &["-p", "vibrocomp-python", "--features", "test-build"],
        "normal",
    );
    let in_ci = service_only(&ci);
    for lib in SERVICE_ONLY {
        assert!(
            in_ci.iter().any(|l| l.starts_with(lib)),
            "{lib} not in CI's build: {in_ci:?}"
        );
    }
    assert!(in_ci.iter().any(|l| l.starts_with("tokio ")), "{in_ci:?}");
}
