//! The tiled log-odds occupancy grid and scan insertion.
//!
//! Storage: square tiles of `TILE_SIZE x TILE_SIZE` cells (`i16` fixed-point log-odds, see
//! [`super::logodds`]), allocated on first write, held as `Arc<Tile>`. A dense directory of
//! tile pointers covers the bounding box of the allocated tiles (8 bytes per 64 x 64 cells,
//! ~1/1000 of a dense grid), so memory follows the visited area and lookups are two index
//! computations, no hashing. Cloning a grid copies the directory and bumps reference counts;
//! writes go through `Arc::make_mut`, so clones (one map per particle) share unchanged tiles
//! and copy a tile only when they first change it.
//!
//! Cells never written read as log-odds 0 (p = 0.5, unknown).
//!
//! Height bins (`[map.height]`): a second directory of tiles, allocated on demand like the
//! first and shared copy-on-write the same way, holds `bins` `i8` log-odds per cell (cell-major,
//! one 16-byte column per cell at 16 bins). Scans with heights update them and rewrite the
//! touched cells' 2-D values as their projection; scans without heights, and
//! [`OccupancyGrid::add_fixed`] / [`OccupancyGrid::set_fixed`], write the 2-D cells only (do
//! not mix both kinds of scan in one grid: the next scan with heights re-projects a cell).

use super::limits::{Cell, CellRect, MapLimits};
use super::logodds::{CellState, FixedLogOdds, LogOddsParams, from_fixed, probability_fixed};
use super::ray::bresenham;
use super::scan::{PlanarScan, ScanPoint};
use super::{MapError, MapOptions};
use std::sync::Arc;

mod apply;
mod batch;
mod heights;
mod insert;
mod inspect;
mod mask;
mod tiles;
mod trace;
pub use apply::*;
pub use batch::{BATCH_SCANS, BatchScratch, CellChange, ChangeLog, split_rays};
pub use heights::*;
pub use mask::*;
pub use tiles::*;

/// The log-odds occupancy grid: unbounded, tiled, cheap to clone (see the module docs).
#[derive(Clone, Debug)]
pub struct OccupancyGrid {
    limits: MapLimits,
    params: LogOddsParams,
    fixed: FixedLogOdds,
    dir: TileDir<Tile>,
    free_margin_cells: i32,
    /// Height bins (`[map.height]` enabled); used by scans that carry heights.
    height: Option<HeightLayer>,
}

impl OccupancyGrid {
    /// An empty grid (every cell unknown) from validated options.
    pub fn new(opts: &MapOptions) -> Result<Self, MapError> {
        opts.validate().map_err(MapError::Options)?;
        let mut grid = OccupancyGrid::with_params(opts.limits(), opts.log_odds);
        grid.free_margin_cells = (opts.free_margin_m / opts.resolution_m).round() as i32;
        let h = &opts.height;
        if h.enabled {
            grid.height = Some(HeightLayer {
                bins: h.bins,
                model: BinLogOdds::new(
                    &opts.log_odds,
                    h.occupied_prob.unwrap_or(opts.log_odds.occupied_prob),
                ),
                z_min_m: h.z_min_m as f32,
                bins_per_m: (h.bins as f64 / (h.z_max_m - h.z_min_m)) as f32,
                dir: TileDir::default(),
            });
        }
        Ok(grid)
    }

    /// An empty grid with explicit limits and parameters. The parameters should have passed
    /// [`LogOddsParams::validate`]; unchecked values still give a well-defined (clamped) grid.
    pub fn with_params(limits: MapLimits, params: LogOddsParams) -> Self {
        OccupancyGrid {
            limits,
            params,
            fixed: params.to_fixed(),
            dir: TileDir::default(),
            free_margin_cells: 0,
            height: None,
        }
    }

    /// World <-> cell conversion.
    #[inline]
    pub fn limits(&self) -> &MapLimits {
        &self.limits
    }

    /// The log-odds model.
    #[inline]
    pub fn params(&self) -> &LogOddsParams {
        &self.params
    }

    /// The log-odds model in fixed point.
    #[inline]
    pub fn fixed(&self) -> &FixedLogOdds {
        &self.fixed
    }

    /// Fixed-point log-odds of a cell (0 when never written). The hot-path accessor.
    #[inline(always)]
    pub fn logodds_fixed(&self, cell: Cell) -> i16 {
        let (ti, tj) = tile_of(cell);
        match self.dir.get(ti, tj) {
            Some(t) => t.cells[local_index(cell)],
            None => 0,
        }
    }

    /// The row-major fixed-point cells (`TILE_SIZE` x `TILE_SIZE`) of the tile holding
    /// tile coordinates `(ti, tj)` = cell coordinates shifted right by `TILE_SHIFT`; `None`
    /// when never written. For kernels that read many neighbouring cells.
    #[inline(always)]
    pub fn tile_cells(&self, ti: i32, tj: i32) -> Option<&[i16]> {
        self.dir.get(ti, tj).map(|t| &t.cells[..])
    }

    /// Log-odds of a cell.
    #[inline]
    pub fn logodds(&self, cell: Cell) -> f64 {
        from_fixed(self.logodds_fixed(cell))
    }

    /// Occupancy probability of a cell (sigmoid of its log-odds).
    #[inline]
    pub fn probability(&self, cell: Cell) -> f32 {
        probability_fixed(self.logodds_fixed(cell))
    }

    /// Occupied / free / unknown by the thresholds.
    #[inline(always)]
    pub fn state(&self, cell: Cell) -> CellState {
        self.fixed.classify(self.logodds_fixed(cell))
    }

    /// True when the cell is occupied by the threshold (one integer compare).
    #[inline(always)]
    pub fn is_occupied(&self, cell: Cell) -> bool {
        self.logodds_fixed(cell) >= self.fixed.occupied
    }

    /// The cell containing a world point.
    #[inline(always)]
    pub fn cell_of(&self, x_m: f64, y_m: f64) -> Cell {
        self.limits.cell_of(x_m, y_m)
    }

    fn check_cell(cell: Cell) -> Result<(), MapError> {
        if cell.i.unsigned_abs() > MAX_CELL_INDEX as u32
            || cell.j.unsigned_abs() > MAX_CELL_INDEX as u32
        {
            return Err(MapError::OutOfRange { cell });
        }
        Ok(())
    }

    /// Adds a fixed-point `delta` to a cell's log-odds, clamped to the bounds.
    #[inline]
    pub fn add_fixed(&mut self, cell: Cell, delta: i16) -> Result<(), MapError> {
        Self::check_cell(cell)?;
        let f = self.fixed;
        let (ti, tj) = tile_of(cell);
        let v = &mut self.dir.get_mut(ti, tj, Tile::unknown).cells[local_index(cell)];
        *v = f.apply(*v, delta);
        Ok(())
    }

    /// Applies the hit (occupied) update to a cell.
    pub fn update_occupied(&mut self, cell: Cell) -> Result<(), MapError> {
        self.add_fixed(cell, self.fixed.hit)
    }

    /// Applies the miss (free) update to a cell.
    pub fn update_free(&mut self, cell: Cell) -> Result<(), MapError> {
        self.add_fixed(cell, self.fixed.miss)
    }

    /// Sets a cell's fixed-point log-odds (clamped to the bounds); readers and tests.
    pub fn set_fixed(&mut self, cell: Cell, value: i16) -> Result<(), MapError> {
        Self::check_cell(cell)?;
        let f = self.fixed;
        let (ti, tj) = tile_of(cell);
        self.dir.get_mut(ti, tj, Tile::unknown).cells[local_index(cell)] =
            value.clamp(f.min, f.max);
        Ok(())
    }
}

/// The grid as the observation model's kernels read it.
impl crate::kernels::likelihood::TileGrid for OccupancyGrid {
    #[inline(always)]
    fn limits(&self) -> &MapLimits {
        &self.limits
    }

    #[inline(always)]
    fn tile_cells(&self, ti: i32, tj: i32) -> Option<&[i16]> {
        OccupancyGrid::tile_cells(self, ti, tj)
    }

    #[inline(always)]
    fn logodds_fixed(&self, cell: Cell) -> i16 {
        OccupancyGrid::logodds_fixed(self, cell)
    }
}

#[cfg(test)]
mod reference_tests;
