//! # vibro-ipc
//!
//! The transport of the vibrocomp services over iceoryx2 (zero-copy shared memory):
//! every stream is one publish-subscribe service carrying a fixed-size `#[repr(C)]`
//! message, plus one event service beside it, which the publisher notifies after each
//! send so that consumers sleep in a `WaitSet` instead of polling.
//!
//! Policies, the same for every stream:
//!
//! - **No silent loss.** Safe overflow is off: a full subscriber buffer is never
//!   overwritten. The publisher retries while the buffer is full, for at most
//!   [`StreamConfig::backpressure_timeout`] (bounded back-pressure); after that the
//!   sample is dropped for that subscriber, counted, and [`StreamPublisher::publish`]
//!   returns [`Error::Undelivered`].
//! - **Signals are the application's.** Nodes and wait sets are created with
//!   iceoryx2's signal handling disabled; the service owns SIGINT/SIGTERM and stops
//!   its loop, so ports are released by `Drop`.
//! - **Dead peers** are cleaned up with [`cleanup_dead_nodes`], which the services
//!   call at start-up and periodically.
//!
//! ```no_run
//! use vibro_ipc::{create_node, StreamConfig, StreamPublisher, StreamSubscriber};
//! # fn main() -> Result<(), vibro_ipc::Error> {
//! let node = create_node("example")?;
//! let config = StreamConfig::default();
//! let mut publisher = StreamPublisher::<u64>::create(&node, "ex/count", "ex/count/event", &config)?;
//! let subscriber = StreamSubscriber::<u64>::create(&node, "ex/count", "ex/count/event", &config)?;
//! publisher.publish(&42)?;
//! assert_eq!(subscriber.receive()?.map(|s| *s), Some(42));
//! # Ok(())
//! # }
//! ```
//!
//! References: iceoryx2 0.10 (publish-subscribe, events, `WaitSet`), pinned `=0.10.0`
//! across the workspace and the Python client.

use core::fmt::Debug;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::BackpressureAction;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

/// The clock of every `*_ns` stamp in the messages: `CLOCK_MONOTONIC`, which on Linux
/// is one clock for all processes, so a latency between two processes' stamps is
/// meaningful (and immune to wall-clock steps).
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on
    // Linux, and on failure `ts` stays zero.
    unsafe {
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
    }
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}

/// The iceoryx2 service variant of every vibrocomp stream: inter-process.
pub type Ipc = ipc::Service;
/// A node of the vibrocomp transport.
pub type IpcNode = Node<Ipc>;
/// A received message, borrowed from shared memory until dropped.
pub type Received<T> = Sample<Ipc, T, ()>;

/// Errors of the transport. Each names the service it happened on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The name is not a valid iceoryx2 service or node name.
    #[error("service name {name:?}: {reason}")]
    Name { name: String, reason: String },
    /// iceoryx2 refused an operation.
    #[error("{operation} on {service:?}: {reason}")]
    Iceoryx {
        operation: &'static str,
        service: String,
        reason: String,
    },
    /// A subscriber's buffer stayed full for the whole back-pressure timeout: the
    /// message was not delivered to it (counted in [`StreamPublisher::undelivered`]).
    #[error("{service:?}: a subscriber's buffer stayed full for {timeout_ms} ms; message {sent} not delivered to it")]
    Undelivered {
        service: String,
        timeout_ms: u128,
        sent: u64,
    },
}

/// Result of the transport.
pub type Result<T> = std::result::Result<T, Error>;

fn iox(operation: &'static str, service: &str, e: impl Debug) -> Error {
    Error::Iceoryx {
        operation,
        service: service.to_owned(),
        reason: format!("{e:?}"),
    }
}

/// Quality of service of one stream; publisher and subscribers must agree (iceoryx2
/// checks it when a service is opened).
#[derive(Debug, Clone, PartialEq)]
pub struct StreamConfig {
    /// Messages a subscriber can hold before the publisher has to wait.
    pub subscriber_buffer: usize,
    /// Messages a late subscriber receives on connecting (0 for streams, 1 for
    /// state such as the latest estimate).
    pub history: usize,
    pub max_publishers: usize,
    pub max_subscribers: usize,
    pub max_nodes: usize,
    /// Longest a publisher waits for a full subscriber buffer before the message is
    /// counted as undelivered to that subscriber.
    pub backpressure_timeout: Duration,
}

impl Default for StreamConfig {
    fn default() -> Self {
        Self {
            subscriber_buffer: 256,
            history: 0,
            max_publishers: 2,
            max_subscribers: 8,
            max_nodes: 16,
            backpressure_timeout: Duration::from_secs(1),
        }
    }
}

/// The quality of service of each vibrocomp stream, the one place it is decided: every
/// participant (services, recorder, replay, rig bridges) opens a stream with this.
/// `estimate` keeps a history of 1, so a compensator that connects late receives the
/// latest estimate with the estimator's next publish; the rest use the defaults.
pub fn stream_config(stream: vibro_msgs::Stream) -> StreamConfig {
    match stream {
        vibro_msgs::Stream::Estimate => StreamConfig {
            history: 1,
            ..StreamConfig::default()
        },
        _ => StreamConfig::default(),
    }
}

/// A node named `name`, with iceoryx2's own signal handling disabled (the
/// application handles SIGINT/SIGTERM and releases ports by dropping them).
pub fn create_node(name: &str) -> Result<IpcNode> {
    quiet_iceoryx_log();
    let node_name = NodeName::new(name).map_err(|e| Error::Name {
        name: name.to_owned(),
        reason: format!("{e:?}"),
    })?;
    NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| iox("create node", name, e))
}

/// iceoryx2 logs at `Warn` by default, and warns on every start that no config file was
/// loaded (running on its defaults is what vibrocomp does): keep its log to errors
/// unless the user asks for more with iceoryx2's own `IOX2_LOG_LEVEL`.
fn quiet_iceoryx_log() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| set_log_level_from_env_or(LogLevel::Error));
}

/// A wait set with iceoryx2's signal handling disabled, for a service's hot loop.
pub fn create_waitset() -> Result<WaitSet<Ipc>> {
    WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| iox("create wait set", "", e))
}

/// Removes the resources of nodes whose processes died; returns how many were
/// cleaned up.
pub fn cleanup_dead_nodes(node: &IpcNode) -> usize {
    node.try_cleanup_dead_nodes().cleanups as usize
}

fn service_name(name: &str) -> Result<ServiceName> {
    ServiceName::new(name).map_err(|e| Error::Name {
        name: name.to_owned(),
        reason: format!("{e:?}"),
    })
}

fn open_pubsub<T: ZeroCopySend + Debug + 'static>(
    node: &IpcNode,
    name: &str,
    config: &StreamConfig,
) -> Result<PubSubFactory<Ipc, T, ()>> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .enable_safe_overflow(false)
        .subscriber_max_buffer_size(config.subscriber_buffer)
        .history_size(config.history)
        .max_publishers(config.max_publishers)
        .max_subscribers(config.max_subscribers)
        .max_nodes(config.max_nodes)
        .open_or_create()
        .map_err(|e| iox("open publish-subscribe service", name, e))
}

fn open_event(
    node: &IpcNode,
    name: &str,
    config: &StreamConfig,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Ipc>> {
    node.service_builder(&service_name(name)?)
        .event()
        .max_nodes(config.max_nodes)
        .max_notifiers(config.max_publishers + 2)
        .max_listeners(config.max_subscribers + 2)
        .open_or_create()
        .map_err(|e| iox("open event service", name, e))
}

/// The sending end of a stream.
pub struct StreamPublisher<T: ZeroCopySend + Debug + 'static> {
    name: String,
    service: PubSubFactory<Ipc, T, ()>,
    publisher: Publisher<Ipc, T, ()>,
    notifier: Notifier<Ipc>,
    timeout: Duration,
    sent: u64,
    /// Deliveries given up after the back-pressure timeout, counted by the handler.
    undelivered: Arc<AtomicU64>,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> StreamPublisher<T> {
    /// Opens (or creates) the stream `name` and its event service `event_name`.
    pub fn create(
        node: &IpcNode,
        name: &str,
        event_name: &str,
        config: &StreamConfig,
    ) -> Result<Self> {
        let service = open_pubsub::<T>(node, name, config)?;
        let undelivered = Arc::new(AtomicU64::new(0));
        let counter = Arc::clone(&undelivered);
        let timeout = config.backpressure_timeout;
        let publisher = service
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(move |info: &iceoryx2::port::BackpressureInfo| {
                if info.elapsed_time < timeout {
                    // Let the consumer run; a 20 us nap keeps a blocked publisher
                    // from burning its core.
                    std::thread::sleep(Duration::from_micros(20));
                    BackpressureAction::Retry
                } else {
                    counter.fetch_add(1, Ordering::Relaxed);
                    BackpressureAction::DiscardDataAndFail
                }
            })
            .create()
            .map_err(|e| iox("create publisher", name, e))?;
        let notifier = open_event(node, event_name, config)?
            .notifier_builder()
            .create()
            .map_err(|e| iox("create notifier", event_name, e))?;
        Ok(Self {
            name: name.to_owned(),
            service,
            publisher,
            notifier,
            timeout,
            sent: 0,
            undelivered,
        })
    }

    /// Opens `stream` of the system `names` with its event service and the stream's
    /// quality of service ([`stream_config`]).
    pub fn open(
        node: &IpcNode,
        names: &vibro_msgs::ServiceNames,
        stream: vibro_msgs::Stream,
    ) -> Result<Self> {
        Self::create(
            node,
            &names.stream(stream),
            &names.event(stream),
            &stream_config(stream),
        )
    }

    /// Sends a copy of `msg` to every subscriber and wakes their wait sets; returns
    /// how many subscribers it reached.
    pub fn publish(&mut self, msg: &T) -> Result<usize> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| iox("loan", &self.name, e))?;
        let sample = sample.write_payload(*msg);
        self.finish_send(sample.send())
    }

    /// Writes the message in place in shared memory (no copy of a large block):
    /// `fill` receives a default-initialised message.
    pub fn publish_with(&mut self, fill: impl FnOnce(&mut T)) -> Result<usize>
    where
        T: Default,
    {
        let mut sample = self
            .publisher
            .loan()
            .map_err(|e| iox("loan", &self.name, e))?;
        fill(sample.payload_mut());
        self.finish_send(sample.send())
    }

    fn finish_send(
        &mut self,
        sent: std::result::Result<usize, iceoryx2::port::SendError>,
    ) -> Result<usize> {
        self.sent += 1;
        // Wake the consumers even if one subscriber was skipped: the others have data.
        let notified = self.notifier.notify();
        let reached = match sent {
            Ok(n) => n,
            Err(_) if self.undelivered.load(Ordering::Relaxed) > 0 => {
                return Err(Error::Undelivered {
                    service: self.name.clone(),
                    timeout_ms: self.timeout.as_millis(),
                    sent: self.sent,
                });
            }
            Err(e) => return Err(iox("send", &self.name, e)),
        };
        notified.map_err(|e| iox("notify", &self.name, e))?;
        Ok(reached)
    }

    /// Subscribers currently connected to the stream.
    pub fn subscriber_count(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }

    /// Messages published so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Deliveries given up after the back-pressure timeout so far.
    pub fn undelivered(&self) -> u64 {
        self.undelivered.load(Ordering::Relaxed)
    }

    pub fn name(&self) -> &str {
        &self.name
    }
}

/// The receiving end of a stream, with the listener of its event service.
pub struct StreamSubscriber<T: ZeroCopySend + Debug + 'static> {
    name: String,
    service: PubSubFactory<Ipc, T, ()>,
    subscriber: Subscriber<Ipc, T, ()>,
    listener: Listener<Ipc>,
}

impl<T: ZeroCopySend + Debug + 'static> StreamSubscriber<T> {
    /// Opens (or creates) the stream `name` and its event service `event_name`.
    pub fn create(
        node: &IpcNode,
        name: &str,
        event_name: &str,
        config: &StreamConfig,
    ) -> Result<Self> {
        let service = open_pubsub::<T>(node, name, config)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(config.subscriber_buffer)
            .create()
            .map_err(|e| iox("create subscriber", name, e))?;
        let listener = open_event(node, event_name, config)?
            .listener_builder()
            .create()
            .map_err(|e| iox("create listener", event_name, e))?;
        Ok(Self {
            name: name.to_owned(),
            service,
            subscriber,
            listener,
        })
    }

    /// Opens `stream` of the system `names` with its event service and the stream's
    /// quality of service ([`stream_config`]).
    pub fn open(
        node: &IpcNode,
        names: &vibro_msgs::ServiceNames,
        stream: vibro_msgs::Stream,
    ) -> Result<Self> {
        Self::create(
            node,
            &names.stream(stream),
            &names.event(stream),
            &stream_config(stream),
        )
    }

    /// The next message, if any (never blocks).
    pub fn receive(&self) -> Result<Option<Received<T>>> {
        self.subscriber
            .receive()
            .map_err(|e| iox("receive", &self.name, e))
    }

    /// The listener to attach to a wait set.
    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Consumes the pending wake-ups (call before draining with [`Self::receive`]).
    pub fn clear_events(&self) -> Result<()> {
        self.listener
            .try_wait(|_| {})
            .map(|_| ())
            .map_err(|e| iox("read events", &self.name, e))
    }

    /// Publishers currently connected to the stream.
    pub fn publisher_count(&self) -> usize {
        self.service.dynamic_config().number_of_publishers()
    }

    pub fn name(&self) -> &str {
        &self.name
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prefix(test: &str) -> String {
        format!("vct-ipc-{}-{test}/", std::process::id())
    }

    #[test]
    fn messages_arrive_in_order_and_wake_the_listener() {
        let p = prefix("order");
        let node = create_node("ipc-order").unwrap();
        let config = StreamConfig::default();
        let (data, event) = (format!("{p}n"), format!("{p}n/event"));
        let mut publisher =
            StreamPublisher::<[u64; 4]>::create(&node, &data, &event, &config).unwrap();
        let subscriber =
            StreamSubscriber::<[u64; 4]>::create(&node, &data, &event, &config).unwrap();
        assert_eq!(publisher.subscriber_count(), 1);
        assert_eq!(subscriber.publisher_count(), 1);
        for k in 0..100u64 {
            assert_eq!(publisher.publish(&[k, k + 1, k + 2, k + 3]).unwrap(), 1);
        }
        let mut woken = 0;
        subscriber
            .listener()
            .timed_wait(|_| woken += 1, Duration::from_secs(1))
            .unwrap();
        assert!(woken > 0);
        for k in 0..100u64 {
            let s = subscriber.receive().unwrap().expect("message");
            assert_eq!(*s, [k, k + 1, k + 2, k + 3]);
        }
        assert!(subscriber.receive().unwrap().is_none());
        assert_eq!(publisher.undelivered(), 0);
    }

    /// With the subscriber not reading, the publisher waits for the timeout, then
    /// reports the loss instead of overwriting the buffer.
    #[test]
    fn a_full_buffer_is_never_overwritten() {
        let p = prefix("full");
        let node = create_node("ipc-full").unwrap();
        let config = StreamConfig {
            subscriber_buffer: 4,
            backpressure_timeout: Duration::from_millis(30),
            ..StreamConfig::default()
        };
        let (data, event) = (format!("{p}n"), format!("{p}n/event"));
        let mut publisher = StreamPublisher::<u64>::create(&node, &data, &event, &config).unwrap();
        let subscriber = StreamSubscriber::<u64>::create(&node, &data, &event, &config).unwrap();
        for k in 0..4u64 {
            publisher.publish(&k).unwrap();
        }
        let err = publisher.publish(&99).unwrap_err();
        assert!(matches!(err, Error::Undelivered { .. }), "{err}");
        assert_eq!(publisher.undelivered(), 1);
        // The first four are intact, in order; the fifth was not delivered.
        for k in 0..4u64 {
            assert_eq!(*subscriber.receive().unwrap().unwrap(), k);
        }
        assert!(subscriber.receive().unwrap().is_none());
    }

    #[test]
    fn bad_names_are_reported_with_the_name() {
        let node = create_node("ipc-names").unwrap();
        let long = "x".repeat(2000);
        let err = StreamPublisher::<u64>::create(&node, &long, "e", &StreamConfig::default())
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.starts_with("service name \"xxxx"), "{err}");
    }
}
