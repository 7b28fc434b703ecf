//! The vector kernels: every loop written with x86-64 intrinsics, each beside the portable
//! twin that gives the same bits, and the CPU's features, detected once.
//!
//! The rule: `unsafe` code lives here and nowhere else in the crate (`#![deny(unsafe_code)]`
//! at the crate root, allowed on this module only). One folder per kernel family:
//! `<family>/mod.rs` holds the safe entry points the domain code calls, which choose the
//! vector path from [`cpu`], and the portable twin (also public, so that tests can force
//! it); `<family>/x86.rs` holds the `#[target_feature]` functions and their intrinsics.
//! Every `unsafe` block says why it is sound in a `// SAFETY:` comment. Every vector
//! kernel has a test that compares it with its twin bit for bit
//! (docs/decisions/0011-vector-kernels-with-portable-twins.md).
//!
//! The families:
//! - `likelihood` and `nearest`: the `rbpf` observation model (a scan's log-likelihood
//!   in a particle's grid, the 3x3 nearest occupied cell);
//! - `coarse`: the scan-matching coarse search (window indices, block sums);
//! - `rotation` and `rotation_f32`: the scan-matching refinement's field sums;
//! - `cell_sum` and `field_score`: the back end's point field (exact cell sums, the
//!   interpolated score);
//! - `field_loglik`: localisation's scan log-likelihood in its f32 field, four poses at a
//!   time;
//! - `heights` and `mask`: the grid's height bins and ray walk;
//! - `allocator`: a setting of the C library's allocator for long runs.
//!
//! The layering: the kernels sit below the modules whose data they walk (`matching`,
//! `localize`, `map`) and use nothing of the crate but `geometry` (poses, cells, the
//! world <-> cell frame). They take plain slices and small `Copy` views defined here
//! (`FieldWindow` of the scan matcher's likelihood field, `PointLevel` of the back end's
//! point field, the families' own parameter structs) or, for the particle grid's tile
//! directory, the `likelihood::TileGrid` trait; the owning modules build these and call the
//! kernels. The constants both sides must agree on (the tile layout, the height bins, the
//! lanes of the interpolations) are defined here once and re-exported by their owners.

use std::sync::OnceLock;

mod views;

pub mod allocator;

#[cfg(target_arch = "x86_64")]
mod block_x86;

pub use views::F32_LIM;
pub(crate) use views::{FieldWindow, PointLevel};

pub(crate) mod cell_sum;
pub(crate) mod coarse;
pub(crate) mod field_loglik;
pub(crate) mod field_score;
pub(crate) mod heights;
pub(crate) mod likelihood;
pub(crate) mod mask;
pub(crate) mod nearest;
pub(crate) mod rotation;
pub(crate) mod rotation_f32;

/// log2 of a grid tile's side.
pub const TILE_SHIFT: u32 = 6;
/// Tile side (cells).
pub const TILE_SIZE: usize = 1 << TILE_SHIFT;
/// A cell index's place within its tile (`i & TILE_MASK`).
pub const TILE_MASK: i32 = (TILE_SIZE as i32) - 1;
/// Cells of one tile.
pub const TILE_CELLS: usize = TILE_SIZE * TILE_SIZE;

/// Most height bins per cell (one 16-byte column, one vector).
pub const MAX_BINS: usize = 16;

/// Points per batch of the f64 interpolations (the scan matcher's refinement and the back
/// end's matcher).
pub const LANES: usize = 4;

/// Zero bytes kept after a likelihood field's cells (never read as cells): the coarse sums'
/// 8-byte row loads may run past the last cell.
pub const FIELD_PAD: usize = 8;

/// The bilinear mix per lane of corners `[f00, f10, f01, f11]` at fractions `(ax, ay)`, in
/// the order of the scalar interpolations (so the same bits).
#[inline(always)]
pub fn mix_lanes(f: &[[f64; 4]; LANES], ax: &[f64; LANES], ay: &[f64; LANES]) -> [f64; LANES] {
    let mut out = [0.0; LANES];
    for k in 0..LANES {
        let [f00, f10, f01, f11] = f[k];
        let bottom = f00 * (1.0 - ax[k]) + f10 * ax[k];
        let top = f01 * (1.0 - ax[k]) + f11 * ax[k];
        out[k] = bottom * (1.0 - ay[k]) + top * ay[k];
    }
    out
}

/// The instruction-set extensions the kernels use, as this CPU (and its operating system)
/// supports them. Only [`cpu`] makes one: a kernel's `unsafe` call relies on a feature being
/// reported only where it is present. Everything is false off x86-64.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cpu {
    avx2: bool,
    sse41: bool,
    avx512bw: bool,
    avx512vl: bool,
    bmi1: bool,
    lzcnt: bool,
    popcnt: bool,
}

impl Cpu {
    #[cfg(target_arch = "x86_64")]
    fn detect() -> Self {
        Cpu {
            avx2: std::arch::is_x86_feature_detected!("avx2"),
            sse41: std::arch::is_x86_feature_detected!("sse4.1"),
            avx512bw: std::arch::is_x86_feature_detected!("avx512bw"),
            avx512vl: std::arch::is_x86_feature_detected!("avx512vl"),
            bmi1: std::arch::is_x86_feature_detected!("bmi1"),
            lzcnt: std::arch::is_x86_feature_detected!("lzcnt"),
            popcnt: std::arch::is_x86_feature_detected!("popcnt"),
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    fn detect() -> Self {
        Cpu {
            avx2: false,
            sse41: false,
            avx512bw: false,
            avx512vl: false,
            bmi1: false,
            lzcnt: false,
            popcnt: false,
        }
    }

    /// AVX2 (256-bit integer vectors, gathers).
    pub fn avx2(&self) -> bool {
        self.avx2
    }

    /// SSE4.1.
    pub fn sse41(&self) -> bool {
        self.sse41
    }

    /// AVX-512BW and AVX-512VL together (byte lanes with mask registers on 128-bit vectors).
    pub fn avx512bw_vl(&self) -> bool {
        self.avx512bw && self.avx512vl
    }

    /// AVX2 with BMI1, LZCNT and POPCNT: what the LiDAR rows' vector parser in `pfslam-io`
    /// needs.
    pub fn avx2_bit_ops(&self) -> bool {
        self.avx2 && self.bmi1 && self.lzcnt && self.popcnt
    }
}

/// This CPU's features, detected on the first call and kept: every kernel's dispatch reads
/// them here.
pub fn cpu() -> &'static Cpu {
    static CPU: OnceLock<Cpu> = OnceLock::new();
    CPU.get_or_init(Cpu::detect)
}

#[cfg(test)]
mod tests {
    #[test]
    fn features_are_detected_once_and_consistently() {
        let first = super::cpu();
        assert!(std::ptr::eq(first, super::cpu()));
        // The parser's set includes AVX2.
        assert!(!first.avx2_bit_ops() || first.avx2());
        #[cfg(not(target_arch = "x86_64"))]
        assert!(!first.avx2() && !first.sse41() && !first.avx512bw_vl());
    }
}
