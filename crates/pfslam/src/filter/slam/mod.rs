//! The SLAM loop: predict at every odometry step, update every k-th scan (`[filter] mode`:
//! the seeds' correlation, or the scan-matching proposal of [`super::scanmatch`]), reweight,
//! resample on low Neff, map with the best particle (the scan-matching mode also maps the
//! scans between updates at the odometry-composed pose), output a pose at every scan.

use super::correlate::{CorrelationSearch, OccupancyLookup};
use super::odometry::OdometryCursor;
use super::scanmatch;
use super::{FilterError, FilterMode, ParticleFilter, ParticleMaps, SERIAL_BELOW_PARTICLE_STEPS};
use crate::config::Config;
use crate::geometry::{Pose2, StampedPose2};
use crate::map::{
    BatchScratch, Cell, CellChange, ChangeLog, InsertScratch, MapError, MapLimits, OccupancyGrid,
    PlanarScan, ScanProjector, ScanUpdates, split_rays, to_world,
};
use crate::sensors::Recording;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

mod front_end;
mod maps;
mod result;

pub use front_end::{FrontEnd, MatchFrontEnd};
pub(crate) use front_end::{drive, feed_scan};
pub use maps::*;
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
    /// Nothing to do.
    #[error("recording {name}: {message}")]
    Input {
        /// The recording's name.
        name: String,
        /// What is missing.
        message: String,
    },
}

/// A noisy motion model: moves a particle by the odometry step `from -> to`. `Send` too, so
/// that a [`crate::Slam`] can run on another thread than the one that made it.
pub trait MotionModel: Send + Sync {
    /// The particle's new pose after the odometry step `from -> to`, with noise drawn from
    /// `rng`.
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2;

    /// The recording's IMU yaw `(stamp_ns, yaw_rad)` so far, for a model that uses it: the
    /// series only grows (live input), so a model keeps what it has and takes the rest.
    fn observe_imu_yaw(&mut self, _series: &[(i64, f64)]) {}
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
    Rbpf(Box<super::rbpf::RbpfFrontEnd>),
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
            let front = super::rbpf::RbpfFrontEnd::new(recording, config, seed, None, start)?;
            return Ok(AnyFrontEnd::Rbpf(Box::new(front.skipped(first))));
        }
        let motion = super::motion_model(config, recording)?;
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

impl ParticleFilter {
    /// Applies the odometry steps `(from, to)` in order to every particle with `motion`, in
    /// parallel over fixed chunks (deterministic for any thread count).
    pub fn predict_steps(
        &mut self,
        steps: &[(StampedPose2, StampedPose2)],
        motion: &dyn MotionModel,
    ) {
        let parallel = self.particles.len() * steps.len() >= SERIAL_BELOW_PARTICLE_STEPS;
        self.par_chunks(parallel, |poses, rng| {
            for (from, to) in steps {
                for p in poses.iter_mut() {
                    *p = motion.sample(p, from, to, rng);
                }
            }
        });
    }

    /// Composes every particle with the odometry steps `(from, to)` in order, without
    /// noise: [`Self::predict_steps`] with exact odometry, each step's increment computed
    /// once for all particles instead of per particle (the same bits: the increment is a pure
    /// function of the step; the per-particle `between` cost two of its three `sin_cos`).
    /// `increments` is a reusable buffer.
    pub fn predict_exact(
        &mut self,
        steps: &[(StampedPose2, StampedPose2)],
        increments: &mut Vec<Pose2>,
    ) {
        increments.clear();
        increments.extend(steps.iter().map(|(from, to)| from.pose.between(&to.pose)));
        let increments = &*increments;
        let parallel = self.particles.len() * steps.len() >= SERIAL_BELOW_PARTICLE_STEPS;
        self.par_chunks(parallel, |poses, _| {
            for d in increments {
                for p in poses.iter_mut() {
                    *p = p.compose(d);
                }
            }
        });
    }
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
mod tests;

#[cfg(test)]
mod flush_tests;
