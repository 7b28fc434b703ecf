//! Worlds: extruded polygons with heights on a ground plane `z = 0`, an optional ground
//! texture, and the route a vehicle drives.
//!
//! # World-file format (`*.world`, plain text)
//!
//! One item per line; `#` starts a comment; blank lines are ignored; tokens are separated by
//! white space; lengths in metres, angles in degrees, colours as 0-255 integers. Every error
//! names `file:line`.
//!
//! ```text
//! name <NAME>                                   # optional, default: the file stem
//! prism <KIND> <Z_MIN> <Z_MAX> <X1> <Y1> <X2> <Y2> <X3> <Y3> [<X> <Y> ...]
//!                                               # vertical extrusion of a simple polygon
//!                                               # (>= 3 vertices, any orientation) from
//!                                               # Z_MIN to Z_MAX (Z_MIN >= 0 < Z_MAX)
//! box <KIND> <CX> <CY> <LENGTH> <WIDTH> <YAW_DEG> <Z_MIN> <Z_MAX>
//!                                               # rotated rectangle (shorthand for a prism)
//! ground <R> <G> <B>                            # default ground colour (default 90 90 90)
//! region <R> <G> <B> <X1> <Y1> <X2> <Y2> <X3> <Y3> [...]
//!                                               # coloured ground polygon (grass, asphalt)
//! marking <R> <G> <B> <WIDTH> <X1> <Y1> <X2> <Y2> [...]
//!                                               # painted polyline on the ground (road lines)
//! route <X1> <Y1> <X2> <Y2> [<X> <Y> ...]       # waypoints of the closed route driven in
//!                                               # order, repeatedly (several `route` lines
//!                                               # append); corners are rounded
//! ```
//!
//! `KIND` is a free word kept for information (`building`, `car`, `pole`, `tree`, `wall`,
//! `desk`, ...). A prism with `Z_MIN > 0` floats (a tree canopy, a table top): rays pass
//! under it. Later regions and markings paint over earlier ones. Obstacles are solid: rays
//! stop at their walls and at their top and bottom faces. See `crates/pfslam/worlds/` for an
//! example.

use super::SimError;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;

/// A vertical extrusion of a simple polygon: an obstacle.
#[derive(Debug, Clone, PartialEq)]
pub struct Prism {
    /// Free-form kind (`building`, `car`, `pole`, ...).
    pub kind: String,
    /// Footprint vertices `(x_m, y_m)`, counter-clockwise (normalised on construction).
    pub footprint: Vec<[f64; 2]>,
    /// Bottom face height (m).
    pub z_min_m: f64,
    /// Top face height (m).
    pub z_max_m: f64,
}

impl Prism {
    /// A prism from a polygon in any orientation; `None` when degenerate (fewer than three
    /// vertices, zero area, non-finite numbers, or `z_max <= z_min`).
    pub fn new(
        kind: &str,
        mut footprint: Vec<[f64; 2]>,
        z_min_m: f64,
        z_max_m: f64,
    ) -> Option<Self> {
        if footprint.len() < 3
            || !z_min_m.is_finite()
            || !z_max_m.is_finite()
            || z_max_m <= z_min_m
            || z_min_m < 0.0
            || footprint
                .iter()
                .any(|p| !p[0].is_finite() || !p[1].is_finite())
        {
            return None;
        }
        let area = signed_area(&footprint);
        if area.abs() < 1e-9 {
            return None;
        }
        if area < 0.0 {
            footprint.reverse();
        }
        Some(Prism {
            kind: kind.to_string(),
            footprint,
            z_min_m,
            z_max_m,
        })
    }

    /// A rotated rectangle centred at `(cx, cy)`.
    pub fn rect(
        kind: &str,
        center_m: [f64; 2],
        length_m: f64,
        width_m: f64,
        yaw_rad: f64,
        z_min_m: f64,
        z_max_m: f64,
    ) -> Option<Self> {
        let (s, c) = yaw_rad.sin_cos();
        let (hl, hw) = (0.5 * length_m, 0.5 * width_m);
        let corners = [(-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw)]
            .iter()
            .map(|&(x, y)| [center_m[0] + c * x - s * y, center_m[1] + s * x + c * y])
            .collect();
        Prism::new(kind, corners, z_min_m, z_max_m)
    }

    /// True when the point lies inside the footprint (even-odd rule).
    pub fn contains_xy(&self, x_m: f64, y_m: f64) -> bool {
        point_in_polygon(&self.footprint, x_m, y_m)
    }
}

/// The signed area of a polygon (positive when counter-clockwise).
pub(crate) fn signed_area(poly: &[[f64; 2]]) -> f64 {
    let n = poly.len();
    let mut a = 0.0;
    for i in 0..n {
        let p = poly[i];
        let q = poly[(i + 1) % n];
        a += p[0] * q[1] - q[0] * p[1];
    }
    0.5 * a
}

/// Even-odd point-in-polygon test.
pub(crate) fn point_in_polygon(poly: &[[f64; 2]], x: f64, y: f64) -> bool {
    let n = poly.len();
    let mut inside = false;
    let mut j = n - 1;
    for i in 0..n {
        let (xi, yi) = (poly[i][0], poly[i][1]);
        let (xj, yj) = (poly[j][0], poly[j][1]);
        if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// A coloured ground polygon.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundRegion {
    /// RGB colour.
    pub rgb: [u8; 3],
    /// Polygon vertices (m).
    pub polygon: Vec<[f64; 2]>,
}

/// A painted polyline on the ground (road marking).
#[derive(Debug, Clone, PartialEq)]
pub struct GroundMarking {
    /// RGB colour.
    pub rgb: [u8; 3],
    /// Line width (m).
    pub width_m: f64,
    /// Polyline vertices (m).
    pub points: Vec<[f64; 2]>,
}

/// The ground's appearance, for the stereo work: a default colour painted over by regions,
/// then markings, in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTexture {
    /// Colour where nothing else is painted.
    pub default_rgb: [u8; 3],
    /// Coloured regions.
    pub regions: Vec<GroundRegion>,
    /// Road markings.
    pub markings: Vec<GroundMarking>,
}

impl Default for GroundTexture {
    fn default() -> Self {
        GroundTexture {
            default_rgb: [90, 90, 90],
            regions: Vec::new(),
            markings: Vec::new(),
        }
    }
}

impl GroundTexture {
    /// The ground colour at a point.
    pub fn rgb_at(&self, x_m: f64, y_m: f64) -> [u8; 3] {
        for m in self.markings.iter().rev() {
            let hw = 0.5 * m.width_m;
            for w in m.points.windows(2) {
                if dist_point_segment(x_m, y_m, w[0], w[1]) <= hw {
                    return m.rgb;
                }
            }
        }
        for r in self.regions.iter().rev() {
            if point_in_polygon(&r.polygon, x_m, y_m) {
                return r.rgb;
            }
        }
        self.default_rgb
    }
}

fn dist_point_segment(x: f64, y: f64, a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let l2 = ex * ex + ey * ey;
    let t = if l2 > 0.0 {
        (((x - a[0]) * ex + (y - a[1]) * ey) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (x - a[0] - t * ex).hypot(y - a[1] - t * ey)
}

/// A world: obstacles, ground texture and route.
#[derive(Debug, Clone, PartialEq)]
pub struct World {
    /// Name (built-in name or file stem).
    pub name: String,
    /// Obstacles.
    pub prisms: Vec<Prism>,
    /// Ground appearance.
    pub ground: GroundTexture,
    /// Closed route (waypoints, m) driven in order, repeatedly.
    pub route: Vec<[f64; 2]>,
}

/// Names of the built-in worlds.
pub const BUILTIN_WORLDS: [&str; 2] = ["campus", "office"];

impl World {
    /// A built-in world: `campus` (car) or `office` (humanoid).
    pub fn builtin(name: &str) -> Result<World, SimError> {
        match name {
            "campus" => Ok(campus()),
            "office" => Ok(office()),
            _ => Err(SimError::UnknownWorld(name.to_string())),
        }
    }

    /// A built-in name or else a world file.
    pub fn from_name_or_file(name_or_path: &str) -> Result<World, SimError> {
        if BUILTIN_WORLDS.contains(&name_or_path) {
            World::builtin(name_or_path)
        } else if !Path::new(name_or_path).exists() {
            Err(SimError::UnknownWorld(name_or_path.to_string()))
        } else {
            World::from_file(Path::new(name_or_path))
        }
    }

    /// Reads a world file (format in the module documentation).
    pub fn from_file(path: &Path) -> Result<World, SimError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SimError::Io(crate::io::IoError::io(path, e)))?;
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "world".to_string());
        World::parse(&text, path, &stem)
    }

    /// Parses world-file text; `path` names the source in errors.
    pub fn parse(text: &str, path: &Path, default_name: &str) -> Result<World, SimError> {
        let mut world = World {
            name: default_name.to_string(),
            prisms: Vec::new(),
            ground: GroundTexture::default(),
            route: Vec::new(),
        };
        for (idx, raw) in text.lines().enumerate() {
            let line_no = idx + 1;
            let content = raw.split('#').next().unwrap_or("").trim();
            if content.is_empty() {
                continue;
            }
            let toks: Vec<&str> = content.split_whitespace().collect();
            let err = |msg: String| SimError::Io(crate::io::IoError::parse(path, line_no, msg));
            let num = |i: usize, what: &str| -> Result<f64, SimError> {
                let t = toks
                    .get(i)
                    .ok_or_else(|| err(format!("{}: missing {what}", toks[0])))?;
                crate::io::parse_finite_f64(path, line_no, what, t).map_err(SimError::Io)
            };
            let colour = |i: usize| -> Result<[u8; 3], SimError> {
                let mut c = [0u8; 3];
                for (k, ck) in c.iter_mut().enumerate() {
                    let t = toks
                        .get(i + k)
                        .ok_or_else(|| err(format!("{}: missing colour component", toks[0])))?;
                    *ck = t.parse().map_err(|_| {
                        err(format!(
                            "{}: colour component not in 0..=255: {t:?}",
                            toks[0]
                        ))
                    })?;
                }
                Ok(c)
            };
            let points = |from: usize, min: usize| -> Result<Vec<[f64; 2]>, SimError> {
                let rest = toks.len().saturating_sub(from);
                if !rest.is_multiple_of(2) {
                    return Err(err(format!("{}: odd number of coordinates", toks[0])));
                }
                if rest / 2 < min {
                    return Err(err(format!(
                        "{}: needs at least {min} points, found {}",
                        toks[0],
                        rest / 2
                    )));
                }
                (0..rest / 2)
                    .map(|k| Ok([num(from + 2 * k, "x")?, num(from + 2 * k + 1, "y")?]))
                    .collect()
            };
            match toks[0] {
                "name" => {
                    if toks.len() != 2 {
                        return Err(err("name: expected exactly one word".to_string()));
                    }
                    world.name = toks[1].to_string();
                }
                "prism" => {
                    let kind = toks
                        .get(1)
                        .ok_or_else(|| err("prism: missing kind".to_string()))?;
                    let (z0, z1) = (num(2, "z_min")?, num(3, "z_max")?);
                    let pts = points(4, 3)?;
                    let p = Prism::new(kind, pts, z0, z1).ok_or_else(|| {
                        err("prism: degenerate (zero area, z_min < 0 or z_max <= z_min)".into())
                    })?;
                    world.prisms.push(p);
                }
                "box" => {
                    if toks.len() != 9 {
                        return Err(err(format!(
                            "box: expected KIND CX CY LENGTH WIDTH YAW_DEG Z_MIN Z_MAX, found {} fields",
                            toks.len() - 1
                        )));
                    }
                    let p = Prism::rect(
                        toks[1],
                        [num(2, "cx")?, num(3, "cy")?],
                        num(4, "length")?,
                        num(5, "width")?,
                        num(6, "yaw_deg")?.to_radians(),
                        num(7, "z_min")?,
                        num(8, "z_max")?,
                    )
                    .ok_or_else(|| err("box: degenerate (zero size or z_max <= z_min)".into()))?;
                    world.prisms.push(p);
                }
                "ground" => {
                    if toks.len() != 4 {
                        return Err(err("ground: expected R G B".to_string()));
                    }
                    world.ground.default_rgb = colour(1)?;
                }
                "region" => {
                    let rgb = colour(1)?;
                    let polygon = points(4, 3)?;
                    world.ground.regions.push(GroundRegion { rgb, polygon });
                }
                "marking" => {
                    let rgb = colour(1)?;
                    let width_m = num(4, "width")?;
                    if width_m <= 0.0 {
                        return Err(err("marking: width must be positive".to_string()));
                    }
                    let pts = points(5, 2)?;
                    world.ground.markings.push(GroundMarking {
                        rgb,
                        width_m,
                        points: pts,
                    });
                }
                "route" => {
                    let pts = points(1, 1)?;
                    world.route.extend(pts);
                }
                other => {
                    return Err(err(format!(
                        "unknown item {other:?} (expected name, prism, box, ground, region, marking or route)"
                    )));
                }
            }
        }
        Ok(world)
    }

    /// The world in the file format (round-trips through [`World::parse`] up to float
    /// formatting, which is Rust's shortest exact representation).
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "name {}", self.name);
        let g = self.ground.default_rgb;
        let _ = writeln!(s, "ground {} {} {}", g[0], g[1], g[2]);
        for r in &self.ground.regions {
            let _ = write!(s, "region {} {} {}", r.rgb[0], r.rgb[1], r.rgb[2]);
            for p in &r.polygon {
                let _ = write!(s, " {} {}", p[0], p[1]);
            }
            s.push('\n');
        }
        for m in &self.ground.markings {
            let _ = write!(
                s,
                "marking {} {} {} {}",
                m.rgb[0], m.rgb[1], m.rgb[2], m.width_m
            );
            for p in &m.points {
                let _ = write!(s, " {} {}", p[0], p[1]);
            }
            s.push('\n');
        }
        for p in &self.prisms {
            let _ = write!(s, "prism {} {} {}", p.kind, p.z_min_m, p.z_max_m);
            for v in &p.footprint {
                let _ = write!(s, " {} {}", v[0], v[1]);
            }
            s.push('\n');
        }
        if !self.route.is_empty() {
            s.push_str("route");
            for p in &self.route {
                let _ = write!(s, " {} {}", p[0], p[1]);
            }
            s.push('\n');
        }
        s
    }

    /// Shifts everything (obstacles, ground, route) by `(dx_m, dy_m)`.
    pub fn translate(&mut self, dx_m: f64, dy_m: f64) {
        let shift = |p: &mut [f64; 2]| {
            p[0] += dx_m;
            p[1] += dy_m;
        };
        self.prisms
            .iter_mut()
            .flat_map(|p| p.footprint.iter_mut())
            .for_each(shift);
        self.ground
            .regions
            .iter_mut()
            .flat_map(|r| r.polygon.iter_mut())
            .for_each(shift);
        self.ground
            .markings
            .iter_mut()
            .flat_map(|m| m.points.iter_mut())
            .for_each(shift);
        self.route.iter_mut().for_each(shift);
    }

    /// Axis-aligned bounds of obstacles and route: `[x_min, y_min, x_max, y_max]`.
    pub fn bounds(&self) -> [f64; 4] {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let pts = self
            .prisms
            .iter()
            .flat_map(|p| p.footprint.iter())
            .chain(self.route.iter());
        for p in pts {
            b[0] = b[0].min(p[0]);
            b[1] = b[1].min(p[1]);
            b[2] = b[2].max(p[0]);
            b[3] = b[3].max(p[1]);
        }
        if !b[0].is_finite() {
            return [-1.0, -1.0, 1.0, 1.0];
        }
        b
    }
}

// ---------------------------------------------------------------------------------------------
// Built-in worlds. Generated from a fixed private seed, so they never change between runs.

/// Street grid of the campus world: x of north-south streets, y of east-west streets (m).
const CAMPUS_X: [f64; 4] = [0.0, 140.0, 280.0, 420.0];
const CAMPUS_Y: [f64; 3] = [0.0, 120.0, 240.0];
/// Half width of a street (kerb to centre line, m).
const STREET_HALF_M: f64 = 7.0;

fn campus() -> World {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(0x00ca_3b05);
    let mut prisms = Vec::new();
    let mut regions = Vec::new();
    let mut markings = Vec::new();
    let (x0, x1) = (CAMPUS_X[0], CAMPUS_X[3]);
    let (y0, y1) = (CAMPUS_Y[0], CAMPUS_Y[2]);
    // Asphalt on the streets, grass in the park, lane lines.
    for &x in &CAMPUS_X {
        regions.push(GroundRegion {
            rgb: [60, 60, 64],
            polygon: rect_poly(
                x - STREET_HALF_M,
                y0 - STREET_HALF_M,
                x + STREET_HALF_M,
                y1 + STREET_HALF_M,
            ),
        });
        markings.push(GroundMarking {
            rgb: [230, 230, 230],
            width_m: 0.15,
            points: vec![[x, y0], [x, y1]],
        });
    }
    for &y in &CAMPUS_Y {
        regions.push(GroundRegion {
            rgb: [60, 60, 64],
            polygon: rect_poly(
                x0 - STREET_HALF_M,
                y - STREET_HALF_M,
                x1 + STREET_HALF_M,
                y + STREET_HALF_M,
            ),
        });
        markings.push(GroundMarking {
            rgb: [230, 230, 230],
            width_m: 0.15,
            points: vec![[x0, y], [x1, y]],
        });
    }
    // Blocks between the streets; block (2, 0) is an open park (the LiDAR sees little there).
    for i in 0..3 {
        for j in 0..2 {
            let bx0 = CAMPUS_X[i] + STREET_HALF_M + 4.0;
            let bx1 = CAMPUS_X[i + 1] - STREET_HALF_M - 4.0;
            let by0 = CAMPUS_Y[j] + STREET_HALF_M + 4.0;
            let by1 = CAMPUS_Y[j + 1] - STREET_HALF_M - 4.0;
            if (i, j) == (2, 0) {
                regions.push(GroundRegion {
                    rgb: [70, 120, 50],
                    polygon: rect_poly(bx0, by0, bx1, by1),
                });
                continue;
            }
            block_buildings(&mut rng, &mut prisms, [bx0, by0, bx1, by1]);
        }
    }
    // Outer row of buildings, except south of the park (open field on both sides there).
    let outer = STREET_HALF_M + 6.0;
    // (start, end, normal towards the street) along the outside of the outer streets
    let sides: [([f64; 2], [f64; 2], [f64; 2]); 4] = [
        (
            [x0 - 20.0, y0 - outer],
            [CAMPUS_X[2] - 10.0, y0 - outer],
            [0.0, 1.0],
        ),
        (
            [x0 - 20.0, y1 + outer],
            [x1 + 20.0, y1 + outer],
            [0.0, -1.0],
        ),
        ([x0 - outer, y0 + 15.0], [x0 - outer, y1 - 15.0], [1.0, 0.0]),
        (
            [x1 + outer, y0 + 40.0],
            [x1 + outer, y1 - 15.0],
            [-1.0, 0.0],
        ),
    ];
    for (a, b, n) in sides {
        facade_row(&mut rng, &mut prisms, a, b, n);
    }
    // Street furniture: poles, trees, parked cars along every street segment.
    for (k, &x) in CAMPUS_X.iter().enumerate() {
        for j in 0..2 {
            let open = false;
            street_furniture(
                &mut rng,
                &mut prisms,
                [x, CAMPUS_Y[j]],
                [x, CAMPUS_Y[j + 1]],
                open,
                k,
            );
        }
    }
    for (k, &y) in CAMPUS_Y.iter().enumerate() {
        for i in 0..3 {
            // the park stretch: only sparse poles
            let open = k == 0 && i == 2;
            street_furniture(
                &mut rng,
                &mut prisms,
                [CAMPUS_X[i], y],
                [CAMPUS_X[i + 1], y],
                open,
                k + 7,
            );
        }
    }
    let p = |i: usize, j: usize| [CAMPUS_X[i], CAMPUS_Y[j]];
    // Start on the first street (so the car starts on a straight, at the origin, heading +x);
    // loop 1 around block (0,0), then the long perimeter past the park, then around block
    // (1,1) and (0,1): the same streets are driven several times in both directions of travel.
    let start = [CAMPUS_X[0] + 20.0, CAMPUS_Y[0]];
    let route = vec![
        start,
        p(1, 0),
        p(1, 1),
        p(0, 1),
        p(0, 0),
        p(3, 0),
        p(3, 2),
        p(2, 2),
        p(2, 1),
        p(1, 1),
        p(1, 2),
        p(0, 2),
        p(0, 0),
    ];
    let mut w = World {
        name: "campus".to_string(),
        prisms,
        ground: GroundTexture {
            default_rgb: [120, 115, 105],
            regions,
            markings,
        },
        route,
    };
    w.translate(-start[0], -start[1]);
    w
}

fn rect_poly(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
    vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
}

fn uniform(rng: &mut Xoshiro256PlusPlus, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// Buildings along the four sides of a block `[x0, y0, x1, y1]`, facades facing the streets.
fn block_buildings(rng: &mut Xoshiro256PlusPlus, out: &mut Vec<Prism>, b: [f64; 4]) {
    let [x0, y0, x1, y1] = b;
    facade_row(rng, out, [x0, y0], [x1, y0], [0.0, -1.0]);
    facade_row(rng, out, [x0, y1], [x1, y1], [0.0, 1.0]);
    facade_row(rng, out, [x0, y0 + 28.0], [x0, y1 - 28.0], [-1.0, 0.0]);
    facade_row(rng, out, [x1, y0 + 28.0], [x1, y1 - 28.0], [1.0, 0.0]);
}

/// A row of buildings whose facades lie along `a -> b`, facing `normal` (towards the street);
/// the buildings extend away from the street.
fn facade_row(
    rng: &mut Xoshiro256PlusPlus,
    out: &mut Vec<Prism>,
    a: [f64; 2],
    b: [f64; 2],
    normal: [f64; 2],
) {
    let len = (b[0] - a[0]).hypot(b[1] - a[1]);
    let u = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
    let mut s = uniform(rng, 0.0, 6.0);
    while s < len - 6.0 {
        let w = uniform(rng, 12.0, 38.0).min(len - s);
        let depth = uniform(rng, 12.0, 24.0);
        let setback = uniform(rng, 0.0, 4.0);
        let height = uniform(rng, 5.0, 28.0);
        let p0 = [
            a[0] + u[0] * s - normal[0] * setback,
            a[1] + u[1] * s - normal[1] * setback,
        ];
        let p1 = [p0[0] + u[0] * w, p0[1] + u[1] * w];
        let p2 = [p1[0] - normal[0] * depth, p1[1] - normal[1] * depth];
        let p3 = [p0[0] - normal[0] * depth, p0[1] - normal[1] * depth];
        if let Some(p) = Prism::new("building", vec![p0, p1, p2, p3], 0.0, height) {
            out.push(p);
        }
        s += w + uniform(rng, 2.0, 14.0);
    }
}

/// Poles, trees and parked cars along a street segment `a -> b` (centre line); `open`
/// streets get only sparse poles.
fn street_furniture(
    rng: &mut Xoshiro256PlusPlus,
    out: &mut Vec<Prism>,
    a: [f64; 2],
    b: [f64; 2],
    open: bool,
    street: usize,
) {
    let len = (b[0] - a[0]).hypot(b[1] - a[1]);
    let u = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
    let n = [-u[1], u[0]];
    let at = |s: f64, off: f64| [a[0] + u[0] * s + n[0] * off, a[1] + u[1] * s + n[1] * off];
    let yaw = u[1].atan2(u[0]);
    // poles on both sidewalks
    let pole_step = if open { 45.0 } else { 28.0 };
    let mut s = 15.0;
    while s < len - 12.0 {
        for side in [-1.0, 1.0] {
            if let Some(p) = Prism::rect("pole", at(s, side * 8.5), 0.3, 0.3, yaw, 0.0, 7.0) {
                out.push(p);
            }
        }
        s += pole_step;
    }
    if open {
        return;
    }
    // trees on every other street
    if street.is_multiple_of(2) {
        let mut s = 20.0;
        while s < len - 15.0 {
            for side in [-1.0, 1.0] {
                let c = at(s + uniform(rng, -2.0, 2.0), side * 9.8);
                if let Some(p) = Prism::rect("tree", c, 0.4, 0.4, 0.0, 0.0, 3.0) {
                    out.push(p);
                }
                let r = uniform(rng, 1.6, 2.4);
                let canopy: Vec<[f64; 2]> = (0..8)
                    .map(|k| {
                        let t = k as f64 * std::f64::consts::FRAC_PI_4;
                        [c[0] + r * t.cos(), c[1] + r * t.sin()]
                    })
                    .collect();
                if let Some(p) = Prism::new("tree", canopy, 2.6, uniform(rng, 5.5, 8.0)) {
                    out.push(p);
                }
            }
            s += uniform(rng, 11.0, 17.0);
        }
    }
    // parked cars along the kerbs, in clusters
    for side in [-1.0, 1.0] {
        let mut s = 16.0;
        while s < len - 16.0 {
            if rng.random::<f64>() < 0.55 {
                // cars stay below the LiDAR (1.76 m), vans and trucks reach above it
                let (kind, l, h) = if rng.random::<f64>() < 0.85 {
                    ("car", uniform(rng, 4.2, 5.0), uniform(rng, 1.35, 1.6))
                } else {
                    ("van", uniform(rng, 5.0, 6.5), uniform(rng, 2.2, 3.0))
                };
                if let Some(p) = Prism::rect(kind, at(s + 0.5 * l, side * 5.9), l, 1.9, yaw, 0.0, h)
                {
                    out.push(p);
                }
                s += l + uniform(rng, 0.8, 2.5);
            } else {
                s += uniform(rng, 5.0, 20.0);
            }
        }
    }
}

/// Walls of the office are this thick (m) and high (m).
const WALL_T_M: f64 = 0.15;
const WALL_H_M: f64 = 2.7;

fn office() -> World {
    let mut prisms = Vec::new();
    let wall = |out: &mut Vec<Prism>, x0: f64, y0: f64, x1: f64, y1: f64| {
        // axis-aligned wall from (x0,y0) to (x1,y1), thickness WALL_T_M
        let h = 0.5 * WALL_T_M;
        let (ax, bx) = (x0.min(x1) - h, x0.max(x1) + h);
        let (ay, by) = (y0.min(y1) - h, y0.max(y1) + h);
        if let Some(p) = Prism::new("wall", rect_poly(ax, ay, bx, by), 0.0, WALL_H_M) {
            out.push(p);
        }
    };
    let (w, h) = (40.0, 24.0);
    // outer walls
    wall(&mut prisms, 0.0, 0.0, w, 0.0);
    wall(&mut prisms, 0.0, h, w, h);
    wall(&mut prisms, 0.0, 0.0, 0.0, h);
    wall(&mut prisms, w, 0.0, w, h);
    // corridor between y = 10.5 and y = 13.5; rooms 8 m wide on both sides, 1.2 m doors
    let (cy0, cy1) = (10.5, 13.5);
    let door = 1.2;
    for k in 0..5 {
        let rx0 = 8.0 * k as f64;
        let rx1 = rx0 + 8.0;
        let dx = rx0 + 4.0;
        // south rooms' corridor wall with a door at dx
        wall(&mut prisms, rx0, cy0, dx - 0.5 * door, cy0);
        wall(&mut prisms, dx + 0.5 * door, cy0, rx1, cy0);
        wall(&mut prisms, rx0, cy1, dx - 0.5 * door, cy1);
        wall(&mut prisms, dx + 0.5 * door, cy1, rx1, cy1);
        if k > 0 {
            wall(&mut prisms, rx0, 0.0, rx0, cy0);
            wall(&mut prisms, rx0, cy1, rx0, h);
        }
        // furniture: desks (0.75 m) and a cabinet (1.9 m) along the outer walls
        for (yd, yc) in [(2.0, 0.5), (h - 2.0, h - 0.5)] {
            if let Some(p) = Prism::rect("desk", [rx0 + 2.0, yd], 1.6, 0.8, 0.0, 0.0, 0.75) {
                prisms.push(p);
            }
            if let Some(p) = Prism::rect("desk", [rx0 + 6.0, yd], 1.6, 0.8, 0.0, 0.0, 0.75) {
                prisms.push(p);
            }
            if let Some(p) = Prism::rect("cabinet", [rx0 + 4.0, yc], 1.2, 0.5, 0.0, 0.0, 1.9) {
                prisms.push(p);
            }
        }
        // a table in the middle of each room, floating top on four legs
        for yt in [5.0, h - 5.0] {
            if let Some(p) = Prism::rect("table", [rx0 + 4.0, yt], 1.4, 0.9, 0.0, 0.7, 0.75) {
                prisms.push(p);
            }
            for (lx, ly) in [(-0.6, -0.35), (0.6, -0.35), (0.6, 0.35), (-0.6, 0.35)] {
                if let Some(p) =
                    Prism::rect("leg", [rx0 + 4.0 + lx, yt + ly], 0.06, 0.06, 0.0, 0.0, 0.7)
                {
                    prisms.push(p);
                }
            }
        }
    }
    // pillars in the corridor walls' line
    for x in [12.0, 28.0] {
        if let Some(p) = Prism::rect("pillar", [x, cy0 - 0.4], 0.5, 0.5, 0.0, 0.0, WALL_H_M) {
            prisms.push(p);
        }
    }
    // Route: start in the corridor heading +x, tour a south room, a north room at the east
    // end, walk back west and tour the first north room; rooms are entered and left through
    // their doors, around their tables.
    let start = [6.0, 12.0];
    let route = vec![
        start,
        [20.0, 12.0],
        [20.0, 7.0],
        [17.5, 7.0],
        [17.5, 3.5],
        [22.5, 3.5],
        [22.5, 7.0],
        [20.0, 7.0],
        [20.0, 12.0],
        [36.0, 12.0],
        [36.0, 16.5],
        [33.0, 16.5],
        [33.0, 20.5],
        [38.0, 20.5],
        [38.0, 16.5],
        [36.0, 16.5],
        [36.0, 12.0],
        [4.0, 12.0],
        [4.0, 16.5],
        [1.5, 16.5],
        [1.5, 20.5],
        [6.5, 20.5],
        [6.5, 16.5],
        [4.0, 16.5],
        [4.0, 12.0],
    ];
    let mut w = World {
        name: "office".to_string(),
        prisms,
        ground: GroundTexture {
            default_rgb: [150, 140, 120],
            regions: vec![GroundRegion {
                rgb: [110, 110, 140],
                polygon: rect_poly(0.0, cy0, w, cy1),
            }],
            markings: Vec::new(),
        },
        route,
    };
    w.translate(-start[0], -start[1]);
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_are_valid() {
        for name in BUILTIN_WORLDS {
            let w = World::builtin(name).unwrap();
            assert!(w.prisms.len() > 20, "{name}");
            assert!(w.route.len() >= 4, "{name}");
            for p in &w.prisms {
                assert!(signed_area(&p.footprint) > 0.0);
            }
        }
        assert!(World::builtin("nope").is_err());
    }

    #[test]
    fn routes_keep_clear_of_obstacles() {
        // the driven path (centre of the vehicle) keeps this far from every footprint
        for (name, radius, clearance) in [("campus", 9.0, 2.5), ("office", 0.6, 0.5)] {
            let w = World::builtin(name).unwrap();
            let path = crate::sim::path::Path::from_route(&w.route, radius).unwrap();
            let mut s = 0.0;
            while s < path.lap_m() {
                let p = path.at(s);
                for pr in &w.prisms {
                    let n = pr.footprint.len();
                    let d = (0..n)
                        .map(|k| {
                            dist_point_segment(
                                p.x_m,
                                p.y_m,
                                pr.footprint[k],
                                pr.footprint[(k + 1) % n],
                            )
                        })
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        !pr.contains_xy(p.x_m, p.y_m) && d >= clearance,
                        "{name}: path at s = {s:.1} ({:.1}, {:.1}) is {d:.2} m from a {}",
                        p.x_m,
                        p.y_m,
                        pr.kind
                    );
                }
                s += 0.5;
            }
        }
    }

    #[test]
    fn text_roundtrip() {
        let w = World::builtin("office").unwrap();
        let back = World::parse(&w.to_text(), Path::new("x.world"), "x").unwrap();
        assert_eq!(w, back);
    }

    #[test]
    fn parse_errors_name_line() {
        let text = "name t\nbox wall 0 0 1 1 0 0 2\nprism building 0 5 0 0 1 0\n";
        let e = World::parse(text, Path::new("my.world"), "t")
            .unwrap_err()
            .to_string();
        assert!(e.contains("my.world:3"), "{e}");
        let e = World::parse("route 1 2 3\n", Path::new("r.world"), "r")
            .unwrap_err()
            .to_string();
        assert!(e.contains("r.world:1") && e.contains("odd"), "{e}");
        let e = World::parse("\n\nfoo 1\n", Path::new("f.world"), "f")
            .unwrap_err()
            .to_string();
        assert!(e.contains("f.world:3") && e.contains("foo"), "{e}");
        let e = World::parse("box a 0 0 1 1 0 0 nan\n", Path::new("n.world"), "n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("n.world:1"), "{e}");
    }

    #[test]
    fn ground_texture_layers() {
        let w = World::builtin("campus").unwrap();
        // the campus is shifted by -20 m in x so the car starts at the origin
        assert_eq!(w.route[0], [0.0, 0.0]);
        assert_eq!(w.ground.rgb_at(-20.0, 50.0), [230, 230, 230]); // lane line
        assert_eq!(w.ground.rgb_at(-17.0, 50.0), [60, 60, 64]); // asphalt
        assert_eq!(w.ground.rgb_at(330.0, 60.0), [70, 120, 50]); // park
    }
}
