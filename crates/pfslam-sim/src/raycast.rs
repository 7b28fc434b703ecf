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

/// The nearest hit of a ray so far: its distance, `kind` = `None` while there is none (then
/// `t` is the range limit).
struct Nearest {
    t: f64,
    kind: Option<HitKind>,
}

impl Nearest {
    /// Takes the hit at `t` when it is nearer (a tie keeps the earlier one).
    #[inline]
    fn offer(&mut self, t: f64, kind: HitKind) {
        if t < self.t {
            self.t = t;
            self.kind = Some(kind);
        }
    }
}

/// One axis of a grid walk from the fractional cell coordinate `f` (in cell `c`) along the
/// direction component `d`: the ray length across one cell and to the next cell border on
/// this axis (both infinite when `d` is 0).
#[inline]
fn axis_start(cell_m: f64, f: f64, c: isize, d: f64) -> (f64, f64) {
    let t_delta = if d != 0.0 {
        cell_m / d.abs()
    } else {
        f64::INFINITY
    };
    let t_max = if d > 0.0 {
        ((c + 1) as f64 - f) * t_delta
    } else if d < 0.0 {
        (f - c as f64) * t_delta
    } else {
        f64::INFINITY
    };
    (t_delta, t_max)
}

/// A ray's walk through the grid's cells in the xy projection (Amanatides & Woo): the cell
/// it is in, and the 3-D distances at which it crosses the next x and y cell boundaries.
struct GridWalk {
    cx: isize,
    cy: isize,
    step_x: isize,
    step_y: isize,
    t_delta_x: f64,
    t_delta_y: f64,
    t_max_x: f64,
    t_max_y: f64,
}

impl GridWalk {
    /// The index of the current cell in a grid `nx` cells wide.
    #[inline]
    fn cell(&self, nx: usize) -> usize {
        self.cy as usize * nx + self.cx as usize
    }

    /// The distance at which the ray leaves the current cell.
    #[inline]
    fn t_next(&self) -> f64 {
        self.t_max_x.min(self.t_max_y)
    }

    /// Steps into the next cell; false when that leaves the `nx` x `ny` grid.
    #[inline]
    fn advance(&mut self, nx: usize, ny: usize) -> bool {
        if self.t_max_x < self.t_max_y {
            self.cx += self.step_x;
            self.t_max_x += self.t_delta_x;
            self.cx >= 0 && self.cx < nx as isize
        } else {
            self.cy += self.step_y;
            self.t_max_y += self.t_delta_y;
            self.cy >= 0 && self.cy < ny as isize
        }
    }
}

/// A world prepared for fast ray casting.
#[derive(Debug, Clone)]
pub struct RayCaster {
    segments: Vec<Segment>,
    footprints: Vec<Vec<[f64; 2]>>,
    /// CSR layout: segments of cell `c` are `cell_items[cell_start[c]..cell_start[c + 1]]`.
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    /// CSR layout of the prisms whose footprint's bounding box touches each cell: their top
    /// and bottom faces are tested in every cell they cover, so a face hit is found in the cell
    /// where it lies (the walk stops at the nearest hit so far, possibly before the ray reaches
    /// the wall through which it would leave the footprint).
    prism_start: Vec<u32>,
    prism_items: Vec<u32>,
    z_range: Vec<[f64; 2]>,
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
        let cell_range = |lo: f64, hi: f64, o: f64, n: usize| {
            let a = (((lo - o) / cell_m).floor().max(0.0) as usize).min(n - 1);
            let b = (((hi - o) / cell_m).floor().max(0.0) as usize).min(n - 1);
            a..=b
        };
        let mut prism_lists: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
        for (pi, p) in world.prisms.iter().enumerate() {
            let xs = p.footprint.iter().map(|q| q[0]);
            let ys = p.footprint.iter().map(|q| q[1]);
            let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
            let (y0, y1) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
            if !(x0.is_finite() && y0.is_finite()) {
                continue;
            }
            for cy in cell_range(y0, y1, origin[1], ny) {
                for cx in cell_range(x0, x1, origin[0], nx) {
                    prism_lists[cy * nx + cx].push(pi as u32);
                }
            }
        }
        let csr = |lists: &[Vec<u32>]| {
            let mut start = Vec::with_capacity(lists.len() + 1);
            let mut items = Vec::new();
            start.push(0u32);
            for l in lists {
                items.extend_from_slice(l);
                start.push(items.len() as u32);
            }
            (start, items)
        };
        let (cell_start, cell_items) = csr(&lists);
        let (prism_start, prism_items) = csr(&prism_lists);
        RayCaster {
            segments,
            footprints: world.prisms.iter().map(|p| p.footprint.clone()).collect(),
            cell_start,
            cell_items,
            prism_start,
            prism_items,
            z_range: world
                .prisms
                .iter()
                .map(|p| [p.z_min_m, p.z_max_m])
                .collect(),
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
        let mut best = Nearest {
            t: max_range_m,
            kind: None,
        };
        if d[2] < 0.0 && o[2] > 0.0 {
            best.offer(-o[2] / d[2], HitKind::Ground);
        }
        // Nothing lies above the highest obstacle: the walk ends there.
        let mut t_end = best.t;
        if d[2] > 0.0 && o[2] < self.top_z_m {
            t_end = t_end.min((self.top_z_m - o[2]) / d[2]);
        } else if d[2] >= 0.0 && o[2] >= self.top_z_m {
            t_end = 0.0;
        }
        // Grid walk in the xy projection; the parameter t is the 3-D distance.
        if let Some(mut walk) = self.walk_from(o, d) {
            loop {
                self.nearest_in_cell(walk.cell(self.nx), o, d, &mut best);
                // The cells beyond lie farther than the nearest hit (or the walk's end).
                if walk.t_next() >= best.t.min(t_end) || !walk.advance(self.nx, self.ny) {
                    break;
                }
            }
        }
        best.kind.map(|kind| Hit {
            range_m: best.t,
            kind,
        })
    }

    /// The walk of the ray from `o` along `d` through the grid's cells, `None` when `o` lies
    /// outside the grid.
    #[inline]
    fn walk_from(&self, o: [f64; 3], d: [f64; 3]) -> Option<GridWalk> {
        let (dx, dy) = (d[0], d[1]);
        let fx = (o[0] - self.origin[0]) / self.cell_m;
        let fy = (o[1] - self.origin[1]) / self.cell_m;
        if fx < 0.0 || fy < 0.0 || fx >= self.nx as f64 || fy >= self.ny as f64 {
            return None;
        }
        let cx = fx as isize;
        let cy = fy as isize;
        let (t_delta_x, t_max_x) = axis_start(self.cell_m, fx, cx, dx);
        let (t_delta_y, t_max_y) = axis_start(self.cell_m, fy, cy, dy);
        Some(GridWalk {
            cx,
            cy,
            step_x: if dx > 0.0 { 1 } else { -1 },
            step_y: if dy > 0.0 { 1 } else { -1 },
            t_delta_x,
            t_delta_y,
            t_max_x,
            t_max_y,
        })
    }

    /// Offers `best` the walls binned in cell `c` and the top and bottom faces of the prisms
    /// over it.
    #[inline]
    fn nearest_in_cell(&self, c: usize, o: [f64; 3], d: [f64; 3], best: &mut Nearest) {
        let (s0, s1) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
        for &si in &self.cell_items[s0..s1] {
            let s = &self.segments[si as usize];
            if let Some(t) = self.intersect(s, o, d) {
                best.offer(t, HitKind::Obstacle(s.prism));
            }
        }
        let (p0, p1) = (
            self.prism_start[c] as usize,
            self.prism_start[c + 1] as usize,
        );
        for &pi in &self.prism_items[p0..p1] {
            if let Some(t) = self.face_hit(pi, o, d) {
                best.offer(t, HitKind::Obstacle(pi));
            }
        }
    }

    /// Distance to the top face (ray going down from above it) or the bottom face (going up
    /// from below it) of prism `pi`, if the ray meets it over the footprint.
    #[inline]
    fn face_hit(&self, pi: u32, o: [f64; 3], d: [f64; 3]) -> Option<f64> {
        let [z_min, z_max] = self.z_range[pi as usize];
        let z_face = if d[2] < 0.0 && o[2] > z_max {
            z_max
        } else if d[2] > 0.0 && o[2] < z_min {
            z_min
        } else {
            return None;
        };
        let tf = (z_face - o[2]) / d[2];
        let px = o[0] + tf * d[0];
        let py = o[1] + tf * d[1];
        point_in_polygon(&self.footprints[pi as usize], px, py).then_some(tf)
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

/// Beam label: no return.
pub const BEAM_NONE: u8 = 0;
/// Beam label: hit an obstacle.
pub const BEAM_OBSTACLE: u8 = 1;
/// Beam label: hit the ground (floor).
pub const BEAM_FLOOR: u8 = 2;

/// Errors applied to every beam of a simulated scan.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BeamErrors {
    /// Range noise (m, standard deviation).
    pub(crate) range_noise_std_m: f64,
    /// Probability that a return is lost (0.0).
    pub(crate) dropout_prob: f64,
    /// Probability that a beam reads the maximum range ("no return").
    pub(crate) max_range_prob: f64,
}

/// A sensor's beams at one pose.
#[derive(Clone, Copy)]
pub(crate) struct ScanBeams<'a> {
    /// The sensor's pose in the world.
    pub(crate) world_from_sensor: &'a pfslam::geometry::Rigid3,
    /// Unit beam directions in the sensor frame.
    pub(crate) beams: &'a [nalgebra::Vector3<f64>],
    /// Beams that hit nothing closer read no return.
    pub(crate) max_range_m: f64,
}

/// Casts one scan: unit beam directions `beams` in the sensor frame, from
/// `world_from_sensor`. Writes ranges (f32 m, 0.0 = no return, with the errors) and, when
/// given, what each beam truly hit ([`BEAM_NONE`], [`BEAM_OBSTACLE`], [`BEAM_FLOOR`]; the label
/// is the truth even when the return was dropped).
pub(crate) fn cast_scan(
    caster: &RayCaster,
    sensor: &ScanBeams<'_>,
    err: &BeamErrors,
    rng: &mut rand_xoshiro::Xoshiro256PlusPlus,
    ranges: &mut [f32],
    mut labels: Option<&mut [u8]>,
) {
    use rand::RngExt;
    let ScanBeams {
        world_from_sensor,
        beams,
        max_range_m,
    } = *sensor;
    let t = &world_from_sensor.translation;
    let o = [t[0], t[1], t[2]];
    for (k, (b, out)) in beams.iter().zip(ranges.iter_mut()).enumerate() {
        let d = world_from_sensor.rotation * b;
        let hit = caster.cast(o, [d[0], d[1], d[2]], max_range_m);
        if let Some(l) = labels.as_deref_mut() {
            l[k] = match hit {
                None => BEAM_NONE,
                Some(Hit {
                    kind: HitKind::Ground,
                    ..
                }) => BEAM_FLOOR,
                Some(_) => BEAM_OBSTACLE,
            };
        }
        let mut range = hit.map_or(0.0, |h| h.range_m);
        if range > 0.0 {
            if err.range_noise_std_m > 0.0 {
                range = (range + err.range_noise_std_m * super::normal(rng))
                    .clamp(0.001, max_range_m - 1e-3);
            }
            if err.dropout_prob > 0.0 && rng.random::<f64>() < err.dropout_prob {
                range = 0.0;
            }
        }
        if err.max_range_prob > 0.0 && rng.random::<f64>() < err.max_range_prob {
            range = max_range_m;
        }
        *out = range as f32;
    }
}

/// Unit beam directions of a planar scanner in its own frame.
pub(crate) fn beam_directions(
    geom: &pfslam::sensors::LidarGeometry,
) -> Vec<nalgebra::Vector3<f64>> {
    (0..geom.beam_count)
        .map(|i| {
            let a = geom.beam_angle_rad(i);
            nalgebra::Vector3::new(a.cos(), a.sin(), 0.0)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Prism;

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
        let dir: [f64; 3] = [20.0, 0.0, -2.5];
        let n = (dir[0] * dir[0] + dir[2] * dir[2]).sqrt();
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

    /// Every segment and the ground, no grid: the reference for the grid walk.
    fn brute_force(rc: &RayCaster, o: [f64; 3], d: [f64; 3], max_range_m: f64) -> Option<f64> {
        let mut best = max_range_m;
        let mut found = false;
        if d[2] < 0.0 && o[2] > 0.0 && -o[2] / d[2] < best {
            best = -o[2] / d[2];
            found = true;
        }
        for s in &rc.segments {
            if let Some(t) = rc.intersect(s, o, d)
                && t < best
            {
                best = t;
                found = true;
            }
        }
        found.then_some(best)
    }

    proptest::proptest! {
        #[test]
        fn grid_walk_matches_brute_force(
            boxes in proptest::collection::vec(
                (-40.0f64..40.0, -40.0f64..40.0, 0.2f64..8.0, 0.2f64..8.0, 0.0f64..3.0,
                 0.0f64..2.0, 0.5f64..20.0),
                1..30,
            ),
            rays in proptest::collection::vec(
                (-30.0f64..30.0, -30.0f64..30.0, 0.1f64..5.0, 0.0f64..6.3, -1.2f64..1.2),
                1..40,
            ),
            cell in 0.5f64..6.0,
        ) {
            let prisms = boxes
                .iter()
                .filter_map(|&(x, y, l, w, yaw, z0, h)| Prism::rect("b", [x, y], l, w, yaw, z0, z0 + h))
                .collect();
            let w = World { name: "p".into(), prisms, ground: Default::default(), route: vec![] };
            let rc = RayCaster::new(&w, cell, 100.0);
            for &(x, y, z, az, el) in &rays {
                let d = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
                let got = rc.cast([x, y, z], d, 80.0).map(|h| h.range_m);
                let want = brute_force(&rc, [x, y, z], d, 80.0);
                match (got, want) {
                    (Some(a), Some(b)) => proptest::prop_assert!((a - b).abs() < 1e-9, "{a} vs {b}"),
                    (None, None) => {}
                    _ => proptest::prop_assert!(false, "{got:?} vs {want:?}"),
                }
            }
        }
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
