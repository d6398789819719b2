//! # vibro-view
//!
//! The view channels (docs/view.md): beside the zero-copy wire streams, which pack a
//! block's samples interleaved by unit, messages made to be plotted by people, one
//! value per field per message, as Foxglove's plot takes them:
//!
//! - `/view/{unit}` ([`UnitStages`]): per accelerometer unit and compensated block, the
//!   acceleration at each stage of [P2 (17)-(20)] (`uncompensated_g` a(1),
//!   `main_removed_g` a(2), `compensated_g` a(4)), each as the block's mean, minimum
//!   and maximum, so that no peak between two messages is hidden; with a reference
//!   (`/truth`) the reference and each stage's error against it, sample by sample;
//! - `/view/vibration/{x,y,z}` ([`VibrationAxis`]): the estimate per body axis with
//!   named fields (the strongest tone's frequency, amplitude and phase, the broadband
//!   RMS, the kurtosis, the flags);
//! - `/view/health/{service}` ([`ServiceHealth`]): each heartbeat with the service and
//!   its state as protobuf enums;
//! - `/log`: the services' log lines (`{prefix}log/{service}`) as Foxglove's well-known
//!   `foxglove.Log`, for its Log panel.
//!
//! Each message is placed on the data's time (docs/logs.md, "Time"). The builder does
//! no I/O: [`ViewBuilder::on_message`] turns a wire message into view messages, which
//! the live view (`vibrocomp view`) sends to Foxglove through [`live::LiveServer`]: the
//! Foxglove SDK's WebSocket server behind a guard that bounds what a client can cost
//! (connections, handshake time, message sizes, log lines; issue 31).
//!
//! ```
//! use vibro_view::{ViewBuilder, UNIT_NAMES};
//! let mut view = ViewBuilder::new(UNIT_NAMES);
//! let mut out = Vec::new();
//! let hb = vibro_msgs::Heartbeat { service: 4, state: 2, ..vibro_msgs::Heartbeat::ZEROED };
//! view.on_message(&vibro_mcap::Message::Heartbeat(hb), &mut out);
//! assert!(out.is_empty(), "a heartbeat before any data waits for the data's time");
//! view.flush(&mut out);
//! assert_eq!(out[0].topic, "/view/health/compensator");
//! ```

#[cfg(feature = "live")]
pub mod live;

use prost::Message as _;
use vibro_mcap::view_proto::{ServiceHealth, Stage, UnitStages, VibrationAxis};
use vibro_mcap::{
    Message, ViewSchema, FOXGLOVE_LOG, VIEW_SERVICE_HEALTH, VIEW_UNIT_STAGES, VIEW_VIBRATION_AXIS,
};
use vibro_msgs::{
    CompensatedBlock, Heartbeat, LogLevel, LogLine, ServiceId, TruthBlock, VibEstimate, UNITS,
};

/// What the live view's server can fail with.
#[cfg(feature = "live")]
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("listening on {addr}")]
    Listen {
        addr: std::net::SocketAddr,
        source: std::io::Error,
    },
    #[error("starting the Foxglove WebSocket server on an ephemeral port of 127.0.0.1")]
    Server(#[source] foxglove::FoxgloveError),
    #[error("the Foxglove channel {topic}")]
    Channel {
        topic: String,
        source: foxglove::FoxgloveError,
    },
    #[error(
        "shutting the Foxglove server's port {port} of 127.0.0.1 to all but the live \
         view's guard"
    )]
    Gate { port: u16, source: std::io::Error },
    #[error("starting the live view's runtime")]
    Runtime(#[source] std::io::Error),
    #[error("the live view's {0} task ended abnormally (it panicked or was cancelled)")]
    Task(&'static str),
}

#[cfg(feature = "live")]
pub type Result<T> = std::result::Result<T, Error>;

/// The triad's unit names when no other are given (RIG.md's AK1..AK3).
pub const UNIT_NAMES: [&str; 3] = ["AK1", "AK2", "AK3"];

/// The body axes' names, in index order.
pub const AXES: [&str; 3] = ["x", "y", "z"];

/// Reference blocks kept to pair with the compensated blocks that answer them.
const TRUTH_KEPT: usize = 64;

/// Compensated blocks held for their reference block (a rig publishes the readings
/// and the reference of a block one after the other, and the compensated block can
/// come back between them); beyond, the oldest goes out without a reference.
const PENDING_KEPT: usize = 16;

/// One view message: its topic, schema, data time and protobuf bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewMessage {
    pub topic: String,
    pub schema: ViewSchema,
    /// The data time it belongs to, ns (docs/logs.md, "Time").
    pub log_time_ns: u64,
    pub data: Vec<u8>,
}

/// Every view topic for a triad with `units`, and its schema (what a viewer can
/// subscribe to before any message arrives).
pub fn topics(units: [&str; 3]) -> Vec<(String, ViewSchema)> {
    let mut out: Vec<(String, ViewSchema)> = units
        .iter()
        .map(|u| (format!("/view/{u}"), VIEW_UNIT_STAGES))
        .collect();
    out.extend(
        AXES.iter()
            .map(|a| (format!("/view/vibration/{a}"), VIEW_VIBRATION_AXIS)),
    );
    out.extend(
        ServiceId::ALL
            .iter()
            .map(|s| (format!("/view/health/{}", s.as_str()), VIEW_SERVICE_HEALTH)),
    );
    out.push((LOG_TOPIC.to_string(), FOXGLOVE_LOG));
    out
}

/// The topic of the services' log lines (`foxglove.Log`).
pub const LOG_TOPIC: &str = "/log";

/// A bounded queue of view messages between the thread that makes them (the iceoryx2
/// loop, which must never wait) and the thread that hands them to the viewers: when
/// full, the oldest message is dropped and counted, so that a sender falling behind
/// costs old messages, never the system's time.
#[derive(Debug)]
pub struct Outbox {
    queue: std::sync::Mutex<(std::collections::VecDeque<ViewMessage>, bool)>,
    ready: std::sync::Condvar,
    capacity: usize,
    dropped: std::sync::atomic::AtomicU64,
}

impl Outbox {
    /// A queue holding at most `capacity` messages (at least 1).
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            queue: std::sync::Mutex::new((
                std::collections::VecDeque::with_capacity(capacity),
                false,
            )),
            ready: std::sync::Condvar::new(),
            capacity,
            dropped: std::sync::atomic::AtomicU64::new(0),
        }
    }

    /// Queues `m`, dropping (and counting) the oldest when full. Never waits for the
    /// receiver (the lock is held for a push and a pop).
    pub fn push(&self, m: ViewMessage) {
        let mut q = self
            .queue
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if q.0.len() == self.capacity {
            q.0.pop_front();
            self.dropped
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        q.0.push_back(m);
        drop(q);
        self.ready.notify_one();
    }

    /// No more messages will come: [`Outbox::pop`] returns `None` once it is empty.
    pub fn close(&self) {
        let mut q = self
            .queue
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        q.1 = true;
        drop(q);
        self.ready.notify_all();
    }

    /// The oldest message, waiting for one; `None` once closed and empty.
    pub fn pop(&self) -> Option<ViewMessage> {
        let mut q = self
            .queue
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        loop {
            if let Some(m) = q.0.pop_front() {
                return Some(m);
            }
            if q.1 {
                return None;
            }
            q = self
                .ready
                .wait(q)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
    }

    /// Messages dropped so far because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// The mean, minimum and maximum of `values`; `None` when there are none or one is
/// not finite (a stage the compensator could not compute).
pub fn stage(values: impl Iterator<Item = f64>) -> Option<Stage> {
    let (mut n, mut sum, mut min, mut max) = (0usize, 0.0, f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        if !v.is_finite() {
            return None;
        }
        n += 1;
        sum += v;
        min = min.min(v);
        max = max.max(v);
    }
    (n > 0).then(|| Stage {
        mean: sum / n as f64,
        min,
        max,
    })
}

fn timestamp(ns: u64) -> prost_types::Timestamp {
    prost_types::Timestamp {
        seconds: (ns / 1_000_000_000) as i64,
        nanos: (ns % 1_000_000_000) as i32,
    }
}

/// Turns wire messages into view messages.
#[derive(Debug, Clone)]
pub struct ViewBuilder {
    units: [String; 3],
    /// Recent reference blocks, by `first_sample_index`.
    truth: std::collections::VecDeque<TruthBlock>,
    /// The latest data time seen (where a heartbeat is placed).
    latest_ns: u64,
    /// Compensated blocks waiting for their reference, while one is expected.
    pending: std::collections::VecDeque<CompensatedBlock>,
    /// Whether a reference stream is expected ([`ViewBuilder::expect_reference`]; a
    /// reference block arriving says so too).
    reference_expected: bool,
    /// Heartbeats and log lines before the first data time: they have no time of their
    /// own on the data's timeline, so they wait for it (at most [`HEALTH_HELD`]).
    health_held: Vec<Message>,
}

/// Heartbeats and log lines held for the first data time (a few seconds of every
/// service's); beyond, the oldest go out at time 0.
pub const HEALTH_HELD: usize = 256;

impl ViewBuilder {
    pub fn new(units: [&str; 3]) -> Self {
        Self {
            units: units.map(str::to_string),
            truth: std::collections::VecDeque::with_capacity(TRUTH_KEPT),
            latest_ns: 0,
            pending: std::collections::VecDeque::with_capacity(PENDING_KEPT),
            reference_expected: false,
            health_held: Vec::new(),
        }
    }

    /// Whether the system has a reference stream (the live view: `/truth` has a
    /// publisher). While it has, a compensated block waits for its reference block;
    /// when it stops having one, what waits goes out without.
    pub fn expect_reference(&mut self, expected: bool, out: &mut Vec<ViewMessage>) {
        self.reference_expected = expected;
        if !expected {
            self.flush_blocks(out);
        }
    }

    /// The compensated blocks still waiting for a reference, without one.
    fn flush_blocks(&mut self, out: &mut Vec<ViewMessage>) {
        while let Some(b) = self.pending.pop_front() {
            self.unit_stages(&b, None, out);
        }
    }

    /// At the end of a stream: the compensated blocks still waiting for a reference,
    /// without one, and the heartbeats still waiting for a data time, at the latest.
    pub fn flush(&mut self, out: &mut Vec<ViewMessage>) {
        self.flush_blocks(out);
        self.release_health(out);
    }

    /// The heartbeats held for the first data time, at the latest data time.
    fn release_health(&mut self, out: &mut Vec<ViewMessage>) {
        for m in std::mem::take(&mut self.health_held) {
            self.timeless(&m, out);
        }
    }

    /// A heartbeat's or a log line's view message, at the latest data time.
    fn timeless(&self, m: &Message, out: &mut Vec<ViewMessage>) {
        match m {
            Message::Heartbeat(h) => self.health(h, out),
            Message::LogLine(l) => self.log(l, out),
            _ => {}
        }
    }

    fn truth_of(&self, b: &CompensatedBlock) -> Option<TruthBlock> {
        self.truth
            .iter()
            .rev()
            .find(|t| t.first_sample_index == b.first_sample_index && t.count == b.count)
            .copied()
    }

    /// The view messages `m` gives, appended to `out` (none for the raw input streams:
    /// a reference block is kept for the compensated block that answers it).
    pub fn on_message(&mut self, m: &Message, out: &mut Vec<ViewMessage>) {
        if let Some(t) = m.data_ns() {
            self.latest_ns = self.latest_ns.max(t);
            if !self.health_held.is_empty() {
                self.release_health(out);
            }
        }
        match m {
            Message::TruthBlock(t) => {
                if self.truth.len() == TRUTH_KEPT {
                    self.truth.pop_front();
                }
                self.truth.push_back(*t);
                self.reference_expected = true;
                // What waited for this reference, and what is older than it (its
                // reference is not coming), in order.
                while let Some(b) = self.pending.front().copied() {
                    if b.first_sample_index > t.first_sample_index {
                        break;
                    }
                    self.pending.pop_front();
                    let truth = self.truth_of(&b);
                    self.unit_stages(&b, truth.as_ref(), out);
                }
            }
            Message::CompensatedBlock(b) => match self.truth_of(b) {
                Some(t) => self.unit_stages(b, Some(&t), out),
                None if self.reference_expected => {
                    if self.pending.len() == PENDING_KEPT {
                        if let Some(old) = self.pending.pop_front() {
                            self.unit_stages(&old, None, out);
                        }
                    }
                    self.pending.push_back(*b);
                }
                None => self.unit_stages(b, None, out),
            },
            Message::VibEstimate(e) => self.vibration(e, out),
            Message::Heartbeat(_) | Message::LogLine(_) if self.latest_ns == 0 => {
                if self.health_held.len() == HEALTH_HELD {
                    let oldest = self.health_held.remove(0);
                    self.timeless(&oldest, out);
                }
                self.health_held.push(*m);
            }
            Message::Heartbeat(h) => self.health(h, out),
            Message::LogLine(l) => self.log(l, out),
            Message::AccelBlock(_) | Message::VibBlock(_) => {}
        }
    }

    fn unit_stages(
        &self,
        b: &CompensatedBlock,
        truth: Option<&TruthBlock>,
        out: &mut Vec<ViewMessage>,
    ) {
        let t_ns = vibro_mcap::last_sample_ns(b.t0_ns, b.count, b.sample_period_ns);
        let n = (b.count as usize).min(b.a1_g.len());
        for u in 0..UNITS {
            let col = |a: &[[f64; UNITS]]| stage(a[..n].iter().map(|s| s[u]));
            let error = |a: &[[f64; UNITS]]| {
                truth.and_then(|t| {
                    stage(
                        a[..n]
                            .iter()
                            .zip(&t.a_sensed_ia_g[..n])
                            .map(|(x, r)| x[u] - r[u]),
                    )
                })
            };
            let msg = UnitStages {
                timestamp: Some(timestamp(t_ns)),
                unit: self.units[u].clone(),
                unit_index: u as u32,
                samples: n as u32,
                first_sample_index: b.first_sample_index,
                uncompensated_g: col(&b.a1_g),
                main_removed_g: col(&b.a2_g),
                compensated_g: col(&b.a4_g),
                reference_g: truth.and_then(|t| col(&t.a_sensed_ia_g)),
                uncompensated_error_g: error(&b.a1_g),
                main_removed_error_g: error(&b.a2_g),
                compensated_error_g: error(&b.a4_g),
                flags: b.flags,
            };
            out.push(ViewMessage {
                topic: format!("/view/{}", self.units[u]),
                schema: VIEW_UNIT_STAGES,
                log_time_ns: t_ns,
                data: msg.encode_to_vec(),
            });
        }
    }

    fn vibration(&self, e: &VibEstimate, out: &mut Vec<ViewMessage>) {
        let tones = (e.tone_count as usize).min(e.tone_frequency_hz.len());
        for (i, axis) in AXES.iter().enumerate() {
            let strongest = (0..tones).max_by(|&a, &b| {
                e.tone_amplitude_g[a][i]
                    .abs()
                    .total_cmp(&e.tone_amplitude_g[b][i].abs())
            });
            let msg = VibrationAxis {
                timestamp: Some(timestamp(e.end_ns)),
                axis: axis.to_string(),
                axis_index: i as u32,
                tone_count: tones as u32,
                tone_frequency_hz: strongest.map_or(0.0, |t| e.tone_frequency_hz[t]),
                tone_amplitude_g: strongest.map_or(0.0, |t| e.tone_amplitude_g[t][i]),
                tone_phase_rad: strongest.map_or(0.0, |t| e.tone_phase_rad[t][i]),
                broadband_rms_g: e.broadband_rms_g[i],
                kurtosis: e.broadband_kurtosis[i],
                flags: e.flags,
                saturated: e.saturated_samples[i] > 0,
            };
            out.push(ViewMessage {
                topic: format!("/view/vibration/{axis}"),
                schema: VIEW_VIBRATION_AXIS,
                log_time_ns: e.end_ns,
                data: msg.encode_to_vec(),
            });
        }
    }

    /// A log line as `foxglove.Log`: the service as its name, the level mapped onto
    /// Foxglove's (trace and debug are `DEBUG`), placed at the latest data time.
    fn log(&self, l: &LogLine, out: &mut Vec<ViewMessage>) {
        use vibro_mcap::foxglove_proto::{log::Level, Log};
        let level = match LogLevel::try_from(l.level) {
            Ok(LogLevel::Trace | LogLevel::Debug) => Level::Debug,
            Ok(LogLevel::Info) => Level::Info,
            Ok(LogLevel::Warn) => Level::Warning,
            Ok(LogLevel::Error) => Level::Error,
            Err(_) => Level::Unknown,
        };
        let msg = Log {
            timestamp: Some(timestamp(self.latest_ns)),
            level: level as i32,
            message: l.text().into_owned(),
            name: ServiceId::try_from(l.service).map_or_else(
                |_| format!("service {}", l.service),
                |s| s.as_str().to_string(),
            ),
            file: String::new(),
            line: 0,
        };
        out.push(ViewMessage {
            topic: LOG_TOPIC.to_string(),
            schema: FOXGLOVE_LOG,
            log_time_ns: self.latest_ns,
            data: msg.encode_to_vec(),
        });
    }

    fn health(&self, h: &Heartbeat, out: &mut Vec<ViewMessage>) {
        let service = ServiceId::try_from(h.service).ok();
        let msg = ServiceHealth {
            timestamp: Some(timestamp(self.latest_ns)),
            // The schema's enum numbers are the wire codes (`ServiceId`, `ServiceState`):
            // an unknown code stays visible as its number.
            service: i32::from(h.service),
            state: i32::from(h.state),
            uptime_s: h.uptime_ns as f64 * 1e-9,
            received: h.received,
            published: h.published,
            lost: h.lost,
            stale: h.stale,
            latency_p50_ms: h.latency_p50_ns as f64 * 1e-6,
            latency_p99_ms: h.latency_p99_ns as f64 * 1e-6,
            out_of_order: h.out_of_order,
            resyncs: h.resyncs,
        };
        out.push(ViewMessage {
            topic: format!("/view/health/{}", service.map_or("unknown", |s| s.as_str())),
            schema: VIEW_SERVICE_HEALTH,
            log_time_ns: self.latest_ns,
            data: msg.encode_to_vec(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_mcap::view_proto::service_health::{Service, State};
    use vibro_msgs::{CompensatedBlock, TruthBlock};

    /// Mean, minimum and maximum against a sum and comparisons written out by hand.
    #[test]
    fn a_stage_is_the_mean_min_and_max() {
        let v = [0.5, -1.25, 3.0, 2.0];
        let s = stage(v.iter().copied()).unwrap();
        assert_eq!((s.mean, s.min, s.max), (4.25 / 4.0, -1.25, 3.0));
        assert!(stage([1.0, f64::NAN].into_iter()).is_none());
        assert!(stage(std::iter::empty()).is_none());
    }

    fn block(n: usize) -> (CompensatedBlock, TruthBlock) {
        let mut b = CompensatedBlock::ZEROED;
        let mut t = TruthBlock::ZEROED;
        b.count = n as u32;
        t.count = n as u32;
        b.first_sample_index = 64;
        t.first_sample_index = 64;
        b.t0_ns = 1_250_000;
        b.sample_period_ns = 1_250_000;
        for k in 0..n {
            for u in 0..3 {
                let x = (k * 7 + u * 3) as f64;
                b.a1_g[k][u] = 1.0 + 1e-3 * x;
                b.a2_g[k][u] = 1.0 + 1e-4 * x;
                b.a4_g[k][u] = 1.0 + 1e-6 * (x - 10.0).abs();
                t.a_sensed_ia_g[k][u] = 1.0 + 1e-6 * (k % 3) as f64;
            }
        }
        (b, t)
    }

    /// One message per unit, each stage over the block's samples, the errors sample by
    /// sample against the reference block with the same first sample; placed at the
    /// block's last reading.
    #[test]
    fn each_unit_gets_its_stages_and_errors() {
        let (b, t) = block(32);
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        view.on_message(&Message::TruthBlock(t), &mut out);
        assert!(out.is_empty());
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        assert_eq!(out.len(), 3);
        for (u, m) in out.iter().enumerate() {
            assert_eq!(m.topic, format!("/view/{}", UNIT_NAMES[u]));
            assert_eq!(m.log_time_ns, 1_250_000 * 32);
            let s = UnitStages::decode(&m.data[..]).unwrap();
            let errs: Vec<f64> = (0..32)
                .map(|k| b.a4_g[k][u] - t.a_sensed_ia_g[k][u])
                .collect();
            let e = s.compensated_error_g.unwrap();
            let max = errs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let min = errs.iter().copied().fold(f64::INFINITY, f64::min);
            assert_eq!((e.min, e.max), (min, max));
            assert!((e.mean - errs.iter().sum::<f64>() / 32.0).abs() < 1e-18);
            let a1 = s.uncompensated_g.unwrap();
            assert_eq!(a1.max, b.a1_g[31][u]);
            assert_eq!(s.samples, 32);
            assert_eq!(s.timestamp.unwrap().nanos, 40_000_000);
        }
        // The compensated block before its reference: held, then sent with it.
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        let (mut b0, mut t0) = (b, t);
        b0.first_sample_index = 32;
        t0.first_sample_index = 32;
        view.on_message(&Message::TruthBlock(t0), &mut out);
        view.on_message(&Message::CompensatedBlock(b0), &mut out);
        assert_eq!(out.len(), 3);
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        assert_eq!(out.len(), 3, "held for its reference");
        view.on_message(&Message::TruthBlock(t), &mut out);
        assert_eq!(out.len(), 6);
        let s = UnitStages::decode(&out[5].data[..]).unwrap();
        assert!(s.compensated_error_g.is_some());
        // A reference stream expected: the first block waits for its reference too.
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        view.expect_reference(true, &mut out);
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        assert!(out.is_empty());
        view.on_message(&Message::TruthBlock(t), &mut out);
        let s = UnitStages::decode(&out[0].data[..]).unwrap();
        assert!(s.compensated_error_g.is_some());
        // Without a matching reference: the stages, no errors.
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        let s = UnitStages::decode(&out[0].data[..]).unwrap();
        assert!(s.reference_g.is_none() && s.compensated_error_g.is_none());
        assert!(s.compensated_g.is_some());
    }

    /// A full outbox drops its oldest message and counts it; what is left comes out
    /// oldest first, and after `close` the rest drains before `pop` says `None`. A
    /// consumer on another thread sees every message not dropped, in order.
    #[test]
    fn the_outbox_drops_the_oldest_and_counts_them() {
        let m = |i: u64| ViewMessage {
            topic: format!("/t{i}"),
            schema: VIEW_SERVICE_HEALTH,
            log_time_ns: i,
            data: Vec::new(),
        };
        let o = Outbox::new(4);
        for i in 0..10 {
            o.push(m(i));
        }
        assert_eq!(o.dropped(), 6);
        o.close();
        let got: Vec<u64> = std::iter::from_fn(|| o.pop())
            .map(|v| v.log_time_ns)
            .collect();
        assert_eq!(got, [6, 7, 8, 9]);
        let o = std::sync::Arc::new(Outbox::new(1 << 16));
        let reader = {
            let o = std::sync::Arc::clone(&o);
            std::thread::spawn(move || std::iter::from_fn(|| o.pop()).count())
        };
        for i in 0..50_000 {
            o.push(m(i));
        }
        o.close();
        assert_eq!(reader.join().unwrap() as u64 + o.dropped(), 50_000);
        assert_eq!(o.dropped(), 0);
    }

    /// A heartbeat before any data would sit at time 0 (1970 in a viewer, stretching
    /// the timeline): it waits for the first data time, in order, and goes out there.
    #[test]
    fn heartbeats_before_the_first_data_wait_for_its_time() {
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        for (i, s) in [ServiceId::Estimator, ServiceId::Compensator]
            .iter()
            .enumerate()
        {
            let hb = Heartbeat {
                service: s.code(),
                seq: i as u64,
                ..Heartbeat::ZEROED
            };
            view.on_message(&Message::Heartbeat(hb), &mut out);
        }
        // A system without a reference stream says so on every wake-up: the
        // heartbeats keep waiting.
        view.expect_reference(false, &mut out);
        assert!(out.is_empty());
        let (b, _) = block(4);
        let t = Message::CompensatedBlock(b).data_ns().expect("data time");
        assert!(t > 0);
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        let topics: Vec<&str> = out.iter().map(|m| m.topic.as_str()).collect();
        assert_eq!(
            topics[..2],
            ["/view/health/estimator", "/view/health/compensator"]
        );
        assert!(out.iter().all(|m| m.log_time_ns == t), "{out:?}");
    }

    /// A log line becomes a `foxglove.Log` on `/log` (decoded here with the schema
    /// Foxglove reads), at the latest data time, its level on Foxglove's scale.
    #[test]
    fn a_log_line_is_a_foxglove_log() {
        use prost::Message as _;
        use prost_types::FileDescriptorSet;
        let set = FileDescriptorSet::decode(FOXGLOVE_LOG.data).unwrap();
        let file = set.file.iter().find(|f| f.package() == "foxglove").unwrap();
        let log = file
            .message_type
            .iter()
            .find(|m| m.name() == "Log")
            .unwrap();
        let fields: Vec<(&str, i32)> = log.field.iter().map(|f| (f.name(), f.number())).collect();
        assert_eq!(
            fields,
            [
                ("timestamp", 1),
                ("level", 2),
                ("message", 3),
                ("name", 4),
                ("file", 5),
                ("line", 6)
            ]
        );
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        let (b, _) = block(4);
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        out.clear();
        let line = LogLine::new(
            ServiceId::Estimator,
            LogLevel::Warn,
            "vibro_estimator: late",
        );
        view.on_message(&Message::LogLine(line), &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].topic, LOG_TOPIC);
        assert_eq!(
            Some(out[0].log_time_ns),
            Message::CompensatedBlock(b).data_ns()
        );
        let l = vibro_mcap::foxglove_proto::Log::decode(&out[0].data[..]).unwrap();
        assert_eq!(l.message, "vibro_estimator: late");
        assert_eq!(l.name, "estimator");
        assert_eq!(l.level, 3, "WARNING");
    }

    /// Heartbeats carry the wire codes as protobuf enums and sit at the latest data
    /// time; the strongest tone on each axis is the one named.
    #[test]
    fn health_and_vibration_have_named_fields() {
        let mut view = ViewBuilder::new(UNIT_NAMES);
        let mut out = Vec::new();
        let (b, _) = block(4);
        view.on_message(&Message::CompensatedBlock(b), &mut out);
        out.clear();
        let hb = Heartbeat {
            service: ServiceId::Estimator.code(),
            state: 3,
            latency_p99_ns: 2_500_000,
            out_of_order: 17,
            resyncs: 2,
            ..Heartbeat::ZEROED
        };
        view.on_message(&Message::Heartbeat(hb), &mut out);
        let h = ServiceHealth::decode(&out[0].data[..]).unwrap();
        assert_eq!(out[0].topic, "/view/health/estimator");
        assert_eq!(h.service(), Service::Estimator);
        assert_eq!(h.state(), State::Degraded);
        assert_eq!(h.latency_p99_ms, 2.5);
        assert_eq!((h.out_of_order, h.resyncs), (17, 2));
        assert_eq!(out[0].log_time_ns, 1_250_000 * 4);
        // The schema's enums number the services and states as the wire does.
        for s in ServiceId::ALL {
            let named = Service::try_from(i32::from(s.code())).unwrap();
            assert_eq!(named.as_str_name(), s.as_str().to_uppercase());
        }
        for s in vibro_msgs::ServiceState::ALL {
            let named = State::try_from(i32::from(s.code())).unwrap();
            assert_eq!(named.as_str_name(), s.as_str().to_uppercase());
        }
        out.clear();
        let mut e = VibEstimate::ZEROED;
        e.end_ns = 9;
        e.tone_count = 2;
        e.tone_frequency_hz[0] = 8.0;
        e.tone_frequency_hz[1] = 16.0;
        e.tone_amplitude_g[0] = [0.5, 0.1, 1.2];
        e.tone_amplitude_g[1] = [-0.7, 0.0, 0.3];
        e.broadband_rms_g = [1.0, 2.0, 3.0];
        view.on_message(&Message::VibEstimate(e), &mut out);
        let axis = |i: usize| VibrationAxis::decode(&out[i].data[..]).unwrap();
        assert_eq!(axis(0).tone_frequency_hz, 16.0);
        assert_eq!(axis(0).tone_amplitude_g, -0.7);
        assert_eq!(axis(1).tone_frequency_hz, 8.0);
        assert_eq!(axis(2).tone_frequency_hz, 8.0);
        assert_eq!(axis(2).broadband_rms_g, 3.0);
        assert_eq!(out[2].topic, "/view/vibration/z");
    }

    /// Whether `path` (`field.sub.field`) names a field of message `name` in the
    /// schema's descriptors, nested messages followed by their type names.
    fn field_exists(schema: &ViewSchema, name: &str, path: &str) -> bool {
        let fds = prost_types::FileDescriptorSet::decode(schema.data).unwrap();
        let find = |full: &str| {
            fds.file.iter().find_map(|f| {
                f.message_type.iter().find(|m| {
                    format!(".{}.{}", f.package(), m.name()) == full
                        || format!("{}.{}", f.package(), m.name()) == full
                })
            })
        };
        let mut msg = find(name);
        let parts: Vec<&str> = path.split('.').collect();
        for (i, part) in parts.iter().enumerate() {
            let Some(m) = msg else { return false };
            let Some(field) = m.field.iter().find(|f| f.name() == *part) else {
                return false;
            };
            if i + 1 < parts.len() {
                msg = find(field.type_name());
            }
        }
        true
    }

    /// Every message path of the shipped layout (`config/foxglove/vibrocomp-layout.json`:
    /// each plot's and state panel's `paths[].value`, each raw panel's `topicPath`)
    /// names a view topic and a field its schema has; a path with a typo fails.
    #[test]
    fn every_path_of_the_shipped_layout_exists_in_the_schemas() {
        let layout: serde_json::Value = serde_json::from_str(include_str!(
            "../../../config/foxglove/vibrocomp-layout.json"
        ))
        .unwrap();
        let topics = topics(UNIT_NAMES);
        let check = |path: &str| -> bool {
            // The longest topic the path starts with, then `.field...` (or nothing).
            let Some((topic, schema)) = topics
                .iter()
                .filter(|(t, _)| path.starts_with(t.as_str()))
                .max_by_key(|(t, _)| t.len())
            else {
                return false;
            };
            let rest = &path[topic.len()..];
            rest.is_empty()
                || rest
                    .strip_prefix('.')
                    .is_some_and(|fields| field_exists(schema, schema.name, fields))
        };
        let mut paths = Vec::new();
        for (_, panel) in layout["configById"].as_object().unwrap() {
            for p in panel["paths"].as_array().into_iter().flatten() {
                paths.push(p["value"].as_str().unwrap().to_string());
            }
            for key in ["topicPath", "topicToRender"] {
                if let Some(t) = panel[key].as_str() {
                    paths.push(t.to_string());
                }
            }
        }
        assert!(paths.len() >= 20, "{paths:?}");
        for p in &paths {
            assert!(check(p), "{p}: no such topic or field");
        }
        for bad in [
            "/view/AK1.compensated_error.mean",
            "/view/AK4.compensated_g.mean",
            "/view/vibration/z.tone_amplitude_g.mean",
        ] {
            assert!(!check(bad), "{bad} passed");
        }
        // Every panel the tree places is configured.
        fn leaves(v: &serde_json::Value, out: &mut Vec<String>) {
            match v {
                serde_json::Value::String(s) => out.push(s.clone()),
                serde_json::Value::Object(o) => {
                    for k in ["first", "second"] {
                        if let Some(c) = o.get(k) {
                            leaves(c, out);
                        }
                    }
                }
                _ => {}
            }
        }
        let mut placed = Vec::new();
        leaves(&layout["layout"], &mut placed);
        for id in &placed {
            assert!(layout["configById"].get(id).is_some(), "{id}");
        }
        assert_eq!(
            placed.len(),
            layout["configById"].as_object().unwrap().len()
        );
    }

    #[test]
    fn every_topic_is_listed_with_its_schema() {
        let t = topics(UNIT_NAMES);
        assert_eq!(t.len(), 3 + 3 + ServiceId::ALL.len() + 1);
        assert!(t.iter().any(|(n, s)| n == LOG_TOPIC && *s == FOXGLOVE_LOG));
        assert!(t
            .iter()
            .any(|(n, s)| n == "/view/AK2" && *s == VIEW_UNIT_STAGES));
    }
}
