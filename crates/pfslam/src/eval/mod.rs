//! Accuracy metrics: absolute trajectory error ([`ate`]), relative pose error ([`rpe`]) and
//! the relations metric of Kümmerle et al. 2009 ([`relations`]), plus the association of two
//! trajectories by timestamp they share ([`associate`]).
//!
//! All results are serde structs, so the CLI prints them as text or JSON.

pub mod ate;
pub mod relations;
pub mod rpe;

use crate::files::IoError;
use crate::geometry::{Pose2, Trajectory};
use serde::{Deserialize, Serialize};

/// Errors of the metrics.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Reading an input file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// Too few poses could be associated to compute the metric.
    #[error("{0}")]
    TooFew(String),
    /// An option is out of range.
    #[error("invalid option: {0}")]
    InvalidOption(String),
}

/// How an estimate pose finds its ground-truth partner.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Association {
    /// The ground-truth pose with the nearest stamp, if within `tolerance_ns` (0 = exact).
    Nearest {
        /// Largest accepted stamp difference (ns).
        tolerance_ns: i64,
    },
    /// The ground truth interpolated at the estimate's stamp, if the two ground-truth poses
    /// around it are at most `max_gap_ns` apart (no interpolation across gaps).
    Interpolate {
        /// Largest accepted gap between the bracketing ground-truth poses (ns).
        max_gap_ns: i64,
    },
}

impl Default for Association {
    /// Nearest stamp within 1 microsecond.
    fn default() -> Self {
        Association::Nearest {
            tolerance_ns: 1_000,
        }
    }
}

/// One associated pair of poses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PosePair {
    /// Stamp of the estimate (ns).
    pub stamp_ns: i64,
    /// The estimated pose.
    pub estimate: Pose2,
    /// The ground-truth pose.
    pub ground_truth: Pose2,
}

/// Index of the pose of `trajectory` nearest in time to `stamp_ns` and the time difference.
pub fn nearest_index(trajectory: &Trajectory, stamp_ns: i64) -> Option<(usize, i64)> {
    let p = &trajectory.poses;
    if p.is_empty() {
        return None;
    }
    let i = p.partition_point(|s| s.stamp_ns < stamp_ns);
    let mut best: Option<(usize, i64)> = None;
    for j in [i.wrapping_sub(1), i] {
        if let Some(s) = p.get(j) {
            let d = (s.stamp_ns - stamp_ns).abs();
            if best.is_none_or(|(_, bd)| d < bd) {
                best = Some((j, d));
            }
        }
    }
    best
}

/// Pairs every estimate pose with its ground truth (estimates without a partner are left out).
pub fn associate(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    association: Association,
) -> Vec<PosePair> {
    let mut out = Vec::with_capacity(estimate.len());
    for e in &estimate.poses {
        let gt = match association {
            Association::Nearest { tolerance_ns } => nearest_index(ground_truth, e.stamp_ns)
                .filter(|&(_, d)| d <= tolerance_ns)
                .map(|(i, _)| ground_truth.poses[i].pose),
            Association::Interpolate { max_gap_ns } => {
                let p = &ground_truth.poses;
                let i = p.partition_point(|s| s.stamp_ns < e.stamp_ns);
                match (i.checked_sub(1).and_then(|j| p.get(j)), p.get(i)) {
                    (_, Some(b)) if b.stamp_ns == e.stamp_ns => Some(b.pose),
                    (Some(a), Some(b)) if b.stamp_ns - a.stamp_ns <= max_gap_ns => {
                        ground_truth.pose_at(e.stamp_ns)
                    }
                    _ => None,
                }
            }
        };
        if let Some(g) = gt {
            out.push(PosePair {
                stamp_ns: e.stamp_ns,
                estimate: e.pose,
                ground_truth: g,
            });
        }
    }
    out
}

/// Summary statistics of a list of non-negative errors.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Number of values.
    pub count: usize,
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Standard deviation (population: divided by `count`).
    pub std: f64,
    /// Median.
    pub median: f64,
    /// Largest value.
    pub max: f64,
}

impl ErrorStats {
    /// Statistics of `values` (all zero when empty).
    pub fn from_values(values: &[f64]) -> Self {
        let n = values.len();
        if n == 0 {
            return ErrorStats::default();
        }
        let nf = n as f64;
        let mean = values.iter().sum::<f64>() / nf;
        let sq = values.iter().map(|v| v * v).sum::<f64>() / nf;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / nf;
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        };
        ErrorStats {
            count: n,
            rmse: sq.sqrt(),
            mean,
            std: var.sqrt(),
            median,
            max: sorted[n - 1],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::StampedPose2;

    fn traj(stamps: &[i64]) -> Trajectory {
        Trajectory::new(
            stamps
                .iter()
                .map(|&s| StampedPose2 {
                    stamp_ns: s,
                    pose: Pose2::new(s as f64, 0.0, 0.0),
                })
                .collect(),
        )
    }

    #[test]
    fn stats() {
        let s = ErrorStats::from_values(&[3.0, 4.0]);
        assert_eq!(s.count, 2);
        assert!((s.mean - 3.5).abs() < 1e-12);
        assert!((s.rmse - 12.5f64.sqrt()).abs() < 1e-12);
        assert!((s.std - 0.5).abs() < 1e-12);
        assert_eq!(s.max, 4.0);
        assert_eq!(s.median, 3.5);
    }

    #[test]
    fn association_modes() {
        let gt = traj(&[0, 10, 20, 100]);
        let est = traj(&[1, 10, 15, 60]);
        let near = associate(&est, &gt, Association::Nearest { tolerance_ns: 1 });
        assert_eq!(near.len(), 2);
        let exact = associate(&est, &gt, Association::Nearest { tolerance_ns: 0 });
        assert_eq!(exact.len(), 1);
        let interp = associate(&est, &gt, Association::Interpolate { max_gap_ns: 10 });
        assert_eq!(interp.len(), 3);
        assert!((interp[2].ground_truth.x_m - 15.0).abs() < 1e-12);
    }
}
