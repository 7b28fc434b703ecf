//! `pfslam dead-reckon` (placeholder).

/// Arguments of `dead-reckon`.
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// Dataset directory.
    pub dataset: std::path::PathBuf,
    /// Output directory.
    #[arg(long)]
    pub out: std::path::PathBuf,
}

/// Runs dead reckoning.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("dead-reckon is not implemented yet")
}
