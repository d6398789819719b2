//! Helpers shared by the test modules.

use std::ops::ControlFlow;
use vibro_physics::passport::{Passport, PassportSpec};
use vibro_sim::scenario::{ScenarioKind, EMBEDDED_SCENARIOS};
use vibro_sim::{parse_scenario, Scenario, Simulator};

/// The text of a shipped scenario.
pub fn shipped_text(id: &str) -> String {
    EMBEDDED_SCENARIOS
        .iter()
        .find(|(i, _, _)| *i == id)
        .map(|(_, _, t)| t.to_string())
        .unwrap_or_else(|| panic!("no shipped scenario {id}"))
}

/// Parses scenario text, panicking with the full error.
pub fn parse(text: &str) -> Scenario {
    parse_scenario(text, "test.toml", None).unwrap_or_else(|e| panic!("{e}"))
}

/// A shipped scenario with its still/vibrating records shortened.
pub fn shortened_campaign(id: &str, still_s: f64, vibrating_s: f64) -> Scenario {
    let text = shipped_text(id)
        .replace("still_s = 300.0", &format!("still_s = {still_s}"))
        .replace(
            "vibrating_s = 300.0",
            &format!("vibrating_s = {vibrating_s}"),
        );
    parse(&text)
}

/// A passport from a shipped one with the nonlinear terms multiplied by `factor`
/// (`d1A`, `k2..k5`, `m31`, `m32`): an exaggerated unit whose VE a short run resolves.
pub fn exaggerated(id: &str, factor: f64) -> Passport {
    let p = vibro_config::resolve_passport(id).unwrap();
    let s = p.to_spec();
    Passport::try_from_spec(&PassportSpec {
        d1a_ppm: s.d1a_ppm * factor,
        k2_ppm_per_g: s.k2_ppm_per_g * factor,
        k3_ppm_per_g2: s.k3_ppm_per_g2 * factor,
        k4_ppm_per_g3: s.k4_ppm_per_g3 * factor,
        k5_ppm_per_g4: s.k5_ppm_per_g4 * factor,
        m31_ppm_per_g: s.m31_ppm_per_g * factor,
        m32_ppm_per_g: s.m32_ppm_per_g * factor,
        ..s
    })
    .unwrap()
}

/// Replaces the unit under test of a campaign scenario.
pub fn set_campaign_passport(s: &mut Scenario, p: Passport) {
    match &mut s.kind {
        ScenarioKind::Campaign(c) => c.passport = p,
        ScenarioKind::Flight(_) => panic!("not a campaign"),
    }
}

/// Everything a flight run produces, concatenated.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Record {
    pub body_g: Vec<[f64; 3]>,
    pub sensor_v: Vec<[f64; 3]>,
    pub accel_v: Vec<[f64; 3]>,
    pub truth: Vec<vibro_sim::Truth>,
    pub sensor_time_ns: Vec<u64>,
    pub output_end_ns: Vec<u64>,
}

/// Runs a simulator to the end and keeps every stream.
pub fn record(sim: &mut Simulator) -> Record {
    let mut r = Record::default();
    sim.run(|c| {
        r.body_g.extend_from_slice(c.body_vibration_g());
        r.sensor_v.extend_from_slice(c.sensor_v());
        r.accel_v.extend_from_slice(c.accel_v());
        r.truth.extend_from_slice(c.truth());
        r.sensor_time_ns
            .extend((0..c.sensor_v().len()).map(|k| c.sensor_time_ns(k)));
        r.output_end_ns
            .extend((0..c.accel_v().len()).map(|k| c.output_interval_ns(k).1));
        ControlFlow::Continue(())
    })
    .unwrap();
    r
}

/// Mean and batch-means standard error of a series (`batches` contiguous batches).
pub fn batch_mean(x: &[f64], batches: usize) -> (f64, f64) {
    let n = x.len();
    let means: Vec<f64> = (0..batches)
        .map(|b| {
            let s = &x[b * n / batches..(b + 1) * n / batches];
            s.iter().sum::<f64>() / s.len() as f64
        })
        .collect();
    let m = means.iter().sum::<f64>() / batches as f64;
    let var = means.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (batches - 1) as f64;
    (
        x.iter().sum::<f64>() / n as f64,
        (var / batches as f64).sqrt(),
    )
}
