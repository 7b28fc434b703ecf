//! The built-in demo (placeholder until the simulator lands).

/// Arguments of `demo`.
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// Output directory.
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
}

/// Runs the demo.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("the demo is not implemented yet")
}
