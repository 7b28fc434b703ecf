//! Undistortion (plumb_bob) and stereo rectification with the calibration's R and P.
//!
//! Remap tables are built once per rig: for each rectified pixel, inverse-project through P,
//! rotate by R^T into the raw camera frame, apply the lens distortion and project with K. The
//! images are then resampled bilinearly.

use super::StereoError;
use super::image::{GrayImage, RgbImage};
use nalgebra::{Matrix3, Vector3};
use pfslam::geometry::Rigid3;
use pfslam::sensors::{CameraInfo, StereoCalibration};
use rayon::prelude::*;

/// Pinhole intrinsics (px) without distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeIntrinsics {
    /// Image width (px).
    pub width: usize,
    /// Image height (px).
    pub height: usize,
    /// Focal length along x (px).
    pub fx_px: f64,
    /// Focal length along y (px).
    pub fy_px: f64,
    /// Principal point x (px).
    pub cx_px: f64,
    /// Principal point y (px).
    pub cy_px: f64,
}

impl PinholeIntrinsics {
    /// The ray (z = 1) through pixel `(u, v)`.
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new(
            (u - self.cx_px) / self.fx_px,
            (v - self.cy_px) / self.fy_px,
            1.0,
        )
    }

    /// Projects a point in the camera frame (z forward) to a pixel; `None` behind the camera.
    #[inline]
    pub fn project(&self, p: &Vector3<f64>) -> Option<(f64, f64)> {
        (p.z > 1e-9).then(|| {
            (
                self.fx_px * p.x / p.z + self.cx_px,
                self.fy_px * p.y / p.z + self.cy_px,
            )
        })
    }
}

/// A camera with lens distortion as OpenCV calibrates it.
#[derive(Debug, Clone, PartialEq)]
pub struct DistortedCamera {
    /// 3x3 camera matrix K (may carry a skew term).
    pub k: Matrix3<f64>,
    /// plumb_bob coefficients k1, k2, p1, p2, k3.
    pub dist: [f64; 5],
}

impl DistortedCamera {
    /// From a calibration record; only `plumb_bob` (or an empty/no distortion) is supported.
    pub fn from_info(info: &CameraInfo) -> Result<Self, StereoError> {
        let model = info.distortion_model.as_str();
        if !(model == "plumb_bob" || model.is_empty() || model == "none") {
            return Err(StereoError::Calibration(format!(
                "distortion model {model:?} is not supported (plumb_bob only)"
            )));
        }
        if info.distortion.len() > 5 {
            return Err(StereoError::Calibration(format!(
                "plumb_bob takes at most 5 coefficients, got {}",
                info.distortion.len()
            )));
        }
        let mut dist = [0.0; 5];
        dist[..info.distortion.len()].copy_from_slice(&info.distortion);
        let k = Matrix3::from_row_slice(&info.camera_matrix);
        if k[(0, 0)].abs() < 1e-9 || k[(1, 1)].abs() < 1e-9 {
            return Err(StereoError::Calibration(
                "camera matrix has a zero focal length".into(),
            ));
        }
        Ok(DistortedCamera { k, dist })
    }

    /// Applies the distortion to normalised coordinates `(x, y)` (z = 1).
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Projects a point in this camera's frame to raw (distorted) pixel coordinates.
    #[inline]
    pub fn project(&self, p: &Vector3<f64>) -> Option<(f64, f64)> {
        if p.z <= 1e-9 {
            return None;
        }
        let (xd, yd) = self.distort(p.x / p.z, p.y / p.z);
        let k = &self.k;
        Some((
            k[(0, 0)] * xd + k[(0, 1)] * yd + k[(0, 2)],
            k[(1, 1)] * yd + k[(1, 2)],
        ))
    }

    /// The undistorted ray (z = 1) of raw pixel `(u, v)` (fixed-point iteration, as OpenCV's
    /// `undistortPoints`).
    pub fn unproject(&self, u: f64, v: f64) -> Vector3<f64> {
        let k = &self.k;
        let yd = (v - k[(1, 2)]) / k[(1, 1)];
        let xd = (u - k[(0, 2)] - k[(0, 1)] * yd) / k[(0, 0)];
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let (dx, dy) = self.distort(x, y);
            x -= dx - xd;
            y -= dy - yd;
        }
        Vector3::new(x, y, 1.0)
    }
}

/// For each output pixel, the (x, y) source coordinates to sample (NaN: outside).
#[derive(Debug, Clone, PartialEq)]
pub struct RemapTable {
    /// Output width (px).
    pub width: usize,
    /// Output height (px).
    pub height: usize,
    /// Source x per output pixel.
    pub map_x: Vec<f32>,
    /// Source y per output pixel.
    pub map_y: Vec<f32>,
}

impl RemapTable {
    /// The table that rectifies a camera: output pixels live in the rectified camera defined by
    /// `rect_from_camera` (R) and `projection` (P's left 3x3).
    pub fn rectification(
        camera: &DistortedCamera,
        rect_from_camera: &Matrix3<f64>,
        projection: &PinholeIntrinsics,
        source_width: usize,
        source_height: usize,
    ) -> Self {
        let (w, h) = (projection.width, projection.height);
        let camera_from_rect = rect_from_camera.transpose();
        let mut map_x = vec![f32::NAN; w * h];
        let mut map_y = vec![f32::NAN; w * h];
        map_x
            .par_chunks_mut(w)
            .zip(map_y.par_chunks_mut(w))
            .enumerate()
            .for_each(|(v, (mx, my))| {
                for u in 0..w {
                    let ray = camera_from_rect * projection.ray(u as f64, v as f64);
                    if let Some((su, sv)) = camera.project(&ray)
                        && su > -1.0
                        && sv > -1.0
                        && su < source_width as f64
                        && sv < source_height as f64
                    {
                        mx[u] = su as f32;
                        my[u] = sv as f32;
                    }
                }
            });
        RemapTable {
            width: w,
            height: h,
            map_x,
            map_y,
        }
    }

    /// Resamples an RGB image bilinearly into `out` (black outside the source).
    pub fn remap_rgb_into(&self, src: &RgbImage, out: &mut RgbImage) {
        out.reshape(self.width, self.height);
        let w = self.width;
        out.data
            .par_chunks_mut(3 * w.max(1))
            .enumerate()
            .for_each(|(v, row)| {
                for u in 0..w {
                    let i = v * w + u;
                    let px = sample_bilinear::<3>(
                        &src.data,
                        src.width,
                        src.height,
                        self.map_x[i],
                        self.map_y[i],
                    );
                    row[3 * u..3 * u + 3].copy_from_slice(&px);
                }
            });
    }

    /// Resamples a grey image bilinearly into `out` (black outside the source).
    pub fn remap_gray_into(&self, src: &GrayImage, out: &mut GrayImage) {
        out.reshape(self.width, self.height);
        let w = self.width;
        out.data
            .par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(v, row)| {
                for (u, o) in row.iter_mut().enumerate() {
                    let i = v * w + u;
                    *o = sample_bilinear::<1>(
                        &src.data,
                        src.width,
                        src.height,
                        self.map_x[i],
                        self.map_y[i],
                    )[0];
                }
            });
    }
}

/// Bilinear sample of an interleaved `N`-channel image at `(x, y)`; zero outside (or NaN).
#[inline]
fn sample_bilinear<const N: usize>(data: &[u8], w: usize, h: usize, x: f32, y: f32) -> [u8; N] {
    let mut out = [0u8; N];
    if !(x >= 0.0 && y >= 0.0) || w == 0 || h == 0 {
        return out;
    }
    let x = x.min((w - 1) as f32);
    let y = y.min((h - 1) as f32);
    let x0 = x as usize;
    let y0 = y as usize;
    let x1 = (x0 + 1).min(w - 1);
    let y1 = (y0 + 1).min(h - 1);
    let fx = x - x0 as f32;
    let fy = y - y0 as f32;
    for (c, o) in out.iter_mut().enumerate() {
        let p = |xx: usize, yy: usize| data[N * (yy * w + xx) + c] as f32;
        let top = p(x0, y0) + fx * (p(x1, y0) - p(x0, y0));
        let bottom = p(x0, y1) + fx * (p(x1, y1) - p(x0, y1));
        *o = (top + fy * (bottom - top) + 0.5).clamp(0.0, 255.0) as u8;
    }
    out
}

/// The rectified stereo geometry: a common pinhole camera for both rectified images, the
/// baseline, and the left rectified camera's mount on the body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RectifiedGeometry {
    /// Intrinsics of the rectified images (shared by both cameras).
    pub intrinsics: PinholeIntrinsics,
    /// Baseline (m).
    pub baseline_m: f64,
    /// The left rectified camera (x right, y down, z forward) in the body frame.
    pub body_from_rectified: Rigid3,
}

impl RectifiedGeometry {
    /// Depth (m) along the rectified optical axis for a disparity (px).
    #[inline]
    pub fn depth_m(&self, disparity_px: f64) -> f64 {
        self.intrinsics.fx_px * self.baseline_m / disparity_px
    }

    /// Disparity (px) of a point at `depth_m` along the rectified optical axis.
    #[inline]
    pub fn disparity_px(&self, depth_m: f64) -> f64 {
        self.intrinsics.fx_px * self.baseline_m / depth_m
    }

    /// The 3-D point in the left rectified camera frame of pixel `(u, v)` with disparity `d`.
    #[inline]
    pub fn point_rectified(&self, u: f64, v: f64, disparity_px: f64) -> Vector3<f64> {
        self.intrinsics.ray(u, v) * self.depth_m(disparity_px)
    }
}

/// The rectifier of a stereo rig: both remap tables and the rectified geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoRectifier {
    /// Left camera's table.
    pub left: RemapTable,
    /// Right camera's table.
    pub right: RemapTable,
    /// The rectified geometry.
    pub geometry: RectifiedGeometry,
}

fn intrinsics_from_projection(info: &CameraInfo) -> Result<PinholeIntrinsics, StereoError> {
    let p = &info.projection;
    if p[0].abs() < 1e-9 || p[5].abs() < 1e-9 {
        return Err(StereoError::Calibration(
            "projection matrix has a zero focal length".into(),
        ));
    }
    Ok(PinholeIntrinsics {
        width: info.width as usize,
        height: info.height as usize,
        fx_px: p[0],
        fy_px: p[5],
        cx_px: p[2],
        cy_px: p[6],
    })
}

impl StereoRectifier {
    /// Builds the tables of a rig (once; reuse for every pair).
    pub fn new(calib: &StereoCalibration) -> Result<Self, StereoError> {
        let (l, r) = (&calib.left, &calib.right);
        if l.width == 0 || l.height == 0 || l.width != r.width || l.height != r.height {
            return Err(StereoError::Calibration(format!(
                "image sizes {}x{} and {}x{} must match and be non-empty",
                l.width, l.height, r.width, r.height
            )));
        }
        let pl = intrinsics_from_projection(l)?;
        let pr = intrinsics_from_projection(r)?;
        if (pl.fx_px - pr.fx_px).abs() > 1e-6 * pl.fx_px
            || (pl.cx_px - pr.cx_px).abs() > 1e-3
            || (pl.cy_px - pr.cy_px).abs() > 1e-3
        {
            return Err(StereoError::Calibration(
                "left and right projection matrices differ: not a horizontally rectified pair"
                    .into(),
            ));
        }
        if !(calib.baseline_m.is_finite() && calib.baseline_m > 0.0) {
            return Err(StereoError::Calibration(format!(
                "baseline must be positive, got {} m",
                calib.baseline_m
            )));
        }
        let rl = Matrix3::from_row_slice(&l.rectification);
        let rr = Matrix3::from_row_slice(&r.rectification);
        let cam_l = DistortedCamera::from_info(l)?;
        let cam_r = DistortedCamera::from_info(r)?;
        let (w, h) = (l.width as usize, l.height as usize);
        let left = RemapTable::rectification(&cam_l, &rl, &pl, w, h);
        let right = RemapTable::rectification(&cam_r, &rr, &pr, w, h);
        // Points in the rectified left frame map to the raw left camera frame by R^T.
        let camera_from_rectified = Rigid3 {
            rotation: rl.transpose(),
            translation: Vector3::zeros(),
        };
        Ok(StereoRectifier {
            left,
            right,
            geometry: RectifiedGeometry {
                intrinsics: pl,
                baseline_m: calib.baseline_m,
                body_from_rectified: calib.body_from_camera.compose(&camera_from_rectified),
            },
        })
    }
}
