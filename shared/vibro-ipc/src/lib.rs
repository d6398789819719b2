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
//! - **Refusals say why.** A service that exists with another payload type (another
//!   version of the message contracts), other quality of service, another iceoryx2
//!   version, or that belongs to another user is refused with an [`Error`] naming the
//!   service, what this process expected and what it found, instead of iceoryx2's bare
//!   error code. [`create_node`] refuses an iceoryx2 root directory of another user
//!   (README, "Who can publish and read: shared-memory permissions").
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

use std::time::Duration;

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
    /// The service exists with another payload type (type name, size or alignment):
    /// the two sides were built against different versions of the message contracts,
    /// or the other side is not vibrocomp's. iceoryx2 refuses to connect them.
    #[error("{service:?} carries {found}, but this process uses {expected}: one of the two was built against an incompatible version of the message contracts (this build's is version {schema}; docs/messages.md, \"Type names and versions\"). Rebuild the other side against the same version, or stop it")]
    IncompatibleType {
        service: String,
        /// This process's payload: type name, size and alignment.
        expected: String,
        /// The existing service's payload, as far as it could be read.
        found: String,
        schema: u32,
    },
    /// The service exists with quality-of-service settings this process cannot work with.
    #[error("{service:?} exists with other settings than this process needs (iceoryx2: {problem}): it has {found}; this process needs {needed}. Another program, or another version of vibrocomp, created it: stop that, or use another prefix")]
    IncompatibleSettings {
        service: String,
        problem: String,
        found: String,
        needed: String,
    },
    /// The service was created by a process using another iceoryx2 version.
    #[error("{service:?} was created with another iceoryx2 version than this process's {ours}: every participant (services, recorder, replay, rig bridges, the Python client) must use iceoryx2 {ours}")]
    IceoryxVersion { service: String, ours: &'static str },
    /// The iceoryx2 root directory belongs to another user: this process could not
    /// (another user) or must not (root, whose files the owner could not open) join
    /// the services there.
    #[error("{path}: the iceoryx2 resources here belong to {owner}, and this process runs as {me}: a process can publish into or read from only the services its own user started (iceoryx2 gives its files and shared memory to their owner alone). Run it as {owner}, or give each user an iceoryx2 root of its own (`root-path` in config/iceoryx2.toml); README, \"Who can publish and read: shared-memory permissions\"")]
    OtherUser {
        path: String,
        owner: String,
        me: String,
    },
    /// iceoryx2 was denied access to a service's files.
    #[error("{operation} on {service:?}: permission denied ({detail}): the service belongs to another user; README, \"Who can publish and read: shared-memory permissions\"")]
    Permission {
        operation: &'static str,
        service: String,
        detail: String,
    },
}

/// The iceoryx2 version every participant must use (pinned `=0.10.0` in the workspace
/// and in the Python client's requirements).
pub const ICEORYX2_VERSION: &str = "0.10.0";

/// Result of the transport.
pub type Result<T> = std::result::Result<T, Error>;

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

/// Log lines a late subscriber of `{prefix}log/{service}` receives on connecting.
pub const LOG_HISTORY: usize = 32;

/// The quality of service of each vibrocomp stream, the one place it is decided: every
/// participant (services, recorder, replay, rig bridges) opens a stream with this.
/// `estimate` keeps a history of 1, so a compensator that connects late receives the
/// latest estimate with the estimator's next publish; a log stream keeps its last
/// [`LOG_HISTORY`] lines; the rest use the defaults.
pub fn stream_config(stream: vibro_msgs::Stream) -> StreamConfig {
    match stream {
        vibro_msgs::Stream::Estimate => StreamConfig {
            history: 1,
            ..StreamConfig::default()
        },
        // A viewer or recorder that attaches later still gets the service's start-up
        // lines (the last 32).
        vibro_msgs::Stream::Log(_) => StreamConfig {
            history: LOG_HISTORY,
            ..StreamConfig::default()
        },
        _ => StreamConfig::default(),
    }
}

#[cfg(feature = "ipc")]
mod transport;
#[cfg(feature = "ipc")]
pub use transport::*;
