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
mod reference_tests {
    use super::*;
    use crate::map::ScanPoint;
    use rand::{RngExt, SeedableRng};
    use std::collections::BTreeMap;

    /// The per-scan rule of [`OccupancyGrid::insert_scan`] written plainly (a map of marks,
    /// per-cell checks on every Bresenham cell): the optimised insertion must equal it.
    fn insert_reference(g: &mut OccupancyGrid, scan: &PlanarScan) -> InsertStats {
        let origin = g.cell_of(scan.sensor_x_m, scan.sensor_y_m);
        let mut marks: BTreeMap<Cell, u8> = BTreeMap::new();
        for p in &scan.points {
            let end = g.cell_of(p.x_m, p.y_m);
            let margin = if p.hit { g.free_margin_cells } else { 0 };
            let (clear_end, partial) = if p.free_to < 1.0 {
                let t = f64::from(p.free_to.max(0.0));
                let x = scan.sensor_x_m + t * (p.x_m - scan.sensor_x_m);
                let y = scan.sensor_y_m + t * (p.y_m - scan.sensor_y_m);
                (g.cell_of(x, y), true)
            } else {
                (end, false)
            };
            bresenham(origin, clear_end, |c| {
                if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin
                    || (partial && c == clear_end)
                {
                    return;
                }
                let m = marks.entry(c).or_insert(1);
                *m = (*m).max(1);
            });
            let m = marks.entry(end).or_insert(0);
            *m = (*m).max(if p.hit { 2 } else { 1 });
        }
        let f = g.fixed;
        let mut stats = InsertStats {
            rays: scan.points.len(),
            ..InsertStats::default()
        };
        for (c, m) in marks {
            let delta = if m == 2 {
                stats.occupied_cells += 1;
                f.hit
            } else {
                stats.free_cells += 1;
                f.miss
            };
            let v = g.logodds_fixed(c);
            g.set_fixed(c, f.apply(v, delta)).unwrap();
        }
        stats
    }

    /// The height-bin rule of [`OccupancyGrid::insert_scan`] written plainly: marks per
    /// (cell, bin), bins kept in `bins`, the cell set to their projection.
    fn insert_reference_heights(
        g: &mut OccupancyGrid,
        bins: &mut BTreeMap<Cell, Vec<i8>>,
        scan: &PlanarScan,
    ) -> InsertStats {
        let layer = g.height.clone().unwrap();
        let bin = |z: f32| layer.bit(z).trailing_zeros() as usize;
        let z0 = scan.sensor_z_m.unwrap() as f32;
        let origin = g.cell_of(scan.sensor_x_m, scan.sensor_y_m);
        // (cell, bin) -> 1 free, 2 occupied
        let mut marks: BTreeMap<(Cell, usize), u8> = BTreeMap::new();
        for p in &scan.points {
            let end = g.cell_of(p.x_m, p.y_m);
            let margin = if p.hit { g.free_margin_cells } else { 0 };
            let (clear_end, partial) = if p.free_to < 1.0 {
                let t = f64::from(p.free_to.max(0.0));
                let x = scan.sensor_x_m + t * (p.x_m - scan.sensor_x_m);
                let y = scan.sensor_y_m + t * (p.y_m - scan.sensor_y_m);
                (g.cell_of(x, y), true)
            } else {
                (end, false)
            };
            let n_full = (end.i - origin.i).abs().max((end.j - origin.j).abs());
            let dz = if n_full > 0 {
                (p.z_m - z0) / n_full as f32
            } else {
                0.0
            };
            let mut step = 0;
            bresenham(origin, clear_end, |c| {
                let z = z0 + step as f32 * dz;
                step += 1;
                if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin
                    || (partial && c == clear_end)
                {
                    return;
                }
                let m = marks.entry((c, bin(z))).or_insert(1);
                *m = (*m).max(1);
            });
            let m = marks.entry((end, bin(p.z_m))).or_insert(0);
            *m = (*m).max(if p.hit { 2 } else { 1 });
        }
        let mut stats = InsertStats {
            rays: scan.points.len(),
            ..InsertStats::default()
        };
        let mut cells: BTreeMap<Cell, bool> = BTreeMap::new();
        for ((c, b), m) in marks {
            let col = bins.entry(c).or_insert_with(|| vec![0; layer.bins]);
            let d = if m == 2 {
                layer.model.hit
            } else {
                layer.model.miss
            };
            col[b] = (col[b] as i32 + d as i32)
                .clamp(layer.model.min as i32, layer.model.max as i32) as i8;
            *cells.entry(c).or_insert(false) |= m == 2;
        }
        for (c, occ) in cells {
            if occ {
                stats.occupied_cells += 1;
            } else {
                stats.free_cells += 1;
            }
            let v = project_bins(&bins[&c], &layer.model, g.fixed.occupied);
            g.set_fixed(c, v).unwrap();
        }
        stats
    }

    /// [`project_bins`] as first written (signed bytes, one at a time).
    fn project_bins_plain(bins: &[i8], model: &BinLogOdds, occupied: i16) -> i16 {
        let (mut lo, mut hi) = (i8::MAX, i8::MIN);
        for &v in bins {
            lo = lo.min(if v == 0 { i8::MAX } else { v });
            hi = hi.max(v);
        }
        let scale = (crate::map::logodds::LOGODDS_SCALE / BIN_SCALE) as i16;
        if hi >= model.occupied {
            (hi as i16 * scale).max(occupied)
        } else if lo == i8::MAX {
            0
        } else {
            lo as i16 * scale
        }
    }

    #[test]
    fn column_projection_equals_project_bins() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let edge = [i8::MIN, -127, -1, 0, 1, 13, 14, 15, 126, i8::MAX];
        for case in 0..20_000 {
            let model = BinLogOdds::new(
                &crate::map::LogOddsParams::ese650(),
                [0.55, 0.7, 0.9, 0.999][case % 4],
            );
            let mut bins = [0i8; MAX_BINS];
            let observed = rng.random_range(0..=MAX_BINS);
            for v in bins.iter_mut().take(observed) {
                *v = if rng.random_range(0..4) == 0 {
                    edge[rng.random_range(0..edge.len())]
                } else {
                    rng.random_range(-128..=127i32) as i8
                };
            }
            bins.swap(0, rng.random_range(0..MAX_BINS));
            for occupied in [1, 563, 25600] {
                let want = project_bins_plain(&bins, &model, occupied);
                assert_eq!(project_column(&bins, &model, occupied), want, "{bins:?}");
                let n = observed.max(1);
                let short = project_bins_plain(&bins[..n], &model, occupied);
                assert_eq!(
                    project_bins(&bins[..n], &model, occupied),
                    short,
                    "{bins:?}"
                );
            }
        }
    }

    #[test]
    fn mask_layout_splits_into_tile_and_row_major_cell() {
        // Every cell of a 3 x 3-tile mask: a distinct index below the mask's size, whose tile
        // and in-tile cell are the cell's (row-major, as `Tile`).
        let blocks = 3usize;
        let side = (blocks * TILE_SIZE) as u32;
        let mut seen = vec![false; blocks * blocks * TILE_CELLS];
        for r in 0..side {
            for c in 0..side {
                let k = (mask_x(c) + mask_y(r, blocks)) as usize;
                assert!(!std::mem::replace(&mut seen[k], true), "({c}, {r}) twice");
                let (tc, tr) = ((c >> TILE_SHIFT) as usize, (r >> TILE_SHIFT) as usize);
                assert_eq!(mask_tile(k), tr * blocks + tc);
                let (lc, lr) = (c as usize % TILE_SIZE, r as usize % TILE_SIZE);
                assert_eq!(local_of(k), lr * TILE_SIZE + lc);
            }
        }
    }

    #[test]
    fn vectorised_walk_equals_the_scalar_walk() {
        // Random rays in masks of 1-30 tiles a side (every octant, axis-parallel and
        // diagonal ones, up to MAX_RAY_CELLS long), each prefix length from 8 to the whole
        // ray: the eight-lane walk writes the scalar walk's indices, and takes every ray
        // that fits in its mask.
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(21);
            let (mut want, mut got) = (Vec::new(), Vec::new());
            let mut taken = 0;
            for case in 0..4000 {
                let blocks = if case % 50 == 0 {
                    260
                } else {
                    rng.random_range(1..=30usize)
                };
                let side = (blocks * TILE_SIZE) as u32;
                let xoff: Vec<u32> = (0..side).map(mask_x).collect();
                let yoff: Vec<u32> = (0..side).map(|r| mask_y(r, blocks)).collect();
                let (mi0, mj0) = (rng.random_range(-5000..5000), rng.random_range(-5000..5000));
                let layout = MaskLayout {
                    xoff: &xoff,
                    yoff: &yoff,
                    mi0,
                    mj0,
                };
                let side = side as i32;
                let max = side.min(MAX_RAY_CELLS + 1);
                let cell = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus| {
                    Cell::new(
                        mi0 + rng.random_range(0..side),
                        mj0 + rng.random_range(0..side),
                    )
                };
                let from = cell(&mut rng);
                let to = match case % 5 {
                    // Axis-parallel, diagonal, or anywhere (steep and shallow alike).
                    0 => Cell::new(from.i, mj0 + rng.random_range(0..side)),
                    1 => Cell::new(mi0 + rng.random_range(0..side), from.j),
                    2 => {
                        let d = rng.random_range(0..max);
                        let d = d
                            .min(side - 1 - (from.i - mi0))
                            .min(side - 1 - (from.j - mj0));
                        Cell::new(from.i + d, from.j + d)
                    }
                    _ => cell(&mut rng),
                };
                let n = (to.i - from.i).abs().max((to.j - from.j).abs()) as usize;
                if n + 1 < 8 {
                    continue;
                }
                let len = if case % 3 == 0 {
                    n + 1
                } else {
                    rng.random_range(8..=n + 1)
                };
                want.resize(len, 0);
                got.resize(len, u32::MAX);
                walk_mask_scalar(from, to, &layout, &mut want);
                // SAFETY: AVX2 is present (checked above).
                assert!(
                    unsafe { walk_mask_avx2(from, to, &layout, &mut got) },
                    "case {case}"
                );
                assert_eq!(got, want, "case {case}: {from:?} -> {to:?}, {len} cells");
                taken += 1;
            }
            assert!(taken > 3000, "{taken}");
            // A ray leaving the mask is left to the scalar walk.
            let xoff: Vec<u32> = (0..TILE_SIZE as u32).map(mask_x).collect();
            let yoff: Vec<u32> = (0..TILE_SIZE as u32).map(|r| mask_y(r, 1)).collect();
            let layout = MaskLayout {
                xoff: &xoff,
                yoff: &yoff,
                mi0: 0,
                mj0: 0,
            };
            let mut out = vec![0u32; 10];
            // SAFETY: AVX2 is present (checked above).
            assert!(!unsafe {
                walk_mask_avx2(Cell::new(60, 0), Cell::new(70, 3), &layout, &mut out)
            });
        }
    }

    #[test]
    fn fresh_cells_are_the_cells_unlike_the_previous_rays() {
        // Lists of 0-100 cells, a share of them equal to the previous ray's at the same
        // place (none, some, all), the previous ray shorter, as long or longer: the
        // compaction keeps exactly the unequal ones, in order, on every path.
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(31);
        for case in 0..3000 {
            let len = rng.random_range(0..100usize);
            let same = [0.0, 0.5, 0.9, 1.0][case % 4];
            let ray: Vec<u32> = (0..len).map(|_| rng.random_range(0..50)).collect();
            let prev: Vec<u32> = ray
                .iter()
                .map(|&k| if rng.random_bool(same) { k } else { k + 1 })
                .collect();
            let common = rng.random_range(0..=len);
            let (ray, prev) = (&ray[..common], &prev[..common]);
            let want: Vec<u32> = ray
                .iter()
                .zip(prev)
                .filter(|(k, p)| k != p)
                .map(|(&k, _)| k)
                .collect();
            let mut out = vec![u32::MAX; common + 8];
            let n = fresh_cells(ray, prev, &mut out);
            assert_eq!(&out[..n], &want[..], "case {case}");
            let n = fresh_cells_scalar(ray, prev, &mut out, 0, 0);
            assert_eq!(&out[..n], &want[..], "case {case}, scalar");
        }
    }

    #[test]
    fn vectorised_bin_updates_equal_the_per_bin_rule() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(13);
        for case in 0..200 {
            // Random models, extremes included: steps up to the whole range, bounds at
            // the `i8` limits and equal bounds.
            let mut model = BinLogOdds::new(&crate::map::LogOddsParams::ese650(), 0.7);
            if case % 2 == 1 {
                let lo = rng.random_range(-127..=0i8);
                let hi = if case % 10 == 3 {
                    lo
                } else {
                    rng.random_range(lo..=127i8)
                };
                model = BinLogOdds {
                    hit: rng.random_range(1..=127),
                    miss: rng.random_range(-127..=-1),
                    min: lo,
                    max: hi,
                    occupied: rng.random_range(1..=127),
                };
            }
            let n = rng.random_range(0..300);
            let updates: Vec<u16> = (0..n)
                .map(|_| rng.random_range(0..TILE_CELLS as u16) | rng.random_range(0..16) << 12)
                .collect();
            let marks: Vec<u32> = (0..n)
                .map(|_| match rng.random_range(0..4) {
                    0 => rng.random::<u32>(),
                    1 => 1 << rng.random_range(0..32),
                    2 => 0,
                    _ => rng.random::<u32>() & rng.random::<u32>(),
                })
                .collect();
            let start = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus| -> Vec<[i8; MAX_BINS]> {
                (0..TILE_CELLS)
                    .map(|_| std::array::from_fn(|_| rng.random_range(model.min..=model.max)))
                    .collect()
            };
            let mut want = start(&mut rng);
            let mut got = want.clone();
            let (mut want_stale, mut got_stale) = ([false; TILE_CELLS], [false; TILE_CELLS]);
            for (&u, &m) in updates.iter().zip(&marks) {
                let local = usize::from(u) & (TILE_CELLS - 1);
                update_bins(&mut want[local], m, &model);
                want_stale[local] = true;
            }
            BinUpdater::new(&model).run(&mut got, &mut got_stale, &updates, &marks, &model);
            assert!(got == want, "case {case}: bins differ");
            assert!(got_stale == want_stale, "case {case}: stale cells differ");
            let one = BinUpdater::new(&model);
            let mut each = start(&mut rng);
            let mut plain = each.clone();
            for (&u, &m) in updates.iter().zip(&marks) {
                let local = usize::from(u) & (TILE_CELLS - 1);
                one.update(&mut each[local], m, &model);
                update_bins(&mut plain[local], m, &model);
            }
            assert!(each == plain, "case {case}: single updates differ");
            // The SSE4.1 path on its own (the updater above takes AVX-512 where it can).
            #[cfg(target_arch = "x86_64")]
            if model.min <= model.max && std::arch::is_x86_feature_detected!("sse4.1") {
                let mut sse = start(&mut rng);
                let mut plain = sse.clone();
                for (&u, &m) in updates.iter().zip(&marks) {
                    let local = usize::from(u) & (TILE_CELLS - 1);
                    // SAFETY: the CPU has SSE4.1 (checked above).
                    unsafe { update_bins_sse41(&mut sse[local], m, &model) };
                    update_bins(&mut plain[local], m, &model);
                }
                assert!(sse == plain, "case {case}: SSE4.1 updates differ");
            }
        }
    }

    #[test]
    fn whole_scan_drain_equals_the_piece_drain() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(14);
        for case in 0..40 {
            let opts = MapOptions {
                resolution_m: [0.05, 0.1, 0.37][case % 3],
                free_margin_m: [0.0, 0.3][(case / 3) % 2],
                ..MapOptions::default()
            };
            let grid = OccupancyGrid::new(&opts).unwrap();
            let mut scratch = InsertScratch::new();
            let centre = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
            let range_max = rng.random_range(0.5..40.0);
            let scan = random_scan(&mut rng, centre, range_max, true, [300, 5, 3]);
            let (mut whole, mut piece) = (ScanUpdates::new(), ScanUpdates::new());
            // Dirty buffers from a scan before: both must start afresh.
            let other = random_scan(&mut rng, (0.0, 0.0), 20.0, case % 2 == 0, [100, 5, 3]);
            grid.trace_updates(&other, &mut scratch, &mut whole)
                .unwrap();
            let a = grid.trace_updates(&scan, &mut scratch, &mut whole).unwrap();
            let b = grid
                .trace_updates_part(&scan, 0..scan.points.len(), &mut scratch, &mut piece)
                .unwrap();
            assert_eq!(a, b, "case {case}");
            assert!(
                whole.heights && piece.heights && !whole.continues,
                "case {case}"
            );
            assert_eq!(whole.tiles, piece.tiles, "case {case}");
            assert_eq!(whole.updates, piece.updates, "case {case}");
            assert_eq!(whole.bin_marks, piece.bin_marks, "case {case}");
            assert_eq!(whole.stats, piece.stats, "case {case}");
            assert!(
                scratch.hmask.iter().all(|&m| m == 0),
                "case {case}: mask left dirty"
            );
        }
    }

    #[test]
    fn vectorised_ray_bins_equal_the_per_step_bin() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
        let special = [
            0.0,
            -0.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
            1e-30,
            0.64,
            3.04,
            1.76,
        ];
        let mut out = Vec::new();
        for case in 0..4_000 {
            let bins = [2, 5, 8, 16][case % 4];
            let layer = HeightLayer {
                bins,
                model: BinLogOdds::new(&crate::map::LogOddsParams::ese650(), 0.7),
                z_min_m: [0.64, -1.0, 0.0][case % 3],
                bins_per_m: [bins as f32 / 2.4, 1e-3, 1e6][(case / 3) % 3],
                dir: TileDir::default(),
            };
            let pick = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus, scale: f32| {
                if rng.random_range(0..6) == 0 {
                    special[rng.random_range(0..special.len())]
                } else {
                    rng.random_range(-scale..scale)
                }
            };
            let z0 = pick(&mut rng, 5.0);
            let dz = pick(&mut rng, 0.1);
            let n = rng.random_range(0..40);
            out.clear();
            out.resize(n, 0);
            layer.fill_bits(z0, dz, &mut out);
            for (s, &b) in out.iter().enumerate() {
                assert_eq!(
                    b,
                    layer.bit(z0 + s as i32 as f32 * dz),
                    "{z0} {dz} step {s}"
                );
            }
        }
    }

    #[test]
    fn optimised_insertion_equals_the_plain_rule() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
        for case in 0..40 {
            let res = [0.05, 0.1, 0.37, 1.0][case % 4];
            let opts = MapOptions {
                resolution_m: res,
                free_margin_m: [0.0, 0.0, 0.2, 1.0][(case / 4) % 4],
                ..MapOptions::default()
            };
            let mut fast = OccupancyGrid::new(&opts).unwrap();
            let mut slow = OccupancyGrid::new(&opts).unwrap();
            let mut scratch = InsertScratch::new();
            let mut slow_bins = BTreeMap::new();
            for _ in 0..4 {
                let (sx, sy) = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
                let range_max = rng.random_range(0.5..40.0);
                // Cases 16-31 carry heights (a tilted scanner): the height-bin insertion.
                let heights = (case / 16) % 2 == 1;
                let scan = random_scan(&mut rng, (sx, sy), range_max, heights, [200, 5, 3]);
                let a = fast.insert_scan(&scan, &mut scratch).unwrap();
                let b = if scan.sensor_z_m.is_some() {
                    insert_reference_heights(&mut slow, &mut slow_bins, &scan)
                } else {
                    insert_reference(&mut slow, &scan)
                };
                assert_eq!(a, b, "case {case}");
            }
            for (c, bins) in &slow_bins {
                assert_eq!(fast.height_bins(*c), Some(&bins[..]), "case {case}");
            }
            assert_same_cells(&fast, &slow, case);
            assert!(
                scratch.mask.iter().all(|&m| m == MARK_NONE),
                "mask left dirty"
            );
        }
    }

    /// Same observed bounds and the same cells in them.
    fn assert_same_cells(fast: &OccupancyGrid, slow: &OccupancyGrid, case: usize) {
        let (ra, rb) = (fast.observed_bounds(), slow.observed_bounds());
        assert_eq!(ra, rb, "case {case}");
        if let Some(r) = ra {
            let (mut va, mut vb) = (Vec::new(), Vec::new());
            fast.copy_rect_fixed(&r, &mut va);
            slow.copy_rect_fixed(&r, &mut vb);
            assert!(va == vb, "case {case}: cells differ");
        }
    }

    #[test]
    fn consecutive_rays_into_one_cell_insert_as_the_plain_rule() {
        // Runs of rays ending within a cell of each other (a densified wall), some partial,
        // some without a return, on the planar path.
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(12);
        let mut same_cell = false;
        for case in 0..24 {
            let opts = MapOptions {
                resolution_m: [0.1, 0.37][case % 2],
                free_margin_m: [0.0, 0.2, 1.0][(case / 2) % 3],
                ..MapOptions::default()
            };
            let mut fast = OccupancyGrid::new(&opts).unwrap();
            let mut slow = OccupancyGrid::new(&opts).unwrap();
            let mut scratch = InsertScratch::new();
            for _ in 0..3 {
                let (sx, sy) = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
                let mut scan = random_scan(&mut rng, (sx, sy), 20.0, false, [60, 6, 4]);
                let mut points = Vec::new();
                for p in &scan.points {
                    for _ in 0..rng.random_range(1..5) {
                        let mut q = *p;
                        q.x_m += rng.random_range(-0.03..0.03);
                        q.y_m += rng.random_range(-0.03..0.03);
                        points.push(q);
                    }
                }
                let lim = fast.limits();
                same_cell |= points.windows(2).any(|w| {
                    w[0].hit == w[1].hit
                        && lim.cell_of(w[0].x_m, w[0].y_m) == lim.cell_of(w[1].x_m, w[1].y_m)
                });
                scan.points = points;
                let a = fast.insert_scan(&scan, &mut scratch).unwrap();
                let b = insert_reference(&mut slow, &scan);
                assert_eq!(a, b, "case {case}");
            }
            assert_same_cells(&fast, &slow, case);
        }
        assert!(same_cell);
    }

    /// A random world scan around `(sx, sy)`: below `points` points, one in `no_return`
    /// without a return, one in `partial` clearing only part of its ray; heights on when
    /// `heights` (a sensor at 1.76 m).
    fn random_scan(
        rng: &mut rand_xoshiro::Xoshiro256PlusPlus,
        (sx, sy): (f64, f64),
        range_max: f64,
        heights: bool,
        [points, no_return, partial]: [i32; 3],
    ) -> PlanarScan {
        let points = (0..rng.random_range(0..points))
            .map(|_| {
                let a = rng.random_range(-3.2..3.2f64);
                let r = rng.random_range(0.0..range_max);
                ScanPoint {
                    x_m: sx + r * a.cos(),
                    y_m: sy + r * a.sin(),
                    hit: rng.random_range(0..no_return) > 0,
                    free_to: if rng.random_range(0..partial) == 0 {
                        rng.random_range(-0.1..1.0)
                    } else {
                        1.0
                    },
                    z_m: rng.random_range(-1.0..5.0),
                }
            })
            .collect();
        PlanarScan {
            sensor_x_m: sx,
            sensor_y_m: sy,
            sensor_z_m: heights.then_some(1.76),
            points,
        }
    }

    /// Same directory (placement, allocated tiles), same cells, same bins.
    fn assert_same_grid(a: &OccupancyGrid, b: &OccupancyGrid, label: &str) {
        fn same_dir<T>(a: &TileDir<T>, b: &TileDir<T>, eq: impl Fn(&T, &T) -> bool) -> bool {
            (a.ti0, a.tj0, a.w, a.h) == (b.ti0, b.tj0, b.w, b.h)
                && a.tiles.len() == b.tiles.len()
                && a.tiles.iter().zip(&b.tiles).all(|(x, y)| match (x, y) {
                    (Some(x), Some(y)) => eq(x, y),
                    (None, None) => true,
                    _ => false,
                })
        }
        assert!(
            same_dir(&a.dir, &b.dir, |x, y| x.cells[..] == y.cells[..]),
            "{label}: cells or tiles differ"
        );
        match (&a.height, &b.height) {
            (Some(x), Some(y)) => assert!(
                same_dir(&x.dir, &y.dir, |x, y| x.bins == y.bins),
                "{label}: bins differ"
            ),
            (None, None) => {}
            _ => panic!("{label}: one grid has bins"),
        }
    }

    #[test]
    fn scans_split_into_pieces_apply_as_sequential_insertion() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(12);
        for case in 0..24 {
            let mut opts = MapOptions {
                resolution_m: [0.1, 0.37][case % 2],
                free_margin_m: [0.0, 0.3][(case / 2) % 2],
                ..MapOptions::default()
            };
            opts.height.enabled = case % 3 != 0;
            // Half the cases clamp hard: two updates reach a bound, so the order of a
            // cell's updates decides its value.
            if (case / 4) % 2 == 1 {
                opts.log_odds.hit = 20.0;
                opts.log_odds.miss = -20.0;
                opts.log_odds.clamp_min = -40.0;
                opts.log_odds.clamp_max = 40.0;
            }
            let scans: Vec<PlanarScan> = (0..30)
                .map(|_| {
                    let centre = (rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
                    let heights = rng.random_range(0..3) > 0;
                    let range_max = rng.random_range(0.5..12.0);
                    random_scan(&mut rng, centre, range_max, heights, [150, 3, 4])
                })
                .collect();
            let mut seq = OccupancyGrid::new(&opts).unwrap();
            let mut scratch = InsertScratch::new();
            for scan in &scans {
                seq.insert_scan(scan, &mut scratch).unwrap();
            }
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut par = OccupancyGrid::new(&opts).unwrap();
                let mut start = 0;
                while start < scans.len() {
                    let end = (start + rng.random_range(1..7)).min(scans.len());
                    // Each scan cut at up to 3 random rays (empty pieces included).
                    let mut pieces = Vec::new();
                    for scan in &scans[start..end] {
                        let n = scan.points.len();
                        let mut cuts: Vec<usize> = (0..rng.random_range(0..4))
                            .map(|_| rng.random_range(0..=n))
                            .collect();
                        cuts.sort_unstable();
                        let mut from = 0;
                        for cut in cuts.into_iter().chain([n]) {
                            let mut out = ScanUpdates::new();
                            par.trace_updates_part(scan, from..cut, &mut scratch, &mut out)
                                .unwrap();
                            pieces.push(out);
                            from = cut;
                        }
                    }
                    let refs: Vec<&ScanUpdates> = pieces.iter().collect();
                    pool.install(|| par.apply_updates(&refs));
                    start = end;
                }
                assert_same_grid(&seq, &par, &format!("case {case}, {threads} threads"));
                assert!(scratch.mask.iter().all(|&m| m == MARK_NONE));
                assert!(scratch.hmask.iter().all(|&m| m == 0));
            }
        }
    }
}
