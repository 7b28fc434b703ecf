//! The height bins' vector kernels: a ray's bins in SSE2, a column's update in AVX-512BW/VL
//! and in SSE4.1.

use super::{BinLogOdds, BinScale};
use crate::kernels::{MAX_BINS, TILE_CELLS};

/// [`super::fill_bits`] of the whole groups of four steps; returns how many steps it did.
#[target_feature(enable = "sse2")]
pub(super) fn fill_bits_sse2(layer: &BinScale, z0: f32, dz: f32, out: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let top = (layer.bins - 1) as f32;
    let (z0v, dzv) = (_mm_set1_ps(z0), _mm_set1_ps(dz));
    let (zminv, bpmv) = (_mm_set1_ps(layer.z_min_m), _mm_set1_ps(layer.bins_per_m));
    let (zero, topv) = (_mm_setzero_ps(), _mm_set1_ps(top));
    let mut steps = _mm_setr_epi32(0, 1, 2, 3);
    let whole = out.len() & !3;
    let mut chunks = out[..whole].chunks_exact_mut(4);
    for chunk in &mut chunks {
        // The same operations in the same order as `bit` (exact: steps < 2^24).
        let z = _mm_add_ps(z0v, _mm_mul_ps(_mm_cvtepi32_ps(steps), dzv));
        let v = _mm_mul_ps(_mm_sub_ps(z, zminv), bpmv);
        // max(v, 0) gives 0 for NaN (its second operand), as the saturating cast does.
        // Clamping before truncating equals truncating then clamping to 0..=top.
        let v = _mm_min_ps(_mm_max_ps(v, zero), topv);
        let b = _mm_cvttps_epi32(v);
        // 1 << b as the float 2^b converted back to an integer (exact for b <= 15).
        let bit = _mm_cvttps_epi32(_mm_castsi128_ps(_mm_slli_epi32(
            _mm_add_epi32(b, _mm_set1_epi32(127)),
            23,
        )));
        // SAFETY: `chunk` is 4 `u32`s (16 bytes); `storeu` needs no alignment.
        unsafe { _mm_storeu_si128(chunk.as_mut_ptr().cast::<__m128i>(), bit) };
        steps = _mm_add_epi32(steps, _mm_set1_epi32(4));
    }
    whole
}

/// [`super::BinUpdater::run`] with AVX-512 (one function: the per-cell update inlines).
#[target_feature(enable = "avx512bw,avx512vl")]
pub(super) fn update_bin_run_avx512(
    bins: &mut [[i8; MAX_BINS]],
    stale: &mut [bool; TILE_CELLS],
    updates: &[u16],
    marks: &[u32],
    model: &BinLogOdds,
) {
    for (&u, &m) in updates.iter().zip(marks) {
        let local = usize::from(u) & (TILE_CELLS - 1);
        update_bins_avx512(&mut bins[local], m, model);
        stale[local] = true;
    }
}

// `update_bins_avx512` loads and stores a column as one 16-byte vector.
const _: () = assert!(MAX_BINS == 16);

/// [`super::update_bins`] as one 16-lane vector operation (see [`super::BinUpdater`]).
#[target_feature(enable = "avx512bw,avx512vl")]
#[inline]
pub(super) fn update_bins_avx512(bins: &mut [i8; MAX_BINS], marks: u32, model: &BinLogOdds) {
    use std::arch::x86_64::*;
    let (occ, touched) = ((marks >> 16) as u16, (marks | marks >> 16) as u16);
    // SAFETY: `bins` is 16 bytes; unaligned loads and stores are allowed.
    let v = unsafe { _mm_loadu_si128(bins.as_ptr().cast::<__m128i>()) };
    let d = _mm_mask_blend_epi8(occ, _mm_set1_epi8(model.miss), _mm_set1_epi8(model.hit));
    let s = _mm_adds_epi8(v, d);
    let s = _mm_min_epi8(
        _mm_max_epi8(s, _mm_set1_epi8(model.min)),
        _mm_set1_epi8(model.max),
    );
    let v = _mm_mask_mov_epi8(v, touched, s);
    // SAFETY: as the load.
    unsafe { _mm_storeu_si128(bins.as_mut_ptr().cast::<__m128i>(), v) };
}

/// [`super::BinUpdater::run`] with SSE4.1 (one function: the per-cell update inlines).
#[target_feature(enable = "sse4.1")]
pub(super) fn update_bin_run_sse41(
    bins: &mut [[i8; MAX_BINS]],
    stale: &mut [bool; TILE_CELLS],
    updates: &[u16],
    marks: &[u32],
    model: &BinLogOdds,
) {
    for (&u, &m) in updates.iter().zip(marks) {
        let local = usize::from(u) & (TILE_CELLS - 1);
        update_bins_sse41(&mut bins[local], m, model);
        stale[local] = true;
    }
}

/// [`super::update_bins`] as one 16-byte vector operation with SSE4.1 (see
/// [`super::BinUpdater`]): each
/// 16-bit mask expanded to one byte per bin (bits 0-7 to lanes 0-7, 8-15 to lanes 8-15).
#[target_feature(enable = "sse4.1")]
#[inline]
pub(super) fn update_bins_sse41(bins: &mut [i8; MAX_BINS], marks: u32, model: &BinLogOdds) {
    use std::arch::x86_64::*;
    let bit = _mm_setr_epi8(1, 2, 4, 8, 16, 32, 64, -128, 1, 2, 4, 8, 16, 32, 64, -128);
    let halves = _mm_setr_epi8(0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1);
    let expand = |m: u16| {
        let v = _mm_shuffle_epi8(_mm_set1_epi16(m as i16), halves);
        _mm_cmpeq_epi8(_mm_and_si128(v, bit), bit)
    };
    let (occ, touched) = (
        expand((marks >> 16) as u16),
        expand((marks | marks >> 16) as u16),
    );
    // SAFETY: `bins` is 16 bytes; unaligned loads and stores are allowed.
    let v = unsafe { _mm_loadu_si128(bins.as_ptr().cast::<__m128i>()) };
    let d = _mm_blendv_epi8(_mm_set1_epi8(model.miss), _mm_set1_epi8(model.hit), occ);
    let s = _mm_adds_epi8(v, d);
    let s = _mm_min_epi8(
        _mm_max_epi8(s, _mm_set1_epi8(model.min)),
        _mm_set1_epi8(model.max),
    );
    let v = _mm_blendv_epi8(v, s, touched);
    // SAFETY: as the load.
    unsafe { _mm_storeu_si128(bins.as_mut_ptr().cast::<__m128i>(), v) };
}
