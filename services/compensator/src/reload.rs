//! Hot reload: a tokio task polls the model files' modification times and sizes, and
//! when one changes reloads and validates the whole configuration off the hot thread,
//! builds the new compensator there (it allocates its tables), and hands both to the
//! hot thread through a channel that the hot loop looks at once per wake-up. An invalid
//! file is logged (file, key, value, rule) and the running model kept.

use crate::config::Config;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::Sender;
use std::sync::Arc;
use std::time::{Duration, SystemTime};
use tokio::time::MissedTickBehavior;
use tracing::{error, info, warn};
use vibro_service::{ServiceConfig, Shutdown};

pub(crate) use crate::core::ModelUpdate;

type Fingerprint = Vec<Option<(SystemTime, u64)>>;

async fn fingerprint(files: &[PathBuf]) -> Fingerprint {
    let mut out = Vec::with_capacity(files.len());
    for f in files {
        let m = tokio::fs::metadata(f).await.ok();
        out.push(m.map(|m| (m.modified().unwrap_or(SystemTime::UNIX_EPOCH), m.len())));
    }
    out
}

/// Watches `path` and the files it references until `shutdown`; counts failed reloads
/// in `errors`.
pub(crate) async fn watch(
    path: PathBuf,
    running: Config,
    poll: Duration,
    updates: Sender<Box<ModelUpdate>>,
    errors: Arc<AtomicU64>,
    shutdown: Shutdown,
) {
    let mut files = running.watched_files.clone();
    let mut seen = fingerprint(&files).await;
    let mut ticks = tokio::time::interval(poll);
    ticks.set_missed_tick_behavior(MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = shutdown.triggered() => return,
            _ = ticks.tick() => {}
        }
        let now = fingerprint(&files).await;
        if now == seen {
            continue;
        }
        seen = now;
        let file = path.clone();
        let loaded = tokio::task::spawn_blocking(move || {
            Config::load(&file).map(|c| {
                let compensator = c.model.compensator();
                (c, compensator)
            })
        })
        .await;
        match loaded {
            Ok(Ok((config, compensator))) => {
                if config.watched_files != files {
                    files = config.watched_files.clone();
                    seen = fingerprint(&files).await;
                }
                note_restart_only_changes(&path, &running, &config);
                info!(
                    file = %path.display(),
                    mode = config.model.mode.name(),
                    triad = %config.model.triad.id,
                    passports = ?config.model.triad.passports.map(|p| p.id().to_string()),
                    max_estimate_age_s = config.model.max_estimate_age_ns as f64 * 1e-9,
                    max_estimate_lead_s = config.model.max_estimate_lead_ns as f64 * 1e-9,
                    "model reloaded"
                );
                let update = ModelUpdate {
                    model: config.model,
                    compensator,
                };
                if updates.send(Box::new(update)).is_err() {
                    return; // the hot loop has ended
                }
            }
            Ok(Err(e)) => {
                errors.fetch_add(1, Ordering::Relaxed);
                error!("{e}; keeping the running model");
            }
            Err(e) => {
                errors.fetch_add(1, Ordering::Relaxed);
                error!(file = %path.display(), "reloading failed: {e}; keeping the running model");
            }
        }
    }
}

fn note_restart_only_changes(path: &Path, running: &Config, new: &Config) {
    if new.as_written.0 != running.as_written.0 {
        warn!(
            file = %path.display(),
            "prefix = {:?}: a new prefix takes effect at the next start; the streams stay under {:?}",
            new.as_written.0,
            running.names.prefix()
        );
    }
    if new.as_written.1 != running.as_written.1 {
        warn!(file = %path.display(), "[service] changes take effect at the next start");
    }
}
