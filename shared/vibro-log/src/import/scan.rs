//! The scanner: the first pass over a file, which validates every row, measures the
//! rate and finds the gaps before anything is written.

use super::csv::{CsvRows, Header, Problems, RowRead};
use super::plan::StreamSpec;
use super::progress::Tracker;
use super::timeline::{median_interval_s, Step, Timeline};
use super::RATE_PROBE_INTERVALS;
use crate::{fmt_sig, Error, Result};

/// What the first pass learnt about a file.
#[derive(Debug, Clone)]
pub(super) struct Scan {
    pub(super) header: Header,
    pub(super) bytes: u64,
    pub(super) rows: u64,
    pub(super) first_time_s: f64,
    pub(super) last_time_s: f64,
    /// Index of the last row: rows + missing samples - 1.
    pub(super) last_index: u64,
    pub(super) gaps: u64,
    pub(super) missing_samples: u64,
    /// The nominal period that classified the intervals (the second pass uses it too,
    /// so that both passes find the same gaps).
    pub(super) nominal_period_s: f64,
    pub(super) nominal_source: String,
    /// The period of the blocks: `--*-rate-hz`, or first to last row time over the
    /// samples between them.
    pub(super) period_s: f64,
    pub(super) rate_from: String,
    /// The rate the time column gives (first to last row), whether used or not.
    pub(super) measured_rate_hz: Option<f64>,
}

/// First pass over one file: every row validated, the rate measured, the gaps found.
/// Returns the problems if there are any.
pub(super) fn scan(
    spec: &StreamSpec,
    tolerance: f64,
    progress: &mut Tracker<'_>,
) -> Result<std::result::Result<Scan, Problems>> {
    let mut problems = Problems::new(&spec.file);
    let Some(mut rows) = CsvRows::open(&spec.file, spec.kind, &mut problems)? else {
        return Ok(Err(problems));
    };
    let bytes = std::fs::metadata(&spec.file)
        .map(|m| m.len())
        .map_err(|source| Error::ReadInput {
            path: spec.file.clone(),
            action: "cannot stat".to_string(),
            source,
        })?;

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
        return Err(Error::Input {
            path: spec.file.clone(),
            problem: "no rows to import".to_string(),
        });
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
        return Err(Error::Input {
            path: spec.file.clone(),
            problem: format!(
                "sample period {period_s} s ({rate_from}): shorter than 1 ns, the resolution of the log's times"
            ),
        });
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
