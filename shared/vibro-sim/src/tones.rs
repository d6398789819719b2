//! Deterministic vibration: tones `aB_i sin(theta(t) + phi_i)` per axis (MODEL.md
//! section 3), with an optional linear frequency sweep.
//!
//! The phase is the integral of the frequency, evaluated in closed form per sample
//! (`theta(t) = theta0 + 2 pi (f0 t + 0.5 (f1 - f0) t^2 / T)` during a sweep of length
//! `T`, then `f1` onwards), so it is continuous under sweeps and does not drift with
//! the number of samples or the chunking. The common start phase `theta0` is drawn
//! from the run's tone-phase stream: the exact model averages every tone over a
//! uniform phase (MODEL.md section 6), and the per-axis phases `phi_i` stay as given.

use crate::streams::{rng, Source};
use rand::Rng;
use std::f64::consts::TAU;
use vibro_physics::vibration::Tone;

/// A frequency sweep of one tone: linear from the tone's frequency to `to_hz` over
/// `duration_s`, then constant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sweep {
    pub to_hz: f64,
    pub duration_s: f64,
}

#[derive(Debug, Clone)]
struct Oscillator {
    amplitude_g: [f64; 3],
    cos_phi: [f64; 3],
    sin_phi: [f64; 3],
    f0_hz: f64,
    /// `(f1 - f0)/T`, Hz/s; 0 without a sweep.
    chirp_hz_per_s: f64,
    sweep_end_s: f64,
    f1_hz: f64,
    /// Start phase, cycles.
    theta0_cycles: f64,
}

impl Oscillator {
    /// Phase in cycles at `t_s`.
    #[inline]
    fn cycles(&self, t_s: f64) -> f64 {
        if self.chirp_hz_per_s == 0.0 {
            self.theta0_cycles + self.f0_hz * t_s
        } else if t_s <= self.sweep_end_s {
            self.theta0_cycles + t_s * (self.f0_hz + 0.5 * self.chirp_hz_per_s * t_s)
        } else {
            let t = self.sweep_end_s;
            self.theta0_cycles
                + t * (self.f0_hz + 0.5 * self.chirp_hz_per_s * t)
                + self.f1_hz * (t_s - t)
        }
    }
}

/// The tones of a run.
#[derive(Debug, Clone, Default)]
pub(crate) struct ToneBank {
    tones: Vec<Oscillator>,
}

impl ToneBank {
    /// `tones[k]` sweeps as `sweeps[k]` (when given); start phases come from the
    /// tone-phase stream of run `(seed, base)`, one draw per tone in order.
    pub(crate) fn new(tones: &[Tone], sweeps: &[Option<Sweep>], seed: u64, base: u64) -> Self {
        let mut r = rng(seed, base, Source::TonePhase);
        let tones = tones
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let theta0_cycles = r.random::<f64>();
                let sweep = sweeps.get(k).copied().flatten();
                let (chirp, end, f1) = match sweep {
                    Some(s) if s.duration_s > 0.0 => {
                        ((s.to_hz - t.freq_hz) / s.duration_s, s.duration_s, s.to_hz)
                    }
                    _ => (0.0, 0.0, t.freq_hz),
                };
                Oscillator {
                    amplitude_g: t.amplitude_g,
                    cos_phi: t.phase_rad.map(f64::cos),
                    sin_phi: t.phase_rad.map(f64::sin),
                    f0_hz: t.freq_hz,
                    chirp_hz_per_s: chirp,
                    sweep_end_s: end,
                    f1_hz: f1,
                    theta0_cycles,
                }
            })
            .collect();
        Self { tones }
    }

    /// Adds the tones to `dst`, whose first sample is sample `first` at `fs_hz`.
    pub(crate) fn add(&self, first: u64, fs_hz: f64, dst: &mut [[f64; 3]]) {
        for osc in &self.tones {
            for (k, d) in dst.iter_mut().enumerate() {
                let t_s = (first + k as u64) as f64 / fs_hz;
                let (s, c) = (TAU * osc.cycles(t_s).fract()).sin_cos();
                for i in 0..3 {
                    // sin(theta + phi) = sin(theta) cos(phi) + cos(theta) sin(phi).
                    d[i] += osc.amplitude_g[i] * (s * osc.cos_phi[i] + c * osc.sin_phi[i]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_is_phase_continuous_and_reaches_its_end_frequency() {
        let tone = Tone {
            freq_hz: 8.0,
            amplitude_g: [1.0, 0.0, 0.0],
            phase_rad: [0.0; 3],
        };
        let bank = ToneBank::new(
            &[tone],
            &[Some(Sweep {
                to_hz: 16.0,
                duration_s: 10.0,
            })],
            1,
            0,
        );
        let osc = &bank.tones[0];
        // Instantaneous frequency by central differences of the phase.
        let f_at = |t: f64| (osc.cycles(t + 1e-4) - osc.cycles(t - 1e-4)) / 2e-4;
        assert!((f_at(0.5) - 8.4).abs() < 1e-6);
        assert!((f_at(10.0 - 1e-3) - 16.0).abs() < 1e-2);
        assert!((f_at(12.0) - 16.0).abs() < 1e-6);
        // Continuous across the end of the sweep.
        assert!((osc.cycles(10.0 + 1e-9) - osc.cycles(10.0 - 1e-9)).abs() < 1e-6);
        // The mean frequency of the sweep is 12 Hz: 120 cycles in 10 s.
        assert!((osc.cycles(10.0) - osc.cycles(0.0) - 120.0).abs() < 1e-9);
    }

    #[test]
    fn per_axis_phases_are_applied() {
        let tone = Tone {
            freq_hz: 1.0,
            amplitude_g: [1.0, 2.0, 0.5],
            phase_rad: [0.0, std::f64::consts::FRAC_PI_2, std::f64::consts::PI],
        };
        let bank = ToneBank::new(&[tone], &[], 5, 0);
        let mut v = vec![[0.0; 3]; 100];
        bank.add(0, 100.0, &mut v);
        let theta0 = TAU * bank.tones[0].theta0_cycles;
        for (k, s) in v.iter().enumerate() {
            let th = theta0 + TAU * k as f64 / 100.0;
            assert!((s[0] - th.sin()).abs() < 1e-12);
            assert!((s[1] - 2.0 * th.cos()).abs() < 1e-12);
            assert!((s[2] + 0.5 * th.sin()).abs() < 1e-12);
        }
    }
}
