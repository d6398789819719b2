//! `unit_response`: the accelerometer's own frequency response on its input axis
//! (MODEL.md section 11, second item; RIG.md: "the accelerometer's own amplitude
//! response (about 1.0..1.3 up to 1.5 kHz)").
//!
//! Physics: a force-balance (servo) accelerometer responds to IA acceleration through
//! its closed servo loop, to first approximation a second-order low-pass
//! `H(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)` (natural frequency `natural_freq_hz`,
//! damping ratio `damping_ratio`; `zeta < 0.707` peaks at `1/(2 zeta sqrt(1 - zeta^2))`).
//! The whole conversion function then acts on the filtered IA acceleration, so the
//! rectification of MODEL.md sees `|H| aB3` with a phase `arg H` against OA and PA.
//! Applied in [`Effect::at_unit_input`] to the IA component, as a biquad (bilinear
//! transform prewarped at the natural frequency).
//!
//! Mean contribution: as `mount_resonance` with the filter on IA only: the exact mean
//! output (MODEL.md section 6) with tones `|H(f)| aB3`, `phi3 + arg H(f)` and the IA
//! variance (and IA covariances) through `H` band by band, minus the exact mean without.

use super::filter::{Analog, Biquad, BiquadState};
use super::spectral::{
    check_rate, exact_shift, filtered_psd, filtered_vibration, BandMemo, Panels, SeenCache,
};
use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext};
use crate::Result;
use realfft::num_complex::Complex;
use vibro_physics::vibration::{PsdBand, Vibration};

const KIND: &str = "unit_response";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "the accelerometer's servo-loop frequency response (2nd-order low-pass) on its \
              IA input",
    params: &[
        ParamInfo {
            name: "natural_freq_hz",
            unit: "Hz",
            meaning: "natural frequency of the servo loop; required, 0 < f <= 1e6",
        },
        ParamInfo {
            name: "damping_ratio",
            unit: "1",
            meaning: "damping ratio zeta of the servo loop; required, 0.01 <= zeta <= 10",
        },
    ],
    hooks: "at_unit_input",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "unit_response"
natural_freq_hz = 1800.0
damping_ratio = 0.45
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let natural_freq_hz = p.required(
        "natural_freq_hz",
        "must be finite and 0 < natural_freq_hz <= 1e6 Hz",
        |f| f > 0.0 && f <= 1e6,
    );
    let damping_ratio = p.required(
        "damping_ratio",
        "must be finite and 0.01 <= damping_ratio <= 10",
        |z| (0.01..=10.0).contains(&z),
    );
    Ok(Box::new(UnitResponse {
        natural_freq_hz,
        damping_ratio,
        analog: Analog::low_pass2(natural_freq_hz, damping_ratio),
        filter: Biquad::IDENTITY,
        state: Default::default(),
        seen: SeenCache::default(),
        bands: BandMemo::default(),
    }))
}

/// The servo loop's response on the IA acceleration.
#[derive(Debug, Clone)]
struct UnitResponse {
    natural_freq_hz: f64,
    damping_ratio: f64,
    analog: Analog,
    filter: Biquad,
    /// Per unit.
    state: [BiquadState; 3],
    /// What the filter last passed ([`SeenCache`]).
    seen: SeenCache,
    /// The filter's integrals over the bands seen so far ([`BandMemo`]).
    bands: BandMemo,
}

impl Effect for UnitResponse {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn reset(&mut self, internal_rate_hz: f64) {
        self.filter = Biquad::bilinear(&self.analog, internal_rate_hz, self.natural_freq_hz);
        self.state = Default::default();
    }

    fn at_unit_input(&mut self, ctx: &BlockCtx, vib_unit_g: &mut [[f64; 3]]) {
        let Some(state) = self.state.get_mut(ctx.unit) else {
            return;
        };
        for s in vib_unit_g.iter_mut() {
            s[2] = state.step(&self.filter, s[2]);
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let (seen, _) = self.seen(ctx)?;
        exact_shift(ctx, &seen)
    }

    fn on_vibration_path(&self) -> bool {
        true
    }

    fn path_transfer(&self, _unit: usize, f_hz: f64) -> Option<[Complex<f64>; 3]> {
        let one = Complex::new(1.0, 0.0);
        Some([one, one, self.analog.at(f_hz)])
    }

    fn transmitted(&self, ctx: &MeanContext<'_>) -> Option<Result<(Vibration, Vec<PsdBand>)>> {
        Some(self.seen(ctx))
    }
}

impl UnitResponse {
    /// The vibration and band PSD the pendulum follows (IA through the loop).
    fn seen(&self, ctx: &MeanContext<'_>) -> Result<(Vibration, Vec<PsdBand>)> {
        let rate = ctx.internal_rate_hz;
        self.seen
            .get_or(ctx.vibration_unit, ctx.psd_unit, rate, || {
                self.seen_now(ctx)
            })
    }

    fn seen_now(&self, ctx: &MeanContext<'_>) -> Result<(Vibration, Vec<PsdBand>)> {
        let rate = ctx.internal_rate_hz;
        check_rate(KIND, rate)?;
        let filter = Biquad::bilinear(&self.analog, rate, self.natural_freq_hz);
        // Panels far narrower than the peak's width (about 2 zeta f0) at the peak, wider
        // away from it.
        let panels = Panels::Graded {
            centre_hz: self.natural_freq_hz,
            finest_hz: self.natural_freq_hz * self.damping_ratio.min(0.5) / 4.0,
        };
        let seen = filtered_vibration(
            KIND,
            ctx.vibration_unit,
            ctx.psd_unit,
            [false, false, true],
            |_, f| filter.response(f, rate),
            panels,
            Some(&self.bands),
            rate,
        )?;
        let psd = filtered_psd(
            ctx.psd_unit,
            [false, false, true],
            |_, f| filter.response(f, rate),
            Some(&self.bands),
            rate,
        );
        Ok((seen, psd))
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{al15, assert_agrees, band, build_toml, tone, unit_shift, Scene};

    /// An underdamped loop scaled down into the test band (a real unit's ~1.5 kHz
    /// would need a faster, longer record for the same power).
    #[test]
    fn mean_formula_matches_time_domain() {
        let p = al15();
        let mut s = Scene::new(2048.0, 1 << 14);
        s.pre_roll = 1024;
        s.a_l_g = [0.5, 0.0, 2.0];
        s.tones = vec![
            tone(97.1, [1.2, 1.0, 1.5], [0.0, 0.0, 0.0]),
            tone(31.9, [0.0, 0.5, 0.8], [0.0, 45.0, 0.0]),
        ];
        s.bands = vec![band(40.0, 240.0, [0.01, 0.01, 0.015])];
        s.coherence = [[1.0, 0.0, 0.4], [0.0, 1.0, 0.0], [0.4, 0.0, 1.0]];
        let mut e = build_toml(
            "kind = \"unit_response\"\nnatural_freq_hz = 120.0\ndamping_ratio = 0.25",
            &p,
        );
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(2, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 2, e.as_mut(), 300);
        assert_agrees("unit_response", est, formula, 10.0);
    }
}
