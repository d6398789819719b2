//! The command line's conventions (docs/view.md's issue: colour, `--json` errors).

use crate::common::bin;
use crate::processes::{free_port, prefix};

/// What `vibrocomp view` (which logs as it starts) writes to a terminal, run under
/// `script` (a real pseudo-terminal), with the environment variable `no_color`.
fn on_a_terminal(no_color: Option<&str>) -> Vec<u8> {
    let exe = env!("CARGO_BIN_EXE_vibrocomp");
    let p = prefix("nc");
    let cmdline = format!(
        "{exe} view --prefix {p} --listen 127.0.0.1:{} --duration-s 0.3",
        free_port()
    );
    let mut c = std::process::Command::new("script");
    c.args(["-qec", &cmdline, "/dev/null"]);
    c.env_remove("NO_COLOR");
    if let Some(v) = no_color {
        c.env("NO_COLOR", v);
    }
    let out = c.output().expect("script (util-linux) runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// Colour only on a terminal and without `NO_COLOR` (https://no-color.org); a file or
/// a pipe gets plain text.
#[test]
fn log_lines_are_coloured_only_on_a_terminal_without_no_color() {
    let esc = |b: &[u8]| b.contains(&0x1b);
    assert!(esc(&on_a_terminal(None)), "a terminal gets colour");
    assert!(!esc(&on_a_terminal(Some("1"))), "NO_COLOR=1 turns it off");
    let out = bin()
        .args([
            "view",
            "--prefix",
            &prefix("np"),
            "--duration-s",
            "0.3",
            "--listen",
        ])
        .arg(format!("127.0.0.1:{}", free_port()))
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(
        !out.stderr.is_empty() && !esc(&out.stderr),
        "a pipe gets none"
    );
}

/// With `--json`, a failure prints a JSON error object on stdout (the whole message
/// and each cause) beside the usual line on stderr, and exits 1.
#[test]
fn a_failure_under_json_is_a_json_error_object() {
    let out = bin()
        .args(["lab", "compare", "/no/such/campaign.csv", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
    let msg = v["error"]["message"].as_str().unwrap();
    assert!(msg.contains("/no/such/campaign.csv"), "{v}");
    assert!(v["error"]["chain"].as_array().unwrap().len() >= 2, "{v}");
    assert_eq!(v["error"]["exit_code"], 1);
    assert!(String::from_utf8_lossy(&out.stderr).starts_with("error: "));
    // Without --json: nothing on stdout.
    let out = bin()
        .args(["lab", "compare", "/no/such/campaign.csv"])
        .output()
        .unwrap();
    assert!(out.stdout.is_empty());
}

/// `-q` and `-v` on every command (global flags): `-q` leaves only errors on stderr,
/// `-v` adds debug lines to the info lines a plain run writes.
#[test]
fn quiet_and_verbose_set_the_log_level() {
    let run = |flag: Option<&str>| {
        let mut c = bin();
        if let Some(f) = flag {
            c.arg(f);
        }
        let out = c
            .args([
                "view",
                "--prefix",
                &prefix("qv"),
                "--duration-s",
                "0.3",
                "--listen",
            ])
            .arg(format!("127.0.0.1:{}", free_port()))
            .env_remove("RUST_LOG")
            .output()
            .unwrap();
        assert!(out.status.success());
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let plain = run(None);
    assert!(plain.contains("INFO"), "{plain}");
    let quiet = run(Some("-q"));
    assert!(quiet.trim().is_empty(), "{quiet}");
    let verbose = run(Some("-v"));
    assert!(verbose.contains("INFO"), "{verbose}");
    assert!(verbose.len() >= plain.len(), "{verbose}");
    // After the subcommand too, and never both.
    let out = bin()
        .args(["view", "-q", "-v", "--duration-s", "0.1"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}
