//! Monte Carlo localisation's hot step: weighing a particle set against the likelihood field
//! (60 returns per particle, as the defaults use), for the particle counts of tracking and of
//! a global search. `pfslam localize` prints the whole run's real-time factor.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use pfslam::geometry::Pose2;
use pfslam::localize::mcl::{FreeSpace, ParticleSet};
use pfslam::map::{BinaryMap, CellState, MapLimits};
use pfslam::matching::map_field::{FieldModel, LikelihoodField, Sharpness};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

/// A 40 x 30 m floor at 5 cm with walls every 4 m (a dense office).
fn floor() -> BinaryMap {
    let (w, h) = (800usize, 600usize);
    let mut m = BinaryMap::filled(MapLimits::new(0.05, 0.0, 0.0), w, h, CellState::Free);
    for j in 0..h {
        for i in 0..w {
            if i % 80 == 0 || j % 80 == 0 {
                m.set(i as i64, j as i64, CellState::Occupied);
            }
        }
    }
    m
}

fn bench(c: &mut Criterion) {
    let map = floor();
    let field = LikelihoodField::new(
        &map,
        &FieldModel {
            sigma_hit_m: [0.1, 0.3],
            z_hit: 0.9,
            max_distance_m: 2.0,
            range_max_m: 30.0,
        },
    );
    let points: Vec<[f64; 2]> = (0..60)
        .map(|k| {
            let a = -1.5 + 3.0 * k as f64 / 59.0;
            let r = 2.0 + (k % 7) as f64;
            [r * a.cos(), r * a.sin()]
        })
        .collect();
    let Some(free) = FreeSpace::new(&map) else {
        return;
    };
    let mut g = c.benchmark_group("localize_weigh");
    for n in [600usize, 20_000] {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let set = if n <= 600 {
            ParticleSet::around(&Pose2::new(20.0, 15.0, 0.3), (0.1, 0.05), n, &mut rng)
        } else {
            ParticleSet::over(&free, n, &mut rng)
        };
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                let mut s = set.clone();
                black_box(s.weigh(&field, Sharpness::Tracking, black_box(&points), None));
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
