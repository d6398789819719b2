//! A recorded session measured against its reference: each compensation stage's error
//! (uncompensated `U/K1`, main error removed `a(2)`, vibration error removed `a(4)`,
//! MODEL.md section 7, [P2 (17)-(20)]) against what each unit should read, averaged
//! over windows; the table `vibrocomp demo` and `vibrocomp log errors` print.
//!
//! Averaging over a window keeps what a navigation system integrates: the slowly
//! varying error. Per sample, the OA/PA vibration passes through the cross-axis
//! sensitivities `m1`, `m2` at about 2 mg RMS; it is zero-mean and no compensator
//! removes it sample by sample.
//!
//! The measure pairs three inputs by accelerometer sample index ([`StagePairs`]): the
//! reading `U` (`/accel`, turned into g with each unit's `K1`), the compensated stages
//! (`/compensated`), and the **reference**, per sample and unit the acceleration the
//! unit should read along its IA. The reference has one source today, the simulator's
//! truth ([`Reference::Truth`]: `TruthBlock.a_sensed_ia_g`); another (a rig's own
//! reference) becomes a variant of [`Reference`] that hands its samples to
//! [`StagePairs::add_reference`], and nothing else changes.
//!
//! Windows are `round(window_s / T)` samples long (`T` the accelerometer's output
//! period) and aligned on the producer's sample index (window `w` holds the indices
//! `w n .. (w + 1) n`); only a window whose every sample has all three inputs counts,
//! and it counts as compensated when none of its samples was compensated for the main
//! error only (`MAIN_ONLY`: no vibration estimate yet, or a stale one). Per window and
//! unit the error is the mean of `stage - reference`; a stage's figure is the RMS of
//! these means over the compensated windows (over the three units for "all").
//!
//! Where the compensator's waveform stage made blocks (`WAVEFORM`, MODEL.md section
//! 12), `a(4)` is its output and the block carries the estimate stage's answer as
//! `a(3)`: that answer gets a figure of its own (`StageErrors::estimate_stage_rms_g`),
//! over the windows in which it was never main error only ([`EstimateStageWindows`]),
//! and the blocks are counted by stage (waveform, fallback, estimate stage alone).
//!
//! ```no_run
//! # fn main() -> vibro_log::Result<()> {
//! use vibro_log::session::{log_errors, DEFAULT_WINDOW_S};
//! let triad = vibro_config::default_triad()?;
//! let report = log_errors("session.mcap".as_ref(), DEFAULT_WINDOW_S, &triad)?;
//! let mut text = String::new();
//! report.errors.write_table(&mut text).expect("writing to a String");
//! print!("{text}");
//! println!("reduction {:.1}x", report.errors.all_units.reduction);
//! # Ok(())
//! # }
//! ```

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use serde::Serialize;
use vibro_mcap::{Message, Reader};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{truth_flags, AccelBlock, CompensatedBlock, MessageKind, Stream, UNITS};

use crate::attachments::{read_passports, TRIAD_UNITS};
use crate::inspect::{check_mcap_file, read_error};
use crate::text::{fmt_g, fmt_ratio};
use crate::{topic, Error, Result};

/// The averaging window of `vibrocomp demo` and `vibrocomp log errors`, s.
pub const DEFAULT_WINDOW_S: f64 = 0.5;

/// The longest averaging window, s (a day): longer ones are a unit mix-up.
pub const MAX_WINDOW_S: f64 = 86_400.0;

/// Most samples held while they wait for the rest of their window (about 42 min at
/// 800 Hz, some 0.5 GB): a window longer than that, or an input missing for that long,
/// stops the measure instead of the machine.
const MAX_OPEN_SAMPLES: usize = 2_000_000;

/// Why `window_s` cannot be an averaging window, if it cannot (the rule of `--window-s`).
pub fn window_problem(window_s: f64) -> Option<String> {
    (!(window_s.is_finite() && window_s > 0.0 && window_s <= MAX_WINDOW_S))
        .then(|| format!("must be finite and 0 < s <= {MAX_WINDOW_S}"))
}

/// Where the reference comes from: per accelerometer sample and unit, the acceleration
/// the unit should read along its IA, g.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reference {
    /// The simulator's truth (`/truth`): `TruthBlock.a_sensed_ia_g`, the whole
    /// acceleration each unit sensed along its IA (flight plus the vibration's own
    /// motion, after input effects), mean over the output interval: what an ideal
    /// unit would read.
    Truth,
    /// A rig's reference (`log import --rig`, docs/logs.md): the same topic, its blocks
    /// flagged `truth_flags::SENSED_UNKNOWN`, `TruthBlock.a_l_ia_g`: what each unit
    /// should read without vibration (the vibration's own motion averages out over a
    /// window). Readings it does not cover (between static orientations) leave their
    /// windows out.
    Rig,
}

/// One block of reference samples.
#[derive(Debug, Clone, Copy)]
pub struct ReferenceBlock<'a> {
    /// The accelerometer sample index of `reference_ia_g[0]`.
    pub first_sample_index: u64,
    /// The accelerometer's output period, ns.
    pub sample_period_ns: u64,
    /// `[sample][unit]`, g.
    pub reference_ia_g: &'a [[f64; UNITS]],
    /// Which reference the block holds.
    pub source: Reference,
}

impl Reference {
    /// Every source, in the order a log is searched for one.
    pub const ALL: [Reference; 1] = [Reference::Truth];

    /// The stream that carries it.
    pub fn stream(self) -> Stream {
        match self {
            Reference::Truth | Reference::Rig => Stream::Truth,
        }
    }

    /// Its topic in a log (`/truth`).
    pub fn topic(self) -> String {
        topic(self.stream())
    }

    /// The wire type of its topic.
    pub fn kind(self) -> MessageKind {
        match self {
            Reference::Truth | Reference::Rig => MessageKind::TruthBlock,
        }
    }

    /// What the error is measured against, as the table's title says it.
    pub fn against(self) -> &'static str {
        match self {
            Reference::Truth => "the sensed acceleration",
            Reference::Rig => "the rig's reference",
        }
    }

    /// The field that holds it, for messages.
    pub fn field(self) -> &'static str {
        match self {
            Reference::Truth => "TruthBlock.a_sensed_ia_g",
            Reference::Rig => "TruthBlock.a_l_ia_g flagged SENSED_UNKNOWN",
        }
    }

    /// The reference samples `message` carries, if it is this source's wire type
    /// (the caller matches the topic); `None` for other messages.
    pub fn samples(self, message: &Message) -> Option<ReferenceBlock<'_>> {
        match (self, message) {
            (Reference::Truth | Reference::Rig, Message::TruthBlock(b)) => {
                let n = (b.count as usize).min(b.a_sensed_ia_g.len());
                let rig = b.flags & truth_flags::SENSED_UNKNOWN != 0;
                Some(ReferenceBlock {
                    first_sample_index: b.first_sample_index,
                    sample_period_ns: b.sample_period_ns,
                    reference_ia_g: if rig {
                        &b.a_l_ia_g[..n]
                    } else {
                        &b.a_sensed_ia_g[..n]
                    },
                    source: if rig {
                        Reference::Rig
                    } else {
                        Reference::Truth
                    },
                })
            }
            _ => None,
        }
    }
}

/// RMS over windows (and units) of one stage's windowed mean error, g.
#[derive(Debug, Clone, Serialize)]
pub struct StageErrors {
    pub uncompensated_rms_g: f64,
    pub main_removed_rms_g: f64,
    /// The published output `a4`: the waveform stage's where it made the block.
    pub vibration_removed_rms_g: f64,
    /// `uncompensated / vibration removed`.
    pub reduction: f64,
    /// With waveform-stage blocks in the log: the estimate stage's answer (`a3` of a
    /// `WAVEFORM` block, `a4` of the others), over the windows the estimate stage
    /// compensated (`SessionErrors::estimate_stage`); NaN when there is none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimate_stage_rms_g: Option<f64>,
}

/// The windows the estimate stage compensated, where the waveform stage ran: a window
/// counts when none of its blocks had the estimate stage's answer for the main error
/// only (`MAIN_ONLY`, or in a `WAVEFORM` block the estimate flags the compensator sets
/// with it: `ESTIMATE_MISSING`, `VIBRATION_ESTIMATE_STALE`, `ESTIMATE_AHEAD`).
#[derive(Debug, Clone, Serialize)]
pub struct EstimateStageWindows {
    pub compensated_windows: u64,
    /// Blocks whose estimate-stage answer is main error only.
    pub main_only_blocks: u64,
}

/// One unit's errors.
#[derive(Debug, Clone, Serialize)]
pub struct UnitErrors {
    /// 1..=3 (AK1..AK3).
    pub unit: usize,
    #[serde(flatten)]
    pub errors: StageErrors,
}

/// The errors of a session against its reference.
#[derive(Debug, Clone, Serialize)]
pub struct SessionErrors {
    pub window_s: f64,
    /// Accelerometer samples per window: `window_s` over the output period, rounded.
    pub window_samples: u64,
    /// The reference's source and topic.
    pub reference: Reference,
    pub reference_topic: String,
    /// The scale factors that turned the readings `U` into g, per unit, V/g.
    pub k1_v_per_g: [f64; UNITS],
    /// Samples each input brought: readings, reference, compensated outputs.
    pub reading_samples: u64,
    pub reference_samples: u64,
    pub compensated_samples: u64,
    /// Samples with a reading, a compensated output and the reference.
    pub samples: u64,
    /// Complete windows (every sample with all three).
    pub windows: u64,
    /// Windows in which every block was compensated with a vibration estimate (the
    /// first ones come before the first estimate: main error only, flagged).
    pub compensated_windows: u64,
    /// Blocks flagged main-only (no usable estimate yet, or stale).
    pub main_only_blocks: u64,
    pub blocks: u64,
    /// Blocks by stage: made by the waveform stage (`WAVEFORM`), by the estimate stage
    /// because the samples did not cover them (`WAVEFORM_FALLBACK`), by the estimate
    /// stage alone (neither flag: `stage = "estimate"`, or an older log).
    pub waveform_blocks: u64,
    pub fallback_blocks: u64,
    pub estimate_only_blocks: u64,
    /// With waveform-stage blocks in the log: the estimate stage's own compensated
    /// windows, which its column is taken over.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimate_stage: Option<EstimateStageWindows>,
    /// Over the compensated windows and the three units.
    pub all_units: StageErrors,
    pub units: Vec<UnitErrors>,
}

/// The linear-response fits `log errors` made for a rig's reference.
#[derive(Debug, Clone, Serialize)]
pub struct LinearResponseSummary {
    pub fits: u64,
    pub fitted_readings: u64,
}

/// A log's errors ([`log_errors`]): the file, where `K1` came from, and the errors.
#[derive(Debug, Clone, Serialize)]
pub struct LogErrors {
    pub log: PathBuf,
    /// The passport attachments that gave `K1`, unit by unit.
    pub passports: Vec<String>,
    /// With a rig's reference: the stretches and readings whose units' linear response
    /// to the vibration was fitted and added to the reference.
    pub linear_response: Option<LinearResponseSummary>,
    pub errors: SessionErrors,
}

impl SessionErrors {
    /// The table: a title line (window, compensated windows, main-only blocks), then
    /// per unit and for all units the RMS of each stage and the reduction. What
    /// `vibrocomp demo` and `vibrocomp log errors` print.
    pub fn write_table(&self, out: &mut impl fmt::Write) -> fmt::Result {
        if let Some(est) = &self.estimate_stage {
            return self.write_two_stage_table(est, out);
        }
        writeln!(
            out,
            "Error against {}, mean over {} s windows ({} of {} windows compensated with a vibration estimate; {} blocks compensated for the main error only: before the first estimate, or with a stale one):",
            self.reference.against(),
            self.window_s,
            self.compensated_windows,
            self.windows,
            self.main_only_blocks
        )?;
        writeln!(
            out,
            "  {:<10}{:>16}{:>16}{:>20}{:>12}",
            "unit", "uncompensated", "main removed", "vibration removed", "reduction"
        )?;
        let mut line = |name: &str, s: &StageErrors| {
            writeln!(
                out,
                "  {:<10}{:>16}{:>16}{:>20}{:>12}",
                name,
                fmt_g(s.uncompensated_rms_g),
                fmt_g(s.main_removed_rms_g),
                fmt_g(s.vibration_removed_rms_g),
                fmt_ratio(s.reduction)
            )
        };
        for u in &self.units {
            line(&format!("AK{}", u.unit), &u.errors)?;
        }
        line("all", &self.all_units)
    }

    /// The table of a log with waveform-stage blocks: the estimate stage's answer as a
    /// column of its own, before the published output.
    fn write_two_stage_table(
        &self,
        est: &EstimateStageWindows,
        out: &mut impl fmt::Write,
    ) -> fmt::Result {
        writeln!(
            out,
            "Error against {}, mean over {} s windows; blocks: {} made by the waveform stage, {} by the estimate stage where the samples did not cover them, {} by the estimate stage alone:",
            self.reference.against(),
            self.window_s,
            self.waveform_blocks,
            self.fallback_blocks,
            self.estimate_only_blocks
        )?;
        writeln!(
            out,
            "  vibration removed (published a4): {} of {} windows compensated ({} blocks main error only); estimate stage (its answer, a3 of waveform blocks): {} of {} windows compensated with a vibration estimate ({} blocks without one)",
            self.compensated_windows,
            self.windows,
            self.main_only_blocks,
            est.compensated_windows,
            self.windows,
            est.main_only_blocks
        )?;
        writeln!(
            out,
            "  {:<10}{:>16}{:>16}{:>18}{:>20}{:>12}",
            "unit",
            "uncompensated",
            "main removed",
            "estimate stage",
            "vibration removed",
            "reduction"
        )?;
        let mut line = |name: &str, s: &StageErrors| {
            writeln!(
                out,
                "  {:<10}{:>16}{:>16}{:>18}{:>20}{:>12}",
                name,
                fmt_g(s.uncompensated_rms_g),
                fmt_g(s.main_removed_rms_g),
                fmt_g(s.estimate_stage_rms_g.unwrap_or(f64::NAN)),
                fmt_g(s.vibration_removed_rms_g),
                fmt_ratio(s.reduction)
            )
        };
        for u in &self.units {
            line(&format!("AK{}", u.unit), &u.errors)?;
        }
        line("all", &self.all_units)
    }
}

impl LogErrors {
    /// `vibrocomp log errors`: what was paired, from which file, then the table.
    pub fn write_text(&self, out: &mut impl fmt::Write) -> fmt::Result {
        let e = &self.errors;
        writeln!(
            out,
            "{}: {} samples with a reading (/accel), a compensated output (/compensated) and the reference ({}, {}); {} windows of {} samples",
            self.log.display(),
            e.samples,
            e.reference_topic,
            e.reference.field(),
            e.windows,
            e.window_samples
        )?;
        writeln!(
            out,
            "  K1 {:?} V/g from {}",
            e.k1_v_per_g,
            self.passports.join(", ")
        )?;
        e.write_table(out)
    }
}

/// Measures the log `path` (a recording with `/accel`, `/compensated` and a reference:
/// the simulator's `/truth`), averaged over `window_s` windows, with each unit's `K1`
/// from the passports the log carries (`vibrocomp record` attaches the compensator's).
///
/// Fails naming the file: not an MCAP log, damaged (with the command that recovers
/// it), no compensated stream (replay it through the services first), no reference,
/// no readings, no passports, or no window to measure.
pub fn log_errors(
    path: &Path,
    window_s: f64,
    triad: &vibro_config::TriadConfig,
) -> Result<LogErrors> {
    if let Some(rule) = window_problem(window_s) {
        return Err(window_error(window_s, rule));
    }
    check_mcap_file(path)?;
    let mut reader = Reader::open(path).map_err(|e| read_error(path, e))?;
    let channels = reader.channels();
    let has = |topic: &str, kind: MessageKind| channels.iter().any(|c| c.0 == topic && c.1 == kind);
    let topics = || {
        let mut all: Vec<&str> = channels.iter().map(|c| c.0.as_str()).collect();
        all.extend(reader.foreign_topics().iter().map(String::as_str));
        all.extend(reader.view_topics().iter().map(String::as_str));
        if all.is_empty() {
            "none".to_string()
        } else {
            all.join(", ")
        }
    };
    if !has(&topic(Stream::Compensated), MessageKind::CompensatedBlock) {
        return Err(bad(
            path,
            no_compensated(path, &format!("it has none (topics: {})", topics())),
        ));
    }
    let Some(reference) = Reference::ALL
        .into_iter()
        .find(|r| has(&r.topic(), r.kind()))
    else {
        return Err(bad(path, no_reference(&format!("topics: {}", topics()))));
    };
    if !has(&topic(Stream::Accel), MessageKind::AccelBlock) {
        return Err(bad(path, no_readings(&format!("topics: {}", topics()))));
    }
    let (k1_v_per_g, passports) = log_k1(path, &mut reader)?;
    let rig = rig_linear(path, &mut reader, triad)?;
    let mut pairs = StagePairs::new(path, reference, k1_v_per_g, window_s)?;
    let mut shifted: Vec<[f64; UNITS]> = Vec::with_capacity(vibro_msgs::ACCEL_BLOCK_MAX);
    let (accel, compensated, reference_topic) = (
        topic(Stream::Accel),
        topic(Stream::Compensated),
        reference.topic(),
    );
    for record in reader {
        let record = record.map_err(|e| read_error(path, e))?;
        let on = &*record.topic;
        match &record.message {
            Message::AccelBlock(b) if on == accel => pairs.add_readings(b)?,
            Message::CompensatedBlock(b) if on == compensated => pairs.add_compensated(b)?,
            m if on == reference_topic => {
                if let Some(mut block) = reference.samples(m) {
                    // A rig's reference plus each unit's fitted linear response to the
                    // vibration (`crate::linear`): what an ideal unit reads.
                    if let (Reference::Rig, Some(rig)) = (block.source, &rig) {
                        shifted.clear();
                        shifted.extend(block.reference_ia_g.iter().enumerate().map(|(k, a)| {
                            let i = block.first_sample_index + k as u64;
                            match rig.readings.get(&i).and_then(|f| f.linear_g) {
                                Some(l) => std::array::from_fn(|u| a[u] + l[u]),
                                None => [f64::NAN; UNITS],
                            }
                        }));
                        block.reference_ia_g = &shifted;
                    }
                    pairs.add_reference(block)?;
                }
            }
            _ => {}
        }
    }
    Ok(LogErrors {
        log: path.to_path_buf(),
        passports,
        linear_response: rig.map(|r| LinearResponseSummary {
            fits: r.fits,
            fitted_readings: r.fitted_readings,
        }),
        errors: pairs.finish()?,
    })
}

/// For a log whose reference is a rig's (`truth_flags::SENSED_UNKNOWN`): each unit's
/// linear response to the vibration, fitted through the vibration sensors
/// (`crate::linear`), with the log's passports, the triad `triad` (the geometry) and the
/// sensors' chain the log states (the estimator's configuration a recording attaches,
/// or an imported log's `rig` metadata). `None` for other logs.
fn rig_linear(
    path: &Path,
    reader: &mut Reader,
    triad: &vibro_config::TriadConfig,
) -> Result<Option<crate::linear::LinearResponses>> {
    use crate::linear::{fit_linear_responses, RigReading};
    let (accel, truth) = (topic(Stream::Accel), topic(Stream::Truth));
    // Per sample index: the reading (latch time, outputs) and the rig's reference.
    type Pair = (Option<(u64, [f64; UNITS])>, Option<[f64; UNITS]>);
    let mut rows: BTreeMap<u64, Pair> = BTreeMap::new();
    let mut period_ns = 0;
    let mut any_rig = false;
    let pass = Reader::open(path).map_err(|e| read_error(path, e))?;
    for record in pass {
        let record = record.map_err(|e| read_error(path, e))?;
        match &record.message {
            Message::AccelBlock(b) if *record.topic == accel => {
                period_ns = b.sample_period_ns;
                for (k, u) in b.samples_v().iter().enumerate() {
                    let latch = b.t0_ns + k as u64 * b.sample_period_ns;
                    rows.entry(b.first_sample_index + k as u64).or_default().0 = Some((latch, *u));
                }
            }
            Message::TruthBlock(b)
                if *record.topic == truth && b.flags & truth_flags::SENSED_UNKNOWN != 0 =>
            {
                any_rig = true;
                for k in 0..(b.count as usize).min(b.a_l_ia_g.len()) {
                    if b.a_l_ia_g[k].iter().all(|x| x.is_finite()) {
                        rows.entry(b.first_sample_index + k as u64).or_default().1 =
                            Some(b.a_l_ia_g[k]);
                    }
                }
            }
            _ => {}
        }
        if rows.len() > MAX_RIG_READINGS {
            return Err(bad(
                path,
                format!("over {MAX_RIG_READINGS} readings of a rig's reference: more than `log errors` fits at once"),
            ));
        }
    }
    if !any_rig {
        return Ok(None);
    }
    let readings: BTreeMap<u64, RigReading> = rows
        .into_iter()
        .filter_map(|(i, (r, a))| {
            let ((latch_ns, output_v), a_l_ia_g) = (r?, a?);
            Some((
                i,
                RigReading {
                    latch_ns,
                    output_v,
                    a_l_ia_g,
                },
            ))
        })
        .collect();
    let mut passports = Vec::with_capacity(UNITS);
    for lp in read_passports(reader)? {
        let file = format!("{} attachment {}", path.display(), lp.attachment);
        let p = vibro_config::parse_passport(&lp.toml, &file)?;
        let mut spec = p.to_spec();
        // The lab's flat passport: lambda(w) is the frequency response's business.
        spec.lambda.clear();
        let flat = vibro_physics::passport::Passport::try_from_spec(&spec)
            .map_err(|e| bad(path, format!("passport {}: {e}", lp.attachment)))?;
        if passports.len() <= lp.index {
            passports.resize(lp.index + 1, flat);
        }
        passports[lp.index] = flat;
    }
    let Ok(passports) = <[vibro_physics::passport::Passport; UNITS]>::try_from(passports) else {
        return Err(bad(
            path,
            "a rig's reference needs the three units' passports".into(),
        ));
    };
    let sensors = log_sensor_chain(path, reader)?;
    let fitted = fit_linear_responses(
        path,
        &readings,
        period_ns,
        &triad.axes,
        &passports,
        &sensors,
    )?;
    Ok(Some(fitted))
}

/// Readings of a rig's reference `log errors` fits at most (45 min at 800 Hz).
const MAX_RIG_READINGS: usize = 2_160_000;

/// The vibration sensors' chain a log states: the estimator's configuration a recording
/// attaches (`estimator.toml`, its `[estimator]` sensitivity and AC corner), else an
/// imported log's `rig` metadata.
fn log_sensor_chain(path: &Path, reader: &mut Reader) -> Result<crate::linear::SensorChain> {
    if let Some(bytes) = reader
        .read_attachment("estimator.toml")
        .map_err(|e| read_error(path, e))?
    {
        let text = String::from_utf8_lossy(&bytes);
        let table: toml::Table = toml::from_str(&text)
            .map_err(|e| bad(path, format!("attachment estimator.toml: {e}")))?;
        let est = table.get("estimator").and_then(|v| v.as_table());
        let sens: Option<Vec<f64>> = est
            .and_then(|t| t.get("sensitivity_raw_per_g"))
            .and_then(|v| v.as_array())
            .map(|a| a.iter().filter_map(|x| x.as_float()).collect());
        if let Some([a, b, c]) = sens.as_deref() {
            let ac = est
                .and_then(|t| t.get("ac_corner_hz"))
                .and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)));
            return Ok(crate::linear::SensorChain {
                sensitivity_v_per_g: [*a, *b, *c],
                ac_corner_hz: ac.filter(|x| *x > 0.0),
            });
        }
    }
    let meta = reader.metadata().map_err(|e| read_error(path, e))?;
    if let Some((_, m)) = meta
        .iter()
        .find(|(n, _)| n == crate::attachments::RIG_METADATA)
    {
        let num = |k: &str| m.get(k).and_then(|v| v.parse::<f64>().ok());
        if let (Some(a), Some(b), Some(c)) = (
            num("sensor1_sensitivity_v_per_g"),
            num("sensor2_sensitivity_v_per_g"),
            num("sensor3_sensitivity_v_per_g"),
        ) {
            return Ok(crate::linear::SensorChain {
                sensitivity_v_per_g: [a, b, c],
                ac_corner_hz: num("sensor_ac_corner_hz").filter(|x| *x > 0.0),
            });
        }
    }
    Err(bad(
        path,
        "a rig's reference needs the vibration sensors' chain (their sensitivity and AC \
         corner): the log states it in neither an estimator.toml attachment (a recording \
         of `vibrocomp up --record`) nor `rig` metadata (`log import --rig`)"
            .into(),
    ))
}

fn bad(path: &Path, problem: String) -> Error {
    Error::BadLog {
        path: path.to_path_buf(),
        problem,
    }
}

fn window_error(window_s: f64, rule: String) -> Error {
    Error::Option {
        name: "--window-s",
        value: window_s.to_string(),
        rule: rule.into(),
    }
}

/// A log without compensated output, and what makes one.
fn no_compensated(path: &Path, found: &str) -> String {
    let p = path.display();
    format!(
        "no compensated output (/compensated, CompensatedBlock): {found}. The errors need the compensator's output: replay the log through the services and record the session first, e.g. `vibrocomp up --record session.mcap` and, in another terminal, `vibrocomp replay {p}`, then `vibrocomp log errors session.mcap`"
    )
}

fn no_reference(found: &str) -> String {
    let sources: Vec<String> = Reference::ALL
        .iter()
        .map(|r| format!("{} ({})", r.topic(), r.field()))
        .collect();
    format!(
        "no reference to measure the errors against: they need, per accelerometer sample, the acceleration each unit should read, from {}; {found} (a replayed simulated flight publishes /truth, which `vibrocomp record` keeps unless --topics leaves it out; a rig's log gets its reference from `vibrocomp log import --rig RIG.toml`)",
        sources.join(" or ")
    )
}

fn no_readings(found: &str) -> String {
    format!("no accelerometer readings (/accel, AccelBlock), whose U/K1 is the uncompensated stage: {found}")
}

/// Each unit's `K1` from the passports `reader`'s log carries, and their attachments.
fn log_k1(path: &Path, reader: &mut Reader) -> Result<([f64; UNITS], Vec<String>)> {
    let mut found: [Option<(String, f64)>; TRIAD_UNITS] = Default::default();
    // A later passport of a unit replaces an earlier one (`read_passports`).
    for lp in read_passports(reader)? {
        let file = format!("{} attachment {}", path.display(), lp.attachment);
        let p = vibro_config::parse_passport(&lp.toml, &file)?;
        if let Some(slot) = found.get_mut(lp.index) {
            *slot = Some((lp.attachment, p.k1_v_per_g));
        }
    }
    let missing: Vec<String> = (0..TRIAD_UNITS)
        .filter(|&i| found[i].is_none())
        .map(|i| format!("AK{} (passport-{i}-*.toml)", i + 1))
        .collect();
    if !missing.is_empty() {
        return Err(bad(
            path,
            format!(
                "no passport of {}: the readings U need each unit's K1 to be compared in g, and `vibrocomp record` attaches the compensator's passports to the logs it writes",
                missing.join(", ")
            ),
        ));
    }
    let mut k1 = [0.0; UNITS];
    let mut names = Vec::with_capacity(UNITS);
    for (i, unit) in found.into_iter().enumerate() {
        if let Some((name, k)) = unit {
            k1[i] = k;
            names.push(name);
        }
    }
    Ok((k1, names))
}

/// One accelerometer sample's inputs, as they arrive.
#[derive(Debug, Default, Clone, Copy)]
struct Sample {
    reading_v: Option<[f64; UNITS]>,
    reference_g: Option<[f64; UNITS]>,
    compensated: Option<Compensated>,
}

#[derive(Debug, Clone, Copy)]
struct Compensated {
    a2_g: [f64; UNITS],
    a4_g: [f64; UNITS],
    main_only: bool,
    /// The estimate stage's answer: `a3` of a `WAVEFORM` block, `a4` of the others.
    estimate_g: [f64; UNITS],
    /// Whether that answer is main error only.
    estimate_main_only: bool,
}

impl Sample {
    fn is_complete(&self) -> bool {
        self.reading_v.is_some() && self.reference_g.is_some() && self.compensated.is_some()
    }
}

/// A complete window: per unit, the mean error of each stage, g.
#[derive(Debug, Clone, Copy)]
struct WindowMeans {
    main_only: bool,
    estimate_main_only: bool,
    uncompensated_g: [f64; UNITS],
    main_removed_g: [f64; UNITS],
    vibration_removed_g: [f64; UNITS],
    estimate_stage_g: [f64; UNITS],
}

/// The three inputs of the measure.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Input {
    Readings,
    Reference,
    Compensated,
}

/// The inputs of a stage-error measure paired by accelerometer sample index: readings
/// ([`add_readings`](Self::add_readings)), reference
/// ([`add_reference`](Self::add_reference)) and compensated stages
/// ([`add_compensated`](Self::add_compensated)), in any order and interleaving. A
/// window is reduced to its means as soon as its last sample is complete, so memory
/// holds only the windows still waiting for an input.
#[derive(Debug)]
pub struct StagePairs {
    /// The log (or stream) the samples come from, named in errors.
    origin: PathBuf,
    reference: Reference,
    k1_v_per_g: [f64; UNITS],
    window_s: f64,
    /// Set by the first block; every block must have it.
    sample_period_ns: Option<u64>,
    window_samples: u64,
    open: BTreeMap<u64, Sample>,
    /// Complete samples of each open window.
    complete: BTreeMap<u64, u64>,
    closed: BTreeMap<u64, WindowMeans>,
    reading_samples: u64,
    reference_samples: u64,
    compensated_samples: u64,
    blocks: u64,
    main_only_blocks: u64,
    waveform_blocks: u64,
    fallback_blocks: u64,
    estimate_main_only_blocks: u64,
}

/// The estimate-stage flags the compensator sets together with `MAIN_ONLY`
/// (services/compensator `core.rs`: no estimate, or a refused one; stale; ahead). A
/// `WAVEFORM` block keeps them for its `a3` but drops `MAIN_ONLY`, its `a4` being the
/// waveform stage's.
const ESTIMATE_MAIN_ONLY: u32 =
    cf::ESTIMATE_MISSING | cf::VIBRATION_ESTIMATE_STALE | cf::ESTIMATE_AHEAD;

impl StagePairs {
    /// A measure of the samples of `origin` against `reference`, the readings turned
    /// into g with `k1_v_per_g`, averaged over `window_s` windows.
    pub fn new(
        origin: &Path,
        reference: Reference,
        k1_v_per_g: [f64; UNITS],
        window_s: f64,
    ) -> Result<StagePairs> {
        if let Some(rule) = window_problem(window_s) {
            return Err(window_error(window_s, rule));
        }
        if let Some(k) = k1_v_per_g.iter().find(|k| !(k.is_finite() && **k != 0.0)) {
            return Err(Error::Option {
                name: "K1_v_per_g",
                value: k.to_string(),
                rule: "must be finite and nonzero".into(),
            });
        }
        Ok(StagePairs {
            origin: origin.to_path_buf(),
            reference,
            k1_v_per_g,
            window_s,
            sample_period_ns: None,
            window_samples: 0,
            open: BTreeMap::new(),
            complete: BTreeMap::new(),
            closed: BTreeMap::new(),
            reading_samples: 0,
            reference_samples: 0,
            compensated_samples: 0,
            blocks: 0,
            main_only_blocks: 0,
            waveform_blocks: 0,
            fallback_blocks: 0,
            estimate_main_only_blocks: 0,
        })
    }

    /// The readings `U` of an accelerometer block.
    pub fn add_readings(&mut self, block: &AccelBlock) -> Result<()> {
        let samples = block.samples_v();
        self.reading_samples += samples.len() as u64;
        self.add(
            Input::Readings,
            block.first_sample_index,
            block.sample_period_ns,
            samples.len(),
            |s, k| s.reading_v.replace(samples[k]).is_none(),
        )
    }

    /// A block of the reference: what each unit should read.
    pub fn add_reference(&mut self, block: ReferenceBlock<'_>) -> Result<()> {
        let samples = block.reference_ia_g;
        self.reference_samples += samples.len() as u64;
        // A rig's reference names the table's; a sample it does not cover (NaN) is
        // left out, and with it its window.
        if block.source == Reference::Rig {
            self.reference = Reference::Rig;
        }
        self.add(
            Input::Reference,
            block.first_sample_index,
            block.sample_period_ns,
            samples.len(),
            |s, k| {
                if samples[k].iter().all(|x| x.is_finite()) {
                    s.reference_g.replace(samples[k]).is_none()
                } else {
                    true
                }
            },
        )
    }

    /// A compensated block: `a(2)`, `a(4)` and whether it was main-only; from a
    /// `WAVEFORM` block also the estimate stage's answer `a(3)` and whether that was.
    pub fn add_compensated(&mut self, block: &CompensatedBlock) -> Result<()> {
        self.blocks += 1;
        let main_only = block.flags & cf::MAIN_ONLY != 0;
        let waveform = block.flags & cf::WAVEFORM != 0;
        let estimate_main_only = if waveform {
            block.flags & ESTIMATE_MAIN_ONLY != 0
        } else {
            main_only
        };
        self.main_only_blocks += u64::from(main_only);
        self.estimate_main_only_blocks += u64::from(estimate_main_only);
        self.waveform_blocks += u64::from(waveform);
        self.fallback_blocks += u64::from(!waveform && block.flags & cf::WAVEFORM_FALLBACK != 0);
        let n = (block.count as usize)
            .min(block.a2_g.len())
            .min(block.a3_g.len())
            .min(block.a4_g.len());
        self.compensated_samples += n as u64;
        self.add(
            Input::Compensated,
            block.first_sample_index,
            block.sample_period_ns,
            n,
            |s, k| {
                let c = Compensated {
                    a2_g: block.a2_g[k],
                    a4_g: block.a4_g[k],
                    main_only,
                    estimate_g: if waveform {
                        block.a3_g[k]
                    } else {
                        block.a4_g[k]
                    },
                    estimate_main_only,
                };
                s.compensated.replace(c).is_none()
            },
        )
    }

    fn bad(&self, problem: String) -> Error {
        bad(&self.origin, problem)
    }

    fn input_name(&self, input: Input) -> String {
        match input {
            Input::Readings => "the readings (/accel)".to_string(),
            Input::Reference => format!("the reference ({})", self.reference.topic()),
            Input::Compensated => "the compensated output (/compensated)".to_string(),
        }
    }

    /// Samples `first .. first + n` of `input`, each filled in by `fill(sample, k)`,
    /// which says whether the sample had none of this input yet.
    fn add(
        &mut self,
        input: Input,
        first: u64,
        sample_period_ns: u64,
        n: usize,
        mut fill: impl FnMut(&mut Sample, usize) -> bool,
    ) -> Result<()> {
        if n == 0 {
            return Ok(());
        }
        let per_window = self.check_period(input, first, sample_period_ns)?;
        for k in 0..n {
            let Some(index) = first.checked_add(k as u64) else {
                return Err(self.bad(format!(
                    "{}: sample index {first} + {k} overflows",
                    self.input_name(input)
                )));
            };
            let window = index / per_window;
            let repeated = |me: &Self| {
                me.bad(format!(
                    "sample {index} of {} comes twice: the log holds more than one run of its producer (two replays into one recording?); measure one run per log",
                    me.input_name(input)
                ))
            };
            if self.closed.contains_key(&window) {
                return Err(repeated(self));
            }
            if self.open.len() >= MAX_OPEN_SAMPLES && !self.open.contains_key(&index) {
                return Err(self.bad(format!(
                    "over {MAX_OPEN_SAMPLES} samples wait for the rest of their window of {} s: an input is missing for that long, or the window is too long",
                    self.window_s
                )));
            }
            let sample = self.open.entry(index).or_default();
            if !fill(sample, k) {
                return Err(repeated(self));
            }
            if sample.is_complete() {
                let done = self.complete.entry(window).or_insert(0);
                *done += 1;
                if *done == per_window {
                    self.close(window, per_window);
                }
            }
        }
        Ok(())
    }

    /// The samples per window, set by the first block; a block of another period is
    /// refused (the windows need one rate).
    fn check_period(&mut self, input: Input, first: u64, sample_period_ns: u64) -> Result<u64> {
        if sample_period_ns == 0 {
            return Err(self.bad(format!(
                "{}: the block from sample {first} has a sample period of 0 ns",
                self.input_name(input)
            )));
        }
        match self.sample_period_ns {
            Some(p) if p == sample_period_ns => Ok(self.window_samples),
            Some(p) => Err(self.bad(format!(
                "{}: the block from sample {first} has a sample period of {sample_period_ns} ns, the log's first block {p} ns: the windows need one rate",
                self.input_name(input)
            ))),
            None => {
                let periods = self.window_s * 1e9 / sample_period_ns as f64;
                if periods < 1.0 {
                    return Err(window_error(
                        self.window_s,
                        format!(
                            "shorter than one accelerometer output of {} ({} s)",
                            self.origin.display(),
                            sample_period_ns as f64 * 1e-9
                        ),
                    ));
                }
                // At most MAX_WINDOW_S / 1 ns = 8.64e13: exact in f64 and u64.
                self.window_samples = (periods.round() as u64).max(1);
                self.sample_period_ns = Some(sample_period_ns);
                Ok(self.window_samples)
            }
        }
    }

    /// Reduces the complete window `window` to its means, in sample order.
    fn close(&mut self, window: u64, per_window: u64) {
        let start = window * per_window;
        let rows: Vec<Sample> = self
            .open
            .range(start..start + per_window)
            .map(|(_, s)| *s)
            .collect();
        for i in start..start + per_window {
            self.open.remove(&i);
        }
        self.complete.remove(&window);
        let n = rows.len() as f64;
        let mut means = WindowMeans {
            main_only: rows
                .iter()
                .any(|r| r.compensated.is_some_and(|c| c.main_only)),
            estimate_main_only: rows
                .iter()
                .any(|r| r.compensated.is_some_and(|c| c.estimate_main_only)),
            uncompensated_g: [0.0; UNITS],
            main_removed_g: [0.0; UNITS],
            vibration_removed_g: [0.0; UNITS],
            estimate_stage_g: [0.0; UNITS],
        };
        let nan3 = [f64::NAN; UNITS];
        for u in 0..UNITS {
            let mean = |f: &dyn Fn(&Sample) -> f64| rows.iter().map(f).sum::<f64>() / n;
            // The reference of the sample (every row here is complete).
            let r = |s: &Sample| s.reference_g.unwrap_or(nan3)[u];
            let k1 = self.k1_v_per_g[u];
            means.uncompensated_g[u] = mean(&|s| s.reading_v.unwrap_or(nan3)[u] / k1 - r(s));
            means.main_removed_g[u] =
                mean(&|s| s.compensated.map_or(f64::NAN, |c| c.a2_g[u]) - r(s));
            means.vibration_removed_g[u] =
                mean(&|s| s.compensated.map_or(f64::NAN, |c| c.a4_g[u]) - r(s));
            means.estimate_stage_g[u] =
                mean(&|s| s.compensated.map_or(f64::NAN, |c| c.estimate_g[u]) - r(s));
        }
        self.closed.insert(window, means);
    }

    /// The errors over the complete windows; fails naming what is missing.
    pub fn finish(self) -> Result<SessionErrors> {
        let origin = self.origin.display().to_string();
        let counts = format!(
            "{} reading, {} reference and {} compensated samples",
            self.reading_samples, self.reference_samples, self.compensated_samples
        );
        if self.compensated_samples == 0 {
            return Err(self.bad(no_compensated(
                &self.origin,
                &format!("its compensated stream has no samples ({counts})"),
            )));
        }
        if self.reference_samples == 0 {
            return Err(self.bad(no_reference(&format!(
                "{} has no samples ({counts})",
                self.reference.topic()
            ))));
        }
        if self.reading_samples == 0 {
            return Err(self.bad(no_readings(&format!("/accel has no samples ({counts})"))));
        }
        let samples =
            self.closed.len() as u64 * self.window_samples + self.complete.values().sum::<u64>();
        if samples == 0 {
            return Err(self.bad(format!(
                "no accelerometer sample has a reading, a reference and a compensated output together ({counts}): do the streams come from one run?"
            )));
        }
        if self.closed.is_empty() {
            return Err(self.bad(format!(
                "no complete window of {} s ({} samples): {samples} samples have all three inputs, but no window has all of its samples (a session shorter than a window, or gaps); try a shorter --window-s",
                self.window_s, self.window_samples
            )));
        }
        let compensated: Vec<&WindowMeans> =
            self.closed.values().filter(|w| !w.main_only).collect();
        if compensated.is_empty() {
            return Err(self.bad(format!(
                "no window of {} s was compensated with a vibration estimate ({} blocks, {} main-only) in {origin}",
                self.window_s, self.blocks, self.main_only_blocks
            )));
        }
        // The estimate stage's column, where the waveform stage made blocks: over the
        // windows it compensated itself (its answer in the others is main error only).
        let two_stages = self.waveform_blocks > 0;
        let by_estimate: Vec<&WindowMeans> = self
            .closed
            .values()
            .filter(|w| !w.estimate_main_only)
            .collect();
        type Means = fn(&WindowMeans) -> [f64; UNITS];
        // One stage's window means of unit `u` (every unit: `None`) over `windows`.
        let values = |windows: &[&WindowMeans], f: Means, u: Option<usize>| -> Vec<f64> {
            let units = u.map_or(0..UNITS, |u| u..u + 1);
            units
                .flat_map(|u| windows.iter().map(move |w| f(w)[u]))
                .collect()
        };
        let errors = |u: Option<usize>| {
            let mut s = stage(
                &values(&compensated, |w| w.uncompensated_g, u),
                &values(&compensated, |w| w.main_removed_g, u),
                &values(&compensated, |w| w.vibration_removed_g, u),
            );
            s.estimate_stage_rms_g =
                two_stages.then(|| rms(&values(&by_estimate, |w| w.estimate_stage_g, u)));
            s
        };
        Ok(SessionErrors {
            window_s: self.window_s,
            window_samples: self.window_samples,
            reference: self.reference,
            reference_topic: self.reference.topic(),
            k1_v_per_g: self.k1_v_per_g,
            reading_samples: self.reading_samples,
            reference_samples: self.reference_samples,
            compensated_samples: self.compensated_samples,
            samples,
            windows: self.closed.len() as u64,
            compensated_windows: compensated.len() as u64,
            main_only_blocks: self.main_only_blocks,
            blocks: self.blocks,
            waveform_blocks: self.waveform_blocks,
            fallback_blocks: self.fallback_blocks,
            estimate_only_blocks: self.blocks - self.waveform_blocks - self.fallback_blocks,
            estimate_stage: two_stages.then_some(EstimateStageWindows {
                compensated_windows: by_estimate.len() as u64,
                main_only_blocks: self.estimate_main_only_blocks,
            }),
            all_units: errors(None),
            units: (0..UNITS)
                .map(|u| UnitErrors {
                    unit: u + 1,
                    errors: errors(Some(u)),
                })
                .collect(),
        })
    }
}

fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

fn stage(unc: &[f64], main: &[f64], vib: &[f64]) -> StageErrors {
    let (u, m, v) = (rms(unc), rms(main), rms(vib));
    StageErrors {
        uncompensated_rms_g: u,
        main_removed_rms_g: m,
        vibration_removed_rms_g: v,
        reduction: if v > 0.0 { u / v } else { f64::INFINITY },
        estimate_stage_rms_g: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIOD_NS: u64 = 1_000_000;
    /// 10 samples per window at 1 kHz.
    const WINDOW_S: f64 = 0.01;
    const K1_V_PER_G: [f64; 3] = [2.0, -1.5, 4.0];
    /// Per unit: the uncompensated bias, what the main stage leaves, and the
    /// vibration stage's residual in window 1 (window `w`: `w` times as much).
    const BIAS_G: [f64; 3] = [1e-3, 2e-3, -3e-3];
    const MAIN_G: [f64; 3] = [4e-5, -5e-5, 6e-5];
    const VIB_G: [f64; 3] = [1e-6, -2e-6, 3e-6];
    /// A zero-mean dither on every vibration-stage sample (+ on even, - on odd
    /// indices), which a window's mean removes.
    const DITHER_G: f64 = 2e-3;

    fn reference_g(i: u64) -> [f64; 3] {
        [1.0 + 0.01 * i as f64, -0.5, 2.0 - 0.001 * i as f64]
    }

    /// Blocks of 8 samples (windows of 10 cut across them), 40 samples: 4 windows.
    /// The first compensated block is main-only, so window 0 is not compensated.
    fn blocks() -> (Vec<AccelBlock>, Vec<[[f64; 3]; 8]>, Vec<CompensatedBlock>) {
        let (mut accel, mut reference, mut comp) = (Vec::new(), Vec::new(), Vec::new());
        for b in 0..5u64 {
            let mut a = AccelBlock::ZEROED;
            let mut c = CompensatedBlock::ZEROED;
            let mut r = [[0.0; 3]; 8];
            for blk in [&mut a.first_sample_index, &mut c.first_sample_index] {
                *blk = 8 * b;
            }
            a.sample_period_ns = PERIOD_NS;
            c.sample_period_ns = PERIOD_NS;
            a.count = 8;
            c.count = 8;
            if b == 0 {
                c.flags = cf::MAIN_ONLY;
            }
            for (k, rk) in r.iter_mut().enumerate() {
                let i = 8 * b + k as u64;
                let w = (i / 10) as f64;
                let dither = if i % 2 == 0 { DITHER_G } else { -DITHER_G };
                *rk = reference_g(i);
                for u in 0..3 {
                    a.output_v[k][u] = K1_V_PER_G[u] * (rk[u] + BIAS_G[u]);
                    c.a2_g[k][u] = rk[u] + MAIN_G[u];
                    c.a4_g[k][u] = rk[u] + w * VIB_G[u] + dither;
                }
            }
            accel.push(a);
            reference.push(r);
            comp.push(c);
        }
        (accel, reference, comp)
    }

    fn reference_block(first: u64, r: &[[f64; 3]]) -> ReferenceBlock<'_> {
        ReferenceBlock {
            first_sample_index: first,
            sample_period_ns: PERIOD_NS,
            reference_ia_g: r,
            source: Reference::Truth,
        }
    }

    fn pairs() -> StagePairs {
        StagePairs::new(Path::new("t.mcap"), Reference::Truth, K1_V_PER_G, WINDOW_S).unwrap()
    }

    /// The five blocks of each input, paired in order, measured.
    fn measured(
        accel: &[AccelBlock],
        reference: &[[[f64; 3]; 8]],
        comp: &[CompensatedBlock],
    ) -> SessionErrors {
        let mut p = pairs();
        for b in 0..5 {
            p.add_readings(&accel[b]).unwrap();
            p.add_reference(reference_block(8 * b as u64, &reference[b]))
                .unwrap();
            p.add_compensated(&comp[b]).unwrap();
        }
        p.finish().unwrap()
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * b.abs()
    }

    /// The closed forms: a constant error's RMS over windows is itself; the vibration
    /// stage's residual grows 1, 2, 3 over the compensated windows 1..3 (window 0 is
    /// main-only), and the per-sample dither averages out.
    #[test]
    fn the_errors_are_the_closed_forms_and_independent_of_the_order_of_arrival() {
        let (accel, reference, comp) = blocks();
        let e = measured(&accel, &reference, &comp);
        assert_eq!(
            (
                e.window_samples,
                e.samples,
                e.windows,
                e.compensated_windows
            ),
            (10, 40, 4, 3)
        );
        assert_eq!((e.blocks, e.main_only_blocks), (5, 1));
        let vib_scale = ((1.0 + 4.0 + 9.0) / 3.0f64).sqrt();
        for (u, unit) in e.units.iter().enumerate() {
            let s = &unit.errors;
            assert_eq!(unit.unit, u + 1);
            assert!(close(s.uncompensated_rms_g, BIAS_G[u].abs()), "{s:?}");
            assert!(close(s.main_removed_rms_g, MAIN_G[u].abs()), "{s:?}");
            assert!(
                close(s.vibration_removed_rms_g, VIB_G[u].abs() * vib_scale),
                "{s:?}"
            );
        }
        let all = |x: [f64; 3]| ((x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) / 3.0).sqrt();
        assert!(close(e.all_units.uncompensated_rms_g, all(BIAS_G)));
        assert!(close(e.all_units.main_removed_rms_g, all(MAIN_G)));
        assert!(close(
            e.all_units.vibration_removed_rms_g,
            all(VIB_G) * vib_scale
        ));

        // Compensated output first, the readings last and backwards: the same bits.
        let mut q = pairs();
        for b in 0..5 {
            q.add_compensated(&comp[b]).unwrap();
            q.add_reference(reference_block(8 * b as u64, &reference[b]))
                .unwrap();
        }
        for b in (0..5).rev() {
            q.add_readings(&accel[b]).unwrap();
        }
        let f = q.finish().unwrap();
        // Debug prints every f64 in its shortest round-trip form: equal text, equal bits.
        assert_eq!(format!("{e:?}"), format!("{f:?}"));
    }

    #[test]
    fn a_repeated_sample_a_second_rate_and_a_window_under_one_period_are_refused() {
        let (accel, reference, comp) = blocks();
        let mut p = pairs();
        p.add_readings(&accel[0]).unwrap();
        let e = p.add_readings(&accel[0]).unwrap_err().to_string();
        assert_eq!(e, "t.mcap: sample 0 of the readings (/accel) comes twice: the log holds more than one run of its producer (two replays into one recording?); measure one run per log");
        // Also once its window has been reduced.
        let mut p = pairs();
        for b in 0..2 {
            p.add_readings(&accel[b]).unwrap();
            p.add_reference(reference_block(8 * b as u64, &reference[b]))
                .unwrap();
            p.add_compensated(&comp[b]).unwrap();
        }
        let e = p.add_compensated(&comp[0]).unwrap_err().to_string();
        assert!(
            e.contains("sample 0 of the compensated output (/compensated) comes twice"),
            "{e}"
        );

        let mut p = pairs();
        p.add_readings(&accel[0]).unwrap();
        let mut faster = accel[1];
        faster.sample_period_ns = PERIOD_NS / 2;
        let e = p.add_readings(&faster).unwrap_err().to_string();
        assert_eq!(e, "t.mcap: the readings (/accel): the block from sample 8 has a sample period of 500000 ns, the log's first block 1000000 ns: the windows need one rate");

        let mut p =
            StagePairs::new(Path::new("t.mcap"), Reference::Truth, K1_V_PER_G, 5e-4).unwrap();
        let e = p.add_readings(&accel[0]).unwrap_err().to_string();
        assert_eq!(
            e,
            "--window-s = 0.0005: shorter than one accelerometer output of t.mcap (0.001 s)"
        );
        assert_eq!(
            window_problem(0.0),
            Some("must be finite and 0 < s <= 86400".to_string())
        );
        assert!(window_problem(f64::NAN).is_some());
        assert!(window_problem(1e5).is_some());
        assert_eq!(window_problem(DEFAULT_WINDOW_S), None);
    }

    /// Each missing input is named, with what makes it; too few samples for a window
    /// and no window with an estimate too.
    #[test]
    fn what_is_missing_is_named() {
        let (accel, reference, comp) = blocks();
        let mut p = pairs();
        p.add_readings(&accel[0]).unwrap();
        p.add_reference(reference_block(0, &reference[0])).unwrap();
        let e = p.finish().unwrap_err().to_string();
        assert!(e.starts_with("t.mcap: no compensated output (/compensated, CompensatedBlock): its compensated stream has no samples (8 reading, 8 reference and 0 compensated samples)."), "{e}");
        assert!(e.contains("`vibrocomp up --record session.mcap`"), "{e}");
        assert!(e.contains("`vibrocomp replay t.mcap`"), "{e}");

        let mut p = pairs();
        p.add_readings(&accel[0]).unwrap();
        p.add_compensated(&comp[0]).unwrap();
        let e = p.finish().unwrap_err().to_string();
        assert!(e.starts_with("t.mcap: no reference to measure the errors against: they need, per accelerometer sample, the acceleration each unit should read, from /truth (TruthBlock.a_sensed_ia_g); /truth has no samples"), "{e}");

        // One block: 8 samples, fewer than a window.
        let mut p = pairs();
        p.add_readings(&accel[0]).unwrap();
        p.add_reference(reference_block(0, &reference[0])).unwrap();
        p.add_compensated(&comp[0]).unwrap();
        let e = p.finish().unwrap_err().to_string();
        assert!(e.starts_with("t.mcap: no complete window of 0.01 s (10 samples): 8 samples have all three inputs"), "{e}");

        // Two blocks: window 0 is complete but main-only.
        let mut p = pairs();
        for b in 0..2 {
            p.add_readings(&accel[b]).unwrap();
            p.add_reference(reference_block(8 * b as u64, &reference[b]))
                .unwrap();
            p.add_compensated(&comp[b]).unwrap();
        }
        let e = p.finish().unwrap_err().to_string();
        assert!(e.starts_with("t.mcap: no window of 0.01 s was compensated with a vibration estimate (2 blocks, 1 main-only)"), "{e}");
    }

    #[test]
    fn the_table_reads_as_the_demo_prints_it() {
        let stage = |u: f64, m: f64, v: f64| StageErrors {
            uncompensated_rms_g: u,
            main_removed_rms_g: m,
            vibration_removed_rms_g: v,
            reduction: u / v,
            estimate_stage_rms_g: None,
        };
        let e = SessionErrors {
            window_s: 0.5,
            window_samples: 400,
            reference: Reference::Truth,
            reference_topic: "/truth".into(),
            k1_v_per_g: K1_V_PER_G,
            reading_samples: 16000,
            reference_samples: 16000,
            compensated_samples: 16000,
            samples: 16000,
            windows: 40,
            compensated_windows: 38,
            main_only_blocks: 24,
            blocks: 500,
            waveform_blocks: 0,
            fallback_blocks: 0,
            estimate_only_blocks: 500,
            estimate_stage: None,
            all_units: stage(8.2258e-3, 97.5141e-6, 8.7034e-6),
            units: vec![UnitErrors {
                unit: 1,
                errors: stage(11.1409e-3, 0.1646e-3, 13.6836e-6),
            }],
        };
        let mut text = String::new();
        e.write_table(&mut text).unwrap();
        assert_eq!(
            text,
            "Error against the sensed acceleration, mean over 0.5 s windows (38 of 40 windows compensated with a vibration estimate; 24 blocks compensated for the main error only: before the first estimate, or with a stale one):
  unit         uncompensated    main removed   vibration removed   reduction
  AK1             11.1409 mg       0.1646 mg          13.6836 ug      814.2x
  all              8.2258 mg      97.5141 ug           8.7034 ug      945.1x
"
        );

        // With waveform-stage blocks: the estimate stage's column and both counts.
        let with = |mut s: StageErrors, est: f64| {
            s.estimate_stage_rms_g = Some(est);
            s
        };
        let e = SessionErrors {
            waveform_blocks: 470,
            fallback_blocks: 6,
            estimate_only_blocks: 24,
            compensated_windows: 40,
            main_only_blocks: 0,
            estimate_stage: Some(EstimateStageWindows {
                compensated_windows: 38,
                main_only_blocks: 24,
            }),
            all_units: with(stage(8.2258e-3, 97.5141e-6, 1.2e-6), 8.7034e-6),
            units: vec![UnitErrors {
                unit: 1,
                errors: with(stage(11.1409e-3, 0.1646e-3, 1.5e-6), 13.6836e-6),
            }],
            ..e
        };
        let mut text = String::new();
        e.write_table(&mut text).unwrap();
        assert_eq!(
            text,
            "Error against the sensed acceleration, mean over 0.5 s windows; blocks: 470 made by the waveform stage, 6 by the estimate stage where the samples did not cover them, 24 by the estimate stage alone:
  vibration removed (published a4): 40 of 40 windows compensated (0 blocks main error only); estimate stage (its answer, a3 of waveform blocks): 38 of 40 windows compensated with a vibration estimate (24 blocks without one)
  unit         uncompensated    main removed    estimate stage   vibration removed   reduction
  AK1             11.1409 mg       0.1646 mg        13.6836 ug           1.5000 ug     7427.3x
  all              8.2258 mg      97.5141 ug         8.7034 ug           1.2000 ug     6854.8x
"
        );
    }

    /// Waveform-stage blocks: `a4` is the published output, `a3` the estimate stage's
    /// answer. Block 0 is `WAVEFORM` with `ESTIMATE_MISSING` (its `a3` main error
    /// only), block 1 `WAVEFORM_FALLBACK` (the estimate stage's `a4`), the rest
    /// `WAVEFORM`: the published output counts windows 0..3, the estimate stage 1..3.
    #[test]
    fn waveform_blocks_give_both_stages_over_their_own_windows() {
        const EST_G: [f64; 3] = [5e-6, -6e-6, 7e-6];
        let (accel, reference, mut comp) = blocks();
        for (b, c) in comp.iter_mut().enumerate() {
            c.flags = match b {
                0 => cf::WAVEFORM | cf::ESTIMATE_MISSING,
                1 => cf::WAVEFORM_FALLBACK,
                _ => cf::WAVEFORM,
            };
            for (k, rk) in reference[b].iter().enumerate() {
                let i = 8 * b as u64 + k as u64;
                let w = (i / 10) as f64;
                for u in 0..3 {
                    let r = rk[u];
                    if b == 1 {
                        // The estimate stage's answer is the block's a4.
                        c.a4_g[k][u] = r + w * EST_G[u];
                        c.a3_g[k][u] = f64::NAN;
                    } else {
                        c.a3_g[k][u] = r + w * EST_G[u];
                    }
                }
            }
        }
        let e = measured(&accel, &reference, &comp);
        assert_eq!(
            (e.windows, e.compensated_windows, e.main_only_blocks),
            (4, 4, 0)
        );
        assert_eq!(
            (e.waveform_blocks, e.fallback_blocks, e.estimate_only_blocks),
            (4, 1, 0)
        );
        let est = e.estimate_stage.as_ref().unwrap();
        assert_eq!((est.compensated_windows, est.main_only_blocks), (3, 1));
        // Published: windows 0..3, the fallback block's a4 in window 1 is the estimate
        // stage's (w EST_G), the waveform blocks' w VIB_G (samples 8..15 in windows 0
        // and 1).
        let window_mean = |w: u64, u: usize| -> f64 {
            (10 * w..10 * w + 10)
                .map(|i| {
                    let scale = (i / 10) as f64;
                    if (8..16).contains(&i) {
                        scale * EST_G[u]
                    } else {
                        scale * VIB_G[u]
                    }
                })
                .sum::<f64>()
                / 10.0
        };
        for (u, unit) in e.units.iter().enumerate() {
            let published = ((0..4).map(|w| window_mean(w, u).powi(2)).sum::<f64>() / 4.0).sqrt();
            assert!(
                close(unit.errors.vibration_removed_rms_g, published),
                "{unit:?}"
            );
            // The estimate stage: w EST_G in windows 1..3.
            let estimate = EST_G[u].abs() * ((1.0 + 4.0 + 9.0) / 3.0f64).sqrt();
            assert!(
                close(unit.errors.estimate_stage_rms_g.unwrap(), estimate),
                "{unit:?}"
            );
            assert!(close(unit.errors.uncompensated_rms_g, BIAS_G[u].abs()));
        }
        // An estimate-only log has no estimate-stage column.
        let (accel, reference, comp) = blocks();
        let e = measured(&accel, &reference, &comp);
        assert!(e.estimate_stage.is_none() && e.all_units.estimate_stage_rms_g.is_none());
        assert_eq!(e.estimate_only_blocks, 5);
    }
}
