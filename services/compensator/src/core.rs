//! The compensator's handling of each message without the transport: validation,
//! continuity, staleness, the estimate in use, flags and the compensation itself
//! ([`Compensation`]), fed by the service's hot loop (`crate::service`) or in-process
//! ([`InProcess`]).

use crate::config::{Config, Model};
use crate::interval::{within_fraction, within_output_interval, within_spectrum};
use crate::mapping::{sensor_map, unit_vibrations, UnitVibrations};
use crate::spectrum::{sensor_spectrum, unit_bands, SpectrumSolver};
use crate::waveform::WaveformPath;
use tracing::{info, warn};
#[cfg(feature = "ipc")]
use vibro_ipc::StreamPublisher;
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{
    accel_flags, estimate_flags, AccelBlock, CompensatedBlock, CompensationMode, VibBlock,
    VibEstimate, WireMessage,
};
use vibro_physics::compensation::TriadCompensator;
use vibro_physics::vibration::{PsdBand, Vibration};
use vibro_service::{
    count_first, now_ns, Continuity, CountersJson, DisorderLog, JsonObject, Latency, Quantiles,
    StreamCounters,
};

/// A new model for the hot thread, with its compensator already built (by hot reload
/// off the hot thread, `reload.rs`).
pub(crate) struct ModelUpdate {
    pub model: Model,
    pub compensator: TriadCompensator,
}

/// Readings beyond this magnitude are treated like NaN: no accelerometer measures them,
/// and the model's fifth powers would overflow.
pub const MAX_ABS_READING_G: f64 = 1e6;

/// What the compensator did, returned by [`run`](crate::run) when it stops (and printed
/// by `--json`).
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Time the hot loop ran.
    pub uptime_s: f64,
    /// The `{prefix}accel` stream (received, lost by `seq` and `first_sample_index`,
    /// out of order = dropped, restarts, resyncs (taken up again after out-of-order
    /// blocks: `vibro_service::continuity`), malformed = dropped).
    pub accel: StreamCounters,
    /// The `{prefix}estimate` stream.
    pub estimates: StreamCounters,
    /// Estimates mapped to the model.
    pub estimates_accepted: u64,
    /// Estimates that could not be used (non-finite values, counts out of range, ...).
    pub estimates_rejected: u64,
    /// Times the compensator's vibration was set (once per estimate used, and when the
    /// estimate went stale or came back).
    pub vibration_updates: u64,
    /// Tones left out because the model holds at most `estimate.max_tones`.
    pub tones_dropped: u64,
    /// Blocks published on `{prefix}compensated`.
    pub published: u64,
    /// Samples compensated (or set NaN for non-finite input).
    pub samples: u64,
    pub non_finite_samples: u64,
    /// Blocks published with `INPUT_GAP`.
    pub input_gap_blocks: u64,
    /// Blocks published with `VIBRATION_ESTIMATE_STALE`.
    pub stale_blocks: u64,
    /// Blocks published with `ESTIMATE_MISSING`.
    pub missing_blocks: u64,
    /// Blocks published with `ESTIMATE_FLAGGED`.
    pub flagged_estimate_blocks: u64,
    /// Blocks published with `ESTIMATE_AHEAD` (an estimate dated beyond the lead limit
    /// after the block: not used).
    pub ahead_blocks: u64,
    /// Blocks published with `RATE_CHANGE`.
    pub rate_change_blocks: u64,
    /// Blocks published with `TIME_JUMP`.
    pub time_jump_blocks: u64,
    /// Blocks published with `INPUT_SATURATED`.
    pub saturated_blocks: u64,
    /// `stage` of the configuration: `waveform` or `estimate`.
    pub stage: &'static str,
    /// Blocks published with `WAVEFORM` (the waveform stage made them).
    pub waveform_blocks: u64,
    /// Blocks published with `WAVEFORM_FALLBACK` (the estimate stage answered them).
    pub fallback_blocks: u64,
    /// The waveform stage's counts (`None` with `stage = "estimate"`).
    pub waveform: Option<crate::waveform::WaveformCounts>,
    /// Estimates for which the extended model's effects could not be evaluated (the
    /// base model was applied without them).
    pub model_effect_errors: u64,
    /// Blocks a subscriber's full buffer did not take (after the back-pressure timeout).
    pub undelivered: u64,
    /// Other publish failures (loan, send): those blocks were not published.
    pub publish_errors: u64,
    pub receive_errors: u64,
    /// Reloaded models taken by the hot loop.
    pub reloads_applied: u64,
    /// Reloads refused (invalid or unreadable files).
    pub reload_errors: u64,
    pub heartbeats: u64,
    /// Mode at the end.
    pub mode: CompensationMode,
    /// From receiving an accelerometer block to publishing its compensated block.
    pub latency: Quantiles,
}

impl Summary {
    /// The summary as one JSON object.
    pub fn to_json(&self) -> String {
        let mut o = JsonObject::new();
        o.str("service", "compensator")
            .f64("uptime_s", self.uptime_s)
            .str("mode", self.mode.as_str())
            .object("accel", self.accel.to_json())
            .object("estimates", self.estimates.to_json())
            .u64("estimates_accepted", self.estimates_accepted)
            .u64("estimates_rejected", self.estimates_rejected)
            .u64("vibration_updates", self.vibration_updates)
            .u64("tones_dropped", self.tones_dropped)
            .u64("published", self.published)
            .u64("samples", self.samples)
            .u64("non_finite_samples", self.non_finite_samples)
            .u64("input_gap_blocks", self.input_gap_blocks)
            .u64("stale_blocks", self.stale_blocks)
            .u64("missing_blocks", self.missing_blocks)
            .u64("flagged_estimate_blocks", self.flagged_estimate_blocks)
            .u64("ahead_blocks", self.ahead_blocks)
            .u64("rate_change_blocks", self.rate_change_blocks)
            .u64("time_jump_blocks", self.time_jump_blocks)
            .u64("saturated_blocks", self.saturated_blocks)
            .str("stage", self.stage)
            .u64("waveform_blocks", self.waveform_blocks)
            .u64("fallback_blocks", self.fallback_blocks)
            .u64("model_effect_errors", self.model_effect_errors)
            .u64("undelivered", self.undelivered)
            .u64("publish_errors", self.publish_errors)
            .u64("receive_errors", self.receive_errors)
            .u64("reloads_applied", self.reloads_applied)
            .u64("reload_errors", self.reload_errors)
            .u64("heartbeats", self.heartbeats)
            .object("latency", self.latency.to_json());
        if let Some(w) = &self.waveform {
            o.object("waveform", w.to_json());
        }
        o.finish()
    }
}

#[cfg(feature = "ipc")]
impl vibro_service::ServiceSummary for Summary {
    fn to_json(&self) -> String {
        Summary::to_json(self)
    }
}

/// Where compensated blocks go: the `{prefix}compensated` publisher in the service,
/// a vector in [`InProcess`].
pub trait OutputSink {
    /// Publishes one block, written in place by `fill` into a default message.
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut CompensatedBlock),
    ) -> vibro_ipc::Result<usize>;
}

#[cfg(feature = "ipc")]
impl OutputSink for StreamPublisher<CompensatedBlock> {
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut CompensatedBlock),
    ) -> vibro_ipc::Result<usize> {
        StreamPublisher::publish_with(self, fill)
    }
}

impl OutputSink for Vec<CompensatedBlock> {
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut CompensatedBlock),
    ) -> vibro_ipc::Result<usize> {
        let mut m = CompensatedBlock::default();
        fill(&mut m);
        self.push(m);
        Ok(1)
    }
}

/// The compensator's handling of each message without the transport: the same code
/// the service's hot loop runs (validation, continuity, staleness, the estimate in
/// use, flags, the compensation itself), fed in-process. A log replayed through the
/// service processes in lock-step gives bit-identical blocks (timestamps aside).
pub struct InProcess {
    st: Compensation,
}

impl InProcess {
    /// The compensator of `config`'s model (the transport settings are not used).
    pub fn new(config: &Config) -> anyhow::Result<Self> {
        Ok(Self {
            st: Compensation::new(config.model.clone(), config.model.compensator())?,
        })
    }

    /// An estimate arrives (the service takes every pending estimate before each
    /// accelerometer block).
    pub fn on_estimate(&mut self, estimate: &VibEstimate) {
        self.st.on_estimate(estimate);
        self.st.prepare();
    }

    /// An accelerometer block arrives at `recv_ns`: its compensated block (if it was
    /// not dropped) is appended to `out`, at once with `stage = "estimate"`, when the
    /// vibration samples cover it with `stage = "waveform"` (crate::waveform).
    pub fn on_accel(&mut self, block: &AccelBlock, recv_ns: u64, out: &mut Vec<CompensatedBlock>) {
        self.st.on_accel(block, recv_ns, out);
    }

    /// A vibration-sensor block arrives at `recv_ns` (the waveform stage's samples);
    /// the held blocks it covers are appended to `out`.
    pub fn on_vib(&mut self, block: &VibBlock, recv_ns: u64, out: &mut Vec<CompensatedBlock>) {
        self.st.on_vib(block, recv_ns, out);
    }

    /// The input has ended: every held block is appended to `out` (covered ones solved,
    /// the rest answered by the estimate stage).
    pub fn finish(&mut self, out: &mut Vec<CompensatedBlock>) {
        self.st.finish(out);
    }

    /// The counters so far.
    pub fn summary(&self) -> Summary {
        self.st.summary()
    }
}

/// The latest usable estimate, mapped to the units.
struct Latest {
    /// Counts the estimates accepted: tells two estimates apart even when a restarted
    /// estimator reuses a `seq`.
    generation: u64,
    estimate: VibEstimate,
    vibrations: UnitVibrations,
    /// The estimate carries quality flags (other than `TONE_FREE`), or its kurtosis
    /// had to be replaced.
    flagged: bool,
}

/// Where the accelerometer stream's last accepted block put its samples: the next
/// block's `t0_ns` is checked against it.
#[derive(Debug, Clone, Copy)]
struct AccelTiming {
    /// End of the block's last sample interval, `t0 + (count - 1) T` (one period
    /// before `t0` for an empty block), ns; wide, so that no input overflows it.
    last_end_ns: i128,
    /// Sample index after the block's last sample.
    next_index: u64,
}

impl AccelTiming {
    fn after(block: &AccelBlock) -> Self {
        let period = i128::from(block.sample_period_ns);
        Self {
            last_end_ns: i128::from(block.t0_ns) + (i128::from(block.count) - 1) * period,
            next_index: block
                .first_sample_index
                .wrapping_add(u64::from(block.count)),
        }
    }

    /// The block's `t0_ns` is more than half its sample period away from where this
    /// timing and the sample index put it: sample 0's interval starts where the last
    /// known sample's ended, one period per sample lost in between (at the block's
    /// own period, so a rate change alone is no jump).
    fn jumped(&self, block: &AccelBlock) -> bool {
        let period = i128::from(block.sample_period_ns);
        let skipped = i128::from(block.first_sample_index) - i128::from(self.next_index);
        let expected_ns = self.last_end_ns + (1 + skipped) * period;
        2 * (i128::from(block.t0_ns) - expected_ns).abs() > period
    }
}

/// Nodes of an [`EffectGrid`]: 17 nodes, at least 0.25 g apart (+-2 g around the
/// reading the grid was built at), wider when a block's readings swing further (a tone
/// the samples resolve, amplified by a mount): the grid spans 1.25 times the block's
/// swing, so that no reading is clamped to the grid's end.
const EFFECT_GRID_NODES: usize = 17;
const EFFECT_GRID_STEP_G: f64 = 0.25;

/// One unit's extended-model correction (the effects' VE change, docs/lab.md) as a
/// function of its flight acceleration `a(1)`, tabulated when the vibration changes
/// (per estimate, or when the reading leaves the grid): the effects' mean formulas
/// run quadratures and build exact-model tables, far too slow per sample. Per sample,
/// a cubic interpolation; beyond the grid, the end value.
#[derive(Debug, Clone, Copy)]
struct EffectGrid {
    a0_g: f64,
    step_g: f64,
    ve_g: [f64; EFFECT_GRID_NODES],
}

/// The span a grid is built for: its centre and the half-width its readings need, g.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct GridSpan {
    center_g: f64,
    half_width_g: f64,
}

impl GridSpan {
    /// The node spacing: 0.25 g, or wider so that the inner nodes span 1.25 times the
    /// half-width.
    fn step_g(&self) -> f64 {
        let inner = (EFFECT_GRID_NODES / 2 - 1) as f64;
        EFFECT_GRID_STEP_G.max(1.25 * self.half_width_g / inner)
    }
}

/// A single tone's part of a unit's effects, taken at each sample's phase: inside one
/// output interval a tone deviates from its mean by a variance that depends on where in
/// its cycle the interval falls (least at the tone's peaks, where the reading `a(1)`
/// carries most of it), so the effects' tone part, tabulated at the mean variance, is
/// scaled per sample by [`ToneWithin`]. Without it a quartic term's cross part
/// `6 k4 E[s^2 w^2]` (`s` the resolved tone in `a(1)`, `w` its deviation inside the
/// interval) is taken as `6 k4 E[s^2] E[w^2]`, twice the truth for a slow tone; a
/// mount that triples a tone makes that hundreds of ug (docs/services.md).
#[derive(Debug, Clone, Copy)]
struct ToneSplit {
    /// The effects with the tone removed (the random part alone).
    without: EffectGrid,
    freq_hz: f64,
    /// The tone's phase on the unit's IA after the effects on the vibration path (a
    /// mount turns it), at the estimate's `center_ns`.
    phase_rad: f64,
    /// Its amplitude there inside one output interval (the mean share), g.
    amplitude_within_g: f64,
    center_ns: u64,
}

/// One unit's extended-model correction: the effects' grid, and for a single tone its
/// split ([`ToneSplit`]).
#[derive(Debug, Clone, Copy)]
struct UnitEffects {
    full: EffectGrid,
    tone: Option<ToneSplit>,
}

impl UnitEffects {
    /// The correction of a sample read at `a_g`, its tone's part times `tone_factor`
    /// ([`ToneWithin`] at the sample's phase; the same factor stage (19) takes,
    /// computed once per sample).
    fn at(&self, a_g: f64, tone_factor: f64) -> f64 {
        let full = self.full.at(a_g);
        match &self.tone {
            None => full,
            Some(t) => {
                let without = t.without.at(a_g);
                without + tone_factor * (full - without)
            }
        }
    }
}

/// [`ToneWithin`]'s factor at one phase.
#[cfg(test)]
fn tone_within_factor(theta: f64, omega_t: f64) -> f64 {
    ToneWithin::new(omega_t).at(theta)
}

/// For a tone `sin(theta + w tau)` over an interval `tau` in `[-T/2, T/2]` (`theta` its
/// phase at the middle, `omega_t = w T`): the variance of its deviation from the
/// interval's mean, `1/2 - 1/2 cos(2 theta) sinc(w T) - sin^2(theta) sinc^2(w T / 2)`,
/// over its mean over `theta`, `1/2 (1 - sinc^2(w T / 2))` (crate::interval's
/// `within_fraction`). 1 where the mean vanishes.
///
/// The parts that do not depend on the phase are taken once per block: with
/// `sin^2(theta) = (1 - cos(2 theta))/2` the factor is
/// `1 - cos(2 theta) (sinc(w T) - s^2)/(1 - s^2)`, `s = sinc(w T / 2)`, one cosine per
/// sample where it took four sines and cosines.
#[derive(Debug, Clone, Copy)]
struct ToneWithin {
    /// `(sinc(w T) - s^2)/(1 - s^2)`; `None` where the mean vanishes (factor 1).
    swing: Option<f64>,
}

impl ToneWithin {
    fn new(omega_t: f64) -> Self {
        let sinc = |x: f64| if x.abs() < 1e-9 { 1.0 } else { x.sin() / x };
        let half = sinc(0.5 * omega_t);
        let mean = 0.5 * (1.0 - half * half);
        let swing =
            (!mean.is_nan() && mean > 1e-12).then(|| 0.5 * (sinc(omega_t) - half * half) / mean);
        Self { swing }
    }

    fn at(&self, theta: f64) -> f64 {
        match self.swing {
            Some(swing) => (1.0 - (2.0 * theta).cos() * swing).max(0.0),
            None => 1.0,
        }
    }
}

/// Phases a [`ToneMoments`] table holds over one period.
const MOMENT_PHASES: usize = 256;
/// Midpoints over one output interval for a [`ToneMoments`] table's moments.
const MOMENT_POINTS: usize = 128;

/// A single tone's third, fourth and fifth central moments inside one output interval,
/// per phase: `sin(theta + w tau)`, `tau` over `[-T/2, T/2]`, about its mean over the
/// interval (midpoint rule over [`MOMENT_POINTS`], [`MOMENT_PHASES`] phases, linear in
/// between), for [`higher_moments_g`].
#[derive(Debug, Clone, Copy)]
struct ToneMoments {
    omega_t: f64,
    /// The tone's amplitude inside the interval over its whole amplitude,
    /// `sqrt(1 - sinc^2(w T / 2))` (`crate::interval`'s share of its mean square).
    share: f64,
    mu: [[f64; 3]; MOMENT_PHASES + 1],
}

impl ToneMoments {
    fn new(omega_t: f64) -> Self {
        // The tone at point `u` and phase `theta` by angle addition,
        // `sin(theta + w T u) = sin(theta) cos(w T u) + cos(theta) sin(w T u)`: the same
        // moments as `sin(theta + w T u)` point by point (to rounding, ~1e-16), with one
        // `sin_cos` per point and per phase instead of two `sin` per point and phase
        // (257 x 128 x 2 per table, rebuilt per estimate, was the hot path's largest
        // cost).
        let mut point_sin = [0.0; MOMENT_POINTS];
        let mut point_cos = [0.0; MOMENT_POINTS];
        for (i, (s, c)) in point_sin.iter_mut().zip(point_cos.iter_mut()).enumerate() {
            let u = (i as f64 + 0.5) / MOMENT_POINTS as f64 - 0.5;
            (*s, *c) = (omega_t * u).sin_cos();
        }
        let mut x = [0.0; MOMENT_POINTS];
        let mut mu = [[0.0; 3]; MOMENT_PHASES + 1];
        // Half a period on, the tone is its negative: the odd moments change sign and
        // the fourth stays (below). Only the first half and its end are summed.
        let half = MOMENT_PHASES / 2;
        for (j, m) in mu.iter_mut().enumerate().take(half + 1) {
            let theta = std::f64::consts::TAU * j as f64 / MOMENT_PHASES as f64;
            let (sin_theta, cos_theta) = theta.sin_cos();
            for ((x, s), c) in x.iter_mut().zip(&point_sin).zip(&point_cos) {
                *x = sin_theta * c + cos_theta * s;
            }
            let mean = x.iter().sum::<f64>() / MOMENT_POINTS as f64;
            for &xi in &x {
                let d = xi - mean;
                let d3 = d * d * d;
                m[0] += d3;
                m[1] += d3 * d;
                m[2] += d3 * d * d;
            }
            for v in m.iter_mut() {
                *v /= MOMENT_POINTS as f64;
            }
        }
        for j in half + 1..=MOMENT_PHASES {
            let [m3, m4, m5] = mu[j - half];
            mu[j] = [-m3, m4, -m5];
        }
        Self {
            omega_t,
            // The inverse of the reduction the estimate's tone took
            // (`within_output_interval`): `f T = w T / 2 pi`.
            share: within_fraction(omega_t / std::f64::consts::TAU, 1.0).sqrt(),
            mu,
        }
    }

    /// The moments at phase `theta`, rad.
    fn at(&self, theta: f64) -> [f64; 3] {
        let x =
            theta.rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU * MOMENT_PHASES as f64;
        let j = (x.floor() as usize).min(MOMENT_PHASES - 1);
        let t = x - j as f64;
        let (a, b) = (self.mu[j], self.mu[j + 1]);
        [0, 1, 2].map(|k| a[k] + t * (b[k] - a[k]))
    }
}

/// What stage (19) leaves of a single tone's part inside an output interval beyond
/// its variance, g: the exact model takes the tone inside the interval as a whole
/// sinusoid of the interval's mean variance (`amplitude_within_g`), scaled per sample
/// by the variance at the sample's phase ([`ToneWithin`], `factor`); a
/// reading's passport polynomial around it (`reading_g`, MODEL.md (1): `k2..k5`)
/// also feels the third, fourth and fifth moments of the tone's deviation inside the
/// interval, which depend on the phase otherwise. The difference:
/// `f'''/6 A^3 mu3 + f''''/24 (A^4 mu4 - factor 3/8 A_w^4) + k5 A^5 mu5`, `A` the
/// tone's whole amplitude, `mu` [`ToneMoments`] at the phase. (Independent check in
/// Python over a 5.4 g, 150 Hz tone read at 800 Hz, AL-15: the variance alone left
/// 41.9 ug on average and 156 ug RMS per sample; with these moments 4.5 ug RMS.)
fn higher_moments_g(
    k: &[f64; 6],
    reading_g: f64,
    amplitude_g: f64,
    amplitude_within_g: f64,
    factor: f64,
    mu: [f64; 3],
) -> f64 {
    let r = reading_g;
    let f3 = 6.0 * k[3] + 24.0 * k[4] * r + 60.0 * k[5] * r * r;
    let f4 = 24.0 * k[4] + 120.0 * k[5] * r;
    let a = amplitude_g;
    let a2 = a * a;
    let aw2 = amplitude_within_g * amplitude_within_g;
    f3 / 6.0 * a2 * a * mu[0]
        + f4 / 24.0 * (a2 * a2 * mu[1] - factor * 0.375 * aw2 * aw2)
        + k[5] * a2 * a2 * a * mu[2]
}

impl EffectGrid {
    /// The grid over `span`, from the VE change at each node.
    fn build(
        span: GridSpan,
        mut ve_at: impl FnMut(f64) -> vibro_effects::Result<f64>,
    ) -> vibro_effects::Result<Self> {
        let step_g = span.step_g();
        let a0_g = span.center_g - step_g * (EFFECT_GRID_NODES / 2) as f64;
        let mut ve_g = [0.0; EFFECT_GRID_NODES];
        for (j, v) in ve_g.iter_mut().enumerate() {
            *v = ve_at(a0_g + step_g * j as f64)?;
        }
        Ok(Self { a0_g, step_g, ve_g })
    }

    fn covers(&self, a_g: f64) -> bool {
        let x = (a_g - self.a0_g) / self.step_g;
        x >= 1.0 && x <= (EFFECT_GRID_NODES - 2) as f64
    }

    /// Cubic (4-point Lagrange) interpolation at `a_g`, clamped to the grid: exact for
    /// cubics; for a smooth `E`, error at most `|E''''| h^4 9/384` (h the spacing).
    fn at(&self, a_g: f64) -> f64 {
        let last = (EFFECT_GRID_NODES - 1) as f64;
        let x = ((a_g - self.a0_g) / self.step_g).clamp(0.0, last);
        // Nodes j-1, j, j+1, j+2 around x, kept inside the grid.
        let j = (x.floor() as usize).clamp(1, EFFECT_GRID_NODES - 3);
        let t = x - j as f64;
        let y = |k: usize| self.ve_g[j + k - 1];
        let (p0, p1, p2, p3) = (y(0), y(1), y(2), y(3));
        -t * (t - 1.0) * (t - 2.0) / 6.0 * p0 + (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0 * p1
            - (t + 1.0) * t * (t - 2.0) / 2.0 * p2
            + (t + 1.0) * t * (t - 1.0) / 6.0 * p3
    }
}

/// The hot loop's state. Nothing in it allocates per block or per sample.
pub(crate) struct Compensation {
    /// The waveform stage and the blocks it holds (`stage = "waveform"`).
    pub(crate) waveform: Option<WaveformPath>,
    model: Model,
    compensator: TriadCompensator,
    /// A clone of `compensator` holding the latest estimate's vibration, built when the
    /// estimate arrives ([`Self::prepare`]) so that the block that needs it swaps it in
    /// instead of building the exact model's tables on its own latency.
    prepared: TriadCompensator,
    /// `generation` of the estimate `prepared` holds; `None`: nothing usable.
    prepared_for: Option<u64>,
    k1_v_per_g: [f64; 3],
    /// The extended model's correction per unit, for the vibration the compensator
    /// holds; `None` without `model = ...` or without vibration.
    effect_grids: Option<[UnitEffects; 3]>,
    /// The readings' span (U/K1) of the block the grids were wanted for, per unit.
    effect_span: [GridSpan; 3],
    /// Per unit, a single tone's higher moments inside the output interval
    /// ([`ToneMoments`], [`higher_moments_g`]), for its frequency and interval.
    tone_moments: [Option<ToneMoments>; 3],
    /// The spectrum behind the estimates' band powers, for the effects' mean formulas
    /// (the lab's reading of an estimate, `vibro_effects::spectrum`).
    spectrum: SpectrumSolver,
    latest: Option<Latest>,
    /// `generation` of the estimate whose vibration the compensator holds; `None`: no
    /// vibration.
    applied: Option<u64>,
    /// The accelerometer stream's sample period (each output is the mean over it), s;
    /// 0 before the first block.
    output_interval_s: f64,
    /// The accelerometer stream's `sample_period_ns`; `None` before the first block.
    period_ns: Option<u64>,
    /// The last accepted block's timing; `None` before the first block.
    timing: Option<AccelTiming>,
    accel_continuity: Continuity,
    estimate_continuity: Continuity,
    /// Out-of-order messages and resyncs of each input, told at a bounded rate (the
    /// service's summary period tells the rest).
    pub(crate) accel_disorder: DisorderLog,
    pub(crate) estimate_disorder: DisorderLog,
    /// A dropped (malformed) block: the next output is flagged `INPUT_GAP`.
    pending_gap: bool,
    rejecting: bool,
    out_seq: u64,
    pub(crate) latency: Latency,
    pub(crate) s: Summary,
}

impl Compensation {
    pub(crate) fn new(model: Model, compensator: TriadCompensator) -> anyhow::Result<Self> {
        let mode = model.wire_mode();
        let stage = model.waveform.stage.name();
        let waveform = WaveformPath::new(&model).map_err(anyhow::Error::msg)?;
        Ok(Compensation {
            waveform,
            k1_v_per_g: model.k1_v_per_g(),
            effect_grids: None,
            effect_span: [GridSpan::default(); 3],
            tone_moments: [None; 3],
            spectrum: SpectrumSolver::from_estimates(),
            model,
            prepared: compensator.clone(),
            prepared_for: None,
            compensator,
            latest: None,
            applied: None,
            output_interval_s: 0.0,
            period_ns: None,
            timing: None,
            accel_continuity: Continuity::new(),
            estimate_continuity: Continuity::new(),
            accel_disorder: DisorderLog::default(),
            estimate_disorder: DisorderLog::default(),
            pending_gap: false,
            rejecting: false,
            out_seq: 0,
            latency: Latency::new()?,
            s: Summary {
                uptime_s: 0.0,
                accel: StreamCounters::default(),
                estimates: StreamCounters::default(),
                estimates_accepted: 0,
                estimates_rejected: 0,
                vibration_updates: 0,
                tones_dropped: 0,
                published: 0,
                samples: 0,
                non_finite_samples: 0,
                input_gap_blocks: 0,
                stale_blocks: 0,
                missing_blocks: 0,
                flagged_estimate_blocks: 0,
                ahead_blocks: 0,
                rate_change_blocks: 0,
                time_jump_blocks: 0,
                saturated_blocks: 0,
                stage,
                waveform_blocks: 0,
                fallback_blocks: 0,
                waveform: None,
                model_effect_errors: 0,
                undelivered: 0,
                publish_errors: 0,
                receive_errors: 0,
                reloads_applied: 0,
                reload_errors: 0,
                heartbeats: 0,
                mode,
                latency: Quantiles::default(),
            },
        })
    }

    /// Readings held for their vibration samples.
    pub(crate) fn held_readings(&self) -> u64 {
        self.waveform.as_ref().map_or(0, |w| w.held_readings())
    }

    /// The counters so far, with the waveform stage's.
    pub(crate) fn summary(&self) -> Summary {
        let mut s = self.s.clone();
        s.waveform = self.waveform.as_ref().map(|w| w.counts());
        s
    }

    pub(crate) fn take_update(&mut self, update: ModelUpdate) {
        // The stage (waveform or estimate) is kept until a restart; the waveform stage
        // takes the new model's passports, effects and sensor chain.
        let mut model = update.model;
        if model.waveform.stage != self.model.waveform.stage {
            warn!(
                running = self.model.waveform.stage.name(),
                reloaded = model.waveform.stage.name(),
                "a change of stage takes effect at the next start; the running stage stays"
            );
            model.waveform.stage = self.model.waveform.stage;
        }
        if let Some(w) = &mut self.waveform {
            match WaveformPath::new(&model) {
                Ok(Some(new)) => w.replace_stage(new),
                Ok(None) => {}
                Err(e) => {
                    warn!("the reloaded model's waveform stage: {e}; keeping the running one")
                }
            }
        }
        self.model = model;
        self.compensator = update.compensator;
        // Allocates, once per reload (not per block).
        self.prepared = self.compensator.clone();
        self.prepared_for = None;
        self.k1_v_per_g = self.model.k1_v_per_g();
        self.remap_latest();
        self.s.reloads_applied += 1;
        self.s.mode = self.model.wire_mode();
        info!(
            mode = self.model.mode.name(),
            "hot loop took the reloaded model"
        );
    }

    /// The averaging interval the estimate is reduced to: the output interval, or 0
    /// (the whole vibration) when `[estimate] within_output_interval = false`.
    fn interval_s(&self) -> f64 {
        if self.model.estimate.within_output_interval {
            self.output_interval_s
        } else {
            0.0
        }
    }

    /// Maps the latest estimate again (after a model or output-rate change); the
    /// compensator takes it at the next block.
    fn remap_latest(&mut self) {
        self.applied = None;
        self.prepared_for = None;
        let interval_s = self.interval_s();
        if let Some(l) = &mut self.latest {
            let within = within_output_interval(&l.estimate, interval_s);
            match unit_vibrations(&within, &self.model.triad.axes, &self.model.estimate) {
                Ok(v) => l.vibrations = v,
                Err(e) => {
                    warn!("{e}: not usable");
                    self.latest = None;
                }
            }
        }
    }

    pub(crate) fn on_estimate(&mut self, e: &VibEstimate) {
        self.s.estimates.received += 1;
        if let Err(err) = e.validate() {
            if count_first(&mut self.s.estimates.malformed) {
                warn!(seq = e.seq, "dropping a malformed estimate: {err}");
            }
            return;
        }
        let arrival = self.estimate_continuity.check_seq(e.seq);
        self.s.estimates.record(&arrival);
        self.estimate_disorder.arrival(
            "vibration estimate",
            &arrival,
            e.seq,
            self.estimate_continuity.last_seq(),
            &self.s.estimates,
        );
        if !arrival.accepted {
            return;
        }
        // The vibration inside one output interval: what the samples do not resolve
        // (crate::interval; unknown before the first block: the whole vibration).
        let within = within_output_interval(e, self.interval_s());
        match unit_vibrations(&within, &self.model.triad.axes, &self.model.estimate) {
            Ok(v) => {
                let quality = e.flags & estimate_flags::ALL & !estimate_flags::TONE_FREE;
                self.s.estimates_accepted += 1;
                self.s.tones_dropped += u64::from(v.tones_dropped);
                self.prepared_for = None;
                self.latest = Some(Latest {
                    generation: self.s.estimates_accepted,
                    estimate: *e,
                    vibrations: v,
                    flagged: quality != 0 || v.kurtosis_defaulted,
                });
                if self.rejecting {
                    info!(seq = e.seq, "vibration estimates usable again");
                    self.rejecting = false;
                }
            }
            Err(err) => {
                self.s.estimates_rejected += 1;
                if !self.rejecting {
                    warn!("{err}; keeping the previous estimate while it is not stale");
                    self.rejecting = true;
                }
            }
        }
    }

    /// Builds the latest estimate's vibration into `prepared`, off the blocks' path:
    /// called once the pending estimates are taken (not per estimate, so a burst
    /// builds once). The extended model's grids depend on the block's reading, so with
    /// `model = ...` the tables are still built by the block ([`Self::apply`]). A
    /// vibration the compensator refuses is left to `apply`, which reports it.
    ///
    /// Not with the waveform stage: there the estimate stage's answer is made when a block
    /// arrives and held with it, so its tables are built on that block's arrival, which
    /// nothing waits for; built here, in the wake-up an estimate arrives in, they would
    /// hold up the release of a block whose last samples arrive meanwhile (1 to 3 ms,
    /// four times a second: the release's p99).
    pub(crate) fn prepare(&mut self) {
        if self.model.effects.is_some() || self.waveform.is_some() {
            return;
        }
        let Some(l) = &self.latest else {
            return;
        };
        if self.prepared_for == Some(l.generation) || self.applied == Some(l.generation) {
            return;
        }
        let ok = (0..3).all(|i| {
            self.prepared
                .set_vibration(i, &l.vibrations.units[i])
                .is_ok()
        });
        self.prepared_for = ok.then_some(l.generation);
    }

    /// Gives the compensator the vibration of estimate generation `want` (or none). Per estimate,
    /// never per sample: `set_vibration` rebuilds the exact model's tables (~1 ms).
    fn apply(&mut self, want: Option<u64>) -> bool {
        self.s.vibration_updates += 1;
        let interval_s = self.interval_s();
        self.effect_grids = None;
        let ok = match (want, &self.latest) {
            (Some(g), Some(_)) if self.model.effects.is_none() && self.prepared_for == Some(g) => {
                self.compensator.swap_units(&mut self.prepared);
                self.prepared_for = None;
                true
            }
            (Some(_), Some(l)) => match &self.model.effects {
                None => (0..3).all(|i| {
                    self.compensator
                        .set_vibration(i, &l.vibrations.units[i])
                        .is_ok()
                }),
                Some((_, lab)) => {
                    let units = l.vibrations.units;
                    let spectra = unit_spectra(
                        &l.estimate,
                        &mut self.spectrum,
                        &self.model.triad.axes,
                        interval_s,
                    );
                    match effect_grids(
                        lab,
                        &self.model.triad.passports,
                        &units,
                        &spectra,
                        self.effect_span,
                        l.estimate.center_ns,
                        interval_s > 0.0,
                    ) {
                        Ok((grids, true_vibrations)) => {
                            self.effect_grids = Some(grids);
                            (0..3).all(|i| {
                                self.compensator
                                    .set_vibration(i, &true_vibrations[i])
                                    .is_ok()
                            })
                        }
                        Err(e) => {
                            // The base model still applies: compensate without the
                            // effects (no MODEL_EFFECTS) rather than not at all.
                            if count_first(&mut self.s.model_effect_errors) {
                                warn!("the extended model cannot evaluate its effects ({e}); compensating with the base model, further failures counted");
                            }
                            (0..3).all(|i| self.compensator.set_vibration(i, &units[i]).is_ok())
                        }
                    }
                }
            },
            _ => true,
        };
        if want.is_none() || !ok {
            self.effect_grids = None;
            for i in 0..3 {
                // `Vibration::none()` always validates.
                let _ = self.compensator.set_vibration(i, &Vibration::none());
            }
        }
        self.applied = if ok { want } else { None };
        ok
    }

    /// The extended model's grids again, over `effect_span`, for the vibration
    /// the compensator holds; without grids (base model) when they cannot be built.
    fn retabulate(&mut self) {
        let interval_s = self.interval_s();
        let (Some((_, lab)), Some(l)) = (&self.model.effects, &self.latest) else {
            return;
        };
        let spectra = unit_spectra(
            &l.estimate,
            &mut self.spectrum,
            &self.model.triad.axes,
            interval_s,
        );
        let passports = &self.model.triad.passports;
        match effect_grids(
            lab,
            passports,
            &l.vibrations.units,
            &spectra,
            self.effect_span,
            l.estimate.center_ns,
            interval_s > 0.0,
        ) {
            Ok((grids, _)) => self.effect_grids = Some(grids),
            Err(e) => {
                self.effect_grids = None;
                if count_first(&mut self.s.model_effect_errors) {
                    warn!("the extended model cannot evaluate its effects ({e}); compensating with the base model, further failures counted");
                }
            }
        }
    }

    pub(crate) fn on_accel(&mut self, block: &AccelBlock, recv_ns: u64, out: &mut impl OutputSink) {
        self.s.accel.received += 1;
        if let Err(e) = block.validate() {
            if count_first(&mut self.s.accel.malformed) {
                warn!(
                    seq = block.seq,
                    "dropping a malformed accelerometer block: {e}"
                );
            }
            self.pending_gap = true;
            return;
        }
        let arrival = self.accel_continuity.check(
            block.seq,
            block.first_sample_index,
            u64::from(block.count),
        );
        self.s.accel.record(&arrival);
        // At a bounded rate: the first at once, the rest per summary period (a resync
        // after 3 dropped blocks, `vibro_service::continuity`, ends any run of them).
        self.accel_disorder.arrival(
            "accelerometer",
            &arrival,
            block.seq,
            self.accel_continuity.last_seq(),
            &self.s.accel,
        );
        if !arrival.accepted {
            return;
        }
        let count = block.count as u64;
        let end_ns = block.t0_ns.saturating_add(
            block
                .sample_period_ns
                .saturating_mul(count.saturating_sub(1)),
        );
        let interval_s = block.sample_period_ns as f64 * 1e-9;
        if interval_s != self.output_interval_s {
            // A new output rate changes what the samples resolve: map the latest
            // estimate again (once per rate change, not per block).
            self.output_interval_s = interval_s;
            self.remap_latest();
        }
        let rate_change = self.period_ns.is_some_and(|p| p != block.sample_period_ns);
        self.period_ns = Some(block.sample_period_ns);
        if rate_change {
            // The stream was reconfigured: start the kernel afresh, so that what
            // follows is compensated as by a compensator started on the new rate.
            self.compensator.reset_tracking();
        }
        // After a restart the stream's earlier timing no longer applies.
        let time_jump =
            !arrival.restarted && self.timing.is_some_and(|timing| timing.jumped(block));
        self.timing = Some(AccelTiming::after(block));
        if arrival.restarted {
            // Blocks held from before the restart are decided now (what covers them
            // has come or never will), ahead of the new stream's.
            self.finish(out);
            // The producer started again (a new replay, a restarted rig), or the
            // stream was taken up again after out-of-order blocks (a resync): the stream
            // history no longer applies, and an estimate dated after this block
            // belongs to the previous run.
            self.compensator.reset_tracking();
            if self
                .latest
                .as_ref()
                .is_some_and(|l| l.estimate.end_ns > end_ns)
            {
                self.latest = None;
            }
        }
        let mut flags = 0u32;
        if arrival.gap() || self.pending_gap || block.flags & accel_flags::GAP_BEFORE != 0 {
            flags |= cf::INPUT_GAP;
        }
        self.pending_gap = false;
        if block.flags & accel_flags::SATURATED != 0 {
            // Which readings are clipped the block does not say: all are compensated
            // as read, and the output carries the producer's warning.
            flags |= cf::INPUT_SATURATED;
        }
        if rate_change {
            flags |= cf::RATE_CHANGE;
        }
        if time_jump {
            flags |= cf::TIME_JUMP;
        }

        // Staleness: the estimate's window end against the end of the block's last
        // sample interval (both on the producers' clock, taken as given even after a
        // TIME_JUMP). Too old: stale. Too new (the clocks disagree, or the block was
        // dated back): not usable either, ESTIMATE_AHEAD.
        let (mut want, mut estimate_seq, mut age_ns) = (None, 0u64, 0i64);
        // `want`: the estimate whose vibration this block needs; `None`: main error only.
        match &self.latest {
            None => flags |= cf::ESTIMATE_MISSING | cf::MAIN_ONLY,
            Some(l) => {
                let age = i128::from(end_ns) - i128::from(l.estimate.end_ns);
                age_ns = age.clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64;
                estimate_seq = l.estimate.seq;
                if age > i128::from(self.model.max_estimate_age_ns) {
                    flags |= cf::VIBRATION_ESTIMATE_STALE | cf::MAIN_ONLY;
                } else if age < -i128::from(self.model.max_estimate_lead_ns) {
                    // Kept: the stream may catch up with it.
                    flags |= cf::ESTIMATE_AHEAD | cf::MAIN_ONLY;
                } else {
                    want = Some(l.generation);
                    if l.flagged {
                        flags |= cf::ESTIMATE_FLAGGED;
                    }
                }
            }
        }
        if self.model.effects.is_some() && block.count > 0 {
            // The block's readings (U/K1) per unit: their span (finite ones only).
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for u_v in block.samples_v() {
                for i in 0..3 {
                    let g = u_v[i] / self.k1_v_per_g[i];
                    if g.is_finite() && g.abs() <= MAX_ABS_READING_G {
                        lo[i] = lo[i].min(g);
                        hi[i] = hi[i].max(g);
                    }
                }
            }
            let known = (0..3).all(|i| lo[i] <= hi[i]);
            let outside = known
                && self.effect_grids.is_some_and(|g| {
                    (0..3).any(|i| !(g[i].full.covers(lo[i]) && g[i].full.covers(hi[i])))
                });
            if known && (want != self.applied || outside) {
                self.effect_span = std::array::from_fn(|i| GridSpan {
                    center_g: 0.5 * (lo[i] + hi[i]),
                    half_width_g: 0.5 * (hi[i] - lo[i]),
                });
            }
            if outside && want == self.applied {
                // The flight acceleration left the grid: tabulate again around it (the
                // compensator's vibration stays as it is).
                self.retabulate();
            }
        }
        if want != self.applied && !self.apply(want) {
            warn!(
                seq = estimate_seq,
                "the compensator refused the estimate's vibration; main error only"
            );
            self.latest = None;
            self.s.estimates_rejected += 1;
            flags = (flags & !cf::ESTIMATE_FLAGGED) | cf::ESTIMATE_MISSING | cf::MAIN_ONLY;
            (estimate_seq, age_ns) = (0, 0);
        }
        let main_only = flags & cf::MAIN_ONLY != 0;

        let seq = self.out_seq;
        self.out_seq += 1;
        let mode = self.model.wire_mode().code();
        let k1 = self.k1_v_per_g;
        let grids = if main_only { None } else { self.effect_grids };
        if grids.is_some() {
            flags |= cf::MODEL_EFFECTS;
        }
        // Stage (19) of a single tone inside the output intervals, at each sample's
        // phase: the tone's phase on each unit's IA (through the extended model's path
        // effects when it has them, `ToneSplit`) and its estimate's centre.
        let within = !main_only && self.interval_s() > 0.0;
        let det_tone: [Option<(f64, f64, f64, u64)>; 3] = std::array::from_fn(|i| {
            if !within {
                return None;
            }
            if let Some(t) = grids.as_ref().and_then(|g| g[i].tone) {
                return Some((t.freq_hz, t.phase_rad, t.amplitude_within_g, t.center_ns));
            }
            let l = self.latest.as_ref()?;
            match l.vibrations.units[i].tones() {
                [t] => Some((
                    t.freq_hz,
                    t.phase_rad[2],
                    t.amplitude_g[2],
                    l.estimate.center_ns,
                )),
                _ => None,
            }
        });
        // The tone's higher moments inside the interval (exact mode: the paper's
        // formulas stay as published), per unit, tabulated when the tone's frequency
        // or the interval changes (about 0.3 ms: once per estimate at most).
        let interval_s = block.sample_period_ns as f64 * 1e-9;
        let exact = self.model.wire_mode() == CompensationMode::Exact;
        // Per unit, the tone's within-interval factor's parts that hold for the whole
        // block (`ToneWithin`), and its moments' table.
        let mut tone_within = [None; 3];
        for (i, t) in det_tone.iter().enumerate() {
            let omega_t = t.map(|(f_hz, ..)| std::f64::consts::TAU * f_hz * interval_s);
            tone_within[i] = omega_t.map(ToneWithin::new);
            match omega_t {
                Some(omega_t) if exact => {
                    if self.tone_moments[i]
                        .as_ref()
                        .is_none_or(|m| m.omega_t != omega_t)
                    {
                        // Units that see the same tone share its table (a copy: the
                        // same numbers as building it again).
                        let shared = self
                            .tone_moments
                            .iter()
                            .flatten()
                            .find(|m| m.omega_t == omega_t)
                            .copied();
                        self.tone_moments[i] =
                            Some(shared.unwrap_or_else(|| ToneMoments::new(omega_t)));
                    }
                }
                _ => self.tone_moments[i] = None,
            }
        }
        let tone_moments = &self.tone_moments;
        let passports = &self.model.triad.passports;
        let compensator = &mut self.compensator;
        let mid_ns = |b: &AccelBlock, k: usize| {
            b.t0_ns
                .saturating_add((k as u64).saturating_mul(b.sample_period_ns))
                .saturating_sub(b.sample_period_ns / 2)
        };
        let mut non_finite = 0u64;
        let mut answer = CompensatedBlock::default();
        {
            let m = &mut answer;
            m.seq = seq;
            m.input_seq = block.seq;
            m.first_sample_index = block.first_sample_index;
            m.t0_ns = block.t0_ns;
            m.sample_period_ns = block.sample_period_ns;
            m.estimate_seq = estimate_seq;
            m.input_publish_ns = block.publish_ns;
            m.recv_ns = recv_ns;
            m.estimate_age_ns = age_ns;
            m.count = block.count;
            m.source_id = block.source_id;
            m.mode = mode;
            for (k, u_v) in block.samples_v().iter().enumerate() {
                // Readings in g: U / K1 per unit (MODEL.md section 2).
                let readings_g = [u_v[0] / k1[0], u_v[1] / k1[1], u_v[2] / k1[2]];
                if !readings_g.iter().all(|r| r.abs() <= MAX_ABS_READING_G) {
                    // The units are coupled through the cross terms: a bad reading
                    // spoils the whole triad sample.
                    non_finite += 1;
                    for a in m.stages_mut() {
                        a[k] = [f64::NAN; 3];
                    }
                    continue;
                }
                let stages = compensator.compensate(readings_g);
                for (i, s) in stages.units.iter().enumerate() {
                    m.a1_g[k][i] = s.a1_g;
                    m.a2_g[k][i] = s.a2_g;
                    m.main_g[k][i] = s.main_g;
                    if main_only {
                        // No vibration model: (19) and (20) remove nothing, exactly.
                        m.a3_g[k][i] = s.a2_g;
                        m.a4_g[k][i] = s.a2_g;
                    } else {
                        // A single tone's part inside the interval at the sample's
                        // phase ([`ToneWithin`]), for stage (19) and the effects'
                        // tone part alike.
                        let (tone_factor, higher_g) = match (det_tone[i], tone_within[i]) {
                            (
                                Some((f_hz, phase_rad, amplitude_within_g, center_ns)),
                                Some(within),
                            ) => {
                                let dt_s = (i128::from(mid_ns(block, k)) - i128::from(center_ns))
                                    as f64
                                    * 1e-9;
                                let w = 2.0 * std::f64::consts::PI * f_hz;
                                let theta = w * dt_s + phase_rad;
                                let factor = within.at(theta);
                                let higher = match &tone_moments[i] {
                                    Some(m) if m.share > 1e-6 => higher_moments_g(
                                        &passports[i].k,
                                        s.a1_g,
                                        amplitude_within_g / m.share,
                                        amplitude_within_g,
                                        factor,
                                        m.at(theta),
                                    ),
                                    _ => 0.0,
                                };
                                (factor, higher)
                            }
                            _ => (1.0, 0.0),
                        };
                        // The extended model's effects at a(1), removed after (20)
                        // and carried in `rand` so that a4 = a3 - rand (first order:
                        // the effects' VE changes slowly with the acceleration).
                        let effects_g =
                            grids.as_ref().map_or(0.0, |g| g[i].at(s.a1_g, tone_factor));
                        let det = s.det_g * tone_factor + higher_g;
                        m.a3_g[k][i] = s.a2_g - det;
                        m.a4_g[k][i] = s.a2_g - det - s.rand_g - effects_g;
                        m.det_g[k][i] = det;
                        m.rand_g[k][i] = s.rand_g + effects_g;
                    }
                }
            }
            m.flags = if non_finite > 0 {
                flags | cf::NON_FINITE_INPUT
            } else {
                flags
            };
        }
        self.s.samples += count;
        self.s.non_finite_samples += non_finite;
        let held = match &mut self.waveform {
            Some(w) => {
                // Held until the samples cover it (crate::waveform), with the readings.
                let mut readings_g = [[f64::NAN; 3]; vibro_msgs::ACCEL_BLOCK_MAX];
                for (r, u_v) in readings_g.iter_mut().zip(block.samples_v()) {
                    *r = [0, 1, 2].map(|i| {
                        let g = u_v[i] / k1[i];
                        if g.abs() <= MAX_ABS_READING_G {
                            g
                        } else {
                            f64::NAN
                        }
                    });
                }
                w.hold(&answer, &readings_g[..block.samples_v().len()], recv_ns);
                true
            }
            None => false,
        };
        if held {
            // The receive time stands for the wall clock: an in-process run stays
            // deterministic (crate::waveform's silence rule).
            self.release(recv_ns, out);
        } else {
            self.publish(&answer, recv_ns, out);
        }
    }

    /// A `{prefix}vib` block arrives at `recv_ns` (the waveform stage keeps its samples;
    /// without it, it is not looked at), and held blocks it covers go out.
    pub(crate) fn on_vib(&mut self, b: &VibBlock, recv_ns: u64, out: &mut impl OutputSink) {
        if let Some(w) = &mut self.waveform {
            w.on_vib(b, recv_ns);
            self.release(recv_ns, out);
        }
    }

    /// Publishes every held block that is decided at wall-clock `now_ns`.
    pub(crate) fn release(&mut self, now_ns: u64, out: &mut impl OutputSink) {
        while let Some((b, recv_ns)) = self.waveform.as_mut().and_then(|w| {
            let recv = w.front_recv_ns();
            w.next_ready(now_ns).map(|b| (b, recv))
        }) {
            self.publish(&b, recv_ns, out);
        }
    }

    /// Publishes every held block, deciding those still waiting (an in-process run's end).
    pub(crate) fn finish(&mut self, out: &mut impl OutputSink) {
        while let Some((b, recv_ns)) = self.waveform.as_mut().and_then(|w| {
            let recv = w.front_recv_ns();
            w.finish().map(|b| (b, recv))
        }) {
            self.publish(&b, recv_ns, out);
        }
    }

    /// Publishes one block and counts it by its flags.
    fn publish(&mut self, answer: &CompensatedBlock, recv_ns: u64, out: &mut impl OutputSink) {
        let flags = answer.flags;
        let mut publish_ns = 0u64;
        let result = out.publish_with(|m| {
            *m = *answer;
            publish_ns = now_ns();
            m.publish_ns = publish_ns;
        });
        match result {
            Ok(_) => {}
            Err(e @ vibro_ipc::Error::Undelivered { .. }) => {
                // Once, then counted: the heartbeat turns `degraded` and the periodic
                // summary line carries the count (no logging per block).
                if count_first(&mut self.s.undelivered) {
                    warn!("{e}; further undelivered blocks are counted in the summary");
                }
            }
            Err(e) => {
                if count_first(&mut self.s.publish_errors) {
                    warn!("{e}");
                }
                return;
            }
        }
        self.s.published += 1;
        self.s.input_gap_blocks += u64::from(flags & cf::INPUT_GAP != 0);
        // A block the waveform stage made was not made with a missing input, whatever
        // the estimate stage beside it had (its flags describe `a3` alone).
        let estimate_output = flags & cf::WAVEFORM == 0;
        let counts = |bit: u32| u64::from(estimate_output && flags & bit != 0);
        self.s.stale_blocks += counts(cf::VIBRATION_ESTIMATE_STALE);
        self.s.missing_blocks += counts(cf::ESTIMATE_MISSING);
        self.s.flagged_estimate_blocks += counts(cf::ESTIMATE_FLAGGED);
        self.s.ahead_blocks += counts(cf::ESTIMATE_AHEAD);
        self.s.rate_change_blocks += u64::from(flags & cf::RATE_CHANGE != 0);
        self.s.time_jump_blocks += u64::from(flags & cf::TIME_JUMP != 0);
        self.s.waveform_blocks += u64::from(flags & cf::WAVEFORM != 0);
        self.s.fallback_blocks += u64::from(flags & cf::WAVEFORM_FALLBACK != 0);
        self.s.saturated_blocks += u64::from(flags & cf::INPUT_SATURATED != 0);
        self.latency.record(publish_ns.saturating_sub(recv_ns));
    }
}

/// Per unit, the random part's spectrum in its axes as the effects' mean formulas
/// read it: the spectrum behind the estimate's band powers (`vibro_effects::spectrum`,
/// the lab's reading of the same estimate), and, when the compensator works within
/// output intervals of `interval_s`, its part inside one interval
/// (`vibro_effects::interval::within_spectrum`), as the base model's vibration is
/// reduced (`within_output_interval`). Empty without bands.
fn unit_spectra(
    est: &VibEstimate,
    solver: &mut SpectrumSolver,
    axes: &vibro_physics::triad::TriadAxes,
    interval_s: f64,
) -> [Vec<PsdBand>; 3] {
    let sensors = within_spectrum(&sensor_spectrum(est, solver), interval_s);
    let map = sensor_map(axes);
    std::array::from_fn(|i| unit_bands(&sensors, &map[i]))
}

/// Per unit: the vibration it really sees (the sensor effects' RMS factor removed from
/// the measured IA vibration, vibro_effects::predict) and the grid of its effects' VE
/// change over `spans[i]` (MODEL.md section 11, docs/lab.md), for a steady vibration
/// (`duration = inf`), with the cross-axis flight acceleration taken as 0; for a single
/// tone, when the compensator works within output intervals (`within_interval`), also
/// the grid without it and the tone's phase on the unit's IA at `center_ns`
/// ([`ToneSplit`]). `spectra[i]`: the random part's spectrum in unit `i`'s axes
/// ([`unit_spectra`]), which the filtering effects (a mount resonance) weigh by their
/// response.
fn effect_grids(
    lab: &vibro_effects::LabModel,
    passports: &[vibro_physics::passport::Passport; 3],
    measured: &[Vibration; 3],
    spectra: &[Vec<PsdBand>; 3],
    spans: [GridSpan; 3],
    center_ns: u64,
    within_interval: bool,
) -> vibro_effects::Result<([UnitEffects; 3], [Vibration; 3])> {
    let mut out: Vec<UnitEffects> = Vec::with_capacity(3);
    let mut true_vib = *measured;
    for i in 0..3 {
        let flat = vibro_effects::predict::flat_passport(&passports[i])?;
        let effects = lab.build_effects(&flat)?;
        let truth = vibro_effects::predict::true_vibration(
            &effects,
            &flat,
            [0.0, 0.0, spans[i].center_g],
            &measured[i],
            &spectra[i],
        )?;
        true_vib[i] = truth.vibration;
        let psd = truth.psd;
        let grid = |vib: &Vibration| {
            EffectGrid::build(spans[i], |a_g| {
                Ok(vibro_effects::predict::effect_shifts_g(
                    &effects,
                    &flat,
                    [0.0, 0.0, a_g],
                    vib,
                    &psd,
                    f64::INFINITY,
                )?
                .iter()
                .map(|(_, v)| v)
                .sum())
            })
        };
        let full = grid(&true_vib[i])?;
        let tone = match true_vib[i].tones() {
            // The whole vibration (intervals long against every period): no per-sample
            // phase.
            [_] if within_interval => {
                let mut random = true_vib[i];
                random.clear_tones();
                let (through, _) = vibro_effects::predict::unit_vibration(
                    &effects,
                    &flat,
                    [0.0, 0.0, spans[i].center_g],
                    &true_vib[i],
                    &psd,
                )?;
                match through.tones().first() {
                    Some(t) => Some(ToneSplit {
                        without: grid(&random)?,
                        freq_hz: t.freq_hz,
                        phase_rad: t.phase_rad[2],
                        amplitude_within_g: t.amplitude_g[2],
                        center_ns,
                    }),
                    None => None,
                }
            }
            _ => None,
        };
        out.push(UnitEffects { full, tone });
    }
    let grids = <[UnitEffects; 3]>::try_from(out).map_err(|v| vibro_effects::Error::Predict {
        what: "the units' effect grids".into(),
        reason: format!("{} built, three needed", v.len()),
    })?;
    Ok((grids, true_vib))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The variance of a tone's deviation inside an interval, from the samples of
    /// `sin(theta + w tau)` on a fine grid of the interval (midpoint rule): independent
    /// of the closed form.
    fn sampled_within_variance(theta: f64, omega_t: f64) -> f64 {
        let n = 20_000;
        let x: Vec<f64> = (0..n)
            .map(|j| {
                let tau = ((j as f64 + 0.5) / n as f64 - 0.5) * omega_t;
                (theta + tau).sin()
            })
            .collect();
        let mean = x.iter().sum::<f64>() / n as f64;
        x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64
    }

    /// `tone_within_factor` against the sampled variance over the sampled mean over the
    /// phase, for a slow tone (150 Hz in 1.25 ms intervals: least inside the interval
    /// at the peaks), a fast one (a whole period inside) and one in between; and its
    /// mean over the phase is 1.
    #[test]
    fn a_tones_within_interval_variance_follows_its_phase() {
        for f_t in [0.1875, 0.6, 1.0, 2.3] {
            let omega_t = 2.0 * std::f64::consts::PI * f_t;
            let phases: Vec<f64> = (0..64)
                .map(|k| 2.0 * std::f64::consts::PI * (k as f64 + 0.5) / 64.0)
                .collect();
            let mean = phases
                .iter()
                .map(|&t| sampled_within_variance(t, omega_t))
                .sum::<f64>()
                / 64.0;
            let mut avg = 0.0;
            for &theta in &phases {
                let want = sampled_within_variance(theta, omega_t) / mean;
                let got = tone_within_factor(theta, omega_t);
                assert!(
                    (got - want).abs() < 1e-6,
                    "fT {f_t}, theta {theta}: {got} vs {want}"
                );
                avg += got / 64.0;
            }
            assert!((avg - 1.0).abs() < 1e-9, "fT {f_t}: mean {avg}");
        }
        // At a slow tone's peak the interval holds a fraction of the mean variance.
        let slow = 2.0 * std::f64::consts::PI * 0.1875;
        assert!(tone_within_factor(std::f64::consts::FRAC_PI_2, slow) < 0.05);
        assert!((tone_within_factor(0.0, slow) - 2.0).abs() < 0.05);
    }

    /// The table's moments against the same moments on a fine grid of the interval
    /// (20,000 midpoints, any phase, not only the table's): within 2e-4 of the tone's
    /// amplitude's power.
    #[test]
    fn a_tones_higher_moments_inside_the_interval_follow_its_phase() {
        for f_t in [0.0625, 0.1875, 0.3, 0.45] {
            let omega_t = std::f64::consts::TAU * f_t;
            let table = ToneMoments::new(omega_t);
            for j in 0..50 {
                let theta = 0.37 + j as f64 * 0.1234;
                let n = 20_000;
                let x: Vec<f64> = (0..n)
                    .map(|i| (theta + ((i as f64 + 0.5) / n as f64 - 0.5) * omega_t).sin())
                    .collect();
                let mean = x.iter().sum::<f64>() / n as f64;
                let moment = |p: i32| x.iter().map(|v| (v - mean).powi(p)).sum::<f64>() / n as f64;
                let got = table.at(theta);
                for (k, p) in [3, 4, 5].into_iter().enumerate() {
                    assert!(
                        (got[k] - moment(p)).abs() < 2e-4,
                        "fT {f_t}, theta {theta}, moment {p}: {} vs {}",
                        got[k],
                        moment(p)
                    );
                }
            }
        }
    }

    /// Stage (19) of one tone inside an output interval, per sample: the exact model's
    /// whole sinusoid of the interval's mean variance, times the variance at the
    /// sample's phase, plus [`higher_moments_g`], against the defining average of the
    /// passport's polynomial over the interval (a 5.4 g tone at 150 Hz read at 800 Hz,
    /// AL-15's k2..k5, aL 1 g; 20,000 midpoints; the sinusoid averaged over 4,096
    /// phases): within 0.3 ug at every phase, where the variance alone errs by up to
    /// hundreds of ug.
    #[test]
    fn a_large_tones_part_inside_the_interval_is_exact_with_its_higher_moments() {
        let k = [0.0, 0.0, 105e-6, 87e-6, 10e-6, 0.9e-6];
        let f = |a: f64| a + a * a * (k[2] + a * (k[3] + a * (k[4] + a * k[5])));
        let (amplitude_g, a_l_g) = (5.4, 1.0);
        let omega_t = std::f64::consts::TAU * 150.0 / 800.0;
        let table = ToneMoments::new(omega_t);
        let half = 0.5 * omega_t;
        let sinc = half.sin() / half;
        let amplitude_within_g = amplitude_g * (1.0 - sinc * sinc).sqrt();
        let mut worst_variance_only = 0.0f64;
        for j in 0..72 {
            let theta = j as f64 * std::f64::consts::TAU / 72.0 + 0.01;
            let n = 20_000;
            let s: Vec<f64> = (0..n)
                .map(|i| {
                    a_l_g
                        + amplitude_g
                            * (theta + ((i as f64 + 0.5) / n as f64 - 0.5) * omega_t).sin()
                })
                .collect();
            let reading = s.iter().sum::<f64>() / n as f64;
            let truth = s.iter().map(|&a| f(a)).sum::<f64>() / n as f64 - f(reading);
            let m = 4096;
            let sinusoid = (0..m)
                .map(|i| {
                    let phi = std::f64::consts::TAU * (i as f64 + 0.5) / m as f64;
                    f(reading + amplitude_within_g * phi.sin())
                })
                .sum::<f64>()
                / m as f64
                - f(reading);
            let factor = tone_within_factor(theta, omega_t);
            let model = sinusoid * factor
                + higher_moments_g(
                    &k,
                    reading,
                    amplitude_g,
                    amplitude_within_g,
                    factor,
                    table.at(theta),
                );
            assert!(
                (model - truth).abs() < 0.3e-6,
                "theta {theta}: {model} vs {truth}"
            );
            worst_variance_only = worst_variance_only.max((sinusoid * factor - truth).abs());
        }
        assert!(worst_variance_only > 100e-6, "{worst_variance_only}");
    }

    /// A grid spans 1.25 times its readings' half-width: no reading is clamped.
    #[test]
    fn a_grid_widens_to_the_readings_swing() {
        let narrow = GridSpan {
            center_g: 1.0,
            half_width_g: 0.1,
        };
        assert_eq!(narrow.step_g(), EFFECT_GRID_STEP_G);
        let wide = GridSpan {
            center_g: 0.0,
            half_width_g: 4.4,
        };
        let g = EffectGrid::build(wide, |a| Ok(a * a * a - 2.0 * a)).unwrap();
        for a in [-4.4, -2.0, 0.3, 4.4] {
            assert!(g.covers(a), "{a}");
            // A cubic is interpolated exactly.
            assert!((g.at(a) - (a * a * a - 2.0 * a)).abs() < 1e-9, "{a}");
        }
    }

    /// Block `seq` of a steady stream at 800 Hz, 32 samples of 1 g on every unit, its
    /// sample index and time in step with its seq.
    fn steady_block(k1_v_per_g: [f64; 3], seq: u64) -> AccelBlock {
        let mut b = AccelBlock::ZEROED;
        b.seq = seq;
        b.first_sample_index = seq.wrapping_mul(32);
        b.sample_period_ns = 1_250_000;
        b.t0_ns = 1_000_000_000u64.wrapping_add(seq.wrapping_mul(32 * 1_250_000));
        b.count = 32;
        for s in b.output_v[..32].iter_mut() {
            *s = k1_v_per_g;
        }
        b
    }

    /// Issue 31: one accelerometer block ahead of the stream by less than 2^20 (seq
    /// 500,000) silenced the compensator: none of the blocks 11..=20 after it came out
    /// (nor any other for 5.5 h at 25 blocks/s), and 499,989 blocks were counted lost.
    /// Now the fourth of them resyncs the stream: 14..=20 come out, the first flagged
    /// `INPUT_GAP`, and no loss is counted.
    #[test]
    fn one_block_ahead_of_the_stream_does_not_silence_the_compensator() {
        use vibro_service::ServiceConfig;
        let config = Config::shipped().unwrap();
        let k1 = config.model.k1_v_per_g();
        let mut c = InProcess::new(&config).unwrap();
        let mut out = Vec::new();
        for seq in 0..=10 {
            c.on_accel(&steady_block(k1, seq), 0, &mut out);
        }
        c.on_accel(&steady_block(k1, 500_000), 0, &mut out);
        out.clear();
        for seq in 11..=20 {
            c.on_accel(&steady_block(k1, seq), 0, &mut out);
        }
        let inputs: Vec<u64> = out.iter().map(|b| b.input_seq).collect();
        assert_eq!(inputs, (14..=20).collect::<Vec<_>>());
        assert_ne!(out[0].flags & cf::INPUT_GAP, 0);
        assert!(out[1..].iter().all(|b| b.flags & cf::INPUT_GAP == 0));
        let s = c.summary();
        assert_eq!(
            (
                s.accel.lost_messages,
                s.accel.lost_samples,
                s.accel.out_of_order,
                s.accel.resyncs
            ),
            (0, 0, 3, 1),
            "{:?}",
            s.accel
        );
        let json = s.to_json();
        assert!(json.contains("\"resyncs\":1"), "{json}");
        assert!(json.contains("\"out_of_order\":3"), "{json}");
    }

    /// The property (`vibro_service::adversary`): random adversarial prefixes of
    /// accelerometer blocks (seq and sample-index jumps both ways, repeats,
    /// reorderings, time jumps, `u64::MAX`, NaN and 1e300 readings), then the real
    /// stream: its output resumes within `RESYNC_AFTER` (4) blocks and never stops
    /// again, and where the episodes are isolated no more blocks are counted lost than
    /// real ones that got no output.
    #[test]
    fn no_sequence_silences_the_compensator() {
        use vibro_service::adversary::{check, generate, Xorshift};
        use vibro_service::ServiceConfig;
        let config = Config::shipped().unwrap();
        let k1 = config.model.k1_v_per_g();
        let mut rng = Xorshift::new(1931);
        for trial in 0..300 {
            let isolated = trial % 3 != 0;
            let ops = (rng.next_u64() % 60) as usize;
            let s = generate(|| Some(rng.next_u64()), ops, 32, isolated);
            let mut c = InProcess::new(&config).unwrap();
            let mut out = Vec::new();
            let taken: Vec<bool> = s
                .messages
                .iter()
                .map(|m| {
                    let mut b = steady_block(k1, m.seq);
                    b.first_sample_index = m.first_sample_index;
                    b.t0_ns =
                        1_000_000_000u64.saturating_add(m.t0_periods.saturating_mul(1_250_000));
                    if m.absurd_values {
                        b.output_v[3] = [f64::NAN, 1e300, -1e300];
                    }
                    let before = out.len();
                    c.on_accel(&b, 0, &mut out);
                    out.len() > before
                })
                .collect();
            let summary = c.summary();
            if let Err(e) = check(&s, &taken, summary.accel.lost_messages) {
                panic!("trial {trial}: {e}\n{:?}", summary.accel);
            }
        }
    }
}
