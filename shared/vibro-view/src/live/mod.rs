//! The live view's server (`vibrocomp view`): the Foxglove SDK's WebSocket server,
//! behind a guard that bounds what clients can cost it (issue 31, items 3 and 4).
//!
//! The SDK's server alone accepts every connection, waits for a WebSocket request
//! forever, takes frames of up to 16 MiB, stops accepting for good at the first failed
//! `accept` (a descriptor limit reached: nothing is logged, the process lives on), and
//! logs a line per bad message, unknown channel id and failed send. So the SDK listens
//! on an ephemeral port of 127.0.0.1, shut by a socket filter to all but the guard's
//! own connections (`inner`: the SDK binds its listener itself and takes no other),
//! and the guard ([`LiveServer`]) is the listener clients reach. Per connection it:
//!
//! - counts it against a cap ([`LiveOptions::max_clients`], lowered at start to what
//!   the descriptor limit allows: a viewer costs 3 descriptors). A connection beyond
//!   the cap takes the place of one that is not using it, or of one of the peer holding
//!   the most places when the newcomer's holds two fewer (`slots`); else it gets
//!   `503 Service Unavailable`;
//! - wants the HTTP upgrade request whole, within 16 KiB, and the SDK's answer within
//!   [`LiveOptions::handshake_timeout`] of the connection, before the SDK sees anything;
//!   a request offering `foxglove.websocket.v1` and none of the SDK's names for it is
//!   served as `foxglove.sdk.v1`, the same protocol (`upgrade`);
//! - pings the client at once and every [`LiveOptions::ping_interval`] (a Ping with a
//!   payload it cannot guess: answering it means reading what the view sent before
//!   it), and closes a client that has not answered within
//!   [`LiveOptions::pong_timeout`];
//! - follows the client's WebSocket frames by their headers ([`frames`]) and closes the
//!   connection at the header of a frame or message longer than
//!   [`LiveOptions::max_client_message_bytes`] (the protocol's client messages are
//!   JSON of a few hundred bytes), before its payload is read;
//! - relays through two 16 KiB buffers, and drops a client that takes none of the
//!   view's bytes for [`LiveOptions::stall_timeout`];
//! - when the client goes, tells the SDK with a Close frame (at a frame boundary) and
//!   reads what the SDK still sends, so that the SDK ends the connection as a client's
//!   close instead of failing a send per queued message.
//!
//! The accept loop survives a failed `accept`: out of descriptors, it closes the oldest
//! connection still without its request, else it backs off (10 ms doubling to 1 s) and
//! tries again. Should the SDK's own listener still end (a descriptor shortage caused
//! elsewhere in the process), the next connection finds its listener closed, and the
//! guard starts a new SDK server on the same context (its port shut as the first's),
//! says so, and carries on; the former one keeps the clients it has.
//!
//! The SDK and the guard run on a runtime of their own (one worker thread), whose
//! threads log through a [`LogLimiter`]: at most [`LiveOptions::log_burst`] lines per
//! source line per [`LiveOptions::log_period`], then one summary line with the count.
//!
//! ```no_run
//! # async fn f() -> vibro_view::Result<()> {
//! use vibro_view::live::{LiveOptions, LiveServer};
//! let ctx = foxglove::Context::new();
//! let live = LiveServer::start(
//!     &ctx,
//!     || foxglove::WebSocketServer::new().name("vibrocomp view"),
//!     LiveOptions::default(),
//! )
//! .await?;
//! println!("open ws://{}", live.local_addr());
//! let stats = live.stop().await;
//! # Ok(()) }
//! ```

pub mod frames;
mod front;
mod inner;
mod peer;
mod quiet;
mod slots;
mod upgrade;

pub use quiet::LogLimiter;
pub use upgrade::{SDK_V1, SDK_V1_1, WEBSOCKET_V1};

use crate::{Error, Result};
use serde::Serialize;
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

/// Where the live view listens unless told otherwise: this machine only.
pub const DEFAULT_LISTEN: SocketAddr =
    SocketAddr::new(std::net::IpAddr::V4(Ipv4Addr::LOCALHOST), 8765);

/// Viewers served at once unless told otherwise: a few people and tools per system.
pub const DEFAULT_MAX_CLIENTS: usize = 16;

/// Time a connection has for its WebSocket upgrade unless told otherwise (a client
/// sends its request at once; the SDK answers in a millisecond).
pub const DEFAULT_HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// The longest client message unless told otherwise, bytes. What a Foxglove client
/// sends the view is JSON: one `subscribe` to every view channel is about 1 KiB;
/// 64 KiB leaves room for clients that send more at once.
pub const DEFAULT_MAX_CLIENT_MESSAGE_BYTES: u64 = 64 * 1024;

/// Time a client may take none of the view's bytes unless told otherwise (the SDK
/// drops the oldest messages for a slow client meanwhile; past this, its place goes).
pub const DEFAULT_STALL_TIMEOUT: Duration = Duration::from_secs(30);

/// How often a client is pinged unless told otherwise (the first at once).
pub const DEFAULT_PING_INTERVAL: Duration = Duration::from_secs(5);

/// Time a client has to answer a ping unless told otherwise. A browser answers within
/// a round trip, whatever its page is doing; 10 s leaves room for a slow link and for a
/// client reading the view's backlog before it reaches the ping.
pub const DEFAULT_PONG_TIMEOUT: Duration = Duration::from_secs(10);

/// The longest a Pong may be owed before the connection owing it gives its place to a
/// newer one (at most the pong timeout): a client that reads answers within a round
/// trip.
pub const MAX_UNANSWERED_GRACE: Duration = Duration::from_secs(1);

/// Log lines let through per source line per period, and the period.
pub const DEFAULT_LOG_BURST: u32 = 5;
pub const DEFAULT_LOG_PERIOD: Duration = Duration::from_secs(10);

/// The longest HTTP request head taken (a browser's is 0.5-2 KiB, cookies included).
pub const MAX_REQUEST_HEAD_BYTES: usize = 16 * 1024;

/// Descriptors a viewer costs: its connection, the guard's to the SDK, the SDK's end.
const DESCRIPTORS_PER_CLIENT: u64 = 3;

/// Descriptors left to the rest of the process when the cap is fitted to the limit
/// (the iceoryx2 ports, a refusal's connection, a new SDK listener).
const DESCRIPTOR_HEADROOM: u64 = 32;

/// How the guard treats clients (the defaults above unless told otherwise).
#[derive(Debug, Clone, PartialEq)]
pub struct LiveOptions {
    /// The address clients connect to.
    pub listen: SocketAddr,
    /// Connections served at once, with or without their WebSocket request (at least 1).
    pub max_clients: usize,
    /// Time from the connection to the SDK's answer to its upgrade request.
    pub handshake_timeout: Duration,
    /// The longest message (or frame) a client may send, bytes.
    pub max_client_message_bytes: u64,
    /// Time a client may take none of the bytes the view has for it.
    pub stall_timeout: Duration,
    /// Time from one ping to the next (the first at once; none while one is owed; at
    /// least 100 ms).
    pub ping_interval: Duration,
    /// Time a client has to answer a ping (at least 1 ms).
    pub pong_timeout: Duration,
    /// Log lines let through per source line per [`LiveOptions::log_period`].
    pub log_burst: u32,
    pub log_period: Duration,
}

impl Default for LiveOptions {
    fn default() -> Self {
        Self {
            listen: DEFAULT_LISTEN,
            max_clients: DEFAULT_MAX_CLIENTS,
            handshake_timeout: DEFAULT_HANDSHAKE_TIMEOUT,
            max_client_message_bytes: DEFAULT_MAX_CLIENT_MESSAGE_BYTES,
            stall_timeout: DEFAULT_STALL_TIMEOUT,
            ping_interval: DEFAULT_PING_INTERVAL,
            pong_timeout: DEFAULT_PONG_TIMEOUT,
            log_burst: DEFAULT_LOG_BURST,
            log_period: DEFAULT_LOG_PERIOD,
        }
    }
}

/// What the guard did, since it started.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct LiveStats {
    /// The cap in force (the option, or less when the descriptor limit allows less).
    pub max_clients: usize,
    /// Connections taken (each counted once, whatever became of it).
    pub accepted: u64,
    /// Connections handed to the Foxglove server (their request complete).
    pub served: u64,
    /// Connections refused with 503: the cap reached by clients with their request.
    pub refused: u64,
    /// Connections closed while still without their request, for a newer one or for a
    /// descriptor.
    pub evicted: u64,
    /// WebSocket connections closed to let a newer one in: one that owed a Pong past
    /// the grace, or one of the peer holding the most places.
    pub displaced: u64,
    /// WebSocket connections closed for not answering a ping within the pong timeout.
    pub unanswered_pings: u64,
    /// Requests offering `foxglove.websocket.v1` and none of the SDK's names, served
    /// as `foxglove.sdk.v1`.
    pub websocket_v1_requests: u64,
    /// Connections closed for want of a complete upgrade within the timeout.
    pub handshake_timeouts: u64,
    /// Connections closed for a request head past 16 KiB or not HTTP.
    pub bad_requests: u64,
    /// Connections closed at a frame or message past the size cap.
    pub oversized: u64,
    /// Connections closed for taking no byte within the stall timeout.
    pub stalled: u64,
    /// Failed `accept` calls (out of descriptors, mostly); the listener went on.
    pub accept_errors: u64,
    /// New Foxglove servers started because the former one's listener had ended.
    pub server_restarts: u64,
    /// Log lines of the SDK and the guard left out by the rate limit (summarised).
    pub log_lines_left_out: u64,
}

#[derive(Debug, Default)]
struct Counters {
    accepted: AtomicU64,
    served: AtomicU64,
    refused: AtomicU64,
    evicted: AtomicU64,
    displaced: AtomicU64,
    unanswered_pings: AtomicU64,
    websocket_v1_requests: AtomicU64,
    handshake_timeouts: AtomicU64,
    bad_requests: AtomicU64,
    oversized: AtomicU64,
    stalled: AtomicU64,
    accept_errors: AtomicU64,
    server_restarts: AtomicU64,
}

impl Counters {
    fn add(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// Builds the Foxglove server (name, backlog, ...); the guard sets its context and
/// address.
type MakeServer = dyn Fn() -> foxglove::WebSocketServer + Send + Sync;

/// The SDK servers: the one new clients go to, and former ones still serving theirs.
struct Servers {
    addr: SocketAddr,
    current: Option<foxglove::WebSocketServerHandle>,
    former: Vec<foxglove::WebSocketServerHandle>,
}

/// What the guard's tasks share.
struct Shared {
    options: LiveOptions,
    max_clients: usize,
    ctx: Arc<foxglove::Context>,
    make_server: Box<MakeServer>,
    servers: Mutex<Servers>,
    /// Held while a new SDK server starts, so that one closed listener starts one.
    restarting: tokio::sync::Mutex<()>,
    /// The current SDK listener's filter and the ports it lets through.
    gate: Arc<Mutex<inner::Gate>>,
    counters: Counters,
}

/// Times an SDK server is replaced at start because connections reached its port
/// before the filter, before the guard gives up.
const MAX_TAINTED_STARTS: u32 = 3;

impl Shared {
    fn servers(&self) -> std::sync::MutexGuard<'_, Servers> {
        self.servers.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Starts an SDK server on an ephemeral port of 127.0.0.1 (on the current runtime,
    /// which its tasks then use), its port shut to all but the guard (`inner`): a
    /// server that connections reached before the filter is stopped and another started.
    async fn start_server(&self) -> Result<(SocketAddr, foxglove::WebSocketServerHandle)> {
        let mut tainted = 0;
        loop {
            let server = (self.make_server)()
                .context(&self.ctx)
                .bind(Ipv4Addr::LOCALHOST.to_string(), 0)
                .start()
                .await
                .map_err(Error::Server)?;
            let port = server.port();
            let shut = inner::Gate::adopt(&self.gate, port)
                .and_then(|()| inner::intruders(port))
                .map_err(|source| Error::Gate { port, source });
            match shut {
                Ok(0) => return Ok((SocketAddr::new(Ipv4Addr::LOCALHOST.into(), port), server)),
                Ok(n) if tainted + 1 < MAX_TAINTED_STARTS => {
                    tainted += 1;
                    tracing::warn!(
                        port,
                        "{n} connections reached the Foxglove server's port {port} before \
                         the guard shut it; stopping that server for a new one"
                    );
                    server.stop().wait().await;
                }
                Ok(n) => {
                    server.stop().wait().await;
                    return Err(Error::Gate {
                        port,
                        source: std::io::Error::other(format!(
                            "{n} connections reached it before the guard shut it, on \
                             {MAX_TAINTED_STARTS} servers in a row"
                        )),
                    });
                }
                Err(e) => {
                    server.stop().wait().await;
                    return Err(e);
                }
            }
        }
    }

    /// A connection to the SDK server, from a port its filter lets through, and that
    /// port's hold (to be dropped when the connection is done with); a new server first
    /// if the current one's listener has closed.
    async fn connect_server(&self) -> std::io::Result<(tokio::net::TcpStream, inner::Hold)> {
        let opening = match inner::Gate::open(&self.gate) {
            Ok(o) => o,
            Err(inner::OpenError::Gone { port }) => {
                self.restart_server(port).await?;
                inner::Gate::open(&self.gate).map_err(|e| match e {
                    inner::OpenError::Io(e) => e,
                    inner::OpenError::Gone { port } => std::io::Error::new(
                        std::io::ErrorKind::ConnectionRefused,
                        format!("the new Foxglove server's listener on port {port} closed"),
                    ),
                })?
            }
            Err(inner::OpenError::Io(e)) => return Err(e),
        };
        let inner::Opening {
            socket,
            addr,
            hold,
            listener,
        } = opening;
        let stream = socket.connect(addr).await;
        drop(listener);
        Ok((stream?, hold))
    }

    /// Replaces the server whose listener on `dead` (a port) closed, unless another
    /// connection did already.
    async fn restart_server(&self, dead: u16) -> std::io::Result<()> {
        let _one = self.restarting.lock().await;
        let current = self.servers().addr;
        if current.port() != dead {
            return Ok(());
        }
        let (addr, server) = self.start_server().await.map_err(std::io::Error::other)?;
        let idle = {
            let mut s = self.servers();
            s.addr = addr;
            if let Some(old) = s.current.replace(server) {
                s.former.push(old);
            }
            // Former servers keep their clients until these leave; one left with none
            // has nothing more to do.
            let (idle, busy): (Vec<_>, Vec<_>) =
                s.former.drain(..).partition(|f| f.client_count() == 0);
            s.former = busy;
            idle
        };
        for f in idle {
            f.stop().wait().await;
        }
        Counters::add(&self.counters.server_restarts);
        tracing::warn!(
            %current,
            %addr,
            "the Foxglove server's listener on {current} is closed; a new Foxglove server \
             serves new viewers from {addr}"
        );
        Ok(())
    }

    fn stats(&self, left_out: u64) -> LiveStats {
        let c = &self.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        LiveStats {
            max_clients: self.max_clients,
            accepted: get(&c.accepted),
            served: get(&c.served),
            refused: get(&c.refused),
            evicted: get(&c.evicted),
            displaced: get(&c.displaced),
            unanswered_pings: get(&c.unanswered_pings),
            websocket_v1_requests: get(&c.websocket_v1_requests),
            handshake_timeouts: get(&c.handshake_timeouts),
            bad_requests: get(&c.bad_requests),
            oversized: get(&c.oversized),
            stalled: get(&c.stalled),
            accept_errors: get(&c.accept_errors),
            server_restarts: get(&c.server_restarts),
            log_lines_left_out: left_out,
        }
    }
}

/// A Foxglove channel on `ctx` for each view topic of a triad with `units`
/// ([`crate::topics`]), with its protobuf schema, by topic.
pub fn channels(
    ctx: &Arc<foxglove::Context>,
    units: [&str; 3],
) -> Result<std::collections::BTreeMap<String, Arc<foxglove::RawChannel>>> {
    let mut out = std::collections::BTreeMap::new();
    for (topic, schema) in crate::topics(units) {
        let ch = ctx
            .channel_builder(topic.as_str())
            .message_encoding(vibro_mcap::MESSAGE_ENCODING)
            .schema(foxglove::Schema::new(
                schema.name,
                vibro_mcap::SCHEMA_ENCODING,
                schema.data,
            ))
            .build_raw()
            .map_err(|source| Error::Channel {
                topic: topic.clone(),
                source,
            })?;
        out.insert(topic, ch);
    }
    Ok(out)
}

/// The live view's server: the Foxglove SDK's server behind the guard (module docs).
/// Stop it with [`LiveServer::stop`]; dropped, it ends its tasks without waiting.
pub struct LiveServer {
    runtime: Option<tokio::runtime::Runtime>,
    local_addr: SocketAddr,
    shared: Arc<Shared>,
    limiter: LogLimiter,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    front: Option<tokio::task::JoinHandle<()>>,
    flusher: Option<tokio::task::JoinHandle<()>>,
}

impl std::fmt::Debug for LiveServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveServer")
            .field("local_addr", &self.local_addr)
            .field("options", &self.shared.options)
            .finish()
    }
}

impl LiveServer {
    /// Starts the SDK server that `make_server` builds, on `ctx`, behind the guard
    /// listening on `options.listen`.
    pub async fn start(
        ctx: &Arc<foxglove::Context>,
        make_server: impl Fn() -> foxglove::WebSocketServer + Send + Sync + 'static,
        options: LiveOptions,
    ) -> Result<Self> {
        let limiter = LogLimiter::new(options.log_burst, options.log_period);
        let runtime = {
            let l = limiter.clone();
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .thread_name("vibro-view-ws")
                .enable_all()
                .on_thread_start(move || l.enter_this_thread())
                .on_thread_stop(LogLimiter::leave_this_thread)
                .build()
                .map_err(Error::Runtime)?
        };
        let max_clients = fit_to_descriptors(options.max_clients.max(1));
        let listen = options.listen;
        let shared = Arc::new(Shared {
            options,
            max_clients,
            ctx: Arc::clone(ctx),
            make_server: Box::new(make_server),
            servers: Mutex::new(Servers {
                addr: SocketAddr::new(Ipv4Addr::LOCALHOST.into(), 0),
                current: None,
                former: Vec::new(),
            }),
            restarting: tokio::sync::Mutex::new(()),
            gate: Arc::new(Mutex::new(inner::Gate::default())),
            counters: Counters::default(),
        });
        let started = {
            let shared = Arc::clone(&shared);
            runtime.spawn(async move {
                let listener = tokio::net::TcpListener::bind(listen)
                    .await
                    .map_err(|source| Error::Listen {
                        addr: listen,
                        source,
                    })?;
                let local_addr = listener.local_addr().map_err(|source| Error::Listen {
                    addr: listen,
                    source,
                })?;
                let (addr, server) = shared.start_server().await?;
                let mut s = shared.servers();
                s.addr = addr;
                s.current = Some(server);
                Ok::<_, Error>((listener, local_addr, addr))
            })
        };
        // The runtime is shut down without waiting on every path out: dropping it here,
        // in an async context, would panic.
        let (listener, local_addr, server_addr) = match started.await {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => {
                runtime.shutdown_background();
                return Err(e);
            }
            Err(_) => {
                runtime.shutdown_background();
                return Err(Error::Task("start"));
            }
        };
        if max_clients < shared.options.max_clients {
            tracing::warn!(
                max_clients,
                "the live view serves at most {max_clients} viewers, not {}: the descriptor \
                 limit (RLIMIT_NOFILE) leaves no room for more (3 descriptors each)",
                shared.options.max_clients
            );
        }
        tracing::debug!(
            %local_addr,
            %server_addr,
            max_clients,
            "the live view's guard listens on {local_addr}, its Foxglove server on {server_addr}"
        );
        let (stop, stopped) = tokio::sync::oneshot::channel();
        let front = runtime.spawn(front::run(listener, Arc::clone(&shared), stopped));
        let flusher = {
            let l = limiter.clone();
            runtime.spawn(async move {
                let mut tick = tokio::time::interval(l.period());
                tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
                tick.tick().await;
                loop {
                    tick.tick().await;
                    l.flush();
                }
            })
        };
        Ok(Self {
            runtime: Some(runtime),
            local_addr,
            shared,
            limiter,
            stop: Some(stop),
            front: Some(front),
            flusher: Some(flusher),
        })
    }

    /// The address clients connect to (the port chosen when `listen` had port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// What the guard did so far.
    pub fn stats(&self) -> LiveStats {
        self.shared.stats(self.limiter.left_out())
    }

    /// Sends `status` to every client (of former SDK servers too).
    pub fn publish_status(&self, status: foxglove::websocket::Status) {
        let s = self.shared.servers();
        for server in s.current.iter().chain(&s.former) {
            server.publish_status(status.clone());
        }
    }

    /// Stops listening, closes every client's connection (the SDK's Close frame first)
    /// and the SDK servers, writes the log summaries still due, and returns what the
    /// guard did.
    pub async fn stop(mut self) -> LiveStats {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(front) = self.front.take() {
            if let Err(e) = front.await {
                tracing::debug!("the live view's guard ended abnormally: {e}");
            }
        }
        if let Some(f) = self.flusher.take() {
            f.abort();
        }
        self.limiter.flush();
        let stats = self.stats();
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
        stats
    }

    /// Stops the current SDK server (its listener then closes), as its listener's end
    /// would: the next client is to find a new one.
    #[cfg(test)]
    async fn end_server_listener(&self) {
        let server = self.shared.servers().current.take();
        if let Some(s) = server {
            let h = self.runtime.as_ref().map(|rt| rt.spawn(s.stop().wait()));
            if let Some(h) = h {
                let _ = h.await;
            }
        }
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

/// `wanted`, or fewer viewers when the descriptor limit leaves room for fewer (each
/// costs [`DESCRIPTORS_PER_CLIENT`], beside those open now and a headroom); at least 1.
fn fit_to_descriptors(wanted: usize) -> usize {
    let Some(limit) = descriptor_limit() else {
        return wanted;
    };
    let open = std::fs::read_dir("/proc/self/fd")
        .map(|d| d.count() as u64)
        .unwrap_or(0);
    let room = limit.saturating_sub(open + DESCRIPTOR_HEADROOM) / DESCRIPTORS_PER_CLIENT;
    wanted
        .min(usize::try_from(room).unwrap_or(usize::MAX))
        .max(1)
}

/// The soft limit on open descriptors, if there is one.
fn descriptor_limit() -> Option<u64> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the struct it is given, which lives for the call.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) } == 0;
    // `rlim_t` is u64 on Linux, narrower on some other systems.
    #[allow(clippy::unnecessary_cast)]
    let limit = r.rlim_cur as u64;
    (ok && r.rlim_cur != libc::RLIM_INFINITY).then_some(limit)
}

#[cfg(test)]
mod tests;
