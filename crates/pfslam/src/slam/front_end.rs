//! The filters fed one scan at a time ([`FrontEnd`], one per mode), the step that hands
//! them a scan ([`feed_scan`], shared by the batch loop [`drive`] and [`crate::Slam`]);
//! here the `scan_match` and `seed` modes' front end.

use super::*;
use crate::filter::UpdateReport;
use crate::matching::correlation::hit_points;
use crate::matching::likelihood_field::cache::FieldCache;

/// A filter fed one scan at a time.
pub trait FrontEnd {
    /// Handles scan `i` of `recording` at odometry pose `odom`, reached through the
    /// odometry `steps` since the last scan; reports updates, progress and snapshots to
    /// `observer`. Every call gets the same recording, which may have grown since the last
    /// (live input).
    fn step(
        &mut self,
        recording: &Recording,
        i: usize,
        odom: StampedPose2,
        steps: &[(StampedPose2, StampedPose2)],
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<(), SlamError>;

    /// Counts a scan left out (no odometry at its stamp).
    fn skip(&mut self);

    /// The pose of the latest scan handled, `None` before the first.
    fn latest_pose(&self) -> Option<StampedPose2>;

    /// The map of the best particle now (its pending insertions applied first).
    fn current_map(&mut self) -> Result<&OccupancyGrid, SlamError>;

    /// The trajectory, odometry, map and statistics; `t_start` began the run.
    fn finish(self, recording: &Recording, t_start: Instant) -> Result<SlamResult, SlamError>;

    /// The scans handled since the last window (or the start), as `finish` would give
    /// their poses; the caller then lets the first `let_go` scans of `recording` go (later
    /// indices shift down by that much). `None` where the front end needs every scan at its
    /// finish (nothing may be let go then).
    fn take_window(
        &mut self,
        _recording: &Recording,
        _let_go: usize,
    ) -> Result<Option<Window>, SlamError> {
        Ok(None)
    }
}

/// Hands scan `i` of `recording` to `front`, with the odometry interpolated at its stamp by
/// `cursor` and the odometry steps since the last scan (gathered in `steps`); a scan the
/// odometry does not reach is counted as skipped. The batch loop ([`drive`]) and the
/// incremental API ([`crate::Slam`]) both feed scans through here.
pub(crate) fn feed_scan<F: FrontEnd + ?Sized>(
    front: &mut F,
    recording: &Recording,
    i: usize,
    (cursor, steps): (&mut OdometryCursor, &mut Vec<(StampedPose2, StampedPose2)>),
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<(), SlamError> {
    steps.clear();
    let stamp_ns = recording.scans.stamps_ns[i];
    let Some(odom) = cursor.advance_to(&recording.odometry, stamp_ns, |a, b| steps.push((*a, *b)))
    else {
        front.skip();
        return Ok(());
    };
    front.step(recording, i, odom, steps, observer)?;
    if let Some(pose) = front.latest_pose() {
        observer(SlamEvent::Pose(pose));
    }
    Ok(())
}

/// The one driver loop of every mode: each scan from `first` on, with the odometry
/// interpolated at its stamp by `cursor` (and the odometry steps since the last scan), is
/// handed to `front`.
pub(crate) fn drive<F: FrontEnd>(
    recording: &Recording,
    (first, mut cursor): (usize, OdometryCursor),
    mut front: F,
    t_start: Instant,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    let mut steps: Vec<(StampedPose2, StampedPose2)> = Vec::new();
    for i in first..recording.scans.len() {
        feed_scan(
            &mut front,
            recording,
            i,
            (&mut cursor, &mut steps),
            observer,
        )?;
    }
    front.finish(recording, t_start)
}

/// The state of a `scan_match` or `seed` run between scans.
pub struct MatchFrontEnd<P: MapPolicy> {
    config: Config,
    mode: FilterMode,
    motion: Box<dyn MotionModel>,
    policy: P,
    projector: ScanProjector,
    search: CorrelationSearch,
    pf: ParticleFilter,
    stats: SlamStats,
    trajectory: Vec<StampedPose2>,
    dead_reckoning: Vec<StampedPose2>,
    body: PlanarScan,
    hits: Vec<[f64; 2]>,
    match_pts: Vec<[f64; 2]>,
    field: likelihood_field::LikelihoodField,
    field_cache: FieldCache,
    match_params: likelihood_field::MatchParams,
    resample_threshold: f64,
    increments: Vec<Pose2>,
    last_estimate: Pose2,
    last_update_odom: Pose2,
    neff_sum: f64,
    score_sum: f64,
    /// The index of the first scan handled.
    first: usize,
}

impl<P: MapPolicy> MatchFrontEnd<P> {
    /// The particles at the odometry's pose `start` at scan `first`, the map `policy`'s.
    pub fn new(
        recording: &Recording,
        config: &Config,
        seed: u64,
        motion: Box<dyn MotionModel>,
        mut policy: P,
        (start, first): (Pose2, usize),
    ) -> Result<Self, SlamError> {
        let opts = &config.filter;
        // `rbpf` (from `auto` too) reaches here only through the explicit-policy entry
        // point; it then runs the scan-matching loop with the given policy.
        let mode = opts.mode.resolve(recording);
        let total = recording.scans.len();
        let projector = ScanProjector::new(
            &recording.lidar,
            &recording.body_from_lidar,
            &config.map.scan.for_filter(),
        )?;
        let stats = SlamStats {
            particles: opts.particles,
            mode,
            seed,
            scans_total: total,
            scans_skipped: first,
            neff_min: f64::INFINITY,
            ..SlamStats::default()
        };
        let field = likelihood_field::LikelihoodField::new();
        policy.log_changes(field.source_threshold_on(policy.map_for_output(0)));
        let resample_threshold = match mode {
            FilterMode::Seed => opts.resample_threshold,
            FilterMode::ScanMatch | FilterMode::Rbpf | FilterMode::Auto => {
                opts.scan_match.resample_threshold
            }
        };
        Ok(MatchFrontEnd {
            config: config.clone(),
            mode,
            motion,
            policy,
            projector,
            search: opts.search(),
            pf: ParticleFilter::new(opts.particles, start, seed),
            stats,
            trajectory: Vec::with_capacity(total - first),
            dead_reckoning: Vec::with_capacity(total - first),
            body: PlanarScan::default(),
            hits: Vec::new(),
            match_pts: Vec::new(),
            field,
            field_cache: FieldCache::new(),
            match_params: opts.scan_match.params(config.map.resolution_m),
            resample_threshold,
            increments: Vec::new(),
            last_estimate: start,
            last_update_odom: start,
            neff_sum: 0.0,
            score_sum: 0.0,
            first,
        })
    }

    /// A filter update with scan `i`, the `k`-th since the first; returns the estimate.
    fn update(
        &mut self,
        recording: &Recording,
        i: usize,
        k: usize,
        odom: StampedPose2,
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<Pose2, SlamError> {
        let t = Instant::now();
        self.projector.aim(recording, i);
        let ranges = recording.scans.ranges(i);
        self.projector.to_body(ranges, &mut self.body)?;
        hit_points(&self.body, &mut self.hits);
        self.stats.timings.preprocess_s += t.elapsed().as_secs_f64();
        let best = if k == 0 {
            // The first scan seeds the map at the start pose; nothing to correlate with.
            0
        } else {
            self.weigh()?
        };
        let estimate = self.pf.particles.poses[best];
        let t = Instant::now();
        self.policy
            .integrate(&self.pf.particles.poses, best, &self.body)?;
        self.stats.timings.map_update_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let method = self.config.filter.resample_method;
        if k > 0
            && let Some(ancestors) = self.pf.resample_if_needed(self.resample_threshold, method)
        {
            self.policy.resampled(ancestors);
            self.stats.resamples += 1;
        }
        self.stats.timings.resample_s += t.elapsed().as_secs_f64();
        self.last_estimate = estimate;
        self.last_update_odom = odom.pose;
        observer(SlamEvent::Update {
            stamp_ns: odom.stamp_ns,
            particles: &self.pf.particles.poses,
            map: None,
        });
        Ok(estimate)
    }

    /// Weighs the particles against the map (the seeds' correlation, or a scan match per
    /// particle); returns the best particle.
    fn weigh(&mut self) -> Result<usize, SlamError> {
        let t = Instant::now();
        self.policy.flush()?;
        self.stats.timings.map_update_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let opts = &self.config.filter;
        let report = match self.mode {
            FilterMode::Seed => self.pf.reweight(
                &self.policy,
                &self.hits,
                &self.search,
                opts.temperature,
                opts.move_to_best_offset,
            ),
            FilterMode::ScanMatch | FilterMode::Rbpf | FilterMode::Auto => self.scan_match(),
        };
        let stats = &mut self.stats;
        stats.timings.correlate_s += t.elapsed().as_secs_f64();
        stats.updates += 1;
        self.neff_sum += report.neff;
        self.score_sum += f64::from(report.best_score);
        stats.neff_min = stats.neff_min.min(report.neff);
        stats.neff_last = report.neff;
        Ok(report.best)
    }

    /// Every particle matched in the likelihood field of the best one's map, then sampled
    /// around its match.
    fn scan_match(&mut self) -> UpdateReport {
        let sm = &self.config.filter.scan_match;
        let pf = &mut self.pf;
        likelihood_field::match_points(
            &self.body,
            sm.match_range_max_m,
            sm.beam_decimation,
            &mut self.match_pts,
        );
        let grid = self.policy.map_for_output(pf.particles.best_index());
        let rect = field_window(
            grid.limits(),
            &pf.particles.poses,
            pf.best_pose(),
            &self.match_pts,
            self.match_params.xy_radius_cells + 2,
        );
        let tb = Instant::now();
        // The field from its cache (the map's changes since the last update).
        let (field, cache) = (&mut self.field, &mut self.field_cache);
        self.policy
            .take_changes(pf.particles.best_index(), |grid, changes| {
                field.build_cached(
                    grid,
                    &rect,
                    sm.field_sigma_m,
                    sm.unknown_value,
                    cache,
                    changes,
                )
            });
        self.stats.timings.field_s += tb.elapsed().as_secs_f64();
        let report = pf.scan_match_update(
            &self.field,
            &self.match_pts,
            &self.match_params,
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

    /// The pose of scan `i` between updates: the last estimate moved by the odometry (the
    /// scan mapped there when `map_between_updates` or in `scan_match` mode).
    fn between_updates(
        &mut self,
        recording: &Recording,
        i: usize,
        odom: StampedPose2,
    ) -> Result<Pose2, SlamError> {
        let estimate = self
            .last_estimate
            .compose(&self.last_update_odom.between(&odom.pose));
        if self.config.filter.map_between_updates || self.mode == FilterMode::ScanMatch {
            // Insert this scan at the composed pose: the map then reaches up to the
            // latest scan when the next update correlates against it.
            let t = Instant::now();
            self.projector.aim(recording, i);
            let ranges = recording.scans.ranges(i);
            self.projector.to_body(ranges, &mut self.body)?;
            self.stats.timings.preprocess_s += t.elapsed().as_secs_f64();
            let t = Instant::now();
            self.policy.integrate_at(&estimate, &self.body)?;
            self.stats.timings.map_update_s += t.elapsed().as_secs_f64();
        }
        Ok(estimate)
    }

    /// Progress after `done` of the `total` scans, and a map snapshot when one is due.
    fn report(
        &mut self,
        (done, total): (usize, usize),
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<(), SlamError> {
        let every = self.config.filter.snapshot_every_scans;
        if report_progress(observer, done, total, &self.stats, every) {
            self.policy.flush()?;
            observer(SlamEvent::Snapshot {
                scans_done: done,
                map: self.policy.map_for_output(self.pf.particles.best_index()),
                trajectory: &self.trajectory,
            });
        }
        Ok(())
    }
}

impl<P: MapPolicy> FrontEnd for MatchFrontEnd<P> {
    /// The particles predicted along the odometry `steps`, then an update every
    /// `update_every_scans` scans, else the last estimate moved by the odometry.
    fn step(
        &mut self,
        recording: &Recording,
        i: usize,
        odom: StampedPose2,
        steps: &[(StampedPose2, StampedPose2)],
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<(), SlamError> {
        let t = Instant::now();
        if let Some(series) = &recording.imu_yaw {
            self.motion.observe_imu_yaw(series);
        }
        self.stats.odometry_steps += steps.len();
        if !steps.is_empty() {
            match self.mode {
                FilterMode::Seed => self.pf.predict_steps(steps, self.motion.as_ref()),
                // The scan match is the proposal: odometry without noise here, the spread
                // comes from sampling around each match.
                FilterMode::ScanMatch | FilterMode::Rbpf | FilterMode::Auto => {
                    self.pf.predict_exact(steps, &mut self.increments)
                }
            }
        }
        self.stats.timings.predict_s += t.elapsed().as_secs_f64();
        let k = i - self.first;
        let estimate = if k.is_multiple_of(self.config.filter.update_every_scans) {
            self.update(recording, i, k, odom, observer)?
        } else {
            self.between_updates(recording, i, odom)?
        };
        self.trajectory.push(StampedPose2 {
            stamp_ns: odom.stamp_ns,
            pose: estimate,
        });
        self.dead_reckoning.push(odom);
        self.stats.scans_processed += 1;
        self.report((i + 1, recording.scans.len()), observer)
    }

    fn skip(&mut self) {
        self.stats.scans_skipped += 1;
    }

    fn latest_pose(&self) -> Option<StampedPose2> {
        self.trajectory.last().copied()
    }

    fn current_map(&mut self) -> Result<&OccupancyGrid, SlamError> {
        self.policy.flush()?;
        Ok(self.policy.map_for_output(self.pf.particles.best_index()))
    }

    fn finish(mut self, recording: &Recording, t_start: Instant) -> Result<SlamResult, SlamError> {
        let t = Instant::now();
        // Fed incrementally, the recording grew after the filter started.
        self.stats.scans_total = recording.scans.len();
        self.policy.flush()?;
        self.stats.timings.map_update_s += t.elapsed().as_secs_f64();
        self.stats.finish_means(self.neff_sum, self.score_sum);
        self.stats.timings.total_s = t_start.elapsed().as_secs_f64();
        let map = self
            .policy
            .map_for_output(self.pf.particles.best_index())
            .clone();
        Ok(SlamResult {
            trajectory: self.trajectory,
            dead_reckoning: self.dead_reckoning,
            map,
            stats: self.stats,
        })
    }
}
