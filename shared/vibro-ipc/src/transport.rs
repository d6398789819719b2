//! The iceoryx2 side of the transport (the feature `ipc`): nodes, publishers,
//! subscribers, event services.

use super::{stream_config, Error, Result, StreamConfig, ICEORYX2_VERSION};
use core::fmt::Debug;
use std::os::unix::fs::MetadataExt;
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
use iceoryx2::service::builder::event::{EventCreateError, EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern as StaticPattern;

/// The iceoryx2 service variant of every vibrocomp stream: inter-process.
pub type Ipc = ipc::Service;
/// A node of the vibrocomp transport.
pub type IpcNode = Node<Ipc>;
/// A received message, borrowed from shared memory until dropped.
pub type Received<T> = Sample<Ipc, T, ()>;

fn iox(operation: &'static str, service: &str, e: impl Debug) -> Error {
    Error::Iceoryx {
        operation,
        service: service.to_owned(),
        reason: format!("{e:?}"),
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
    let config = Config::global_config();
    check_owner(config)?;
    NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| node_error(config, name, e))
}

/// Makes this process join the iceoryx2 system of the config file `path` (its
/// `root-path` and shared-memory file `prefix`: another "host" on this machine) instead
/// of the one `config/iceoryx2.toml` in the working directory names. Must come before
/// the first node of the process; fails if another configuration is already in use.
pub fn use_config_file(path: &std::path::Path) -> Result<()> {
    let shown = path.display().to_string();
    let err = |reason: String| Error::Iceoryx {
        operation: "load the iceoryx2 config file",
        service: shown.clone(),
        reason,
    };
    let file = FilePath::new(shown.as_bytes()).map_err(|e| err(format!("{e:?}")))?;
    let wanted = Config::from_file(&file).map_err(|e| err(format!("{e:?}")))?;
    let config = Config::setup_global_config_from_file(&file).map_err(|e| err(format!("{e:?}")))?;
    if config.global.root_path() != wanted.global.root_path()
        || config.global.prefix != wanted.global.prefix
    {
        return Err(err(format!(
            "this process already uses the iceoryx2 root {} (set before this file was read)",
            iceoryx_root(config)
        )));
    }
    Ok(())
}

/// The directory under which iceoryx2 keeps its files (`/tmp/iceoryx2/` unless an
/// iceoryx2 config file, e.g. `config/iceoryx2.toml` in the working directory, says
/// otherwise).
fn iceoryx_root(config: &Config) -> String {
    config.global.root_path().to_string()
}

/// `name (uid N)` of a user id, or `uid N` if it has no name.
fn user(uid: u32) -> String {
    // SAFETY: `passwd` is a C struct of integers and pointers, for which all-zero
    // bytes are a valid value; getpwuid_r fills it in.
    let mut pwd: libc::passwd = unsafe { std::mem::zeroed() };
    let mut buf = vec![0 as libc::c_char; 4096];
    let mut found: *mut libc::passwd = std::ptr::null_mut();
    // SAFETY: getpwuid_r writes into `pwd` and `buf` (whose length is passed) only,
    // and `found` points at `pwd` or is null; the name is read before `buf` is freed.
    let rc = unsafe { libc::getpwuid_r(uid, &mut pwd, buf.as_mut_ptr(), buf.len(), &mut found) };
    if rc == 0 && !found.is_null() && !pwd.pw_name.is_null() {
        // SAFETY: on success `pw_name` is a NUL-terminated string inside `buf`.
        let name = unsafe { std::ffi::CStr::from_ptr(pwd.pw_name) };
        return format!("{} (uid {uid})", name.to_string_lossy());
    }
    format!("uid {uid}")
}

fn effective_uid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// iceoryx2 0.10 (without its `dev_permissions` feature) creates its root directory
/// (mode 0750) and every file in it and in /dev/shm (0600, static configs 0400) for the
/// user of the first process. Another user, even one in the owner's group, cannot
/// create a node there (iceoryx2 says `InternalError`); root can, but the owner's
/// processes then cannot open what root creates, so messages between them are lost
/// while root's publisher counts them delivered (measured). Either way: refuse, and
/// say whose the system is.
fn check_owner(config: &Config) -> Result<()> {
    let root = iceoryx_root(config);
    // Not there yet: this process creates it and owns it.
    let Ok(meta) = std::fs::metadata(&root) else {
        return Ok(());
    };
    let me = effective_uid();
    if meta.uid() != me {
        return Err(Error::OtherUser {
            path: root,
            owner: user(meta.uid()),
            me: user(me),
        });
    }
    Ok(())
}

fn node_error(config: &Config, name: &str, e: iceoryx2::node::NodeCreationFailure) -> Error {
    let root = iceoryx_root(config);
    let path = std::ffi::CString::new(root.trim_end_matches('/')).unwrap_or_default();
    // SAFETY: `path` is a valid NUL-terminated string; access only reads it.
    let writable = unsafe { libc::access(path.as_ptr(), libc::W_OK | libc::X_OK) } == 0;
    let reason = if writable {
        format!("{e:?}")
    } else {
        // Read errno before anything else can change it.
        let why = std::io::Error::last_os_error();
        format!(
            "{e:?}: {root} is not writable for {} ({why})",
            user(effective_uid())
        )
    };
    Error::Iceoryx {
        operation: "create node",
        service: name.to_owned(),
        reason,
    }
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
    let service = service_name(name)?;
    node.service_builder(&service)
        .publish_subscribe::<T>()
        .enable_safe_overflow(false)
        .subscriber_max_buffer_size(config.subscriber_buffer)
        .history_size(config.history)
        .max_publishers(config.max_publishers)
        .max_subscribers(config.max_subscribers)
        .max_nodes(config.max_nodes)
        .open_or_create()
        .map_err(|e| pubsub_error::<T>(node, name, &service, config, e))
}

/// What a payload type is to iceoryx2: its type name, size and alignment.
fn payload_of<T: ZeroCopySend>() -> String {
    // SAFETY: `type_name` is unsafe only for implementors, who must keep it unique;
    // reading it has no precondition.
    let type_name = unsafe { <T as ZeroCopySend>::type_name() };
    format!(
        "{type_name} ({} bytes, alignment {})",
        size_of::<T>(),
        align_of::<T>()
    )
}

/// The static configuration of an existing service, if it can be read.
fn existing(
    node: &IpcNode,
    service: &ServiceName,
    pattern: MessagingPattern,
) -> Option<iceoryx2::service::static_config::StaticConfig> {
    Ipc::details(service, node.config(), pattern)
        .ok()
        .flatten()
        .map(|d| d.static_details)
}

fn pubsub_error<T: ZeroCopySend>(
    node: &IpcNode,
    name: &str,
    service: &ServiceName,
    config: &StreamConfig,
    e: PublishSubscribeOpenOrCreateError,
) -> Error {
    use PublishSubscribeOpenError as O;
    const OPERATION: &str = "open publish-subscribe service";
    let static_config = || {
        existing(node, service, MessagingPattern::PublishSubscribe)
            .filter(|c| matches!(c.messaging_pattern(), StaticPattern::PublishSubscribe(_)))
    };
    let open = match e {
        PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(o) => o,
        PublishSubscribeOpenOrCreateError::PublishSubscribeCreateError(
            PublishSubscribeCreateError::InsufficientPermissions,
        ) => return permission(OPERATION, name, "cannot create it"),
        other => return iox(OPERATION, name, other),
    };
    match open {
        O::IncompatibleTypes => Error::IncompatibleType {
            service: name.to_owned(),
            expected: payload_of::<T>(),
            found: static_config().map_or_else(
                || "another payload type".to_string(),
                |c| {
                    let p = &c.publish_subscribe().message_type_details().payload;
                    format!(
                        "{} ({} bytes, alignment {})",
                        p.type_name(),
                        p.size(),
                        p.alignment()
                    )
                },
            ),
            schema: vibro_msgs::SCHEMA_VERSION,
        },
        O::IncompatibleOverflowBehavior
        | O::IncompatibleAttributes
        | O::IncompatibleMessagingPattern
        | O::DoesNotSupportRequestedMinBufferSize
        | O::DoesNotSupportRequestedMinHistorySize
        | O::DoesNotSupportRequestedMinSubscriberBorrowedSamples
        | O::DoesNotSupportRequestedAmountOfPublishers
        | O::DoesNotSupportRequestedAmountOfSubscribers
        | O::DoesNotSupportRequestedAmountOfNodes => Error::IncompatibleSettings {
            service: name.to_owned(),
            problem: format!("{open:?}"),
            found: static_config().map_or_else(
                || "settings that could not be read".to_string(),
                |c| {
                    let p = c.publish_subscribe();
                    format!(
                        "subscriber buffer {}, history {}, safe overflow {}, max publishers {}, max subscribers {}, max nodes {}",
                        p.subscriber_max_buffer_size(),
                        p.history_size(),
                        if p.has_safe_overflow() { "on" } else { "off" },
                        p.max_publishers(),
                        p.max_subscribers(),
                        p.max_nodes()
                    )
                },
            ),
            needed: format!(
                "subscriber buffer >= {}, history >= {}, safe overflow off, max publishers >= {}, max subscribers >= {}, max nodes >= {}",
                config.subscriber_buffer,
                config.history,
                config.max_publishers,
                config.max_subscribers,
                config.max_nodes
            ),
        },
        O::VersionMismatch => Error::IceoryxVersion {
            service: name.to_owned(),
            ours: ICEORYX2_VERSION,
        },
        O::InsufficientPermissions => permission(OPERATION, name, "cannot open it"),
        other => iox(OPERATION, name, other),
    }
}

fn permission(operation: &'static str, service: &str, what: &str) -> Error {
    Error::Permission {
        operation,
        service: service.to_owned(),
        detail: format!("{} {what}", user(effective_uid())),
    }
}

fn open_event(
    node: &IpcNode,
    name: &str,
    config: &StreamConfig,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Ipc>> {
    let service = service_name(name)?;
    node.service_builder(&service)
        .event()
        .max_nodes(config.max_nodes)
        .max_notifiers(config.max_publishers + 2)
        .max_listeners(config.max_subscribers + 2)
        .open_or_create()
        .map_err(|e| event_error(node, name, &service, config, e))
}

fn event_error(
    node: &IpcNode,
    name: &str,
    service: &ServiceName,
    config: &StreamConfig,
    e: EventOpenOrCreateError,
) -> Error {
    use EventOpenError as O;
    const OPERATION: &str = "open event service";
    let open = match e {
        EventOpenOrCreateError::EventOpenError(o) => o,
        EventOpenOrCreateError::EventCreateError(EventCreateError::InsufficientPermissions) => {
            return permission(OPERATION, name, "cannot create it")
        }
        other => return iox(OPERATION, name, other),
    };
    match open {
        O::IncompatibleMessagingPattern
        | O::IncompatibleAttributes
        | O::IncompatibleDeadline
        | O::IncompatibleNotifierCreatedEvent
        | O::IncompatibleNotifierDroppedEvent
        | O::IncompatibleNotifierDeadEvent
        | O::DoesNotSupportRequestedAmountOfNotifiers
        | O::DoesNotSupportRequestedAmountOfListeners
        | O::DoesNotSupportRequestedMaxEventId
        | O::DoesNotSupportRequestedAmountOfNodes => Error::IncompatibleSettings {
            service: name.to_owned(),
            problem: format!("{open:?}"),
            found: existing(node, service, MessagingPattern::Event)
                .filter(|c| matches!(c.messaging_pattern(), StaticPattern::Event(_)))
                .map_or_else(
                    || "settings that could not be read".to_string(),
                    |c| {
                        let ev = c.event();
                        format!(
                            "max notifiers {}, max listeners {}, max nodes {}",
                            ev.max_notifiers(),
                            ev.max_listeners(),
                            ev.max_nodes()
                        )
                    },
                ),
            needed: format!(
                "max notifiers >= {}, max listeners >= {}, max nodes >= {}",
                config.max_publishers + 2,
                config.max_subscribers + 2,
                config.max_nodes
            ),
        },
        O::VersionMismatch => Error::IceoryxVersion {
            service: name.to_owned(),
            ours: ICEORYX2_VERSION,
        },
        O::InsufficientPermissions => permission(OPERATION, name, "cannot open it"),
        other => iox(OPERATION, name, other),
    }
}

/// The process ids of the publishers of `service` other than `ours` (by iceoryx2's
/// node list: each publisher names its node, each node its process). A publisher
/// whose node is no longer listed is left out.
fn publisher_pids<T: ZeroCopySend + Debug + 'static>(
    service: &PubSubFactory<Ipc, T, ()>,
    ours: Option<&iceoryx2::identifiers::UniquePublisherId>,
) -> Vec<u32> {
    let mut nodes = Vec::new();
    service.dynamic_config().list_publishers(|p| {
        if Some(&p.publisher_id) != ours {
            nodes.push(p.node_id);
        }
        CallbackProgression::Continue
    });
    let mut pids = Vec::new();
    if nodes.is_empty() {
        return pids;
    }
    let _ = Node::<Ipc>::list(Config::global_config(), |state| {
        use iceoryx2::node::NodeView;
        if let NodeState::Alive(v) = &state {
            if nodes.contains(v.id()) {
                if let Some(d) = v.details() {
                    pids.push(d.process_id().value() as u32);
                }
            }
        }
        CallbackProgression::Continue
    });
    pids.sort_unstable();
    pids.dedup();
    pids
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

    /// Publishers currently connected to the stream (this one included).
    pub fn publisher_count(&self) -> usize {
        self.service.dynamic_config().number_of_publishers()
    }

    /// The process ids of the other publishers on this stream (alive nodes only).
    pub fn other_publisher_pids(&self) -> Vec<u32> {
        publisher_pids(&self.service, Some(&self.publisher.id()))
    }

    /// Subscribers currently connected to the stream.
    pub fn subscriber_count(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }

    /// Connects subscribers that appeared since the last publish, delivering the
    /// stream's history to them now rather than with the next message.
    pub fn update_connections(&self) -> Result<()> {
        use iceoryx2::port::update_connections::UpdateConnections as _;
        self.publisher
            .update_connections()
            .map_err(|e| iox("update connections", &self.name, e))
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

    /// The process ids of the stream's publishers (alive nodes only).
    pub fn publisher_pids(&self) -> Vec<u32> {
        publisher_pids(&self.service, None)
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

    /// A service opened with another payload type names both types; iceoryx2 alone
    /// says `IncompatibleTypes`.
    #[test]
    fn a_foreign_payload_type_is_refused_naming_both_types() {
        let p = prefix("type");
        let node = create_node("ipc-type").unwrap();
        let config = StreamConfig::default();
        let (data, event) = (format!("{p}n"), format!("{p}n/event"));
        let _ours = StreamPublisher::<u64>::create(&node, &data, &event, &config).unwrap();
        let err = StreamSubscriber::<[u32; 4]>::create(&node, &data, &event, &config)
            .err()
            .expect("refused");
        assert!(matches!(err, Error::IncompatibleType { .. }), "{err}");
        let text = err.to_string();
        for wanted in [
            data.as_str(),
            "carries u64 (8 bytes, alignment 8)",
            "this process uses [u32; 4] (16 bytes, alignment 4)",
            "incompatible version of the message contracts",
        ] {
            assert!(text.contains(wanted), "{wanted:?} not in: {text}");
        }
    }

    /// A service created with a smaller buffer than vibrocomp needs says what it has
    /// and what is needed.
    #[test]
    fn other_settings_are_refused_naming_what_exists_and_what_is_needed() {
        let p = prefix("qos");
        let node = create_node("ipc-qos").unwrap();
        let (data, event) = (format!("{p}n"), format!("{p}n/event"));
        let small = StreamConfig {
            subscriber_buffer: 4,
            ..StreamConfig::default()
        };
        let _theirs = StreamPublisher::<u64>::create(&node, &data, &event, &small).unwrap();
        let err = StreamSubscriber::<u64>::create(&node, &data, &event, &StreamConfig::default())
            .err()
            .expect("refused");
        assert!(matches!(err, Error::IncompatibleSettings { .. }), "{err}");
        let text = err.to_string();
        for wanted in [
            data.as_str(),
            "DoesNotSupportRequestedMinBufferSize",
            "it has subscriber buffer 4,",
            "needs subscriber buffer >= 256",
        ] {
            assert!(text.contains(wanted), "{wanted:?} not in: {text}");
        }
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
