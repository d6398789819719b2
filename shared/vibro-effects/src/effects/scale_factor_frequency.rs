//! `scale_factor_frequency`: the frequency dependence of the scale factor, `lambda(w)`
//! of MODEL.md section 2, in the time domain.
//!
//! Physics: the FP of [P1 (1)-(2)] reads `k1 lambda(w) (1 + 0.5 d1A sign(a3)) a3`; the
//! simulator's per-sample FP takes `lambda = 1` (`vibro_physics::fp`). This effect makes
//! `lambda` a filter `L` on the IA acceleration: a first-order shelf with unit DC gain,
//! `L(s) = (1 + lambda_hf s/wc) / (1 + s/wc)` (corner `corner_hz`, high-frequency
//! scale-factor ratio `lambda_hf`), and adds in [`Effect::at_unit_output`] what the
//! FP lacks: `out += k1 (1 + 0.5 d1A sign(a3)) (L a3 - a3)`, with `sign(a3)` of the
//! true acceleration as [P1 (1)] writes it. `L a3 - a3 = L v3 - v3` because `L(0) = 1`
//! (the filter starts in its DC steady state). `k1`, `d1A` are the unit's passport's,
//! so the effect must be built with the passports ([`super::build_for_rig`]).
//!
//! Mean contribution: `k1 E[L v3 - v3] = 0`, so it is
//! `0.5 k1 d1A E[sign(a3) (L v3 - v3)]`, with `a3 = aL3 + sum_k A_k sin(theta_k) + x3`:
//! - a tone passes as `A_k (Re L_k sin theta_k + Im L_k cos theta_k)`, and
//!   `E[sign(a3) cos theta_k] = 0` (theta_k -> pi - theta_k leaves `a3` unchanged), so
//!   it contributes `A_k (Re L(f_k) - 1) E[sign(a3) sin theta_k]`;
//! - the random part: `y = L x3 - x3` is jointly Gaussian with `x3` (given the
//!   mixture scale), so `E[y | x3] = (cov(y, x3)/sigma3^2) x3` and it contributes
//!   `beta E[sign(a3) x3]`, `beta = int (Re L - 1) S3 df / int S3 df` (quadrature over
//!   the bands of `psd_unit`);
//! - `E[sign(m + x) x] = 2 s phi(m/s)` for `x ~ N(0, s^2)` (Stein's lemma / Price's
//!   theorem), `E[sign(m + x)] = erf(m/(s sqrt 2))`, averaged over the mixture scales;
//!   with no random part the last tone is integrated in closed form,
//!   `E[sin t sign(m + A sin t)] = (2/pi) sqrt(1 - m^2/A^2)` (the derivative in `A` of
//!   MODEL.md section 6's `E|m + A sin|`), `E[sign(m + A sin t)] = (2/pi) asin(m/A)`
//!   (both for `|m| < A`; 0 and `sign(m)` beyond);
//! - one tone on a random part: its phase by the periodic trapezoid rule, nodes
//!   doubled (from about one random scale of the tone's swing between nodes, at least
//!   16) until two estimates agree to 1e-14 or 4096 nodes; the inner means are
//!   entire in the phase, so the rule converges faster than exponentially;
//! - the other tones' phases by the midpoint rule (tensor grid of at most 65536
//!   nodes), exponentially convergent when a random part smooths the inner means.
//!
//! `L` is the exact discrete-time response at the internal rate. For real passports
//! (`d1A` of 15..25 ppm) the mean is tiny (micro-g); the tests exaggerate `d1A` to
//! 1e5 ppm so the time-domain check can resolve it. The exact model of
//! `vibro_physics::exact` treats the passport's `lambda` table differently (inside
//! `E|.|`, tones scaled by `lambda(f)`); this effect follows [P1 (1)] literally.

use super::filter::{Analog, Biquad, BiquadState};
use super::quad::{for_each_phase, normal_pdf, periodic_mean, periodic_start, points_per_tone};
use super::spectral::{band_integral, check_rate, no_spectrum, Panels};
use super::{EffectInfo, ParamInfo, Params, Scope};
use crate::effect::{BlockCtx, Effect, MeanContext};
use crate::Result;
use std::f64::consts::FRAC_2_PI;
use vibro_physics::abs_mean::ScaleMixture;

const KIND: &str = "scale_factor_frequency";
const OUTER_BUDGET: usize = 1 << 16;
const OUTER_MAX_PER_TONE: usize = 4096;
/// Fewest nodes of the doubled periodic trapezoid rule over one tone's phase on noise.
const PERIODIC_START: usize = 16;
/// Agreement of two successive periodic trapezoid estimates of the sign moments that
/// ends the doubling (dimensionless moments of order 1; once converging, each doubling
/// squares the error).
const PERIODIC_TOL: f64 = 1e-14;

/// Catalogue entry.
pub const INFO: EffectInfo = EffectInfo {
    kind: KIND,
    summary: "frequency-dependent scale factor lambda(w) as a first-order shelf on the IA \
              vibration: out += k1 (1 + 0.5 d1A sign(a3)) (L a3 - a3)",
    params: &[
        ParamInfo {
            name: "corner_hz",
            unit: "Hz",
            meaning: "corner (pole) frequency of the shelf; required, 0 < f <= 1e6",
        },
        ParamInfo {
            name: "lambda_hf",
            unit: "1",
            meaning: "scale-factor ratio lambda well above the corner (lambda(0) = 1); \
                      required, 0 < lambda_hf <= 10",
        },
    ],
    hooks: "at_unit_output (needs the passports: build_for_rig)",
    scope: Scope::Unit,
    example: r#"[[effect]]
kind = "scale_factor_frequency"
corner_hz = 800.0
lambda_hf = 1.2
"#,
    build,
};

fn build(p: &mut Params<'_>) -> Result<Box<dyn Effect>> {
    let corner_hz = p.required(
        "corner_hz",
        "must be finite and 0 < corner_hz <= 1e6 Hz",
        |f| f > 0.0 && f <= 1e6,
    );
    let lambda_hf = p.required("lambda_hf", "must be finite and 0 < lambda_hf <= 10", |l| {
        l > 0.0 && l <= 10.0
    });
    let passports = p.rig().passports;
    if passports.is_none() {
        p.problem(
            "",
            "no passports".into(),
            "needs the units' passports (k1, d1A) for its time-domain term: build it with \
             effects::build_for_rig",
        );
    }
    let k1_d1a = passports.map_or([(1.0, 0.0); 3], |ps| ps.map(|p| (p.k1, p.d1a)));
    Ok(Box::new(ScaleFactorFrequency {
        corner_hz,
        analog: Analog::shelf1(corner_hz, lambda_hf),
        filter: Biquad::IDENTITY,
        state: Default::default(),
        k1_d1a,
    }))
}

#[derive(Debug, Clone)]
struct ScaleFactorFrequency {
    corner_hz: f64,
    analog: Analog,
    filter: Biquad,
    /// Per unit.
    state: [BiquadState; 3],
    /// Per unit: `(k1, d1A)` of its passport.
    k1_d1a: [(f64, f64); 3],
}

impl ScaleFactorFrequency {
    fn lambda_filter(&self, rate_hz: f64) -> Biquad {
        Biquad::bilinear(&self.analog, rate_hz, self.corner_hz)
    }
}

impl Effect for ScaleFactorFrequency {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn reset(&mut self, internal_rate_hz: f64) {
        self.filter = self.lambda_filter(internal_rate_hz);
        self.state = Default::default();
    }

    fn at_unit_output(&mut self, ctx: &BlockCtx, input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        let (Some(state), Some(&(k1, d1a))) =
            (self.state.get_mut(ctx.unit), self.k1_d1a.get(ctx.unit))
        else {
            return;
        };
        for (a, o) in input_unit_g.iter().zip(out_g.iter_mut()) {
            let a3 = a[2];
            let sign = vibro_physics::fp::asymmetry_sign(a3);
            let la3 = state.step_primed(&self.filter, a3);
            *o += k1 * (1.0 + 0.5 * d1a * sign) * (la3 - a3);
        }
    }

    fn mean_shift_g(&self, ctx: &MeanContext<'_>) -> Result<f64> {
        let rate = ctx.internal_rate_hz;
        check_rate(KIND, rate)?;
        let lf = self.lambda_filter(rate);
        let vib = ctx.vibration_unit;
        let tones: Vec<(f64, f64)> = vib
            .tones()
            .iter()
            .filter(|t| t.amplitude_g[2] > 0.0)
            .map(|t| (t.amplitude_g[2], lf.response(t.freq_hz, rate).re - 1.0))
            .collect();
        let sigma3 = vib.sigma_g(2);
        let beta = if sigma3 > 0.0 {
            // Panels an eighth of the corner there, an eighth of the distance from it
            // away (the response of the first-order lambda(w) changes on the scale of
            // its distance from the pole): uniform panels of corner/8 took 160,000 per
            // 2 kHz band for a 0.1 Hz corner, a second per evaluation of a flight log.
            let (num, den) = band_integral(
                ctx.psd_unit,
                |b| b.psd_g2_per_hz[2].max(0.0),
                |f| lf.response(f, rate).re - 1.0,
                Panels::Graded {
                    centre_hz: self.corner_hz,
                    finest_hz: self.corner_hz / 8.0,
                },
            );
            if den.is_nan() || den <= 0.0 {
                return Err(no_spectrum(
                    KIND,
                    format!("sigma3^2 = {} g^2", sigma3 * sigma3),
                ));
            }
            num / den
        } else {
            0.0
        };
        let amplitudes: Vec<f64> = tones.iter().map(|t| t.0).collect();
        let mixture = ScaleMixture::for_kurtosis(vib.kurtosis[2]);
        let m = sign_moments(ctx.a_l_unit_g[2], &amplitudes, sigma3, &mixture);
        let tone_part: f64 = tones
            .iter()
            .zip(&m.tone)
            .map(|((a, re_l_minus_1), s)| a * re_l_minus_1 * s)
            .sum();
        let p = ctx.passport;
        Ok(0.5 * p.k1 * p.d1a * (tone_part + beta * m.random))
    }
}

/// `E[sign(a3) sin theta_k]` per tone and `E[sign(a3) x3]`.
#[derive(Debug, Clone, PartialEq)]
struct SignMoments {
    tone: Vec<f64>,
    random: f64,
}

/// The moments of `sign(a3)` with its components, `a3 = a_l + sum A_k sin theta_k +
/// sigma sqrt(w) z` (module docs).
fn sign_moments(a_l: f64, amplitudes: &[f64], sigma: f64, mixture: &ScaleMixture) -> SignMoments {
    let n = amplitudes.len();
    let mut out = SignMoments {
        tone: vec![0.0; n],
        random: 0.0,
    };
    let scales: Vec<(f64, f64)> = mixture
        .prob
        .iter()
        .zip(mixture.scale)
        .filter(|(p, _)| **p > 0.0)
        .map(|(p, w)| (*p, sigma * w.sqrt()))
        .collect();
    let random = sigma > 0.0;
    if random && n == 1 {
        // One tone on noise: the inner means are smooth (entire) in the tone's phase,
        // so the periodic trapezoid rule, doubled until it agrees with itself, replaces
        // the fixed grid (module docs).
        let narrowest = scales.iter().map(|(_, s)| *s).fold(f64::INFINITY, f64::min);
        let start = periodic_start(amplitudes[0], narrowest, PERIODIC_START, OUTER_MAX_PER_TONE);
        let [tone, own] = periodic_mean(
            &mut |s, _| {
                let m = a_l + amplitudes[0] * s;
                let (sign_mean, own) = gaussian_sign_moments(m, &scales);
                [s * sign_mean, own]
            },
            start,
            OUTER_MAX_PER_TONE,
            PERIODIC_TOL,
        );
        out.tone[0] = tone;
        out.random = own;
        return out;
    }
    let n_outer = if random { n } else { n.saturating_sub(1) };
    let per_tone = points_per_tone(n_outer, OUTER_BUDGET, OUTER_MAX_PER_TONE);
    for_each_phase(n_outer, per_tone, |sines, _, weight| {
        let m = a_l
            + amplitudes
                .iter()
                .zip(sines)
                .map(|(a, s)| a * s)
                .sum::<f64>();
        // Inner averages: E[sign(m + inner)] and the inner component's own moment.
        let (sign_mean, own) = if random {
            gaussian_sign_moments(m, &scales)
        } else if let Some(&a) = amplitudes.last() {
            let r = (m / a).clamp(-1.0, 1.0);
            (
                FRAC_2_PI * r.asin(),
                FRAC_2_PI * (1.0 - r * r).max(0.0).sqrt(),
            )
        } else {
            (m.signum(), 0.0)
        };
        for (t, s) in out.tone.iter_mut().zip(sines) {
            *t += weight * s * sign_mean;
        }
        if random {
            out.random += weight * own;
        } else if let Some(last) = out.tone.last_mut() {
            *last += weight * own;
        }
    });
    out
}

/// `(E[sign(m + x)], E[sign(m + x) x])` for `x` a scale mixture of centred Gaussians,
/// `scales` as (probability, standard deviation): `erf(m / (s sqrt 2))` and
/// `2 s phi(m/s)` per scale (module docs).
fn gaussian_sign_moments(m: f64, scales: &[(f64, f64)]) -> (f64, f64) {
    scales.iter().fold((0.0, 0.0), |(sm, xm), &(p, s)| {
        // erf(m / (s sqrt 2)) = 1 - 2 Phi(-m/s).
        let erf = 1.0 - 2.0 * vibro_physics::abs_mean::normal_cdf(-m / s);
        (sm + p * erf, xm + p * 2.0 * s * normal_pdf(m / s))
    })
}

#[cfg(test)]
mod tests {
    use super::super::testkit::{
        al15_spec, assert_agrees, band, build_toml, passport, tone, unit_shift, Scene,
    };
    use super::*;

    #[test]
    fn sign_moments_match_brute_force_phase_averages() {
        // One tone and Gaussian noise: E[sign(a) sin t], E[sign(a) x] by a fine grid.
        let gauss = ScaleMixture::for_kurtosis(3.0);
        let m = sign_moments(0.4, &[1.5], 0.6, &gauss);
        let (n, nz) = (2000, 4000);
        let (mut st, mut sx) = (0.0, 0.0);
        for i in 0..n {
            let th = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
            for k in 0..nz {
                let z = -9.0 + 18.0 * (k as f64 + 0.5) / nz as f64;
                let w = normal_pdf(z) * 18.0 / nz as f64 / n as f64;
                let a = 0.4 + 1.5 * th.sin() + 0.6 * z;
                let sg = a.signum();
                st += w * sg * th.sin();
                sx += w * sg * 0.6 * z;
            }
        }
        // The brute-force midpoint rule in z errs by O(h) at the sign jump (h = 4.5e-3).
        assert!((m.tone[0] - st).abs() < 1e-5, "{} vs {st}", m.tone[0]);
        assert!((m.random - sx).abs() < 1e-5, "{} vs {sx}", m.random);
        // Two tones, no noise: the inner tone in closed form.
        let m = sign_moments(0.3, &[1.0, 0.7], 0.0, &gauss);
        let mut want = [0.0; 2];
        let n = 3000;
        for i in 0..n {
            let t1 = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
            for k in 0..n {
                let t2 = std::f64::consts::TAU * (k as f64 + 0.5) / n as f64;
                let sg = (0.3 + t1.sin() + 0.7 * t2.sin()).signum();
                want[0] += sg * t1.sin() / (n * n) as f64;
                want[1] += sg * t2.sin() / (n * n) as f64;
            }
        }
        for (k, (got, want)) in m.tone.iter().zip(want).enumerate() {
            assert!((got - want).abs() < 2e-4, "tone {k}: {got} vs {want}");
        }
    }

    /// One tone on noise, narrow and wide beside the tone (the doubled trapezoid rule):
    /// the closed-form inner moments averaged over 65536 midpoint phases.
    #[test]
    fn one_tone_on_noise_matches_a_fine_phase_grid() {
        let gauss = ScaleMixture::for_kurtosis(3.0);
        for (a_l, amp, sigma) in [(0.4, 1.5, 0.6), (-0.3, 3.0, 0.02), (0.1, 0.2, 1.0)] {
            let m = sign_moments(a_l, &[amp], sigma, &gauss);
            let n = 1 << 16;
            let (mut tone, mut own) = (0.0, 0.0);
            for k in 0..n {
                let s = (std::f64::consts::TAU * (k as f64 + 0.5) / n as f64).sin();
                let mean = a_l + amp * s;
                let erf = 1.0 - 2.0 * vibro_physics::abs_mean::normal_cdf(-mean / sigma);
                tone += s * erf / n as f64;
                own += 2.0 * sigma * normal_pdf(mean / sigma) / n as f64;
            }
            assert!(
                (m.tone[0] - tone).abs() < 1e-12,
                "A {amp}: {} vs {tone}",
                m.tone[0]
            );
            assert!(
                (m.random - own).abs() < 1e-12,
                "A {amp}: {} vs {own}",
                m.random
            );
        }
    }

    /// `d1A` exaggerated to 1e5 ppm (real units: 15..25 ppm give micro-g means).
    #[test]
    fn mean_formula_matches_time_domain() {
        let mut spec = al15_spec();
        spec.d1a_ppm = 1e5;
        let p = passport(&spec);
        let mut s = Scene::new(2048.0, 1 << 14);
        s.pre_roll = 256;
        s.a_l_g = [0.0, 0.0, 0.5];
        s.tones = vec![
            tone(41.3, [0.0, 0.0, 2.0], [0.0; 3]),
            tone(97.9, [0.0, 0.0, 0.6], [0.0; 3]),
        ];
        s.bands = vec![band(20.0, 200.0, [0.0, 0.0, 0.25 / 180.0])];
        let mut e = build_toml(
            "kind = \"scale_factor_frequency\"\ncorner_hz = 60.0\nlambda_hf = 1.5",
            &p,
        );
        let vib = s.vibration();
        let formula = e.mean_shift_g(&s.ctx(2, &p, &vib)).unwrap();
        let est = unit_shift(&s, &p, 2, e.as_mut(), 1500);
        assert_agrees("scale_factor_frequency (d1A = 1e5 ppm)", est, formula, 10.0);
    }

    #[test]
    fn needs_the_passports() {
        let spec: crate::effects::EffectSpec =
            toml::from_str("kind = \"scale_factor_frequency\"\ncorner_hz = 60.0\nlambda_hf = 1.5")
                .unwrap();
        let err = crate::effects::build(&spec)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            err.starts_with("effect[scale_factor_frequency] = no passports: needs"),
            "{err}"
        );
    }
}
