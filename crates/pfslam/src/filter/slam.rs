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

impl OccupancyLookup for OccupancyGrid {
    #[inline]
    fn cell_limits(&self) -> MapLimits {
        *self.limits()
    }
    #[inline]
    fn occupied(&self, cell: Cell) -> bool {
        self.is_occupied(cell)
    }
}

/// How maps are kept: the seeds' single map written by the best particle, or one map per
/// particle. The filter sees maps only through this trait.
pub trait MapPolicy: ParticleMaps {
    /// Integrates the body-frame scan at the particles' poses (`best` is the heaviest).
    fn integrate(
        &mut self,
        poses: &[Pose2],
        best: usize,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError>;
    /// Integrates a scan between updates at `world_from_body` (the output pose: the last
    /// estimate moved by odometry) into every map.
    fn integrate_at(
        &mut self,
        world_from_body: &Pose2,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError>;
    /// The particles were resampled: particle `k` is now a copy of old particle
    /// `ancestors[k]`.
    fn resampled(&mut self, ancestors: &[usize]);
    /// The map to report for particle `best`.
    fn map_for_output(&self, best: usize) -> &OccupancyGrid;
    /// Completes integrations a policy deferred (the loop calls it before every read of the
    /// maps). The default defers nothing.
    fn flush(&mut self) -> Result<(), MapError> {
        Ok(())
    }
    /// Logs the cells of the output map whose observed or wall status (`threshold`,
    /// fixed-point log-odds) insertions change, for [`Self::take_changes`]. The default logs
    /// nothing.
    fn log_changes(&mut self, _threshold: i16) {}
    /// Hands the map of particle `best` and the changes logged since the last call to
    /// `use_changes` (`None` when they are not known: nothing logged, or an insertion that
    /// did not log) and clears the log.
    fn take_changes<R>(
        &mut self,
        best: usize,
        use_changes: impl FnOnce(&OccupancyGrid, Option<&[CellChange]>) -> R,
    ) -> R {
        use_changes(self.map_for_output(best), None)
    }
}

/// The seeds' policy: one map, updated with the best particle's pose.
///
/// Scans are queued (in the world frame) and inserted at [`MapPolicy::flush`]: the rays of
/// the scans between two updates are cut into one run of about equal work per thread (a scan
/// may be split between two), traced in parallel and applied in scan order, tile by tile in
/// parallel, which leaves the grid exactly as inserting them one by one would: planar scans
/// as one batch ([`OccupancyGrid::insert_planar_batch`]: one mask with a mark per scan, each
/// cell visited once), scans with heights on a grid with bins scan by scan
/// ([`OccupancyGrid::trace_updates_part`] / [`OccupancyGrid::apply_updates`]). `grid` is
/// complete after a flush.
#[derive(Debug, Clone)]
pub struct BestParticleMap {
    /// The map.
    pub grid: OccupancyGrid,
    /// One scratch per tracing task (a mask of megabytes each: reused, never per scan).
    scratches: Vec<InsertScratch>,
    /// The same for batches of planar scans ([`OccupancyGrid::insert_planar_batch`]).
    batches: Vec<BatchScratch>,
    /// With [`Self::log_changes`]: the cells changed since the log was last taken, and
    /// whether the log is complete (false after an insertion that does not log).
    log: Option<(ChangeLog, bool)>,
    /// Queued world-frame scans: the first `queued` are pending (the rest keep allocations).
    pending: Vec<PlanarScan>,
    queued: usize,
    traced: Vec<ScanUpdates>,
    /// Where a scan cut between two threads may be cut, and the work before each place
    /// ([`split_rays`], [`OccupancyGrid::trace_cuts`]).
    weights: Vec<(usize, u64)>,
}

impl BestParticleMap {
    /// A policy around an (empty) grid.
    pub fn new(grid: OccupancyGrid) -> Self {
        BestParticleMap {
            grid,
            scratches: vec![InsertScratch::new()],
            batches: Vec::new(),
            log: None,
            pending: Vec::new(),
            queued: 0,
            traced: Vec::new(),
            weights: Vec::new(),
        }
    }
}

impl ParticleMaps for BestParticleMap {
    type Map = OccupancyGrid;
    fn map_of(&self, _i: usize) -> &OccupancyGrid {
        &self.grid
    }
}

impl MapPolicy for BestParticleMap {
    fn log_changes(&mut self, threshold: i16) {
        self.log = Some((
            ChangeLog {
                threshold,
                changes: Vec::new(),
            },
            true,
        ));
    }
    fn take_changes<R>(
        &mut self,
        _best: usize,
        use_changes: impl FnOnce(&OccupancyGrid, Option<&[CellChange]>) -> R,
    ) -> R {
        match &mut self.log {
            Some((log, complete)) => {
                let r = use_changes(&self.grid, complete.then_some(&log.changes[..]));
                log.changes.clear();
                *complete = true;
                r
            }
            None => use_changes(&self.grid, None),
        }
    }
    fn integrate(
        &mut self,
        poses: &[Pose2],
        best: usize,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError> {
        let pose = poses.get(best).copied().unwrap_or_default();
        if self.pending.len() <= self.queued {
            self.pending.push(PlanarScan::default());
        }
        to_world(body_scan, &pose, &mut self.pending[self.queued]);
        self.queued += 1;
        Ok(())
    }
    fn integrate_at(
        &mut self,
        world_from_body: &Pose2,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError> {
        self.integrate(std::slice::from_ref(world_from_body), 0, body_scan)
    }
    fn resampled(&mut self, _ancestors: &[usize]) {}
    fn map_for_output(&self, _best: usize) -> &OccupancyGrid {
        &self.grid
    }
    fn flush(&mut self) -> Result<(), MapError> {
        let n = std::mem::take(&mut self.queued);
        if n == 0 {
            return Ok(());
        }
        let threads = rayon::current_num_threads().max(1);
        if n == 1 && threads == 1 && self.log.is_none() {
            self.grid
                .insert_scan(&self.pending[0], &mut self.scratches[0])?;
            return Ok(());
        }
        // Run on a pool thread: one hand-over to the pool per flush instead of one per
        // parallel phase (tracing, applying).
        if self.pending[..n].iter().any(|s| self.grid.uses_heights(s)) {
            // Not logged: whoever reads the log starts over.
            if let Some(log) = &mut self.log {
                log.1 = false;
            }
            rayon::scope(|_| self.flush_queued(n, threads))
        } else {
            let Self {
                grid,
                pending,
                batches,
                weights,
                log,
                ..
            } = self;
            let log = log.as_mut().map(|l| &mut l.0);
            rayon::scope(|_| {
                grid.insert_planar_batch(&pending[..n], threads, batches, weights, log)
            })
        }
    }
}

impl BestParticleMap {
    /// [`MapPolicy::flush`] of the `n` queued scans on `threads` threads, scan by scan (scans
    /// with heights on a grid with bins).
    fn flush_queued(&mut self, n: usize, threads: usize) -> Result<(), MapError> {
        // The scans' rays, in order, cut into one contiguous run per thread with about the
        // same number of cells to walk (a scan may be cut in two: its pieces are applied as
        // the whole scan). Tracing reads the grid's geometry only, so the runs are
        // independent; the updates are applied in scan order.
        let pieces = split_rays(&self.grid, &self.pending[..n], threads, &mut self.weights);
        if self.scratches.len() < pieces.len() {
            self.scratches.resize_with(pieces.len(), InsertScratch::new);
        }
        let total: usize = pieces.iter().map(Vec::len).sum();
        if self.traced.len() < total {
            self.traced.resize_with(total, ScanUpdates::new);
        }
        let mut outs: Vec<&mut [ScanUpdates]> = Vec::with_capacity(pieces.len());
        let mut rest = &mut self.traced[..total];
        for run in &pieces {
            let (head, tail) = rest.split_at_mut(run.len());
            outs.push(head);
            rest = tail;
        }
        let grid = &self.grid;
        let scans = &self.pending[..n];
        let traced: Result<(), MapError> = outs
            .into_par_iter()
            .zip(pieces.par_iter())
            .zip(self.scratches.par_iter_mut())
            .try_for_each(|((out, run), scratch)| {
                for (updates, (k, rays)) in out.iter_mut().zip(run) {
                    grid.trace_updates_part(&scans[*k], rays.clone(), scratch, updates)?;
                }
                Ok(())
            });
        traced?;
        let updates: Vec<&ScanUpdates> = self.traced[..total].iter().collect();
        self.grid.apply_updates(&updates);
        Ok(())
    }
}

/// Wall-clock seconds spent per stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageTimings {
    /// Ranges -> body-frame points.
    pub preprocess_s: f64,
    /// Motion model sampling.
    pub predict_s: f64,
    /// Correlation search and reweighting.
    pub correlate_s: f64,
    /// Of `correlate_s`: the likelihood fields (`scan_match`).
    pub field_s: f64,
    /// Resampling.
    pub resample_s: f64,
    /// Map insertion.
    pub map_update_s: f64,
    /// The whole loop.
    pub total_s: f64,
}

/// Counts and statistics of a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SlamStats {
    /// Particles.
    pub particles: usize,
    /// The filter mode that ran (`auto` resolved).
    pub mode: FilterMode,
    /// Seed of the random streams.
    pub seed: u64,
    /// Scans in the recording.
    pub scans_total: usize,
    /// Scans with a pose in the output (inside the odometry's time span).
    pub scans_processed: usize,
    /// Scans skipped because the odometry does not cover them.
    pub scans_skipped: usize,
    /// Odometry steps predicted.
    pub odometry_steps: usize,
    /// Update steps (correlation + reweight + map).
    pub updates: usize,
    /// Resampling events.
    pub resamples: usize,
    /// Neff after reweighting: minimum over updates.
    pub neff_min: f64,
    /// Neff after reweighting: mean over updates.
    pub neff_mean: f64,
    /// Neff after reweighting at the last update.
    pub neff_last: f64,
    /// Mean correlation score (occupied cells hit) of the best particle.
    pub best_score_mean: f64,
    /// Time per stage.
    pub timings: StageTimings,
    /// Tiles held by the particles' maps at the end (`rbpf` mode only).
    pub map_memory: Option<super::rbpf::MapMemory>,
}

impl SlamStats {
    /// Turns the sums over updates into means (Neff = the particle count without updates).
    pub(crate) fn finish_means(&mut self, neff_sum: f64, score_sum: f64) {
        if self.updates > 0 {
            self.neff_mean = neff_sum / self.updates as f64;
            self.best_score_mean = score_sum / self.updates as f64;
        } else {
            let n = self.particles as f64;
            (self.neff_min, self.neff_mean, self.neff_last) = (n, n, n);
        }
    }
}

/// What a run produced.
#[derive(Debug, Clone)]
pub struct SlamResult {
    /// The best particle's pose at every processed scan (odometry composed onto the last
    /// estimate between updates).
    pub trajectory: Vec<StampedPose2>,
    /// The odometry pose at every processed scan (dead reckoning, same frame).
    pub dead_reckoning: Vec<StampedPose2>,
    /// The final map.
    pub map: OccupancyGrid,
    /// Counts, Neff and timings.
    pub stats: SlamStats,
}

/// Progress reports of [`run_slam`].
#[derive(Debug)]
pub enum SlamEvent<'a> {
    /// `done` of `total` scans handled.
    Progress {
        /// Scans handled.
        done: usize,
        /// Scans in the recording.
        total: usize,
    },
    /// A map snapshot after `scan_index` scans (every `filter.snapshot_every_scans`).
    Snapshot {
        /// Number of scans handled so far.
        scans_done: usize,
        /// The current map.
        map: &'a OccupancyGrid,
        /// The trajectory so far.
        trajectory: &'a [StampedPose2],
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

/// Odometry composed without noise: the reference of [`ParticleFilter::predict_exact`].
#[cfg(test)]
struct ExactOdometry;

#[cfg(test)]
impl MotionModel for ExactOdometry {
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        _rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2 {
        pose.compose(&from.pose.between(&to.pose))
    }
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
mod tests {
    use super::*;

    #[test]
    fn exact_prediction_equals_the_per_particle_odometry_bit_for_bit() {
        use rand::{RngExt, SeedableRng};
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
        let mut odo = |t: i64| StampedPose2 {
            stamp_ns: t,
            pose: Pose2::new(
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
                rng.random_range(-3.2..3.2),
            ),
        };
        let mut steps = Vec::new();
        let mut prev = odo(0);
        for t in 1..40 {
            let next = odo(t);
            steps.push((prev, next));
            prev = next;
        }
        for n in [1, 7, 100, 300] {
            let mut a = ParticleFilter::new(n, Pose2::new(1.0, -2.0, 0.3), 5);
            a.jitter(0.5, 0.2);
            let mut b = a.clone();
            a.predict_steps(&steps, &ExactOdometry);
            b.predict_exact(&steps, &mut Vec::new());
            for (p, q) in a.particles.poses.iter().zip(&b.particles.poses) {
                assert_eq!(
                    [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits),
                    [q.x_m, q.y_m, q.yaw_rad].map(f64::to_bits),
                    "{n} particles"
                );
            }
        }
    }
}

#[cfg(test)]
mod flush_tests {
    use super::*;
    use crate::map::{MapOptions, ScanPoint};
    use rand::{RngExt, SeedableRng};

    fn random_body_scan(rng: &mut Xoshiro256PlusPlus, points: usize, heights: bool) -> PlanarScan {
        let range_max = rng.random_range(0.5..12.0);
        PlanarScan {
            sensor_x_m: 0.3,
            sensor_y_m: 0.0,
            sensor_z_m: heights.then_some(1.5),
            points: (0..points)
                .map(|_| {
                    let a = rng.random_range(-3.2..3.2f64);
                    let r = rng.random_range(0.0..range_max);
                    ScanPoint {
                        x_m: 0.3 + r * a.cos(),
                        y_m: r * a.sin(),
                        hit: rng.random_range(0..3) > 0,
                        free_to: if rng.random_range(0..4) == 0 {
                            rng.random_range(0.0..1.0)
                        } else {
                            1.0
                        },
                        z_m: rng.random_range(-1.0..4.0),
                    }
                })
                .collect(),
        }
    }

    /// Same allocated tiles, cells and bins (not the same directory: its slack depends on
    /// the order tiles are created, and a batch creates them in its mask's order).
    fn assert_same_grid(a: &OccupancyGrid, b: &OccupancyGrid, label: &str) {
        assert_eq!(a.tile_count(), b.tile_count(), "{label}");
        assert_eq!(a.height_tile_count(), b.height_tile_count(), "{label}");
        let r = a.allocated_bounds();
        assert_eq!(r, b.allocated_bounds(), "{label}");
        let Some(r) = r else { return };
        let (mut va, mut vb) = (Vec::new(), Vec::new());
        a.copy_rect_fixed(&r, &mut va);
        b.copy_rect_fixed(&r, &mut vb);
        assert!(va == vb, "{label}: cells differ");
        for j in r.min_j..=r.max_j {
            for i in r.min_i..=r.max_i {
                let c = crate::map::Cell { i, j };
                assert_eq!(a.height_bins(c), b.height_bins(c), "{label}: bins of {c:?}");
            }
        }
    }

    #[test]
    fn split_rays_cover_every_ray_once_in_order() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let grid = OccupancyGrid::new(&MapOptions::default()).unwrap();
        let mut cum = Vec::new();
        for case in 0..200 {
            let n = rng.random_range(0..8);
            let scans: Vec<PlanarScan> = (0..n)
                .map(|_| {
                    let k = rng.random_range(0..40);
                    random_body_scan(&mut rng, k, false)
                })
                .collect();
            let parts = rng.random_range(1..5);
            let runs = split_rays(&grid, &scans, parts, &mut cum);
            assert!(runs.len() <= parts, "case {case}");
            let mut flat = Vec::new();
            for run in &runs {
                assert!(!run.is_empty(), "case {case}");
                for (k, rays) in run {
                    assert!(!rays.is_empty(), "case {case}");
                    flat.extend(rays.clone().map(|r| (*k, r)));
                }
            }
            let want: Vec<(usize, usize)> = scans
                .iter()
                .enumerate()
                .flat_map(|(k, s)| (0..s.points.len()).map(move |r| (k, r)))
                .collect();
            assert_eq!(flat, want, "case {case}");
        }
        // Five like scans on two threads: two and a half each, the middle scan cut.
        let scan = random_body_scan(&mut rng, 100, false);
        let scans = vec![scan; 5];
        let runs = split_rays(&grid, &scans, 2, &mut cum);
        assert_eq!(runs.len(), 2);
        assert_eq!(runs[0].len(), 3);
        assert_eq!(runs[1].len(), 3);
        assert_eq!(runs[0][2].0, 2);
        assert_eq!(runs[1][0].0, 2);
        assert_eq!(runs[0][2].1.end, runs[1][0].1.start);
    }

    #[test]
    fn flush_equals_inserting_the_scans_one_by_one_for_any_thread_count() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
        for case in 0..12 {
            let mut opts = MapOptions {
                resolution_m: [0.1, 0.25][case % 2],
                free_margin_m: [0.0, 0.2][(case / 2) % 2],
                ..MapOptions::default()
            };
            opts.height.enabled = (case / 4) % 3 == 1;
            // Clamping-heavy cases: a cell reaches a bound in two updates, so the order of
            // its updates decides its value.
            if (case / 4) % 3 == 2 {
                opts.log_odds.hit = 20.0;
                opts.log_odds.miss = -20.0;
                opts.log_odds.clamp_min = -40.0;
                opts.log_odds.clamp_max = 40.0;
            }
            let heights = opts.height.enabled;
            // Flushes of 1 to 7 scans from poses near each other (as between two updates).
            let mut flushes = Vec::new();
            for _ in 0..8 {
                let k = rng.random_range(1..8);
                let scans: Vec<(Pose2, PlanarScan)> = (0..k)
                    .map(|_| {
                        let pose = Pose2::new(
                            rng.random_range(-1.0..1.0),
                            rng.random_range(-1.0..1.0),
                            rng.random_range(-3.0..3.0),
                        );
                        let points = rng.random_range(0..120);
                        (pose, random_body_scan(&mut rng, points, heights))
                    })
                    .collect();
                flushes.push(scans);
            }
            let mut want = OccupancyGrid::new(&opts).unwrap();
            let mut scratch = InsertScratch::new();
            let mut world = PlanarScan::default();
            for (pose, scan) in flushes.iter().flatten() {
                to_world(scan, pose, &mut world);
                want.insert_scan(&world, &mut scratch).unwrap();
            }
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut policy = BestParticleMap::new(OccupancyGrid::new(&opts).unwrap());
                for scans in &flushes {
                    for (pose, scan) in scans {
                        policy.integrate_at(pose, scan).unwrap();
                    }
                    pool.install(|| policy.flush()).unwrap();
                }
                assert_same_grid(
                    &want,
                    &policy.grid,
                    &format!("case {case}, {threads} threads"),
                );
            }
        }
    }
}
