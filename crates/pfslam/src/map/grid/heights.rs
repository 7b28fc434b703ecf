//! Height bins: per cell a column of log-odds bins for 3-D returns, projected to one
//! occupancy value (their updates' kernels in `crate::kernels::heights`).

use super::*;
use crate::kernels::heights::{BinScale, update_bins};

/// Fixed-point units per log-odds unit in a height bin (`i8`: |log-odds| <= 7.9, p within
/// 0.0004 of 0 or 1; 1/16 resolution). Coarser than the 2-D cells' 1/256, so a column of bins
/// costs one byte per bin; a bin only has to tell "hit at this height" from "passed free".
pub const BIN_SCALE: f64 = 16.0;

/// The log-odds model of a height bin, defined with the bins' kernels (which apply it).
pub use crate::kernels::heights::BinLogOdds;

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
}

/// Most height bins per cell ([`crate::map::HeightOptions::bins`]), defined with the bins'
/// kernels.
pub use crate::kernels::MAX_BINS;

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
pub(crate) struct HeightLayer {
    pub(crate) bins: usize,
    pub(super) model: BinLogOdds,
    pub(crate) z_min_m: f32,
    pub(crate) bins_per_m: f32,
    pub(super) dir: TileDir<HeightTile>,
}

impl HeightLayer {
    /// The bit of the bin holding height `z_m`.
    #[inline(always)]
    pub(crate) fn bit(&self, z_m: f32) -> u32 {
        self.scale().bit(z_m)
    }

    /// The bins' heights as the kernels read them.
    #[inline(always)]
    pub(crate) fn scale(&self) -> BinScale {
        BinScale {
            bins: self.bins,
            z_min_m: self.z_min_m,
            bins_per_m: self.bins_per_m,
        }
    }

    /// `out[s] = self.bit(z0 + s as f32 * dz)` for every `s`: the bins of a ray's steps
    /// (the kernel in `crate::kernels::heights`).
    pub(super) fn fill_bits(&self, z0: f32, dz: f32, out: &mut [u32]) {
        crate::kernels::heights::fill_bits(&self.scale(), z0, dz, out);
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
