//! Losses of a recording, each counted once, by the services' rule
//! (`vibro_msgs::continuity`), for `log info` ([`crate::info`]) and the recorder
//! (`vibro_log::record`):
//!
//! - per channel, the messages missing by its sequence numbers ([`unwrap_sequence`]
//!   turns MCAP's 32 bits into the rule's `seq`): a step of more than 2^20 is a jump,
//!   and a loss counted at a message ahead of the stream is taken back when the stream
//!   resumes (so a forged `seq` of 500,000 after block 10 counts no loss);
//! - per compensated channel, the accelerometer blocks *in the recording* that got no
//!   compensated output ([`Answers`]: the `seq` of each `/accel` block against the
//!   `input_seq` of each `/compensated` one), listed as ranges of `seq`.
//!
//! A block the recorder missed counts on `/accel` only (it is not in the file to be
//! answered); a block recorded but never answered counts on `/compensated` only; an
//! output the recorder missed counts on `/compensated`'s sequence, and excuses one
//! unanswered block (it had an output: the log lost it). So a total over the channels
//! adds each loss once.

use prost::Message as _;
use std::collections::{HashMap, VecDeque};
use vibro_msgs::{MessageKind, SeqTally};

/// How many ranges of unanswered blocks are listed (all are counted).
pub const MAX_LISTED_UNANSWERED: usize = 16;

/// The most blocks waiting for their output (and outputs for their block) at once:
/// an output recorded more than this many blocks after its block is not matched with
/// it. 4096 blocks are 164 s of 40 ms accelerometer blocks, far beyond the
/// compensator's latency (one block) and its subscriber's buffer (a few blocks).
pub const MAX_PENDING_ANSWERS: usize = 4096;

/// The `seq` (64 bits) that the 32-bit MCAP sequence number `sequence` stands for,
/// given the last one accepted on its channel (`last`): the one with these low 32
/// bits closest to `last` (so counting goes on across the wrap at 2^32, a step of up to
/// 2^31 either way), except that 0 out of step is 0 (a producer that restarted: the
/// rule's restart).
pub fn unwrap_sequence(last: Option<u64>, sequence: u32) -> u64 {
    let Some(last) = last else {
        return u64::from(sequence);
    };
    // Truncation intended: the low 32 bits of the last one.
    let step = sequence.wrapping_sub(last as u32);
    if sequence == 0 && step != 1 {
        return 0;
    }
    // A step of at most 2^31 - 1 forwards, or of up to 2^31 backwards.
    let signed = i128::from(step as i32);
    let seq = i128::from(last) + signed;
    u64::try_from(seq).unwrap_or(if seq < 0 {
        u64::from(sequence)
    } else {
        u64::MAX
    })
}

/// Consecutive `seq`s `first..=last`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SeqRange {
    pub first: u64,
    pub last: u64,
}

/// `seq`s counted and listed as ranges of consecutive ones, in the order found: all are
/// counted, the first [`MAX_LISTED_UNANSWERED`] ranges listed.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct SeqRanges {
    /// `seq`s in all the ranges.
    pub count: u64,
    /// Ranges of consecutive `seq`s.
    pub ranges: u64,
    /// The first [`MAX_LISTED_UNANSWERED`] of them.
    pub listed: Vec<SeqRange>,
    /// The last `seq` added, and whether its range is listed (the next one may extend it).
    #[serde(skip)]
    open: Option<(u64, bool)>,
}

impl SeqRanges {
    /// Adds `first..=last` after what was added so far.
    pub fn add_range(&mut self, first: u64, last: u64) {
        let n = last.saturating_sub(first).saturating_add(1);
        self.count = self.count.saturating_add(n);
        let listed = match self.open {
            Some((end, listed)) if end.checked_add(1) == Some(first) => {
                if listed {
                    if let Some(r) = self.listed.last_mut() {
                        r.last = last;
                    }
                }
                listed
            }
            _ => {
                self.ranges = self.ranges.saturating_add(1);
                let room = self.listed.len() < MAX_LISTED_UNANSWERED;
                if room {
                    self.listed.push(SeqRange { first, last });
                }
                room
            }
        };
        self.open = Some((last, listed));
    }

    pub fn add(&mut self, seq: u64) {
        self.add_range(seq, seq);
    }

    /// Adds what `other` holds after what was added so far (its ranges beyond the
    /// listed ones are counted, not listed).
    fn append(&mut self, other: SeqRanges) {
        let listed_count: u64 = other
            .listed
            .iter()
            .map(|r| r.last.saturating_sub(r.first).saturating_add(1))
            .sum();
        let unlisted_ranges = other.ranges.saturating_sub(other.listed.len() as u64);
        for r in &other.listed {
            self.add_range(r.first, r.last);
        }
        if unlisted_ranges > 0 {
            self.count = self
                .count
                .saturating_add(other.count.saturating_sub(listed_count));
            self.ranges = self.ranges.saturating_add(unlisted_ranges);
            self.open = other.open.map(|(end, _)| (end, false));
        }
    }
}

/// `seq 11..=13, 20, 22..=23`, then `and N more in M more ranges` for those not
/// listed.
impl std::fmt::Display for SeqRanges {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("seq ")?;
        let mut shown = 0u64;
        for (i, r) in self.listed.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            if r.first == r.last {
                write!(f, "{}", r.first)?;
            } else {
                write!(f, "{}..={}", r.first, r.last)?;
            }
            shown = shown.saturating_add(r.last.saturating_sub(r.first).saturating_add(1));
        }
        let more_ranges = self.ranges.saturating_sub(self.listed.len() as u64);
        if more_ranges > 0 {
            write!(
                f,
                " and {} more in {more_ranges} more ranges",
                self.count.saturating_sub(shown)
            )?;
        }
        Ok(())
    }
}

/// An output waiting for its block (recorded first, or its block missed by the
/// recorder).
#[derive(Clone, Copy, Debug)]
struct PendingOutput {
    input_seq: u64,
    /// Outputs the log lost right before this one (its channel's sequence).
    lost_before: u64,
}

/// The accelerometer blocks of a recording without a compensated output: each block's
/// `seq` ([`Self::input`]) against each output's `input_seq` ([`Self::output`]), in
/// the order they were recorded.
///
/// The compensator answers blocks in their order, so an output answers its block and
/// shows that every block still waiting before it got none. Each is matched by `seq`
/// with the oldest waiting one (a `seq` may come twice: a restarted producer, a
/// replayed block). An output recorded before its block waits for it (the recorder
/// drains its streams in turn). Not counted: blocks before the first one answered (the
/// compensator not yet running) and after the last (it stopped, or the recording did),
/// and outputs whose block is not in the recording (the recorder missed it: a loss of
/// `/accel`). Memory is bounded ([`MAX_PENDING_ANSWERS`], [`MAX_LISTED_UNANSWERED`]):
/// a block waits for its output among the last [`MAX_PENDING_ANSWERS`] blocks.
#[derive(Clone, Debug, Default)]
pub struct Answers {
    /// Blocks waiting for their output, by `seq`, in the order recorded.
    inputs: VecDeque<u64>,
    /// How many of `inputs` have each `seq`.
    input_counts: HashMap<u64, u32>,
    outputs: VecDeque<PendingOutput>,
    output_counts: HashMap<u64, u32>,
    /// A block was answered: the compensator was running (blocks before the first one
    /// answered are not counted).
    answered_any: bool,
    /// Blocks pushed out of `inputs` unanswered, counted once an output comes after them.
    tentative: SeqRanges,
    unanswered: SeqRanges,
}

fn take(counts: &mut HashMap<u64, u32>, seq: u64) {
    if let Some(n) = counts.get_mut(&seq) {
        *n = n.saturating_sub(1);
        if *n == 0 {
            counts.remove(&seq);
        }
    }
}

fn put(counts: &mut HashMap<u64, u32>, seq: u64) {
    let n = counts.entry(seq).or_insert(0);
    *n = n.saturating_add(1);
}

impl Answers {
    pub fn new() -> Self {
        Self::default()
    }

    /// The accelerometer blocks found without an output so far.
    pub fn unanswered(&self) -> &SeqRanges {
        &self.unanswered
    }

    /// An accelerometer block numbered `seq` was recorded.
    pub fn input(&mut self, seq: u64) {
        if self.output_counts.contains_key(&seq) {
            // Its output came first: answered. The outputs waiting before it answer
            // blocks the recording does not have.
            let mut lost_before = 0;
            while let Some(o) = self.outputs.pop_front() {
                take(&mut self.output_counts, o.input_seq);
                if o.input_seq == seq {
                    lost_before = o.lost_before;
                    break;
                }
            }
            // Every block still waiting came before this one, whose output came: none
            // of them got one (the outputs keep the blocks' order).
            let waiting = std::mem::take(&mut self.inputs);
            self.input_counts.clear();
            self.unanswered_before(waiting, lost_before);
            return;
        }
        self.inputs.push_back(seq);
        put(&mut self.input_counts, seq);
        if self.inputs.len() > MAX_PENDING_ANSWERS {
            if let Some(p) = self.inputs.pop_front() {
                take(&mut self.input_counts, p);
                if self.answered_any {
                    self.tentative.add(p);
                }
            }
        }
    }

    /// A compensated block answering the block numbered `input_seq` was recorded;
    /// `lost_before`: the outputs its channel's sequence shows missing right before it
    /// (each excuses one unanswered block: it was answered, the log lost the answer).
    pub fn output(&mut self, input_seq: u64, lost_before: u64) {
        // Blocks pushed out unanswered long ago: an output came after them.
        let tentative = std::mem::take(&mut self.tentative);
        self.unanswered.append(tentative);
        if !self.input_counts.contains_key(&input_seq) {
            self.outputs.push_back(PendingOutput {
                input_seq,
                lost_before,
            });
            put(&mut self.output_counts, input_seq);
            if self.outputs.len() > MAX_PENDING_ANSWERS {
                if let Some(o) = self.outputs.pop_front() {
                    take(&mut self.output_counts, o.input_seq);
                }
            }
            return;
        }
        let mut before = VecDeque::new();
        while let Some(p) = self.inputs.pop_front() {
            take(&mut self.input_counts, p);
            if p == input_seq {
                break;
            }
            before.push_back(p);
        }
        // The outputs waiting for their block came before this one: their blocks are
        // not in the recording.
        self.outputs.clear();
        self.output_counts.clear();
        self.unanswered_before(before, lost_before);
    }

    /// A block was answered: counts the blocks `waiting` before it as unanswered, but
    /// `excused` of them (answers the log lost), and none before the first block
    /// answered.
    fn unanswered_before(&mut self, waiting: VecDeque<u64>, mut excused: u64) {
        if !std::mem::replace(&mut self.answered_any, true) {
            return;
        }
        for p in waiting {
            if excused > 0 {
                excused -= 1;
                continue;
            }
            self.unanswered.add(p);
        }
    }
}

/// The one field of a `vibrocomp.v1.CompensatedBlock` that the loss count reads:
/// decoding the whole message would allocate its seven sample arrays for nothing
/// (prost skips the other fields by their length). The tag is the one of
/// [`crate::proto::CompensatedBlock`] (checked by a test).
#[derive(Clone, PartialEq, prost::Message)]
struct InputSeqOnly {
    #[prost(uint64, tag = "2")]
    input_seq: u64,
}

/// The `seq` of a `vibrocomp.v1.AccelBlock` (tag checked by a test), likewise.
#[derive(Clone, PartialEq, prost::Message)]
struct SeqOnly {
    #[prost(uint64, tag = "1")]
    seq: u64,
}

/// What one channel's losses need.
#[derive(Debug, Default)]
struct Channel {
    topic: String,
    tally: SeqTally,
    /// An accelerometer channel (protobuf): its blocks' `seq`s go to the compensated
    /// channels paired with it.
    accel: bool,
    /// A compensated channel (protobuf): the accelerometer channel paired with it (by
    /// topic: `P/compensated` with `P/accel`), and the matching.
    answers: Option<(Option<u16>, Answers)>,
    /// Messages whose `seq` or `input_seq` could not be decoded.
    undecodable: u64,
}

/// The losses of every channel of a file, as [`crate::info`] reads it: sequence numbers
/// by the rule, and the accelerometer blocks without output ([`Answers`]).
#[derive(Debug, Default)]
pub(crate) struct ChannelLosses {
    channels: HashMap<u16, Channel>,
}

/// The accelerometer topic whose blocks a compensated topic answers: the same prefix.
fn accel_topic_of(compensated: &str) -> Option<String> {
    compensated
        .strip_suffix("compensated")
        .map(|prefix| format!("{prefix}accel"))
}

impl ChannelLosses {
    /// A channel record (again, for one already known: nothing changes). `protobuf`:
    /// its messages are protobuf-encoded (their fields can be read).
    pub(crate) fn channel(
        &mut self,
        id: u16,
        topic: &str,
        kind: Option<MessageKind>,
        protobuf: bool,
    ) {
        if self.channels.contains_key(&id) {
            return;
        }
        let mut c = Channel {
            topic: topic.to_string(),
            ..Channel::default()
        };
        match kind {
            Some(MessageKind::AccelBlock) if protobuf => {
                c.accel = true;
                // Compensated channels declared before it that answer it.
                for other in self.channels.values_mut() {
                    let answers_it = accel_topic_of(&other.topic).as_deref() == Some(topic);
                    if let Some((pair @ None, _)) = other.answers.as_mut() {
                        if answers_it {
                            *pair = Some(id);
                        }
                    }
                }
            }
            Some(MessageKind::CompensatedBlock) if protobuf => {
                let want = accel_topic_of(topic);
                let accel = self
                    .channels
                    .iter()
                    .filter(|(_, other)| other.accel && Some(&other.topic) == want.as_ref())
                    .map(|(other, _)| *other)
                    .min();
                c.answers = Some((accel, Answers::new()));
            }
            _ => {}
        }
        self.channels.insert(id, c);
    }

    /// A message on channel `id` with MCAP sequence number `sequence`.
    pub(crate) fn message(&mut self, id: u16, sequence: u32, data: &[u8]) {
        let Some(c) = self.channels.get_mut(&id) else {
            return;
        };
        let seq = unwrap_sequence(c.tally.last_seq(), sequence);
        let arrival = c.tally.seq(seq);
        if let Some((_, answers)) = c.answers.as_mut() {
            match InputSeqOnly::decode(data) {
                Ok(m) => answers.output(m.input_seq, arrival.lost_messages),
                Err(_) => c.undecodable += 1,
            }
            return;
        }
        if !c.accel {
            return;
        }
        let Ok(block) = SeqOnly::decode(data) else {
            c.undecodable += 1;
            return;
        };
        for other in self.channels.values_mut() {
            if let Some((Some(accel), answers)) = other.answers.as_mut() {
                if *accel == id {
                    answers.input(block.seq);
                }
            }
        }
    }

    /// The channel's loss fields.
    pub(crate) fn fill(&self, info: &mut crate::ChannelInfo) {
        let Some(c) = self.channels.get(&info.id) else {
            return;
        };
        let t = &c.tally.totals;
        info.lost = t.lost_messages;
        info.gaps = c.tally.gaps;
        info.jumps = t.seq_jumps;
        info.out_of_order = t.out_of_order;
        info.restarts = t.restarts;
        info.resyncs = t.resyncs;
        info.retracted = c.tally.retracted;
        info.undecodable = c.undecodable;
        if let Some((accel, answers)) = &c.answers {
            info.inputs_topic = accel
                .and_then(|a| self.channels.get(&a))
                .map(|a| a.topic.clone());
            info.unanswered = answers.unanswered().clone();
            info.inputs_without_output = info.unanswered.count;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_seq_fields_are_read_as_the_schemas_have_them() {
        let mut b = vibro_msgs::CompensatedBlock::ZEROED;
        (b.seq, b.input_seq, b.estimate_seq, b.count) = (7, 123_456_789_012, 99, 32);
        b.a1_g[31] = [1.0, 2.0, 3.0];
        let bytes = crate::proto::CompensatedBlock::try_from(&b)
            .unwrap()
            .encode_to_vec();
        let m = InputSeqOnly::decode(bytes.as_slice()).unwrap();
        assert_eq!(m.input_seq, 123_456_789_012);
        let mut a = vibro_msgs::AccelBlock::ZEROED;
        (a.seq, a.first_sample_index, a.count) = (987_654_321_098, 5, 32);
        let bytes = crate::proto::AccelBlock::try_from(&a)
            .unwrap()
            .encode_to_vec();
        assert_eq!(
            SeqOnly::decode(bytes.as_slice()).unwrap().seq,
            987_654_321_098
        );
    }

    #[test]
    fn sequence_numbers_unwrap_across_2_to_the_32_and_a_zero_is_a_restart() {
        let cases = [
            (None, 7, 7),
            (Some(10), 11, 11),
            (Some(10), 5, 5),
            (Some(u64::from(u32::MAX)), 0, 1 << 32),
            (Some(u64::from(u32::MAX) - 1), 3, (1 << 32) + 3),
            (Some((1 << 32) + 3), u32::MAX, u64::from(u32::MAX)),
            (Some(123), 0, 0),
            (Some((5 << 32) + 9), 0, 0),
            // Half the range ahead is the furthest forwards; beyond it is behind.
            (Some(0), (1 << 31) - 1, (1 << 31) - 1),
            (Some(1 << 40), 1 << 31, (1 << 40) - (1 << 31)),
            (Some(5), u32::MAX, u64::from(u32::MAX)),
            (Some(u64::MAX), 5, u64::MAX),
        ];
        for (last, s, want) in cases {
            assert_eq!(unwrap_sequence(last, s), want, "{last:?} {s}");
        }
    }

    #[test]
    fn ranges_are_counted_merged_and_listed_up_to_the_limit() {
        let mut r = SeqRanges::default();
        for s in [11, 12, 13, 20, 22, 23] {
            r.add(s);
        }
        assert_eq!((r.count, r.ranges), (6, 3));
        assert_eq!(r.to_string(), "seq 11..=13, 20, 22..=23");
        assert_eq!(
            r.listed,
            [
                SeqRange {
                    first: 11,
                    last: 13
                },
                SeqRange {
                    first: 20,
                    last: 20
                },
                SeqRange {
                    first: 22,
                    last: 23
                }
            ]
        );
        let mut many = SeqRanges::default();
        for k in 0..100u64 {
            many.add(k * 10);
            many.add(k * 10 + 1);
        }
        assert_eq!((many.count, many.ranges), (200, 100));
        assert_eq!(many.listed.len(), MAX_LISTED_UNANSWERED);
        assert_eq!(
            many.listed[15],
            SeqRange {
                first: 150,
                last: 151
            }
        );
        assert!(
            many.to_string()
                .ends_with(", 150..=151 and 168 more in 84 more ranges"),
            "{many}"
        );
    }

    /// Feeds `events` (`I(seq)`: a block recorded; `O(input_seq, lost_before)`: an
    /// output recorded) and returns the unanswered blocks listed.
    fn run(events: &[Ev]) -> SeqRanges {
        let mut a = Answers::new();
        for e in events {
            match *e {
                Ev::I(s) => a.input(s),
                Ev::O(s, lost) => a.output(s, lost),
            }
        }
        a.unanswered().clone()
    }

    #[derive(Clone, Copy)]
    enum Ev {
        I(u64),
        O(u64, u64),
    }
    use Ev::{I, O};

    /// The reference, by brute force, for distinct `seq`s: the blocks recorded, in
    /// order, between the first one answered and the last one answered, that no output
    /// answers.
    fn brute(events: &[Ev]) -> Vec<u64> {
        let answered: std::collections::BTreeSet<u64> = events
            .iter()
            .filter_map(|e| match e {
                O(s, _) => Some(*s),
                I(_) => None,
            })
            .collect();
        let inputs: Vec<u64> = events
            .iter()
            .filter_map(|e| match e {
                I(s) => Some(*s),
                O(..) => None,
            })
            .collect();
        let first = inputs.iter().position(|s| answered.contains(s));
        let last = inputs.iter().rposition(|s| answered.contains(s));
        match (first, last) {
            (Some(f), Some(l)) => inputs[f..=l]
                .iter()
                .filter(|s| !answered.contains(s))
                .copied()
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Issue 46, item 6: 0..=10, a forged 500,000, then 11..=60; the compensator
    /// answers 0..=10, 500,000 and 14..=60 (11..=13 dropped while it resynced), each
    /// output recorded right after its block, or before it.
    #[test]
    fn blocks_dropped_after_a_forged_seq_are_listed() {
        let seqs: Vec<u64> = (0..=10).chain([500_000]).chain(11..=60).collect();
        let answered = |s: u64| !(11..=13).contains(&s);
        for output_first in [false, true] {
            let mut events = Vec::new();
            for &s in &seqs {
                if output_first && answered(s) {
                    events.push(O(s, 0));
                }
                events.push(I(s));
                if !output_first && answered(s) {
                    events.push(O(s, 0));
                }
            }
            let r = run(&events);
            assert_eq!((r.count, r.ranges), (3, 1), "{output_first}");
            assert_eq!(
                r.listed,
                [SeqRange {
                    first: 11,
                    last: 13
                }]
            );
            assert_eq!(brute(&events), [11, 12, 13]);
        }
    }

    /// A compensator restart: its outputs stop for blocks 270..=275; a block answered
    /// whose output the log lost is excused; a repeated seq (a restarted producer)
    /// is matched with its own output; blocks before the first output and after the
    /// last are not counted.
    #[test]
    fn unanswered_blocks_against_a_brute_force_count() {
        let mut events: Vec<Ev> = (0..5).map(I).collect();
        for s in 5..=300u64 {
            events.push(I(s));
            if !(270..=275).contains(&s) {
                events.push(O(s, 0));
            }
        }
        // A producer restart: 0..=9 again, all answered but 4 (dropped).
        for s in 0..10u64 {
            events.push(I(s));
            if s != 4 {
                events.push(O(s, 0));
            }
        }
        events.extend([I(10), I(11)]);
        let r = run(&events);
        assert_eq!(
            r.listed,
            [
                SeqRange {
                    first: 270,
                    last: 275
                },
                SeqRange { first: 4, last: 4 }
            ]
        );
        assert_eq!((r.count, r.ranges), (7, 2));
        // Every block first, then every output (a file written stream by stream): the
        // same.
        let (mut blocks, mut outputs): (Vec<Ev>, Vec<Ev>) =
            events.iter().partition(|e| matches!(e, I(_)));
        blocks.append(&mut outputs);
        assert_eq!(run(&blocks).listed, r.listed);
        // The log lost the output of block 100 (its channel's sequence shows it lost
        // before the output of 101): not an unanswered block.
        let events: Vec<Ev> = (0..200u64)
            .flat_map(|s| match s {
                100 => vec![I(s)],
                101 => vec![I(s), O(s, 1)],
                _ => vec![I(s), O(s, 0)],
            })
            .collect();
        assert_eq!(run(&events).count, 0);
    }

    /// Random interleavings against the brute force: blocks with random drops, outputs
    /// recorded up to a few blocks late or early.
    #[test]
    fn random_recordings_match_the_brute_force() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..300 {
            let n = 50 + next() % 200;
            let start = next() % 1000;
            let mut inputs = Vec::new();
            let mut outputs = Vec::new();
            for s in start..start + n {
                inputs.push(s);
                if next() % 5 != 0 {
                    outputs.push(s);
                }
            }
            // Interleave: each output after (or just before) its block, in order.
            let mut events = Vec::new();
            let (mut i, mut o) = (0, 0);
            while i < inputs.len() || o < outputs.len() {
                let early = next() % 3 == 0;
                let can_out = o < outputs.len()
                    && (i > 0 && outputs[o] <= inputs[i - 1]
                        || early && i < inputs.len() && outputs[o] == inputs[i]);
                if can_out && (next() % 2 == 0 || i == inputs.len()) {
                    events.push(O(outputs[o], 0));
                    o += 1;
                } else if i < inputs.len() {
                    events.push(I(inputs[i]));
                    i += 1;
                } else {
                    events.push(O(outputs[o], 0));
                    o += 1;
                }
            }
            let r = run(&events);
            let want = brute(&events);
            assert_eq!(r.count, want.len() as u64, "{want:?} {r:?}");
            let listed: Vec<u64> = r.listed.iter().flat_map(|g| g.first..=g.last).collect();
            assert_eq!(listed[..], want[..listed.len()]);
        }
    }
}
