//! The streaming estimator: takes blocks as they arrive, checks their sequence and
//! timing, keeps one window of samples, and estimates each window as it fills.

use crate::config::EstimatorConfig;
use crate::detect::{Detected, Detector};
use crate::kurtosis::Kurtosis;
use crate::output::{BandEstimate, Estimate, FixedList, ToneEstimate};
use crate::response::Response;
use crate::sinefit::{FitState, SineFit};
use crate::welch::{Welch, PAIRS};
use crate::{Result, MAX_TONES};
use realfft::RealFftPlanner;
use std::f64::consts::{PI, TAU};

const FLAG_NON_FINITE: u8 = 1;
const FLAG_GAP: u8 = 2;
const FLAG_INVALID: u8 = FLAG_NON_FINITE | FLAG_GAP;
const FLAG_SATURATED: [u8; 3] = [4, 8, 16];
/// Samples beyond this magnitude are treated like NaN: no sensor measures them, and
/// their fourth powers would overflow the kurtosis sums.
pub const MAX_ABS_SAMPLE_G: f64 = 1e30;

/// Out-of-order blocks in a row, each with a sequence number above the one before, after
/// which the last of them is taken (as a clock that stepped back: the window restarts)
/// rather than dropped. Without it one block dated and numbered ahead of the stream
/// would have every later block dropped until the stream caught up with it, hours on.
/// The same rule, and the same count, as `vibro_service::RESYNC_AFTER` (the services'
/// continuity check, which resyncs first and says so with [`Estimator::resync`]).
pub const RESYNC_AFTER_DROPS: u32 = 4;

/// One block of 3-axis samples from the vibration sensors.
#[derive(Debug, Clone, Copy)]
pub struct SampleBlock<'a> {
    /// Increases by one per block; a jump means blocks were lost.
    pub seq: u64,
    /// Timestamp of the block's first sample.
    pub t0_ns: u64,
    /// Samples in raw units (V or counts; g when the sensitivity is 1), `[x, y, z]`.
    pub samples_raw: &'a [[f64; 3]],
}

/// What happened to one block.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct BlockStatus {
    /// False when the block was dropped (out of order or overlapping).
    pub accepted: bool,
    /// The block's sequence number or timestamp went backwards: it was dropped.
    pub out_of_order: bool,
    /// The sequence number jumped by more than one.
    pub sequence_gap: bool,
    /// Samples missing before this block, by its timestamp.
    pub gap_samples: u64,
    /// The gap was longer than a window: the window was restarted.
    pub restarted: bool,
    /// Samples of this block with a NaN or infinite value on some axis.
    pub non_finite_samples: usize,
    /// Samples of this block at or over full scale on some axis.
    pub saturated_samples: usize,
    /// Estimates emitted while taking this block.
    pub estimates: usize,
}

/// Totals since the estimator was built, for a periodic summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counters {
    pub blocks_accepted: u64,
    pub blocks_dropped: u64,
    pub sequence_gaps: u64,
    pub gap_samples: u64,
    pub restarts: u64,
    pub non_finite_samples: u64,
    pub saturated_samples: u64,
    pub estimates: u64,
}

/// The samples of the current window, as they arrive.
struct Intake {
    window: usize,
    hop: usize,
    x_g: [Vec<f64>; 3],
    flags: Vec<u8>,
    times_ns: Vec<u64>,
    filled: usize,
    /// Sequence number of the last accepted block and the expected timestamp of the
    /// sample after it.
    last: Option<(u64, u64)>,
    pending_gap: bool,
    pending_out_of_order: bool,
    /// The caller took the stream up again ([`Estimator::resync`]): the next block is
    /// newer whatever its sequence number.
    rebased: bool,
    /// The sequence number of the last block dropped as out of order and how many were
    /// dropped in a row, each numbered above the one before ([`RESYNC_AFTER_DROPS`]).
    dropped_run: Option<(u64, u32)>,
    inverse_sensitivity: [f64; 3],
    full_scale_g: [f64; 3],
    period_ns: f64,
    /// Timestamps within this of the expected one are taken as contiguous.
    tolerance_ns: f64,
}

impl Intake {
    /// Stores one sample; returns whether the window is now full.
    #[inline]
    fn put(&mut self, x_g: [f64; 3], flags: u8, t_ns: u64) -> bool {
        let k = self.filled;
        for (buf, v) in self.x_g.iter_mut().zip(x_g) {
            buf[k] = v;
        }
        self.flags[k] = flags;
        self.times_ns[k] = t_ns;
        self.filled += 1;
        self.filled == self.window
    }

    /// Drops the oldest `hop` samples after a window was estimated.
    fn advance(&mut self) {
        let (n, hop) = (self.window, self.hop.min(self.window));
        for buf in self.x_g.iter_mut() {
            buf.copy_within(hop..n, 0);
        }
        self.flags.copy_within(hop..n, 0);
        self.times_ns.copy_within(hop..n, 0);
        self.filled = n - hop;
    }

    fn offset_ns(&self, samples: u64) -> u64 {
        (samples as f64 * self.period_ns).round() as u64
    }
}

/// Buffers of the per-window computation, all allocated when the estimator is built.
struct Work {
    detector: Detector,
    fit: SineFit,
    welch: Welch,
    kurtosis: Kurtosis,
    response: Response,
    detected: FixedList<Detected, MAX_TONES>,
    fit_state: FitState,
    keep: [bool; MAX_TONES],
    invalid: Vec<u32>,
    invalid_prefix: Vec<u32>,
    residual: [Vec<f64>; 3],
}

/// Estimates tones, band PSD, broadband RMS, covariance and kurtosis from a stream of
/// 3-axis sample blocks. Build it once ([`Estimator::new`] allocates everything), then
/// feed it blocks with [`Estimator::push_block`]; it calls back with each estimate.
pub struct Estimator {
    config: EstimatorConfig,
    intake: Intake,
    work: Box<Work>,
    estimate: Box<Estimate>,
    counters: Counters,
}

impl Estimator {
    /// Allocates every buffer and plans every FFT for `config`.
    pub fn new(config: EstimatorConfig) -> Self {
        let raw = config.raw();
        let n = config.window_samples();
        let fs_hz = config.sample_rate_hz();
        let response = Response::new(raw.ac_corner_hz, &raw.response);
        let mut planner = RealFftPlanner::<f64>::new();
        // Every band the Welch average is asked for: the broadband one and the PSD's.
        let welch_bands: Vec<[f64; 2]> = std::iter::once(raw.broadband_band_hz)
            .chain(raw.psd_bands_hz.iter().copied())
            .collect();
        let work = Work {
            detector: Detector::new(n, fs_hz, &mut planner),
            fit: SineFit::new(n),
            welch: Welch::new(
                config.segment_samples(),
                fs_hz,
                &response,
                &welch_bands,
                &mut planner,
            ),
            kurtosis: Kurtosis::new(n, fs_hz, raw.broadband_band_hz, &response, &mut planner),
            response,
            detected: FixedList::new(),
            fit_state: FitState::default(),
            keep: [false; MAX_TONES],
            invalid: Vec::with_capacity(n),
            invalid_prefix: vec![0; n + 1],
            residual: std::array::from_fn(|_| vec![0.0; n]),
        };
        let intake = Intake {
            window: n,
            hop: config.hop_samples(),
            x_g: std::array::from_fn(|_| vec![0.0; n]),
            flags: vec![0; n],
            times_ns: vec![0; n],
            filled: 0,
            last: None,
            pending_gap: false,
            pending_out_of_order: false,
            rebased: false,
            dropped_run: None,
            inverse_sensitivity: raw.sensitivity_raw_per_g.map(|s| 1.0 / s),
            full_scale_g: raw.full_scale_g.unwrap_or([f64::INFINITY; 3]),
            period_ns: config.sample_period_ns(),
            tolerance_ns: raw
                .timestamp_tolerance_s
                .map_or(config.sample_period_ns() / 2.0, |s| s * 1e9),
        };
        Self {
            config,
            intake,
            work: Box::new(work),
            estimate: Box::default(),
            counters: Counters::default(),
        }
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.config
    }

    /// Samples the current window still needs: the next estimate comes out when this
    /// many more are placed (received, or filled in for a gap). Never 0 between calls
    /// (a full window is estimated and slid at once).
    pub fn samples_to_next_estimate(&self) -> u64 {
        (self.intake.window - self.intake.filled) as u64
    }

    /// Samples between two estimates after the next (the hop): a full window is
    /// estimated and slid by this many.
    pub fn samples_per_estimate(&self) -> u64 {
        self.intake.hop.min(self.intake.window) as u64
    }

    /// Totals since the estimator was built.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Forgets the current window and the stream's sequence (e.g. after a sensor
    /// restart); counters are kept.
    pub fn reset(&mut self) {
        self.intake.filled = 0;
        self.intake.last = None;
        self.intake.pending_gap = false;
        self.intake.pending_out_of_order = false;
        self.intake.rebased = false;
        self.intake.dropped_run = None;
    }

    /// The stream's sequence numbers were taken up again upstream (a continuity check
    /// resynchronised to them, `vibro_service::Continuity`): the next block is taken as
    /// newer than the last whatever its sequence number, and flagged as a gap; its
    /// timestamp decides the rest as for any newer block (contiguous: the window goes
    /// on; dated back: the window restarts; later: a gap). Unlike [`Self::reset`], the
    /// window is kept when time goes on. Without it a block whose sequence number went
    /// back, dated before the window's end, would be dropped as out of order, and so
    /// would every block after it until the old sequence number was passed.
    pub fn resync(&mut self) {
        self.intake.rebased = self.intake.last.is_some();
    }

    /// Takes one block. A block dated before the end of the previous one (beyond the
    /// timestamp tolerance) is dropped as out of order, unless its sequence number is
    /// newer (the source's clock stepped back: the window restarts) or it is the
    /// [`RESYNC_AFTER_DROPS`]th such block in a row, each numbered above the one before
    /// (the stream is taken up again, as after a clock that stepped back). A gap up to one
    /// window long is filled with invalid samples (kept out of the estimate), a longer
    /// one restarts the window. A sequence jump or reset with contiguous time is flagged
    /// as a gap. `on_estimate` is called for every window that fills, possibly several
    /// times for a long block.
    ///
    /// An empty block places no sample, so its timestamp is not looked at (producers
    /// may leave it zero): only its sequence number counts, a jump flagging a gap and
    /// an older one being dropped as out of order, like any block's. The window is
    /// untouched, so empty blocks anywhere in a stream leave its estimates as they are.
    ///
    /// Errors only on an internal FFT failure (buffer sizes are fixed at build, so
    /// this would be a bug); input problems are flagged, never errors.
    pub fn push_block<F: FnMut(&Estimate)>(
        &mut self,
        block: &SampleBlock<'_>,
        mut on_estimate: F,
    ) -> Result<BlockStatus> {
        if block.samples_raw.is_empty() {
            return Ok(self.take_empty(block.seq));
        }
        let mut status = BlockStatus::default();
        let period_ns = self.intake.period_ns;
        let tolerance_ns = self.intake.tolerance_ns;
        if let Some((last_seq, next_t_ns)) = self.intake.last {
            // Time is the authority on where samples sit; the sequence number tells a
            // stale block (duplicate, late) from a clock that stepped back.
            // The difference first, exactly, then to f64 (timestamps since the epoch
            // exceed f64's integer precision).
            let late_ns = (block.t0_ns as i128 - next_t_ns as i128) as f64;
            let rebased = std::mem::take(&mut self.intake.rebased);
            let newer = rebased || block.seq > last_seq;
            if late_ns < -tolerance_ns {
                if !newer && !self.drops_too_many(block.seq) {
                    status.out_of_order = true;
                    self.intake.pending_out_of_order = true;
                    self.counters.blocks_dropped += 1;
                    return Ok(status);
                }
                // A newer block dated in the past: the source's clock stepped back (or
                // the stream is taken up again after RESYNC_AFTER_DROPS drops).
                status.restarted = true;
                self.restart();
            } else {
                let missing = if late_ns > tolerance_ns {
                    (late_ns / period_ns).round() as u64
                } else {
                    0
                };
                // A jump, or a sequence restarting while time goes on (publisher restart),
                // or taken up again upstream.
                status.sequence_gap = rebased || !newer || block.seq > last_seq.saturating_add(1);
                status.gap_samples = missing;
                if status.sequence_gap {
                    self.counters.sequence_gaps += 1;
                    self.intake.pending_gap = true;
                }
                if missing > self.intake.window as u64 {
                    status.restarted = true;
                    self.restart();
                } else {
                    self.counters.gap_samples += missing;
                    for j in 0..missing {
                        let t = next_t_ns.saturating_add(self.intake.offset_ns(j));
                        if self.intake.put([0.0; 3], FLAG_GAP, t) {
                            self.emit(&mut on_estimate, &mut status)?;
                        }
                    }
                }
            }
        }
        status.accepted = true;
        self.intake.dropped_run = None;
        self.counters.blocks_accepted += 1;
        for (j, raw) in block.samples_raw.iter().enumerate() {
            let mut x_g = [0.0; 3];
            let mut flags = 0u8;
            for a in 0..3 {
                x_g[a] = raw[a] * self.intake.inverse_sensitivity[a];
                if x_g[a].abs() >= self.intake.full_scale_g[a] && x_g[a].is_finite() {
                    flags |= FLAG_SATURATED[a];
                }
            }
            if !x_g.iter().all(|v| v.abs() <= MAX_ABS_SAMPLE_G) {
                // A sample is invalid as a whole: the cross-spectra need all axes.
                x_g = [0.0; 3];
                flags = FLAG_NON_FINITE;
                status.non_finite_samples += 1;
            } else if flags != 0 {
                status.saturated_samples += 1;
            }
            let t = block.t0_ns.saturating_add(self.intake.offset_ns(j as u64));
            if self.intake.put(x_g, flags, t) {
                self.emit(&mut on_estimate, &mut status)?;
            }
        }
        self.counters.non_finite_samples += status.non_finite_samples as u64;
        self.counters.saturated_samples += status.saturated_samples as u64;
        let len = block.samples_raw.len() as u64;
        self.intake.last = Some((
            block.seq,
            block.t0_ns.saturating_add(self.intake.offset_ns(len)),
        ));
        Ok(status)
    }

    /// An empty block: its sequence number only (see [`Self::push_block`]).
    fn take_empty(&mut self, seq: u64) -> BlockStatus {
        let mut status = BlockStatus::default();
        if let Some((last_seq, next_t_ns)) = self.intake.last {
            let rebased = std::mem::take(&mut self.intake.rebased);
            if seq <= last_seq && !rebased && !self.drops_too_many(seq) {
                status.out_of_order = true;
                self.intake.pending_out_of_order = true;
                self.counters.blocks_dropped += 1;
                return status;
            }
            if rebased || seq <= last_seq || seq > last_seq.saturating_add(1) {
                status.sequence_gap = true;
                self.counters.sequence_gaps += 1;
                self.intake.pending_gap = true;
            }
            // The next sample is still expected where the last non-empty block said.
            self.intake.last = Some((seq, next_t_ns));
        }
        status.accepted = true;
        self.intake.dropped_run = None;
        self.counters.blocks_accepted += 1;
        status
    }

    /// An out-of-order block numbered `seq`: true when it is the
    /// [`RESYNC_AFTER_DROPS`]th in a row numbered above the one before, to be taken.
    fn drops_too_many(&mut self, seq: u64) -> bool {
        let run = match self.intake.dropped_run {
            Some((last, n)) if seq > last => n + 1,
            _ => 1,
        };
        self.intake.dropped_run = Some((seq, run));
        run >= RESYNC_AFTER_DROPS
    }

    /// Drops the partial window after a discontinuity; the next estimate says so.
    fn restart(&mut self) {
        self.counters.restarts += 1;
        self.intake.filled = 0;
        self.intake.pending_gap = true;
    }

    /// Estimates the full window, hands the estimate over, and slides the window.
    fn emit<F: FnMut(&Estimate)>(
        &mut self,
        on_estimate: &mut F,
        status: &mut BlockStatus,
    ) -> Result<()> {
        self.estimate.index = self.counters.estimates;
        self.work
            .estimate_window(&self.config, &self.intake, &mut self.estimate)?;
        self.intake.pending_gap = false;
        self.intake.pending_out_of_order = false;
        self.counters.estimates += 1;
        status.estimates += 1;
        on_estimate(&self.estimate);
        self.intake.advance();
        Ok(())
    }
}

impl Work {
    fn estimate_window(
        &mut self,
        config: &EstimatorConfig,
        intake: &Intake,
        est: &mut Estimate,
    ) -> Result<()> {
        let raw = config.raw();
        let n = intake.window;
        let fs_hz = config.sample_rate_hz();
        let period_ns = intake.period_ns;

        est.samples = n;
        // The samples saw the base `delay_s` before their stamps: the estimate is dated
        // when the base moved, and its tone phases (fitted about the window's centre)
        // refer to that time.
        let delay_ns = config.delay_ns();
        est.start_ns = intake.times_ns[0].saturating_sub(delay_ns);
        est.end_ns = intake.times_ns[n - 1]
            .saturating_add(intake.offset_ns(1))
            .saturating_sub(delay_ns);
        est.center_ns = intake.times_ns[0]
            .saturating_add(((n as f64 - 1.0) / 2.0 * period_ns).round() as u64)
            .saturating_sub(delay_ns);
        est.tones.clear();
        est.bands.clear();
        est.flags = Default::default();
        est.flags.out_of_order = intake.pending_out_of_order;
        est.flags.gap = intake.pending_gap;

        self.invalid.clear();
        est.saturated_samples = [0; 3];
        for (k, &f) in intake.flags.iter().enumerate() {
            self.invalid_prefix[k] = self.invalid.len() as u32;
            if f & FLAG_INVALID != 0 {
                self.invalid.push(k as u32);
                est.flags.gap |= f & FLAG_GAP != 0;
                est.flags.non_finite |= f & FLAG_NON_FINITE != 0;
            }
            for a in 0..3 {
                if f & FLAG_SATURATED[a] != 0 {
                    est.saturated_samples[a] += 1;
                }
            }
        }
        self.invalid_prefix[n] = self.invalid.len() as u32;
        est.flags.saturated = est.saturated_samples.map(|c| c > 0);
        est.valid_samples = n - self.invalid.len();

        fill_not_estimated(est, raw.broadband_band_hz, &raw.psd_bands_hz);
        if self.invalid.len() as f64 > raw.max_invalid_fraction * n as f64 {
            est.flags.insufficient_data = true;
            est.flags.tone_free = true;
            return Ok(());
        }

        let x = [&intake.x_g[0][..], &intake.x_g[1][..], &intake.x_g[2][..]];
        let threshold = 10f64.powf(raw.tone_snr_threshold_db / 10.0);
        self.detector.run(
            x,
            &self.invalid,
            config.tone_bins(),
            raw.max_tones,
            threshold,
            &mut self.detected,
        )?;
        let mut omega0 = [0.0; MAX_TONES];
        let k = self.detected.len();
        for (w, d) in omega0.iter_mut().zip(self.detected.iter()) {
            *w = TAU * d.bin / n as f64;
        }
        if !self
            .fit
            .fit(x, &self.invalid, &omega0[..k], &mut self.fit_state)
        {
            // Tones too close to separate: report none rather than a wrong fit.
            self.fit.fit(x, &self.invalid, &[], &mut self.fit_state);
        }
        // Keep the tones whose fitted amplitude still passes the threshold. Peaks that
        // only the detector saw are dropped here: with gaps in the window the Hann
        // spectrum has sidelobes the detector cannot tell from tones, the fit can.
        self.keep = [false; MAX_TONES];
        let resolution_hz = fs_hz / n as f64;
        for (i, keep) in self.keep.iter_mut().enumerate().take(self.fit_state.tones) {
            let bin = self.fit_state.omega[i] * n as f64 / TAU;
            let amp = self.fit_state.amplitudes(i);
            *keep = (0..3).any(|a| {
                let (ca, cb) = amp[a];
                let floor = self.detector.floor_psd_at_bin(a, bin);
                0.5 * (ca * ca + cb * cb) / (floor * resolution_hz) >= threshold
            });
        }
        self.fit.residual(
            x,
            &self.fit_state,
            &self.keep,
            &self.invalid,
            &mut self.residual,
        );
        self.write_tones(fs_hz, n - self.invalid.len(), est);

        let r = [
            &self.residual[0][..],
            &self.residual[1][..],
            &self.residual[2][..],
        ];
        let segments = self.welch.run(r, n, &self.invalid_prefix)?;
        est.broadband.welch_segments = segments;
        est.broadband.welch_segment_samples = config.segment_samples();
        if segments == 0 {
            est.flags.insufficient_data = true;
            return Ok(());
        }
        self.write_broadband(raw.broadband_band_hz, est)?;
        for (band, out) in raw.psd_bands_hz.iter().zip(est.bands.as_mut_slice()) {
            let p = self.welch.band_power(band[0], band[1]);
            let width = band[1] - band[0];
            for a in 0..3 {
                out.psd_g2_per_hz[a] = p.auto_g2[a] / width;
                out.psd_u_g2_per_hz[a] = p.auto_var_g4[a].sqrt() / width;
                out.rms_g[a] = p.auto_g2[a].max(0.0).sqrt();
            }
        }
        let mut kurtosis = [(f64::NAN, 0); 3];
        if self.invalid.is_empty() {
            // The residual's band from the detector's plain DFT less the kept tones.
            let plain = std::array::from_fn(|a| self.detector.plain_spectrum(a));
            self.kurtosis
                .run_clean(plain, &self.fit_state, &self.keep, &mut kurtosis)?;
        } else {
            for (a, k) in kurtosis.iter_mut().enumerate() {
                *k = self
                    .kurtosis
                    .run(a, &self.residual[a], &self.invalid_prefix)?;
            }
        }
        for (a, &(kurt, used)) in kurtosis.iter().enumerate() {
            let rho4 =
                self.welch
                    .rho4_sum(a, raw.broadband_band_hz[0], raw.broadband_band_hz[1])?;
            est.broadband.kurtosis[a] = kurt;
            est.broadband.kurtosis_u[a] = (24.0 * rho4 / used as f64).sqrt();
            if kurt.is_nan() {
                est.flags.insufficient_data = true;
            }
        }
        Ok(())
    }

    /// Converts the fitted tones into estimates (see [`ToneEstimate`] for the model).
    fn write_tones(&self, fs_hz: f64, valid: usize, est: &mut Estimate) {
        let s = &self.fit_state;
        let window_s = valid as f64 / fs_hz;
        let resolution_hz = fs_hz / self.fit_samples() as f64;
        for i in (0..s.tones).filter(|&i| self.keep[i]) {
            let f_hz = s.omega[i] * fs_hz / TAU;
            let bin = f_hz / resolution_hz;
            let mut t = ToneEstimate {
                frequency_hz: f_hz,
                ..Default::default()
            };
            // Fisher information of the frequency adds over the axes (Kay 1993, ex.
            // 3.14: var(f) = 12 S / ((2 pi)^2 A^2 T^3) per axis, S the one-sided floor PSD).
            let mut info = 0.0;
            let amp = s.amplitudes(i);
            for a in 0..3 {
                let (ca, cb) = amp[a];
                let amp = ca.hypot(cb);
                // A cos + B sin = R sin(w n + phi) with A = R sin phi, B = R cos phi.
                let phase = ca.atan2(cb);
                let floor = self.detector.floor_psd_at_bin(a, bin);
                let amp_u = (floor / window_s).sqrt();
                let h = self.response.gain(a, f_hz);
                let gain = h.norm();
                t.amplitude_g[a] = amp / gain;
                t.amplitude_u_g[a] = amp_u / gain;
                t.phase_rad[a] = wrap_pi(phase - h.arg());
                t.phase_u_rad[a] = (amp_u / amp).min(PI);
                t.snr_db[a] = 10.0 * (0.5 * amp * amp / (floor * resolution_hz)).log10();
                info += amp * amp / floor;
            }
            t.frequency_u_hz = (12.0 / (TAU * TAU * window_s.powi(3) * info)).sqrt();
            est.tones.push(t);
        }
        est.tones
            .as_mut_slice()
            .sort_unstable_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
        est.flags.tone_free = est.tones.is_empty();
    }

    fn fit_samples(&self) -> usize {
        self.residual[0].len()
    }

    fn write_broadband(&mut self, band_hz: [f64; 2], est: &mut Estimate) -> Result<()> {
        let p = self.welch.band_power(band_hz[0], band_hz[1]);
        let b = &mut est.broadband;
        // Degrees of freedom of each axis' band power: var = 2 P^2 / nu.
        let nu: [f64; 3] =
            std::array::from_fn(|a| 2.0 * p.auto_g2[a] * p.auto_g2[a] / p.auto_var_g4[a]);
        for a in 0..3 {
            b.rms_g[a] = p.auto_g2[a].max(0.0).sqrt();
            // d(sqrt P) = dP / (2 sqrt P).
            b.rms_u_g[a] = p.auto_var_g4[a].sqrt() / (2.0 * b.rms_g[a]);
            b.covariance_g2[a][a] = p.auto_g2[a];
            b.covariance_u_g2[a][a] = p.auto_var_g4[a].sqrt();
        }
        for (pair, &(i, j)) in PAIRS.iter().enumerate() {
            let c = p.cross_g2[pair];
            // Gaussian cross-power: var = (P_i P_j + C_ij^2) / nu (Bendat & Piersol 2010, 9.3).
            let u = ((p.auto_g2[i] * p.auto_g2[j] + c * c) * 2.0 / (nu[i] + nu[j])).sqrt();
            b.covariance_g2[i][j] = c;
            b.covariance_g2[j][i] = c;
            b.covariance_u_g2[i][j] = u;
            b.covariance_u_g2[j][i] = u;
        }
        Ok(())
    }
}

/// Resets the values of `est` to "not estimated" (NaN) with the configured bands.
fn fill_not_estimated(est: &mut Estimate, broadband_hz: [f64; 2], bands_hz: &[[f64; 2]]) {
    let nan3 = [f64::NAN; 3];
    est.broadband = crate::output::Broadband {
        f_lo_hz: broadband_hz[0],
        f_hi_hz: broadband_hz[1],
        rms_g: nan3,
        rms_u_g: nan3,
        covariance_g2: [nan3; 3],
        covariance_u_g2: [nan3; 3],
        kurtosis: nan3,
        kurtosis_u: nan3,
        welch_segments: 0,
        welch_segment_samples: 0,
    };
    est.bands.clear();
    for b in bands_hz {
        est.bands.push(BandEstimate {
            f_lo_hz: b[0],
            f_hi_hz: b[1],
            psd_g2_per_hz: nan3,
            psd_u_g2_per_hz: nan3,
            rms_g: nan3,
        });
    }
}

fn wrap_pi(x: f64) -> f64 {
    let y = (x + PI).rem_euclid(TAU) - PI;
    if y <= -PI {
        y + TAU
    } else {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{EstimatorConfig, EstimatorConfigRaw};

    /// The estimates of `samples` stamped from `t0_ns`, with the chain's delay `delay_s`.
    fn run(samples: &[[f64; 3]], t0_ns: u64, fs_hz: f64, delay_s: f64) -> Vec<Estimate> {
        let mut raw = EstimatorConfigRaw::new(fs_hz, [1.0; 3]);
        raw.delay_s = delay_s;
        let mut est = Estimator::new(EstimatorConfig::try_from(raw).unwrap());
        let mut out = Vec::new();
        let period_ns = 1e9 / fs_hz;
        for (seq, chunk) in samples.chunks(256).enumerate() {
            let block = SampleBlock {
                seq: seq as u64,
                t0_ns: t0_ns + ((seq * 256) as f64 * period_ns).round() as u64,
                samples_raw: chunk,
            };
            est.push_block(&block, |e| out.push(*e)).unwrap();
        }
        out
    }

    /// A chain delay of D dates every estimate D earlier (start, end and centre, to the
    /// ns) and leaves the fitted tone unchanged, so its phase is the base's phase at the
    /// new centre: the samples stamped `s` are the base's motion at `s - D`.
    #[test]
    fn a_chain_delay_dates_the_estimates_when_the_base_moved() {
        let (fs_hz, f_hz, phi_rad, delay_s) = (8192.0, 137.0, 0.7, 0.00156);
        let delay_ns = 1_560_000;
        let t0_ns = 2_000_000_000u64;
        // The sample stamped t saw the base at t - D: base(t) = sin(2 pi f t + phi).
        let samples: Vec<[f64; 3]> = (0..3 * 8192)
            .map(|k| {
                let stamp_s = t0_ns as f64 * 1e-9 + k as f64 / fs_hz;
                let base = (TAU * f_hz * (stamp_s - delay_s) + phi_rad).sin();
                [base, 0.5 * base, -0.25 * base]
            })
            .collect();
        let plain = run(&samples, t0_ns, fs_hz, 0.0);
        let delayed = run(&samples, t0_ns, fs_hz, delay_s);
        assert_eq!(plain.len(), 5);
        assert_eq!(plain.len(), delayed.len());
        for (p, d) in plain.iter().zip(&delayed) {
            assert_eq!(p.start_ns - d.start_ns, delay_ns);
            assert_eq!(p.end_ns - d.end_ns, delay_ns);
            assert_eq!(p.center_ns - d.center_ns, delay_ns);
            assert_eq!(p.tones.len(), 1);
            let (tp, td) = (p.tones[0], d.tones[0]);
            assert_eq!(tp.phase_rad, td.phase_rad);
            assert_eq!(tp.amplitude_g, td.amplitude_g);
            // The base's phase at the delayed estimate's centre (closed form).
            let centre_s = d.center_ns as f64 * 1e-9;
            let base_phase = wrap_pi(TAU * f_hz * centre_s + phi_rad);
            for a in 0..2 {
                let dphi = wrap_pi(td.phase_rad[a] - base_phase).abs();
                assert!(dphi < 1e-6, "axis {a}: off the base's phase by {dphi} rad");
            }
            let dphi = wrap_pi(td.phase_rad[2] - wrap_pi(base_phase + PI)).abs();
            assert!(dphi < 1e-6, "axis 2: off the base's phase by {dphi} rad");
        }
        // Without the delay the phase is the base's a delay later, 2 pi f D away.
        let centre_s = plain[0].center_ns as f64 * 1e-9;
        let dphi = wrap_pi(plain[0].tones[0].phase_rad[0] - (TAU * f_hz * centre_s + phi_rad));
        assert!((dphi + TAU * f_hz * delay_s).abs() < 1e-6, "{dphi}");
    }

    #[test]
    fn a_delay_outside_0_to_1_s_is_refused_with_its_value() {
        for bad in [-0.001, 2.0, f64::NAN] {
            let mut raw = EstimatorConfigRaw::new(1000.0, [1.0; 3]);
            raw.delay_s = bad;
            let e = EstimatorConfig::try_from(raw).unwrap_err().to_string();
            assert!(
                e.contains(&format!(
                    "delay_s = {bad}: must be finite and 0 <= delay <= 1 s"
                )),
                "{e}"
            );
        }
    }
}
