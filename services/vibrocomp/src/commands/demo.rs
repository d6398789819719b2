//! `vibrocomp demo`: the whole system on the embedded Cyclone-4 flight.
//!
//! 1. The rig simulator flies `cyclone-4-short` (RIG.md's Cyclone-4 profile in 20 s:
//!    AL-15 triad, 1 -> 5 g, 0.5 g / 1.2 g tones sweeping 8..16 Hz, 1.4 g RMS random
//!    vibration) into `flight.mcap`: vibration-sensor and accelerometer streams plus
//!    the truth.
//! 2. The estimator, the compensator and a recorder start as separate processes under a
//!    private service prefix.
//! 3. The flight is replayed into them as fast as possible, lock-stepped (nothing
//!    dropped, the result independent of timing); the recorder writes every stream into
//!    `session.mcap`.
//! 4. The services stop; the recording is read back and each stage's error is measured
//!    against the acceleration each unit really sensed (`TruthBlock.a_sensed_ia_g`),
//!    averaged over windows (default 0.5 s): uncompensated `U/K1`, main error removed
//!    `a(2)`, vibration error removed `a(4)` (MODEL.md section 7, [P2 (17)-(20)]).
//!
//! The error measure is `vibro_log::session::session_errors`.

use anyhow::{bail, Context};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};
use vibro_log::session::{session_errors, SessionErrors, StageErrors};
use vibro_log::{Pace, ReplayOptions, ReplaySummary};
use vibro_msgs::{ServiceId, ServiceNames};
use vibro_service::ServiceConfig;
use vibro_sim::ScenarioKind;

use crate::commands::replay::replay_with_bar;
use crate::commands::sim::simulate_flight;
use crate::output::{fmt_g, fmt_ratio, print_json};
use crate::system::{Role, SystemSpec};
use vibro_service::supervise::{private_prefix, wait_for_heartbeats};

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Flight scenario: a TOML file or a shipped id.
    #[arg(long, default_value = "cyclone-4-short")]
    pub scenario: String,
    /// Where the flight log, the session recording and the services' log go (created
    /// if missing; one holding a previous run is refused unless --force).
    #[arg(long = "out-dir", default_value = "vibrocomp-demo")]
    pub out_dir: PathBuf,
    /// Replace the files of a previous run in --out-dir.
    #[arg(long)]
    pub force: bool,
    /// Averaging window of the error measure, s.
    #[arg(long = "window-s", default_value_t = 0.5)]
    pub window_s: f64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct ServiceLosses {
    service: &'static str,
    /// The service's own `--json` summary at exit.
    summary: serde_json::Value,
}

#[derive(Debug, Serialize)]
struct DemoReport {
    scenario: String,
    flight_log: String,
    session_log: String,
    services_log: String,
    prefix: String,
    simulated_in_s: f64,
    replay: ReplaySummary,
    recording: serde_json::Value,
    services: Vec<ServiceLosses>,
    lost_messages: u64,
    errors: SessionErrors,
    elapsed_s: f64,
}

/// Losses a service's summary reports (input messages and samples, undelivered output).
fn losses(v: &serde_json::Value) -> u64 {
    let get = |path: &[&str]| {
        path.iter()
            .try_fold(v, |v, k| v.get(k))
            .and_then(|x| x.as_u64())
            .unwrap_or(0)
    };
    get(&["vib", "lost_messages"])
        + get(&["vib", "lost_samples"])
        + get(&["accel", "lost_messages"])
        + get(&["accel", "lost_samples"])
        + get(&["undelivered"])
        + get(&["lost"])
}

/// The files of a run, in the folder `--out-dir`.
const DEMO_FILES: [&str; 3] = ["flight.mcap", "session.mcap", "services.log"];

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let scenario = vibro_sim::resolve_scenario(&args.scenario)
        .with_context(|| format!("scenario {}", args.scenario))?;
    let ScenarioKind::Flight(flight) = &scenario.kind else {
        bail!(
            "--scenario {}: the demo needs a flight, not a campaign",
            args.scenario
        );
    };
    // Before anything runs: a window holds at least one accelerometer output of the
    // scenario and fits in its flight (beyond, no window is ever complete).
    let mut problems = crate::flags::FlagProblems::new();
    problems.seconds(
        "--window-s",
        args.window_s,
        1.0 / scenario.rates.output_hz,
        flight.duration_s,
    );
    problems.finish()?;
    // README, "Files": a folder of a previous run is replaced only with --force.
    crate::files::check_dir(&args.out_dir, &DEMO_FILES, args.force)?;
    crate::files::create_dir(&args.out_dir)?;
    let [flight_log, session_log, services_log] = DEMO_FILES.map(|f| args.out_dir.join(f));
    let _ = std::fs::remove_file(&services_log);

    // 1. The flight.
    if !args.json {
        outln!(
            "Simulating {} into {} ...",
            scenario.name,
            flight_log.display()
        )?;
    }
    let flight = simulate_flight(&scenario, Some(&flight_log), None, args.force)?;

    // 2. The system, under a prefix of its own.
    let prefix = private_prefix("vcdemo");
    let names = ServiceNames::new(&prefix)?;
    let spec = SystemSpec {
        prefix: prefix.clone(),
        record: Some(session_log.clone()),
        // The folder was checked above: a previous run's recording is replaced.
        force_record: true,
        json: true,
        ..SystemSpec::default()
    };
    let k1_v_per_g = {
        let c = vibro_compensator::Config::load_default()?;
        c.model.triad.passports.map(|p| p.k1_v_per_g)
    };
    let mut estimator = spec.spawn(Role::Estimator, Some(&services_log))?;
    let mut compensator = spec.spawn(Role::Compensator, Some(&services_log))?;
    let mut recorder = spec.spawn(Role::Recorder, Some(&services_log))?;
    wait_for_heartbeats(
        &names,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        Duration::from_secs(30),
        || {
            estimator.check_alive()?;
            compensator.check_alive()?;
            recorder.check_alive()
        },
    )
    .with_context(|| {
        format!(
            "starting the services (their log: {})",
            services_log.display()
        )
    })?;
    if !args.json {
        outln!(
            "Services up under {prefix} (estimator, compensator, recorder); replaying the flight as fast as possible, lock-stepped ..."
        )?;
    }

    // 3. The replay.
    let options = ReplayOptions::new(names, Pace::AsFastAsPossible);
    let stop = AtomicBool::new(false);
    let replay = replay_with_bar(&flight_log, &options, &stop)?;

    // 4. Stop: the recorder first (it takes what the services published), then them.
    let timeout = Duration::from_secs(20);
    let recording = recorder.stop(timeout)?.summary()?;
    let est = estimator.stop(timeout)?.summary()?;
    let comp = compensator.stop(timeout)?.summary()?;
    let lost_messages = losses(&est)
        + losses(&comp)
        + recording.get("lost").and_then(|x| x.as_u64()).unwrap_or(0)
        + replay.undelivered;
    let errors = session_errors(&session_log, k1_v_per_g, args.window_s)?;
    let report = DemoReport {
        scenario: format!("{} ({})", scenario.name, scenario.file),
        flight_log: flight_log.display().to_string(),
        session_log: session_log.display().to_string(),
        services_log: services_log.display().to_string(),
        prefix,
        simulated_in_s: flight.elapsed_s,
        replay,
        recording,
        services: vec![
            ServiceLosses {
                service: "estimator",
                summary: est,
            },
            ServiceLosses {
                service: "compensator",
                summary: comp,
            },
        ],
        lost_messages,
        errors,
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    if args.json {
        return print_json(&report);
    }
    print_report(&report)
}

fn print_report(r: &DemoReport) -> anyhow::Result<()> {
    let e = &r.errors;
    outln!(
        "Replayed {} messages ({:.0} s of flight) in {:.2} s ({:.0}x real time); recorded {} messages into {}; lost {}",
        r.replay.messages,
        r.replay.log_span_s,
        r.replay.elapsed_s,
        r.replay.real_time_factor,
        r.recording.get("messages").and_then(|x| x.as_u64()).unwrap_or(0),
        r.session_log,
        r.lost_messages
    )?;
    outln!(
        "Error against the sensed acceleration, mean over {} s windows ({} of {} windows compensated with a vibration estimate; the first {} blocks came before the first estimate):",
        e.window_s, e.compensated_windows, e.windows, e.main_only_blocks
    )?;
    outln!(
        "  {:<10}{:>16}{:>16}{:>20}{:>12}",
        "unit",
        "uncompensated",
        "main removed",
        "vibration removed",
        "reduction"
    )?;
    let line = |name: &str, s: &StageErrors| {
        outln!(
            "  {:<10}{:>16}{:>16}{:>20}{:>12}",
            name,
            fmt_g(s.uncompensated_rms_g),
            fmt_g(s.main_removed_rms_g),
            fmt_g(s.vibration_removed_rms_g),
            fmt_ratio(s.reduction)
        )
    };
    for u in &e.units {
        line(&format!("AK{}", u.unit), &u.errors)?;
    }
    line("all", &e.all_units)?;
    outln!(
        "Logs: {}, {}, {}",
        r.flight_log,
        r.session_log,
        r.services_log
    )?;
    Ok(())
}
