//! Analytic rendering of a textured ground plane (world z = 0) into the car's raw stereo pair
//! (distorted, Bayer-mosaiced), with the exact disparity: the reference scene of the stereo
//! tests and the seed of the simulator's camera.

use super::StereoError;
use super::image::{BayerPattern, GrayImage};
use super::rectify::{DistortedCamera, RectifiedGeometry, StereoRectifier};
use crate::geometry::{Pose2, Rigid3};
use crate::sensors::StereoCalibration;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Poses of both raw cameras in the body frame, derived from the calibration: the left is
/// `body_from_camera`; the right sits one baseline along the rectified x axis, rotated by its
/// own rectification.
pub fn raw_camera_mounts(calib: &StereoCalibration) -> Result<(Rigid3, Rigid3), StereoError> {
    let rect = StereoRectifier::new(calib)?;
    let rr = Matrix3::from_row_slice(&calib.right.rectification);
    let right = rect
        .geometry
        .body_from_rectified
        .compose(&Rigid3 {
            rotation: Matrix3::identity(),
            translation: Vector3::new(calib.baseline_m, 0.0, 0.0),
        })
        .compose(&Rigid3 {
            // R maps raw right camera coordinates into the rectified right frame.
            rotation: rr,
            translation: Vector3::zeros(),
        });
    Ok((calib.body_from_camera, right))
}

/// Where the ray from `origin` along `dir` meets the plane z = 0 (only forward hits).
#[inline]
fn hit_ground(origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<(f64, f64)> {
    if dir.z >= -1e-9 {
        return None;
    }
    let s = -origin.z / dir.z;
    (s > 0.0).then(|| (origin.x + s * dir.x, origin.y + s * dir.y))
}

/// Renders one raw Bayer frame of the camera `world_from_camera` (intrinsics and distortion of
/// `camera`) looking at the ground `ground(x, y) -> rgb (0..255)`; rays that miss the ground
/// take `sky`. Each pixel averages `supersample x supersample` rays.
#[allow(clippy::too_many_arguments)]
pub fn render_ground_frame<F>(
    camera: &DistortedCamera,
    width: usize,
    height: usize,
    world_from_camera: &Rigid3,
    ground: &F,
    sky: [f64; 3],
    supersample: usize,
    pattern: BayerPattern,
) -> GrayImage
where
    F: Fn(f64, f64) -> [f64; 3] + Sync,
{
    let n = supersample.max(1);
    let mut out = GrayImage::new(width, height);
    out.data
        .par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            for (u, o) in row.iter_mut().enumerate() {
                let c = pattern.channel(u, v);
                let mut acc = 0.0;
                for j in 0..n {
                    for i in 0..n {
                        let su = u as f64 - 0.5 + (i as f64 + 0.5) / n as f64;
                        let sv = v as f64 - 0.5 + (j as f64 + 0.5) / n as f64;
                        let dir = world_from_camera.rotation * camera.unproject(su, sv);
                        acc += match hit_ground(&world_from_camera.translation, &dir) {
                            Some((x, y)) => ground(x, y)[c],
                            None => sky[c],
                        };
                    }
                }
                *o = (acc / (n * n) as f64).round().clamp(0.0, 255.0) as u8;
            }
        });
    out
}

/// Renders the raw (left, right) Bayer pair of the rig at `world_from_body`.
pub fn render_ground_pair<F>(
    calib: &StereoCalibration,
    world_from_body: &Pose2,
    ground: &F,
    sky: [f64; 3],
    supersample: usize,
    pattern: BayerPattern,
) -> Result<(GrayImage, GrayImage), StereoError>
where
    F: Fn(f64, f64) -> [f64; 3] + Sync,
{
    let (body_from_left, body_from_right) = raw_camera_mounts(calib)?;
    let world_from_body = Rigid3::from_pose2(world_from_body);
    let (w, h) = (calib.left.width as usize, calib.left.height as usize);
    let left = render_ground_frame(
        &DistortedCamera::from_info(&calib.left)?,
        w,
        h,
        &world_from_body.compose(&body_from_left),
        ground,
        sky,
        supersample,
        pattern,
    );
    let right = render_ground_frame(
        &DistortedCamera::from_info(&calib.right)?,
        w,
        h,
        &world_from_body.compose(&body_from_right),
        ground,
        sky,
        supersample,
        pattern,
    );
    Ok((left, right))
}

/// The exact disparity (px) of the ground plane z = 0 at each left rectified pixel seen from
/// `world_from_body` (NaN where the ray misses the ground).
pub fn ground_disparity(geometry: &RectifiedGeometry, world_from_body: &Pose2) -> Vec<f32> {
    let k = &geometry.intrinsics;
    let world_from_rect =
        Rigid3::from_pose2(world_from_body).compose(&geometry.body_from_rectified);
    let rect_from_world = world_from_rect.inverse();
    let mut out = vec![f32::NAN; k.width * k.height];
    out.par_chunks_mut(k.width.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            for (u, o) in row.iter_mut().enumerate() {
                let ray = k.ray(u as f64, v as f64);
                let dir = world_from_rect.rotation * ray;
                if let Some((x, y)) = hit_ground(&world_from_rect.translation, &dir) {
                    let p_rect = rect_from_world.transform_point(&Vector3::new(x, y, 0.0));
                    *o = geometry.disparity_px(p_rect.z) as f32;
                }
            }
        });
    out
}
