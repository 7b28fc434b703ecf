//! Bresenham's line between two cells, as the UCSD seed's `bresenham2D`: every cell of the
//! 8-connected digital line from the start to the end, both included, in order.

use super::limits::Cell;

/// Calls `visit` for every cell of the line from `from` to `to` (both included), in order from
/// `from`. A zero-length ray visits `from` once. Consecutive cells are 8-neighbours and the
/// number of cells is `max(|di|, |dj|) + 1`.
#[inline]
pub fn bresenham<F: FnMut(Cell)>(from: Cell, to: Cell, mut visit: F) {
    // i64 so that extreme indices cannot overflow the error term.
    let (x0, y0) = (from.i as i64, from.j as i64);
    let (x1, y1) = (to.i as i64, to.j as i64);
    let dx = (x1 - x0).abs();
    let dy = (y1 - y0).abs();
    let sx = if x1 >= x0 { 1 } else { -1 };
    let sy = if y1 >= y0 { 1 } else { -1 };
    let (mut x, mut y) = (x0, y0);
    if dx >= dy {
        // x-major: one step in x per cell, y steps when the error crosses half a cell.
        let mut err = 2 * dy - dx;
        for _ in 0..=dx {
            visit(Cell::new(x as i32, y as i32));
            if err > 0 {
                y += sy;
                err -= 2 * dx;
            }
            err += 2 * dy;
            x += sx;
        }
    } else {
        let mut err = 2 * dx - dy;
        for _ in 0..=dy {
            visit(Cell::new(x as i32, y as i32));
            if err > 0 {
                x += sx;
                err -= 2 * dy;
            }
            err += 2 * dx;
            y += sy;
        }
    }
}

/// The cells of [`bresenham`] collected into a vector (tests, tools; the hot path uses the
/// callback form).
pub fn bresenham_cells(from: Cell, to: Cell) -> Vec<Cell> {
    let mut v = Vec::new();
    bresenham(from, to, |c| v.push(c));
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(i: i32, j: i32) -> Cell {
        Cell::new(i, j)
    }

    #[test]
    fn zero_length_ray() {
        assert_eq!(bresenham_cells(c(3, -4), c(3, -4)), vec![c(3, -4)]);
    }

    #[test]
    fn axis_and_diagonal() {
        assert_eq!(
            bresenham_cells(c(0, 0), c(3, 0)),
            vec![c(0, 0), c(1, 0), c(2, 0), c(3, 0)]
        );
        assert_eq!(
            bresenham_cells(c(0, 0), c(0, -2)),
            vec![c(0, 0), c(0, -1), c(0, -2)]
        );
        assert_eq!(
            bresenham_cells(c(0, 0), c(-2, 2)),
            vec![c(0, 0), c(-1, 1), c(-2, 2)]
        );
    }

    #[test]
    fn all_octants() {
        // (5, 2) reflected into all eight octants: the digital line is the reflection too,
        // because every octant uses the same error rule.
        let base = bresenham_cells(c(0, 0), c(5, 2));
        assert_eq!(
            base,
            vec![c(0, 0), c(1, 0), c(2, 1), c(3, 1), c(4, 2), c(5, 2)]
        );
        let maps: [fn(Cell) -> Cell; 8] = [
            |p| c(p.i, p.j),
            |p| c(p.j, p.i),
            |p| c(-p.j, p.i),
            |p| c(-p.i, p.j),
            |p| c(-p.i, -p.j),
            |p| c(-p.j, -p.i),
            |p| c(p.j, -p.i),
            |p| c(p.i, -p.j),
        ];
        for (k, m) in maps.iter().enumerate() {
            let line = bresenham_cells(c(0, 0), m(c(5, 2)));
            let expected: Vec<Cell> = base.iter().map(|p| m(*p)).collect();
            assert_eq!(line, expected, "octant map {k}");
        }
    }

    #[test]
    fn extreme_indices_do_not_overflow() {
        let cells = bresenham_cells(c(i32::MAX - 2, i32::MIN), c(i32::MAX, i32::MIN + 1));
        assert_eq!(cells.len(), 3);
        assert_eq!(*cells.last().unwrap(), c(i32::MAX, i32::MIN + 1));
    }
}
