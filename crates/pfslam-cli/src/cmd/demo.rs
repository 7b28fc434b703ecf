//! The built-in demo (`cargo run --release` with no arguments): simulate the seed car in the
//! default campus world, then run every pipeline stage on what was written to disk and report
//! the accuracy against the simulator's ground truth.
//!
//! Each stage is the same code as its subcommand, run on the files the previous stage wrote,
//! so the demo exercises the readers and writers end to end.

use anyhow::Context;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output directory (created if needed; earlier demo outputs in it are replaced).
    #[arg(long, default_value = "pfslam-out")]
    pub out: PathBuf,
    /// Length of the simulated drive (s).
    #[arg(long, default_value_t = 180.0)]
    pub duration_s: f64,
    /// Seed of the simulator and of the filter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of particles (default: the configuration's).
    #[arg(long)]
    pub particles: Option<usize>,
    /// Stereo pair rate of the simulation (Hz; 0 = no stereo, no texture). Each pair costs
    /// ~1 s to render and ~0.6 s to match on 2 cores, hence the low default.
    #[arg(long, default_value_t = DEMO_STEREO_RATE_HZ)]
    pub stereo_rate_hz: f64,
}

/// One pair every 10 s: ~18 pairs over the default drive, the texture of ~18 stretches of road.
const DEMO_STEREO_RATE_HZ: f64 = 0.1;

impl Default for Args {
    fn default() -> Self {
        Args {
            out: PathBuf::from("pfslam-out"),
            duration_s: 180.0,
            seed: 1,
            particles: None,
            stereo_rate_hz: DEMO_STEREO_RATE_HZ,
        }
    }
}

fn stage(n: usize, what: &str) {
    say!();
    say!("== {n}/4 {what}");
}

/// The demo's output folders, one per stage.
struct StageDirs {
    sim: PathBuf,
    dead_reckoning: PathBuf,
    map: PathBuf,
    slam: PathBuf,
}

/// Runs the demo.
pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.duration_s.is_finite() && args.duration_s > 0.0) {
        anyhow::bail!("--duration-s must be positive, got {}", args.duration_s);
    }
    if args.particles == Some(0) {
        anyhow::bail!("--particles must be at least 1");
    }
    let t0 = Instant::now();
    let out = &args.out;
    let dirs = StageDirs {
        sim: out.join("sim"),
        dead_reckoning: out.join("dead_reckoning"),
        map: out.join("map_ground_truth"),
        slam: out.join("slam"),
    };
    say!(
        "pfslam demo: simulating {} s of the seed car in the built-in campus world, then dead \
         reckoning, mapping with known poses, particle-filter SLAM and the ground's colours from \
         the stereo pairs along the SLAM path; outputs in {}",
        args.duration_s,
        out.display()
    );
    simulate(&args, &dirs)?;
    dead_reckon(&dirs)?;
    map_with_true_poses(&dirs)?;
    run_slam(&args, &dirs)?;

    say!();
    say!("== summary ({:.1} s)", t0.elapsed().as_secs_f64());
    print_summary(&dirs.slam.join("summary.json"))?;
    say!("pictures:");
    for p in [
        dirs.sim.join("true_map.png"),
        dirs.dead_reckoning.join("trajectory.png"),
        dirs.map.join("map.png"),
        dirs.slam.join("map.png"),
        dirs.slam.join("binary_map.png"),
        dirs.slam.join("texture.png"),
    ] {
        if p.is_file() {
            say!("  {}", p.display());
        }
    }
    Ok(())
}

/// Stage 1: `simulate` of the seed car in its default world.
fn simulate(args: &Args, dirs: &StageDirs) -> anyhow::Result<()> {
    stage(1, "simulate");
    super::simulate::run(super::simulate::Args {
        vehicle: None,
        world: None,
        duration_s: Some(args.duration_s),
        seed: Some(args.seed),
        stereo_rate_hz: Some(args.stereo_rate_hz),
        noise_free: false,
        config: None,
        out: dirs.sim.clone(),
    })
    .context("simulate")
}

/// Stage 2: `dead-reckon` on the simulated dataset.
fn dead_reckon(dirs: &StageDirs) -> anyhow::Result<()> {
    stage(2, "dead reckoning (wheel encoders + FOG)");
    super::dead_reckon::run(super::dead_reckon::Args {
        dataset: dirs.sim.clone(),
        out: dirs.dead_reckoning.clone(),
        config: None,
        sort_timestamps: false,
        input: Default::default(),
    })
    .context("dead-reckon")
}

/// Stage 3: `map` along the ground-truth poses, the dead reckoning drawn over it, compared
/// with the true map.
fn map_with_true_poses(dirs: &StageDirs) -> anyhow::Result<()> {
    stage(3, "occupancy map with the ground-truth poses");
    super::map::run(super::map::Args {
        dataset: dirs.sim.clone(),
        poses: dirs.sim.join("ground_truth.tum"),
        out: dirs.map.clone(),
        config: None,
        resolution: None,
        preset: None,
        z_min: None,
        z_max: None,
        overlays: vec![format!(
            "dead reckoning={}",
            dirs.dead_reckoning.join("trajectory.tum").display()
        )],
        truth: Some(dirs.sim.join("true_map.yaml")),
        tolerance_cells: 1,
        input: Default::default(),
    })
    .context("map")
}

/// Stage 4: `run` on the simulated dataset (with the texture when it has stereo pairs).
fn run_slam(args: &Args, dirs: &StageDirs) -> anyhow::Result<()> {
    stage(
        4,
        "particle-filter SLAM (and texture mapping when there are stereo pairs)",
    );
    super::run::run(super::run::Args {
        dataset: dirs.sim.clone(),
        config: None,
        particles: args.particles,
        seed: args.seed,
        out: dirs.slam.clone(),
        sort_timestamps: false,
        graph_on_odometry: false,
        input: Default::default(),
        ..Default::default()
    })
    .context("run")
}

/// Prints the accuracy figures of a `run` summary.
fn print_summary(path: &Path) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let v: serde_json::Value = serde_json::from_str(&text)?;
    let rmse = |key: &str| v[key]["ate"]["aligned_m"]["rmse"].as_f64();
    if let (Some(slam), Some(dr)) = (
        rmse("slam_vs_ground_truth"),
        rmse("dead_reckoning_vs_ground_truth"),
    ) {
        say!(
            "ATE RMSE vs ground truth (SE(2)-aligned): SLAM {slam:.3} m, dead reckoning {dr:.3} m \
             (SLAM/DR = {:.2})",
            slam / dr
        );
    }
    for (key, how) in [
        ("map_vs_true_map", "as written"),
        (
            "map_vs_true_map_aligned",
            "through the ATE's SE(2) alignment",
        ),
    ] {
        if let Some(m) = v.get(key) {
            say!(
                "SLAM map vs true map (1 cell), {how}: precision {:.3}, recall {:.3}",
                m["precision"].as_f64().unwrap_or(f64::NAN),
                m["recall"].as_f64().unwrap_or(f64::NAN)
            );
        }
    }
    Ok(())
}
