//! `axis_phase`: phase between the body axes of the deterministic vibration (MODEL.md
//! section 11, third item).
//!
//! Physics: the papers take every axis in phase (`phi_i = 0`, MODEL.md section 3), so
//! their cross terms are `0.5 m31 aB3 aB1`; a structure vibrating in a rocking or
//! torsional mode moves its axes with phase offsets. This effect adds `phase_x_deg`,
//! `phase_y_deg`, `phase_z_deg` to every tone's phase on body axes x, y, z in
//! [`Effect::adjust_body_vibration`] (before samples are drawn, for every unit; the
//! broadband random part has no phase to shift and is left alone).
//!
//! Mean contribution: the exact mean output (MODEL.md section 6) with the unit-axis
//! phases shifted by the offsets of the body axes the unit's OA, PA, IA lie on (a
//! negative axis adds pi to a phase, which an additive offset leaves unchanged), minus
//! the exact mean without. Only the cross terms move:
//! `sum_tones 0.5 m31 aB3 aB1 (cos(phi3 - phi1 + d3 - d1) - cos(phi3 - phi1))` and the
//! same with m32 and axis 2 (MODEL.md section 6, cross terms).
//!
//! In a prediction with other effects the offsets are on the vibration path
//! ([`Effect::on_vibration_path`]): every other effect's mean is taken under the
//! shifted phases, as in the simulator, where the samples every hook sees are drawn
//! after the shift (the anisoelastic product `k_ae a1 a2` then rectifies
//! `0.5 k_ae aB1 aB2 cos(phi1 - phi2 + d1 - d2)` per tone).

use super::spectral::exact_shift;
use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{Effect, MeanContext};
use crate::Result;
use vibro_physics::triad::TriadAxes;
use vibro_physics::vibration::{PsdBand, Vibration};

const KIND: &str = "axis_phase";
const RULE: &str = "must be finite and -360 <= phase <= 360 deg";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "phase offsets between body axes added to every tone of the vibration",
    params: &[
        ParamInfo {
            name: "phase_x_deg",
            unit: "deg",
            meaning: "offset added to every tone's phase on body x; default 0, |phase| <= 360",
        },
        ParamInfo {
            name: "phase_y_deg",
            unit: "deg",
            meaning: "offset on body y; default 0, |phase| <= 360",
        },
        ParamInfo {
            name: "phase_z_deg",
            unit: "deg",
            meaning: "offset on body z; default 0, |phase| <= 360",
        },
    ],
    hooks: "adjust_body_vibration",
    scope: Scope::Body,
    example: r#"[[effect]]
kind = "axis_phase"
phase_x_deg = 0.0
phase_y_deg = 60.0
phase_z_deg = -30.0
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    p.require_any(&["phase_x_deg", "phase_y_deg", "phase_z_deg"]);
    let ok = |x: f64| x.abs() <= 360.0;
    let offsets_rad = [
        p.with_default("phase_x_deg", 0.0, RULE, ok),
        p.with_default("phase_y_deg", 0.0, RULE, ok),
        p.with_default("phase_z_deg", 0.0, RULE, ok),
    ]
    .map(f64::to_radians);
    Ok(Box::new(AxisPhase {
        offsets_rad,
        triad: p.rig().triad,
    }))
}

/// Phase offsets per body axis.
#[derive(Debug, Clone)]
struct AxisPhase {
    /// Per body axis x, y, z.
    offsets_rad: [f64; 3],
    triad: TriadAxes,
}

impl Effect for AxisPhase {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn adjust_body_vibration(&self, vib_body: &mut Vibration) {
        let mut out = *vib_body;
        out.clear_tones();
        for t in vib_body.tones() {
            let mut t2 = *t;
            for (phase, offset) in t2.phase_rad.iter_mut().zip(self.offsets_rad) {
                *phase += offset;
            }
            // Same number of tones as before: cannot overflow.
            let _ = out.push_tone(t2);
        }
        *vib_body = out;
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        exact_shift(ctx, &self.shifted(ctx)?)
    }

    /// The shifted phases are what every other effect of the unit sees (the
    /// simulator draws the samples after [`Effect::adjust_body_vibration`]): the
    /// vibropendulous and anisoelastic products and the saturation take them.
    fn on_vibration_path(&self) -> bool {
        true
    }

    fn transmitted(&self, ctx: &MeanContext<'_>) -> Option<Result<(Vibration, Vec<PsdBand>)>> {
        Some(self.shifted(ctx).map(|v| (v, ctx.psd_unit.to_vec())))
    }
}

impl AxisPhase {
    /// The unit's vibration with each tone's unit-axis phases moved by the offsets of
    /// the body axes the unit's axes lie on (the random part unchanged).
    fn shifted(&self, ctx: &MeanContext<'_>) -> Result<Vibration> {
        let Some(axes) = self.triad.units.get(ctx.unit) else {
            return Ok(*ctx.vibration_unit);
        };
        let body_index = [axes.oa.body_index, axes.pa.body_index, axes.ia.body_index];
        let mut shifted = *ctx.vibration_unit;
        shifted.clear_tones();
        for t in ctx.vibration_unit.tones() {
            let mut t2 = *t;
            for (j, phase) in t2.phase_rad.iter_mut().enumerate() {
                *phase += self.offsets_rad[body_index[j]];
            }
            shifted.push_tone(t2)?;
        }
        Ok(shifted)
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{
        al15_spec, assert_agrees, band, bands_to_unit, body_shift, body_to_unit, build_toml,
        passport, tone, Scene,
    };
    use vibro_physics::triad::TriadAxes;

    /// Tones in phase on all body axes (the papers' assumption) and noise; the offsets
    /// turn the IA x OA and IA x PA products partly into quadrature. m31, m32 are
    /// raised to 200 ppm/g so that the cross terms stand out of the noise.
    #[test]
    fn mean_formula_matches_time_domain() {
        let mut spec = al15_spec();
        spec.m31_ppm_per_g = 200.0;
        spec.m32_ppm_per_g = -150.0;
        let p = passport(&spec);
        let mut s = Scene::new(1024.0, 1 << 13);
        s.reps = 16;
        s.a_l_g = [0.2, 0.1, 1.0];
        s.tones = vec![
            tone(23.3, [1.5, 1.2, 2.0], [0.0, 0.0, 0.0]),
            tone(71.1, [0.8, 1.0, 0.6], [0.0, 0.0, 0.0]),
        ];
        // Noise away from the tones, so that tone x noise products average out.
        s.bands = vec![band(100.0, 300.0, [0.002, 0.002, 0.002])];
        let e = build_toml(
            "kind = \"axis_phase\"\nphase_x_deg = 70.0\nphase_y_deg = -20.0\nphase_z_deg = 150.0",
            &p,
        );
        let triad = TriadAxes::standard();
        for unit in 0..3 {
            let axes = triad.units[unit];
            let vib = body_to_unit(&s.vibration(), &axes);
            let bands = bands_to_unit(&s.bands, &axes);
            let mut ctx = s.ctx(unit, &p, &vib);
            ctx.psd_unit = &bands;
            let formula = e.mean_shift_g(&ctx).unwrap();
            let est = body_shift(&s, &p, &axes, unit, e.as_ref(), 400 + 50 * unit as u64);
            assert_agrees(&format!("axis_phase (unit {unit})"), est, formula, 10.0);
        }
    }

    #[test]
    fn refuses_units_and_needs_an_offset() {
        let err = super::super::testkit::build_error("kind = \"axis_phase\"\nunits = [0]");
        assert!(
            err.contains("effect[axis_phase].units = [0]: this effect acts on the body-frame"),
            "{err}"
        );
        assert!(
            err.contains("effect[axis_phase] = no parameter given: at least one of phase_x_deg"),
            "{err}"
        );
    }
}
