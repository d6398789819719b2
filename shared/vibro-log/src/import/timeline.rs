//! The time grid: row times to sample indices, one period apart, with gaps of a whole
//! number of periods.

use super::GAP_PERIODS;
use crate::fmt_sig;

/// Turns increasing row times into sample indices: consecutive rows are one period
/// apart; an interval longer than [`GAP_PERIODS`] periods is a gap of a whole number of
/// periods, whose missing samples advance the index.
#[derive(Debug, Clone)]
pub(super) struct Timeline {
    /// The nominal period that classifies intervals.
    pub(super) period_s: f64,
    tolerance: f64,
    /// Where it came from, for messages.
    pub(super) period_source: String,
    prev: Option<(u64, f64)>,
    index: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Step {
    First,
    Next,
    Gap { missing: u64 },
}

impl Timeline {
    pub(super) fn new(period_s: f64, tolerance: f64, period_source: String) -> Timeline {
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
    pub(super) fn step(&mut self, line: u64, time_s: f64) -> (u64, Step, Option<String>) {
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
pub(super) fn median_interval_s(times: &[f64]) -> f64 {
    let mut dt: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    dt.sort_by(f64::total_cmp);
    dt[dt.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;

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
