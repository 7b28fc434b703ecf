//! What the map-insertion profiling examples share: a car-layout dataset read as a recording
//! with its ground-truth trajectory.

use pfslam::config::Config;
use pfslam::geometry::Trajectory;
use pfslam::sensors::Recording;
use pfslam_io::ucsd::{ReadOptions, read_car_dataset};
use std::path::Path;

/// The recording of the car-layout dataset in `dir` and its poses
/// (`dir/ground_truth.tum`). The dataset is dropped before the poses are read, so its other
/// sensors do not stay in memory beside the recording.
pub fn car_recording_at_truth(
    dir: &Path,
    config: &Config,
) -> Result<(Recording, Trajectory), Box<dyn std::error::Error>> {
    let mut ds = read_car_dataset(dir, &ReadOptions::default())?;
    let rec = pfslam::motion::car_recording_taking_scans(&mut ds, &config.motion, "d")?;
    drop(ds);
    let truth = Trajectory::new(pfslam_io::tum::read_tum(&dir.join("ground_truth.tum"))?.poses);
    Ok((rec, truth))
}
