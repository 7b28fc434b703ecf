//! `pfslam.Slam`: the incremental API. The Rust [`Slam`] needs the LiDAR's geometry at
//! construction, so it is made at the first scan (the odometry before it is kept until
//! then). Every push goes straight to it; the pose of each scan it handles comes back as a
//! [`SlamEvent::Pose`].

use crate::config::config_from;
use crate::convert::{nanoseconds, pose_tuple, poses_array, rigid_from};
use crate::errors::{PfslamError, online_error};
use crate::occupancy::occupancy;
use crate::result::{RunContext, RunResult, run_result};
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pfslam::geometry::{Pose2, Rigid3, StampedPose2};
use pfslam::pipeline::PipelineOptions;
use pfslam::sensors::LidarGeometry;
use pfslam::slam::SlamEvent;
use pfslam::{Config, OnlineError, ScanInput, SensorSetup, Slam, check_imu_yaw, check_odometry};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

/// The filter fed as the data arrive: `Slam(config=None, seed=1, body_from_lidar=None)`.
///
/// Odometry and scans come in time order, each stream on its own; a scan is handled once the
/// odometry reaches its stamp. After `finish()` the result equals `run`'s on the same data
/// bit for bit. `body_from_lidar`: the LiDAR's mount, a 4x4 matrix or `(x_m, y_m, yaw_rad)`.
/// Stamps in seconds become nanoseconds as `round(t * 1e9)` (float64, halves away from
/// zero); the `*_ns` methods take integer nanoseconds.
#[pyclass(module = "pfslam", name = "Slam")]
pub struct PySlam {
    config: Config,
    seed: u64,
    body_from_lidar: Rigid3,
    /// Made at the first scan; `None` after `finish`.
    slam: Option<Slam>,
    finished: bool,
    /// The odometry pushed before the first scan.
    early_odometry: Vec<StampedPose2>,
    /// The IMU yaw pushed before the first scan.
    early_imu: Vec<(i64, f64)>,
    /// The pose reported after each scan handled.
    poses: Vec<StampedPose2>,
}

#[pymethods]
impl PySlam {
    #[new]
    #[pyo3(signature = (config = None, seed = 1, body_from_lidar = None))]
    fn new(
        config: Option<&Bound<'_, PyAny>>,
        seed: u64,
        body_from_lidar: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let body_from_lidar = match body_from_lidar {
            Some(m) if !m.is_none() => rigid_from(m)?,
            _ => Rigid3::IDENTITY,
        };
        Ok(PySlam {
            config: config_from(config)?,
            seed,
            body_from_lidar,
            slam: None,
            finished: false,
            early_odometry: Vec::new(),
            early_imu: Vec::new(),
            poses: Vec::new(),
        })
    }

    /// Odometry pose at `t` seconds (rounded to the nearest nanosecond); returns the pose of
    /// the latest scan it let the filter handle, else None.
    fn add_odometry<'py>(
        &mut self,
        py: Python<'py>,
        t: f64,
        x: f64,
        y: f64,
        yaw: f64,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        self.add_odometry_ns(py, nanoseconds(t)?, x, y, yaw)
    }

    /// `add_odometry` with the stamp in integer nanoseconds.
    fn add_odometry_ns<'py>(
        &mut self,
        py: Python<'py>,
        stamp_ns: i64,
        x: f64,
        y: f64,
        yaw: f64,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        self.check_running()?;
        let pose = Pose2::new(x, y, yaw);
        let Some(slam) = self.slam.as_mut() else {
            // checked as the filter would, before it exists
            let last_ns = self.early_odometry.last().map(|p| p.stamp_ns);
            check_odometry(stamp_ns, &pose, last_ns).map_err(|e| online_error(&e))?;
            self.early_odometry.push(StampedPose2 { stamp_ns, pose });
            return Ok(None);
        };
        let new = push_collect(py, &mut self.poses, |obs| {
            slam.push_odometry_observed(stamp_ns, pose, obs)
        })?;
        new.last().map(|p| pose_tuple(py, p)).transpose()
    }

    /// The IMU's absolute yaw (rad) at `t` seconds, for the motion model that takes the turn
    /// from it (`[filter.odometry_model] model = "ese650"`); once any is given, a scan also
    /// waits for the IMU to reach its stamp. Returns like `add_odometry`.
    fn add_imu_yaw<'py>(
        &mut self,
        py: Python<'py>,
        t: f64,
        yaw: f64,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        self.check_running()?;
        let stamp_ns = nanoseconds(t)?;
        let Some(slam) = self.slam.as_mut() else {
            let last_ns = self.early_imu.last().map(|s| s.0);
            check_imu_yaw(stamp_ns, yaw, last_ns).map_err(|e| online_error(&e))?;
            self.early_imu.push((stamp_ns, yaw));
            return Ok(None);
        };
        let new = push_collect(py, &mut self.poses, |obs| {
            slam.push_imu_yaw_observed(stamp_ns, yaw, obs)
        })?;
        new.last().map(|p| pose_tuple(py, p)).transpose()
    }

    /// A scan at `t` seconds: `ranges` (m, one per beam; 0, NaN or beyond the limits: no
    /// return) from `angle_min` (rad) in steps of `angle_increment` (rad, counter-clockwise),
    /// with the sensor's `range_min` and `range_max` (m). Returns its pose `(t, x, y, yaw)`,
    /// or None while it waits for the odometry to reach its stamp.
    #[pyo3(signature = (t, ranges, angle_min, angle_increment, range_min, range_max))]
    // The parameters are the Python signature's alone: the `Python` token comes from `ranges`.
    fn add_scan<'py>(
        &mut self,
        t: f64,
        ranges: &Bound<'py, PyAny>,
        angle_min: f64,
        angle_increment: f64,
        range_min: f32,
        range_max: f32,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let beams = (angle_min, angle_increment, range_min, range_max);
        self.push_scan(nanoseconds(t)?, ranges, beams)
    }

    /// `add_scan` with the stamp in integer nanoseconds.
    #[pyo3(signature = (stamp_ns, ranges, angle_min, angle_increment, range_min, range_max))]
    fn add_scan_ns<'py>(
        &mut self,
        stamp_ns: i64,
        ranges: &Bound<'py, PyAny>,
        angle_min: f64,
        angle_increment: f64,
        range_min: f32,
        range_max: f32,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let beams = (angle_min, angle_increment, range_min, range_max);
        self.push_scan(stamp_ns, ranges, beams)
    }

    /// The pose `(t, x, y, yaw)` of the latest scan handled, None before the first.
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyTuple>>> {
        self.poses.last().map(|p| pose_tuple(py, p)).transpose()
    }

    /// `(N, 4)` float64 rows `t_s, x_m, y_m, yaw_rad`: the pose reported after each scan
    /// handled so far (the online estimates; `finish` gives the final trajectory).
    fn trajectory<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        poses_array(py, &self.poses)
    }

    /// The filter's current map (its best particle's) as `(logodds, resolution_m, origin)`
    /// in the form of `Result`'s `occupancy`, `resolution_m` and `origin`; None before the
    /// first scan is handled.
    fn occupancy<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let Some(slam) = self.slam.as_mut() else {
            return Ok(None);
        };
        let Some(grid) = slam.map().map_err(|e| online_error(&e))? else {
            return Ok(None);
        };
        let map = occupancy(py, grid);
        let fields = (map.logodds, map.resolution_m, map.origin);
        Ok(Some(fields.into_pyobject(py)?))
    }

    /// Ends the run: the scans still waiting count as beyond the odometry, then the back end
    /// and the final map, as `pfslam run` does. The object takes no data after it.
    fn finish(&mut self, py: Python<'_>) -> PyResult<RunResult> {
        self.check_running()?;
        self.finished = true;
        let Some(slam) = self.slam.take() else {
            return Err(PfslamError::new_err("no scan was added: nothing to finish"));
        };
        let (config, seed, poses) = (self.config.clone(), self.seed, &mut self.poses);
        let options = PipelineOptions::default();
        let (pipeline, recording) = py
            .detach(|| slam.finish_observed(&options, &mut collect(poses)))
            .map_err(|e| online_error(&e))?;
        let ctx = RunContext {
            recording: &recording,
            config: &config,
            seed,
            loaded: None,
        };
        run_result(py, &pipeline, &ctx)
    }

    fn __repr__(&self) -> String {
        let handled = self.poses.len();
        match (&self.slam, self.finished) {
            (_, true) => format!("Slam({handled} scans handled, finished)"),
            (None, false) => "Slam(no scan yet)".to_string(),
            (Some(s), false) => {
                // A long run lets go of consolidated scans: this counts the ones it holds.
                let held = s.recording().scans.len();
                format!("Slam({handled} scans handled, {held} held)")
            }
        }
    }
}

impl PySlam {
    /// Checks a scan, keeps it until the odometry reaches it and hands the filter what it
    /// can; the scan's pose once handled.
    fn push_scan<'py>(
        &mut self,
        stamp_ns: i64,
        ranges: &Bound<'py, PyAny>,
        (angle_min_rad, angle_increment_rad, range_min_m, range_max_m): (f64, f64, f32, f32),
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let py = ranges.py();
        self.check_running()?;
        let ranges_m = ranges_f32(ranges)?;
        let lidar = LidarGeometry {
            angle_min_rad,
            angle_increment_rad,
            beam_count: ranges_m.len(),
            range_min_m,
            range_max_m,
        };
        self.start(stamp_ns, lidar)?;
        let (Some(slam), poses) = (self.slam.as_mut(), &mut self.poses) else {
            return Ok(None);
        };
        let input = ScanInput {
            stamp_ns,
            ranges_m: &ranges_m,
            lidar: (lidar != slam.recording().lidar).then_some(lidar),
            body_from_lidar: None,
        };
        let new = push_collect(py, poses, |obs| slam.push_scan_observed(input, obs))?;
        // its pose, when the odometry already reached it
        let this = new.iter().rfind(|p| p.stamp_ns == stamp_ns);
        this.map(|p| pose_tuple(py, p)).transpose()
    }

    fn check_running(&self) -> PyResult<()> {
        match self.finished {
            true => Err(PfslamError::new_err(
                "finish() was called: this Slam takes no more data",
            )),
            false => Ok(()),
        }
    }

    /// Makes the Rust filter at the first scan (stamped `stamp_ns`), with its geometry, and
    /// hands it the odometry kept until then.
    fn start(&mut self, stamp_ns: i64, lidar: LidarGeometry) -> PyResult<()> {
        if self.slam.is_some() {
            return Ok(());
        }
        if let Some(message) = lidar.problem() {
            return Err(online_error(&OnlineError::Scan { stamp_ns, message }));
        }
        let setup = SensorSetup {
            body_from_lidar: self.body_from_lidar,
            ..SensorSetup::planar("slam", lidar)
        };
        let mut slam =
            Slam::new(self.config.clone(), setup, self.seed).map_err(|e| online_error(&e))?;
        for p in self.early_odometry.drain(..) {
            slam.push_odometry(p.stamp_ns, p.pose)
                .map_err(|e| online_error(&e))?;
        }
        for (stamp_ns, yaw_rad) in self.early_imu.drain(..) {
            slam.push_imu_yaw(stamp_ns, yaw_rad)
                .map_err(|e| online_error(&e))?;
        }
        self.slam = Some(slam);
        Ok(())
    }
}

/// Hands one input to the filter with the GIL released, keeping the poses it reports in
/// `poses`; returns the new ones.
fn push_collect<'a, F>(
    py: Python<'_>,
    poses: &'a mut Vec<StampedPose2>,
    push: F,
) -> PyResult<&'a [StampedPose2]>
where
    F: FnOnce(&mut dyn FnMut(SlamEvent<'_>)) -> Result<Option<StampedPose2>, OnlineError> + Send,
{
    let before = poses.len();
    py.detach(|| push(&mut collect(poses)))
        .map_err(|e| online_error(&e))?;
    Ok(&poses[before..])
}

/// An observer keeping the pose of each scan handled.
fn collect(poses: &mut Vec<StampedPose2>) -> impl FnMut(SlamEvent<'_>) + '_ {
    |ev| {
        if let SlamEvent::Pose(p) = ev {
            poses.push(p);
        }
    }
}

/// The ranges as float32: a float32 array without a copy through Python, else any sequence
/// of numbers.
fn ranges_f32(o: &Bound<'_, PyAny>) -> PyResult<Vec<f32>> {
    if let Ok(a) = o.cast::<PyArray1<f32>>() {
        return Ok(a.readonly().as_array().to_vec());
    }
    o.extract::<Vec<f32>>()
        .map_err(|_| PyValueError::new_err("ranges: a 1-D sequence of numbers"))
}
