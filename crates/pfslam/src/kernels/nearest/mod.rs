//! The observation model's 3x3 kernel: the nearest occupied cell around a point within one
//! tile (its AVX2 twin in `x86.rs`, called from the likelihood's AVX2 kernel).

use super::TILE_SHIFT;

#[cfg(target_arch = "x86_64")]
pub(super) mod x86;

/// A point inside one tile's interior: where it lies, its cell, and the cell's place in the
/// tile.
#[derive(Clone, Copy)]
pub struct TilePoint {
    /// The point in cells (cell `(i, j)` covers `[i, i + 1) x [j, j + 1)`).
    pub u_cells: f64,
    pub v_cells: f64,
    /// Its cell.
    pub i: i32,
    pub j: i32,
    /// The cell's column and row in its tile.
    pub local_i: i32,
    pub local_j: i32,
}

/// The smallest squared distance (cells) from `at` to the centre of an occupied cell (above
/// `occ`) of the 3x3 block around `at`'s cell in the tile `cells`; infinity if none.
#[inline(always)]
pub fn nearest_3x3(cells: &[i16], at: TilePoint, occ: i16) -> f64 {
    let TilePoint {
        u_cells: u,
        v_cells: v,
        i,
        j,
        local_i: li,
        local_j: lj,
    } = at;
    let du2 = [-1, 0, 1].map(|d| {
        let du = u - (f64::from(i + d) + 0.5);
        du * du
    });
    let mut best = f64::INFINITY;
    for dj in -1..=1 {
        let dv = v - (f64::from(j + dj) + 0.5);
        let dv2 = dv * dv;
        let start = (((lj + dj) as usize) << TILE_SHIFT) + (li - 1) as usize;
        let Some(row) = cells.get(start..start + 3) else {
            continue;
        };
        for (cell, du2) in row.iter().zip(du2) {
            let d = if *cell > occ {
                du2 + dv2
            } else {
                f64::INFINITY
            };
            // `d` is never NaN where `best` could be replaced (finite inputs; a NaN point
            // compares false and keeps infinity, as `f64::min` would): a plain compare-select.
            best = if d < best { d } else { best };
        }
    }
    best
}
