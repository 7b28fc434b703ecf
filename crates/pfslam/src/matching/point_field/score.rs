//! The interpolated score of a scan in a [`PointField`] (bilinear between cell centres,
//! several poses per pass; the kernels in `crate::kernels::field_score`) and the curvature
//! of the match objective.

use super::PointField;
use crate::geometry::Pose2;
use rayon::prelude::*;

/// Poses scored in one pass by the refinement (a pattern-search iteration's candidates).
pub(super) const PASS: usize = 6;

impl PointField {
    /// Mean interpolated field value (0..1) of `points_body` seen from `pose`.
    pub fn score(&self, points_body: &[[f64; 2]], pose: &Pose2) -> f64 {
        let (s, c) = pose.yaw_rad.sin_cos();
        self.score_rotated(points_body, pose, s, c)
    }

    /// [`Self::score`] with `(s, c)` = `pose.yaw_rad.sin_cos()` given.
    pub(super) fn score_rotated(
        &self,
        points_body: &[[f64; 2]],
        pose: &Pose2,
        s: f64,
        c: f64,
    ) -> f64 {
        let [score] = self.scores_rotated(points_body, [*pose], [(s, c)]);
        score
    }

    /// [`Self::score_rotated`] of `K` poses (`sin_cos[k]` of `poses[k]`'s yaw) in one pass
    /// over the points. Each pose has its own accumulator and adds its own values in its
    /// own order, so each score is the bits of its [`Self::score_rotated`]; the independent
    /// chains of additions can overlap.
    fn scores_rotated<const K: usize>(
        &self,
        points_body: &[[f64; 2]],
        poses: [Pose2; K],
        sin_cos: [(f64, f64); K],
    ) -> [f64; K] {
        crate::kernels::field_score::scores(&self.level(0), points_body, poses, sin_cos)
    }

    /// [`Self::scores_rotated`] of any number of poses into `out`, up to [`PASS`] per pass (a
    /// pattern-search iteration's candidates).
    pub(super) fn scores_batched(
        &self,
        points_body: &[[f64; 2]],
        poses: &[Pose2],
        sin_cos: &[(f64, f64)],
        out: &mut [f64],
    ) {
        let chunks = poses.chunks(PASS).zip(sin_cos.chunks(PASS));
        for ((p, sc), o) in chunks.zip(out.chunks_mut(PASS)) {
            crate::matching::likelihood_field::by_count!(p.len().min(sc.len()).min(o.len()), K => {
                let scores = self.scores_rotated::<K>(
                    points_body,
                    std::array::from_fn(|i| p[i]),
                    std::array::from_fn(|i| sc[i]),
                );
                o.copy_from_slice(&scores);
            });
        }
    }

    /// Curvature of the match objective `n * score` at `pose`: minus its Hessian with
    /// respect to world (x, y, yaw), by central differences with steps `h_xy_m`, `h_yaw_rad`.
    /// Large along directions the scan pins down, near zero along a corridor's axis.
    pub fn curvature(
        &self,
        points_body: &[[f64; 2]],
        pose: &Pose2,
        h_xy_m: f64,
        h_yaw_rad: f64,
    ) -> nalgebra::Matrix3<f64> {
        let n = points_body.len() as f64;
        let h = [h_xy_m, h_xy_m, h_yaw_rad];
        // The 19 displacements of the central differences, scored in parallel (each score
        // is computed alone, so the same bits as one after the other).
        let mut steps: Vec<[f64; 3]> = vec![[0.0; 3]];
        for i in 0..3 {
            for si in [1.0, -1.0] {
                let mut d = [0.0; 3];
                d[i] = si * h[i];
                steps.push(d);
            }
            for j in 0..i {
                for (si, sj) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                    let mut d = [0.0; 3];
                    d[i] = si * h[i];
                    d[j] = sj * h[j];
                    steps.push(d);
                }
            }
        }
        let values: Vec<f64> = steps
            .par_iter()
            .map(|d| {
                let p = Pose2::new(pose.x_m + d[0], pose.y_m + d[1], pose.yaw_rad + d[2]);
                n * self.score(points_body, &p)
            })
            .collect();
        let mut next = values[1..].iter();
        let mut take = || next.next().copied().unwrap_or(f64::NAN);
        let f0 = values[0];
        let mut m = nalgebra::Matrix3::zeros();
        for i in 0..3 {
            let fp = take();
            let fm = take();
            m[(i, i)] = -(fp - 2.0 * f0 + fm) / (h[i] * h[i]);
            for j in 0..i {
                let (pp, pm, mp, mm) = (take(), take(), take(), take());
                let v = -(pp - pm - mp + mm) / (4.0 * h[i] * h[j]);
                m[(i, j)] = v;
                m[(j, i)] = v;
            }
        }
        m
    }
}
