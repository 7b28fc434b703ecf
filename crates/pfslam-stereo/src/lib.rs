//! # pfslam-stereo — the ground's colours from stereo pairs
//!
//! Stereo texture mapping on top of the `pfslam` library: the ground's colours from the car's
//! stereo camera (or an RGB-D camera) onto a grid.
//!
//! Pipeline: raw Bayer frames -> [`image::demosaic_into`] -> [`rectify::StereoRectifier`]
//! (undistort + rectify with the calibration's R and P) -> [`disparity::compute_disparity`]
//! (census block matching, left-right check, sub-pixel) -> 3-D points in the body frame ->
//! world frame with the pose at the image's stamp -> ground points coloured into a
//! [`texture::TextureMap`].
//!
//! [`render`] draws what a shading function sees into the rig's raw pair, with the exact
//! disparity (the analytic ground plane here; the simulator's worlds in `pfslam-sim`). The
//! options ([`StereoOptions`], `[stereo]` in the configuration) are declared in
//! `pfslam::config::stereo` so the library's `Config` holds them, and re-exported here.
#![deny(missing_docs)]

pub mod disparity;
pub mod ground;
pub mod image;
pub mod rectify;
pub mod render;
pub mod texture;

use std::path::PathBuf;

pub use pfslam::config::stereo::{StereoOptionError, StereoOptions};

pub use disparity::{DisparityMap, DisparityWorkspace, INVALID_DISPARITY, MatcherOptions};
pub use ground::{ColouredPoint, PlaneFit, RgbdCamera, fit_plane_ransac};
pub use image::{BayerPattern, Demosaic, GrayImage, RgbImage};
pub use rectify::{PinholeIntrinsics, RectifiedGeometry, StereoRectifier};
pub use texture::{CellColour, TextureMap};

use pfslam::geometry::{Pose2, Rigid3};
use pfslam::sensors::StereoCalibration;

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
    Io(#[from] pfslam::files::IoError),
}

impl From<StereoOptionError> for StereoError {
    fn from(e: StereoOptionError) -> Self {
        match e {
            StereoOptionError::Options(m) => StereoError::Options(m),
            StereoOptionError::Size(m) => StereoError::Size(m),
        }
    }
}

/// The whole stereo chain for one rig, with every buffer owned and reused across pairs.
#[derive(Debug, Clone)]
pub struct StereoPipeline {
    options: StereoOptions,
    rectifier: StereoRectifier,
    workspace: DisparityWorkspace,
    raw_left: RgbImage,
    raw_right: RgbImage,
    rect_left: RgbImage,
    rect_right: RgbImage,
    gray_left: GrayImage,
    gray_right: GrayImage,
    disparity: DisparityMap,
    points: Vec<ColouredPoint>,
}

impl StereoPipeline {
    /// Builds the rectification tables of the rig and checks the options.
    pub fn new(
        calibration: &StereoCalibration,
        options: &StereoOptions,
    ) -> Result<Self, StereoError> {
        options.validate(calibration.left.width as usize)?;
        Ok(StereoPipeline {
            options: options.clone(),
            rectifier: StereoRectifier::new(calibration)?,
            workspace: DisparityWorkspace::new(),
            raw_left: RgbImage::default(),
            raw_right: RgbImage::default(),
            rect_left: RgbImage::default(),
            rect_right: RgbImage::default(),
            gray_left: GrayImage::default(),
            gray_right: GrayImage::default(),
            disparity: DisparityMap::default(),
            points: Vec::new(),
        })
    }

    /// The rectified geometry (intrinsics, baseline, mount).
    pub fn geometry(&self) -> &RectifiedGeometry {
        &self.rectifier.geometry
    }

    /// Demosaics, rectifies and matches a pair of raw Bayer frames.
    pub fn process_raw_pair(
        &mut self,
        left: &GrayImage,
        right: &GrayImage,
    ) -> Result<(), StereoError> {
        let geometry = &self.rectifier.geometry.intrinsics;
        for img in [left, right] {
            if img.width != geometry.width || img.height != geometry.height {
                return Err(StereoError::Size(format!(
                    "frame is {}x{}, the calibration says {}x{}",
                    img.width, img.height, geometry.width, geometry.height
                )));
            }
        }
        let (pattern, method) = (self.options.bayer_pattern, self.options.demosaic);
        image::demosaic_into(left, pattern, method, &mut self.raw_left)?;
        image::demosaic_into(right, pattern, method, &mut self.raw_right)?;
        self.rectifier
            .left
            .remap_rgb_into(&self.raw_left, &mut self.rect_left);
        self.rectifier
            .right
            .remap_rgb_into(&self.raw_right, &mut self.rect_right);
        self.rect_left.to_gray_into(&mut self.gray_left);
        self.rect_right.to_gray_into(&mut self.gray_right);
        disparity::compute_disparity(
            &self.gray_left,
            &self.gray_right,
            &self.options.matcher,
            &mut self.workspace,
            &mut self.disparity,
        )
    }

    /// The disparity of the last pair (left rectified image).
    pub fn disparity(&self) -> &DisparityMap {
        &self.disparity
    }

    /// The last left rectified colour image.
    pub fn rectified_left(&self) -> &RgbImage {
        &self.rect_left
    }

    /// The last right rectified colour image.
    pub fn rectified_right(&self) -> &RgbImage {
        &self.rect_right
    }

    /// The last pair's coloured points in the frame `frame_from_body` maps into (identity: the
    /// body frame), within `max_depth_m`, every `pixel_stride`-th pixel.
    pub fn points(&mut self, frame_from_body: &Rigid3) -> &[ColouredPoint] {
        self.points.clear();
        let frame_from_rectified =
            frame_from_body.compose(&self.rectifier.geometry.body_from_rectified);
        ground::disparity_to_points(
            &self.disparity,
            &self.rect_left,
            &self.rectifier.geometry,
            &frame_from_rectified,
            self.options.max_depth_m,
            self.options.pixel_stride,
            &mut self.points,
        );
        &self.points
    }

    /// Adds the last pair's ground points (world z in the options' window), seen from
    /// `world_from_body`, to `map`; returns how many points were added.
    pub fn accumulate(&mut self, world_from_body: &Pose2, map: &mut TextureMap) -> usize {
        let (z0, z1) = (self.options.ground_z_min_m, self.options.ground_z_max_m);
        let pts = self.points(&Rigid3::from_pose2(world_from_body));
        map.add_ground_points(pts, z0, z1)
    }
}

/// One RGB-D frame with its camera, mount and pose.
#[derive(Debug, Clone, Copy)]
pub struct RgbdFrame<'a> {
    /// Depth (m, row-major, registered to `camera.depth`).
    pub depth_m: &'a [f32],
    /// The colour image.
    pub colour: &'a RgbImage,
    /// The camera's intrinsics and the colour camera's place.
    pub camera: &'a RgbdCamera,
    /// The depth camera's mount on the body.
    pub body_from_depth: &'a Rigid3,
    /// The body's pose in the world.
    pub world_from_body: &'a Pose2,
}

/// Adds an RGB-D frame's ground points to `map`. Returns how many points were added.
pub fn accumulate_rgbd(
    frame: &RgbdFrame<'_>,
    options: &StereoOptions,
    points: &mut Vec<ColouredPoint>,
    map: &mut TextureMap,
) -> usize {
    let RgbdFrame {
        depth_m,
        colour,
        camera,
        body_from_depth,
        world_from_body,
    } = *frame;
    points.clear();
    let world_from_depth = Rigid3::from_pose2(world_from_body).compose(body_from_depth);
    ground::depth_to_points(
        depth_m,
        colour,
        camera,
        &world_from_depth,
        options.max_depth_m,
        options.pixel_stride,
        points,
    );
    map.add_ground_points(points, options.ground_z_min_m, options.ground_z_max_m)
}
