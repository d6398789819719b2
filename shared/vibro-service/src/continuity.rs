//! No silent loss: the continuity of an input stream's `seq` (one per message) and
//! `first_sample_index` (one per sample), so every gap is counted and the outputs it
//! affects can be flagged.

use serde::Serialize;

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
    /// The producer started again (`seq` back to 0): what was lost in between is unknown.
    pub restarted: bool,
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
                arrival.lost_samples = first_sample_index - next;
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
            Some(last) if seq > last => arrival.lost_messages = seq - last - 1,
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
        self.restarts += u64::from(a.restarted);
        self.index_backwards += u64::from(a.index_backwards);
    }

    pub fn to_json(&self) -> crate::JsonObject {
        let mut o = crate::JsonObject::new();
        o.u64("received", self.received)
            .u64("lost_messages", self.lost_messages)
            .u64("lost_samples", self.lost_samples)
            .u64("out_of_order", self.out_of_order)
            .u64("restarts", self.restarts)
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
                index_backwards: 1,
                malformed: 0,
            }
        );
    }
}
