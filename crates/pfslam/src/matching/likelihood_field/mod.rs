//! The likelihood-field matcher of the scan-matching mode (`[filter] mode = "scan_match"`):
//! a smooth observation model and a scan-matching proposal.
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
//! - [`cache`]: the field kept up to date with the map's logged changes instead of
//!   rebuilt at every update.
//!
//! The parameters of a match ([`MatchParams`]) come from the mode's options
//! ([`ScanMatchOptions::params`](crate::filter::scan_match::ScanMatchOptions::params)).
//! The back end's point field shares the pattern search ([`pattern_search`]) and the
//! batch dispatch of the cached rotations (`by_count!`).

pub mod cache;
mod field;
mod params;
mod rotation;
mod search;
#[cfg(test)]
mod tests;

pub use field::*;
pub use params::*;
pub(crate) use rotation::*;
pub use search::*;
