//! `saturation`: the servo cannot produce more than its range (MODEL.md section 11,
//! sixth item).
//!
//! Physics: the torquer current of a force-balance accelerometer saturates, so the
//! output is clipped at `+-range_g`: `out = clip(out, -range, range)` in
//! [`Effect::at_unit_output`] (list it last, so that it clips the other effects'
//! terms too). Clipping is a rectifier: when vibration pushes the output past the
//! range on one side more than on the other, the mean moves.
//!
//! Mean contribution: `E[clip(FP(a)) - FP(a)]` over the exact distribution of the
//! input (MODEL.md sections 3 and 6: independent tones with uniform phases, a
//! Gaussian or scale-mixture random part), by deterministic quadrature with the
//! passport's FP ([`vibro_physics::fp::output_g`]):
//! - random part on IA: innermost, over `z` with `x3 = sigma3 sqrt(w) z` for each
//!   scale `w` of the mixture: the clipping thresholds `FP = +-range` along the path
//!   are located by bracketing and bisection and become panel edges of a composite
//!   8-point Gauss–Legendre rule on `|z| <= 9` (panels <= 0.5 wide; the tail beyond
//!   9 is below 1e-18 of probability), which makes it exact to about 1e-12;
//! - with no random part, the last tone is innermost, over its phase the same way;
//! - one tone on a random part: the periodic trapezoid rule over the tone's phase,
//!   nodes doubled (from one per random scale of the tone's IA swing, at least 16)
//!   until two estimates agree to 1e-14 g or 1024 nodes: the inner mean is a
//!   Gaussian-smoothed kink, entire in the phase, and the rule converges faster than
//!   exponentially (typically 32..128 nodes);
//! - the other tones: midpoint rule over each phase (tensor grid of at most 4096
//!   nodes, 1024 per tone for one tone): exponentially convergent when a random part
//!   smooths the inner mean, `O(n^-1.5)` (about 3e-5 relative for one outer tone)
//!   when the inner mean is itself a tone's, and poorer beyond three tones.
//!
//! OA and PA enter FP through `m1 a1 + m2 a2 + m31 a3 a1 + m32 a3 a2`: their tones
//! exactly (same phases as IA's), their random parts through their regression on the
//! IA random part, `E[x_i | x3] = (cov_i3 / sigma3^2) x3`. The residual spread of
//! `x_i` is left out; it smooths the clipping threshold by about `m1 sigma1`, which
//! changes the mean by about `0.5 (m1 sigma1)^2` times the output density at the
//! threshold (below 1e-7 g for the passports of MODEL.md).

use super::quad::{
    crossings, for_each_phase, integrate_between_breaks, normal_pdf, periodic_mean, periodic_start,
    points_per_tone,
};
use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext, OutputTerms};
use crate::Result;
use std::f64::consts::TAU;
use vibro_physics::abs_mean::ScaleMixture;
use vibro_physics::fp::output_g;
use vibro_physics::passport::Passport;

const KIND: &str = "saturation";
/// Half-width of the Gaussian integration range, standard deviations.
const Z_MAX: f64 = 9.0;
/// Bracketing cells over `[-Z_MAX, Z_MAX]` or over a phase period.
const CELLS: usize = 96;
/// Largest panel of the inner Gauss–Legendre rule in `z`, standard deviations.
const MAX_PANEL_Z: f64 = 0.5;
/// Largest panel of the inner Gauss–Legendre rule over a phase, rad.
const MAX_PANEL_RAD: f64 = TAU / 32.0;
/// Nodes of the outer phase grid.
const OUTER_BUDGET: usize = 4096;
const OUTER_MAX_PER_TONE: usize = 1024;
/// Fewest nodes of the doubled periodic trapezoid rule over one tone's phase on noise.
const PERIODIC_START: usize = 16;
/// Agreement of two successive periodic trapezoid estimates that ends the doubling, g
/// (each doubling squares the relative error once converging: the last estimate is
/// far better than this).
const PERIODIC_TOL_G: f64 = 1e-14;

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "servo saturation: the instantaneous output is clipped to +-range_g",
    params: &[ParamInfo {
        name: "range_g",
        unit: "g",
        meaning: "output range (clip level); required, 0.1 <= range <= 1e4",
    }],
    hooks: "at_unit_output",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "saturation"
range_g = 15.0
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let range_g = p.required(
        "range_g",
        "must be finite and 0.1 <= range_g <= 1e4 g",
        |r| (0.1..=1e4).contains(&r),
    );
    Ok(Box::new(Saturation { range_g }))
}

#[derive(Debug, Clone)]
struct Saturation {
    range_g: f64,
}

impl Effect for Saturation {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn at_unit_output(&mut self, _ctx: &BlockCtx, _input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        let r = self.range_g;
        for o in out_g.iter_mut() {
            *o = o.clamp(-r, r);
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        ctx.vibration_unit.validate()?;
        Ok(clip_mean_shift(ctx, self.range_g, &OutputTerms::default()))
    }

    fn clips_output(&self) -> bool {
        true
    }

    fn mean_shift_over_g(
        &self,
        ctx: &MeanContext<'_>,
        others: &OutputTerms,
    ) -> Option<Result<f64>> {
        Some(
            ctx.vibration_unit
                .validate()
                .map(|()| clip_mean_shift(ctx, self.range_g, others))
                .map_err(Into::into),
        )
    }
}

/// `E[clip(y, -r, r) - y]`, `y = FP(a) + others(a)`, by the quadrature of the module
/// docs.
fn clip_mean_shift(ctx: &MeanContext<'_>, r: f64, others: &OutputTerms) -> f64 {
    let p = ctx.passport;
    let vib = ctx.vibration_unit;
    let a_l = ctx.a_l_unit_g;
    let tones = vib.tones();
    let sigma3 = vib.sigma_g(2);
    let random = sigma3 > 0.0;
    // Regression of the OA, PA random parts on IA's.
    let beta = if random {
        [
            vib.covariance_g2[0][2] / (sigma3 * sigma3),
            vib.covariance_g2[1][2] / (sigma3 * sigma3),
        ]
    } else {
        [0.0; 2]
    };
    let mixture = ScaleMixture::for_kurtosis(vib.kurtosis[2]);
    let components: &[(f64, f64)] = &if mixture.is_gaussian() {
        [(1.0, 1.0), (0.0, 0.0)]
    } else {
        [
            (mixture.prob[0], mixture.scale[0]),
            (mixture.prob[1], mixture.scale[1]),
        ]
    };
    // Nothing reaches the range anywhere on the integration domain: the integrand is
    // 0 everywhere and so is the quadrature (the common case while a fit explores).
    let widest = components
        .iter()
        .filter(|(prob, _)| *prob > 0.0)
        .map(|(_, w)| w.sqrt())
        .fold(0.0, f64::max);
    let reach_g: [f64; 3] = std::array::from_fn(|i| {
        let random_g = if random {
            Z_MAX * sigma3 * widest * if i < 2 { beta[i].abs() } else { 1.0 }
        } else {
            0.0
        };
        a_l[i].abs() + tones.iter().map(|t| t.amplitude_g[i].abs()).sum::<f64>() + random_g
    });
    // The IA filter term's `h` (a vibropendulous `c HP[a3]`): per tone the gain
    // rotated by the tone's IA phase, `G_k e^(j phi3_k)`.
    let h_gain: Vec<(f64, f64)> = tones
        .iter()
        .zip(&others.ia_filter_tone_gain)
        .map(|(t, &(gr, gi))| {
            let (s3, c3) = t.phase_rad[2].sin_cos();
            (gr * c3 - gi * s3, gr * s3 + gi * c3)
        })
        .collect();
    let h_random = others.ia_filter_random_gain;
    let h_reach = tones
        .iter()
        .zip(&h_gain)
        .map(|(t, g)| t.amplitude_g[2].abs() * g.0.hypot(g.1))
        .sum::<f64>()
        + if random {
            h_random.abs() * Z_MAX * sigma3 * widest
        } else {
            0.0
        };
    if output_bound_g(p, reach_g) + others.bound_g(reach_g, h_reach) < r {
        return 0.0;
    }
    // Each tone's phases as (cos, sin) per axis, once.
    let phase_cs: Vec<[(f64, f64); 3]> = tones
        .iter()
        .map(|t| std::array::from_fn(|i| (t.phase_rad[i].cos(), t.phase_rad[i].sin())))
        .collect();
    // The base acceleration at the outer tones' phases (sin theta_k, cos theta_k),
    // with the IA filter term's `h` there as a fourth entry (HP(0) = 0: no static part).
    let base_at = |sines: &[f64], cosines: &[f64]| {
        let mut base = [a_l[0], a_l[1], a_l[2], 0.0];
        for ((((t, cs), g), s), c) in tones
            .iter()
            .zip(&phase_cs)
            .zip(&h_gain)
            .zip(sines)
            .zip(cosines)
        {
            for (i, b) in base.iter_mut().take(3).enumerate() {
                // aB sin(theta + phi) = aB (sin theta cos phi + cos theta sin phi).
                *b += t.amplitude_g[i] * (s * cs[i].0 + c * cs[i].1);
            }
            // A3 |G| sin(theta + phi3 + arg G) = A3 Im(G e^(j phi3) e^(j theta)).
            base[3] += t.amplitude_g[2] * (s * g.0 + c * g.1);
        }
        base
    };
    let mut breaks = Vec::new();
    let mut inner = |base: [f64; 4]| {
        if random {
            let mut sum = 0.0;
            for &(prob, w) in components.iter().filter(|(prob, _)| *prob > 0.0) {
                let s = sigma3 * w.sqrt();
                let path = |z: f64| {
                    [
                        base[0] + beta[0] * s * z,
                        base[1] + beta[1] * s * z,
                        base[2] + s * z,
                        base[3] + h_random * s * z,
                    ]
                };
                sum += prob
                    * clipped_integral(
                        p,
                        others,
                        r,
                        &path,
                        -Z_MAX,
                        Z_MAX,
                        MAX_PANEL_Z,
                        &mut breaks,
                        normal_pdf,
                    );
            }
            sum
        } else if let (Some(last), Some(g)) = (tones.last(), h_gain.last()) {
            let path = |th: f64| {
                let (s, c) = th.sin_cos();
                [
                    base[0] + last.amplitude_g[0] * (th + last.phase_rad[0]).sin(),
                    base[1] + last.amplitude_g[1] * (th + last.phase_rad[1]).sin(),
                    base[2] + last.amplitude_g[2] * (th + last.phase_rad[2]).sin(),
                    base[3] + last.amplitude_g[2] * (s * g.0 + c * g.1),
                ]
            };
            clipped_integral(
                p,
                others,
                r,
                &path,
                0.0,
                TAU,
                MAX_PANEL_RAD,
                &mut breaks,
                |_| 1.0 / TAU,
            )
        } else {
            let f = output_g(p, base[0], base[1], base[2])
                + others.at([base[0], base[1], base[2]], base[3]);
            f.clamp(-r, r) - f
        }
    };
    if random && tones.len() == 1 {
        // One tone on noise: the inner mean is the clipping excess smoothed by a
        // Gaussian, an entire function of the tone's phase, so the periodic trapezoid
        // rule converges faster than exponentially (module docs); its nodes are
        // doubled until two estimates agree. It starts with a node spacing that
        // resolves the smoothing: at most about one narrowest random scale of the
        // tone's IA swing between nodes.
        let narrowest = components
            .iter()
            .filter(|(prob, _)| *prob > 0.0)
            .map(|(_, w)| sigma3 * w.sqrt())
            .fold(f64::INFINITY, f64::min);
        let start = periodic_start(
            tones[0].amplitude_g[2],
            narrowest,
            PERIODIC_START,
            OUTER_MAX_PER_TONE,
        );
        let [mean] = periodic_mean(
            &mut |s, c| [inner(base_at(&[s], &[c]))],
            start,
            OUTER_MAX_PER_TONE,
            PERIODIC_TOL_G,
        );
        return mean;
    }
    let n_outer = if random {
        tones.len()
    } else {
        tones.len().saturating_sub(1)
    };
    let n_points = points_per_tone(n_outer, OUTER_BUDGET, OUTER_MAX_PER_TONE);
    let mut total = 0.0;
    for_each_phase(n_outer, n_points, |sines, cosines, weight| {
        total += weight * inner(base_at(sines, cosines));
    });
    total
}

/// An upper bound of `|FP(a)|` (MODEL.md (1), [`output_g`]) over `|a_i| <= reach_g[i]`:
/// every term by its largest magnitude.
fn output_bound_g(p: &Passport, reach_g: [f64; 3]) -> f64 {
    let [a1, a2, a3] = reach_g;
    let poly =
        a3 * a3 * (p.k[2].abs() + a3 * (p.k[3].abs() + a3 * (p.k[4].abs() + a3 * p.k[5].abs())));
    p.a0_g.abs()
        + p.k1.abs() * a3 * (1.0 + 0.5 * p.d1a.abs())
        + poly
        + p.m1.abs() * a1
        + p.m2.abs() * a2
        + a3 * (p.m31_per_g.abs() * a1 + p.m32_per_g.abs() * a2)
}

/// `int_lo^hi (clip(y) - y) density(x) dx`, `y = FP(a) + others(a, h)` with
/// `(a, h) = path(x)` (`h` the IA filter term's filtered acceleration), with
/// the points where `y = +-r` along the path as panel edges; pieces where nothing is clipped are
/// skipped (the integrand is zero on them).
#[allow(clippy::too_many_arguments)]
fn clipped_integral(
    p: &Passport,
    others: &OutputTerms,
    r: f64,
    path: &impl Fn(f64) -> [f64; 4],
    lo: f64,
    hi: f64,
    max_panel: f64,
    breaks: &mut Vec<f64>,
    density: impl Fn(f64) -> f64,
) -> f64 {
    let fp = |x: f64| {
        let a = path(x);
        output_g(p, a[0], a[1], a[2]) + others.at([a[0], a[1], a[2]], a[3])
    };
    breaks.clear();
    crossings(&mut |x| fp(x) - r, lo, hi, CELLS, breaks);
    crossings(&mut |x| fp(x) + r, lo, hi, CELLS, breaks);
    breaks.sort_by(f64::total_cmp);
    let mut sum = 0.0;
    let mut left = lo;
    for right in breaks.iter().copied().chain([hi]) {
        if right > left {
            let mid = fp(0.5 * (left + right));
            if mid.abs() > r {
                let mut f = |x: f64| {
                    let v = fp(x);
                    (v.clamp(-r, r) - v) * density(x)
                };
                sum += integrate_between_breaks(&mut f, left, right, &[], max_panel);
            }
            left = right;
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{
        al15, al15_spec, assert_agrees, band, build_toml, passport, tone, unit_shift, Scene,
    };
    use super::*;
    use std::f64::consts::PI;
    use vibro_physics::abs_mean::normal_cdf;
    use vibro_physics::passport::PassportSpec;
    use vibro_physics::vibration::Vibration;

    /// A linear unit (`aF = a3`), so closed forms of the clipped mean exist.
    fn linear() -> vibro_physics::passport::Passport {
        passport(&PassportSpec {
            a0_g: 0.0,
            d1a_ppm: 0.0,
            k2_ppm_per_g: 0.0,
            k3_ppm_per_g2: 0.0,
            k4_ppm_per_g3: 0.0,
            k5_ppm_per_g4: 0.0,
            m1_ppm: 0.0,
            m2_ppm: 0.0,
            m31_ppm_per_g: 0.0,
            m32_ppm_per_g: 0.0,
            ..al15_spec()
        })
    }

    fn shift(p: &vibro_physics::passport::Passport, a_l3: f64, vib: &Vibration, r: f64) -> f64 {
        let s = Scene::new(1000.0, 1024);
        let mut ctx = s.ctx(0, p, vib);
        ctx.a_l_unit_g = [0.0, 0.0, a_l3];
        clip_mean_shift(&ctx, r, &OutputTerms::default())
    }

    /// Independent closed forms: `E[(mu + x - r)+]` for a Gaussian,
    /// `sigma phi(d) - (r - mu) Q(d)` with `d = (r - mu)/sigma`, and for a sinusoid,
    /// `(sqrt(A^2 - c^2) - c acos(c/A)) / pi` with `c = r - mu`.
    #[test]
    fn quadrature_matches_closed_forms_for_a_linear_unit() {
        let p = linear();
        let (mu, r) = (1.0, 2.5);
        let excess_gauss = |s: f64, c: f64| {
            let d = c / s;
            s * normal_pdf(d) - c * (1.0 - normal_cdf(d))
        };
        let s = 1.1;
        let want = -excess_gauss(s, r - mu) + excess_gauss(s, r + mu);
        let got = shift(&p, mu, &Vibration::random_rms([0.0, 0.0, s]), r);
        assert!((got - want).abs() < 1e-12, "gauss: {got} vs {want}");
        let excess_sine = |a: f64, c: f64| {
            if c >= a {
                0.0
            } else {
                ((a * a - c * c).sqrt() - c * (c / a).acos()) / PI
            }
        };
        let a = 2.0;
        let want = -excess_sine(a, r - mu) + excess_sine(a, r + mu);
        let got = shift(&p, mu, &Vibration::single_tone(30.0, [0.0, 0.0, a]), r);
        assert!((got - want).abs() < 1e-12, "sine: {got} vs {want}");
        // Nothing reaches the range: exactly zero.
        assert_eq!(
            shift(&p, mu, &Vibration::single_tone(30.0, [0.0, 0.0, 1.0]), r),
            0.0
        );
    }

    /// One tone on Gaussian noise (the doubled trapezoid rule over the phase) against
    /// the Gaussian closed form at each phase averaged over 65536 phases, for noise
    /// wide and narrow beside the tone (the start rule must resolve the narrow one).
    #[test]
    fn one_tone_on_noise_matches_closed_forms_over_a_fine_phase_grid() {
        let p = linear();
        let excess_gauss = |s: f64, c: f64| {
            let d = c / s;
            s * normal_pdf(d) - c * (1.0 - normal_cdf(d))
        };
        for (mu, amp, sigma, r) in [
            (0.3, 2.0, 0.8, 2.4),
            (0.3, 3.0, 0.05, 2.9),
            (-0.2, 1.5, 0.3, 1.2),
        ] {
            let n = 1 << 16;
            let want = (0..n)
                .map(|k| {
                    let x = mu + amp * (TAU * (k as f64 + 0.5) / n as f64).sin();
                    -excess_gauss(sigma, r - x) + excess_gauss(sigma, r + x)
                })
                .sum::<f64>()
                / n as f64;
            let mut vib = Vibration::single_tone(40.0, [0.0, 0.0, amp]);
            vib.covariance_g2[2][2] = sigma * sigma;
            let got = shift(&p, mu, &vib, r);
            assert!(want.abs() > 1e-5, "{want}");
            assert!(
                (got - want).abs() < 1e-11 * want.abs(),
                "A {amp} sigma {sigma}: {got} vs {want}"
            );
        }
    }

    /// Two tones (the outer phase grid against an inner tone): the result is stable
    /// when the outer grid is refined, and a tone plus noise converges fast.
    #[test]
    fn outer_phase_grid_is_converged() {
        let p = al15();
        let mut v = Vibration::single_tone(30.0, [0.5, 0.0, 1.5]);
        v.push_tone(tone(71.0, [0.0, 0.4, 1.0], [0.0, 0.0, 40.0]))
            .unwrap();
        let coarse = {
            let s = Scene::new(1000.0, 1024);
            let mut ctx = s.ctx(0, &p, &v);
            ctx.a_l_unit_g = [0.0, 0.0, 1.0];
            clip_mean_shift(&ctx, 2.8, &OutputTerms::default())
        };
        // Reference: the same quadrature with the two tones' roles swapped.
        let mut w = Vibration::none();
        w.push_tone(tone(71.0, [0.0, 0.4, 1.0], [0.0, 0.0, 40.0]))
            .unwrap();
        w.push_tone(tone(30.0, [0.5, 0.0, 1.5], [0.0, 0.0, 0.0]))
            .unwrap();
        let s = Scene::new(1000.0, 1024);
        let mut ctx = s.ctx(0, &p, &w);
        ctx.a_l_unit_g = [0.0, 0.0, 1.0];
        let swapped = clip_mean_shift(&ctx, 2.8, &OutputTerms::default());
        assert!(coarse < -1e-3, "{coarse}");
        assert!(
            (coarse - swapped).abs() < 1e-4 * coarse.abs(),
            "{coarse} vs {swapped}"
        );
    }

    fn scene() -> Scene {
        let mut s = Scene::new(2048.0, 1 << 14);
        s.a_l_g = [0.4, -0.2, 1.0];
        s.tones = vec![tone(30.7, [1.0, 0.5, 1.6], [0.0, 60.0, 0.0])];
        s.bands = vec![band(20.0, 300.0, [0.002, 0.001, 0.001])];
        s.coherence = [[1.0, 0.0, 0.5], [0.0, 1.0, 0.0], [0.5, 0.0, 1.0]];
        s
    }

    #[test]
    fn mean_formula_matches_time_domain_tone_and_noise() {
        let p = al15();
        let s = scene();
        let mut e = build_toml("kind = \"saturation\"\nrange_g = 3.0", &p);
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(0, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 0, e.as_mut(), 900);
        assert_agrees("saturation (tone + noise)", est, formula, 10.0);
    }

    #[test]
    fn mean_formula_matches_time_domain_two_tones_kurtotic_noise() {
        let p = al15();
        let mut s = scene();
        s.tones.push(tone(77.3, [0.2, 0.3, 0.8], [0.0, 0.0, 30.0]));
        s.kurtosis = 6.0;
        let mut e = build_toml("kind = \"saturation\"\nrange_g = 3.2", &p);
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(0, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 0, e.as_mut(), 1000);
        assert_agrees(
            "saturation (two tones + kurtotic noise)",
            est,
            formula,
            10.0,
        );
    }

    /// The shortcut's bound holds: `|FP|` at random points of the box (a passport with
    /// every coefficient made large and of both signs, so that a term taken without
    /// its magnitude shows) never exceeds it, and the box's corners come within 1 % of
    /// it (the bound is the corner's value when all terms add up).
    #[test]
    fn the_output_bound_holds_over_the_box() {
        use rand::{Rng, SeedableRng};
        let p = passport(&PassportSpec {
            a0_g: -0.02,
            d1a_ppm: -3000.0,
            k2_ppm_per_g: -800.0,
            k3_ppm_per_g2: 300.0,
            k4_ppm_per_g3: -40.0,
            k5_ppm_per_g4: 6.0,
            m1_ppm: -2000.0,
            m2_ppm: 1500.0,
            m31_ppm_per_g: -700.0,
            m32_ppm_per_g: 900.0,
            ..al15_spec()
        });
        let reach_g = [3.0, 2.0, 12.0];
        let bound = output_bound_g(&p, reach_g);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut largest = 0.0f64;
        for _ in 0..200_000 {
            let a: [f64; 3] = std::array::from_fn(|i| reach_g[i] * rng.random_range(-1.0..=1.0));
            largest = largest.max(output_g(&p, a[0], a[1], a[2]).abs());
        }
        for signs in 0..8u32 {
            let a: [f64; 3] = std::array::from_fn(|i| {
                if signs >> i & 1 == 1 {
                    reach_g[i]
                } else {
                    -reach_g[i]
                }
            });
            largest = largest.max(output_g(&p, a[0], a[1], a[2]).abs());
        }
        assert!(largest <= bound, "{largest} > {bound}");
        assert!(largest >= 0.5 * bound, "{largest} far below {bound}");
    }

    /// Just past the bound the quadrature still runs: a sinusoid on a linear unit
    /// (`aF = a3`, where the bound is the peak itself) whose peak passes the range by
    /// 1 %, against the closed form `-(sqrt(A^2 - c^2) - c acos(c/A)) / pi` with
    /// `c = r - mu`; 1 % below the range, exactly 0.
    #[test]
    fn the_shortcut_leaves_the_clipping_near_the_range() {
        let p = linear();
        let (mu, amp) = (0.5f64, 2.0f64);
        let peak = mu + amp;
        let c = peak / 1.01 - mu;
        let want = -((amp * amp - c * c).sqrt() - c * (c / amp).acos()) / PI;
        let vib = Vibration::single_tone(80.0, [0.0, 0.0, amp]);
        let got = shift(&p, mu, &vib, peak / 1.01);
        assert!(want < -1e-4, "{want}");
        assert!((got - want).abs() < 1e-9 * want.abs(), "{got} vs {want}");
        assert_eq!(shift(&p, mu, &vib, peak * 1.01), 0.0);
    }
}
