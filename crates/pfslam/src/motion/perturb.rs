//! Odometry degraded the way real odometry goes wrong, to check that SLAM recovers a known
//! path: a distance scale error, a turning scale error, a yaw drift per metre, a random walk
//! in position and heading, and occasional slips (part of a step lost, a sudden turn).
//!
//! Severity levels ([`OdometryErrors::level`]): 0 none; 1 a well-calibrated robot (about
//! 2.5 m ATE over the 500 m of Radish's Intel log); 2 about as bad as the Intel Research
//! Lab recording's own odometry (about 22 m there, where the Intel bag's odometry is 24 m
//! off pfslam's trajectory); 3 worse than any robot one would map with on purpose.

use crate::geometry::{Pose2, StampedPose2, Trajectory};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

/// The errors added to odometry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometryErrors {
    /// Relative error of every distance (its sign is drawn per run).
    pub scale_error: f64,
    /// Relative error of every turn (its sign is drawn per run).
    pub turn_scale_error: f64,
    /// Heading drift per metre travelled (rad/m; sign drawn per run).
    pub yaw_drift_rad_per_m: f64,
    /// Position random walk (m per square root of metre travelled, per axis).
    pub walk_xy_m: f64,
    /// Heading random walk (rad per square root of metre travelled or radian turned).
    pub walk_yaw_rad: f64,
    /// Slips per metre travelled.
    pub slips_per_m: f64,
    /// Largest sudden turn of a slip (rad); a slip also loses up to half of its step.
    pub slip_yaw_rad: f64,
}

impl OdometryErrors {
    /// No error at all (level 0).
    pub const NONE: OdometryErrors = OdometryErrors {
        scale_error: 0.0,
        turn_scale_error: 0.0,
        yaw_drift_rad_per_m: 0.0,
        walk_xy_m: 0.0,
        walk_yaw_rad: 0.0,
        slips_per_m: 0.0,
        slip_yaw_rad: 0.0,
    };

    /// The errors of severity `level` (0-3; see the module docs).
    pub fn level(level: u8) -> Option<OdometryErrors> {
        let deg = |d: f64| d.to_radians();
        let e = |s, t, drift, wxy, wyaw, slips, slip_yaw| OdometryErrors {
            scale_error: s,
            turn_scale_error: t,
            yaw_drift_rad_per_m: drift,
            walk_xy_m: wxy,
            walk_yaw_rad: wyaw,
            slips_per_m: slips,
            slip_yaw_rad: slip_yaw,
        };
        match level {
            0 => Some(Self::NONE),
            1 => Some(e(0.01, 0.01, deg(0.1), 0.005, deg(0.1), 0.002, deg(2.0))),
            2 => Some(e(0.02, 0.05, deg(1.5), 0.01, deg(0.5), 0.005, deg(5.0))),
            3 => Some(e(0.05, 0.08, deg(3.0), 0.02, deg(1.0), 0.01, deg(10.0))),
            _ => None,
        }
    }
}

/// `odometry` with `errors` added to each of its increments, drawn from `seed`: the first
/// pose is kept, every later one is the previous perturbed pose composed with the perturbed
/// increment. The same seed gives the same odometry.
pub fn perturb_odometry(odometry: &Trajectory, errors: &OdometryErrors, seed: u64) -> Trajectory {
    if *errors == OdometryErrors::NONE {
        // no error: the poses as they are, not recomposed from their increments
        return odometry.clone();
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut sign = || if rng.random::<bool>() { 1.0 } else { -1.0 };
    let (s_scale, s_turn, s_drift) = (sign(), sign(), sign());
    let p = &odometry.poses;
    let mut out: Vec<StampedPose2> = Vec::with_capacity(p.len());
    for (k, cur) in p.iter().enumerate() {
        let pose = match out.last() {
            Some(prev) => {
                let inc = p[k - 1].pose.between(&cur.pose);
                prev.pose.compose(&perturb_step(
                    &inc,
                    errors,
                    [s_scale, s_turn, s_drift],
                    &mut rng,
                ))
            }
            None => cur.pose,
        };
        out.push(StampedPose2 {
            stamp_ns: cur.stamp_ns,
            pose,
        });
    }
    Trajectory::new(out)
}

/// One increment with the errors added (`signs`: of the scale, turn and drift errors).
fn perturb_step(
    inc: &Pose2,
    e: &OdometryErrors,
    signs: [f64; 3],
    rng: &mut Xoshiro256PlusPlus,
) -> Pose2 {
    let d = inc.x_m.hypot(inc.y_m);
    let turned = inc.yaw_rad.abs();
    let mut normal = || -> f64 { rng.sample(StandardNormal) };
    let scale = 1.0 + signs[0] * e.scale_error;
    let walk = e.walk_xy_m * d.sqrt();
    let mut x = inc.x_m * scale + walk * normal();
    let mut y = inc.y_m * scale + walk * normal();
    let mut yaw = inc.yaw_rad * (1.0 + signs[1] * e.turn_scale_error)
        + signs[2] * e.yaw_drift_rad_per_m * d
        + e.walk_yaw_rad * (d + turned).sqrt() * normal();
    if e.slips_per_m > 0.0 && rng.random::<f64>() < e.slips_per_m * d {
        let kept = 1.0 - 0.5 * rng.random::<f64>();
        x *= kept;
        y *= kept;
        yaw += e.slip_yaw_rad * (2.0 * rng.random::<f64>() - 1.0);
    }
    Pose2::new(x, y, yaw)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square_drive() -> Trajectory {
        // 4 x 25 m around a square, 0.1 m steps, quarter turns at the corners
        let mut poses = Vec::new();
        let mut pose = Pose2::IDENTITY;
        let mut t = 0;
        for _ in 0..4 {
            for _ in 0..250 {
                pose = pose.compose(&Pose2::new(0.1, 0.0, 0.0));
                poses.push(StampedPose2 { stamp_ns: t, pose });
                t += 1;
            }
            pose = pose.compose(&Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        }
        Trajectory::new(poses)
    }

    fn end_gap(a: &Trajectory, b: &Trajectory) -> f64 {
        let (p, q) = (a.poses.last().unwrap().pose, b.poses.last().unwrap().pose);
        (p.x_m - q.x_m).hypot(p.y_m - q.y_m)
    }

    #[test]
    fn levels_grow_and_seeds_repeat() {
        let drive = square_drive();
        let zero = perturb_odometry(&drive, &OdometryErrors::level(0).unwrap(), 1);
        assert!(zero.poses == drive.poses, "level 0 changes nothing");
        let mut gaps = Vec::new();
        for level in 1..=3 {
            let e = OdometryErrors::level(level).unwrap();
            let a = perturb_odometry(&drive, &e, 7);
            assert!(
                a.poses == perturb_odometry(&drive, &e, 7).poses,
                "same seed"
            );
            assert!(
                a.poses != perturb_odometry(&drive, &e, 8).poses,
                "another seed"
            );
            // the mean end error over seeds grows with the level
            let mean: f64 = (0..20)
                .map(|s| end_gap(&perturb_odometry(&drive, &e, s), &drive))
                .sum::<f64>()
                / 20.0;
            gaps.push(mean);
        }
        assert!(gaps[0] < gaps[1] && gaps[1] < gaps[2], "{gaps:?}");
        assert!(gaps[0] > 0.1, "{gaps:?}");
        assert!(OdometryErrors::level(4).is_none());
    }
}
