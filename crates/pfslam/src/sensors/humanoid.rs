//! The humanoid (THOR-like): odometry poses, IMU attitude, head joints and a Hokuyo UTM-30LX
//! on the head. [`HumanoidDataset`] holds one recording; [`humanoid_recording`] turns it into
//! the common [`Recording`]. Its file layout is `pfslam_io::humanoid`.
//!
//! The chain: `body_from_lidar = T(body_to_neck) Rz(neck_yaw) T(neck_to_head)
//! Ry(head_pitch) T(head_to_lidar)`; the body's attitude is `Rz(yaw) Ry(pitch) Rx(roll)` from
//! the IMU.

use crate::geometry::{Rigid3, StampedPose2, Trajectory};
use crate::sensors::{LidarGeometry, Recording, ScanSet};

/// The head/neck chain and the head LiDAR.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HumanoidCalibration {
    /// Neck yaw joint in the body frame (m).
    pub body_to_neck_m: [f64; 3],
    /// Head pitch joint in the neck frame (m).
    pub neck_to_head_m: [f64; 3],
    /// LiDAR origin in the head frame (m).
    pub head_to_lidar_m: [f64; 3],
    /// LiDAR beams.
    pub lidar: LidarGeometry,
}

impl Default for HumanoidCalibration {
    /// A THOR-like head: neck at 1.25 m, a Hokuyo UTM-30LX (1081 beams over 270 deg, 30 m)
    /// 12 cm above and 5 cm in front of the pitch axis.
    fn default() -> Self {
        HumanoidCalibration {
            body_to_neck_m: [0.0, 0.0, 1.25],
            neck_to_head_m: [0.0, 0.0, 0.08],
            head_to_lidar_m: [0.05, 0.0, 0.12],
            lidar: LidarGeometry {
                angle_min_rad: (-135.0f64).to_radians(),
                angle_increment_rad: 0.25f64.to_radians(),
                beam_count: 1081,
                range_min_m: 2.0,
                range_max_m: 30.0,
            },
        }
    }
}

impl HumanoidCalibration {
    /// The LiDAR in the body frame for these joint angles.
    pub fn body_from_lidar(&self, neck_yaw_rad: f64, head_pitch_rad: f64) -> Rigid3 {
        let neck = Rigid3::from_rpy(0.0, 0.0, neck_yaw_rad, self.body_to_neck_m);
        let head = Rigid3::from_rpy(0.0, head_pitch_rad, 0.0, self.neck_to_head_m);
        let lidar = Rigid3::from_rpy(0.0, 0.0, 0.0, self.head_to_lidar_m);
        neck.compose(&head).compose(&lidar)
    }
}

/// Head joint angles at one time (one row of the humanoid layout's `joints.csv`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointSample {
    /// Time (ns).
    pub stamp_ns: i64,
    /// Neck yaw (rad, counter-clockwise).
    pub neck_yaw_rad: f64,
    /// Head pitch (rad, positive = looking down).
    pub head_pitch_rad: f64,
}

/// IMU attitude at one time (one row of the humanoid layout's `imu.csv`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Time (ns).
    pub stamp_ns: i64,
    /// Roll (rad).
    pub roll_rad: f64,
    /// Pitch (rad).
    pub pitch_rad: f64,
    /// Yaw (rad).
    pub yaw_rad: f64,
}

/// A humanoid recording.
#[derive(Debug, Clone, PartialEq)]
pub struct HumanoidDataset {
    /// Head chain and LiDAR.
    pub calibration: HumanoidCalibration,
    /// Odometry poses.
    pub odometry: Vec<StampedPose2>,
    /// IMU attitude.
    pub imu: Vec<ImuSample>,
    /// Head joint angles.
    pub joints: Vec<JointSample>,
    /// LiDAR scans.
    pub lidar: ScanSet,
}

/// Linear interpolation of a sampled signal at `stamp_ns` (clamped at the ends); `None` when
/// there is no sample.
fn interpolate<T, const N: usize>(
    samples: &[T],
    stamp_ns: i64,
    get: impl Fn(&T) -> (i64, [f64; N]),
) -> Option<[f64; N]> {
    let first = samples.first()?;
    let i = samples.partition_point(|s| get(s).0 <= stamp_ns);
    if i == 0 {
        return Some(get(first).1);
    }
    let (ta, a) = get(&samples[i - 1]);
    if i == samples.len() || ta == stamp_ns {
        return Some(a);
    }
    let (tb, b) = get(&samples[i]);
    let f = (stamp_ns - ta) as f64 / (tb - ta) as f64;
    let mut out = [0.0; N];
    for k in 0..N {
        out[k] = a[k] + f * (b[k] - a[k]);
    }
    Some(out)
}

/// The common [`Recording`] of a humanoid dataset: odometry poses, IMU yaw, scans, and a
/// per-scan LiDAR mount from the joint angles (interpolated at each scan stamp) tilted by the
/// IMU's roll and pitch — i.e. the LiDAR in the gravity-levelled body frame, so a `z` filter
/// on the mapped points removes floor hits. No ground truth (the simulator adds it).
pub fn humanoid_recording(ds: &HumanoidDataset, name: &str) -> Recording {
    let cal = &ds.calibration;
    let per_scan: Vec<Rigid3> = ds
        .lidar
        .stamps_ns
        .iter()
        .map(|&t| {
            let [yaw, pitch] = interpolate(&ds.joints, t, |j| {
                (j.stamp_ns, [j.neck_yaw_rad, j.head_pitch_rad])
            })
            .unwrap_or([0.0, 0.0]);
            let [roll_b, pitch_b] =
                interpolate(&ds.imu, t, |s| (s.stamp_ns, [s.roll_rad, s.pitch_rad]))
                    .unwrap_or([0.0, 0.0]);
            let level_from_body = Rigid3::from_rpy(roll_b, pitch_b, 0.0, [0.0, 0.0, 0.0]);
            level_from_body.compose(&cal.body_from_lidar(yaw, pitch))
        })
        .collect();
    Recording {
        name: name.to_string(),
        odometry: Trajectory::new(ds.odometry.clone()),
        imu_yaw: Some(ds.imu.iter().map(|s| (s.stamp_ns, s.yaw_rad)).collect()),
        scans: ds.lidar.clone(),
        lidar: cal.lidar,
        body_from_lidar: cal.body_from_lidar(0.0, 0.0),
        body_from_lidar_per_scan: Some(per_scan),
        lidar_per_scan: None,
        ground_truth: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chain_looks_down_when_pitched() {
        let c = HumanoidCalibration::default();
        let t = c.body_from_lidar(0.0, 0.3);
        // beam 540 points straight ahead in the LiDAR frame
        let d = t.rotation * nalgebra::Vector3::new(1.0, 0.0, 0.0);
        assert!((d[2] + 0.3f64.sin()).abs() < 1e-12);
        let t = c.body_from_lidar(std::f64::consts::FRAC_PI_2, 0.0);
        let d = t.rotation * nalgebra::Vector3::new(1.0, 0.0, 0.0);
        assert!((d[1] - 1.0).abs() < 1e-12);
        let o = t.translation;
        assert!((o[2] - 1.45).abs() < 1e-12 && (o[1] - 0.05).abs() < 1e-12);
    }
}
