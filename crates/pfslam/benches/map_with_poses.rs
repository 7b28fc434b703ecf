//! Mapping with known poses (`pfslam::map::map_with_poses`, the `pfslam map` command and the
//! pipeline's map rebuild) on 1,000 scans of the simulated car (tilted LMS511, default
//! preprocessing: 2-75 m, densified returns), 0.1 m cells:
//! - `bins/sequential`: the scans inserted one after another (`ScanInserter::insert`, the
//!   sequential baseline) with the default `[map.height]` bins;
//! - `bins/threads_1`, `bins/threads_2`: `map_with_poses` in a rayon pool of 1 / 2 threads
//!   (the same grid bit for bit);
//! - `flat/...`: the same without height bins (one log-odds value per cell).
//!
//! Wall time: on a shared machine the 2-thread figure is only as good as the cores it gets.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pfslam::geometry::Trajectory;
use pfslam::map::{MapOptions, OccupancyGrid, ScanInserter, ScanProjector, map_with_poses};
use pfslam::sensors::Recording;

fn sequential(rec: &Recording, poses: &Trajectory, opts: &MapOptions) -> OccupancyGrid {
    let mut grid = OccupancyGrid::new(opts).unwrap();
    let projector = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &opts.scan).unwrap();
    let mut ins = ScanInserter::new(projector);
    for k in 0..rec.scans.len() {
        if let Some(pose) = poses.pose_at(rec.scans.stamps_ns[k]) {
            ins.insert(&mut grid, rec.scans.ranges(k), &pose).unwrap();
        }
    }
    grid
}

fn bench(c: &mut Criterion) {
    let sim = pfslam_sim::SimOptions {
        duration_s: 10.0,
        ..pfslam_sim::SimOptions::noise_free()
    };
    let world = pfslam_sim::World::builtin(sim.world_name()).unwrap();
    let out = pfslam_sim::simulate_car(&world, &sim).unwrap();
    let rec = out
        .recording(&pfslam::motion::MotionOptions::default())
        .unwrap();
    let poses = Trajectory::new(out.ground_truth.clone());
    let flat = MapOptions {
        height: pfslam::map::HeightOptions {
            enabled: false,
            ..Default::default()
        },
        ..MapOptions::default()
    };
    let pools: Vec<rayon::ThreadPool> = [1, 2]
        .iter()
        .map(|&n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        })
        .collect();
    for (name, opts) in [("bins", MapOptions::default()), ("flat", flat)] {
        let mut group = c.benchmark_group(format!("map_with_poses/{name}"));
        group.throughput(Throughput::Elements(rec.scans.len() as u64));
        group.bench_function("sequential", |b| b.iter(|| sequential(&rec, &poses, &opts)));
        for (pool, n) in pools.iter().zip([1, 2]) {
            group.bench_function(format!("threads_{n}"), |b| {
                b.iter(|| pool.install(|| map_with_poses(&rec, &poses, &opts).unwrap()))
            });
        }
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).measurement_time(std::time::Duration::from_secs(5)).warm_up_time(std::time::Duration::from_millis(500));
    targets = bench
}
criterion_main!(benches);
