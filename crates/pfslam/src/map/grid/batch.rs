//! Several planar scans inserted at once, exactly as one after the other
//! ([`OccupancyGrid::insert_planar_batch`]): the SLAM filter's map takes the ~5 scans between
//! two updates this way.
//!
//! Inserting scan by scan lists every touched cell of every scan, sorts the list by tile and
//! applies it: on the car ~21,000 cells per scan, although consecutive scans (9 cm apart at
//! 100 Hz) touch nearly the same cells. Here the scans of a batch are traced into one mask of
//! 16-bit marks, two bits per scan (touched, occupied), so each cell is visited once per batch
//! and applied scan by scan in order, the same clamped integer additions as scan by scan. The
//! mask has a flag per 4 x 4 block, so applying reads only the blocks that were marked.
//! Threads trace contiguous pieces of the batch's rays into their own masks; the masks are
//! ORed per cell when applied (a scan cut in two still gets one update per cell, occupied
//! winning), tile by tile in parallel. The result does not depend on the thread count.

use super::*;
use rayon::prelude::*;

/// Scans one batch may hold: two bits of a `u16` mark per scan.
pub const BATCH_SCANS: usize = 8;

/// Per-thread scratch of [`OccupancyGrid::insert_planar_batch`]: a mask of 16-bit marks in the
/// layout of [`InsertScratch`]'s (tiles of 16 x 16 blocks of 4 x 4 cells), a flag per block,
/// and the tracing buffers. Reuse it (megabytes); insertion leaves it zeroed.
#[derive(Debug, Default, Clone)]
pub struct BatchScratch {
    mask: Vec<u16>,
    /// Per 4 x 4 block of `mask` (index >> 4): nonzero when a cell of it is marked.
    flags: Vec<u8>,
    /// Mask side in tiles (the same in every scratch of one insertion).
    blocks: usize,
    xoff: Vec<u32>,
    yoff: Vec<u32>,
    walk: RayCells,
}

impl BatchScratch {
    /// Empty scratch; it grows to the batches seen.
    pub fn new() -> Self {
        BatchScratch::default()
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        2 * self.mask.capacity()
            + self.flags.capacity()
            + 4 * (self.xoff.capacity() + self.yoff.capacity())
            + self.walk.bytes()
    }

    /// Lays the mask out `blocks` tiles a side (zeroed; a no-op when it already is).
    fn ensure_blocks(&mut self, blocks: usize) {
        if self.blocks != blocks {
            let side = (blocks * TILE_SIZE) as u32;
            self.mask = vec![0; blocks * blocks * TILE_CELLS];
            self.flags = vec![0; blocks * blocks * TILE_CELLS / 16];
            self.xoff = (0..side).map(mask_x).collect();
            self.yoff = (0..side).map(|r| mask_y(r, blocks)).collect();
            self.blocks = blocks;
        }
    }
}

/// One scan's marks in a batch mask: `free` or `occupied` ORed into the cell, its block
/// flagged.
struct BitMarks<'a> {
    mask: &'a mut [u16],
    flags: &'a mut [u8],
    free: u16,
    occupied: u16,
}

impl Marks for BitMarks<'_> {
    #[inline(always)]
    fn reserve(&mut self, _n: usize) {}

    #[inline(always)]
    fn mark(&mut self, k: usize, occupied: bool) {
        self.mask[k] |= if occupied { self.occupied } else { self.free };
        self.flags[k >> 4] = 1;
    }

    /// A block's flag is stored when the line enters the block, not at every cell: about
    /// one cell in three stores it, and the flag stores were ~40 % of this loop's cost on the
    /// car (`examples/filter_map`: ~370 -> ~310 us per scan on one thread,
    /// docs/decisions/0014-insertion-mask-and-batched-insertion.md);
    /// the branch costs less than the stores it saves.
    #[inline(always)]
    fn mark_free(&mut self, cells: &[u32]) {
        let mut last = usize::MAX;
        for &k in cells {
            let k = k as usize;
            self.mask[k] |= self.free;
            if k >> 4 != last {
                last = k >> 4;
                self.flags[last] = 1;
            }
        }
    }
}

/// Cuts the rays of `scans`, in order, into `parts` contiguous runs of about the same work;
/// returns each run as (scan, ray range) pieces, a scan cut between two runs giving one piece
/// to each; empty runs are dropped. The scans of one batch are alike (consecutive sweeps of
/// the same place), so each counts as one unit of work, and within a scan that is cut the
/// rays are weighed by the cells they walk (Chebyshev length in cells, plus one for the end
/// cell: left and right halves of a sweep can differ a lot); a scan is cut only where [`OccupancyGrid::trace_cuts`] allows, so the pieces
/// insert as the whole scan. `cum` is a reusable buffer.
pub fn split_rays(
    grid: &OccupancyGrid,
    scans: &[PlanarScan],
    parts: usize,
    cum: &mut Vec<(usize, u64)>,
) -> Vec<Vec<(usize, std::ops::Range<usize>)>> {
    let parts = parts.max(1);
    let n = scans.len();
    // Where each run ends: (scan, ray) with the ray exclusive; the last run ends after all.
    let mut cuts = Vec::with_capacity(parts);
    for t in 1..parts {
        // Cut at n * t / parts scans: scan `k`, the fraction `num / parts` of its work.
        let (k, num) = ((n * t) / parts, (n * t) % parts);
        if k >= n {
            cuts.push((n, 0));
            continue;
        }
        let ray = if num == 0 {
            0
        } else {
            // The last place the scan may be cut with at most its share of the work before.
            grid.trace_cuts(&scans[k], cum);
            let total = cum.last().map_or(0, |c| c.1);
            let share = total * num as u64 / parts as u64;
            let at = cum.partition_point(|&(_, w)| w <= share);
            cum.get(at.saturating_sub(1)).map_or(0, |c| c.0)
        };
        cuts.push((k, ray));
    }
    cuts.push((n, 0));
    let mut runs = Vec::with_capacity(parts);
    let mut at = (0usize, 0usize);
    for &cut in &cuts {
        let mut run = Vec::new();
        while at < cut {
            let (k, ray) = at;
            let end = if k == cut.0 {
                cut.1
            } else {
                scans[k].points.len()
            };
            if end > ray {
                run.push((k, ray..end));
            }
            at = if k == cut.0 { cut } else { (k + 1, 0) };
        }
        if !run.is_empty() {
            runs.push(run);
        }
    }
    runs
}

/// One tile's part of a scratch's mask and block flags.
type MaskPart<'a> = (&'a mut [u16], &'a mut [u8]);

/// A tile of the grid being updated from the batch masks: the tile (taken out of the
/// directory), its part of every scratch's mask and block flags, and the changes it logged.
struct TileJob<'a> {
    pub(super) slot: usize,
    origin: Cell,
    pub(super) tile: Option<Arc<Tile>>,
    parts: Vec<MaskPart<'a>>,
    changes: Vec<CellChange>,
}

/// A cell whose log-odds changed between observed and never written (0), or across a
/// threshold, in an insertion: what a structure derived from the grid's walls and observed
/// cells (the scan matcher's likelihood field) must update.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CellChange {
    /// The cell.
    pub cell: Cell,
    /// Fixed-point log-odds before.
    pub old: i16,
    /// Fixed-point log-odds after.
    pub new: i16,
}

/// The changes [`OccupancyGrid::insert_planar_batch`] logs: cells that became observed (or
/// returned to 0) or crossed `threshold` (a wall: observed and at least `threshold`).
#[derive(Debug, Clone, Default)]
pub struct ChangeLog {
    /// The wall threshold (fixed-point log-odds).
    pub threshold: i16,
    /// The changes, in no particular order; a cell may appear once per insertion.
    pub changes: Vec<CellChange>,
}

impl ChangeLog {
    /// Whether the step `old` -> `new` changes a cell's observed or wall status.
    #[inline(always)]
    pub fn matters(&self, old: i16, new: i16) -> bool {
        let wall = |v: i16| v != 0 && v >= self.threshold;
        (old != 0) != (new != 0) || wall(old) != wall(new)
    }
}

impl OccupancyGrid {
    /// Whether `world_scan` would be inserted with height bins (a scan with heights on a
    /// grid with bins); [`Self::insert_planar_batch`] takes only the others.
    pub fn uses_heights(&self, world_scan: &PlanarScan) -> bool {
        world_scan.sensor_z_m.is_some() && self.height.is_some()
    }

    /// Inserts `scans` (world frame, in order, none with [`Self::uses_heights`]) on
    /// `threads` threads: the grid ends exactly as after [`Self::insert_scan`] of each in
    /// turn, whatever the thread count (see the module docs). At most [`BATCH_SCANS`] scans
    /// are traced into one mask; more are inserted batch after batch. `scratches` grows to
    /// one per thread, `work` is a reusable buffer. With `log`, every cell whose step from
    /// before to after a batch [`ChangeLog::matters`] is appended to it. Errors (grid unchanged by the failing
    /// batch) as [`Self::insert_scan`]: a cell beyond [`MAX_CELL_INDEX`] or a ray longer than
    /// [`MAX_RAY_CELLS`]; a scan with heights on a grid with bins is an options error.
    pub fn insert_planar_batch(
        &mut self,
        scans: &[PlanarScan],
        threads: usize,
        scratches: &mut Vec<BatchScratch>,
        work: &mut Vec<(usize, u64)>,
        mut log: Option<&mut ChangeLog>,
    ) -> Result<(), MapError> {
        if scans.iter().any(|s| self.uses_heights(s)) {
            return Err(MapError::Options(
                "a batch of planar scans holds a scan with heights on a grid with bins".into(),
            ));
        }
        for batch in scans.chunks(BATCH_SCANS) {
            let pieces = split_rays(self, batch, threads, work);
            if scratches.len() < pieces.len().max(1) {
                scratches.resize_with(pieces.len().max(1), BatchScratch::new);
            }
            self.insert_batch(batch, &pieces, scratches, log.as_deref_mut())?;
        }
        Ok(())
    }

    /// One batch of at most [`BATCH_SCANS`] scans, traced as `pieces` (one per scratch).
    fn insert_batch(
        &mut self,
        scans: &[PlanarScan],
        pieces: &[Vec<(usize, std::ops::Range<usize>)>],
        scratches: &mut [BatchScratch],
        mut log: Option<&mut ChangeLog>,
    ) -> Result<(), MapError> {
        let Some((o, half)) = self.batch_extent(scans)? else {
            return Ok(());
        };
        // 2 * half + 1 cells starting anywhere in a tile span at most this many tiles; the
        // mask only grows (all scratches alike), so it is allocated a few times per run.
        let need = ((2 * half + 1 + TILE_MASK) / TILE_SIZE as i32 + 1) as usize;
        let blocks = scratches.iter().map(|s| s.blocks).fold(need, usize::max);
        for s in scratches.iter_mut() {
            s.ensure_blocks(blocks);
        }
        let t0 = ((o.i - half) >> TILE_SHIFT, (o.j - half) >> TILE_SHIFT);
        self.trace_batch(scans, pieces, scratches, t0);
        let used = &mut scratches[..pieces.len().max(1)];
        let parallel = used.len() > 1;
        let mut jobs = self.tile_jobs(used, blocks, t0);
        let f = self.fixed;
        let watch = log.as_deref().map(|l| ChangeLog {
            threshold: l.threshold,
            changes: Vec::new(),
        });
        let apply = |job: &mut TileJob<'_>| apply_tile_job(job, &f, watch.as_ref());
        if parallel {
            jobs.par_iter_mut().for_each(apply);
        } else {
            jobs.iter_mut().for_each(apply);
        }
        for job in jobs {
            self.dir.tiles[job.slot] = job.tile;
            if let Some(log) = log.as_deref_mut() {
                log.changes.extend_from_slice(&job.changes);
            }
        }
        Ok(())
    }

    /// Each scan of the batch checked as `insert_scan` checks it: the first scan's sensor
    /// cell, around which the mask is placed, and the half-width (cells) that holds every
    /// ray of the batch; `None` for an empty batch.
    fn batch_extent(&self, scans: &[PlanarScan]) -> Result<Option<(Cell, i32)>, MapError> {
        let Some(first) = scans.first() else {
            return Ok(None);
        };
        let o = self.cell_of(first.sensor_x_m, first.sensor_y_m);
        let mut half = 0i32;
        for scan in scans {
            let origin = self.cell_of(scan.sensor_x_m, scan.sensor_y_m);
            Self::check_cell(origin)?;
            half = half.max((origin.i - o.i).abs()).max((origin.j - o.j).abs());
            let mut longest = 0i32;
            for p in &scan.points {
                let c = self.cell_of(p.x_m, p.y_m);
                Self::check_cell(c)?;
                longest = longest.max((c.i - origin.i).abs().max((c.j - origin.j).abs()));
                half = half.max((c.i - o.i).abs()).max((c.j - o.j).abs());
            }
            if longest > MAX_RAY_CELLS {
                return Err(MapError::RayTooLong {
                    cells: longest,
                    max: MAX_RAY_CELLS,
                });
            }
        }
        Ok(Some((o, half)))
    }

    /// Traces the batch: each scratch its pieces, scan `s` of the batch into bits 2s
    /// (touched) and 2s + 1 (occupied) of the mask whose first tile is `t0`.
    fn trace_batch(
        &self,
        scans: &[PlanarScan],
        pieces: &[Vec<(usize, std::ops::Range<usize>)>],
        scratches: &mut [BatchScratch],
        (t0i, t0j): (i32, i32),
    ) {
        let (mi0, mj0) = (t0i << TILE_SHIFT, t0j << TILE_SHIFT);
        let trace = |(scratch, run): (&mut BatchScratch, &Vec<(usize, std::ops::Range<usize>)>)| {
            let BatchScratch {
                mask,
                flags,
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
            for (s, rays) in run {
                let scan = &scans[*s];
                let origin = self.cell_of(scan.sensor_x_m, scan.sensor_y_m);
                let end = rays.end.min(scan.points.len());
                let points = &scan.points[rays.start.min(end)..end];
                let mut marks = BitMarks {
                    mask,
                    flags,
                    free: 1 << (2 * s),
                    occupied: 3 << (2 * s),
                };
                self.trace_planar_marks(scan, points, origin, &layout, walk, &mut marks);
            }
        };
        if pieces.len() > 1 {
            scratches
                .par_iter_mut()
                .zip(pieces.par_iter())
                .for_each(trace);
        } else {
            scratches.iter_mut().zip(pieces.iter()).for_each(trace);
        }
    }

    /// The tiles with a marked block in any of the `used` scratches (masks `blocks` tiles
    /// a side from tile `t0`), created in mask order and taken out of the directory, each
    /// with its part of every scratch.
    fn tile_jobs<'m>(
        &mut self,
        used: &'m mut [BatchScratch],
        blocks: usize,
        (t0i, t0j): (i32, i32),
    ) -> Vec<TileJob<'m>> {
        let tiles = blocks * blocks;
        // An OR over the tile's flag bytes, which compiles to whole-vector ORs (the u64
        // assembled from single bytes it replaced did not, and this serial scan of every
        // scratch's tiles was ~2 % of a default-drive run's samples).
        let marked = |flags: &[u8], t: usize| {
            flags[t * (TILE_CELLS / 16)..(t + 1) * (TILE_CELLS / 16)]
                .iter()
                .fold(0u8, |acc, &b| acc | b)
                != 0
        };
        let touched: Vec<usize> = (0..tiles)
            .filter(|&t| used.iter().any(|s| marked(&s.flags, t)))
            .collect();
        let mut views: Vec<Vec<Option<MaskPart<'m>>>> = used
            .iter_mut()
            .map(|s| {
                s.mask
                    .chunks_mut(TILE_CELLS)
                    .zip(s.flags.chunks_mut(TILE_CELLS / 16))
                    .map(Some)
                    .collect()
            })
            .collect();
        let tile_of = |t: usize| (t0i + (t % blocks) as i32, t0j + (t / blocks) as i32);
        for &t in &touched {
            let (ti, tj) = tile_of(t);
            self.dir.get_mut(ti, tj, Tile::unknown);
        }
        // Slots once every tile exists (creating one may grow the directory).
        let mut jobs: Vec<TileJob<'m>> = Vec::with_capacity(touched.len());
        for &t in &touched {
            let (ti, tj) = tile_of(t);
            let Some(slot) = self.dir.slot(ti, tj) else {
                continue;
            };
            jobs.push(TileJob {
                slot,
                origin: Cell::new(ti << TILE_SHIFT, tj << TILE_SHIFT),
                tile: None,
                parts: views.iter_mut().filter_map(|v| v[t].take()).collect(),
                changes: Vec::new(),
            });
        }
        for job in &mut jobs {
            job.tile = self.dir.tiles[job.slot].take();
        }
        jobs
    }
}

/// Applies a tile's marks block by block (all scratches ORed, the masks and flags left
/// zeroed) with the fixed-point update `f`; with `watch`, logs the cells whose step
/// [`ChangeLog::matters`].
fn apply_tile_job(job: &mut TileJob<'_>, f: &FixedLogOdds, watch: Option<&ChangeLog>) {
    let Some(tile) = job.tile.as_mut().map(Arc::make_mut) else {
        return;
    };
    for b in 0..TILE_CELLS / 16 {
        if job.parts.iter().all(|(_, flags)| flags[b] == 0) {
            continue;
        }
        // The block's marks (all scratches ORed, the masks left zeroed) and its cells: four
        // runs of four in the tile's rows.
        let mut m = [0u16; 16];
        for (mask, _) in job.parts.iter_mut() {
            for (x, k) in m.iter_mut().zip(&mut mask[b * 16..b * 16 + 16]) {
                *x |= std::mem::take(k);
            }
        }
        let base = local_of(b * 16);
        let mut cells = [0i16; 16];
        for r in 0..4 {
            let row = base + r * TILE_SIZE;
            cells[4 * r..4 * r + 4].copy_from_slice(&tile.cells[row..row + 4]);
        }
        let old = cells;
        apply_block_marks(&mut cells, &m, f);
        for r in 0..4 {
            let row = base + r * TILE_SIZE;
            tile.cells[row..row + 4].copy_from_slice(&cells[4 * r..4 * r + 4]);
        }
        if let Some(w) = watch
            && old != cells
        {
            log_block_changes(w, job.origin, &mut job.changes, base, (&old, &cells));
        }
        for (_, flags) in job.parts.iter_mut() {
            flags[b] = 0;
        }
    }
}

/// Appends to `changes` the cells of the block at `base` of the tile at `origin` whose step
/// from `old` to `new` [`ChangeLog::matters`] to `watch`.
fn log_block_changes(
    watch: &ChangeLog,
    origin: Cell,
    changes: &mut Vec<CellChange>,
    base: usize,
    (old, new): (&[i16; 16], &[i16; 16]),
) {
    for l in 0..16 {
        if watch.matters(old[l], new[l]) {
            let local = base + (l >> 2) * TILE_SIZE + (l & 3);
            changes.push(CellChange {
                cell: Cell::new(
                    origin.i + (local & (TILE_SIZE - 1)) as i32,
                    origin.j + (local >> TILE_SHIFT) as i32,
                ),
                old: old[l],
                new: new[l],
            });
        }
    }
}

/// [`apply_scan_marks`] of 16 cells at once, lane-wise so it compiles to vector code: scan
/// by scan, each lane the scan touched adds `hit` or `miss` and is clamped (the others keep
/// their value, selected by masks, not branches). The saturating i16 addition clamps as the
/// i32 one would (the bounds are i16), so the bits are those of the per-cell loop; it
/// replaced that loop's bit scan per cell (the apply phase was ~10 % of a default-drive
/// run's samples).
#[inline(always)]
fn apply_block_marks(cells: &mut [i16; 16], m: &[u16; 16], f: &FixedLogOdds) {
    // Scans up to the last one that touched any lane (bit 2s), no further.
    let touched = m.iter().fold(0u16, |a, &x| a | x) & 0x5555;
    let scans = (u16::BITS - touched.leading_zeros()).div_ceil(2);
    for s in 0..scans {
        for (v, &x) in cells.iter_mut().zip(m) {
            let touched = 0i16.wrapping_sub((x >> (2 * s) & 1) as i16);
            let occupied = 0i16.wrapping_sub((x >> (2 * s + 1) & 1) as i16);
            let delta = (occupied & f.hit) | (!occupied & f.miss);
            let stepped = v.saturating_add(delta).clamp(f.min, f.max);
            *v = (touched & stepped) | (!touched & *v);
        }
    }
}

/// A cell's updates from the batch marks `m`, scan by scan in order (bit 2s: scan s touched
/// it, bit 2s + 1: occupied): the additions of inserting the scans one by one. The reference
/// of [`apply_block_marks`].
#[cfg(test)]
fn apply_scan_marks(cell: &mut i16, m: u16, f: &FixedLogOdds) {
    let mut scans = m & 0x5555;
    let mut v = *cell;
    while scans != 0 {
        let bit = scans.trailing_zeros();
        let delta = if m >> (bit + 1) & 1 != 0 {
            f.hit
        } else {
            f.miss
        };
        v = f.apply(v, delta);
        scans &= scans - 1;
    }
    *cell = v;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::MapOptions;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A car-like scan from `(sx, sy)`: beams every `step_deg` over a half turn hitting
    /// walls at random distances (runs of beams on one wall), returns cleared part of the way
    /// now and then, joining points every <= 0.1 m between neighbours closer than 1 m.
    fn wall_scan(rng: &mut Xoshiro256PlusPlus, sx: f64, sy: f64) -> PlanarScan {
        let mut points: Vec<ScanPoint> = Vec::new();
        let step = rng.random_range(0.3..1.0f64).to_radians();
        let a0 = rng.random_range(-3.2..3.2f64);
        let mut r = rng.random_range(2.0..40.0f64);
        let mut dr = 0.0;
        for k in 0..rng.random_range(0..300) {
            if rng.random_range(0..25) == 0 {
                r = rng.random_range(2.0..60.0);
                dr = rng.random_range(-0.3..0.3);
            }
            r = (r + dr).clamp(1.0, 70.0);
            let a = a0 + k as f64 * step;
            // Range noise: a wall's end cells zigzag.
            let rn = r + rng.random_range(-0.05..0.05);
            let (x, y) = (sx + rn * a.cos(), sy + rn * a.sin());
            let free_to = if rng.random_range(0..3) == 0 {
                rng.random_range(0.2..1.0)
            } else {
                1.0
            };
            let hit = rng.random_range(0..50) > 0;
            if let Some(prev) = points.last().copied()
                && prev.hit
                && hit
            {
                let d = (x - prev.x_m).hypot(y - prev.y_m);
                if d <= 1.0 && d > 0.1 {
                    let n = (d / 0.1).ceil() as usize;
                    for j in 1..n {
                        let t = j as f64 / n as f64;
                        points.push(ScanPoint {
                            x_m: prev.x_m + t * (x - prev.x_m),
                            y_m: prev.y_m + t * (y - prev.y_m),
                            hit: true,
                            free_to: 1.0,
                            z_m: 0.0,
                        });
                    }
                }
            }
            points.push(ScanPoint {
                x_m: x,
                y_m: y,
                hit,
                free_to,
                z_m: 0.0,
            });
        }
        PlanarScan {
            sensor_x_m: sx,
            sensor_y_m: sy,
            sensor_z_m: None,
            points,
        }
    }

    #[test]
    fn block_marks_apply_as_the_per_cell_loop() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        for case in 0..2000 {
            let f = if case % 2 == 0 {
                FixedLogOdds {
                    hit: rng.random_range(1..3000),
                    miss: rng.random_range(-3000..0),
                    min: rng.random_range(-32768..-1),
                    max: rng.random_range(1..32767),
                    occupied: 0,
                    free: 0,
                }
            } else {
                // Steps near the i16 range: the saturating addition must clamp as i32.
                FixedLogOdds {
                    hit: rng.random_range(20000..32767),
                    miss: rng.random_range(-32768..-20000),
                    min: -32768,
                    max: 32767,
                    occupied: 0,
                    free: 0,
                }
            };
            let mut cells = [0i16; 16];
            let mut m = [0u16; 16];
            let scans = rng.random_range(0..=BATCH_SCANS as u32);
            for (v, x) in cells.iter_mut().zip(m.iter_mut()) {
                *v = [0, f.min, f.max, rng.random_range(f.min..=f.max)][rng.random_range(0..4)];
                for s in 0..scans {
                    // Untouched, free or occupied (the occupied bit only with the touched one).
                    *x |= [0, 1, 3][rng.random_range(0..3)] << (2 * s);
                }
            }
            let mut want = cells;
            for (v, &x) in want.iter_mut().zip(&m) {
                apply_scan_marks(v, x, &f);
            }
            apply_block_marks(&mut cells, &m, &f);
            assert_eq!(cells, want, "case {case}: {m:?}");
        }
    }

    #[test]
    fn batches_insert_as_scan_by_scan_for_any_thread_count() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        for case in 0..16 {
            let mut opts = MapOptions {
                resolution_m: [0.1, 0.1, 0.25, 0.25][case % 4],
                free_margin_m: if case % 8 >= 4 { 0.2 } else { 0.0 },
                ..MapOptions::default()
            };
            opts.height.enabled = false;
            if case >= 8 {
                // Clamping-heavy: a cell reaches a bound in two updates, so the order of
                // its updates decides its value.
                opts.log_odds.hit = 20.0;
                opts.log_odds.miss = -20.0;
                opts.log_odds.clamp_min = -40.0;
                opts.log_odds.clamp_max = 40.0;
            }
            let flushes: Vec<Vec<PlanarScan>> = (0..6)
                .map(|_| {
                    let (x, y) = (rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
                    (0..rng.random_range(1..12))
                        .map(|k| wall_scan(&mut rng, x + 0.09 * k as f64, y))
                        .collect()
                })
                .collect();
            let mut want = OccupancyGrid::new(&opts).unwrap();
            let mut scratch = InsertScratch::new();
            for scan in flushes.iter().flatten() {
                want.insert_scan(scan, &mut scratch).unwrap();
            }
            let bounds = want.allocated_bounds().unwrap();
            let mut cells = Vec::new();
            want.copy_rect_fixed(&bounds, &mut cells);
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut got = OccupancyGrid::new(&opts).unwrap();
                let (mut batches, mut work) = (Vec::new(), Vec::new());
                for scans in &flushes {
                    pool.install(|| {
                        got.insert_planar_batch(scans, threads, &mut batches, &mut work, None)
                    })
                    .unwrap();
                }
                let label = format!("case {case}, {threads} threads");
                assert_eq!(got.tile_count(), want.tile_count(), "{label}");
                assert_eq!(got.allocated_bounds(), Some(bounds), "{label}");
                let mut g = Vec::new();
                got.copy_rect_fixed(&bounds, &mut g);
                let differ = g.iter().zip(&cells).filter(|(a, b)| a != b).count();
                assert_eq!(differ, 0, "{label}: cells differ");
                // The masks are left zeroed.
                for b in &batches {
                    assert!(b.mask.iter().all(|&m| m == 0) && b.flags.iter().all(|&f| f == 0));
                }
            }
        }
    }
}
