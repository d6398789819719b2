//! `vibrocomp log import`: rig data recorded as CSV into a log with the simulator's
//! topics and wire types (`/accel` AccelBlock, `/vib` VibBlock), so that it replays
//! like a simulated flight (docs/logs.md).
//!
//! Each file is read twice. The first pass validates every row (every problem, up to
//! [`MAX_PROBLEMS`] per file, is reported at once, and nothing is written) and finds
//! the sample rate and the gaps. The second cuts the rows into blocks as the rig's
//! [`crate::rig::Packetizer`] does, checks each row against the uniform time grid, and
//! writes the blocks of both streams in time order into a temporary file that is
//! renamed over OUT only when the log is complete.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufRead, BufReader, IsTerminal};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::Serialize;
use vibro_mcap::{Recorder, RecorderOptions};
use vibro_msgs::{accel_flags, vib_flags, AccelBlock, Stream, VibBlock};
use vibro_msgs::{ACCEL_BLOCK_MAX, VIB_BLOCK_MAX};

use super::{check_output, fmt_sig, print_text, same_file, PartFile};
use crate::commands::sim::topic;
use crate::output::print_json;
use crate::rig::RigMessage;

/// At most this many problems are listed per CSV file before reading stops.
const MAX_PROBLEMS: usize = 20;
/// The nominal period is the median interval of the first rows, this many intervals at
/// most: robust to a gap among them, and known before the file has been read through.
const RATE_PROBE_INTERVALS: usize = 1000;
/// An interval longer than this many periods is a gap (shorter ones must be one period).
const GAP_PERIODS: f64 = 1.5;
/// Default tolerance on row times, as a fraction of the sample period.
const DEFAULT_PERIOD_TOLERANCE: f64 = 0.1;
/// Inputs smaller than this are imported without a progress bar.
const PROGRESS_MIN_BYTES: u64 = 4 << 20;
/// The largest time a `u64` of nanoseconds holds, in seconds (rounded down).
const MAX_TIME_S: f64 = 1.8e10;

#[derive(Debug, Args)]
pub struct ImportArgs {
    /// Accelerometer CSV: columns time_s, u1_v, u2_v, u3_v (time the reading was
    /// latched, in s; unit outputs of AK1..AK3 in V). Becomes `/accel` (AccelBlock).
    #[arg(long, value_name = "CSV", required_unless_present = "vib")]
    pub accel: Option<PathBuf>,
    /// Vibration-sensor CSV: columns time_s, vd1_v, vd2_v, vd3_v (sample time in s;
    /// sensor outputs of VD1..VD3 in V). Becomes `/vib` (VibBlock).
    #[arg(long, value_name = "CSV")]
    pub vib: Option<PathBuf>,
    /// The MCAP log to write.
    #[arg(long, value_name = "OUT.mcap")]
    pub out: PathBuf,
    /// Accelerometer output rate (default: measured from the time column).
    #[arg(long)]
    pub accel_rate_hz: Option<f64>,
    /// Vibration-sensor sample rate (default: measured from the time column).
    #[arg(long)]
    pub vib_rate_hz: Option<f64>,
    /// Samples per AccelBlock, 1..=32.
    #[arg(long, default_value_t = ACCEL_BLOCK_MAX)]
    pub accel_block_samples: usize,
    /// Samples per VibBlock, 1..=512.
    #[arg(long, default_value_t = VIB_BLOCK_MAX)]
    pub vib_block_samples: usize,
    /// `source_id` of every block (the producer: rig or simulator instance).
    #[arg(long, default_value_t = 1)]
    pub source_id: u32,
    /// How far a row's time may be from the uniform sample grid, as a fraction of the
    /// sample period (0 < tolerance < 0.5).
    #[arg(long, default_value_t = DEFAULT_PERIOD_TOLERANCE)]
    pub period_tolerance: f64,
    /// Overwrite OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Which stream a CSV file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ImportKind {
    /// Accelerometer outputs (`--accel`): `/accel`, AccelBlock.
    Accel,
    /// Vibration-sensor outputs (`--vib`): `/vib`, VibBlock.
    Vib,
}

impl ImportKind {
    fn name(self) -> &'static str {
        match self {
            ImportKind::Accel => "accel",
            ImportKind::Vib => "vib",
        }
    }

    fn stream(self) -> Stream {
        match self {
            ImportKind::Accel => Stream::Accel,
            ImportKind::Vib => Stream::Vib,
        }
    }

    /// The documented columns: time, then one per unit.
    fn columns(self) -> [&'static str; 4] {
        match self {
            ImportKind::Accel => ["time_s", "u1_v", "u2_v", "u3_v"],
            ImportKind::Vib => ["time_s", "vd1_v", "vd2_v", "vd3_v"],
        }
    }

    fn units(self) -> [&'static str; 3] {
        match self {
            ImportKind::Accel => ["AK1", "AK2", "AK3"],
            ImportKind::Vib => ["VD1", "VD2", "VD3"],
        }
    }

    /// The wire field the unit columns fill.
    fn field(self) -> &'static str {
        match self {
            ImportKind::Accel => "output_v",
            ImportKind::Vib => "sample_v",
        }
    }

    /// What the time column means, which is what the block's `t0_ns` means.
    fn time_meaning(self) -> &'static str {
        match self {
            ImportKind::Accel => "time the reading was latched, the end of its averaging interval",
            ImportKind::Vib => "time the sample was taken",
        }
    }

    fn max_block(self) -> usize {
        match self {
            ImportKind::Accel => ACCEL_BLOCK_MAX,
            ImportKind::Vib => VIB_BLOCK_MAX,
        }
    }

    fn rate_flag(self) -> &'static str {
        match self {
            ImportKind::Accel => "--accel-rate-hz",
            ImportKind::Vib => "--vib-rate-hz",
        }
    }
}

/// One CSV file to import, its options validated.
#[derive(Debug)]
struct StreamSpec {
    kind: ImportKind,
    file: PathBuf,
    rate_hz: Option<f64>,
    block_samples: usize,
}

/// `log import`'s options, validated.
#[derive(Debug)]
struct ImportPlan {
    /// Vibration first: in a tie of block times it is written first, as the simulator
    /// does.
    streams: Vec<StreamSpec>,
    out: PathBuf,
    source_id: u32,
    tolerance: f64,
}

impl TryFrom<&ImportArgs> for ImportPlan {
    type Error = anyhow::Error;

    /// Checks every option and reports all problems at once.
    fn try_from(args: &ImportArgs) -> anyhow::Result<ImportPlan> {
        let mut problems = Vec::new();
        let mut streams = Vec::new();
        for (kind, file, rate_hz, block_samples, block_flag) in [
            (
                ImportKind::Vib,
                &args.vib,
                args.vib_rate_hz,
                args.vib_block_samples,
                "--vib-block-samples",
            ),
            (
                ImportKind::Accel,
                &args.accel,
                args.accel_rate_hz,
                args.accel_block_samples,
                "--accel-block-samples",
            ),
        ] {
            if let Some(r) = rate_hz {
                if !(r.is_finite() && r > 0.0 && r <= 1e9) {
                    problems.push(format!(
                        "{} = {r}: must be finite, > 0 and at most 1e9 Hz (a period of at least 1 ns)",
                        kind.rate_flag()
                    ));
                }
                if file.is_none() {
                    problems.push(format!(
                        "{} = {r} given without --{} CSV",
                        kind.rate_flag(),
                        kind.name()
                    ));
                }
            }
            if !(1..=kind.max_block()).contains(&block_samples) {
                problems.push(format!(
                    "{block_flag} = {block_samples}: must be 1..={} (the wire type's capacity)",
                    kind.max_block()
                ));
            }
            if let Some(file) = file {
                streams.push(StreamSpec {
                    kind,
                    file: file.clone(),
                    rate_hz,
                    block_samples,
                });
            }
        }
        if streams.is_empty() {
            problems.push("nothing to import: give --accel CSV, --vib CSV, or both".to_string());
        }
        let tolerance = args.period_tolerance;
        if !(tolerance.is_finite() && tolerance > 0.0 && tolerance < 0.5) {
            problems.push(format!(
                "--period-tolerance = {tolerance}: must be > 0 and < 0.5 (of a period), so that a whole number of periods is unambiguous"
            ));
        }
        if let [a, b] = streams.as_slice() {
            if same_file(&a.file, &b.file) {
                problems.push(format!(
                    "--accel and --vib name the same file {}: the streams have different columns",
                    a.file.display()
                ));
            }
        }
        if !problems.is_empty() {
            bail!("log import options:\n  {}", problems.join("\n  "));
        }
        let inputs: Vec<&Path> = streams.iter().map(|s| s.file.as_path()).collect();
        check_output(&args.out, &inputs, args.force)?;
        Ok(ImportPlan {
            streams,
            out: args.out.clone(),
            source_id: args.source_id,
            tolerance,
        })
    }
}

// ---------------------------------------------------------------------------------
// reading CSV

/// Problems found in one file, each naming the file, line, column, value and rule.
#[derive(Debug)]
struct Problems {
    file: String,
    /// `(line, text)`, sorted when reported.
    list: Vec<(u64, String)>,
    /// More problems were found than are listed.
    more: bool,
}

impl Problems {
    fn new(file: &Path) -> Problems {
        Problems {
            file: file.display().to_string(),
            list: Vec::new(),
            more: false,
        }
    }

    fn add(&mut self, line: u64, text: String) {
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

    fn full(&self) -> bool {
        self.list.len() >= MAX_PROBLEMS
    }

    fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// The problems as lines of an error message.
    fn lines(&mut self) -> Vec<String> {
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
struct Header {
    /// Line of the header in the file (1-based; comment lines before it count).
    line: u64,
    /// Column names as written (trimmed).
    names: Vec<String>,
    /// 0-based index of time_s and of each unit's column.
    columns: [usize; 4],
    /// The comment lines before the header and the header line, as in the file.
    preamble: String,
}

impl Header {
    /// Which column feeds which wire field, for the log's metadata.
    fn mapping(&self, kind: ImportKind) -> String {
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

    fn ignored(&self) -> Vec<String> {
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
struct Row {
    line: u64,
    time_s: f64,
    values: [f64; 3],
}

enum RowRead {
    Row(Row),
    /// A row with problems (recorded), with its line and time if the time was valid.
    Bad(Option<(u64, f64)>),
    End,
}

/// The data rows of a CSV file, after its header. A line-based reader (numeric CSV
/// needs no quoting rules beyond trimming quotes off a cell), so that every reported
/// line number is the file's own, comment and blank lines included.
struct CsvRows {
    path: PathBuf,
    reader: BufReader<File>,
    /// The current line, without its line ending.
    text: Vec<u8>,
    /// 1-based number of the current line.
    line: u64,
    bytes_read: u64,
    /// Byte ranges of the current line's cells (trimmed).
    cells: Vec<(usize, usize)>,
    header: Header,
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

/// Reads the next line into `text` (line ending removed); false at the end of the file.
fn read_line(
    reader: &mut BufReader<File>,
    text: &mut Vec<u8>,
    path: &Path,
    line: u64,
) -> anyhow::Result<Option<usize>> {
    text.clear();
    let n = reader
        .read_until(b'\n', text)
        .with_context(|| format!("{}: cannot read line {}", path.display(), line + 1))?;
    if n == 0 {
        return Ok(None);
    }
    while text.last().is_some_and(|&b| b == b'\n' || b == b'\r') {
        text.pop();
    }
    Ok(Some(n))
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
    fn open(
        path: &Path,
        kind: ImportKind,
        problems: &mut Problems,
    ) -> anyhow::Result<Option<CsvRows>> {
        let name = path.display();
        let file = File::open(path).with_context(|| format!("{name}: cannot open"))?;
        let mut reader = BufReader::with_capacity(1 << 18, file);
        let mut text = Vec::new();
        let mut line = 0u64;
        let mut bytes_read = 0u64;
        let mut preamble = Vec::new();
        let expected = kind.columns();
        let expected_text = expected.join(", ");
        loop {
            let Some(n) = read_line(&mut reader, &mut text, path, line)? else {
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
                            " (header): column {want} appears {} times (columns {:?}); it must appear once",
                            several.len(),
                            several
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
                    " (header) = {:?}: missing column(s) {}; the header must name {expected_text} (in any order; other columns are ignored){}",
                    names.join(","),
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
            path: path.to_path_buf(),
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
    fn bytes_read(&self) -> u64 {
        self.bytes_read
    }

    /// The next data row; problems are recorded and the row returned as `Bad`.
    fn next(&mut self, problems: &mut Problems) -> anyhow::Result<RowRead> {
        loop {
            let Some(n) = read_line(&mut self.reader, &mut self.text, &self.path, self.line)?
            else {
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
                        " = {:?}: {} columns, the header (line {}) has {width}",
                        String::from_utf8_lossy(&self.text),
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
                                ", column {} = {:?}: {rule}",
                                self.names[k],
                                String::from_utf8_lossy(cell)
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
fn parse_time(cell: &[u8]) -> Result<f64, &'static str> {
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
fn parse_cell(cell: &[u8]) -> Result<f64, &'static str> {
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

// ---------------------------------------------------------------------------------
// sample indices from row times

/// Turns increasing row times into sample indices: consecutive rows are one period
/// apart; an interval longer than [`GAP_PERIODS`] periods is a gap of a whole number of
/// periods, whose missing samples advance the index.
#[derive(Debug, Clone)]
struct Timeline {
    /// The nominal period that classifies intervals.
    period_s: f64,
    tolerance: f64,
    /// Where it came from, for messages.
    period_source: String,
    prev: Option<(u64, f64)>,
    index: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Step {
    First,
    Next,
    Gap { missing: u64 },
}

impl Timeline {
    fn new(period_s: f64, tolerance: f64, period_source: String) -> Timeline {
        Timeline {
            period_s,
            tolerance,
            period_source,
            prev: None,
            index: 0,
        }
    }

    /// The sample index of the row at `time_s` (times must increase, checked by the
    /// caller). An interval that breaks the rule is an `Err` with the rule; the index
    /// advances by the nearest whole number of periods all the same, so that one bad
    /// interval does not make every later row wrong.
    fn step(&mut self, line: u64, time_s: f64) -> (u64, Step, Option<String>) {
        let Some((prev_line, prev_s)) = self.prev.replace((line, time_s)) else {
            return (self.index, Step::First, None);
        };
        let periods = (time_s - prev_s) / self.period_s;
        let whole = periods.round().max(1.0);
        let off = (periods - whole).abs();
        let (step, rule) = if periods <= GAP_PERIODS {
            let rule = (off > self.tolerance).then(|| {
                format!(
                    "{periods:.4} periods after line {prev_line} ({prev_s}): consecutive rows must be 1 period apart (+- {}), a gap more than {GAP_PERIODS} periods; period {} s ({})",
                    self.tolerance, fmt_sig(self.period_s), self.period_source
                )
            });
            (Step::Next, rule)
        } else {
            let rule = (off > self.tolerance).then(|| {
                format!(
                    "{periods:.4} periods after line {prev_line} ({prev_s}): a gap must be a whole number of periods (+- {}); period {} s ({})",
                    self.tolerance, fmt_sig(self.period_s), self.period_source
                )
            });
            // `whole` >= 2 here; `as` saturates a count beyond u64 (a gap of more
            // periods than the index holds), which the index check below reports.
            let missing = whole as u64 - 1;
            (Step::Gap { missing }, rule)
        };
        let advance = match step {
            Step::Gap { missing } => missing.saturating_add(1),
            _ => 1,
        };
        let Some(index) = self.index.checked_add(advance) else {
            // The file is refused (this is one of its problems), so the index that
            // stops here never reaches a block.
            self.index = u64::MAX;
            let overflow = format!(
                "{periods:.4e} periods after line {prev_line} ({prev_s}): the sample index passes 2^64 - 1; period {} s ({})",
                fmt_sig(self.period_s),
                self.period_source
            );
            return (self.index, step, Some(overflow));
        };
        self.index = index;
        (self.index, step, rule)
    }
}

/// The median of the intervals between `times` (at least two, increasing).
fn median_interval_s(times: &[f64]) -> f64 {
    let mut dt: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    dt.sort_by(f64::total_cmp);
    dt[dt.len() / 2]
}

/// What the first pass learnt about a file.
#[derive(Debug, Clone)]
struct Scan {
    header: Header,
    bytes: u64,
    rows: u64,
    first_time_s: f64,
    last_time_s: f64,
    /// Index of the last row: rows + missing samples - 1.
    last_index: u64,
    gaps: u64,
    missing_samples: u64,
    /// The nominal period that classified the intervals (the second pass uses it too,
    /// so that both passes find the same gaps).
    nominal_period_s: f64,
    nominal_source: String,
    /// The period of the blocks: `--*-rate-hz`, or first to last row time over the
    /// samples between them.
    period_s: f64,
    rate_from: String,
    /// The rate the time column gives (first to last row), whether used or not.
    measured_rate_hz: Option<f64>,
}

/// First pass over one file: every row validated, the rate measured, the gaps found.
/// Returns the problems if there are any.
fn scan(
    spec: &StreamSpec,
    tolerance: f64,
    progress: &Progress,
) -> anyhow::Result<Result<Scan, Problems>> {
    let mut problems = Problems::new(&spec.file);
    let Some(mut rows) = CsvRows::open(&spec.file, spec.kind, &mut problems)? else {
        return Ok(Err(problems));
    };
    let bytes = std::fs::metadata(&spec.file)
        .map(|m| m.len())
        .with_context(|| format!("{}: cannot stat", spec.file.display()))?;

    struct Counts {
        last_index: u64,
        gaps: u64,
        missing: u64,
    }
    let mut counts = Counts {
        last_index: 0,
        gaps: 0,
        missing: 0,
    };
    let classify = |timeline: &mut Timeline,
                    counts: &mut Counts,
                    problems: &mut Problems,
                    line: u64,
                    t: f64| {
        let (index, step, rule) = timeline.step(line, t);
        if let Some(rule) = rule {
            problems.add(line, format!(", column time_s = {t}: {rule}"));
        }
        if let Step::Gap { missing } = step {
            counts.gaps += 1;
            counts.missing += missing;
        }
        counts.last_index = index;
    };

    let mut timeline = spec
        .rate_hz
        .map(|r| Timeline::new(1.0 / r, tolerance, format!("{} {r}", spec.kind.rate_flag())));
    // Row times waiting for the nominal period (the median of their intervals).
    let mut pending: Vec<(u64, f64)> = Vec::new();
    let mut last_good: Option<(u64, f64)> = None;
    let mut first_time_s = None;
    let mut n_rows = 0u64;
    let mut since_progress = 0u32;
    while !problems.full() {
        // A row with bad values still has its place in time.
        let (line, time_s) = match rows.next(&mut problems)? {
            RowRead::End => break,
            RowRead::Bad(None) => {
                n_rows += 1;
                continue;
            }
            RowRead::Bad(Some(at)) => at,
            RowRead::Row(row) => (row.line, row.time_s),
        };
        n_rows += 1;
        since_progress += 1;
        if since_progress == 1 << 16 {
            since_progress = 0;
            progress.set_current(rows.bytes_read());
        }
        if let Some((prev_line, prev_s)) = last_good {
            if time_s <= prev_s {
                problems.add(
                    line,
                    format!(
                        ", column time_s = {time_s}: not after line {prev_line}'s {prev_s}: time must increase from row to row"
                    ),
                );
                continue;
            }
        }
        last_good = Some((line, time_s));
        first_time_s.get_or_insert(time_s);
        match &mut timeline {
            Some(tl) => classify(tl, &mut counts, &mut problems, line, time_s),
            None => {
                pending.push((line, time_s));
                if pending.len() > RATE_PROBE_INTERVALS {
                    let times: Vec<f64> = pending.iter().map(|p| p.1).collect();
                    let mut tl = Timeline::new(
                        median_interval_s(&times),
                        tolerance,
                        format!("median interval of lines {}..{line}", pending[0].0),
                    );
                    for (line, t) in pending.drain(..) {
                        classify(&mut tl, &mut counts, &mut problems, line, t);
                    }
                    timeline = Some(tl);
                }
            }
        }
    }
    progress.set_current(bytes);
    let name = spec.file.display();
    if n_rows == 0 {
        problems.add(
            rows.header.line,
            format!(
                " (header): no data rows after the header (one row per sample: {})",
                spec.kind.columns().join(", ")
            ),
        );
    }
    let timeline = match timeline {
        Some(tl) => Some(tl),
        None if pending.len() >= 2 => {
            let times: Vec<f64> = pending.iter().map(|p| p.1).collect();
            let mut tl = Timeline::new(
                median_interval_s(&times),
                tolerance,
                format!(
                    "median interval of lines {}..{}",
                    pending[0].0,
                    pending[pending.len() - 1].0
                ),
            );
            for (line, t) in pending.drain(..) {
                classify(&mut tl, &mut counts, &mut problems, line, t);
            }
            Some(tl)
        }
        None => {
            if problems.is_empty() {
                problems.add(
                    rows.header.line,
                    format!(
                        " (header): {} data row(s): the rate cannot be measured from one row; give {}",
                        pending.len(),
                        spec.kind.rate_flag()
                    ),
                );
            }
            None
        }
    };
    if !problems.is_empty() {
        return Ok(Err(problems));
    }
    let (Some(timeline), Some((_, last_time_s)), Some(first_time_s)) =
        (timeline, last_good, first_time_s)
    else {
        bail!("{name}: no rows to import");
    };
    let measured_period_s =
        (counts.last_index > 0).then(|| (last_time_s - first_time_s) / counts.last_index as f64);
    let (period_s, rate_from) = match spec.rate_hz {
        Some(r) => (1.0 / r, spec.kind.rate_flag().to_string()),
        None => (
            (last_time_s - first_time_s) / counts.last_index as f64,
            format!(
                "time column: {} s from the first to the last row over {} periods",
                fmt_sig(last_time_s - first_time_s),
                counts.last_index
            ),
        ),
    };
    if period_s * 1e9 < 0.5 {
        bail!(
            "{name}: sample period {period_s} s ({rate_from}): shorter than 1 ns, the resolution of the log's times"
        );
    }
    Ok(Ok(Scan {
        header: rows.header,
        bytes,
        rows: n_rows,
        first_time_s,
        last_time_s,
        last_index: counts.last_index,
        gaps: counts.gaps,
        missing_samples: counts.missing,
        nominal_period_s: timeline.period_s,
        nominal_source: timeline.period_source,
        period_s,
        rate_from,
        measured_rate_hz: measured_period_s.map(|p| 1.0 / p),
    }))
}

// ---------------------------------------------------------------------------------
// blocks

/// The block being filled, allocated once (a `VibBlock` is 12 kB).
enum Block {
    Accel(Box<AccelBlock>),
    Vib(Box<VibBlock>),
}

impl Block {
    fn new(kind: ImportKind, period_ns: u64, source_id: u32) -> Block {
        match kind {
            ImportKind::Accel => {
                let mut b = Box::new(AccelBlock::ZEROED);
                b.sample_period_ns = period_ns;
                b.source_id = source_id;
                Block::Accel(b)
            }
            ImportKind::Vib => {
                let mut b = Box::new(VibBlock::ZEROED);
                b.sample_period_ns = period_ns;
                b.source_id = source_id;
                Block::Vib(b)
            }
        }
    }

    fn count(&self) -> usize {
        match self {
            Block::Accel(b) => b.count as usize,
            Block::Vib(b) => b.count as usize,
        }
    }

    fn first_index(&self) -> u64 {
        match self {
            Block::Accel(b) => b.first_sample_index,
            Block::Vib(b) => b.first_sample_index,
        }
    }

    /// Starts an empty block at sample `index`, taken (vib) or latched (accel) at `t0_ns`.
    fn begin(&mut self, index: u64, t0_ns: u64, gap: bool) {
        match self {
            Block::Accel(b) => {
                b.count = 0;
                b.first_sample_index = index;
                b.t0_ns = t0_ns;
                b.flags = if gap { accel_flags::GAP_BEFORE } else { 0 };
            }
            Block::Vib(b) => {
                b.count = 0;
                b.first_sample_index = index;
                b.t0_ns = t0_ns;
                b.flags = if gap { vib_flags::GAP_BEFORE } else { 0 };
            }
        }
    }

    fn push(&mut self, values: [f64; 3]) {
        match self {
            Block::Accel(b) => {
                b.output_v[b.count as usize] = values;
                b.count += 1;
            }
            Block::Vib(b) => {
                b.sample_v[b.count as usize] = values;
                b.count += 1;
            }
        }
    }

    /// Stamps a complete block: `seq`, zeroed unused slots, `publish_ns` = the time of
    /// its last sample (the Packetizer's rule).
    fn seal(&mut self, seq: u64) {
        match self {
            Block::Accel(b) => {
                let n = b.count as usize;
                b.output_v[n..].fill([0.0; 3]);
                b.seq = seq;
                b.publish_ns = RigMessage::Accel(b).time_ns();
            }
            Block::Vib(b) => {
                let n = b.count as usize;
                b.sample_v[n..].fill([0.0; 3]);
                b.seq = seq;
                b.publish_ns = RigMessage::Vib(b).time_ns();
            }
        }
    }

    fn message(&self) -> RigMessage<'_> {
        match self {
            Block::Accel(b) => RigMessage::Accel(b),
            Block::Vib(b) => RigMessage::Vib(b),
        }
    }
}

/// Second pass over one file: rows to blocks.
struct BlockMaker {
    topic: String,
    rows: CsvRows,
    timeline: Timeline,
    first_time_s: f64,
    period_s: f64,
    tolerance: f64,
    block: Block,
    block_samples: usize,
    /// A row read past the end of the previous block (after a gap).
    carry: Option<(u64, [f64; 3])>,
    /// The index that follows the last block without a gap.
    next_index: u64,
    seq: u64,
    /// The largest distance of a row's time from the grid, s.
    max_residual_s: f64,
    /// Rows farther from the grid than the tolerance: how many, the first (line and
    /// problem), and the farthest (periods, line).
    off_grid: u64,
    off_grid_first: Option<(u64, String)>,
    off_grid_max: (f64, u64),
    /// Why the grid may be wrong, for the problem.
    off_grid_hint: String,
    /// Problems of this pass: rows off the grid, or a file changed since the first.
    problems: Problems,
}

impl BlockMaker {
    fn new(
        spec: &StreamSpec,
        scan: &Scan,
        tolerance: f64,
        source_id: u32,
    ) -> anyhow::Result<BlockMaker> {
        let mut problems = Problems::new(&spec.file);
        let Some(rows) = CsvRows::open(&spec.file, spec.kind, &mut problems)? else {
            bail!(
                "{}: changed while it was imported (its header no longer reads)",
                spec.file.display()
            );
        };
        let period_ns = (scan.period_s * 1e9).round() as u64;
        Ok(BlockMaker {
            topic: topic(spec.kind.stream()),
            rows,
            timeline: Timeline::new(
                scan.nominal_period_s,
                tolerance,
                scan.nominal_source.clone(),
            ),
            first_time_s: scan.first_time_s,
            period_s: scan.period_s,
            tolerance,
            block: Block::new(spec.kind, period_ns, source_id),
            block_samples: spec.block_samples,
            carry: None,
            next_index: 0,
            seq: 0,
            max_residual_s: 0.0,
            off_grid: 0,
            off_grid_first: None,
            off_grid_max: (0.0, 0),
            off_grid_hint: match (spec.rate_hz, scan.measured_rate_hz) {
                (Some(_), Some(measured)) => format!(
                    "{} disagrees with the time column, which gives {} Hz from its first to its last row",
                    spec.kind.rate_flag(),
                    fmt_sig(measured)
                ),
                _ => "the sample rate drifts or jumps within the file".to_string(),
            },
            problems,
        })
    }

    /// The time of sample `index` on the uniform grid, ns.
    fn grid_ns(&self, index: u64) -> u64 {
        ((self.first_time_s + index as f64 * self.period_s) * 1e9).round() as u64
    }

    /// Reads rows until the next block is complete: full, cut by a gap, or at the end of
    /// the file. Returns false when there is no block left.
    fn fill(&mut self) -> anyhow::Result<bool> {
        self.block.begin(0, 0, false);
        loop {
            let (index, values) = match self.carry.take() {
                Some(c) => c,
                None => match self.rows.next(&mut self.problems)? {
                    RowRead::End => break,
                    RowRead::Bad(_) => continue,
                    RowRead::Row(row) => {
                        let (index, _, rule) = self.timeline.step(row.line, row.time_s);
                        if let Some(rule) = rule {
                            self.problems.add(
                                row.line,
                                format!(", column time_s = {}: {rule}", row.time_s),
                            );
                        }
                        self.check_grid(&row, index);
                        (index, row.values)
                    }
                },
            };
            if self.block.count() == 0 {
                let gap = index != self.next_index;
                let t0_ns = self.grid_ns(index);
                self.block.begin(index, t0_ns, gap);
            } else if index != self.block.first_index() + self.block.count() as u64 {
                // A gap: the row starts the next block.
                self.carry = Some((index, values));
                break;
            }
            self.block.push(values);
            if self.block.count() == self.block_samples {
                break;
            }
        }
        let n = self.block.count();
        if n == 0 {
            return Ok(false);
        }
        self.next_index = self.block.first_index() + n as u64;
        self.block.seal(self.seq);
        self.seq += 1;
        Ok(true)
    }

    /// Every row must lie on the grid `first time + index x period` within the
    /// tolerance: a rate that drifts, or a `--*-rate-hz` that disagrees with the time
    /// column, would otherwise put samples at the wrong times.
    fn check_grid(&mut self, row: &Row, index: u64) {
        let grid_s = self.first_time_s + index as f64 * self.period_s;
        let residual_s = row.time_s - grid_s;
        self.max_residual_s = self.max_residual_s.max(residual_s.abs());
        let periods = residual_s / self.period_s;
        if periods.abs() <= self.tolerance {
            return;
        }
        self.off_grid += 1;
        if periods.abs() > self.off_grid_max.0 {
            self.off_grid_max = (periods.abs(), row.line);
        }
        if self.off_grid_first.is_none() {
            self.off_grid_first = Some((
                row.line,
                format!(
                    ", column time_s = {}: {periods:+.4} periods off the uniform grid (sample {index} is due at {} s: from {} s every {} s); rows must lie within +- {} periods of it",
                    row.time_s,
                    fmt_sig(grid_s),
                    self.first_time_s,
                    fmt_sig(self.period_s),
                    self.tolerance
                ),
            ));
        }
    }

    /// Rows off the grid as one problem: the first, how many, the farthest, and why.
    fn report_off_grid(&mut self) {
        let Some((line, text)) = self.off_grid_first.take() else {
            return;
        };
        let (max_periods, max_line) = self.off_grid_max;
        self.problems.add(
            line,
            format!(
                "{text}; {} rows are off it, the farthest by {max_periods:.4} periods at line {max_line}: {}",
                self.off_grid, self.off_grid_hint
            ),
        );
    }
}

/// Writes one block, waiting for room in the recorder's queue (an import must lose
/// nothing).
fn write_block(rec: &Recorder, topic: &str, msg: RigMessage<'_>) -> anyhow::Result<()> {
    let t = msg.time_ns();
    loop {
        let result = match msg {
            RigMessage::Vib(b) => rec.write(topic, t, b.publish_ns, b.seq as u32, b),
            RigMessage::Accel(b) => rec.write(topic, t, b.publish_ns, b.seq as u32, b),
            RigMessage::Truth(b) => rec.write(topic, t, b.publish_ns, b.seq as u32, b),
        };
        match result {
            Err(vibro_mcap::Error::QueueFull { .. }) => {
                std::thread::sleep(Duration::from_micros(200))
            }
            other => return other.with_context(|| format!("writing {topic} to the log")),
        }
    }
}

/// The blocks that `log import` makes of one CSV file, without writing a log: the
/// first pass (every row validated, the rate measured, the gaps found), then the second
/// (rows cut into blocks of `block_samples`, each row checked against the time grid),
/// each complete block handed to `each`. Returns the number of blocks. The options are
/// those of `log import` (`rate_hz` for `--*-rate-hz`, `tolerance` for
/// `--period-tolerance`) and are checked as it checks them; problems in the file are
/// one error listing them all, as `log import` reports them. The command's parsing
/// core, public for the fuzz targets (`fuzz/`).
pub fn read_csv_blocks(
    kind: ImportKind,
    file: &Path,
    rate_hz: Option<f64>,
    block_samples: usize,
    tolerance: f64,
    mut each: impl FnMut(RigMessage<'_>),
) -> anyhow::Result<u64> {
    if let Some(r) = rate_hz {
        if !(r.is_finite() && r > 0.0 && r <= 1e9) {
            bail!(
                "{} = {r}: must be finite, > 0 and at most 1e9 Hz",
                kind.rate_flag()
            );
        }
    }
    if !(1..=kind.max_block()).contains(&block_samples) {
        bail!(
            "block samples = {block_samples}: must be 1..={} (the wire type's capacity)",
            kind.max_block()
        );
    }
    if !(tolerance.is_finite() && tolerance > 0.0 && tolerance < 0.5) {
        bail!("--period-tolerance = {tolerance}: must be > 0 and < 0.5 (of a period)");
    }
    let spec = StreamSpec {
        kind,
        file: file.to_path_buf(),
        rate_hz,
        block_samples,
    };
    let scan = match scan(&spec, tolerance, &Progress::new(0))? {
        Ok(scan) => scan,
        Err(mut p) => bail!("problem(s) in the CSV input:\n  {}", p.lines().join("\n  ")),
    };
    let mut maker = BlockMaker::new(&spec, &scan, tolerance, 1)?;
    while maker.fill()? {
        each(maker.block.message());
    }
    maker.report_off_grid();
    if !maker.problems.is_empty() {
        bail!(
            "problem(s) in the CSV input:\n  {}",
            maker.problems.lines().join("\n  ")
        );
    }
    Ok(maker.seq)
}

// ---------------------------------------------------------------------------------
// progress and report

/// A progress bar over the bytes of both passes; hidden unless stderr is a terminal and
/// the inputs are large.
struct Progress {
    bar: ProgressBar,
    /// Bytes of earlier files and passes.
    done: std::cell::Cell<u64>,
}

impl Progress {
    fn new(total_bytes: u64) -> Progress {
        let bar = if total_bytes < PROGRESS_MIN_BYTES || !std::io::stderr().is_terminal() {
            ProgressBar::hidden()
        } else {
            let bar =
                ProgressBar::with_draw_target(Some(total_bytes), ProgressDrawTarget::stderr());
            if let Ok(style) =
                ProgressStyle::with_template("{msg} {bar:40} {bytes}/{total_bytes} ({eta} left)")
            {
                bar.set_style(style);
            }
            bar
        };
        Progress {
            bar,
            done: std::cell::Cell::new(0),
        }
    }

    fn set_current(&self, bytes: u64) {
        self.bar.set_position(self.done.get() + bytes);
    }

    fn finish_part(&self, bytes: u64) {
        self.done.set(self.done.get() + bytes);
        self.bar.set_position(self.done.get());
    }
}

#[derive(Debug, Serialize)]
struct StreamReport {
    stream: ImportKind,
    topic: String,
    message_type: String,
    file: String,
    file_bytes: u64,
    /// Data rows (samples) read.
    rows: u64,
    /// 1-based column of each documented name.
    columns: BTreeMap<String, usize>,
    ignored_columns: Vec<String>,
    rate_hz: f64,
    rate_from: String,
    sample_period_ns: u64,
    first_time_s: f64,
    last_time_s: f64,
    /// Sample indices spanned: rows + missing samples.
    samples_spanned: u64,
    block_samples: usize,
    blocks: u64,
    gaps: u64,
    missing_samples: u64,
    /// Largest distance of a row's time from the uniform grid.
    max_time_residual_s: f64,
    source_id: u32,
}

#[derive(Debug, Serialize)]
struct ImportReport {
    out: String,
    messages: u64,
    chunks: u64,
    bytes: u64,
    elapsed_s: f64,
    rows_per_s: f64,
    streams: Vec<StreamReport>,
}

// ---------------------------------------------------------------------------------
// The command

pub(super) fn run(args: &ImportArgs) -> anyhow::Result<()> {
    let plan = ImportPlan::try_from(args)?;
    let started = Instant::now();
    let total_bytes: u64 = plan
        .streams
        .iter()
        .map(|s| std::fs::metadata(&s.file).map_or(0, |m| m.len()))
        .sum();
    let progress = Progress::new(2 * total_bytes);

    // Pass 1: validate everything before writing anything.
    progress.bar.set_message("checking");
    let mut scans = Vec::new();
    let mut problems = Vec::new();
    for spec in &plan.streams {
        match scan(spec, plan.tolerance, &progress)? {
            Ok(scan) => {
                progress.finish_part(scan.bytes);
                scans.push(scan);
            }
            Err(mut p) => problems.extend(p.lines()),
        }
    }
    if !problems.is_empty() {
        progress.bar.finish_and_clear();
        bail!(
            "{} problem(s) in the CSV input, nothing written:\n  {}",
            problems.len(),
            problems.join("\n  ")
        );
    }

    // Pass 2: blocks, in time order over the streams, into a temporary file.
    progress.bar.set_message("importing");
    let part = PartFile::beside(&plan.out);
    let mut rec = Recorder::create(&part.path, RecorderOptions::default())
        .with_context(|| format!("{}: cannot create the log", plan.out.display()))?;
    let mut makers = Vec::new();
    for (spec, scan) in plan.streams.iter().zip(&scans) {
        rec.add_channel(&topic(spec.kind.stream()), spec.kind.stream().kind())?;
        rec.add_attachment_at(
            &format!("{}-header.csv", spec.kind.name()),
            "text/csv",
            scan.header.preamble.clone().into_bytes(),
            0,
        )?;
        makers.push(BlockMaker::new(spec, scan, plan.tolerance, plan.source_id)?);
    }
    let mut ready = Vec::with_capacity(makers.len());
    for m in &mut makers {
        ready.push(m.fill()?);
    }
    let mut writing = true;
    let mut blocks_since_progress = 0u32;
    loop {
        // The complete block with the earliest time; ties go to the first stream (vib).
        let next = makers
            .iter()
            .enumerate()
            .filter(|(i, _)| ready[*i])
            .min_by_key(|(_, m)| m.block.message().time_ns())
            .map(|(i, _)| i);
        let Some(i) = next else { break };
        // A row off the grid anywhere stops the writing; reading goes on to list
        // every such row.
        writing &= makers.iter().all(|m| m.problems.is_empty());
        if writing {
            write_block(&rec, &makers[i].topic, makers[i].block.message())?;
        }
        ready[i] = makers[i].fill()?;
        blocks_since_progress += 1;
        if blocks_since_progress == 256 {
            blocks_since_progress = 0;
            progress.set_current(makers.iter().map(|m| m.rows.bytes_read()).sum());
        }
    }
    progress.bar.finish_and_clear();
    for m in &mut makers {
        m.report_off_grid();
    }
    let problems: Vec<String> = makers.iter_mut().flat_map(|m| m.problems.lines()).collect();
    if !problems.is_empty() {
        bail!(
            "{} problem(s) in the CSV input, nothing written:\n  {}",
            problems.len(),
            problems.join("\n  ")
        );
    }

    let mut meta = BTreeMap::from([
        (
            "tool".to_string(),
            format!("vibrocomp {} log import", env!("CARGO_PKG_VERSION")),
        ),
        ("period_tolerance".to_string(), plan.tolerance.to_string()),
        ("source_id".to_string(), plan.source_id.to_string()),
    ]);
    let mut streams = Vec::new();
    for ((spec, scan), maker) in plan.streams.iter().zip(&scans).zip(&makers) {
        let s = spec.kind.name();
        let period_ns = (scan.period_s * 1e9).round() as u64;
        let entries = [
            ("file", spec.file.display().to_string()),
            ("topic", maker.topic.clone()),
            ("rows", scan.rows.to_string()),
            ("rate_hz", (1.0 / scan.period_s).to_string()),
            ("rate_from", scan.rate_from.clone()),
            ("sample_period_ns", period_ns.to_string()),
            ("first_time_s", scan.first_time_s.to_string()),
            ("columns", scan.header.mapping(spec.kind)),
            ("ignored_columns", scan.header.ignored().join(", ")),
            ("block_samples", spec.block_samples.to_string()),
            ("blocks", maker.seq.to_string()),
            ("gaps", scan.gaps.to_string()),
            ("missing_samples", scan.missing_samples.to_string()),
            ("max_time_residual_s", format!("{:e}", maker.max_residual_s)),
        ];
        for (k, v) in entries {
            meta.insert(format!("{s}.{k}"), v);
        }
        let names = spec.kind.columns();
        streams.push(StreamReport {
            stream: spec.kind,
            topic: maker.topic.clone(),
            message_type: spec.kind.stream().kind().name().to_string(),
            file: spec.file.display().to_string(),
            file_bytes: scan.bytes,
            rows: scan.rows,
            columns: names
                .iter()
                .zip(scan.header.columns)
                .map(|(n, c)| (n.to_string(), c + 1))
                .collect(),
            ignored_columns: scan.header.ignored(),
            rate_hz: 1.0 / scan.period_s,
            rate_from: scan.rate_from.clone(),
            sample_period_ns: period_ns,
            first_time_s: scan.first_time_s,
            last_time_s: scan.last_time_s,
            samples_spanned: scan.last_index + 1,
            block_samples: spec.block_samples,
            blocks: maker.seq,
            gaps: scan.gaps,
            missing_samples: scan.missing_samples,
            max_time_residual_s: maker.max_residual_s,
            source_id: plan.source_id,
        });
    }
    rec.add_metadata("import", meta)?;
    let summary = rec.finish().context("finishing the log")?;
    part.commit(&plan.out)?;
    let elapsed_s = started.elapsed().as_secs_f64();
    let rows: u64 = streams.iter().map(|s| s.rows).sum();
    let report = ImportReport {
        out: plan.out.display().to_string(),
        messages: summary.messages,
        chunks: summary.chunks,
        bytes: summary.bytes,
        elapsed_s,
        rows_per_s: rows as f64 / elapsed_s.max(1e-9),
        streams,
    };
    if args.json {
        return print_json(&report);
    }
    print_text(|out| write_import(out, &report))
}

fn write_import(out: &mut String, r: &ImportReport) -> std::fmt::Result {
    writeln!(
        out,
        "Imported {} stream(s) into {}: {} messages, {} chunks, {} bytes, in {:.2} s ({:.2e} rows/s)",
        r.streams.len(),
        r.out,
        r.messages,
        r.chunks,
        r.bytes,
        r.elapsed_s,
        r.rows_per_s
    )?;
    for s in &r.streams {
        writeln!(
            out,
            "  {:<7} {}: {} rows -> {} {}s of up to {} samples, {} gap(s), {} sample(s) missing",
            s.topic,
            s.file,
            s.rows,
            s.blocks,
            s.message_type,
            s.block_samples,
            s.gaps,
            s.missing_samples
        )?;
        writeln!(
            out,
            "          rate {} Hz, period {} ns ({})",
            fmt_sig(s.rate_hz),
            s.sample_period_ns,
            s.rate_from
        )?;
        writeln!(
            out,
            "          time {} .. {} s; every row within {:.2e} s of the uniform grid",
            fmt_sig(s.first_time_s),
            fmt_sig(s.last_time_s),
            s.max_time_residual_s
        )?;
        let columns: Vec<String> = s
            .columns
            .iter()
            .map(|(n, c)| format!("{n} (column {c})"))
            .collect();
        writeln!(
            out,
            "          columns: {}{}",
            columns.join(", "),
            if s.ignored_columns.is_empty() {
                String::new()
            } else {
                format!("; ignored: {}", s.ignored_columns.join(", "))
            }
        )?;
    }
    Ok(())
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

    #[test]
    fn the_timeline_advances_over_gaps_by_the_missing_samples() {
        let mut tl = Timeline::new(1e-3, 0.1, "test".into());
        let times = [0.0, 0.001, 0.002, 0.00505, 0.006, 0.00705];
        let steps: Vec<_> = times
            .iter()
            .enumerate()
            .map(|(i, &t)| tl.step(i as u64 + 2, t))
            .collect();
        let indices: Vec<u64> = steps.iter().map(|s| s.0).collect();
        assert_eq!(indices, [0, 1, 2, 5, 6, 7]);
        assert_eq!(steps[3].1, Step::Gap { missing: 2 });
        assert!(steps.iter().all(|s| s.2.is_none()), "{steps:?}");
    }

    #[test]
    fn intervals_off_the_period_break_the_rule() {
        let mut tl = Timeline::new(1e-3, 0.1, "test".into());
        tl.step(2, 0.0);
        // 1.3 periods: neither one period nor a gap.
        let (_, step, rule) = tl.step(3, 0.0013);
        assert_eq!(step, Step::Next);
        assert!(rule.is_some_and(|r| r.contains("1.3000 periods")));
        // 2.5 periods: a gap, but not of a whole number of periods.
        let (_, step, rule) = tl.step(4, 0.0038);
        assert!(matches!(step, Step::Gap { .. }));
        assert!(rule.is_some_and(|r| r.contains("whole number")));
    }

    #[test]
    fn a_gap_beyond_the_u64_index_is_a_problem_not_an_overflow() {
        // fuzz/regressions/csv_import/subnormal-period: rows 5e-324 s apart, then a
        // row at 1 s: 2e323 periods, and the index (u64) overflowed.
        let mut tl = Timeline::new(5e-324, 0.1, "median".into());
        tl.step(2, 0.0);
        tl.step(3, 5e-324);
        let (index, step, rule) = tl.step(4, 1.0);
        assert_eq!(index, u64::MAX);
        assert!(matches!(step, Step::Gap { .. }));
        assert!(rule.is_some_and(|r| r.contains("passes 2^64 - 1")));
        let (index, _, rule) = tl.step(5, 2.0);
        assert_eq!(index, u64::MAX);
        assert!(rule.is_some());
    }

    #[test]
    fn the_median_interval_ignores_a_gap() {
        assert_eq!(median_interval_s(&[0.0, 1.0, 2.0, 10.0, 11.0]), 1.0);
    }
}
