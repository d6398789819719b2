//! The lab's CSV tables read within bounds: one reader for every caller (a campaign
//! table from a file or as text, through [`crate::inputs::load`]: the `lab` commands
//! and the Python package; a manifest's runs CSV, [`crate::campaign`]).
//!
//! A table is input from outside: `/dev/zero`, a file without a line ending, a line of a
//! million commas or two million rows must be refused after reading at most what the
//! bounds allow, with a message that names the file, the line, the value and the rule,
//! never slurped whole or echoed whole. The bounds ([`MAX_LINE_BYTES`],
//! [`MAX_COLUMNS`], [`MAX_ROWS`], [`MAX_TEXT_CELL_BYTES`], [`MAX_PASSPORT_BYTES`]) are
//! set from what a real campaign holds, with a wide margin (their docs say why).
//!
//! The bytes are read through a fixed buffer, a line at a time; every line ending
//! (`\n`, `\r\n`, a lone `\r` of old Mac files) ends a line, so that line numbers are
//! the file's whatever its convention (blank and comment lines counted), and a line
//! longer than the cap is refused once the cap is passed. A UTF-8 byte order mark is skipped; UTF-16 (a byte
//! order mark `FF FE` or `FE FF`) and cells that are not UTF-8 (Latin-1 bytes) are
//! refused by line and column. A quoted input is shown by its excerpt
//! ([`vibro_toml::echo`]): at most a line's worth, control characters escaped.
//!
//! ```
//! use vibro_lab::table_input::TableReader;
//! let text = "# a comment\r\nrun_id,x\r\nR1,0.5\r\n";
//! let mut reader = TableReader::new(text.as_bytes(), "t.csv").unwrap();
//! assert_eq!(reader.header().unwrap(), ["run_id", "x"]);
//! // A row, or its problem (a cell too many, not UTF-8): reading goes on after one.
//! let row = reader.next_row().unwrap().unwrap().unwrap();
//! assert_eq!((row.line, row.cells.as_slice()), (3, &["R1".to_string(), "0.5".into()][..]));
//! assert!(reader.next_row().unwrap().is_none());
//!
//! // A file that is not line-based text stops at the cap on a line.
//! let zero = std::io::Read::take(std::io::repeat(0), 1 << 30);
//! let mut reader = TableReader::new(zero, "/dev/zero").unwrap();
//! let e = reader.header().unwrap_err().to_string();
//! assert!(e.starts_with("/dev/zero: line 1: longer than 65536 bytes"), "{e}");
//! assert!(e.len() < 1024 && e.ends_with(" bytes cut)\""), "{e}");
//! ```

use std::io::{BufRead, ErrorKind, Read};

use vibro_toml::echo::{excerpt, excerpt_bytes, ECHO_MAX_CHARS};

use crate::{Error, Result};

/// The longest line read, line ending excluded: `log import`'s cap (64 KiB), one home
/// for both readers (`vibro_log::import::MAX_LINE_BYTES`). A row of a campaign table is
/// under 1 KiB (19 numbers written in full, `{:e}`, are about 400 bytes, the run id and
/// passport a few tens, extras 20 each), so this only stops input that is not a table.
pub const MAX_LINE_BYTES: usize = vibro_log::import::MAX_LINE_BYTES;

/// Most columns of a table: the 19 required ones and 45 extras. The lab reads five
/// extras (`vibrating_s`, `band_lo_hz`, `band_hi_hz`, `aB3_u_g`, `sigma3_u_g`), the
/// simulator writes three more (`tp`, `angle_deg`), and a rig may log a few of its own
/// (temperature, fixture, operator's notes as numbers); tens more is not a campaign.
/// Each extra column is a value kept on every row (about 60 bytes with its name), so
/// the columns times [`MAX_ROWS`] bound the table's memory.
pub const MAX_COLUMNS: usize = 64;

/// Most data rows of a table (comment and blank lines not counted). A shake-table
/// campaign is tens to a few thousand conditions (RIG.md: twelve units, each a few
/// orientations, frequencies and amplitudes of a 5-minute record: 1000 rows are 3.5
/// days of shaker time); a flight's log cut into 0.5 s windows gives 3 rows a window,
/// 3600 for a 600 s flight (RIG.md's Cyclone-4), 518 400 for a day-long soak. A million
/// rows is twice that day, and about 1 GB of memory for the table and its prediction.
pub const MAX_ROWS: usize = 1_000_000;

/// Longest `run_id` (and any text cell other than a passport), in bytes: a name of a
/// few words (`vibro_toml::bounds::MAX_NAME_BYTES`, the configurations' bound on an
/// id).
pub const MAX_TEXT_CELL_BYTES: usize = vibro_toml::bounds::MAX_NAME_BYTES;

/// Longest `passport` cell, in bytes: a path (`vibro_toml::bounds::MAX_PATH_BYTES`,
/// Linux's `PATH_MAX`); a longer one cannot be opened.
pub const MAX_PASSPORT_BYTES: usize = vibro_toml::bounds::MAX_PATH_BYTES;

/// Problems listed in one error before the rest are only counted: as `log import`
/// (`vibro_log::import::MAX_PROBLEMS`), a screenful.
pub const MAX_LISTED_PROBLEMS: usize = vibro_log::import::MAX_PROBLEMS;

/// Largest CSV campaign manifest or runs CSV read (`crate::campaign`), bytes (16 MiB):
/// [`crate::campaign::MAX_RUNS`] runs of up to 1.6 KiB each (two paths and a dozen
/// numbers; a run's row is under 200 bytes in the rig generator's files).
pub const MAX_RUNS_CSV_BYTES: u64 = 16 << 20;

/// The text of the file at `path`, if it has at most `max_bytes` bytes: a bigger file
/// is refused by the size it says it has before anything is read, and one that does
/// not say (a device, a pipe) is read no further than one byte past the bound. The
/// error of a file too big says its size, `what` the file is and the bound; the others
/// are the operating system's, or invalid UTF-8.
///
/// ```
/// use vibro_lab::table_input::read_text;
/// let e = read_text("/dev/zero".as_ref(), 1000, "a runs CSV").unwrap_err();
/// assert_eq!(e.to_string(), "more than 1000 bytes: a runs CSV holds at most 1000 bytes");
/// ```
pub fn read_text(path: &std::path::Path, max_bytes: u64, what: &str) -> std::io::Result<String> {
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    let too_big = |size: String| {
        std::io::Error::new(
            ErrorKind::FileTooLarge,
            format!("{size}: {what} holds at most {max_bytes} bytes"),
        )
    };
    if meta.is_file() && meta.len() > max_bytes {
        return Err(too_big(format!("{} bytes", meta.len())));
    }
    let mut bytes = Vec::new();
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big(format!("more than {max_bytes} bytes")));
    }
    String::from_utf8(bytes).map_err(|e| {
        std::io::Error::new(
            ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (byte {:#04x} at offset {})",
                e.as_bytes()
                    .get(e.utf8_error().valid_up_to())
                    .copied()
                    .unwrap_or(0),
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// A file's problems as an [`Error::Table`]: at most [`MAX_LISTED_PROBLEMS`] listed, the
/// others counted.
#[derive(Debug, Default)]
pub struct Problems {
    listed: Vec<String>,
    more: usize,
}

impl Problems {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, problem: String) {
        if self.listed.len() < MAX_LISTED_PROBLEMS {
            self.listed.push(problem);
        } else {
            self.more += 1;
        }
    }

    /// Every problem found so far, listed or counted.
    pub fn count(&self) -> usize {
        self.listed.len() + self.more
    }

    pub fn is_empty(&self) -> bool {
        self.count() == 0
    }

    /// The problems as lines of a message, the count of those not listed last.
    pub fn into_lines(self) -> Vec<String> {
        let mut lines = self.listed;
        if self.more > 0 {
            lines.push(format!(
                "... and {} more problems (the first {MAX_LISTED_PROBLEMS} are listed)",
                self.more
            ));
        }
        lines
    }
}

/// One data row: its line (1-based, the file's) and its cells, trimmed.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub line: usize,
    pub cells: Vec<String>,
}

/// A table read within the bounds ([module docs](self)): the header, then one row at a
/// time. Lines are read through a fixed buffer (64 KiB) into one line's
/// buffer, never more than [`MAX_LINE_BYTES`] of it; cells are split as CSV (RFC 4180:
/// a cell opening with `"` is quoted, `""` in it is a `"`; a quoted cell ends on its
/// line), trimmed. Blank lines and lines opening with `#` are skipped (and counted).
pub struct TableReader<R: Read> {
    reader: std::io::BufReader<std::io::Chain<std::io::Cursor<Vec<u8>>, R>>,
    name: String,
    /// 1-based number of the last line read.
    line: usize,
    /// The last line ended with a `\r`: a `\n` first on the next is the same ending.
    after_cr: bool,
    /// The current line, without its ending.
    text: Vec<u8>,
    /// The current line's cells, unquoted, and where each ends in `cells_text`.
    cells_text: Vec<u8>,
    cell_ends: Vec<usize>,
    width: usize,
    rows: usize,
}

/// Bytes read from the input at once.
const BUFFER_BYTES: usize = 1 << 16;

impl<R: Read> TableReader<R> {
    /// A table read from `reader`; `name` stands for it in messages. Its first bytes
    /// are looked at for a byte order mark: UTF-8's is skipped, UTF-16's refused.
    pub fn new(mut reader: R, name: &str) -> Result<Self> {
        let mut start = Vec::with_capacity(3);
        let mut byte = [0u8; 1];
        while start.len() < 3 {
            match reader.read(&mut byte) {
                Ok(0) => break,
                Ok(_) => start.push(byte[0]),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(Error::Io {
                        path: name.to_string(),
                        source,
                    })
                }
            }
            if start.len() == 2 && (start == [0xff, 0xfe] || start == [0xfe, 0xff]) {
                return Err(refused(
                    name,
                    format!(
                        "UTF-16 text (byte order mark {:02X} {:02X}): a table is UTF-8 text; \
                         save it as UTF-8 (\"CSV UTF-8\")",
                        start[0], start[1]
                    ),
                ));
            }
        }
        if start == [0xef, 0xbb, 0xbf] {
            start.clear();
        }
        Ok(Self {
            reader: std::io::BufReader::with_capacity(
                BUFFER_BYTES,
                std::io::Cursor::new(start).chain(reader),
            ),
            name: name.to_string(),
            line: 0,
            after_cr: false,
            text: Vec::new(),
            cells_text: Vec::new(),
            cell_ends: Vec::new(),
            width: 0,
            rows: 0,
        })
    }

    /// Reads the next line into `self.text` (its ending, `\n`, `\r\n` or `\r`, left
    /// out); `false` at the end. A line longer than [`MAX_LINE_BYTES`] is refused after
    /// reading at most the cap and one buffer of it.
    fn read_line(&mut self) -> Result<bool> {
        self.text.clear();
        let mut any = false;
        loop {
            let buf = match self.reader.fill_buf() {
                Ok(b) => b,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(source) => {
                    return Err(Error::Io {
                        path: self.name.clone(),
                        source,
                    })
                }
            };
            if buf.is_empty() {
                break;
            }
            if std::mem::take(&mut self.after_cr) && buf[0] == b'\n' {
                self.reader.consume(1);
                continue;
            }
            any = true;
            let end = buf.iter().position(|&b| b == b'\n' || b == b'\r');
            let take = end.unwrap_or(buf.len());
            if self.text.len() + take > MAX_LINE_BYTES {
                let seen = self.text.len() + take;
                let head = ECHO_MAX_CHARS.saturating_sub(self.text.len()).min(take);
                self.text.extend_from_slice(&buf[..head]);
                self.text.truncate(ECHO_MAX_CHARS);
                return Err(refused(
                    &self.name,
                    format!(
                        "line {}: longer than {MAX_LINE_BYTES} bytes (the cap on a line: a \
                         table's row is under 1 KiB; this is not a table). It starts \"{}… \
                         (more than {} bytes cut)\"",
                        self.line + 1,
                        excerpt_bytes(&self.text),
                        seen - self.text.len()
                    ),
                ));
            }
            self.text.extend_from_slice(&buf[..take]);
            match end {
                Some(i) => {
                    self.after_cr = buf[i] == b'\r';
                    self.reader.consume(i + 1);
                    self.line += 1;
                    return Ok(true);
                }
                None => self.reader.consume(take),
            }
        }
        if any {
            self.line += 1;
        }
        Ok(any)
    }

    /// Reads the next line that is neither blank nor a comment and splits it into
    /// `cells_text`/`cell_ends`; `Ok(None)` at the end, `Ok(Some(Err))` for a quoted
    /// cell left open at the end of its line.
    fn next_record(&mut self) -> Result<Option<std::result::Result<(), String>>> {
        loop {
            if !self.read_line()? {
                return Ok(None);
            }
            if self.text.first() == Some(&b'#') || self.text.iter().all(u8::is_ascii_whitespace) {
                continue;
            }
            return Ok(Some(self.split()));
        }
    }

    /// Splits `text` at commas into cells (quotes removed, `""` as `"`).
    fn split(&mut self) -> std::result::Result<(), String> {
        self.cells_text.clear();
        self.cell_ends.clear();
        let text = &self.text;
        let mut i = 0;
        loop {
            if text.get(i) == Some(&b'"') {
                i += 1;
                loop {
                    match text.get(i) {
                        None => {
                            return Err(format!(
                                "line {}: a quoted cell is not closed on its line (a table's \
                                 cells are on one line): \"{}\"",
                                self.line,
                                excerpt_bytes(text)
                            ))
                        }
                        Some(b'"') if text.get(i + 1) == Some(&b'"') => {
                            self.cells_text.push(b'"');
                            i += 2;
                        }
                        Some(b'"') => {
                            i += 1;
                            break;
                        }
                        Some(&b) => {
                            self.cells_text.push(b);
                            i += 1;
                        }
                    }
                }
            }
            // The rest of the cell (all of it when not quoted; after a closing quote,
            // what follows it is kept, as CSV readers do).
            let end = text[i..].iter().position(|&b| b == b',').map(|k| i + k);
            let stop = end.unwrap_or(text.len());
            self.cells_text.extend_from_slice(&text[i..stop]);
            self.cell_ends.push(self.cells_text.len());
            match end {
                Some(comma) => i = comma + 1,
                None => return Ok(()),
            }
        }
    }

    /// The cells of the last record, as bytes.
    fn cells(&self) -> impl Iterator<Item = &[u8]> {
        let mut start = 0;
        self.cell_ends.iter().map(move |&end| {
            let cell = &self.cells_text[start..end];
            start = end;
            cell
        })
    }

    /// The header's column names, trimmed: at most [`MAX_COLUMNS`], UTF-8 without NUL
    /// bytes (names appearing twice are the caller's rule). An input without any line
    /// but blanks and comments is refused.
    pub fn header(&mut self) -> Result<Vec<String>> {
        let split = match self.next_record()? {
            Some(split) => split,
            None => {
                return Err(refused(
                    &self.name,
                    "empty: a table is a header line, then one row per condition".into(),
                ))
            }
        };
        let line = self.line;
        split.map_err(|problem| refused(&self.name, format!("{problem} (header)")))?;
        let n = self.cell_ends.len();
        if n > MAX_COLUMNS {
            return Err(refused(
                &self.name,
                format!(
                    "line {line} (header): {n} columns: at most {MAX_COLUMNS} (the 19 \
                     required and up to {} extra variables). It starts \"{}\"",
                    MAX_COLUMNS - crate::table::REQUIRED_COLUMNS.len(),
                    excerpt_bytes(&self.text)
                ),
            ));
        }
        let mut names = Vec::with_capacity(n);
        for (j, cell) in self.cells().enumerate() {
            match std::str::from_utf8(cell) {
                Ok(s) if !s.contains('\0') => names.push(s.trim().to_string()),
                Ok(_) => {
                    return Err(refused(
                        &self.name,
                        format!(
                            "line {line} (header), column {}: NUL bytes in \"{}\": not \
                             text (UTF-16 without its byte order mark, or a binary file); a \
                             table is UTF-8 text",
                            j + 1,
                            excerpt_bytes(cell)
                        ),
                    ))
                }
                Err(e) => return Err(refused(&self.name, not_utf8(line, j + 1, cell, &e))),
            }
        }
        self.width = n;
        Ok(names)
    }

    /// The next data row, or `None` at the end. Past [`MAX_ROWS`] rows, or on a line too
    /// long, reading stops with the error; a row whose cells are not UTF-8 or not as
    /// many as the header's, or with a quoted cell left open, is a problem of that row
    /// (`Err` in the row's place, reading goes on).
    pub fn next_row(&mut self) -> Result<Option<std::result::Result<Row, String>>> {
        let Some(split) = self.next_record()? else {
            return Ok(None);
        };
        self.rows += 1;
        let line = self.line;
        if self.rows > MAX_ROWS {
            return Err(refused(
                &self.name,
                format!(
                    "line {line}: row {}: at most {MAX_ROWS} rows in a table (a campaign is \
                     thousands, a day-long log's windows half a million); split it, or \
                     pool repeated conditions",
                    self.rows
                ),
            ));
        }
        if let Err(problem) = split {
            return Ok(Some(Err(problem)));
        }
        if self.cell_ends.len() != self.width {
            return Ok(Some(Err(format!(
                "line {line}: {} cells where the header has {}: every row has the header's \
                 columns (a cell holding a comma is quoted: \"0.6,0,0.8\"). It starts \"{}\"",
                self.cell_ends.len(),
                self.width,
                excerpt_bytes(&self.text)
            ))));
        }
        let mut cells = Vec::with_capacity(self.width);
        for (j, cell) in self.cells().enumerate() {
            match std::str::from_utf8(cell) {
                Ok(s) => cells.push(s.trim().to_string()),
                Err(e) => return Ok(Some(Err(not_utf8(line, j + 1, cell, &e)))),
            }
        }
        Ok(Some(Ok(Row { line, cells })))
    }

    /// The name the input is known by.
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// The message of a cell that is not UTF-8.
fn not_utf8(line: usize, column: usize, cell: &[u8], e: &std::str::Utf8Error) -> String {
    format!(
        "line {line}, column {column} = \"{}\": not UTF-8 (byte {:#04x} at {}): a table is \
         UTF-8 text; save it as UTF-8, not Latin-1 or another code page",
        excerpt_bytes(cell),
        cell.get(e.valid_up_to()).copied().unwrap_or(0),
        e.valid_up_to()
    )
}

fn refused(name: &str, problem: String) -> Error {
    Error::Table {
        path: name.to_string(),
        problems: vec![problem],
    }
}

/// A cell quoted in a message: its excerpt, in double quotes.
pub fn quote(cell: &str) -> String {
    format!("\"{}\"", excerpt(cell))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The header, and each row or its problem.
    type HeaderAndRows = (Vec<String>, Vec<std::result::Result<Row, String>>);

    fn rows(input: &[u8]) -> Result<HeaderAndRows> {
        let mut r = TableReader::new(input, "t.csv")?;
        let header = r.header()?;
        let mut out = Vec::new();
        while let Some(row) = r.next_row()? {
            out.push(row);
        }
        Ok((header, out))
    }

    #[test]
    fn every_line_ending_numbers_lines_as_the_file_does() {
        for text in [
            &b"a,b\n1,2\n\n# c\n3,4\n"[..],
            b"a,b\r\n1,2\r\n\r\n# c\r\n3,4\r\n",
            b"a,b\r1,2\r\r# c\r3,4",
            b"\xef\xbb\xbfa,b\n1,2\n\n# c\n3,4",
        ] {
            let (h, r) = rows(text).unwrap();
            assert_eq!(h, ["a", "b"]);
            let got: Vec<_> = r.into_iter().map(|r| r.unwrap()).collect();
            assert_eq!(got.len(), 2, "{text:?}");
            assert_eq!((got[0].line, got[1].line), (2, 5), "{text:?}");
            assert_eq!(got[1].cells, ["3", "4"]);
        }
    }

    #[test]
    fn a_line_over_the_cap_stops_the_reading_at_the_cap() {
        let mut text = b"a,b\n1,2\n".to_vec();
        text.extend(std::iter::repeat_n(b'7', MAX_LINE_BYTES + 1));
        text.extend(b"\n3,4\n");
        let e = rows(&text).unwrap_err().to_string();
        assert!(
            e.starts_with("t.csv: line 3: longer than 65536 bytes (the cap on a line"),
            "{e}"
        );
        assert!(
            e.ends_with(&format!(
                "It starts \"{}… (more than {} bytes cut)\"",
                "7".repeat(ECHO_MAX_CHARS),
                MAX_LINE_BYTES + 1 - ECHO_MAX_CHARS
            )),
            "{e}"
        );
        // Exactly the cap is a line.
        let mut text = b"a\n".to_vec();
        text.extend(std::iter::repeat_n(b'7', MAX_LINE_BYTES));
        text.extend(b"\r\n");
        assert_eq!(rows(&text).unwrap().1.len(), 1);
    }

    #[test]
    fn an_endless_input_is_read_no_further_than_the_cap() {
        struct Counting(u64);
        impl Read for Counting {
            fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
                out.fill(0);
                self.0 += out.len() as u64;
                Ok(out.len())
            }
        }
        let mut src = Counting(0);
        let e = match TableReader::new(&mut src, "/dev/zero") {
            Ok(mut r) => r.header().unwrap_err().to_string(),
            Err(e) => e.to_string(),
        };
        assert!(e.contains("line 1: longer than 65536 bytes"), "{e}");
        assert!(e.contains(&"\\u{0}".repeat(ECHO_MAX_CHARS)), "{e}");
        assert!(e.len() < 1024, "{e}");
        // The parser's buffer (64 KiB) and the bytes before the cap.
        assert!(
            src.0 <= 3 * (MAX_LINE_BYTES as u64) + 3,
            "{} bytes read",
            src.0
        );
    }

    #[test]
    fn too_many_columns_utf16_and_latin1_are_refused_by_line_and_column() {
        let wide = vec!["c"; MAX_COLUMNS + 1].join(",");
        let e = rows(wide.as_bytes()).unwrap_err().to_string();
        assert!(
            e.starts_with("t.csv: line 1 (header): 65 columns: at most 64"),
            "{e}"
        );
        let e = rows(b"\xff\xfer\x00u\x00n\x00").unwrap_err().to_string();
        assert!(
            e.starts_with("t.csv: UTF-16 text (byte order mark FF FE)"),
            "{e}"
        );
        let e = rows(b"r\x00u\x00n\x00,\x00x\x00\n\x00")
            .unwrap_err()
            .to_string();
        assert!(e.contains("NUL bytes"), "{e}");
        let (_, r) = rows(b"run_id,x\nR\xe9sum\xe9,1\n").unwrap();
        let e = r[0].as_ref().unwrap_err();
        assert!(
            e.starts_with("line 2, column 1 = \"R\\xe9sum\\xe9\": not UTF-8 (byte 0xe9 at 1)"),
            "{e}"
        );
        let (_, r) = rows(b"a,b\n\"1,2\n3,4\n").unwrap();
        let e = r[0].as_ref().unwrap_err();
        assert!(
            e.starts_with("line 2: a quoted cell is not closed on its line"),
            "{e}"
        );
        assert_eq!(r[1].as_ref().unwrap().cells, ["3", "4"]);
        // Quotes that close, `""` inside them, a quote inside a plain cell, a comment.
        let (_, r) = rows(b"a,b\n\"1,\"\"x\",2\n# \"\n3\"4,5\n").unwrap();
        assert_eq!(r[0].as_ref().unwrap().cells, ["1,\"x", "2"]);
        assert_eq!(r[1].as_ref().unwrap().cells, ["3\"4", "5"]);
        let (_, r) = rows(b"a,b\n1,2,3\n").unwrap();
        assert!(r[0]
            .as_ref()
            .unwrap_err()
            .starts_with("line 2: 3 cells where the header has 2"));
    }

    #[test]
    fn rows_past_the_limit_stop_the_reading() {
        let mut text = String::from("a\n");
        for _ in 0..MAX_ROWS + 1 {
            text.push_str("1\n");
        }
        let e = rows(text.as_bytes()).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "t.csv: line {}: row {}: at most {MAX_ROWS} rows in a table (a campaign is \
                 thousands, a day-long log's windows half a million); split it, or pool \
                 repeated conditions",
                MAX_ROWS + 2,
                MAX_ROWS + 1
            )
        );
    }

    #[test]
    fn problems_past_the_listed_ones_are_counted() {
        let mut p = Problems::new();
        for i in 0..MAX_LISTED_PROBLEMS + 5 {
            p.push(format!("p{i}"));
        }
        assert_eq!(p.count(), MAX_LISTED_PROBLEMS + 5);
        let lines = p.into_lines();
        assert_eq!(lines.len(), MAX_LISTED_PROBLEMS + 1);
        assert_eq!(
            lines.last().unwrap(),
            "... and 5 more problems (the first 20 are listed)"
        );
    }
}
