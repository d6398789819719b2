//! Issue 46, item 7 and two of item 8, through the `vibrocomp` binary:
//!
//! - every configuration type refuses a string or a list over its bound before
//!   anything starts, naming the file, the key, an excerpt of the value and the bound
//!   (one table: [`every_configuration_refuses_a_string_or_a_list_over_its_bound`]);
//!   among them the bridge's `key_prefix` of 1 MB in 10 000 chunks, which the bridge
//!   accepted and then took 5.1 GB and overflowed a thread's stack with;
//! - a configuration file bigger than 1 MiB is refused by its size, unread;
//! - a TOML error on a 200 KB line quotes a line's worth of it, marked cut;
//! - a bridge socket named without a folder goes in this user's own folder, and a
//!   folder another user planted there is refused, naming it and its owner.
//!
//! `VIBROCOMP_BIN` runs the tables against another build of the binary (the one before
//! the change, to see them fail).

use crate::common::repo_path;
use crate::processes::{prefix, Dir};
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The binary under test: `VIBROCOMP_BIN`, else this build's.
fn binary() -> Command {
    match std::env::var_os("VIBROCOMP_BIN") {
        Some(b) => Command::new(b),
        None => crate::common::bin(),
    }
}

/// What a run of the binary left: its exit, stderr, wall time and peak RSS.
struct Ran {
    code: Option<i32>,
    signal: Option<i32>,
    stderr: String,
    elapsed: Duration,
    max_rss_kb: i64,
    /// This test process's own peak RSS when it started the command: the child is
    /// started by `posix_spawn`, sharing the parent's memory until it execs, and the
    /// kernel counts that memory's peak in the child's `ru_maxrss` too; a child's own
    /// peak is only seen above this.
    parent_max_rss_kb: i64,
}

impl Ran {
    /// Whether the command's peak RSS stayed below `kb` of its own (module doc of
    /// [`Ran::parent_max_rss_kb`]).
    fn peak_below(&self, kb: i64) -> bool {
        self.max_rss_kb < kb.max(self.parent_max_rss_kb + 20_000)
    }
}

/// Runs `vibrocomp ARGS` in `dir` (stdout and stderr to files, so that a huge message
/// cannot block it), killing it after `limit`: a configuration that is not refused at
/// once starts the command, which then runs until the limit.
fn run(dir: &Dir, args: &[String], env: &[(&str, Option<&Path>)], limit: Duration) -> Ran {
    let out = std::fs::File::create(dir.path("stdout.txt")).unwrap();
    let err = std::fs::File::create(dir.path("stderr.txt")).unwrap();
    let mut cmd = binary();
    cmd.args(args)
        .current_dir(dir.path(""))
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(err);
    for (k, v) in env {
        match v {
            Some(v) => cmd.env(k, v),
            None => cmd.env_remove(k),
        };
    }
    // SAFETY: a zeroed rusage is a valid value for getrusage to fill.
    let mut own: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: our own usage, with a valid pointer.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut own) };
    let started = Instant::now();
    let child = cmd.spawn().unwrap();
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value for wait4 to fill.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let mut killed = false;
    loop {
        // SAFETY: waits for our own child, with valid pointers.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        assert!(r == 0, "wait4: {}", std::io::Error::last_os_error());
        if !killed && started.elapsed() > limit {
            // SAFETY: signals our own child.
            unsafe { libc::kill(pid, libc::SIGKILL) };
            killed = true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let elapsed = started.elapsed();
    drop(child);
    let status = std::process::ExitStatus::from_raw(status);
    Ran {
        code: status.code(),
        signal: status.signal(),
        stderr: std::fs::read_to_string(dir.path("stderr.txt")).unwrap_or_default(),
        elapsed,
        max_rss_kb: usage.ru_maxrss,
        parent_max_rss_kb: own.ru_maxrss,
    }
}

/// The arguments that make the binary read a configuration file, given its path.
type Args = fn(&str) -> Vec<String>;

/// One configuration type: how the binary is asked to read the file, and what it must
/// say when the file breaks a bound.
struct Case {
    what: &'static str,
    /// The file's name in the case's folder, and its text.
    file: &'static str,
    text: String,
    /// Other files the command reads, in the same folder.
    others: Vec<(&'static str, String)>,
    /// The arguments, the file's path given.
    args: Args,
    /// What the message holds besides the file's name.
    wanted: Vec<String>,
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

fn shipped(rel: &str) -> String {
    std::fs::read_to_string(repo_path(rel)).unwrap()
}

/// `text` with `from` (which it must hold) replaced by `to`.
fn edit(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "{from:?} not in:\n{text}");
    text.replacen(from, to, 1)
}

/// A TOML array of `n` copies of `item`.
fn array(n: usize, item: &str) -> String {
    format!("[{}]", vec![item; n].join(", "))
}

/// The bridge's `key_prefix` of issue 46: 1 MB in 10 000 chunks.
fn megabyte_key_prefix() -> String {
    let chunks: Vec<String> = (0..10_000)
        .map(|i| "a".repeat(if i == 0 { 100 } else { 99 }))
        .collect();
    chunks.join("/")
}

/// A bridge listening on a Unix socket in the case's folder (valid but for `edit`s).
fn bridge_text(p: &str) -> String {
    format!(
        "prefix = \"{p}\"\nkey_prefix = \"vibrocomp/bounds\"\n[zenoh]\nmode = \"peer\"\n\
         listen = [\"unixsock-stream/b.sock\"]\nconnect_timeout_s = 2.0\n[export]\n\
         streams = [\"vib\", \"accel\"]\n[import]\nstreams = [\"estimate\"]\n"
    )
}

fn cases() -> Vec<Case> {
    let p = prefix("bnd");
    let estimator = edit(
        &shipped("config/services/estimator.toml"),
        "prefix = \"vibrocomp/\"",
        &format!("prefix = \"{p}\""),
    );
    let compensator = edit(
        &shipped("config/services/compensator.toml"),
        "prefix = \"vibrocomp/\"",
        &format!("prefix = \"{p}\""),
    );
    let response_point =
        "{ frequency_hz = 1.0, gain = [1.0, 1.0, 1.0], phase_rad = [0.0, 0.0, 0.0] }";
    let passport = shipped("config/accelerometers/al-15.toml");
    let lambda = "[[lambda]]\nfreq_hz = 10.0\nlambda = 1.0\n";
    let scenario = shipped("config/scenarios/cyclone-4-short.toml");
    let profile = "[[flight.profile]]\nt_s = 0.0\naccel_body_g = [1.0, 0.0, 0.0]\n";
    let rig = "format = \"vibrocomp-rig/1\"\n[sensors]\nsensitivity_v_per_g = 0.1\n\
               [reference]\nkind = \"static\"\n";
    let segment = "[[reference.segment]]\nfrom_s = 0.0\nto_s = 1.0\nup = \"+z\"\n";
    let run = "[[run]]\nid = \"r\"\naccel = \"a.csv\"\nreference = \"r.csv\"\nup = \"+z\"\n";
    let manifest = "format = \"vibrocomp-campaign/1\"\n[segments]\nstill_before_s = [0.0, 8.0]\n\
                    vibrating_s = [8.2, 15.9]\nstill_after_s = [16.1, 24.0]\n";
    let bridge_args: Args = |f| strings(&["bridge", "--config", f]);
    let estimator_args: Args = |f| strings(&["service", "estimator", "--config", f]);
    let compensator_args: Args = |f| strings(&["service", "compensator", "--config", f]);
    let passport_args: Args = |f| {
        strings(&[
            "model",
            "ve",
            "--passport",
            f,
            "--aL3-g",
            "1",
            "--aB3-g",
            "0.1",
        ])
    };
    let sim_args: Args = |f| strings(&["sim", f, "--out", "flight.mcap"]);
    let rig_args: Args = |f| {
        strings(&[
            "log", "import", "--rig", f, "--accel", "a.csv", "--out", "x.mcap",
        ])
    };
    let model_args: Args = |f| {
        let table = repo_path("shared/vibro-lab/tests/data/walkthrough-14-rows.csv");
        strings(&["lab", "compare", "--model", f, table.to_str().unwrap()])
    };
    let manifest_args: Args = |f| strings(&["identify", "campaign", f]);
    vec![
        Case {
            what: "bridge: the key_prefix of issue 46 (1 MB in 10 000 chunks)",
            file: "bridge.toml",
            // The socket by its absolute path: a build before the default folder took
            // this file, and ran.
            text: edit(
                &edit(&bridge_text(&p), "vibrocomp/bounds", &megabyte_key_prefix()),
                "unixsock-stream/b.sock",
                "unixsock-stream/@DIR@/z/b.sock",
            ),
            others: vec![],
            args: bridge_args,
            wanted: strings(&[
                "key_prefix = \"aaaa",
                "(1000000 bytes): at most 256 bytes",
                "(10000 '/'-separated chunks): at most 16 chunks",
            ]),
        },
        Case {
            what: "bridge: a list of endpoints",
            file: "bridge.toml",
            text: edit(
                &bridge_text(&p),
                "listen = [\"unixsock-stream/b.sock\"]",
                &format!("listen = {}", array(100, "\"unixsock-stream/b.sock\"")),
            ),
            others: vec![],
            args: bridge_args,
            wanted: strings(&["zenoh.listen: 100 entries: at most 64"]),
        },
        Case {
            what: "estimator: its prefix",
            file: "estimator.toml",
            text: edit(&estimator, &p, &format!("{}/", "p".repeat(100_000))),
            others: vec![],
            args: estimator_args,
            wanted: strings(&["prefix = \"pppp", "more bytes cut)\": 100001 bytes long"]),
        },
        Case {
            what: "estimator: its frequency-response table",
            file: "estimator.toml",
            text: edit(
                &estimator,
                "[estimator]\n",
                &format!("[estimator]\nresponse = {}\n", array(2000, response_point)),
            ),
            others: vec![],
            args: estimator_args,
            wanted: strings(&["estimator.response: 2000 points, at most 1024 are allowed"]),
        },
        Case {
            what: "compensator: its mode",
            file: "compensator.toml",
            text: edit(
                &compensator,
                "mode = \"exact\"",
                &format!("mode = \"{}\"", "e".repeat(100_000)),
            ),
            others: vec![],
            args: compensator_args,
            wanted: strings(&["mode = \"eeee", "(100000 bytes): at most 64 bytes"]),
        },
        Case {
            what: "compensator: its passports",
            file: "compensator.toml",
            text: edit(
                &compensator,
                "triad = \"default\"",
                &format!(
                    "triad = \"default\"\npassports = {}",
                    array(1000, "\"AL-15\"")
                ),
            ),
            others: vec![],
            args: compensator_args,
            wanted: strings(&["passports: 1000 entries, a triad has exactly 3 units"]),
        },
        Case {
            what: "triad (named by a compensator's configuration): a unit's name",
            file: "compensator.toml",
            text: edit(
                &compensator,
                "triad = \"default\"",
                "triad = \"triad.toml\"",
            ),
            others: vec![(
                "triad.toml",
                edit(
                    &shipped("config/triads/default.toml"),
                    "name = \"AK1\"",
                    &format!("name = \"{}\"", "n".repeat(100_000)),
                ),
            )],
            args: compensator_args,
            wanted: strings(&["unit[0].name = \"nnnn", "(100000 bytes): at most 128 bytes"]),
        },
        Case {
            what: "passport: its id",
            file: "passport.toml",
            text: edit(
                &passport,
                "id = \"AL-15\"",
                &format!("id = \"{}\"", "i".repeat(100_000)),
            ),
            others: vec![],
            args: passport_args,
            wanted: strings(&["id = \"iiii", "(100000 bytes): at most 32 bytes"]),
        },
        Case {
            what: "passport: its lambda table",
            file: "passport.toml",
            text: format!("{passport}\n{}", lambda.repeat(10_000)),
            others: vec![],
            args: passport_args,
            wanted: strings(&["lambda: 10000 entries: at most 32"]),
        },
        Case {
            what: "scenario: its name",
            file: "scenario.toml",
            text: edit(
                &scenario,
                "name = \"cyclone-4-short\"",
                &format!("name = \"{}\"", "n".repeat(100_000)),
            ),
            others: vec![],
            args: sim_args,
            wanted: strings(&["name = \"nnnn", "(100000 bytes): at most 128 bytes"]),
        },
        Case {
            what: "scenario: its flight profile",
            file: "scenario.toml",
            text: format!("{scenario}\n{}", profile.repeat(10_001)),
            others: vec![],
            args: sim_args,
            wanted: strings(&["flight.profile: 100", "entries: at most 10000"]),
        },
        Case {
            what: "rig: its format",
            file: "rig.toml",
            text: edit(
                rig,
                "vibrocomp-rig/1",
                &format!("vibrocomp-rig/1{}", "f".repeat(100_000)),
            ),
            others: vec![],
            args: rig_args,
            wanted: strings(&[
                "format = \"vibrocomp-rig/1ffff",
                "(100015 bytes): at most 64 bytes",
            ]),
        },
        Case {
            what: "rig: its static orientations",
            file: "rig.toml",
            text: format!("{rig}{}", segment.repeat(5000)),
            others: vec![],
            args: rig_args,
            wanted: strings(&["reference.segment: 5000 entries: at most 4096"]),
        },
        Case {
            what: "lab model: its mode",
            file: "model.toml",
            text: format!("mode = \"{}\"\n", "m".repeat(100_000)),
            others: vec![],
            args: model_args,
            wanted: strings(&["mode = \"mmmm", "(100000 bytes): at most 64 bytes"]),
        },
        Case {
            what: "lab model: its effects",
            file: "model.toml",
            text: "[[effect]]\nkind = \"anisoelastic\"\nk_ae_per_g = 1e-5\n".repeat(100),
            others: vec![],
            args: model_args,
            wanted: strings(&["effect: 100 entries: at most 64"]),
        },
        Case {
            what: "campaign manifest: a run's id",
            file: "manifest.toml",
            text: format!(
                "{manifest}{}",
                edit(
                    run,
                    "id = \"r\"",
                    &format!("id = \"{}\"", "r".repeat(100_000))
                )
            ),
            others: vec![],
            args: manifest_args,
            wanted: strings(&["run[0].id = \"rrrr", "(100000 bytes): at most 128 bytes"]),
        },
        Case {
            what: "campaign manifest: its unit columns",
            file: "manifest.toml",
            text: edit(
                &format!("{manifest}{run}"),
                "[segments]",
                &format!("unit_columns = {}\n[segments]", array(4, "\"u\"")),
            ),
            others: vec![],
            args: manifest_args,
            wanted: strings(&["unit_columns: 4 entries: at most 3"]),
        },
    ]
}

/// Issue 46, item 7: each configuration type, given a string or a list over its bound,
/// is refused at once (within 10 s, far less in practice), before anything starts,
/// with the file, the key, an excerpt of the value and the bound, in a message of at
/// most a few lines. Before, the bridge accepted the megabyte `key_prefix` and ran
/// (3.6 GB after 6 s; SIGINT then overflowed its export thread's stack), and every
/// other one either ran or quoted the value whole.
#[test]
fn every_configuration_refuses_a_string_or_a_list_over_its_bound() {
    let mut failures = Vec::new();
    for case in cases() {
        let dir = Dir::new("bounds");
        let path = dir.path(case.file);
        let folder = dir.path("");
        let folder = folder.to_str().unwrap().trim_end_matches('/');
        std::fs::write(&path, case.text.replace("@DIR@", folder)).unwrap();
        for (name, text) in &case.others {
            std::fs::write(dir.path(name), text).unwrap();
        }
        // The bridge's socket folder: this case's own.
        let own = dir.path("");
        let env = [("XDG_RUNTIME_DIR", None), ("TMPDIR", Some(own.as_path()))];
        let args = (case.args)(path.to_str().unwrap());
        let ran = run(&dir, &args, &env, Duration::from_secs(10));
        let mut missing: Vec<String> = case
            .wanted
            .iter()
            .filter(|w| !ran.stderr.contains(w.as_str()))
            .cloned()
            .collect();
        if !ran.stderr.contains(&path.display().to_string()) {
            missing.push(format!("the file's name {}", path.display()));
        }
        let refused = ran.code == Some(1) && ran.signal.is_none();
        let short = ran.stderr.len() < 2048;
        eprintln!(
            "{}: exit {:?} in {:.3} s, peak RSS {} MB, {} bytes of stderr",
            case.what,
            ran.code,
            ran.elapsed.as_secs_f64(),
            ran.max_rss_kb / 1024,
            ran.stderr.len()
        );
        if !(refused && short && missing.is_empty()) {
            failures.push(format!(
                "{}: exit {:?} (signal {:?}) after {:.2} s, peak RSS {} MB, {} bytes of stderr; missing {missing:?}; stderr starts:\n{}",
                case.what,
                ran.code,
                ran.signal,
                ran.elapsed.as_secs_f64(),
                ran.max_rss_kb / 1024,
                ran.stderr.len(),
                ran.stderr.chars().take(600).collect::<String>()
            ));
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n\n"));
}

/// A configuration file of 2 GiB (sparse: no disk) is refused by its size, unread, in
/// each reader: the services', the bridge's, the scenario's, the passport's, the lab
/// model's and the rig's.
#[test]
fn a_configuration_file_over_a_mebibyte_is_refused_unread() {
    let mut failures = Vec::new();
    let all: [(&str, Args); 6] = [
        ("estimator", |f| {
            strings(&["service", "estimator", "--config", f])
        }),
        ("bridge", |f| strings(&["bridge", "--config", f])),
        ("scenario", |f| strings(&["sim", f, "--out", "flight.mcap"])),
        ("passport", |f| {
            strings(&[
                "model",
                "ve",
                "--passport",
                f,
                "--aL3-g",
                "1",
                "--aB3-g",
                "0.1",
            ])
        }),
        ("lab model", |f| {
            let table = repo_path("shared/vibro-lab/tests/data/walkthrough-14-rows.csv");
            strings(&["lab", "compare", "--model", f, table.to_str().unwrap()])
        }),
        ("rig", |f| {
            strings(&[
                "log", "import", "--rig", f, "--accel", "a.csv", "--out", "x.mcap",
            ])
        }),
    ];
    for (what, args) in all {
        let dir = Dir::new("bigcfg");
        let path = dir.path("big.toml");
        std::fs::File::create(&path)
            .unwrap()
            .set_len(2 << 30)
            .unwrap();
        let ran = run(
            &dir,
            &args(path.to_str().unwrap()),
            &[],
            Duration::from_secs(20),
        );
        let wanted = "2147483648 bytes: a configuration file holds at most 1048576 bytes (1 MiB)";
        if !(ran.code == Some(1) && ran.stderr.contains(wanted) && ran.peak_below(200_000)) {
            failures.push(format!(
                "{what}: exit {:?} after {:.2} s, peak RSS {} MB; stderr starts:\n{}",
                ran.code,
                ran.elapsed.as_secs_f64(),
                ran.max_rss_kb / 1024,
                ran.stderr.chars().take(400).collect::<String>()
            ));
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n\n"));
}

/// Issue 46, item 8: a TOML error on a line of 200 KB (`a=[[[[…`) quoted the whole
/// line (200 KB of stderr); it quotes a line's worth, says it cut, and still points at
/// the line and the column.
#[test]
fn a_toml_error_on_a_huge_line_quotes_a_lines_worth() {
    let dir = Dir::new("nested");
    let path = dir.path("nested.toml");
    std::fs::write(&path, format!("a={}\n", "[".repeat(200_000))).unwrap();
    let args = strings(&["service", "estimator", "--config", path.to_str().unwrap()]);
    let ran = run(&dir, &args, &[], Duration::from_secs(20));
    assert_eq!(ran.code, Some(1), "{}", ran.stderr);
    assert!(
        ran.stderr.len() < 1024,
        "{} bytes of stderr",
        ran.stderr.len()
    );
    for wanted in [
        &format!("{}: TOML parse error at line 1, column ", path.display()),
        "= line 1 cut: 200002 characters long, 120 shown",
    ] {
        assert!(
            ran.stderr.contains(wanted),
            "{wanted:?} missing:\n{}",
            ran.stderr
        );
    }
    // With --json: the line and the column as numbers, the message as short.
    let mut args = args;
    args.push("--json".into());
    let ran = run(&dir, &args, &[], Duration::from_secs(20));
    let v: serde_json::Value = serde_json::from_str(ran.stderr.trim())
        .or_else(|_| {
            let out = std::fs::read_to_string(dir.path("stdout.txt")).unwrap();
            serde_json::from_str(out.trim())
        })
        .unwrap_or_else(|e| panic!("no JSON error ({e}):\n{}", ran.stderr));
    assert_eq!(v["error"]["line"], 1, "{v}");
    assert!(v["error"]["column"].as_u64().is_some_and(|c| c > 2), "{v}");
    assert!(v.to_string().len() < 2048, "{v}");
}

/// Issue 46, item 8: the bridges' socket folder was `/tmp/vibrocomp-bridge` for every
/// user, and the first user to create it locked out every other. A socket named
/// alone (the shipped configurations) now goes in this user's own folder; a folder
/// planted there by another user (uid 65534, as root) is refused, naming the folder
/// and its owner; and the default is not the shared folder.
#[test]
fn a_socket_folder_planted_by_another_user_is_refused_and_the_default_is_this_users() {
    let dir = Dir::new("planted");
    let tmp = dir.path("tmp");
    std::fs::create_dir(&tmp).unwrap();
    // SAFETY: geteuid has no preconditions.
    let uid = unsafe { libc::geteuid() };
    let ours = tmp.join(format!("vibrocomp-bridge-{uid}"));
    assert_ne!(ours, Path::new("/tmp/vibrocomp-bridge"));
    let config = dir.path("bridge.toml");
    std::fs::write(&config, bridge_text(&prefix("pl"))).unwrap();
    let env = [("XDG_RUNTIME_DIR", None), ("TMPDIR", Some(tmp.as_path()))];
    let args = strings(&["bridge", "--config", config.to_str().unwrap()]);
    if uid != 0 {
        eprintln!(
            "*** SKIPPED the planted folder of a_socket_folder_planted_by_another_user_is_refused: not root, cannot give a folder away ***"
        );
        return;
    }
    use std::os::unix::fs::PermissionsExt;
    std::fs::create_dir(&ours).unwrap();
    std::fs::set_permissions(&ours, std::fs::Permissions::from_mode(0o700)).unwrap();
    std::os::unix::fs::chown(&ours, Some(65534), Some(65534)).unwrap();
    let ran = run(&dir, &args, &env, Duration::from_secs(10));
    assert_eq!(ran.code, Some(1), "{}", ran.stderr);
    for wanted in [
        format!("the directory {} belongs to uid 65534", ours.display()),
        format!("it must belong to this process's user (uid {uid})"),
        "zenoh.listen[0]".to_string(),
    ] {
        assert!(
            ran.stderr.contains(&wanted),
            "{wanted:?} missing:\n{}",
            ran.stderr
        );
    }
    // The shipped configurations name their socket alone: the same folder.
    for shipped in [
        "config/bridge/compute-host.toml",
        "config/bridge/rig-host.toml",
    ] {
        let text = shipped_text_with_prefix(shipped, &prefix("pl"));
        let file = dir.path("shipped.toml");
        std::fs::write(&file, text).unwrap();
        let args = strings(&["bridge", "--config", file.to_str().unwrap()]);
        let ran = run(&dir, &args, &env, Duration::from_secs(10));
        let wanted = format!("the directory {} belongs to uid 65534", ours.display());
        assert!(
            ran.code == Some(1) && ran.stderr.contains(&wanted),
            "{shipped}: {wanted:?} missing:\n{}",
            ran.stderr
        );
    }
}

/// A shipped file with its iceoryx2 prefix replaced (a test's own).
fn shipped_text_with_prefix(rel: &str, p: &str) -> String {
    edit(
        &shipped(rel),
        "prefix = \"vibrocomp/\"",
        &format!("prefix = \"{p}\""),
    )
}
