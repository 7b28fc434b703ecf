//! The particle filter run over a recording: the driver above the filter's building blocks
//! ([`crate::filter`]) that takes the whole [`Config`]. The loop predicts at every odometry
//! step, updates every k-th scan (`[filter] mode`: the seeds' correlation, or the
//! scan-matching proposal of [`crate::matching::likelihood_field`]), reweights, resamples on low
//! Neff, maps with the best particle (the scan-matching mode also maps the scans between
//! updates at the odometry-composed pose) and outputs a pose at every scan; the `rbpf` mode's
//! front end ([`RbpfFrontEnd`]) updates once the odometry moved far enough and re-matches its
//! final path.
//!
//! - [`run_slam`]: the mode `[filter] mode` selects (`auto` resolved); [`run_slam_with`]:
//!   an explicit motion model and map policy; [`run_rbpf_in`]: the `rbpf` mode continuing a
//!   saved map.
//! - [`FrontEnd`]: a filter fed one scan at a time, shared by the batch loop and
//!   [`crate::Slam`]; [`MapPolicy`]: how the maps are kept; [`SlamResult`] and
//!   [`SlamEvent`]: what a run produces and reports.
//! - [`seed_config`] and [`motion_model`]: the configuration of the seeds and the noisy
//!   motion model a configuration selects.

use crate::config::Config;
use crate::filter::odometry::OdometryCursor;
use crate::filter::prediction::{self, PredictionModel};
use crate::filter::{FilterError, FilterMode, ParticleFilter, ParticleMaps};
use crate::geometry::{Pose2, StampedPose2};
use crate::map::{
    BatchScratch, CellChange, ChangeLog, InsertScratch, MapError, OccupancyGrid, PlanarScan,
    ScanProjector, ScanUpdates, split_rays, to_world,
};
use crate::matching::correlation::CorrelationSearch;
use crate::matching::likelihood_field;
use crate::sensors::Recording;
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

mod front_end;
mod maps;
mod rbpf;
mod result;

pub use crate::filter::prediction::MotionModel;
pub use front_end::{FrontEnd, MatchFrontEnd};
pub(crate) use front_end::{drive, feed_scan};
pub use maps::*;
pub use rbpf::*;
pub use result::*;

/// Errors of a SLAM run.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    /// Bad filter options.
    #[error(transparent)]
    Filter(#[from] FilterError),
    /// Bad map options or a failed insertion.
    #[error(transparent)]
    Map(#[from] MapError),
    /// Bad motion options.
    #[error("invalid motion options: {0}")]
    Motion(String),
    /// Bad `[input]` options.
    #[error("{0}")]
    InputOptions(String),
    /// Nothing to do.
    #[error("recording {name}: {message}")]
    Input {
        /// The recording's name.
        name: String,
        /// What is missing.
        message: String,
    },
}

/// After scan `done` of `total`: reports progress about every 0.5 % (and at the end) to
/// `observer`, and says whether a map snapshot is due (every `snapshot_every_scans`
/// processed scans; 0 = never). Shared by the filter loops.
pub(crate) fn report_progress(
    observer: &mut dyn FnMut(SlamEvent<'_>),
    done: usize,
    total: usize,
    stats: &SlamStats,
    snapshot_every_scans: usize,
) -> bool {
    let progress_every = (total / 200).max(1);
    if done.is_multiple_of(progress_every) || done == total {
        observer(SlamEvent::Progress { done, total });
    }
    snapshot_every_scans > 0 && stats.scans_processed.is_multiple_of(snapshot_every_scans)
}

/// The front end of the mode `config` runs on `recording` (`auto` resolved), its particles
/// at the odometry's pose `start` at scan `first` (the scans before counted as skipped).
pub enum AnyFrontEnd {
    /// The `rbpf` mode.
    Rbpf(Box<RbpfFrontEnd>),
    /// The `scan_match` and `seed` modes.
    Match(Box<MatchFrontEnd<BestParticleMap>>),
}

impl AnyFrontEnd {
    /// The front end `run_slam` runs (see the type).
    pub fn new(
        recording: &Recording,
        config: &Config,
        seed: u64,
        (start, first): (Pose2, usize),
    ) -> Result<Self, SlamError> {
        let mode = config.filter.mode.resolve(recording);
        if mode == FilterMode::Rbpf {
            let front = RbpfFrontEnd::new(recording, config, seed, None, start)?;
            return Ok(AnyFrontEnd::Rbpf(Box::new(front.skipped(first))));
        }
        let motion = motion_model(config, recording)?;
        // `scan_match` matches against a map without height bins
        // (docs/decisions/0015-height-bins.md).
        let grid = if mode == FilterMode::ScanMatch {
            let mut map = config.map.clone();
            map.height.enabled = false;
            OccupancyGrid::new(&map)?
        } else {
            OccupancyGrid::new(&config.map)?
        };
        let policy = BestParticleMap::new(grid);
        let front = MatchFrontEnd::new(recording, config, seed, motion, policy, (start, first))?;
        Ok(AnyFrontEnd::Match(Box::new(front)))
    }
}

impl FrontEnd for AnyFrontEnd {
    fn step(
        &mut self,
        recording: &Recording,
        i: usize,
        odom: StampedPose2,
        steps: &[(StampedPose2, StampedPose2)],
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<(), SlamError> {
        match self {
            AnyFrontEnd::Rbpf(f) => f.step(recording, i, odom, steps, observer),
            AnyFrontEnd::Match(f) => f.step(recording, i, odom, steps, observer),
        }
    }

    fn skip(&mut self) {
        match self {
            AnyFrontEnd::Rbpf(f) => f.skip(),
            AnyFrontEnd::Match(f) => f.skip(),
        }
    }

    fn latest_pose(&self) -> Option<StampedPose2> {
        match self {
            AnyFrontEnd::Rbpf(f) => f.latest_pose(),
            AnyFrontEnd::Match(f) => f.latest_pose(),
        }
    }

    fn current_map(&mut self) -> Result<&OccupancyGrid, SlamError> {
        match self {
            AnyFrontEnd::Rbpf(f) => f.current_map(),
            AnyFrontEnd::Match(f) => f.current_map(),
        }
    }

    fn finish(self, recording: &Recording, t_start: Instant) -> Result<SlamResult, SlamError> {
        match self {
            AnyFrontEnd::Rbpf(f) => f.finish(recording, t_start),
            AnyFrontEnd::Match(f) => f.finish(recording, t_start),
        }
    }

    fn take_window(
        &mut self,
        recording: &Recording,
        let_go: usize,
    ) -> Result<Option<Window>, SlamError> {
        match self {
            AnyFrontEnd::Rbpf(f) => f.take_window(recording, let_go),
            AnyFrontEnd::Match(f) => f.take_window(recording, let_go),
        }
    }
}

/// Runs the seeds' particle-filter SLAM on `recording` with `config` and random `seed`,
/// reporting progress and snapshots to `observer`.
pub fn run_slam(
    recording: &Recording,
    config: &Config,
    seed: u64,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    let t_start = Instant::now();
    let (first, cursor) = check_and_start(recording, config)?;
    let start = (cursor.current().pose, first);
    let front = AnyFrontEnd::new(recording, config, seed, start)?;
    drive(recording, (first, cursor), front, t_start, observer)
}

/// [`run_slam`] with an explicit motion model and map policy.
pub fn run_slam_with<P: MapPolicy>(
    recording: &Recording,
    config: &Config,
    seed: u64,
    motion: Box<dyn MotionModel>,
    policy: P,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    let t_start = Instant::now();
    let (first, cursor) = check_and_start(recording, config)?;
    let start = cursor.current().pose;
    let front = MatchFrontEnd::new(recording, config, seed, motion, policy, (start, first))?;
    drive(recording, (first, cursor), front, t_start, observer)
}

/// Validates the options and the recording, and finds the first scan inside the odometry's
/// time span: its index and an odometry cursor standing on it (shared by every mode's loop).
pub(crate) fn check_and_start(
    recording: &Recording,
    config: &Config,
) -> Result<(usize, OdometryCursor), SlamError> {
    config.filter.validate()?;
    config.map.validate().map_err(MapError::Options)?;
    config.input.validate().map_err(SlamError::InputOptions)?;
    let scans = &recording.scans;
    let total = scans.len();
    let input_err = |message: &str| SlamError::Input {
        name: recording.name.clone(),
        message: message.to_string(),
    };
    if recording.odometry.is_empty() {
        return Err(input_err("no odometry"));
    }
    if let Some(per_scan) = &recording.body_from_lidar_per_scan
        && per_scan.len() != total
    {
        return Err(input_err("per-scan LiDAR mounts do not match the scans"));
    }
    let Some(first) =
        (0..total).find(|&i| recording.odometry.pose_at(scans.stamps_ns[i]).is_some())
    else {
        return Err(input_err("no scan lies within the odometry's time span"));
    };
    let cursor = OdometryCursor::new(&recording.odometry, scans.stamps_ns[first])
        .ok_or_else(|| input_err("no odometry at the first scan"))?;
    Ok((first, cursor))
}

/// The seeds' configuration: `mode = "seed"`, the UCSD log-odds model (one hit makes a cell
/// occupied), and none of the scan preprocessing the scan-matching mode relies on (ground
/// removal, densification, partial clearing of climbing beams). Everything else as [`Config::default`].
pub fn seed_config() -> Config {
    let mut config = Config::default();
    config.filter.mode = FilterMode::Seed;
    config.map.log_odds = crate::map::LogOddsParams::ucsd();
    config.map.scan.ground_clearance_m = None;
    config.map.scan.densify_max_gap_m = None;
    config.map.scan.free_z_max_m = None;
    config
}

/// The noisy motion model `[filter] motion_model` selects: velocity noise from
/// `[motion.noise]` or the odometry model of `[filter.odometry_model]` (using the recording's
/// IMU yaw, when it has one, for the ESE650 variant).
pub fn motion_model(
    config: &Config,
    recording: &crate::sensors::Recording,
) -> Result<Box<dyn MotionModel>, SlamError> {
    config
        .motion
        .validate()
        .map_err(|e| SlamError::Motion(e.to_string()))?;
    Ok(match config.filter.motion_model {
        PredictionModel::Velocity => Box::new(prediction::VelocityMotion {
            noise: config.motion.noise,
            step: config.motion.step,
        }),
        PredictionModel::Odometry => {
            let o = &config.filter.odometry_model;
            let sigmas = [o.alpha1, o.alpha2, o.alpha3, o.alpha4]
                .into_iter()
                .chain(o.ese650_sigma);
            if sigmas.into_iter().any(|v| !(v.is_finite() && v >= 0.0)) {
                return Err(SlamError::Motion(
                    "filter.odometry_model: alphas and sigmas must be finite and >= 0".into(),
                ));
            }
            Box::new(prediction::OdometryMotion {
                options: *o,
                imu_yaw: recording.imu_yaw.clone(),
            })
        }
    })
}

/// The window of the likelihood field for one update: the matching points seen from `best`,
/// grown by how far the other particles are from it (at most 5 m) and by `margin_cells`.
fn field_window(
    limits: &crate::map::MapLimits,
    poses: &[Pose2],
    best: Pose2,
    points_body: &[[f64; 2]],
    margin_cells: i32,
) -> crate::map::CellRect {
    let c0 = limits.cell_of(best.x_m, best.y_m);
    let mut rect = crate::map::CellRect::around(c0);
    for p in points_body {
        let (x, y) = best.transform_point(p[0], p[1]);
        rect = rect.union(&crate::map::CellRect::around(limits.cell_of(x, y)));
    }
    let spread_m = poses
        .iter()
        .map(|p| (p.x_m - best.x_m).hypot(p.y_m - best.y_m))
        .fold(0.0, f64::max)
        .min(5.0);
    let reach_m = points_body
        .iter()
        .map(|p| p[0].hypot(p[1]))
        .fold(0.0, f64::max);
    // A yaw difference between particles swings far points sideways too.
    let yaw_spread = poses
        .iter()
        .map(|p| crate::geometry::wrap_angle(p.yaw_rad - best.yaw_rad).abs())
        .fold(0.0, f64::max)
        .min(0.1);
    let grow_m = spread_m + reach_m * yaw_spread;
    rect.expanded((grow_m / limits.resolution_m()).ceil() as i32 + margin_cells)
}

/// Re-expresses the odometry of `recording` in its ground truth's frame, anchored at the first
/// scan both cover: `odometry' = gt(t0) * odometry(t0)^-1 * odometry`. SLAM then starts at
/// the true initial pose, so its map and trajectory can be drawn over and compared with the
/// true ones without alignment (only the start is used, never later ground truth). Returns
/// false (recording unchanged) without ground truth or overlap.
pub fn anchor_odometry_to_ground_truth(recording: &mut Recording) -> bool {
    let Some(gt) = &recording.ground_truth else {
        return false;
    };
    let gt = crate::geometry::Trajectory::new(gt.clone());
    let anchor = recording.scans.stamps_ns.iter().find_map(|&t| {
        Some(
            gt.pose_at(t)?
                .compose(&recording.odometry.pose_at(t)?.inverse()),
        )
    });
    let Some(world_from_odom) = anchor else {
        return false;
    };
    for p in &mut recording.odometry.poses {
        p.pose = world_from_odom.compose(&p.pose);
    }
    true
}

#[cfg(test)]
mod flush_tests;
