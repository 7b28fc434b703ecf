//! Applying a traced scan: the per-tile runs of marks merged into the log-odds and bins.

use super::*;
use crate::kernels::heights::BinUpdater;

/// Counts of what one insertion did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InsertStats {
    /// Rays traced.
    pub rays: usize,
    /// Cells given the occupied update.
    pub occupied_cells: usize,
    /// Cells given the free update.
    pub free_cells: usize,
}

impl InsertStats {
    #[inline(always)]
    pub(super) fn count(&mut self, occupied: bool) {
        self.occupied_cells += usize::from(occupied);
        self.free_cells += usize::from(!occupied);
    }
}

/// [`OccupancyGrid::trace_updates`]' second half for a whole scan traced with heights: the
/// touched cells' bin marks moved from the mask into `out`, grouped by tile (tiles in
/// first-touch order, cells in touch order within a tile: what
/// [`OccupancyGrid::trace_updates_part`] writes), the mask left zeroed. A counting sort over
/// the runs of one tile (touch order is ray order): the first pass lists the runs, the second
/// copies each run without a per-cell tile check.
pub(super) fn drain_heights(
    traced: &Traced,
    rays: usize,
    scratch: &mut InsertScratch,
    out: &mut ScanUpdates,
) -> InsertStats {
    let blocks = scratch.blocks;
    let InsertScratch {
        hmask,
        touched,
        block_count,
        block_order,
        runs,
        ..
    } = scratch;
    let touched = &touched[..traced.len];
    if block_count.len() < blocks * blocks {
        block_count.resize(blocks * blocks, 0);
    }
    // Slices, not the scratch's vectors: their pointers and lengths stay in registers.
    let (hmask, block_count) = (&mut hmask[..], &mut block_count[..]);
    block_order.clear();
    runs.clear();
    let mut start = 0;
    while start < touched.len() {
        let b = mask_tile(touched[start] as usize);
        let mut end = start + 1;
        while end < touched.len() && mask_tile(touched[end] as usize) == b {
            end += 1;
        }
        if block_count[b] == 0 {
            block_order.push(b as u32);
        }
        block_count[b] += (end - start) as u32;
        runs.push((b as u32, start as u32, end as u32));
        start = end;
    }
    // Each tile's first position in `out`; the tiles' ends.
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
    let n = touched.len();
    out.heights = true;
    // Zeroed, then every element overwritten: the runs partition `0..n` and each tile's runs
    // fill its range (its count from the first pass).
    out.updates.clear();
    out.bin_marks.clear();
    out.updates.resize(n, 0);
    out.bin_marks.resize(n, 0);
    let (updates, marks) = (&mut out.updates[..], &mut out.bin_marks[..]);
    let mut occupied = 0usize;
    for &(b, start, end) in runs.iter() {
        let pos = &mut block_count[b as usize];
        let run = &touched[start as usize..end as usize];
        let p0 = *pos as usize;
        for ((&k, u), m) in run
            .iter()
            .zip(&mut updates[p0..p0 + run.len()])
            .zip(&mut marks[p0..p0 + run.len()])
        {
            let k = k as usize;
            let v = std::mem::replace(&mut hmask[k], 0);
            occupied += usize::from(v >> 16 != 0);
            *u = local_of(k) as u16;
            *m = v;
        }
        *pos += run.len() as u32;
    }
    for &b in block_order.iter() {
        block_count[b as usize] = 0;
    }
    out.stats = InsertStats {
        rays,
        occupied_cells: occupied,
        free_cells: n - occupied,
    };
    out.stats
}

/// Where a traced scan's marks lie ([`OccupancyGrid::trace_scan`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Traced {
    /// Tile coordinates of the mask's first tile.
    pub(super) t0i: i32,
    pub(super) t0j: i32,
    /// Cells touched: the first `len` of `InsertScratch::touched`.
    pub(super) len: usize,
    /// The marks are height bins (`hmask`), not 2-D marks (`mask`).
    pub(super) heights: bool,
}

/// One scan's cell updates, grouped by tile ([`OccupancyGrid::trace_updates`]), to be
/// applied by [`OccupancyGrid::apply_updates`]. Reuse one per scan slot: it keeps its
/// allocations.
#[derive(Debug, Clone, Default)]
pub struct ScanUpdates {
    /// Per-bin marks (a scan with heights on a grid with bins), else 2-D marks.
    pub(super) heights: bool,
    /// Tiles in first-touch order: (tile column, tile row, end of its updates).
    pub(super) tiles: Vec<(i32, i32, u32)>,
    /// Per cell: its index within its tile (bits 0-11) and, for a 2-D mark, bit 15 set when
    /// occupied (2 bytes per update: the batch's lists are written and read once each).
    pub(super) updates: Vec<u16>,
    /// With `heights`, per cell: the bins passed free (low 16 bits) and hit (high 16 bits).
    pub(super) bin_marks: Vec<u32>,
    pub(super) stats: InsertStats,
    /// A piece of a scan after its first ray ([`OccupancyGrid::trace_updates_part`]): the
    /// same scan as the entry before it in [`OccupancyGrid::apply_updates`].
    pub(super) continues: bool,
}

/// Bit of a 2-D update in [`ScanUpdates`]: the cell is occupied.
pub(super) const UPDATE_OCCUPIED: u16 = 1 << 15;

impl ScanUpdates {
    /// Empty updates (nothing to apply).
    pub fn new() -> Self {
        ScanUpdates::default()
    }

    /// Forgets the updates, keeping the allocations.
    pub fn clear(&mut self) {
        self.tiles.clear();
        self.updates.clear();
        self.bin_marks.clear();
        self.stats = InsertStats::default();
        self.heights = false;
        self.continues = false;
    }

    /// What the insertion of these updates does (as [`OccupancyGrid::insert_scan`] reports).
    pub fn stats(&self) -> InsertStats {
        self.stats
    }

    /// Number of cell updates.
    pub fn len(&self) -> usize {
        self.updates.len()
    }

    /// True when there is nothing to apply.
    pub fn is_empty(&self) -> bool {
        self.updates.is_empty()
    }

    /// Bytes held by the buffers (their capacity).
    pub fn capacity_bytes(&self) -> usize {
        self.tiles.capacity() * std::mem::size_of::<(i32, i32, u32)>()
            + self.updates.capacity() * std::mem::size_of::<u16>()
            + self.bin_marks.capacity() * std::mem::size_of::<u32>()
    }
}

/// One tile's share of [`OccupancyGrid::apply_updates`]: the tile (and its bins) taken out of
/// the directory while a worker updates it.
pub(super) struct TileJob {
    pub(super) slot: usize,
    pub(super) hslot: Option<usize>,
    pub(super) tile: Option<Arc<Tile>>,
    pub(super) htile: Option<Arc<HeightTile>>,
    /// Its range of the sorted (slot, scan, group) list.
    pub(super) entries: std::ops::Range<usize>,
}

/// Per-thread buffers of [`OccupancyGrid::apply_updates`] merging a split scan's pieces in a
/// tile: marks ORed per cell (left zeroed) and the cells in first-seen order.
pub(super) struct MergeScratch {
    pub(super) acc: Box<[u32; TILE_CELLS]>,
    pub(super) order: Box<[u16; TILE_CELLS]>,
}

thread_local! {
    pub(super) static MERGE: std::cell::RefCell<MergeScratch> = std::cell::RefCell::new(MergeScratch {
        acc: Box::new([0; TILE_CELLS]),
        order: Box::new([0; TILE_CELLS]),
    });
}

/// One scan's updates of one tile ([`OccupancyGrid::apply_updates`]).
pub(super) struct TileRun<'a> {
    pub(super) tile: &'a mut Tile,
    pub(super) htile: Option<&'a mut HeightTile>,
    /// Cells whose 2-D value awaits the projection of their bins.
    pub(super) stale: &'a mut [bool; TILE_CELLS],
    /// The grid's bin model (when it has bins).
    pub(super) model: Option<BinLogOdds>,
    /// The scan's marks are height bins.
    pub(super) heights: bool,
    pub(super) f: &'a FixedLogOdds,
}

impl TileRun<'_> {
    /// The marks are height bins (the scan has heights and the tile has bins).
    pub(super) fn heights(&self) -> bool {
        self.heights && self.model.is_some() && self.htile.is_some()
    }

    /// [`Self::apply`] of one piece's bin marks (`updates[i]`'s cell gets `marks[i]`), with
    /// [`Self::heights`].
    #[inline(always)]
    pub(super) fn apply_bins(&mut self, updates: &[u16], marks: &[u32]) {
        if let (Some(ht), Some(model)) = (self.htile.as_deref_mut(), self.model) {
            BinUpdater::new(&model).run(&mut ht.bins, self.stale, updates, marks, &model);
        }
    }

    /// Applies (cell, mark) pairs, each cell once: bin marks when [`Self::heights`], else
    /// 1 = occupied, 0 = free.
    #[inline(always)]
    pub(super) fn apply(&mut self, marks: impl Iterator<Item = (usize, u32)>) {
        let heights = self.heights();
        match (self.htile.as_deref_mut(), self.model) {
            (Some(ht), Some(model)) if heights => {
                let vector = BinUpdater::new(&model);
                for (local, m) in marks {
                    vector.update(&mut ht.bins[local], m, &model);
                    self.stale[local] = true;
                }
            }
            (ht, _) => {
                for (local, occupied) in marks {
                    if self.stale[local]
                        && let (Some(ht), Some(model)) = (ht.as_deref(), self.model)
                    {
                        self.stale[local] = false;
                        self.tile.cells[local] =
                            project_column(&ht.bins[local], &model, self.f.occupied);
                    }
                    apply_mark(&mut self.tile.cells[local], occupied != 0, self.f);
                }
            }
        }
    }
}

/// One scan's update of a cell: the occupied update when `occupied`, else the free one.
#[inline(always)]
pub(super) fn apply_mark(cell: &mut i16, occupied: bool, f: &FixedLogOdds) {
    let delta = if occupied { f.hit } else { f.miss };
    *cell = f.apply(*cell, delta);
}

impl OccupancyGrid {
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
        self.create_update_tiles(scans);
        let entries = self.sorted_entries(scans);
        let mut jobs = self.update_jobs(scans, &entries);
        let plan = UpdatePlan {
            scans,
            entries: &entries,
            scan_of: &scan_numbers(scans),
            f: self.fixed,
            model: self.height.as_ref().map(|l| l.model),
        };
        use rayon::prelude::*;
        jobs.par_iter_mut().for_each(|job| plan.apply(job));
        for job in jobs {
            self.dir.tiles[job.slot] = job.tile;
            if let (Some(h), Some(l)) = (job.hslot, self.height.as_mut()) {
                l.dir.tiles[h] = job.htile;
            }
        }
    }

    /// Creates the tiles `scans` touch in the order sequential insertion would (the
    /// directory grows alike).
    fn create_update_tiles(&mut self, scans: &[&ScanUpdates]) {
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
    }

    /// (directory slot, scan, tile group), sorted: each tile's groups in scan order.
    fn sorted_entries(&self, scans: &[&ScanUpdates]) -> Vec<(u32, u32, u32)> {
        let mut entries: Vec<(u32, u32, u32)> = Vec::new();
        for (s, su) in scans.iter().enumerate() {
            for (g, &(ti, tj, _)) in su.tiles.iter().enumerate() {
                if let Some(slot) = self.dir.slot(ti, tj) {
                    entries.push((slot as u32, s as u32, g as u32));
                }
            }
        }
        entries.sort_unstable();
        entries
    }

    /// One job per tile of `entries`, its tile (and bins, when a scan of it has heights)
    /// taken out of the directory.
    fn update_jobs(&mut self, scans: &[&ScanUpdates], entries: &[(u32, u32, u32)]) -> Vec<TileJob> {
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
        jobs
    }
}

/// Per piece, the number of its scan: pieces of one scan
/// ([`OccupancyGrid::trace_updates_part`]) share the number of its first.
fn scan_numbers(scans: &[&ScanUpdates]) -> Vec<u32> {
    let mut scan_of: Vec<u32> = Vec::with_capacity(scans.len());
    for (p, su) in scans.iter().enumerate() {
        let first = match scan_of.last() {
            Some(&prev) if su.continues => prev,
            _ => p as u32,
        };
        scan_of.push(first);
    }
    scan_of
}

/// What every tile's job of [`OccupancyGrid::apply_updates`] reads.
struct UpdatePlan<'a> {
    scans: &'a [&'a ScanUpdates],
    entries: &'a [(u32, u32, u32)],
    scan_of: &'a [u32],
    f: FixedLogOdds,
    model: Option<BinLogOdds>,
}

impl UpdatePlan<'_> {
    /// A piece's updates of one tile: the piece and its range of updates.
    fn group(&self, &(_, p, g): &(u32, u32, u32)) -> (&ScanUpdates, std::ops::Range<usize>) {
        let su = self.scans[p as usize];
        let g = g as usize;
        let from = if g == 0 {
            0
        } else {
            su.tiles[g - 1].2 as usize
        };
        (su, from..su.tiles[g].2 as usize)
    }

    /// Applies the job's updates scan by scan.
    fn apply(&self, job: &mut TileJob) {
        let Some(tile) = job.tile.as_mut().map(Arc::make_mut) else {
            return;
        };
        let mut htile = job.htile.as_mut().map(Arc::make_mut);
        // Cells whose bins changed since their 2-D value was last projected: a cell's value
        // is only read by a later 2-D update or at the end, so it is projected then (once
        // per batch instead of once per scan; the same value). One byte per cell: flagging
        // neighbours makes no chain of stores to one word.
        let mut stale = [false; TILE_CELLS];
        let job_entries = &self.entries[job.entries.clone()];
        let mut e = 0;
        while e < job_entries.len() {
            // This tile's entries of one scan: one piece, or several to merge.
            let scan = self.scan_of[job_entries[e].1 as usize];
            let mut end = e + 1;
            while end < job_entries.len() && self.scan_of[job_entries[end].1 as usize] == scan {
                end += 1;
            }
            let mut run = TileRun {
                tile: &mut *tile,
                htile: htile.as_deref_mut(),
                stale: &mut stale,
                model: self.model,
                heights: self.scans[job_entries[e].1 as usize].heights,
                f: &self.f,
            };
            if end == e + 1 {
                self.apply_piece(&mut run, &job_entries[e]);
            } else {
                self.apply_merged(&mut run, &job_entries[e..end]);
            }
            e = end;
        }
        if let (Some(ht), Some(model)) = (&htile, self.model) {
            for (local, _) in stale.iter().enumerate().filter(|s| *s.1) {
                tile.cells[local] = project_column(&ht.bins[local], &model, self.f.occupied);
            }
        }
    }

    /// One piece, the scan's only one in this tile.
    #[inline(always)]
    fn apply_piece(&self, run: &mut TileRun<'_>, entry: &(u32, u32, u32)) {
        let (su, range) = self.group(entry);
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
    }

    /// Several pieces of one scan: marks ORed per cell as one mask would (occupied wins,
    /// bins united), then applied once per cell.
    fn apply_merged(&self, run: &mut TileRun<'_>, entries: &[(u32, u32, u32)]) {
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
            for entry in entries {
                let (su, range) = self.group(entry);
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
            let shift = if run.heights { 0 } else { 1 };
            run.apply(order[..n].iter().map(|&l| {
                let l = usize::from(l);
                (l, std::mem::take(&mut acc[l]) >> shift)
            }));
        });
    }
}
