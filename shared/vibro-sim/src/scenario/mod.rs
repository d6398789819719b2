//! Scenarios (`config/scenarios/*.toml`): what to simulate.
//!
//! A file is read into [`ScenarioRaw`] (every table `deny_unknown_fields`), then
//! validated into a [`Scenario`] by [`Scenario::try_from_raw`], which checks every rule
//! and reports all problems at once, each naming the file, the key path, the value and
//! the rule (`flight.profile[2].t_s = 3: must be greater than the previous t_s = 5`).
//! Only the validated type reaches the simulator. The format is documented in
//! `config/scenarios/README.md`.
//!
//! A scenario is either a **flight** (the triad of RIG.md along a flight profile, with
//! tones and random vibration in body axes) or a shake-table **campaign** (one unit,
//! conditions still / vibrating / still, MODEL.md sections 8-9).
//!
//! File references (triad, passports, PSD tables) are resolved relative to the
//! scenario's directory, then the working directory, then as a shipped id
//! (`default`, `AL-15`, `p1-table3`, ...), so the shipped scenarios, which only use
//! ids, run from anywhere.

mod raw;

pub use raw::{
    BandRaw, CampaignRaw, FlightRaw, GridRaw, ProfilePointRaw, RandomRaw, RatesRaw, ScenarioRaw,
    SensorRaw, ToneRaw,
};

use crate::effects::{build_for_rig, EffectSpec, Rig};
use crate::random::{cholesky_residual, filter_len, RandomSetup, MAX_FILTER_LEN};
use crate::{Error, Result};
use std::f64::consts::FRAC_1_SQRT_2;
use std::fmt::Display;
use std::path::{Path, PathBuf};
use vibro_config::TriadConfig;
use vibro_physics::passport::Passport;
use vibro_physics::triad::{SignedAxis, TriadAxes, UnitAxes};
use vibro_physics::vibration::{PsdBand, Tone, MAX_TONES};

/// Default vibration-sensor rate, Hz (RIG.md: "25.6 kHz is a common rig rate").
pub const DEFAULT_SENSOR_RATE_HZ: f64 = 25_600.0;
/// Default segment of the non-Gaussian scale mixture, s.
pub const DEFAULT_KURTOSIS_SEGMENT_S: f64 = 0.25;
/// Default resolution of the random-vibration FIR, Hz.
pub const DEFAULT_FILTER_RESOLUTION_HZ: f64 = 1.0;
/// Default number of batches of the batch-means uncertainty (as `vibro-ident`).
pub const DEFAULT_BATCHES: usize = 20;
/// Default tilt limit of the still-drift check, rad (\[P2\], MODEL.md section 8).
pub const DEFAULT_TILT_LIMIT_RAD: f64 = 1e-4;

/// The PSD tables shipped in `config/vibration/`: (id, file, text).
pub const EMBEDDED_PSD_TABLES: [(&str, &str, &str); 2] = [
    (
        "p1-table3",
        "config/vibration/p1-table3.csv",
        include_str!("../../../../config/vibration/p1-table3.csv"),
    ),
    (
        "band-320-640",
        "config/vibration/band-320-640.csv",
        include_str!("../../../../config/vibration/band-320-640.csv"),
    ),
];

/// The scenarios shipped in `config/scenarios/`: (id, file, text).
pub const EMBEDDED_SCENARIOS: [(&str, &str, &str); 10] = [
    (
        "cyclone-4",
        "config/scenarios/cyclone-4.toml",
        include_str!("../../../../config/scenarios/cyclone-4.toml"),
    ),
    (
        "cyclone-4-short",
        "config/scenarios/cyclone-4-short.toml",
        include_str!("../../../../config/scenarios/cyclone-4-short.toml"),
    ),
    (
        "tactical-100s",
        "config/scenarios/tactical-100s.toml",
        include_str!("../../../../config/scenarios/tactical-100s.toml"),
    ),
    (
        "tactical-300s",
        "config/scenarios/tactical-300s.toml",
        include_str!("../../../../config/scenarios/tactical-300s.toml"),
    ),
    (
        "section8-grid",
        "config/scenarios/section8-grid.toml",
        include_str!("../../../../config/scenarios/section8-grid.toml"),
    ),
    (
        "random-runs",
        "config/scenarios/random-runs.toml",
        include_str!("../../../../config/scenarios/random-runs.toml"),
    ),
    (
        "ten-positions",
        "config/scenarios/ten-positions.toml",
        include_str!("../../../../config/scenarios/ten-positions.toml"),
    ),
    (
        "compensation-experiment-al1m",
        "config/scenarios/compensation-experiment-al1m.toml",
        include_str!("../../../../config/scenarios/compensation-experiment-al1m.toml"),
    ),
    (
        "compensation-experiment-aks05",
        "config/scenarios/compensation-experiment-aks05.toml",
        include_str!("../../../../config/scenarios/compensation-experiment-aks05.toml"),
    ),
    (
        "lab-walkthrough",
        "config/scenarios/lab-walkthrough.toml",
        include_str!("../../../../config/scenarios/lab-walkthrough.toml"),
    ),
];

// ---------------------------------------------------------------------------------
// Validated types

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

    fn parse(text: &str) -> Option<Self> {
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

// ---------------------------------------------------------------------------------
// Loading

/// Collects every problem of a file.
#[derive(Debug, Default)]
struct Problems(Vec<String>);

impl Problems {
    fn push(&mut self, key: impl Display, value: impl Display, rule: impl Display) {
        self.0.push(format!("{key} = {value}: {rule}"));
    }

    fn note(&mut self, text: String) {
        self.0.push(text);
    }
}

/// Whether `x` is within `1e-9` (relative) of a whole number >= 1.
fn whole(x: f64) -> Option<u64> {
    if !(x.is_finite() && (0.5..9e15).contains(&x)) {
        return None;
    }
    let r = x.round();
    ((x - r).abs() <= 1e-9 * r.max(1.0)).then_some(r as u64)
}

fn toml_error(file: &str, e: toml::de::Error) -> Error {
    // toml's message names the line, column and key; keep it on one line.
    let message = e
        .to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    Error::Scenario {
        file: file.to_string(),
        problems: vec![message],
    }
}

/// Resolves file references of a scenario.
struct Refs<'a> {
    base_dir: Option<&'a Path>,
}

impl Refs<'_> {
    fn locate(&self, arg: &str) -> Option<PathBuf> {
        let p = Path::new(arg);
        if p.is_absolute() {
            return p.is_file().then(|| p.to_path_buf());
        }
        if let Some(b) = self.base_dir {
            let q = b.join(p);
            if q.is_file() {
                return Some(q);
            }
        }
        p.is_file().then(|| p.to_path_buf())
    }

    fn passport(&self, arg: &str) -> Result<Passport> {
        Ok(match self.locate(arg) {
            Some(path) => vibro_config::load_passport(&path)?,
            None => vibro_config::resolve_passport(arg)?,
        })
    }

    fn triad(&self, arg: &str) -> Result<TriadConfig> {
        Ok(match self.locate(arg) {
            Some(path) => vibro_config::load_triad(&path)?,
            None => vibro_config::resolve_triad(arg)?,
        })
    }

    /// A PSD table, its name for reports, and whether its OA/PA columns hold anything.
    fn psd(&self, arg: &str) -> Result<(Vec<PsdBand>, String)> {
        if let Some(path) = self.locate(arg) {
            return Ok((vibro_config::load_psd_table(&path)?, arg.to_string()));
        }
        if let Some((id, file, text)) = EMBEDDED_PSD_TABLES
            .iter()
            .find(|(id, _, _)| id.eq_ignore_ascii_case(arg))
        {
            let bands = vibro_config::parse_psd_table(text, &format!("{file} (embedded)"))?;
            return Ok((bands, id.to_string()));
        }
        Err(Error::Config(vibro_config::ConfigError::Unknown {
            arg: arg.to_string(),
            kind: "PSD table",
            known: EMBEDDED_PSD_TABLES
                .iter()
                .map(|(id, _, _)| *id)
                .collect::<Vec<_>>()
                .join(", "),
        }))
    }
}

/// Parses and validates a scenario from TOML text; `file` names it in errors and
/// `base_dir` (the file's directory) anchors its relative references.
pub fn parse_scenario(text: &str, file: &str, base_dir: Option<&Path>) -> Result<Scenario> {
    let raw: ScenarioRaw = toml::from_str(text).map_err(|e| toml_error(file, e))?;
    Scenario::try_from_raw(raw, file, base_dir)
}

/// Loads a scenario file.
pub fn load_scenario(path: &Path) -> Result<Scenario> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        file: path.display().to_string(),
        source,
    })?;
    parse_scenario(&text, &path.display().to_string(), path.parent())
}

/// A scenario from a path, or the id of a shipped one (`cyclone-4`, ...). An existing
/// file wins over an id.
pub fn resolve_scenario(arg: &str) -> Result<Scenario> {
    let path = Path::new(arg);
    if path.is_file() {
        return load_scenario(path);
    }
    if let Some((_, file, text)) = EMBEDDED_SCENARIOS
        .iter()
        .find(|(id, _, _)| id.eq_ignore_ascii_case(arg))
    {
        return parse_scenario(text, &format!("{file} (embedded)"), None);
    }
    Err(Error::Config(vibro_config::ConfigError::Unknown {
        arg: arg.to_string(),
        kind: "scenario",
        known: EMBEDDED_SCENARIOS
            .iter()
            .map(|(id, _, _)| *id)
            .collect::<Vec<_>>()
            .join(", "),
    }))
}

/// The triad frame a campaign simulates in: the unit under test is unit 0 with body
/// axes = its own axes (`x` = OA, `y` = PA, `z` = IA), so that body-frame and unit-frame
/// vibration coincide. Units 1 and 2 only complete the geometry (they are not run).
pub fn campaign_axes() -> TriadAxes {
    let ax = |body_index| SignedAxis {
        body_index,
        sign: 1,
    };
    let unit = |ia, oa, pa| UnitAxes {
        ia: ax(ia),
        oa: ax(oa),
        pa: ax(pa),
    };
    TriadAxes {
        units: [unit(2, 0, 1), unit(0, 1, 2), unit(1, 2, 0)],
    }
}

impl TryFrom<ScenarioRaw> for Scenario {
    type Error = Error;

    /// Validates a scenario built in code (file references relative to the working
    /// directory); see [`Scenario::try_from_raw`].
    fn try_from(raw: ScenarioRaw) -> Result<Self> {
        Scenario::try_from_raw(raw, "<scenario>", None)
    }
}

impl Scenario {
    /// Checks every rule of `raw`, reporting all problems at once.
    pub fn try_from_raw(raw: ScenarioRaw, file: &str, base_dir: Option<&Path>) -> Result<Self> {
        let refs = Refs { base_dir };
        let mut p = Problems::default();
        if raw.name.trim().is_empty() {
            p.push("name", format!("{:?}", raw.name), "must not be empty");
        }
        let rates = validate_rates(&raw.rates, &mut p);
        let sensor = validate_sensor(&raw.sensor, rates.sensor_hz, &mut p);
        let kind = match (&raw.flight, &raw.campaign) {
            (Some(f), None) => {
                validate_flight(f, &rates, &refs, &mut p).map(|f| ScenarioKind::Flight(Box::new(f)))
            }
            (None, Some(c)) => validate_campaign(c, &rates, &refs, &mut p)
                .map(|c| ScenarioKind::Campaign(Box::new(c))),
            (Some(_), Some(_)) => {
                p.note("[flight] and [campaign]: a scenario is one or the other, not both".into());
                None
            }
            (None, None) => {
                p.note("missing [flight] or [campaign]: a scenario needs one of them".into());
                None
            }
        };
        // Every effect is built once (enabled or not) so that its parameters are
        // checked now, not mid-run.
        if let Some(kind) = &kind {
            let rig = match kind {
                ScenarioKind::Flight(f) => Rig {
                    triad: f.triad.axes,
                    passports: Some(f.triad.passports),
                },
                ScenarioKind::Campaign(c) => Rig {
                    triad: campaign_axes(),
                    passports: Some([c.passport; 3]),
                },
            };
            for (i, spec) in raw.effect.iter().enumerate() {
                if let Err(e) = build_for_rig(spec, &rig) {
                    p.note(format!("effect[{i}] (kind = {:?}): {e}", spec.kind));
                }
                if matches!(kind, ScenarioKind::Campaign(_)) {
                    if let Some(units) = &spec.units {
                        if units.iter().any(|u| *u != 0) {
                            p.push(
                                format!("effect[{i}].units"),
                                format!("{units:?}"),
                                "a campaign has one unit under test: only unit 0",
                            );
                        }
                    }
                }
            }
        }
        match kind {
            Some(kind) if p.0.is_empty() => Ok(Scenario {
                name: raw.name,
                description: raw.description.unwrap_or_default(),
                file: file.to_string(),
                seed: raw.seed,
                rates,
                sensor,
                effects: raw.effect,
                kind,
            }),
            _ => Err(Error::Scenario {
                file: file.to_string(),
                problems: p.0,
            }),
        }
    }
}

fn validate_rates(r: &RatesRaw, p: &mut Problems) -> Rates {
    let sensor_hz = r.sensor_hz.unwrap_or(DEFAULT_SENSOR_RATE_HZ);
    let sensor_ok = whole(sensor_hz).is_some() && (100.0..=1e6).contains(&sensor_hz);
    if !sensor_ok {
        p.push(
            "rates.sensor_hz",
            sensor_hz,
            "must be a whole number of Hz within 100..=1e6",
        );
    }
    let internal_hz = r.internal_hz.unwrap_or(sensor_hz);
    match whole(internal_hz / sensor_hz) {
        Some(m) if (1..=64).contains(&m) && sensor_ok => {}
        _ => p.push(
            "rates.internal_hz",
            internal_hz,
            format!("must be the sensor rate {sensor_hz} Hz times a whole number 1..=64"),
        ),
    }
    let output_ok = r.output_hz.is_finite() && r.output_hz > 0.0;
    match whole(internal_hz / r.output_hz) {
        Some(_) if output_ok => {}
        _ => p.push(
            "rates.output_hz",
            r.output_hz,
            format!(
                "must divide the internal rate {internal_hz} Hz a whole number of times \
                 (the output is the mean over whole internal samples)"
            ),
        ),
    }
    Rates {
        sensor_hz,
        internal_hz,
        output_hz: r.output_hz,
    }
}

fn validate_sensor(s: &SensorRaw, sensor_hz: f64, p: &mut Problems) -> SensorSpec {
    let k = "sensor";
    let sens = s.sensitivity_v_per_g;
    if !(sens.is_finite() && (1e-6..=1e3).contains(&sens.abs())) {
        p.push(
            format!("{k}.sensitivity_v_per_g"),
            sens,
            "must be finite with 1e-6 <= |sensitivity| <= 1e3 V/g",
        );
    }
    if !(s.ac_corner_hz.is_finite() && s.ac_corner_hz >= 0.0 && s.ac_corner_hz < sensor_hz / 4.0) {
        p.push(
            format!("{k}.ac_corner_hz"),
            s.ac_corner_hz,
            format!("must be finite, >= 0 (0: DC-coupled) and below a quarter of the sensor rate, {} Hz", sensor_hz / 4.0),
        );
    }
    if !(s.noise_g_rms.is_finite() && (0.0..=1e3).contains(&s.noise_g_rms)) {
        p.push(
            format!("{k}.noise_g_rms"),
            s.noise_g_rms,
            "must be finite and 0 <= noise <= 1000 g RMS",
        );
    }
    if !(2..=32).contains(&s.adc_bits) {
        p.push(format!("{k}.adc_bits"), s.adc_bits, "must be 2..=32 bits");
    }
    if !(s.full_scale_v.is_finite() && s.full_scale_v > 0.0 && s.full_scale_v <= 1e4) {
        p.push(
            format!("{k}.full_scale_v"),
            s.full_scale_v,
            "must be finite and 0 < full scale <= 1e4 V",
        );
    }
    SensorSpec {
        sensitivity_v_per_g: sens,
        ac_corner_hz: s.ac_corner_hz,
        noise_g_rms: s.noise_g_rms,
        adc_bits: s.adc_bits,
        full_scale_v: s.full_scale_v,
    }
}

/// A record or flight length that must hold a whole number of output intervals.
fn check_length(key: &str, seconds: f64, rates: &Rates, p: &mut Problems) -> bool {
    let ok = seconds.is_finite() && seconds > 0.0 && seconds <= 1e6;
    if !ok {
        p.push(key, seconds, "must be finite and 0 < length <= 1e6 s");
        return false;
    }
    if whole(seconds * rates.output_hz).is_none() {
        p.push(
            key,
            seconds,
            format!(
                "must be a whole number of output intervals (1/output_hz = {} s)",
                1.0 / rates.output_hz
            ),
        );
        return false;
    }
    true
}

fn check_tone_freq(key: &str, f: f64, rates: &Rates, p: &mut Problems) {
    let limit = 0.5 * rates.sensor_hz.min(rates.internal_hz);
    if !(f.is_finite() && f > 0.0 && f < limit) {
        p.push(
            key,
            f,
            format!("must be finite, > 0 and below the sensor's Nyquist frequency {limit} Hz"),
        );
    }
}

fn validate_flight(
    f: &FlightRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
) -> Option<Flight> {
    check_length("flight.duration_s", f.duration_s, rates, p);
    let mut triad = match refs.triad(&f.triad) {
        Ok(t) => Some(t),
        Err(e) => {
            p.push("flight.triad", format!("{:?}", f.triad), e);
            None
        }
    };
    if let Some(list) = &f.passports {
        if list.len() != 3 {
            p.push(
                "flight.passports",
                format!("{list:?}"),
                "must list exactly 3 passports, one per unit",
            );
        }
        for (i, arg) in list.iter().enumerate().take(3) {
            match refs.passport(arg) {
                Ok(pp) => {
                    if let Some(t) = triad.as_mut() {
                        t.passports[i] = pp;
                    }
                }
                Err(e) => p.push(format!("flight.passports[{i}]"), format!("{arg:?}"), e),
            }
        }
    }
    if f.profile.is_empty() {
        p.note("flight.profile: no points: at least one [[flight.profile]] is required".into());
    }
    let mut previous_t = f64::NEG_INFINITY;
    for (i, pt) in f.profile.iter().enumerate() {
        let key = format!("flight.profile[{i}]");
        if i == 0 && pt.t_s != 0.0 {
            p.push(
                format!("{key}.t_s"),
                pt.t_s,
                "the first point must be at 0 s",
            );
        } else if !(pt.t_s.is_finite() && pt.t_s > previous_t) {
            p.push(
                format!("{key}.t_s"),
                pt.t_s,
                format!("must be finite and greater than the previous t_s = {previous_t}"),
            );
        }
        if pt.t_s.is_finite() {
            previous_t = pt.t_s;
        }
        for (a, v) in pt.accel_body_g.iter().enumerate() {
            if !(v.is_finite() && v.abs() <= 1e3) {
                p.push(
                    format!("{key}.accel_body_g[{a}]"),
                    v,
                    "must be finite and within +-1000 g",
                );
            }
        }
    }
    if f.tone.len() > MAX_TONES {
        p.push(
            "flight.tone",
            format!("{} tones", f.tone.len()),
            format!("at most {MAX_TONES} tones are supported"),
        );
    }
    let mut tones = Vec::new();
    for (k, t) in f.tone.iter().enumerate() {
        let key = format!("flight.tone[{k}]");
        check_tone_freq(&format!("{key}.freq_hz"), t.freq_hz, rates, p);
        if let Some(to) = t.sweep_to_hz {
            check_tone_freq(&format!("{key}.sweep_to_hz"), to, rates, p);
        }
        for (i, a) in t.amplitude_g.iter().enumerate() {
            if !(a.is_finite() && (0.0..=1e3).contains(a)) {
                p.push(
                    format!("{key}.amplitude_g[{i}]"),
                    a,
                    "must be finite and 0 <= amplitude <= 1000 g",
                );
            }
        }
        let phase_deg = t.phase_deg.unwrap_or([0.0; 3]);
        for (i, ph) in phase_deg.iter().enumerate() {
            if !ph.is_finite() {
                p.push(format!("{key}.phase_deg[{i}]"), ph, "must be finite");
            }
        }
        tones.push(FlightTone {
            tone: Tone {
                freq_hz: t.freq_hz,
                amplitude_g: t.amplitude_g,
                phase_rad: phase_deg.map(f64::to_radians),
            },
            sweep_to_hz: t.sweep_to_hz,
        });
    }
    let random = f
        .random
        .as_ref()
        .and_then(|r| validate_random(r, rates, refs, p));
    Some(Flight {
        duration_s: f.duration_s,
        triad: triad?,
        profile: Profile::from_points(
            f.profile
                .iter()
                .map(|pt| (pt.t_s, pt.accel_body_g))
                .collect(),
        ),
        tones,
        random,
    })
}

/// Checks the table's psd1/psd2 columns are empty (the psd3 column is the PSD along
/// the axis or direction) and returns the psd3 shape.
fn psd3_shape(key: &str, arg: &str, bands: &[PsdBand], p: &mut Problems) -> Vec<(f64, f64, f64)> {
    if bands
        .iter()
        .any(|b| b.psd_g2_per_hz[0] != 0.0 || b.psd_g2_per_hz[1] != 0.0)
    {
        p.push(
            key,
            format!("{arg:?}"),
            "its psd1_g2_per_hz/psd2_g2_per_hz columns are not used here: the psd3_g2_per_hz \
             column is the PSD along the axis (or direction); give one table per axis instead",
        );
    }
    bands
        .iter()
        .map(|b| (b.f_lo_hz, b.f_hi_hz, b.psd_g2_per_hz[2]))
        .collect()
}

/// Merges per-axis shapes (each a list of `(f_lo, f_hi, S)`) into bands holding all
/// three axes, on the union of their edges.
fn merge_axes(shapes: &[Vec<(f64, f64, f64)>; 3]) -> Vec<PsdBand> {
    let mut edges: Vec<f64> = shapes.iter().flatten().flat_map(|b| [b.0, b.1]).collect();
    edges.sort_by(f64::total_cmp);
    edges.dedup();
    let mut out = Vec::new();
    for w in edges.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        let mid = 0.5 * (lo + hi);
        let mut psd = [0.0; 3];
        for (axis, shape) in shapes.iter().enumerate() {
            psd[axis] = shape
                .iter()
                .filter(|b| b.0 <= mid && mid < b.1)
                .map(|b| b.2)
                .sum();
        }
        if psd.iter().any(|s| *s > 0.0) {
            out.push(PsdBand {
                f_lo_hz: lo,
                f_hi_hz: hi,
                psd_g2_per_hz: psd,
            });
        }
    }
    out
}

fn check_coherence(key: &str, c: &[[f64; 3]; 3], p: &mut Problems) {
    let mut ok = true;
    for i in 0..3 {
        for j in 0..3 {
            let v = c[i][j];
            if i == j && v != 1.0 {
                p.push(format!("{key}[{i}][{j}]"), v, "the diagonal must be 1");
                ok = false;
            } else if !(v.is_finite() && v.abs() <= 1.0) {
                p.push(
                    format!("{key}[{i}][{j}]"),
                    v,
                    "must be finite and within -1..=1",
                );
                ok = false;
            } else if (v - c[j][i]).abs() > 1e-12 {
                p.push(
                    format!("{key}[{i}][{j}]"),
                    v,
                    format!("must equal {key}[{j}][{i}] = {} (symmetric)", c[j][i]),
                );
                ok = false;
            }
        }
    }
    if ok {
        let r = cholesky_residual(c);
        if r > 1e-9 {
            p.push(
                key,
                format!("{c:?}"),
                format!("must be positive semi-definite (a correlation matrix); its Cholesky factor misses it by {r:.3e}"),
            );
        }
    }
}

fn check_kurtosis(key: &str, k: f64, p: &mut Problems) {
    if !(k.is_finite() && (3.0..=30.0).contains(&k)) {
        p.push(
            key,
            k,
            "must be within 3..=30 (Gaussian to the scale mixture's limit; the generator has \
             no sub-Gaussian family)",
        );
    }
}

/// The settings shared by flight and campaign random vibration.
fn random_numerics(
    key: &str,
    segment: Option<f64>,
    resolution: Option<f64>,
    bands: &[PsdBand],
    rates: &Rates,
    p: &mut Problems,
) -> (f64, f64) {
    let segment_s = segment.unwrap_or(DEFAULT_KURTOSIS_SEGMENT_S);
    let lowest_hz = bands
        .iter()
        .map(|b| b.f_lo_hz)
        .filter(|f| *f > 0.0)
        .fold(f64::INFINITY, f64::min);
    let min_segment_s = if lowest_hz.is_finite() {
        1.0 / lowest_hz
    } else {
        0.0
    };
    if !(segment_s.is_finite() && segment_s > 0.0 && segment_s >= min_segment_s && segment_s <= 1e3)
    {
        p.push(
            format!("{key}.kurtosis_segment_s"),
            segment_s,
            format!(
                "must be finite, at most 1000 s and at least one period of the lowest band \
                 edge ({min_segment_s} s), so that a segment is long against the correlation time"
            ),
        );
    }
    let resolution_hz = resolution.unwrap_or(DEFAULT_FILTER_RESOLUTION_HZ);
    let finest_hz = rates.internal_hz / MAX_FILTER_LEN as f64;
    if !(resolution_hz.is_finite() && resolution_hz >= finest_hz && resolution_hz <= 100.0) {
        p.push(
            format!("{key}.filter_resolution_hz"),
            resolution_hz,
            format!("must be finite within {finest_hz}..=100 Hz"),
        );
    }
    let nyquist = 0.5 * rates.sensor_hz.min(rates.internal_hz);
    for b in bands {
        if b.f_hi_hz > nyquist {
            p.push(
                format!("{key} band {}..{} Hz", b.f_lo_hz, b.f_hi_hz),
                b.f_hi_hz,
                format!("must end below the sensor's Nyquist frequency {nyquist} Hz"),
            );
            break;
        }
    }
    (segment_s, resolution_hz)
}

fn validate_random(
    r: &RandomRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
) -> Option<RandomSpec> {
    let key = "flight.random";
    let given = [
        r.psd_table.is_some(),
        r.psd_tables.is_some(),
        r.band.is_some(),
    ];
    if given.iter().filter(|g| **g).count() != 1 {
        p.note(format!(
            "{key}: give exactly one of psd_table, psd_tables and [[{key}.band]]"
        ));
        return None;
    }
    let mut source;
    let mut shapes: [Vec<(f64, f64, f64)>; 3] = Default::default();
    if let Some(arg) = &r.psd_table {
        match refs.psd(arg) {
            Ok((bands, name)) => {
                let s = psd3_shape(&format!("{key}.psd_table"), arg, &bands, p);
                shapes = [s.clone(), s.clone(), s];
                source = name;
            }
            Err(e) => {
                p.push(format!("{key}.psd_table"), format!("{arg:?}"), e);
                return None;
            }
        }
    } else if let Some(args) = &r.psd_tables {
        let mut names = Vec::new();
        for (i, arg) in args.iter().enumerate() {
            match refs.psd(arg) {
                Ok((bands, name)) => {
                    shapes[i] = psd3_shape(&format!("{key}.psd_tables[{i}]"), arg, &bands, p);
                    names.push(name);
                }
                Err(e) => p.push(format!("{key}.psd_tables[{i}]"), format!("{arg:?}"), e),
            }
        }
        source = names.join("/");
    } else {
        let bands = r.band.as_deref().unwrap_or_default();
        if bands.is_empty() {
            p.note(format!("{key}.band: no bands: at least one is required"));
        }
        let mut s = Vec::new();
        for (i, b) in bands.iter().enumerate() {
            let k = format!("{key}.band[{i}]");
            if !(b.f_lo_hz.is_finite() && b.f_lo_hz >= 0.0) {
                p.push(
                    format!("{k}.f_lo_hz"),
                    b.f_lo_hz,
                    "must be finite and >= 0 Hz",
                );
            }
            if !(b.f_hi_hz.is_finite() && b.f_hi_hz > b.f_lo_hz) {
                p.push(
                    format!("{k}.f_hi_hz"),
                    b.f_hi_hz,
                    format!("must be finite and exceed f_lo_hz = {}", b.f_lo_hz),
                );
            }
            if !(b.psd_g2_per_hz.is_finite() && (0.0..=1e4).contains(&b.psd_g2_per_hz)) {
                p.push(
                    format!("{k}.psd_g2_per_hz"),
                    b.psd_g2_per_hz,
                    "must be finite within 0..=1e4 g^2/Hz",
                );
            }
            s.push((b.f_lo_hz, b.f_hi_hz, b.psd_g2_per_hz));
        }
        shapes = [s.clone(), s.clone(), s];
        source = "inline bands".into();
    }
    if let Some(gains) = &r.band_gain {
        if r.psd_tables.is_some() {
            p.push(
                format!("{key}.band_gain"),
                format!("{gains:?}"),
                "only with a single psd_table or inline bands",
            );
        } else if gains.len() != shapes[0].len() {
            p.push(
                format!("{key}.band_gain"),
                format!("{gains:?}"),
                format!("must give one gain per band ({} bands)", shapes[0].len()),
            );
        } else {
            for (i, g) in gains.iter().enumerate() {
                if !(g.is_finite() && (0.0..=1e3).contains(g)) {
                    p.push(
                        format!("{key}.band_gain[{i}]"),
                        g,
                        "must be finite within 0..=1000",
                    );
                }
            }
            for shape in shapes.iter_mut() {
                for (b, g) in shape.iter_mut().zip(gains) {
                    b.2 *= g * g;
                }
            }
            source += " x band gains";
        }
    }
    let variance: Vec<f64> = shapes
        .iter()
        .map(|s| s.iter().map(|b| b.2 * (b.1 - b.0)).sum())
        .collect();
    let scale = match (r.scale, r.rms_g) {
        (Some(_), Some(_)) => {
            p.note(format!("{key}: give scale or rms_g, not both"));
            [1.0; 3]
        }
        (Some(s), None) => {
            for (i, v) in s.iter().enumerate() {
                if !(v.is_finite() && (0.0..=1e3).contains(v)) {
                    p.push(
                        format!("{key}.scale[{i}]"),
                        v,
                        "must be finite within 0..=1000",
                    );
                }
            }
            source += &format!(" x scale {s:?}");
            s
        }
        (None, Some(rms)) => {
            let mut s = [1.0; 3];
            for i in 0..3 {
                if !(rms[i].is_finite() && (0.0..=1e3).contains(&rms[i])) {
                    p.push(
                        format!("{key}.rms_g[{i}]"),
                        rms[i],
                        "must be finite within 0..=1000 g",
                    );
                } else if rms[i] > 0.0 && variance[i] <= 0.0 {
                    p.push(
                        format!("{key}.rms_g[{i}]"),
                        rms[i],
                        "the PSD of this axis is zero: nothing to scale",
                    );
                } else if rms[i] > 0.0 {
                    s[i] = rms[i] / variance[i].sqrt();
                } else {
                    s[i] = 0.0;
                }
            }
            source += &format!(" at rms {rms:?} g");
            s
        }
        (None, None) => [1.0; 3],
    };
    for (shape, s) in shapes.iter_mut().zip(scale) {
        for b in shape.iter_mut() {
            b.2 *= s * s;
        }
    }
    let bands = merge_axes(&shapes);
    let coherence = r
        .coherence
        .unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    check_coherence(&format!("{key}.coherence"), &coherence, p);
    let kurtosis = r.kurtosis.unwrap_or([3.0; 3]);
    for (i, k) in kurtosis.iter().enumerate() {
        check_kurtosis(&format!("{key}.kurtosis[{i}]"), *k, p);
    }
    let (segment_s, filter_resolution_hz) = random_numerics(
        key,
        r.kurtosis_segment_s,
        r.filter_resolution_hz,
        &bands,
        rates,
        p,
    );
    Some(RandomSpec {
        source,
        setup: RandomSetup {
            bands,
            coherence,
            kurtosis,
            segment_s,
            filter_resolution_hz,
        },
    })
}

fn validate_campaign(
    c: &CampaignRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
) -> Option<Campaign> {
    let passport = match refs.passport(&c.passport) {
        Ok(pp) => Some(pp),
        Err(e) => {
            p.push("campaign.passport", format!("{:?}", c.passport), e);
            None
        }
    };
    let batches = c.batches.unwrap_or(DEFAULT_BATCHES);
    if !(2..=10_000).contains(&batches) {
        p.push("campaign.batches", batches, "must be 2..=10000");
    }
    for (key, len) in [
        ("campaign.still_s", c.still_s),
        ("campaign.vibrating_s", c.vibrating_s),
    ] {
        if check_length(key, len, rates, p) && (len * rates.output_hz).round() < batches as f64 {
            p.push(
                key,
                len,
                format!("must hold at least {batches} output samples, one per batch"),
            );
        }
    }
    let settle_s = c.settle_s.unwrap_or(0.0);
    let settle_out = settle_s * rates.output_hz;
    if !(settle_s.is_finite() && settle_s >= 0.0 && (settle_out - settle_out.round()).abs() < 1e-6)
    {
        p.push(
            "campaign.settle_s",
            settle_s,
            "must be finite, >= 0 and a whole number of output intervals",
        );
    } else {
        for (key, len) in [
            ("campaign.still_s", c.still_s),
            ("campaign.vibrating_s", c.vibrating_s),
        ] {
            if ((len - settle_s) * rates.output_hz).round() < batches as f64 {
                p.push(
                    key,
                    len,
                    format!(
                        "must hold at least {batches} output samples after settle_s = {settle_s}"
                    ),
                );
            }
        }
    }
    let tilt_limit_rad = c.tilt_limit_rad.unwrap_or(DEFAULT_TILT_LIMIT_RAD);
    if !(tilt_limit_rad.is_finite() && tilt_limit_rad > 0.0) {
        p.push(
            "campaign.tilt_limit_rad",
            tilt_limit_rad,
            "must be finite and > 0 rad",
        );
    }
    if c.grid.is_empty() {
        p.note("campaign.grid: no grids: at least one [[campaign.grid]] is required".into());
    }
    let mut conditions = Vec::new();
    for (g, grid) in c.grid.iter().enumerate() {
        expand_grid(g, grid, rates, refs, p, &mut conditions);
    }
    Some(Campaign {
        passport: passport?,
        passport_source: c.passport.clone(),
        still_s: c.still_s,
        vibrating_s: c.vibrating_s,
        batches,
        tilt_limit_rad,
        settle_s,
        conditions,
    })
}

/// A random level of a grid: an amplitude scale of the table or an RMS, along the
/// direction.
#[derive(Debug, Clone, Copy)]
enum Level {
    Scale(f64),
    Rms(f64),
}

/// One random level of a grid: table name, its psd3 shape, level and kurtosis.
type GridRandom = (String, Vec<(f64, f64, f64)>, Level, f64);

fn expand_grid(
    g: usize,
    grid: &GridRaw,
    rates: &Rates,
    refs: &Refs<'_>,
    p: &mut Problems,
    out: &mut Vec<Condition>,
) {
    let key = format!("campaign.grid[{g}]");
    let nonempty = |name: &str, n: usize, p: &mut Problems| {
        if n == 0 {
            p.note(format!("{key}.{name}: empty list: give at least one value"));
        }
    };
    nonempty("angle_deg", grid.angle_deg.len(), p);
    for (i, a) in grid.angle_deg.iter().enumerate() {
        if !a.is_finite() {
            p.push(format!("{key}.angle_deg[{i}]"), a, "must be finite");
        }
    }
    let tilt = match grid.tilt_toward.trim().to_ascii_lowercase().as_str() {
        "oa" => TiltAxis::Oa,
        "pa" => TiltAxis::Pa,
        _ => {
            p.push(
                format!("{key}.tilt_toward"),
                format!("{:?}", grid.tilt_toward),
                "must be \"oa\" or \"pa\" (the axis that takes the rest of gravity)",
            );
            TiltAxis::Oa
        }
    };
    nonempty("direction", grid.direction.len(), p);
    let mut directions = Vec::new();
    for (i, d) in grid.direction.iter().enumerate() {
        match Direction::parse(d) {
            Some(d) => directions.push(d),
            None => p.push(
                format!("{key}.direction[{i}]"),
                format!("{d:?}"),
                "must be \"ia\", \"ia-oa-45\" or \"ia-pa-45\"",
            ),
        }
    }
    let sqrt2 = grid.scale_45_by_sqrt2.unwrap_or(false);
    // Tones: amplitude x frequency, or none.
    let tones: Vec<Option<(f64, f64)>> = match (&grid.tone_amplitude_g, &grid.tone_freq_hz) {
        (Some(amps), Some(freqs)) => {
            nonempty("tone_amplitude_g", amps.len(), p);
            nonempty("tone_freq_hz", freqs.len(), p);
            for (i, a) in amps.iter().enumerate() {
                if !(a.is_finite() && *a > 0.0 && *a <= 500.0) {
                    p.push(
                        format!("{key}.tone_amplitude_g[{i}]"),
                        a,
                        "must be finite and 0 < amplitude <= 500 g",
                    );
                }
            }
            for (i, f) in freqs.iter().enumerate() {
                check_tone_freq(&format!("{key}.tone_freq_hz[{i}]"), *f, rates, p);
            }
            amps.iter()
                .flat_map(|a| freqs.iter().map(move |f| Some((*a, *f))))
                .collect()
        }
        (None, None) => vec![None],
        _ => {
            p.note(format!(
                "{key}: tone_amplitude_g and tone_freq_hz go together: give both or neither"
            ));
            vec![None]
        }
    };
    // Random: table x level x kurtosis, or none.
    let mut randoms: Vec<Option<GridRandom>> = vec![None];
    let mut numerics = (DEFAULT_KURTOSIS_SEGMENT_S, DEFAULT_FILTER_RESOLUTION_HZ);
    if let Some(tables) = &grid.psd_table {
        nonempty("psd_table", tables.len(), p);
        let levels: Vec<Level> = match (&grid.random_scale, &grid.random_rms_g) {
            (Some(_), Some(_)) => {
                p.note(format!(
                    "{key}: give random_scale or random_rms_g, not both"
                ));
                vec![]
            }
            (Some(s), None) => {
                nonempty("random_scale", s.len(), p);
                for (i, v) in s.iter().enumerate() {
                    if !(v.is_finite() && *v > 0.0 && *v <= 1e3) {
                        p.push(
                            format!("{key}.random_scale[{i}]"),
                            v,
                            "must be finite within 0 < scale <= 1000",
                        );
                    }
                }
                s.iter().map(|v| Level::Scale(*v)).collect()
            }
            (None, Some(r)) => {
                nonempty("random_rms_g", r.len(), p);
                for (i, v) in r.iter().enumerate() {
                    if !(v.is_finite() && *v > 0.0 && *v <= 1e3) {
                        p.push(
                            format!("{key}.random_rms_g[{i}]"),
                            v,
                            "must be finite within 0 < rms <= 1000 g",
                        );
                    }
                }
                r.iter().map(|v| Level::Rms(*v)).collect()
            }
            (None, None) => vec![Level::Scale(1.0)],
        };
        let kurtoses = grid.kurtosis.clone().unwrap_or_else(|| vec![3.0]);
        nonempty("kurtosis", kurtoses.len(), p);
        for (i, k) in kurtoses.iter().enumerate() {
            check_kurtosis(&format!("{key}.kurtosis[{i}]"), *k, p);
        }
        randoms.clear();
        let mut all_bands = Vec::new();
        for (i, arg) in tables.iter().enumerate() {
            match refs.psd(arg) {
                Ok((bands, name)) => {
                    let shape = psd3_shape(&format!("{key}.psd_table[{i}]"), arg, &bands, p);
                    let variance: f64 = shape.iter().map(|b| b.2 * (b.1 - b.0)).sum();
                    if variance <= 0.0 {
                        p.push(
                            format!("{key}.psd_table[{i}]"),
                            format!("{arg:?}"),
                            "has no power along the direction (psd3 column all zero)",
                        );
                    }
                    all_bands.extend(bands);
                    for level in &levels {
                        for k in &kurtoses {
                            randoms.push(Some((name.clone(), shape.clone(), *level, *k)));
                        }
                    }
                }
                Err(e) => p.push(format!("{key}.psd_table[{i}]"), format!("{arg:?}"), e),
            }
        }
        numerics = random_numerics(
            &key,
            grid.kurtosis_segment_s,
            grid.filter_resolution_hz,
            &all_bands,
            rates,
            p,
        );
    } else if grid.random_scale.is_some() || grid.random_rms_g.is_some() || grid.kurtosis.is_some()
    {
        p.note(format!(
            "{key}: random_scale, random_rms_g and kurtosis need psd_table"
        ));
    }
    if tones == [None] && randoms.iter().all(Option::is_none) {
        p.note(format!(
            "{key}: no vibration: give tone_amplitude_g/tone_freq_hz, psd_table, or both"
        ));
    }
    for &angle_deg in &grid.angle_deg {
        let g3 = vibro_ident::cos_deg(angle_deg);
        let g_tilt = vibro_ident::cos_deg(angle_deg - 90.0);
        let a_l_unit_g = match tilt {
            TiltAxis::Oa => [g_tilt, 0.0, g3],
            TiltAxis::Pa => [0.0, g_tilt, g3],
        };
        for &direction in &directions {
            let factors = direction.axis_factors(sqrt2);
            for tone in &tones {
                for random in &randoms {
                    let index = out.len();
                    let tone_spec = tone.map(|(a, f)| Tone {
                        freq_hz: f,
                        amplitude_g: factors.map(|k| k * a),
                        phase_rad: [0.0; 3],
                    });
                    let random_spec = random.as_ref().map(|(name, shape, level, k)| {
                        let variance: f64 = shape.iter().map(|b| b.2 * (b.1 - b.0)).sum();
                        let (along, label) = match *level {
                            Level::Scale(s) => (s, format!("{name} x{s}")),
                            Level::Rms(r) => (
                                if variance > 0.0 {
                                    r / variance.sqrt()
                                } else {
                                    0.0
                                },
                                format!("{name} at {r} g rms"),
                            ),
                        };
                        let per_axis: [Vec<(f64, f64, f64)>; 3] = std::array::from_fn(|i| {
                            let s = along * factors[i];
                            shape.iter().map(|b| (b.0, b.1, b.2 * s * s)).collect()
                        });
                        let bands = merge_axes(&per_axis);
                        // Axes moved by the shaker are fully coherent (one drive signal).
                        let mut coherence = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
                        for i in 0..3 {
                            for j in 0..3 {
                                if i != j && factors[i] != 0.0 && factors[j] != 0.0 {
                                    coherence[i][j] = 1.0;
                                }
                            }
                        }
                        let (segment_s, filter_resolution_hz) = numerics;
                        RandomSpec {
                            source: label,
                            setup: RandomSetup {
                                bands,
                                coherence,
                                kurtosis: [*k; 3],
                                segment_s,
                                filter_resolution_hz,
                            },
                        }
                    });
                    out.push(Condition {
                        index,
                        id: format!("C{:03}", index + 1),
                        tp: u32::try_from(index + 1).unwrap_or(u32::MAX),
                        angle_deg,
                        tilt_toward: tilt,
                        a_l_unit_g,
                        direction,
                        scale_45_by_sqrt2: sqrt2,
                        tone: tone_spec,
                        tone_amplitude_g: tone.map(|t| t.0),
                        random: random_spec,
                    });
                }
            }
        }
    }
}

/// The FIR length the random vibration of `spec` gets at `internal_hz` (for reports).
pub fn random_filter_len(spec: &RandomSpec, internal_hz: f64) -> usize {
    filter_len(internal_hz, spec.setup.filter_resolution_hz)
}
