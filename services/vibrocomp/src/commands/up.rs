//! `vibrocomp up [--record OUT.mcap]`: starts the estimator and the compensator (and
//! the recorder) as child processes, restarts a crashed service (up to a limit), and
//! stops everything cleanly on Ctrl-C / SIGTERM.
//!
//! `--rig RIG.toml` gives both services the rig's vibration-sensor chain and `--model
//! MODEL.toml` gives the compensator an extended model: their configurations with those
//! keys replaced are written into a private folder (`vibro_system::derived`) and the
//! services are started with them. The rig file, the model and the derived
//! configurations are checked before anything starts.

use anyhow::Context;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio::sync::mpsc;
use tracing::info;
use vibro_msgs::{ServiceId, ServiceNames};
use vibro_service::supervise::{claim_prefix, running_on, supervise, ProcessReport, RestartLimits};
use vibro_service::{init_tracing, run_service};
use vibro_system::derived::DerivedConfigs;
use vibro_system::{Role, SystemSpec};

use crate::output::print_json;

#[derive(Debug, Clone, clap::Args)]
pub struct UpArgs {
    /// Service-name prefix of the system.
    #[arg(long, default_value = vibro_msgs::DEFAULT_PREFIX)]
    pub prefix: String,
    /// Records every stream into this log while the system runs (an existing file only
    /// with --force; written in place, so that a crash leaves what `log recover` restores).
    #[arg(long, value_name = "OUT.mcap")]
    pub record: Option<PathBuf>,
    /// Replace the --record log if it exists.
    #[arg(long, requires = "record")]
    pub force: bool,
    /// Serves the live view to Foxglove (`vibrocomp view`) on this address
    /// [default when given alone: 127.0.0.1:8765].
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1,
          default_missing_value = crate::commands::view::DEFAULT_LISTEN)]
    pub foxglove: Option<std::net::SocketAddr>,
    /// The estimator's configuration [default: config/services/estimator.toml, else shipped].
    #[arg(long, value_name = "FILE")]
    pub estimator_config: Option<PathBuf>,
    /// The compensator's configuration [default: config/services/compensator.toml, else shipped].
    #[arg(long, value_name = "FILE")]
    pub compensator_config: Option<PathBuf>,
    /// A rig file (`format = "vibrocomp-rig/1"`, docs/logs.md): its vibration sensors'
    /// chain (`[sensors]` sensitivity_v_per_g, ac_corner_hz, delay_s) replaces the
    /// estimator's (`[estimator]` sensitivity_raw_per_g, ac_corner_hz, delay_s) and the
    /// compensator's (`[sensors]`); its `rate_hz`, when stated, the estimator's
    /// `sample_rate_hz` (the compensator takes the rate from the stream).
    #[arg(long, value_name = "RIG.toml")]
    pub rig: Option<PathBuf>,
    /// An extended model (`vibrocomp lab add --out`, docs/lab.md): replaces the
    /// compensator's `model`. Its mode must be the compensator's `mode`.
    #[arg(long, value_name = "MODEL.toml")]
    pub model: Option<PathBuf>,
    /// The services' loop mode: event (default) or spin.
    #[arg(long, value_name = "event|spin")]
    pub mode: Option<String>,
    /// Run both services' hot loops under SCHED_FIFO at this priority (1..=99),
    /// overriding their `[service] realtime_priority`; needs CAP_SYS_NICE.
    #[arg(long, value_name = "1..99", value_parser = clap::value_parser!(u8).range(1..=99))]
    pub realtime_priority: Option<u8>,
    /// Also run a Zenoh bridge to other hosts with this configuration (docs/bridge.md),
    /// restarted like the services.
    #[arg(long, value_name = "FILE")]
    pub bridge: Option<PathBuf>,
    /// Restarts allowed per service within --restart-window-s before `up` gives up.
    #[arg(long, default_value_t = 5)]
    pub max_restarts: u32,
    /// The window --max-restarts counts restarts in, s.
    #[arg(long = "restart-window-s", default_value_t = 60.0)]
    pub restart_window_s: f64,
    /// Seconds a stopping process gets before it is killed.
    #[arg(long = "stop-timeout-s", default_value_t = 5.0)]
    pub stop_timeout_s: f64,
    /// Print a JSON summary (restarts, exit codes) at exit.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct UpReport {
    prefix: String,
    record: Option<String>,
    /// `--rig` and `--model`, as given.
    rig: Option<String>,
    model: Option<String>,
    processes: Vec<ProcessReport>,
}

pub fn run(args: &UpArgs) -> anyhow::Result<()> {
    init_tracing();
    ServiceNames::new(&args.prefix).with_context(|| format!("--prefix {:?}", args.prefix))?;
    // Before anything starts (a duration `Duration` cannot hold would panic in the
    // supervisor, with the services running): a day at most.
    let mut problems = crate::flags::FlagProblems::new();
    let window = problems.seconds("--restart-window-s", args.restart_window_s, 0.1, 86_400.0);
    let stop_timeout = problems.seconds("--stop-timeout-s", args.stop_timeout_s, 0.01, 3600.0);
    problems.finish()?;
    let (window, stop_timeout) = (window.unwrap_or_default(), stop_timeout.unwrap_or_default());
    // A bad configuration, rig file or model fails here, once, instead of in a restart
    // loop. Kept for `up`'s life: restarted services read the derived files again.
    if let Some(path) = &args.bridge {
        drop(vibro_bridge::BridgeConfig::load(path)?);
    }
    let derived = vibro_system::derived::derive(
        args.estimator_config.as_deref(),
        args.compensator_config.as_deref(),
        args.rig.as_deref(),
        args.model.as_deref(),
    )?;
    let derived_path = |pick: fn(&DerivedConfigs) -> Option<&Path>, given: &Option<PathBuf>| {
        derived
            .as_ref()
            .and_then(pick)
            .map(Path::to_path_buf)
            .or_else(|| given.clone())
    };
    let estimator_config = derived_path(DerivedConfigs::estimator, &args.estimator_config);
    let compensator_config = derived_path(DerivedConfigs::compensator, &args.compensator_config);
    if let Some(out) = &args.record {
        check_record_path(out, args.force)?;
    }
    // Two systems on one prefix would each compensate every block: refuse to start
    // beside a running one (docs/services.md, "Running the system"). The claim (a
    // lock held for `up`'s life) settles two `up`s started at the same instant, which
    // would both find nobody running; the look for running services also catches a
    // system started some other way.
    let names = ServiceNames::new(&args.prefix)?;
    let claim =
        claim_prefix(&args.prefix).with_context(|| format!("claiming prefix {:?}", args.prefix))?;
    let running = running_on(
        &names,
        &[
            ServiceId::Estimator,
            ServiceId::Compensator,
            ServiceId::Recorder,
        ],
        Duration::from_millis(1500),
    )
    .context("looking for a system already running on the prefix")?;
    if !running.is_empty() {
        let list: Vec<String> = running.iter().map(|r| r.to_string()).collect();
        anyhow::bail!(
            "a system is already running on prefix {:?}: {}; stop it first or choose another --prefix",
            args.prefix,
            list.join("; ")
        );
    }
    let _claim = match claim {
        Ok(c) => c,
        Err(other) => anyhow::bail!(
            "another `vibrocomp up` (pid {}) is starting on prefix {:?} (it holds {}); stop it first or choose another --prefix",
            other
                .pid
                .map_or_else(|| "unknown".to_string(), |p| p.to_string()),
            args.prefix,
            other.path.display()
        ),
    };
    let spec = SystemSpec {
        prefix: args.prefix.clone(),
        estimator_config,
        compensator_config,
        mode: args.mode.clone(),
        realtime_priority: args.realtime_priority,
        record: args.record.clone(),
        force_record: args.force,
        foxglove: args.foxglove,
        json: false,
        exe: None,
        bridge: args.bridge.clone(),
        cwd: None,
    };
    let roles = spec.roles();
    let reports = run_service(|shutdown| async move {
        let (tx, mut rx) = mpsc::unbounded_channel();
        let mut tasks = Vec::new();
        for role in roles {
            let limits = RestartLimits {
                max_restarts: args.max_restarts,
                window,
                stop_timeout,
            };
            let (spec, shutdown, tx) = (spec.clone(), shutdown.clone(), tx.clone());
            tasks.push(tokio::spawn(async move {
                // The recorder is not restarted: a new recorder would replace the log.
                let restart = role != Role::Recorder;
                let report = supervise(
                    role.name(),
                    restart,
                    || spec.command(role),
                    limits,
                    shutdown,
                )
                .await?;
                let _ = tx.send(report);
                anyhow::Ok(())
            }));
        }
        drop(tx);
        info!(
            prefix = %spec.prefix,
            record = ?spec.record,
            "system up; Ctrl-C stops it"
        );
        let mut first_error = None;
        for t in tasks {
            match t.await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    shutdown.trigger();
                    first_error.get_or_insert(e);
                }
                Err(e) => {
                    shutdown.trigger();
                    first_error.get_or_insert(anyhow::anyhow!("supervisor task failed: {e}"));
                }
            }
        }
        let mut reports = Vec::new();
        while let Some(r) = rx.recv().await {
            reports.push(r);
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(reports),
        }
    })?;
    let gave_up = reports.iter().any(|r| r.gave_up);
    if args.json {
        print_json(&UpReport {
            prefix: args.prefix.clone(),
            record: args.record.as_ref().map(|p| p.display().to_string()),
            rig: args.rig.as_ref().map(|p| p.display().to_string()),
            model: args.model.as_ref().map(|p| p.display().to_string()),
            processes: reports.clone(),
        })?;
    } else {
        for r in &reports {
            outln!(
                "{:<12} started {} time(s), crashed {}, last exit: {}",
                r.role,
                r.starts,
                r.crashes,
                r.last_exit.as_deref().unwrap_or("-")
            )?;
        }
    }
    anyhow::ensure!(
        !gave_up,
        "a service crashed too often; the system was stopped"
    );
    Ok(())
}

/// Refuses a recording path the recorder could not write, before any service starts,
/// by the same check as `record` ([`crate::files::check_recording`]): an input, a
/// directory, a missing folder, a device, a FIFO or a link, an existing regular file
/// without --force (README, "Files"), or a file or folder this user cannot write.
fn check_record_path(out: &std::path::Path, force: bool) -> anyhow::Result<()> {
    crate::files::check_recording(out, &[], force)
        .with_context(|| format!("--record {}", out.display()))
}
