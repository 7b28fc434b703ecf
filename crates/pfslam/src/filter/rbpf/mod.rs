//! The Rao-Blackwellised particle filter (`[filter] mode = "rbpf"`), after GMapping
//! (Grisetti, Stachniss, Burgard 2007).
//!
//! - Every particle carries its own [`OccupancyGrid`](crate::map::OccupancyGrid). Grids are
//!   tiled with `Arc` tiles and copy-on-write, so a resampled copy shares all tiles with its
//!   ancestor and memory grows with the tiles particles actually changed, not with the
//!   particle count.
//! - Updates happen only once the odometry moved `linear_update_m` or turned
//!   `angular_update_deg` since the last one. At an update each particle composes the
//!   odometry increment onto its pose (no noise), scan-matches from there against its OWN
//!   map (coarse yaw/x/y search, then a hill climb with step halving on a smooth observation
//!   model, see [`scan_log_likelihood`]; the matcher is [`crate::matching::nearest_occupied`];
//!   the prior's sigmas are GMapping's four-parameter motion noise for the increment,
//!   `odometry_noise`), then samples its pose around the match (`search.jitter_xy_m`,
//!   `search.jitter_yaw_deg`); its log-weight grows by the match log-likelihood /
//!   `weight_temperature` (GMapping samples the motion noise first and matches from the
//!   sample: decision 0005). Maps are updated with the particle's pose; resampling is
//!   selective (Neff below a fraction of N).
//! - Each particle's trajectory is a chain of [`PathNode`]s with `Arc` parent links, one per
//!   update, so resampled copies share their history. The output is the FINAL best
//!   particle's whole ancestral path: loop closures found late correct the whole past. Scans
//!   between updates get the previous node's pose composed with the odometry increment, so
//!   every scan has a pose.
//! - Randomness: one `jump()`ed stream per fixed chunk of particles (`filter::rng`), the
//!   master stream for resampling: results do not depend on the thread count.
//!
//! The filter is fed a recording scan by scan, and its final path re-matched in the best
//! map, by `crate::slam::RbpfFrontEnd`.
//!
//! [`scan_log_likelihood`]: crate::matching::nearest_occupied::scan_log_likelihood

mod options;
mod particles;
mod path;
#[cfg(test)]
mod tests;

pub use options::*;
pub use particles::*;
pub use path::*;
