//! The Python rig client (`examples/python/rig_client.py`, iceoryx2's Python binding)
//! against the real services, each in its own process: `vibrocomp service estimator`
//! and `vibrocomp service compensator` on a prefix of their own, the client streaming
//! its synthetic rig and collecting every compensated block.
//!
//! The outputs are checked against an independent reference computed here:
//! `TriadCompensator` in main-only mode on the readings the client's documented
//! formula gives (bit for bit for `a(1)`, `a(2)`), the wire layouts against
//! `vibro_msgs`, and the loss accounting against the services' own `--json` summaries.
//!
//! Needs `python3` with `iceoryx2==0.10.0`: `pip install -r
//! examples/python/requirements.txt` (CI does). Without it the test fails, it does not
//! skip.

use crate::common::repo_path;
use serde_json::Value;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, StreamConfig, StreamSubscriber};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{
    AccelBlock, CompensatedBlock, FieldLayout, Heartbeat, ServiceId, ServiceNames, Stream,
    TruthBlock, VibBlock, VibEstimate,
};
use vibro_physics::compensation::{Mode, TriadCompensator};

const PIP_HINT: &str = "run `pip install -r examples/python/requirements.txt` (CI does)";
/// Data time the client streams: 100 accelerometer blocks, 200 vibration blocks, the
/// first estimate (1 s window) a quarter of the way in.
const DURATION_S: f64 = 4.0;
/// The client's rates and block sizes (rig_client.py).
const ACCEL_RATE_HZ: u64 = 800;
const ACCEL_PER_BLOCK: u64 = 32;
const VIB_RATE_HZ: u64 = 25_600;
const VIB_PER_BLOCK: u64 = 512;
const TONE_HZ: f64 = 12.0;
const TONE_G: [f64; 3] = [1.2, 0.8, 0.5];

fn next_id() -> u32 {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A temporary directory, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        let d = std::env::temp_dir().join(format!("vct-py-{}-{}", std::process::id(), next_id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("temporary directory");
        Self(d)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A child process whose output goes to files (a full pipe would stall it). Dropping it
/// stops it: SIGTERM, then SIGKILL after 5 s; a killed child's iceoryx2 resources are
/// then released by cleaning up dead nodes.
struct Proc {
    name: String,
    child: Child,
    stdout: PathBuf,
    stderr: PathBuf,
}

impl Proc {
    fn spawn(name: &str, cmd: &mut Command, dir: &TempDir) -> Self {
        let stdout = dir.path(&format!("{name}.stdout"));
        let stderr = dir.path(&format!("{name}.stderr"));
        let child = cmd
            .current_dir(&dir.0)
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&stdout).expect("stdout file"))
            .stderr(std::fs::File::create(&stderr).expect("stderr file"))
            .spawn()
            .unwrap_or_else(|e| panic!("{name}: cannot start {cmd:?}: {e}"));
        Self {
            name: name.to_owned(),
            child,
            stdout,
            stderr,
        }
    }

    fn stdout(&self) -> String {
        std::fs::read_to_string(&self.stdout).unwrap_or_default()
    }

    fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    /// Waits until the process exits, at most `timeout`.
    fn wait(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let start = Instant::now();
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            if start.elapsed() >= timeout {
                return None;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Sends SIGTERM (the services' clean stop) and waits at most `timeout`.
    fn terminate(&mut self, timeout: Duration) -> Option<ExitStatus> {
        if let Ok(Some(status)) = self.child.try_wait() {
            return Some(status);
        }
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        self.wait(timeout)
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if self.terminate(Duration::from_secs(5)).is_some() {
            return;
        }
        eprintln!("{}: still running 5 s after SIGTERM, killing it", self.name);
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Ok(node) = create_node("vct-py-cleanup") {
            vibro_ipc::cleanup_dead_nodes(&node);
        }
    }
}

/// `python3` with iceoryx2 0.10.0, or a failure that says how to install it.
fn check_python() {
    let probe = "import importlib.metadata as m, iceoryx2; print(m.version('iceoryx2'))";
    let out = Command::new("python3")
        .args(["-c", probe])
        .output()
        .unwrap_or_else(|e| panic!("cannot run python3 ({e}): install Python 3 and {PIP_HINT}"));
    let version = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    assert!(
        out.status.success(),
        "python3 cannot import iceoryx2: {PIP_HINT}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        version, "0.10.0",
        "python3 has iceoryx2 {version}, the services use 0.10.0: {PIP_HINT}"
    );
}

fn client_script() -> PathBuf {
    repo_path("examples/python/rig_client.py")
}

/// The client's ctypes layouts (`--print-layout`) equal the Rust wire types field by
/// field, so iceoryx2 accepts them as the same types and the bytes mean the same.
fn check_layouts() {
    let out = Command::new("python3")
        .arg(client_script())
        .arg("--print-layout")
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "rig_client.py --print-layout failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let layouts: Value = serde_json::from_slice(&out.stdout).expect("layout JSON");
    let rust: [(&str, &str, usize, usize, &[FieldLayout]); 6] = [
        (
            "AccelBlock",
            AccelBlock::TYPE_NAME,
            size_of::<AccelBlock>(),
            align_of::<AccelBlock>(),
            AccelBlock::FIELDS,
        ),
        (
            "VibBlock",
            VibBlock::TYPE_NAME,
            size_of::<VibBlock>(),
            align_of::<VibBlock>(),
            VibBlock::FIELDS,
        ),
        (
            "VibEstimate",
            VibEstimate::TYPE_NAME,
            size_of::<VibEstimate>(),
            align_of::<VibEstimate>(),
            VibEstimate::FIELDS,
        ),
        (
            "CompensatedBlock",
            CompensatedBlock::TYPE_NAME,
            size_of::<CompensatedBlock>(),
            align_of::<CompensatedBlock>(),
            CompensatedBlock::FIELDS,
        ),
        (
            "Heartbeat",
            Heartbeat::TYPE_NAME,
            size_of::<Heartbeat>(),
            align_of::<Heartbeat>(),
            Heartbeat::FIELDS,
        ),
        (
            "TruthBlock",
            TruthBlock::TYPE_NAME,
            size_of::<TruthBlock>(),
            align_of::<TruthBlock>(),
            TruthBlock::FIELDS,
        ),
    ];
    for (name, type_name, size, align, fields) in rust {
        let py = &layouts[name];
        assert_eq!(
            py["type_name"].as_str(),
            Some(type_name),
            "rig_client.py's {name} type name (update its SCHEMA_VERSION)"
        );
        assert_eq!(py["size"].as_u64(), Some(size as u64), "{name} size");
        assert_eq!(
            py["alignment"].as_u64(),
            Some(align as u64),
            "{name} alignment"
        );
        let py_fields: Vec<(String, u64, u64)> = py["fields"]
            .as_array()
            .unwrap_or_else(|| panic!("{name}: no fields in {py}"))
            .iter()
            .map(|f| (f[0].as_str().unwrap_or("?").to_owned(), u(&f[1]), u(&f[2])))
            .collect();
        let rust_fields: Vec<(String, u64, u64)> = fields
            .iter()
            .map(|f| {
                (
                    f.name.to_owned(),
                    f.offset_bytes as u64,
                    f.size_bytes as u64,
                )
            })
            .collect();
        assert_eq!(
            py_fields, rust_fields,
            "{name}: (field, offset, size) differ"
        );
    }
}

fn u(v: &Value) -> u64 {
    v.as_u64()
        .unwrap_or_else(|| panic!("{v} is not an unsigned integer"))
}

/// Waits until each service published a heartbeat on `prefix`.
fn wait_for_heartbeats(prefix: &str, procs: &mut [&mut Proc]) {
    let names = ServiceNames::new(prefix).expect("prefix");
    let node = create_node("vct-py-test").expect("node");
    let subscribers: Vec<_> = [ServiceId::Estimator, ServiceId::Compensator]
        .into_iter()
        .map(|s| {
            let stream = Stream::Heartbeat(s);
            StreamSubscriber::<Heartbeat>::create(
                &node,
                &names.stream(stream),
                &names.event(stream),
                &StreamConfig::default(),
            )
            .expect("heartbeat subscriber")
        })
        .collect();
    let mut up = [false; 2];
    let start = Instant::now();
    while up != [true; 2] {
        for (k, s) in subscribers.iter().enumerate() {
            while s.receive().expect("heartbeat").is_some() {
                up[k] = true;
            }
        }
        for p in procs.iter_mut() {
            if let Ok(Some(status)) = p.child.try_wait() {
                panic!("{} exited at start ({status}):\n{}", p.name, p.stderr());
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no heartbeat within 30 s (estimator {}, compensator {})",
            up[0],
            up[1]
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Stops a service with SIGTERM and returns its `--json` summary.
fn stop(mut p: Proc) -> Value {
    let status = p.terminate(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| s.success()),
        "{}: exit {status:?} after SIGTERM:\n{}",
        p.name,
        p.stderr()
    );
    let stdout = p.stdout();
    let line = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(line)
        .unwrap_or_else(|e| panic!("{}: summary is not JSON ({e}): {stdout}", p.name))
}

/// A reference block as the probe saw it: first sample index, count, flags, `a_l_ia_g`
/// rows, and whether the sensed and VE fields were all NaN.
type ReferenceSeen = (u64, u32, u32, Vec<[f64; 3]>, bool);

/// The client's accelerometer formula (rig_client.py `accel_g`), operation for
/// operation, so the readings are the same doubles.
fn accel_g(n: u64, unit: u64) -> f64 {
    1.0 + 1e-4 * ((n * (unit + 1)) % 1000) as f64
}

/// `round(index * 1e9 / rate)`, half away from zero (the Packetizer's rounding).
fn time_ns(index: u64, rate_hz: u64) -> u64 {
    (2 * index * 1_000_000_000 + rate_hz) / (2 * rate_hz)
}

/// `rows[sample][unit]` of a block's bit-pattern array, as doubles.
fn stage(block: &Value, name: &str) -> Vec<[f64; 3]> {
    block["bits"][name]
        .as_array()
        .unwrap_or_else(|| panic!("no bits.{name} in block {}", block["seq"]))
        .iter()
        .map(|row| [0, 1, 2].map(|i| f64::from_bits(u(&row[i]))))
        .collect()
}

fn same_bits(a: &[[f64; 3]], b: &[[f64; 3]]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| (0..3).all(|i| x[i].to_bits() == y[i].to_bits()))
}

#[test]
fn python_rig_client_round_trips_through_both_services() {
    check_python();
    check_layouts();

    let dir = TempDir::new();
    let prefix = format!("vct-py-{}-{}/", std::process::id(), next_id());
    let config = dir.path("compensator.toml");
    // Exact mode on the shipped triad; no hot reload; fast heartbeats for the start-up.
    // The estimate stage: the reference below is the paper's kernel (the waveform
    // stage on a rig client's streams: tests/integration/rig_generator.rs).
    std::fs::write(
        &config,
        "prefix = \"unused/\"\nmode = \"exact\"\ntriad = \"default\"\n\
         max_estimate_age_s = 2.0\nreload_poll_s = 0.0\nstage = \"estimate\"\n\n[service]\n\
         loop_mode = \"event\"\nheartbeat_period_s = 0.1\nsummary_period_s = 10.0\n\
         shutdown_poll_s = 0.02\n",
    )
    .expect("compensator config");
    let bin = env!("CARGO_BIN_EXE_vibrocomp");
    let mut estimator = Proc::spawn(
        "estimator",
        Command::new(bin).args(["service", "estimator", "--prefix", &prefix, "--json"]),
        &dir,
    );
    let mut compensator = Proc::spawn(
        "compensator",
        Command::new(bin)
            .args([
                "service",
                "compensator",
                "--prefix",
                &prefix,
                "--json",
                "--config",
            ])
            .arg(&config),
        &dir,
    );
    wait_for_heartbeats(&prefix, &mut [&mut estimator, &mut compensator]);

    // The client's reference channel (`{prefix}truth`), drained as it comes: a rig's
    // reference, flagged SENSED_UNKNOWN, each unit's `a_l_ia_g` the client's formula.
    let stop_probe = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let reference = {
        let (prefix, stop) = (prefix.clone(), stop_probe.clone());
        let (opened, is_open) = std::sync::mpsc::channel();
        let probe = std::thread::spawn(move || -> Vec<ReferenceSeen> {
            let node = create_node(&format!("vct-py-ref-{}", next_id())).expect("probe node");
            let names = ServiceNames::new(&prefix).expect("names");
            let sub = StreamSubscriber::<TruthBlock>::open(&node, &names, Stream::Truth)
                .expect("the reference stream");
            let _ = opened.send(());
            let mut got = Vec::new();
            loop {
                let stopping = stop.load(Ordering::SeqCst);
                while let Ok(Some(m)) = sub.receive() {
                    let b: &TruthBlock = &m;
                    let n = (b.count as usize).min(b.a_l_ia_g.len());
                    let unknown = b.a_sensed_ia_g[..n]
                        .iter()
                        .chain(&b.vib_error_ia_g[..n])
                        .flatten()
                        .all(|x| x.is_nan());
                    got.push((
                        b.first_sample_index,
                        b.count,
                        b.flags,
                        b.a_l_ia_g[..n].to_vec(),
                        unknown,
                    ));
                }
                if stopping {
                    return got;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
        });
        // Subscribed before the client publishes its first block.
        is_open
            .recv_timeout(Duration::from_secs(30))
            .expect("the reference probe subscribed");
        probe
    };

    let results_path = dir.path("results.json");
    let started = Instant::now();
    let mut client = Proc::spawn(
        "rig_client",
        Command::new("python3")
            .arg(client_script())
            .args(["--prefix", &prefix, "--duration-s", &DURATION_S.to_string()])
            .args(["--timeout-s", "20", "--out"])
            .arg(&results_path),
        &dir,
    );
    // Behind on purpose: once the client is well under way, the compensator is stopped
    // for 0.5 s (SIGSTOP, SIGCONT) while the client and the estimator go on, so that
    // accelerometer blocks queue up while newer estimates could be published. Each block
    // must still use the latest estimate sent before it (`check_results`): the client
    // waits for its outputs before it sends the vibration that completes an estimate.
    // Without that wait a compensator that was behind took the newer estimate.
    {
        let node = create_node(&format!("vct-py-probe-{}", next_id())).expect("probe node");
        let names = ServiceNames::new(&prefix).expect("names");
        let out = StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated)
            .expect("the compensated stream");
        let mut seen = 0;
        let t = Instant::now();
        while seen < 40 && t.elapsed() < Duration::from_secs(60) {
            while let Ok(Some(_)) = out.receive() {
                seen += 1;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(seen >= 40, "only {seen} compensated blocks within 60 s");
        let pid = compensator.child.id().to_string();
        let signal = |sig: &str| {
            let ok = Command::new("kill")
                .args([sig, &pid])
                .status()
                .is_ok_and(|s| s.success());
            assert!(ok, "kill {sig} {pid}");
        };
        signal("-STOP");
        std::thread::sleep(Duration::from_millis(500));
        signal("-CONT");
    }
    let status = client.wait(Duration::from_secs(180));
    let client_s = started.elapsed().as_secs_f64();
    assert!(
        status.is_some_and(|s| s.success()),
        "rig_client.py: {} after {client_s:.1} s:\n{}\n--- estimator:\n{}\n--- compensator:\n{}",
        status.map_or_else(|| "no exit within 180 s".to_owned(), |s| s.to_string()),
        client.stderr(),
        estimator.stderr(),
        compensator.stderr()
    );
    stop_probe.store(true, Ordering::SeqCst);
    let reference = reference.join().expect("the reference probe");
    let estimator_summary = stop(estimator);
    let compensator_summary = stop(compensator);
    // Every reference block arrived, with the client's accelerations.
    let mut samples = 0u64;
    for (first, count, flags, a_l, unknown) in &reference {
        assert_eq!(
            *flags,
            vibro_msgs::truth_flags::SENSED_UNKNOWN,
            "block at {first}"
        );
        assert!(*unknown, "block at {first}: sensed or VE not NaN");
        assert_eq!(a_l.len(), *count as usize);
        for (k, row) in a_l.iter().enumerate() {
            for u in 0..3u64 {
                assert_eq!(
                    row[u as usize].to_bits(),
                    accel_g(first + k as u64, u).to_bits(),
                    "reference of sample {} unit {u}",
                    first + k as u64
                );
            }
        }
        samples += u64::from(*count);
    }
    let accel_samples = (DURATION_S * ACCEL_RATE_HZ as f64).round() as u64;
    assert_eq!(samples, accel_samples, "reference samples received");
    let results: Value = serde_json::from_str(
        &std::fs::read_to_string(&results_path).expect("results.json written"),
    )
    .expect("results.json is JSON");

    check_results(&results);
    check_summaries(&results, &estimator_summary, &compensator_summary);

    let blocks = results["blocks"].as_array().map_or(0, Vec::len);
    let mut latency_ns: Vec<u64> = results["blocks"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|b| u(&b["service_latency_ns"]))
        .collect();
    latency_ns.sort_unstable();
    eprintln!(
        "python rig client: sent {} vib + {} accel blocks, {blocks} compensated back, \
         {} estimates; streaming {:.3} s ({client_s:.2} s with the client's start-up); compensator \
         receive -> publish p50 {:.0} us, max {:.0} us",
        u(&results["sent"]["vib_blocks"]),
        u(&results["sent"]["accel_blocks"]),
        results["estimates"].as_array().map_or(0, Vec::len),
        results["wall_s"].as_f64().unwrap_or(f64::NAN),
        latency_ns.get(latency_ns.len() / 2).copied().unwrap_or(0) as f64 / 1e3,
        latency_ns.last().copied().unwrap_or(0) as f64 / 1e3,
    );
}

/// The compensated blocks against the in-process reference and the stream's rules.
fn check_results(results: &Value) {
    let accel_samples = (DURATION_S * ACCEL_RATE_HZ as f64).round() as u64;
    let accel_blocks = accel_samples.div_ceil(ACCEL_PER_BLOCK);
    let vib_samples = (DURATION_S * VIB_RATE_HZ as f64).round() as u64;
    assert_eq!(u(&results["sent"]["accel_samples"]), accel_samples);
    assert_eq!(u(&results["sent"]["accel_blocks"]), accel_blocks);
    assert_eq!(u(&results["sent"]["vib_samples"]), vib_samples);
    assert_eq!(
        u(&results["sent"]["vib_blocks"]),
        vib_samples.div_ceil(VIB_PER_BLOCK)
    );
    let blocks = results["blocks"].as_array().expect("blocks");
    let estimates = results["estimates"].as_array().expect("estimates");
    assert_eq!(
        blocks.len() as u64,
        accel_blocks,
        "every block comes back once"
    );
    assert!(!estimates.is_empty(), "the estimator published no estimate");

    // The reference: the shipped triad, exact mode, no vibration (main error only), fed
    // sample after sample as the service does (Newton tracks the previous sample).
    let triad = vibro_config::default_triad().expect("default triad");
    let k1 = triad.passports.map(|p| p.k1_v_per_g);
    let mut reference = TriadCompensator::new(triad.axes, triad.passports, Mode::Exact);
    let period_ns = time_ns(1, ACCEL_RATE_HZ);

    let mut first_estimated = None;
    let mut last_estimate_seq = 0;
    for (b, block) in blocks.iter().enumerate() {
        let b = b as u64;
        let first = b * ACCEL_PER_BLOCK;
        let count = ACCEL_PER_BLOCK.min(accel_samples - first);
        assert_eq!(u(&block["seq"]), b, "output seq");
        assert_eq!(
            u(&block["input_seq"]),
            b,
            "blocks come back in order, once each"
        );
        assert_eq!(u(&block["first_sample_index"]), first, "block {b}");
        assert_eq!(
            u(&block["t0_ns"]),
            time_ns(first + 1, ACCEL_RATE_HZ),
            "block {b}"
        );
        assert_eq!(u(&block["count"]), count, "block {b}");
        assert_eq!(u(&block["mode"]), 3, "block {b}: mode exact");

        let flags = u(&block["flags"]) as u32;
        let a = ["a1_g", "a2_g", "a3_g", "a4_g"].map(|s| stage(block, s));
        assert!(
            a.iter().all(|s| s.len() as u64 == count),
            "block {b}: {count} rows"
        );
        let missing = block["expected_estimate_seq"].is_null();
        if missing {
            // No estimate was published before this block was sent.
            assert!(
                first_estimated.is_none(),
                "block {b}: estimate missing again"
            );
            assert_eq!(
                flags,
                cf::ESTIMATE_MISSING | cf::MAIN_ONLY,
                "block {b} flags"
            );
            assert_eq!(u(&block["estimate_seq"]), 0, "block {b}");
            assert!(
                same_bits(&a[2], &a[1]),
                "block {b}: a3 == a2 without an estimate"
            );
            assert!(
                same_bits(&a[3], &a[1]),
                "block {b}: a4 == a2 without an estimate"
            );
        } else {
            first_estimated.get_or_insert(b);
            // The latest estimate published before the block was sent, never stale.
            let seq = u(&block["estimate_seq"]);
            assert_eq!(
                Some(seq),
                block["expected_estimate_seq"].as_u64(),
                "block {b}: the estimate used is the latest one sent before it"
            );
            assert!(
                seq >= last_estimate_seq,
                "block {b}: estimate seq went back"
            );
            last_estimate_seq = seq;
            let bad = cf::ESTIMATE_MISSING
                | cf::MAIN_ONLY
                | cf::VIBRATION_ESTIMATE_STALE
                | cf::INPUT_GAP
                | cf::NON_FINITE_INPUT;
            assert_eq!(flags & bad, 0, "block {b} flags {flags:#x}");
            // Its age: end of the block's last interval minus the estimate's end.
            let estimate = estimates
                .iter()
                .find(|e| u(&e["seq"]) == seq)
                .unwrap_or_else(|| panic!("block {b}: estimate {seq} never seen by the client"));
            let end_ns = time_ns(first + 1, ACCEL_RATE_HZ) + (count - 1) * period_ns;
            assert_eq!(
                block["estimate_age_ns"].as_i64(),
                Some(end_ns as i64 - u(&estimate["end_ns"]) as i64),
                "block {b}: estimate age"
            );
            // The vibration correction is applied: finite, not nothing, and small.
            let det_g: Vec<f64> = (0..count as usize)
                .flat_map(|k| (0..3).map(move |i| (k, i)))
                .map(|(k, i)| a[1][k][i] - a[2][k][i])
                .collect();
            assert!(
                a[2..].iter().flatten().flatten().all(|x| x.is_finite()),
                "block {b}: a3, a4 finite"
            );
            let largest = det_g.iter().fold(0.0f64, |m, d| m.max(d.abs()));
            assert!(
                largest > 1e-7 && largest < 1e-2,
                "block {b}: |a2 - a3| up to {largest:e} g"
            );
        }

        // a(1), a(2) bit for bit against the reference, sample after sample, with an
        // estimate too: a(2) is the vibration-free stage, whose Newton iteration runs
        // apart from those of (19), (20) and starts from the last sample's a(2).
        for (k, n) in (first..first + count).enumerate() {
            let u_v = [0, 1, 2].map(|unit| accel_g(n, unit) * k1[unit as usize]);
            let readings_g = [0, 1, 2].map(|i| u_v[i] / k1[i]);
            let want = reference.compensate(readings_g);
            for (i, s) in want.units.iter().enumerate() {
                assert_eq!(
                    (a[0][k][i].to_bits(), a[1][k][i].to_bits()),
                    (s.a1_g.to_bits(), s.a2_g.to_bits()),
                    "block {b} sample {k} unit {i}: (a1, a2) = ({}, {}) g, reference ({}, {}) g",
                    a[0][k][i],
                    a[1][k][i],
                    s.a1_g,
                    s.a2_g
                );
            }
        }
    }
    let first_estimated = first_estimated.expect("no block was compensated with an estimate");
    assert!(
        first_estimated > 0,
        "the first block already had an estimate: the client did not start cold"
    );

    // The estimator found the client's tone, and only it, on every axis. It undoes the
    // sensors' first-order AC coupling (corner f_c), which the synthetic stream does not
    // have, so it reports the sent amplitude times 1/|H(f)| = sqrt(1 + (f_c / f)^2).
    let f_c_hz = shipped_ac_corner_hz();
    let gain = (1.0 + (f_c_hz / TONE_HZ).powi(2)).sqrt();
    for e in estimates {
        let freqs = e["tone_frequency_hz"].as_array().expect("tones");
        assert_eq!(freqs.len(), 1, "estimate {}: tones {freqs:?}", e["seq"]);
        let f_hz = freqs[0].as_f64().unwrap_or(f64::NAN);
        assert!(
            (f_hz - TONE_HZ).abs() < 1e-6,
            "estimate {}: tone at {f_hz} Hz",
            e["seq"]
        );
        for (axis, sent_g) in TONE_G.iter().enumerate() {
            let got = e["tone_amplitude_g"][0][axis].as_f64().unwrap_or(f64::NAN);
            let want = sent_g * gain;
            assert!(
                (got / want - 1.0).abs() < 1e-6,
                "estimate {} axis {axis}: tone amplitude {got} g, want {want} g ({sent_g} g sent)",
                e["seq"]
            );
        }
    }
}

/// `[estimator] ac_corner_hz` of the shipped estimator configuration, which the service
/// runs with when given no `--config`.
fn shipped_ac_corner_hz() -> f64 {
    let path = repo_path("config/services/estimator.toml");
    let text = std::fs::read_to_string(&path).expect("shipped estimator config");
    let config: toml::Value = toml::from_str(&text).expect("estimator config is TOML");
    config["estimator"]["ac_corner_hz"]
        .as_float()
        .unwrap_or_else(|| panic!("{}: no [estimator] ac_corner_hz", path.display()))
}

/// The services' own accounting: nothing lost, nothing undelivered, and the same counts
/// as the client's.
fn check_summaries(results: &Value, estimator: &Value, compensator: &Value) {
    let vib_blocks = u(&results["sent"]["vib_blocks"]);
    let accel_blocks = u(&results["sent"]["accel_blocks"]);
    let estimates = results["estimates"].as_array().map_or(0, Vec::len) as u64;
    let zero = |summary: &Value, path: &[&str]| {
        let v = path.iter().fold(summary, |v, k| &v[*k]);
        assert_eq!(
            v.as_u64(),
            Some(0),
            "{}: {path:?} = {v}",
            summary["service"]
        );
    };
    assert_eq!(u(&estimator["vib"]["received"]), vib_blocks, "{estimator}");
    for key in [
        "lost_messages",
        "lost_samples",
        "out_of_order",
        "restarts",
        "index_backwards",
        "malformed",
    ] {
        zero(estimator, &["vib", key]);
        zero(compensator, &["accel", key]);
    }
    for key in [
        "undelivered",
        "publish_errors",
        "receive_errors",
        "rate_mismatches",
    ] {
        zero(estimator, &[key]);
    }
    assert_eq!(
        u(&estimator["estimates_published"]),
        estimates,
        "{estimator}"
    );

    assert_eq!(
        u(&compensator["accel"]["received"]),
        accel_blocks,
        "{compensator}"
    );
    assert_eq!(u(&compensator["published"]), accel_blocks, "{compensator}");
    for key in [
        "undelivered",
        "publish_errors",
        "receive_errors",
        "input_gap_blocks",
        "stale_blocks",
        "estimates_rejected",
        "non_finite_samples",
    ] {
        zero(compensator, &[key]);
    }
    let missing = results["blocks"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|b| u(&b["flags"]) as u32 & cf::ESTIMATE_MISSING != 0)
        .count() as u64;
    assert_eq!(u(&compensator["missing_blocks"]), missing, "{compensator}");
    assert_eq!(
        u(&compensator["estimates"]["received"]),
        estimates,
        "{compensator}"
    );
}
