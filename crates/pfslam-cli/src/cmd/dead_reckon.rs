//! `pfslam dead-reckon DATASET --out DIR`: dead reckoning of a dataset (for the car, its
//! encoders + FOG; for other recordings, their odometry), written as `trajectory.tum` and
//! `trajectory.csv` (one pose per LiDAR scan) and `trajectory.png`.

use anyhow::Context;
use pfslam::geometry::StampedPose2;
use pfslam::io::tum::{format_stamp_s, write_tum};
use pfslam::io::{write_atomic, write_bytes_atomic};
use pfslam::sensors::sync::poses_at_stamps;
use pfslam::viz::plot::{PALETTE, PathRef, render_trajectories_png};
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `dead-reckon`.
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// Dataset: a car dataset directory (sensor_data/, param/ as the course distributed them),
    /// a humanoid dataset directory, or a recording file (CARMEN log, ROS bag, MCAP).
    pub dataset: PathBuf,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML configuration; its `[motion]` section (step model, yaw source) applies.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Sort rows whose timestamps go backwards (with a warning) instead of rejecting them.
    #[arg(long)]
    pub sort_timestamps: bool,
    /// Input selection and strictness.
    #[command(flatten)]
    pub input: super::input::InputArgs,
}

/// Runs dead reckoning.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.input.config(args.config.as_deref())?;
    config.validate()?;
    let staging = super::output::Staging::new(&args.out)?;
    let out = staging.path().to_path_buf();
    // Every format's odometry is its dead reckoning: for the car it is the integration of
    // wheel ticks and FOG yaw (`motion::car_recording`), for recordings their odometry poses.
    let ds = super::dataset::load_dataset(&args.dataset, &config, args.sort_timestamps)?;
    super::input::report(&ds.account);
    let traj = &ds.recording.odometry;
    if traj.is_empty() {
        anyhow::bail!("{}: no odometry to dead-reckon", args.dataset.display());
    }
    let (at_scans, clamped) = poses_at_stamps(traj, &ds.recording.scans.stamps_ns);
    if clamped > 0 {
        tracing::warn!(
            "{clamped} LiDAR scans lie outside the odometry's time span: they get the first/last pose"
        );
    }

    let name = args
        .dataset
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".to_string());
    // Render first: a drawing failure must not leave the other files behind.
    let png = render_trajectories_png(
        &[("dead reckoning", PathRef::Trajectory(traj), PALETTE[0])],
        &format!("Dead reckoning: {name}"),
    )
    .context("trajectory.png")?;
    write_tum(&out.join("trajectory.tum"), &at_scans)?;
    write_csv(&out.join("trajectory.csv"), &at_scans)?;
    write_bytes_atomic(&out.join("trajectory.png"), &png)?;
    staging.commit()?;

    let first = traj.poses.first().map(|p| p.stamp_ns).unwrap_or(0);
    let last = traj.poses.last().copied();
    let duration_s = last.map(|p| p.stamp_ns - first).unwrap_or(0) as f64 * 1e-9;
    match &ds.car {
        Some(car) => say!(
            "rows: {} encoder, {} FOG, {} LiDAR scans",
            car.encoder.len(),
            car.fog.len(),
            ds.recording.scans.len()
        ),
        None => say!(
            "odometry poses: {}, scans: {}",
            traj.len(),
            ds.recording.scans.len()
        ),
    }
    say!("distance: {:.3} m", traj.path_length_m());
    say!("duration: {duration_s:.3} s");
    if let Some(p) = last {
        say!(
            "final pose: x {:.3} m, y {:.3} m, yaw {:.2} deg (t = {} s)",
            p.pose.x_m,
            p.pose.y_m,
            p.pose.yaw_rad.to_degrees(),
            format_stamp_s(p.stamp_ns)
        );
    }
    say!(
        "wrote {}/trajectory.tum, trajectory.csv, trajectory.png ({} poses at LiDAR stamps)",
        args.out.display(),
        at_scans.len()
    );
    Ok(())
}

fn write_csv(path: &std::path::Path, poses: &[StampedPose2]) -> anyhow::Result<()> {
    write_atomic(path, |w: &mut dyn Write| {
        writeln!(w, "stamp_ns,x_m,y_m,yaw_rad")?;
        for p in poses {
            writeln!(
                w,
                "{},{},{},{}",
                p.stamp_ns, p.pose.x_m, p.pose.y_m, p.pose.yaw_rad
            )?;
        }
        Ok(())
    })?;
    Ok(())
}
