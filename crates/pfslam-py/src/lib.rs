//! The `pfslam` Python package's native module (`pfslam._pfslam`): `run` a recording file as
//! `pfslam run` does, feed a `Slam` message by message, `read_recording` into numpy arrays.
//! The Python side (`python/pfslam/`) re-exports it with type stubs.

mod config;
mod convert;
mod errors;
mod occupancy;
mod recording;
mod result;
mod slam;

use crate::config::config_from;
use crate::errors::{ConfigError, PfslamError, config_error, pfslam_error};
use crate::result::{RunContext, RunResult, run_result};
use pfslam_io::run_file::{RunFileError, run_file};
use pyo3::prelude::*;
use std::path::PathBuf;

/// SLAM on a recording file exactly as `pfslam run FILE --seed SEED` runs it (the same
/// trajectory bit for bit); `config` is None, TOML text or a dict of sections.
#[pyfunction]
#[pyo3(signature = (path, config = None, seed = 1))]
fn run(
    py: Python<'_>,
    path: PathBuf,
    config: Option<&Bound<'_, PyAny>>,
    seed: u64,
) -> PyResult<RunResult> {
    let config = config_from(config)?;
    let done = py.detach(|| run_file(&path, &config, seed));
    let done = done.map_err(|e| match &e {
        RunFileError::Config(_) => config_error(&e),
        _ => pfslam_error(&e),
    })?;
    let ctx = RunContext {
        recording: &done.recording,
        config: &config,
        seed,
        loaded: Some((&done.account, done.load_s)),
    };
    run_result(py, &done.pipeline, &ctx)
}

#[pymodule]
#[pyo3(name = "_pfslam")]
fn pfslam_py(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(recording::read_recording, m)?)?;
    m.add_class::<RunResult>()?;
    m.add_class::<recording::PyRecording>()?;
    m.add_class::<slam::PySlam>()?;
    m.add("PfslamError", py.get_type::<PfslamError>())?;
    m.add("ConfigError", py.get_type::<ConfigError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
