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
mod mask;
mod tiles;
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

    /// Inserts one scan given in the world frame: for every ray, Bresenham from the sensor's
    /// cell to the end cell; the cells before the end get the free update, the end cell the
    /// occupied update for a return (the free update for a "no return" clearing ray).
    ///
    /// Per-scan rule: each cell gets at most one update, occupied winning over free, so a cell
    /// crossed by many rays near the sensor is not over-counted and a wall cell grazed by a
    /// neighbouring ray stays occupied. The result is independent of ray order.
    ///
    /// Errors (grid unchanged) when the scan reaches beyond [`MAX_CELL_INDEX`].
    pub fn insert_scan(
        &mut self,
        world_scan: &PlanarScan,
        scratch: &mut InsertScratch,
    ) -> Result<InsertStats, MapError> {
        let traced = self.trace_scan(world_scan, &world_scan.points, scratch)?;
        let mut stats = InsertStats {
            rays: world_scan.points.len(),
            ..InsertStats::default()
        };
        let (t0i, t0j, blocks) = (traced.t0i, traced.t0j, scratch.blocks);
        let f = self.fixed;
        let InsertScratch {
            mask,
            hmask,
            touched,
            ..
        } = scratch;
        let touched = &touched[..traced.len];
        let dir = &mut self.dir;
        // Apply in touch order (ray order: consecutive cells share tiles), clearing the mask.
        match self.height.as_mut() {
            Some(layer) if traced.heights => {
                let model = layer.model;
                for_each_tile_run(touched, blocks, |bi, bj, run| {
                    let (ti, tj) = (t0i + bi, t0j + bj);
                    let tile = dir.get_mut(ti, tj, Tile::unknown);
                    let htile = layer.dir.get_mut(ti, tj, HeightTile::unknown);
                    for &k in run {
                        let k = k as usize;
                        let m = std::mem::replace(&mut hmask[k], 0);
                        stats.count(m >> 16 != 0);
                        let local = local_of(k);
                        apply_bin_marks(
                            &mut tile.cells[local],
                            &mut htile.bins[local],
                            m,
                            &model,
                            f.occupied,
                        );
                    }
                });
            }
            _ => {
                for_each_tile_run(touched, blocks, |bi, bj, run| {
                    let tile = dir.get_mut(t0i + bi, t0j + bj, Tile::unknown);
                    for &k in run {
                        let k = k as usize;
                        let m = std::mem::replace(&mut mask[k], MARK_NONE);
                        stats.count(m == MARK_OCCUPIED);
                        apply_mark(&mut tile.cells[local_of(k)], m == MARK_OCCUPIED, &f);
                    }
                });
            }
        }
        Ok(stats)
    }

    /// The first half of [`Self::insert_scan`] for parallel insertion: traces `world_scan`'s
    /// rays with the same rule and writes its cell updates, grouped by tile, into `out`,
    /// leaving the grid unchanged (it needs only `&self`, so many scans can be traced at once,
    /// one scratch per thread). [`Self::apply_updates`] applies them.
    ///
    /// Errors (`out` left empty) when the scan reaches beyond [`MAX_CELL_INDEX`].
    pub fn trace_updates(
        &self,
        world_scan: &PlanarScan,
        scratch: &mut InsertScratch,
        out: &mut ScanUpdates,
    ) -> Result<InsertStats, MapError> {
        if world_scan.sensor_z_m.is_some() && self.height.is_some() {
            out.clear();
            let traced = self.trace_scan(world_scan, &world_scan.points, scratch)?;
            return Ok(drain_heights(
                &traced,
                world_scan.points.len(),
                scratch,
                out,
            ));
        }
        self.trace_updates_part(world_scan, 0..world_scan.points.len(), scratch, out)
    }

    /// [`Self::trace_updates`] of the rays `rays` of `world_scan` only (clamped to its
    /// points): one piece of a scan split over several tasks. Pieces of one scan, traced in
    /// ray order and passed one after another to [`Self::apply_updates`], are applied as the
    /// whole scan (their marks merged per cell: one update per cell, occupied winning). A
    /// piece that does not start at ray 0 continues the scan of the entry before it. Its
    /// stats count the piece's rays and cells (a cell on two pieces counts in both).
    pub fn trace_updates_part(
        &self,
        world_scan: &PlanarScan,
        rays: std::ops::Range<usize>,
        scratch: &mut InsertScratch,
        out: &mut ScanUpdates,
    ) -> Result<InsertStats, MapError> {
        out.clear();
        let end = rays.end.min(world_scan.points.len());
        let start = rays.start.min(end);
        let points = &world_scan.points[start..end];
        out.continues = start > 0;
        let traced = self.trace_scan(world_scan, points, scratch)?;
        let blocks = scratch.blocks;
        let InsertScratch {
            mask,
            hmask,
            touched,
            block_count,
            block_order,
            ..
        } = scratch;
        let touched = &touched[..traced.len];
        if block_count.len() < blocks * blocks {
            block_count.resize(blocks * blocks, 0);
        }
        // Mask index -> the mask's tile (row-major over `blocks` x `blocks`).
        let block_of = mask_tile;
        // A counting sort by tile; tiles listed in the order the scan first touched them
        // (that of `insert_scan`'s tile runs, so the directory grows the same way).
        // Counted per run of one tile (touch order is ray order): a counter in a register, not
        // a chain of stores to one slot.
        block_order.clear();
        let mut add = |b: usize, n: u32| {
            if block_count[b] == 0 {
                block_order.push(b as u32);
            }
            block_count[b] += n;
        };
        let (mut cur, mut run) = (usize::MAX, 0u32);
        for &k in touched {
            let b = block_of(k as usize);
            if b != cur {
                if run > 0 {
                    add(cur, run);
                }
                (cur, run) = (b, 0);
            }
            run += 1;
        }
        if run > 0 {
            add(cur, run);
        }
        let mut end = 0u32;
        for &b in block_order.iter() {
            let b = b as usize;
            let n = std::mem::replace(&mut block_count[b], end);
            end += n;
            out.tiles.push((
                traced.t0i + (b % blocks) as i32,
                traced.t0j + (b / blocks) as i32,
                end,
            ));
        }
        out.heights = traced.heights;
        out.updates.resize(touched.len(), 0);
        if traced.heights {
            out.bin_marks.resize(touched.len(), 0);
        }
        let mut stats = InsertStats {
            rays: points.len(),
            ..InsertStats::default()
        };
        let (mut cur, mut pos) = (usize::MAX, 0usize);
        for &k in touched {
            let k = k as usize;
            let b = block_of(k);
            if b != cur {
                if cur != usize::MAX {
                    block_count[cur] = pos as u32;
                }
                (cur, pos) = (b, block_count[b] as usize);
            }
            let local = local_of(k) as u16;
            if traced.heights {
                let m = std::mem::replace(&mut hmask[k], 0);
                stats.count(m >> 16 != 0);
                out.updates[pos] = local;
                out.bin_marks[pos] = m;
            } else {
                let occupied = std::mem::replace(&mut mask[k], MARK_NONE) == MARK_OCCUPIED;
                stats.count(occupied);
                out.updates[pos] = local | if occupied { UPDATE_OCCUPIED } else { 0 };
            }
            pos += 1;
        }
        for &b in block_order.iter() {
            block_count[b as usize] = 0;
        }
        out.stats = stats;
        Ok(stats)
    }

    /// Applies traced scans ([`Self::trace_updates`]) in their order: the grid ends exactly as
    /// after [`Self::insert_scan`] of each scan in turn (same cells, bins, tiles and directory),
    /// whatever the thread count. Tiles are created (or copied when shared) serially in the
    /// sequential order, then updated in parallel, one task per tile applying its updates scan
    /// by scan: an update reads and writes only its own cell (and bins), so the tiles are
    /// independent and each cell sees its updates in scan order. Consecutive pieces of one
    /// scan ([`Self::trace_updates_part`]) are merged per tile first (marks ORed per cell, as
    /// one mask would), so each cell still gets one update per scan. The updates must come
    /// from this grid (or a clone with the same options) and be applied once, in scan order.
    pub fn apply_updates(&mut self, scans: &[&ScanUpdates]) {
        // Create the tiles in the order sequential insertion would (the directory grows alike).
        for su in scans {
            for &(ti, tj, _) in &su.tiles {
                self.dir.get_mut(ti, tj, Tile::unknown);
                if su.heights
                    && let Some(layer) = self.height.as_mut()
                {
                    layer.dir.get_mut(ti, tj, HeightTile::unknown);
                }
            }
        }
        // (directory slot, scan, tile group), sorted: each tile's groups in scan order.
        let mut entries: Vec<(u32, u32, u32)> = Vec::new();
        for (s, su) in scans.iter().enumerate() {
            for (g, &(ti, tj, _)) in su.tiles.iter().enumerate() {
                if let Some(slot) = self.dir.slot(ti, tj) {
                    entries.push((slot as u32, s as u32, g as u32));
                }
            }
        }
        entries.sort_unstable();
        let mut jobs: Vec<TileJob> = Vec::new();
        let mut start = 0;
        while start < entries.len() {
            let slot = entries[start].0;
            let mut end = start + 1;
            while end < entries.len() && entries[end].0 == slot {
                end += 1;
            }
            let (ti, tj) = self.dir.coords(slot as usize);
            let needs_bins = entries[start..end]
                .iter()
                .any(|e| scans[e.1 as usize].heights);
            let hslot = self
                .height
                .as_ref()
                .filter(|_| needs_bins)
                .and_then(|l| l.dir.slot(ti, tj));
            jobs.push(TileJob {
                slot: slot as usize,
                hslot,
                tile: self.dir.tiles[slot as usize].take(),
                htile: match (hslot, self.height.as_mut()) {
                    (Some(h), Some(l)) => l.dir.tiles[h].take(),
                    _ => None,
                },
                entries: start..end,
            });
            start = end;
        }
        let f = self.fixed;
        let model = self.height.as_ref().map(|l| l.model);
        // Pieces of one scan ([`Self::trace_updates_part`]) share the number of its first.
        let mut scan_of: Vec<u32> = Vec::with_capacity(scans.len());
        for (p, su) in scans.iter().enumerate() {
            let first = match scan_of.last() {
                Some(&prev) if su.continues => prev,
                _ => p as u32,
            };
            scan_of.push(first);
        }
        let (entries, scan_of) = (&entries, &scan_of);
        let apply = |job: &mut TileJob| {
            let Some(tile) = job.tile.as_mut().map(Arc::make_mut) else {
                return;
            };
            let mut htile = job.htile.as_mut().map(Arc::make_mut);
            // Cells whose bins changed since their 2-D value was last projected: a cell's
            // value is only read by a later 2-D update or at the end, so it is projected then
            // (once per batch instead of once per scan; the same value).
            // One byte per cell: flagging neighbours makes no chain of stores to one word.
            let mut stale = [false; TILE_CELLS];
            let job_entries = &entries[job.entries.clone()];
            let group = |&(_, p, g): &(u32, u32, u32)| {
                let su = scans[p as usize];
                let g = g as usize;
                let from = if g == 0 {
                    0
                } else {
                    su.tiles[g - 1].2 as usize
                };
                (su, from..su.tiles[g].2 as usize)
            };
            let mut e = 0;
            while e < job_entries.len() {
                // This tile's entries of one scan: one piece, or several to merge.
                let scan = scan_of[job_entries[e].1 as usize];
                let mut end = e + 1;
                while end < job_entries.len() && scan_of[job_entries[end].1 as usize] == scan {
                    end += 1;
                }
                let heights = scans[job_entries[e].1 as usize].heights;
                let mut run = TileRun {
                    tile: &mut *tile,
                    htile: htile.as_deref_mut(),
                    stale: &mut stale,
                    model,
                    heights,
                    f: &f,
                };
                if end == e + 1 {
                    let (su, range) = group(&job_entries[e]);
                    let updates = &su.updates[range.clone()];
                    if run.heights() {
                        run.apply_bins(updates, &su.bin_marks[range]);
                    } else {
                        run.apply(updates.iter().map(|&u| {
                            (
                                usize::from(u) & (TILE_CELLS - 1),
                                u32::from(u & UPDATE_OCCUPIED != 0),
                            )
                        }));
                    }
                } else {
                    // Marks ORed per cell as one mask would (occupied wins, bins united),
                    // then applied once per cell.
                    MERGE.with_borrow_mut(|m| {
                        let MergeScratch { acc, order } = m;
                        let mut n = 0;
                        let mut add = |local: usize, mark: u32| {
                            if acc[local] == 0 {
                                order[n] = local as u16;
                                n += 1;
                            }
                            acc[local] |= mark;
                        };
                        for entry in &job_entries[e..end] {
                            let (su, range) = group(entry);
                            let updates = &su.updates[range.clone()];
                            if su.heights {
                                for (&u, &m) in updates.iter().zip(&su.bin_marks[range]) {
                                    add(usize::from(u) & (TILE_CELLS - 1), m);
                                }
                            } else {
                                for &u in updates {
                                    let occupied = u32::from(u & UPDATE_OCCUPIED != 0);
                                    add(usize::from(u) & (TILE_CELLS - 1), 1 | occupied << 1);
                                }
                            }
                        }
                        let shift = if heights { 0 } else { 1 };
                        run.apply(order[..n].iter().map(|&l| {
                            let l = usize::from(l);
                            (l, std::mem::take(&mut acc[l]) >> shift)
                        }));
                    });
                }
                e = end;
            }
            if let (Some(ht), Some(model)) = (&htile, model) {
                for (local, _) in stale.iter().enumerate().filter(|s| *s.1) {
                    tile.cells[local] = project_column(&ht.bins[local], &model, f.occupied);
                }
            }
        };
        use rayon::prelude::*;
        jobs.par_iter_mut().for_each(apply);
        for job in jobs {
            self.dir.tiles[job.slot] = job.tile;
            if let (Some(h), Some(l)) = (job.hslot, self.height.as_mut()) {
                l.dir.tiles[h] = job.htile;
            }
        }
    }

    /// Traces a scan's rays into the scratch mask (`mask`, or `hmask` for a scan with heights
    /// on a grid with height bins) and lists the touched cells; the grid is not changed.
    fn trace_scan(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        scratch: &mut InsertScratch,
    ) -> Result<Traced, MapError> {
        let origin = self.scan_origin(world_scan, points, scratch)?;
        let sh = scratch.half;
        // Tile coordinates of the mask's first tile, and its first cell.
        let (t0i, t0j) = ((origin.i - sh) >> TILE_SHIFT, (origin.j - sh) >> TILE_SHIFT);
        let (mi0, mj0) = (t0i << TILE_SHIFT, t0j << TILE_SHIFT);
        let len = match (world_scan.sensor_z_m, self.height.as_ref()) {
            (Some(z), Some(layer)) => {
                self.trace_heights(world_scan, points, z, layer, origin, (mi0, mj0), scratch)
            }
            _ => self.trace_planar(world_scan, points, origin, (mi0, mj0), scratch),
        };
        Ok(Traced {
            t0i,
            t0j,
            len,
            heights: world_scan.sensor_z_m.is_some() && self.height.is_some(),
        })
    }

    /// [`Self::trace_scan`] for a scan without heights: one mark per cell.
    fn trace_planar(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        origin: Cell,
        (mi0, mj0): (i32, i32),
        scratch: &mut InsertScratch,
    ) -> usize {
        let InsertScratch {
            mask,
            touched,
            xoff,
            yoff,
            walk,
            ..
        } = scratch;
        let layout = MaskLayout {
            xoff,
            yoff,
            mi0,
            mj0,
        };
        let mut marks = TouchMarks {
            mask,
            touched,
            len: 0,
        };
        self.trace_planar_marks(world_scan, points, origin, &layout, walk, &mut marks);
        marks.len
    }

    /// [`Self::trace_planar`]'s rays into `marks`, one after the other (ray by ray, see
    /// `docs/decisions/0016-joining-returns-in-maps.md`).
    #[inline(always)]
    fn trace_planar_marks<M: Marks>(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        origin: Cell,
        layout: &MaskLayout<'_>,
        walk: &mut RayCells,
        marks: &mut M,
    ) {
        // Another scan, or another piece of one: no ray of it marked yet.
        walk.forget();
        for p in points {
            trace_planar_ray(
                &self.limits,
                world_scan,
                p,
                self.free_margin_cells,
                origin,
                layout,
                walk,
                marks,
            );
        }
    }

    /// Where the tracing of `world_scan` may be cut into pieces
    /// ([`Self::trace_updates_part`]) that insert as the whole scan, with the work before
    /// each place, into `out` (cleared first): `(ray, work)` in ray order, from `(0, 0)` to
    /// `(points, total)`. Every ray is such a place. Work: cells walked per ray (Chebyshev
    /// length plus its end cell).
    pub fn trace_cuts(&self, world_scan: &PlanarScan, out: &mut Vec<(usize, u64)>) {
        out.clear();
        let points = &world_scan.points;
        let o = self.cell_of(world_scan.sensor_x_m, world_scan.sensor_y_m);
        let mut work = 0u64;
        for (i, p) in points.iter().enumerate() {
            out.push((i, work));
            let c = self.cell_of(p.x_m, p.y_m);
            work += u64::from((c.i - o.i).unsigned_abs().max((c.j - o.j).unsigned_abs())) + 1;
        }
        out.push((points.len(), work));
    }

    /// Checks a scan's cells and sizes the scratch mask for its longest ray; returns the
    /// sensor's cell.
    fn scan_origin(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        scratch: &mut InsertScratch,
    ) -> Result<Cell, MapError> {
        let origin = self.cell_of(world_scan.sensor_x_m, world_scan.sensor_y_m);
        Self::check_cell(origin)?;
        // Mask half-size: the farthest end cell (Chebyshev), so every ray fits.
        let mut half = 0i32;
        for p in points {
            let c = self.cell_of(p.x_m, p.y_m);
            Self::check_cell(c)?;
            half = half.max((c.i - origin.i).abs()).max((c.j - origin.j).abs());
        }
        if half > MAX_RAY_CELLS {
            return Err(MapError::RayTooLong {
                cells: half,
                max: MAX_RAY_CELLS,
            });
        }
        scratch.ensure_half(half);
        Ok(origin)
    }

    /// [`Self::trace_scan`] for a scan with heights on a grid with height bins: the same
    /// cells, rules and margins, but per (cell, height bin). A ray is the 3-D segment from the
    /// sensor (`sensor_z_m`) to its end point (`z_m`); the cell `k` steps along its digital
    /// line (of `n` to the end cell) is passed at the height `k / n` of the way, the end cell
    /// hit at the return's height. Per scan each bin of a cell gets at most one update,
    /// occupied winning; applying re-projects the cell's 2-D log-odds ([`project_bins`]).
    #[allow(clippy::too_many_arguments)]
    fn trace_heights(
        &self,
        world_scan: &PlanarScan,
        points: &[ScanPoint],
        sensor_z_m: f64,
        layer: &HeightLayer,
        origin: Cell,
        (mi0, mj0): (i32, i32),
        scratch: &mut InsertScratch,
    ) -> usize {
        let InsertScratch {
            hmask,
            touched,
            mask,
            bits,
            cells,
            xoff,
            yoff,
            ..
        } = scratch;
        let layout = MaskLayout {
            xoff,
            yoff,
            mi0,
            mj0,
        };
        let flat = |c: Cell| layout.index(c);
        if hmask.len() != mask.len() {
            // Zeroed: a previous insertion left it clear, a new one is clear.
            *hmask = vec![0; mask.len()];
        }
        let mut len = 0usize;
        let mark = |hmask: &mut [u32], touched: &mut [u32], len: &mut usize, k: usize, m: u32| {
            let old = hmask[k];
            hmask[k] = old | m;
            touched[*len] = k as u32;
            *len += usize::from(old == 0);
        };
        let limits = self.limits;
        let z0 = sensor_z_m as f32;
        let margin_cells = self.free_margin_cells;
        for p in points {
            let (end, clear_end, partial) = ray_cells(&limits, world_scan, p);
            let margin = if p.hit { margin_cells } else { 0 };
            let n_full = (end.i - origin.i).abs().max((end.j - origin.j).abs());
            // Height gained per step of the full ray's digital line.
            let dz = if n_full > 0 {
                (p.z_m - z0) / n_full as f32
            } else {
                0.0
            };
            let n = (clear_end.i - origin.i)
                .abs()
                .max((clear_end.j - origin.j).abs());
            if touched.len() < len + n as usize + 2 {
                touched.resize(len + n as usize + 2 + 4096, 0);
            }
            // Steps along the clearing line stand for the same distance as along the full
            // ray's (both are the major-axis distance to the sensor's cell, up to rounding).
            if partial && margin > 0 {
                let mut step = 0i32;
                bresenham(origin, clear_end, |c| {
                    let z = z0 + step as f32 * dz;
                    step += 1;
                    if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin || c == clear_end {
                        return;
                    }
                    mark(hmask, touched, &mut len, flat(c), layer.bit(z));
                });
            } else {
                let count = if partial { n } else { (n - margin).max(0) } as usize;
                if bits.len() < count {
                    bits.resize(count + 1024, 0);
                }
                if cells.len() < count {
                    cells.resize(count + 1024, 0);
                }
                let (bits, cells) = (&mut bits[..count], &mut cells[..count]);
                layer.fill_bits(z0, dz, bits);
                walk_mask(origin, clear_end, &layout, cells);
                len = mark_cells(hmask, touched, len, cells, bits.iter().copied());
            }
            let bit = layer.bit(p.z_m);
            let want = if p.hit { bit << 16 } else { bit };
            mark(hmask, touched, &mut len, flat(end), want);
        }
        len
    }

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

#[cfg(test)]
mod reference_tests;
