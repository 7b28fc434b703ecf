//! The full SLAM step: `run_slam` (default `scan_match` mode) over a 10 s simulated car drive
//! (1,000 scans, an update every 5th), reported per scan; 40 and 100 particles.
//! The end-to-end figure (read CSVs -> SLAM -> write maps on the full-size recording) is
//! `pfslam bench-e2e`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use pfslam::config::Config;
use pfslam::slam::run_slam;
use pfslam_sim::{SimOptions, World, simulate_car};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let opts = SimOptions {
        duration_s: 10.0,
        ..SimOptions::default()
    };
    let world = World::builtin(opts.world_name()).expect("campus");
    let out = simulate_car(&world, &opts).expect("simulation");
    let mut config = Config::default();
    config.filter.snapshot_every_scans = 0;
    let rec = pfslam::motion::car_recording(&out.dataset, &config.motion, "bench").expect("rec");
    let mut g = c.benchmark_group("slam_step");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(8));
    g.throughput(Throughput::Elements(rec.scans.len() as u64));
    for particles in [40usize, 100] {
        config.filter.particles = particles;
        g.bench_with_input(
            BenchmarkId::new("run_slam_1000_scans", particles),
            &particles,
            |b, _| b.iter(|| black_box(run_slam(&rec, &config, 1, &mut |_| {}).expect("slam"))),
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
