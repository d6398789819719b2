//! The guard in-process, with a real Foxglove SDK server behind it and clients of the
//! SDK's own WebSocket library (tungstenite) or raw sockets.

use super::*;
use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Instant;
use tungstenite::client::IntoClientRequest as _;
use tungstenite::Message as WsMessage;

type Ws = tungstenite::WebSocket<TcpStream>;

/// A view: the view channels on a context, the guard with `options` (on a free port
/// of 127.0.0.1) and the runtime the test awaits it on.
struct View {
    rt: tokio::runtime::Runtime,
    live: Option<LiveServer>,
    channels: BTreeMap<String, Arc<foxglove::RawChannel>>,
    _ctx: Arc<foxglove::Context>,
}

impl View {
    fn start(options: LiveOptions) -> Self {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let ctx = foxglove::Context::new();
        let channels = channels(&ctx, crate::UNIT_NAMES).unwrap();
        let options = LiveOptions {
            listen: "127.0.0.1:0".parse().unwrap(),
            ..options
        };
        let live = rt
            .block_on(LiveServer::start(
                &ctx,
                || foxglove::WebSocketServer::new().name("test view"),
                options,
            ))
            .unwrap();
        Self {
            rt,
            live: Some(live),
            channels,
            _ctx: ctx,
        }
    }

    fn live(&self) -> &LiveServer {
        self.live.as_ref().unwrap()
    }

    fn addr(&self) -> SocketAddr {
        self.live().local_addr()
    }

    /// Logs `n` messages of `bytes` bytes on `/view/AK1`.
    fn publish(&self, n: usize, bytes: usize) {
        let data = vec![7u8; bytes];
        for _ in 0..n {
            self.channels["/view/AK1"].log(&data);
        }
    }

    fn stop(mut self) -> LiveStats {
        let live = self.live.take().unwrap();
        self.rt.block_on(live.stop())
    }
}

/// A Foxglove client past its handshake (subprotocol `foxglove.sdk.v1`), `serverInfo`
/// and the advertisement of every view channel read: the socket, the channel ids by
/// topic.
fn foxglove_client(addr: SocketAddr) -> std::result::Result<(Ws, BTreeMap<String, u64>), String> {
    let stream = TcpStream::connect(addr).map_err(|e| e.to_string())?;
    let (ws, _) = upgrade(stream, addr, "foxglove.sdk.v1").map_err(|e| e.to_string())?;
    read_advertised(ws)
}

/// A WebSocket upgrade on `stream` offering `offer` (one header's value, as a browser
/// sends the list it is given), by tungstenite (which fails an answer naming a
/// subprotocol not offered): the socket and the subprotocol the answer names.
fn upgrade(
    stream: TcpStream,
    addr: SocketAddr,
    offer: &str,
) -> std::result::Result<(Ws, Option<String>), tungstenite::Error> {
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut req = format!("ws://{addr}").into_client_request().unwrap();
    req.headers_mut().insert(
        "sec-websocket-protocol",
        tungstenite::http::HeaderValue::from_str(offer).unwrap(),
    );
    let (ws, resp) = tungstenite::client(req, stream).map_err(|e| match e {
        tungstenite::HandshakeError::Failure(e) => e,
        tungstenite::HandshakeError::Interrupted(_) => {
            tungstenite::Error::Io(std::io::ErrorKind::WouldBlock.into())
        }
    })?;
    assert_eq!(resp.status(), 101);
    let protocol = resp
        .headers()
        .get("sec-websocket-protocol")
        .map(|v| v.to_str().unwrap().to_string());
    Ok((ws, protocol))
}

/// Reads `serverInfo` and the advertisement of every view channel: the socket, the
/// channel ids by topic.
fn read_advertised(mut ws: Ws) -> std::result::Result<(Ws, BTreeMap<String, u64>), String> {
    let wanted = crate::topics(crate::UNIT_NAMES).len();
    let mut ids = BTreeMap::new();
    let mut info = false;
    while !info || ids.len() < wanted {
        if let WsMessage::Text(t) = ws.read().map_err(|e| e.to_string())? {
            let v: serde_json::Value = serde_json::from_str(&t).unwrap();
            match v["op"].as_str() {
                Some("serverInfo") => info = true,
                Some("advertise") => {
                    for c in v["channels"].as_array().unwrap() {
                        ids.insert(
                            c["topic"].as_str().unwrap().to_string(),
                            c["id"].as_u64().unwrap(),
                        );
                    }
                }
                _ => {}
            }
        }
    }
    Ok((ws, ids))
}

/// [`foxglove_client`], tried again while refused (a place is given back once the
/// connection that held it has ended on both sides).
fn foxglove_client_within(addr: SocketAddr, within: Duration) -> (Ws, BTreeMap<String, u64>) {
    let t0 = Instant::now();
    loop {
        match foxglove_client(addr) {
            Ok(c) => return c,
            Err(e) if t0.elapsed() < within => {
                eprintln!("trying again: {e}");
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => panic!("not served within {within:?}: {e}"),
        }
    }
}

/// Subscribes to `channel` as subscription 1, and reads until a message of it comes
/// (the view publishing `/view/AK1` meanwhile); its payload.
fn first_message(view: &View, ws: &mut Ws, channel: u64) -> Vec<u8> {
    let sub = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [{"id": 1, "channelId": channel}],
    });
    ws.send(WsMessage::text(sub.to_string())).unwrap();
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(10) {
        view.publish(1, 40);
        match ws.read() {
            Ok(WsMessage::Binary(b)) if b[0] == 1 => {
                assert_eq!(u32::from_le_bytes(b[1..5].try_into().unwrap()), 1);
                return b[13..].to_vec();
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => panic!("{e}"),
        }
    }
    panic!("no message on channel {channel} within 10 s");
}

/// Reads what `s` gets until it closes (or 5 s).
fn read_to_end(mut s: TcpStream) -> Vec<u8> {
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut got = Vec::new();
    let _ = s.read_to_end(&mut got);
    got
}

/// A client of Foxglove's protocol is served through the guard as by the SDK alone:
/// the subprotocol, `serverInfo`, every view channel advertised, a subscription's
/// messages with their payload.
#[test]
fn a_foxglove_client_is_served_through_the_guard() {
    let view = View::start(LiveOptions::default());
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    assert_eq!(ids.len(), crate::topics(crate::UNIT_NAMES).len());
    let payload = first_message(&view, &mut ws, ids["/view/AK1"]);
    assert_eq!(payload, [7; 40]);
    ws.close(None).unwrap();
    drop(ws);
    let stats = view.stop();
    assert_eq!((stats.accepted, stats.served), (1, 1), "{stats:?}");
    assert_eq!(stats.max_clients, DEFAULT_MAX_CLIENTS);
}

/// When the SDK server's listener has ended (as it does at its first failed `accept`),
/// the next client finds its port refused: the guard starts a new SDK server on the
/// same channels and serves the client from it, and says so in its counts.
#[test]
fn a_new_sdk_server_takes_over_when_the_listener_of_the_former_ends() {
    let view = View::start(LiveOptions::default());
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    first_message(&view, &mut ws, ids["/view/AK1"]);
    view.rt.block_on(view.live().end_server_listener());
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    assert_eq!(first_message(&view, &mut ws, ids["/view/AK1"]), [7; 40]);
    let (_ws2, _) = foxglove_client(view.addr()).unwrap();
    let stats = view.stop();
    assert_eq!(stats.server_restarts, 1, "{stats:?}");
    assert_eq!(stats.served, 3, "{stats:?}");
}

/// Reads until the guard's first Ping has come and answers it (tungstenite queues the
/// Pong, the flush sends it).
fn answer_first_ping(ws: &mut Ws) {
    loop {
        if let WsMessage::Ping(_) = ws.read().unwrap() {
            ws.flush().unwrap();
            return;
        }
    }
}

/// At the cap, a new connection takes the place of the oldest one still without its
/// request (which is closed); when every place has a client past its request that
/// answers its pings, the new one is refused with 503 and the cap in the body.
#[test]
fn at_the_cap_idle_connections_give_way_and_then_clients_are_refused() {
    let view = View::start(LiveOptions {
        max_clients: 2,
        ..LiveOptions::default()
    });
    let idle = TcpStream::connect(view.addr()).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    let (mut a, _) = foxglove_client(view.addr()).unwrap();
    let (mut b, ids) = foxglove_client(view.addr()).unwrap();
    answer_first_ping(&mut a);
    answer_first_ping(&mut b);
    assert!(
        read_to_end(idle).is_empty(),
        "the idle connection is closed"
    );
    let mut refused = TcpStream::connect(view.addr()).unwrap();
    let _ = refused.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n");
    let answer = String::from_utf8_lossy(&read_to_end(refused)).to_string();
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    assert!(answer.contains("2 viewers are connected"), "{answer}");
    first_message(&view, &mut b, ids["/view/AK1"]);
    let stats = view.stop();
    assert_eq!(
        (stats.evicted, stats.refused, stats.served),
        (1, 1, 2),
        "{stats:?}"
    );
}

/// A connection without a complete request in the handshake time is closed (with 408),
/// whether it sent nothing or half a head; a request that is not an HTTP GET, or a head
/// past 16 KiB, is closed at once (with 400). The SDK never sees them.
#[test]
fn slow_and_bad_requests_are_closed_before_the_sdk_sees_them() {
    let view = View::start(LiveOptions {
        handshake_timeout: Duration::from_millis(300),
        ..LiveOptions::default()
    });
    let t0 = Instant::now();
    let silent = TcpStream::connect(view.addr()).unwrap();
    let mut half = TcpStream::connect(view.addr()).unwrap();
    half.write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        .unwrap();
    for s in [silent, half] {
        let got = String::from_utf8_lossy(&read_to_end(s)).to_string();
        assert!(got.starts_with("HTTP/1.1 408"), "{got}");
    }
    let waited = t0.elapsed();
    assert!(
        waited >= Duration::from_millis(250) && waited < Duration::from_secs(3),
        "{waited:?}"
    );
    let mut garbage = TcpStream::connect(view.addr()).unwrap();
    garbage.write_all(&[0x16, 0x03, 0x01, 0x02, 0x00]).unwrap();
    let got = String::from_utf8_lossy(&read_to_end(garbage)).to_string();
    assert!(got.starts_with("HTTP/1.1 400"), "{got}");
    let mut long = TcpStream::connect(view.addr()).unwrap();
    let mut head = b"GET / HTTP/1.1\r\n".to_vec();
    while head.len() <= MAX_REQUEST_HEAD_BYTES {
        head.extend_from_slice(b"X-Padding: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\r\n");
    }
    let _ = long.write_all(&head);
    let got = String::from_utf8_lossy(&read_to_end(long)).to_string();
    assert!(got.starts_with("HTTP/1.1 400"), "{got}");
    let stats = view.stop();
    assert_eq!(
        (stats.handshake_timeouts, stats.bad_requests, stats.served),
        (2, 2, 0),
        "{stats:?}"
    );
}

/// A client message past the cap closes the connection with 1009 (message too big) at
/// its header; one within the cap is taken (the SDK answers a message it cannot parse
/// with an error status, and the client stays).
#[test]
fn a_message_past_the_cap_closes_the_connection_with_1009() {
    let view = View::start(LiveOptions {
        max_client_message_bytes: 4096,
        ..LiveOptions::default()
    });
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    ws.send(WsMessage::binary(vec![0u8; 4096])).unwrap();
    first_message(&view, &mut ws, ids["/view/AK1"]);
    ws.send(WsMessage::binary(vec![0u8; 4097])).unwrap();
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let code = loop {
        match ws.read() {
            Ok(WsMessage::Close(Some(f))) => break u16::from(f.code),
            Ok(WsMessage::Close(None)) => break 0,
            Ok(_) => {}
            Err(e) => panic!("{e}"),
        }
    };
    assert_eq!(code, 1009);
    let stats = view.stop();
    assert_eq!(stats.oversized, 1, "{stats:?}");
}

/// A client that reads nothing while the view has bytes for it is closed once it took
/// none for the stall time (its buffers full), and its place is free again.
#[test]
fn a_client_that_reads_nothing_is_closed_after_the_stall_time() {
    let view = View::start(LiveOptions {
        stall_timeout: Duration::from_millis(300),
        max_clients: 1,
        ..LiveOptions::default()
    });
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    first_message(&view, &mut ws, ids["/view/AK1"]);
    let t0 = Instant::now();
    while view.live().stats().stalled == 0 {
        assert!(t0.elapsed() < Duration::from_secs(20), "never stalled");
        view.publish(16, 16 * 1024);
        std::thread::sleep(Duration::from_millis(5));
    }
    drop(ws);
    let (mut ws, ids) = foxglove_client_within(view.addr(), Duration::from_secs(3));
    first_message(&view, &mut ws, ids["/view/AK1"]);
    let stats = view.stop();
    assert_eq!(stats.stalled, 1, "{stats:?}");
}

/// A connection that completes its WebSocket upgrade (tungstenite, `foxglove.sdk.v1`)
/// and then never reads nor writes.
fn silent_client(addr: SocketAddr) -> Ws {
    let stream = TcpStream::connect(addr).unwrap();
    upgrade(stream, addr, "foxglove.sdk.v1").unwrap().0
}

/// Item 3 of issue 46: sixteen connections that finish the upgrade and then neither
/// read nor write hold every place (16, the default); a client that reads is still
/// served, a message of a subscription within 10 s (today's view refused it with 503
/// for as long as they stayed: 75 s in the probe). They owe the Pong of the
/// Ping each was sent at once, so one of them gives its place.
#[test]
fn sixteen_silent_clients_leave_room_for_a_client_that_reads() {
    let view = View::start(LiveOptions::default());
    let silent: Vec<Ws> = (0..DEFAULT_MAX_CLIENTS)
        .map(|_| silent_client(view.addr()))
        .collect();
    let t0 = Instant::now();
    let (mut ws, ids) = foxglove_client_within(view.addr(), Duration::from_secs(10));
    let payload = first_message(&view, &mut ws, ids["/view/AK1"]);
    let took = t0.elapsed();
    assert_eq!(payload, [7; 40]);
    assert!(took < Duration::from_secs(10), "served after {took:?}");
    let stats = view.live().stats();
    println!(
        "FIGURES view 16 silent clients then one that reads: served (a message) after \
         {:.2} s; {stats:?}",
        took.as_secs_f64()
    );
    drop(silent);
    let stats = view.stop();
    assert!(stats.displaced >= 1, "{stats:?}");
    assert_eq!(stats.served, DEFAULT_MAX_CLIENTS as u64 + 1, "{stats:?}");
}

/// A connection that never reads is closed once it has not answered its ping for the
/// pong timeout (10 s by default), counted, with a Close 1008 for when it reads again;
/// a client that reads all the while answers its pings and stays.
#[test]
fn a_client_that_does_not_answer_a_ping_is_closed_after_the_pong_timeout() {
    let view = View::start(LiveOptions::default());
    let t0 = Instant::now();
    let mut silent = silent_client(view.addr());
    let (mut reader, ids) = foxglove_client(view.addr()).unwrap();
    let ak1 = ids["/view/AK1"];
    first_message(&view, &mut reader, ak1);
    let mut got = 0;
    while view.live().stats().unanswered_pings == 0 {
        assert!(t0.elapsed() < Duration::from_secs(20), "never closed");
        view.publish(1, 40);
        std::thread::sleep(Duration::from_millis(2));
        match reader.read() {
            Ok(WsMessage::Binary(_)) => got += 1,
            Ok(_) => {}
            Err(tungstenite::Error::Io(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => panic!("the reading client lost its connection: {e}"),
        }
    }
    let closed_after = t0.elapsed();
    assert!(
        closed_after >= DEFAULT_PONG_TIMEOUT && closed_after < DEFAULT_PONG_TIMEOUT * 2,
        "{closed_after:?}"
    );
    assert!(got > 100, "{got} messages read meanwhile");
    println!(
        "FIGURES view a silent client closed {:.2} s after its upgrade (pong timeout \
         {DEFAULT_PONG_TIMEOUT:?}); a reading client meanwhile got {got} messages",
        closed_after.as_secs_f64()
    );
    // What the silent one finds when it reads at last: the view's first bytes, the
    // Ping, the Close.
    silent
        .get_ref()
        .set_read_timeout(Some(Duration::from_secs(3)))
        .unwrap();
    let code = loop {
        match silent.read() {
            Ok(WsMessage::Close(f)) => break f.map(|f| u16::from(f.code)),
            Ok(_) => {}
            Err(e) => panic!("no Close: {e}"),
        }
    };
    assert_eq!(code, Some(1008));
    first_message(&view, &mut reader, ak1);
    let stats = view.stop();
    assert_eq!(
        (stats.unanswered_pings, stats.displaced, stats.stalled),
        (1, 0, 0),
        "{stats:?}"
    );
}

/// A socket connected to `addr` made by user `uid` (its owner, as the kernel sees it:
/// the filesystem uid of the thread that made it), or `None` when this process may not
/// take another uid (not root).
fn connect_as(uid: u32, addr: SocketAddr) -> Option<TcpStream> {
    std::thread::spawn(move || {
        // SAFETY: setfsuid changes this thread's filesystem uid only (glibc does not
        // pass it to the other threads); it is set back before the thread ends.
        let before = unsafe { libc::setfsuid(uid) };
        let now = unsafe { libc::setfsuid(uid) };
        let s = (now as u32 == uid).then(|| TcpStream::connect(addr).unwrap());
        unsafe { libc::setfsuid(before as u32) };
        s
    })
    .join()
    .unwrap()
}

/// Issue 46, item 3's share: sixteen clients of one local user that read and answer
/// their pings hold every place; a client of another user still gets one (the oldest
/// of the first user's gives it, Close 1013), and a seventeenth of the first user is
/// refused (503). On a view every client reaches at 127.0.0.1, a peer is the user that
/// owns the client's socket. Needs root (a socket owned by another user).
#[test]
fn one_user_holding_every_place_gives_one_to_another() {
    const OTHER: u32 = 65534;
    let view = View::start(LiveOptions::default());
    let addr = view.addr();
    let Some(probe) = connect_as(OTHER, addr) else {
        eprintln!("SKIPPED: not root, so no socket of another user can be made");
        return;
    };
    drop(probe);
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let readers: Vec<_> = (0..DEFAULT_MAX_CLIENTS)
        .map(|_| {
            let stream = connect_as(OTHER, addr).unwrap();
            let (ws, _) = upgrade(stream, addr, "foxglove.sdk.v1").unwrap();
            let (mut ws, _) = read_advertised(ws).unwrap();
            let stop = Arc::clone(&stop);
            ws.get_ref()
                .set_read_timeout(Some(Duration::from_millis(50)))
                .unwrap();
            std::thread::spawn(move || {
                let mut close = None;
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    match ws.read() {
                        Ok(WsMessage::Close(f)) => close = f.map(|f| u16::from(f.code)),
                        Ok(_) => {}
                        Err(tungstenite::Error::Io(e))
                            if e.kind() == std::io::ErrorKind::WouldBlock => {}
                        Err(_) => break,
                    }
                }
                close
            })
        })
        .collect();
    // Their first pings answered.
    std::thread::sleep(Duration::from_millis(300));
    let (mut ws, ids) = foxglove_client(addr).expect("another user's client is let in");
    assert_eq!(first_message(&view, &mut ws, ids["/view/AK1"]), [7; 40]);
    let mut again = connect_as(OTHER, addr).unwrap();
    let _ = again.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n");
    let answer = String::from_utf8_lossy(&read_to_end(again)).to_string();
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let closes: Vec<Option<u16>> = readers.into_iter().map(|r| r.join().unwrap()).collect();
    assert_eq!(
        closes[0],
        Some(1013),
        "the oldest gave its place: {closes:?}"
    );
    assert!(closes[1..].iter().all(Option::is_none), "{closes:?}");
    let stats = view.stop();
    assert_eq!((stats.displaced, stats.refused), (1, 1), "{stats:?}");
}

/// Issue 46, item 8: every subprotocol current Foxglove and Lichtblick clients offer
/// is served: `foxglove.websocket.v1` alone (Lichtblick before lichtblick-suite/
/// lichtblick#819, Foxglove Studio 1.x: today's view answered 400) gets an answer naming
/// it and the same messages; Lichtblick's offer of both names, and the SDK's own
/// (`foxglove.sdk.v1`, `foxglove.sdk.v1.1`), get what the SDK chooses. An offer of
/// none is refused (400) as the SDK refuses it.
#[test]
fn the_subprotocols_foxglove_and_lichtblick_offer_are_served() {
    let view = View::start(LiveOptions::default());
    let addr = view.addr();
    for (offer, chosen) in [
        (WEBSOCKET_V1, WEBSOCKET_V1),
        ("foxglove.websocket.v1, foxglove.sdk.v1", SDK_V1),
        (SDK_V1, SDK_V1),
        ("foxglove.sdk.v1, foxglove.sdk.v1.1", SDK_V1_1),
    ] {
        let stream = TcpStream::connect(addr).unwrap();
        let (ws, protocol) =
            upgrade(stream, addr, offer).unwrap_or_else(|e| panic!("{offer}: {e}"));
        assert_eq!(protocol.as_deref(), Some(chosen), "{offer}");
        let (mut ws, ids) = read_advertised(ws).unwrap();
        assert_eq!(ids.len(), crate::topics(crate::UNIT_NAMES).len(), "{offer}");
        assert_eq!(
            first_message(&view, &mut ws, ids["/view/AK1"]),
            [7; 40],
            "{offer}"
        );
        ws.close(None).unwrap();
    }
    let stream = TcpStream::connect(addr).unwrap();
    match upgrade(stream, addr, "chat") {
        Err(tungstenite::Error::Http(r)) => assert_eq!(r.status(), 400),
        other => panic!("{:?}", other.map(|(_, p)| p)),
    }
    let stats = view.stop();
    assert_eq!(stats.websocket_v1_requests, 1, "{stats:?}");
}

/// A client subscribed to a busy channel that stops reading (its buffers fill, so the
/// next ping cannot even be sent) is closed once it has taken nothing for the pong
/// timeout past that ping's time (10 s), not after the stall timeout (30 s: today's
/// view).
#[test]
fn a_subscribed_client_that_stops_reading_is_closed_at_the_pong_timeout() {
    let view = View::start(LiveOptions::default());
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    first_message(&view, &mut ws, ids["/view/AK1"]);
    let t0 = Instant::now();
    let closed = || {
        let s = view.live().stats();
        s.unanswered_pings + s.stalled > 0
    };
    while !closed() {
        assert!(t0.elapsed() < Duration::from_secs(40), "never closed");
        view.publish(4, 16 * 1024);
        std::thread::sleep(Duration::from_millis(5));
    }
    let took = t0.elapsed();
    println!(
        "FIGURES view a subscribed client that stopped reading closed after {:.2} s",
        took.as_secs_f64()
    );
    assert!(
        took < DEFAULT_PING_INTERVAL + DEFAULT_PONG_TIMEOUT + Duration::from_secs(2),
        "{took:?}"
    );
    drop(ws);
    let stats = view.stop();
    assert_eq!((stats.unanswered_pings, stats.stalled), (1, 0), "{stats:?}");
}

/// A client that reads a busy stream (16 KiB messages as fast as the view takes them,
/// so that the guard's reads end inside frames) gets its pings all the same, at about
/// the interval, and answers them: it is never closed.
#[test]
fn a_client_reading_a_busy_stream_gets_its_pings_and_stays() {
    let view = View::start(LiveOptions {
        ping_interval: Duration::from_millis(200),
        pong_timeout: Duration::from_secs(1),
        ..LiveOptions::default()
    });
    let (mut ws, ids) = foxglove_client(view.addr()).unwrap();
    first_message(&view, &mut ws, ids["/view/AK1"]);
    let t0 = Instant::now();
    let (mut pings, mut bytes) = (0u32, 0usize);
    while t0.elapsed() < Duration::from_secs(3) {
        view.publish(2, 16 * 1024);
        match ws.read() {
            Ok(WsMessage::Ping(_)) => pings += 1,
            Ok(WsMessage::Binary(b)) => bytes += b.len(),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => panic!("closed after {:?}: {e}", t0.elapsed()),
        }
    }
    println!(
        "FIGURES view a client reading a busy stream: {pings} pings in 3 s, {} MiB read",
        bytes >> 20
    );
    // 15 at the interval (a ping waits for its Pong, and this loop for the view); 5
    // when a ping waited for a read of the stream to end between two frames.
    assert!(pings >= 10, "{pings} pings");
    assert!(bytes > 16 << 20, "{bytes} bytes");
    first_message(&view, &mut ws, ids["/view/AK1"]);
    // Taken while it still reads (at stop it reads no more, and owes the next ping).
    let stats = view.live().stats();
    assert_eq!((stats.unanswered_pings, stats.stalled), (0, 0), "{stats:?}");
    view.stop();
}
