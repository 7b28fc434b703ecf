//! Rigid-body geometry: planar poses (`Pose2`), 3-D rigid transforms (`Rigid3`) and
//! timestamped trajectories.
//!
//! Naming follows `a_from_b`: a transform that maps coordinates expressed in frame `b` into
//! frame `a`. Composition reads left to right: `world_from_lidar = world_from_body *
//! body_from_lidar`. Angles are radians, lengths metres, time `i64` nanoseconds.

use nalgebra::{Matrix3, Matrix4, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

pub mod cells;

/// Wraps an angle into `(-pi, pi]`.
#[inline]
pub fn wrap_angle(angle_rad: f64) -> f64 {
    let mut a = angle_rad % (2.0 * PI);
    if a <= -PI {
        a += 2.0 * PI;
    } else if a > PI {
        a -= 2.0 * PI;
    }
    a
}

/// A planar rigid transform / robot pose: position in metres and heading in radians
/// (counter-clockwise from the x axis, z up).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose2 {
    /// x coordinate (m).
    pub x_m: f64,
    /// y coordinate (m).
    pub y_m: f64,
    /// Heading (rad), kept in `(-pi, pi]` by the constructors and operations of this type.
    pub yaw_rad: f64,
}

impl Pose2 {
    /// The identity pose.
    pub const IDENTITY: Pose2 = Pose2 {
        x_m: 0.0,
        y_m: 0.0,
        yaw_rad: 0.0,
    };

    /// Creates a pose; the yaw is wrapped into `(-pi, pi]`.
    #[inline]
    pub fn new(x_m: f64, y_m: f64, yaw_rad: f64) -> Self {
        Pose2 {
            x_m,
            y_m,
            yaw_rad: wrap_angle(yaw_rad),
        }
    }

    /// `self * other`: applies `other` in the frame of `self` (`a_from_c = a_from_b * b_from_c`).
    #[inline]
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let (s, c) = self.yaw_rad.sin_cos();
        Pose2::new(
            self.x_m + c * other.x_m - s * other.y_m,
            self.y_m + s * other.x_m + c * other.y_m,
            self.yaw_rad + other.yaw_rad,
        )
    }

    /// The inverse transform (`b_from_a` for `a_from_b`).
    #[inline]
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.yaw_rad.sin_cos();
        Pose2::new(
            -(c * self.x_m + s * self.y_m),
            s * self.x_m - c * self.y_m,
            -self.yaw_rad,
        )
    }

    /// The relative pose `inv(self) * other`: where `other` lies in the frame of `self`.
    #[inline]
    pub fn between(&self, other: &Pose2) -> Pose2 {
        self.inverse().compose(other)
    }

    /// Maps a point given in this pose's frame into the parent frame.
    #[inline]
    pub fn transform_point(&self, x_m: f64, y_m: f64) -> (f64, f64) {
        self.transform_point_with(self.yaw_rad.sin_cos(), x_m, y_m)
    }

    /// [`Self::transform_point`] with the heading's `(sin, cos)` computed once by the caller
    /// (mapping many points: the same bits).
    #[inline]
    pub fn transform_point_with(&self, (s, c): (f64, f64), x_m: f64, y_m: f64) -> (f64, f64) {
        (self.x_m + c * x_m - s * y_m, self.y_m + s * x_m + c * y_m)
    }

    /// Euclidean norm of the translation (m).
    #[inline]
    pub fn translation_norm_m(&self) -> f64 {
        self.x_m.hypot(self.y_m)
    }

    /// Interpolates between `self` (`t = 0`) and `other` (`t = 1`): linear in position,
    /// shortest arc in yaw.
    #[inline]
    pub fn interpolate(&self, other: &Pose2, t: f64) -> Pose2 {
        let dyaw = wrap_angle(other.yaw_rad - self.yaw_rad);
        Pose2::new(
            self.x_m + t * (other.x_m - self.x_m),
            self.y_m + t * (other.y_m - self.y_m),
            self.yaw_rad + t * dyaw,
        )
    }
}

/// A pose with its timestamp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StampedPose2 {
    /// Time (ns since the epoch of the recording's clock).
    pub stamp_ns: i64,
    /// The pose at that time.
    pub pose: Pose2,
}

/// A time-ordered sequence of stamped poses.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// The poses, strictly increasing in `stamp_ns`.
    pub poses: Vec<StampedPose2>,
}

impl Trajectory {
    /// Wraps poses that are already sorted by time.
    pub fn new(poses: Vec<StampedPose2>) -> Self {
        Trajectory { poses }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The pose at `stamp_ns`, interpolated between the two nearest poses; `None` outside the
    /// trajectory's time span.
    pub fn pose_at(&self, stamp_ns: i64) -> Option<Pose2> {
        let p = &self.poses;
        let first = p.first()?;
        let last = p.last()?;
        if stamp_ns < first.stamp_ns || stamp_ns > last.stamp_ns {
            return None;
        }
        let i = p.partition_point(|s| s.stamp_ns <= stamp_ns);
        // p[i-1].stamp <= stamp < p[i].stamp (or i == len when stamp == last)
        let a = &p[i - 1];
        if a.stamp_ns == stamp_ns || i == p.len() {
            return Some(a.pose);
        }
        let b = &p[i];
        let t = (stamp_ns - a.stamp_ns) as f64 / (b.stamp_ns - a.stamp_ns) as f64;
        Some(a.pose.interpolate(&b.pose, t))
    }

    /// The pose with exactly this stamp, if present (binary search).
    pub fn pose_exact(&self, stamp_ns: i64) -> Option<Pose2> {
        self.poses
            .binary_search_by_key(&stamp_ns, |s| s.stamp_ns)
            .ok()
            .map(|i| self.poses[i].pose)
    }

    /// Total path length (m).
    pub fn path_length_m(&self) -> f64 {
        self.poses
            .windows(2)
            .map(|w| w[0].pose.between(&w[1].pose).translation_norm_m())
            .sum()
    }
}

/// A 3-D rigid transform stored as a rotation matrix and a translation, exactly as
/// calibration files give them (the rotation is not re-orthonormalised, so the numbers of a
/// calibration file survive a round trip unchanged).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid3 {
    /// Rotation part.
    pub rotation: Matrix3<f64>,
    /// Translation part (m).
    pub translation: Vector3<f64>,
}

impl Default for Rigid3 {
    fn default() -> Self {
        Rigid3::IDENTITY
    }
}

impl Rigid3 {
    /// The identity transform.
    pub const IDENTITY: Rigid3 = Rigid3 {
        rotation: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        translation: Vector3::new(0.0, 0.0, 0.0),
    };

    /// From a row-major rotation and a translation.
    pub fn from_row_major(rotation_row_major: [f64; 9], translation_m: [f64; 3]) -> Self {
        Rigid3 {
            rotation: Matrix3::from_row_slice(&rotation_row_major),
            translation: Vector3::from(translation_m),
        }
    }

    /// From roll/pitch/yaw (rad) as "XYZ extrinsic" (R = Rz(yaw) * Ry(pitch) * Rx(roll)),
    /// the convention of the car's calibration files, and a translation.
    pub fn from_rpy(roll_rad: f64, pitch_rad: f64, yaw_rad: f64, translation_m: [f64; 3]) -> Self {
        let r = nalgebra::Rotation3::from_euler_angles(roll_rad, pitch_rad, yaw_rad);
        Rigid3 {
            rotation: *r.matrix(),
            translation: Vector3::from(translation_m),
        }
    }

    /// The 4x4 homogeneous matrix.
    pub fn to_homogeneous(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// Row-major rotation entries.
    pub fn rotation_row_major(&self) -> [f64; 9] {
        let r = &self.rotation;
        [
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
            r[(2, 0)],
            r[(2, 1)],
            r[(2, 2)],
        ]
    }

    /// `self * other`.
    pub fn compose(&self, other: &Rigid3) -> Rigid3 {
        Rigid3 {
            rotation: self.rotation * other.rotation,
            translation: self.rotation * other.translation + self.translation,
        }
    }

    /// Inverse, assuming the rotation is orthonormal.
    pub fn inverse(&self) -> Rigid3 {
        let rt = self.rotation.transpose();
        Rigid3 {
            rotation: rt,
            translation: -(rt * self.translation),
        }
    }

    /// Maps a point from the source frame into the target frame.
    #[inline]
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// The planar part `world_from_body` lifted to 3-D (rotation about z, z translation 0).
    pub fn from_pose2(pose: &Pose2) -> Rigid3 {
        let (s, c) = pose.yaw_rad.sin_cos();
        Rigid3 {
            rotation: Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
            translation: Vector3::new(pose.x_m, pose.y_m, 0.0),
        }
    }

    /// The planar part: x, y and the yaw of the rotation's x axis about z.
    pub fn to_pose2(&self) -> Pose2 {
        let r = &self.rotation;
        Pose2::new(
            self.translation.x,
            self.translation.y,
            r[(1, 0)].atan2(r[(0, 0)]),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_angle_range() {
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-12);
        assert!((wrap_angle(-PI - 0.1) - (PI - 0.1)).abs() < 1e-12);
    }

    #[test]
    fn compose_inverse_identity() {
        let a = Pose2::new(1.0, -2.0, 0.7);
        let i = a.compose(&a.inverse());
        assert!(i.x_m.abs() < 1e-12 && i.y_m.abs() < 1e-12 && i.yaw_rad.abs() < 1e-12);
        let b = Pose2::new(0.3, 0.4, -2.5);
        let rel = a.between(&b);
        let back = a.compose(&rel);
        assert!((back.x_m - b.x_m).abs() < 1e-12);
        assert!((back.y_m - b.y_m).abs() < 1e-12);
        assert!(wrap_angle(back.yaw_rad - b.yaw_rad).abs() < 1e-12);
    }

    #[test]
    fn trajectory_interpolation() {
        let t = Trajectory::new(vec![
            StampedPose2 {
                stamp_ns: 0,
                pose: Pose2::new(0.0, 0.0, 3.0),
            },
            StampedPose2 {
                stamp_ns: 10,
                pose: Pose2::new(10.0, 0.0, -3.0),
            },
        ]);
        let p = t.pose_at(5).unwrap();
        assert!((p.x_m - 5.0).abs() < 1e-12);
        // shortest arc across +-pi
        assert!(p.yaw_rad.abs() > 3.0);
        assert!(t.pose_at(11).is_none());
        assert_eq!(t.pose_at(10).unwrap().x_m, 10.0);
    }

    #[test]
    fn rigid3_roundtrip() {
        let t = Rigid3::from_rpy(0.1, -0.2, 0.3, [1.0, 2.0, 3.0]);
        let p = Vector3::new(0.5, -0.25, 2.0);
        let q = t.inverse().transform_point(&t.transform_point(&p));
        assert!((p - q).norm() < 1e-12);
    }
}
