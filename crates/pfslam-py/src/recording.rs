//! `pfslam.read_recording`: a recording file's scans, odometry and mount as numpy arrays.

use crate::config::config_from;
use crate::convert::{geometry_dict, poses_array, rigid_array, to_python};
use crate::errors::pfslam_error;
use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2, PyUntypedArrayMethods};
use pfslam::sensors::ScanSet;
use pfslam_io::run_file::load_file;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::PathBuf;

/// A recording as read, before any SLAM.
#[pyclass(module = "pfslam", name = "Recording", frozen, get_all)]
pub struct PyRecording {
    /// A short name (the file's stem).
    pub name: String,
    /// `(S,)` int64 stamps of the scans (ns).
    pub scan_stamps_ns: Py<PyArray1<i64>>,
    /// `(S, B)` float32 ranges (m) when every scan has `B` beams, else a list of `(B_i,)`
    /// arrays.
    pub ranges: Py<PyAny>,
    /// The beams' geometry (`angle_min_rad`, `angle_increment_rad`, `beam_count`,
    /// `range_min_m`, `range_max_m`).
    pub lidar: Py<PyDict>,
    /// Each scan's geometry when they differ, else None.
    pub lidar_per_scan: Py<PyAny>,
    /// `(M, 4)` float64 odometry rows `t_s, x_m, y_m, yaw_rad` (in its own frame).
    pub odometry: Py<PyArray2<f64>>,
    /// `(M,)` int64 stamps of the odometry (ns).
    pub odometry_stamps_ns: Py<PyArray1<i64>>,
    /// `4x4` float64 homogeneous transform of the LiDAR's mount on the body.
    pub body_from_lidar: Py<PyArray2<f64>>,
    /// `(K, 4)` ground truth rows like `odometry`, or None.
    pub ground_truth: Py<PyAny>,
    /// What the reader read, kept, dropped and repaired.
    pub account: Py<PyAny>,
}

#[pymethods]
impl PyRecording {
    fn __repr__(&self, py: Python<'_>) -> String {
        let scans = self.scan_stamps_ns.bind(py).len();
        let odometry = self.odometry_stamps_ns.bind(py).len();
        format!(
            "Recording({:?}, {scans} scans, {odometry} odometry poses)",
            self.name
        )
    }
}

/// Reads a dataset as `pfslam run` reads it: a recording file (CARMEN log, ROS 1 bag, MCAP),
/// a rosbag2 directory, or a directory of the car's or the humanoid's layout.
///
/// `config` (None, TOML text or a dict) selects topics and the span through `[input]`.
#[pyfunction]
#[pyo3(signature = (path, config = None))]
pub fn read_recording(
    py: Python<'_>,
    path: PathBuf,
    config: Option<&Bound<'_, PyAny>>,
) -> PyResult<PyRecording> {
    let config = config_from(config)?;
    let opened = py
        .detach(|| load_file(&path, &config))
        .map_err(|e| pfslam_error(&e))?;
    let rec = &opened.recording;
    let stamps: &[i64] = &rec.scans.stamps_ns;
    let odometry = &rec.odometry.poses;
    let per_scan = match &rec.lidar_per_scan {
        None => py.None(),
        Some(g) => PyList::new(
            py,
            g.iter()
                .map(|g| geometry_dict(py, g))
                .collect::<PyResult<Vec<_>>>()?,
        )?
        .into_any()
        .unbind(),
    };
    let ground_truth = match &rec.ground_truth {
        None => py.None(),
        Some(gt) => poses_array(py, gt)?.into_any().unbind(),
    };
    Ok(PyRecording {
        name: rec.name.clone(),
        scan_stamps_ns: PyArray1::from_slice(py, stamps).unbind(),
        ranges: ranges(py, &rec.scans)?,
        lidar: geometry_dict(py, &rec.lidar)?.unbind(),
        lidar_per_scan: per_scan,
        odometry: poses_array(py, odometry)?.unbind(),
        odometry_stamps_ns: PyArray1::from_vec(py, odometry.iter().map(|p| p.stamp_ns).collect())
            .unbind(),
        body_from_lidar: rigid_array(py, &rec.body_from_lidar)?.unbind(),
        ground_truth,
        account: to_python(py, &opened.account)?.unbind(),
    })
}

/// The ranges as one `(S, B)` array, or a list of arrays when the beam counts differ.
fn ranges(py: Python<'_>, scans: &ScanSet) -> PyResult<Py<PyAny>> {
    if scans.is_uniform() {
        let flat = scans.ranges_m.clone();
        let array = Array2::from_shape_vec((scans.len(), scans.beam_count), flat)
            .map_err(|e| crate::errors::PfslamError::new_err(e.to_string()))?;
        return Ok(PyArray2::from_owned_array(py, array).into_any().unbind());
    }
    let list: Vec<_> = (0..scans.len())
        .map(|i| PyArray1::from_slice(py, scans.ranges(i)))
        .collect();
    Ok(PyList::new(py, list)?.into_any().unbind())
}
