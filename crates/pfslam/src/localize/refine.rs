//! The converged estimate refined by matching the whole scan in the likelihood field: the
//! particles' mean carries their spread's noise (a cloud of hundreds about the true pose),
//! a local match of every return does not.

use super::field::{LikelihoodField, Sharpness};
use crate::geometry::{Pose2, wrap_angle};

/// The first x/y step of the climb (m); halved `LEVELS` times.
const STEP_XY_M: f64 = 0.05;
/// The first yaw step (deg).
const STEP_YAW_DEG: f64 = 1.0;
/// Step halvings.
const LEVELS: u32 = 4;
/// A refinement that moves farther than this from the estimate (m, deg) found another basin
/// and is not used.
const MAX_MOVE: (f64, f64) = (0.25, 5.0);

fn score(field: &LikelihoodField, points: &[[f64; 2]], pose: &Pose2) -> f64 {
    let (s, c) = pose.yaw_rad.sin_cos();
    points
        .iter()
        .map(|p| {
            let (x, y) = pose.transform_point_with((s, c), p[0], p[1]);
            f64::from(field.log_likelihood(Sharpness::Tracking, x, y))
        })
        .sum()
}

/// `pose` moved to the best score of `points` (body frame) in `field` by a hill climb (six
/// moves, step halving); `pose` itself when the climb leaves [`MAX_MOVE`].
pub fn refine_pose(field: &LikelihoodField, points: &[[f64; 2]], pose: &Pose2) -> Pose2 {
    let mut best = *pose;
    let mut best_score = score(field, points, &best);
    let (mut sxy, mut syaw) = (STEP_XY_M, STEP_YAW_DEG.to_radians());
    let mut level = 0;
    let mut iterations = 0;
    while level < LEVELS && iterations < 100 {
        iterations += 1;
        let mut moved = false;
        for (dx, dy, da) in [
            (sxy, 0.0, 0.0),
            (-sxy, 0.0, 0.0),
            (0.0, sxy, 0.0),
            (0.0, -sxy, 0.0),
            (0.0, 0.0, syaw),
            (0.0, 0.0, -syaw),
        ] {
            let cand = Pose2::new(best.x_m + dx, best.y_m + dy, best.yaw_rad + da);
            let s = score(field, points, &cand);
            if s > best_score {
                (best, best_score, moved) = (cand, s, true);
            }
        }
        if !moved {
            sxy *= 0.5;
            syaw *= 0.5;
            level += 1;
        }
    }
    best.yaw_rad = wrap_angle(best.yaw_rad);
    let far = (best.x_m - pose.x_m).hypot(best.y_m - pose.y_m) > MAX_MOVE.0
        || wrap_angle(best.yaw_rad - pose.yaw_rad).abs() > MAX_MOVE.1.to_radians();
    if far { *pose } else { best }
}
