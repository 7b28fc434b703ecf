//! From disparity or depth to coloured 3-D points, and robust plane fitting.

use super::disparity::DisparityMap;
use super::image::RgbImage;
use super::rectify::{PinholeIntrinsics, RectifiedGeometry};
use nalgebra::{Matrix3, Vector3};
use pfslam::geometry::Rigid3;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// A 3-D point (m) with its colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColouredPoint {
    /// Position in the frame the producer was asked for (m).
    pub p_m: Vector3<f64>,
    /// Colour (RGB).
    pub rgb: [u8; 3],
}

/// Turns a disparity image into coloured points expressed in the frame `frame_from_rectified`
/// maps into (e.g. the body frame with [`RectifiedGeometry::body_from_rectified`]). Points
/// farther than `max_depth_m` are dropped; every `stride`-th pixel is used. Appends to `out`.
pub fn disparity_to_points(
    disparity: &DisparityMap,
    colour: &RgbImage,
    geometry: &RectifiedGeometry,
    frame_from_rectified: &Rigid3,
    max_depth_m: f64,
    stride: usize,
    out: &mut Vec<ColouredPoint>,
) {
    let stride = stride.max(1);
    let min_disparity = geometry.intrinsics.fx_px * geometry.baseline_m / max_depth_m;
    for v in (0..disparity.height).step_by(stride) {
        for u in (0..disparity.width).step_by(stride) {
            let d = disparity.data[v * disparity.width + u] as f64;
            if !(d >= min_disparity && d > 0.0) {
                continue;
            }
            let p = geometry.point_rectified(u as f64, v as f64, d);
            out.push(ColouredPoint {
                p_m: frame_from_rectified.transform_point(&p),
                rgb: colour.get(u, v),
            });
        }
    }
}

/// An RGB-D camera: depth and colour intrinsics and the colour camera's pose relative to the
/// depth camera (identity with equal intrinsics for a registered depth image).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RgbdCamera {
    /// Intrinsics of the depth image.
    pub depth: PinholeIntrinsics,
    /// Intrinsics of the colour image.
    pub colour: PinholeIntrinsics,
    /// Maps points from the depth camera frame into the colour camera frame.
    pub colour_from_depth: Rigid3,
}

/// Turns a depth image (m along the optical axis, row-major, `<= 0` or non-finite = none) and
/// its colour image into coloured points in the frame `frame_from_depth` maps into. Each depth
/// pixel is coloured by the nearest colour pixel it projects to; pixels outside the colour
/// image are dropped. Appends to `out`.
pub fn depth_to_points(
    depth_m: &[f32],
    colour: &RgbImage,
    camera: &RgbdCamera,
    frame_from_depth: &Rigid3,
    max_depth_m: f64,
    stride: usize,
    out: &mut Vec<ColouredPoint>,
) {
    let stride = stride.max(1);
    let (w, h) = (camera.depth.width, camera.depth.height);
    if depth_m.len() != w * h {
        return;
    }
    for v in (0..h).step_by(stride) {
        for u in (0..w).step_by(stride) {
            let z = depth_m[v * w + u] as f64;
            if !(z.is_finite() && z > 0.0 && z <= max_depth_m) {
                continue;
            }
            let p = camera.depth.ray(u as f64, v as f64) * z;
            let pc = camera.colour_from_depth.transform_point(&p);
            let Some((cu, cv)) = camera.colour.project(&pc) else {
                continue;
            };
            let (cu, cv) = (cu.round(), cv.round());
            if cu < 0.0 || cv < 0.0 || cu >= colour.width as f64 || cv >= colour.height as f64 {
                continue;
            }
            out.push(ColouredPoint {
                p_m: frame_from_depth.transform_point(&p),
                rgb: colour.get(cu as usize, cv as usize),
            });
        }
    }
}

/// A plane `normal . p = offset_m` with unit `normal` (z component >= 0) and its fit quality.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFit {
    /// Unit normal, pointing up (non-negative z).
    pub normal: Vector3<f64>,
    /// Offset (m): the signed distance of the origin is `-offset_m`.
    pub offset_m: f64,
    /// Number of inliers of the final fit.
    pub inliers: usize,
    /// Root-mean-square point-to-plane distance of the inliers (m).
    pub rms_m: f64,
    /// Centroid of the inliers.
    pub centroid: Vector3<f64>,
}

impl PlaneFit {
    /// Angle between the normal and the z axis (rad).
    pub fn tilt_rad(&self) -> f64 {
        self.normal.z.clamp(-1.0, 1.0).acos()
    }

    /// The plane's z at `(x, y)` (m); NaN for a vertical plane.
    pub fn z_at(&self, x_m: f64, y_m: f64) -> f64 {
        (self.offset_m - self.normal.x * x_m - self.normal.y * y_m) / self.normal.z
    }

    /// Signed distance of a point from the plane (m), positive above.
    pub fn distance_m(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) - self.offset_m
    }
}

/// Least-squares plane through points (smallest eigenvector of the scatter matrix).
fn least_squares_plane(points: &[Vector3<f64>]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p) / n;
    let mut scatter = Matrix3::zeros();
    for p in points {
        let d = p - centroid;
        scatter += d * d.transpose();
    }
    let eig = scatter.symmetric_eigen();
    let (i, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut normal: Vector3<f64> = eig.eigenvectors.column(i).into_owned();
    if normal.z < 0.0 {
        normal = -normal;
    }
    Some((normal, centroid))
}

/// Robust plane fit: RANSAC on 3-point samples (seeded, deterministic) with an inlier
/// threshold, then least squares on the inliers, twice. `None` with fewer than 3 points or no
/// non-degenerate sample.
pub fn fit_plane_ransac(
    points: &[Vector3<f64>],
    inlier_threshold_m: f64,
    iterations: usize,
    seed: u64,
) -> Option<PlaneFit> {
    if points.len() < 3 {
        return None;
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut best: Option<(usize, Vector3<f64>, f64)> = None;
    for _ in 0..iterations {
        let a = points[rng.random_range(0..points.len())];
        let b = points[rng.random_range(0..points.len())];
        let c = points[rng.random_range(0..points.len())];
        let n = (b - a).cross(&(c - a));
        let norm = n.norm();
        if norm < 1e-9 {
            continue;
        }
        let n = n / norm;
        let off = n.dot(&a);
        let count = points
            .iter()
            .filter(|p| (n.dot(p) - off).abs() < inlier_threshold_m)
            .count();
        if best.is_none_or(|(bc, _, _)| count > bc) {
            best = Some((count, n, off));
        }
    }
    let (_, mut normal, mut offset) = best?;
    let mut fit = None;
    for _ in 0..2 {
        let inliers: Vec<Vector3<f64>> = points
            .iter()
            .filter(|p| (normal.dot(p) - offset).abs() < inlier_threshold_m)
            .copied()
            .collect();
        let (n, centroid) = least_squares_plane(&inliers)?;
        normal = n;
        offset = n.dot(&centroid);
        let rms = (inliers
            .iter()
            .map(|p| (n.dot(p) - offset).powi(2))
            .sum::<f64>()
            / inliers.len() as f64)
            .sqrt();
        fit = Some(PlaneFit {
            normal,
            offset_m: offset,
            inliers: inliers.len(),
            rms_m: rms,
            centroid,
        });
    }
    fit
}
