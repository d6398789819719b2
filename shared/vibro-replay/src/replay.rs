//! Replaying the rig streams of a log into a running system.

use crate::topics::{known_topics, rig_streams, stream_of_topic, topic};
use crate::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use tracing::{debug, info};
use vibro_ipc::{
    cleanup_dead_nodes, create_node, now_ns, IpcNode, StreamPublisher, StreamSubscriber,
};
use vibro_mcap::{Message, Reader};
use vibro_msgs::{AccelBlock, Heartbeat, ServiceId, ServiceNames, Stream, TruthBlock, VibBlock};

/// How fast a replay publishes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// At `x` times the recorded pace (by log time): `1.0` is real time. Does not wait
    /// for the consumers beyond the transport's bounded back-pressure.
    Rate(f64),
    /// As fast as the services take the messages, lock-stepped with them through their
    /// progress messages: nothing dropped, outputs independent of timing.
    AsFastAsPossible,
}

/// What to replay and how.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    pub names: ServiceNames,
    pub pace: Pace,
    /// Skip the first `start_s` seconds of the log (by log time).
    pub start_s: f64,
    /// Replay at most this long a stretch (by log time); `None`: to the end.
    pub duration_s: Option<f64>,
    /// Topics to publish (rig topics only: `/vib`, `/accel`, `/truth`); `None`: every
    /// rig topic the log has.
    pub topics: Option<Vec<String>>,
    /// Times through the log; `0` loops until stopped. Each pass continues the
    /// sequence numbers, sample indices and data times of the one before, so the
    /// services see one continuous stream.
    pub passes: u64,
    /// How long to wait for the consumers (subscribers and, when lock-stepped, their
    /// progress) to be there before the first message.
    pub connect_timeout: Duration,
    /// A lock-stepped replay gives up when a consumer makes no progress this long.
    pub stall_timeout: Duration,
}

impl ReplayOptions {
    pub fn new(names: ServiceNames, pace: Pace) -> Self {
        Self {
            names,
            pace,
            start_s: 0.0,
            duration_s: None,
            topics: None,
            passes: 1,
            connect_timeout: Duration::from_secs(10),
            stall_timeout: Duration::from_secs(10),
        }
    }

    fn check(&self) -> Result<()> {
        if let Pace::Rate(x) = self.pace {
            if !(x.is_finite() && x > 0.0) {
                return Err(Error::Option {
                    name: "rate",
                    value: x.to_string(),
                    rule: "must be finite and > 0",
                });
            }
        }
        if !(self.start_s.is_finite() && self.start_s >= 0.0) {
            return Err(Error::Option {
                name: "start_s",
                value: self.start_s.to_string(),
                rule: "must be finite and >= 0",
            });
        }
        if let Some(d) = self.duration_s {
            if !(d.is_finite() && d > 0.0) {
                return Err(Error::Option {
                    name: "duration_s",
                    value: d.to_string(),
                    rule: "must be finite and > 0",
                });
            }
        }
        Ok(())
    }
}

/// What a replay published.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReplaySummary {
    /// Messages published per topic.
    pub topics: BTreeMap<String, u64>,
    pub messages: u64,
    /// Passes through the log completed.
    pub passes: u64,
    /// Messages a subscriber's full buffer did not take within the back-pressure timeout.
    pub undelivered: u64,
    /// Log time covered by one pass, s.
    pub log_span_s: f64,
    pub elapsed_s: f64,
    /// Log time replayed over wall time.
    pub real_time_factor: f64,
    /// Times a lock-stepped replay waited for a consumer, and the time spent waiting.
    pub lockstep_waits: u64,
    pub lockstep_wait_s: f64,
    pub lockstepped: bool,
}

/// The consumer of one stream, followed through its progress messages.
struct Consumer {
    service: ServiceId,
    stream: String,
    progress: StreamSubscriber<Heartbeat>,
    /// `received` of the service when the replay started.
    baseline: u64,
    /// Latest `received` seen.
    received: u64,
}

impl Consumer {
    fn open(
        node: &IpcNode,
        names: &ServiceNames,
        service: ServiceId,
        data: Stream,
    ) -> Result<Self> {
        let s = Stream::Progress(service);
        Ok(Self {
            service,
            stream: names.stream(data),
            progress: StreamSubscriber::open(node, names, s)?,
            baseline: 0,
            received: 0,
        })
    }

    fn name(&self) -> &'static str {
        match self.service {
            ServiceId::Estimator => "estimator",
            ServiceId::Compensator => "compensator",
            _ => "service",
        }
    }

    fn poll(&mut self) -> Result<()> {
        while let Some(m) = self.progress.receive()? {
            self.received = self.received.max(m.received);
        }
        Ok(())
    }

    /// Waits until the service has taken `sent` messages of this replay.
    fn wait_for(&mut self, sent: u64, stall: Duration, stop: &AtomicBool) -> Result<bool> {
        self.poll()?;
        if self.received.saturating_sub(self.baseline) >= sent {
            return Ok(false);
        }
        let mut last = self.received;
        let mut since = Instant::now();
        loop {
            if stop.load(Ordering::Acquire) {
                return Ok(true);
            }
            // Sleeps until the service's next progress message (or 10 ms).
            let _ = self
                .progress
                .listener()
                .timed_wait(|_| {}, Duration::from_millis(10));
            self.poll()?;
            if self.received.saturating_sub(self.baseline) >= sent {
                return Ok(true);
            }
            if self.received != last {
                last = self.received;
                since = Instant::now();
            } else if since.elapsed() > stall {
                return Err(Error::Stalled {
                    service: self.name(),
                    stream: self.stream.clone(),
                    taken: self.received.saturating_sub(self.baseline),
                    sent,
                    waited_s: stall.as_secs_f64(),
                });
            }
        }
    }
}

/// The service's `received` count before the replay: from its next heartbeat.
fn baseline(
    node: &IpcNode,
    names: &ServiceNames,
    c: &mut Consumer,
    timeout: Duration,
) -> Result<()> {
    let s = Stream::Heartbeat(c.service);
    let heartbeats: StreamSubscriber<Heartbeat> = StreamSubscriber::open(node, names, s)?;
    let start = Instant::now();
    loop {
        if let Some(h) = heartbeats.receive()? {
            c.baseline = h.received;
            c.received = h.received;
            // Progress messages older than the heartbeat would only repeat it.
            while c.progress.receive()?.is_some() {}
            return Ok(());
        }
        if start.elapsed() > timeout {
            return Err(Error::NoProgress {
                service: c.name(),
                stream: names.stream(s),
                waited_s: timeout.as_secs_f64(),
            });
        }
        let _ = heartbeats
            .listener()
            .timed_wait(|_| {}, Duration::from_millis(50));
    }
}

/// Continuation of a stream from one pass to the next.
#[derive(Clone, Copy, Default)]
struct Shift {
    seq: u64,
    index: u64,
    time_ns: u64,
    /// The first message's own (unshifted) values in the log.
    first: Option<(u64, u64, u64)>,
    /// The end of the last message of this pass (shifted): where the next pass starts.
    next: (u64, u64, u64),
}

impl Shift {
    /// The shift of the next pass: its first message continues where this one ended.
    fn advance(&mut self) {
        if let Some((seq, index, time_ns)) = self.first {
            self.seq = self.next.0.wrapping_sub(seq);
            self.index = self.next.1.wrapping_sub(index);
            self.time_ns = self.next.2.wrapping_sub(time_ns);
        }
    }
}

/// The publishers of the rig streams and their per-pass shifts.
struct Publishers {
    vib: Option<StreamPublisher<VibBlock>>,
    accel: Option<StreamPublisher<AccelBlock>>,
    truth: Option<StreamPublisher<TruthBlock>>,
    shifts: [Shift; 3],
}

fn open_publisher<T: vibro_msgs::WireMessage>(
    node: &IpcNode,
    names: &ServiceNames,
    stream: Stream,
    wanted: bool,
) -> Result<Option<StreamPublisher<T>>> {
    if !wanted {
        return Ok(None);
    }
    Ok(Some(StreamPublisher::open(node, names, stream)?))
}

/// Shifts a block's counters by `s` and records where it ends.
macro_rules! shifted {
    ($b:expr, $s:expr) => {{
        let mut b = *$b;
        $s.first
            .get_or_insert((b.seq, b.first_sample_index, b.t0_ns));
        b.seq = b.seq.wrapping_add($s.seq);
        b.first_sample_index = b.first_sample_index.wrapping_add($s.index);
        b.t0_ns = b.t0_ns.wrapping_add($s.time_ns);
        let count = u64::from(b.count);
        $s.next = (
            b.seq.wrapping_add(1),
            b.first_sample_index.wrapping_add(count),
            b.t0_ns
                .wrapping_add(count.saturating_mul(b.sample_period_ns)),
        );
        b.publish_ns = now_ns();
        b
    }};
}

/// Replays the rig streams of the log at `path` under `options.names`. `progress`
/// receives (messages published, messages in one pass) now and then. Stops early,
/// cleanly, when `stop` is set.
pub fn replay(
    path: &Path,
    options: &ReplayOptions,
    stop: &AtomicBool,
    mut progress: impl FnMut(u64, u64),
) -> Result<ReplaySummary> {
    options.check()?;
    let reader = Reader::open(path)?;
    let in_log: Vec<Stream> = reader
        .channels()
        .iter()
        .filter_map(|(t, _)| stream_of_topic(t))
        .filter(|s| rig_streams().contains(s))
        .collect();
    let selected: Vec<Stream> = match &options.topics {
        None => in_log.clone(),
        Some(topics) => {
            let mut v = Vec::new();
            for t in topics {
                let stream = stream_of_topic(t).ok_or_else(|| Error::Topic {
                    topic: t.clone(),
                    rule: "not a vibrocomp stream",
                    known: known_topics(),
                })?;
                if !rig_streams().contains(&stream) {
                    return Err(Error::Topic {
                        topic: t.clone(),
                        rule: "a replay publishes the rig streams only (the services produce the others)",
                        known: "/vib, /accel, /truth".to_string(),
                    });
                }
                if !in_log.contains(&stream) {
                    return Err(Error::Topic {
                        topic: t.clone(),
                        rule: "not in this log",
                        known: in_log
                            .iter()
                            .map(|&s| topic(s))
                            .collect::<Vec<_>>()
                            .join(", "),
                    });
                }
                v.push(stream);
            }
            v
        }
    };
    if selected.is_empty() {
        return Err(Error::Empty {
            path: path.to_path_buf(),
            what: "no rig stream (/vib, /accel, /truth) to replay".to_string(),
        });
    }
    let per_pass = reader.message_count().unwrap_or(0);
    drop(reader);

    let names = &options.names;
    let node = create_node("vibrocomp-replay")?;
    let mut pubs = Publishers {
        vib: open_publisher(&node, names, Stream::Vib, selected.contains(&Stream::Vib))?,
        accel: open_publisher(
            &node,
            names,
            Stream::Accel,
            selected.contains(&Stream::Accel),
        )?,
        truth: open_publisher(
            &node,
            names,
            Stream::Truth,
            selected.contains(&Stream::Truth),
        )?,
        shifts: [Shift::default(); 3],
    };
    // The services' inputs need someone listening before the first message (the truth
    // is for recorders and monitors, if any).
    let connect_start = Instant::now();
    let counts = |p: &Publishers| {
        [
            p.vib.as_ref().map(|x| x.subscriber_count()),
            p.accel.as_ref().map(|x| x.subscriber_count()),
        ]
    };
    loop {
        let c = counts(&pubs);
        if c.iter().all(|n| n.is_none_or(|n| n > 0)) {
            break;
        }
        if connect_start.elapsed() > options.connect_timeout {
            let missing = [Stream::Vib, Stream::Accel]
                .into_iter()
                .zip(c)
                .find(|(_, n)| *n == Some(0))
                .map(|(s, _)| names.stream(s))
                .unwrap_or_default();
            return Err(Error::NoSubscriber {
                stream: missing,
                waited_s: options.connect_timeout.as_secs_f64(),
            });
        }
        if stop.load(Ordering::Acquire) {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let lockstep = options.pace == Pace::AsFastAsPossible;
    let mut estimator = None;
    let mut compensator = None;
    if lockstep {
        if pubs.vib.is_some() {
            let mut c = Consumer::open(&node, names, ServiceId::Estimator, Stream::Vib)?;
            baseline(&node, names, &mut c, options.connect_timeout)?;
            estimator = Some(c);
        }
        if pubs.accel.is_some() {
            let mut c = Consumer::open(&node, names, ServiceId::Compensator, Stream::Accel)?;
            baseline(&node, names, &mut c, options.connect_timeout)?;
            compensator = Some(c);
        }
    }

    let mut topics: BTreeMap<String, u64> = selected.iter().map(|&s| (topic(s), 0)).collect();
    let (mut vib_sent, mut accel_sent) = (0u64, 0u64);
    let (mut waits, mut wait_s) = (0u64, 0.0f64);
    let mut last: Option<Stream> = None;
    let mut messages = 0u64;
    let mut passes = 0u64;
    let mut span_ns = 0u64;
    let started = Instant::now();
    let mut pass_start_ns = 0u64; // wall-clock offset of the current pass (Rate pace)
    'passes: loop {
        let reader = Reader::open(path)?;
        let mut first_log_ns: Option<u64> = None;
        let mut window: Option<(u64, u64)> = None;
        let mut last_due_ns = 0u64;
        for record in reader {
            let record = record?;
            if stop.load(Ordering::Acquire) {
                break 'passes;
            }
            let t0 = *first_log_ns.get_or_insert(record.log_time_ns);
            let (from, to) = *window.get_or_insert_with(|| {
                let from = t0.saturating_add((options.start_s * 1e9) as u64);
                let to = options
                    .duration_s
                    .map_or(u64::MAX, |d| from.saturating_add((d * 1e9) as u64));
                (from, to)
            });
            if record.log_time_ns < from {
                continue;
            }
            if record.log_time_ns >= to {
                break;
            }
            let Some(stream) = stream_of_topic(&record.topic) else {
                continue;
            };
            if !selected.contains(&stream) {
                continue;
            }
            if let Pace::Rate(x) = options.pace {
                let due_ns = pass_start_ns + ((record.log_time_ns - from) as f64 / x) as u64;
                last_due_ns = due_ns;
                let now = started.elapsed().as_nanos() as u64;
                if due_ns > now {
                    std::thread::sleep(Duration::from_nanos(due_ns - now));
                }
            }
            // Lock-step: the other stream's consumer must have taken everything sent
            // before this stream gets its next message.
            if lockstep && last != Some(stream) {
                let t = Instant::now();
                let waited = match stream {
                    Stream::Accel => match &mut estimator {
                        Some(c) => c.wait_for(vib_sent, options.stall_timeout, stop)?,
                        None => false,
                    },
                    Stream::Vib => match &mut compensator {
                        Some(c) => c.wait_for(accel_sent, options.stall_timeout, stop)?,
                        None => false,
                    },
                    _ => false,
                };
                if waited {
                    waits += 1;
                    wait_s += t.elapsed().as_secs_f64();
                }
            }
            let sent = match (&record.message, stream) {
                (Message::VibBlock(b), Stream::Vib) => match &mut pubs.vib {
                    Some(p) => {
                        let b = shifted!(b, pubs.shifts[0]);
                        vib_sent += 1;
                        Some(p.publish(&b))
                    }
                    None => None,
                },
                (Message::AccelBlock(b), Stream::Accel) => match &mut pubs.accel {
                    Some(p) => {
                        let b = shifted!(b, pubs.shifts[1]);
                        accel_sent += 1;
                        Some(p.publish(&b))
                    }
                    None => None,
                },
                (Message::TruthBlock(b), Stream::Truth) => match &mut pubs.truth {
                    Some(p) => {
                        let b = shifted!(b, pubs.shifts[2]);
                        Some(p.publish(&b))
                    }
                    None => None,
                },
                _ => None,
            };
            match sent {
                None => continue,
                // Counted by the publisher (`undelivered`); the replay goes on. A
                // consumer killed without closing its ports keeps a full buffer on the
                // stream until someone removes its dead node, and every later message
                // would wait the whole back-pressure timeout for it: remove it now.
                Some(Err(vibro_ipc::Error::Undelivered { .. })) => {
                    let cleaned = cleanup_dead_nodes(&node);
                    if cleaned > 0 {
                        info!(cleaned, "removed the resources of dead iceoryx2 nodes");
                    }
                }
                Some(Err(e)) => return Err(e.into()),
                Some(Ok(_)) => {}
            }
            last = Some(stream);
            messages += 1;
            if let Some(n) = topics.get_mut(&topic(stream)) {
                *n += 1;
            }
            span_ns = span_ns.max(record.log_time_ns - from);
            if messages % 256 == 0 {
                progress(messages, per_pass);
            }
        }
        passes += 1;
        progress(messages, per_pass);
        if options.passes != 0 && passes >= options.passes {
            break;
        }
        for s in &mut pubs.shifts {
            s.advance();
        }
        // Each pass starts after the previous one ended (Rate pace).
        pass_start_ns = last_due_ns.max(started.elapsed().as_nanos() as u64);
        debug!(passes, "replay pass finished");
    }
    // Lock-step: wait until the services have taken everything.
    if lockstep && !stop.load(Ordering::Acquire) {
        let t = Instant::now();
        if let Some(c) = &mut estimator {
            c.wait_for(vib_sent, options.stall_timeout, stop)?;
        }
        if let Some(c) = &mut compensator {
            c.wait_for(accel_sent, options.stall_timeout, stop)?;
        }
        wait_s += t.elapsed().as_secs_f64();
    }
    let undelivered = pubs.vib.as_ref().map_or(0, |p| p.undelivered())
        + pubs.accel.as_ref().map_or(0, |p| p.undelivered())
        + pubs.truth.as_ref().map_or(0, |p| p.undelivered());
    let elapsed_s = started.elapsed().as_secs_f64();
    let log_span_s = span_ns as f64 * 1e-9;
    let summary = ReplaySummary {
        topics,
        messages,
        passes,
        undelivered,
        log_span_s,
        elapsed_s,
        real_time_factor: log_span_s * passes.max(1) as f64 / elapsed_s.max(1e-9),
        lockstep_waits: waits,
        lockstep_wait_s: wait_s,
        lockstepped: lockstep,
    };
    info!(
        messages,
        passes,
        undelivered,
        real_time_factor = summary.real_time_factor,
        "replay finished"
    );
    Ok(summary)
}
