//! The package's exceptions and the messages of the Rust errors they carry.

use pyo3::PyErr;
use pyo3::create_exception;
use pyo3::exceptions::PyException;

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
