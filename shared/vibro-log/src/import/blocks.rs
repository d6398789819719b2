//! The block maker: the second pass over a file, which cuts its rows into wire blocks
//! as the rig's [`crate::rig::Packetizer`] does and checks each row against the
//! uniform time grid.

use vibro_msgs::{accel_flags, vib_flags, AccelBlock, VibBlock};

use super::csv::{CsvRows, Problems, Row, RowRead};
use super::plan::StreamSpec;
use super::scan::Scan;
use super::timeline::Timeline;
use super::ImportKind;
use crate::rig::RigMessage;
use crate::topics::topic;
use crate::{fmt_sig, Error, Result};

/// The block being filled, allocated once (a `VibBlock` is 12 kB).
pub(super) enum Block {
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

    pub(super) fn message(&self) -> RigMessage<'_> {
        match self {
            Block::Accel(b) => RigMessage::Accel(b),
            Block::Vib(b) => RigMessage::Vib(b),
        }
    }
}

/// Second pass over one file: rows to blocks.
pub(super) struct BlockMaker {
    pub(super) topic: String,
    pub(super) rows: CsvRows,
    timeline: Timeline,
    first_time_s: f64,
    period_s: f64,
    tolerance: f64,
    pub(super) block: Block,
    block_samples: usize,
    /// A row read past the end of the previous block (after a gap).
    carry: Option<(u64, [f64; 3])>,
    /// The index that follows the last block without a gap.
    next_index: u64,
    pub(super) seq: u64,
    /// The largest distance of a row's time from the grid, s.
    pub(super) max_residual_s: f64,
    /// Rows farther from the grid than the tolerance: how many, the first (line and
    /// problem), and the farthest (periods, line).
    off_grid: u64,
    off_grid_first: Option<(u64, String)>,
    off_grid_max: (f64, u64),
    /// Why the grid may be wrong, for the problem.
    off_grid_hint: String,
    /// Problems of this pass: rows off the grid, or a file changed since the first.
    pub(super) problems: Problems,
}

impl BlockMaker {
    pub(super) fn new(
        spec: &StreamSpec,
        scan: &Scan,
        tolerance: f64,
        source_id: u32,
    ) -> Result<BlockMaker> {
        let mut problems = Problems::new(&spec.file);
        let Some(rows) = CsvRows::open(&spec.file, spec.kind, &mut problems)? else {
            return Err(Error::Input {
                path: spec.file.clone(),
                problem: "changed while it was imported (its header no longer reads)".to_string(),
            });
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
    pub(super) fn fill(&mut self) -> Result<bool> {
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
    pub(super) fn report_off_grid(&mut self) {
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
