//! The package's exceptions and the messages of the Rust errors they carry.

use pyo3::PyErr;
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};

create_exception!(
    pfslam,
    PfslamError,
    PyException,
    "An error of pfslam: its message is the Rust error's, causes joined by \": \"."
);
create_exception!(
    pfslam,
    ConfigError,
    PfslamError,
    "A configuration that is malformed, has an unknown key or a value out of range."
);

/// `err` and its causes joined by ": ", as `pfslam` (anyhow) prints them.
pub fn message(err: &(dyn std::error::Error + 'static)) -> String {
    let mut text = err.to_string();
    let mut source = err.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}

/// `err` as a [`PfslamError`].
pub fn pfslam_error(err: &(dyn std::error::Error + 'static)) -> PyErr {
    PfslamError::new_err(message(err))
}

/// `err` as a [`ConfigError`].
pub fn config_error(err: &(dyn std::error::Error + 'static)) -> PyErr {
    ConfigError::new_err(message(err))
}

/// An error of the incremental API: bad pushes (order, beams, values) as `ValueError`, the
/// filter's and the back end's failures as [`PfslamError`].
pub fn online_error(err: &pfslam::OnlineError) -> PyErr {
    use pfslam::OnlineError as E;
    match err {
        E::OutOfOrder { .. }
        | E::Odometry { .. }
        | E::Imu { .. }
        | E::Setup(_)
        | E::Scan { .. } => PyValueError::new_err(message(err)),
        _ => pfslam_error(err),
    }
}
