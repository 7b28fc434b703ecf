//! The map rebuild's two phases timed apart, on one thread, to profile them:
//! `cargo run --release -p pfslam --example rebuild_phases -- DATASET POSES.tum [SCANS] [ROUNDS]`
//! maps the first `SCANS` scans (default all) of a car-layout dataset along `POSES` as
//! [`pfslam::map::map_with_poses`] does (batches of [`pfslam::map::MAP_BATCH_SCANS`]: trace
//! every scan of a batch, then apply the batch), `ROUNDS` times (default 3), and prints each
//! round's thread CPU seconds of tracing (`ScanInserter::trace`) and of applying
//! (`OccupancyGrid::apply_updates`), and a hash of the grid's cells and bins.

use pfslam::config::Config;
use pfslam::map::{Cell, MAP_BATCH_SCANS, OccupancyGrid, ScanInserter, ScanProjector, ScanUpdates};
use pfslam_io::tum::read_tum;
use pfslam_io::ucsd::{ReadOptions, read_car_dataset};
use std::hash::{Hash, Hasher};
use std::path::PathBuf;

/// CPU time of the calling thread (ns), from `/proc/thread-self/schedstat`.
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse().ok()))
        .unwrap_or(0)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: rebuild_phases DATASET POSES.tum [SCANS] [ROUNDS]".into());
    }
    let config = Config::default();
    let mut ds = read_car_dataset(&PathBuf::from(&args[1]), &ReadOptions::default())?;
    let recording = pfslam::motion::car_recording_taking_scans(&mut ds, &config.motion, "d")?;
    drop(ds);
    let poses = pfslam::geometry::Trajectory::new(read_tum(&PathBuf::from(&args[2]))?.poses);
    let n = args
        .get(3)
        .map_or(Ok(recording.scans.len()), |s| s.parse::<usize>())?
        .min(recording.scans.len());
    let rounds = args.get(4).map_or(Ok(3), |s| s.parse::<usize>())?;
    let opts = &config.map;
    let projector = ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &opts.scan)?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    for round in 0..rounds {
        let mut grid = OccupancyGrid::new(opts)?;
        let mut ins = ScanInserter::new(projector.clone());
        let mut slots: Vec<ScanUpdates> = Vec::new();
        let (mut trace_ns, mut apply_ns, mut updates) = (0u64, 0u64, 0usize);
        let scans: Vec<usize> = (0..n).step_by(opts.scan_step).collect();
        for batch in scans.chunks(MAP_BATCH_SCANS) {
            slots.resize_with(batch.len(), ScanUpdates::new);
            let t = thread_cpu_ns();
            let mut done = 0;
            for &k in batch {
                if let Some(pose) = poses.pose_at(recording.scans.stamps_ns[k]) {
                    ins.trace(&grid, recording.scans.ranges(k), &pose, &mut slots[done])?;
                    updates += slots[done].len();
                    done += 1;
                }
            }
            trace_ns += thread_cpu_ns() - t;
            let refs: Vec<&ScanUpdates> = slots[..done].iter().collect();
            apply_ns += pool.install(|| {
                let t = thread_cpu_ns();
                grid.apply_updates(&refs);
                thread_cpu_ns() - t
            });
        }
        let mut h = std::collections::hash_map::DefaultHasher::new();
        if let Some(r) = grid.allocated_bounds() {
            let mut v = Vec::new();
            grid.copy_rect_fixed(&r, &mut v);
            v.hash(&mut h);
            for j in r.min_j..=r.max_j {
                for i in r.min_i..=r.max_i {
                    grid.height_bins(Cell::new(i, j)).hash(&mut h);
                }
            }
        }
        println!(
            "round {round}: {} scans, {updates} cell updates, trace {:.3} s, apply {:.3} s CPU, bits {:016x}",
            scans.len(),
            trace_ns as f64 * 1e-9,
            apply_ns as f64 * 1e-9,
            h.finish()
        );
    }
    Ok(())
}
