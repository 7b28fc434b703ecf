//! The ray walk's AVX2 kernels: [`super::walk_mask`] and [`super::fresh_cells`].

use super::MaskLayout;
use super::fresh_cells_portable;
use crate::geometry::cells::Cell;
use crate::kernels::{TILE_MASK, TILE_SHIFT};

/// [`super::walk_mask`] eight cells at a time; returns false (nothing written) for a ray it does not
/// take: one whose box leaves the mask's tables, a zero-length one, or one so long that its
/// sums could leave `i32`. Bresenham's minor-axis steps after `t` cells are
/// `floor((2 d_minor t + d_major - 1) / (2 d_major))` (the error term's invariant), so each
/// lane computes its cell from `t` alone: the quotient from an `f32` estimate (off by at
/// most one: the quotient is below 2^14 and its relative error ~2^-22), corrected by the
/// integer remainder, so exact. The mask index is `mask_x` + `mask_y` (`map/grid/mask.rs`) in bit
/// arithmetic, the tables' values. The walk was ~45 % of the filter map's tracing (the
/// table loads and bounds checks per cell), the marking the rest.
#[target_feature(enable = "avx2")]
pub(super) fn walk_mask_avx2(
    from: Cell,
    to: Cell,
    layout: &MaskLayout<'_>,
    out: &mut [u32],
) -> bool {
    use std::arch::x86_64::*;
    let Some(Plan {
        x_major,
        major0,
        minor0,
        s_major,
        s_minor,
        d_major,
        d_minor,
        blocks,
    }) = plan(from, to, layout, out.len())
    else {
        return false;
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

/// A ray the eight-lane walk takes ([`walk_mask_avx2`]): its axes, its first cell
/// relative to the mask, its steps and lengths, the mask's tiles per row.
struct Plan {
    x_major: bool,
    major0: i64,
    minor0: i64,
    s_major: i32,
    s_minor: i32,
    d_major: i64,
    d_minor: i64,
    blocks: i32,
}

/// The walk of the first `n` cells of `from` -> `to` in `layout`, if the eight-lane walk
/// takes it: not a zero-length ray, not one whose box leaves the mask's tables, not one so
/// long that its sums could leave `i32`.
#[inline(always)]
fn plan(from: Cell, to: Cell, layout: &MaskLayout<'_>, n: usize) -> Option<Plan> {
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
    let n = n as i64;
    // Every cell lies in the box of the two ends as long as the walk stops at the end.
    let inside = |v: i64| (0..side).contains(&v);
    if d_major == 0
        || n > d_major + 1
        || !(inside(x0) && inside(y0) && inside(x1) && inside(y1))
        || 2 * d_minor * n + d_major >= 1 << 30
        || (layout.yoff.len() as i64) != i64::from(blocks) << TILE_SHIFT
    {
        return None;
    }
    let step = |a: i64, b: i64| if b >= a { 1 } else { -1 };
    let (sx, sy) = (step(x0, x1), step(y0, y1));
    let x_major = dx >= dy;
    let (major0, minor0, s_major, s_minor) = if x_major {
        (x0, y0, sx, sy)
    } else {
        (y0, x0, sy, sx)
    };
    Some(Plan {
        x_major,
        major0,
        minor0,
        s_major,
        s_minor,
        d_major,
        d_minor,
        blocks,
    })
}

/// [`super::fresh_cells`] eight cells at a time: the unequal lanes moved to the front by a
/// permutation looked up from the compare's bit mask, stored whole, the count advanced by
/// their number.
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
    fresh_cells_portable(ray, prev, out, 8 * chunks, n)
}

/// Per 8-bit lane mask, the lanes set, in order, then zeros: `vpermd`'s compaction indices.
static COMPACT: [[u32; 8]; 256] = {
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
