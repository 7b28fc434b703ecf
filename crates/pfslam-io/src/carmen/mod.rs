//! CARMEN logs (`.clf`, `.log`, optionally gzipped), read line by line (streaming).
//!
//! Messages understood (lines of other types, e.g. `SYNC`, `NEFF`, are counted in the
//! account's `ignored`; `#` lines are comments):
//! - `FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp`
//!   (front laser), `RLASER` (rear laser, same layout)
//! - `ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1..r_n
//!   m rem_1..rem_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
//!   forward_safety side_safety turn_axis ipc_timestamp host logger_timestamp`
//! - `RAWLASER1` (front) / `RAWLASER2` (rear) `laser_type start_angle fov resolution
//!   max_range accuracy remission_mode n r_1..r_n m rem_1..rem_m ipc_timestamp host
//!   logger_timestamp`: used when the log has none of the lines above for that laser
//! - `ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp`: the odometry of
//!   `RAWLASER` logs (whose lines carry no pose); its stamps can serve as the clock (below)
//! - `TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta ipc_timestamp host
//!   logger_timestamp` (simulated logs): becomes the recording's ground truth
//! - `PARAM name value [host stamp]`: `robot_{front,rear}laser_{offset,side_offset,angular_offset}`
//!   give the laser mount.
//!
//! Conventions chosen here (documented because CARMEN files do not say them):
//! - **Every laser line is a scan**, in file order: the file's order is the order of events.
//! - **Odometry** is the pose each laser line carries (`odom_x odom_y odom_theta` of
//!   FLASER/RLASER, the robot pose of ROBOTLASER1): exact at its scan whatever its stamp,
//!   which is how GMapping reads CARMEN. `ODOM` lines are needed only for `RAWLASER` lines,
//!   which carry no pose: the `ODOM` poses on their clock (none usable: LiDAR-only).
//! - **Stamps** are the `ipc_timestamp` field (seconds, parsed exactly into ns; the Freiburg
//!   relations name scans by it). Real logs write zero, repeated, rounded (`1.13486e+09`) or
//!   wild stamps, so the clock is chosen by this rule:
//!   1. the laser stamps, when the longest run of positive stamps that increase in file order
//!      holds at least half of the laser lines; every other laser line is stamped evenly
//!      between its trusted neighbours (or one median interval on past the ends);
//!   2. else the `ODOM` lines' stamps by the same test, each laser line placed by its file
//!      position among the `ODOM` lines;
//!   3. else a clock of one scan per second in file order (the account says so: relations
//!      and ground truth named by stamp cannot be matched then).
//! - **Beam angles** (FLASER/RLASER carry no geometry): beam `i` points at
//!   `-90 deg + i * res` with `res = 1 deg` for 180 or 181 beams and `0.5 deg` for 360 or 361
//!   beams (the convention of CARMEN and GMapping's CARMEN reader); any other count spreads
//!   180 deg over `n - 1` intervals starting at -90 deg. ROBOTLASER1 lines carry their own
//!   `start_angle`, `resolution` and `max_range`, used as recorded. The geometry is per scan:
//!   a log may mix beam counts.
//! - **No return**: readings at or above [`CarmenOptions::range_max_m`] (default 50 m; the
//!   Freiburg logs write 81.83/81.91 m or 50 m for "no return"), or a ROBOTLASER1 line's own
//!   smaller `max_range`; readings that are not finite.
//! - **Malformed lines** are dropped and counted with the first line number, unless
//!   [`CarmenOptions::strict`]; a cut last line (a logger stopped mid-line) is dropped with a
//!   warning.

mod lines;
mod live;
mod parse;
mod stream;
mod write;

pub use live::{CarmenLive, LiveMessage, LiveScan};
pub use pfslam::sensors::reader_options::CarmenLaser;
pub use stream::{ScanPose, stream_scan_poses};
pub use write::write_carmen;

use super::account::InputAccount;
use super::clock::{RepairedClock, place_between, repair_in_file_order};
use super::{IoError, clock::SYNTHETIC_PERIOD_NS};
use lines::{for_each_message, maybe_gz};
use parse::{LaserKind, LaserLine, Message};
use pfslam::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
use pfslam::sensors::{LidarGeometry, Recording, ScanSet};
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Read};
use std::path::Path;

/// Options of the CARMEN reader.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CarmenOptions {
    /// Which laser to read.
    pub laser: CarmenLaser,
    /// Readings at or above this range (m) mean "no return".
    pub range_max_m: f32,
    /// A malformed line is an error naming the file and line, instead of a counted drop.
    pub strict: bool,
}

impl Default for CarmenOptions {
    fn default() -> Self {
        CarmenOptions {
            laser: CarmenLaser::Front,
            range_max_m: 50.0,
            strict: false,
        }
    }
}

/// A CARMEN log read into a [`Recording`], with its account.
#[derive(Debug, Clone)]
pub struct CarmenLog {
    /// The recording.
    pub recording: Recording,
    /// What was read, dropped and repaired.
    pub account: InputAccount,
    /// The pose each laser line gives for its scan (`x y theta` of FLASER/RLASER, the laser
    /// pose of ROBOTLASER1), at the scans' stamps: in corrected logs the corrected poses.
    pub laser_poses: Trajectory,
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
        range_min_m: 0.0,
        range_max_m,
    }
}

/// The laser lines of one kind, as read.
#[derive(Default)]
struct LaserStream {
    scans: ScanSet,
    geometry: Vec<LidarGeometry>,
    odom: Vec<Pose2>,
    pose: Vec<Pose2>,
    /// `ODOM` lines before each laser line.
    odom_before: Vec<usize>,
    first_robot_mount: Option<Pose2>,
}

impl LaserStream {
    fn push(&mut self, l: &LaserLine, g: LidarGeometry, ranges: &[f32], odom_before: usize) {
        self.scans.push_any(l.stamp_ns, ranges);
        self.geometry.push(g);
        self.odom.push(l.odom);
        self.pose.push(l.pose);
        self.odom_before.push(odom_before);
        if l.kind == LaserKind::Robot && self.first_robot_mount.is_none() {
            self.first_robot_mount = Some(l.odom.between(&l.pose));
        }
    }
}

/// A laser line's beam layout: its own (ROBOTLASER1) or CARMEN's convention.
fn line_geometry(l: &LaserLine, beam_count: usize, options: &CarmenOptions) -> LidarGeometry {
    match l.geometry {
        Some((start, res, max)) => LidarGeometry {
            angle_min_rad: start,
            angle_increment_rad: res,
            beam_count,
            range_min_m: 0.0,
            range_max_m: if max > 0.0 {
                max.min(options.range_max_m)
            } else {
                options.range_max_m
            },
        },
        None => carmen_geometry(beam_count, options.range_max_m),
    }
}

/// Everything read from the lines, before the clock is chosen.
#[derive(Default)]
struct LogContent {
    front: LaserStream,
    rear: LaserStream,
    robot: LaserStream,
    odom_stamps: Vec<Option<i64>>,
    odom_poses: Vec<Pose2>,
    raw: [LaserStream; 2],
    truepos: Vec<StampedPose2>,
    /// `[front, rear]` x, y, yaw offsets from PARAM lines.
    offsets: [[f64; 3]; 2],
}

impl LogContent {
    fn add(
        &mut self,
        msg: Message,
        ranges: &[f32],
        options: &CarmenOptions,
        acc: &mut InputAccount,
    ) {
        match msg {
            Message::Comment => {}
            Message::Laser(l) => {
                let g = line_geometry(&l, ranges.len(), options);
                acc.repair("readings", "not finite, taken as no return", l.non_finite);
                let before = self.odom_stamps.len();
                match l.kind {
                    LaserKind::Front => self.front.push(&l, g, ranges, before),
                    LaserKind::Rear => self.rear.push(&l, g, ranges, before),
                    LaserKind::Robot => self.robot.push(&l, g, ranges, before),
                    LaserKind::Raw { rear } => {
                        self.raw[usize::from(rear)].push(&l, g, ranges, before)
                    }
                }
            }
            Message::Odom { stamp_ns, pose } => {
                self.odom_stamps.push(Some(stamp_ns));
                self.odom_poses.push(pose);
            }
            Message::TruePos { stamp_ns, pose } => {
                self.truepos.push(StampedPose2 { stamp_ns, pose })
            }
            Message::Param { name, value } => set_offset(&mut self.offsets, &name, value),
            Message::Other(kind) => acc.ignore_one(&kind, "lines"),
        }
    }
}

/// Stores a `PARAM` laser offset (`robot_{front,rear}laser_{offset,side_offset,angular_offset}`).
fn set_offset(offsets: &mut [[f64; 3]; 2], name: &str, value: f64) {
    let which = usize::from(name.contains("rear"));
    let k = if name.ends_with("side_offset") {
        1
    } else if name.ends_with("angular_offset") {
        2
    } else {
        0
    };
    offsets[which][k] = value;
}

/// Reads a CARMEN log into a [`Recording`] (see the module docs for the conventions).
pub fn read_carmen(path: &Path, options: &CarmenOptions) -> Result<CarmenLog, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    read_carmen_from(file, path, options)
}

/// [`read_carmen`] from any byte source (plain or gzipped); `path` names it in errors and in
/// the account.
pub fn read_carmen_from(
    source: impl Read,
    path: &Path,
    options: &CarmenOptions,
) -> Result<CarmenLog, IoError> {
    let mut acc = InputAccount::new("carmen", path, "lines");
    let content = read_lines(maybe_gz(source, path)?, path, options, &mut acc)?;
    assemble(path, options, content, acc)
}

/// Reads every line, dropping (or, strict, refusing) malformed ones.
fn read_lines(
    reader: Box<dyn BufRead + '_>,
    path: &Path,
    options: &CarmenOptions,
    acc: &mut InputAccount,
) -> Result<LogContent, IoError> {
    let mut content = LogContent::default();
    for_each_message(reader, path, options, acc, |msg, ranges, acc| {
        content.add(msg, ranges, options, acc);
        Ok(())
    })?;
    Ok(content)
}

/// The laser line types, in the order [`LaserKind`] indexes them.
const KINDS: [&str; 5] = ["FLASER", "RLASER", "ROBOTLASER1", "RAWLASER1", "RAWLASER2"];

fn kind_index(kind: LaserKind) -> usize {
    match kind {
        LaserKind::Front => 0,
        LaserKind::Rear => 1,
        LaserKind::Robot => 2,
        LaserKind::Raw { rear } => 3 + usize::from(rear),
    }
}

/// The line types the chosen laser's scans may come from, in order of preference (indices
/// into [`KINDS`]).
fn candidates(laser: CarmenLaser) -> &'static [usize] {
    match laser {
        CarmenLaser::Front => &[0, 2, 3],
        CarmenLaser::Rear => &[1, 4],
    }
}

/// The laser mount of line type `k`: PARAM offsets, or the first ROBOTLASER1 line's.
fn laser_mount(offsets: &[[f64; 3]; 2], robot_mount: Option<Pose2>, k: usize) -> Pose2 {
    let at = |i: usize, yaw: f64| Pose2::new(offsets[i][0], offsets[i][1], yaw + offsets[i][2]);
    match k {
        2 => robot_mount.unwrap_or(Pose2::IDENTITY),
        1 | 4 => at(1, std::f64::consts::PI),
        _ => at(0, 0.0),
    }
}

impl LogContent {
    fn stream_mut(&mut self, k: usize) -> &mut LaserStream {
        match k {
            0 => &mut self.front,
            1 => &mut self.rear,
            2 => &mut self.robot,
            3 => &mut self.raw[0],
            _ => &mut self.raw[1],
        }
    }
}

/// The laser stream a log's scans come from (the first non-empty of the chosen laser's
/// line types), its name and the laser mount.
fn choose_stream(
    options: &CarmenOptions,
    c: &mut LogContent,
) -> (LaserStream, &'static str, Pose2) {
    for &k in candidates(options.laser) {
        if !c.stream_mut(k).scans.is_empty() {
            let mount = laser_mount(&c.offsets, c.robot.first_robot_mount, k);
            return (std::mem::take(c.stream_mut(k)), KINDS[k], mount);
        }
    }
    (LaserStream::default(), "", Pose2::IDENTITY)
}

/// Chooses the laser stream and the clock, and builds the recording.
fn assemble(
    path: &Path,
    options: &CarmenOptions,
    mut content: LogContent,
    mut acc: InputAccount,
) -> Result<CarmenLog, IoError> {
    let (stream, kind_name, mount) = choose_stream(options, &mut content);
    let others: [usize; 5] = std::array::from_fn(|k| content.stream_mut(k).scans.len());
    let n = stream.scans.len();
    account_laser(path, options, &mut acc, others, kind_name, n)?;
    for g in &stream.geometry {
        acc.add_layout(g);
    }
    let stamps = choose_clock(path, &stream, &content.odom_stamps, &mut acc);
    let raw = kind_name.starts_with("RAWLASER");
    let odometry = if raw {
        // these lines carry no pose: the ODOM lines are the odometry
        let odom = odom_lines(&content, &mut acc);
        acc.odometry_source = "the ODOM lines (the RAWLASER lines carry no pose)".into();
        Some(odom)
    } else {
        account_pose_odometry(&mut acc, kind_name, n, content.odom_poses.len());
        None
    };
    Ok(build(
        path,
        stream,
        stamps,
        mount,
        odometry,
        content.truepos,
        acc,
    ))
}

/// The account of the chosen laser's `n` scans (`others`: the lines of each other laser
/// type, ignored); an error when the log has none.
fn account_laser(
    path: &Path,
    options: &CarmenOptions,
    acc: &mut InputAccount,
    others: [usize; 5],
    kind_name: &str,
    n: usize,
) -> Result<(), IoError> {
    for (name, count) in KINDS.iter().zip(others) {
        acc.ignore_many(name, "lines (another laser)", count);
    }
    if n == 0 {
        return Err(IoError::parse(
            path,
            0,
            match options.laser {
                CarmenLaser::Front => "no FLASER, ROBOTLASER1 or RAWLASER1 line in the log",
                CarmenLaser::Rear => "no RLASER or RAWLASER2 line in the log",
            },
        ));
    }
    acc.scans_read += n;
    acc.scans_kept = n;
    acc.mount_source = match kind_name {
        "ROBOTLASER1" => "the first ROBOTLASER1 line's laser and robot poses".into(),
        _ => "PARAM laser offsets (zero when absent)".into(),
    };
    Ok(())
}

/// The account of odometry taken from the `n` laser lines' poses (the ODOM lines ignored).
fn account_pose_odometry(acc: &mut InputAccount, kind_name: &str, n: usize, odom_lines: usize) {
    let why = "lines (the laser lines carry the odometry)";
    acc.ignore_many("ODOM", why, odom_lines);
    acc.odometry_read = n;
    acc.odometry_kept = n;
    acc.odometry_source = format!("the {kind_name} lines' odometry poses");
}

/// The account's clock when `repaired` of the laser lines' stamps were placed by file order.
fn account_laser_clock(acc: &mut InputAccount, repaired: usize) {
    acc.clock = if repaired == 0 {
        "the laser lines' stamps".into()
    } else {
        format!("the laser lines' stamps, {repaired} placed by file order")
    };
    acc.repair(
        "scans",
        "stamp zero, repeated or out of order: placed by file order",
        repaired,
    );
}

/// The ODOM lines as odometry, on their clock (empty when they have none: LiDAR-only).
fn odom_lines(content: &LogContent, acc: &mut InputAccount) -> Trajectory {
    acc.odometry_read = content.odom_poses.len();
    let Some(clock) = repair_in_file_order(&content.odom_stamps) else {
        acc.warnings.push("the ODOM lines have no usable stamps: the odometry comes from scan matching (LiDAR-only)".into());
        return Trajectory::default();
    };
    acc.repair(
        "odometry",
        "stamp zero, repeated or out of order: placed by file order",
        clock.repaired,
    );
    acc.odometry_kept = content.odom_poses.len();
    Trajectory::new(
        clock
            .stamps_ns
            .iter()
            .zip(&content.odom_poses)
            .map(|(&stamp_ns, &pose)| StampedPose2 { stamp_ns, pose })
            .collect(),
    )
}

/// The scans' stamps by the rule of the module docs, with the account's `clock`.
fn choose_clock(
    path: &Path,
    stream: &LaserStream,
    odom: &[Option<i64>],
    acc: &mut InputAccount,
) -> Vec<i64> {
    let laser: Vec<Option<i64>> = stream.scans.stamps_ns.iter().map(|&s| Some(s)).collect();
    if let Some(c) = repair_in_file_order(&laser) {
        account_laser_clock(acc, c.repaired);
        return c.stamps_ns;
    }
    let odom_clock: Option<RepairedClock> = repair_in_file_order(odom);
    let (stamps, clock) = match odom_clock {
        Some(c) => (
            place_between(&c, &stream.odom_before),
            "the ODOM lines' stamps, each scan placed by its file position (laser stamps unusable)",
        ),
        None => (
            (0..stream.scans.len() as i64)
                .map(|k| k * SYNTHETIC_PERIOD_NS)
                .collect(),
            "one scan per second in file order (no usable stamps)",
        ),
    };
    acc.clock = clock.into();
    acc.repair(
        "scans",
        "stamp unusable: placed by file order",
        stream.scans.len(),
    );
    acc.warnings.push(format!(
        "{}: the laser stamps are unusable (zero, repeated or not increasing); the clock is {clock}: relations or ground truth named by stamp will not match",
        path.display()
    ));
    stamps
}

fn build(
    path: &Path,
    stream: LaserStream,
    stamps: Vec<i64>,
    mount: Pose2,
    odometry: Option<Trajectory>,
    truepos: Vec<StampedPose2>,
    acc: InputAccount,
) -> CarmenLog {
    let LaserStream {
        mut scans,
        geometry,
        odom,
        pose,
        ..
    } = stream;
    scans.stamps_ns.clone_from(&stamps);
    let at = |v: &[Pose2]| -> Trajectory {
        Trajectory::new(
            stamps
                .iter()
                .zip(v)
                .map(|(&stamp_ns, &pose)| StampedPose2 { stamp_ns, pose })
                .collect(),
        )
    };
    let uniform = geometry.windows(2).all(|w| w[0] == w[1]);
    let recording = Recording {
        name: recording_name(path),
        odometry: odometry.unwrap_or_else(|| at(&odom)),
        imu_yaw: None,
        lidar: geometry[0],
        lidar_per_scan: (!uniform).then_some(geometry),
        scans,
        body_from_lidar: pose_to_rigid(&mount),
        body_from_lidar_per_scan: None,
        ground_truth: (!truepos.is_empty()).then(|| {
            let stamps: Vec<i64> = truepos.iter().map(|p| p.stamp_ns).collect();
            super::clock::longest_increasing(&stamps)
                .iter()
                .map(|&i| truepos[i])
                .collect()
        }),
    };
    CarmenLog {
        laser_poses: at(&pose),
        recording,
        account: acc,
    }
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

#[cfg(test)]
mod tests {
    use super::*;

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
