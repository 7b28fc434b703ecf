//! What a grid holds: its bounds, memory, shared tiles and observed cells.

use super::*;

impl OccupancyGrid {
    /// The rectangle of allocated tiles, in cells (`None` for an empty grid).
    pub fn allocated_bounds(&self) -> Option<CellRect> {
        let d = &self.dir;
        let mut r: Option<CellRect> = None;
        for tj in 0..d.h {
            for ti in 0..d.w {
                if d.tiles[(tj * d.w + ti) as usize].is_some() {
                    let (ci, cj) = ((d.ti0 + ti) << TILE_SHIFT, (d.tj0 + tj) << TILE_SHIFT);
                    let t = CellRect {
                        min_i: ci,
                        min_j: cj,
                        max_i: ci + TILE_MASK,
                        max_j: cj + TILE_MASK,
                    };
                    r = Some(r.map_or(t, |r| r.union(&t)));
                }
            }
        }
        r
    }

    /// The tightest rectangle of cells with non-zero log-odds (`None` when none).
    pub fn observed_bounds(&self) -> Option<CellRect> {
        let d = &self.dir;
        let mut r: Option<CellRect> = None;
        for tj in 0..d.h {
            for ti in 0..d.w {
                let Some(tile) = &d.tiles[(tj * d.w + ti) as usize] else {
                    continue;
                };
                let (ci, cj) = ((d.ti0 + ti) << TILE_SHIFT, (d.tj0 + tj) << TILE_SHIFT);
                for (k, &v) in tile.cells.iter().enumerate() {
                    if v != 0 {
                        let c = Cell::new(
                            ci + (k & (TILE_SIZE - 1)) as i32,
                            cj + (k >> TILE_SHIFT) as i32,
                        );
                        let t = CellRect::around(c);
                        r = Some(r.map_or(t, |r| r.union(&t)));
                    }
                }
            }
        }
        r
    }

    /// Number of allocated tiles.
    pub fn tile_count(&self) -> usize {
        self.dir.count()
    }

    /// Bytes held by tiles and directory, height bins included (shared tiles counted in full).
    pub fn memory_bytes(&self) -> usize {
        let height = self.height.as_ref().map_or(0, |h| {
            h.dir.count() * (TILE_CELLS * MAX_BINS + std::mem::size_of::<HeightTile>())
                + h.dir.tiles.len() * std::mem::size_of::<Option<Arc<HeightTile>>>()
        });
        self.tile_count() * std::mem::size_of::<Tile>()
            + self.dir.tiles.len() * std::mem::size_of::<Option<Arc<Tile>>>()
            + height
    }

    /// Number of tiles holding height bins (0 without `[map.height]` or scans with heights).
    pub fn height_tile_count(&self) -> usize {
        self.height.as_ref().map_or(0, |h| h.dir.count())
    }

    /// The fixed-point log-odds ([`BIN_SCALE`]) of a cell's height bins, lowest first (`None` when the grid
    /// keeps no bins or the cell's tile has none).
    pub fn height_bins(&self, cell: Cell) -> Option<&[i8]> {
        let h = self.height.as_ref()?;
        let (ti, tj) = tile_of(cell);
        h.dir
            .get(ti, tj)
            .map(|t| &t.bins[local_index(cell)][..h.bins])
    }

    /// The identity (address) of every allocated tile: equal ids in two grids mean one
    /// shared tile. For memory reports (distinct tiles over many per-particle maps).
    pub fn tile_ids(&self) -> Vec<usize> {
        self.dir
            .tiles
            .iter()
            .flatten()
            .map(|t| Arc::as_ptr(t) as usize)
            .collect()
    }

    /// Number of tiles this grid shares with another grid (same allocation); for tests of
    /// copy-on-write and memory reports.
    pub fn shared_tiles_with(&self, other: &OccupancyGrid) -> usize {
        let d = &self.dir;
        let mut n = 0;
        for tj in 0..d.h {
            for ti in 0..d.w {
                if let Some(a) = &d.tiles[(tj * d.w + ti) as usize]
                    && let Some(s) = other.dir.slot(d.ti0 + ti, d.tj0 + tj)
                    && let Some(b) = &other.dir.tiles[s]
                    && Arc::ptr_eq(a, b)
                {
                    n += 1;
                }
            }
        }
        n
    }

    /// Calls `visit(cell, log_odds_fixed)` with every cell of `rect` whose log-odds is not 0
    /// (observed at least once), tile by tile (unallocated tiles are skipped without a lookup
    /// per cell). Order: tiles row-major, then cells row-major within a tile; deterministic.
    pub fn for_each_observed_in<F: FnMut(Cell, i16)>(&self, rect: &CellRect, mut visit: F) {
        let (ti_a, tj_a) = (rect.min_i >> TILE_SHIFT, rect.min_j >> TILE_SHIFT);
        let (ti_b, tj_b) = (rect.max_i >> TILE_SHIFT, rect.max_j >> TILE_SHIFT);
        for tj in tj_a..=tj_b {
            for ti in ti_a..=ti_b {
                let Some(tile) = self.dir.get(ti, tj) else {
                    continue;
                };
                let (ci, cj) = (ti << TILE_SHIFT, tj << TILE_SHIFT);
                let li0 = (rect.min_i - ci).max(0);
                let li1 = (rect.max_i - ci).min(TILE_MASK);
                let lj0 = (rect.min_j - cj).max(0);
                let lj1 = (rect.max_j - cj).min(TILE_MASK);
                for lj in lj0..=lj1 {
                    let row = &tile.cells[(lj as usize) << TILE_SHIFT..][..TILE_SIZE];
                    for li in li0..=li1 {
                        let v = row[li as usize];
                        if v != 0 {
                            visit(Cell::new(ci + li, cj + lj), v);
                        }
                    }
                }
            }
        }
    }

    /// Copies the fixed-point log-odds of `rect` into `out` (row-major, row 0 = `rect.min_j`,
    /// i.e. the lowest y), resizing it.
    pub fn copy_rect_fixed(&self, rect: &CellRect, out: &mut Vec<i16>) {
        let (w, h) = (rect.width(), rect.height());
        out.clear();
        out.resize(w * h, 0);
        for (r, row) in out.chunks_mut(w.max(1)).enumerate().take(h) {
            let j = rect.min_j + r as i32;
            for (k, v) in row.iter_mut().enumerate() {
                *v = self.logodds_fixed(Cell::new(rect.min_i + k as i32, j));
            }
        }
    }
}
