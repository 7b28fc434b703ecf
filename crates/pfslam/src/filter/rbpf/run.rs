//! The filter's driver over a recording, and the final re-matching of every pose.

use super::*;
use crate::config::Config;
use crate::filter::scanmatch::match_points;
use crate::filter::slam::{SlamError, SlamEvent, SlamResult, SlamStats};
use crate::geometry::{Pose2, StampedPose2};
use crate::map::{MapError, OccupancyGrid, PlanarScan, ScanProjector};
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
    let opts = &config.filter;
    let ro = &opts.rbpf;
    let t_start = Instant::now();
    let (first, mut cursor) = crate::filter::slam::check_and_start(recording, config)?;
    let scans = &recording.scans;
    let total = scans.len();
    let odom_start = cursor.current().pose;
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
    let mut projector =
        ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &scan_opts)?;
    let mut stats = SlamStats {
        particles: opts.particles,
        mode: crate::filter::FilterMode::Rbpf,
        seed,
        scans_total: total,
        scans_skipped: first,
        neff_min: f64::INFINITY,
        ..SlamStats::default()
    };
    let mut pf = Rbpf::new(opts.particles, start, odom_start, grid, ro, seed);
    let mut dead_reckoning: Vec<StampedPose2> = Vec::with_capacity(total - first);
    let mut scan_index: Vec<usize> = Vec::with_capacity(total - first);
    let mut body = PlanarScan::default();
    let mut pts: Vec<[f64; 2]> = Vec::new();
    let mut last_update_odom = odom_start;
    let (mut neff_sum, mut ll_sum) = (0.0, 0.0);
    let angular = ro.angular_update_deg.to_radians();
    let mut have_first = false;
    let mut poses: Vec<Pose2> = Vec::with_capacity(opts.particles);
    for i in first..total {
        let stamp_ns = scans.stamps_ns[i];
        let Some(odom) = cursor.advance_to(stamp_ns, |_, _| {}) else {
            stats.scans_skipped += 1;
            continue;
        };
        let k = dead_reckoning.len();
        dead_reckoning.push(odom);
        scan_index.push(i);
        let delta = last_update_odom.between(&odom.pose);
        let due = !have_first
            || delta.translation_norm_m() >= ro.linear_update_m
            || delta.yaw_rad.abs() >= angular;
        if due {
            let t = Instant::now();
            projector.aim(recording, i);
            projector.to_body(scans.ranges(i), &mut body)?;
            clip_scan(&mut body, ro.range_max_m);
            match_points(&body, ro.range_max_m, ro.beam_decimation, &mut pts);
            stats.timings.preprocess_s += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let input = UpdateScan {
                scan_index: k,
                odom_pose: odom.pose,
                odom_delta: &delta,
                match_points_m: &pts,
                body_scan: &body,
                map_only: !have_first,
            };
            let report = pf.update(&input, opts.resample_method)?;
            stats.timings.correlate_s += report.match_s;
            stats.timings.map_update_s += report.map_s;
            stats.timings.resample_s += t.elapsed().as_secs_f64() - report.match_s - report.map_s;
            if have_first {
                stats.updates += 1;
                neff_sum += report.neff;
                ll_sum += report.best_ll_per_point;
                stats.neff_min = stats.neff_min.min(report.neff);
                stats.neff_last = report.neff;
                stats.resamples += usize::from(report.resampled);
            }
            have_first = true;
            last_update_odom = odom.pose;
            poses.clear();
            poses.extend(pf.particles.iter().map(|p| p.pose));
            observer(SlamEvent::Update {
                stamp_ns,
                particles: &poses,
                map: Some(&pf.particles[pf.best()].map),
            });
        }
        stats.scans_processed += 1;
        let done = i + 1;
        if crate::filter::slam::report_progress(
            observer,
            done,
            total,
            &stats,
            opts.snapshot_every_scans,
        ) {
            let best = &pf.particles[pf.best()];
            let trajectory = path_poses(&best.node, &dead_reckoning);
            observer(SlamEvent::Snapshot {
                scans_done: done,
                map: &best.map,
                trajectory: &trajectory,
            });
        }
    }
    stats.odometry_steps = dead_reckoning.len();
    stats.finish_means(neff_sum, ll_sum);
    let best = &pf.particles[pf.best()];
    let mut trajectory = path_poses(&best.node, &dead_reckoning);
    if ro.final_refine && recording.body_from_lidar_per_scan.is_none() {
        let t = Instant::now();
        refine_in_final_map(
            &mut trajectory,
            &scan_index,
            recording,
            &projector,
            &best.map,
            ro,
        )?;
        stats.timings.correlate_s += t.elapsed().as_secs_f64();
    }
    stats.timings.total_s = t_start.elapsed().as_secs_f64();
    stats.map_memory = Some(pf.map_memory());
    Ok(SlamResult {
        trajectory,
        dead_reckoning,
        map: best.map.clone(),
        stats,
    })
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
    scan_index: &[usize],
    recording: &Recording,
    projector: &ScanProjector,
    map: &OccupancyGrid,
    ro: &RbpfOptions,
) -> Result<(), MapError> {
    let res = map.limits().resolution_m();
    let model = ro.observation(res);
    let mut search = SearchParams::new(ro, res);
    search.yaw_offsets_rad = vec![0.0];
    search.xy_cells = 0;
    search.step_xy_m = 0.5 * ro.step_xy_m;
    search.step_yaw_rad = 0.5 * ro.step_yaw_deg.to_radians();
    search.prior = Some(MatchPrior {
        inv_var_xy: 1.0 / ro.refine_sigma_xy_m.powi(2),
        inv_var_yaw: 1.0 / ro.refine_sigma_yaw_deg.to_radians().powi(2),
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
