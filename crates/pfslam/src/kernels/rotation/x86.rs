//! [`Rotation::sums`] in AVX2, and the corner loads the f32 kernel shares.

use super::Rotation;
use crate::geometry::cells::MapLimits;
use crate::kernels::{FieldWindow, LANES};
use std::arch::x86_64::*;

/// The field values at the four corners `(i, j)`, `(i + 1, j)`, `(i, j + 1)`,
/// `(i + 1, j + 1)` of four points whose cell floors are `$fx`, `$fy` (finite, within 1e9
/// cells): `(f00, f10, f01, f11)`, as [`FieldWindow::corners`] gives them. A macro, not
/// a function: it expands into each instance of [`Rotation::sums_avx2`], where a
/// `#[target_feature]` function of this size was called, not inlined. Only in an `unsafe`
/// context where `$field.vector_ok()` holds (its sides fit in `i32` and its values cover
/// the window).
macro_rules! corners4 {
    ($field:expr, $fx:expr, $fy:expr) => {{
        let (i0, j0) = (_mm_set1_epi32($field.i0), _mm_set1_epi32($field.j0));
        // `vector_ok` guarantees these fit in i32.
        let (w, h) = ($field.w as i32, $field.h as i32);
        let (vw, wm1, hm1) = (
            _mm_set1_epi32(w),
            _mm_set1_epi32(w - 1),
            _mm_set1_epi32(h - 1),
        );
        let minus1 = _mm_set1_epi32(-1);
        let byte = _mm_set1_epi32(0xff);
        let base = $field.values.as_ptr();
        let fw = $field.w;
        let (i, j) = (_mm256_cvttpd_epi32($fx), _mm256_cvttpd_epi32($fy));
        let (li, lj) = (_mm_sub_epi32(i, i0), _mm_sub_epi32(j, j0));
        let inside = _mm_and_si128(
            _mm_and_si128(_mm_cmpgt_epi32(li, minus1), _mm_cmpgt_epi32(wm1, li)),
            _mm_and_si128(_mm_cmpgt_epi32(lj, minus1), _mm_cmpgt_epi32(hm1, lj)),
        );
        if _mm_movemask_ps(_mm_castsi128_ps(inside)) == 0xf {
            let k = _mm_add_epi32(_mm_mullo_epi32(lj, vw), li);
            // Per point the two corner pairs as scalar u16 loads, packed
            // `f00 f10 f01 f11` into one 32-bit lane (on this Zen, cheaper
            // than two 4-lane gathers).
            // SAFETY: all four corners lie inside the window (checked above), whose values
            // cover `w * h` cells (`vector_ok`, the caller's precondition).
            let d = unsafe {
                _mm_setr_epi32(
                    corner_pairs(base, _mm_extract_epi32::<0>(k), fw),
                    corner_pairs(base, _mm_extract_epi32::<1>(k), fw),
                    corner_pairs(base, _mm_extract_epi32::<2>(k), fw),
                    corner_pairs(base, _mm_extract_epi32::<3>(k), fw),
                )
            };
            let byte_at = |d| _mm256_cvtepi32_pd(_mm_and_si128(d, byte));
            (
                byte_at(d),
                byte_at(_mm_srli_epi32::<8>(d)),
                byte_at(_mm_srli_epi32::<16>(d)),
                _mm256_cvtepi32_pd(_mm_srli_epi32::<24>(d)),
            )
        } else {
            // A corner outside the window: `corners`' slow path per lane.
            let mut ia = [0i32; LANES];
            let mut ja = [0i32; LANES];
            // SAFETY: stores into local arrays.
            unsafe {
                _mm_storeu_si128(ia.as_mut_ptr().cast(), i);
                _mm_storeu_si128(ja.as_mut_ptr().cast(), j);
            }
            let f: [[f64; 4]; LANES] = std::array::from_fn(|l| $field.corners(ia[l], ja[l]));
            let col = |c: usize| _mm256_setr_pd(f[0][c], f[1][c], f[2][c], f[3][c]);
            (col(0), col(1), col(2), col(3))
        }
    }};
}

impl Rotation {
    /// [`Self::sums_portable`] in AVX2: the same IEEE operations per lane (no FMA: Rust
    /// never contracts), so the same bits; the four corner bytes of a point come from two
    /// scalar u16 loads (two 4-lane 32-bit gathers before: ~10 % slower on this Zen 4).
    ///
    /// # Safety
    /// The CPU has AVX2, and `field.vector_ok()`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sums_avx2<const K: usize>(
        rots: [&Rotation; K],
        at: [[f64; 2]; K],
        field: &FieldWindow<'_>,
        limits: &MapLimits,
    ) -> [f64; K] {
        let (ox, oy) = (limits.origin_x_m(), limits.origin_y_m());
        // The same division `MapLimits::new` caches for `cell_coords`: the same bits.
        let inv = 1.0 / limits.resolution_m();
        let (vox, voy, vinv) = (_mm256_set1_pd(ox), _mm256_set1_pd(oy), _mm256_set1_pd(inv));
        let half = _mm256_set1_pd(0.5);
        let one = _mm256_set1_pd(1.0);
        let lim = _mm256_set1_pd(1e9);
        let sign = _mm256_set1_pd(-0.0);
        let vx: [__m256d; K] = std::array::from_fn(|k| _mm256_set1_pd(at[k][0]));
        let vy: [__m256d; K] = std::array::from_fn(|k| _mm256_set1_pd(at[k][1]));
        let mut sums = [-0.0; K];
        let mut values = [[0.0; LANES]; K];
        for b in 0..Rotation::common_blocks(&rots) {
            for k in 0..K {
                let [r0, r1, r2, r3] = &rots[k].blocks[b];
                // SAFETY: unaligned loads of whole `[f64; 4]` arrays.
                let (r0, r1, r2, r3) = unsafe {
                    (
                        _mm256_loadu_pd(r0.as_ptr()),
                        _mm256_loadu_pd(r1.as_ptr()),
                        _mm256_loadu_pd(r2.as_ptr()),
                        _mm256_loadu_pd(r3.as_ptr()),
                    )
                };
                let wx = _mm256_sub_pd(_mm256_add_pd(vx[k], r0), r1);
                let wy = _mm256_add_pd(_mm256_add_pd(vy[k], r2), r3);
                let u = _mm256_mul_pd(_mm256_sub_pd(wx, vox), vinv);
                let v = _mm256_mul_pd(_mm256_sub_pd(wy, voy), vinv);
                let x = _mm256_sub_pd(u, half);
                let y = _mm256_sub_pd(v, half);
                let ok = _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, x), lim),
                    _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, y), lim),
                );
                let out = if _mm256_movemask_pd(ok) != 0xf {
                    // A lane beyond the fast path's range (or NaN): the scalar path per lane.
                    let mut ua = [0.0; LANES];
                    let mut va = [0.0; LANES];
                    // SAFETY: stores into local arrays.
                    unsafe {
                        _mm256_storeu_pd(ua.as_mut_ptr(), u);
                        _mm256_storeu_pd(va.as_mut_ptr(), v);
                    }
                    std::array::from_fn(|l| field.bilinear(ua[l], va[l]))
                } else {
                    // `floor_to_i32` as a float: the same value (the lanes are finite and
                    // within 1e9; `x`, `y` are never -0.0, as `u - 0.5` cannot be).
                    let fx = _mm256_floor_pd(x);
                    let fy = _mm256_floor_pd(y);
                    let ax = _mm256_sub_pd(x, fx);
                    let ay = _mm256_sub_pd(y, fy);
                    let (f00, f10, f01, f11) = corners4!(field, fx, fy);
                    // `f00 * (1 - ax) + f10 * ax` etc., as `mix_lanes`.
                    let omx = _mm256_sub_pd(one, ax);
                    let bottom = _mm256_add_pd(_mm256_mul_pd(f00, omx), _mm256_mul_pd(f10, ax));
                    let top = _mm256_add_pd(_mm256_mul_pd(f01, omx), _mm256_mul_pd(f11, ax));
                    let mixed = _mm256_add_pd(
                        _mm256_mul_pd(bottom, _mm256_sub_pd(one, ay)),
                        _mm256_mul_pd(top, ay),
                    );
                    let mut out = [0.0; LANES];
                    // SAFETY: a store into a local array.
                    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), mixed) };
                    out
                };
                values[k] = out;
            }
            // Apart from the loop above (which stays a loop): unrolled, so that the
            // accumulators stay in registers and the chains overlap.
            for (sum, values) in sums.iter_mut().zip(&values) {
                for value in values {
                    *sum += value;
                }
            }
        }
        std::array::from_fn(|k| rots[k].sum_tail(field, limits, at[k][0], at[k][1], sums[k]))
    }
}

/// The field bytes at `k`, `k + 1` (low half) and `k + w`, `k + w + 1` (high half) as one
/// little-endian 32-bit value.
///
/// # Safety
/// `base + k + w + 1` lies inside the field's values (`k` non-negative).
#[inline(always)]
pub(crate) unsafe fn corner_pairs(base: *const u8, k: i32, w: usize) -> i32 {
    let k = k as usize;
    // SAFETY: the caller guarantees both 2-byte reads lie inside the values.
    let (row0, row1) = unsafe {
        (
            base.add(k).cast::<u16>().read_unaligned(),
            base.add(k + w).cast::<u16>().read_unaligned(),
        )
    };
    (u32::from(row0) | (u32::from(row1) << 16)) as i32
}
