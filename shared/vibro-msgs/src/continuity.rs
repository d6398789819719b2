//! No silent loss, and no silence: the continuity of an input stream's `seq` (one per
//! message) and `first_sample_index` (one per sample), so every gap is counted and the
//! outputs it affects can be flagged, and so that no input sequence stops a service
//! from taking its stream.
//!
//! This is the one home of the rule for every reader of a `seq`: the services (through
//! `vibro_service`, which re-exports it), the recorder (`vibro_log::record`), `log info`
//! (`vibro_mcap::info`, on the recorded sequence numbers) and the bridge's import
//! (`vibro_bridge`). It lives beside the wire types because it is part of their
//! contract (docs/messages.md: `seq` counts a producer's messages) and because the
//! MCAP codec, which depends on nothing else, needs it too.
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
//!
//! **Out of order, and resync.** A message whose `seq` is not above the last accepted
//! one (and not a return to 0) is out of order: rejected, counted, the stream's state
//! unchanged. On its own that rule lets one message silence a stream: a single `seq`
//! ahead of the stream by less than 2^20 is accepted (as a loss), and every real
//! message after it is then out of order until the real `seq` catches up, hours later
//! (issue 31). So the rejected messages are watched too. They form *runs*: a rejected
//! message extends a run when it follows the run's last one as an accepted message
//! would (forward, by at most [`MAX_LOST_MESSAGES`] + 1), and an accepted message that
//! continues the stream (no jump, no restart) ends every run. When a run reaches
//! [`RESYNC_AFTER`] (4) messages, its last one is accepted: the stream is taken up at
//! that run ([`Arrival::resynced`], with `restarted`: the output is flagged as a gap;
//! [`StreamCounters::resyncs`]). So whatever came before, a real stream loses at most
//! `RESYNC_AFTER - 1` (3) messages before it is followed again, and none after: each
//! of its messages is either accepted, after which the next one is too, or extends the
//! run its previous one extended. Why these choices:
//!
//! - Runs run forward by plausible steps: repeats of one `seq` never make a run, and a
//!   flood of random `seq`s extends one with a probability of about 2^-44 per message.
//!   A repeat of the last accepted message shows its stream alive: it starts no run.
//! - Up to 4 runs are followed at once (the one extended least recently is replaced),
//!   so that a few strays between a real stream's messages do not break its run.
//! - Old messages interleaved with a stream that is accepted never resync it: each
//!   accepted message ends the runs. Only 4 old messages in a row, none of the
//!   stream's between them, do: a replay burst. Data streams keep no history
//!   (vibro-ipc), so that takes a misbehaving producer or bridge.
//! - A jump or a restart does not end the runs: a flood of random `seq`s, half of them
//!   accepted as jumps, cannot keep a real stream's run from growing.
//! - 4 is short: 3 blocks (120 ms of accelerometer blocks) dropped at a resync; a late
//!   message (a bridge reordering) stays out of order as before.
//!
//! **Taking back a loss.** A resync can show that a loss counted earlier was none.
//! Each discontinuity (a loss, a jump, a restart, a resync) keeps the baseline it left,
//! with the loss totals there (up to 8; when full, the oldest stays and the next oldest
//! goes), until [`RESYNC_AFTER`] messages in step confirm the stream after it. A resync
//! whose message continues a kept baseline (at most 2^20 + 1 above it; the closest one)
//! goes back to it: the totals are set back to what they were there (the difference
//! in [`Arrival::retracted_messages`] / [`Arrival::retracted_samples`], which
//! [`StreamCounters::record`] subtracts), and the seqs missing between it and this
//! message, less the run's other messages, are counted. So the message 500,000 of
//! issue 31 counts no loss once the stream resyncs (its 499,989 are taken back).
//! Likewise a message not in step with the last one that continues a kept baseline
//! above it (left at a resync backwards or a return to 0) goes back to it: a replay
//! burst of old messages (up to 7 in a row: 8 would confirm the stream they make), or a
//! stray `seq` of 0, costs a resync there and back, not a loss. Both are counted in `resyncs`. `lost_messages` (and the heartbeat's `lost`)
//! can therefore decrease: compare them with saturating differences.
//!
//! What is not taken back: a fake stream of more than [`RESYNC_AFTER`] messages in
//! step is a stream like any other, and what it skipped stays counted; episodes that
//! pile up more than 8 discontinuities before the stream is confirmed may leave a
//! fake step counted (never more than 2^20 + 1 per step: never a jump); a sample index
//! alone that steps forward and back (a corrupt `first_sample_index`, `seq` in step)
//! counts its `lost_samples`, then `index_backwards`. `crate::adversary` (with the
//! `testing` feature) generates such sequences; the property tests check the bound
//! on all of them, and that no more messages are counted lost than real ones never
//! taken where the episodes are isolated (each followed by `2 RESYNC_AFTER` real
//! messages).
/// The most messages a forward `seq` step counts as lost (see the module doc); a
/// bigger step is a jump.
pub const MAX_LOST_MESSAGES: u64 = 1 << 20;

/// The most samples a forward `first_sample_index` step counts as lost (see the module
/// doc); a bigger step is a jump.
pub const MAX_LOST_SAMPLES: u64 = 1 << 32;

/// Rejected messages of one run (their `seq`s running forward among themselves, no
/// message accepted in between that continues the stream) after which the stream is
/// taken up at that run: the last of them is accepted ([`Arrival::resynced`]). Also the
/// messages in step that confirm a stream after a discontinuity. See the module doc.
pub const RESYNC_AFTER: u32 = 4;

/// Runs of rejected messages followed at once.
const RUNS: usize = 4;
/// Baselines kept after discontinuities while the stream is not confirmed.
const HISTORY: usize = 8;

/// What the arrival of one message tells about the stream.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Arrival {
    /// False for a duplicate or an older message (`seq` not above the last one and not a
    /// restart): the caller drops or flags it; the stream's state is unchanged.
    pub accepted: bool,
    /// Messages missing between the previous one and this one (`seq` jump). After a
    /// [`Self::resynced`] arrival: those missing since the baseline it went back to,
    /// plus any counted there and taken back since.
    pub lost_messages: u64,
    /// Samples missing before this message (`first_sample_index` jump); likewise.
    pub lost_samples: u64,
    /// The stream's history no longer applies: the producer started again (`seq` back
    /// to 0), or `seq` or `first_sample_index` jumped ([`Self::seq_jump`],
    /// [`Self::index_jump`]), or the stream was taken up again ([`Self::resynced`]).
    /// What was lost in between is unknown: start afresh.
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
    /// The stream was taken up again at this message: it ends a run of
    /// [`RESYNC_AFTER`] rejected messages, or it continues a baseline left at an
    /// earlier resync or restart (module doc). `restarted` is set too.
    pub resynced: bool,
    /// Messages counted lost at earlier arrivals that this one shows were not (module
    /// doc, "Retraction"): to be taken off the totals.
    pub retracted_messages: u64,
    /// Samples counted lost at earlier arrivals that this one shows were not.
    pub retracted_samples: u64,
}

impl Arrival {
    /// Data is missing right before this message, or its history is unknown.
    pub fn gap(&self) -> bool {
        self.lost_messages > 0 || self.lost_samples > 0 || self.restarted || self.index_backwards
    }
}

/// A place in the stream: the last accepted message, and this continuity's loss totals
/// when it was there (what a return takes back).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Baseline {
    last_seq: u64,
    next_sample_index: Option<u64>,
    lost_messages: u64,
    lost_samples: u64,
}

/// A run of rejected messages whose `seq`s run forward; `len` 0: an empty slot.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Run {
    last_seq: u64,
    len: u32,
    /// When it was last extended (a count of rejected messages): the least recent goes
    /// first.
    touched: u64,
}

/// The continuity state of one input stream. Fixed size: nothing allocates.
#[derive(Debug, Clone, Default)]
pub struct Continuity {
    last_seq: Option<u64>,
    next_sample_index: Option<u64>,
    /// What this continuity counted lost so far, net of what it took back.
    lost_messages: u64,
    lost_samples: u64,
    /// Baselines left at discontinuities since the stream was last confirmed, oldest
    /// (the confirmed one) first, packed at the front.
    history: [Option<Baseline>; HISTORY],
    /// Accepted messages in step (`seq` + 1, not restarted) since the last
    /// discontinuity.
    in_step: u32,
    runs: [Run; RUNS],
    rejected: u64,
}

impl Continuity {
    pub fn new() -> Self {
        Self::default()
    }

    /// The `seq` of the last accepted message.
    pub fn last_seq(&self) -> Option<u64> {
        self.last_seq
    }

    /// Checks a message that carries `count` samples from `first_sample_index` on.
    pub fn check(&mut self, seq: u64, first_sample_index: u64, count: u64) -> Arrival {
        self.arrive(seq, Some((first_sample_index, count)))
    }

    /// Checks a message that carries no sample index (an estimate).
    pub fn check_seq(&mut self, seq: u64) -> Arrival {
        self.arrive(seq, None)
    }

    fn arrive(&mut self, seq: u64, samples: Option<(u64, u64)>) -> Arrival {
        let mut a = Arrival {
            accepted: true,
            ..Arrival::default()
        };
        let mut left = self.baseline();
        let Some(last) = self.last_seq else {
            self.take(seq, samples, None, &mut a, None);
            return a;
        };
        // The sample index this message is expected to continue (none: not compared).
        let expected;
        // A message in step with the last one continues this stream, whatever was kept
        // (a restarted count passes through the seqs of older baselines).
        let in_step = last.checked_add(1) == Some(seq);
        if let Some(b) = (!in_step)
            .then(|| self.kept(seq, Some(last)))
            .flatten()
            .and_then(|h| self.resume(h, &mut a))
        {
            // A baseline above the last one, left at a resync backwards or a return to
            // 0, goes on: back to it, and on from there (a repeat of its last message
            // too is taken: it shows that stream alive, and the real stream may pass
            // through a fake's seq).
            a.lost_messages = a
                .lost_messages
                .saturating_add((seq - b.last_seq).saturating_sub(1));
            expected = b.next_sample_index;
            left = Some(b);
        } else if seq > last {
            let lost = seq - last - 1;
            if lost > MAX_LOST_MESSAGES {
                // Not a loss: a corrupt or renumbered counter (module doc).
                a.seq_jump = true;
                a.restarted = true;
                expected = None;
            } else {
                a.lost_messages = lost;
                expected = self.next_sample_index;
            }
        } else if seq == 0 && last > 0 {
            // A producer that restarts counts from 0 again.
            a.restarted = true;
            expected = None;
        } else {
            return self.reject(seq, samples);
        }
        self.take(seq, samples, expected, &mut a, left);
        a
    }

    /// A message whose `seq` is not above the last: rejected, unless it completes a run
    /// of [`RESYNC_AFTER`] (module doc).
    fn reject(&mut self, seq: u64, samples: Option<(u64, u64)>) -> Arrival {
        // A repeat of the last message shows the stream alive: it starts no run (it may
        // end one that the stream's own messages began, a fake having taken their seq).
        let repeat = self.last_seq == Some(seq);
        self.rejected += 1;
        let stamp = self.rejected;
        let extends =
            |r: &Run| r.len > 0 && seq > r.last_seq && seq - r.last_seq - 1 <= MAX_LOST_MESSAGES;
        let slot = match (0..RUNS)
            .filter(|&i| extends(&self.runs[i]))
            .max_by_key(|&i| self.runs[i].touched)
        {
            Some(i) => {
                let r = &mut self.runs[i];
                r.last_seq = seq;
                r.len += 1;
                r.touched = stamp;
                i
            }
            None if repeat => return Arrival::default(),
            None => {
                // A new run, in an empty slot or in place of the least recent one.
                let i = (0..RUNS)
                    .min_by_key(|&i| (self.runs[i].len > 0, self.runs[i].touched))
                    .unwrap_or(0);
                self.runs[i] = Run {
                    last_seq: seq,
                    len: 1,
                    touched: stamp,
                };
                i
            }
        };
        let run = self.runs[slot];
        if run.len < RESYNC_AFTER {
            return Arrival::default();
        }
        // Resync: the stream goes on at this run.
        self.runs = [Run::default(); RUNS];
        let mut a = Arrival {
            accepted: true,
            restarted: true,
            resynced: true,
            ..Arrival::default()
        };
        if repeat {
            // Where the stream already is.
            self.take(seq, samples, None, &mut a, None);
            return a;
        }
        match self.kept(seq, None).and_then(|h| self.resume(h, &mut a)) {
            Some(b) => {
                // The run continues a baseline left earlier: on from there. Missing are
                // the seqs between that baseline and this message but the run's others
                // (taken to lie in between: a run that began with a repeat of the
                // baseline counts no loss for it).
                a.lost_messages = a.lost_messages.saturating_add(
                    (seq - b.last_seq)
                        .saturating_sub(1)
                        .saturating_sub(u64::from(run.len - 1)),
                );
                self.take(seq, samples, None, &mut a, Some(b));
            }
            None => {
                if let Some(left) = self.baseline() {
                    self.push(left);
                }
                self.take(seq, samples, None, &mut a, None);
            }
        }
        a
    }

    /// The kept baseline a message at `seq` continues, if any: at or below `seq` by at
    /// most [`MAX_LOST_MESSAGES`] + 1 and above `above` (if given), the closest one.
    fn kept(&self, seq: u64, above: Option<u64>) -> Option<usize> {
        (0..HISTORY)
            .filter(|&i| {
                self.history[i].is_some_and(|b| {
                    b.last_seq <= seq
                        && seq - b.last_seq <= MAX_LOST_MESSAGES + 1
                        && above.is_none_or(|a| b.last_seq > a)
                })
            })
            .max_by_key(|&i| self.history[i].map_or(0, |b| b.last_seq))
    }

    /// Goes back to kept baseline `h`: marks `a` resynced and restarted, with the totals
    /// set back to what they were there (the losses counted since taken back, or those
    /// taken back since counted again); that baseline and those kept after it are
    /// dropped (the caller keeps it again if the message steps on from it with a gap).
    fn resume(&mut self, h: usize, a: &mut Arrival) -> Option<Baseline> {
        let b = self.history[h]?;
        a.resynced = true;
        a.restarted = true;
        a.retracted_messages = self.lost_messages.saturating_sub(b.lost_messages);
        a.lost_messages = b.lost_messages.saturating_sub(self.lost_messages);
        a.retracted_samples = self.lost_samples.saturating_sub(b.lost_samples);
        a.lost_samples = b.lost_samples.saturating_sub(self.lost_samples);
        for slot in &mut self.history[h..] {
            *slot = None;
        }
        Some(b)
    }

    fn baseline(&self) -> Option<Baseline> {
        self.last_seq.map(|last_seq| Baseline {
            last_seq,
            next_sample_index: self.next_sample_index,
            lost_messages: self.lost_messages,
            lost_samples: self.lost_samples,
        })
    }

    /// Keeps a baseline left at a discontinuity; when full, the oldest (the confirmed
    /// one) stays and the next oldest goes.
    fn push(&mut self, b: Baseline) {
        if let Some(slot) = self.history.iter_mut().find(|h| h.is_none()) {
            *slot = Some(b);
            return;
        }
        self.history.copy_within(2.., 1);
        self.history[HISTORY - 1] = Some(b);
    }

    /// Makes the message at `seq` the stream's last one: its samples are compared with
    /// `expected`, the totals kept, and `left` (the baseline before it) kept if the
    /// message is a discontinuity.
    fn take(
        &mut self,
        seq: u64,
        samples: Option<(u64, u64)>,
        expected: Option<u64>,
        a: &mut Arrival,
        left: Option<Baseline>,
    ) {
        if let Some((first_sample_index, count)) = samples {
            if let Some(next) = expected {
                if first_sample_index > next {
                    let step = first_sample_index - next;
                    if step > MAX_LOST_SAMPLES {
                        a.index_jump = true;
                        a.restarted = true;
                    } else {
                        a.lost_samples = a.lost_samples.saturating_add(step);
                    }
                } else if first_sample_index < next {
                    a.index_backwards = true;
                }
            }
            self.next_sample_index = Some(first_sample_index.saturating_add(count));
        }
        self.last_seq = Some(seq);
        self.lost_messages = net_loss(self.lost_messages, a.retracted_messages, a.lost_messages);
        self.lost_samples = net_loss(self.lost_samples, a.retracted_samples, a.lost_samples);
        if a.restarted || a.lost_messages > 0 {
            // A discontinuity: the baseline it left is kept (a plain resync keeps it
            // itself; a return keeps the baseline it returned to if it steps on with a
            // gap).
            if a.lost_messages > 0 || !a.resynced {
                if let Some(left) = left {
                    self.push(left);
                }
            }
            self.in_step = 0;
        } else {
            self.in_step = self.in_step.saturating_add(1);
            if self.in_step >= RESYNC_AFTER {
                // Confirmed: no return to what came before.
                self.history = [None; HISTORY];
            }
        }
        if !a.restarted {
            // The stream goes on: the rejected messages so far were strays.
            self.runs = [Run::default(); RUNS];
        }
    }
}

/// A running loss total after an arrival: what a resync showed was no loss taken back,
/// the new loss added (saturating both ways).
fn net_loss(total: u64, retracted: u64, lost: u64) -> u64 {
    total.saturating_sub(retracted).saturating_add(lost)
}

/// Totals of one input stream, for the heartbeat and the summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamCounters {
    /// Messages taken from the stream, good or bad.
    pub received: u64,
    /// Messages missing by `seq`, net of those a resync showed were not (module doc,
    /// "Retraction"): it can decrease.
    pub lost_messages: u64,
    /// Samples missing by `first_sample_index`, net likewise.
    pub lost_samples: u64,
    /// Duplicate or older messages, dropped.
    pub out_of_order: u64,
    /// Producer restarts (`seq` back to 0).
    pub restarts: u64,
    /// The stream taken up again after a run of out-of-order messages, or back at a
    /// baseline left earlier ([`Arrival::resynced`], [`RESYNC_AFTER`]).
    pub resyncs: u64,
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
        self.lost_messages = net_loss(self.lost_messages, a.retracted_messages, a.lost_messages);
        self.lost_samples = net_loss(self.lost_samples, a.retracted_samples, a.lost_samples);
        self.out_of_order += u64::from(!a.accepted);
        self.restarts += u64::from(a.restarted && !a.seq_jump && !a.index_jump && !a.resynced);
        self.resyncs += u64::from(a.resynced);
        self.seq_jumps += u64::from(a.seq_jump);
        self.index_jumps += u64::from(a.index_jump);
        self.index_backwards += u64::from(a.index_backwards);
    }

    /// Out-of-order messages and resyncs together: a heartbeat is `degraded` in a period
    /// where they grew.
    pub fn disorder(&self) -> u64 {
        self.out_of_order.saturating_add(self.resyncs)
    }

    /// The counters by name, in the order the services' JSON summaries print them
    /// (`vibro_service`'s `CountersJson`).
    pub fn fields(&self) -> [(&'static str, u64); 10] {
        [
            ("received", self.received),
            ("lost_messages", self.lost_messages),
            ("lost_samples", self.lost_samples),
            ("out_of_order", self.out_of_order),
            ("restarts", self.restarts),
            ("resyncs", self.resyncs),
            ("seq_jumps", self.seq_jumps),
            ("index_jumps", self.index_jumps),
            ("index_backwards", self.index_backwards),
            ("malformed", self.malformed),
        ]
    }
}

/// A stream's [`Continuity`] with its totals, for a reader that counts but keeps every
/// message whatever the rule says of it: the recorder (which records them all), `log
/// info` (which reads a file) and the bridge (which forwards them). Out-of-order
/// messages are still counted as such.
#[derive(Debug, Clone, Default)]
pub struct SeqTally {
    continuity: Continuity,
    /// The totals ([`StreamCounters::record`]): `lost_messages` net of what was taken back.
    pub totals: StreamCounters,
    /// Arrivals that counted a loss ([`Arrival::lost_messages`] > 0) when they came, some
    /// perhaps taken back since.
    pub gaps: u64,
    /// Messages counted lost and later taken back ([`Arrival::retracted_messages`],
    /// summed): what a forged `seq` ahead of the stream would have counted.
    pub retracted: u64,
}

impl SeqTally {
    pub fn new() -> Self {
        Self::default()
    }

    /// Counts the arrival of a message numbered `seq`.
    pub fn seq(&mut self, seq: u64) -> Arrival {
        let a = self.continuity.check_seq(seq);
        self.totals.received = self.totals.received.saturating_add(1);
        self.totals.record(&a);
        self.gaps += u64::from(a.lost_messages > 0);
        self.retracted = self.retracted.saturating_add(a.retracted_messages);
        a
    }

    /// The `seq` of the last accepted message.
    pub fn last_seq(&self) -> Option<u64> {
        self.continuity.last_seq()
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
                resyncs: 0,
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
        // The summaries carry the new counter.
        assert!(totals.fields().contains(&("seq_jumps", totals.seq_jumps)));
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

    /// Feeds `seqs` (sample index 32 per seq, 32 samples each): the arrivals and totals.
    fn feed(
        c: &mut Continuity,
        totals: &mut StreamCounters,
        seqs: impl IntoIterator<Item = u64>,
    ) -> Vec<Arrival> {
        seqs.into_iter()
            .map(|seq| {
                let a = c.check(seq, seq.wrapping_mul(32), 32);
                totals.record(&a);
                a
            })
            .collect()
    }

    /// Issue 31: one message ahead of the stream by less than 2^20 (500,000) silenced
    /// it for hours (every later message out of order) and counted 499,989 messages
    /// lost. Now the stream resyncs at its fourth message, and the loss is taken back.
    #[test]
    fn one_message_ahead_neither_silences_the_stream_nor_counts_a_loss() {
        let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
        feed(&mut c, &mut totals, 0..=10);
        let ahead = feed(&mut c, &mut totals, [500_000])[0];
        assert!(
            ahead.accepted && ahead.lost_messages == 499_989,
            "{ahead:?}"
        );
        let after = feed(&mut c, &mut totals, 11..=20);
        let taken: Vec<u64> = (11..=20)
            .zip(&after)
            .filter(|(_, a)| a.accepted)
            .map(|(s, _)| s)
            .collect();
        assert_eq!(taken, (14..=20).collect::<Vec<_>>());
        let resync = after[3];
        assert!(
            resync.resynced && resync.restarted && resync.gap(),
            "{resync:?}"
        );
        assert_eq!(
            (
                resync.retracted_messages,
                resync.retracted_samples,
                resync.lost_messages
            ),
            (499_989, 499_989 * 32, 0)
        );
        assert!(after[4..].iter().all(|a| !a.gap()), "{after:?}");
        assert_eq!(
            (
                totals.lost_messages,
                totals.lost_samples,
                totals.out_of_order,
                totals.resyncs
            ),
            (0, 0, 3, 1)
        );
        assert_eq!(totals.restarts + totals.seq_jumps, 0);
        assert!(totals.fields().contains(&("resyncs", 1)));
    }

    /// The same through [`SeqTally`], which a recorder or a reader of a file uses: the
    /// forged message's 499,989 counted, then taken back; three messages out of order.
    #[test]
    fn a_tally_takes_back_the_loss_of_a_message_ahead() {
        let mut t = SeqTally::new();
        for seq in (0..=10).chain([500_000]).chain(11..=60) {
            t.seq(seq);
        }
        assert_eq!(
            (
                t.totals.received,
                t.totals.lost_messages,
                t.totals.out_of_order,
                t.totals.resyncs,
                t.totals.seq_jumps,
                t.gaps,
                t.retracted
            ),
            (62, 0, 3, 1, 0, 1, 499_989)
        );
        assert_eq!(t.last_seq(), Some(60));
    }

    /// The same with the message ahead by more than 2^20 (a jump), by u64::MAX, and
    /// with real messages lost around it: the losses counted are those of the stream.
    #[test]
    fn a_stream_resumes_after_any_message_ahead_and_its_own_losses_count() {
        for ahead in [MAX_LOST_MESSAGES + 100, u64::MAX - 1, u64::MAX, 12] {
            let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
            feed(&mut c, &mut totals, 0..=10);
            feed(&mut c, &mut totals, [ahead]);
            // 11 lost; 12..=15 dropped as out of order (a run with 14 missing), 16 taken.
            let after = feed(&mut c, &mut totals, [12, 13, 15, 16, 17]);
            let taken: Vec<bool> = after.iter().map(|a| a.accepted).collect();
            if ahead == 12 {
                // Not ahead of the stream: 12 was the stream's, 13 goes on.
                assert_eq!(taken, [false, true, true, true, true], "{after:?}");
                assert_eq!((totals.lost_messages, totals.resyncs), (1 + 1, 0));
                continue;
            }
            assert_eq!(
                taken,
                [false, false, false, true, true],
                "{ahead}: {after:?}"
            );
            assert!(after[3].resynced);
            assert_eq!(after[3].lost_messages, 2, "11 and 14");
            assert_eq!(
                (totals.lost_messages, totals.resyncs, totals.out_of_order),
                (2, 1, 3),
                "{ahead}"
            );
        }
    }

    /// Old messages between the stream's own never resync it, even runs of three.
    #[test]
    fn interleaved_old_messages_never_resync() {
        let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
        let mut old = 5u64;
        for seq in 100..200u64 {
            let a = feed(&mut c, &mut totals, [seq])[0];
            assert!(a.accepted && !a.gap() || seq == 100, "{seq}: {a:?}");
            let n = seq % 4;
            let olds = feed(&mut c, &mut totals, old..old + n);
            assert!(olds.iter().all(|a| !a.accepted));
            old += n;
        }
        assert_eq!((totals.resyncs, totals.lost_messages), (0, 0), "{totals:?}");
    }

    /// A burst of old messages replayed in order resyncs to them; the stream then goes
    /// on where it was: a resync there and back, no loss.
    #[test]
    fn a_replay_burst_resyncs_there_and_back_without_a_loss() {
        let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
        feed(&mut c, &mut totals, 100..=110);
        // Up to 2 RESYNC_AFTER - 1 (7): 3 dropped, 4 taken, not yet a confirmed stream.
        let burst = feed(&mut c, &mut totals, 50..=56);
        assert_eq!(burst.iter().filter(|a| a.accepted).count(), 4);
        let back = feed(&mut c, &mut totals, [111])[0];
        assert!(
            back.accepted && back.resynced && back.lost_messages == 0,
            "{back:?}"
        );
        assert!(!back.index_backwards && back.lost_samples == 0, "{back:?}");
        assert!(feed(&mut c, &mut totals, 112..=120)
            .iter()
            .all(|a| a.accepted && !a.gap()));
        assert_eq!(
            (
                totals.lost_messages,
                totals.lost_samples,
                totals.resyncs,
                totals.out_of_order
            ),
            (0, 0, 2, 3)
        );
    }

    /// A message that comes late (a bridge reordering) is out of order and its seq
    /// counted lost, as before the resync rule; a producer's return to 0 is a restart.
    #[test]
    fn a_late_message_and_a_restart_are_as_before() {
        let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
        let a = feed(&mut c, &mut totals, [0, 1, 2, 3, 6, 4, 7, 8, 9]);
        assert!(!a[5].accepted && a.iter().filter(|a| a.accepted).count() == 8);
        assert_eq!(
            (totals.lost_messages, totals.out_of_order, totals.resyncs),
            (2, 1, 0)
        );
        let r = feed(&mut c, &mut totals, 0..=20);
        assert!(r[0].restarted && !r[0].resynced && r[1..].iter().all(|a| !a.gap()));
        assert_eq!(
            (totals.restarts, totals.resyncs, totals.lost_messages),
            (1, 0, 2)
        );
    }

    /// A stray return to 0 (a corrupt seq of 0): the stream goes on as a return, no
    /// loss counted for the step back up.
    #[test]
    fn a_stray_zero_is_a_return_not_a_loss() {
        let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
        feed(&mut c, &mut totals, 1000..=1010);
        let a = feed(&mut c, &mut totals, [0, 1011, 1012]);
        assert!(
            a[0].restarted && a[1].resynced && a[1].lost_messages == 0,
            "{a:?}"
        );
        assert!(!a[2].gap());
        assert_eq!(
            (
                totals.lost_messages,
                totals.lost_samples,
                totals.restarts,
                totals.resyncs
            ),
            (0, 0, 1, 1)
        );
    }

    /// The property: random adversarial prefixes (`crate::adversary`), then the real
    /// stream alone: at most `RESYNC_AFTER - 1` (3) of its messages dropped, none after
    /// the first taken, and, where no fake stream could pass for a real one, no more
    /// messages counted lost than real ones never taken (no jump or fake step counted).
    #[test]
    fn no_sequence_silences_the_stream_or_counts_a_jump_as_a_loss() {
        use crate::adversary::{check, generate, Xorshift};
        let mut rng = Xorshift::new(31);
        for trial in 0..4000 {
            let isolated = trial % 4 != 0;
            let ops = (rng.next_u64() % 80) as usize;
            let s = generate(|| Some(rng.next_u64()), ops, 32, isolated);
            let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
            let taken: Vec<bool> = s
                .messages
                .iter()
                .map(|m| {
                    let a = c.check(m.seq, m.first_sample_index, 32);
                    totals.record(&a);
                    // A jump counts nothing, whatever the sequence.
                    assert!(!a.seq_jump || a.lost_messages == 0, "{a:?}");
                    a.accepted
                })
                .collect();
            if let Err(e) = check(&s, &taken, totals.lost_messages) {
                let mut c = Continuity::new();
                for m in &s.messages[..s.tail + 8] {
                    let a = c.check(m.seq, m.first_sample_index, 32);
                    eprintln!(
                        "{} {} acc {} lost {} resync {} retr {} restart {} | hist {:?}",
                        m.seq,
                        if m.real { "real" } else { "FAKE" },
                        a.accepted,
                        a.lost_messages,
                        a.resynced,
                        a.retracted_messages,
                        a.restarted,
                        c.history
                            .iter()
                            .flatten()
                            .map(|b| b.last_seq)
                            .collect::<Vec<_>>()
                    );
                }
                panic!("trial {trial}: {e}\n{totals:?}");
            }
        }
    }
}
