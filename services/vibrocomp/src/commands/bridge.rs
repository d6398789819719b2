//! `vibrocomp bridge --config FILE`: forwards the streams the file names between this
//! host's iceoryx2 system and Zenoh (`vibro_bridge`, docs/bridge.md), until Ctrl-C /
//! SIGTERM; `--json` prints every stream's counters at exit.

use std::path::PathBuf;
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
    // Zenoh's blocking calls and the iceoryx2 loops: on a thread of their own.
    let summary = vibro_service::run_service(|shutdown| async move {
        let result = vibro_service::on_own_thread("vibrocomp-bridge", shutdown, move |stop| {
            vibro_bridge::run(&config, stop)
        })
        .await?;
        Ok(result?)
    })?;
    if args.json {
        return crate::output::print_text(&format!("{}\n", summary.to_json()));
    }
    outln!("bridge {}: lost {}", summary.zenoh_id, summary.lost())?;
    for s in &summary.streams {
        // `seq` jumps (a corrupt or forged counter, not in `lost`) only when seen.
        let jumps = if s.seq_jumps > 0 {
            format!("  seq jumps {}", s.seq_jumps)
        } else {
            String::new()
        };
        outln!(
            "  {:<22} {:<7} forwarded {:>9}  lost {:>6}{jumps}",
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
