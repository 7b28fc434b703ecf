//! Tracing a scan into an insertion mask: the mask's layout, the ray walk (AVX2 with a
//! portable twin), the cells not already marked by the previous ray.

use super::*;

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

/// Cells -> mask indices of the mask placed with its first cell at `(mi0, mj0)`.
#[derive(Clone, Copy)]
pub(super) struct MaskLayout<'a> {
    pub(super) xoff: &'a [u32],
    pub(super) yoff: &'a [u32],
    pub(super) mi0: i32,
    pub(super) mj0: i32,
}

impl MaskLayout<'_> {
    #[inline(always)]
    pub(super) fn index(&self, c: Cell) -> usize {
        (self.xoff[(c.i - self.mi0) as usize] + self.yoff[(c.j - self.mj0) as usize]) as usize
    }
}

/// Writes the first `out.len()` cells of [`bresenham`]`(from, to)` as mask indices into
/// `out`: the same cells, in the same order, as the callback form. The mask is marked from
/// this list in a second loop, which keeps both loops' state in registers. Eight cells at a
/// time in AVX2 where the CPU has it ([`walk_mask_avx2`]).
#[inline(always)]
pub(super) fn walk_mask(from: Cell, to: Cell, layout: &MaskLayout<'_>, out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if out.len() >= 8 && std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is present (checked above).
        if unsafe { walk_mask_avx2(from, to, layout, out) } {
            return;
        }
    }
    walk_mask_scalar(from, to, layout, out);
}

/// [`walk_mask`] one cell at a time: the reference, and the path without AVX2.
#[inline(always)]
pub(super) fn walk_mask_scalar(from: Cell, to: Cell, layout: &MaskLayout<'_>, out: &mut [u32]) {
    let (dx, dy) = ((to.i - from.i).abs(), (to.j - from.j).abs());
    let step_x: isize = if to.i >= from.i { 1 } else { -1 };
    let step_y: isize = if to.j >= from.j { 1 } else { -1 };
    let x = (from.i - layout.mi0) as isize;
    let y = (from.j - layout.mj0) as isize;
    // Major axis: one step per cell; minor axis: when the error crosses half a cell. The
    // index is the sum of the two axes' offsets, whichever is major.
    let (mut major, mut minor, d_major, d_minor, s_major, s_minor, off_major, off_minor) =
        if dx >= dy {
            (x, y, dx, dy, step_x, step_y, layout.xoff, layout.yoff)
        } else {
            (y, x, dy, dx, step_y, step_x, layout.yoff, layout.xoff)
        };
    let mut err = 2 * d_minor - d_major;
    for o in out.iter_mut() {
        *o = off_major[major as usize] + off_minor[minor as usize];
        if err > 0 {
            minor += s_minor;
            err -= 2 * d_major;
        }
        err += 2 * d_minor;
        major += s_major;
    }
}

/// [`walk_mask`] eight cells at a time; returns false (nothing written) for a ray it does not
/// take: one whose box leaves the mask's tables, a zero-length one, or one so long that its
/// sums could leave `i32`. Bresenham's minor-axis steps after `t` cells are
/// `floor((2 d_minor t + d_major - 1) / (2 d_major))` (the error term's invariant), so each
/// lane computes its cell from `t` alone: the quotient from an `f32` estimate (off by at
/// most one: the quotient is below 2^14 and its relative error ~2^-22), corrected by the
/// integer remainder, so exact. The mask index is [`mask_x`] + [`mask_y`] in bit
/// arithmetic, the tables' values. The walk was ~45 % of the filter map's tracing (the
/// table loads and bounds checks per cell), the marking the rest.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) fn walk_mask_avx2(
    from: Cell,
    to: Cell,
    layout: &MaskLayout<'_>,
    out: &mut [u32],
) -> bool {
    use std::arch::x86_64::*;
    let side = layout.xoff.len().min(layout.yoff.len()) as i64;
    let blocks = (layout.yoff.len() >> TILE_SHIFT) as i32;
    let rel = |c: Cell| {
        (
            i64::from(c.i) - i64::from(layout.mi0),
            i64::from(c.j) - i64::from(layout.mj0),
        )
    };
    let ((x0, y0), (x1, y1)) = (rel(from), rel(to));
    let (dx, dy) = ((x1 - x0).abs(), (y1 - y0).abs());
    let (d_major, d_minor) = (dx.max(dy), dx.min(dy));
    let n = out.len() as i64;
    // Every cell lies in the box of the two ends as long as the walk stops at the end.
    let inside = |v: i64| (0..side).contains(&v);
    if d_major == 0
        || n > d_major + 1
        || !(inside(x0) && inside(y0) && inside(x1) && inside(y1))
        || 2 * d_minor * n + d_major >= 1 << 30
        || (layout.yoff.len() as i64) != i64::from(blocks) << TILE_SHIFT
    {
        return false;
    }
    let step = |a: i64, b: i64| if b >= a { 1 } else { -1 };
    let (sx, sy) = (step(x0, x1), step(y0, y1));
    let x_major = dx >= dy;
    let (major0, minor0, s_major, s_minor) = if x_major {
        (x0, y0, sx, sy)
    } else {
        (y0, x0, sy, sx)
    };
    let b = (2 * d_major) as i32;
    let bv = _mm256_set1_epi32(b);
    let inv = _mm256_set1_ps(1.0 / b as f32);
    let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    // a(t) = 2 d_minor t + d_major - 1, t = lane + 8k.
    let mut a = _mm256_add_epi32(
        _mm256_mullo_epi32(lanes, _mm256_set1_epi32((2 * d_minor) as i32)),
        _mm256_set1_epi32((d_major - 1) as i32),
    );
    let a_step = _mm256_set1_epi32((16 * d_minor) as i32);
    // major(t) = major0 + s_major t, minor(t) = minor0 + s_minor q(t).
    let mut major = _mm256_add_epi32(
        _mm256_set1_epi32(major0 as i32),
        _mm256_sign_epi32(lanes, _mm256_set1_epi32(s_major)),
    );
    let major_step = _mm256_set1_epi32(8 * s_major);
    let minor0 = _mm256_set1_epi32(minor0 as i32);
    let s_minor = _mm256_set1_epi32(s_minor);
    let blocks = _mm256_set1_epi32(blocks);
    let (m3, m60, m_hi) = (
        _mm256_set1_epi32(3),
        _mm256_set1_epi32(60),
        _mm256_set1_epi32(!(TILE_MASK)),
    );
    let one = _mm256_set1_epi32(1);
    let index = |a: __m256i, major: __m256i| {
        let q = _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_cvtepi32_ps(a), inv));
        let r = _mm256_sub_epi32(a, _mm256_mullo_epi32(q, bv));
        // r < 0: one too many; r >= b: one too few.
        let q = _mm256_add_epi32(q, _mm256_srai_epi32::<31>(r));
        let q = _mm256_add_epi32(q, _mm256_andnot_si256(_mm256_cmpgt_epi32(bv, r), one));
        let minor = _mm256_add_epi32(minor0, _mm256_sign_epi32(q, s_minor));
        let (x, y) = if x_major {
            (major, minor)
        } else {
            (minor, major)
        };
        // mask_x(x) + mask_y(y).
        let mx = _mm256_or_si256(
            _mm256_or_si256(
                _mm256_slli_epi32::<6>(_mm256_and_si256(x, m_hi)),
                _mm256_slli_epi32::<2>(_mm256_and_si256(x, m60)),
            ),
            _mm256_and_si256(x, m3),
        );
        let my = _mm256_or_si256(
            _mm256_or_si256(
                _mm256_slli_epi32::<12>(_mm256_mullo_epi32(_mm256_srli_epi32::<6>(y), blocks)),
                _mm256_slli_epi32::<6>(_mm256_and_si256(y, m60)),
            ),
            _mm256_slli_epi32::<2>(_mm256_and_si256(y, m3)),
        );
        _mm256_add_epi32(mx, my)
    };
    let mut chunks = out.chunks_exact_mut(8);
    for chunk in &mut chunks {
        let k = index(a, major);
        // SAFETY: an unaligned 32-byte store into a slice of eight u32.
        unsafe { _mm256_storeu_si256(chunk.as_mut_ptr().cast(), k) };
        a = _mm256_add_epi32(a, a_step);
        major = _mm256_add_epi32(major, major_step);
    }
    let rest = chunks.into_remainder();
    if !rest.is_empty() {
        let mut last = [0u32; 8];
        // SAFETY: an unaligned 32-byte store into a local array of eight u32.
        unsafe { _mm256_storeu_si256(last.as_mut_ptr().cast(), index(a, major)) };
        rest.copy_from_slice(&last[..rest.len()]);
    }
    true
}

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

/// Writes the `ray` cells that differ from `prev`'s at the same place to the front of `out`
/// (which has room for `ray.len() + 8`), in order; returns how many.
#[inline(always)]
pub(super) fn fresh_cells(ray: &[u32], prev: &[u32], out: &mut [u32]) -> usize {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is present (checked above).
        return unsafe { fresh_cells_avx2(ray, prev, out) };
    }
    fresh_cells_scalar(ray, prev, out, 0, 0)
}

/// [`fresh_cells`] from `ray[at..]`, `n` written so far: branch-free, one cell at a time.
#[inline(always)]
pub(super) fn fresh_cells_scalar(
    ray: &[u32],
    prev: &[u32],
    out: &mut [u32],
    at: usize,
    mut n: usize,
) -> usize {
    for (&k, &p) in ray[at..].iter().zip(&prev[at..]) {
        out[n] = k;
        n += usize::from(k != p);
    }
    n
}

/// [`fresh_cells`] eight cells at a time: the unequal lanes moved to the front by a
/// permutation looked up from the compare's bit mask, stored whole, the count advanced by
/// their number.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) fn fresh_cells_avx2(ray: &[u32], prev: &[u32], out: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let mut n = 0;
    let chunks = ray.len().min(prev.len()) / 8;
    for c in 0..chunks {
        let (Some(r), Some(p), Some(o)) = (
            ray[8 * c..].first_chunk::<8>(),
            prev[8 * c..].first_chunk::<8>(),
            out.get_mut(n..n + 8),
        ) else {
            break;
        };
        // SAFETY: unaligned 32-byte loads from checked 8-element slices.
        let (r, p) = unsafe {
            (
                _mm256_loadu_si256(r.as_ptr().cast()),
                _mm256_loadu_si256(p.as_ptr().cast()),
            )
        };
        let same = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(r, p))) as usize;
        let keep = !same & 0xff;
        // SAFETY: a 32-byte load from a table entry of eight u32.
        let perm = unsafe { _mm256_loadu_si256(COMPACT[keep].as_ptr().cast()) };
        // SAFETY: an unaligned 32-byte store into a checked 8-element slice.
        unsafe { _mm256_storeu_si256(o.as_mut_ptr().cast(), _mm256_permutevar8x32_epi32(r, perm)) };
        n += keep.count_ones() as usize;
    }
    fresh_cells_scalar(ray, prev, out, 8 * chunks, n)
}

/// Per 8-bit lane mask, the lanes set, in order, then zeros: `vpermd`'s compaction indices.
pub(super) static COMPACT: [[u32; 8]; 256] = {
    let mut t = [[0u32; 8]; 256];
    let mut m = 0;
    while m < 256 {
        let (mut n, mut lane) = (0, 0);
        while lane < 8 {
            if m >> lane & 1 == 1 {
                t[m][n] = lane as u32;
                n += 1;
            }
            lane += 1;
        }
        m += 1;
    }
    t
};

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
