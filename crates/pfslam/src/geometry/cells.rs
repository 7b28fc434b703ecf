//! World <-> cell conversion.
//!
//! Convention: cell `(i, j)` covers the half-open square
//! `[origin_x_m + i * res, origin_x_m + (i + 1) * res) x [origin_y_m + j * res, origin_y_m + (j + 1) * res)`;
//! its centre is at `origin + (index + 0.5) * res`. `i` grows with world x, `j` with world y.
//! Indices may be negative: the tiled grid is unbounded in every direction. This is also the
//! ROS map_server convention when `origin` is the lower-left corner of the lower-left pixel.

/// Index of a cell: `i` along world x, `j` along world y.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Cell {
    /// Column (world x).
    pub i: i32,
    /// Row (world y).
    pub j: i32,
}

impl Cell {
    /// A cell from its indices.
    #[inline]
    pub const fn new(i: i32, j: i32) -> Self {
        Cell { i, j }
    }
}

/// A copyable world <-> cell conversion: cell size and the world position of the corner of
/// cell `(0, 0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapLimits {
    // Private so that the cached inverse cannot go stale.
    resolution_m: f64,
    origin_x_m: f64,
    origin_y_m: f64,
    /// `1 / resolution_m`, cached for the hot path.
    inv_resolution: f64,
}

impl Default for MapLimits {
    fn default() -> Self {
        MapLimits::new(0.1, 0.0, 0.0)
    }
}

/// `floor(v)` as `i32`, saturating; faster than `f64::floor` on baseline x86-64 (no SSE4.1),
/// where `floor` is a libm call.
#[inline(always)]
pub fn floor_to_i32(v: f64) -> i32 {
    let t = v as i32;
    if (t as f64) > v {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// `floor(v)` as `i64` without the libm call (`f64::floor` on baseline x86-64); the same
/// value as `v.floor() as i64` for every finite `v` within +-2^53 (cells always are).
#[inline(always)]
pub fn floor_to_i64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v {
        t.saturating_sub(1)
    } else {
        t
    }
}

impl MapLimits {
    /// Limits with this resolution and origin. The resolution must be positive and finite
    /// (validated by `MapOptions::validate` in `map`); a non-positive one is replaced by 1 m so
    /// that the conversions stay finite.
    pub fn new(resolution_m: f64, origin_x_m: f64, origin_y_m: f64) -> Self {
        let resolution_m = if resolution_m.is_finite() && resolution_m > 0.0 {
            resolution_m
        } else {
            1.0
        };
        MapLimits {
            resolution_m,
            origin_x_m,
            origin_y_m,
            inv_resolution: 1.0 / resolution_m,
        }
    }

    /// Cell side (m).
    #[inline]
    pub fn resolution_m(&self) -> f64 {
        self.resolution_m
    }

    /// `1 / resolution` (cells per m), the factor [`Self::cell_coords`] multiplies by.
    #[inline]
    pub fn inv_resolution(&self) -> f64 {
        self.inv_resolution
    }

    /// World x of the lower-left corner of cell (0, 0) (m).
    #[inline]
    pub fn origin_x_m(&self) -> f64 {
        self.origin_x_m
    }

    /// World y of the lower-left corner of cell (0, 0) (m).
    #[inline]
    pub fn origin_y_m(&self) -> f64 {
        self.origin_y_m
    }

    /// The cell containing world point `(x_m, y_m)` (see the module's convention). Coordinates
    /// beyond the `i32` range saturate.
    #[inline(always)]
    pub fn cell_of(&self, x_m: f64, y_m: f64) -> Cell {
        Cell {
            i: floor_to_i32((x_m - self.origin_x_m) * self.inv_resolution),
            j: floor_to_i32((y_m - self.origin_y_m) * self.inv_resolution),
        }
    }

    /// Continuous cell coordinates of a world point (cell `(i, j)` spans `[i, i+1) x [j, j+1)`).
    #[inline]
    pub fn cell_coords(&self, x_m: f64, y_m: f64) -> (f64, f64) {
        (
            (x_m - self.origin_x_m) * self.inv_resolution,
            (y_m - self.origin_y_m) * self.inv_resolution,
        )
    }

    /// World coordinates of the centre of `cell`.
    #[inline]
    pub fn cell_centre(&self, cell: Cell) -> (f64, f64) {
        (
            self.origin_x_m + (cell.i as f64 + 0.5) * self.resolution_m,
            self.origin_y_m + (cell.j as f64 + 0.5) * self.resolution_m,
        )
    }

    /// World coordinates of the lower-left corner of `cell`.
    #[inline]
    pub fn cell_corner(&self, cell: Cell) -> (f64, f64) {
        (
            self.origin_x_m + cell.i as f64 * self.resolution_m,
            self.origin_y_m + cell.j as f64 * self.resolution_m,
        )
    }
}
