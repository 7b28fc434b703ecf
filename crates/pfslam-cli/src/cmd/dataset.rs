//! Loading a dataset from a path, whatever its format: the one place that knows layouts.
//!
//! - a directory with `sensor_data/` + `param/`: the seed car's layout (the simulator writes it
//!   too, with `ground_truth.tum` and `true_map.yaml` (+ `true_map_visible.yaml`) beside,
//!   which are picked up);
//! - a directory with `calibration.txt` + `odometry.csv`: the humanoid layout;
//! - a file: CARMEN log (`.clf`, `.log`, gzipped or not), ROS 1 bag, ROS 2 MCAP, detected by
//!   [`pfslam::io::recording::read_recording`].

use pfslam::config::Config;
use pfslam::geometry::Pose2;
use pfslam::io::account::InputAccount;
use pfslam::io::map_files::read_map_server;
use pfslam::io::recording::Opened;
use pfslam::io::tum::read_tum;
use pfslam::io::ucsd::{ReadOptions, TimestampPolicy, read_car_dataset};
use pfslam::map::{BinaryMap, MapComparison, compare_maps_aligned, compare_maps_visible_aligned};
use pfslam::sensors::{CarDataset, Recording};
use std::path::Path;

/// A loaded dataset: the recording and, for simulator output, the true map.
pub struct Dataset {
    /// The recording (ground truth included when known).
    pub recording: Recording,
    /// The true occupancy map, when the dataset has one.
    pub true_map: Option<TrueMaps>,
    /// The raw car streams, for a car-layout dataset (without the LiDAR scans, which moved
    /// into `recording`).
    pub car: Option<CarDataset>,
    /// What the reader read, kept, dropped and repaired.
    pub account: InputAccount,
}

/// The layouts a directory is looked up as, for the error when it is none of them.
pub const DIRECTORY_LAYOUTS: &str = "the car's layout (sensor_data/{encoder,fog,lidar}.csv + \
     param/), the humanoid's layout (calibration.txt + odometry.csv), a rosbag2 directory \
     (metadata.yaml + one .mcap)";

/// Loads `path` as a [`Dataset`].
pub fn load_dataset(
    path: &Path,
    config: &Config,
    sort_timestamps: bool,
) -> anyhow::Result<Dataset> {
    let name = path
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".into());
    if !path.exists() {
        anyhow::bail!("{}: no such file or directory", path.display());
    }
    if path.is_dir() && !path.join("metadata.yaml").is_file() {
        let humanoid = path.join(pfslam::io::humanoid::CALIBRATION_FILE).is_file()
            && path.join(pfslam::io::humanoid::ODOMETRY_CSV).is_file();
        let car_layout = path.join("sensor_data").is_dir() || path.join("param").is_dir();
        if !humanoid && !car_layout {
            anyhow::bail!(
                "{}: a directory of no known layout; looked for {DIRECTORY_LAYOUTS}",
                path.display()
            );
        }
        let (mut recording, car) = if humanoid {
            let ds = pfslam::io::humanoid::read_humanoid_dataset(path)?;
            (pfslam::io::humanoid::humanoid_recording(&ds, &name), None)
        } else {
            let opts = ReadOptions {
                timestamp_policy: if sort_timestamps {
                    TimestampPolicy::SortWithWarning
                } else {
                    TimestampPolicy::Reject
                },
                ..ReadOptions::default()
            };
            let mut ds = read_car_dataset(path, &opts)?;
            // The scans move into the recording (`car.lidar` is left empty): no second copy.
            let rec = pfslam::motion::car_recording_taking_scans(&mut ds, &config.motion, &name)?;
            (rec, Some(ds))
        };
        let gt_path = path.join("ground_truth.tum");
        if gt_path.is_file() {
            recording.ground_truth = Some(read_tum(&gt_path)?.poses);
        }
        let map_path = path.join("true_map.yaml");
        let true_map = if map_path.is_file() {
            Some(TrueMaps::read(&map_path)?)
        } else {
            None
        };
        let account = directory_account(path, &recording, car.as_ref());
        let mut opened = Opened { recording, account };
        opened.keep_span(config.input.start_s, config.input.end_s);
        return Ok(Dataset {
            recording: opened.recording,
            true_map,
            car,
            account: opened.account,
        });
    }
    let Opened { recording, account } = pfslam::run_file::load_file(path, config)?;
    Ok(Dataset {
        recording,
        true_map: None,
        car: None,
        account,
    })
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

/// A true map (map_server yaml) and, when a `<stem>_visible.yaml` lies beside it (the
/// simulator's scan-surface truth, see `pfslam::sim::scan_truth`), its visibility raster.
pub struct TrueMaps {
    /// Occupancy truth: precision is counted against it.
    pub occupancy: BinaryMap,
    /// Visible surfaces (occupied) and passed-free cells (free): recall and free agreement.
    pub visible: Option<BinaryMap>,
}

impl TrueMaps {
    /// Reads `path` and its `_visible` sibling when present.
    pub fn read(path: &Path) -> anyhow::Result<TrueMaps> {
        let occupancy = read_map_server(path)?;
        let stem = path.file_stem().unwrap_or_default().to_string_lossy();
        let sibling = path.with_file_name(format!("{stem}_visible.yaml"));
        let visible = if sibling.is_file() {
            Some(read_map_server(&sibling)?)
        } else {
            None
        };
        Ok(TrueMaps { occupancy, visible })
    }

    /// Compares an estimate (`compare_maps_visible` with a visibility raster, else
    /// `compare_maps`).
    pub fn compare(
        &self,
        estimate: &BinaryMap,
        tolerance_cells: u32,
    ) -> anyhow::Result<MapComparison> {
        self.compare_aligned(estimate, tolerance_cells, &Pose2::IDENTITY)
    }

    /// [`Self::compare`] with the estimate moved by `truth_from_estimate` (a SLAM map
    /// through its trajectory's SE(2) alignment onto the ground truth).
    pub fn compare_aligned(
        &self,
        estimate: &BinaryMap,
        tolerance_cells: u32,
        truth_from_estimate: &Pose2,
    ) -> anyhow::Result<MapComparison> {
        Ok(match &self.visible {
            Some(v) => compare_maps_visible_aligned(
                estimate,
                &self.occupancy,
                v,
                tolerance_cells,
                truth_from_estimate,
            )?,
            None => compare_maps_aligned(
                estimate,
                &self.occupancy,
                tolerance_cells,
                truth_from_estimate,
            )?,
        })
    }
}
