//! # pfslam — particle-filter SLAM for 2-D LiDAR
//!
//! pfslam estimates where a robot drove and draws the map it saw: a log-odds occupancy grid
//! and its binary map.
//!
//! ## Use it incrementally
//!
//! [`Slam`] takes odometry and scans as they arrive and reports the pose after each scan;
//! [`Slam::finish`] runs the back end and returns the trajectory, the map and the
//! self-check. The [`online`] module shows a whole run;
//! `crates/pfslam/examples/incremental.rs` feeds a recording through it message by message.
//! [`pipeline::run_pipeline`] does the same over a whole [`sensors::Recording`].
//!
//! ## The pipeline (data flows one way)
//!
//! ```text
//!  sensors ──► motion ──► filter ◄──► map ──► eval
//!  (typed       (odometry   (particles,  (grid,     (metrics)
//!   streams)     models)     weights)     rays)
//! ```
//!
//! - [`sensors`] holds typed, timestamped measurements ([`sensors::CarDataset`],
//!   [`sensors::Recording`], the humanoid's [`sensors::humanoid::HumanoidDataset`])
//!   independent of any format, and the readers' `[input]` options
//!   ([`sensors::reader_options::ReaderOptions`]).
//! - [`files`] is what every reader and writer shares whatever the format: [`files::IoError`]
//!   naming file and line, atomic writes, number fields.
//! - [`motion`] turns wheel ticks and gyro increments (or odometry poses) into motion, with
//!   the noise models the particle filter samples from.
//! - [`map`] is the occupancy grid: [`map::MapLimits`] for world <-> cell, log-odds, ray
//!   insertion.
//! - [`matching`] holds the scan matchers, for every filter mode and the back end: a scan
//!   placed against a map (hit counts, likelihood fields, nearest occupied cells).
//! - [`filter`] is the particle filter (prediction, weighting by a scan matcher,
//!   resampling) and its options; [`slam`] runs it over a recording with a whole
//!   [`config::Config`] (the front ends fed one scan at a time, [`slam::run_slam`],
//!   [`slam::SlamResult`]).
//! - [`eval`] measures accuracy (ATE, RPE, the Kümmerle relations metric).
//!
//! [`config::Config`] gathers one options struct per component; each is one TOML section,
//! including those of the crates beside this one (`[sim]`: [`config::sim`], `[stereo]`:
//! [`config::stereo`]). The options structs and the components' building blocks sit below
//! `config`; what takes a whole `Config` ([`slam`], [`pipeline`], [`online`], [`session`])
//! sits above it.
//!
//! The recording and dataset formats (the car's CSV layout, calibration files, TUM
//! trajectories, CARMEN logs, ROS bags, MCAP, map files, relations files), opening a path as a
//! dataset and running it (`pfslam_io::run_file`) are the `pfslam-io` crate's; pictures of the results (map images, trajectory plots, MCAP run
//! records) are the `pfslam-viz` crate's; the simulator (worlds, vehicles, true maps, writing
//! simulated datasets) is `pfslam-sim`'s and stereo texture mapping (demosaicing,
//! rectification, disparity, ground colours) `pfslam-stereo`'s. All of them sit on top of this
//! one, which reads only its own files: the configuration and saved sessions ([`session`]).
//!
//! Conventions: frames in names (`world_from_body`), units in names (`range_m`, `yaw_rad`),
//! time as `i64` nanoseconds (`stamp_ns`), angles in radians, z up, yaw counter-clockwise.
#![deny(missing_docs)]
// `unsafe` only in `kernels` (allowed there), each block with a `// SAFETY:` comment.
#![deny(unsafe_code)]
#![warn(clippy::undocumented_unsafe_blocks)]

pub mod config;
pub mod eval;
pub mod files;
pub mod filter;
pub mod geometry;
pub mod graph;
#[allow(unsafe_code)]
pub mod kernels;
pub mod localize;
pub mod map;
pub mod matching;
pub mod motion;
pub mod online;
pub mod pipeline;
pub mod quality;
pub mod sensors;
pub mod session;
pub mod slam;

pub use config::Config;
pub use online::{OnlineError, ScanInput, SensorSetup, Slam, check_imu_yaw, check_odometry};
