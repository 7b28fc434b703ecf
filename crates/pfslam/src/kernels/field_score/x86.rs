//! [`super::scores`] with the four lanes' interpolation in AVX2.

use super::{bilinear_lane, scores_with};
use crate::geometry::Pose2;
use crate::kernels::{LANES, PointLevel};

/// [`super::scores`] with the four lanes' interpolation in AVX2
/// ([`bilinear_lanes_avx2`]); the same bits.
#[target_feature(enable = "avx2")]
pub(super) fn scores_avx2<const K: usize>(
    field: &PointLevel<'_>,
    points_body: &[[f64; 2]],
    poses: [Pose2; K],
    sin_cos: [(f64, f64); K],
) -> [f64; K] {
    // The closure inherits this function's AVX2.
    scores_with(field, points_body, poses, sin_cos, |u, v| {
        bilinear_lanes_avx2(field, u, v)
    })
}

/// [`super::bilinear_lanes`] in AVX2: the floors and fractions in vector registers, the
/// two corner pairs of each point gathered (one 8-byte load per row) where its 2x2 block
/// lies inside the field, the mix lane by lane in the scalar order (no fused
/// multiply-add): the same bits. Points near or beyond the edges take
/// [`bilinear_lane`].
#[target_feature(enable = "avx2")]
#[inline]
fn bilinear_lanes_avx2(field: &PointLevel<'_>, u: &[f64; LANES], v: &[f64; LANES]) -> [f64; LANES] {
    use std::arch::x86_64::*;
    let lv = field.cells;
    // SAFETY: unaligned loads of four f64 from arrays of four.
    let (uv, vv) = unsafe { (_mm256_loadu_pd(u.as_ptr()), _mm256_loadu_pd(v.as_ptr())) };
    let (fu, fv) = (_mm256_floor_pd(uv), _mm256_floor_pd(vv));
    // `u - i as f64` with `i` the floor: the floor itself for the lanes inside (below).
    let (au, av) = (_mm256_sub_pd(uv, fu), _mm256_sub_pd(vv, fv));
    // w, h at most 2^14.
    let (w, h) = (field.w as i32, field.h as i32);
    let (i, j, inside) = super::super::block_x86::block_inside(fu, fv, w, h);
    // (A level shorter than `w * h` never happens; it would take the scalar way.)
    let inside_bits = match lv.len() >= field.w * field.h {
        true => _mm_movemask_ps(_mm_castsi128_ps(inside)),
        false => 0,
    };
    let mut out = [0.0f64; LANES];
    if inside_bits != 0 {
        let k = _mm_add_epi32(_mm_mullo_epi32(j, _mm_set1_epi32(w)), i);
        let mask = _mm256_cvtepi32_epi64(inside);
        // SAFETY: only lanes inside are read: `k + 1` and `k + w + 1` are cells of the
        // 2x2 block, below `w * h <= lv.len()`.
        let (row0, row1) = unsafe {
            (
                _mm256_mask_i32gather_epi64::<4>(
                    _mm256_setzero_si256(),
                    lv.as_ptr().cast(),
                    k,
                    mask,
                ),
                _mm256_mask_i32gather_epi64::<4>(
                    _mm256_setzero_si256(),
                    lv.as_ptr().cast(),
                    _mm_add_epi32(k, _mm_set1_epi32(w)),
                    mask,
                ),
            )
        };
        // [a0 b0 a1 b1 a2 b2 a3 b3] -> [a0 a1 a2 a3 | b0 b1 b2 b3], then to f64.
        let pick = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
        let split = |r| {
            let r = _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(r, pick));
            (
                _mm256_cvtps_pd(_mm256_castps256_ps128(r)),
                _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(r)),
            )
        };
        let ((f00, f10), (f01, f11)) = (split(row0), split(row1));
        let one = _mm256_set1_pd(1.0);
        let (nu, nv) = (_mm256_sub_pd(one, au), _mm256_sub_pd(one, av));
        let bottom = _mm256_add_pd(_mm256_mul_pd(f00, nu), _mm256_mul_pd(f10, au));
        let top = _mm256_add_pd(_mm256_mul_pd(f01, nu), _mm256_mul_pd(f11, au));
        let mix = _mm256_add_pd(_mm256_mul_pd(bottom, nv), _mm256_mul_pd(top, av));
        // SAFETY: a store into a local array of four f64.
        unsafe { _mm256_storeu_pd(out.as_mut_ptr(), mix) };
    }
    if inside_bits != 0b1111 {
        for l in 0..LANES {
            if inside_bits >> l & 1 == 0 {
                out[l] = bilinear_lane(field, u[l], v[l]);
            }
        }
    }
    out
}
