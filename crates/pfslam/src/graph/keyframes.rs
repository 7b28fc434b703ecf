//! Keyframes: their selection along the input trajectory and their matching points, the
//! submaps gathered from them, and every input pose moved with its keyframe.

use super::{GraphError, GraphOptions};
use crate::geometry::{Pose2, StampedPose2};
use crate::map::{PlanarScan, ScanOptions, ScanProjector};
use crate::sensors::Recording;

/// One keyframe: its input-trajectory index, front-end pose and matching points.
pub(super) struct Keyframe {
    pub(super) traj_index: usize,
    pub(super) front_pose: Pose2,
    pub(super) points_body: Vec<[f64; 2]>,
    pub(super) path_m: f64,
}

/// The world-frame bounding box of `points_body` seen from `pose`, grown by `margin_m`.
pub(super) fn bounds_around(
    points_body: &[[f64; 2]],
    pose: &Pose2,
    margin_m: f64,
) -> Option<([f64; 2], [f64; 2])> {
    if points_body.is_empty() {
        return None;
    }
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in points_body {
        let (x, y) = pose.transform_point(p[0], p[1]);
        lo = [lo[0].min(x), lo[1].min(y)];
        hi = [hi[0].max(x), hi[1].max(y)];
    }
    Some((
        [lo[0] - margin_m, lo[1] - margin_m],
        [hi[0] + margin_m, hi[1] + margin_m],
    ))
}

/// `bounds` cut to the bounding box of `points` grown by `margin_m`; `None` if they do not
/// overlap.
pub(super) fn clip_to_points(
    bounds: ([f64; 2], [f64; 2]),
    points: &[[f64; 2]],
    margin_m: f64,
) -> Option<([f64; 2], [f64; 2])> {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    let lo = [
        bounds.0[0].max(lo[0] - margin_m),
        bounds.0[1].max(lo[1] - margin_m),
    ];
    let hi = [
        bounds.1[0].min(hi[0] + margin_m),
        bounds.1[1].min(hi[1] + margin_m),
    ];
    (lo[0] < hi[0] && lo[1] < hi[1]).then_some((lo, hi))
}

/// World-frame points of keyframes `range` at `poses` into `out`.
pub(super) fn gather_points(
    keyframes: &[Keyframe],
    poses: &[Pose2],
    range: std::ops::Range<usize>,
    out: &mut Vec<[f64; 2]>,
) {
    out.clear();
    for j in range {
        let p = &poses[j];
        out.extend(keyframes[j].points_body.iter().map(|q| {
            let (x, y) = p.transform_point(q[0], q[1]);
            [x, y]
        }));
    }
}

/// Keyframes along `trajectory` with their matching points.
pub(super) fn select_keyframes(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
) -> Result<Vec<Keyframe>, GraphError> {
    let mut pts = ScanPoints::new(recording, scan_opts, opts)?;
    let mut out: Vec<Keyframe> = Vec::new();
    let mut path_m = 0.0;
    let mut last_pose: Option<Pose2> = None;
    let mut last_kf: Option<Pose2> = None;
    for (t, sp) in trajectory.iter().enumerate() {
        if let Some(lp) = last_pose {
            path_m += lp.between(&sp.pose).translation_norm_m();
        }
        last_pose = Some(sp.pose);
        let due = match last_kf {
            None => true,
            Some(kp) => {
                let d = kp.between(&sp.pose);
                d.translation_norm_m() >= opts.keyframe_distance_m
                    || d.yaw_rad.abs() >= opts.keyframe_angle_deg.to_radians()
            }
        };
        // The last pose is always a keyframe, so every pose has one before it.
        if !due && t + 1 != trajectory.len() {
            continue;
        }
        let points_body = pts.at_stamp(sp.stamp_ns)?;
        if out.is_empty() || due || t + 1 == trajectory.len() {
            out.push(Keyframe {
                traj_index: t,
                front_pose: sp.pose,
                points_body,
                path_m,
            });
            last_kf = Some(sp.pose);
        }
    }
    Ok(out)
}

/// The matching points of a recording's scans, looked up by stamp.
#[derive(Clone)]
pub(super) struct ScanPoints<'a> {
    recording: &'a Recording,
    projector: ScanProjector,
    body: PlanarScan,
    range_max_m: f64,
    max_points: usize,
}

impl<'a> ScanPoints<'a> {
    pub(super) fn new(
        recording: &'a Recording,
        scan_opts: &ScanOptions,
        opts: &GraphOptions,
    ) -> Result<Self, GraphError> {
        // Matching takes every return in the range window; densification would only add
        // correlated points.
        let proj_opts = ScanOptions {
            range_min_m: opts.range_min_m as f32,
            range_max_m: scan_opts.range_max_m.max(opts.range_max_m as f32),
            densify_max_gap_m: None,
            ..*scan_opts
        };
        let projector =
            ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &proj_opts)?;
        Ok(ScanPoints {
            recording,
            projector,
            body: PlanarScan::default(),
            range_max_m: opts.range_max_m,
            max_points: opts.max_points,
        })
    }

    /// Returns of the scan stamped `stamp_ns` within `range_max_m` of the sensor, evenly
    /// thinned to `max_points` (empty when no scan has that stamp).
    pub(super) fn at_stamp(&mut self, stamp_ns: i64) -> Result<Vec<[f64; 2]>, GraphError> {
        let rec = self.recording;
        let stamps = &rec.scans.stamps_ns;
        let i = stamps.partition_point(|&s| s < stamp_ns);
        if i >= stamps.len() || stamps[i] != stamp_ns {
            return Ok(Vec::new());
        }
        self.projector.aim(rec, i);
        self.projector
            .to_body(rec.scans.ranges(i), &mut self.body)?;
        let mut pts = Vec::new();
        crate::matching::likelihood_field::match_points(&self.body, self.range_max_m, 1, &mut pts);
        if pts.len() > self.max_points {
            let n = pts.len();
            pts = (0..self.max_points)
                .map(|k| pts[k * n / self.max_points])
                .collect();
        }
        Ok(pts)
    }
}

/// Every input pose moved with its keyframe: `corrected(kf) * front(kf)^-1 * front(t)`.
pub(super) fn correct_trajectory(
    trajectory: &[StampedPose2],
    keyframes: &[Keyframe],
    corrected: &[Pose2],
) -> Vec<StampedPose2> {
    let mut out = Vec::with_capacity(trajectory.len());
    let mut k = 0;
    for (t, sp) in trajectory.iter().enumerate() {
        while k + 1 < keyframes.len() && keyframes[k + 1].traj_index <= t {
            k += 1;
        }
        let pose = match (keyframes.get(k), corrected.get(k)) {
            (Some(kf), Some(c)) => c.compose(&kf.front_pose.between(&sp.pose)),
            _ => sp.pose,
        };
        out.push(StampedPose2 {
            stamp_ns: sp.stamp_ns,
            pose,
        });
    }
    out
}
