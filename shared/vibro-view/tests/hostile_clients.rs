//! The live view's server against hostile clients (issue 31, items 3 and 4): idle
//! connections under a low descriptor limit, 16 MiB frames, garbage, a subscription to
//! 1,000 unknown channels, clients that never read. Each test runs the view in a child
//! process (this binary again, `VIBRO_VIEW_CHILD` set: the view channels published at
//! a steady rate, the server of `vibro_view::live`, the process's log on its stderr),
//! so that its descriptor limit, memory and log lines are its own, and ends with a
//! well-behaved Foxglove client served.
//!
//! `VIBRO_VIEW_SERVER=sdk` runs the same tests against the Foxglove SDK's server alone
//! (the view before the guard): they fail, and their `FIGURES` lines are the "before"
//! of docs/reliability.md:
//!
//! ```text
//! VIBRO_VIEW_SERVER=sdk cargo test -p vibro-view --test hostile_clients -- --nocapture
//! ```

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest as _;
use tungstenite::Message as WsMessage;

type Ws = tungstenite::WebSocket<TcpStream>;

/// Set in the child: which server it runs (`guarded` or `sdk`).
const CHILD_ENV: &str = "VIBRO_VIEW_CHILD";
/// The child's soft descriptor limit.
const NOFILE_ENV: &str = "VIBRO_VIEW_NOFILE";
/// The child's publishing: payload bytes of each unit message, and the period, ms.
const PUBLISH_ENV: &str = "VIBRO_VIEW_PUBLISH";

/// Which server the tests start (`guarded` unless `VIBRO_VIEW_SERVER=sdk`).
fn server_kind() -> String {
    std::env::var("VIBRO_VIEW_SERVER").unwrap_or_else(|_| "guarded".into())
}

/// The child's entry: runs the view when this binary is the child, else nothing.
#[test]
fn child_view() {
    if let Ok(kind) = std::env::var(CHILD_ENV) {
        child::run(&kind);
    }
}

mod child {
    use super::*;

    /// Descriptors taken by `hog` until `release`.
    static HOGGED: Mutex<Vec<std::fs::File>> = Mutex::new(Vec::new());

    fn set_nofile(limit: u64) {
        let mut r = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: both calls read or write the struct they are given, alive meanwhile.
        unsafe {
            assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut r), 0);
            r.rlim_cur = limit as libc::rlim_t;
            assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &r), 0);
        }
    }

    fn status() -> String {
        let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let kb = |key: &str| {
            s.lines()
                .find_map(|l| l.strip_prefix(key))
                .and_then(|v| v.split_whitespace().next())
                .unwrap_or("0")
                .to_string()
        };
        let fds = std::fs::read_dir("/proc/self/fd").map_or(0, |d| d.count());
        format!("rss_kb={} hwm_kb={} fds={fds}", kb("VmRSS:"), kb("VmHWM:"))
    }

    pub fn run(kind: &str) {
        if let Some(n) = std::env::var(NOFILE_ENV).ok().and_then(|v| v.parse().ok()) {
            set_nofile(n);
        }
        // As `vibro_service::init_tracing` sets it up: INFO and above, to stderr.
        tracing_subscriber::fmt()
            .with_env_filter(tracing_subscriber::EnvFilter::new("info"))
            .with_writer(std::io::stderr)
            .with_ansi(false)
            .init();
        let (bytes, period_ms) = std::env::var(PUBLISH_ENV)
            .ok()
            .and_then(|v| {
                let (b, p) = v.split_once(',')?;
                Some((b.parse().ok()?, p.parse().ok()?))
            })
            .unwrap_or((200usize, 10u64));
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let ctx = foxglove::Context::new();
        let channels = vibro_view::live::channels(&ctx, vibro_view::UNIT_NAMES).unwrap();
        let make = || {
            foxglove::WebSocketServer::new()
                .name("vibrocomp view (test)")
                .message_backlog_size(4096)
        };
        enum Server {
            Sdk(foxglove::WebSocketServerHandle),
            Guarded(vibro_view::live::LiveServer),
        }
        let (server, addr) = rt.block_on(async {
            if kind == "sdk" {
                let s = make()
                    .bind("127.0.0.1", 0)
                    .context(&ctx)
                    .start()
                    .await
                    .unwrap();
                let addr = SocketAddr::from(([127, 0, 0, 1], s.port()));
                (Server::Sdk(s), addr)
            } else {
                let options = vibro_view::live::LiveOptions {
                    listen: "127.0.0.1:0".parse().unwrap(),
                    ..Default::default()
                };
                let s = vibro_view::live::LiveServer::start(&ctx, make, options)
                    .await
                    .unwrap();
                let addr = s.local_addr();
                (Server::Guarded(s), addr)
            }
        });
        println!("VIEW listening {addr}");
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let publisher = {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                let data = vec![0x5Au8; bytes];
                let mut t_ns = 1_000_000_000u64;
                while !stop.load(Ordering::Relaxed) {
                    for unit in vibro_view::UNIT_NAMES {
                        channels[&format!("/view/{unit}")].log_with_meta(
                            &data,
                            foxglove::PartialMetadata {
                                log_time: Some(t_ns),
                            },
                        );
                    }
                    t_ns += period_ms * 1_000_000;
                    std::thread::sleep(Duration::from_millis(period_ms));
                }
            })
        };
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { break };
            match line.trim() {
                "status" => println!("VIEW status {}", status()),
                "hog" => {
                    let mut h = HOGGED.lock().unwrap();
                    while let Ok(f) = std::fs::File::open("/dev/null") {
                        h.push(f);
                    }
                    println!("VIEW hogged {}", h.len());
                }
                "release" => {
                    HOGGED.lock().unwrap().clear();
                    println!("VIEW released");
                }
                _ => break,
            }
        }
        stop.store(true, Ordering::Relaxed);
        let _ = publisher.join();
        let stats = rt.block_on(async {
            match server {
                Server::Sdk(s) => {
                    s.stop().wait().await;
                    "{}".to_string()
                }
                Server::Guarded(s) => serde_json::to_string(&s.stop().await).unwrap(),
            }
        });
        println!("VIEW stats {stats}");
        println!("VIEW {}", status());
        rt.shutdown_timeout(Duration::from_secs(2));
    }
}

/// The view in its child process: its address, its stdout's `VIEW` lines, its stderr
/// (the log) counted. Killed when dropped, if still running.
struct View {
    child: std::process::Child,
    stdin: Option<std::process::ChildStdin>,
    lines: mpsc::Receiver<String>,
    addr: SocketAddr,
    log_lines: Arc<AtomicUsize>,
    log_tail: Arc<Mutex<std::collections::VecDeque<String>>>,
    /// Addresses the Foxglove SDK's log says its servers started on.
    sdk_logged: Arc<Mutex<Vec<SocketAddr>>>,
    readers: Vec<std::thread::JoinHandle<()>>,
}

/// What [`View::stop`] returns.
struct Stopped {
    log_lines: usize,
    /// The guard's `LiveStats` (`{}` for the SDK alone).
    stats: serde_json::Value,
    status: String,
}

impl View {
    fn start(nofile: Option<u64>, publish: Option<&str>) -> Self {
        let mut cmd = Command::new(std::env::current_exe().unwrap());
        cmd.args(["child_view", "--exact", "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, server_kind())
            .env_remove("RUST_LOG")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if let Some(n) = nofile {
            cmd.env(NOFILE_ENV, n.to_string());
        }
        if let Some(p) = publish {
            cmd.env(PUBLISH_ENV, p);
        }
        let mut child = cmd.spawn().unwrap();
        let stdin = child.stdin.take();
        let (tx, lines) = mpsc::channel();
        let out = child.stdout.take().unwrap();
        let err = child.stderr.take().unwrap();
        let log_lines = Arc::new(AtomicUsize::new(0));
        let log_tail = Arc::new(Mutex::new(std::collections::VecDeque::new()));
        let sdk_logged = Arc::new(Mutex::new(Vec::new()));
        let readers = vec![
            std::thread::spawn(move || {
                for l in BufReader::new(out).lines().map_while(Result::ok) {
                    // libtest's `test child_view ... ` has no line end of its own.
                    if let Some(i) = l.find("VIEW ") {
                        let _ = tx.send(l[i + 5..].to_string());
                    }
                }
            }),
            {
                let (n, tail) = (Arc::clone(&log_lines), Arc::clone(&log_tail));
                let logged = Arc::clone(&sdk_logged);
                std::thread::spawn(move || {
                    for l in BufReader::new(err).lines().map_while(Result::ok) {
                        n.fetch_add(1, Ordering::Relaxed);
                        // The SDK's "Started server on 127.0.0.1:PORT".
                        if let Some(a) = l
                            .split("Started server on ")
                            .nth(1)
                            .and_then(|r| r.split_whitespace().next())
                            .and_then(|a| a.parse().ok())
                        {
                            logged.lock().unwrap().push(a);
                        }
                        let mut t = tail.lock().unwrap();
                        if t.len() == 40 {
                            t.pop_front();
                        }
                        t.push_back(l);
                    }
                })
            },
        ];
        let Ok(first) = lines.recv_timeout(Duration::from_secs(20)) else {
            let _ = child.kill();
            let _ = child.wait();
            let tail = log_tail.lock().unwrap().iter().cloned().collect::<Vec<_>>();
            panic!("the child view did not start: {}", tail.join("\n"));
        };
        let addr = first
            .strip_prefix("listening ")
            .and_then(|a| a.parse().ok())
            .unwrap_or_else(|| panic!("{first}"));
        Self {
            child,
            stdin,
            lines,
            addr,
            log_lines,
            log_tail,
            sdk_logged,
            readers,
        }
    }

    /// The addresses the view process listens on besides its public one, found as
    /// another user of the machine finds them: the Foxglove SDK's log line ("Started
    /// server on ..."), and the listening sockets of `/proc/net/tcp` that belong to the
    /// process (its descriptors' socket inodes).
    fn other_listeners(&self) -> (Vec<SocketAddr>, Vec<SocketAddr>) {
        let logged = self.sdk_logged.lock().unwrap().clone();
        let pid = self.child.id();
        let inodes: std::collections::BTreeSet<String> =
            std::fs::read_dir(format!("/proc/{pid}/fd"))
                .unwrap()
                .flatten()
                .filter_map(|e| std::fs::read_link(e.path()).ok())
                .filter_map(|l| {
                    let l = l.to_str()?;
                    Some(l.strip_prefix("socket:[")?.strip_suffix(']')?.to_string())
                })
                .collect();
        let table = std::fs::read_to_string("/proc/net/tcp").unwrap();
        let listening = table
            .lines()
            .skip(1)
            .filter_map(|l| {
                let f: Vec<&str> = l.split_whitespace().collect();
                (f.get(3) == Some(&"0A") && inodes.contains(*f.get(9)?)).then_some(f[1])
            })
            .filter_map(|local| {
                let (a, p) = local.split_once(':')?;
                let a = u32::from_str_radix(a, 16).ok()?;
                let ip = std::net::Ipv4Addr::from(a.to_ne_bytes());
                Some(SocketAddr::from((ip, u16::from_str_radix(p, 16).ok()?)))
            })
            .filter(|a| *a != self.addr)
            .collect();
        (logged, listening)
    }

    /// Sends the child `command`; its answer.
    fn ask(&mut self, command: &str) -> String {
        let stdin = self.stdin.as_mut().unwrap();
        writeln!(stdin, "{command}").unwrap();
        stdin.flush().unwrap();
        self.lines
            .recv_timeout(Duration::from_secs(20))
            .unwrap_or_else(|_| panic!("no answer to {command}; log: {}", self.tail()))
    }

    /// The child's resident memory now and at its peak, KiB.
    fn memory_kb(&mut self) -> (u64, u64) {
        let s = self.ask("status");
        let field = |k: &str| {
            s.split_whitespace()
                .find_map(|f| f.strip_prefix(k))
                .and_then(|v| v.parse().ok())
                .unwrap_or(0)
        };
        (field("rss_kb="), field("hwm_kb="))
    }

    fn log_lines(&self) -> usize {
        self.log_lines.load(Ordering::Relaxed)
    }

    fn tail(&self) -> String {
        let t = self.log_tail.lock().unwrap();
        t.iter().cloned().collect::<Vec<_>>().join("\n")
    }

    /// Ends the child (its stdin closed: it stops its server and exits).
    fn stop(mut self) -> Stopped {
        drop(self.stdin.take());
        let t0 = Instant::now();
        let mut got = Vec::new();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(20)) {
            got.push(l);
            if got.len() == 2 || t0.elapsed() > Duration::from_secs(20) {
                break;
            }
        }
        let status = self.child.wait().unwrap();
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        assert!(
            status.success(),
            "child view: {status}; log: {}",
            self.tail()
        );
        let stats = got
            .iter()
            .find_map(|l| l.strip_prefix("stats "))
            .and_then(|s| serde_json::from_str(s).ok())
            .unwrap_or_default();
        Stopped {
            log_lines: self.log_lines(),
            stats,
            status: got.last().cloned().unwrap_or_default(),
        }
    }
}

impl Drop for View {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A Foxglove client's handshake (subprotocol `foxglove.sdk.v1`), `serverInfo` and
/// the advertised channels read: the socket and the channel ids by topic.
fn foxglove_client(addr: SocketAddr) -> Result<(Ws, Vec<(String, u64)>), String> {
    let stream =
        TcpStream::connect_timeout(&addr, Duration::from_secs(2)).map_err(|e| e.to_string())?;
    stream
        .set_read_timeout(Some(Duration::from_secs(3)))
        .unwrap();
    stream
        .set_write_timeout(Some(Duration::from_secs(3)))
        .unwrap();
    let mut req = format!("ws://{addr}").into_client_request().unwrap();
    req.headers_mut().insert(
        "sec-websocket-protocol",
        tungstenite::http::HeaderValue::from_static("foxglove.sdk.v1"),
    );
    let (mut ws, _) = tungstenite::client(req, stream).map_err(|e| e.to_string())?;
    let wanted = vibro_view::topics(vibro_view::UNIT_NAMES).len();
    let mut ids = Vec::new();
    while ids.len() < wanted {
        if let WsMessage::Text(t) = ws.read().map_err(|e| e.to_string())? {
            let v: serde_json::Value = serde_json::from_str(&t).map_err(|e| e.to_string())?;
            if v["op"] == "advertise" {
                for c in v["channels"].as_array().into_iter().flatten() {
                    ids.push((
                        c["topic"].as_str().unwrap_or("").to_string(),
                        c["id"].as_u64().unwrap_or(0),
                    ));
                }
            }
        }
    }
    Ok((ws, ids))
}

/// Subscribes `ws` to `channels` (subscription ids from 1).
fn subscribe(ws: &mut Ws, channels: &[u64]) -> Result<(), String> {
    let subs: Vec<serde_json::Value> = channels
        .iter()
        .enumerate()
        .map(|(i, c)| serde_json::json!({"id": i + 1, "channelId": c}))
        .collect();
    let msg = serde_json::json!({"op": "subscribe", "subscriptions": subs});
    ws.send(WsMessage::text(msg.to_string()))
        .map_err(|e| e.to_string())
}

/// A well-behaved Foxglove client: connects, subscribes to `/view/AK1` and gets 3 of
/// its messages; tried again (as Foxglove does) until served or `within` passed. How
/// long it took, or the last failure.
fn well_behaved(addr: SocketAddr, within: Duration) -> Result<Duration, String> {
    let t0 = Instant::now();
    let mut last = String::new();
    while t0.elapsed() < within {
        let attempt = || -> Result<(), String> {
            let (mut ws, ids) = foxglove_client(addr)?;
            let ak1 = ids
                .iter()
                .find(|(t, _)| t == "/view/AK1")
                .ok_or("no /view/AK1")?
                .1;
            subscribe(&mut ws, &[ak1])?;
            let mut got = 0;
            while got < 3 {
                if let WsMessage::Binary(b) = ws.read().map_err(|e| e.to_string())? {
                    if b.first() == Some(&1) {
                        got += 1;
                    }
                }
            }
            let _ = ws.close(None);
            let _ = ws.flush();
            Ok(())
        };
        match attempt() {
            Ok(()) => return Ok(t0.elapsed()),
            Err(e) => last = e,
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    Err(format!("not served within {within:?}: {last}"))
}

/// `n` connections that send nothing (kept open by the caller); how many connected.
fn idle_connections(addr: SocketAddr, n: usize) -> Vec<TcpStream> {
    (0..n)
        .filter_map(|_| TcpStream::connect_timeout(&addr, Duration::from_millis(500)).ok())
        .collect()
}

/// A masked client frame header (RFC 6455 §5.2) for a payload of `len` bytes, key 0.
fn frame_header(opcode: u8, len: u64) -> Vec<u8> {
    let mut h = vec![0x80 | opcode];
    if len < 126 {
        h.push(0x80 | len as u8);
    } else if len <= 0xFFFF {
        h.push(0x80 | 126);
        h.extend_from_slice(&(len as u16).to_be_bytes());
    } else {
        h.push(0x80 | 127);
        h.extend_from_slice(&len.to_be_bytes());
    }
    h.extend_from_slice(&[0; 4]);
    h
}

/// `clients` clients at once, each past its handshake sending one binary frame of
/// `bytes` bytes as fast as the view takes it; the bytes each got through before the
/// view closed it.
fn huge_frames(addr: SocketAddr, clients: usize, bytes: u64) -> Vec<u64> {
    let threads: Vec<_> = (0..clients)
        .map(|_| {
            std::thread::spawn(move || {
                let Ok((ws, _)) = foxglove_client(addr) else {
                    return 0;
                };
                let mut s = ws.into_inner();
                s.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
                if s.write_all(&frame_header(2, bytes)).is_err() {
                    return 0;
                }
                let chunk = vec![0u8; 64 * 1024];
                let mut sent = 0u64;
                while sent < bytes {
                    match s.write(&chunk[..chunk.len().min((bytes - sent) as usize)]) {
                        Ok(n) if n > 0 => sent += n as u64,
                        _ => break,
                    }
                }
                // Held until the view has read what it will (the SDK reads it all).
                std::thread::sleep(Duration::from_millis(500));
                sent
            })
        })
        .collect();
    threads.into_iter().map(|t| t.join().unwrap()).collect()
}

/// A client sending `frames` frames of garbage (text that is not JSON, binary with an
/// unknown opcode byte), reading what comes back meanwhile.
fn garbage(addr: SocketAddr, frames: usize) -> Result<(), String> {
    let (ws, _) = foxglove_client(addr)?;
    let mut s = ws.into_inner();
    let drain = s.try_clone().map_err(|e| e.to_string())?;
    let reader = std::thread::spawn(move || {
        let mut d = drain;
        let _ = d.set_read_timeout(Some(Duration::from_secs(3)));
        let _ = std::io::copy(&mut d, &mut std::io::sink());
    });
    let mut bytes = Vec::new();
    for i in 0..frames {
        let (op, payload): (u8, &[u8]) = if i % 2 == 0 {
            (1, b"{\"op\": not json at all")
        } else {
            (2, &[0xEE, 1, 2, 3, 4, 5, 6, 7])
        };
        bytes.extend(frame_header(op, payload.len() as u64));
        bytes.extend_from_slice(payload);
    }
    let r = s.write_all(&bytes);
    std::thread::sleep(Duration::from_millis(300));
    let _ = s.shutdown(std::net::Shutdown::Both);
    let _ = reader.join();
    r.map_err(|e| e.to_string())
}

/// A client subscribing to `n` channel ids the view does not have, in one message.
fn unknown_subscriptions(addr: SocketAddr, n: u64) -> Result<(), String> {
    let (mut ws, _) = foxglove_client(addr)?;
    let ids: Vec<u64> = (0..n).map(|i| 1_000_000 + i).collect();
    subscribe(&mut ws, &ids)?;
    // Its answers (an error status per id) read a moment, then it leaves.
    let _ = ws
        .get_ref()
        .set_read_timeout(Some(Duration::from_millis(200)));
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(500) {
        if ws.read().is_err() {
            break;
        }
    }
    let _ = ws.close(None);
    Ok(())
}

/// `n` clients subscribed to every channel that never read, for `hold`, then gone (a
/// reset: their unread bytes dropped).
fn never_reading(addr: SocketAddr, n: usize, hold: Duration) -> usize {
    let clients: Vec<_> = (0..n)
        .filter_map(|_| {
            let (mut ws, ids) = foxglove_client(addr).ok()?;
            let all: Vec<u64> = ids.iter().map(|(_, id)| *id).collect();
            subscribe(&mut ws, &all).ok()?;
            Some(ws)
        })
        .collect();
    let connected = clients.len();
    std::thread::sleep(hold);
    drop(clients);
    connected
}

/// Item 3: idle connections past a low descriptor limit (64: the SDK alone stopped
/// accepting for good after 169 under 256), then the process's descriptors all taken
/// (by anything): the listener lives through it, and a well-behaved client is served
/// after each, within seconds.
#[test]
fn idle_connections_under_a_low_descriptor_limit_leave_the_view_serving() {
    let mut view = View::start(Some(64), None);
    let idle = idle_connections(view.addr, 300);
    let served_idle = well_behaved(view.addr, Duration::from_secs(8));
    // Every descriptor taken, those the client's connections give back included.
    std::thread::sleep(Duration::from_millis(300));
    view.ask("hog");
    std::thread::sleep(Duration::from_millis(200));
    let hogged = view.ask("hog");
    let more = idle_connections(view.addr, 20);
    std::thread::sleep(Duration::from_millis(300));
    let released = view.ask("release");
    let served_hog = well_behaved(view.addr, Duration::from_secs(8));
    drop((idle, more));
    let s = view.stop();
    println!(
        "FIGURES view ({}) under RLIMIT_NOFILE 64: 300 idle connections made, then a \
         client: {served_idle:?}; all descriptors taken ({hogged}), 20 more connections, \
         {released}, then a client: {served_hog:?}; {} log lines; {}",
        server_kind(),
        s.log_lines,
        s.stats
    );
    served_idle.expect("a client after 300 idle connections");
    served_hog.expect("a client after the descriptors came back");
    assert!(s.stats["accept_errors"].as_u64() > Some(0), "{}", s.stats);
}

/// Item 4, memory: 20 clients at once each sending a 16 MiB frame (the SDK alone took
/// them all: 84 MB to 413 MB) are closed at their frame's header; the view's peak
/// memory grows by a few MiB at most, and a client is served after.
#[test]
fn huge_frames_close_their_connections_and_memory_stays_bounded() {
    let mut view = View::start(None, None);
    std::thread::sleep(Duration::from_millis(300));
    let (rss0, hwm0) = view.memory_kb();
    let sent = huge_frames(view.addr, 20, 16 << 20);
    let (rss1, hwm1) = view.memory_kb();
    let served = well_behaved(view.addr, Duration::from_secs(8));
    let s = view.stop();
    let sent_mib = sent.iter().sum::<u64>() as f64 / (1 << 20) as f64;
    println!(
        "FIGURES view ({}) 20 clients x 16 MiB frame: {sent_mib:.0} MiB sent before closed; \
         RSS {rss0} KiB before, {rss1} KiB after, peak {hwm0} -> {hwm1} KiB; client after: \
         {served:?}; {} log lines; {}",
        server_kind(),
        s.log_lines,
        s.stats
    );
    served.expect("a client after the huge frames");
    let grew_kib = hwm1.saturating_sub(hwm0);
    assert!(grew_kib < 32 * 1024, "peak memory grew {grew_kib} KiB");
    // Each huge-frame client let in (the cap is 16) was closed at its frame; the
    // well-behaved client was served too.
    let (oversized, served) = (&s.stats["oversized"], &s.stats["served"]);
    assert!(oversized.as_u64() >= Some(16), "{}", s.stats);
    assert_eq!(
        served.as_u64(),
        oversized.as_u64().map(|n| n + 1),
        "{}",
        s.stats
    );
}

/// Item 4, logs: a client sending 2,000 garbage frames (the SDK alone: 4,037 ERROR
/// lines), one subscribing to 1,000 unknown channel ids (1,000 lines), 20 clients
/// that never read and then go (5,875 "Broken pipe" lines): a bounded number of log
/// lines, the rest summarised, and a client served after.
#[test]
fn floods_from_clients_log_a_bounded_number_of_lines() {
    // 3 KiB a millisecond: the clients that never read fill their buffers in 2 s.
    let view = View::start(None, Some("1024,1"));
    let garbage = garbage(view.addr, 2000);
    let unknown = unknown_subscriptions(view.addr, 1000);
    let stalled = never_reading(view.addr, 20, Duration::from_secs(2));
    std::thread::sleep(Duration::from_millis(500));
    let served = well_behaved(view.addr, Duration::from_secs(8));
    let during = view.log_lines();
    let tail = view.tail();
    let s = view.stop();
    println!(
        "FIGURES view ({}) floods: garbage {garbage:?}, 1000 unknown ids {unknown:?}, \
         {stalled} never-reading clients: {during} log lines during, {} in all with the \
         summaries at stop; client after: {served:?}; {}",
        server_kind(),
        s.log_lines,
        s.stats
    );
    served.expect("a client after the floods");
    assert!(
        s.log_lines < 150,
        "{} log lines; the last: {tail}",
        s.log_lines
    );
}

/// The whole crowd at once under a descriptor limit of 128: 300 idle connections,
/// garbage, 1,000 unknown ids, 20 x 16 MiB frames, 20 clients that never read; the
/// view ends serving a well-behaved client, its peak memory and log lines bounded.
#[test]
fn a_hostile_crowd_leaves_the_view_serving_with_bounded_memory_and_logs() {
    let mut view = View::start(Some(128), Some("1024,1"));
    std::thread::sleep(Duration::from_millis(300));
    let (_, hwm0) = view.memory_kb();
    let addr = view.addr;
    let crowd = vec![
        std::thread::spawn(move || {
            let idle = idle_connections(addr, 300);
            std::thread::sleep(Duration::from_secs(3));
            format!("{} idle", idle.len())
        }),
        std::thread::spawn(move || format!("garbage {:?}", garbage(addr, 2000))),
        std::thread::spawn(move || format!("unknown ids {:?}", unknown_subscriptions(addr, 1000))),
        std::thread::spawn(move || {
            let sent: u64 = huge_frames(addr, 20, 16 << 20).iter().sum();
            format!("{} MiB of huge frames sent", sent >> 20)
        }),
        std::thread::spawn(move || {
            let n = never_reading(addr, 20, Duration::from_secs(2));
            format!("{n} never-reading")
        }),
    ];
    let crowd: Vec<String> = crowd.into_iter().map(|t| t.join().unwrap()).collect();
    let served = well_behaved(view.addr, Duration::from_secs(10));
    let (rss1, hwm1) = view.memory_kb();
    let s = view.stop();
    println!(
        "FIGURES view ({}) hostile crowd under RLIMIT_NOFILE 128 ({}): client after: \
         {served:?}; peak RSS {hwm0} -> {hwm1} KiB (now {rss1}); {} log lines; {}; {}",
        server_kind(),
        crowd.join(", "),
        s.log_lines,
        s.stats,
        s.status
    );
    served.expect("a client after the crowd");
    let grew_kib = hwm1.saturating_sub(hwm0);
    assert!(grew_kib < 64 * 1024, "peak memory grew {grew_kib} KiB");
    assert!(s.log_lines < 200, "{} log lines", s.log_lines);
}

/// Item 4 of issue 46: the Foxglove SDK's own port (its log names it; `/proc/net/tcp`
/// lists it among the view's listening sockets) takes no connection but the guard's:
/// a direct one is never made (today's view took 20 x 16 MiB frames through it, 21.8
/// to 351 MB); the view's memory stays where it was, and a client is served through
/// the guard after.
#[test]
fn the_foxglove_servers_own_port_takes_no_connection_but_the_guards() {
    let mut view = View::start(None, None);
    std::thread::sleep(Duration::from_millis(300));
    let (logged, listening) = view.other_listeners();
    assert!(
        !logged.is_empty(),
        "the SDK logged no address: {}",
        view.tail()
    );
    for a in &logged {
        assert!(listening.contains(a), "{a} not among {listening:?}");
    }
    let inner = logged[0];
    let (rss0, hwm0) = view.memory_kb();
    let direct: Vec<String> = listening
        .iter()
        .map(
            |a| match TcpStream::connect_timeout(a, Duration::from_secs(1)) {
                Ok(_) => format!("{a}: connected"),
                Err(e) => format!("{a}: {e}"),
            },
        )
        .collect();
    let sent = huge_frames(inner, 20, 16 << 20);
    let (rss1, hwm1) = view.memory_kb();
    let served = well_behaved(view.addr, Duration::from_secs(8));
    let s = view.stop();
    let sent_mib = sent.iter().sum::<u64>() as f64 / (1 << 20) as f64;
    println!(
        "FIGURES view ({}) the SDK's port {inner} (logged; listening: {listening:?}): direct \
         connections {direct:?}; 20 clients x 16 MiB frame there: {sent_mib:.0} MiB sent; RSS \
         {rss0} KiB before, {rss1} KiB after, peak {hwm0} -> {hwm1} KiB; client through the \
         guard after: {served:?}; {}",
        server_kind(),
        s.stats
    );
    assert!(
        direct.iter().all(|d| !d.ends_with("connected")),
        "a direct connection was made: {direct:?}"
    );
    assert!(sent.iter().all(|&b| b == 0), "{sent:?}");
    let grew_kib = hwm1.saturating_sub(hwm0);
    assert!(grew_kib < 32 * 1024, "peak memory grew {grew_kib} KiB");
    served.expect("a client through the guard after");
}
