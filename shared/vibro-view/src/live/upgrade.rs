//! The subprotocol of a client's upgrade request, as the Foxglove SDK is to get it.
//!
//! Foxglove's protocol was `foxglove.websocket.v1` (the ws-protocol specification and
//! its TypeScript client, which the Foxglove app used and Lichtblick still uses); the
//! SDK names the same protocol `foxglove.sdk.v1` (and its schema-table variant
//! `foxglove.sdk.v1.1`) and answers an offer of `foxglove.websocket.v1` alone with
//! `400 Bad Request`. Lichtblick offers both names since December 2025
//! (lichtblick-suite/lichtblick#819, "currently this subprotocol is identical to
//! `foxglove.websocket.v1`"); earlier Lichtblick releases, Foxglove Studio 1.x and
//! clients built on `@foxglove/ws-protocol`'s `FoxgloveClient.SUPPORTED_SUBPROTOCOL`
//! offer `foxglove.websocket.v1` only. So a request that offers `foxglove.websocket.v1`
//! and none of the SDK's names reaches the SDK offering `foxglove.sdk.v1` (the same
//! messages: channels advertised with their schemas inline), and the SDK's answer
//! reaches the client naming the subprotocol the client offered, as RFC 6455 §4.1
//! requires of it (a browser fails a connection whose answer names another).

use std::borrow::Cow;

/// The SDK's name of Foxglove's protocol v1.
pub const SDK_V1: &str = "foxglove.sdk.v1";
/// The SDK's v1 with a schema table (channels advertised without their schemas).
pub const SDK_V1_1: &str = "foxglove.sdk.v1.1";
/// The name the ws-protocol specification and its clients give protocol v1.
pub const WEBSOCKET_V1: &str = "foxglove.websocket.v1";

/// The header that carries the subprotocols, offered or chosen (§11.3.4).
const HEADER: &[u8] = b"sec-websocket-protocol";

/// The lines of an HTTP head (its blank line and what follows excluded).
fn lines(head: &[u8]) -> impl Iterator<Item = &[u8]> {
    let end = super::frames::head_end(head, 0).map_or(head.len(), |e| e - 4);
    head[..end]
        .split(|&b| b == b'\n')
        .map(|l| l.strip_suffix(b"\r").unwrap_or(l))
}

/// The value of `line` if it is a header named `name` (case-insensitive), trimmed.
fn header_value<'a>(line: &'a [u8], name: &[u8]) -> Option<&'a [u8]> {
    let colon = line.iter().position(|&b| b == b':')?;
    line[..colon]
        .eq_ignore_ascii_case(name)
        .then(|| line[colon + 1..].trim_ascii())
}

/// The subprotocols `head` offers, in its order (every `Sec-WebSocket-Protocol` header,
/// each a comma-separated list).
pub fn offered(head: &[u8]) -> Vec<&[u8]> {
    lines(head)
        .filter_map(|l| header_value(l, HEADER))
        .flat_map(|v| v.split(|&b| b == b','))
        .map(<[u8]>::trim_ascii)
        .filter(|t| !t.is_empty())
        .collect()
}

/// The request head `head` (up to and with its blank line) as the SDK is to get it,
/// and whether the SDK's answer is to name [`WEBSOCKET_V1`] instead of [`SDK_V1`]:
/// `head` itself unless it offers `foxglove.websocket.v1` and none of the SDK's names,
/// then `head` with its subprotocol headers replaced by one offering `foxglove.sdk.v1`.
pub fn request_for_sdk(head: &[u8]) -> (Cow<'_, [u8]>, bool) {
    let offers = offered(head);
    let sdk = offers
        .iter()
        .any(|t| *t == SDK_V1.as_bytes() || *t == SDK_V1_1.as_bytes());
    if sdk || !offers.iter().any(|t| *t == WEBSOCKET_V1.as_bytes()) {
        return (Cow::Borrowed(head), false);
    }
    let mut out = Vec::with_capacity(head.len() + 32);
    for line in lines(head).filter(|l| header_value(l, HEADER).is_none()) {
        out.extend_from_slice(line);
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"Sec-WebSocket-Protocol: ");
    out.extend_from_slice(SDK_V1.as_bytes());
    out.extend_from_slice(b"\r\n\r\n");
    (Cow::Owned(out), true)
}

/// The SDK's answer head (up to and with its blank line) with its chosen subprotocol
/// `foxglove.sdk.v1` named `foxglove.websocket.v1`, for a client that offered that.
pub fn answer_for_client(head: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(head.len() + 8);
    for line in lines(head) {
        if header_value(line, HEADER) == Some(SDK_V1.as_bytes()) {
            out.extend_from_slice(b"Sec-WebSocket-Protocol: ");
            out.extend_from_slice(WEBSOCKET_V1.as_bytes());
        } else {
            out.extend_from_slice(line);
        }
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"\r\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(protocols: &[&str]) -> Vec<u8> {
        let mut r = b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n".to_vec();
        for p in protocols {
            r.extend_from_slice(format!("sec-WebSocket-Protocol:  {p} \r\n").as_bytes());
        }
        r.extend_from_slice(b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n");
        r
    }

    /// What the SDK chooses (its `select_subprotocol`: the newest of its names offered)
    /// is never changed: an offer naming one of them passes as it is.
    #[test]
    fn offers_the_sdk_knows_pass_as_they_are() {
        for offer in [
            vec![SDK_V1],
            vec![SDK_V1_1],
            vec!["foxglove.websocket.v1, foxglove.sdk.v1"],
            vec![WEBSOCKET_V1, SDK_V1_1],
            vec!["chat"],
            vec![],
        ] {
            let head = request(&offer);
            let (got, alias) = request_for_sdk(&head);
            assert_eq!((&*got, alias), (&head[..], false), "{offer:?}");
        }
    }

    /// `foxglove.websocket.v1` alone (Lichtblick before #819, Foxglove Studio 1.x), in
    /// one header or several, in any case of the header's name: the SDK is offered
    /// `foxglove.sdk.v1` in one header, every other line kept in order.
    #[test]
    fn the_websocket_v1_offer_reaches_the_sdk_as_sdk_v1() {
        for offer in [vec![WEBSOCKET_V1], vec!["x.y", "foxglove.websocket.v1 ,z"]] {
            let head = request(&offer);
            let (got, alias) = request_for_sdk(&head);
            assert!(alias, "{offer:?}");
            let text = String::from_utf8(got.into_owned()).unwrap();
            assert_eq!(
                text,
                "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n\
                 Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\
                 Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
            );
            assert_eq!(offered(text.as_bytes()), [SDK_V1.as_bytes()]);
        }
    }

    #[test]
    fn the_answer_names_the_subprotocol_the_client_offered() {
        let answer = b"HTTP/1.1 101 Switching Protocols\r\nconnection: Upgrade\r\n\
                       sec-websocket-protocol: foxglove.sdk.v1\r\nupgrade: websocket\r\n\r\n";
        let got = String::from_utf8(answer_for_client(answer)).unwrap();
        assert_eq!(
            got,
            "HTTP/1.1 101 Switching Protocols\r\nconnection: Upgrade\r\n\
             Sec-WebSocket-Protocol: foxglove.websocket.v1\r\nupgrade: websocket\r\n\r\n"
        );
        let other = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(answer_for_client(other), other);
    }
}
