//! Which scans a session keeps as keyframes: a scan once the body moved or turned enough
//! since the last keyframe, unless a keyframe already stands there (the rule that keeps a
//! map driven many times as small as one driven once).

use super::SessionOptions;
use crate::geometry::{Pose2, wrap_angle};
use std::collections::HashMap;

/// Keyframe poses bucketed by a square cell of the prune radius, for the "already mapped
/// here" test.
#[derive(Debug, Default)]
pub struct KeyframeIndex {
    cell_m: f64,
    buckets: HashMap<(i64, i64), Vec<Pose2>>,
}

impl KeyframeIndex {
    /// An empty index for `options`' prune radius.
    pub fn new(options: &SessionOptions) -> Self {
        KeyframeIndex {
            cell_m: options.prune_radius_m.max(1e-3),
            buckets: HashMap::new(),
        }
    }

    fn key(&self, p: &Pose2) -> (i64, i64) {
        (
            (p.x_m / self.cell_m).floor() as i64,
            (p.y_m / self.cell_m).floor() as i64,
        )
    }

    /// Adds a keyframe pose.
    pub fn insert(&mut self, p: Pose2) {
        let k = self.key(&p);
        self.buckets.entry(k).or_default().push(p);
    }

    /// True when a keyframe lies within `radius_m` and `angle_rad` of `p`.
    pub fn covers(&self, p: &Pose2, radius_m: f64, angle_rad: f64) -> bool {
        let (ci, cj) = self.key(p);
        (ci - 1..=ci + 1).any(|i| {
            (cj - 1..=cj + 1).any(|j| {
                self.buckets.get(&(i, j)).is_some_and(|v| {
                    v.iter().any(|q| {
                        (q.x_m - p.x_m).hypot(q.y_m - p.y_m) <= radius_m
                            && wrap_angle(q.yaw_rad - p.yaw_rad).abs() <= angle_rad
                    })
                })
            })
        })
    }
}

/// The indices of `poses` kept as keyframes, given the keyframes already in `index` (which
/// receives the new ones): a pose becomes a keyframe when it moved `keyframe_distance_m` or
/// turned `keyframe_angle_deg` since the last pose considered, and no keyframe lies within
/// `prune_radius_m` and `prune_angle_deg` of it.
pub fn select_keyframes(
    poses: &[Pose2],
    options: &SessionOptions,
    index: &mut KeyframeIndex,
) -> Vec<usize> {
    let angle = options.keyframe_angle_deg.to_radians();
    let prune_angle = options.prune_angle_deg.to_radians();
    let mut kept = Vec::new();
    let mut last: Option<Pose2> = None;
    for (i, p) in poses.iter().enumerate() {
        let due = last.is_none_or(|q| {
            (q.x_m - p.x_m).hypot(q.y_m - p.y_m) >= options.keyframe_distance_m
                || wrap_angle(q.yaw_rad - p.yaw_rad).abs() >= angle
        });
        if !due {
            continue;
        }
        last = Some(*p);
        if index.covers(p, options.prune_radius_m, prune_angle) {
            continue;
        }
        index.insert(*p);
        kept.push(i);
    }
    kept
}
