//! A finite raster of occupied / free / unknown cells: the thresholded map (the seeds' "binary
//! map", with unknown kept), the content of a ROS map_server `pgm` + `yaml` pair and the form
//! in which true maps (simulator) are compared.

use super::grid::OccupancyGrid;
use super::limits::{Cell, CellRect, MapLimits};
use super::logodds::CellState;

/// A `width x height` raster of cell states. Cell `(i, j)` (0-based, `i` along x, `j` along
/// y, row 0 = lowest y) covers the square of [`MapLimits`] cell `(i, j)`: the limits' origin is
/// the lower-left corner of the lower-left cell (map_server's `origin`).
#[derive(Debug, Clone, PartialEq)]
pub struct BinaryMap {
    /// World <-> cell conversion; cell (0, 0) is the lower-left cell.
    pub limits: MapLimits,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// States, row-major from the lowest row: `cells[j * width + i]`.
    pub cells: Vec<CellState>,
}

impl BinaryMap {
    /// A map filled with one state.
    pub fn filled(limits: MapLimits, width: usize, height: usize, state: CellState) -> Self {
        BinaryMap {
            limits,
            width,
            height,
            cells: vec![state; width * height],
        }
    }

    /// The state of cell `(i, j)`; `Unknown` outside the raster.
    #[inline]
    pub fn get(&self, i: i64, j: i64) -> CellState {
        if i < 0 || j < 0 || i >= self.width as i64 || j >= self.height as i64 {
            CellState::Unknown
        } else {
            self.cells[j as usize * self.width + i as usize]
        }
    }

    /// Sets cell `(i, j)`; ignored outside the raster.
    #[inline]
    pub fn set(&mut self, i: i64, j: i64, state: CellState) {
        if i >= 0 && j >= 0 && i < self.width as i64 && j < self.height as i64 {
            self.cells[j as usize * self.width + i as usize] = state;
        }
    }

    /// The state at a world point (`Unknown` outside).
    #[inline]
    pub fn state_at(&self, x_m: f64, y_m: f64) -> CellState {
        let c = self.limits.cell_of(x_m, y_m);
        self.get(c.i as i64, c.j as i64)
    }

    /// Number of cells in each state: (occupied, free, unknown).
    pub fn counts(&self) -> (usize, usize, usize) {
        let mut n = (0, 0, 0);
        for s in &self.cells {
            match s {
                CellState::Occupied => n.0 += 1,
                CellState::Free => n.1 += 1,
                CellState::Unknown => n.2 += 1,
            }
        }
        n
    }

    /// The raster as an occupancy grid with default log-odds parameters (occupied cells at
    /// the upper clamp, free ones at the lower, unknown untouched), e.g. to draw a map read
    /// from a file with the same renderer as a built one.
    pub fn to_grid(&self) -> Result<OccupancyGrid, super::MapError> {
        let mut grid = OccupancyGrid::with_params(self.limits, super::LogOddsParams::default());
        let f = *grid.fixed();
        for (k, s) in self.cells.iter().enumerate() {
            let value = match s {
                CellState::Occupied => f.max,
                CellState::Free => f.min,
                CellState::Unknown => continue,
            };
            let cell = Cell::new((k % self.width) as i32, (k / self.width) as i32);
            grid.set_fixed(cell, value)?;
        }
        Ok(grid)
    }
}

impl OccupancyGrid {
    /// The thresholded map over `rect` (default: the observed cells, or an empty 0 x 0 map).
    pub fn to_binary_map(&self, rect: Option<CellRect>) -> BinaryMap {
        let res = self.limits().resolution_m();
        let Some(rect) = rect.or_else(|| self.observed_bounds()) else {
            return BinaryMap::filled(*self.limits(), 0, 0, CellState::Unknown);
        };
        let (x0, y0) = self.limits().cell_corner(Cell::new(rect.min_i, rect.min_j));
        let (w, h) = (rect.width(), rect.height());
        let mut cells = Vec::with_capacity(w * h);
        for j in 0..h as i32 {
            for i in 0..w as i32 {
                cells.push(self.state(Cell::new(rect.min_i + i, rect.min_j + j)));
            }
        }
        BinaryMap {
            limits: MapLimits::new(res, x0, y0),
            width: w,
            height: h,
            cells,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::LogOddsParams;

    #[test]
    fn grid_to_binary_keeps_world_positions() {
        let mut g =
            OccupancyGrid::with_params(MapLimits::new(0.5, 1.0, -1.0), LogOddsParams::ucsd());
        g.update_occupied(Cell::new(-3, 2)).unwrap();
        g.update_free(Cell::new(4, -1)).unwrap();
        let b = g.to_binary_map(None);
        assert_eq!((b.width, b.height), (8, 4));
        let (x, y) = g.limits().cell_centre(Cell::new(-3, 2));
        assert_eq!(b.state_at(x, y), CellState::Occupied);
        let (x, y) = g.limits().cell_centre(Cell::new(4, -1));
        assert_eq!(b.state_at(x, y), CellState::Free);
        assert_eq!(b.counts(), (1, 1, 30));
        assert_eq!(b.get(-1, 0), CellState::Unknown);
    }

    #[test]
    fn a_raster_read_from_a_file_becomes_a_grid_with_the_same_cells() {
        let mut b = BinaryMap::filled(MapLimits::new(0.05, -3.0, 2.0), 70, 90, CellState::Unknown);
        b.set(0, 0, CellState::Occupied);
        b.set(69, 89, CellState::Free);
        b.set(12, 71, CellState::Occupied);
        b.set(13, 71, CellState::Free);
        let g = b.to_grid().unwrap();
        let rect = CellRect {
            min_i: 0,
            min_j: 0,
            max_i: 69,
            max_j: 89,
        };
        assert_eq!(g.to_binary_map(Some(rect)), b);
    }
}
