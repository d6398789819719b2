//! A rig's units' linear response to the vibration, from its vibration sensors: what a
//! rig's reference (`log import --rig`: the flight acceleration, `truth_flags::SENSED_UNKNOWN`)
//! leaves out of what each unit senses.
//!
//! Per reading of a rig's reference, [`fit_linear_responses`] reads the log's vibration
//! sensors (sensor `u` along unit `u`'s input axis, so the three give the body's
//! vibration through the triad) and gives
//!
//! - the mean of each sensor over the reading's interval `(latch - T, latch]` over its
//!   stated sensitivity, g: the vibration at the sensors' base along each IA;
//! - each unit's linear response to that vibration over the reading's interval, g,
//!   fitted to its readings: the readings regressed on the body's vibration filtered by
//!   a response piecewise linear in frequency (real and imaginary part per knot, the
//!   sensors' AC coupling undone) and averaged over each reading's interval exactly
//!   (`vibro_ident::reference`, the shake-table campaign's fit). A unit behind a mount
//!   (a resonance between the sensors' base and the unit) does not respond to the base's
//!   motion as its passport says; its fitted response does, and the rectified part of
//!   its readings, even in the vibration, is not correlated with it.
//!
//! The readings are fitted in stretches of at most [`FIT_CHUNK_S`] as the sensors'
//! samples stream past (memory bounded by a stretch), with [`FIT_MARGIN_S`] of samples
//! on each side; readings within that margin of the sensors' record's ends (the log's
//! first and last second) are left out of the fit ([`Fitted::linear_g`] NaN), as is a
//! stretch whose sensor samples have a gap or change rate (its readings keep the
//! sensors' means only). The lab (`vibro_lab::log_table`) and `log errors` read a rig's
//! log through it.

use std::collections::BTreeMap;
use std::path::Path;

use vibro_config::rig::TriadAxes;
use vibro_mcap::{Message, Reader};
use vibro_msgs::Stream;
use vibro_physics::passport::Passport;

use crate::{topic, Error, Result};

/// One reading of a rig's reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigReading {
    /// Its latch time (the end of its interval), ns.
    pub latch_ns: u64,
    /// The units' outputs, V.
    pub output_v: [f64; 3],
    /// The rig's reference along each unit's IA, g.
    pub a_l_ia_g: [f64; 3],
}

/// What turns the sensors' volts into g.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorChain {
    /// Per sensor (sensor `u` along unit `u`'s IA), V/g; a negative one flips.
    pub sensitivity_v_per_g: [f64; 3],
    /// The sensors' first-order AC coupling, Hz (undone in the fit); `None`: DC-coupled.
    pub ac_corner_hz: Option<f64>,
}

/// What the sensors give one reading.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Fitted {
    /// The sensors' means over the reading's interval, g, along each unit's IA; `None`
    /// when no sensor sample falls in it.
    pub sensor_mean_g: Option<[f64; 3]>,
    /// Each unit's fitted linear response over the interval, g; `None`: its stretch was
    /// not fitted; NaN for a unit: the reading is left out of its stretch's fit.
    pub linear_g: Option<[f64; 3]>,
    sum_v: [f64; 3],
    samples: u32,
}

/// Every reading's [`Fitted`], and how many stretches and readings were fitted.
#[derive(Debug, Clone, Default)]
pub struct LinearResponses {
    pub readings: BTreeMap<u64, Fitted>,
    pub fits: u64,
    pub fitted_readings: u64,
}

/// Reads the vibration sensors of the log at `path` for `readings` (by sample index;
/// the accelerometer's output period `period_ns`) of a triad with `axes` and (flat)
/// `passports` (module doc).
pub fn fit_linear_responses(
    path: &Path,
    readings: &BTreeMap<u64, RigReading>,
    period_ns: u64,
    axes: &TriadAxes,
    passports: &[Passport; 3],
    sensors: &SensorChain,
) -> Result<LinearResponses> {
    let mut out: BTreeMap<u64, Fitted> = BTreeMap::new();
    let (Some((&first_index, first)), true) = (readings.iter().next(), period_ns > 0) else {
        return Ok(LinearResponses::default());
    };
    let first_latch_ns = first.latch_ns;
    let mut fitter = ResponseFitter::new(readings, period_ns, axes, passports, sensors);
    let vib_topic = topic(Stream::Vib);
    let reader = Reader::open(path).map_err(|source| Error::ReadLog {
        context: format!("{}: reading the vibration sensors", path.display()),
        source,
    })?;
    for record in reader {
        let record = record.map_err(|source| Error::ReadLog {
            context: format!("{}: reading the vibration sensors", path.display()),
            source,
        })?;
        let Message::VibBlock(b) = &record.message else {
            continue;
        };
        if *record.topic != vib_topic {
            continue;
        }
        for (k, v) in b.samples_v().iter().enumerate() {
            let t_ns = b.t0_ns as i128 + k as i128 * b.sample_period_ns as i128;
            fitter.push(t_ns, b.sample_period_ns, *v, readings, &mut out);
            // The reading whose interval (latch - T, latch] holds t.
            let d = t_ns - first_latch_ns as i128;
            let steps =
                d.div_euclid(period_ns as i128) + i128::from(d.rem_euclid(period_ns as i128) != 0);
            let Ok(index) = u64::try_from(first_index as i128 + steps) else {
                continue;
            };
            if let Some(r) = readings.get(&index) {
                if t_ns <= r.latch_ns as i128 && t_ns > r.latch_ns as i128 - period_ns as i128 {
                    let f = out.entry(index).or_default();
                    for (sum, x) in f.sum_v.iter_mut().zip(v) {
                        *sum += x;
                    }
                    f.samples += 1;
                }
            }
        }
    }
    fitter.finish(readings, &mut out);
    let s = sensors.sensitivity_v_per_g;
    for f in out.values_mut() {
        if f.samples > 0 {
            let n = f64::from(f.samples);
            f.sensor_mean_g = Some(std::array::from_fn(|u| f.sum_v[u] / n / s[u]));
        }
    }
    Ok(LinearResponses {
        readings: out,
        fits: fitter.fits,
        fitted_readings: fitter.fitted_readings,
    })
}

/// Longest stretch of readings one linear-response fit spans, s: its basis holds
/// `2 x knots x 3` values per reading (16 s at 800 Hz: 12 800 readings, about 30 MB).
pub const FIT_CHUNK_S: f64 = 16.0;
/// Sensor samples kept on each side of a fit's readings, s: the fitted filters' impulse
/// responses (knots 20 Hz apart, the AC coupling undone above fc / 4) have died out by
/// then, and the record's ends, where its periodic extension jumps, stay clear of the
/// readings.
pub const FIT_MARGIN_S: f64 = 1.0;

/// The fits of [`fit_linear_responses`], stretch by stretch as the sensors' samples stream
/// past: the readings of a rig's reference in chunks of at most [`FIT_CHUNK_S`], each
/// fitted once the samples reach [`FIT_MARGIN_S`] beyond it.
struct ResponseFitter<'u> {
    axes: &'u TriadAxes,
    passports: &'u [Passport; 3],
    sensitivity: [f64; 3],
    /// The sensors' AC coupling, undone in the fit.
    ac_corner_hz: Option<f64>,
    period_ns: u64,
    /// The chunks: (first, last) reading index, in order; `next` is the one being filled.
    chunks: Vec<(u64, u64, i128, i128)>,
    next: usize,
    /// Sensor samples: time, the three channels (V).
    samples: std::collections::VecDeque<(i128, [f64; 3])>,
    /// The sensors' sample period, ns (0: none yet); a change, or a sample off the grid,
    /// breaks the record: the chunk it falls in is not fitted.
    sample_period_ns: u64,
    broken: bool,
    fits: u64,
    fitted_readings: u64,
}

impl<'u> ResponseFitter<'u> {
    fn new(
        rows: &BTreeMap<u64, RigReading>,
        period_ns: u64,
        axes: &'u TriadAxes,
        passports: &'u [Passport; 3],
        sensors: &SensorChain,
    ) -> Self {
        let (sensitivity, ac_corner_hz) = (sensors.sensitivity_v_per_g, sensors.ac_corner_hz);
        let mut chunks = Vec::new();
        let chunk_ns = (FIT_CHUNK_S * 1e9) as i128;
        let mut current: Option<(u64, u64, i128, i128)> = None;
        for (&i, r) in rows {
            let t = r.latch_ns as i128;
            match &mut current {
                Some(c) if t - c.2 < chunk_ns && i == c.1 + 1 => {
                    c.1 = i;
                    c.3 = t;
                }
                _ => {
                    if let Some(c) = current.take() {
                        chunks.push(c);
                    }
                    current = Some((i, i, t, t));
                }
            }
        }
        chunks.extend(current);
        Self {
            axes,
            passports,
            sensitivity,
            ac_corner_hz,
            period_ns,
            chunks,
            next: 0,
            samples: Default::default(),
            sample_period_ns: 0,
            broken: false,
            fits: 0,
            fitted_readings: 0,
        }
    }

    /// One sensor sample at `t_ns`.
    fn push(
        &mut self,
        t_ns: i128,
        period_ns: u64,
        v: [f64; 3],
        rows: &BTreeMap<u64, RigReading>,
        out: &mut BTreeMap<u64, Fitted>,
    ) {
        let margin = (FIT_MARGIN_S * 1e9) as i128;
        // Fit every chunk the samples have passed.
        while let Some(&(_, _, _, end)) = self.chunks.get(self.next) {
            if t_ns <= end + margin {
                break;
            }
            self.fit_next(rows, out);
        }
        let Some(&(_, _, start, _)) = self.chunks.get(self.next) else {
            return;
        };
        if t_ns < start - self.period_ns as i128 - margin {
            return;
        }
        if let Some(&(last, _)) = self.samples.back() {
            if period_ns != self.sample_period_ns || t_ns - last != i128::from(period_ns) {
                self.broken = true;
            }
        }
        self.sample_period_ns = period_ns;
        self.samples.push_back((t_ns, v));
    }

    /// Fits the remaining chunks with the samples there are.
    fn finish(&mut self, rows: &BTreeMap<u64, RigReading>, out: &mut BTreeMap<u64, Fitted>) {
        while self.next < self.chunks.len() {
            self.fit_next(rows, out);
        }
    }

    /// Fits chunk `next` and moves on, dropping the samples the following chunk does
    /// not need.
    fn fit_next(&mut self, rows: &BTreeMap<u64, RigReading>, out: &mut BTreeMap<u64, Fitted>) {
        let (first, last, _, _) = self.chunks[self.next];
        if !self.broken {
            self.fit(first, last, rows, out);
        }
        self.next += 1;
        self.broken = false;
        let margin = (FIT_MARGIN_S * 1e9) as i128;
        let keep_from = self
            .chunks
            .get(self.next)
            .map_or(i128::MAX, |c| c.2 - self.period_ns as i128 - margin);
        while self.samples.front().is_some_and(|s| s.0 < keep_from) {
            self.samples.pop_front();
        }
    }

    /// Each unit's linear response over readings `first..=last`: the readings
    /// regressed on the body's vibration (the sensors through the triad, in g) filtered
    /// by a response piecewise linear in frequency and averaged over each reading's
    /// interval exactly (`vibro_ident::reference`, the campaign's fit); the fitted part
    /// (without the constant) over K1 is the reading's linear response, g.
    fn fit(
        &mut self,
        first: u64,
        last: u64,
        rows: &BTreeMap<u64, RigReading>,
        out: &mut BTreeMap<u64, Fitted>,
    ) {
        let n = self.samples.len();
        if n < 16 || self.sample_period_ns == 0 {
            return;
        }
        let rate_hz = 1e9 / self.sample_period_ns as f64;
        let t0_s = self.samples[0].0 as f64 * 1e-9;
        let axes = self.axes;
        // The body's vibration: sensor u is along unit u's IA.
        let mut body: [Vec<f64>; 3] = Default::default();
        for b in &mut body {
            b.reserve(n);
        }
        for (_, v) in &self.samples {
            let mut x = [0.0; 3];
            for (u, unit) in axes.units.iter().enumerate() {
                x[unit.ia.body_index] = f64::from(unit.ia.sign) * v[u] / self.sensitivity[u];
            }
            for a in 0..3 {
                body[a].push(x[a]);
            }
        }
        let readings: Vec<(u64, f64, [f64; 3], [f64; 3])> = rows
            .range(first..=last)
            .map(|(&i, r)| (i, r.latch_ns as f64 * 1e-9, r.output_v, r.a_l_ia_g))
            .collect();
        if readings.is_empty() {
            return;
        }
        let times: Vec<f64> = readings.iter().map(|r| r.1).collect();
        let interval_s = self.period_ns as f64 * 1e-9;
        let Some(inputs) = body
            .iter()
            .map(|x| {
                vibro_ident::reference::IntervalMeans::with_line_span(
                    x,
                    t0_s,
                    rate_hz,
                    interval_s,
                    &times,
                    FIT_MARGIN_S,
                )
            })
            .collect::<Option<Vec<_>>>()
            .and_then(|v| <[_; 3]>::try_from(v).ok())
        else {
            return;
        };
        // The readings whose intervals the samples cover (the log's first and last may
        // reach past its sensors' record).
        // Readings within FIT_MARGIN_S of the record's ends (the log's first and last
        // chunk: no samples beyond them) are left out: the record's periodic extension
        // jumps there. They are left without a sensed acceleration (not used).
        let t_end_s = self.samples[n - 1].0 as f64 * 1e-9;
        let window = [
            (times[0] - interval_s).max(t0_s + FIT_MARGIN_S),
            times[times.len() - 1].min(t_end_s - FIT_MARGIN_S),
        ];
        let knots = vibro_ident::reference::response_knots_hz(
            vibro_ident::rig::RESPONSE_TOP_FRACTION_OF_RATE * rate_hz,
        );
        let kind = vibro_ident::reference::BasisInputs {
            ac_corner_hz: self.ac_corner_hz,
        };
        let Some(basis) = vibro_ident::reference::ResponseBasis::with_inputs(
            &inputs, &times, window, &knots, &kind,
        ) else {
            return;
        };
        let mut fitted_any = false;
        for (u, unit) in axes.units.iter().enumerate() {
            let p = &self.passports[u];
            // The passport's linear response per body axis at the chunk's mean flight
            // acceleration: J(aL) in the unit's axes, through the unit's axes, times K1.
            let mean_ia: [f64; 3] = std::array::from_fn(|j| {
                readings.iter().map(|r| r.3[j]).sum::<f64>() / readings.len() as f64
            });
            let a_l = unit.to_unit(&axes.body_from_ia(&mean_ia));
            let grad = vibro_physics::fp::gradient_g(p, a_l[0], a_l[1], a_l[2]);
            let rows_of = [unit.oa, unit.pa, unit.ia];
            let mut weights = [0.0; 3];
            for (j, axis) in rows_of.iter().enumerate() {
                weights[axis.body_index] += p.k1_v_per_g * grad[j] * f64::from(axis.sign);
            }
            let u_v: Vec<f64> = readings.iter().map(|r| r.2[u]).collect();
            let Some((fitted, _)) = basis.fit(weights, &u_v) else {
                continue;
            };
            for (r, f) in readings.iter().zip(fitted) {
                let l = out
                    .entry(r.0)
                    .or_default()
                    .linear_g
                    .get_or_insert([f64::NAN; 3]);
                l[u] = f / p.k1_v_per_g;
            }
            fitted_any = true;
        }
        if fitted_any {
            self.fits += 1;
            self.fitted_readings += readings.len() as u64;
        }
    }
}
