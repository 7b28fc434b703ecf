//! CARMEN logs (`.clf`, `.log`, optionally gzipped), read line by line (streaming).
//!
//! Messages understood (all others, e.g. `SYNC`, `NEFF`, `RAWLASER*`, are counted
//! and skipped; `#` lines are comments):
//! - `ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp`
//! - `FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp`
//!   (front laser), `RLASER` (rear laser, same layout)
//! - `ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1..r_n
//!   m rem_1..rem_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
//!   forward_safety side_safety turn_axis ipc_timestamp host logger_timestamp`
//! - `TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta ipc_timestamp host
//!   logger_timestamp` (simulated logs): becomes the recording's ground truth
//! - `PARAM name value [host stamp]`: `robot_{front,rear}laser_{offset,side_offset,angular_offset}`
//!   give the laser mount.
//!
//! Conventions chosen here (documented because CARMEN files do not say them):
//! - **Stamps** are the `ipc_timestamp` field (seconds, parsed exactly into ns). The Freiburg
//!   relations files match the `ipc_timestamp` of the laser lines (checked on MIT-CSAIL:
//!   every relation stamp is within half a unit of its last printed decimal of a scan's
//!   `ipc_timestamp`; the `logger_timestamp` is relative to the start of logging and matches none).
//! - **Beam angles** (FLASER/RLASER carry no geometry): beam `i` points at
//!   `-90 deg + i * res` with `res = 1 deg` for 180 or 181 beams and `0.5 deg` for 360 or 361
//!   beams (the convention of CARMEN and GMapping's CARMEN reader); any other count spreads 180 deg
//!   over `n - 1` intervals starting at -90 deg. ROBOTLASER1 lines carry their own
//!   `start_angle` and `resolution`, which are used as recorded.
//! - **No return**: readings at or above [`CarmenOptions::range_max_m`] (default 50 m; the
//!   Freiburg logs write 81.83/81.91 m or 50 m for "no return").
//! - **Odometry**: the `ODOM` lines when there are any, else the odometry poses embedded in the
//!   laser lines (`odom_x odom_y odom_theta` of FLASER/RLASER, the robot pose of ROBOTLASER1),
//!   stamped with the laser line's stamp (MIT-CSAIL has no ODOM line).
//! - **Timestamps that go backwards** (Radish's corrected Intel log has hundreds): the poses in
//!   a log are in the order the robot produced them, only some stamps are wrong (a stamp jumps
//!   ahead and the following ones continue from before the jump). We keep the longest
//!   subsequence of messages whose stamps strictly increase in file order (longest increasing
//!   subsequence) and drop the others, which removes each wrong stamp and every duplicate
//!   stamp (the first of equal stamps is kept). The benchmark's relations name scans by their
//!   stamps, so scans are all kept and sorted by stamp instead (stable; a scan whose stamp
//!   repeats an earlier one is dropped). `ODOM` lines whose stamp is 0 once rounded to the
//!   nanosecond are dropped first: corrected logs write the corrected pose of each keyframe as
//!   an `ODOM` line with stamp `0` (or garbage like `1e-42`), which is not odometry. [`CarmenStats`] counts what was dropped or moved.

use super::tum::parse_stamp_ns;
use super::{IoError, parse_finite_f64};
use crate::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
use crate::sensors::{LidarGeometry, Recording, ScanSet};
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Read};
use std::path::Path;

/// Which laser of the log becomes the recording's scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CarmenLaser {
    /// `FLASER` lines, or `ROBOTLASER1` lines when the log has no `FLASER`.
    #[default]
    Front,
    /// `RLASER` lines (mounted facing backwards: yaw pi in the body frame).
    Rear,
}

/// Options of the CARMEN reader.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CarmenOptions {
    /// Which laser to read.
    pub laser: CarmenLaser,
    /// Readings at or above this range (m) mean "no return".
    pub range_max_m: f32,
}

impl Default for CarmenOptions {
    fn default() -> Self {
        CarmenOptions {
            laser: CarmenLaser::Front,
            range_max_m: 50.0,
        }
    }
}

/// What the reader saw and dropped.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CarmenStats {
    /// Lines read (including comments).
    pub lines: usize,
    /// `ODOM` lines.
    pub odom_lines: usize,
    /// `ODOM` lines dropped because their stamp is 0.
    pub odom_zero_stamp: usize,
    /// `ODOM` lines dropped because their stamp is out of order or repeated.
    pub odom_out_of_order: usize,
    /// Laser lines of the chosen laser.
    pub laser_lines: usize,
    /// Laser lines whose stamp is not above the previous one's (sorted into place; a repeated
    /// stamp is dropped).
    pub laser_out_of_order: usize,
    /// `TRUEPOS` lines (ground truth of simulated logs).
    pub truepos_lines: usize,
    /// Lines of other message types (skipped).
    pub other_lines: usize,
    /// True when the odometry came from the poses embedded in laser lines.
    pub odometry_from_laser: bool,
}

/// A CARMEN log read into a [`Recording`], with its reading statistics.
#[derive(Debug, Clone)]
pub struct CarmenLog {
    /// The recording.
    pub recording: Recording,
    /// What was read and dropped.
    pub stats: CarmenStats,
}

/// The CARMEN beam geometry for `beam_count` beams spread over 180 deg (see the module docs).
pub fn carmen_geometry(beam_count: usize, range_max_m: f32) -> LidarGeometry {
    let res_deg = match beam_count {
        180 | 181 => 1.0,
        360 | 361 => 0.5,
        n => 180.0 / (n.max(2) - 1) as f64,
    };
    LidarGeometry {
        angle_min_rad: (-90.0f64).to_radians(),
        angle_increment_rad: res_deg.to_radians(),
        beam_count,
        range_max_m,
    }
}

/// Indices of a longest subsequence of strictly increasing values (of equal values the first
/// is kept), in order. O(n log n).
pub(crate) fn longest_increasing(stamps: &[i64]) -> Vec<usize> {
    // tails[k] = index of the smallest tail of an increasing run of length k + 1
    let mut tails: Vec<usize> = Vec::new();
    let mut prev: Vec<usize> = vec![usize::MAX; stamps.len()];
    for (i, &s) in stamps.iter().enumerate() {
        let k = tails.partition_point(|&j| stamps[j] < s);
        if k > 0 {
            prev[i] = tails[k - 1];
        }
        if k == tails.len() {
            tails.push(i);
        } else if stamps[tails[k]] > s {
            tails[k] = i;
        }
    }
    let mut out = Vec::with_capacity(tails.len());
    let mut cur = tails.last().copied().unwrap_or(usize::MAX);
    while cur != usize::MAX {
        out.push(cur);
        cur = prev[cur];
    }
    out.reverse();
    out
}

/// Scans sorted by stamp (stable; of scans with equal stamps the first is kept) and the
/// number of scans whose stamp is not above the previous one's in file order.
pub(crate) fn sort_scans(scans: ScanSet) -> (ScanSet, usize) {
    let backwards = scans.stamps_ns.windows(2).filter(|w| w[1] <= w[0]).count();
    if backwards == 0 {
        return (scans, 0);
    }
    let mut order: Vec<usize> = (0..scans.len()).collect();
    order.sort_by_key(|&i| scans.stamps_ns[i]);
    let mut out = ScanSet::new(scans.beam_count);
    for &i in &order {
        let s = scans.stamps_ns[i];
        if out.stamps_ns.last() != Some(&s) {
            out.push(s, scans.ranges(i));
        }
    }
    (out, backwards)
}

/// Opens a possibly gzipped text file for buffered reading (gzip detected by its magic bytes).
pub(crate) fn open_maybe_gz(path: &Path) -> Result<Box<dyn BufRead>, IoError> {
    let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut magic = [0u8; 2];
    let n = file.read(&mut magic).map_err(|e| IoError::io(path, e))?;
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    if n == 2 && magic == [0x1f, 0x8b] {
        Ok(Box::new(std::io::BufReader::with_capacity(
            1 << 16,
            flate2::read::MultiGzDecoder::new(file),
        )))
    } else {
        Ok(Box::new(std::io::BufReader::with_capacity(1 << 16, file)))
    }
}

struct LaserMount {
    x_m: f64,
    y_m: f64,
    yaw_rad: f64,
}

/// Reads a CARMEN log into a [`Recording`] (see the module docs for the conventions).
pub fn read_carmen(path: &Path, options: &CarmenOptions) -> Result<CarmenLog, IoError> {
    let mut reader = open_maybe_gz(path)?;
    let mut stats = CarmenStats::default();
    let mut line = String::new();
    let mut ranges: Vec<f32> = Vec::new();

    let mut odom: Vec<StampedPose2> = Vec::new();
    let mut laser = LaserLines::default();
    let mut truepos: Vec<StampedPose2> = Vec::new();
    let mut robotlaser_mount: Option<Pose2> = None;
    let mut front = LaserMount {
        x_m: 0.0,
        y_m: 0.0,
        yaw_rad: 0.0,
    };
    let mut rear = LaserMount {
        x_m: 0.0,
        y_m: 0.0,
        yaw_rad: 0.0,
    };
    let mut saw_flaser = false;

    loop {
        line.clear();
        let n = match reader.read_line(&mut line) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::InvalidData => {
                return Err(IoError::parse(
                    path,
                    stats.lines + 1,
                    "line is not valid UTF-8 text",
                ));
            }
            Err(e) => {
                return Err(IoError::parse(
                    path,
                    stats.lines + 1,
                    format!("read failed: {e}"),
                ));
            }
        };
        if n == 0 {
            break;
        }
        stats.lines += 1;
        let line_no = stats.lines;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = t.split_ascii_whitespace().collect();
        let kind = fields[0];
        match kind {
            "ODOM" => {
                stats.odom_lines += 1;
                if fields.len() < 8 {
                    return Err(IoError::parse(
                        path,
                        line_no,
                        format!(
                            "ODOM: expected 9 fields (x y theta tv rv accel ipc_timestamp host logger_timestamp), found {}",
                            fields.len() - 1
                        ),
                    ));
                }
                let x = parse_finite_f64(path, line_no, "ODOM x", fields[1])?;
                let y = parse_finite_f64(path, line_no, "ODOM y", fields[2])?;
                let th = parse_finite_f64(path, line_no, "ODOM theta", fields[3])?;
                let stamp_ns = parse_stamp(path, line_no, "ODOM ipc_timestamp", fields[7])?;
                if stamp_ns == 0 {
                    stats.odom_zero_stamp += 1;
                    continue;
                }
                odom.push(StampedPose2 {
                    stamp_ns,
                    pose: Pose2::new(x, y, th),
                });
            }
            "FLASER" | "RLASER" => {
                let wanted = match options.laser {
                    CarmenLaser::Front => kind == "FLASER",
                    CarmenLaser::Rear => kind == "RLASER",
                };
                if kind == "FLASER" {
                    saw_flaser = true;
                }
                if !wanted {
                    stats.other_lines += 1;
                    continue;
                }
                stats.laser_lines += 1;
                let n = parse_count(path, line_no, kind, fields.get(1).copied())?;
                if fields.len() != n + 11 {
                    return Err(IoError::parse(
                        path,
                        line_no,
                        format!(
                            "{kind}: {n} readings need {} fields (n, readings, x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp), found {}",
                            n + 10,
                            fields.len() - 1
                        ),
                    ));
                }
                parse_ranges(path, line_no, kind, &fields[2..2 + n], &mut ranges)?;
                let o = 2 + n;
                let ox = parse_finite_f64(path, line_no, "odom_x", fields[o + 3])?;
                let oy = parse_finite_f64(path, line_no, "odom_y", fields[o + 4])?;
                let oth = parse_finite_f64(path, line_no, "odom_theta", fields[o + 5])?;
                let stamp_ns = parse_stamp(path, line_no, "ipc_timestamp", fields[o + 6])?;
                let g = carmen_geometry(n, options.range_max_m);
                let odom_pose = Pose2::new(ox, oy, oth);
                laser.push(path, line_no, g, stamp_ns, odom_pose, &ranges)?;
            }
            "ROBOTLASER1" => {
                if options.laser != CarmenLaser::Front || saw_flaser {
                    stats.other_lines += 1;
                    continue;
                }
                stats.laser_lines += 1;
                if fields.len() < 10 {
                    return Err(IoError::parse(path, line_no, "ROBOTLASER1: line too short"));
                }
                let start = parse_finite_f64(path, line_no, "start_angle", fields[2])?;
                let res = parse_finite_f64(path, line_no, "angular_resolution", fields[4])?;
                let n = parse_count(path, line_no, kind, Some(fields[8]))?;
                let m_at = 9 + n;
                let m = parse_count(path, line_no, "num_remissions", fields.get(m_at).copied())?;
                let rest = m_at + 1 + m;
                if fields.len() != rest + 14 {
                    return Err(IoError::parse(
                        path,
                        line_no,
                        format!(
                            "ROBOTLASER1: {n} readings and {m} remissions need {} fields, found {}",
                            rest + 13,
                            fields.len() - 1
                        ),
                    ));
                }
                parse_ranges(path, line_no, kind, &fields[9..9 + n], &mut ranges)?;
                let mut v = [0.0f64; 6];
                let names = [
                    "laser_pose_x",
                    "laser_pose_y",
                    "laser_pose_theta",
                    "robot_pose_x",
                    "robot_pose_y",
                    "robot_pose_theta",
                ];
                for k in 0..6 {
                    v[k] = parse_finite_f64(path, line_no, names[k], fields[rest + k])?;
                }
                let stamp_ns = parse_stamp(path, line_no, "ipc_timestamp", fields[rest + 11])?;
                let g = LidarGeometry {
                    angle_min_rad: start,
                    angle_increment_rad: res,
                    beam_count: n,
                    range_max_m: options.range_max_m,
                };
                let laser_pose = Pose2::new(v[0], v[1], v[2]);
                let robot = Pose2::new(v[3], v[4], v[5]);
                if robotlaser_mount.is_none() {
                    robotlaser_mount = Some(robot.between(&laser_pose));
                }
                laser.push(path, line_no, g, stamp_ns, robot, &ranges)?;
            }
            "TRUEPOS" => {
                stats.truepos_lines += 1;
                if fields.len() < 8 {
                    return Err(IoError::parse(
                        path,
                        line_no,
                        format!(
                            "TRUEPOS: expected 9 fields (true_x true_y true_theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp), found {}",
                            fields.len() - 1
                        ),
                    ));
                }
                let x = parse_finite_f64(path, line_no, "TRUEPOS true_x", fields[1])?;
                let y = parse_finite_f64(path, line_no, "TRUEPOS true_y", fields[2])?;
                let th = parse_finite_f64(path, line_no, "TRUEPOS true_theta", fields[3])?;
                let stamp_ns = parse_stamp(path, line_no, "TRUEPOS ipc_timestamp", fields[7])?;
                truepos.push(StampedPose2 {
                    stamp_ns,
                    pose: Pose2::new(x, y, th),
                });
            }
            "PARAM" => {
                if fields.len() < 3 {
                    continue;
                }
                let target = match fields[1] {
                    "robot_frontlaser_offset" => Some((&mut front, 0)),
                    "robot_frontlaser_side_offset" => Some((&mut front, 1)),
                    "robot_frontlaser_angular_offset" => Some((&mut front, 2)),
                    "robot_rearlaser_offset" => Some((&mut rear, 0)),
                    "robot_rearlaser_side_offset" => Some((&mut rear, 1)),
                    "robot_rearlaser_angular_offset" => Some((&mut rear, 2)),
                    _ => None,
                };
                if let Some((mount, k)) = target {
                    let v = parse_finite_f64(path, line_no, fields[1], fields[2])?;
                    match k {
                        0 => mount.x_m = v,
                        1 => mount.y_m = v,
                        _ => mount.yaw_rad = v,
                    }
                }
            }
            _ => stats.other_lines += 1,
        }
    }

    let LaserLines {
        scans,
        geometry,
        odom: laser_odom,
    } = laser;
    let Some(scans) = scans else {
        return Err(IoError::parse(
            path,
            0,
            match options.laser {
                CarmenLaser::Front => "no FLASER or ROBOTLASER1 line in the log",
                CarmenLaser::Rear => "no RLASER line in the log",
            },
        ));
    };
    let lidar = geometry.unwrap_or_else(|| carmen_geometry(scans.beam_count, options.range_max_m));

    let (scans, moved) = sort_scans(scans);
    stats.laser_out_of_order = moved;

    let odometry_src = if odom.is_empty() {
        stats.odometry_from_laser = true;
        laser_odom
    } else {
        odom
    };
    let stamps: Vec<i64> = odometry_src.iter().map(|p| p.stamp_ns).collect();
    let keep = longest_increasing(&stamps);
    let dropped = odometry_src.len() - keep.len();
    if stats.odometry_from_laser {
        // the same lines as the scans: already counted there
    } else {
        stats.odom_out_of_order = dropped;
    }
    let odometry = Trajectory::new(keep.iter().map(|&i| odometry_src[i]).collect());
    if odometry.is_empty() {
        return Err(IoError::parse(path, 0, "no odometry in the log"));
    }

    let body_from_lidar = match (options.laser, robotlaser_mount) {
        (CarmenLaser::Front, Some(m)) => pose_to_rigid(&m),
        (CarmenLaser::Front, None) => {
            pose_to_rigid(&Pose2::new(front.x_m, front.y_m, front.yaw_rad))
        }
        (CarmenLaser::Rear, _) => pose_to_rigid(&Pose2::new(
            rear.x_m,
            rear.y_m,
            std::f64::consts::PI + rear.yaw_rad,
        )),
    };
    let recording = Recording {
        name: recording_name(path),
        odometry,
        imu_yaw: None,
        scans,
        lidar,
        body_from_lidar,
        body_from_lidar_per_scan: None,
        ground_truth: (!truepos.is_empty()).then(|| {
            let stamps: Vec<i64> = truepos.iter().map(|p| p.stamp_ns).collect();
            longest_increasing(&stamps)
                .iter()
                .map(|&i| truepos[i])
                .collect()
        }),
    };
    Ok(CarmenLog { recording, stats })
}

/// The file name without its extensions (`intel-corrected.log.gz` -> `intel-corrected`).
pub(crate) fn recording_name(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    match name.split_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem.to_string(),
        _ => name,
    }
}

/// A planar pose as a 3-D transform (rotation about z).
pub(crate) fn pose_to_rigid(p: &Pose2) -> Rigid3 {
    Rigid3::from_pose2(p)
}

fn parse_stamp(path: &Path, line: usize, field: &str, text: &str) -> Result<i64, IoError> {
    parse_stamp_ns(text).ok_or_else(|| {
        IoError::parse(
            path,
            line,
            format!("{field}: not a time in seconds: {text:?}"),
        )
    })
}

fn parse_count(path: &Path, line: usize, kind: &str, text: Option<&str>) -> Result<usize, IoError> {
    let text = text.ok_or_else(|| IoError::parse(path, line, format!("{kind}: missing count")))?;
    let n: usize = text.parse().map_err(|_| {
        IoError::parse(
            path,
            line,
            format!("{kind}: count is not a non-negative integer: {text:?}"),
        )
    })?;
    if n > 100_000 {
        return Err(IoError::parse(
            path,
            line,
            format!("{kind}: implausible count {n}"),
        ));
    }
    Ok(n)
}

fn parse_ranges(
    path: &Path,
    line: usize,
    kind: &str,
    texts: &[&str],
    out: &mut Vec<f32>,
) -> Result<(), IoError> {
    out.clear();
    for (k, t) in texts.iter().enumerate() {
        match t.parse::<f32>() {
            Ok(v) if v.is_finite() => out.push(v),
            _ => {
                return Err(IoError::parse(
                    path,
                    line,
                    format!("{kind}: reading {} is not a finite number: {t:?}", k + 1),
                ));
            }
        }
    }
    Ok(())
}

/// The scans of the chosen laser and the odometry poses embedded in its lines.
#[derive(Default)]
struct LaserLines {
    scans: Option<ScanSet>,
    geometry: Option<LidarGeometry>,
    odom: Vec<StampedPose2>,
}

impl LaserLines {
    /// Adds one laser line; its geometry must match the first line's.
    fn push(
        &mut self,
        path: &Path,
        line: usize,
        g: LidarGeometry,
        stamp_ns: i64,
        odom_pose: Pose2,
        ranges: &[f32],
    ) -> Result<(), IoError> {
        if ranges.is_empty() {
            return Err(IoError::parse(path, line, "laser line with 0 readings"));
        }
        match &self.geometry {
            Some(prev) if *prev != g => {
                return Err(IoError::parse(
                    path,
                    line,
                    format!(
                        "laser geometry changes within the log ({} beams from {:.4} rad step {:.6} rad, earlier {} beams from {:.4} step {:.6})",
                        g.beam_count,
                        g.angle_min_rad,
                        g.angle_increment_rad,
                        prev.beam_count,
                        prev.angle_min_rad,
                        prev.angle_increment_rad
                    ),
                ));
            }
            Some(_) => {}
            None => self.geometry = Some(g),
        }
        self.scans
            .get_or_insert_with(|| ScanSet::new(g.beam_count))
            .push(stamp_ns, ranges);
        self.odom.push(StampedPose2 {
            stamp_ns,
            pose: odom_pose,
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lis_drops_outliers_and_duplicates() {
        let s = [1, 2, 9, 3, 4, 5, 5, 6, 0, 7];
        let keep = longest_increasing(&s);
        let kept: Vec<i64> = keep.iter().map(|&i| s[i]).collect();
        assert_eq!(kept, vec![1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(keep[4], 5, "first of equal stamps kept");
        assert!(longest_increasing(&[]).is_empty());
    }

    #[test]
    fn geometry_convention() {
        let g = carmen_geometry(180, 50.0);
        assert!((g.beam_angle_rad(0) + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((g.beam_angle_rad(90)).abs() < 1e-12);
        let g = carmen_geometry(361, 50.0);
        assert!((g.beam_angle_rad(360) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let g = carmen_geometry(360, 50.0);
        assert!((g.angle_increment_rad - 0.5f64.to_radians()).abs() < 1e-15);
    }

    #[test]
    fn names() {
        assert_eq!(
            recording_name(Path::new("/a/intel-corrected.log.gz")),
            "intel-corrected"
        );
        assert_eq!(recording_name(Path::new("mit-csail.clf")), "mit-csail");
    }
}
