//! Registry tests: catalogue and builder agree, validation messages, the `units`
//! filter, `reset`, and the examples of docs/effects.md.

use super::testkit::{al15, build_error, rig_with, tone, Scene};
use super::*;
use vibro_physics::fp::output_g;

/// The effects guide, whose examples must build.
const GUIDE: &str = include_str!("../../../../docs/effects.md");

#[derive(serde::Deserialize)]
struct Scenario {
    effect: Vec<EffectSpec>,
}

fn spec_of(example: &str) -> EffectSpec {
    let mut s: Scenario = toml::from_str(example).expect("example is valid TOML");
    assert_eq!(s.effect.len(), 1);
    s.effect.remove(0)
}

#[test]
fn catalogue_lists_exactly_the_kinds_build_accepts() {
    let rig = rig_with(&al15());
    let mut kinds = Vec::new();
    for info in catalogue() {
        let spec = spec_of(info.example);
        assert_eq!(spec.kind, info.kind, "example of {}", info.kind);
        let e = build_for_rig(&spec, &rig).unwrap_or_else(|e| panic!("{}: {e}", info.kind));
        assert_eq!(e.kind(), info.kind);
        assert!(!kinds.contains(&info.kind), "{} listed twice", info.kind);
        kinds.push(info.kind);
        for p in info.params {
            assert!(
                p.name.ends_with("_hz")
                    || p.name.ends_with("_g")
                    || p.name.ends_with("_s")
                    || p.name.ends_with("_deg")
                    || p.name.contains("_per_")
                    || p.name.ends_with("_rad")
                    || p.unit == "1"
                    || p.unit == "-",
                "{}.{} has no unit in its name",
                info.kind,
                p.name
            );
        }
    }
    // Every kind build accepts is in the catalogue: the error for any other kind lists
    // exactly the catalogue's kinds.
    let err = build_error("kind = \"no_such_effect\"");
    assert_eq!(
        err,
        format!(
            "effect.kind = \"no_such_effect\": unknown effect; expected one of {}",
            kinds.join(", ")
        )
    );
}

#[test]
fn guide_shows_every_example_and_parameter() {
    for info in catalogue() {
        assert!(
            GUIDE.contains(info.example),
            "docs/effects.md lacks the example of {}:\n{}",
            info.kind,
            info.example
        );
        for p in info.params {
            assert!(
                GUIDE.contains(&format!("`{}`", p.name)),
                "docs/effects.md lacks {}.{}",
                info.kind,
                p.name
            );
        }
    }
}

#[test]
fn unknown_keys_and_out_of_range_values_name_kind_key_value_and_rule() {
    let err = build_error("kind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.5\nfreq = 3");
    assert_eq!(
        err,
        "effect[mount_resonance].freq = 3: unknown parameter; expected one of freq_hz, q, axes"
    );
    let err = build_error("kind = \"mount_resonance\"\nfreq_hz = -48.0\nq = 1.5");
    assert_eq!(
        err,
        "effect[mount_resonance].freq_hz = -48.0: must be finite and 0 < freq_hz <= 1e5 Hz"
    );
    let err = build_error("kind = \"heating\"\nc_g_per_g2 = \"hot\"\ntau_s = 10");
    assert_eq!(
        err,
        "effect[heating].c_g_per_g2 = \"hot\": must be a number; must be finite and |c| <= 0.1 g/g^2"
    );
}

#[test]
fn every_problem_is_reported_at_once() {
    let spec = spec_of("[[effect]]\nkind = \"vibropendulous\"\nc_rad_per_g = 5.0\nunits = [0, 7]\ncolour = \"red\"");
    let Err(Error::Several(problems)) = build(&spec) else {
        panic!("expected several problems");
    };
    let text: Vec<String> = problems.iter().map(ToString::to_string).collect();
    assert_eq!(text.len(), 4, "{text:?}");
    assert!(text[0].starts_with("effect[vibropendulous].units = [0, 7]: must list distinct"));
    assert!(text[1].starts_with("effect[vibropendulous].c_rad_per_g = 5.0: must be finite"));
    assert!(text[2].starts_with("effect[vibropendulous].tau_s = (missing): is required"));
    assert!(text[3].starts_with("effect[vibropendulous].colour = \"red\": unknown parameter"));
}

/// A body-frame record strong enough for every effect to act (the tone pushes every
/// unit's output past `saturation`'s 15 g example range).
fn strong_record(n: usize, rate_hz: f64) -> Vec<[f64; 3]> {
    let mut s = Scene::new(rate_hz, n);
    s.tones = vec![tone(31.0, [16.0, 14.0, 16.0], [0.0, 40.0, 70.0])];
    s.bands = vec![testkit::band(20.0, 400.0, [0.01, 0.01, 0.01])];
    s.synth(&s.vibration(), 7)
}

/// Everything the hooks of one unit produce from a body-frame record: the sensor
/// reading, the vibration at the unit and the output (AL-15 FP, standard triad).
fn run_hooks(e: &mut dyn Effect, unit: usize, body: &[[f64; 3]], rate_hz: f64) -> Vec<f64> {
    let axes = TriadAxes::standard().units[unit];
    let p = al15();
    let a_l = [0.5, 0.4, 2.0];
    let mut trace = Vec::with_capacity(5 * body.len());
    for (k, chunk) in body.chunks(333).enumerate() {
        let ctx = BlockCtx {
            unit,
            t0_s: (k * 333) as f64 / rate_hz,
            dt_s: 1.0 / rate_hz,
        };
        let mut sensor: Vec<f64> = chunk.iter().map(|b| axes.ia.project(b)).collect();
        e.at_sensor(&ctx, chunk, &mut sensor);
        let mut vib: Vec<[f64; 3]> = chunk.iter().map(|b| axes.to_unit(b)).collect();
        e.at_unit_input(&ctx, &mut vib);
        let input: Vec<[f64; 3]> = vib
            .iter()
            .map(|v| [a_l[0] + v[0], a_l[1] + v[1], a_l[2] + v[2]])
            .collect();
        let mut out: Vec<f64> = input
            .iter()
            .map(|a| output_g(&p, a[0], a[1], a[2]))
            .collect();
        e.at_unit_output(&ctx, &input, &mut out);
        for i in 0..chunk.len() {
            trace.extend([sensor[i], vib[i][0], vib[i][1], vib[i][2], out[i]]);
        }
    }
    trace
}

#[test]
fn reset_clears_state() {
    let rate = 4096.0;
    let body = strong_record(4096, rate);
    let rig = rig_with(&al15());
    for info in catalogue() {
        let mut e = build_for_rig(&spec_of(info.example), &rig).unwrap();
        e.reset(rate);
        let first = run_hooks(e.as_mut(), 2, &body, rate);
        e.reset(rate);
        let second = run_hooks(e.as_mut(), 2, &body, rate);
        assert!(
            first == second,
            "{}: reset did not clear the state",
            info.kind
        );
    }
}

#[test]
fn units_filter_is_honoured_by_every_hook() {
    let rate = 4096.0;
    let body = strong_record(4096, rate);
    let p = al15();
    let rig = rig_with(&p);
    let mut plain = Vibration::single_tone(31.0, [16.0, 14.0, 16.0]);
    plain.set_random_from_psd(&[testkit::band(20.0, 400.0, [0.01, 0.01, 0.01])]);
    let bands = [testkit::band(20.0, 400.0, [0.01, 0.01, 0.01])];
    for info in catalogue() {
        let mut spec = spec_of(info.example);
        spec.units = Some(vec![1]);
        if info.scope == Scope::Body {
            let err = build_for_rig(&spec, &rig).err().map(|e| e.to_string());
            assert!(
                err.as_deref().is_some_and(|e| e.contains(".units = [1]: this effect acts on the body-frame")),
                "{}: {err:?}",
                info.kind
            );
            continue;
        }
        let mut e = build_for_rig(&spec, &rig).unwrap();
        let mut bare = build_for_rig(&spec_of(info.example), &rig).unwrap();
        let mut none = NoEffect;
        for unit in 0..3 {
            e.reset(rate);
            none.reset(rate);
            let got = run_hooks(e.as_mut(), unit, &body, rate);
            let untouched = run_hooks(&mut none, unit, &body, rate);
            if unit == 1 {
                assert!(got != untouched, "{}: does nothing on its unit", info.kind);
            } else {
                assert!(got == untouched, "{}: acts on unit {unit}", info.kind);
            }
            let ctx = MeanContext {
                unit,
                passport: &p,
                a_l_unit_g: [0.5, 0.4, 2.0],
                vibration_unit: &plain,
                psd_unit: &bands,
                internal_rate_hz: rate,
                duration_s: 100.0,
            };
            let shift = e.mean_shift_g(&ctx).unwrap();
            let factor = e.sensor_rms_factor(&ctx);
            if unit == 1 {
                bare.reset(rate);
                assert_eq!(shift, bare.mean_shift_g(&ctx).unwrap(), "{}", info.kind);
                assert_eq!(factor, bare.sensor_rms_factor(&ctx), "{}", info.kind);
            } else {
                assert_eq!(shift, 0.0, "{}: mean shift on unit {unit}", info.kind);
                assert!(factor.is_none() || factor == Some(1.0), "{}", info.kind);
            }
        }
    }
}

/// The simulator without any effect, for comparisons.
struct NoEffect;

impl Effect for NoEffect {
    fn kind(&self) -> &'static str {
        "none"
    }

    fn mean_shift_g(&self, _ctx: &MeanContext<'_>) -> Result<f64> {
        Ok(0.0)
    }
}

/// Several effects at once, in the simulator's order: every `at_unit_input` in turn,
/// then every `at_unit_output` on what reaches the unit.
struct Chain(Vec<Box<dyn Effect>>);

impl Effect for Chain {
    fn kind(&self) -> &'static str {
        "chain"
    }

    fn reset(&mut self, internal_rate_hz: f64) {
        for e in &mut self.0 {
            e.reset(internal_rate_hz);
        }
    }

    fn at_unit_input(&mut self, ctx: &BlockCtx, vib_unit_g: &mut [[f64; 3]]) {
        for e in &mut self.0 {
            e.at_unit_input(ctx, vib_unit_g);
        }
    }

    fn at_unit_output(&mut self, ctx: &BlockCtx, input_unit_g: &[[f64; 3]], out_g: &mut [f64]) {
        for e in &mut self.0 {
            e.at_unit_output(ctx, input_unit_g, out_g);
        }
    }

    fn mean_shift_g(&self, _ctx: &MeanContext<'_>) -> Result<f64> {
        Ok(0.0)
    }
}

/// A 6th-order term behind a mount resonance rectifies the amplified vibration: the
/// prediction's effects (`predict::effect_shifts_g`: the path effects first, the
/// others on what they pass) agree with the time-domain simulation of both effects
/// together, and the sum of each effect's own mean under the measured vibration (the
/// prediction before the chain) does not.
#[test]
fn effects_behind_a_resonance_act_on_the_vibration_it_passes() {
    use super::testkit::{assert_agrees, band, unit_shift};
    let p = al15();
    let mut s = Scene::new(crate::predict::INTERNAL_RATE_HZ, 1 << 15);
    s.pre_roll = 4096;
    s.a_l_g = [0.0, 0.0, 1.0];
    s.tones = vec![tone(45.0, [0.0, 0.0, 3.0], [0.0, 0.0, 0.0])];
    s.bands = vec![band(20.0, 160.0, [0.0, 0.0, 0.02])];
    s.coherence = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let rig = rig_with(&p);
    let build = |text: &str| {
        let spec: EffectSpec = toml::from_str(text).expect("effect");
        build_for_rig(&spec, &rig).expect("build")
    };
    let resonance = "kind = \"mount_resonance\"\nfreq_hz = 48.0\nq = 1.56";
    let k6 = "kind = \"high_order_nonlinearity\"\nk6_ppm_per_g5 = 0.5";
    let effects = vec![build(resonance), build(k6)];
    let vib = s.vibration();
    let ctx = s.ctx(0, &p, &vib);
    // The effects as the lab's prediction adds them (at the prediction's internal
    // rate, the scene's: it enters the resonance's digital filter).
    let shifts: f64 = crate::predict::effect_shifts_g(&effects, &p, s.a_l_g, &vib, &s.bands, 1.0)
        .expect("prediction")
        .iter()
        .map(|(_, x)| x)
        .sum();
    let separate: f64 = effects
        .iter()
        .map(|e| {
            let off = Vibration::none();
            let c0 = MeanContext {
                vibration_unit: &off,
                psd_unit: &[],
                ..ctx
            };
            e.mean_shift_g(&ctx).expect("shift") - e.mean_shift_g(&c0).expect("off")
        })
        .sum();
    let mut chain = Chain(vec![build(resonance), build(k6)]);
    let est = unit_shift(&s, &p, 0, &mut chain, 300);
    assert_agrees("resonance + k6, chained", est, shifts, 10.0);
    let z_separate = (est.mean_g - separate) / est.se_g;
    assert!(
        z_separate.abs() > 8.0,
        "the effects added each under the measured vibration ({separate:.6e} g) should \
         miss the time domain ({:.6e} +- {:.1e} g)",
        est.mean_g,
        est.se_g
    );
}

#[test]
fn the_listing_is_the_catalogue_with_named_parameter_fields() {
    let list = listing();
    assert_eq!(list.len(), catalogue().len());
    for (l, e) in list.iter().zip(catalogue()) {
        assert_eq!((l.kind, l.summary, l.hooks), (e.kind, e.summary, e.hooks));
        assert_eq!(l.params.len(), e.params.len());
        for (lp, p) in l.params.iter().zip(e.params) {
            assert_eq!(lp["name"], p.name);
            assert_eq!(lp["unit"], p.unit);
            assert_eq!(lp["meaning"], p.meaning);
            // Serialised in key order: meaning, name, unit.
            assert_eq!(
                lp.keys().copied().collect::<Vec<_>>(),
                ["meaning", "name", "unit"]
            );
        }
    }
}
