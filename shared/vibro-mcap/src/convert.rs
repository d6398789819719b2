//! Lossless conversions between the wire types of `vibro-msgs` and the protobuf messages
//! of `proto/vibrocomp/v1`, and the [`Message`] enum that holds any wire type.
//!
//! Only the valid slots (`count`, `tone_count`, `band_count`) travel; the others come
//! back zeroed. Doubles are copied, never computed, so every bit pattern survives
//! (negative zero, subnormals, infinities and NaN payloads included): repeated doubles
//! are always written, and scalar doubles are proto3 `optional`, which is written even
//! for -0.0.

use crate::proto;
use crate::{Error, Result};
use vibro_msgs::{
    AccelBlock, CompensatedBlock, Heartbeat, LogLine, MessageKind, TruthBlock, VibBlock,
    VibEstimate, WireMessage, ACCEL_BLOCK_MAX, MAX_BANDS, MAX_TONES, UNITS, VIB_BLOCK_MAX,
};

/// Any wire type, by value.
///
/// The variants differ in size (a [`VibBlock`] is 12 KiB) on purpose: a message is
/// copied into the recorder's preallocated queue slot instead of being boxed, so that
/// recording costs the caller no heap allocation.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    AccelBlock(AccelBlock),
    VibBlock(VibBlock),
    VibEstimate(VibEstimate),
    CompensatedBlock(CompensatedBlock),
    TruthBlock(TruthBlock),
    Heartbeat(Heartbeat),
    LogLine(LogLine),
}

macro_rules! message_from {
    ($($t:ident),*) => {
        $(
            impl From<$t> for Message {
                fn from(m: $t) -> Self {
                    Message::$t(m)
                }
            }
        )*
    };
}

message_from!(
    AccelBlock,
    VibBlock,
    VibEstimate,
    CompensatedBlock,
    TruthBlock,
    Heartbeat,
    LogLine
);

/// The time of a block's last sample, `t0_ns + (count - 1) sample_period_ns`
/// (saturating): a block's data time ([`Message::data_ns`]).
pub fn last_sample_ns(t0_ns: u64, count: u32, sample_period_ns: u64) -> u64 {
    t0_ns.saturating_add(u64::from(count.saturating_sub(1)).saturating_mul(sample_period_ns))
}

impl Message {
    /// Which wire type this is.
    pub fn kind(&self) -> MessageKind {
        match self {
            Message::AccelBlock(_) => MessageKind::AccelBlock,
            Message::VibBlock(_) => MessageKind::VibBlock,
            Message::VibEstimate(_) => MessageKind::VibEstimate,
            Message::CompensatedBlock(_) => MessageKind::CompensatedBlock,
            Message::TruthBlock(_) => MessageKind::TruthBlock,
            Message::Heartbeat(_) => MessageKind::Heartbeat,
            Message::LogLine(_) => MessageKind::LogLine,
        }
    }

    /// The time the message's data belongs to, ns (the recordings' log time,
    /// docs/logs.md "Time"): a block's last sample, `t0_ns + (count - 1)
    /// sample_period_ns` (for an accelerometer or compensated block, the end of its
    /// last reading's interval); an estimate's window end `end_ns`. `None` for a
    /// heartbeat or a log line, which carry no data time (only their producer's
    /// clock).
    pub fn data_ns(&self) -> Option<u64> {
        let last = last_sample_ns;
        match self {
            Message::AccelBlock(m) => Some(last(m.t0_ns, m.count, m.sample_period_ns)),
            Message::VibBlock(m) => Some(last(m.t0_ns, m.count, m.sample_period_ns)),
            Message::CompensatedBlock(m) => Some(last(m.t0_ns, m.count, m.sample_period_ns)),
            Message::TruthBlock(m) => Some(last(m.t0_ns, m.count, m.sample_period_ns)),
            Message::VibEstimate(m) => Some(m.end_ns),
            Message::Heartbeat(_) | Message::LogLine(_) => None,
        }
    }

    /// The wire struct's bytes (shared-memory layout).
    pub fn wire_bytes(&self) -> &[u8] {
        match self {
            Message::AccelBlock(m) => m.bytes(),
            Message::VibBlock(m) => m.bytes(),
            Message::VibEstimate(m) => m.bytes(),
            Message::CompensatedBlock(m) => m.bytes(),
            Message::TruthBlock(m) => m.bytes(),
            Message::Heartbeat(m) => m.bytes(),
            Message::LogLine(m) => m.bytes(),
        }
    }

    /// Checks that every count fits its array (what encoding needs).
    pub fn validate(&self) -> Result<()> {
        let checked = match self {
            Message::AccelBlock(m) => m.validate(),
            Message::VibBlock(m) => m.validate(),
            Message::VibEstimate(m) => m.validate(),
            Message::CompensatedBlock(m) => m.validate(),
            Message::TruthBlock(m) => m.validate(),
            Message::Heartbeat(m) => m.validate(),
            Message::LogLine(m) => m.validate(),
        };
        checked.map_err(Error::Invalid)
    }

    /// Serialises the message as protobuf into `buf` (cleared first), so a caller that
    /// keeps `buf` allocates only when a message outgrows it.
    pub fn encode(&self, buf: &mut Vec<u8>) -> Result<()> {
        use prost::Message as _;
        buf.clear();
        let encoded = match self {
            Message::AccelBlock(m) => proto::AccelBlock::try_from(m)?.encode(buf),
            Message::VibBlock(m) => proto::VibBlock::try_from(m)?.encode(buf),
            Message::VibEstimate(m) => proto::VibEstimate::try_from(m)?.encode(buf),
            Message::CompensatedBlock(m) => proto::CompensatedBlock::try_from(m)?.encode(buf),
            Message::TruthBlock(m) => proto::TruthBlock::try_from(m)?.encode(buf),
            Message::Heartbeat(m) => proto::Heartbeat::from(m).encode(buf),
            Message::LogLine(m) => proto::LogLine::from(m).encode(buf),
        };
        // A `Vec` grows as needed, so encoding cannot run out of room.
        encoded.map_err(|e| Error::Encode {
            kind: self.kind(),
            reason: e.to_string(),
        })
    }

    /// Parses protobuf bytes of the given kind back into the wire type.
    pub fn decode(kind: MessageKind, bytes: &[u8]) -> Result<Message> {
        use prost::Message as _;
        let fail = |e: prost::DecodeError| Error::Decode {
            kind,
            reason: e.to_string(),
        };
        Ok(match kind {
            MessageKind::AccelBlock => {
                Message::AccelBlock((&proto::AccelBlock::decode(bytes).map_err(fail)?).try_into()?)
            }
            MessageKind::VibBlock => {
                Message::VibBlock((&proto::VibBlock::decode(bytes).map_err(fail)?).try_into()?)
            }
            MessageKind::VibEstimate => Message::VibEstimate(
                (&proto::VibEstimate::decode(bytes).map_err(fail)?).try_into()?,
            ),
            MessageKind::CompensatedBlock => Message::CompensatedBlock(
                (&proto::CompensatedBlock::decode(bytes).map_err(fail)?).try_into()?,
            ),
            MessageKind::TruthBlock => {
                Message::TruthBlock((&proto::TruthBlock::decode(bytes).map_err(fail)?).try_into()?)
            }
            MessageKind::Heartbeat => {
                Message::Heartbeat((&proto::Heartbeat::decode(bytes).map_err(fail)?).try_into()?)
            }
            MessageKind::LogLine => {
                Message::LogLine((&proto::LogLine::decode(bytes).map_err(fail)?).try_into()?)
            }
        })
    }
}

/// `rows[..count]` flattened sample-major (`3 * sample + unit`).
fn flatten(rows: &[[f64; UNITS]], count: usize) -> Vec<f64> {
    rows.iter().take(count).flatten().copied().collect()
}

/// The inverse of [`flatten`]: `values` must hold whole rows, at most `N` of them.
fn unflatten<const N: usize>(
    message: MessageKind,
    field: &'static str,
    values: &[f64],
) -> Result<([[f64; UNITS]; N], usize)> {
    if values.len() % UNITS != 0 || values.len() > N * UNITS {
        return Err(Error::FieldLength {
            message,
            field,
            len: values.len(),
            expected: format!("a multiple of {UNITS}, at most {}", N * UNITS),
        });
    }
    let mut rows = [[0.0; UNITS]; N];
    for (row, chunk) in rows.iter_mut().zip(values.chunks_exact(UNITS)) {
        row.copy_from_slice(chunk);
    }
    Ok((rows, values.len() / UNITS))
}

/// A per-axis vector: exactly `UNITS` values.
fn axes(message: MessageKind, field: &'static str, values: &[f64]) -> Result<[f64; UNITS]> {
    <[f64; UNITS]>::try_from(values).map_err(|_| Error::FieldLength {
        message,
        field,
        len: values.len(),
        expected: format!("{UNITS}"),
    })
}

/// A 3x3 matrix stored row-major: exactly 9 values.
fn matrix(
    message: MessageKind,
    field: &'static str,
    values: &[f64],
) -> Result<[[f64; UNITS]; UNITS]> {
    let (rows, n) = unflatten::<UNITS>(message, field, values)?;
    if n != UNITS {
        return Err(Error::FieldLength {
            message,
            field,
            len: values.len(),
            expected: format!("{}", UNITS * UNITS),
        });
    }
    Ok(rows)
}

/// Stage arrays of one block must all describe the same samples.
fn same_count(
    message: MessageKind,
    field: &'static str,
    values: &[f64],
    count: usize,
) -> Result<()> {
    if values.len() == count * UNITS {
        Ok(())
    } else {
        Err(Error::FieldLength {
            message,
            field,
            len: values.len(),
            expected: format!("{} (3 x count = {count})", count * UNITS),
        })
    }
}

fn small_code(message: MessageKind, field: &'static str, value: u32) -> Result<u8> {
    u8::try_from(value).map_err(|_| Error::ValueOutOfRange {
        message,
        field,
        value: value.into(),
        max: u8::MAX.into(),
    })
}

fn count_u32(n: usize) -> u32 {
    // Every count here is bounded by an array capacity (at most 512).
    u32::try_from(n).unwrap_or(u32::MAX)
}

fn valid(m: &impl WireMessage) -> Result<()> {
    m.validate().map_err(Error::Invalid)
}

impl TryFrom<&AccelBlock> for proto::AccelBlock {
    type Error = Error;
    fn try_from(m: &AccelBlock) -> Result<Self> {
        valid(m)?;
        Ok(Self {
            seq: m.seq,
            first_sample_index: m.first_sample_index,
            t0_ns: m.t0_ns,
            sample_period_ns: m.sample_period_ns,
            publish_ns: m.publish_ns,
            source_id: m.source_id,
            flags: m.flags,
            output_v: flatten(&m.output_v, m.count as usize),
        })
    }
}

impl TryFrom<&proto::AccelBlock> for AccelBlock {
    type Error = Error;
    fn try_from(p: &proto::AccelBlock) -> Result<Self> {
        let (output_v, count) =
            unflatten::<ACCEL_BLOCK_MAX>(MessageKind::AccelBlock, "output_v", &p.output_v)?;
        Ok(Self {
            seq: p.seq,
            first_sample_index: p.first_sample_index,
            t0_ns: p.t0_ns,
            sample_period_ns: p.sample_period_ns,
            publish_ns: p.publish_ns,
            output_v,
            count: count_u32(count),
            source_id: p.source_id,
            flags: p.flags,
            _pad: [0; 4],
        })
    }
}

impl TryFrom<&VibBlock> for proto::VibBlock {
    type Error = Error;
    fn try_from(m: &VibBlock) -> Result<Self> {
        valid(m)?;
        Ok(Self {
            seq: m.seq,
            first_sample_index: m.first_sample_index,
            t0_ns: m.t0_ns,
            sample_period_ns: m.sample_period_ns,
            publish_ns: m.publish_ns,
            source_id: m.source_id,
            flags: m.flags,
            sample_v: flatten(&m.sample_v, m.count as usize),
        })
    }
}

impl TryFrom<&proto::VibBlock> for VibBlock {
    type Error = Error;
    fn try_from(p: &proto::VibBlock) -> Result<Self> {
        let (sample_v, count) =
            unflatten::<VIB_BLOCK_MAX>(MessageKind::VibBlock, "sample_v", &p.sample_v)?;
        Ok(Self {
            seq: p.seq,
            first_sample_index: p.first_sample_index,
            t0_ns: p.t0_ns,
            sample_period_ns: p.sample_period_ns,
            publish_ns: p.publish_ns,
            sample_v,
            count: count_u32(count),
            source_id: p.source_id,
            flags: p.flags,
            _pad: [0; 4],
        })
    }
}

impl TryFrom<&VibEstimate> for proto::VibEstimate {
    type Error = Error;
    fn try_from(m: &VibEstimate) -> Result<Self> {
        use proto::vib_estimate::{Band, Broadband, Tone};
        valid(m)?;
        let tones = (0..m.tone_count as usize)
            .map(|k| Tone {
                frequency_hz: Some(m.tone_frequency_hz[k]),
                frequency_u_hz: Some(m.tone_frequency_u_hz[k]),
                amplitude_g: m.tone_amplitude_g[k].to_vec(),
                amplitude_u_g: m.tone_amplitude_u_g[k].to_vec(),
                phase_rad: m.tone_phase_rad[k].to_vec(),
                phase_u_rad: m.tone_phase_u_rad[k].to_vec(),
                snr_db: m.tone_snr_db[k].to_vec(),
            })
            .collect();
        let bands = (0..m.band_count as usize)
            .map(|b| Band {
                f_lo_hz: Some(m.band_f_lo_hz[b]),
                f_hi_hz: Some(m.band_f_hi_hz[b]),
                psd_g2_per_hz: m.band_psd_g2_per_hz[b].to_vec(),
                psd_u_g2_per_hz: m.band_psd_u_g2_per_hz[b].to_vec(),
                rms_g: m.band_rms_g[b].to_vec(),
            })
            .collect();
        Ok(Self {
            seq: m.seq,
            index: m.index,
            source_seq: m.source_seq,
            publish_ns: m.publish_ns,
            start_ns: m.start_ns,
            end_ns: m.end_ns,
            center_ns: m.center_ns,
            samples: m.samples,
            valid_samples: m.valid_samples,
            saturated_samples: m.saturated_samples.to_vec(),
            flags: m.flags,
            broadband: Some(Broadband {
                f_lo_hz: Some(m.broadband_f_lo_hz),
                f_hi_hz: Some(m.broadband_f_hi_hz),
                rms_g: m.broadband_rms_g.to_vec(),
                rms_u_g: m.broadband_rms_u_g.to_vec(),
                covariance_g2: flatten(&m.broadband_covariance_g2, UNITS),
                covariance_u_g2: flatten(&m.broadband_covariance_u_g2, UNITS),
                kurtosis: m.broadband_kurtosis.to_vec(),
                kurtosis_u: m.broadband_kurtosis_u.to_vec(),
                welch_segments: m.broadband_welch_segments,
                welch_segment_samples: m.welch_segment_samples,
            }),
            tones,
            bands,
        })
    }
}

impl TryFrom<&proto::VibEstimate> for VibEstimate {
    type Error = Error;
    fn try_from(p: &proto::VibEstimate) -> Result<Self> {
        const K: MessageKind = MessageKind::VibEstimate;
        let mut m = VibEstimate::ZEROED;
        m.seq = p.seq;
        m.index = p.index;
        m.source_seq = p.source_seq;
        m.publish_ns = p.publish_ns;
        m.start_ns = p.start_ns;
        m.end_ns = p.end_ns;
        m.center_ns = p.center_ns;
        m.samples = p.samples;
        m.valid_samples = p.valid_samples;
        m.saturated_samples =
            <[u32; UNITS]>::try_from(p.saturated_samples.as_slice()).map_err(|_| {
                Error::FieldLength {
                    message: K,
                    field: "saturated_samples",
                    len: p.saturated_samples.len(),
                    expected: format!("{UNITS}"),
                }
            })?;
        m.flags = p.flags;
        let b = p.broadband.as_ref().ok_or(Error::FieldLength {
            message: K,
            field: "broadband",
            len: 0,
            expected: "1".to_string(),
        })?;
        m.broadband_f_lo_hz = b.f_lo_hz.unwrap_or_default();
        m.broadband_f_hi_hz = b.f_hi_hz.unwrap_or_default();
        m.broadband_rms_g = axes(K, "broadband.rms_g", &b.rms_g)?;
        m.broadband_rms_u_g = axes(K, "broadband.rms_u_g", &b.rms_u_g)?;
        m.broadband_covariance_g2 = matrix(K, "broadband.covariance_g2", &b.covariance_g2)?;
        m.broadband_covariance_u_g2 = matrix(K, "broadband.covariance_u_g2", &b.covariance_u_g2)?;
        m.broadband_kurtosis = axes(K, "broadband.kurtosis", &b.kurtosis)?;
        m.broadband_kurtosis_u = axes(K, "broadband.kurtosis_u", &b.kurtosis_u)?;
        m.broadband_welch_segments = b.welch_segments;
        m.welch_segment_samples = b.welch_segment_samples;
        if p.tones.len() > MAX_TONES {
            return Err(Error::FieldLength {
                message: K,
                field: "tones",
                len: p.tones.len(),
                expected: format!("at most {MAX_TONES}"),
            });
        }
        for (k, t) in p.tones.iter().enumerate() {
            m.tone_frequency_hz[k] = t.frequency_hz.unwrap_or_default();
            m.tone_frequency_u_hz[k] = t.frequency_u_hz.unwrap_or_default();
            m.tone_amplitude_g[k] = axes(K, "tones.amplitude_g", &t.amplitude_g)?;
            m.tone_amplitude_u_g[k] = axes(K, "tones.amplitude_u_g", &t.amplitude_u_g)?;
            m.tone_phase_rad[k] = axes(K, "tones.phase_rad", &t.phase_rad)?;
            m.tone_phase_u_rad[k] = axes(K, "tones.phase_u_rad", &t.phase_u_rad)?;
            m.tone_snr_db[k] = axes(K, "tones.snr_db", &t.snr_db)?;
        }
        m.tone_count = count_u32(p.tones.len());
        if p.bands.len() > MAX_BANDS {
            return Err(Error::FieldLength {
                message: K,
                field: "bands",
                len: p.bands.len(),
                expected: format!("at most {MAX_BANDS}"),
            });
        }
        for (i, band) in p.bands.iter().enumerate() {
            m.band_f_lo_hz[i] = band.f_lo_hz.unwrap_or_default();
            m.band_f_hi_hz[i] = band.f_hi_hz.unwrap_or_default();
            m.band_psd_g2_per_hz[i] = axes(K, "bands.psd_g2_per_hz", &band.psd_g2_per_hz)?;
            m.band_psd_u_g2_per_hz[i] = axes(K, "bands.psd_u_g2_per_hz", &band.psd_u_g2_per_hz)?;
            m.band_rms_g[i] = axes(K, "bands.rms_g", &band.rms_g)?;
        }
        m.band_count = count_u32(p.bands.len());
        Ok(m)
    }
}

impl TryFrom<&CompensatedBlock> for proto::CompensatedBlock {
    type Error = Error;
    fn try_from(m: &CompensatedBlock) -> Result<Self> {
        valid(m)?;
        let n = m.count as usize;
        Ok(Self {
            seq: m.seq,
            input_seq: m.input_seq,
            first_sample_index: m.first_sample_index,
            t0_ns: m.t0_ns,
            sample_period_ns: m.sample_period_ns,
            estimate_seq: m.estimate_seq,
            estimate_age_ns: m.estimate_age_ns,
            input_publish_ns: m.input_publish_ns,
            recv_ns: m.recv_ns,
            publish_ns: m.publish_ns,
            source_id: m.source_id,
            flags: m.flags,
            mode: m.mode.into(),
            a1_g: flatten(&m.a1_g, n),
            a2_g: flatten(&m.a2_g, n),
            a3_g: flatten(&m.a3_g, n),
            a4_g: flatten(&m.a4_g, n),
            main_g: flatten(&m.main_g, n),
            det_g: flatten(&m.det_g, n),
            rand_g: flatten(&m.rand_g, n),
        })
    }
}

impl TryFrom<&proto::CompensatedBlock> for CompensatedBlock {
    type Error = Error;
    fn try_from(p: &proto::CompensatedBlock) -> Result<Self> {
        const K: MessageKind = MessageKind::CompensatedBlock;
        let (a1_g, n) = unflatten::<ACCEL_BLOCK_MAX>(K, "a1_g", &p.a1_g)?;
        let stage = |field: &'static str, values: &[f64]| {
            same_count(K, field, values, n)?;
            unflatten::<ACCEL_BLOCK_MAX>(K, field, values).map(|(rows, _)| rows)
        };
        Ok(Self {
            seq: p.seq,
            input_seq: p.input_seq,
            first_sample_index: p.first_sample_index,
            t0_ns: p.t0_ns,
            sample_period_ns: p.sample_period_ns,
            estimate_seq: p.estimate_seq,
            input_publish_ns: p.input_publish_ns,
            recv_ns: p.recv_ns,
            publish_ns: p.publish_ns,
            estimate_age_ns: p.estimate_age_ns,
            a1_g,
            a2_g: stage("a2_g", &p.a2_g)?,
            a3_g: stage("a3_g", &p.a3_g)?,
            a4_g: stage("a4_g", &p.a4_g)?,
            main_g: stage("main_g", &p.main_g)?,
            det_g: stage("det_g", &p.det_g)?,
            rand_g: stage("rand_g", &p.rand_g)?,
            count: count_u32(n),
            source_id: p.source_id,
            flags: p.flags,
            mode: small_code(K, "mode", p.mode)?,
            _pad: [0; 3],
        })
    }
}

impl TryFrom<&TruthBlock> for proto::TruthBlock {
    type Error = Error;
    fn try_from(m: &TruthBlock) -> Result<Self> {
        valid(m)?;
        let n = m.count as usize;
        Ok(Self {
            seq: m.seq,
            first_sample_index: m.first_sample_index,
            t0_ns: m.t0_ns,
            sample_period_ns: m.sample_period_ns,
            publish_ns: m.publish_ns,
            source_id: m.source_id,
            flags: m.flags,
            a_l_ia_g: flatten(&m.a_l_ia_g, n),
            a_sensed_ia_g: flatten(&m.a_sensed_ia_g, n),
            vib_error_ia_g: flatten(&m.vib_error_ia_g, n),
        })
    }
}

impl TryFrom<&proto::TruthBlock> for TruthBlock {
    type Error = Error;
    fn try_from(p: &proto::TruthBlock) -> Result<Self> {
        const K: MessageKind = MessageKind::TruthBlock;
        let (a_l_ia_g, n) = unflatten::<ACCEL_BLOCK_MAX>(K, "a_l_ia_g", &p.a_l_ia_g)?;
        same_count(K, "vib_error_ia_g", &p.vib_error_ia_g, n)?;
        same_count(K, "a_sensed_ia_g", &p.a_sensed_ia_g, n)?;
        let (a_sensed_ia_g, _) =
            unflatten::<ACCEL_BLOCK_MAX>(K, "a_sensed_ia_g", &p.a_sensed_ia_g)?;
        let (vib_error_ia_g, _) =
            unflatten::<ACCEL_BLOCK_MAX>(K, "vib_error_ia_g", &p.vib_error_ia_g)?;
        Ok(Self {
            seq: p.seq,
            first_sample_index: p.first_sample_index,
            t0_ns: p.t0_ns,
            sample_period_ns: p.sample_period_ns,
            publish_ns: p.publish_ns,
            a_l_ia_g,
            a_sensed_ia_g,
            vib_error_ia_g,
            count: count_u32(n),
            source_id: p.source_id,
            flags: p.flags,
            _pad: [0; 4],
        })
    }
}

impl From<&Heartbeat> for proto::Heartbeat {
    fn from(m: &Heartbeat) -> Self {
        Self {
            seq: m.seq,
            publish_ns: m.publish_ns,
            uptime_ns: m.uptime_ns,
            received: m.received,
            published: m.published,
            lost: m.lost,
            stale: m.stale,
            latency_p50_ns: m.latency_p50_ns,
            latency_p99_ns: m.latency_p99_ns,
            input_samples_to_output: m.input_samples_to_output,
            input_samples_per_output: m.input_samples_per_output,
            out_of_order: m.out_of_order,
            resyncs: m.resyncs,
            service: m.service.into(),
            state: m.state.into(),
        }
    }
}

impl TryFrom<&proto::Heartbeat> for Heartbeat {
    type Error = Error;
    fn try_from(p: &proto::Heartbeat) -> Result<Self> {
        const K: MessageKind = MessageKind::Heartbeat;
        Ok(Self {
            seq: p.seq,
            publish_ns: p.publish_ns,
            uptime_ns: p.uptime_ns,
            received: p.received,
            published: p.published,
            lost: p.lost,
            stale: p.stale,
            latency_p50_ns: p.latency_p50_ns,
            latency_p99_ns: p.latency_p99_ns,
            input_samples_to_output: p.input_samples_to_output,
            input_samples_per_output: p.input_samples_per_output,
            out_of_order: p.out_of_order,
            resyncs: p.resyncs,
            service: small_code(K, "service", p.service)?,
            state: small_code(K, "state", p.state)?,
            _pad: [0; 6],
        })
    }
}

impl From<&LogLine> for proto::LogLine {
    fn from(m: &LogLine) -> Self {
        Self {
            seq: m.seq,
            publish_ns: m.publish_ns,
            wall_ns: m.wall_ns,
            service: m.service.into(),
            level: m.level.into(),
            text: m.text().into_owned(),
        }
    }
}

impl TryFrom<&proto::LogLine> for LogLine {
    type Error = Error;
    fn try_from(p: &proto::LogLine) -> Result<Self> {
        const K: MessageKind = MessageKind::LogLine;
        if p.text.len() > vibro_msgs::LOG_TEXT_MAX {
            return Err(Error::Invalid(vibro_msgs::Error::CountOutOfRange {
                field: "LogLine.len",
                count: u32::try_from(p.text.len()).unwrap_or(u32::MAX),
                max: vibro_msgs::LOG_TEXT_MAX,
            }));
        }
        let mut m = LogLine::ZEROED;
        m.seq = p.seq;
        m.publish_ns = p.publish_ns;
        m.wall_ns = p.wall_ns;
        m.service = small_code(K, "service", p.service)?;
        m.level = small_code(K, "level", p.level)?;
        m.len = p.text.len() as u16;
        m.text[..p.text.len()].copy_from_slice(p.text.as_bytes());
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message as _;
    use vibro_msgs::CompensationMode;

    /// Values that a lossy conversion would change: signed zero, subnormals, extremes,
    /// infinities, and NaNs with payloads.
    const SPECIAL: [f64; 9] = [
        -0.0,
        0.0,
        f64::MIN_POSITIVE / 8.0,
        -f64::MIN_POSITIVE / 1024.0,
        f64::MAX,
        -f64::MAX,
        f64::INFINITY,
        f64::from_bits(0x7FF8_0000_0000_0123),
        f64::from_bits(0xFFF4_0000_0000_0001), // signalling, negative
    ];

    fn v(i: usize) -> f64 {
        if i % 3 == 0 {
            SPECIAL[(i / 3) % SPECIAL.len()]
        } else {
            -1.6698 + i as f64 * 1.0e-7
        }
    }

    fn fill<const N: usize>(rows: &mut [[f64; 3]; N], count: usize, base: usize) {
        for (i, row) in rows.iter_mut().take(count).enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = v(base + 3 * i + j);
            }
        }
    }

    fn all_messages() -> Vec<Message> {
        let mut a = AccelBlock::ZEROED;
        a.seq = u64::MAX;
        a.first_sample_index = 12345;
        a.t0_ns = u64::MAX - 1;
        a.sample_period_ns = 1_000_000;
        a.publish_ns = 77;
        fill(&mut a.output_v, 31, 0);
        a.count = 31;
        a.source_id = u32::MAX;
        a.flags = 3;

        let mut b = VibBlock::ZEROED;
        b.seq = 1;
        b.t0_ns = 2;
        b.sample_period_ns = 39_062;
        fill(&mut b.sample_v, VIB_BLOCK_MAX, 5);
        b.count = VIB_BLOCK_MAX as u32;

        let mut e = VibEstimate::ZEROED;
        e.seq = 9;
        e.index = 10;
        e.source_seq = 11;
        e.start_ns = 100;
        e.end_ns = 200;
        e.center_ns = 150;
        e.broadband_f_lo_hz = -0.0;
        e.broadband_f_hi_hz = 2000.0;
        e.broadband_rms_g = [v(0), v(1), v(2)];
        e.broadband_rms_u_g = [v(3), v(4), v(5)];
        fill(&mut e.broadband_covariance_g2, 3, 6);
        fill(&mut e.broadband_covariance_u_g2, 3, 15);
        e.broadband_kurtosis = [3.0, -0.0, f64::NAN];
        e.broadband_kurtosis_u = [0.1, 0.2, 0.3];
        e.broadband_welch_segments = 7;
        e.welch_segment_samples = 6400;
        for k in 0..5 {
            e.tone_frequency_hz[k] = v(30 + k);
            e.tone_frequency_u_hz[k] = v(33 + k);
            e.tone_amplitude_g[k] = [v(k), v(k + 1), v(k + 2)];
            e.tone_amplitude_u_g[k] = [v(k + 3), v(k + 4), v(k + 5)];
            e.tone_phase_rad[k] = [v(k + 6), v(k + 7), v(k + 8)];
            e.tone_phase_u_rad[k] = [v(k + 9), v(k + 10), v(k + 11)];
            e.tone_snr_db[k] = [v(k + 12), v(k + 13), v(k + 14)];
        }
        e.tone_count = 5;
        for i in 0..MAX_BANDS {
            e.band_f_lo_hz[i] = v(60 + i);
            e.band_f_hi_hz[i] = v(61 + i);
            e.band_psd_g2_per_hz[i] = [v(i), v(2 * i), v(3 * i)];
            e.band_psd_u_g2_per_hz[i] = [v(i + 1), v(2 * i + 1), v(3 * i + 1)];
            e.band_rms_g[i] = [v(i + 2), v(2 * i + 2), v(3 * i + 2)];
        }
        e.band_count = MAX_BANDS as u32;
        e.samples = 8192;
        e.valid_samples = 8000;
        e.saturated_samples = [1, 2, u32::MAX];
        e.flags = 0x701;

        let mut c = CompensatedBlock::ZEROED;
        c.seq = 1;
        c.input_seq = 2;
        c.first_sample_index = 3;
        c.t0_ns = 4;
        c.sample_period_ns = 5;
        c.estimate_seq = 6;
        c.input_publish_ns = 7;
        c.recv_ns = 8;
        c.publish_ns = 9;
        c.estimate_age_ns = i64::MIN;
        fill(&mut c.a1_g, 20, 1);
        fill(&mut c.a2_g, 20, 2);
        fill(&mut c.a3_g, 20, 3);
        fill(&mut c.a4_g, 20, 4);
        fill(&mut c.main_g, 20, 5);
        fill(&mut c.det_g, 20, 6);
        fill(&mut c.rand_g, 20, 7);
        c.count = 20;
        c.source_id = 4;
        c.flags = 0x3F;
        c.mode = CompensationMode::Paper.code();

        let mut t = TruthBlock::ZEROED;
        t.seq = 5;
        t.first_sample_index = 6;
        t.t0_ns = 7;
        t.sample_period_ns = 8;
        t.publish_ns = 9;
        fill(&mut t.a_l_ia_g, ACCEL_BLOCK_MAX, 8);
        fill(&mut t.vib_error_ia_g, ACCEL_BLOCK_MAX, 9);
        fill(&mut t.a_sensed_ia_g, ACCEL_BLOCK_MAX, 10);
        t.count = ACCEL_BLOCK_MAX as u32;
        t.flags = 2;

        let h = Heartbeat {
            seq: 1,
            publish_ns: 2,
            uptime_ns: 3,
            received: 4,
            published: 5,
            lost: 6,
            stale: 7,
            latency_p50_ns: 8,
            latency_p99_ns: u64::MAX,
            input_samples_to_output: 12_800,
            input_samples_per_output: 12_801,
            out_of_order: 12_802,
            resyncs: 12_803,
            service: 4,
            state: 255,
            _pad: [0; 6],
        };
        vec![a.into(), b.into(), e.into(), c.into(), t.into(), h.into()]
    }

    #[test]
    fn every_type_round_trips_bit_for_bit() {
        let mut buf = Vec::new();
        for m in all_messages() {
            m.encode(&mut buf).unwrap();
            let back = Message::decode(m.kind(), &buf).unwrap();
            assert_eq!(back.kind(), m.kind());
            assert_eq!(back.wire_bytes(), m.wire_bytes(), "{} changed", m.kind());
        }
    }

    #[test]
    fn the_special_values_really_are_in_the_messages() {
        let msgs = all_messages();
        let Message::AccelBlock(a) = &msgs[0] else {
            panic!()
        };
        assert_eq!(a.output_v[0][0].to_bits(), (-0.0f64).to_bits());
        assert!(a.output_v[2][0].is_subnormal());
        assert_eq!(a.output_v[4][0], f64::MAX);
        assert_eq!(a.output_v[7][0].to_bits(), 0x7FF8_0000_0000_0123);
        let Message::VibEstimate(e) = &msgs[2] else {
            panic!()
        };
        assert!(e.broadband_f_lo_hz.is_sign_negative() && e.broadband_f_lo_hz == 0.0);
    }

    #[test]
    fn negative_zero_scalars_survive_where_proto3_defaults_would_drop_them() {
        let mut e = VibEstimate::ZEROED;
        e.broadband_f_lo_hz = -0.0;
        e.tone_count = 1;
        e.tone_frequency_hz[0] = -0.0;
        let p = proto::VibEstimate::try_from(&e).unwrap();
        let bytes = p.encode_to_vec();
        let back = VibEstimate::try_from(&proto::VibEstimate::decode(&*bytes).unwrap()).unwrap();
        assert!(back.broadband_f_lo_hz.is_sign_negative());
        assert!(back.tone_frequency_hz[0].is_sign_negative());
    }

    #[test]
    fn only_valid_slots_are_stored() {
        let mut a = AccelBlock::ZEROED;
        a.count = 2;
        a.output_v[0] = [1.0, 2.0, 3.0];
        a.output_v[1] = [4.0, 5.0, 6.0];
        a.output_v[2] = [7.0, 8.0, 9.0]; // beyond count: not part of the message
        let p = proto::AccelBlock::try_from(&a).unwrap();
        assert_eq!(p.output_v, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let back = AccelBlock::try_from(&p).unwrap();
        assert_eq!(back.count, 2);
        assert_eq!(back.output_v[2], [0.0; 3]);
        // 2 x 3 doubles packed: 48 bytes of payload plus a 2-byte tag and length.
        let mut m = AccelBlock::ZEROED;
        m.count = 2;
        assert_eq!(
            proto::AccelBlock::try_from(&m)
                .unwrap()
                .encode_to_vec()
                .len(),
            50
        );
    }

    #[test]
    fn malformed_protobuf_is_rejected_with_the_field_named() {
        let p = proto::AccelBlock {
            output_v: vec![1.0; 4],
            ..Default::default()
        };
        let e = AccelBlock::try_from(&p).unwrap_err();
        assert_eq!(
            e.to_string(),
            "AccelBlock.output_v has 4 values, expected a multiple of 3, at most 96"
        );
        let p = proto::VibBlock {
            sample_v: vec![0.0; 3 * (VIB_BLOCK_MAX + 1)],
            ..Default::default()
        };
        assert!(VibBlock::try_from(&p).is_err());
        let p = proto::CompensatedBlock {
            a1_g: vec![0.0; 6],
            a2_g: vec![0.0; 3],
            ..Default::default()
        };
        assert_eq!(
            CompensatedBlock::try_from(&p).unwrap_err().to_string(),
            "CompensatedBlock.a2_g has 3 values, expected 6 (3 x count = 2)"
        );
        let p = proto::Heartbeat {
            service: 256,
            ..Default::default()
        };
        assert_eq!(
            Heartbeat::try_from(&p).unwrap_err().to_string(),
            "Heartbeat.service = 256: out of range (at most 255)"
        );
        let mut p = proto::VibEstimate::default();
        assert_eq!(
            VibEstimate::try_from(&p).unwrap_err().to_string(),
            "VibEstimate.saturated_samples has 0 values, expected 3"
        );
        p.saturated_samples = vec![0; 3];
        assert_eq!(
            VibEstimate::try_from(&p).unwrap_err().to_string(),
            "VibEstimate.broadband has 0 values, expected 1"
        );
        assert!(matches!(
            Message::decode(MessageKind::AccelBlock, &[0xFF, 0xFF]),
            Err(Error::Decode {
                kind: MessageKind::AccelBlock,
                ..
            })
        ));
    }

    #[test]
    fn counts_beyond_capacity_cannot_be_encoded() {
        let mut b = VibBlock::ZEROED;
        b.count = VIB_BLOCK_MAX as u32 + 1;
        let e = Message::from(b).encode(&mut Vec::new()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "invalid message: VibBlock.count = 513: must be at most 512"
        );
    }
}
