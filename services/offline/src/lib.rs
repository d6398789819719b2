//! # vibro-offline
//!
//! One log through the estimator's and the compensator's cores in-process, with no
//! shared memory and no service: what a lock-stepped replay through the services
//! (`vibrocomp up --record S.mcap`, then `vibrocomp replay LOG`, lock-stepped by default)
//! records, written as the same kind of session log (`vibrocomp log compensate`).
//!
//! - [`Setup::derive`]: the services' configurations as `vibrocomp up` derives them
//!   (the configuration files or their default rule, a rig file's sensor chain, an
//!   extended model: `vibro_system::derived`).
//! - [`compensate_log`]: the log into a session log (the input streams, `/estimate`,
//!   `/compensated`, the view channels, the configurations and passports), which
//!   `vibrocomp log errors` measures as it measures a recording.
//! - [`compensate_blocks`]: the same without a file, the compensated blocks in order.
//!
//! **Lock-step.** The log's rig streams in log order, as a replay publishes them: each
//! `/vib` block goes to the estimator's core (`vibro_estimator::InProcess`, the code the
//! estimator service runs: numbering, flags, continuity), every estimate it completes
//! to the compensator's core (`vibro_compensator::InProcess::on_estimate`) *before*
//! the compensator takes that block's samples (`on_vib`, the waveform stage); each
//! `/accel` block goes to `on_accel`, and at the end `finish`. A lock-stepped replay
//! guarantees the services the same order: the compensator has every estimate of the
//! vibration blocks before an accelerometer block when it takes that block
//! (`vibro_log::replay`, docs/messages.md "progress").
//!
//! **No wall clock.** Every receive time is [`RECV_NS`] (0). The compensator's only
//! wall-clock rule, the waveform stage's silence (`vibro_compensator::waveform::
//! SILENCE_NS`: held blocks wait no longer once the sensors' stream has been silent
//! for 1 s), then never fires while data flows, as in a lock-stepped replay, whose
//! pauses are far shorter; at the end [`vibro_compensator::InProcess::finish`]
//! decides the held blocks as the services do once the replay has stopped (a replay
//! sends no end-of-stream block: the services' silence rule decides them the same
//! way). The session's log time is the data time as the recorder places it
//! (`vibro_log::Timeline`), its publish time the same data time, and its attachments
//! are stamped 0: the same log gives the same file, byte for byte.
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! use std::path::Path;
//! let setup = vibro_offline::Setup::derive(None, None, None, None)?;
//! let options = vibro_offline::OutputOptions::default();
//! let summary = vibro_offline::compensate_log(
//!     Path::new("flight.mcap"),
//!     &setup,
//!     Path::new("session.mcap"),
//!     &options,
//!     &|| None,
//!     &mut |_done, _total| {},
//! )?;
//! println!("{} blocks, {:.0}x real time", summary.compensated_blocks, summary.real_time_factor);
//! # Ok(())
//! # }
//! ```
//!
//! References: docs/logs.md (`log compensate`, "Time"), docs/services.md (streams,
//! flags), `vibro_log::record` (what a recording holds).

mod copy;
mod session;

use anyhow::Context;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;
use vibro_log::{rig_streams, stream_of_topic, topic};
use vibro_mcap::{Message, Reader, Record};
use vibro_msgs::compensation_flags as cf;
use vibro_msgs::{CompensatedBlock, Stream, VibBlock, VibEstimate};
use vibro_service::ServiceConfig;

pub use session::OutputOptions;

/// The receive time every message is given: no wall clock in an offline run.
pub const RECV_NS: u64 = 0;

/// Messages between two calls of the progress callback.
const PROGRESS_EVERY: u64 = 1024;

/// Messages between two looks at the stop signal.
const STOP_EVERY: u64 = 64;

/// The services' configurations as `vibrocomp up` derives them, loaded and checked.
#[derive(Debug)]
pub struct Setup {
    pub estimator: vibro_estimator::Config,
    pub compensator: vibro_compensator::Config,
    /// Where each came from: a file, `config/services/x.toml (shipped)`, with `--rig`
    /// and `--model` named when they were put in.
    pub estimator_source: String,
    pub compensator_source: String,
    /// Their text, attached to the session as `vibrocomp record` attaches them (with a
    /// rig, the derived text: the sensors' chain `log errors` reads).
    pub estimator_text: Vec<u8>,
    pub compensator_text: Vec<u8>,
    pub rig: Option<PathBuf>,
    pub model: Option<PathBuf>,
}

impl Setup {
    /// The configurations `vibrocomp up` gives the services: `estimator_config` and
    /// `compensator_config` (`None`: `config/services/*.toml` in the working directory
    /// if present, else the shipped copy, the services' own rule), with the sensor
    /// chain of the rig file `rig` and the extended model `model` put in
    /// (`vibro_system::derived::derive`, every input checked first, each problem named).
    pub fn derive(
        estimator_config: Option<&Path>,
        compensator_config: Option<&Path>,
        rig: Option<&Path>,
        model: Option<&Path>,
    ) -> anyhow::Result<Setup> {
        let derived =
            vibro_system::derived::derive(estimator_config, compensator_config, rig, model)?;
        let derived_estimator = derived.as_ref().and_then(|d| d.estimator());
        let derived_compensator = derived.as_ref().and_then(|d| d.compensator());
        let (estimator, estimator_text) =
            load::<vibro_estimator::Config>(derived_estimator.or(estimator_config))?;
        let (compensator, compensator_text) =
            load::<vibro_compensator::Config>(derived_compensator.or(compensator_config))?;
        let mut estimator_source = source_name::<vibro_estimator::Config>(estimator_config);
        let mut compensator_source = source_name::<vibro_compensator::Config>(compensator_config);
        // The derived files are temporary (removed below): the sources name their inputs.
        if derived_estimator.is_some() {
            if let Some(r) = rig {
                estimator_source = format!("{estimator_source} with --rig {}", r.display());
            }
        }
        if derived_compensator.is_some() {
            let given = [("--rig", rig), ("--model", model)];
            for (flag, p) in given.iter().filter_map(|(f, p)| Some((f, (*p)?))) {
                compensator_source = format!("{compensator_source} with {flag} {}", p.display());
            }
        }
        drop(derived);
        Ok(Setup {
            estimator,
            compensator,
            estimator_source,
            compensator_source,
            estimator_text,
            compensator_text,
            rig: rig.map(Path::to_path_buf),
            model: model.map(Path::to_path_buf),
        })
    }
}

/// A service's configuration from `file` (else the services' default rule: the file
/// in the working directory if present, else the shipped copy), and its text.
fn load<C: ServiceConfig>(file: Option<&Path>) -> anyhow::Result<(C, Vec<u8>)> {
    let default = Path::new(C::DEFAULT_CONFIG_PATH);
    match file.or_else(|| default.is_file().then_some(default)) {
        Some(p) => Ok((
            C::load(p)?,
            vibro_service::read_config_file(p)?.into_bytes(),
        )),
        None => Ok((C::shipped()?, C::shipped_text().as_bytes().to_vec())),
    }
}

/// Where a service's configuration comes from, by the same rule: the file given, the
/// default file, or `... (shipped)`.
fn source_name<C: ServiceConfig>(given: Option<&Path>) -> String {
    let default = Path::new(C::DEFAULT_CONFIG_PATH);
    match given {
        Some(p) => p.display().to_string(),
        None if default.is_file() => C::DEFAULT_CONFIG_PATH.to_string(),
        None => format!("{} (shipped)", C::DEFAULT_CONFIG_PATH),
    }
}

/// What an offline run did.
#[derive(Debug, Clone, Serialize)]
pub struct OfflineSummary {
    pub log: PathBuf,
    /// The session written (`None`: [`compensate_blocks`]).
    pub out: Option<PathBuf>,
    /// Messages taken from the log per rig topic (`/vib`, `/accel`, `/truth`).
    pub messages_in: BTreeMap<String, u64>,
    /// Channels of the log not taken (the services' outputs of a recorded session, a
    /// foreign topic), each with its count.
    pub skipped: BTreeMap<String, u64>,
    /// Messages written per topic, the view channels included (empty without a file).
    pub messages_out: BTreeMap<String, u64>,
    /// Estimates the estimator's core completed.
    pub estimates: u64,
    /// Compensated blocks.
    pub compensated_blocks: u64,
    /// Of those, made by the waveform stage (`WAVEFORM`) and answered by the estimate
    /// stage instead (`WAVEFORM_FALLBACK`).
    pub waveform_blocks: u64,
    pub fallback_blocks: u64,
    /// Messages whose data time was off the session's timeline (`vibro_log::Timeline`).
    pub off_timeline: u64,
    /// The data's span, first sample to the end of the last block (`/vib`, `/accel`).
    pub flight_s: f64,
    /// Wall-clock time of the run.
    pub wall_s: f64,
    /// `flight_s / wall_s`.
    pub real_time_factor: f64,
    /// Bytes of the session written (0 without a file).
    pub bytes: u64,
    /// The log's chunks copied into the session as they are (`OutputOptions::copy_chunks`).
    pub copied_chunks: u64,
    /// The configurations used.
    pub estimator_config: String,
    pub compensator_config: String,
    /// The cores' counters, as the services' `--json` summaries give them (latency and
    /// uptime mean nothing offline).
    pub estimator: serde_json::Value,
    pub compensator: serde_json::Value,
}

impl OfflineSummary {
    /// The summary as a few lines of text (`vibrocomp log compensate` without `--json`).
    pub fn write_text(&self, out: &mut impl std::fmt::Write) -> std::fmt::Result {
        let shown = self.out.as_deref().unwrap_or(&self.log).display();
        writeln!(
            out,
            "Compensated {} into {shown} ({} bytes)",
            self.log.display(),
            self.bytes
        )?;
        writeln!(
            out,
            "  {:.1} s of data in {:.2} s ({:.0}x real time): {} estimates, {} compensated \
             blocks ({} by the waveform stage, {} by the estimate stage instead)",
            self.flight_s,
            self.wall_s,
            self.real_time_factor,
            self.estimates,
            self.compensated_blocks,
            self.waveform_blocks,
            self.fallback_blocks
        )?;
        if self.copied_chunks > 0 {
            writeln!(
                out,
                "  {} of the log's chunks copied as they are",
                self.copied_chunks
            )?;
        }
        writeln!(
            out,
            "  estimator: {}; compensator: {}",
            self.estimator_config, self.compensator_config
        )?;
        writeln!(out, "  measure it: vibrocomp log errors {shown}")
    }
}

/// Where the cores' outputs go, in the order a lock-stepped replay's recorder would
/// see them: each input, then what it made.
pub(crate) trait Outputs {
    /// An input taken from the log: `record`, the last one `reader` yielded.
    fn input(&mut self, stream: Stream, record: &Record, reader: &mut Reader)
        -> anyhow::Result<()>;
    fn estimate(&mut self, estimate: &VibEstimate) -> anyhow::Result<()>;
    fn compensated(&mut self, block: &CompensatedBlock) -> anyhow::Result<()>;
    /// The log is read and the cores have given all they will.
    fn end_of_input(&mut self, _reader: &mut Reader) -> anyhow::Result<()> {
        Ok(())
    }
    /// Whether `reader` should keep what each chunk held, for copying chunks.
    fn copies_chunks(&self) -> bool {
        false
    }
}

/// The two cores in lock-step, and their output buffers (reused, never per block).
struct Cores {
    estimator: vibro_estimator::InProcess,
    compensator: vibro_compensator::InProcess,
    estimates: Vec<VibEstimate>,
    blocks: Vec<CompensatedBlock>,
    estimates_made: u64,
    waveform_blocks: u64,
    fallback_blocks: u64,
    compensated_blocks: u64,
}

impl Cores {
    fn new(setup: &Setup) -> anyhow::Result<Self> {
        Ok(Self {
            estimator: vibro_estimator::InProcess::new(&setup.estimator.estimator)?,
            compensator: vibro_compensator::InProcess::new(&setup.compensator)?,
            estimates: Vec::with_capacity(4),
            blocks: Vec::with_capacity(vibro_compensator::waveform::MAX_PENDING + 2),
            estimates_made: 0,
            waveform_blocks: 0,
            fallback_blocks: 0,
            compensated_blocks: 0,
        })
    }

    fn vib(&mut self, b: &VibBlock, out: &mut dyn Outputs) -> anyhow::Result<()> {
        self.estimates.clear();
        self.estimator
            .on_block(b, RECV_NS, &mut self.estimates)
            .context("the estimator's core")?;
        for e in &self.estimates {
            self.estimates_made += 1;
            out.estimate(e)?;
            self.compensator.on_estimate(e);
        }
        self.compensator.on_vib(b, RECV_NS, &mut self.blocks);
        self.flush(out)
    }

    /// Hands the compensated blocks made so far to `out`, publish time made
    /// deterministic (the compensator stamps its wall clock).
    fn flush(&mut self, out: &mut dyn Outputs) -> anyhow::Result<()> {
        for b in self.blocks.iter_mut() {
            b.publish_ns = RECV_NS;
            self.compensated_blocks += 1;
            self.waveform_blocks += u64::from(b.flags & cf::WAVEFORM != 0);
            self.fallback_blocks += u64::from(b.flags & cf::WAVEFORM_FALLBACK != 0);
            out.compensated(b)?;
        }
        self.blocks.clear();
        Ok(())
    }
}

/// The log's rig channels, checked as a replay checks them: each carries its stream's
/// wire type; `/accel` is there.
fn open_log(log: &Path) -> anyhow::Result<Reader> {
    vibro_log::inspect::check_mcap_file(log)?;
    let reader = Reader::open(log).with_context(|| {
        format!(
            "reading the log {} (a damaged log: `vibrocomp log recover {} OUT.mcap` keeps its complete chunks)",
            log.display(),
            log.display()
        )
    })?;
    let channels = reader.channels();
    for (t, kind) in &channels {
        if let Some(stream) = stream_of_topic(t).filter(|s| rig_streams().contains(s)) {
            anyhow::ensure!(
                stream.kind() == *kind,
                "{}: topic {t} carries {kind} messages, but the system's {t} carries {}",
                log.display(),
                stream.kind()
            );
        }
    }
    let accel = topic(Stream::Accel);
    anyhow::ensure!(
        channels.iter().any(|(t, _)| *t == accel),
        "{}: no accelerometer readings (/accel, AccelBlock) to compensate (topics: {})",
        log.display(),
        channels
            .iter()
            .map(|(t, _)| t.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(reader)
}

/// Runs the log through the cores into `out`; fills the summary's counts.
fn run(
    log: &Path,
    setup: &Setup,
    out: &mut dyn Outputs,
    stop: &dyn Fn() -> Option<&'static str>,
    progress: &mut dyn FnMut(u64, u64),
) -> anyhow::Result<OfflineSummary> {
    let started = Instant::now();
    let mut reader = open_log(log)?;
    if out.copies_chunks() {
        reader.keep_chunk_facts();
    }
    let total = reader.message_count().unwrap_or(0);
    let mut cores = Cores::new(setup)?;
    let (vib, accel, truth) = (
        topic(Stream::Vib),
        topic(Stream::Accel),
        topic(Stream::Truth),
    );
    let mut messages_in: BTreeMap<String, u64> = BTreeMap::new();
    let mut skipped: BTreeMap<String, u64> = BTreeMap::new();
    let (mut first_ns, mut end_ns) = (u64::MAX, 0u64);
    let mut span = |t0_ns: u64, count: u32, period_ns: u64| {
        if count > 0 {
            first_ns = first_ns.min(t0_ns);
            end_ns = end_ns.max(t0_ns.saturating_add(period_ns.saturating_mul(u64::from(count))));
        }
    };
    let mut done = 0u64;
    while let Some(record) = reader.next() {
        let record = record.with_context(|| {
            format!(
                "{}: damaged after {done} messages (`vibrocomp log recover {} OUT.mcap` keeps its complete chunks)",
                log.display(),
                log.display()
            )
        })?;
        done += 1;
        if done % PROGRESS_EVERY == 0 {
            progress(done, total);
        }
        if done % STOP_EVERY == 0 {
            if let Some(signal) = stop() {
                anyhow::bail!("stopped by {signal} after {done} of {total} messages");
            }
        }
        let on = &*record.topic;
        let taken = match &record.message {
            Message::VibBlock(b) if on == vib => {
                span(b.t0_ns, b.count, b.sample_period_ns);
                out.input(Stream::Vib, &record, &mut reader)?;
                cores.vib(b, out)?;
                true
            }
            Message::AccelBlock(b) if on == accel => {
                span(b.t0_ns, b.count, b.sample_period_ns);
                out.input(Stream::Accel, &record, &mut reader)?;
                cores.compensator.on_accel(b, RECV_NS, &mut cores.blocks);
                cores.flush(out)?;
                true
            }
            Message::TruthBlock(_) if on == truth => {
                out.input(Stream::Truth, &record, &mut reader)?;
                true
            }
            _ => false,
        };
        let counts = if taken {
            &mut messages_in
        } else {
            &mut skipped
        };
        match counts.get_mut(on) {
            Some(n) => *n += 1,
            None => {
                counts.insert(on.to_string(), 1);
            }
        }
    }
    cores.compensator.finish(&mut cores.blocks);
    cores.flush(out)?;
    out.end_of_input(&mut reader)?;
    progress(done, total.max(done));
    let flight_s = end_ns.saturating_sub(first_ns.min(end_ns)) as f64 * 1e-9;
    let wall_s = started.elapsed().as_secs_f64();
    let json = |s: String| serde_json::from_str(&s).unwrap_or(serde_json::Value::String(s));
    Ok(OfflineSummary {
        log: log.to_path_buf(),
        out: None,
        messages_in,
        skipped,
        messages_out: BTreeMap::new(),
        estimates: cores.estimates_made,
        compensated_blocks: cores.compensated_blocks,
        waveform_blocks: cores.waveform_blocks,
        fallback_blocks: cores.fallback_blocks,
        off_timeline: 0,
        flight_s,
        wall_s,
        real_time_factor: flight_s / wall_s.max(1e-9),
        bytes: 0,
        copied_chunks: 0,
        estimator_config: setup.estimator_source.clone(),
        compensator_config: setup.compensator_source.clone(),
        estimator: json(cores.estimator.summary().to_json()),
        compensator: json(cores.compensator.summary().to_json()),
    })
}

/// Collects the compensated blocks only.
struct Blocks(Vec<CompensatedBlock>);

impl Outputs for Blocks {
    fn input(&mut self, _: Stream, _: &Record, _: &mut Reader) -> anyhow::Result<()> {
        Ok(())
    }
    fn estimate(&mut self, _: &VibEstimate) -> anyhow::Result<()> {
        Ok(())
    }
    fn compensated(&mut self, block: &CompensatedBlock) -> anyhow::Result<()> {
        self.0.push(*block);
        Ok(())
    }
}

/// The log `log` through the cores with `setup`: the compensated blocks in order, as
/// the services publish them in a lock-stepped replay (their `publish_ns` 0), and what
/// was done.
pub fn compensate_blocks(
    log: &Path,
    setup: &Setup,
) -> anyhow::Result<(Vec<CompensatedBlock>, OfflineSummary)> {
    let mut blocks = Blocks(Vec::new());
    let summary = run(log, setup, &mut blocks, &|| None, &mut |_, _| {})?;
    Ok((blocks.0, summary))
}

/// The log `log` through the cores with `setup` into the session log `out`: what
/// `vibrocomp record` writes during a lock-stepped replay of `log` through services
/// started as `vibrocomp up` starts them, without heartbeats and log lines (no service
/// ran). `out` follows the file rule (`vibro_files`: never through a link, never into
/// a FIFO or device, never the log itself, an existing file only with
/// `options.force`) and appears only when complete. `progress(messages done, messages
/// in the log)` is called now and then, `stop` more often: a signal's name stops the
/// run there, and nothing is written.
pub fn compensate_log(
    log: &Path,
    setup: &Setup,
    out: &Path,
    options: &OutputOptions,
    stop: &dyn Fn() -> Option<&'static str>,
    progress: &mut dyn FnMut(u64, u64),
) -> anyhow::Result<OfflineSummary> {
    let started = Instant::now();
    vibro_files::check_output(out, &[log], options.force)?;
    // The input is refused before an output is made.
    drop(open_log(log)?);
    let (mut summary, written) = vibro_files::write_with(out, options.force, |part| {
        let mut writer = session::SessionWriter::create(part.path(), log, setup, options)
            .with_context(|| format!("writing the session {}", out.display()))?;
        let summary = run(log, setup, &mut writer, stop, progress)?;
        let written = writer
            .finish()
            .with_context(|| format!("writing the session {}", out.display()))?;
        anyhow::Ok((summary, written))
    })?;
    summary.out = Some(out.to_path_buf());
    summary.messages_out = written.messages;
    summary.off_timeline = written.off_timeline;
    summary.bytes = written.bytes;
    summary.copied_chunks = written.copied_chunks;
    summary.wall_s = started.elapsed().as_secs_f64();
    summary.real_time_factor = summary.flight_s / summary.wall_s.max(1e-9);
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vibro_log::flight::{simulate_flight, FlightOutput};

    /// The demo's flight, `seconds` long, into `dir/flight.mcap`.
    fn flight(dir: &Path, seconds: f64) -> PathBuf {
        let mut scenario = vibro_sim::resolve_scenario("cyclone-4-short").unwrap();
        match &mut scenario.kind {
            vibro_sim::ScenarioKind::Flight(f) => f.duration_s = seconds,
            _ => panic!("cyclone-4-short is a flight"),
        }
        let out = dir.join("flight.mcap");
        let output = FlightOutput {
            out: Some(&out),
            live: None,
            force: false,
        };
        simulate_flight(&scenario, output, &|| None, &mut |_, _| {}).unwrap();
        out
    }

    /// Every record of `path` (view channels too) in the reader's order: topic,
    /// sequence, log and publish time, protobuf bytes.
    fn all_records(path: &Path) -> Records {
        let mut reader = Reader::open(path).unwrap();
        let topics: Vec<String> = reader.topics().into_iter().map(|(t, _)| t).collect();
        let topics: Vec<&str> = topics.iter().map(String::as_str).collect();
        reader.select_topics(&topics).unwrap();
        let mut out = Vec::new();
        while let Some(r) = reader.next_raw() {
            let r = r.unwrap();
            out.push((
                r.topic.to_string(),
                r.sequence,
                r.log_time_ns,
                r.publish_time_ns,
                r.data,
            ));
        }
        out
    }

    /// The chunks of `log` that hold messages, by its chunk index (`mcap`'s reader).
    fn chunks_with_messages(log: &Path) -> u64 {
        mcap::Summary::read(&std::fs::read(log).unwrap())
            .unwrap()
            .unwrap()
            .chunk_indexes
            .iter()
            .filter(|c| !c.message_index_offsets.is_empty())
            .count() as u64
    }

    /// The records of each topic, in order.
    type Records = Vec<(String, u32, u64, u64, Vec<u8>)>;
    fn by_topic(records: &Records) -> BTreeMap<String, Records> {
        let mut out: BTreeMap<String, Records> = BTreeMap::new();
        for r in records {
            out.entry(r.0.clone()).or_default().push(r.clone());
        }
        out
    }

    /// Copying the log's chunks as they are changes the chunking, not the messages:
    /// the session reads back record for record on every channel (view channels too)
    /// as one written record by record. A log whose records the session would not
    /// write as they are (publish time after the data time, as a recorder's receive
    /// time is) has none of its chunks copied, and gives the same session too.
    #[test]
    fn copied_chunks_hold_the_same_records_as_a_session_written_record_by_record() {
        let dir = tempfile::TempDir::new().unwrap();
        let log = flight(dir.path(), 4.0);
        let setup = Setup::derive(None, None, None, None).unwrap();
        let plain_options = OutputOptions {
            copy_chunks: false,
            ..OutputOptions::default()
        };
        let (copied, plain) = (
            dir.path().join("copied.mcap"),
            dir.path().join("plain.mcap"),
        );
        let run = |log: &Path, out: &Path, options: &OutputOptions| {
            compensate_log(log, &setup, out, options, &|| None, &mut |_, _| {}).unwrap()
        };
        let with_copies = run(&log, &copied, &OutputOptions::default());
        let without = run(&log, &plain, &plain_options);
        let log_chunks = chunks_with_messages(&log);
        assert!(log_chunks >= 2, "{log_chunks}");
        assert_eq!(with_copies.copied_chunks, log_chunks);
        assert_eq!(without.copied_chunks, 0);
        assert_eq!(with_copies.messages_out, without.messages_out);
        let (a, b) = (all_records(&copied), all_records(&plain));
        assert_eq!(a.len(), b.len());
        assert!(a.len() > 500, "{}", a.len());
        assert_eq!(by_topic(&a), by_topic(&b));
        // Both in log-time order; only records of different channels at the same log
        // time may come in another order (MCAP leaves it open).
        for records in [&a, &b] {
            assert!(records.windows(2).all(|w| w[0].2 <= w[1].2));
        }
        // The same log with every publish time 1 ns after its data time.
        let late = dir.path().join("late.mcap");
        {
            let mut reader = Reader::open(&log).unwrap();
            let mut recorder = vibro_mcap::Recorder::create(
                &late,
                vibro_mcap::RecorderOptions {
                    writer_thread: false,
                    ..Default::default()
                },
            )
            .unwrap();
            // The session's channel IDs: only the publish times differ.
            let mut channels = std::collections::HashMap::new();
            for s in [Stream::Vib, Stream::Accel, Stream::Truth] {
                let id = recorder.add_channel(&topic(s), s.kind()).unwrap();
                channels.insert(topic(s), id);
            }
            for r in reader.by_ref() {
                let r = r.unwrap();
                let mut data = Vec::new();
                r.message.encode(&mut data).unwrap();
                let channel = &channels[&*r.topic];
                recorder
                    .write_encoded(channel, r.log_time_ns, r.log_time_ns + 1, r.sequence, &data)
                    .unwrap();
            }
            recorder.finish().unwrap();
        }
        let late_session = dir.path().join("late-session.mcap");
        let from_late = run(&late, &late_session, &OutputOptions::default());
        assert_eq!(from_late.copied_chunks, 0);
        assert!(
            by_topic(&all_records(&late_session)) == by_topic(&b),
            "a late log gives the same session"
        );
    }

    /// A chunk of the log that is taken only at the end (it holds the last `/truth`
    /// block, written first) keeps what follows it held: within the bound every chunk
    /// is still copied; beyond it the undecided ones are written record by record.
    /// The session is the same either way.
    #[test]
    fn a_chunk_taken_at_the_end_is_held_within_the_bound_and_written_beyond_it() {
        let dir = tempfile::TempDir::new().unwrap();
        let flight_log = flight(dir.path(), 4.0);
        let mut records: Vec<Record> = Reader::open(&flight_log)
            .unwrap()
            .map(|r| r.unwrap())
            .collect();
        let last_truth = records.iter().rposition(|r| &*r.topic == "/truth").unwrap();
        let late = records.remove(last_truth);
        records.insert(0, late);
        let log = dir.path().join("late-truth-first.mcap");
        {
            let options = vibro_mcap::RecorderOptions {
                chunk_size_bytes: 64 * 1024,
                writer_thread: false,
                ..Default::default()
            };
            let mut rec = vibro_mcap::Recorder::create(&log, options).unwrap();
            let mut channels = std::collections::HashMap::new();
            for s in [Stream::Vib, Stream::Accel, Stream::Truth] {
                channels.insert(topic(s), rec.add_channel(&topic(s), s.kind()).unwrap());
            }
            // Closes the chunk holding the channels: the next ones hold messages only.
            rec.add_attachment_at("note.txt", "text/plain", b"x".to_vec(), 0)
                .unwrap();
            for r in &records {
                rec.write_to(
                    &channels[&*r.topic],
                    r.log_time_ns,
                    r.publish_time_ns,
                    r.sequence,
                    r.message,
                )
                .unwrap();
            }
            rec.finish().unwrap();
        }
        let setup = Setup::derive(None, None, None, None).unwrap();
        let run = |out: &str, copy_chunks: bool| {
            let out = dir.path().join(out);
            let options = OutputOptions {
                copy_chunks,
                ..OutputOptions::default()
            };
            let s = compensate_log(&log, &setup, &out, &options, &|| None, &mut |_, _| {}).unwrap();
            (s.copied_chunks, by_topic(&all_records(&out)))
        };
        let (_, plain) = run("plain.mcap", false);
        let (copied, held) = run("held.mcap", true);
        let with_messages = chunks_with_messages(&log);
        assert!(with_messages > 10, "{with_messages}");
        assert_eq!(copied, with_messages);
        copy::HELD_LIMIT.with(|l| l.set(256 * 1024));
        let (copied_bounded, bounded) = run("bounded.mcap", true);
        copy::HELD_LIMIT.with(|l| l.set(copy::MAX_HELD_BYTES));
        assert!(
            copied_bounded < with_messages,
            "{copied_bounded} of {with_messages}"
        );
        assert!(
            held == plain,
            "held: not the session written record by record"
        );
        assert!(
            bounded == plain,
            "bounded: not the session written record by record"
        );
    }

    /// The session holds the blocks `compensate_blocks` gives, is the same file on a
    /// second run, and `log errors` measures it.
    #[test]
    fn the_session_holds_the_blocks_and_is_deterministic() {
        let dir = tempfile::TempDir::new().unwrap();
        let log = flight(dir.path(), 3.0);
        let setup = Setup::derive(None, None, None, None).unwrap();
        let (blocks, summary) = compensate_blocks(&log, &setup).unwrap();
        // 3 s at 800 Hz in blocks of 32; 5 windows of 1 s sliding by 0.5 s.
        assert_eq!((blocks.len(), summary.estimates), (75, 5), "{summary:?}");
        assert!(summary.waveform_blocks > 60, "{summary:?}");
        let out = dir.path().join("session.mcap");
        let options = OutputOptions::default();
        let written =
            compensate_log(&log, &setup, &out, &options, &|| None, &mut |_, _| {}).unwrap();
        assert_eq!(written.messages_out["/compensated"], 75);
        assert_eq!(written.messages_out["/view/AK2"], 75);
        let recorded: Vec<CompensatedBlock> = Reader::open(&out)
            .unwrap()
            .filter_map(|r| match r.unwrap().message {
                Message::CompensatedBlock(b) => Some(b),
                _ => None,
            })
            .collect();
        assert_eq!(recorded.len(), blocks.len());
        for (a, b) in recorded.iter().zip(&blocks) {
            assert_eq!(format!("{a:?}"), format!("{b:?}"));
        }
        let again = dir.path().join("again.mcap");
        compensate_log(&log, &setup, &again, &options, &|| None, &mut |_, _| {}).unwrap();
        assert!(std::fs::read(&out).unwrap() == std::fs::read(&again).unwrap());
        let triad = vibro_config::default_triad().unwrap();
        let errors = vibro_log::session::log_errors(&out, 0.5, &triad).unwrap();
        assert_eq!(errors.passports.len(), 3);
        // An existing output needs `force`; the log itself is never the output.
        let e = compensate_log(&log, &setup, &out, &options, &|| None, &mut |_, _| {}).unwrap_err();
        assert!(format!("{e:#}").contains("--force"), "{e:#}");
        let forced = OutputOptions {
            force: true,
            ..OutputOptions::default()
        };
        let e = compensate_log(&log, &setup, &log, &forced, &|| None, &mut |_, _| {}).unwrap_err();
        assert!(
            format!("{e:#}").contains(&log.display().to_string()),
            "{e:#}"
        );
        // Stopped by a signal: an error, and no session (nor a part file) left.
        let stopped = dir.path().join("stopped.mcap");
        let stop = || Some("SIGINT");
        let e =
            compensate_log(&log, &setup, &stopped, &options, &stop, &mut |_, _| {}).unwrap_err();
        assert!(format!("{e:#}").contains("SIGINT"), "{e:#}");
        let left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .filter(|n| n.contains("stopped"))
            .collect();
        assert!(left.is_empty(), "{left:?}");
    }

    /// `--model` reaches the compensator (as `up --model` gives it), and is named.
    #[test]
    fn an_extended_model_is_put_in_and_named() {
        let dir = tempfile::TempDir::new().unwrap();
        let model = dir.path().join("mount.toml");
        std::fs::write(
            &model,
            "mode = \"exact\"\n[[effect]]\nkind = \"mount_resonance\"\nfreq_hz = 150.0\nq = 2.5\n",
        )
        .unwrap();
        let plain = Setup::derive(None, None, None, None).unwrap();
        let setup = Setup::derive(None, None, None, Some(&model)).unwrap();
        let shown = model.display().to_string();
        assert!(setup
            .compensator_source
            .ends_with(&format!("with --model {shown}")));
        assert_eq!(setup.estimator_source, plain.estimator_source);
        let text = String::from_utf8(setup.compensator_text.clone()).unwrap();
        assert!(text.contains(&shown), "{text}");
        let log = flight(dir.path(), 3.0);
        let (with, _) = compensate_blocks(&log, &setup).unwrap();
        let (without, _) = compensate_blocks(&log, &plain).unwrap();
        let differ = with
            .iter()
            .zip(&without)
            .filter(|(a, b)| a.flags & cf::MODEL_EFFECTS != 0 && b.flags & cf::MODEL_EFFECTS == 0)
            .count();
        assert!(differ > 0, "the model's effects were not applied");
    }

    #[test]
    fn a_missing_rig_file_is_named() {
        let e =
            Setup::derive(None, None, Some(Path::new("/nonexistent/rig.toml")), None).unwrap_err();
        assert!(format!("{e:#}").contains("/nonexistent/rig.toml"), "{e:#}");
    }
}
