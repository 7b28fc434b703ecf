//! Rendering into the car's raw stereo pair (distorted, Bayer-mosaiced) of whatever a shading
//! function sees along each ray, with the exact disparity; analytically for a textured ground
//! plane (world z = 0). The simulator's camera renders its worlds through these.

use super::StereoError;
use super::image::{BayerPattern, GrayImage};
use super::rectify::{DistortedCamera, RectifiedGeometry, StereoRectifier};
use nalgebra::{Matrix3, Vector3};
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::sensors::StereoCalibration;
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
/// `camera`): `shade(origin, unit direction)` gives the colour (0..255) seen along a world ray.
/// Each pixel averages `supersample x supersample` rays.
pub fn render_frame<F>(
    camera: &DistortedCamera,
    (width, height): (usize, usize),
    world_from_camera: &Rigid3,
    shade: &F,
    supersample: usize,
    pattern: BayerPattern,
) -> GrayImage
where
    F: Fn(&Vector3<f64>, &Vector3<f64>) -> [f64; 3] + Sync,
{
    let n = supersample.max(1);
    let origin = world_from_camera.translation;
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
                        let dir =
                            (world_from_camera.rotation * camera.unproject(su, sv)).normalize();
                        acc += shade(&origin, &dir)[c];
                    }
                }
                *o = (acc / (n * n) as f64).round().clamp(0.0, 255.0) as u8;
            }
        });
    out
}

/// Renders the raw (left, right) Bayer pair of the rig at `world_from_body` (see
/// [`render_frame`]).
pub fn render_pair<F>(
    calib: &StereoCalibration,
    world_from_body: &Pose2,
    shade: &F,
    supersample: usize,
    pattern: BayerPattern,
) -> Result<(GrayImage, GrayImage), StereoError>
where
    F: Fn(&Vector3<f64>, &Vector3<f64>) -> [f64; 3] + Sync,
{
    let (body_from_left, body_from_right) = raw_camera_mounts(calib)?;
    let world_from_body = Rigid3::from_pose2(world_from_body);
    let size = (calib.left.width as usize, calib.left.height as usize);
    let mut frames = [
        (&calib.left, body_from_left),
        (&calib.right, body_from_right),
    ]
    .into_iter()
    .map(|(info, mount)| {
        Ok(render_frame(
            &DistortedCamera::from_info(info)?,
            size,
            &world_from_body.compose(&mount),
            shade,
            supersample,
            pattern,
        ))
    })
    .collect::<Result<Vec<_>, StereoError>>()?;
    let right = frames.pop().unwrap_or_default();
    let left = frames.pop().unwrap_or_default();
    Ok((left, right))
}

/// Renders the raw pair of the rig looking at the ground `ground(x, y) -> rgb` (plane z = 0);
/// rays that miss the ground take `sky`.
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
    let shade = |o: &Vector3<f64>, d: &Vector3<f64>| match hit_ground(o, d) {
        Some((x, y)) => ground(x, y),
        None => sky,
    };
    render_pair(calib, world_from_body, &shade, supersample, pattern)
}

/// The exact disparity (px) at each left rectified pixel seen from `world_from_body`, given
/// `range(origin, unit direction)`: the distance (m) to the first surface along a world ray
/// (NaN where it returns `None`).
pub fn true_disparity<F>(
    geometry: &RectifiedGeometry,
    world_from_body: &Pose2,
    range: &F,
) -> Vec<f32>
where
    F: Fn(&Vector3<f64>, &Vector3<f64>) -> Option<f64> + Sync,
{
    let k = &geometry.intrinsics;
    let world_from_rect =
        Rigid3::from_pose2(world_from_body).compose(&geometry.body_from_rectified);
    let mut out = vec![f32::NAN; k.width * k.height];
    out.par_chunks_mut(k.width.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            for (u, o) in row.iter_mut().enumerate() {
                let ray = k.ray(u as f64, v as f64);
                let dir = world_from_rect.rotation * ray;
                let norm = dir.norm();
                if let Some(r) = range(&world_from_rect.translation, &(dir / norm)) {
                    // The ray has unit depth along the rectified axis: depth = r / |ray|.
                    *o = geometry.disparity_px(r / norm) as f32;
                }
            }
        });
    out
}

/// The exact disparity of the ground plane z = 0 (NaN where the ray misses it).
pub fn ground_disparity(geometry: &RectifiedGeometry, world_from_body: &Pose2) -> Vec<f32> {
    let range = |o: &Vector3<f64>, d: &Vector3<f64>| {
        hit_ground(o, d).map(|(x, y)| (Vector3::new(x, y, 0.0) - o).norm())
    };
    true_disparity(geometry, world_from_body, &range)
}

/// Deterministic lattice hash in [0, 1).
#[inline]
pub fn hash01(ix: i64, iy: i64, seed: u64) -> f64 {
    let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Bilinear value noise on a lattice of step `step_m`, in [0, 1).
pub fn value_noise(x: f64, y: f64, step_m: f64, seed: u64) -> f64 {
    let (gx, gy) = (x / step_m, y / step_m);
    let (ix, iy) = (gx.floor() as i64, gy.floor() as i64);
    let (fx, fy) = (gx - ix as f64, gy - iy as f64);
    let a = hash01(ix, iy, seed);
    let b = hash01(ix + 1, iy, seed);
    let c = hash01(ix, iy + 1, seed);
    let d = hash01(ix + 1, iy + 1, seed);
    let top = a + fx * (b - a);
    let bottom = c + fx * (d - c);
    top + fy * (bottom - top)
}

/// The grain the rendered simulator paints over its flat colours (stereo needs texture): a
/// multiplier in [0.6, 1.4) from value noise at 4 cm and 15 cm.
pub fn grain(x: f64, y: f64) -> f64 {
    0.6 + 0.5 * value_noise(x, y, 0.04, 101) + 0.3 * value_noise(x, y, 0.15, 102)
}
