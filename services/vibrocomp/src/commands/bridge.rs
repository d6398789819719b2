//! `vibrocomp bridge --config FILE`: forwards the streams the file names between this
//! host's iceoryx2 system and Zenoh (`vibro_bridge`, docs/bridge.md), until Ctrl-C /
//! SIGTERM; `--json` prints every stream's counters at exit.

use anyhow::Context;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use vibro_bridge::BridgeConfig;

#[derive(Debug, Clone, clap::Args)]
pub struct BridgeArgs {
    /// The bridge's configuration (docs/bridge.md; config/bridge/*.toml are examples).
    #[arg(long, value_name = "FILE")]
    pub config: PathBuf,
    /// Service-name prefix of the local system [default: the file's `prefix`].
    #[arg(long)]
    pub prefix: Option<String>,
    /// Print the counters of every stream as JSON at exit.
    #[arg(long)]
    pub json: bool,
}

/// The validated configuration of `args`.
pub fn load(args: &BridgeArgs) -> anyhow::Result<BridgeConfig> {
    let mut config = BridgeConfig::load(&args.config)?;
    if let Some(p) = &args.prefix {
        config = config.with_prefix(p)?;
    }
    Ok(config)
}

pub fn run(args: &BridgeArgs) -> anyhow::Result<()> {
    vibro_service::init_tracing();
    let config = load(args)?;
    let summary = vibro_service::run_service(|shutdown| async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let worker = Arc::clone(&stop);
        // Zenoh's blocking calls and the iceoryx2 loops: on threads of their own,
        // never on a tokio worker.
        std::thread::Builder::new()
            .name("vibrocomp-bridge".into())
            .spawn(move || {
                let _ = tx.send(vibro_bridge::run(&config, &worker));
            })
            .context("spawning the bridge thread")?;
        let watcher = tokio::spawn({
            let stop = Arc::clone(&stop);
            async move {
                shutdown.triggered().await;
                stop.store(true, Ordering::Release);
            }
        });
        let result = rx.await.map_err(|_| {
            anyhow::anyhow!("the bridge thread ended without a result (it panicked)")
        })?;
        watcher.abort();
        Ok(result?)
    })?;
    if args.json {
        return crate::output::print_text(&format!("{}\n", summary.to_json()));
    }
    outln!("bridge {}: lost {}", summary.zenoh_id, summary.lost())?;
    for s in &summary.streams {
        outln!(
            "  {:<22} {:<7} forwarded {:>9}  lost {:>6}",
            s.stream,
            match s.direction {
                vibro_bridge::Direction::Export => "export",
                vibro_bridge::Direction::Import => "import",
            },
            s.forwarded,
            s.lost()
        )?;
    }
    Ok(())
}
