//! IMU yaw: its series from the IMU's messages, its value at any stamp, and the fusion of
//! odometry translation with IMU yaw (the ESE650 seed's: wheels measure distance well and
//! turning badly, a gyro the reverse).

use crate::geometry::{Pose2, StampedPose2, Trajectory, wrap_angle};

/// One IMU sample: stamp (ns), absolute yaw when the IMU gives an orientation, yaw rate.
pub type ImuSample = (i64, Option<f64>, f64);

/// The absolute yaw series `(stamp_ns, yaw_rad)` of time-ordered IMU samples: the
/// orientation's yaw when every sample has one, else the yaw rate integrated (trapezoid)
/// from 0. Samples whose stamp does not increase are left out.
pub fn yaw_series(samples: &[ImuSample]) -> Vec<(i64, f64)> {
    let mut kept: Vec<ImuSample> = Vec::with_capacity(samples.len());
    for &s in samples {
        if kept.last().is_none_or(|l| s.0 > l.0) {
            kept.push(s);
        }
    }
    if kept.iter().all(|s| s.1.is_some()) {
        return kept.iter().map(|s| (s.0, s.1.unwrap_or(0.0))).collect();
    }
    let mut yaw = 0.0;
    let mut out = Vec::with_capacity(kept.len());
    for (k, s) in kept.iter().enumerate() {
        if k > 0 {
            let p = kept[k - 1];
            yaw += 0.5 * (p.2 + s.2) * (s.0 - p.0) as f64 * 1e-9;
        }
        out.push((s.0, yaw));
    }
    out
}

/// Yaw of `series` at `stamp_ns` (interpolated, clamped to the ends); `None` when empty.
pub fn yaw_at(series: &[(i64, f64)], stamp_ns: i64) -> Option<f64> {
    let (first, last) = (series.first()?, series.last()?);
    if stamp_ns <= first.0 {
        return Some(first.1);
    }
    if stamp_ns >= last.0 {
        return Some(last.1);
    }
    let i = series.partition_point(|s| s.0 <= stamp_ns);
    let (a, b) = (series[i - 1], series[i]);
    let t = (stamp_ns - a.0) as f64 / (b.0 - a.0) as f64;
    Some(a.1 + t * wrap_angle(b.1 - a.1))
}

/// The odometry with each increment's turn replaced by the IMU's over the same interval:
/// the translation of an increment, in the body frame at its start, is kept.
pub fn fuse_odometry_with_imu_yaw(odometry: &Trajectory, series: &[(i64, f64)]) -> Trajectory {
    let p = &odometry.poses;
    let mut out: Vec<StampedPose2> = Vec::with_capacity(p.len());
    for (k, cur) in p.iter().enumerate() {
        let pose = match (k.checked_sub(1), out.last()) {
            (Some(j), Some(prev)) => {
                let inc = p[j].pose.between(&cur.pose);
                let turn = match (yaw_at(series, p[j].stamp_ns), yaw_at(series, cur.stamp_ns)) {
                    (Some(a), Some(b)) => wrap_angle(b - a),
                    _ => inc.yaw_rad,
                };
                prev.pose.compose(&Pose2::new(inc.x_m, inc.y_m, turn))
            }
            _ => cur.pose,
        };
        out.push(StampedPose2 {
            stamp_ns: cur.stamp_ns,
            pose,
        });
    }
    Trajectory::new(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn series_from_orientation_or_rate() {
        let s = yaw_series(&[
            (0, Some(0.1), 9.0),
            (10, Some(0.2), 9.0),
            (10, Some(5.0), 0.0),
        ]);
        assert_eq!(s, vec![(0, 0.1), (10, 0.2)]);
        let s = yaw_series(&[
            (0, None, 1.0),
            (1_000_000_000, None, 1.0),
            (2_000_000_000, None, 0.0),
        ]);
        assert_eq!(
            s,
            vec![(0, 0.0), (1_000_000_000, 1.0), (2_000_000_000, 1.5)]
        );
        assert_eq!(yaw_at(&s, 500_000_000), Some(0.5));
        assert_eq!(yaw_at(&[], 5), None);
    }

    #[test]
    fn fusion_keeps_translation_and_takes_the_imu_turn() {
        // the odometry says straight on; the IMU says a quarter turn after the first metre
        let odom = Trajectory::new(
            (0..3)
                .map(|k| StampedPose2 {
                    stamp_ns: k,
                    pose: Pose2::new(k as f64, 0.0, 0.0),
                })
                .collect(),
        );
        let imu = [
            (0, 0.0),
            (1, std::f64::consts::FRAC_PI_2),
            (2, std::f64::consts::FRAC_PI_2),
        ];
        let f = fuse_odometry_with_imu_yaw(&odom, &imu);
        let last = f.poses[2].pose;
        assert!(
            (last.x_m - 1.0).abs() < 1e-12 && (last.y_m - 1.0).abs() < 1e-12,
            "{last:?}"
        );
        assert!((last.yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }
}
