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
//! The error measure and its table are `vibro_log::session::log_errors` and
//! `SessionErrors::write_table`, which `vibrocomp log errors` prints too: the demo's
//! table and `log errors` on its `session.mcap` are one computation.

use anyhow::{bail, Context};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};
use vibro_log::session::{log_errors, SessionErrors, DEFAULT_WINDOW_S};
use vibro_log::{Pace, ReplayOptions, ReplaySummary};
use vibro_msgs::{ServiceId, ServiceNames};
use vibro_service::ServiceConfig;
use vibro_sim::ScenarioKind;
use vibro_system::hosts::TwoHosts;
use vibro_system::{Role, SystemSpec};

use crate::commands::replay::replay_with_bar;
use crate::commands::sim::simulate_flight;
use crate::output::print_json;
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
    #[arg(long = "window-s", default_value_t = DEFAULT_WINDOW_S)]
    pub window_s: f64,
    /// 2: the services on a second "host" (its own iceoryx2 root), reached only
    /// through two Zenoh bridges over a Unix socket; the replay and the recorder stay on
    /// the first (README, "Several hosts").
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub hosts: u8,
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
    /// The bridges' `--json` counters (`--hosts 2`).
    bridges: Vec<ServiceLosses>,
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
    // With --hosts 2: host B runs the services and the bridge that listens; host A
    // (this process: the replay) the recorder and the bridge that connects.
    let (spec_a, spec_b, hosts) = if args.hosts == 2 {
        let (a, b, hosts) = two_host_specs(&spec, &args.out_dir, &session_log)?;
        (a, b, Some(hosts))
    } else {
        (spec.clone(), spec.clone(), None)
    };
    let mut bridges = Vec::new();
    if hosts.is_some() {
        bridges.push(spec_b.spawn(Role::Bridge, Some(&services_log))?);
    }
    let mut estimator = spec_b.spawn(Role::Estimator, Some(&services_log))?;
    let mut compensator = spec_b.spawn(Role::Compensator, Some(&services_log))?;
    if hosts.is_some() {
        bridges.push(spec_a.spawn(Role::Bridge, Some(&services_log))?);
    }
    let mut recorder = spec_a.spawn(Role::Recorder, Some(&services_log))?;
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
            for b in &mut bridges {
                b.check_alive()?;
            }
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
        match &hosts {
            Some(h) => outln!(
                "Services up under {prefix} on host B ({}), recorder on host A ({}), bridged over Zenoh ({}); replaying the flight on host A as fast as possible, lock-stepped ...",
                h.b.dir.display(),
                h.a.dir.display(),
                h.endpoint_b
            )?,
            None => outln!(
                "Services up under {prefix} (estimator, compensator, recorder); replaying the flight as fast as possible, lock-stepped ..."
            )?,
        }
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
    let mut bridge_summaries = Vec::new();
    for (b, host) in bridges
        .into_iter()
        .zip(["bridge on host B", "bridge on host A"])
    {
        bridge_summaries.push(ServiceLosses {
            service: host,
            summary: b.stop(timeout)?.summary()?,
        });
    }
    drop(hosts);
    let lost_messages = losses(&est)
        + losses(&comp)
        + recording.get("lost").and_then(|x| x.as_u64()).unwrap_or(0)
        + bridge_summaries
            .iter()
            .map(|b| b.summary.get("lost").and_then(|x| x.as_u64()).unwrap_or(0))
            .sum::<u64>()
        + replay.undelivered;
    // K1 from the passports the recorder attached: the compensator's.
    let errors = log_errors(&session_log, args.window_s, &vibro_config::default_triad()?)?.errors;
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
        bridges: bridge_summaries,
        lost_messages,
        errors,
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    if args.json {
        return print_json(&report);
    }
    print_report(&report)
}

/// The systems of host A (recorder, bridge) and host B (services, bridge) for
/// `--hosts 2`, from the one-host `spec`: every path absolute (their processes run in
/// the hosts' folders), the shipped service configurations of this working directory
/// passed on (as the one-host run reads them), and this process joined to host A.
fn two_host_specs(
    spec: &SystemSpec,
    out_dir: &std::path::Path,
    session_log: &std::path::Path,
) -> anyhow::Result<(SystemSpec, SystemSpec, TwoHosts)> {
    let out_dir = std::fs::canonicalize(out_dir)
        .with_context(|| format!("--out-dir {}", out_dir.display()))?;
    let tag = format!("vcd{}", std::process::id());
    let hosts = TwoHosts::create(&out_dir.join("hosts"), &tag, &spec.prefix)?;
    vibro_ipc::use_config_file(&hosts.a.iceoryx_config)?;
    let shipped = |rel: &str| std::fs::canonicalize(rel).ok();
    let common = SystemSpec {
        estimator_config: shipped(vibro_estimator::Config::DEFAULT_CONFIG_PATH),
        compensator_config: shipped(vibro_compensator::Config::DEFAULT_CONFIG_PATH),
        ..spec.clone()
    };
    let a = SystemSpec {
        record: session_log.file_name().map(|f| out_dir.join(f)),
        cwd: Some(hosts.a.dir.clone()),
        bridge: Some(hosts.a.bridge_config.clone()),
        ..common.clone()
    };
    let b = SystemSpec {
        cwd: Some(hosts.b.dir.clone()),
        bridge: Some(hosts.b.bridge_config.clone()),
        ..common
    };
    Ok((a, b, hosts))
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
    let mut table = String::new();
    e.write_table(&mut table)
        .context("formatting the error table")?;
    out!("{table}")?;
    outln!(
        "Logs: {}, {}, {}",
        r.flight_log,
        r.session_log,
        r.services_log
    )?;
    Ok(())
}
