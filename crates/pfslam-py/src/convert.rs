//! Rust values as Python ones: poses as `(N, 4)` arrays, JSON as dicts, the beams' geometry
//! and the LiDAR mount.

use crate::errors::PfslamError;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pfslam::geometry::{Pose2, Rigid3, StampedPose2};
use pfslam::sensors::LidarGeometry;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

/// Seconds of a nanosecond stamp: the nearest double to `stamp_ns / 1e9`.
pub fn seconds(stamp_ns: i64) -> f64 {
    stamp_ns as f64 / 1e9
}

/// Nanoseconds of a stamp in seconds, rounded to the nearest (halves away from zero).
pub fn nanoseconds(t_s: f64) -> PyResult<i64> {
    let ns = (t_s * 1e9).round();
    // i64 holds about +-292 years of nanoseconds around 1970.
    if !ns.is_finite() || ns.abs() >= 9.2e18 {
        return Err(PyValueError::new_err(format!(
            "stamp {t_s} s is not a finite time within +-292 years of 0"
        )));
    }
    Ok(ns as i64)
}

/// `(N, 4)` float64 rows `t_s, x_m, y_m, yaw_rad`.
pub fn poses_array<'py>(
    py: Python<'py>,
    poses: &[StampedPose2],
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = poses
        .iter()
        .flat_map(|p| [seconds(p.stamp_ns), p.pose.x_m, p.pose.y_m, p.pose.yaw_rad])
        .collect();
    let array = Array2::from_shape_vec((poses.len(), 4), flat)
        .map_err(|e| PfslamError::new_err(e.to_string()))?;
    Ok(array.into_pyarray(py))
}

/// The stamps of `poses` (ns) as int64.
pub fn stamps_array<'py>(py: Python<'py>, poses: &[StampedPose2]) -> Bound<'py, PyArray1<i64>> {
    let stamps: Vec<i64> = poses.iter().map(|p| p.stamp_ns).collect();
    PyArray1::from_vec(py, stamps)
}

/// A pose as the tuple `(t_s, x_m, y_m, yaw_rad)`.
pub fn pose_tuple<'py>(py: Python<'py>, p: &StampedPose2) -> PyResult<Bound<'py, PyTuple>> {
    let fields = [seconds(p.stamp_ns), p.pose.x_m, p.pose.y_m, p.pose.yaw_rad];
    PyTuple::new(py, fields)
}

/// Any serialisable value as its Python form through JSON (dicts, lists, floats, ...).
pub fn to_python<'py>(
    py: Python<'py>,
    value: &impl serde::Serialize,
) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| PfslamError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// The beams' geometry as a dict with the field names of `LidarGeometry`.
pub fn geometry_dict<'py>(py: Python<'py>, g: &LidarGeometry) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("angle_min_rad", g.angle_min_rad)?;
    d.set_item("angle_increment_rad", g.angle_increment_rad)?;
    d.set_item("beam_count", g.beam_count)?;
    d.set_item("range_min_m", g.range_min_m)?;
    d.set_item("range_max_m", g.range_max_m)?;
    Ok(d)
}

/// The 4x4 homogeneous matrix of a transform.
pub fn rigid_array<'py>(py: Python<'py>, r: &Rigid3) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let m = r.to_homogeneous();
    let rows: Vec<Vec<f64>> = (0..4)
        .map(|i| (0..4).map(|j| m[(i, j)]).collect())
        .collect();
    PyArray2::from_vec2(py, &rows).map_err(|e| PfslamError::new_err(e.to_string()))
}

/// A mount from a 4x4 homogeneous matrix or a planar `(x_m, y_m, yaw_rad)`.
pub fn rigid_from(o: &Bound<'_, PyAny>) -> PyResult<Rigid3> {
    if let Ok(a) = o.cast::<PyArray2<f64>>() {
        if a.shape() != [4, 4] {
            return Err(PyValueError::new_err(format!(
                "body_from_lidar: a 4x4 matrix, not {:?}",
                a.shape()
            )));
        }
        let m = a.readonly();
        let m = m.as_array();
        let rotation = [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)]));
        return Ok(Rigid3::from_row_major(
            rotation
                .concat()
                .try_into()
                .map_err(|_| PyValueError::new_err("body_from_lidar"))?,
            [m[(0, 3)], m[(1, 3)], m[(2, 3)]],
        ));
    }
    let (x_m, y_m, yaw_rad): (f64, f64, f64) = o.extract().map_err(|_| {
        PyValueError::new_err("body_from_lidar: a 4x4 float64 array or (x_m, y_m, yaw_rad)")
    })?;
    Ok(Rigid3::from_pose2(&Pose2::new(x_m, y_m, yaw_rad)))
}
