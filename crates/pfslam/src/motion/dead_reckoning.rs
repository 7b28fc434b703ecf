//! Dead reckoning of the car (the seed's prediction-only filter with one particle and no
//! noise) and the car's [`Recording`].

use super::{MotionError, MotionOptions, YawSource, step_pose, wheel_distances_m};
use crate::geometry::{Pose2, StampedPose2, Trajectory};
use crate::sensors::sync::CumulativeYaw;
use crate::sensors::{CarDataset, Recording};

/// The motion between two consecutive encoder rows: what the particle filter's prediction
/// consumes (`v = distance_m / dt_s`, `omega = dyaw_rad / dt_s`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryStep {
    /// Stamp of the later encoder row (ns); the step covers `(previous stamp, stamp_ns]`.
    pub stamp_ns: i64,
    /// Duration (s).
    pub dt_s: f64,
    /// Mean distance of the two wheels (m).
    pub distance_m: f64,
    /// Yaw change (rad), from the FOG or the wheels per [`MotionOptions::yaw_source`].
    pub dyaw_rad: f64,
}

/// The odometry increments between consecutive encoder rows (one fewer than rows).
pub fn odometry_steps(
    ds: &CarDataset,
    opts: &MotionOptions,
) -> Result<Vec<OdometryStep>, MotionError> {
    let enc = &ds.encoder;
    if enc.is_empty() {
        return Err(MotionError::NoEncoder);
    }
    if let Some(i) = enc.windows(2).position(|w| w[1].stamp_ns <= w[0].stamp_ns) {
        return Err(MotionError::NotIncreasing {
            index: i + 1,
            stamp_ns: enc[i + 1].stamp_ns,
        });
    }
    let fog_yaw = match opts.yaw_source {
        YawSource::Fog => Some(CumulativeYaw::from_fog(&ds.fog).ok_or(MotionError::NoFog)?),
        YawSource::Wheels => None,
    };
    if let Some(y) = &fog_yaw
        && y.max_gap_ns() > 20 * y.median_period_ns()
    {
        tracing::warn!(
            "FOG rows have a gap of {:.3} s (median spacing {:.6} s): its rotation is spread uniformly over the gap",
            y.max_gap_ns() as f64 * 1e-9,
            y.median_period_ns() as f64 * 1e-9
        );
    }
    let params = &ds.calibration.encoder;
    let mut uncovered = 0usize;
    let steps: Vec<OdometryStep> = enc
        .windows(2)
        .map(|w| {
            let (a, b) = (&w[0], &w[1]);
            let (sl, sr) = wheel_distances_m(
                params,
                b.left_count - a.left_count,
                b.right_count - a.right_count,
            );
            let wheel_yaw = (sr - sl) / params.wheel_base_m;
            let dyaw_rad = match &fog_yaw {
                Some(y) if y.covers(a.stamp_ns, b.stamp_ns) => y.increment(a.stamp_ns, b.stamp_ns),
                Some(_) => {
                    uncovered += 1;
                    wheel_yaw
                }
                None => wheel_yaw,
            };
            OdometryStep {
                stamp_ns: b.stamp_ns,
                dt_s: (b.stamp_ns - a.stamp_ns) as f64 * 1e-9,
                distance_m: 0.5 * (sl + sr),
                dyaw_rad,
            }
        })
        .collect();
    if uncovered > 0 {
        tracing::warn!(
            "{uncovered} of {} encoder intervals lie outside the FOG's time span: their yaw comes from the wheels",
            steps.len()
        );
    }
    Ok(steps)
}

/// Dead reckoning: the pose at every encoder stamp, starting at the identity at the first
/// row, stepped with [`MotionOptions::step`] and no noise.
pub fn dead_reckon(ds: &CarDataset, opts: &MotionOptions) -> Result<Trajectory, MotionError> {
    opts.validate()?;
    let steps = odometry_steps(ds, opts)?;
    let mut poses = Vec::with_capacity(steps.len() + 1);
    let mut pose = Pose2::IDENTITY;
    poses.push(StampedPose2 {
        stamp_ns: ds.encoder[0].stamp_ns,
        pose,
    });
    for s in &steps {
        pose = step_pose(&pose, s.distance_m, s.dyaw_rad, opts.step);
        poses.push(StampedPose2 {
            stamp_ns: s.stamp_ns,
            pose,
        });
    }
    Ok(Trajectory::new(poses))
}

/// The car's [`Recording`]: odometry = dead reckoning at encoder stamps, the LiDAR scans,
/// beam geometry and mount from the calibration, and (FOG yaw source) the FOG's cumulative
/// yaw at encoder stamps relative to the first as `imu_yaw`.
pub fn car_recording(
    ds: &CarDataset,
    opts: &MotionOptions,
    name: &str,
) -> Result<Recording, MotionError> {
    let odometry = dead_reckon(ds, opts)?;
    let imu_yaw = match opts.yaw_source {
        YawSource::Fog => CumulativeYaw::from_fog(&ds.fog).map(|y| {
            let y0 = y.yaw_at(ds.encoder[0].stamp_ns);
            ds.encoder
                .iter()
                .map(|e| (e.stamp_ns, y.yaw_at(e.stamp_ns) - y0))
                .collect()
        }),
        YawSource::Wheels => None,
    };
    Ok(Recording {
        name: name.to_string(),
        odometry,
        imu_yaw,
        scans: ds.lidar.clone(),
        lidar: ds.calibration.lidar,
        body_from_lidar: ds.calibration.body_from_lidar,
        body_from_lidar_per_scan: None,
        lidar_per_scan: None,
        ground_truth: None,
    })
}

/// [`car_recording`] that moves the LiDAR scans out of `ds` (left empty) instead of copying
/// them: they are most of a car dataset's memory (133 MB of the full-size recording). On
/// error `ds` is left as it was.
pub fn car_recording_taking_scans(
    ds: &mut CarDataset,
    opts: &MotionOptions,
    name: &str,
) -> Result<Recording, MotionError> {
    let scans = std::mem::take(&mut ds.lidar);
    // The copy made here is of the now empty scan set.
    match car_recording(ds, opts, name) {
        Ok(mut rec) => {
            rec.scans = scans;
            Ok(rec)
        }
        Err(e) => {
            ds.lidar = scans;
            Err(e)
        }
    }
}
