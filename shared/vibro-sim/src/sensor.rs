//! The vibration sensor next to each accelerometer (RIG.md: a piezoelectric
//! accelerometer through a charge converter and an ADC), sample by sample at the
//! sensor rate:
//!
//! ```text
//! a (g) --x sensitivity--> V --AC coupling--> + white noise --> ADC (bits, full scale) --> V
//! ```
//!
//! **AC coupling.** The first-order high-pass `H(s) = s/(s + wc)` of an RC coupling
//! (the model `vibro_dsp` divides out), realised by the bilinear transform with the
//! corner pre-warped, so the digital corner is exactly `fc`:
//!
//! ```text
//! t = tan(pi fc / fs),  y[n] = (x[n] - x[n-1])/(1 + t) + (1 - t)/(1 + t) * y[n-1]
//! H(f) = j u / (1 + j u),  u = tan(pi f / fs) / tan(pi fc / fs)
//! ```
//!
//! ([`ac_coupling_response`]). It equals the analog `j (f/fc) / (1 + j f/fc)` up to the
//! frequency warping `tan(pi f/fs) ~ pi f/fs (1 + (pi f/fs)^2/3)`, whose effect on `H`
//! vanishes far above the corner: below 1e-6 in gain at 20 Hz with a 0.5 Hz corner at
//! 25.6 kHz. `ac_corner_hz = 0` is a DC-coupled sensor. The coupling starts as if its
//! first input had been there before the run (`x[-1] = y[-1] = x[0]`): a vibration
//! that is stationary from the start (a flight) then has no switch-on transient, while
//! one switched on later (a campaign's vibrating record) has the real one.
//!
//! **Noise** is white Gaussian, `noise_g_rms` referred to the input (times the
//! sensitivity in volts), added after the coupling, from the sensor's own stream.
//!
//! **ADC.** Step `q = full_scale_v / 2^(bits-1)`; codes `-2^(bits-1) .. 2^(bits-1) - 1`,
//! round to nearest (ties to even); a sample beyond the codes is clipped to the end
//! code and counted. The output is the code times `q`, in volts.

use crate::scenario::SensorSpec;
use crate::streams::{rng, Source};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{FRAC_PI_2, PI};

/// `1.5 * 2^52`: adding and subtracting it rounds to the nearest integer (ties to even)
/// in hardware for `|x| < 2^51` (`f64::round` is a library call on baseline x86-64).
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

/// Gain and phase (rad, output leading input) of the digital AC coupling at `f_hz`
/// (module docs); `(1, 0)` when `corner_hz = 0` (DC-coupled).
pub fn ac_coupling_response(f_hz: f64, corner_hz: f64, fs_hz: f64) -> (f64, f64) {
    if corner_hz <= 0.0 {
        return (1.0, 0.0);
    }
    let u = (PI * f_hz / fs_hz).tan() / (PI * corner_hz / fs_hz).tan();
    (u / (1.0 + u * u).sqrt(), FRAC_PI_2 - u.atan())
}

/// One vibration-sensor channel (module docs). Holds its filter state, its noise
/// stream and the clipping count; no allocation.
#[derive(Debug, Clone)]
pub struct SensorChain {
    sensitivity_v_per_g: f64,
    /// High-pass coefficients `y = b (x - x1) + a y1`; `None` when DC-coupled.
    high_pass: Option<(f64, f64)>,
    x_prev_v: f64,
    y_prev_v: f64,
    primed: bool,
    noise_v_rms: f64,
    step_v: f64,
    inv_step_per_v: f64,
    code_min: f64,
    code_max: f64,
    clipped: u64,
    noise: ChaCha8Rng,
}

impl SensorChain {
    /// The channel of unit `unit` in run `(seed, base)` at `sensor_hz`.
    pub fn new(spec: &SensorSpec, sensor_hz: f64, seed: u64, base: u64, unit: usize) -> Self {
        let high_pass = (spec.ac_corner_hz > 0.0).then(|| {
            let t = (PI * spec.ac_corner_hz / sensor_hz).tan();
            (1.0 / (1.0 + t), (1.0 - t) / (1.0 + t))
        });
        let half_codes = 2f64.powi(spec.adc_bits as i32 - 1);
        let step_v = spec.full_scale_v / half_codes;
        Self {
            sensitivity_v_per_g: spec.sensitivity_v_per_g,
            high_pass,
            x_prev_v: 0.0,
            y_prev_v: 0.0,
            primed: false,
            noise_v_rms: spec.noise_g_rms * spec.sensitivity_v_per_g.abs(),
            step_v,
            inv_step_per_v: 1.0 / step_v,
            code_min: -half_codes,
            code_max: half_codes - 1.0,
            clipped: 0,
            noise: rng(seed, base, Source::SensorNoise(unit)),
        }
    }

    /// The ADC step `q = full_scale_v / 2^(bits-1)`, V.
    pub fn step_v(&self) -> f64 {
        self.step_v
    }

    /// Samples clipped by the ADC so far.
    pub fn clipped_samples(&self) -> u64 {
        self.clipped
    }

    /// One sample: the acceleration along the sensor's axis, g, to the ADC output, V.
    #[inline]
    pub fn process(&mut self, accel_g: f64) -> f64 {
        let x = accel_g * self.sensitivity_v_per_g;
        if !self.primed {
            self.x_prev_v = x;
            self.y_prev_v = x;
            self.primed = true;
        }
        let coupled = match self.high_pass {
            Some((b, a)) => {
                let y = b * (x - self.x_prev_v) + a * self.y_prev_v;
                self.x_prev_v = x;
                self.y_prev_v = y;
                y
            }
            None => x,
        };
        let noisy = if self.noise_v_rms > 0.0 {
            coupled + self.noise_v_rms * self.noise.sample::<f64, _>(StandardNormal)
        } else {
            coupled
        };
        let mut code = noisy * self.inv_step_per_v;
        if !(code > self.code_min - 0.5 && code < self.code_max + 0.5) {
            // Beyond the end codes (or not a number): clip and count.
            self.clipped += 1;
            code = if code > 0.0 {
                self.code_max
            } else {
                self.code_min
            };
        }
        ((code + ROUND_MAGIC) - ROUND_MAGIC) * self.step_v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_approaches_the_analog_high_pass_far_from_nyquist() {
        let (g, p) = ac_coupling_response(0.5, 0.5, 25_600.0);
        assert!((g - 0.5f64.sqrt()).abs() < 1e-15, "corner exactly at fc");
        assert!((p - std::f64::consts::FRAC_PI_4).abs() < 1e-15);
        let (g, _) = ac_coupling_response(20.0, 0.5, 25_600.0);
        let analog = 40.0 / (1.0f64 + 1600.0).sqrt();
        assert!((g - analog).abs() < 1e-6);
    }

    #[test]
    fn rounding_trick_rounds_to_nearest() {
        for (x, want) in [(2.4, 2.0), (2.6, 3.0), (-2.6, -3.0), (2.5, 2.0), (3.5, 4.0)] {
            assert_eq!((x + ROUND_MAGIC) - ROUND_MAGIC, want, "{x}");
        }
    }
}
