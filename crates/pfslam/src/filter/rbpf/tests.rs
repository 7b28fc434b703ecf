use super::*;
use crate::geometry::{Pose2, StampedPose2};
use std::sync::Arc;

fn node(pose: Pose2, odom: Pose2, scan: usize, parent: &Arc<PathNode>) -> Arc<PathNode> {
    Arc::new(PathNode {
        pose,
        odom,
        scan,
        parent: Some(parent.clone()),
    })
}

#[test]
fn output_path_is_the_survivors_history_with_odometry_between_nodes() {
    let o = |x: f64| Pose2::new(x, 0.0, 0.0);
    let root = Arc::new(PathNode {
        pose: o(0.0),
        odom: o(0.0),
        scan: 0,
        parent: None,
    });
    // Two particles branch at scan 2: A thinks it is at y = +1, B at y = -1.
    let a = node(Pose2::new(2.0, 1.0, 0.0), o(2.0), 2, &root);
    let b = node(Pose2::new(2.0, -1.0, 0.0), o(2.0), 2, &root);
    // Resampling keeps only B (two copies); they extend B's history.
    let b1 = node(Pose2::new(4.0, -1.0, 0.0), o(4.0), 4, &b);
    let b2 = node(Pose2::new(4.0, -1.2, 0.0), o(4.0), 4, &b);
    drop(a);
    let odometry: Vec<StampedPose2> = (0..6)
        .map(|k| StampedPose2 {
            stamp_ns: k as i64,
            pose: o(k as f64),
        })
        .collect();
    let path = path_poses(&b2, &odometry);
    let ys: Vec<f64> = path.iter().map(|p| p.pose.y_m).collect();
    let xs: Vec<f64> = path.iter().map(|p| p.pose.x_m).collect();
    assert_eq!(ys, vec![0.0, 0.0, -1.0, -1.0, -1.2, -1.2]);
    assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(path_poses(&b1, &odometry)[5].pose.y_m, -1.0);
    assert_eq!(ancestry(&b2).len(), 3);
}

#[test]
fn dropping_a_long_path_does_not_recurse() {
    let mut leaf = Arc::new(PathNode {
        pose: Pose2::IDENTITY,
        odom: Pose2::IDENTITY,
        scan: 0,
        parent: None,
    });
    for k in 1..1_000_000 {
        leaf = node(Pose2::IDENTITY, Pose2::IDENTITY, k, &leaf);
    }
    drop(leaf);
}
