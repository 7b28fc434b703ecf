//! Simulator speed: the car on the campus world, simulated, and simulated + written.
//!
//! `cargo bench -p pfslam-sim --bench simulate` runs a 60 s drive (6k scans, 60k FOG rows).
//! With `PFSLAM_BENCH_FULL=1` it also runs the full-size recording (1160.5 s: 116k LiDAR
//! scans, 1.16M FOG rows, 116k encoder rows), simulated and written (10 samples: minutes).

use criterion::{Criterion, criterion_group, criterion_main};
use pfslam_sim::dataset::write_car_sim;
use pfslam_sim::{SimOptions, World, simulate_car};
use std::hint::black_box;
use std::time::Duration;

fn bench_simulate(c: &mut Criterion) {
    let world = World::builtin("campus").expect("built-in world");
    let mut group = c.benchmark_group("simulate_car");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    let opts = SimOptions {
        duration_s: 60.0,
        ..SimOptions::default()
    };
    group.bench_function("simulate_60s", |b| {
        b.iter(|| black_box(simulate_car(&world, &opts).expect("simulate")))
    });
    let dir = tempfile::tempdir().expect("tempdir");
    group.bench_function("simulate_and_write_60s", |b| {
        b.iter(|| {
            let out = simulate_car(&world, &opts).expect("simulate");
            write_car_sim(dir.path(), &out).expect("write");
        })
    });
    if std::env::var_os("PFSLAM_BENCH_FULL").is_some() {
        let full = SimOptions {
            duration_s: 1160.5,
            ..SimOptions::default()
        };
        group.measurement_time(Duration::from_secs(120));
        group.bench_function("simulate_and_write_full_size", |b| {
            b.iter(|| {
                let out = simulate_car(&world, &full).expect("simulate");
                write_car_sim(dir.path(), &out).expect("write");
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_simulate);
criterion_main!(benches);
