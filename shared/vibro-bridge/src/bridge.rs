//! The running bridge: one thread drains the exported iceoryx2 streams into Zenoh
//! publishers, another publishes what the Zenoh subscribers queued into iceoryx2.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::Duration;

use iceoryx2::prelude::CallbackProgression;
use tracing::{debug, info, warn};
use vibro_ipc::{create_node, create_waitset, StreamPublisher, StreamSubscriber};
use vibro_msgs::{
    AccelBlock, Arrival, CompensatedBlock, Heartbeat, LogLine, MessageKind, SeqTally, ServiceNames,
    Stream, TruthBlock, VibBlock, VibEstimate, WireMessage,
};
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

use crate::config::{BridgeConfig, Congestion};
use crate::{Error, Result};

/// How often the loops look at the stop flag when nothing arrives.
const STOP_POLL: Duration = Duration::from_millis(50);

/// Counters of one bridged stream, shared by the Zenoh callbacks and the loops.
#[derive(Debug, Default)]
pub struct StreamStats {
    /// Messages taken from one side and handed to the other.
    pub forwarded: AtomicU64,
    /// Export: messages sent while no remote subscriber was matched (nobody got them).
    pub unmatched: AtomicU64,
    /// Import: messages missing by the producer's sequence numbers that this bridge
    /// did not drop itself (lost on the network or on the remote side), by the
    /// services' rule (`vibro_msgs::continuity`), net of what a resync took back
    /// ([`Self::retracted`]): it can decrease.
    pub gap_messages: AtomicU64,
    /// Import: messages the rule puts out of order (a repeat, or behind the stream):
    /// forwarded all the same (the service behind decides).
    pub out_of_order: AtomicU64,
    /// Import: times the producer's `seq` restarted from 0.
    pub producer_restarts: AtomicU64,
    /// Import: forward steps of `seq` too big to be losses (more than
    /// [`vibro_service::MAX_LOST_MESSAGES`] skipped, the services' rule): a corrupt,
    /// crafted or renumbered counter, counted here and never in `gap_messages`.
    pub seq_jumps: AtomicU64,
    /// Import: times the stream was taken up again after out-of-order messages (the
    /// services' resync).
    pub resyncs: AtomicU64,
    /// Import: messages counted lost (in `gap_messages` or `superseded`, or matched
    /// with this bridge's drops) and taken back at a resync: what a `seq` ahead of the
    /// stream had counted (a forged 500,000 after 10: 499,989).
    pub retracted: AtomicU64,
    /// Import: messages dropped because the queue to iceoryx2 was full.
    pub queue_dropped: AtomicU64,
    /// Messages refused: another type name, size or invalid counts.
    pub refused: AtomicU64,
    /// Import: messages iceoryx2 could not deliver to a subscriber (back-pressure
    /// timeout); export: Zenoh put errors.
    pub undelivered: AtomicU64,
    /// A state stream's messages (a heartbeat: the service's whole state, its
    /// counters cumulative) replaced by a newer one before they were sent (export,
    /// nobody matched yet) or missing by `seq` (import): not lost, the newer one says
    /// all they said ([`is_state`]).
    pub superseded: AtomicU64,
}

/// A stream whose every message carries its producer's whole state, so that only the
/// newest one matters: heartbeats (docs/bridge.md, "How a loss shows").
pub fn is_state(stream: Stream) -> bool {
    matches!(stream, Stream::Heartbeat(_))
}

impl StreamStats {
    fn add(c: &AtomicU64, n: u64) {
        c.fetch_add(n, Ordering::Relaxed);
    }
    fn get(c: &AtomicU64) -> u64 {
        c.load(Ordering::Relaxed)
    }
    fn set(c: &AtomicU64, n: u64) {
        c.store(n, Ordering::Relaxed);
    }
    fn sub(c: &AtomicU64, n: u64) {
        let _ = c.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| {
            Some(v.saturating_sub(n))
        });
    }
}

/// Which way a stream goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// iceoryx2 → Zenoh.
    Export,
    /// Zenoh → iceoryx2.
    Import,
}

/// One stream's counters at the end of a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StreamReport {
    pub stream: String,
    pub direction: Direction,
    pub key: String,
    pub forwarded: u64,
    pub unmatched: u64,
    pub gap_messages: u64,
    pub out_of_order: u64,
    pub producer_restarts: u64,
    pub seq_jumps: u64,
    pub resyncs: u64,
    pub retracted: u64,
    pub queue_dropped: u64,
    pub refused: u64,
    pub undelivered: u64,
    pub superseded: u64,
}

impl StreamReport {
    /// Messages this stream lost or refused, whatever the cause (a `seq` jump is none:
    /// what it skipped is unknown; a superseded state message is none: a newer one
    /// carries all it said).
    pub fn lost(&self) -> u64 {
        [
            self.unmatched,
            self.gap_messages,
            self.queue_dropped,
            self.refused,
            self.undelivered,
        ]
        .into_iter()
        .fold(0, u64::saturating_add)
    }
}

/// What a bridge did, for `--json`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BridgeSummary {
    pub zenoh_id: String,
    pub streams: Vec<StreamReport>,
}

impl BridgeSummary {
    /// Every stream's losses.
    pub fn lost(&self) -> u64 {
        self.streams
            .iter()
            .map(StreamReport::lost)
            .fold(0, u64::saturating_add)
    }

    /// One JSON object: `{"zenoh_id", "lost", "streams": [{...}]}`.
    pub fn to_json(&self) -> String {
        let mut s = format!(
            "{{\"zenoh_id\":\"{}\",\"lost\":{},\"streams\":[",
            self.zenoh_id,
            self.lost()
        );
        for (i, r) in self.streams.iter().enumerate() {
            if i > 0 {
                s.push(',');
            }
            let _ = write!(
                s,
                "{{\"stream\":\"{}\",\"direction\":\"{}\",\"key\":\"{}\",\"forwarded\":{},\"unmatched\":{},\"gap_messages\":{},\"out_of_order\":{},\"producer_restarts\":{},\"seq_jumps\":{},\"resyncs\":{},\"retracted\":{},\"queue_dropped\":{},\"refused\":{},\"undelivered\":{},\"superseded\":{},\"lost\":{}}}",
                r.stream,
                match r.direction {
                    Direction::Export => "export",
                    Direction::Import => "import",
                },
                r.key,
                r.forwarded,
                r.unmatched,
                r.gap_messages,
                r.out_of_order,
                r.producer_restarts,
                r.seq_jumps,
                r.resyncs,
                r.retracted,
                r.queue_dropped,
                r.refused,
                r.undelivered,
                r.superseded,
                r.lost()
            );
        }
        s.push_str("]}");
        s
    }
}

/// Makes sure that the directory of every `unixsock-stream/` endpoint is this user's
/// alone (creating it if missing, [`crate::socket`]); every problem at once, each with
/// its key, endpoint and rule.
pub fn secure_sockets(config: &BridgeConfig) -> Result<()> {
    let mut problems = Vec::new();
    for (key, path) in config.sockets() {
        let Some(dir) = path.parent() else { continue };
        if let Err(why) = crate::socket::secure_dir(dir) {
            // (Checked when the file was loaded; this is the directory now.)
            problems.push(format!(
                "{key} = \"{}/{}\": {why}",
                crate::config::UNIXSOCK,
                path.display()
            ));
        }
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(vibro_service::ConfigError::new(config.source.clone(), problems).into())
    }
}

/// The Zenoh session of `config`: fails after `connect_timeout` when a `connect`
/// endpoint cannot be reached, naming the endpoints and the file. The directories of
/// its Unix sockets are checked first ([`secure_sockets`]).
pub fn open_session(config: &BridgeConfig) -> Result<Session> {
    secure_sockets(config)?;
    let json5 = config.zenoh_json5();
    let zc = zenoh::Config::from_json5(&json5).map_err(|e| Error::ZenohConfig {
        file: config.source.clone(),
        reason: e.to_string(),
    })?;
    zenoh::open(zc).wait().map_err(|e| Error::Open {
        file: config.source.clone(),
        listen: config.listen.join(", "),
        connect: config.connect.join(", "),
        timeout_s: config.connect_timeout.as_secs_f64(),
        reason: e.to_string(),
    })
}

/// Runs the bridge until `stop` is set: returns the counters of every stream.
///
/// Opens the Zenoh session first (a peer that cannot be reached is an error before
/// any iceoryx2 port opens), then one thread per direction.
pub fn run(config: &BridgeConfig, stop: &AtomicBool) -> Result<BridgeSummary> {
    let session = open_session(config)?;
    let result = run_on(config, &session, stop);
    if let Err(e) = session.close().wait() {
        debug!("closing the Zenoh session: {e}");
    }
    result
}

/// [`run`] on an open session.
pub fn run_on(
    config: &BridgeConfig,
    session: &Session,
    stop: &AtomicBool,
) -> Result<BridgeSummary> {
    let zid = session.zid().to_string();
    let export_stats: Vec<Arc<StreamStats>> =
        config.export.iter().map(|_| Arc::default()).collect();
    let import_stats: Vec<Arc<StreamStats>> =
        config.import.iter().map(|_| Arc::default()).collect();
    info!(
        prefix = config.names.prefix(),
        key_prefix = %config.key_prefix,
        listen = ?config.listen,
        connect = ?config.connect,
        export = ?config.export.iter().map(|s| s.suffix()).collect::<Vec<_>>(),
        import = ?config.import.iter().map(|s| s.suffix()).collect::<Vec<_>>(),
        zenoh_id = %zid,
        "bridge running"
    );
    let failed = AtomicBool::new(false);
    let stopping = || stop.load(Ordering::Acquire) || failed.load(Ordering::Acquire);
    let (export_result, import_result) = std::thread::scope(|scope| {
        let export = (!config.export.is_empty()).then(|| {
            std::thread::Builder::new()
                .name("bridge-export".into())
                .spawn_scoped(scope, || {
                    let r = export_loop(config, session, &export_stats, &stopping);
                    if r.is_err() {
                        failed.store(true, Ordering::Release);
                    }
                    r
                })
        });
        let import = (!config.import.is_empty()).then(|| {
            std::thread::Builder::new()
                .name("bridge-import".into())
                .spawn_scoped(scope, || {
                    let r = import_loop(config, session, &import_stats, &stopping);
                    if r.is_err() {
                        failed.store(true, Ordering::Release);
                    }
                    r
                })
        });
        let join =
            |h: Option<std::io::Result<std::thread::ScopedJoinHandle<'_, Result<()>>>>| match h {
                None => Ok(()),
                Some(Err(e)) => {
                    failed.store(true, Ordering::Release);
                    Err(Error::Thread(e.to_string()))
                }
                Some(Ok(h)) => h
                    .join()
                    .unwrap_or_else(|_| Err(Error::Thread("a bridge thread panicked".into()))),
            };
        (join(export), join(import))
    });
    export_result?;
    import_result?;
    let report = |s: &Stream, st: &StreamStats, direction| StreamReport {
        stream: s.suffix(),
        direction,
        key: config.key(*s),
        forwarded: StreamStats::get(&st.forwarded),
        unmatched: StreamStats::get(&st.unmatched),
        gap_messages: StreamStats::get(&st.gap_messages),
        out_of_order: StreamStats::get(&st.out_of_order),
        producer_restarts: StreamStats::get(&st.producer_restarts),
        seq_jumps: StreamStats::get(&st.seq_jumps),
        resyncs: StreamStats::get(&st.resyncs),
        retracted: StreamStats::get(&st.retracted),
        queue_dropped: StreamStats::get(&st.queue_dropped),
        refused: StreamStats::get(&st.refused),
        undelivered: StreamStats::get(&st.undelivered),
        superseded: StreamStats::get(&st.superseded),
    };
    let mut streams: Vec<StreamReport> = config
        .export
        .iter()
        .zip(&export_stats)
        .map(|(s, st)| report(s, st, Direction::Export))
        .collect();
    streams.extend(
        config
            .import
            .iter()
            .zip(&import_stats)
            .map(|(s, st)| report(s, st, Direction::Import)),
    );
    let summary = BridgeSummary {
        zenoh_id: zid,
        streams,
    };
    info!(lost = summary.lost(), "bridge stopped");
    Ok(summary)
}

/// The encoding every bridged message carries: raw bytes, with the iceoryx2 type name
/// (`vibrocomp::AccelBlock::v5`) as its schema.
pub fn encoding_of(kind: MessageKind) -> Encoding {
    Encoding::APPLICATION_OCTET_STREAM.with_schema(kind.type_name())
}

/// Runs `$body` with `$t` the wire type of `$kind`.
macro_rules! with_type {
    ($kind:expr, $t:ident => $body:expr) => {
        match $kind {
            MessageKind::AccelBlock => {
                type $t = AccelBlock;
                $body
            }
            MessageKind::VibBlock => {
                type $t = VibBlock;
                $body
            }
            MessageKind::VibEstimate => {
                type $t = VibEstimate;
                $body
            }
            MessageKind::CompensatedBlock => {
                type $t = CompensatedBlock;
                $body
            }
            MessageKind::TruthBlock => {
                type $t = TruthBlock;
                $body
            }
            MessageKind::Heartbeat => {
                type $t = Heartbeat;
                $body
            }
            MessageKind::LogLine => {
                type $t = LogLine;
                $body
            }
        }
    };
}

trait ExportPort {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<vibro_ipc::Ipc>;
    fn clear_events(&self);
    /// A held stream: takes what is there now (at most [`HOLD_MAX`]), sent by the next
    /// [`Self::drain`]. Returns whether it stopped at the bound (more may wait).
    fn hold(&self) -> Result<bool>;
    fn drain(&self) -> Result<usize>;
    /// At stop: what is still pending never reached anybody.
    fn finish(&self);
}

/// Most messages of a stream held through one pass (a stream's subscriber buffer).
const HOLD_MAX: usize = 256;

/// Passes at most at stop, for what the producers published before it.
const STOP_PASSES: usize = 4;

/// Where an exported stream goes in each pass of the exporting bridge. The streams
/// are taken in the reverse of this order and sent in this order, so that a message
/// is sent after every message of an earlier rank published before it (it was taken
/// before them, and they are sent first). Each stream keeps its own order; the other
/// way round (a later rank's message published before an earlier rank's) the order
/// is not kept, and need not be:
///
/// - [`Rank::Samples`]: the sensors' samples (`vib`). Samples may reach the
///   compensator's waveform stage ahead of the readings they cover, never behind: a
///   reading that arrives before the samples published ahead of it waits for them,
///   and an accelerometer block one sensor block past a held reading gives that
///   reading up (`vibro_compensator::waveform`, "late"). One host's iceoryx2 keeps
///   publish order; a bridge must too, or the compensator's answer depends on the
///   network (a lock-stepped replay across two hosts would differ from one host's).
/// - [`Rank::Data`]: every other stream. Held (taken before the samples) only when
///   the bridge exports samples too; otherwise taken and sent at once.
/// - [`Rank::Progress`]: a progress stream says "everything I published before this is
///   out": taken first and sent last, so that on the other side none overtakes an
///   output it reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Rank {
    Samples,
    Data,
    Progress,
}

impl Rank {
    fn of(stream: Stream) -> Self {
        match stream {
            Stream::Vib => Self::Samples,
            Stream::Progress(_) => Self::Progress,
            _ => Self::Data,
        }
    }
}

struct Exporter<T: WireMessage> {
    sub: StreamSubscriber<T>,
    /// Taken first in a pass and sent by the next drain ([`Rank`]).
    held_stream: bool,
    /// Copies (a subscriber may borrow only 2 samples from shared memory at a time).
    held: std::cell::RefCell<Vec<T>>,
    /// A stream with a history for late subscribers (`estimate` 1, `log/*` 32,
    /// `vibro_ipc::stream_config`; a state stream 1): the last that many messages
    /// taken while nobody on the other side was matched, sent when somebody is (as
    /// iceoryx2 would to a late subscriber); older ones are counted `unmatched`, or
    /// `superseded` on a state stream.
    history: usize,
    /// [`is_state`].
    state: bool,
    pending: std::cell::RefCell<std::collections::VecDeque<T>>,
    publisher: zenoh::pubsub::Publisher<'static>,
    matched: Arc<AtomicBool>,
    stats: Arc<StreamStats>,
    key: String,
    put_errors_logged: std::cell::Cell<bool>,
}

impl<T: WireMessage> Exporter<T> {
    /// The exporter of `stream` by `config`; `with_samples`: the bridge exports the
    /// sensors' samples too ([`Rank`]).
    fn open(
        node: &vibro_ipc::IpcNode,
        config: &BridgeConfig,
        stream: Stream,
        session: &Session,
        stats: Arc<StreamStats>,
        with_samples: bool,
    ) -> Result<Self> {
        let key = config.key(stream);
        let sub = StreamSubscriber::<T>::open(node, &config.names, stream)?;
        let cc = match config.congestion {
            Congestion::Block => CongestionControl::Block,
            Congestion::Drop => CongestionControl::Drop,
        };
        let publisher = session
            .declare_publisher(key.clone())
            .encoding(encoding_of(T::KIND))
            .congestion_control(cc)
            // Each message goes out at once instead of waiting for a batch to fill
            // (Zenoh's batching holds a message up to 1 ms): a block is due within
            // one sample period.
            .express(true)
            .wait()
            .map_err(|e| Error::Zenoh {
                operation: "declare publisher",
                key: key.clone(),
                reason: e.to_string(),
            })?;
        let matched = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&matched);
        publisher
            .matching_listener()
            .callback(move |status| flag.store(status.matching(), Ordering::Release))
            .background()
            .wait()
            .map_err(|e| Error::Zenoh {
                operation: "declare matching listener",
                key: key.clone(),
                reason: e.to_string(),
            })?;
        let rank = Rank::of(stream);
        let held_stream = match rank {
            Rank::Samples => false,
            Rank::Data => with_samples,
            Rank::Progress => true,
        };
        let state = is_state(stream);
        // A heartbeat taken before the other side's bridge came up (its host started
        // later) waits for it instead of being lost: the newest one, sent on matching.
        let history = if state {
            1
        } else {
            vibro_ipc::stream_config(stream).history
        };
        Ok(Self {
            sub,
            held_stream,
            history,
            state,
            pending: std::cell::RefCell::new(std::collections::VecDeque::with_capacity(history)),
            held: std::cell::RefCell::new(Vec::with_capacity(if held_stream {
                HOLD_MAX
            } else {
                0
            })),
            publisher,
            matched,
            stats,
            key,
            put_errors_logged: std::cell::Cell::new(false),
        })
    }
}

impl<T: WireMessage> ExportPort for Exporter<T> {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<vibro_ipc::Ipc> {
        self.sub.listener()
    }

    fn clear_events(&self) {
        if let Err(e) = self.sub.clear_events() {
            debug!("{e}");
        }
    }

    fn finish(&self) {
        let n = self.pending.borrow().len() as u64;
        StreamStats::add(&self.stats.unmatched, n);
    }

    fn hold(&self) -> Result<bool> {
        if !self.held_stream {
            return Ok(false);
        }
        let mut held = self.held.borrow_mut();
        while held.len() < HOLD_MAX {
            match self.sub.receive()? {
                Some(s) => held.push(*s),
                None => return Ok(false),
            }
        }
        Ok(true)
    }

    fn drain(&self) -> Result<usize> {
        if self.history > 0 && self.matched.load(Ordering::Acquire) {
            let mut pending = self.pending.borrow_mut();
            while let Some(m) = pending.pop_front() {
                self.send(m.bytes());
            }
        }
        if self.held_stream {
            let mut held = self.held.borrow_mut();
            let n = held.len();
            for m in held.iter() {
                self.take(m);
            }
            held.clear();
            return Ok(n);
        }
        let mut n = 0;
        while let Some(sample) = self.sub.receive()? {
            n += 1;
            self.take(&sample);
        }
        Ok(n)
    }
}

impl<T: WireMessage> Exporter<T> {
    /// One message taken from iceoryx2: sent, or kept for a late peer (`history`).
    fn take(&self, m: &T) {
        if self.history > 0 && !self.matched.load(Ordering::Acquire) {
            let mut pending = self.pending.borrow_mut();
            if pending.len() == self.history {
                pending.pop_front();
                StreamStats::add(
                    if self.state {
                        &self.stats.superseded
                    } else {
                        &self.stats.unmatched
                    },
                    1,
                );
            }
            pending.push_back(*m);
            return;
        }
        self.send(m.bytes());
    }

    fn send(&self, bytes: &[u8]) {
        if !self.matched.load(Ordering::Acquire) {
            // Nobody on the other side: the message is lost, and counted here (the
            // receiving side sees the gap in `seq` when it comes back).
            StreamStats::add(&self.stats.unmatched, 1);
            return;
        }
        // Zenoh owns what it sends: one copy of the wire bytes per message.
        match self.publisher.put(bytes).wait() {
            Ok(()) => StreamStats::add(&self.stats.forwarded, 1),
            Err(e) => {
                StreamStats::add(&self.stats.undelivered, 1);
                if !self.put_errors_logged.replace(true) {
                    warn!(key = %self.key, "Zenoh put failed (further failures counted): {e}");
                }
            }
        }
    }
}

fn export_loop(
    config: &BridgeConfig,
    session: &Session,
    stats: &[Arc<StreamStats>],
    stopping: &dyn Fn() -> bool,
) -> Result<()> {
    let node = create_node("vibrocomp-bridge-out")?;
    // A bridge killed before this one (restarted by `vibrocomp up`) left its ports.
    vibro_ipc::cleanup_dead_nodes(&node);
    let with_samples = config.export.iter().any(|s| Rank::of(*s) == Rank::Samples);
    // In send order ([`Rank`]); taken in the reverse.
    let mut streams = config.export.iter().zip(stats).collect::<Vec<_>>();
    streams.sort_by_key(|(s, _)| Rank::of(**s));
    let mut ports: Vec<Box<dyn ExportPort>> = Vec::with_capacity(streams.len());
    for &(stream, st) in &streams {
        let port: Box<dyn ExportPort> = with_type!(stream.kind(), T => Box::new(Exporter::<T>::open(
            &node,
            config,
            *stream,
            session,
            Arc::clone(st),
            with_samples,
        )?));
        ports.push(port);
    }
    let waitset = create_waitset()?;
    let mut guards = Vec::with_capacity(ports.len());
    for (p, (s, _)) in ports.iter().zip(&streams) {
        guards.push(waitset.attach_notification(p.listener()).map_err(|e| {
            vibro_ipc::Error::Iceoryx {
                operation: "attach to the wait set",
                service: config.names.event(**s),
                reason: format!("{e:?}"),
            }
        })?);
    }
    // One pass: the held streams taken (the last rank first), then every stream sent
    // in rank order. Whether a held stream stopped at its bound (more is waiting).
    let pass = |ports: &[Box<dyn ExportPort>]| -> Result<bool> {
        let mut more = false;
        for p in ports.iter().rev() {
            more |= p.hold()?;
        }
        for p in ports {
            p.drain()?;
        }
        Ok(more)
    };
    let mut more = false;
    while !stopping() {
        if !more {
            waitset
                .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, STOP_POLL)
                .map_err(|e| vibro_ipc::Error::Iceoryx {
                    operation: "wait",
                    service: "bridge wait set".into(),
                    reason: format!("{e:?}"),
                })?;
        }
        for p in &ports {
            p.clear_events();
        }
        more = pass(&ports)?;
    }
    drop(guards);
    // What the producers published before the stop and this loop has not taken yet:
    // sent (or counted), never dropped silently (a subscriber's buffer is a few
    // holds' worth; a producer still publishing cannot keep the bridge from stopping).
    for _ in 0..STOP_PASSES {
        if !pass(&ports)? {
            break;
        }
    }
    for p in &ports {
        p.finish();
    }
    Ok(())
}

trait ImportPort {
    fn forward(&mut self, sample: &Sample);
}

/// The import side's count of one stream's `seq`, by the services' rule
/// (`vibro_msgs::continuity`, through [`SeqTally`]): a gap is a loss up to
/// [`vibro_service::MAX_LOST_MESSAGES`], a bigger step a jump, and a loss counted at a
/// message ahead of the stream (a forged `seq`) is taken back when the stream resumes.
/// Every message is forwarded whatever it says: the service behind applies the rule
/// again and drops what it must.
#[derive(Debug, Clone, Default)]
struct SeqCount {
    tally: SeqTally,
    /// Messages this stream counted lost (into `gap_messages` or `superseded`), net.
    counted: u64,
    /// Of this bridge's own queue drops, those matched with a gap (counted there,
    /// not as lost on the network).
    drops_seen: u64,
}

/// What one arrival changes in a stream's loss counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Counted {
    arrival: Arrival,
    /// Messages newly counted lost (those that this bridge's drops do not explain).
    lost: u64,
    /// Messages counted lost before and taken back now.
    taken_back: u64,
}

impl SeqCount {
    /// The arrival of `seq`; `dropped_here`: this bridge's queue drops of the stream so
    /// far.
    fn arrive(&mut self, seq: u64, dropped_here: u64) -> Counted {
        let arrival = self.tally.seq(seq);
        let taken_back = arrival.retracted_messages.min(self.counted);
        self.counted -= taken_back;
        // What was taken back beyond that was matched with drops: they are free to
        // explain a later gap.
        self.drops_seen = self
            .drops_seen
            .saturating_sub(arrival.retracted_messages - taken_back);
        let explained = arrival
            .lost_messages
            .min(dropped_here.saturating_sub(self.drops_seen));
        self.drops_seen += explained;
        let lost = arrival.lost_messages - explained;
        self.counted = self.counted.saturating_add(lost);
        Counted {
            arrival,
            lost,
            taken_back,
        }
    }
}

struct Importer<T: WireMessage> {
    publisher: StreamPublisher<T>,
    stats: Arc<StreamStats>,
    key: String,
    schema: &'static str,
    encoding: Encoding,
    /// The wire bytes of one message, gathered from Zenoh's slices (allocated once).
    scratch: Vec<u8>,
    seq: SeqCount,
    /// [`is_state`].
    state: bool,
    refused_logged: bool,
    gap_logged: bool,
    jump_logged: bool,
}

impl<T: WireMessage> Importer<T> {
    fn open(
        node: &vibro_ipc::IpcNode,
        names: &ServiceNames,
        stream: Stream,
        key: String,
        stats: Arc<StreamStats>,
    ) -> Result<Self> {
        Ok(Self {
            publisher: StreamPublisher::<T>::open(node, names, stream)?,
            stats,
            key,
            schema: T::KIND.type_name(),
            encoding: encoding_of(T::KIND),
            scratch: Vec::with_capacity(T::KIND.size_bytes()),
            seq: SeqCount::default(),
            state: is_state(stream),
            refused_logged: false,
            gap_logged: false,
            jump_logged: false,
        })
    }

    fn refuse(&mut self, why: std::fmt::Arguments<'_>) {
        StreamStats::add(&self.stats.refused, 1);
        if !self.refused_logged {
            self.refused_logged = true;
            warn!(key = %self.key, "message refused (further refusals counted): {why}");
        }
    }
}

impl<T: WireMessage> ImportPort for Importer<T> {
    fn forward(&mut self, sample: &Sample) {
        if sample.encoding() != &self.encoding {
            let found = sample.encoding();
            let wanted = self.encoding.clone();
            self.refuse(format_args!(
                "encoding {found}, but this side carries {wanted} (docs/messages.md, \"Type names and versions\")"
            ));
            return;
        }
        self.scratch.clear();
        for slice in sample.payload().slices() {
            self.scratch.extend_from_slice(slice);
        }
        let Some(msg) = T::from_wire_bytes(&self.scratch) else {
            let (len, schema) = (self.scratch.len(), self.schema);
            self.refuse(format_args!(
                "{len} bytes, but {schema} is {} bytes",
                T::KIND.size_bytes()
            ));
            return;
        };
        if let Err(e) = msg.validate() {
            self.refuse(format_args!("{e}"));
            return;
        }
        let seq = msg.seq();
        let dropped_here = StreamStats::get(&self.stats.queue_dropped);
        let Counted {
            arrival: a,
            lost,
            taken_back,
        } = self.seq.arrive(seq, dropped_here);
        // Heartbeats the other side replaced before sending, or lost on the way: a
        // newer one says all they said.
        let lost_counter = if self.state {
            &self.stats.superseded
        } else {
            &self.stats.gap_messages
        };
        StreamStats::sub(lost_counter, taken_back);
        StreamStats::add(lost_counter, lost);
        if lost > 0 && !self.state && !self.gap_logged {
            self.gap_logged = true;
            warn!(key = %self.key, missing = a.lost_messages, got = seq, "messages lost on the network (further gaps counted)");
        }
        if a.seq_jump && !self.jump_logged {
            self.jump_logged = true;
            warn!(key = %self.key, got = seq, "seq jumped too far to be a loss (more than {} messages): counted as a jump, not as lost (further jumps counted)", vibro_service::MAX_LOST_MESSAGES);
        }
        // The rule's other counters, this stream's totals (only this thread writes them).
        let t = &self.seq.tally.totals;
        StreamStats::set(&self.stats.out_of_order, t.out_of_order);
        StreamStats::set(&self.stats.producer_restarts, t.restarts);
        StreamStats::set(&self.stats.seq_jumps, t.seq_jumps);
        StreamStats::set(&self.stats.resyncs, t.resyncs);
        StreamStats::set(&self.stats.retracted, self.seq.tally.retracted);
        match self.publisher.publish(&msg) {
            Ok(_) => StreamStats::add(&self.stats.forwarded, 1),
            Err(vibro_ipc::Error::Undelivered { .. }) => {
                StreamStats::add(&self.stats.forwarded, 1);
                StreamStats::add(&self.stats.undelivered, 1);
            }
            Err(e) => {
                StreamStats::add(&self.stats.undelivered, 1);
                debug!(key = %self.key, "{e}");
            }
        }
    }
}

/// A received sample and the index of its import stream.
type Queued = (usize, Sample);

fn import_loop(
    config: &BridgeConfig,
    session: &Session,
    stats: &[Arc<StreamStats>],
    stopping: &dyn Fn() -> bool,
) -> Result<()> {
    let node = create_node("vibrocomp-bridge-in")?;
    vibro_ipc::cleanup_dead_nodes(&node);
    let mut ports: Vec<Box<dyn ImportPort>> = Vec::with_capacity(config.import.len());
    for (stream, st) in config.import.iter().zip(stats) {
        let key = config.key(*stream);
        let port: Box<dyn ImportPort> = with_type!(stream.kind(), T => Box::new(
            Importer::<T>::open(&node, &config.names, *stream, key, Arc::clone(st))?
        ));
        ports.push(port);
    }
    // One bounded queue between Zenoh's receive tasks and this thread: a full queue
    // drops the newest message and counts it (the publisher's `seq` shows the gap
    // downstream too).
    let (tx, rx): (SyncSender<Queued>, Receiver<Queued>) = sync_channel(config.queue_depth);
    let mut subscribers = Vec::with_capacity(config.import.len());
    for (i, (stream, st)) in config.import.iter().zip(stats).enumerate() {
        let key = config.key(*stream);
        let (tx, st) = (tx.clone(), Arc::clone(st));
        let sub = session
            .declare_subscriber(key.clone())
            .callback(move |sample| match tx.try_send((i, sample)) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) => StreamStats::add(&st.queue_dropped, 1),
                Err(TrySendError::Disconnected(_)) => {}
            })
            .wait()
            .map_err(|e| Error::Zenoh {
                operation: "declare subscriber",
                key,
                reason: e.to_string(),
            })?;
        subscribers.push(sub);
    }
    drop(tx);
    while !stopping() {
        match rx.recv_timeout(STOP_POLL) {
            Ok((i, sample)) => {
                if let Some(p) = ports.get_mut(i) {
                    p.forward(&sample);
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    for s in subscribers {
        if let Err(e) = s.undeclare().wait() {
            debug!("undeclaring a subscriber: {e}");
        }
    }
    // What Zenoh handed over before the stop: forwarded, never dropped silently.
    while let Ok((i, sample)) = rx.try_recv() {
        if let Some(p) = ports.get_mut(i) {
            p.forward(&sample);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_service::MAX_LOST_MESSAGES as MAX;

    /// The totals of `seqs` through one stream's count (no queue drops): (gap
    /// messages net, out of order, restarts, jumps, resyncs, taken back).
    fn counts(seqs: &[u64]) -> (u64, u64, u64, u64, u64, u64) {
        let mut c = SeqCount::default();
        let (mut lost, mut back) = (0u64, 0u64);
        for &s in seqs {
            let k = c.arrive(s, 0);
            lost += k.lost;
            back += k.taken_back;
        }
        let t = c.tally.totals;
        assert_eq!(lost - back, c.counted);
        (
            c.counted,
            t.out_of_order,
            t.restarts,
            t.seq_jumps,
            t.resyncs,
            back,
        )
    }

    /// The sequence of the integration test (a crafted peer): a gap of 2, one of
    /// exactly 2^20 (the limit, inclusive), a step of 2^20 + 2 and one to 0xF000...
    #[test]
    fn gaps_count_up_to_the_services_limit_and_bigger_steps_are_jumps() {
        let s1 = 5 + MAX + 1;
        let s2 = s1 + MAX + 2;
        let s3 = 0xF000_0000_0000_0000u64;
        assert_eq!(
            counts(&[0, 1, 2, 5, s1, s2, s2 + 1, s3, s3 + 1]),
            (2 + MAX, 0, 0, 2, 0, 0)
        );
        // Late, repeated and restarted; a jump to u64::MAX, and 0 again.
        assert_eq!(
            counts(&[10, 12, 11, 12, 13, 0, 1, u64::MAX, 0]),
            (1, 2, 2, 1, 0, 0)
        );
    }

    /// Issue 46, item 6: seq 0..=10, a forged 500,000, then 11..=60. The bridge counted
    /// 499,989 messages lost on the network; by the services' rule they are taken back
    /// when the stream resumes (one resync, 11..=13 out of order: forwarded all the
    /// same).
    #[test]
    fn a_forged_seq_ahead_is_taken_back_when_the_stream_resumes() {
        let seqs: Vec<u64> = (0..=10).chain([500_000]).chain(11..=60).collect();
        assert_eq!(counts(&seqs), (0, 3, 0, 0, 1, 499_989));
        // This bridge's queue dropped the real 11..=15 (5 drops), then the forged one
        // came: its gap matched the 5 drops, the other 499,984 counted lost. When the
        // stream resumes (16..=18 out of order, 19 resyncs), all of it is taken back and
        // the 5 drops explain the 5 the stream really misses: nothing lost on the
        // network. A later gap (70 -> 77) is lost on the network: 6.
        let mut c = SeqCount::default();
        for s in (0..=10).chain([500_000]).chain(16..=70).chain([77]) {
            let dropped_here = if s > 10 { 5 } else { 0 };
            c.arrive(s, dropped_here);
            if s == 19 {
                assert_eq!((c.counted, c.tally.totals.lost_messages), (0, 5), "{c:?}");
            }
        }
        assert_eq!((c.counted, c.tally.retracted), (6, 499_989), "{c:?}");
    }

    /// A xorshift64 generator: the random `seq`s of a crafted peer, reproducibly.
    fn xorshift(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    /// Random `seq`s: what counts as lost stays below MAX per message (here none: two
    /// random u64 fall within 2^20 of each other with probability 2^-43), every forward
    /// step is a jump, and nothing overflows in the totals.
    #[test]
    fn random_seqs_are_jumps_and_the_totals_stay_bounded() {
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let n = 10_000u64;
        let seqs: Vec<u64> = (0..n).map(|_| xorshift(&mut rng)).collect();
        let (lost, late, restarts, jumps, resyncs, back) = counts(&seqs);
        assert_eq!((lost, restarts, resyncs, back), (0, 0, 0, 0));
        assert_eq!(jumps + late + 1, n, "{jumps} jumps, {late} late");
        assert!(jumps > 0);
    }

    /// The summary's sums saturate instead of overflowing (a debug build panicked on
    /// them with counters near u64::MAX).
    #[test]
    fn the_loss_totals_saturate() {
        let r = StreamReport {
            stream: "accel".into(),
            direction: Direction::Import,
            key: "k/accel".into(),
            forwarded: 0,
            unmatched: 3,
            gap_messages: u64::MAX - 1,
            out_of_order: 0,
            producer_restarts: 0,
            seq_jumps: 0,
            resyncs: 0,
            retracted: 0,
            queue_dropped: 0,
            refused: 0,
            undelivered: 0,
            superseded: 0,
        };
        assert_eq!(r.lost(), u64::MAX);
        // Superseded heartbeats are not lost.
        let replaced = StreamReport {
            unmatched: 0,
            gap_messages: 0,
            superseded: 5,
            ..r.clone()
        };
        assert_eq!(replaced.lost(), 0);
        let s = BridgeSummary {
            zenoh_id: String::new(),
            streams: vec![r.clone(), r],
        };
        assert_eq!(s.lost(), u64::MAX);
        assert!(s.to_json().contains("\"seq_jumps\":0"));
    }
}
