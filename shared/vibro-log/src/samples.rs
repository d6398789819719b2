//! A recorded 3-axis vibration-sensor stream as CSV, through the estimator
//! (`vibrocomp estimate`, docs/estimation.md): three columns (x, y, z), one sample a
//! row at the configured rate, an optional header row naming the columns; blank and
//! `#` lines skipped. A header that opens with `time_s` (the rig's format, as `log
//! import` reads it: the time each sample was taken, s) adds a time column: the rows
//! must then be one sample period apart (within [`TIME_STEP_TOLERANCE`] of it), and the
//! estimates are stamped on the file's own time base. The file is read line by line through [`LineReader`]'s cap and
//! handed to `vibro_dsp::Estimator` in blocks, as a recorder's stream would be.
//! Also the frequency-response table the estimator divides out.
//!
//! Bad cells are listed with their line, column, value and rule, up to
//! [`MAX_PROBLEMS`], and nothing is estimated.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use vibro_dsp::{Estimate, Estimator, ResponsePoint, SampleBlock};
use vibro_toml::echo::excerpt;

use crate::import::LineReader;
use crate::{Error, Result};

/// Samples handed to the estimator at a time: the block size of a recorder's stream.
pub const BLOCK_SAMPLES: usize = 4096;
/// How far a row's `time_s` step may be from one sample period, as a fraction of it:
/// one rule for every rig file (`identify`'s reader has it).
pub use vibro_ident::table::TIME_STEP_TOLERANCE;
/// At most this many bad cells are listed before reading stops.
pub const MAX_PROBLEMS: usize = 10;

/// The columns of a response table, in order (header required).
pub const RESPONSE_COLUMNS: [&str; 7] = [
    "frequency_hz",
    "gain_x",
    "gain_y",
    "gain_z",
    "phase_x_deg",
    "phase_y_deg",
    "phase_z_deg",
];

/// What a stream file gave the estimator.
#[derive(Debug, Clone)]
pub struct StreamEstimates {
    pub estimates: Vec<Estimate>,
    /// The axes' columns' names: the header's, or x, y, z.
    pub columns: [String; 3],
    /// The file has a `time_s` column (its first).
    pub time_column: bool,
    /// Data rows read.
    pub rows: u64,
}

/// One data line of a CSV file: its 1-based line number and its text, trimmed.
struct Line {
    number: u64,
    text: String,
}

/// Reads the lines of a numeric CSV file, skipping blank and `#` lines, through the
/// capped line reader: a line over [`crate::import::MAX_LINE_BYTES`] (`/dev/zero`, a
/// binary file) stops the reading with its number and first bytes.
struct CsvLines<R> {
    reader: LineReader<R>,
    /// The current line's bytes, reused from line to line.
    bytes: Vec<u8>,
    file: PathBuf,
}

impl<R: BufRead> CsvLines<R> {
    fn new(reader: R, file: &Path) -> CsvLines<R> {
        CsvLines {
            reader: LineReader::new(reader, file),
            bytes: Vec::new(),
            file: file.to_path_buf(),
        }
    }

    fn next_line(&mut self) -> Result<Option<Line>> {
        loop {
            if self.reader.read_line(&mut self.bytes)?.is_none() {
                return Ok(None);
            }
            let number = self.reader.line();
            let text = std::str::from_utf8(&self.bytes).map_err(|_| Error::ReadInput {
                path: self.file.clone(),
                action: format!("cannot read line {number}"),
                // As `BufRead::read_line` said it before this reader.
                source: std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    "stream did not contain valid UTF-8",
                ),
            })?;
            let trimmed = text.trim();
            if trimmed.is_empty() || trimmed.starts_with('#') {
                continue;
            }
            return Ok(Some(Line {
                number,
                text: trimmed.to_string(),
            }));
        }
    }
}

/// The cells of a CSV line, trimmed and unquoted.
fn cells(text: &str) -> Vec<&str> {
    text.split(',')
        .map(|c| c.trim().trim_matches('"').trim())
        .collect()
}

/// Counts bytes read, for the progress.
struct Counted<R> {
    inner: R,
    bytes: std::rc::Rc<std::cell::Cell<u64>>,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.bytes.set(self.bytes.get() + n as u64);
        Ok(n)
    }
}

fn open(file: &Path) -> Result<File> {
    File::open(file).map_err(|source| Error::ReadInput {
        path: file.to_path_buf(),
        action: "cannot open".into(),
        source,
    })
}

fn input(file: &Path, problem: String) -> Error {
    Error::Input {
        path: file.to_path_buf(),
        problem,
    }
}

/// Streams the CSV file `file` through `estimator` in blocks of [`BLOCK_SAMPLES`]
/// (sample `n` at `n / sample_rate`); `progress(bytes_read, total_bytes)` after each
/// block. Fails on a file with no data row, a bad header, bad cells (each listed), or
/// fewer rows than one window.
pub fn estimate_stream_csv(
    file: &Path,
    estimator: &mut Estimator,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<StreamEstimates> {
    let handle = open(file)?;
    let total_bytes = handle.metadata().map(|m| m.len()).unwrap_or(0);
    let bytes = std::rc::Rc::new(std::cell::Cell::new(0));
    let mut lines = CsvLines::new(
        BufReader::new(Counted {
            inner: handle,
            bytes: bytes.clone(),
        }),
        file,
    );

    let mut columns = ["x".to_string(), "y".to_string(), "z".to_string()];
    let mut pending = lines.next_line()?;
    let Some(first) = &pending else {
        return Err(input(
            file,
            "no data rows (expected three columns: x, y, z, one sample a row)".into(),
        ));
    };
    let first_cells = cells(&first.text);
    let mut time_column = false;
    if first_cells.iter().any(|c| c.parse::<f64>().is_err()) {
        // A header row names the columns; it must still have one per axis, after a
        // `time_s` column if it opens with one.
        time_column = first_cells.first() == Some(&"time_s");
        let axes_cells = &first_cells[usize::from(time_column)..];
        if axes_cells.len() != 3 {
            return Err(input(
                file,
                format!(
                    "line {}: header has {} columns ({}); expected 3, one per axis (x, y, z){}",
                    first.number,
                    first_cells.len(),
                    // A line is up to 64 KiB (a CR-only file is one line): a line's worth.
                    excerpt(&first_cells.join(", ")),
                    if time_column { ", after time_s" } else { "" }
                ),
            ));
        }
        columns = std::array::from_fn(|i| axes_cells[i].to_string());
        pending = lines.next_line()?;
    }

    let period_ns = 1e9 / estimator.config().sample_rate_hz();
    let period_s = 1.0 / estimator.config().sample_rate_hz();
    let mut problems: Vec<String> = Vec::new();
    let mut block: Vec<[f64; 3]> = Vec::with_capacity(BLOCK_SAMPLES);
    let mut estimates = Vec::new();
    let mut rows: u64 = 0;
    let mut seq: u64 = 0;
    let mut block_first_row: u64 = 0;
    // With a time column: the time of the block's first row, and of the previous row.
    let mut block_t0_s: Option<f64> = None;
    let mut last_time: Option<(u64, f64)> = None;
    let mut flush = |block: &mut Vec<[f64; 3]>,
                     seq: &mut u64,
                     first_row: u64,
                     t0_s: Option<f64>,
                     estimator: &mut Estimator|
     -> Result<()> {
        let t0_ns = match t0_s {
            Some(t) => (t * 1e9).round() as u64,
            None => (first_row as f64 * period_ns).round() as u64,
        };
        let b = SampleBlock {
            seq: *seq,
            t0_ns,
            samples_raw: block,
        };
        estimator
            .push_block(&b, |e| estimates.push(*e))
            .map_err(|source| Error::Estimate {
                path: file.to_path_buf(),
                first_row,
                source,
            })?;
        *seq += 1;
        block.clear();
        Ok(())
    };
    while let Some(line) = pending {
        let all = cells(&line.text);
        let width = 3 + usize::from(time_column);
        if all.len() != width {
            problems.push(format!(
                "line {}: {} columns; expected {width}, {}one per axis ({})",
                line.number,
                all.len(),
                if time_column { "time_s then " } else { "" },
                columns.join(", ")
            ));
        } else {
            if time_column {
                match check_time(all[0], line.number, last_time, period_s) {
                    Ok(t) => {
                        if block.is_empty() {
                            block_t0_s = Some(t);
                        }
                        last_time = Some((line.number, t));
                    }
                    Err(p) => problems.push(p),
                }
            }
            let c = &all[usize::from(time_column)..];
            let mut sample = [0.0; 3];
            for (i, cell) in c.iter().enumerate() {
                match cell.parse::<f64>() {
                    Ok(v) => sample[i] = v,
                    Err(_) => problems.push(format!(
                        "line {}, column {} (\"{}\"): \"{}\": {}",
                        line.number,
                        i + 1 + usize::from(time_column),
                        excerpt(&columns[i]),
                        excerpt(cell),
                        if cell.is_empty() {
                            "empty cell; every row needs a number per axis"
                        } else {
                            "not a number"
                        }
                    )),
                }
            }
            block.push(sample);
        }
        if problems.len() >= MAX_PROBLEMS {
            break;
        }
        rows += 1;
        if block.len() == BLOCK_SAMPLES && problems.is_empty() {
            flush(&mut block, &mut seq, block_first_row, block_t0_s, estimator)?;
            block_first_row = rows;
            progress(bytes.get(), total_bytes);
        }
        pending = lines.next_line()?;
    }
    if !problems.is_empty() {
        let more = if problems.len() >= MAX_PROBLEMS {
            format!(" (stopped after the first {MAX_PROBLEMS})")
        } else {
            String::new()
        };
        return Err(input(
            file,
            format!("bad input{more}:\n  {}", problems.join("\n  ")),
        ));
    }
    if !block.is_empty() {
        flush(&mut block, &mut seq, block_first_row, block_t0_s, estimator)?;
    }
    if estimates.is_empty() {
        return Err(input(
            file,
            format!(
                "{rows} rows at {} Hz are shorter than one window ({} samples)",
                estimator.config().sample_rate_hz(),
                estimator.config().window_samples()
            ),
        ));
    }
    Ok(StreamEstimates {
        estimates,
        columns,
        time_column,
        rows,
    })
}

/// A row's `time_s` cell: a finite time `0 <= t < 1.8e10` s (the wire's range, as `log
/// import` takes it), one sample period `period_s` after the previous row's within
/// [`TIME_STEP_TOLERANCE`] of it. A problem names the line, the value and the rule.
fn check_time(
    cell: &str,
    line: u64,
    previous: Option<(u64, f64)>,
    period_s: f64,
) -> std::result::Result<f64, String> {
    let t = match cell.parse::<f64>() {
        Ok(t) if t.is_finite() && (0.0..1.8e10).contains(&t) => t,
        _ => {
            return Err(format!(
                "line {line}, column 1 (\"time_s\"): \"{}\": must be a time 0 <= t < 1.8e10 s",
                excerpt(cell)
            ))
        }
    };
    if let Some((prev_line, prev)) = previous {
        let step = t - prev;
        if (step - period_s).abs() > TIME_STEP_TOLERANCE * period_s {
            return Err(format!(
                "line {line}, column 1 (\"time_s\"): \"{}\": {step} s after line {prev_line}'s \
                 {prev}: rows must be one sample period ({period_s} s at the configured rate) \
                 apart, within {} %",
                excerpt(cell),
                100.0 * TIME_STEP_TOLERANCE
            ));
        }
    }
    Ok(t)
}

/// Reads a frequency-response table (columns [`RESPONSE_COLUMNS`], header required;
/// gains measured / true, phases in degrees).
pub fn read_response_table(file: &Path) -> Result<Vec<ResponsePoint>> {
    const COLUMNS: [&str; 7] = RESPONSE_COLUMNS;
    let mut lines = CsvLines::new(BufReader::new(open(file)?), file);
    let Some(header) = lines.next_line()? else {
        return Err(input(
            file,
            format!("empty response table (header: {})", COLUMNS.join(", ")),
        ));
    };
    if cells(&header.text) != COLUMNS {
        return Err(input(
            file,
            format!(
                "line {}: header \"{}\"; expected {}",
                header.number,
                excerpt(&header.text),
                COLUMNS.join(", ")
            ),
        ));
    }
    let mut points = Vec::new();
    let mut problems = Vec::new();
    while let Some(line) = lines.next_line()? {
        let c = cells(&line.text);
        if c.len() != COLUMNS.len() {
            problems.push(format!(
                "line {}: {} columns; expected {}",
                line.number,
                c.len(),
                COLUMNS.len()
            ));
            continue;
        }
        let mut v = [0.0; 7];
        for (i, cell) in c.iter().enumerate() {
            match cell.parse::<f64>() {
                Ok(x) => v[i] = x,
                Err(_) => problems.push(format!(
                    "line {}, column {} ({}): \"{}\": not a number",
                    line.number,
                    i + 1,
                    COLUMNS[i],
                    excerpt(cell)
                )),
            }
        }
        points.push(ResponsePoint {
            frequency_hz: v[0],
            gain: [v[1], v[2], v[3]],
            phase_rad: [v[4].to_radians(), v[5].to_radians(), v[6].to_radians()],
        });
    }
    if !problems.is_empty() {
        return Err(input(
            file,
            format!("bad response table:\n  {}", problems.join("\n  ")),
        ));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_dsp::{EstimatorConfig, EstimatorConfigRaw};

    fn file(name: &str, text: &str) -> tempfile::TempPath {
        crate::test_file(name, text.as_bytes())
    }

    #[test]
    fn cells_are_trimmed_and_unquoted() {
        assert_eq!(cells(" 1 , \"x\" ,2"), ["1", "x", "2"]);
    }

    #[test]
    fn a_response_table_converts_its_phases_to_radians() {
        let path = file(
            "response.csv",
            &format!(
                "# measured\n{}\n10,1,1,1,90,0,-180\n",
                RESPONSE_COLUMNS.join(",")
            ),
        );
        let points = read_response_table(&path).unwrap();
        assert_eq!(points.len(), 1);
        assert_eq!(points[0].frequency_hz, 10.0);
        assert_eq!(points[0].phase_rad[0], std::f64::consts::FRAC_PI_2);
        assert_eq!(points[0].phase_rad[2], -std::f64::consts::PI);
        let bad = file(
            "bad-response.csv",
            &format!("{}\n1,2\n", RESPONSE_COLUMNS.join(",")),
        );
        assert_eq!(
            read_response_table(&bad).unwrap_err().to_string(),
            format!(
                "{}: bad response table:\n  line 2: 2 columns; expected 7",
                bad.display()
            )
        );
    }

    #[test]
    fn bad_cells_are_listed_by_line_and_column() {
        let config = EstimatorConfig::try_from(EstimatorConfigRaw::new(25600.0, [1.0; 3])).unwrap();
        let mut estimator = Estimator::new(config);
        let path = file("bad-samples.csv", "a,b,c\n1,2,3\n1,,x\n1,2\n");
        let e = estimate_stream_csv(&path, &mut estimator, &mut |_, _| {})
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "{}: bad input:\n  \
                 line 3, column 2 (\"b\"): \"\": empty cell; every row needs a number per axis\n  \
                 line 3, column 3 (\"c\"): \"x\": not a number\n  \
                 line 4: 2 columns; expected 3, one per axis (a, b, c)",
                path.display()
            )
        );
    }

    #[test]
    fn a_short_stream_is_shorter_than_a_window() {
        let config = EstimatorConfig::try_from(EstimatorConfigRaw::new(25600.0, [1.0; 3])).unwrap();
        let window = config.window_samples();
        let mut estimator = Estimator::new(config);
        let path = file("short.csv", "0,0,0\n0,0,0\n");
        let e = estimate_stream_csv(&path, &mut estimator, &mut |_, _| {})
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "{}: 2 rows at 25600 Hz are shorter than one window ({window} samples)",
                path.display()
            )
        );
    }

    /// The rig's format: a `time_s` column first. The same samples give the same
    /// estimates as without it, stamped on the file's time base (here 100 s on).
    #[test]
    fn a_time_column_stamps_the_estimates_on_the_files_time() {
        let rate_hz = 1024.0;
        let config = || {
            let mut raw = EstimatorConfigRaw::new(rate_hz, [1.0; 3]);
            raw.broadband_band_hz = [20.0, 400.0];
            raw.psd_bands_hz = vec![[20.0, 100.0], [100.0, 400.0]];
            EstimatorConfig::try_from(raw).unwrap()
        };
        let n = 3 * 1024;
        let (mut plain, mut timed) = (String::from("x,y,z\n"), String::from("time_s,x,y,z\n"));
        for k in 0..n {
            let t = k as f64 / rate_hz;
            let v = [
                (std::f64::consts::TAU * 97.0 * t).sin(),
                0.5 * (std::f64::consts::TAU * 211.0 * t).cos(),
                0.25 * (std::f64::consts::TAU * 53.0 * t).sin(),
            ];
            plain.push_str(&format!("{},{},{}\n", v[0], v[1], v[2]));
            timed.push_str(&format!("{},{},{},{}\n", 100.0 + t, v[0], v[1], v[2]));
        }
        let run = |text: &str, name: &str| {
            let mut estimator = Estimator::new(config());
            estimate_stream_csv(&file(name, text), &mut estimator, &mut |_, _| {}).unwrap()
        };
        let (a, b) = (run(&plain, "plain.csv"), run(&timed, "timed.csv"));
        assert!(!a.time_column && b.time_column);
        assert_eq!(b.columns, ["x", "y", "z"]);
        assert_eq!(a.estimates.len(), b.estimates.len());
        assert!(!a.estimates.is_empty());
        for (x, y) in a.estimates.iter().zip(&b.estimates) {
            assert_eq!(y.start_ns - x.start_ns, 100_000_000_000);
            assert_eq!(x.tones.len(), y.tones.len());
            for (tx, ty) in x.tones.iter().zip(y.tones.iter()) {
                assert_eq!(tx.frequency_hz, ty.frequency_hz);
                assert_eq!(tx.amplitude_g, ty.amplitude_g);
            }
            assert_eq!(x.broadband.rms_g, y.broadband.rms_g);
        }
    }

    /// Rows not one sample period apart, or a time that is no time, are refused with
    /// their line, value and rule.
    #[test]
    fn a_time_column_must_step_by_one_sample_period() {
        let config = EstimatorConfig::try_from(EstimatorConfigRaw::new(4096.0, [1.0; 3])).unwrap();
        let mut estimator = Estimator::new(config);
        let path = file(
            "bad-times.csv",
            "time_s,a,b,c\n0,1,2,3\n0.000244140625,1,2,3\n0.001,1,2,3\nx,1,2,3\n",
        );
        let e = estimate_stream_csv(&path, &mut estimator, &mut |_, _| {})
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 4, column 1 (\"time_s\"): \"0.001\": 0.000755")
                && e.contains(
                    "s after line 3's 0.000244140625: rows must be one sample period \
                     (0.000244140625 s at the configured rate) apart, within 1 %"
                ),
            "{e}"
        );
        assert!(
            e.contains("line 5, column 1 (\"time_s\"): \"x\": must be a time 0 <= t < 1.8e10 s"),
            "{e}"
        );
    }
}
