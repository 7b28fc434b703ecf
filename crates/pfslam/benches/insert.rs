//! Scan insertion throughput (rays/s) at 0.1 m on realistic car scans:
//! - `street_scan`: a level 286-beam LMS511 fan (-5..185 deg) in a street canyon (facades at
//!   +-9 m, a cross street, the far end at 75 m): every beam returns, ranges 2-75 m;
//! - `campus_scan`: a scan of the simulated car (tilted mount, real calibration) on the
//!   campus world, preprocessed as `pfslam map` does (2-75 m, no z window);
//! - `campus_scan_heights`: the same scan into the default `[map.height]` bins;
//! - `full_pipeline`: ranges -> body -> world -> insert for the street scan;
//! - `clone_mapped_grid`: cloning a grid after 2,000 scans (what a particle's map copy costs).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::map::{
    InsertScratch, LogOddsParams, MapLimits, OccupancyGrid, PlanarScan, ScanOptions, ScanProjector,
    to_world,
};
use pfslam::sensors::LidarGeometry;

/// Ranges of a level LMS511 in a street: facades at +-9 m, a 14 m wide cross street 20-34 m
/// ahead with buildings behind it at 60 m, the street's far end at 75 m.
fn street_ranges(g: &LidarGeometry) -> Vec<f32> {
    (0..g.beam_count)
        .map(|k| {
            // The fan's 90 deg beam looks ahead (+x of the body).
            let a = g.beam_angle_rad(k) - std::f64::consts::FRAC_PI_2;
            let (s, c) = a.sin_cos();
            let mut r = 75.0f64;
            if s.abs() > 1e-9 {
                let to_facade = 9.0 / s.abs();
                let x = to_facade * c;
                let facade_here = !(20.0..34.0).contains(&x);
                if facade_here {
                    r = r.min(to_facade);
                } else if c > 0.0 {
                    // through the cross street: buildings at 60 m ahead
                    r = r.min(60.0 / c);
                }
            }
            if c > 1e-9 {
                r = r.min(75.0 / c);
            }
            r.clamp(2.0, 75.0) as f32
        })
        .collect()
}

fn grid() -> OccupancyGrid {
    OccupancyGrid::with_params(MapLimits::new(0.1, 0.0, 0.0), LogOddsParams::ucsd())
}

fn bench(c: &mut Criterion) {
    let g = LidarGeometry::ucsd_lms511();
    let level = Rigid3::from_rpy(0.0, 0.0, std::f64::consts::FRAC_PI_2, [0.83, 0.0, 1.76]);
    // The beams as measured: no densification (the default joins close returns with extra
    // rays; `campus_scan` below keeps the defaults).
    let opts = ScanOptions {
        densify_max_gap_m: None,
        ..ScanOptions::default()
    };
    let proj = ScanProjector::new(&g, &level, &opts).unwrap();
    let ranges = street_ranges(&g);
    let pose = Pose2::new(100.0, 50.0, 0.3);
    let (mut body, mut world) = (PlanarScan::default(), PlanarScan::default());
    proj.to_body(&ranges, &mut body).unwrap();
    to_world(&body, &pose, &mut world);
    assert_eq!(world.points.len(), 286);
    let st = grid()
        .insert_scan(&world, &mut InsertScratch::new())
        .unwrap();
    eprintln!(
        "street scan: {} rays, {} cells updated ({} occupied)",
        st.rays,
        st.occupied_cells + st.free_cells,
        st.occupied_cells
    );

    let mut group = c.benchmark_group("insert");
    group.throughput(Throughput::Elements(world.points.len() as u64));
    let mut gr = grid();
    let mut scratch = InsertScratch::new();
    group.bench_function("street_scan", |b| {
        b.iter(|| gr.insert_scan(&world, &mut scratch).unwrap())
    });
    let mut gr = grid();
    group.bench_function("full_pipeline", |b| {
        b.iter(|| {
            proj.to_body(&ranges, &mut body).unwrap();
            to_world(&body, &pose, &mut world);
            gr.insert_scan(&world, &mut scratch).unwrap()
        })
    });

    // A simulated campus scan with the real (tilted) mount.
    let sim = pfslam_sim::SimOptions {
        duration_s: 12.0,
        ..pfslam_sim::SimOptions::noise_free()
    };
    let w = pfslam_sim::World::builtin(sim.world_name()).unwrap();
    let out = pfslam_sim::simulate_car(&w, &sim).unwrap();
    let cal = &out.dataset.calibration;
    let proj_real =
        ScanProjector::new(&cal.lidar, &cal.body_from_lidar, &ScanOptions::default()).unwrap();
    let k = out.dataset.lidar.len() * 3 / 4;
    proj_real
        .to_body(out.dataset.lidar.ranges(k), &mut body)
        .unwrap();
    to_world(&body, &out.ground_truth[k].pose, &mut world);
    group.throughput(Throughput::Elements(world.points.len() as u64));
    eprintln!("campus scan: {} rays of 286 beams", world.points.len());
    let mut gr = grid();
    group.bench_function("campus_scan", |b| {
        b.iter(|| gr.insert_scan(&world, &mut scratch).unwrap())
    });
    // The same scan into the default `[map.height]` bins (what `pfslam map` does for the car).
    let mut gr = OccupancyGrid::new(&pfslam::map::MapOptions::default()).unwrap();
    group.bench_function("campus_scan_heights", |b| {
        b.iter(|| gr.insert_scan(&world, &mut scratch).unwrap())
    });
    group.finish();

    // Clone cost of a mapped grid (2,000 street scans along a 200 m drive).
    let mut gr = grid();
    proj.to_body(&ranges, &mut body).unwrap();
    for i in 0..2000 {
        to_world(&body, &Pose2::new(i as f64 * 0.1, 0.0, 0.0), &mut world);
        gr.insert_scan(&world, &mut scratch).unwrap();
    }
    eprintln!(
        "mapped grid: {} tiles, {:.1} MB",
        gr.tile_count(),
        gr.memory_bytes() as f64 / 1e6
    );
    c.bench_function("clone_mapped_grid", |b| b.iter(|| gr.clone()));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(2)).warm_up_time(std::time::Duration::from_millis(500));
    targets = bench
}
criterion_main!(benches);
