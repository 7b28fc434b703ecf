//! [`PointField`]: a likelihood field of submap points with max-pooled levels, and how it is
//! built (kernels splatted by bands of tile rows in parallel, then the levels pooled).

use super::floor_to_i64;
use super::storage::{Buffer, TILE, TILE_SHIFT};
use crate::kernels::PointLevel;
use rayon::prelude::*;

/// A likelihood-field window with max-pooled levels.
///
/// Dense (`w x h` per level), but only the `TILE x TILE` tiles where some level can be
/// non-zero (near a submap point; a loop closure's submap touched ~16 % of its window's
/// tiles on the full-size car) are written: the buffers come from a per-thread pool, and a
/// reused buffer gets only the cells its last use wrote set back to zero.
#[derive(Debug, Clone)]
pub struct PointField {
    pub(crate) origin_x_m: f64,
    pub(crate) origin_y_m: f64,
    pub(crate) resolution_m: f64,
    pub(crate) w: usize,
    pub(crate) h: usize,
    /// `levels[0]` = the field, `levels[k]` = max over `2^k x 2^k` blocks.
    pub(crate) levels: Vec<Buffer>,
}

/// The larger of two field values, which are never NaN nor -0: the same value as
/// `f32::max` in one `maxps` (the field's pooling vectorises).
#[inline(always)]
fn max_f32(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `out = max(a0, a1)` elementwise (one pooling step over a run of cells).
#[inline]
fn pool_run(out: &mut [f32], a0: &[f32], a1: &[f32]) {
    for (o, (&p, &q)) in out.iter_mut().zip(a0.iter().zip(a1)) {
        *o = max_f32(p, q);
    }
}

/// `out = max(max(a.0, a.1), max(b.0, b.1))` elementwise (a pooling step of two rows).
#[inline]
fn pool_rows(out: &mut [f32], a: (&[f32], &[f32]), b: (&[f32], &[f32])) {
    let n = out.len();
    let (a0, a1, b0, b1) = (&a.0[..n], &a.1[..n], &b.0[..n], &b.1[..n]);
    for x in 0..n {
        out[x] = max_f32(max_f32(a0[x], a1[x]), max_f32(b0[x], b1[x]));
    }
}

/// Per kernel row `dj = -r..=r`: the values above 0.01, a run `-a..=a` centred on the
/// point's column (the Gaussian falls with |di|).
fn kernel_rows(r: i64, sigma_cells: f64) -> Vec<Vec<f32>> {
    (-r..=r)
        .map(|dj| {
            (-r..=r)
                .map(|di| {
                    let d2 = (di * di + dj * dj) as f64;
                    (-0.5 * d2 / (sigma_cells * sigma_cells)).exp() as f32
                })
                .filter(|&v| v > 0.01)
                .collect()
        })
        .collect()
}

/// The window a field is built over: its corner, cells and size, and the kernel's radius.
struct FieldGrid {
    min: [f64; 2],
    resolution_m: f64,
    w: usize,
    h: usize,
    kernel_radius_cells: i64,
}

impl FieldGrid {
    /// The points' cells within the kernel's reach of the window, each once, by row: a
    /// cell's value is the maximum over the kernels stamped on it, which neither order nor
    /// repetition changes (a submap's overlapping scans put many points in one cell), and
    /// each band of rows of [`Self::splat`] takes a contiguous run of them.
    fn point_cells(&self, points: &[[f64; 2]]) -> Vec<(i64, i64)> {
        let (min, resolution_m, r) = (self.min, self.resolution_m, self.kernel_radius_cells);
        let (wi, hi) = (self.w as i64, self.h as i64);
        let span = wi + 2 * r;
        let mut keys: Vec<u64> = points
            .iter()
            .filter_map(|p| {
                let ci = floor_to_i64((p[0] - min[0]) / resolution_m);
                let cj = floor_to_i64((p[1] - min[1]) / resolution_m);
                let outside = ci < -r || cj < -r || ci >= wi + r || cj >= hi + r;
                (!outside).then(|| ((cj + r) * span + (ci + r)) as u64)
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        keys.iter()
            .map(|&key| {
                let key = key as i64;
                (key % span - r, key / span - r)
            })
            .collect()
    }

    /// Per tile row: the cell columns `x0..x1` of the tiles written, neighbours joined into
    /// one run (long runs vectorise; a tile is 32 cells). The tiles a point's kernel touches
    /// hold level 0's non-zero cells; a pooled level reaches `2^levels - 1` cells further
    /// left and down, so the tiles within that many tiles left and down of them are stored
    /// too.
    fn written_tiles(&self, cells: &[(i64, i64)], levels: usize) -> Vec<Vec<(usize, usize)>> {
        let (w, h, r) = (self.w, self.h, self.kernel_radius_cells);
        let (wi, hi) = (w as i64, h as i64);
        let (tw, th) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut occupied = vec![false; tw * th];
        for &(ci, cj) in cells {
            let (x0, x1) = ((ci - r).max(0), (ci + r).min(wi - 1));
            let (y0, y1) = ((cj - r).max(0), (cj + r).min(hi - 1));
            if x0 > x1 || y0 > y1 {
                continue;
            }
            for ty in (y0 >> TILE_SHIFT)..=(y1 >> TILE_SHIFT) {
                for tx in (x0 >> TILE_SHIFT)..=(x1 >> TILE_SHIFT) {
                    occupied[ty as usize * tw + tx as usize] = true;
                }
            }
        }
        let reach = 1usize
            .checked_shl(levels.min(31) as u32)
            .map_or(usize::MAX, |v| v - 1)
            .div_ceil(TILE);
        let mut present: Vec<Vec<(usize, usize)>> = vec![Vec::new(); th];
        for (ty, row) in present.iter_mut().enumerate() {
            for tx in 0..tw {
                let (ty1, tx1) = (
                    ty.saturating_add(reach).min(th - 1),
                    tx.saturating_add(reach).min(tw - 1),
                );
                if (ty..=ty1).any(|uy| occupied[uy * tw + tx..=uy * tw + tx1].contains(&true)) {
                    let (x0, x1) = (tx * TILE, ((tx + 1) * TILE).min(w));
                    match row.last_mut() {
                        Some(run) if run.1 == x0 => run.1 = x1,
                        _ => row.push((x0, x1)),
                    }
                }
            }
        }
        present
    }

    /// The row runs `(first cell, length)` of the written tiles, the same for every level.
    fn written_runs(&self, present: &[Vec<(usize, usize)>]) -> Vec<(usize, usize)> {
        let (w, h) = (self.w, self.h);
        let mut written = Vec::new();
        for (ty, row) in present.iter().enumerate() {
            for y in ty * TILE..((ty + 1) * TILE).min(h) {
                for &(x0, x1) in row {
                    written.push((y * w + x0, x1 - x0));
                }
            }
        }
        written
    }

    /// Level 0: the kernels stamped on `cells`. Bands of tile rows in parallel, each taking
    /// the kernel cells of every point that fall in it: a cell's value is the maximum over
    /// the same values in any order.
    fn splat(&self, cells: &[(i64, i64)], kernel_rows: &[Vec<f32>]) -> Buffer {
        let (w, h, r) = (self.w, self.h, self.kernel_radius_cells);
        let wi = w as i64;
        let mut field = Buffer::zeroed(w * h);
        field.cells[..w * h]
            .par_chunks_mut(w * TILE)
            .enumerate()
            .for_each(|(ty, band)| {
                let y0 = (ty * TILE) as i64;
                let y1 = y0 + (band.len() / w) as i64;
                let first = cells.partition_point(|&(_, cj)| cj + r < y0);
                let end = cells.partition_point(|&(_, cj)| cj - r < y1);
                for &(ci, cj) in &cells[first..end.max(first)] {
                    for (dj, values) in (-r..=r).zip(kernel_rows) {
                        let y = cj + dj;
                        if y < y0 || y >= y1 || values.is_empty() {
                            continue;
                        }
                        // The row's cells `ci - a ..= ci + a`, cut to the window.
                        let a = (values.len() / 2) as i64;
                        let (x, x_end) = ((ci - a).max(0), (ci + a).min(wi - 1));
                        if x > x_end {
                            continue;
                        }
                        let k = (y - y0) as usize * w + x as usize;
                        let len = (x_end - x + 1) as usize;
                        let from = (x - (ci - a)) as usize;
                        if let (Some(run), Some(vals)) =
                            (band.get_mut(k..k + len), values.get(from..from + len))
                        {
                            for (c, &v) in run.iter_mut().zip(vals) {
                                *c = max_f32(v, *c);
                            }
                        }
                    }
                }
            });
        field
    }

    /// The level above `prev`: the maximum over `prev`'s cells `(x, y)`, `(x + s, y)`,
    /// `(x, y + s)` and `(x + s, y + s)` within the window, on the written tiles `present`.
    fn pool(&self, prev: &[f32], s: usize, present: &[Vec<(usize, usize)>]) -> Buffer {
        let (w, h) = (self.w, self.h);
        let mut next = Buffer::zeroed(w * h);
        next.cells[..w * h]
            .par_chunks_mut(w * TILE)
            .enumerate()
            .for_each(|(ty, band)| {
                for (yy, out) in band.chunks_exact_mut(w).enumerate() {
                    let y = ty * TILE + yy;
                    let a = &prev[y * w..(y + 1) * w];
                    // Row `y + s` (none above the window: the maximum over the rest).
                    let b = prev.get((y + s) * w..(y + s + 1) * w).filter(|_| y + s < h);
                    for &(x0, x1) in &present[ty] {
                        // Cells whose right neighbour `x + s` lies in the window
                        // (none when the run lies in the last `s` columns).
                        let xm = x1.min(w.saturating_sub(s)).max(x0);
                        match b {
                            Some(b) => {
                                if xm > x0 {
                                    pool_rows(
                                        &mut out[x0..xm],
                                        (&a[x0..xm], &a[x0 + s..xm + s]),
                                        (&b[x0..xm], &b[x0 + s..xm + s]),
                                    );
                                }
                                pool_run(&mut out[xm..x1], &a[xm..x1], &b[xm..x1]);
                            }
                            None => {
                                if xm > x0 {
                                    pool_run(&mut out[x0..xm], &a[x0..xm], &a[x0 + s..xm + s]);
                                }
                                out[xm..x1].copy_from_slice(&a[xm..x1]);
                            }
                        }
                    }
                }
            });
        next
    }
}

impl PointField {
    /// Builds the field over `[min, max]` (world, m) from `points` (world, m), with cells of
    /// `resolution_m`, Gaussian `sigma_m` (truncated at 3 sigma) and `levels` pooled levels
    /// above the field.
    pub fn build(
        points: &[[f64; 2]],
        min: [f64; 2],
        max: [f64; 2],
        resolution_m: f64,
        sigma_m: f64,
        levels: usize,
    ) -> PointField {
        let w = (((max[0] - min[0]) / resolution_m).ceil().max(1.0) as usize).min(1 << 14);
        let h = (((max[1] - min[1]) / resolution_m).ceil().max(1.0) as usize).min(1 << 14);
        let sigma_cells = (sigma_m / resolution_m).max(0.25);
        let grid = FieldGrid {
            min,
            resolution_m,
            w,
            h,
            kernel_radius_cells: (3.0 * sigma_cells).ceil() as i64,
        };
        let kernel_rows = kernel_rows(grid.kernel_radius_cells, sigma_cells);
        let cells = grid.point_cells(points);
        let present = grid.written_tiles(&cells, levels);
        let written = grid.written_runs(&present);
        let mut field = grid.splat(&cells, &kernel_rows);
        field.written.clone_from(&written);
        let mut all = vec![field];
        for k in 1..=levels {
            let mut next = grid.pool(&all[k - 1].cells[..], 1usize << (k - 1), &present);
            next.written.clone_from(&written);
            all.push(next);
        }
        PointField {
            origin_x_m: min[0],
            origin_y_m: min[1],
            resolution_m,
            w,
            h,
            levels: all,
        }
    }

    /// Number of pooled levels above the field.
    pub fn pooled_levels(&self) -> usize {
        self.levels.len() - 1
    }

    /// Level `level` as the kernels read it.
    #[inline(always)]
    pub(crate) fn level(&self, level: usize) -> PointLevel<'_> {
        PointLevel {
            cells: &self.levels[level].cells,
            w: self.w,
            h: self.h,
            origin_x_m: self.origin_x_m,
            origin_y_m: self.origin_y_m,
            resolution_m: self.resolution_m,
        }
    }

    #[cfg(test)]
    pub(crate) fn at(&self, level: usize, i: i64, j: i64) -> f32 {
        self.level(level).at(i, j)
    }
}
