//! A recording file run as `pfslam run FILE` runs it, for callers other than the CLI (the
//! Python package): read with the configuration's `[input]`, odometry from the scans alone
//! when the file has none, the odometry anchored at its ground truth when it has one, then
//! the incremental API's driver loop ([`Slam::with_recording`]) with the default options.
//!
//! Directories of the car's or the humanoid's layout are the CLI's (`pfslam run DIR`); a
//! rosbag2 directory is read as its `.mcap` file.

use crate::config::{Config, OptionError};
use crate::filter::slam::anchor_odometry_to_ground_truth;
use crate::io::account::InputAccount;
use crate::io::recording::{Opened, ReadError, open_recording};
use crate::map::MapError;
use crate::online::{OnlineError, Slam};
use crate::pipeline::{PipelineOptions, PipelineResult, ensure_odometry};
use crate::sensors::Recording;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What [`run_file`] read and produced.
#[derive(Debug)]
pub struct FileRun {
    /// The recording as the filter saw it (odometry anchored when `anchored`).
    pub recording: Recording,
    /// What the reader read, kept, dropped and repaired.
    pub account: InputAccount,
    /// Wall seconds spent reading.
    pub load_s: f64,
    /// Whether the odometry starts at the ground truth's first pose.
    pub anchored: bool,
    /// The filter, back end and final map.
    pub pipeline: PipelineResult,
}

/// Errors of loading a recording file.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// Nothing at the path.
    #[error("{}: no such file or directory", path.display())]
    Missing {
        /// The path given.
        path: PathBuf,
    },
    /// The reader failed.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The odometry of the scans alone failed (a recording without odometry).
    #[error(transparent)]
    LidarOdometry(#[from] MapError),
}

/// Errors of [`run_file`]: the configuration, the loading or the pipeline.
#[derive(Debug, thiserror::Error)]
pub enum RunFileError {
    /// A configuration value is out of range.
    #[error(transparent)]
    Config(#[from] OptionError),
    /// The file could not be loaded.
    #[error("loading {}", path.display())]
    Load {
        /// The file.
        path: PathBuf,
        /// Why.
        source: LoadError,
    },
    /// The filter or the back end failed.
    #[error(transparent)]
    Slam(#[from] OnlineError),
}

/// Reads `path` as `pfslam run` does: `config.input` selects topics and the span; a
/// recording without odometry gets the odometry of its scans (LiDAR-only), recorded in the
/// account.
pub fn load_file(path: &Path, config: &Config) -> Result<Opened, LoadError> {
    if !path.exists() {
        return Err(LoadError::Missing {
            path: path.to_path_buf(),
        });
    }
    let mut opened = open_recording(path, &config.input)?;
    if ensure_odometry(&mut opened.recording)? {
        opened.account.odometry_source = "scan matching of the scans alone (LiDAR-only)".into();
        opened.account.odometry_kept = opened.recording.odometry.len();
    }
    Ok(opened)
}

/// Checks `config`, loads `path` ([`load_file`]), anchors its odometry at its ground truth
/// and runs the pipeline with `seed`: the trajectory `pfslam run FILE --seed SEED` writes.
pub fn run_file(path: &Path, config: &Config, seed: u64) -> Result<FileRun, RunFileError> {
    config.validate()?;
    let t_load = Instant::now();
    let Opened {
        mut recording,
        account,
    } = load_file(path, config).map_err(|source| RunFileError::Load {
        path: path.to_path_buf(),
        source,
    })?;
    let load_s = t_load.elapsed().as_secs_f64();
    // With ground truth, start at the true pose so maps and paths overlay without alignment.
    let anchored = anchor_odometry_to_ground_truth(&mut recording);
    let slam = Slam::with_recording(config.clone(), recording, seed)?;
    let (pipeline, recording) = slam.finish_observed(&PipelineOptions::default(), &mut |_| {})?;
    Ok(FileRun {
        recording,
        account,
        load_s,
        anchored,
        pipeline,
    })
}
