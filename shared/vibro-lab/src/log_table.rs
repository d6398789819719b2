//! The lab's log input: an MCAP log with a reference (`/truth`) turned into the lab's
//! table, one condition per estimator window and unit ([`crate::flight`], docs/lab.md
//! "Logs as input").
//!
//! The log's `/vib` stream goes through the estimator (the estimator service's own core,
//! `vibro_estimator_core::InProcess`, with its configuration: validation, continuity
//! and flags as the service applies them), offline and deterministic; its estimates
//! are mapped to each unit's axes as the compensator maps them
//! (`vibro_effects::mapping`), with the whole vibration (the lab compares the VE of
//! the papers' static model, not the compensator's per-interval part), and the random
//! part's spectrum is solved from the band powers ([`crate::spectrum`]). Windows that
//! do not overlap are kept; those the estimator flagged, those the log does not cover
//! with readings and reference, and those over which the flight acceleration changes
//! by more than [`LogOptions::max_al_span_g`] are left out and counted.
//!
//! ```no_run
//! use vibro_lab::log_table::{table_from_log, LogOptions};
//! use vibro_lab::{BaseMode, LabModel};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let options = LogOptions {
//!     triad: vibro_config::resolve_triad("default")?,
//!     estimator: vibro_dsp::EstimatorConfig::try_from(
//!         vibro_dsp::EstimatorConfigRaw::new(25600.0, [0.1; 3]),
//!     )?,
//!     batches: 8,
//!     max_al_span_g: 1.0,
//!     pool_windows: 0,
//! };
//! let model = LabModel::base(BaseMode::Exact);
//! let (table, summary) = table_from_log("flight.mcap".as_ref(), &model, &options)?;
//! println!("{} conditions from {} windows", table.conditions.len(), summary.windows);
//! # Ok(())
//! # }
//! ```

use crate::flight::{self, ReferenceSample, VibrationU, WindowInput, WindowVe};
use crate::spectrum::{sensor_spectrum, sensor_spectrum_u, unit_bands, SpectrumSolver};
use crate::table::ScaleGroup;
use crate::waveform::{LabWindow, LogWaveform};
use crate::{CampaignTable, Condition, Error, LabModel, Result};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;
use vibro_config::TriadConfig;
use vibro_dsp::{BandLeakage, EstimatorConfig};
use vibro_effects::mapping::{sensor_map, unit_vibrations, EstimateMapping, UnitVibrations};
use vibro_effects::predict::flat_passport;
use vibro_log::linear::{RigReading, SensorChain};
use vibro_log::topic;
use vibro_mcap::{Message, Reader};
use vibro_msgs::{estimate_flags, truth_flags, Stream, VibEstimate};
use vibro_physics::passport::Passport;
use vibro_physics::vibration::PsdBand;

/// How a log becomes the lab's table.
#[derive(Debug, Clone)]
pub struct LogOptions {
    /// The triad whose geometry the log's units have, and its passports; passports the
    /// log carries (a simulator's log) win.
    pub triad: TriadConfig,
    /// The estimator's configuration; the sensor rate, sensitivity and AC corner the
    /// log's metadata states win.
    pub estimator: EstimatorConfig,
    /// Contiguous batches per window for the measured VE's uncertainty (batch means),
    /// at least 2.
    pub batches: usize,
    /// Windows over which a flight-acceleration component changes by more than this are
    /// left out (the model is evaluated at the window's mean, with the curvature over
    /// the window's aL3 in the uncertainty), g.
    pub max_al_span_g: f64,
    /// Most consecutive estimator windows pooled into one lab window (0: one per 60th
    /// of the log's windows, 1 to 10); a pool also ends where the windows' tones or
    /// bands differ or the flight acceleration spans more than `max_al_span_g`.
    pub pool_windows: usize,
}

/// Lab windows per unit that `--pool-windows 0` aims at.
const AUTO_POOL_TARGET: usize = 60;
/// Most estimator windows `--pool-windows 0` pools.
const AUTO_POOL_MAX: usize = 10;

/// Estimate flags that make a window unusable.
const BAD_ESTIMATE: u32 = estimate_flags::GAP
    | estimate_flags::NON_FINITE
    | estimate_flags::OUT_OF_ORDER
    | estimate_flags::INSUFFICIENT_DATA
    | estimate_flags::RATE_MISMATCH
    | estimate_flags::SATURATED_AXIS0
    | (estimate_flags::SATURATED_AXIS0 << 1)
    | (estimate_flags::SATURATED_AXIS0 << 2);

/// What became of the log's windows.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LogTableSummary {
    pub log: String,
    /// Where the passports came from: `log` (its attachments) or the triad.
    pub passports_from: String,
    pub units: Vec<String>,
    pub estimator_window_s: f64,
    pub estimator_overlap_fraction: f64,
    /// Sensor settings taken from the log's metadata, by key.
    pub sensor_from_log: BTreeMap<String, f64>,
    pub accel_samples: u64,
    /// Readings whose sensed acceleration came from the vibration sensors (a rig's
    /// reference, [`sensed_from_sensors`]); 0 for a simulated log (its truth states it).
    pub sensed_from_sensors: u64,
    /// Chunks of a rig's readings whose units' linear response was fitted through the
    /// vibration sensors, and the readings they hold ([`sensed_from_sensors`]).
    pub linear_response_fits: u64,
    pub linear_response_readings: u64,
    pub estimates: u64,
    /// Estimates whose windows do not overlap the previous one kept.
    pub windows: u64,
    pub windows_used: u64,
    pub left_out_flagged: u64,
    pub left_out_incomplete: u64,
    pub left_out_al_span: u64,
    /// Most estimator windows pooled into one lab window.
    pub pool_windows: usize,
    /// Lab windows (pools of consecutive estimator windows).
    pub lab_windows: usize,
    pub conditions: usize,
    /// This log's first row in the joined table of the inputs (`inputs::load`).
    #[serde(skip)]
    pub first_row: usize,
    /// What `lab compare` needs to predict the log's windows from its samples
    /// ([`crate::waveform`]).
    #[serde(skip)]
    pub waveform: Option<std::sync::Arc<LogWaveform>>,
}

/// One accelerometer sample with its reference, by sample index.
#[derive(Debug, Clone, Copy, Default)]
struct Row {
    latch_ns: u64,
    output_v: Option<[f64; 3]>,
    a_l_ia_g: Option<[f64; 3]>,
    a_sensed_ia_g: Option<[f64; 3]>,
    /// A rig's reference (`truth_flags::SENSED_UNKNOWN`): the sensed acceleration comes
    /// from the vibration sensors ([`sensed_from_sensors`]).
    sensed_unknown: bool,
    /// Per unit, its linear response to the vibration over the reading's interval, g,
    /// fitted through the sensors (`vibro_log::linear`); `None` where not fitted.
    linear_g: Option<[f64; 3]>,
}

/// A row with its reading and its reference.
#[derive(Debug, Clone, Copy)]
struct Complete {
    latch_ns: u64,
    output_v: [f64; 3],
    a_l_ia_g: [f64; 3],
    a_sensed_ia_g: [f64; 3],
    linear_g: [f64; 3],
}

/// Windows on each side whose batch-means variance a window's measured VE pools
/// (`flight::neighbour_pooled_u`): 5 windows of 8 batches, 35 degrees of freedom
/// instead of 7.
const NEIGHBOUR_WINDOWS: usize = 2;

/// Window edges this close are the same edge (sample times are rounded to 1 ns).
const SAME_EDGE_NS: u64 = 1_000;

/// Most accelerometer samples the lab reads from one log (about 35 h at 800 Hz).
const MAX_SAMPLES: usize = 100_000_000;

/// The row of sample `index` (rows are keyed by the producer's sample index, which a
/// long-running rig starts far from 0).
fn row_at(rows: &mut BTreeMap<u64, Row>, index: u64) -> Result<&mut Row> {
    if rows.len() >= MAX_SAMPLES && !rows.contains_key(&index) {
        return Err(Error::Invalid(format!(
            "over {MAX_SAMPLES} accelerometer samples: more than the lab reads from one log"
        )));
    }
    Ok(rows.entry(index).or_default())
}

/// The log's passports (`vibro_log::attachments::read_passports`), if it has all three.
fn log_passports(reader: &mut Reader) -> Result<Option<[(String, Passport); 3]>> {
    let mut found: [Option<(String, Passport)>; 3] = [None, None, None];
    for lp in vibro_log::attachments::read_passports(reader)? {
        let name = lp.attachment;
        let p = vibro_config::parse_passport(&lp.toml, &format!("attachment {name}"))?;
        if let Some(slot) = found.get_mut(lp.index) {
            *slot = Some((name, p));
        }
    }
    Ok(match found {
        [Some(a), Some(b), Some(c)] => Some([a, b, c]),
        _ => None,
    })
}

/// The estimator's configuration, with the sensor settings the log's metadata states.
pub(crate) fn estimator_config(
    base: &EstimatorConfig,
    reader: &mut Reader,
    summary: &mut LogTableSummary,
) -> Result<EstimatorConfig> {
    let mut raw = base.raw().clone();
    let meta = reader.metadata()?;
    // A simulated log's `scenario`, or a rig's (`log import --rig`).
    if let Some((_, m)) = meta
        .iter()
        .find(|(name, _)| name == "scenario" || name == vibro_log::attachments::RIG_METADATA)
    {
        let num = |key: &str| m.get(key).and_then(|v| v.parse::<f64>().ok());
        let per_sensor: Option<Vec<f64>> = (1..=3)
            .map(|u| num(&format!("sensor{u}_sensitivity_v_per_g")))
            .collect();
        if let Some(s) = per_sensor {
            raw.sensitivity_raw_per_g = [s[0], s[1], s[2]];
            for (u, v) in s.iter().enumerate() {
                summary
                    .sensor_from_log
                    .insert(format!("sensor{}_sensitivity_v_per_g", u + 1), *v);
            }
        }
        if let Some(hz) = num("sensor_hz") {
            raw.sample_rate_hz = hz;
            summary.sensor_from_log.insert("sensor_hz".into(), hz);
        }
        if let (Some(s), false) = (
            num("sensor_sensitivity_v_per_g"),
            summary
                .sensor_from_log
                .contains_key("sensor1_sensitivity_v_per_g"),
        ) {
            raw.sensitivity_raw_per_g = [s; 3];
            summary
                .sensor_from_log
                .insert("sensor_sensitivity_v_per_g".into(), s);
        }
        if let Some(delay_s) = num("sensor_delay_s") {
            summary
                .sensor_from_log
                .insert("sensor_delay_s".into(), delay_s);
        }
        if let Some(fc) = num("sensor_ac_corner_hz") {
            raw.ac_corner_hz = (fc > 0.0).then_some(fc);
            summary
                .sensor_from_log
                .insert("sensor_ac_corner_hz".into(), fc);
        }
    }
    summary.estimator_window_s = raw.window_s;
    summary.estimator_overlap_fraction = raw.overlap_fraction;
    EstimatorConfig::try_from(raw).map_err(|e| {
        Error::Invalid(format!(
            "the estimator's configuration with the log's sensor settings: {e}"
        ))
    })
}

/// Opens a log the lab reads (the statistics and the waveform path alike): a file that
/// is not an MCAP log at all (a text file named `.mcap`) is said to be so, as
/// `log info` says it, not reported as a damaged log ending mid-record.
pub(crate) fn open_log(path: &Path) -> Result<Reader> {
    vibro_log::inspect::check_mcap_file(path)?;
    Ok(Reader::open(path)?)
}

/// Reads `path` and builds the lab's table (module doc).
pub fn table_from_log(
    path: &Path,
    model: &LabModel,
    args: &LogOptions,
) -> Result<(CampaignTable, LogTableSummary)> {
    if args.batches < 2 {
        return Err(Error::Invalid(format!(
            "--batches {}: must be at least 2 (batch means)",
            args.batches
        )));
    }
    if !(args.max_al_span_g.is_finite() && args.max_al_span_g >= 0.0) {
        return Err(Error::Invalid(format!(
            "--max-al-span-g {}: must be finite and >= 0",
            args.max_al_span_g
        )));
    }
    let mut summary = LogTableSummary {
        log: path.display().to_string(),
        ..Default::default()
    };
    let mut reader = open_log(path)?;
    let units = log_units(&mut reader, args, &mut summary)?;
    let config = estimator_config(&args.estimator, &mut reader, &mut summary)?;
    let mut estimator =
        vibro_estimator_core::InProcess::new(&config).map_err(|e| Error::Context {
            what: "the estimator".into(),
            source: e.into(),
        })?;
    let mut streams = read_streams(path, reader, &mut estimator, &mut summary)?;
    if streams.sensed_unknown {
        sensed_from_sensors(path, &mut streams, &config, &units, &mut summary)?;
    }
    // A fitted linear response leaves a residual whose window means are end terms
    // (`flight::window_ve`): tapered over half the estimator's Welch segment. The
    // simulator's sensed acceleration removes the linear response exactly: no taper
    // (on its flights a taper took a right model's chi2/dof to 2.0 on one seed of
    // three, and two flights fitted jointly no longer pinned the resonance tighter
    // than each alone: left as it was).
    if streams.sensed_unknown {
        let half_segment_ns = 0.5 * config.raw().welch_segment_s * 1e9;
        streams.taper_samples =
            (half_segment_ns / streams.period_ns.max(1) as f64).round() as usize;
    }
    let mut solver = SpectrumSolver::new(BandLeakage::new(&config));
    let mut windows = Vec::new();
    let conditions = window_conditions(
        &streams,
        &units,
        &mut solver,
        model,
        args,
        &mut summary,
        &mut windows,
    )?;
    summary.conditions = conditions.len();
    summary.waveform = Some(std::sync::Arc::new(LogWaveform {
        path: path.to_path_buf(),
        axes: units.triad.axes,
        passports: [units.flat[0], units.flat[1], units.flat[2]],
        chain: vibro_waveform::SensorChain {
            sensitivity_v_per_g: config.raw().sensitivity_raw_per_g,
            ac_corner_hz: config.raw().ac_corner_hz.unwrap_or(0.0),
            // A rig's DAQ delay when its metadata states it (`sensor_delay_s`), else none.
            delay_s: summary
                .sensor_from_log
                .get("sensor_delay_s")
                .copied()
                .unwrap_or(0.0),
        },
        taper_samples: streams.taper_samples,
        windows,
    }));
    if conditions.is_empty() {
        return Err(Error::Invalid(format!(
            "{}: no usable window ({} estimates, {} windows: {} flagged by the estimator, \
             {} not covered by readings and reference, {} with the flight acceleration \
             changing by more than {} g)",
            path.display(),
            summary.estimates,
            summary.windows,
            summary.left_out_flagged,
            summary.left_out_incomplete,
            summary.left_out_al_span,
            args.max_al_span_g
        )));
    }
    Ok((
        CampaignTable {
            path: path.to_path_buf(),
            conditions,
            extra_columns: ["t_s", "unit", "vibrating_s"].map(String::from).to_vec(),
        },
        summary,
    ))
}

/// The log's units: the triad's geometry and names, and their passports.
pub(crate) struct Units {
    pub(crate) triad: TriadConfig,
    /// Per unit: the passport as the table names it.
    refs: Vec<String>,
    /// Per unit: the passport, flat (`vibro_effects::predict::flat_passport`).
    pub(crate) flat: Vec<Passport>,
    /// Per unit axis: the vibration sensor that measures it, and the sign.
    map: [[(usize, f64); 3]; 3],
}

/// The units of `--triad`, with the passports the log carries if it has all three.
pub(crate) fn log_units(
    reader: &mut Reader,
    args: &LogOptions,
    summary: &mut LogTableSummary,
) -> Result<Units> {
    let triad = args.triad.clone();
    let (refs, passports): (Vec<String>, Vec<Passport>) = match log_passports(reader)? {
        Some(list) => {
            summary.passports_from = "log".into();
            list.into_iter()
                .map(|(name, p)| (format!("{} ({name})", p.id()), p))
                .unzip()
        }
        None => {
            summary.passports_from = format!("triad {}", triad.id);
            triad
                .passports
                .iter()
                .map(|p| (p.id().to_string(), *p))
                .unzip()
        }
    };
    let flat: Vec<Passport> = passports
        .iter()
        .map(flat_passport)
        .collect::<std::result::Result<_, _>>()?;
    summary.units = triad.names.to_vec();
    let map = sensor_map(&triad.axes);
    Ok(Units {
        triad,
        refs,
        flat,
        map,
    })
}

/// The log's streams, read in one pass.
struct LogStreams {
    /// The accelerometer samples and their reference, by sample index.
    rows: BTreeMap<u64, Row>,
    /// The accelerometer stream's sample period, ns.
    period_ns: u64,
    /// The estimates of the `/vib` stream, in order.
    estimates: Vec<VibEstimate>,
    /// Some reference rows are a rig's ([`Row::sensed_unknown`]).
    sensed_unknown: bool,
    /// The taper at each end of a window's measured VE, samples
    /// (`flight::window_ve`): half the estimator's Welch segment.
    taper_samples: usize,
}

/// Reads the log: `/vib` through the estimator (its windows' estimates), `/accel` and
/// `/truth` into rows. Fails when the log lacks one of the three.
fn read_streams(
    path: &Path,
    reader: Reader,
    estimator: &mut vibro_estimator_core::InProcess,
    summary: &mut LogTableSummary,
) -> Result<LogStreams> {
    let (vib_topic, accel_topic, truth_topic) = (
        topic(Stream::Vib),
        topic(Stream::Accel),
        topic(Stream::Truth),
    );
    let mut rows: BTreeMap<u64, Row> = BTreeMap::new();
    let mut period_ns = 0u64;
    let mut estimates: Vec<VibEstimate> = Vec::new();
    let (mut have_vib, mut have_truth) = (false, false);
    let mut sensed_unknown = false;
    for record in reader {
        let record = record?;
        let t = &*record.topic;
        match &record.message {
            Message::VibBlock(b) if t == vib_topic => {
                have_vib = true;
                // Offline: no receive time (the estimates' latency means nothing here).
                estimator
                    .on_block(b, 0, &mut estimates)
                    .map_err(|e| Error::Context {
                        what: "the estimator".into(),
                        source: e.into(),
                    })?;
            }
            Message::AccelBlock(b) if t == accel_topic => {
                period_ns = b.sample_period_ns;
                for (k, u) in b.samples_v().iter().enumerate() {
                    let r = row_at(&mut rows, b.first_sample_index + k as u64)?;
                    r.latch_ns = b.t0_ns + k as u64 * b.sample_period_ns;
                    r.output_v = Some(*u);
                    summary.accel_samples += 1;
                }
            }
            Message::TruthBlock(b) if t == truth_topic => {
                have_truth = true;
                let rig = b.flags & truth_flags::SENSED_UNKNOWN != 0;
                sensed_unknown |= rig;
                for k in 0..(b.count as usize).min(b.a_l_ia_g.len()) {
                    let r = row_at(&mut rows, b.first_sample_index + k as u64)?;
                    let a_l = b.a_l_ia_g[k];
                    r.a_l_ia_g = a_l.iter().all(|x| x.is_finite()).then_some(a_l);
                    r.sensed_unknown = rig;
                    r.a_sensed_ia_g = (!rig).then_some(b.a_sensed_ia_g[k]);
                }
            }
            _ => {}
        }
    }
    if !have_vib || period_ns == 0 {
        return Err(Error::Invalid(format!(
            "{}: the lab needs the vibration sensors ({vib_topic}) and the readings \
             ({accel_topic}); the log has {}{}",
            path.display(),
            if have_vib { "" } else { "no vibration blocks" },
            if period_ns == 0 {
                if have_vib {
                    "no accelerometer blocks"
                } else {
                    ", no accelerometer blocks"
                }
            } else {
                ""
            }
        )));
    }
    if !have_truth {
        return Err(Error::Invalid(format!(
            "{}: no reference ({truth_topic}): a window's VE is measured against what each \
             unit should read without vibration; import a rig's log with its rig file \
             (vibrocomp log import --rig RIG.toml [--reference CSV], docs/logs.md), which \
             writes the rig's reference (orientations, a centrifuge or a reference stream) \
             (docs/lab.md, \"Logs as input\")",
            path.display()
        )));
    }
    summary.estimates = estimates.len() as u64;
    Ok(LogStreams {
        rows,
        period_ns,
        taper_samples: 0,
        estimates,
        sensed_unknown,
    })
}

/// A rig's reference rows (`truth_flags::SENSED_UNKNOWN`): the acceleration each unit
/// sensed is not known, only what it should read without vibration. The vibration
/// sensors give it (`vibro_log::linear`, which reads the log a second time): per
/// reading, its sensor's mean over the reading's interval over the sensor's stated
/// sensitivity, added to the reference; and per unit, its linear response to the
/// vibration fitted to its readings, which replaces `J(aL) (a_sensed - aL)`: a unit
/// behind a mount (a resonance between the sensors' base and the unit) does not respond
/// to the base's motion as its passport says, and the unremoved part of that response
/// fills the batch means (the shake-table campaign's finding, docs/identification.md).
/// A reading of a fitted stretch that the fit leaves out (within a second of the
/// sensors' record's ends) is not used.
fn sensed_from_sensors(
    path: &Path,
    streams: &mut LogStreams,
    config: &EstimatorConfig,
    units: &Units,
    summary: &mut LogTableSummary,
) -> Result<()> {
    let readings: BTreeMap<u64, RigReading> = streams
        .rows
        .iter()
        .filter(|(_, r)| r.sensed_unknown)
        .filter_map(|(&i, r)| {
            Some((
                i,
                RigReading {
                    latch_ns: r.latch_ns,
                    output_v: r.output_v?,
                    a_l_ia_g: r.a_l_ia_g?,
                },
            ))
        })
        .collect();
    let passports: [Passport; 3] = [units.flat[0], units.flat[1], units.flat[2]];
    let sensors = SensorChain {
        sensitivity_v_per_g: config.raw().sensitivity_raw_per_g,
        ac_corner_hz: config.raw().ac_corner_hz,
    };
    let fitted = vibro_log::linear::fit_linear_responses(
        path,
        &readings,
        streams.period_ns,
        &units.triad.axes,
        &passports,
        &sensors,
    )?;
    summary.linear_response_fits = fitted.fits;
    summary.linear_response_readings = fitted.fitted_readings;
    for (i, r) in streams.rows.iter_mut() {
        let Some(f) = fitted.readings.get(i) else {
            continue;
        };
        r.linear_g = f.linear_g;
        let unfitted = f.linear_g.is_some_and(|l| l.iter().any(|x| !x.is_finite()));
        if let (Some(a_l), Some(v), false) = (r.a_l_ia_g, f.sensor_mean_g, unfitted) {
            r.a_sensed_ia_g = Some(std::array::from_fn(|u| a_l[u] + v[u]));
            summary.sensed_from_sensors += 1;
        }
    }
    Ok(())
}

/// The rows with everything, in time order (sample index order).
fn complete_rows(rows: &BTreeMap<u64, Row>) -> Vec<Complete> {
    rows.values()
        .filter_map(|r| match (r.output_v, r.a_l_ia_g, r.a_sensed_ia_g) {
            (Some(output_v), Some(a_l_ia_g), Some(a_sensed_ia_g)) => Some(Complete {
                latch_ns: r.latch_ns,
                output_v,
                a_l_ia_g,
                a_sensed_ia_g,
                linear_g: r.linear_g.unwrap_or([f64::NAN; 3]),
            }),
            _ => None,
        })
        .collect()
}

/// An estimator window the lab uses.
struct UsedWindow<'e> {
    est: &'e VibEstimate,
    /// The vibration each unit sees (the whole vibration, not the compensator's
    /// per-interval part).
    vib: UnitVibrations,
    /// The random part's spectrum, sensor axes ([`sensor_spectrum`]).
    spectrum: Vec<PsdBand>,
    /// Its levels' standard uncertainties ([`sensor_spectrum_u`]).
    spectrum_u: Vec<PsdBand>,
    /// The window's centre from the first complete sample, s.
    center_s: f64,
    /// Its samples, `complete[range]`.
    range: std::ops::Range<usize>,
    /// Per unit: the measured VE.
    measured: Vec<WindowVe>,
    /// Per unit: the stated uncertainty `sqrt(u_measured^2 + u_prediction^2)`, g.
    stated_u_g: Vec<f64>,
    /// Follows the previous used window with none left out between them.
    joined: bool,
}

/// The table's conditions: the estimator windows that do not overlap the previous one
/// kept and that [`measure_window`] does not leave out, pooled into lab windows of
/// consecutive ones ([`pools`]), one condition per lab window and unit, with the
/// stated uncertainties to be scaled by the residuals' own scatter against the model
/// under test (`vibro_lab::flight::data_scales`, by each row's `ScaleGroup`).
fn window_conditions(
    streams: &LogStreams,
    units: &Units,
    solver: &mut SpectrumSolver,
    model: &LabModel,
    args: &LogOptions,
    summary: &mut LogTableSummary,
    windows: &mut Vec<LabWindow>,
) -> Result<Vec<Condition>> {
    let complete = complete_rows(&streams.rows);
    let period_ns = streams.period_ns;
    let t_first_ns = complete
        .first()
        .map(|r| r.latch_ns.saturating_sub(period_ns))
        .unwrap_or(0);
    let mapping = EstimateMapping {
        within_output_interval: false,
        ..EstimateMapping::default()
    };
    let mut used: Vec<UsedWindow<'_>> = Vec::new();
    let mut last_end_ns = 0u64;
    let mut joined = false;
    for est in &streams.estimates {
        // Consecutive windows' edges agree to rounding (a fractional sample period).
        if est.start_ns + SAME_EDGE_NS < last_end_ns {
            continue;
        }
        summary.windows += 1;
        let follows = joined && est.start_ns <= last_end_ns + SAME_EDGE_NS;
        last_end_ns = est.end_ns;
        let Some((vib, range, measured)) =
            measure_window(est, &complete, streams, units, &mapping, args, summary)
        else {
            joined = false;
            continue;
        };
        joined = true;
        summary.windows_used += 1;
        let center_s = est.center_ns.saturating_sub(t_first_ns) as f64 * 1e-9;
        let spectrum = sensor_spectrum(est, solver);
        used.push(UsedWindow {
            est,
            vib,
            spectrum_u: sensor_spectrum_u(est, &spectrum),
            spectrum,
            center_s,
            range,
            measured,
            stated_u_g: Vec::with_capacity(3),
            joined: follows,
        });
    }
    // Per unit, the measured VE's batch-means variance pooled over the neighbouring
    // windows of its run (`flight::neighbour_pooled_u`), then the stated uncertainty.
    let n_units = units.flat.len();
    let mut start = 0;
    while start < used.len() {
        let end = (start + 1..used.len())
            .find(|&j| !used[j].joined)
            .unwrap_or(used.len());
        for u in 0..n_units {
            let own: Vec<f64> = used[start..end].iter().map(|w| w.measured[u].u_g).collect();
            let pooled = flight::neighbour_pooled_u(&own, NEIGHBOUR_WINDOWS);
            for (w, p) in used[start..end].iter_mut().zip(pooled) {
                w.measured[u].u_g = p;
            }
        }
        start = end;
    }
    for w in &mut used {
        for u in 0..w.measured.len() {
            let stated = stated_u(w, u, units, model)?;
            w.stated_u_g.push(stated);
        }
    }
    let pool_max = match args.pool_windows {
        0 => (used.len() / AUTO_POOL_TARGET).clamp(1, AUTO_POOL_MAX),
        k => k,
    };
    summary.pool_windows = pool_max;
    let groups = pools(&used, &complete, units, pool_max, args);
    let taper_samples = streams.taper_samples;
    summary.lab_windows = groups.len();
    // Runs of consecutive windows, for the scale of the stated uncertainties.
    let run_of: Vec<u32> = used
        .iter()
        .scan(0u32, |run, w| {
            if !w.joined {
                *run += 1;
            }
            Some(*run)
        })
        .collect();
    let mut conditions = Vec::new();
    for g in groups {
        let run = run_of[g.start];
        let rows = &complete[used[g.start].range.start..used[g.end - 1].range.end];
        windows.push(LabWindow {
            first_condition: conditions.len(),
            units: units.flat.len(),
            latch_ns: rows.iter().map(|r| r.latch_ns).collect(),
            a_l_ia_g: rows.iter().map(|r| r.a_l_ia_g).collect(),
        });
        for u in 0..units.flat.len() {
            let line = conditions.len() + 1;
            conditions.push(pool_condition(
                &used[g.clone()],
                &complete,
                u,
                taper_samples,
                units,
                model,
                args,
                ScaleGroup {
                    source: 0,
                    unit: u as u32,
                    run,
                },
                line,
            )?);
        }
    }
    Ok(conditions)
}

/// Greedy pools of at most `pool_max` consecutive used windows: a pool ends at a window
/// that does not follow the previous one, whose tones' count or bands' edges differ
/// (the vibration cannot be pooled), or over which the flight acceleration would span
/// more than `--max-al-span-g`.
fn pools(
    used: &[UsedWindow<'_>],
    complete: &[Complete],
    units: &Units,
    pool_max: usize,
    args: &LogOptions,
) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = 0;
    while start < used.len() {
        let mut end = start + 1;
        while end < used.len() && end - start < pool_max && used[end].joined {
            let group = &used[start..=end];
            let fits = (0..units.flat.len()).all(|u| {
                let vibs: Vec<_> = group.iter().map(|w| w.vib.units[u]).collect();
                let bands: Vec<_> = group
                    .iter()
                    .map(|w| unit_bands(&w.spectrum, &units.map[u]))
                    .collect();
                flight::pooled_vibration(&vibs).is_some() && flight::pooled_bands(&bands).is_some()
            });
            let span_ok = (0..units.flat.len()).all(|u| {
                let range = group[0].range.start..group[group.len() - 1].range.end;
                let samples = unit_samples(&complete[range], u, units);
                flight::window_ve(&units.flat[u], &samples, args.batches, 0)
                    .is_some_and(|m| m.a_l_span_g <= args.max_al_span_g)
            });
            if !(fits && span_ok) {
                break;
            }
            end += 1;
        }
        out.push(start..end);
        start = end;
    }
    out
}

/// The samples of unit `u` with their reference, in the unit's axes.
fn unit_samples(rows: &[Complete], u: usize, units: &Units) -> Vec<ReferenceSample> {
    let triad = &units.triad;
    let axes = &triad.axes.units[u];
    let k1 = units.flat[u].k1_v_per_g;
    rows.iter()
        .map(|r| ReferenceSample {
            reading_g: r.output_v[u] / k1,
            a_l_unit_g: axes.to_unit(&triad.axes.body_from_ia(&r.a_l_ia_g)),
            a_sensed_unit_g: axes.to_unit(&triad.axes.body_from_ia(&r.a_sensed_ia_g)),
            linear_g: r.linear_g[u].is_finite().then_some(r.linear_g[u]),
        })
        .collect()
}

/// The vibration, the sample range and the measured VE of each unit over the window of
/// `est`; `None` (counted in `summary`) for a window the lab leaves out: flagged by the
/// estimator, not covered by readings and reference, or with the flight acceleration
/// changing by more than `--max-al-span-g`.
fn measure_window(
    est: &VibEstimate,
    complete: &[Complete],
    streams: &LogStreams,
    units: &Units,
    mapping: &EstimateMapping,
    args: &LogOptions,
    summary: &mut LogTableSummary,
) -> Option<(UnitVibrations, std::ops::Range<usize>, Vec<WindowVe>)> {
    if est.flags & BAD_ESTIMATE != 0 {
        summary.left_out_flagged += 1;
        return None;
    }
    let period_ns = streams.period_ns;
    // Samples whose interval (latch - T, latch] lies inside the window.
    let first = complete.partition_point(|r| r.latch_ns < est.start_ns + period_ns);
    let last = complete.partition_point(|r| r.latch_ns <= est.end_ns);
    let expected = est.end_ns.saturating_sub(est.start_ns) / period_ns.max(1);
    let got = last.saturating_sub(first) as u64;
    if got + 1 < expected || got < args.batches as u64 {
        summary.left_out_incomplete += 1;
        return None;
    }
    let vib = match unit_vibrations(est, &units.triad.axes, mapping) {
        Ok(v) => v,
        Err(e) => {
            tracing::debug!("window at {} ns left out: {e}", est.start_ns);
            summary.left_out_flagged += 1;
            return None;
        }
    };
    let measured: Vec<Option<WindowVe>> = (0..units.flat.len())
        .map(|u| {
            let samples = unit_samples(&complete[first..last], u, units);
            flight::window_ve(
                &units.flat[u],
                &samples,
                args.batches,
                streams.taper_samples,
            )
        })
        .collect();
    if measured
        .iter()
        .any(|m| m.is_none_or(|m| m.a_l_span_g > args.max_al_span_g))
    {
        summary.left_out_al_span += u64::from(measured.iter().all(Option::is_some));
        summary.left_out_incomplete += u64::from(measured.iter().any(Option::is_none));
        return None;
    }
    Some((vib, first..last, measured.into_iter().flatten().collect()))
}

/// The stated uncertainty of unit `u` over one estimator window (the measured VE's by
/// batch means and the prediction's from the estimate's uncertainties,
/// `flight::prediction_u_g`), and its residual against the base model, g.
fn stated_u(w: &UsedWindow<'_>, u: usize, units: &Units, model: &LabModel) -> Result<f64> {
    let (est, map) = (w.est, &units.map);
    let v = w.vib.units[u];
    let m = w.measured[u];
    // The uncertainties of the unit's tones (the mapping keeps the estimate's
    // values: a tone is found by its frequency) and RMS per axis.
    let count = (est.tone_count as usize).min(est.tone_frequency_hz.len());
    let tone_amplitude_u_g = v
        .tones()
        .iter()
        .map(|t| {
            let k = (0..count).find(|&k| est.tone_frequency_hz[k] == t.freq_hz);
            map[u].map(|(j, _)| k.map_or(0.0, |k| est.tone_amplitude_u_g[k][j]))
        })
        .collect();
    let u_vib = VibrationU {
        tone_amplitude_u_g,
        sigma_u_g: map[u].map(|(j, _)| est.broadband_rms_u_g[j]),
    };
    let context = || {
        format!(
            "window at {:.3} s, unit {}",
            w.center_s, units.triad.names[u]
        )
    };
    let prediction_u_g = flight::prediction_u_g(
        model.mode,
        &units.flat[u],
        m.a_l_unit_g,
        m.a_l3_var_g2,
        &v,
        &u_vib,
    )
    .map_err(|e| e.context(context()))?;
    Ok(m.u_g.hypot(prediction_u_g))
}

/// The condition of unit `u` over a lab window (consecutive used windows `group`):
/// the measured VE over all its samples, the pooled vibration and spectrum, and the
/// uncertainty `sqrt(sum u_j^2) / k` of its `k` windows' stated ones (their
/// errors are independent), plus, for a pool, the curvature of the VE over the pool's
/// `aL3` (`flight::prediction_u_g` without the vibration's uncertainties). The
/// measured VE is tapered over `taper_samples` at the pool's ends (`flight::window_ve`).
#[allow(clippy::too_many_arguments)]
fn pool_condition(
    group: &[UsedWindow<'_>],
    complete: &[Complete],
    u: usize,
    taper_samples: usize,
    units: &Units,
    model: &LabModel,
    args: &LogOptions,
    scale_group: ScaleGroup,
    line: usize,
) -> Result<Condition> {
    let k = group.len();
    let (first, last) = (&group[0], &group[k - 1]);
    let center_s = group.iter().map(|w| w.center_s).sum::<f64>() / k as f64;
    let context = || format!("window at {center_s:.3} s, unit {}", units.triad.names[u]);
    let vibs: Vec<_> = group.iter().map(|w| w.vib.units[u]).collect();
    let bands: Vec<_> = group
        .iter()
        .map(|w| unit_bands(&w.spectrum, &units.map[u]))
        .collect();
    let bands_u: Vec<_> = group
        .iter()
        .map(|w| unit_bands(&w.spectrum_u, &units.map[u]))
        .collect();
    let (Some(vibration), Some(bands), Some(bands_u)) = (
        flight::pooled_vibration(&vibs),
        flight::pooled_bands(&bands),
        flight::pooled_bands_u(&bands_u),
    ) else {
        return Err(Error::Invalid(format!(
            "{}: the pooled windows differ",
            context()
        )));
    };
    let stated_u_g = group
        .iter()
        .map(|w| w.stated_u_g[u].powi(2))
        .sum::<f64>()
        .sqrt()
        / k as f64;
    let (mut measured, curvature_u_g) = if k == 1 {
        (first.measured[u], 0.0)
    } else {
        let samples = unit_samples(&complete[first.range.start..last.range.end], u, units);
        let Some(m) = flight::window_ve(&units.flat[u], &samples, args.batches, taper_samples)
        else {
            return Err(Error::Invalid(format!("{}: too few samples", context())));
        };
        let c = flight::prediction_u_g(
            model.mode,
            &units.flat[u],
            m.a_l_unit_g,
            m.a_l3_var_g2,
            &vibration,
            &VibrationU::default(),
        )
        .map_err(|e| e.context(context()))?;
        (m, c)
    };
    measured.u_g = stated_u_g;
    let extra = BTreeMap::from([
        ("t_s".to_string(), center_s),
        ("unit".to_string(), (u + 1) as f64),
        // The vibration has run since the log's start (heating's time).
        ("vibrating_s".to_string(), center_s),
    ]);
    Ok(flight::condition(WindowInput {
        run_id: format!("{}@{center_s:.2}s", units.triad.names[u]),
        line,
        passport_ref: units.refs[u].clone(),
        passport: units.flat[u],
        vibration,
        bands,
        bands_u,
        measured,
        prediction_u_g: curvature_u_g,
        scale_group: Some(scale_group),
        extra,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BaseMode;

    fn options() -> LogOptions {
        LogOptions {
            triad: vibro_config::resolve_triad("default").unwrap(),
            estimator: EstimatorConfig::try_from(vibro_dsp::EstimatorConfigRaw::new(
                25600.0, [0.1; 3],
            ))
            .unwrap(),
            batches: 8,
            max_al_span_g: 1.0,
            pool_windows: 0,
        }
    }

    #[test]
    fn bad_options_are_refused_before_the_log_is_read() {
        let model = LabModel::base(BaseMode::Exact);
        let path = Path::new("/nonexistent/flight.mcap");
        let e = table_from_log(
            path,
            &model,
            &LogOptions {
                batches: 1,
                ..options()
            },
        );
        assert_eq!(
            e.unwrap_err().to_string(),
            "--batches 1: must be at least 2 (batch means)"
        );
        let e = table_from_log(
            path,
            &model,
            &LogOptions {
                max_al_span_g: f64::NAN,
                ..options()
            },
        );
        assert!(e
            .unwrap_err()
            .to_string()
            .contains("must be finite and >= 0"));
        // Good options: the missing file is what is wrong, named.
        let e = table_from_log(path, &model, &options()).unwrap_err();
        assert!(
            matches!(&e, Error::Log(b) if matches!(**b, vibro_log::Error::ReadInput { .. })),
            "{e:?}"
        );
        assert!(e.to_string().contains("/nonexistent/flight.mcap"), "{e}");
    }

    #[test]
    fn the_rows_a_log_may_hold_are_bounded() {
        let mut rows = BTreeMap::new();
        assert!(row_at(&mut rows, 7).is_ok());
        assert_eq!(rows.len(), 1);
        // A row already held is found again without counting against the bound.
        assert!(row_at(&mut rows, 7).is_ok());
        assert_eq!(rows.len(), 1);
    }
}
