//! The refinement of the scans between keyframes against the corrected keyframes around
//! them (`graph refine.scans`).

use super::keyframes::{Keyframe, ScanPoints, bounds_around, clip_to_points, gather_points};
use super::{GraphError, GraphOptions};
use crate::geometry::{Pose2, StampedPose2};
use crate::map::ScanOptions;
use crate::matching::point_field::{PointField, Prior, SearchWindow};
use crate::sensors::Recording;
use rayon::prelude::*;

/// Matches every non-keyframe pose of `out` (already moved with its keyframe) against the
/// corrected keyframes around its keyframe (see `graph refine.scans`).
pub(super) fn refine_scans(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    keyframes: &[Keyframe],
    corrected: &[Pose2],
    opts: &GraphOptions,
    out: &mut [StampedPose2],
) -> Result<(), GraphError> {
    let pts = ScanPoints::new(recording, scan_opts, opts)?;
    let half = opts.sequential.submap_keyframes.div_ceil(2);
    let win = SearchWindow {
        xy_m: opts.refine.window_m,
        yaw_rad: opts.refine.window_deg.to_radians(),
        yaw_step_rad: opts.yaw_step_deg.to_radians(),
    };
    let current: &[StampedPose2] = out;
    // Keyframes are independent here: in parallel, each worker with its own projector.
    let moved: Vec<Result<Vec<(usize, Pose2)>, GraphError>> = (0..keyframes.len())
        .into_par_iter()
        .map_init(
            || (pts.clone(), Vec::new()),
            |(pts, submap), k| {
                let kf = &keyframes[k];
                let end = keyframes
                    .get(k + 1)
                    .map_or(trajectory.len(), |n| n.traj_index);
                let mut found = Vec::new();
                if end <= kf.traj_index + 1 {
                    return Ok(found);
                }
                let range = k.saturating_sub(half)..(k + half + 1).min(keyframes.len());
                gather_points(keyframes, corrected, range, submap);
                // The scans until the next keyframe stay within a keyframe step of this one.
                let margin = opts.keyframe_distance_m + win.xy_m + 3.0 * opts.field_sigma_m + 0.5;
                let Some((lo, hi)) = bounds_around(&kf.points_body, &corrected[k], margin)
                    .and_then(|b| clip_to_points(b, submap, 3.0 * opts.field_sigma_m))
                else {
                    return Ok(found);
                };
                let field =
                    PointField::build(submap, lo, hi, opts.resolution_m, opts.field_sigma_m, 0);
                for t in kf.traj_index + 1..end {
                    let body = pts.at_stamp(trajectory[t].stamp_ns)?;
                    if body.len() < opts.min_points {
                        continue;
                    }
                    let prior = Prior {
                        pose: current[t].pose,
                        sigma_xy_m: opts.sequential.prior_sigma_m,
                        sigma_yaw_rad: opts.sequential.prior_sigma_deg.to_radians(),
                    };
                    let coarse = field.search_with_prior(&body, &prior, &win);
                    let (pose, score) =
                        field.refine(&body, &coarse, win.yaw_step_rad, 4, Some(&prior));
                    if score >= opts.sequential.min_score {
                        found.push((t, pose));
                    }
                }
                Ok(found)
            },
        )
        .collect();
    for m in moved {
        for (t, pose) in m? {
            out[t].pose = pose;
        }
    }
    Ok(())
}
