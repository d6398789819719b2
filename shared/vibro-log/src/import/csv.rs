//! Reading the CSV files: a line-based reader of the header and the data rows, and
//! the list of problems found in a file, each naming the file, line, column, value
//! and rule.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use super::lines::LineReader;
// A line is up to 64 KiB (a CR-only file is one line): its cells are quoted by a line's
// worth, control characters escaped.
use super::{ImportKind, MAX_PROBLEMS, MAX_TIME_S};
use crate::{Error, Result};
use vibro_toml::echo::{excerpt, excerpt_bytes};

/// Problems found in one file, each naming the file, line, column, value and rule.
#[derive(Debug)]
pub(super) struct Problems {
    file: String,
    /// `(line, text)`, sorted when reported.
    list: Vec<(u64, String)>,
    /// More problems were found than are listed.
    more: bool,
}

impl Problems {
    pub(super) fn new(file: &Path) -> Problems {
        Problems {
            file: file.display().to_string(),
            list: Vec::new(),
            more: false,
        }
    }

    pub(super) fn add(&mut self, line: u64, text: String) {
        if self.list.len() < MAX_PROBLEMS {
            let at = if line == 0 {
                String::new()
            } else {
                format!(" line {line}")
            };
            self.list.push((line, format!("{}{at}{text}", self.file)));
        } else {
            self.more = true;
        }
    }

    pub(super) fn full(&self) -> bool {
        self.list.len() >= MAX_PROBLEMS
    }

    pub(super) fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// The problems as lines of an error message.
    pub(super) fn lines(&mut self) -> Vec<String> {
        self.list.sort_by_key(|(line, _)| *line);
        let mut out: Vec<String> = self.list.iter().map(|(_, t)| t.clone()).collect();
        if self.more {
            out.push(format!(
                "{}: more problems; reading stopped after the first {MAX_PROBLEMS}",
                self.file
            ));
        }
        out
    }
}

/// The header of a CSV file: where the documented columns are.
#[derive(Debug, Clone)]
pub(super) struct Header {
    /// Line of the header in the file (1-based; comment lines before it count).
    pub(super) line: u64,
    /// Column names as written (trimmed).
    pub(super) names: Vec<String>,
    /// 0-based index of time_s and of each unit's column.
    pub(super) columns: [usize; 4],
    /// The comment lines before the header and the header line, as in the file.
    pub(super) preamble: String,
}

impl Header {
    /// Which column feeds which wire field, for the log's metadata.
    pub(super) fn mapping(&self, kind: ImportKind) -> String {
        let names = kind.columns();
        let mut parts = vec![format!(
            "{} = column {} ({}) -> t0_ns",
            names[0],
            self.columns[0] + 1,
            kind.time_meaning()
        )];
        for u in 0..3 {
            parts.push(format!(
                "{} = column {} -> {}[sample][{u}] ({})",
                names[u + 1],
                self.columns[u + 1] + 1,
                kind.field(),
                kind.units()[u]
            ));
        }
        parts.join("; ")
    }

    pub(super) fn ignored(&self) -> Vec<String> {
        self.names
            .iter()
            .enumerate()
            .filter(|(i, _)| !self.columns.contains(i))
            .map(|(_, n)| n.clone())
            .collect()
    }
}

/// One valid data row.
#[derive(Debug, Clone, Copy)]
pub(super) struct Row {
    pub(super) line: u64,
    pub(super) time_s: f64,
    pub(super) values: [f64; 3],
}

pub(super) enum RowRead {
    Row(Row),
    /// A row with problems (recorded), with its line and time if the time was valid.
    Bad(Option<(u64, f64)>),
    End,
}

/// The data rows of a CSV file, after its header. A line-based reader (numeric CSV
/// needs no quoting rules beyond trimming quotes off a cell), so that every reported
/// line number is the file's own, comment and blank lines included.
pub(super) struct CsvRows {
    /// Capped at [`super::MAX_LINE_BYTES`] a line.
    reader: LineReader<BufReader<File>>,
    /// The current line, without its line ending.
    text: Vec<u8>,
    /// 1-based number of the current line.
    line: u64,
    bytes_read: u64,
    /// Byte ranges of the current line's cells (trimmed).
    cells: Vec<(usize, usize)>,
    pub(super) header: Header,
    names: [&'static str; 4],
}

/// Splits `text` at commas into trimmed cells (blanks, then one pair of double quotes).
fn split_cells(text: &[u8], cells: &mut Vec<(usize, usize)>) {
    cells.clear();
    let mut start = 0;
    for end in text
        .iter()
        .enumerate()
        .filter(|(_, &b)| b == b',')
        .map(|(i, _)| i)
        .chain(std::iter::once(text.len()))
    {
        let (mut a, mut b) = (start, end);
        while a < b && text[a].is_ascii_whitespace() {
            a += 1;
        }
        while b > a && text[b - 1].is_ascii_whitespace() {
            b -= 1;
        }
        if b - a >= 2 && text[a] == b'"' && text[b - 1] == b'"' {
            a += 1;
            b -= 1;
        }
        cells.push((a, b));
        start = end + 1;
    }
}

/// A line that carries no row: blank, or a `#` comment.
fn is_skipped(text: &[u8]) -> bool {
    match text.iter().position(|b| !b.is_ascii_whitespace()) {
        None => true,
        Some(i) => text[i] == b'#',
    }
}

impl CsvRows {
    /// Opens `path` and maps its header. Header problems are recorded and end the
    /// file's reading (`Ok(None)`).
    pub(super) fn open(
        path: &Path,
        kind: ImportKind,
        problems: &mut Problems,
    ) -> Result<Option<CsvRows>> {
        let file = File::open(path).map_err(|source| Error::ReadInput {
            path: path.to_path_buf(),
            action: "cannot open".to_string(),
            source,
        })?;
        let mut reader = LineReader::new(BufReader::with_capacity(1 << 18, file), path);
        let mut text = Vec::new();
        let mut line = 0u64;
        let mut bytes_read = 0u64;
        let mut preamble = Vec::new();
        let expected = kind.columns();
        let expected_text = expected.join(", ");
        loop {
            let Some(n) = reader.read_line(&mut text)? else {
                problems.add(
                    0,
                    format!(
                        ": the file has no header (expected the columns {expected_text}, then one row per sample)"
                    ),
                );
                return Ok(None);
            };
            line += 1;
            bytes_read += n as u64;
            preamble.extend_from_slice(&text);
            preamble.push(b'\n');
            if !is_skipped(&text) {
                break;
            }
        }
        // A spreadsheet's UTF-8 byte-order mark.
        let header_text = text.strip_prefix("\u{feff}".as_bytes()).unwrap_or(&text);
        let mut cells = Vec::new();
        split_cells(header_text, &mut cells);
        let names: Vec<String> = cells
            .iter()
            .map(|&(a, b)| String::from_utf8_lossy(&header_text[a..b]).into_owned())
            .collect();
        let mut columns = [0usize; 4];
        let mut missing = Vec::new();
        let mut repeated = false;
        for (k, want) in expected.iter().enumerate() {
            let at: Vec<usize> = names
                .iter()
                .enumerate()
                .filter(|(_, n)| n.as_str() == *want)
                .map(|(i, _)| i + 1)
                .collect();
            match at.as_slice() {
                [i] => columns[k] = i - 1,
                [] => missing.push(*want),
                several => {
                    repeated = true;
                    problems.add(
                        line,
                        format!(
                            " (header): column {want} appears {} times (columns {}); it must appear once",
                            several.len(),
                            excerpt(&format!("{several:?}"))
                        ),
                    );
                }
            }
        }
        if !missing.is_empty() {
            let numeric = names.iter().all(|n| n.parse::<f64>().is_ok());
            problems.add(
                line,
                format!(
                    " (header) = \"{}\": missing column(s) {}; the header must name {expected_text} (in any order; other columns are ignored){}",
                    excerpt(&names.join(",")),
                    missing.join(", "),
                    if numeric {
                        "; the first line that is not a # comment must be the header"
                    } else {
                        ""
                    }
                ),
            );
        }
        if repeated || !missing.is_empty() {
            return Ok(None);
        }
        Ok(Some(CsvRows {
            reader,
            text,
            line,
            bytes_read,
            cells,
            header: Header {
                line,
                names,
                columns,
                preamble: String::from_utf8_lossy(&preamble).into_owned(),
            },
            names: expected,
        }))
    }

    /// Bytes of the file read so far.
    pub(super) fn bytes_read(&self) -> u64 {
        self.bytes_read
    }

    /// The next data row; problems are recorded and the row returned as `Bad`.
    pub(super) fn next(&mut self, problems: &mut Problems) -> Result<RowRead> {
        loop {
            let Some(n) = self.reader.read_line(&mut self.text)? else {
                return Ok(RowRead::End);
            };
            self.line += 1;
            self.bytes_read += n as u64;
            if is_skipped(&self.text) {
                continue;
            }
            let line = self.line;
            split_cells(&self.text, &mut self.cells);
            let width = self.header.names.len();
            if self.cells.len() != width {
                problems.add(
                    line,
                    format!(
                        " = \"{}\": {} columns, the header (line {}) has {width}",
                        excerpt_bytes(&self.text),
                        self.cells.len(),
                        self.header.line
                    ),
                );
                // Its time, if it has one, still orders the rows.
                let time = self
                    .cells
                    .get(self.header.columns[0])
                    .and_then(|&(a, b)| parse_time(&self.text[a..b]).ok());
                return Ok(RowRead::Bad(time.map(|t| (line, t))));
            }
            let mut values = [0.0f64; 4];
            let mut ok = true;
            let mut time_ok = false;
            for (k, &c) in self.header.columns.iter().enumerate() {
                let (a, b) = self.cells[c];
                let cell = &self.text[a..b];
                let parsed = if k == 0 {
                    parse_time(cell)
                } else {
                    parse_cell(cell)
                };
                match parsed {
                    Ok(v) => {
                        values[k] = v;
                        time_ok |= k == 0;
                    }
                    Err(rule) => {
                        ok = false;
                        problems.add(
                            line,
                            format!(
                                ", column {} = \"{}\": {rule}",
                                self.names[k],
                                excerpt_bytes(cell)
                            ),
                        );
                    }
                }
            }
            if !ok {
                return Ok(RowRead::Bad(time_ok.then_some((line, values[0]))));
            }
            return Ok(RowRead::Row(Row {
                line,
                time_s: values[0],
                values: [values[1], values[2], values[3]],
            }));
        }
    }
}

/// A time cell: a number of seconds on the data time base.
fn parse_time(cell: &[u8]) -> std::result::Result<f64, &'static str> {
    parse_cell(cell).and_then(|v| {
        if (0.0..MAX_TIME_S).contains(&v) {
            Ok(v)
        } else {
            Err("must be >= 0 and < 1.8e10 s (the data time base is u64 nanoseconds from 0)")
        }
    })
}

/// A cell as a finite number (Rust's parser rounds correctly, so a value written with
/// enough digits comes back bit for bit).
fn parse_cell(cell: &[u8]) -> std::result::Result<f64, &'static str> {
    let text = std::str::from_utf8(cell).map_err(|_| "not a number (not UTF-8 text)")?;
    if text.is_empty() {
        return Err("empty: every row needs a number here");
    }
    let v: f64 = text.parse().map_err(|_| "not a number")?;
    if !v.is_finite() {
        return Err("must be finite (NaN and infinities are not samples)");
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_parse_to_finite_numbers_only() {
        assert_eq!(parse_cell(b"1.25"), Ok(1.25));
        assert_eq!(parse_cell(b"-3e-7"), Ok(-3e-7));
        assert!(parse_cell(b"").is_err());
        assert!(parse_cell(b"abc").is_err());
        assert!(parse_cell(b"NaN").unwrap_err().contains("finite"));
        assert!(parse_cell(b"-inf").unwrap_err().contains("finite"));
        assert!(parse_cell(b"1,5").is_err());
    }
}
