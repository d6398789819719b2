//! A vibrocomp MCAP log read one stream at a time into arrays (docs/logs.md): only the
//! asked-for channel's messages are decoded, and chunks without them are not read
//! (`vibro_mcap::Reader::select_topics`). Blocks become one row per sample on the data
//! timeline (`t_ns = t0_ns + i * sample_period_ns`) beside one row per block; the other
//! streams one row per message. Array slots beyond a message's count (tones, bands)
//! are NaN. Integers are int64 (times in ns, indices, counters), the `flags` bit fields
//! uint32; a value an int64 cannot hold refuses the read, naming it.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use prost::Message as _;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use vibro_mcap::foxglove_proto::Log as FoxgloveLog;
use vibro_mcap::view_proto::{ServiceHealth, Stage, UnitStages, VibrationAxis};
use vibro_mcap::{Message, RawRecord, Reader};
use vibro_msgs::{VibEstimate, UNITS};

use crate::errors::IntoPy;

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<LogFile>()?;
    Ok(())
}

/// One column's values, by type. Every integer is an int64 (numpy's and pandas'
/// default, so that a difference of two times or counters is negative where it should
/// be, never a wrapped uint64), apart from the `flags` bit fields (uint32, as sent).
enum Data {
    F64(Vec<f64>),
    I64(Vec<i64>),
    U32(Vec<u32>),
    Bool(Vec<bool>),
    Str(Vec<String>),
}

/// Columns in the order first pushed, each with its shape beyond the row axis.
#[derive(Default)]
struct Cols {
    rows: usize,
    cols: Vec<(&'static str, Vec<usize>, Data)>,
    /// The first value pushed that an int64 cannot hold (`name = value`): the read
    /// that pushed it is refused (see [`beyond_int64`]).
    beyond: Option<String>,
}

/// Why a value is refused: nanoseconds since the log's epoch fit an int64 for 292
/// years, so a value beyond it is a damaged or forged field, not a time to wrap or clip.
fn beyond_int64(what: &str) -> String {
    format!(
        "{what} is beyond the int64 columns of the package (at most {} = 2^63 - 1; \
         as nanoseconds, 292 years after the log's epoch)",
        i64::MAX
    )
}

impl Cols {
    fn slot(&mut self, name: &'static str, shape: &[usize], empty: fn() -> Data) -> &mut Data {
        let at = match self.cols.iter().position(|(n, _, _)| *n == name) {
            Some(at) => at,
            None => {
                self.cols.push((name, shape.to_vec(), empty()));
                self.cols.len() - 1
            }
        };
        &mut self.cols[at].2
    }

    fn f64s(&mut self, name: &'static str, shape: &[usize], values: impl Iterator<Item = f64>) {
        if let Data::F64(v) = self.slot(name, shape, || Data::F64(Vec::new())) {
            v.extend(values);
        }
    }

    fn f64(&mut self, name: &'static str, value: f64) {
        self.f64s(name, &[], std::iter::once(value));
    }

    fn i64s(&mut self, name: &'static str, shape: &[usize], values: impl Iterator<Item = i64>) {
        if let Data::I64(v) = self.slot(name, shape, || Data::I64(Vec::new())) {
            v.extend(values);
        }
    }

    fn i64(&mut self, name: &'static str, value: i64) {
        self.i64s(name, &[], std::iter::once(value));
    }

    /// An unsigned 64-bit field as an int64; one beyond `i64::MAX` is noted in
    /// `beyond` (the read is refused) and stands as -1 until then.
    fn u64(&mut self, name: &'static str, value: u64) {
        let v = i64::try_from(value).unwrap_or_else(|_| {
            self.beyond
                .get_or_insert_with(|| beyond_int64(&format!("{name} = {value}")));
            -1
        });
        self.i64(name, v);
    }

    fn u32s(&mut self, name: &'static str, shape: &[usize], values: impl Iterator<Item = u32>) {
        self.i64s(name, shape, values.map(i64::from));
    }

    fn u32(&mut self, name: &'static str, value: u32) {
        self.u32s(name, &[], std::iter::once(value));
    }

    /// A bit field, kept as the uint32 it is sent as.
    fn bits(&mut self, name: &'static str, values: impl Iterator<Item = u32>) {
        if let Data::U32(v) = self.slot(name, &[], || Data::U32(Vec::new())) {
            v.extend(values);
        }
    }

    fn flags(&mut self, value: u32) {
        self.bits("flags", std::iter::once(value));
    }

    fn bool(&mut self, name: &'static str, value: bool) {
        if let Data::Bool(v) = self.slot(name, &[], || Data::Bool(Vec::new())) {
            v.push(value);
        }
    }

    fn str(&mut self, name: &'static str, value: String) {
        if let Data::Str(v) = self.slot(name, &[], || Data::Str(Vec::new())) {
            v.push(value);
        }
    }

    /// The message's MCAP header fields: the data time (`log_time_ns`), the receive
    /// time (`publish_time_ns`) and the publisher's 32-bit counter.
    /// Room for `rows` more rows in every column (each row `shape` values).
    fn reserve(&mut self, rows: usize) {
        for (_, shape, data) in &mut self.cols {
            let n = rows.saturating_mul(shape.iter().product::<usize>());
            match data {
                Data::F64(v) => v.reserve(n),
                Data::I64(v) => v.reserve(n),
                Data::U32(v) => v.reserve(n),
                Data::Bool(v) => v.reserve(n),
                Data::Str(v) => v.reserve(n),
            }
        }
    }

    fn header(&mut self, r: &RawRecord) {
        self.u64("log_time_ns", r.log_time_ns);
        self.u64("publish_time_ns", r.publish_time_ns);
        self.u32("sequence", r.sequence);
    }

    fn into_dict(self, py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
        let d = PyDict::new(py);
        for (name, shape, data) in self.cols {
            let mut dims = vec![self.rows];
            dims.extend(&shape);
            let array = match data {
                Data::F64(v) => crate::arrays::out(py, &v, dims)?,
                Data::I64(v) => crate::arrays::out(py, &v, dims)?,
                Data::U32(v) => crate::arrays::out(py, &v, dims)?,
                Data::Bool(v) => crate::arrays::out(py, &v, dims)?,
                Data::Str(v) => v.into_pyobject(py)?.into_any(),
            };
            d.set_item(name, array)?;
        }
        Ok(d)
    }
}

/// NaN in the slots at and beyond `count`.
fn valid<const N: usize>(values: &[f64; N], count: u32) -> impl Iterator<Item = f64> + '_ {
    values
        .iter()
        .enumerate()
        .map(move |(i, &v)| if i < count as usize { v } else { f64::NAN })
}

/// [`valid`] over rows of unit values.
fn valid_rows<const N: usize>(
    values: &[[f64; UNITS]; N],
    count: u32,
) -> impl Iterator<Item = f64> + '_ {
    values.iter().enumerate().flat_map(move |(i, row)| {
        row.iter()
            .map(move |&v| if i < count as usize { v } else { f64::NAN })
    })
}

/// A block stream: its samples and its blocks.
#[derive(Default)]
struct BlockStream {
    samples: Cols,
    blocks: Cols,
}

/// One block's common fields.
struct BlockHead {
    seq: u64,
    first_sample_index: u64,
    t0_ns: u64,
    sample_period_ns: u64,
    publish_ns: u64,
    count: u32,
    source_id: u32,
    flags: u32,
}

impl BlockStream {
    /// Appends a block's head and its samples' times; `values` pushes its per-sample
    /// arrays (each `count` rows of the units' values).
    fn push(&mut self, r: &RawRecord, h: &BlockHead, values: impl FnOnce(&mut Cols, usize)) {
        let n = h.count as usize;
        let row = i64::try_from(self.blocks.rows).unwrap_or(i64::MAX);
        let b = &mut self.blocks;
        b.header(r);
        b.u64("seq", h.seq);
        b.u64("first_sample_index", h.first_sample_index);
        b.u64("t0_ns", h.t0_ns);
        b.u64("sample_period_ns", h.sample_period_ns);
        b.u64("publish_ns", h.publish_ns);
        b.u32("count", h.count);
        b.u32("source_id", h.source_id);
        b.flags(h.flags);
        b.rows += 1;
        let s = &mut self.samples;
        // The last sample's time and index bound the others: if they fit an int64,
        // every sample's does (computed wide, so that nothing wraps on the way).
        let last = n.saturating_sub(1) as u128;
        let t_last = u128::from(h.t0_ns) + last * u128::from(h.sample_period_ns);
        let index_last = u128::from(h.first_sample_index) + last;
        let max = i64::MAX as u128;
        if t_last > max || index_last > max {
            let what = if t_last > max {
                format!(
                    "t_ns of its last sample = t0_ns {} + {last} x sample_period_ns {} = {t_last}",
                    h.t0_ns, h.sample_period_ns
                )
            } else {
                format!(
                    "sample_index of its last sample = first_sample_index {} + {last} = {index_last}",
                    h.first_sample_index
                )
            };
            s.beyond.get_or_insert_with(|| beyond_int64(&what));
        } else {
            // Both fit: no product or sum below overflows an int64.
            let (t0, dt) = (h.t0_ns as i64, h.sample_period_ns as i64);
            let first = h.first_sample_index as i64;
            s.i64s("t_ns", &[], (0..n as i64).map(|i| t0 + i * dt));
            s.i64s("sample_index", &[], (0..n as i64).map(|i| first + i));
        }
        s.i64s("block", &[], std::iter::repeat_n(row, n));
        s.bits("flags", std::iter::repeat_n(h.flags, n));
        values(s, n);
        s.rows += n;
    }
}

/// Rows `..n` of a block's per-unit array, flattened.
fn rows(values: &[[f64; UNITS]], n: usize) -> impl Iterator<Item = f64> + '_ {
    values[..n.min(values.len())].iter().flatten().copied()
}

fn push_estimate(c: &mut Cols, r: &RawRecord, e: &VibEstimate) {
    const U: &[usize] = &[UNITS];
    const UU: &[usize] = &[UNITS, UNITS];
    let (t, b) = (e.tone_count, e.band_count);
    let tones = &[vibro_msgs::MAX_TONES];
    let tones_u = &[vibro_msgs::MAX_TONES, UNITS];
    let bands = &[vibro_msgs::MAX_BANDS];
    let bands_u = &[vibro_msgs::MAX_BANDS, UNITS];
    c.header(r);
    c.u64("seq", e.seq);
    c.u64("index", e.index);
    c.u64("source_seq", e.source_seq);
    c.u64("publish_ns", e.publish_ns);
    c.u64("start_ns", e.start_ns);
    c.u64("end_ns", e.end_ns);
    c.u64("center_ns", e.center_ns);
    c.f64("broadband_f_lo_hz", e.broadband_f_lo_hz);
    c.f64("broadband_f_hi_hz", e.broadband_f_hi_hz);
    c.f64s("broadband_rms_g", U, e.broadband_rms_g.iter().copied());
    c.f64s("broadband_rms_u_g", U, e.broadband_rms_u_g.iter().copied());
    let cov = e.broadband_covariance_g2.iter().flatten().copied();
    c.f64s("broadband_covariance_g2", UU, cov);
    let cov_u = e.broadband_covariance_u_g2.iter().flatten().copied();
    c.f64s("broadband_covariance_u_g2", UU, cov_u);
    c.f64s(
        "broadband_kurtosis",
        U,
        e.broadband_kurtosis.iter().copied(),
    );
    c.f64s(
        "broadband_kurtosis_u",
        U,
        e.broadband_kurtosis_u.iter().copied(),
    );
    c.u32("tone_count", t);
    c.f64s("tone_frequency_hz", tones, valid(&e.tone_frequency_hz, t));
    c.f64s(
        "tone_frequency_u_hz",
        tones,
        valid(&e.tone_frequency_u_hz, t),
    );
    c.f64s(
        "tone_amplitude_g",
        tones_u,
        valid_rows(&e.tone_amplitude_g, t),
    );
    c.f64s(
        "tone_amplitude_u_g",
        tones_u,
        valid_rows(&e.tone_amplitude_u_g, t),
    );
    c.f64s("tone_phase_rad", tones_u, valid_rows(&e.tone_phase_rad, t));
    c.f64s(
        "tone_phase_u_rad",
        tones_u,
        valid_rows(&e.tone_phase_u_rad, t),
    );
    c.f64s("tone_snr_db", tones_u, valid_rows(&e.tone_snr_db, t));
    c.u32("band_count", b);
    c.f64s("band_f_lo_hz", bands, valid(&e.band_f_lo_hz, b));
    c.f64s("band_f_hi_hz", bands, valid(&e.band_f_hi_hz, b));
    c.f64s(
        "band_psd_g2_per_hz",
        bands_u,
        valid_rows(&e.band_psd_g2_per_hz, b),
    );
    let psd_u = valid_rows(&e.band_psd_u_g2_per_hz, b);
    c.f64s("band_psd_u_g2_per_hz", bands_u, psd_u);
    c.f64s("band_rms_g", bands_u, valid_rows(&e.band_rms_g, b));
    c.u32("samples", e.samples);
    c.u32("valid_samples", e.valid_samples);
    c.u32s("saturated_samples", U, e.saturated_samples.iter().copied());
    c.u32("broadband_welch_segments", e.broadband_welch_segments);
    c.u32("welch_segment_samples", e.welch_segment_samples);
    c.flags(e.flags);
    c.rows += 1;
}

/// A protobuf timestamp on the data timeline as `t_ns` (absent: 0; one an int64
/// cannot hold refuses the read, as [`Cols::u64`]).
fn push_timestamp(c: &mut Cols, t: Option<&prost_types::Timestamp>) {
    let (s, n) = t.map_or((0, 0), |t| (t.seconds, t.nanos));
    let ns = i128::from(s) * 1_000_000_000 + i128::from(n);
    let v = i64::try_from(ns).unwrap_or_else(|_| {
        c.beyond
            .get_or_insert_with(|| beyond_int64(&format!("t_ns = {s} s + {n} ns = {ns} ns")));
        -1
    });
    c.i64("t_ns", v);
}

fn push_stage(c: &mut Cols, names: [&'static str; 3], s: Option<&Stage>) {
    let (mean, min, max) = s.map_or((f64::NAN, f64::NAN, f64::NAN), |s| (s.mean, s.min, s.max));
    c.f64(names[0], mean);
    c.f64(names[1], min);
    c.f64(names[2], max);
}

/// Decodes one view message into its row.
fn push_view(c: &mut Cols, r: &RawRecord) -> anyhow::Result<()> {
    let bad = |e: prost::DecodeError| anyhow::anyhow!("{} message {}: {e}", r.topic, r.sequence);
    c.header(r);
    match &*r.schema {
        "vibrocomp.view.v1.UnitStages" => {
            let m = UnitStages::decode(r.data.as_slice()).map_err(bad)?;
            push_timestamp(c, m.timestamp.as_ref());
            c.str("unit", m.unit);
            c.u32("unit_index", m.unit_index);
            c.u32("samples", m.samples);
            c.u64("first_sample_index", m.first_sample_index);
            // Each stage's mean, min and max as `<stage>_mean`, `_min`, `_max`.
            macro_rules! stages {
                ($($field:ident),*) => {
                    $(
                        let names = [
                            concat!(stringify!($field), "_mean"),
                            concat!(stringify!($field), "_min"),
                            concat!(stringify!($field), "_max"),
                        ];
                        push_stage(c, names, m.$field.as_ref());
                    )*
                };
            }
            stages!(
                uncompensated_g,
                main_removed_g,
                compensated_g,
                reference_g,
                uncompensated_error_g,
                main_removed_error_g,
                compensated_error_g
            );
            c.flags(m.flags);
        }
        "vibrocomp.view.v1.VibrationAxis" => {
            let m = VibrationAxis::decode(r.data.as_slice()).map_err(bad)?;
            push_timestamp(c, m.timestamp.as_ref());
            c.str("axis", m.axis);
            c.u32("axis_index", m.axis_index);
            c.u32("tone_count", m.tone_count);
            c.f64("tone_frequency_hz", m.tone_frequency_hz);
            c.f64("tone_amplitude_g", m.tone_amplitude_g);
            c.f64("tone_phase_rad", m.tone_phase_rad);
            c.f64("broadband_rms_g", m.broadband_rms_g);
            c.f64("kurtosis", m.kurtosis);
            c.flags(m.flags);
            c.bool("saturated", m.saturated);
        }
        "vibrocomp.view.v1.ServiceHealth" => {
            let m = ServiceHealth::decode(r.data.as_slice()).map_err(bad)?;
            push_timestamp(c, m.timestamp.as_ref());
            c.str("service", m.service().as_str_name().to_string());
            c.str("state", m.state().as_str_name().to_string());
            c.f64("uptime_s", m.uptime_s);
            c.u64("received", m.received);
            c.u64("published", m.published);
            c.u64("lost", m.lost);
            c.u64("stale", m.stale);
            c.f64("latency_p50_ms", m.latency_p50_ms);
            c.f64("latency_p99_ms", m.latency_p99_ms);
            c.u64("out_of_order", m.out_of_order);
            c.u64("resyncs", m.resyncs);
        }
        "foxglove.Log" => {
            let m = FoxgloveLog::decode(r.data.as_slice()).map_err(bad)?;
            push_timestamp(c, m.timestamp.as_ref());
            c.str("level", m.level().as_str_name().to_string());
            c.str("message", m.message);
            c.str("name", m.name);
            c.str("file", m.file);
            c.u32("line", m.line);
        }
        other => anyhow::bail!("{}: view schema {other} is not known here", r.topic),
    }
    c.rows += 1;
    Ok(())
}

/// The [`BlockHead`] of any block type (they share these fields).
macro_rules! head {
    ($b:expr) => {
        BlockHead {
            seq: $b.seq,
            first_sample_index: $b.first_sample_index,
            t0_ns: $b.t0_ns,
            sample_period_ns: $b.sample_period_ns,
            publish_ns: $b.publish_ns,
            count: $b.count,
            source_id: $b.source_id,
            flags: $b.flags,
        }
    };
}

/// One wire message into its stream's columns.
fn push_wire(s: &mut BlockStream, m: &Message, r: &RawRecord) {
    match m {
        Message::AccelBlock(b) => {
            let h = head!(b);
            s.push(r, &h, |c, n| {
                c.f64s("output_v", &[UNITS], rows(&b.output_v, n))
            });
        }
        Message::VibBlock(b) => {
            let h = head!(b);
            s.push(r, &h, |c, n| {
                c.f64s("sample_v", &[UNITS], rows(&b.sample_v, n))
            });
        }
        Message::TruthBlock(b) => {
            let h = head!(b);
            s.push(r, &h, |c, n| {
                c.f64s("a_l_ia_g", &[UNITS], rows(&b.a_l_ia_g, n));
                c.f64s("a_sensed_ia_g", &[UNITS], rows(&b.a_sensed_ia_g, n));
                c.f64s("vib_error_ia_g", &[UNITS], rows(&b.vib_error_ia_g, n));
            });
        }
        Message::CompensatedBlock(b) => {
            let h = head!(b);
            s.blocks.u64("input_seq", b.input_seq);
            s.blocks.u64("estimate_seq", b.estimate_seq);
            s.blocks.u64("input_publish_ns", b.input_publish_ns);
            s.blocks.u64("recv_ns", b.recv_ns);
            s.blocks.i64("estimate_age_ns", b.estimate_age_ns);
            s.blocks.u32("mode", u32::from(b.mode));
            s.push(r, &h, |c, n| {
                for (name, v) in [
                    ("a1_g", &b.a1_g),
                    ("a2_g", &b.a2_g),
                    ("a3_g", &b.a3_g),
                    ("a4_g", &b.a4_g),
                    ("main_g", &b.main_g),
                    ("det_g", &b.det_g),
                    ("rand_g", &b.rand_g),
                ] {
                    c.f64s(name, &[UNITS], rows(v, n));
                }
            });
        }
        Message::VibEstimate(e) => push_estimate(&mut s.blocks, r, e),
        Message::Heartbeat(h) => {
            let c = &mut s.blocks;
            c.header(r);
            for (name, v) in [
                ("seq", h.seq),
                ("publish_ns", h.publish_ns),
                ("uptime_ns", h.uptime_ns),
                ("received", h.received),
                ("published", h.published),
                ("lost", h.lost),
                ("stale", h.stale),
                ("latency_p50_ns", h.latency_p50_ns),
                ("latency_p99_ns", h.latency_p99_ns),
                ("input_samples_to_output", h.input_samples_to_output),
                ("input_samples_per_output", h.input_samples_per_output),
                ("out_of_order", h.out_of_order),
                ("resyncs", h.resyncs),
            ] {
                c.u64(name, v);
            }
            c.u32("service", u32::from(h.service));
            c.u32("state", u32::from(h.state));
            c.rows += 1;
        }
        Message::LogLine(l) => {
            let c = &mut s.blocks;
            c.header(r);
            c.u64("seq", l.seq);
            c.u64("publish_ns", l.publish_ns);
            c.u64("wall_ns", l.wall_ns);
            c.u32("service", u32::from(l.service));
            c.u32("level", u32::from(l.level));
            let len = usize::from(l.len).min(l.text.len());
            c.str("text", String::from_utf8_lossy(&l.text[..len]).into_owned());
            c.rows += 1;
        }
    }
}

/// The most messages a stream's columns are sized for ahead of reading them (the
/// statistics' count; beyond, the columns grow as they are read).
const MAX_RESERVED_MESSAGES: u64 = 1 << 20;

/// What one stream read into: its kind and its columns.
struct Stream {
    kind: String,
    block: bool,
    data: BlockStream,
}

/// Reads every message of `topic` into columns.
/// `topic`'s messages of the log at `path` as columns. `stop` is looked at before each
/// message: a call stopped (Ctrl-C) does not go on reading behind its exception.
fn read_stream(
    path: &std::path::Path,
    topic: &str,
    stop: &vibro_lab::Stop,
) -> anyhow::Result<Stream> {
    let mut reader = Reader::open(path)?;
    let wire = reader
        .channels()
        .into_iter()
        .find(|(t, _)| t == topic)
        .map(|(_, k)| k);
    reader.select_topics(&[topic])?;
    // The statistics' count of messages sizes the columns once the first message
    // shows their shapes (capped: a forged count must not become an allocation).
    let expected = reader.topic_message_count(topic).map_or(0, |n| {
        usize::try_from(n.min(MAX_RESERVED_MESSAGES)).unwrap_or(0)
    });
    let mut data = BlockStream::default();
    let mut kind = None;
    while let Some(r) = reader.next_raw() {
        if stop.requested() {
            anyhow::bail!("stopped");
        }
        let r = r?;
        let first = kind.is_none();
        if first {
            kind = Some(r.schema.to_string());
        }
        match wire {
            Some(k) => {
                let m = Message::decode(k, &r.data)
                    .with_context(|| format!("{topic} message {}", r.sequence))?;
                push_wire(&mut data, &m, &r);
            }
            None => push_view(&mut data.blocks, &r)?,
        }
        if let Some(why) = data.blocks.beyond.take().or(data.samples.beyond.take()) {
            anyhow::bail!("{topic} message {}: {why}", r.sequence);
        }
        if first {
            let more = expected.saturating_sub(1);
            data.blocks.reserve(more);
            data.samples.reserve(more.saturating_mul(data.samples.rows));
        }
    }
    let kind = match (kind, wire) {
        (Some(k), _) => k,
        (None, Some(k)) => vibro_mcap::schema(k).name.to_string(),
        (None, None) => reader_schema(path, topic)?,
    };
    if data.blocks.rows == 0 {
        data = empty_columns(&kind, wire);
    }
    let block = matches!(
        wire,
        Some(
            vibro_msgs::MessageKind::AccelBlock
                | vibro_msgs::MessageKind::VibBlock
                | vibro_msgs::MessageKind::TruthBlock
                | vibro_msgs::MessageKind::CompensatedBlock
        )
    );
    Ok(Stream { kind, block, data })
}

/// The columns of a stream without messages: those of a default message, with no
/// rows, so that an empty stream has the same columns as any other.
fn empty_columns(schema: &str, wire: Option<vibro_msgs::MessageKind>) -> BlockStream {
    let mut data = BlockStream::default();
    let record = RawRecord {
        topic: std::sync::Arc::from(""),
        schema: std::sync::Arc::from(schema),
        sequence: 0,
        log_time_ns: 0,
        publish_time_ns: 0,
        data: Vec::new(),
    };
    match wire {
        Some(k) => {
            use vibro_msgs::MessageKind as K;
            let m = match k {
                K::AccelBlock => Message::AccelBlock(Default::default()),
                K::VibBlock => Message::VibBlock(Default::default()),
                K::VibEstimate => Message::VibEstimate(Default::default()),
                K::CompensatedBlock => Message::CompensatedBlock(Default::default()),
                K::TruthBlock => Message::TruthBlock(Default::default()),
                K::Heartbeat => Message::Heartbeat(Default::default()),
                K::LogLine => Message::LogLine(Default::default()),
            };
            push_wire(&mut data, &m, &record);
        }
        None => {
            let _ = push_view(&mut data.blocks, &record);
        }
    }
    for cols in [&mut data.samples, &mut data.blocks] {
        cols.rows = 0;
        for (_, _, d) in &mut cols.cols {
            match d {
                Data::F64(v) => v.clear(),
                Data::I64(v) => v.clear(),
                Data::U32(v) => v.clear(),
                Data::Bool(v) => v.clear(),
                Data::Str(v) => v.clear(),
            }
        }
    }
    data
}

/// The schema name of a view channel (one without messages has no record to say it).
fn reader_schema(path: &std::path::Path, topic: &str) -> anyhow::Result<String> {
    let info = vibro_log::inspect::read_info(path)?;
    Ok(info
        .channels
        .iter()
        .find(|c| c.topic == topic)
        .map(|c| c.message_type.clone())
        .unwrap_or_default())
}

/// A vibrocomp MCAP log, read stream by stream.
#[pyclass(module = "vibrocomp._vibrocomp", frozen)]
struct LogFile {
    path: PathBuf,
}

#[pymethods]
impl LogFile {
    /// Opens the log at `path`: what is not an MCAP log is refused, and its summary
    /// section is read and checked (no chunk is read).
    #[new]
    fn new(path: PathBuf) -> PyResult<Self> {
        let open = || -> anyhow::Result<()> {
            vibro_log::inspect::check_mcap_file(&path)?;
            Reader::open(&path)?;
            Ok(())
        };
        open().py_err()?;
        Ok(Self { path })
    }

    /// `vibrocomp log info --json`.
    fn info(&self, py: Python<'_>) -> PyResult<String> {
        // On a thread of its own, as `read`: Ctrl-C is not held up by a long scan.
        let path = self.path.clone();
        crate::lab::stoppable(py, None, move |_, _| {
            let info = vibro_log::inspect::read_info(&path)?;
            Ok(serde_json::to_string(&info)?)
        })
    }

    /// Every channel's `(topic, schema name)`, from the summary.
    fn topics(&self) -> PyResult<Vec<(String, String)>> {
        let run = || -> anyhow::Result<_> { Ok(Reader::open(&self.path)?.topics()) };
        run().py_err()
    }

    /// Every metadata record, `(name, entries)`, in file order.
    fn metadata(&self) -> PyResult<Vec<(String, BTreeMap<String, String>)>> {
        let run = || -> anyhow::Result<_> { Ok(Reader::open(&self.path)?.metadata()?) };
        run().py_err()
    }

    /// Every attachment: `(name, media type, bytes)`, in file order.
    fn attachments<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Vec<(String, String, Bound<'py, PyBytes>)>> {
        let run = || -> anyhow::Result<_> {
            let mut reader = Reader::open(&self.path)?;
            let mut out = Vec::new();
            for (name, media_type) in reader.attachment_types() {
                let data = reader.read_attachment(&name)?.unwrap_or_default();
                out.push((name, media_type, data));
            }
            Ok(out)
        };
        Ok(run()
            .py_err()?
            .into_iter()
            .map(|(n, m, d)| (n, m, PyBytes::new(py, &d)))
            .collect())
    }

    /// A TOML text (an attachment) as JSON, for the Python side's dicts (Python 3.9
    /// has no TOML reader).
    #[staticmethod]
    fn toml_to_json(text: &str, name: &str) -> PyResult<String> {
        let run = || -> anyhow::Result<String> {
            let value: toml::Value =
                toml::from_str(text).with_context(|| format!("{name}: not TOML"))?;
            Ok(serde_json::to_string(&value)?)
        };
        run().py_err()
    }

    /// The stream on `topic`: `(kind, samples, rows)`: for a block stream its samples'
    /// columns and its blocks' columns, for the others `None` and one row per message.
    fn read<'py>(
        &self,
        py: Python<'py>,
        topic: &str,
    ) -> PyResult<(String, Option<Bound<'py, PyDict>>, Bound<'py, PyDict>)> {
        // On a thread of its own: Ctrl-C raises `KeyboardInterrupt` at once, and the
        // reading stops at its next message.
        let (path, topic) = (self.path.clone(), topic.to_string());
        let stream = crate::lab::stoppable(py, None, move |_, stop| {
            read_stream(&path, &topic, stop).with_context(|| format!("log {}", path.display()))
        })?;
        let samples = if stream.block {
            Some(stream.data.samples.into_dict(py)?)
        } else {
            None
        };
        Ok((stream.kind, samples, stream.data.blocks.into_dict(py)?))
    }
}
