//! The wire types. Field order puts every 8-byte field first, then 4-byte, then 1-byte
//! fields, then explicit padding, so the layout is the same for any C compiler and there
//! are no holes. Sample arrays are `[sample][unit]`: unit (or axis) index 0, 1, 2 is
//! accelerometer AK1..AK3 and the vibration sensor VD1..VD3 mounted next to it (RIG.md).
//!
//! Slots at or beyond `count` are not part of the message: producers should zero them,
//! consumers must ignore them (the MCAP codec does not store them).

use crate::layout::wire_struct;
use crate::{Error, Result, ACCEL_BLOCK_MAX, MAX_BANDS, MAX_TONES, UNITS, VIB_BLOCK_MAX};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;

/// Flag bits of [`AccelBlock::flags`]. Bits not listed are reserved and zero.
pub mod accel_flags {
    /// Samples were lost between the previous block and this one (`first_sample_index`
    /// jumped, or the producer knows it dropped readings).
    pub const GAP_BEFORE: u32 = 1 << 0;
    /// At least one sample of the block is at or beyond the accelerometer's output range.
    pub const SATURATED: u32 = 1 << 1;
    /// Every defined bit.
    pub const ALL: u32 = GAP_BEFORE | SATURATED;
}

/// Flag bits of [`VibBlock::flags`]. Bits not listed are reserved and zero.
pub mod vib_flags {
    /// Samples were lost between the previous block and this one.
    pub const GAP_BEFORE: u32 = 1 << 0;
    /// At least one sample of the block is at or beyond the sensor's full scale.
    pub const SATURATED: u32 = 1 << 1;
    /// The producer's stream ends here (a replay's last block, a rig stopping): the
    /// block is empty (`count` 0) and continues the stream's `seq`, index and time. A
    /// consumer waiting for samples past it (the compensator's waveform stage) stops
    /// waiting.
    pub const END_OF_STREAM: u32 = 1 << 2;
    /// Every defined bit.
    pub const ALL: u32 = GAP_BEFORE | SATURATED | END_OF_STREAM;
}

/// Flag bits of [`VibEstimate::flags`], mirroring `vibro_dsp::Flags` (plus the estimator
/// service's `RATE_MISMATCH`). Bits not listed are reserved and zero.
pub mod estimate_flags {
    /// No tone passed the detection threshold.
    pub const TONE_FREE: u32 = 1 << 0;
    /// Samples were missing in or just before the window.
    pub const GAP: u32 = 1 << 1;
    /// NaN, infinite or absurd samples were kept out of the estimate.
    pub const NON_FINITE: u32 = 1 << 2;
    /// Out-of-order or overlapping blocks were dropped since the previous estimate.
    pub const OUT_OF_ORDER: u32 = 1 << 3;
    /// Too few valid samples or Welch segments: some values are NaN.
    pub const INSUFFICIENT_DATA: u32 = 1 << 4;
    /// The window spans vibration blocks the estimator service dropped because their
    /// `sample_period_ns` disagreed with its configured `sample_rate_hz`: their samples
    /// were kept out (missing from the window, so `GAP` is normally set too). Set by the
    /// service, not by `vibro_dsp`, which never sees those samples.
    pub const RATE_MISMATCH: u32 = 1 << 5;
    /// Axis 0 had samples at or over full scale; axis `i` is `SATURATED_AXIS0 << i`.
    pub const SATURATED_AXIS0: u32 = 1 << 8;
    /// Every defined bit.
    pub const ALL: u32 = TONE_FREE
        | GAP
        | NON_FINITE
        | OUT_OF_ORDER
        | INSUFFICIENT_DATA
        | RATE_MISMATCH
        | SATURATED_AXIS0
        | (SATURATED_AXIS0 << 1)
        | (SATURATED_AXIS0 << 2);
}

/// Flag bits of [`CompensatedBlock::flags`]. Bits not listed are reserved and zero.
pub mod compensation_flags {
    /// The vibration estimate used is older than the compensator's staleness limit.
    pub const VIBRATION_ESTIMATE_STALE: u32 = 1 << 0;
    /// No vibration estimate was available: `a3_g`/`a4_g` equal `a2_g`, `det_g`/`rand_g` are 0.
    pub const ESTIMATE_MISSING: u32 = 1 << 1;
    /// Only the main error was removed (by configuration or because the estimate was
    /// unusable): `a3_g`/`a4_g` equal `a2_g`.
    pub const MAIN_ONLY: u32 = 1 << 2;
    /// The input block had samples lost before it.
    pub const INPUT_GAP: u32 = 1 << 3;
    /// At least one input sample was NaN or infinite; its outputs are NaN.
    pub const NON_FINITE_INPUT: u32 = 1 << 4;
    /// The estimate used carried quality flags (gap, non-finite, insufficient data, ...).
    pub const ESTIMATE_FLAGGED: u32 = 1 << 5;
    /// The input's `sample_period_ns` differs from the previous block's: the estimate was
    /// mapped to the new output interval and the stream kernel started afresh.
    pub const RATE_CHANGE: u32 = 1 << 6;
    /// The input's `t0_ns` is more than half a sample period away from where the
    /// previous block's timing and the sample index put it: the accelerometer clock
    /// stepped (back or forward) or the timestamp is corrupt. The timestamp is used as
    /// given (staleness, output).
    pub const TIME_JUMP: u32 = 1 << 7;
    /// The latest estimate's window ends more than the compensator's lead limit after
    /// the block's last sample (the two streams' clocks disagree): it was not used, the
    /// block is compensated for the main error only (`MAIN_ONLY`).
    pub const ESTIMATE_AHEAD: u32 = 1 << 8;
    /// The input block was flagged `SATURATED` by its producer: some readings are clipped
    /// and their compensated values are wrong by the clipped amount.
    pub const INPUT_SATURATED: u32 = 1 << 9;
    /// The compensator's extended model (`model = ...`, docs/lab.md) also removed its
    /// effects' VE: `rand_g` holds the random VE plus the effects', so that
    /// `a4 = a3 - rand` still holds.
    pub const MODEL_EFFECTS: u32 = 1 << 10;
    /// The waveform stage made the block (MODEL.md section 12): `a4_g` is each reading
    /// solved for its interval-mean acceleration from the vibration sensors' samples.
    /// The block carries the estimate stage's answer beside it: `a3_g` is that stage's
    /// whole answer (its `a4`, stages (19) and (20) together), `det_g = a2 - a3`, and
    /// `rand_g = a3 - a4` is what the waveform stage removes beyond it; `a1_g`, `a2_g`
    /// and `main_g` are stages (17) and (18) as always. The estimate flags (missing,
    /// stale, ahead, flagged) describe `a3_g`; `MAIN_ONLY` is never set with it.
    pub const WAVEFORM: u32 = 1 << 11;
    /// The compensator runs the waveform stage, but the samples did not cover this
    /// block's readings in time (missing, late, a gap, a break in the sensors'
    /// stream, a flagged sensor block): the estimate stage (17)-(20) made it.
    pub const WAVEFORM_FALLBACK: u32 = 1 << 12;
    /// Every defined bit.
    pub const ALL: u32 = VIBRATION_ESTIMATE_STALE
        | ESTIMATE_MISSING
        | MAIN_ONLY
        | INPUT_GAP
        | NON_FINITE_INPUT
        | ESTIMATE_FLAGGED
        | RATE_CHANGE
        | TIME_JUMP
        | ESTIMATE_AHEAD
        | INPUT_SATURATED
        | MODEL_EFFECTS
        | WAVEFORM
        | WAVEFORM_FALLBACK;
}

/// Flag bits of [`TruthBlock::flags`]. Bits not listed are reserved and zero.
pub mod truth_flags {
    /// Samples were lost between the previous block and this one.
    pub const GAP_BEFORE: u32 = 1 << 0;
    /// `vib_error_ia_g` holds the true mean vibration error; without this bit it is NaN.
    pub const VIB_ERROR_KNOWN: u32 = 1 << 1;
    /// A rig's reference (`log import --rig`, docs/logs.md): `a_l_ia_g` is the rig's
    /// reference (NaN for a reading it does not cover), `a_sensed_ia_g` is not known
    /// (NaN): the vibration each unit sensed comes from the vibration sensors.
    pub const SENSED_UNKNOWN: u32 = 1 << 2;
    /// Every defined bit.
    pub const ALL: u32 = GAP_BEFORE | VIB_ERROR_KNOWN | SENSED_UNKNOWN;
}

wire_struct! {
    /// Raw outputs of the accelerometer triad: each sample is a unit's mean output over one
    /// output interval `T = sample_period_ns`. Sample `i` is the mean over
    /// `(t0_ns + (i - 1) T, t0_ns + i T]`: `t0_ns` is the END of sample 0's interval, the
    /// time the reading is latched (RIG.md: "read as means over navigation intervals").
    type_name = "vibrocomp::AccelBlock::v5";
    pub struct AccelBlock {
        /// Producer's block counter: +1 per published block, from 0.
        pub seq: u64,
        /// Index of sample 0 in the producer's sample stream since it started.
        pub first_sample_index: u64,
        /// End of sample 0's averaging interval (its latch time).
        pub t0_ns: u64,
        /// Output interval `T`.
        pub sample_period_ns: u64,
        /// Producer's clock when it published the block.
        pub publish_ns: u64,
        /// Mean output `U` of each unit over each interval, `[sample][unit]`.
        pub output_v: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Valid samples in `output_v`, `0..=ACCEL_BLOCK_MAX`.
        pub count: u32,
        /// Identifies the producer (rig or simulator instance).
        pub source_id: u32,
        /// [`accel_flags`] bits.
        pub flags: u32,
        /// Zero.
        pub _pad: [u8; 4],
    }
}

wire_struct! {
    /// Vibration-sensor samples, one sensor per accelerometer unit (axis index = unit
    /// index), in the sensor's raw output (volts: sensitivity, AC coupling and response
    /// are the estimator's job). Sample `i` was taken at `t0_ns + i T`. `f64` keeps
    /// simulated samples bit-exact through the system.
    type_name = "vibrocomp::VibBlock::v5";
    pub struct VibBlock {
        /// Producer's block counter: +1 per published block, from 0.
        pub seq: u64,
        /// Index of sample 0 in the producer's sample stream since it started.
        pub first_sample_index: u64,
        /// Time of sample 0.
        pub t0_ns: u64,
        /// Sampling interval `T`.
        pub sample_period_ns: u64,
        /// Producer's clock when it published the block.
        pub publish_ns: u64,
        /// Sensor output, `[sample][axis]`.
        pub sample_v: [[f64; UNITS]; VIB_BLOCK_MAX],
        /// Valid samples in `sample_v`, `0..=VIB_BLOCK_MAX`.
        pub count: u32,
        /// Identifies the producer (rig or simulator instance).
        pub source_id: u32,
        /// [`vib_flags`] bits.
        pub flags: u32,
        /// Zero.
        pub _pad: [u8; 4],
    }
}

wire_struct! {
    /// One window's vibration estimate: a field-by-field mirror of `vibro_dsp::Estimate`
    /// (tones, broadband, bands as struct-of-arrays; `usize` counts as `u32`; `Flags` as
    /// [`estimate_flags`] bits) plus stream bookkeeping. Values that could not be estimated
    /// are NaN. Per-axis arrays are in sensor-axis order; tone and band slots at or beyond
    /// `tone_count`/`band_count` are not part of the message.
    type_name = "vibrocomp::VibEstimate::v5";
    pub struct VibEstimate {
        /// Estimator service's publish counter: +1 per published estimate, from 0.
        pub seq: u64,
        /// `Estimate::index`: estimates emitted since the estimator was built.
        pub index: u64,
        /// `seq` of the last [`VibBlock`] that entered the window.
        pub source_seq: u64,
        /// Estimator service's clock when it published the estimate.
        pub publish_ns: u64,
        /// Timestamp of the window's first sample.
        pub start_ns: u64,
        /// One sample period after the window's last sample (exclusive end).
        pub end_ns: u64,
        /// Mid-point of the window: the reference time of the tone phases.
        pub center_ns: u64,
        /// Lower edge of the broadband band.
        pub broadband_f_lo_hz: f64,
        /// Upper edge of the broadband band.
        pub broadband_f_hi_hz: f64,
        /// Broadband RMS per axis (`sigma_i` of MODEL.md), tones removed.
        pub broadband_rms_g: [f64; UNITS],
        /// Standard uncertainty of `broadband_rms_g`.
        pub broadband_rms_u_g: [f64; UNITS],
        /// Covariance `K_ij(0)` over the band, `[i][j]`.
        pub broadband_covariance_g2: [[f64; UNITS]; UNITS],
        /// Standard uncertainty of `broadband_covariance_g2`.
        pub broadband_covariance_u_g2: [[f64; UNITS]; UNITS],
        /// Kurtosis `E[x^4] / E[x^2]^2` per axis (3 for Gaussian), dimensionless.
        pub broadband_kurtosis: [f64; UNITS],
        /// Standard uncertainty of `broadband_kurtosis` under the Gaussian hypothesis.
        pub broadband_kurtosis_u: [f64; UNITS],
        /// Tone frequency, per tone.
        pub tone_frequency_hz: [f64; MAX_TONES],
        /// Standard uncertainty of `tone_frequency_hz`.
        pub tone_frequency_u_hz: [f64; MAX_TONES],
        /// Tone amplitude `[tone][axis]` (`aB_i` of MODEL.md).
        pub tone_amplitude_g: [[f64; UNITS]; MAX_TONES],
        /// Standard uncertainty of `tone_amplitude_g`.
        pub tone_amplitude_u_g: [[f64; UNITS]; MAX_TONES],
        /// Tone phase at `center_ns`, `[tone][axis]`.
        pub tone_phase_rad: [[f64; UNITS]; MAX_TONES],
        /// Standard uncertainty of `tone_phase_rad`.
        pub tone_phase_u_rad: [[f64; UNITS]; MAX_TONES],
        /// Tone power over the local noise floor, `[tone][axis]`.
        pub tone_snr_db: [[f64; UNITS]; MAX_TONES],
        /// Lower edge of each band.
        pub band_f_lo_hz: [f64; MAX_BANDS],
        /// Upper edge of each band.
        pub band_f_hi_hz: [f64; MAX_BANDS],
        /// Mean one-sided PSD over the band, `[band][axis]`.
        pub band_psd_g2_per_hz: [[f64; UNITS]; MAX_BANDS],
        /// Standard uncertainty of `band_psd_g2_per_hz`.
        pub band_psd_u_g2_per_hz: [[f64; UNITS]; MAX_BANDS],
        /// RMS in the band, `[band][axis]`.
        pub band_rms_g: [[f64; UNITS]; MAX_BANDS],
        /// Samples in the window, valid or not.
        pub samples: u32,
        /// Samples that entered the estimate.
        pub valid_samples: u32,
        /// Samples at or over full scale, per axis.
        pub saturated_samples: [u32; UNITS],
        /// Welch segments averaged for the broadband values.
        pub broadband_welch_segments: u32,
        /// Valid tone slots, `0..=MAX_TONES`.
        pub tone_count: u32,
        /// Valid band slots, `0..=MAX_BANDS`.
        pub band_count: u32,
        /// [`estimate_flags`] bits.
        pub flags: u32,
        /// Samples per Welch segment of the band PSDs (their bin width is the sample
        /// rate over it): what a consumer needs to undo the window's leakage between
        /// bands (`vibro_effects::spectrum`). 0: not stated (an estimator before this
        /// field, which was zero padding in the same place).
        pub welch_segment_samples: u32,
    }
}

wire_struct! {
    /// Compensated accelerometer readings, one output block per input [`AccelBlock`], in
    /// acceleration units along each unit's IA: the stages of MODEL.md section 7,
    /// `a(1)` (17) to `a(4)` (20), and the corrections removed between them
    /// (`a2 = a1 - main`, `a3 = a2 - det`, `a4 = a3 - rand`). Sample timing is the input's.
    type_name = "vibrocomp::CompensatedBlock::v5";
    pub struct CompensatedBlock {
        /// Compensator's publish counter: +1 per published block, from 0.
        pub seq: u64,
        /// `seq` of the input [`AccelBlock`].
        pub input_seq: u64,
        /// The input's `first_sample_index`.
        pub first_sample_index: u64,
        /// The input's `t0_ns` (end of sample 0's averaging interval).
        pub t0_ns: u64,
        /// The input's `sample_period_ns`.
        pub sample_period_ns: u64,
        /// `seq` of the [`VibEstimate`] used (0 with `ESTIMATE_MISSING`).
        pub estimate_seq: u64,
        /// The input's `publish_ns`.
        pub input_publish_ns: u64,
        /// Compensator's clock when it received the input.
        pub recv_ns: u64,
        /// Compensator's clock when it published this block.
        pub publish_ns: u64,
        /// End of the last sample's interval minus the estimate's `end_ns`: how old the
        /// vibration estimate is relative to the data (negative if the estimate is newer).
        pub estimate_age_ns: i64,
        /// First approximation `a(1)`, [P2 (17)], `[sample][unit]`.
        pub a1_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Main error removed, `a(2)`, [P2 (18)].
        pub a2_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Deterministic vibration error removed, `a(3)`, [P2 (19)].
        pub a3_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Random vibration error removed, `a(4)`, [P2 (20)]: the compensated reading.
        pub a4_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Main-error correction `dO(a(1))`, `a1 - a2`.
        pub main_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Deterministic VE correction, `a2 - a3`.
        pub det_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Random VE correction, `a3 - a4`.
        pub rand_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Valid samples, equal to the input's `count`.
        pub count: u32,
        /// The input's `source_id`.
        pub source_id: u32,
        /// [`compensation_flags`] bits.
        pub flags: u32,
        /// [`CompensationMode`] code.
        pub mode: u8,
        /// Zero.
        pub _pad: [u8; 3],
    }
}

wire_struct! {
    /// The simulator's truth for each accelerometer output sample, aligned with the
    /// [`AccelBlock`] of the same `seq` (same `first_sample_index`, `t0_ns`, `count`).
    type_name = "vibrocomp::TruthBlock::v5";
    pub struct TruthBlock {
        /// `seq` of the matching [`AccelBlock`].
        pub seq: u64,
        /// `first_sample_index` of the matching [`AccelBlock`].
        pub first_sample_index: u64,
        /// `t0_ns` of the matching [`AccelBlock`].
        pub t0_ns: u64,
        /// `sample_period_ns` of the matching [`AccelBlock`].
        pub sample_period_ns: u64,
        /// Simulator's clock when it published the block.
        pub publish_ns: u64,
        /// True flight (slowly varying) acceleration along each unit's IA, `aL3` of
        /// MODEL.md, mean over the sample's interval, `[sample][unit]`.
        pub a_l_ia_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// The whole acceleration each unit sensed along its IA (flight plus the
        /// vibration's own motion, after input effects such as a mount resonance), mean
        /// over the sample's interval, `[sample][unit]`: what a perfect accelerometer
        /// would output, so `a(k) - a_sensed_ia_g` is the error left after stage `k`.
        pub a_sensed_ia_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// True mean vibration error along each unit's IA over the interval (NaN unless
        /// `VIB_ERROR_KNOWN`).
        pub vib_error_ia_g: [[f64; UNITS]; ACCEL_BLOCK_MAX],
        /// Valid samples, equal to the matching block's `count`.
        pub count: u32,
        /// The matching block's `source_id`.
        pub source_id: u32,
        /// [`truth_flags`] bits.
        pub flags: u32,
        /// Zero.
        pub _pad: [u8; 4],
    }
}

wire_struct! {
    /// A service's periodic health report, published on `{prefix}heartbeat/{service}`.
    /// Counters are cumulative since the service started.
    type_name = "vibrocomp::Heartbeat::v5";
    pub struct Heartbeat {
        /// Heartbeat counter: +1 per heartbeat, from 0.
        pub seq: u64,
        /// Service's clock when it published the heartbeat.
        pub publish_ns: u64,
        /// Time since the service started.
        pub uptime_ns: u64,
        /// Messages received.
        pub received: u64,
        /// Messages published.
        pub published: u64,
        /// Input messages or samples known lost (sequence gaps, overflow).
        pub lost: u64,
        /// Outputs produced with a stale or missing input (e.g. a stale estimate).
        pub stale: u64,
        /// Median receive-to-publish latency over the last period.
        pub latency_p50_ns: u64,
        /// 99th percentile receive-to-publish latency over the last period.
        pub latency_p99_ns: u64,
        /// Contiguous input samples the service still needs before its next output
        /// (the estimator: what its window lacks); 0 when not reported, meaning that
        /// any input may cause output. A lock-stepped replay need not wait for the
        /// service while the samples it sent stay below this (docs/messages.md).
        pub input_samples_to_output: u64,
        /// Input samples between two outputs once the next has come out (the
        /// estimator's hop); 0 when not reported.
        pub input_samples_per_output: u64,
        /// Input messages taken as out of order (a sequence number behind the stream's),
        /// over all the service's inputs. A service drops them, the recorder records them.
        pub out_of_order: u64,
        /// Times the service took an input stream up again after a run of out-of-order
        /// messages from one producer (a reset or glitched counter; docs/reliability.md);
        /// the recorder: times its data timeline was taken up again.
        pub resyncs: u64,
        /// [`ServiceId`] code.
        pub service: u8,
        /// [`ServiceState`] code.
        pub state: u8,
        /// Zero.
        pub _pad: [u8; 6],
    }
}

wire_struct! {
    /// One log line of a service, published on `{prefix}log/{service}` beside what it
    /// writes to stderr: for viewers (`foxglove.Log` in the view) and recordings. Never
    /// published per sample (the services log a summary per period).
    type_name = "vibrocomp::LogLine::v5";
    pub struct LogLine {
        /// Line counter: +1 per line, from 0.
        pub seq: u64,
        /// Service's `CLOCK_MONOTONIC` time when it published the line.
        pub publish_ns: u64,
        /// Wall-clock time of the line (Unix epoch), ns.
        pub wall_ns: u64,
        /// [`ServiceId`] code.
        pub service: u8,
        /// [`LogLevel`] code.
        pub level: u8,
        /// Bytes of `text` used (UTF-8), at most [`crate::LOG_TEXT_MAX`].
        pub len: u16,
        /// Zero.
        pub _pad: [u8; 4],
        /// The line: `target: message key=value ...`.
        pub text: [u8; crate::LOG_TEXT_MAX],
    }
}

impl LogLine {
    /// A line of `service` at `level`: `text` cut to [`crate::LOG_TEXT_MAX`] bytes at a
    /// character boundary.
    pub fn new(service: ServiceId, level: LogLevel, text: &str) -> Self {
        let mut end = text.len().min(crate::LOG_TEXT_MAX);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        let mut m = Self::ZEROED;
        m.service = service.code();
        m.level = level.code();
        m.len = end as u16;
        m.text[..end].copy_from_slice(&text.as_bytes()[..end]);
        m
    }

    /// The text (a byte sequence that is not UTF-8 shows its invalid bytes as U+FFFD).
    pub fn text(&self) -> std::borrow::Cow<'_, str> {
        let n = usize::from(self.len).min(crate::LOG_TEXT_MAX);
        String::from_utf8_lossy(&self.text[..n])
    }

    fn validate_counts(&self) -> Result<()> {
        check_count("LogLine.len", u32::from(self.len), crate::LOG_TEXT_MAX)?;
        std::str::from_utf8(&self.text[..usize::from(self.len)]).map_err(|e| Error::NotUtf8 {
            field: "LogLine.text",
            valid_up_to: e.valid_up_to(),
        })?;
        Ok(())
    }
}

fn check_count(field: &'static str, count: u32, max: usize) -> Result<()> {
    if usize::try_from(count).is_ok_and(|c| c <= max) {
        Ok(())
    } else {
        Err(Error::CountOutOfRange { field, count, max })
    }
}

impl AccelBlock {
    /// The valid samples, `[sample][unit]` (at most `ACCEL_BLOCK_MAX`, even if `count` is larger).
    pub fn samples_v(&self) -> &[[f64; UNITS]] {
        &self.output_v[..(self.count as usize).min(ACCEL_BLOCK_MAX)]
    }
}

impl VibBlock {
    /// The valid samples, `[sample][axis]` (at most `VIB_BLOCK_MAX`, even if `count` is larger).
    pub fn samples_v(&self) -> &[[f64; UNITS]] {
        &self.sample_v[..(self.count as usize).min(VIB_BLOCK_MAX)]
    }
}

/// The kinds of wire type, for code that handles any of them (recorders, replay).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MessageKind {
    AccelBlock,
    VibBlock,
    VibEstimate,
    CompensatedBlock,
    TruthBlock,
    Heartbeat,
    LogLine,
}

impl MessageKind {
    /// Every kind, in declaration order.
    pub const ALL: [MessageKind; 7] = [
        MessageKind::AccelBlock,
        MessageKind::VibBlock,
        MessageKind::VibEstimate,
        MessageKind::CompensatedBlock,
        MessageKind::TruthBlock,
        MessageKind::Heartbeat,
        MessageKind::LogLine,
    ];

    /// The Rust type's name, e.g. `AccelBlock`.
    pub const fn name(self) -> &'static str {
        match self {
            MessageKind::AccelBlock => "AccelBlock",
            MessageKind::VibBlock => "VibBlock",
            MessageKind::VibEstimate => "VibEstimate",
            MessageKind::CompensatedBlock => "CompensatedBlock",
            MessageKind::TruthBlock => "TruthBlock",
            MessageKind::Heartbeat => "Heartbeat",
            MessageKind::LogLine => "LogLine",
        }
    }

    /// The iceoryx2 payload type name, e.g. `vibrocomp::AccelBlock::v5`.
    pub const fn type_name(self) -> &'static str {
        match self {
            MessageKind::AccelBlock => AccelBlock::TYPE_NAME,
            MessageKind::VibBlock => VibBlock::TYPE_NAME,
            MessageKind::VibEstimate => VibEstimate::TYPE_NAME,
            MessageKind::CompensatedBlock => CompensatedBlock::TYPE_NAME,
            MessageKind::TruthBlock => TruthBlock::TYPE_NAME,
            MessageKind::Heartbeat => Heartbeat::TYPE_NAME,
            MessageKind::LogLine => LogLine::TYPE_NAME,
        }
    }

    /// Size of the wire struct in bytes.
    pub const fn size_bytes(self) -> usize {
        match self {
            MessageKind::AccelBlock => size_of::<AccelBlock>(),
            MessageKind::VibBlock => size_of::<VibBlock>(),
            MessageKind::VibEstimate => size_of::<VibEstimate>(),
            MessageKind::CompensatedBlock => size_of::<CompensatedBlock>(),
            MessageKind::TruthBlock => size_of::<TruthBlock>(),
            MessageKind::Heartbeat => size_of::<Heartbeat>(),
            MessageKind::LogLine => size_of::<LogLine>(),
        }
    }

    /// Alignment of the wire struct in bytes.
    pub const fn align_bytes(self) -> usize {
        match self {
            MessageKind::AccelBlock => align_of::<AccelBlock>(),
            MessageKind::VibBlock => align_of::<VibBlock>(),
            MessageKind::VibEstimate => align_of::<VibEstimate>(),
            MessageKind::CompensatedBlock => align_of::<CompensatedBlock>(),
            MessageKind::TruthBlock => align_of::<TruthBlock>(),
            MessageKind::Heartbeat => align_of::<Heartbeat>(),
            MessageKind::LogLine => align_of::<LogLine>(),
        }
    }

    /// The byte layout of every field.
    pub const fn fields(self) -> &'static [crate::FieldLayout] {
        match self {
            MessageKind::AccelBlock => AccelBlock::FIELDS,
            MessageKind::VibBlock => VibBlock::FIELDS,
            MessageKind::VibEstimate => VibEstimate::FIELDS,
            MessageKind::CompensatedBlock => CompensatedBlock::FIELDS,
            MessageKind::TruthBlock => TruthBlock::FIELDS,
            MessageKind::Heartbeat => Heartbeat::FIELDS,
            MessageKind::LogLine => LogLine::FIELDS,
        }
    }
}

impl std::fmt::Display for MessageKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What iceoryx2 needs of a payload: `ZeroCopySend` with the feature `ipc`, nothing
/// without it (a build that leaves iceoryx2 out, such as the Python package's).
#[cfg(feature = "ipc")]
pub trait Payload: ZeroCopySend {}
#[cfg(feature = "ipc")]
impl<T: ZeroCopySend> Payload for T {}
/// What iceoryx2 needs of a payload: `ZeroCopySend` with the feature `ipc`, nothing
/// without it (a build that leaves iceoryx2 out, such as the Python package's).
#[cfg(not(feature = "ipc"))]
pub trait Payload {}
#[cfg(not(feature = "ipc"))]
impl<T> Payload for T {}

/// What every wire type offers to generic code.
pub trait WireMessage: Copy + std::fmt::Debug + Payload + 'static {
    /// Which wire type this is.
    const KIND: MessageKind;

    /// Checks what a receiver must check before indexing the arrays: every count is
    /// within its array's capacity. Flags and codes are carried as they are.
    fn validate(&self) -> Result<()>;

    /// The message's bytes in shared memory (native byte order, no padding holes).
    fn bytes(&self) -> &[u8];

    /// The message from its bytes (native byte order), e.g. received from a network
    /// bridge; `None` unless `bytes` is exactly the type's size. Counts are not
    /// checked: call [`WireMessage::validate`] before indexing the arrays.
    fn from_wire_bytes(bytes: &[u8]) -> Option<Self>;

    /// The producer's sequence number (every type has one).
    fn seq(&self) -> u64;

    /// The producer's `CLOCK_MONOTONIC` time of publishing, ns.
    fn publish_ns(&self) -> u64;
}

macro_rules! wire_message {
    ($($t:ident),*) => {
        $(
            impl WireMessage for $t {
                const KIND: MessageKind = MessageKind::$t;
                fn validate(&self) -> Result<()> {
                    self.validate_counts()
                }
                fn bytes(&self) -> &[u8] {
                    self.as_bytes()
                }
                fn from_wire_bytes(bytes: &[u8]) -> Option<Self> {
                    Self::from_bytes(bytes)
                }
                fn seq(&self) -> u64 {
                    self.seq
                }
                fn publish_ns(&self) -> u64 {
                    self.publish_ns
                }
            }
        )*
    };
}

wire_message!(
    AccelBlock,
    VibBlock,
    VibEstimate,
    CompensatedBlock,
    TruthBlock,
    Heartbeat,
    LogLine
);

impl AccelBlock {
    fn validate_counts(&self) -> Result<()> {
        check_count("AccelBlock.count", self.count, ACCEL_BLOCK_MAX)
    }
}

impl VibBlock {
    fn validate_counts(&self) -> Result<()> {
        check_count("VibBlock.count", self.count, VIB_BLOCK_MAX)
    }
}

impl VibEstimate {
    fn validate_counts(&self) -> Result<()> {
        check_count("VibEstimate.tone_count", self.tone_count, MAX_TONES)?;
        check_count("VibEstimate.band_count", self.band_count, MAX_BANDS)
    }
}

impl CompensatedBlock {
    /// Every per-sample array: the stages `a1..a4` and the corrections `main`, `det`,
    /// `rand`, `[sample][unit]`.
    pub fn stages_mut(&mut self) -> [&mut [[f64; UNITS]; ACCEL_BLOCK_MAX]; 7] {
        [
            &mut self.a1_g,
            &mut self.a2_g,
            &mut self.a3_g,
            &mut self.a4_g,
            &mut self.main_g,
            &mut self.det_g,
            &mut self.rand_g,
        ]
    }

    fn validate_counts(&self) -> Result<()> {
        check_count("CompensatedBlock.count", self.count, ACCEL_BLOCK_MAX)
    }
}

impl TruthBlock {
    fn validate_counts(&self) -> Result<()> {
        check_count("TruthBlock.count", self.count, ACCEL_BLOCK_MAX)
    }
}

impl Heartbeat {
    fn validate_counts(&self) -> Result<()> {
        Ok(())
    }
}

/// Declares a `u8`-coded enum carried in a wire field: the wire keeps the raw `u8` (an
/// out-of-range byte from a C publisher must not be undefined behaviour), and this type
/// converts it with an error that names the field and value.
macro_rules! wire_code {
    (
        $(#[$meta:meta])*
        $name:ident, field = $field:literal {
            $( $(#[$vmeta:meta])* $variant:ident = $code:literal => $text:literal, )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name {
            $( $(#[$vmeta])* $variant = $code, )*
        }

        impl $name {
            /// Every value, in code order.
            pub const ALL: &'static [$name] = &[$($name::$variant),*];

            /// The wire code.
            pub const fn code(self) -> u8 {
                self as u8
            }

            /// The lower-case name used in service names, logs and JSON.
            pub const fn as_str(self) -> &'static str {
                match self {
                    $( $name::$variant => $text, )*
                }
            }
        }

        impl TryFrom<u8> for $name {
            type Error = Error;
            fn try_from(code: u8) -> Result<Self> {
                match code {
                    $( $code => Ok($name::$variant), )*
                    _ => Err(Error::UnknownCode {
                        field: $field,
                        value: code,
                        known: $name::ALL
                            .iter()
                            .map(|v| format!("{} = {}", v.code(), v.as_str()))
                            .collect::<Vec<_>>()
                            .join(", "),
                    }),
                }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.as_str())
            }
        }
    };
}

wire_code! {
    /// The compensation mode of a [`CompensatedBlock`] (`mode` field); 0 is not a mode,
    /// so a zeroed block is never mistaken for a valid one.
    CompensationMode, field = "CompensatedBlock.mode" {
        /// The papers' constants, including [P2 (19)]'s misprinted 1.185.
        AsPublished = 1 => "as-published",
        /// The papers' model with the misprint fixed.
        Paper = 2 => "paper",
        /// Exact means of the conversion function (MODEL.md section 6).
        Exact = 3 => "exact",
    }
}

wire_code! {
    /// Which service published a [`Heartbeat`] (`service` field, and the heartbeat's
    /// service name `{prefix}heartbeat/{name}`); 0 is not a service.
    ServiceId, field = "Heartbeat.service" {
        /// The flight/rig simulator.
        Sim = 1 => "sim",
        /// A hardware rig bridge.
        Rig = 2 => "rig",
        /// The vibration estimator.
        Estimator = 3 => "estimator",
        /// The compensator.
        Compensator = 4 => "compensator",
        /// The MCAP recorder.
        Recorder = 5 => "recorder",
        /// The monitor / user interface.
        Monitor = 6 => "monitor",
    }
}

wire_code! {
    /// The level of a [`LogLine`] (`level` field), as `tracing`'s; 0 is not a level.
    LogLevel, field = "LogLine.level" {
        Trace = 1 => "trace",
        Debug = 2 => "debug",
        Info = 3 => "info",
        Warn = 4 => "warn",
        Error = 5 => "error",
    }
}

wire_code! {
    /// A service's state in its [`Heartbeat`] (`state` field); 0 is not a state.
    ServiceState, field = "Heartbeat.state" {
        /// Started, not yet processing (waiting for inputs or configuration).
        Starting = 1 => "starting",
        /// Processing normally.
        Running = 2 => "running",
        /// Processing, but with stale or missing inputs or losses.
        Degraded = 3 => "degraded",
        /// Shutting down.
        Stopping = 4 => "stopping",
    }
}
