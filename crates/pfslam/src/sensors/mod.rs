//! Typed, timestamped sensor measurements and calibrations, independent of any file format.
//!
//! Readers in the `pfslam-io` crate produce these; everything downstream (motion, filter, map)
//! consumes them. Two shapes exist:
//! - [`CarDataset`]: the seed car's raw streams (encoder counts, FOG increments, LiDAR ranges)
//!   with its calibration, as recorded;
//! - [`Recording`]: the common input of mapping and SLAM: odometry poses, LiDAR scans with their
//!   geometry and mount, optional ground truth. Every source (car, humanoid, CARMEN, ROS bags,
//!   MCAP) is turned into a `Recording`.

pub mod humanoid;
pub mod reader_options;
pub mod stale;
pub mod sync;

use crate::geometry::{Rigid3, StampedPose2, Trajectory};
use serde::{Deserialize, Serialize};

/// One row of `encoder.csv`: cumulative wheel tick counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncoderSample {
    /// Time (ns).
    pub stamp_ns: i64,
    /// Cumulative left wheel count (ticks).
    pub left_count: i64,
    /// Cumulative right wheel count (ticks).
    pub right_count: i64,
}

/// One row of `fog.csv`: attitude increments since the previous row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FogSample {
    /// Time (ns).
    pub stamp_ns: i64,
    /// Roll increment (rad).
    pub delta_roll_rad: f64,
    /// Pitch increment (rad).
    pub delta_pitch_rad: f64,
    /// Yaw increment (rad), counter-clockwise positive about the body's z (up) axis.
    pub delta_yaw_rad: f64,
}

/// Beam geometry of a planar scanner: beam `i` points at `angle_min_rad + i *
/// angle_increment_rad` in the sensor's x-y plane (x forward, counter-clockwise positive).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LidarGeometry {
    /// Angle of the first beam (rad).
    pub angle_min_rad: f64,
    /// Angle step between beams (rad).
    pub angle_increment_rad: f64,
    /// Number of beams per scan.
    pub beam_count: usize,
    /// Shortest valid range (m); shorter readings are no returns. The sensor's own statement
    /// where the format has one (a ROS LaserScan's `range_min`), 0 for CARMEN logs; 2 m for
    /// the seeds' car and humanoid, whose reports drop the returns "too close to the
    /// vehicle".
    #[serde(default)]
    pub range_min_m: f32,
    /// Largest valid range (m); readings at or above it mean "no return".
    pub range_max_m: f32,
}

impl LidarGeometry {
    /// Why scans with these beams cannot be used, if they cannot.
    pub fn problem(&self) -> Option<String> {
        if self.beam_count == 0 {
            Some("no ranges".to_string())
        } else if !(self.angle_min_rad.is_finite() && self.angle_increment_rad.is_finite()) {
            Some("angle_min and angle_increment must be finite".to_string())
        } else if !(self.range_min_m >= 0.0 && self.range_max_m > self.range_min_m) {
            Some(format!(
                "range_min {} and range_max {} must satisfy 0 <= range_min < range_max",
                self.range_min_m, self.range_max_m
            ))
        } else {
            None
        }
    }

    /// The seed car's SICK LMS511: 286 beams from -5 deg in 0.666 deg steps, 2-80 m.
    pub fn ucsd_lms511() -> Self {
        LidarGeometry {
            angle_min_rad: (-5.0f64).to_radians(),
            angle_increment_rad: 0.666f64.to_radians(),
            beam_count: 286,
            range_min_m: 2.0,
            range_max_m: 80.0,
        }
    }

    /// Angle of beam `i` (rad).
    #[inline]
    pub fn beam_angle_rad(&self, i: usize) -> f64 {
        self.angle_min_rad + i as f64 * self.angle_increment_rad
    }
}

/// A set of scans stored flat. When every scan has `beam_count` beams (the usual case, and
/// the only one the car's CSV reader produces) scan `i` is
/// `ranges_m[i * beam_count .. (i + 1) * beam_count]`; once a scan of another length is pushed
/// with [`ScanSet::push_any`], each scan's start is kept instead and `beam_count` is the
/// largest count. Ranges are `f32` metres; `0.0` (or anything non-finite, or >= the sensor's
/// maximum) means "no return".
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ScanSet {
    /// Beams per scan (the largest, when scans differ).
    pub beam_count: usize,
    /// Time of each scan (ns).
    pub stamps_ns: Vec<i64>,
    /// All ranges, scan after scan (m).
    pub ranges_m: Vec<f32>,
    /// Start of each scan in `ranges_m` plus the end, when scans differ in length; empty when
    /// every scan has `beam_count` beams.
    starts: Vec<usize>,
}

impl ScanSet {
    /// An empty set for scans of `beam_count` beams.
    pub fn new(beam_count: usize) -> Self {
        ScanSet {
            beam_count,
            stamps_ns: Vec::new(),
            ranges_m: Vec::new(),
            starts: Vec::new(),
        }
    }

    /// Number of scans.
    #[inline]
    pub fn len(&self) -> usize {
        self.stamps_ns.len()
    }

    /// True when empty.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.stamps_ns.is_empty()
    }

    /// True when every scan has `beam_count` beams.
    #[inline]
    pub fn is_uniform(&self) -> bool {
        self.starts.is_empty()
    }

    /// The ranges of scan `i`.
    #[inline]
    pub fn ranges(&self, i: usize) -> &[f32] {
        if self.starts.is_empty() {
            &self.ranges_m[i * self.beam_count..(i + 1) * self.beam_count]
        } else {
            &self.ranges_m[self.starts[i]..self.starts[i + 1]]
        }
    }

    /// Appends a scan; `ranges_m.len()` must equal `beam_count` (checked by the caller, which
    /// knows the file and line to report).
    #[inline]
    pub fn push(&mut self, stamp_ns: i64, ranges_m: &[f32]) {
        debug_assert_eq!(ranges_m.len(), self.beam_count);
        self.push_any(stamp_ns, ranges_m);
    }

    /// Appends a scan of any length (a scanner whose beam count changes from scan to scan).
    pub fn push_any(&mut self, stamp_ns: i64, ranges_m: &[f32]) {
        if self.starts.is_empty() && ranges_m.len() != self.beam_count {
            if self.is_empty() {
                self.beam_count = ranges_m.len();
            } else {
                self.starts = (0..=self.len()).map(|i| i * self.beam_count).collect();
            }
        }
        self.stamps_ns.push(stamp_ns);
        self.ranges_m.extend_from_slice(ranges_m);
        if !self.starts.is_empty() {
            self.starts.push(self.ranges_m.len());
            self.beam_count = self.beam_count.max(ranges_m.len());
        }
    }

    /// Room for `n` more scans of `beam_count` beams, so that a store filled to a known
    /// size holds no spare capacity.
    pub fn reserve_scans(&mut self, n: usize) {
        self.stamps_ns.reserve(n);
        self.ranges_m.reserve(n * self.beam_count);
        if !self.starts.is_empty() {
            self.starts.reserve(n);
        }
    }

    /// The scans `keep` selects (indices in increasing order or not), in that order.
    pub fn select(&self, keep: &[usize]) -> ScanSet {
        let mut out = ScanSet::new(self.beam_count);
        for &i in keep {
            out.push_any(self.stamps_ns[i], self.ranges(i));
        }
        out
    }
}

/// Wheel encoder calibration (`EncoderParameter.txt`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EncoderParams {
    /// Ticks per wheel revolution.
    pub resolution_ticks: u32,
    /// Left wheel diameter (m).
    pub left_wheel_diameter_m: f64,
    /// Right wheel diameter (m).
    pub right_wheel_diameter_m: f64,
    /// Distance between the wheels (m).
    pub wheel_base_m: f64,
}

impl Default for EncoderParams {
    /// The seed car's calibration.
    fn default() -> Self {
        EncoderParams {
            resolution_ticks: 4096,
            left_wheel_diameter_m: 0.623479,
            right_wheel_diameter_m: 0.622806,
            wheel_base_m: 1.52439,
        }
    }
}

/// Intrinsics of one camera as OpenCV's calibration YAML stores them.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// 3x3 camera matrix K, row-major.
    pub camera_matrix: [f64; 9],
    /// Distortion model name (`plumb_bob`).
    pub distortion_model: String,
    /// Distortion coefficients (k1, k2, p1, p2, k3 for plumb_bob).
    pub distortion: Vec<f64>,
    /// 3x3 rectification rotation, row-major.
    pub rectification: [f64; 9],
    /// 3x4 projection matrix, row-major.
    pub projection: [f64; 12],
}

/// The stereo rig: both cameras, the baseline and the left camera's mount.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoCalibration {
    /// Left camera.
    pub left: CameraInfo,
    /// Right camera.
    pub right: CameraInfo,
    /// Baseline (m).
    pub baseline_m: f64,
    /// Left camera frame in the body frame.
    pub body_from_camera: Rigid3,
}

/// All calibration of the seed car.
#[derive(Debug, Clone, PartialEq)]
pub struct CarCalibration {
    /// Wheel encoders.
    pub encoder: EncoderParams,
    /// FOG mount.
    pub body_from_fog: Rigid3,
    /// LiDAR mount (equation 8 of the UCSD seed).
    pub body_from_lidar: Rigid3,
    /// LiDAR beam geometry.
    pub lidar: LidarGeometry,
    /// The stereo rig, when its files are present.
    pub stereo: Option<StereoCalibration>,
}

impl CarCalibration {
    /// The real calibration of the seed car (`shared/data/ucsd/param/`), built in: the default
    /// vehicle of the simulator. Numbers copied verbatim from the calibration files.
    pub fn ucsd() -> Self {
        CarCalibration {
            encoder: EncoderParams::default(),
            body_from_fog: Rigid3::from_row_major(
                [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                [-0.335, -0.035, 0.78],
            ),
            body_from_lidar: Rigid3::from_row_major(
                [
                    0.00130201,
                    0.796097,
                    0.605167,
                    0.999999,
                    -0.000419027,
                    -0.00160026,
                    -0.00102038,
                    0.605169,
                    -0.796097,
                ],
                [0.8349, -0.0126869, 1.76416],
            ),
            lidar: LidarGeometry::ucsd_lms511(),
            stereo: Some(StereoCalibration::ucsd()),
        }
    }
}

/// One of the seed car's cameras as its calibration YAML gives it (1280x560, `plumb_bob`),
/// the digits exactly as OpenCV wrote them.
struct UcsdCamera {
    camera_matrix: [f64; 9],
    distortion: [f64; 5],
    rectification: [f64; 9],
    projection: [f64; 12],
}

impl UcsdCamera {
    /// The camera as the stereo pipeline takes it.
    fn info(&self) -> CameraInfo {
        CameraInfo {
            width: 1280,
            height: 560,
            camera_matrix: self.camera_matrix,
            distortion_model: "plumb_bob".to_string(),
            distortion: self.distortion.to_vec(),
            rectification: self.rectification,
            projection: self.projection,
        }
    }
}

/// The seed car's left camera (`left_camera.yaml`).
#[allow(clippy::excessive_precision)]
const UCSD_LEFT_CAMERA: UcsdCamera = UcsdCamera {
    camera_matrix: [
        8.1690378992770002e+02,
        5.0510166700000003e-01,
        6.0850726281690004e+02,
        0.,
        8.1156803828490001e+02,
        2.6347599764440002e+02,
        0.,
        0.,
        1.,
    ],
    distortion: [
        -5.6143027800000002e-02,
        1.3952563200000001e-01,
        -1.2155906999999999e-03,
        -9.7281389999999998e-04,
        -8.0878168799999997e-02,
    ],
    rectification: [
        9.9996942080938533e-01,
        3.6208456669806118e-04,
        -7.8119357978017733e-03,
        -3.4412461339106772e-04,
        9.9999729518344416e-01,
        2.3002617343453663e-03,
        7.8127475572218850e-03,
        -2.2975031148170580e-03,
        9.9996684067775188e-01,
    ],
    projection: [
        7.7537235550066748e+02,
        0.,
        6.1947309112548828e+02,
        0.,
        0.,
        7.7537235550066748e+02,
        2.5718049049377441e+02,
        0.,
        0.,
        0.,
        1.,
        0.,
    ],
};

/// The seed car's right camera (`right_camera.yaml`).
#[allow(clippy::excessive_precision)]
const UCSD_RIGHT_CAMERA: UcsdCamera = UcsdCamera {
    camera_matrix: [
        8.1378205539589999e+02,
        3.4880336220000002e-01,
        6.1386419539320002e+02,
        0.,
        8.0852165574269998e+02,
        2.4941049348650000e+02,
        0.,
        0.,
        1.,
    ],
    distortion: [
        -5.4921981799999998e-02,
        1.4243657430000001e-01,
        7.5412299999999996e-05,
        -6.7560530000000001e-04,
        -8.5665408299999996e-02,
    ],
    rectification: [
        9.9998812489422739e-01,
        2.4089155522231892e-03,
        -4.2364131513853301e-03,
        -2.4186483057924992e-03,
        9.9999444433315865e-01,
        -2.2937835970734117e-03,
        4.2308640843048539e-03,
        2.3040027516418276e-03,
        9.9998839561287933e-01,
    ],
    projection: [
        7.7537235550066748e+02,
        0.,
        6.1947309112548828e+02,
        -3.6841758740842312e+02,
        0.,
        7.7537235550066748e+02,
        2.5718049049377441e+02,
        0.,
        0.,
        0.,
        1.,
        0.,
    ],
};

impl StereoCalibration {
    /// The seed car's stereo rig (`left_camera.yaml`, `right_camera.yaml`,
    /// `stereo_param.txt`, `Vehicle2Stereo.txt`), built in.
    pub fn ucsd() -> Self {
        StereoCalibration {
            left: UCSD_LEFT_CAMERA.info(),
            right: UCSD_RIGHT_CAMERA.info(),
            baseline_m: 0.475143600050775,
            body_from_camera: Rigid3::from_row_major(
                [
                    -0.00680499,
                    -0.0153215,
                    0.99985,
                    -0.999977,
                    0.000334627,
                    -0.00680066,
                    -0.000230383,
                    -0.999883,
                    -0.0153234,
                ],
                [1.64239, 0.247401, 1.58411],
            ),
        }
    }
}

/// The seed car's raw recording.
#[derive(Debug, Clone, PartialEq)]
pub struct CarDataset {
    /// Calibration.
    pub calibration: CarCalibration,
    /// Encoder rows, time ordered.
    pub encoder: Vec<EncoderSample>,
    /// FOG rows, time ordered.
    pub fog: Vec<FogSample>,
    /// LiDAR scans, time ordered.
    pub lidar: ScanSet,
    /// Stamps of the stereo pairs found on disk (images are loaded lazily).
    pub stereo_stamps_ns: Vec<i64>,
}

/// The common input of mapping and SLAM, whatever the source.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// A short name (file stem) for reports.
    pub name: String,
    /// Odometry poses in the odometry frame, time ordered (dead reckoning of the source).
    pub odometry: Trajectory,
    /// Optional absolute yaw from an IMU/gyro at odometry stamps or its own stamps (rad).
    pub imu_yaw: Option<Vec<(i64, f64)>>,
    /// Scans.
    pub scans: ScanSet,
    /// Beam geometry.
    pub lidar: LidarGeometry,
    /// Default LiDAR mount in the body frame.
    pub body_from_lidar: Rigid3,
    /// Per-scan LiDAR mount when the sensor moves on the body (a humanoid's head); same
    /// length as `scans` when present.
    pub body_from_lidar_per_scan: Option<Vec<Rigid3>>,
    /// Per-scan beam geometry when it changes from scan to scan (an interlaced scanner, a log
    /// that mixes lasers); same length as `scans` when present, else `lidar` holds for all.
    pub lidar_per_scan: Option<Vec<LidarGeometry>>,
    /// Ground-truth poses (simulator) when known.
    pub ground_truth: Option<Vec<StampedPose2>>,
}

impl Default for LidarGeometry {
    fn default() -> Self {
        LidarGeometry::ucsd_lms511()
    }
}

impl Recording {
    /// The mount of scan `i`.
    #[inline]
    pub fn body_from_lidar_at(&self, i: usize) -> &Rigid3 {
        match &self.body_from_lidar_per_scan {
            Some(v) => &v[i],
            None => &self.body_from_lidar,
        }
    }

    /// The beam geometry of scan `i`.
    #[inline]
    pub fn lidar_at(&self, i: usize) -> &LidarGeometry {
        match &self.lidar_per_scan {
            Some(v) => &v[i],
            None => &self.lidar,
        }
    }

    /// Keeps only the scans at `keep` (increasing indices), with their per-scan geometry and
    /// mount; the odometry and the other sensors stay as they are.
    pub fn keep_scans(&mut self, keep: &[usize]) {
        self.scans = self.scans.select(keep);
        if let Some(g) = &mut self.lidar_per_scan {
            *g = keep.iter().map(|&i| g[i]).collect();
        }
        if let Some(m) = &mut self.body_from_lidar_per_scan {
            *m = keep.iter().map(|&i| m[i]).collect();
        }
    }

    /// Moves the first `n` scans out into a recording of their own, with the odometry of
    /// their time span (and a pose on each side); this one keeps the later scans, and its
    /// odometry whole.
    pub fn split_front(&mut self, n: usize) -> Recording {
        let n = n.min(self.scans.len());
        let mut front = Recording {
            name: self.name.clone(),
            lidar: self.lidar,
            body_from_lidar: self.body_from_lidar,
            scans: self.scans.select(&(0..n).collect::<Vec<_>>()),
            body_from_lidar_per_scan: self
                .body_from_lidar_per_scan
                .as_ref()
                .map(|m| m[..n].to_vec()),
            lidar_per_scan: self.lidar_per_scan.as_ref().map(|g| g[..n].to_vec()),
            ..Recording::default()
        };
        self.keep_scans(&(n..self.scans.len()).collect::<Vec<_>>());
        let stamps = &front.scans.stamps_ns;
        if let (Some(&first), Some(&last)) = (stamps.first(), stamps.last()) {
            let poses = &self.odometry.poses;
            let a = poses
                .partition_point(|p| p.stamp_ns < first)
                .saturating_sub(1);
            let b = (poses.partition_point(|p| p.stamp_ns <= last) + 1).min(poses.len());
            front.odometry = Trajectory::new(poses[a..b].to_vec());
        }
        front
    }

    /// True when the mount or the beam geometry changes from scan to scan: a scan projector
    /// must then be re-aimed ([`crate::map::ScanProjector::aim`]) before each scan.
    #[inline]
    pub fn sensor_varies(&self) -> bool {
        self.body_from_lidar_per_scan.is_some() || self.lidar_per_scan.is_some()
    }
}
