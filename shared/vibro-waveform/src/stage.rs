//! The waveform stage (crate docs): the vibration sensors' stream kept in a ring of
//! samples with the chain undone, and each block of readings solved for the
//! interval-mean acceleration of each unit.
//!
//! The stream's continuity: a block continues the stream when its `seq` and
//! `first_sample_index` follow the last one, its period is the same and its `t0_ns`
//! lies within half a period of where the stream puts it. Otherwise:
//!
//! - the same block again (its `seq` and index already taken): dropped, counted;
//! - a jump (lost blocks, a `GAP_BEFORE` flag), a time stamp off by more than half a
//!   period (forward or backwards), a rate change: a new *segment* starts, counted by
//!   kind; readings whose interval (with the interpolation's half-width) is not inside
//!   one segment are never covered ([`Coverage::Never`]): the caller falls back to the
//!   estimate stage for them;
//! - a flagged (`SATURATED`) block or one with a sample that is not finite: not stored,
//!   and the segment ends before it.
//!
//! Times: a segment's sample `k` was stamped at `t0 + (k - k0) P`, `P` the stamped
//! period refined from the blocks' own `t0_ns` over the segment (a 25.6 kHz stream's
//! integer `sample_period_ns` is 39062 or 39063 ns; the blocks' stamps carry the exact
//! rate). It saw the base at that time minus the chain's delay.

use crate::chain::{ChainInverse, SensorChain};
use crate::kernel::{Kernel, WeightsCache, HALF_WIDTH};
use vibro_effects::effect::{BlockCtx, Effect};
use vibro_physics::fp;
use vibro_physics::passport::Passport;
use vibro_physics::triad::TriadAxes;

/// The grid runs at least this fast, Hz, and at least at the sensor rate: FP raises a
/// 640 Hz vibration band to 3.2 kHz (its fifth power), which Gregory's rule on the grid
/// must resolve (MODEL.md section 12); 32 points per 800 Hz reading leave 0.013 ug at
/// worst on a reading (tests/tone_and_noise.rs).
pub const MIN_FINE_RATE_HZ: f64 = 25_600.0;
/// Most fine points per reading (a reading interval of 1 s at 51.2 kHz is 51,200).
pub const MAX_FINE_POINTS: usize = 65_536;
/// Path effects whose state starts afresh (the first reading, or after a break) are
/// first run over up to this much of the vibration before the reading.
pub const WARM_UP_S: f64 = 0.05;
/// The warm-up's readings at most.
const MAX_WARM_UP_READINGS: i128 = 256;
/// The ring holds at least this long a stretch of the stream, s (plus two readings): a
/// lock-stepped replay sends the sensors' blocks ahead of the accelerometer's by up to
/// the estimator's window (1 s shipped) until the first estimate is out.
const RING_S: f64 = 4.0;
const MAX_RING: usize = 1 << 19;
/// Newton's iterations at most; it stops when no mean moves by more than
/// [`NEWTON_TOLERANCE_G`], or when a bound on the error the last step left is below it
/// ([`newton_error_bound_g`]). The three units' means are stepped together with the
/// 3 x 3 Jacobian (their coupling through `m1`, `m2`, `m31`, `m32` is linear in the
/// other units' means, so it is in the Jacobian), and each step converges
/// quadratically. The first step is what the vibration error changed since the
/// previous reading (the guess is that reading's correction; 1e-4..1e-2 g on the 600 s
/// Cyclone-4 flight), the second its square times FP's curvature (1e-10..1e-5 g), after
/// which the bound is far below the tolerance: two iterations per reading (2.000 on
/// average, `StageCounters::newton_iterations`). Without the bound a third step was
/// needed to see that nothing moves (1e-16..1e-15 g); stepping the units one after the
/// other (Gauss-Seidel) shrank the coupling's part by only its size, about 1e-3, per
/// iteration: four.
const NEWTON_ITERATIONS: usize = 8;
const NEWTON_TOLERANCE_G: f64 = 1e-12;
/// Newton's error bound is tried after steps below this (g): with the AL-15's `k2` the
/// bound after a 1e-6 g step is about 1e-16 g, after 1e-4 g about 1e-12 g.
const BOUND_TRIED_BELOW_G: f64 = 1e-6;
/// Blocks the stream already holds, in a row, before the producer is taken to have
/// started again (the continuity rule's resync after 3, `vibro_msgs::continuity`).
const REPEATS_BEFORE_RESTART: u32 = 3;

/// Why the stage cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum WaveformError {
    #[error("the vibration sensors' chain: {0}")]
    Chain(String),
}

/// Whether a block of readings can be solved now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coverage {
    /// The samples cover every reading's interval: [`WaveformStage::compensate`].
    Ready,
    /// The samples that would cover the last reading have not arrived yet.
    NotYet,
    /// The samples will never cover the block (a break, a gap, the ring has moved on,
    /// a rate the stage does not take): the estimate stage answers it.
    Never,
}

/// What a vibration block did to the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VibPush {
    /// Appended to the stream.
    Continued,
    /// The first block, or the first after a break: a new segment.
    Started,
    /// A block already taken (same `seq` and index): dropped.
    Repeated,
    /// A flagged block or one with a sample that is not finite: not stored.
    Refused,
}

/// The stage's counts (cumulative).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StageCounters {
    pub vib_blocks: u64,
    pub vib_samples: u64,
    /// New segments after the first (the sum of the kinds below).
    pub breaks: u64,
    pub gaps: u64,
    pub time_jumps: u64,
    pub backwards: u64,
    pub rate_changes: u64,
    pub repeated: u64,
    /// Flagged (saturated, `GAP_BEFORE` aside) or non-finite blocks.
    pub refused: u64,
    /// Readings solved.
    pub readings: u64,
    /// Readings whose Newton did not meet its tolerance (their last iterate is used).
    pub unconverged: u64,
    /// Newton's iterations over all readings.
    pub newton_iterations: u64,
    /// Times the path effects' state started afresh.
    pub effect_resets: u64,
}

#[derive(Debug, Clone, Copy)]
struct Segment {
    /// Index and stamp of the segment's first sample.
    index0: u64,
    t0_ns: i128,
    /// The stamped period, refined from the blocks' stamps, ns.
    period_ns: f64,
    nominal_period_ns: u64,
    /// Oldest index still in the ring, and the index after the newest.
    lo: u64,
    hi: u64,
    next_seq: u64,
}

/// The fine grid's state: the reading the path effects expect next.
#[derive(Debug, Clone, Copy)]
struct Grid {
    period_ns: u64,
    points: usize,
    next_end_ns: i128,
}

/// The waveform stage of one triad (crate docs).
pub struct WaveformStage {
    chain: SensorChain,
    passports: [Passport; 3],
    effects: [Vec<Box<dyn Effect>>; 3],
    has_effects: [bool; 3],
    kernel: Kernel,
    /// The kernel's weights at the grid's recent offsets between samples.
    weights_cache: WeightsCache,
    ring: Vec<[f64; 3]>,
    seg: Option<Segment>,
    inverse: Option<ChainInverse>,
    /// The segment ended (a refused block): the next block starts a new one.
    broken: bool,
    /// Blocks in a row the stream already held.
    repeats: u32,
    grid: Option<Grid>,
    /// Per unit: the vibration at the unit on the reading's grid points, `[OA, PA, IA]`,
    /// its deviations from the interval's mean, and the output effects' part.
    vib: [Vec<[f64; 3]>; 3],
    dev: [Vec<[f64; 3]>; 3],
    /// The sensors' samples interpolated at the grid's points (`[IA of unit 0, 1, 2]`).
    sensors: Vec<[f64; 3]>,
    /// `dev` by axis (`[unit][axis][point]`), for Newton's sums.
    dev_axes: [[Vec<f64>; 3]; 3],
    /// Newton's weighted terms per point (FP and its slope), summed in point order.
    term_f: Vec<f64>,
    term_g: Vec<f64>,
    eff: [Vec<f64>; 3],
    /// Gregory's weights of the interval's mean on its `m + 1` points.
    weights: Vec<f64>,
    /// Their sum (1 to rounding), in point order.
    weight_sum: f64,
    /// `ia_to_unit[u][i][v] = d a_i / d m3[v]`: unit `u`'s `[OA, PA, IA]` from the
    /// units' IA means (constant: the triad's axes, which it and `sensor_pick` hold).
    ia_to_unit: [[[f64; 3]; 3]; 3],
    /// The same map as a pick: unit `u`'s axis `i` is `sign * sensors[v]` for
    /// `sensor_pick[u][i] = (v, sign)` (the triad's axes are a signed permutation).
    sensor_pick: [[(usize, f64); 3]; 3],
    /// The last reading's point `m` is this reading's point 0 (the grid continues).
    carry: bool,
    carry_effects: bool,
    input: Vec<[f64; 3]>,
    out: Vec<f64>,
    fp_out: Vec<f64>,
    /// Per unit: the last reading minus its solution (the guess for the next).
    correction_g: [Option<f64>; 3],
    epoch_ns: Option<i128>,
    counters: StageCounters,
}

impl WaveformStage {
    /// The stage for a triad with `passports` and, per unit, the extended model's
    /// effects (empty for the base model), built by the caller from the model
    /// (`LabModel::build_effects`).
    pub fn new(
        chain: SensorChain,
        axes: TriadAxes,
        passports: [Passport; 3],
        effects: [Vec<Box<dyn Effect>>; 3],
    ) -> Result<Self, WaveformError> {
        let problems = chain.problems();
        if !problems.is_empty() {
            let text: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
            return Err(WaveformError::Chain(text.join("; ")));
        }
        let has_effects = [0, 1, 2].map(|u| !effects[u].is_empty());
        let map = ia_to_unit(&axes);
        Ok(Self {
            chain,
            passports,
            effects,
            has_effects,
            kernel: Kernel::new(),
            weights_cache: WeightsCache::new(),
            ring: Vec::new(),
            seg: None,
            inverse: None,
            broken: false,
            repeats: 0,
            grid: None,
            vib: [Vec::new(), Vec::new(), Vec::new()],
            dev: [Vec::new(), Vec::new(), Vec::new()],
            dev_axes: Default::default(),
            sensors: Vec::new(),
            term_f: Vec::new(),
            term_g: Vec::new(),
            eff: [Vec::new(), Vec::new(), Vec::new()],
            weights: Vec::new(),
            weight_sum: 0.0,
            ia_to_unit: map,
            sensor_pick: sensor_pick(&map),
            carry: false,
            carry_effects: false,
            input: Vec::new(),
            out: Vec::new(),
            fp_out: Vec::new(),
            correction_g: [None; 3],
            epoch_ns: None,
            counters: StageCounters::default(),
        })
    }

    /// The chain the stage undoes.
    pub fn chain(&self) -> &SensorChain {
        &self.chain
    }

    pub fn counters(&self) -> StageCounters {
        self.counters
    }

    /// The producer's stream has ended (an end-of-stream block): nothing more comes into
    /// the current segment, so readings it does not cover never will be
    /// ([`Coverage::Never`]); the next block starts a new segment.
    pub fn end_of_stream(&mut self) {
        if self.seg.is_some() {
            self.broken = true;
        }
    }

    /// Forgets the stream and the effects' state (a restarted producer).
    pub fn reset(&mut self) {
        self.seg = None;
        self.broken = false;
        self.grid = None;
        self.correction_g = [None; 3];
    }

    /// One vibration-sensor block, samples in volts `[sample][sensor]` (sensor `i` along
    /// unit `i`'s IA), sample `k` stamped `t0_ns + k period`. `flagged`: the producer
    /// marked it saturated; `gap_before`: it says samples were lost before it.
    #[allow(clippy::too_many_arguments)]
    pub fn push_vib(
        &mut self,
        seq: u64,
        first_index: u64,
        t0_ns: u64,
        period_ns: u64,
        samples_v: &[[f64; 3]],
        flagged: bool,
        gap_before: bool,
    ) -> VibPush {
        self.counters.vib_blocks += 1;
        self.counters.vib_samples += samples_v.len() as u64;
        let count = samples_v.len() as u64;
        if period_ns == 0 {
            self.counters.refused += 1;
            self.broken = true;
            return VibPush::Refused;
        }
        // Continuity against the current segment.
        let mut start = self.seg.is_none() || self.broken;
        if let (Some(s), false) = (&self.seg, start) {
            let predicted = s.t0_ns as f64 + (first_index as f64 - s.index0 as f64) * s.period_ns;
            let off = t0_ns as f64 - predicted;
            // A block the stream already holds (a duplicate, a late copy), at its own
            // time: dropped. After REPEATS_BEFORE_RESTART in a row the producer is taken
            // to have started again on the same time base (a replay run twice).
            let old = first_index.wrapping_add(count) <= s.hi && first_index >= s.index0;
            if old
                && period_ns == s.nominal_period_ns
                && 2.0 * off.abs() <= s.period_ns
                && self.repeats < REPEATS_BEFORE_RESTART
            {
                self.repeats += 1;
                self.counters.repeated += 1;
                return VibPush::Repeated;
            }
            if period_ns != s.nominal_period_ns {
                self.counters.rate_changes += 1;
                start = true;
            } else if gap_before || seq != s.next_seq || first_index != s.hi {
                self.counters.gaps += 1;
                start = true;
            } else if 2.0 * off.abs() > s.period_ns {
                if off < 0.0 {
                    self.counters.backwards += 1;
                } else {
                    self.counters.time_jumps += 1;
                }
                start = true;
            }
            if start {
                self.counters.breaks += 1;
            }
        }
        self.repeats = 0;
        if flagged || samples_v.iter().any(|v| !v.iter().all(|x| x.is_finite())) {
            self.counters.refused += 1;
            self.broken = true;
            return VibPush::Refused;
        }
        let rate_hz = 1e9 / period_ns as f64;
        if start {
            if !self.chain.usable_at(rate_hz) {
                self.counters.refused += 1;
                self.broken = true;
                return VibPush::Refused;
            }
            let want = ((RING_S + 2.0 * self.grid_period_s()) * rate_hz).ceil() as usize;
            let cap = want.max(4096).next_power_of_two().min(MAX_RING);
            if self.ring.len() != cap {
                // Allocates: at the first block and at a rate change, not per block.
                self.ring = vec![[0.0; 3]; cap];
            }
            let inverse = match &mut self.inverse {
                Some(inv) if self.seg.is_some_and(|s| s.nominal_period_ns == period_ns) => {
                    inv.reset();
                    *inv
                }
                _ => ChainInverse::new(&self.chain, rate_hz),
            };
            self.inverse = Some(inverse);
            self.seg = Some(Segment {
                index0: first_index,
                t0_ns: i128::from(t0_ns),
                period_ns: period_ns as f64,
                nominal_period_ns: period_ns,
                lo: first_index,
                hi: first_index,
                next_seq: seq,
            });
            self.broken = false;
        }
        let (Some(s), Some(inv)) = (&mut self.seg, &mut self.inverse) else {
            return VibPush::Refused;
        };
        // The stamped period from the segment's own stamps.
        if first_index > s.index0 {
            s.period_ns = (i128::from(t0_ns) - s.t0_ns) as f64 / (first_index - s.index0) as f64;
        }
        let mask = self.ring.len() as u64 - 1;
        // The filter's state in a local for the block: kept in registers rather than
        // stored and loaded back through `self` on every sample (the ring's stores
        // could otherwise alias it): the recurrence's chain was twice as long.
        let mut chain = *inv;
        for (k, v) in samples_v.iter().enumerate() {
            let idx = first_index.wrapping_add(k as u64);
            self.ring[(idx & mask) as usize] = chain.undo(*v);
        }
        *inv = chain;
        s.hi = first_index.wrapping_add(count);
        s.lo = s.lo.max(s.hi.saturating_sub(self.ring.len() as u64));
        s.next_seq = seq.wrapping_add(1);
        if start {
            VibPush::Started
        } else {
            VibPush::Continued
        }
    }

    fn grid_period_s(&self) -> f64 {
        self.grid.map_or(0.0, |g| g.period_ns as f64 * 1e-9)
    }

    /// Fine points per reading of `period_ns` with the current stream's rate.
    fn points_for(&self, period_ns: u64) -> Option<usize> {
        let s = self.seg?;
        let sensor_hz = 1e9 / s.period_ns;
        let fine_hz = sensor_hz.max(MIN_FINE_RATE_HZ);
        let m = (fine_hz * period_ns as f64 * 1e-9).ceil();
        (m >= 1.0 && m <= MAX_FINE_POINTS as f64).then_some(m as usize)
    }

    /// The fractional sample index of base time `t_ns` (relative arithmetic: `rel_ns`
    /// is the time after the segment's first stamp).
    #[inline]
    fn position(s: &Segment, rel_ns: f64) -> f64 {
        s.index0 as f64 + rel_ns / s.period_ns
    }

    /// Can the readings whose first interval ends at `first_end_ns`, `count` of them
    /// every `period_ns`, be solved now?
    pub fn coverage(&self, first_end_ns: u64, period_ns: u64, count: usize) -> Coverage {
        let Some(s) = self.seg else {
            return Coverage::NotYet;
        };
        if count == 0 || period_ns == 0 {
            return Coverage::Never;
        }
        if self.points_for(period_ns).is_none() {
            return Coverage::Never;
        }
        let delay_ns = self.chain.delay_s * 1e9;
        let first = i128::from(first_end_ns) - s.t0_ns;
        let last = first + (count as i128 - 1) * i128::from(period_ns);
        let x_first = Self::position(&s, first as f64 - period_ns as f64 + delay_ns);
        let x_last = Self::position(&s, last as f64 + delay_ns);
        let w = HALF_WIDTH as f64;
        if x_first.floor() - w + 1.0 < s.lo as f64 {
            return Coverage::Never;
        }
        if x_last.floor() + w < s.hi as f64 {
            return Coverage::Ready;
        }
        if self.broken {
            // The segment has ended: nothing more comes into it.
            return Coverage::Never;
        }
        Coverage::NotYet
    }

    /// Solves a block of readings (`readings_g[k][u]` = `U/K1` of unit `u`, reading `k`'s
    /// interval ending at `first_end_ns + k period_ns`) for each unit's interval-mean
    /// acceleration along its IA, into `out_g`. Readings that are not finite give NaN.
    /// Call only when [`Self::coverage`] says `Ready`.
    pub fn compensate(
        &mut self,
        first_end_ns: u64,
        period_ns: u64,
        readings_g: &[[f64; 3]],
        out_g: &mut [[f64; 3]],
    ) {
        self.compensate_with_ve(first_end_ns, period_ns, readings_g, out_g, None);
    }

    /// [`Self::compensate`], and per reading and unit the error the model puts in it
    /// (`ve_g`, when given): the reading less what the unit's FP gives at its solved
    /// means without the vibration, `R - FP(m1, m2, m3)`. It is the vibration error
    /// (what the vibration rectifies, with the output effects), the quantity the lab
    /// predicts per window: one evaluation for the compensator and the lab.
    pub fn compensate_with_ve(
        &mut self,
        first_end_ns: u64,
        period_ns: u64,
        readings_g: &[[f64; 3]],
        out_g: &mut [[f64; 3]],
        mut ve_g: Option<&mut [[f64; 3]]>,
    ) {
        let Some(m) = self.points_for(period_ns) else {
            out_g.fill([f64::NAN; 3]);
            if let Some(v) = ve_g {
                v.fill([f64::NAN; 3]);
            }
            return;
        };
        let first = i128::from(first_end_ns);
        let p = i128::from(period_ns);
        let continues = self
            .grid
            .is_some_and(|g| g.period_ns == period_ns && g.points == m && g.next_end_ns == first);
        if !continues {
            self.restart_grid(first, period_ns, m, readings_g.first().copied());
        }
        for (k, (r, o)) in readings_g.iter().zip(out_g.iter_mut()).enumerate() {
            let end = first + k as i128 * p;
            *o = self.solve(end, period_ns, m, *r);
            if let Some(v) = ve_g.as_deref_mut().and_then(|v| v.get_mut(k)) {
                *v = [0, 1, 2].map(|u| {
                    let a = pick(&self.sensor_pick[u], o);
                    r[u] - fp::output_g(&self.passports[u], a[0], a[1], a[2])
                });
            }
        }
        if let Some(g) = &mut self.grid {
            g.next_end_ns = first + readings_g.len() as i128 * p;
        }
    }

    /// The path effects start afresh at `first_end_ns` and are run over the vibration
    /// before it (up to [`WARM_UP_S`], as far as the segment reaches).
    fn restart_grid(
        &mut self,
        first_end_ns: i128,
        period_ns: u64,
        m: usize,
        reading: Option<[f64; 3]>,
    ) {
        let h_s = period_ns as f64 * 1e-9 / m as f64;
        for u in 0..3 {
            if self.vib[u].len() != m + 1 {
                // Allocates: at the first block and when the grid changes size.
                self.vib[u] = vec![[0.0; 3]; m + 1];
                self.dev[u] = vec![[0.0; 3]; m + 1];
                self.dev_axes[u] = std::array::from_fn(|_| vec![0.0; m + 1]);
                self.eff[u] = vec![0.0; m + 1];
            }
            for e in self.effects[u].iter_mut() {
                e.reset(1.0 / h_s);
            }
        }
        if self.weights.len() != m + 1 {
            self.weights = gregory_weights(m);
            self.weight_sum = self.weights.iter().sum();
            self.input = vec![[0.0; 3]; m + 1];
            self.out = vec![0.0; m + 1];
            self.fp_out = vec![0.0; m + 1];
            self.sensors = vec![[0.0; 3]; m + 1];
            self.term_f = vec![0.0; m + 1];
            self.term_g = vec![0.0; m + 1];
        }
        self.counters.effect_resets += 1;
        self.carry = false;
        self.grid = Some(Grid {
            period_ns,
            points: m,
            next_end_ns: first_end_ns,
        });
        if self.epoch_ns.is_none() {
            self.epoch_ns = Some(first_end_ns);
        }
        self.correction_g = [None; 3];
        if !self.has_effects.iter().any(|&e| e) {
            return;
        }
        // Warm-up readings that the segment covers.
        // At most MAX_WARM_UP_READINGS: a stream's period is input (a hostile 1 ns
        // period must not buy 5e7 readings of work).
        let wanted =
            ((WARM_UP_S / (period_ns as f64 * 1e-9)).ceil() as i128).min(MAX_WARM_UP_READINGS);
        let p = i128::from(period_ns);
        let mut k0 = wanted;
        while k0 > 0 && self.coverage_at(first_end_ns - k0 * p, period_ns) != Coverage::Ready {
            k0 -= 1;
        }
        let r = reading.unwrap_or([f64::NAN; 3]);
        let guess = self.guess(r);
        for k in (1..=k0).rev() {
            let end = first_end_ns - k * p;
            self.fill_fine(end, period_ns, m);
            // Output effects see the vibration at the guess of the first reading.
            if guess.iter().all(|x| x.is_finite()) {
                self.output_effects(end, period_ns, m, guess);
            }
        }
    }

    fn coverage_at(&self, end_ns: i128, period_ns: u64) -> Coverage {
        if end_ns < 0 || end_ns > i128::from(u64::MAX) {
            return Coverage::Never;
        }
        self.coverage(end_ns as u64, period_ns, 1)
    }

    fn ctx(
        &self,
        unit: usize,
        end_ns: i128,
        period_ns: u64,
        m: usize,
        first_point: usize,
    ) -> BlockCtx {
        let h = period_ns as f64 / m as f64;
        let epoch = self.epoch_ns.unwrap_or(end_ns);
        BlockCtx {
            unit,
            t0_s: ((end_ns - epoch) as f64 - period_ns as f64 + first_point as f64 * h) * 1e-9,
            dt_s: h * 1e-9,
        }
    }

    /// The vibration at each unit on the `m + 1` grid points of the reading ending at
    /// `end_ns` (`end - T + j T/m`), through the path effects, into `self.vib`. Point 0
    /// is the previous reading's point `m` when the grid continues (each point goes
    /// through the effects once).
    fn fill_fine(&mut self, end_ns: i128, period_ns: u64, m: usize) {
        let Some(s) = self.seg else {
            return;
        };
        let first_point = if self.carry {
            for u in 0..3 {
                self.vib[u][0] = self.vib[u][m];
            }
            1
        } else {
            0
        };
        let h = period_ns as f64 / m as f64;
        let delay_ns = self.chain.delay_s * 1e9;
        let rel_start = (end_ns - s.t0_ns) as f64 - period_ns as f64 + delay_ns;
        let mask = self.ring.len() as u64 - 1;
        let ring = &self.ring;
        let (kernel, cache) = (&self.kernel, &mut self.weights_cache);
        let sensors = &mut self.sensors[..=m];
        // `Kernel::interpolate` at the point with the offset's weights looked up (bit
        // for bit the same: crate::kernel's test): its first tap and weights' slot.
        let tap = |cache: &mut WeightsCache, j: usize| {
            let x = Self::position(&s, rel_start + j as f64 * h);
            let k0 = x.floor();
            let slot = cache.slot(kernel, x - k0);
            (k0 as i64, slot)
        };
        // The taps of a point as one slice of the ring (`None`: they wrap around its end).
        let taps = |k0: i64| -> Option<&[[f64; 3]; 2 * HALF_WIDTH]> {
            let first = ((k0 - HALF_WIDTH as i64 + 1) as u64 & mask) as usize;
            ring.get(first..first + 2 * HALF_WIDTH)
                .and_then(|t| t.try_into().ok())
        };
        let mut j = first_point;
        while j <= m {
            let (ka, slot_a) = tap(cache, j);
            if j < m {
                // Two points at a time (independent sums).
                let (kb, slot_b) = tap(cache, j + 1);
                if let (Some(ta), Some(tb)) = (taps(ka), taps(kb)) {
                    let (wa, wb) = (cache.entry(slot_a), cache.entry(slot_b));
                    (sensors[j], sensors[j + 1]) = wa.interpolate_pair(ta, wb, tb);
                    j += 2;
                    continue;
                }
            }
            let w = cache.entry(slot_a);
            sensors[j] = match taps(ka) {
                Some(t) => w.interpolate_slice(t),
                None => w.interpolate(ka, |k| ring[(k as u64 & mask) as usize]),
            };
            j += 1;
        }
        // Each unit's [OA, PA, IA] from the sensors.
        for u in 0..3 {
            let unit_pick = self.sensor_pick[u];
            let points = self.vib[u][first_point..=m]
                .iter_mut()
                .zip(&self.sensors[first_point..=m]);
            for (out, sensors) in points {
                *out = pick(&unit_pick, sensors);
            }
        }
        for u in 0..3 {
            let ctx = self.ctx(u, end_ns, period_ns, m, first_point);
            for e in self.effects[u].iter_mut() {
                e.at_unit_input(&ctx, &mut self.vib[u][first_point..=m]);
            }
        }
        // The deviations from the interval's mean (Gregory's weights).
        for u in 0..3 {
            let mut mean = [0.0; 3];
            for (v, w) in self.vib[u][..=m].iter().zip(&self.weights) {
                for i in 0..3 {
                    mean[i] += w * v[i];
                }
            }
            let [d0, d1, d2] = &mut self.dev_axes[u];
            for (j, (d, v)) in self.dev[u][..=m]
                .iter_mut()
                .zip(&self.vib[u][..=m])
                .enumerate()
            {
                *d = [v[0] - mean[0], v[1] - mean[1], v[2] - mean[2]];
                (d0[j], d1[j], d2[j]) = (d[0], d[1], d[2]);
            }
        }
        self.carry_effects = self.carry;
        self.carry = true;
    }

    /// The guess of each unit's IA mean for readings `r` (g): the reading less the last
    /// correction, or the first approximation [P2 (17)].
    fn guess(&self, r: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|u| match self.correction_g[u] {
            Some(c) => r[u] - c,
            None => {
                let p = &self.passports[u];
                (r[u] - p.a0_g) / p.k1
            }
        })
    }

    /// The output effects' contribution on the grid points of the reading ending at
    /// `end_ns`, at the IA means `m3`, into `self.eff` (crate docs: held fixed while
    /// Newton solves FP); returns its weighted mean per unit.
    fn output_effects(&mut self, end_ns: i128, period_ns: u64, m: usize, m3: [f64; 3]) -> [f64; 3] {
        let mut e_mean = [0.0; 3];
        let first_point = if self.carry_effects { 1 } else { 0 };
        for u in 0..3 {
            if !self.has_effects[u] {
                continue;
            }
            if first_point == 1 {
                self.eff[u][0] = self.eff[u][m];
            }
            let a = pick(&self.sensor_pick[u], &m3);
            let p = &self.passports[u];
            for j in first_point..=m {
                let d = self.dev[u][j];
                let x = [a[0] + d[0], a[1] + d[1], a[2] + d[2]];
                self.input[j] = x;
                let f = fp::output_g(p, x[0], x[1], x[2]);
                self.out[j] = f;
                self.fp_out[j] = f;
            }
            let ctx = self.ctx(u, end_ns, period_ns, m, first_point);
            for e in self.effects[u].iter_mut() {
                e.at_unit_output(
                    &ctx,
                    &self.input[first_point..=m],
                    &mut self.out[first_point..=m],
                );
            }
            for j in first_point..=m {
                self.eff[u][j] = self.out[j] - self.fp_out[j];
            }
            e_mean[u] = self.eff[u][..=m]
                .iter()
                .zip(&self.weights)
                .map(|(e, w)| e * w)
                .sum();
        }
        e_mean
    }

    /// One reading: its grid points, the output effects at the guess, and Newton.
    fn solve(&mut self, end_ns: i128, period_ns: u64, m: usize, r: [f64; 3]) -> [f64; 3] {
        self.fill_fine(end_ns, period_ns, m);
        if !r.iter().all(|x| x.is_finite()) {
            // The effects' state advanced; the guess stays as it was.
            return [f64::NAN; 3];
        }
        let mut m3 = self.guess(r);
        let effects_g = self.output_effects(end_ns, period_ns, m, m3);
        let mut converged = false;
        for _ in 0..NEWTON_ITERATIONS {
            self.counters.newton_iterations += 1;
            let mut residual = [0.0; 3];
            let mut jacobian = [[0.0; 3]; 3];
            let mut ia_g = [0.0; 3];
            for u in 0..3 {
                let a = pick(&self.sensor_pick[u], &m3);
                ia_g[u] = a[2];
                let p = &self.passports[u];
                // The weighted terms point by point (independent: they vectorise),
                // then summed in point order: the same sums as one loop, bit for bit.
                let [d0, d1, d2] = &self.dev_axes[u];
                newton_terms(
                    p,
                    a,
                    [&d0[..=m], &d1[..=m], &d2[..=m]],
                    &self.weights[..=m],
                    &mut self.term_f[..=m],
                    &mut self.term_g[..=m],
                );
                let (mut f, mut g) = (0.0, 0.0);
                for (tf, tg) in self.term_f[..=m].iter().zip(&self.term_g[..=m]) {
                    f += tf;
                    g += tg;
                }
                residual[u] = f + effects_g[u] - r[u];
                // The OA and PA columns, `sum w (m1 + m31 (a3 + d3))` and the same
                // with `m2`, `m32`: the deviations' weighted sum is 0 (to rounding,
                // and the Jacobian only sets how fast Newton converges, not where).
                let ia_sum = a[2] * self.weight_sum;
                let gradient = [
                    p.m1 * self.weight_sum + p.m31_per_g * ia_sum,
                    p.m2 * self.weight_sum + p.m32_per_g * ia_sum,
                    g,
                ];
                let map = &self.ia_to_unit[u];
                for v in 0..3 {
                    jacobian[u][v] = (0..3).map(|i| gradient[i] * map[i][v]).sum();
                }
            }
            let step = solve_3x3(&jacobian, residual)
                .unwrap_or_else(|| [0, 1, 2].map(|u| residual[u] / jacobian[u][u]));
            let mut step_max: f64 = 0.0;
            for u in 0..3 {
                m3[u] -= step[u];
                step_max = step_max.max(step[u].abs());
            }
            // A NaN step (no finite solution) is not convergence: `NaN <= x` is false.
            let tolerance_g =
                NEWTON_TOLERANCE_G * (1.0 + m3.iter().fold(0.0f64, |a, x| a.max(x.abs())));
            // The bound is tried only once the step is small: before, it could not pass
            // with any sizeable nonlinearity, and trying it costs a pass over the points.
            if step_max <= tolerance_g
                || (step_max <= BOUND_TRIED_BELOW_G
                    && newton_error_bound_g(
                        &self.passports,
                        &self.ia_to_unit,
                        [0, 1, 2].map(|u| &self.dev_axes[u][2][..=m]),
                        &jacobian,
                        &step,
                        ia_g,
                    ) <= tolerance_g)
            {
                converged = true;
                break;
            }
        }
        if !converged {
            self.counters.unconverged += 1;
        }
        self.counters.readings += 1;
        for u in 0..3 {
            self.correction_g[u] = Some(r[u] - m3[u]);
        }
        m3
    }
}

/// A bound on how far the IA means are from FP's root after the Newton step `step`
/// taken with `jacobian` from the means whose units' IA accelerations were `ia_g`,
/// the points' IA deviations being `dev_ia` per unit; infinite when none can be
/// given.
///
/// The step zeroes the linearised residual, so what is left is the residual's
/// second-order remainder along the step. Each unit's `[OA, PA, IA]` moved by
/// `delta = ia_to_unit * step`, the same at every point. FP's second derivatives
/// are `d2/da3^2 = 2 k2 + 6 k3 a3 + 12 k4 a3^2 + 20 k5 a3^3`, `d2/da3 da1 = m31`,
/// `d2/da3 da2 = m32`, and zero otherwise; with `R` the largest `|a3|` on the
/// segment, the remainder at a point is at most
/// `0.5 (H3 d3^2 + 2 |m31| d1 d3 + 2 |m32| d2 d3)`, `H3 = 2|k2| + 6|k3| R +
/// 12|k4| R^2 + 20|k5| R^3`. The asymmetry's `|a3|` has no second derivative: it
/// adds nothing if no point's `a3` crosses zero during the step (every `|a3| >
/// d3`), and otherwise no bound is given. The grid's weights are positive and sum
/// to 1, so the weighted residual keeps the pointwise bound. The means' error is
/// then at most `|J^-1|_inf` times the largest unit's remainder, doubled for the
/// Jacobian's change along the step (of relative size `H3 d3`, far below 1 here).
fn newton_error_bound_g(
    passports: &[Passport; 3],
    ia_to_unit: &[[[f64; 3]; 3]; 3],
    dev_ia: [&[f64]; 3],
    jacobian: &[[f64; 3]; 3],
    step: &[f64; 3],
    ia_g: [f64; 3],
) -> f64 {
    let Some(inverse_norm) = inverse_norm_inf(jacobian) else {
        return f64::INFINITY;
    };
    let mut remainder_g: f64 = 0.0;
    for u in 0..3 {
        let map = &ia_to_unit[u];
        let delta = [0, 1, 2]
            .map(|i| (map[i][0] * step[0] + map[i][1] * step[1] + map[i][2] * step[2]).abs());
        let (nearest, farthest) = abs_range(ia_g[u], dev_ia[u]);
        let clear_of_kink = delta[2].is_finite() && nearest > delta[2];
        if !clear_of_kink {
            // A point's IA may cross zero (the asymmetry's kink).
            return f64::INFINITY;
        }
        let r = farthest + delta[2];
        let k = &passports[u].k;
        let h3 = 2.0 * k[2].abs()
            + r * (6.0 * k[3].abs() + r * (12.0 * k[4].abs() + r * 20.0 * k[5].abs()));
        let p = &passports[u];
        let unit_g = 0.5
            * (h3 * delta[2] * delta[2]
                + 2.0 * p.m31_per_g.abs() * delta[0] * delta[2]
                + 2.0 * p.m32_per_g.abs() * delta[1] * delta[2]);
        remainder_g = remainder_g.max(unit_g);
    }
    2.0 * inverse_norm * remainder_g
}

/// The smallest and largest `|ia + d|` over `dev`, in four lanes (independent chains of
/// compare-and-select: `minpd`/`maxpd`); NaNs are passed over.
#[inline]
fn abs_range(ia: f64, dev: &[f64]) -> (f64, f64) {
    const LANES: usize = 4;
    let (mut lo, mut hi) = ([f64::INFINITY; LANES], [0.0f64; LANES]);
    let chunks = dev.chunks_exact(LANES);
    let tail = chunks.remainder();
    for c in chunks {
        for l in 0..LANES {
            let x = (ia + c[l]).abs();
            lo[l] = if x < lo[l] { x } else { lo[l] };
            hi[l] = if x > hi[l] { x } else { hi[l] };
        }
    }
    for (l, d) in tail.iter().enumerate() {
        let x = (ia + d).abs();
        lo[l] = if x < lo[l] { x } else { lo[l] };
        hi[l] = if x > hi[l] { x } else { hi[l] };
    }
    (
        lo.iter().fold(f64::INFINITY, |a, &b| a.min(b)),
        hi.iter().fold(0.0f64, |a, &b| a.max(b)),
    )
}

/// `|j^-1|_inf` (the largest absolute row sum of the inverse), by the adjugate; `None`
/// if `j` is singular or not finite.
fn inverse_norm_inf(j: &[[f64; 3]; 3]) -> Option<f64> {
    let det = det3(j);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    // inverse[r][c] = cofactor[c][r] / det, cofactor[c][r] from the rows other than c
    // and the columns other than r.
    let minor = |c: usize, r: usize| {
        let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
        let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
        j[c0][r0] * j[c1][r1] - j[c0][r1] * j[c1][r0]
    };
    let norm = (0..3)
        .map(|r| (0..3).map(|c| minor(c, r).abs()).sum::<f64>())
        .fold(0.0f64, f64::max)
        / det.abs();
    norm.is_finite().then_some(norm)
}

/// `d a_i / d m3[v]` for each unit (`[u][i][v]`): its `[OA, PA, IA]` from the units'
/// IA means through the body frame, a linear map ([`TriadAxes::body_from_ia`], then
/// `to_unit`), taken column by column.
fn ia_to_unit(axes: &TriadAxes) -> [[[f64; 3]; 3]; 3] {
    let mut map = [[[0.0; 3]; 3]; 3];
    for v in 0..3 {
        let mut e = [0.0; 3];
        e[v] = 1.0;
        let body = axes.body_from_ia(&e);
        for u in 0..3 {
            let a = axes.units[u].to_unit(&body);
            for i in 0..3 {
                map[u][i][v] = a[i];
            }
        }
    }
    map
}

/// [`ia_to_unit`] as a signed pick per unit and axis: the one sensor with a nonzero
/// entry, and that entry (+-1). The triad's IAs cover x, y and z
/// ([`TriadAxes`] checks it), so every row has exactly one.
fn sensor_pick(map: &[[[f64; 3]; 3]; 3]) -> [[(usize, f64); 3]; 3] {
    map.map(|unit| {
        unit.map(|row| {
            (0..3)
                .find(|&v| row[v] != 0.0)
                .map_or((0, 0.0), |v| (v, row[v]))
        })
    })
}

/// A unit's `[OA, PA, IA]` from the three units' IA values `ia` (sensor samples or IA
/// means) by its [`sensor_pick`]: `to_unit(body_from_ia(ia))` to the bit (a sign
/// times a value; the two signs' product is exact).
#[inline(always)]
fn pick(unit_pick: &[(usize, f64); 3], ia: &[f64; 3]) -> [f64; 3] {
    let [(v0, s0), (v1, s1), (v2, s2)] = *unit_pick;
    [s0 * ia[v0], s1 * ia[v1], s2 * ia[v2]]
}

/// `x` with `j x = b` by Cramer's rule, or `None` if `j` is singular or not finite.
/// Newton's Jacobian is diagonally dominant (`k1` about 1 against cross terms of about
/// 1e-3), where Cramer's rule is as accurate as elimination.
#[inline]
fn solve_3x3(j: &[[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = det3(j);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    // Column k replaced by b, written out: `array::map` with a closure here was not
    // inlined (a call per reading, 2 % of a flight's replay).
    let with_column = |k: usize| {
        let mut c = *j;
        c[0][k] = b[0];
        c[1][k] = b[1];
        c[2][k] = b[2];
        c
    };
    let x = [
        det3(&with_column(0)) / det,
        det3(&with_column(1)) / det,
        det3(&with_column(2)) / det,
    ];
    (x[0].is_finite() && x[1].is_finite() && x[2].is_finite()).then_some(x)
}

/// The determinant of `c` by its first row's cofactors.
#[inline(always)]
fn det3(c: &[[f64; 3]; 3]) -> f64 {
    c[0][0] * (c[1][1] * c[2][2] - c[1][2] * c[2][1])
        - c[0][1] * (c[1][0] * c[2][2] - c[1][2] * c[2][0])
        + c[0][2] * (c[1][0] * c[2][1] - c[1][1] * c[2][0])
}

/// Newton's weighted terms at each grid point, `w FP(a + d)` and `w dFP/da3(a + d)`,
/// into `term_f`, `term_g` (independent per point: they vectorise; the caller sums them
/// in point order).
fn newton_terms(
    p: &Passport,
    a: [f64; 3],
    dev: [&[f64]; 3],
    weights: &[f64],
    term_f: &mut [f64],
    term_g: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, the only feature this copy is compiled for.
        return unsafe { newton_terms_avx2(p, a, dev, weights, term_f, term_g) };
    }
    newton_terms_portable(p, a, dev, weights, term_f, term_g)
}

/// [`newton_terms`] compiled for AVX2 (4 points per instruction instead of 2): the
/// same IEEE operations (no FMA), so the same numbers bit for bit.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn newton_terms_avx2(
    p: &Passport,
    a: [f64; 3],
    dev: [&[f64]; 3],
    weights: &[f64],
    term_f: &mut [f64],
    term_g: &mut [f64],
) {
    newton_terms_portable(p, a, dev, weights, term_f, term_g)
}

#[inline(always)]
fn newton_terms_portable(
    p: &Passport,
    a: [f64; 3],
    dev: [&[f64]; 3],
    weights: &[f64],
    term_f: &mut [f64],
    term_g: &mut [f64],
) {
    let [d0, d1, d2] = dev;
    let points = term_f
        .iter_mut()
        .zip(term_g.iter_mut())
        .zip(weights)
        .zip(d0.iter().zip(d1).zip(d2));
    for (((tf, tg), w), ((x0, x1), x2)) in points {
        let x = [a[0] + x0, a[1] + x1, a[2] + x2];
        *tf = w * fp::output_g(p, x[0], x[1], x[2]);
        *tg = w * fp::gradient_g(p, x[0], x[1], x[2])[2];
    }
}

/// Gregory's end-corrected trapezoid rule on `m + 1` equally spaced points, as weights
/// of the interval's mean (they sum to 1): `(3/8, 7/6, 23/24, 1, ..., 1, 23/24, 7/6,
/// 3/8) / m`, exact for cubics, error `O(h^4)` where the midpoint rule's is `O(h^2)`.
/// Below 6 intervals, the trapezoid rule.
pub fn gregory_weights(m: usize) -> Vec<f64> {
    let mut w = vec![1.0 / m as f64; m + 1];
    if m >= 6 {
        for (j, c) in [3.0 / 8.0, 7.0 / 6.0, 23.0 / 24.0].into_iter().enumerate() {
            w[j] = c / m as f64;
            w[m - j] = c / m as f64;
        }
    } else {
        w[0] = 0.5 / m as f64;
        w[m] = 0.5 / m as f64;
    }
    w
}

#[cfg(test)]
mod tests {
    use super::{gregory_weights, inverse_norm_inf, newton_error_bound_g, solve_3x3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use vibro_physics::fp;
    use vibro_physics::passport::Passport;

    /// The AL-15 with its nonlinearity (`k2..k5`), cross terms (`m31`, `m32`) and
    /// asymmetry (`d1A`) scaled by `gains`.
    fn scaled_passport(scale: f64, [nonlinear, cross, asymmetry]: [f64; 3]) -> Passport {
        let mut spec = vibro_config::resolve_passport("AL-15")
            .expect("shipped")
            .to_spec();
        spec.lambda.clear();
        spec.k2_ppm_per_g *= nonlinear * scale;
        spec.k3_ppm_per_g2 *= nonlinear * scale;
        spec.k4_ppm_per_g3 *= nonlinear * scale;
        spec.k5_ppm_per_g4 *= nonlinear * scale;
        spec.m31_ppm_per_g = 300.0 * cross * scale;
        spec.m32_ppm_per_g = -200.0 * cross * scale;
        spec.d1a_ppm = 500.0 * asymmetry * scale;
        Passport::try_from_spec(&spec).expect("valid")
    }

    /// Newton's stopping bound against the true error. The residual is written out
    /// here (Gregory's weighted mean of FP over 33 points of random deviations, each
    /// unit's `[OA, PA, IA]` a linear map of the three IA means) and solved from a
    /// guess 0.03 g off, with the exact Jacobian; the root is the means the readings
    /// were made from. At every step with a finite bound the error left is within it.
    /// Each of the bound's terms is made to dominate in turn (each would fail the test
    /// if left out): the nonlinearity raised 60-fold; the IA x OA and IA x PA terms
    /// with OA and PA moving with the means (cross terms of 0.3 in the map); the
    /// asymmetry with a point put within the step of IA's zero, where the bound must
    /// be infinite. Without a kink in reach, the bound falls below the stage's
    /// tolerance within three steps.
    #[test]
    fn newton_error_bound_holds_the_true_error() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let points = 33;
        let weights = gregory_weights(points - 1);
        let mut finite_bounds = 0;
        let mut infinite_bounds = 0;
        // (nonlinear, cross, asymmetry) gains, map cross terms, point near the kink.
        let kinds: [([f64; 3], f64, bool); 3] = [
            ([60.0, 0.0, 0.0], 1e-2, false),
            ([0.0, 25.0, 0.0], 0.3, false),
            ([1.0, 0.0, 100.0], 1e-2, true),
        ];
        for case in 0..60 {
            let (gains, cross_map, near_kink) = kinds[case % 3];
            let passports = [0.7, 1.0, 1.3].map(|s| scaled_passport(s, gains));
            let map: [[[f64; 3]; 3]; 3] = std::array::from_fn(|u| {
                std::array::from_fn(|i| {
                    std::array::from_fn(|v| {
                        let own = if i == 2 && v == u { 1.0 } else { 0.0 };
                        own + cross_map * (rng.random::<f64>() - 0.5)
                    })
                })
            });
            let truth = [2.5, -3.0, 3.5].map(|c| c + rng.random::<f64>() - 0.5);
            let unit = |u: usize, m: &[f64; 3]| -> [f64; 3] {
                std::array::from_fn(|i| (0..3).map(|v| map[u][i][v] * m[v]).sum())
            };
            let guess = [truth[0] + 0.03, truth[1] - 0.02, truth[2] + 0.01];
            let dev: [Vec<[f64; 3]>; 3] = std::array::from_fn(|u| {
                let mut d: Vec<[f64; 3]> = (0..points)
                    .map(|_| std::array::from_fn(|_| 3.0 * (rng.random::<f64>() - 0.5)))
                    .collect();
                // Deviations from the weighted mean, as the stage's.
                for i in 0..3 {
                    let mean: f64 = d.iter().zip(&weights).map(|(x, w)| w * x[i]).sum();
                    d.iter_mut().for_each(|x| x[i] -= mean);
                }
                if near_kink {
                    // Point 5's IA 1 mg from zero at the guess, 10 mg at the root.
                    let ia_guess = unit(u, &guess)[2];
                    d[5][2] = -ia_guess + 1e-3 * (1.0 + 9.0 * rng.random::<f64>());
                }
                d
            });
            let mean_fp = |u: usize, m: &[f64; 3]| -> f64 {
                let a = unit(u, m);
                dev[u]
                    .iter()
                    .zip(&weights)
                    .map(|(d, w)| {
                        w * fp::output_g(&passports[u], a[0] + d[0], a[1] + d[1], a[2] + d[2])
                    })
                    .sum()
            };
            let readings: [f64; 3] = std::array::from_fn(|u| mean_fp(u, &truth));
            let dev_ia: [Vec<f64>; 3] =
                std::array::from_fn(|u| dev[u].iter().map(|d| d[2]).collect());
            let mut m = guess;
            let mut settled = false;
            for step_no in 0..6 {
                let residual: [f64; 3] = std::array::from_fn(|u| mean_fp(u, &m) - readings[u]);
                let jacobian: [[f64; 3]; 3] = std::array::from_fn(|u| {
                    let a = unit(u, &m);
                    let mut grad = [0.0; 3];
                    for (d, w) in dev[u].iter().zip(&weights) {
                        let g =
                            fp::gradient_g(&passports[u], a[0] + d[0], a[1] + d[1], a[2] + d[2]);
                        for i in 0..3 {
                            grad[i] += w * g[i];
                        }
                    }
                    std::array::from_fn(|v| (0..3).map(|i| grad[i] * map[u][i][v]).sum())
                });
                let ia_g = [0, 1, 2].map(|u| unit(u, &m)[2]);
                let step = solve_3x3(&jacobian, residual).expect("regular");
                for u in 0..3 {
                    m[u] -= step[u];
                }
                let bound = newton_error_bound_g(
                    &passports,
                    &map,
                    [0, 1, 2].map(|u| &dev_ia[u][..]),
                    &jacobian,
                    &step,
                    ia_g,
                );
                let error = (0..3).map(|u| (m[u] - truth[u]).abs()).fold(0.0, f64::max);
                if bound.is_finite() {
                    finite_bounds += 1;
                    assert!(
                        error <= bound + 1e-14,
                        "case {case} step {step_no}: error {error:e} g over its bound {bound:e} g"
                    );
                    settled |= bound <= super::NEWTON_TOLERANCE_G && step_no < 3;
                } else {
                    infinite_bounds += 1;
                    // Only a point within the step of IA's zero makes it infinite.
                    let in_reach = (0..3).any(|u| {
                        let d3: f64 = (0..3).map(|v| map[u][2][v] * step[v]).sum::<f64>().abs();
                        dev_ia[u].iter().any(|d| (ia_g[u] + d).abs() <= d3)
                    });
                    assert!(in_reach, "case {case} step {step_no}: no bound");
                }
            }
            if !near_kink {
                assert!(
                    settled,
                    "case {case}: the bound never fell below the tolerance"
                );
            }
        }
        assert!(
            finite_bounds > 200 && infinite_bounds >= 20,
            "{finite_bounds} {infinite_bounds}"
        );
    }

    /// `|J^-1|_inf` against the inverse taken column by column with Cramer's rule.
    #[test]
    fn inverse_norm_is_the_largest_row_sum_of_the_inverse() {
        let j = [[2.0, -1.0, 0.5], [1.0, 3.0, -2.0], [0.25, 4.0, 1.0]];
        let columns = [0, 1, 2].map(|c| {
            let mut e = [0.0; 3];
            e[c] = 1.0;
            solve_3x3(&j, e).expect("regular")
        });
        let want = (0..3)
            .map(|r| (0..3).map(|c| columns[c][r].abs()).sum::<f64>())
            .fold(0.0, f64::max);
        let got = inverse_norm_inf(&j).expect("regular");
        assert!((got - want).abs() < 1e-14 * want, "{got} vs {want}");
        assert!(inverse_norm_inf(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]]).is_none());
    }

    /// Cramer's rule against a system with a known solution (a diagonally dominant
    /// Jacobian as Newton's, and a general one), and singular or non-finite systems
    /// refused.
    #[test]
    fn solve_3x3_solves_and_refuses_singular_systems() {
        let x = [0.3, -1.7, 2.5e-6];
        for j in [
            [
                [1.0002, 1e-3, -2e-3],
                [5e-4, 0.9998, 1e-3],
                [-1e-3, 2e-3, 1.0],
            ],
            [[2.0, -1.0, 0.5], [1.0, 3.0, -2.0], [0.25, 4.0, 1.0]],
        ] {
            let b = [0, 1, 2].map(|r| (0..3).map(|c| j[r][c] * x[c]).sum::<f64>());
            let got = solve_3x3(&j, b).expect("regular");
            for k in 0..3 {
                assert!((got[k] - x[k]).abs() < 1e-14, "{k}: {} vs {}", got[k], x[k]);
            }
        }
        let singular = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]];
        assert!(solve_3x3(&singular, [1.0, 2.0, 3.0]).is_none());
        let nan = [[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(solve_3x3(&nan, [1.0, 2.0, 3.0]).is_none());
        assert!(solve_3x3(
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [f64::INFINITY, 0.0, 0.0]
        )
        .is_none());
    }
}
