//! The likelihood field: a window of the map where each cell holds its closeness to the
//! nearest occupied cell, built per update (banded, cached).

use super::*;
use crate::filter::field_cache::FieldCache;
use crate::kernels::rotation_f32::F32_LIM;
use crate::map::limits::floor_to_i32;
use crate::map::{Cell, CellRect, MapLimits, OccupancyGrid};
use rayon::prelude::*;

/// Rows per parallel band of the field build.
pub(super) const FIELD_BAND_ROWS: usize = 32;

/// Zero bytes kept after a field's cells (never read as cells).
pub(super) const FIELD_PAD: usize = 8;

/// A window of the likelihood field (see the module docs), in the map's cell frame.
#[derive(Debug, Clone, Default)]
pub struct LikelihoodField {
    pub(super) limits: Option<MapLimits>,
    pub(crate) i0: i32,
    pub(crate) j0: i32,
    pub(crate) w: usize,
    pub(crate) h: usize,
    pub(crate) values: Vec<u8>,
    kernel: Vec<(i32, i32, u8)>,
    kernel_radius: i32,
    /// Occupied cells reaching each band of rows (pass 1 of the build).
    occupied: Vec<Vec<(i32, i32)>>,
}

impl LikelihoodField {
    /// An empty field (every lookup 0).
    pub fn new() -> Self {
        LikelihoodField::default()
    }

    /// The field as [`Self::build`] gives it, from `cache` ([`FieldCache`]: the same values,
    /// bit for bit, from tiles kept up to date with the grid's logged changes). `changes`:
    /// the grid's changes since the last call with this cache (`None`: unknown, the cache
    /// starts over).
    pub fn build_cached(
        &mut self,
        grid: &OccupancyGrid,
        rect: &CellRect,
        sigma_m: f64,
        unknown_value: f64,
        cache: &mut FieldCache,
        changes: Option<&[crate::map::CellChange]>,
    ) {
        let (r, unknown, threshold) = self.prepare(grid, rect, sigma_m, unknown_value);
        cache.configure(&self.kernel, r, threshold);
        match changes {
            Some(changes) => cache.apply(grid, changes),
            None => cache.reset(),
        }
        self.values.clear();
        self.values.resize(self.w * self.h, 0);
        cache.fill(grid, rect, unknown, &mut self.values);
        self.values.extend_from_slice(&[0; FIELD_PAD]);
    }

    /// The wall threshold this field uses on `grid` (fixed-point log-odds): the grid's
    /// occupied threshold (`docs/decisions/0040-likelihood-field-walls-at-the-maps-threshold.md`).
    pub fn source_threshold_on(&self, grid: &OccupancyGrid) -> i16 {
        grid.fixed().occupied
    }

    /// Sets the kernel for `sigma_m` on `grid`'s cells and the window `rect`; returns the
    /// kernel radius (cells), the unknown value and the wall threshold.
    pub(super) fn prepare(
        &mut self,
        grid: &OccupancyGrid,
        rect: &CellRect,
        sigma_m: f64,
        unknown_value: f64,
    ) -> (i32, u8, i16) {
        let limits = *grid.limits();
        let sigma_cells = (sigma_m / limits.resolution_m()).max(0.25);
        let r = (3.0 * sigma_cells).ceil().min(16.0) as i32;
        if self.kernel_radius != r || self.kernel.is_empty() {
            self.kernel.clear();
            for dj in -r..=r {
                for di in -r..=r {
                    let d2 = f64::from(di * di + dj * dj);
                    let v = (255.0 * (-0.5 * d2 / (sigma_cells * sigma_cells)).exp()).round();
                    if v >= 1.0 {
                        self.kernel.push((di, dj, v as u8));
                    }
                }
            }
            self.kernel_radius = r;
        }
        self.limits = Some(limits);
        self.i0 = rect.min_i;
        self.j0 = rect.min_j;
        self.w = rect.width();
        self.h = rect.height();
        let unknown = (255.0 * unknown_value.clamp(0.0, 1.0)).round() as u8;
        (r, unknown, self.source_threshold_on(grid))
    }

    /// Rebuilds the field over `rect` from the occupied cells of `grid` (Gaussian of
    /// `sigma_m`, truncated at 3 sigma); never-observed cells away from walls hold
    /// `unknown_value` (0..1), observed ones 0. Reuses its buffers.
    pub fn build(
        &mut self,
        grid: &OccupancyGrid,
        rect: &CellRect,
        sigma_m: f64,
        unknown_value: f64,
    ) {
        let (r, unknown, occupied_threshold) = self.prepare(grid, rect, sigma_m, unknown_value);
        self.values.clear();
        self.values.resize(self.w * self.h, unknown);
        let w = self.w as i32;
        let (i0, j0) = (self.i0, self.j0);
        let bands = self.h.div_ceil(FIELD_BAND_ROWS);
        if self.occupied.len() < bands {
            self.occupied.resize_with(bands, Vec::new);
        }
        let kernel = &self.kernel;
        let n_cells = self.w * self.h;
        self.values[..n_cells]
            .par_chunks_mut((self.w * FIELD_BAND_ROWS).max(1))
            .zip(self.occupied.par_iter_mut())
            .enumerate()
            .for_each(|(b, (band, occupied))| {
                let y0 = (b * FIELD_BAND_ROWS) as i32;
                let y1 = y0 + (band.len() / self.w) as i32;
                let band_rect = CellRect {
                    min_i: rect.min_i,
                    min_j: j0 + y0,
                    max_i: rect.max_i,
                    max_j: j0 + y1 - 1,
                };
                // Pass 1: observed cells are 0 (free or not yet occupied); collect the
                // occupied ones, including those up to `r` outside the band (they still
                // reach into it).
                occupied.clear();
                grid.for_each_observed_in(&band_rect.expanded(r), |c, v| {
                    let (li, lj) = (c.i - i0, c.j - j0);
                    if li >= 0 && lj >= y0 && li < w && lj < y1 {
                        band[((lj - y0) * w + li) as usize] = 0;
                    }
                    if v >= occupied_threshold {
                        occupied.push((li, lj));
                    }
                });
                // Pass 2: the Gaussian around every occupied cell.
                for &(li, lj) in occupied.iter() {
                    let inside = li >= r && lj >= y0 + r && li < w - r && lj < y1 - r;
                    for &(di, dj, v) in kernel {
                        let (x, y) = (li + di, lj + dj);
                        if !inside && (x < 0 || y < y0 || x >= w || y >= y1) {
                            continue;
                        }
                        let slot = &mut band[((y - y0) * w + x) as usize];
                        if v > *slot {
                            *slot = v;
                        }
                    }
                }
            });
        // Spare bytes after the last cell: the coarse search loads whole 8-byte rows.
        self.values.extend_from_slice(&[0; FIELD_PAD]);
    }

    /// The vector kernel's preconditions: cell indices fit in i32 and the spare bytes are
    /// there.
    pub(crate) fn vector_ok(&self) -> bool {
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
    pub(crate) fn bilinear(&self, u: f64, v: f64) -> f64 {
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
    pub(crate) fn bilinear_lanes(&self, u: &[f64; LANES], v: &[f64; LANES]) -> [f64; LANES] {
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
    pub(crate) fn corners(&self, i: i32, j: i32) -> [f64; 4] {
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

    /// The f32 kernel's preconditions: both sides below its coordinate bound.
    pub(super) fn f32_ok(&self) -> bool {
        self.w < F32_LIM as usize && self.h < F32_LIM as usize
    }

    /// The f32 kernel's frame of a position (world m): its continuous cell coordinates
    /// relative to the window's first cell, less half a cell (so that the floor is the
    /// lower-left corner of the bilinear cell), rounded to f32 once. Relative to the
    /// window the coordinates stay small, so f32 resolves ~1e-4 cell.
    pub(super) fn f32_origin(&self, limits: &MapLimits, x_m: f64, y_m: f64) -> [f32; 2] {
        let (u, v) = limits.cell_coords(x_m, y_m);
        [
            (u - f64::from(self.i0) - 0.5) as f32,
            (v - f64::from(self.j0) - 0.5) as f32,
        ]
    }

    /// [`Self::bilinear`] in f32 at `(x, y)` in the frame of [`Self::f32_origin`]: the same
    /// operations, cells outside the window 0; beyond [`F32_LIM`] (outside any window
    /// `f32_ok` admits) 0, NaN for NaN. The f32 kernel's reference per lane.
    #[inline(always)]
    pub(crate) fn bilinear_f32(&self, x: f32, y: f32) -> f32 {
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
    pub(super) fn bilinear_reference(&self, u: f64, v: f64) -> f64 {
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
