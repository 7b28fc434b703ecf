//! Texture mapping of a whole car dataset: every stereo pair of
//! `stereo_images/stereo_{left,right}/<stamp_ns>.png`, placed with a trajectory.

use crate::ucsd::{STEREO_LEFT_DIR, STEREO_RIGHT_DIR, read_stereo_stamps};
use pfslam::geometry::Trajectory;
use pfslam::map::MapLimits;
use pfslam::sensors::StereoCalibration;
use pfslam_stereo::image::load_gray_png;
use pfslam_stereo::{StereoError, StereoOptions, StereoPipeline, TextureMap};
use serde::Serialize;
use std::path::Path;

/// What [`texture_dataset`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct TextureStats {
    /// Pairs in the dataset.
    pub pairs_total: usize,
    /// Pairs matched and accumulated.
    pub pairs_used: usize,
    /// Pairs skipped: outside the trajectory's time span.
    pub pairs_without_pose: usize,
    /// Ground points added to the map.
    pub ground_points: usize,
}

/// Colours the ground with every `every`-th stereo pair of the dataset `dir`, each placed
/// with the trajectory's `world_from_body` at the pair's stamp (interpolated; pairs outside
/// the trajectory are skipped and counted). The map's grid is `limits`.
pub fn texture_dataset(
    dir: &Path,
    calibration: &StereoCalibration,
    poses: &Trajectory,
    options: &StereoOptions,
    limits: MapLimits,
    every: usize,
) -> Result<(TextureMap, TextureStats), StereoError> {
    if every == 0 {
        return Err(StereoError::Options("every must be >= 1".into()));
    }
    let stamps = read_stereo_stamps(dir)?;
    let mut pipeline = StereoPipeline::new(calibration, options)?;
    let mut texture = TextureMap::new(limits);
    let mut stats = TextureStats {
        pairs_total: stamps.len(),
        ..TextureStats::default()
    };
    let (left_dir, right_dir) = (dir.join(STEREO_LEFT_DIR), dir.join(STEREO_RIGHT_DIR));
    for &stamp in stamps.iter().step_by(every) {
        let Some(pose) = poses.pose_at(stamp) else {
            stats.pairs_without_pose += 1;
            continue;
        };
        let name = format!("{stamp}.png");
        let left = load_gray_png(&left_dir.join(&name))?;
        let right = load_gray_png(&right_dir.join(&name))?;
        pipeline
            .process_raw_pair(&left, &right)
            .map_err(|e| match e {
                StereoError::Size(m) => StereoError::Size(format!("{}: {m}", name)),
                other => other,
            })?;
        stats.ground_points += pipeline.accumulate(&pose, &mut texture);
        stats.pairs_used += 1;
    }
    Ok((texture, stats))
}
