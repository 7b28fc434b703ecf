//! [`nearest_3x3`](super::nearest_3x3) in AVX2.

use super::TilePoint;
use crate::kernels::TILE_SHIFT;

/// [`nearest_3x3`](super::nearest_3x3) in AVX2: a row's three cells and squared distances in one vector each
/// (a fourth lane never occupied), a compare-select per row. The minimum of the same
/// values, taken in the same way (a candidate replaces the best only when smaller, so a NaN
/// never does): the same bits.
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn nearest_3x3_avx2(cells: &[i16], at: TilePoint, occ: i16) -> f64 {
    use std::arch::x86_64::*;
    let TilePoint {
        u_cells: u,
        v_cells: v,
        i,
        j,
        local_i: li,
        local_j: lj,
    } = at;
    // Columns i - 1, i, i + 1 (and i + 2, masked off): `f64::from(i + d) + 0.5` exactly.
    let columns = _mm_add_epi32(_mm_set1_epi32(i), _mm_setr_epi32(-1, 0, 1, 2));
    let du = _mm256_sub_pd(
        _mm256_set1_pd(u),
        _mm256_add_pd(_mm256_cvtepi32_pd(columns), _mm256_set1_pd(0.5)),
    );
    let du2 = _mm256_mul_pd(du, du);
    let occ_v = _mm_set1_epi16(occ);
    let inf = _mm256_set1_pd(f64::INFINITY);
    let mut best = inf;
    for dj in -1..=1 {
        let dv = v - (f64::from(j + dj) + 0.5);
        let dv2 = dv * dv;
        let start = (((lj + dj) as usize) << TILE_SHIFT) + (li - 1) as usize;
        let Some(row) = cells.get(start..start + 3) else {
            continue;
        };
        // The fourth lane is i16::MIN, which no threshold is below.
        let four = [row[0], row[1], row[2], i16::MIN];
        // SAFETY: an unaligned 8-byte load from a local array of four i16.
        let row_v = unsafe { _mm_loadl_epi64(four.as_ptr().cast()) };
        let occupied = _mm256_castsi256_pd(_mm256_cvtepi16_epi64(_mm_cmpgt_epi16(row_v, occ_v)));
        let d = _mm256_blendv_pd(inf, _mm256_add_pd(du2, _mm256_set1_pd(dv2)), occupied);
        // `minpd(a, b)` is `a < b ? a : b`: the scalar rule `if d < best { d } else { best }`.
        best = _mm256_min_pd(d, best);
    }
    let mut lanes = [0.0f64; 4];
    // SAFETY: a store into a local array of four f64.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), best) };
    let mut m = f64::INFINITY;
    for l in lanes {
        m = if l < m { l } else { m };
    }
    m
}
