//! The soak's background load: a `latency-peer load` child process running
//! `vibrocomp lab diagnose INPUT` in a loop ([`peer_load`]), started and stopped by
//! the soak ([`start_load`], [`stop_load`]).

use anyhow::{bail, Context};
use serde::Serialize;
use std::io::{Read, Write};
use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use crate::cpu::rusage_cpu_s;
use crate::peers::install_stop;

/// The background load: `latency-peer load` and what it said at its end.
#[derive(Debug, Clone, Serialize)]
pub struct LoadReport {
    pub input: String,
    pub jobs: u32,
    pub pid: u32,
    pub runs_started: u64,
    pub runs_completed: u64,
    pub failures: u64,
    /// The loop's own CPU plus its diagnose runs', percent of one core over its life.
    pub cpu_percent: f64,
    pub wall_s: f64,
    /// The loop exited on our SIGTERM, after stopping its runs under way.
    pub stopped: bool,
}

pub(crate) fn start_load(
    input: &Path,
    jobs: u32,
    log: &Path,
) -> anyhow::Result<std::process::Child> {
    let mut c = std::process::Command::new(std::env::current_exe()?);
    c.args(["latency-peer", "load", "--input"])
        .arg(input)
        .args(["--jobs", &jobs.to_string()])
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(vibro_files::open_append(log)?);
    vibro_service::supervise::stop_with_parent(&mut c);
    c.spawn().context("starting the background load")
}

pub(crate) fn stop_load(
    mut child: std::process::Child,
    input: &Path,
    jobs: u32,
) -> anyhow::Result<LoadReport> {
    let pid = child.id();
    vibro_service::supervise::terminate(&child);
    let t = Instant::now();
    let mut status = None;
    while t.elapsed() < Duration::from_secs(10) {
        if let Some(s) = child.try_wait()? {
            status = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    if status.is_none() {
        let _ = child.kill();
        let _ = child.wait();
    }
    let mut out = String::new();
    if let Some(mut o) = child.stdout.take() {
        let _ = o.read_to_string(&mut out);
    }
    let v: serde_json::Value = serde_json::from_str(out.trim()).with_context(|| {
        format!("the background load (pid {pid}) printed no summary: {out:?}; see its log")
    })?;
    let n = |k: &str| v[k].as_u64().unwrap_or(0);
    if n("failures") > 0 {
        bail!(
            "--load {}: `vibrocomp lab diagnose {}` failed: {}",
            input.display(),
            input.display(),
            v["first_failure"].as_str().unwrap_or("(no message)")
        );
    }
    let wall_s = v["wall_s"].as_f64().unwrap_or(0.0);
    Ok(LoadReport {
        input: input.display().to_string(),
        jobs,
        pid,
        runs_started: n("runs_started"),
        runs_completed: n("runs_completed"),
        failures: n("failures"),
        cpu_percent: if wall_s > 0.0 {
            100.0 * v["cpu_s"].as_f64().unwrap_or(0.0) / wall_s
        } else {
            0.0
        },
        wall_s,
        stopped: status.is_some_and(|s| s.success()),
    })
}

/// The load peer (see [`crate::PeerCommand::Load`]).
pub(crate) fn peer_load(input: &Path, jobs: u32) -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let stop = install_stop()?;
    let start = Instant::now();
    let err_path = |k: u64| {
        std::env::temp_dir().join(format!("vibrocomp-load-{}-{k}.err", std::process::id()))
    };
    let (mut started, mut completed, mut failures) = (0u64, 0u64, 0u64);
    let mut first_failure: Option<String> = None;
    let mut running: Vec<(std::process::Child, u64)> = Vec::new();
    while !stop.load(Ordering::Acquire) && failures == 0 {
        while running.len() < jobs as usize {
            let err = err_path(started);
            let mut c = std::process::Command::new(&exe);
            c.args(["lab", "diagnose"])
                .arg(input)
                .stdin(std::process::Stdio::null())
                .stdout(std::process::Stdio::null())
                .stderr(
                    // A name in /tmp anyone may guess: never through a planted link.
                    vibro_files::create_in_place(&err, true)
                        .with_context(|| err.display().to_string())?,
                );
            vibro_service::supervise::stop_with_parent(&mut c);
            let child = c.spawn().with_context(|| {
                format!("starting `vibrocomp lab diagnose {}`", input.display())
            })?;
            running.push((child, started));
            started += 1;
        }
        let mut i = 0;
        while i < running.len() {
            match running[i].0.try_wait()? {
                Some(status) => {
                    let (_, k) = running.swap_remove(i);
                    if status.success() {
                        completed += 1;
                    } else {
                        failures += 1;
                        let text = std::fs::read_to_string(err_path(k)).unwrap_or_default();
                        first_failure.get_or_insert_with(|| format!("{status}: {}", text.trim()));
                    }
                    let _ = std::fs::remove_file(err_path(k));
                }
                None => i += 1,
            }
        }
        // Short: the load's CPU is the diagnose runs', not this loop's waits.
        std::thread::sleep(Duration::from_millis(1));
    }
    for (mut c, k) in running {
        let _ = c.kill();
        let _ = c.wait();
        let _ = std::fs::remove_file(err_path(k));
    }
    let v = serde_json::json!({
        "runs_started": started,
        "runs_completed": completed,
        "failures": failures,
        "first_failure": first_failure,
        "cpu_s": rusage_cpu_s(),
        "wall_s": start.elapsed().as_secs_f64(),
    });
    writeln!(std::io::stdout().lock(), "{v}").context("writing the load's summary on stdout")?;
    Ok(())
}
