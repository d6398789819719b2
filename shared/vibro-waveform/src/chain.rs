//! The vibration sensors' chain as a rig has it, and its inverse sample by sample.
//!
//! ```text
//! base acceleration (g) --x sensitivity--> V --AC coupling--> ADC --delay--> stamped sample
//! ```
//!
//! - **Sensitivity**, V/g per sensor (axis `i` = unit `i`'s IA): divided out.
//! - **AC coupling**, the first-order high-pass `H(s) = s / (s + wc)` of a piezoelectric
//!   sensor's charge converter (RIG.md), realised digitally by the bilinear transform
//!   pre-warped at the corner, as the simulator's sensor and the estimator model it:
//!   `y[n] = (x[n] - x[n-1]) / (1 + t) + (1 - t) / (1 + t) y[n-1]`, `t = tan(pi fc / fs)`.
//!   Its inverse, `x[n] = rho x[n-1] + (1 + t) y[n] - (1 - t) y[n-1]`, is an integrator:
//!   `rho = 1 - 2 pi (fc 1e-5) / fs` leaks it at 1e-5 of the corner, so that the
//!   sensors' noise and an unknown initial value cannot walk without bound. The leak
//!   changes the inverse at `f` by about `1e-5 fc / f` (1e-6 at 20 Hz with a 2 Hz corner). A
//!   constant left in `x` does not matter: the waveform stage uses the deviation of the
//!   vibration from its mean over each reading's interval (MODEL.md section 12).
//!   Against the analog high-pass of a real sensor, the bilinear inverse differs by the
//!   frequency warping, `(pi f / fs)^2 / 3` relative in `f / fc`, whose effect on `H`
//!   falls as `fc / f`: 1e-4 at 640 Hz with 6.4 kHz sensors and a 2 Hz corner.
//! - **Delay** `delay_s`: a sample stamped `s` saw the base at `s - delay_s` (a DAQ's
//!   anti-alias group delay, an ADC pipeline). Taken off the time stamps.

use std::f64::consts::PI;

/// The vibration sensors' chain, as the services' configuration and a rig file state it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorChain {
    /// V/g per sensor (axis `i` = unit `i`'s IA); nonzero and finite.
    pub sensitivity_v_per_g: [f64; 3],
    /// Corner of the first-order AC coupling, Hz; 0 for a DC-coupled sensor.
    pub ac_corner_hz: f64,
    /// The chain's delay, s: a sample stamped `s` saw the base at `s - delay_s`.
    pub delay_s: f64,
}

/// The longest delay a chain may state, s: a DAQ's filter delays by milliseconds; a
/// second is a unit mix-up (ms for s).
pub const MAX_DELAY_S: f64 = 1.0;

/// One broken rule of a [`SensorChain`]: the key, the value and the rule, for the caller
/// to prefix with the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key} = {value}: {rule}")]
pub struct ChainProblem {
    pub key: &'static str,
    pub value: String,
    pub rule: &'static str,
}

impl Default for SensorChain {
    /// The shipped estimator's sensors (config/services/estimator.toml): 0.1 V/g, a
    /// 0.5 Hz AC coupling, no delay.
    fn default() -> Self {
        Self {
            sensitivity_v_per_g: [0.1; 3],
            ac_corner_hz: 0.5,
            delay_s: 0.0,
        }
    }
}

impl SensorChain {
    /// Every broken rule at once (empty when the chain is usable).
    pub fn problems(&self) -> Vec<ChainProblem> {
        let mut out = Vec::new();
        for s in self.sensitivity_v_per_g {
            if !(s.is_finite() && s != 0.0 && s.abs() <= 1e6) {
                out.push(ChainProblem {
                    key: "sensitivity_v_per_g",
                    value: format!("{:?}", self.sensitivity_v_per_g),
                    rule: "each sensitivity must be finite, nonzero and at most 1e6 V/g in size",
                });
                break;
            }
        }
        if !(self.ac_corner_hz.is_finite() && self.ac_corner_hz >= 0.0 && self.ac_corner_hz <= 1e3)
        {
            out.push(ChainProblem {
                key: "ac_corner_hz",
                value: self.ac_corner_hz.to_string(),
                rule: "must be a finite corner from 0 (DC-coupled) to 1000 Hz",
            });
        }
        if !(self.delay_s.is_finite() && self.delay_s >= 0.0 && self.delay_s <= MAX_DELAY_S) {
            out.push(ChainProblem {
                key: "delay_s",
                value: self.delay_s.to_string(),
                rule: "must be from 0 to 1 s (a sample stamped s saw the base at s - delay_s)",
            });
        }
        out
    }

    /// Whether the chain's AC coupling can be inverted at `rate_hz`: its corner must lie
    /// well below the Nyquist frequency.
    pub fn usable_at(&self, rate_hz: f64) -> bool {
        rate_hz.is_finite() && rate_hz > 0.0 && self.ac_corner_hz < 0.05 * rate_hz
    }
}

/// The chain undone sample by sample, one state per sensor axis (module docs).
#[derive(Debug, Clone, Copy)]
pub struct ChainInverse {
    inv_sensitivity: [f64; 3],
    /// `(1 + t, 1 - t, rho)` of the inverse high-pass; `None` when DC-coupled.
    high_pass: Option<(f64, f64, f64)>,
    y_prev: [f64; 3],
    x_prev: [f64; 3],
    primed: bool,
}

impl ChainInverse {
    /// The inverse of `chain` for samples at `rate_hz` ([`SensorChain::usable_at`]).
    pub fn new(chain: &SensorChain, rate_hz: f64) -> Self {
        let high_pass = (chain.ac_corner_hz > 0.0).then(|| {
            let t = (PI * chain.ac_corner_hz / rate_hz).tan();
            let rho = 1.0 - 2.0 * PI * (chain.ac_corner_hz * 1e-5) / rate_hz;
            (1.0 + t, 1.0 - t, rho)
        });
        Self {
            inv_sensitivity: chain.sensitivity_v_per_g.map(|s| 1.0 / s),
            high_pass,
            y_prev: [0.0; 3],
            x_prev: [0.0; 3],
            primed: false,
        }
    }

    /// Starts again (after a break in the stream): the next sample primes the state.
    pub fn reset(&mut self) {
        self.primed = false;
    }

    /// One sample of the three sensors, V, to the base acceleration along each sensor's
    /// axis, g (up to a constant, module docs).
    #[inline]
    pub fn undo(&mut self, v: [f64; 3]) -> [f64; 3] {
        let y = [
            v[0] * self.inv_sensitivity[0],
            v[1] * self.inv_sensitivity[1],
            v[2] * self.inv_sensitivity[2],
        ];
        let Some((a, b, rho)) = self.high_pass else {
            return y;
        };
        if !self.primed {
            self.primed = true;
            self.y_prev = y;
            self.x_prev = y;
            return y;
        }
        let mut x = [0.0; 3];
        for i in 0..3 {
            x[i] = rho * self.x_prev[i] + a * y[i] - b * self.y_prev[i];
        }
        self.y_prev = y;
        self.x_prev = x;
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulator's digital AC coupling (vibro_sim::sensor), written out again.
    fn coupled(x: &[f64], fc: f64, fs: f64) -> Vec<f64> {
        let t = (PI * fc / fs).tan();
        let (b, a) = (1.0 / (1.0 + t), (1.0 - t) / (1.0 + t));
        let (mut xp, mut yp) = (x[0], x[0]);
        x.iter()
            .map(|&xi| {
                let y = b * (xi - xp) + a * yp;
                xp = xi;
                yp = y;
                y
            })
            .collect()
    }

    #[test]
    fn inverse_restores_a_tone_through_the_coupling() {
        let (fs, fc) = (6400.0, 2.0);
        let n = 64_000;
        let x: Vec<f64> = (0..n)
            .map(|k| 2.0 * (2.0 * PI * 20.0 * k as f64 / fs + 0.3).sin())
            .collect();
        let y = coupled(&x, fc, fs);
        let chain = SensorChain {
            sensitivity_v_per_g: [0.1; 3],
            ac_corner_hz: fc,
            delay_s: 0.0,
        };
        let mut inv = ChainInverse::new(&chain, fs);
        let back: Vec<f64> = y.iter().map(|&v| inv.undo([0.1 * v; 3])[0]).collect();
        // After the first second: the tone, up to a slowly varying constant (the
        // integrator's start, leaking away): deviations from each 8-sample interval's
        // mean, as the waveform stage uses them.
        let mut worst: f64 = 0.0;
        for (a, b) in back[6400..].chunks(8).zip(x[6400..].chunks(8)) {
            let ma = a.iter().sum::<f64>() / 8.0;
            let mb = b.iter().sum::<f64>() / 8.0;
            for (p, q) in a.iter().zip(b) {
                worst = worst.max(((p - ma) - (q - mb)).abs());
            }
        }
        assert!(worst < 2e-6, "worst {worst} g on a 2 g tone");
    }

    #[test]
    fn problems_name_key_value_and_rule() {
        let chain = SensorChain {
            sensitivity_v_per_g: [0.1, 0.0, 0.1],
            ac_corner_hz: -1.0,
            delay_s: 1.5,
        };
        let p = chain.problems();
        assert_eq!(p.len(), 3, "{p:?}");
        assert_eq!(p[2].key, "delay_s");
        assert_eq!(p[2].value, "1.5");
        assert!(SensorChain {
            delay_s: -0.001,
            ..SensorChain::default()
        }
        .problems()[0]
            .to_string()
            .contains("delay_s = -0.001: must be from 0 to 1 s"));
        assert!(SensorChain::default().problems().is_empty());
    }
}
