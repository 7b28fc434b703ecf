//! The seed car's dataset layout (UCSD ECE276A / KAIST Complex Urban):
//!
//! ```text
//! DIR/sensor_data/encoder.csv   timestamp_ns,left_count,right_count   (cumulative ticks)
//! DIR/sensor_data/fog.csv       timestamp_ns,delta_roll,delta_pitch,delta_yaw   (rad)
//! DIR/sensor_data/lidar.csv     timestamp_ns,r_0,...,r_285   (m; 0.0 = no return)
//! DIR/param/...                 calibration (see [`calib`])
//! DIR/stereo_images/stereo_left/<stamp_ns>.png, stereo_right/<stamp_ns>.png   (optional)
//! ```
//!
//! The CSV readers stream: 1 MiB blocks read into one reused buffer, lines found there with
//! `memchr` and parsed in place, fields split by hand and parsed with `fast-float2`, ranges
//! stored as `f32` in a flat [`ScanSet`]. The LiDAR rows' plain decimals take a vector parser
//! first (`ranges`), with the scalar one as the fallback for anything else. The text is never
//! held in memory. A header line whose first field mentions "time" is skipped. Every
//! malformed row is an [`IoError::Parse`] naming file and line.

pub mod calib;
mod lidar;
mod lines;
mod odometry;
#[cfg(test)]
mod tests;
mod write;

pub use calib::{read_car_calibration, write_car_calibration};
pub use lidar::*;
use lines::*;
pub use odometry::*;
pub use write::*;

use crate::kernels::ranges;
use ranges::small_decimal_f32;

use super::{IoError, write_atomic};
use pfslam::sensors::{CarDataset, EncoderParams, EncoderSample, FogSample, ScanSet};
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};

/// What to do with timestamps that do not increase strictly.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TimestampPolicy {
    /// A timestamp that is not later than the previous row's is an error naming the line.
    #[default]
    Reject,
    /// Rows are stably sorted by time with a warning; rows with a repeated stamp are merged
    /// (FOG: increments summed) or dropped (encoder, LiDAR: the first row is kept).
    SortWithWarning,
}

/// Options of [`read_car_dataset`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReadOptions {
    /// Non-increasing timestamps: reject (default) or sort with a warning.
    pub timestamp_policy: TimestampPolicy,
    /// Encoder rows implying a wheel faster than this (m/s) are a count jump (error).
    pub max_wheel_speed_mps: f64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            timestamp_policy: TimestampPolicy::Reject,
            // A car; far above anything it drives, far below a corrupted count.
            max_wheel_speed_mps: 60.0,
        }
    }
}

/// `sensor_data/encoder.csv` relative to a dataset directory.
pub const ENCODER_CSV: &str = "sensor_data/encoder.csv";
/// `sensor_data/fog.csv`.
pub const FOG_CSV: &str = "sensor_data/fog.csv";
/// `sensor_data/lidar.csv`.
pub const LIDAR_CSV: &str = "sensor_data/lidar.csv";
/// `param/`.
pub const PARAM_DIR: &str = "param";
/// `stereo_images/stereo_left/`.
pub const STEREO_LEFT_DIR: &str = "stereo_images/stereo_left";
/// `stereo_images/stereo_right/` (same file names as the left images).
pub const STEREO_RIGHT_DIR: &str = "stereo_images/stereo_right";

/// Stamps of the stereo pairs: `stereo_images/stereo_left/<stamp_ns>.png`, sorted. No folder
/// means no stereo.
pub fn read_stereo_stamps(dir: &Path) -> Result<Vec<i64>, IoError> {
    let left = dir.join(STEREO_LEFT_DIR);
    if !left.is_dir() {
        return Ok(Vec::new());
    }
    let mut stamps = Vec::new();
    for entry in std::fs::read_dir(&left).map_err(|e| IoError::io(&left, e))? {
        let entry = entry.map_err(|e| IoError::io(&left, e))?;
        let p = entry.path();
        if p.extension().and_then(|e| e.to_str()) != Some("png") {
            continue;
        }
        let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        let stamp: i64 = stem.parse().map_err(|_| {
            IoError::parse(
                &p,
                0,
                "stereo image name is not a timestamp in ns (<stamp_ns>.png)",
            )
        })?;
        stamps.push(stamp);
    }
    stamps.sort_unstable();
    Ok(stamps)
}

/// Reads a whole dataset directory: calibration, the three CSVs, stereo stamps.
pub fn read_car_dataset(dir: &Path, opts: &ReadOptions) -> Result<CarDataset, IoError> {
    if !dir.is_dir() {
        return Err(IoError::Missing {
            path: dir.to_path_buf(),
            what: "dataset directory (sensor_data/, param/)".to_string(),
        });
    }
    let calibration = read_car_calibration(&dir.join(PARAM_DIR))?;
    // The LiDAR file (the largest) is parsed beside the two others; the first error in the
    // order encoder, FOG, LiDAR is reported, whichever thread finished first.
    let ((encoder, fog), lidar) = rayon::join(
        || {
            (
                read_encoder_csv(&dir.join(ENCODER_CSV), &calibration.encoder, opts),
                read_fog_csv(&dir.join(FOG_CSV), opts),
            )
        },
        || read_lidar_csv(&dir.join(LIDAR_CSV), calibration.lidar.beam_count, opts),
    );
    let (encoder, fog, lidar) = (encoder?, fog?, lidar?);
    let stereo_stamps_ns = read_stereo_stamps(dir)?;
    Ok(CarDataset {
        calibration,
        encoder,
        fog,
        lidar,
        stereo_stamps_ns,
    })
}
