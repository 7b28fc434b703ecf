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
use crate::io::IoError;
use crate::io::tum::parse_stamp_ns;
use serde::{Deserialize, Serialize};
use std::io::BufRead;
use std::path::Path;

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

fn decimals_tolerance_ns(text: &str) -> i64 {
    let d = text
        .split_once('.')
        .map(|(_, f)| f.bytes().take_while(|b| b.is_ascii_digit()).count())
        .unwrap_or(0)
        .min(9);
    // half a unit of the last printed decimal
    5 * 10i64.pow(8 - d.min(8) as u32) / if d == 9 { 10 } else { 1 }
}

/// Reads a `.relations` file: `t1 t2 x y z roll pitch yaw` per line (`#` comments allowed).
pub fn read_relations(path: &Path) -> Result<Vec<Relation>, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    read_relations_from(std::io::BufReader::new(file), path)
}

/// [`read_relations`] from any reader; `path` names the source in errors.
pub fn read_relations_from(reader: impl BufRead, path: &Path) -> Result<Vec<Relation>, IoError> {
    let mut out = Vec::new();
    for (idx, line) in reader.lines().enumerate() {
        let line_no = idx + 1;
        let line = line.map_err(|e| IoError::parse(path, line_no, format!("read failed: {e}")))?;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = t.split_whitespace().collect();
        if f.len() != 8 {
            return Err(IoError::parse(
                path,
                line_no,
                format!(
                    "expected 8 fields (t1 t2 x y z roll pitch yaw), found {}",
                    f.len()
                ),
            ));
        }
        let stamp = |k: usize, name: &str| {
            parse_stamp_ns(f[k]).ok_or_else(|| {
                IoError::parse(path, line_no, format!("{name}: not a time: {:?}", f[k]))
            })
        };
        let t1_ns = stamp(0, "t1")?;
        let t2_ns = stamp(1, "t2")?;
        let x = crate::io::parse_finite_f64(path, line_no, "x", f[2])?;
        let y = crate::io::parse_finite_f64(path, line_no, "y", f[3])?;
        for (k, name) in [(4, "z"), (5, "roll"), (6, "pitch")] {
            crate::io::parse_finite_f64(path, line_no, name, f[k])?;
        }
        let yaw = crate::io::parse_finite_f64(path, line_no, "yaw", f[7])?;
        out.push(Relation {
            t1_ns,
            t2_ns,
            t1_tolerance_ns: decimals_tolerance_ns(f[0]),
            t2_tolerance_ns: decimals_tolerance_ns(f[1]),
            t1_from_t2: Pose2::new(x, y, yaw),
        });
    }
    Ok(out)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tolerance_from_decimals() {
        assert_eq!(decimals_tolerance_ns("976052905.167303"), 500);
        assert_eq!(decimals_tolerance_ns("1134864645.90321"), 5_000);
        assert_eq!(decimals_tolerance_ns("12"), 500_000_000);
        assert_eq!(decimals_tolerance_ns("1.123456789"), 0);
    }
}
