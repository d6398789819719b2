//! The waveform stage in the compensator (MODEL.md section 12, `vibro_waveform`): the
//! `{prefix}vib` samples kept, and each accelerometer block held until the samples
//! cover its readings' intervals, then solved; the estimate stage's answer, made when
//! the block arrived, goes out instead when they do not (flagged `WAVEFORM_FALLBACK`).
//!
//! When a held block is decided, in the streams' time wherever possible so that a
//! lock-stepped replay gives the same blocks on every run:
//!
//! - **covered**: the samples reach past the last reading's interval by the
//!   interpolation's half-width: solved, `WAVEFORM`;
//! - **never**: a break in the sensors' stream (a gap, a rate change, time stamps that
//!   jump or run backwards, a flagged or non-finite sensor block) falls inside the
//!   readings, or the ring has moved past them, or no sensor block came yet while
//!   accelerometer blocks did: the estimate stage's answer;
//! - **late**: an accelerometer block dated `max_wait` (default: one vibration block)
//!   after the held block's last reading arrived before the samples covering it;
//! - **ended**: the sensors' stream ended (`vib_flags::END_OF_STREAM`, a replay's last
//!   block): held readings it does not cover are never;
//! - **silent**: nothing came on `{prefix}vib` for [`SILENCE_NS`] of the wall clock
//!   and the block has waited `max_wait` (the end of a replay, a sensor stream that
//!   died while the accelerometer stream stopped too);
//! - **full**: more than [`MAX_PENDING`] blocks are held: the oldest goes.
//!
//! Blocks leave in the order they came. Nothing here allocates per block: the queue's
//! slots and the stage's buffers are sized when the stage is built or the rate
//! changes.

use crate::config::{Model, Stage};
use std::collections::VecDeque;
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{vib_flags, CompensatedBlock, VibBlock, WireMessage, ACCEL_BLOCK_MAX};
use vibro_service::{Continuity, CountersJson, JsonObject, StreamCounters};
use vibro_waveform::{Coverage, StageCounters, WaveformStage};

/// Flags of the estimate stage's answer that do not describe the waveform stage's `a4`.
const ESTIMATE_STAGE_ONLY: u32 = cf::MAIN_ONLY | cf::MODEL_EFFECTS;

/// Blocks held at most (at 800 Hz in blocks of 32, 1.6 s of readings).
pub const MAX_PENDING: usize = 40;
/// Wall-clock silence of the sensors' stream after which held blocks wait no longer (a
/// sensor stream that died with the accelerometer's, with no end-of-stream block).
/// Long against a lock-stepped replay's pauses on a loaded machine, so that those never
/// decide a block; a replay ends its stream with an end-of-stream block instead.
pub const SILENCE_NS: u64 = 1_000_000_000;

/// One held block: the estimate stage's answer and the readings `U/K1`.
struct Pending {
    block: CompensatedBlock,
    readings_g: [[f64; 3]; ACCEL_BLOCK_MAX],
    recv_ns: u64,
    /// Readings solved so far (each as soon as the samples cover it), and their answers.
    solved: usize,
    out_g: [[f64; 3]; ACCEL_BLOCK_MAX],
}

/// Why held blocks went out with the estimate stage's answer, and what the stage did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WaveformCounts {
    /// Blocks the waveform stage made.
    pub waveform_blocks: u64,
    /// Blocks the estimate stage answered (the sum of the reasons below).
    pub fallback_blocks: u64,
    pub fallback_never: u64,
    pub fallback_late: u64,
    pub fallback_silent: u64,
    pub fallback_full: u64,
    /// Readings the stage solved that came out not finite (their block fell back).
    pub fallback_not_finite: u64,
    /// Most blocks held at once.
    pub max_pending: u64,
    /// `{prefix}vib` blocks received, and malformed ones (dropped).
    pub vib_received: u64,
    pub vib_malformed: u64,
    /// End-of-stream blocks (`vib_flags::END_OF_STREAM`).
    pub vib_ends: u64,
    /// The sensors' stream by the continuity rule (losses, out of order, restarts,
    /// jumps, resyncs).
    pub vib: StreamCounters,
    pub stage: StageCounters,
}

impl WaveformCounts {
    pub fn to_json(&self) -> JsonObject {
        let s = &self.stage;
        let mut o = JsonObject::new();
        o.u64("waveform_blocks", self.waveform_blocks)
            .u64("fallback_blocks", self.fallback_blocks)
            .u64("fallback_never", self.fallback_never)
            .u64("fallback_late", self.fallback_late)
            .u64("fallback_silent", self.fallback_silent)
            .u64("fallback_full", self.fallback_full)
            .u64("fallback_not_finite", self.fallback_not_finite)
            .u64("max_pending", self.max_pending)
            .u64("vib_received", self.vib_received)
            .u64("vib_malformed", self.vib_malformed)
            .u64("vib_ends", self.vib_ends)
            .object("vib", self.vib.to_json())
            .u64("vib_samples", s.vib_samples)
            .u64("vib_breaks", s.breaks)
            .u64("vib_gaps", s.gaps)
            .u64("vib_time_jumps", s.time_jumps)
            .u64("vib_backwards", s.backwards)
            .u64("vib_rate_changes", s.rate_changes)
            .u64("vib_repeated", s.repeated)
            .u64("vib_refused", s.refused)
            .u64("readings", s.readings)
            .u64("unconverged", s.unconverged)
            .u64("effect_resets", s.effect_resets);
        o
    }
}

/// The stage, its held blocks and their rules (module docs).
pub(crate) struct WaveformPath {
    stage: WaveformStage,
    pending: VecDeque<Pending>,
    max_wait_ns: Option<u64>,
    /// The latest sensor block's span, ns (the default `max_wait`).
    vib_block_ns: u64,
    last_vib_recv_ns: Option<u64>,
    continuity: Continuity,
    /// End of the newest accelerometer block's last reading, ns.
    newest_accel_end_ns: u64,
    /// The model has effects (their hooks run in the stage).
    model_effects: bool,
    pub(crate) counts: WaveformCounts,
}

impl WaveformPath {
    /// The path for `model`, `None` with `stage = "estimate"`. An extended model whose
    /// effects cannot be built is an error (the configuration's validation builds them).
    pub(crate) fn new(model: &Model) -> Result<Option<Self>, String> {
        if model.waveform.stage != Stage::Waveform {
            return Ok(None);
        }
        let passports = model.triad.passports;
        let mut effects: [Vec<Box<dyn vibro_effects::Effect>>; 3] = Default::default();
        if let Some((file, lab)) = &model.effects {
            for (u, e) in effects.iter_mut().enumerate() {
                *e = lab
                    .build_effects(&passports[u])
                    .map_err(|err| format!("model = {}: unit {u}: {err}", file.display()))?;
            }
        }
        let stage = WaveformStage::new(model.waveform.chain, model.triad.axes, passports, effects)
            .map_err(|e| e.to_string())?;
        Ok(Some(Self {
            stage,
            pending: VecDeque::with_capacity(MAX_PENDING + 1),
            max_wait_ns: model.waveform.max_wait_ns,
            vib_block_ns: 0,
            last_vib_recv_ns: None,
            continuity: Continuity::new(),
            newest_accel_end_ns: 0,
            model_effects: model.effects.is_some(),
            counts: WaveformCounts::default(),
        }))
    }

    /// A new model's stage (a reload): the held blocks stay, the samples go (the new
    /// stage starts on the next sensor block).
    pub(crate) fn replace_stage(&mut self, new: WaveformPath) {
        self.stage = new.stage;
        self.max_wait_ns = new.max_wait_ns;
        self.model_effects = new.model_effects;
    }

    pub(crate) fn counts(&self) -> WaveformCounts {
        let mut c = self.counts.clone();
        c.stage = self.stage.counters();
        c
    }

    /// A sensor block arrives at `recv_ns`. Its `seq` and sample index go through the
    /// continuity rule every reader of a stream applies (`vibro_msgs::continuity`):
    /// out-of-order blocks are dropped (counted), a restarted producer starts the
    /// stage afresh, a loss is a gap; the stage then applies its own time rules.
    pub(crate) fn on_vib(&mut self, b: &VibBlock, recv_ns: u64) {
        self.counts.vib_received += 1;
        if b.validate().is_err() {
            self.counts.vib_malformed += 1;
            return;
        }
        let arrival = self
            .continuity
            .check(b.seq, b.first_sample_index, u64::from(b.count));
        self.counts.vib.record(&arrival);
        if !arrival.accepted {
            return;
        }
        if arrival.restarted {
            self.stage.reset();
        }
        self.last_vib_recv_ns = Some(recv_ns);
        if b.flags & vib_flags::END_OF_STREAM != 0 {
            // A replay's or a rig's last word: held readings past the samples are
            // answered now, by the estimate stage.
            self.counts.vib_ends += 1;
            self.stage.end_of_stream();
            return;
        }
        self.vib_block_ns = u64::from(b.count).saturating_mul(b.sample_period_ns);
        self.stage.push_vib(
            b.seq,
            b.first_sample_index,
            b.t0_ns,
            b.sample_period_ns,
            b.samples_v(),
            b.flags & vib_flags::SATURATED != 0,
            arrival.gap() || b.flags & vib_flags::GAP_BEFORE != 0,
        );
        self.advance();
    }

    /// Holds a block (its estimate-stage answer, and the readings `U/K1`).
    pub(crate) fn hold(&mut self, block: &CompensatedBlock, readings_g: &[[f64; 3]], recv_ns: u64) {
        let count = u64::from(block.count);
        let end = block.t0_ns.saturating_add(
            block
                .sample_period_ns
                .saturating_mul(count.saturating_sub(1)),
        );
        self.newest_accel_end_ns = self.newest_accel_end_ns.max(end);
        let mut r = [[f64::NAN; 3]; ACCEL_BLOCK_MAX];
        r[..readings_g.len()].copy_from_slice(readings_g);
        self.pending.push_back(Pending {
            block: *block,
            readings_g: r,
            recv_ns,
            solved: 0,
            out_g: [[f64::NAN; 3]; ACCEL_BLOCK_MAX],
        });
        self.counts.max_pending = self.counts.max_pending.max(self.pending.len() as u64);
        self.advance();
    }

    /// Solves the held readings the samples cover, in order, each as soon as they do:
    /// when the samples that complete a block arrive, only the readings they cover are
    /// left to solve (about half a block's with 20 ms sensor blocks), not the block.
    fn advance(&mut self) {
        let stage = &mut self.stage;
        for p in self.pending.iter_mut() {
            let count = p.block.count as usize;
            if p.solved >= count {
                continue;
            }
            let period = p.block.sample_period_ns;
            let first_end = p
                .block
                .t0_ns
                .saturating_add(period.saturating_mul(p.solved as u64));
            let left = count - p.solved;
            // The most readings from `solved` on that the samples cover (monotone in n).
            let n = if stage.coverage(first_end, period, left) == Coverage::Ready {
                left
            } else {
                let (mut lo, mut hi) = (0usize, left - 1);
                while lo < hi {
                    let mid = (lo + hi).div_ceil(2);
                    if stage.coverage(first_end, period, mid) == Coverage::Ready {
                        lo = mid;
                    } else {
                        hi = mid - 1;
                    }
                }
                lo
            };
            if n == 0 {
                break;
            }
            let range = p.solved..p.solved + n;
            stage.compensate(
                first_end,
                period,
                &p.readings_g[range.clone()],
                &mut p.out_g[range],
            );
            p.solved += n;
            if p.solved < count {
                break;
            }
        }
    }

    /// The next block that may go out at wall-clock `now_ns`, decided (module docs);
    /// `None` while the oldest held block still waits.
    pub(crate) fn next_ready(&mut self, now_ns: u64) -> Option<CompensatedBlock> {
        self.advance();
        let front = self.pending.front()?;
        let b = &front.block;
        let count = b.count as usize;
        let period = b.sample_period_ns;
        let last_end = b
            .t0_ns
            .saturating_add(period.saturating_mul((count as u64).saturating_sub(1)));
        let max_wait = self.max_wait_ns.unwrap_or(self.vib_block_ns);
        let left_end = b
            .t0_ns
            .saturating_add(period.saturating_mul(front.solved as u64));
        let decision = if count == 0 {
            Some(Decision::Fallback(Reason::Never))
        } else if front.solved == count {
            Some(Decision::Solve)
        } else if self.pending.len() > MAX_PENDING {
            Some(Decision::Fallback(Reason::Full))
        } else if self.last_vib_recv_ns.is_none() {
            // No sensor stream (yet): nothing to wait for.
            Some(Decision::Fallback(Reason::Never))
        } else {
            match self.stage.coverage(left_end, period, count - front.solved) {
                // `advance` solves what is covered: not reached.
                Coverage::Ready | Coverage::Never => Some(Decision::Fallback(Reason::Never)),
                Coverage::NotYet => {
                    let silent = self
                        .last_vib_recv_ns
                        .is_none_or(|t| now_ns.saturating_sub(t) >= SILENCE_NS)
                        && now_ns.saturating_sub(front.recv_ns) >= max_wait;
                    if self.newest_accel_end_ns > last_end.saturating_add(max_wait) {
                        Some(Decision::Fallback(Reason::Late))
                    } else if silent {
                        Some(Decision::Fallback(Reason::Silent))
                    } else {
                        None
                    }
                }
            }
        };
        let decision = decision?;
        let Pending {
            mut block, out_g, ..
        } = self.pending.pop_front()?;
        match decision {
            Decision::Solve => {
                let out = &out_g[..count];
                // A reading the estimate stage set NaN (not finite, out of range) stays so.
                let finite = out
                    .iter()
                    .zip(&block.a4_g[..count])
                    .all(|(o, a)| (0..3).all(|u| o[u].is_finite() || !a[u].is_finite()));
                if finite {
                    // Both stages in one block: `a3` becomes the estimate stage's whole
                    // answer (its `a4`), `a4` the waveform stage's; the corrections
                    // keep `a2 = a1 - main`, `a3 = a2 - det`, `a4 = a3 - rand`.
                    for k in 0..count {
                        for u in 0..3 {
                            let m = out[k][u];
                            if !block.a4_g[k][u].is_finite() {
                                continue;
                            }
                            let estimate_a4 = block.a4_g[k][u];
                            block.a3_g[k][u] = estimate_a4;
                            block.det_g[k][u] = block.a2_g[k][u] - estimate_a4;
                            block.a4_g[k][u] = m;
                            block.rand_g[k][u] = estimate_a4 - m;
                        }
                    }
                    // The estimate flags (missing, stale, ahead, flagged) stay: they
                    // describe `a3`, the estimate stage's answer. `a4` is not main
                    // error only; the extended model's effects ran on the samples.
                    block.flags = (block.flags & !ESTIMATE_STAGE_ONLY) | cf::WAVEFORM;
                    if self.model_effects {
                        block.flags |= cf::MODEL_EFFECTS;
                    }
                    self.counts.waveform_blocks += 1;
                } else {
                    self.counts.fallback_not_finite += 1;
                    block.flags |= cf::WAVEFORM_FALLBACK;
                    self.counts.fallback_blocks += 1;
                }
            }
            Decision::Fallback(reason) => {
                block.flags |= cf::WAVEFORM_FALLBACK;
                self.counts.fallback_blocks += 1;
                match reason {
                    Reason::Never => self.counts.fallback_never += 1,
                    Reason::Late => self.counts.fallback_late += 1,
                    Reason::Silent => self.counts.fallback_silent += 1,
                    Reason::Full => self.counts.fallback_full += 1,
                }
            }
        }
        Some(block)
    }

    /// Every held block, decided now as if the sensors' stream had ended (the end of an
    /// in-process run): covered ones solved, the rest the estimate stage's.
    pub(crate) fn finish(&mut self) -> Option<CompensatedBlock> {
        if self.pending.is_empty() {
            // A restart: the streams' time starts again.
            self.newest_accel_end_ns = 0;
        }
        if let Some(b) = self.next_ready(u64::MAX) {
            return Some(b);
        }
        // Still waiting with no more input to come: the estimate stage answers it.
        let Pending { mut block, .. } = self.pending.pop_front()?;
        block.flags |= cf::WAVEFORM_FALLBACK;
        self.counts.fallback_blocks += 1;
        self.counts.fallback_silent += 1;
        Some(block)
    }

    /// Blocks held now.
    pub(crate) fn held(&self) -> usize {
        self.pending.len()
    }

    /// Readings held now.
    pub(crate) fn held_readings(&self) -> u64 {
        self.pending.iter().map(|p| u64::from(p.block.count)).sum()
    }

    /// The receive time of the oldest held block (0 when none).
    pub(crate) fn front_recv_ns(&self) -> u64 {
        self.pending.front().map_or(0, |p| p.recv_ns)
    }
}

#[derive(Debug, Clone, Copy)]
enum Reason {
    Never,
    Late,
    Silent,
    Full,
}

#[derive(Debug, Clone, Copy)]
enum Decision {
    Solve,
    Fallback(Reason),
}
