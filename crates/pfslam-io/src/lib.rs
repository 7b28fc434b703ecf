//! # pfslam-io — pfslam's file formats
//!
//! Readers and writers of every format pfslam handles, on top of the `pfslam` library (which
//! knows no file format):
//!
//! - [`ucsd`]: the car's dataset layout (encoder, FOG and LiDAR CSVs, calibration files,
//!   stereo image folders); [`humanoid`]: the humanoid's layout.
//! - [`carmen`]: CARMEN logs (`.clf`, `.log`, gzipped), read whole or line by line as they
//!   arrive, and written.
//! - [`ros1`] (ROS 1 bags), [`mcap`] (ROS 2 MCAP), decoded by [`ros_msgs`] and assembled into
//!   recordings by [`ros_assemble`]; [`recording`] opens any of them by magic bytes or name;
//!   [`options`] holds their `[input]` options; [`account`] counts what each reader read,
//!   kept, dropped and repaired; [`clock`] repairs their timestamps.
//! - [`tum`]: TUM trajectories; [`relations`]: the Freiburg `.relations` files of the
//!   relations metric; [`map_files`]: map_server maps (`.pgm` + `.yaml`); [`opencv_yaml`]:
//!   OpenCV calibration YAML.
//! - [`run_file`](mod@run_file): a path opened as a dataset (recording file, rosbag2
//!   directory, car or humanoid directory) and run through the pipeline.
//! - [`stereo_dataset`]: texture mapping of a car dataset's stereo pairs (with
//!   `pfslam-stereo`).
//!
//! Every reader reports malformed input as an [`IoError`] naming the file, the line (1-based)
//! and the problem; every writer writes to a temporary file in the target directory and renames
//! it into place ([`write_atomic`]), so a failed or interrupted run leaves no half-written file.
//! Those shared helpers are the core's (`pfslam::files`), re-exported here.
#![deny(missing_docs)]
// `unsafe` only in `kernels` (allowed there), each block with a `// SAFETY:` comment.
#![deny(unsafe_code)]
#![warn(clippy::undocumented_unsafe_blocks)]

pub mod account;
pub mod carmen;
pub mod clock;
pub mod humanoid;
#[allow(unsafe_code)]
mod kernels;
pub mod map_files;
pub mod mcap;
pub mod opencv_yaml;
pub mod options;
pub mod recording;
pub mod relations;
pub mod ros1;
pub mod ros_assemble;
pub mod ros_msgs;
pub mod run_file;
pub mod stereo_dataset;
pub mod tum;
pub mod ucsd;

pub use pfslam::files::{
    IoError, data_root, parse_finite_f64, parse_i64, write_atomic, write_bytes_atomic,
};
pub use run_file::{FileRun, RunFileError, run_file};
