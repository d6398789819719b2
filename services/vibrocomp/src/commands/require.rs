use clap::Args;
#[derive(Debug, Args)]
pub struct RequireArgs {}
pub fn run(_args: RequireArgs) -> anyhow::Result<()> {
    anyhow::bail!("being built")
}
