//! The observation model: a scan's log-likelihood in a particle's own map (its kernels in
//! `crate::kernels::likelihood`).

use crate::geometry::Pose2;
use crate::map::OccupancyGrid;

/// The observation model and a candidate's bar, defined with their kernels.
pub use crate::kernels::likelihood::{Bar, ObservationModel};

/// Log-likelihood of the body-frame `points` seen from `pose` in `grid` (sum over points).
///
/// Per point, the same arithmetic as the plain rule (`tests::scan_log_likelihood_plain`), so
/// the same bits: squared distances `du^2 + dv^2` from the same products (the per-row and
/// per-column squares are computed once), the minimum taken exactly, the sum in point order.
/// Faster: an integer floor (`f64::floor` is a libm call on baseline x86-64), the tile of the
/// previous point reused, and for the default 3x3 kernel a branch-free minimum. With AVX2
/// (the default kernel): four points at a time, projected together, their kernel rows
/// gathered (one 8-byte load per point and row) and their minima taken across lanes.
pub fn scan_log_likelihood(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
) -> f64 {
    scan_log_likelihood_above(grid, model, points, pose, None)
}

/// [`scan_log_likelihood`], but with a `bar` it may stop early: every point's term is <= 0,
/// so the running sum only falls (rounding is monotonic) and once `sum - penalty <= bar`
/// the candidate cannot win. Then it returns that partial sum, for which `sum - penalty >
/// bar` is false, as it would be for the full sum. Otherwise (and without a bar) the
/// full sum, the same bits as [`scan_log_likelihood`].
pub fn scan_log_likelihood_above(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
    bar: Option<Bar>,
) -> f64 {
    crate::kernels::likelihood::scan_log_likelihood_above(grid, model, points, pose, bar)
}
