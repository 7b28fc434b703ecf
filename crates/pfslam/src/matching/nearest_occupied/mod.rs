//! The nearest-occupied-cell matcher of the Rao-Blackwellised mode (`[filter] mode =
//! "rbpf"`): a scan matched against a particle's own occupancy grid.
//!
//! - [`scan_log_likelihood`]: the observation model. Each scan point scores by its squared
//!   distance to the nearest occupied cell within a small kernel, floored at a no-hit value
//!   (its kernels in `crate::kernels::likelihood` and `crate::kernels::nearest`).
//! - [`match_in_own_map`]: a coarse yaw/x/y search around the particle's pose, then a hill
//!   climb with step halving, on that likelihood minus a Gaussian prior ([`MatchPrior`]) on
//!   the deviation from the pose.
//!
//! The search parameters ([`SearchParams`]) and the observation model come from the mode's
//! options ([`RbpfOptions::search_params`](crate::filter::rbpf::RbpfOptions::search_params),
//! [`RbpfOptions::observation`](crate::filter::rbpf::RbpfOptions::observation)).

mod likelihood;
mod matcher;

pub use likelihood::*;
pub use matcher::*;
