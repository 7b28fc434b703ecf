//! Particles' trajectories: a tree of update nodes with shared parents.

use crate::geometry::{Pose2, StampedPose2};
use std::sync::Arc;

/// One node of a particle's trajectory tree: its pose at an update, the odometry pose there,
/// and the node of the previous update. Resampled copies share their parents.
#[derive(Debug)]
pub struct PathNode {
    /// The particle's pose at this update.
    pub pose: Pose2,
    /// The odometry pose at this update (the increments to later scans start here).
    pub odom: Pose2,
    /// Index of the update's scan among the processed scans.
    pub scan: usize,
    /// The previous update's node (`None` at the start).
    pub parent: Option<Arc<PathNode>>,
}

impl Drop for PathNode {
    /// Iterative: a long chain must not recurse once per node (stack overflow).
    fn drop(&mut self) {
        let mut next = self.parent.take();
        while let Some(node) = next {
            match Arc::try_unwrap(node) {
                Ok(mut n) => next = n.parent.take(),
                Err(_) => break,
            }
        }
    }
}

/// The nodes from the root to `leaf`, in time order.
pub fn ancestry(leaf: &Arc<PathNode>) -> Vec<&PathNode> {
    let mut out = Vec::new();
    let mut cur: Option<&PathNode> = Some(leaf);
    while let Some(n) = cur {
        out.push(n);
        cur = n.parent.as_deref();
    }
    out.reverse();
    out
}

/// Poses of every processed scan along the path ending at `leaf`: each scan takes the last
/// node at or before it, composed with the odometry increment from that node to the scan.
/// `odometry[k]` is the odometry pose of processed scan `k`.
pub fn path_poses(leaf: &Arc<PathNode>, odometry: &[StampedPose2]) -> Vec<StampedPose2> {
    path_poses_from(leaf, odometry, 0)
}

/// [`path_poses`] for the processed scans from `first` on: `odometry[j]` is the odometry
/// pose of processed scan `first + j`.
pub fn path_poses_from(
    leaf: &Arc<PathNode>,
    odometry: &[StampedPose2],
    first: usize,
) -> Vec<StampedPose2> {
    let nodes = ancestry(leaf);
    let mut out = Vec::with_capacity(odometry.len());
    let mut n = 0;
    for (j, o) in odometry.iter().enumerate() {
        let k = first + j;
        while n + 1 < nodes.len() && nodes[n + 1].scan <= k {
            n += 1;
        }
        let node = nodes[n];
        out.push(StampedPose2 {
            stamp_ns: o.stamp_ns,
            pose: node.pose.compose(&node.odom.between(&o.pose)),
        });
    }
    out
}
