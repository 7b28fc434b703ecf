//! The parse kernel: throughput (MB/s) of the streaming `lidar.csv` reader on a generated file
//! shaped like the car's (286 ranges per row, millimetre decimals, some zeros), and of the
//! `fog.csv` reader (1 kHz rows of shortest-round-trip f64 increments).
//!
//! Each is measured twice: wall time (criterion's default) and the reading thread's CPU time
//! (`/proc/thread-self/schedstat`, Linux), which does not grow when other processes share
//! the cores; throughput is quoted per core, so the CPU figure is the one to quote on a
//! busy machine.

mod cpu_time;

use cpu_time::ThreadCpuTime;
use criterion::measurement::Measurement;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pfslam::sensors::{FogSample, ScanSet};
use pfslam_io::ucsd::{ReadOptions, read_fog_csv, read_lidar_csv, write_fog_csv, write_lidar_csv};

fn xorshift(state: &mut u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state
}

fn generate(dir: &std::path::Path, scans: usize) -> (std::path::PathBuf, u64) {
    let beams = 286;
    let mut set = ScanSet::new(beams);
    let mut row = vec![0.0f32; beams];
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for i in 0..scans {
        for r in row.iter_mut() {
            // deterministic pseudo-random ranges in [0, 80) m, 1 mm resolution
            let x = xorshift(&mut state);
            let mm = (x % 80_000) as f32;
            *r = if x.is_multiple_of(13) {
                0.0
            } else {
                mm / 1000.0
            };
        }
        set.push(1_544_582_648_735_140_000 + i as i64 * 10_000_000, &row);
    }
    let path = dir.join("lidar.csv");
    write_lidar_csv(&path, &set).unwrap();
    let bytes = std::fs::metadata(&path).unwrap().len();
    (path, bytes)
}

fn generate_fog(dir: &std::path::Path, rows: usize) -> (std::path::PathBuf, u64) {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut noise = || (xorshift(&mut state) as f64 / u64::MAX as f64 - 0.5) * 1e-5;
    let fog: Vec<FogSample> = (0..rows)
        .map(|i| FogSample {
            stamp_ns: 1_544_582_648_000_348_375 + i as i64 * 1_000_000,
            delta_roll_rad: noise(),
            delta_pitch_rad: noise(),
            delta_yaw_rad: noise(),
        })
        .collect();
    let path = dir.join("fog.csv");
    write_fog_csv(&path, &fog).unwrap();
    let bytes = std::fs::metadata(&path).unwrap().len();
    (path, bytes)
}

fn run<M: Measurement>(c: &mut Criterion<M>, suffix: &str) {
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = generate(dir.path(), 10_000);
    let (fog_path, fog_bytes) = generate_fog(dir.path(), 100_000);
    let opts = ReadOptions::default();
    let mut g = c.benchmark_group(format!("parse_{suffix}"));
    g.sample_size(10);
    g.throughput(Throughput::BytesDecimal(bytes));
    g.bench_function("read_lidar_csv_10k_scans", |b| {
        b.iter(|| {
            let s = read_lidar_csv(&path, 286, &opts).unwrap();
            assert_eq!(s.len(), 10_000);
            s
        })
    });
    g.throughput(Throughput::BytesDecimal(fog_bytes));
    g.bench_function("read_fog_csv_100k_rows", |b| {
        b.iter(|| read_fog_csv(&fog_path, &opts).unwrap())
    });
    g.finish();
}

fn wall(c: &mut Criterion) {
    run(c, "wall");
}

fn cpu(c: &mut Criterion<ThreadCpuTime>) {
    run(c, "thread_cpu");
}

criterion_group!(wall_benches, wall);
criterion_group! {
    name = cpu_benches;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = cpu
}
criterion_main!(wall_benches, cpu_benches);
