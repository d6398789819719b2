//! The validated scenario: what the simulator runs. Built only by the validation
//! ([`super::Scenario::try_from_raw`]).

use crate::random::{filter_len, RandomSetup};
use std::f64::consts::FRAC_1_SQRT_2;
use vibro_config::TriadConfig;
use vibro_effects::EffectSpec;
use vibro_physics::passport::Passport;
use vibro_physics::vibration::Tone;

/// A validated scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub name: String,
    pub description: String,
    /// Where it came from (a path, or `config/scenarios/x.toml (embedded)`).
    pub file: String,
    pub seed: u64,
    pub rates: Rates,
    pub sensor: SensorSpec,
    /// `[[effect]]` tables in file order (each validated by building it once).
    pub effects: Vec<EffectSpec>,
    pub kind: ScenarioKind,
}

/// Flight or campaign.
#[derive(Debug, Clone)]
pub enum ScenarioKind {
    // Boxed: both are large (passports carry their lambda tables) and built once.
    Flight(Box<Flight>),
    Campaign(Box<Campaign>),
}

impl Scenario {
    /// The flight, if this scenario is one.
    pub fn flight(&self) -> Option<&Flight> {
        match &self.kind {
            ScenarioKind::Flight(f) => Some(f.as_ref()),
            ScenarioKind::Campaign(_) => None,
        }
    }

    /// The campaign, if this scenario is one.
    pub fn campaign(&self) -> Option<&Campaign> {
        match &self.kind {
            ScenarioKind::Campaign(c) => Some(c.as_ref()),
            ScenarioKind::Flight(_) => None,
        }
    }
}

/// Sample rates. `internal_hz = sensor_decimation * sensor_hz` and
/// `internal_hz = output_decimation * output_hz`, both whole numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rates {
    pub sensor_hz: f64,
    pub internal_hz: f64,
    pub output_hz: f64,
}

impl Rates {
    /// Internal samples per vibration-sensor sample.
    pub fn sensor_decimation(&self) -> usize {
        (self.internal_hz / self.sensor_hz).round() as usize
    }

    /// Internal samples per accelerometer output sample (the averaging interval).
    pub fn output_decimation(&self) -> usize {
        (self.internal_hz / self.output_hz).round() as usize
    }
}

/// The vibration sensor of every unit (see [`crate::sensor`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSpec {
    pub sensitivity_v_per_g: f64,
    /// 0 for a DC-coupled sensor.
    pub ac_corner_hz: f64,
    pub noise_g_rms: f64,
    pub adc_bits: u32,
    pub full_scale_v: f64,
}

/// A flight of the triad.
#[derive(Debug, Clone)]
pub struct Flight {
    pub duration_s: f64,
    /// Geometry, names and passports of the three units.
    pub triad: TriadConfig,
    /// Flight (apparent) acceleration in body axes, piecewise linear.
    pub profile: Profile,
    /// Tones in body axes (index = body axis x, y, z).
    pub tones: Vec<FlightTone>,
    /// Random vibration in body axes.
    pub random: Option<RandomSpec>,
}

/// One tone of a flight: the tone at the start, and the end of its sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightTone {
    pub tone: Tone,
    /// Linear sweep from `tone.freq_hz` to this over the whole flight.
    pub sweep_to_hz: Option<f64>,
}

/// Random vibration: the generator's setup and a label of where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct RandomSpec {
    /// E.g. `p1-table3 (band gains, rms 1.4 g)`.
    pub source: String,
    pub setup: RandomSetup,
}

/// A piecewise-linear acceleration profile, held constant after its last point.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    points: Vec<(f64, [f64; 3])>,
}

impl Profile {
    /// A constant acceleration.
    pub fn constant(accel_g: [f64; 3]) -> Self {
        Self {
            points: vec![(0.0, accel_g)],
        }
    }

    /// Breakpoints `(t_s, accel_g)`; `t_s` must start at 0 and increase (checked by
    /// the scenario validation; unordered points give a meaningless profile).
    pub fn from_points(points: Vec<(f64, [f64; 3])>) -> Self {
        Self { points }
    }

    /// The breakpoints.
    pub fn points(&self) -> &[(f64, [f64; 3])] {
        &self.points
    }

    /// Index of the segment holding `t_s` (the last point whose time is <= t_s).
    pub(crate) fn segment(&self, t_s: f64, from: usize) -> usize {
        let mut i = from.min(self.points.len().saturating_sub(1));
        while i + 1 < self.points.len() && self.points[i + 1].0 <= t_s {
            i += 1;
        }
        i
    }

    /// The acceleration in segment `i` at `t_s` (0 for a profile without points).
    #[inline]
    pub(crate) fn eval_in(&self, i: usize, t_s: f64) -> [f64; 3] {
        let Some(&(t0, a0)) = self.points.get(i) else {
            return [0.0; 3];
        };
        match self.points.get(i + 1) {
            Some(&(t1, a1)) if t_s > t0 => {
                let w = (t_s - t0) / (t1 - t0);
                [
                    a0[0] + w * (a1[0] - a0[0]),
                    a0[1] + w * (a1[1] - a0[1]),
                    a0[2] + w * (a1[2] - a0[2]),
                ]
            }
            _ => a0,
        }
    }

    /// The acceleration at `t_s`, g.
    pub fn at(&self, t_s: f64) -> [f64; 3] {
        self.eval_in(self.segment(t_s, 0), t_s)
    }

    /// The exact time average over `[0, duration_s]` (trapezoids of the breakpoints).
    pub fn mean(&self, duration_s: f64) -> [f64; 3] {
        let mut sum = [0.0; 3];
        let mut t_prev = 0.0;
        let mut a_prev = self.at(0.0);
        let mut knots: Vec<f64> = self
            .points
            .iter()
            .map(|p| p.0)
            .filter(|t| *t > 0.0 && *t < duration_s)
            .collect();
        knots.push(duration_s);
        for t in knots {
            let a = self.at(t);
            for i in 0..3 {
                sum[i] += 0.5 * (a_prev[i] + a[i]) * (t - t_prev);
            }
            t_prev = t;
            a_prev = a;
        }
        sum.map(|s| s / duration_s)
    }
}

/// A shake-table campaign on one unit (MODEL.md sections 8-9).
#[derive(Debug, Clone)]
pub struct Campaign {
    pub passport: Passport,
    /// The passport's file or id, as written.
    pub passport_source: String,
    pub still_s: f64,
    pub vibrating_s: f64,
    pub batches: usize,
    pub tilt_limit_rad: f64,
    /// Left out of the measurement at the start of the vibrating record and of the
    /// second still record (the transients of switching the vibration on and off),
    /// s. A whole number of output intervals.
    pub settle_s: f64,
    pub conditions: Vec<Condition>,
}

/// Where the part of gravity not on IA goes when the unit is turned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TiltAxis {
    Oa,
    Pa,
}

impl TiltAxis {
    pub fn name(self) -> &'static str {
        match self {
            TiltAxis::Oa => "oa",
            TiltAxis::Pa => "pa",
        }
    }
}

/// Direction of the shaker's vibration in the unit frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Along IA.
    Ia,
    /// At 45 deg between IA and OA (TP9).
    IaOa45,
    /// At 45 deg between IA and PA (TP10).
    IaPa45,
    /// At 45 deg between OA and PA, IA still (the unit turned with IA normal to the
    /// shaker axis): the only direction that vibrates OA and PA together.
    OaPa45,
}

impl Direction {
    pub fn name(self) -> &'static str {
        match self {
            Direction::Ia => "ia",
            Direction::IaOa45 => "ia-oa-45",
            Direction::IaPa45 => "ia-pa-45",
            Direction::OaPa45 => "oa-pa-45",
        }
    }

    pub(super) fn parse(text: &str) -> Option<Self> {
        match text.trim().to_ascii_lowercase().as_str() {
            "ia" => Some(Direction::Ia),
            "ia-oa-45" => Some(Direction::IaOa45),
            "ia-pa-45" => Some(Direction::IaPa45),
            "oa-pa-45" => Some(Direction::OaPa45),
            _ => None,
        }
    }

    /// The amplitude on each unit axis `[OA, PA, IA]` per unit amplitude along the
    /// direction: `1/sqrt(2)` on both axes of a 45-deg direction, or exactly 1 when
    /// the amplitude is scaled by sqrt(2) (MODEL.md section 9: "with amplitude
    /// `sqrt(2)*aB`, so both axes get `aB`").
    pub fn axis_factors(self, scale_45_by_sqrt2: bool) -> [f64; 3] {
        let s = if scale_45_by_sqrt2 {
            1.0
        } else {
            FRAC_1_SQRT_2
        };
        match self {
            Direction::Ia => [0.0, 0.0, 1.0],
            Direction::IaOa45 => [s, 0.0, s],
            Direction::IaPa45 => [0.0, s, s],
            Direction::OaPa45 => [s, s, 0.0],
        }
    }
}

/// One condition of a campaign: the unit's orientation and the vibration applied.
#[derive(Debug, Clone, PartialEq)]
pub struct Condition {
    /// Index in the campaign, from 0.
    pub index: usize,
    /// `C001`, `C002`, ...
    pub id: String,
    /// Test-position number: index + 1 (the ten-positions campaign lists TP1..TP10 in
    /// the paper's order).
    pub tp: u32,
    /// Angle of IA from the vertical, deg: gravity on IA is `g cos(angle)`.
    pub angle_deg: f64,
    pub tilt_toward: TiltAxis,
    /// Gravity in the unit frame `[aL1 (OA), aL2 (PA), aL3 (IA)]`, g (g = 1 g).
    pub a_l_unit_g: [f64; 3],
    pub direction: Direction,
    pub scale_45_by_sqrt2: bool,
    /// The tone in unit axes `[OA, PA, IA]` (at most one per condition).
    pub tone: Option<Tone>,
    /// Amplitude of the tone along the direction as listed, g.
    pub tone_amplitude_g: Option<f64>,
    /// Random vibration in unit axes.
    pub random: Option<RandomSpec>,
}

/// The FIR length the random vibration of `spec` gets at `internal_hz` (for reports).
pub fn random_filter_len(spec: &RandomSpec, internal_hz: f64) -> usize {
    filter_len(internal_hz, spec.setup.filter_resolution_hz)
}
