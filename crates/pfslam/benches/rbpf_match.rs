//! The `rbpf` matcher's kernels (Intel's default filter): the observation model's
//! log-likelihood of one scan at one pose, and one particle's whole match (coarse yaw search,
//! then the hill climb with a prior), against a 0.05 m grid built from simulated car scans at
//! their true poses. One thread, the default `[filter.rbpf]` options; the points are the
//! scan's returns within `range_max_m`, every `beam_decimation`-th, as the filter takes them.

mod mapped_drive;

use criterion::{Criterion, criterion_group, criterion_main};
use mapped_drive::mapped_drive;
use pfslam::config::Config;
use pfslam::filter::rbpf::RbpfOptions;
use pfslam::geometry::Pose2;
use pfslam::matching::likelihood_field::match_points;
use pfslam::matching::nearest_occupied::{MatchPrior, match_in_own_map, scan_log_likelihood};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let o = RbpfOptions::default();
    let mut config = Config::default();
    config.map.resolution_m = 0.05;
    config.map.scan.z_min_m = Some(0.5);
    let (grid, body, truth) = mapped_drive(&config, 5);
    let mut points = Vec::new();
    match_points(&body, o.range_max_m, o.beam_decimation, &mut points);
    let model = o.observation(0.05);
    let mut search = o.search_params(0.05);
    // The prior's smallest sigmas (as after a short step).
    search.prior = Some(MatchPrior {
        inv_var_xy: 1.0 / (o.search.prior_min_xy_m * o.search.prior_min_xy_m),
        inv_var_yaw: 1.0 / o.search.prior_min_yaw_deg.to_radians().powi(2),
    });
    let start = Pose2::new(truth.x_m + 0.04, truth.y_m - 0.03, truth.yaw_rad + 0.01);
    let mut g = c.benchmark_group("rbpf");
    g.bench_function(format!("likelihood_{}_points", points.len()), |b| {
        b.iter(|| {
            black_box(scan_log_likelihood(
                &grid,
                &model,
                black_box(&points),
                &start,
            ))
        })
    });
    g.bench_function(format!("match_{}_points", points.len()), |b| {
        b.iter(|| {
            black_box(match_in_own_map(
                &grid,
                &model,
                black_box(&points),
                &start,
                &search,
            ))
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
