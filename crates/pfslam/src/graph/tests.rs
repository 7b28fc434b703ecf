use super::back_end::optimize_tail;
use super::*;
use rand::{RngExt, SeedableRng};

/// A 400-node lawnmower path: noisy odometry edges and loop edges from every 10th node
/// of each later lane to the node beside it on the earlier lane; node 0 at the origin.
fn lanes() -> PoseGraph {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
    let truth: Vec<Pose2> = (0..400)
        .map(|i| {
            let (lane, t) = (i / 50, (i % 50) as f64);
            let x = if lane % 2 == 0 { t } else { 49.0 - t };
            let yaw = if lane % 2 == 0 {
                0.0
            } else {
                std::f64::consts::PI
            };
            Pose2::new(x, 2.0 * lane as f64, yaw)
        })
        .collect();
    let mut g = PoseGraph::default();
    let mut noise = |s: f64| s * (rng.random::<f64>() - 0.5);
    for i in 0..truth.len() {
        g.poses.push(match i {
            0 => truth[0],
            _ => {
                let z = truth[i - 1].between(&truth[i]);
                let z = Pose2::new(
                    z.x_m + noise(0.05),
                    z.y_m + noise(0.05),
                    z.yaw_rad + noise(0.01),
                );
                g.edges
                    .push(Edge::with_sigmas(i - 1, i, z, 0.02, 0.005, None));
                g.poses[i - 1].compose(&z)
            }
        });
    }
    for i in (60..400).step_by(10) {
        let (lane, t) = (i / 50, i % 50);
        let j = (lane - 1) * 50 + 49 - t;
        let z = truth[j].between(&truth[i]);
        g.edges
            .push(Edge::with_sigmas(j, i, z, 0.05, 0.02, Some(3.0)));
    }
    g
}

/// `optimize_tail`: from node 1 on (node 0 at the origin) the bits of `optimize`; from a
/// later node, the earlier ones keep their bits and the rest is the optimum with them
/// pinned (here: pinned by stiff edges from the origin instead).
#[test]
fn tail_optimisation_holds_the_head_fixed() {
    let opts = OptimizeOptions::default();
    let (mut a, mut b) = (lanes(), lanes());
    a.optimize(&opts);
    optimize_tail(&mut b, 1, &opts);
    assert_eq!(a.poses, b.poses);
    let first = 230;
    let mut tail = lanes();
    let before = tail.cost();
    optimize_tail(&mut tail, first, &opts);
    assert_eq!(tail.poses[..first], lanes().poses[..first]);
    assert!(tail.cost() < 0.7 * before, "{} -> {}", before, tail.cost());
    let mut pinned = lanes();
    for v in 1..first {
        let e = Edge::with_sigmas(0, v, pinned.poses[v], 1e-9, 1e-9, None);
        pinned.edges.push(e);
    }
    pinned.optimize(&opts);
    for (p, q) in tail.poses.iter().zip(&pinned.poses).skip(first) {
        assert!(p.between(q).translation_norm_m() < 1e-4, "{p:?} {q:?}");
        assert!(wrap_angle_abs(p.yaw_rad - q.yaw_rad) < 1e-5, "{p:?} {q:?}");
    }
}

fn wrap_angle_abs(a: f64) -> f64 {
    crate::geometry::wrap_angle(a).abs()
}
