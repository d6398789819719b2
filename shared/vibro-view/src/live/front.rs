//! The guard's accept loop and its relay of each connection (the module above says
//! what they bound and why).

use super::frames::{self, FrameScanner};
use super::{Counters, Shared, MAX_REQUEST_HEAD_BYTES};
use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::oneshot;
use tokio::task::JoinSet;
use tokio::time::Instant;

/// Each direction's relay buffer, bytes.
const COPY_BUFFER_BYTES: usize = 16 * 1024;

/// The wait after a failed `accept` with nothing to close, first and longest.
const MIN_BACKOFF: Duration = Duration::from_millis(10);
const MAX_BACKOFF: Duration = Duration::from_secs(1);

/// The time a connection closed for a descriptor is given to close its socket.
const EVICTION_SETTLE: Duration = Duration::from_millis(5);

/// After a client leaves, the time the SDK has to end its side of the connection.
const LINGER: Duration = Duration::from_secs(1);

/// At stop, the time the connections have to end after the SDK's Close frames.
const STOP_GRACE: Duration = Duration::from_secs(2);

/// A last word to a client (a refusal, a Close frame): never waited for longer, nor
/// more of its bytes read and dropped meanwhile.
const LAST_WORD: Duration = Duration::from_millis(100);
const LAST_WORD_BYTES: usize = 256 * 1024;

/// The connections open, and those still without their request, oldest first, each
/// with the way to close it.
struct Slots {
    open: usize,
    waiting: VecDeque<(u64, SocketAddr, oneshot::Sender<()>)>,
    next_id: u64,
}

impl Slots {
    /// Closes the oldest connection still waiting for its request; which one, if any.
    fn evict_oldest(&mut self) -> Option<SocketAddr> {
        while let Some((_, peer, close)) = self.waiting.pop_front() {
            if close.send(()).is_ok() {
                return Some(peer);
            }
        }
        None
    }
}

fn lock(slots: &Mutex<Slots>) -> MutexGuard<'_, Slots> {
    slots.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A connection's place, given back when its task ends.
struct Slot {
    id: u64,
    slots: Arc<Mutex<Slots>>,
}

impl Slot {
    /// The connection has its request: it no longer gives its place to newer ones.
    fn arrived(&self) {
        lock(&self.slots)
            .waiting
            .retain(|(id, _, _)| *id != self.id);
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut s = lock(&self.slots);
        s.open = s.open.saturating_sub(1);
        s.waiting.retain(|(id, _, _)| *id != self.id);
    }
}

/// Whether a failed `accept` means the process (or system) is out of descriptors or
/// buffers, which closing a connection gives back.
fn out_of_descriptors(e: &std::io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::EMFILE | libc::ENFILE | libc::ENOBUFS | libc::ENOMEM)
    )
}

/// An HTTP response that closes the connection, with a text body.
fn http_response(status: &str, body: &str) -> Vec<u8> {
    format!(
        "HTTP/1.1 {status}\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\n\
         Connection: close\r\n\r\n{body}\n",
        body.len() + 1
    )
    .into_bytes()
}

/// Accepts clients until `stop`, then stops the SDK servers (each closes its clients'
/// connections with a Close frame, which the relays pass on) and ends the relays.
pub(super) async fn run(
    listener: TcpListener,
    shared: Arc<Shared>,
    mut stop: oneshot::Receiver<()>,
) {
    let slots = Arc::new(Mutex::new(Slots {
        open: 0,
        waiting: VecDeque::new(),
        next_id: 0,
    }));
    let mut conns = JoinSet::new();
    let mut backoff = MIN_BACKOFF;
    let refusal = http_response(
        "503 Service Unavailable",
        &format!(
            "vibrocomp view: {} viewers are connected, the most it serves; try again later",
            shared.max_clients
        ),
    );
    loop {
        // Connections closed to make room count until their task has ended (and closed
        // the socket): none is taken past the cap meanwhile, so that a flood of new
        // connections cannot outrun the closing of the old ones.
        while lock(&slots).open > shared.max_clients {
            tokio::task::yield_now().await;
            if lock(&slots).open > shared.max_clients {
                tokio::time::sleep(EVICTION_SETTLE).await;
            }
        }
        let accepted = tokio::select! {
            _ = &mut stop => break,
            Some(_) = conns.join_next(), if !conns.is_empty() => continue,
            r = listener.accept() => r,
        };
        match accepted {
            Ok((stream, peer)) => {
                backoff = MIN_BACKOFF;
                Counters::add(&shared.counters.accepted);
                admit(stream, peer, &shared, &slots, &mut conns, &refusal);
            }
            Err(e) => {
                Counters::add(&shared.counters.accept_errors);
                let evicted = if out_of_descriptors(&e) {
                    lock(&slots).evict_oldest()
                } else {
                    None
                };
                if let Some(old) = evicted {
                    Counters::add(&shared.counters.evicted);
                    tracing::warn!(
                        "accepting a viewer: {e}; closed the connection from {old}, still \
                         without its WebSocket request, to make room"
                    );
                    tokio::time::sleep(EVICTION_SETTLE).await;
                } else {
                    tracing::warn!(
                        "accepting a viewer: {e}; trying again in {} ms (the view keeps \
                         listening)",
                        backoff.as_millis()
                    );
                    tokio::select! {
                        _ = &mut stop => break,
                        () = tokio::time::sleep(backoff) => {}
                    }
                    backoff = (backoff * 2).min(MAX_BACKOFF);
                }
            }
        }
    }
    drop(listener);
    let servers: Vec<_> = {
        let mut s = shared.servers();
        s.current
            .take()
            .into_iter()
            .chain(s.former.drain(..))
            .collect()
    };
    for s in servers {
        s.stop().wait().await;
    }
    let _ = tokio::time::timeout(STOP_GRACE, async {
        while conns.join_next().await.is_some() {}
    })
    .await;
    conns.shutdown().await;
}

/// Gives `stream` a place (the place of the oldest connection still without its
/// request, at the cap) and its relay task, or refuses it with 503.
fn admit(
    stream: TcpStream,
    peer: SocketAddr,
    shared: &Arc<Shared>,
    slots: &Arc<Mutex<Slots>>,
    conns: &mut JoinSet<()>,
    refusal: &[u8],
) {
    let mut s = lock(slots);
    if s.open >= shared.max_clients {
        let Some(old) = s.evict_oldest() else {
            drop(s);
            Counters::add(&shared.counters.refused);
            tracing::warn!(
                "refused viewer {peer}: {} viewers are connected, the most the view serves",
                shared.max_clients
            );
            // A fresh connection's send buffer is empty: the write takes it whole or
            // the client is gone anyway.
            let _ = stream.try_write(refusal);
            return;
        };
        Counters::add(&shared.counters.evicted);
        tracing::warn!(
            "closed the connection from {old}, still without its WebSocket request, to let \
             {peer} in ({} connections, the most the view serves)",
            shared.max_clients
        );
    }
    s.open += 1;
    let id = s.next_id;
    s.next_id += 1;
    let (evict, evicted) = oneshot::channel();
    s.waiting.push_back((id, peer, evict));
    drop(s);
    let slot = Slot {
        id,
        slots: Arc::clone(slots),
    };
    conns.spawn(connection(stream, peer, Arc::clone(shared), slot, evicted));
}

/// Why a request head was not taken.
enum BadHead {
    TooLong,
    NotGet,
    Closed,
}

/// Reads the HTTP request head into `head` (with what follows it in the same reads);
/// where it ends.
async fn read_head(client: &mut TcpStream, head: &mut Vec<u8>) -> Result<usize, BadHead> {
    loop {
        let have = head.len();
        let room = (MAX_REQUEST_HEAD_BYTES - have).min(4096);
        head.resize(have + room, 0);
        let r = client.read(&mut head[have..]).await;
        let n = *r.as_ref().unwrap_or(&0);
        head.truncate(have + n);
        if n == 0 {
            return Err(BadHead::Closed);
        }
        if head.len() >= 4 && !head.starts_with(b"GET ") {
            return Err(BadHead::NotGet);
        }
        if let Some(end) = frames::head_end(head, have) {
            return Ok(end);
        }
        if head.len() >= MAX_REQUEST_HEAD_BYTES {
            return Err(BadHead::TooLong);
        }
    }
}

/// One client: its request within the handshake time (unless a newer connection takes
/// its place first), then the relay to a new connection to the SDK server.
async fn connection(
    mut client: TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    slot: Slot,
    evicted: oneshot::Receiver<()>,
) {
    let timeout = shared.options.handshake_timeout;
    let deadline = Instant::now() + timeout;
    let mut head = Vec::with_capacity(2048);
    let end = tokio::select! {
        _ = evicted => return,
        r = tokio::time::timeout_at(deadline, read_head(&mut client, &mut head)) => match r {
            Ok(Ok(end)) => end,
            Err(_) => {
                Counters::add(&shared.counters.handshake_timeouts);
                tracing::warn!(
                    "closed the connection from {peer}: no complete WebSocket request \
                     within {} s",
                    timeout.as_secs_f64()
                );
                let _ = client.try_write(&http_response("408 Request Timeout", "no request"));
                return;
            }
            Ok(Err(BadHead::Closed)) => {
                tracing::debug!("the connection from {peer} ended before its request");
                return;
            }
            Ok(Err(bad)) => {
                Counters::add(&shared.counters.bad_requests);
                let why = match bad {
                    BadHead::TooLong => format!("a request head over {MAX_REQUEST_HEAD_BYTES} bytes"),
                    _ => "not an HTTP GET request".to_string(),
                };
                tracing::warn!("closed the connection from {peer}: {why}");
                let _ = client.try_write(&http_response("400 Bad Request", &why));
                return;
            }
        }
    };
    slot.arrived();
    let server = match shared.connect_server().await {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!("viewer {peer}: the Foxglove server cannot be reached: {e}");
            let _ = client.try_write(&http_response(
                "503 Service Unavailable",
                "vibrocomp view: its Foxglove server cannot be reached",
            ));
            return;
        }
    };
    Counters::add(&shared.counters.served);
    let local = server
        .local_addr()
        .map_or_else(|_| "?".to_string(), |a| a.to_string());
    tracing::info!("viewer {peer} connected (the Foxglove server's client {local})");
    relay(client, server, &head, end, &shared, peer, deadline).await;
    drop(slot);
}

/// What ended a relay.
enum Ending {
    /// The client closed or failed.
    ClientGone,
    /// The SDK closed its side (it sent its Close frame first, or failed).
    ServerGone,
    /// The client sent a frame or message of this many bytes, past the cap.
    Oversized(u64),
    /// The client took none of the view's bytes within the stall timeout.
    Stalled,
    /// The SDK did not answer the request within the handshake time.
    NoAnswer,
}

/// Passes the client's `bytes` on to the SDK, whole frames only past a frame too long;
/// `clean` says afterwards whether what the SDK got ends on a frame boundary.
async fn pass_up(
    up: &mut FrameScanner,
    bytes: &[u8],
    sw: &mut OwnedWriteHalf,
    clean: &mut bool,
) -> Option<Ending> {
    let (pass, boundary, ending) = match up.feed(bytes) {
        Ok(()) => (bytes.len(), up.at_boundary(), None),
        // Cut at the long frame's header: a boundary if the header began in `bytes`.
        Err(o) => (
            o.at.unwrap_or(0),
            o.at.is_some(),
            Some(Ending::Oversized(o.bytes)),
        ),
    };
    if pass > 0 {
        *clean = false;
        if sw.write_all(&bytes[..pass]).await.is_err() {
            return Some(Ending::ServerGone);
        }
    }
    *clean = boundary;
    ending
}

/// Relays between the client and the SDK until one side ends or breaks a rule, then
/// ends both as the module above says.
async fn relay(
    client: TcpStream,
    server: TcpStream,
    head: &[u8],
    end: usize,
    shared: &Shared,
    peer: SocketAddr,
    deadline: Instant,
) {
    let options = &shared.options;
    let (mut cr, mut cw) = client.into_split();
    let (mut sr, mut sw) = server.into_split();
    let mut up = FrameScanner::new(options.max_client_message_bytes);
    let mut down = FrameScanner::new(u64::MAX);
    // Whether what each side got so far ends between two frames (a Close may follow).
    let (mut up_clean, mut down_clean) = (true, true);
    let ending = 'relay: {
        if sw.write_all(&head[..end]).await.is_err() {
            break 'relay Ending::ServerGone;
        }
        if end < head.len() {
            if let Some(e) = pass_up(&mut up, &head[end..], &mut sw, &mut up_clean).await {
                break 'relay e;
            }
        }
        let to_server = async {
            let mut buf = vec![0; COPY_BUFFER_BYTES];
            loop {
                let n = match cr.read(&mut buf).await {
                    Ok(0) | Err(_) => return Ending::ClientGone,
                    Ok(n) => n,
                };
                if let Some(e) = pass_up(&mut up, &buf[..n], &mut sw, &mut up_clean).await {
                    return e;
                }
            }
        };
        let to_client = async {
            let mut buf = vec![0; COPY_BUFFER_BYTES];
            // The SDK's HTTP answer, then frames.
            let mut answer = frames::HeadEnd::default();
            let mut in_answer = true;
            let mut answered = false;
            loop {
                let r = if answered {
                    sr.read(&mut buf).await
                } else {
                    match tokio::time::timeout_at(deadline, sr.read(&mut buf)).await {
                        Ok(r) => r,
                        Err(_) => return Ending::NoAnswer,
                    }
                };
                let n = match r {
                    Ok(0) | Err(_) => return Ending::ServerGone,
                    Ok(n) => n,
                };
                answered = true;
                down_clean = false;
                match tokio::time::timeout(options.stall_timeout, cw.write_all(&buf[..n])).await {
                    Ok(Ok(())) => {}
                    Ok(Err(_)) => return Ending::ClientGone,
                    Err(_) => return Ending::Stalled,
                }
                let frames_from = if in_answer {
                    match answer.feed(&buf[..n]) {
                        Some(e) => {
                            in_answer = false;
                            e
                        }
                        None => n,
                    }
                } else {
                    0
                };
                // Never fails: no cap on what the SDK sends.
                let _ = down.feed(&buf[frames_from..n]);
                down_clean = !in_answer && down.at_boundary();
            }
        };
        tokio::select! {
            e = to_server => e,
            e = to_client => e,
        }
    };
    match ending {
        Ending::ServerGone => {
            // The SDK ended the connection: the client learns it from the closed socket.
            let _ = tokio::time::timeout(LAST_WORD, cw.shutdown()).await;
            return;
        }
        Ending::ClientGone => tracing::debug!("viewer {peer} left"),
        Ending::Oversized(bytes) => {
            Counters::add(&shared.counters.oversized);
            let cap = options.max_client_message_bytes;
            tracing::warn!(
                "closed viewer {peer}: it sent a message of {bytes} bytes, past the view's \
                 cap of {cap} bytes"
            );
            if down_clean {
                let close = frames::server_close_frame(
                    1009,
                    &format!("message of {bytes} bytes, past the cap of {cap} bytes"),
                );
                // The Close, the end of the stream, then what the client still sends is
                // read and dropped a moment: closing with its bytes unread would reset
                // the connection, and the client might lose the Close. Not for long:
                // the rest of a long message is reset.
                let _ = tokio::time::timeout(LAST_WORD, async {
                    cw.write_all(&close).await?;
                    cw.shutdown().await?;
                    let mut buf = vec![0; COPY_BUFFER_BYTES];
                    let mut left = LAST_WORD_BYTES;
                    while left > 0 {
                        match cr.read(&mut buf).await? {
                            0 => break,
                            n => left = left.saturating_sub(n),
                        }
                    }
                    std::io::Result::Ok(())
                })
                .await;
            }
        }
        Ending::Stalled => {
            Counters::add(&shared.counters.stalled);
            tracing::warn!(
                "closed viewer {peer}: it took none of the view's bytes for {} s",
                options.stall_timeout.as_secs_f64()
            );
        }
        Ending::NoAnswer => {
            Counters::add(&shared.counters.handshake_timeouts);
            tracing::warn!(
                "closed viewer {peer}: the Foxglove server did not answer its request within {} s",
                options.handshake_timeout.as_secs_f64()
            );
        }
    }
    drop((cr, cw));
    linger(sr, sw, up_clean).await;
}

/// Tells the SDK the client is gone: a client's Close frame where a frame may start
/// (else the bare end of the connection), then reads and drops what the SDK still
/// sends until it closes, so that it never fails a send (a log line each).
async fn linger(mut sr: OwnedReadHalf, mut sw: OwnedWriteHalf, clean: bool) {
    let _ = tokio::time::timeout(LINGER, async {
        if clean {
            let _ = sw.write_all(&frames::client_close_frame(1001)).await;
        } else {
            let _ = sw.shutdown().await;
        }
        let mut buf = vec![0; COPY_BUFFER_BYTES];
        while matches!(sr.read(&mut buf).await, Ok(n) if n > 0) {}
    })
    .await;
}
