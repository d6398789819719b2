//! Recording live streams into an MCAP file.

use crate::attachments::{LogExtras, RECORDING_METADATA};
use crate::timeline::{Placement, Timeline, TIMELINE_RESYNC_AFTER};
use crate::topics::topic;
use crate::{Error, Result};
use iceoryx2::prelude::CallbackProgression;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tracing::{info, warn};
use vibro_ipc::{
    cleanup_dead_nodes, create_node, create_waitset, now_ns, Ipc, StreamPublisher, StreamSubscriber,
};
use vibro_mcap::{
    Answers, ChannelId, Message, Recorder, RecorderOptions, SeqRanges, ViewChannelId,
};
use vibro_msgs::{
    AccelBlock, Arrival, CompensatedBlock, Heartbeat, LogLine, SeqTally, ServiceId, ServiceNames,
    ServiceState, Stream, TruthBlock, VibBlock, VibEstimate, WireMessage,
};
use vibro_view::{ViewBuilder, ViewMessage, UNIT_NAMES};

/// What to record and how.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    pub names: ServiceNames,
    /// Streams to record (see [`crate::DEFAULT_RECORD_STREAMS`]).
    pub streams: Vec<Stream>,
    /// Attachments (configurations, passports) and metadata records stored in the log
    /// after the recorder's own `recording` record, in order
    /// ([`crate::attachments`]).
    pub extras: LogExtras,
    pub recorder: RecorderOptions,
    /// Record the view channels beside the wire streams (docs/view.md: each unit's
    /// stages, the vibration per axis, the services' health, made to be plotted),
    /// from the streams recorded. Default on.
    pub view: bool,
    /// How often the recorder publishes its heartbeat (`{prefix}heartbeat/recorder`).
    pub heartbeat_period: Duration,
    /// Longest sleep before the stop flag is looked at.
    pub stop_poll: Duration,
    /// Replace the file if it exists (a regular file only: `vibro_files`); without it
    /// an existing file is refused. Default off.
    pub force: bool,
}

impl RecordOptions {
    pub fn new(names: ServiceNames, streams: Vec<Stream>) -> Self {
        Self {
            names,
            streams,
            extras: LogExtras::recorded(),
            recorder: RecorderOptions::default(),
            view: true,
            heartbeat_period: Duration::from_secs(1),
            stop_poll: Duration::from_millis(100),
            force: false,
        }
    }
}

/// Counters of one recorded topic.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct TopicCounts {
    /// Messages taken from the stream.
    pub received: u64,
    /// Messages written to the log.
    pub recorded: u64,
    /// Messages missing by the producer's `seq`, by the services' rule
    /// (`vibro_msgs::continuity`, as `log info` counts them): a forward step of `n`
    /// counts `n - 1`, up to [`MAX_LOST_MESSAGES`]; net of what a resync took back
    /// ([`Self::retracted`]).
    pub lost: u64,
    /// Forward `seq` steps that skip more than [`MAX_LOST_MESSAGES`]: a corrupt or
    /// renumbered counter, not a loss (not in `lost`); counting goes on from the new `seq`.
    pub jumps: u64,
    /// Messages the rule puts out of order (a repeat, or behind the stream): recorded
    /// all the same.
    pub out_of_order: u64,
    /// Times the producer's `seq` went back to 0.
    pub restarts: u64,
    /// Times the stream was taken up again after out-of-order messages (the rule's
    /// resync).
    pub resyncs: u64,
    /// Messages counted lost, then taken back at a resync: what a `seq` ahead of the
    /// stream counted (a forged 500,000 after 10: 499,989). Not in `lost`.
    pub retracted: u64,
    /// Messages whose counts exceed their arrays: not recorded (their `seq` then shows
    /// as missing in the log).
    pub malformed: u64,
    /// Times the recorder waited for room in the MCAP writer's queue.
    pub queue_waits: u64,
    /// Messages whose data time was off the recording's timeline ([`Timeline`]): written
    /// at the timeline's time instead (their own time stays in the message), left out
    /// of the view channels.
    pub off_timeline: u64,
}

// The most messages one forward `seq` step counts as lost; a bigger step is a jump
// (the rule of `vibro_msgs::continuity`, which the services and `log info` apply too).
#[cfg(any(test, doc))]
use vibro_msgs::MAX_LOST_MESSAGES;

/// What a recording holds, returned when it stops.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecordSummary {
    pub path: PathBuf,
    pub prefix: String,
    pub topics: BTreeMap<String, TopicCounts>,
    /// View messages written per view topic (docs/view.md).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub view: BTreeMap<String, u64>,
    pub messages: u64,
    /// Messages the recorder lost: the sum of every topic's [`TopicCounts::lost`]
    /// (each net of what was taken back). The blocks without an output
    /// ([`Self::inputs_without_output`]) are not in it: the recorder has them, and the
    /// compensator's own counters say why it gave none (a block it never received is
    /// in its `lost_messages`, which `demo` adds to this: counted once). `log info`,
    /// which has only the file, adds them to its `lost`.
    pub lost: u64,
    /// `seq` jumps over all topics ([`TopicCounts::jumps`]).
    pub jumps: u64,
    /// Resyncs over all topics ([`TopicCounts::resyncs`]).
    pub resyncs: u64,
    /// Losses taken back over all topics ([`TopicCounts::retracted`]; not in `lost`).
    pub retracted: u64,
    /// Accelerometer blocks recorded that got no compensated output in the recording
    /// (`vibro_mcap::Answers`, as `log info` counts them; blocks before the first one
    /// answered and after the last are not counted). Not in `lost`.
    pub inputs_without_output: u64,
    /// Those blocks, as ranges of `seq` (the first 16 listed).
    pub unanswered: SeqRanges,
    /// Messages off the data timeline over all topics ([`TopicCounts::off_timeline`]).
    pub off_timeline: u64,
    /// Times the timeline moved to where the data went ([`Timeline`]).
    pub timeline_resyncs: u64,
    pub chunks: u64,
    pub bytes: u64,
    pub duration_s: f64,
}

/// One recorded stream: its subscriber and its channel in the log.
struct Channel<T: WireMessage> {
    subscriber: StreamSubscriber<T>,
    channel: ChannelId,
}

/// A recorded stream's counters (apart from the subscriber, which the wait set borrows).
struct State {
    topic: String,
    counts: TopicCounts,
    tally: SeqTally,
}

/// The data's timeline (docs/logs.md, "Time"): a message's log time is the time its
/// data belongs to ([`Message::data_ns`]), so that a replay at any rate spans the
/// flight's own time in a viewer; a heartbeat, which has no data time, gets the
/// timeline's time. A data time far from the timeline does not move it ([`Timeline`]).
/// Heartbeats that arrive before the first data message wait for it (at most
/// [`PENDING_MAX`]; beyond, and when no data ever comes, they keep their receive time).
struct DataClock {
    timeline: Timeline,
    pending: Vec<Pending>,
    /// When a message off the timeline was last logged (bounded rate).
    off_logged_ns: Option<u64>,
}

/// A message waiting for the first data time.
struct Pending {
    channel: ChannelId,
    receive_ns: u64,
    seq: u32,
    message: Message,
}

/// The most heartbeats held for the first data time (a few seconds of every service's).
pub const PENDING_MAX: usize = 256;

impl DataClock {
    fn new() -> Self {
        Self {
            timeline: Timeline::default(),
            pending: Vec::new(),
            off_logged_ns: None,
        }
    }

    /// Writes what waits, at log time `log_ns` (or each at its receive time).
    fn flush(&mut self, recorder: &Recorder, log_ns: Option<u64>, st: &mut State) -> Result<()> {
        for p in self.pending.drain(..) {
            let t = log_ns.unwrap_or(p.receive_ns);
            write_waiting(recorder, &p.channel, t, p.receive_ns, p.seq, p.message, st)?;
        }
        Ok(())
    }
}

/// Writes one message, waiting while the writer's queue is full (the publishers feel
/// it as back-pressure, bounded and counted by them) rather than dropping it.
fn write_waiting(
    recorder: &Recorder,
    channel: &ChannelId,
    log_time_ns: u64,
    receive_ns: u64,
    seq: u32,
    message: Message,
    st: &mut State,
) -> Result<()> {
    loop {
        match recorder.write_to(channel, log_time_ns, receive_ns, seq, message) {
            Ok(()) => return Ok(()),
            Err(vibro_mcap::Error::QueueFull { .. }) => {
                st.counts.queue_waits += 1;
                std::thread::sleep(Duration::from_micros(200));
            }
            Err(e) => return Err(e.into()),
        }
    }
}

/// The view channels of the recording: the builder and where its messages go.
struct View {
    builder: ViewBuilder,
    channels: BTreeMap<String, (ViewChannelId, u32)>,
    out: Vec<ViewMessage>,
    written: BTreeMap<String, u64>,
    queue_waits: u64,
}

impl View {
    /// The view channels that `streams` feed: the units' with `/compensated`, the
    /// axes' with `/estimate`, each recorded service's health, `/log` with the log
    /// streams (no empty channel).
    fn open(recorder: &mut Recorder, streams: &[Stream]) -> Result<Self> {
        let fed = |topic: &str| {
            if topic == vibro_view::LOG_TOPIC {
                streams.iter().any(|s| matches!(s, Stream::Log(_)))
            } else if let Some(service) = topic.strip_prefix("/view/health/") {
                streams
                    .iter()
                    .any(|s| matches!(s, Stream::Heartbeat(id) if id.as_str() == service))
            } else if topic.starts_with("/view/vibration/") {
                streams.contains(&Stream::Estimate)
            } else {
                streams.contains(&Stream::Compensated)
            }
        };
        let mut channels = BTreeMap::new();
        for (topic, schema) in vibro_view::topics(UNIT_NAMES) {
            if !fed(&topic) {
                continue;
            }
            let id = recorder.add_view_channel(&topic, schema)?;
            channels.insert(topic, (id, 0));
        }
        Ok(Self {
            builder: ViewBuilder::new(UNIT_NAMES),
            channels,
            out: Vec::new(),
            written: BTreeMap::new(),
            queue_waits: 0,
        })
    }

    /// Writes what the builder made (`receive_ns`: the publish time of each), waiting
    /// for room in the writer's queue as the wire messages do.
    fn write(&mut self, recorder: &Recorder, receive_ns: u64) -> Result<()> {
        for v in self.out.drain(..) {
            let Some((channel, seq)) = self.channels.get_mut(&v.topic) else {
                continue;
            };
            if recorder.write_view(channel, v.log_time_ns, receive_ns, *seq, v.data)? {
                self.queue_waits += 1;
            }
            *seq = seq.wrapping_add(1);
            *self.written.entry(v.topic).or_default() += 1;
        }
        Ok(())
    }
}

/// The type-erased operations of a [`Channel`], so that one loop drains every stream.
trait Drain {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<Ipc>;
    fn clear_events(&self);
    /// Records every message waiting (and makes its view messages, and matches
    /// accelerometer blocks with their outputs); returns how many.
    fn drain(
        &self,
        recorder: &Recorder,
        st: &mut State,
        clock: &mut DataClock,
        view: &mut Option<View>,
        answers: &mut Answers,
    ) -> Result<u64>;
    /// Publishers of the stream now.
    fn publishers(&self) -> usize;
}

impl<T: WireMessage + Into<Message>> Drain for Channel<T> {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<Ipc> {
        self.subscriber.listener()
    }

    fn clear_events(&self) {
        let _ = self.subscriber.clear_events();
    }

    fn publishers(&self) -> usize {
        self.subscriber.publisher_count()
    }

    fn drain(
        &self,
        recorder: &Recorder,
        st: &mut State,
        clock: &mut DataClock,
        view: &mut Option<View>,
        answers: &mut Answers,
    ) -> Result<u64> {
        let mut n = 0;
        while let Some(sample) = self.subscriber.receive()? {
            let receive_ns = now_ns();
            let message: T = *sample;
            drop(sample);
            n += 1;
            st.counts.received += 1;
            let seq = message.seq();
            let arrival = count_seq(&mut st.counts, &mut st.tally, seq);
            if let Err(e) = message.validate() {
                st.counts.malformed += 1;
                if st.counts.malformed == 1 {
                    warn!(topic = %st.topic, seq, "not recording a malformed message: {e}");
                }
                continue;
            }
            let wire: Message = message.into();
            st.counts.recorded += 1;
            // Blocks without an output, as `log info` finds them in the file.
            match &wire {
                Message::AccelBlock(b) => answers.input(b.seq),
                Message::CompensatedBlock(b) => {
                    answers.output(b.input_seq, arrival.lost_messages);
                }
                _ => {}
            }
            let started = clock.timeline.now_ns().is_some();
            let (log_time_ns, on_timeline) = match wire.data_ns() {
                Some(t) => match clock.timeline.place(t) {
                    Placement::On(t) => (t, true),
                    Placement::Resync(t) => {
                        warn!(topic = %st.topic, data_time_ns = t, "the data timeline moved: {} messages in a row agreed on it", TIMELINE_RESYNC_AFTER);
                        (t, true)
                    }
                    Placement::Off(now) => {
                        st.counts.off_timeline += 1;
                        // Bounded rate: at most one line a second of receive time.
                        if clock
                            .off_logged_ns
                            .is_none_or(|l| receive_ns.saturating_sub(l) >= 1_000_000_000)
                        {
                            clock.off_logged_ns = Some(receive_ns);
                            warn!(topic = %st.topic, seq, data_time_ns = t, timeline_ns = now, off = st.counts.off_timeline, "a message's data time is off the recording's timeline: written at the timeline's time");
                        }
                        (now, false)
                    }
                },
                None => match clock.timeline.now_ns() {
                    Some(t) => (t, true),
                    None if clock.pending.len() < PENDING_MAX => {
                        // The view takes it now (its own time is the receive time).
                        if let Some(v) = view.as_mut() {
                            v.builder.on_message(&wire, &mut v.out);
                            v.write(recorder, receive_ns)?;
                        }
                        clock.pending.push(Pending {
                            channel: self.channel.clone(),
                            receive_ns,
                            seq: seq as u32,
                            message: wire,
                        });
                        continue;
                    }
                    None => (receive_ns, true),
                },
            };
            if !started {
                if let Some(t) = clock.timeline.now_ns() {
                    clock.flush(recorder, Some(t), st)?;
                }
            }
            if on_timeline {
                if let Some(v) = view.as_mut() {
                    v.builder.on_message(&wire, &mut v.out);
                    v.write(recorder, receive_ns)?;
                }
            }
            write_waiting(
                recorder,
                &self.channel,
                log_time_ns,
                receive_ns,
                seq as u32,
                wire,
                st,
            )?;
        }
        Ok(n)
    }
}

/// Counts the arrival of `seq` on a topic by the services' rule
/// (`vibro_msgs::continuity`): a loss, a jump (more than [`MAX_LOST_MESSAGES`]
/// skipped), out of order, a restart, a resync that takes back a loss counted at a
/// message ahead of the stream. Every message is recorded whatever it says.
fn count_seq(counts: &mut TopicCounts, tally: &mut SeqTally, seq: u64) -> Arrival {
    let a = tally.seq(seq);
    let t = &tally.totals;
    counts.lost = t.lost_messages;
    counts.jumps = t.seq_jumps;
    counts.out_of_order = t.out_of_order;
    counts.restarts = t.restarts;
    counts.resyncs = t.resyncs;
    counts.retracted = tally.retracted;
    a
}

fn open<T: WireMessage + Into<Message>>(
    node: &vibro_ipc::IpcNode,
    names: &ServiceNames,
    stream: Stream,
    recorder: &mut Recorder,
) -> Result<(Box<dyn Drain>, State)> {
    let subscriber = StreamSubscriber::<T>::open(node, names, stream)?;
    let topic = topic(stream);
    let channel = recorder.add_channel(&topic, stream.kind())?;
    Ok((
        Box::new(Channel {
            subscriber,
            channel,
        }),
        State {
            topic,
            counts: TopicCounts::default(),
            tally: SeqTally::new(),
        },
    ))
}

fn open_stream(
    node: &vibro_ipc::IpcNode,
    names: &ServiceNames,
    stream: Stream,
    recorder: &mut Recorder,
) -> Result<(Box<dyn Drain>, State)> {
    use vibro_msgs::MessageKind as K;
    match stream.kind() {
        K::AccelBlock => open::<AccelBlock>(node, names, stream, recorder),
        K::VibBlock => open::<VibBlock>(node, names, stream, recorder),
        K::VibEstimate => open::<VibEstimate>(node, names, stream, recorder),
        K::CompensatedBlock => open::<CompensatedBlock>(node, names, stream, recorder),
        K::TruthBlock => open::<TruthBlock>(node, names, stream, recorder),
        K::Heartbeat => open::<Heartbeat>(node, names, stream, recorder),
        K::LogLine => open::<LogLine>(node, names, stream, recorder),
    }
}

/// The recorder's own heartbeat and progress publishers.
struct Status {
    heartbeat: StreamPublisher<Heartbeat>,
    progress: StreamPublisher<Heartbeat>,
    started_ns: u64,
    heartbeat_seq: u64,
    progress_seq: u64,
}

impl Status {
    fn new(node: &vibro_ipc::IpcNode, names: &ServiceNames) -> Result<Self> {
        let hb = Stream::Heartbeat(ServiceId::Recorder);
        let pr = Stream::Progress(ServiceId::Recorder);
        Ok(Self {
            heartbeat: StreamPublisher::open(node, names, hb)?,
            progress: StreamPublisher::open(node, names, pr)?,
            started_ns: now_ns(),
            heartbeat_seq: 0,
            progress_seq: 0,
        })
    }

    fn message(&self, seq: u64, t: &Totals, state: ServiceState) -> Heartbeat {
        let now = now_ns();
        Heartbeat {
            seq,
            publish_ns: now,
            uptime_ns: now.saturating_sub(self.started_ns),
            received: t.received,
            published: t.recorded,
            lost: t.lost,
            out_of_order: t.out_of_order,
            resyncs: t.timeline_resyncs,
            service: ServiceId::Recorder.code(),
            state: state.code(),
            ..Heartbeat::ZEROED
        }
    }

    fn heartbeat(&mut self, t: &Totals, state: ServiceState) {
        let m = self.message(self.heartbeat_seq, t, state);
        self.heartbeat_seq += 1;
        let _ = self.heartbeat.publish(&m);
    }

    fn progress(&mut self, t: &Totals) {
        let m = self.message(self.progress_seq, t, ServiceState::Running);
        self.progress_seq += 1;
        let _ = self.progress.publish(&m);
    }
}

/// The recorder's counters over all topics, for its heartbeat.
#[derive(Debug, Default, Clone, Copy)]
struct Totals {
    received: u64,
    recorded: u64,
    lost: u64,
    /// Messages behind their topic's sequence (recorded all the same).
    out_of_order: u64,
    /// Times the data timeline was taken up again ([`Timeline`]).
    timeline_resyncs: u64,
}

impl Totals {
    fn of(states: &[State], clock: &DataClock) -> Self {
        let mut t = states.iter().fold(Self::default(), |t, c| {
            let k = &c.counts;
            Self {
                received: t.received + k.received,
                recorded: t.recorded + k.recorded,
                lost: t.lost + k.lost,
                out_of_order: t.out_of_order + k.out_of_order,
                ..t
            }
        });
        t.timeline_resyncs = clock.timeline.resyncs;
        t
    }
}

/// Records `options.streams` into `path` until `stop` is set, then takes what is still
/// waiting, finishes the file and returns what it holds. `ready` is called once every
/// subscriber exists (messages published from then on are recorded).
///
/// Runs on the calling thread, which it never gives back to an async runtime: call it
/// from a thread of its own.
///
/// A file that cannot be created or written (a missing or read-only folder, a full
/// disk) is [`Error::Output`] with the operating system's reason: the recording stops
/// at once, its subscribers are released first (the publishers are never held up by a
/// recorder that cannot write), and the file keeps what was flushed before.
pub fn record(
    path: &Path,
    options: &RecordOptions,
    stop: &AtomicBool,
    ready: impl FnOnce(),
) -> Result<RecordSummary> {
    let started_ns = now_ns();
    // The file rule (README, "Files"): never through a link, into a FIFO or device;
    // an existing file only with `force`.
    let recorder = if options.force {
        Recorder::create(path, options.recorder.clone())
    } else {
        Recorder::create_new(path, options.recorder.clone())
    };
    let mut recorder = recorder.map_err(|e| output_error("create", path, e, None))?;
    let Recorded {
        states,
        view,
        timeline_resyncs,
        answers,
    } = match record_into(&mut recorder, path, options, stop, ready, started_ns) {
        Ok(x) => x,
        Err(e) => {
            // The loop only sees that the writer thread stopped; `finish` says why.
            let stopped = matches!(e, Error::Mcap(vibro_mcap::Error::RecorderStopped { .. }));
            let written = recorder.stats().written;
            return Err(match recorder.finish() {
                Err(cause) if stopped => output_error("write", path, cause, Some(written)),
                _ => e,
            });
        }
    };
    let topics: BTreeMap<String, TopicCounts> =
        states.into_iter().map(|c| (c.topic, c.counts)).collect();
    let written = recorder.stats().written;
    let finished = recorder
        .finish()
        .map_err(|e| output_error("write", path, e, Some(written)))?;
    let unanswered = answers.unanswered().clone();
    let summary = RecordSummary {
        path: path.to_path_buf(),
        prefix: options.names.prefix().to_string(),
        view,
        messages: finished.messages,
        lost: topics.values().map(|t| t.lost).fold(0, u64::saturating_add),
        jumps: topics.values().map(|t| t.jumps).sum(),
        resyncs: topics.values().map(|t| t.resyncs).sum(),
        retracted: topics
            .values()
            .map(|t| t.retracted)
            .fold(0, u64::saturating_add),
        inputs_without_output: unanswered.count,
        unanswered,
        off_timeline: topics.values().map(|t| t.off_timeline).sum(),
        timeline_resyncs,
        topics,
        chunks: finished.chunks,
        bytes: finished.bytes,
        duration_s: now_ns().saturating_sub(started_ns) as f64 * 1e-9,
    };
    info!(
        messages = summary.messages,
        lost = summary.lost,
        seq_jumps = summary.jumps,
        resyncs = summary.resyncs,
        retracted = summary.retracted,
        inputs_without_output = summary.inputs_without_output,
        off_timeline = summary.off_timeline,
        timeline_resyncs = summary.timeline_resyncs,
        bytes = summary.bytes,
        "recording finished"
    );
    Ok(summary)
}

/// An error of the MCAP writer on `path`: with the operating system's reason when it
/// is an I/O error (`written`: messages the writer had taken when it failed).
fn output_error(
    action: &'static str,
    path: &Path,
    e: vibro_mcap::Error,
    written: Option<u64>,
) -> Error {
    let Some(io) = crate::io_cause(&e) else {
        return Error::Mcap(e);
    };
    let what_is_kept = match written {
        None => String::new(),
        Some(0) => "; nothing was recorded".to_string(),
        Some(n) => format!(
            "; of the {n} messages taken, the file keeps those of its complete chunks: `vibrocomp log recover {} OUT.mcap` restores them",
            path.display()
        ),
    };
    Error::Output {
        action,
        path: path.to_path_buf(),
        reason: io.to_string(),
        what_is_kept,
    }
}

/// What [`record_into`] counted.
struct Recorded {
    states: Vec<State>,
    /// View messages written per view topic.
    view: BTreeMap<String, u64>,
    timeline_resyncs: u64,
    /// Accelerometer blocks against their outputs.
    answers: Answers,
}

/// Subscribes, writes the header records and records until `stop`; returns the
/// counters. Every port is released when it returns, whatever the outcome.
fn record_into(
    recorder: &mut Recorder,
    path: &Path,
    options: &RecordOptions,
    stop: &AtomicBool,
    ready: impl FnOnce(),
    started_ns: u64,
) -> Result<Recorded> {
    let node = create_node("vibrocomp-recorder")?;
    let cleaned = cleanup_dead_nodes(&node);
    if cleaned > 0 {
        info!(cleaned, "removed the resources of dead iceoryx2 nodes");
    }
    let mut channels = Vec::with_capacity(options.streams.len());
    let mut states = Vec::with_capacity(options.streams.len());
    for &stream in &options.streams {
        let (channel, state) = open_stream(&node, &options.names, stream, recorder)?;
        channels.push(channel);
        states.push(state);
    }
    let mut meta = BTreeMap::from([
        ("prefix".to_string(), options.names.prefix().to_string()),
        (
            "topics".to_string(),
            states
                .iter()
                .map(|c| c.topic.clone())
                .collect::<Vec<_>>()
                .join(", "),
        ),
        (
            "log_time".to_string(),
            "data time, ns: a block's last sample, an estimate's window end; a heartbeat \
             the latest data time seen (docs/logs.md, Time)"
                .to_string(),
        ),
        (
            "publish_time".to_string(),
            "receive time, CLOCK_MONOTONIC ns".to_string(),
        ),
    ]);
    meta.insert("started_ns".to_string(), started_ns.to_string());
    let mut view = if options.view {
        Some(View::open(recorder, &options.streams)?)
    } else {
        None
    };
    let truth_at = options.streams.iter().position(|s| *s == Stream::Truth);
    let mut own = LogExtras::recorded();
    own.metadata(RECORDING_METADATA, meta);
    own.write_to(recorder)?;
    options.extras.write_to(recorder)?;
    let mut status = Status::new(&node, &options.names)?;
    let waitset = create_waitset()?;
    let mut guards = Vec::with_capacity(channels.len() + 1);
    for (c, st) in channels.iter().zip(&states) {
        guards.push(waitset.attach_notification(c.listener()).map_err(|e| {
            vibro_ipc::Error::Iceoryx {
                operation: "attach to the wait set",
                service: st.topic.clone(),
                reason: format!("{e:?}"),
            }
        })?);
    }
    info!(
        prefix = options.names.prefix(),
        streams = channels.len(),
        path = %path.display(),
        "recording"
    );
    let mut clock = DataClock::new();
    let mut answers = Answers::new();
    status.heartbeat(&Totals::default(), ServiceState::Starting);
    ready();
    let heartbeat_ns = options.heartbeat_period.as_nanos() as u64;
    let mut next_heartbeat_ns = now_ns().saturating_add(heartbeat_ns);
    loop {
        let stopping = stop.load(Ordering::Acquire);
        if !stopping {
            waitset
                .wait_and_process_once_with_timeout(
                    |_| CallbackProgression::Continue,
                    options.stop_poll,
                )
                .map_err(|e| vibro_ipc::Error::Iceoryx {
                    operation: "wait",
                    service: "recorder wait set".to_string(),
                    reason: format!("{e:?}"),
                })?;
            for c in &channels {
                c.clear_events();
            }
        }
        // A rig (or replay) publishing a reference: compensated blocks wait for theirs
        // in the view (as in the live view).
        if let Some(v) = view.as_mut() {
            let reference = truth_at.is_some_and(|i| channels[i].publishers() > 0);
            v.builder.expect_reference(reference, &mut v.out);
            v.write(recorder, now_ns())?;
        }
        let mut taken = 0;
        for (c, st) in channels.iter().zip(&mut states) {
            taken += c.drain(recorder, st, &mut clock, &mut view, &mut answers)?;
        }
        let totals = Totals::of(&states, &clock);
        if taken > 0 {
            status.progress(&totals);
        }
        let now = now_ns();
        if now >= next_heartbeat_ns {
            next_heartbeat_ns = now.saturating_add(heartbeat_ns);
            let state = if totals.received == 0 {
                ServiceState::Starting
            } else {
                ServiceState::Running
            };
            status.heartbeat(&totals, state);
        }
        // On stop: one last pass took everything the publishers had sent.
        if stopping {
            break;
        }
    }
    // No data came: what waited for its time keeps its receive time.
    if let Some(st) = states.first_mut() {
        clock.flush(recorder, None, st)?;
    }
    let mut view_written = BTreeMap::new();
    if let Some(mut v) = view {
        v.builder.flush(&mut v.out);
        v.write(recorder, now_ns())?;
        if v.queue_waits > 0 {
            info!(
                waits = v.queue_waits,
                "view messages waited for the writer's queue"
            );
        }
        view_written = v.written;
    }
    status.heartbeat(&Totals::of(&states, &clock), ServiceState::Stopping);
    drop(guards);
    drop(channels);
    Ok(Recorded {
        states,
        view: view_written,
        timeline_resyncs: clock.timeline.resyncs,
        answers,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::timeline::MAX_TIMELINE_STEP_NS;

    #[test]
    fn random_seqs_are_jumps_and_a_real_gap_is_a_loss() {
        let (mut counts, mut tally) = (TopicCounts::default(), SeqTally::new());
        // 7 lost (11..=17), then the limit exactly, then one beyond it.
        for seq in [
            10u64,
            18,
            19 + MAX_LOST_MESSAGES,
            21 + 2 * MAX_LOST_MESSAGES,
        ] {
            count_seq(&mut counts, &mut tally, seq);
        }
        assert_eq!((counts.lost, counts.jumps), (7 + MAX_LOST_MESSAGES, 1));
        // Random u64 seqs (the probe that printed lost_blocks=18366207225729211778).
        let (mut counts, mut tally) = (TopicCounts::default(), SeqTally::new());
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        for _ in 0..1000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            count_seq(&mut counts, &mut tally, x);
        }
        assert_eq!(counts.lost, 0, "{counts:?}");
        assert_eq!(counts.jumps + counts.out_of_order, 999, "{counts:?}");
    }

    /// Issue 46, item 6: seq 0..=10, a forged 500,000, then 11..=60 counted 499,989
    /// lost and no jump. By the services' rule: none lost once the stream resumed,
    /// 499,989 taken back at one resync, 11..=13 out of order (recorded all the same).
    #[test]
    fn a_forged_seq_ahead_is_taken_back_when_the_stream_resumes() {
        let (mut counts, mut tally) = (TopicCounts::default(), SeqTally::new());
        for seq in (0..=10).chain([500_000]).chain(11..=60) {
            count_seq(&mut counts, &mut tally, seq);
        }
        assert_eq!(
            (
                counts.lost,
                counts.jumps,
                counts.out_of_order,
                counts.resyncs,
                counts.retracted
            ),
            (0, 0, 3, 1, 499_989),
            "{counts:?}"
        );
    }

    /// Issue 31's probe: one block with `t0_ns = u64::MAX` stamped every later heartbeat
    /// and log line at 18,446,744,073.7 s. It must not move the timeline.
    #[test]
    fn one_forged_data_time_does_not_move_the_timeline() {
        let mut tl = Timeline::default();
        let period_ns = 40_000_000;
        let t0 = 1_000_000_000_000u64; // 1000 s
        assert_eq!(tl.place(t0), Placement::On(t0));
        assert_eq!(tl.place(t0 + period_ns), Placement::On(t0 + period_ns));
        assert_eq!(tl.place(u64::MAX), Placement::Off(t0 + period_ns));
        for k in 2..200u64 {
            let t = t0 + k * period_ns;
            assert_eq!(tl.place(t), Placement::On(t), "block {k}");
            // Forged times between real blocks, each far from the last: never a run.
            if k % 3 == 0 {
                let forged = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) | (1 << 63);
                assert!(
                    matches!(tl.place(forged), Placement::Off(_)),
                    "forged at {k}"
                );
            }
        }
        assert_eq!(tl.now_ns(), Some(t0 + 199 * period_ns));
        assert_eq!(tl.resyncs, 0);
        // A time far in the past does not pull it back either.
        assert!(matches!(tl.place(0), Placement::Off(_)));
        assert_eq!(tl.now_ns(), Some(t0 + 199 * period_ns));
    }

    #[test]
    fn a_real_move_of_the_data_clock_is_followed_after_a_run() {
        let mut tl = Timeline::default();
        tl.place(500_000_000_000);
        // Another log replayed from t = 0: the first messages are off, then it moves.
        let mut placed = Vec::new();
        for k in 0..TIMELINE_RESYNC_AFTER as u64 + 2 {
            placed.push(tl.place(k * 10_000_000 + 1));
        }
        let n = TIMELINE_RESYNC_AFTER as usize;
        assert!(
            placed[..n - 1]
                .iter()
                .all(|p| *p == Placement::Off(500_000_000_000)),
            "{placed:?}"
        );
        assert_eq!(
            placed[n - 1],
            Placement::Resync((n as u64 - 1) * 10_000_000 + 1)
        );
        assert_eq!(placed[n], Placement::On(n as u64 * 10_000_000 + 1));
        assert_eq!(tl.resyncs, 1);
        // Forward by more than the step (a stream paused for minutes) moves the same way.
        let later = 10 * MAX_TIMELINE_STEP_NS;
        let p: Vec<_> = (0..TIMELINE_RESYNC_AFTER as u64)
            .map(|k| tl.place(later + k))
            .collect();
        assert_eq!(
            p.last(),
            Some(&Placement::Resync(later + TIMELINE_RESYNC_AFTER as u64 - 1))
        );
        assert_eq!(tl.resyncs, 2);
    }

    /// Random data times, any order: the timeline never leaves the neighbourhood of
    /// what it was fed as a real stream while that stream goes on, and placements are
    /// always within the step of the timeline or its new place.
    #[test]
    fn random_data_times_never_stretch_the_timeline() {
        let mut tl = Timeline::default();
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut real = 3_000_000_000u64;
        tl.place(real);
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            // One forged time in two, then the real stream's next block.
            if x & 1 == 0 {
                tl.place(x);
            }
            real += 40_000_000;
            assert_eq!(tl.place(real), Placement::On(real));
        }
        assert_eq!(tl.now_ns(), Some(real));
        assert_eq!(tl.resyncs, 0);
    }
}
