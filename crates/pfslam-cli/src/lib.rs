//! The commands of the pfslam tools, one module per subcommand: `pfslam` (the user's tool,
//! `src/main.rs`) and `pfslam-dev` (the developers' measurements, `src/bin/pfslam-dev.rs`).
#![forbid(unsafe_code)]

pub mod cmd;

/// The options both binaries take before or after their subcommand.
#[derive(Debug, clap::Args)]
pub struct GlobalArgs {
    /// Log verbosity (error, warn, info, debug, trace).
    #[arg(long, global = true, default_value = "info")]
    pub log: String,
}

/// Logs to standard error at `level` (`info` when it does not parse).
pub fn init_logging(level: &str) {
    let filter = tracing_subscriber::EnvFilter::try_new(level)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

/// The exit code of a command's result: 0 on success; 2, the error printed on stderr, otherwise.
pub fn exit_code(result: anyhow::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::from(2)
        }
    }
}
