//! The SLAM filter's map insertion alone, on a car-layout dataset at its ground-truth poses:
//! the scans in flushes of `FLUSH` (as between two filter updates), inserted scan by scan
//! (`trace_updates_part` + `apply_updates`, the path before batches) and as batches
//! (`insert_planar_batch`); prints the process CPU per scan on one thread and the wall time
//! on the pool's threads, and a hash of the cells of each map (the two must be equal).
//! `cargo run --release -p pfslam --example filter_map -- DATASET [SCANS] [FLUSH] [ONLY]`
//! (`ONLY` = `batch`: the batch on one thread alone, to profile it).

mod common;

use pfslam::config::Config;
use pfslam::map::{
    BatchScratch, InsertScratch, OccupancyGrid, PlanarScan, ScanProjector, ScanUpdates, to_world,
};
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 2 {
        return Err("usage: filter_map DATASET [SCANS] [FLUSH]".into());
    }
    let scans: usize = args.get(2).map_or(Ok(20_000), |s| s.parse())?;
    let flush: usize = args.get(3).map_or(Ok(5), |s| s.parse())?;
    let only_batch = args.get(4).is_some_and(|s| s == "batch");
    let config = Config::default();
    let (rec, truth) = common::car_recording_at_truth(&PathBuf::from(&args[1]), &config)?;
    let mut opts = config.map.clone();
    opts.height.enabled = false;
    let proj = ScanProjector::new(
        &rec.lidar,
        &rec.body_from_lidar,
        &config.map.scan.for_filter(),
    )?;
    let mut worlds = Vec::new();
    let mut body = PlanarScan::default();
    for k in 0..rec.scans.len().min(scans) {
        let Some(pose) = truth.pose_at(rec.scans.stamps_ns[k]) else {
            continue;
        };
        proj.to_body(rec.scans.ranges(k), &mut body)?;
        let mut w = PlanarScan::default();
        to_world(&body, &pose, &mut w);
        worlds.push(w);
    }
    let n = worlds.len().max(1) as f64;
    let hash = |g: &OccupancyGrid| {
        let mut h = std::collections::hash_map::DefaultHasher::new();
        if let Some(r) = g.allocated_bounds() {
            let mut v = Vec::new();
            g.copy_rect_fixed(&r, &mut v);
            (r.min_i, r.min_j, r.max_i, r.max_j).hash(&mut h);
            v.hash(&mut h);
        }
        h.finish()
    };
    if only_batch {
        let (cpu, t) = (pfslam::pipeline::process_cpu_s(), Instant::now());
        let mut g = OccupancyGrid::new(&opts)?;
        let (mut batches, mut work) = (Vec::new(), Vec::new());
        for group in worlds.chunks(flush) {
            g.insert_planar_batch(group, 1, &mut batches, &mut work, None)?;
        }
        report("1 thread", "batch", cpu, t, n, hash(&g));
        return Ok(());
    }
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let all = rayon::ThreadPoolBuilder::new().build()?;
    for (name, threads) in [("1 thread", 1usize), ("pool", all.current_num_threads())] {
        let pool = if threads == 1 { &one } else { &all };
        // Scan by scan: each scan traced whole, applied per flush.
        let (cpu, t) = (pfslam::pipeline::process_cpu_s(), Instant::now());
        let mut g = OccupancyGrid::new(&opts)?;
        let mut ups: Vec<ScanUpdates> = (0..flush).map(|_| ScanUpdates::new()).collect();
        pool.install(|| -> Result<(), pfslam::map::MapError> {
            use rayon::prelude::*;
            for group in worlds.chunks(flush) {
                let grid = &g;
                ups[..group.len()]
                    .par_iter_mut()
                    .zip(group.par_iter())
                    .try_for_each_init(InsertScratch::new, |s, (u, w)| {
                        grid.trace_updates(w, s, u).map(|_| ())
                    })?;
                let refs: Vec<&ScanUpdates> = ups[..group.len()].iter().collect();
                g.apply_updates(&refs);
            }
            Ok(())
        })?;
        report(name, "scan by scan", cpu, t, n, hash(&g));
        let (cpu, t) = (pfslam::pipeline::process_cpu_s(), Instant::now());
        let mut g = OccupancyGrid::new(&opts)?;
        let mut batches: Vec<BatchScratch> = Vec::new();
        let mut work = Vec::new();
        pool.install(|| -> Result<(), pfslam::map::MapError> {
            for group in worlds.chunks(flush) {
                g.insert_planar_batch(group, threads, &mut batches, &mut work, None)?;
            }
            Ok(())
        })?;
        report(name, "batch", cpu, t, n, hash(&g));
    }
    Ok(())
}

fn report(name: &str, label: &str, cpu: Option<f64>, t: Instant, n: f64, hash: u64) {
    let cpu = pfslam::pipeline::process_cpu_s()
        .zip(cpu)
        .map_or(f64::NAN, |(b, a)| b - a);
    println!(
        "{name}, {label}: {:.1} us CPU, {:.1} us wall per scan; cells hash {hash:016x}",
        cpu * 1e6 / n,
        t.elapsed().as_secs_f64() * 1e6 / n
    );
}
