use super::*;

#[test]
fn jacobians_match_finite_differences() {
    let xi = Pose2::new(1.0, -2.0, 0.7);
    let xj = Pose2::new(2.5, 0.3, -2.9);
    let z = Pose2::new(0.4, 1.1, 0.2);
    let (e0, a, b) = linearise(&xi, &xj, &z, &rot(z.yaw_rad));
    // The cost's error is the linearisation's, bit for bit.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let mut pose = || {
        Pose2::new(
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(-4.0..4.0),
        )
    };
    for _ in 0..2000 {
        let (p, q, r) = (pose(), pose(), pose());
        let rr = rot(r.yaw_rad);
        let (fast, slow) = (edge_error(&p, &q, &r, &rr), linearise(&p, &q, &r, &rr).0);
        for k in 0..3 {
            assert_eq!(fast[k].to_bits(), slow[k].to_bits());
        }
    }
    let h = 1e-6;
    for k in 0..3 {
        let bump = |p: &Pose2| {
            let mut v = [p.x_m, p.y_m, p.yaw_rad];
            v[k] += h;
            Pose2::new(v[0], v[1], v[2])
        };
        let (ei, _, _) = linearise(&bump(&xi), &xj, &z, &rot(z.yaw_rad));
        let (ej, _, _) = linearise(&xi, &bump(&xj), &z, &rot(z.yaw_rad));
        for r in 0..3 {
            assert!(((ei[r] - e0[r]) / h - a[(r, k)]).abs() < 1e-4, "A {r} {k}");
            assert!(((ej[r] - e0[r]) / h - b[(r, k)]).abs() < 1e-4, "B {r} {k}");
        }
    }
}

use nalgebra::DMatrix;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// A chain of `n` nodes with loop closures between far-apart nodes (bunched, as
/// revisits are) and a prior on every node (an edge from the fixed node 0).
fn loopy_structure(n: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<(usize, usize)> {
    let mut pairs: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
    pairs.extend((2..n).map(|k| (0, k)));
    for k in 10..n {
        if rng.random::<f64>() < 0.3 {
            let j = rng.random_range(0..k - 5);
            for d in 0..3.min(n - k) {
                pairs.push((j + d, k + d));
            }
        }
    }
    pairs
}

fn random_block(rng: &mut Xoshiro256PlusPlus) -> Matrix3<f64> {
    Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0))
}

/// Random normal equations `sum J^T W J`, `-J^T W e` on `pairs`, in the sparse solver
/// and densely (free nodes 1.., `3 * (node - 1) + axis`).
fn random_system(
    n: usize,
    pairs: &[(usize, usize)],
    rng: &mut Xoshiro256PlusPlus,
) -> (BlockCholesky, DMatrix<f64>, Vec<f64>) {
    let edges: Vec<Edge> = pairs
        .iter()
        .map(|&(a, b)| Edge::with_sigmas(a, b, Pose2::default(), 1.0, 1.0, None))
        .collect();
    let mut solver = BlockCholesky::new(n, &edges);
    solver.clear();
    let m = 3 * (n - 1);
    let mut dense = DMatrix::zeros(m, m);
    let mut rhs = vec![0.0; m];
    for (k, &(a, b)) in pairs.iter().enumerate() {
        let (ja, jb) = (random_block(rng), random_block(rng));
        let root = random_block(rng);
        let w = root * root.transpose() + Matrix3::identity() * 0.5;
        let e = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let (wa, wb) = (ja.transpose() * w, jb.transpose() * w);
        let (haa, hbb, hba) = (wa * ja, wb * jb, wb * ja);
        let (ga, gb) = (-(wa * e), -(wb * e));
        solver.add_edge(k, (&haa, &hbb, &hba), (&ga, &gb));
        let mut put = |r: usize, c: usize, h: &Matrix3<f64>| {
            if r > 0 && c > 0 {
                let mut view = dense.fixed_view_mut::<3, 3>(3 * (r - 1), 3 * (c - 1));
                view += h;
            }
        };
        put(a, a, &haa);
        put(b, b, &hbb);
        put(b, a, &hba);
        put(a, b, &hba.transpose());
        for (node, g) in [(a, ga), (b, gb)] {
            if node > 0 {
                for r in 0..3 {
                    rhs[3 * (node - 1) + r] += g[r];
                }
            }
        }
    }
    (solver, dense, rhs)
}

#[test]
fn sparse_solve_matches_a_dense_solve() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    for n in [2, 3, 8, 60, 400] {
        let pairs = loopy_structure(n, &mut rng);
        let (mut solver, dense, rhs) = random_system(n, &pairs, &mut rng);
        for lambda in [0.0, 1e-6, 0.1, 10.0] {
            let mut damped = dense.clone();
            for r in 0..damped.nrows() {
                damped[(r, r)] += lambda * damped[(r, r)].abs().max(1e-9);
            }
            let truth = damped
                .cholesky()
                .expect("positive definite")
                .solve(&nalgebra::DVector::from_column_slice(&rhs));
            assert!(solver.solve_damped(lambda), "n {n} lambda {lambda}");
            let scale = truth.amax();
            let mut worst: f64 = 0.0;
            for node in 1..n {
                let got = solver.step_of(node);
                for r in 0..3 {
                    worst = worst.max((got[r] - truth[3 * (node - 1) + r]).abs());
                }
            }
            assert!(
                worst <= 1e-9 * scale,
                "n {n} lambda {lambda}: {worst} vs {scale}"
            );
        }
    }
}

#[test]
fn non_positive_definite_system_is_refused() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    let n = 200;
    let pairs = loopy_structure(n, &mut rng);
    for node in [1, 77, 199] {
        let (mut solver, _, _) = random_system(n, &pairs, &mut rng);
        assert!(solver.solve_damped(1e-6));
        // A negative curvature on one node (through its prior edge's block).
        let k = pairs.iter().position(|&p| p == (0, node)).unwrap_or(0);
        let zero = Matrix3::zeros();
        let g = Vector3::zeros();
        solver.add_edge(k, (&zero, &(Matrix3::identity() * -1e6), &zero), (&g, &g));
        assert!(!solver.solve_damped(1e-6), "node {node}");
        // The same system again after the refusal (buffers reused): still refused.
        assert!(!solver.solve_damped(1e-6), "node {node}");
    }
}

#[test]
fn minimum_degree_order_is_a_permutation_without_fill_on_a_tree() {
    // A tree (a chain with side branches): eliminating leaves first creates no fill.
    let n = 300;
    let mut edges = Vec::new();
    for k in 1..n {
        let parent = if k % 7 == 0 { k / 2 } else { k - 1 };
        edges.push(Edge::with_sigmas(
            parent,
            k,
            Pose2::default(),
            1.0,
            1.0,
            None,
        ));
    }
    let solver = BlockCholesky::new(n, &edges);
    let free_edges = edges.iter().filter(|e| e.from != 0).count();
    assert_eq!(solver.row_idx.len(), free_edges);
    let mut seen = solver.perm.clone();
    seen.sort_unstable();
    assert_eq!(seen, (0..n - 1).collect::<Vec<_>>());
    // Loops do fill, but far less than the dense triangle.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let pairs = loopy_structure(n, &mut rng);
    let (solver, _, _) = random_system(n, &pairs, &mut rng);
    let m = n - 1;
    assert!(
        solver.row_idx.len() < m * (m - 1) / 20,
        "{}",
        solver.row_idx.len()
    );
}

/// A corridor driven in laps, closures between laps, from drifted odometry.
fn lapped_graph(per_lap: usize, laps: usize) -> PoseGraph {
    let n = per_lap * laps;
    let pose = |k: usize| {
        let t = (k % per_lap) as f64 / per_lap as f64 * std::f64::consts::TAU;
        let r = 1.0 + 0.02 * (k / per_lap) as f64;
        Pose2::new(8.0 * r * t.cos(), 5.0 * r * t.sin(), t + 1.5)
    };
    let mut graph = PoseGraph::default();
    let mut odo = pose(0);
    graph.poses.push(odo);
    for k in 1..n {
        let mut z = pose(k - 1).between(&pose(k));
        z.yaw_rad += 0.003 * ((k * 7 % 5) as f64 - 1.5);
        graph
            .edges
            .push(Edge::with_sigmas(k - 1, k, z, 0.05, 0.02, None));
        odo = odo.compose(&z);
        graph.poses.push(odo);
    }
    for k in (per_lap..n).step_by(4) {
        let j = k - per_lap + (k * 13) % 3;
        let mut z = pose(j).between(&pose(k));
        z.x_m += 0.01;
        graph
            .edges
            .push(Edge::with_sigmas(j, k, z, 0.1, 0.03, Some(3.0)));
    }
    graph
}

#[test]
fn parallel_cost_is_the_serial_sum() {
    // 5,000 nodes, 6,250 edges: the parallel branch; 400 nodes: the serial one.
    for graph in [lapped_graph(1000, 5), lapped_graph(100, 4)] {
        let serial: f64 = (0..graph.edges.len())
            .map(|k| robust(graph.edge_chi2(k), graph.edges[k].robust_width).0)
            .sum();
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            assert_eq!(pool.install(|| graph.cost()).to_bits(), serial.to_bits());
        }
        assert!(serial > 1.0);
    }
}

#[test]
fn optimisation_has_the_same_bits_on_any_thread_count() {
    for graph in [lapped_graph(100, 4), lapped_graph(1000, 5)] {
        same_bits_on_any_thread_count(&graph);
    }
}

fn same_bits_on_any_thread_count(graph: &PoseGraph) {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| {
            let mut g = graph.clone();
            let report = g.optimize(&OptimizeOptions::default());
            (g, report)
        })
    };
    let (one, r1) = run(1);
    assert!(r1.final_cost < 0.01 * r1.initial_cost, "{r1:?}");
    for threads in [2, 3] {
        let (other, r) = run(threads);
        assert_eq!(r1.final_cost.to_bits(), r.final_cost.to_bits());
        for (a, b) in one.poses.iter().zip(&other.poses) {
            for (u, v) in [(a.x_m, b.x_m), (a.y_m, b.y_m), (a.yaw_rad, b.yaw_rad)] {
                assert_eq!(u.to_bits(), v.to_bits());
            }
        }
    }
}

#[test]
fn cholesky_solves_a_chain_with_a_long_edge() {
    // A chain with one closure: the solution must satisfy every edge exactly (consistent
    // measurements), from a perturbed start.
    let truth: Vec<Pose2> = (0..30)
        .map(|k| {
            Pose2::new(
                f64::from(k).cos() * 3.0,
                f64::from(k).sin() * 2.0,
                0.1 * f64::from(k),
            )
        })
        .collect();
    let mut g = PoseGraph::default();
    for k in 1..truth.len() {
        g.edges.push(Edge::with_sigmas(
            k - 1,
            k,
            truth[k - 1].between(&truth[k]),
            0.1,
            0.01,
            None,
        ));
    }
    g.edges.push(Edge::with_sigmas(
        3,
        27,
        truth[3].between(&truth[27]),
        0.1,
        0.01,
        None,
    ));
    g.poses = truth
        .iter()
        .enumerate()
        .map(|(k, p)| {
            if k == 0 {
                *p
            } else {
                Pose2::new(p.x_m + 0.3, p.y_m - 0.2, p.yaw_rad + 0.05)
            }
        })
        .collect();
    let r = g.optimize(&OptimizeOptions::default());
    assert!(r.final_cost < 1e-12, "{r:?}");
    for (p, t) in g.poses.iter().zip(&truth) {
        assert!(p.between(t).translation_norm_m() < 1e-6);
    }
}
