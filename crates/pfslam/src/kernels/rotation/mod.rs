//! The scan-matching refinement's f64 kernel: a scan rotated for one yaw ([`Rotation`]) and
//! its bilinear field sums seen from up to six positions in one pass; the AVX2 kernel in
//! `x86.rs`.

use super::{FieldWindow, LANES};
use crate::geometry::cells::MapLimits;

#[cfg(target_arch = "x86_64")]
pub(super) mod x86;

/// Body-frame points rotated by one yaw: `(c x, s y, s x, c y)` per point, whole blocks of
/// [`LANES`] points lane-wise (so a vector kernel loads each product of a block at once),
/// the last `n % LANES` points apart.
#[derive(Debug, Clone, Default)]
pub struct Rotation {
    blocks: Vec<[[f64; LANES]; 4]>,
    tail: Vec<[f64; 4]>,
}

impl Rotation {
    /// Rotates `points_body` by the yaw of sine `s` and cosine `c`.
    pub fn fill(&mut self, points_body: &[[f64; 2]], s: f64, c: f64) {
        let rot = |p: &[f64; 2]| [c * p[0], s * p[1], s * p[0], c * p[1]];
        let chunks = points_body.chunks_exact(LANES);
        self.tail.clear();
        self.tail.extend(chunks.remainder().iter().map(rot));
        self.blocks.clear();
        self.blocks.extend(chunks.map(|quad| {
            let mut b = [[0.0; LANES]; 4];
            for (k, p) in quad.iter().enumerate() {
                for (lane, r) in b.iter_mut().zip(rot(p)) {
                    lane[k] = r;
                }
            }
            b
        }));
    }

    /// Sums of bilinear field values of the points seen from `at[k]` (x m, y m) with the
    /// rotation `rots[k]`, `K` candidates in one pass over the points: per point
    /// `x_m + c * p[0] - s * p[1]` evaluated left to right as written, then `cell_coords`
    /// and `bilinear`; summed left to right from -0.0 (as `Iterator::sum`). Each candidate
    /// has its own accumulator and adds its own values in its own order, so each result is
    /// the bits of the candidate summed alone (`K = 1`); the independent chains of
    /// additions can overlap. The rotations hold the same points (of different yaws, or one
    /// rotation repeated).
    pub fn sums<const K: usize>(
        rots: [&Rotation; K],
        at: [[f64; 2]; K],
        field: &FieldWindow<'_>,
        limits: &MapLimits,
    ) -> [f64; K] {
        #[cfg(target_arch = "x86_64")]
        if field.vector_ok() && super::cpu().avx2() {
            // SAFETY: the CPU has AVX2 (`cpu` detected it) and the field is `vector_ok`.
            return unsafe { Rotation::sums_avx2(rots, at, field, limits) };
        }
        Rotation::sums_portable(rots, at, field, limits)
    }

    /// Whole blocks every rotation of a batch has (all the same: they rotate the same
    /// points; the minimum keeps a mismatch from indexing out of bounds).
    pub fn common_blocks(rots: &[&Rotation]) -> usize {
        debug_assert!(rots.iter().all(|r| {
            r.blocks.len() == rots[0].blocks.len() && r.tail.len() == rots[0].tail.len()
        }));
        rots.iter().map(|r| r.blocks.len()).min().unwrap_or(0)
    }

    /// [`Self::sums`] without vector instructions: the portable twin.
    pub fn sums_portable<const K: usize>(
        rots: [&Rotation; K],
        at: [[f64; 2]; K],
        field: &FieldWindow<'_>,
        limits: &MapLimits,
    ) -> [f64; K] {
        let mut sums = [-0.0; K];
        let mut values = [[0.0; LANES]; K];
        for b in 0..Rotation::common_blocks(&rots) {
            for k in 0..K {
                let [r0, r1, r2, r3] = &rots[k].blocks[b];
                let [x_m, y_m] = at[k];
                // Per lane the same operations in the same order as `sum_tail`.
                let mut u = [0.0; LANES];
                let mut v = [0.0; LANES];
                for l in 0..LANES {
                    (u[l], v[l]) = limits.cell_coords(x_m + r0[l] - r1[l], y_m + r2[l] + r3[l]);
                }
                values[k] = field.bilinear_lanes(&u, &v);
            }
            for (sum, values) in sums.iter_mut().zip(&values) {
                for value in values {
                    *sum += value;
                }
            }
        }
        std::array::from_fn(|k| rots[k].sum_tail(field, limits, at[k][0], at[k][1], sums[k]))
    }

    /// The single-candidate portable sum, written plainly (no batching):
    /// the reference the batched ones must equal.
    #[cfg(test)]
    pub fn sum_portable(
        &self,
        field: &FieldWindow<'_>,
        limits: &MapLimits,
        x_m: f64,
        y_m: f64,
    ) -> f64 {
        let mut sum = -0.0;
        for [r0, r1, r2, r3] in &self.blocks {
            let mut u = [0.0; LANES];
            let mut v = [0.0; LANES];
            for k in 0..LANES {
                (u[k], v[k]) = limits.cell_coords(x_m + r0[k] - r1[k], y_m + r2[k] + r3[k]);
            }
            for b in field.bilinear_lanes(&u, &v) {
                sum += b;
            }
        }
        self.sum_tail(field, limits, x_m, y_m, sum)
    }

    /// Adds the field values of the points after the whole blocks to `sum`, in order.
    pub fn sum_tail(
        &self,
        field: &FieldWindow<'_>,
        limits: &MapLimits,
        x_m: f64,
        y_m: f64,
        mut sum: f64,
    ) -> f64 {
        for r in &self.tail {
            let (u, v) = limits.cell_coords(x_m + r[0] - r[1], y_m + r[2] + r[3]);
            sum += field.bilinear(u, v);
        }
        sum
    }
}
