//! The back end's Levenberg-Marquardt optimiser on an Intel-like pose graph: a long chain
//! of keyframes driving laps around a closed corridor, with loop closures between laps
//! (about as many nodes as Intel's 2,557 keyframes), started from drifted odometry; a small
//! one, and a car-sized one with few closures. Measured in the calling thread's CPU time
//! (the optimiser is serial), so the figures hold on a loaded machine.

mod cpu_time;

use cpu_time::ThreadCpuTime;
use criterion::{Criterion, criterion_group, criterion_main};
use pfslam::geometry::Pose2;
use pfslam::graph::optimize::{Edge, OptimizeOptions, PoseGraph};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

/// `laps` laps of `per_lap` nodes around a 30 m x 20 m rounded loop (each lap shifted a
/// little sideways), odometry edges with noise, closures to the two previous laps.
fn corridor_graph(per_lap: usize, laps: usize, seed: u64) -> PoseGraph {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let n = per_lap * laps;
    let truth: Vec<Pose2> = (0..n)
        .map(|k| {
            let t = (k % per_lap) as f64 / per_lap as f64 * std::f64::consts::TAU;
            let lap = (k / per_lap) as f64;
            let (s, c) = t.sin_cos();
            let r = 1.0 + 0.02 * lap;
            Pose2::new(15.0 * r * c, 10.0 * r * s, t + std::f64::consts::FRAC_PI_2)
        })
        .collect();
    let noisy = |z: Pose2, sxy: f64, syaw: f64, rng: &mut Xoshiro256PlusPlus| {
        Pose2::new(
            z.x_m + sxy * (rng.random::<f64>() - 0.5),
            z.y_m + sxy * (rng.random::<f64>() - 0.5),
            z.yaw_rad + syaw * (rng.random::<f64>() - 0.5),
        )
    };
    let mut graph = PoseGraph::default();
    let mut odo = truth[0];
    graph.poses.push(odo);
    for k in 1..n {
        let z = noisy(truth[k - 1].between(&truth[k]), 0.02, 0.01, &mut rng);
        graph
            .edges
            .push(Edge::with_sigmas(k - 1, k, z, 0.05, 0.02, None));
        odo = odo.compose(&z);
        graph.poses.push(odo);
    }
    for k in per_lap..n {
        if k % 3 != 0 {
            continue;
        }
        for back in [1, 2] {
            let Some(j) = (k + rng.random_range(0..5)).checked_sub(back * per_lap + 2) else {
                continue;
            };
            let z = noisy(truth[j].between(&truth[k]), 0.01, 0.005, &mut rng);
            graph
                .edges
                .push(Edge::with_sigmas(j, k, z, 0.1, 0.03, Some(3.0)));
        }
    }
    graph
}

fn bench(c: &mut Criterion<ThreadCpuTime>) {
    let mut g = c.benchmark_group("optimize");
    g.sample_size(10);
    let opts = OptimizeOptions::default();
    // Intel-sized; a small graph (the size rule: no cheaper solver below some size); a
    // car-sized one (the full-size drive's last graphs: 25,000 nodes, few closures).
    for (name, graph) in [
        ("corridor_2560_nodes", corridor_graph(320, 8, 1)),
        ("corridor_120_nodes", corridor_graph(40, 3, 2)),
        (
            "drive_25000_nodes",
            sparse_closures(corridor_graph(5000, 5, 3), 20),
        ),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut work = graph.clone();
                black_box(work.optimize(black_box(&opts)))
            })
        });
    }
    g.finish();
}

/// Keeps every `keep`-th loop closure (a drive revisits less than Intel's robot).
fn sparse_closures(mut graph: PoseGraph, keep: usize) -> PoseGraph {
    let mut closure = 0;
    graph.edges.retain(|e| {
        if e.to == e.from + 1 {
            return true;
        }
        closure += 1;
        closure % keep == 0
    });
    graph
}

criterion_group! {
    name = benches;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = bench
}
criterion_main!(benches);
