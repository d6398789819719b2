//! The service's log lines on the system's own transport: `{prefix}log/{service}`
//! ([`vibro_msgs::LogLine`]), beside what it writes to stderr, so that a viewer
//! (`foxglove.Log` in the live view) and a recording see them (docs/messages.md).
//!
//! [`init_tracing`](crate::init_tracing) always installs [`ForwardLayer`], which does
//! nothing until [`start`] gives it somewhere to send: then each event that passes the
//! log filter is formatted once (`target: message key=value ...`) and offered to a
//! bounded queue without waiting (a full queue drops the line and counts it), and a
//! thread of its own publishes the queue over iceoryx2. A hot loop never logs per
//! sample (STYLE.md), so a line costs it one formatting and one `try_send` at most.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Mutex;
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::Context;
use vibro_ipc::{create_node, StreamPublisher};
use vibro_msgs::{LogLevel, LogLine, ServiceId, ServiceNames, Stream};

/// Lines queued for the publishing thread before new ones are dropped.
pub const LOG_QUEUE: usize = 256;

/// Where [`ForwardLayer`] sends: set by [`start`], cleared when its guard drops.
static SINK: Mutex<Option<(SyncSender<LogLine>, ServiceId)>> = Mutex::new(None);

/// Lines dropped because the queue was full (or the publisher gone), process-wide.
static DROPPED: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// Set on the publishing thread: what it logs itself is not forwarded again.
    static PUBLISHING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// The `tracing` layer that forwards events to the log stream once [`start`]ed.
#[derive(Debug, Default)]
pub struct ForwardLayer;

/// Collects an event's fields as `message key=value ...`, as the stderr lines of
/// `tracing_subscriber::fmt` show them.
struct Fields(String);

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            // The message first, whatever order the fields came in.
            self.0.insert_str(0, &format!("{value:?}"));
        } else {
            let _ = write!(self.0, " {}={value:?}", field.name());
        }
    }

    fn record_str(&mut self, field: &Field, value: &str) {
        // As `tracing_subscriber::fmt` writes them: a string field quoted.
        if field.name() == "message" {
            self.0.insert_str(0, value);
        } else {
            let _ = write!(self.0, " {}={value:?}", field.name());
        }
    }
}

fn level_of(level: &Level) -> LogLevel {
    match *level {
        Level::TRACE => LogLevel::Trace,
        Level::DEBUG => LogLevel::Debug,
        Level::INFO => LogLevel::Info,
        Level::WARN => LogLevel::Warn,
        Level::ERROR => LogLevel::Error,
    }
}

fn wall_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl<S: Subscriber> tracing_subscriber::Layer<S> for ForwardLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        if PUBLISHING.with(std::cell::Cell::get) {
            return;
        }
        let Ok(sink) = SINK.lock() else {
            return;
        };
        let Some((tx, service)) = sink.as_ref() else {
            return;
        };
        let meta = event.metadata();
        let mut fields = Fields(String::new());
        event.record(&mut fields);
        let text = format!("{}: {}", meta.target(), fields.0.trim_start());
        let mut line = LogLine::new(*service, level_of(meta.level()), &text);
        line.wall_ns = wall_ns();
        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(line) {
            DROPPED.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Lines dropped so far (a full queue, or nobody publishing).
pub fn dropped() -> u64 {
    DROPPED.load(Ordering::Relaxed)
}

/// Publishing `service`'s log lines on `{prefix}log/{service}` until dropped: then the
/// queue is drained, the publisher released and its thread joined.
#[derive(Debug)]
pub struct LogStream {
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Starts publishing the log lines of `service` of the system `names`. An error (the
/// stream cannot be opened) leaves the service logging to stderr only.
pub fn start(names: &ServiceNames, service: ServiceId) -> anyhow::Result<LogStream> {
    let (tx, rx) = std::sync::mpsc::sync_channel::<LogLine>(LOG_QUEUE);
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let names = names.clone();
    let thread = std::thread::Builder::new()
        .name(format!("{service}-log"))
        .spawn(move || publish(&names, service, &rx, &ready_tx))?;
    match ready_rx.recv() {
        Ok(Ok(())) => {
            if let Ok(mut sink) = SINK.lock() {
                *sink = Some((tx, service));
            }
            Ok(LogStream {
                thread: Some(thread),
            })
        }
        Ok(Err(e)) => {
            let _ = thread.join();
            Err(e)
        }
        Err(_) => {
            let _ = thread.join();
            anyhow::bail!("the log stream's thread ended before it was ready")
        }
    }
}

fn publish(
    names: &ServiceNames,
    service: ServiceId,
    rx: &Receiver<LogLine>,
    ready: &std::sync::mpsc::Sender<anyhow::Result<()>>,
) {
    PUBLISHING.with(|p| p.set(true));
    let opened = create_node(&format!("vibrocomp-{service}-log")).and_then(|node| {
        StreamPublisher::<LogLine>::open(&node, names, Stream::Log(service)).map(|p| (node, p))
    });
    let (_node, mut publisher) = match opened {
        Ok(x) => {
            let _ = ready.send(Ok(()));
            x
        }
        Err(e) => {
            let _ = ready.send(Err(anyhow::Error::from(e)
                .context(format!("opening {}", names.stream(Stream::Log(service))))));
            return;
        }
    };
    let (mut seq, mut subscribers) = (0u64, publisher.subscriber_count());
    loop {
        match rx.recv_timeout(CONNECT_POLL) {
            Ok(mut line) => {
                line.seq = seq;
                line.publish_ns = crate::now_ns();
                seq += 1;
                if publisher.publish(&line).is_err() {
                    DROPPED.fetch_add(1, Ordering::Relaxed);
                }
            }
            // A viewer or recorder that came since gets the history now, not with
            // the next line (which may be minutes away).
            Err(RecvTimeoutError::Timeout) => {
                let now = publisher.subscriber_count();
                if now > subscribers {
                    let _ = publisher.update_connections();
                }
                subscribers = now;
            }
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
}

/// How often the publishing thread looks for new subscribers while no line comes.
const CONNECT_POLL: std::time::Duration = std::time::Duration::from_millis(100);

impl Drop for LogStream {
    fn drop(&mut self) {
        // The sender gone, the thread drains what is queued and ends.
        if let Ok(mut sink) = SINK.lock() {
            *sink = None;
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
