//! Hostile input quoted in a message: at most a line's worth of it.
//!
//! An error message names the offending value, but a value read from a file or a peer
//! can be megabytes long, a single line of carriage returns, or a nest of brackets. A
//! message quotes at most [`ECHO_MAX_CHARS`] characters of it, with every control
//! character (CR, LF, tab, escape, ...) written as its escape so that the quote stays on
//! one line and cannot move a terminal's cursor, and says how much was cut.

use std::borrow::Cow;
use std::fmt::Write as _;

/// How many characters of an input a message quotes: about one terminal line.
pub const ECHO_MAX_CHARS: usize = 120;

/// `text` as a message may quote it ([module docs](self)): unchanged when it is short
/// and printable, else its first [`ECHO_MAX_CHARS`] characters with control characters
/// escaped, followed by `… (N more bytes cut)` when anything was left out.
///
/// ```
/// assert_eq!(vibro_toml::echo::excerpt("k2_ppm"), "k2_ppm");
/// let cr = "\r".repeat(50_000);
/// let quoted = vibro_toml::echo::excerpt(&cr);
/// assert!(quoted.len() < 300 && quoted.ends_with("… (49880 more bytes cut)"), "{quoted}");
/// assert!(!quoted.contains('\r'));
/// ```
pub fn excerpt(text: &str) -> Cow<'_, str> {
    let clean = |c: char| !c.is_control();
    let mut end = text.len();
    let mut printable = true;
    for (count, (i, c)) in text.char_indices().enumerate() {
        if count == ECHO_MAX_CHARS {
            end = i;
            break;
        }
        printable &= clean(c);
    }
    if end == text.len() && printable {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(end + 32);
    for c in text[..end].chars() {
        if clean(c) {
            out.push(c);
        } else {
            out.extend(c.escape_default());
        }
    }
    if end < text.len() {
        let _ = write!(out, "… ({} more bytes cut)", text.len() - end);
    }
    Cow::Owned(out)
}

/// [`excerpt`] of bytes that may not be UTF-8: each invalid byte is shown as `\xNN`,
/// and the count of cut bytes is of the input's bytes.
pub fn excerpt_bytes(bytes: &[u8]) -> String {
    let mut out = String::new();
    let mut shown_chars = 0;
    let mut used = 0;
    'chunks: for chunk in bytes.utf8_chunks() {
        for c in chunk.valid().chars() {
            if shown_chars == ECHO_MAX_CHARS {
                break 'chunks;
            }
            if c.is_control() {
                out.extend(c.escape_default());
            } else {
                out.push(c);
            }
            shown_chars += 1;
            used += c.len_utf8();
        }
        for b in chunk.invalid() {
            if shown_chars == ECHO_MAX_CHARS {
                break 'chunks;
            }
            let _ = write!(out, "\\x{b:02x}");
            shown_chars += 1;
            used += 1;
        }
    }
    if used < bytes.len() {
        let _ = write!(out, "… ({} more bytes cut)", bytes.len() - used);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_printable_text_is_kept_and_long_or_control_text_is_cut_and_escaped() {
        assert!(matches!(excerpt("sensor_hz = 5e3"), Cow::Borrowed(_)));
        assert_eq!(excerpt("a\rb"), "a\\rb");
        let long = "é".repeat(1000);
        let q = excerpt(&long);
        assert_eq!(q.chars().filter(|&c| c == 'é').count(), ECHO_MAX_CHARS);
        assert!(q.ends_with(&format!(
            "… ({} more bytes cut)",
            2 * (1000 - ECHO_MAX_CHARS)
        )));
        let nested = "[".repeat(200_000);
        assert!(excerpt(&nested).len() < 200);
        assert_eq!(excerpt_bytes(b"ab\xffc\rd"), "ab\\xffc\\rd");
        let q = excerpt_bytes(&[b'x'; 10_000]);
        assert!(
            q.ends_with(&format!("… ({} more bytes cut)", 10_000 - ECHO_MAX_CHARS)),
            "{q}"
        );
    }
}
