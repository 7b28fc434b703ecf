//! Scan insertion: a scan traced and applied at once, or traced into [`ScanUpdates`] for
//! [`OccupancyGrid::apply_updates`].

use super::*;

impl OccupancyGrid {
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
}
