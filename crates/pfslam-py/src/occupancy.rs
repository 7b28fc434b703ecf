//! An occupancy grid as a dense array over the cells it observed.

use numpy::PyArray2;
use numpy::ndarray::Array2;
use pfslam::map::{Cell, OccupancyGrid};
use pyo3::prelude::*;

/// The log-odds of every cell in a grid's observed bounds, with the cell size and the world
/// position of the array's first cell.
pub struct Occupancy {
    /// `(rows, cols)` float32 log-odds (0: never observed); `logodds[r, c]` is the cell `c`
    /// cells along world x and `r` cells along world y from `origin` (row 0 = lowest y).
    pub logodds: Py<PyArray2<f32>>,
    /// Cell size (m).
    pub resolution_m: f64,
    /// World `(x_m, y_m)` of the lower-left corner of cell `logodds[0, 0]`.
    pub origin: (f64, f64),
}

/// `grid` over its observed bounds (an empty `(0, 0)` array when it observed nothing).
pub fn occupancy(py: Python<'_>, grid: &OccupancyGrid) -> Occupancy {
    let limits = grid.limits();
    let resolution_m = limits.resolution_m();
    let Some(rect) = grid.observed_bounds() else {
        return Occupancy {
            logodds: PyArray2::from_owned_array(py, Array2::zeros((0, 0))).unbind(),
            resolution_m,
            origin: (limits.origin_x_m(), limits.origin_y_m()),
        };
    };
    let array = Array2::from_shape_fn((rect.height(), rect.width()), |(r, c)| {
        grid.logodds(Cell::new(rect.min_i + c as i32, rect.min_j + r as i32)) as f32
    });
    Occupancy {
        logodds: PyArray2::from_owned_array(py, array).unbind(),
        resolution_m,
        origin: limits.cell_corner(Cell::new(rect.min_i, rect.min_j)),
    }
}
