//! The true map: the world's obstacles rasterised into an occupancy raster (written as PNG and
//! as a map_server pair by [`crate::dataset::write_true_map`]).
//!
//! Rule: a cell is occupied when it lies inside (cell centre) or on the outline of the
//! footprint of an obstacle whose vertical extent `[z_min, z_max]` intersects the LiDAR's
//! scanning band `[band_min, band_max]` (options `truth_band_min_m`, `truth_band_max_m`):
//! those are the obstacles a horizontal-ish scanner at that height range can hit and a 2-D
//! SLAM map can show. Defaults: car 1.7-4 m (the LiDAR is at 1.76 m and its beams run level
//! sideways and rise forwards, so lower obstacles such as parked cars are overflown, not
//! hit); humanoid 0.2-2 m (walls, furniture; the floor is never in the map). Everything else (ground, obstacles entirely below or above the band) is
//! free. Footprints are filled: the SLAM map only ever sees their outlines, so compare
//! boundaries (or "occupied cells near a true occupied cell"), not interiors.

use super::world::{World, point_in_polygon};
use pfslam::map::{BinaryMap, CellState, MapLimits};

/// An occupancy raster of the world (true = occupied).
#[derive(Debug, Clone, PartialEq)]
pub struct TrueMap {
    /// Cell size (m).
    pub resolution_m: f64,
    /// World coordinates of the lower-left corner of cell `(0, 0)` (m).
    pub origin_m: [f64; 2],
    /// Cells along x.
    pub width: usize,
    /// Cells along y.
    pub height: usize,
    /// Row-major, row 0 at the lowest y: cell `(ix, iy)` is `occupied[iy * width + ix]`.
    pub occupied: Vec<bool>,
}

impl TrueMap {
    /// Rasterises the obstacles of `world` that intersect the height band, over the world's
    /// bounds plus `margin_m`.
    pub fn rasterize(world: &World, resolution_m: f64, band_m: [f64; 2], margin_m: f64) -> TrueMap {
        let b = world.bounds();
        let res = resolution_m.max(1e-3);
        let origin_m = [b[0] - margin_m, b[1] - margin_m];
        let width = ((b[2] + margin_m - origin_m[0]) / res).ceil().max(1.0) as usize;
        let height = ((b[3] + margin_m - origin_m[1]) / res).ceil().max(1.0) as usize;
        let mut occupied = vec![false; width * height];
        for p in &world.prisms {
            if p.z_max_m < band_m[0] || p.z_min_m > band_m[1] {
                continue;
            }
            for_each_footprint_cell(p, origin_m, res, [width, height], |i| occupied[i] = true);
        }
        TrueMap {
            resolution_m: res,
            origin_m,
            width,
            height,
            occupied,
        }
    }

    /// Whether the cell containing `(x_m, y_m)` is occupied (false outside the raster).
    pub fn is_occupied_at(&self, x_m: f64, y_m: f64) -> bool {
        let ix = ((x_m - self.origin_m[0]) / self.resolution_m).floor();
        let iy = ((y_m - self.origin_m[1]) / self.resolution_m).floor();
        if ix < 0.0 || iy < 0.0 || ix as usize >= self.width || iy as usize >= self.height {
            return false;
        }
        self.occupied[iy as usize * self.width + ix as usize]
    }

    /// Number of occupied cells.
    pub fn occupied_count(&self) -> usize {
        self.occupied.iter().filter(|&&o| o).count()
    }

    /// 8-bit image rows, top row = highest y: 0 (black) occupied, 254 free (map_server
    /// convention with `negate: 0`).
    pub fn image_rows(&self) -> Vec<u8> {
        let mut px = Vec::with_capacity(self.width * self.height);
        for iy in (0..self.height).rev() {
            let row = &self.occupied[iy * self.width..(iy + 1) * self.width];
            px.extend(row.iter().map(|&o| if o { 0u8 } else { 254u8 }));
        }
        px
    }

    /// The map as the map component's raster (occupied / free; nothing unknown), e.g. for
    /// [`pfslam::map::compare_maps`].
    pub fn to_binary_map(&self) -> BinaryMap {
        BinaryMap {
            limits: MapLimits::new(self.resolution_m, self.origin_m[0], self.origin_m[1]),
            width: self.width,
            height: self.height,
            cells: self
                .occupied
                .iter()
                .map(|&o| {
                    if o {
                        CellState::Occupied
                    } else {
                        CellState::Free
                    }
                })
                .collect(),
        }
    }
}

/// Calls `mark(iy * width + ix)` for every cell of the raster (`origin_m`, `res`, `size` =
/// `[width, height]`) covered by the footprint of `p`: cells whose centre lies inside, and
/// cells its outline passes through (sampled every quarter cell, so thin obstacles such as
/// poles appear).
pub(crate) fn for_each_footprint_cell(
    p: &super::world::Prism,
    origin_m: [f64; 2],
    res: f64,
    size: [usize; 2],
    mut mark: impl FnMut(usize),
) {
    let [width, height] = size;
    if width == 0 || height == 0 {
        return;
    }
    let cell = |x: f64, y: f64| -> Option<usize> {
        let ix = ((x - origin_m[0]) / res).floor();
        let iy = ((y - origin_m[1]) / res).floor();
        (ix >= 0.0 && iy >= 0.0 && (ix as usize) < width && (iy as usize) < height)
            .then(|| iy as usize * width + ix as usize)
    };
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for v in &p.footprint {
        x0 = x0.min(v[0]);
        y0 = y0.min(v[1]);
        x1 = x1.max(v[0]);
        y1 = y1.max(v[1]);
    }
    // interior: cell centres inside the polygon
    let ix0 = ((x0 - origin_m[0]) / res).floor().max(0.0) as usize;
    let iy0 = ((y0 - origin_m[1]) / res).floor().max(0.0) as usize;
    let ix1 = (((x1 - origin_m[0]) / res).floor().max(0.0) as usize).min(width - 1);
    let iy1 = (((y1 - origin_m[1]) / res).floor().max(0.0) as usize).min(height - 1);
    for iy in iy0..=iy1 {
        let cy = origin_m[1] + (iy as f64 + 0.5) * res;
        for ix in ix0..=ix1 {
            let cx = origin_m[0] + (ix as f64 + 0.5) * res;
            if point_in_polygon(&p.footprint, cx, cy) {
                mark(iy * width + ix);
            }
        }
    }
    // outline: sample every edge densely so thin obstacles (poles) appear
    let n = p.footprint.len();
    for k in 0..n {
        let a = p.footprint[k];
        let c = p.footprint[(k + 1) % n];
        let len = (c[0] - a[0]).hypot(c[1] - a[1]);
        let steps = (len / (0.25 * res)).ceil().max(1.0) as usize;
        for j in 0..=steps {
            let t = j as f64 / steps as f64;
            if let Some(i) = cell(a[0] + t * (c[0] - a[0]), a[1] + t * (c[1] - a[1])) {
                mark(i);
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::world::Prism;

    /// A 3 m block, a 0.3 m block below the band and a thin 5 m pole.
    pub(crate) fn three_prisms() -> World {
        World {
            name: "t".into(),
            prisms: vec![
                Prism::rect("b", [5.0, 5.0], 2.0, 2.0, 0.0, 0.0, 3.0).unwrap(),
                Prism::rect("low", [-5.0, 5.0], 2.0, 2.0, 0.0, 0.0, 0.3).unwrap(),
                Prism::rect("pole", [0.0, -5.0], 0.05, 0.05, 0.0, 0.0, 5.0).unwrap(),
            ],
            ground: Default::default(),
            route: vec![],
        }
    }

    #[test]
    fn band_rule_and_raster() {
        let w = three_prisms();
        let m = TrueMap::rasterize(&w, 0.1, [1.0, 4.0], 1.0);
        assert!(m.is_occupied_at(5.0, 5.0));
        assert!(m.is_occupied_at(4.05, 5.0));
        assert!(!m.is_occupied_at(3.9, 5.0));
        assert!(!m.is_occupied_at(-5.0, 5.0), "below the band");
        assert!(m.is_occupied_at(0.0, -5.0), "thin pole");
        // 2 m x 2 m = 400 cells (+ outline cells on the far edges) + pole
        let n = m.occupied_count();
        assert!((400..=450).contains(&n), "{n}");
    }
}
