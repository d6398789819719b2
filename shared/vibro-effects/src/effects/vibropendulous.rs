//! `vibropendulous`: the servo lag lets the pendulum deflect under IA vibration, and
//! the deflected pendulum senses PA acceleration (MODEL.md section 11, fourth item).
//!
//! Physics: a force-balance loop nulls the pendulum angle at DC but lags at vibration
//! frequencies, so the pendulum swings by `theta(t) = c * HP[a3](t)` with
//! `HP(s) = s tau / (1 + s tau)` (servo-loop time constant `tau_s`, zero at DC). A
//! pendulum turned by `theta` about OA tilts the sensitive axis towards PA and adds
//! `sin(theta) a2 ~ theta a2` to the output. Sign convention: positive `c_rad_per_g`
//! turns the pendulum so that positive PA acceleration adds positive output, i.e.
//! `out += theta(t) * a2(t)` with `a2` the total PA acceleration. This is the
//! vibropendulous error of pendulous accelerometers (the dynamic counterpart of the
//! IA x PA cross-coupling of the model equation in IEEE Std 1293, section 8.3), here
//! with the servo lag that makes it depend on frequency and on the IA-PA phase.
//! Hook: [`Effect::at_unit_output`], with `HP` a first-order section (bilinear
//! transform) on the total IA acceleration, started in its DC steady state.
//!
//! Mean contribution (zero at DC, depends on frequency and phase):
//! - tones: `sum 0.5 c aB3 aB2 Re(HP(j w) e^{j(phi3 - phi2)})`: `HP(a3)` is
//!   `|HP| aB3 sin(w t + phi3 + arg HP)`, whose product with `aB2 sin(w t + phi2)`
//!   averages to `0.5 |HP| aB3 aB2 cos(phi3 + arg HP - phi2)`;
//! - random: `c int Re(HP(j 2 pi f)) S_32(f) df` with the simulator's real
//!   cross-spectrum `S_32 = cov_32 sqrt(S_3 S_2) / int sqrt(S_3 S_2) df` (Bendat &
//!   Piersol, cross-spectrum of a filtered input with another), by quadrature over the
//!   bands. `HP` is the exact discrete-time response at the internal rate.

use super::filter::{Analog, Biquad, BiquadState};
use super::spectral::{band_integral, check_rate, cross_weight, no_spectrum, Panels};
use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext, OutputTerms};
use crate::Result;
use realfft::num_complex::Complex;
use std::f64::consts::PI;

const KIND: &str = "vibropendulous";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "servo lag lets the pendulum swing with high-passed IA vibration and sense PA: \
              out += c HP[a3] a2",
    params: &[
        ParamInfo {
            name: "c_rad_per_g",
            unit: "rad/g",
            meaning: "pendulum angle per g of high-passed IA acceleration; positive turns IA \
                      towards +PA; required, |c| <= 0.1",
        },
        ParamInfo {
            name: "tau_s",
            unit: "s",
            meaning: "servo-loop time constant of the high-pass s tau/(1 + s tau); required, \
                      0 < tau <= 10",
        },
    ],
    hooks: "at_unit_output",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "vibropendulous"
c_rad_per_g = 2.0e-4
tau_s = 0.002
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let c_rad_per_g = p.required("c_rad_per_g", "must be finite and |c| <= 0.1 rad/g", |c| {
        c.abs() <= 0.1
    });
    let tau_s = p.required("tau_s", "must be finite and 0 < tau_s <= 10 s", |t| {
        t > 0.0 && t <= 10.0
    });
    Ok(Box::new(Vibropendulous {
        c_rad_per_g,
        analog: Analog::high_pass1(tau_s),
        tau_s,
        filter: Biquad::IDENTITY,
        state: Default::default(),
    }))
}

#[derive(Debug, Clone)]
struct Vibropendulous {
    c_rad_per_g: f64,
    tau_s: f64,
    analog: Analog,
    filter: Biquad,
    /// Per unit.
    state: [BiquadState; 3],
}

impl Vibropendulous {
    /// `int Re HP S_3j df / int S_3j df` over the context's bands (the cross-spectral
    /// weight of IA and axis `j`), None without a spectrum there.
    fn band_mean_re_hp(&self, ctx: &MeanContext<'_>, hp: &Biquad, j: usize) -> Option<f64> {
        let rate = ctx.internal_rate_hz;
        // Panels a quarter of the corner frequency wide resolve Re HP's transition; a
        // first-order response's pole is at `i f_c`, so above the corner the panels
        // may grow with the frequency.
        let panels = Panels::Graded {
            centre_hz: 0.0,
            finest_hz: (0.25 / (2.0 * PI * self.tau_s)).max(1e-3),
        };
        let (num, den) = band_integral(
            ctx.psd_unit,
            |b| cross_weight(b, 2, j),
            |f| hp.response(f, rate).re,
            panels,
        );
        (!den.is_nan() && den > 0.0).then(|| num / den)
    }

    fn high_pass(&self, rate_hz: f64) -> Biquad {
        // Plain bilinear: the corner 1/(2 pi tau) may lie above Nyquist for a fast loop.
        Biquad::bilinear(&self.analog, rate_hz, 0.0)
    }
}

impl Effect for Vibropendulous {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn reset(&mut self, internal_rate_hz: f64) {
        self.filter = self.high_pass(internal_rate_hz);
        self.state = Default::default();
    }

    fn at_unit_output(&mut self, ctx: &BlockCtx, input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        let Some(state) = self.state.get_mut(ctx.unit) else {
            return;
        };
        for (a, o) in input_unit_g.iter().zip(out_g.iter_mut()) {
            let theta_rad = self.c_rad_per_g * state.step_primed(&self.filter, a[2]);
            *o += theta_rad * a[1];
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let rate = ctx.internal_rate_hz;
        check_rate(KIND, rate)?;
        let hp = self.high_pass(rate);
        let vib = ctx.vibration_unit;
        let mut sum = 0.0;
        for t in vib.tones() {
            let rot = Complex::from_polar(1.0, t.phase_rad[2] - t.phase_rad[1]);
            sum +=
                0.5 * t.amplitude_g[2] * t.amplitude_g[1] * (hp.response(t.freq_hz, rate) * rot).re;
        }
        let cov32 = vib.covariance_g2[2][1];
        if cov32 != 0.0 {
            let Some(mean_re) = self.band_mean_re_hp(ctx, &hp, 1) else {
                return Err(no_spectrum(KIND, format!("cov32 = {cov32} g^2")));
            };
            sum += cov32 * mean_re;
        }
        Ok(self.c_rad_per_g * sum)
    }

    /// `c HP[a3] a2` for a clip: per tone `c HP(f)`, and for the random part the
    /// regression of `c HP[x3]` on `x3`, `c int Re HP S33 df / int S33 df` (None when
    /// the rate or the spectrum the mean formula needs is missing).
    fn output_terms(&self, ctx: &MeanContext<'_>) -> Option<OutputTerms> {
        let rate = ctx.internal_rate_hz;
        check_rate(KIND, rate).ok()?;
        let hp = self.high_pass(rate);
        let vib = ctx.vibration_unit;
        let mut terms = OutputTerms::default();
        for (g, t) in terms.ia_filter_tone_gain.iter_mut().zip(vib.tones()) {
            let h = hp.response(t.freq_hz, rate) * self.c_rad_per_g;
            *g = (h.re, h.im);
        }
        if vib.covariance_g2[2][2] > 0.0 {
            terms.ia_filter_random_gain = self.c_rad_per_g * self.band_mean_re_hp(ctx, &hp, 2)?;
        }
        Some(terms)
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{al15, assert_agrees, band, build_toml, tone, unit_shift, Scene};

    /// Tones around the loop's corner (80 Hz) with IA-PA phases, and band noise with
    /// IA-PA coherence 0.6; c exaggerated to 1 mrad/g.
    #[test]
    fn mean_formula_matches_time_domain() {
        let p = al15();
        let mut s = Scene::new(2048.0, 1 << 14);
        s.pre_roll = 512;
        s.a_l_g = [0.0, 0.7, 1.5];
        s.tones = vec![
            tone(51.7, [0.0, 1.5, 2.0], [0.0, -40.0, 0.0]),
            tone(143.3, [0.3, 0.6, 1.0], [0.0, 0.0, 75.0]),
        ];
        s.bands = vec![
            band(20.0, 80.0, [0.01, 0.01, 0.01]),
            band(80.0, 300.0, [0.005, 0.005, 0.02]),
        ];
        s.coherence = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.6], [0.0, 0.6, 1.0]];
        let mut e = build_toml(
            "kind = \"vibropendulous\"\nc_rad_per_g = 1e-3\ntau_s = 0.002",
            &p,
        );
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(0, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 0, e.as_mut(), 500);
        assert_agrees("vibropendulous", est, formula, 10.0);
        // The random part alone, checking the cross-spectral quadrature on its own.
        s.tones.clear();
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(0, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 0, e.as_mut(), 600);
        assert_agrees("vibropendulous (random only)", est, formula, 10.0);
    }

    #[test]
    fn zero_for_static_acceleration() {
        let p = al15();
        let s = Scene::new(1000.0, 4096);
        let e = build_toml(
            "kind = \"vibropendulous\"\nc_rad_per_g = 1e-3\ntau_s = 0.01",
            &p,
        );
        let vib = s.vibration();
        assert_eq!(e.mean_shift_g(&s.ctx(0, &p, &vib)).unwrap(), 0.0);
    }
}
