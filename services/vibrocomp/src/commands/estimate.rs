//! `vibrocomp estimate`: placeholder replaced by the estimation work (issue 3) in this session.

use clap::Args;

#[derive(Debug, Args)]
pub struct EstimateArgs {
    /// Input file (CSV).
    pub file: std::path::PathBuf,
}

pub fn run(_args: EstimateArgs) -> anyhow::Result<()> {
    anyhow::bail!("vibrocomp estimate is being built")
}
