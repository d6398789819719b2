//! The pipelines of a latency run: vibrocomp's services, bare iceoryx2 and Unix
//! sockets (and, with two hosts, [`crate::hosts`]'s), each measured by the rig.

use anyhow::Context;
use serde::Serialize;
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vibro_ipc::now_ns;
use vibro_msgs::{CompensatedBlock, ServiceId, ServiceNames};
use vibro_service::supervise::{private_prefix, wait_for_heartbeats};
use vibro_service::LoopMode;
use vibro_system::{Role, SystemSpec};

use crate::cpu::Cpu;
use crate::histogram::{hop, Histograms, HopUs, Stamps};
use crate::memory::{MemorySampler, MemorySeries};
use crate::peers::{spawn_peer, KillOnDrop};
use crate::rig::{pace, run_iceoryx, RigStream};
use crate::view::{view_client, ViewLoad};
use crate::{hosts, Options};

/// One pipeline's run.
#[derive(Debug, Clone, Serialize)]
pub struct PipelineRun {
    pub pipeline: &'static str,
    pub accel_blocks_sent: u64,
    pub vib_blocks_sent: u64,
    pub compensated_received: u64,
    /// Accelerometer samples without a compensated output (must be 0).
    pub lost_samples: u64,
    /// Every loss counter of the pipeline's processes that was not 0 at the end of
    /// the run, named by process and counter (must be empty).
    pub losses: Vec<Loss>,
    pub rig_to_service: HopUs,
    pub processing: HopUs,
    pub service_to_subscriber: HopUs,
    pub end_to_end: HopUs,
    /// Rig publish of the accelerometer block -> service publish (rig -> service and
    /// processing together): with the compensator's waveform stage, the wait for the
    /// vibration block covering the block's end is in it.
    pub input_to_publish: HopUs,
    /// Rig publish of the last input a block needed -> service publish: for a block
    /// the waveform stage made, the later of its accelerometer block and the newest
    /// vibration block before its publish (the samples that released it); for the
    /// others, its accelerometer block. One transport hop and the service's work,
    /// without the wait for the samples.
    pub last_input_to_publish: HopUs,
    /// The compensator's stage (`waveform` or `estimate`, from its summary; `None`
    /// for the baselines).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<String>,
    /// Compensated blocks after the warm-up made by the waveform stage (flag
    /// `WAVEFORM`, bit 11), over all compensated blocks after the warm-up.
    pub waveform_fraction: f64,
    /// The compensator's waveform-stage counters (its summary's `waveform`: blocks
    /// solved, fallbacks by reason, most blocks held), when it ran the stage.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub waveform: Option<serde_json::Value>,
    /// Percent of one core over the run.
    pub cpu_percent: Vec<(String, f64)>,
    /// With `--view`: the live view and its client over the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<ViewLoad>,
}

/// A loss counter that was not 0 when a process stopped: which process, which
/// counter (its path in the process's JSON summary) and how many, in the counter's
/// own unit (messages, samples or blocks, as its name says).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Loss {
    pub process: String,
    pub counter: String,
    pub count: u64,
}

/// A service's loss counters on its input `stream` and its undelivered outputs.
pub(crate) fn service_losses(
    process: &str,
    summary: &serde_json::Value,
    stream: &str,
) -> Vec<Loss> {
    let counters = [
        (
            format!("{stream}.lost_messages"),
            &summary[stream]["lost_messages"],
        ),
        (
            format!("{stream}.lost_samples"),
            &summary[stream]["lost_samples"],
        ),
        ("undelivered".to_string(), &summary["undelivered"]),
    ];
    nonzero(process, counters)
}

/// A bridge's loss counters, stream by stream (`StreamReport::lost`'s terms).
pub(crate) fn bridge_losses(process: &str, summary: &serde_json::Value) -> Vec<Loss> {
    let mut out = Vec::new();
    for s in summary["streams"].as_array().into_iter().flatten() {
        let name = s["stream"].as_str().unwrap_or("?");
        let dir = s["direction"].as_str().unwrap_or("?");
        let counters = [
            "unmatched",
            "gap_messages",
            "queue_dropped",
            "refused",
            "undelivered",
        ]
        .map(|k| (format!("{name} ({dir}).{k}"), &s[k]));
        out.extend(nonzero(process, counters));
    }
    out
}

fn nonzero<'a>(
    process: &str,
    counters: impl IntoIterator<Item = (String, &'a serde_json::Value)>,
) -> Vec<Loss> {
    counters
        .into_iter()
        .filter_map(|(counter, v)| {
            let count = v.as_u64().unwrap_or(0);
            (count > 0).then(|| Loss {
                process: process.to_string(),
                counter,
                count,
            })
        })
        .collect()
}

/// The vibrocomp pipeline against the baselines, end to end.
#[derive(Debug, Clone, Serialize)]
pub struct Ratios {
    /// vibrocomp end to end over bare iceoryx2 end to end.
    pub vs_bare_p50: f64,
    pub vs_bare_p99: f64,
    /// What our processing adds to the bare hop, us (end to end).
    pub added_p50_us: f64,
    pub added_p99_us: f64,
    pub vs_sockets_p50: f64,
    pub vs_sockets_p99: f64,
}

impl Ratios {
    /// vibrocomp's end to end against bare iceoryx2's and the sockets'.
    pub fn new(vibrocomp: &HopUs, bare: &HopUs, sockets: &HopUs) -> Self {
        let (v, b, u) = (vibrocomp, bare, sockets);
        Self {
            vs_bare_p50: v.p50_us / b.p50_us,
            vs_bare_p99: v.p99_us / b.p99_us,
            added_p50_us: v.p50_us - b.p50_us,
            added_p99_us: v.p99_us - b.p99_us,
            vs_sockets_p50: v.p50_us / u.p50_us,
            vs_sockets_p99: v.p99_us / u.p99_us,
        }
    }
}

/// The pipelines' runs (`vibrocomp latency` without `--soak`).
#[derive(Debug, Clone, Serialize)]
pub struct LatencyReport {
    pub mode: String,
    pub duration_s: f64,
    pub rate_hz: f64,
    pub block_samples: u32,
    pub vib_rate_hz: f64,
    pub vib_block_samples: u32,
    /// vibrocomp first; then, with the baselines, bare iceoryx2 and Unix sockets; then,
    /// with two hosts, vibrocomp across them and (with the baselines) bare Zenoh.
    pub runs: Vec<PipelineRun>,
    /// With the baselines.
    pub ratios: Option<Ratios>,
}

pub(crate) fn run_pipelines(
    opts: &Options,
    k1: [f64; 3],
    log: &Path,
    prefix: &str,
    (estimator_config, compensator_config): (Option<&Path>, Option<&Path>),
) -> anyhow::Result<LatencyReport> {
    let configs = (estimator_config, compensator_config);
    let mut runs = vec![run_vibrocomp(opts, k1, log, prefix, configs)?.run];
    if opts.baselines {
        runs.push(run_bare(opts, k1, log)?);
        runs.push(run_uds(opts, k1, log, estimator_config)?);
    }
    if opts.two_hosts {
        runs.push(hosts::run_bridged(opts, k1, log, configs)?);
        if opts.baselines {
            runs.push(hosts::run_bare_zenoh(opts, k1, log)?);
        }
    }
    let ratios = (opts.baselines && runs.len() >= 3).then(|| {
        Ratios::new(
            &runs[0].end_to_end,
            &runs[1].end_to_end,
            &runs[2].end_to_end,
        )
    });
    Ok(LatencyReport {
        mode: opts.mode.as_str().to_string(),
        duration_s: opts.duration_s,
        rate_hz: opts.rate_hz,
        block_samples: opts.block_samples,
        vib_rate_hz: opts.vib_rate_hz,
        vib_block_samples: opts.vib_block_samples,
        runs,
        ratios,
    })
}

pub(crate) fn summarize(
    pipeline: &'static str,
    opts: &Options,
    (ka, kv, stamps): (u64, u64, &[Stamps]),
    losses: Vec<Loss>,
    cpu_percent: Vec<(String, f64)>,
) -> anyhow::Result<PipelineRun> {
    let mut h = Histograms::new()?;
    let warmup_ns = (opts.warmup_s * 1e9) as u64;
    for s in stamps.iter().filter(|s| s.t0_ns >= warmup_ns) {
        h.record(s);
    }
    let received: u64 = stamps.iter().map(|s| u64::from(s.count)).sum();
    let sent = ka * u64::from(opts.block_samples);
    Ok(PipelineRun {
        pipeline,
        accel_blocks_sent: ka,
        vib_blocks_sent: kv,
        compensated_received: stamps.len() as u64,
        lost_samples: sent.saturating_sub(received),
        losses,
        rig_to_service: hop(&h.rig_to_service),
        processing: hop(&h.processing),
        service_to_subscriber: hop(&h.service_to_subscriber),
        end_to_end: hop(&h.end_to_end),
        input_to_publish: hop(&h.input_to_publish),
        last_input_to_publish: hop(&h.last_input_to_publish),
        stage: None,
        waveform_fraction: if h.blocks > 0 {
            h.waveform_blocks as f64 / h.blocks as f64
        } else {
            0.0
        },
        waveform: None,
        cpu_percent,
        view: None,
    })
}

pub(crate) fn spec_for(prefix: &str, mode: LoopMode, realtime_priority: Option<u8>) -> SystemSpec {
    SystemSpec {
        prefix: prefix.to_string(),
        mode: Some(mode.as_str().to_string()),
        realtime_priority,
        json: true,
        ..SystemSpec::default()
    }
}

pub(crate) fn losses(summary: &serde_json::Value, stream: &str) -> u64 {
    let g = |k: &str| summary[stream][k].as_u64().unwrap_or(0);
    g("lost_messages") + g("lost_samples") + summary["undelivered"].as_u64().unwrap_or(0)
}

/// The vibrocomp pipeline's run, with what the soak reads beside the hops.
pub(crate) struct VibrocompRun {
    pub(crate) run: PipelineRun,
    pub(crate) stamps: Vec<Stamps>,
    /// The services' JSON summaries at exit.
    pub(crate) compensator: serde_json::Value,
    pub(crate) estimator: serde_json::Value,
    /// The services' resident memory, sampled every second while the rig ran.
    pub(crate) memory: Vec<MemorySeries>,
}

pub(crate) fn run_vibrocomp(
    opts: &Options,
    k1: [f64; 3],
    log: &Path,
    prefix: &str,
    (estimator_config, compensator_config): (Option<&Path>, Option<&Path>),
) -> anyhow::Result<VibrocompRun> {
    let mut spec = spec_for(prefix, opts.mode, opts.realtime_priority);
    spec.estimator_config = estimator_config.map(Path::to_path_buf);
    spec.compensator_config = compensator_config.map(Path::to_path_buf);
    let mut est = spec.spawn(Role::Estimator, Some(log))?;
    let mut comp = spec.spawn(Role::Compensator, Some(log))?;
    wait_for_heartbeats(
        &ServiceNames::new(prefix)?,
        &[ServiceId::Estimator, ServiceId::Compensator],
        Duration::from_secs(30),
        || {
            est.check_alive()?;
            comp.check_alive()
        },
    )?;
    let mut pids = vec![
        ("estimator", est.pid()),
        ("compensator", comp.pid()),
        ("rig", std::process::id()),
    ];
    // With --view: the live view and a client reading everything, before the rig starts.
    let mut viewer = None;
    if opts.view {
        let listen = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .context("a free port on 127.0.0.1 for the view")?;
        spec.foxglove = Some(listen);
        let view = spec.spawn(Role::View, Some(log))?;
        pids.push(("view", view.pid()));
        let stop = Arc::new(AtomicBool::new(false));
        let client = view_client(listen, Arc::clone(&stop));
        // Subscribed before the first block: the advertisement comes on connection.
        std::thread::sleep(Duration::from_millis(500));
        viewer = Some((listen, view, stop, client));
    }
    let cpu = Cpu::start(&pids);
    let memory = MemorySampler::start(&pids[..2]);
    let result = run_iceoryx(opts, prefix, k1);
    let memory = memory.finish();
    let (ka, kv, stamps) = result?;
    let cpu = cpu.finish();
    let view = match viewer {
        Some((listen, view, stop, client)) => {
            // The view's last messages out, then the client and the view stopped.
            std::thread::sleep(Duration::from_millis(300));
            stop.store(true, Ordering::Release);
            let (client_channels, client_messages) = client
                .join()
                .map_err(|_| anyhow::anyhow!("the view client panicked"))??;
            let view_summary = view.stop(Duration::from_secs(10))?.summary()?;
            Some(ViewLoad {
                listen: listen.to_string(),
                client_channels,
                client_messages,
                view_summary,
            })
        }
        None => None,
    };
    let c = comp.stop(Duration::from_secs(10))?.summary()?;
    let e = est.stop(Duration::from_secs(10))?.summary()?;
    let mut lost = service_losses("compensator", &c, "accel");
    lost.extend(service_losses("estimator", &e, "vib"));
    let name = if view.is_some() {
        "vibrocomp (iceoryx2), live view + 1 client"
    } else {
        "vibrocomp (iceoryx2)"
    };
    let mut run = summarize(name, opts, (ka, kv, &stamps), lost, cpu)?;
    run.view = view;
    run.stage = c["stage"].as_str().map(str::to_string);
    run.waveform = c.get("waveform").cloned();
    Ok(VibrocompRun {
        run,
        stamps,
        compensator: c,
        estimator: e,
        memory,
    })
}

fn run_bare(opts: &Options, k1: [f64; 3], log: &Path) -> anyhow::Result<PipelineRun> {
    let prefix = private_prefix("vcbare");
    let spawn = |peer: &str, what: &str| {
        spawn_peer(
            &[peer, "--prefix", &prefix, "--mode", opts.mode.as_str()],
            log,
            &format!("the bare {what}"),
        )
    };
    // Both streams travel, as in the vibrocomp pipeline: the forwarder answers the
    // accelerometer blocks, the sink takes the vibration blocks (the estimator's
    // process, without the estimation).
    let mut forwarder = spawn("bare", "forwarder")?;
    let forwarder = KillOnDrop(Some(&mut forwarder));
    let mut sink = spawn("bare-vib", "vibration sink")?;
    let sink = KillOnDrop(Some(&mut sink));
    wait_for_heartbeats(
        &ServiceNames::new(&prefix)?,
        &[ServiceId::Compensator, ServiceId::Estimator],
        Duration::from_secs(30),
        || Ok(()),
    )?;
    let cpu = Cpu::start(&[
        ("vibration sink", sink.pid()),
        ("forwarder", forwarder.pid()),
        ("rig", std::process::id()),
    ]);
    let (ka, kv, stamps) = run_iceoryx(opts, &prefix, k1)?;
    let cpu = cpu.finish();
    drop(sink);
    drop(forwarder);
    summarize("bare iceoryx2", opts, (ka, kv, &stamps), Vec::new(), cpu)
}

fn connect(path: &Path) -> anyhow::Result<UnixStream> {
    let t = Instant::now();
    loop {
        match UnixStream::connect(path) {
            Ok(s) => return Ok(s),
            Err(_) if t.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(e) => return Err(e).with_context(|| format!("connecting to {}", path.display())),
        }
    }
}

fn run_uds(
    opts: &Options,
    k1: [f64; 3],
    log: &Path,
    estimator_config: Option<&Path>,
) -> anyhow::Result<PipelineRun> {
    let dir = std::env::temp_dir().join(format!("vibrocomp-uds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut args: Vec<std::ffi::OsString> =
        vec!["uds".into(), "--socket-dir".into(), dir.clone().into()];
    if let Some(c) = estimator_config {
        args.extend(["--estimator-config".into(), c.into()]);
    }
    let mut child = spawn_peer(&args, log, "the socket peer")?;
    let guard = KillOnDrop(Some(&mut child));
    let mut vib_sock = connect(&dir.join("vib.sock"))?;
    let mut accel_sock = connect(&dir.join("accel.sock"))?;
    let mut reader = accel_sock.try_clone()?;
    let pid = guard.pid();
    let cpu = Cpu::start(&[("uds peer", pid), ("rig", std::process::id())]);
    let expected = (opts.duration_s * opts.rate_hz / f64::from(opts.block_samples)) as usize;
    let rx = std::thread::spawn(move || -> anyhow::Result<Vec<Stamps>> {
        let mut out = Vec::with_capacity(expected + 16);
        let mut buf = vec![0u8; std::mem::size_of::<CompensatedBlock>()];
        loop {
            match reader.read_exact(&mut buf) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(out),
                Err(e) => return Err(e.into()),
            }
            let sub_recv_ns = now_ns();
            let b = CompensatedBlock::from_bytes(&buf).context("compensated block size")?;
            out.push(Stamps::of(&b, sub_recv_ns));
        }
    });
    let mut stream = RigStream::new(opts, k1);
    let (ka, kv) = pace(
        opts,
        &mut stream,
        |b| accel_sock.write_all(b.as_bytes()).map_err(Into::into),
        |b| vib_sock.write_all(b.as_bytes()).map_err(Into::into),
    )?;
    std::thread::sleep(Duration::from_millis(300));
    // Closing the rig's ends stops the peer, which closes its answers: EOF.
    let _ = vib_sock.shutdown(std::net::Shutdown::Both);
    let _ = accel_sock.shutdown(std::net::Shutdown::Write);
    let mut stamps = rx
        .join()
        .map_err(|_| anyhow::anyhow!("the socket receiver panicked"))??;
    stream.stamp_vib(&mut stamps);
    let cpu = cpu.finish();
    drop(guard);
    let _ = std::fs::remove_dir_all(&dir);
    summarize("Unix sockets", opts, (ka, kv, &stamps), Vec::new(), cpu)
}
