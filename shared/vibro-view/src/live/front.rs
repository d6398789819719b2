//! The guard's accept loop and its relay of each connection (the module above says
//! what they bound and why).

use super::frames::{self, FrameScanner};
use super::peer;
use super::slots::{lock, Admission, Displacement, Slot, Slots};
use super::upgrade;
use super::{Counters, Shared, MAX_REQUEST_HEAD_BYTES, MAX_UNANSWERED_GRACE};
use std::borrow::Cow;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
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

/// The shortest time between pings, whatever the options say (a client answers each
/// within a round trip: without it, a zero interval would ping without pause).
const MIN_PING_INTERVAL: Duration = Duration::from_millis(100);

/// Close codes (RFC 6455 §7.4.1, and IANA's registry for 1013).
const CLOSE_POLICY: u16 = 1008;
const CLOSE_TOO_BIG: u16 = 1009;
const CLOSE_TRY_AGAIN_LATER: u16 = 1013;

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
    let slots = Arc::new(Mutex::new(Slots::default()));
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
        while lock(&slots).open() > shared.max_clients {
            tokio::task::yield_now().await;
            if lock(&slots).open() > shared.max_clients {
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
                    lock(&slots).evict_waiting()
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

/// Gives `stream` a place (at the cap, another connection's, as [`super::slots`]
/// says) and its relay task, or refuses it with 503.
fn admit(
    stream: TcpStream,
    peer: SocketAddr,
    shared: &Arc<Shared>,
    slots: &Arc<Mutex<Slots>>,
    conns: &mut JoinSet<()>,
    refusal: &[u8],
) {
    let max = shared.max_clients;
    let key = peer::key(peer, stream.local_addr().unwrap_or(peer));
    let grace = shared.options.pong_timeout.min(MAX_UNANSWERED_GRACE);
    let admission = lock(slots).admit(peer, key, max, Instant::now(), grace);
    let Admission::Admitted {
        id,
        closed,
        displaced,
    } = admission
    else {
        Counters::add(&shared.counters.refused);
        tracing::warn!(
            "refused viewer {peer} ({key}): the {max} places, the most the view serves, are \
             held by viewers that answer their pings or were pinged less than {} s ago",
            grace.as_secs_f64()
        );
        // A fresh connection's send buffer is empty: the write takes it whole or
        // the client is gone anyway.
        let _ = stream.try_write(refusal);
        return;
    };
    match displaced {
        None => {}
        Some((old, _, Displacement::NoRequest)) => {
            Counters::add(&shared.counters.evicted);
            tracing::warn!(
                "closed the connection from {old}, still without its WebSocket request, to \
                 let {peer} in ({max} connections, the most the view serves)"
            );
        }
        Some((old, old_key, Displacement::Unanswered(owed))) => {
            Counters::add(&shared.counters.displaced);
            tracing::warn!(
                "closed viewer {old} ({old_key}): it has not answered a ping sent {:.1} s \
                 ago; its place goes to {peer} ({key})",
                owed.as_secs_f64()
            );
        }
        Some((old, old_key, Displacement::Share { held, theirs })) => {
            Counters::add(&shared.counters.displaced);
            tracing::warn!(
                "closed viewer {old}: {old_key} held {held} of the {max} places and \
                 {key} {theirs}; its place goes to {peer}"
            );
        }
    }
    let slot = Slot {
        id,
        slots: Arc::clone(slots),
    };
    conns.spawn(connection(stream, peer, Arc::clone(shared), slot, closed));
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
    mut closed: oneshot::Receiver<Displacement>,
) {
    let timeout = shared.options.handshake_timeout;
    let deadline = Instant::now() + timeout;
    let mut head = Vec::with_capacity(2048);
    let end = tokio::select! {
        _ = &mut closed => return,
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
    if !slot.upgrading() {
        return;
    }
    let (request, alias) = upgrade::request_for_sdk(&head[..end]);
    if alias {
        Counters::add(&shared.counters.websocket_v1_requests);
    }
    let (server, hold) = match shared.connect_server().await {
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
    let to_sdk = Upgrade {
        request: &request,
        rest: &head[end..],
        alias,
    };
    relay(
        client,
        server,
        to_sdk,
        &shared,
        peer,
        deadline,
        &slot,
        &mut closed,
    )
    .await;
    // The port leaves the filter before the socket holding it closes (the hold keeps a
    // duplicate of it).
    drop(hold);
    drop(slot);
}

/// What the SDK is to get of a client's upgrade: its request as the SDK is to take it
/// ([`upgrade::request_for_sdk`]), the client's bytes after it, and whether the SDK's
/// answer is to name `foxglove.websocket.v1`.
struct Upgrade<'a> {
    request: &'a [u8],
    rest: &'a [u8],
    alias: bool,
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
    /// The client did not answer a ping within the pong timeout.
    Unanswered,
    /// The client's place went to a newer connection.
    Displaced(Displacement),
}

/// A ping the client owes a Pong for: its payload and when it was sent.
#[derive(Debug, Clone, Copy)]
struct Ping {
    nonce: [u8; 8],
    sent: Instant,
}

/// A ping payload no client can tell without reading the Ping: SipHash (std's
/// `RandomState`, keyed at random per thread and per instance) of a counter.
fn nonce() -> [u8; 8] {
    use std::hash::{BuildHasher, Hasher};
    static COUNT: AtomicU64 = AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(COUNT.fetch_add(1, Ordering::Relaxed));
    h.finish().to_le_bytes()
}

/// Sends the client a ping (owed from now, in `owed` and in its slot); when it was sent.
async fn send_ping(
    cw: &mut OwnedWriteHalf,
    owed: &Mutex<Option<Ping>>,
    slot: &Slot,
    stall: Duration,
) -> Result<Instant, Ending> {
    let ping = Ping {
        nonce: nonce(),
        sent: Instant::now(),
    };
    // Owed before it is written: its Pong may come back first.
    *owed.lock().unwrap_or_else(PoisonError::into_inner) = Some(ping);
    slot.pinged(ping.sent);
    let frame = frames::server_ping_frame(&ping.nonce);
    match to_client_within(cw, &frame, stall).await {
        Some(e) => Err(e),
        None => Ok(ping.sent),
    }
}

/// Writes `bytes` to the client, unless it takes none of them for `stall`.
async fn to_client_within(
    cw: &mut OwnedWriteHalf,
    bytes: &[u8],
    stall: Duration,
) -> Option<Ending> {
    match tokio::time::timeout(stall, cw.write_all(bytes)).await {
        Ok(Ok(())) => None,
        Ok(Err(_)) => Some(Ending::ClientGone),
        Err(_) => Some(Ending::Stalled),
    }
}

/// [`to_client_within`], unless the client still owes the Pong of the ping in `owed`
/// when its `pong_timeout` is up, or, owing none, takes none of these bytes within the
/// pong timeout of `ping_due` (the next ping, which cannot go before them): a client
/// that reads nothing is closed then, whether or not the view has bytes for it.
async fn to_client_by_pong(
    cw: &mut OwnedWriteHalf,
    bytes: &[u8],
    stall: Duration,
    owed: &Mutex<Option<Ping>>,
    ping_due: Instant,
    pong_timeout: Duration,
) -> Option<Ending> {
    let answer_by = || {
        owed.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .map_or(ping_due, |p| p.sent)
            + pong_timeout
    };
    let write = to_client_within(cw, bytes, stall);
    tokio::pin!(write);
    let mut by = answer_by();
    loop {
        tokio::select! {
            // A write the client takes at once goes, whatever the time.
            biased;
            r = &mut write => return r,
            () = tokio::time::sleep_until(by) => {
                // Only an answer changes what is owed while this write lasts.
                let now = answer_by();
                if now == by {
                    return Some(Ending::Unanswered);
                }
                by = now;
            }
        }
    }
}

/// A Close frame with `code` and `reason` to the client, the end of the stream, then
/// what the client still sends read and dropped a moment: closing with its bytes unread
/// would reset the connection, and the client might lose the Close. Not for long: the
/// rest of a long message is reset.
async fn last_word(cw: &mut OwnedWriteHalf, cr: &mut OwnedReadHalf, code: u16, reason: &str) {
    let close = frames::server_close_frame(code, reason);
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

/// Passes the client's `bytes` on to the SDK, whole frames only past a frame too long,
/// and the payload of each Pong among them to `on_pong`; `clean` says afterwards whether
/// what the SDK got ends on a frame boundary. (The SDK takes the Pongs too, and ignores
/// them.)
async fn pass_up(
    up: &mut FrameScanner,
    bytes: &[u8],
    sw: &mut OwnedWriteHalf,
    clean: &mut bool,
    on_pong: impl Fn(&[u8]),
) -> Option<Ending> {
    let (pass, boundary, ending) = match up.feed_pongs(bytes, on_pong) {
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

/// Relays between the client and the SDK until one side ends or breaks a rule (or the
/// client's place goes to a newer connection), then ends both as the module above says.
/// Pings the client once the SDK has answered its upgrade, as [`super::LiveOptions`]
/// says.
// One connection's parts, each used once: a struct would only rename them.
#[allow(clippy::too_many_arguments)]
async fn relay(
    client: TcpStream,
    server: TcpStream,
    to_sdk: Upgrade<'_>,
    shared: &Shared,
    peer: SocketAddr,
    deadline: Instant,
    slot: &Slot,
    closed: &mut oneshot::Receiver<Displacement>,
) {
    let options = &shared.options;
    let stall = options.stall_timeout;
    let pong_timeout = options.pong_timeout.max(Duration::from_millis(1));
    let ping_interval = options.ping_interval.max(MIN_PING_INTERVAL);
    let (mut cr, mut cw) = client.into_split();
    let (mut sr, mut sw) = server.into_split();
    let mut up = FrameScanner::new(options.max_client_message_bytes);
    let mut down = FrameScanner::new(u64::MAX);
    // Whether what each side got so far ends between two frames (a Close may follow).
    let (mut up_clean, mut down_clean) = (true, true);
    let owed: Mutex<Option<Ping>> = Mutex::new(None);
    let owed_now = || *owed.lock().unwrap_or_else(PoisonError::into_inner);
    // A Pong with the payload of the ping owed answers it.
    let on_pong = |payload: &[u8]| {
        let mut o = owed.lock().unwrap_or_else(PoisonError::into_inner);
        if o.is_some_and(|p| p.nonce[..] == *payload) {
            *o = None;
            drop(o);
            slot.answered();
        }
    };
    let ending = 'relay: {
        if sw.write_all(to_sdk.request).await.is_err() {
            break 'relay Ending::ServerGone;
        }
        if !to_sdk.rest.is_empty() {
            let e = pass_up(&mut up, to_sdk.rest, &mut sw, &mut up_clean, on_pong).await;
            if let Some(e) = e {
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
                if let Some(e) = pass_up(&mut up, &buf[..n], &mut sw, &mut up_clean, on_pong).await
                {
                    return e;
                }
            }
        };
        let to_client = async {
            let mut buf = vec![0; COPY_BUFFER_BYTES];
            // The SDK's answer head whole, within the handshake time.
            let mut answer = Vec::with_capacity(1024);
            let mut scan = frames::HeadEnd::default();
            let end = loop {
                let n = match tokio::time::timeout_at(deadline, sr.read(&mut buf)).await {
                    Err(_) => return Ending::NoAnswer,
                    Ok(Ok(0) | Err(_)) => return Ending::ServerGone,
                    Ok(Ok(n)) => n,
                };
                let found = scan.feed(&buf[..n]);
                let from = answer.len();
                answer.extend_from_slice(&buf[..n]);
                if let Some(e) = found {
                    break from + e;
                }
                if answer.len() > MAX_REQUEST_HEAD_BYTES {
                    // Not an HTTP answer: the SDK's is a few hundred bytes.
                    return Ending::ServerGone;
                }
            };
            let upgraded = answer.starts_with(b"HTTP/1.1 101 ");
            let head = if to_sdk.alias && upgraded {
                Cow::Owned(upgrade::answer_for_client(&answer[..end]))
            } else {
                Cow::Borrowed(&answer[..end])
            };
            down_clean = false;
            for bytes in [&head[..], &answer[end..]] {
                if let Some(e) = to_client_within(&mut cw, bytes, stall).await {
                    return e;
                }
            }
            if !upgraded {
                // A refusal (400 for a subprotocol the SDK does not know): its body,
                // until the SDK closes.
                loop {
                    let n = match sr.read(&mut buf).await {
                        Ok(0) | Err(_) => return Ending::ServerGone,
                        Ok(n) => n,
                    };
                    if let Some(e) = to_client_within(&mut cw, &buf[..n], stall).await {
                        return e;
                    }
                }
            }
            // Never fails: no cap on what the SDK sends.
            let _ = down.feed(&answer[end..]);
            down_clean = down.at_boundary();
            slot.live();
            let mut next_ping = Instant::now();
            let mut ping_due = false;
            loop {
                let owed_since = owed_now().map(|p| p.sent);
                let answer_by = owed_since.map_or(next_ping, |s| s + pong_timeout);
                tokio::select! {
                    r = sr.read(&mut buf) => {
                        let n = match r {
                            Ok(0) | Err(_) => return Ending::ServerGone,
                            Ok(n) => n,
                        };
                        // Never fails: no cap on what the SDK sends.
                        let _ = down.feed(&buf[..n]);
                        // A ping due goes in after the first frame that ends in these
                        // bytes, so that a busy stream does not hold it back.
                        let cut = if ping_due {
                            down.first_frame_end().filter(|&e| e < n)
                        } else {
                            None
                        };
                        down_clean = false;
                        let (first, rest) = buf[..n].split_at(cut.unwrap_or(n));
                        let wrote =
                            to_client_by_pong(&mut cw, first, stall, &owed, next_ping, pong_timeout)
                                .await;
                        if let Some(e) = wrote {
                            return e;
                        }
                        if cut.is_some() {
                            match send_ping(&mut cw, &owed, slot, stall).await {
                                Ok(sent) => {
                                    ping_due = false;
                                    next_ping = sent + ping_interval;
                                }
                                Err(e) => return e,
                            }
                            let wrote = to_client_by_pong(
                                &mut cw,
                                rest,
                                stall,
                                &owed,
                                next_ping,
                                pong_timeout,
                            )
                            .await;
                            if let Some(e) = wrote {
                                return e;
                            }
                        }
                        down_clean = down.at_boundary();
                    }
                    () = tokio::time::sleep_until(next_ping), if owed_since.is_none() && !ping_due => {
                        ping_due = true;
                    }
                    () = tokio::time::sleep_until(answer_by), if owed_since.is_some() => {
                        if owed_now().map(|p| p.sent) == owed_since {
                            return Ending::Unanswered;
                        }
                    }
                }
                // A ping goes between two of the SDK's frames.
                if ping_due && down_clean {
                    match send_ping(&mut cw, &owed, slot, stall).await {
                        Ok(sent) => {
                            ping_due = false;
                            next_ping = sent + ping_interval;
                        }
                        Err(e) => return e,
                    }
                }
            }
        };
        tokio::select! {
            e = to_server => e,
            e = to_client => e,
            why = &mut *closed => why.map_or(Ending::ClientGone, Ending::Displaced),
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
                let why = format!("message of {bytes} bytes, past the cap of {cap} bytes");
                last_word(&mut cw, &mut cr, CLOSE_TOO_BIG, &why).await;
            }
        }
        Ending::Stalled => {
            Counters::add(&shared.counters.stalled);
            tracing::warn!(
                "closed viewer {peer}: it took none of the view's bytes for {} s",
                stall.as_secs_f64()
            );
        }
        Ending::NoAnswer => {
            Counters::add(&shared.counters.handshake_timeouts);
            tracing::warn!(
                "closed viewer {peer}: the Foxglove server did not answer its request within {} s",
                options.handshake_timeout.as_secs_f64()
            );
        }
        Ending::Unanswered => {
            Counters::add(&shared.counters.unanswered_pings);
            let s = pong_timeout.as_secs_f64();
            tracing::warn!(
                "closed viewer {peer}: it did not answer a ping (or take the view's bytes \
                 before it) within {s} s"
            );
            if down_clean {
                let why = format!("no answer to a ping within {s} s");
                last_word(&mut cw, &mut cr, CLOSE_POLICY, &why).await;
            }
        }
        // Counted and logged when its place was given.
        Ending::Displaced(why) => {
            if down_clean {
                let (code, reason) = match why {
                    Displacement::Share { .. } => (
                        CLOSE_TRY_AGAIN_LATER,
                        "its place went to a viewer from a peer holding fewer",
                    ),
                    _ => (
                        CLOSE_POLICY,
                        "no answer to a ping; its place went to a newer viewer",
                    ),
                };
                last_word(&mut cw, &mut cr, code, reason).await;
            }
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
