//! Localisation's scan log-likelihood: the summed bilinear values of a scan's returns in the
//! likelihood field's f32 table for several poses in one pass; the AVX2 version in `x86.rs`.

use crate::geometry::cells::floor_to_i32;

#[cfg(target_arch = "x86_64")]
mod x86;

#[cfg(test)]
mod tests;

/// Poses scored together by [`sums4`]: one per f64 lane of an AVX2 register.
pub const POSES: usize = 4;

/// A likelihood table in coordinates with cell centres at whole numbers, row-major.
#[derive(Debug, Clone, Copy)]
pub struct CentreTable<'a> {
    /// The values, `width * height` of them.
    pub cells: &'a [f32],
    /// Cells per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

/// A pose folded into the table's coordinates: a body-frame point `(x, y)` (m) lands at
/// `u = u0 + cs * x - ss * y`, `v = v0 + ss * x + cs * y` (cells).
#[derive(Debug, Clone, Copy)]
pub struct CentrePose {
    /// Where the body's origin lands, first axis (cells).
    pub u0_cells: f64,
    /// Where the body's origin lands, second axis (cells).
    pub v0_cells: f64,
    /// Cosine of the yaw over the cell size (cells per metre).
    pub cs_per_m: f64,
    /// Sine of the yaw over the cell size (cells per metre).
    pub ss_per_m: f64,
}

impl CentrePose {
    /// Where the body-frame point `p` (m) lands (cells).
    #[inline(always)]
    pub fn place(&self, p: &[f64; 2]) -> (f64, f64) {
        let u = self.u0_cells + self.cs_per_m * p[0] - self.ss_per_m * p[1];
        let v = self.v0_cells + self.ss_per_m * p[0] + self.cs_per_m * p[1];
        (u, v)
    }
}

/// The sums over `points_body` of the table's values at [`POSES`] poses, in AVX2 where the
/// CPU has it, else [`portable`] a pose at a time (four interleaved scalar chains measured
/// 5-15 % slower than one); the same bits. `off(u, v)` gives the value of a point whose
/// 2x2 block is not inside the table.
pub fn sums4(
    table: &CentreTable<'_>,
    points_body: &[[f64; 2]],
    poses: [CentrePose; POSES],
    off: impl Fn(f64, f64) -> f32,
) -> [f64; POSES] {
    #[cfg(target_arch = "x86_64")]
    if super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return unsafe { x86::sums4_avx2(table, points_body, poses, off) };
    }
    poses.map(|pose| {
        let [sum] = portable(table, points_body, [pose], &off);
        sum
    })
}

/// [`sums4`] without vector instructions, for any count of poses: each pose has its own
/// accumulator and adds its values in point order from -0.0 (as `Iterator::sum` does), so
/// each sum has the bits of the pose summed alone while the chains of additions overlap.
pub fn portable<const K: usize>(
    table: &CentreTable<'_>,
    points_body: &[[f64; 2]],
    poses: [CentrePose; K],
    off: impl Fn(f64, f64) -> f32,
) -> [f64; K] {
    let mut sums = [-0.0f64; K];
    for p in points_body {
        for (sum, pose) in sums.iter_mut().zip(&poses) {
            let (u, v) = pose.place(p);
            *sum += f64::from(inside(table, u, v).unwrap_or_else(|| off(u, v)));
        }
    }
    sums
}

/// The bilinear value at `(u, v)` when its 2x2 block lies inside the table: the operations
/// of the field's own interpolation in its order, so the same bits.
#[inline(always)]
pub fn inside(table: &CentreTable<'_>, u: f64, v: f64) -> Option<f32> {
    let (i0, j0) = (f64::from(floor_to_i32(u)), f64::from(floor_to_i32(v)));
    let (w, h) = (table.width as f64, table.height as f64);
    if !(i0 >= 0.0 && j0 >= 0.0 && i0 + 1.0 < w && j0 + 1.0 < h) {
        return None;
    }
    let (fx, fy) = ((u - i0) as f32, (v - j0) as f32);
    let k = j0 as usize * table.width + i0 as usize;
    let row0 = table.cells.get(k..k + 2)?;
    let row1 = table.cells.get(k + table.width..k + table.width + 2)?;
    let low = row0[0] + fx * (row0[1] - row0[0]);
    let high = row1[0] + fx * (row1[1] - row1[0]);
    Some(low + fy * (high - low))
}
