//! Scan matching in a particle's own map: a coarse yaw/x/y search, then a hill climb.

use super::*;
use crate::geometry::{Pose2, wrap_angle};
use crate::map::OccupancyGrid;

/// Search parameters of [`match_in_own_map`].
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

impl SearchParams {
    /// From the options, for maps of `resolution_m`.
    pub fn new(o: &RbpfOptions, resolution_m: f64) -> Self {
        let o = &o.search;
        let steps = (o.coarse_yaw_deg / o.coarse_yaw_step_deg).floor() as i32;
        let mut yaw_offsets_rad = vec![0.0];
        for k in 1..=steps {
            let d = (f64::from(k) * o.coarse_yaw_step_deg).to_radians();
            yaw_offsets_rad.push(-d);
            yaw_offsets_rad.push(d);
        }
        SearchParams {
            yaw_offsets_rad,
            xy_cells: o.coarse_xy_cells as i32,
            resolution_m,
            step_xy_m: o.step_xy_m,
            step_yaw_rad: o.step_yaw_deg.to_radians(),
            refine_levels: o.refine_levels,
            prior: None,
        }
    }
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
    let prior = search.prior;
    // The objective `ll - penalty` (`ll` alone without a prior: `x - 0.0` is `x`). Given
    // the value to beat, the likelihood may stop early; the result then does not beat it.
    let eval = |p: &Pose2, bar: Option<f64>| {
        let penalty = match prior {
            Some(pr) => {
                let (dx, dy) = (p.x_m - start.x_m, p.y_m - start.y_m);
                let da = wrap_angle(p.yaw_rad - start.yaw_rad);
                0.5 * ((dx * dx + dy * dy) * pr.inv_var_xy + da * da * pr.inv_var_yaw)
            }
            None => 0.0,
        };
        let bar = bar.map(|bar| Bar { penalty, bar });
        let ll = scan_log_likelihood_above(grid, model, points, p, bar);
        let objective = match prior {
            Some(_) => ll - penalty,
            None => ll,
        };
        (objective, ll)
    };
    // Every pose evaluated so far has an objective <= the current value to beat (which
    // only rises: a candidate either lost against it or raised it), so a candidate equal
    // to one of them bit for bit cannot win and is not evaluated again.
    let bits = |p: &Pose2| [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits);
    let mut seen: Vec<[u64; 3]> = Vec::with_capacity(64);
    let mut best = *start;
    // `best_raw`: the best pose's log-likelihood without the prior (always a full sum: a
    // winner never stopped early).
    let (mut best_ll, mut best_raw) = eval(&best, None);
    seen.push(bits(&best));
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
                let (ll, raw) = eval(&cand, Some(best_ll));
                seen.push(bits(&cand));
                if ll > best_ll {
                    best_ll = ll;
                    best_raw = raw;
                    best = cand;
                }
            }
        }
    }
    let (mut sxy, mut syaw) = (search.step_xy_m, search.step_yaw_rad);
    let mut level = 0;
    let mut iterations = 0;
    // (Not `scanmatch::pattern_search`: this climb wraps the yaw at every step.)
    while level < search.refine_levels && iterations < 200 {
        iterations += 1;
        let mut moved: Option<(Pose2, f64, f64)> = None;
        for (ex, ey, ea) in [
            (sxy, 0.0, 0.0),
            (-sxy, 0.0, 0.0),
            (0.0, sxy, 0.0),
            (0.0, -sxy, 0.0),
            (0.0, 0.0, syaw),
            (0.0, 0.0, -syaw),
        ] {
            let cand = Pose2::new(best.x_m + ex, best.y_m + ey, best.yaw_rad + ea);
            let key = bits(&cand);
            if seen.contains(&key) {
                continue;
            }
            seen.push(key);
            let to_beat = moved.map_or(best_ll, |m| m.1);
            let (ll, raw) = eval(&cand, Some(to_beat));
            if ll > to_beat {
                moved = Some((cand, ll, raw));
            }
        }
        match moved {
            Some((p, ll, raw)) => {
                best = p;
                best_ll = ll;
                best_raw = raw;
            }
            None => {
                sxy *= 0.5;
                syaw *= 0.5;
                level += 1;
            }
        }
    }
    let wrapped = wrap_angle(best.yaw_rad);
    // The weight is the observation's likelihood, without the prior: the one computed for
    // this pose, unless wrapping the yaw changed the pose (then recomputed, with a prior).
    let ll = if prior.is_none() || wrapped.to_bits() == best.yaw_rad.to_bits() {
        best_raw
    } else {
        scan_log_likelihood(
            grid,
            model,
            points,
            &Pose2 {
                yaw_rad: wrapped,
                ..best
            },
        )
    };
    best.yaw_rad = wrapped;
    (best, ll)
}

/// Gaussian prior of the matcher on the deviation from the sampled pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchPrior {
    /// `1 / sigma_xy^2` (1/m^2).
    pub inv_var_xy: f64,
    /// `1 / sigma_yaw^2` (1/rad^2).
    pub inv_var_yaw: f64,
}
