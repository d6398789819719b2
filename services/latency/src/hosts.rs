//! `latency --hosts 2`: the vibrocomp pipeline across two hosts on this machine (the
//! services in another iceoryx2 root, only two Zenoh bridges over a Unix socket between
//! it and the rig), and its baseline, a bare Zenoh publisher/subscriber pair.
//!
//! The rig (this process) stays in its own iceoryx2 root: host A, with host A's bridge
//! in it. Host B is a folder of its own (`vibro_system::hosts::TwoHosts`) where the
//! estimator, the compensator and host B's bridge run. One machine, one
//! `CLOCK_MONOTONIC`: the hops' stamps compare as in the local pipelines, and
//! `rig -> service` and `service -> subscriber` now include a bridge each way.
//!
//! The baseline: two Zenoh sessions in two processes, the rig's listening on a free
//! loopback port and a peer (`latency-peer bare-zenoh`) connected to it, with the
//! messages of the pipeline: the rig puts accelerometer blocks (answered by the peer
//! with a compensated-block-sized message carrying the stamps) and vibration blocks
//! (taken and dropped): Zenoh's own cost for the same traffic, two hops per answer, no
//! iceoryx2 and no computation.
//! Its publishers are `express` (not batched), as the bridge's are.

use anyhow::Context;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use vibro_ipc::now_ns;
use vibro_msgs::{
    AccelBlock, CompensatedBlock, Heartbeat, ServiceId, ServiceNames, Stream, WireMessage,
};
use zenoh::Wait;

use vibro_service::supervise::{private_prefix, wait_for_heartbeats};
use vibro_system::hosts::{free_port, TwoHosts};
use vibro_system::Role;

use crate::cpu::Cpu;
use crate::histogram::Stamps;
use crate::peers::{spawn_peer, KillOnDrop};
use crate::pipelines::{bridge_losses, service_losses, spec_for, summarize, PipelineRun};
use crate::rig::{pace, run_iceoryx, RigStream};
use crate::Options;

/// The vibrocomp pipeline with the services on host B.
pub(crate) fn run_bridged(
    opts: &Options,
    k1: [f64; 3],
    log: &Path,
    (estimator_config, compensator_config): (Option<&Path>, Option<&Path>),
) -> anyhow::Result<PipelineRun> {
    let prefix = private_prefix("vclatz");
    let base = std::env::temp_dir().join(format!("vibrocomp-latency-{}-hosts", std::process::id()));
    let tag = format!("vcl{}", std::process::id());
    let hosts = TwoHosts::create(&base, &tag, &prefix)?;
    let result = (|| {
        let mut spec_b = spec_for(&prefix, opts.mode, opts.realtime_priority);
        spec_b.estimator_config = estimator_config.map(Path::to_path_buf);
        spec_b.compensator_config = match compensator_config {
            Some(p) => Some(p.to_path_buf()),
            None => std::fs::canonicalize(
                <vibro_compensator::Config as vibro_service::ServiceConfig>::DEFAULT_CONFIG_PATH,
            )
            .ok(),
        };
        spec_b.cwd = Some(hosts.b.dir.clone());
        spec_b.bridge = Some(hosts.b.bridge_config.clone());
        // Host A's bridge: in this process's iceoryx2 root.
        let mut spec_a = spec_for(&prefix, opts.mode, opts.realtime_priority);
        spec_a.bridge = Some(hosts.a.bridge_config.clone());
        let mut bridge_b = spec_b.spawn(Role::Bridge, Some(log))?;
        let mut est = spec_b.spawn(Role::Estimator, Some(log))?;
        let mut comp = spec_b.spawn(Role::Compensator, Some(log))?;
        let mut bridge_a = spec_a.spawn(Role::Bridge, Some(log))?;
        wait_for_heartbeats(
            &ServiceNames::new(&prefix)?,
            &[ServiceId::Estimator, ServiceId::Compensator],
            Duration::from_secs(30),
            || {
                bridge_b.check_alive()?;
                bridge_a.check_alive()?;
                est.check_alive()?;
                comp.check_alive()
            },
        )
        .context("the services on host B, through the bridges")?;
        let cpu = Cpu::start(&[
            ("estimator", est.pid()),
            ("compensator", comp.pid()),
            ("bridge A", bridge_a.pid()),
            ("bridge B", bridge_b.pid()),
            ("rig", std::process::id()),
        ]);
        // The estimator's progress, bridged back to this host: read after the rig
        // stops, so that the services are stopped only once the last vibration
        // blocks crossed the bridges.
        let node = vibro_ipc::create_node("vibrocomp-latency-progress")?;
        let progress = vibro_ipc::StreamSubscriber::<Heartbeat>::open(
            &node,
            &ServiceNames::new(&prefix)?,
            Stream::Progress(ServiceId::Estimator),
        )?;
        let (ka, kv, stamps) = run_iceoryx(opts, &prefix, k1)?;
        wait_received(&progress, kv, Duration::from_secs(5))?;
        let cpu = cpu.finish();
        let timeout = Duration::from_secs(10);
        let c = comp.stop(timeout)?.summary()?;
        let e = est.stop(timeout)?.summary()?;
        let ba = bridge_a.stop(timeout)?.summary()?;
        let bb = bridge_b.stop(timeout)?.summary()?;
        let mut lost = service_losses("compensator", &c, "accel");
        lost.extend(service_losses("estimator", &e, "vib"));
        lost.extend(bridge_losses("bridge A", &ba));
        lost.extend(bridge_losses("bridge B", &bb));
        let mut run = summarize(
            "vibrocomp, 2 hosts (iceoryx2 + Zenoh bridges over a Unix socket)",
            opts,
            (ka, kv, &stamps),
            lost,
            cpu,
        )?;
        run.stage = c["stage"].as_str().map(str::to_string);
        run.waveform = c.get("waveform").cloned();
        Ok(run)
    })();
    drop(hosts);
    let _ = std::fs::remove_dir_all(&base);
    result
}

/// Waits until the service whose progress `sub` reads has received `at_least`
/// messages, or `timeout` has passed. The rig's last blocks may still be crossing the
/// bridges when it stops (the accelerometer blocks were all answered, the vibration
/// blocks go at twice their rate): a service stopped before they arrive leaves them to
/// its bridge as undelivered, counted lost (seen as 2 lost blocks in about one run
/// in ten). Past the timeout the run goes on and reports what was lost.
fn wait_received(
    sub: &vibro_ipc::StreamSubscriber<Heartbeat>,
    at_least: u64,
    timeout: Duration,
) -> anyhow::Result<()> {
    let start = std::time::Instant::now();
    let mut received = 0;
    while received < at_least && start.elapsed() < timeout {
        while let Some(p) = sub.receive()? {
            received = received.max(p.received);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(())
}

fn session(endpoint: (&str, &str)) -> anyhow::Result<zenoh::Session> {
    let mut c = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, k: &str, v: &str| {
        c.insert_json5(k, v)
            .map_err(|e| anyhow::anyhow!("zenoh config {k} = {v}: {e}"))
    };
    set(&mut c, "mode", "\"peer\"")?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "transport/shared_memory/enabled", "false")?;
    let (which, ep) = endpoint;
    set(
        &mut c,
        &format!("{which}/endpoints"),
        &format!("[\"{ep}\"]"),
    )?;
    if which == "connect" {
        set(&mut c, "listen/endpoints", "[]")?;
        set(&mut c, "connect/timeout_ms", "10000")?;
        set(&mut c, "connect/exit_on_failure", "true")?;
    }
    zenoh::open(c)
        .wait()
        .map_err(|e| anyhow::anyhow!("opening a Zenoh session on {ep}: {e}"))
}

/// The bare Zenoh baseline's peer process: answers each accelerometer block with a
/// compensated-block-sized message holding the stamps, takes the vibration blocks.
pub(crate) fn peer_bare_zenoh(
    endpoint: &str,
    key: &str,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> anyhow::Result<()> {
    let peer = session(("connect", endpoint))?;
    let zerr = |what: &'static str| move |e: zenoh::Error| anyhow::anyhow!("{what}: {e}");
    let answer = peer
        .declare_publisher(format!("{key}/compensated"))
        .express(true)
        .wait()
        .map_err(zerr("declare the answer publisher"))?;
    let _accel_in = peer
        .declare_subscriber(format!("{key}/accel"))
        .callback(move |s| {
            let recv_ns = now_ns();
            let bytes = s.payload().to_bytes();
            let Some(a) = AccelBlock::from_bytes(&bytes) else {
                return;
            };
            let mut out = CompensatedBlock::ZEROED;
            out.input_seq = a.seq;
            out.t0_ns = a.t0_ns;
            out.count = a.count;
            out.input_publish_ns = a.publish_ns;
            out.recv_ns = recv_ns;
            out.publish_ns = now_ns();
            let _ = answer.put(out.bytes()).wait();
        })
        .wait()
        .map_err(zerr("declare the accel subscriber"))?;
    let _vib_in = peer
        .declare_subscriber(format!("{key}/vib"))
        .callback(|s| {
            std::hint::black_box(s.payload().len());
        })
        .wait()
        .map_err(zerr("declare the vib subscriber"))?;
    while !stop.load(std::sync::atomic::Ordering::Acquire) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = peer.close().wait();
    Ok(())
}

/// The bare Zenoh baseline: this process (the rig) listens, the peer process connects.
pub(crate) fn run_bare_zenoh(
    opts: &Options,
    k1: [f64; 3],
    log: &Path,
) -> anyhow::Result<PipelineRun> {
    let port = free_port()?;
    let ep = format!("tcp/127.0.0.1:{port}");
    let rig = session(("listen", &ep))?;
    let key = format!("vibrocomp/latency-{}", std::process::id());
    let zerr = |what: &'static str| move |e: zenoh::Error| anyhow::anyhow!("{what}: {e}");
    let mut child = spawn_peer(
        &["bare-zenoh", "--endpoint", &ep, "--key", &key],
        log,
        "the bare Zenoh peer",
    )?;
    let peer = KillOnDrop(Some(&mut child));
    // The rig's receiver.
    let capacity = (opts.duration_s * opts.rate_hz / f64::from(opts.block_samples)) as usize + 16;
    let stamps = Arc::new(Mutex::new(Vec::<Stamps>::with_capacity(capacity)));
    let _answers = rig
        .declare_subscriber(format!("{key}/compensated"))
        .callback({
            let stamps = Arc::clone(&stamps);
            move |s| {
                let sub_recv_ns = now_ns();
                let bytes = s.payload().to_bytes();
                if let Some(b) = CompensatedBlock::from_bytes(&bytes) {
                    if let Ok(mut v) = stamps.lock() {
                        v.push(Stamps::of(&b, sub_recv_ns));
                    }
                }
            }
        })
        .wait()
        .map_err(zerr("declare the answer subscriber"))?;
    let accel = rig
        .declare_publisher(format!("{key}/accel"))
        .express(true)
        .wait()
        .map_err(zerr("declare the accel publisher"))?;
    let vib = rig
        .declare_publisher(format!("{key}/vib"))
        .express(true)
        .wait()
        .map_err(zerr("declare the vib publisher"))?;
    let t = std::time::Instant::now();
    let matched = |p: &zenoh::pubsub::Publisher<'_>| {
        p.matching_status()
            .wait()
            .map(|m| m.matching())
            .unwrap_or(false)
    };
    while !(matched(&accel) && matched(&vib)) {
        anyhow::ensure!(
            t.elapsed() < Duration::from_secs(10),
            "the bare Zenoh peer did not subscribe within 10 s (its log: {})",
            log.display()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // Its answer publisher reaches this subscriber too.
    std::thread::sleep(Duration::from_millis(300));
    let cpu = Cpu::start(&[("peer", peer.pid()), ("rig", std::process::id())]);
    let mut stream = RigStream::new(opts, k1);
    let (ka, kv) = pace(
        opts,
        &mut stream,
        |b| accel.put(b.bytes()).wait().map_err(zerr("put accel")),
        |b| vib.put(b.bytes()).wait().map_err(zerr("put vib")),
    )?;
    std::thread::sleep(Duration::from_millis(300));
    let cpu = cpu.finish();
    drop(peer);
    let stamps = stamps
        .lock()
        .map_err(|_| anyhow::anyhow!("the answer subscriber panicked"))?
        .clone();
    drop((accel, vib));
    let _ = rig.close().wait();
    summarize(
        "bare Zenoh (2 processes, loopback TCP)",
        opts,
        (ka, kv, &stamps),
        Vec::new(),
        cpu,
    )
}
