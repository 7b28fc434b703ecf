//! [`super::cell_sum`] in AVX2.

use super::portable;
use crate::kernels::PointLevel;

/// [`super::cell_sum`] eight points at a time: the offsets, the window test and the index
/// in `i32` lanes, the values gathered where inside (the others not read), summed in two
/// `f64` accumulators; the last points as [`portable`].
#[target_feature(enable = "avx2")]
pub(super) fn cell_sum_avx2(
    field: PointLevel<'_>,
    (xs_all, ys_all): (&[i32], &[i32]),
    level: usize,
    dx: i64,
    dy: i64,
) -> f64 {
    use std::arch::x86_64::*;
    let lv = field.cells;
    let span = (1i64 << level) - 1;
    let n = xs_all.len().min(ys_all.len());
    // Offsets beyond any window (2^14 cells) and clamped cells (2^30) stay apart in i32:
    // such offsets go the scalar way.
    let small = |d: i64| d.abs() <= 1 << 20;
    // (No points: the scalar sum's -0.0.)
    if n == 0 || !(small(dx) && small(dy) && span < 1 << 20 && lv.len() >= field.w * field.h) {
        return portable(field, (xs_all, ys_all), level, dx, dy);
    }
    let (xs, ys) = (
        xs_all[..n].as_chunks::<8>().0,
        ys_all[..n].as_chunks::<8>().0,
    );
    let shift_x = _mm256_set1_epi32((dx + span) as i32);
    let shift_y = _mm256_set1_epi32((dy + span) as i32);
    let span_v = _mm256_set1_epi32(span as i32);
    // `ws`, `hs` of the scalar test: `0 <= x + span < w + span`, likewise y.
    let ws = _mm256_set1_epi32((field.w as i64 + span) as i32);
    let hs = _mm256_set1_epi32((field.h as i64 + span) as i32);
    let w = _mm256_set1_epi32(field.w as i32);
    let minus_one = _mm256_set1_epi32(-1);
    let zero = _mm256_setzero_si256();
    let (mut lo, mut hi) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    for (x8, y8) in xs.iter().zip(ys) {
        // SAFETY: unaligned loads of eight i32 from arrays of eight.
        let (x, y) = unsafe {
            (
                _mm256_loadu_si256(x8.as_ptr().cast()),
                _mm256_loadu_si256(y8.as_ptr().cast()),
            )
        };
        let (xs_, ys_) = (_mm256_add_epi32(x, shift_x), _mm256_add_epi32(y, shift_y));
        let inside = _mm256_and_si256(
            _mm256_and_si256(
                _mm256_cmpgt_epi32(xs_, minus_one),
                _mm256_cmpgt_epi32(ws, xs_),
            ),
            _mm256_and_si256(
                _mm256_cmpgt_epi32(ys_, minus_one),
                _mm256_cmpgt_epi32(hs, ys_),
            ),
        );
        // `x.max(0)`, `y.max(0)` of `x = xs_ - span`; then `y * w + x` (< w * h).
        let x = _mm256_max_epi32(_mm256_sub_epi32(xs_, span_v), zero);
        let y = _mm256_max_epi32(_mm256_sub_epi32(ys_, span_v), zero);
        let index = _mm256_add_epi32(_mm256_mullo_epi32(y, w), x);
        // SAFETY: only lanes inside the window are read, at `y * w + x < w * h <=
        // lv.len()`; the others keep 0.
        let v = unsafe {
            _mm256_mask_i32gather_ps::<4>(
                _mm256_setzero_ps(),
                lv.as_ptr(),
                index,
                _mm256_castsi256_ps(inside),
            )
        };
        lo = _mm256_add_pd(lo, _mm256_cvtps_pd(_mm256_castps256_ps128(v)));
        hi = _mm256_add_pd(hi, _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v)));
    }
    let mut lanes = [0.0f64; 4];
    // SAFETY: a store into a local array of four f64.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), _mm256_add_pd(lo, hi)) };
    let done = xs.len() * 8;
    let rest = (&xs_all[done..n], &ys_all[done..n]);
    lanes.iter().sum::<f64>() + portable(field, rest, level, dx, dy)
}
