//! The back end's loop-closure kernel on a car-like street submap: building a candidate's
//! [`PointField`] (41 keyframes x 200 points within 30 m, +-1.5 m window at 0.05 m, 3 pooled
//! levels, as `[graph]`'s defaults on the full-size car) and verifying a closure in it (the
//! branch and bound, its ambiguity test and the sub-cell refinement), and a per-scan
//! refinement field (11 keyframes, level 0 only) and the sub-cell refinement in it (the
//! pattern search of `refine.scans`). Run on a one-thread pool that includes the
//! calling thread, so the calling thread's CPU time is the kernel's whole CPU time.

mod cpu_time;

use cpu_time::ThreadCpuTime;
use criterion::{Criterion, criterion_group, criterion_main};
use pfslam::geometry::Pose2;
use pfslam::graph::{GraphOptions, verify_closure};
use pfslam::matching::point_field::{PointField, SearchWindow};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

/// Wall segments of a street grid: facades along two streets crossing at the origin (with
/// gaps), and parked cars as small boxes.
fn street_segments(rng: &mut Xoshiro256PlusPlus) -> Vec<([f64; 2], [f64; 2])> {
    let mut segs = Vec::new();
    for side in [-8.0, 8.0] {
        let mut x: f64 = -60.0;
        while x < 60.0 {
            let len = rng.random_range(4.0..15.0);
            if x.abs() > 10.0 || x + len < -10.0 {
                segs.push(([x, side], [x + len, side]));
                segs.push(([side, x], [side, x + len]));
            }
            x += len + rng.random_range(0.5..3.0);
        }
    }
    for _ in 0..40 {
        let (cx, cy) = (rng.random_range(-50.0..50.0), rng.random_range(-6.5..6.5));
        let (cx, cy) = if rng.random::<bool>() {
            (cx, cy)
        } else {
            (cy, cx)
        };
        let (hx, hy) = (2.2, 0.9);
        let c = [
            [cx - hx, cy - hy],
            [cx + hx, cy - hy],
            [cx + hx, cy + hy],
            [cx - hx, cy + hy],
        ];
        for k in 0..4 {
            segs.push((c[k], c[(k + 1) % 4]));
        }
    }
    segs
}

/// `n` points (body frame of `pose`) sampled on the segments within 30 m of `pose`.
fn scan(
    segs: &[([f64; 2], [f64; 2])],
    pose: &Pose2,
    n: usize,
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<[f64; 2]> {
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let (a, b) = segs[rng.random_range(0..segs.len())];
        let t = rng.random::<f64>();
        let p = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
        let q = pose.inverse().transform_point(p[0], p[1]);
        if q.0.hypot(q.1) < 30.0 {
            out.push([q.0, q.1]);
        }
    }
    out
}

/// World points of `keyframes` keyframes every 0.3 m along the x street around `x_m`.
fn submap(
    segs: &[([f64; 2], [f64; 2])],
    x_m: f64,
    keyframes: usize,
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<[f64; 2]> {
    let mut pts = Vec::new();
    for k in 0..keyframes {
        let pose = Pose2::new(x_m + (k as f64 - keyframes as f64 / 2.0) * 0.3, 0.5, 0.02);
        pts.extend(scan(segs, &pose, 200, rng).iter().map(|q| {
            let (x, y) = pose.transform_point(q[0], q[1]);
            [x, y]
        }));
    }
    pts
}

/// The field's window as the back end sizes it: the scan's box around `pose` grown by
/// `margin_m`, cut to the submap's box grown by 3 sigma.
fn bounds(
    scan: &[[f64; 2]],
    pose: &Pose2,
    margin_m: f64,
    submap: &[[f64; 2]],
    sigma_m: f64,
) -> ([f64; 2], [f64; 2]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in scan {
        let (x, y) = pose.transform_point(q[0], q[1]);
        lo = [lo[0].min(x - margin_m), lo[1].min(y - margin_m)];
        hi = [hi[0].max(x + margin_m), hi[1].max(y + margin_m)];
    }
    let (mut slo, mut shi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in submap {
        slo = [
            slo[0].min(p[0] - 3.0 * sigma_m),
            slo[1].min(p[1] - 3.0 * sigma_m),
        ];
        shi = [
            shi[0].max(p[0] + 3.0 * sigma_m),
            shi[1].max(p[1] + 3.0 * sigma_m),
        ];
    }
    (
        [lo[0].max(slo[0]), lo[1].max(slo[1])],
        [hi[0].min(shi[0]), hi[1].min(shi[1])],
    )
}

fn bench(c: &mut Criterion<ThreadCpuTime>) {
    // The calling thread is the pool's only worker: the kernels' parallel loops run on it.
    let _pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .use_current_thread()
        .build()
        .unwrap();
    let opts = GraphOptions::default();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let segs = street_segments(&mut rng);
    let loop_submap = submap(&segs, 0.0, 41, &mut rng);
    let refine_submap = submap(&segs, 0.0, 11, &mut rng);
    let truth = Pose2::new(0.35, 0.45, 0.03);
    let body = scan(&segs, &truth, 200, &mut rng);
    let centre = truth.compose(&Pose2::new(0.2, -0.15, 1f64.to_radians()));
    let win = SearchWindow {
        xy_m: opts.loops.window_m,
        yaw_rad: opts.loops.window_deg.to_radians(),
        yaw_step_rad: opts.yaw_step_deg.to_radians(),
    };
    let (res, sigma) = (opts.resolution_m, opts.field_sigma_m);
    let margin = opts.loops.window_m + 3.0 * sigma + res;
    let (lo, hi) = bounds(&body, &centre, margin, &loop_submap, sigma);
    let (rlo, rhi) = bounds(&body, &centre, 1.06, &refine_submap, sigma);
    let mut g = c.benchmark_group("loop_field");
    g.sample_size(20);
    {
        g.bench_function("build_loop_field", |b| {
            b.iter(|| {
                black_box(PointField::build(
                    black_box(&loop_submap),
                    lo,
                    hi,
                    res,
                    sigma,
                    3,
                ))
            })
        });
        let field = PointField::build(&loop_submap, lo, hi, res, sigma, 3);
        g.bench_function("verify_closure", |b| {
            b.iter(|| {
                black_box(verify_closure(
                    &field,
                    black_box(&body),
                    &centre,
                    &win,
                    &opts,
                ))
            })
        });
        g.bench_function("build_refine_field", |b| {
            b.iter(|| {
                black_box(PointField::build(
                    black_box(&refine_submap),
                    rlo,
                    rhi,
                    res,
                    sigma,
                    0,
                ))
            })
        });
        // From a cell-grid optimum's distance (as after `refine.scans`' exhaustive search).
        let refine_field = PointField::build(&refine_submap, rlo, rhi, res, sigma, 0);
        let start = truth.compose(&Pose2::new(0.03, -0.02, 0.2f64.to_radians()));
        g.bench_function("refine", |b| {
            b.iter(|| {
                black_box(refine_field.refine(black_box(&body), &start, win.yaw_step_rad, 4, None))
            })
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = bench
}
criterion_main!(benches);
