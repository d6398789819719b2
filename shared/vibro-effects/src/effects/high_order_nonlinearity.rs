//! `high_order_nonlinearity`: 6th- and 7th-order terms of the conversion function
//! (MODEL.md section 11, seventh item; the FP of section 2 stops at `k5`).
//!
//! Physics: `out += k6 a3^6 + k7 a3^7` on the total IA acceleration, in
//! [`Effect::at_unit_output`]. Coefficients are quoted like the passport's `k2..k5`:
//! `kn` in ppm/g^(n-1) (= ug/g^n), so `k6_ppm_per_g5 = 1` adds 1 ug at 1 g.
//!
//! Mean contribution: the change of mean output when switched on,
//! `k6 E[a3^6] + k7 E[a3^7]`, including the static `k6 aL3^6 + k7 aL3^7`, from the raw
//! moments of `a3 = aL3 + v3` by MODEL.md section 6's rule extended to order 7:
//! `E[a3^n] = sum_j C(n, j) aL3^(n-j) E[v3^j]`, the moments of `v3` combining over its
//! independent parts binomially; a tone of amplitude `A` has `E[s^2] = A^2/2`,
//! `E[s^4] = 3A^4/8`, `E[s^6] = 5A^6/16` (`E[sin^(2m)] = C(2m, m)/4^m`); the random part
//! `E[x^2] = sigma^2`, `E[x^4] = K sigma^4` (as `vibro_physics::exact::ia_moments`) and
//! `E[x^6] = 15 E[w^3] sigma^6` for the scale mixture of kurtosis `K`
//! ([`ScaleMixture::for_kurtosis`]; `15 sigma^6` when Gaussian); odd moments are 0.

use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext, OutputTerms};
use crate::Result;
use vibro_physics::abs_mean::ScaleMixture;
use vibro_physics::vibration::Vibration;

const KIND: &str = "high_order_nonlinearity";
/// Parts per million, as the passport divides (`vibro_physics::passport`).
const PER_PPM: f64 = 1e6;

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "nonlinearity beyond 5th order: out += k6 a3^6 + k7 a3^7",
    params: &[
        ParamInfo {
            name: "k6_ppm_per_g5",
            unit: "ppm/g^5",
            meaning: "sixth-order coefficient (ug/g^6); default 0, |k6| <= 1e4",
        },
        ParamInfo {
            name: "k7_ppm_per_g6",
            unit: "ppm/g^6",
            meaning: "seventh-order coefficient (ug/g^7); default 0, |k7| <= 1e4; at least \
                      one of the two is required",
        },
    ],
    hooks: "at_unit_output",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "high_order_nonlinearity"
k6_ppm_per_g5 = 0.05
k7_ppm_per_g6 = 0.01
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    p.require_any(&["k6_ppm_per_g5", "k7_ppm_per_g6"]);
    let ok = |k: f64| k.abs() <= 1e4;
    let k6 = p.with_default(
        "k6_ppm_per_g5",
        0.0,
        "must be finite and |k6| <= 1e4 ppm/g^5",
        ok,
    );
    let k7 = p.with_default(
        "k7_ppm_per_g6",
        0.0,
        "must be finite and |k7| <= 1e4 ppm/g^6",
        ok,
    );
    Ok(Box::new(HighOrder {
        k6_per_g5: k6 / PER_PPM,
        k7_per_g6: k7 / PER_PPM,
    }))
}

#[derive(Debug, Clone)]
struct HighOrder {
    k6_per_g5: f64,
    k7_per_g6: f64,
}

impl Effect for HighOrder {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn at_unit_output(&mut self, _ctx: &BlockCtx, input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        for (a, o) in input_unit_g.iter().zip(out_g.iter_mut()) {
            let x = a[2];
            let x2 = x * x;
            let x6 = x2 * x2 * x2;
            *o += x6 * (self.k6_per_g5 + self.k7_per_g6 * x);
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let m = ia_moments7(ctx.vibration_unit);
        let a = ctx.a_l_unit_g[2];
        let raw = |n: usize| -> f64 {
            (0..=n)
                .map(|j| binomial(n, j) * a.powi((n - j) as i32) * m[j])
                .sum()
        };
        Ok(self.k6_per_g5 * raw(6) + self.k7_per_g6 * raw(7))
    }

    fn output_terms(&self, _ctx: &MeanContext<'_>) -> Option<OutputTerms> {
        Some(OutputTerms {
            a3_pow6_per_g5: self.k6_per_g5,
            a3_pow7_per_g6: self.k7_per_g6,
            ..OutputTerms::default()
        })
    }
}

/// `C(n, k)` for the small orders used here.
fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |c, i| c * (n - i) as f64 / (i + 1) as f64)
}

/// Raw moments of independent sums: `E[(X + Y)^n]`, n = 0..7.
fn combine(a: &[f64; 8], b: &[f64; 8]) -> [f64; 8] {
    std::array::from_fn(|n| (0..=n).map(|j| binomial(n, j) * a[j] * b[n - j]).sum())
}

/// Raw moments `E[v3^j]`, j = 0..7, of the IA vibration (the rule of
/// `vibro_physics::exact::ia_moments`, to order 7).
fn ia_moments7(vib: &Vibration) -> [f64; 8] {
    let mut m = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for t in vib.tones() {
        let a2 = t.amplitude_g[2] * t.amplitude_g[2];
        let tone = [
            1.0,
            0.0,
            0.5 * a2,
            0.0,
            0.375 * a2 * a2,
            0.0,
            0.3125 * a2 * a2 * a2,
            0.0,
        ];
        m = combine(&m, &tone);
    }
    let s2 = vib.covariance_g2[2][2].max(0.0);
    let mix = ScaleMixture::for_kurtosis(vib.kurtosis[2]);
    let e_w3 = mix.prob[0] * mix.scale[0].powi(3) + mix.prob[1] * mix.scale[1].powi(3);
    let random = [
        1.0,
        0.0,
        s2,
        0.0,
        vib.kurtosis[2] * s2 * s2,
        0.0,
        15.0 * e_w3 * s2 * s2 * s2,
        0.0,
    ];
    combine(&m, &random)
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{al15, assert_agrees, band, build_toml, tone, unit_shift, Scene};
    use super::*;

    #[test]
    fn moments_agree_with_the_exact_model_to_order_5_and_quadrature_beyond() {
        let mut v = Vibration::single_tone(20.0, [0.0, 0.0, 1.3]);
        v.push_tone(vibro_physics::vibration::Tone {
            freq_hz: 50.0,
            amplitude_g: [0.0, 0.0, 0.7],
            phase_rad: [0.0; 3],
        })
        .unwrap();
        v.covariance_g2[2][2] = 0.64;
        v.kurtosis[2] = 5.0;
        let m = ia_moments7(&v);
        let e = vibro_physics::exact::ia_moments(&v);
        for j in 0..6 {
            assert!(
                (m[j] - e[j]).abs() < 1e-12 * e[j].abs().max(1.0),
                "order {j}"
            );
        }
        // E[v^6] by quadrature over both phases and the mixture (Gauss: 15 s^6 w^3).
        let mix = ScaleMixture::for_kurtosis(5.0);
        let n = 64;
        let mut want = 0.0;
        for i in 0..n {
            for k in 0..n {
                let s = 1.3 * (std::f64::consts::TAU * (i as f64 + 0.5) / n as f64).sin()
                    + 0.7 * (std::f64::consts::TAU * (k as f64 + 0.5) / n as f64).sin();
                // E[(s + x)^6] for x ~ mixture: sum_j C(6, j) s^(6-j) E[x^j].
                let ex = |j: usize| match j {
                    0 => 1.0,
                    2 => 0.64,
                    4 => 5.0 * 0.64 * 0.64,
                    6 => (0..2)
                        .map(|c| mix.prob[c] * 15.0 * (0.64 * mix.scale[c]).powi(3))
                        .sum(),
                    _ => 0.0,
                };
                want += (0..=6)
                    .map(|j| binomial(6, j) * s.powi(6 - j as i32) * ex(j))
                    .sum::<f64>()
                    / (n * n) as f64;
            }
        }
        assert!((m[6] - want).abs() < 1e-10 * want, "{} vs {want}", m[6]);
        assert_eq!(m[7], 0.0);
    }

    /// Tone plus kurtotic noise (kurtosis 4.5, checking the mixture's 6th moment),
    /// aL3 small so that the vibration part dominates; coefficients exaggerated.
    #[test]
    fn mean_formula_matches_time_domain() {
        let p = al15();
        let mut s = Scene::new(2048.0, 1 << 14);
        s.a_l_g = [0.0, 0.0, 0.5];
        s.tones = vec![tone(41.3, [0.0, 0.0, 1.2], [0.0; 3])];
        s.bands = vec![band(20.0, 500.0, [0.0, 0.0, 0.49 / 480.0])];
        s.kurtosis = 4.5;
        // x^6 of kurtotic noise is heavy-tailed: enough records for a fair spread.
        s.reps = 48;
        let mut e = build_toml(
            "kind = \"high_order_nonlinearity\"\nk6_ppm_per_g5 = 50.0\nk7_ppm_per_g6 = 20.0",
            &p,
        );
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(2, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 2, e.as_mut(), 1100);
        let z = assert_agrees("high_order_nonlinearity (kurtosis 4.5)", est, formula, 10.0);
        let static_g = 50e-6 * 0.5f64.powi(6) + 20e-6 * 0.5f64.powi(7);
        assert!(
            formula - static_g > 10.0 * est.se_g,
            "vibration part resolved (z = {z:.2})"
        );
    }
}
