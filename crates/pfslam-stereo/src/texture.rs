//! The ground's colour per grid cell: a sparse running mean, rasterised on demand.

use super::ground::ColouredPoint;
use pfslam::map::{Cell, CellRect, MapLimits};
use std::collections::BTreeMap;

/// Mean colour of one cell.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CellColour {
    /// Running mean of R, G, B (0..255).
    pub mean: [f64; 3],
    /// Number of samples.
    pub count: u32,
}

impl CellColour {
    /// Adds one sample to the running mean.
    #[inline]
    pub fn add(&mut self, rgb: [u8; 3]) {
        self.count += 1;
        let n = self.count as f64;
        for (m, v) in self.mean.iter_mut().zip(rgb) {
            *m += (v as f64 - *m) / n;
        }
    }

    /// The mean rounded to 8 bits.
    pub fn rgb8(&self) -> [u8; 3] {
        self.mean.map(|m| m.round().clamp(0.0, 255.0) as u8)
    }
}

/// Ground colours accumulated per cell of a [`MapLimits`] grid (the occupancy map's
/// convention: cell `(i, j)` along world x and y). Sparse (only observed cells are stored) and
/// ordered, so every output is deterministic.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureMap {
    limits: MapLimits,
    /// Observed cells.
    pub cells: BTreeMap<Cell, CellColour>,
}

impl TextureMap {
    /// An empty map on the grid `limits`.
    pub fn new(limits: MapLimits) -> Self {
        TextureMap {
            limits,
            cells: BTreeMap::new(),
        }
    }

    /// The grid geometry.
    pub fn limits(&self) -> &MapLimits {
        &self.limits
    }

    /// The colour of a cell, if observed.
    pub fn get(&self, cell: Cell) -> Option<&CellColour> {
        self.cells.get(&cell)
    }

    /// Adds the world points whose z lies in `[z_min_m, z_max_m]`; returns how many were kept.
    pub fn add_ground_points(
        &mut self,
        points: &[ColouredPoint],
        z_min_m: f64,
        z_max_m: f64,
    ) -> usize {
        let mut kept = 0;
        for p in points {
            if !(p.p_m.z >= z_min_m
                && p.p_m.z <= z_max_m
                && p.p_m.x.is_finite()
                && p.p_m.y.is_finite())
            {
                continue;
            }
            let cell = self.limits.cell_of(p.p_m.x, p.p_m.y);
            self.cells.entry(cell).or_default().add(p.rgb);
            kept += 1;
        }
        kept
    }

    /// The smallest rectangle holding every observed cell (`None` when empty).
    pub fn bounds(&self) -> Option<CellRect> {
        let mut it = self.cells.keys();
        let first = CellRect::around(*it.next()?);
        Some(it.fold(first, |r, c| r.union(&CellRect::around(*c))))
    }

    /// Rasterises `rect`: `(rgb, count)` with `rgb` HxWx3 (0-255 means, NaN where unobserved)
    /// and `count` HxW, row 0 at the top (largest y), column 0 at the left (smallest x), as the
    /// map's images and files.
    pub fn rasterize(&self, rect: &CellRect) -> (Vec<f32>, Vec<f32>) {
        let (w, h) = (rect.width(), rect.height());
        let mut rgb = vec![f32::NAN; 3 * w * h];
        let mut count = vec![0f32; w * h];
        for (cell, c) in &self.cells {
            if !rect.contains(*cell) {
                continue;
            }
            let i = (rect.max_j - cell.j) as usize * w + (cell.i - rect.min_i) as usize;
            for k in 0..3 {
                rgb[3 * i + k] = c.mean[k] as f32;
            }
            count[i] = c.count as f32;
        }
        (rgb, count)
    }
}
