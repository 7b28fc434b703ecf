//! The filter's prediction: adapters from an odometry step `(from, to)` to the motion
//! module's noisy models (velocity noise of the UCSD seed, relative-odometry noise of the
//! ESE650 seed and Thrun's model).

use crate::geometry::{Pose2, StampedPose2, wrap_angle};
use crate::motion::odometry_model::{OdometryModelOptions, sample_odometry_motion};
use crate::motion::{StepModel, VelocityNoise, sample_velocity_step_with};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

/// Which motion model predicts the particles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PredictionModel {
    /// UCSD seed: velocities `v = distance / dt`, `omega = dyaw / dt` of each odometry step
    /// with Gaussian noise (`[motion.noise]`, Table 1 presets).
    #[default]
    Velocity,
    /// Relative motion between odometry poses with noise (`[filter.odometry_model]`: the
    /// ESE650 seed's `[0.005, 0.005, 0.005]` or Thrun's four-parameter model).
    Odometry,
}

/// A noisy motion model: moves a particle by the odometry step `from -> to`. `Send` too, so
/// that a [`crate::Slam`] can run on another thread than the one that made it.
pub trait MotionModel: Send + Sync {
    /// The particle's new pose after the odometry step `from -> to`, with noise drawn from
    /// `rng`.
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2;

    /// The recording's IMU yaw `(stamp_ns, yaw_rad)` so far, for a model that uses it: the
    /// series only grows (live input), so a model keeps what it has and takes the rest.
    fn observe_imu_yaw(&mut self, _series: &[(i64, f64)]) {}
}

/// The UCSD seed's model: each odometry step as linear and angular velocity plus noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityMotion {
    /// Noise on the velocities.
    pub noise: VelocityNoise,
    /// How a (distance, yaw change) increment moves a pose.
    pub step: StepModel,
}

/// `sin(x) / x`, accurate near 0.
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        1.0 - x * x / 6.0
    } else {
        x.sin() / x
    }
}

impl MotionModel for VelocityMotion {
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2 {
        let dt_s = (to.stamp_ns - from.stamp_ns) as f64 * 1e-9;
        let rel = from.pose.between(&to.pose);
        let dyaw = rel.yaw_rad;
        // Invert the exact arc: the chord is `distance * sinc(dyaw / 2)`; reversing shows
        // as a chord pointing backwards.
        let chord = rel.translation_norm_m();
        let sign = if rel.x_m < 0.0 { -1.0 } else { 1.0 };
        let distance = sign * chord / sinc(0.5 * dyaw);
        if dt_s <= 0.0 {
            return *pose;
        }
        sample_velocity_step_with(
            pose,
            distance / dt_s,
            dyaw / dt_s,
            dt_s,
            &self.noise,
            self.step,
            rng,
        )
    }
}

/// The odometry-pose models (ESE650 seed, Thrun), with the recording's IMU yaw when it has
/// one (the ESE650 seed takes yaw from the IMU).
#[derive(Debug, Clone)]
pub struct OdometryMotion {
    /// Model and noise.
    pub options: OdometryModelOptions,
    /// Absolute IMU yaw `(stamp_ns, yaw_rad)`, time ordered, when known.
    pub imu_yaw: Option<Vec<(i64, f64)>>,
}

impl OdometryMotion {
    /// IMU yaw interpolated at `stamp_ns` (clamped to the ends), when known.
    fn imu_yaw_at(&self, stamp_ns: i64) -> Option<f64> {
        crate::motion::imu_yaw::yaw_at(self.imu_yaw.as_deref()?, stamp_ns)
    }
}

impl MotionModel for OdometryMotion {
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2 {
        let imu_dyaw = match (self.imu_yaw_at(from.stamp_ns), self.imu_yaw_at(to.stamp_ns)) {
            (Some(a), Some(b)) => Some(wrap_angle(b - a)),
            _ => None,
        };
        sample_odometry_motion(&self.options, pose, &from.pose, &to.pose, imu_dyaw, rng)
    }

    fn observe_imu_yaw(&mut self, series: &[(i64, f64)]) {
        let known = self.imu_yaw.get_or_insert_with(Vec::new);
        if let Some(new) = series.get(known.len()..) {
            known.extend_from_slice(new);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::step_pose;
    use rand::SeedableRng;

    #[test]
    fn noiseless_velocity_model_reproduces_the_odometry() {
        let m = VelocityMotion {
            noise: VelocityNoise::OFF,
            step: StepModel::ExactArc,
        };
        let a = Pose2::new(1.0, 2.0, 0.3);
        let b = step_pose(&a, 0.8, 0.2, StepModel::ExactArc);
        let back = step_pose(&a, -0.5, -0.1, StepModel::ExactArc);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let p = Pose2::new(-4.0, 1.0, -1.0);
        for target in [b, back] {
            let from = StampedPose2 {
                stamp_ns: 0,
                pose: a,
            };
            let to = StampedPose2 {
                stamp_ns: 10_000_000,
                pose: target,
            };
            let q = m.sample(&p, &from, &to, &mut rng);
            let want = p.compose(&a.between(&target));
            assert!((q.x_m - want.x_m).abs() < 1e-9, "{q:?} {want:?}");
            assert!((q.y_m - want.y_m).abs() < 1e-9);
            assert!(wrap_angle(q.yaw_rad - want.yaw_rad).abs() < 1e-9);
        }
    }

    #[test]
    fn imu_yaw_interpolates() {
        let m = OdometryMotion {
            options: OdometryModelOptions::ese650(),
            imu_yaw: Some(vec![(0, 0.0), (10, 1.0)]),
        };
        assert_eq!(m.imu_yaw_at(5), Some(0.5));
        assert_eq!(m.imu_yaw_at(-5), Some(0.0));
        assert_eq!(m.imu_yaw_at(50), Some(1.0));
    }
}
