//! Tiles of cells and the directory that holds them (copy-on-write `Arc` tiles).

use super::*;

/// The tile layout, defined with the kernels that walk the tiles.
pub(crate) use crate::kernels::{TILE_CELLS, TILE_MASK};
pub use crate::kernels::{TILE_SHIFT, TILE_SIZE};

/// Cell indices beyond this magnitude are refused (1,677 km at 0.1 m), which bounds the tile
/// directory whatever a pose says.
pub const MAX_CELL_INDEX: i32 = 1 << 24;

/// The longest ray [`OccupancyGrid::insert_scan`] accepts, in cells (Chebyshev): bounds the
/// scratch mask to 16,385^2 bytes (268 MB); 75 m at 0.05 m is 1,500 cells.
pub const MAX_RAY_CELLS: i32 = 8192;

/// Bytes of one tile's cells.
pub const TILE_BYTES: usize = std::mem::size_of::<Tile>();

/// One tile: `TILE_SIZE^2` cells, row-major (`local_j * TILE_SIZE + local_i`).
#[derive(Clone)]
pub struct Tile {
    pub(super) cells: [i16; TILE_CELLS],
}

impl Tile {
    pub(super) fn unknown() -> Self {
        Tile {
            cells: [0; TILE_CELLS],
        }
    }

    /// The cells, row-major.
    pub fn cells(&self) -> &[i16] {
        &self.cells
    }
}

impl std::fmt::Debug for Tile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let nonzero = self.cells.iter().filter(|&&v| v != 0).count();
        write!(f, "Tile({nonzero} observed cells)")
    }
}

#[inline(always)]
pub(super) fn tile_of(cell: Cell) -> (i32, i32) {
    (cell.i >> TILE_SHIFT, cell.j >> TILE_SHIFT)
}

#[inline(always)]
pub(super) fn local_index(cell: Cell) -> usize {
    (((cell.j & TILE_MASK) as usize) << TILE_SHIFT) | (cell.i & TILE_MASK) as usize
}

/// Dense directory of optional tiles (of cells, or of height bins) over a rectangle of tile
/// coordinates.
#[derive(Clone, Debug)]
pub(super) struct TileDir<T> {
    pub(super) ti0: i32,
    pub(super) tj0: i32,
    pub(super) w: i32,
    pub(super) h: i32,
    pub(super) tiles: Vec<Option<Arc<T>>>,
}

impl<T> Default for TileDir<T> {
    fn default() -> Self {
        TileDir {
            ti0: 0,
            tj0: 0,
            w: 0,
            h: 0,
            tiles: Vec::new(),
        }
    }
}

impl<T: Clone> TileDir<T> {
    #[inline(always)]
    pub(super) fn slot(&self, ti: i32, tj: i32) -> Option<usize> {
        let di = ti.wrapping_sub(self.ti0);
        let dj = tj.wrapping_sub(self.tj0);
        if (di as u32) < (self.w as u32) && (dj as u32) < (self.h as u32) {
            Some(dj as usize * self.w as usize + di as usize)
        } else {
            None
        }
    }

    #[inline(always)]
    pub(super) fn get(&self, ti: i32, tj: i32) -> Option<&T> {
        self.slot(ti, tj).and_then(|s| self.tiles[s].as_deref())
    }

    /// Grows the directory to include tile `(ti, tj)`, with slack so that growth is amortised.
    pub(super) fn grow_to(&mut self, ti: i32, tj: i32) {
        let (mut i0, mut j0, mut i1, mut j1) = if self.w == 0 {
            (ti, tj, ti, tj)
        } else {
            (
                self.ti0.min(ti),
                self.tj0.min(tj),
                (self.ti0 + self.w - 1).max(ti),
                (self.tj0 + self.h - 1).max(tj),
            )
        };
        // Slack: extend the side that grew by half the current span (at least 4 tiles).
        let slack_i = ((i1 - i0 + 1) / 2).max(4);
        let slack_j = ((j1 - j0 + 1) / 2).max(4);
        if self.w != 0 {
            if ti < self.ti0 {
                i0 -= slack_i;
            }
            if ti >= self.ti0 + self.w {
                i1 += slack_i;
            }
            if tj < self.tj0 {
                j0 -= slack_j;
            }
            if tj >= self.tj0 + self.h {
                j1 += slack_j;
            }
        } else {
            i0 -= 2;
            j0 -= 2;
            i1 += 2;
            j1 += 2;
        }
        let (w, h) = (i1 - i0 + 1, j1 - j0 + 1);
        let mut tiles: Vec<Option<Arc<T>>> = vec![None; w as usize * h as usize];
        for dj in 0..self.h {
            for di in 0..self.w {
                let old = (dj * self.w + di) as usize;
                let new = ((self.tj0 + dj - j0) * w + (self.ti0 + di - i0)) as usize;
                tiles[new] = self.tiles[old].take();
            }
        }
        *self = TileDir {
            ti0: i0,
            tj0: j0,
            w,
            h,
            tiles,
        };
    }

    /// The tile `(ti, tj)` for writing (created by `new` when absent; copied when shared).
    #[inline]
    pub(super) fn get_mut(&mut self, ti: i32, tj: i32, new: impl FnOnce() -> T) -> &mut T {
        let s = match self.slot(ti, tj) {
            Some(s) => s,
            None => {
                self.grow_to(ti, tj);
                // In range after growing.
                self.slot(ti, tj).unwrap_or(0)
            }
        };
        Arc::make_mut(self.tiles[s].get_or_insert_with(|| Arc::new(new())))
    }

    pub(super) fn count(&self) -> usize {
        self.tiles.iter().filter(|t| t.is_some()).count()
    }

    /// The tile coordinates of a slot.
    pub(super) fn coords(&self, slot: usize) -> (i32, i32) {
        let w = self.w.max(1) as usize;
        (self.ti0 + (slot % w) as i32, self.tj0 + (slot / w) as i32)
    }
}
