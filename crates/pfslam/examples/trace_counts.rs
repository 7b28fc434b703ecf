//! Counts what map insertion traces on a car-layout dataset, per scan, for each way of
//! inserting the joining returns (`ScanOptions::densify_rays`: whole rays or end cells):
//! returns, joining points of the densification, rays cleared only part of the way, cells walked (every ray's free cells plus its end cell) and
//! cells touched (unique per scan), on the filter's planar grid and on the rebuild's grid
//! with height bins, plus the single-thread tracing time of each.
//! `cargo run --release -p pfslam --example trace_counts -- DATASET [EVERY_NTH_SCAN]`
//! (scans at the poses of `DATASET/ground_truth.tum`).

mod common;

use pfslam::config::Config;
use pfslam::map::InsertScratch;
use pfslam::map::{DensifyRays, OccupancyGrid, PlanarScan, ScanProjector, ScanUpdates, to_world};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Default)]
struct Sums {
    scans: usize,
    points: usize,
    returns: usize,
    joining: usize,
    partial_returns: usize,
    partial_joining: usize,
    walk: u64,
    walk_joining: u64,
    dup_rays: usize,
    walk_dup: u64,
    dup_any_rays: usize,
    walk_dup_any: u64,
    touched_planar: u64,
    touched_heights: u64,
    planar_s: f64,
    heights_s: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 2 {
        return Err("usage: trace_counts DATASET [EVERY_NTH_SCAN]".into());
    }
    let every: usize = args.get(2).map_or(Ok(10), |s| s.parse())?;
    let config = Config::default();
    let (rec, truth) = common::car_recording_at_truth(&PathBuf::from(&args[1]), &config)?;
    let mut planar_opts = config.map.clone();
    planar_opts.height.enabled = false;
    let margin = (config.map.free_margin_m / config.map.resolution_m).round() as i32;
    let mut kept: Vec<(DensifyRays, Vec<PlanarScan>)> = Vec::new();
    for mode in [DensifyRays::Full, DensifyRays::HitOnly] {
        let mut worlds = Vec::new();
        let mut scan_opts = config.map.scan;
        scan_opts.densify_rays = mode;
        let proj = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &scan_opts)?;
        let mut plain_opts = scan_opts;
        plain_opts.densify_max_gap_m = None;
        let plain = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &plain_opts)?;
        let planar = OccupancyGrid::new(&planar_opts)?;
        let heights = OccupancyGrid::new(&config.map)?;
        let (mut body, mut body0, mut world) = (
            PlanarScan::default(),
            PlanarScan::default(),
            PlanarScan::default(),
        );
        let (mut scratch, mut scratch_h) = (InsertScratch::new(), InsertScratch::new());
        let mut up = ScanUpdates::new();
        let mut s = Sums::default();
        for k in (0..rec.scans.len()).step_by(every) {
            let Some(pose) = truth.pose_at(rec.scans.stamps_ns[k]) else {
                continue;
            };
            proj.to_body(rec.scans.ranges(k), &mut body)?;
            plain.to_body(rec.scans.ranges(k), &mut body0)?;
            to_world(&body, &pose, &mut world);
            s.scans += 1;
            s.points += world.points.len();
            s.returns += body0.points.iter().filter(|p| p.hit).count();
            let lim = planar.limits();
            let o = lim.cell_of(world.sensor_x_m, world.sensor_y_m);
            let cheb = |c: pfslam::map::Cell| (c.i - o.i).abs().max((c.j - o.j).abs());
            // Joining points: those of `body` not in `body0` (same order, returns equal).
            let mut r = 0;
            let mut last: Option<(pfslam::map::Cell, pfslam::map::Cell, bool)> = None;
            let mut seen = std::collections::HashSet::new();
            for (p, pb) in world.points.iter().zip(&body.points) {
                let is_return = r < body0.points.len()
                    && body0.points[r].x_m == pb.x_m
                    && body0.points[r].y_m == pb.y_m;
                r += usize::from(is_return);
                let end = lim.cell_of(p.x_m, p.y_m);
                let steps = if p.free_to < 1.0 {
                    let t = f64::from(p.free_to.max(0.0));
                    let ce = lim.cell_of(
                        world.sensor_x_m + t * (p.x_m - world.sensor_x_m),
                        world.sensor_y_m + t * (p.y_m - world.sensor_y_m),
                    );
                    cheb(ce) as u64 + 1
                } else {
                    (cheb(end) - if p.hit { margin } else { 0 }).max(0) as u64 + 1
                };
                s.walk += steps;
                let t = f64::from(p.free_to.clamp(0.0, 1.0));
                let key = (
                    end,
                    lim.cell_of(
                        world.sensor_x_m + t * (p.x_m - world.sensor_x_m),
                        world.sensor_y_m + t * (p.y_m - world.sensor_y_m),
                    ),
                    p.hit,
                );
                if last == Some(key) {
                    s.dup_rays += 1;
                    s.walk_dup += steps;
                }
                last = Some(key);
                if !seen.insert(key) {
                    s.dup_any_rays += 1;
                    s.walk_dup_any += steps;
                }
                if is_return {
                    s.partial_returns += usize::from(p.free_to < 1.0);
                } else {
                    s.joining += 1;
                    s.walk_joining += steps;
                    s.partial_joining += usize::from(p.free_to < 1.0);
                }
            }
            worlds.push(world.clone());
            let t = Instant::now();
            planar.trace_updates(&world, &mut scratch, &mut up)?;
            s.planar_s += t.elapsed().as_secs_f64();
            s.touched_planar += up.len() as u64;
            let t = Instant::now();
            heights.trace_updates(&world, &mut scratch_h, &mut up)?;
            s.heights_s += t.elapsed().as_secs_f64();
            s.touched_heights += up.len() as u64;
        }
        let n = s.scans.max(1) as f64;
        println!(
            "{mode:?}: {} scans (every {every}th); per scan: points {:.1}, returns {:.1}, \
             joining {:.1}, partial returns {:.1}, partial joining {:.1}, walk steps {:.0} \
             (joining {:.0}), same cells as the ray before {:.1} rays / {:.0} steps (as any ray before {:.1} / {:.0}), touched planar {:.0}, touched heights {:.0}; trace 1 thread: \
             planar {:.1} us, heights {:.1} us per scan",
            s.scans,
            s.points as f64 / n,
            s.returns as f64 / n,
            s.joining as f64 / n,
            s.partial_returns as f64 / n,
            s.partial_joining as f64 / n,
            s.walk as f64 / n,
            s.walk_joining as f64 / n,
            s.dup_rays as f64 / n,
            s.walk_dup as f64 / n,
            s.dup_any_rays as f64 / n,
            s.walk_dup_any as f64 / n,
            s.touched_planar as f64 / n,
            s.touched_heights as f64 / n,
            s.planar_s * 1e6 / n,
            s.heights_s * 1e6 / n,
        );
        kept.push((mode, worlds));
    }
    // Process CPU of the planar tracing alone (one thread, 3 passes over the kept scans).
    let planar = OccupancyGrid::new(&planar_opts)?;
    let mut scratch = InsertScratch::new();
    let mut up = ScanUpdates::new();
    for (mode, worlds) in &kept {
        let cpu = pfslam::pipeline::process_cpu_s();
        for _ in 0..3 {
            for w in worlds {
                planar.trace_updates(w, &mut scratch, &mut up)?;
            }
        }
        let cpu = pfslam::pipeline::process_cpu_s()
            .zip(cpu)
            .map(|(b, a)| b - a);
        println!(
            "{mode:?}: planar tracing {:.1} us CPU per scan (3 passes over {} scans)",
            cpu.unwrap_or(f64::NAN) * 1e6 / (3 * worlds.len()).max(1) as f64,
            worlds.len()
        );
    }
    Ok(())
}
