//! Motion from odometry poses: the relative motion between two consecutive odometry poses,
//! perturbed by noise, applied to a particle.
//!
//! Two models ([`OdometryModel`]):
//! - [`OdometryModel::Thrun`]: `sample_motion_model_odometry` of Thrun, Burgard and Fox,
//!   *Probabilistic Robotics* (table 5.6): the motion is decomposed into a first rotation
//!   `rot1`, a translation `trans` and a second rotation `rot2`, each perturbed by zero-mean
//!   Gaussian noise with variance `alpha1 * rot^2 + alpha2 * trans^2` (rotations) and
//!   `alpha3 * trans^2 + alpha4 * (rot1^2 + rot2^2)` (translation). The alphas are
//!   dimensionless ratios: rotation from rotation, rotation from translation (rad^2/m^2),
//!   translation from translation, translation from rotation (m^2/rad^2).
//! - [`OdometryModel::Ese650`]: the seed ESE650 model: the body-frame relative motion
//!   `(dx, dy, dyaw)` between odometry poses, with `dyaw` replaced by the IMU's yaw change
//!   when an IMU yaw is given, plus independent Gaussian noise of standard deviations
//!   `[0.005 m, 0.005 m, 0.005 rad]` per step.

use crate::geometry::{Pose2, wrap_angle};
use rand::RngExt;
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

/// Which odometry motion model to sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OdometryModel {
    /// Four-parameter rot1-trans-rot2 model (Probabilistic Robotics, table 5.6), with the
    /// turn-in-place and reversing rules of ROS AMCL's differential model: below 1 cm of
    /// travel the turn is all in `rot2`, and each turn's noise grows with its distance to 0 or
    /// 180 deg (`docs/decisions/0057-localisation-turns-and-stale-scans.md`).
    #[default]
    Thrun,
    /// Seed ESE650: body-frame (dx, dy, dyaw) + Gaussian noise, IMU yaw when available.
    Ese650,
}

/// Options of the odometry motion models.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryModelOptions {
    /// The model.
    pub model: OdometryModel,
    /// Thrun: rotation noise from rotation (rad^2/rad^2).
    pub alpha1: f64,
    /// Thrun: rotation noise from translation (rad^2/m^2).
    pub alpha2: f64,
    /// Thrun: translation noise from translation (m^2/m^2).
    pub alpha3: f64,
    /// Thrun: translation noise from rotation (m^2/rad^2).
    pub alpha4: f64,
    /// ESE650: standard deviations of the noise on (dx m, dy m, dyaw rad) per step.
    pub ese650_sigma: [f64; 3],
}

impl Default for OdometryModelOptions {
    /// Thrun's model with all four alphas 0.05 (a moderate starting point, not tuned on any
    /// recording) and the ESE650 seed's sigmas for the other variant.
    fn default() -> Self {
        OdometryModelOptions {
            model: OdometryModel::Thrun,
            alpha1: 0.05,
            alpha2: 0.05,
            alpha3: 0.05,
            alpha4: 0.05,
            ese650_sigma: [0.005, 0.005, 0.005],
        }
    }
}

impl OdometryModelOptions {
    /// The seed ESE650 preset.
    pub fn ese650() -> Self {
        OdometryModelOptions {
            model: OdometryModel::Ese650,
            ..OdometryModelOptions::default()
        }
    }
}

/// The relative motion between two odometry poses as rot1, trans, rot2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryDelta {
    /// First rotation, towards the direction of travel (rad).
    pub rot1_rad: f64,
    /// Distance travelled (m).
    pub trans_m: f64,
    /// Second rotation, to the final heading (rad).
    pub rot2_rad: f64,
}

/// Below this travel (m) the direction of travel is odometry noise: the turn is all in `rot2`.
const MIN_TRAVEL_M: f64 = 0.01;

/// A turn's magnitude for the noise: driving backwards turns by 180 deg before and after
/// without turning the robot, so the noise grows with the distance to 0 or 180 deg.
fn folded(rot_rad: f64) -> f64 {
    let r = rot_rad.abs();
    r.min((std::f64::consts::PI - r).abs())
}

impl OdometryDelta {
    /// Decomposes the motion from `prev` to `next` (odometry frame). Below 1 cm of travel the
    /// direction of travel is meaningless, so `rot1` is 0 and the turn is all in `rot2`.
    pub fn between(prev: &Pose2, next: &Pose2) -> Self {
        let dx = next.x_m - prev.x_m;
        let dy = next.y_m - prev.y_m;
        let trans_m = dx.hypot(dy);
        let rot1_rad = if trans_m < MIN_TRAVEL_M {
            0.0
        } else {
            wrap_angle(dy.atan2(dx) - prev.yaw_rad)
        };
        let rot2_rad = wrap_angle(next.yaw_rad - prev.yaw_rad - rot1_rad);
        OdometryDelta {
            rot1_rad,
            trans_m,
            rot2_rad,
        }
    }

    /// Applies the motion to `pose` without noise.
    pub fn apply(&self, pose: &Pose2) -> Pose2 {
        let heading = pose.yaw_rad + self.rot1_rad;
        Pose2::new(
            pose.x_m + self.trans_m * heading.cos(),
            pose.y_m + self.trans_m * heading.sin(),
            heading + self.rot2_rad,
        )
    }
}

#[inline]
fn gauss(rng: &mut Xoshiro256PlusPlus, sigma: f64) -> f64 {
    let z: f64 = rng.sample(StandardNormal);
    sigma * z
}

/// Samples the pose a particle at `pose` reaches when the odometry moved from `odom_prev` to
/// `odom_next`. `imu_yaw_change_rad` (ESE650 only) replaces the odometry's yaw change.
pub fn sample_odometry_motion(
    options: &OdometryModelOptions,
    pose: &Pose2,
    odom_prev: &Pose2,
    odom_next: &Pose2,
    imu_yaw_change_rad: Option<f64>,
    rng: &mut Xoshiro256PlusPlus,
) -> Pose2 {
    match options.model {
        OdometryModel::Thrun => {
            let d = OdometryDelta::between(odom_prev, odom_next);
            let (r1, t, r2) = (folded(d.rot1_rad), d.trans_m, folded(d.rot2_rad));
            let a = options;
            let s_r1 = (a.alpha1 * r1 * r1 + a.alpha2 * t * t).max(0.0).sqrt();
            let s_t = (a.alpha3 * t * t + a.alpha4 * (r1 * r1 + r2 * r2))
                .max(0.0)
                .sqrt();
            let s_r2 = (a.alpha1 * r2 * r2 + a.alpha2 * t * t).max(0.0).sqrt();
            let noisy = OdometryDelta {
                rot1_rad: d.rot1_rad - gauss(rng, s_r1),
                trans_m: t - gauss(rng, s_t),
                rot2_rad: d.rot2_rad - gauss(rng, s_r2),
            };
            noisy.apply(pose)
        }
        OdometryModel::Ese650 => {
            let mut rel = odom_prev.between(odom_next);
            if let Some(dyaw) = imu_yaw_change_rad {
                rel.yaw_rad = wrap_angle(dyaw);
            }
            let [sx, sy, syaw] = options.ese650_sigma;
            let noisy = Pose2::new(
                rel.x_m + gauss(rng, sx),
                rel.y_m + gauss(rng, sy),
                rel.yaw_rad + gauss(rng, syaw),
            );
            pose.compose(&noisy)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn noiseless_reproduces_odometry() {
        let a = Pose2::new(1.0, 2.0, 0.3);
        let b = Pose2::new(1.5, 2.8, -0.4);
        let d = OdometryDelta::between(&a, &b);
        let c = d.apply(&a);
        assert!((c.x_m - b.x_m).abs() < 1e-12 && (c.y_m - b.y_m).abs() < 1e-12);
        assert!(wrap_angle(c.yaw_rad - b.yaw_rad).abs() < 1e-12);
        let zero = OdometryModelOptions {
            alpha1: 0.0,
            alpha2: 0.0,
            alpha3: 0.0,
            alpha4: 0.0,
            ..OdometryModelOptions::default()
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        // applied to a particle elsewhere: the same motion in its own frame
        let p = Pose2::new(-3.0, 0.5, 2.0);
        let q = sample_odometry_motion(&zero, &p, &a, &b, None, &mut rng);
        let want = p.compose(&a.between(&b));
        assert!((q.x_m - want.x_m).abs() < 1e-12 && (q.y_m - want.y_m).abs() < 1e-12);
    }

    /// Turning in place with millimetres of wheel jitter, and driving backwards, have no
    /// meaningful direction of travel: the heading noise follows the turn, not the 180 deg
    /// the decomposition sees.
    #[test]
    fn heading_noise_follows_the_turn_when_turning_in_place_or_reversing() {
        let thrun = OdometryModelOptions {
            model: OdometryModel::Thrun,
            alpha1: 0.1,
            alpha2: 0.05,
            alpha3: 0.05,
            alpha4: 0.05,
            ..OdometryModelOptions::default()
        };
        let start = Pose2::new(0.0, 0.0, 0.0);
        for end in [
            Pose2::new(-0.005, 0.0, 10f64.to_radians()),
            Pose2::new(-0.5, 0.0, 0.0),
        ] {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
            let yaw: Vec<f64> = (0..4000)
                .map(|_| {
                    let p = sample_odometry_motion(&thrun, &start, &start, &end, None, &mut rng);
                    wrap_angle(p.yaw_rad - end.yaw_rad)
                })
                .collect();
            let std = (yaw.iter().map(|y| y * y).sum::<f64>() / yaw.len() as f64).sqrt();
            // Expected 0.08 and 0.16 rad (the translation's share); the bare decomposition
            // gives about 1.4 rad.
            assert!(std < 0.25, "{end:?}: heading noise {std} rad");
        }
    }

    #[test]
    fn noise_scales_with_alphas_and_is_seeded() {
        let a = Pose2::IDENTITY;
        let b = Pose2::new(1.0, 0.0, 0.0);
        let opts = OdometryModelOptions {
            alpha1: 0.0,
            alpha2: 0.0,
            alpha3: 0.01,
            alpha4: 0.0,
            ..OdometryModelOptions::default()
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let n = 20_000;
        let xs: Vec<f64> = (0..n)
            .map(|_| sample_odometry_motion(&opts, &a, &a, &b, None, &mut rng).x_m)
            .collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!((mean - 1.0).abs() < 0.005, "{mean}");
        assert!((var - 0.01).abs() < 0.001, "{var}"); // alpha3 * trans^2
        let mut r1 = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut r2 = Xoshiro256PlusPlus::seed_from_u64(3);
        let e = OdometryModelOptions::ese650();
        for _ in 0..10 {
            assert_eq!(
                sample_odometry_motion(&e, &a, &a, &b, Some(0.1), &mut r1),
                sample_odometry_motion(&e, &a, &a, &b, Some(0.1), &mut r2)
            );
        }
    }

    #[test]
    fn ese650_uses_imu_yaw() {
        let e = OdometryModelOptions {
            ese650_sigma: [0.0; 3],
            ..OdometryModelOptions::ese650()
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let a = Pose2::IDENTITY;
        let b = Pose2::new(0.5, 0.0, 0.2);
        let q = sample_odometry_motion(&e, &a, &a, &b, Some(-0.3), &mut rng);
        assert!((q.yaw_rad + 0.3).abs() < 1e-12 && (q.x_m - 0.5).abs() < 1e-12);
    }
}
