//! A log read for the lab on the waveform (issue 44, [`crate::wave_diagnose`]): its
//! readings, its reference and its vibration samples, as `vibro_wavefit::RunInput`.
//!
//! The units' passports and the sensors' chain come as for the statistics path
//! ([`crate::log_table`]): the log's own passports when it carries all three, else the
//! triad's; the sensors' sensitivity, AC corner and delay from the log's metadata (a
//! rig file's `[sensors]`), over the estimator's configuration. A delay the metadata
//! does not state is unknown: the fit finds it.
//!
//! Bounds: at most [`MAX_VIB_SAMPLES`] sensor samples and [`MAX_READINGS`] readings per
//! log (refused beyond, with the figure). The readings must run on one clock (a block
//! whose stamps leave the first block's grid by a quarter period is refused, with its
//! index); the samples may break (a gap, a rate change, a flagged block): each stretch
//! is a segment, and the readings near a break are left out by the fit.

use crate::log_table::{estimator_config, log_units, LogOptions, LogTableSummary};
use crate::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;
use vibro_log::topic;
use vibro_mcap::Message;
use vibro_msgs::{vib_flags, Stream};
use vibro_wavefit::{RunInput, VibSegment};

/// Most sensor samples read from one log (about 33 min at 25.6 kHz; 24 bytes each).
pub const MAX_VIB_SAMPLES: usize = 50_000_000;
/// Most readings read from one log (about 17 h at 800 Hz).
pub const MAX_READINGS: usize = 50_000_000;

/// A log as the waveform fit reads it.
#[derive(Debug, Clone)]
pub struct WaveLog {
    pub input: RunInput,
    /// The log's metadata states the sensors' delay.
    pub delay_stated: bool,
    /// Where the passports came from (`log`, or `triad ID`).
    pub passports_from: String,
    /// Sensor blocks left out (flagged saturated), and breaks in the samples.
    pub vib_blocks_refused: u64,
    pub vib_breaks: u64,
}

/// Reads `path` (module doc).
pub fn read_log(path: &Path, options: &LogOptions) -> Result<WaveLog> {
    let name = path.display().to_string();
    let mut summary = LogTableSummary {
        log: name.clone(),
        ..Default::default()
    };
    let mut reader = crate::log_table::open_log(path)?;
    let units = log_units(&mut reader, options, &mut summary)?;
    let config = estimator_config(&options.estimator, &mut reader, &mut summary)?;
    let delay = summary.sensor_from_log.get("sensor_delay_s").copied();
    let chain = vibro_waveform::SensorChain {
        sensitivity_v_per_g: config.raw().sensitivity_raw_per_g,
        ac_corner_hz: config.raw().ac_corner_hz.unwrap_or(0.0),
        delay_s: delay.unwrap_or(0.0),
    };
    let (vib_topic, accel_topic, truth_topic) = (
        topic(Stream::Vib),
        topic(Stream::Accel),
        topic(Stream::Truth),
    );
    let k1: Vec<f64> = units.flat.iter().map(|p| p.k1_v_per_g).collect();
    // Readings and reference by sample index.
    let mut rows: BTreeMap<u64, ([f64; 3], [f64; 3])> = BTreeMap::new();
    let nan3 = [f64::NAN; 3];
    let mut clock: Option<(u64, u64, u64)> = None; // (index, latch ns, period ns)
    let mut segments: Vec<VibSegment> = Vec::new();
    let mut vib_samples = 0usize;
    let (mut refused, mut breaks) = (0u64, 0u64);
    let mut next_vib: Option<(u64, u64, u64)> = None; // (index, t ns, period ns)
                                                      // The current segment's first sample index and stamp (its period from the stamps).
    let mut seg_start: (u64, u64) = (0, 0);
    let too_many = |what: &str, max: usize| {
        Error::Invalid(format!(
            "{name}: over {max} {what}: more than the lab's waveform fit reads from one log \
             (split it with `vibrocomp log cut`, or use --path statistics)"
        ))
    };
    for record in reader {
        let record = record?;
        let t = &*record.topic;
        match &record.message {
            Message::VibBlock(b) if t == vib_topic => {
                if b.flags & vib_flags::SATURATED != 0
                    || b.sample_period_ns == 0
                    || b.samples_v().iter().flatten().any(|x| !x.is_finite())
                {
                    refused += 1;
                    next_vib = None;
                    continue;
                }
                let continues = next_vib.is_some_and(|(i, t_ns, p)| {
                    i == b.first_sample_index
                        && p == b.sample_period_ns
                        && t_ns.abs_diff(b.t0_ns) <= p / 4
                        && b.t0_ns >= seg_start.1
                }) && b.flags & vib_flags::GAP_BEFORE == 0;
                let samples = b.samples_v();
                vib_samples += samples.len();
                if vib_samples > MAX_VIB_SAMPLES {
                    return Err(too_many("vibration samples", MAX_VIB_SAMPLES));
                }
                match segments.last_mut() {
                    Some(seg) if continues => {
                        seg.samples_v.extend_from_slice(samples);
                        // The period from the stamps: the first block's to this one's.
                        let k = b.first_sample_index - seg_start.0;
                        if k > 0 {
                            seg.period_s = (b.t0_ns - seg_start.1) as f64 * 1e-9 / k as f64;
                        }
                    }
                    _ => {
                        if !segments.is_empty() {
                            breaks += 1;
                        }
                        seg_start = (b.first_sample_index, b.t0_ns);
                        segments.push(VibSegment {
                            t0_ns: b.t0_ns,
                            period_s: b.sample_period_ns as f64 * 1e-9,
                            samples_v: samples.to_vec(),
                        });
                    }
                }
                let n = samples.len() as u64;
                next_vib = Some((
                    b.first_sample_index + n,
                    b.t0_ns + n * b.sample_period_ns,
                    b.sample_period_ns,
                ));
            }
            Message::AccelBlock(b) if t == accel_topic => {
                let p = b.sample_period_ns;
                let (i0, l0, p0) = *clock.get_or_insert((b.first_sample_index, b.t0_ns, p));
                let expected =
                    l0 as i128 + (b.first_sample_index as i128 - i0 as i128) * p0 as i128;
                if p != p0 || (b.t0_ns as i128 - expected).unsigned_abs() > u128::from(p0 / 4) {
                    return Err(Error::Invalid(format!(
                        "{name}: the accelerometer block at sample {} (t0 {} ns, period {p} \
                         ns) leaves the readings' clock (period {p0} ns, {expected} ns \
                         expected): the waveform fit needs the readings on one clock",
                        b.first_sample_index, b.t0_ns
                    )));
                }
                for (k, u) in b.samples_v().iter().enumerate() {
                    if rows.len() >= MAX_READINGS {
                        return Err(too_many("readings", MAX_READINGS));
                    }
                    let row = rows
                        .entry(b.first_sample_index + k as u64)
                        .or_insert((nan3, nan3));
                    row.0 = std::array::from_fn(|i| u[i] / k1[i]);
                }
            }
            Message::TruthBlock(b) if t == truth_topic => {
                for k in 0..(b.count as usize).min(b.a_l_ia_g.len()) {
                    let idx = b.first_sample_index + k as u64;
                    if rows.len() >= MAX_READINGS && !rows.contains_key(&idx) {
                        return Err(too_many("readings", MAX_READINGS));
                    }
                    let row = rows.entry(idx).or_insert((nan3, nan3));
                    row.1 = b.a_l_ia_g[k];
                }
            }
            _ => {}
        }
    }
    let Some((i0, l0, p0)) = clock else {
        return Err(Error::Invalid(format!(
            "{name}: no accelerometer readings ({accel_topic})"
        )));
    };
    if segments.is_empty() {
        return Err(Error::Invalid(format!(
            "{name}: the lab on the waveform needs the vibration sensors ({vib_topic}): none \
             usable ({refused} blocks refused); it predicts each reading from them"
        )));
    }
    if !rows.values().any(|r| r.1[0].is_finite()) {
        return Err(Error::Invalid(format!(
            "{name}: no reference ({truth_topic}): import a rig's log with its rig file \
             (vibrocomp log import --rig RIG.toml, docs/logs.md)"
        )));
    }
    // Contiguous readings from the first index with a reading to the last.
    let first = rows
        .iter()
        .find(|(_, r)| r.0[0].is_finite())
        .map(|(&i, _)| i);
    let last = rows
        .iter()
        .rev()
        .find(|(_, r)| r.0[0].is_finite())
        .map(|(&i, _)| i);
    let (Some(first), Some(last)) = (first, last) else {
        return Err(Error::Invalid(format!("{name}: no readings")));
    };
    let count = (last - first + 1) as usize;
    if count > MAX_READINGS {
        return Err(too_many("readings", MAX_READINGS));
    }
    let mut readings_g = vec![nan3; count];
    let mut a_l_ia_g = vec![nan3; count];
    for (&i, r) in rows.range(first..=last) {
        readings_g[(i - first) as usize] = r.0;
        a_l_ia_g[(i - first) as usize] = r.1;
    }
    let first_latch_ns = (l0 as i128 + (first as i128 - i0 as i128) * p0 as i128).max(0) as u64;
    let passports = [units.flat[0], units.flat[1], units.flat[2]];
    Ok(WaveLog {
        input: RunInput {
            name,
            axes: units.triad.axes,
            passports,
            chain,
            delay_stated: delay.is_some(),
            period_ns: p0,
            first_latch_ns,
            readings_g,
            a_l_ia_g,
            vib: segments,
        },
        delay_stated: delay.is_some(),
        passports_from: summary.passports_from,
        vib_blocks_refused: refused,
        vib_breaks: breaks,
    })
}
