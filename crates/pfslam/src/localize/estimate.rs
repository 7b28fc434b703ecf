//! The pose estimate of a weighted particle set: the weighted mean of its heaviest cluster,
//! and the share of the weight that cluster holds (the convergence test). A mean over all
//! particles would average two candidate places into a wall between them.

use crate::geometry::{Pose2, wrap_angle};
use std::collections::HashMap;

/// The heaviest cluster.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Its weighted mean.
    pub pose: Pose2,
    /// Its share of the total weight.
    pub mass: f64,
}

/// The extent of a cluster about its centre.
#[derive(Debug, Clone, Copy)]
pub struct ClusterShape {
    /// Distance (m).
    pub radius_m: f64,
    /// Yaw (rad).
    pub yaw_rad: f64,
}

/// The estimate of `poses` with normalised `weights`: seeded at the heaviest histogram bin
/// (bins of the cluster's radius and yaw), then the weighted mean of every particle within
/// the cluster's extent of that bin's mean.
pub fn estimate(poses: &[Pose2], weights: &[f64], shape: &ClusterShape) -> Estimate {
    let key = |p: &Pose2| {
        (
            (p.x_m / shape.radius_m).floor() as i64,
            (p.y_m / shape.radius_m).floor() as i64,
            (wrap_angle(p.yaw_rad) / shape.yaw_rad).floor() as i64,
        )
    };
    let mut bins: HashMap<(i64, i64, i64), f64> = HashMap::new();
    for (p, &w) in poses.iter().zip(weights) {
        *bins.entry(key(p)).or_insert(0.0) += w;
    }
    // Ties broken by the key, so the result does not depend on the map's order.
    let best = bins
        .iter()
        .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(a.0)))
        .map(|(k, _)| *k);
    let seed = mean(
        poses
            .iter()
            .zip(weights)
            .filter(|(p, _)| Some(key(p)) == best),
    );
    let member = |p: &Pose2| {
        (p.x_m - seed.pose.x_m).hypot(p.y_m - seed.pose.y_m) <= shape.radius_m
            && wrap_angle(p.yaw_rad - seed.pose.yaw_rad).abs() <= shape.yaw_rad
    };
    mean(poses.iter().zip(weights).filter(|(p, _)| member(p)))
}

/// Weighted mean (circular for yaw) and total weight of some particles.
fn mean<'a>(members: impl Iterator<Item = (&'a Pose2, &'a f64)>) -> Estimate {
    let (mut w_sum, mut x, mut y, mut s, mut c) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (p, &w) in members {
        w_sum += w;
        x += w * p.x_m;
        y += w * p.y_m;
        s += w * p.yaw_rad.sin();
        c += w * p.yaw_rad.cos();
    }
    if w_sum <= 0.0 {
        return Estimate {
            pose: Pose2::IDENTITY,
            mass: 0.0,
        };
    }
    Estimate {
        pose: Pose2::new(x / w_sum, y / w_sum, s.atan2(c)),
        mass: w_sum,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn picks_the_heavier_of_two_places() {
        let mut poses = Vec::new();
        let mut weights = Vec::new();
        for k in 0..10 {
            let d = k as f64 * 0.01;
            poses.push(Pose2::new(5.0 + d, 1.0, 3.1));
            weights.push(0.07);
            poses.push(Pose2::new(-2.0 - d, 4.0, -3.1 + d));
            weights.push(0.03);
        }
        let shape = ClusterShape {
            radius_m: 1.0,
            yaw_rad: 0.5,
        };
        let e = estimate(&poses, &weights, &shape);
        assert!((e.mass - 0.7).abs() < 1e-9, "{e:?}");
        assert!((e.pose.x_m - 5.045).abs() < 1e-9 && (e.pose.y_m - 1.0).abs() < 1e-12);
        assert!((e.pose.yaw_rad - 3.1).abs() < 1e-9);
    }

    #[test]
    fn yaw_mean_crosses_pi() {
        let poses = [Pose2::new(0.0, 0.0, 3.1), Pose2::new(0.0, 0.0, -3.1)];
        let e = estimate(
            &poses,
            &[0.5, 0.5],
            &ClusterShape {
                radius_m: 1.0,
                yaw_rad: 0.5,
            },
        );
        assert!((e.mass - 1.0).abs() < 1e-12);
        assert!(wrap_angle(e.pose.yaw_rad - std::f64::consts::PI).abs() < 1e-9);
    }
}
