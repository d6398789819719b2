//! The shake table's reference accelerometer: what each reading of a unit averaged of
//! the table's motion, and the VE measured with the unit's linear response to it removed
//! (MODEL.md section 8, issue 30).
//!
//! **Why.** A unit's reading is the mean of its output over the reading's interval
//! (RIG.md: 800 Hz readings). Under a tone and random vibration the vibrating record's
//! readings carry the unit's linear response `K1*(k1*a3 + m1*a1 + m2*a2)` [P1 (1)] to
//! the vibration. Its mean over the record is tiny (the vibration has no power at 0 Hz),
//! but its batch means are not: a tone's leftover part-period in each batch, the random
//! part's slow sidelobes. The batch-means uncertainty of [P2 (16)] then states about
//! 14 times the VE's scatter over repeats (measured on the independent rig generator's
//! runs with tones of 0.5..2 g and 20..640 Hz random vibration; docs/identification.md).
//! Removing that linear response, computed from a DC-coupled reference accelerometer on
//! the table, leaves the rectified part and the noise: the uncertainty then states the
//! scatter within 10 %.
//!
//! **The reading's average of the reference.** A reading latched at `t` is the mean of
//! the output over `(t - T, t]`, `T` the reading period. For a band-limited reference
//! sampled at `f_s` the exact mean over that interval of `x(tau) = e^{i 2 pi f tau}` is
//! `e^{i 2 pi f t} sinc(f T) e^{-i pi f T}` (`sinc(u) = sin(pi u)/(pi u)`): the reference
//! is filtered by that response in the frequency domain (a real FFT of the whole record,
//! the straight line through its first and last reading intervals' means removed first
//! and added back as its value at `t - T/2`, the line's own interval mean: a record that
//! starts and ends still then joins end to start without a jump), then read at each
//! reading's latch time. The filter also moves the
//! record by the readings' offset from the reference's sample grid (a fractional delay),
//! so a reading between two reference samples is exact too; readings whose offset differs
//! from the first's (rates that are not multiples) are read by linear interpolation.
//! A rate-independent rule: the trapezoid rule over the reference's samples instead
//! states 1.58 times the scatter at 3.2 kHz (docs/identification.md).

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner};
use std::f64::consts::PI;
use std::sync::Arc;

/// A record prepared for interval means: its straight line (module docs) and the
/// spectrum of the rest, and where the readings fall on its sample grid.
pub struct IntervalMeans {
    spectrum: Vec<Complex<f64>>,
    /// The inverse transform, planned once for every filter applied.
    inverse: Arc<dyn ComplexToReal<f64>>,
    n: usize,
    t0_s: f64,
    rate_hz: f64,
    interval_s: f64,
    offset_s: f64,
    /// The line through the first and last intervals' means: value at sample 0, slope
    /// per sample.
    line: (f64, f64),
}

impl IntervalMeans {
    /// Prepares `x` (sampled at `rate_hz` from `t0_s`) for readings over
    /// `(t - interval_s, t]` at `times_s`. `None` for a record of fewer than 4 samples
    /// or a rate or interval that is not positive.
    pub fn new(
        x: &[f64],
        t0_s: f64,
        rate_hz: f64,
        interval_s: f64,
        times_s: &[f64],
    ) -> Option<Self> {
        Self::with_line_span(x, t0_s, rate_hz, interval_s, times_s, interval_s)
    }

    /// [`Self::new`] with the straight line drawn through the means of the record's
    /// first and last `line_span_s` (at least one reading's interval) instead of one
    /// reading's interval: for a record that vibrates at its ends (a stretch of a
    /// vibration sensor's stream), whose one-interval means are the vibration's
    /// instantaneous values, a line through them is not the record's slow part.
    pub fn with_line_span(
        x: &[f64],
        t0_s: f64,
        rate_hz: f64,
        interval_s: f64,
        times_s: &[f64],
        line_span_s: f64,
    ) -> Option<Self> {
        let n = x.len();
        if n < 4 || !(rate_hz > 0.0 && interval_s > 0.0) {
            return None;
        }
        let dt = 1.0 / rate_hz;
        let t_end_s = t0_s + (n - 1) as f64 * dt;
        // The readings' offset from the sample grid (the first covered reading's).
        let offset_s = times_s
            .iter()
            .find(|&&t| t - interval_s >= t0_s - 1e-9 * dt && t <= t_end_s)
            .map(|&t| {
                let k = ((t - t0_s) / dt).floor();
                t - (t0_s + k * dt)
            })
            .unwrap_or(0.0);
        // The straight line through the means of the record's first and last reading
        // intervals, removed and added back: a rig's record starts and ends still, so the
        // rest joins its end to its start without a jump (the FFT sees a periodic signal).
        let m = ((line_span_s.max(interval_s) * rate_hz).round() as usize).clamp(1, n / 2);
        let head = x[..m].iter().sum::<f64>() / m as f64;
        let tail = x[n - m..].iter().sum::<f64>() / m as f64;
        let (c0, c1) = ((m - 1) as f64 / 2.0, (n - 1) as f64 - (m - 1) as f64 / 2.0);
        let slope = (tail - head) / (c1 - c0);
        let at0 = head - slope * c0;
        let mut buf: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(i, v)| v - (at0 + slope * i as f64))
            .collect();
        let mut planner = RealFftPlanner::<f64>::new();
        let forward = planner.plan_fft_forward(n);
        let mut spectrum = forward.make_output_vec();
        forward.process(&mut buf, &mut spectrum).ok()?;
        // The interval mean over (t - T, t], advanced by the offset (the value at grid
        // sample i is the mean over (t_i + offset - T, t_i + offset]), and the inverse
        // transform's 1/n, once for every filter applied later.
        let nf = n as f64;
        for (k, c) in spectrum.iter_mut().enumerate() {
            let f_hz = k as f64 * rate_hz / nf;
            let u = f_hz * interval_s;
            let sinc = if u == 0.0 {
                1.0
            } else {
                (PI * u).sin() / (PI * u)
            };
            let phase = -PI * f_hz * interval_s + 2.0 * PI * f_hz * offset_s;
            *c *= Complex::from_polar(sinc / nf, phase);
        }
        Some(Self {
            spectrum,
            inverse: planner.plan_fft_inverse(n),
            n,
            t0_s,
            rate_hz,
            interval_s,
            offset_s,
            line: (at0, slope),
        })
    }

    /// The interval means at `times_s` of the record filtered by `response(f_hz)` (a
    /// real filter's response at `f >= 0`; 1 everywhere: the record itself). The line is
    /// added back with the response at 0 Hz (`with_line`; a response that is 0 at 0 Hz
    /// passes no line). `None` where an interval is not inside the record.
    pub fn filtered(
        &self,
        response: impl Fn(f64) -> Complex<f64>,
        with_line: bool,
        times_s: &[f64],
    ) -> Vec<Option<f64>> {
        let n = self.n;
        let nf = n as f64;
        let (rate_hz, interval_s, offset_s) = (self.rate_hz, self.interval_s, self.offset_s);
        let mut spectrum = self.spectrum.clone();
        let last = spectrum.len() - 1;
        for (k, c) in spectrum.iter_mut().enumerate() {
            *c *= response(k as f64 * rate_hz / nf);
            if k == last && n.is_multiple_of(2) {
                // The Nyquist bin of a real signal has no phase.
                c.im = 0.0;
            }
        }
        spectrum[0].im = 0.0;
        let mut buf = self.inverse.make_output_vec();
        if self.inverse.process(&mut spectrum, &mut buf).is_err() {
            return vec![None; times_s.len()];
        }
        let dt = 1.0 / rate_hz;
        let t_end_s = self.t0_s + (n - 1) as f64 * dt;
        let gain0 = if with_line { response(0.0).re } else { 0.0 };
        let (at0, slope) = self.line;
        // The line's own interval mean at t: its value at t - T/2.
        let line_at = |t: f64| gain0 * (at0 + slope * (t - interval_s / 2.0 - self.t0_s) / dt);
        times_s
            .iter()
            .map(|&t| {
                if !(t - interval_s >= self.t0_s - 1e-9 * dt && t <= t_end_s + 1e-9 * dt) {
                    return None;
                }
                let pos = (t - offset_s - self.t0_s) / dt;
                let i = pos.round();
                let value = if (pos - i).abs() < 1e-6 {
                    *buf.get(i as usize)?
                } else {
                    // Off the common offset: linear interpolation between grid values.
                    let i0 = pos.floor();
                    let w = pos - i0;
                    let a = *buf.get(i0 as usize)?;
                    let b = *buf.get(i0 as usize + 1).unwrap_or(&a);
                    a + w * (b - a)
                };
                Some(value + line_at(t))
            })
            .collect()
    }
}

/// The mean of the band-limited signal `x` (sampled at `rate_hz` from `t0_s`) over
/// `(t - interval_s, t]` for each `t` of `times_s` (module docs). `None` where the
/// interval is not inside the record (from its first sample to its last).
pub fn interval_means_at(
    x: &[f64],
    t0_s: f64,
    rate_hz: f64,
    interval_s: f64,
    times_s: &[f64],
) -> Vec<Option<f64>> {
    match IntervalMeans::new(x, t0_s, rate_hz, interval_s, times_s) {
        Some(m) => m.filtered(|_| Complex::new(1.0, 0.0), true, times_s),
        None => vec![None; times_s.len()],
    }
}

/// The frequencies of the fitted response's knots, Hz: every 20 Hz up to 320 Hz, then
/// 1/16 of the frequency apart (a resonance of Q up to about 8 spans several knots),
/// up to `f_top_hz`.
pub fn response_knots_hz(f_top_hz: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let mut f = 20.0;
    while f <= f_top_hz {
        out.push(f);
        f += (f / 16.0).max(20.0);
    }
    out
}

/// The piecewise-linear "hat" of knot `k` at `f_hz`: 1 at the knot, 0 at its
/// neighbours (0 Hz below the first; flat beyond the last).
fn hat(knots: &[f64], k: usize, f_hz: f64) -> f64 {
    let f_k = knots[k];
    let left = if k == 0 { 0.0 } else { knots[k - 1] };
    if f_hz <= f_k {
        return ((f_hz - left) / (f_k - left)).max(0.0);
    }
    match knots.get(k + 1) {
        Some(&right) => ((right - f_hz) / (right - f_k)).max(0.0),
        None => 1.0,
    }
}

/// What the inputs of a [`ResponseBasis`] are.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BasisInputs {
    /// The inputs passed a first-order AC coupling at this corner (Hz), undone in the
    /// fit's columns: `1 - j fc / f` above `fc / 4`, tapered linearly to 0 at 0 Hz
    /// below (the inverse's gain, at most 4.1, does not lift the slowest drifts).
    pub ac_corner_hz: Option<f64>,
}

impl BasisInputs {
    fn undo_coupling(&self, f_hz: f64) -> Complex<f64> {
        let Some(fc) = self.ac_corner_hz.filter(|fc| *fc > 0.0) else {
            return Complex::new(1.0, 0.0);
        };
        let floor = 0.25 * fc;
        if f_hz >= floor {
            Complex::new(1.0, -fc / f_hz)
        } else {
            Complex::new(1.0, -fc / floor) * (f_hz / floor)
        }
    }
}

/// A unit's linear response fitted to its vibrating readings ([`ResponseBasis::fit`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LinearFit {
    /// The knots, Hz.
    pub knots_hz: Vec<f64>,
    /// The fitted response at each knot relative to the passport's `K1`: magnitude and
    /// phase (deg). 1 and 0 without a mount between the reference and the unit.
    pub gain: Vec<f64>,
    pub phase_deg: Vec<f64>,
    /// Readings the fit used.
    pub readings: usize,
}

/// The reference's body axes over one run's vibrating window, filtered by each knot's
/// hat (real and imaginary part) and averaged over each reading's interval: the columns
/// of [`ResponseBasis::fit`], computed once per run for all its units.
pub struct ResponseBasis {
    knots_hz: Vec<f64>,
    /// The readings (indices into the run's times) inside the window.
    rows: Vec<usize>,
    /// Per body axis, per knot, real then imaginary part: one value per row.
    columns: [Vec<Vec<f64>>; 3],
}

impl ResponseBasis {
    /// The basis over the readings at `times_s` whose intervals lie inside
    /// `window_s`. `None` when the reference does not cover one of them.
    pub fn new(
        inputs: &[IntervalMeans; 3],
        times_s: &[f64],
        window_s: [f64; 2],
        knots_hz: &[f64],
    ) -> Option<Self> {
        Self::with_inputs(inputs, times_s, window_s, knots_hz, &BasisInputs::default())
    }

    /// [`Self::new`] for inputs of another kind ([`BasisInputs`]): AC-coupled vibration
    /// sensors instead of a DC-coupled reference.
    pub fn with_inputs(
        inputs: &[IntervalMeans; 3],
        times_s: &[f64],
        window_s: [f64; 2],
        knots_hz: &[f64],
        kind: &BasisInputs,
    ) -> Option<Self> {
        let interval_s = inputs[0].interval_s;
        let rows: Vec<usize> = (0..times_s.len())
            .filter(|&i| {
                times_s[i] - interval_s >= window_s[0] - 1e-9 && times_s[i] <= window_s[1] + 1e-9
            })
            .collect();
        let times: Vec<f64> = rows.iter().map(|&i| times_s[i]).collect();
        let mut columns: [Vec<Vec<f64>>; 3] = Default::default();
        for (axis, input) in inputs.iter().enumerate() {
            for k in 0..knots_hz.len() {
                for part in [Complex::new(1.0, 0.0), Complex::new(0.0, 1.0)] {
                    let y = input.filtered(
                        |f| part * hat(knots_hz, k, f) * kind.undo_coupling(f),
                        false,
                        &times,
                    );
                    columns[axis].push(y.into_iter().collect::<Option<Vec<f64>>>()?);
                }
            }
        }
        Some(Self {
            knots_hz: knots_hz.to_vec(),
            rows,
            columns,
        })
    }

    /// The unit's linear response to the table's motion, fitted: the readings `u_v` of
    /// the window regressed on the reference's interval means filtered by a response
    /// that is piecewise linear in frequency (real and imaginary part at each knot, 0 at
    /// 0 Hz) plus a constant; `weights_v_per_g` is the passport's linear response per
    /// body axis (`K1 k1` on the IA's axis with its sign, `K1 m1`, `K1 m2` on the OA's
    /// and PA's). This is the passport's linear response when the unit sits on the table
    /// itself, and the unit's own when a mount between them filters the motion (a
    /// resonance between base and unit); the rectified part, even in the vibration, is
    /// not correlated with it. Returns the fitted response at every reading (NaN outside
    /// the window) and the fit; `None` when the window holds fewer readings than twice
    /// the unknowns or the least squares fail.
    pub fn fit(&self, weights_v_per_g: [f64; 3], u_v: &[f64]) -> Option<(Vec<f64>, LinearFit)> {
        let n_rows = self.rows.len();
        let unknowns = 2 * self.knots_hz.len() + 1;
        if self.knots_hz.is_empty() || n_rows < 2 * unknowns {
            return None;
        }
        let column = |c: usize, r: usize| -> f64 {
            if c == 0 {
                return 1.0;
            }
            (0..3)
                .map(|axis| weights_v_per_g[axis] * self.columns[axis][c - 1][r])
                .sum()
        };
        let b: Vec<f64> = self
            .rows
            .iter()
            .map(|&i| u_v.get(i).copied().unwrap_or(f64::NAN))
            .collect();
        if !b.iter().all(|v| v.is_finite()) {
            return None;
        }
        // The design, one column at a time (each a weighted sum of the axes' columns).
        let design: Vec<Vec<f64>> = (0..unknowns)
            .map(|c| (0..n_rows).map(|r| column(c, r)).collect())
            .collect();
        // Normal equations of the columns scaled to unit norm, solved by the SVD of the
        // small (unknowns x unknowns) matrix: a knot where the reference has no power
        // leaves its columns near zero, and the pseudo-inverse leaves its response at 0.
        let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
        let norms: Vec<f64> = design
            .iter()
            .map(|c| dot(c, c).sqrt().max(1e-300))
            .collect();
        let mut ata = nalgebra::DMatrix::<f64>::zeros(unknowns, unknowns);
        let mut atb = nalgebra::DVector::<f64>::zeros(unknowns);
        for i in 0..unknowns {
            atb[i] = dot(&design[i], &b) / norms[i];
            for j in 0..=i {
                let v = dot(&design[i], &design[j]) / (norms[i] * norms[j]);
                ata[(i, j)] = v;
                ata[(j, i)] = v;
            }
        }
        let svd = ata.svd(true, true);
        let theta = svd.solve(&atb, 1e-12 * svd.singular_values.max()).ok()?;
        let theta: Vec<f64> = (0..unknowns).map(|c| theta[c] / norms[c]).collect();
        let mut fitted = vec![f64::NAN; u_v.len()];
        for (r, &i) in self.rows.iter().enumerate() {
            if let Some(slot) = fitted.get_mut(i) {
                *slot = (1..unknowns).map(|c| theta[c] * design[c][r]).sum();
            }
        }
        let gain: Vec<Complex<f64>> = (0..self.knots_hz.len())
            .map(|k| Complex::new(theta[1 + 2 * k], theta[2 + 2 * k]))
            .collect();
        Some((
            fitted,
            LinearFit {
                knots_hz: self.knots_hz.clone(),
                gain: gain.iter().map(|g| g.norm()).collect(),
                phase_deg: gain.iter().map(|g| g.arg().to_degrees()).collect(),
                readings: n_rows,
            },
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The test signal: gravity, a drift, and tones switched on and off with raised-cosine
    /// ramps in the middle of the record (still at both ends, as a rig's run).
    fn signal(t: f64, tones: &[(f64, f64, f64)]) -> f64 {
        let ramp = |u: f64| 0.5 - 0.5 * (PI * u.clamp(0.0, 1.0)).cos();
        let w = ramp(t - 2.0) * ramp(9.0 - t);
        1.0 + 1e-3 * t
            + w * tones
                .iter()
                .map(|(a, f, p)| a * (2.0 * PI * f * t + p).sin())
                .sum::<f64>()
    }

    /// The mean of [`signal`] over `(t - T, t]` by 64-node Gauss-Legendre quadrature on
    /// each of 16 sub-intervals (independent of the FFT).
    fn quadrature_mean(t: f64, big_t: f64, tones: &[(f64, f64, f64)]) -> f64 {
        // 8-node Gauss-Legendre nodes and weights on [-1, 1].
        const X: [f64; 4] = [
            0.183_434_642_495_649_8,
            0.525_532_409_916_329,
            0.796_666_477_413_626_7,
            0.960_289_856_497_536_3,
        ];
        const W: [f64; 4] = [
            0.362_683_783_378_362,
            0.313_706_645_877_887_3,
            0.222_381_034_453_374_5,
            0.101_228_536_290_376_3,
        ];
        let parts = 64;
        let h = big_t / parts as f64;
        let mut sum = 0.0;
        for k in 0..parts {
            let mid = t - big_t + (k as f64 + 0.5) * h;
            for (x, w) in X.iter().zip(W) {
                sum += w * (signal(mid + x * h / 2.0, tones) + signal(mid - x * h / 2.0, tones));
            }
        }
        sum * h / 2.0 / big_t
    }

    #[test]
    fn interval_means_of_a_rig_record_match_quadrature() {
        // 6.4 kHz reference, 800 Hz readings (8 samples per reading), tones up to a
        // tenth of the sample rate, gravity, a drift, still at both ends.
        let (fs, fa, n) = (6400.0, 800.0, 70_400usize);
        let t_rec = n as f64 / fs;
        let tones = [(1.5, 40.0, 0.3), (0.7, 640.0, 2.0), (0.2, 133.3, -1.0)];
        let x: Vec<f64> = (0..n).map(|i| signal(i as f64 / fs, &tones)).collect();
        // Readings on the sample grid and off it (0.37 of a sample later).
        for offset in [0.0, 0.37 / fs] {
            let times: Vec<f64> = (1..(t_rec * fa) as usize - 1)
                .map(|j| j as f64 / fa + offset)
                .collect();
            let got = interval_means_at(&x, 0.0, fs, 1.0 / fa, &times);
            let mut worst: f64 = 0.0;
            for (t, g) in times.iter().zip(&got) {
                let want = quadrature_mean(*t, 1.0 / fa, &tones);
                worst = worst.max((g.expect("covered") - want).abs());
            }
            assert!(worst < 1e-9, "offset {offset}: worst {worst:e} g");
        }
        // Readings whose interval leaves the record have none.
        let edge = interval_means_at(&x, 0.0, fs, 1.0 / fa, &[0.5 / fa, t_rec + 1.0]);
        assert_eq!(edge, vec![None, None]);
    }
}
