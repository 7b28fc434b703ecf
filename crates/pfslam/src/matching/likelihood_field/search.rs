//! One match: the coarse search, then the sub-cell pattern search; every particle's match.

use super::*;
use crate::geometry::Pose2;
use crate::kernels::coarse::{CoarseYaw, coarse_sums, coarse_sums_any, coarse_sums_fast};
use crate::map::MapLimits;
use rayon::prelude::*;

/// Caller-owned buffers of [`match_scan`], one per worker.
#[derive(Debug, Clone, Default)]
pub struct MatchScratch {
    base: Vec<usize>,
    /// Refinement: the points rotated by the current yaw and by one-off yaws.
    rotated: RotationBuffers,
    /// Coarse search: field sums per x/y offset for one yaw.
    sums: Vec<u32>,
}

/// The optimum found for one particle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchResult {
    /// The matched pose.
    pub pose: Pose2,
    /// Objective there: log-likelihood of the points minus the prior's penalty.
    pub objective: f64,
    /// Mean field value of the points there (0..1): how well the scan fits.
    pub fit: f64,
}

impl MatchResult {
    /// The result without a field to match against: the pose as given, nothing gained.
    pub(super) fn unmatched(pose: Pose2) -> Self {
        MatchResult {
            pose,
            objective: 0.0,
            fit: 0.0,
        }
    }
}

pub(super) fn prior_penalty(p: &MatchParams, dx: f64, dy: f64, dyaw: f64) -> f64 {
    0.5 * ((dx * dx + dy * dy) * p.inv_var_xy + dyaw * dyaw * p.inv_var_yaw)
}

/// The six moves of a hill climb's step, `(dx, dy, dyaw)`: +-`step_xy` in x, then in y,
/// then +-`step_yaw` in yaw. Every climb tries them in this order, which decides its ties.
#[inline]
pub(crate) fn six_moves(step_xy: f64, step_yaw: f64) -> [(f64, f64, f64); 6] {
    [
        (step_xy, 0.0, 0.0),
        (-step_xy, 0.0, 0.0),
        (0.0, step_xy, 0.0),
        (0.0, -step_xy, 0.0),
        (0.0, 0.0, step_yaw),
        (0.0, 0.0, -step_yaw),
    ]
}

/// Evaluations [`pattern_search`] remembers (the last ones).
pub(super) const MEMO: usize = 16;

/// Pattern search with step halving (the sub-cell refinement of the matchers): from `start`
/// (x, y, yaw; `first` = its objective and score, i.e. the value of `start`), try
/// +-`step_xy` in x and y and +-`step_yaw` in yaw, move to the best strict improvement
/// (ties: the first in that order), halve the steps when none improves, `levels` times (at
/// most `max_iterations` moves or halvings). Returns the final position with its objective
/// and score.
///
/// `eval(cands, values)` writes (objective, score) of each candidate `(at, same_yaw)` into
/// `values` (as many as candidates, at most six); `same_yaw` says the candidate keeps the
/// current yaw (so rotated points can be reused). Every candidate of an iteration that is
/// not remembered goes to one call, so the evaluator can sum them in one pass; `eval` must
/// be a pure function of each position, and then the search moves exactly as it would
/// evaluating the candidates one at a time.
pub fn pattern_search(
    start: [f64; 3],
    first: (f64, f64),
    step_xy: f64,
    step_yaw: f64,
    levels: u32,
    max_iterations: u32,
    mut eval: impl FnMut(&[([f64; 3], bool)], &mut [(f64, f64)]),
) -> ([f64; 3], (f64, f64)) {
    let (mut at, mut best) = (start, first);
    let (mut step_xy, mut step_yaw) = (step_xy, step_yaw);
    let mut level = 0;
    let mut iterations = 0;
    // The last evaluations by position (bit patterns): a candidate that lands exactly on
    // one (the position the last move came from, or a diagonal neighbour of an earlier
    // position) reuses its value (~3 % fewer evaluations in the car's filter). Entries are
    // added in candidate order, as evaluating one candidate after the other would.
    let mut memo = [([u64::MAX; 3], (0.0, 0.0)); MEMO];
    memo[0] = (start.map(f64::to_bits), first);
    let mut memo_len = 1usize;
    while level < levels && iterations < max_iterations {
        iterations += 1;
        let moves = six_moves(step_xy, step_yaw);
        let cands = moves.map(|(ex, ey, eyaw)| [at[0] + ex, at[1] + ey, at[2] + eyaw]);
        // Per candidate: its value if remembered, else its index among the new ones. A
        // remembered value is read now (a later insertion of this iteration may reuse its
        // slot); a repeat of a new candidate of this iteration shares its evaluation.
        let mut values = [(0.0, 0.0); NEIGHBOURS];
        let mut new_of: [Option<usize>; NEIGHBOURS] = [None; NEIGHBOURS];
        let mut todo = [([0.0; 3], false); NEIGHBOURS];
        let mut todo_slot = [0usize; NEIGHBOURS];
        let mut n_todo = 0;
        for (i, (cand, &(_, _, eyaw))) in cands.iter().zip(&moves).enumerate() {
            let key = cand.map(f64::to_bits);
            let seen = memo[..memo_len.min(MEMO)].iter().position(|m| m.0 == key);
            match seen.map(|pos| (pos, todo_slot[..n_todo].iter().position(|&s| s == pos))) {
                Some((_, Some(t))) => new_of[i] = Some(t),
                Some((pos, None)) => values[i] = memo[pos].1,
                None => {
                    let pos = memo_len % MEMO;
                    memo[pos].0 = key;
                    memo_len += 1;
                    todo[n_todo] = (*cand, eyaw == 0.0);
                    todo_slot[n_todo] = pos;
                    new_of[i] = Some(n_todo);
                    n_todo += 1;
                }
            }
        }
        let mut evaluated = [(0.0, 0.0); NEIGHBOURS];
        if n_todo > 0 {
            eval(&todo[..n_todo], &mut evaluated[..n_todo]);
        }
        for t in 0..n_todo {
            memo[todo_slot[t]].1 = evaluated[t];
        }
        let mut moved: Option<([f64; 3], (f64, f64))> = None;
        for i in 0..NEIGHBOURS {
            let value = new_of[i].map_or(values[i], |t| evaluated[t]);
            if value.0 > moved.map_or(best.0, |m| m.1.0) {
                moved = Some((cands[i], value));
            }
        }
        match moved {
            Some((cand, value)) => {
                at = cand;
                best = value;
            }
            None => {
                step_xy *= 0.5;
                step_yaw *= 0.5;
                level += 1;
            }
        }
    }
    (at, best)
}

/// [`pattern_search`] without batched evaluation: one candidate evaluated
/// after the other, `eval(at, same_yaw)`. The reference the batched search must follow.
#[cfg(test)]
pub(crate) fn pattern_search_sequential(
    start: [f64; 3],
    first: (f64, f64),
    step_xy: f64,
    step_yaw: f64,
    levels: u32,
    max_iterations: u32,
    mut eval: impl FnMut([f64; 3], bool) -> (f64, f64),
) -> ([f64; 3], (f64, f64)) {
    let (mut at, mut best) = (start, first);
    let (mut step_xy, mut step_yaw) = (step_xy, step_yaw);
    let mut level = 0;
    let mut iterations = 0;
    // The last evaluations by position (bit patterns): a candidate that lands exactly on
    // one (the position the last move came from, or a diagonal neighbour of an earlier
    // position) reuses its value. `eval` is a pure function of the position, so this
    // changes no result (~3 % fewer evaluations in the car's filter).
    let mut memo = [([u64::MAX; 3], (0.0, 0.0)); MEMO];
    memo[0] = (start.map(f64::to_bits), first);
    let mut memo_len = 1usize;
    while level < levels && iterations < max_iterations {
        iterations += 1;
        let mut moved: Option<([f64; 3], (f64, f64))> = None;
        for (ex, ey, eyaw) in six_moves(step_xy, step_yaw) {
            let cand = [at[0] + ex, at[1] + ey, at[2] + eyaw];
            let key = cand.map(f64::to_bits);
            let seen = memo[..memo_len.min(MEMO)].iter().find(|m| m.0 == key);
            let value = match seen {
                Some(&(_, value)) => value,
                None => {
                    let value = eval(cand, eyaw == 0.0);
                    memo[memo_len % MEMO] = (key, value);
                    memo_len += 1;
                    value
                }
            };
            if value.0 > moved.map_or(best.0, |m| m.1.0) {
                moved = Some((cand, value));
            }
        }
        match moved {
            Some((cand, value)) => {
                at = cand;
                best = value;
            }
            None => {
                step_xy *= 0.5;
                step_yaw *= 0.5;
                level += 1;
            }
        }
    }
    (at, best)
}

/// Matches `points_body` (body-frame returns, m) against `field` around `predicted` (see the
/// module docs). Deterministic: fixed search order, strict improvements only.
pub fn match_scan(
    field: &LikelihoodField,
    points_body: &[[f64; 2]],
    predicted: &Pose2,
    params: &MatchParams,
    scratch: &mut MatchScratch,
) -> MatchResult {
    let Some(limits) = field.limits else {
        return MatchResult::unmatched(*predicted);
    };
    let res = params.resolution_m;
    let r = params.xy_radius_cells.max(0);
    let side = (2 * r + 1) as usize;
    // Coarse: per yaw, points to window indices once; x/y offsets are index shifts.
    let mut best = (f64::NEG_INFINITY, 0i32, 0i32, 0.0f64);
    for &dyaw in &params.yaw_offsets_rad {
        let (s, c) = (predicted.yaw_rad + dyaw).sin_cos();
        let coarse = CoarseYaw {
            field: field.window(),
            limits: &limits,
            predicted,
            sin_cos: (s, c),
            r,
        };
        coarse.bases(points_body, &mut scratch.base);
        // Point by point, the side x side block of the field under it is added to the sums
        // of all offsets at once: contiguous rows instead of one scattered byte per point
        // and offset. Integer sums: the same values in any order.
        scratch.sums.clear();
        scratch.sums.resize(side * side, 0);
        let (values, fw, base) = (&field.values[..], field.w, &scratch.base[..]);
        let sums = &mut scratch.sums[..];
        match side {
            // Fixed sides: the accumulators live in registers.
            3 => coarse_sums_fast::<3>(values, fw, base, sums),
            5 => coarse_sums_fast::<5>(values, fw, base, sums),
            7 => coarse_sums_fast::<7>(values, fw, base, sums),
            9 => coarse_sums::<9>(values, fw, base, sums),
            11 => coarse_sums::<11>(values, fw, base, sums),
            _ => coarse_sums_any(values, fw, side, base, sums),
        }
        for oy in 0..side {
            for ox in 0..side {
                let sum = scratch.sums[oy * side + ox];
                let (dx, dy) = (ox as i32 - r, oy as i32 - r);
                let obj = params.gain_per_unit * f64::from(sum)
                    - prior_penalty(params, f64::from(dx) * res, f64::from(dy) * res, dyaw);
                if obj > best.0 {
                    best = (obj, dx, dy, dyaw);
                }
            }
        }
    }
    let refine = RefineSteps {
        start_offset: [f64::from(best.1) * res, f64::from(best.2) * res, best.3],
        first_step_xy_m: 0.5 * res,
        first_step_yaw_rad: 0.5 * params.yaw_step_rad,
        halvings: params.refine_levels,
    };
    refine_from(
        field,
        &limits,
        points_body,
        predicted,
        params,
        scratch,
        &refine,
    )
}

/// Where the refinement's pattern search starts and how it shrinks.
#[derive(Debug, Clone, Copy)]
pub(super) struct RefineSteps {
    /// The first offset from the predicted pose: x m, y m, yaw rad.
    pub(super) start_offset: [f64; 3],
    /// The first step in x and y.
    pub(super) first_step_xy_m: f64,
    /// The first step in yaw.
    pub(super) first_step_yaw_rad: f64,
    /// How many times the steps are halved.
    pub(super) halvings: u32,
}

/// The refinement of [`match_scan`]: pattern search from `predicted` as `refine` says.
pub(super) fn refine_from(
    field: &LikelihoodField,
    limits: &MapLimits,
    points_body: &[[f64; 2]],
    predicted: &Pose2,
    params: &MatchParams,
    scratch: &mut MatchScratch,
    refine: &RefineSteps,
) -> MatchResult {
    let start = refine.start_offset;
    let steps = [refine.first_step_xy_m, refine.first_step_yaw_rad];
    let levels = refine.halvings;
    let n = points_body.len().max(1) as f64;
    let [dx, dy, dyaw] = start;
    let mut rot = RotatedPoints::take(&mut scratch.rotated, params.kernel_precision);
    // (objective, field sum) at the offset `d` with field sum `sum`.
    let value = |d: [f64; 3], sum: f64| {
        (
            params.gain_per_unit * sum - prior_penalty(params, d[0], d[1], d[2]),
            sum,
        )
    };
    let mut eval = |dx: f64, dy: f64, dyaw: f64, keep: bool| {
        let pose = offset_pose(predicted, [dx, dy, dyaw]);
        value(
            [dx, dy, dyaw],
            rot.field_sum(field, limits, points_body, &pose, keep),
        )
    };
    let first = eval(dx, dy, dyaw, true);
    // Refinement: pattern search with step halving on the interpolated field, an
    // iteration's candidates summed in one pass.
    let ([dx, dy, dyaw], (obj, sum)) = pattern_search(
        [dx, dy, dyaw],
        first,
        steps[0],
        steps[1],
        levels,
        64,
        |cands, values| {
            for (cands, values) in cands.chunks(NEIGHBOURS).zip(values.chunks_mut(NEIGHBOURS)) {
                let mut poses = [(Pose2::default(), false); NEIGHBOURS];
                let mut sums = [0.0; NEIGHBOURS];
                for (p, &(d, keep)) in poses.iter_mut().zip(cands) {
                    *p = (offset_pose(predicted, d), keep);
                }
                let n = cands.len();
                rot.field_sums(field, limits, points_body, &poses[..n], &mut sums[..n]);
                for ((v, &(d, _)), sum) in values.iter_mut().zip(cands).zip(sums) {
                    *v = value(d, sum);
                }
            }
        },
    );
    rot.give_back(&mut scratch.rotated);
    MatchResult {
        pose: offset_pose(predicted, [dx, dy, dyaw]),
        objective: obj,
        fit: sum / (255.0 * n),
    }
}

/// `predicted` moved by the offset `d` (x m, y m, yaw rad), as every refinement forms it.
pub(super) fn offset_pose(predicted: &Pose2, d: [f64; 3]) -> Pose2 {
    Pose2::new(
        predicted.x_m + d[0],
        predicted.y_m + d[1],
        predicted.yaw_rad + d[2],
    )
}

/// Matches every particle (`predicted[i]` -> `results[i]`) with [`match_scan`], in
/// parallel; deterministic for any thread count (each result depends only on its inputs).
pub fn match_particles(
    field: &LikelihoodField,
    points_body: &[[f64; 2]],
    predicted: &[Pose2],
    params: &MatchParams,
    results: &mut [MatchResult],
) {
    results
        .par_iter_mut()
        .zip(predicted.par_iter())
        .for_each_init(MatchScratch::default, |scratch, (m, pose)| {
            *m = match_scan(field, points_body, pose, params, scratch);
        });
}

/// The returns of `scan` within `range_max_m` of the sensor, every `decimation`-th, as
/// body-frame matching points (into a caller-owned buffer).
pub fn match_points(
    scan: &crate::map::PlanarScan,
    range_max_m: f64,
    decimation: usize,
    out: &mut Vec<[f64; 2]>,
) {
    out.clear();
    let r2 = range_max_m * range_max_m;
    out.extend(
        scan.points
            .iter()
            .filter(|p| {
                p.hit && {
                    let (dx, dy) = (p.x_m - scan.sensor_x_m, p.y_m - scan.sensor_y_m);
                    dx * dx + dy * dy <= r2
                }
            })
            .step_by(decimation.max(1))
            .map(|p| [p.x_m, p.y_m]),
    );
}
