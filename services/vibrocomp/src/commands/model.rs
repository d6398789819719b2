use clap::Subcommand;
#[derive(Debug, Subcommand)]
pub enum ModelCommand {
    /// VE components.
    Ve,
}
pub fn run(_cmd: ModelCommand) -> anyhow::Result<()> {
    anyhow::bail!("being built")
}
