//! The Zenoh bridge (`vibrocomp bridge`, shared/vibro-bridge, docs/bridge.md).
//!
//! - its configuration refused with file, line, key and every problem at once;
//! - a peer that cannot be reached at start: a clear error naming the endpoint;
//! - a message lost and one reordered on the network, put into Zenoh by this test as a
//!   remote bridge would: the receiving bridge's counters and the compensator's own
//!   counters and flags against what the test left out and swapped;
//! - the Python `eclipse-zenoh` client decoding the bridged compensated stream by
//!   docs/messages.md, against the blocks read from iceoryx2 here;
//! - two hosts on one machine (two iceoryx2 roots joined only by Zenoh over loopback):
//!   `demo --hosts 2` against `demo`, bit for bit, and the order across streams it
//!   rests on (a sensor block never overtaken by a later accelerometer block);
//!
//! - who may connect: a process of another user (uid 65534, when the tests run as
//!   root) cannot reach a bridge on one host (a Unix socket in a directory of this
//!   user's alone), and a socket directory others may enter stops the bridge at start;
//! - `seq` jumps from a crafted peer counted as jumps, never as losses.
//!
//! Every test uses its own service-name prefix, its own Unix socket (or free port on
//! 127.0.0.1) in temporary folders it removes (kept, and named on stderr, when a test
//! fails with `VCB_KEEP` set); the processes stop when their handles drop.

use crate::common::{bin, repo_path, run_failing};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, StreamPublisher, StreamSubscriber};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{
    AccelBlock, CompensatedBlock, ServiceId, ServiceNames, Stream, VibBlock, WireMessage,
};
use vibro_system::hosts::free_port;
use zenoh::Wait;

fn next_id() -> u32 {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A short prefix of this test's own.
fn prefix(what: &str) -> String {
    format!("vcb{what}-{}-{}/", std::process::id(), next_id())
}

/// A temporary folder, removed on drop.
struct Dir(PathBuf);

impl Dir {
    fn new(what: &str) -> Self {
        let d =
            std::env::temp_dir().join(format!("vcb-{what}-{}-{}", std::process::id(), next_id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Dir {
    fn drop(&mut self) {
        if std::thread::panicking() && std::env::var_os("VCB_KEEP").is_some() {
            eprintln!("kept {}", self.0.display());
            return;
        }
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A child process, stderr to a file, stopped with SIGTERM (then SIGKILL) on drop.
struct Kid {
    name: &'static str,
    child: Option<Child>,
    stderr: PathBuf,
}

impl Kid {
    fn spawn(name: &'static str, cmd: &mut Command, dir: &Dir) -> Self {
        let stderr = dir.path(&format!("{name}.stderr"));
        let child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        Self {
            name,
            child: Some(child),
            stderr,
        }
    }

    fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    /// SIGTERM, then the JSON summary it printed (it must exit 0).
    fn summary(mut self) -> Value {
        let mut child = self.child.take().unwrap();
        let _ = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status();
        let start = Instant::now();
        while child.try_wait().unwrap().is_none() {
            if start.elapsed() > Duration::from_secs(10) {
                let _ = child.kill();
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let out = child.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "{} exited with {:?}:\n{}",
            self.name,
            out.status,
            self.stderr()
        );
        let text = String::from_utf8_lossy(&out.stdout);
        let start = text
            .find('{')
            .unwrap_or_else(|| panic!("{}: no JSON in {text:?}", self.name));
        serde_json::from_str(&text[start..]).unwrap()
    }
}

impl Drop for Kid {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = Command::new("kill")
                .args(["-TERM", &c.id().to_string()])
                .status();
            let start = Instant::now();
            while start.elapsed() < Duration::from_secs(5) {
                if let Ok(Some(_)) = c.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn write(path: &Path, text: &str) -> PathBuf {
    std::fs::write(path, text).unwrap();
    path.to_path_buf()
}

/// A bridge configuration in `dir` on `prefix`, listening on a Unix socket in `dir`
/// (its directory `zenoh/`, made mode 0700 by the bridge) under a fresh key prefix
/// named after `what`, with the `streams` section given (e.g.
/// `[import]\nstreams = ["accel"]\n`): the file, the endpoint and the key prefix.
fn listening_config(
    dir: &Dir,
    prefix: &str,
    what: &str,
    streams: &str,
) -> (PathBuf, String, String) {
    let endpoint = format!("unixsock-stream/{}", dir.path("zenoh/b.sock").display());
    let key_prefix = format!("vibrocomp/{what}{}", next_id());
    let config = write(
        &dir.path("b.toml"),
        &format!(
            "prefix = {prefix:?}\nkey_prefix = {key_prefix:?}\n[zenoh]\nmode = \"peer\"\nlisten = [{endpoint:?}]\nconnect_timeout_s = 5.0\n{streams}"
        ),
    );
    (config, endpoint, key_prefix)
}

/// The compensator as a process on `prefix` (the shipped configuration).
fn compensator(prefix: &str, dir: &Dir) -> Kid {
    Kid::spawn(
        "compensator",
        bin().args([
            "service",
            "compensator",
            "--prefix",
            prefix,
            "--config",
            repo_path("config/services/compensator.toml")
                .to_str()
                .unwrap(),
            "--json",
        ]),
        dir,
    )
}

fn bridge(config: &Path, dir: &Dir) -> Kid {
    Kid::spawn(
        "bridge",
        bin().args(["bridge", "--config", config.to_str().unwrap(), "--json"]),
        dir,
    )
}

/// Waits until `ok()` or fails after `timeout`, saying what was awaited.
fn wait_until(what: &str, timeout: Duration, mut ok: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ok() {
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Accelerometer block `seq` of a steady 800 Hz stream (sample values vary per block).
fn accel_block(seq: u64) -> AccelBlock {
    const PERIOD_NS: u64 = 1_250_000;
    let mut b = AccelBlock::ZEROED;
    b.seq = seq;
    b.first_sample_index = seq * 32;
    b.t0_ns = (seq * 32 + 1) * PERIOD_NS;
    b.sample_period_ns = PERIOD_NS;
    b.count = 32;
    b.source_id = 7;
    for (i, s) in b.output_v.iter_mut().enumerate() {
        let x = (seq * 32 + i as u64) as f64 * 1e-4;
        *s = [-1.67 + x, -0.02 - x, 0.01 + 0.5 * x];
    }
    b
}

#[test]
fn bridge_config_errors_name_file_line_key_and_every_problem() {
    let dir = Dir::new("cfg");
    let unknown = write(
        &dir.path("unknown.toml"),
        "key_prefix = \"vibrocomp/a\"\n[zenoh]\nmode = \"peer\"\nlisten = [\"tcp/127.0.0.1:7447\"]\nconnect_timeout_s = 1.0\nconect = []\n[export]\nstreams = [\"vib\"]\n",
    );
    let out = run_failing(&["bridge", "--config", unknown.to_str().unwrap(), "--json"]);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let e = &v["error"];
    assert_eq!(e["file"], unknown.to_str().unwrap(), "{v}");
    assert_eq!(e["line"], 6, "{v}");
    assert!(
        e["message"]
            .as_str()
            .unwrap()
            .contains("conect: unknown key (did you mean connect?)"),
        "{v}"
    );

    let bad = write(
        &dir.path("bad.toml"),
        "key_prefix = \"vibrocomp/**\"\n[zenoh]\nmode = \"router\"\nlisten = [\"tcp/0.0.0.0:7447\"]\nconnect = [\"tcp/127.0.0.1:7447\"]\nconnect_timeout_s = 0.0\n[export]\nstreams = [\"vibe\"]\n[import]\nqueue_depth = 0\n",
    );
    let out = run_failing(&["bridge", "--config", bad.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stderr);
    for needle in [
        "key_prefix = \"vibrocomp/**\"",
        "zenoh.mode = \"router\": must be peer or client",
        "zenoh.listen[0] = \"tcp/0.0.0.0:7447\": plain TCP proves nobody's identity",
        "zenoh.listen[0] = \"tcp/0.0.0.0:7447\": listens beyond loopback, so it needs [tls] with mutual = true and [access] allow_cert_common_names",
        "zenoh.connect[0] = \"tcp/127.0.0.1:7447\": plain TCP proves nobody's identity, on loopback too",
        "zenoh.connect_timeout_s = 0: must be finite",
        "export.streams: \"vibe\" is not a stream",
        "import.queue_depth = 0",
    ] {
        assert!(text.contains(needle), "missing {needle:?} in:\n{text}");
    }
    assert!(text.contains(bad.to_str().unwrap()), "{text}");
}

#[test]
fn the_shipped_two_host_configurations_are_valid_and_match() {
    let rig = vibro_bridge::BridgeConfig::load(&repo_path("config/bridge/rig-host.toml")).unwrap();
    let compute =
        vibro_bridge::BridgeConfig::load(&repo_path("config/bridge/compute-host.toml")).unwrap();
    assert_eq!(rig.key_prefix, compute.key_prefix);
    // What one sends, the other receives, and nothing goes both ways.
    let mut a = rig.export.clone();
    let mut b = compute.import.clone();
    a.sort_by_key(|s| s.suffix());
    b.sort_by_key(|s| s.suffix());
    assert_eq!(a, b);
    let mut a = rig.import.clone();
    let mut b = compute.export.clone();
    a.sort_by_key(|s| s.suffix());
    b.sort_by_key(|s| s.suffix());
    assert_eq!(a, b);
}

#[test]
fn an_unreachable_peer_fails_at_start_naming_the_endpoint() {
    let dir = Dir::new("unreach");
    let endpoint = format!("unixsock-stream/{}", dir.path("zenoh/b.sock").display());
    let config = write(
        &dir.path("b.toml"),
        &format!(
            "prefix = {:?}\nkey_prefix = \"vibrocomp/unreach\"\n[zenoh]\nmode = \"peer\"\nconnect = [{endpoint:?}]\nconnect_timeout_s = 0.5\n[export]\nstreams = [\"compensated\"]\n",
            prefix("u")
        ),
    );
    let start = Instant::now();
    let out = run_failing(&["bridge", "--config", config.to_str().unwrap(), "--json"]);
    let text = String::from_utf8_lossy(&out.stderr);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["file"], config.to_str().unwrap(), "{v}");
    assert!(text.contains(&format!("connect [{endpoint}]")), "{text}");
    assert!(text.contains("connect_timeout_s = 0.5"), "{text}");
    assert!(
        start.elapsed() < Duration::from_secs(8),
        "{:?}",
        start.elapsed()
    );
}

/// A Zenoh peer connected to the bridge listening on `endpoint`, with a publisher of
/// accelerometer blocks on `{key_prefix}/accel` that the bridge has matched: what a
/// remote bridge would be.
fn remote_accel_publisher(
    endpoint: &str,
    key_prefix: &str,
) -> (zenoh::Session, zenoh::pubsub::Publisher<'static>) {
    let session = remote_session(endpoint);
    let publisher = matched_publisher(
        &session,
        format!("{key_prefix}/accel"),
        vibro_msgs::MessageKind::AccelBlock,
    );
    (session, publisher)
}

/// A publisher of `kind` on `key` in `session`, once the bridge's subscriber matched it.
fn matched_publisher(
    session: &zenoh::Session,
    key: String,
    kind: vibro_msgs::MessageKind,
) -> zenoh::pubsub::Publisher<'static> {
    let publisher = session
        .declare_publisher(key)
        .encoding(vibro_bridge::encoding_of(kind))
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .wait()
        .unwrap();
    wait_until(
        "the bridge's Zenoh subscriber",
        Duration::from_secs(10),
        || publisher.matching_status().wait().unwrap().matching(),
    );
    publisher
}

/// This test stands for a remote bridge: it puts accelerometer blocks 0..=9 into Zenoh
/// without block 5 and with block 4 after block 6. The receiving bridge counts the gap
/// and the late block; the compensator behind it counts and flags them exactly as it
/// does a local loss (docs/services.md, loss accounting).
#[test]
fn a_message_lost_or_reordered_on_the_network_is_counted_and_flagged() {
    let dir = Dir::new("loss");
    let prefix = prefix("l");
    let (config, endpoint, key_prefix) =
        listening_config(&dir, &prefix, "loss", "[import]\nstreams = [\"accel\"]\n");
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-loss").unwrap();
    let out =
        StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated).unwrap();
    let comp = compensator(&prefix, &dir);
    let br = bridge(&config, &dir);
    // The bridge's iceoryx2 publisher and the compensator's subscriber meet.
    let probe = StreamSubscriber::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        Stream::Heartbeat(ServiceId::Compensator),
    )
    .unwrap();
    wait_until(
        "the compensator's heartbeat",
        Duration::from_secs(20),
        || probe.receive().unwrap().is_some(),
    );

    let (session, publisher) = remote_accel_publisher(&endpoint, &key_prefix);
    let order = [0u64, 1, 2, 3, 6, 4, 7, 8, 9];
    for seq in order {
        publisher.put(accel_block(seq).bytes()).wait().unwrap();
    }
    // Blocks 0..=3, 6..=9 compensated; 4 (late) refused, 5 never sent.
    let mut got = Vec::new();
    wait_until("8 compensated blocks", Duration::from_secs(10), || {
        while let Some(b) = out.receive().unwrap() {
            got.push(*b);
        }
        got.len() >= 8
    });
    drop(publisher);
    session.close().wait().unwrap();
    let b = br.summary();
    let c = comp.summary();
    let inputs: Vec<u64> = got.iter().map(|b| b.input_seq).collect();
    assert_eq!(inputs, [0, 1, 2, 3, 6, 7, 8, 9]);
    for blk in &got {
        let gap = blk.flags & cf::INPUT_GAP != 0;
        assert_eq!(
            gap,
            blk.input_seq == 6,
            "block {}: flags {:#x}",
            blk.input_seq,
            blk.flags
        );
    }
    // The reference: what this test did. Never sent: 1 (seq 5); late: 1 (seq 4), so when
    // seq 6 arrived two were missing, and one of them came after.
    let (never_sent, late) = (1u64, 1u64);
    let s = &b["streams"][0];
    assert_eq!(s["stream"], "accel", "{b}");
    assert_eq!(s["forwarded"], order.len() as u64, "{b}");
    assert_eq!(s["gap_messages"], never_sent + late, "{b}");
    assert_eq!(s["out_of_order"], late, "{b}");
    assert_eq!(s["queue_dropped"], 0, "{b}");
    assert_eq!(c["accel"]["lost_messages"], never_sent + late, "{c}");
    assert_eq!(c["accel"]["out_of_order"], late, "{c}");
    assert_eq!(c["accel"]["lost_samples"], (never_sent + late) * 32, "{c}");
}

/// A peer that sends crafted `seq`s (issue 31, item 5: a bridge's final line read
/// `lost 17752385060991721825`). The bridge applies the services' jump rule
/// (vibro_service::Continuity: at most 2^20 messages count as lost in one step; a
/// bigger step is a jump, counted as such and never as a loss). The reference is the
/// list of `seq`s this test put: a gap of 2, a gap of exactly 2^20 (the limit,
/// inclusive), a step of 2^20 + 2 and one to 0xF000... (two jumps).
#[test]
fn a_seq_jump_from_the_network_is_counted_as_a_jump_never_as_a_loss() {
    const MAX_LOST: u64 = 1 << 20; // vibro_service's MAX_LOST_MESSAGES
    let dir = Dir::new("jump");
    let prefix = prefix("j");
    let (config, endpoint, key_prefix) =
        listening_config(&dir, &prefix, "jump", "[import]\nstreams = [\"accel\"]\n");
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-jump").unwrap();
    let local = StreamSubscriber::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let br = bridge(&config, &dir);
    let (session, publisher) = remote_accel_publisher(&endpoint, &key_prefix);
    let s1 = 5 + MAX_LOST + 1;
    let s2 = s1 + MAX_LOST + 2;
    let s3 = 0xF000_0000_0000_0000u64;
    let seqs = [0, 1, 2, 5, s1, s2, s2 + 1, s3, s3 + 1];
    for (i, &seq) in seqs.iter().enumerate() {
        let mut b = accel_block(i as u64);
        b.seq = seq;
        publisher.put(b.bytes()).wait().unwrap();
    }
    let mut got = Vec::new();
    wait_until("the blocks in iceoryx2", Duration::from_secs(10), || {
        while let Some(b) = local.receive().unwrap() {
            got.push(b.seq);
        }
        got.len() >= seqs.len()
    });
    assert_eq!(got, seqs, "the bridge forwards every block, jumps included");
    drop(publisher);
    session.close().wait().unwrap();
    let b = br.summary();
    let s = &b["streams"][0];
    let (gaps, jumps) = (2 + MAX_LOST, 2u64);
    assert_eq!(s["gap_messages"], gaps, "{b}");
    assert_eq!(s["seq_jumps"], jumps, "{b}");
    assert_eq!(s["producer_restarts"], 0, "{b}");
    assert_eq!(s["out_of_order"], 0, "{b}");
    assert_eq!(s["forwarded"], seqs.len() as u64, "{b}");
    assert_eq!(b["lost"], gaps, "{b}");
}

/// A Zenoh peer connected to the bridge listening on `endpoint`, with nothing declared.
fn remote_session(endpoint: &str) -> zenoh::Session {
    let mut zc = zenoh::Config::default();
    zc.insert_json5("mode", "\"peer\"").unwrap();
    zc.insert_json5("connect/endpoints", &format!("[{endpoint:?}]"))
        .unwrap();
    zc.insert_json5("connect/timeout_ms", "10000").unwrap();
    zc.insert_json5("connect/exit_on_failure", "true").unwrap();
    zc.insert_json5("listen/endpoints", "[]").unwrap();
    zc.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zenoh::open(zc).wait().unwrap()
}

fn heartbeat(service: ServiceId, seq: u64) -> vibro_msgs::Heartbeat {
    vibro_msgs::Heartbeat {
        seq,
        publish_ns: vibro_ipc::now_ns(),
        uptime_ns: seq * 1_000_000_000,
        received: 10 * seq,
        service: service.code(),
        ..vibro_msgs::Heartbeat::ZEROED
    }
}

/// CI (after 1656 s, `latency --hosts 2` under load): the compute host's bridge counted
/// a heartbeat of each service as lost, taken before the rig host's bridge came up a
/// second later. A heartbeat is its service's whole state (cumulative counters): the
/// newest one waits for the other side and is sent when it comes; the ones it replaced
/// are `superseded`, not lost. The reference is what this test published: heartbeats 0,
/// 1, 2 with nobody on the other side, then a peer subscribes and must get heartbeat 2
/// (before the fix it got none, and the bridge counted 3 lost). The other way, a peer
/// puts heartbeats 0, 1, 4, 5: all forwarded, 2 superseded, none lost.
#[test]
fn heartbeats_taken_before_the_other_side_came_up_wait_for_it_and_are_not_lost() {
    let dir = Dir::new("state");
    let prefix = prefix("s");
    let (config, endpoint, key_prefix) = listening_config(
        &dir,
        &prefix,
        "state",
        "[export]\nstreams = [\"heartbeat/compensator\"]\n[import]\nstreams = [\"heartbeat/estimator\"]\n",
    );
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-state").unwrap();
    let mut hb_out = StreamPublisher::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        Stream::Heartbeat(ServiceId::Compensator),
    )
    .unwrap();
    let hb_in = StreamSubscriber::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        Stream::Heartbeat(ServiceId::Estimator),
    )
    .unwrap();
    let br = bridge(&config, &dir);
    wait_until(
        "the bridge's iceoryx2 subscriber",
        Duration::from_secs(20),
        || hb_out.subscriber_count() >= 1,
    );
    for seq in 0..3 {
        hb_out
            .publish(&heartbeat(ServiceId::Compensator, seq))
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
    }
    // Taken by the bridge while no peer was there.
    std::thread::sleep(Duration::from_millis(500));
    let session = remote_session(&endpoint);
    let got = std::sync::Arc::new(std::sync::Mutex::new(Vec::<u64>::new()));
    let _sub = session
        .declare_subscriber(format!("{key_prefix}/heartbeat/compensator"))
        .callback({
            let got = std::sync::Arc::clone(&got);
            move |s| {
                let bytes = s.payload().to_bytes();
                if let Some(h) = vibro_msgs::Heartbeat::from_wire_bytes(&bytes) {
                    got.lock().unwrap().push(h.seq);
                }
            }
        })
        .wait()
        .unwrap();
    wait_until("heartbeat 2 at the peer", Duration::from_secs(10), || {
        got.lock().unwrap().contains(&2)
    });
    let publisher = matched_publisher(
        &session,
        format!("{key_prefix}/heartbeat/estimator"),
        vibro_msgs::MessageKind::Heartbeat,
    );
    let sent = [0u64, 1, 4, 5];
    for seq in sent {
        publisher
            .put(heartbeat(ServiceId::Estimator, seq).bytes())
            .wait()
            .unwrap();
    }
    let mut local = Vec::new();
    wait_until(
        "the heartbeats in iceoryx2",
        Duration::from_secs(10),
        || {
            while let Some(h) = hb_in.receive().unwrap() {
                local.push(h.seq);
            }
            local.len() >= sent.len()
        },
    );
    assert_eq!(local, sent);
    drop(publisher);
    drop(_sub);
    session.close().wait().unwrap();
    let b = br.summary();
    let stream = |name: &str| {
        b["streams"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["stream"] == name)
            .unwrap_or_else(|| panic!("{name} in {b}"))
            .clone()
    };
    let out = stream("heartbeat/compensator");
    let received = got.lock().unwrap().clone();
    // What the peer got: the newest heartbeat taken before it came, nothing older.
    assert_eq!(received, [2], "{b}");
    assert_eq!(out["unmatched"], 0, "{b}");
    assert_eq!(out["forwarded"], 1, "{b}");
    assert_eq!(out["superseded"], 2, "{b}");
    let inn = stream("heartbeat/estimator");
    assert_eq!(inn["forwarded"], sent.len() as u64, "{b}");
    assert_eq!(inn["superseded"], 2, "{b}");
    assert_eq!(inn["gap_messages"], 0, "{b}");
    assert_eq!(b["lost"], 0, "{b}");
}

/// A bridge keeps the order the compensator's waveform stage needs across its
/// streams: a sensor block published before an accelerometer block reaches the other
/// side before it (docs/bridge.md, "Order across streams"). This test publishes
/// sensor block k, then accelerometer block k, as fast as the bridge takes them, and
/// reads both keys on one Zenoh session (one link: Zenoh keeps its order). Before
/// the exporter took the accelerometer stream ahead of the sensors', a block taken
/// between the two takes overtook the sensor block before it: under load in CI the
/// two-host demo's compensator gave up 20 of 75 blocks as "late" that one host solved.
#[test]
fn a_sensor_block_published_before_an_accelerometer_block_arrives_before_it() {
    const PAIRS: u64 = 3000;
    let dir = Dir::new("order");
    let prefix = prefix("o");
    let (config, endpoint, key_prefix) = listening_config(
        &dir,
        &prefix,
        "order",
        "[export]\nstreams = [\"accel\", \"vib\"]\n",
    );
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-order").unwrap();
    let mut vib_out = StreamPublisher::<VibBlock>::open(&node, &names, Stream::Vib).unwrap();
    let mut accel_out = StreamPublisher::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let br = bridge(&config, &dir);
    wait_until(
        "the bridge's iceoryx2 subscribers",
        Duration::from_secs(20),
        || vib_out.subscriber_count() >= 1 && accel_out.subscriber_count() >= 1,
    );
    let session = remote_session(&endpoint);
    // (stream, seq) in arrival order: 0 a sensor block, 1 an accelerometer block.
    let got = std::sync::Arc::new(std::sync::Mutex::new(Vec::<(u8, u64)>::new()));
    let subscribe = |suffix: &str, which: u8| {
        let got = std::sync::Arc::clone(&got);
        session
            .declare_subscriber(format!("{key_prefix}/{suffix}"))
            .callback(move |s| {
                let bytes = s.payload().to_bytes();
                let seq = match which {
                    0 => VibBlock::from_wire_bytes(&bytes).map(|b| b.seq),
                    _ => AccelBlock::from_wire_bytes(&bytes).map(|b| b.seq),
                };
                if let Some(seq) = seq {
                    got.lock().unwrap().push((which, seq));
                }
            })
            .wait()
            .unwrap()
    };
    let _subs = [subscribe("vib", 0), subscribe("accel", 1)];
    // The bridge's publishers matched (its stream report counts no `unmatched`).
    std::thread::sleep(Duration::from_millis(500));
    for k in 0..PAIRS {
        let mut v = VibBlock::ZEROED;
        v.seq = k;
        vib_out.publish(&v).unwrap();
        accel_out.publish(&accel_block(k)).unwrap();
        if k % 64 == 63 {
            // The bridge's subscriber buffers hold 256: no back-pressure timeout.
            std::thread::yield_now();
        }
    }
    wait_until("every block at the peer", Duration::from_secs(30), || {
        got.lock().unwrap().len() as u64 >= 2 * PAIRS
    });
    let got = got.lock().unwrap().clone();
    let mut vib_seen = vec![false; PAIRS as usize];
    let mut overtaken = Vec::new();
    for &(which, seq) in &got {
        match which {
            0 => vib_seen[seq as usize] = true,
            _ if !vib_seen[seq as usize] => overtaken.push(seq),
            _ => {}
        }
    }
    let b = br.summary();
    assert_eq!(b["lost"], 0, "{b}");
    assert!(
        overtaken.is_empty(),
        "{} of {PAIRS} accelerometer blocks arrived before the sensor block published before them (first: {:?})",
        overtaken.len(),
        &overtaken[..overtaken.len().min(10)]
    );
    // Each stream in its own order.
    for which in [0u8, 1] {
        let seqs: Vec<u64> = got.iter().filter(|g| g.0 == which).map(|g| g.1).collect();
        assert_eq!(seqs, (0..PAIRS).collect::<Vec<_>>());
    }
}

/// The uid and gid the intruder runs as (`nobody` on Debian and most distributions).
const INTRUDER_ID: u32 = 65534;

/// What the intruder reports: whether its Zenoh session opened (and why not), whether
/// the bridge matched its accelerometer publisher, and how many bridged messages it
/// received (its own puts not counted).
#[derive(Debug)]
struct Intrusion {
    /// A Unix-socket endpoint: what a bare `connect(2)` to it met (`Ok`, or the
    /// `io::ErrorKind`), so that a refusal is seen to be the operating system's.
    socket: String,
    opened: bool,
    error: String,
    matched: bool,
    received: u64,
}

/// Runs [`intruder_child`] as uid/gid [`INTRUDER_ID`] (no supplementary groups: std
/// clears them when root changes the uid): a Zenoh peer connecting to `endpoint`,
/// subscribing to `{key_prefix}/**` and putting 10 accelerometer blocks on
/// `{key_prefix}/accel`. The child is this test binary (any user can run it from the
/// target folder; Python's zenoh lives under /root, which that user cannot read).
fn intrude(endpoint: &str, key_prefix: &str) -> Intrusion {
    use std::os::unix::process::CommandExt;
    let out = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "bridge::intruder_child",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env("VCB_INTRUDER", format!("{endpoint} {key_prefix}"))
        .current_dir("/")
        .uid(INTRUDER_ID)
        .gid(INTRUDER_ID)
        .stdin(Stdio::null())
        .output()
        .expect("the intruder starts");
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find_map(|l| l.split_once("INTRUDER ").map(|(_, json)| json))
        .unwrap_or_else(|| {
            panic!(
                "the intruder (uid {INTRUDER_ID}) did not report; it must be able to run {}:\n{text}\n{}",
                std::env::current_exe().unwrap().display(),
                String::from_utf8_lossy(&out.stderr)
            )
        });
    let v: Value = serde_json::from_str(line).unwrap();
    Intrusion {
        socket: v["socket"].as_str().unwrap_or_default().to_string(),
        opened: v["opened"].as_bool().unwrap(),
        error: v["error"].as_str().unwrap_or_default().to_string(),
        matched: v["matched"].as_bool().unwrap_or(false),
        received: v["received"].as_u64().unwrap_or(0),
    }
}

/// The intruder of [`another_user_cannot_publish_into_or_read_from_a_single_host_bridge`],
/// run by [`intrude`] as another user; does nothing unless `VCB_INTRUDER` is set.
#[test]
#[ignore = "a child process of another test"]
fn intruder_child() {
    let Ok(spec) = std::env::var("VCB_INTRUDER") else {
        return;
    };
    let (endpoint, key_prefix) = spec.split_once(' ').unwrap();
    let socket = match endpoint.split_once('/') {
        Some(("unixsock-stream", path)) => match std::os::unix::net::UnixStream::connect(path) {
            Ok(_) => "Ok".to_string(),
            Err(e) => format!("{:?}", e.kind()),
        },
        _ => String::new(),
    };
    let mut zc = zenoh::Config::default();
    zc.insert_json5("mode", "\"peer\"").unwrap();
    zc.insert_json5("connect/endpoints", &format!("[{endpoint:?}]"))
        .unwrap();
    zc.insert_json5("connect/timeout_ms", "3000").unwrap();
    zc.insert_json5("connect/exit_on_failure", "true").unwrap();
    zc.insert_json5("listen/endpoints", "[]").unwrap();
    zc.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let session = match zenoh::open(zc).wait() {
        Ok(s) => s,
        Err(e) => {
            let v = serde_json::json!({"socket": socket, "opened": false, "error": e.to_string()});
            println!("INTRUDER {v}");
            return;
        }
    };
    // What the bridge sends it: everything but its own accelerometer blocks (which
    // Zenoh delivers to its own subscriber too).
    let received = std::sync::Arc::new(AtomicU32::new(0));
    let r = std::sync::Arc::clone(&received);
    let own = format!("{key_prefix}/accel");
    let sub = session
        .declare_subscriber(format!("{key_prefix}/**"))
        .callback(move |sample| {
            if sample.key_expr().as_str() != own {
                r.fetch_add(1, Ordering::Relaxed);
            }
        })
        .wait()
        .unwrap();
    let publisher = session
        .declare_publisher(format!("{key_prefix}/accel"))
        .encoding(vibro_bridge::encoding_of(
            vibro_msgs::MessageKind::AccelBlock,
        ))
        .wait()
        .unwrap();
    let start = Instant::now();
    let mut matched = false;
    while !matched && start.elapsed() < Duration::from_secs(5) {
        matched = publisher.matching_status().wait().unwrap().matching();
        std::thread::sleep(Duration::from_millis(20));
    }
    for seq in 0..10 {
        publisher.put(accel_block(seq).bytes()).wait().unwrap();
    }
    std::thread::sleep(Duration::from_millis(1500));
    let v = serde_json::json!({
        "socket": socket,
        "opened": true,
        "matched": matched,
        "received": received.load(Ordering::Relaxed),
    });
    println!("INTRUDER {v}");
    drop((sub, publisher));
    let _ = session.close().wait();
}

/// Issue 31, item 2: on one host, another user (uid 65534 against this test's root)
/// published accelerometer blocks into the shipped loopback bridge and read its
/// streams. The bridge here is `config/bridge/compute-host.toml` as shipped, with
/// only its prefixes and its listen address moved to this test's own; the intruder
/// connects to it, subscribes to everything and puts 10 accelerometer blocks while
/// this test publishes compensated blocks for the bridge to export. Nothing of the
/// intruder's may arrive, and it may receive nothing. A control run of the same
/// intruder against a socket it may reach shows that it would have got through.
///
/// Not as root, the other-user part cannot run: the test says so on stderr and checks
/// only what a same-user process meets.
#[test]
fn another_user_cannot_publish_into_or_read_from_a_single_host_bridge() {
    let dir = Dir::new("intr");
    let prefix = prefix("i");
    let key_prefix = format!("vibrocomp/intr{}", next_id());
    let shipped = std::fs::read_to_string(repo_path("config/bridge/compute-host.toml")).unwrap();
    let mut endpoint = String::new();
    let text: String = shipped
        .lines()
        .map(|l| {
            if l.starts_with("prefix = ") {
                format!("prefix = {prefix:?}")
            } else if l.starts_with("key_prefix = ") {
                format!("key_prefix = {key_prefix:?}")
            } else if let Some(rest) = l.strip_prefix("listen = [\"") {
                let shipped_ep = rest.split('"').next().unwrap();
                endpoint = match shipped_ep.split_once('/').unwrap().0 {
                    "tcp" => format!("tcp/127.0.0.1:{}", free_port().unwrap()),
                    "unixsock-stream" => {
                        format!("unixsock-stream/{}", dir.path("zenoh/b.sock").display())
                    }
                    other => panic!("the shipped listen endpoint's protocol {other:?}"),
                };
                format!("listen = [{endpoint:?}]")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert!(!endpoint.is_empty(), "no listen line in:\n{shipped}");
    let config = write(&dir.path("b.toml"), &text);
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-intr").unwrap();
    let local = StreamSubscriber::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let mut compensated =
        StreamPublisher::<CompensatedBlock>::open(&node, &names, Stream::Compensated).unwrap();
    let br = bridge(&config, &dir);
    wait_until(
        "the bridge's endpoint",
        Duration::from_secs(10),
        || match endpoint.split_once('/').unwrap() {
            ("unixsock-stream", path) => Path::new(path).exists(),
            (_, addr) => std::net::TcpStream::connect(addr).is_ok(),
        },
    );
    // What any user meets: the socket's directory is this user's alone.
    if let Some(("unixsock-stream", path)) = endpoint.split_once('/') {
        use std::os::unix::fs::MetadataExt;
        let meta = std::fs::metadata(Path::new(path).parent().unwrap()).unwrap();
        assert_eq!(meta.mode() & 0o777, 0o700, "the socket's directory");
        // SAFETY: geteuid has no preconditions.
        assert_eq!(meta.uid(), unsafe { libc::geteuid() });
    }
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!(
            "\n*** SKIPPED: another_user_cannot_publish_into_or_read_from_a_single_host_bridge: not running as root, so no process of another user can be started; only the same-user checks ran ***\n"
        );
        drop(br);
        return;
    }
    // The bridge exports compensated blocks all along (to anybody it matched).
    // (An iceoryx2 publisher stays on its thread: the intruder runs on another.)
    let intrusion = std::thread::scope(|s| {
        let intruder = s.spawn(|| intrude(&endpoint, &key_prefix));
        let mut seq = 0;
        while !intruder.is_finished() {
            let mut b = CompensatedBlock::ZEROED;
            b.seq = seq;
            seq += 1;
            let _ = compensated.publish(&b);
            std::thread::sleep(Duration::from_millis(20));
        }
        intruder.join().unwrap()
    });
    let mut arrived = 0;
    while local.receive().unwrap().is_some() {
        arrived += 1;
    }
    let b = br.summary();
    let accel = b["streams"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["stream"] == "accel")
        .unwrap()
        .clone();
    assert_eq!(
        (accel["forwarded"].as_u64().unwrap(), arrived),
        (0, 0),
        "the intruder's accelerometer blocks went through ({intrusion:?}): {b}"
    );
    assert_eq!(
        intrusion.received, 0,
        "the intruder read the bridge's streams: {intrusion:?}"
    );
    assert!(!intrusion.matched, "{intrusion:?}");
    assert!(
        !intrusion.opened,
        "the intruder's session opened ({}): {intrusion:?}",
        intrusion.error
    );
    assert_eq!(
        intrusion.socket, "PermissionDenied",
        "the operating system refuses the intruder: {intrusion:?}"
    );

    // Control: the same intruder, given a socket it may reach, gets its 10 blocks
    // through (so the refusal above is the bridge's directory, not the harness).
    let open = dir.path("open");
    std::fs::create_dir_all(&open).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o777)).unwrap();
    let sock = open.join("c.sock");
    let control_ep = format!("unixsock-stream/{}", sock.display());
    let mut zc = zenoh::Config::default();
    zc.insert_json5("mode", "\"peer\"").unwrap();
    zc.insert_json5("listen/endpoints", &format!("[{control_ep:?}]"))
        .unwrap();
    zc.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    let session = zenoh::open(zc).wait().unwrap();
    std::fs::set_permissions(&sock, std::fs::Permissions::from_mode(0o777)).unwrap();
    let got = std::sync::Arc::new(AtomicU32::new(0));
    let g = std::sync::Arc::clone(&got);
    let sub = session
        .declare_subscriber(format!("{key_prefix}/accel"))
        .callback(move |_| {
            g.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .unwrap();
    let control = intrude(&control_ep, &key_prefix);
    assert!(
        control.socket == "Ok" && control.opened && control.matched,
        "control: {control:?}"
    );
    assert_eq!(got.load(Ordering::Relaxed), 10, "control: {control:?}");
    eprintln!("intruder (uid {INTRUDER_ID}): {intrusion:?}\ncontrol: {control:?}");
    drop(sub);
    session.close().wait().unwrap();
}

/// A socket directory that others may enter (mode 0755), or a plain-TCP endpoint,
/// stops the bridge at start: exit 1 before any Zenoh session or iceoryx2 port, the
/// file, key, endpoint, what was found and the rule in the message.
#[test]
fn a_socket_directory_others_may_enter_stops_the_bridge_at_start() {
    use std::os::unix::fs::PermissionsExt;
    let dir = Dir::new("open");
    let (config, endpoint, _) = listening_config(
        &dir,
        &prefix("o"),
        "open",
        "[import]\nstreams = [\"accel\"]\n",
    );
    std::fs::create_dir(dir.path("zenoh")).unwrap();
    std::fs::set_permissions(dir.path("zenoh"), std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = run_failing(&["bridge", "--config", config.to_str().unwrap(), "--json"]);
    let text = String::from_utf8_lossy(&out.stderr);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"]["file"], config.to_str().unwrap(), "{v}");
    for needle in [
        format!("zenoh.listen[0] = {endpoint:?}"),
        "with mode 0755".to_string(),
        "give its group and others no permission (mode 0700".to_string(),
    ] {
        assert!(text.contains(&needle), "missing {needle:?} in:\n{text}");
    }
    assert!(
        !dir.path("zenoh/b.sock").exists(),
        "the bridge bound its socket"
    );
}

/// The Python `eclipse-zenoh` client subscribes to the compensated stream a bridge
/// exports and decodes it by docs/messages.md; every field of every block equals the
/// block read from iceoryx2 here (doubles bit for bit).
#[test]
fn a_python_zenoh_client_decodes_the_bridged_compensated_stream() {
    const BLOCKS: u64 = 12;
    let dir = Dir::new("py");
    let prefix = prefix("p");
    let (config, endpoint, key_prefix) = listening_config(
        &dir,
        &prefix,
        "py",
        "[export]\nstreams = [\"compensated\"]\n",
    );
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-py").unwrap();
    let out =
        StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated).unwrap();
    let mut accel = StreamPublisher::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let comp = compensator(&prefix, &dir);
    let br = bridge(&config, &dir);
    let py_out = dir.path("py.stdout");
    let mut py = Command::new("python3")
        .arg(repo_path("tests/python/zenoh_client.py"))
        .args([
            &endpoint,
            &format!("{key_prefix}/compensated"),
            "CompensatedBlock",
            &BLOCKS.to_string(),
            "30",
        ])
        .stdout(std::fs::File::create(&py_out).unwrap())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 runs (pip install -r tests/python/requirements.txt)");
    wait_until("the Python client", Duration::from_secs(20), || {
        std::fs::read_to_string(&py_out)
            .unwrap_or_default()
            .starts_with("ready")
    });
    wait_until(
        "the compensator's accel subscriber",
        Duration::from_secs(20),
        || accel.subscriber_count() >= 1,
    );
    // The client's subscription reaches the bridge (a message sent before that is
    // counted unmatched, and this test would fail on the count below).
    std::thread::sleep(Duration::from_millis(1000));
    for seq in 0..BLOCKS {
        accel.publish(&accel_block(seq)).unwrap();
    }
    let mut local = Vec::new();
    wait_until("the compensated blocks", Duration::from_secs(10), || {
        while let Some(b) = out.receive().unwrap() {
            local.push(*b);
        }
        local.len() as u64 >= BLOCKS
    });
    let status = py.wait().unwrap();
    let err = {
        use std::io::Read;
        let mut s = String::new();
        py.stderr.take().unwrap().read_to_string(&mut s).unwrap();
        s
    };
    assert!(status.success(), "zenoh_client.py: {status}\n{err}");
    let b = br.summary();
    drop(comp);
    assert_eq!(b["streams"][0]["forwarded"], BLOCKS, "{b}");
    assert_eq!(b["lost"], 0, "{b}");
    let text = std::fs::read_to_string(&py_out).unwrap();
    let decoded: Vec<Value> = text
        .lines()
        .skip(1)
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(decoded.len() as u64, BLOCKS);
    for (d, blk) in decoded.iter().zip(&local) {
        assert_eq!(d["key"], format!("{key_prefix}/compensated"));
        let f = &d["fields"];
        assert_eq!(f["seq"], blk.seq);
        assert_eq!(f["input_seq"], blk.input_seq);
        assert_eq!(f["t0_ns"], blk.t0_ns);
        assert_eq!(f["sample_period_ns"], blk.sample_period_ns);
        assert_eq!(f["publish_ns"], blk.publish_ns);
        assert_eq!(f["count"], blk.count);
        assert_eq!(f["source_id"], blk.source_id);
        assert_eq!(f["flags"], blk.flags);
        assert_eq!(f["mode"], blk.mode);
        for (name, arr) in [
            ("a1_g", &blk.a1_g),
            ("a2_g", &blk.a2_g),
            ("a4_g", &blk.a4_g),
        ] {
            let bits: Vec<u64> = arr.iter().flatten().map(|x| x.to_bits()).collect();
            let py_bits: Vec<u64> = f[name]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap())
                .collect();
            assert_eq!(py_bits, bits, "{name} of block {}", blk.seq);
        }
    }
}

/// The compensated blocks of a recording, without the stamps of the clock of the
/// machine (`input_publish_ns`, `recv_ns`, `publish_ns`), as bytes.
fn compensated_of(session: &Path) -> Vec<Vec<u8>> {
    let recs: Vec<vibro_mcap::Record> = vibro_mcap::Reader::open(session)
        .unwrap()
        .map(|r| r.unwrap())
        .collect();
    recs.iter()
        .filter_map(|r| match &r.message {
            vibro_mcap::Message::CompensatedBlock(b) if &*r.topic == "/compensated" => {
                let mut b = *b;
                b.input_publish_ns = 0;
                b.recv_ns = 0;
                b.publish_ns = 0;
                Some(b.bytes().to_vec())
            }
            _ => None,
        })
        .collect()
}

/// `demo --hosts 2`: the flight replayed on host A into the services on host B (another
/// iceoryx2 root), recorded on host A, only Zenoh between them. The compensated output
/// is the one-host run's, bit for bit, and the same table is printed.
#[test]
fn the_two_host_demo_is_bit_identical_to_the_one_host_demo() {
    // Not beside the lab's heavy tests: the compensator's one wall-clock rule (a held
    // block given up after 1 s of silence on the sensors' stream) must not fire
    // mid-run. The failures under load that this lock was added for were the bridge's
    // order across streams instead (fallbacks "late", not "silent"; see
    // a_sensor_block_published_before_an_accelerometer_block_arrives_before_it).
    let _quiet = crate::common::heavy();
    let dir = Dir::new("demo");
    let text = std::fs::read_to_string(repo_path("config/scenarios/cyclone-4-short.toml"))
        .unwrap()
        .replace("duration_s = 20.0", "duration_s = 3.0");
    let scenario = write(&dir.path("short.toml"), &text);
    let run = |hosts: &str, out: &str| {
        let o = bin()
            .current_dir(repo_path(""))
            .args([
                "demo",
                "--scenario",
                scenario.to_str().unwrap(),
                "--out-dir",
                dir.path(out).to_str().unwrap(),
                "--hosts",
                hosts,
                "--json",
            ])
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "demo --hosts {hosts}: {}\n{}",
            String::from_utf8_lossy(&o.stderr),
            std::fs::read_to_string(dir.path(out).join("services.log")).unwrap_or_default()
        );
        serde_json::from_slice::<Value>(&o.stdout).unwrap()
    };
    let one = run("1", "one");
    let two = run("2", "two");
    let a = compensated_of(&dir.path("one/session.mcap"));
    let b = compensated_of(&dir.path("two/session.mcap"));
    assert!(a.len() > 50, "{} compensated blocks", a.len());
    assert_eq!(a.len(), b.len());
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!(
            x == y,
            "compensated block {i} differs between one and two hosts"
        );
    }
    assert_eq!(one["errors"], two["errors"]);
    assert_eq!(two["lost_messages"], 0, "{two}");
    assert_eq!(two["bridges"].as_array().unwrap().len(), 2, "{two}");
    for br in two["bridges"].as_array().unwrap() {
        assert_eq!(br["summary"]["lost"], 0, "{br}");
    }
    // Nothing of the two hosts' iceoryx2 roots is left, in /tmp or in /dev/shm.
    let tag = format!(
        "vcd{}",
        two["prefix"]
            .as_str()
            .unwrap()
            .trim_start_matches("vcdemo-")
            .trim_end_matches('/')
    );
    let mut leftovers = Vec::new();
    for folder in [std::env::temp_dir(), PathBuf::from("/dev/shm")] {
        for e in std::fs::read_dir(&folder).unwrap().flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            if n.starts_with(&format!("iox2-{tag}"))
                || n.starts_with(&format!("{tag}a_"))
                || n.starts_with(&format!("{tag}b_"))
            {
                leftovers.push(e.path());
            }
        }
    }
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// A bridge killed mid-run: host B (`vibrocomp up --bridge`, services and bridge in
/// their own iceoryx2 root) and host A (this test's root: its bridge, a paced replay,
/// and this test reading what comes back). Host B's bridge is killed with SIGKILL two
/// seconds in; `up` restarts it. Host A's bridge counts what it sent while nobody
/// listened (`unmatched`); the compensator on host B counts the same blocks as a gap
/// in `seq` (its progress messages, bridged back, carry `lost`), flags the block after
/// the gap `INPUT_GAP`, the blocks until the estimator's window is full again
/// `VIBRATION_ESTIMATE_STALE`, and recovers.
#[test]
fn a_bridge_killed_mid_run_is_restarted_and_the_gap_is_counted_on_both_sides() {
    use crate::processes::{children, flight_log, kill, Dir as PDir};
    let pdir = PDir::new("bkill");
    let dir = Dir::new("bkill");
    let prefix = prefix("k");
    let flight = flight_log(&pdir, "6");
    let tag = format!("vck{}x{}", std::process::id(), next_id());
    let hosts = vibro_system::hosts::TwoHosts::create(&dir.path("hosts"), &tag, &prefix).unwrap();
    // The shipped model with estimates stale after 1.2 s instead of 2 s: in steady
    // state an estimate is at most a hop (0.5 s) old, and the outage (about 1 s: the
    // restart's back-off and the reconnection) then ages it past 1.2 s.
    let comp_config = write(
        &dir.path("compensator.toml"),
        "prefix = \"vibrocomp/\"\nmode = \"exact\"\ntriad = \"default\"\nmax_estimate_age_s = 1.2\nreload_poll_s = 0.0\n",
    );
    <vibro_compensator::Config as vibro_service::ServiceConfig>::load(&comp_config).unwrap();
    let up = Kid::spawn(
        "up",
        bin()
            .current_dir(&hosts.b.dir)
            .args(["up", "--json", "--prefix", &prefix, "--bridge"])
            .arg(&hosts.b.bridge_config)
            .arg("--estimator-config")
            .arg(repo_path("config/services/estimator.toml"))
            .arg("--compensator-config")
            .arg(&comp_config),
        &dir,
    );
    // Host A's bridge runs in this process's iceoryx2 root.
    let br_a = bridge(&hosts.a.bridge_config, &dir);
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-kill").unwrap();
    let out =
        StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated).unwrap();
    let progress = StreamSubscriber::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        Stream::Progress(ServiceId::Compensator),
    )
    .unwrap();
    let hb = StreamSubscriber::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        Stream::Heartbeat(ServiceId::Compensator),
    )
    .unwrap();
    wait_until(
        "host B's compensator heartbeat on host A",
        Duration::from_secs(30),
        || hb.receive().unwrap().is_some(),
    );
    let up_pid = up.child.as_ref().unwrap().id();
    let mut replay = Kid::spawn(
        "replay",
        bin()
            .args(["replay", "--rate", "1", "--prefix", &prefix, "--json"])
            .arg(&flight),
        &dir,
    );
    let mut blocks: Vec<CompensatedBlock> = Vec::new();
    let mut lost = 0;
    let mut killed_after = None;
    let start = Instant::now();
    loop {
        while let Some(b) = out.receive().unwrap() {
            blocks.push(*b);
        }
        while let Some(p) = progress.receive().unwrap() {
            lost = p.lost;
        }
        if killed_after.is_none() && blocks.len() >= 50 {
            let (pid, _) = children(up_pid)
                .into_iter()
                .find(|(_, cmd)| cmd.contains(" bridge "))
                .expect("host B's bridge under up");
            kill(pid, libc::SIGKILL);
            killed_after = Some(blocks.last().unwrap().input_seq);
        }
        if replay.child.as_mut().unwrap().try_wait().unwrap().is_some() {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the replay did not end"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // What is still on its way back.
    std::thread::sleep(Duration::from_millis(500));
    while let Some(b) = out.receive().unwrap() {
        blocks.push(*b);
    }
    while let Some(p) = progress.receive().unwrap() {
        lost = p.lost;
    }
    let _ = replay.summary();
    let a = br_a.summary();
    let report = up.summary();
    let killed_after = killed_after.expect("the bridge was killed");

    let bridge_report = report["processes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["role"] == "bridge")
        .unwrap_or_else(|| panic!("{report}"));
    assert_eq!(bridge_report["starts"], 2, "{report}");
    assert_eq!(bridge_report["crashes"], 1, "{report}");
    let stream = |name: &str| {
        a["streams"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["stream"] == name)
            .unwrap()
            .clone()
    };
    let unmatched = stream("accel")["unmatched"].as_u64().unwrap();
    assert!(unmatched > 0, "{a}");
    assert!(stream("vib")["unmatched"].as_u64().unwrap() > 0, "{a}");
    // Both sides count the same gap; a block already on the wire when the bridge died
    // is counted by the compensator only (at most the link's few in flight).
    assert!(
        (unmatched..=unmatched + 2).contains(&lost),
        "host A's bridge sent {unmatched} accelerometer blocks while nobody listened; the compensator counted {lost} lost"
    );
    let after: Vec<&CompensatedBlock> = blocks
        .iter()
        .filter(|b| b.input_seq > killed_after)
        .collect();
    assert!(
        after.iter().any(|b| b.flags & cf::INPUT_GAP != 0),
        "no block after the restart flagged INPUT_GAP"
    );
    // On the way back: compensated blocks the dead bridge never sent are a gap in
    // their `seq` here, counted by host A's bridge as the test sees it.
    let missing: u64 = blocks.windows(2).map(|w| w[1].seq - w[0].seq - 1).sum();
    assert_eq!(stream("compensated")["gap_messages"], missing, "{a}");
    assert!(
        after
            .iter()
            .any(|b| b.flags & cf::VIBRATION_ESTIMATE_STALE != 0),
        "no stale block after the gap ({unmatched} blocks unmatched): {:?}",
        after
            .iter()
            .map(|b| (b.input_seq, b.flags, b.estimate_age_ns / 1_000_000))
            .collect::<Vec<_>>()
    );
    let last = blocks.last().unwrap();
    assert_eq!(
        last.flags & (cf::VIBRATION_ESTIMATE_STALE | cf::MAIN_ONLY | cf::ESTIMATE_MISSING),
        0,
        "not recovered by the end: {:#x}",
        last.flags
    );
    drop(hosts);
}

/// A slow receiving side: the bridge's iceoryx2 publisher is held back by a subscriber
/// that reads nothing (its buffer full, the publisher waits its bounded second), so the
/// bridge's bounded import queue (`queue_depth = 2`) fills while a burst arrives from
/// the network. The queue drops, counts (`queue_dropped`), and the compensator behind
/// it counts exactly as many lost from the gaps in `seq`; nothing else is lost.
#[test]
fn a_slow_receiving_side_drops_at_its_bounded_queue_and_counts_it() {
    const BURST: u64 = 400;
    let dir = Dir::new("slow");
    let prefix = prefix("s");
    let (config, endpoint, key_prefix) = listening_config(
        &dir,
        &prefix,
        "slow",
        "[import]\nstreams = [\"accel\"]\nqueue_depth = 2\n",
    );
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-slow").unwrap();
    let comp = compensator(&prefix, &dir);
    let br = bridge(&config, &dir);
    let probe = StreamSubscriber::<vibro_msgs::Heartbeat>::open(
        &node,
        &names,
        Stream::Heartbeat(ServiceId::Compensator),
    )
    .unwrap();
    wait_until(
        "the compensator's heartbeat",
        Duration::from_secs(20),
        || probe.receive().unwrap().is_some(),
    );
    let stuck = StreamSubscriber::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let (session, publisher) = remote_accel_publisher(&endpoint, &key_prefix);
    for seq in 0..BURST {
        publisher.put(accel_block(seq).bytes()).wait().unwrap();
    }
    std::thread::sleep(Duration::from_millis(300));
    drop(stuck);
    // A last block after the burst has drained, so that a drop at the burst's end is
    // a gap too.
    std::thread::sleep(Duration::from_millis(1500));
    publisher.put(accel_block(BURST).bytes()).wait().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    drop(publisher);
    session.close().wait().unwrap();
    let b = br.summary();
    let c = comp.summary();
    let s = &b["streams"][0];
    let dropped = s["queue_dropped"].as_u64().unwrap();
    assert!(dropped > 0, "{b}");
    assert_eq!(s["forwarded"].as_u64().unwrap() + dropped, BURST + 1, "{b}");
    assert_eq!(s["gap_messages"], 0, "{b}");
    assert_eq!(
        c["accel"]["received"].as_u64().unwrap() + dropped,
        BURST + 1,
        "{c}"
    );
    assert_eq!(c["accel"]["lost_messages"], dropped, "{c}");
    assert_eq!(c["accel"]["lost_samples"], dropped * 32, "{c}");
}

/// A CA and certificates for `names` (common name = the name, valid for localhost and
/// 127.0.0.1), made with the `openssl` command line in `dir`.
fn certificates(dir: &Dir, names: &[&str]) {
    let run = |args: &[&str]| {
        let out = Command::new("openssl")
            .current_dir(&dir.0)
            .args(args)
            .output()
            .expect("openssl runs");
        assert!(
            out.status.success(),
            "openssl {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let ec = [
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
    ];
    let mut ca = vec!["req", "-x509"];
    ca.extend(ec);
    ca.extend([
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        "2",
        "-subj",
        "/CN=vibrocomp-test-ca",
    ]);
    run(&ca);
    std::fs::write(
        dir.path("ext.cnf"),
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\nkeyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n",
    )
    .unwrap();
    for n in names {
        let (key, csr, pem, subj) = (
            format!("{n}.key"),
            format!("{n}.csr"),
            format!("{n}.pem"),
            format!("/CN={n}"),
        );
        let mut req = vec!["req"];
        req.extend(ec);
        req.extend(["-keyout", &key, "-out", &csr, "-subj", &subj]);
        run(&req);
        run(&[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-out",
            &pem,
            "-days",
            "2",
            "-extfile",
            "ext.cnf",
        ]);
    }
}

/// A Zenoh peer over TLS to `tls/localhost:{port}` with the certificate of `name`
/// (none: no client certificate), or the error of opening it.
fn tls_peer(dir: &Dir, port: u16, name: Option<&str>) -> zenoh::Result<zenoh::Session> {
    let mut zc = zenoh::Config::default();
    let q = |p: PathBuf| format!("{:?}", p.display().to_string());
    zc.insert_json5("mode", "\"peer\"").unwrap();
    zc.insert_json5("connect/endpoints", &format!("[\"tls/localhost:{port}\"]"))
        .unwrap();
    zc.insert_json5("connect/timeout_ms", "1500").unwrap();
    zc.insert_json5("connect/exit_on_failure", "true").unwrap();
    zc.insert_json5("listen/endpoints", "[]").unwrap();
    zc.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zc.insert_json5(
        "transport/link/tls/root_ca_certificate",
        &q(dir.path("ca.pem")),
    )
    .unwrap();
    if let Some(n) = name {
        zc.insert_json5("transport/link/tls/enable_mtls", "true")
            .unwrap();
        zc.insert_json5(
            "transport/link/tls/connect_certificate",
            &q(dir.path(&format!("{n}.pem"))),
        )
        .unwrap();
        zc.insert_json5(
            "transport/link/tls/connect_private_key",
            &q(dir.path(&format!("{n}.key"))),
        )
        .unwrap();
    }
    zenoh::open(zc).wait()
}

/// Who may connect: a bridge with mutual TLS and `[access] allow_cert_common_names =
/// ["rig-a"]` takes blocks from `rig-a`; a peer whose certificate (signed by the same
/// CA) says `intruder` is connected but refused by Zenoh's access control (its
/// publisher is never matched, nothing it puts arrives; with `intruder` named too, this
/// test fails there); a peer without a certificate fails the TLS handshake.
#[test]
fn a_tls_bridge_takes_only_the_clients_its_configuration_names() {
    let dir = Dir::new("tls");
    certificates(&dir, &["compute-1", "rig-a", "intruder"]);
    let prefix = prefix("t");
    let port = free_port().unwrap();
    let key_prefix = format!("vibrocomp/tls{}", next_id());
    let p = |n: &str| dir.path(n).display().to_string();
    let config = write(
        &dir.path("b.toml"),
        &format!(
            "prefix = {prefix:?}\nkey_prefix = {key_prefix:?}\n[zenoh]\nmode = \"peer\"\nlisten = [\"tls/127.0.0.1:{port}\"]\nconnect_timeout_s = 5.0\n[import]\nstreams = [\"accel\"]\n[tls]\nroot_ca_certificate = {:?}\ncertificate = {:?}\nprivate_key = {:?}\nmutual = true\n[access]\nallow_cert_common_names = [\"rig-a\"]\n",
            p("ca.pem"),
            p("compute-1.pem"),
            p("compute-1.key")
        ),
    );
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-tls").unwrap();
    let accel = StreamSubscriber::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let br = bridge(&config, &dir);
    let key = format!("{key_prefix}/accel");
    let encoding = vibro_bridge::encoding_of(vibro_msgs::MessageKind::AccelBlock);

    // Named: matched, and its blocks arrive.
    let rig = {
        let start = Instant::now();
        loop {
            match tls_peer(&dir, port, Some("rig-a")) {
                Ok(s) => break s,
                Err(_) if start.elapsed() < Duration::from_secs(10) => {
                    std::thread::sleep(Duration::from_millis(100));
                }
                Err(e) => panic!("rig-a could not connect: {e}\n{}", br.stderr()),
            }
        }
    };
    let publisher = rig
        .declare_publisher(key.clone())
        .encoding(encoding.clone())
        .wait()
        .unwrap();
    wait_until("the bridge matching rig-a", Duration::from_secs(10), || {
        publisher.matching_status().wait().unwrap().matching()
    });
    for seq in 0..3 {
        publisher.put(accel_block(seq).bytes()).wait().unwrap();
    }
    let mut got = Vec::new();
    wait_until("rig-a's 3 blocks", Duration::from_secs(10), || {
        while let Some(b) = accel.receive().unwrap() {
            got.push(b.seq);
        }
        got.len() >= 3
    });
    assert_eq!(got, [0, 1, 2]);

    // Not named: connected by TLS, refused by access control.
    let intruder =
        tls_peer(&dir, port, Some("intruder")).expect("the TLS handshake itself succeeds");
    let p2 = intruder
        .declare_publisher(key.clone())
        .encoding(encoding)
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    assert!(
        !p2.matching_status().wait().unwrap().matching(),
        "the intruder was matched"
    );
    for seq in 3..6 {
        p2.put(accel_block(seq).bytes()).wait().unwrap();
    }
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        accel.receive().unwrap().is_none(),
        "a block of the intruder arrived"
    );

    // No certificate: the handshake fails.
    assert!(
        tls_peer(&dir, port, None).is_err(),
        "a peer without a certificate connected"
    );

    drop((publisher, p2));
    let _ = rig.close().wait();
    let _ = intruder.close().wait();
    let b = br.summary();
    assert_eq!(b["streams"][0]["forwarded"], 3, "{b}");
}

/// Issue 46, item 6: a peer sends accelerometer blocks 0..=10, a forged 500,000, then
/// 11..=60. Before, the bridge counted 499,989 messages lost on the network. By the
/// services' rule (vibro_msgs::continuity) the forged step's loss is taken back when
/// the stream resumes: nothing lost, one resync, 11..=13 out of order (forwarded all
/// the same: the service behind applies the rule itself). The reference is the list of
/// `seq`s this test put: every real block 0..=60 sent, none missing.
#[test]
fn a_forged_seq_ahead_from_the_network_is_taken_back_not_lost() {
    let dir = Dir::new("forged");
    let prefix = prefix("f");
    let (config, endpoint, key_prefix) =
        listening_config(&dir, &prefix, "forged", "[import]\nstreams = [\"accel\"]\n");
    let names = ServiceNames::new(&prefix).unwrap();
    let node = create_node("vcb-forged").unwrap();
    let local = StreamSubscriber::<AccelBlock>::open(&node, &names, Stream::Accel).unwrap();
    let br = bridge(&config, &dir);
    let (session, publisher) = remote_accel_publisher(&endpoint, &key_prefix);
    let seqs: Vec<u64> = (0..=10).chain([500_000]).chain(11..=60).collect();
    for &seq in &seqs {
        // The forged one carries block 11's samples.
        let mut b = accel_block(seq.min(11));
        b.seq = seq;
        publisher.put(b.bytes()).wait().unwrap();
    }
    let mut got = Vec::new();
    wait_until("the blocks in iceoryx2", Duration::from_secs(10), || {
        while let Some(b) = local.receive().unwrap() {
            got.push(b.seq);
        }
        got.len() >= seqs.len()
    });
    assert_eq!(got, seqs, "the bridge forwards every block");
    drop(publisher);
    session.close().wait().unwrap();
    let b = br.summary();
    let s = &b["streams"][0];
    // Every real block was sent: none lost on the network.
    assert_eq!(s["gap_messages"], 0, "{b}");
    assert_eq!(s["retracted"], 499_989, "{b}");
    assert_eq!(s["resyncs"], 1, "{b}");
    assert_eq!(s["out_of_order"], 3, "{b}");
    assert_eq!(s["seq_jumps"], 0, "{b}");
    assert_eq!(s["forwarded"], seqs.len() as u64, "{b}");
    assert_eq!(b["lost"], 0, "{b}");
    eprintln!("FIGURES bridge-forged-seq: {s}");
}
