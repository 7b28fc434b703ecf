//! The back end: loop closure by pose-graph optimisation after any filter mode.
//!
//! 1. Keyframes every `keyframe_distance_m` / `keyframe_angle_deg` of the front end's path.
//! 2. Sequential edges: each keyframe's scan is matched against a submap of the preceding
//!    `sequential.submap_keyframes` keyframes (at their current, already corrected estimates) around
//!    the front end's relative motion, with a prior on the deviation from it; a poor front
//!    end still gives good local edges. For a tilted or moving LiDAR (the car) these matches
//!    are biased, so there the front end's relative motion alone ties consecutive keyframes,
//!    with a random-walk uncertainty (`sequential.matching`).
//! 3. Loop closures: earlier keyframes within `loops.search_radius_m` of the new keyframe's
//!    estimate but at least `loops.min_path_m` back along the path are candidates; the scan
//!    is matched by branch and bound over a window of `loops.window_m` / `loops.window_deg`
//!    against the candidate's neighbourhood submap, refined below a cell, and accepted only
//!    if the score is high, enough points fall on the submap, and no other pose outside
//!    `loops.ambiguity_radius_m` scores nearly as well (a corridor is ambiguous along its
//!    axis). Loop edges carry a Cauchy kernel; after the final optimisation edges with a large
//!    error are dropped and the graph is optimised again.
//! 4. The graph is optimised ([`optimize`]) whenever closures were accepted and at least
//!    `optimize.every_keyframes` keyframes passed, so the next search starts from corrected
//!    estimates, and once more at the end.
//! 5. Every scan's corrected pose = its keyframe's corrected pose composed with the front
//!    end's motion since that keyframe.
//!
//! This file holds the entry points and the driver's state; the driver's steps are in
//! `back_end` (keyframes added, optimisations, the final result), `sequential` (the edges
//! to the previous keyframe) and `loop_search` (the loop searches of a keyframe). The
//! options are in `options`, keyframes and their submaps in `keyframes`, loop-closure search
//! and verification in `loop_closure`, the refinement of the scans between keyframes in
//! `refine`, and the pose graph in [`optimize`]. The scan-to-submap matcher is
//! [`crate::matching::point_field`].

pub mod lidar_odometry;
pub mod optimize;

mod back_end;
mod keyframes;
mod loop_closure;
mod loop_search;
mod options;
mod refine;
mod sequential;

pub use loop_closure::{LOOK_AHEAD_SEARCHES, Verdict, verify_closure, verify_closure_in};
pub use options::{BackEndInput, GraphOptions, Switch};

use crate::geometry::{Pose2, StampedPose2};
use crate::map::{MapError, ScanOptions};
use crate::matching::point_field::{PointField, Prior, SearchWindow};
use crate::sensors::Recording;
use keyframes::{
    Keyframe, bounds_around, clip_to_points, correct_trajectory, gather_points, select_keyframes,
};
use loop_closure::{
    AheadJob, Checked, ClosurePair, LOOK_AHEAD_UNBOUNDED, LookAhead, Search, Vouches,
    look_ahead_jobs, loop_candidates, verify_candidate,
};
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
    /// Sequential edges from the front end alone (`sequential.matching` off).
    pub sequential_front_end: usize,
    /// Odometry-yaw edges (`sequential.odometry_yaw_sigma_deg_per_sqrt_m`).
    pub odometry_yaw_edges: usize,
    /// Loop-closure candidates tried.
    pub loop_candidates: usize,
    /// Closures accepted by the matcher.
    pub loop_accepted: usize,
    /// Candidates rejected: score too low or too few points.
    pub loop_rejected_score: usize,
    /// Candidates rejected as ambiguous.
    pub loop_rejected_ambiguous: usize,
    /// Candidates verified in the local window (`loops.local.search`), those counted again
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
/// [`crate::slam::SlamResult::trajectory`]), using `scan_opts` for preprocessing.
pub fn optimize_trajectory(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
) -> Result<GraphResult, GraphError> {
    optimize_trajectory_look_ahead(recording, scan_opts, trajectory, opts, LOOK_AHEAD_SEARCHES)
}

/// [`optimize_trajectory`] where the first `saved` poses of `trajectory` are a saved
/// session's keyframes: their relative poses are kept as stiff edges instead of being
/// matched in sequence; loops are searched among all keyframes, old and new.
pub fn optimize_after_saved(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
    saved: usize,
) -> Result<GraphResult, GraphError> {
    let look_ahead = LOOK_AHEAD_SEARCHES;
    run_back_end(recording, scan_opts, trajectory, opts, look_ahead, saved)
}

/// The back end over `trajectory`, its first `saved` poses a saved session's keyframes.
fn run_back_end(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
    look_ahead: usize,
    saved: usize,
) -> Result<GraphResult, GraphError> {
    opts.validate().map_err(GraphError::Options)?;
    let t_start = Instant::now();
    let keyframes = select_keyframes(recording, scan_opts, trajectory, opts)?;
    let mut back_end = BackEnd::new(recording, trajectory, opts, &keyframes, look_ahead);
    back_end.saved_prefix = saved;
    for k in 0..keyframes.len() {
        back_end.add_keyframe(k);
    }
    back_end.finish(scan_opts, t_start)
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
    run_back_end(recording, scan_opts, trajectory, opts, look_ahead, 0)
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
    /// Input poses before this index are a saved session's keyframes.
    saved_prefix: usize,
}

#[cfg(test)]
mod tests;
