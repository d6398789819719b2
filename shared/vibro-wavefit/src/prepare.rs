//! A log's run made ready for fitting: the sensors' samples on a fine grid aligned with
//! the readings' intervals, their chain undone in the frequency domain, and each
//! reading with its reference and whether it is used.
//!
//! The grid: `M` points per reading interval (`M = ceil(max(sensor rate, 25.6 kHz) /
//! reading rate)`), point `i` at `t_i = t_latch(0) - P + i P / M`, so that reading `j`'s
//! interval `(t_j - P, t_j]` runs from point `j M` to point `(j + 1) M`. The samples are
//! interpolated there band-limited (the compensator's Kaiser-windowed sinc,
//! `vibro_waveform::kernel`), at the stamps `t_i + delay0` (a sample stamped `s` saw
//! the base at `s - delay`). The record of `J` readings is then one period of `N = J M`
//! points for the FFT. Each stretch the samples cover is tapered to 0 over `taper_s`
//! at its ends (raised cosine): a flight's record does not end where it began, and the
//! wrap's step, through the AC coupling's inverse (an integrator below the corner),
//! would spread over a second on each side. Readings within `guard_s` of the record's
//! ends or of a gap (the taper, the high-pass's settling, a path filter's ringing, the
//! interpolation's half-width) are left out.
//!
//! The chain is undone per bin: the sensitivity divided out and the AC coupling's
//! analog high-pass `s / (s + wc)` inverted exactly (a real sensor's coupling is an RC
//! network, not the bilinear filter of the compensator's `ChainInverse`). Below the
//! corner the inverse would amplify the sensors' own noise without bound (a 2 Hz
//! corner, 24 s record: by 50 at the lowest bin), and what the base does there is the
//! rig's reference's to say: the sensors' band starts at `band_floor_factor` times the
//! corner, with a raised-cosine taper from the corner up to it (departure from an
//! ideal inverse, written down: content below twice the corner is not predicted from
//! the sensors).

use crate::{Error, Result};
use realfft::num_complex::Complex;
use realfft::RealFftPlanner;
use serde::Serialize;
use std::f64::consts::PI;
use vibro_physics::passport::Passport;
use vibro_physics::triad::TriadAxes;
use vibro_waveform::kernel::{Kernel, HALF_WIDTH};
use vibro_waveform::SensorChain;

/// A stretch of the sensors' samples at a constant rate.
#[derive(Debug, Clone)]
pub struct VibSegment {
    /// Stamp of the first sample, ns.
    pub t0_ns: u64,
    /// The sample period, s: from the stamps of the stretch's blocks, not a block's
    /// whole-ns period (25.6 kHz is 39062.5 ns: rounded, 0.15 ms off after 12 s).
    pub period_s: f64,
    /// Raw samples per sensor (sensor `i` along unit `i`'s IA), in the sensors' units (V).
    pub samples_v: Vec<[f64; 3]>,
}

/// One run (a log) as the fit needs it.
#[derive(Debug, Clone)]
pub struct RunInput {
    /// For messages and reports: the log's path.
    pub name: String,
    pub axes: TriadAxes,
    /// Per unit, flat (`lambda(w) = 1`).
    pub passports: [Passport; 3],
    /// The sensors' chain as stated; its `delay_s` is where the fit starts.
    pub chain: SensorChain,
    /// Whether `chain.delay_s` is stated (a rig file's); if not, a fit may move it.
    pub delay_stated: bool,
    /// The readings' period, ns.
    pub period_ns: u64,
    /// Latch time of reading 0, ns.
    pub first_latch_ns: u64,
    /// Per reading `k` (latched at `first_latch_ns + k period_ns`), each unit's output
    /// over its `K1`, g; NaN where the reading is missing.
    pub readings_g: Vec<[f64; 3]>,
    /// Per reading, the reference along each unit's IA, g; NaN where there is none.
    pub a_l_ia_g: Vec<[f64; 3]>,
    /// The sensors' samples, in time order.
    pub vib: Vec<VibSegment>,
}

/// How a run is prepared.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct PrepareOptions {
    /// The grid's rate is at least this and the sensors' rate, Hz.
    pub min_grid_rate_hz: f64,
    /// Readings this close to the record's ends or to a gap in the samples are left
    /// out, s.
    pub guard_s: f64,
    /// Each covered stretch is tapered to 0 over this at its ends, s.
    pub taper_s: f64,
    /// The sensors' band starts at this multiple of the AC corner.
    pub band_floor_factor: f64,
    /// Readings this close to the vibration's start or end (a used reading next to a
    /// quiet one) are left out, s: there the table's motion spreads below the sensors'
    /// AC corner (a random band's envelope reaches down to DC), which the sensors do not
    /// record and the DC-coupled units do (about 200 ug for 1 g RMS from 20 Hz with
    /// 0.1 s ramps, tests/python/rig_generator.py).
    pub transition_guard_s: f64,
    /// Most grid points of one run (its memory: about 80 bytes a point).
    pub max_grid_points: usize,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        Self {
            min_grid_rate_hz: 25_600.0,
            guard_s: 0.5,
            taper_s: 0.2,
            band_floor_factor: 2.0,
            transition_guard_s: 0.3,
            max_grid_points: 1 << 26,
        }
    }
}

/// What became of a run's readings.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct PrepareCounts {
    pub readings: usize,
    pub used: usize,
    pub missing: usize,
    pub no_reference: usize,
    /// Not covered by the samples with the interpolation's half-width and the guard.
    pub uncovered: usize,
    /// Used readings whose vibration is at the sensors' noise (the noise reference).
    pub quiet: usize,
    /// Left out next to the vibration's start or end.
    pub transition: usize,
}

/// A run ready for evaluation ([`crate::eval`]).
#[derive(Debug, Clone)]
pub struct PreparedRun {
    pub name: String,
    pub axes: TriadAxes,
    pub passports: [Passport; 3],
    /// Grid points per reading.
    pub m: usize,
    /// Readings (the record's period is `j` readings).
    pub j: usize,
    /// Grid points, `j m`.
    pub n: usize,
    /// The grid's spacing, s.
    pub dt_s: f64,
    pub period_s: f64,
    pub first_latch_ns: u64,
    pub readings_g: Vec<[f64; 3]>,
    /// Per reading, the reference in each unit's axes `[OA, PA, IA]`, g.
    pub a_l_unit_g: Vec<[[f64; 3]; 3]>,
    pub used: Vec<bool>,
    pub quiet: Vec<bool>,
    /// Per reading, its latch time from reading 0's, s.
    pub t_s: Vec<f64>,
    /// Per sensor, the spectrum (bins `0..=n/2`) of what it measured along its unit's
    /// IA, g, chain undone, at the stamps shifted by `delay0_s`.
    pub sensors: [Vec<Complex<f64>>; 3],
    pub delay0_s: f64,
    /// The delay is the run's own (stated): a fit's delay does not apply to it.
    pub delay_stated: bool,
    /// The last grid signals evaluated, by the path's key (`crate::eval`).
    pub(crate) signals_cache: crate::eval::SignalsCache,
    /// Where 1 % and 99 % of the sensors' power lie, Hz.
    pub band_hz: (f64, f64),
    /// The bins the linear response is predicted from, `0..lin_bins` ([`signal_bins`]).
    pub lin_bins: usize,
    /// Per sensor, its own noise per bin, `E|S_k|^2` (g^2, [`signal_bins`]); 0 where
    /// not measured.
    pub noise_per_bin_g2: [f64; 3],
    pub counts: PrepareCounts,
}

impl PreparedRun {
    /// The frequency of bin `k`, Hz.
    pub fn freq_hz(&self, k: usize) -> f64 {
        k as f64 / (self.n as f64 * self.dt_s)
    }
}

/// Interpolates, transforms and checks one run.
pub fn prepare(input: &RunInput, options: &PrepareOptions) -> Result<PreparedRun> {
    let name = &input.name;
    let bad = |reason: String| Error::Input {
        run: name.clone(),
        reason,
    };
    let problems = input.chain.problems();
    if !problems.is_empty() {
        let p: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
        return Err(bad(format!("the sensors' chain: {}", p.join("; "))));
    }
    if input.period_ns == 0 || input.readings_g.len() != input.a_l_ia_g.len() {
        return Err(bad(format!(
            "readings' period {} ns, {} readings and {} references: a period above 0 and a \
             reference per reading are needed",
            input.period_ns,
            input.readings_g.len(),
            input.a_l_ia_g.len()
        )));
    }
    let j = input.readings_g.len();
    if j < 16 {
        return Err(bad(format!("{j} readings: at least 16 are needed")));
    }
    let sensor_period_s = input
        .vib
        .iter()
        .map(|s| s.period_s)
        .filter(|&p| p > 0.0 && p.is_finite())
        .min_by(f64::total_cmp)
        .ok_or_else(|| bad("no vibration samples".into()))?;
    let period_s = input.period_ns as f64 * 1e-9;
    let sensor_rate_hz = 1.0 / sensor_period_s;
    if !input.chain.usable_at(sensor_rate_hz) {
        return Err(bad(format!(
            "an AC corner of {} Hz cannot be undone at {sensor_rate_hz} Hz",
            input.chain.ac_corner_hz
        )));
    }
    let rate = options.min_grid_rate_hz.max(sensor_rate_hz);
    let m = ((rate * period_s).ceil() as usize).max(2);
    let n = j * m;
    if n > options.max_grid_points {
        return Err(bad(format!(
            "{j} readings of {m} grid points each: more than {} grid points (split the log)",
            options.max_grid_points
        )));
    }
    let dt_s = period_s / m as f64;
    let delay0_s = input.chain.delay_s;
    // Grid point 0 at t_latch(0) - P; sample stamps relative to it, s.
    let base_ns = input.first_latch_ns as i128 - input.period_ns as i128;
    let kernel = Kernel::new();
    let mut grid: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; n]);
    let mut covered = vec![false; n];
    let w = HALF_WIDTH as i64;
    for seg in &input.vib {
        let len = seg.samples_v.len() as i64;
        if !(seg.period_s > 0.0 && seg.period_s.is_finite()) || len < 2 * w {
            continue;
        }
        let seg_t0_s = (seg.t0_ns as i128 - base_ns) as f64 * 1e-9;
        let seg_dt_s = seg.period_s;
        // Grid points whose stamps lie inside the segment with the kernel's half-width.
        let lo_s = seg_t0_s + (w - 1) as f64 * seg_dt_s - delay0_s;
        let hi_s = seg_t0_s + (len - 1 - w) as f64 * seg_dt_s - delay0_s;
        let i_lo = (lo_s / dt_s).ceil().max(0.0) as usize;
        let i_hi = ((hi_s / dt_s).floor() as i64).min(n as i64 - 1);
        if i_hi < i_lo as i64 {
            continue;
        }
        for i in i_lo..=i_hi as usize {
            let x = (i as f64 * dt_s + delay0_s - seg_t0_s) / seg_dt_s;
            let v = kernel.interpolate(x, |k| seg.samples_v[k.clamp(0, len - 1) as usize]);
            for s in 0..3 {
                grid[s][i] = v[s];
            }
            covered[i] = true;
        }
    }
    // Mean of the covered points out (the FFT's DC, and a gap's fill, at 0), and each
    // covered stretch tapered at its ends (module doc).
    for g in grid.iter_mut() {
        let (sum, cnt) = g
            .iter()
            .zip(&covered)
            .filter(|(_, &c)| c)
            .fold((0.0, 0usize), |(s, c), (x, _)| (s + x, c + 1));
        let mean = sum / cnt.max(1) as f64;
        for (x, &c) in g.iter_mut().zip(&covered) {
            *x = if c { *x - mean } else { 0.0 };
        }
    }
    let taper_n = ((options.taper_s / dt_s).round() as usize).max(1);
    let mut i = 0;
    while i < n {
        if !covered[i] {
            i += 1;
            continue;
        }
        let start = i;
        while i < n && covered[i] {
            i += 1;
        }
        let len = i - start;
        let t = taper_n.min(len / 2);
        for k in 0..t {
            let w = 0.5 - 0.5 * (PI * (k as f64 + 0.5) / t as f64).cos();
            for g in grid.iter_mut() {
                g[start + k] *= w;
                g[start + len - 1 - k] *= w;
            }
        }
    }
    let mut planner = RealFftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(n);
    let inv = planner.plan_fft_inverse(n);
    let df = 1.0 / (n as f64 * dt_s);
    let fc = input.chain.ac_corner_hz;
    let floor_hz = fc * options.band_floor_factor;
    let mut sensors: [Vec<Complex<f64>>; 3] = std::array::from_fn(|_| Vec::new());
    let mut scratch = fwd.make_scratch_vec();
    for s in 0..3 {
        let mut spec = fwd.make_output_vec();
        fwd.process_with_scratch(&mut grid[s], &mut spec, &mut scratch)
            .map_err(|e| bad(format!("FFT: {e}")))?;
        let inv_sens = 1.0 / input.chain.sensitivity_v_per_g[s];
        for (k, x) in spec.iter_mut().enumerate() {
            let f = k as f64 * df;
            *x *= inv_sens * inverse_coupling(f, fc, floor_hz);
        }
        sensors[s] = spec;
    }
    // The vibration's RMS per reading (body frame, from the undone spectra), for the
    // quiet readings and the band.
    let mut rms = vec![0.0; j];
    {
        let mut sq = vec![0.0; n];
        let mut scratch = inv.make_scratch_vec();
        for s in 0..3 {
            let mut spec = sensors[s].clone();
            spec[0].im = 0.0;
            if n % 2 == 0 {
                spec[n / 2].im = 0.0;
            }
            let mut out = inv.make_output_vec();
            inv.process_with_scratch(&mut spec, &mut out, &mut scratch)
                .map_err(|e| bad(format!("inverse FFT: {e}")))?;
            for (a, x) in sq.iter_mut().zip(&out) {
                let x = x / n as f64;
                *a += x * x;
            }
        }
        for (r, chunk) in rms.iter_mut().zip(sq.chunks(m)) {
            *r = (chunk.iter().sum::<f64>() / m as f64).sqrt();
        }
    }
    let band_hz = power_band(&sensors, df);
    let nyquist_bin = (0.5 * sensor_rate_hz / df).floor() as usize;
    let (lin_bins, noise_per_bin_g2) = signal_bins(&sensors, nyquist_bin);
    // Readings: reference, coverage with the guard.
    let guard = (options.guard_s / period_s).ceil() as usize;
    let mut counts = PrepareCounts {
        readings: j,
        ..Default::default()
    };
    // Per reading: is every grid point of its interval covered?
    let interval_covered: Vec<bool> = (0..j)
        .map(|r| {
            let end = ((r + 1) * m).min(n - 1);
            covered[r * m..=end].iter().all(|&c| c) && (r + 1) * m < n
        })
        .collect();
    // Distance (readings) to the nearest uncovered interval or the record's ends.
    let mut near_gap = vec![usize::MAX; j];
    let mut last = None;
    for r in 0..j {
        if !interval_covered[r] {
            last = Some(r);
        }
        near_gap[r] = last.map_or(r + 1, |l| r - l).min(r + 1);
    }
    let mut next = None;
    for r in (0..j).rev() {
        if !interval_covered[r] {
            next = Some(r);
        }
        near_gap[r] = near_gap[r].min(next.map_or(j - r, |nx| nx - r));
    }
    let mut used = vec![false; j];
    let mut a_l_unit_g = vec![[[f64::NAN; 3]; 3]; j];
    for r in 0..j {
        let reading = input.readings_g[r];
        let a_l = input.a_l_ia_g[r];
        if !reading.iter().all(|x| x.is_finite()) {
            counts.missing += 1;
            continue;
        }
        if !a_l.iter().all(|x| x.is_finite()) {
            counts.no_reference += 1;
            continue;
        }
        let body = input.axes.body_from_ia(&a_l);
        a_l_unit_g[r] = std::array::from_fn(|u| input.axes.units[u].to_unit(&body));
        if near_gap[r] <= guard {
            counts.uncovered += 1;
            continue;
        }
        used[r] = true;
        counts.used += 1;
    }
    // Fill the reference of unused readings from the nearest used one (the grid's
    // output hooks run through every point).
    let mut carry = a_l_unit_g.iter().find(|a| a[0][0].is_finite()).copied();
    for a in a_l_unit_g.iter_mut() {
        if a[0][0].is_finite() {
            carry = Some(*a);
        } else if let Some(c) = carry {
            *a = c;
        } else {
            *a = [[0.0; 3]; 3];
        }
    }
    let quiet = quiet_readings(&rms, &used);
    // Readings near a change between quiet and vibrating are left out.
    let g = (options.transition_guard_s / period_s).ceil() as usize;
    if g > 0 && quiet.iter().any(|&q| q) {
        let changes: Vec<usize> = (1..j)
            .filter(|&r| used[r] && used[r - 1] && quiet[r] != quiet[r - 1])
            .collect();
        for c in changes {
            for r in c.saturating_sub(g)..(c + g).min(j) {
                if used[r] {
                    used[r] = false;
                    counts.used -= 1;
                    counts.transition += 1;
                }
            }
        }
    }
    let quiet: Vec<bool> = quiet.iter().zip(&used).map(|(&q, &u)| q && u).collect();
    counts.quiet = quiet.iter().filter(|&&q| q).count();
    let t_s = (0..j).map(|r| r as f64 * period_s).collect();
    Ok(PreparedRun {
        name: name.clone(),
        axes: input.axes,
        passports: input.passports,
        m,
        j,
        n,
        dt_s,
        period_s,
        first_latch_ns: input.first_latch_ns,
        readings_g: input.readings_g.clone(),
        a_l_unit_g,
        used,
        quiet,
        t_s,
        sensors,
        delay0_s,
        delay_stated: input.delay_stated,
        signals_cache: Default::default(),
        band_hz,
        lin_bins,
        noise_per_bin_g2,
        counts,
    })
}

/// The bins that carry the vibration, and each sensor's noise per bin (`E|S_k|^2`, the
/// unnormalised spectrum's, g^2). The noise floor: the median over blocks of 64 bins
/// from half to 0.8 of the sensors' Nyquist frequency (below the interpolation kernel's
/// roll-off), when that part is flat within a factor 10; the bins: up to 1.25 times the
/// highest block whose power exceeds 3 times the floor. Above it the sensors record
/// their own noise only: a linear response predicted from there would put that noise
/// into every reading's prediction. All bins and no floor when the part is not flat (a
/// vibration that reaches the sensors' Nyquist frequency).
pub fn signal_bins(
    sensors: &[Vec<Complex<f64>>; 3],
    sensor_nyquist_bin: usize,
) -> (usize, [f64; 3]) {
    let nb = sensors[0].len();
    const B: usize = 64;
    let power = |s: &[Complex<f64>], b: usize| -> f64 {
        (b * B..(b + 1) * B).map(|k| s[k].norm_sqr()).sum::<f64>() / B as f64
    };
    let top = sensor_nyquist_bin.min(nb) / B;
    let blocks: Vec<f64> = (0..top)
        .map(|b| sensors.iter().map(|s| power(s, b)).sum())
        .collect();
    if blocks.len() < 16 {
        return (nb, [0.0; 3]);
    }
    let range = blocks.len() / 2..blocks.len() * 4 / 5;
    let mut upper: Vec<f64> = blocks[range.clone()].to_vec();
    upper.sort_by(f64::total_cmp);
    let floor = upper[upper.len() / 2];
    let (lo, hi) = (upper[upper.len() / 10], upper[upper.len() * 9 / 10]);
    if !(floor > 0.0 && hi < 10.0 * lo) {
        return (nb, [0.0; 3]);
    }
    let per_sensor: [f64; 3] = std::array::from_fn(|s| {
        let mut v: Vec<f64> = range.clone().map(|b| power(&sensors[s], b)).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    });
    let last = blocks.iter().rposition(|&p| p > 3.0 * floor).unwrap_or(0);
    let bins = (((last + 1) * B) as f64 * 1.25).ceil().min(nb as f64) as usize;
    (bins, per_sensor)
}

/// The inverse of the AC coupling `s / (s + wc)` at `f`, tapered to 0 from the corner
/// down (module doc); 1 for a DC-coupled sensor but at DC.
fn inverse_coupling(f_hz: f64, fc_hz: f64, floor_hz: f64) -> Complex<f64> {
    if f_hz <= 0.0 {
        return Complex::new(0.0, 0.0);
    }
    if fc_hz <= 0.0 {
        return Complex::new(1.0, 0.0);
    }
    let taper = if f_hz >= floor_hz {
        1.0
    } else if f_hz <= 0.5 * floor_hz {
        0.0
    } else {
        let x = (f_hz - 0.5 * floor_hz) / (0.5 * floor_hz);
        0.5 - 0.5 * (PI * x).cos()
    };
    // 1 / (j f / (j f + fc)) = 1 + fc / (j f) = 1 - j fc / f.
    Complex::new(taper, -taper * fc_hz / f_hz)
}

/// The frequencies below which 1 % and 99 % of the sensors' power lie.
fn power_band(sensors: &[Vec<Complex<f64>>; 3], df: f64) -> (f64, f64) {
    let nb = sensors[0].len();
    let p: Vec<f64> = (0..nb)
        .map(|k| sensors.iter().map(|s| s[k].norm_sqr()).sum())
        .collect();
    let total: f64 = p.iter().sum();
    if total <= 0.0 {
        return (0.0, 0.0);
    }
    let (mut acc, mut lo, mut hi) = (0.0, None, None);
    for (k, x) in p.iter().enumerate() {
        acc += x;
        if lo.is_none() && acc >= 0.01 * total {
            lo = Some(k as f64 * df);
        }
        if hi.is_none() && acc >= 0.99 * total {
            hi = Some(k as f64 * df);
        }
    }
    (lo.unwrap_or(0.0), hi.unwrap_or(nb as f64 * df))
}

/// Readings at the sensors' own noise: a used reading whose vibration RMS is below 3
/// times the run's 5th percentile, when its 95th percentile is more than 100 times the
/// 5th (a run that starts and ends still); none otherwise (vibrating throughout).
fn quiet_readings(rms: &[f64], used: &[bool]) -> Vec<bool> {
    let mut v: Vec<f64> = rms
        .iter()
        .zip(used)
        .filter(|(_, &u)| u)
        .map(|(r, _)| *r)
        .collect();
    if v.len() < 20 {
        return vec![false; rms.len()];
    }
    v.sort_by(f64::total_cmp);
    let p5 = v[v.len() / 20];
    let p95 = v[v.len() * 19 / 20];
    if p95.partial_cmp(&(100.0 * p5)) != Some(std::cmp::Ordering::Greater) {
        return vec![false; rms.len()];
    }
    // Near the floor: the ramps into and out of the vibration are not quiet.
    let threshold = (3.0 * p5).min((p5 * p95).sqrt());
    rms.iter()
        .zip(used)
        .map(|(r, &u)| u && *r < threshold)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The inverse undoes the analog high-pass exactly above the band's floor.
    #[test]
    fn the_coupling_is_undone_above_the_floor() {
        for f in [4.0, 20.0, 640.0] {
            let h = Complex::new(0.0, f) / Complex::new(2.0, f);
            let x = inverse_coupling(f, 2.0, 4.0) * h;
            assert!((x - Complex::new(1.0, 0.0)).norm() < 1e-14, "{f}: {x}");
        }
        assert_eq!(inverse_coupling(1.0, 2.0, 4.0), Complex::new(0.0, 0.0));
        assert_eq!(inverse_coupling(0.0, 0.0, 0.0), Complex::new(0.0, 0.0));
        assert_eq!(inverse_coupling(3.0, 0.0, 0.0), Complex::new(1.0, 0.0));
    }

    #[test]
    fn quiet_needs_a_still_part() {
        let mut rms = vec![1.0; 100];
        let used = vec![true; 100];
        assert!(quiet_readings(&rms, &used).iter().all(|q| !q));
        for r in rms.iter_mut().take(40) {
            *r = 1e-3;
        }
        let q = quiet_readings(&rms, &used);
        assert_eq!(q.iter().filter(|&&q| q).count(), 40);
    }
}
