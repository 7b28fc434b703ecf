//! The scan matchers: where a scan is placed against a map, for every filter mode and for
//! the back end.
//!
//! - [`correlation`], for the `seed` mode: a scan point scores a hit on an occupied cell,
//!   searched over a small grid of whole-cell offsets.
//! - [`likelihood_field`], for the `scan_match` mode: a point scores by a field of its
//!   closeness to the nearest wall in a window of the one map; a correlative search, then a
//!   pattern search (which also refines the point field's matches).
//! - [`nearest_occupied`], for the `rbpf` mode ([`crate::filter::rbpf`]): a point scores by
//!   its distance to the nearest occupied cell of the particle's own grid; a coarse search,
//!   then a hill climb.
//! - [`map_field`], for localisation in a fixed map ([`crate::localize`]): a point scores
//!   by the log-likelihood of the map's cell it ends in, from the distance to the nearest
//!   wall; the particles are weighed in it and the converged estimate refined by a climb.
//! - [`point_field`], for the back end ([`crate::graph`]): a point scores by a field of its
//!   closeness to a submap's points, with max-pooled levels for branch and bound
//!   (sequential edges, loop closures, the scans between keyframes, the odometry made from
//!   scans).
//!
//! The modes' options, and the parameters derived from them, stay with the filter
//! ([`crate::filter::FilterOptions::search`], `ScanMatchOptions::params` in
//! [`crate::filter::scan_match`], `RbpfOptions::search_params` in [`crate::filter::rbpf`]);
//! the back end builds its windows and priors from `[graph]`. The matchers depend only on
//! the lower modules: [`crate::map`] (the grid and its cell frame), [`crate::geometry`] and
//! [`crate::kernels`] (their vector kernels); never on the filter, the back end or the
//! drivers above them.

pub mod correlation;
pub mod likelihood_field;
pub mod map_field;
pub mod nearest_occupied;
pub mod point_field;

/// The coarse yaw offsets of a search `search_deg` to each side in steps of `step_deg`
/// (rad): 0 first, then growing magnitude, so exact ties keep the smallest offset.
pub fn yaw_offsets_rad(search_deg: f64, step_deg: f64) -> Vec<f64> {
    let steps = (search_deg / step_deg).floor() as i32;
    let mut offsets = vec![0.0];
    for k in 1..=steps {
        let d = (f64::from(k) * step_deg).to_radians();
        offsets.push(-d);
        offsets.push(d);
    }
    offsets
}
