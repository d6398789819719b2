//! What the guard reads of the bytes it relays, without copying or decoding them: where
//! a client's HTTP upgrade request ends, and where each WebSocket frame starts and how
//! long it says it is (RFC 6455 §5.2), so that a frame or message past the cap is caught
//! at its header, before any of its payload is read. Sans-io: the caller feeds the
//! bytes as they come, in pieces of any size.

/// Where the HTTP request head that `buf` starts with ends (just after its blank line),
/// if it is complete. `from` is how much of `buf` was searched already (the search
/// resumes 3 bytes before it, where a `\r\n\r\n` split across reads may start).
pub fn head_end(buf: &[u8], from: usize) -> Option<usize> {
    let start = from.saturating_sub(3);
    buf.get(start..)?
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map(|i| start + i + 4)
}

/// Finds the end of an HTTP head (its blank line) in bytes fed piece by piece.
#[derive(Debug, Clone, Default)]
pub struct HeadEnd {
    /// Bytes of `\r\n\r\n` matched so far.
    matched: usize,
}

impl HeadEnd {
    /// Where in `bytes` the head ends (just after its blank line), if it ends there;
    /// once it has, the scanner is not to be fed again.
    pub fn feed(&mut self, bytes: &[u8]) -> Option<usize> {
        const END: &[u8; 4] = b"\r\n\r\n";
        for (i, &b) in bytes.iter().enumerate() {
            // The pattern overlaps itself only in `\r`, where a mismatch restarts.
            self.matched = if b == END[self.matched] {
                self.matched + 1
            } else {
                usize::from(b == b'\r')
            };
            if self.matched == END.len() {
                return Some(i + 1);
            }
        }
        None
    }
}

/// A frame or message longer than the cap, found at its header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Oversized {
    /// Where, in the bytes of the [`FrameScanner::feed`] call, the offending frame's
    /// header starts (what comes before is whole frames, and may still be passed on);
    /// `None` when it started in an earlier call's bytes.
    pub at: Option<usize>,
    /// The frame's payload length, or the message's so far with it, bytes.
    pub bytes: u64,
}

/// Follows one direction of a WebSocket connection frame by frame.
#[derive(Debug, Clone)]
pub struct FrameScanner {
    max_message_bytes: u64,
    header: [u8; 14],
    /// Header bytes gathered so far (0 between frames).
    have: usize,
    /// Payload bytes of the current frame still to pass.
    payload_left: u64,
    /// Payload bytes of the data message being assembled from fragments (§5.4).
    message_bytes: u64,
    frames: u64,
    /// The payload of the Pong frame being read (a control frame's is at most 125
    /// bytes, §5.5), still masked, and its mask key; `None` outside a Pong.
    pong: Option<Pong>,
    /// Where the first frame to end in the last bytes fed ended, in them.
    first_end: Option<usize>,
}

/// A Pong frame's payload gathered as it passes.
#[derive(Debug, Clone)]
struct Pong {
    mask: [u8; 4],
    len: usize,
    have: usize,
    payload: [u8; MAX_CONTROL_PAYLOAD],
}

/// The longest payload of a control frame (RFC 6455 §5.5).
pub const MAX_CONTROL_PAYLOAD: usize = 125;

/// The opcode of a Pong frame (§5.5.3).
const PONG: u8 = 0xA;

impl FrameScanner {
    /// A scanner refusing any frame, and any message (its fragments summed), whose
    /// payload is longer than `max_message_bytes`.
    pub fn new(max_message_bytes: u64) -> Self {
        Self {
            max_message_bytes,
            header: [0; 14],
            have: 0,
            payload_left: 0,
            message_bytes: 0,
            frames: 0,
            pong: None,
            first_end: None,
        }
    }

    /// Whether the bytes so far end on a frame boundary (a frame may be inserted here).
    pub fn at_boundary(&self) -> bool {
        self.have == 0 && self.payload_left == 0
    }

    /// Frames whose header was read so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Where, in the bytes of the last [`FrameScanner::feed`], the first frame to end in
    /// them ended (a frame may be inserted there), if one did.
    pub fn first_frame_end(&self) -> Option<usize> {
        self.first_end
    }

    /// Follows `bytes`, the next ones of the stream. Once this returns an error, the
    /// stream is not to be followed further.
    pub fn feed(&mut self, bytes: &[u8]) -> Result<(), Oversized> {
        self.feed_pongs(bytes, |_| {})
    }

    /// [`FrameScanner::feed`], and `on_pong` called with the (unmasked) payload of each
    /// Pong frame that ends in `bytes` (of at most [`MAX_CONTROL_PAYLOAD`] bytes: a longer
    /// one breaks the protocol, and its payload is not gathered).
    pub fn feed_pongs(
        &mut self,
        bytes: &[u8],
        mut on_pong: impl FnMut(&[u8]),
    ) -> Result<(), Oversized> {
        let mut i = 0;
        // Where the header being read started in `bytes`, if it did.
        let mut header_start = None;
        self.first_end = None;
        while i < bytes.len() {
            if self.payload_left > 0 {
                let skip = self.payload_left.min((bytes.len() - i) as u64);
                if let Some(p) = self.pong.as_mut() {
                    // `skip` <= the Pong's length left, at most 125.
                    let n = skip as usize;
                    p.payload[p.have..p.have + n].copy_from_slice(&bytes[i..i + n]);
                    p.have += n;
                }
                self.payload_left -= skip;
                i += skip as usize;
                if self.payload_left == 0 {
                    self.first_end.get_or_insert(i);
                    if let Some(mut p) = self.pong.take() {
                        on_pong(p.unmask());
                    }
                }
                continue;
            }
            if self.have == 0 {
                header_start = Some(i);
            }
            self.header[self.have] = bytes[i];
            self.have += 1;
            i += 1;
            if self.have < 2 {
                continue;
            }
            let len7 = self.header[1] & 0x7F;
            let masked = self.header[1] & 0x80 != 0;
            let ext = match len7 {
                126 => 2,
                127 => 8,
                _ => 0,
            };
            let need = 2 + ext + if masked { 4 } else { 0 };
            if self.have < need {
                continue;
            }
            let len = match ext {
                0 => u64::from(len7),
                2 => u64::from(u16::from_be_bytes([self.header[2], self.header[3]])),
                _ => {
                    let mut b = [0; 8];
                    b.copy_from_slice(&self.header[2..10]);
                    u64::from_be_bytes(b)
                }
            };
            let opcode = self.header[0] & 0x0F;
            let fin = self.header[0] & 0x80 != 0;
            let message = if opcode >= 8 {
                // A control frame (close, ping, pong) stands alone, between fragments too.
                len
            } else {
                if opcode != 0 {
                    self.message_bytes = 0;
                }
                self.message_bytes.saturating_add(len)
            };
            if len > self.max_message_bytes || message > self.max_message_bytes {
                self.have = 0;
                return Err(Oversized {
                    at: header_start,
                    bytes: message,
                });
            }
            if opcode < 8 {
                self.message_bytes = if fin { 0 } else { message };
            }
            self.have = 0;
            self.payload_left = len;
            self.frames += 1;
            if len == 0 {
                self.first_end.get_or_insert(i);
            }
            if opcode == PONG && len <= MAX_CONTROL_PAYLOAD as u64 {
                let mut mask = [0; 4];
                if masked {
                    mask.copy_from_slice(&self.header[2 + ext..2 + ext + 4]);
                }
                let pong = Pong {
                    mask,
                    len: len as usize,
                    have: 0,
                    payload: [0; MAX_CONTROL_PAYLOAD],
                };
                if len == 0 {
                    on_pong(&[]);
                } else {
                    self.pong = Some(pong);
                }
            }
        }
        Ok(())
    }
}

impl Pong {
    /// The payload with its mask removed (§5.3).
    fn unmask(&mut self) -> &[u8] {
        for (i, b) in self.payload[..self.len].iter_mut().enumerate() {
            *b ^= self.mask[i % 4];
        }
        &self.payload[..self.len]
    }
}

/// An unmasked Ping frame with `payload` (at most 125 bytes kept), as a server sends it
/// (§5.5.2): the client is to answer with a Pong of the same payload.
pub fn server_ping_frame(payload: &[u8]) -> Vec<u8> {
    let payload = &payload[..payload.len().min(MAX_CONTROL_PAYLOAD)];
    let mut f = Vec::with_capacity(2 + payload.len());
    f.push(0x89);
    f.push(payload.len() as u8);
    f.extend_from_slice(payload);
    f
}

/// A masked Close frame (RFC 6455 §5.5.1) with `code` and no reason, as a client sends
/// it: what the guard tells the Foxglove server for a client that went away, so that
/// the server ends the connection as a client closing it instead of failing its sends.
/// The mask key is zero (the payload is sent as it is): the frame never leaves this
/// machine, and the key only guards against proxies' caches (§10.3).
pub fn client_close_frame(code: u16) -> [u8; 8] {
    let [hi, lo] = code.to_be_bytes();
    [0x88, 0x80 | 2, 0, 0, 0, 0, hi, lo]
}

/// An unmasked Close frame with `code` and `reason` (at most 123 bytes kept), as a
/// server sends it.
pub fn server_close_frame(code: u16, reason: &str) -> Vec<u8> {
    let mut end = reason.len().min(123);
    while !reason.is_char_boundary(end) {
        end -= 1;
    }
    let reason = &reason.as_bytes()[..end];
    let mut f = Vec::with_capacity(4 + reason.len());
    f.push(0x88);
    f.push(2 + reason.len() as u8);
    f.extend_from_slice(&code.to_be_bytes());
    f.extend_from_slice(reason);
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame as a client sends it (masked with key `k`), its header built by hand
    /// after RFC 6455 §5.2's figure, independently of the scanner.
    fn frame(fin: bool, opcode: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![(u8::from(fin) << 7) | opcode];
        let n = payload.len();
        if n < 126 {
            f.push(0x80 | n as u8);
        } else if n <= 0xFFFF {
            f.push(0x80 | 126);
            f.extend_from_slice(&(n as u16).to_be_bytes());
        } else {
            f.push(0x80 | 127);
            f.extend_from_slice(&(n as u64).to_be_bytes());
        }
        let k = [1u8, 2, 3, 4];
        f.extend_from_slice(&k);
        f.extend(payload.iter().enumerate().map(|(i, b)| b ^ k[i % 4]));
        f
    }

    #[test]
    fn the_head_ends_at_the_first_blank_line_split_or_not() {
        let req = b"GET / HTTP/1.1\r\nHost: x\r\n\r\n\x81\x80";
        assert_eq!(head_end(req, 0), Some(req.len() - 2));
        for cut in 1..req.len() {
            let first = head_end(&req[..cut], 0);
            let then = head_end(req, cut);
            assert_eq!(first.or(then), Some(req.len() - 2), "cut at {cut}");
        }
        assert_eq!(head_end(b"GET / HTTP/1.1\r\n", 0), None);
        // The same, fed in pieces, with near misses before the blank line.
        let answer = b"HTTP/1.1 101 OK\r\nA: \r\r\n\n\r\n\r\n\x81\x00";
        let end = answer.len() - 2;
        for piece in 1..answer.len() {
            let mut h = HeadEnd::default();
            let found = answer
                .chunks(piece)
                .enumerate()
                .find_map(|(k, c)| h.feed(c).map(|e| k * piece + e));
            assert_eq!(found, Some(end), "pieces of {piece}");
        }
    }

    /// Frames of each length encoding pass whole and in pieces of every size; the scanner
    /// is on a boundary exactly between them.
    #[test]
    fn frames_of_each_length_encoding_are_followed_in_any_pieces() {
        let mut stream = Vec::new();
        let mut ends = Vec::new();
        for n in [0, 1, 125, 126, 127, 65_535, 65_536, 70_000] {
            stream.extend(frame(true, 2, &vec![7; n]));
            ends.push(stream.len());
        }
        for piece in [1, 2, 3, 7, 1000, stream.len()] {
            let mut s = FrameScanner::new(1 << 20);
            let mut fed = 0;
            for chunk in stream.chunks(piece) {
                s.feed(chunk).unwrap();
                fed += chunk.len();
                assert_eq!(
                    s.at_boundary(),
                    ends.contains(&fed),
                    "piece {piece} at {fed}"
                );
            }
            assert_eq!(s.frames(), ends.len() as u64);
        }
        // Where the first frame ends in each piece, against the ends computed above.
        for piece in [1, 2, 3, 7, 1000, 70_001, stream.len()] {
            let mut s = FrameScanner::new(1 << 20);
            for (k, chunk) in stream.chunks(piece).enumerate() {
                s.feed(chunk).unwrap();
                let from = k * piece;
                let want = ends
                    .iter()
                    .find(|&&e| e > from && e <= from + chunk.len())
                    .map(|e| e - from);
                assert_eq!(s.first_frame_end(), want, "piece {piece} at {from}");
            }
        }
    }

    /// A frame past the cap is refused at its header, whatever its length encoding, and
    /// the error says where it starts; a 16 MiB frame is refused before its payload.
    #[test]
    fn a_frame_past_the_cap_is_refused_at_its_header() {
        let ok = frame(true, 1, b"{\"op\":\"subscribe\"}");
        for n in [126usize, 65_536] {
            let mut s = FrameScanner::new(125);
            let mut bytes = ok.clone();
            bytes.extend(frame(true, 2, &vec![0; n]));
            let e = s.feed(&bytes).unwrap_err();
            assert_eq!(
                e,
                Oversized {
                    at: Some(ok.len()),
                    bytes: n as u64
                }
            );
        }
        // Only the header of a 16 MiB frame: enough to refuse it.
        let mut s = FrameScanner::new(64 * 1024);
        let mut header = vec![0x82, 0x80 | 127];
        header.extend_from_slice(&(16u64 << 20).to_be_bytes());
        header.extend_from_slice(&[0; 4]);
        s.feed(&header[..13]).unwrap();
        let e = s.feed(&header[13..]).unwrap_err();
        assert_eq!(
            (e.at, e.bytes),
            (None, 16 << 20),
            "begun in the earlier piece"
        );
        // A length with the top bit set (invalid, §5.2) is past any cap.
        let mut s = FrameScanner::new(u64::MAX - 1);
        let mut header = vec![0x82, 0x80 | 127];
        header.extend_from_slice(&u64::MAX.to_be_bytes());
        header.extend_from_slice(&[0; 4]);
        assert!(s.feed(&header).is_err());
    }

    /// Fragments add up to their message; a control frame between them does not count,
    /// and a new message starts from zero.
    #[test]
    fn fragments_add_up_to_their_message() {
        let cap = 100;
        let mut s = FrameScanner::new(cap);
        let mut bytes = frame(false, 1, &[b'a'; 60]);
        bytes.extend(frame(true, 9, b"ping"));
        bytes.extend(frame(true, 0, &[b'a'; 40]));
        bytes.extend(frame(true, 1, &[b'b'; 100]));
        s.feed(&bytes).unwrap();
        let before = bytes.len();
        bytes.extend(frame(false, 2, &[0; 60]));
        bytes.extend(frame(true, 0, &[0; 41]));
        let mut s = FrameScanner::new(cap);
        let e = s.feed(&bytes).unwrap_err();
        assert_eq!(e.bytes, 101);
        assert_eq!(e.at, Some(before + 2 + 4 + 60));
    }

    #[test]
    fn close_frames_carry_their_code() {
        assert_eq!(
            client_close_frame(1001),
            [0x88, 0x82, 0, 0, 0, 0, 0x03, 0xE9]
        );
        let f = server_close_frame(1009, "too big");
        assert_eq!(f[..4], [0x88, 9, 0x03, 0xF1]);
        assert_eq!(&f[4..], b"too big");
        assert_eq!(server_close_frame(1009, &"é".repeat(100)).len(), 4 + 122);
    }
}
