//! `mount_resonance`: the INS suspension between the vibration sensors and the
//! accelerometer (MODEL.md section 11, first item; RIG.md: "a resonance near 48 Hz
//! peaking at about 1.85").
//!
//! Physics: the accelerometer sits on a suspension that the vibration sensor does not
//! see through, so the vibration reaching the unit is the sensed vibration through the
//! base-excitation transmissibility of a single-degree-of-freedom mount,
//! `T(s) = (wn^2 + 2 zeta wn s) / (s^2 + 2 zeta wn s + wn^2)`, `zeta = 1/(2q)`,
//! peaking at `|T(j wn)| = sqrt(1 + q^2)` (q = 1.56 gives RIG.md's 1.85 at 48 Hz).
//! It acts on the selected unit axes (`axes`, default all) in
//! [`Effect::at_unit_input`], as a biquad (bilinear transform prewarped at `freq_hz`).
//!
//! Mean contribution: the exact mean output (MODEL.md section 6) under the vibration as
//! transmitted minus under the vibration as described. Tones are scaled by
//! `|T(f)|` and shifted by `arg T(f)` on the selected axes; each band's random
//! covariance becomes `int Re(T_i conj T_j) S_ij df` (`spectral.rs`), i.e. a
//! variance is scaled by the band average of `|T|^2`. `T` is the exact discrete-time
//! response at the internal rate.

use super::filter::{Analog, Biquad, BiquadState};
use super::spectral::{
    check_rate, exact_shift, filtered_psd, filtered_vibration, BandMemo, Panels, SeenCache,
};
use super::{unit_axes_param, EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext};
use crate::Result;
use realfft::num_complex::Complex;
use vibro_physics::vibration::{PsdBand, Vibration};

const KIND: &str = "mount_resonance";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "INS suspension between vibration sensor and unit: 2nd-order base-excitation \
              transmissibility on the vibration reaching the unit",
    params: &[
        ParamInfo {
            name: "freq_hz",
            unit: "Hz",
            meaning: "natural frequency f0 of the suspension; required, 0 < f0 <= 1e5",
        },
        ParamInfo {
            name: "q",
            unit: "1",
            meaning: "quality factor q = 1/(2 zeta); peak transmissibility sqrt(1 + q^2); \
                      required, 0.05 <= q <= 1000",
        },
        ParamInfo {
            name: "axes",
            unit: "-",
            meaning: "unit axes it acts on, from \"OA\", \"PA\", \"IA\"; default all three",
        },
    ],
    hooks: "at_unit_input",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "mount_resonance"
freq_hz = 48.0
q = 1.56
axes = ["OA", "PA", "IA"]
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let freq_hz = p.required("freq_hz", "must be finite and 0 < freq_hz <= 1e5 Hz", |f| {
        f > 0.0 && f <= 1e5
    });
    let q = p.required("q", "must be finite and 0.05 <= q <= 1000", |q| {
        (0.05..=1000.0).contains(&q)
    });
    let axes = unit_axes_param(p, "axes");
    Ok(Box::new(MountResonance {
        freq_hz,
        q,
        axes,
        analog: Analog::transmissibility(freq_hz, q),
        filter: Biquad::IDENTITY,
        state: Default::default(),
        seen: SeenCache::default(),
        bands: BandMemo::default(),
    }))
}

/// The suspension transmissibility on the vibration at the unit.
#[derive(Debug, Clone)]
struct MountResonance {
    freq_hz: f64,
    q: f64,
    axes: [bool; 3],
    analog: Analog,
    filter: Biquad,
    /// Per unit, per unit axis.
    state: [[BiquadState; 3]; 3],
    /// What the filter last passed ([`SeenCache`]).
    seen: SeenCache,
    /// The filter's integrals over the bands seen so far ([`BandMemo`]).
    bands: BandMemo,
}

impl Effect for MountResonance {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn reset(&mut self, internal_rate_hz: f64) {
        self.filter = Biquad::bilinear(&self.analog, internal_rate_hz, self.freq_hz);
        self.state = Default::default();
    }

    fn at_unit_input(&mut self, ctx: &BlockCtx, vib_unit_g: &mut [[f64; 3]]) {
        let Some(state) = self.state.get_mut(ctx.unit) else {
            return;
        };
        for s in vib_unit_g.iter_mut() {
            for i in 0..3 {
                if self.axes[i] {
                    s[i] = state[i].step(&self.filter, s[i]);
                }
            }
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let (transmitted, _) = self.seen(ctx)?;
        exact_shift(ctx, &transmitted)
    }

    fn on_vibration_path(&self) -> bool {
        true
    }

    fn path_transfer(&self, _unit: usize, f_hz: f64) -> Option<[Complex<f64>; 3]> {
        let t = self.analog.at(f_hz);
        let one = Complex::new(1.0, 0.0);
        Some(std::array::from_fn(|i| if self.axes[i] { t } else { one }))
    }

    fn transmitted(&self, ctx: &MeanContext<'_>) -> Option<Result<(Vibration, Vec<PsdBand>)>> {
        Some(self.seen(ctx))
    }
}

impl MountResonance {
    /// The vibration and band PSD through the suspension.
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
        let filter = Biquad::bilinear(&self.analog, rate, self.freq_hz);
        // Panels far narrower than the resonance's half-power width f0/q at the
        // resonance, wider away from it.
        let panels = Panels::Graded {
            centre_hz: self.freq_hz,
            finest_hz: self.freq_hz / (8.0 * self.q.max(1.0)),
        };
        let transmitted = filtered_vibration(
            KIND,
            ctx.vibration_unit,
            ctx.psd_unit,
            self.axes,
            |_, f| filter.response(f, rate),
            panels,
            Some(&self.bands),
            rate,
        )?;
        let psd = filtered_psd(
            ctx.psd_unit,
            self.axes,
            |_, f| filter.response(f, rate),
            Some(&self.bands),
            rate,
        );
        Ok((transmitted, psd))
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{
        al15, assert_agrees, band, build_error, build_toml, tone, unit_shift, Scene,
    };

    /// RIG.md's suspension on the Cyclone-4 environment scaled into a short record:
    /// tones near the resonance with phases, correlated band noise, aL off zero.
    fn scene() -> Scene {
        let mut s = Scene::new(2048.0, 1 << 14);
        s.pre_roll = 2048;
        s.a_l_g = [0.3, -0.2, 1.0];
        s.tones = vec![
            tone(45.3, [1.0, 0.8, 2.0], [0.0, 30.0, 0.0]),
            tone(93.7, [0.5, 0.5, 0.7], [10.0, 0.0, -40.0]),
        ];
        s.bands = vec![band(20.0, 160.0, [0.01, 0.01, 0.02])];
        s.coherence = [[1.0, 0.1, 0.3], [0.1, 1.0, 0.2], [0.3, 0.2, 1.0]];
        s
    }

    /// What the filter passes is kept between calls with the same vibration
    /// (`SeenCache`): one effect asked at three flight accelerations, then about
    /// another spectrum, then the first again, gives bit for bit what a new effect
    /// gives for each; the cache never answers for another input.
    #[test]
    fn the_filter_s_cache_answers_only_for_its_own_input() {
        let p = al15();
        let s = scene();
        let mut other = scene();
        other.bands = vec![band(20.0, 640.0, [0.002, 0.003, 0.004])];
        let toml = "kind = \"mount_resonance\"\nfreq_hz = 150.0\nq = 2.5";
        let kept = build_toml(toml, &p);
        let vib = s.vibration();
        let fresh = |scene: &Scene, a3: f64| {
            let mut sc = scene.clone();
            sc.a_l_g[2] = a3;
            build_toml(toml, &p)
                .mean_shift_g(&sc.ctx(0, &p, &vib))
                .unwrap()
        };
        for (scene, a3) in [(&s, 1.0), (&s, -0.5), (&s, 2.0), (&other, 1.0), (&s, 1.0)] {
            let mut sc = scene.clone();
            sc.a_l_g[2] = a3;
            let got = kept.mean_shift_g(&sc.ctx(0, &p, &vib)).unwrap();
            assert_eq!(got.to_bits(), fresh(scene, a3).to_bits(), "a3 = {a3}");
        }
        assert_ne!(fresh(&s, 1.0), fresh(&other, 1.0));
    }

    #[test]
    fn mean_formula_matches_time_domain_all_axes() {
        let p = al15();
        let s = scene();
        let mut e = build_toml("kind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56", &p);
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(0, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 0, e.as_mut(), 100);
        assert_agrees("mount_resonance (all axes)", est, formula, 10.0);
    }

    #[test]
    fn mean_formula_matches_time_domain_ia_only() {
        let p = al15();
        let mut s = scene();
        s.tones.truncate(1);
        let mut e = build_toml(
            "kind = \"mount_resonance\"\nfreq_hz = 60.0\nq = 4.0\naxes = [\"ia\"]",
            &p,
        );
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(1, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 1, e.as_mut(), 200);
        assert_agrees("mount_resonance (IA only, q = 4)", est, formula, 10.0);
    }

    #[test]
    fn random_vibration_without_psd_is_an_error_naming_the_effect() {
        let p = al15();
        let s = scene();
        let e = build_toml("kind = \"mount_resonance\"\nfreq_hz = 48\nq = 2", &p);
        let vib = s.vibration();
        let mut ctx = s.ctx(0, &p, &vib);
        ctx.psd_unit = &[];
        let err = e.mean_shift_g(&ctx).unwrap_err().to_string();
        assert!(
            err.starts_with("effect[mount_resonance] = sigma1^2"),
            "{err}"
        );
    }

    #[test]
    fn axes_are_validated() {
        let err =
            build_error("kind = \"mount_resonance\"\nfreq_hz = 48\nq = 2\naxes = [\"IA\", \"XA\"]");
        assert!(
            err.starts_with(
                "effect[mount_resonance].axes = [\"IA\", \"XA\"]: must list distinct unit axes"
            ),
            "{err}"
        );
    }
}
