//! The rig's reference in an import (`log import --rig FILE [--reference CSV]`): what
//! each reading should read without vibration, per accelerometer output interval,
//! written as the reference channel (`/truth` TruthBlocks with
//! `truth_flags::SENSED_UNKNOWN`: `a_l_ia_g` from the rig's reference, the sensed and
//! vibration-error fields unknown), aligned with the `/accel` blocks as the simulator
//! writes its truth.
//!
//! The reference at a reading latched at `t` (the mean over `(t - T, t]`) is the rig's
//! reference at the interval's middle: exact for a static orientation or a centrifuge
//! inside one segment, and for a stream to the second order in `T` (a linear
//! interpolation between the stream's samples). A reading whose interval is not
//! inside one static segment (the table turning between orientations) gets no
//! reference (NaN, counted); the readings must lie within the reference's span.

use std::path::Path;

use vibro_config::rig::{ReferenceSpec, RigConfig};
use vibro_msgs::{truth_flags, AccelBlock, TruthBlock};

/// The reference as the import evaluates it.
#[derive(Debug)]
pub(super) enum Reference {
    /// A static orientation or a centrifuge (the rig file's own).
    Spec(ReferenceSpec),
    /// A stream read from `--reference`: times, and the body axes' values, g.
    Stream {
        file: String,
        time_s: Vec<f64>,
        body_g: Vec<[f64; 3]>,
    },
}

impl Reference {
    /// The rig's reference, reading the stream's CSV for `kind = "stream"`; every
    /// problem as one line (file, key or line, value, rule).
    pub(super) fn load(
        rig: &RigConfig,
        stream: Option<&Path>,
    ) -> std::result::Result<Self, Vec<String>> {
        match (&rig.reference, stream) {
            (ReferenceSpec::Stream { columns }, Some(file)) => {
                let cols: Vec<&str> = columns.iter().map(String::as_str).collect();
                let t = vibro_ident::table::read_timed(file, &cols)
                    .map_err(|e| vec![format!("--reference {}: {e}", file.display())])?;
                let body_g = (0..t.time_s.len())
                    .map(|i| [t.columns[0][i], t.columns[1][i], t.columns[2][i]])
                    .collect();
                Ok(Reference::Stream {
                    file: file.display().to_string(),
                    time_s: t.time_s,
                    body_g,
                })
            }
            (ReferenceSpec::Stream { .. }, None) => Err(vec![format!(
                "{}: reference.kind = \"stream\": give the stream's CSV with --reference FILE",
                rig.file
            )]),
            (spec, Some(file)) => Err(vec![format!(
                "--reference {}: the rig file {} states a {} reference (reference.kind = \"{}\"): \
                 a reference stream needs kind = \"stream\"",
                file.display(),
                rig.file,
                spec.kind(),
                spec.kind()
            )]),
            (spec, None) => Ok(Reference::Spec(spec.clone())),
        }
    }

    /// The span the reference covers, s; `None`: all times (a centrifuge).
    fn span_s(&self) -> Option<[f64; 2]> {
        match self {
            Reference::Spec(ReferenceSpec::Centrifuge { .. }) => None,
            Reference::Spec(ReferenceSpec::Static { segments, .. }) => Some([
                segments
                    .iter()
                    .map(|s| s.from_s)
                    .fold(f64::INFINITY, f64::min),
                segments
                    .iter()
                    .map(|s| s.to_s)
                    .fold(f64::NEG_INFINITY, f64::max),
            ]),
            Reference::Spec(ReferenceSpec::Stream { .. }) => Some([0.0, 0.0]),
            // An empty stream covers nothing (read_timed refuses one anyway).
            Reference::Stream { time_s, .. } => match (time_s.first(), time_s.last()) {
                (Some(a), Some(b)) => Some([*a, *b]),
                _ => Some([f64::INFINITY, f64::NEG_INFINITY]),
            },
        }
    }

    /// Checks that the readings from `first_latch_s - period_s` to `last_latch_s` lie
    /// within the reference's span; the problem as one line.
    pub(super) fn check_covers(
        &self,
        accel_file: &Path,
        first_latch_s: f64,
        last_latch_s: f64,
        period_s: f64,
    ) -> std::result::Result<(), String> {
        let Some([lo, hi]) = self.span_s() else {
            return Ok(());
        };
        let from = first_latch_s - period_s;
        // Rounding of the CSV's times: a thousandth of a period.
        let slack = 1e-3 * period_s;
        if from + slack >= lo && last_latch_s - slack <= hi {
            return Ok(());
        }
        let source = match self {
            Reference::Stream { file, .. } => format!("the reference stream {file}"),
            Reference::Spec(_) => "the rig's reference.segment list".to_string(),
        };
        Err(format!(
            "{}: the readings span {from:.6} .. {last_latch_s:.6} s (their intervals), but \
             {source} covers {lo:.6} .. {hi:.6} s: the reference must cover every reading",
            accel_file.display()
        ))
    }

    /// The specific force along the body axes at `t_s`, g; `None` where the reference
    /// states none (between static segments).
    fn body_g_at(&self, t_s: f64) -> Option<[f64; 3]> {
        match self {
            Reference::Spec(spec) => spec.body_g_at(t_s),
            Reference::Stream { time_s, body_g, .. } => {
                let n = time_s.len();
                if n == 0 || !(t_s >= time_s[0] && t_s <= time_s[n - 1]) {
                    return None;
                }
                let k = time_s.partition_point(|&x| x <= t_s).clamp(1, n - 1);
                let (t0, t1) = (time_s[k - 1], time_s[k]);
                let w = if t1 > t0 { (t_s - t0) / (t1 - t0) } else { 0.0 };
                let (a, b) = (body_g[k - 1], body_g[k]);
                Some(std::array::from_fn(|i| a[i] + w * (b[i] - a[i])))
            }
        }
    }

    /// The reading's reference over `(t - T, t]`: at the interval's middle, when the
    /// whole interval has one (module doc).
    fn interval_body_g(&self, latch_s: f64, period_s: f64) -> Option<[f64; 3]> {
        let start = self.body_g_at(latch_s - period_s)?;
        let end = self.body_g_at(latch_s)?;
        if let Reference::Spec(ReferenceSpec::Static { .. }) = self {
            // Both ends in the same orientation (segments do not overlap).
            if start != end {
                return None;
            }
        }
        self.body_g_at(latch_s - 0.5 * period_s)
    }

    /// The reference channel's block for `accel` (same `seq`, indices, timing, count
    /// and source), each unit's `a_l_ia_g` the reference projected on its input axis;
    /// returns the readings left without a reference.
    pub(super) fn truth_block(
        &self,
        axes: &vibro_config::rig::TriadAxes,
        accel: &AccelBlock,
        out: &mut TruthBlock,
    ) -> u64 {
        *out = TruthBlock::ZEROED;
        out.seq = accel.seq;
        out.first_sample_index = accel.first_sample_index;
        out.t0_ns = accel.t0_ns;
        out.sample_period_ns = accel.sample_period_ns;
        out.publish_ns = accel.publish_ns;
        out.count = accel.count;
        out.source_id = accel.source_id;
        out.flags = truth_flags::SENSED_UNKNOWN;
        if accel.flags & vibro_msgs::accel_flags::GAP_BEFORE != 0 {
            out.flags |= truth_flags::GAP_BEFORE;
        }
        let period_s = accel.sample_period_ns as f64 * 1e-9;
        let mut missing = 0;
        let n = (accel.count as usize).min(out.a_l_ia_g.len());
        for k in 0..n {
            let latch_s = (accel.t0_ns as f64 + k as f64 * accel.sample_period_ns as f64) * 1e-9;
            let value = match self.interval_body_g(latch_s, period_s) {
                Some(body) => axes.units.map(|u| u.ia.project(&body)),
                None => {
                    missing += 1;
                    [f64::NAN; 3]
                }
            };
            out.a_l_ia_g[k] = value;
            out.a_sensed_ia_g[k] = [f64::NAN; 3];
            out.vib_error_ia_g[k] = [f64::NAN; 3];
        }
        missing
    }
}
