//! Digital filters of the effects: second-order sections from analog prototypes by the
//! bilinear transform, and their exact discrete-time frequency response.
//!
//! The time-domain hooks run the difference equation; the mean formulas use
//! [`Biquad::response`] of the same coefficients, so both describe one filter and the
//! only gap between them is the sampling error of the simulation (no "analog vs
//! digital" mismatch near the Nyquist frequency).

use realfft::num_complex::Complex;
use std::f64::consts::PI;

/// Above this fraction of the sample rate the bilinear transform is not prewarped
/// (`tan` grows without bound at Nyquist); the filter is then the plain bilinear
/// image of the prototype, and the mean formulas still use its exact response.
const MAX_PREWARP_FRACTION: f64 = 0.4;

/// An analog prototype `H(s) = (n0 + n1 s + n2 s^2) / (d0 + d1 s + d2 s^2)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Analog {
    pub num: [f64; 3],
    pub den: [f64; 3],
}

impl Analog {
    /// Base-excitation transmissibility of a suspension with natural frequency
    /// `freq_hz` and quality factor `q` (damping ratio `zeta = 1/(2q)`):
    /// `T(s) = (wn^2 + 2 zeta wn s) / (s^2 + 2 zeta wn s + wn^2)`, the textbook
    /// transmissibility of a mass on a spring-damper whose base moves (single degree of
    /// freedom; Harris' Shock and Vibration Handbook, chapter on the transmission of
    /// vibration). `|T(j wn)| = sqrt(1 + q^2)`.
    pub fn transmissibility(freq_hz: f64, q: f64) -> Self {
        let wn = 2.0 * PI * freq_hz;
        let two_zeta_wn = wn / q;
        Self {
            num: [wn * wn, two_zeta_wn, 0.0],
            den: [wn * wn, two_zeta_wn, 1.0],
        }
    }

    /// Second-order low-pass `wn^2 / (s^2 + 2 zeta wn s + wn^2)`: the closed servo loop
    /// of a force-balance accelerometer.
    pub fn low_pass2(freq_hz: f64, damping_ratio: f64) -> Self {
        let wn = 2.0 * PI * freq_hz;
        Self {
            num: [wn * wn, 0.0, 0.0],
            den: [wn * wn, 2.0 * damping_ratio * wn, 1.0],
        }
    }

    /// First-order high-pass `s tau / (1 + s tau)`.
    pub fn high_pass1(tau_s: f64) -> Self {
        Self {
            num: [0.0, tau_s, 0.0],
            den: [1.0, tau_s, 0.0],
        }
    }

    /// First-order shelf with unit DC gain and high-frequency gain `g_hf`:
    /// `(1 + g_hf s/wc) / (1 + s/wc)`.
    pub fn shelf1(corner_hz: f64, g_hf: f64) -> Self {
        let tc = 1.0 / (2.0 * PI * corner_hz);
        Self {
            num: [1.0, g_hf * tc, 0.0],
            den: [1.0, tc, 0.0],
        }
    }
}

impl Analog {
    /// The continuous-time response `H(j 2 pi f)`.
    pub fn at(&self, freq_hz: f64) -> Complex<f64> {
        let s = Complex::new(0.0, 2.0 * PI * freq_hz);
        let poly = |c: &[f64; 3]| c[0] + s * (c[1] + s * c[2]);
        poly(&self.num) / poly(&self.den)
    }
}

/// A second-order section, `a0 = 1`:
/// `H(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
}

impl Biquad {
    /// Passes its input through unchanged (the state before `reset` gives a rate).
    pub const IDENTITY: Self = Self {
        b: [1.0, 0.0, 0.0],
        a: [0.0, 0.0],
    };

    /// The bilinear image `s = K (1 - z^-1)/(1 + z^-1)` of `analog` at `rate_hz`, with
    /// `K = w_w / tan(w_w T / 2)` prewarped at `prewarp_hz` so that the response there
    /// is the analog one (the bilinear transformation with prewarping, Oppenheim &
    /// Schafer, Discrete-Time Signal Processing, chapter on filter design). Invalid
    /// rates give the identity rather than NaNs.
    pub fn bilinear(analog: &Analog, rate_hz: f64, prewarp_hz: f64) -> Self {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Self::IDENTITY;
        }
        let k = if prewarp_hz.is_finite()
            && prewarp_hz > 0.0
            && prewarp_hz < MAX_PREWARP_FRACTION * rate_hz
        {
            let ww = 2.0 * PI * prewarp_hz;
            ww / (PI * prewarp_hz / rate_hz).tan()
        } else {
            2.0 * rate_hz
        };
        let map = |c: &[f64; 3]| {
            let k2 = k * k;
            [
                c[0] + c[1] * k + c[2] * k2,
                2.0 * c[0] - 2.0 * c[2] * k2,
                c[0] - c[1] * k + c[2] * k2,
            ]
        };
        let n = map(&analog.num);
        let d = map(&analog.den);
        if !(d[0].is_finite() && d[0] != 0.0) {
            return Self::IDENTITY;
        }
        Self {
            b: [n[0] / d[0], n[1] / d[0], n[2] / d[0]],
            a: [d[1] / d[0], d[2] / d[0]],
        }
    }

    /// The exact frequency response `H(e^{j 2 pi f / rate})`.
    pub fn response(&self, freq_hz: f64, rate_hz: f64) -> Complex<f64> {
        let w = 2.0 * PI * freq_hz / rate_hz;
        let z1 = Complex::from_polar(1.0, -w);
        let z2 = z1 * z1;
        let num = self.b[0] + z1 * self.b[1] + z2 * self.b[2];
        let den = 1.0 + z1 * self.a[0] + z2 * self.a[1];
        num / den
    }

    /// Gain at DC, `H(1)`.
    pub fn dc_gain(&self) -> f64 {
        (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1])
    }
}

/// The state of one [`Biquad`] (transposed direct form II).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct BiquadState {
    s: [f64; 2],
    primed: bool,
}

impl BiquadState {
    /// One output sample.
    #[inline]
    pub fn step(&mut self, f: &Biquad, x: f64) -> f64 {
        let y = f.b[0] * x + self.s[0];
        self.s[0] = f.b[1] * x - f.a[0] * y + self.s[1];
        self.s[1] = f.b[2] * x - f.a[1] * y;
        y
    }

    /// One output sample; on the first call after a reset the state is first set to
    /// the steady state of a constant input `x`. Filters on the total acceleration use
    /// this so that switching on at a nonzero flight acceleration is not a step.
    #[inline]
    pub fn step_primed(&mut self, f: &Biquad, x: f64) -> f64 {
        if !self.primed {
            let y = f.dc_gain() * x;
            self.s[1] = f.b[2] * x - f.a[1] * y;
            self.s[0] = f.b[1] * x - f.a[0] * y + self.s[1];
            self.primed = true;
        }
        self.step(f, x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The difference equation's steady state under a sinusoid is the response.
    #[test]
    fn steady_state_matches_the_response() {
        let rate = 2000.0;
        for (analog, prewarp) in [
            (Analog::transmissibility(48.0, 1.56), 48.0),
            (Analog::low_pass2(300.0, 0.4), 300.0),
            (Analog::high_pass1(2e-3), 0.0),
            (Analog::shelf1(60.0, 1.5), 60.0),
        ] {
            let f = Biquad::bilinear(&analog, rate, prewarp);
            let freq = 37.0;
            let mut st = BiquadState::default();
            let n = 40_000;
            let (mut c, mut s) = (0.0, 0.0);
            for i in 0..n {
                let t = i as f64 / rate;
                let y = st.step(&f, (2.0 * PI * freq * t).sin());
                if i >= n / 2 {
                    // y = |H| sin(w t + arg H): project on sin and cos.
                    c += y * (2.0 * PI * freq * t).sin();
                    s += y * (2.0 * PI * freq * t).cos();
                }
            }
            let h = Complex::new(c, s) * (4.0 / n as f64);
            let want = f.response(freq, rate);
            assert!((h - want).norm() < 1e-3, "{analog:?}: {h} vs {want}");
        }
    }

    #[test]
    fn prewarped_resonance_sits_at_its_frequency() {
        let f = Biquad::bilinear(&Analog::transmissibility(48.0, 1.56), 1000.0, 48.0);
        let want = (1.0f64 + 1.56 * 1.56).sqrt();
        assert!((f.response(48.0, 1000.0).norm() - want).abs() < 1e-12);
        assert!((f.dc_gain() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn priming_starts_in_the_dc_steady_state() {
        let f = Biquad::bilinear(&Analog::shelf1(60.0, 1.5), 1000.0, 60.0);
        let mut st = BiquadState::default();
        for _ in 0..5 {
            assert!((st.step_primed(&f, 3.0) - 3.0).abs() < 1e-12);
        }
        let hp = Biquad::bilinear(&Analog::high_pass1(1e-2), 1000.0, 0.0);
        let mut st = BiquadState::default();
        assert!(st.step_primed(&hp, 5.0).abs() < 1e-12);
    }
}
