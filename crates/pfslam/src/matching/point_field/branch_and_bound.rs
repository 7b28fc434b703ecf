//! Branch-and-bound correlative search over a large x/y/yaw window (loop closures): exact
//! on the cell grid, the pooled levels bounding each branch; optionally excluding a
//! neighbourhood of a pose (to measure ambiguity).

use super::cells::PointCells;
use super::{PointField, SearchWindow};
use crate::geometry::{Pose2, wrap_angle};
use rayon::prelude::*;

#[derive(Debug, Clone, Copy)]
struct Candidate {
    yaw_index: usize,
    dx: i64,
    dy: i64,
    level: usize,
    score: f64,
}

/// The prepared top level of a branch-and-bound search ([`PointField::bnb_start`]).
#[derive(Debug, Clone)]
pub struct BnbStart {
    centre: Pose2,
    yaws: Vec<f64>,
    cells: Vec<PointCells>,
    cands: Vec<Candidate>,
    n: i64,
    n_pts: f64,
}

impl PointField {
    /// Branch-and-bound search of the best pose within `win` around `centre` whose mean
    /// cell score exceeds `min_score`; poses within `exclude.1` (m) and `exclude.2` (rad) of
    /// `exclude.0` are not considered (whole branches at once when they lie inside). Returns the pose (on the cell grid) and its mean
    /// cell score.
    pub fn search_bnb(
        &self,
        points_body: &[[f64; 2]],
        centre: &Pose2,
        win: &SearchWindow,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
    ) -> Option<(Pose2, f64)> {
        let start = self.bnb_start(points_body, centre, win)?;
        self.search_bnb_from(&start, min_score, exclude)
    }

    /// The top level of [`Self::search_bnb`] (yaws, cells of the points per yaw, scored
    /// top-level candidates), to share between searches of one scan in one window (the best
    /// pose, then the ambiguity test). Scored in parallel over yaws, collected in yaw order:
    /// the same candidates whatever the thread count. `None` without points.
    pub fn bnb_start(
        &self,
        points_body: &[[f64; 2]],
        centre: &Pose2,
        win: &SearchWindow,
    ) -> Option<BnbStart> {
        if points_body.is_empty() {
            return None;
        }
        let n_pts = points_body.len() as f64;
        let yaws = Self::window_yaws(centre, win);
        let n = (win.xy_m / self.resolution_m).ceil() as i64;
        let top = self.pooled_levels();
        let step = 1i64 << top;
        type YawCells = (PointCells, Vec<Candidate>);
        let per_yaw: Vec<YawCells> = yaws
            .par_iter()
            .enumerate()
            .map(|(a, &yaw)| {
                let c = self.cells_at(points_body, centre, yaw);
                let mut cands = Vec::new();
                let mut dy = -n;
                while dy <= n {
                    let mut dx = -n;
                    while dx <= n {
                        cands.push(Candidate {
                            yaw_index: a,
                            dx,
                            dy,
                            level: top,
                            score: self.cell_sum(&c, top, dx, dy) / n_pts,
                        });
                        dx += step;
                    }
                    dy += step;
                }
                (c, cands)
            })
            .collect();
        let mut cells = Vec::with_capacity(per_yaw.len());
        let mut cands = Vec::new();
        for (c, k) in per_yaw {
            cells.push(c);
            cands.extend(k);
        }
        // Sorted as `branch` sorts them (stable, best first): each search's own sort then
        // finds one run, the same order.
        cands.sort_by(|a, b| b.score.total_cmp(&a.score));
        Some(BnbStart {
            centre: *centre,
            yaws,
            cells,
            cands,
            n,
            n_pts,
        })
    }

    /// Whether `pose` (a pose of the search's cell grid, as [`Self::search_bnb_from`]
    /// returns) lies on the edge of `start`'s window: its x or y offset the window's
    /// half-width in cells, or its yaw the first or last of the window's (a window without
    /// any offset in a dimension has no edge there).
    pub fn on_window_edge(&self, start: &BnbStart, pose: &Pose2) -> bool {
        let c = &start.centre;
        let cells = |d: f64| (d / self.resolution_m).round().abs() as i64;
        let n = start.n;
        let xy = n > 0 && (cells(pose.x_m - c.x_m) >= n || cells(pose.y_m - c.y_m) >= n);
        let last = start.yaws.len().saturating_sub(1);
        let yaw = last > 0
            && start
                .yaws
                .iter()
                .position(|&y| y.to_bits() == pose.yaw_rad.to_bits())
                .is_some_and(|a| a == 0 || a == last);
        xy || yaw
    }

    /// [`Self::search_bnb`] from a prepared top level.
    pub fn search_bnb_from(
        &self,
        start: &BnbStart,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
    ) -> Option<(Pose2, f64)> {
        self.bnb_from(start, min_score, exclude, false)
    }

    /// Whether [`Self::search_bnb_from`] would find a pose (its `is_some()`): the search
    /// stops at the first pose above `min_score` instead of looking for the best (the
    /// ambiguity test needs no more).
    pub fn any_bnb_from(
        &self,
        start: &BnbStart,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
    ) -> bool {
        self.bnb_from(start, min_score, exclude, true).is_some()
    }

    fn bnb_from(
        &self,
        start: &BnbStart,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
        first_only: bool,
    ) -> Option<(Pose2, f64)> {
        let BnbStart {
            centre,
            yaws,
            cells,
            cands,
            n,
            n_pts,
        } = start;
        let mut best: Option<Candidate> = None;
        let mut best_score = min_score;
        let pose_of = |c: &Candidate| {
            Pose2::new(
                centre.x_m + c.dx as f64 * self.resolution_m,
                centre.y_m + c.dy as f64 * self.resolution_m,
                yaws[c.yaw_index],
            )
        };
        self.branch(
            cands.clone(),
            cells,
            (*n, *n_pts, first_only),
            &mut best,
            &mut best_score,
            // A node is excluded when every offset it covers is: its four corners are.
            &|c: &Candidate| {
                exclude.is_some_and(|(p, r, ryaw)| {
                    let span = (1i64 << c.level) - 1;
                    let q = pose_of(c);
                    wrap_angle(q.yaw_rad - p.yaw_rad).abs() < ryaw
                        && [(0, 0), (span, 0), (0, span), (span, span)]
                            .iter()
                            .all(|&(ox, oy)| {
                                let x = q.x_m + ox as f64 * self.resolution_m;
                                let y = q.y_m + oy as f64 * self.resolution_m;
                                (x - p.x_m).hypot(y - p.y_m) < r
                            })
                })
            },
        );
        best.map(|c| (pose_of(&c), c.score))
    }

    /// Depth first over `cands` (best bound first); `(n, n_pts, first_only)`: the window's
    /// half-width in cells, the point count, and whether to stop at the first leaf above
    /// `best_score`. Returns true when it stopped there.
    fn branch(
        &self,
        mut cands: Vec<Candidate>,
        cells: &[PointCells],
        (n, n_pts, first_only): (i64, f64, bool),
        best: &mut Option<Candidate>,
        best_score: &mut f64,
        excluded: &dyn Fn(&Candidate) -> bool,
    ) -> bool {
        cands.sort_by(|a, b| b.score.total_cmp(&a.score));
        for c in cands {
            if c.score <= *best_score {
                break;
            }
            if excluded(&c) {
                continue;
            }
            if c.level == 0 {
                *best_score = c.score;
                *best = Some(c);
                if first_only {
                    return true;
                }
                continue;
            }
            let half = 1i64 << (c.level - 1);
            let mut children = Vec::with_capacity(4);
            for (ox, oy) in [(0, 0), (half, 0), (0, half), (half, half)] {
                let (dx, dy) = (c.dx + ox, c.dy + oy);
                if dx > n || dy > n {
                    continue;
                }
                children.push(Candidate {
                    yaw_index: c.yaw_index,
                    dx,
                    dy,
                    level: c.level - 1,
                    score: self.cell_sum(&cells[c.yaw_index], c.level - 1, dx, dy) / n_pts,
                });
            }
            if self.branch(
                children,
                cells,
                (n, n_pts, first_only),
                best,
                best_score,
                excluded,
            ) {
                return true;
            }
        }
        false
    }
}
