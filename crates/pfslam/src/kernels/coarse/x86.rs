//! The coarse search's AVX2 kernels: [`CoarseYaw::bases`] and [`super::coarse_sums`].

use super::CoarseYaw;
use crate::kernels::LANES;

/// [`super::coarse_sums`] for sides up to 8 in AVX2: each row of the block is one 8-byte load
/// widened to eight u16 lanes and added to that row's accumulator (u16 lanes cannot
/// overflow within blocks of 257 points; lanes beyond `S` are ignored). Integer sums: the
/// same values as the other kernels.
#[target_feature(enable = "avx2")]
pub(crate) fn coarse_sums_avx2<const S: usize>(
    values: &[u8],
    w: usize,
    base: &[usize],
    sums: &mut [u32],
) {
    use std::arch::x86_64::*;
    for block in base.chunks(257) {
        let mut acc = [_mm_setzero_si128(); S];
        for &b in block {
            for (oy, a) in acc.iter_mut().enumerate() {
                let Some(bytes) = values[b + oy * w..].first_chunk::<8>() else {
                    continue;
                };
                // SAFETY: an unaligned 8-byte load from a checked 8-byte slice.
                let row = unsafe { _mm_loadl_epi64(bytes.as_ptr().cast()) };
                *a = _mm_add_epi16(*a, _mm_cvtepu8_epi16(row));
            }
        }
        for (sum_row, a) in sums.chunks_exact_mut(S).zip(&acc) {
            let mut lanes = [0u16; 8];
            // SAFETY: a store into a local array of 16 bytes.
            unsafe { _mm_storeu_si128(lanes.as_mut_ptr().cast(), *a) };
            for (s, &l) in sum_row.iter_mut().zip(&lanes) {
                *s += u32::from(l);
            }
        }
    }
}

impl CoarseYaw<'_> {
    /// [`CoarseYaw::bases_portable`] of the whole blocks of [`LANES`] points in AVX2 (the same
    /// floating-point operations per lane, so the same cells; a block with a coordinate beyond
    /// +-1e9 cells, or NaN, takes the portable path).
    #[target_feature(enable = "avx2")]
    pub(super) fn bases_avx2(&self, points_body: &[[f64; 2]], base: &mut Vec<usize>) {
        let (field, limits, predicted, r) = (self.field, self.limits, self.predicted, self.r);
        let (s, c) = self.sin_cos;
        use std::arch::x86_64::*;
        let (vs, vc) = (_mm256_set1_pd(s), _mm256_set1_pd(c));
        let (vx, vy) = (_mm256_set1_pd(predicted.x_m), _mm256_set1_pd(predicted.y_m));
        let (vox, voy) = (
            _mm256_set1_pd(limits.origin_x_m()),
            _mm256_set1_pd(limits.origin_y_m()),
        );
        // The same division `MapLimits::new` caches for `cell_of`: the same bits.
        let vinv = _mm256_set1_pd(1.0 / limits.resolution_m());
        let one = _mm256_set1_pd(1.0);
        let lim = _mm256_set1_pd(1e9);
        let sign = _mm256_set1_pd(-0.0);
        // `vector_ok` guarantees these fit in i32.
        let (w, h) = (field.w as i32, field.h as i32);
        // Inside: r <= li < w - r and r <= lj < h - r, with li = i - i0.
        let (lo_i, hi_i) = (
            _mm_set1_epi32(field.i0 + r - 1),
            _mm_set1_epi32(field.i0 + w - r),
        );
        let (lo_j, hi_j) = (
            _mm_set1_epi32(field.j0 + r - 1),
            _mm_set1_epi32(field.j0 + h - r),
        );
        // Wrapping: the pushed lanes' indices are exact modulo 2^32 and small.
        let corner = _mm_set1_epi32(
            field
                .i0
                .wrapping_add(r)
                .wrapping_add(field.j0.wrapping_add(r).wrapping_mul(w)),
        );
        let vw = _mm_set1_epi32(w);
        for quad in points_body.chunks_exact(LANES) {
            // SAFETY: two unaligned loads of 4 f64 each from a block of 4 `[f64; 2]`.
            let (a, b) = unsafe {
                let p = quad.as_ptr().cast::<f64>();
                (_mm256_loadu_pd(p), _mm256_loadu_pd(p.add(4)))
            };
            // (x0 y0 x1 y1), (x2 y2 x3 y3) -> (x0 x1 x2 x3), (y0 y1 y2 y3).
            let px = _mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_unpacklo_pd(a, b));
            let py = _mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_unpackhi_pd(a, b));
            let x = _mm256_sub_pd(
                _mm256_add_pd(vx, _mm256_mul_pd(vc, px)),
                _mm256_mul_pd(vs, py),
            );
            let y = _mm256_add_pd(
                _mm256_add_pd(vy, _mm256_mul_pd(vs, px)),
                _mm256_mul_pd(vc, py),
            );
            let u = _mm256_mul_pd(_mm256_sub_pd(x, vox), vinv);
            let v = _mm256_mul_pd(_mm256_sub_pd(y, voy), vinv);
            let ok = _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, u), lim),
                _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, v), lim),
            );
            if _mm256_movemask_pd(ok) != 0xf {
                self.bases_portable(quad, base);
                continue;
            }
            // floor_to_i32: truncate, minus one where the truncation lies above.
            let tu = _mm256_cvtepi32_pd(_mm256_cvttpd_epi32(u));
            let tv = _mm256_cvtepi32_pd(_mm256_cvttpd_epi32(v));
            let fu = _mm256_sub_pd(tu, _mm256_and_pd(_mm256_cmp_pd::<_CMP_GT_OQ>(tu, u), one));
            let fv = _mm256_sub_pd(tv, _mm256_and_pd(_mm256_cmp_pd::<_CMP_GT_OQ>(tv, v), one));
            let (i, j) = (_mm256_cvttpd_epi32(fu), _mm256_cvttpd_epi32(fv));
            let inside = _mm_and_si128(
                _mm_and_si128(_mm_cmpgt_epi32(i, lo_i), _mm_cmpgt_epi32(hi_i, i)),
                _mm_and_si128(_mm_cmpgt_epi32(j, lo_j), _mm_cmpgt_epi32(hi_j, j)),
            );
            let mask = _mm_movemask_ps(_mm_castsi128_ps(inside));
            if mask == 0 {
                continue;
            }
            // (j - j0 - r) w + (i - i0 - r) = j w + i - ((j0 + r) w + i0 + r).
            let k = _mm_sub_epi32(_mm_add_epi32(_mm_mullo_epi32(j, vw), i), corner);
            let mut ka = [0i32; LANES];
            // SAFETY: a store into a local array of 16 bytes.
            unsafe { _mm_storeu_si128(ka.as_mut_ptr().cast(), k) };
            for (lane, &k) in ka.iter().enumerate() {
                if mask & (1 << lane) != 0 {
                    base.push(k as usize);
                }
            }
        }
    }
}
