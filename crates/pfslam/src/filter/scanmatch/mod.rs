//! The scan-matching mode: a smooth observation model and a scan-matching proposal.
//!
//! - [`LikelihoodField`]: per update, a local window of the map around the scan where each
//!   cell holds `255 * exp(-d^2 / 2 sigma^2)`, `d` the distance to the nearest occupied cell
//!   (truncated at 3 sigma). A scan point scores by its field value, so points that land
//!   beside a wall still count, and sliding along a wall costs nothing.
//! - [`match_scan`]: per particle, a correlative search over x/y (whole cells, integer index
//!   shifts) and yaw around the particle's predicted pose, then a sub-cell hill climb on the
//!   bilinearly interpolated field. The objective adds a Gaussian prior on the deviation from
//!   the predicted pose: where the scan does not fix the pose (along a street whose walls are
//!   sampled at the same body-frame spots every scan) the odometry decides, instead of the
//!   previous scan's beam pattern.
//! - The particle moves to the optimum and its log-weight grows by the objective divided by a
//!   temperature; resampling is selective (Neff below a fraction of N).
//! - [`match_particles`]: every particle matched in full (see
//!   `docs/decisions/0019-scan-match-refinement.md`).

mod field;
mod options;
mod rotation;
mod search;
#[cfg(test)]
mod tests;

pub use field::*;
pub use options::*;
pub(crate) use rotation::*;
pub use search::*;
