//! Recurring problems told at a bounded rate: [`Recurring`], and [`DisorderLog`] for an
//! input stream's out-of-order messages and resyncs (`crate::continuity`).

use crate::{Arrival, StreamCounters};
use tracing::warn;
/// A problem that recurs (out-of-order messages, resyncs), logged at a bounded rate:
/// its first occurrence after a quiet summary period at once ([`Recurring::now`]), the
/// others as one count per summary period ([`Recurring::period`]). So a flood costs
/// one line per period, and a new episode hours later is still told when it starts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Recurring {
    /// The problem's total when it was last told (at once or in a period's line).
    told: u64,
    /// Occurrences in the current or the last period: the next one waits for the
    /// period's line.
    busy: bool,
}

impl Recurring {
    /// The problem occurred, its counter now at `total`: true when the caller logs this
    /// occurrence now (the first since a quiet period).
    pub fn now(&mut self, total: u64) -> bool {
        if self.busy {
            return false;
        }
        self.busy = true;
        self.told = total;
        true
    }

    /// At the end of a summary period, the counter at `total`: the occurrences not told
    /// yet, which the caller logs when not 0.
    pub fn period(&mut self, total: u64) -> u64 {
        let untold = total.saturating_sub(self.told);
        self.told = total;
        self.busy = untold > 0;
        untold
    }
}

/// An input stream's out-of-order messages and resyncs, told at a bounded rate: the
/// first of each after a quiet summary period at once ([`Self::arrival`]), the rest in
/// one line per summary period ([`Self::period`]). Never "only the first one per
/// process": a new episode hours later is told when it starts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DisorderLog {
    out_of_order: Recurring,
    resyncs: Recurring,
}

impl DisorderLog {
    /// After `arrival` (of the message numbered `seq`) was recorded in `totals`:
    /// `last_seq` is the stream's last accepted message now
    /// (`Continuity::last_seq`). `stream` names it in the lines (`"accelerometer"`).
    pub fn arrival(
        &mut self,
        stream: &str,
        arrival: &Arrival,
        seq: u64,
        last_seq: Option<u64>,
        totals: &StreamCounters,
    ) {
        if !arrival.accepted && self.out_of_order.now(totals.out_of_order) {
            warn!(
                seq,
                last_seq,
                "dropping an out-of-order {stream} message (a repeat, or older than the \
                 last one taken); more are counted, and told once per summary period"
            );
        }
        if arrival.resynced && self.resyncs.now(totals.resyncs) {
            warn!(
                seq,
                retracted_messages = arrival.retracted_messages,
                "{stream} stream taken up again at seq {seq} (resync after out-of-order \
                 messages, or back to the stream left at one); its output is flagged \
                 as a gap; more are counted, and told once per summary period"
            );
        }
    }

    /// At the end of a summary period: one line with what was not told yet, if anything.
    pub fn period(&mut self, stream: &str, totals: &StreamCounters) {
        let out_of_order = self.out_of_order.period(totals.out_of_order);
        let resyncs = self.resyncs.period(totals.resyncs);
        if out_of_order + resyncs > 0 {
            warn!(
                "{stream} stream: {out_of_order} more out-of-order messages dropped and \
                 {resyncs} more resyncs in the last period (in all {} and {})",
                totals.out_of_order, totals.resyncs
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flood: the first at once, then one count per period; after a quiet period the
    /// next one at once again.
    #[test]
    fn a_recurring_problem_is_told_at_a_bounded_rate() {
        let mut r = Recurring::default();
        let mut total = 0;
        let mut told_now = 0;
        for _ in 0..100 {
            total += 1;
            told_now += u64::from(r.now(total));
        }
        assert_eq!((told_now, r.period(total)), (1, 99));
        for _ in 0..50 {
            total += 1;
            assert!(!r.now(total));
        }
        assert_eq!(r.period(total), 50);
        assert_eq!(r.period(total), 0, "a quiet period");
        total += 1;
        assert!(r.now(total), "a new episode is told at once");
        assert_eq!(r.period(total), 0);
        total += 1;
        assert!(r.now(total));
    }
}
