//! A shake-table campaign from a rig's raw records: a manifest (TOML) lists the runs,
//! each with its unit-output record (still / vibrating / still, one CSV for the triad)
//! and the reference accelerometer's record on the table, and the table's orientation;
//! this module measures each unit's VE by [P2 (16)] with the unit's linear response to
//! the table's motion removed through the reference (`vibro_ident::rig`, which
//! `vibrocomp identify measure` shares for one unit's files), and
//! estimates the vibration each unit saw from the reference's vibrating record with the
//! estimator (tones with per-axis amplitudes and phases, random RMS, covariances,
//! kurtosis, band PSDs), mapped to each unit's axes through the triad. The result is the
//! lab's table, one row per run and unit (docs/lab.md, "Shake-table campaigns from raw
//! records"; issue 30).
//!
//! ```toml
//! format = "vibrocomp-campaign/1"
//! triad = "default"                  # a triad file (relative to the manifest) or "default"
//! gravity_g = 1.0                    # the local gravity, g (default 1)
//! unit_columns = ["u1_v", "u2_v", "u3_v"]          # the triad's outputs, V (default)
//! reference_columns = ["ax_g", "ay_g", "az_g"]     # body x, y, z, g, DC-coupled (default)
//! batches = 20                       # batch means per record (default 20)
//! tilt_limit_rad = 1e-4              # [P2] (default)
//!
//! [segments]                         # every run's windows on its files' time, s
//! still_before_s = [0.0, 8.0]
//! vibrating_s = [8.2, 15.9]
//! still_after_s = [16.1, 24.0]
//!
//! [[run]]
//! id = "run000"
//! accel = "run000/accel.csv"         # time_s and the unit columns
//! reference = "run000/reference.csv" # time_s and the reference columns
//! up = "+z"                          # the body direction pointing up: "+x".."-z" or [x, y, z]
//! # segments = { ... }               # this run's own windows
//! ```

use crate::flight::{self, WindowInput, WindowVe};
use crate::spectrum::{sensor_spectrum, unit_bands, SpectrumSolver};
use crate::{CampaignTable, Condition, Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use vibro_config::TriadConfig;
use vibro_dsp::{BandLeakage, Estimator, EstimatorConfig, EstimatorConfigRaw, SampleBlock};
use vibro_effects::mapping::{sensor_map, unit_vibrations, EstimateMapping};
use vibro_effects::predict::flat_passport;
use vibro_ident::reference::LinearFit;
use vibro_ident::rig::{check_segments, BodyAxes, RunReference};
use vibro_ident::{MeasureOptions, Segments, TimedMeasurement};
use vibro_msgs::{estimate_flags, VibEstimate};
use vibro_physics::passport::Passport;
use vibro_physics::triad::SignedAxis;
use vibro_physics::vibration::{PsdBand, Vibration};

/// The manifest's `format`.
pub const FORMAT: &str = "vibrocomp-campaign/1";

/// An orientation stated as `|up| = 1` within this (the rule of every body direction,
/// `vibro_ident::rig`).
pub const UNIT_VECTOR_TOLERANCE: f64 = vibro_ident::rig::UNIT_VECTOR_TOLERANCE;

/// The reference's still mean may differ from `gravity_g * up` by this much, g, before
/// the run is refused (a wrong orientation is 1 g or more off; a reference's bias and a
/// table's level are far less).
pub const ORIENTATION_CHECK_G: f64 = 0.05;

/// A band of the estimated spectrum counts in the random part's flat band when its PSD
/// on the unit's IA is at least this fraction of the strongest band's.
pub const FLAT_BAND_FRACTION: f64 = 0.05;

/// Most runs one manifest lists.
pub const MAX_RUNS: usize = 10_000;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    format: String,
    #[serde(default = "default_triad")]
    triad: String,
    #[serde(default = "default_gravity")]
    gravity_g: f64,
    #[serde(default = "default_unit_columns")]
    unit_columns: Vec<String>,
    #[serde(default = "default_reference_columns")]
    reference_columns: Vec<String>,
    #[serde(default = "default_batches")]
    batches: usize,
    #[serde(default = "default_tilt_limit")]
    tilt_limit_rad: f64,
    segments: Option<Segments>,
    #[serde(default)]
    run: Vec<RawRun>,
}

fn default_triad() -> String {
    "default".into()
}
fn default_gravity() -> f64 {
    1.0
}
fn default_unit_columns() -> Vec<String> {
    ["u1_v", "u2_v", "u3_v"].map(String::from).to_vec()
}
fn default_reference_columns() -> Vec<String> {
    ["ax_g", "ay_g", "az_g"].map(String::from).to_vec()
}
fn default_batches() -> usize {
    MeasureOptions::default().n_batches
}
fn default_tilt_limit() -> f64 {
    MeasureOptions::default().tilt_limit_rad
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRun {
    id: String,
    accel: PathBuf,
    reference: PathBuf,
    up: Up,
    segments: Option<Segments>,
}

/// The body direction pointing up: a signed axis or a vector.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum Up {
    Axis(String),
    Vector(Vec<f64>),
}

/// One run of a validated manifest.
#[derive(Debug, Clone, Serialize)]
pub struct Run {
    pub id: String,
    pub accel: PathBuf,
    pub reference: PathBuf,
    /// The body direction pointing up, a unit vector.
    pub up: [f64; 3],
    pub segments: Segments,
}

/// A validated manifest: every path resolved against the manifest's folder.
#[derive(Debug, Clone)]
pub struct Manifest {
    pub path: PathBuf,
    pub triad: TriadConfig,
    pub gravity_g: f64,
    pub unit_columns: [String; 3],
    pub reference_columns: [String; 3],
    pub measure: MeasureOptions,
    pub runs: Vec<Run>,
}

impl Manifest {
    /// Reads and validates a manifest: every problem at once (key, value, rule), the
    /// files each run names checked to exist before anything is read.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// [`Manifest::load`] from text; `path` names it and its folder anchors the runs'
    /// files.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let name = path.display().to_string();
        // The TOML error names the file, the line and the key.
        let raw: RawManifest =
            vibro_toml::from_str(text, &name).map_err(|e| Error::Invalid(e.to_string()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut problems = Vec::new();
        if raw.format != FORMAT {
            problems.push(format!("format = {:?}: must be {FORMAT:?}", raw.format));
        }
        let triad_path = dir.join(&raw.triad);
        let triad_arg = if triad_path.is_file() {
            triad_path.display().to_string()
        } else {
            raw.triad.clone()
        };
        let triad = match vibro_config::resolve_triad(&triad_arg) {
            Ok(t) => Some(t),
            Err(e) => {
                problems.push(format!("triad = {:?}: {e}", raw.triad));
                None
            }
        };
        if !(raw.gravity_g.is_finite() && raw.gravity_g > 0.0 && raw.gravity_g <= 2.0) {
            problems.push(format!(
                "gravity_g = {}: must be a local gravity in (0, 2] g",
                raw.gravity_g
            ));
        }
        let columns =
            |key: &str, list: &[String], problems: &mut Vec<String>| match <[String; 3]>::try_from(
                list.to_vec(),
            ) {
                Ok(c) if c.iter().all(|s| !s.is_empty() && s != "time_s") => Some(c),
                _ => {
                    problems.push(format!(
                        "{key} = {list:?}: must name three columns other than time_s, one per \
                         unit (unit_columns) or body axis x, y, z (reference_columns)"
                    ));
                    None
                }
            };
        let unit_columns = columns("unit_columns", &raw.unit_columns, &mut problems);
        let reference_columns = columns("reference_columns", &raw.reference_columns, &mut problems);
        let measure = MeasureOptions {
            n_batches: raw.batches,
            tilt_limit_rad: raw.tilt_limit_rad,
        };
        problems.extend(measure.problems());
        if let Some(s) = &raw.segments {
            problems.extend(s.problems().into_iter().map(|p| format!("segments.{p}")));
        }
        if raw.run.is_empty() {
            problems.push("run: no runs: list each as [[run]] (id, accel, reference, up)".into());
        }
        if raw.run.len() > MAX_RUNS {
            problems.push(format!(
                "run: {} runs: at most {MAX_RUNS} in one manifest",
                raw.run.len()
            ));
        }
        let mut runs = Vec::new();
        let mut seen = std::collections::BTreeSet::new();
        for (i, r) in raw.run.iter().enumerate().take(MAX_RUNS) {
            let key = format!("run[{i}]");
            if r.id.trim().is_empty() {
                problems.push(format!("{key}.id = {:?}: must not be empty", r.id));
            } else if !seen.insert(r.id.clone()) {
                problems.push(format!(
                    "{key}.id = {:?}: must be unique (used before)",
                    r.id
                ));
            }
            for (field, file) in [("accel", &r.accel), ("reference", &r.reference)] {
                let full = dir.join(file);
                if !full.is_file() {
                    problems.push(format!(
                        "{key}.{field} = {:?}: no such file ({})",
                        file.display(),
                        full.display()
                    ));
                }
            }
            let up = match &r.up {
                Up::Axis(text) => match SignedAxis::parse(text) {
                    Some(a) => {
                        let mut v = [0.0; 3];
                        v[a.body_index] = f64::from(a.sign);
                        Some(v)
                    }
                    None => {
                        problems.push(format!(
                            "{key}.up = {text:?}: must be a signed body axis such as \"+z\", or \
                             a unit vector [x, y, z]"
                        ));
                        None
                    }
                },
                Up::Vector(v) => {
                    if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
                        problems.push(format!(
                            "{key}.up = {v:?}: must be three finite numbers [x, y, z]"
                        ));
                        None
                    } else {
                        match vibro_ident::rig::unit_vector(v) {
                            Ok(up) => Some(up),
                            Err(rule) => {
                                problems.push(format!("{key}.up = {v:?}: {rule}"));
                                None
                            }
                        }
                    }
                }
            };
            let segments = match (&r.segments, &raw.segments) {
                (Some(s), _) => {
                    problems.extend(
                        s.problems()
                            .into_iter()
                            .map(|p| format!("{key}.segments.{p}")),
                    );
                    Some(*s)
                }
                (None, Some(s)) => Some(*s),
                (None, None) => {
                    problems.push(format!(
                        "{key}.segments: missing: give [segments] for every run or the run's own"
                    ));
                    None
                }
            };
            if let (Some(up), Some(segments)) = (up, segments) {
                runs.push(Run {
                    id: r.id.clone(),
                    accel: dir.join(&r.accel),
                    reference: dir.join(&r.reference),
                    up,
                    segments,
                });
            }
        }
        match (triad, unit_columns, reference_columns) {
            (Some(triad), Some(unit_columns), Some(reference_columns)) if problems.is_empty() => {
                Ok(Self {
                    path: path.to_path_buf(),
                    triad,
                    gravity_g: raw.gravity_g,
                    unit_columns,
                    reference_columns,
                    measure,
                    runs,
                })
            }
            _ => Err(Error::Table {
                path: name,
                problems,
            }),
        }
    }
}

/// One unit of one run: the measured VE and the vibration it saw.
#[derive(Debug, Clone, Serialize)]
pub struct UnitResult {
    pub run_id: String,
    pub unit: String,
    /// `[aL1, aL2, aL3]` from the orientation, g.
    pub a_l_g: [f64; 3],
    /// The VE with the linear response removed through the reference, and the raw
    /// records' (for comparison).
    pub measurement: TimedMeasurement,
    /// The unit's linear response fitted through the reference; `None`: the
    /// passport's was removed (a vibrating window too short for the fit).
    pub linear_response: Option<LinearFit>,
    /// The table's row.
    pub condition: Condition,
}

/// What became of one run.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    pub id: String,
    pub readings: usize,
    pub accel_rate_hz: f64,
    pub reference_rate_hz: f64,
    /// Estimator windows inside the vibrating window, and those pooled into the row.
    pub windows: usize,
    pub windows_used: usize,
    /// The reference's still mean, body axes, g (against `gravity_g * up`).
    pub reference_still_g: [f64; 3],
}

/// A campaign measured: the lab's table and, per run and unit, the measurement.
#[derive(Debug, Clone)]
pub struct CampaignResult {
    pub table: CampaignTable,
    pub runs: Vec<RunSummary>,
    pub units: Vec<UnitResult>,
}

/// Measures every run of `manifest` (module docs). `estimator` is the base
/// configuration: the rate is the reference file's, the samples are in g
/// (sensitivity 1, DC-coupled, no response table). `progress(done, of)` after each run.
pub fn measure_campaign(
    manifest: &Manifest,
    estimator: &EstimatorConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<CampaignResult> {
    let passports: Vec<Passport> = manifest
        .triad
        .passports
        .iter()
        .map(flat_passport)
        .collect::<std::result::Result<_, _>>()?;
    let mut runs = Vec::new();
    let mut units = Vec::new();
    let mut problems = Vec::new();
    for (k, run) in manifest.runs.iter().enumerate() {
        match measure_run(manifest, run, &passports, estimator) {
            Ok((summary, mut list)) => {
                runs.push(summary);
                units.append(&mut list);
            }
            Err(e) => problems.push(format!("run {:?}: {e}", run.id)),
        }
        progress(k + 1, manifest.runs.len());
    }
    if !problems.is_empty() {
        return Err(Error::Table {
            path: manifest.path.display().to_string(),
            problems,
        });
    }
    let mut conditions: Vec<Condition> = units.iter().map(|u| u.condition.clone()).collect();
    for (i, c) in conditions.iter_mut().enumerate() {
        c.line = i + 1;
    }
    Ok(CampaignResult {
        table: CampaignTable {
            path: manifest.path.clone(),
            conditions,
            extra_columns: EXTRA_COLUMNS.map(String::from).to_vec(),
        },
        runs,
        units,
    })
}

/// The extra columns of a campaign's rows.
pub const EXTRA_COLUMNS: [&str; 4] = ["vibrating_s", "band_lo_hz", "band_hi_hz", "unit"];

/// Estimate flags that make a window unusable.
const BAD_ESTIMATE: u32 = estimate_flags::GAP
    | estimate_flags::NON_FINITE
    | estimate_flags::OUT_OF_ORDER
    | estimate_flags::INSUFFICIENT_DATA
    | estimate_flags::RATE_MISMATCH;

fn measure_run(
    manifest: &Manifest,
    run: &Run,
    passports: &[Passport],
    base: &EstimatorConfig,
) -> Result<(RunSummary, Vec<UnitResult>)> {
    fn cols(c: &[String; 3]) -> [&str; 3] {
        [c[0].as_str(), c[1].as_str(), c[2].as_str()]
    }
    let ident = |e: vibro_ident::Error| Error::Context {
        what: e.to_string(),
        source: Box::new(e),
    };
    let accel =
        vibro_ident::read_timed(&run.accel, &cols(&manifest.unit_columns)).map_err(ident)?;
    let reference = vibro_ident::read_timed(&run.reference, &cols(&manifest.reference_columns))
        .map_err(ident)?;
    let seg = run.segments;
    check_segments(&accel, &run.accel, &seg).map_err(ident)?;
    // The reference's body axes prepared for each reading's interval mean, and the
    // basis of the units' fitted response, once for the run's three units.
    let f_top_hz = base.raw().broadband_band_hz[1]
        .min(vibro_ident::rig::RESPONSE_TOP_FRACTION_OF_RATE * reference.rate_hz());
    let prepared =
        RunReference::new(&accel, &reference, &run.reference, &seg, f_top_hz).map_err(ident)?;
    // The reference's still mean against the stated orientation.
    let still_mean = |axis: usize| {
        let (mut sum, mut n) = (0.0, 0usize);
        for (i, &t) in reference.time_s.iter().enumerate() {
            let inside = |w: [f64; 2]| t >= w[0] && t <= w[1];
            if inside(seg.still_before_s) || inside(seg.still_after_s) {
                sum += reference.columns[axis][i];
                n += 1;
            }
        }
        sum / n.max(1) as f64
    };
    let reference_still_g = [still_mean(0), still_mean(1), still_mean(2)];
    let stated = run.up.map(|u| u * manifest.gravity_g);
    let off = (0..3)
        .map(|i| (reference_still_g[i] - stated[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    if off > ORIENTATION_CHECK_G {
        return Err(Error::Invalid(format!(
            "the reference reads [{:.4}, {:.4}, {:.4}] g while still; the orientation up = \
             [{:.4}, {:.4}, {:.4}] and gravity_g = {} state [{:.4}, {:.4}, {:.4}] g: {off:.4} g \
             apart, more than {ORIENTATION_CHECK_G} g (a wrong `up`, reference columns in the \
             wrong order or sign, or the reference not in g)",
            reference_still_g[0],
            reference_still_g[1],
            reference_still_g[2],
            run.up[0],
            run.up[1],
            run.up[2],
            manifest.gravity_g,
            stated[0],
            stated[1],
            stated[2]
        )));
    }
    let triad = &manifest.triad;
    let (windows, vibs) = estimate_run(run, &reference, triad, base)?;
    let windows_used = vibs.len();
    let mut out = Vec::new();
    for (u, passport) in passports.iter().enumerate() {
        let axes = &triad.axes.units[u];
        // The passport's linear response [P1 (1)] per body axis: K1 (k1 a3 + m1 a1 + m2 a2),
        // the fitted response's starting point.
        let weights = BodyAxes::from(axes).weights_v_per_g(passport);
        let unit = prepared
            .measure_unit(
                &accel.columns[u],
                weights,
                passport.k1_v_per_g,
                &manifest.measure,
            )
            .map_err(|e| Error::Invalid(format!("unit {}: {e}", triad.names[u])))?;
        let (measurement, fit) = (unit.measurement, unit.linear_response);
        let a_l_g = axes.to_unit(&run.up).map(|x| x * manifest.gravity_g);
        let condition = unit_condition(run, u, passport, a_l_g, &measurement, &vibs, triad)?;
        out.push(UnitResult {
            run_id: run.id.clone(),
            unit: triad.names[u].clone(),
            a_l_g,
            measurement,
            linear_response: fit,
            condition,
        });
    }
    Ok((
        RunSummary {
            id: run.id.clone(),
            readings: accel.time_s.len(),
            accel_rate_hz: accel.rate_hz(),
            reference_rate_hz: reference.rate_hz(),
            windows,
            windows_used,
            reference_still_g,
        },
        out,
    ))
}

/// One estimator window inside the vibrating segment, mapped.
struct Window {
    units: [Vibration; 3],
    spectrum: Vec<PsdBand>,
}

/// The reference's vibrating record through the estimator: channel `j` is the reference
/// along unit `j`'s IA (where the triad's vibration sensor `j` measures), in g. Returns
/// the windows inside the vibrating segment and those usable (not flagged, mapped, with
/// the most common tone count: the pool needs one).
fn estimate_run(
    run: &Run,
    reference: &vibro_ident::Timed,
    triad: &TriadConfig,
    base: &EstimatorConfig,
) -> Result<(usize, Vec<Window>)> {
    let mut raw: EstimatorConfigRaw = base.raw().clone();
    raw.sample_rate_hz = reference.rate_hz();
    raw.sensitivity_raw_per_g = [1.0; 3];
    raw.ac_corner_hz = None;
    raw.response = Vec::new();
    raw.full_scale_g = None;
    // The rows are one period apart (read_timed): the block times are exact.
    raw.timestamp_tolerance_s = Some(0.5 / reference.rate_hz());
    let config = EstimatorConfig::try_from(raw).map_err(|e| {
        Error::Invalid(format!(
            "the estimator's configuration at the reference's rate ({} Hz): {e}",
            reference.rate_hz()
        ))
    })?;
    let mut estimator = Estimator::new(config.clone());
    let [lo, hi] = run.segments.vibrating_s;
    let first = reference.time_s.partition_point(|&t| t < lo);
    let last = reference.time_s.partition_point(|&t| t <= hi);
    let samples: Vec<[f64; 3]> = (first..last)
        .map(|i| {
            let body = [
                reference.columns[0][i],
                reference.columns[1][i],
                reference.columns[2][i],
            ];
            triad.axes.units.map(|u| u.ia.project(&body))
        })
        .collect();
    let mut estimates: Vec<VibEstimate> = Vec::new();
    let block = vibro_log::samples::BLOCK_SAMPLES;
    for (k, chunk) in samples.chunks(block).enumerate() {
        // The estimator's clock starts at the vibrating window (times may be negative
        // in a rig's file); only differences matter.
        let t0_ns = ((k * block) as f64 / reference.rate_hz() * 1e9).round() as u64;
        let b = SampleBlock {
            seq: k as u64,
            t0_ns,
            samples_raw: chunk,
        };
        estimator
            .push_block(&b, |e| {
                let mut m = VibEstimate::default();
                vibro_estimator_core::mirror_estimate(e, &mut m);
                estimates.push(m);
            })
            .map_err(|e| Error::Invalid(format!("the estimator on the reference: {e}")))?;
    }
    let windows = estimates.len();
    let mapping = EstimateMapping {
        within_output_interval: false,
        ..EstimateMapping::default()
    };
    let mut solver = SpectrumSolver::new(BandLeakage::new(&config));
    let mut used: Vec<Window> = Vec::new();
    for est in estimates {
        if est.flags & BAD_ESTIMATE != 0 {
            continue;
        }
        let Ok(v) = unit_vibrations(&est, &triad.axes, &mapping) else {
            continue;
        };
        let spectrum = sensor_spectrum(&est, &mut solver);
        used.push(Window {
            spectrum,
            units: v.units,
        });
    }
    // The most common tone count (a window may miss or add a weak tone).
    let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
    for w in &used {
        *counts.entry(w.units[0].tones().len()).or_default() += 1;
    }
    if let Some((&mode, _)) = counts.iter().max_by_key(|(_, &n)| n) {
        used.retain(|w| w.units[0].tones().len() == mode);
    }
    if used.is_empty() {
        return Err(Error::Invalid(format!(
            "no usable estimator window in the vibrating segment {lo}..{hi} s ({windows} \
             windows of {} s): the segment must hold at least one whole window",
            config.raw().window_s
        )));
    }
    Ok((windows, used))
}

/// The table row of unit `u`: the pooled vibration and spectrum of the run's windows,
/// the random part as one flat band over the bands that carry its power.
fn unit_condition(
    run: &Run,
    u: usize,
    passport: &Passport,
    a_l_g: [f64; 3],
    m: &TimedMeasurement,
    windows: &[Window],
    triad: &TriadConfig,
) -> Result<Condition> {
    let map = sensor_map(&triad.axes);
    let vibs: Vec<Vibration> = windows.iter().map(|w| w.units[u]).collect();
    let bands: Vec<Vec<PsdBand>> = windows
        .iter()
        .map(|w| unit_bands(&w.spectrum, &map[u]))
        .collect();
    let (Some(vibration), Some(bands)) = (
        flight::pooled_vibration(&vibs),
        flight::pooled_bands(&bands),
    ) else {
        return Err(Error::Invalid(format!(
            "unit {}: the estimator's windows differ (tones or bands): cannot pool them",
            triad.names[u]
        )));
    };
    // No `aB3_u_g`/`sigma3_u_g`: the estimator's tone amplitude and random RMS err in
    // opposite directions (random power at the tone's frequency taken for the tone, or
    // left in the random part), so propagating each on its own overstates the
    // prediction's uncertainty: on the independent generator's 48 unit-runs chi2/dof
    // falls from 0.74 to 0.49 with them (docs/identification.md).
    // The flat band: from the lowest to the highest band with power on IA.
    let strongest = bands
        .iter()
        .map(|b| b.psd_g2_per_hz[2])
        .fold(0.0f64, f64::max);
    let with_power: Vec<&PsdBand> = bands
        .iter()
        .filter(|b| strongest > 0.0 && b.psd_g2_per_hz[2] >= FLAT_BAND_FRACTION * strongest)
        .collect();
    let band = match (with_power.first(), with_power.last()) {
        (Some(a), Some(b)) => [a.f_lo_hz, b.f_hi_hz],
        _ => [f64::NAN, f64::NAN],
    };
    let measured = WindowVe {
        ve_g: m.measurement.ve_g,
        u_g: m.measurement.ve_sigma_g,
        a_l_unit_g: a_l_g,
        a_l_span_g: 0.0,
        a_l3_var_g2: 0.0,
        samples: m.measurement.vib.n_samples,
    };
    let [vlo, vhi] = run.segments.vibrating_s;
    let extra = BTreeMap::from([
        ("vibrating_s".to_string(), vhi - vlo),
        ("band_lo_hz".to_string(), band[0]),
        ("band_hi_hz".to_string(), band[1]),
        ("unit".to_string(), (u + 1) as f64),
    ]);
    let mut c = flight::condition(WindowInput {
        run_id: format!("{}/{}", run.id, triad.names[u]),
        line: 0,
        passport_ref: passport.id().to_string(),
        passport: *passport,
        vibration,
        bands: Vec::new(),
        bands_u: Vec::new(),
        measured,
        prediction_u_g: 0.0,
        scale_group: None,
        extra,
    });
    // One tone per row (a CSV row holds one); the estimator's weaker ones are dropped.
    c.more_tones.clear();
    if let Some(r) = c.random.as_mut() {
        r.cov12_g2 = 0.0;
    }
    Ok(c)
}
