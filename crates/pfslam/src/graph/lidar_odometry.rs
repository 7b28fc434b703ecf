//! Odometry from the scans alone, for recordings that have none (LiDAR-only mode): each scan
//! is matched against a local map of the last keyframes' returns (a correlative search
//! around a constant-velocity prediction with a Gaussian prior, then sub-cell refinement) and
//! the poses are chained. The filter then runs on this odometry as on a wheel odometry.

use crate::geometry::{Pose2, StampedPose2, Trajectory};
use crate::map::{MapError, PlanarScan, ScanOptions, ScanProjector, to_world};
use crate::matching::point_field::{PointField, Prior, SearchWindow};
use crate::sensors::Recording;
use std::collections::VecDeque;

/// Keyframes in the local map.
const KEYFRAMES: usize = 10;
/// A scan becomes a keyframe after this much travel (m) ...
const KEYFRAME_TRAVEL_M: f64 = 0.25;
/// ... or this much turning (rad, 10 deg).
const KEYFRAME_TURN_RAD: f64 = 0.1745;
/// Most returns matched per scan (evenly thinned above).
const MAX_POINTS: usize = 360;
/// Local map cells (m) and the field's Gaussian (m).
const RESOLUTION_M: f64 = 0.05;
const SIGMA_M: f64 = 0.1;
/// Fewer matched returns than this: the prediction is kept.
const MIN_POINTS: usize = 20;

/// The search around the prediction: +-0.3 m, +-12 deg in 1 deg steps.
fn window() -> SearchWindow {
    SearchWindow {
        xy_m: 0.3,
        yaw_rad: 12f64.to_radians(),
        yaw_step_rad: 1f64.to_radians(),
    }
}

/// The returns used for matching, in the body frame: nearer than 30 m, farther than 0.1 m.
fn scan_options() -> ScanOptions {
    ScanOptions {
        range_min_m: 0.1,
        range_max_m: 30.0,
        densify_max_gap_m: None,
        ..ScanOptions::default()
    }
}

/// A pose per scan of `recording` from scan matching alone, starting at the identity.
pub fn lidar_odometry(recording: &Recording) -> Result<Trajectory, MapError> {
    let mut projector = ScanProjector::new(
        &recording.lidar,
        &recording.body_from_lidar,
        &scan_options(),
    )?;
    let mut body = PlanarScan::default();
    let mut world = PlanarScan::default();
    let mut keyframes: VecDeque<Vec<[f64; 2]>> = VecDeque::new();
    let mut last_key = Pose2::IDENTITY;
    let mut poses: Vec<StampedPose2> = Vec::with_capacity(recording.scans.len());
    let mut velocity = Pose2::IDENTITY;
    for i in 0..recording.scans.len() {
        projector.aim(recording, i);
        projector.to_body(recording.scans.ranges(i), &mut body)?;
        let pts = thinned_returns(&body);
        let prev = poses.last().map_or(Pose2::IDENTITY, |p| p.pose);
        let predicted = prev.compose(&velocity);
        let pose = match_scan(&keyframes, &pts, &predicted).unwrap_or(predicted);
        if !poses.is_empty() {
            velocity = prev.between(&pose);
        }
        poses.push(StampedPose2 {
            stamp_ns: recording.scans.stamps_ns[i],
            pose,
        });
        let step = last_key.between(&pose);
        if keyframes.is_empty()
            || step.translation_norm_m() > KEYFRAME_TRAVEL_M
            || step.yaw_rad.abs() > KEYFRAME_TURN_RAD
        {
            to_world(&body, &pose, &mut world);
            keyframes.push_back(
                world
                    .points
                    .iter()
                    .filter(|p| p.hit)
                    .map(|p| [p.x_m, p.y_m])
                    .collect(),
            );
            if keyframes.len() > KEYFRAMES {
                keyframes.pop_front();
            }
            last_key = pose;
        }
    }
    Ok(Trajectory::new(poses))
}

/// The scan's returns, evenly thinned to at most [`MAX_POINTS`].
fn thinned_returns(body: &PlanarScan) -> Vec<[f64; 2]> {
    let hits: Vec<[f64; 2]> = body
        .points
        .iter()
        .filter(|p| p.hit)
        .map(|p| [p.x_m, p.y_m])
        .collect();
    let step = hits.len().div_ceil(MAX_POINTS).max(1);
    hits.into_iter().step_by(step).collect()
}

/// The pose of `pts` (body frame) in the local map, searched around `predicted`; `None`
/// when there is no map yet or too few returns.
fn match_scan(
    keyframes: &VecDeque<Vec<[f64; 2]>>,
    pts: &[[f64; 2]],
    predicted: &Pose2,
) -> Option<Pose2> {
    if keyframes.is_empty() || pts.len() < MIN_POINTS {
        return None;
    }
    let map: Vec<[f64; 2]> = keyframes.iter().flatten().copied().collect();
    let (mut min, mut max) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in &map {
        for k in 0..2 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let margin = 1.0;
    let field = PointField::build(
        &map,
        [min[0] - margin, min[1] - margin],
        [max[0] + margin, max[1] + margin],
        RESOLUTION_M,
        SIGMA_M,
        0,
    );
    let win = window();
    let prior = Prior {
        pose: *predicted,
        sigma_xy_m: 0.5,
        sigma_yaw_rad: 20f64.to_radians(),
    };
    let coarse = field.search_with_prior(pts, &prior, &win);
    Some(
        field
            .refine(pts, &coarse, win.yaw_step_rad, 4, Some(&prior))
            .0,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::{LidarGeometry, ScanSet};

    /// Ranges of a 360-beam scan from `pose` inside a 10 x 6 m room centred on the origin.
    fn room_scan(pose: &Pose2, g: &LidarGeometry) -> Vec<f32> {
        (0..g.beam_count)
            .map(|k| {
                let a = pose.yaw_rad + g.beam_angle_rad(k);
                let (s, c) = a.sin_cos();
                let tx = if c > 1e-9 {
                    (5.0 - pose.x_m) / c
                } else if c < -1e-9 {
                    (-5.0 - pose.x_m) / c
                } else {
                    f64::MAX
                };
                let ty = if s > 1e-9 {
                    (3.0 - pose.y_m) / s
                } else if s < -1e-9 {
                    (-3.0 - pose.y_m) / s
                } else {
                    f64::MAX
                };
                tx.min(ty) as f32
            })
            .collect()
    }

    #[test]
    fn follows_a_drive_in_a_room_from_scans_alone() {
        let g = LidarGeometry {
            angle_min_rad: -std::f64::consts::PI,
            angle_increment_rad: 1f64.to_radians(),
            beam_count: 360,
            range_min_m: 0.0,
            range_max_m: 30.0,
        };
        let mut scans = ScanSet::new(360);
        let mut truth = Vec::new();
        for k in 0..60 {
            let t = k as f64 * 0.1;
            // walls oblique to the first pose's axes, as real walls are to a field's cells
            let pose = Pose2::new(-2.0 + 0.6 * t, 0.3 * (0.5 * t).sin(), 0.4 + 0.15 * t);
            scans.push(k * 100_000_000, &room_scan(&pose, &g));
            truth.push(pose);
        }
        let rec = Recording {
            scans,
            lidar: g,
            ..Recording::default()
        };
        let odo = lidar_odometry(&rec).unwrap();
        assert_eq!(odo.len(), 60);
        // the path relative to its start, as the truth relative to its start
        let (t0, e0) = (truth[0], odo.poses[0].pose);
        for (t, e) in truth.iter().zip(&odo.poses) {
            let want = t0.between(t);
            let got = e0.between(&e.pose);
            assert!(
                (want.x_m - got.x_m).hypot(want.y_m - got.y_m) < 0.05,
                "{want:?} vs {got:?}"
            );
        }
    }
}
