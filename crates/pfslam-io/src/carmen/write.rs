//! A recording written as a CARMEN log (`pfslam perturb`): one laser line per scan, in time
//! order, with the odometry pose at the scan and, where the line has room for it, a
//! reference pose. Scans with the CARMEN beam geometry become `FLASER` lines (their `x y
//! theta` is the reference pose, as in a corrected log); other scans `ROBOTLASER1` lines,
//! which carry their own geometry and the laser's mount. Readings that mean "no return"
//! are written as the scan's maximum range.

use super::carmen_geometry;
use crate::IoError;
use crate::tum::format_stamp_s;
use pfslam::geometry::{Pose2, Trajectory};
use pfslam::sensors::{LidarGeometry, Recording};
use std::io::Write;
use std::path::Path;

/// Writes `recording` as a CARMEN log at `path` (atomically). Each scan's odometry is the
/// recording's odometry at its stamp; `reference` (when given) fills the pose fields of
/// `FLASER` lines, else the odometry does. Scans outside the odometry's time span are left
/// out; the count written is returned.
pub fn write_carmen(
    path: &Path,
    recording: &Recording,
    reference: Option<&Trajectory>,
) -> Result<usize, IoError> {
    let mount = recording.body_from_lidar.to_pose2();
    let mut written = 0;
    crate::write_atomic(path, |w| {
        writeln!(w, "# written by pfslam: one laser line per scan")?;
        writeln!(w, "PARAM robot_frontlaser_offset {} pfslam 0", mount.x_m)?;
        writeln!(
            w,
            "PARAM robot_frontlaser_side_offset {} pfslam 0",
            mount.y_m
        )?;
        writeln!(
            w,
            "PARAM robot_frontlaser_angular_offset {} pfslam 0",
            mount.yaw_rad
        )?;
        for i in 0..recording.scans.len() {
            let stamp_ns = recording.scans.stamps_ns[i];
            let Some(odom) = recording.odometry.pose_at(stamp_ns) else {
                continue;
            };
            let reference = reference.and_then(|r| r.pose_at(stamp_ns)).unwrap_or(odom);
            let line = LaserLine {
                geometry: recording.lidar_at(i),
                ranges: recording.scans.ranges(i),
                odom,
                reference,
                mount,
                stamp: format_stamp_s(stamp_ns),
            };
            line.write(w)?;
            written += 1;
        }
        Ok(())
    })?;
    Ok(written)
}

struct LaserLine<'a> {
    geometry: &'a LidarGeometry,
    ranges: &'a [f32],
    odom: Pose2,
    reference: Pose2,
    mount: Pose2,
    stamp: String,
}

impl LaserLine<'_> {
    fn write(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let g = self.geometry;
        let n = self.ranges.len();
        let no_return = g.range_max_m.min(1e6);
        // FLASER lines are read with the CARMEN geometry and the reader's default maximum
        let carmen = *g == carmen_geometry(n, super::CarmenOptions::default().range_max_m);
        if carmen {
            write!(w, "FLASER {n}")?;
        } else {
            let fov = g.angle_increment_rad * n.saturating_sub(1) as f64;
            write!(
                w,
                "ROBOTLASER1 0 {} {fov} {} {no_return} 0.01 0 {n}",
                g.angle_min_rad, g.angle_increment_rad
            )?;
        }
        for &r in self.ranges {
            let r = if r.is_finite() { r } else { no_return };
            write!(w, " {r}")?;
        }
        let (o, s) = (self.odom, &self.stamp);
        if carmen {
            let p = self.reference;
            let poses = [p.x_m, p.y_m, p.yaw_rad, o.x_m, o.y_m, o.yaw_rad];
            write!(
                w,
                " {} {} {} {} {} {}",
                poses[0], poses[1], poses[2], poses[3], poses[4], poses[5]
            )?;
        } else {
            let l = o.compose(&self.mount);
            write!(
                w,
                " 0 {} {} {} {} {} {}",
                l.x_m, l.y_m, l.yaw_rad, o.x_m, o.y_m, o.yaw_rad
            )?;
            write!(w, " 0 0 0 0 0")?;
        }
        writeln!(w, " {s} pfslam {s}")
    }
}
