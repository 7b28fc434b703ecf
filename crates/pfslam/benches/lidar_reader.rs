//! Throughput (MB/s) of the streaming `lidar.csv` reader on a generated file shaped like the
//! car's (286 ranges per row, millimetre decimals, some zeros).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pfslam::io::ucsd::{ReadOptions, read_lidar_csv, write_lidar_csv};
use pfslam::sensors::ScanSet;

fn generate(dir: &std::path::Path, scans: usize) -> (std::path::PathBuf, u64) {
    let beams = 286;
    let mut set = ScanSet::new(beams);
    let mut row = vec![0.0f32; beams];
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for i in 0..scans {
        for r in row.iter_mut() {
            // xorshift: deterministic pseudo-random ranges in [0, 80) m, 1 mm resolution
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let mm = (state % 80_000) as f32;
            *r = if state.is_multiple_of(13) {
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

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = generate(dir.path(), 10_000);
    let opts = ReadOptions::default();
    let mut g = c.benchmark_group("lidar_reader");
    g.throughput(Throughput::Bytes(bytes));
    g.sample_size(10);
    g.bench_function("read_lidar_csv_10k_scans", |b| {
        b.iter(|| {
            let s = read_lidar_csv(&path, 286, &opts).unwrap();
            assert_eq!(s.len(), 10_000);
            s
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
