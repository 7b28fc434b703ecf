//! Relative pose error: the error of the relative motion between pose `i` and a later pose
//! `j`, where `j` is a fixed number of frames later or the first pose at least a given
//! distance (along the ground-truth path) later.

use super::{Association, ErrorStats, EvalError, PosePair, associate};
use crate::geometry::{Trajectory, wrap_angle};
use serde::{Deserialize, Serialize};

/// The step between the two poses of each relative motion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RpeDelta {
    /// `j = i + frames` (over the associated pairs).
    Frames(usize),
    /// The first `j` whose ground-truth path length from `i` is at least this many metres.
    Metres(f64),
}

impl Default for RpeDelta {
    fn default() -> Self {
        RpeDelta::Frames(1)
    }
}

/// RPE of an estimate against ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RpeResult {
    /// The step used.
    pub delta: RpeDelta,
    /// Translational error of the relative motions (m).
    pub trans_m: ErrorStats,
    /// Rotational error of the relative motions (deg).
    pub rot_deg: ErrorStats,
}

/// RPE over already associated pairs (in time order).
pub fn rpe_of_pairs(pairs: &[PosePair], delta: RpeDelta) -> Result<RpeResult, EvalError> {
    let mut trans = Vec::new();
    let mut rot = Vec::new();
    let mut push = |i: usize, j: usize| {
        let g = pairs[i].ground_truth.between(&pairs[j].ground_truth);
        let e = pairs[i].estimate.between(&pairs[j].estimate);
        let d = g.between(&e);
        trans.push(d.translation_norm_m());
        rot.push(wrap_angle(d.yaw_rad).abs().to_degrees());
    };
    match delta {
        RpeDelta::Frames(k) => {
            if k == 0 {
                return Err(EvalError::InvalidOption("RPE delta of 0 frames".into()));
            }
            for i in 0..pairs.len().saturating_sub(k) {
                push(i, i + k);
            }
        }
        RpeDelta::Metres(d) => {
            if !(d > 0.0 && d.is_finite()) {
                return Err(EvalError::InvalidOption(format!(
                    "RPE delta must be a positive distance, got {d} m"
                )));
            }
            // cumulative ground-truth path length, then a two-pointer sweep
            let mut cum = Vec::with_capacity(pairs.len());
            let mut s = 0.0;
            for (k, p) in pairs.iter().enumerate() {
                if k > 0 {
                    s += pairs[k - 1]
                        .ground_truth
                        .between(&p.ground_truth)
                        .translation_norm_m();
                }
                cum.push(s);
            }
            let mut j = 0;
            for i in 0..pairs.len() {
                j = j.max(i + 1);
                while j < pairs.len() && cum[j] - cum[i] < d {
                    j += 1;
                }
                if j >= pairs.len() {
                    break;
                }
                push(i, j);
            }
        }
    }
    if trans.is_empty() {
        return Err(EvalError::TooFew(format!(
            "RPE: no pose pair {delta:?} apart among {} associated poses",
            pairs.len()
        )));
    }
    Ok(RpeResult {
        delta,
        trans_m: ErrorStats::from_values(&trans),
        rot_deg: ErrorStats::from_values(&rot),
    })
}

/// RPE of `estimate` against `ground_truth`, pairing poses by `association`.
pub fn rpe(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    association: Association,
    delta: RpeDelta,
) -> Result<RpeResult, EvalError> {
    rpe_of_pairs(&associate(estimate, ground_truth, association), delta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;

    fn straight(n: usize, step: f64) -> Vec<PosePair> {
        (0..n)
            .map(|i| PosePair {
                stamp_ns: i as i64,
                estimate: Pose2::new(i as f64 * step * 1.1, 0.0, 0.0),
                ground_truth: Pose2::new(i as f64 * step, 0.0, 0.0),
            })
            .collect()
    }

    #[test]
    fn scale_error_shows_per_step() {
        let p = straight(11, 1.0);
        let r = rpe_of_pairs(&p, RpeDelta::Frames(1)).unwrap();
        assert_eq!(r.trans_m.count, 10);
        assert!((r.trans_m.mean - 0.1).abs() < 1e-9);
        let r = rpe_of_pairs(&p, RpeDelta::Metres(2.0)).unwrap();
        assert_eq!(r.trans_m.count, 9);
        assert!((r.trans_m.max - 0.2).abs() < 1e-9);
        assert!(rpe_of_pairs(&p, RpeDelta::Frames(0)).is_err());
        assert!(rpe_of_pairs(&p, RpeDelta::Metres(100.0)).is_err());
    }
}
