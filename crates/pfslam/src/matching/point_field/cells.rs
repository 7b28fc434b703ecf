//! The cells of a scan's points at one heading and their exact sums over a level of a
//! [`PointField`] (the kernels in `crate::kernels::cell_sum`): the scores of the grid
//! searches.

use super::{PointField, SearchWindow, floor_to_i64};
use crate::geometry::Pose2;

/// The cells of a scan's points at one heading ([`PointField::cells_at`]), as two columns.
/// Stored in `i32`, clamped to `+-CELL_CLAMP`: a clamped cell lies outside any window (at
/// most 2^14 cells a side) for any offset under 2^29 cells, as the cell it stands for
/// (search windows are at most 10 m, 10^3 cells at 0.01 m).
#[derive(Debug, Clone, Default)]
pub(super) struct PointCells {
    pub(super) x: Vec<i32>,
    pub(super) y: Vec<i32>,
}

/// See [`PointCells`].
const CELL_CLAMP: i64 = 1 << 30;

impl PointField {
    /// Cells of the points seen from `centre`'s position with heading `yaw`.
    pub(super) fn cells_at(
        &self,
        points_body: &[[f64; 2]],
        centre: &Pose2,
        yaw: f64,
    ) -> PointCells {
        let (s, c) = yaw.sin_cos();
        let clamp = |v: i64| v.clamp(-CELL_CLAMP, CELL_CLAMP) as i32;
        let (x, y) = points_body
            .iter()
            .map(|p| {
                let x = centre.x_m + c * p[0] - s * p[1];
                let y = centre.y_m + s * p[0] + c * p[1];
                (
                    clamp(floor_to_i64((x - self.origin_x_m) / self.resolution_m)),
                    clamp(floor_to_i64((y - self.origin_y_m) / self.resolution_m)),
                )
            })
            .unzip();
        PointCells { x, y }
    }

    pub(super) fn window_yaws(centre: &Pose2, win: &SearchWindow) -> Vec<f64> {
        let m = (win.yaw_rad / win.yaw_step_rad.max(1e-6)).ceil() as i64;
        (-m..=m)
            .map(|k| centre.yaw_rad + k as f64 * win.yaw_step_rad)
            .collect()
    }

    /// Sum of level `level` over `cells` shifted by `(dx, dy)` (0 outside).
    ///
    /// Exact in any order, so the point-order sum's bits: every field value is 0 or an
    /// `f32` above 0.01 ([`Self::build`] keeps only such kernel values; the pooled levels
    /// take maxima of them), that is, at most 1 and a multiple of 2^-30. A sum of up to
    /// 2^22 of them is a multiple of 2^-30 below 2^22, which `f64` holds exactly, and so
    /// is every partial sum. With AVX2, eight points at a time (gathered).
    pub(super) fn cell_sum(&self, cells: &PointCells, level: usize, dx: i64, dy: i64) -> f64 {
        crate::kernels::cell_sum::cell_sum(self.level(level), (&cells.x, &cells.y), level, dx, dy)
    }
}
