//! `anisoelastic`: unequal compliance of the pendulum suspension along OA and PA.
//!
//! Physics: a suspension that is softer along one cross axis than the other lets the
//! proof mass move along the stiff/soft diagonal, so the output gains a term in the
//! product of the two cross-axis accelerations, `k_ae * a1 * a2` (OA x PA). This is
//! the anisoelasticity of inertial sensors (an OA x PA cross-coupling term of the
//! model equation in IEEE Std 1293, section 8.3); MODEL.md's conversion function has the
//! products IA x OA and IA x PA (`m31`, `m32`) but not OA x PA (MODEL.md section 2).
//! Hook: [`Effect::at_unit_output`], `out += k_ae_per_g * a1 * a2` on the total
//! accelerations.
//!
//! Mean contribution: the change of mean output when the effect is switched on,
//! `k_ae (aL1 aL2 + E[v1 v2])` with
//! `E[v1 v2] = sum_tones 0.5 aB1 aB2 cos(phi1 - phi2) + cov_12` (MODEL.md section 6's
//! cross-term rule applied to axes 1 and 2). It includes the static `k_ae aL1 aL2`,
//! which belongs to the main error, not to the vibration error: the vibration error
//! alone is `k_ae E[v1 v2]`.

use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext, OutputTerms};
use crate::Result;

const KIND: &str = "anisoelastic";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "unequal suspension compliance: out += k_ae a1 a2 (OA x PA product)",
    params: &[ParamInfo {
        name: "k_ae_per_g",
        unit: "1/g",
        meaning: "anisoelastic coefficient (g of output per g^2 of OA x PA); required, \
                  |k_ae| <= 0.01",
    }],
    hooks: "at_unit_output",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "anisoelastic"
k_ae_per_g = 2.0e-5
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let k_ae_per_g = p.required(
        "k_ae_per_g",
        "must be finite and |k_ae| <= 0.01 1/g (1e4 ppm/g)",
        |k| k.abs() <= 0.01,
    );
    Ok(Box::new(Anisoelastic { k_ae_per_g }))
}

#[derive(Debug, Clone)]
struct Anisoelastic {
    k_ae_per_g: f64,
}

impl Effect for Anisoelastic {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn at_unit_output(&mut self, _ctx: &BlockCtx, input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        for (a, o) in input_unit_g.iter().zip(out_g.iter_mut()) {
            *o += self.k_ae_per_g * a[0] * a[1];
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let vib = ctx.vibration_unit;
        let [a1, a2, _] = ctx.a_l_unit_g;
        let tones: f64 = vib
            .tones()
            .iter()
            .map(|t| {
                0.5 * t.amplitude_g[0] * t.amplitude_g[1] * (t.phase_rad[0] - t.phase_rad[1]).cos()
            })
            .sum();
        Ok(self.k_ae_per_g * (a1 * a2 + tones + vib.covariance_g2[0][1]))
    }

    fn output_terms(&self, _ctx: &MeanContext<'_>) -> Option<OutputTerms> {
        Some(OutputTerms {
            a1_a2_per_g: self.k_ae_per_g,
            ..OutputTerms::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{al15, assert_agrees, band, build_toml, tone, unit_shift, Scene};

    #[test]
    fn mean_formula_matches_time_domain() {
        let p = al15();
        let mut s = Scene::new(1024.0, 1 << 13);
        s.a_l_g = [0.5, -0.3, 1.0];
        s.tones = vec![
            tone(17.3, [1.2, 1.2, 0.5], [0.0, 50.0, 0.0]),
            tone(61.9, [0.4, 0.9, 0.2], [0.0, 160.0, 0.0]),
        ];
        s.bands = vec![band(10.0, 300.0, [0.004, 0.006, 0.004])];
        s.coherence = [[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut e = build_toml("kind = \"anisoelastic\"\nk_ae_per_g = 1e-4", &p);
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(1, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 1, e.as_mut(), 700);
        assert_agrees("anisoelastic", est, formula, 10.0);
    }
}
