//! Replaying the rig streams of a log into a running system.

use crate::topics::{known_topics, rig_streams, stream_of_topic, topic};
use crate::{Error, Result};
use std::collections::{BTreeMap, VecDeque};
use std::io::Read as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use tracing::{debug, info, warn};
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

impl Pace {
    /// Slowest paced replay, times real time: 1 s of log in about 17 min. Slower, the
    /// wait before a message (`log time / rate`, u64 ns) outgrows any real session and
    /// a 5e-324 rate waits for ever.
    pub const MIN_RATE: f64 = 1e-3;
    /// Fastest paced replay, times real time (beyond it, `--as-fast-as-possible`).
    pub const MAX_RATE: f64 = 1e6;

    /// The rule of a paced rate (`Pace::Rate`, `replay --rate`, `sim --live --rate`):
    /// `None` when `x` keeps it, else the rule it breaks.
    pub fn rate_problem(x: f64) -> Option<String> {
        (!(x.is_finite() && (Self::MIN_RATE..=Self::MAX_RATE).contains(&x))).then(|| {
            format!(
                "must be finite and {:e} <= rate <= {:e} (a multiple of real time)",
                Self::MIN_RATE,
                Self::MAX_RATE
            )
        })
    }
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
            if let Some(rule) = Pace::rate_problem(x) {
                return Err(Error::Option {
                    name: "rate",
                    value: x.to_string(),
                    rule: rule.into(),
                });
            }
        }
        if !(self.start_s.is_finite() && self.start_s >= 0.0) {
            return Err(Error::Option {
                name: "start_s",
                value: self.start_s.to_string(),
                rule: "must be finite and >= 0".into(),
            });
        }
        if let Some(d) = self.duration_s {
            if !(d.is_finite() && d > 0.0) {
                return Err(Error::Option {
                    name: "duration_s",
                    value: d.to_string(),
                    rule: "must be finite and > 0".into(),
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
    /// Channels of the log that were not replayed, each with the reason: foreign
    /// schemas, topics that are not streams of the system.
    pub skipped_topics: Vec<String>,
}

/// Every MCAP file starts (and ends) with these 8 bytes.
const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// A finished MCAP file holds at least its opening magic, a footer record (opcode,
/// length, 20 bytes) and the closing magic.
const MIN_FINISHED_BYTES: u64 = 8 + 29 + 8;

fn bad(path: &Path, problem: impl Into<String>) -> Error {
    Error::BadLog {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

fn recover_hint(path: &Path) -> String {
    format!(
        "; `vibrocomp log recover {} OUT.mcap` keeps every complete chunk, and OUT.mcap replays",
        path.display()
    )
}

/// What is wrong with a log, in words, and whether `vibrocomp log recover` helps.
fn log_problem(e: &vibro_mcap::Error) -> (String, bool) {
    use vibro_mcap::Error as E;
    match e {
        E::NotFinished { what, .. } => (
            format!(
                "damaged: not finished ({what}); the recorder or simulator did not close it (a crash, a full disk, or a copy still in progress)"
            ),
            true,
        ),
        E::Truncated { .. } => ("damaged: it ends in the middle of a record (truncated)".to_string(), true),
        E::ChunkCrc {
            saved, calculated, ..
        } => (
            format!("damaged: a chunk fails its CRC (expected {saved:08X}, got {calculated:08X})"),
            true,
        ),
        E::Mcap { source, .. } => (
            format!("damaged: {}", crate::describe(source)),
            true,
        ),
        E::Io { action, source, .. } => (format!("cannot {action} it: {source}"), false),
        E::Decode { .. }
        | E::FieldLength { .. }
        | E::ValueOutOfRange { .. }
        | E::Invalid(_) => (format!("a malformed message: {}", crate::describe(e)), false),
        other => (crate::describe(other), false),
    }
}

fn bad_log(path: &Path, e: &vibro_mcap::Error) -> Error {
    let (problem, recoverable) = log_problem(e);
    let hint = if recoverable {
        recover_hint(path)
    } else {
        String::new()
    };
    bad(path, format!("{problem}{hint}"))
}

/// The topics of `streams`, for messages.
fn topic_list(streams: &[Stream]) -> String {
    streams
        .iter()
        .map(|&s| topic(s))
        .collect::<Vec<_>>()
        .join(", ")
}

/// A log opened for replay, with its rig streams and what it holds that is not
/// replayed.
struct Log {
    reader: Reader,
    rig: Vec<Stream>,
    skipped: Vec<String>,
}

/// Opens the log at `path` and checks, before anything is published, that it is an
/// MCAP file, finished, and that its rig topics carry their own message types.
fn open_log(path: &Path) -> Result<Log> {
    let meta = std::fs::metadata(path).map_err(|e| bad(path, format!("cannot open it: {e}")))?;
    if meta.is_dir() {
        return Err(bad(path, "is a directory, not a log file"));
    }
    if !meta.is_file() {
        return Err(bad(
            path,
            "is not a regular file (a log is read from its end first: it must be a file)",
        ));
    }
    if meta.len() == 0 {
        return Err(bad(path, "empty file (0 bytes), not an MCAP log"));
    }
    let mut head = Vec::with_capacity(MCAP_MAGIC.len());
    std::fs::File::open(path)
        .and_then(|f| f.take(MCAP_MAGIC.len() as u64).read_to_end(&mut head))
        .map_err(|e| bad(path, format!("cannot read it: {e}")))?;
    if !MCAP_MAGIC.starts_with(&head) {
        return Err(bad(
            path,
            "not an MCAP log: it does not start with the MCAP magic bytes 89 4D 43 41 50 30 0D 0A",
        ));
    }
    if head.len() < MCAP_MAGIC.len() {
        return Err(bad(
            path,
            format!(
                "damaged: {} bytes, it ends inside the MCAP magic (truncated); nothing to recover",
                head.len()
            ),
        ));
    }
    if meta.len() < MIN_FINISHED_BYTES {
        return Err(bad(
            path,
            format!(
                "damaged: {} bytes, too short for a finished MCAP log (its magic, footer and closing magic alone take {MIN_FINISHED_BYTES}): truncated{}",
                meta.len(),
                recover_hint(path)
            ),
        ));
    }
    let reader = Reader::open(path).map_err(|e| bad_log(path, &e))?;
    let mut skipped: Vec<String> = reader
        .foreign_topics()
        .iter()
        .map(|t| format!("{t} (not a vibrocomp.v1 schema)"))
        .collect();
    let mut rig = Vec::new();
    for (t, kind) in reader.channels() {
        match stream_of_topic(&t) {
            None => skipped.push(format!("{t} ({kind}, not a stream of the system)")),
            Some(stream) if rig_streams().contains(&stream) => {
                if stream.kind() != kind {
                    return Err(bad(
                        path,
                        format!(
                            "topic {t} carries {kind} messages, but the system's {t} carries {}: the log was written wrongly",
                            stream.kind()
                        ),
                    ));
                }
                if !rig.contains(&stream) {
                    rig.push(stream);
                }
            }
            // The services' outputs (/estimate, /compensated, heartbeats): a replay
            // never publishes them, the services make them anew.
            Some(_) => {}
        }
    }
    Ok(Log {
        reader,
        rig,
        skipped,
    })
}

/// The rig streams a replay publishes when not told: all the log has, if that makes
/// sense for the services.
fn default_selection(path: &Path, in_log: &[Stream], skipped: &[String]) -> Result<Vec<Stream>> {
    let has = |s: Stream| in_log.contains(&s);
    if !has(Stream::Vib) && !has(Stream::Accel) {
        let mut what = format!(
            "nothing to replay: no /vib or /accel channel (the services' inputs){}",
            if has(Stream::Truth) {
                "; it has /truth only"
            } else {
                ""
            }
        );
        if !skipped.is_empty() {
            what.push_str(&format!("; not replayable: {}", skipped.join(", ")));
        }
        return Err(Error::Empty {
            path: path.to_path_buf(),
            what,
        });
    }
    if has(Stream::Accel) && !has(Stream::Vib) {
        return Err(bad(
            path,
            "has /accel but no /vib: the estimator would get no vibration, and the compensator would publish main-only readings flagged ESTIMATE_MISSING; select the topics (--topics /accel) to replay it anyway",
        ));
    }
    Ok(in_log.to_vec())
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
    /// `input_samples_to_output` and `input_samples_per_output` of the latest progress
    /// message (0: not reported).
    samples_to_output: u64,
    samples_per_output: u64,
    /// The processes publishing its progress when the replay started (empty: not
    /// known, and then only the stall timeout applies).
    pids: Vec<u32>,
    /// Messages taken by earlier processes of a service restarted during a paced
    /// replay.
    carried: u64,
    /// Since when none of `pids` publishes the progress any more, while that lasts.
    gone_since: Option<Instant>,
    /// The next look at the publishers' processes ([`Consumer::check_alive`]).
    next_probe: Instant,
}

/// The longest a lock-stepped replay waits at its end for the compensator to release
/// the blocks its waveform stage holds (they go out after 1 s of silence on the
/// sensors' stream, `vibro_compensator::waveform::SILENCE_NS`).
const HELD_RELEASE_MAX: Duration = Duration::from_secs(3);

/// How often a replay looks whether its consumers' processes are still there (a list
/// of the progress stream's publishers and of iceoryx2's nodes: a few file reads).
const PROBE_PERIOD: Duration = Duration::from_millis(250);

/// Where a lock-stepped replay must wait (docs/messages.md, "progress"). Waiting at
/// every switch between `/vib` and `/accel` is always right, but each wait is a
/// round trip through the scheduler, and the estimator idles while the replay
/// publishes. An estimate can only come out of a vibration block that completes the
/// estimator's window, and the estimator says where its windows end (the samples its
/// window still needs, and its hop), so:
///
/// - the accelerometer (and truth) blocks after a window-completing vibration block
///   are held, and the vibration blocks that complete nothing go on ahead of them;
/// - before the next vibration block that may complete a window, the replay waits
///   for the estimator (the estimate is out), sends the held blocks, and waits for
///   the compensator to take them, so that the new estimate cannot overtake them.
///
/// "May complete" is conservative: a vibration block that does not follow the
/// previous one exactly (sequence, sample index, rate, or a start time off by more
/// than the rounding of an integer `sample_period_ns`), or a flagged block, is taken
/// as completing one (the estimator may fill a gap with samples), and so is
/// everything from then on, or while the estimator reports 0 (not known), until the
/// next wait for the estimator.
#[derive(Debug, Default)]
struct Gate {
    /// Samples from the last wait for the estimator to the end of its next window
    /// (advanced by `hop` as blocks complete windows); 0: unknown.
    budget: u64,
    /// The estimator's hop; 0: not reported.
    hop: u64,
    /// Vibration samples sent since that wait.
    spent: u64,
    /// A vibration block sent since that wait may have completed a window.
    estimator_due: bool,
    /// Accelerometer blocks were sent since the compensator last took everything.
    accel_pending: bool,
    /// Where the next vibration block follows the last one: `(seq, first index,
    /// t0, period)`.
    next_vib: Option<(u64, u64, u64, u64)>,
}

impl Gate {
    /// The held blocks go out at the latest at this many (about 1 s of the default
    /// flight's accelerometer and truth streams).
    const HELD_MAX: usize = 128;

    fn follows(&self, b: &VibHead) -> bool {
        let count = u64::from(b.count);
        self.next_vib.is_some_and(|(seq, index, t0_ns, period_ns)| {
            b.seq == seq
                && b.first_sample_index == index
                && b.sample_period_ns == period_ns
                && b.t0_ns.abs_diff(t0_ns) <= count.max(1)
                && b.flags == 0
        })
    }

    /// May vibration block `b`, sent next, complete the estimator's window?
    fn may_complete(&self, b: &VibHead) -> bool {
        self.may_complete_given(b, self.follows(b))
    }

    fn may_complete_given(&self, b: &VibHead, follows: bool) -> bool {
        !follows || self.budget == 0 || self.spent.saturating_add(u64::from(b.count)) >= self.budget
    }

    /// Before vibration block `b` (as published): must the replay first wait for the
    /// compensator? Also books the block.
    fn before_vib(&mut self, b: VibHead) -> bool {
        let count = u64::from(b.count);
        let follows = self.follows(&b);
        let may_complete = self.may_complete_given(&b, follows);
        self.next_vib = Some((
            b.seq.wrapping_add(1),
            b.first_sample_index.wrapping_add(count),
            b.t0_ns.wrapping_add(count.wrapping_mul(b.sample_period_ns)),
            b.sample_period_ns,
        ));
        self.spent = self.spent.saturating_add(count);
        if may_complete {
            self.estimator_due = true;
            if follows && self.budget > 0 && self.hop > 0 {
                // A contiguous block completed a window: the next ends a hop later.
                while self.spent >= self.budget {
                    self.budget = self.budget.saturating_add(self.hop);
                }
            } else {
                self.budget = 0;
            }
        }
        may_complete && self.accel_pending
    }

    /// The compensator has taken every accelerometer block sent.
    fn compensator_synced(&mut self) {
        self.accel_pending = false;
    }

    /// Should the next accelerometer or truth block be held (behind the vibration
    /// blocks that follow it)? `held` blocks are already waiting.
    fn hold(&self, held: usize) -> bool {
        held > 0 || self.estimator_due
    }

    /// Before an accelerometer block: must the replay first wait for the estimator?
    fn before_accel(&mut self) -> bool {
        self.accel_pending = true;
        self.estimator_due
    }

    /// The estimator has taken every vibration block sent and reports that its
    /// window needs `samples_to_output` more samples, then `per_output` per estimate.
    fn estimator_synced(&mut self, samples_to_output: u64, per_output: u64) {
        self.budget = samples_to_output;
        self.hop = per_output;
        self.spent = 0;
        self.estimator_due = false;
    }
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
            samples_to_output: 0,
            samples_per_output: 0,
            pids: Vec::new(),
            carried: 0,
            gone_since: None,
            next_probe: Instant::now(),
        })
    }

    /// Messages of this replay the service has taken (its restarted processes'
    /// included, in a paced replay).
    fn taken(&self) -> u64 {
        self.carried + self.received.saturating_sub(self.baseline)
    }

    /// Looks (at most every [`PROBE_PERIOD`]) whether the process that took this
    /// replay's messages still publishes the service's progress. Fails with
    /// [`Error::Vanished`] once it has been gone for `grace`: no alive process
    /// publishes it (stopped, killed: a killed process's node is dead, not alive), or,
    /// unless `restart_ok`, another process does (a restart: its counts start again).
    /// With `restart_ok` (paced replay) a new process takes over the count. Returns
    /// whether the process is there at the last look.
    fn check_alive(&mut self, sent: u64, grace: Duration, restart_ok: bool) -> Result<bool> {
        let now = Instant::now();
        if self.pids.is_empty() || now < self.next_probe {
            return Ok(self.gone_since.is_none());
        }
        self.next_probe = now + PROBE_PERIOD;
        let live = self.progress.publisher_pids();
        if live.iter().any(|p| self.pids.contains(p)) {
            self.gone_since = None;
            return Ok(true);
        }
        if restart_ok && !live.is_empty() {
            self.poll()?;
            self.carried = self.taken();
            info!(
                service = self.name(),
                was = ?self.pids,
                now = ?live,
                taken = self.carried,
                "the service was restarted; counting what the new process takes"
            );
            (self.baseline, self.received) = (0, 0);
            self.pids = live;
            self.gone_since = None;
            return Ok(true);
        }
        let since = *self.gone_since.get_or_insert(now);
        if now.duration_since(since) < grace {
            return Ok(false);
        }
        self.poll()?;
        let taken = self.taken();
        let list = |v: &[u32]| v.iter().map(u32::to_string).collect::<Vec<_>>().join(", ");
        let mut how = if live.is_empty() {
            "no live process publishes its progress any more: it exited or was killed".to_string()
        } else {
            format!(
                "pid {} publishes its progress now: it was restarted, and a lock-stepped replay cannot count what a new process takes",
                list(&live)
            )
        };
        if restart_ok {
            how.push_str(&format!(
                ", and none replaced it within {} s",
                grace.as_secs_f64()
            ));
        }
        Err(Error::Vanished {
            service: self.name(),
            pids: list(&self.pids),
            stream: self.stream.clone(),
            how,
            taken,
            sent,
            unprocessed: sent.saturating_sub(taken),
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
            self.samples_to_output = m.input_samples_to_output;
            self.samples_per_output = m.input_samples_per_output;
        }
        Ok(())
    }

    /// Waits until the service reports nothing held (`input_samples_to_output` 0: the
    /// compensator's readings waiting for their vibration samples), at most `max`.
    fn wait_released(&mut self, max: Duration, stop: &AtomicBool) -> Result<()> {
        let t = Instant::now();
        self.poll()?;
        while self.samples_to_output > 0 && t.elapsed() < max && !stop.load(Ordering::Acquire) {
            let _ = self
                .progress
                .listener()
                .timed_wait(|_| {}, Duration::from_millis(10));
            self.poll()?;
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
                self.gone_since = None;
            } else if since.elapsed() >= PROBE_PERIOD {
                // No progress for a while: is the process still there? Two looks
                // PROBE_PERIOD apart that find it gone end the wait.
                self.check_alive(sent, PROBE_PERIOD, false)?;
            }
            if self.received == last && since.elapsed() > stall {
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

/// Each service's `received` count before the replay, from its next heartbeat (all
/// waited for at once: at most one heartbeat period), and the processes publishing
/// its progress. [`Error::NoProgress`] names the first service with no heartbeat
/// within `timeout`.
fn baselines(
    node: &IpcNode,
    names: &ServiceNames,
    consumers: &mut [&mut Consumer],
    timeout: Duration,
) -> Result<()> {
    let heartbeats = consumers
        .iter()
        .map(|c| StreamSubscriber::<Heartbeat>::open(node, names, Stream::Heartbeat(c.service)))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let mut done = vec![false; consumers.len()];
    let start = Instant::now();
    loop {
        for ((c, hb), done) in consumers.iter_mut().zip(&heartbeats).zip(&mut done) {
            if *done {
                continue;
            }
            if let Some(h) = hb.receive()? {
                c.baseline = h.received;
                c.received = h.received;
                c.pids = c.progress.publisher_pids();
                // Progress messages older than the heartbeat would only repeat it.
                while c.progress.receive()?.is_some() {}
                *done = true;
            }
        }
        if let Some(i) = done.iter().position(|d| !d) {
            if start.elapsed() > timeout {
                return Err(Error::NoProgress {
                    service: consumers[i].name(),
                    stream: names.stream(Stream::Heartbeat(consumers[i].service)),
                    waited_s: timeout.as_secs_f64(),
                });
            }
            let _ = heartbeats[i]
                .listener()
                .timed_wait(|_| {}, Duration::from_millis(50));
        } else {
            return Ok(());
        }
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

/// Records decoded ahead of the replay loop, on a thread of their own: decompressing
/// and decoding the log (zstd and protobuf, most of the replay's own CPU time) then
/// overlaps with the waits for the services, and the loop only publishes. Holds at
/// most [`ReadAhead::DEPTH`] records; dropping it stops the thread. Reads on the
/// caller's thread if no thread can be started.
enum ReadAhead {
    Thread {
        records: Option<std::sync::mpsc::Receiver<vibro_mcap::Result<vibro_mcap::Record>>>,
        thread: Option<std::thread::JoinHandle<()>>,
    },
    Inline(Box<Reader>),
}

impl ReadAhead {
    /// About 0.5 s of the default flight's rig streams.
    const DEPTH: usize = 64;

    fn new(reader: Reader) -> Self {
        let (tx, rx) = std::sync::mpsc::sync_channel(Self::DEPTH);
        // The reader moves into the thread only if it starts.
        let slot = std::sync::Arc::new(std::sync::Mutex::new(Some(reader)));
        let theirs = std::sync::Arc::clone(&slot);
        let spawned = std::thread::Builder::new()
            .name("vibro-log-read".into())
            .spawn(move || {
                let reader = theirs.lock().ok().and_then(|mut r| r.take());
                for record in reader.into_iter().flatten() {
                    if tx.send(record).is_err() {
                        break; // the replay stopped
                    }
                }
            });
        match spawned {
            Ok(thread) => ReadAhead::Thread {
                records: Some(rx),
                thread: Some(thread),
            },
            Err(e) => {
                debug!("reading the log on the replay's thread (no reader thread: {e})");
                match slot.lock().ok().and_then(|mut r| r.take()) {
                    Some(reader) => ReadAhead::Inline(Box::new(reader)),
                    // Unreachable: a thread that did not start took nothing.
                    None => ReadAhead::Thread {
                        records: None,
                        thread: None,
                    },
                }
            }
        }
    }
}

impl Iterator for ReadAhead {
    type Item = vibro_mcap::Result<vibro_mcap::Record>;

    fn next(&mut self) -> Option<Self::Item> {
        match self {
            ReadAhead::Thread { records, .. } => records.as_ref()?.recv().ok(),
            ReadAhead::Inline(reader) => reader.next(),
        }
    }
}

impl Drop for ReadAhead {
    fn drop(&mut self) {
        if let ReadAhead::Thread { records, thread } = self {
            // The thread's next send fails, and it ends.
            *records = None;
            if let Some(t) = thread.take() {
                let _ = t.join();
            }
        }
    }
}

/// What [`Gate`] looks at in a vibration block, as published (shifted).
#[derive(Debug, Clone, Copy)]
struct VibHead {
    seq: u64,
    first_sample_index: u64,
    t0_ns: u64,
    sample_period_ns: u64,
    count: u32,
    flags: u32,
}

impl Shift {
    /// The head of `b` as it will be published in this pass.
    fn head(&self, b: &VibBlock) -> VibHead {
        VibHead {
            seq: b.seq.wrapping_add(self.seq),
            first_sample_index: b.first_sample_index.wrapping_add(self.index),
            t0_ns: b.t0_ns.wrapping_add(self.time_ns),
            sample_period_ns: b.sample_period_ns,
            count: b.count,
            flags: b.flags,
        }
    }

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
///
/// The log is checked before any service is opened: [`Error::BadLog`] for a file that
/// is not a finished MCAP log or whose rig topics carry other types, or that has
/// `/accel` without `/vib` (unless `options.topics` names them), [`Error::Empty`] for
/// one with nothing to replay. Foreign channels are skipped and listed in
/// [`ReplaySummary::skipped_topics`]. A chunk that turns out damaged stops the replay
/// where it is ([`Error::DamagedPartWay`]), and so does a pass that publishes nothing
/// (a window past the end), which `passes = 0` would otherwise repeat for ever.
///
/// The phases: the log (`ReplayLog::open`), the ports (`Ports::open`: publishers,
/// their subscribers), the lock-step's gate and consumers (`LockStep::open`), then
/// the services a paced replay watches (`Watch::open`), then the passes through the
/// log (`Replayer::run`).
///
/// A consumer whose process goes away fails the replay with [`Error::Vanished`] and
/// the count of the messages it did not take: when lock-stepped, once it has made
/// no progress for two looks [`PROBE_PERIOD`] apart (a stopped, killed or restarted
/// service); when paced, once it has been gone for `stall_timeout` without a new
/// process (a restart) taking its place.
pub fn replay(
    path: &Path,
    options: &ReplayOptions,
    stop: &AtomicBool,
    mut progress: impl FnMut(u64, u64),
) -> Result<ReplaySummary> {
    options.check()?;
    let log = ReplayLog::open(path, options)?;
    let ports = Ports::open(&log.selected, options, stop)?;
    let lock = LockStep::open(&ports, options)?;
    let watch = Watch::open(&ports, options)?;
    Replayer::new(path, options, stop, log, ports, lock, watch).run(&mut progress)
}

/// A replay's log, checked, and what of it to publish: the first phase of [`replay`],
/// before anything is opened on the transport.
struct ReplayLog {
    /// The rig streams to publish.
    selected: Vec<Stream>,
    /// Channels of the log that are not replayed, each with the reason.
    skipped_topics: Vec<String>,
    /// Messages in one pass through the log (0: not known).
    per_pass: u64,
}

impl ReplayLog {
    fn open(path: &Path, options: &ReplayOptions) -> Result<Self> {
        let log = open_log(path)?;
        let (reader, in_log, skipped_topics) = (log.reader, log.rig, log.skipped);
        if !skipped_topics.is_empty() {
            warn!(path = %path.display(), skipped = %skipped_topics.join("; "), "not replaying some channels of the log");
        }
        let selected: Vec<Stream> = match &options.topics {
            None => default_selection(path, &in_log, &skipped_topics)?,
            Some(topics) => chosen_selection(topics, &in_log)?,
        };
        if reader.message_count() == Some(0) {
            return Err(Error::Empty {
                path: path.to_path_buf(),
                what: format!(
                    "no messages: a valid MCAP log, but its channels ({}) hold nothing to replay",
                    topic_list(&in_log)
                ),
            });
        }
        let per_pass = reader.message_count().unwrap_or(0);
        drop(reader);
        Ok(Self {
            selected,
            skipped_topics,
            per_pass,
        })
    }
}

/// The rig streams of `topics` (`ReplayOptions::topics`), each a rig stream of the log.
fn chosen_selection(topics: &[String], in_log: &[Stream]) -> Result<Vec<Stream>> {
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
    Ok(v)
}

/// A replay's side of the transport: the publishers of the selected streams, each of
/// the services' inputs with a subscriber, and their node. The second phase of
/// [`replay`].
struct Ports {
    // Declared before the node: the ports close first.
    pubs: Publishers,
    node: IpcNode,
}

impl Ports {
    fn open(selected: &[Stream], options: &ReplayOptions, stop: &AtomicBool) -> Result<Self> {
        let names = &options.names;
        let node = create_node("vibrocomp-replay")?;
        let pubs = Publishers {
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
        // A second feeder (another replay, a live rig) on the services' inputs: the
        // services would see two streams interleaved as one (sequence and sample
        // index jumps, every window mixing both), paced or not, and a lock-step would
        // count the other's messages as this replay's. Refused, not serialised: the
        // other feeder may run for ever (`--loop`, a rig). Only the streams this
        // replay publishes are checked (`--topics /truth` beside a rig is fine).
        {
            let others = [
                (
                    Stream::Vib,
                    pubs.vib
                        .as_ref()
                        .map(|p| (p.publisher_count(), p.other_publisher_pids())),
                ),
                (
                    Stream::Accel,
                    pubs.accel
                        .as_ref()
                        .map(|p| (p.publisher_count(), p.other_publisher_pids())),
                ),
            ];
            for (stream, found) in others {
                let Some((count, pids)) = found else { continue };
                if count > 1 {
                    let dead = cleanup_dead_nodes(&node);
                    let pids = match stream {
                        Stream::Vib => pubs.vib.as_ref().map(|p| p.other_publisher_pids()),
                        _ => pubs.accel.as_ref().map(|p| p.other_publisher_pids()),
                    }
                    .unwrap_or(pids);
                    if dead > 0 && pids.is_empty() {
                        continue; // the other publisher was a dead process's
                    }
                    return Err(Error::SecondFeeder {
                        stream: names.stream(stream),
                        pids: if pids.is_empty() {
                            "unknown".into()
                        } else {
                            pids.iter()
                                .map(u32::to_string)
                                .collect::<Vec<_>>()
                                .join(", ")
                        },
                    });
                }
            }
        }
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
        Ok(Self { pubs, node })
    }
}

/// A lock-stepped replay's gate and the consumers it waits for, their baselines taken:
/// the third phase of [`replay`] (none for a paced replay).
struct LockStep {
    gate: Gate,
    /// The estimator, when `/vib` is published.
    estimator: Option<Consumer>,
    /// The compensator, when `/accel` is published.
    compensator: Option<Consumer>,
}

impl LockStep {
    fn open(ports: &Ports, options: &ReplayOptions) -> Result<Option<Self>> {
        if options.pace != Pace::AsFastAsPossible {
            return Ok(None);
        }
        let (node, names) = (&ports.node, &options.names);
        let mut estimator = ports
            .pubs
            .vib
            .is_some()
            .then(|| Consumer::open(node, names, ServiceId::Estimator, Stream::Vib))
            .transpose()?;
        let mut compensator = ports
            .pubs
            .accel
            .is_some()
            .then(|| Consumer::open(node, names, ServiceId::Compensator, Stream::Accel))
            .transpose()?;
        let mut both: Vec<&mut Consumer> =
            estimator.iter_mut().chain(compensator.iter_mut()).collect();
        baselines(node, names, &mut both, options.connect_timeout)?;
        Ok(Some(Self {
            gate: Gate::default(),
            estimator,
            compensator,
        }))
    }
}

/// The services a paced replay watches (it does not wait for them): the estimator
/// and the compensator, each if it publishes its progress when the replay starts. A
/// paced replay fails ([`Error::Vanished`]) when one of them is gone for longer than
/// the stall timeout and no new process (a restart by `vibrocomp up`) took its place,
/// saying how many of the messages sent it had taken.
///
/// It does not wait for a baseline either: each service's count starts at its first
/// heartbeat during the replay (at most a heartbeat period in), taken to have caught
/// up with what was sent by then (a paced replay does not outrun a live service; the
/// count is off by the blocks in flight at that instant otherwise, at most a
/// subscriber buffer). Until then a vanished service is reported with 0 taken.
struct Watch {
    consumers: Vec<Consumer>,
    /// Each consumer's heartbeats, until the first one gives its baseline.
    heartbeats: Vec<Option<StreamSubscriber<Heartbeat>>>,
}

impl Watch {
    fn open(ports: &Ports, options: &ReplayOptions) -> Result<Self> {
        let (mut consumers, mut heartbeats) = (Vec::new(), Vec::new());
        if options.pace == Pace::AsFastAsPossible {
            return Ok(Self {
                consumers,
                heartbeats,
            });
        }
        let (node, names) = (&ports.node, &options.names);
        for (published, service, stream) in [
            (ports.pubs.vib.is_some(), ServiceId::Estimator, Stream::Vib),
            (
                ports.pubs.accel.is_some(),
                ServiceId::Compensator,
                Stream::Accel,
            ),
        ] {
            if !published {
                continue;
            }
            let mut c = Consumer::open(node, names, service, stream)?;
            c.pids = c.progress.publisher_pids();
            if c.pids.is_empty() {
                debug!(
                    service = c.name(),
                    "not running: the paced replay does not watch it"
                );
                continue;
            }
            // No count before the first heartbeat (`taken` saturates to 0).
            c.baseline = u64::MAX;
            heartbeats.push(Some(StreamSubscriber::open(
                node,
                names,
                Stream::Heartbeat(service),
            )?));
            consumers.push(c);
        }
        Ok(Self {
            consumers,
            heartbeats,
        })
    }

    /// Takes the services' progress messages (their publishers must not wait for
    /// this replay) and, now and then, looks whether they are still there.
    fn check(&mut self, vib_sent: u64, accel_sent: u64, grace: Duration) -> Result<bool> {
        let mut all_there = true;
        for (c, hb) in self.consumers.iter_mut().zip(&mut self.heartbeats) {
            c.poll()?;
            let sent = match c.service {
                ServiceId::Estimator => vib_sent,
                _ => accel_sent,
            };
            if let Some(h) = hb.as_ref().map(|s| s.receive()).transpose()?.flatten() {
                (c.baseline, c.carried) = (h.received, sent);
                c.received = c.received.max(h.received);
                *hb = None;
            }
            all_there &= c.check_alive(sent, grace, true)?;
        }
        Ok(all_there)
    }
}

/// How a pass through the log ended.
enum PassEnd {
    /// Through the log, or its window: the time the last record was due (Rate pace).
    Done { last_due_ns: u64 },
    /// `stop` was set.
    Stopped,
}

/// The replay loop over the passes through the log: the last phase of [`replay`].
struct Replayer<'a> {
    path: &'a Path,
    options: &'a ReplayOptions,
    stop: &'a AtomicBool,
    log: ReplayLog,
    // Declared before the ports: the consumers' subscribers close before the node.
    lock: Option<LockStep>,
    watch: Watch,
    ports: Ports,
    /// Messages published per topic.
    topics: BTreeMap<String, u64>,
    vib_sent: u64,
    accel_sent: u64,
    /// Times the lock-step waited, and the time spent waiting, s.
    waits: u64,
    wait_s: f64,
    /// Records to publish now, and records held behind the vibration blocks (`Gate`).
    ready: VecDeque<(vibro_mcap::Record, Stream)>,
    held: VecDeque<(vibro_mcap::Record, Stream)>,
    messages: u64,
    passes: u64,
    /// Log time covered by one pass, ns.
    span_ns: u64,
    started: Instant,
    /// Wall-clock offset of the current pass (Rate pace), ns.
    pass_start_ns: u64,
}

impl<'a> Replayer<'a> {
    fn new(
        path: &'a Path,
        options: &'a ReplayOptions,
        stop: &'a AtomicBool,
        log: ReplayLog,
        ports: Ports,
        lock: Option<LockStep>,
        watch: Watch,
    ) -> Self {
        let topics = log.selected.iter().map(|&s| (topic(s), 0)).collect();
        Self {
            path,
            options,
            stop,
            log,
            lock,
            watch,
            ports,
            topics,
            vib_sent: 0,
            accel_sent: 0,
            waits: 0,
            wait_s: 0.0,
            ready: VecDeque::new(),
            held: VecDeque::new(),
            messages: 0,
            passes: 0,
            span_ns: 0,
            started: Instant::now(),
            pass_start_ns: 0,
        }
    }

    /// Passes through the log until `options.passes` are done (or `stop`), then waits
    /// for the services (lock-step) and sums up.
    fn run(mut self, progress: &mut dyn FnMut(u64, u64)) -> Result<ReplaySummary> {
        loop {
            let published_before = self.messages;
            let last_due_ns = match self.pass(progress)? {
                PassEnd::Done { last_due_ns } => last_due_ns,
                PassEnd::Stopped => break,
            };
            // A pass that published nothing would loop for ever with `passes = 0`.
            if self.messages == published_before && !self.stop.load(Ordering::Acquire) {
                let options = self.options;
                return Err(Error::Empty {
                    path: self.path.to_path_buf(),
                    what: format!(
                        "no message of {} from {} s into the log{} (the log has {} messages in all)",
                        topic_list(&self.log.selected),
                        options.start_s,
                        options
                            .duration_s
                            .map_or_else(String::new, |d| format!(" for {d} s")),
                        self.log.per_pass
                    ),
                });
            }
            self.passes += 1;
            progress(self.messages, self.log.per_pass);
            if self.options.passes != 0 && self.passes >= self.options.passes {
                break;
            }
            for s in &mut self.ports.pubs.shifts {
                s.advance();
            }
            // Each pass starts after the previous one ended (Rate pace).
            self.pass_start_ns = last_due_ns.max(self.started.elapsed().as_nanos() as u64);
            debug!(passes = self.passes, "replay pass finished");
        }
        self.finish()
    }

    /// One pass through the log: the records in the window, paced or held as the gate
    /// says, published in order.
    fn pass(&mut self, progress: &mut dyn FnMut(u64, u64)) -> Result<PassEnd> {
        let (path, options) = (self.path, self.options);
        let reader = ReadAhead::new(Reader::open(path).map_err(|e| bad_log(path, &e))?);
        let mut first_log_ns: Option<u64> = None;
        let mut window: Option<(u64, u64)> = None;
        let mut last_due_ns = 0u64;
        let mut last_log_ns = 0u64;
        // `None` after the last record: the pass is over, the held blocks go out.
        let mut records = reader.map(Some).chain(std::iter::once(None));
        loop {
            let Some(Some(record)) = records.next() else {
                self.ready.extend(self.held.drain(..));
                self.publish_ready(window, progress)?;
                break;
            };
            let record = match record {
                Ok(record) => record,
                Err(e) => {
                    // What came before the damage goes out first.
                    self.ready.extend(self.held.drain(..));
                    self.publish_ready(window, progress)?;
                    debug!(
                        messages = self.messages,
                        waits = self.waits,
                        wait_s = self.wait_s,
                        "the log is damaged here; stopping"
                    );
                    let (problem, recoverable) = log_problem(&e);
                    return Err(Error::DamagedPartWay {
                        path: path.to_path_buf(),
                        problem,
                        published: self.messages,
                        log_time_s: last_log_ns.saturating_sub(first_log_ns.unwrap_or(0)) as f64
                            * 1e-9,
                        hint: if recoverable {
                            recover_hint(path)
                        } else {
                            String::new()
                        },
                    });
                }
            };
            last_log_ns = record.log_time_ns;
            if self.stop.load(Ordering::Acquire) {
                return Ok(PassEnd::Stopped);
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
                self.ready.extend(self.held.drain(..));
                self.publish_ready(window, progress)?;
                break;
            }
            let Some(stream) = stream_of_topic(&record.topic) else {
                continue;
            };
            if !self.log.selected.contains(&stream) {
                continue;
            }
            if let Pace::Rate(x) = options.pace {
                let due_ns = self.pass_start_ns + ((record.log_time_ns - from) as f64 / x) as u64;
                last_due_ns = due_ns;
                let now = self.started.elapsed().as_nanos() as u64;
                if due_ns > now {
                    std::thread::sleep(Duration::from_nanos(due_ns - now));
                }
            }
            // Lock-step: hold what could be overtaken (`Gate`).
            match (&record.message, stream, &self.lock) {
                (Message::VibBlock(b), Stream::Vib, Some(lock)) => {
                    if lock.gate.may_complete(&self.ports.pubs.shifts[0].head(b)) {
                        self.ready.extend(self.held.drain(..));
                    }
                    self.ready.push_back((record, stream));
                }
                (_, Stream::Accel | Stream::Truth, Some(lock))
                    if lock.gate.hold(self.held.len()) =>
                {
                    self.held.push_back((record, stream));
                    if self.held.len() >= Gate::HELD_MAX {
                        self.ready.extend(self.held.drain(..));
                    }
                }
                _ => self.ready.push_back((record, stream)),
            }
            self.publish_ready(window, progress)?;
        }
        Ok(PassEnd::Done { last_due_ns })
    }

    /// Publishes what is ready, in order, each after the waits it needs. `window` is the
    /// pass's log-time window (for the span covered).
    fn publish_ready(
        &mut self,
        window: Option<(u64, u64)>,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<()> {
        while let Some((record, stream)) = self.ready.pop_front() {
            // Lock-step: the other stream's consumer must have taken everything sent
            // before this stream's next message, where that message could be overtaken
            // (`Gate`).
            if let Some(lock) = &mut self.lock {
                let t = Instant::now();
                let mut waited = false;
                let consumer = match (&record.message, stream) {
                    (Message::AccelBlock(_), Stream::Accel) => {
                        lock.gate.before_accel().then_some(ServiceId::Estimator)
                    }
                    (Message::VibBlock(b), Stream::Vib) => lock
                        .gate
                        .before_vib(self.ports.pubs.shifts[0].head(b))
                        .then_some(ServiceId::Compensator),
                    _ => None,
                };
                match consumer {
                    Some(ServiceId::Estimator) => {
                        if let Some(c) = &mut lock.estimator {
                            waited =
                                c.wait_for(self.vib_sent, self.options.stall_timeout, self.stop)?;
                            lock.gate
                                .estimator_synced(c.samples_to_output, c.samples_per_output);
                        }
                    }
                    Some(_) => {
                        if let Some(c) = &mut lock.compensator {
                            waited =
                                c.wait_for(self.accel_sent, self.options.stall_timeout, self.stop)?;
                        }
                        lock.gate.compensator_synced();
                    }
                    None => {}
                }
                if waited {
                    self.waits += 1;
                    self.wait_s += t.elapsed().as_secs_f64();
                }
            }
            let pubs = &mut self.ports.pubs;
            let sent = match (&record.message, stream) {
                (Message::VibBlock(b), Stream::Vib) => match &mut pubs.vib {
                    Some(p) => {
                        let b = shifted!(b, pubs.shifts[0]);
                        self.vib_sent += 1;
                        Some(p.publish(&b))
                    }
                    None => None,
                },
                (Message::AccelBlock(b), Stream::Accel) => match &mut pubs.accel {
                    Some(p) => {
                        let b = shifted!(b, pubs.shifts[1]);
                        self.accel_sent += 1;
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
                    let cleaned = cleanup_dead_nodes(&self.ports.node);
                    if cleaned > 0 {
                        info!(cleaned, "removed the resources of dead iceoryx2 nodes");
                    }
                }
                Some(Err(e)) => return Err(e.into()),
                Some(Ok(_)) => {}
            }
            self.messages += 1;
            if !self.watch.consumers.is_empty() {
                self.watch
                    .check(self.vib_sent, self.accel_sent, self.options.stall_timeout)?;
            }
            if let Some(n) = self.topics.get_mut(&topic(stream)) {
                *n += 1;
            }
            self.span_ns = self
                .span_ns
                .max(record.log_time_ns.saturating_sub(window.map_or(0, |w| w.0)));
            if self.messages % 256 == 0 {
                progress(self.messages, self.log.per_pass);
            }
        }
        Ok(())
    }

    /// Lock-step: waits until the services have taken everything; then the summary.
    fn finish(mut self) -> Result<ReplaySummary> {
        let lockstep = self.lock.is_some();
        if let Some(lock) = &mut self.lock {
            if !self.stop.load(Ordering::Acquire) {
                let t = Instant::now();
                if let Some(c) = &mut lock.estimator {
                    c.wait_for(self.vib_sent, self.options.stall_timeout, self.stop)?;
                }
                if let Some(c) = &mut lock.compensator {
                    c.wait_for(self.accel_sent, self.options.stall_timeout, self.stop)?;
                    // The waveform stage holds the last blocks until the sensors'
                    // stream has been silent a while (the log's last samples cannot
                    // cover them; a log's stream does not end with an end-of-stream
                    // block, and one added here would be a message the log lacks):
                    // wait until it has published them, so that a recorder stopped
                    // right after the replay records every block.
                    c.wait_released(HELD_RELEASE_MAX, self.stop)?;
                }
                self.wait_s += t.elapsed().as_secs_f64();
            }
        }
        // Paced: the services must still be there (or restarted) at the end; one that
        // is gone gets the rest of its grace to come back.
        if !self.watch.consumers.is_empty() {
            for c in &mut self.watch.consumers {
                c.next_probe = Instant::now();
            }
            while !self
                .watch
                .check(self.vib_sent, self.accel_sent, self.options.stall_timeout)?
            {
                if self.stop.load(Ordering::Acquire) {
                    break;
                }
                std::thread::sleep(PROBE_PERIOD);
            }
        }
        let pubs = &self.ports.pubs;
        let undelivered = pubs.vib.as_ref().map_or(0, |p| p.undelivered())
            + pubs.accel.as_ref().map_or(0, |p| p.undelivered())
            + pubs.truth.as_ref().map_or(0, |p| p.undelivered());
        let elapsed_s = self.started.elapsed().as_secs_f64();
        let log_span_s = self.span_ns as f64 * 1e-9;
        let passes = self.passes;
        let summary = ReplaySummary {
            topics: self.topics,
            messages: self.messages,
            passes,
            undelivered,
            log_span_s,
            elapsed_s,
            real_time_factor: log_span_s * passes.max(1) as f64 / elapsed_s.max(1e-9),
            lockstep_waits: self.waits,
            lockstep_wait_s: self.wait_s,
            lockstepped: lockstep,
            skipped_topics: self.log.skipped_topics,
        };
        info!(
            messages = summary.messages,
            passes,
            undelivered,
            real_time_factor = summary.real_time_factor,
            "replay finished"
        );
        Ok(summary)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 512-sample blocks at 25.6 kHz: 20 ms apart exactly, while the integer period
    /// (39062 ns) times 512 falls 256 ns short, as in the simulator's logs.
    fn vib(k: u64) -> VibHead {
        VibHead {
            seq: k,
            first_sample_index: 512 * k,
            t0_ns: 20_000_000 * k,
            sample_period_ns: 39_062,
            count: 512,
            flags: 0,
        }
    }

    /// Estimates an estimator with this window and hop has made after `m` blocks.
    fn completions(m: u64, window: u64, hop: u64) -> u64 {
        let s = 512 * m;
        if s >= window {
            (s - window) / hop + 1
        } else {
            0
        }
    }

    /// Samples the estimator's window still needs after `m` blocks.
    fn remaining(m: u64, window: u64, hop: u64) -> u64 {
        let s = 512 * m;
        if s < window {
            window - s
        } else {
            hop - (s - window) % hop
        }
    }

    #[derive(Debug, Clone, Copy)]
    enum Item {
        Vib(u64),
        Accel(u64),
        Truth,
    }

    /// Replays the default flight's log order (two vibration blocks, then an
    /// accelerometer and a truth block) as `replay` does (holding, then publishing
    /// each record after its waits), against an estimator with this window and hop,
    /// and checks the lock-step's promise at every publish:
    /// - an accelerometer block goes out when exactly the estimates of the vibration
    ///   blocks before it in the log are out (no later one: the blocks sent ahead of
    ///   it complete no window);
    /// - a vibration block that completes a window goes out when the compensator has
    ///   taken every accelerometer block before it in the log.
    ///
    /// Returns the waits `(estimator, compensator)` and the most records held.
    fn simulate(blocks: u64, window: u64, hop: u64, report: bool) -> (u64, u64, usize) {
        let mut gate = Gate::default();
        let (mut held, mut ready) = (VecDeque::new(), VecDeque::new());
        let (mut vib_sent, mut accel_sent, mut taken, mut synced) = (0u64, 0u64, 0u64, 0u64);
        let (mut est_waits, mut comp_waits, mut most_held) = (0, 0, 0);
        let mut log = (0..blocks).flat_map(|k| {
            let mut v = vec![Item::Vib(k)];
            if k % 2 == 1 {
                v.extend([Item::Accel(k / 2), Item::Truth]);
            }
            v
        });
        let mut over = false;
        while !over {
            match log.next() {
                None => {
                    ready.extend(held.drain(..));
                    over = true;
                }
                Some(Item::Vib(k)) => {
                    if gate.may_complete(&vib(k)) {
                        ready.extend(held.drain(..));
                    }
                    ready.push_back(Item::Vib(k));
                }
                Some(other) => {
                    if gate.hold(held.len()) {
                        held.push_back(other);
                        most_held = most_held.max(held.len());
                        if held.len() >= Gate::HELD_MAX {
                            ready.extend(held.drain(..));
                        }
                    } else {
                        ready.push_back(other);
                    }
                }
            }
            while let Some(item) = ready.pop_front() {
                match item {
                    Item::Vib(k) => {
                        if gate.before_vib(vib(k)) {
                            comp_waits += 1;
                            taken = accel_sent;
                            gate.compensator_synced();
                        }
                        assert_eq!(vib_sent, k, "vibration blocks in order");
                        vib_sent += 1;
                        let makes = completions(k + 1, window, hop) > completions(k, window, hop);
                        // Accelerometer blocks before vib k in the log: k / 2.
                        assert!(!makes || taken >= k / 2, "vib {k}: accel not taken");
                    }
                    Item::Accel(a) => {
                        if gate.before_accel() {
                            est_waits += 1;
                            synced = completions(vib_sent, window, hop);
                            let (r, h) = if report {
                                (remaining(vib_sent, window, hop), hop)
                            } else {
                                (0, 0)
                            };
                            gate.estimator_synced(r, h);
                        }
                        assert_eq!(accel_sent, a, "accelerometer blocks in order");
                        let before = completions(2 * a + 2, window, hop);
                        assert_eq!(completions(vib_sent, window, hop), before, "accel {a}");
                        assert_eq!(synced, before, "accel {a}: estimate not awaited");
                        accel_sent += 1;
                    }
                    Item::Truth => {}
                }
            }
        }
        assert_eq!((vib_sent, accel_sent), (blocks, blocks / 2));
        (est_waits, comp_waits, most_held)
    }

    #[test]
    fn the_gate_waits_only_where_an_estimate_can_come_out() {
        // 600 s: 30,000 blocks, an estimate every 12,800 samples (25 blocks).
        let estimates = completions(30_000, 25_600, 12_800);
        assert_eq!(estimates, 1199);
        let (est, comp, most_held) = simulate(30_000, 25_600, 12_800, true);
        // One wait each per estimate, plus the first blocks (nothing known yet).
        assert!((estimates..=estimates + 2).contains(&est), "{est}");
        assert!((estimates - 1..=estimates + 2).contains(&comp), "{comp}");
        // What follows an estimate waits behind the next 25 vibration blocks.
        assert!((24..=26).contains(&most_held), "{most_held}");
        // Other windows and hops, with the estimates 1 block or less apart.
        for (window, hop) in [(25_600, 25_600), (1000, 300), (4096, 512), (2048, 1)] {
            simulate(2_000, window, hop, true);
        }
        // Without the estimator's report: a wait at every switch, as before.
        let (est, comp, most_held) = simulate(30_000, 25_600, 12_800, false);
        assert_eq!((est, comp, most_held), (15_000, 14_999, 2));
    }

    #[test]
    fn anything_irregular_in_the_vibration_stream_counts_as_a_completed_window() {
        let synced = |k: u64| {
            let mut g = Gate::default();
            g.before_vib(vib(k));
            g.before_accel();
            g.estimator_synced(10_000, 12_800);
            g
        };
        // Contiguous: within the budget, no wait.
        let mut g = synced(0);
        assert!(!g.before_vib(vib(1)));
        assert!(!g.before_accel());
        type Edit = fn(&mut VibHead);
        let cases: [(&str, Edit); 6] = [
            ("sequence jump", |b| b.seq += 1),
            ("sample index jump", |b| b.first_sample_index += 512),
            ("time gap of one period", |b| b.t0_ns += 39_062),
            ("time 513 ns off", |b| b.t0_ns += 513),
            ("rate change", |b| b.sample_period_ns = 78_125),
            ("flagged", |b| b.flags = vibro_msgs::vib_flags::GAP_BEFORE),
        ];
        for (what, edit) in cases {
            let mut g = synced(0);
            let mut b = vib(1);
            edit(&mut b);
            // An accelerometer block is pending: the compensator must take it first,
            // and the estimator must be waited for before the next one.
            assert!(g.before_vib(b), "{what}");
            g.compensator_synced();
            assert!(g.before_accel(), "{what}");
        }
        // 256 ns of integer-period rounding is not a gap.
        let mut g = synced(0);
        let mut b = vib(1);
        b.t0_ns -= 256;
        assert!(!g.before_vib(b));
        // The budget: the block that reaches it may complete the window.
        let mut g = synced(0);
        g.before_accel();
        for k in 1..=19 {
            assert!(!g.before_vib(vib(k)), "block {k}: 512 * {k} < 10,000");
        }
        assert!(g.before_vib(vib(20)), "512 * 20 >= 10,000");
    }
}
