//! 3-D ray casting against a [`World`] (vertical walls of extruded polygons, their top and
//! bottom faces) and the ground plane `z = 0`.
//!
//! Wall segments are binned in a uniform 2-D grid; a ray walks the grid cells it crosses in
//! order (Amanatides & Woo) and stops at the first cell whose far boundary lies beyond the
//! nearest hit found so far. A ray also stops where it leaves the grid, rises above the
//! highest obstacle, or reaches the ground.

use super::world::{World, point_in_polygon};

/// What a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HitKind {
    /// The ground plane `z = 0`.
    Ground,
    /// Obstacle number `i` of [`World::prisms`].
    Obstacle(u32),
}

/// A hit: distance along the ray (m) and what was hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance from the ray origin (m).
    pub range_m: f64,
    /// What was hit.
    pub kind: HitKind,
}

#[derive(Debug, Clone, Copy)]
struct Segment {
    ax: f64,
    ay: f64,
    ex: f64,
    ey: f64,
    z_min: f64,
    z_max: f64,
    prism: u32,
}

/// A world prepared for fast ray casting.
#[derive(Debug, Clone)]
pub struct RayCaster {
    segments: Vec<Segment>,
    footprints: Vec<Vec<[f64; 2]>>,
    /// CSR layout: segments of cell `c` are `cell_items[cell_start[c]..cell_start[c + 1]]`.
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    origin: [f64; 2],
    cell_m: f64,
    nx: usize,
    ny: usize,
    top_z_m: f64,
}

impl RayCaster {
    /// Indexes the world's walls in a grid of `cell_m` cells covering its bounds plus
    /// `margin_m` on every side.
    pub fn new(world: &World, cell_m: f64, margin_m: f64) -> Self {
        let b = world.bounds();
        let origin = [b[0] - margin_m, b[1] - margin_m];
        let cell_m = cell_m.max(0.1);
        let nx = (((b[2] + margin_m - origin[0]) / cell_m).ceil() as usize).max(1);
        let ny = (((b[3] + margin_m - origin[1]) / cell_m).ceil() as usize).max(1);
        let mut segments = Vec::new();
        let mut top_z_m: f64 = 0.0;
        for (pi, p) in world.prisms.iter().enumerate() {
            top_z_m = top_z_m.max(p.z_max_m);
            let n = p.footprint.len();
            for k in 0..n {
                let a = p.footprint[k];
                let c = p.footprint[(k + 1) % n];
                segments.push(Segment {
                    ax: a[0],
                    ay: a[1],
                    ex: c[0] - a[0],
                    ey: c[1] - a[1],
                    z_min: p.z_min_m,
                    z_max: p.z_max_m,
                    prism: pi as u32,
                });
            }
        }
        // Bin each segment into the cells its bounding box touches (conservative, simple).
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
        for (si, s) in segments.iter().enumerate() {
            let (x0, x1) = (s.ax.min(s.ax + s.ex), s.ax.max(s.ax + s.ex));
            let (y0, y1) = (s.ay.min(s.ay + s.ey), s.ay.max(s.ay + s.ey));
            let cx0 = (((x0 - origin[0]) / cell_m).floor().max(0.0) as usize).min(nx - 1);
            let cx1 = (((x1 - origin[0]) / cell_m).floor().max(0.0) as usize).min(nx - 1);
            let cy0 = (((y0 - origin[1]) / cell_m).floor().max(0.0) as usize).min(ny - 1);
            let cy1 = (((y1 - origin[1]) / cell_m).floor().max(0.0) as usize).min(ny - 1);
            for cy in cy0..=cy1 {
                for cx in cx0..=cx1 {
                    lists[cy * nx + cx].push(si as u32);
                }
            }
        }
        let mut cell_start = Vec::with_capacity(nx * ny + 1);
        let mut cell_items = Vec::new();
        cell_start.push(0u32);
        for l in &lists {
            cell_items.extend_from_slice(l);
            cell_start.push(cell_items.len() as u32);
        }
        RayCaster {
            segments,
            footprints: world.prisms.iter().map(|p| p.footprint.clone()).collect(),
            cell_start,
            cell_items,
            origin,
            cell_m,
            nx,
            ny,
            top_z_m,
        }
    }

    /// Casts a ray from `o` along the unit direction `d` (world frame, m); returns the first
    /// hit closer than `max_range_m`, or `None`.
    pub fn cast(&self, o: [f64; 3], d: [f64; 3], max_range_m: f64) -> Option<Hit> {
        let mut best_t = max_range_m;
        let mut best_kind = None;
        if d[2] < 0.0 && o[2] > 0.0 {
            let tg = -o[2] / d[2];
            if tg < best_t {
                best_t = tg;
                best_kind = Some(HitKind::Ground);
            }
        }
        // Nothing lies above the highest obstacle: the walk ends there.
        let mut t_end = best_t;
        if d[2] > 0.0 && o[2] < self.top_z_m {
            t_end = t_end.min((self.top_z_m - o[2]) / d[2]);
        } else if d[2] >= 0.0 && o[2] >= self.top_z_m {
            t_end = 0.0;
        }
        // Grid walk in the xy projection; the parameter t is the 3-D distance.
        let (dx, dy) = (d[0], d[1]);
        let fx = (o[0] - self.origin[0]) / self.cell_m;
        let fy = (o[1] - self.origin[1]) / self.cell_m;
        if fx < 0.0 || fy < 0.0 || fx >= self.nx as f64 || fy >= self.ny as f64 {
            return best_kind.map(|kind| Hit {
                range_m: best_t,
                kind,
            });
        }
        let mut cx = fx as isize;
        let mut cy = fy as isize;
        let step_x: isize = if dx > 0.0 { 1 } else { -1 };
        let step_y: isize = if dy > 0.0 { 1 } else { -1 };
        let t_delta_x = if dx != 0.0 {
            self.cell_m / dx.abs()
        } else {
            f64::INFINITY
        };
        let t_delta_y = if dy != 0.0 {
            self.cell_m / dy.abs()
        } else {
            f64::INFINITY
        };
        let mut t_max_x = if dx > 0.0 {
            ((cx + 1) as f64 - fx) * t_delta_x
        } else if dx < 0.0 {
            (fx - cx as f64) * t_delta_x
        } else {
            f64::INFINITY
        };
        let mut t_max_y = if dy > 0.0 {
            ((cy + 1) as f64 - fy) * t_delta_y
        } else if dy < 0.0 {
            (fy - cy as f64) * t_delta_y
        } else {
            f64::INFINITY
        };
        loop {
            let c = cy as usize * self.nx + cx as usize;
            let (s0, s1) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
            for &si in &self.cell_items[s0..s1] {
                let s = &self.segments[si as usize];
                if let Some(t) = self.intersect(s, o, d) {
                    if t < best_t {
                        best_t = t;
                        best_kind = Some(HitKind::Obstacle(s.prism));
                    }
                }
            }
            let t_next = t_max_x.min(t_max_y);
            if t_next >= best_t.min(t_end) {
                break;
            }
            if t_max_x < t_max_y {
                cx += step_x;
                t_max_x += t_delta_x;
                if cx < 0 || cx >= self.nx as isize {
                    break;
                }
            } else {
                cy += step_y;
                t_max_y += t_delta_y;
                if cy < 0 || cy >= self.ny as isize {
                    break;
                }
            }
        }
        best_kind.map(|kind| Hit {
            range_m: best_t,
            kind,
        })
    }

    /// Distance to the obstacle surface reached through wall segment `s`, if any: the wall
    /// itself, or the top/bottom face reached over the footprint. (An exactly vertical ray
    /// crosses no wall and so sees no face: no sensor here looks straight up or down.)
    #[inline]
    fn intersect(&self, s: &Segment, o: [f64; 3], d: [f64; 3]) -> Option<f64> {
        // Solve o + t d = a + u e in xy.
        let denom = s.ex * d[1] - s.ey * d[0];
        if denom == 0.0 {
            return None;
        }
        let wx = s.ax - o[0];
        let wy = s.ay - o[1];
        let t = (s.ex * wy - s.ey * wx) / denom;
        if t < 0.0 {
            return None;
        }
        let u = (d[0] * wy - d[1] * wx) / denom;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let z = o[2] + t * d[2];
        // Footprints are counter-clockwise: entering when the ray crosses to the left side.
        let entering = denom > 0.0;
        if entering && z >= s.z_min && z <= s.z_max {
            return Some(t);
        }
        // A top (bottom) face is hit when the ray reaches z_max going down (z_min going up)
        // over the footprint: it entered above (below) the wall, or started over the footprint
        // and leaves it below (above) that height.
        let z_face = if entering && d[2] < 0.0 && z > s.z_max {
            s.z_max
        } else if entering && d[2] > 0.0 && z < s.z_min {
            s.z_min
        } else if entering {
            return None;
        } else if d[2] < 0.0 && o[2] > s.z_max && z < s.z_max {
            s.z_max
        } else if d[2] > 0.0 && o[2] < s.z_min && z > s.z_min {
            s.z_min
        } else {
            return None;
        };
        let tf = (z_face - o[2]) / d[2];
        let px = o[0] + tf * d[0];
        let py = o[1] + tf * d[1];
        point_in_polygon(&self.footprints[s.prism as usize], px, py).then_some(tf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::world::Prism;

    fn one(p: Prism) -> World {
        World {
            name: "t".into(),
            prisms: vec![p],
            ground: Default::default(),
            route: vec![],
        }
    }

    #[test]
    fn wall_top_and_ground() {
        // a 2 m high block from x = 10 to 12
        let w = one(Prism::rect("b", [11.0, 0.0], 2.0, 20.0, 0.0, 0.0, 2.0).unwrap());
        let rc = RayCaster::new(&w, 1.5, 100.0);
        // horizontal at z = 1: wall at 10
        let h = rc.cast([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], 80.0).unwrap();
        assert!((h.range_m - 10.0).abs() < 1e-9 && h.kind == HitKind::Obstacle(0));
        // from z = 3 going down at 45 deg... hits the top at x = 1 + ... : z = 3 - t/sqrt2
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let h = rc.cast([9.5, 0.0, 3.0], [s, 0.0, -s], 80.0).unwrap();
        // reaches z = 2 at x = 10.5 (inside): t = sqrt(2)
        assert!((h.range_m - 2f64.sqrt()).abs() < 1e-9, "{h:?}");
        // over it and beyond: ground at x = 20 from z = 3 with slope 3/20... misses the top
        let dir = [20.0, 0.0, -2.5];
        let n = (dir[0] * dir[0] + dir[2] * dir[2] as f64).sqrt();
        let h = rc
            .cast([0.0, 0.0, 2.5], [dir[0] / n, 0.0, dir[2] / n], 80.0)
            .unwrap();
        // at x = 10 z = 1.25 -> wall hit
        assert!((h.range_m - n * 0.5).abs() < 1e-9, "{h:?}");
        // ground hit in the other direction
        let h = rc
            .cast([0.0, 0.0, 2.5], [-dir[0] / n, 0.0, dir[2] / n], 80.0)
            .unwrap();
        assert_eq!(h.kind, HitKind::Ground);
        assert!((h.range_m - n).abs() < 1e-9);
        // upward over the wall: nothing
        assert!(rc.cast([0.0, 0.0, 1.0], [0.6, 0.0, 0.8], 80.0).is_none());
    }

    #[test]
    fn floating_canopy_bottom() {
        let w = one(Prism::rect("t", [5.0, 0.0], 2.0, 2.0, 0.0, 3.0, 6.0).unwrap());
        let rc = RayCaster::new(&w, 2.0, 50.0);
        // under it horizontally: nothing
        assert!(rc.cast([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], 80.0).is_none());
        // slanted up from outside into the bottom face
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let h = rc.cast([2.0, 0.0, 1.0], [s, 0.0, s], 80.0).unwrap();
        // wall x = 4 at z = 3: exactly the bottom edge -> counts as the wall
        assert!((h.range_m - 2.0 * 2f64.sqrt()).abs() < 1e-9, "{h:?}");
        let h = rc.cast([2.5, 0.0, 1.0], [s, 0.0, s], 80.0).unwrap();
        // reaches z = 3 at x = 4.5 (inside): bottom face
        assert!((h.range_m - 2.0 * 2f64.sqrt()).abs() < 1e-9, "{h:?}");
    }
}
