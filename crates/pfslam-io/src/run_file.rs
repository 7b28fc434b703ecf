//! A recording file run as `pfslam run FILE` runs it, for callers other than the CLI (the
//! Python package): read with the configuration's `[input]`, odometry from the scans alone
//! when the file has none, the odometry anchored at its ground truth when it has one, then
//! the incremental API's driver loop ([`Slam::with_recording`]) with the default options.
//!
//! [`load_path`] reads any dataset `pfslam run` reads: a recording file, a rosbag2
//! directory (as its `.mcap` file), or a directory of the car's or the humanoid's layout
//! (with the simulator's `ground_truth.tum` when it lies beside).

use crate::IoError;
use crate::account::InputAccount;
use crate::recording::{Opened, ReadError, open_recording};
use crate::tum::read_tum;
use crate::ucsd::{ReadOptions, TimestampPolicy, read_car_dataset};
use pfslam::config::{Config, OptionError};
use pfslam::map::MapError;
use pfslam::motion::MotionError;
use pfslam::online::{OnlineError, Slam};
use pfslam::pipeline::{PipelineOptions, PipelineResult, ensure_odometry};
use pfslam::sensors::CarDataset;
use pfslam::sensors::Recording;
use pfslam::slam::anchor_odometry_to_ground_truth;
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
    /// A directory of no layout pfslam reads.
    #[error("{}: a directory of no known layout; looked for {DIRECTORY_LAYOUTS}", path.display())]
    Layout {
        /// The directory.
        path: PathBuf,
    },
    /// The reader failed.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// A directory's reader failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The car's dead reckoning failed.
    #[error(transparent)]
    Motion(#[from] MotionError),
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

/// The layouts a directory is looked up as, for the error when it is none of them.
pub const DIRECTORY_LAYOUTS: &str = "the car's layout (sensor_data/{encoder,fog,lidar}.csv + \
     param/), the humanoid's layout (calibration.txt + odometry.csv), a rosbag2 directory \
     (metadata.yaml + one .mcap)";

/// A dataset as read: the recording with its account and, for the car's layout, its raw
/// streams (without the scans, which moved into the recording).
#[derive(Debug)]
pub struct Loaded {
    /// The recording and its account.
    pub opened: Opened,
    /// The car's encoder, FOG and stereo streams, for the car's layout.
    pub car: Option<CarDataset>,
}

/// Reads `path` as `pfslam run` does (see the module docs): `config.input` selects topics and
/// the span, `config.motion` the car's dead reckoning; `sort_timestamps` sorts car CSV rows
/// that go back in time instead of refusing them. A recording without odometry gets the
/// odometry of its scans (LiDAR-only), recorded in the account.
pub fn load_path(path: &Path, config: &Config, sort_timestamps: bool) -> Result<Loaded, LoadError> {
    if !path.exists() {
        return Err(LoadError::Missing {
            path: path.to_path_buf(),
        });
    }
    if path.is_dir() && !path.join("metadata.yaml").is_file() {
        return load_directory(path, config, sort_timestamps);
    }
    let mut opened = open_recording(path, &config.input)?;
    if ensure_odometry(&mut opened.recording)? {
        opened.account.odometry_source = "scan matching of the scans alone (LiDAR-only)".into();
        opened.account.odometry_kept = opened.recording.odometry.len();
    }
    Ok(Loaded { opened, car: None })
}

/// [`load_path`] without the car's raw streams.
pub fn load_file(path: &Path, config: &Config) -> Result<Opened, LoadError> {
    Ok(load_path(path, config, false)?.opened)
}

/// A directory of the car's or the humanoid's layout.
fn load_directory(
    path: &Path,
    config: &Config,
    sort_timestamps: bool,
) -> Result<Loaded, LoadError> {
    let name = path
        .file_stem()
        .map_or_else(|| "dataset".into(), |n| n.to_string_lossy().into_owned());
    let humanoid = path.join(crate::humanoid::CALIBRATION_FILE).is_file()
        && path.join(crate::humanoid::ODOMETRY_CSV).is_file();
    let car_layout = path.join("sensor_data").is_dir() || path.join("param").is_dir();
    let (mut recording, car) = if humanoid {
        let ds = crate::humanoid::read_humanoid_dataset(path)?;
        (crate::humanoid::humanoid_recording(&ds, &name), None)
    } else if car_layout {
        let timestamp_policy = match sort_timestamps {
            true => TimestampPolicy::SortWithWarning,
            false => TimestampPolicy::Reject,
        };
        let opts = ReadOptions {
            timestamp_policy,
            ..ReadOptions::default()
        };
        let mut ds = read_car_dataset(path, &opts)?;
        // The scans move into the recording (`car.lidar` is left empty): no second copy.
        let rec = pfslam::motion::car_recording_taking_scans(&mut ds, &config.motion, &name)?;
        (rec, Some(ds))
    } else {
        return Err(LoadError::Layout {
            path: path.to_path_buf(),
        });
    };
    let gt_path = path.join("ground_truth.tum");
    if gt_path.is_file() {
        recording.ground_truth = Some(read_tum(&gt_path)?.poses);
    }
    let account = directory_account(path, &recording, car.as_ref());
    let mut opened = Opened { recording, account };
    opened.keep_span(config.input.start_s, config.input.end_s);
    Ok(Loaded { opened, car })
}

/// The account of a car or humanoid directory: their readers refuse bad rows, so every row
/// read is kept.
fn directory_account(path: &Path, rec: &Recording, car: Option<&CarDataset>) -> InputAccount {
    let (format, rows, source, mount) = match car {
        Some(c) => (
            "ucsd_car",
            c.encoder.len() + c.fog.len() + rec.scans.len(),
            "wheel encoders and FOG (dead reckoning)",
            "param/Vehicle2Lidar.txt",
        ),
        None => (
            "humanoid",
            rec.odometry.len() + rec.scans.len(),
            "odometry.csv",
            "calibration.txt and the head joints",
        ),
    };
    let mut a = InputAccount::new(format, path, "rows");
    a.records_read = rows;
    a.scans_read = rec.scans.len();
    a.scans_kept = rec.scans.len();
    a.odometry_read = rec.odometry.len();
    a.odometry_kept = rec.odometry.len();
    a.odometry_source = source.into();
    a.clock = "the files' stamps".into();
    a.mount_source = mount.into();
    for i in 0..rec.scans.len() {
        a.add_layout(rec.lidar_at(i));
    }
    a
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
