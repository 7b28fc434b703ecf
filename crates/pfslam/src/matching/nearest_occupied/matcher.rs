//! Scan matching in a particle's own map: a coarse yaw/x/y search, then a hill climb.

use super::*;
use crate::geometry::{Pose2, wrap_angle};
use crate::map::OccupancyGrid;

/// Search parameters of [`match_in_own_map`] (from the `rbpf` mode's options:
/// [`RbpfOptions::search_params`](crate::filter::rbpf::RbpfOptions::search_params)).
#[derive(Debug, Clone, PartialEq)]
pub struct SearchParams {
    /// Coarse yaw offsets (rad), 0 first.
    pub yaw_offsets_rad: Vec<f64>,
    /// Coarse x/y half-width (cells).
    pub xy_cells: i32,
    /// Cell side (m).
    pub resolution_m: f64,
    /// Initial hill-climb steps (m, rad).
    pub step_xy_m: f64,
    /// Initial hill-climb yaw step (rad).
    pub step_yaw_rad: f64,
    /// Step halvings.
    pub refine_levels: u32,
    /// Prior on the deviation from the sampled pose (set per update from the motion).
    pub prior: Option<MatchPrior>,
}

/// Scan-matches `points` against `grid` around `start`: coarse search over the yaw offsets
/// and x/y cells, then a hill climb (six moves, step halving). Returns the pose and its
/// log-likelihood. Deterministic: fixed order, strict improvements only.
pub fn match_in_own_map(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    start: &Pose2,
    search: &SearchParams,
) -> (Pose2, f64) {
    let objective = Objective {
        grid,
        model,
        points,
        start,
        prior: search.prior,
    };
    let mut best = Best::at_start(&objective);
    best.coarse_search(&objective, search);
    best.hill_climb(&objective, search);
    best.into_wrapped(&objective)
}

/// The matcher's objective: the scan's log-likelihood at a pose minus the prior's penalty
/// on the deviation from `start`.
struct Objective<'a> {
    grid: &'a OccupancyGrid,
    model: &'a ObservationModel,
    points: &'a [[f64; 2]],
    start: &'a Pose2,
    prior: Option<MatchPrior>,
}

impl Objective<'_> {
    /// `(ll - penalty, ll)` at `p` (`ll` alone without a prior: `x - 0.0` is `x`). Given
    /// the value to beat, the likelihood may stop early; the result then does not beat it.
    #[inline]
    fn eval(&self, p: &Pose2, bar: Option<f64>) -> (f64, f64) {
        let start = self.start;
        let penalty = match self.prior {
            Some(pr) => {
                let (dx, dy) = (p.x_m - start.x_m, p.y_m - start.y_m);
                let da = wrap_angle(p.yaw_rad - start.yaw_rad);
                0.5 * ((dx * dx + dy * dy) * pr.inv_var_xy + da * da * pr.inv_var_yaw)
            }
            None => 0.0,
        };
        let bar = bar.map(|bar| Bar { penalty, bar });
        let ll = scan_log_likelihood_above(self.grid, self.model, self.points, p, bar);
        let objective = match self.prior {
            Some(_) => ll - penalty,
            None => ll,
        };
        (objective, ll)
    }
}

/// A pose's exact bits, to recognise a candidate already evaluated.
#[inline]
fn pose_bits(p: &Pose2) -> [u64; 3] {
    [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits)
}

/// The best pose so far and every pose evaluated on the way to it.
struct Best {
    pose: Pose2,
    /// The best pose's objective.
    objective: f64,
    /// The best pose's log-likelihood without the prior (always a full sum: a winner
    /// never stopped early).
    raw_ll: f64,
    /// Every pose evaluated so far has an objective <= the current value to beat (which
    /// only rises: a candidate either lost against it or raised it), so a candidate equal
    /// to one of them bit for bit cannot win and is not evaluated again.
    seen: Vec<[u64; 3]>,
}

impl Best {
    /// The start pose, evaluated in full.
    fn at_start(f: &Objective) -> Self {
        let pose = *f.start;
        let (objective, raw_ll) = f.eval(&pose, None);
        let mut seen: Vec<[u64; 3]> = Vec::with_capacity(64);
        seen.push(pose_bits(&pose));
        Best {
            pose,
            objective,
            raw_ll,
            seen,
        }
    }

    /// Coarse search over the yaw offsets and x/y cells around `start`.
    fn coarse_search(&mut self, f: &Objective, search: &SearchParams) {
        let start = f.start;
        let r = search.xy_cells;
        for &dyaw in &search.yaw_offsets_rad {
            for oy in -r..=r {
                for ox in -r..=r {
                    if dyaw == 0.0 && ox == 0 && oy == 0 {
                        continue;
                    }
                    let cand = Pose2::new(
                        start.x_m + f64::from(ox) * search.resolution_m,
                        start.y_m + f64::from(oy) * search.resolution_m,
                        start.yaw_rad + dyaw,
                    );
                    let (ll, raw) = f.eval(&cand, Some(self.objective));
                    self.seen.push(pose_bits(&cand));
                    if ll > self.objective {
                        self.objective = ll;
                        self.raw_ll = raw;
                        self.pose = cand;
                    }
                }
            }
        }
    }

    /// Hill climb from the best pose: six moves, steps halved when none improves.
    /// (Not `likelihood_field::pattern_search`: this climb wraps the yaw at every step.)
    fn hill_climb(&mut self, f: &Objective, search: &SearchParams) {
        let (mut sxy, mut syaw) = (search.step_xy_m, search.step_yaw_rad);
        let mut level = 0;
        let mut iterations = 0;
        while level < search.refine_levels && iterations < 200 {
            iterations += 1;
            match self.best_move(f, sxy, syaw) {
                Some((p, ll, raw)) => {
                    self.pose = p;
                    self.objective = ll;
                    self.raw_ll = raw;
                }
                None => {
                    sxy *= 0.5;
                    syaw *= 0.5;
                    level += 1;
                }
            }
        }
    }

    /// The best of the six moves of `sxy` (m) / `syaw` (rad) that beats the current
    /// objective, as `(pose, objective, raw_ll)`; moves to poses already seen are skipped.
    #[inline]
    fn best_move(&mut self, f: &Objective, sxy: f64, syaw: f64) -> Option<(Pose2, f64, f64)> {
        let best = self.pose;
        let mut moved: Option<(Pose2, f64, f64)> = None;
        for (ex, ey, ea) in crate::matching::likelihood_field::six_moves(sxy, syaw) {
            let cand = Pose2::new(best.x_m + ex, best.y_m + ey, best.yaw_rad + ea);
            let key = pose_bits(&cand);
            if self.seen.contains(&key) {
                continue;
            }
            self.seen.push(key);
            let to_beat = moved.map_or(self.objective, |m| m.1);
            let (ll, raw) = f.eval(&cand, Some(to_beat));
            if ll > to_beat {
                moved = Some((cand, ll, raw));
            }
        }
        moved
    }

    /// The best pose with its yaw wrapped, and its log-likelihood without the prior: the
    /// one computed for this pose, unless wrapping the yaw changed the pose (then
    /// recomputed, with a prior).
    fn into_wrapped(self, f: &Objective) -> (Pose2, f64) {
        let mut best = self.pose;
        let wrapped = wrap_angle(best.yaw_rad);
        let ll = if f.prior.is_none() || wrapped.to_bits() == best.yaw_rad.to_bits() {
            self.raw_ll
        } else {
            scan_log_likelihood(
                f.grid,
                f.model,
                f.points,
                &Pose2 {
                    yaw_rad: wrapped,
                    ..best
                },
            )
        };
        best.yaw_rad = wrapped;
        (best, ll)
    }
}

/// Gaussian prior of the matcher on the deviation from the sampled pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchPrior {
    /// `1 / sigma_xy^2` (1/m^2).
    pub inv_var_xy: f64,
    /// `1 / sigma_yaw^2` (1/rad^2).
    pub inv_var_yaw: f64,
}
