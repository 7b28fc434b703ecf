//! The scan-matching coarse search's kernels: per yaw, the window index of every point
//! ([`CoarseYaw::bases`]) and the field sums of every whole-cell x/y offset at once
//! ([`coarse_sums`] and its variants); the AVX2 kernels in `x86.rs`.

use super::{FieldWindow, LANES};
use crate::geometry::Pose2;
use crate::geometry::cells::{Cell, MapLimits};

#[cfg(target_arch = "x86_64")]
mod x86;

/// Adds, for every base index `b`, the `S x S` block of `values` (row stride `w`) at `b` to
/// `sums` (row-major, `S * S`). u16 accumulators over blocks of at most 257 points
/// (257 * 255 < 65536), flushed into the u32 sums: exact integer sums.
pub fn coarse_sums<const S: usize>(values: &[u8], w: usize, base: &[usize], sums: &mut [u32]) {
    for block in base.chunks(257) {
        let mut acc = [[0u16; S]; S];
        for &b in block {
            for (oy, acc_row) in acc.iter_mut().enumerate() {
                if let Some(row) = values[b + oy * w..].first_chunk::<S>() {
                    for (a, &v) in acc_row.iter_mut().zip(row) {
                        *a += u16::from(v);
                    }
                }
            }
        }
        for (sum_row, acc_row) in sums.chunks_exact_mut(S).zip(&acc) {
            for (s, &a) in sum_row.iter_mut().zip(acc_row) {
                *s += u32::from(a);
            }
        }
    }
}

/// [`coarse_sums`] for sides up to 8, in SWAR: each row of the block is one 8-byte load
/// (the field keeps 8 spare bytes after its last cell), split into even and odd bytes as four
/// u16 lanes each and added to two u64 accumulators per row. Lanes cannot carry into each
/// other within blocks of 257 points (257 * 255 = 65535); lanes beyond `S` hold bytes right
/// of the block and are ignored.
pub fn coarse_sums_swar<const S: usize>(values: &[u8], w: usize, base: &[usize], sums: &mut [u32]) {
    const EVEN: u64 = 0x00ff_00ff_00ff_00ff;
    for block in base.chunks(257) {
        let mut even = [0u64; S];
        let mut odd = [0u64; S];
        for &b in block {
            for oy in 0..S {
                let Some(bytes) = values[b + oy * w..].first_chunk::<8>() else {
                    continue;
                };
                let x = u64::from_le_bytes(*bytes);
                even[oy] = even[oy].wrapping_add(x & EVEN);
                odd[oy] = odd[oy].wrapping_add((x >> 8) & EVEN);
            }
        }
        for (oy, sum_row) in sums.chunks_exact_mut(S).enumerate() {
            for (ox, s) in sum_row.iter_mut().enumerate() {
                let lanes = if ox % 2 == 0 { even[oy] } else { odd[oy] };
                *s += ((lanes >> (16 * (ox / 2))) & 0xffff) as u32;
            }
        }
    }
}

/// [`coarse_sums_swar`], in AVX2 when the CPU has it.
pub fn coarse_sums_fast<const S: usize>(values: &[u8], w: usize, base: &[usize], sums: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return unsafe { x86::coarse_sums_avx2::<S>(values, w, base, sums) };
    }
    coarse_sums_swar::<S>(values, w, base, sums)
}

/// [`coarse_sums`] for any side.
pub fn coarse_sums_any(values: &[u8], w: usize, side: usize, base: &[usize], sums: &mut [u32]) {
    for &b in base {
        for (oy, sum_row) in sums.chunks_exact_mut(side).enumerate() {
            let row = &values[b + oy * w..][..side];
            for (acc, &v) in sum_row.iter_mut().zip(row) {
                *acc += u32::from(v);
            }
        }
    }
}

/// One yaw of the coarse search: the field, the predicted pose, the yaw's sine and cosine
/// and the search's half-width `r` (cells).
#[derive(Clone, Copy)]
pub struct CoarseYaw<'a> {
    pub field: FieldWindow<'a>,
    pub limits: &'a MapLimits,
    pub predicted: &'a Pose2,
    pub sin_cos: (f64, f64),
    pub r: i32,
}

impl CoarseYaw<'_> {
    /// The window indices: per point seen from `predicted` at this yaw, the index of the
    /// lower-left cell of its `2r+1` block of offsets, if the whole block lies in the window
    /// (else the point is left out), in point order (into `base`, cleared first).
    pub fn bases(&self, points_body: &[[f64; 2]], base: &mut Vec<usize>) {
        base.clear();
        #[cfg(target_arch = "x86_64")]
        if self.field.vector_ok() && super::cpu().avx2() {
            // SAFETY: the CPU has AVX2 (`cpu` detected it) and the field is `vector_ok`.
            unsafe { self.bases_avx2(points_body, base) };
            let tail = points_body.chunks_exact(LANES).remainder();
            self.bases_portable(tail, base);
            return;
        }
        self.bases_portable(points_body, base);
    }

    /// [`CoarseYaw::bases`] a point at a time (the arithmetic of four points vectorises).
    pub fn bases_portable(&self, points_body: &[[f64; 2]], base: &mut Vec<usize>) {
        let CoarseYaw {
            field,
            limits,
            predicted,
            sin_cos: (s, c),
            r,
        } = *self;
        let (w, h) = (field.w as i32, field.h as i32);
        let mut push = |cell: Cell| {
            let (li, lj) = (cell.i - field.i0, cell.j - field.j0);
            if li >= r && lj >= r && li < w - r && lj < h - r {
                base.push((lj - r) as usize * field.w + (li - r) as usize);
            }
        };
        let cell_of = |p: &[f64; 2]| {
            let x = predicted.x_m + c * p[0] - s * p[1];
            let y = predicted.y_m + s * p[0] + c * p[1];
            limits.cell_of(x, y)
        };
        // Cells of four points at a time (the arithmetic vectorises), then kept in order.
        let mut chunks = points_body.chunks_exact(LANES);
        for quad in &mut chunks {
            let mut cells = [Cell::new(0, 0); LANES];
            for (cell, p) in cells.iter_mut().zip(quad) {
                *cell = cell_of(p);
            }
            cells.into_iter().for_each(&mut push);
        }
        chunks.remainder().iter().map(cell_of).for_each(push);
    }
}
