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
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut req = format!("ws://{addr}").into_client_request().unwrap();
    req.headers_mut().insert(
        "sec-websocket-protocol",
        tungstenite::http::HeaderValue::from_static("foxglove.sdk.v1"),
    );
    let (mut ws, resp) = tungstenite::client(req, stream).map_err(|e| e.to_string())?;
    assert_eq!(resp.status(), 101);
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

/// At the cap, a new connection takes the place of the oldest one still without its
/// request (which is closed); when every place has a client past its request, the new
/// one is refused with 503 and the cap in the body.
#[test]
fn at_the_cap_idle_connections_give_way_and_then_clients_are_refused() {
    let view = View::start(LiveOptions {
        max_clients: 2,
        ..LiveOptions::default()
    });
    let idle = TcpStream::connect(view.addr()).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    let (_a, _) = foxglove_client(view.addr()).unwrap();
    let (mut b, ids) = foxglove_client(view.addr()).unwrap();
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
