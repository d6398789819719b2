//! The streaming simulator: body-frame vibration, the chain of each unit, its
//! vibration sensor and the truth, chunk by chunk (see the crate docs for the chain).

use crate::random::RandomGenerator;
use crate::scenario::{campaign_axes, Condition, Profile, Rates, Scenario, SensorSpec};
use crate::sensor::SensorChain;
use crate::tones::{Sweep, ToneBank};
use crate::{Error, Result};
use std::f64::consts::PI;
use std::ops::ControlFlow;
use vibro_effects::{build_for_rig, BlockCtx, Effect, MeanContext, Rig};
use vibro_physics::exact::MeanModel;
use vibro_physics::fp;
use vibro_physics::passport::Passport;
use vibro_physics::triad::UnitAxes;
use vibro_physics::vibration::{PsdBand, Tone, Vibration};

/// Default length of a chunk, s (rounded to whole output samples).
pub const DEFAULT_CHUNK_S: f64 = 0.1;

/// The truth of one accelerometer output sample, per unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// Flight acceleration in each unit's axes `[aL1 (OA), aL2 (PA), aL3 (IA)]`, g: the
    /// mean over the internal samples (at `t = n/fs`) the output sample averages.
    pub a_l_unit_g: [[f64; 3]; 3],
    /// Mean over the output interval of the whole acceleration the unit senses (flight
    /// plus vibration, after the input effects such as a mount resonance), in its axes,
    /// g: the reference of an error that excludes the vibration's own (real, zero-mean)
    /// motion, so that `U/K1 - a_mean` is the offset, main error and VE alone.
    pub a_mean_unit_g: [[f64; 3]; 3],
    /// The exact mean output `E[aF]` of (FP) at `a_l_unit_g` under the scenario's
    /// vibration (MODEL.md section 6), g: what an ideal average of the output tends to,
    /// with no effect.
    pub exact_mean_output_g: [f64; 3],
    /// The exact VE: `exact_mean_output_g - aF(a_l_unit_g)` (MODEL.md sections 4, 6), g.
    pub exact_ve_g: [f64; 3],
}

/// Total sample counts of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SampleCounts {
    /// Samples at the internal rate.
    pub internal: u64,
    /// Vibration-sensor samples (per channel).
    pub sensor: u64,
    /// Accelerometer output samples (per unit).
    pub output: u64,
}

/// One chunk of a run: whole accelerometer output intervals and the samples inside.
/// Buffers are allocated once; each chunk overwrites the previous one.
#[derive(Debug, Clone)]
pub struct SimChunk {
    index: u64,
    internal_hz: u64,
    sensor_decimation: u64,
    output_decimation: u64,
    internal_first: u64,
    n_internal: usize,
    sensor_first: u64,
    n_sensor: usize,
    output_first: u64,
    n_output: usize,
    body_g: Vec<[f64; 3]>,
    sensor_v: Vec<[f64; 3]>,
    accel_v: Vec<[f64; 3]>,
    truth: Vec<Truth>,
}

impl SimChunk {
    fn new(rates: &Rates, chunk_output: usize) -> Self {
        let d = rates.output_decimation();
        let m = rates.sensor_decimation();
        let n_internal = chunk_output * d;
        Self {
            index: 0,
            internal_hz: rates.internal_hz.round() as u64,
            sensor_decimation: m as u64,
            output_decimation: d as u64,
            internal_first: 0,
            n_internal: 0,
            sensor_first: 0,
            n_sensor: 0,
            output_first: 0,
            n_output: 0,
            body_g: vec![[0.0; 3]; n_internal],
            sensor_v: vec![[0.0; 3]; n_internal / m + 1],
            accel_v: vec![[0.0; 3]; chunk_output],
            truth: vec![
                Truth {
                    a_l_unit_g: [[0.0; 3]; 3],
                    a_mean_unit_g: [[0.0; 3]; 3],
                    exact_mean_output_g: [0.0; 3],
                    exact_ve_g: [0.0; 3],
                };
                chunk_output
            ],
        }
    }

    /// Chunk number, from 0.
    pub fn index(&self) -> u64 {
        self.index
    }

    fn ns(&self, internal_index: u64) -> u64 {
        let ns = u128::from(internal_index) * 1_000_000_000 / u128::from(self.internal_hz.max(1));
        u64::try_from(ns).unwrap_or(u64::MAX)
    }

    /// Time of the chunk's first internal sample since the start of the run, ns.
    pub fn t0_ns(&self) -> u64 {
        self.ns(self.internal_first)
    }

    /// Index of the first internal sample.
    pub fn internal_first_index(&self) -> u64 {
        self.internal_first
    }

    /// The vibration at the internal rate in body axes `[x, y, z]`, g (for a campaign
    /// condition: the unit's axes `[OA, PA, IA]`), as generated, before any effect.
    pub fn body_vibration_g(&self) -> &[[f64; 3]] {
        &self.body_g[..self.n_internal]
    }

    /// Index (in the whole run) of the chunk's first vibration-sensor sample.
    pub fn sensor_first_index(&self) -> u64 {
        self.sensor_first
    }

    /// Vibration-sensor samples, V: channel `u` is the sensor of unit `u`, measuring
    /// along that unit's IA. Feed them to `vibro_dsp` with the scenario's sensitivity
    /// and AC-coupling corner.
    pub fn sensor_v(&self) -> &[[f64; 3]] {
        &self.sensor_v[..self.n_sensor]
    }

    /// Time of sensor sample `k` of this chunk, ns from the run start.
    pub fn sensor_time_ns(&self, k: usize) -> u64 {
        self.ns((self.sensor_first + k as u64) * self.sensor_decimation)
    }

    /// Index (in the whole run) of the chunk's first accelerometer output sample.
    pub fn output_first_index(&self) -> u64 {
        self.output_first
    }

    /// Accelerometer outputs `U = K1 * <aF>`, V: the mean of the instantaneous output
    /// over each output interval, per unit.
    pub fn accel_v(&self) -> &[[f64; 3]] {
        &self.accel_v[..self.n_output]
    }

    /// Start and end of the averaging interval of output sample `k`, ns.
    pub fn output_interval_ns(&self, k: usize) -> (u64, u64) {
        let i = self.output_first + k as u64;
        (
            self.ns(i * self.output_decimation),
            self.ns((i + 1) * self.output_decimation),
        )
    }

    /// The truth per output sample.
    pub fn truth(&self) -> &[Truth] {
        &self.truth[..self.n_output]
    }
}

/// One unit's chain and buffers.
struct Unit {
    name: String,
    axes: UnitAxes,
    /// The passport as given (effects' mean formulas see it).
    passport: Passport,
    /// Same without `lambda`: the time-domain FP has `lambda = 1`.
    passport_flat: Passport,
    /// Exact mean model of the scenario's vibration (no effect).
    model: MeanModel,
    still_model: MeanModel,
    vibration_unit: Vibration,
    psd_unit: Vec<PsdBand>,
    sensor: SensorChain,
    sensor_g: Vec<f64>,
    vib_g: Vec<[f64; 3]>,
    input_g: Vec<[f64; 3]>,
    out_g: Vec<f64>,
}

/// What a run is made of; built from a flight or a campaign condition.
pub(crate) struct Plan {
    pub seed: u64,
    pub stream_base: u64,
    pub rates: Rates,
    pub sensor: SensorSpec,
    pub total_output: u64,
    pub profile: Profile,
    pub units: Vec<(String, UnitAxes, Passport)>,
    pub tones: Vec<Tone>,
    pub sweeps: Vec<Option<Sweep>>,
    pub random: Option<crate::random::RandomSetup>,
    /// Vibration on for output samples `[a, b)` only (campaigns); always on if `None`.
    pub gate_output: Option<(u64, u64)>,
}

/// A body-frame vibration description in one unit's axes `[OA, PA, IA]`: a negative
/// axis adds pi to the tone phase and flips covariance signs.
pub(crate) fn to_unit_frame(body: &Vibration, axes: &UnitAxes) -> Result<Vibration> {
    let map = [axes.oa, axes.pa, axes.ia];
    let mut v = Vibration::none();
    for t in body.tones() {
        let mut u = Tone {
            freq_hz: t.freq_hz,
            amplitude_g: [0.0; 3],
            phase_rad: [0.0; 3],
        };
        for (i, ax) in map.iter().enumerate() {
            u.amplitude_g[i] = t.amplitude_g[ax.body_index];
            u.phase_rad[i] = t.phase_rad[ax.body_index] + if ax.sign < 0 { PI } else { 0.0 };
        }
        v.push_tone(u)?;
    }
    for (i, a) in map.iter().enumerate() {
        for (j, b) in map.iter().enumerate() {
            v.covariance_g2[i][j] =
                f64::from(a.sign * b.sign) * body.covariance_g2[a.body_index][b.body_index];
        }
        v.kurtosis[i] = body.kurtosis[a.body_index];
    }
    Ok(v)
}

pub(crate) fn passport_without_lambda(p: &Passport) -> Result<Passport> {
    let mut spec = p.to_spec();
    spec.lambda.clear();
    Ok(Passport::try_from_spec(&spec)?)
}

/// The streaming simulator (see the crate docs). Build it from a validated
/// [`Scenario`], then pull chunks with [`Simulator::next_chunk`] or
/// [`Simulator::run`]. Every buffer is allocated here: producing a chunk does not
/// allocate.
pub struct Simulator {
    rates: Rates,
    internal_hz: f64,
    sensor_decimation: u64,
    output_decimation: usize,
    total_internal: u64,
    next_internal: u64,
    chunk_output: usize,
    chunk: SimChunk,
    started: bool,
    profile: Profile,
    profile_cursor: usize,
    units: Vec<Unit>,
    effects: Vec<Box<dyn Effect>>,
    tones: ToneBank,
    random: Option<RandomGenerator>,
    gate_internal: Option<(u64, u64)>,
    body_scenario: Vibration,
    body_generated: Vibration,
    flight_g: Vec<[f64; 3]>,
    duration_s: f64,
    /// `Vibration::none()`, for the still mean contexts.
    no_vibration: Vibration,
}

impl std::fmt::Debug for Simulator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulator")
            .field("rates", &self.rates)
            .field("total_internal", &self.total_internal)
            .field("next_internal", &self.next_internal)
            .field("units", &self.units.len())
            .field(
                "effects",
                &self.effects.iter().map(|e| e.kind()).collect::<Vec<_>>(),
            )
            .field("random", &self.random)
            .finish()
    }
}

impl Simulator {
    /// A simulator of a flight scenario with the given effects (applied to every unit
    /// unless an effect restricts itself; hooks run in the order given). The effects
    /// listed in the scenario are *not* added: see [`Simulator::from_scenario`].
    pub fn new(scenario: &Scenario, effects: Vec<Box<dyn Effect>>) -> Result<Self> {
        let Some(flight) = scenario.flight() else {
            return Err(Error::Unsupported {
                what: format!("scenario {:?}", scenario.name),
                reason: "is a campaign: run it with run_campaign, or one condition with \
                         Simulator::for_condition"
                    .into(),
            });
        };
        let rates = scenario.rates;
        let total_output = (flight.duration_s * rates.output_hz).round() as u64;
        let plan = Plan {
            seed: scenario.seed,
            stream_base: 0,
            rates,
            sensor: scenario.sensor,
            total_output,
            profile: flight.profile.clone(),
            units: (0..3)
                .map(|u| {
                    (
                        flight.triad.names[u].clone(),
                        flight.triad.axes.units[u],
                        flight.triad.passports[u],
                    )
                })
                .collect(),
            tones: flight.tones.iter().map(|t| t.tone).collect(),
            sweeps: flight
                .tones
                .iter()
                .map(|t| {
                    t.sweep_to_hz.map(|to_hz| Sweep {
                        to_hz,
                        duration_s: flight.duration_s,
                    })
                })
                .collect(),
            random: flight.random.as_ref().map(|r| r.setup.clone()),
            gate_output: None,
        };
        Self::from_plan(plan, effects)
    }

    /// A simulator of a flight scenario with its own `[[effect]]` tables (the enabled
    /// ones, built for the scenario's triad and passports).
    pub fn from_scenario(scenario: &Scenario) -> Result<Self> {
        let effects = scenario_effects(scenario)?;
        Self::new(scenario, effects)
    }

    /// A simulator of condition `index` of a campaign scenario: one unit (unit 0; the
    /// columns of units 1 and 2 hold NaN) in the unit frame (body `x, y, z` = OA, PA,
    /// IA), still / vibrating / still.
    pub fn for_condition(
        scenario: &Scenario,
        index: usize,
        effects: Vec<Box<dyn Effect>>,
    ) -> Result<Self> {
        let Some(campaign) = scenario.campaign() else {
            return Err(Error::Unsupported {
                what: format!("scenario {:?}", scenario.name),
                reason: "is a flight, not a campaign".into(),
            });
        };
        let Some(c) = campaign.conditions.get(index) else {
            return Err(Error::Invalid {
                key: "condition index".into(),
                value: index.to_string(),
                rule: format!("the campaign has {} conditions", campaign.conditions.len()),
            });
        };
        Self::from_plan(condition_plan(scenario, campaign, c), effects)
    }

    fn from_plan(plan: Plan, mut effects: Vec<Box<dyn Effect>>) -> Result<Self> {
        let rates = plan.rates;
        let fs = rates.internal_hz;
        let d = rates.output_decimation();
        let m = rates.sensor_decimation() as u64;
        // Validated scenarios always pass; this guards hand-built ones.
        if d == 0 || m == 0 || !(fs.is_finite() && fs > 0.0) {
            return Err(Error::Invalid {
                key: "rates".into(),
                value: format!("{rates:?}"),
                rule: "internal_hz must be a positive whole multiple of sensor_hz and output_hz"
                    .into(),
            });
        }
        let mut random = match &plan.random {
            Some(setup) => Some(RandomGenerator::new(
                setup,
                fs,
                plan.seed,
                plan.stream_base,
            )?),
            None => None,
        };
        // The scenario's description in body axes (what the truth uses).
        let mut body_scenario = Vibration::none();
        for t in &plan.tones {
            body_scenario.push_tone(*t)?;
        }
        if let (Some(g), Some(setup)) = (&random, &plan.random) {
            body_scenario.covariance_g2 = g.covariance_g2();
            body_scenario.kurtosis = setup.kurtosis;
        }
        body_scenario.validate()?;
        // Generation side: the effects adjust the description before any draw.
        let mut adjusted = body_scenario;
        for e in &effects {
            e.adjust_body_vibration(&mut adjusted);
        }
        let mut body_generated = adjusted;
        if let Some(g) = random.as_mut() {
            g.set_kurtosis(adjusted.kurtosis);
            let mut gain = [1.0; 3];
            for i in 0..3 {
                let (before, after) = (
                    body_scenario.covariance_g2[i][i],
                    adjusted.covariance_g2[i][i],
                );
                if before > 0.0 {
                    gain[i] = (after.max(0.0) / before).sqrt();
                } else if after != 0.0 {
                    return Err(unsupported_adjustment(
                        &effects,
                        "adds random vibration to an axis the scenario leaves silent",
                    ));
                }
            }
            for i in 0..3 {
                for j in 0..3 {
                    let want = body_scenario.covariance_g2[i][j] * gain[i] * gain[j];
                    let got = adjusted.covariance_g2[i][j];
                    if i != j && (got - want).abs() > 1e-9 * (1.0 + want.abs()) {
                        return Err(unsupported_adjustment(
                            &effects,
                            "changes the cross-covariance other than by scaling the axes",
                        ));
                    }
                }
            }
            g.set_amplitude_gain(gain);
            body_generated.covariance_g2 = g.covariance_g2();
        } else if adjusted.covariance_g2.iter().flatten().any(|c| *c != 0.0) {
            return Err(unsupported_adjustment(
                &effects,
                "adds random vibration to a scenario without any",
            ));
        }
        // Sweeps follow their tone if an effect moved its frequency.
        let sweeps: Vec<Option<Sweep>> = adjusted
            .tones()
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let base = plan.tones.get(k)?;
                let sweep = plan.sweeps.get(k).copied().flatten()?;
                let ratio = if base.freq_hz > 0.0 {
                    t.freq_hz / base.freq_hz
                } else {
                    1.0
                };
                Some(Sweep {
                    to_hz: sweep.to_hz * ratio,
                    duration_s: sweep.duration_s,
                })
            })
            .collect();
        let tones = ToneBank::new(adjusted.tones(), &sweeps, plan.seed, plan.stream_base);
        let duration_s = plan.total_output as f64 / rates.output_hz;
        let chunk_output = ((DEFAULT_CHUNK_S * rates.output_hz).round() as usize).max(1);
        let n_chunk = chunk_output * d;
        let mut units = Vec::with_capacity(plan.units.len());
        for (u, (name, axes, passport)) in plan.units.iter().enumerate() {
            let passport_flat = passport_without_lambda(passport)?;
            let vibration_unit = to_unit_frame(&body_scenario, axes)?;
            let mut model = MeanModel::new(passport_flat);
            model.set_vibration(&vibration_unit)?;
            let map = [axes.oa, axes.pa, axes.ia];
            let psd_unit = plan
                .random
                .as_ref()
                .map(|s| {
                    s.bands
                        .iter()
                        .map(|b| PsdBand {
                            f_lo_hz: b.f_lo_hz,
                            f_hi_hz: b.f_hi_hz,
                            psd_g2_per_hz: map.map(|a| b.psd_g2_per_hz[a.body_index]),
                        })
                        .collect()
                })
                .unwrap_or_default();
            units.push(Unit {
                name: name.clone(),
                axes: *axes,
                passport: *passport,
                passport_flat,
                model,
                still_model: MeanModel::new(passport_flat),
                vibration_unit,
                psd_unit,
                sensor: SensorChain::new(
                    &plan.sensor,
                    rates.sensor_hz,
                    plan.seed,
                    plan.stream_base,
                    u,
                ),
                sensor_g: vec![0.0; n_chunk],
                vib_g: vec![[0.0; 3]; n_chunk],
                input_g: vec![[0.0; 3]; n_chunk],
                out_g: vec![0.0; n_chunk],
            });
        }
        for e in effects.iter_mut() {
            e.reset(fs);
        }
        Ok(Self {
            rates,
            internal_hz: fs,
            sensor_decimation: m,
            output_decimation: d,
            total_internal: plan.total_output * d as u64,
            next_internal: 0,
            chunk_output,
            chunk: SimChunk::new(&rates, chunk_output),
            started: false,
            profile: plan.profile,
            profile_cursor: 0,
            units,
            effects,
            tones,
            random,
            gate_internal: plan.gate_output.map(|(a, b)| (a * d as u64, b * d as u64)),
            body_scenario,
            body_generated,
            flight_g: vec![[0.0; 3]; n_chunk],
            duration_s,
            no_vibration: Vibration::none(),
        })
    }

    /// Sets the chunk length in accelerometer output samples (default: 0.1 s worth).
    /// Only before the first chunk; the output does not depend on it.
    pub fn set_chunk_output_samples(&mut self, n: usize) -> Result<()> {
        if self.started || n == 0 || n > 1 << 24 {
            return Err(Error::Invalid {
                key: "chunk_output_samples".into(),
                value: n.to_string(),
                rule: "must be 1..=2^24 and set before the first chunk".into(),
            });
        }
        let n_chunk = n * self.output_decimation;
        self.chunk_output = n;
        self.chunk = SimChunk::new(&self.rates, n);
        self.flight_g = vec![[0.0; 3]; n_chunk];
        for u in &mut self.units {
            u.sensor_g = vec![0.0; n_chunk];
            u.vib_g = vec![[0.0; 3]; n_chunk];
            u.input_g = vec![[0.0; 3]; n_chunk];
            u.out_g = vec![0.0; n_chunk];
        }
        Ok(())
    }

    /// The sample rates.
    pub fn rates(&self) -> Rates {
        self.rates
    }

    /// Duration of the run, s.
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Total samples of the whole run.
    pub fn total_samples(&self) -> SampleCounts {
        let n = self.total_internal;
        SampleCounts {
            internal: n,
            sensor: n.div_ceil(self.sensor_decimation),
            output: n / self.output_decimation as u64,
        }
    }

    /// Fraction of the run produced so far, 0..=1.
    pub fn progress(&self) -> f64 {
        if self.total_internal == 0 {
            1.0
        } else {
            self.next_internal as f64 / self.total_internal as f64
        }
    }

    /// Samples each vibration sensor's ADC clipped so far.
    pub fn sensor_clipped(&self) -> [u64; 3] {
        let mut c = [0; 3];
        for (ci, u) in c.iter_mut().zip(&self.units) {
            *ci = u.sensor.clipped_samples();
        }
        c
    }

    /// The ADC step of the vibration sensors, V.
    pub fn sensor_step_v(&self) -> f64 {
        self.units.first().map_or(0.0, |u| u.sensor.step_v())
    }

    /// Names of the units (one for a campaign condition).
    pub fn unit_names(&self) -> Vec<&str> {
        self.units.iter().map(|u| u.name.as_str()).collect()
    }

    /// The scenario's vibration in body axes, with the realised random covariance and
    /// no effect: what the truth is computed from.
    pub fn body_vibration_scenario(&self) -> &Vibration {
        &self.body_scenario
    }

    /// The vibration actually generated, in body axes, after the effects'
    /// `adjust_body_vibration` (with the covariance of the generator).
    pub fn body_vibration_generated(&self) -> &Vibration {
        &self.body_generated
    }

    /// The scenario's vibration in unit `unit`'s axes (no effect).
    pub fn unit_vibration(&self, unit: usize) -> Option<&Vibration> {
        self.units.get(unit).map(|u| &u.vibration_unit)
    }

    /// What an effect's mean formula sees for unit `unit` at flight acceleration
    /// `a_l_unit_g` (its axes), for comparing [`Effect::mean_shift_g`] with a run.
    pub fn mean_context(&self, unit: usize, a_l_unit_g: [f64; 3]) -> Option<MeanContext<'_>> {
        let u = self.units.get(unit)?;
        Some(MeanContext {
            unit,
            passport: &u.passport,
            a_l_unit_g,
            vibration_unit: &u.vibration_unit,
            psd_unit: &u.psd_unit,
            internal_rate_hz: self.internal_hz,
            duration_s: self.duration_s,
        })
    }

    /// Each effect's documented mean contribution ([`Effect::mean_shift_g`]) for unit
    /// `unit` at `a_l_unit_g`, under the scenario's vibration (`vibrating`) or none, for
    /// a record of `duration_s`; in the effects' order, with their kinds.
    pub fn effect_mean_shifts_g(
        &self,
        unit: usize,
        a_l_unit_g: [f64; 3],
        vibrating: bool,
        duration_s: f64,
    ) -> Vec<(&'static str, Result<f64>)> {
        let Some(u) = self.units.get(unit) else {
            return Vec::new();
        };
        let ctx = MeanContext {
            unit,
            passport: &u.passport,
            a_l_unit_g,
            vibration_unit: if vibrating {
                &u.vibration_unit
            } else {
                &self.no_vibration
            },
            psd_unit: if vibrating { &u.psd_unit } else { &[] },
            internal_rate_hz: self.internal_hz,
            duration_s,
        };
        self.effects
            .iter()
            .map(|e| (e.kind(), e.mean_shift_g(&ctx).map_err(Error::from)))
            .collect()
    }

    /// The exact mean output and VE of unit `unit` at `a_l_unit_g` under the scenario's
    /// vibration (no effect), g: `(E[aF], E[aF] - aF(aL))`.
    pub fn exact_mean_and_ve_g(&self, unit: usize, a_l_unit_g: [f64; 3]) -> Option<(f64, f64)> {
        let u = self.units.get(unit)?;
        let (mean, _) = u.model.mean_output_g(a_l_unit_g);
        let still = fp::output_g(
            &u.passport_flat,
            a_l_unit_g[0],
            a_l_unit_g[1],
            a_l_unit_g[2],
        );
        Some((mean, mean - still))
    }

    /// Runs to the end (or until `f` breaks), handing every chunk to `f`.
    pub fn run<F>(&mut self, mut f: F) -> Result<SampleCounts>
    where
        F: FnMut(&SimChunk) -> ControlFlow<()>,
    {
        while let Some(chunk) = self.next_chunk()? {
            if f(chunk).is_break() {
                break;
            }
        }
        Ok(SampleCounts {
            internal: self.next_internal,
            sensor: self.next_internal.div_ceil(self.sensor_decimation),
            output: self.next_internal / self.output_decimation as u64,
        })
    }

    /// The next chunk, or `None` at the end of the run.
    pub fn next_chunk(&mut self) -> Result<Option<&SimChunk>> {
        if self.next_internal >= self.total_internal {
            return Ok(None);
        }
        self.started = true;
        let d = self.output_decimation;
        let m = self.sensor_decimation;
        let n0 = self.next_internal;
        let n = (self.chunk_output * d).min((self.total_internal - n0) as usize);
        let fs = self.internal_hz;
        let chunk = &mut self.chunk;
        let body = &mut chunk.body_g[..n];
        // 1. Body-frame vibration: random part, then the tones, then the gate.
        match self.random.as_mut() {
            Some(g) => g.fill(body)?,
            None => body.fill([0.0; 3]),
        }
        self.tones.add(n0, fs, body);
        if let Some((on, off)) = self.gate_internal {
            for (k, b) in body.iter_mut().enumerate() {
                let i = n0 + k as u64;
                if i < on || i >= off {
                    *b = [0.0; 3];
                }
            }
        }
        // 2. Flight acceleration in body axes.
        for (k, a) in self.flight_g[..n].iter_mut().enumerate() {
            let t_s = (n0 + k as u64) as f64 / fs;
            self.profile_cursor = self.profile.segment(t_s, self.profile_cursor);
            *a = self.profile.eval_in(self.profile_cursor, t_s);
        }
        // 3. Each unit: sensor, input, FP, output, truth.
        let first_sensor = n0.div_ceil(m);
        let first_offset = (first_sensor * m - n0) as usize;
        let n_sensor = if first_offset < n {
            (n - first_offset).div_ceil(m as usize)
        } else {
            0
        };
        let n_output = n / d;
        for row in chunk.sensor_v[..n_sensor].iter_mut() {
            *row = [f64::NAN; 3];
        }
        for row in chunk.accel_v[..n_output].iter_mut() {
            *row = [f64::NAN; 3];
        }
        let t0_s = n0 as f64 / fs;
        for (ui, unit) in self.units.iter_mut().enumerate() {
            let ctx = BlockCtx {
                unit: ui,
                t0_s,
                dt_s: 1.0 / fs,
            };
            let body = &chunk.body_g[..n];
            let sensor_g = &mut unit.sensor_g[..n];
            for (s, b) in sensor_g.iter_mut().zip(body) {
                *s = unit.axes.ia.project(b);
            }
            for e in self.effects.iter_mut() {
                e.at_sensor(&ctx, body, sensor_g);
            }
            for (j, row) in chunk.sensor_v[..n_sensor].iter_mut().enumerate() {
                row[ui] = unit.sensor.process(sensor_g[first_offset + j * m as usize]);
            }
            let vib = &mut unit.vib_g[..n];
            for (v, b) in vib.iter_mut().zip(body) {
                *v = unit.axes.to_unit(b);
            }
            for e in self.effects.iter_mut() {
                e.at_unit_input(&ctx, vib);
            }
            let input = &mut unit.input_g[..n];
            let out = &mut unit.out_g[..n];
            let p = &unit.passport;
            for (((x, v), a), o) in input
                .iter_mut()
                .zip(vib.iter())
                .zip(&self.flight_g[..n])
                .zip(out.iter_mut())
            {
                let al = unit.axes.to_unit(a);
                *x = [al[0] + v[0], al[1] + v[1], al[2] + v[2]];
                *o = fp::output_g(p, x[0], x[1], x[2]);
            }
            for e in self.effects.iter_mut() {
                e.at_unit_output(&ctx, input, out);
            }
            let inv_d = 1.0 / d as f64;
            for j in 0..n_output {
                let range = j * d..(j + 1) * d;
                let mean_g = out[range.clone()].iter().sum::<f64>() * inv_d;
                chunk.accel_v[j][ui] = p.k1_v_per_g * mean_g;
                let mut al = [0.0; 3];
                for a in &self.flight_g[range] {
                    let u = unit.axes.to_unit(a);
                    for i in 0..3 {
                        al[i] += u[i];
                    }
                }
                let al = al.map(|x| x * inv_d);
                let mut a_mean = [0.0; 3];
                for x in &input[j * d..(j + 1) * d] {
                    for i in 0..3 {
                        a_mean[i] += x[i];
                    }
                }
                let a_mean = a_mean.map(|x| x * inv_d);
                let start = n0 + (j * d) as u64;
                let vibrating = match self.gate_internal {
                    Some((on, off)) => start >= on && start < off,
                    None => true,
                };
                let model = if vibrating {
                    &unit.model
                } else {
                    &unit.still_model
                };
                let (mean, _) = model.mean_output_g(al);
                let still = fp::output_g(&unit.passport_flat, al[0], al[1], al[2]);
                let t = &mut chunk.truth[j];
                t.a_l_unit_g[ui] = al;
                t.a_mean_unit_g[ui] = a_mean;
                t.exact_mean_output_g[ui] = mean;
                t.exact_ve_g[ui] = mean - still;
            }
        }
        for ui in self.units.len()..3 {
            for t in chunk.truth[..n_output].iter_mut() {
                t.a_l_unit_g[ui] = [f64::NAN; 3];
                t.a_mean_unit_g[ui] = [f64::NAN; 3];
                t.exact_mean_output_g[ui] = f64::NAN;
                t.exact_ve_g[ui] = f64::NAN;
            }
        }
        chunk.index = n0 / (self.chunk_output * d) as u64;
        chunk.internal_first = n0;
        chunk.n_internal = n;
        chunk.sensor_first = first_sensor;
        chunk.n_sensor = n_sensor;
        chunk.output_first = n0 / d as u64;
        chunk.n_output = n_output;
        self.next_internal = n0 + n as u64;
        Ok(Some(&self.chunk))
    }
}

fn unsupported_adjustment(effects: &[Box<dyn Effect>], what: &str) -> Error {
    Error::Unsupported {
        what: format!(
            "effects [{}]: adjust_body_vibration",
            effects
                .iter()
                .map(|e| e.kind())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        reason: format!(
            "{what}; the generator realises changes of tones, kurtosis and per-axis scale \
             of the random part"
        ),
    }
}

/// The enabled `[[effect]]` tables of a scenario, built for its rig.
pub fn scenario_effects(scenario: &Scenario) -> Result<Vec<Box<dyn Effect>>> {
    let rig = match (scenario.flight(), scenario.campaign()) {
        (Some(f), _) => Rig {
            triad: f.triad.axes,
            passports: Some(f.triad.passports),
        },
        (None, Some(c)) => Rig {
            triad: campaign_axes(),
            passports: Some([c.passport; 3]),
        },
        (None, None) => Rig::standard(),
    };
    scenario
        .effects
        .iter()
        .filter(|s| s.enabled)
        .map(|s| build_for_rig(s, &rig).map_err(Error::from))
        .collect()
}

/// The run of one campaign condition (MODEL.md section 8): still, vibrating, still,
/// with gravity `a_l_unit_g` and the vibration in the unit frame.
pub(crate) fn condition_plan(
    scenario: &Scenario,
    campaign: &crate::scenario::Campaign,
    c: &Condition,
) -> Plan {
    let rates = scenario.rates;
    let still = (campaign.still_s * rates.output_hz).round() as u64;
    let vib = (campaign.vibrating_s * rates.output_hz).round() as u64;
    let axes = campaign_axes().units[0];
    Plan {
        seed: scenario.seed,
        stream_base: (c.index as u64 + 1) << 8,
        rates,
        sensor: scenario.sensor,
        total_output: 2 * still + vib,
        // Body = unit frame, so the unit-frame gravity is the body profile.
        profile: Profile::constant(c.a_l_unit_g),
        units: vec![("UUT".to_string(), axes, campaign.passport)],
        tones: c.tone.into_iter().collect(),
        sweeps: vec![None],
        random: c.random.as_ref().map(|r| r.setup.clone()),
        gate_output: Some((still, still + vib)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The CLI runs a simulator on its own thread.
    #[test]
    fn simulator_and_chunks_are_send() {
        fn send<T: Send>() {}
        send::<Simulator>();
        send::<SimChunk>();
    }

    #[test]
    fn unit_frame_rotation_flips_negative_axes() {
        let axes = UnitAxes {
            ia: vibro_physics::triad::SignedAxis {
                body_index: 2,
                sign: -1,
            },
            oa: vibro_physics::triad::SignedAxis {
                body_index: 0,
                sign: 1,
            },
            pa: vibro_physics::triad::SignedAxis {
                body_index: 1,
                sign: -1,
            },
        };
        let mut body = Vibration::single_tone(10.0, [1.0, 2.0, 3.0]);
        body.covariance_g2 = [[1.0, 0.2, 0.3], [0.2, 4.0, 0.5], [0.3, 0.5, 9.0]];
        body.kurtosis = [3.0, 4.0, 5.0];
        let u = to_unit_frame(&body, &axes).unwrap();
        let t = u.tones()[0];
        assert_eq!(t.amplitude_g, [1.0, 2.0, 3.0]);
        assert_eq!(t.phase_rad, [0.0, PI, PI]);
        // [OA, PA, IA] = [x, -y, -z]: K_31 = cov(-z, x) = -0.3, K_32 = cov(-z, -y) = 0.5.
        assert_eq!(u.covariance_g2[2][0], -0.3);
        assert_eq!(u.covariance_g2[2][1], 0.5);
        assert_eq!(u.kurtosis, [3.0, 4.0, 5.0]);
        // The exact model sees the same cross moment either way.
        let e = vibro_physics::exact::cross_moments_g2(&u);
        assert!((e[0] - (-0.3 - 0.5 * 3.0 * 1.0)).abs() < 1e-12);
    }
}
