//! `pfslam.Result`: what a run produced, as numpy arrays and a summary dict.

use crate::convert::{poses_array, stamps_array, to_python};
use crate::errors::pfslam_error;
use crate::occupancy::occupancy;
use numpy::{PyArray1, PyArray2, PyUntypedArrayMethods};
use pfslam::Config;
use pfslam::pipeline::PipelineResult;
use pfslam::sensors::Recording;
use pfslam_io::account::InputAccount;
use pfslam_io::tum::write_tum_to;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The outcome of `run` or `Slam.finish`.
#[pyclass(module = "pfslam", name = "Result", frozen, get_all)]
pub struct RunResult {
    /// `(N, 4)` float64 rows `t_s, x_m, y_m, yaw_rad`: the final trajectory, a pose per scan.
    pub trajectory: Py<PyArray2<f64>>,
    /// `(N,)` int64 stamps (ns) of `trajectory`'s rows.
    pub stamps_ns: Py<PyArray1<i64>>,
    /// `trajectory` as the TUM text `pfslam run` writes to `trajectory.tum`.
    pub trajectory_tum: String,
    /// `(N, 4)` the filter's trajectory before the back end.
    pub front_end: Py<PyArray2<f64>>,
    /// `(N, 4)` the odometry at every scan (dead reckoning, same frame).
    pub dead_reckoning: Py<PyArray2<f64>>,
    /// `(rows, cols)` float32 log-odds of the final map (row 0 = lowest y, column 0 =
    /// lowest x; 0: never observed).
    pub occupancy: Py<PyArray2<f32>>,
    /// Cell size of `occupancy` (m).
    pub resolution_m: f64,
    /// World `(x_m, y_m)` of the lower-left corner of cell `occupancy[0, 0]`.
    pub origin: (f64, f64),
    /// Counts, self-check (`quality`), timings, back end and configuration.
    pub summary: Py<PyDict>,
}

#[pymethods]
impl RunResult {
    fn __repr__(&self, py: Python<'_>) -> String {
        let n = self.stamps_ns.bind(py).len();
        format!("Result({n} poses, resolution_m={})", self.resolution_m)
    }
}

/// What the run read besides the pipeline's result.
pub struct RunContext<'a> {
    /// The recording the filter saw.
    pub recording: &'a Recording,
    /// Its configuration.
    pub config: &'a Config,
    /// Its seed.
    pub seed: u64,
    /// The reader's account and the seconds it took, for a file.
    pub loaded: Option<(&'a InputAccount, f64)>,
}

/// The Python result of `pipeline`.
pub fn run_result(
    py: Python<'_>,
    pipeline: &PipelineResult,
    ctx: &RunContext<'_>,
) -> PyResult<RunResult> {
    let result = &pipeline.result;
    let mut tum = Vec::new();
    write_tum_to(&mut tum, &result.trajectory).map_err(|e| pfslam_error(&e))?;
    let map = occupancy(py, &result.map);
    let summary = to_python(py, &summary_json(pipeline, ctx))?.cast_into::<PyDict>()?;
    Ok(RunResult {
        trajectory: poses_array(py, &result.trajectory)?.unbind(),
        stamps_ns: stamps_array(py, &result.trajectory).unbind(),
        trajectory_tum: String::from_utf8_lossy(&tum).into_owned(),
        front_end: poses_array(py, &pipeline.front_end)?.unbind(),
        dead_reckoning: poses_array(py, &result.dead_reckoning)?.unbind(),
        occupancy: map.logodds,
        resolution_m: map.resolution_m,
        origin: map.origin,
        summary: summary.unbind(),
    })
}

/// The keys of `summary.json` that the library provides (the CLI adds the metrics against
/// ground truth and its output timings).
fn summary_json(p: &PipelineResult, ctx: &RunContext<'_>) -> serde_json::Value {
    let stats = &p.result.stats;
    let mut s = serde_json::json!({
        "recording": ctx.recording.name,
        "seed": ctx.seed,
        "config": ctx.config,
        "stats": stats,
        "quality": p.quality,
        "odometry_timing": p.odometry_timing,
        "timings_s": { "slam": stats.timings.total_s },
    });
    if let Some((account, load_s)) = ctx.loaded {
        s["input"] = serde_json::json!(account);
        s["timings_s"]["load"] = load_s.into();
    }
    if let Some(g) = &p.graph {
        s["graph"] = serde_json::json!(g);
        s["graph_input"] = serde_json::json!({
            "input": p.back_end_input,
            "odometry_calibration": p.calibration,
        });
        s["timings_s"]["graph"] = g.total_s.into();
        s["timings_s"]["graph_remap"] = p.rebuild_s.into();
    }
    s
}
