//! The converged estimate refined by matching the whole scan in the likelihood field: the
//! particles' mean carries their spread's noise (a cloud of hundreds about the true pose),
//! a local match of every return does not.

use super::{LikelihoodField, Sharpness};
use crate::geometry::{Pose2, wrap_angle};
use crate::matching::likelihood_field::six_moves;

/// The first x/y step of the climb (m); halved `LEVELS` times.
const STEP_XY_M: f64 = 0.05;
/// The first yaw step (deg).
const STEP_YAW_DEG: f64 = 1.0;
/// Step halvings.
const LEVELS: u32 = 4;
/// A refinement that moves farther than this from the estimate (m, deg) found another basin
/// and is not used.
pub const MAX_MOVE: (f64, f64) = (0.25, 5.0);

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
        for (dx, dy, da) in six_moves(sxy, syaw) {
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
    within_max_move(pose, best)
}

/// Floor of a point's squared residual in [`gauss_newton_step`]: a point on the wall has
/// none, and would weigh without bound (a quarter of the field's sigma squared).
const MIN_RESIDUAL2: f64 = 0.0625;

/// Gauss-Newton iterations of [`track_pose`] at most.
const TRACK_ITERATIONS: u32 = 5;

/// `pose` moved to a nearby maximum of the tracking score of `points` (body frame) by
/// Gauss-Newton steps on the bilinear field (residual: the field's peak minus a point's
/// log-likelihood), each kept only when it raises the score; `pose` itself when the result
/// leaves [`MAX_MOVE`]. A few passes over the points where [`refine_pose`]'s climb takes
/// dozens: for the poses between updates, which start close to the answer.
pub fn track_pose(field: &LikelihoodField, points: &[[f64; 2]], pose: &Pose2) -> Pose2 {
    let peak = f64::from(field.peak());
    let mut best = *pose;
    let mut best_score = score(field, points, &best);
    for _ in 0..TRACK_ITERATIONS {
        let Some(step) = gauss_newton_step(field, points, &best, peak) else {
            break;
        };
        // The full step, else half of it (a step overshoots where the field bends).
        let taken = [1.0, 0.5].into_iter().find_map(|f| {
            let cand = Pose2::new(
                best.x_m + f * step[0],
                best.y_m + f * step[1],
                best.yaw_rad + f * step[2],
            );
            let s = score(field, points, &cand);
            (s > best_score).then_some((cand, s))
        });
        let Some(taken) = taken else {
            break;
        };
        (best, best_score) = taken;
    }
    within_max_move(pose, best)
}

/// One Gauss-Newton step `(dx, dy, dyaw)` at `pose`; `None` when the normal equations are
/// singular (no point on a slope of the field).
fn gauss_newton_step(
    field: &LikelihoodField,
    points: &[[f64; 2]],
    pose: &Pose2,
    peak: f64,
) -> Option<[f64; 3]> {
    let (s, c) = pose.yaw_rad.sin_cos();
    let mut h = nalgebra::Matrix3::<f64>::zeros();
    let mut g = nalgebra::Vector3::<f64>::zeros();
    for p in points {
        let (x, y) = pose.transform_point_with((s, c), p[0], p[1]);
        let (ll, [gx, gy]) = field.tracking_with_gradient(x, y);
        let (gx, gy) = (f64::from(gx), f64::from(gy));
        // d(world point)/d(yaw) = (-s px - c py, c px - s py)
        let j = nalgebra::Vector3::new(
            gx,
            gy,
            gx * (-s * p[0] - c * p[1]) + gy * (c * p[0] - s * p[1]),
        );
        // Residual r = sqrt(2 (peak - ll)): minimising the sum of r^2 / 2 maximises the
        // score; dr = -dll / r, so the normal equations weigh each point by 1 / r^2.
        let r2 = (2.0 * (peak - f64::from(ll))).max(MIN_RESIDUAL2);
        h += j * j.transpose() / r2;
        g += j;
    }
    let step = h.try_inverse()? * g;
    step.iter()
        .all(|v| v.is_finite())
        .then(|| [step[0], step[1], step[2]])
}

/// `best` (its yaw wrapped) unless it lies beyond [`MAX_MOVE`] of `pose`: then `pose`.
fn within_max_move(pose: &Pose2, mut best: Pose2) -> Pose2 {
    best.yaw_rad = wrap_angle(best.yaw_rad);
    let far = (best.x_m - pose.x_m).hypot(best.y_m - pose.y_m) > MAX_MOVE.0
        || wrap_angle(best.yaw_rad - pose.yaw_rad).abs() > MAX_MOVE.1.to_radians();
    if far { *pose } else { best }
}
