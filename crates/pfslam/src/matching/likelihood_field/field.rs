//! The likelihood field: a window of the map where each cell holds its closeness to the
//! nearest occupied cell, built per update (banded, cached).

use super::cache::FieldCache;
use crate::kernels::{F32_LIM, FieldWindow};
use crate::map::{Cell, CellRect, MapLimits, OccupancyGrid};
use rayon::prelude::*;

/// Rows per parallel band of the field build.
pub(super) const FIELD_BAND_ROWS: usize = 32;

/// Zero bytes kept after a field's cells, as the kernels read them.
pub(super) use crate::kernels::FIELD_PAD;

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

    /// The window as the kernels read it.
    #[inline(always)]
    pub(crate) fn window(&self) -> FieldWindow<'_> {
        FieldWindow {
            values: &self.values,
            i0: self.i0,
            j0: self.j0,
            w: self.w,
            h: self.h,
        }
    }

    /// The vector kernels' preconditions ([`FieldWindow::vector_ok`]).
    #[cfg(test)]
    pub(crate) fn vector_ok(&self) -> bool {
        self.window().vector_ok()
    }

    /// Field value of a cell (0 outside the window).
    #[inline]
    pub fn at(&self, cell: Cell) -> u8 {
        self.window().at(cell)
    }

    /// Bilinear interpolation between cell centres at continuous cell coordinates `(u, v)`
    /// ([`FieldWindow::bilinear`]), in field units (0..=255).
    #[cfg(test)]
    pub(crate) fn bilinear(&self, u: f64, v: f64) -> f64 {
        self.window().bilinear(u, v)
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

    /// [`Self::bilinear`] as first written ([`FieldWindow::bilinear_reference`]).
    #[cfg(test)]
    pub(super) fn bilinear_reference(&self, u: f64, v: f64) -> f64 {
        self.window().bilinear_reference(u, v)
    }
}
