//! Height bins: per cell a column of log-odds bins for 3-D returns, projected to one
//! occupancy value; their updates in AVX-512 and SSE4.1 with portable twins.

use super::*;

/// Fixed-point units per log-odds unit in a height bin (`i8`: |log-odds| <= 7.9, p within
/// 0.0004 of 0 or 1; 1/16 resolution). Coarser than the 2-D cells' 1/256, so a column of bins
/// costs one byte per bin; a bin only has to tell "hit at this height" from "passed free".
pub const BIN_SCALE: f64 = 16.0;

/// The log-odds model of a height bin in its fixed point (`i8`, see [`BIN_SCALE`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BinLogOdds {
    /// Hit increment.
    pub hit: i8,
    /// Miss increment.
    pub miss: i8,
    /// Lower clamp bound.
    pub min: i8,
    /// Upper clamp bound.
    pub max: i8,
    /// A bin is occupied at this value.
    pub occupied: i8,
}

impl BinLogOdds {
    /// The bin model of `params`, a bin being occupied at probability `occupied_prob`.
    /// Increments round to at least one unit; clamps and threshold saturate to the `i8` range.
    pub fn new(params: &LogOddsParams, occupied_prob: f64) -> Self {
        let q = |v: f64| (v * BIN_SCALE).round().clamp(-127.0, 127.0) as i8;
        BinLogOdds {
            hit: q(params.hit).max(1),
            miss: q(params.miss).min(-1),
            min: q(params.clamp_min),
            max: q(params.clamp_max),
            occupied: q(crate::map::logodds::logit(occupied_prob)).max(1),
        }
    }

    #[inline(always)]
    pub(super) fn apply(&self, v: i8, delta: i8) -> i8 {
        (v as i16 + delta as i16).clamp(self.min as i16, self.max as i16) as i8
    }
}

/// Most height bins per cell ([`super::HeightOptions::bins`]).
pub const MAX_BINS: usize = 16;

/// The height bins of one tile: one column of [`MAX_BINS`] fixed-point log-odds per cell (same
/// cell order as [`Tile`]; bins beyond the configured count stay 0). A fixed 16-byte column
/// lets the projection run on whole vectors and puts each column in one cache line.
#[derive(Clone)]
pub(super) struct HeightTile {
    pub(super) bins: Vec<[i8; MAX_BINS]>,
}

impl HeightTile {
    pub(super) fn unknown() -> Self {
        HeightTile {
            bins: vec![[0; MAX_BINS]; TILE_CELLS],
        }
    }
}

impl std::fmt::Debug for HeightTile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "HeightTile({} bins)", self.bins.len())
    }
}

/// Per-cell height evidence ([`super::HeightOptions`]): bin `b` covers heights
/// `[z_min + b * w, z_min + (b + 1) * w)`, the first bin extends down and the last up without
/// bound. The cell's 2-D log-odds is the projection of its bins ([`project_bins`]).
#[derive(Clone, Debug)]
pub(super) struct HeightLayer {
    pub(super) bins: usize,
    pub(super) model: BinLogOdds,
    pub(super) z_min_m: f32,
    pub(super) bins_per_m: f32,
    pub(super) dir: TileDir<HeightTile>,
}

impl HeightLayer {
    /// The bit of the bin holding height `z_m`.
    #[inline(always)]
    pub(super) fn bit(&self, z_m: f32) -> u32 {
        // Truncation, not floor (a libm call here): both give bin 0 for everything below the
        // window once clamped. The float -> int conversion saturates; NaN gives 0.
        let b = (((z_m - self.z_min_m) * self.bins_per_m) as i32).clamp(0, self.bins as i32 - 1);
        1 << b
    }

    /// `out[s] = self.bit(z0 + s as f32 * dz)` for every `s`: the bins of a ray's steps, the
    /// same bits as [`Self::bit`] step by step, four steps per vector instruction on x86-64
    /// (the scalar form's saturating conversion and clamps cost ~40 % of a binned ray walk).
    pub(super) fn fill_bits(&self, z0: f32, dz: f32, out: &mut [u32]) {
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: SSE2 is part of the x86-64 baseline.
            let done = unsafe { self.fill_bits_sse2(z0, dz, out) };
            for (s, o) in out.iter_mut().enumerate().skip(done) {
                *o = self.bit(z0 + s as f32 * dz);
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        for (s, o) in out.iter_mut().enumerate() {
            *o = self.bit(z0 + s as f32 * dz);
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl HeightLayer {
    /// [`Self::fill_bits`] of the whole groups of four steps; returns how many steps it did.
    #[target_feature(enable = "sse2")]
    pub(super) fn fill_bits_sse2(&self, z0: f32, dz: f32, out: &mut [u32]) -> usize {
        use std::arch::x86_64::*;
        let top = (self.bins - 1) as f32;
        let (z0v, dzv) = (_mm_set1_ps(z0), _mm_set1_ps(dz));
        let (zminv, bpmv) = (_mm_set1_ps(self.z_min_m), _mm_set1_ps(self.bins_per_m));
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
}

/// The 2-D log-odds (fixed point, 1/256) of a cell from its height bins. When a bin is
/// occupied (`>= model.occupied`) the value is the largest bin, raised to at least
/// `occupied` (the 2-D occupied threshold): the cell is occupied. Otherwise it is the smallest
/// observed (non-zero) bin — free when some height was passed free often enough — and 0
/// (unknown) when no bin is observed. So a cell seen occupied at one height and passed free
/// at another stays occupied, whatever the order of the scans.
///
/// Computed on the bins biased to `u8` (`v ^ 0x80` keeps the order of `i8`), whose min and
/// max are SSE2 instructions: a whole 16-bin column is a few vector instructions.
#[inline(always)]
pub fn project_bins(bins: &[i8], model: &BinLogOdds, occupied: i16) -> i16 {
    let (mut lo, mut hi) = (u8::MAX, 0u8);
    for &v in bins {
        let u = (v as u8) ^ 0x80;
        // Unobserved bins (0) must not count: as the low one they would hide free space.
        lo = lo.min(if v == 0 { u8::MAX } else { u });
        hi = hi.max(u);
    }
    let (lo, hi) = ((lo ^ 0x80) as i8, (hi ^ 0x80) as i8);
    let scale = (crate::map::logodds::LOGODDS_SCALE / BIN_SCALE) as i16;
    if hi >= model.occupied {
        (hi as i16 * scale).max(occupied)
    } else if lo == i8::MAX {
        0
    } else {
        lo as i16 * scale
    }
}

/// One scan's update of a cell's height bins (`marks`: bins passed free in the low 16 bits,
/// bins hit in the high 16; hit wins), then the cell's 2-D value re-projected.
#[inline(always)]
pub(super) fn apply_bin_marks(
    cell: &mut i16,
    bins: &mut [i8; MAX_BINS],
    marks: u32,
    model: &BinLogOdds,
    occupied: i16,
) {
    update_bins(bins, marks, model);
    *cell = project_column(bins, model, occupied);
}

/// [`project_bins`] of a whole column (a fixed length: vectorised).
#[inline(always)]
pub(super) fn project_column(bins: &[i8; MAX_BINS], model: &BinLogOdds, occupied: i16) -> i16 {
    project_bins(bins, model, occupied)
}

/// The bins' part of [`apply_bin_marks`] (the cell's projection left to the caller).
#[inline(always)]
pub(super) fn update_bins(bins: &mut [i8; MAX_BINS], marks: u32, model: &BinLogOdds) {
    let (occ, free) = (marks >> 16, marks & 0xffff);
    let mut todo = occ | free;
    while todo != 0 {
        let b = todo.trailing_zeros();
        todo &= todo - 1;
        let v = &mut bins[b as usize];
        let d = if occ >> b & 1 == 1 {
            model.hit
        } else {
            model.miss
        };
        *v = model.apply(*v, d);
    }
}

/// [`update_bins`] with the bins of a column updated as one vector when the CPU has
/// AVX-512BW/VL (mask registers select the hit, missed and untouched bins): no loop over the
/// marks' bits, no mispredicted branch per bin, and the columns' loads do not wait on each
/// other. The same values: a saturating `i8` add then the clamp equals the `i16` add then the
/// clamp, the bounds being within `i8` and `min <= max`.
/// Without AVX-512, SSE4.1 does the same with 16-byte vectors (the masks expanded to bytes).
#[derive(Clone, Copy)]
pub(super) struct BinUpdater {
    #[cfg(target_arch = "x86_64")]
    avx512: bool,
    #[cfg(target_arch = "x86_64")]
    sse41: bool,
}

impl BinUpdater {
    pub(super) fn new(model: &BinLogOdds) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            BinUpdater {
                avx512: model.min <= model.max
                    && std::arch::is_x86_feature_detected!("avx512bw")
                    && std::arch::is_x86_feature_detected!("avx512vl"),
                sse41: model.min <= model.max && std::arch::is_x86_feature_detected!("sse4.1"),
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = model;
            BinUpdater {}
        }
    }

    /// [`update_bins`] of `bins[updates[i]]` with `marks[i]` (the cell's index in the low 12
    /// bits of the update), each such cell flagged in `stale`.
    #[inline(always)]
    pub(super) fn run(
        &self,
        bins: &mut [[i8; MAX_BINS]],
        stale: &mut [bool; TILE_CELLS],
        updates: &[u16],
        marks: &[u32],
        model: &BinLogOdds,
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.avx512 {
            // SAFETY: the CPU has AVX-512BW and AVX-512VL (checked in `new`).
            unsafe { update_bin_run_avx512(bins, stale, updates, marks, model) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.sse41 {
            // SAFETY: the CPU has SSE4.1 (checked in `new`).
            unsafe { update_bin_run_sse41(bins, stale, updates, marks, model) };
            return;
        }
        for (&u, &m) in updates.iter().zip(marks) {
            let local = usize::from(u) & (TILE_CELLS - 1);
            update_bins(&mut bins[local], m, model);
            stale[local] = true;
        }
    }

    /// [`update_bins`]`(bins, marks, model)`.
    #[inline(always)]
    pub(super) fn update(&self, bins: &mut [i8; MAX_BINS], marks: u32, model: &BinLogOdds) {
        #[cfg(target_arch = "x86_64")]
        if self.avx512 {
            // SAFETY: the CPU has AVX-512BW and AVX-512VL (checked in `new`).
            unsafe { update_bins_avx512(bins, marks, model) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.sse41 {
            // SAFETY: the CPU has SSE4.1 (checked in `new`).
            unsafe { update_bins_sse41(bins, marks, model) };
            return;
        }
        update_bins(bins, marks, model);
    }
}

/// [`BinUpdater::run`] with AVX-512 (one function: the per-cell update inlines).
#[cfg(target_arch = "x86_64")]
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

/// [`update_bins`] as one 16-lane vector operation (see [`BinUpdater`]).
// `update_bins_avx512` loads and stores a column as one 16-byte vector.
const _: () = assert!(MAX_BINS == 16);

#[cfg(target_arch = "x86_64")]
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

/// [`BinUpdater::run`] with SSE4.1 (one function: the per-cell update inlines).
#[cfg(target_arch = "x86_64")]
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

/// [`update_bins`] as one 16-byte vector operation with SSE4.1 (see [`BinUpdater`]): each
/// 16-bit mask expanded to one byte per bin (bits 0-7 to lanes 0-7, 8-15 to lanes 8-15).
#[cfg(target_arch = "x86_64")]
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
