//! Rectangles of cells; the world <-> cell conversion itself ([`Cell`], [`MapLimits`],
//! [`floor_to_i32`]) lives in `geometry`, below the kernels that use it, and is re-exported
//! here.

pub use crate::geometry::cells::{Cell, MapLimits, floor_to_i32};

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
