//! The correlation search (9x9 cells x 3 yaws) of one scan for one particle and for a set of
//! particles in parallel, against a grid built from simulated car scans.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use pfslam::config::Config;
use pfslam::filter::correlate::{CorrelationScratch, best_match};
use pfslam::filter::slam::BestParticleMap;
use pfslam::filter::{ParticleFilter, SharedMap};
use pfslam::map::{InsertScratch, OccupancyGrid, PlanarScan, ScanProjector, to_world};
use pfslam::sim::{SimOptions, World, simulate_car};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let opts = SimOptions {
        duration_s: 8.0,
        ..SimOptions::default()
    };
    let world = World::builtin(opts.world_name()).expect("campus");
    let out = simulate_car(&world, &opts).expect("simulation");
    let mut config = Config::default();
    config.map.scan.z_min_m = Some(0.5);
    let rec = pfslam::motion::car_recording(&out.dataset, &config.motion, "bench").expect("rec");
    let proj = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &config.map.scan).expect("p");
    let mut grid = OccupancyGrid::new(&config.map).expect("grid");
    let (mut body, mut world_scan) = (PlanarScan::default(), PlanarScan::default());
    let mut ins = InsertScratch::new();
    let n = rec.scans.len();
    for k in (0..n - 1).step_by(5) {
        proj.to_body(rec.scans.ranges(k), &mut body).expect("scan");
        to_world(&body, &out.ground_truth[k].pose, &mut world_scan);
        grid.insert_scan(&world_scan, &mut ins).expect("insert");
    }
    proj.to_body(rec.scans.ranges(n - 1), &mut body)
        .expect("scan");
    let mut hits = Vec::new();
    pfslam::filter::correlate::hit_points(&body, &mut hits);
    let pose = out.ground_truth[n - 1].pose;
    let search = config.filter.search();
    let mut g = c.benchmark_group("correlate");
    let mut scratch = CorrelationScratch::default();
    g.bench_function(format!("one_particle_{}_points", hits.len()), |b| {
        b.iter(|| {
            black_box(best_match(
                &grid,
                black_box(&hits),
                &pose,
                &search,
                &mut scratch,
            ))
        })
    });
    let policy = BestParticleMap::new(grid.clone());
    for particles in [40usize, 100] {
        let mut pf = ParticleFilter::new(particles, pose, 1);
        g.bench_with_input(
            BenchmarkId::new("reweight", particles),
            &particles,
            |b, _| {
                b.iter(|| {
                    pf.particles.poses.fill(pose);
                    black_box(pf.reweight(&SharedMap(&policy.grid), &hits, &search, 10.0, true))
                })
            },
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
