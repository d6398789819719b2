//! The extended model's vibration error for one condition.
//!
//! `VE = VE_base(v_true) + sum_p [VE_exact(v_p) - VE_exact(v_(p-1))]
//!       + sum_e [m_e(v_unit) - m_e(0)]`, where
//!
//! - `v_true` is the vibration at the unit: the measured one with its IA amplitudes and
//!   RMS (the unit's vibration sensor is along IA) divided by the product of the sensor
//!   effects' RMS factors (`Effect::sensor_rms_factor`, e.g. a sensor gain error);
//! - `VE_base` is MODEL.md section 6 (`exact`) or section 5 (`paper`, `as-published`),
//!   with the passport's `lambda(w)` taken as 1, as in the simulator (the frequency
//!   dependence of the scale factor is the `scale_factor_frequency` effect);
//! - the effects on the vibration path `p` (`Effect::on_vibration_path`: a mount
//!   resonance, the unit's own response) pass `v_(p-1)` on as `v_p`, in order
//!   (`v_0 = v_true`), each adding its documented mean change; `v_unit` is what the
//!   last passes: as in the simulator, where every `at_unit_input` runs before the
//!   conversion and `at_unit_output`;
//! - `m_e(v)` is every other effect's documented mean contribution (docs/effects.md) under
//!   vibration `v`, and `m_e(0)` the same without vibration: a campaign measures the
//!   VE as the vibrating record minus the still ones (MODEL.md section 8), so an
//!   effect's static part cancels;
//! - an effect that clips the whole output (`saturation`,
//!   `Effect::mean_shift_over_g`) clips the FP plus the memoryless output terms of the
//!   unit's other effects (`Effect::output_terms`: k6/k7, anisoelastic, heating's
//!   mean bias, vibropendulous's `c HP[a3] a2` with `HP[a3]` per tone exactly and
//!   its random part by its regression on IA's), whatever their order, as the servo's
//!   range bounds everything the unit outputs; its `m_e` is `E[clip(y) - y]` with that
//!   `y`, so that the total is `E[clip(y)] - E[FP]`. `scale_factor_frequency` stays
//!   outside the clip: a departure from the simulator, which clips whatever is listed
//!   before `saturation`.

use crate::effect::OutputTerms;
use crate::model::BaseMode;
use crate::{Effect, Error, MeanContext, Result};
use serde::Serialize;
use vibro_physics::exact::exact_ve;
use vibro_physics::passport::Passport;
use vibro_physics::ve::{published, Constants};
use vibro_physics::vibration::{PsdBand, Vibration};

/// Internal sample rate the effects' discrete-time formulas assume (the simulator's
/// default, `rates.internal_hz`), Hz.
pub const INTERNAL_RATE_HZ: f64 = 25_600.0;

/// The extended model's prediction for one condition.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Prediction {
    /// VE of the base model under the true vibration, g.
    pub base_ve_g: f64,
    /// Each non-sensor effect's VE change, g, in model order.
    pub effects: Vec<(String, f64)>,
    /// Product of the sensor effects' RMS factors (1 without any).
    pub sensor_rms_factor: f64,
    /// The total, g.
    pub ve_g: f64,
}

/// The unit passport as the lab uses it: `lambda(w)` dropped (see the module doc).
pub fn flat_passport(p: &Passport) -> Result<Passport> {
    let mut spec = p.to_spec();
    spec.lambda.clear();
    Passport::try_from_spec(&spec).map_err(|e| Error::Predict {
        what: format!("passport {}", p.id()),
        reason: e.to_string(),
    })
}

/// The base VE under `vib`, g.
pub fn base_ve_g(
    mode: BaseMode,
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    vib: &Vibration,
) -> Result<f64> {
    Ok(match mode {
        BaseMode::Exact => {
            exact_ve(passport, a_l_unit_g, vib)
                .map_err(|e| Error::Predict {
                    what: "exact VE".into(),
                    reason: e.to_string(),
                })?
                .total_g
        }
        BaseMode::Paper | BaseMode::AsPublished => {
            published(passport, a_l_unit_g, vib, Constants::PAPER).total_g
        }
    })
}

/// `vib` as the unit sees it when its vibration sensor (along IA) reads `factor` times
/// the truth: the IA amplitude of every tone and the IA RMS divided by `factor` (the
/// IA covariances by `factor`, the IA variance by `factor^2`); OA and PA untouched.
pub fn scaled_vibration(vib: &Vibration, factor: f64) -> Vibration {
    if factor == 1.0 {
        return *vib;
    }
    let mut out = *vib;
    out.clear_tones();
    for t in vib.tones() {
        let mut t = *t;
        t.amplitude_g[2] /= factor;
        // A tone that fitted before fits after.
        let _ = out.push_tone(t);
    }
    for j in 0..3 {
        out.covariance_g2[2][j] /= factor;
        out.covariance_g2[j][2] /= factor;
    }
    out
}

pub(crate) fn scaled_psd(psd: &[PsdBand], factor: f64) -> Vec<PsdBand> {
    psd.iter()
        .map(|b| PsdBand {
            psd_g2_per_hz: [
                b.psd_g2_per_hz[0],
                b.psd_g2_per_hz[1],
                b.psd_g2_per_hz[2] / (factor * factor),
            ],
            ..*b
        })
        .collect()
}

/// The context an effect's mean formula is evaluated in: unit 0 of the lab's frame.
fn context<'a>(
    passport: &'a Passport,
    a_l_unit_g: [f64; 3],
    vibration_unit: &'a Vibration,
    psd_unit: &'a [PsdBand],
    duration_s: f64,
) -> MeanContext<'a> {
    MeanContext {
        unit: 0,
        passport,
        a_l_unit_g,
        vibration_unit,
        psd_unit,
        internal_rate_hz: INTERNAL_RATE_HZ,
        duration_s,
    }
}

/// Product of the sensor effects' RMS factors under the measured vibration.
pub fn sensor_rms_factor(
    effects: &[Box<dyn Effect>],
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    vibration_unit: &Vibration,
    psd_unit: &[PsdBand],
) -> f64 {
    let ctx = context(
        passport,
        a_l_unit_g,
        vibration_unit,
        psd_unit,
        f64::INFINITY,
    );
    effects
        .iter()
        .filter_map(|e| e.sensor_rms_factor(&ctx))
        .product()
}

/// The non-sensor effects' VE changes under the true vibration `vib_true`, in order.
///
/// The effects on the vibration path (`Effect::on_vibration_path`: a mount resonance,
/// the unit's own response) act first, in order, each on what the one before passed
/// (its change: its own mean formula there); every other effect then acts on the
/// vibration that reaches the unit, as in the simulator, where `at_unit_input` runs
/// before `at_unit_output` (a 6th-order term behind a resonance rectifies the
/// amplified vibration, not the measured one).
pub fn effect_shifts_g(
    effects: &[Box<dyn Effect>],
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    vib_true: &Vibration,
    psd_true: &[PsdBand],
    duration_s: f64,
) -> Result<Vec<(String, f64)>> {
    let none = Vibration::none();
    let off = context(passport, a_l_unit_g, &none, &[], duration_s);
    let fail = |e: &dyn Effect, err: Error| Error::Predict {
        what: format!("effect {}", e.kind()),
        reason: err.to_string(),
    };
    let mut shifts: Vec<Option<f64>> = vec![None; effects.len()];
    let mut vib = *vib_true;
    let mut psd = psd_true.to_vec();
    for (k, e) in effects.iter().enumerate() {
        let on = context(passport, a_l_unit_g, &vib, &psd, duration_s);
        if e.sensor_rms_factor(&on).is_some() || !e.on_vibration_path() {
            continue;
        }
        // A path effect's change is the exact model's (MODEL.md 6) at what it passes
        // minus at what it receives: its own mean formula (`exact_shift`), from the
        // one quadrature that also gives the vibration passed on.
        let Some(t) = e.transmitted(&on) else {
            continue;
        };
        let (v, p) = t.map_err(|x| fail(e.as_ref(), x))?;
        let exact = |x: &Vibration| {
            exact_ve(passport, a_l_unit_g, x)
                .map(|r| r.total_g)
                .map_err(|err| Error::Predict {
                    what: format!("effect {}", e.kind()),
                    reason: err.to_string(),
                })
        };
        shifts[k] = Some(exact(&v)? - exact(&vib)?);
        vib = v;
        psd = p;
    }
    let on = context(passport, a_l_unit_g, &vib, &psd, duration_s);
    // What a clip (saturation) clips besides the FP: every memoryless output term of
    // the unit's other effects, whatever their order in the model.
    let terms = |ctx: &MeanContext<'_>| {
        effects
            .iter()
            .enumerate()
            .filter(|(k, e)| shifts[*k].is_none() && e.sensor_rms_factor(&on).is_none())
            .filter_map(|(_, e)| e.output_terms(ctx))
            .fold(OutputTerms::default(), OutputTerms::plus)
    };
    // Only a clip reads them (a vibropendulous term's integrates over the bands).
    let (terms_on, terms_off) = if effects.iter().any(|e| e.clips_output()) {
        (terms(&on), terms(&off))
    } else {
        Default::default()
    };
    let mut out = Vec::new();
    for (k, e) in effects.iter().enumerate() {
        if e.sensor_rms_factor(&on).is_some() {
            continue;
        }
        let shift = match shifts[k] {
            Some(s) => s,
            None => match e
                .clips_output()
                .then(|| e.mean_shift_over_g(&on, &terms_on))
                .flatten()
            {
                Some(with) => {
                    let without = e
                        .mean_shift_over_g(&off, &terms_off)
                        .unwrap_or_else(|| e.mean_shift_g(&off));
                    with.map_err(|x| fail(e.as_ref(), x))?
                        - without.map_err(|x| fail(e.as_ref(), x))?
                }
                None => {
                    e.mean_shift_g(&on).map_err(|x| fail(e.as_ref(), x))?
                        - e.mean_shift_g(&off).map_err(|x| fail(e.as_ref(), x))?
                }
            },
        };
        out.push((e.kind().to_string(), shift));
    }
    Ok(out)
}

/// The vibration and band PSD reaching the unit: `vib_true` through the effects on
/// the vibration path, in order ([`effect_shifts_g`]).
pub fn unit_vibration(
    effects: &[Box<dyn Effect>],
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    vib_true: &Vibration,
    psd_true: &[PsdBand],
) -> Result<(Vibration, Vec<PsdBand>)> {
    let mut vib = *vib_true;
    let mut psd = psd_true.to_vec();
    for e in effects {
        let on = context(passport, a_l_unit_g, &vib, &psd, f64::INFINITY);
        if e.sensor_rms_factor(&on).is_some() {
            continue;
        }
        if let Some(t) = e.transmitted(&on) {
            let (v, p) = t.map_err(|err| Error::Predict {
                what: format!("effect {}", e.kind()),
                reason: err.to_string(),
            })?;
            vib = v;
            psd = p;
        }
    }
    Ok((vib, psd))
}

/// The vibration the unit really sees: the measured one with the sensor effects'
/// RMS factor taken out (module doc).
#[derive(Debug, Clone)]
pub struct TrueVibration {
    /// Product of the sensor effects' RMS factors (1 without any).
    pub sensor_rms_factor: f64,
    pub vibration: Vibration,
    pub psd: Vec<PsdBand>,
}

/// [`TrueVibration`] of a measured vibration under `effects`.
pub fn true_vibration(
    effects: &[Box<dyn Effect>],
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    vibration_unit: &Vibration,
    psd_unit: &[PsdBand],
) -> Result<TrueVibration> {
    let factor = sensor_rms_factor(effects, passport, a_l_unit_g, vibration_unit, psd_unit);
    if !(factor.is_finite() && factor > 0.0) {
        return Err(Error::Predict {
            what: "sensor effects".into(),
            reason: format!("RMS factor {factor}: must be finite and > 0"),
        });
    }
    Ok(TrueVibration {
        sensor_rms_factor: factor,
        vibration: scaled_vibration(vibration_unit, factor),
        psd: scaled_psd(psd_unit, factor),
    })
}

/// The extended model's VE for one unit under the true vibration `truth`.
pub fn predict_ve_true(
    mode: BaseMode,
    effects: &[Box<dyn Effect>],
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    truth: &TrueVibration,
    duration_s: f64,
) -> Result<Prediction> {
    let base_ve_g = base_ve_g(mode, passport, a_l_unit_g, &truth.vibration)?;
    let effects = effect_shifts_g(
        effects,
        passport,
        a_l_unit_g,
        &truth.vibration,
        &truth.psd,
        duration_s,
    )?;
    let ve_g = base_ve_g + effects.iter().map(|(_, s)| s).sum::<f64>();
    Ok(Prediction {
        base_ve_g,
        effects,
        sensor_rms_factor: truth.sensor_rms_factor,
        ve_g,
    })
}

/// The extended model's VE for one unit (module doc). `passport` should be flat
/// ([`flat_passport`]) to agree with the simulator.
pub fn predict_ve(
    mode: BaseMode,
    effects: &[Box<dyn Effect>],
    passport: &Passport,
    a_l_unit_g: [f64; 3],
    vibration_unit: &Vibration,
    psd_unit: &[PsdBand],
    duration_s: f64,
) -> Result<Prediction> {
    let truth = true_vibration(effects, passport, a_l_unit_g, vibration_unit, psd_unit)?;
    predict_ve_true(mode, effects, passport, a_l_unit_g, &truth, duration_s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::build_effects;

    fn al15() -> Passport {
        flat_passport(&vibro_config::resolve_passport("AL-15").unwrap()).unwrap()
    }

    fn table(text: &str) -> toml::Table {
        toml::from_str(text).unwrap()
    }

    /// The VE change of the effect `kind` in a prediction.
    fn share(p: &Prediction, kind: &str) -> f64 {
        p.effects
            .iter()
            .find(|(k, _)| k == kind)
            .map(|(_, s)| *s)
            .unwrap()
    }

    /// anisoelastic: `k_ae E[v1 v2]` with `E[v1 v2] = 0.5 aB1 aB2 cos(phi1 - phi2) +
    /// cov12` (docs/effects.md); its static `k_ae aL1 aL2` cancels.
    #[test]
    fn an_effect_adds_its_closed_form_ve_change_to_the_base() {
        let p = al15();
        let mut vib = Vibration::single_tone(30.0, [1.2, 0.8, 0.42]);
        vib.covariance_g2[0][1] = 0.05;
        vib.covariance_g2[1][0] = 0.05;
        vib.covariance_g2[0][0] = 0.3;
        vib.covariance_g2[1][1] = 0.2;
        let a_l = [0.3, 0.5, 1.0];
        let k_ae = 2.0e-5;
        let effects = build_effects(
            &[table(&format!(
                "kind = \"anisoelastic\"\nk_ae_per_g = {k_ae:e}"
            ))],
            &p,
        )
        .unwrap();
        let with = predict_ve(BaseMode::Exact, &effects, &p, a_l, &vib, &[], 300.0).unwrap();
        let base = exact_ve(&p, a_l, &vib).unwrap().total_g;
        let want = k_ae * (0.5 * 1.2 * 0.8 + 0.05);
        assert!((with.base_ve_g - base).abs() < 1e-18);
        assert!(
            (with.ve_g - base - want).abs() < 1e-15,
            "{} vs {}",
            with.ve_g - base,
            want
        );
    }

    /// axis_phase is on the vibration path: the anisoelastic product sees the shifted
    /// phases, in either order of the two in the model, `k_ae 0.5 aB1 aB2 cos(phi1 -
    /// phi2 + d1 - d2)` (`build_effects`' frame: OA on body x, PA on y, IA on z),
    /// and axis_phase's own change is the exact model's with the phases shifted.
    #[test]
    fn the_anisoelastic_term_sees_the_shifted_phases() {
        let p = al15();
        let mut vib = Vibration::none();
        let tone = |phases: [f64; 3]| vibro_physics::vibration::Tone {
            freq_hz: 30.0,
            amplitude_g: [1.2, 0.8, 1.5],
            phase_rad: phases,
        };
        vib.push_tone(tone([0.3, -0.5, 0.1])).unwrap();
        let a_l = [0.3, 0.5, 1.0];
        let k_ae = 2.0e-5;
        let (dy, dz) = (70f64.to_radians(), -40f64.to_radians());
        let ae = format!("kind = \"anisoelastic\"\nk_ae_per_g = {k_ae:e}");
        let phase = "kind = \"axis_phase\"\nphase_y_deg = 70.0\nphase_z_deg = -40.0";
        let mut shifted = Vibration::none();
        shifted.push_tone(tone([0.3, -0.5 + dy, 0.1 + dz])).unwrap();
        let base = exact_ve(&p, a_l, &vib).unwrap().total_g;
        let want_phase = exact_ve(&p, a_l, &shifted).unwrap().total_g - base;
        let want_ae = k_ae * 0.5 * 1.2 * 0.8 * (0.3 - (-0.5 + dy)).cos();
        assert!(
            (want_ae - k_ae * 0.5 * 1.2 * 0.8 * 0.8f64.cos()).abs() > 1e-6,
            "the offsets must move the product"
        );
        for order in [[ae.as_str(), phase], [phase, ae.as_str()]] {
            let effects = build_effects(&[table(order[0]), table(order[1])], &p).unwrap();
            let got = predict_ve(BaseMode::Exact, &effects, &p, a_l, &vib, &[], 300.0).unwrap();
            let by_kind = |k: &str| share(&got, k);
            assert!(
                (by_kind("anisoelastic") - want_ae).abs() < 1e-18,
                "{order:?}: {} vs {want_ae}",
                by_kind("anisoelastic")
            );
            assert!((by_kind("axis_phase") - want_phase).abs() < 1e-15);
            assert!((got.ve_g - base - want_ae - want_phase).abs() < 1e-15);
        }
    }

    /// saturation clips what the 6th-order term adds, in either order of the two:
    /// `E[clip(FP + k6 a3^6)] - E[FP + k6 a3^6]` against the same mean over 200,000
    /// phases of the tone (midpoint rule; the clipped excess has square-root kinks, so
    /// it converges as n^-1.5: about 1e-9 relative here). Without the 6th-order term
    /// nothing reaches the range and the clip alone changes nothing.
    #[test]
    fn saturation_clips_the_sixth_order_term() {
        let p = al15();
        let (a_l, amp, r) = ([0.0, 0.0, 1.0], 3.0, 4.2);
        let vib = Vibration::single_tone(40.0, [0.0, 0.0, amp]);
        let k6_ppm = 100.0;
        let k6 = k6_ppm * 1e-6;
        let n = 200_000;
        let fp_mean = |with_k6: bool| {
            (0..n)
                .map(|i| {
                    let th = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
                    let a3 = a_l[2] + amp * th.sin();
                    let y = vibro_physics::fp::output_g(&p, 0.0, 0.0, a3)
                        + if with_k6 { k6 * a3.powi(6) } else { 0.0 };
                    y.clamp(-r, r) - y
                })
                .sum::<f64>()
                / n as f64
        };
        let want_clip = fp_mean(true);
        assert!(want_clip < -1e-3, "{want_clip}");
        assert_eq!(fp_mean(false), 0.0);
        let sat = format!("kind = \"saturation\"\nrange_g = {r}");
        let high = format!("kind = \"high_order_nonlinearity\"\nk6_ppm_per_g5 = {k6_ppm}");
        let alone = build_effects(&[table(&sat)], &p).unwrap();
        let got = predict_ve(BaseMode::Exact, &alone, &p, a_l, &vib, &[], 300.0).unwrap();
        assert_eq!(got.effects[0].1, 0.0);
        for order in [[sat.as_str(), high.as_str()], [high.as_str(), sat.as_str()]] {
            let effects = build_effects(&[table(order[0]), table(order[1])], &p).unwrap();
            let got = predict_ve(BaseMode::Exact, &effects, &p, a_l, &vib, &[], 300.0).unwrap();
            let clip = share(&got, "saturation");
            assert!(
                (clip - want_clip).abs() < 1e-7 * want_clip.abs(),
                "{order:?}: {clip} vs {want_clip}"
            );
        }
    }

    /// saturation clips the vibropendulous term too: `y = FP(a) + c HP[a3] a2` on a
    /// tone, HP the bilinear image of `s tau / (1 + s tau)` at the internal rate, by its
    /// closed form `H = j K tau / (1 + j K tau)`, `K = 2 fs tan(pi f / fs)`, against
    /// the phase average of `clip(y) - y` over 200,000 phases.
    #[test]
    fn saturation_clips_the_vibropendulous_term() {
        let p = al15();
        let (a_l, r) = ([0.0, 0.5, 1.0], 3.99);
        let (f, amp2, amp3, phi2) = (40.0, 2.0, 3.0, 0.4);
        let (c, tau) = (0.01, 0.002);
        let mut vib = Vibration::none();
        vib.push_tone(vibro_physics::vibration::Tone {
            freq_hz: f,
            amplitude_g: [0.0, amp2, amp3],
            phase_rad: [0.0, phi2, 0.0],
        })
        .unwrap();
        let k = 2.0 * INTERNAL_RATE_HZ * (std::f64::consts::PI * f / INTERNAL_RATE_HZ).tan();
        let (re, im) = {
            // j k tau / (1 + j k tau) = (k tau)^2 / (1 + (k tau)^2) + j k tau / (1 + (k tau)^2)
            let x = k * tau;
            (x * x / (1.0 + x * x), x / (1.0 + x * x))
        };
        let n = 200_000;
        let mean = |with_vp: bool| {
            (0..n)
                .map(|i| {
                    let th = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
                    let a2 = a_l[1] + amp2 * (th + phi2).sin();
                    let a3 = a_l[2] + amp3 * th.sin();
                    let h = amp3 * (re * th.sin() + im * th.cos());
                    let y = vibro_physics::fp::output_g(&p, 0.0, a2, a3)
                        + if with_vp { c * h * a2 } else { 0.0 };
                    y.clamp(-r, r) - y
                })
                .sum::<f64>()
                / n as f64
        };
        let (want, without) = (mean(true), mean(false));
        assert!(
            (want - without).abs() > 1e-4 * want.abs(),
            "{want} vs {without}"
        );
        let sat = format!("kind = \"saturation\"\nrange_g = {r}");
        let vp = format!("kind = \"vibropendulous\"\nc_rad_per_g = {c}\ntau_s = {tau}");
        let effects = build_effects(&[table(&vp), table(&sat)], &p).unwrap();
        let got = predict_ve(BaseMode::Exact, &effects, &p, a_l, &vib, &[], 300.0).unwrap();
        let clip = share(&got, "saturation");
        assert!(
            (clip - want).abs() < 1e-6 * want.abs(),
            "{clip} vs {want} (without the term {without})"
        );
    }

    /// A sensor gain error `g` makes the sensors read `(1 + g)` times the vibration:
    /// the model predicts the VE of the measured amplitude divided by `1 + g`.
    #[test]
    fn a_sensor_gain_error_scales_the_vibration_the_model_sees() {
        let p = al15();
        let vib = Vibration::single_tone(30.0, [0.0, 0.0, 2.0]);
        let effects =
            build_effects(&[table("kind = \"sensor_error\"\ngain_error = 0.05")], &p).unwrap();
        let got = predict_ve(
            BaseMode::Paper,
            &effects,
            &p,
            [0.0, 0.0, 1.0],
            &vib,
            &[],
            1.0,
        )
        .unwrap();
        let truth = Vibration::single_tone(30.0, [0.0, 0.0, 2.0 / 1.05]);
        let want = published(&p, [0.0, 0.0, 1.0], &truth, Constants::PAPER).total_g;
        assert!((got.sensor_rms_factor - 1.05).abs() < 1e-15);
        assert!((got.ve_g - want).abs() < 1e-15, "{} vs {want}", got.ve_g);
    }
}
