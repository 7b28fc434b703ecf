//! `pfslam experiment seeds --out DIR`: the seeds' experiment table on the simulated car:
//! particles {1, 5, 40, 100} x the UCSD seed's Table 1 velocity-noise levels, ATE and time
//! per configuration, written as `seeds_table.md` and `seeds_table.json`.

use anyhow::Context;
use pfslam::config::Config;
use pfslam::eval::{Association, ate::ate};
use pfslam::geometry::{StampedPose2, Trajectory};
use pfslam::motion::VelocityNoise;
use pfslam::slam::{anchor_odometry_to_ground_truth, run_slam};
use pfslam_sim::{SimOptions, World, simulate_car};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Arguments of `experiment`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Which experiment: `seeds` (the only one so far).
    #[arg(value_parser = ["seeds"])]
    pub which: String,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// TOML configuration over the defaults (its `[sim]` and `[filter]` apply; particles and
    /// noise are set by the table).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Length of the simulated drive (s); default: the config's `[sim] duration_s`.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Particle counts (comma separated).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 5, 40, 100])]
    pub particles: Vec<usize>,
    /// Seed of the filter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

fn ate_rmse(est: &[StampedPose2], gt: &[StampedPose2]) -> anyhow::Result<f64> {
    Ok(ate(
        &Trajectory::new(est.to_vec()),
        &Trajectory::new(gt.to_vec()),
        Association::Nearest { tolerance_ns: 1000 },
    )?
    .aligned_m
    .rmse)
}

/// The velocity-noise levels of the table: the UCSD seed's Table 1.
fn noise_levels() -> [(&'static str, VelocityNoise); 3] {
    [
        (
            "Table 1 #1 (var 0.5 / 0.05)",
            VelocityNoise::seed_iteration_1(),
        ),
        (
            "Table 1 #2 (var 1 / 0.05)",
            VelocityNoise::seed_iteration_2(),
        ),
        (
            "Table 1 #3 (var 2 / 0.1)",
            VelocityNoise::seed_iteration_3(),
        ),
    ]
}

/// Runs the experiment.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = experiment_config(&args)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let sim: SimOptions = config.sim.clone();
    let world = World::from_name_or_file(sim.world_name())?;
    let out = simulate_car(&world, &sim)?;
    let mut rec = out.recording(&config.motion)?;
    anchor_odometry_to_ground_truth(&mut rec);
    let (rows, dr_ate) = run_table(&rec, &out.ground_truth, &config, &args)?;
    let drive = Drive {
        sim: &sim,
        distance_m: out.distance_m,
        scans: rec.scans.len(),
        seed: args.seed,
        dr_ate,
    };
    let md = markdown_table(&drive, &rows);
    pfslam_io::write_bytes_atomic(&args.out.join("seeds_table.md"), md.as_bytes())?;
    let json = serde_json::json!({
        "world": sim.world_name(),
        "duration_s": sim.duration_s,
        "distance_m": out.distance_m,
        "scans": rec.scans.len(),
        "seed": args.seed,
        "dead_reckoning_ate_rmse_m": dr_ate,
        "config": config,
        "rows": rows,
    });
    pfslam_io::write_bytes_atomic(
        &args.out.join("seeds_table.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    print!("{md}");
    Ok(())
}

/// The configuration of the experiment: `--config` or the seeds', with `--duration-s`;
/// checks the particle counts and the filter options.
fn experiment_config(args: &Args) -> anyhow::Result<Config> {
    let mut config = match &args.config {
        Some(p) => Config::from_toml_file(p)?,
        None => pfslam::slam::seed_config(),
    };
    if let Some(d) = args.duration_s {
        config.sim.duration_s = d;
    }
    anyhow::ensure!(
        args.particles.iter().all(|&n| n > 0),
        "--particles: counts must be >= 1"
    );
    config.filter.validate()?;
    Ok(config)
}

/// One filter run per noise level and particle count on `rec`: the table's rows, and the
/// dead reckoning's ATE against `gt` (the same for every run).
fn run_table(
    rec: &pfslam::sensors::Recording,
    gt: &[StampedPose2],
    config: &Config,
    args: &Args,
) -> anyhow::Result<(Vec<serde_json::Value>, f64)> {
    let mut rows = Vec::new();
    let mut dr_ate = f64::NAN;
    for (label, noise) in noise_levels() {
        for &n in &args.particles {
            let mut c = config.clone();
            c.filter.particles = n;
            c.motion.noise = noise;
            let res = run_slam(rec, &c, args.seed, &mut |_| {})?;
            let slam = ate_rmse(&res.trajectory, gt)?;
            dr_ate = ate_rmse(&res.dead_reckoning, gt)?;
            let t = res.stats.timings.total_s;
            say!("{label}, {n} particles: ATE {slam:.3} m, {t:.2} s");
            rows.push(serde_json::json!({
                "noise": label,
                "sigma_v_mps": noise.sigma_v_mps,
                "sigma_omega_radps": noise.sigma_omega_radps,
                "particles": n,
                "ate_rmse_m": slam,
                "slam_time_s": t,
                "neff_mean": res.stats.neff_mean,
                "resamples": res.stats.resamples,
            }));
        }
    }
    Ok((rows, dr_ate))
}

/// The simulated drive the table was measured on, for its heading.
struct Drive<'a> {
    sim: &'a SimOptions,
    distance_m: f64,
    scans: usize,
    seed: u64,
    dr_ate: f64,
}

/// `seeds_table.md`: the drive, then one line per row.
fn markdown_table(drive: &Drive<'_>, rows: &[serde_json::Value]) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Simulated car, world {}, {:.0} s drive ({:.0} m, {} scans), seed {}; dead reckoning ATE RMSE {:.3} m.\n",
        drive.sim.world_name(),
        drive.sim.duration_s,
        drive.distance_m,
        drive.scans,
        drive.seed,
        drive.dr_ate
    );
    let _ = writeln!(
        md,
        "| velocity noise | particles | SLAM ATE RMSE (m) | SLAM time (s) |"
    );
    let _ = writeln!(md, "|---|---|---|---|");
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {:.3} | {:.2} |",
            r["noise"].as_str().unwrap_or(""),
            r["particles"],
            r["ate_rmse_m"].as_f64().unwrap_or(f64::NAN),
            r["slam_time_s"].as_f64().unwrap_or(f64::NAN)
        );
    }
    md
}
