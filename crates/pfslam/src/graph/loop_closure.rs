//! Loop closures: the candidates of a keyframe, their verification by branch and bound
//! (full or local window, score and ambiguity tests), the look-ahead that verifies the
//! searches of later keyframes in one parallel batch, and the vouches that decide a local
//! search.

use super::GraphOptions;
use super::keyframes::{Keyframe, bounds_around, clip_to_points, gather_points};
use super::optimize::PoseGraph;
use crate::geometry::Pose2;
use crate::matching::point_field::{PointField, SearchWindow};

/// Keyframes due for a loop search verified in one parallel batch, up to the next periodic
/// optimisation: the loop-closure verifications of a keyframe with one candidate left a
/// core idle in the serial parts (branch and bound, refinement), and a small batch leaves
/// one idle at its end (the full-size car: 4 searches a batch, 900 batches; 16, 285).
pub const LOOK_AHEAD_SEARCHES: usize = 16;

/// ... but at most this many when an optimisation may come at any accepted closure (after
/// `optimize.every_keyframes` without one): a look-ahead past it is discarded.
pub(super) const LOOK_AHEAD_UNBOUNDED: usize = 4;

/// One keyframe's loop search verified ahead.
pub(super) struct AheadJob {
    pub(super) k: usize,
    pub(super) pose: Pose2,
    pub(super) tried: Vec<usize>,
    pub(super) verdicts: Vec<Checked>,
}

/// The look-ahead verdicts and the optimisation count they were computed at.
pub(super) struct LookAhead {
    pub(super) generation: usize,
    pub(super) jobs: Vec<AheadJob>,
}

/// The loop searches of the keyframes after `k` (the graph's last pose, `poses` = keyframes
/// `0..=k`) up to keyframe `last` until `look_ahead - 1` of them have candidates, for a
/// graph without sequential matching: each later keyframe's pose follows from the previous
/// one by the front end's motion alone, composed exactly as
/// `optimize_trajectory_look_ahead` does, so until the next optimisation these are the bits
/// it will find. Returns the jobs (verdicts empty); `poses` is extended to the last
/// keyframe looked at.
pub(super) fn look_ahead_jobs(
    keyframes: &[Keyframe],
    poses: &mut Vec<Pose2>,
    k: usize,
    look_ahead: usize,
    last: usize,
    opts: &GraphOptions,
) -> Vec<AheadJob> {
    let mut jobs = Vec::new();
    let mut p = poses[k];
    let mut searches = 1;
    for m in k + 1..keyframes.len().min(last.saturating_add(1)) {
        if searches >= look_ahead {
            break;
        }
        let rel = keyframes[m - 1]
            .front_pose
            .between(&keyframes[m].front_pose);
        p = p.compose(&rel);
        poses.push(p);
        if m % opts.loops.every_keyframes == 0 && keyframes[m].points_body.len() >= opts.min_points
        {
            let tried = loop_candidates(keyframes, poses, m, &p, opts);
            searches += usize::from(!tried.is_empty());
            jobs.push(AheadJob {
                k: m,
                pose: p,
                tried,
                verdicts: Vec::new(),
            });
        }
    }
    jobs
}

/// The loop-closure candidates of keyframe `k` at `pose`: earlier keyframes (at `poses`)
/// within `loops.search_radius_m` and at least `loops.min_path_m` back along the path, the
/// nearest first, at most `loops.max_candidates`, no two within `loops.submap_keyframes`.
pub(super) fn loop_candidates(
    keyframes: &[Keyframe],
    poses: &[Pose2],
    k: usize,
    pose: &Pose2,
    opts: &GraphOptions,
) -> Vec<usize> {
    let path_m = keyframes[k].path_m;
    let radius = opts.loops.search_radius_m;
    let near = pose.x_m.abs() + pose.y_m.abs() + radius + 1.0;
    let mut cands: Vec<(f64, usize)> = (0..k)
        .filter(|&j| path_m - keyframes[j].path_m >= opts.loops.min_path_m)
        .filter_map(|j| {
            let q = &poses[j];
            // The distance is `between`'s (its rounding decides ties and the radius), but
            // only worth computing (a `sin_cos` and a `hypot`) near the radius: the plain
            // difference differs from it by rounding alone (~1e-15 of the coordinates),
            // far inside this margin. NaN never skips.
            let (dx, dy) = (pose.x_m - q.x_m, pose.y_m - q.y_m);
            let reach = radius + 1e-9 * (near + q.x_m.abs() + q.y_m.abs());
            if dx * dx + dy * dy > reach * reach {
                return None;
            }
            let d = q.between(pose).translation_norm_m();
            (d <= radius).then_some((d, j))
        })
        .collect();
    cands.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut tried: Vec<usize> = Vec::new();
    for &(_, j) in &cands {
        if tried.len() >= opts.loops.max_candidates {
            break;
        }
        // Candidates next to one already tried would test the same submap.
        if tried
            .iter()
            .any(|&t| t.abs_diff(j) <= opts.loops.submap_keyframes)
        {
            continue;
        }
        tried.push(j);
    }
    tried
}

/// Which windows a loop candidate was searched in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Search {
    /// The full window (`loop_window_*`).
    Full,
    /// The local window (`loop_local_window_*`).
    Local,
    /// The local window, then the full one (the best pose on the local window's edge, or
    /// too low a score).
    LocalThenFull,
}

/// A candidate's verdict and where it was searched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Checked {
    pub(super) verdict: Verdict,
    pub(super) search: Search,
}

/// What the last optimisation vouches for: the loop edges it left consistent (whitened
/// squared error at most `optimize.chi2`), by the path lengths at their ends (see
/// `[graph.loops.local] search`).
#[derive(Debug, Clone)]
pub(super) struct Vouches {
    /// Path length (m) at the later end of the last consistent loop edge.
    last_path_m: f64,
    /// Path lengths (m) at both ends of every consistent loop edge, sorted (empty when
    /// fewer than `loops.local.min_closures`: no vouch).
    ends_path_m: Vec<f64>,
}

impl Default for Vouches {
    fn default() -> Self {
        Vouches {
            last_path_m: f64::NEG_INFINITY,
            ends_path_m: Vec::new(),
        }
    }
}

impl Vouches {
    /// After an optimisation of `graph`, whose loop edges are `graph.edges[loop_edges]`.
    pub(super) fn after_optimisation(
        graph: &PoseGraph,
        loop_edges: &[usize],
        keyframes: &[Keyframe],
        opts: &GraphOptions,
    ) -> Vouches {
        let mut out = Vouches::default();
        for &e in loop_edges {
            if graph.edge_chi2(e) > opts.optimize.chi2 {
                continue;
            }
            let edge = &graph.edges[e];
            let (a, b) = (keyframes[edge.from].path_m, keyframes[edge.to].path_m);
            out.last_path_m = out.last_path_m.max(a.max(b));
            out.ends_path_m.extend([a, b]);
        }
        if out.ends_path_m.len() < 2 * opts.loops.local.min_closures {
            return Vouches::default();
        }
        out.ends_path_m.sort_by(f64::total_cmp);
        out
    }

    /// Whether candidate `j` of keyframe `k` is searched in the local window: a consistent
    /// loop edge ends at most `loops.local.vouch_path_m` before `k`, and one within that
    /// much of `j` (none vouches below `loops.local.min_closures`).
    pub(super) fn vouch(
        &self,
        keyframes: &[Keyframe],
        k: usize,
        j: usize,
        opts: &GraphOptions,
    ) -> bool {
        let d = opts.loops.local.vouch_path_m;
        let (pk, pj) = (keyframes[k].path_m, keyframes[j].path_m);
        if pk - self.last_path_m > d {
            return false;
        }
        let at = self.ends_path_m.partition_point(|&p| p < pj - d);
        self.ends_path_m.get(at).is_some_and(|&p| p <= pj + d)
    }
}

/// A loop closure to verify: a keyframe, at a pose, against the submap around a candidate.
#[derive(Clone, Copy)]
pub(super) struct ClosurePair<'a> {
    /// The keyframe's index.
    pub(super) keyframe: usize,
    /// The candidate keyframe's index (before `keyframe`).
    pub(super) candidate: usize,
    /// The keyframe's pose in the world.
    pub(super) pose: &'a Pose2,
}

/// Verifies keyframe `k` (at `pose`) against the submap around candidate `j` (keyframes at
/// `poses`, only those before `k`): in `local` when given, and in `loop_win` when not or
/// when the local search's best pose lies on its edge or scores too low.
pub(super) fn verify_candidate(
    keyframes: &[Keyframe],
    poses: &[Pose2],
    pair: &ClosurePair<'_>,
    loop_win: &SearchWindow,
    local: Option<&SearchWindow>,
    opts: &GraphOptions,
) -> Checked {
    let ClosurePair {
        keyframe: k,
        candidate: j,
        pose,
    } = *pair;
    let kf = &keyframes[k];
    let lo = j.saturating_sub(opts.loops.submap_keyframes);
    let hi = (j + opts.loops.submap_keyframes + 1).min(k);
    let mut submap = Vec::new();
    gather_points(keyframes, poses, lo..hi, &mut submap);
    // The local window's search is small beside building a pooled level: one level fewer
    // (+-0.3 m: 2 levels, 4 x 4 top-level nodes per yaw).
    let in_window = |win: &SearchWindow, ambiguity_radius_m: f64, edge_stops: bool| {
        let levels = match edge_stops {
            true => levels_for(win.xy_m, opts.resolution_m).saturating_sub(1),
            false => levels_for(win.xy_m, opts.resolution_m),
        };
        let margin = win.xy_m + 3.0 * opts.field_sigma_m + opts.resolution_m;
        let Some((blo, bhi)) = bounds_around(&kf.points_body, pose, margin)
            .and_then(|b| clip_to_points(b, &submap, 3.0 * opts.field_sigma_m))
        else {
            return Some(Verdict::LowScore);
        };
        let field = PointField::build(
            &submap,
            blo,
            bhi,
            opts.resolution_m,
            opts.field_sigma_m,
            levels,
        );
        let points = &kf.points_body;
        verify_closure_in(
            &field,
            points,
            pose,
            win,
            ambiguity_radius_m,
            edge_stops,
            opts,
        )
    };
    let mut search = Search::Full;
    if let Some(win) = local {
        match in_window(win, opts.loops.local.ambiguity_radius_m, true) {
            None | Some(Verdict::LowScore) => search = Search::LocalThenFull,
            Some(verdict) => {
                return Checked {
                    verdict,
                    search: Search::Local,
                };
            }
        }
    }
    let verdict = in_window(loop_win, opts.loops.ambiguity_radius_m, false);
    Checked {
        verdict: verdict.unwrap_or(Verdict::LowScore),
        search,
    }
}

/// The outcome of a loop-closure verification.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// The matched pose of the scan (world frame of the submap).
    Accepted(Pose2),
    /// Best score below `loops.min_score` (or too few points).
    LowScore,
    /// Another pose scores nearly as well.
    Ambiguous,
}

/// Matches `points_body` in `field` over `win` around `centre` and applies the acceptance
/// tests of `opts` (score, ambiguity); refines an accepted match below a cell.
pub fn verify_closure(
    field: &PointField,
    points_body: &[[f64; 2]],
    centre: &Pose2,
    win: &SearchWindow,
    opts: &GraphOptions,
) -> Verdict {
    let radius = opts.loops.ambiguity_radius_m;
    verify_closure_in(field, points_body, centre, win, radius, false, opts)
        .unwrap_or(Verdict::LowScore)
}

/// [`verify_closure`] with the ambiguity radius `ambiguity_radius_m`. With `edge_stops`,
/// `None` when the best pose on the cell grid lies on the window's edge (in x, y or yaw:
/// the best of a larger window may lie beyond it), before the ambiguity test.
pub fn verify_closure_in(
    field: &PointField,
    points_body: &[[f64; 2]],
    centre: &Pose2,
    win: &SearchWindow,
    ambiguity_radius_m: f64,
    edge_stops: bool,
    opts: &GraphOptions,
) -> Option<Verdict> {
    if points_body.len() < opts.min_points {
        return Some(Verdict::LowScore);
    }
    // Both searches start from the same top level: score it once.
    let Some(start) = field.bnb_start(points_body, centre, win) else {
        return Some(Verdict::LowScore);
    };
    let Some((best, score)) = field.search_bnb_from(&start, opts.loops.min_score, None) else {
        return Some(Verdict::LowScore);
    };
    if edge_stops && field.on_window_edge(&start, &best) {
        return None;
    }
    let exclusion = (best, ambiguity_radius_m, win.yaw_rad * 2.0 + 1.0);
    if field.any_bnb_from(&start, opts.loops.ambiguity_ratio * score, Some(exclusion)) {
        return Some(Verdict::Ambiguous);
    }
    let (pose, _) = field.refine(points_body, &best, win.yaw_step_rad, 4, None);
    Some(Verdict::Accepted(pose))
}

/// Pooled levels of a branch-and-bound field for a window of half-width `window_m`: the
/// fewest whose top level's blocks (`2^levels` cells) are as wide as the half-width, at
/// most 6. The search's top level then has 2 x 2 nodes per yaw (+-1.5 m at 0.05 m: 5
/// levels); with 3 levels (the top level an eighth of the window, before) it had 8 x 8, and
/// scoring those was two fifths of the full-size car's back end. The answer is the same
/// for any number of levels (the branch and bound is exact on the cell grid).
fn levels_for(window_m: f64, resolution_m: f64) -> usize {
    let cells = (window_m / resolution_m).ceil().max(1.0);
    (cells.log2().ceil().max(0.0) as usize).min(6)
}
