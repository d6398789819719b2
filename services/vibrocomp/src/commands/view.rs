//! `vibrocomp view`: the live view. Attaches to a running system (its prefix) like any
//! other participant, turns its streams into the view channels (`vibro_view`,
//! docs/view.md) and serves them over Foxglove's WebSocket protocol (the `foxglove`
//! crate), on 127.0.0.1:8765 unless told otherwise, until Ctrl-C / SIGTERM (or
//! `--duration-s`).
//!
//! The iceoryx2 loop runs on its own thread and never waits for a client: it puts the
//! view messages into a bounded outbox (`vibro_view::Outbox`, the oldest dropped and
//! counted when full), from which a sender thread hands them to the Foxglove server;
//! the server queues each client's messages in a bounded queue of its own and drops
//! the oldest for a client that falls behind. So the services never feel a viewer.
//!
//! The Foxglove server listens on 127.0.0.1 only, its port shut to all but the guard of
//! `vibro_view::live` (the address given): a cap on viewers (`--max-clients`) with a
//! share per peer (a local peer is the user owning the client's socket), a handshake
//! timeout, pings that a client must answer within 10 s, client messages of 64 KiB at
//! most, a listener that outlives a descriptor shortage, log lines about clients
//! rate-limited (issues 31 and 46); `foxglove.websocket.v1` is served as well as the
//! SDK's `foxglove.sdk.v1`.

use anyhow::Context;
use iceoryx2::prelude::CallbackProgression;
use serde::Serialize;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use vibro_ipc::{create_node, create_waitset, Ipc, StreamSubscriber};
use vibro_log::{topic, DEFAULT_RECORD_STREAMS};
use vibro_mcap::Message;
use vibro_msgs::{
    CompensatedBlock, Heartbeat, LogLine, MessageKind, ServiceNames, Stream, TruthBlock,
    VibEstimate, WireMessage,
};
use vibro_service::{init_tracing, run_service};
use vibro_view::live::{LiveOptions, LiveServer, LiveStats};
use vibro_view::{ViewBuilder, ViewMessage, UNIT_NAMES};

use crate::flags::FlagProblems;
use crate::output::print_json;

/// Where the live view listens unless told otherwise: this machine only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8765";

/// Messages each client may have queued before the oldest are dropped.
const CLIENT_BACKLOG: usize = 4096;

/// View messages waiting for the sender thread before the oldest are dropped (about
/// 40 s of a system's view: 75 unit messages a second, a few others).
const OUTBOX_CAPACITY: usize = 4096;

/// How often the sender tells the clients about drops (a Foxglove status message).
const DROP_STATUS_PERIOD: Duration = Duration::from_secs(1);

#[derive(Debug, Clone, clap::Args)]
pub struct ViewArgs {
    /// Service-name prefix of the system to watch.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Address the Foxglove WebSocket server listens on (HOST:PORT; another host than
    /// 127.0.0.1 only when you mean it).
    #[arg(long, default_value = DEFAULT_LISTEN)]
    pub listen: SocketAddr,
    /// Viewers served at once. One more takes the place of one that does not answer its
    /// pings, or of the peer holding the most when its own holds two fewer; else it is
    /// refused (HTTP 503).
    #[arg(long, default_value_t = vibro_view::live::DEFAULT_MAX_CLIENTS as u16,
          value_parser = clap::value_parser!(u16).range(1..=1024))]
    pub max_clients: u16,
    /// Stop by itself after this many seconds.
    #[arg(long = "duration-s")]
    pub duration_s: Option<f64>,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What a view served, returned when it stops.
#[derive(Debug, Default, Serialize)]
struct Summary {
    listen: String,
    /// Wire messages taken from the system, per topic.
    received: BTreeMap<String, u64>,
    /// View messages handed to the Foxglove server, per view topic.
    published: BTreeMap<String, u64>,
    /// View messages dropped because the sender fell behind the system (the outbox
    /// was full). A client's own backlog (4096) is the Foxglove SDK's: it drops the
    /// oldest for a client that falls behind without counting them.
    dropped: u64,
    /// What the guard in front of the Foxglove server did (connections refused, closed,
    /// log lines left out).
    clients: LiveStats,
}

/// One subscribed stream, type-erased so that one loop drains them all.
trait Feed {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<Ipc>;
    fn clear_events(&self);
    /// Every message waiting, as wire messages.
    fn drain(&self, out: &mut Vec<Message>) -> anyhow::Result<()>;
    fn topic(&self) -> &str;
    fn publishers(&self) -> usize;
}

struct Sub<T: WireMessage> {
    subscriber: StreamSubscriber<T>,
    topic: String,
}

impl<T: WireMessage + Into<Message>> Feed for Sub<T> {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<Ipc> {
        self.subscriber.listener()
    }

    fn clear_events(&self) {
        let _ = self.subscriber.clear_events();
    }

    fn drain(&self, out: &mut Vec<Message>) -> anyhow::Result<()> {
        while let Some(sample) = self.subscriber.receive()? {
            let m: T = *sample;
            drop(sample);
            if m.validate().is_ok() {
                out.push(m.into());
            }
        }
        Ok(())
    }

    fn topic(&self) -> &str {
        &self.topic
    }

    fn publishers(&self) -> usize {
        self.subscriber.publisher_count()
    }
}

fn subscribe(
    node: &vibro_ipc::IpcNode,
    names: &ServiceNames,
    stream: Stream,
) -> anyhow::Result<Option<Box<dyn Feed>>> {
    fn sub<T: WireMessage + Into<Message>>(
        node: &vibro_ipc::IpcNode,
        names: &ServiceNames,
        stream: Stream,
    ) -> anyhow::Result<Option<Box<dyn Feed>>> {
        Ok(Some(Box::new(Sub::<T> {
            subscriber: StreamSubscriber::open(node, names, stream)?,
            topic: topic(stream),
        })))
    }
    match stream.kind() {
        MessageKind::CompensatedBlock => sub::<CompensatedBlock>(node, names, stream),
        MessageKind::TruthBlock => sub::<TruthBlock>(node, names, stream),
        MessageKind::VibEstimate => sub::<VibEstimate>(node, names, stream),
        MessageKind::Heartbeat => sub::<Heartbeat>(node, names, stream),
        MessageKind::LogLine => sub::<LogLine>(node, names, stream),
        // The raw rig streams make no view channel of their own.
        MessageKind::AccelBlock | MessageKind::VibBlock => Ok(None),
    }
}

/// The iceoryx2 side: subscribes, turns each message into view messages and puts them
/// in `outbox`, until `stop`; returns the wire messages taken per topic.
fn pump(
    names: &ServiceNames,
    outbox: &vibro_view::Outbox,
    stop: &AtomicBool,
) -> anyhow::Result<BTreeMap<String, u64>> {
    let node = create_node("vibrocomp-view")?;
    let mut feeds = Vec::new();
    for stream in DEFAULT_RECORD_STREAMS {
        if let Some(f) = subscribe(&node, names, stream)? {
            feeds.push(f);
        }
    }
    let waitset = create_waitset()?;
    let mut guards = Vec::with_capacity(feeds.len());
    for f in &feeds {
        guards.push(
            waitset
                .attach_notification(f.listener())
                .map_err(|e| anyhow::anyhow!("attaching {} to the wait set: {e:?}", f.topic()))?,
        );
    }
    let mut received = BTreeMap::new();
    let mut view = ViewBuilder::new(UNIT_NAMES);
    let truth_topic = topic(Stream::Truth);
    let (mut wire, mut out): (Vec<Message>, Vec<ViewMessage>) = (Vec::new(), Vec::new());
    while !stop.load(Ordering::Acquire) {
        waitset
            .wait_and_process_once_with_timeout(
                |_| CallbackProgression::Continue,
                Duration::from_millis(100),
            )
            .map_err(|e| anyhow::anyhow!("waiting on the view's wait set: {e:?}"))?;
        wire.clear();
        for f in &feeds {
            f.clear_events();
            let before = wire.len();
            f.drain(&mut wire)?;
            *received.entry(f.topic().to_string()).or_default() += (wire.len() - before) as u64;
        }
        // A rig (or replay) publishing a reference: compensated blocks wait for theirs.
        let reference = feeds
            .iter()
            .any(|f| f.topic() == truth_topic && f.publishers() > 0);
        view.expect_reference(reference, &mut out);
        // The references first: a compensated block pairs with the reference block of
        // its samples, which the rig published before the block it answers.
        wire.sort_by_key(|m| !matches!(m, Message::TruthBlock(_)));
        for m in &wire {
            view.on_message(m, &mut out);
        }
        for v in out.drain(..) {
            outbox.push(v);
        }
    }
    view.flush(&mut out);
    for v in out.drain(..) {
        outbox.push(v);
    }
    drop(guards);
    Ok(received)
}

/// The sender side: hands each view message of `outbox` to its Foxglove channel, on
/// the data's time, until the outbox is closed and empty; tells the clients (a
/// Foxglove status) when messages were dropped. Returns the messages sent per topic.
fn send_all(
    outbox: &vibro_view::Outbox,
    channels: &BTreeMap<String, Arc<foxglove::RawChannel>>,
    status: impl Fn(u64),
) -> BTreeMap<String, u64> {
    let mut published = BTreeMap::new();
    let (mut told, mut last): (u64, Option<std::time::Instant>) = (0, None);
    while let Some(v) = outbox.pop() {
        if let Some(ch) = channels.get(&v.topic) {
            ch.log_with_meta(
                &v.data,
                foxglove::PartialMetadata {
                    log_time: Some(v.log_time_ns),
                },
            );
            *published.entry(v.topic).or_default() += 1;
        }
        let dropped = outbox.dropped();
        if dropped > told && last.is_none_or(|t| t.elapsed() >= DROP_STATUS_PERIOD) {
            status(dropped);
            (told, last) = (dropped, Some(std::time::Instant::now()));
        }
    }
    if outbox.dropped() > told {
        status(outbox.dropped());
    }
    published
}

pub fn run(args: &ViewArgs) -> anyhow::Result<()> {
    init_tracing();
    let names =
        ServiceNames::new(&args.prefix).with_context(|| format!("--prefix {:?}", args.prefix))?;
    let mut problems = FlagProblems::new();
    let duration = args
        .duration_s
        .and_then(|d| problems.seconds("--duration-s", d, 1e-3, 1e9));
    problems.finish()?;
    let listen = args.listen;
    let options = LiveOptions {
        listen,
        max_clients: usize::from(args.max_clients),
        ..LiveOptions::default()
    };
    let summary = run_service(|shutdown| async move {
        let ctx = foxglove::Context::new();
        let channels = vibro_view::live::channels(&ctx, UNIT_NAMES)?;
        let name = format!("vibrocomp view ({})", names.prefix());
        let server = LiveServer::start(
            &ctx,
            move || {
                foxglove::WebSocketServer::new()
                    .name(name.clone())
                    .message_backlog_size(CLIENT_BACKLOG)
            },
            options,
        )
        .await
        .with_context(|| format!("starting the Foxglove WebSocket server on {listen}"))?;
        // The address it got (`--listen 127.0.0.1:0`: the port the system chose).
        let listen = server.local_addr();
        tracing::info!(
            listen = %listen,
            prefix = names.prefix(),
            "live view: open ws://{listen} in Foxglove"
        );
        let server = Arc::new(server);
        let outbox = Arc::new(vibro_view::Outbox::new(OUTBOX_CAPACITY));
        let sender = {
            let (outbox, server) = (Arc::clone(&outbox), Arc::clone(&server));
            std::thread::Builder::new()
                .name("vibrocomp-view-send".into())
                .spawn(move || {
                    send_all(&outbox, &channels, |dropped| {
                        server.publish_status(
                            foxglove::websocket::Status::new(
                                foxglove::websocket::StatusLevel::Warning,
                                format!(
                                    "vibrocomp view: {dropped} view messages dropped (the \
                                     view's sender fell behind the system)"
                                ),
                            )
                            .with_id("vibrocomp-view-drops"),
                        );
                    })
                })
                .context("spawning the view's sender thread")?
        };
        let (tx, rx) = tokio::sync::oneshot::channel();
        let flag = shutdown.clone();
        let pump_outbox = Arc::clone(&outbox);
        std::thread::Builder::new()
            .name("vibrocomp-view".into())
            .spawn(move || {
                let r = pump(&names, &pump_outbox, flag.flag());
                pump_outbox.close();
                let _ = tx.send(r);
            })
            .context("spawning the view thread")?;
        if let Some(d) = duration {
            let timer = shutdown.clone();
            tokio::spawn(async move {
                tokio::time::sleep(d).await;
                timer.trigger();
            });
        }
        let received = rx.await.map_err(|_| {
            anyhow::anyhow!("the view thread ended without a result (it panicked)")
        })??;
        let published = tokio::task::spawn_blocking(move || sender.join())
            .await
            .context("waiting for the view's sender thread")?
            .map_err(|_| anyhow::anyhow!("the view's sender thread panicked"))?;
        let clients = match Arc::try_unwrap(server) {
            Ok(server) => server.stop().await,
            Err(server) => server.stats(),
        };
        Ok(Summary {
            listen: listen.to_string(),
            received,
            published,
            dropped: outbox.dropped(),
            clients,
        })
    })?;
    if args.json {
        return print_json(&summary);
    }
    let received: u64 = summary.received.values().sum();
    let published: u64 = summary.published.values().sum();
    outln!(
        "Served {published} view messages from {received} messages of the system on ws://{}; \
         dropped {} (the view's sender behind the system)",
        summary.listen,
        summary.dropped
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Drops in the outbox reach the clients as a status (at once, then at most once
    /// a period, and the final count when the outbox closes).
    #[test]
    fn drops_are_told_to_the_clients() {
        let outbox = vibro_view::Outbox::new(2);
        for i in 0..5 {
            outbox.push(ViewMessage {
                topic: "/view/AK1".into(),
                schema: vibro_mcap::VIEW_UNIT_STAGES,
                log_time_ns: i,
                data: Vec::new(),
            });
        }
        outbox.close();
        let told = std::sync::Mutex::new(Vec::new());
        let published = send_all(&outbox, &BTreeMap::new(), |d| told.lock().unwrap().push(d));
        assert!(published.is_empty(), "no channel: nothing sent");
        assert_eq!(*told.lock().unwrap(), [3]);
    }
}
