//! No silent loss: the continuity of an input stream's `seq` (one per message) and
//! `first_sample_index` (one per sample), so every gap is counted and the outputs it
//! affects can be flagged.
//!
//! **Gaps and jumps.** A forward step of `seq` by `k` is a gap of `k - 1` lost messages
//! only while `k - 1` is at most [`MAX_LOST_MESSAGES`] (2^20); a step of `first_sample_index` past
//! the expected index is a gap of that many lost samples only while it is at most
//! [`MAX_LOST_SAMPLES`] (2^32). A bigger step is not a loss that a subscriber could
//! have suffered: iceoryx2 drops at most a subscriber's buffer (a few blocks) at a
//! time, and 2^20 blocks is hours of any vibrocomp stream (11.7 h of 40 ms
//! accelerometer blocks, 2.9 h of 10 ms vibration blocks), 2^32 samples days of any
//! sensor (5 days at 10 kHz). Such a step is a corrupt or crafted counter, or a
//! producer that renumbered: it is flagged as a jump ([`Arrival::seq_jump`],
//! [`Arrival::index_jump`], counted in [`StreamCounters::seq_jumps`] /
//! [`StreamCounters::index_jumps`]), never summed into the losses (a random `u64` `seq`
//! would otherwise count ~2^63 messages lost), and handled like a restart: what follows
//! starts a new history ([`Arrival::restarted`] is set) and the output after it is
//! flagged as a gap.
use serde::Serialize;

/// The most messages a forward `seq` step counts as lost (see the module doc); a
/// bigger step is a jump.
pub const MAX_LOST_MESSAGES: u64 = 1 << 20;

/// The most samples a forward `first_sample_index` step counts as lost (see the module
/// doc); a bigger step is a jump.
pub const MAX_LOST_SAMPLES: u64 = 1 << 32;

/// What the arrival of one message tells about the stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Arrival {
    /// False for a duplicate or an older message (`seq` not above the last one and not a
    /// restart): the caller drops or flags it; the stream's state is unchanged.
    pub accepted: bool,
    /// Messages missing between the previous one and this one (`seq` jump).
    pub lost_messages: u64,
    /// Samples missing before this message (`first_sample_index` jump).
    pub lost_samples: u64,
    /// The stream's history no longer applies: the producer started again (`seq` back
    /// to 0), or `seq` or `first_sample_index` jumped ([`Self::seq_jump`],
    /// [`Self::index_jump`]). What was lost in between is unknown: start afresh.
    pub restarted: bool,
    /// `seq` stepped forward by more than [`MAX_LOST_MESSAGES`] + 1: not counted in
    /// `lost_messages`; `restarted` is set too.
    pub seq_jump: bool,
    /// `first_sample_index` stepped forward by more than [`MAX_LOST_SAMPLES`] past the
    /// expected index: not counted in `lost_samples`; `restarted` is set too.
    pub index_jump: bool,
    /// `first_sample_index` went backwards although `seq` went forwards (overlapping
    /// samples, or the producer reset its sample counter).
    pub index_backwards: bool,
}

impl Arrival {
    /// Data is missing right before this message, or its history is unknown.
    pub fn gap(&self) -> bool {
        self.lost_messages > 0 || self.lost_samples > 0 || self.restarted || self.index_backwards
    }
}

/// The continuity state of one input stream.
#[derive(Debug, Clone, Default)]
pub struct Continuity {
    last_seq: Option<u64>,
    next_sample_index: Option<u64>,
}

impl Continuity {
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks a message that carries `count` samples from `first_sample_index` on.
    pub fn check(&mut self, seq: u64, first_sample_index: u64, count: u64) -> Arrival {
        let mut arrival = self.check_seq(seq);
        if !arrival.accepted {
            return arrival;
        }
        if let (Some(next), false) = (self.next_sample_index, arrival.restarted) {
            if first_sample_index > next {
                let step = first_sample_index - next;
                if step > MAX_LOST_SAMPLES {
                    arrival.index_jump = true;
                    arrival.restarted = true;
                } else {
                    arrival.lost_samples = step;
                }
            } else if first_sample_index < next {
                arrival.index_backwards = true;
            }
        }
        self.next_sample_index = Some(first_sample_index.saturating_add(count));
        arrival
    }

    /// Checks a message that carries no sample index (an estimate).
    pub fn check_seq(&mut self, seq: u64) -> Arrival {
        let mut arrival = Arrival {
            accepted: true,
            ..Arrival::default()
        };
        match self.last_seq {
            None => {}
            Some(last) if seq > last => {
                let lost = seq - last - 1;
                if lost > MAX_LOST_MESSAGES {
                    // Not a loss: a corrupt or renumbered counter (module doc).
                    arrival.seq_jump = true;
                    arrival.restarted = true;
                } else {
                    arrival.lost_messages = lost;
                }
            }
            // A producer that restarts counts from 0 again.
            Some(last) if seq == 0 && last > 0 => arrival.restarted = true,
            Some(_) => {
                arrival.accepted = false;
                return arrival;
            }
        }
        self.last_seq = Some(seq);
        arrival
    }
}

/// Totals of one input stream, for the heartbeat and the summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct StreamCounters {
    /// Messages taken from the stream, good or bad.
    pub received: u64,
    /// Messages missing by `seq`.
    pub lost_messages: u64,
    /// Samples missing by `first_sample_index`.
    pub lost_samples: u64,
    /// Duplicate or older messages.
    pub out_of_order: u64,
    /// Producer restarts (`seq` back to 0).
    pub restarts: u64,
    /// `seq` jumps too big to be losses (more than [`MAX_LOST_MESSAGES`] skipped): not
    /// in `lost_messages`; each starts a new history, like a restart.
    pub seq_jumps: u64,
    /// `first_sample_index` jumps too big to be losses (more than [`MAX_LOST_SAMPLES`]):
    /// not in `lost_samples`; each starts a new history, like a restart.
    pub index_jumps: u64,
    /// `first_sample_index` went backwards.
    pub index_backwards: u64,
    /// Messages that broke the wire contract (a count beyond the capacity) and were dropped.
    pub malformed: u64,
}

impl StreamCounters {
    pub fn record(&mut self, a: &Arrival) {
        self.lost_messages += a.lost_messages;
        self.lost_samples += a.lost_samples;
        self.out_of_order += u64::from(!a.accepted);
        self.restarts += u64::from(a.restarted && !a.seq_jump && !a.index_jump);
        self.seq_jumps += u64::from(a.seq_jump);
        self.index_jumps += u64::from(a.index_jump);
        self.index_backwards += u64::from(a.index_backwards);
    }

    pub fn to_json(&self) -> crate::JsonObject {
        let mut o = crate::JsonObject::new();
        o.u64("received", self.received)
            .u64("lost_messages", self.lost_messages)
            .u64("lost_samples", self.lost_samples)
            .u64("out_of_order", self.out_of_order)
            .u64("restarts", self.restarts)
            .u64("seq_jumps", self.seq_jumps)
            .u64("index_jumps", self.index_jumps)
            .u64("index_backwards", self.index_backwards)
            .u64("malformed", self.malformed);
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_duplicates_and_restarts_are_told_apart() {
        let mut c = Continuity::new();
        let mut totals = StreamCounters::default();
        let mut feed = |seq, fsi, count| {
            let a = c.check(seq, fsi, count);
            totals.record(&a);
            a
        };
        assert!(
            !feed(5, 100, 10).gap(),
            "the first message sets the baseline"
        );
        assert!(!feed(6, 110, 10).gap());
        let a = feed(9, 140, 10); // seq 7, 8 and their 20 samples lost
        assert_eq!((a.lost_messages, a.lost_samples), (2, 20));
        let dup = feed(9, 140, 10);
        assert!(!dup.accepted);
        assert!(!feed(4, 90, 10).accepted);
        let back = feed(10, 145, 10);
        assert!(back.accepted && back.index_backwards && back.gap());
        let restart = feed(0, 0, 10);
        assert!(restart.accepted && restart.restarted && restart.lost_samples == 0);
        assert!(!feed(1, 10, 10).gap());
        assert_eq!(
            totals,
            StreamCounters {
                received: 0,
                lost_messages: 2,
                lost_samples: 20,
                out_of_order: 2,
                restarts: 1,
                seq_jumps: 0,
                index_jumps: 0,
                index_backwards: 1,
                malformed: 0,
            }
        );
    }

    /// A xorshift64 generator: the random `seq`s of a crafted log, reproducibly.
    fn xorshift(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    #[test]
    fn random_seqs_give_bounded_counts_and_flagged_jumps() {
        let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let n = 1000u64;
        for _ in 0..n {
            let (seq, fsi) = (xorshift(&mut rng), xorshift(&mut rng));
            let a = c.check(seq, fsi, 32);
            totals.record(&a);
            if a.seq_jump || a.index_jump {
                assert!(a.accepted && a.restarted && a.gap(), "{a:?}");
            }
        }
        // Every accepted message but the first is a jump: two random u64 fall within
        // 2^20 (or 2^32) of each other with probability 2^-43 (2^-31).
        assert!(totals.lost_messages <= n * MAX_LOST_MESSAGES, "{totals:?}");
        assert_eq!(
            (totals.lost_messages, totals.lost_samples),
            (0, 0),
            "{totals:?}"
        );
        assert!(totals.seq_jumps > 0, "{totals:?}");
        assert_eq!(totals.restarts + totals.index_jumps, 0, "{totals:?}");
        // Accepted messages: the first, then one per jump (and per return to 0: none).
        assert_eq!(totals.seq_jumps + totals.out_of_order + 1, n, "{totals:?}");
        // The JSON carries the new counter.
        let json = totals.to_json().finish();
        assert!(
            json.contains(&format!("\"seq_jumps\":{}", totals.seq_jumps)),
            "{json}"
        );
    }

    #[test]
    fn a_genuine_gap_still_counts_and_the_limits_are_inclusive() {
        let mut c = Continuity::new();
        c.check(10, 1000, 10);
        // seq 11..=17 lost (7 blocks of 10 samples).
        let a = c.check(18, 1080, 10);
        assert_eq!((a.lost_messages, a.lost_samples), (7, 70));
        assert!(a.gap() && !a.restarted && !a.seq_jump);
        // Exactly MAX_LOST_MESSAGES lost: still a loss.
        let a = c.check(18 + MAX_LOST_MESSAGES + 1, 1090, 10);
        assert_eq!(a.lost_messages, MAX_LOST_MESSAGES);
        assert!(!a.seq_jump && !a.restarted);
        // One more: a jump, and the sample index is not compared across it.
        let last = 18 + MAX_LOST_MESSAGES + 1;
        let a = c.check(last + MAX_LOST_MESSAGES + 2, 5, 10);
        assert!(a.seq_jump && a.restarted && a.gap(), "{a:?}");
        assert_eq!((a.lost_messages, a.lost_samples), (0, 0));
        assert!(!a.index_backwards);
        // The history goes on from the jump: the next block is continuous.
        let a = c.check(last + MAX_LOST_MESSAGES + 3, 15, 10);
        assert!(!a.gap(), "{a:?}");
        // A sample index jump with a continuous seq.
        let a = c.check(last + MAX_LOST_MESSAGES + 4, 25 + MAX_LOST_SAMPLES + 1, 10);
        assert!(a.index_jump && a.restarted && !a.seq_jump && a.lost_samples == 0);
        let a = c.check(
            last + MAX_LOST_MESSAGES + 5,
            35 + MAX_LOST_SAMPLES + 1 + MAX_LOST_SAMPLES,
            10,
        );
        assert_eq!(a.lost_samples, MAX_LOST_SAMPLES);
        assert!(!a.index_jump);
        let mut totals = StreamCounters::default();
        let mut c = Continuity::new();
        for seq in [0u64, u64::MAX - 1] {
            totals.record(&c.check_seq(seq));
        }
        assert_eq!(
            (totals.lost_messages, totals.seq_jumps, totals.restarts),
            (0, 1, 0)
        );
    }
}
