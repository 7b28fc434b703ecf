//! The back end: loop closure by pose-graph optimisation after any filter mode.
//!
//! 1. Keyframes every `keyframe_distance_m` / `keyframe_angle_deg` of the front end's path.
//! 2. Sequential edges: each keyframe's scan is matched against a submap of the preceding
//!    `submap_keyframes` keyframes (at their current, already corrected estimates) around
//!    the front end's relative motion, with a prior on the deviation from it; a poor front
//!    end still gives good local edges. For a tilted or moving LiDAR (the car) these matches
//!    are biased, so there the front end's relative motion alone ties consecutive keyframes,
//!    with a random-walk uncertainty (`sequential_matching`).
//! 3. Loop closures: earlier keyframes within `loop_search_radius_m` of the new keyframe's
//!    estimate but at least `loop_min_path_m` back along the path are candidates; the scan
//!    is matched by branch and bound over a window of `loop_window_m` / `loop_window_deg`
//!    against the candidate's neighbourhood submap, refined below a cell, and accepted only
//!    if the score is high, enough points fall on the submap, and no other pose outside
//!    `loop_ambiguity_radius_m` scores nearly as well (a corridor is ambiguous along its
//!    axis). Loop edges carry a Cauchy kernel; after the final optimisation edges with a large
//!    error are dropped and the graph is optimised again.
//! 4. The graph is optimised ([`optimize`]) whenever closures were accepted and at least
//!    `optimize_every_keyframes` keyframes passed, so the next search starts from corrected
//!    estimates, and once more at the end.
//! 5. Every scan's corrected pose = its keyframe's corrected pose composed with the front
//!    end's motion since that keyframe.
//!
//! This file holds the driver; the options are in `options`, keyframes and their submaps in
//! `keyframes`, loop-closure search and verification in `loop_closure`, the refinement of
//! the scans between keyframes in `refine`, the matcher in [`matcher`] and the pose graph
//! in [`optimize`].

pub mod lidar_odometry;
pub mod matcher;
pub mod optimize;

mod keyframes;
mod loop_closure;
mod options;
mod refine;

pub use loop_closure::{LOOK_AHEAD_SEARCHES, Verdict, verify_closure, verify_closure_in};
pub use options::{BackEndInput, GraphOptions, Switch};

use crate::geometry::{Pose2, StampedPose2};
use crate::map::{MapError, ScanOptions};
use crate::sensors::Recording;
use keyframes::{
    Keyframe, bounds_around, clip_to_points, correct_trajectory, gather_points, select_keyframes,
};
use loop_closure::{
    AheadJob, Checked, LOOK_AHEAD_UNBOUNDED, LookAhead, Search, Vouches, look_ahead_jobs,
    loop_candidates, verify_candidate,
};
use matcher::{PointField, Prior, SearchWindow};
use optimize::{Edge, OptimizeOptions, PoseGraph};
use rayon::prelude::*;
use refine::refine_scans;
use serde::Serialize;
use std::time::Instant;

/// Errors of the back end.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// Invalid options (the message names the key).
    #[error("invalid graph options: {0}")]
    Options(String),
    /// Scan preprocessing failed.
    #[error(transparent)]
    Map(#[from] MapError),
}

/// Counts and timings of a back-end run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct GraphStats {
    /// Keyframes (nodes).
    pub nodes: usize,
    /// Edges in the final graph.
    pub edges: usize,
    /// Sequential edges from a scan match.
    pub sequential_matched: usize,
    /// Sequential edges from the front end (match too poor).
    pub sequential_fallback: usize,
    /// Sequential edges from the front end alone (`sequential_matching` off).
    pub sequential_front_end: usize,
    /// Odometry-yaw edges (`odometry_yaw_sigma_deg_per_sqrt_m`).
    pub odometry_yaw_edges: usize,
    /// Loop-closure candidates tried.
    pub loop_candidates: usize,
    /// Closures accepted by the matcher.
    pub loop_accepted: usize,
    /// Candidates rejected: score too low or too few points.
    pub loop_rejected_score: usize,
    /// Candidates rejected as ambiguous.
    pub loop_rejected_ambiguous: usize,
    /// Candidates verified in the local window (`loop_local_search`), those counted again
    /// in `loop_local_fallbacks` included.
    pub loop_local: usize,
    /// ... of which searched again in the full window (best pose on the local window's
    /// edge, or too low a score).
    pub loop_local_fallbacks: usize,
    /// Accepted closures removed as outliers after optimisation.
    pub loop_removed_outliers: usize,
    /// Optimisations run.
    pub optimizations: usize,
    /// Levenberg-Marquardt iterations in all.
    pub iterations: usize,
    /// Robust cost after the final optimisation.
    pub final_cost: f64,
    /// Seconds in scan matching (sequential and loop).
    pub matching_s: f64,
    /// Seconds in optimisation.
    pub optimize_s: f64,
    /// Seconds in the final per-scan refinement.
    pub refine_s: f64,
    /// Seconds in all.
    pub total_s: f64,
}

/// What the back end produced.
#[derive(Debug, Clone)]
pub struct GraphResult {
    /// A corrected pose for every pose of the input trajectory (same stamps).
    pub trajectory: Vec<StampedPose2>,
    /// The corrected keyframe poses.
    pub keyframes: Vec<StampedPose2>,
    /// Index pairs `(from, to)` of the accepted loop closures (keyframe indices).
    pub loop_edges: Vec<(usize, usize)>,
    /// Counts and timings.
    pub stats: GraphStats,
}

/// Runs the back end on `trajectory` (a pose at some scans of `recording`, e.g.
/// [`crate::filter::slam::SlamResult::trajectory`]), using `scan_opts` for preprocessing.
pub fn optimize_trajectory(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
) -> Result<GraphResult, GraphError> {
    optimize_trajectory_look_ahead(recording, scan_opts, trajectory, opts, LOOK_AHEAD_SEARCHES)
}

/// [`optimize_trajectory`] verifying the loop searches of up to `look_ahead` keyframes in
/// one parallel batch (the default [`LOOK_AHEAD_SEARCHES`]; 1 = one keyframe at a time):
/// the same result for any value (tested).
#[doc(hidden)]
pub fn optimize_trajectory_look_ahead(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
    look_ahead: usize,
) -> Result<GraphResult, GraphError> {
    opts.validate().map_err(GraphError::Options)?;
    let t_start = Instant::now();
    let keyframes = select_keyframes(recording, scan_opts, trajectory, opts)?;
    let mut back_end = BackEnd::new(recording, trajectory, opts, &keyframes, look_ahead);
    for k in 0..keyframes.len() {
        back_end.add_keyframe(k);
    }
    back_end.finish(scan_opts, t_start)
}

/// The back end while keyframes are added: the graph so far, and what decides the next loop
/// searches and optimisations.
struct BackEnd<'a> {
    recording: &'a Recording,
    trajectory: &'a [StampedPose2],
    opts: &'a GraphOptions,
    keyframes: &'a [Keyframe],
    look_ahead: usize,
    opt_opts: OptimizeOptions,
    periodic_opts: OptimizeOptions,
    seq_win: SearchWindow,
    loop_win: SearchWindow,
    local_win: SearchWindow,
    local_on: bool,
    seq_matching: bool,
    yaw_edges: bool,
    stats: GraphStats,
    graph: PoseGraph,
    loop_edges: Vec<usize>,
    vouches: Vouches,
    closures_pending: bool,
    urgent: bool,
    last_opt: usize,
    submap_pts: Vec<[f64; 2]>,
    /// Loop searches verified ahead, valid while the graph is not optimised.
    ahead: Option<LookAhead>,
    generation: usize,
}

impl<'a> BackEnd<'a> {
    fn new(
        recording: &'a Recording,
        trajectory: &'a [StampedPose2],
        opts: &'a GraphOptions,
        keyframes: &'a [Keyframe],
        look_ahead: usize,
    ) -> Self {
        let opt_opts = OptimizeOptions {
            max_iterations: opts.max_iterations,
            ..OptimizeOptions::default()
        };
        let periodic_opts = OptimizeOptions {
            relative_tolerance: opts.periodic_relative_tolerance,
            ..opt_opts
        };
        let seq_win = SearchWindow {
            xy_m: opts.sequential_window_m,
            yaw_rad: opts.sequential_window_deg.to_radians(),
            yaw_step_rad: opts.yaw_step_deg.to_radians(),
        };
        let loop_win = SearchWindow {
            xy_m: opts.loop_window_m,
            yaw_rad: opts.loop_window_deg.to_radians(),
            yaw_step_rad: seq_win.yaw_step_rad,
        };
        let local_win = SearchWindow {
            xy_m: opts.loop_local_window_m,
            yaw_rad: opts.loop_local_window_deg.to_radians(),
            yaw_step_rad: seq_win.yaw_step_rad,
        };
        // What the last optimisation vouches for (nothing before the first).
        let local_on = opts.loop_local_search.is_on(false);
        // `auto`: sequential matching for a level LiDAR fixed on the body (the recordings `auto`
        // runs `rbpf` on); odometry-yaw edges for a LiDAR fixed on the body.
        let level_and_fixed =
            crate::filter::FilterMode::Auto.resolve(recording) == crate::filter::FilterMode::Rbpf;
        let seq_matching = opts.sequential_matching.is_on(level_and_fixed);
        let yaw_edges = !seq_matching
            && opts.odometry_yaw_sigma_deg_per_sqrt_m > 0.0
            && opts
                .odometry_yaw_edges
                .is_on(recording.body_from_lidar_per_scan.is_none());
        BackEnd {
            recording,
            trajectory,
            opts,
            keyframes,
            look_ahead,
            opt_opts,
            periodic_opts,
            seq_win,
            loop_win,
            local_win,
            local_on,
            seq_matching,
            yaw_edges,
            stats: GraphStats::default(),
            graph: PoseGraph::default(),
            loop_edges: Vec::new(),
            vouches: Vouches::default(),
            closures_pending: false,
            urgent: false,
            last_opt: 0,
            submap_pts: Vec::new(),
            ahead: None,
            generation: 0,
        }
    }

    /// Adds keyframe `k` (after keyframes `0..k`): its sequential and odometry-yaw edges,
    /// its loop searches when due, and an optimisation when due.
    fn add_keyframe(&mut self, k: usize) {
        let opts = self.opts;
        let kf = &self.keyframes[k];
        if k == 0 {
            self.graph.poses.push(kf.front_pose);
            return;
        }
        let t = Instant::now();
        let pose = self.add_sequential_edges(k);
        // Loop closures.
        let due =
            k.is_multiple_of(opts.loop_every_keyframes) && kf.points_body.len() >= opts.min_points;
        if due {
            self.search_loops(k, pose);
        }
        self.stats.matching_s += t.elapsed().as_secs_f64();
        self.maybe_optimize(k);
    }

    /// Keyframe `k`'s pose and the edges to keyframe `k - 1`: a sequential match (with the
    /// front end's relative motion beside it) or the front end's relative motion alone,
    /// and the odometry-yaw edge. Returns the pose.
    fn add_sequential_edges(&mut self, k: usize) -> Pose2 {
        let opts = self.opts;
        let (keyframes, graph, stats) = (self.keyframes, &mut self.graph, &mut self.stats);
        let seq_matching = self.seq_matching;
        let seq_win = &self.seq_win;
        let kf = &keyframes[k];
        let prev = &keyframes[k - 1];
        let rel_front = prev.front_pose.between(&kf.front_pose);
        let predicted = graph.poses[k - 1].compose(&rel_front);
        // Sequential edge: match against the previous keyframes' submap.
        let first = k.saturating_sub(opts.submap_keyframes);
        gather_points(keyframes, &graph.poses, first..k, &mut self.submap_pts);
        let submap_pts = &self.submap_pts;
        let margin = opts.sequential_window_m + 3.0 * opts.field_sigma_m + opts.resolution_m;
        let bounds = bounds_around(&kf.points_body, &predicted, margin)
            .and_then(|b| clip_to_points(b, submap_pts, 3.0 * opts.field_sigma_m));
        let enough = seq_matching && kf.points_body.len() >= opts.min_points;
        let matched = bounds.filter(|_| enough).and_then(|(lo, hi)| {
            let field =
                PointField::build(submap_pts, lo, hi, opts.resolution_m, opts.field_sigma_m, 0);
            let prior = Prior {
                pose: predicted,
                sigma_xy_m: opts.sequential_prior_sigma_m,
                sigma_yaw_rad: opts.sequential_prior_sigma_deg.to_radians(),
            };
            let coarse = field.search_with_prior(&kf.points_body, &prior, seq_win);
            let (pose, score) = field.refine(
                &kf.points_body,
                &coarse,
                seq_win.yaw_step_rad,
                4,
                Some(&prior),
            );
            (score >= opts.sequential_min_score).then(|| {
                let curv = field.curvature(
                    &kf.points_body,
                    &pose,
                    0.5 * opts.resolution_m,
                    seq_win.yaw_step_rad,
                );
                (pose, curv)
            })
        });
        // The front end's relative motion always constrains the pair (weakly): where the
        // match pins nothing down (along a corridor) it decides. Without sequential matching
        // it is the only edge, with its random-walk uncertainty.
        let (sigma_m, sigma_deg) = match seq_matching {
            true => (opts.fallback_sigma_m, opts.fallback_sigma_deg),
            false => {
                let root = rel_front.translation_norm_m().max(0.01).sqrt();
                (
                    opts.front_end_sigma_m_per_sqrt_m * root,
                    opts.front_end_sigma_deg_per_sqrt_m * root,
                )
            }
        };
        let front_edge =
            Edge::with_sigmas(k - 1, k, rel_front, sigma_m, sigma_deg.to_radians(), None);
        let (pose, edge) = match matched {
            Some((pose, curv)) => {
                stats.sequential_matched += 1;
                let z = graph.poses[k - 1].between(&pose);
                let e = Edge {
                    from: k - 1,
                    to: k,
                    measurement: z,
                    information: capped_information(
                        &curv,
                        pose.yaw_rad,
                        opts.sequential_sigma_m,
                        opts.sequential_sigma_deg.to_radians(),
                    ),
                    robust_width: None,
                };
                graph.edges.push(front_edge);
                (pose, e)
            }
            None if seq_matching => {
                stats.sequential_fallback += 1;
                (predicted, front_edge)
            }
            None => {
                stats.sequential_front_end += 1;
                (predicted, front_edge)
            }
        };
        graph.poses.push(pose);
        graph.edges.push(edge);
        if self.yaw_edges {
            let odo = &self.recording.odometry;
            let trajectory = self.trajectory;
            let stamp = |kf: &Keyframe| trajectory[kf.traj_index].stamp_ns;
            if let (Some(a), Some(b)) = (odo.pose_at(stamp(prev)), odo.pose_at(stamp(kf))) {
                // Yaw only: the x/y standard deviation is far beyond any error.
                let z = a.between(&b);
                let root = z.translation_norm_m().max(0.01).sqrt();
                let sigma_yaw_deg = opts.odometry_yaw_sigma_deg_per_sqrt_m * root;
                graph.edges.push(Edge::with_sigmas(
                    k - 1,
                    k,
                    z,
                    1e3,
                    sigma_yaw_deg.to_radians(),
                    None,
                ));
                stats.odometry_yaw_edges += 1;
            }
        }
        pose
    }

    /// The loop searches of keyframe `k` at `pose`: its candidates verified (or taken from
    /// the look-ahead), the accepted closures added as loop edges.
    fn search_loops(&mut self, k: usize, pose: Pose2) {
        let (tried, verdicts) = self.loop_verdicts(k, pose);
        let opts = self.opts;
        let (graph, stats) = (&mut self.graph, &mut self.stats);
        stats.loop_candidates += tried.len();
        for (&j, checked) in tried.iter().zip(verdicts) {
            stats.loop_local += usize::from(checked.search != Search::Full);
            stats.loop_local_fallbacks += usize::from(checked.search == Search::LocalThenFull);
            match checked.verdict {
                Verdict::Accepted(found) => {
                    stats.loop_accepted += 1;
                    let z = graph.poses[j].between(&found);
                    let width = (opts.loop_kernel_width > 0.0).then_some(opts.loop_kernel_width);
                    graph.edges.push(Edge::with_sigmas(
                        j,
                        k,
                        z,
                        opts.loop_sigma_m,
                        opts.loop_sigma_deg.to_radians(),
                        width,
                    ));
                    self.loop_edges.push(graph.edges.len() - 1);
                    self.closures_pending = true;
                    if graph.edge_chi2(graph.edges.len() - 1) > opts.optimize_chi2 {
                        self.urgent = true;
                    }
                }
                Verdict::LowScore => stats.loop_rejected_score += 1,
                Verdict::Ambiguous => stats.loop_rejected_ambiguous += 1,
            }
        }
    }

    /// Keyframe `k`'s loop candidates and their verdicts: from the look-ahead when it holds
    /// them, else verified now in one parallel batch with the look-ahead's next jobs.
    fn loop_verdicts(&mut self, k: usize, pose: Pose2) -> (Vec<usize>, Vec<Checked>) {
        let opts = self.opts;
        let keyframes = self.keyframes;
        let generation = self.generation;
        let graph = &mut self.graph;
        // A look-ahead job computed before any optimisation since, at the same pose:
        // the same candidates (the earlier keyframes' poses are the same bits).
        let cached = match &mut self.ahead {
            Some(a) if a.generation == generation => a
                .jobs
                .iter()
                .position(|j| j.k == k && j.pose == pose)
                .map(|at| a.jobs.swap_remove(at)),
            _ => None,
        };
        match cached {
            Some(job) => (job.tried, job.verdicts),
            None => {
                let tried = loop_candidates(keyframes, &graph.poses, k, &pose, opts);
                if tried.is_empty() {
                    (tried, Vec::new())
                } else {
                    // The look-ahead's predicted poses go onto the graph's (removed
                    // after the batch): no copy of the whole path per batch.
                    let look_ahead = self.look_ahead;
                    let mut jobs = if !self.seq_matching && look_ahead > 1 {
                        // No periodic optimisation before `last_opt + every`: up to
                        // there the look-ahead cannot be overtaken by one.
                        let bound = self.last_opt + opts.optimize_every_keyframes;
                        let (searches, last) = if k < bound {
                            (look_ahead, bound)
                        } else {
                            (look_ahead.min(LOOK_AHEAD_UNBOUNDED), usize::MAX)
                        };
                        look_ahead_jobs(keyframes, &mut graph.poses, k, searches, last, opts)
                    } else {
                        Vec::new()
                    };
                    jobs.insert(
                        0,
                        AheadJob {
                            k,
                            pose,
                            tried: tried.clone(),
                            verdicts: Vec::new(),
                        },
                    );
                    let poses: &[Pose2] = &graph.poses;
                    // All independent: verified in parallel, collected in order.
                    let pairs: Vec<(usize, usize)> = jobs
                        .iter()
                        .enumerate()
                        .flat_map(|(a, job)| job.tried.iter().map(move |&j| (a, j)))
                        .collect();
                    // Whether a candidate is searched locally depends only on the last
                    // optimisation, which the look-ahead's verdicts are valid for.
                    let vouches = &self.vouches;
                    let (local_on, loop_win, local_win) =
                        (self.local_on, &self.loop_win, &self.local_win);
                    let found: Vec<Checked> = pairs
                        .par_iter()
                        .map(|&(a, j)| {
                            let job = &jobs[a];
                            let local = (local_on && vouches.vouch(keyframes, job.k, j, opts))
                                .then_some(local_win);
                            verify_candidate(
                                keyframes, poses, job.k, j, &job.pose, loop_win, local, opts,
                            )
                        })
                        .collect();
                    for (&(a, _), v) in pairs.iter().zip(found) {
                        jobs[a].verdicts.push(v);
                    }
                    graph.poses.truncate(k + 1);
                    let own = jobs.swap_remove(0).verdicts;
                    self.ahead = Some(LookAhead { generation, jobs });
                    (tried, own)
                }
            }
        }
    }

    /// Optimises after keyframe `k` when a closure disagreed with the estimates, or when
    /// closures were accepted and `optimize_every_keyframes` passed since the last time.
    fn maybe_optimize(&mut self, k: usize) {
        let opts = self.opts;
        if self.urgent
            || (self.closures_pending && k - self.last_opt >= opts.optimize_every_keyframes)
        {
            let t = Instant::now();
            let last_opt = self.last_opt;
            let graph = &mut self.graph;
            let r = match self.urgent {
                true => graph.optimize(&self.opt_opts),
                // Keyframe 0 is always held: from keyframe 1 on is the whole graph.
                false
                    if opts.periodic_free_keyframes > 0
                        && last_opt > opts.periodic_free_keyframes + 1 =>
                {
                    let first = last_opt - opts.periodic_free_keyframes;
                    optimize_tail(graph, first, &self.periodic_opts)
                }
                false => graph.optimize(&self.periodic_opts),
            };
            self.generation += 1;
            if self.local_on {
                self.vouches = Vouches::after_optimisation(
                    &self.graph,
                    &self.loop_edges,
                    self.keyframes,
                    opts,
                );
            }
            self.stats.optimizations += 1;
            self.stats.iterations += r.iterations;
            self.stats.optimize_s += t.elapsed().as_secs_f64();
            self.closures_pending = false;
            self.urgent = false;
            self.last_opt = k;
        }
    }

    /// The final optimisation, outlier removal and again; every scan's corrected pose
    /// (refined when `refine_scans` is on).
    fn finish(self, scan_opts: &ScanOptions, t_start: Instant) -> Result<GraphResult, GraphError> {
        let BackEnd {
            recording,
            trajectory,
            opts,
            keyframes,
            opt_opts,
            mut stats,
            mut graph,
            loop_edges,
            ..
        } = self;
        // Final optimisation, outlier removal, again.
        let t = Instant::now();
        let r = graph.optimize(&opt_opts);
        stats.optimizations += 1;
        stats.iterations += r.iterations;
        let outliers: Vec<usize> = loop_edges
            .iter()
            .copied()
            .filter(|&e| graph.edge_chi2(e) > opts.loop_outlier_chi2)
            .collect();
        if !outliers.is_empty() {
            stats.loop_removed_outliers = outliers.len();
            let mut keep = vec![true; graph.edges.len()];
            for &e in &outliers {
                keep[e] = false;
            }
            let mut idx = 0;
            graph.edges.retain(|_| {
                idx += 1;
                keep[idx - 1]
            });
            let r = graph.optimize(&opt_opts);
            stats.optimizations += 1;
            stats.iterations += r.iterations;
        }
        stats.final_cost = graph.cost();
        stats.optimize_s += t.elapsed().as_secs_f64();
        stats.nodes = graph.poses.len();
        stats.edges = graph.edges.len();
        let loop_pairs = graph
            .edges
            .iter()
            .filter(|e| e.to != e.from + 1)
            .map(|e| (e.from, e.to))
            .collect();
        let t = Instant::now();
        let closed = stats.loop_accepted > stats.loop_removed_outliers;
        if !closed && opts.keep_front_end_without_closures {
            graph.poses = keyframes.iter().map(|kf| kf.front_pose).collect();
        }
        let mut out = correct_trajectory(trajectory, keyframes, &graph.poses);
        if opts.refine_scans.is_on(true) && (closed || !opts.keep_front_end_without_closures) {
            refine_scans(
                recording,
                scan_opts,
                trajectory,
                keyframes,
                &graph.poses,
                opts,
                &mut out,
            )?;
        }
        stats.refine_s = t.elapsed().as_secs_f64();
        let kf_out = keyframes
            .iter()
            .zip(&graph.poses)
            .map(|(kf, p)| StampedPose2 {
                stamp_ns: trajectory[kf.traj_index].stamp_ns,
                pose: *p,
            })
            .collect();
        stats.total_s = t_start.elapsed().as_secs_f64();
        Ok(GraphResult {
            trajectory: out,
            keyframes: kf_out,
            loop_edges: loop_pairs,
            stats,
        })
    }
}

/// Optimises keyframes `first..` of `graph` (`first >= 1`) with the earlier ones held
/// fixed: a graph of those keyframes behind a fixed origin, each edge from a fixed keyframe
/// re-anchored at the origin (its measurement composed with the fixed pose: the same
/// error), edges between fixed keyframes left out (their error cannot change). Every edge
/// here runs from an earlier keyframe to a later one; should one run backwards into the
/// fixed part, the whole graph is optimised instead.
fn optimize_tail(
    graph: &mut PoseGraph,
    first: usize,
    opts: &OptimizeOptions,
) -> optimize::OptimizeReport {
    if first >= graph.poses.len() || graph.edges.iter().any(|e| e.from >= first && e.to < first) {
        return graph.optimize(opts);
    }
    let mut tail = PoseGraph {
        poses: Vec::with_capacity(graph.poses.len() - first + 1),
        edges: Vec::new(),
    };
    tail.poses.push(Pose2::IDENTITY);
    tail.poses.extend_from_slice(&graph.poses[first..]);
    let at = |v: usize| v + 1 - first;
    for e in graph.edges.iter().filter(|e| e.to >= first) {
        tail.edges.push(match e.from >= first {
            true => Edge {
                from: at(e.from),
                to: at(e.to),
                ..*e
            },
            false => Edge {
                from: 0,
                to: at(e.to),
                measurement: graph.poses[e.from].compose(&e.measurement),
                ..*e
            },
        });
    }
    let r = tail.optimize(opts);
    graph.poses[first..].copy_from_slice(&tail.poses[1..]);
    r
}

/// The information of a match edge: the match's curvature (world x, y, yaw) in the edge's
/// error frame (rotated into the matched pose's frame), its eigenvalues capped, after
/// whitening by `sigma_xy_m` / `sigma_yaw_rad`, at 1 (no direction more certain than those
/// standard deviations) and floored at 0.
fn capped_information(
    curvature_world: &nalgebra::Matrix3<f64>,
    yaw_rad: f64,
    sigma_xy_m: f64,
    sigma_yaw_rad: f64,
) -> nalgebra::Matrix3<f64> {
    let (s, c) = yaw_rad.sin_cos();
    let r = nalgebra::Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let local = r.transpose() * curvature_world * r;
    let w = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(
        sigma_xy_m,
        sigma_xy_m,
        sigma_yaw_rad,
    ));
    let m = w * local * w;
    let m = (m + m.transpose()) * 0.5;
    let eig = m.symmetric_eigen();
    let capped = eig.eigenvalues.map(|v| v.clamp(0.0, 1.0));
    let m =
        eig.eigenvectors * nalgebra::Matrix3::from_diagonal(&capped) * eig.eigenvectors.transpose();
    let winv = w.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
    winv * m * winv
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// A 400-node lawnmower path: noisy odometry edges and loop edges from every 10th node
    /// of each later lane to the node beside it on the earlier lane; node 0 at the origin.
    fn lanes() -> PoseGraph {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let truth: Vec<Pose2> = (0..400)
            .map(|i| {
                let (lane, t) = (i / 50, (i % 50) as f64);
                let x = if lane % 2 == 0 { t } else { 49.0 - t };
                let yaw = if lane % 2 == 0 {
                    0.0
                } else {
                    std::f64::consts::PI
                };
                Pose2::new(x, 2.0 * lane as f64, yaw)
            })
            .collect();
        let mut g = PoseGraph::default();
        let mut noise = |s: f64| s * (rng.random::<f64>() - 0.5);
        for i in 0..truth.len() {
            g.poses.push(match i {
                0 => truth[0],
                _ => {
                    let z = truth[i - 1].between(&truth[i]);
                    let z = Pose2::new(
                        z.x_m + noise(0.05),
                        z.y_m + noise(0.05),
                        z.yaw_rad + noise(0.01),
                    );
                    g.edges
                        .push(Edge::with_sigmas(i - 1, i, z, 0.02, 0.005, None));
                    g.poses[i - 1].compose(&z)
                }
            });
        }
        for i in (60..400).step_by(10) {
            let (lane, t) = (i / 50, i % 50);
            let j = (lane - 1) * 50 + 49 - t;
            let z = truth[j].between(&truth[i]);
            g.edges
                .push(Edge::with_sigmas(j, i, z, 0.05, 0.02, Some(3.0)));
        }
        g
    }

    /// `optimize_tail`: from node 1 on (node 0 at the origin) the bits of `optimize`; from a
    /// later node, the earlier ones keep their bits and the rest is the optimum with them
    /// pinned (here: pinned by stiff edges from the origin instead).
    #[test]
    fn tail_optimisation_holds_the_head_fixed() {
        let opts = OptimizeOptions::default();
        let (mut a, mut b) = (lanes(), lanes());
        a.optimize(&opts);
        optimize_tail(&mut b, 1, &opts);
        assert_eq!(a.poses, b.poses);
        let first = 230;
        let mut tail = lanes();
        let before = tail.cost();
        optimize_tail(&mut tail, first, &opts);
        assert_eq!(tail.poses[..first], lanes().poses[..first]);
        assert!(tail.cost() < 0.7 * before, "{} -> {}", before, tail.cost());
        let mut pinned = lanes();
        for v in 1..first {
            let e = Edge::with_sigmas(0, v, pinned.poses[v], 1e-9, 1e-9, None);
            pinned.edges.push(e);
        }
        pinned.optimize(&opts);
        for (p, q) in tail.poses.iter().zip(&pinned.poses).skip(first) {
            assert!(p.between(q).translation_norm_m() < 1e-4, "{p:?} {q:?}");
            assert!(wrap_angle_abs(p.yaw_rad - q.yaw_rad) < 1e-5, "{p:?} {q:?}");
        }
    }

    fn wrap_angle_abs(a: f64) -> f64 {
        crate::geometry::wrap_angle(a).abs()
    }
}
