//! The searches around a prediction: an exhaustive window on the cell grid with a Gaussian
//! prior on the deviation (sequential edges, refinement of the scans between keyframes), and
//! the sub-cell pattern search on the interpolated field.

use super::score::PASS;
use super::{PointField, SearchWindow};
use crate::geometry::{Pose2, wrap_angle};
use rayon::prelude::*;

/// A Gaussian prior on the deviation from a predicted pose, in units of "points": the
/// objective is `sum(field) - 0.5 * (d_xy^2 / sigma_xy^2 + d_yaw^2 / sigma_yaw^2)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prior {
    /// The predicted pose.
    pub pose: Pose2,
    /// Standard deviation in x and y (m).
    pub sigma_xy_m: f64,
    /// Standard deviation in yaw (rad).
    pub sigma_yaw_rad: f64,
}

impl Prior {
    pub(super) fn penalty(&self, p: &Pose2) -> f64 {
        let (dx, dy) = (p.x_m - self.pose.x_m, p.y_m - self.pose.y_m);
        let dyaw = wrap_angle(p.yaw_rad - self.pose.yaw_rad);
        0.5 * ((dx * dx + dy * dy) / (self.sigma_xy_m * self.sigma_xy_m)
            + dyaw * dyaw / (self.sigma_yaw_rad * self.sigma_yaw_rad))
    }
}

impl PointField {
    /// Exhaustive search over `win` around `prior.pose` maximising the cell scores minus
    /// the prior's penalty; returns the best pose on the cell grid.
    pub fn search_with_prior(
        &self,
        points_body: &[[f64; 2]],
        prior: &Prior,
        win: &SearchWindow,
    ) -> Pose2 {
        let centre = prior.pose;
        let yaws = Self::window_yaws(&centre, win);
        let n = (win.xy_m / self.resolution_m).ceil() as i64;
        // Each yaw's first best in (dy, dx) order, in parallel; then the first strictly
        // better over yaws in order: the sequential scan's answer for any thread count.
        let per_yaw: Vec<(f64, Pose2)> = yaws
            .par_iter()
            .map(|&yaw| {
                let c = self.cells_at(points_body, &centre, yaw);
                let mut best = (f64::NEG_INFINITY, centre);
                for dy in -n..=n {
                    for dx in -n..=n {
                        let pose = Pose2::new(
                            centre.x_m + dx as f64 * self.resolution_m,
                            centre.y_m + dy as f64 * self.resolution_m,
                            yaw,
                        );
                        let obj = self.cell_sum(&c, 0, dx, dy) - prior.penalty(&pose);
                        if obj > best.0 {
                            best = (obj, pose);
                        }
                    }
                }
                best
            })
            .collect();
        let mut best = (f64::NEG_INFINITY, centre);
        for b in per_yaw {
            if b.0 > best.0 {
                best = b;
            }
        }
        best.1
    }

    /// Sub-cell pattern search from `start` on the interpolated field (step halving from half
    /// a cell and `yaw_step_rad / 2`, `levels` times), with an optional prior. Returns the
    /// pose and its mean interpolated score.
    pub fn refine(
        &self,
        points_body: &[[f64; 2]],
        start: &Pose2,
        yaw_step_rad: f64,
        levels: u32,
        prior: Option<&Prior>,
    ) -> (Pose2, f64) {
        let n_pts = points_body.len().max(1) as f64;
        // Most steps of the pattern search keep the yaw: its sine and cosine once per yaw.
        let mut kept_yaw = (f64::NAN.to_bits(), 0.0, 0.0);
        let mut sin_cos = |yaw: f64, keep: bool| {
            if kept_yaw.0 == yaw.to_bits() {
                return (kept_yaw.1, kept_yaw.2);
            }
            let (s, c) = yaw.sin_cos();
            if keep {
                kept_yaw = (yaw.to_bits(), s, c);
            }
            (s, c)
        };
        let value = |p: &Pose2, s: f64| (s * n_pts - prior.map_or(0.0, |q| q.penalty(p)), s);
        let (s, c) = sin_cos(start.yaw_rad, true);
        let first = value(start, self.score_rotated(points_body, start, s, c));
        let ([x_m, y_m, yaw_rad], (_, score)) = crate::matching::likelihood_field::pattern_search(
            [start.x_m, start.y_m, start.yaw_rad],
            first,
            0.5 * self.resolution_m,
            0.5 * yaw_step_rad,
            levels,
            100,
            // An iteration's candidates scored in one pass.
            |cands, values| {
                for (cands, values) in cands.chunks(PASS).zip(values.chunks_mut(PASS)) {
                    let n = cands.len();
                    let mut poses = [Pose2::default(); PASS];
                    let mut sc = [(0.0, 0.0); PASS];
                    for ((p, sc), &(at, keep)) in poses.iter_mut().zip(&mut sc).zip(cands) {
                        *p = Pose2::new(at[0], at[1], at[2]);
                        *sc = sin_cos(p.yaw_rad, keep);
                    }
                    let mut scores = [0.0; PASS];
                    self.scores_batched(points_body, &poses[..n], &sc[..n], &mut scores[..n]);
                    for ((v, p), s) in values.iter_mut().zip(&poses).zip(scores) {
                        *v = value(p, s);
                    }
                }
            },
        );
        (Pose2::new(x_m, y_m, yaw_rad), score)
    }
}
