//! The Rao-Blackwellised filter's driver over a recording ([`crate::filter::rbpf`]), and the
//! final re-matching of every pose.

use super::{FrontEnd, SlamError, SlamEvent, SlamResult, SlamStats};
use crate::config::Config;
use crate::filter::rbpf::{Rbpf, RbpfOptions, UpdateScan, path_poses_from};
use crate::geometry::{Pose2, StampedPose2};
use crate::map::{MapError, OccupancyGrid, PlanarScan, ScanProjector};
use crate::matching::likelihood_field::match_points;
use crate::matching::nearest_occupied::{MatchPrior, match_in_own_map};
use crate::sensors::Recording;
use rayon::prelude::*;
use std::time::Instant;

/// Runs the Rao-Blackwellised filter on `recording` (see the module docs).
pub fn run_rbpf(
    recording: &Recording,
    config: &Config,
    seed: u64,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    run_rbpf_in(recording, config, seed, observer, None)
}

/// A map to continue: earlier scans at their poses in the map frame, and where the new
/// recording's odometry frame lies in it.
#[derive(Debug, Clone, Copy)]
pub struct PriorMap<'a> {
    /// The earlier scans (their own geometry and mount).
    pub recording: &'a Recording,
    /// The pose of each of those scans in the map frame.
    pub world_from_body: &'a [Pose2],
    /// The new recording's odometry frame in the map frame.
    pub world_from_odom: Pose2,
}

/// [`run_rbpf`], the particles starting in `prior`'s map (every particle holds it) at the
/// pose `prior.world_from_odom` gives the first scan; without a prior, in an empty map at
/// the first odometry pose.
pub fn run_rbpf_in(
    recording: &Recording,
    config: &Config,
    seed: u64,
    observer: &mut dyn FnMut(SlamEvent<'_>),
    prior: Option<&PriorMap<'_>>,
) -> Result<SlamResult, SlamError> {
    let t_start = Instant::now();
    let (first, cursor) = super::check_and_start(recording, config)?;
    let odom_start = cursor.current().pose;
    let front = RbpfFrontEnd::new(recording, config, seed, prior, odom_start)?.skipped(first);
    super::drive(recording, (first, cursor), front, t_start, observer)
}

/// The filter fed one scan at a time, with its odometry pose: what [`run_rbpf_in`] runs
/// over a recording.
pub struct RbpfFrontEnd {
    opts: crate::filter::FilterOptions,
    pf: Rbpf,
    projector: ScanProjector,
    stats: SlamStats,
    /// The odometry pose of each processed scan since `window_start`.
    dead_reckoning: Vec<StampedPose2>,
    /// The recording's index of each processed scan since `window_start`.
    scan_index: Vec<usize>,
    /// How many processed scans earlier windows took ([`RbpfFrontEnd::take_window`]).
    window_start: usize,
    /// The odometry pose of the latest processed scan.
    latest_odom: Option<StampedPose2>,
    /// Scans the recording let go with earlier windows (counted in progress and in
    /// `scans_total`).
    released_scans: usize,
    body: PlanarScan,
    pts: Vec<[f64; 2]>,
    poses: Vec<Pose2>,
    last_update_odom: Pose2,
    neff_sum: f64,
    ll_sum: f64,
    have_first: bool,
}

impl RbpfFrontEnd {
    /// The particles at the start (see [`run_rbpf_in`]), the first odometry pose
    /// `odom_start`.
    pub fn new(
        recording: &Recording,
        config: &Config,
        seed: u64,
        prior: Option<&PriorMap<'_>>,
        odom_start: Pose2,
    ) -> Result<Self, SlamError> {
        let opts = &config.filter;
        let ro = &opts.rbpf;
        let start = prior.map_or(odom_start, |p| p.world_from_odom.compose(&odom_start));
        let mut map_opts = config.map.clone();
        if ro.resolution_m > 0.0 {
            map_opts.resolution_m = ro.resolution_m;
        }
        let mut grid = OccupancyGrid::new(&map_opts)?;
        let mut scan_opts = config.map.scan.for_filter();
        scan_opts.range_min_m = ro.range_min_m as f32;
        if !ro.densify {
            scan_opts.densify_max_gap_m = None;
        }
        scan_opts.validate().map_err(MapError::Options)?;
        if let Some(p) = prior {
            insert_prior(&mut grid, p, &scan_opts, ro.range_max_m)?;
        }
        let projector =
            ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &scan_opts)?;
        let total = recording.scans.len();
        let stats = SlamStats {
            particles: opts.particles,
            mode: crate::filter::FilterMode::Rbpf,
            seed,
            scans_total: total,
            neff_min: f64::INFINITY,
            ..SlamStats::default()
        };
        Ok(RbpfFrontEnd {
            opts: opts.clone(),
            pf: Rbpf::new(opts.particles, start, odom_start, grid, ro, seed),
            projector,
            stats,
            dead_reckoning: Vec::with_capacity(total),
            scan_index: Vec::with_capacity(total),
            window_start: 0,
            latest_odom: None,
            released_scans: 0,
            body: PlanarScan::default(),
            pts: Vec::new(),
            poses: Vec::with_capacity(opts.particles),
            last_update_odom: odom_start,
            neff_sum: 0.0,
            ll_sum: 0.0,
            have_first: false,
        })
    }
}

impl FrontEnd for RbpfFrontEnd {
    /// A filter update once the odometry moved far enough since the last one (the odometry
    /// steps between are not needed: the update composes the whole increment).
    fn step(
        &mut self,
        recording: &Recording,
        i: usize,
        odom: StampedPose2,
        _steps: &[(StampedPose2, StampedPose2)],
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<(), SlamError> {
        let ro = &self.opts.rbpf;
        let k = self.window_start + self.dead_reckoning.len();
        self.dead_reckoning.push(odom);
        self.latest_odom = Some(odom);
        self.scan_index.push(i);
        let delta = self.last_update_odom.between(&odom.pose);
        let due = !self.have_first
            || delta.translation_norm_m() >= ro.linear_update_m
            || delta.yaw_rad.abs() >= ro.angular_update_deg.to_radians();
        if due {
            self.update(recording, i, k, odom, &delta)?;
            self.poses.clear();
            self.poses.extend(self.pf.particles.iter().map(|p| p.pose));
            observer(SlamEvent::Update {
                stamp_ns: odom.stamp_ns,
                particles: &self.poses,
                map: Some(&self.pf.particles[self.pf.best()].map),
            });
        }
        self.stats.scans_processed += 1;
        let released = self.released_scans;
        self.report(
            (released + i + 1, released + recording.scans.len()),
            observer,
        );
        Ok(())
    }

    fn skip(&mut self) {
        self.stats.scans_skipped += 1;
    }

    fn current_map(&mut self) -> Result<&OccupancyGrid, SlamError> {
        Ok(&self.pf.particles[self.pf.best()].map)
    }

    /// The best particle's pose at its last update moved by the odometry since.
    fn latest_pose(&self) -> Option<StampedPose2> {
        let odom = self.latest_odom.as_ref()?;
        let best = &self.pf.particles[self.pf.best()];
        Some(StampedPose2 {
            stamp_ns: odom.stamp_ns,
            pose: best
                .pose
                .compose(&self.last_update_odom.between(&odom.pose)),
        })
    }

    fn take_window(
        &mut self,
        recording: &Recording,
        let_go: usize,
    ) -> Result<Option<Window>, SlamError> {
        let trajectory = self.window_path(recording)?;
        let dead_reckoning = std::mem::take(&mut self.dead_reckoning);
        self.window_start += dead_reckoning.len();
        self.released_scans += let_go;
        self.scan_index.clear();
        Ok(Some(Window {
            trajectory,
            dead_reckoning,
        }))
    }

    /// The best particle's whole path (each pose re-matched in its final map with
    /// `final_refine.enabled`), its map and the statistics.
    fn finish(mut self, recording: &Recording, t_start: Instant) -> Result<SlamResult, SlamError> {
        // Fed incrementally, the recording grew after the filter started.
        self.stats.scans_total = self.released_scans + recording.scans.len();
        self.stats.odometry_steps = self.window_start + self.dead_reckoning.len();
        self.stats.finish_means(self.neff_sum, self.ll_sum);
        let trajectory = self.window_path(recording)?;
        self.stats.timings.total_s = t_start.elapsed().as_secs_f64();
        let best = &self.pf.particles[self.pf.best()];
        self.stats.map_memory = Some(self.pf.map_memory());
        Ok(SlamResult {
            trajectory,
            dead_reckoning: self.dead_reckoning,
            map: best.map.clone(),
            stats: self.stats,
        })
    }
}

impl RbpfFrontEnd {
    /// The best particle's path over the scans processed since the window's start, each
    /// pose re-matched in its map now with `final_refine.enabled`.
    fn window_path(&mut self, recording: &Recording) -> Result<Vec<StampedPose2>, MapError> {
        let ro = &self.opts.rbpf;
        let best = &self.pf.particles[self.pf.best()];
        let mut trajectory = path_poses_from(&best.node, &self.dead_reckoning, self.window_start);
        if ro.final_refine.enabled && recording.body_from_lidar_per_scan.is_none() {
            let t = Instant::now();
            let scans = (self.scan_index.as_slice(), recording);
            refine_in_final_map(&mut trajectory, scans, &self.projector, &best.map, ro)?;
            self.stats.timings.correlate_s += t.elapsed().as_secs_f64();
        }
        Ok(trajectory)
    }

    /// The same, counting the `first` scans before the odometry's start as skipped.
    pub(crate) fn skipped(mut self, first: usize) -> Self {
        self.stats.scans_skipped = first;
        self
    }

    /// One filter update with scan `i`, the `k`-th scan handled.
    fn update(
        &mut self,
        recording: &Recording,
        i: usize,
        k: usize,
        odom: StampedPose2,
        delta: &Pose2,
    ) -> Result<(), SlamError> {
        let ro = &self.opts.rbpf;
        let stats = &mut self.stats;
        let t = Instant::now();
        self.projector.aim(recording, i);
        self.projector
            .to_body(recording.scans.ranges(i), &mut self.body)?;
        clip_scan(&mut self.body, ro.range_max_m);
        match_points(
            &self.body,
            ro.range_max_m,
            ro.beam_decimation,
            &mut self.pts,
        );
        stats.timings.preprocess_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let input = UpdateScan {
            scan_index: k,
            odom_pose: odom.pose,
            odom_delta: delta,
            match_points_m: &self.pts,
            body_scan: &self.body,
            map_only: !self.have_first,
        };
        let report = self.pf.update(&input, self.opts.resample_method)?;
        stats.timings.correlate_s += report.match_s;
        stats.timings.map_update_s += report.map_s;
        stats.timings.resample_s += t.elapsed().as_secs_f64() - report.match_s - report.map_s;
        if self.have_first {
            stats.updates += 1;
            self.neff_sum += report.neff;
            self.ll_sum += report.best_ll_per_point;
            stats.neff_min = stats.neff_min.min(report.neff);
            stats.neff_last = report.neff;
            stats.resamples += usize::from(report.resampled);
        }
        self.have_first = true;
        self.last_update_odom = odom.pose;
        Ok(())
    }

    /// Progress after `done` of the `total` scans, and a map snapshot when one is due.
    fn report(&self, (done, total): (usize, usize), observer: &mut dyn FnMut(SlamEvent<'_>)) {
        let every = self.opts.snapshot_every_scans;
        if super::report_progress(observer, done, total, &self.stats, every) {
            let best = &self.pf.particles[self.pf.best()];
            let trajectory = path_poses_from(&best.node, &self.dead_reckoning, self.window_start);
            observer(SlamEvent::Snapshot {
                scans_done: done,
                map: &best.map,
                trajectory: &trajectory,
            });
        }
    }
}

/// A stretch of the front end's output: a pose and an odometry pose per processed scan.
#[derive(Debug, Clone, Default)]
pub struct Window {
    /// The front end's pose of each scan.
    pub trajectory: Vec<StampedPose2>,
    /// The odometry's pose of each scan.
    pub dead_reckoning: Vec<StampedPose2>,
}

/// Maps `prior`'s scans at their poses into `grid`, as the particles map theirs.
fn insert_prior(
    grid: &mut OccupancyGrid,
    prior: &PriorMap<'_>,
    scan_opts: &crate::map::ScanOptions,
    range_max_m: f64,
) -> Result<(), MapError> {
    let rec = prior.recording;
    let mut projector = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, scan_opts)?;
    let (mut body, mut world) = (PlanarScan::default(), PlanarScan::default());
    let mut scratch = crate::map::InsertScratch::default();
    for (i, pose) in prior
        .world_from_body
        .iter()
        .enumerate()
        .take(rec.scans.len())
    {
        projector.aim(rec, i);
        projector.to_body(rec.scans.ranges(i), &mut body)?;
        clip_scan(&mut body, range_max_m);
        crate::map::to_world(&body, pose, &mut world);
        grid.insert_scan(&world, &mut scratch)?;
    }
    Ok(())
}

/// Re-matches every output pose against the final best map (hill climb only, with a tight
/// prior around the path's pose): the poses between updates come from odometry composed onto
/// the last node, and the odometry's yaw errs most while turning. In parallel over scans;
/// each result depends only on its scan, so any thread count gives the same output.
fn refine_in_final_map(
    trajectory: &mut [StampedPose2],
    (scan_index, recording): (&[usize], &Recording),
    projector: &ScanProjector,
    map: &OccupancyGrid,
    ro: &RbpfOptions,
) -> Result<(), MapError> {
    let res = map.limits().resolution_m();
    let model = ro.observation(res);
    let mut search = ro.search_params(res);
    search.yaw_offsets_rad = vec![0.0];
    search.xy_cells = 0;
    search.step_xy_m = 0.5 * ro.search.step_xy_m;
    search.step_yaw_rad = 0.5 * ro.search.step_yaw_deg.to_radians();
    search.prior = Some(MatchPrior {
        inv_var_xy: 1.0 / ro.final_refine.sigma_xy_m.powi(2),
        inv_var_yaw: 1.0 / ro.final_refine.sigma_yaw_deg.to_radians().powi(2),
    });
    trajectory
        .par_iter_mut()
        .zip(scan_index.par_iter())
        .try_for_each_init(
            || (projector.clone(), PlanarScan::default(), Vec::new()),
            |(projector, body, pts), (sp, &i)| {
                projector.aim(recording, i);
                projector.to_body(recording.scans.ranges(i), body)?;
                clip_scan(body, ro.range_max_m);
                match_points(body, ro.range_max_m, ro.beam_decimation, pts);
                if pts.len() >= 10 {
                    sp.pose = match_in_own_map(map, &model, pts, &sp.pose, &search).0;
                }
                Ok(())
            },
        )
}

/// Turns returns beyond `range_max_m` from the sensor into no-returns (they are neither
/// matched nor mapped: far returns carry more angular error than they help).
fn clip_scan(scan: &mut PlanarScan, range_max_m: f64) {
    let r2 = range_max_m * range_max_m;
    let (sx, sy) = (scan.sensor_x_m, scan.sensor_y_m);
    scan.points.retain(|p| {
        let (dx, dy) = (p.x_m - sx, p.y_m - sy);
        !p.hit || dx * dx + dy * dy <= r2
    });
}
