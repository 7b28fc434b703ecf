//! Odometry calibration against a reference trajectory: the distance scale and the yaw-rate
//! bias that make the odometry fit, say, the filter's trajectory best.
//!
//! Why: the car's dead reckoning is locally excellent (FOG yaw, 4096-tick encoders) but its
//! distance scale is off by the wheels' diameter error (+0.2 / +0.4 % on the simulator), which
//! grows without bound; the filter's trajectory has no such scale error (it is measured
//! against the world), but it is locally noisier than the odometry. Fitting the odometry's
//! two intrinsic errors to the filter's whole trajectory keeps the best of both: on the default
//! simulated drive the fitted odometry is within 0.07 % of the true scale although the filter's
//! poses wander by 0.2 m (what the `[graph]` back end then builds on, see
//! [`crate::graph::BackEndInput`]).
//!
//! Model: the odometry's relative motion between consecutive poses, `(dx, dy, dyaw)` over
//! `dt`, is truly `(s dx, s dy, dyaw - b dt)`: one scale `s` for distance (the mean of the two
//! wheels' errors when the yaw comes from a gyro) and one constant yaw-rate bias `b` (a gyro's
//! bias, or a leg odometry's heading drift). Fit: positions are linear in `s` for a given `b`,
//! so each `b` has a closed-form best similarity (2-D Umeyama: scale, rotation, translation)
//! of the odometry onto the reference; `b` itself is found by a scan over
//! `[-max, max]` and a golden-section search around the best scan point. One robust pass drops
//! the pairs whose residual exceeds `trim_sigmas` times the first fit's RMS (a filter that lost
//! its way for a while) and fits again.

use super::MotionError;
use crate::geometry::{Pose2, StampedPose2, align_points_2d, wrap_angle};
use serde::{Deserialize, Serialize};

/// Options of the calibration fit (`[graph.calibration]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrationOptions {
    /// Fit the yaw-rate bias too (false: scale only, `b = 0`).
    pub fit_yaw_rate_bias: bool,
    /// The bias is searched in `[-this, this]` (rad/s).
    pub max_yaw_rate_bias_rad_per_s: f64,
    /// A fitted scale farther than this from 1 is refused (the odometry or the reference is
    /// broken; relative, e.g. 0.1 = +-10 %).
    pub max_scale_error: f64,
    /// Pairs whose residual exceeds this many times the first fit's RMS are dropped before
    /// the second fit (0 = no second fit).
    pub trim_sigmas: f64,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            fit_yaw_rate_bias: true,
            max_yaw_rate_bias_rad_per_s: 0.01,
            max_scale_error: 0.1,
            trim_sigmas: 3.0,
        }
    }
}

impl CalibrationOptions {
    /// Checks the values.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.max_yaw_rate_bias_rad_per_s.is_finite()
            && self.max_yaw_rate_bias_rad_per_s >= 0.0)
        {
            return Err(format!(
                "max_yaw_rate_bias_rad_per_s must be finite and >= 0, got {}",
                self.max_yaw_rate_bias_rad_per_s
            ));
        }
        if !(self.max_scale_error.is_finite() && self.max_scale_error > 0.0) {
            return Err(format!(
                "max_scale_error must be finite and > 0, got {}",
                self.max_scale_error
            ));
        }
        if !(self.trim_sigmas.is_finite() && self.trim_sigmas >= 0.0) {
            return Err(format!(
                "trim_sigmas must be finite and >= 0, got {}",
                self.trim_sigmas
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
    /// `reference_from_odometry`: the rigid transform that puts the corrected odometry
    /// (as [`OdometryCalibration::apply`] gives it) onto the reference.
    pub alignment: Pose2,
    /// RMS position residual of the fit (m), over the pairs kept.
    pub rms_m: f64,
    /// RMS position residual of the uncorrected odometry after its best rigid alignment
    /// (m), over the same pairs: what the correction gained.
    pub rms_uncorrected_m: f64,
    /// Pose pairs (common stamps) used.
    pub pairs: usize,
    /// Pairs dropped by the robust pass.
    pub trimmed: usize,
}

/// Positions of the odometry `relative` (to its first pose) corrected by the bias `b` with
/// scale 1, at the paired indices.
fn corrected_positions(
    relative: &[StampedPose2],
    bias_rad_per_s: f64,
    paired: &[usize],
    out: &mut Vec<[f64; 2]>,
) {
    out.clear();
    let c = OdometryCalibration {
        scale: 1.0,
        yaw_rate_bias_rad_per_s: bias_rad_per_s,
    }
    .apply(relative);
    out.extend(paired.iter().map(|&i| [c[i].pose.x_m, c[i].pose.y_m]));
}

/// One similarity fit for a given bias: (alignment, scale, RMS residual).
fn fit_for_bias(
    relative: &[StampedPose2],
    reference: &[[f64; 2]],
    paired: &[usize],
    keep: &[bool],
    bias: f64,
    scratch: &mut Vec<[f64; 2]>,
) -> (Pose2, f64, f64) {
    corrected_positions(relative, bias, paired, scratch);
    let pairs: Vec<([f64; 2], [f64; 2])> = scratch
        .iter()
        .zip(reference)
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|((a, b), _)| (*a, *b))
        .collect();
    let (t, s) = align_points_2d(&pairs, true);
    let rms = rms_residual(&pairs, &t, s);
    (t, s, rms)
}

fn residual(a: &[f64; 2], b: &[f64; 2], t: &Pose2, s: f64) -> f64 {
    let (x, y) = t.transform_point(s * a[0], s * a[1]);
    (x - b[0]).hypot(y - b[1])
}

fn rms_residual(pairs: &[([f64; 2], [f64; 2])], t: &Pose2, s: f64) -> f64 {
    if pairs.is_empty() {
        return 0.0;
    }
    let sum: f64 = pairs
        .iter()
        .map(|(a, b)| residual(a, b, t, s).powi(2))
        .sum();
    (sum / pairs.len() as f64).sqrt()
}

/// The best bias in `[lo, hi]`: a scan of `SCAN` points, then a golden-section search in the
/// interval around the best one.
fn search_bias(lo: f64, hi: f64, cost: &mut dyn FnMut(f64) -> f64) -> f64 {
    const SCAN: usize = 41;
    if hi <= lo {
        return lo;
    }
    let step = (hi - lo) / (SCAN - 1) as f64;
    let mut best = (f64::INFINITY, lo);
    for i in 0..SCAN {
        let b = lo + step * i as f64;
        let c = cost(b);
        if c < best.0 {
            best = (c, b);
        }
    }
    let (mut a, mut d) = ((best.1 - step).max(lo), (best.1 + step).min(hi));
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let mut b = d - g * (d - a);
    let mut c = a + g * (d - a);
    let (mut fb, mut fc) = (cost(b), cost(c));
    for _ in 0..60 {
        if fb < fc {
            d = c;
            c = b;
            fc = fb;
            b = d - g * (d - a);
            fb = cost(b);
        } else {
            a = b;
            b = c;
            fb = fc;
            c = a + g * (d - a);
            fc = cost(c);
        }
    }
    let mid = 0.5 * (a + d);
    if best.0 <= fb.min(fc) { best.1 } else { mid }
}

/// Fits the odometry's scale and yaw-rate bias so that the corrected odometry matches
/// `reference` best (least squares over positions, after the best rigid alignment). Poses are
/// paired by equal stamps; both inputs must be time ordered.
pub fn fit_odometry_calibration(
    odometry: &[StampedPose2],
    reference: &[StampedPose2],
    opts: &CalibrationOptions,
) -> Result<CalibrationFit, MotionError> {
    opts.validate().map_err(MotionError::InvalidCalibration)?;
    // Pair by equal stamps (merge join).
    let mut paired = Vec::new();
    let mut ref_xy = Vec::new();
    let mut j = 0;
    for (i, o) in odometry.iter().enumerate() {
        while j < reference.len() && reference[j].stamp_ns < o.stamp_ns {
            j += 1;
        }
        if j < reference.len() && reference[j].stamp_ns == o.stamp_ns {
            paired.push(i);
            ref_xy.push([reference[j].pose.x_m, reference[j].pose.y_m]);
        }
    }
    const MIN_PAIRS: usize = 10;
    if paired.len() < MIN_PAIRS {
        return Err(MotionError::Calibration(format!(
            "{} poses share a stamp with the reference; at least {MIN_PAIRS} are needed",
            paired.len()
        )));
    }
    let max_b = match opts.fit_yaw_rate_bias {
        true => opts.max_yaw_rate_bias_rad_per_s,
        false => 0.0,
    };
    // Positions are linear in the scale about the start: fit relative to the first pose.
    let inv_first = odometry[0].pose.inverse();
    let relative: Vec<StampedPose2> = odometry
        .iter()
        .map(|p| StampedPose2 {
            stamp_ns: p.stamp_ns,
            pose: inv_first.compose(&p.pose),
        })
        .collect();
    let odometry_rel = &relative;
    let mut keep = vec![true; paired.len()];
    let mut scratch = Vec::new();
    let fit = |keep: &[bool], scratch: &mut Vec<[f64; 2]>| {
        let mut cost =
            |b: f64| fit_for_bias(odometry_rel, &ref_xy, &paired, keep, b, &mut Vec::new()).2;
        let b = search_bias(-max_b, max_b, &mut cost);
        let (t, s, rms) = fit_for_bias(odometry_rel, &ref_xy, &paired, keep, b, scratch);
        (b, t, s, rms)
    };
    let (mut b, mut t, mut s, mut rms) = fit(&keep, &mut scratch);
    let mut trimmed = 0;
    if opts.trim_sigmas > 0.0 && rms > 0.0 {
        // `scratch` holds the positions corrected with the first fit's bias.
        for (k, (a, r)) in keep.iter_mut().zip(scratch.iter().zip(&ref_xy)) {
            if residual(a, r, &t, s) > opts.trim_sigmas * rms {
                *k = false;
                trimmed += 1;
            }
        }
        if trimmed > 0 && paired.len() - trimmed >= MIN_PAIRS {
            (b, t, s, rms) = fit(&keep, &mut scratch);
        }
    }
    if !(s.is_finite() && (s - 1.0).abs() <= opts.max_scale_error) {
        return Err(MotionError::Calibration(format!(
            "fitted scale {s:.5} is more than {} away from 1",
            opts.max_scale_error
        )));
    }
    // The uncorrected odometry's rigid fit over the same pairs, for the report.
    corrected_positions(odometry_rel, 0.0, &paired, &mut scratch);
    let plain: Vec<([f64; 2], [f64; 2])> = scratch
        .iter()
        .zip(&ref_xy)
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|((a, r), _)| (*a, *r))
        .collect();
    let (t_plain, _) = align_points_2d(&plain, false);
    let rms_uncorrected_m = rms_residual(&plain, &t_plain, 1.0);
    // The fit used the odometry relative to its first pose; `apply` starts at the first
    // pose itself.
    let alignment = t.compose(&odometry[0].pose.inverse());
    Ok(CalibrationFit {
        calibration: OdometryCalibration {
            scale: s,
            yaw_rate_bias_rad_per_s: b,
        },
        alignment,
        rms_m: rms,
        rms_uncorrected_m,
        pairs: paired.len(),
        trimmed,
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
        assert!(fit.rms_m < 1e-3, "{fit:?}");
        assert!(fit.rms_uncorrected_m > 10.0, "{fit:?}");
        assert_eq!((fit.pairs, fit.trimmed), (t.len(), 0));
        // Corrected and put onto the reference by the alignment, the odometry is the truth.
        let corrected = fit.calibration.apply(&odo);
        for (c, g) in corrected.iter().zip(&t).step_by(97) {
            let p = fit.alignment.compose(&c.pose);
            assert!(
                (p.x_m - g.pose.x_m).hypot(p.y_m - g.pose.y_m) < 5e-3,
                "{p:?} {g:?}"
            );
            assert!(wrap_angle(p.yaw_rad - g.pose.yaw_rad).abs() < 1e-5);
        }
        // Scale only: the bias stays 0 and the fit is worse.
        let opts = CalibrationOptions {
            fit_yaw_rate_bias: false,
            ..CalibrationOptions::default()
        };
        let scale_only = fit_odometry_calibration(&odo, &t, &opts).unwrap();
        assert_eq!(scale_only.calibration.yaw_rate_bias_rad_per_s, 0.0);
        assert!(scale_only.rms_m > 100.0 * fit.rms_m, "{scale_only:?}");
    }

    /// A reference that lost its way for a while (5 % of its poses 4 m off) and is noisy
    /// elsewhere: the robust pass drops the outliers and the fit stays close.
    #[test]
    fn fit_survives_a_reference_with_outliers() {
        let t = truth();
        let odo = odometry_of(&t, &ERRORS);
        let mut reference = t.clone();
        for (i, p) in reference.iter_mut().enumerate() {
            let wobble = 0.05 * ((i as f64) * 0.7).sin();
            p.pose.x_m += wobble;
            p.pose.y_m -= wobble;
            if (5000..5600).contains(&i) {
                p.pose.x_m += 4.0;
            }
        }
        let fit =
            fit_odometry_calibration(&odo, &reference, &CalibrationOptions::default()).unwrap();
        assert!(fit.trimmed >= 600, "{fit:?}");
        assert!(
            (fit.calibration.scale - ERRORS.scale).abs() < 1e-4,
            "{fit:?}"
        );
        assert!(
            (fit.calibration.yaw_rate_bias_rad_per_s - ERRORS.yaw_rate_bias_rad_per_s).abs() < 1e-6,
            "{fit:?}"
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
            trim_sigmas: f64::NAN,
            ..CalibrationOptions::default()
        };
        let e = fit_odometry_calibration(&t, &t, &bad);
        assert!(
            matches!(e, Err(MotionError::InvalidCalibration(_))),
            "{e:?}"
        );
    }
}
