//! # vibro-estimator-core
//!
//! The estimator's handling of each vibration block without the transport: validation,
//! continuity, restarts, producer flags, rate mismatches, the estimator itself, the
//! estimates' flags and numbering, the counters. The estimator service's hot loop
//! (`vibro-estimator`) feeds it from `{prefix}vib` and publishes on `{prefix}estimate`;
//! offline users (the lab reading a log, the socket pipeline of `vibrocomp latency`)
//! feed it in-process and get the same estimates. It lives in `shared/` so that a
//! library (the lab) can run it without depending on a service.
//!
//! ```
//! use vibro_dsp::{EstimatorConfig, EstimatorConfigRaw};
//! use vibro_estimator_core::InProcess;
//! use vibro_msgs::{VibBlock, VibEstimate};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let config = EstimatorConfig::try_from(EstimatorConfigRaw::new(4096.0, [0.1; 3]))?;
//! let mut core = InProcess::new(&config)?;
//! let mut estimates: Vec<VibEstimate> = Vec::new();
//! let block = VibBlock::ZEROED; // an empty block only advances `seq`
//! core.on_block(&block, 0, &mut estimates)?;
//! assert!(estimates.is_empty());
//! # Ok(())
//! # }
//! ```
//!
//! References: `docs/services.md` (streams, flags, loss accounting), `docs/estimation.md`
//! (the estimator).

use tracing::warn;
use vibro_dsp::{Estimate, Estimator, EstimatorConfig, SampleBlock};
#[cfg(feature = "ipc")]
use vibro_ipc::StreamPublisher;
use vibro_msgs::{estimate_flags, vib_flags, VibBlock, VibEstimate, WireMessage};
use vibro_service::{
    count_first, Continuity, CountersJson, DisorderLog, JsonObject, Latency, Quantiles,
    StreamCounters,
};

/// What the estimator did, returned by the service's `run` when it stops (and printed
/// by `--json`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Summary {
    /// Time the hot loop ran.
    pub uptime_s: f64,
    /// The `{prefix}vib` stream: received, lost (by `seq` and by `first_sample_index`),
    /// out of order, restarts, resyncs (taken up again after out-of-order blocks:
    /// `vibro_service::continuity`), malformed.
    pub vib: StreamCounters,
    /// Blocks whose `sample_period_ns` disagrees with the configured rate by more than
    /// 1 ns: their samples were kept out (a gap), the estimates over them flagged
    /// `RATE_MISMATCH`.
    pub rate_mismatches: u64,
    /// Blocks flagged `GAP_BEFORE` or `SATURATED` by their producer.
    pub producer_flagged: u64,
    /// The estimator's own totals (time gaps, dropped blocks, non-finite samples, ...).
    pub dsp: vibro_dsp::Counters,
    /// Estimates published on `{prefix}estimate`.
    pub estimates_published: u64,
    /// Estimates published with a quality flag other than `TONE_FREE` (gap, non-finite,
    /// out of order, insufficient data, saturation, rate mismatch).
    pub estimates_flagged: u64,
    /// Estimates a subscriber's full buffer did not take (after the back-pressure timeout).
    pub undelivered: u64,
    /// Other publish failures (loan, send).
    pub publish_errors: u64,
    /// Receive failures.
    pub receive_errors: u64,
    pub heartbeats: u64,
    /// From receiving the block that completed a window to publishing its estimate.
    pub latency: Quantiles,
}

impl Summary {
    /// The summary as one JSON object.
    pub fn to_json(&self) -> String {
        let d = &self.dsp;
        let mut dsp = JsonObject::new();
        dsp.u64("blocks_accepted", d.blocks_accepted)
            .u64("blocks_dropped", d.blocks_dropped)
            .u64("sequence_gaps", d.sequence_gaps)
            .u64("gap_samples", d.gap_samples)
            .u64("restarts", d.restarts)
            .u64("non_finite_samples", d.non_finite_samples)
            .u64("saturated_samples", d.saturated_samples)
            .u64("estimates", d.estimates);
        let mut o = JsonObject::new();
        o.str("service", "estimator")
            .f64("uptime_s", self.uptime_s)
            .object("vib", self.vib.to_json())
            .u64("rate_mismatches", self.rate_mismatches)
            .u64("producer_flagged", self.producer_flagged)
            .object("dsp", dsp)
            .u64("estimates_published", self.estimates_published)
            .u64("estimates_flagged", self.estimates_flagged)
            .u64("undelivered", self.undelivered)
            .u64("publish_errors", self.publish_errors)
            .u64("receive_errors", self.receive_errors)
            .u64("heartbeats", self.heartbeats)
            .object("latency", self.latency.to_json());
        o.finish()
    }
}

#[cfg(feature = "ipc")]
impl vibro_service::ServiceSummary for Summary {
    fn to_json(&self) -> String {
        Summary::to_json(self)
    }
}

/// Mirrors one `vibro_dsp::Estimate` into the wire type, field by field (values that
/// could not be estimated stay NaN, as the estimator gives them). The stream
/// bookkeeping (`seq`, `source_seq`, `publish_ns`) is the caller's.
pub fn mirror_estimate(e: &Estimate, m: &mut VibEstimate) {
    m.index = e.index;
    m.start_ns = e.start_ns;
    m.end_ns = e.end_ns;
    m.center_ns = e.center_ns;
    m.samples = saturating_u32(e.samples);
    m.valid_samples = saturating_u32(e.valid_samples);
    m.saturated_samples = e.saturated_samples.map(saturating_u32);
    let b = &e.broadband;
    m.broadband_f_lo_hz = b.f_lo_hz;
    m.broadband_f_hi_hz = b.f_hi_hz;
    m.broadband_rms_g = b.rms_g;
    m.broadband_rms_u_g = b.rms_u_g;
    m.broadband_covariance_g2 = b.covariance_g2;
    m.broadband_covariance_u_g2 = b.covariance_u_g2;
    m.broadband_kurtosis = b.kurtosis;
    m.broadband_kurtosis_u = b.kurtosis_u;
    m.broadband_welch_segments = saturating_u32(b.welch_segments);
    m.welch_segment_samples = saturating_u32(b.welch_segment_samples);
    // Both lists hold at most vibro_dsp::MAX_TONES / MAX_BANDS = the wire capacities
    // (checked by vibro-msgs' tests); `zip` bounds the copy anyway.
    let mut tones = 0;
    for (k, t) in (0..m.tone_frequency_hz.len()).zip(e.tones.iter()) {
        m.tone_frequency_hz[k] = t.frequency_hz;
        m.tone_frequency_u_hz[k] = t.frequency_u_hz;
        m.tone_amplitude_g[k] = t.amplitude_g;
        m.tone_amplitude_u_g[k] = t.amplitude_u_g;
        m.tone_phase_rad[k] = t.phase_rad;
        m.tone_phase_u_rad[k] = t.phase_u_rad;
        m.tone_snr_db[k] = t.snr_db;
        tones += 1;
    }
    m.tone_count = tones;
    let mut bands = 0;
    for (i, band) in (0..m.band_f_lo_hz.len()).zip(e.bands.iter()) {
        m.band_f_lo_hz[i] = band.f_lo_hz;
        m.band_f_hi_hz[i] = band.f_hi_hz;
        m.band_psd_g2_per_hz[i] = band.psd_g2_per_hz;
        m.band_psd_u_g2_per_hz[i] = band.psd_u_g2_per_hz;
        m.band_rms_g[i] = band.rms_g;
        bands += 1;
    }
    m.band_count = bands;
    let f = &e.flags;
    let mut flags = 0;
    for (set, bit) in [
        (f.tone_free, estimate_flags::TONE_FREE),
        (f.gap, estimate_flags::GAP),
        (f.non_finite, estimate_flags::NON_FINITE),
        (f.out_of_order, estimate_flags::OUT_OF_ORDER),
        (f.insufficient_data, estimate_flags::INSUFFICIENT_DATA),
    ] {
        if set {
            flags |= bit;
        }
    }
    for (axis, &sat) in f.saturated.iter().enumerate() {
        if sat {
            flags |= estimate_flags::SATURATED_AXIS0 << axis;
        }
    }
    m.flags = flags;
}

fn saturating_u32(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// Where finished estimates go: the `{prefix}estimate` publisher in the service, a
/// vector (or a channel) in-process.
pub trait EstimateSink {
    /// Publishes one estimate: `fill` writes it in place into a default message
    /// (everything but `publish_ns`), then the sink stamps `publish_ns` and sends it.
    /// Returns that stamp (0 for a sink that does not stamp) with the outcome.
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut VibEstimate),
    ) -> (u64, vibro_ipc::Result<usize>);
}

#[cfg(feature = "ipc")]
impl EstimateSink for StreamPublisher<VibEstimate> {
    /// Stamps `publish_ns` with [`vibro_service::now_ns`] once the estimate is written, right before
    /// it is sent.
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut VibEstimate),
    ) -> (u64, vibro_ipc::Result<usize>) {
        let mut publish_ns = 0;
        let result = StreamPublisher::publish_with(self, |m| {
            fill(m);
            publish_ns = vibro_service::now_ns();
            m.publish_ns = publish_ns;
        });
        (publish_ns, result)
    }
}

/// Collects the estimates, `publish_ns` left 0.
impl EstimateSink for Vec<VibEstimate> {
    fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut VibEstimate),
    ) -> (u64, vibro_ipc::Result<usize>) {
        let mut m = VibEstimate::default();
        fill(&mut m);
        self.push(m);
        (0, Ok(1))
    }
}

/// Everything the estimator counts; no allocation after start. The fields are those of
/// [`Summary`] that the service reports per period.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Counters {
    pub vib: StreamCounters,
    pub rate_mismatches: u64,
    pub producer_flagged: u64,
    pub estimates_published: u64,
    pub estimates_flagged: u64,
    pub undelivered: u64,
    pub publish_errors: u64,
    /// The transport's: counted by the service's loop.
    pub receive_errors: u64,
}

/// The estimator's handling of each vibration block without the transport: the same
/// code the service's hot loop runs (validation, continuity, restarts, producer flags,
/// rate mismatches and `RATE_MISMATCH`, `vibro_dsp::Estimator`, the estimates' `seq`
/// and `source_seq`, the counters), fed in-process. A log's `/vib` stream fed here
/// gives the estimates the service publishes for it (timestamps aside).
pub struct InProcess {
    estimator: Estimator,
    expected_period_ns: f64,
    continuity: Continuity,
    /// Out-of-order blocks and resyncs, told at a bounded rate ([`Self::tell_disorder`]
    /// tells the rest once per summary period).
    disorder: DisorderLog,
    /// The time span `[from, to)` of the blocks dropped for their rate since the last
    /// estimate that started after them: the estimates whose windows overlap it are
    /// flagged RATE_MISMATCH.
    mismatch_span: Option<(u64, u64)>,
    /// `seq` of the next estimate.
    estimate_seq: u64,
    c: Counters,
    latency: Latency,
}

impl InProcess {
    /// The estimator of `config`; allocates its buffers and latency histograms here,
    /// never per block. Errs only when the latency histograms cannot be made
    /// (`vibro_service::Latency`, whose error is the service runtime's `anyhow`).
    pub fn new(config: &EstimatorConfig) -> anyhow::Result<Self> {
        Ok(Self {
            estimator: Estimator::new(config.clone()),
            expected_period_ns: config.sample_period_ns(),
            continuity: Continuity::new(),
            disorder: DisorderLog::default(),
            mismatch_span: None,
            estimate_seq: 0,
            c: Counters::default(),
            latency: Latency::new()?,
        })
    }

    /// A block arrives at `recv_ns`: every estimate it completes goes to `sink`, which
    /// stamps its `publish_ns`. Only an internal FFT failure (a bug) errors.
    pub fn on_block(
        &mut self,
        block: &VibBlock,
        recv_ns: u64,
        sink: &mut impl EstimateSink,
    ) -> Result<(), vibro_dsp::Error> {
        self.c.vib.received += 1;
        if let Err(e) = block.validate() {
            // The samples beyond the capacity do not exist: drop the block; the
            // estimator then sees its seq missing and flags the window GAP.
            if count_first(&mut self.c.vib.malformed) {
                warn!(seq = block.seq, "dropping a malformed block: {e}");
            }
            return Ok(());
        }
        let arrival =
            self.continuity
                .check(block.seq, block.first_sample_index, u64::from(block.count));
        self.c.vib.record(&arrival);
        self.disorder.arrival(
            "vibration",
            &arrival,
            block.seq,
            self.continuity.last_seq(),
            &self.c.vib,
        );
        if arrival.resynced {
            // Taken up again after out-of-order blocks (or back to the stream left at
            // a resync): the estimator takes this block as newer whatever its seq, so
            // that it is not dropped by its older seq; its time decides whether the
            // window goes on or restarts.
            self.estimator.resync();
        } else if arrival.restarted {
            // The producer started again (a new replay, a restarted rig): a new
            // time base, so a new window rather than "out of order" blocks.
            self.estimator.reset();
            self.mismatch_span = None;
        }
        // The producer's quality flags (an end-of-stream block carries no samples to
        // doubt).
        if block.flags & (vib_flags::GAP_BEFORE | vib_flags::SATURATED) != 0 {
            self.c.producer_flagged += 1;
        }
        // A block at another rate than the estimator's: its samples would sit at the
        // wrong times in the window, so they are kept out. (0: the producer does not
        // say; an empty block has no samples at any rate.)
        let expected_period_ns = self.expected_period_ns;
        let rate_mismatch = block.count > 0
            && block.sample_period_ns != 0
            && (block.sample_period_ns as f64 - expected_period_ns).abs() > 1.0;
        let samples_raw = if rate_mismatch {
            if count_first(&mut self.c.rate_mismatches) {
                warn!(
                    seq = block.seq,
                    sample_period_ns = block.sample_period_ns,
                    expected_ns = expected_period_ns,
                    "vibration blocks do not match estimator.sample_rate_hz: their samples \
                     are kept out of the estimates (further ones are counted)"
                );
            }
            // In the estimates' time: the samples' stamps less the chain's delay.
            let from = block
                .t0_ns
                .saturating_sub(self.estimator.config().delay_ns());
            let to = from.saturating_add(
                block
                    .sample_period_ns
                    .saturating_mul(u64::from(block.count)),
            );
            self.mismatch_span = Some(match self.mismatch_span {
                Some((f, t)) => (f.min(from), t.max(to)),
                None => (from, to),
            });
            // Handed over empty: the estimator takes its seq (no false sequence
            // gap), and the next block's timestamp shows the samples missing.
            &[][..]
        } else {
            block.samples_v()
        };
        // Out-of-order blocks go to the estimator too: it drops them by their
        // timestamps and flags the next estimate OUT_OF_ORDER.
        let input = SampleBlock {
            seq: block.seq,
            t0_ns: block.t0_ns,
            samples_raw,
        };
        let source_seq = block.seq;
        let Self {
            estimator,
            mismatch_span,
            estimate_seq,
            c,
            latency,
            ..
        } = self;
        estimator.push_block(&input, |e| {
            let over_mismatch = match *mismatch_span {
                Some((from, to)) => {
                    if e.start_ns >= to {
                        // Estimates come in time order: none will overlap it again.
                        *mismatch_span = None;
                    }
                    e.start_ns < to && e.end_ns > from
                }
                None => false,
            };
            let seq = *estimate_seq;
            let (publish_ns, result) = sink.publish_with(|m| {
                mirror_estimate(e, m);
                if over_mismatch {
                    m.flags |= estimate_flags::RATE_MISMATCH;
                }
                m.seq = seq;
                m.source_seq = source_seq;
            });
            *estimate_seq += 1;
            match result {
                Ok(_) => {}
                Err(vibro_ipc::Error::Undelivered { .. }) => c.undelivered += 1,
                Err(err) => {
                    if count_first(&mut c.publish_errors) {
                        warn!("{err}");
                    }
                    return;
                }
            }
            c.estimates_published += 1;
            let f = &e.flags;
            if f.gap
                || f.non_finite
                || f.out_of_order
                || f.insufficient_data
                || f.saturated.contains(&true)
                || over_mismatch
            {
                c.estimates_flagged += 1;
            }
            latency.record(publish_ns.saturating_sub(recv_ns));
        })?;
        Ok(())
    }

    /// The counters so far.
    pub fn counters(&self) -> Counters {
        self.c
    }

    /// At the end of a summary period: logs the out-of-order blocks and resyncs not told
    /// yet (at most one line; `vibro_service::DisorderLog`).
    pub fn tell_disorder(&mut self) {
        self.disorder.period("vibration", &self.c.vib);
    }

    /// A receive failure of the transport (counted by the service's loop): true for the
    /// first one, which the caller logs (further ones are counted only).
    pub fn count_receive_error(&mut self) -> bool {
        count_first(&mut self.c.receive_errors)
    }

    /// The publish latencies (block that completed a window to its estimate published).
    pub fn latency_mut(&mut self) -> &mut Latency {
        &mut self.latency
    }

    /// Contiguous input samples still needed before the next estimate.
    pub fn samples_to_next_estimate(&self) -> u64 {
        self.estimator.samples_to_next_estimate()
    }

    /// Input samples between estimates after the next.
    pub fn samples_per_estimate(&self) -> u64 {
        self.estimator.samples_per_estimate()
    }

    /// The estimator's own totals (time gaps, dropped blocks, non-finite samples, ...).
    pub fn dsp_counters(&self) -> vibro_dsp::Counters {
        self.estimator.counters()
    }

    /// The counters so far; `latency` over everything recorded, `uptime_s` and
    /// `heartbeats` (the service's) 0.
    pub fn summary(&self) -> Summary {
        let c = &self.c;
        Summary {
            uptime_s: 0.0,
            vib: c.vib,
            rate_mismatches: c.rate_mismatches,
            producer_flagged: c.producer_flagged,
            dsp: self.estimator.counters(),
            estimates_published: c.estimates_published,
            estimates_flagged: c.estimates_flagged,
            undelivered: c.undelivered,
            publish_errors: c.publish_errors,
            receive_errors: c.receive_errors,
            heartbeats: 0,
            latency: self.latency.total(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `[estimator]` of the shipped service configuration
    /// (`config/services/estimator.toml`).
    fn shipped() -> EstimatorConfig {
        #[derive(serde::Deserialize)]
        struct File {
            estimator: vibro_dsp::EstimatorConfigRaw,
        }
        let text = include_str!("../../../config/services/estimator.toml");
        let file: File = toml::from_str(text).unwrap();
        EstimatorConfig::try_from(file.estimator).unwrap()
    }

    const BLOCK: usize = 512;

    /// Block `seq` of a 3-axis signal at `period_ns`: a 97 Hz tone plus a deterministic
    /// pseudo-random part, in volts at 0.1 V/g (the shipped sensitivity).
    fn block(seq: u64, period_ns: u64) -> VibBlock {
        let mut b = VibBlock::ZEROED;
        b.seq = seq;
        b.first_sample_index = seq * BLOCK as u64;
        b.t0_ns = seq * BLOCK as u64 * period_ns;
        b.sample_period_ns = period_ns;
        b.count = BLOCK as u32;
        let mut state = seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        for k in 0..BLOCK {
            let t_s = (b.t0_ns + k as u64 * period_ns) as f64 * 1e-9;
            for (a, v) in b.sample_v[k].iter_mut().enumerate() {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let noise_g = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                let tone_g = (1.0 + a as f64) * (std::f64::consts::TAU * 97.0 * t_s).sin();
                *v = 0.1 * (tone_g + noise_g);
            }
        }
        b
    }

    /// On a clean stream the core's estimates are the bare estimator's, mirrored and
    /// numbered from 0 (what the lab and the socket pipeline computed by hand before).
    #[test]
    fn on_a_clean_stream_the_core_is_the_bare_estimator() {
        let config = shipped();
        let period_ns = config.sample_period_ns().round() as u64;
        let blocks: Vec<VibBlock> = (0..120).map(|seq| block(seq, period_ns)).collect();

        let mut bare = Estimator::new(config.clone());
        let mut expected: Vec<VibEstimate> = Vec::new();
        for b in &blocks {
            let input = SampleBlock {
                seq: b.seq,
                t0_ns: b.t0_ns,
                samples_raw: b.samples_v(),
            };
            bare.push_block(&input, |e| {
                let mut m = VibEstimate::default();
                mirror_estimate(e, &mut m);
                m.seq = expected.len() as u64;
                m.source_seq = b.seq;
                expected.push(m);
            })
            .unwrap();
        }

        let mut core = InProcess::new(&config).unwrap();
        let mut got: Vec<VibEstimate> = Vec::new();
        for b in &blocks {
            core.on_block(b, 0, &mut got).unwrap();
        }
        assert!(expected.len() >= 3, "{}", expected.len());
        assert_eq!(got.len(), expected.len());
        for (g, e) in got.iter().zip(&expected) {
            assert_eq!(g.as_bytes(), e.as_bytes(), "estimate {}", e.seq);
        }
        let s = core.summary();
        assert_eq!(s.vib.received, blocks.len() as u64);
        assert_eq!(s.estimates_published, got.len() as u64);
        assert_eq!((s.estimates_flagged, s.rate_mismatches), (0, 0));
        assert_eq!(s.dsp, bare.counters());
        assert_eq!(
            core.samples_to_next_estimate(),
            bare.samples_to_next_estimate()
        );
    }

    /// A block at another rate is kept out and flags the estimates over it; malformed
    /// blocks are dropped and counted; a producer restart starts a new window.
    #[test]
    fn rate_mismatches_malformed_blocks_and_restarts() {
        let config = shipped();
        let period_ns = config.sample_period_ns().round() as u64;
        let mut core = InProcess::new(&config).unwrap();
        let mut out: Vec<VibEstimate> = Vec::new();
        for seq in 0..120 {
            let mut b = block(seq, period_ns);
            if seq == 10 {
                b.sample_period_ns = 2 * period_ns;
            }
            if seq == 20 {
                b.count = VIB_BLOCK_MAX_PLUS_ONE;
            }
            core.on_block(&b, 0, &mut out).unwrap();
        }
        let s = core.summary();
        assert_eq!((s.rate_mismatches, s.vib.malformed), (1, 1));
        let flagged = |m: &VibEstimate, bit| m.flags & bit != 0;
        // Windows of 1 s every 0.5 s: only the first covers block 10 (0.20 s .. 0.24 s).
        assert!(flagged(&out[0], estimate_flags::RATE_MISMATCH));
        assert!(out[1..]
            .iter()
            .all(|m| !flagged(m, estimate_flags::RATE_MISMATCH)));
        assert!(out.iter().all(|m| m.seq < out.len() as u64));
        let before = out.len();
        core.on_block(&block(0, period_ns), 0, &mut out).unwrap();
        assert_eq!(core.summary().vib.restarts, 1);
        assert_eq!(out.len(), before);
        assert_eq!(
            core.samples_to_next_estimate(),
            config.window_samples() as u64 - BLOCK as u64
        );
    }

    const VIB_BLOCK_MAX_PLUS_ONE: u32 = vibro_msgs::VIB_BLOCK_MAX as u32 + 1;

    /// Issue 31: one vibration block ahead of the stream (seq 500,000, its sample index
    /// and time too) silenced the estimator: the blocks after it were dropped as out of
    /// order (none of 11..=20 taken), no estimate came out of the next 180 blocks, and
    /// 499,989 blocks were counted lost. Now the fourth block after it resyncs the
    /// stream, the window restarts there, and estimates come again a window later.
    #[test]
    fn one_block_ahead_of_the_stream_does_not_silence_the_estimator() {
        let config = shipped();
        let period_ns = config.sample_period_ns().round() as u64;
        let mut core = InProcess::new(&config).unwrap();
        let mut out: Vec<VibEstimate> = Vec::new();
        for seq in 0..=10 {
            core.on_block(&block(seq, period_ns), 0, &mut out).unwrap();
        }
        core.on_block(&block(500_000, period_ns), 0, &mut out)
            .unwrap();
        let before = core.dsp_counters().blocks_accepted;
        for seq in 11..=20 {
            core.on_block(&block(seq, period_ns), 0, &mut out).unwrap();
        }
        assert_eq!(core.dsp_counters().blocks_accepted - before, 7, "14..=20");
        out.clear();
        for seq in 21..=200 {
            core.on_block(&block(seq, period_ns), 0, &mut out).unwrap();
        }
        // A window (50 blocks) from block 14, then one per hop (25 blocks).
        assert_eq!(out.len(), (200 - (14 + 49)) / 25 + 1);
        assert_ne!(out[0].flags & estimate_flags::GAP, 0);
        let s = core.summary();
        assert_eq!(
            (
                s.vib.lost_messages,
                s.vib.lost_samples,
                s.vib.out_of_order,
                s.vib.resyncs
            ),
            (0, 0, 3, 1),
            "{:?}",
            s.vib
        );
        assert!(s.to_json().contains("\"resyncs\":1"));
    }

    /// The property (`vibro_service::adversary`): random adversarial prefixes of
    /// vibration blocks (seq, sample-index and time jumps both ways, repeats,
    /// reorderings, `u64::MAX`, NaN and 1e300 samples), then the real stream: its blocks
    /// are taken again within `RESYNC_AFTER` (4) and all after, the estimator takes
    /// every one of those, an estimate comes out within `RESYNC_AFTER - 1 + 50` blocks
    /// (3 dropped, then a window of 50 blocks at most), and where the episodes are
    /// isolated no more blocks are counted lost than real ones never taken.
    #[test]
    fn no_sequence_silences_the_estimator() {
        use vibro_service::adversary::{check, generate, Xorshift};
        use vibro_service::RESYNC_AFTER;
        let config = shipped();
        let period_ns = config.sample_period_ns().round() as u64;
        let window_blocks = config.window_samples().div_ceil(BLOCK);
        let bound = RESYNC_AFTER as usize - 1 + window_blocks;
        let mut rng = Xorshift::new(3131);
        for trial in 0..120 {
            let isolated = trial % 3 != 0;
            let ops = (rng.next_u64() % 50) as usize;
            let s = generate(|| Some(rng.next_u64()), ops, BLOCK as u64, isolated);
            let mut core = InProcess::new(&config).unwrap();
            let mut out: Vec<VibEstimate> = Vec::new();
            let mut taken = Vec::new();
            let mut first_estimate = None;
            for (i, m) in s.messages.iter().enumerate() {
                // The samples of the real block, with the message's numbers and time.
                let mut b = block(m.seq % 1_000, period_ns);
                b.seq = m.seq;
                b.first_sample_index = m.first_sample_index;
                b.t0_ns = m.t0_periods.saturating_mul(period_ns);
                if m.absurd_values {
                    b.sample_v[7] = [f64::NAN, 1e300, f64::INFINITY];
                }
                let (ooo, dsp) = (core.counters().vib.out_of_order, core.dsp_counters());
                let estimates = out.len();
                core.on_block(&b, 0, &mut out).unwrap();
                let took = core.counters().vib.out_of_order == ooo;
                taken.push(took);
                if i >= s.tail {
                    if took {
                        // Every tail block the continuity takes, the estimator takes.
                        assert_eq!(
                            core.dsp_counters().blocks_accepted,
                            dsp.blocks_accepted + 1,
                            "trial {trial}: tail block {} taken but dropped by the estimator",
                            i - s.tail
                        );
                    }
                    if first_estimate.is_none() && out.len() > estimates {
                        first_estimate = Some(i - s.tail);
                    }
                }
            }
            if let Err(e) = check(&s, &taken, core.summary().vib.lost_messages) {
                panic!("trial {trial}: {e}\n{:?}", core.summary().vib);
            }
            match first_estimate {
                Some(k) if k <= bound => {}
                other => {
                    panic!("trial {trial}: first estimate at tail block {other:?}, bound {bound}")
                }
            }
        }
    }
}
