//! Stereo texture mapping: the ground's colours from the car's stereo camera (or an RGB-D
//! camera) onto a grid.
//!
//! Pipeline: raw Bayer frames -> [`image::demosaic_into`] -> [`rectify::StereoRectifier`]
//! (undistort + rectify with the calibration's R and P) -> [`disparity::compute_disparity`]
//! (census block matching, left-right check, sub-pixel) -> 3-D points in the body frame ->
//! world frame with the pose at the image's stamp -> ground points coloured into a
//! [`texture::TextureMap`].

pub mod disparity;
pub mod image;
pub mod rectify;

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

pub use disparity::{DisparityMap, DisparityWorkspace, INVALID_DISPARITY, MatcherOptions};
pub use image::{BayerPattern, Demosaic, GrayImage, RgbImage};
pub use rectify::{PinholeIntrinsics, RectifiedGeometry, StereoRectifier};

/// Errors of the stereo pipeline.
#[derive(Debug, thiserror::Error)]
pub enum StereoError {
    /// An image could not be read, decoded or encoded.
    #[error("{path}: {message}")]
    Image {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// Image sizes do not fit together.
    #[error("image size: {0}")]
    Size(String),
    /// The calibration is unusable.
    #[error("calibration: {0}")]
    Calibration(String),
    /// Invalid options.
    #[error("stereo options: {0}")]
    Options(String),
    /// Writing an output failed.
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
}

/// Options of the stereo component (`[stereo]` in the configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StereoOptions {
    /// Colour filter layout of the raw frames (the car: `bggr`).
    pub bayer_pattern: BayerPattern,
    /// Demosaicing algorithm.
    pub demosaic: Demosaic,
    /// Block matcher.
    pub matcher: MatcherOptions,
    /// Texture grid cell size (m); 0 takes the occupancy map's resolution.
    pub cell_size_m: f64,
    /// Points below this world z (m) are not ground.
    pub ground_z_min_m: f64,
    /// Points above this world z (m) are not ground.
    pub ground_z_max_m: f64,
    /// Points farther than this along the optical axis (m) are dropped (depth error grows
    /// with the square of the distance).
    pub max_depth_m: f64,
    /// Use every n-th pixel in both directions when projecting (1 = all).
    pub pixel_stride: usize,
}

impl Default for StereoOptions {
    fn default() -> Self {
        StereoOptions {
            bayer_pattern: BayerPattern::UCSD,
            demosaic: Demosaic::MalvarHeCutler,
            matcher: MatcherOptions::default(),
            cell_size_m: 0.0,
            ground_z_min_m: -0.3,
            ground_z_max_m: 0.3,
            max_depth_m: 20.0,
            pixel_stride: 1,
        }
    }
}
