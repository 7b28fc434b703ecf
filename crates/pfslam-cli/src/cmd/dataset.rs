//! Loading a dataset from a path, whatever its format: the library's
//! [`pfslam_io::run_file::load_path`] (a recording file, a rosbag2 directory, the car's or the
//! humanoid's layout), and beside a simulator output its `true_map.yaml` (+
//! `true_map_visible.yaml`), which the CLI compares maps with.

use pfslam::config::Config;
use pfslam::geometry::Pose2;
use pfslam::map::{BinaryMap, MapComparison, compare_maps_aligned, compare_maps_visible_aligned};
use pfslam::sensors::{CarDataset, Recording};
use pfslam_io::account::InputAccount;
use pfslam_io::map_files::read_map_server;
use pfslam_io::run_file::{Loaded, load_path};
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

/// Loads `path` as a [`Dataset`] ([`pfslam_io::run_file::load_path`], and a simulator output's
/// true map beside it).
pub fn load_dataset(
    path: &Path,
    config: &Config,
    sort_timestamps: bool,
) -> anyhow::Result<Dataset> {
    let Loaded { opened, car } = load_path(path, config, sort_timestamps)?;
    let map_path = path.join("true_map.yaml");
    let true_map = match path.is_dir() && map_path.is_file() {
        true => Some(TrueMaps::read(&map_path)?),
        false => None,
    };
    Ok(Dataset {
        recording: opened.recording,
        true_map,
        car,
        account: opened.account,
    })
}

/// A true map (map_server yaml) and, when a `<stem>_visible.yaml` lies beside it (the
/// simulator's scan-surface truth, see `pfslam_sim::scan_truth`), its visibility raster.
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
