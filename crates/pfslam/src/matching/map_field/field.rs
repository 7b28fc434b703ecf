//! The likelihood field: for every cell of the map, the log-likelihood of a return ending
//! there, from its distance to the nearest occupied cell (an exact Euclidean distance
//! transform). Two tables: sharp for tracking, broad for global localisation.

use crate::kernels::field_loglik::CentreTable;
use crate::map::{BinaryMap, CellState, MapLimits};

/// Log-likelihood tables over a map's raster.
#[derive(Debug, Clone)]
pub struct LikelihoodField {
    limits: MapLimits,
    width: usize,
    height: usize,
    /// Distance to the nearest occupied cell (m), clamped at the field's reach.
    distance_m: Vec<f32>,
    /// Log-likelihood of a return per cell: tracking, then global.
    tables: [Vec<f32>; 2],
    /// The log-likelihood off the raster (the uniform floor alone).
    floor: f32,
    /// The log-likelihood at distance 0 (on a wall).
    peak: f32,
}

/// Which table to read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sharpness {
    /// `sigma_hit_m`: tracking a converged estimate.
    Tracking = 0,
    /// `global_sigma_hit_m`: global localisation and recovery.
    Global = 1,
}

/// The parameters of the field's model.
#[derive(Debug, Clone, Copy)]
pub struct FieldModel {
    /// Hit standard deviations: tracking, global (m).
    pub sigma_hit_m: [f64; 2],
    /// Weight of the hit model.
    pub z_hit: f64,
    /// Reach of the distance transform (m).
    pub max_distance_m: f64,
    /// The sensor's range, over which the uniform floor spreads (m).
    pub range_max_m: f64,
}

impl LikelihoodField {
    /// The field of `map` under `model`.
    pub fn new(map: &BinaryMap, model: &FieldModel) -> Self {
        let res = map.limits.resolution_m();
        let reach_cells = (model.max_distance_m / res).ceil();
        let squared = distance_transform(map, (reach_cells * reach_cells) as f32);
        let cap = model.max_distance_m as f32;
        let distance_m: Vec<f32> = squared
            .iter()
            .map(|&d2| (d2.sqrt() * res as f32).min(cap))
            .collect();
        let floor_p = (1.0 - model.z_hit) / model.range_max_m.max(1.0);
        let table = |sigma: f64| -> Vec<f32> {
            let k = 1.0 / (2.0 * sigma * sigma);
            distance_m
                .iter()
                .map(|&d| {
                    let d = d as f64;
                    (model.z_hit * (-d * d * k).exp() + floor_p).ln() as f32
                })
                .collect()
        };
        let tables = [table(model.sigma_hit_m[0]), table(model.sigma_hit_m[1])];
        LikelihoodField {
            limits: map.limits,
            width: map.width,
            height: map.height,
            distance_m,
            tables,
            floor: floor_p.ln() as f32,
            peak: (model.z_hit + floor_p).ln() as f32,
        }
    }

    /// The log-likelihood of a return at `(x_m, y_m)`, bilinear between the four nearest
    /// cell centres: a step function of the cell would leave the estimate free to wander
    /// inside a cell, and the map's cells are often as large as the accuracy wanted.
    #[inline]
    pub fn log_likelihood(&self, sharpness: Sharpness, x_m: f64, y_m: f64) -> f32 {
        let (cx, cy) = self.limits.cell_coords(x_m, y_m);
        self.log_likelihood_at_centres(sharpness, cx - 0.5, cy - 0.5)
    }

    /// The tracking log-likelihood at `(x_m, y_m)` as [`Self::log_likelihood`] gives it, with
    /// its gradient (per metre) inside the raster; off it, the floor and a zero gradient.
    pub fn tracking_with_gradient(&self, x_m: f64, y_m: f64) -> (f32, [f32; 2]) {
        let (cx, cy) = self.limits.cell_coords(x_m, y_m);
        let (u, v) = (cx - 0.5, cy - 0.5);
        let (i0, j0) = (floor_f64(u), floor_f64(v));
        let (w, h) = (self.width as f64, self.height as f64);
        if !(i0 >= 0.0 && j0 >= 0.0 && i0 + 1.0 < w && j0 + 1.0 < h) {
            return (
                self.log_likelihood_at_centres(Sharpness::Tracking, u, v),
                [0.0; 2],
            );
        }
        let table = &self.tables[Sharpness::Tracking as usize];
        let (fx, fy) = ((u - i0) as f32, (v - j0) as f32);
        let k = j0 as usize * self.width + i0 as usize;
        let (a, b) = (table[k], table[k + 1]);
        let (c, d) = (table[k + self.width], table[k + self.width + 1]);
        let low = a + fx * (b - a);
        let high = c + fx * (d - c);
        let inv = self.limits.inv_resolution() as f32;
        let d_du = (b - a) + fy * ((d - c) - (b - a));
        (low + fy * (high - low), [d_du * inv, (high - low) * inv])
    }

    /// The highest log-likelihood of a return (on a wall).
    pub fn peak(&self) -> f32 {
        self.peak
    }

    /// The map from world to the coordinates [`Self::log_likelihood_at_centres`] takes:
    /// `(u, v) = (x_m, y_m) * scale - offset`, cell centres at whole numbers.
    pub fn centre_coordinates(&self) -> (f64, [f64; 2]) {
        let inv = self.limits.inv_resolution();
        (
            inv,
            [
                self.limits.origin_x_m() * inv + 0.5,
                self.limits.origin_y_m() * inv + 0.5,
            ],
        )
    }

    /// The table of `sharpness` for the kernels, in the coordinates of
    /// [`Self::log_likelihood_at_centres`].
    pub(crate) fn centre_table(&self, sharpness: Sharpness) -> CentreTable<'_> {
        CentreTable {
            cells: &self.tables[sharpness as usize],
            width: self.width,
            height: self.height,
        }
    }

    /// [`Self::log_likelihood`] at coordinates in which cell centres lie at whole numbers.
    #[inline]
    pub fn log_likelihood_at_centres(&self, sharpness: Sharpness, u: f64, v: f64) -> f32 {
        let table = &self.tables[sharpness as usize];
        let (i0, j0) = (floor_f64(u), floor_f64(v));
        let (fx, fy) = ((u - i0) as f32, (v - j0) as f32);
        let (w, h) = (self.width as f64, self.height as f64);
        if i0 >= 0.0 && j0 >= 0.0 && i0 + 1.0 < w && j0 + 1.0 < h {
            // Inside: the four cells without a bounds test each (the same values and
            // arithmetic as below, so the same bits).
            let k = j0 as usize * self.width + i0 as usize;
            let (row0, row1) = (&table[k..k + 2], &table[k + self.width..k + self.width + 2]);
            let low = row0[0] + fx * (row0[1] - row0[0]);
            let high = row1[0] + fx * (row1[1] - row1[0]);
            return low + fy * (high - low);
        }
        let at = |i: f64, j: f64| -> f32 {
            if i < 0.0 || j < 0.0 || i >= w || j >= h {
                self.floor
            } else {
                table[j as usize * self.width + i as usize]
            }
        };
        let (a, b) = (at(i0, j0), at(i0 + 1.0, j0));
        let (c, d) = (at(i0, j0 + 1.0), at(i0 + 1.0, j0 + 1.0));
        let low = a + fx * (b - a);
        let high = c + fx * (d - c);
        low + fy * (high - low)
    }

    /// The distance from `(x_m, y_m)` to the nearest occupied cell (m, clamped at the reach;
    /// the reach off the raster).
    pub fn distance_m(&self, x_m: f64, y_m: f64) -> f32 {
        match self.index(x_m, y_m) {
            Some(k) => self.distance_m[k],
            None => f32::INFINITY,
        }
    }

    #[inline]
    fn index(&self, x_m: f64, y_m: f64) -> Option<usize> {
        let (ci, cj) = self.limits.cell_coords(x_m, y_m);
        let (i, j) = (floor_f64(ci), floor_f64(cj));
        if i < 0.0 || j < 0.0 || i >= self.width as f64 || j >= self.height as f64 {
            return None;
        }
        Some(j as usize * self.width + i as usize)
    }
}

/// `v.floor()` for the cell coordinates of the raster (within +-2^31 cells; saturating
/// beyond, which stays off the raster) without the libm call of baseline x86-64.
#[inline(always)]
fn floor_f64(v: f64) -> f64 {
    f64::from(crate::map::limits::floor_to_i32(v))
}

/// Squared distance (cells²) from every cell to the nearest occupied cell, at most `cap`
/// (Felzenszwalb and Huttenlocher's exact transform: columns, then rows).
fn distance_transform(map: &BinaryMap, cap: f32) -> Vec<f32> {
    let (w, h) = (map.width, map.height);
    let mut d2: Vec<f32> = map
        .cells
        .iter()
        .map(|&s| if s == CellState::Occupied { 0.0 } else { cap })
        .collect();
    let mut scratch = Scratch::new(w.max(h));
    let mut line = vec![0f32; h];
    for i in 0..w {
        for j in 0..h {
            line[j] = d2[j * w + i];
        }
        scratch.transform(&mut line);
        for j in 0..h {
            d2[j * w + i] = line[j].min(cap);
        }
    }
    for row in d2.chunks_mut(w.max(1)) {
        scratch.transform(row);
        for v in row.iter_mut() {
            *v = v.min(cap);
        }
    }
    d2
}

/// Buffers of the 1-D transform (lower envelope of parabolas).
struct Scratch {
    sites: Vec<usize>,
    bounds: Vec<f32>,
    out: Vec<f32>,
}

impl Scratch {
    fn new(n: usize) -> Self {
        Scratch {
            sites: vec![0; n],
            bounds: vec![0.0; n + 1],
            out: vec![0.0; n],
        }
    }

    /// `f[q] <- min_p (f[p] + (q - p)²)` in place.
    fn transform(&mut self, f: &mut [f32]) {
        let n = f.len();
        if n == 0 {
            return;
        }
        let (v, z) = (&mut self.sites, &mut self.bounds);
        let intersect = |f: &[f32], q: usize, p: usize| -> f32 {
            let (qf, pf) = (q as f32, p as f32);
            ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
        };
        let mut k = 0usize;
        v[0] = 0;
        z[0] = f32::NEG_INFINITY;
        z[1] = f32::INFINITY;
        for q in 1..n {
            let mut s = intersect(f, q, v[k]);
            while k > 0 && s <= z[k] {
                k -= 1;
                s = intersect(f, q, v[k]);
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f32::INFINITY;
        }
        k = 0;
        for q in 0..n {
            while z[k + 1] < q as f32 {
                k += 1;
            }
            let dq = q as f32 - v[k] as f32;
            self.out[q] = dq * dq + f[v[k]];
        }
        f.copy_from_slice(&self.out[..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map_with(occupied: &[(i64, i64)], w: usize, h: usize) -> BinaryMap {
        let mut m = BinaryMap::filled(MapLimits::new(0.1, 0.0, 0.0), w, h, CellState::Free);
        for &(i, j) in occupied {
            m.set(i, j, CellState::Occupied);
        }
        m
    }

    /// The field of a 3 x 3 m map with one occupied cell at (1.05, 1.05) m.
    fn one_cell_field() -> LikelihoodField {
        let model = FieldModel {
            sigma_hit_m: [0.1, 0.3],
            z_hit: 0.9,
            max_distance_m: 1.0,
            range_max_m: 30.0,
        };
        LikelihoodField::new(&map_with(&[(10, 10)], 30, 30), &model)
    }

    #[test]
    fn transform_matches_brute_force() {
        let occ = [(3, 4), (17, 2), (9, 15), (0, 0), (12, 12)];
        let (w, h) = (21, 18);
        let m = map_with(&occ, w, h);
        let d2 = distance_transform(&m, 1e9);
        for j in 0..h {
            for i in 0..w {
                let want = occ
                    .iter()
                    .map(|&(a, b)| ((a - i as i64).pow(2) + (b - j as i64).pow(2)) as f32)
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(d2[j * w + i], want, "cell ({i}, {j})");
            }
        }
    }

    #[test]
    fn likelihood_falls_with_distance_and_floors_off_map() {
        let f = one_cell_field();
        let at = |s, d: f64| f.log_likelihood(s, 1.05 + d, 1.05);
        assert!(at(Sharpness::Tracking, 0.0) > at(Sharpness::Tracking, 0.1));
        assert!(at(Sharpness::Tracking, 0.1) > at(Sharpness::Tracking, 0.3));
        // the broad table forgives the same offset more
        let drop = |s| at(s, 0.0) - at(s, 0.3);
        assert!(drop(Sharpness::Global) < drop(Sharpness::Tracking));
        assert!((f.distance_m(1.05, 1.05 + 0.5) - 0.5).abs() < 1e-5);
        assert_eq!(f.distance_m(2.95, 2.95), 1.0);
        assert_eq!(f.log_likelihood(Sharpness::Tracking, -5.0, 1.0), f.floor);
        // between two cell centres, the mean of the two
        let (c0, c1) = (at(Sharpness::Tracking, 0.1), at(Sharpness::Tracking, 0.2));
        let mid = at(Sharpness::Tracking, 0.15);
        assert!((mid - 0.5 * (c0 + c1)).abs() < 1e-5, "{c0} {mid} {c1}");
        assert!(f.floor < at(Sharpness::Tracking, 0.3));
    }

    /// The gradient is the bilinear field's slope: central differences inside a cell agree,
    /// the value is `log_likelihood`'s, and off the raster the slope is 0.
    #[test]
    fn tracking_gradient_is_the_fields_slope() {
        let f = one_cell_field();
        let h = 1e-4;
        for (x, y) in [(1.13, 1.01), (0.91, 1.17), (1.32, 0.84)] {
            let (v, [gx, gy]) = f.tracking_with_gradient(x, y);
            assert_eq!(v, f.log_likelihood(Sharpness::Tracking, x, y));
            let ll = |x, y| f64::from(f.log_likelihood(Sharpness::Tracking, x, y));
            let dx = (ll(x + h, y) - ll(x - h, y)) / (2.0 * h);
            let dy = (ll(x, y + h) - ll(x, y - h)) / (2.0 * h);
            assert!(
                (f64::from(gx) - dx).abs() < 0.02 * dx.abs().max(1.0),
                "{gx} {dx}"
            );
            assert!(
                (f64::from(gy) - dy).abs() < 0.02 * dy.abs().max(1.0),
                "{gy} {dy}"
            );
        }
        assert_eq!(f.tracking_with_gradient(-5.0, 1.0), (f.floor, [0.0, 0.0]));
        assert!(f.peak() >= f.log_likelihood(Sharpness::Tracking, 1.05, 1.05));
    }
}
