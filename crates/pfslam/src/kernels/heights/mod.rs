//! The grid's height-bin kernels: a ray's bins ([`fill_bits`], SSE2) and a column's bin
//! updates ([`BinUpdater`]: AVX-512BW/VL, else SSE4.1, else [`update_bins`]); the vector
//! code in `x86.rs`.

use super::{MAX_BINS, TILE_CELLS};

#[cfg(target_arch = "x86_64")]
mod x86;

/// The log-odds model of a height bin in its fixed point (`i8`; `BIN_SCALE` units per log-odds unit in `map`, which builds it).
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
    /// `v + delta`, clamped to `min..=max`.
    #[inline(always)]
    pub(crate) fn apply(&self, v: i8, delta: i8) -> i8 {
        (v as i16 + delta as i16).clamp(self.min as i16, self.max as i16) as i8
    }
}

/// The heights of a cell's bins: bin `b` covers `[z_min + b / bins_per_m, z_min + (b + 1) /
/// bins_per_m)`, the first bin extending down and the last up without bound.
#[derive(Clone, Copy, Debug)]
pub struct BinScale {
    /// Bins in use (1..=[`MAX_BINS`]).
    pub bins: usize,
    /// Bottom of bin 0 (m).
    pub z_min_m: f32,
    /// Bins per metre.
    pub bins_per_m: f32,
}

impl BinScale {
    /// The bit of the bin holding height `z_m`.
    #[inline(always)]
    pub fn bit(&self, z_m: f32) -> u32 {
        // Truncation, not floor (a libm call here): both give bin 0 for everything below the
        // window once clamped. The float -> int conversion saturates; NaN gives 0.
        let b = (((z_m - self.z_min_m) * self.bins_per_m) as i32).clamp(0, self.bins as i32 - 1);
        1 << b
    }
}

/// `out[s] = layer.bit(z0 + s as f32 * dz)` for every `s`: the bins of a ray's steps, the
/// same bits as [`BinScale::bit`] step by step, four steps per vector instruction on
/// x86-64 (the scalar form's saturating conversion and clamps cost ~40 % of a binned ray
/// walk).
pub fn fill_bits(layer: &BinScale, z0: f32, dz: f32, out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: SSE2 is part of the x86-64 baseline: every x86-64 CPU has it.
        let done = unsafe { x86::fill_bits_sse2(layer, z0, dz, out) };
        fill_bits_from(layer, z0, dz, out, done);
    }
    #[cfg(not(target_arch = "x86_64"))]
    fill_bits_portable(layer, z0, dz, out);
}

/// [`fill_bits`] a step at a time: the portable twin.
#[cfg(any(test, not(target_arch = "x86_64")))]
pub fn fill_bits_portable(layer: &BinScale, z0: f32, dz: f32, out: &mut [u32]) {
    fill_bits_from(layer, z0, dz, out, 0);
}

/// [`fill_bits`] of the steps from `start` on, a step at a time.
#[inline(always)]
fn fill_bits_from(layer: &BinScale, z0: f32, dz: f32, out: &mut [u32], start: usize) {
    for (s, o) in out.iter_mut().enumerate().skip(start) {
        *o = layer.bit(z0 + s as f32 * dz);
    }
}

/// One scan's update of a column of height bins (`marks`: bins passed free in the low 16
/// bits, bins hit in the high 16; hit wins), a bin at a time: the rule, and the portable
/// twin of [`BinUpdater`].
#[inline(always)]
pub fn update_bins(bins: &mut [i8; MAX_BINS], marks: u32, model: &BinLogOdds) {
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
pub struct BinUpdater {
    #[cfg(target_arch = "x86_64")]
    avx512: bool,
    #[cfg(target_arch = "x86_64")]
    sse41: bool,
}

impl BinUpdater {
    pub fn new(model: &BinLogOdds) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            BinUpdater {
                avx512: model.min <= model.max && super::cpu().avx512bw_vl(),
                sse41: model.min <= model.max && super::cpu().sse41(),
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = model;
            BinUpdater {}
        }
    }

    /// The SSE4.1 updater even where the CPU has AVX-512 (its test forces that path): none
    /// without SSE4.1 or with `model.min > model.max`.
    #[cfg(test)]
    pub fn sse41_only(model: &BinLogOdds) -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if model.min <= model.max && super::cpu().sse41() {
            return Some(BinUpdater {
                avx512: false,
                sse41: true,
            });
        }
        let _ = model;
        None
    }

    /// [`update_bins`] of `bins[updates[i]]` with `marks[i]` (the cell's index in the low 12
    /// bits of the update), each such cell flagged in `stale`.
    #[inline(always)]
    pub fn run(
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
            unsafe { x86::update_bin_run_avx512(bins, stale, updates, marks, model) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.sse41 {
            // SAFETY: the CPU has SSE4.1 (checked in `new`).
            unsafe { x86::update_bin_run_sse41(bins, stale, updates, marks, model) };
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
    pub fn update(&self, bins: &mut [i8; MAX_BINS], marks: u32, model: &BinLogOdds) {
        #[cfg(target_arch = "x86_64")]
        if self.avx512 {
            // SAFETY: the CPU has AVX-512BW and AVX-512VL (checked in `new`).
            unsafe { x86::update_bins_avx512(bins, marks, model) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.sse41 {
            // SAFETY: the CPU has SSE4.1 (checked in `new`).
            unsafe { x86::update_bins_sse41(bins, marks, model) };
            return;
        }
        update_bins(bins, marks, model);
    }
}
