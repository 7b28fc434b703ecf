//! The views the kernels read: plain `Copy` structs of slices and numbers, built by the
//! modules that own the data (the scan matcher's likelihood field, the back end's point
//! field) for each kernel call, so that the kernels depend on nothing above them.

use super::{FIELD_PAD, LANES, mix_lanes};
use crate::geometry::cells::{Cell, floor_to_i32};

/// The f32 kernel's coordinate bound (cells, 2^23): below it a coordinate's floor and
/// fraction are exact in f32, and a point beyond it lies outside every window the kernel
/// takes.
pub const F32_LIM: f32 = 8_388_608.0;

/// A likelihood field's window: `w x h` byte values (0..=255) of the cells from `(i0, j0)`
/// on, row-major, followed by [`FIELD_PAD`] spare bytes; cells outside the window are 0.
/// The interpolations here are the scan matcher's, kept with the kernels that vectorise
/// them.
#[derive(Clone, Copy)]
pub struct FieldWindow<'a> {
    /// The cells' values, row-major, then the spare bytes.
    pub values: &'a [u8],
    /// The window's first cell: column,
    pub i0: i32,
    /// and row.
    pub j0: i32,
    /// Its width (cells).
    pub w: usize,
    /// Its height (cells).
    pub h: usize,
}

impl FieldWindow<'_> {
    /// The vector kernel's preconditions: cell indices fit in i32 and the spare bytes are
    /// there.
    pub fn vector_ok(&self) -> bool {
        self.w
            .checked_mul(self.h)
            .is_some_and(|n| n < i32::MAX as usize / 2 && self.values.len() >= n + FIELD_PAD)
    }

    /// Field value of a cell (0 outside the window).
    #[inline]
    pub fn at(&self, cell: Cell) -> u8 {
        let (li, lj) = (cell.i - self.i0, cell.j - self.j0);
        if li < 0 || lj < 0 || li as usize >= self.w || lj as usize >= self.h {
            return 0;
        }
        self.values[lj as usize * self.w + li as usize]
    }

    /// Bilinear interpolation between cell centres at continuous cell coordinates `(u, v)`
    /// (cell `(i, j)` spans `[i, i+1) x [j, j+1)`), in field units (0..=255).
    /// Always inlined: it is the refinement's inner loop (a call per point cost ~10 %).
    #[inline(always)]
    pub fn bilinear(&self, u: f64, v: f64) -> f64 {
        let (x, y) = (u - 0.5, v - 0.5);
        // `floor` is a libm call on baseline x86-64; the integer floor gives the same value
        // (and, after the subtraction below, the same fraction) inside the i32 range, which
        // every window lies in. Outside it, the reference path.
        const LIM: f64 = 1e9;
        if !(x.abs() < LIM && y.abs() < LIM) {
            return self.bilinear_reference(u, v);
        }
        let (i, j) = (floor_to_i32(x), floor_to_i32(y));
        let (ax, ay) = (x - f64::from(i), y - f64::from(j));
        let [f00, f10, f01, f11] = self.corners(i, j);
        let bottom = f00 * (1.0 - ax) + f10 * ax;
        let top = f01 * (1.0 - ax) + f11 * ax;
        bottom * (1.0 - ay) + top * ay
    }

    /// [`Self::bilinear`] of `LANES` points at once: the same operations per lane (so the same
    /// bits), written lane-wise so that the arithmetic vectorises; only the four byte loads
    /// per point stay scalar. A lane outside the fast path's range takes [`Self::bilinear`].
    #[inline(always)]
    pub fn bilinear_lanes(&self, u: &[f64; LANES], v: &[f64; LANES]) -> [f64; LANES] {
        const LIM: f64 = 1e9;
        let mut x = [0.0; LANES];
        let mut y = [0.0; LANES];
        let mut ok = true;
        for k in 0..LANES {
            x[k] = u[k] - 0.5;
            y[k] = v[k] - 0.5;
            ok &= x[k].abs() < LIM && y[k].abs() < LIM;
        }
        if !ok {
            return std::array::from_fn(|k| self.bilinear(u[k], v[k]));
        }
        let mut ax = [0.0; LANES];
        let mut ay = [0.0; LANES];
        let mut f = [[0.0; 4]; LANES];
        for k in 0..LANES {
            let (i, j) = (floor_to_i32(x[k]), floor_to_i32(y[k]));
            ax[k] = x[k] - f64::from(i);
            ay[k] = y[k] - f64::from(j);
            f[k] = self.corners(i, j);
        }
        mix_lanes(&f, &ax, &ay)
    }

    /// The field values at cells `(i, j)`, `(i+1, j)`, `(i, j+1)`, `(i+1, j+1)`: one bounds
    /// check when all four lie inside the window (nearly always).
    #[inline(always)]
    pub fn corners(&self, i: i32, j: i32) -> [f64; 4] {
        let (li, lj) = (i - self.i0, j - self.j0);
        if li >= 0 && lj >= 0 && (li as usize) + 1 < self.w && (lj as usize) + 1 < self.h {
            let k = lj as usize * self.w + li as usize;
            let row0 = &self.values[k..k + 2];
            let row1 = &self.values[k + self.w..k + self.w + 2];
            [
                f64::from(row0[0]),
                f64::from(row0[1]),
                f64::from(row1[0]),
                f64::from(row1[1]),
            ]
        } else {
            let f = |di, dj| f64::from(self.at(Cell::new(i + di, j + dj)));
            [f(0, 0), f(1, 0), f(0, 1), f(1, 1)]
        }
    }

    /// [`Self::bilinear`] in f32 at `(x, y)` in the window's frame less half a cell (the scan matcher's `f32_origin`): the same
    /// operations, cells outside the window 0; beyond [`F32_LIM`] (outside any window
    /// the f32 kernel takes) 0, NaN for NaN. The f32 kernel's reference per lane.
    #[inline(always)]
    pub fn bilinear_f32(&self, x: f32, y: f32) -> f32 {
        if !(x.abs() < F32_LIM && y.abs() < F32_LIM) {
            return if x.is_nan() || y.is_nan() {
                f32::NAN
            } else {
                0.0
            };
        }
        // The floor by truncation (a libm call otherwise on baseline x86-64): exact below
        // 2^23, as the fraction `x - floor(x)` is.
        let floor = |x: f32| {
            let t = x as i32;
            if t as f32 > x { t - 1 } else { t }
        };
        let (i, j) = (floor(x), floor(y));
        let (ax, ay) = (x - i as f32, y - j as f32);
        let at = |i: i32, j: i32| {
            if i >= 0 && j >= 0 && (i as usize) < self.w && (j as usize) < self.h {
                f32::from(self.values[j as usize * self.w + i as usize])
            } else {
                0.0
            }
        };
        let (f00, f10, f01, f11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
        let omx = 1.0 - ax;
        let bottom = f00 * omx + f10 * ax;
        let top = f01 * omx + f11 * ax;
        bottom * (1.0 - ay) + top * ay
    }

    /// [`Self::bilinear`] as first written (the reference the fast path must equal).
    #[cold]
    pub fn bilinear_reference(&self, u: f64, v: f64) -> f64 {
        let (x, y) = (u - 0.5, v - 0.5);
        let (fx, fy) = (x.floor(), y.floor());
        let (ax, ay) = (x - fx, y - fy);
        let (i, j) = (fx as i32, fy as i32);
        let f = |di, dj| f64::from(self.at(Cell::new(i + di, j + dj)));
        let bottom = f(0, 0) * (1.0 - ax) + f(1, 0) * ax;
        let top = f(0, 1) * (1.0 - ax) + f(1, 1) * ax;
        bottom * (1.0 - ay) + top * ay
    }
}

/// One level of the back end's point field: `w x h` values of `f32`, row-major (shorter
/// storage reads 0), in the metric frame of `origin` and `resolution_m`.
#[derive(Clone, Copy)]
pub struct PointLevel<'a> {
    /// The level's values, row-major.
    pub cells: &'a [f32],
    /// Width (cells; the field's, for every level).
    pub w: usize,
    /// Height (cells).
    pub h: usize,
    /// World x of cell `(0, 0)`'s lower-left corner (m).
    pub origin_x_m: f64,
    /// World y of that corner (m).
    pub origin_y_m: f64,
    /// Cell side (m).
    pub resolution_m: f64,
}

impl PointLevel<'_> {
    /// The value at cell `(i, j)` (0 outside).
    #[inline]
    pub fn at(&self, i: i64, j: i64) -> f32 {
        if i < 0 || j < 0 || i >= self.w as i64 || j >= self.h as i64 {
            return 0.0;
        }
        let k = j as usize * self.w + i as usize;
        self.cells.get(k).copied().unwrap_or(0.0)
    }
}
