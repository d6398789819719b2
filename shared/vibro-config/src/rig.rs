//! Rig descriptions: what a real rig knows about its own data (docs/logs.md, "A rig's
//! own data"). A rig file states the triad (geometry and passports), the vibration
//! sensors' chain and the reference the readings are compared with; `vibrocomp log
//! import --rig FILE` writes that reference into the log beside the readings, so that
//! the lab and `log errors` work on a rig's log as on a simulated one.
//!
//! ```toml
//! format = "vibrocomp-rig/1"
//! triad = "default"                 # a triad file (relative to this file) or "default"
//!
//! [sensors]
//! sensitivity_v_per_g = 0.1         # one value or [s1, s2, s3]; a negative one flips
//! ac_corner_hz = 2.0                # first-order AC coupling; absent or 0: DC-coupled
//! delay_s = 0.0                     # a sample stamped s saw the base at s - delay_s (0..1 s)
//! # rate_hz = 25600.0               # optional: the vibration CSV must be at this rate
//!
//! [reference]
//! kind = "static"                   # "static" | "centrifuge" | "stream"
//! gravity_g = 1.0
//! [[reference.segment]]             # static: the orientation per time segment
//! from_s = 0.0                      # the readings' time base (their time_s column)
//! to_s = 8.0
//! up = "+z"                         # the body direction pointing up: "+x".."-z" or [x, y, z]
//! ```
//!
//! A reference accelerometer recorded as a rig records a piezoelectric one (AC-coupled,
//! in V; RIG.md's B&K 8503 through a charge converter) states its chain under the
//! static or centrifuge reference; its gravity then comes from the stated orientation:
//!
//! ```toml
//! [reference.chain]                 # absent: the reference CSV is DC-coupled, in g
//! sensitivity_v_per_g = 0.01        # one value or [x, y, z] (body axes); a negative one flips
//! ac_corner_hz = 0.5                # first-order AC coupling; absent or 0: DC-coupled
//! delay_s = 0.0013                  # a sample stamped s saw the table at s - delay_s (0..1 s)
//! ```
//!
//! A centrifuge (`kind = "centrifuge"`) states `gravity_g`, `up`, `radius_m`,
//! `rate_rad_s` and `toward_centre` (the body direction pointing at the axis of
//! rotation): the specific force is `gravity_g up + rate^2 radius / g0 toward_centre`.
//! A stream (`kind = "stream"`) is a CSV given with `--reference` (`time_s` and one
//! column per body axis, `columns`, default `ax_g, ay_g, az_g`): the flight
//! acceleration, a navigation solution or a low-passed reference accelerometer.
//!
//! Every problem of a file is reported at once, each with the key, the value and the
//! rule ([`ConfigError::Invalid`]).

use crate::{read, resolve_triad, ConfigError, Result, TriadConfig};
use serde::Deserialize;
use std::path::Path;
use vibro_physics::triad::SignedAxis;
/// The triad geometry a rig's reference is projected through (re-exported for the
/// crates that read rig files).
pub use vibro_physics::triad::TriadAxes;

/// The rig file's `format`.
pub const RIG_FORMAT: &str = "vibrocomp-rig/1";

/// Standard gravity, m/s^2: a centrifuge's `rate^2 radius` in g.
pub const G0_M_PER_S2: f64 = 9.806_65;

/// The vibration sensors' chain: what turns a sensor's volts into g.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorChain {
    /// Volts per g per sensor (sensor `u` is along unit `u`'s input axis); a negative
    /// value flips the axis.
    pub sensitivity_v_per_g: [f64; 3],
    /// Corner of the first-order AC coupling, Hz; `None`: DC-coupled.
    pub ac_corner_hz: Option<f64>,
    /// The chain's delay, s: a sample stamped `s` saw the base at `s - delay_s`
    /// (0..=[`MAX_DELAY_S`]; absent: 0).
    pub delay_s: f64,
    /// Whether the file states `delay_s` (absent, the lab on the waveform fits it).
    pub delay_stated: bool,
    /// The sensors' sample rate, Hz, when the file states it: a vibration stream at
    /// another rate is not this rig's.
    pub rate_hz: Option<f64>,
}

/// The longest chain delay a rig file may state, s: a DAQ's filter delays by
/// milliseconds; a second is a unit mix-up (ms for s). The same bound as the
/// estimator's `delay_s` (`vibro_dsp::MAX_DELAY_S`) and the compensator's
/// `[sensors] delay_s` (`vibro_waveform::MAX_DELAY_S`).
pub const MAX_DELAY_S: f64 = 1.0;

/// The sample rates `sensors.rate_hz` may state: a period between 1 ns and 1000 s, as
/// `vibrocomp log import` takes a CSV's rate.
pub const SENSOR_RATE_RANGE_HZ: [f64; 2] = [1e-3, 1e9];

/// One time segment of a static reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticSegment {
    pub from_s: f64,
    pub to_s: f64,
    /// The body direction pointing up, a unit vector.
    pub up: [f64; 3],
}

/// What the readings are compared with.
#[derive(Debug, Clone, PartialEq)]
pub enum ReferenceSpec {
    /// Gravity along a body direction, per time segment.
    Static {
        gravity_g: f64,
        segments: Vec<StaticSegment>,
    },
    /// A centrifuge turning at a constant rate.
    Centrifuge {
        gravity_g: f64,
        up: [f64; 3],
        radius_m: f64,
        rate_rad_s: f64,
        toward_centre: [f64; 3],
    },
    /// A CSV stream of the flight acceleration per body axis (`--reference`).
    Stream {
        /// The columns of the body axes x, y, z.
        columns: [String; 3],
    },
}

impl ReferenceSpec {
    /// `static`, `centrifuge` or `stream`.
    pub fn kind(&self) -> &'static str {
        match self {
            ReferenceSpec::Static { .. } => "static",
            ReferenceSpec::Centrifuge { .. } => "centrifuge",
            ReferenceSpec::Stream { .. } => "stream",
        }
    }

    /// The specific force along the body axes at `t_s` for a static reference or a
    /// centrifuge, g; `None` outside every static segment, and for a stream (read from
    /// its file by the caller).
    pub fn body_g_at(&self, t_s: f64) -> Option<[f64; 3]> {
        match self {
            ReferenceSpec::Static {
                gravity_g,
                segments,
            } => segments
                .iter()
                .find(|s| t_s >= s.from_s && t_s <= s.to_s)
                .map(|s| s.up.map(|u| u * gravity_g)),
            ReferenceSpec::Centrifuge {
                gravity_g,
                up,
                radius_m,
                rate_rad_s,
                toward_centre,
            } => {
                let centripetal_g = rate_rad_s * rate_rad_s * radius_m / G0_M_PER_S2;
                Some(std::array::from_fn(|i| {
                    gravity_g * up[i] + centripetal_g * toward_centre[i]
                }))
            }
            ReferenceSpec::Stream { .. } => None,
        }
    }

    /// The time span `[from, to]` a static reference covers as one interval, `None` when
    /// its segments leave a hole inside it (or for the others: they cover all times).
    pub fn static_span_s(&self) -> Option<[f64; 2]> {
        let ReferenceSpec::Static { segments, .. } = self else {
            return None;
        };
        let mut sorted: Vec<&StaticSegment> = segments.iter().collect();
        sorted.sort_by(|a, b| a.from_s.total_cmp(&b.from_s));
        let first = sorted.first()?;
        let mut end = first.to_s;
        for s in &sorted[1..] {
            if s.from_s > end {
                return None;
            }
            end = end.max(s.to_s);
        }
        Some([first.from_s, end])
    }
}

/// The chain of a reference accelerometer recorded in V (`[reference.chain]` of a rig
/// file, `[reference_chain]` of a campaign manifest): what turns its volts into g, body
/// axes x, y, z. Undone by `vibro_ident::chain` (MODEL.md section 12's sensor chain).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ReferenceChain {
    /// Volts per g per body axis; a negative value flips the axis.
    pub sensitivity_v_per_g: [f64; 3],
    /// Corner of the first-order AC coupling, Hz; `None`: DC-coupled.
    pub ac_corner_hz: Option<f64>,
    /// A sample stamped `s` saw the table at `s - delay_s`, s (0..=[`MAX_DELAY_S`]).
    pub delay_s: f64,
}

/// The largest sensitivity a chain may state, V/g (as `vibro_waveform::chain`'s).
pub const MAX_SENSITIVITY_V_PER_G: f64 = 1e6;

/// The highest AC corner a chain may state, Hz (as `vibro_waveform::chain`'s).
pub const MAX_AC_CORNER_HZ: f64 = 1e3;

/// A reference chain as written in a file (`deny_unknown_fields`): validated by
/// [`ReferenceChain::from_raw`].
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawReferenceChain {
    sensitivity_v_per_g: Option<OneOrThree>,
    ac_corner_hz: Option<f64>,
    delay_s: Option<f64>,
}

impl ReferenceChain {
    /// Validates `raw`, each broken rule added to `problems` as `KEY.field = value: rule`
    /// (`key`: where the table sits, `reference.chain` or `reference_chain`); `None`
    /// when any rule is broken.
    pub fn from_raw(
        raw: &RawReferenceChain,
        key: &str,
        problems: &mut Vec<String>,
    ) -> Option<ReferenceChain> {
        let start = problems.len();
        let sensitivity = match &raw.sensitivity_v_per_g {
            None => {
                problems.push(format!(
 "{key}.sensitivity_v_per_g: missing: the reference's V/g (one value or [x, y, z])"
                ));
                None
            }
            Some(s) => {
                let v = match s {
                    OneOrThree::One(x) => Some([*x; 3]),
                    OneOrThree::Three(v) => <[f64; 3]>::try_from(v.as_slice()).ok(),
                };
                match v {
                    Some(v)
                        if v.iter().all(|x| {
                            x.is_finite() && *x != 0.0 && x.abs() <= MAX_SENSITIVITY_V_PER_G
                        }) =>
                    {
                        Some(v)
                    }
                    _ => {
                        problems.push(format!(
 "{key}.sensitivity_v_per_g = {}: must be one or three finite non-zero numbers of at most {MAX_SENSITIVITY_V_PER_G:e} V/g in size (a negative one flips the axis)",
                            s.show()
                        ));
                        None
                    }
                }
            }
        };
        let ac_corner_hz = match raw.ac_corner_hz {
            None | Some(0.0) => None,
            Some(x) if x.is_finite() && x > 0.0 && x <= MAX_AC_CORNER_HZ => Some(x),
            Some(x) => {
                problems.push(format!(
 "{key}.ac_corner_hz = {x}: must be finite, > 0 and <= {MAX_AC_CORNER_HZ} Hz (absent or 0: DC-coupled)"
                ));
                None
            }
        };
        let delay_s = raw.delay_s.unwrap_or(0.0);
        if !(delay_s.is_finite() && (0.0..=MAX_DELAY_S).contains(&delay_s)) {
            problems.push(format!(
 "{key}.delay_s = {delay_s}: must be finite and 0 <= delay <= {MAX_DELAY_S} s (a sample stamped s saw the table at s - delay_s)"
            ));
        }
        match (problems.len() == start, sensitivity) {
            (true, Some(sensitivity_v_per_g)) => Some(ReferenceChain {
                sensitivity_v_per_g,
                ac_corner_hz,
                delay_s,
            }),
            _ => None,
        }
    }
}

/// A validated rig file.
#[derive(Debug, Clone)]
pub struct RigConfig {
    /// The file, as given.
    pub file: String,
    pub triad: TriadConfig,
    pub sensors: SensorChain,
    pub reference: ReferenceSpec,
    /// The reference accelerometer's chain (`[reference.chain]`): its CSV is in V;
    /// `None`: DC-coupled, in g.
    pub reference_chain: Option<ReferenceChain>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRig {
    format: String,
    triad: Option<String>,
    sensors: RawSensors,
    reference: RawReference,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSensors {
    sensitivity_v_per_g: OneOrThree,
    ac_corner_hz: Option<f64>,
    delay_s: Option<f64>,
    rate_hz: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum OneOrThree {
    One(f64),
    Three(Vec<f64>),
}

impl OneOrThree {
    fn show(&self) -> String {
        match self {
            OneOrThree::One(x) => x.to_string(),
            OneOrThree::Three(v) => format!("{v:?}"),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawReference {
    kind: String,
    gravity_g: Option<f64>,
    #[serde(default)]
    segment: Vec<RawSegment>,
    up: Option<Direction>,
    radius_m: Option<f64>,
    rate_rad_s: Option<f64>,
    toward_centre: Option<Direction>,
    columns: Option<Vec<String>>,
    chain: Option<RawReferenceChain>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSegment {
    from_s: f64,
    to_s: f64,
    up: Direction,
}

/// A body direction: a signed axis or a vector.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum Direction {
    Axis(String),
    Vector(Vec<f64>),
}

/// A body direction as a unit vector, or the rule it breaks.
fn direction(d: &Direction) -> std::result::Result<[f64; 3], String> {
    match d {
        Direction::Axis(text) => SignedAxis::parse(text)
            .map(|a| {
                let mut v = [0.0; 3];
                v[a.body_index] = f64::from(a.sign);
                v
            })
            .ok_or_else(|| {
                "must be a signed body axis such as \"+z\", or a unit vector [x, y, z]".into()
            }),
        Direction::Vector(v) => {
            let [x, y, z] = v[..] else {
                return Err("must be three finite numbers [x, y, z]".into());
            };
            if ![x, y, z].iter().all(|c| c.is_finite()) {
                return Err("must be three finite numbers [x, y, z]".into());
            }
            vibro_physics::triad::unit_vector(&[x, y, z])
        }
    }
}

fn show(d: &Direction) -> String {
    match d {
        Direction::Axis(t) => format!("{t:?}"),
        Direction::Vector(v) => format!("{v:?}"),
    }
}

/// Most orientations a static reference lists: a multi-position test holds tens (ten
/// positions, each twice); they are sorted to find overlaps.
pub const MAX_SEGMENTS: usize = 4096;

/// Every string and list of the file against its bound: whether all are within, each
/// one over added to `p`.
fn check_sizes(raw: &RawRig, p: &mut Vec<String>) -> bool {
    use vibro_toml::bounds::{list, text, texts, MAX_NAME_BYTES, MAX_PATH_BYTES};
    // A format, a kind or a signed axis: one word.
    const MAX_WORD_BYTES: usize = 64;
    let direction = |key: &str, d: &Direction, p: &mut Vec<String>| match d {
        Direction::Axis(a) => text(key, a, MAX_WORD_BYTES, p),
        Direction::Vector(v) => list(key, v.len(), 3, p),
    };
    let mut ok = text("format", &raw.format, MAX_WORD_BYTES, p);
    if let Some(t) = &raw.triad {
        ok &= text("triad", t, MAX_PATH_BYTES, p);
    }
    if let OneOrThree::Three(v) = &raw.sensors.sensitivity_v_per_g {
        ok &= list("sensors.sensitivity_v_per_g", v.len(), 3, p);
    }
    let r = &raw.reference;
    ok &= text("reference.kind", &r.kind, MAX_WORD_BYTES, p);
    if list("reference.segment", r.segment.len(), MAX_SEGMENTS, p) {
        for (i, s) in r.segment.iter().enumerate() {
            ok &= direction(&format!("reference.segment[{i}].up"), &s.up, p);
        }
    } else {
        ok = false;
    }
    for (key, d) in [
        ("reference.up", &r.up),
        ("reference.toward_centre", &r.toward_centre),
    ] {
        if let Some(d) = d {
            ok &= direction(key, d, p);
        }
    }
    if let Some(c) = &r.columns {
        ok &= texts("reference.columns", c, 3, MAX_NAME_BYTES, p);
    }
    if let Some(OneOrThree::Three(v)) = r
        .chain
        .as_ref()
        .and_then(|c| c.sensitivity_v_per_g.as_ref())
    {
        ok &= list("reference.chain.sensitivity_v_per_g", v.len(), 3, p);
    }
    ok
}

/// Parses and validates a rig file's text; `file` names it in errors and anchors a
/// relative triad path.
pub fn parse_rig(text: &str, file: &str) -> Result<RigConfig> {
    let raw: RawRig = vibro_toml::from_str(text, file)?;
    let mut problems = Vec::new();
    // Sizes first: a value over its bound is not looked at further.
    if !check_sizes(&raw, &mut problems) {
        return Err(ConfigError::Invalid {
            file: file.to_string(),
            problems,
        });
    }
    if raw.format != RIG_FORMAT {
        problems.push(format!("format = {:?}: must be {RIG_FORMAT:?}", raw.format));
    }
    let triad_arg = raw.triad.clone().unwrap_or_else(|| "default".into());
    let triad_path = Path::new(file)
        .parent()
        .map(|d| d.join(&triad_arg))
        .filter(|p| p.is_file());
    let triad = match triad_path {
        Some(p) => crate::load_triad(&p),
        None => resolve_triad(&triad_arg),
    };
    let triad = match triad {
        Ok(t) => Some(t),
        Err(e) => {
            problems.push(format!("triad = {triad_arg:?}: {e}"));
            None
        }
    };

    let s = &raw.sensors;
    let sensitivity = match &s.sensitivity_v_per_g {
        OneOrThree::One(x) => Some([*x; 3]),
        OneOrThree::Three(v) => <[f64; 3]>::try_from(v.as_slice()).ok(),
    };
    let sensitivity = match sensitivity {
        Some(v) if v.iter().all(|x| x.is_finite() && *x != 0.0) => Some(v),
        _ => {
            problems.push(format!(
                "sensors.sensitivity_v_per_g = {:?}: must be one or three finite non-zero \
                 numbers (V/g; a negative one flips the axis)",
                s.sensitivity_v_per_g
            ));
            None
        }
    };
    let ac_corner_hz = match s.ac_corner_hz {
        None => Some(None),
        Some(0.0) => Some(None),
        Some(x) if x.is_finite() && x > 0.0 => Some(Some(x)),
        Some(x) => {
            problems.push(format!(
                "sensors.ac_corner_hz = {x}: must be finite and > 0 (absent or 0: DC-coupled)"
            ));
            None
        }
    };

    let raw_delay_stated = s.delay_s.is_some();
    let delay_s = match s.delay_s.unwrap_or(0.0) {
        x if x.is_finite() && (0.0..=MAX_DELAY_S).contains(&x) => Some(x),
        x => {
            problems.push(format!(
                "sensors.delay_s = {x}: must be finite and 0 <= delay <= {MAX_DELAY_S} s \
                 (a sample stamped s saw the base at s - delay_s)"
            ));
            None
        }
    };
    let [lo_hz, hi_hz] = SENSOR_RATE_RANGE_HZ;
    let rate_hz = match s.rate_hz {
        None => Some(None),
        Some(x) if x.is_finite() && (lo_hz..=hi_hz).contains(&x) => Some(Some(x)),
        Some(x) => {
            problems.push(format!(
                "sensors.rate_hz = {x}: must be finite and {lo_hz:e} <= rate <= {hi_hz:e} Hz"
            ));
            None
        }
    };

    let reference = reference(&raw.reference, &mut problems);
    let reference_chain = match &raw.reference.chain {
        None => Some(None),
        Some(_) if raw.reference.kind == "stream" => {
            problems.push(
                "reference.chain: not a key of kind = \"stream\" (a stream is in g; a chain \
                 goes with a static or centrifuge reference, whose orientation gives gravity)"
                    .into(),
            );
            None
        }
        Some(c) => ReferenceChain::from_raw(c, "reference.chain", &mut problems).map(Some),
    };
    if let (
        true,
        Some(triad),
        Some(sensitivity_v_per_g),
        Some(ac_corner_hz),
        Some(delay_s),
        Some(rate_hz),
        Some(reference),
        Some(reference_chain),
    ) = (
        problems.is_empty(),
        triad,
        sensitivity,
        ac_corner_hz,
        delay_s,
        rate_hz,
        reference,
        reference_chain,
    ) {
        return Ok(RigConfig {
            file: file.to_string(),
            triad,
            sensors: SensorChain {
                sensitivity_v_per_g,
                ac_corner_hz,
                delay_s,
                delay_stated: raw_delay_stated,
                rate_hz,
            },
            reference,
            reference_chain,
        });
    }
    Err(ConfigError::Invalid {
        file: file.to_string(),
        problems,
    })
}

/// The `[reference]` table, its problems added to `problems`.
fn reference(r: &RawReference, problems: &mut Vec<String>) -> Option<ReferenceSpec> {
    let start = problems.len();
    let gravity = |problems: &mut Vec<String>| match r.gravity_g {
        None => Some(1.0),
        Some(g) if g.is_finite() && g > 0.0 && g < 100.0 => Some(g),
        Some(g) => {
            problems.push(format!(
                "reference.gravity_g = {g}: must be finite, > 0 and < 100 (g)"
            ));
            None
        }
    };
    let unused = |key: &str, present: bool, problems: &mut Vec<String>| {
        if present {
            problems.push(format!("reference.{key}: not a key of kind = {:?}", r.kind));
        }
    };
    let out = match r.kind.as_str() {
        "static" => {
            unused("up", r.up.is_some(), problems);
            unused("radius_m", r.radius_m.is_some(), problems);
            unused("rate_rad_s", r.rate_rad_s.is_some(), problems);
            unused("toward_centre", r.toward_centre.is_some(), problems);
            unused("columns", r.columns.is_some(), problems);
            let gravity_g = gravity(problems);
            if r.segment.is_empty() {
                problems.push(
                    "reference.segment: none: a static reference lists its orientations as \
                     [[reference.segment]] (from_s, to_s, up)"
                        .into(),
                );
            }
            let mut segments = Vec::new();
            for (i, s) in r.segment.iter().enumerate() {
                let key = format!("reference.segment[{i}]");
                if !(s.from_s.is_finite() && s.to_s.is_finite() && s.to_s > s.from_s) {
                    problems.push(format!(
                        "{key}: from_s = {}, to_s = {}: must be finite with to_s > from_s",
                        s.from_s, s.to_s
                    ));
                }
                match direction(&s.up) {
                    Ok(up) => segments.push(StaticSegment {
                        from_s: s.from_s,
                        to_s: s.to_s,
                        up,
                    }),
                    Err(rule) => problems.push(format!("{key}.up = {}: {rule}", show(&s.up))),
                }
            }
            let mut sorted: Vec<(usize, &RawSegment)> = r.segment.iter().enumerate().collect();
            sorted.sort_by(|a, b| a.1.from_s.total_cmp(&b.1.from_s));
            for w in sorted.windows(2) {
                let ((i, a), (j, b)) = (w[0], w[1]);
                if b.from_s < a.to_s {
                    problems.push(format!(
                        "reference.segment[{j}] (from_s = {}) overlaps reference.segment[{i}] \
                         (to_s = {}): one orientation at a time",
                        b.from_s, a.to_s
                    ));
                }
            }
            gravity_g.map(|gravity_g| ReferenceSpec::Static {
                gravity_g,
                segments,
            })
        }
        "centrifuge" => {
            unused("segment", !r.segment.is_empty(), problems);
            unused("columns", r.columns.is_some(), problems);
            let gravity_g = gravity(problems);
            let dir = |key: &str, d: &Option<Direction>, problems: &mut Vec<String>| match d {
                None => {
                    problems.push(format!(
                        "reference.{key}: missing: a centrifuge states it (a signed body axis or [x, y, z])"
                    ));
                    None
                }
                Some(d) => match direction(d) {
                    Ok(v) => Some(v),
                    Err(rule) => {
                        problems.push(format!("reference.{key} = {}: {rule}", show(d)));
                        None
                    }
                },
            };
            let up = dir("up", &r.up, problems);
            let toward_centre = dir("toward_centre", &r.toward_centre, problems);
            let positive = |key: &str, v: Option<f64>, problems: &mut Vec<String>| match v {
                Some(x) if x.is_finite() && x >= 0.0 => Some(x),
                Some(x) => {
                    problems.push(format!("reference.{key} = {x}: must be finite and >= 0"));
                    None
                }
                None => {
                    problems.push(format!("reference.{key}: missing: a centrifuge states it"));
                    None
                }
            };
            let radius_m = positive("radius_m", r.radius_m, problems);
            let rate_rad_s = positive("rate_rad_s", r.rate_rad_s, problems);
            match (gravity_g, up, toward_centre, radius_m, rate_rad_s) {
                (
                    Some(gravity_g),
                    Some(up),
                    Some(toward_centre),
                    Some(radius_m),
                    Some(rate_rad_s),
                ) => Some(ReferenceSpec::Centrifuge {
                    gravity_g,
                    up,
                    radius_m,
                    rate_rad_s,
                    toward_centre,
                }),
                _ => None,
            }
        }
        "stream" => {
            unused("segment", !r.segment.is_empty(), problems);
            unused("up", r.up.is_some(), problems);
            unused("radius_m", r.radius_m.is_some(), problems);
            unused("rate_rad_s", r.rate_rad_s.is_some(), problems);
            unused("toward_centre", r.toward_centre.is_some(), problems);
            unused("gravity_g", r.gravity_g.is_some(), problems);
            let columns = r
                .columns
                .clone()
                .unwrap_or_else(|| ["ax_g", "ay_g", "az_g"].map(String::from).to_vec());
            match <[String; 3]>::try_from(columns.clone()) {
                Ok(c)
                    if c.iter().all(|x| !x.trim().is_empty())
                        && c[0] != c[1]
                        && c[1] != c[2]
                        && c[0] != c[2] =>
                {
                    Some(ReferenceSpec::Stream { columns: c })
                }
                _ => {
                    problems.push(format!(
                        "reference.columns = {columns:?}: must be three different column names \
                         (body x, y, z)"
                    ));
                    None
                }
            }
        }
        other => {
            problems.push(format!(
                "reference.kind = {other:?}: must be \"static\", \"centrifuge\" or \"stream\""
            ));
            None
        }
    };
    if problems.len() > start {
        return None;
    }
    out
}

/// Loads a rig file.
pub fn load_rig(path: &Path) -> Result<RigConfig> {
    parse_rig(&read(path)?, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "format = \"vibrocomp-rig/1\"\n\
        [sensors]\nsensitivity_v_per_g = 0.1\nac_corner_hz = 2.0\n\
        [reference]\nkind = \"static\"\n\
        [[reference.segment]]\nfrom_s = 0.0\nto_s = 8.0\nup = \"+z\"\n\
        [[reference.segment]]\nfrom_s = 8.0\nto_s = 16.0\nup = [0.6, 0.0, -0.8]\n";

    /// Issue 46, item 7: every string and list is bounded, checked first, every one
    /// over its bound reported at once.
    #[test]
    fn strings_and_lists_over_their_bounds_are_refused_first() {
        let segment = "[[reference.segment]]\nfrom_s = 0.0\nto_s = 1.0\nup = \"+z\"\n";
        let text = format!(
            "format = \"vibrocomp-rig/1\"\ntriad = \"{}\"\n[sensors]\nsensitivity_v_per_g = [{}]\n\
             [reference]\nkind = \"static\"\n{}",
            "t".repeat(5000),
            ["0.1"; 4].join(", "),
            segment.repeat(MAX_SEGMENTS + 1)
        );
        let e = parse_rig(&text, "r.toml").unwrap_err();
        let ConfigError::Invalid { problems, .. } = &e else {
            panic!("{e}")
        };
        assert_eq!(problems.len(), 3, "{e}");
        assert!(problems[0].starts_with("triad = \"tttt"), "{e}");
        assert!(
            problems[0].ends_with("(5000 bytes): at most 4095 bytes"),
            "{e}"
        );
        assert_eq!(
            problems[1],
            "sensors.sensitivity_v_per_g: 4 entries: at most 3"
        );
        assert_eq!(problems[2], "reference.segment: 4097 entries: at most 4096");
        let text = GOOD.replace("up = \"+z\"", &format!("up = \"{}\"", "+".repeat(70)));
        let e = parse_rig(&text, "r.toml").unwrap_err().to_string();
        assert!(
            e.contains("reference.segment[0].up = \"++++")
                && e.ends_with("(70 bytes): at most 64 bytes"),
            "{e}"
        );
    }

    #[test]
    fn a_static_rig_reads_its_orientations() {
        let rig = parse_rig(GOOD, "rig.toml").unwrap();
        assert_eq!(rig.sensors.sensitivity_v_per_g, [0.1; 3]);
        assert_eq!(rig.sensors.ac_corner_hz, Some(2.0));
        assert_eq!((rig.sensors.delay_s, rig.sensors.rate_hz), (0.0, None));
        assert!(!rig.sensors.delay_stated);
        assert_eq!(rig.triad.id, "default");
        assert_eq!(rig.reference.body_g_at(4.0), Some([0.0, 0.0, 1.0]));
        let b = rig.reference.body_g_at(12.0).unwrap();
        assert!((b[0] - 0.6).abs() < 1e-15 && (b[2] + 0.8).abs() < 1e-15);
        assert_eq!(rig.reference.body_g_at(16.5), None);
        assert_eq!(rig.reference.static_span_s(), Some([0.0, 16.0]));
    }

    /// `sensors.delay_s` (default 0) and the optional `sensors.rate_hz`, each refused
    /// with its key, value and rule when out of bounds, all at once.
    #[test]
    fn the_chain_delay_and_rate_are_read_and_bounded() {
        let with = |extra: &str| {
            GOOD.replace(
                "ac_corner_hz = 2.0\n",
                &format!("ac_corner_hz = 2.0\n{extra}"),
            )
        };
        let rig = parse_rig(&with("delay_s = 0.00156\nrate_hz = 25600.0\n"), "r.toml").unwrap();
        assert_eq!(rig.sensors.delay_s, 0.00156);
        assert!(rig.sensors.delay_stated);
        assert_eq!(rig.sensors.rate_hz, Some(25_600.0));
        for (text, want) in [
            (
                "delay_s = -0.001\n",
                "sensors.delay_s = -0.001: must be finite and 0 <= delay <= 1 s",
            ),
            (
                "delay_s = 2\n",
                "sensors.delay_s = 2: must be finite and 0 <= delay <= 1 s",
            ),
            ("delay_s = nan\n", "sensors.delay_s = NaN: must be finite"),
            ("delay_s = inf\n", "sensors.delay_s = inf: must be finite"),
            (
                "rate_hz = 0.0\n",
                "sensors.rate_hz = 0: must be finite and 1e-3 <= rate <= 1e9 Hz",
            ),
        ] {
            let e = parse_rig(&with(text), "r.toml").unwrap_err().to_string();
            assert!(
                e.starts_with("r.toml: ") && e.contains(want),
                "{want:?} not in {e}"
            );
        }
        let e = parse_rig(&with("delay_s = -1.0\nrate_hz = -5.0\n"), "r.toml").unwrap_err();
        let ConfigError::Invalid { problems, .. } = &e else {
            panic!("{e}")
        };
        assert_eq!(problems.len(), 2, "{e}");
    }

    /// Issue "round two", item 9: `[reference.chain]` states an AC-coupled reference's
    /// sensitivity, corner and delay; absent, the reference is DC-coupled in g.
    #[test]
    fn a_reference_chain_is_read() {
        assert_eq!(parse_rig(GOOD, "r.toml").unwrap().reference_chain, None);
        let text = format!(
            "{GOOD}[reference.chain]\nsensitivity_v_per_g = [0.01, -0.01, 0.02]\n\
             ac_corner_hz = 0.5\ndelay_s = 0.0013\n"
        );
        let chain = parse_rig(&text, "r.toml").unwrap().reference_chain.unwrap();
        assert_eq!(chain.sensitivity_v_per_g, [0.01, -0.01, 0.02]);
        assert_eq!((chain.ac_corner_hz, chain.delay_s), (Some(0.5), 0.0013));
        let dc = format!("{GOOD}[reference.chain]\nsensitivity_v_per_g = 0.01\nac_corner_hz = 0\n");
        let chain = parse_rig(&dc, "r.toml").unwrap().reference_chain.unwrap();
        assert_eq!((chain.ac_corner_hz, chain.delay_s), (None, 0.0));
    }

    /// Every bad chain value at once, each with the file, the key, the value and the rule.
    #[test]
    fn bad_reference_chain_values_are_listed_at_once() {
        let text = format!(
            "{GOOD}[reference.chain]\nsensitivity_v_per_g = [0.01, 0.0, 0.01]\n\
             ac_corner_hz = -2.0\ndelay_s = 1.5\n"
        );
        let e = parse_rig(&text, "bad.toml").unwrap_err();
        let ConfigError::Invalid { file, problems } = &e else {
            panic!("{e}")
        };
        assert_eq!(file, "bad.toml");
        assert_eq!(problems.len(), 3, "{e}");
        assert!(
            problems[0].starts_with(
                "reference.chain.sensitivity_v_per_g = [0.01, 0.0, 0.01]: must be one or three \
             finite non-zero numbers"
            ),
            "{e}"
        );
        assert!(problems[1].starts_with("reference.chain.ac_corner_hz = -2: must be finite, > 0"));
        assert!(problems[2]
            .starts_with("reference.chain.delay_s = 1.5: must be finite and 0 <= delay <= 1 s"));
        let e = parse_rig(
            &format!("{GOOD}[reference.chain]\nac_corner_hz = 0.5\n"),
            "m.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("m.toml") && e.contains("reference.chain.sensitivity_v_per_g: missing"),
            "{e}"
        );
        let e = parse_rig(
            &format!("{GOOD}[reference.chain]\nsensitivity_v_per_g = 0.01\ncorner = 1\n"),
            "u.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("corner"), "{e}");
        let stream = "format = \"vibrocomp-rig/1\"\n[sensors]\nsensitivity_v_per_g = 0.1\n\
            [reference]\nkind = \"stream\"\n[reference.chain]\nsensitivity_v_per_g = 0.01\n";
        let e = parse_rig(stream, "s.toml").unwrap_err().to_string();
        assert!(
            e.contains("reference.chain: not a key of kind = \"stream\""),
            "{e}"
        );
    }

    #[test]
    fn a_centrifuge_adds_its_centripetal_acceleration() {
        let text =
            "format = \"vibrocomp-rig/1\"\n[sensors]\nsensitivity_v_per_g = [0.1, -0.1, 0.1]\n\
            [reference]\nkind = \"centrifuge\"\nup = \"+z\"\ntoward_centre = \"-x\"\n\
            radius_m = 1.0\nrate_rad_s = 9.90285\n";
        let rig = parse_rig(text, "c.toml").unwrap();
        let a = rig.reference.body_g_at(123.0).unwrap();
        // 9.90285^2 * 1 m = 98.0664 m/s^2 = 10.000 g toward the centre.
        assert!((a[0] + 10.0).abs() < 1e-4, "{a:?}");
        assert_eq!((a[1], a[2]), (0.0, 1.0));
        assert_eq!(rig.sensors.sensitivity_v_per_g, [0.1, -0.1, 0.1]);
    }

    #[test]
    fn every_problem_is_listed_at_once() {
        let text = "format = \"vibrocomp-rig/2\"\ntriad = \"nowhere.toml\"\n\
            [sensors]\nsensitivity_v_per_g = [0.1, 0.0]\nac_corner_hz = -1.0\n\
            [reference]\nkind = \"static\"\ngravity_g = 0.0\n\
            [[reference.segment]]\nfrom_s = 0.0\nto_s = 8.0\nup = [0.0, 0.5, 0.5]\n\
            [[reference.segment]]\nfrom_s = 6.0\nto_s = 4.0\nup = \"+w\"\n";
        let e = parse_rig(text, "bad.toml").unwrap_err().to_string();
        for want in [
            "bad.toml",
            "format = \"vibrocomp-rig/2\": must be \"vibrocomp-rig/1\"",
            "triad = \"nowhere.toml\"",
            "sensors.sensitivity_v_per_g",
            "sensors.ac_corner_hz = -1: must be finite and > 0",
            "reference.gravity_g = 0: must be finite, > 0",
            "reference.segment[0].up = [0.0, 0.5, 0.5]: must be a unit vector (its norm is 0.707107",
            "reference.segment[1]: from_s = 6, to_s = 4: must be finite with to_s > from_s",
            "reference.segment[1].up = \"+w\": must be a signed body axis",
        ] {
            assert!(e.contains(want), "missing {want:?} in {e}");
        }
        let e = parse_rig(
            "format = \"vibrocomp-rig/1\"\n[sensors]\nsensitivity_v_per_g = 0.1\n\
             [reference]\nkind = \"static\"\nup = \"+z\"\nspeed = 3\n",
            "k.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("speed"), "{e}");
        let e = parse_rig(
            "format = \"vibrocomp-rig/1\"\n[sensors]\nsensitivity_v_per_g = 0.1\n\
             [reference]\nkind = \"static\"\nup = \"+z\"\n",
            "k.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("reference.up: not a key of kind = \"static\"")
                && e.contains("reference.segment: none"),
            "{e}"
        );
        let e = parse_rig(
            "format = \"vibrocomp-rig/1\"\n[sensors]\nsensitivity_v_per_g = 0.1\n\
             [reference]\nkind = \"static\"\n[[reference.segment]]\nfrom_s = 0.0\nto_s = 5.0\nup = \"+z\"\n\
             [[reference.segment]]\nfrom_s = 4.0\nto_s = 8.0\nup = \"-z\"\n",
            "o.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("reference.segment[1] (from_s = 4) overlaps"),
            "{e}"
        );
    }
}
