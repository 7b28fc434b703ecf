//! Motion: the car's differential drive from wheel ticks and FOG yaw, the two step models
//! (the seed's Euler step, equation 2, and the exact arc), and the velocity noise model the
//! particle filter samples from.
//!
//! Conventions: body frame x forward, y left, z up; yaw counter-clockwise positive about z.
//! The FOG's `delta_yaw` is taken as the body's yaw increment in that convention (the FOG is
//! mounted without rotation, `Vehicle2FOG.txt`). Wheel distance = `pi * d * dticks / res`
//! per wheel with its own diameter; the car's distance is the mean of the two wheels.

pub mod calibration;
pub mod dead_reckoning;
pub mod imu_yaw;
pub mod odometry_model;
pub mod odometry_timing;
pub mod perturb;

pub use dead_reckoning::{
    OdometryStep, car_recording, car_recording_taking_scans, dead_reckon, odometry_steps,
};

use crate::geometry::{Pose2, wrap_angle};
use crate::sensors::EncoderParams;
use rand::RngExt;
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

/// How one motion increment (distance, yaw change) moves a pose.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StepModel {
    /// The seed's equation (2): move `distance` along the *old* heading, then turn. Error per
    /// step ~ `distance * dyaw / 2` sideways: on a 10.4 m radius circle at 100 Hz (1.5
    /// turns) the position error is 2.6e-4 of the path length (exact arc: 4e-16), see the
    /// `motion` integration tests.
    Euler,
    /// Exact for constant speed and yaw rate over the step: a circular arc (chord of length
    /// `distance * sinc(dyaw / 2)` along the mid heading).
    #[default]
    ExactArc,
}

/// Where the yaw increments come from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum YawSource {
    /// The FOG, integrated by timestamp; encoder intervals outside the FOG's span fall back to
    /// the wheels (with a warning).
    #[default]
    Fog,
    /// Wheel odometry only: `(right distance - left distance) / wheel base`.
    Wheels,
}

/// Zero-mean Gaussian noise on linear and angular velocity (standard deviations).
///
/// The seed's Table 1 gives *variances*; the presets convert them (`sigma = sqrt(var)`):
///
/// | preset | var v (m²/s²) | var ω (rad²/s²) | σ_v (m/s) | σ_ω (rad/s) |
/// |---|---|---|---|---|
/// | [`VelocityNoise::seed_iteration_1`] (the seed's final choice) | 0.5 | 0.05 | 0.7071 | 0.2236 |
/// | [`VelocityNoise::seed_iteration_2`] | 1 | 0.05 | 1.0 | 0.2236 |
/// | [`VelocityNoise::seed_iteration_3`] | 2 | 0.1 | 1.4142 | 0.3162 |
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VelocityNoise {
    /// Standard deviation of the linear velocity (m/s).
    pub sigma_v_mps: f64,
    /// Standard deviation of the angular velocity (rad/s).
    pub sigma_omega_radps: f64,
}

impl Default for VelocityNoise {
    /// The seed's final choice (Table 1, iteration 1).
    fn default() -> Self {
        VelocityNoise::seed_iteration_1()
    }
}

impl VelocityNoise {
    /// No noise (dead reckoning).
    pub const OFF: VelocityNoise = VelocityNoise {
        sigma_v_mps: 0.0,
        sigma_omega_radps: 0.0,
    };

    /// From variances, as the seed's Table 1 states them.
    pub fn from_variances(var_v: f64, var_omega: f64) -> Self {
        VelocityNoise {
            sigma_v_mps: var_v.max(0.0).sqrt(),
            sigma_omega_radps: var_omega.max(0.0).sqrt(),
        }
    }

    /// Table 1, iteration 1: variances 0.5 and 0.05 (kept by the seed for its results).
    pub fn seed_iteration_1() -> Self {
        Self::from_variances(0.5, 0.05)
    }

    /// Table 1, iteration 2: variances 1 and 0.05.
    pub fn seed_iteration_2() -> Self {
        Self::from_variances(1.0, 0.05)
    }

    /// Table 1, iteration 3: variances 2 and 0.1 (the trajectory drifts away in the seed).
    pub fn seed_iteration_3() -> Self {
        Self::from_variances(2.0, 0.1)
    }

    /// True when both sigmas are zero.
    pub fn is_off(&self) -> bool {
        self.sigma_v_mps == 0.0 && self.sigma_omega_radps == 0.0
    }
}

/// Options of the motion component (`[motion]` in the configuration).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotionOptions {
    /// Step model (default: exact arc; `euler` is the seed's equation 2).
    pub step: StepModel,
    /// Yaw source (default: FOG).
    pub yaw_source: YawSource,
    /// Velocity noise for the particle filter's prediction (dead reckoning ignores it).
    pub noise: VelocityNoise,
}

/// Errors of the motion component.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// Fewer than one encoder row.
    #[error("no encoder rows: nothing to dead-reckon")]
    NoEncoder,
    /// FOG yaw requested but there is no usable FOG row.
    #[error("yaw source is the FOG but there are no FOG rows (or their stamps do not increase)")]
    NoFog,
    /// Encoder stamps must increase strictly.
    #[error("encoder row {index}: timestamp {stamp_ns} does not increase")]
    NotIncreasing {
        /// Row index (0-based).
        index: usize,
        /// The stamp.
        stamp_ns: i64,
    },
    /// Noise sigmas must be finite and non-negative.
    #[error("invalid velocity noise: {0}")]
    InvalidNoise(String),
    /// Invalid calibration options.
    #[error("invalid odometry calibration options: {0}")]
    InvalidCalibration(String),
    /// The odometry calibration could not be fitted.
    #[error("odometry calibration: {0}")]
    Calibration(String),
}

/// Distances travelled by the left and right wheels (m) for tick changes.
#[inline]
pub fn wheel_distances_m(
    params: &EncoderParams,
    d_left_ticks: i64,
    d_right_ticks: i64,
) -> (f64, f64) {
    let k = std::f64::consts::PI / f64::from(params.resolution_ticks);
    (
        k * params.left_wheel_diameter_m * d_left_ticks as f64,
        k * params.right_wheel_diameter_m * d_right_ticks as f64,
    )
}

/// `sin(x) / x`, accurate near 0.
#[inline]
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        let x2 = x * x;
        1.0 - x2 / 6.0 + x2 * x2 / 120.0
    } else {
        x.sin() / x
    }
}

/// Moves `pose` by `distance_m` along the body x axis while turning by `dyaw_rad`.
#[inline]
pub fn step_pose(pose: &Pose2, distance_m: f64, dyaw_rad: f64, model: StepModel) -> Pose2 {
    match model {
        StepModel::Euler => {
            let (s, c) = pose.yaw_rad.sin_cos();
            Pose2::new(
                pose.x_m + distance_m * c,
                pose.y_m + distance_m * s,
                pose.yaw_rad + dyaw_rad,
            )
        }
        StepModel::ExactArc => {
            let half = 0.5 * dyaw_rad;
            let chord = distance_m * sinc(half);
            let (s, c) = (pose.yaw_rad + half).sin_cos();
            Pose2::new(
                pose.x_m + chord * c,
                pose.y_m + chord * s,
                wrap_angle(pose.yaw_rad + dyaw_rad),
            )
        }
    }
}

/// Prediction step of the particle filter: adds zero-mean Gaussian noise to `v_mps` and
/// `omega_radps` (sigmas from `noise`) and moves `pose` for `dt_s` seconds with the exact arc
/// step. Draws exactly two standard normals from `rng` (also when the noise is off), so
/// particles stay on the same random stream whatever the sigmas.
#[inline]
pub fn sample_velocity_step(
    pose: &Pose2,
    v_mps: f64,
    omega_radps: f64,
    dt_s: f64,
    noise: &VelocityNoise,
    rng: &mut Xoshiro256PlusPlus,
) -> Pose2 {
    sample_velocity_step_with(
        pose,
        v_mps,
        omega_radps,
        dt_s,
        noise,
        StepModel::ExactArc,
        rng,
    )
}

/// [`sample_velocity_step`] with a chosen step model.
#[inline]
pub fn sample_velocity_step_with(
    pose: &Pose2,
    v_mps: f64,
    omega_radps: f64,
    dt_s: f64,
    noise: &VelocityNoise,
    model: StepModel,
    rng: &mut Xoshiro256PlusPlus,
) -> Pose2 {
    let nv: f64 = rng.sample(StandardNormal);
    let nw: f64 = rng.sample(StandardNormal);
    let v = v_mps + noise.sigma_v_mps * nv;
    let w = omega_radps + noise.sigma_omega_radps * nw;
    step_pose(pose, v * dt_s, w * dt_s, model)
}

impl MotionOptions {
    /// Checks the options (finite, non-negative sigmas).
    pub fn validate(&self) -> Result<(), MotionError> {
        let n = &self.noise;
        for (name, v) in [
            ("sigma_v_mps", n.sigma_v_mps),
            ("sigma_omega_radps", n.sigma_omega_radps),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(MotionError::InvalidNoise(format!(
                    "{name} = {v} (must be finite and >= 0)"
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn arc_step_on_a_circle() {
        // Quarter circle of radius 2 in one step.
        let p = step_pose(
            &Pose2::IDENTITY,
            std::f64::consts::PI,
            std::f64::consts::FRAC_PI_2,
            StepModel::ExactArc,
        );
        assert!((p.x_m - 2.0).abs() < 1e-12 && (p.y_m - 2.0).abs() < 1e-12);
        assert!((p.yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let e = step_pose(&Pose2::IDENTITY, 1.0, 0.5, StepModel::Euler);
        assert_eq!((e.x_m, e.y_m, e.yaw_rad), (1.0, 0.0, 0.5));
    }

    #[test]
    fn noise_off_is_deterministic_and_noise_has_the_right_spread() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let p = sample_velocity_step(
            &Pose2::IDENTITY,
            2.0,
            0.0,
            0.5,
            &VelocityNoise::OFF,
            &mut rng,
        );
        assert!((p.x_m - 1.0).abs() < 1e-15 && p.y_m == 0.0);
        let noise = VelocityNoise::seed_iteration_1();
        assert!((noise.sigma_v_mps - 0.5f64.sqrt()).abs() < 1e-15);
        let n = 20000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            // dt = 1, v = 0, omega = 0: yaw = noise in omega
            let q = sample_velocity_step(
                &Pose2::IDENTITY,
                0.0,
                0.0,
                1.0,
                &VelocityNoise {
                    sigma_v_mps: 0.0,
                    sigma_omega_radps: 0.1,
                },
                &mut rng,
            );
            s += q.yaw_rad;
            s2 += q.yaw_rad * q.yaw_rad;
        }
        let mean = s / n as f64;
        let sd = (s2 / n as f64 - mean * mean).sqrt();
        assert!(
            mean.abs() < 0.005 && (sd - 0.1).abs() < 0.005,
            "{mean} {sd}"
        );
    }

    #[test]
    fn options_roundtrip_toml() {
        let o = MotionOptions {
            step: StepModel::Euler,
            yaw_source: YawSource::Wheels,
            noise: VelocityNoise::seed_iteration_3(),
        };
        let t = toml::to_string(&o).unwrap();
        assert_eq!(toml::from_str::<MotionOptions>(&t).unwrap(), o);
        assert!(
            MotionOptions {
                noise: VelocityNoise {
                    sigma_v_mps: -1.0,
                    sigma_omega_radps: 0.0
                },
                ..o
            }
            .validate()
            .is_err()
        );
    }
}
