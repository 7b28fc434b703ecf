//! The correlation search (9x9 cells x 3 yaws) of one scan for one particle and for a set of
//! particles in parallel, against a grid built from simulated car scans (the `seed` mode);
//! and the default `scan_match` mode's kernels: the likelihood field's build, one particle's
//! match (7x7 cells x 7 yaws, then the sub-cell refinement), and the update of 40 / 100
//! particles in parallel; `scan_match_cpu`: 100 jittered particles matched serially, in the
//! calling thread's CPU time (whole match with the f64 and the f32 refinement kernel, and the
//! coarse search alone).

mod cpu_time;
mod mapped_drive;

use cpu_time::ThreadCpuTime;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use mapped_drive::mapped_drive;
use pfslam::config::Config;
use pfslam::filter::{ParticleFilter, SharedMap};
use pfslam::geometry::Pose2;
use pfslam::map::OccupancyGrid;
use pfslam::matching::correlation::{CorrelationScratch, best_match};
use pfslam::slam::BestParticleMap;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let mut config = Config::default();
    config.map.scan.z_min_m = Some(0.5);
    let (grid, body, pose) = mapped_drive(&config, 5);
    let mut hits = Vec::new();
    pfslam::matching::correlation::hit_points(&body, &mut hits);
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
    scan_match(c);
}

/// The scan_match benches' map (the bench drive), the last scan's matching points, its true
/// pose and the window the SLAM loop would use for particles within a few cells of it.
fn scan_match_setup(
    config: &Config,
) -> (OccupancyGrid, Vec<[f64; 2]>, Pose2, pfslam::map::CellRect) {
    use pfslam::matching::likelihood_field::match_points;
    let (grid, body, pose) = mapped_drive(config, 1);
    let sm = &config.filter.scan_match;
    let mut pts = Vec::new();
    match_points(&body, sm.match_range_max_m, sm.beam_decimation, &mut pts);
    let limits = *grid.limits();
    let mut rect = pfslam::map::CellRect::around(limits.cell_of(pose.x_m, pose.y_m));
    for p in &pts {
        let (x, y) = pose.transform_point(p[0], p[1]);
        rect = rect.union(&pfslam::map::CellRect::around(limits.cell_of(x, y)));
    }
    let rect = rect.expanded(sm.xy_search_radius_cells as i32 + 4);
    (grid, pts, pose, rect)
}

fn scan_match(c: &mut Criterion) {
    use pfslam::matching::likelihood_field::{LikelihoodField, MatchScratch, match_scan};
    let config = Config::default();
    let sm = &config.filter.scan_match;
    let (grid, pts, pose, rect) = scan_match_setup(&config);
    let params = sm.params(config.map.resolution_m);
    let mut field = LikelihoodField::new();
    let mut g = c.benchmark_group("scan_match");
    g.bench_function(
        format!("field_build_{}x{}", rect.width(), rect.height()),
        |b| b.iter(|| field.build(&grid, &rect, sm.field_sigma_m, sm.unknown_value)),
    );
    // Built here too: a filtered run skips the build bench above.
    field.build(&grid, &rect, sm.field_sigma_m, sm.unknown_value);
    let mut scratch = MatchScratch::default();
    // A prediction 12 cm and 0.3 deg off, as after an odometry step.
    let predicted =
        pfslam::geometry::Pose2::new(pose.x_m + 0.09, pose.y_m - 0.08, pose.yaw_rad + 0.005);
    g.bench_function(format!("one_particle_{}_points", pts.len()), |b| {
        b.iter(|| {
            black_box(match_scan(
                &field,
                black_box(&pts),
                &predicted,
                &params,
                &mut scratch,
            ))
        })
    });
    for particles in [40usize, 100] {
        let mut pf = ParticleFilter::new(particles, predicted, 1);
        g.bench_with_input(BenchmarkId::new("update", particles), &particles, |b, _| {
            b.iter(|| {
                pf.particles.poses.fill(predicted);
                black_box(pf.scan_match_update(&field, &pts, &params, sm.weight_temperature))
            })
        });
    }
    // A cloud as after resampling: jittered copies of one pose (`proposal_sigma_xy_m`).
    let mut pf = ParticleFilter::new(100, predicted, 1);
    g.bench_function("update_jittered_100", |b| {
        b.iter(|| {
            pf.particles.poses.fill(predicted);
            pf.jitter(
                sm.proposal_sigma_xy_m,
                sm.proposal_sigma_yaw_deg.to_radians(),
            );
            black_box(pf.scan_match_update(&field, &pts, &params, sm.weight_temperature))
        })
    });
    g.finish();
}

/// One update's matching of a cloud of 100 particles as after resampling (jittered copies of
/// one prediction), one particle after the other on the calling thread, in that thread's CPU
/// time (figures that hold on a loaded machine): the whole match, and the coarse search
/// alone (`refine_levels = 0`); their difference is the refinement.
fn scan_match_cpu(c: &mut Criterion<ThreadCpuTime>) {
    use pfslam::matching::likelihood_field::{LikelihoodField, MatchScratch, match_scan};
    let config = Config::default();
    let sm = &config.filter.scan_match;
    let (grid, pts, pose, rect) = scan_match_setup(&config);
    let mut field = LikelihoodField::new();
    field.build(&grid, &rect, sm.field_sigma_m, sm.unknown_value);
    let predicted = Pose2::new(pose.x_m + 0.09, pose.y_m - 0.08, pose.yaw_rad + 0.005);
    let mut pf = ParticleFilter::new(100, predicted, 1);
    pf.jitter(
        sm.proposal_sigma_xy_m,
        sm.proposal_sigma_yaw_deg.to_radians(),
    );
    let cloud = pf.particles.poses.clone();
    let mut g = c.benchmark_group("scan_match_cpu");
    g.sample_size(20);
    use pfslam::filter::scan_match::ScanMatchOptions;
    use pfslam::matching::likelihood_field::{KernelPrecision, MatchParams};
    for (name, levels, kernel_precision) in [
        ("match_100_jittered", sm.refine_levels, KernelPrecision::F64),
        (
            "match_100_jittered_f32",
            sm.refine_levels,
            KernelPrecision::F32,
        ),
        ("coarse_100_jittered", 0, KernelPrecision::F64),
    ] {
        let params = MatchParams {
            kernel_precision,
            ..ScanMatchOptions {
                refine_levels: levels,
                ..sm.clone()
            }
            .params(config.map.resolution_m)
        };
        let mut scratch = MatchScratch::default();
        g.bench_function(name, |b| {
            b.iter(|| {
                for p in &cloud {
                    black_box(match_scan(
                        &field,
                        black_box(&pts),
                        p,
                        &params,
                        &mut scratch,
                    ));
                }
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_group! {
    name = cpu;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = scan_match_cpu
}
criterion_main!(benches, cpu);
