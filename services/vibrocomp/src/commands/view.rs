//! `vibrocomp view`: the live view. Attaches to a running system (its prefix) like any
//! other participant, turns its streams into the view channels (`vibro_view`,
//! docs/view.md) and serves them over Foxglove's WebSocket protocol (the `foxglove`
//! crate), on 127.0.0.1:8765 unless told otherwise, until Ctrl-C / SIGTERM (or
//! `--duration-s`).
//!
//! The iceoryx2 loop runs on its own thread and never waits for a client: the
//! Foxglove server queues each client's messages in a bounded queue and drops the
//! oldest for a client that falls behind, so the services never feel a viewer.

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
    CompensatedBlock, Heartbeat, MessageKind, ServiceNames, Stream, TruthBlock, VibEstimate,
    WireMessage,
};
use vibro_service::{init_tracing, run_service};
use vibro_view::{ViewBuilder, ViewMessage, UNIT_NAMES};

use crate::flags::FlagProblems;
use crate::output::print_json;

/// Where the live view listens unless told otherwise: this machine only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8765";

/// Messages each client may have queued before the oldest are dropped.
const CLIENT_BACKLOG: usize = 4096;

#[derive(Debug, Clone, clap::Args)]
pub struct ViewArgs {
    /// Service-name prefix of the system to watch.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Address the Foxglove WebSocket server listens on (HOST:PORT; another host than
    /// 127.0.0.1 only when you mean it).
    #[arg(long, default_value = DEFAULT_LISTEN)]
    pub listen: SocketAddr,
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
    /// View messages made, per view topic.
    published: BTreeMap<String, u64>,
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
        // The raw rig streams make no view channel of their own.
        MessageKind::AccelBlock | MessageKind::VibBlock => Ok(None),
    }
}

/// The iceoryx2 side: subscribes, turns each message into view messages and logs them
/// on their Foxglove channels, until `stop`.
fn pump(
    names: &ServiceNames,
    channels: &BTreeMap<String, Arc<foxglove::RawChannel>>,
    stop: &AtomicBool,
    summary: &mut Summary,
) -> anyhow::Result<()> {
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
            *summary.received.entry(f.topic().to_string()).or_default() +=
                (wire.len() - before) as u64;
        }
        // A rig (or replay) publishing a reference: compensated blocks wait for theirs.
        let reference = feeds
            .iter()
            .any(|f| f.topic() == truth_topic && f.publishers() > 0);
        out.clear();
        view.expect_reference(reference, &mut out);
        send(channels, &out, summary);
        // The references first: a compensated block pairs with the reference block of
        // its samples, which the rig published before the block it answers.
        wire.sort_by_key(|m| !matches!(m, Message::TruthBlock(_)));
        for m in &wire {
            out.clear();
            view.on_message(m, &mut out);
            send(channels, &out, summary);
        }
    }
    out.clear();
    view.flush(&mut out);
    send(channels, &out, summary);
    drop(guards);
    Ok(())
}

/// Logs each view message on its Foxglove channel, on the data's time.
fn send(
    channels: &BTreeMap<String, Arc<foxglove::RawChannel>>,
    out: &[ViewMessage],
    summary: &mut Summary,
) {
    for v in out {
        if let Some(ch) = channels.get(&v.topic) {
            ch.log_with_meta(
                &v.data,
                foxglove::PartialMetadata {
                    log_time: Some(v.log_time_ns),
                },
            );
            *summary.published.entry(v.topic.clone()).or_default() += 1;
        }
    }
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
    let summary = run_service(|shutdown| async move {
        let ctx = foxglove::Context::new();
        let mut channels = BTreeMap::new();
        for (topic, schema) in vibro_view::topics(UNIT_NAMES) {
            let ch = ctx
                .channel_builder(topic.as_str())
                .message_encoding(vibro_mcap::MESSAGE_ENCODING)
                .schema(foxglove::Schema::new(
                    schema.name,
                    vibro_mcap::SCHEMA_ENCODING,
                    schema.data,
                ))
                .build_raw()
                .with_context(|| format!("the Foxglove channel {topic}"))?;
            channels.insert(topic, ch);
        }
        let server = foxglove::WebSocketServer::new()
            .name(format!("vibrocomp view ({})", names.prefix()))
            .bind(listen.ip().to_string(), listen.port())
            .message_backlog_size(CLIENT_BACKLOG)
            .context(&ctx)
            .start()
            .await
            .with_context(|| format!("starting the Foxglove WebSocket server on {listen}"))?;
        tracing::info!(
            listen = %listen,
            prefix = names.prefix(),
            "live view: open ws://{listen} in Foxglove"
        );
        let (tx, rx) = tokio::sync::oneshot::channel();
        let flag = shutdown.clone();
        std::thread::Builder::new()
            .name("vibrocomp-view".into())
            .spawn(move || {
                let mut summary = Summary {
                    listen: listen.to_string(),
                    ..Summary::default()
                };
                let r = pump(&names, &channels, flag.flag(), &mut summary);
                let _ = tx.send(r.map(|()| summary));
            })
            .context("spawning the view thread")?;
        if let Some(d) = duration {
            let timer = shutdown.clone();
            tokio::spawn(async move {
                tokio::time::sleep(d).await;
                timer.trigger();
            });
        }
        let result = rx
            .await
            .map_err(|_| anyhow::anyhow!("the view thread ended without a result (it panicked)"))?;
        server.stop().wait().await;
        result
    })?;
    if args.json {
        return print_json(&summary);
    }
    let received: u64 = summary.received.values().sum();
    let published: u64 = summary.published.values().sum();
    outln!(
        "Served {published} view messages from {received} messages of the system on ws://{}",
        summary.listen
    )?;
    Ok(())
}
