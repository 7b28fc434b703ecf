//! Tracing a scan into an insertion mask: the mask's layout, the rays' cells not already
//! marked by the previous ray (the ray walk's kernels in `crate::kernels::mask`).

use super::*;
use crate::kernels::mask::{fresh_cells, walk_mask};

/// What one scan does to a cell. Rule: each cell gets at most one update per scan; a cell
/// that is the end cell of any return is occupied, whatever other rays crossed it (occupied
/// wins over free).
/// Encoded so that "occupied wins" is a bitwise OR: `max(a, b) == a | b` on {0, 1, 3}.
pub(super) const MARK_NONE: u8 = 0;
pub(super) const MARK_FREE: u8 = 1;
pub(super) const MARK_OCCUPIED: u8 = 3;

/// Caller-owned scratch for [`OccupancyGrid::insert_scan`]: a zeroed mask around the
/// sensor's cell and the list of cells touched by the current scan. The mask covers whole
/// tiles of the grid (its origin is aligned with them), stored tile after tile (row-major
/// over the mask's tiles), each tile as 16 x 16 blocks of 4 x 4 cells (a block of `u32` marks
/// is one 64-byte cache line): a ray in any direction touches about one cache line per 4
/// cells, not one per cell as a steep ray does in a row-major mask, and a mask index splits
/// into tile and cell with shifts. The index is separable, `xoff[column] + yoff[row]`, so a
/// ray walks it with two table reads per step. Reuse one per thread (or per particle); it
/// never needs clearing (insertion leaves the mask zeroed).
#[derive(Debug, Default, Clone)]
pub struct InsertScratch {
    pub(super) mask: Vec<u8>,
    /// Largest Chebyshev ray length the mask holds (cells).
    pub(super) half: i32,
    /// Mask side in cells (a whole number of tiles).
    pub(super) side: i32,
    /// Mask side in tiles.
    pub(super) blocks: usize,
    /// Mask index of a column's / a row's cells: `xoff[column] + yoff[row]`.
    pub(super) xoff: Vec<u32>,
    pub(super) yoff: Vec<u32>,
    /// Touched cells (mask indices); only the first `len` of an insertion are meaningful.
    pub(super) touched: Vec<u32>,
    /// Height insertion's mask (same layout as `mask`): bits 0-15 = bins passed free, bits
    /// 16-31 = bins hit. Allocated on the first scan with heights; left zeroed.
    pub(super) hmask: Vec<u32>,
    /// [`OccupancyGrid::trace_updates`]' counting sort: cells per tile of the mask (left
    /// zeroed), and the tiles in first-touch order.
    pub(super) block_count: Vec<u32>,
    pub(super) block_order: Vec<u32>,
    /// [`OccupancyGrid::trace_heights`]: the height bin of each step of the current ray.
    pub(super) bits: Vec<u32>,
    /// The current ray's cells (mask indices), walked before they are marked (heights).
    pub(super) cells: Vec<u32>,
    /// Planar rays' walks ([`RayCells`]).
    pub(super) walk: RayCells,
    /// [`drain_heights`]' runs of touched cells in one tile: (mask tile, start, end).
    pub(super) runs: Vec<(u32, u32, u32)>,
}

impl InsertScratch {
    /// Empty scratch; it grows to the longest ray seen.
    pub fn new() -> Self {
        InsertScratch::default()
    }

    /// Bytes held (masks and lists).
    pub fn memory_bytes(&self) -> usize {
        self.mask.capacity()
            + 4 * (self.hmask.capacity()
                + self.touched.capacity()
                + self.block_count.capacity()
                + self.block_order.capacity()
                + self.bits.capacity()
                + self.cells.capacity()
                + 3 * self.runs.capacity()
                + self.xoff.capacity()
                + self.yoff.capacity())
            + self.walk.bytes()
    }

    pub(super) fn ensure_half(&mut self, half: i32) {
        if half > self.half || self.mask.is_empty() {
            // 2 * half + 1 cells starting anywhere in a tile span at most this many tiles.
            let blocks = (2 * half + 1 + TILE_MASK) / TILE_SIZE as i32 + 1;
            let side = blocks * TILE_SIZE as i32;
            let blocks = blocks as usize;
            self.mask = vec![MARK_NONE; blocks * blocks * TILE_CELLS];
            self.half = half;
            self.side = side;
            self.blocks = blocks;
            self.xoff = (0..side as u32).map(mask_x).collect();
            self.yoff = (0..side as u32).map(|r| mask_y(r, blocks)).collect();
        }
    }
}

/// Mask index of column `c` (of the first row): tile, block column and column in block.
pub(super) fn mask_x(c: u32) -> u32 {
    ((c >> TILE_SHIFT) << (2 * TILE_SHIFT)) | ((c & TILE_MASK as u32) >> 2) << 4 | (c & 3)
}

/// Mask index of row `r` (of the first column), `blocks` tiles per mask row.
pub(super) fn mask_y(r: u32, blocks: usize) -> u32 {
    ((r >> TILE_SHIFT) * blocks as u32) << (2 * TILE_SHIFT)
        | ((r & TILE_MASK as u32) >> 2) << 8
        | (r & 3) << 2
}

/// A mask index's tile (row-major over the mask's tiles).
#[inline(always)]
pub(super) fn mask_tile(k: usize) -> usize {
    k >> (2 * TILE_SHIFT)
}

/// A mask index's cell index within its tile (row-major, as [`Tile`]): the mask's tile holds
/// block row (bits 8-11), block column (4-7), row in block (2-3), column in block (0-1).
#[inline(always)]
pub(super) fn local_of(k: usize) -> usize {
    usize::from(LOCAL_OF_MASK_CELL[k & (TILE_CELLS - 1)])
}

/// [`local_of`] as a table (one load instead of the bit shuffle, for every touched cell).
pub(super) static LOCAL_OF_MASK_CELL: [u16; TILE_CELLS] = {
    let mut t = [0u16; TILE_CELLS];
    let mut k = 0;
    while k < TILE_CELLS {
        t[k] = ((k & 0xf00) | (k & 0xc) << 4 | (k & 0xf0) >> 2 | (k & 3)) as u16;
        k += 1;
    }
    t
};

/// The mask's layout, defined with the ray walk's kernels.
pub(crate) use crate::kernels::mask::MaskLayout;

/// A scan's planar ray walks: the cells of the ray being walked, those of the ray before it
/// (already marked free by this scan), and the new ray's cells that differ from the
/// previous ray's at the same step. Rays of a scan come in angular order and start in one
/// cell, so neighbours share most cells near the sensor (and the joining rays, whose ends
/// lie one cell apart, most of their length): on the car 53.7k cells walked per scan for
/// 21.4k distinct. Marking is an OR of the same free mark, so leaving those out is exact,
/// and the marking's read-modify-writes were the tracing's largest cost.
#[derive(Debug, Default, Clone)]
pub(crate) struct RayCells {
    ray: Vec<u32>,
    prev: Vec<u32>,
    /// Cells of `prev` walked (0: no previous ray to compare with).
    prev_len: usize,
    fresh: Vec<u32>,
}

impl RayCells {
    pub(super) fn bytes(&self) -> usize {
        4 * (self.ray.capacity() + self.prev.capacity() + self.fresh.capacity())
    }

    /// No previous ray: a new scan (or piece of one), or a ray walked another way.
    #[inline(always)]
    pub(super) fn forget(&mut self) {
        self.prev_len = 0;
    }

    /// Walks the first `count` cells of `from` -> `to` ([`walk_mask`]) and returns those
    /// not equal to the previous ray's cell at the same step; the ray becomes the previous.
    #[inline(always)]
    pub(super) fn walk_fresh(
        &mut self,
        from: Cell,
        to: Cell,
        layout: &MaskLayout<'_>,
        count: usize,
    ) -> &[u32] {
        // Eight spare lanes: the vector compaction stores whole registers.
        for v in [&mut self.ray, &mut self.fresh] {
            if v.len() < count + 8 {
                v.resize(count + 8 + 1024, 0);
            }
        }
        walk_mask(from, to, layout, &mut self.ray[..count]);
        let common = count.min(self.prev_len);
        let mut n = fresh_cells(&self.ray[..common], &self.prev[..common], &mut self.fresh);
        self.fresh[n..n + count - common].copy_from_slice(&self.ray[common..count]);
        n += count - common;
        std::mem::swap(&mut self.ray, &mut self.prev);
        self.prev_len = count;
        &self.fresh[..n]
    }
}

/// Marks a ray's `cells` (mask indices) with `marks` (OR: occupied wins) and appends the
/// newly touched ones to `touched` from `len` (room for all of them is the caller's);
/// returns the new length. Its own function, on slices: the loop keeps the lengths and
/// pointers in registers instead of reloading them through the scratch's vectors per cell.
#[inline(never)]
pub(super) fn mark_cells<T>(
    mask: &mut [T],
    touched: &mut [u32],
    mut len: usize,
    cells: &[u32],
    marks: impl Iterator<Item = T>,
) -> usize
where
    T: Copy + Default + PartialEq + std::ops::BitOr<Output = T>,
{
    for (&k, m) in cells.iter().zip(marks) {
        let old = mask[k as usize];
        mask[k as usize] = old | m;
        touched[len] = k;
        len += usize::from(old == T::default());
    }
    len
}

/// A ray's end cell, the cell its free updates stop at, and whether they stop short of the
/// end (a ray cleared only part of the way, `ScanPoint::free_to < 1`, clears free cells only).
#[inline(always)]
pub(super) fn ray_cells(
    limits: &MapLimits,
    scan: &PlanarScan,
    p: &ScanPoint,
) -> (Cell, Cell, bool) {
    let end = limits.cell_of(p.x_m, p.y_m);
    if p.free_to < 1.0 {
        let t = f64::from(p.free_to.max(0.0));
        let x = scan.sensor_x_m + t * (p.x_m - scan.sensor_x_m);
        let y = scan.sensor_y_m + t * (p.y_m - scan.sensor_y_m);
        (end, limits.cell_of(x, y), true)
    } else {
        (end, end, false)
    }
}

/// Where planar tracing puts a scan's marks: one call per cell, free or occupied (occupied
/// wins over free within a scan, whatever the order).
pub(crate) trait Marks {
    /// Room for `n` more marks (a list that grows).
    fn reserve(&mut self, n: usize);
    /// Marks mask cell `k`.
    fn mark(&mut self, k: usize, occupied: bool);
    /// Marks mask cells `cells` free (a walked ray).
    fn mark_free(&mut self, cells: &[u32]);
}

/// One scan's marks in a byte mask, with the list of cells in first-touch order
/// ([`OccupancyGrid::insert_scan`], [`OccupancyGrid::trace_updates_part`]).
pub(super) struct TouchMarks<'a> {
    pub(super) mask: &'a mut [u8],
    pub(super) touched: &'a mut Vec<u32>,
    pub(super) len: usize,
}

impl Marks for TouchMarks<'_> {
    #[inline(always)]
    fn reserve(&mut self, n: usize) {
        if self.touched.len() < self.len + n {
            self.touched.resize(self.len + n + 4096, 0);
        }
    }

    /// Branch-free: whether a cell is new is unpredictable.
    #[inline(always)]
    fn mark(&mut self, k: usize, occupied: bool) {
        let m = if occupied { MARK_OCCUPIED } else { MARK_FREE };
        let old = self.mask[k];
        self.mask[k] = old | m;
        self.touched[self.len] = k as u32;
        self.len += usize::from(old == MARK_NONE);
    }

    #[inline(always)]
    fn mark_free(&mut self, cells: &[u32]) {
        self.len = mark_cells(
            self.mask,
            self.touched,
            self.len,
            cells,
            std::iter::repeat(MARK_FREE),
        );
    }
}

/// Splits the touched mask indices (in touch order: ray order, so consecutive cells share
/// tiles) into runs within one tile, and calls `apply(tile column, tile row, run)` with the
/// tile's position in the mask (`blocks` tiles per row): one directory lookup per run.
#[inline(always)]
pub(super) fn for_each_tile_run(
    touched: &[u32],
    blocks: usize,
    mut apply: impl FnMut(i32, i32, &[u32]),
) {
    let mut start = 0;
    while start < touched.len() {
        let block = mask_tile(touched[start] as usize);
        let mut end = start + 1;
        while end < touched.len() && mask_tile(touched[end] as usize) == block {
            end += 1;
        }
        apply(
            (block % blocks) as i32,
            (block / blocks) as i32,
            &touched[start..end],
        );
        start = end;
    }
}
