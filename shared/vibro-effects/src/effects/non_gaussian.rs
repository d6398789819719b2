//! `non_gaussian`: kurtotic (bursty) random vibration (MODEL.md section 11, fifth
//! item).
//!
//! Physics: flight vibration comes in bursts, so its random part has heavier tails
//! than a Gaussian of the same PSD. MODEL.md section 6 takes `E[x^4] = 3 sigma^4`;
//! with kurtosis `K` it is `K sigma^4`, which moves the `k4` and `k5` terms (and the
//! asymmetry mean `E|a3|`). The effect sets the kurtosis of the body random vibration
//! per body axis in [`Effect::adjust_body_vibration`]; the simulator then draws the
//! random part as the Gaussian scale mixture of
//! [`vibro_physics::abs_mean::ScaleMixture::for_kurtosis`] at the same PSD (the family
//! the exact model assumes, `3 <= K <= 30`).
//!
//! Mean contribution: the exact mean output (MODEL.md section 6, non-Gaussian random
//! part: `E[x^4] = K sigma^4` and the mixture's `E|.|`) with the unit's IA kurtosis set
//! to that of the body axis its IA lies on, minus the exact mean with the kurtosis as
//! described (3 unless the scenario says otherwise). The simulator draws the burst
//! state once for all axes, so with equal kurtoses the covariances are kept; across
//! axes of different kurtoses a covariance is multiplied by
//! `c_ij = E[sqrt(w_i w_j)] = (1-p) sqrt(w_lo,i w_lo,j) + p sqrt(w_hi,i w_hi,j)`
//! (`p = ScaleMixture::P_HIGH`), and the formula applies the ratio of `c_ij` after to
//! `c_ij` before (this moves the `m31`, `m32` cross terms).

use super::spectral::exact_shift;
use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{Effect, MeanContext};
use crate::Result;
use vibro_physics::abs_mean::ScaleMixture;
use vibro_physics::triad::TriadAxes;
use vibro_physics::vibration::Vibration;

const KIND: &str = "non_gaussian";
const RULE: &str = "must be finite and 3 <= kurtosis <= 30 (the scale-mixture family)";

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "kurtotic random vibration: the body random part becomes a Gaussian scale \
              mixture with the given kurtosis at the same PSD",
    params: &[
        ParamInfo {
            name: "kurtosis",
            unit: "1",
            meaning: "kurtosis E[x^4]/sigma^4 of the random part on every body axis, 3..30",
        },
        ParamInfo {
            name: "kurtosis_x",
            unit: "1",
            meaning: "kurtosis on body x, overriding `kurtosis`, 3..30",
        },
        ParamInfo {
            name: "kurtosis_y",
            unit: "1",
            meaning: "kurtosis on body y, overriding `kurtosis`, 3..30",
        },
        ParamInfo {
            name: "kurtosis_z",
            unit: "1",
            meaning: "kurtosis on body z, overriding `kurtosis`, 3..30; at least one of the \
                      four is required, unset axes stay Gaussian (3)",
        },
    ],
    hooks: "adjust_body_vibration",
    scope: Scope::Body,
    example: r#"[[effect]]
kind = "non_gaussian"
kurtosis = 6.0
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    p.require_any(&["kurtosis", "kurtosis_x", "kurtosis_y", "kurtosis_z"]);
    let ok = |k: f64| (3.0..=ScaleMixture::MAX_KURTOSIS).contains(&k);
    let all = p.with_default("kurtosis", 3.0, RULE, ok);
    let kurtosis = [
        p.with_default("kurtosis_x", all, RULE, ok),
        p.with_default("kurtosis_y", all, RULE, ok),
        p.with_default("kurtosis_z", all, RULE, ok),
    ];
    Ok(Box::new(NonGaussian {
        kurtosis,
        triad: p.rig().triad,
    }))
}

#[derive(Debug, Clone)]
struct NonGaussian {
    /// Per body axis x, y, z.
    kurtosis: [f64; 3],
    triad: TriadAxes,
}

impl Effect for NonGaussian {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn adjust_body_vibration(&self, vib_body: &mut Vibration) {
        vib_body.kurtosis = self.kurtosis;
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let Some(axes) = self.triad.units.get(ctx.unit) else {
            return Ok(0.0);
        };
        let before = ctx.vibration_unit;
        let mut changed = *before;
        for (j, ax) in [axes.oa, axes.pa, axes.ia].iter().enumerate() {
            changed.kurtosis[j] = self.kurtosis[ax.body_index];
        }
        for i in 0..3 {
            for j in 0..3 {
                if i != j {
                    changed.covariance_g2[i][j] *=
                        common_scale(changed.kurtosis[i], changed.kurtosis[j])
                            / common_scale(before.kurtosis[i], before.kurtosis[j]);
                }
            }
        }
        exact_shift(ctx, &changed)
    }
}

/// `E[sqrt(w_i w_j)]` for the scale mixtures of kurtoses `k_i`, `k_j` in one common
/// burst state (1 for equal kurtoses, since `E[w] = 1`).
fn common_scale(k_i: f64, k_j: f64) -> f64 {
    let (a, b) = (
        ScaleMixture::for_kurtosis(k_i),
        ScaleMixture::for_kurtosis(k_j),
    );
    a.prob[0] * (a.scale[0] * b.scale[0]).sqrt() + a.prob[1] * (a.scale[1] * b.scale[1]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{
        al15, assert_agrees, band, bands_to_unit, body_shift, body_to_unit, build_toml, tone, Scene,
    };
    use vibro_physics::triad::TriadAxes;

    /// Broadband vibration of 1.5 g RMS with a tone, kurtosis 9, aL3 = 2 g (AL-15): the
    /// k4 and k5 terms and the asymmetry move.
    #[test]
    fn mean_formula_matches_time_domain() {
        let p = al15();
        let mut s = Scene::new(2048.0, 1 << 14);
        s.a_l_g = [0.0, 0.3, 2.0];
        s.tones = vec![tone(37.1, [0.5, 0.5, 1.0], [0.0, 0.0, 0.0])];
        s.bands = vec![band(20.0, 640.0, [2.25 / 620.0; 3])];
        s.coherence = [[1.0, 0.2, 0.2], [0.2, 1.0, 0.2], [0.2, 0.2, 1.0]];
        let e = build_toml("kind = \"non_gaussian\"\nkurtosis = 9.0", &p);
        let axes = TriadAxes::standard().units[2];
        let vib = body_to_unit(&s.vibration(), &axes);
        let bands = bands_to_unit(&s.bands, &axes);
        let mut ctx = s.ctx(2, &p, &vib);
        ctx.psd_unit = &bands;
        let formula = e.mean_shift_g(&ctx).unwrap();
        let est = body_shift(&s, &p, &axes, 2, e.as_ref(), 800);
        assert_agrees("non_gaussian (kurtosis 9)", est, formula, 10.0);
    }

    #[test]
    fn per_axis_kurtosis_maps_to_the_unit_ia() {
        let p = al15();
        let e = build_toml("kind = \"non_gaussian\"\nkurtosis_y = 12.0", &p);
        let mut body = vibro_physics::vibration::Vibration::random_rms([1.0, 1.0, 1.0]);
        e.adjust_body_vibration(&mut body);
        assert_eq!(body.kurtosis, [3.0, 12.0, 3.0]);
        let s = Scene::new(1000.0, 1024);
        let vib = vibro_physics::vibration::Vibration::random_rms([1.0, 1.0, 1.0]);
        let ctx = |u| s.ctx(u, &p, &vib);
        // Unit 1 has IA on body y: k4 (12 - 3) sigma^4 plus the asymmetry change.
        let shift = e.mean_shift_g(&ctx(1)).unwrap();
        assert!((shift - 9.0 * 10e-6).abs() < 2e-6, "{shift}");
        assert_eq!(e.mean_shift_g(&ctx(0)).unwrap(), 0.0);
    }
}
