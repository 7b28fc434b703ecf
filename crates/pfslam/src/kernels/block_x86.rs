//! What the AVX2 bilinear kernels (`field_score`, `field_loglik`) share: which of four
//! points' 2x2 blocks of cells lie inside a raster.

use std::arch::x86_64::*;

/// The floors `fu`, `fv` of four points' cell coordinates as i32 lanes `(i, j)`, and the
/// mask of the lanes with `i >= 0 && j >= 0 && i + 1 < w && j + 1 < h`. The conversion is
/// exact inside the i32 range; beyond it, and for NaN, it gives i32::MIN, which the test
/// puts outside.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn block_inside(
    fu: __m256d,
    fv: __m256d,
    w: i32,
    h: i32,
) -> (__m128i, __m128i, __m128i) {
    let (i, j) = (_mm256_cvttpd_epi32(fu), _mm256_cvttpd_epi32(fv));
    let minus_one = _mm_set1_epi32(-1);
    let inside = _mm_and_si128(
        _mm_and_si128(_mm_cmpgt_epi32(i, minus_one), _mm_cmpgt_epi32(j, minus_one)),
        _mm_and_si128(
            _mm_cmpgt_epi32(_mm_set1_epi32(w - 1), i),
            _mm_cmpgt_epi32(_mm_set1_epi32(h - 1), j),
        ),
    );
    (i, j, inside)
}
