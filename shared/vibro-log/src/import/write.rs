//! The import itself: both passes over every file, the blocks of all streams written in
//! time order into a temporary file that replaces the output when complete, the
//! metadata and attachments, and the report. Also the parsing core alone
//! ([`read_csv_blocks`]), for the fuzz targets.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use serde::Serialize;
use vibro_mcap::{Recorder, RecorderOptions};
use vibro_msgs::{Stream, TruthBlock};

use super::blocks::BlockMaker;
use super::plan::{ImportPlan, StreamSpec};
use super::progress::{ImportProgress, Tracker};
use super::reference::Reference;
use super::scan::scan;
use super::ImportKind;
use crate::attachments::{LogExtras, IMPORT_METADATA, RIG_METADATA};
use crate::output::PartFile;
use crate::rig::RigMessage;
use crate::{Error, Result};

/// What an import found and wrote for one stream.
#[derive(Debug, Clone, Serialize)]
pub struct StreamReport {
    pub stream: ImportKind,
    pub topic: String,
    pub message_type: String,
    pub file: String,
    pub file_bytes: u64,
    /// Data rows (samples) read.
    pub rows: u64,
    /// 1-based column of each documented name.
    pub columns: BTreeMap<String, usize>,
    pub ignored_columns: Vec<String>,
    pub rate_hz: f64,
    pub rate_from: String,
    pub sample_period_ns: u64,
    pub first_time_s: f64,
    pub last_time_s: f64,
    /// Sample indices spanned: rows + missing samples.
    pub samples_spanned: u64,
    pub block_samples: usize,
    pub blocks: u64,
    pub gaps: u64,
    pub missing_samples: u64,
    /// Largest distance of a row's time from the uniform grid.
    pub max_time_residual_s: f64,
    pub source_id: u32,
}

/// What an import wrote (`vibrocomp log import --json` prints it).
#[derive(Debug, Clone, Serialize)]
pub struct ImportReport {
    pub out: String,
    pub messages: u64,
    pub chunks: u64,
    pub bytes: u64,
    pub elapsed_s: f64,
    pub rows_per_s: f64,
    pub streams: Vec<StreamReport>,
    /// The rig's reference channel (`--rig`).
    pub reference: Option<ReferenceReport>,
}

/// The reference channel an import with a rig file wrote.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceReport {
    pub topic: String,
    /// The rig file.
    pub rig: String,
    /// `static`, `centrifuge` or `stream`.
    pub kind: String,
    /// The stream's CSV (`--reference`).
    pub file: Option<String>,
    /// Readings given a reference block.
    pub readings: u64,
    /// Readings whose interval has no reference (between static orientations): NaN.
    pub readings_without_reference: u64,
}

/// Runs the import `plan`: validates every file (pass 1; problems in the input are
/// [`Error::CsvInput`], all of them at once, and nothing is written), then writes the
/// blocks of every stream in time order into a temporary file beside the output
/// (pass 2; a row off the uniform grid stops the writing, and reading goes on to list
/// every such row), with the `import` metadata and the CSV headers attached, and
/// renames it over the output when complete.
pub fn import(plan: &ImportPlan, progress: &mut dyn ImportProgress) -> Result<ImportReport> {
    let started = Instant::now();
    let total_bytes: u64 = plan
        .streams
        .iter()
        .map(|s| std::fs::metadata(&s.file).map_or(0, |m| m.len()))
        .sum();
    progress.start(2 * total_bytes);
    let mut progress = Tracker::new(progress);

    // Pass 1: validate everything before writing anything.
    progress.sink.pass("checking");
    let mut scans = Vec::new();
    let mut problems = Vec::new();
    for spec in &plan.streams {
        match scan(spec, plan.tolerance, &mut progress)? {
            Ok(scan) => {
                progress.finish_part(scan.bytes);
                scans.push(scan);
            }
            Err(mut p) => problems.extend(p.lines()),
        }
    }
    if let Some(rig) = &plan.rig {
        problems.extend(rate_against_rig(plan, rig, &scans));
    }
    if !problems.is_empty() {
        progress.sink.finish();
        return Err(Error::CsvInput { problems });
    }
    // The rig's reference, covering every reading, before anything is written.
    let reference = match &plan.rig {
        Some(rig) => {
            let r = Reference::load(rig, plan.reference.as_deref());
            let covered = r.as_ref().ok().and_then(|r| {
                let (spec, scan) = plan
                    .streams
                    .iter()
                    .zip(&scans)
                    .find(|(s, _)| s.kind == ImportKind::Accel)?;
                r.check_covers(
                    &spec.file,
                    scan.first_time_s,
                    scan.last_time_s,
                    scan.period_s,
                )
                .err()
            });
            match (r, covered) {
                (Ok(r), None) => Some((rig, r)),
                (Ok(_), Some(problem)) => {
                    progress.sink.finish();
                    return Err(Error::Reference {
                        problems: vec![problem],
                    });
                }
                (Err(problems), _) => {
                    progress.sink.finish();
                    return Err(Error::Reference { problems });
                }
            }
        }
        None => None,
    };

    // Pass 2: blocks, in time order over the streams, into a temporary file.
    progress.sink.pass("importing");
    let part = PartFile::beside(&plan.out)?;
    let mut rec = Recorder::create(part.path(), RecorderOptions::default()).map_err(|source| {
        Error::CreateLog {
            path: plan.out.clone(),
            source,
        }
    })?;
    let mut extras = LogExtras::generated();
    let truth_topic = crate::topic(Stream::Truth);
    if let Some((rig, _)) = &reference {
        rec.add_channel(&truth_topic, Stream::Truth.kind())?;
        for (i, p) in rig.triad.passports.iter().enumerate() {
            let text = toml::to_string(&p.to_spec()).map_err(Error::PassportToml)?;
            extras.passport(i, p.id(), text);
        }
    }
    let mut truth = TruthBlock::ZEROED;
    let mut readings_without_reference = 0u64;
    let mut makers = Vec::new();
    for (spec, scan) in plan.streams.iter().zip(&scans) {
        rec.add_channel(&crate::topic(spec.kind.stream()), spec.kind.stream().kind())?;
        let mut header = LogExtras::generated();
        header.csv_header(spec.kind.name(), scan.header.preamble.clone());
        header.write_to(&rec)?;
        makers.push(BlockMaker::new(spec, scan, plan.tolerance, plan.source_id)?);
    }
    let mut ready = Vec::with_capacity(makers.len());
    for m in &mut makers {
        ready.push(m.fill()?);
    }
    let mut writing = true;
    let mut blocks_since_progress = 0u32;
    loop {
        // The complete block with the earliest time; ties go to the first stream (vib).
        let next = makers
            .iter()
            .enumerate()
            .filter(|(i, _)| ready[*i])
            .min_by_key(|(_, m)| m.block.message().time_ns())
            .map(|(i, _)| i);
        let Some(i) = next else { break };
        // A row off the grid anywhere stops the writing; reading goes on to list
        // every such row.
        writing &= makers.iter().all(|m| m.problems.is_empty());
        if writing {
            let msg = makers[i].block.message();
            write_block(&rec, &makers[i].topic, msg)?;
            if let (Some((rig, r)), RigMessage::Accel(b)) = (&reference, msg) {
                readings_without_reference += r.truth_block(&rig.triad.axes, b, &mut truth);
                write_block(&rec, &truth_topic, RigMessage::Truth(&truth))?;
            }
        }
        ready[i] = makers[i].fill()?;
        blocks_since_progress += 1;
        if blocks_since_progress == 256 {
            blocks_since_progress = 0;
            progress.set_current(makers.iter().map(|m| m.rows.bytes_read()).sum());
        }
    }
    progress.sink.finish();
    for m in &mut makers {
        m.report_off_grid();
    }
    let problems: Vec<String> = makers.iter_mut().flat_map(|m| m.problems.lines()).collect();
    if !problems.is_empty() {
        return Err(Error::CsvInput { problems });
    }

    let mut meta = BTreeMap::from([
        ("tool".to_string(), plan.tool.clone()),
        ("period_tolerance".to_string(), plan.tolerance.to_string()),
        ("source_id".to_string(), plan.source_id.to_string()),
    ]);
    let mut streams = Vec::new();
    for ((spec, scan), maker) in plan.streams.iter().zip(&scans).zip(&makers) {
        let s = spec.kind.name();
        let period_ns = (scan.period_s * 1e9).round() as u64;
        let entries = [
            ("file", spec.file.display().to_string()),
            ("topic", maker.topic.clone()),
            ("rows", scan.rows.to_string()),
            ("rate_hz", (1.0 / scan.period_s).to_string()),
            ("rate_from", scan.rate_from.clone()),
            ("sample_period_ns", period_ns.to_string()),
            ("first_time_s", scan.first_time_s.to_string()),
            ("columns", scan.header.mapping(spec.kind)),
            ("ignored_columns", scan.header.ignored().join(", ")),
            ("block_samples", spec.block_samples.to_string()),
            ("blocks", maker.seq.to_string()),
            ("gaps", scan.gaps.to_string()),
            ("missing_samples", scan.missing_samples.to_string()),
            ("max_time_residual_s", format!("{:e}", maker.max_residual_s)),
        ];
        for (k, v) in entries {
            meta.insert(format!("{s}.{k}"), v);
        }
        let names = spec.kind.columns();
        streams.push(StreamReport {
            stream: spec.kind,
            topic: maker.topic.clone(),
            message_type: spec.kind.stream().kind().name().to_string(),
            file: spec.file.display().to_string(),
            file_bytes: scan.bytes,
            rows: scan.rows,
            columns: names
                .iter()
                .zip(scan.header.columns)
                .map(|(n, c)| (n.to_string(), c + 1))
                .collect(),
            ignored_columns: scan.header.ignored(),
            rate_hz: 1.0 / scan.period_s,
            rate_from: scan.rate_from.clone(),
            sample_period_ns: period_ns,
            first_time_s: scan.first_time_s,
            last_time_s: scan.last_time_s,
            samples_spanned: scan.last_index + 1,
            block_samples: spec.block_samples,
            blocks: maker.seq,
            gaps: scan.gaps,
            missing_samples: scan.missing_samples,
            max_time_residual_s: maker.max_residual_s,
            source_id: plan.source_id,
        });
    }
    if let Some((rig, _)) = &reference {
        extras.metadata(
            RIG_METADATA,
            rig_metadata(plan, rig, &scans, readings_without_reference),
        );
    }
    extras.metadata(IMPORT_METADATA, meta);
    extras.write_to(&rec)?;
    let summary = rec.finish().map_err(Error::FinishLog)?;
    part.commit(&plan.out, plan.force)?;
    let elapsed_s = started.elapsed().as_secs_f64();
    let rows: u64 = streams.iter().map(|s| s.rows).sum();
    Ok(ImportReport {
        out: plan.out.display().to_string(),
        messages: summary.messages,
        chunks: summary.chunks,
        bytes: summary.bytes,
        elapsed_s,
        rows_per_s: rows as f64 / elapsed_s.max(1e-9),
        reference: reference.as_ref().map(|(rig, _)| ReferenceReport {
            topic: truth_topic.clone(),
            rig: rig.file.clone(),
            kind: rig.reference.kind().to_string(),
            file: plan.reference.as_ref().map(|p| p.display().to_string()),
            readings: streams
                .iter()
                .filter(|s| s.stream == ImportKind::Accel)
                .map(|s| s.rows)
                .sum(),
            readings_without_reference,
        }),
        streams,
    })
}

/// Largest relative difference between the rate a rig file states (`sensors.rate_hz`)
/// and a vibration CSV's rate: a CSV's time column printed to the microsecond over a
/// second measures the rate to 1e-6.
const RIG_RATE_TOLERANCE: f64 = 1e-6;

/// The vibration CSV's rate against the rate the rig file states, if it states one: a
/// problem naming both files, the key, both rates and the rule when they disagree.
fn rate_against_rig(
    plan: &ImportPlan,
    rig: &vibro_config::RigConfig,
    scans: &[super::scan::Scan],
) -> Option<String> {
    let rig_hz = rig.sensors.rate_hz?;
    let (spec, scan) = plan
        .streams
        .iter()
        .zip(scans)
        .find(|(spec, _)| spec.kind == ImportKind::Vib)?;
    let csv_hz = 1.0 / scan.period_s;
    ((csv_hz - rig_hz).abs() > RIG_RATE_TOLERANCE * rig_hz).then(|| {
        format!(
            "{}: sensors.rate_hz = {rig_hz}, but the vibration CSV {} is at {csv_hz} Hz ({}): \
             the CSV must be at the rig's sensor rate (within {RIG_RATE_TOLERANCE:e} relative)",
            rig.file,
            spec.file.display(),
            scan.rate_from
        )
    })
}

/// The log's `rig` metadata: the rig file, its reference, and the sensor settings the
/// lab's estimator takes from a log (`sensor_hz`, `sensor_sensitivity_v_per_g` per
/// sensor, `sensor_ac_corner_hz`, `sensor_delay_s` when the rig file states it; the keys of a simulated log's
/// `scenario`, plus the chain's delay: a sample stamped `s` saw the base at
/// `s - sensor_delay_s`).
fn rig_metadata(
    plan: &ImportPlan,
    rig: &vibro_config::RigConfig,
    scans: &[super::scan::Scan],
    readings_without_reference: u64,
) -> BTreeMap<String, String> {
    let mut m = BTreeMap::from([
        ("file".to_string(), rig.file.clone()),
        ("triad".to_string(), rig.triad.id.clone()),
        (
            "reference_kind".to_string(),
            rig.reference.kind().to_string(),
        ),
        (
            "readings_without_reference".to_string(),
            readings_without_reference.to_string(),
        ),
        (
            "sensor_ac_corner_hz".to_string(),
            rig.sensors.ac_corner_hz.unwrap_or(0.0).to_string(),
        ),
    ]);
    // Only a delay the rig file states: absent, the lab on the waveform fits it.
    if rig.sensors.delay_stated {
        m.insert("sensor_delay_s".into(), rig.sensors.delay_s.to_string());
    }
    if let Some(r) = &plan.reference {
        m.insert("reference_file".into(), r.display().to_string());
    }
    let s = rig.sensors.sensitivity_v_per_g;
    for (u, v) in s.iter().enumerate() {
        m.insert(
            format!("sensor{}_sensitivity_v_per_g", u + 1),
            v.to_string(),
        );
    }
    if s.iter().all(|v| *v == s[0]) {
        m.insert("sensor_sensitivity_v_per_g".into(), s[0].to_string());
    }
    if let Some((_, scan)) = plan
        .streams
        .iter()
        .zip(scans)
        .find(|(spec, _)| spec.kind == ImportKind::Vib)
    {
        m.insert("sensor_hz".into(), (1.0 / scan.period_s).to_string());
    }
    m
}

/// Writes one block, waiting for room in the recorder's queue (an import must lose
/// nothing).
fn write_block(rec: &Recorder, topic: &str, msg: RigMessage<'_>) -> Result<()> {
    let t = msg.time_ns();
    loop {
        let result = match msg {
            RigMessage::Vib(b) => rec.write(topic, t, b.publish_ns, b.seq as u32, b),
            RigMessage::Accel(b) => rec.write(topic, t, b.publish_ns, b.seq as u32, b),
            RigMessage::Truth(b) => rec.write(topic, t, b.publish_ns, b.seq as u32, b),
        };
        match result {
            Err(vibro_mcap::Error::QueueFull { .. }) => {
                std::thread::sleep(Duration::from_micros(200))
            }
            other => {
                return other.map_err(|source| Error::WriteLog {
                    topic: topic.to_string(),
                    source,
                })
            }
        }
    }
}

/// The blocks that an import makes of one CSV file, without writing a log: the first
/// pass (every row validated, the rate measured, the gaps found), then the second
/// (rows cut into blocks of `block_samples`, each row checked against the time grid),
/// each complete block handed to `each`. Returns the number of blocks. The options are
/// those of [`super::ImportOptions`] (`rate_hz` for `--*-rate-hz`, `tolerance` for
/// `--period-tolerance`) and are checked as it checks them; problems in the file are
/// one error listing them all ([`Error::CsvBlocks`]). The import's parsing core, public
/// for the fuzz targets (`fuzz/`).
pub fn read_csv_blocks(
    kind: ImportKind,
    file: &Path,
    rate_hz: Option<f64>,
    block_samples: usize,
    tolerance: f64,
    mut each: impl FnMut(RigMessage<'_>),
) -> Result<u64> {
    if let Some(r) = rate_hz {
        if !(r.is_finite() && r > 0.0 && r <= 1e9) {
            return Err(Error::Option {
                name: kind.rate_flag(),
                value: r.to_string(),
                rule: "must be finite, > 0 and at most 1e9 Hz".into(),
            });
        }
    }
    if !(1..=kind.max_block()).contains(&block_samples) {
        return Err(Error::Option {
            name: "block samples",
            value: block_samples.to_string(),
            rule: format!(
                "must be 1..={} (the wire type's capacity)",
                kind.max_block()
            )
            .into(),
        });
    }
    if !(tolerance.is_finite() && tolerance > 0.0 && tolerance < 0.5) {
        return Err(Error::Option {
            name: "--period-tolerance",
            value: tolerance.to_string(),
            rule: "must be > 0 and < 0.5 (of a period)".into(),
        });
    }
    let spec = StreamSpec {
        kind,
        file: file.to_path_buf(),
        rate_hz,
        block_samples,
    };
    let scan = match scan(&spec, tolerance, &mut Tracker::new(&mut ()))? {
        Ok(scan) => scan,
        Err(mut p) => {
            return Err(Error::CsvBlocks {
                problems: p.lines(),
            })
        }
    };
    let mut maker = BlockMaker::new(&spec, &scan, tolerance, 1)?;
    while maker.fill()? {
        each(maker.block.message());
    }
    maker.report_off_grid();
    if !maker.problems.is_empty() {
        return Err(Error::CsvBlocks {
            problems: maker.problems.lines(),
        });
    }
    Ok(maker.seq)
}
