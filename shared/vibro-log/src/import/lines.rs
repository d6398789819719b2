//! A line reader with a cap on the length of a line, shared by the CSV import and
//! `vibrocomp estimate`: a file that is not line-based text (`/dev/zero`, a binary
//! file, a never-ending line) fails at [`MAX_LINE_BYTES`] with the line's number and
//! first bytes, instead of being buffered whole (gigabytes in seconds) and echoed into
//! an error.

use std::io::{BufRead, ErrorKind};
use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// The longest line read, line ending excluded: 64 KiB. A row of the CSV files read
/// here is under 200 bytes, so this only stops input that is not such a file.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Bytes of a too-long line shown in its error (escaped).
const HEAD_BYTES: usize = 60;

/// Reads the lines of `R` one at a time into a caller's buffer (reused: no allocation
/// per line), never holding more than [`MAX_LINE_BYTES`] plus a line ending of a line.
///
/// ```
/// use vibro_log::import::LineReader;
/// # fn main() -> vibro_log::Result<()> {
/// let mut lines = LineReader::new(&b"time_s,x\r\n0,1\n"[..], "a.csv");
/// let mut text = Vec::new();
/// assert_eq!(lines.read_line(&mut text)?, Some(10));
/// assert_eq!((text.as_slice(), lines.line()), (&b"time_s,x"[..], 1));
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub struct LineReader<R> {
    reader: R,
    path: PathBuf,
    /// 1-based number of the last line read (0 before the first).
    line: u64,
    cap: usize,
}

impl<R: BufRead> LineReader<R> {
    /// Lines of `reader`; `path` names the file in errors.
    pub fn new(reader: R, path: impl AsRef<Path>) -> LineReader<R> {
        LineReader::with_cap(reader, path, MAX_LINE_BYTES)
    }

    /// With another cap than [`MAX_LINE_BYTES`] (tests).
    pub fn with_cap(reader: R, path: impl AsRef<Path>, cap: usize) -> LineReader<R> {
        LineReader {
            reader,
            path: path.as_ref().to_path_buf(),
            line: 0,
            cap,
        }
    }

    /// The number of the last line read, 1-based (comment and blank lines count).
    pub fn line(&self) -> u64 {
        self.line
    }

    /// Reads the next line into `text` without its line ending (`\n`, `\r\n`); returns
    /// the bytes it took from the file, or `None` at the end of the file. A line longer
    /// than the cap is [`Error::LineTooLong`], found after reading at most the cap
    /// plus two bytes of it.
    pub fn read_line(&mut self, text: &mut Vec<u8>) -> Result<Option<usize>> {
        text.clear();
        // Room for the cap and a `\r\n`: one byte more is a line too long.
        let room = self.cap.saturating_add(2);
        let mut taken = 0usize;
        loop {
            let available = match self.reader.fill_buf() {
                Ok(b) => b,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(source) => {
                    return Err(Error::ReadInput {
                        path: self.path.clone(),
                        action: format!("cannot read line {}", self.line + 1),
                        source,
                    })
                }
            };
            if available.is_empty() {
                break;
            }
            let (n, done) = match available.iter().position(|&b| b == b'\n') {
                Some(i) => (i + 1, true),
                None => (available.len(), false),
            };
            if text.len() + n > room {
                let head = HEAD_BYTES.saturating_sub(text.len()).min(n);
                text.extend_from_slice(&available[..head]);
                return Err(self.too_long(text));
            }
            text.extend_from_slice(&available[..n]);
            self.reader.consume(n);
            taken += n;
            if done {
                break;
            }
        }
        if taken == 0 {
            return Ok(None);
        }
        // The `\n`, then every `\r` before it (as the readers before this one trimmed).
        if text.last() == Some(&b'\n') {
            text.pop();
        }
        while text.last() == Some(&b'\r') {
            text.pop();
        }
        if text.len() > self.cap {
            return Err(self.too_long(text));
        }
        self.line += 1;
        Ok(Some(taken))
    }

    fn too_long(&self, text: &[u8]) -> Error {
        let mut head = &text[..text.len().min(HEAD_BYTES)];
        while let [rest @ .., b'\r' | b'\n'] = head {
            head = rest;
        }
        Error::LineTooLong {
            path: self.path.clone(),
            line: self.line + 1,
            cap: self.cap,
            head: head.escape_ascii().to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(input: &[u8], cap: usize) -> Vec<Result<(Vec<u8>, u64)>> {
        // A tiny buffer, so that lines span several `fill_buf`s.
        let reader = std::io::BufReader::with_capacity(3, input);
        let mut lines = LineReader::with_cap(reader, "t.csv", cap);
        let mut out = Vec::new();
        let mut text = Vec::new();
        loop {
            match lines.read_line(&mut text) {
                Ok(None) => return out,
                Ok(Some(_)) => out.push(Ok((text.clone(), lines.line()))),
                Err(e) => {
                    out.push(Err(e));
                    return out;
                }
            }
        }
    }

    #[test]
    fn lines_lose_their_endings_and_keep_their_numbers() {
        let got: Vec<_> = lines(b"a,b\r\n\n12345\nlast", 5)
            .into_iter()
            .map(|r| r.map_err(|e| e.to_string()))
            .collect();
        assert_eq!(
            got,
            vec![
                Ok((b"a,b".to_vec(), 1)),
                Ok((b"".to_vec(), 2)),
                Ok((b"12345".to_vec(), 3)),
                Ok((b"last".to_vec(), 4)),
            ]
        );
    }

    #[test]
    fn a_line_over_the_cap_names_its_line_the_cap_and_its_first_bytes() {
        let got = lines(b"ok\n123456\r\nmore", 5);
        assert!(got[0].is_ok());
        let e = got[1].as_ref().unwrap_err().to_string();
        assert!(e.starts_with("t.csv line 2: longer than 5 bytes"), "{e}");
        assert!(e.contains("\"123456\""), "{e}");
        // At the end of the file too, without a line ending.
        let e = lines(b"123456", 5)[0].as_ref().unwrap_err().to_string();
        assert!(e.contains("line 1:"), "{e}");
    }

    #[test]
    fn an_endless_line_stops_at_the_cap_with_its_first_bytes_escaped() {
        // A reader that never ends, like /dev/zero.
        let zero = std::io::BufReader::new(std::io::repeat(0));
        let mut lines = LineReader::new(zero, "/dev/zero");
        let mut text = Vec::new();
        let e = lines.read_line(&mut text).unwrap_err().to_string();
        assert!(
            text.capacity() <= 2 * (MAX_LINE_BYTES + 2),
            "{}",
            text.capacity()
        );
        assert!(e.contains(&"\\x00".repeat(HEAD_BYTES)), "{e}");
        assert!(!e.contains(&"\\x00".repeat(HEAD_BYTES + 1)), "{e}");
        assert!(e.len() < 1024, "{} bytes: {e}", e.len());
    }
}
