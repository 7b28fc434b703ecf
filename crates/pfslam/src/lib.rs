//! # pfslam — particle-filter SLAM for 2-D LiDAR
//!
//! pfslam estimates where a robot drove and draws the map it saw: a log-odds occupancy grid,
//! its binary map and the ground colours seen by a stereo camera.
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
//!  io ──► sensors ──► motion ──► filter ◄──► map ──► eval
//!  (files)  (typed      (odometry   (particles,  (grid,     (metrics)
//!           streams)     models)     weights)     rays)
//!  sim: produces datasets with ground truth        stereo: image pairs -> ground colour
//! ```
//!
//! - [`io`] reads and writes every file format (the car's CSV layout, calibration files,
//!   TUM trajectories, CARMEN logs, ROS bags, MCAP, map files), atomically on write.
//! - [`sensors`] holds typed, timestamped measurements ([`sensors::CarDataset`],
//!   [`sensors::Recording`]) independent of any format.
//! - [`motion`] turns wheel ticks and gyro increments (or odometry poses) into motion, with
//!   the noise models the particle filter samples from.
//! - [`map`] is the occupancy grid: [`map::MapLimits`] for world <-> cell, log-odds, ray
//!   insertion.
//! - [`filter`] is the particle filter (prediction, map correlation, weights, resampling).
//! - [`eval`] measures accuracy (ATE, RPE, the Kümmerle relations metric).
//! - [`sim`] simulates the seed car and the humanoid in built-in or user worlds.
//! - [`stereo`] demosaics, rectifies and matches stereo pairs to colour the ground.
//!
//! [`config::Config`] gathers one options struct per component; each is one TOML section.
//!
//! Pictures of the results (map images, trajectory plots, MCAP run records) are the
//! `pfslam-viz` crate's, on top of this one.
//!
//! Conventions: frames in names (`world_from_body`), units in names (`range_m`, `yaw_rad`),
//! time as `i64` nanoseconds (`stamp_ns`), angles in radians, z up, yaw counter-clockwise.
#![deny(missing_docs)]

pub mod config;
pub mod eval;
pub mod filter;
pub mod geometry;
pub mod graph;
pub mod io;
pub mod localize;
pub mod map;
pub mod motion;
pub mod online;
pub mod pipeline;
pub mod quality;
pub mod run_file;
pub mod sensors;
pub mod session;
pub mod sim;
pub mod stereo;

pub use config::Config;
pub use online::{OnlineError, ScanInput, SensorSetup, Slam, check_imu_yaw, check_odometry};
pub use run_file::{FileRun, RunFileError, run_file};
