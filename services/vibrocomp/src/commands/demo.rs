//! `vibrocomp demo`: the whole system on the embedded Cyclone-4 flight.
//!
//! 1. The rig simulator flies `cyclone-4-short` (RIG.md's Cyclone-4 profile in 20 s:
//!    AL-15 triad, 1 -> 5 g, 0.5 g / 1.2 g tones sweeping 8..16 Hz, 1.4 g RMS random
//!    vibration) into `flight.mcap`: vibration-sensor and accelerometer streams plus
//!    the truth.
//! 2. The estimator, the compensator and a recorder start as separate processes under a
//!    private service prefix, on the shipped configurations. Both undo the vibration
//!    sensors' chain (sensitivity, AC coupling, delay; the estimator also needs their
//!    rate), which must be the one the scenario simulates: where the shipped files state
//!    another (a scenario file of one's own), the services get copies with the
//!    scenario's chain put in (`vibro_system::derived`, as `up --rig` does).
//! 3. The flight is replayed into them as fast as possible, lock-stepped (nothing
//!    dropped, the result independent of timing); the recorder writes every stream into
//!    `session.mcap`.
//! 4. The services stop; the recording is read back and each stage's error is measured
//!    against the acceleration each unit really sensed (`TruthBlock.a_sensed_ia_g`),
//!    averaged over windows (default 0.5 s): uncompensated `U/K1`, main error removed
//!    `a(2)`, vibration error removed `a(4)` (MODEL.md section 7, [P2 (17)-(20)]),
//!    and, where the compensator's waveform stage made the blocks (MODEL.md section
//!    12), the estimate stage's own answer beside it.
//!
//! The error measure and its table are `vibro_log::session::log_errors` and
//! `SessionErrors::write_table`, which `vibrocomp log errors` prints too: the demo's
//! table and `log errors` on its `session.mcap` are one computation.

use anyhow::{bail, Context};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};
use vibro_config::rig::SensorChain;
use vibro_log::session::{log_errors, SessionErrors, DEFAULT_WINDOW_S};
use vibro_log::{Pace, ReplayOptions, ReplaySummary};
use vibro_msgs::{ServiceId, ServiceNames};
use vibro_service::ServiceConfig;
use vibro_sim::{Scenario, ScenarioKind};
use vibro_system::derived::{self, DerivedConfigs};
use vibro_system::hosts::TwoHosts;
use vibro_system::{Role, SystemSpec};

use crate::commands::replay::replay_with_bar;
use crate::commands::sim::simulate_flight;
use crate::output::print_json;
use vibro_service::supervise::{private_prefix, wait_for_heartbeats, wait_for_published};

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

    // 2. The system, under a prefix of its own, undoing the sensors' chain the
    // scenario simulates.
    let prefix = private_prefix("vcdemo");
    let names = ServiceNames::new(&prefix)?;
    let derived = scenario_configs(&scenario)?;
    if let (Some(d), false) = (&derived, args.json) {
        outln!(
            "The shipped service configurations state another vibration-sensor chain than {}'s; the services run on copies with the scenario's ({})",
            scenario.name,
            d.dir().display()
        )?;
    }
    let spec = SystemSpec {
        prefix: prefix.clone(),
        record: Some(session_log.clone()),
        // The folder was checked above: a previous run's recording is replaced.
        force_record: true,
        json: true,
        estimator_config: derived
            .as_ref()
            .and_then(|d| d.estimator().map(Path::to_path_buf)),
        compensator_config: derived
            .as_ref()
            .and_then(|d| d.compensator().map(Path::to_path_buf)),
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
    let options = ReplayOptions::new(names.clone(), Pace::AsFastAsPossible);
    let stop = AtomicBool::new(false);
    let replay = replay_with_bar(&flight_log, &options, &stop)?;

    // 4. Stop: the recorder first (it takes what the services published), then them.
    // The compensator's waveform stage holds a reading until the sensors' samples cover
    // it, and the flight's last one never is: it goes out once the sensors' stream has
    // been silent for a while (`vibro_compensator::waveform::SILENCE_NS`, wall clock),
    // after the replay has returned. The recorder waits for it.
    let accel_blocks = replay
        .topics
        .get(&vibro_log::topic(vibro_msgs::Stream::Accel))
        .copied()
        .unwrap_or(0);
    wait_for_published(
        &names,
        ServiceId::Compensator,
        accel_blocks,
        Duration::from_secs(10),
        || compensator.check_alive(),
    )?;
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
    drop(derived);
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
    // The scenario's derived configurations if the one-host spec has them (absolute
    // already), else the shipped ones.
    let common = SystemSpec {
        estimator_config: spec
            .estimator_config
            .clone()
            .or_else(|| shipped(vibro_estimator::Config::DEFAULT_CONFIG_PATH)),
        compensator_config: spec
            .compensator_config
            .clone()
            .or_else(|| shipped(vibro_compensator::Config::DEFAULT_CONFIG_PATH)),
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

/// The vibration sensors' chain `scenario` simulates (`[sensor]`, `[rates] sensor_hz`;
/// the simulator's sensors have no delay), as a rig file states one.
fn scenario_chain(scenario: &Scenario) -> SensorChain {
    let s = &scenario.sensor;
    SensorChain {
        sensitivity_v_per_g: [s.sensitivity_v_per_g; 3],
        ac_corner_hz: (s.ac_corner_hz > 0.0).then_some(s.ac_corner_hz),
        delay_s: 0.0,
        delay_stated: true,
        rate_hz: Some(scenario.rates.sensor_hz),
    }
}

/// The services' configurations for `scenario`: `None` when the shipped ones (the files
/// of the working directory, else the copies compiled in) state the chain it simulates,
/// as they do for every shipped flight; else copies with its chain put in.
fn scenario_configs(scenario: &Scenario) -> anyhow::Result<Option<DerivedConfigs>> {
    let chain = scenario_chain(scenario);
    let estimator =
        vibro_estimator::Config::load_default().context("the estimator's shipped configuration")?;
    let compensator = vibro_compensator::Config::load_default()
        .context("the compensator's shipped configuration")?;
    let e = estimator.estimator.raw();
    let c = compensator.model.waveform.chain;
    let ac_corner_hz = chain.ac_corner_hz.unwrap_or(0.0);
    let same = e.sample_rate_hz == scenario.rates.sensor_hz
        && e.sensitivity_raw_per_g == chain.sensitivity_v_per_g
        && e.ac_corner_hz.unwrap_or(0.0) == ac_corner_hz
        && c.sensitivity_v_per_g == chain.sensitivity_v_per_g
        && c.ac_corner_hz == ac_corner_hz
        && c.delay_s == chain.delay_s;
    if same {
        return Ok(None);
    }
    // The base texts as the services would read them: the working directory's files
    // (their folder resolving the compensator's relative names), else the shipped ones.
    let text = |rel: &str, shipped: &str| -> anyhow::Result<(String, Option<PathBuf>)> {
        let path = Path::new(rel);
        if path.is_file() {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading {}", path.display()))?;
            Ok((text, path.parent().map(Path::to_path_buf)))
        } else {
            Ok((shipped.to_string(), None))
        }
    };
    let (est_base, _) = text(
        vibro_estimator::Config::DEFAULT_CONFIG_PATH,
        vibro_estimator::Config::shipped_text(),
    )?;
    let (comp_base, comp_dir) = text(
        vibro_compensator::Config::DEFAULT_CONFIG_PATH,
        vibro_compensator::Config::shipped_text(),
    )?;
    let est = derived::estimator_text(&est_base, &chain)?;
    let comp = derived::compensator_text(&comp_base, comp_dir.as_deref(), Some(&chain), None)?;
    Ok(Some(DerivedConfigs::write(Some(&est), Some(&comp))?))
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
