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

mod maps;
mod result;

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

/// A noisy motion model: moves a particle by the odometry step `from -> to`.
pub trait MotionModel: Sync {
    /// The particle's new pose after the odometry step `from -> to`, with noise drawn from
    /// `rng`.
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2;
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

/// Runs the seeds' particle-filter SLAM on `recording` with `config` and random `seed`,
/// reporting progress and snapshots to `observer`.
pub fn run_slam(
    recording: &Recording,
    config: &Config,
    seed: u64,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    let mode = config.filter.mode.resolve(recording);
    if mode == FilterMode::Rbpf {
        return super::rbpf::run_rbpf(recording, config, seed, observer);
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
    let mut policy = BestParticleMap::new(grid);
    run_slam_with(
        recording,
        config,
        seed,
        motion.as_ref(),
        &mut policy,
        observer,
    )
}

/// [`run_slam`] with an explicit motion model and map policy.
pub fn run_slam_with<P: MapPolicy>(
    recording: &Recording,
    config: &Config,
    seed: u64,
    motion: &dyn MotionModel,
    policy: &mut P,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    let opts = &config.filter;
    // `rbpf` (from `auto` too) reaches here only through this explicit-policy entry point;
    // it then runs the scan-matching loop with the given policy.
    let mode = opts.mode.resolve(recording);
    let t_start = Instant::now();
    let (first, mut cursor) = check_and_start(recording, config)?;
    let scans = &recording.scans;
    let total = scans.len();
    let start = cursor.current().pose;
    let mut projector = ScanProjector::new(
        &recording.lidar,
        &recording.body_from_lidar,
        &config.map.scan.for_filter(),
    )?;
    let search: CorrelationSearch = opts.search();
    let mut pf = ParticleFilter::new(opts.particles, start, seed);
    let mut stats = SlamStats {
        particles: opts.particles,
        mode,
        seed,
        scans_total: total,
        scans_skipped: first,
        neff_min: f64::INFINITY,
        ..SlamStats::default()
    };
    let mut trajectory = Vec::with_capacity(total - first);
    let mut dead_reckoning = Vec::with_capacity(total - first);
    let mut body = PlanarScan::default();
    let mut hits: Vec<[f64; 2]> = Vec::new();
    let mut steps: Vec<(StampedPose2, StampedPose2)> = Vec::new();
    let mut last_estimate = start;
    let mut last_update_odom = start;
    let mut match_pts: Vec<[f64; 2]> = Vec::new();
    let mut field = scanmatch::LikelihoodField::new();
    let mut field_cache = super::field_cache::FieldCache::new();
    policy.log_changes(field.source_threshold_on(policy.map_for_output(0)));
    let match_params = opts.scan_match.params(config.map.resolution_m);
    let resample_threshold = match mode {
        FilterMode::Seed => opts.resample_threshold,
        FilterMode::ScanMatch | FilterMode::Rbpf | FilterMode::Auto => {
            opts.scan_match.resample_threshold
        }
    };
    let mut neff_sum = 0.0;
    let mut score_sum = 0.0;
    let mut increments: Vec<Pose2> = Vec::new();
    for i in first..total {
        let stamp_ns = scans.stamps_ns[i];
        let t = Instant::now();
        steps.clear();
        let Some(odom) = cursor.advance_to(stamp_ns, |a, b| steps.push((*a, *b))) else {
            stats.scans_skipped += 1;
            continue;
        };
        stats.odometry_steps += steps.len();
        if !steps.is_empty() {
            match mode {
                FilterMode::Seed => pf.predict_steps(&steps, motion),
                // The scan match is the proposal: odometry without noise here, the spread
                // comes from sampling around each match.
                FilterMode::ScanMatch | FilterMode::Rbpf | FilterMode::Auto => {
                    pf.predict_exact(&steps, &mut increments)
                }
            }
        }
        stats.timings.predict_s += t.elapsed().as_secs_f64();
        let k = i - first;
        let due = k.is_multiple_of(opts.update_every_scans);
        let estimate = if due {
            let t = Instant::now();
            projector.aim(recording, i);
            projector.to_body(scans.ranges(i), &mut body)?;
            super::correlate::hit_points(&body, &mut hits);
            stats.timings.preprocess_s += t.elapsed().as_secs_f64();
            let best = if k == 0 {
                // The first scan seeds the map at the start pose; nothing to correlate with.
                0
            } else {
                let t = Instant::now();
                policy.flush()?;
                stats.timings.map_update_s += t.elapsed().as_secs_f64();
                let t = Instant::now();
                let report = match mode {
                    FilterMode::Seed => pf.reweight(
                        &*policy,
                        &hits,
                        &search,
                        opts.temperature,
                        opts.move_to_best_offset,
                    ),
                    FilterMode::ScanMatch | FilterMode::Rbpf | FilterMode::Auto => {
                        let sm = &opts.scan_match;
                        scanmatch::match_points(
                            &body,
                            sm.match_range_max_m,
                            sm.beam_decimation,
                            &mut match_pts,
                        );
                        let grid = policy.map_for_output(pf.particles.best_index());
                        let rect = field_window(
                            grid.limits(),
                            &pf.particles.poses,
                            pf.best_pose(),
                            &match_pts,
                            match_params.xy_radius_cells + 2,
                        );
                        let tb = Instant::now();
                        // The field from its cache (the map's changes since the last update).
                        policy.take_changes(pf.particles.best_index(), |grid, changes| {
                            field.build_cached(
                                grid,
                                &rect,
                                sm.field_sigma_m,
                                sm.unknown_value,
                                &mut field_cache,
                                changes,
                            )
                        });
                        stats.timings.field_s += tb.elapsed().as_secs_f64();
                        let report = pf.scan_match_update(
                            &field,
                            &match_pts,
                            &match_params,
                            sm.weight_temperature,
                        );
                        let best = pf.particles.poses[report.best];
                        pf.jitter(
                            sm.proposal_sigma_xy_m,
                            sm.proposal_sigma_yaw_deg.to_radians(),
                        );
                        // The estimate is the match itself, not its jittered sample.
                        pf.particles.poses[report.best] = best;
                        report
                    }
                };
                stats.timings.correlate_s += t.elapsed().as_secs_f64();
                stats.updates += 1;
                neff_sum += report.neff;
                score_sum += f64::from(report.best_score);
                stats.neff_min = stats.neff_min.min(report.neff);
                stats.neff_last = report.neff;
                report.best
            };
            let estimate = pf.particles.poses[best];
            let t = Instant::now();
            policy.integrate(&pf.particles.poses, best, &body)?;
            stats.timings.map_update_s += t.elapsed().as_secs_f64();
            let t = Instant::now();
            if k > 0
                && let Some(ancestors) =
                    pf.resample_if_needed(resample_threshold, opts.resample_method)
            {
                policy.resampled(ancestors);
                stats.resamples += 1;
            }
            stats.timings.resample_s += t.elapsed().as_secs_f64();
            last_estimate = estimate;
            last_update_odom = odom.pose;
            observer(SlamEvent::Update {
                stamp_ns,
                particles: &pf.particles.poses,
                map: None,
            });
            estimate
        } else {
            let estimate = last_estimate.compose(&last_update_odom.between(&odom.pose));
            if opts.map_between_updates || mode == FilterMode::ScanMatch {
                // Insert this scan at the composed pose: the map then reaches up to the
                // latest scan when the next update correlates against it.
                let t = Instant::now();
                projector.aim(recording, i);
                projector.to_body(scans.ranges(i), &mut body)?;
                stats.timings.preprocess_s += t.elapsed().as_secs_f64();
                let t = Instant::now();
                policy.integrate_at(&estimate, &body)?;
                stats.timings.map_update_s += t.elapsed().as_secs_f64();
            }
            estimate
        };
        trajectory.push(StampedPose2 {
            stamp_ns,
            pose: estimate,
        });
        dead_reckoning.push(odom);
        stats.scans_processed += 1;
        let done = i + 1;
        if report_progress(observer, done, total, &stats, opts.snapshot_every_scans) {
            policy.flush()?;
            observer(SlamEvent::Snapshot {
                scans_done: done,
                map: policy.map_for_output(pf.particles.best_index()),
                trajectory: &trajectory,
            });
        }
    }
    let t = Instant::now();
    policy.flush()?;
    stats.timings.map_update_s += t.elapsed().as_secs_f64();
    stats.finish_means(neff_sum, score_sum);
    stats.timings.total_s = t_start.elapsed().as_secs_f64();
    let map = policy.map_for_output(pf.particles.best_index()).clone();
    Ok(SlamResult {
        trajectory,
        dead_reckoning,
        map,
        stats,
    })
}

/// Validates the options and the recording, and finds the first scan inside the odometry's
/// time span: its index and an odometry cursor standing on it (shared by every mode's loop).
pub(crate) fn check_and_start<'a>(
    recording: &'a Recording,
    config: &Config,
) -> Result<(usize, OdometryCursor<'a>), SlamError> {
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
