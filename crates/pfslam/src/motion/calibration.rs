//! Odometry calibration against a reference trajectory: the distance scale and the yaw-rate
//! bias that make the odometry's relative motions match, say, the filter's.
//!
//! Why: the car's dead reckoning is locally excellent (FOG yaw, 4096-tick encoders) but its
//! distance scale is off by the wheels' diameter error (+0.2 / +0.4 % on the simulator), so
//! its error grows without bound; the filter's trajectory has no such scale error (it is
//! measured against the world), but it is locally noisier. The odometry corrected by the two
//! errors fitted to the filter's whole trajectory keeps the best of both (what the `[graph]`
//! back end is fed on the car, see [`crate::graph::BackEndInput`]).
//!
//! Model: the odometry's relative motion over an interval, `(dx, dy, dyaw)` over `dt`, is
//! truly `(s dx, s dy, dyaw - b dt)`: one scale `s` for distance (the mean of the two wheels'
//! errors when the yaw comes from a gyro) and one constant yaw-rate bias `b` (a gyro's bias,
//! or a leg odometry's heading drift). Fit: least squares over increments of the path (see
//! [`fit_odometry_calibration`]), every increment kept (no robust pass:
//! `docs/decisions/0043-calibration-fit-keeps-every-increment.md`).

use super::MotionError;
use crate::geometry::{Pose2, StampedPose2, wrap_angle};
use serde::{Deserialize, Serialize};

/// Options of the calibration fit (`[graph.calibration]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrationOptions {
    /// Fit the yaw-rate bias too (false: scale only, `b = 0`).
    pub fit_yaw_rate_bias: bool,
    /// The motions are compared over increments of at least this much odometry travel (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub increment_m: f64,
    /// A fitted scale farther than this from 1 is refused (the odometry or the reference is
    /// broken; relative, e.g. 0.1 = +-10 %).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_scale_error: f64,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            fit_yaw_rate_bias: true,
            increment_m: 0.5,
            max_scale_error: 0.1,
        }
    }
}

impl CalibrationOptions {
    /// Checks the values.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.increment_m.is_finite() && self.increment_m > 0.0) {
            return Err(format!(
                "increment_m must be finite and > 0, got {}",
                self.increment_m
            ));
        }
        if !(self.max_scale_error.is_finite() && self.max_scale_error > 0.0) {
            return Err(format!(
                "max_scale_error must be finite and > 0, got {}",
                self.max_scale_error
            ));
        }
        Ok(())
    }
}

/// The odometry's two intrinsic errors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometryCalibration {
    /// True distance over odometry distance.
    pub scale: f64,
    /// Subtracted from the odometry's yaw rate (rad/s).
    pub yaw_rate_bias_rad_per_s: f64,
}

impl OdometryCalibration {
    /// No correction.
    pub const IDENTITY: OdometryCalibration = OdometryCalibration {
        scale: 1.0,
        yaw_rate_bias_rad_per_s: 0.0,
    };

    /// The corrected odometry: starts at `odometry[0]` and composes each corrected relative
    /// motion. Empty in, empty out.
    pub fn apply(&self, odometry: &[StampedPose2]) -> Vec<StampedPose2> {
        let mut out = Vec::with_capacity(odometry.len());
        let Some(first) = odometry.first() else {
            return out;
        };
        let mut pose = first.pose;
        out.push(*first);
        for w in odometry.windows(2) {
            let rel = w[0].pose.between(&w[1].pose);
            let dt_s = (w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9;
            let corrected = Pose2::new(
                self.scale * rel.x_m,
                self.scale * rel.y_m,
                rel.yaw_rad - self.yaw_rate_bias_rad_per_s * dt_s,
            );
            pose = pose.compose(&corrected);
            pose.yaw_rad = wrap_angle(pose.yaw_rad);
            out.push(StampedPose2 {
                stamp_ns: w[1].stamp_ns,
                pose,
            });
        }
        out
    }
}

/// The result of [`fit_odometry_calibration`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CalibrationFit {
    /// The fitted errors.
    pub calibration: OdometryCalibration,
    /// RMS translation residual of the reference's increments after the correction (m).
    pub rms_m: f64,
    /// The same without correction (scale 1, no bias): what the correction gained.
    pub rms_uncorrected_m: f64,
    /// Pose pairs (common stamps) used.
    pub pairs: usize,
    /// Increments compared (`increment_m` of odometry travel or more each).
    pub increments: usize,
}

/// One increment: the odometry's and the reference's relative motion (each in its own body
/// frame at the increment's start) and its duration.
#[derive(Debug, Clone, Copy)]
struct Increment {
    odometry: Pose2,
    reference: Pose2,
    dt_s: f64,
}

impl Increment {
    /// Translation residual (m) of the reference after correcting the odometry.
    fn residual_m(&self, c: &OdometryCalibration) -> f64 {
        (self.reference.x_m - c.scale * self.odometry.x_m)
            .hypot(self.reference.y_m - c.scale * self.odometry.y_m)
    }
}

/// Least squares over the increments: `scale = sum(r . o) / sum(|o|^2)`, `bias = sum(o_yaw
/// - r_yaw) / sum(dt)` (0 without `fit_bias`).
fn solve(increments: &[Increment], fit_bias: bool) -> OdometryCalibration {
    let (mut ro, mut oo, mut dyaw, mut dt) = (0.0, 0.0, 0.0, 0.0);
    for inc in increments {
        let (o, r) = (&inc.odometry, &inc.reference);
        ro += r.x_m * o.x_m + r.y_m * o.y_m;
        oo += o.x_m * o.x_m + o.y_m * o.y_m;
        dyaw += o.yaw_rad - r.yaw_rad;
        dt += inc.dt_s;
    }
    OdometryCalibration {
        scale: if oo > 0.0 { ro / oo } else { 1.0 },
        yaw_rate_bias_rad_per_s: if fit_bias && dt > 0.0 { dyaw / dt } else { 0.0 },
    }
}

fn rms<I: Iterator<Item = f64>>(values: I) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
}

/// Fits the odometry's scale and yaw-rate bias so that the corrected odometry's relative
/// motions match `reference`'s. Poses are paired by equal stamps (both inputs time ordered)
/// and compared in increments of at least `increment_m` of odometry travel, each in its own
/// body frame (so the reference's heading errors do not leak into the scale).
///
/// Why increments and not the positions: the reference's errors (a filter's) are a random
/// walk, for which the ratio of the summed relative motions is the efficient estimator; a
/// least-squares fit of the positions weights that walk's slow excursions like a scale. On the
/// default simulated drive (true scale 1.00300, five filter seeds) the increments gave
/// 1.00326 / 1.00267 / 1.00293 / 1.00266 / 1.00285, a rigid-plus-scale fit of the positions
/// 1.00259 / 1.00258 / 1.00246 / 1.00261 / 1.00207.
pub fn fit_odometry_calibration(
    odometry: &[StampedPose2],
    reference: &[StampedPose2],
    opts: &CalibrationOptions,
) -> Result<CalibrationFit, MotionError> {
    opts.validate().map_err(MotionError::InvalidCalibration)?;
    // Pair by equal stamps (merge join).
    let mut pairs: Vec<(&StampedPose2, &StampedPose2)> = Vec::new();
    let mut j = 0;
    for o in odometry {
        while j < reference.len() && reference[j].stamp_ns < o.stamp_ns {
            j += 1;
        }
        if j < reference.len() && reference[j].stamp_ns == o.stamp_ns {
            pairs.push((o, &reference[j]));
        }
    }
    // Increments of at least `increment_m` of odometry travel (the last, shorter one is
    // dropped: it carries the same information per metre but little travel).
    let mut increments = Vec::new();
    let mut start = 0;
    let mut travel_m = 0.0;
    for k in 1..pairs.len() {
        travel_m += pairs[k - 1]
            .0
            .pose
            .between(&pairs[k].0.pose)
            .translation_norm_m();
        if travel_m >= opts.increment_m {
            let (o0, r0) = pairs[start];
            let (o1, r1) = pairs[k];
            let mut odometry = o0.pose.between(&o1.pose);
            let mut reference = r0.pose.between(&r1.pose);
            odometry.yaw_rad = wrap_angle(odometry.yaw_rad);
            reference.yaw_rad = wrap_angle(reference.yaw_rad);
            increments.push(Increment {
                odometry,
                reference,
                dt_s: (o1.stamp_ns - o0.stamp_ns) as f64 * 1e-9,
            });
            start = k;
            travel_m = 0.0;
        }
    }
    const MIN_INCREMENTS: usize = 10;
    if increments.len() < MIN_INCREMENTS {
        return Err(MotionError::Calibration(format!(
            "{} poses share a stamp with the reference, {} increments of {} m of travel; at \
             least {MIN_INCREMENTS} are needed",
            pairs.len(),
            increments.len(),
            opts.increment_m
        )));
    }
    let calibration = solve(&increments, opts.fit_yaw_rate_bias);
    let s = calibration.scale;
    if !(s.is_finite() && (s - 1.0).abs() <= opts.max_scale_error) {
        return Err(MotionError::Calibration(format!(
            "fitted scale {s:.5} is more than {} away from 1",
            opts.max_scale_error
        )));
    }
    Ok(CalibrationFit {
        calibration,
        rms_m: rms(increments.iter().map(|i| i.residual_m(&calibration))),
        rms_uncorrected_m: rms(increments
            .iter()
            .map(|i| i.residual_m(&OdometryCalibration::IDENTITY))),
        pairs: pairs.len(),
        increments: increments.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A winding 20 min drive sampled at 10 Hz: straight stretches, curves both ways.
    fn truth() -> Vec<StampedPose2> {
        let mut pose = Pose2::new(3.0, -2.0, 0.4);
        let mut out = vec![StampedPose2 {
            stamp_ns: 5_000_000_000,
            pose,
        }];
        for i in 1..12_000 {
            let t = i as f64 * 0.1;
            let v = 8.0 + 2.0 * (t / 37.0).sin();
            let w = 0.15 * (t / 23.0).sin() + 0.1 * (t / 71.0).cos();
            pose = pose.compose(&Pose2::new(v * 0.1, 0.0, w * 0.1));
            out.push(StampedPose2 {
                stamp_ns: 5_000_000_000 + i * 100_000_000,
                pose,
            });
        }
        out
    }

    /// The odometry a sensor with `calibration`'s errors would give for `truth`, in a frame
    /// of its own (rotated and shifted).
    fn odometry_of(truth: &[StampedPose2], calibration: &OdometryCalibration) -> Vec<StampedPose2> {
        let inverse = OdometryCalibration {
            scale: 1.0 / calibration.scale,
            yaw_rate_bias_rad_per_s: -calibration.yaw_rate_bias_rad_per_s,
        };
        let frame = Pose2::new(-40.0, 7.0, -1.1);
        inverse
            .apply(truth)
            .into_iter()
            .map(|p| StampedPose2 {
                stamp_ns: p.stamp_ns,
                pose: frame.compose(&p.pose),
            })
            .collect()
    }

    const ERRORS: OdometryCalibration = OdometryCalibration {
        scale: 1.003,
        yaw_rate_bias_rad_per_s: 2e-4,
    };

    #[test]
    fn identity_reproduces_the_odometry() {
        let t = truth();
        let out = OdometryCalibration::IDENTITY.apply(&t);
        assert_eq!(out.len(), t.len());
        for (a, b) in out.iter().zip(&t) {
            assert_eq!(a.stamp_ns, b.stamp_ns);
            assert!((a.pose.x_m - b.pose.x_m).abs() < 1e-9);
            assert!((a.pose.y_m - b.pose.y_m).abs() < 1e-9);
            assert!(wrap_angle(a.pose.yaw_rad - b.pose.yaw_rad).abs() < 1e-12);
        }
        assert!(OdometryCalibration::IDENTITY.apply(&[]).is_empty());
    }

    #[test]
    fn fit_recovers_scale_and_bias() {
        let t = truth();
        let odo = odometry_of(&t, &ERRORS);
        let fit = fit_odometry_calibration(&odo, &t, &CalibrationOptions::default()).unwrap();
        assert!(
            (fit.calibration.scale - ERRORS.scale).abs() < 1e-6,
            "{fit:?}"
        );
        assert!(
            (fit.calibration.yaw_rate_bias_rad_per_s - ERRORS.yaw_rate_bias_rad_per_s).abs() < 1e-8,
            "{fit:?}"
        );
        assert!(fit.rms_m < 1e-6, "{fit:?}");
        assert!(fit.rms_uncorrected_m > 1e-3, "{fit:?}");
        assert_eq!(fit.pairs, t.len());
        assert!(fit.increments > 10_000, "{fit:?}");
        // Corrected, the odometry moves as the truth does.
        let corrected = fit.calibration.apply(&odo);
        for k in (0..t.len() - 100).step_by(97) {
            let c = corrected[k].pose.between(&corrected[k + 100].pose);
            let g = t[k].pose.between(&t[k + 100].pose);
            assert!((c.x_m - g.x_m).hypot(c.y_m - g.y_m) < 1e-6, "{c:?} {g:?}");
            assert!(wrap_angle(c.yaw_rad - g.yaw_rad).abs() < 1e-9);
        }
        // Scale only: the bias stays 0, and the scale is unaffected (each increment is
        // compared in its own body frame, so heading errors do not leak into it).
        let opts = CalibrationOptions {
            fit_yaw_rate_bias: false,
            ..CalibrationOptions::default()
        };
        let scale_only = fit_odometry_calibration(&odo, &t, &opts).unwrap();
        assert_eq!(scale_only.calibration.yaw_rate_bias_rad_per_s, 0.0);
        assert!(
            (scale_only.calibration.scale - ERRORS.scale).abs() < 1e-6,
            "{scale_only:?}"
        );
    }

    #[test]
    fn fit_refuses_bad_inputs() {
        let t = truth();
        // No common stamps.
        let shifted: Vec<StampedPose2> = t
            .iter()
            .map(|p| StampedPose2 {
                stamp_ns: p.stamp_ns + 1,
                pose: p.pose,
            })
            .collect();
        let e = fit_odometry_calibration(&t, &shifted, &CalibrationOptions::default());
        assert!(matches!(e, Err(MotionError::Calibration(_))), "{e:?}");
        // A scale far beyond the allowed error.
        let odo = odometry_of(
            &t,
            &OdometryCalibration {
                scale: 1.5,
                yaw_rate_bias_rad_per_s: 0.0,
            },
        );
        let e = fit_odometry_calibration(&odo, &t, &CalibrationOptions::default());
        assert!(matches!(e, Err(MotionError::Calibration(_))), "{e:?}");
        let bad = CalibrationOptions {
            increment_m: f64::NAN,
            ..CalibrationOptions::default()
        };
        let e = fit_odometry_calibration(&t, &t, &bad);
        assert!(
            matches!(e, Err(MotionError::InvalidCalibration(_))),
            "{e:?}"
        );
    }
}
