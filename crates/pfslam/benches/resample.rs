//! Resampling and the log-space weight update for typical particle counts.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use pfslam::filter::resample::{ResampleMethod, resample};
use pfslam::filter::weights::update_log_space;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("resample");
    for n in [40usize, 100, 1000] {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let w: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
        let scores: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..300.0)).collect();
        for m in ResampleMethod::ALL {
            let mut out = Vec::with_capacity(n);
            g.bench_with_input(BenchmarkId::new(format!("{m:?}"), n), &n, |b, _| {
                b.iter(|| {
                    resample(black_box(&w), m, &mut rng, &mut out);
                    black_box(&out);
                })
            });
        }
        let mut ww = vec![1.0 / n as f64; n];
        g.bench_with_input(BenchmarkId::new("softmax", n), &n, |b, _| {
            b.iter(|| {
                ww.fill(1.0 / n as f64);
                update_log_space(black_box(&mut ww), black_box(&scores), 10.0);
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
