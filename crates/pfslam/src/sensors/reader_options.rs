//! The options of every recording reader: the `[input]` section of the configuration. The
//! readers themselves are the `pfslam-io` crate's.

use serde::{Deserialize, Serialize};

/// The largest odometry shift accepted (s): beyond it the streams are not of one robot run.
pub const MAX_ODOMETRY_SHIFT_S: f64 = 1.0;

/// Checks an odometry shift (`[input] odometry_shift_s`); the message names the key.
pub fn check_odometry_shift(shift_s: Option<f64>) -> Result<(), String> {
    match shift_s {
        Some(s) if !(s.is_finite() && s.abs() <= MAX_ODOMETRY_SHIFT_S) => Err(format!(
            "input.odometry_shift_s must be finite and within +-{MAX_ODOMETRY_SHIFT_S} s"
        )),
        _ => Ok(()),
    }
}

/// Options of all recording readers (`[input]`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReaderOptions {
    /// ROS topic of the scans; unset: the only `LaserScan` topic, or `/scan` among several.
    pub scan_topic: Option<String>,
    /// ROS topic of the odometry; unset: the only `Odometry` topic, or `/odom` among
    /// several, or odometry from `/tf` when there is none.
    pub odom_topic: Option<String>,
    /// ROS body frame; unset: the odometry's `child_frame_id`, or the first child of
    /// `odom_frame` in `/tf`.
    pub base_frame: Option<String>,
    /// ROS odometry frame in `/tf`; unset: `odom`.
    pub odom_frame: Option<String>,
    /// ROS topic of `sensor_msgs/Imu` whose yaw replaces the odometry's turning (its
    /// translation is kept); unset: no IMU.
    pub imu_topic: Option<String>,
    /// ROS beam angles: `auto` (CARMEN geometry for bags converted from CARMEN logs, else as
    /// recorded), `as_recorded`, `carmen`.
    pub beam_geometry: BeamGeometry,
    /// Readings at or above this range (m) mean "no return"; unset: 50 m for CARMEN logs and
    /// CARMEN-converted bags, else each scan's own maximum.
    pub range_max_m: Option<f32>,
    /// The laser of a CARMEN log: `front` (FLASER, else ROBOTLASER1) or `rear` (RLASER).
    pub carmen_laser: CarmenLaser,
    /// A malformed line is an error naming the file and line, instead of a counted drop.
    pub strict: bool,
    /// Only the part of the recording from this many seconds after its first scan.
    pub start_s: Option<f64>,
    /// Only the part of the recording up to this many seconds after its first scan.
    pub end_s: Option<f64>,
    /// Added to every odometry stamp (s) before use, for odometry stamped early (positive)
    /// or late against the scans. Unset: the run measures the odometry's lag from its
    /// filter's yaw corrections and, where the lag is notable, runs the filter again on the
    /// odometry shifted by it (`summary.json` `odometry_timing`); 0 turns that off.
    pub odometry_shift_s: Option<f64>,
}

impl ReaderOptions {
    /// Checks the values; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if self
            .range_max_m
            .is_some_and(|r| !(r.is_finite() && r > 0.0))
        {
            return Err("input.range_max_m must be finite and > 0".into());
        }
        for (k, v) in [("start_s", self.start_s), ("end_s", self.end_s)] {
            if v.is_some_and(|s| !(s.is_finite() && s >= 0.0)) {
                return Err(format!("input.{k} must be finite and >= 0"));
            }
        }
        check_odometry_shift(self.odometry_shift_s)?;
        if let (Some(a), Some(b)) = (self.start_s, self.end_s)
            && a >= b
        {
            return Err("input: start_s must be below end_s".into());
        }
        Ok(())
    }
}

/// Which beam angles the scans get (see `pfslam_io::ros_assemble`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BeamGeometry {
    /// CARMEN geometry for scans converted from CARMEN logs, else as recorded.
    #[default]
    Auto,
    /// As recorded in each message.
    AsRecorded,
    /// Always the CARMEN convention (-90 deg + i * 1 deg or 0.5 deg).
    Carmen,
}

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
