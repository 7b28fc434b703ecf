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

impl MapLimits {
    /// Limits with this resolution and origin. The resolution must be positive and finite
    /// (validated by [`super::MapOptions::validate`]); a non-positive one is replaced by 1 m so
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

/// An inclusive rectangle of cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CellRect {
    /// Smallest column.
    pub min_i: i32,
    /// Smallest row.
    pub min_j: i32,
    /// Largest column (inclusive).
    pub max_i: i32,
    /// Largest row (inclusive).
    pub max_j: i32,
}

impl CellRect {
    /// Number of columns.
    #[inline]
    pub fn width(&self) -> usize {
        (self.max_i as i64 - self.min_i as i64 + 1).max(0) as usize
    }

    /// Number of rows.
    #[inline]
    pub fn height(&self) -> usize {
        (self.max_j as i64 - self.min_j as i64 + 1).max(0) as usize
    }

    /// True when `cell` lies inside.
    #[inline]
    pub fn contains(&self, cell: Cell) -> bool {
        cell.i >= self.min_i && cell.i <= self.max_i && cell.j >= self.min_j && cell.j <= self.max_j
    }

    /// The smallest rectangle containing both.
    pub fn union(&self, other: &CellRect) -> CellRect {
        CellRect {
            min_i: self.min_i.min(other.min_i),
            min_j: self.min_j.min(other.min_j),
            max_i: self.max_i.max(other.max_i),
            max_j: self.max_j.max(other.max_j),
        }
    }

    /// The rectangle grown by `margin` cells on every side.
    pub fn expanded(&self, margin: i32) -> CellRect {
        CellRect {
            min_i: self.min_i.saturating_sub(margin),
            min_j: self.min_j.saturating_sub(margin),
            max_i: self.max_i.saturating_add(margin),
            max_j: self.max_j.saturating_add(margin),
        }
    }

    /// The rectangle around one cell.
    pub fn around(cell: Cell) -> CellRect {
        CellRect {
            min_i: cell.i,
            min_j: cell.j,
            max_i: cell.i,
            max_j: cell.j,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_matches_std() {
        for v in [-2.5, -2.0, -1e-12, 0.0, 1e-12, 0.999, 1.0, 3.7, -0.5] {
            assert_eq!(floor_to_i32(v), v.floor() as i32, "{v}");
        }
    }

    #[test]
    fn cell_convention() {
        let l = MapLimits::new(0.5, -1.0, 2.0);
        assert_eq!(l.cell_of(-1.0, 2.0), Cell::new(0, 0));
        assert_eq!(l.cell_of(-0.51, 2.49), Cell::new(0, 0));
        assert_eq!(l.cell_of(-0.5, 2.5), Cell::new(1, 1));
        assert_eq!(l.cell_of(-1.01, 1.99), Cell::new(-1, -1));
        assert_eq!(l.cell_centre(Cell::new(0, 0)), (-0.75, 2.25));
        assert_eq!(l.cell_corner(Cell::new(-2, 3)), (-2.0, 3.5));
        let c = l.cell_of(10.3, -7.2);
        assert_eq!(l.cell_of(l.cell_centre(c).0, l.cell_centre(c).1), c);
    }

    #[test]
    fn bad_resolution_is_replaced() {
        assert_eq!(MapLimits::new(0.0, 0.0, 0.0).resolution_m(), 1.0);
        assert_eq!(MapLimits::new(f64::NAN, 0.0, 0.0).resolution_m(), 1.0);
    }

    #[test]
    fn rect_sizes() {
        let r = CellRect::around(Cell::new(3, -2)).union(&CellRect::around(Cell::new(-1, 4)));
        assert_eq!((r.width(), r.height()), (5, 7));
        assert!(r.contains(Cell::new(0, 0)));
        assert!(!r.contains(Cell::new(4, 0)));
    }
}
