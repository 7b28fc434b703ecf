//! The f32 kernel's AVX2 versions: [`RotationF32::fill_whole`] and [`RotationF32::sums`].

use super::{F32_LIM, LANES32, RotationF32, reduce_lanes};
use crate::kernels::FieldWindow;
use crate::kernels::rotation::x86::corner_pairs;
use std::arch::x86_64::*;

impl RotationF32 {
    /// [`Self::block`] of whole chunks in AVX2, four points per f64 vector: the same
    /// products, difference, sum and scaling in the same order (no fused multiply-add), then
    /// rounded to f32 as `as f32` does, so the same bits. The scalar loop was ~6 % of the
    /// car's CPU (a rotation per yaw the refinement tries).
    #[target_feature(enable = "avx2")]
    pub(super) fn fill_avx2(
        blocks: &mut Vec<[[f32; LANES32]; 2]>,
        whole: std::slice::ChunksExact<'_, [f64; 2]>,
        s: f64,
        c: f64,
        inv_res: f64,
    ) {
        let (sv, cv, iv) = (
            _mm256_set1_pd(s),
            _mm256_set1_pd(c),
            _mm256_set1_pd(inv_res),
        );
        // Four points [x0 y0 x1 y1], [x2 y2 x3 y3] -> the rotated x and y of the four, each
        // rounded to four f32.
        let quad = |a: __m256d, b: __m256d| {
            // unpack gives [x0 x2 x1 x3]; the permute restores the point order.
            let x = _mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_unpacklo_pd(a, b));
            let y = _mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_unpackhi_pd(a, b));
            let rx = _mm256_mul_pd(
                _mm256_sub_pd(_mm256_mul_pd(cv, x), _mm256_mul_pd(sv, y)),
                iv,
            );
            let ry = _mm256_mul_pd(
                _mm256_add_pd(_mm256_mul_pd(sv, x), _mm256_mul_pd(cv, y)),
                iv,
            );
            (_mm256_cvtpd_ps(rx), _mm256_cvtpd_ps(ry))
        };
        blocks.reserve(whole.len());
        for chunk in whole {
            let Some(p) = chunk.as_flattened().first_chunk::<16>() else {
                continue;
            };
            // SAFETY: unaligned 32-byte loads from a checked 16-element slice.
            let (a0, a1, a2, a3) = unsafe {
                (
                    _mm256_loadu_pd(p.as_ptr()),
                    _mm256_loadu_pd(p.as_ptr().add(4)),
                    _mm256_loadu_pd(p.as_ptr().add(8)),
                    _mm256_loadu_pd(p.as_ptr().add(12)),
                )
            };
            let (x_lo, y_lo) = quad(a0, a1);
            let (x_hi, y_hi) = quad(a2, a3);
            let mut b = [[0.0f32; LANES32]; 2];
            // SAFETY: unaligned 32-byte stores into local arrays of eight f32.
            unsafe {
                _mm256_storeu_ps(b[0].as_mut_ptr(), _mm256_set_m128(x_hi, x_lo));
                _mm256_storeu_ps(b[1].as_mut_ptr(), _mm256_set_m128(y_hi, y_lo));
            }
            blocks.push(b);
        }
    }

    /// [`Self::sums_portable`] in AVX2 (8 lanes of f32): the same IEEE operations per lane,
    /// so the same bits; a block with a lane beyond [`F32_LIM`] (or NaN) or a corner outside
    /// the window takes [`FieldWindow::bilinear_f32`] per lane.
    ///
    /// # Safety
    /// The CPU has AVX2, and `field.vector_ok()`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sums_avx2<const K: usize>(
        rots: [&RotationF32; K],
        at: [[f32; 2]; K],
        field: &FieldWindow<'_>,
    ) -> [f64; K] {
        let lim = _mm256_set1_ps(F32_LIM);
        let sign = _mm256_set1_ps(-0.0);
        let bx: [__m256; K] = std::array::from_fn(|k| _mm256_set1_ps(at[k][0]));
        let by: [__m256; K] = std::array::from_fn(|k| _mm256_set1_ps(at[k][1]));
        let mut acc = [_mm256_setzero_ps(); K];
        let blocks = RotationF32::common_blocks(&rots);
        let lane_ids = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        for b in 0..blocks {
            let valid = rots[0].valid_in(b, blocks) as i32;
            let mask = _mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_set1_epi32(valid), lane_ids));
            for k in 0..K {
                let [rx, ry] = &rots[k].blocks[b];
                // SAFETY: unaligned loads of whole `[f32; 8]` arrays.
                let (rx, ry) =
                    unsafe { (_mm256_loadu_ps(rx.as_ptr()), _mm256_loadu_ps(ry.as_ptr())) };
                let x = _mm256_add_ps(bx[k], rx);
                let y = _mm256_add_ps(by[k], ry);
                let ok = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_andnot_ps(sign, x), lim),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_andnot_ps(sign, y), lim),
                );
                let fast = match _mm256_movemask_ps(ok) {
                    // SAFETY: the caller guarantees `field.vector_ok()`.
                    0xff => unsafe { bilinear8(field, x, y) },
                    _ => None,
                };
                let value = fast.unwrap_or_else(|| {
                    let mut xa = [0.0f32; LANES32];
                    let mut ya = [0.0f32; LANES32];
                    // SAFETY: stores into local arrays.
                    unsafe {
                        _mm256_storeu_ps(xa.as_mut_ptr(), x);
                        _mm256_storeu_ps(ya.as_mut_ptr(), y);
                    }
                    let v: [f32; LANES32] =
                        std::array::from_fn(|l| field.bilinear_f32(xa[l], ya[l]));
                    // SAFETY: a load from a local array.
                    unsafe { _mm256_loadu_ps(v.as_ptr()) }
                });
                acc[k] = _mm256_add_ps(acc[k], _mm256_and_ps(value, mask));
            }
        }
        acc.map(|a| {
            let mut lanes = [0.0f32; LANES32];
            // SAFETY: a store into a local array.
            unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), a) };
            reduce_lanes(lanes)
        })
    }
}

/// [`FieldWindow::bilinear_f32`] of eight points at window coordinates `x`, `y` (each
/// below [`F32_LIM`] in magnitude), the same operations per lane; none when a corner of
/// some point lies outside the window.
///
/// # Safety
/// `field.vector_ok()`: its sides fit in `i32` and its values cover the window.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn bilinear8(field: &FieldWindow<'_>, x: __m256, y: __m256) -> Option<__m256> {
    let one = _mm256_set1_ps(1.0);
    // `vector_ok` guarantees these fit in i32.
    let (w, h) = (field.w as i32, field.h as i32);
    let (vw, wm1, hm1) = (
        _mm256_set1_epi32(w),
        _mm256_set1_epi32(w - 1),
        _mm256_set1_epi32(h - 1),
    );
    let minus1 = _mm256_set1_epi32(-1);
    let byte = _mm256_set1_epi32(0xff);
    let base = field.values.as_ptr();
    let fw = field.w;
    let fx = _mm256_floor_ps(x);
    let fy = _mm256_floor_ps(y);
    let (i, j) = (_mm256_cvttps_epi32(fx), _mm256_cvttps_epi32(fy));
    let inside = _mm256_and_si256(
        _mm256_and_si256(_mm256_cmpgt_epi32(i, minus1), _mm256_cmpgt_epi32(wm1, i)),
        _mm256_and_si256(_mm256_cmpgt_epi32(j, minus1), _mm256_cmpgt_epi32(hm1, j)),
    );
    if _mm256_movemask_ps(_mm256_castsi256_ps(inside)) != 0xff {
        return None;
    }
    let cell = _mm256_add_epi32(_mm256_mullo_epi32(j, vw), i);
    let mut ka = [0i32; LANES32];
    // SAFETY: a store into a local array of 32 bytes.
    unsafe { _mm256_storeu_si256(ka.as_mut_ptr().cast(), cell) };
    // Per point the two corner pairs as scalar u16 loads, as in the f64
    // kernel (8-lane gathers and lane extracts measured no faster).
    // SAFETY: all four corners of every lane lie inside the window.
    let d = unsafe {
        _mm256_setr_epi32(
            corner_pairs(base, ka[0], fw),
            corner_pairs(base, ka[1], fw),
            corner_pairs(base, ka[2], fw),
            corner_pairs(base, ka[3], fw),
            corner_pairs(base, ka[4], fw),
            corner_pairs(base, ka[5], fw),
            corner_pairs(base, ka[6], fw),
            corner_pairs(base, ka[7], fw),
        )
    };
    let byte_at = |d| _mm256_cvtepi32_ps(_mm256_and_si256(d, byte));
    let f00 = byte_at(d);
    let f10 = byte_at(_mm256_srli_epi32::<8>(d));
    let f01 = byte_at(_mm256_srli_epi32::<16>(d));
    let f11 = _mm256_cvtepi32_ps(_mm256_srli_epi32::<24>(d));
    let ax = _mm256_sub_ps(x, fx);
    let ay = _mm256_sub_ps(y, fy);
    // As `bilinear_f32`.
    let omx = _mm256_sub_ps(one, ax);
    let bottom = _mm256_add_ps(_mm256_mul_ps(f00, omx), _mm256_mul_ps(f10, ax));
    let top = _mm256_add_ps(_mm256_mul_ps(f01, omx), _mm256_mul_ps(f11, ax));
    Some(_mm256_add_ps(
        _mm256_mul_ps(bottom, _mm256_sub_ps(one, ay)),
        _mm256_mul_ps(top, ay),
    ))
}
