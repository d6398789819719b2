//! `vibrocomp sim`: runs a scenario of the rig simulator (`shared/vibro-sim`).
//!
//! - A **flight** streams the vibration sensors, the accelerometers and the truth:
//!   into an MCAP log (`--out`), live over iceoryx2 at real-time rate (`--live`), or
//!   both; it always prints the mean error of each unit against the exact model.
//! - A **campaign** runs every shake-table condition (MODEL.md section 8) and prints
//!   the measured VE beside the exact and published models; `--summary-csv` writes the
//!   per-condition table the model lab reads, `--positions-csv` the test positions
//!   `vibrocomp identify positions` reads.
//!
//! Effects of the scenario can be switched off (`--no-effects`) or on and tuned
//! (`--effect kind:key=value,...`); `--list-effects` prints the library.
//!
//! A flight with `--out` stopped by SIGINT (Ctrl-C) or SIGTERM stops generating between
//! chunks, finishes the log (a valid MCAP holding every message written so far), says
//! on stderr the simulated time it reached and exits with status 1.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI32, Ordering};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use vibro_effects::{catalogue, EffectSpec};
use vibro_log::attachments::{effect_metadata_name, LogExtras, SCENARIO_METADATA};
use vibro_log::rig::{Packetizer, RigChunk, RigMessage, TruthSample};
use vibro_mcap::{Recorder, RecorderOptions};
use vibro_msgs::{ServiceNames, Stream};
use vibro_sim::{Scenario, ScenarioKind, Simulator};

use crate::flags::FlagProblems;
use crate::output::{fmt_g, fmt_num, print_json};

/// Topics of the rig streams in a log: the stream names without the prefix.
pub use vibro_log::topic;

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Scenario: a TOML file or a shipped id (cyclone-4, cyclone-4-short,
    /// tactical-100s, tactical-300s, section8-grid, random-runs, ten-positions,
    /// compensation-experiment-al1m, compensation-experiment-aks05, lab-walkthrough).
    #[arg(required_unless_present = "list_effects")]
    pub scenario: Option<String>,
    /// Replaces the scenario's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Replaces a flight's duration, s.
    #[arg(long = "duration-s")]
    pub duration_s: Option<f64>,
    /// Switches an effect on, with parameters: `kind` or `kind:key=value,key=value`
    /// (values in TOML syntax; `units=[0,2]` limits it to those units). Repeatable.
    #[arg(long = "effect", value_name = "KIND[:KEY=VALUE,...]")]
    pub effects: Vec<String>,
    /// Switches off every effect of the scenario (before `--effect`).
    #[arg(long)]
    pub no_effects: bool,
    /// Flight: writes the rig streams, the truth and the scenario to this MCAP log
    /// (an existing file only with --force; it appears when finished). Stopped by
    /// SIGINT/SIGTERM, the flight ends early with the log finished (valid, holding what
    /// was generated so far) and exit status 1.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Flight: publishes the rig streams over iceoryx2 at real-time rate.
    #[arg(long)]
    pub live: bool,
    /// Service-name prefix of the live streams.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Live speed as a multiple of real time.
    #[arg(long, default_value_t = 1.0)]
    pub rate: f64,
    /// Campaign: writes the per-condition summary table (CSV; an existing file only
    /// with --force).
    #[arg(long = "summary-csv")]
    pub summary_csv: Option<PathBuf>,
    /// Campaign: writes the campaign table of the model lab (docs/lab.md) for
    /// `vibrocomp lab` (an existing file only with --force).
    #[arg(long = "lab-csv")]
    pub lab_csv: Option<PathBuf>,
    /// Campaign: optional floor of the uncertainty written to `--lab-csv`, g. Each
    /// row already states its real standard uncertainty (the VE's batch means and the
    /// vibration sensor's, propagated); 0, the default, adds only
    /// `vibro_sim::campaign::Z_FLOOR_G` (1e-9 g, what a noise-free run is compared at).
    #[arg(long = "ve-resolution-g", default_value_t = 0.0)]
    pub ve_resolution_g: f64,
    /// Campaign: writes the conditions as test positions for `identify positions` (an
    /// existing file only with --force).
    #[arg(long = "positions-csv")]
    pub positions_csv: Option<PathBuf>,
    #[arg(long, help = crate::files::FORCE_HELP)]
    pub force: bool,
    /// Campaign: conditions simulated in parallel (results do not depend on it).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Prints the effects library and exits.
    #[arg(long)]
    pub list_effects: bool,
    /// Print the report (or the effects library) as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &SimArgs) -> anyhow::Result<()> {
    if args.list_effects {
        return list_effects(args.json);
    }
    let Some(arg) = args.scenario.as_deref() else {
        bail!("a scenario is required (a file or a shipped id)");
    };
    let mut scenario =
        vibro_sim::resolve_scenario(arg).with_context(|| format!("scenario {arg}"))?;
    apply_overrides(&mut scenario, args)?;
    // Every output, before anything runs (README, "Files"); the scenario file is an input.
    let scenario_file = Path::new(arg);
    let inputs: Vec<&Path> = if scenario_file.is_file() {
        vec![scenario_file]
    } else {
        Vec::new()
    };
    for out in [
        &args.out,
        &args.summary_csv,
        &args.lab_csv,
        &args.positions_csv,
    ]
    .into_iter()
    .flatten()
    {
        crate::files::check(out, &inputs, args.force)?;
    }
    match &scenario.kind {
        ScenarioKind::Flight(_) => run_flight(&scenario, args),
        ScenarioKind::Campaign(_) => run_campaign(&scenario, args),
    }
}

/// `--seed`, `--duration-s`, `--no-effects`, `--effect`; the numeric flags are checked
/// first, all at once, before anything runs.
fn apply_overrides(scenario: &mut Scenario, args: &SimArgs) -> anyhow::Result<()> {
    let mut problems = FlagProblems::new();
    // The scenario file's own rule on a flight's length.
    if let Some(d) = args.duration_s {
        problems.rule("--duration-s", d, scenario.rates.length_problem(d));
    }
    // A paced replay's rule: a 5e-324 rate would wait for ever before a message.
    problems.rate("--rate", args.rate);
    // Written to `--lab-csv` as the uncertainty's floor: the lab table's rule on an
    // uncertainty's size (0 is floored to `vibro_sim::campaign::Z_FLOOR_G`).
    let max_g = vibro_lab::table::MAX_VE_G;
    problems.check(
        "--ve-resolution-g",
        args.ve_resolution_g,
        args.ve_resolution_g.is_finite() && (0.0..=max_g).contains(&args.ve_resolution_g),
        format_args!(
            "must be finite and 0 <= resolution <= {} g (the lab table's largest uncertainty)",
            fmt_num(max_g)
        ),
    );
    problems.finish()?;
    if let Some(seed) = args.seed {
        scenario.seed = seed;
    }
    if let Some(d) = args.duration_s {
        let ScenarioKind::Flight(flight) = &mut scenario.kind else {
            bail!(
                "--duration-s = {}: applies to flights only; {} is a campaign",
                fmt_num(d),
                scenario.name
            );
        };
        flight.duration_s = d;
    }
    if args.no_effects {
        for e in &mut scenario.effects {
            e.enabled = false;
        }
    }
    for text in &args.effects {
        let spec = parse_effect(text)?;
        match scenario.effects.iter_mut().find(|e| e.kind == spec.kind) {
            // `--effect kind` switches the scenario's own table on; parameters replace it.
            Some(existing) if spec.params.is_empty() && spec.units.is_none() => {
                existing.enabled = true
            }
            Some(existing) => *existing = spec,
            None => scenario.effects.push(spec),
        }
    }
    // Builds every enabled effect once: a bad parameter fails here, named.
    vibro_sim::scenario_effects(scenario).context("effects")?;
    Ok(())
}

/// `kind` or `kind:key=value,key=value` (values in TOML syntax, arrays allowed).
fn parse_effect(text: &str) -> anyhow::Result<EffectSpec> {
    let (kind, rest) = text.split_once(':').unwrap_or((text, ""));
    let kind = kind.trim();
    if !catalogue().iter().any(|e| e.kind == kind) {
        let known: Vec<&str> = catalogue().iter().map(|e| e.kind).collect();
        bail!(
            "--effect {text:?}: unknown kind {kind:?}; known: {}",
            known.join(", ")
        );
    }
    let mut table = toml::Table::new();
    for item in split_params(rest) {
        let Some((key, value)) = item.split_once('=') else {
            bail!("--effect {text:?}: {item:?} is not key=value");
        };
        let parsed: toml::Table = toml::from_str(&format!("{} = {}", key.trim(), value.trim()))
            .with_context(|| format!("--effect {text:?}: {item:?}: the value must be TOML (a number, a string in quotes, an array)"))?;
        table.extend(parsed);
    }
    let mut spec_table = toml::Table::new();
    spec_table.insert("kind".into(), toml::Value::String(kind.to_string()));
    spec_table.extend(table);
    let spec: EffectSpec = spec_table
        .try_into()
        .with_context(|| format!("--effect {text:?}"))?;
    Ok(spec)
}

/// Splits `a=1,b=[1,2],c=3` on the commas outside brackets.
fn split_params(text: &str) -> Vec<&str> {
    let (mut out, mut depth, mut start) = (Vec::new(), 0i32, 0);
    for (i, c) in text.char_indices() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            ',' if depth == 0 => {
                out.push(&text[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&text[start..]);
    out.into_iter()
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect()
}

#[derive(Serialize)]
struct EffectListing<'a> {
    kind: &'a str,
    summary: &'a str,
    hooks: &'a str,
    params: Vec<BTreeMap<&'static str, &'a str>>,
}

fn list_effects(json: bool) -> anyhow::Result<()> {
    let list: Vec<EffectListing> = catalogue()
        .iter()
        .map(|e| EffectListing {
            kind: e.kind,
            summary: e.summary,
            hooks: e.hooks,
            params: e
                .params
                .iter()
                .map(|p| {
                    BTreeMap::from([("name", p.name), ("unit", p.unit), ("meaning", p.meaning)])
                })
                .collect(),
        })
        .collect();
    if json {
        return print_json(&list);
    }
    for e in &list {
        outln!("{:<26} {}", e.kind, e.summary)?;
        for p in &e.params {
            outln!("    {:<24} [{}] {}", p["name"], p["unit"], p["meaning"])?;
        }
    }
    outln!("\nSwitch one on with --effect kind:key=value,...; docs/effects.md has the formulas.")?;
    Ok(())
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(len), crate::output::progress_target());
    if let Ok(style) =
        ProgressStyle::with_template(&format!("{what} {{bar:40}} {{pos}}/{{len}} ({{eta}} left)"))
    {
        bar.set_style(style);
    }
    bar
}

fn effect_labels(scenario: &Scenario) -> Vec<String> {
    scenario
        .effects
        .iter()
        .filter(|e| e.enabled)
        .map(|e| {
            if e.params.is_empty() {
                e.kind.clone()
            } else {
                let params: Vec<String> =
                    e.params.iter().map(|(k, v)| format!("{k}={v}")).collect();
                format!("{}({})", e.kind, params.join(", "))
            }
        })
        .collect()
}

/// Per-unit statistics of a flight.
#[derive(Debug, Serialize)]
pub struct UnitReport {
    pub name: String,
    /// Mean of `U/K1 - a` over the flight, `a` the mean acceleration the unit sensed
    /// over each output interval: the simulated total error (offset, main error, VE
    /// and every effect), g.
    pub mean_error_g: f64,
    /// Mean of `E[aF] - aL3` from the exact model, no effect, g.
    pub exact_mean_error_g: f64,
    /// Mean exact VE, g.
    pub exact_ve_g: f64,
    /// `mean_error_g - exact_mean_error_g`: what the model does not explain (effects,
    /// plus the run's statistical error), g.
    pub unexplained_g: f64,
    /// Standard error of `unexplained_g` from 10 batch means, g.
    pub unexplained_sigma_g: f64,
}

#[derive(Debug, Serialize)]
pub struct FlightReport {
    pub scenario: String,
    pub file: String,
    pub seed: u64,
    pub duration_s: f64,
    pub effects: Vec<String>,
    pub sensor_samples: u64,
    pub output_samples: u64,
    pub vib_blocks: u64,
    pub accel_blocks: u64,
    pub sensor_clipped: [u64; 3],
    pub elapsed_s: f64,
    pub real_time_factor: f64,
    pub out: Option<String>,
    pub live_prefix: Option<String>,
    pub units: Vec<UnitReport>,
}

/// Live publishers of the rig streams.
pub struct Live {
    _node: vibro_ipc::IpcNode,
    vib: vibro_ipc::StreamPublisher<vibro_msgs::VibBlock>,
    accel: vibro_ipc::StreamPublisher<vibro_msgs::AccelBlock>,
    truth: vibro_ipc::StreamPublisher<vibro_msgs::TruthBlock>,
    start: Instant,
    rate: f64,
}

impl Live {
    fn new(prefix: &str, rate: f64) -> anyhow::Result<Self> {
        // Checked with the other flags (`apply_overrides`); kept for other callers.
        let mut problems = FlagProblems::new();
        problems.rate("--rate", rate);
        problems.finish()?;
        let names = ServiceNames::new(prefix).with_context(|| format!("--prefix {prefix:?}"))?;
        let node = vibro_ipc::create_node("vibrocomp-sim").context("iceoryx2 node")?;
        let config = vibro_ipc::StreamConfig::default();
        let open = |s: Stream| (names.stream(s), names.event(s));
        let (vd, ve) = open(Stream::Vib);
        let (ad, ae) = open(Stream::Accel);
        let (td, te) = open(Stream::Truth);
        Ok(Self {
            vib: vibro_ipc::StreamPublisher::create(&node, &vd, &ve, &config)?,
            accel: vibro_ipc::StreamPublisher::create(&node, &ad, &ae, &config)?,
            truth: vibro_ipc::StreamPublisher::create(&node, &td, &te, &config)?,
            _node: node,
            start: Instant::now(),
            rate,
        })
    }

    /// Waits until the message's simulated time, scaled by `rate`, then publishes it
    /// stamped with the publish clock.
    fn publish(&mut self, msg: RigMessage<'_>) -> anyhow::Result<()> {
        let due = Duration::from_nanos((msg.time_ns() as f64 / self.rate) as u64);
        if let Some(wait) = due.checked_sub(self.start.elapsed()) {
            std::thread::sleep(wait);
        }
        let now = vibro_ipc::now_ns();
        match msg {
            RigMessage::Vib(b) => {
                let mut b = *b;
                b.publish_ns = now;
                self.vib.publish(&b)?;
            }
            RigMessage::Accel(b) => {
                let mut b = *b;
                b.publish_ns = now;
                self.accel.publish(&b)?;
            }
            RigMessage::Truth(b) => {
                let mut b = *b;
                b.publish_ns = now;
                self.truth.publish(&b)?;
            }
        }
        Ok(())
    }
}

/// Opens a recorder for a flight log, with the scenario as metadata and the passports
/// and scenario description as attachments.
/// `path` is where it is written (a temporary name), `shown` the log it becomes.
fn open_log(
    path: &Path,
    shown: &Path,
    scenario: &Scenario,
    effects: &[String],
) -> anyhow::Result<Recorder> {
    let mut rec = Recorder::create(path, RecorderOptions::default())
        .with_context(|| format!("{}: cannot create the log", shown.display()))?;
    for s in [Stream::Vib, Stream::Accel, Stream::Truth] {
        rec.add_channel(&topic(s), s.kind())?;
    }
    let rates = scenario.rates;
    let mut meta = BTreeMap::from([
        ("name".to_string(), scenario.name.clone()),
        ("file".to_string(), scenario.file.clone()),
        ("seed".to_string(), scenario.seed.to_string()),
        ("sensor_hz".to_string(), rates.sensor_hz.to_string()),
        ("internal_hz".to_string(), rates.internal_hz.to_string()),
        ("output_hz".to_string(), rates.output_hz.to_string()),
        (
            "sensor_sensitivity_v_per_g".to_string(),
            scenario.sensor.sensitivity_v_per_g.to_string(),
        ),
        (
            "sensor_ac_corner_hz".to_string(),
            scenario.sensor.ac_corner_hz.to_string(),
        ),
        ("effects".to_string(), effects.join("; ")),
    ]);
    let mut extras = LogExtras::generated();
    if let Some(f) = scenario.flight() {
        meta.insert("duration_s".into(), f.duration_s.to_string());
        meta.insert("units".into(), f.triad.names.join(", "));
        for (i, p) in f.triad.passports.iter().enumerate() {
            let text = toml::to_string(&p.to_spec()).context("passport as TOML")?;
            extras.passport(i, p.id(), text);
        }
    }
    extras.metadata(SCENARIO_METADATA, meta);
    for (i, e) in scenario.effects.iter().filter(|e| e.enabled).enumerate() {
        let mut m: BTreeMap<String, String> = e
            .params
            .iter()
            .map(|(k, v)| (k.clone(), v.to_string()))
            .collect();
        m.insert("kind".into(), e.kind.clone());
        if let Some(units) = &e.units {
            m.insert("units".into(), format!("{units:?}"));
        }
        extras.metadata(&effect_metadata_name(i), m);
    }
    // The scenario as written: its file, or the shipped text it was parsed from.
    let text = std::fs::read(&scenario.file).ok().or_else(|| {
        vibro_sim::scenario::EMBEDDED_SCENARIOS
            .iter()
            .find(|(_, file, _)| scenario.file == format!("{file} (embedded)"))
            .map(|(_, _, text)| text.as_bytes().to_vec())
    });
    if let Some(text) = text {
        extras.scenario_text(text);
    }
    extras.write_to(&rec)?;
    Ok(rec)
}

/// Writes one message to the log, waiting for room in the writer's queue (offline
/// generation must lose nothing).
fn write_log(rec: &Recorder, msg: RigMessage<'_>) -> anyhow::Result<()> {
    let t = msg.time_ns();
    loop {
        let result = match msg {
            RigMessage::Vib(b) => rec.write(&topic(Stream::Vib), t, b.publish_ns, b.seq as u32, b),
            RigMessage::Accel(b) => {
                rec.write(&topic(Stream::Accel), t, b.publish_ns, b.seq as u32, b)
            }
            RigMessage::Truth(b) => {
                rec.write(&topic(Stream::Truth), t, b.publish_ns, b.seq as u32, b)
            }
        };
        match result {
            Err(vibro_mcap::Error::QueueFull { .. }) => {
                std::thread::sleep(Duration::from_micros(200))
            }
            other => return other.map_err(Into::into),
        }
    }
}

/// What the rig's truth stream carries of a sample's truth: each unit's IA component.
fn truth_sample(t: &vibro_sim::Truth) -> TruthSample {
    TruthSample {
        a_l_ia_g: [t.a_l_unit_g[0][2], t.a_l_unit_g[1][2], t.a_l_unit_g[2][2]],
        a_sensed_ia_g: [
            t.a_mean_unit_g[0][2],
            t.a_mean_unit_g[1][2],
            t.a_mean_unit_g[2][2],
        ],
        vib_error_ia_g: t.exact_ve_g,
    }
}

fn run_flight(scenario: &Scenario, args: &SimArgs) -> anyhow::Result<()> {
    let live = if args.live {
        Some(Live::new(&args.prefix, args.rate)?)
    } else {
        None
    };
    // Only a flight into a file is worth finishing on a signal; a live-only flight
    // keeps the default action (its publishers are released when the process ends).
    let stop = args.out.as_ref().map(|_| StopSignal::install());
    let result = simulate(
        scenario,
        args.out.as_deref(),
        live,
        stop.as_ref(),
        args.force,
    );
    drop(stop);
    let mut report = result?;
    report.live_prefix = args.live.then(|| args.prefix.clone());
    if args.json {
        return print_json(&report);
    }
    print_flight(&report)?;
    Ok(())
}

/// Runs a flight scenario: into the MCAP log `out` (rig streams, truth, scenario,
/// effects, passports), live (already opened publishers), or both; returns each
/// unit's mean error against the exact model.
pub fn simulate_flight(
    scenario: &Scenario,
    out: Option<&Path>,
    live: Option<Live>,
    force: bool,
) -> anyhow::Result<FlightReport> {
    simulate(scenario, out, live, None, force)
}

/// The signal (SIGINT or SIGTERM) caught while a [`StopSignal`] is installed, or 0.
static CAUGHT_SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_stop_signal(signal: libc::c_int) {
    // Async-signal-safe: one store to an atomic.
    CAUGHT_SIGNAL.store(signal, Ordering::Release);
}

/// SIGINT/SIGTERM handlers that only note the signal, so that a flight into a log
/// stops between chunks and finishes its file; dropping it restores the default
/// action (a second Ctrl-C after the flight ends kills as usual).
pub struct StopSignal(());

impl StopSignal {
    fn install() -> StopSignal {
        CAUGHT_SIGNAL.store(0, Ordering::Release);
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe {
            libc::signal(
                libc::SIGINT,
                on_stop_signal as *const () as libc::sighandler_t,
            );
            libc::signal(
                libc::SIGTERM,
                on_stop_signal as *const () as libc::sighandler_t,
            );
        }
        StopSignal(())
    }

    /// The signal caught so far, if any.
    fn caught(&self) -> Option<&'static str> {
        match CAUGHT_SIGNAL.load(Ordering::Acquire) {
            0 => None,
            libc::SIGINT => Some("SIGINT"),
            libc::SIGTERM => Some("SIGTERM"),
            _ => Some("a signal"),
        }
    }
}

impl Drop for StopSignal {
    fn drop(&mut self) {
        // SAFETY: restores the default actions; no handler state is left behind.
        unsafe {
            libc::signal(libc::SIGINT, libc::SIG_DFL);
            libc::signal(libc::SIGTERM, libc::SIG_DFL);
        }
    }
}

/// [`simulate_flight`], stopping between chunks once `stop` has caught a signal: the
/// log is then finished with what was generated, and the result is an error saying
/// where the flight stopped.
fn simulate(
    scenario: &Scenario,
    out: Option<&Path>,
    mut live: Option<Live>,
    stop: Option<&StopSignal>,
    force: bool,
) -> anyhow::Result<FlightReport> {
    let effects_text = effect_labels(scenario);
    let effects = vibro_sim::scenario_effects(scenario)?;
    let mut sim = Simulator::new(scenario, effects).context("simulator")?;
    let rates = scenario.rates;
    let names: Vec<String> = sim.unit_names().iter().map(|s| s.to_string()).collect();
    let k1_v_per_g: Vec<f64> = scenario
        .flight()
        .map(|f| f.triad.passports.iter().map(|p| p.k1_v_per_g).collect())
        .unwrap_or_default();
    let m: Vec<[f64; 2]> = scenario
        .flight()
        .map(|f| f.triad.passports.iter().map(|p| [p.m1, p.m2]).collect())
        .unwrap_or_default();
    let total = sim.total_samples();
    let mut packetizer = Packetizer::new(rates.sensor_hz, rates.output_hz, 512, 32, 1);
    // Written under a temporary name, renamed to `out` once finished (README, "Files").
    let part = out.map(vibro_log::output::PartFile::beside);
    let recorder = match (&part, out) {
        (Some(part), Some(path)) => Some(open_log(part.path(), path, scenario, &effects_text)?),
        _ => None,
    };
    let bar = progress_bar(total.output, "simulating");
    // Sums per unit, and per batch for the standard error.
    const BATCHES: usize = 10;
    let batch_len = (total.output / BATCHES as u64).max(1);
    let mut sum_err = [0.0f64; 3];
    let mut sum_resid = [[0.0f64; 3]; BATCHES];
    let mut sum_exact = [0.0f64; 3];
    let mut sum_ve = [0.0f64; 3];
    let mut n = 0u64;
    let started = Instant::now();
    let mut emit = |msg: RigMessage<'_>| -> anyhow::Result<()> {
        if let Some(rec) = &recorder {
            write_log(rec, msg)?;
        }
        if let Some(live) = &mut live {
            live.publish(msg)?;
        }
        Ok(())
    };
    let mut interrupted = None;
    loop {
        // Once per chunk, never per sample.
        if let Some(signal) = stop.and_then(StopSignal::caught) {
            interrupted = Some(signal);
            break;
        }
        let Some(chunk) = sim.next_chunk()? else {
            break;
        };
        for (row, truth) in chunk.accel_v().iter().zip(chunk.truth()) {
            let batch = ((n / batch_len) as usize).min(BATCHES - 1);
            for u in 0..3 {
                let [a_l1, a_l2, a_l3] = truth.a_l_unit_g[u];
                let [a1, a2, a3] = truth.a_mean_unit_g[u];
                // Against the acceleration the unit sensed: the vibration's own motion
                // along IA is measured, not an error.
                let error_g = row[u] / k1_v_per_g[u] - a3;
                let model_error_g = truth.exact_mean_output_g[u] - a_l3;
                sum_err[u] += error_g;
                // The cross-axis sensitivities m1, m2 pass the OA/PA vibration through
                // linearly (zero-mean, but not averaged away within an output interval);
                // taking it out leaves the residual's noise to the rectified terms.
                let cross_g = m[u][0] * (a1 - a_l1) + m[u][1] * (a2 - a_l2);
                sum_resid[batch][u] += error_g - model_error_g - cross_g;
                sum_exact[u] += model_error_g;
                sum_ve[u] += truth.exact_ve_g[u];
            }
            n += 1;
        }
        let rig_chunk = RigChunk {
            sensor_first_index: chunk.sensor_first_index(),
            sensor_v: chunk.sensor_v(),
            output_first_index: chunk.output_first_index(),
            accel_v: chunk.accel_v(),
        };
        packetizer.push_chunk(rig_chunk, chunk.truth().iter().map(truth_sample), &mut emit)?;
        bar.set_position(n);
    }
    packetizer.flush(&mut emit)?;
    if live.is_some() {
        // A subscriber's queued samples live in the publisher's shared memory: give
        // the consumers a moment to take the last blocks before the ports close.
        std::thread::sleep(Duration::from_millis(300));
    }
    bar.finish_and_clear();
    let finished = match recorder {
        Some(rec) => Some(rec.finish().context("finishing the log")?),
        None => None,
    };
    // Finished, also when interrupted: a valid log of what was generated.
    if let (Some(part), Some(path)) = (part, out) {
        if !force && std::fs::symlink_metadata(path).is_ok() {
            bail!(
                "output {}: appeared while the flight was simulated; pass --force to overwrite it",
                path.display()
            );
        }
        part.commit(path)?;
    }
    if let Some(signal) = interrupted {
        let reached_s = n as f64 / rates.output_hz;
        let log = match (&finished, out) {
            (Some(f), Some(path)) => format!(
                "; {} is finished with the {} messages written so far",
                path.display(),
                f.messages
            ),
            _ => String::new(),
        };
        bail!(
            "interrupted by {signal} at simulated time {reached_s:.3} s of {:.3} s{log}",
            sim.duration_s()
        );
    }
    let elapsed_s = started.elapsed().as_secs_f64();
    let nf = n.max(1) as f64;
    let units = (0..3)
        .map(|u| {
            let mean = sum_err[u] / nf;
            let resid: f64 = sum_resid.iter().map(|b| b[u]).sum::<f64>() / nf;
            // Batch means of the residual (the last batch takes the remainder).
            let means: Vec<f64> = (0..BATCHES)
                .map(|b| {
                    let len = if b == BATCHES - 1 {
                        n.saturating_sub(batch_len * (BATCHES as u64 - 1))
                    } else {
                        batch_len
                    };
                    sum_resid[b][u] / len.max(1) as f64
                })
                .collect();
            let var =
                means.iter().map(|m| (m - resid).powi(2)).sum::<f64>() / (BATCHES as f64 - 1.0);
            UnitReport {
                name: names.get(u).cloned().unwrap_or_default(),
                mean_error_g: mean,
                exact_mean_error_g: sum_exact[u] / nf,
                exact_ve_g: sum_ve[u] / nf,
                unexplained_g: resid,
                unexplained_sigma_g: (var / BATCHES as f64).sqrt(),
            }
        })
        .collect();
    let (vib_blocks, accel_blocks) = packetizer.blocks();
    let duration_s = sim.duration_s();
    let report = FlightReport {
        scenario: scenario.name.clone(),
        file: scenario.file.clone(),
        seed: scenario.seed,
        duration_s,
        effects: effects_text,
        sensor_samples: total.sensor,
        output_samples: n,
        vib_blocks,
        accel_blocks,
        sensor_clipped: sim.sensor_clipped(),
        elapsed_s,
        real_time_factor: duration_s / elapsed_s.max(1e-9),
        out: out.map(|p| p.display().to_string()),
        live_prefix: None,
        units,
    };
    Ok(report)
}

fn print_flight(report: &FlightReport) -> anyhow::Result<()> {
    let duration_s = report.duration_s;
    let elapsed_s = report.elapsed_s;
    outln!(
        "Flight {} ({}), seed {}, {:.1} s: {} sensor samples x3, {} accelerometer samples x3",
        report.scenario,
        report.file,
        report.seed,
        duration_s,
        report.sensor_samples,
        report.output_samples
    )?;
    outln!(
        "  effects: {}",
        if report.effects.is_empty() {
            "none".to_string()
        } else {
            report.effects.join(", ")
        }
    )?;
    outln!(
        "  mean error over the flight (U/K1 minus the sensed acceleration), simulated and by the exact model (no effect):"
    )?;
    outln!("  unit    simulated      exact model    of which VE     simulated - exact")?;
    for u in &report.units {
        outln!(
            "  {:<6} {:>12}  {:>12}  {:>12}  {:>12} +- {}",
            u.name,
            fmt_g(u.mean_error_g),
            fmt_g(u.exact_mean_error_g),
            fmt_g(u.exact_ve_g),
            fmt_g(u.unexplained_g),
            fmt_g(u.unexplained_sigma_g)
        )?;
    }
    outln!(
        "  generated in {:.2} s ({:.1}x real time){}",
        elapsed_s,
        report.real_time_factor,
        report
            .out
            .as_ref()
            .map(|p| format!("; log: {p}"))
            .unwrap_or_default()
    )?;
    Ok(())
}

#[derive(Debug, Serialize)]
struct ConditionReport {
    id: String,
    angle_deg: f64,
    a_l_unit_g: [f64; 3],
    direction: String,
    tone_freq_hz: Option<f64>,
    tone_amplitude_g: Option<f64>,
    sigma_unit_g: [f64; 3],
    measured_ve_g: f64,
    measured_ve_sigma_g: f64,
    exact_ve_g: f64,
    published_ve_g: f64,
    z_exact: f64,
    drift_accepted: bool,
}

#[derive(Debug, Serialize)]
struct CampaignReport {
    scenario: String,
    file: String,
    seed: u64,
    passport: String,
    effects: Vec<String>,
    elapsed_s: f64,
    conditions: Vec<ConditionReport>,
    summary_csv: Option<String>,
    lab_csv: Option<String>,
    positions_csv: Option<String>,
}

fn run_campaign(scenario: &Scenario, args: &SimArgs) -> anyhow::Result<()> {
    if args.out.is_some() || args.live {
        bail!(
            "--out/--live stream a flight; {} is a campaign: use --summary-csv / --positions-csv",
            scenario.name
        );
    }
    let Some(campaign) = scenario.campaign() else {
        bail!("{} is not a campaign", scenario.name);
    };
    let bar = progress_bar(campaign.conditions.len() as u64, "conditions");
    let started = Instant::now();
    let options = vibro_sim::CampaignOptions {
        threads: args.threads.max(1),
    };
    let summaries = vibro_sim::run_campaign(scenario, &options, &mut |_| bar.inc(1))?;
    bar.finish_and_clear();
    let write = |path: &PathBuf, positions: bool| -> anyhow::Result<()> {
        crate::files::write_file(path, args.force, |w| {
            if positions {
                let comment = vec![format!(
                    "simulated by vibrocomp sim {} (seed {})",
                    scenario.name, scenario.seed
                )];
                vibro_sim::write_positions_csv(w, &summaries, &comment)?;
            } else {
                vibro_sim::write_summary_csv(w, &summaries)?;
            }
            Ok(())
        })
    };
    if let Some(p) = &args.summary_csv {
        write(p, false)?;
    }
    if let Some(p) = &args.positions_csv {
        write(p, true)?;
    }
    if let Some(p) = &args.lab_csv {
        // `--ve-resolution-g` was checked before the campaign ran (`apply_overrides`).
        let table =
            vibro_lab::CampaignTable::from_campaign(p, scenario, &summaries, args.ve_resolution_g)?;
        crate::files::write_file(p, args.force, |w| {
            use std::io::Write as _;
            writeln!(
                w,
                "# campaign table of the model lab (docs/lab.md): vibrocomp sim {} (seed {}{})",
                scenario.name,
                scenario.seed,
                effect_labels(scenario)
                    .iter()
                    .map(|e| format!(", effect {e}"))
                    .collect::<String>()
            )?;
            table.write_csv(w)?;
            Ok(())
        })?;
    }
    let conditions: Vec<ConditionReport> = summaries
        .iter()
        .map(|s| ConditionReport {
            id: s.condition.id.clone(),
            angle_deg: s.condition.angle_deg,
            a_l_unit_g: s.condition.a_l_unit_g,
            direction: s.condition.direction.name().to_string(),
            tone_freq_hz: s.condition.tone.map(|t| t.freq_hz),
            tone_amplitude_g: s.condition.tone_amplitude_g,
            sigma_unit_g: s.sigma_unit_g(),
            measured_ve_g: s.measurement.ve_g,
            measured_ve_sigma_g: s.measurement.ve_sigma_g,
            exact_ve_g: s.exact_ve_g,
            published_ve_g: s.published_ve_g,
            z_exact: s.z_exact,
            drift_accepted: s.drift_accepted,
        })
        .collect();
    let report = CampaignReport {
        scenario: scenario.name.clone(),
        file: scenario.file.clone(),
        seed: scenario.seed,
        passport: campaign.passport_source.clone(),
        effects: effect_labels(scenario),
        elapsed_s: started.elapsed().as_secs_f64(),
        conditions,
        summary_csv: args.summary_csv.as_ref().map(|p| p.display().to_string()),
        lab_csv: args.lab_csv.as_ref().map(|p| p.display().to_string()),
        positions_csv: args.positions_csv.as_ref().map(|p| p.display().to_string()),
    };
    if args.json {
        return print_json(&report);
    }
    outln!(
        "Campaign {} ({}), passport {}, seed {}, {} conditions in {:.1} s",
        report.scenario,
        report.file,
        report.passport,
        report.seed,
        report.conditions.len(),
        report.elapsed_s
    )?;
    outln!(
        "  effects: {}",
        if report.effects.is_empty() {
            "none".to_string()
        } else {
            report.effects.join(", ")
        }
    )?;
    outln!("  id     angle  direction   tone            sigma3     measured VE           exact        published     z")?;
    for c in &report.conditions {
        let tone = match (c.tone_freq_hz, c.tone_amplitude_g) {
            (Some(f), Some(a)) => format!("{a:.2} g @ {f:.0} Hz"),
            _ => "-".to_string(),
        };
        outln!(
            "  {:<6} {:>5.0}  {:<10} {:<15} {:>7.3} g  {:>11} +- {:<10} {:>11}  {:>11}  {:>5.1}{}",
            c.id,
            c.angle_deg,
            c.direction,
            tone,
            c.sigma_unit_g[2],
            fmt_g(c.measured_ve_g),
            fmt_g(c.measured_ve_sigma_g),
            fmt_g(c.exact_ve_g),
            fmt_g(c.published_ve_g),
            c.z_exact,
            if c.drift_accepted {
                ""
            } else {
                "  (tilt check failed)"
            }
        )?;
    }
    Ok(())
}
