//! `vibrocomp identify`: placeholder replaced by the identification work in this session.

use clap::Subcommand;

#[derive(Debug, Subcommand)]
pub enum IdentifyCommand {
    /// Components from a CSV of test positions.
    Positions {
        /// CSV file of test positions.
        file: std::path::PathBuf,
    },
}

pub fn run(_cmd: IdentifyCommand) -> anyhow::Result<()> {
    anyhow::bail!("vibrocomp identify is being built")
}
