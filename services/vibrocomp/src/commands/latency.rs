//! `vibrocomp latency`: how late a compensated sample arrives, and how much of that is
//! ours.
//!
//! The command is the rig: it publishes vibration-sensor and accelerometer blocks in
//! real time at the given rates and receives the compensated blocks, and it measures
//! from the timestamps the messages carry (all `CLOCK_MONOTONIC`, one clock for every
//! process): rig publish -> compensator receive (`recv_ns - input_publish_ns`),
//! compensator receive -> publish (`publish_ns - recv_ns`), compensator publish ->
//! subscriber receive, and end to end. Three pipelines, one after the other, with the
//! same rig, rates and messages:
//!
//! - **vibrocomp**: the real estimator and compensator processes over iceoryx2;
//! - **bare iceoryx2**: a forwarder process with the same hot-loop structure (WaitSet or
//!   spin) that answers each accelerometer block with a compensated block holding its
//!   timestamps and nothing computed, and a sink process that takes the vibration
//!   blocks: the transport alone, for both streams;
//! - **Unix sockets**: one process running the estimator's and the compensator's logic
//!   (`vibro_estimator::InProcess`, `vibro_compensator::InProcess`, the hot loops' own
//!   handlers) on two threads, fed over two Unix stream sockets with the same
//!   fixed-size messages, answering on the accelerometer socket.
//!
//! Each histogram is an HdrHistogram (1 ns .. 60 s, 3 significant digits); the blocks
//! of the first `--warmup-s` of data (before the first vibration estimate, and while
//! caches warm) are left out. CPU use is each process's user + system time from
//! `/proc/PID/stat` over the run, in percent of one core.

use anyhow::{bail, Context};
use hdrhistogram::Histogram;
use serde::Serialize;
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use vibro_ipc::{create_node, create_waitset, now_ns, StreamPublisher, StreamSubscriber};
use vibro_msgs::{
    AccelBlock, CompensatedBlock, Heartbeat, ServiceId, ServiceNames, Stream, VibBlock, VibEstimate,
};
use vibro_service::{LoopMode, ServiceConfig};

use crate::output::print_json;
use crate::system::{Role, SystemSpec};
use vibro_service::supervise::{private_prefix, wait_for_heartbeats};

#[derive(Debug, Clone, clap::Args)]
pub struct LatencyArgs {
    /// Length of each pipeline's run, s.
    #[arg(long = "duration-s", default_value_t = 5.0)]
    pub duration_s: f64,
    /// Accelerometer sample rate, Hz.
    #[arg(long = "rate-hz", default_value_t = 800.0)]
    pub rate_hz: f64,
    /// Accelerometer samples per block (1..32).
    #[arg(long = "block-samples", default_value_t = 32)]
    pub block_samples: u32,
    /// Vibration-sensor sample rate, Hz (the estimator's configuration must match).
    #[arg(long = "vib-rate-hz", default_value_t = 25600.0)]
    pub vib_rate_hz: f64,
    /// Vibration-sensor samples per block (1..512).
    #[arg(long = "vib-block-samples", default_value_t = 512)]
    pub vib_block_samples: u32,
    /// Loop mode of the services and of the rig's receiver: event or spin.
    #[arg(long, default_value = "event")]
    pub mode: LoopMode,
    /// Data time left out at the start, s.
    #[arg(long = "warmup-s", default_value_t = 1.5)]
    pub warmup_s: f64,
    /// Only the vibrocomp pipeline (no bare-iceoryx2 and socket baselines).
    #[arg(long)]
    pub no_baselines: bool,
    #[arg(long)]
    pub json: bool,
}

/// The hidden peers of the baselines.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum PeerCommand {
    /// Answers every accelerometer block on `{prefix}accel` with a compensated block
    /// holding its timestamps, nothing computed.
    Bare {
        #[arg(long)]
        prefix: String,
        #[arg(long, default_value = "event")]
        mode: LoopMode,
    },
    /// Takes every vibration block on `{prefix}vib` and drops it: the estimator's
    /// process without the estimation, so that the bare pipeline moves both streams.
    BareVib {
        #[arg(long)]
        prefix: String,
        #[arg(long, default_value = "event")]
        mode: LoopMode,
    },
    /// The estimator's and the compensator's logic over two Unix stream sockets in DIR.
    Uds {
        #[arg(long = "socket-dir")]
        socket_dir: PathBuf,
    },
}

/// Percentiles of one hop, microseconds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct HopUs {
    pub count: u64,
    pub p50_us: f64,
    pub p90_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
}

fn hop(h: &Histogram<u64>) -> HopUs {
    if h.is_empty() {
        return HopUs::default();
    }
    let q = |x: f64| h.value_at_quantile(x) as f64 * 1e-3;
    HopUs {
        count: h.len(),
        p50_us: q(0.5),
        p90_us: q(0.9),
        p99_us: q(0.99),
        p999_us: q(0.999),
        max_us: h.max() as f64 * 1e-3,
    }
}

/// One pipeline's run.
#[derive(Debug, Clone, Serialize)]
pub struct PipelineRun {
    pub pipeline: &'static str,
    pub accel_blocks_sent: u64,
    pub vib_blocks_sent: u64,
    pub compensated_received: u64,
    /// Accelerometer samples without a compensated output, plus the services' own
    /// loss counters (must be 0).
    pub lost_samples: u64,
    pub rig_to_service: HopUs,
    pub processing: HopUs,
    pub service_to_subscriber: HopUs,
    pub end_to_end: HopUs,
    /// Percent of one core over the run.
    pub cpu_percent: Vec<(String, f64)>,
}

#[derive(Debug, Serialize)]
struct Ratios {
    /// vibrocomp end to end over bare iceoryx2 end to end.
    vs_bare_p50: f64,
    vs_bare_p99: f64,
    /// What our processing adds to the bare hop, us (end to end).
    added_p50_us: f64,
    added_p99_us: f64,
    vs_sockets_p50: f64,
    vs_sockets_p99: f64,
}

#[derive(Debug, Serialize)]
struct LatencyReport {
    mode: String,
    duration_s: f64,
    rate_hz: f64,
    block_samples: u32,
    vib_rate_hz: f64,
    vib_block_samples: u32,
    runs: Vec<PipelineRun>,
    ratios: Option<Ratios>,
}

/// The four stamps of one compensated block.
#[derive(Clone, Copy)]
struct Stamps {
    t0_ns: u64,
    input_publish_ns: u64,
    recv_ns: u64,
    publish_ns: u64,
    sub_recv_ns: u64,
    count: u32,
}

struct Histograms {
    rig_to_service: Histogram<u64>,
    processing: Histogram<u64>,
    service_to_subscriber: Histogram<u64>,
    end_to_end: Histogram<u64>,
}

impl Histograms {
    fn new() -> anyhow::Result<Self> {
        let h = || Histogram::new_with_bounds(1, 60_000_000_000, 3).context("histogram");
        Ok(Self {
            rig_to_service: h()?,
            processing: h()?,
            service_to_subscriber: h()?,
            end_to_end: h()?,
        })
    }

    fn record(&mut self, s: &Stamps) {
        let d = |a: u64, b: u64| a.saturating_sub(b).max(1);
        let _ = self.rig_to_service.record(d(s.recv_ns, s.input_publish_ns));
        let _ = self.processing.record(d(s.publish_ns, s.recv_ns));
        let _ = self
            .service_to_subscriber
            .record(d(s.sub_recv_ns, s.publish_ns));
        let _ = self.end_to_end.record(d(s.sub_recv_ns, s.input_publish_ns));
    }
}

/// The rig's synthetic signal: 1 g on every unit with a 12 Hz tone, and sensors seeing
/// the tone plus deterministic broadband noise.
struct Signal {
    k1_v_per_g: [f64; 3],
    sensitivity_v_per_g: f64,
    noise: u64,
}

impl Signal {
    fn accel_v(&self, t_s: f64) -> [f64; 3] {
        let a = 1.0 + 0.05 * (2.0 * std::f64::consts::PI * 12.0 * t_s).sin();
        [0, 1, 2].map(|u| a * self.k1_v_per_g[u])
    }

    fn vib_v(&mut self, t_s: f64) -> [f64; 3] {
        let tone = (2.0 * std::f64::consts::PI * 12.0 * t_s).sin();
        [0, 1, 2].map(|_| {
            // xorshift64*: cheap, deterministic, roughly uniform in [-1, 1).
            self.noise ^= self.noise >> 12;
            self.noise ^= self.noise << 25;
            self.noise ^= self.noise >> 27;
            let u =
                (self.noise.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
            self.sensitivity_v_per_g * (0.5 * tone + 2.0 * (u - 0.5))
        })
    }
}

/// The messages of the run, built once per block (no allocation in the loop).
struct RigStream {
    signal: Signal,
    accel: AccelBlock,
    vib: VibBlock,
    accel_period_ns: f64,
    vib_period_ns: f64,
    accel_block_ns: u64,
    vib_block_ns: u64,
}

impl RigStream {
    fn new(args: &LatencyArgs, k1_v_per_g: [f64; 3]) -> Self {
        let accel_period_ns = 1e9 / args.rate_hz;
        let vib_period_ns = 1e9 / args.vib_rate_hz;
        let mut accel = AccelBlock::ZEROED;
        accel.count = args.block_samples;
        accel.sample_period_ns = accel_period_ns.round() as u64;
        accel.source_id = 7;
        let mut vib = VibBlock::ZEROED;
        vib.count = args.vib_block_samples;
        vib.sample_period_ns = vib_period_ns.round() as u64;
        vib.source_id = 7;
        Self {
            signal: Signal {
                k1_v_per_g,
                sensitivity_v_per_g: 0.1,
                noise: 0x9e37_79b9_7f4a_7c15,
            },
            accel,
            vib,
            accel_period_ns,
            vib_period_ns,
            accel_block_ns: (accel_period_ns * f64::from(args.block_samples)) as u64,
            vib_block_ns: (vib_period_ns * f64::from(args.vib_block_samples)) as u64,
        }
    }

    /// Fills accelerometer block `k` (samples `k * count ..`).
    fn accel_block(&mut self, k: u64) -> &AccelBlock {
        let n = u64::from(self.accel.count);
        let first = k * n;
        self.accel.seq = k;
        self.accel.first_sample_index = first;
        // The end of the first sample's interval, as the rig's packetizer stamps it.
        self.accel.t0_ns = ((first + 1) as f64 * self.accel_period_ns).round() as u64;
        for i in 0..n as usize {
            let t_s = (first + i as u64) as f64 * self.accel_period_ns * 1e-9;
            self.accel.output_v[i] = self.signal.accel_v(t_s);
        }
        self.accel.publish_ns = now_ns();
        &self.accel
    }

    fn vib_block(&mut self, k: u64) -> &VibBlock {
        let n = u64::from(self.vib.count);
        let first = k * n;
        self.vib.seq = k;
        self.vib.first_sample_index = first;
        self.vib.t0_ns = (first as f64 * self.vib_period_ns).round() as u64;
        for i in 0..n as usize {
            let t_s = (first + i as u64) as f64 * self.vib_period_ns * 1e-9;
            self.vib.sample_v[i] = self.signal.vib_v(t_s);
        }
        self.vib.publish_ns = now_ns();
        &self.vib
    }
}

/// Sends the run's blocks in real time: `send(Some(accel), None)` or `(None, Some(vib))`
/// in data-time order. Returns (accel, vib) blocks sent.
fn pace(
    args: &LatencyArgs,
    stream: &mut RigStream,
    mut send_accel: impl FnMut(&AccelBlock) -> anyhow::Result<()>,
    mut send_vib: impl FnMut(&VibBlock) -> anyhow::Result<()>,
) -> anyhow::Result<(u64, u64)> {
    let end_ns = (args.duration_s * 1e9) as u64;
    let start = Instant::now();
    let (mut ka, mut kv) = (0u64, 0u64);
    loop {
        // A block is due when its last sample has been taken.
        let due_a = (ka + 1) * stream.accel_block_ns;
        let due_v = (kv + 1) * stream.vib_block_ns;
        let due = due_a.min(due_v);
        if due > end_ns {
            break;
        }
        let now = start.elapsed().as_nanos() as u64;
        if due > now {
            std::thread::sleep(Duration::from_nanos(due - now));
        }
        if due_v <= due_a {
            send_vib(stream.vib_block(kv))?;
            kv += 1;
        } else {
            send_accel(stream.accel_block(ka))?;
            ka += 1;
        }
    }
    Ok((ka, kv))
}

fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces): state is field 3.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the whole line: 12 and 13 here.
    Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
}

fn ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 {
        t as f64
    } else {
        100.0
    }
}

struct Cpu {
    pids: Vec<(String, u32, u64)>,
    start: Instant,
}

impl Cpu {
    fn start(pids: &[(&str, u32)]) -> Self {
        Self {
            pids: pids
                .iter()
                .map(|&(n, p)| (n.to_string(), p, cpu_ticks(p).unwrap_or(0)))
                .collect(),
            start: Instant::now(),
        }
    }

    fn finish(&self) -> Vec<(String, f64)> {
        let wall = self.start.elapsed().as_secs_f64().max(1e-9);
        self.pids
            .iter()
            .map(|(n, p, t0)| {
                let t = cpu_ticks(*p).unwrap_or(*t0).saturating_sub(*t0);
                (n.clone(), 100.0 * t as f64 / ticks_per_s() / wall)
            })
            .collect()
    }
}

/// Receives compensated blocks until `stop` and the expected count, stamping each.
fn receive_iceoryx(
    prefix: String,
    mode: LoopMode,
    stop: Arc<AtomicBool>,
    capacity: usize,
) -> anyhow::Result<Vec<Stamps>> {
    let names = ServiceNames::new(&prefix)?;
    let node = create_node("vibrocomp-latency-rx")?;
    let sub = StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated)?;
    let waitset = create_waitset()?;
    let _guard = waitset
        .attach_notification(sub.listener())
        .map_err(|e| anyhow::anyhow!("attaching the receiver: {e:?}"))?;
    let mut out = Vec::with_capacity(capacity);
    loop {
        let mut any = false;
        while let Some(b) = sub.receive()? {
            let sub_recv_ns = now_ns();
            any = true;
            out.push(Stamps {
                t0_ns: b.t0_ns,
                input_publish_ns: b.input_publish_ns,
                recv_ns: b.recv_ns,
                publish_ns: b.publish_ns,
                sub_recv_ns,
                count: b.count,
            });
        }
        if stop.load(Ordering::Acquire) && !any {
            return Ok(out);
        }
        match mode {
            LoopMode::Event => {
                waitset
                    .wait_and_process_once_with_timeout(
                        |_| iceoryx2::prelude::CallbackProgression::Continue,
                        Duration::from_millis(20),
                    )
                    .map_err(|e| anyhow::anyhow!("receiver wait: {e:?}"))?;
                let _ = sub.clear_events();
            }
            LoopMode::Spin => {
                if any {
                    let _ = sub.clear_events();
                } else {
                    std::hint::spin_loop();
                }
            }
        }
    }
}

/// Runs the rig against a system listening on `prefix` over iceoryx2.
fn run_iceoryx(
    args: &LatencyArgs,
    prefix: &str,
    k1_v_per_g: [f64; 3],
) -> anyhow::Result<(u64, u64, Vec<Stamps>)> {
    let names = ServiceNames::new(prefix)?;
    let node = create_node("vibrocomp-latency")?;
    let mut accel = StreamPublisher::<AccelBlock>::open(&node, &names, Stream::Accel)?;
    let mut vib = StreamPublisher::<VibBlock>::open(&node, &names, Stream::Vib)?;
    let stop = Arc::new(AtomicBool::new(false));
    let capacity = (args.duration_s * args.rate_hz / f64::from(args.block_samples)) as usize + 16;
    let rx = {
        let (prefix, mode, stop) = (prefix.to_string(), args.mode, Arc::clone(&stop));
        std::thread::Builder::new()
            .name("latency-rx".into())
            .spawn(move || receive_iceoryx(prefix, mode, stop, capacity))?
    };
    // The receiver subscribes before the first block.
    let t = Instant::now();
    while accel.subscriber_count() < 2 && t.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut stream = RigStream::new(args, k1_v_per_g);
    let (ka, kv) = pace(
        args,
        &mut stream,
        |b| accel.publish(b).map(|_| ()).map_err(Into::into),
        |b| vib.publish(b).map(|_| ()).map_err(Into::into),
    )?;
    // The last outputs: a moment to arrive.
    std::thread::sleep(Duration::from_millis(300));
    stop.store(true, Ordering::Release);
    let stamps = rx
        .join()
        .map_err(|_| anyhow::anyhow!("the receiver thread panicked"))??;
    Ok((ka, kv, stamps))
}

fn summarize(
    pipeline: &'static str,
    args: &LatencyArgs,
    (ka, kv, stamps): (u64, u64, Vec<Stamps>),
    extra_lost: u64,
    cpu_percent: Vec<(String, f64)>,
) -> anyhow::Result<PipelineRun> {
    let mut h = Histograms::new()?;
    let warmup_ns = (args.warmup_s * 1e9) as u64;
    for s in stamps.iter().filter(|s| s.t0_ns >= warmup_ns) {
        h.record(s);
    }
    let received: u64 = stamps.iter().map(|s| u64::from(s.count)).sum();
    let sent = ka * u64::from(args.block_samples);
    Ok(PipelineRun {
        pipeline,
        accel_blocks_sent: ka,
        vib_blocks_sent: kv,
        compensated_received: stamps.len() as u64,
        lost_samples: sent.saturating_sub(received) + extra_lost,
        rig_to_service: hop(&h.rig_to_service),
        processing: hop(&h.processing),
        service_to_subscriber: hop(&h.service_to_subscriber),
        end_to_end: hop(&h.end_to_end),
        cpu_percent,
    })
}

fn spec_for(prefix: &str, mode: LoopMode) -> SystemSpec {
    SystemSpec {
        prefix: prefix.to_string(),
        mode: Some(mode.as_str().to_string()),
        json: true,
        ..SystemSpec::default()
    }
}

fn losses(summary: &serde_json::Value, stream: &str) -> u64 {
    let g = |k: &str| summary[stream][k].as_u64().unwrap_or(0);
    g("lost_messages") + g("lost_samples") + summary["undelivered"].as_u64().unwrap_or(0)
}

fn run_vibrocomp(args: &LatencyArgs, k1: [f64; 3], log: &Path) -> anyhow::Result<PipelineRun> {
    let prefix = private_prefix("vclat");
    let spec = spec_for(&prefix, args.mode);
    let mut est = spec.spawn(Role::Estimator, Some(log))?;
    let mut comp = spec.spawn(Role::Compensator, Some(log))?;
    wait_for_heartbeats(
        &ServiceNames::new(&prefix)?,
        &[ServiceId::Estimator, ServiceId::Compensator],
        Duration::from_secs(30),
        || {
            est.check_alive()?;
            comp.check_alive()
        },
    )?;
    let pids = [
        ("estimator", est.pid()),
        ("compensator", comp.pid()),
        ("rig", std::process::id()),
    ];
    let cpu = Cpu::start(&pids);
    let result = run_iceoryx(args, &prefix, k1)?;
    let cpu = cpu.finish();
    let c = comp.stop(Duration::from_secs(10))?.summary()?;
    let e = est.stop(Duration::from_secs(10))?.summary()?;
    let lost = losses(&c, "accel") + losses(&e, "vib");
    summarize("vibrocomp (iceoryx2)", args, result, lost, cpu)
}

fn run_bare(args: &LatencyArgs, k1: [f64; 3], log: &Path) -> anyhow::Result<PipelineRun> {
    let prefix = private_prefix("vcbare");
    let exe = std::env::current_exe()?;
    let spawn = |peer: &str, what: &str| -> anyhow::Result<std::process::Child> {
        std::process::Command::new(&exe)
            .args([
                "latency-peer",
                peer,
                "--prefix",
                &prefix,
                "--mode",
                args.mode.as_str(),
            ])
            .stdout(std::process::Stdio::null())
            .stderr(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(log)?,
            )
            .spawn()
            .with_context(|| format!("starting the bare {what}"))
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
    let result = run_iceoryx(args, &prefix, k1)?;
    let cpu = cpu.finish();
    drop(sink);
    drop(forwarder);
    summarize("bare iceoryx2", args, result, 0, cpu)
}

struct KillOnDrop<'a>(Option<&'a mut std::process::Child>);
impl KillOnDrop<'_> {
    fn pid(&self) -> u32 {
        self.0.as_ref().map_or(0, |c| c.id())
    }
}
impl Drop for KillOnDrop<'_> {
    fn drop(&mut self) {
        if let Some(c) = self.0.take() {
            vibro_service::supervise::terminate(c);
            let t = Instant::now();
            while t.elapsed() < Duration::from_secs(3) {
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

fn run_uds(args: &LatencyArgs, k1: [f64; 3], log: &Path) -> anyhow::Result<PipelineRun> {
    let dir = std::env::temp_dir().join(format!("vibrocomp-uds-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let exe = std::env::current_exe()?;
    let mut child = std::process::Command::new(exe)
        .args(["latency-peer", "uds", "--socket-dir"])
        .arg(&dir)
        .stdout(std::process::Stdio::null())
        .stderr(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(log)?,
        )
        .spawn()
        .context("starting the socket peer")?;
    let guard = KillOnDrop(Some(&mut child));
    let mut vib_sock = connect(&dir.join("vib.sock"))?;
    let mut accel_sock = connect(&dir.join("accel.sock"))?;
    let mut reader = accel_sock.try_clone()?;
    let pid = guard.pid();
    let cpu = Cpu::start(&[("uds peer", pid), ("rig", std::process::id())]);
    let expected = (args.duration_s * args.rate_hz / f64::from(args.block_samples)) as usize;
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
            out.push(Stamps {
                t0_ns: b.t0_ns,
                input_publish_ns: b.input_publish_ns,
                recv_ns: b.recv_ns,
                publish_ns: b.publish_ns,
                sub_recv_ns,
                count: b.count,
            });
        }
    });
    let mut stream = RigStream::new(args, k1);
    let (ka, kv) = pace(
        args,
        &mut stream,
        |b| accel_sock.write_all(b.as_bytes()).map_err(Into::into),
        |b| vib_sock.write_all(b.as_bytes()).map_err(Into::into),
    )?;
    std::thread::sleep(Duration::from_millis(300));
    // Closing the rig's ends stops the peer, which closes its answers: EOF.
    let _ = vib_sock.shutdown(std::net::Shutdown::Both);
    let _ = accel_sock.shutdown(std::net::Shutdown::Write);
    let stamps = rx
        .join()
        .map_err(|_| anyhow::anyhow!("the socket receiver panicked"))??;
    let cpu = cpu.finish();
    drop(guard);
    let _ = std::fs::remove_dir_all(&dir);
    summarize("Unix sockets", args, (ka, kv, stamps), 0, cpu)
}

pub fn run(args: &LatencyArgs) -> anyhow::Result<()> {
    for (name, v) in [
        ("--duration-s", args.duration_s),
        ("--rate-hz", args.rate_hz),
        ("--vib-rate-hz", args.vib_rate_hz),
    ] {
        anyhow::ensure!(
            v.is_finite() && v > 0.0,
            "{name} = {v}: must be finite and > 0"
        );
    }
    anyhow::ensure!(
        (1..=vibro_msgs::ACCEL_BLOCK_MAX as u32).contains(&args.block_samples),
        "--block-samples = {}: must be 1..={}",
        args.block_samples,
        vibro_msgs::ACCEL_BLOCK_MAX
    );
    anyhow::ensure!(
        (1..=vibro_msgs::VIB_BLOCK_MAX as u32).contains(&args.vib_block_samples),
        "--vib-block-samples = {}: must be 1..={}",
        args.vib_block_samples,
        vibro_msgs::VIB_BLOCK_MAX
    );
    anyhow::ensure!(
        args.warmup_s.is_finite() && args.warmup_s >= 0.0 && args.warmup_s < args.duration_s,
        "--warmup-s = {}: must be >= 0 and shorter than --duration-s",
        args.warmup_s
    );
    let k1 = vibro_compensator::Config::load_default()?
        .model
        .triad
        .passports
        .map(|p| p.k1_v_per_g);
    let log = std::env::temp_dir().join(format!("vibrocomp-latency-{}.log", std::process::id()));
    let mut runs = vec![run_vibrocomp(args, k1, &log)?];
    if !args.no_baselines {
        runs.push(run_bare(args, k1, &log)?);
        runs.push(run_uds(args, k1, &log)?);
    }
    let _ = std::fs::remove_file(&log);
    let ratios = (runs.len() == 3).then(|| {
        let (v, b, u) = (
            &runs[0].end_to_end,
            &runs[1].end_to_end,
            &runs[2].end_to_end,
        );
        Ratios {
            vs_bare_p50: v.p50_us / b.p50_us,
            vs_bare_p99: v.p99_us / b.p99_us,
            added_p50_us: v.p50_us - b.p50_us,
            added_p99_us: v.p99_us - b.p99_us,
            vs_sockets_p50: v.p50_us / u.p50_us,
            vs_sockets_p99: v.p99_us / u.p99_us,
        }
    });
    let report = LatencyReport {
        mode: args.mode.as_str().to_string(),
        duration_s: args.duration_s,
        rate_hz: args.rate_hz,
        block_samples: args.block_samples,
        vib_rate_hz: args.vib_rate_hz,
        vib_block_samples: args.vib_block_samples,
        runs,
        ratios,
    };
    if args.json {
        return print_json(&report);
    }
    outln!(
        "Latency, {} mode: {} s per pipeline, accelerometer blocks of {} at {} Hz, vibration blocks of {} at {} Hz (first {} s left out)",
        report.mode, args.duration_s, args.block_samples, args.rate_hz, args.vib_block_samples, args.vib_rate_hz, args.warmup_s
    )?;
    for r in &report.runs {
        outln!(
            "{}: {} blocks sent, {} received, lost samples {}; CPU {}",
            r.pipeline,
            r.accel_blocks_sent,
            r.compensated_received,
            r.lost_samples,
            r.cpu_percent
                .iter()
                .map(|(n, p)| format!("{n} {p:.1}%"))
                .collect::<Vec<_>>()
                .join(", ")
        )?;
        outln!(
            "  {:<26}{:>10}{:>10}{:>10}{:>10}{:>10}",
            "hop, us",
            "p50",
            "p90",
            "p99",
            "p99.9",
            "max"
        )?;
        for (name, h) in [
            ("rig -> service receive", &r.rig_to_service),
            ("service receive -> publish", &r.processing),
            ("publish -> subscriber", &r.service_to_subscriber),
            ("end to end", &r.end_to_end),
        ] {
            outln!(
                "  {:<26}{:>10.1}{:>10.1}{:>10.1}{:>10.1}{:>10.1}",
                name,
                h.p50_us,
                h.p90_us,
                h.p99_us,
                h.p999_us,
                h.max_us
            )?;
        }
    }
    if let Some(r) = &report.ratios {
        outln!(
            "vibrocomp / bare iceoryx2, end to end: p50 {:.2}x ({:+.1} us), p99 {:.2}x ({:+.1} us); vibrocomp / Unix sockets: p50 {:.2}x, p99 {:.2}x",
            r.vs_bare_p50, r.added_p50_us, r.vs_bare_p99, r.added_p99_us, r.vs_sockets_p50, r.vs_sockets_p99
        )?;
    }
    Ok(())
}

/// The loop of a bare peer, the services' loop structure without their work: wait on
/// `input` (WaitSet or spin), hand every message to `take`, and publish a heartbeat as
/// `service` every 0.2 s (with `received` = what `take` returned last).
fn bare_peer_loop<T: iceoryx2::prelude::ZeroCopySend + std::fmt::Debug + 'static>(
    names: &ServiceNames,
    node: &vibro_ipc::IpcNode,
    input: Stream,
    service: ServiceId,
    mode: LoopMode,
    mut take: impl FnMut(&T) -> u64,
) -> anyhow::Result<()> {
    let sub = StreamSubscriber::<T>::open(node, names, input)?;
    let mut heartbeat =
        StreamPublisher::<Heartbeat>::open(node, names, Stream::Heartbeat(service))?;
    let waitset = create_waitset()?;
    let _g = waitset
        .attach_notification(sub.listener())
        .map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let stop = install_stop()?;
    let (mut next_hb, mut received) = (0u64, 0u64);
    while !stop.load(Ordering::Acquire) {
        if mode == LoopMode::Event {
            waitset
                .wait_and_process_once_with_timeout(
                    |_| iceoryx2::prelude::CallbackProgression::Continue,
                    Duration::from_millis(100),
                )
                .map_err(|e| anyhow::anyhow!("wait: {e:?}"))?;
            let _ = sub.clear_events();
        }
        let mut any = false;
        while let Some(m) = sub.receive()? {
            any = true;
            received = take(&m);
        }
        if mode == LoopMode::Spin {
            if any {
                let _ = sub.clear_events();
            } else {
                std::hint::spin_loop();
            }
        }
        let now = now_ns();
        if now >= next_hb {
            next_hb = now + 200_000_000;
            let _ = heartbeat.publish(&Heartbeat {
                publish_ns: now,
                received,
                service: service.code(),
                state: vibro_msgs::ServiceState::Running.code(),
                ..Heartbeat::ZEROED
            });
        }
    }
    Ok(())
}

/// The bare forwarder: the compensator's loop without the compensation.
fn peer_bare(prefix: &str, mode: LoopMode) -> anyhow::Result<()> {
    let names = ServiceNames::new(prefix)?;
    let node = create_node("vibrocomp-bare")?;
    let mut out = StreamPublisher::<CompensatedBlock>::open(&node, &names, Stream::Compensated)?;
    let mut seq = 0u64;
    bare_peer_loop(
        &names,
        &node,
        Stream::Accel,
        ServiceId::Compensator,
        mode,
        |b: &AccelBlock| {
            let recv_ns = now_ns();
            let _ = out.publish_with(|m| {
                m.seq = seq;
                m.input_seq = b.seq;
                m.first_sample_index = b.first_sample_index;
                m.t0_ns = b.t0_ns;
                m.sample_period_ns = b.sample_period_ns;
                m.input_publish_ns = b.publish_ns;
                m.recv_ns = recv_ns;
                m.count = b.count;
                m.publish_ns = now_ns();
            });
            seq += 1;
            seq
        },
    )
}

/// The bare vibration sink: the estimator's loop without the estimation.
fn peer_bare_vib(prefix: &str, mode: LoopMode) -> anyhow::Result<()> {
    let names = ServiceNames::new(prefix)?;
    let node = create_node("vibrocomp-bare-vib")?;
    let mut taken = 0u64;
    bare_peer_loop(
        &names,
        &node,
        Stream::Vib,
        ServiceId::Estimator,
        mode,
        |_: &VibBlock| {
            taken += 1;
            taken
        },
    )
}

/// SIGTERM/SIGINT set the returned flag (the peers have no tokio runtime).
fn install_stop() -> anyhow::Result<Arc<AtomicBool>> {
    static STOP: AtomicBool = AtomicBool::new(false);
    extern "C" fn on_signal(_: libc::c_int) {
        STOP.store(true, Ordering::Release);
    }
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
    }
    let flag = Arc::new(AtomicBool::new(false));
    let f = Arc::clone(&flag);
    std::thread::spawn(move || {
        while !STOP.load(Ordering::Acquire) {
            std::thread::sleep(Duration::from_millis(20));
        }
        f.store(true, Ordering::Release);
    });
    Ok(flag)
}

/// The socket peer's estimates, sent to its compensator thread: stamped as the
/// service's publisher stamps them (after the estimate is written).
struct EstimateChannel(std::sync::mpsc::Sender<VibEstimate>);

impl vibro_estimator::EstimateSink for EstimateChannel {
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut VibEstimate),
    ) -> (u64, vibro_ipc::Result<usize>) {
        let mut m = VibEstimate::ZEROED;
        fill(&mut m);
        let publish_ns = now_ns();
        m.publish_ns = publish_ns;
        // The compensator thread gone: the run is ending.
        let _ = self.0.send(m);
        (publish_ns, Ok(1))
    }
}

/// The socket peer: the estimator's and compensator's logic on two threads.
fn peer_uds(dir: &Path) -> anyhow::Result<()> {
    let est_config = vibro_estimator::Config::load_default()?;
    let comp_config = vibro_compensator::Config::load_default()?;
    let vib_path = dir.join("vib.sock");
    let accel_path = dir.join("accel.sock");
    let _ = std::fs::remove_file(&vib_path);
    let _ = std::fs::remove_file(&accel_path);
    let vib_listener =
        UnixListener::bind(&vib_path).with_context(|| format!("{}", vib_path.display()))?;
    let accel_listener =
        UnixListener::bind(&accel_path).with_context(|| format!("{}", accel_path.display()))?;
    let (tx, rx) = std::sync::mpsc::channel::<VibEstimate>();
    let estimator = std::thread::spawn(move || -> anyhow::Result<()> {
        let (mut sock, _) = vib_listener.accept()?;
        let mut est = vibro_estimator::InProcess::new(&est_config)?;
        let mut estimates = EstimateChannel(tx);
        let mut buf = vec![0u8; std::mem::size_of::<VibBlock>()];
        loop {
            if sock.read_exact(&mut buf).is_err() {
                return Ok(());
            }
            let recv_ns = now_ns();
            let Some(b) = VibBlock::from_bytes(&buf) else {
                bail!("vib block size")
            };
            est.on_block(&b, recv_ns, &mut estimates)?;
        }
    });
    let (mut sock, _) = accel_listener.accept()?;
    let mut writer = sock.try_clone()?;
    let mut comp = vibro_compensator::InProcess::new(&comp_config)?;
    let mut buf = vec![0u8; std::mem::size_of::<AccelBlock>()];
    let mut out = Vec::with_capacity(4);
    loop {
        if sock.read_exact(&mut buf).is_err() {
            break;
        }
        let recv_ns = now_ns();
        let Some(b) = AccelBlock::from_bytes(&buf) else {
            bail!("accel block size")
        };
        while let Ok(e) = rx.try_recv() {
            comp.on_estimate(&e);
        }
        out.clear();
        comp.on_accel(&b, recv_ns, &mut out);
        for m in &out {
            writer.write_all(m.as_bytes())?;
        }
    }
    let _ = writer.shutdown(std::net::Shutdown::Both);
    let _ = estimator.join();
    Ok(())
}

pub fn run_peer(cmd: &PeerCommand) -> anyhow::Result<()> {
    match cmd {
        PeerCommand::Bare { prefix, mode } => peer_bare(prefix, *mode),
        PeerCommand::BareVib { prefix, mode } => peer_bare_vib(prefix, *mode),
        PeerCommand::Uds { socket_dir } => peer_uds(socket_dir),
    }
}
