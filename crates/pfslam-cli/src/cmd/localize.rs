//! `pfslam localize RECORDING --map MAP.yaml --out DIR`: Monte Carlo localisation in a fixed
//! map (a ROS map_server pair from any tool).
//!
//! Writes `trajectory.tum` (a pose at every scan), `map.png` (the map with the path),
//! `updates.csv` (particles, fit and convergence at every update) and `summary.json` (convergence, particle counts, timings, the self-check).

use anyhow::Context;
use pfslam::geometry::{Pose2, StampedPose2};
use pfslam::localize::{LocalizeQuality, LocalizeResult, localize_timed};
use pfslam_io::map_files::read_map_server;
use pfslam_io::tum::{format_stamp_s, write_tum};
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, write_map_png};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `localize`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recording (ROS bag, MCAP, CARMEN log, car dataset directory).
    pub recording: PathBuf,
    /// The map: a map_server yaml (its pgm beside it).
    #[arg(long)]
    pub map: PathBuf,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// The pose at the first scan, `X,Y,YAW_DEG` in the map's frame; without it the filter
    /// localises globally over the map's free space.
    #[arg(long, allow_hyphen_values = true)]
    pub initial_pose: Option<String>,
    /// Most particles (overrides `[localize] max_particles`).
    #[arg(long)]
    pub particles: Option<usize>,
    /// TOML configuration over the defaults (see `pfslam print-config`, `[localize]`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seed of the filter's random streams.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Input selection and strictness.
    #[command(flatten)]
    pub input: super::input::InputArgs,
}

/// `X,Y,YAW_DEG` as a pose.
pub(super) fn parse_pose(text: &str) -> anyhow::Result<Pose2> {
    let v: Vec<f64> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--initial-pose {text:?}: expected X,Y,YAW_DEG"))?;
    match v[..] {
        [x, y, yaw] if v.iter().all(|a| a.is_finite()) => Ok(Pose2::new(x, y, yaw.to_radians())),
        _ => anyhow::bail!("--initial-pose {text:?}: expected three finite numbers X,Y,YAW_DEG"),
    }
}

/// Localises and writes the outputs.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = args.input.config(args.config.as_deref())?;
    if let Some(n) = args.particles {
        config.localize.max_particles = n;
        config.localize.min_particles = config.localize.min_particles.min(n);
    }
    let initial_pose = args.initial_pose.as_deref().map(parse_pose).transpose()?;
    config.validate()?;
    let staging = super::output::Staging::new(&args.out)?;
    let t_load = Instant::now();
    let map = read_map_server(&args.map)?;
    let dataset = super::dataset::load_dataset(&args.recording, &config, false)
        .with_context(|| format!("loading {}", args.recording.display()))?;
    super::input::report(&dataset.account);
    let recording = &dataset.recording;
    let load_s = t_load.elapsed().as_secs_f64();
    let t = Instant::now();
    let (result, odometry_timing) = localize_timed(
        recording,
        &map,
        &config.localize,
        &config.map.scan,
        initial_pose,
        args.seed,
        config.input.odometry_shift_s,
    )?;
    let localize_s = t.elapsed().as_secs_f64();
    let quality = LocalizeQuality::assess(&result);
    let out = staging.path().to_path_buf();
    write_tum(&out.join("trajectory.tum"), &result.trajectory)?;
    write_updates(&out.join("updates.csv"), &result)?;
    let path: Vec<Pose2> = result.trajectory.iter().map(|p| p.pose).collect();
    write_map_png(
        &out.join("map.png"),
        &map.to_grid()?,
        &[TrajectoryOverlay {
            label: "localised",
            poses: &path,
        }],
        None,
        &MapImageOptions::default(),
    )?;
    let mut summary = summary(&args, &config, &result, &quality, [load_s, localize_s]);
    summary["odometry_timing"] = serde_json::to_value(odometry_timing)?;
    summary["input"] = serde_json::to_value(&dataset.account)?;
    let text = serde_json::to_string_pretty(&summary)?;
    pfslam_io::write_bytes_atomic(&out.join("summary.json"), text.as_bytes())?;
    staging.commit()?;
    report(&recording.name, &result, &summary, localize_s);
    for reason in &quality.reasons {
        eprintln!("warning: suspect result: {reason}");
    }
    Ok(())
}

/// One line per filter update: what the particles did.
fn write_updates(path: &std::path::Path, result: &LocalizeResult) -> anyhow::Result<()> {
    let mut text =
        String::from("stamp_s,particles,injected,mass,fit,core_fit,converged,off_wall_share\n");
    for u in &result.updates {
        text.push_str(&format!(
            "{},{},{},{:.4},{:.4},{:.4},{},{:.4}\n",
            format_stamp_s(u.stamp_ns),
            u.particles,
            u.injected,
            u.mass,
            u.fit,
            u.core_fit,
            u64::from(u.converged),
            u.off_wall_share
        ));
    }
    pfslam_io::write_bytes_atomic(path, text.as_bytes())?;
    Ok(())
}

/// Seconds from the first pose to `stamp_ns`.
fn since_start_s(trajectory: &[StampedPose2], stamp_ns: i64) -> f64 {
    trajectory
        .first()
        .map_or(0.0, |p| (stamp_ns - p.stamp_ns) as f64 * 1e-9)
}

fn summary(
    args: &Args,
    config: &pfslam::config::Config,
    result: &LocalizeResult,
    quality: &LocalizeQuality,
    [load_s, localize_s]: [f64; 2],
) -> serde_json::Value {
    let traj = &result.trajectory;
    let duration_s = match (traj.first(), traj.last()) {
        (Some(a), Some(b)) => (b.stamp_ns - a.stamp_ns) as f64 * 1e-9,
        _ => 0.0,
    };
    let mut counts: Vec<usize> = result.updates.iter().map(|u| u.particles).collect();
    counts.sort_unstable();
    let pick = |q: f64| {
        counts
            .get(((counts.len() as f64 - 1.0) * q) as usize)
            .copied()
    };
    serde_json::json!({
        "recording": args.recording.display().to_string(),
        "map": args.map.display().to_string(),
        "seed": args.seed,
        "initial_pose": args.initial_pose,
        "config": config.localize,
        "scans": traj.len(),
        "scans_outside_odometry": result.scans_outside_odometry,
        "scans_without_returns": result.scans_without_returns,
        "scans_stale": result.scans_stale,
        "updates": result.updates.len(),
        "first_converged_at_s": result.first_converged_ns().map(|t| since_start_s(traj, t)),
        "converged_at_s": result.converged_from_ns().map(|t| since_start_s(traj, t)),
        "convergence_losses": result.convergence_losses(),
        "particles": {
            "first": result.updates.first().map(|u| u.particles),
            "min": pick(0.0), "median": pick(0.5), "max": pick(1.0),
            "last": result.updates.last().map(|u| u.particles),
        },
        "injected_total": result.updates.iter().map(|u| u.injected).sum::<usize>(),
        "duration_s": duration_s,
        "realtime_factor": duration_s / localize_s.max(1e-9),
        "quality": quality,
        "timings_s": { "load": load_s, "localize": localize_s },
    })
}

fn report(name: &str, result: &LocalizeResult, summary: &serde_json::Value, localize_s: f64) {
    let converged = match summary["converged_at_s"].as_f64() {
        Some(s) => format!("converged at {s:.1} s"),
        None => "not converged at the end".to_string(),
    };
    say!(
        "{name}: {} scans, {} updates, {converged}, {} convergence losses, particles {}-{}",
        result.trajectory.len(),
        result.updates.len(),
        result.convergence_losses(),
        summary["particles"]["min"],
        summary["particles"]["max"],
    );
    say!(
        "time: localisation {localize_s:.2} s for {:.1} s of recording ({:.0}x real time); \
         returns far from the map's walls {:.1} %",
        summary["duration_s"].as_f64().unwrap_or(0.0),
        summary["realtime_factor"].as_f64().unwrap_or(0.0),
        100.0 * result.off_wall_share
    );
    let skipped = [
        (
            result.scans_stale,
            "stale (repeating a scan of the last seconds)",
        ),
        (result.scans_outside_odometry, "outside the odometry's span"),
    ];
    for (count, why) in skipped.into_iter().filter(|s| s.0 > 0) {
        say!("{count} scans left out: {why}");
    }
}
