//! `pfslam`: the command-line front end of the pfslam library.
//!
//! Arguments are parsed by clap and validated into a configuration before any work starts.
//! Exit codes: 0 success, 2 any error (bad input, bad arguments, failed output).
#![forbid(unsafe_code)]

use clap::{Parser, Subcommand};
use pfslam_cli::cmd;
use std::process::ExitCode;

/// Particle-filter SLAM for 2-D LiDAR: dead reckoning, occupancy mapping, SLAM, evaluation.
#[derive(Debug, Parser)]
#[command(name = "pfslam", version, about, long_about = None)]
pub struct Cli {
    /// What to do; with no subcommand, runs the built-in demo on the simulator.
    #[command(subcommand)]
    pub command: Option<Command>,
    /// Options of every command.
    #[command(flatten)]
    pub global: pfslam_cli::GlobalArgs,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Simulate, dead-reckon, map and run SLAM on the built-in world (the default).
    Demo(cmd::demo::Args),
    /// Dead-reckon a dataset: trajectory.tum/.csv/.png.
    DeadReckon(cmd::dead_reckon::Args),
    /// Describe a recording: format, topics or line types, beam layouts, odometry, clock,
    /// what was dropped or repaired, and what `run` would use.
    Info(cmd::info::Args),
    /// Write a recording with its odometry degraded (severity 0-3) as a CARMEN log, and the
    /// reference trajectory beside it.
    Perturb(cmd::perturb::Args),
    /// Occupancy mapping with known poses: map.png, map.pgm/.yaml, logodds.npy.
    Map(cmd::map::Args),
    /// Simulate the car (or the humanoid) in a world: dataset + ground truth.
    Simulate(cmd::simulate::Args),
    /// Particle-filter SLAM on a dataset: trajectory, maps, summary.
    Run(cmd::run::Args),
    /// Monte Carlo localisation in a saved map (map_server pgm + yaml from any tool):
    /// trajectory, map with the path, summary.
    Localize(cmd::localize::Args),
    /// SLAM on every Freiburg recording with relations: one accuracy table.
    Benchmark(cmd::benchmark::Args),
    /// Colour the ground from the car's stereo pairs along a trajectory: texture.png/.npy.
    Texture(cmd::texture::Args),
    /// Print the full default configuration as TOML.
    PrintConfig(cmd::print_config::Args),
    /// Accuracy of a trajectory: ATE/RPE against ground truth, or the relations metric.
    Eval(cmd::eval::Args),
}

/// Runs the CLI on already-parsed arguments.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    pfslam_cli::init_logging(&cli.global.log);
    match cli.command {
        None => cmd::demo::run(cmd::demo::Args::default()),
        Some(Command::Demo(a)) => cmd::demo::run(a),
        Some(Command::DeadReckon(a)) => cmd::dead_reckon::run(a),
        Some(Command::Info(a)) => cmd::info::run(a),
        Some(Command::Perturb(a)) => cmd::perturb::run(a),
        Some(Command::PrintConfig(a)) => cmd::print_config::run(a),
        Some(Command::Run(a)) => cmd::run::run(a),
        Some(Command::Localize(a)) => cmd::localize::run(a),
        Some(Command::Eval(a)) => cmd::eval::run(a),
        Some(Command::Simulate(a)) => cmd::simulate::run(a),
        Some(Command::Map(a)) => cmd::map::run(a),
        Some(Command::Texture(a)) => cmd::texture::run(a),
        Some(Command::Benchmark(a)) => cmd::benchmark::run(a),
    }
}

fn main() -> ExitCode {
    pfslam::kernels::allocator::unmap_large_blocks();
    cmd::interrupt::install();
    let cli = Cli::parse();
    pfslam_cli::exit_code(run(cli))
}
