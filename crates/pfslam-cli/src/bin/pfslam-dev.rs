//! `pfslam-dev`: the developers' measurements, kept out of the user's `pfslam`: end-to-end
//! speed on the full-size simulated car and the seed report's experiment tables.
//!
//! Exit codes: 0 success, 2 any error.
#![forbid(unsafe_code)]

use clap::{Parser, Subcommand};
use pfslam_cli::cmd;
use std::process::ExitCode;

/// Developer measurements of pfslam: speed and the seed report's experiments.
#[derive(Debug, Parser)]
#[command(name = "pfslam-dev", version, about, long_about = None)]
pub struct Cli {
    /// What to measure.
    #[command(subcommand)]
    pub command: Command,
    /// Options of every command.
    #[command(flatten)]
    pub global: pfslam_cli::GlobalArgs,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// End-to-end speed: simulate the full-size car recording once, then time read -> SLAM
    /// -> write maps (median of N runs, CPU time, peak memory).
    BenchE2e(cmd::bench_e2e::Args),
    /// Reproduce an experiment table (`seeds`: particles x Table 1 noise on the simulator).
    Experiment(cmd::experiment::Args),
}

fn main() -> ExitCode {
    pfslam::kernels::allocator::unmap_large_blocks();
    cmd::interrupt::install();
    let cli = Cli::parse();
    pfslam_cli::init_logging(&cli.global.log);
    pfslam_cli::exit_code(match cli.command {
        Command::BenchE2e(a) => cmd::bench_e2e::run(a),
        Command::Experiment(a) => cmd::experiment::run(a),
    })
}
