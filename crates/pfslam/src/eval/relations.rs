//! The relations metric of Kümmerle et al. 2009 ("On measuring the accuracy of SLAM
//! algorithms"): for each ground-truth relation `(t1, t2, x, y, yaw)` (the pose at `t2` in the
//! frame of the pose at `t1`), the estimate's relative pose `inv(X(t1)) * X(t2)` is compared
//! with it: `d = inv(relation) * estimate`, translational error `|d.xy|` (m) and rotational
//! error `|d.yaw|` (deg), absolute and squared.
//!
//! Stamp matching: the poses at `t1` and `t2` are taken from the trajectory at exactly those
//! stamps (the trajectory must hold a pose for every scan); a relation stamp printed with `d`
//! decimals matches the trajectory stamp nearest to it if they differ by at most half a unit of
//! the last decimal (`0.5 * 10^-d` s: 0.5 us for the Intel/ACES files' 6 decimals, 5 us for
//! MIT-CSAIL's 5), or by [`RelationsOptions::stamp_tolerance_ns`] when set. A relation whose
//! stamps do not both match is skipped and counted. `z`, `roll` and `pitch` are read and
//! ignored (planar SLAM; they are 0 in the Freiburg files).

use super::{EvalError, nearest_index};
use crate::geometry::{Pose2, Trajectory, wrap_angle};
use serde::{Deserialize, Serialize};

/// One ground-truth relation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Relation {
    /// First stamp (ns).
    pub t1_ns: i64,
    /// Second stamp (ns).
    pub t2_ns: i64,
    /// Matching tolerance implied by the decimals printed for `t1` (ns).
    pub t1_tolerance_ns: i64,
    /// Matching tolerance implied by the decimals printed for `t2` (ns).
    pub t2_tolerance_ns: i64,
    /// The pose at `t2` in the frame of the pose at `t1`.
    pub t1_from_t2: Pose2,
}

/// Options of the relations metric.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelationsOptions {
    /// Overrides the stamp tolerance implied by the printed decimals (ns).
    pub stamp_tolerance_ns: Option<i64>,
}

/// Mean, standard deviation (population) and maximum.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct MeanStd {
    /// Mean.
    pub mean: f64,
    /// Standard deviation (divided by the count).
    pub std: f64,
    /// Largest value.
    pub max: f64,
}

impl MeanStd {
    fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return MeanStd::default();
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        MeanStd {
            mean,
            std: var.sqrt(),
            max: values.iter().copied().fold(0.0, f64::max),
        }
    }
}

/// An error in absolute and squared form.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct AbsSquared {
    /// |error|.
    pub abs: MeanStd,
    /// error^2.
    pub squared: MeanStd,
}

/// The relations metric of one trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelationsResult {
    /// Relations in the file.
    pub relations: usize,
    /// Relations evaluated.
    pub used: usize,
    /// Relations skipped because a stamp has no pose in the trajectory.
    pub skipped: usize,
    /// Translational error (m; squared in m^2).
    pub trans_m: AbsSquared,
    /// Rotational error (deg; squared in deg^2).
    pub rot_deg: AbsSquared,
}

/// The trajectory pose matching a relation stamp (see the module docs), if any.
pub fn pose_for_stamp(trajectory: &Trajectory, stamp_ns: i64, tolerance_ns: i64) -> Option<Pose2> {
    nearest_index(trajectory, stamp_ns)
        .filter(|&(_, d)| d <= tolerance_ns)
        .map(|(i, _)| trajectory.poses[i].pose)
}

/// The error pose `inv(relation) * inv(X(t1)) * X(t2)` of every relation whose stamps match,
/// in file order (`None` for skipped relations).
pub fn relation_errors(
    trajectory: &Trajectory,
    relations: &[Relation],
    options: &RelationsOptions,
) -> Vec<Option<Pose2>> {
    relations
        .iter()
        .map(|r| {
            let tol1 = options.stamp_tolerance_ns.unwrap_or(r.t1_tolerance_ns);
            let tol2 = options.stamp_tolerance_ns.unwrap_or(r.t2_tolerance_ns);
            let a = pose_for_stamp(trajectory, r.t1_ns, tol1)?;
            let b = pose_for_stamp(trajectory, r.t2_ns, tol2)?;
            Some(r.t1_from_t2.between(&a.between(&b)))
        })
        .collect()
}

/// The relations metric of `trajectory` (see the module docs).
pub fn evaluate_relations(
    trajectory: &Trajectory,
    relations: &[Relation],
    options: &RelationsOptions,
) -> Result<RelationsResult, EvalError> {
    let errs = relation_errors(trajectory, relations, options);
    let mut t = Vec::with_capacity(errs.len());
    let mut r = Vec::with_capacity(errs.len());
    for d in errs.iter().flatten() {
        t.push(d.translation_norm_m());
        r.push(wrap_angle(d.yaw_rad).abs().to_degrees());
    }
    if t.is_empty() {
        return Err(EvalError::TooFew(format!(
            "none of the {} relations has both stamps in the trajectory ({} poses)",
            relations.len(),
            trajectory.len()
        )));
    }
    let sq = |v: &[f64]| v.iter().map(|x| x * x).collect::<Vec<f64>>();
    Ok(RelationsResult {
        relations: relations.len(),
        used: t.len(),
        skipped: relations.len() - t.len(),
        trans_m: AbsSquared {
            abs: MeanStd::of(&t),
            squared: MeanStd::of(&sq(&t)),
        },
        rot_deg: AbsSquared {
            abs: MeanStd::of(&r),
            squared: MeanStd::of(&sq(&r)),
        },
    })
}
