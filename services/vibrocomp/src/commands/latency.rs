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
//!
//! The estimator runs with `sample_rate_hz = --vib-rate-hz` (a private copy of its
//! default configuration when the rates differ: it refuses blocks at any other rate).
//!
//! **Soak** (`--soak`, issue 18): the vibrocomp pipeline alone for `--duration-s`,
//! optionally beside a background load (`--load INPUT`: a child process running
//! `vibrocomp lab diagnose INPUT` in a loop, `--load-jobs` at a time, for the whole
//! soak, stopped at its end). It reports every accelerometer block answered (from the
//! compensated blocks' `input_seq`) and the services' own counters, the services'
//! resident memory (`VmRSS` from `/proc/PID/status`, one sample a second: first,
//! last, max, growth and slope after the warm-up), the end-to-end latency's
//! percentiles and buckets per accelerometer block, and p99.9 against one
//! accelerometer sample period. The target is reported, never enforced: a soak that
//! misses it still exits 0.

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

#[path = "latency_hosts.rs"]
mod hosts;

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
    /// Soak: the vibrocomp pipeline only, for `--duration-s`, with every accelerometer
    /// block's input sequence checked, the services' resident memory sampled every
    /// second, and the end-to-end histogram; a 10x vibration rate is `--vib-rate-hz
    /// 256000`.
    #[arg(long)]
    pub soak: bool,
    /// With `--soak`: a background load, `vibrocomp lab diagnose INPUT` run in a loop
    /// in a child process for the whole soak (a campaign table or a log, docs/lab.md).
    #[arg(long, value_name = "INPUT", requires = "soak")]
    pub load: Option<PathBuf>,
    /// With `--load`: how many diagnose loops run side by side.
    #[arg(long = "load-jobs", default_value_t = 1, requires = "load")]
    pub load_jobs: u32,
    /// The vibrocomp pipeline's service-name prefix [default: a private one,
    /// `vclat-PID/`]. The baselines always use private prefixes.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Run the services' hot loops and the rig's receiver under SCHED_FIFO at this
    /// priority (1..=99; needs CAP_SYS_NICE), as a real-time deployment would: a block
    /// then wakes its process ahead of any normal-priority work, a `--load` included.
    #[arg(long, value_name = "1..99", value_parser = clap::value_parser!(u8).range(1..=99))]
    pub realtime_priority: Option<u8>,
    /// Run the vibrocomp pipeline with the live view attached (`vibrocomp view` on a
    /// free port of 127.0.0.1) and one Foxglove client subscribed to every view channel
    /// and reading all it is sent: what a connected viewer costs the services.
    #[arg(long)]
    pub view: bool,
    /// 2: also the vibrocomp pipeline across two hosts on this machine (the services
    /// in another iceoryx2 root, two Zenoh bridges over loopback TCP between), and a
    /// bare Zenoh publisher/subscriber pair as its baseline (docs/bridge.md).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub hosts: u8,
    /// Print the measured latencies as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The hidden peers of the baselines.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum PeerCommand {
    /// Answers every accelerometer block on `{prefix}accel` with a compensated block
    /// holding its timestamps, nothing computed.
    Bare {
        /// Service-name prefix of the streams.
        #[arg(long)]
        prefix: String,
        /// Loop mode: event or spin.
        #[arg(long, default_value = "event")]
        mode: LoopMode,
    },
    /// Takes every vibration block on `{prefix}vib` and drops it: the estimator's
    /// process without the estimation, so that the bare pipeline moves both streams.
    BareVib {
        /// Service-name prefix of the streams.
        #[arg(long)]
        prefix: String,
        /// Loop mode: event or spin.
        #[arg(long, default_value = "event")]
        mode: LoopMode,
    },
    /// The bare Zenoh baseline's peer (`--hosts 2`): connects to ENDPOINT, answers
    /// every accelerometer block on `{key}/accel` on `{key}/compensated` with its
    /// timestamps, takes the vibration blocks on `{key}/vib`; until SIGTERM.
    BareZenoh {
        /// The rig's Zenoh endpoint (`tcp/127.0.0.1:PORT`).
        #[arg(long)]
        endpoint: String,
        /// The key prefix.
        #[arg(long)]
        key: String,
    },
    /// The estimator's and the compensator's logic over two Unix stream sockets in DIR.
    Uds {
        /// The folder of the two Unix sockets.
        #[arg(long = "socket-dir")]
        socket_dir: PathBuf,
        /// The estimator's configuration [default: its default one].
        #[arg(long = "estimator-config")]
        estimator_config: Option<PathBuf>,
    },
    /// The soak's background load: runs `vibrocomp lab diagnose INPUT` again and again,
    /// JOBS at a time, until SIGTERM; then kills the runs under way and prints
    /// `{"runs_started", "runs_completed", "failures", "first_failure", "cpu_s",
    /// "wall_s"}` on stdout (`cpu_s`: its own and its waited-for runs' CPU).
    /// Stops at the first failed run.
    Load {
        /// The campaign table or log `lab diagnose` runs on.
        #[arg(long)]
        input: PathBuf,
        /// Runs at a time.
        #[arg(long, default_value_t = 1)]
        jobs: u32,
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
    /// With `--view`: the live view and its client over the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<ViewLoad>,
}

/// What the live view served a connected client during a `--view` run.
#[derive(Debug, Clone, Serialize)]
pub struct ViewLoad {
    pub listen: String,
    /// Channels the client subscribed to.
    pub client_channels: usize,
    /// View messages the client received (binary message frames).
    pub client_messages: u64,
    /// The view's own summary at exit (`vibrocomp view --json`).
    pub view_summary: serde_json::Value,
}

/// A Foxglove WebSocket client on its own thread (`foxglove.sdk.v1`, the synchronous
/// `tungstenite` client): subscribes to every channel the server advertises and counts
/// the message frames until `stop`. Returns (channels, messages).
fn view_client(
    listen: std::net::SocketAddr,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<anyhow::Result<(usize, u64)>> {
    std::thread::spawn(move || -> anyhow::Result<(usize, u64)> {
        use tungstenite::client::IntoClientRequest;
        use tungstenite::Message as Ws;
        let deadline = Instant::now() + Duration::from_secs(20);
        let stream = loop {
            match std::net::TcpStream::connect(listen) {
                Ok(s) => break s,
                Err(_) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(50))
                }
                Err(e) => {
                    return Err(e).with_context(|| format!("connecting to the view on {listen}"))
                }
            }
        };
        stream.set_read_timeout(Some(Duration::from_millis(100)))?;
        let mut request = format!("ws://{listen}").into_client_request()?;
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            tungstenite::http::HeaderValue::from_static("foxglove.sdk.v1"),
        );
        let (mut ws, _) = tungstenite::client(request, stream)
            .map_err(|e| anyhow::anyhow!("the WebSocket handshake with {listen}: {e}"))?;
        let (mut channels, mut messages, mut next_id) = (0usize, 0u64, 1u32);
        while !stop.load(Ordering::Acquire) {
            match ws.read() {
                Ok(Ws::Text(t)) => {
                    let v: serde_json::Value = serde_json::from_str(t.as_str())?;
                    if v["op"] == "advertise" {
                        let subs: Vec<serde_json::Value> = v["channels"]
                            .as_array()
                            .into_iter()
                            .flatten()
                            .map(|c| {
                                next_id += 1;
                                serde_json::json!({"id": next_id, "channelId": c["id"]})
                            })
                            .collect();
                        channels += subs.len();
                        let sub = serde_json::json!({"op": "subscribe", "subscriptions": subs});
                        ws.send(Ws::text(sub.to_string()))?;
                    }
                }
                Ok(Ws::Binary(_)) => messages += 1,
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(anyhow::anyhow!("reading from the view: {e}")),
            }
        }
        let _ = ws.close(None);
        Ok((channels, messages))
    })
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
    input_seq: u64,
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
    (mode, realtime_priority): (LoopMode, Option<u8>),
    stop: Arc<AtomicBool>,
    ready: Arc<AtomicBool>,
    capacity: usize,
) -> anyhow::Result<Vec<Stamps>> {
    vibro_service::realtime::enter(realtime_priority)?;
    let names = ServiceNames::new(&prefix)?;
    let node = create_node("vibrocomp-latency-rx")?;
    let sub = StreamSubscriber::<CompensatedBlock>::open(&node, &names, Stream::Compensated)?;
    ready.store(true, Ordering::Release);
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
                input_seq: b.input_seq,
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
    let ready = Arc::new(AtomicBool::new(false));
    let capacity = (args.duration_s * args.rate_hz / f64::from(args.block_samples)) as usize + 16;
    let rx = {
        let (prefix, stop) = (prefix.to_string(), Arc::clone(&stop));
        let mode = (args.mode, args.realtime_priority);
        let ready = Arc::clone(&ready);
        std::thread::Builder::new()
            .name("latency-rx".into())
            .spawn(move || receive_iceoryx(prefix, mode, stop, ready, capacity))?
    };
    // The receiver subscribes, and the services' (or peers') inputs are connected,
    // before the first block. The receiver is not an `accel` subscriber: it says so
    // itself (waiting for two `accel` subscribers timed out on every run).
    let t = Instant::now();
    let connected = || {
        ready.load(Ordering::Acquire)
            && accel.subscriber_count() >= 1
            && vib.subscriber_count() >= 1
    };
    while !connected() {
        if rx.is_finished() || t.elapsed() > Duration::from_secs(10) {
            stop.store(true, Ordering::Release);
            if rx.is_finished() {
                rx.join()
                    .map_err(|_| anyhow::anyhow!("the receiver thread panicked"))??;
            }
            bail!(
                "the rig's ports on {prefix:?} did not connect within 10 s: receiver subscribed {}, {} accel and {} vib subscribers (want at least 1 each)",
                ready.load(Ordering::Acquire),
                accel.subscriber_count(),
                vib.subscriber_count()
            );
        }
        std::thread::sleep(Duration::from_millis(5));
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
    (ka, kv, stamps): (u64, u64, &[Stamps]),
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
        view: None,
    })
}

fn spec_for(prefix: &str, mode: LoopMode, realtime_priority: Option<u8>) -> SystemSpec {
    SystemSpec {
        prefix: prefix.to_string(),
        mode: Some(mode.as_str().to_string()),
        realtime_priority,
        json: true,
        ..SystemSpec::default()
    }
}

fn losses(summary: &serde_json::Value, stream: &str) -> u64 {
    let g = |k: &str| summary[stream][k].as_u64().unwrap_or(0);
    g("lost_messages") + g("lost_samples") + summary["undelivered"].as_u64().unwrap_or(0)
}

/// The vibrocomp pipeline's run, with what the soak reads beside the hops.
struct VibrocompRun {
    run: PipelineRun,
    stamps: Vec<Stamps>,
    /// The services' JSON summaries at exit.
    compensator: serde_json::Value,
    estimator: serde_json::Value,
    /// The services' resident memory, sampled every second while the rig ran.
    memory: Vec<MemorySeries>,
}

fn run_vibrocomp(
    args: &LatencyArgs,
    k1: [f64; 3],
    log: &Path,
    prefix: &str,
    estimator_config: Option<&Path>,
) -> anyhow::Result<VibrocompRun> {
    let mut spec = spec_for(prefix, args.mode, args.realtime_priority);
    spec.estimator_config = estimator_config.map(Path::to_path_buf);
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
    if args.view {
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
    let result = run_iceoryx(args, prefix, k1);
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
    let lost = losses(&c, "accel") + losses(&e, "vib");
    let name = if view.is_some() {
        "vibrocomp (iceoryx2), live view + 1 client"
    } else {
        "vibrocomp (iceoryx2)"
    };
    let mut run = summarize(name, args, (ka, kv, &stamps), lost, cpu)?;
    run.view = view;
    Ok(VibrocompRun {
        run,
        stamps,
        compensator: c,
        estimator: e,
        memory,
    })
}

/// This executable's `latency-peer` with `args`, its stderr appended to `log`
/// (`what`: how an error names it).
pub(super) fn spawn_peer(
    args: &[&str],
    log: &Path,
    what: &str,
) -> anyhow::Result<std::process::Child> {
    std::process::Command::new(std::env::current_exe()?)
        .arg("latency-peer")
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(log)?,
        )
        .spawn()
        .with_context(|| format!("starting {what}"))
}

fn run_bare(args: &LatencyArgs, k1: [f64; 3], log: &Path) -> anyhow::Result<PipelineRun> {
    let prefix = private_prefix("vcbare");
    let spawn = |peer: &str, what: &str| {
        spawn_peer(
            &[peer, "--prefix", &prefix, "--mode", args.mode.as_str()],
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
    let (ka, kv, stamps) = run_iceoryx(args, &prefix, k1)?;
    let cpu = cpu.finish();
    drop(sink);
    drop(forwarder);
    summarize("bare iceoryx2", args, (ka, kv, &stamps), 0, cpu)
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

fn run_uds(
    args: &LatencyArgs,
    k1: [f64; 3],
    log: &Path,
    estimator_config: Option<&Path>,
) -> anyhow::Result<PipelineRun> {
    let dir = std::env::temp_dir().join(format!("vibrocomp-uds-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let exe = std::env::current_exe()?;
    let mut child = std::process::Command::new(exe);
    child
        .args(["latency-peer", "uds", "--socket-dir"])
        .arg(&dir);
    if let Some(c) = estimator_config {
        child.arg("--estimator-config").arg(c);
    }
    let mut child = child
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
                input_seq: b.input_seq,
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
    summarize("Unix sockets", args, (ka, kv, &stamps), 0, cpu)
}

/// A process's resident memory, sampled every second.
struct MemorySeries {
    process: String,
    /// Seconds since the rig started sending.
    t_s: Vec<f64>,
    /// `VmRSS` and `RssAnon` of `/proc/PID/status`, KiB.
    rss_kib: Vec<u64>,
    anon_kib: Vec<u64>,
}

/// `key` (e.g. `VmRSS`) of `/proc/PID/status`, KiB.
fn status_kib(status: &str, key: &str) -> Option<u64> {
    let line = status
        .lines()
        .find(|l| l.strip_prefix(key).is_some_and(|r| r.starts_with(':')))?;
    line[key.len() + 1..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Samples the processes' memory once a second on a thread of its own, until
/// [`MemorySampler::finish`].
struct MemorySampler {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Vec<MemorySeries>>,
}

impl MemorySampler {
    fn start(pids: &[(&str, u32)]) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let pids: Vec<(String, u32)> = pids.iter().map(|&(n, p)| (n.to_string(), p)).collect();
        let flag = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let mut series: Vec<MemorySeries> = pids
                .iter()
                .map(|(n, _)| MemorySeries {
                    process: n.clone(),
                    t_s: Vec::new(),
                    rss_kib: Vec::new(),
                    anon_kib: Vec::new(),
                })
                .collect();
            let start = Instant::now();
            let mut k = 0u32;
            'sampling: loop {
                let t = start.elapsed().as_secs_f64();
                for ((_, pid), s) in pids.iter().zip(&mut series) {
                    let Ok(status) = std::fs::read_to_string(format!("/proc/{pid}/status")) else {
                        continue;
                    };
                    if let (Some(rss), Some(anon)) =
                        (status_kib(&status, "VmRSS"), status_kib(&status, "RssAnon"))
                    {
                        s.t_s.push(t);
                        s.rss_kib.push(rss);
                        s.anon_kib.push(anon);
                    }
                }
                k += 1;
                let next = Duration::from_secs(u64::from(k));
                loop {
                    if flag.load(Ordering::Acquire) {
                        break 'sampling;
                    }
                    let now = start.elapsed();
                    if now >= next {
                        break;
                    }
                    std::thread::sleep((next - now).min(Duration::from_millis(50)));
                }
            }
            series
        });
        Self { stop, thread }
    }

    fn finish(self) -> Vec<MemorySeries> {
        self.stop.store(true, Ordering::Release);
        self.thread.join().unwrap_or_default()
    }
}

/// "Flat": after the warm-up, the anonymous resident memory (`RssAnon`) never rises
/// more than this above its first sample after the warm-up.
const MEMORY_FLAT_BOUND_KIB: u64 = 1024;

/// One process's memory over the soak, KiB.
#[derive(Debug, Serialize)]
struct MemorySummary {
    process: String,
    samples: usize,
    first_kib: u64,
    last_kib: u64,
    max_kib: u64,
    /// The first sample at or after `--warmup-s`.
    after_warmup_kib: u64,
    /// Highest sample after the warm-up minus `after_warmup_kib`.
    growth_after_warmup_kib: u64,
    /// Least-squares slope of the samples after the warm-up, KiB per minute.
    slope_kib_per_min: f64,
    anon_first_kib: u64,
    anon_last_kib: u64,
    /// `RssAnon` (the heap and stacks: what a leak grows), the same way as
    /// `growth_after_warmup_kib`. `VmRSS` also counts the shared-memory pages of the
    /// iceoryx2 segments as the process first touches them, which stops at the
    /// segments' size.
    anon_growth_after_warmup_kib: u64,
    /// `VmRSS`: the highest sample of the second half of the soak minus the sample at
    /// its middle. A leak keeps growing there; a one-time step while the services
    /// settle (a thread's first allocation, a table built once) does not.
    second_half_growth_kib: u64,
    /// `RssAnon` grew at most [`MEMORY_FLAT_BOUND_KIB`] after the warm-up.
    flat: bool,
    /// `VmRSS`, one sample a second.
    series_kib: Vec<u64>,
}

fn memory_summary(s: &MemorySeries, warmup_s: f64) -> MemorySummary {
    let first = s.rss_kib.first().copied().unwrap_or(0);
    let last = s.rss_kib.last().copied().unwrap_or(0);
    // Samples at or after the warm-up; all of them in a run too short to have any.
    let from = s.t_s.iter().position(|&t| t >= warmup_s).unwrap_or(0);
    let (t, m) = (&s.t_s[from..], &s.rss_kib[from..]);
    let base = m.first().copied().unwrap_or(0);
    let growth = m.iter().max().copied().unwrap_or(0).saturating_sub(base);
    let anon = &s.anon_kib[from.min(s.anon_kib.len())..];
    let anon_growth = anon
        .iter()
        .max()
        .copied()
        .unwrap_or(0)
        .saturating_sub(anon.first().copied().unwrap_or(0));
    let n = t.len() as f64;
    let slope = if t.len() >= 2 {
        let (tm, mm) = (
            t.iter().sum::<f64>() / n,
            m.iter().map(|&x| x as f64).sum::<f64>() / n,
        );
        let sxy: f64 = t
            .iter()
            .zip(m)
            .map(|(&t, &x)| (t - tm) * (x as f64 - mm))
            .sum();
        let sxx: f64 = t.iter().map(|&t| (t - tm) * (t - tm)).sum();
        if sxx > 0.0 {
            60.0 * sxy / sxx
        } else {
            0.0
        }
    } else {
        0.0
    };
    MemorySummary {
        process: s.process.clone(),
        samples: s.rss_kib.len(),
        first_kib: first,
        last_kib: last,
        max_kib: s.rss_kib.iter().max().copied().unwrap_or(0),
        after_warmup_kib: base,
        growth_after_warmup_kib: growth,
        slope_kib_per_min: slope,
        anon_first_kib: s.anon_kib.first().copied().unwrap_or(0),
        anon_last_kib: s.anon_kib.last().copied().unwrap_or(0),
        anon_growth_after_warmup_kib: anon_growth,
        second_half_growth_kib: {
            let half = &s.rss_kib[s.rss_kib.len() / 2..];
            let mid = half.first().copied().unwrap_or(0);
            half.iter().max().copied().unwrap_or(0).saturating_sub(mid)
        },
        flat: !anon.is_empty() && anon_growth <= MEMORY_FLAT_BOUND_KIB,
        series_kib: s.rss_kib.clone(),
    }
}

/// Every accelerometer block answered once, in order: from the compensated blocks'
/// `input_seq`.
#[derive(Debug, Serialize)]
struct AccelCheck {
    sent: u64,
    /// Distinct blocks `0..sent` answered.
    answered: u64,
    /// Blocks never answered.
    missing: u64,
    /// Blocks answered more than once (extra answers).
    duplicates: u64,
    /// Answers whose `input_seq` is not the previous one's plus 1.
    out_of_order: u64,
    /// Answers to blocks the rig never sent.
    unknown: u64,
    continuous: bool,
}

fn accel_check(sent: u64, stamps: &[Stamps]) -> AccelCheck {
    let mut seen = vec![0u32; sent as usize];
    let (mut unknown, mut out_of_order) = (0u64, 0u64);
    let mut prev: Option<u64> = None;
    for s in stamps {
        match seen.get_mut(s.input_seq as usize) {
            Some(n) => *n += 1,
            None => unknown += 1,
        }
        if prev.is_some_and(|p| s.input_seq != p + 1) || (prev.is_none() && s.input_seq != 0) {
            out_of_order += 1;
        }
        prev = Some(s.input_seq);
    }
    let answered = seen.iter().filter(|&&n| n > 0).count() as u64;
    let duplicates: u64 = seen.iter().map(|&n| u64::from(n.saturating_sub(1))).sum();
    let missing = sent - answered;
    AccelCheck {
        sent,
        answered,
        missing,
        duplicates,
        out_of_order,
        unknown,
        continuous: missing == 0 && duplicates == 0 && out_of_order == 0 && unknown == 0,
    }
}

/// The services' own counters at exit.
#[derive(Debug, Serialize)]
struct ServiceCounts {
    compensator_accel_received: u64,
    /// Lost messages and samples on `{prefix}accel`, plus outputs not delivered.
    compensator_lost: u64,
    estimator_vib_received: u64,
    estimator_lost: u64,
    estimator_rate_mismatches: u64,
    estimates_published: u64,
    estimates_flagged: u64,
    /// From the block that completes a window to its estimate: the estimator's own
    /// `latency` (count, p50_ns, p99_ns, max_ns).
    estimator_window: serde_json::Value,
}

/// One line of the percentile table.
#[derive(Debug, Serialize)]
struct PercentileRow {
    percentile: f64,
    value_us: f64,
    /// Blocks whose end-to-end latency is at or below `value_us` (counted exactly).
    blocks_at_or_below: u64,
}

/// One bucket: blocks with `lower_us < latency <= upper_us` (`upper_us` null: above
/// the last bound).
#[derive(Debug, Serialize)]
struct BucketRow {
    lower_us: f64,
    upper_us: Option<f64>,
    blocks: u64,
}

/// The end-to-end latency per accelerometer block after the warm-up.
#[derive(Debug, Serialize)]
struct EndToEndHistogram {
    count: u64,
    percentiles: Vec<PercentileRow>,
    buckets: Vec<BucketRow>,
}

const BUCKET_BOUNDS_US: [f64; 16] = [
    100.0, 150.0, 200.0, 250.0, 300.0, 400.0, 500.0, 750.0, 1000.0, 1250.0, 1500.0, 2000.0, 3000.0,
    5000.0, 10000.0, 50000.0,
];

fn end_to_end_histogram(
    args: &LatencyArgs,
    stamps: &[Stamps],
) -> anyhow::Result<EndToEndHistogram> {
    let warmup_ns = (args.warmup_s * 1e9) as u64;
    // The same values as the hop table's end to end (`Histograms::record`).
    let values_ns: Vec<u64> = stamps
        .iter()
        .filter(|s| s.t0_ns >= warmup_ns)
        .map(|s| s.sub_recv_ns.saturating_sub(s.input_publish_ns).max(1))
        .collect();
    let mut h = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3).context("histogram")?;
    for &v in &values_ns {
        let _ = h.record(v);
    }
    let percentiles = if h.is_empty() {
        Vec::new()
    } else {
        [
            50.0, 75.0, 90.0, 95.0, 99.0, 99.5, 99.9, 99.95, 99.99, 100.0,
        ]
        .iter()
        .map(|&p| {
            let v = if p >= 100.0 {
                h.max()
            } else {
                h.value_at_quantile(p / 100.0)
            };
            PercentileRow {
                percentile: p,
                value_us: v as f64 * 1e-3,
                blocks_at_or_below: values_ns.iter().filter(|&&x| x <= v).count() as u64,
            }
        })
        .collect()
    };
    let mut lower_us = 0.0;
    let mut buckets = Vec::with_capacity(BUCKET_BOUNDS_US.len() + 1);
    for upper in BUCKET_BOUNDS_US.iter().map(|&u| Some(u)).chain([None]) {
        let (lo_ns, hi_ns) = (lower_us * 1e3, upper.map_or(f64::INFINITY, |u| u * 1e3));
        let blocks = values_ns
            .iter()
            .filter(|&&x| (x as f64) > lo_ns && (x as f64) <= hi_ns)
            .count() as u64;
        buckets.push(BucketRow {
            lower_us,
            upper_us: upper,
            blocks,
        });
        lower_us = upper.unwrap_or(lower_us);
    }
    Ok(EndToEndHistogram {
        count: values_ns.len() as u64,
        percentiles,
        buckets,
    })
}

/// The machine's CPU time (`/proc/stat`, all cores): busy and total ticks.
struct MachineCpu(Option<(u64, u64)>);

impl MachineCpu {
    fn read() -> Option<(u64, u64)> {
        let stat = std::fs::read_to_string("/proc/stat").ok()?;
        let line = stat.lines().find(|l| l.starts_with("cpu "))?;
        let f: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .filter_map(|x| x.parse().ok())
            .collect();
        // user nice system idle iowait irq softirq steal ...: idle and iowait are idle.
        let total: u64 = f.iter().take(8).sum();
        let idle = f.get(3)? + f.get(4).copied().unwrap_or(0);
        Some((total - idle, total))
    }

    fn now() -> Self {
        Self(Self::read())
    }

    fn busy_percent_since(&self) -> f64 {
        match (self.0, Self::read()) {
            (Some((b0, t0)), Some((b1, t1))) if t1 > t0 => {
                100.0 * (b1 - b0) as f64 / (t1 - t0) as f64
            }
            _ => 0.0,
        }
    }
}

/// The background load: `latency-peer load` and what it said at its end.
#[derive(Debug, Serialize)]
struct LoadReport {
    input: String,
    jobs: u32,
    pid: u32,
    runs_started: u64,
    runs_completed: u64,
    failures: u64,
    /// The loop's own CPU plus its diagnose runs', percent of one core over its life.
    cpu_percent: f64,
    wall_s: f64,
    /// The loop exited on our SIGTERM, after stopping its runs under way.
    stopped: bool,
}

fn start_load(input: &Path, jobs: u32, log: &Path) -> anyhow::Result<std::process::Child> {
    let mut c = std::process::Command::new(std::env::current_exe()?);
    c.args(["latency-peer", "load", "--input"])
        .arg(input)
        .args(["--jobs", &jobs.to_string()])
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(log)?,
        );
    vibro_service::supervise::stop_with_parent(&mut c);
    c.spawn().context("starting the background load")
}

fn stop_load(
    mut child: std::process::Child,
    input: &Path,
    jobs: u32,
) -> anyhow::Result<LoadReport> {
    let pid = child.id();
    vibro_service::supervise::terminate(&child);
    let t = Instant::now();
    let mut status = None;
    while t.elapsed() < Duration::from_secs(10) {
        if let Some(s) = child.try_wait()? {
            status = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    if status.is_none() {
        let _ = child.kill();
        let _ = child.wait();
    }
    let mut out = String::new();
    if let Some(mut o) = child.stdout.take() {
        let _ = o.read_to_string(&mut out);
    }
    let v: serde_json::Value = serde_json::from_str(out.trim()).with_context(|| {
        format!("the background load (pid {pid}) printed no summary: {out:?}; see its log")
    })?;
    let n = |k: &str| v[k].as_u64().unwrap_or(0);
    if n("failures") > 0 {
        bail!(
            "--load {}: `vibrocomp lab diagnose {}` failed: {}",
            input.display(),
            input.display(),
            v["first_failure"].as_str().unwrap_or("(no message)")
        );
    }
    let wall_s = v["wall_s"].as_f64().unwrap_or(0.0);
    Ok(LoadReport {
        input: input.display().to_string(),
        jobs,
        pid,
        runs_started: n("runs_started"),
        runs_completed: n("runs_completed"),
        failures: n("failures"),
        cpu_percent: if wall_s > 0.0 {
            100.0 * v["cpu_s"].as_f64().unwrap_or(0.0) / wall_s
        } else {
            0.0
        },
        wall_s,
        stopped: status.is_some_and(|s| s.success()),
    })
}

/// CPU seconds (user + system) of this process, and of its children that were waited
/// for.
fn rusage_cpu_s() -> f64 {
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    let mut total = 0.0;
    for who in [libc::RUSAGE_SELF, libc::RUSAGE_CHILDREN] {
        // SAFETY: getrusage writes one rusage into the zeroed struct we own.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        if unsafe { libc::getrusage(who, &mut u) } == 0 {
            total += tv(u.ru_utime) + tv(u.ru_stime);
        }
    }
    total
}

/// The load peer (see [`PeerCommand::Load`]).
fn peer_load(input: &Path, jobs: u32) -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let stop = install_stop()?;
    let start = Instant::now();
    let err_path = |k: u64| {
        std::env::temp_dir().join(format!("vibrocomp-load-{}-{k}.err", std::process::id()))
    };
    let (mut started, mut completed, mut failures) = (0u64, 0u64, 0u64);
    let mut first_failure: Option<String> = None;
    let mut running: Vec<(std::process::Child, u64)> = Vec::new();
    while !stop.load(Ordering::Acquire) && failures == 0 {
        while running.len() < jobs as usize {
            let err = err_path(started);
            let mut c = std::process::Command::new(&exe);
            c.args(["lab", "diagnose"])
                .arg(input)
                .stdin(std::process::Stdio::null())
                .stdout(std::process::Stdio::null())
                .stderr(std::fs::File::create(&err).with_context(|| err.display().to_string())?);
            vibro_service::supervise::stop_with_parent(&mut c);
            let child = c.spawn().with_context(|| {
                format!("starting `vibrocomp lab diagnose {}`", input.display())
            })?;
            running.push((child, started));
            started += 1;
        }
        let mut i = 0;
        while i < running.len() {
            match running[i].0.try_wait()? {
                Some(status) => {
                    let (_, k) = running.swap_remove(i);
                    if status.success() {
                        completed += 1;
                    } else {
                        failures += 1;
                        let text = std::fs::read_to_string(err_path(k)).unwrap_or_default();
                        first_failure.get_or_insert_with(|| format!("{status}: {}", text.trim()));
                    }
                    let _ = std::fs::remove_file(err_path(k));
                }
                None => i += 1,
            }
        }
        // Short: the load's CPU is the diagnose runs', not this loop's waits.
        std::thread::sleep(Duration::from_millis(1));
    }
    for (mut c, k) in running {
        let _ = c.kill();
        let _ = c.wait();
        let _ = std::fs::remove_file(err_path(k));
    }
    let v = serde_json::json!({
        "runs_started": started,
        "runs_completed": completed,
        "failures": failures,
        "first_failure": first_failure,
        "cpu_s": rusage_cpu_s(),
        "wall_s": start.elapsed().as_secs_f64(),
    });
    println!("{v}");
    Ok(())
}

/// The estimator's configuration for `--vib-rate-hz`: `None` (its default one) when
/// the default's `sample_rate_hz` is that rate; else the default's text with
/// `[estimator] sample_rate_hz` set to it, written to `path` and validated.
fn estimator_config_for(vib_rate_hz: f64, path: &Path) -> anyhow::Result<Option<PathBuf>> {
    let default = Path::new(<vibro_estimator::Config as ServiceConfig>::DEFAULT_CONFIG_PATH);
    let (text, source) = if default.is_file() {
        (
            std::fs::read_to_string(default)
                .with_context(|| format!("reading {}", default.display()))?,
            default.display().to_string(),
        )
    } else {
        (
            <vibro_estimator::Config as ServiceConfig>::shipped_text().to_string(),
            "the shipped estimator configuration".to_string(),
        )
    };
    let mut table: toml::Table = text.parse().with_context(|| source.clone())?;
    let Some(est) = table.get_mut("estimator").and_then(|v| v.as_table_mut()) else {
        bail!("{source}: no [estimator] table");
    };
    if est.get("sample_rate_hz").and_then(|v| v.as_float()) == Some(vib_rate_hz) {
        return Ok(None);
    }
    est.insert("sample_rate_hz".into(), toml::Value::Float(vib_rate_hz));
    std::fs::write(path, toml::to_string(&table)?)
        .with_context(|| format!("writing {}", path.display()))?;
    <vibro_estimator::Config as ServiceConfig>::load(path).with_context(|| {
        format!("--vib-rate-hz = {vib_rate_hz}: {source} at this sample rate is not valid")
    })?;
    Ok(Some(path.to_path_buf()))
}

#[derive(Debug, Serialize)]
struct SoakReport {
    soak: bool,
    mode: String,
    /// `SCHED_FIFO` priority of the services' hot loops and the rig's receiver.
    realtime_priority: Option<u8>,
    prefix: String,
    duration_s: f64,
    warmup_s: f64,
    rate_hz: f64,
    block_samples: u32,
    vib_rate_hz: f64,
    vib_block_samples: u32,
    /// The estimator ran with `sample_rate_hz = vib_rate_hz` (a private configuration
    /// when the default's rate differs).
    estimator_config: String,
    run: PipelineRun,
    accel: AccelCheck,
    services: ServiceCounts,
    /// Every vibration block the rig sent was taken by the estimator.
    vib_blocks_taken: bool,
    /// Accelerometer blocks not answered, plus the services' own losses.
    lost: u64,
    memory_flat_bound_kib: u64,
    memory: Vec<MemorySummary>,
    load: Option<LoadReport>,
    /// All cores' busy time over the soak (from `/proc/stat`), percent of all of them:
    /// ours and whatever else the machine ran.
    machine_busy_percent: f64,
    cores: usize,
    end_to_end_histogram: EndToEndHistogram,
    /// One accelerometer sample period, us.
    target_p999_us: f64,
    p999_met: bool,
}

fn run_soak(
    args: &LatencyArgs,
    k1: [f64; 3],
    log: &Path,
    prefix: &str,
    estimator_config: Option<&Path>,
) -> anyhow::Result<SoakReport> {
    let machine = MachineCpu::now();
    // The load first, so that the services start and run beside it.
    let load = match &args.load {
        Some(input) => Some(start_load(input, args.load_jobs, log)?),
        None => None,
    };
    let result = run_vibrocomp(args, k1, log, prefix, estimator_config);
    let machine_busy_percent = machine.busy_percent_since();
    // Stopped whatever happened; the pipeline's error, if any, comes first.
    let load = match (load, &args.load) {
        (Some(child), Some(input)) => Some(stop_load(child, input, args.load_jobs)),
        _ => None,
    };
    let v = result?;
    let load = load.transpose()?;
    let g = |s: &serde_json::Value, a: &str, b: &str| s[a][b].as_u64().unwrap_or(0);
    let services = ServiceCounts {
        compensator_accel_received: g(&v.compensator, "accel", "received"),
        compensator_lost: losses(&v.compensator, "accel"),
        estimator_vib_received: g(&v.estimator, "vib", "received"),
        estimator_lost: losses(&v.estimator, "vib"),
        estimator_rate_mismatches: v.estimator["rate_mismatches"].as_u64().unwrap_or(0),
        estimates_published: v.estimator["estimates_published"].as_u64().unwrap_or(0),
        estimates_flagged: v.estimator["estimates_flagged"].as_u64().unwrap_or(0),
        estimator_window: v.estimator["latency"].clone(),
    };
    let accel = accel_check(v.run.accel_blocks_sent, &v.stamps);
    let target_p999_us = 1e6 / args.rate_hz;
    Ok(SoakReport {
        soak: true,
        mode: args.mode.as_str().to_string(),
        realtime_priority: args.realtime_priority,
        prefix: prefix.to_string(),
        duration_s: args.duration_s,
        warmup_s: args.warmup_s,
        rate_hz: args.rate_hz,
        block_samples: args.block_samples,
        vib_rate_hz: args.vib_rate_hz,
        vib_block_samples: args.vib_block_samples,
        estimator_config: estimator_config
            .map_or("default".to_string(), |p| p.display().to_string()),
        vib_blocks_taken: services.estimator_vib_received == v.run.vib_blocks_sent
            && services.estimator_rate_mismatches == 0,
        lost: accel.missing + services.compensator_lost + services.estimator_lost,
        accel,
        services,
        memory_flat_bound_kib: MEMORY_FLAT_BOUND_KIB,
        memory: v
            .memory
            .iter()
            .map(|s| memory_summary(s, args.warmup_s))
            .collect(),
        load,
        machine_busy_percent,
        cores: std::thread::available_parallelism().map_or(0, |n| n.get()),
        end_to_end_histogram: end_to_end_histogram(args, &v.stamps)?,
        target_p999_us,
        p999_met: v.run.end_to_end.count > 0 && v.run.end_to_end.p999_us < target_p999_us,
        run: v.run,
    })
}

fn print_soak(r: &SoakReport) -> anyhow::Result<()> {
    outln!(
        "Soak, {} mode ({}), prefix {}: {} s, accelerometer blocks of {} at {} Hz, vibration blocks of {} at {} Hz (estimator configuration: {}); first {} s left out",
        r.mode,
        r.realtime_priority.map_or_else(|| "normal scheduling".to_string(), |p| format!("SCHED_FIFO priority {p}")),
        r.prefix, r.duration_s, r.block_samples, r.rate_hz, r.vib_block_samples, r.vib_rate_hz, r.estimator_config, r.warmup_s
    )?;
    let a = &r.accel;
    outln!(
        "accelerometer blocks: {} sent, {} answered, {} missing, {} duplicate, {} out of order; input sequence {}",
        a.sent, a.answered, a.missing, a.duplicates, a.out_of_order,
        if a.continuous { "continuous" } else { "NOT continuous" }
    )?;
    let s = &r.services;
    outln!(
        "services: compensator received {} accelerometer blocks, lost {}; estimator received {} of {} vibration blocks, lost {}, rate mismatches {}, {} estimates ({} flagged); window -> estimate {}",
        s.compensator_accel_received, s.compensator_lost, s.estimator_vib_received, r.run.vib_blocks_sent,
        s.estimator_lost, s.estimator_rate_mismatches, s.estimates_published, s.estimates_flagged,
        s.estimator_window
    )?;
    outln!(
        "lost: {}; CPU {}",
        r.lost,
        r.run
            .cpu_percent
            .iter()
            .map(|(n, p)| format!("{n} {p:.1}%"))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    match &r.load {
        Some(l) => outln!(
            "load: `vibrocomp lab diagnose {}` x{}: {} runs started, {} completed, CPU {:.1}% of one core over {:.1} s, {}",
            l.input, l.jobs, l.runs_started, l.runs_completed, l.cpu_percent, l.wall_s,
            if l.stopped { "stopped" } else { "NOT stopped cleanly" }
        )?,
        None => outln!("load: none")?,
    }
    outln!(
        "machine: {} cores, {:.1}% busy over the soak (everything it ran)",
        r.cores,
        r.machine_busy_percent
    )?;
    outln!(
        "memory (KiB, every second; flat = RssAnon at most {} KiB above its first sample after the warm-up; VmRSS also counts the iceoryx2 segments' pages as they are first touched):",
        r.memory_flat_bound_kib
    )?;
    for m in &r.memory {
        outln!(
            "  {:<12} {} samples of VmRSS: first {}, after warm-up {}, last {}, max {}, growth {}, slope {:+.1} KiB/min; RssAnon {} -> {}, growth after warm-up {}; VmRSS growth over the second half {}: {}",
            m.process, m.samples, m.first_kib, m.after_warmup_kib, m.last_kib, m.max_kib,
            m.growth_after_warmup_kib, m.slope_kib_per_min, m.anon_first_kib, m.anon_last_kib,
            m.anon_growth_after_warmup_kib,
            m.second_half_growth_kib,
            if m.flat { "flat" } else { "NOT flat" }
        )?;
    }
    print_hops(&r.run)?;
    let h = &r.end_to_end_histogram;
    outln!("end to end per accelerometer block, {} blocks:", h.count)?;
    outln!("  {:>10}{:>12}{:>12}", "percentile", "us", "blocks <=")?;
    for p in &h.percentiles {
        outln!(
            "  {:>10}{:>12.1}{:>12}",
            p.percentile,
            p.value_us,
            p.blocks_at_or_below
        )?;
    }
    outln!("  {:>20}{:>10}", "latency, us", "blocks")?;
    for b in h.buckets.iter().filter(|b| b.blocks > 0) {
        let range = match b.upper_us {
            Some(u) => format!("{} .. {}", b.lower_us, u),
            None => format!("> {}", b.lower_us),
        };
        outln!("  {:>20}{:>10}", range, b.blocks)?;
    }
    outln!(
        "p99.9 {:.1} us against one accelerometer sample period {:.1} us: {}",
        r.run.end_to_end.p999_us,
        r.target_p999_us,
        if r.p999_met { "met" } else { "NOT met" }
    )?;
    Ok(())
}

fn print_hops(r: &PipelineRun) -> anyhow::Result<()> {
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
    Ok(())
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
    anyhow::ensure!(
        (1..=64).contains(&args.load_jobs),
        "--load-jobs = {}: must be 1..=64",
        args.load_jobs
    );
    if let Some(input) = &args.load {
        anyhow::ensure!(
            input.is_file(),
            "--load {}: not a file (a campaign table or an MCAP log for `lab diagnose`)",
            input.display()
        );
    }
    let prefix = match &args.prefix {
        Some(p) => {
            ServiceNames::new(p).with_context(|| format!("--prefix {p:?}"))?;
            p.clone()
        }
        None => private_prefix("vclat"),
    };
    let k1 = vibro_compensator::Config::load_default()?
        .model
        .triad
        .passports
        .map(|p| p.k1_v_per_g);
    let tmp = |what: &str| {
        std::env::temp_dir().join(format!("vibrocomp-latency-{}.{what}", std::process::id()))
    };
    let log = tmp("log");
    // The estimator's configuration follows --vib-rate-hz (its blocks are refused at
    // any other rate).
    let estimator_config = estimator_config_for(args.vib_rate_hz, &tmp("estimator.toml"))?;
    let est = estimator_config.as_deref();
    let result = if args.soak {
        run_soak(args, k1, &log, &prefix, est).map(|r| Outcome::Soak(Box::new(r)))
    } else {
        run_pipelines(args, k1, &log, &prefix, est).map(Outcome::Pipelines)
    };
    let _ = std::fs::remove_file(&log);
    if let Some(p) = &estimator_config {
        let _ = std::fs::remove_file(p);
    }
    match result? {
        Outcome::Soak(soak) if args.json => print_json(&soak),
        Outcome::Soak(soak) => print_soak(&soak),
        Outcome::Pipelines(runs) => print_latency(args, runs),
    }
}

enum Outcome {
    Pipelines(Vec<PipelineRun>),
    Soak(Box<SoakReport>),
}

fn run_pipelines(
    args: &LatencyArgs,
    k1: [f64; 3],
    log: &Path,
    prefix: &str,
    estimator_config: Option<&Path>,
) -> anyhow::Result<Vec<PipelineRun>> {
    let mut runs = vec![run_vibrocomp(args, k1, log, prefix, estimator_config)?.run];
    if !args.no_baselines {
        runs.push(run_bare(args, k1, log)?);
        runs.push(run_uds(args, k1, log, estimator_config)?);
    }
    if args.hosts == 2 {
        runs.push(hosts::run_bridged(args, k1, log, estimator_config)?);
        if !args.no_baselines {
            runs.push(hosts::run_bare_zenoh(args, k1, log)?);
        }
    }
    Ok(runs)
}

fn print_latency(args: &LatencyArgs, runs: Vec<PipelineRun>) -> anyhow::Result<()> {
    let ratios = (!args.no_baselines && runs.len() >= 3).then(|| {
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
        print_hops(r)?;
        if let Some(v) = &r.view {
            outln!(
                "  live view on ws://{}: its client subscribed to {} channels and received {} \
                 messages; the view dropped {}",
                v.listen,
                v.client_channels,
                v.client_messages,
                v.view_summary["dropped"]
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
fn peer_uds(dir: &Path, estimator_config: Option<&Path>) -> anyhow::Result<()> {
    let est_config = match estimator_config {
        Some(p) => <vibro_estimator::Config as ServiceConfig>::load(p)?,
        None => vibro_estimator::Config::load_default()?,
    };
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
        let mut est = vibro_estimator::InProcess::new(&est_config.estimator)?;
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
        PeerCommand::BareZenoh { endpoint, key } => {
            hosts::peer_bare_zenoh(endpoint, key, install_stop()?)
        }
        PeerCommand::Uds {
            socket_dir,
            estimator_config,
        } => peer_uds(socket_dir, estimator_config.as_deref()),
        PeerCommand::Load { input, jobs } => peer_load(input, *jobs),
    }
}
