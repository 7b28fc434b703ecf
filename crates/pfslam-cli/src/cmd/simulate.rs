//! `pfslam simulate`: simulate the car (or the humanoid) in a built-in or user world and
//! write the dataset with its ground truth.

use anyhow::Context;
use pfslam_sim::{SimOptions, Vehicle, World};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Vehicle: `car` (the seed car, default) or `humanoid`.
    #[arg(long, value_parser = ["car", "humanoid"])]
    pub vehicle: Option<String>,
    /// Built-in world (`campus`, `office`) or a world file; default: the vehicle's world.
    #[arg(long)]
    pub world: Option<String>,
    /// Length of the recording (s); the default is the config's (180 s).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Random seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Switch every simulated error off (exact sensors, true wheels = calibrated).
    #[arg(long)]
    pub noise_free: bool,
    /// Stereo pair rate (Hz; overrides `[sim.car] stereo_rate_hz`; 0 = none). Each pair is
    /// ray-cast (~1 s on 2 cores), so keep it low for long drives.
    #[arg(long)]
    pub stereo_rate_hz: Option<f64>,
    /// Configuration file (TOML); its `[sim]` section sets every simulator option. A
    /// `sim.toml` written by an earlier run reproduces that run.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
}

/// Resolves the options: config file (or defaults), then the flags.
pub fn options(args: &Args) -> anyhow::Result<SimOptions> {
    let mut opts = match &args.config {
        Some(p) => pfslam::config::Config::from_toml_file(p)?.sim,
        None => SimOptions::default(),
    };
    if args.noise_free {
        opts.car = pfslam_sim::CarSimOptions::noise_free();
        opts.humanoid = pfslam_sim::HumanoidSimOptions::noise_free();
    }
    if let Some(v) = &args.vehicle {
        opts.vehicle = if v == "humanoid" {
            Vehicle::Humanoid
        } else {
            Vehicle::Car
        };
    }
    if let Some(w) = &args.world {
        opts.world = w.clone();
    }
    if let Some(d) = args.duration_s {
        opts.duration_s = d;
    }
    if let Some(s) = args.seed {
        opts.seed = s;
    }
    if let Some(r) = args.stereo_rate_hz {
        opts.car.stereo_rate_hz = r;
    }
    opts.validate()?;
    Ok(opts)
}

/// Runs the simulation and writes everything into `--out`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = options(&args)?;
    let world = World::from_name_or_file(opts.world_name())?;
    let t0 = Instant::now();
    match opts.vehicle {
        Vehicle::Car => {
            let out = pfslam_sim::simulate_car(&world, &opts)?;
            let t_sim = t0.elapsed().as_secs_f64();
            pfslam_sim::dataset::write_car_sim(&args.out, &out)
                .with_context(|| format!("writing {}", args.out.display()))?;
            let t_all = t0.elapsed().as_secs_f64();
            let ds = &out.dataset;
            say!(
                "simulated the car in world {:?} for {:.1} s ({:.0} m driven): {} encoder rows, {} FOG rows, {} LiDAR scans, {} stereo pairs",
                world.name,
                opts.duration_s,
                out.distance_m,
                ds.encoder.len(),
                ds.fog.len(),
                ds.lidar.len(),
                out.stereo_poses.len()
            );
            say!(
                "simulation {t_sim:.2} s, simulation + writing{} {t_all:.2} s; wrote {}",
                if out.stereo_poses.is_empty() {
                    ""
                } else {
                    " + rendering the stereo pairs"
                },
                args.out.display()
            );
        }
        Vehicle::Humanoid => {
            let out = pfslam_sim::simulate_humanoid(&world, &opts)?;
            let t_sim = t0.elapsed().as_secs_f64();
            pfslam_sim::dataset::write_humanoid_sim(&args.out, &out)
                .with_context(|| format!("writing {}", args.out.display()))?;
            let t_all = t0.elapsed().as_secs_f64();
            say!(
                "simulated the humanoid in world {:?} for {:.1} s ({:.0} m walked): {} odometry rows, {} scans ({} beams marked as floor hits)",
                world.name,
                opts.duration_s,
                out.distance_m,
                out.dataset.odometry.len(),
                out.dataset.lidar.len(),
                out.ground_beam_count()
            );
            say!(
                "simulation {t_sim:.2} s, simulation + writing {t_all:.2} s; wrote {}",
                args.out.display()
            );
        }
    }
    Ok(())
}
