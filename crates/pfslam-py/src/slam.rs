//! `pfslam.Slam`: the incremental API. The Rust [`Slam`] needs the LiDAR's geometry at
//! construction, so it is made at the first scan (the odometry before it is kept until
//! then). Scans wait here until the odometry reaches them, then go in one at a time: each
//! push hands exactly one scan to the filter, so every scan's pose is seen.

use crate::config::config_from;
use crate::convert::{nanoseconds, pose_tuple, poses_array, rigid_from};
use crate::errors::{PfslamError, pfslam_error};
use crate::occupancy::occupancy;
use crate::result::{RunContext, RunResult, run_result};
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pfslam::geometry::{Pose2, Rigid3, StampedPose2};
use pfslam::sensors::LidarGeometry;
use pfslam::{Config, OnlineError, ScanInput, SensorSetup, Slam};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use std::collections::VecDeque;

/// A scan waiting for the odometry to reach its stamp.
struct Waiting {
    stamp_ns: i64,
    ranges_m: Vec<f32>,
    lidar: LidarGeometry,
}

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
    last_odometry_ns: Option<i64>,
    last_scan_ns: Option<i64>,
    waiting: VecDeque<Waiting>,
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
            last_odometry_ns: None,
            last_scan_ns: None,
            waiting: VecDeque::new(),
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
        if !(x.is_finite() && y.is_finite() && yaw.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "odometry at {stamp_ns} ns: x, y and yaw must be finite, not {x}, {y}, {yaw}"
            )));
        }
        if let Some(last_ns) = self.last_odometry_ns
            && stamp_ns <= last_ns
        {
            let e = OnlineError::OutOfOrder {
                what: "odometry",
                stamp_ns,
                last_ns,
            };
            return Err(PyValueError::new_err(e.to_string()));
        }
        self.last_odometry_ns = Some(stamp_ns);
        let pose = StampedPose2 {
            stamp_ns,
            pose: Pose2::new(x, y, yaw),
        };
        let Some(slam) = self.slam.as_mut() else {
            self.early_odometry.push(pose);
            return Ok(None);
        };
        slam.push_odometry(stamp_ns, pose.pose)
            .map_err(|e| pfslam_error(&e))?;
        let latest = py.detach(|| self.handle_reached())?;
        latest.map(|p| pose_tuple(py, &p)).transpose()
    }

    /// A scan at `t` seconds: `ranges` (m, one per beam; 0, NaN or beyond the limits: no
    /// return) from `angle_min` (rad) in steps of `angle_increment` (rad, counter-clockwise),
    /// with the sensor's `range_min` and `range_max` (m). Returns its pose `(t, x, y, yaw)`,
    /// or None while it waits for the odometry to reach its stamp.
    #[pyo3(signature = (t, ranges, angle_min, angle_increment, range_min, range_max))]
    // The Python signature: the stamp, the ranges and the beams' four numbers.
    #[allow(clippy::too_many_arguments)]
    fn add_scan<'py>(
        &mut self,
        py: Python<'py>,
        t: f64,
        ranges: &Bound<'py, PyAny>,
        angle_min: f64,
        angle_increment: f64,
        range_min: f32,
        range_max: f32,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let beams = (angle_min, angle_increment, range_min, range_max);
        self.push_scan(py, nanoseconds(t)?, ranges, beams)
    }

    /// `add_scan` with the stamp in integer nanoseconds.
    #[pyo3(signature = (stamp_ns, ranges, angle_min, angle_increment, range_min, range_max))]
    #[allow(clippy::too_many_arguments)]
    fn add_scan_ns<'py>(
        &mut self,
        py: Python<'py>,
        stamp_ns: i64,
        ranges: &Bound<'py, PyAny>,
        angle_min: f64,
        angle_increment: f64,
        range_min: f32,
        range_max: f32,
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        let beams = (angle_min, angle_increment, range_min, range_max);
        self.push_scan(py, stamp_ns, ranges, beams)
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
        let Some(grid) = slam.map().map_err(|e| pfslam_error(&e))? else {
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
        let Some(mut slam) = self.slam.take() else {
            return Err(PfslamError::new_err("no scan was added: nothing to finish"));
        };
        let waiting = std::mem::take(&mut self.waiting);
        let (config, seed) = (self.config.clone(), self.seed);
        let (pipeline, recording) = py
            .detach(|| {
                for w in &waiting {
                    slam.push_scan_with(scan_input(w, slam_lidar(&slam)))?;
                }
                let recording = slam.recording().clone();
                Ok::<_, OnlineError>((slam.finish()?, recording))
            })
            .map_err(|e| pfslam_error(&e))?;
        let ctx = RunContext {
            recording: &recording,
            config: &config,
            seed,
            loaded: None,
        };
        run_result(py, &pipeline, &ctx)
    }

    fn __repr__(&self) -> String {
        format!(
            "Slam({} scans handled, {} waiting{})",
            self.poses.len(),
            self.waiting.len(),
            if self.finished { ", finished" } else { "" }
        )
    }
}

impl PySlam {
    /// Checks a scan, keeps it until the odometry reaches it and hands the filter what it
    /// can; the scan's pose once handled.
    fn push_scan<'py>(
        &mut self,
        py: Python<'py>,
        stamp_ns: i64,
        ranges: &Bound<'py, PyAny>,
        (angle_min_rad, angle_increment_rad, range_min_m, range_max_m): (f64, f64, f32, f32),
    ) -> PyResult<Option<Bound<'py, PyTuple>>> {
        self.check_running()?;
        let ranges_m = ranges_f32(ranges)?;
        let lidar = LidarGeometry {
            angle_min_rad,
            angle_increment_rad,
            beam_count: ranges_m.len(),
            range_min_m,
            range_max_m,
        };
        check_scan(stamp_ns, self.last_scan_ns, &lidar)?;
        self.last_scan_ns = Some(stamp_ns);
        self.start(lidar)?;
        self.waiting.push_back(Waiting {
            stamp_ns,
            ranges_m,
            lidar,
        });
        let before = self.poses.len();
        py.detach(|| self.handle_reached())?;
        let this = self.poses[before..]
            .last()
            .filter(|p| p.stamp_ns == stamp_ns);
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

    /// Makes the Rust filter at the first scan, with its geometry, and hands it the odometry
    /// kept until then.
    fn start(&mut self, lidar: LidarGeometry) -> PyResult<()> {
        if self.slam.is_some() {
            return Ok(());
        }
        let setup = SensorSetup {
            body_from_lidar: self.body_from_lidar,
            ..SensorSetup::planar("slam", lidar)
        };
        let mut slam =
            Slam::new(self.config.clone(), setup, self.seed).map_err(|e| pfslam_error(&e))?;
        for p in self.early_odometry.drain(..) {
            slam.push_odometry(p.stamp_ns, p.pose)
                .map_err(|e| pfslam_error(&e))?;
        }
        self.slam = Some(slam);
        Ok(())
    }

    /// Hands the filter every waiting scan the odometry reaches, one push each; the pose of
    /// the last one handled.
    fn handle_reached(&mut self) -> PyResult<Option<StampedPose2>> {
        let (Some(slam), Some(last_ns)) = (self.slam.as_mut(), self.last_odometry_ns) else {
            return Ok(None);
        };
        let mut latest = None;
        while let Some(w) = self.waiting.front() {
            if w.stamp_ns > last_ns {
                break;
            }
            let pose = slam
                .push_scan_with(scan_input(w, slam_lidar(slam)))
                .map_err(|e| pfslam_error(&e))?;
            // A scan before the odometry's first pose is left out: it reports no pose.
            if let Some(p) = pose.filter(|p| p.stamp_ns == w.stamp_ns) {
                self.poses.push(p);
                latest = Some(p);
            }
            self.waiting.pop_front();
        }
        Ok(latest)
    }
}

/// The setup's beams of `slam` (those of its first scan).
fn slam_lidar(slam: &Slam) -> LidarGeometry {
    slam.recording().lidar
}

/// `w` as a push, its beams given only when they differ from the setup's.
fn scan_input(w: &Waiting, setup: LidarGeometry) -> ScanInput<'_> {
    ScanInput {
        stamp_ns: w.stamp_ns,
        ranges_m: &w.ranges_m,
        lidar: (w.lidar != setup).then_some(w.lidar),
        body_from_lidar: None,
    }
}

/// Refuses a scan out of time order or with unusable beams.
fn check_scan(stamp_ns: i64, last_ns: Option<i64>, g: &LidarGeometry) -> PyResult<()> {
    if let Some(last_ns) = last_ns
        && stamp_ns < last_ns
    {
        let e = OnlineError::OutOfOrder {
            what: "scan",
            stamp_ns,
            last_ns,
        };
        return Err(PyValueError::new_err(e.to_string()));
    }
    let problem = if g.beam_count == 0 {
        Some("no ranges".to_string())
    } else if !(g.angle_min_rad.is_finite() && g.angle_increment_rad.is_finite()) {
        Some("angle_min and angle_increment must be finite".to_string())
    } else if !(g.range_min_m >= 0.0 && g.range_max_m > g.range_min_m) {
        Some(format!(
            "range_min {} and range_max {} must satisfy 0 <= range_min < range_max",
            g.range_min_m, g.range_max_m
        ))
    } else {
        None
    };
    match problem {
        Some(message) => Err(PyValueError::new_err(
            OnlineError::Scan { stamp_ns, message }.to_string(),
        )),
        None => Ok(()),
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
