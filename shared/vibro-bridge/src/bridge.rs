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
    AccelBlock, CompensatedBlock, Heartbeat, LogLine, MessageKind, ServiceNames, Stream,
    TruthBlock, VibBlock, VibEstimate, WireMessage,
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
    /// did not drop itself (lost on the network or on the remote side).
    pub gap_messages: AtomicU64,
    /// Import: messages whose `seq` was below the next expected one.
    pub out_of_order: AtomicU64,
    /// Import: times the producer's `seq` restarted from 0.
    pub producer_restarts: AtomicU64,
    /// Import: forward steps of `seq` too big to be losses (more than
    /// [`vibro_service::MAX_LOST_MESSAGES`] skipped, the services' rule): a corrupt,
    /// crafted or renumbered counter, counted here and never in `gap_messages`.
    pub seq_jumps: AtomicU64,
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
                "{{\"stream\":\"{}\",\"direction\":\"{}\",\"key\":\"{}\",\"forwarded\":{},\"unmatched\":{},\"gap_messages\":{},\"out_of_order\":{},\"producer_restarts\":{},\"seq_jumps\":{},\"queue_dropped\":{},\"refused\":{},\"undelivered\":{},\"superseded\":{},\"lost\":{}}}",
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
    /// A progress stream: takes what is there now, sent by the next [`Self::drain`].
    fn hold(&self) -> Result<()>;
    fn drain(&self) -> Result<usize>;
    /// At stop: what is still pending never reached anybody.
    fn finish(&self);
}

/// Most progress messages held through one pass (a stream's subscriber buffer).
const HOLD_MAX: usize = 256;

struct Exporter<T: WireMessage> {
    sub: StreamSubscriber<T>,
    /// A progress stream says "everything I published before this is out": its
    /// messages are taken first and sent after the other streams' of the same pass,
    /// so that on the other side none overtakes an output it reports.
    deferred: bool,
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
    fn open(
        node: &vibro_ipc::IpcNode,
        names: &ServiceNames,
        stream: Stream,
        session: &Session,
        key: String,
        congestion: Congestion,
        stats: Arc<StreamStats>,
    ) -> Result<Self> {
        let sub = StreamSubscriber::<T>::open(node, names, stream)?;
        let cc = match congestion {
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
        let deferred = matches!(stream, Stream::Progress(_));
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
            deferred,
            history,
            state,
            pending: std::cell::RefCell::new(std::collections::VecDeque::with_capacity(history)),
            held: std::cell::RefCell::new(Vec::with_capacity(if deferred { HOLD_MAX } else { 0 })),
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

    fn hold(&self) -> Result<()> {
        if self.deferred {
            let mut held = self.held.borrow_mut();
            while held.len() < HOLD_MAX {
                match self.sub.receive()? {
                    Some(s) => held.push(*s),
                    None => break,
                }
            }
        }
        Ok(())
    }

    fn drain(&self) -> Result<usize> {
        if self.history > 0 && self.matched.load(Ordering::Acquire) {
            let mut pending = self.pending.borrow_mut();
            while let Some(m) = pending.pop_front() {
                self.send(m.bytes());
            }
        }
        if self.deferred {
            let mut held = self.held.borrow_mut();
            let n = held.len();
            for m in held.iter() {
                self.send(m.bytes());
            }
            held.clear();
            return Ok(n);
        }
        let mut n = 0;
        while let Some(sample) = self.sub.receive()? {
            n += 1;
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
                pending.push_back(*sample);
                continue;
            }
            self.send(sample.bytes());
        }
        Ok(n)
    }
}

impl<T: WireMessage> Exporter<T> {
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
    let mut ports: Vec<Box<dyn ExportPort>> = Vec::with_capacity(config.export.len());
    for (stream, st) in config.export.iter().zip(stats) {
        let key = config.key(*stream);
        let port: Box<dyn ExportPort> = with_type!(stream.kind(), T => Box::new(Exporter::<T>::open(
            &node,
            &config.names,
            *stream,
            session,
            key,
            config.congestion,
            Arc::clone(st),
        )?));
        ports.push(port);
    }
    let waitset = create_waitset()?;
    let mut guards = Vec::with_capacity(ports.len());
    for (p, s) in ports.iter().zip(&config.export) {
        guards.push(waitset.attach_notification(p.listener()).map_err(|e| {
            vibro_ipc::Error::Iceoryx {
                operation: "attach to the wait set",
                service: config.names.event(*s),
                reason: format!("{e:?}"),
            }
        })?);
    }
    while !stopping() {
        waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, STOP_POLL)
            .map_err(|e| vibro_ipc::Error::Iceoryx {
                operation: "wait",
                service: "bridge wait set".into(),
                reason: format!("{e:?}"),
            })?;
        for p in &ports {
            p.clear_events();
        }
        for p in &ports {
            p.hold()?;
        }
        for p in &ports {
            p.drain()?;
        }
    }
    drop(guards);
    // What the producers published before the stop and this loop has not taken yet:
    // sent (or counted), never dropped silently.
    for p in &ports {
        p.hold()?;
    }
    for p in &ports {
        p.drain()?;
    }
    for p in &ports {
        p.finish();
    }
    Ok(())
}

trait ImportPort {
    fn forward(&mut self, sample: &Sample);
}

/// What one imported message's `seq` says about its stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SeqStep {
    /// The first message, or the one expected.
    InStep,
    /// This many messages missing before it (at most
    /// [`vibro_service::MAX_LOST_MESSAGES`]).
    Gap(u64),
    /// A forward step too big to be a loss (the services' jump rule, vibro-service's
    /// `continuity` module): what follows starts a new history.
    Jump,
    /// `seq` back to 0: the producer restarted.
    Restart,
    /// Below the next expected `seq` (late, or repeated): the expectation stays.
    Late,
}

/// The import side's expectation of a stream's `seq`.
#[derive(Debug, Clone, Copy, Default)]
struct SeqCheck {
    next: Option<u64>,
}

impl SeqCheck {
    fn arrive(&mut self, seq: u64) -> SeqStep {
        let step = match self.next {
            None => SeqStep::InStep,
            Some(next) if seq > next => {
                let missing = seq - next;
                if missing > vibro_service::MAX_LOST_MESSAGES {
                    SeqStep::Jump
                } else {
                    SeqStep::Gap(missing)
                }
            }
            Some(next) if seq == next => SeqStep::InStep,
            Some(_) if seq == 0 => SeqStep::Restart,
            Some(_) => SeqStep::Late,
        };
        if step != SeqStep::Late {
            self.next = Some(seq.wrapping_add(1));
        }
        step
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
    seq: SeqCheck,
    /// [`is_state`].
    state: bool,
    /// Of `stats.queue_dropped`, the drops already matched with a gap in `seq`.
    drops_seen: u64,
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
            seq: SeqCheck::default(),
            state: is_state(stream),
            drops_seen: 0,
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
        match self.seq.arrive(seq) {
            SeqStep::InStep => {}
            SeqStep::Gap(missing) => {
                // Messages this bridge's own queue dropped are counted there already;
                // the rest of the gap was lost before they reached it.
                let dropped_here = StreamStats::get(&self.stats.queue_dropped);
                let explained = missing.min(dropped_here.saturating_sub(self.drops_seen));
                self.drops_seen += explained;
                let lost = missing - explained;
                if self.state {
                    // Heartbeats the other side replaced before sending, or lost on
                    // the way: this one says all they said.
                    StreamStats::add(&self.stats.superseded, lost);
                } else {
                    StreamStats::add(&self.stats.gap_messages, lost);
                }
                if lost > 0 && !self.state && !self.gap_logged {
                    self.gap_logged = true;
                    warn!(key = %self.key, missing, got = seq, "messages lost on the network (further gaps counted)");
                }
            }
            SeqStep::Jump => {
                StreamStats::add(&self.stats.seq_jumps, 1);
                if !self.jump_logged {
                    self.jump_logged = true;
                    warn!(key = %self.key, got = seq, "seq jumped too far to be a loss (more than {} messages): counted as a jump, not as lost (further jumps counted)", vibro_service::MAX_LOST_MESSAGES);
                }
            }
            SeqStep::Restart => StreamStats::add(&self.stats.producer_restarts, 1),
            SeqStep::Late => StreamStats::add(&self.stats.out_of_order, 1),
        }
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

    fn steps(seqs: &[u64]) -> Vec<SeqStep> {
        let mut c = SeqCheck::default();
        seqs.iter().map(|&s| c.arrive(s)).collect()
    }

    /// The sequence of the integration test (a crafted peer): a gap of 2, one of
    /// exactly 2^20 (the limit, inclusive), a step of 2^20 + 2 and one to 0xF000...
    #[test]
    fn gaps_count_up_to_the_services_limit_and_bigger_steps_are_jumps() {
        let s1 = 5 + MAX + 1;
        let s2 = s1 + MAX + 2;
        let s3 = 0xF000_0000_0000_0000u64;
        use SeqStep::*;
        assert_eq!(
            steps(&[0, 1, 2, 5, s1, s2, s2 + 1, s3, s3 + 1]),
            [
                InStep,
                InStep,
                InStep,
                Gap(2),
                Gap(MAX),
                Jump,
                InStep,
                Jump,
                InStep
            ]
        );
        // Late, repeated and restarted, as before the jump rule.
        assert_eq!(
            steps(&[10, 12, 11, 12, 13, 0, 1, u64::MAX, 0]),
            [
                InStep,
                Gap(1),
                Late,
                Late,
                InStep,
                Restart,
                InStep,
                Jump,
                InStep
            ]
        );
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
        let mut c = SeqCheck::default();
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let (mut lost, mut jumps, mut late) = (0u64, 0u64, 0u64);
        let n = 10_000u64;
        for _ in 0..n {
            match c.arrive(xorshift(&mut rng)) {
                SeqStep::Gap(k) => lost += k,
                SeqStep::Jump => jumps += 1,
                SeqStep::Late => late += 1,
                SeqStep::InStep | SeqStep::Restart => {}
            }
        }
        assert_eq!(lost, 0);
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
