//! Adversarial input sequences for the continuity rule ([`crate::Continuity`], its
//! module doc): a real stream with fake messages, repeats, reorderings, losses and
//! corrupt fields in it, then the real stream alone. The property tests of the
//! continuity, of the compensator's and the estimator's cores, and the
//! `stream_sequence` fuzz target feed a sequence to what they test and [`check`] what
//! it took (with the `testing` feature; `vibro_service`'s `testing` feature turns it on
//! and re-exports this module as `vibro_service::adversary`).
//!
//! ```
//! use vibro_msgs::adversary::{check, generate, Xorshift};
//! use vibro_msgs::{Continuity, StreamCounters};
//! let mut rng = Xorshift::new(7);
//! let s = generate(|| Some(rng.next_u64()), 40, 32, true);
//! let (mut c, mut totals) = (Continuity::new(), StreamCounters::default());
//! let taken: Vec<bool> = s
//!     .messages
//!     .iter()
//!     .map(|m| {
//!         let a = c.check(m.seq, m.first_sample_index, 32);
//!         totals.record(&a);
//!         a.accepted
//!     })
//!     .collect();
//! check(&s, &taken, totals.lost_messages).unwrap();
//! ```

use crate::{MAX_LOST_MESSAGES, RESYNC_AFTER};

/// Messages of the real stream alone at the end of every sequence.
pub const TAIL: usize = 64;

/// One message of a sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Message {
    pub seq: u64,
    pub first_sample_index: u64,
    /// Its first sample's time in sample periods (a real message's is its sample index
    /// unless its time is corrupt).
    pub t0_periods: u64,
    /// Sample values are absurd (NaN, 1e300).
    pub absurd_values: bool,
    /// A message of the real stream (its sample index or time possibly corrupt), not
    /// an injected one.
    pub real: bool,
}

/// A sequence: an adversarial prefix, then [`TAIL`] messages of the real stream alone.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sequence {
    pub messages: Vec<Message>,
    /// Index of the tail's first message.
    pub tail: usize,
    /// Adversarial episodes are isolated: at most two steps each, fake bursts at most
    /// [`RESYNC_AFTER`] in step, each episode followed by `2 RESYNC_AFTER` messages
    /// of the real stream. No fake stream can pass for the real one then, so every loss
    /// a consumer counts must be a real message it never took.
    pub isolated: bool,
}

/// A xorshift64 generator, for seeded sequences.
#[derive(Debug, Clone, Copy)]
pub struct Xorshift(u64);

impl Xorshift {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// A sequence of at most `ops` adversarial steps, each drawn from `next` (a step ends
/// the prefix when `next` has nothing more), then the real stream alone. Messages carry
/// `samples` samples each. With `isolated` ([`Sequence::isolated`]), episodes of one
/// or two steps, fake bursts of at most [`RESYNC_AFTER`] in step, each from a place of
/// its own, and the real stream in between.
///
/// The steps: a real message; a real message lost; two real ones swapped; a repeat of
/// the last real one; fake bursts ahead (by up to 1,000, or beyond 2^20) or behind
/// (old `seq`s, replayed); a random `seq`; `u64::MAX`; 0; a real message with its
/// sample index stepped (both ways, by a little or beyond 2^32, or to `u64::MAX`) or
/// its time stepped (both ways, or absurd); absurd sample values; and without
/// `isolated`, long fake streams (5 to 40 in step).
pub fn generate(
    mut next: impl FnMut() -> Option<u64>,
    ops: usize,
    samples: u64,
    isolated: bool,
) -> Sequence {
    let mut v = next().unwrap_or(0);
    // Where the real stream starts: room behind it for old seqs, and far from u64::MAX.
    let mut r = 1_000 + v % (1 << 40);
    let real = |seq: u64| Message {
        seq,
        first_sample_index: seq.wrapping_mul(samples),
        t0_periods: seq.wrapping_mul(samples),
        absurd_values: false,
        real: true,
    };
    let fake = |seq: u64, v: u64| Message {
        seq,
        // Consistent with the seq, or anywhere.
        first_sample_index: if v & 1 == 0 {
            seq.wrapping_mul(samples)
        } else {
            v >> 1
        },
        t0_periods: if v & 2 == 0 {
            seq.wrapping_mul(samples)
        } else {
            v >> 2
        },
        absurd_values: v & 4 != 0,
        real: false,
    };
    let mut messages = Vec::new();
    // The seqs of the last fake burst: the next one must not continue or overlap it.
    let mut last_fakes: Option<(u64, u64)> = None;
    // Adversarial steps since the real stream last went on alone.
    let mut episode = 0;
    if isolated {
        // The stream starts real (what a consumer sees first is its baseline).
        for _ in 0..2 * RESYNC_AFTER - 1 {
            messages.push(real(r));
            r += 1;
        }
    }
    for _ in 0..ops {
        let Some(x) = next() else {
            break;
        };
        v = x;
        if isolated && episode > 0 && (episode >= 2 || v & (1 << 63) != 0) {
            // The real stream alone, long enough to be resynced to and confirmed.
            for _ in 0..2 * RESYNC_AFTER {
                messages.push(real(r));
                r += 1;
            }
            episode = 0;
        }
        let burst = 1 + (v >> 8) % u64::from(RESYNC_AFTER);
        let mut fakes = |from: u64, len: u64, messages: &mut Vec<Message>| {
            let mut from = from;
            if let (true, Some((start, end))) = (isolated, last_fakes) {
                if from >= start.saturating_sub(2 * u64::from(RESYNC_AFTER)) && from <= end {
                    from = end.saturating_add(2);
                }
            }
            for k in 0..len {
                messages.push(fake(from.wrapping_add(k), v.rotate_left(k as u32 * 7)));
            }
            last_fakes = Some((from, from.saturating_add(len)));
        };
        episode += 1;
        match v % 16 {
            0..=2 => {
                messages.push(real(r));
                r += 1;
                episode -= 1;
            }
            3 => r += 1 + (v >> 8) % 3,
            4 => {
                messages.push(real(r + 1));
                messages.push(real(r));
                r += 2;
            }
            5 => messages.push(real(r.saturating_sub(1))),
            6 => fakes(r + 1 + (v >> 16) % 1_000, burst, &mut messages),
            7 => fakes(
                r + MAX_LOST_MESSAGES + 2 + (v >> 16) % (1 << 30),
                burst,
                &mut messages,
            ),
            8 => fakes(r - 1 - (v >> 16) % 999, burst, &mut messages),
            9 => fakes(v >> 4, 1, &mut messages),
            10 => fakes(u64::MAX - (v >> 8) % 2, 1, &mut messages),
            11 => fakes(0, 1, &mut messages),
            12 => {
                let mut m = real(r);
                let step = match (v >> 8) % 5 {
                    0 => m.first_sample_index.wrapping_add(1 + (v >> 16) % 1_000),
                    1 => m.first_sample_index.saturating_sub(1 + (v >> 16) % 1_000),
                    2 => m.first_sample_index.wrapping_add(1 << 33),
                    3 => m.first_sample_index.wrapping_sub(1 << 33),
                    _ => u64::MAX,
                };
                m.first_sample_index = step;
                messages.push(m);
                r += 1;
            }
            13 => {
                let mut m = real(r);
                m.t0_periods = match (v >> 8) % 4 {
                    0 => m.t0_periods.wrapping_add(1 + (v >> 16) % 100_000),
                    1 => m.t0_periods.saturating_sub(1 + (v >> 16) % 100_000),
                    2 => 0,
                    _ => u64::MAX,
                };
                messages.push(m);
                r += 1;
            }
            14 => {
                let mut m = real(r);
                m.absurd_values = true;
                messages.push(m);
                r += 1;
            }
            _ => {
                if isolated {
                    fakes(r + 1 + (v >> 16) % 1_000, burst, &mut messages);
                } else {
                    // A fake stream long enough to be taken for the real one.
                    let from = match (v >> 8) % 3 {
                        0 => r + 1 + (v >> 16) % 1_000,
                        1 => r - 1 - (v >> 16) % 999,
                        _ => v >> 4,
                    };
                    fakes(from, 5 + (v >> 32) % 36, &mut messages);
                }
            }
        }
    }
    let tail = messages.len();
    messages.extend((r..r + TAIL as u64).map(real));
    Sequence {
        messages,
        tail,
        isolated,
    }
}

/// What a consumer did with a sequence, against the continuity rule: `taken[i]` tells
/// whether it took message `i` (accepted it, gave an output for it),
/// `lost_messages` what it counted lost in the end. Errs with the reason when:
///
/// - in the tail, more than `RESYNC_AFTER - 1` messages were not taken before the
///   first one that was, or one after a taken one was not (the stream silenced);
/// - with [`Sequence::isolated`], more messages were counted lost than messages
///   of the real stream, between its first and last `seq`, that were never taken (a
///   jump, or a fake step, counted as a loss).
pub fn check(s: &Sequence, taken: &[bool], lost_messages: u64) -> Result<(), String> {
    if taken.len() != s.messages.len() {
        return Err(format!(
            "{} messages, {} verdicts",
            s.messages.len(),
            taken.len()
        ));
    }
    let tail = &taken[s.tail..];
    let first = tail.iter().position(|&t| t);
    match first {
        None => return Err(format!("none of the {} tail messages taken", tail.len())),
        Some(k) if k >= RESYNC_AFTER as usize => {
            return Err(format!(
                "the first tail message taken is number {k}: more than {} dropped",
                RESYNC_AFTER - 1
            ))
        }
        Some(k) => {
            if let Some(j) = tail[k..].iter().position(|&t| !t) {
                return Err(format!(
                    "tail message {} (seq {}) not taken after {k}",
                    k + j,
                    s.messages[s.tail + k + j].seq
                ));
            }
        }
    }
    if s.isolated {
        let reals = s.messages.iter().zip(taken).filter(|(m, _)| m.real);
        let (mut lo, mut hi) = (u64::MAX, 0);
        let mut took = std::collections::BTreeSet::new();
        for (m, &t) in reals {
            lo = lo.min(m.seq);
            hi = hi.max(m.seq);
            if t {
                took.insert(m.seq);
            }
        }
        let never_taken = (hi - lo + 1).saturating_sub(took.len() as u64);
        if lost_messages > never_taken {
            return Err(format!(
                "{lost_messages} messages counted lost, but only {never_taken} real ones \
                 (seq {lo}..={hi}) were never taken"
            ));
        }
    }
    Ok(())
}
