//! What a service's `main` needs besides its library: logging, a tokio runtime that
//! turns SIGINT/SIGTERM into the [`Shutdown`] signal, and [`main_with`], which puts
//! them together with the configuration and the command line.

use crate::{ServiceArgs, ServiceConfig, Shutdown};
use anyhow::Context;
use std::future::Future;
use tokio::signal::unix::{signal, SignalKind};

/// Runs `work` on a thread of its own named `name` until it returns: blocking code (an
/// iceoryx2 loop, Zenoh's blocking calls, file I/O) never runs on a tokio worker. A
/// shutdown (SIGINT, SIGTERM) sets the flag `work` polls, which should then end soon.
/// Its result, or an error naming the thread if it panicked.
pub async fn on_own_thread<T, W>(name: &str, shutdown: Shutdown, work: W) -> anyhow::Result<T>
where
    T: Send + 'static,
    W: FnOnce(&std::sync::atomic::AtomicBool) -> T + Send + 'static,
{
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    let (tx, rx) = tokio::sync::oneshot::channel();
    let stop = Arc::new(AtomicBool::new(false));
    let worker = Arc::clone(&stop);
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            let _ = tx.send(work(&worker));
        })
        .with_context(|| format!("spawning the {name} thread"))?;
    let watcher = tokio::spawn(async move {
        shutdown.triggered().await;
        stop.store(true, Ordering::Release);
    });
    let result = rx
        .await
        .map_err(|_| anyhow::anyhow!("the {name} thread ended without a result (it panicked)"));
    watcher.abort();
    result
}

/// Logs to stderr, INFO by default, `RUST_LOG` to change it; the same lines go to the
/// service's log stream once [`crate::logstream::start`]ed. Safe to call twice.
pub fn init_tracing() {
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(colour_on_stderr()),
        )
        .with(crate::logstream::ForwardLayer)
        .try_init();
}

/// Whether log lines may carry colour: only on a terminal, and never when `NO_COLOR`
/// is set to anything but the empty string (<https://no-color.org>). Files, pipes and
/// a supervisor's log get plain text.
pub fn colour_on_stderr() -> bool {
    use std::io::IsTerminal;
    let no_color = std::env::var_os("NO_COLOR").is_some_and(|v| !v.is_empty());
    !no_color && std::io::stderr().is_terminal()
}

/// How long after the first stop signal further signals are taken as repeats of it.
pub const SAME_REQUEST: std::time::Duration = std::time::Duration::from_secs(1);

/// Runs `service(shutdown)` on a tokio runtime with SIGINT and SIGTERM handled: the first
/// signal triggers `shutdown` (the service stops its loop, releases its ports and
/// returns), a second one exits at once with 128 + the signal number. Signals within
/// [`SAME_REQUEST`] of the first count as the same request (a terminal's Ctrl-C and a
/// supervisor's SIGTERM arrive together).
///
/// The handlers are installed before `service` starts, so a signal can never hit the
/// default action (process death without releasing shared memory) once this runs.
pub fn run_service<F, Fut, T>(service: F) -> anyhow::Result<T>
where
    F: FnOnce(Shutdown) -> Fut,
    Fut: Future<Output = anyhow::Result<T>>,
{
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("vibro-tokio")
        .enable_all()
        .build()
        .context("starting the tokio runtime")?;
    runtime.block_on(async move {
        let shutdown = Shutdown::new();
        let mut interrupt =
            signal(SignalKind::interrupt()).context("installing the SIGINT handler")?;
        let mut terminate =
            signal(SignalKind::terminate()).context("installing the SIGTERM handler")?;
        let signals = tokio::spawn({
            let shutdown = shutdown.clone();
            async move {
                let mut first_at: Option<std::time::Instant> = None;
                loop {
                    let number = tokio::select! {
                        _ = interrupt.recv() => libc::SIGINT,
                        _ = terminate.recv() => libc::SIGTERM,
                    };
                    match first_at {
                        None => {
                            tracing::info!(
                                signal = number,
                                "shutting down (a second signal exits at once)"
                            );
                            shutdown.trigger();
                            first_at = Some(std::time::Instant::now());
                        }
                        // One request delivered more than once: Ctrl-C in a terminal
                        // reaches the whole process group and `vibrocomp up` then sends
                        // SIGTERM too; a dying parent's `PR_SET_PDEATHSIG` arrives once
                        // per reparenting.
                        Some(at) if at.elapsed() < SAME_REQUEST => {
                            tracing::debug!(signal = number, "signal repeated: already stopping");
                        }
                        Some(_) => {
                            tracing::warn!(
                                signal = number,
                                "second signal: exiting without cleanup"
                            );
                            std::process::exit(128 + number);
                        }
                    }
                }
            }
        });
        let result = service(shutdown).await;
        signals.abort();
        result
    })
}

/// A service's final summary, as `--json` prints it.
pub trait ServiceSummary {
    /// The summary as one JSON object.
    fn to_json(&self) -> String;
}

/// What a service's binary (and `vibrocomp service <name>`) does with its command line:
/// loads the configuration (`--config FILE`, else [`ServiceConfig::load_default`]),
/// applies `--prefix`, `--mode` and `--realtime-priority`, runs `run_async(config, shutdown)` under
/// [`run_service`] until SIGINT/SIGTERM, and prints the summary's JSON on stdout with
/// `--json`.
pub fn main_with<C, S, F, Fut>(args: &ServiceArgs, run_async: F) -> anyhow::Result<()>
where
    C: ServiceConfig,
    S: ServiceSummary,
    F: FnOnce(C, Shutdown) -> Fut,
    Fut: Future<Output = anyhow::Result<S>>,
{
    let mut config = match &args.config {
        Some(path) => C::load(path)?,
        None => C::load_default()?,
    };
    if let Some(prefix) = &args.prefix {
        config = config.with_prefix(prefix)?;
    }
    if let Some(mode) = args.mode {
        config.service_mut().loop_mode = mode;
    }
    if let Some(priority) = args.realtime_priority {
        config.service_mut().realtime_priority = Some(priority);
    }
    let log_stream = config.log_stream();
    let summary = run_service(|shutdown| async move {
        // The log lines on `{prefix}log/{service}` while the service runs (stderr only
        // if the stream cannot be opened). Opened once the signal handlers are in
        // place, and released before the runtime ends, as every port is.
        let _log_stream = match log_stream {
            Some((names, service)) => match crate::logstream::start(&names, service) {
                Ok(s) => Some(s),
                Err(e) => {
                    tracing::warn!("log lines to stderr only: {e:#}");
                    None
                }
            },
            None => None,
        };
        run_async(config, shutdown).await
    })?;
    if args.json {
        println!("{}", summary.to_json());
    }
    Ok(())
}
