//! Scan-to-submap matching for the back end's pose-graph edges ([`crate::graph`]).
//!
//! A [`PointField`] is a dense window of a likelihood field built from submap points: each
//! cell holds `exp(-d^2 / 2 sigma^2)` of the distance `d` to the nearest point (0..1), plus
//! max-pooled copies (cell `c` of level `k` = the maximum over the `2^k x 2^k` cells from
//! `c`), the upper bounds of Olson's / Cartographer's branch-and-bound correlative search.
//! - [`PointField::search_bnb`]: the best pose over a large x/y/yaw window (loop closures),
//!   exact on the cell grid, optionally excluding a neighbourhood (to measure ambiguity).
//! - [`PointField::search_with_prior`]: a small exhaustive window with a Gaussian prior on the
//!   deviation from a prediction (sequential edges: along a corridor the prediction decides).
//! - [`PointField::refine`]: sub-cell pattern search on the bilinearly interpolated field.
//!
//! The field and its storage live in `field` and `storage`; the interpolated scores
//! (the refinement's objective and the edges' curvature) in `score`; the cell sums of the
//! grid searches in `cells`; the searches in `branch_and_bound` and `local_search`.

mod branch_and_bound;
mod cells;
mod field;
mod local_search;
mod score;
mod storage;
#[cfg(test)]
mod tests;

pub use branch_and_bound::BnbStart;
pub use field::PointField;
pub use local_search::Prior;

/// A search window around a centre pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchWindow {
    /// Half-width in x and y (m).
    pub xy_m: f64,
    /// Half-width in yaw (rad).
    pub yaw_rad: f64,
    /// Yaw step (rad).
    pub yaw_step_rad: f64,
}

pub(crate) use crate::geometry::cells::floor_to_i64;
