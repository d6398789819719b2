//! `--view`: a Foxglove WebSocket client reading everything the live view serves,
//! what a connected viewer costs the services.

use anyhow::Context;
use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What the live view served a connected client during a `--view` run.
#[derive(Debug, Clone, Serialize)]
pub struct ViewLoad {
    pub listen: String,
    /// Channels the client subscribed to.
    pub client_channels: usize,
    /// View messages the client received (binary message frames).
    pub client_messages: u64,
    /// The view's own summary at exit (`vibrocomp view --json`).
    pub view_summary: serde_json::Value,
}

/// A Foxglove WebSocket client on its own thread (`foxglove.sdk.v1`, the synchronous
/// `tungstenite` client): subscribes to every channel the server advertises and counts
/// the message frames until `stop`. Returns (channels, messages).
pub(crate) fn view_client(
    listen: std::net::SocketAddr,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<anyhow::Result<(usize, u64)>> {
    std::thread::spawn(move || -> anyhow::Result<(usize, u64)> {
        use tungstenite::client::IntoClientRequest;
        use tungstenite::Message as Ws;
        let deadline = Instant::now() + Duration::from_secs(20);
        let stream = loop {
            match std::net::TcpStream::connect(listen) {
                Ok(s) => break s,
                Err(_) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(50))
                }
                Err(e) => {
                    return Err(e).with_context(|| format!("connecting to the view on {listen}"))
                }
            }
        };
        stream.set_read_timeout(Some(Duration::from_millis(100)))?;
        let mut request = format!("ws://{listen}").into_client_request()?;
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            tungstenite::http::HeaderValue::from_static("foxglove.sdk.v1"),
        );
        let (mut ws, _) = tungstenite::client(request, stream)
            .map_err(|e| anyhow::anyhow!("the WebSocket handshake with {listen}: {e}"))?;
        let (mut channels, mut messages, mut next_id) = (0usize, 0u64, 1u32);
        while !stop.load(Ordering::Acquire) {
            match ws.read() {
                Ok(Ws::Text(t)) => {
                    let v: serde_json::Value = serde_json::from_str(t.as_str())?;
                    if v["op"] == "advertise" {
                        let subs: Vec<serde_json::Value> = v["channels"]
                            .as_array()
                            .into_iter()
                            .flatten()
                            .map(|c| {
                                next_id += 1;
                                serde_json::json!({"id": next_id, "channelId": c["id"]})
                            })
                            .collect();
                        channels += subs.len();
                        let sub = serde_json::json!({"op": "subscribe", "subscriptions": subs});
                        ws.send(Ws::text(sub.to_string()))?;
                    }
                }
                Ok(Ws::Binary(_)) => messages += 1,
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(anyhow::anyhow!("reading from the view: {e}")),
            }
        }
        let _ = ws.close(None);
        Ok((channels, messages))
    })
}
