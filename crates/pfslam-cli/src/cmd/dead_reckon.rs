//! `pfslam dead-reckon DATASET --out DIR`: dead reckoning of a dataset (for the car, its
//! encoders + FOG; for other recordings, their odometry), written as `trajectory.tum` and
//! `trajectory.csv` (one pose per LiDAR scan) and `trajectory.png`.
//!
//! A CARMEN log whose laser lines carry their poses and clean stamps is streamed
//! ([`pfslam_io::carmen::stream_scan_poses`]): memory does not grow with its length.

use super::thinned::Thinned;
use anyhow::Context;
use pfslam::geometry::StampedPose2;
use pfslam::sensors::sync::poses_at_stamps;
use pfslam_io::tum::{format_stamp_s, write_tum, write_tum_line};
use pfslam_io::{write_atomic, write_bytes_atomic};
use pfslam_viz::plot::{PALETTE, PathRef, render_trajectories_png};
use std::io::Write;
use std::path::{Path, PathBuf};

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
    if let Some(summary) = streamed_carmen(&args, &config, &out)? {
        staging.commit()?;
        summary.print(&args.out);
        return Ok(());
    }
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

    let name = file_name(&args.dataset);
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

    let mut summary = Summary::new(at_scans.len());
    summary.odometry_poses = traj.len();
    summary.first_stamp_ns = traj.poses.first().map(|p| p.stamp_ns);
    summary.last = traj.poses.last().copied();
    summary.distance_m = traj.path_length_m();
    summary.car_rows = ds.car.as_ref().map(|c| (c.encoder.len(), c.fog.len()));
    summary.scans = ds.recording.scans.len();
    summary.print(&args.out);
    Ok(())
}

/// What `dead-reckon` says at the end.
struct Summary {
    odometry_poses: usize,
    scans: usize,
    poses_at_scans: usize,
    car_rows: Option<(usize, usize)>,
    distance_m: f64,
    first_stamp_ns: Option<i64>,
    last: Option<StampedPose2>,
}

impl Summary {
    fn new(poses_at_scans: usize) -> Summary {
        Summary {
            odometry_poses: 0,
            scans: 0,
            poses_at_scans,
            car_rows: None,
            distance_m: 0.0,
            first_stamp_ns: None,
            last: None,
        }
    }

    fn print(&self, out: &Path) {
        match self.car_rows {
            Some((encoder, fog)) => say!(
                "rows: {encoder} encoder, {fog} FOG, {} LiDAR scans",
                self.scans
            ),
            None => say!(
                "odometry poses: {}, scans: {}",
                self.odometry_poses,
                self.scans
            ),
        }
        let first = self.first_stamp_ns.unwrap_or(0);
        let duration_s = self.last.map_or(0, |p| p.stamp_ns - first) as f64 * 1e-9;
        say!("distance: {:.3} m", self.distance_m);
        say!("duration: {duration_s:.3} s");
        if let Some(p) = self.last {
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
            out.display(),
            self.poses_at_scans
        );
    }
}

/// Dead reckoning of a CARMEN log streamed scan by scan into `out` (see the module docs);
/// `None` when the dataset is not such a log or must be read whole.
fn streamed_carmen(
    args: &Args,
    config: &pfslam::config::Config,
    out: &Path,
) -> anyhow::Result<Option<Summary>> {
    use pfslam_io::IoError;
    use pfslam_io::recording::{RecordingFormat, detect_format};
    let input = &config.input;
    if !args.dataset.is_file()
        || input.start_s.is_some()
        || input.end_s.is_some()
        || detect_format(&args.dataset)? != Some(RecordingFormat::Carmen)
    {
        return Ok(None);
    }
    let (tum_path, csv_path) = (out.join("trajectory.tum"), out.join("trajectory.csv"));
    let create = |p: &Path| -> anyhow::Result<std::io::BufWriter<std::fs::File>> {
        let f = std::fs::File::create(p).with_context(|| p.display().to_string())?;
        Ok(std::io::BufWriter::with_capacity(1 << 16, f))
    };
    let (mut tum, mut csv) = (create(&tum_path)?, create(&csv_path)?);
    writeln!(tum, "# stamp_s x y z qx qy qz qw")?;
    writeln!(csv, "{CSV_HEADER}")?;
    let mut summary = Summary::new(0);
    let mut plot = Thinned::default();
    let account = pfslam_io::carmen::stream_scan_poses(
        &args.dataset,
        &pfslam_io::carmen::CarmenOptions::from_reader(input),
        |s| {
            let p = StampedPose2 {
                stamp_ns: s.stamp_ns,
                pose: s.odom,
            };
            write_tum_line(&mut tum, &p).map_err(|e| IoError::io(&tum_path, e))?;
            write_csv_line(&mut csv, &p).map_err(|e| IoError::io(&csv_path, e))?;
            if let Some(last) = summary.last {
                summary.distance_m += last.pose.between(&p.pose).translation_norm_m();
            }
            summary.first_stamp_ns.get_or_insert(p.stamp_ns);
            summary.last = Some(p);
            summary.poses_at_scans += 1;
            plot.push(p);
            Ok(())
        },
    )?;
    let Some(account) = account else {
        return Ok(None);
    };
    super::input::report(&account);
    tum.flush()
        .with_context(|| tum_path.display().to_string())?;
    csv.flush()
        .with_context(|| csv_path.display().to_string())?;
    let name = file_name(&args.dataset);
    let traj = pfslam::geometry::Trajectory::new(plot.poses);
    let png = render_trajectories_png(
        &[("dead reckoning", PathRef::Trajectory(&traj), PALETTE[0])],
        &format!("Dead reckoning: {name}"),
    )
    .context("trajectory.png")?;
    write_bytes_atomic(&out.join("trajectory.png"), &png)?;
    summary.odometry_poses = summary.poses_at_scans;
    summary.scans = summary.poses_at_scans;
    Ok(Some(summary))
}

fn file_name(dataset: &Path) -> String {
    dataset
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".to_string())
}

const CSV_HEADER: &str = "stamp_ns,x_m,y_m,yaw_rad";

fn write_csv_line(w: &mut dyn Write, p: &StampedPose2) -> std::io::Result<()> {
    writeln!(
        w,
        "{},{},{},{}",
        p.stamp_ns, p.pose.x_m, p.pose.y_m, p.pose.yaw_rad
    )
}

fn write_csv(path: &std::path::Path, poses: &[StampedPose2]) -> anyhow::Result<()> {
    write_atomic(path, |w: &mut dyn Write| {
        writeln!(w, "{CSV_HEADER}")?;
        for p in poses {
            write_csv_line(w, p)?;
        }
        Ok(())
    })?;
    Ok(())
}
