//! `pfslam print-config`.

use pfslam::config::Config;

/// Arguments of `print-config`.
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// Print this file's configuration resolved over the defaults instead.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Leave out the comments.
    #[arg(long)]
    pub bare: bool,
}

/// Prints the resolved configuration, each key preceded by its documentation.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(p) => Config::from_toml_file(p)?,
        None => Config::default(),
    };
    let text = if args.bare {
        config.to_toml()
    } else {
        config.to_annotated_toml()
    };
    super::print_stdout(&text)
}
