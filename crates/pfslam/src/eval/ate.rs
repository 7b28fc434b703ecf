//! Absolute trajectory error: the position error of every associated pose, after the best
//! SE(2) alignment of the estimate onto the ground truth (closed-form 2-D Horn/Umeyama without
//! scale) and without alignment.

use super::{Association, ErrorStats, EvalError, PosePair, associate};
use crate::geometry::{Pose2, Trajectory, wrap_angle};
use serde::{Deserialize, Serialize};

/// ATE of an estimate against ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AteResult {
    /// Associated pose pairs used.
    pub pairs: usize,
    /// Estimate poses without a ground-truth partner.
    pub unmatched: usize,
    /// Position error (m) after SE(2) alignment.
    pub aligned_m: ErrorStats,
    /// Heading error (deg) after SE(2) alignment.
    pub aligned_rot_deg: ErrorStats,
    /// Position error (m) as given.
    pub unaligned_m: ErrorStats,
    /// Heading error (deg) as given.
    pub unaligned_rot_deg: ErrorStats,
    /// The alignment `gt_from_estimate` applied to the estimate.
    pub alignment: Pose2,
}

/// The rigid planar transform `T` minimising `sum |g_i - T e_i|^2` over the positions (no
/// scale): centroids, then the angle of the cross-covariance.
pub fn align_se2(pairs: &[PosePair]) -> Pose2 {
    if pairs.is_empty() {
        return Pose2::IDENTITY;
    }
    let n = pairs.len() as f64;
    let (mut ex, mut ey, mut gx, mut gy) = (0.0, 0.0, 0.0, 0.0);
    for p in pairs {
        ex += p.estimate.x_m;
        ey += p.estimate.y_m;
        gx += p.ground_truth.x_m;
        gy += p.ground_truth.y_m;
    }
    let (ex, ey, gx, gy) = (ex / n, ey / n, gx / n, gy / n);
    let (mut sin_sum, mut cos_sum) = (0.0, 0.0);
    for p in pairs {
        let (ax, ay) = (p.estimate.x_m - ex, p.estimate.y_m - ey);
        let (bx, by) = (p.ground_truth.x_m - gx, p.ground_truth.y_m - gy);
        sin_sum += ax * by - ay * bx;
        cos_sum += ax * bx + ay * by;
    }
    let theta = if sin_sum == 0.0 && cos_sum == 0.0 {
        0.0
    } else {
        sin_sum.atan2(cos_sum)
    };
    let (s, c) = theta.sin_cos();
    Pose2::new(gx - (c * ex - s * ey), gy - (s * ex + c * ey), theta)
}

fn errors(pairs: &[PosePair], t: &Pose2) -> (Vec<f64>, Vec<f64>) {
    pairs
        .iter()
        .map(|p| {
            let e = t.compose(&p.estimate);
            (
                (e.x_m - p.ground_truth.x_m).hypot(e.y_m - p.ground_truth.y_m),
                wrap_angle(e.yaw_rad - p.ground_truth.yaw_rad)
                    .abs()
                    .to_degrees(),
            )
        })
        .unzip()
}

/// ATE of already associated pairs.
pub fn ate_of_pairs(pairs: &[PosePair], unmatched: usize) -> Result<AteResult, EvalError> {
    if pairs.len() < 2 {
        return Err(EvalError::TooFew(format!(
            "ATE needs at least 2 associated poses, found {} ({} estimate poses without ground truth)",
            pairs.len(),
            unmatched
        )));
    }
    let alignment = align_se2(pairs);
    let (ta, ra) = errors(pairs, &alignment);
    let (tu, ru) = errors(pairs, &Pose2::IDENTITY);
    Ok(AteResult {
        pairs: pairs.len(),
        unmatched,
        aligned_m: ErrorStats::from_values(&ta),
        aligned_rot_deg: ErrorStats::from_values(&ra),
        unaligned_m: ErrorStats::from_values(&tu),
        unaligned_rot_deg: ErrorStats::from_values(&ru),
        alignment,
    })
}

/// ATE of `estimate` against `ground_truth`, pairing poses by `association`.
pub fn ate(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    association: Association,
) -> Result<AteResult, EvalError> {
    let pairs = associate(estimate, ground_truth, association);
    ate_of_pairs(&pairs, estimate.len() - pairs.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::StampedPose2;

    #[test]
    fn alignment_recovers_transform() {
        let t = Pose2::new(3.0, -2.0, 0.8);
        let pairs: Vec<PosePair> = (0..20)
            .map(|i| {
                let e = Pose2::new((i as f64 * 0.7).sin() * 5.0, i as f64 * 0.3, i as f64 * 0.1);
                PosePair {
                    stamp_ns: i,
                    estimate: e,
                    ground_truth: t.compose(&e),
                }
            })
            .collect();
        let a = align_se2(&pairs);
        assert!((a.x_m - 3.0).abs() < 1e-9 && (a.y_m + 2.0).abs() < 1e-9);
        assert!((a.yaw_rad - 0.8).abs() < 1e-9);
        let r = ate_of_pairs(&pairs, 0).unwrap();
        assert!(r.aligned_m.rmse < 1e-9);
        assert!(r.aligned_rot_deg.max < 1e-6);
        assert!(r.unaligned_m.rmse > 1.0);
    }

    #[test]
    fn too_few() {
        let t = Trajectory::new(vec![StampedPose2 {
            stamp_ns: 0,
            pose: Pose2::IDENTITY,
        }]);
        assert!(ate(&t, &t, Association::default()).is_err());
    }
}
