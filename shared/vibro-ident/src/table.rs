//! The CSV files of `vibrocomp identify`: test positions (MODEL.md section 9) and the
//! still / vibrating / still records of a measurement (section 8), read and validated
//! with every problem at once, each naming its line, column, value and rule.
//!
//! Blank lines and `#` comment lines are skipped; the problems keep the file's own line
//! numbers.

use std::path::Path;

use crate::{Amplitudes, Error, Result, TestPosition};

/// A CSV table: header names with the line of each data row.
struct Table {
    header: Vec<String>,
    header_line: usize,
    rows: Vec<(usize, csv::StringRecord)>,
}

/// Reads a CSV file whose blank lines and `#` comment lines are skipped.
///
/// The csv crate's line count skips some comment and blank lines between records, so
/// the file's own line numbers are kept here: comments and blanks are removed first,
/// and each record's line in the filtered text maps back to the file. A numeric table
/// has no quoted multi-line cells, so one record is one line. Rows whose number of
/// cells differs from the header are reported as problems, all at once.
fn read_table(file: &Path, problems: &mut Problems) -> Result<Table> {
    let name = || file.display().to_string();
    let text = std::fs::read_to_string(file).map_err(|source| Error::ReadFile {
        file: name(),
        source: source.into(),
    })?;
    let mut file_lines = Vec::new();
    let mut kept = String::new();
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        file_lines.push(i + 1);
        kept.push_str(line);
        kept.push('\n');
    }
    let line_of = |position: Option<&csv::Position>| {
        position
            .and_then(|p| usize::try_from(p.line()).ok())
            .and_then(|l| file_lines.get(l.wrapping_sub(1)).copied())
            .unwrap_or(0)
    };
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(kept.as_bytes());
    let header_record = reader
        .headers()
        .map_err(|source| Error::Csv {
            file: name(),
            what: "cannot read the header",
            source: source.into(),
        })?
        .clone();
    let header: Vec<String> = header_record.iter().map(str::to_string).collect();
    let header_line = line_of(header_record.position());
    if header.iter().all(String::is_empty) {
        return Err(Error::EmptyTable { file: name() });
    }
    let mut rows = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|source| Error::Csv {
            file: name(),
            what: "malformed CSV",
            source: source.into(),
        })?;
        let line = line_of(record.position());
        if record.len() != header.len() {
            problems.push(format!(
                "line {line}: {} cells, the header (line {header_line}) has {}",
                record.len(),
                header.len()
            ));
            continue;
        }
        rows.push((line, record));
    }
    Ok(Table {
        header,
        header_line,
        rows,
    })
}

/// Collects every problem of a file, then fails once with all of them.
struct Problems {
    file: String,
    list: Vec<String>,
}

impl Problems {
    fn new(file: &Path) -> Self {
        Self {
            file: file.display().to_string(),
            list: Vec::new(),
        }
    }

    fn push(&mut self, problem: String) {
        self.list.push(problem);
    }

    fn finish(self) -> Result<()> {
        if self.list.is_empty() {
            return Ok(());
        }
        Err(Error::Table {
            file: self.file,
            problems: self.list,
        })
    }
}

/// Checks the header against the known columns; returns the index of each known one.
fn columns<const N: usize>(
    table: &Table,
    known: [&str; N],
    required: &[&str],
    problems: &mut Problems,
) -> [Option<usize>; N] {
    for name in &table.header {
        if !known.contains(&name.as_str()) {
            problems.push(format!(
                "header (line {}): unknown column {name:?} (known: {})",
                table.header_line,
                known.join(", ")
            ));
        }
    }
    let index = known.map(|k| table.header.iter().position(|h| h == k));
    for (k, i) in known.iter().zip(&index) {
        if i.is_none() && required.contains(k) {
            problems.push(format!(
                "header (line {}): missing column {k:?} (required: {})",
                table.header_line,
                required.join(", ")
            ));
        }
    }
    index
}

/// A cell's rule: what it must be, and the test.
type Rule = (&'static str, fn(f64) -> bool);

/// Parses one numeric cell; records a problem naming line, column, value and rule.
fn number(
    record: &csv::StringRecord,
    line: usize,
    column: &str,
    index: usize,
    rule: Rule,
    problems: &mut Problems,
) -> Option<f64> {
    let cell = record.get(index).unwrap_or("");
    match cell.parse::<f64>() {
        Ok(v) if (rule.1)(v) => Some(v),
        _ => {
            problems.push(format!(
                "line {line}, column {column}: {cell:?}: {}",
                rule.0
            ));
            None
        }
    }
}

const FINITE: Rule = ("must be a finite number", |v| v.is_finite());
const AMPLITUDE: Rule = ("must be a finite vibration amplitude >= 0 g", |v| {
    v.is_finite() && v >= 0.0
});
const SIGMA: Rule = ("must be a finite standard uncertainty > 0 V", |v| {
    v.is_finite() && v > 0.0
});
const TP: Rule = ("must be a test-position number 1, 2, ...", |v| {
    v.is_finite() && v >= 1.0 && v.fract() == 0.0 && v <= f64::from(u32::MAX)
});

/// Columns of the positions CSV, in this order in [`read_positions`]; the first seven
/// are required, `u_sigma_v` (the standard uncertainty of dU) is optional.
pub const POSITION_COLUMNS: [&str; 8] = [
    "tp",
    "angle_deg",
    "aB3_g",
    "aB1_g",
    "aB2_g",
    "u_still_v",
    "u_vib_v",
    "u_sigma_v",
];

/// Reads the test positions of a CSV file (columns [`POSITION_COLUMNS`],
/// `dU = u_vib_v - u_still_v`) and the file line of each.
pub fn read_positions(file: &Path) -> Result<(Vec<TestPosition>, Vec<usize>)> {
    let mut problems = Problems::new(file);
    let table = read_table(file, &mut problems)?;
    let cols = columns(
        &table,
        POSITION_COLUMNS,
        &POSITION_COLUMNS[..7],
        &mut problems,
    );
    // Cells of the columns present are checked even when others are missing, so
    // that one run reports every problem.
    let mut positions = Vec::new();
    let mut lines = Vec::new();
    for (line, record) in &table.rows {
        let rules = [
            TP, FINITE, AMPLITUDE, AMPLITUDE, AMPLITUDE, FINITE, FINITE, SIGMA,
        ];
        let mut v = [0.0; 8];
        let mut ok = true;
        for (k, (rule, col)) in rules.iter().zip(&cols).enumerate() {
            if let Some(i) = col {
                match number(record, *line, POSITION_COLUMNS[k], *i, *rule, &mut problems) {
                    Some(x) => v[k] = x,
                    None => ok = false,
                }
            }
        }
        if !ok {
            continue;
        }
        let du_v = v[6] - v[5];
        positions.push(TestPosition {
            // Checked above: a whole number in 1..=u32::MAX.
            tp: v[0] as u32,
            angle_deg: v[1],
            amplitudes: Amplitudes {
                a_b3_g: v[2],
                a_b1_g: v[3],
                a_b2_g: v[4],
            },
            du_v,
            du_sigma_v: cols[7].map(|_| v[7]),
        });
        lines.push(*line);
    }
    if table.rows.is_empty() && problems.list.is_empty() {
        problems.push("no test positions: at least one data row is required".into());
    }
    problems.finish()?;
    Ok((positions, lines))
}

/// Reads the three records `[still1, vib, still2]` of a section-8 measurement, V:
/// columns `phase` (still1 | vib | still2) and `u_v`, one sample a row; or three
/// columns `still1_v, vib_v, still2_v` (an empty cell: that record has ended).
pub fn read_records(file: &Path) -> Result<[Vec<f64>; 3]> {
    let mut problems = Problems::new(file);
    let table = read_table(file, &mut problems)?;
    let mut records: [Vec<f64>; 3] = Default::default();
    let has = |c: &str| table.header.iter().any(|h| h == c);
    if has("phase") || has("u_v") {
        let cols = columns(&table, ["phase", "u_v"], &["phase", "u_v"], &mut problems);
        if let [Some(phase_col), Some(u_col)] = cols {
            for (line, record) in &table.rows {
                let phase = record.get(phase_col).unwrap_or("");
                let slot = match phase {
                    "still1" => Some(0),
                    "vib" => Some(1),
                    "still2" => Some(2),
                    other => {
                        problems.push(format!(
                            "line {line}, column phase: {other:?}: must be still1, vib or still2"
                        ));
                        None
                    }
                };
                let value = number(record, *line, "u_v", u_col, FINITE, &mut problems);
                if let (Some(slot), Some(value)) = (slot, value) {
                    records[slot].push(value);
                }
            }
        }
    } else {
        let names = ["still1_v", "vib_v", "still2_v"];
        let cols = columns(&table, names, &names, &mut problems);
        for (line, record) in &table.rows {
            for (k, col) in cols.iter().enumerate() {
                let Some(i) = col else { continue };
                // An empty cell: that record has ended.
                if record.get(*i).unwrap_or("").is_empty() {
                    continue;
                }
                if let Some(v) = number(record, *line, names[k], *i, FINITE, &mut problems) {
                    records[k].push(v);
                }
            }
        }
    }
    problems.finish()?;
    Ok(records)
}

/// Largest relative departure of a row's time step from the file's first step: a rig's
/// file has its rows one sample period apart ([`read_timed`]).
pub const TIME_STEP_TOLERANCE: f64 = 0.01;

/// Most problems one timed file reports (a broken file of a million rows would
/// otherwise list a million).
pub const MAX_TIMED_PROBLEMS: usize = 10;

/// A rig's time-stamped record (`time_s` and named columns), as [`read_timed`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed {
    /// The rows' times, s, strictly increasing.
    pub time_s: Vec<f64>,
    /// The sample period: the mean time step, s.
    pub step_s: f64,
    /// The columns asked for, in the order asked.
    pub columns: Vec<Vec<f64>>,
}

impl Timed {
    /// The sample rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        1.0 / self.step_s
    }
}

/// Reads a rig's CSV file: a header whose first column is `time_s`, then the columns
/// `wanted` (others are ignored: a rig's file may carry more channels). Every cell of
/// those columns must be a finite number and the rows one sample period apart: each
/// step within [`TIME_STEP_TOLERANCE`] of the first. Problems are reported together,
/// at most [`MAX_TIMED_PROBLEMS`], each with its line, column, value and rule.
pub fn read_timed(file: &Path, wanted: &[&str]) -> Result<Timed> {
    let mut problems = Problems::new(file);
    let table = read_table(file, &mut problems)?;
    if table.header.first().map(String::as_str) != Some("time_s") {
        problems.push(format!(
            "header (line {}): the first column is {:?}: must be time_s (the rig's time, s)",
            table.header_line,
            table.header.first().map(String::as_str).unwrap_or("")
        ));
    }
    let index: Vec<Option<usize>> = wanted
        .iter()
        .map(|w| table.header.iter().position(|h| h == w))
        .collect();
    for (w, i) in wanted.iter().zip(&index) {
        if i.is_none() {
            problems.push(format!(
                "header (line {}): missing column {w:?} (the file has: {})",
                table.header_line,
                table.header.join(", ")
            ));
        }
    }
    if table.rows.len() < 2 && problems.list.is_empty() {
        problems.push(format!(
            "{} data rows: a record needs at least 2",
            table.rows.len()
        ));
    }
    if !problems.list.is_empty() {
        return Err(Error::Table {
            file: problems.file,
            problems: problems.list,
        });
    }
    let n = table.rows.len();
    let mut time_s = Vec::with_capacity(n);
    let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(n); wanted.len()];
    let mut first_step_s: Option<f64> = None;
    for (line, record) in &table.rows {
        if problems.list.len() >= MAX_TIMED_PROBLEMS {
            break;
        }
        let Some(t) = number(record, *line, "time_s", 0, FINITE, &mut problems) else {
            continue;
        };
        if let Some(&prev) = time_s.last() {
            let step: f64 = t - prev;
            let first = *first_step_s.get_or_insert(step);
            if !(step > 0.0 && first > 0.0 && (step - first).abs() <= TIME_STEP_TOLERANCE * first) {
                problems.push(format!(
                    "line {line}, column time_s: {t}: must follow the previous row ({prev}) \
                     by one sample period ({first} s) within {} % (a gap, a repeat or rows \
                     out of order)",
                    TIME_STEP_TOLERANCE * 100.0
                ));
            }
        }
        time_s.push(t);
        for (k, i) in index.iter().enumerate() {
            if let Some(i) = *i {
                if let Some(v) = number(record, *line, wanted[k], i, FINITE, &mut problems) {
                    columns[k].push(v);
                }
            }
        }
    }
    problems.finish()?;
    let step_s = (time_s[n - 1] - time_s[0]) / (n - 1) as f64;
    Ok(Timed {
        time_s,
        step_s,
        columns,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file named like `name` holding `text`, removed when dropped.
    fn file(name: &str, text: &str) -> tempfile::TempPath {
        let name = std::path::Path::new(name);
        let mut f = tempfile::Builder::new()
            .prefix(&name.file_stem().unwrap_or_default())
            .suffix(
                &name
                    .extension()
                    .map_or(String::new(), |e| format!(".{}", e.to_string_lossy())),
            )
            .tempfile()
            .unwrap();
        std::io::Write::write_all(&mut f, text.as_bytes()).unwrap();
        f.into_temp_path()
    }

    #[test]
    fn positions_keep_their_file_lines_and_du() {
        let path = file(
            "positions.csv",
            "# comment\ntp,angle_deg,aB3_g,aB1_g,aB2_g,u_still_v,u_vib_v\n\n\
             1,0,2,0,0,1.5,1.75\n# more\n2,90,2,0,0,0.0,-0.5\n",
        );
        let (positions, lines) = read_positions(&path).unwrap();
        assert_eq!(lines, [4, 6]);
        assert_eq!(positions[0].tp, 1);
        assert_eq!(positions[0].du_v, 0.25);
        assert_eq!(positions[1].du_v, -0.5);
        assert_eq!(positions[1].du_sigma_v, None);
    }

    #[test]
    fn every_problem_of_a_positions_file_is_named() {
        let path = file(
            "bad-positions.csv",
            "tp,angle_deg,aB3_g,aB1_g,aB2_g,u_still_v,u_vib_v,extra\n\
             0,0,-1,0,0,1,1,0\n1,0,1\n",
        );
        let e = read_positions(&path).unwrap_err().to_string();
        let p = path.display();
        assert_eq!(
            e,
            format!(
                "{p}: 4 problems:\n  \
                 line 3: 3 cells, the header (line 1) has 8\n  \
                 header (line 1): unknown column \"extra\" (known: {})\n  \
                 line 2, column tp: \"0\": must be a test-position number 1, 2, ...\n  \
                 line 2, column aB3_g: \"-1\": must be a finite vibration amplitude >= 0 g",
                POSITION_COLUMNS.join(", ")
            )
        );
    }

    #[test]
    fn records_read_in_both_layouts() {
        let long = file("long.csv", "phase,u_v\nstill1,1\nvib,2\nvib,3\nstill2,4\n");
        assert_eq!(
            read_records(&long).unwrap(),
            [vec![1.0], vec![2.0, 3.0], vec![4.0]]
        );
        let wide = file("wide.csv", "still1_v,vib_v,still2_v\n1,2,3\n,4,\n");
        assert_eq!(
            read_records(&wide).unwrap(),
            [vec![1.0], vec![2.0, 4.0], vec![3.0]]
        );
        let bad = file("bad-phase.csv", "phase,u_v\nstill3,x\n");
        assert_eq!(
            read_records(&bad).unwrap_err().to_string(),
            format!(
                "{}: 2 problems:\n  line 2, column phase: \"still3\": must be still1, vib or \
                 still2\n  line 2, column u_v: \"x\": must be a finite number",
                bad.display()
            )
        );
    }

    #[test]
    fn an_empty_file_needs_a_header() {
        let path = file("empty.csv", "# nothing\n\n");
        assert_eq!(
            read_records(&path).unwrap_err().to_string(),
            format!("{}: empty file: a header row is required", path.display())
        );
    }

    #[test]
    fn timed_records_read_with_their_rate_and_every_problem_named() {
        let good = file(
            "timed.csv",
            "# rig\ntime_s,u1_v,other\n0.00125,1,9\n0.0025,2,9\n0.00375,3,9\n",
        );
        let t = read_timed(&good, &["u1_v"]).unwrap();
        assert_eq!(t.columns, vec![vec![1.0, 2.0, 3.0]]);
        assert!((t.rate_hz() - 800.0).abs() < 1e-9, "{}", t.rate_hz());
        let bad = file(
            "timed-bad.csv",
            "time_s,u1_v\n0.0,1\n0.1,x\n0.25,3\n0.25,4\n",
        );
        let p = bad.display();
        assert_eq!(
            read_timed(&bad, &["u1_v", "u2_v"]).unwrap_err().to_string(),
            format!("{p}: header (line 1): missing column \"u2_v\" (the file has: time_s, u1_v)")
        );
        assert_eq!(
            read_timed(&bad, &["u1_v"]).unwrap_err().to_string(),
            format!(
                "{p}: 3 problems:\n  line 3, column u1_v: \"x\": must be a finite number\n  \
                 line 4, column time_s: 0.25: must follow the previous row (0.1) by one sample \
                 period (0.1 s) within 1 % (a gap, a repeat or rows out of order)\n  \
                 line 5, column time_s: 0.25: must follow the previous row (0.25) by one \
                 sample period (0.1 s) within 1 % (a gap, a repeat or rows out of order)"
            )
        );
        let no_time = file("timed-notime.csv", "t,u1_v\n0,1\n1,2\n");
        assert!(read_timed(&no_time, &["u1_v"])
            .unwrap_err()
            .to_string()
            .contains("the first column is \"t\": must be time_s"));
    }
}
