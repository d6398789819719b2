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

/// The 1-based line of the first line of `text` that starts with `start`.
fn line_of(text: &str, start: &str) -> usize {
    text.lines()
        .position(|l| l.starts_with(start))
        .unwrap_or_else(|| panic!("{start:?} not in the text"))
        + 1
}

/// A scenario file with three unknown keys: all three are reported at once, each with
/// its table path, line and the key it is a near miss of; with `--json`, the error
/// object carries the file and the first one's line and key.
#[test]
fn a_config_file_reports_every_unknown_key_with_its_line() {
    let dir = crate::processes::Dir::new("conv-unknown");
    let text = std::fs::read_to_string(crate::common::repo_path(
        "config/scenarios/cyclone-4-short.toml",
    ))
    .unwrap()
    .replace("seed = 4\n", "seed = 4\nsede = 5\n")
    .replace("output_hz = 800\n", "output_hz = 800\noutput_hzz = 1\n")
    .replace("adc_bits = 24\n", "adc_bits = 24\nadc_bit = 2\n");
    let file = dir.path("scenario.toml");
    std::fs::write(&file, &text).unwrap();
    let f = file.to_str().unwrap();
    let out = bin().args(["sim", f, "--json"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    for (key, path, suggestion) in [
        ("sede =", "sede", "seed"),
        ("output_hzz =", "rates.output_hzz", "output_hz"),
        ("adc_bit =", "sensor.adc_bit", "adc_bits"),
    ] {
        let want = format!(
            "line {}, column 1: {path}: unknown key (did you mean {suggestion}?)",
            line_of(&text, key)
        );
        assert!(stderr.contains(&want), "missing {want:?} in:\n{stderr}");
    }
    assert!(stderr.contains("3 unknown keys"), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
    let e = &v["error"];
    assert_eq!(e["file"], f, "{v}");
    assert_eq!(e["line"], line_of(&text, "sede ="), "{v}");
    assert_eq!(e["key"], "sede", "{v}");
}

/// A TOML syntax error keeps toml's snippet: the offending line and a caret under it
/// (not a flattened one-liner); `--json` gives its file, line and (for a value the
/// type refuses) key.
#[test]
fn a_config_syntax_error_shows_the_line_and_a_caret() {
    let dir = crate::processes::Dir::new("conv-syntax");
    let text =
        std::fs::read_to_string(crate::common::repo_path("config/accelerometers/al-15.toml"))
            .unwrap();
    let broken = text.replace("k2_ppm_per_g = 105.0", "k2_ppm_per_g = = 105.0");
    let file = dir.path("broken.toml");
    std::fs::write(&file, &broken).unwrap();
    let f = file.to_str().unwrap();
    let out = bin()
        .args(["model", "ve", "--passport", f, "--aL3-g", "1", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    let n = line_of(&broken, "k2_ppm_per_g");
    let shown = format!("{n} | k2_ppm_per_g = = 105.0");
    let caret = format!("{} |{}^", " ".repeat(n.to_string().len()), " ".repeat(16));
    assert!(
        stderr.contains(&shown) && stderr.contains(&caret),
        "no snippet {shown:?} / {caret:?} in:\n{stderr}"
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["file"], f, "{v}");
    assert_eq!(v["error"]["line"], n, "{v}");

    // A value of the wrong type: the key too.
    let typed = text.replace("k2_ppm_per_g = 105.0", "k2_ppm_per_g = \"high\"");
    std::fs::write(&file, &typed).unwrap();
    let out = bin()
        .args(["model", "ve", "--passport", f, "--aL3-g", "1", "--json"])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["key"], "k2_ppm_per_g", "{v}");
    assert_eq!(v["error"]["line"], line_of(&typed, "k2_ppm_per_g"), "{v}");
}

/// Issue 47, item 5: a model file's problem found after parsing (an effect's unknown
/// parameter, a value against its rule) gives `--json` the file, the first problem's
/// key (`effect[1].foo`) and its line, as a parse error does.
#[test]
fn a_model_files_effect_problem_has_its_key_and_line() {
    let dir = crate::processes::Dir::new("conv-effect");
    let text = "mode = \"exact\"\n\n[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 1e-5\n\n\
                [[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 100.0\nq = 5.0\nfoo = 1\n";
    let file = dir.path("model.toml");
    std::fs::write(&file, text).unwrap();
    let f = file.to_str().unwrap();
    let table = crate::common::repo_path("shared/vibro-lab/tests/data/walkthrough-14-rows.csv");
    let out = bin()
        .args([
            "lab",
            "compare",
            "--model",
            f,
            table.to_str().unwrap(),
            "--json",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
    let e = &v["error"];
    assert_eq!(e["file"], f, "{v}");
    assert_eq!(e["key"], "effect[1].foo", "{v}");
    assert_eq!(e["line"], line_of(text, "foo ="), "{v}");
    assert!(
        e["message"].as_str().unwrap().contains("unknown parameter"),
        "{v}"
    );
}

/// A log that cannot be read gives `--json` its file, as a configuration does: missing,
/// not an MCAP log, cut short (before: only the message named it).
#[test]
fn a_logs_json_error_names_the_file() {
    let dir = crate::processes::Dir::new("conv-logfile");
    let missing = dir.path("missing.mcap");
    let text = dir.path("text.mcap");
    std::fs::write(&text, "not a log\n").unwrap();
    let cut = dir.path("cut.mcap");
    // MCAP's magic and the start of a header record, then nothing.
    std::fs::write(&cut, b"\x89MCAP0\r\n\x01\x10\x00\x00").unwrap();
    for (args, file) in [
        (vec!["log", "info"], &missing),
        (vec!["log", "errors"], &missing),
        (vec!["log", "errors"], &text),
        (vec!["log", "errors"], &cut),
        (vec!["lab", "diagnose"], &text),
    ] {
        let f = file.to_str().unwrap();
        let out = bin().args(&args).args([f, "--json"]).output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?} {f}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
        assert_eq!(v["error"]["file"], f, "{args:?}: {v}");
    }
}

/// An error about no file (a flag's value) has no `file`, `line` or `key` in its JSON
/// error object: they are absent, not null.
#[test]
fn a_json_error_without_a_file_has_no_location_fields() {
    let out = bin()
        .args(["sim", "cyclone-4-short", "--duration-s=-1", "--json"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let e = v["error"].as_object().unwrap();
    assert!(
        e["message"].as_str().unwrap().contains("--duration-s"),
        "{v}"
    );
    for field in ["file", "line", "key"] {
        assert!(!e.contains_key(field), "{field} in {v}");
    }
}

/// Issue 31, item 7: `view --listen 127.0.0.1:0` reports the port the system gave it,
/// in its log line and its `--json` summary (before: port 0 in both).
#[test]
fn view_on_port_zero_reports_the_port_it_got() {
    let out = bin()
        .args([
            "view",
            "--prefix",
            &prefix("pz"),
            "--duration-s",
            "0.3",
            "--listen",
            "127.0.0.1:0",
            "--json",
        ])
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)));
    let listen: std::net::SocketAddr = v["listen"].as_str().unwrap().parse().unwrap();
    assert_ne!(listen.port(), 0, "{v}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("ws://{listen}")), "{err}");
}
