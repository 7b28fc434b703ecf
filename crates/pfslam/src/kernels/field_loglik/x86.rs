//! [`super::sums4`] in AVX2: the four poses in the four lanes.

use super::{CentrePose, CentreTable, POSES, portable};
use std::arch::x86_64::*;

/// [`super::sums4`] with one pose per lane: the placement in f64 lanes, the interpolation
/// in f32 lanes ([`values_avx2`]), each lane's accumulator adding its values in point
/// order; the operations of [`super::portable`] (no fused multiply-add), so the same bits.
#[target_feature(enable = "avx2")]
pub(super) fn sums4_avx2(
    table: &CentreTable<'_>,
    points_body: &[[f64; 2]],
    poses: [CentrePose; POSES],
    off: impl Fn(f64, f64) -> f32,
) -> [f64; POSES] {
    // The lanes' cell index `j * w + i` is an i32: larger tables take the portable way.
    let (w, h) = (table.width, table.height);
    let cells = w.saturating_mul(h);
    if cells > i32::MAX as usize || cells > table.cells.len() {
        return portable(table, points_body, poses, off);
    }
    let lanes = |f: fn(&CentrePose) -> f64| {
        _mm256_setr_pd(f(&poses[0]), f(&poses[1]), f(&poses[2]), f(&poses[3]))
    };
    let (u0, v0) = (lanes(|p| p.u0_cells), lanes(|p| p.v0_cells));
    let (cs, ss) = (lanes(|p| p.cs_per_m), lanes(|p| p.ss_per_m));
    let mut sums = _mm256_set1_pd(-0.0);
    for p in points_body {
        let (x, y) = (_mm256_set1_pd(p[0]), _mm256_set1_pd(p[1]));
        let u = _mm256_sub_pd(
            _mm256_add_pd(u0, _mm256_mul_pd(cs, x)),
            _mm256_mul_pd(ss, y),
        );
        let v = _mm256_add_pd(
            _mm256_add_pd(v0, _mm256_mul_pd(ss, x)),
            _mm256_mul_pd(cs, y),
        );
        let values = values_avx2(table, u, v, &off);
        sums = _mm256_add_pd(sums, _mm256_cvtps_pd(values));
    }
    let mut out = [0.0f64; POSES];
    // SAFETY: a store into a local array of four f64.
    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), sums) };
    out
}

/// [`super::inside`] of four points in AVX2: the floors and fractions in vector registers,
/// each point's two corner pairs gathered (one 8-byte load per row) where its 2x2 block
/// lies inside the table, the mix in the scalar order; the other lanes take `off`. The
/// table holds `width * height` cells, fewer than 2^31.
#[target_feature(enable = "avx2")]
#[inline]
fn values_avx2(
    table: &CentreTable<'_>,
    u: __m256d,
    v: __m256d,
    off: &impl Fn(f64, f64) -> f32,
) -> __m128 {
    let (fu, fv) = (_mm256_floor_pd(u), _mm256_floor_pd(v));
    // `(u - i0) as f32`: rounded to nearest as `as` does.
    let fx = _mm256_cvtpd_ps(_mm256_sub_pd(u, fu));
    let fy = _mm256_cvtpd_ps(_mm256_sub_pd(v, fv));
    let (w, h) = (table.width as i32, table.height as i32);
    let (i, j, inside) = super::super::block_x86::block_inside(fu, fv, w, h);
    let inside_bits = _mm_movemask_ps(_mm_castsi128_ps(inside));
    let mut values = _mm_setzero_ps();
    if inside_bits != 0 {
        let k = _mm_add_epi32(_mm_mullo_epi32(j, _mm_set1_epi32(w)), i);
        let mask = _mm256_cvtepi32_epi64(inside);
        let base = table.cells.as_ptr().cast::<i64>();
        // SAFETY: only lanes inside are read: cells `k`, `k + 1`, `k + w`, `k + w + 1` of
        // their 2x2 block, below `w * h <= cells.len()`.
        let (row0, row1) = unsafe {
            (
                _mm256_mask_i32gather_epi64::<4>(_mm256_setzero_si256(), base, k, mask),
                _mm256_mask_i32gather_epi64::<4>(
                    _mm256_setzero_si256(),
                    base,
                    _mm_add_epi32(k, _mm_set1_epi32(w)),
                    mask,
                ),
            )
        };
        // [a0 b0 a1 b1 a2 b2 a3 b3] -> ([a0 a1 a2 a3], [b0 b1 b2 b3]).
        let pick = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
        let split = |r| {
            let r = _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(r, pick));
            (_mm256_castps256_ps128(r), _mm256_extractf128_ps::<1>(r))
        };
        let ((a, b), (c, d)) = (split(row0), split(row1));
        let low = _mm_add_ps(a, _mm_mul_ps(fx, _mm_sub_ps(b, a)));
        let high = _mm_add_ps(c, _mm_mul_ps(fx, _mm_sub_ps(d, c)));
        values = _mm_add_ps(low, _mm_mul_ps(fy, _mm_sub_ps(high, low)));
    }
    if inside_bits != 0b1111 {
        values = patch_outside(values, inside_bits, u, v, off);
    }
    values
}

/// `values` with the lanes not in `inside_bits` replaced by `off` of their point.
#[target_feature(enable = "avx2")]
#[inline(never)]
fn patch_outside(
    values: __m128,
    inside_bits: i32,
    u: __m256d,
    v: __m256d,
    off: &impl Fn(f64, f64) -> f32,
) -> __m128 {
    let (mut out, mut us, mut vs) = ([0.0f32; 4], [0.0f64; 4], [0.0f64; 4]);
    // SAFETY: stores into local arrays of four f32 and four f64.
    unsafe {
        _mm_storeu_ps(out.as_mut_ptr(), values);
        _mm256_storeu_pd(us.as_mut_ptr(), u);
        _mm256_storeu_pd(vs.as_mut_ptr(), v);
    }
    for l in 0..4 {
        if inside_bits >> l & 1 == 0 {
            out[l] = off(us[l], vs[l]);
        }
    }
    // SAFETY: a load from a local array of four f32.
    unsafe { _mm_loadu_ps(out.as_ptr()) }
}
