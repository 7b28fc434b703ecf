//! Monte Carlo localisation in a fixed map (`pfslam localize`): the particle filter's other
//! classic use. The map is any occupancy raster ([`crate::map::BinaryMap`], e.g. a ROS
//! map_server pair read by `pfslam_io::map_files::read_map_server`), so maps made by other
//! tools work as well as pfslam's own.
//!
//! - [`mcl`]: the particle set: odometry motion model, weighing, KLD-adaptive resampling
//!   with augmented MCL's random particles for recovery.
//! - [`estimate`]: the heaviest cluster's mean and mass (the convergence test).
//! - [`run`]: the loop over a recording.
//! - [`check`]: the run's self-check.

pub mod check;
pub mod estimate;
pub mod kld;
pub mod mcl;
pub mod options;
pub mod run;
#[cfg(test)]
mod tests;

pub use check::LocalizeQuality;
pub use options::{LikelihoodOptions, LocalizeOptions, RecoveryOptions};
pub use run::{LocalizeResult, UpdateRecord, localize, localize_timed};

/// Errors of localisation.
#[derive(Debug, thiserror::Error)]
pub enum LocalizeError {
    /// An option out of range (the message names the key).
    #[error("configuration [localize]: {0}")]
    Options(String),
    /// A bad odometry shift (`[input] odometry_shift_s`).
    #[error("configuration [input]: {0}")]
    Shift(String),
    /// The map has no free cell to place particles in.
    #[error("the map has no free cell")]
    NoFreeSpace,
    /// Bad scan preprocessing options or a scan of the wrong beam count.
    #[error(transparent)]
    Map(#[from] crate::map::MapError),
    /// The recording cannot be localised.
    #[error("recording {name}: {message}")]
    Input {
        /// The recording's name.
        name: String,
        /// What is missing.
        message: String,
    },
}
