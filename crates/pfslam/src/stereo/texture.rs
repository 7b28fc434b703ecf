//! The ground's colour per grid cell: a sparse running mean, rasterised on demand.

use super::ground::ColouredPoint;
use std::collections::BTreeMap;
use std::io::Write;

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

/// A raster window of the texture grid: `width x height` cells whose cell `(0, 0)` (bottom
/// left) has integer index `(ix0, iy0)`. Row 0 of an image of it is the top (largest y).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CellWindow {
    /// Cell index (x) of the leftmost column.
    pub ix0: i64,
    /// Cell index (y) of the bottom row.
    pub iy0: i64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

/// Ground colours accumulated per square cell of side `cell_size_m`; cell `(ix, iy)` covers
/// `[ix * s, (ix + 1) * s) x [iy * s, (iy + 1) * s)` in the world frame. Sparse (only observed
/// cells are stored) and ordered, so every output is deterministic.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureMap {
    /// Cell side (m).
    pub cell_size_m: f64,
    /// Observed cells.
    pub cells: BTreeMap<(i64, i64), CellColour>,
}

impl TextureMap {
    /// An empty map with cells of `cell_size_m` (must be positive; checked by the options).
    pub fn new(cell_size_m: f64) -> Self {
        TextureMap {
            cell_size_m,
            cells: BTreeMap::new(),
        }
    }

    /// The cell index of a world position.
    #[inline]
    pub fn cell_of(&self, x_m: f64, y_m: f64) -> (i64, i64) {
        (
            (x_m / self.cell_size_m).floor() as i64,
            (y_m / self.cell_size_m).floor() as i64,
        )
    }

    /// The world position of a cell's centre.
    #[inline]
    pub fn cell_centre(&self, ix: i64, iy: i64) -> (f64, f64) {
        (
            (ix as f64 + 0.5) * self.cell_size_m,
            (iy as f64 + 0.5) * self.cell_size_m,
        )
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
            let key = self.cell_of(p.p_m.x, p.p_m.y);
            self.cells.entry(key).or_default().add(p.rgb);
            kept += 1;
        }
        kept
    }

    /// The smallest window holding every observed cell (`None` when empty).
    pub fn bounding_window(&self) -> Option<CellWindow> {
        let mut it = self.cells.keys();
        let &(x, y) = it.next()?;
        let (mut x0, mut x1, mut y0, mut y1) = (x, x, y, y);
        for &(x, y) in it {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        Some(CellWindow {
            ix0: x0,
            iy0: y0,
            width: (x1 - x0 + 1) as usize,
            height: (y1 - y0 + 1) as usize,
        })
    }

    /// Rasterises a window: `(rgb, count)` with `rgb` HxWx3 and `count` HxW, row 0 at the top
    /// (largest y), column 0 at the left (smallest x). Unobserved cells are black, count 0.
    pub fn rasterize(&self, window: &CellWindow) -> (Vec<u8>, Vec<u32>) {
        let (w, h) = (window.width, window.height);
        let mut rgb = vec![0u8; 3 * w * h];
        let mut count = vec![0u32; w * h];
        for (&(ix, iy), c) in &self.cells {
            let col = ix - window.ix0;
            let row_from_bottom = iy - window.iy0;
            if col < 0 || row_from_bottom < 0 || col >= w as i64 || row_from_bottom >= h as i64 {
                continue;
            }
            let i = (h - 1 - row_from_bottom as usize) * w + col as usize;
            rgb[3 * i..3 * i + 3].copy_from_slice(&c.rgb8());
            count[i] = c.count;
        }
        (rgb, count)
    }
}

/// Element types of the NPY files written here.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NpyDtype {
    /// `|u1`.
    U8,
    /// `<u4`.
    U32,
    /// `<f4`.
    F32,
}

/// Writes an NPY (format version 1.0, C order) header for `shape` and `dtype`.
pub fn write_npy_header(
    w: &mut dyn Write,
    dtype: NpyDtype,
    shape: &[usize],
) -> std::io::Result<()> {
    let descr = match dtype {
        NpyDtype::U8 => "|u1",
        NpyDtype::U32 => "<u4",
        NpyDtype::F32 => "<f4",
    };
    let shape_text = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Magic (6) + version (2) + length (2) + header + '\n' must be a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    header.push('\n');
    w.write_all(b"\x93NUMPY\x01\x00")?;
    w.write_all(&(header.len() as u16).to_le_bytes())?;
    w.write_all(header.as_bytes())
}

/// Writes a `u8` array as NPY.
pub fn write_npy_u8(w: &mut dyn Write, shape: &[usize], data: &[u8]) -> std::io::Result<()> {
    write_npy_header(w, NpyDtype::U8, shape)?;
    w.write_all(data)
}

/// Writes a `u32` array as NPY (little endian).
pub fn write_npy_u32(w: &mut dyn Write, shape: &[usize], data: &[u32]) -> std::io::Result<()> {
    write_npy_header(w, NpyDtype::U32, shape)?;
    for v in data {
        w.write_all(&v.to_le_bytes())?;
    }
    Ok(())
}
