//! The built-in worlds, generated from a fixed private seed so they never change between
//! runs.

use super::*;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Street grid of the campus world: x of north-south streets, y of east-west streets (m).
const CAMPUS_X: [f64; 4] = [0.0, 140.0, 280.0, 420.0];
const CAMPUS_Y: [f64; 3] = [0.0, 120.0, 240.0];
/// Half width of a street (kerb to centre line, m).
const STREET_HALF_M: f64 = 7.0;

pub(super) fn campus() -> World {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(0x00ca_3b05);
    let (mut regions, markings) = campus_streets();
    // One random stream for every prism: blocks, then the outer rows, then the furniture.
    let mut prisms = Vec::new();
    campus_blocks(&mut rng, &mut prisms, &mut regions);
    campus_outer_rows(&mut rng, &mut prisms);
    campus_furniture(&mut rng, &mut prisms);
    // Start on the first street (so the car starts on a straight, at the origin, heading +x),
    // then the corners of `CAMPUS_ROUTE`.
    let start = [CAMPUS_X[0] + 20.0, CAMPUS_Y[0]];
    let corners = CAMPUS_ROUTE
        .iter()
        .map(|&(i, j)| [CAMPUS_X[i], CAMPUS_Y[j]]);
    let route = std::iter::once(start).chain(corners).collect();
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

/// The campus route after its start, as street crossings `(i, j)` = (`CAMPUS_X[i]`,
/// `CAMPUS_Y[j]`): loop 1 around block (0,0), then the long perimeter past the park, then
/// around block (1,1) and (0,1): the same streets are driven several times in both
/// directions of travel.
const CAMPUS_ROUTE: [(usize, usize); 12] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (0, 0),
    (3, 0),
    (3, 2),
    (2, 2),
    (2, 1),
    (1, 1),
    (1, 2),
    (0, 2),
    (0, 0),
];

/// The campus streets' asphalt and lane lines: one region and one line per street.
fn campus_streets() -> (Vec<GroundRegion>, Vec<GroundMarking>) {
    let (x0, x1) = (CAMPUS_X[0], CAMPUS_X[3]);
    let (y0, y1) = (CAMPUS_Y[0], CAMPUS_Y[2]);
    let mut regions = Vec::new();
    let mut markings = Vec::new();
    // A street along its centre line from `a` to `b` (`b` north or east of `a`).
    let mut street = |a: [f64; 2], b: [f64; 2]| {
        let h = STREET_HALF_M;
        regions.push(GroundRegion {
            rgb: [60, 60, 64],
            polygon: rect_poly(a[0] - h, a[1] - h, b[0] + h, b[1] + h),
        });
        markings.push(GroundMarking {
            rgb: [230, 230, 230],
            width_m: 0.15,
            points: vec![a, b],
        });
    };
    for &x in &CAMPUS_X {
        street([x, y0], [x, y1]);
    }
    for &y in &CAMPUS_Y {
        street([x0, y], [x1, y]);
    }
    (regions, markings)
}

/// The blocks between the streets: buildings on their four sides, except block (2, 0), an
/// open park of grass (the LiDAR sees little there).
fn campus_blocks(
    rng: &mut Xoshiro256PlusPlus,
    prisms: &mut Vec<Prism>,
    regions: &mut Vec<GroundRegion>,
) {
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
            block_buildings(rng, prisms, [bx0, by0, bx1, by1]);
        }
    }
}

/// The outer row of buildings along the outside of the outer streets, except south of the
/// park (open field on both sides there).
fn campus_outer_rows(rng: &mut Xoshiro256PlusPlus, prisms: &mut Vec<Prism>) {
    let (x0, x1) = (CAMPUS_X[0], CAMPUS_X[3]);
    let (y0, y1) = (CAMPUS_Y[0], CAMPUS_Y[2]);
    let outer = STREET_HALF_M + 6.0;
    // (start, end, normal towards the street)
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
        facade_row(rng, prisms, a, b, n);
    }
}

/// Street furniture (poles, trees, parked cars) along every street segment between two
/// crossings; the street past the park gets only sparse poles.
fn campus_furniture(rng: &mut Xoshiro256PlusPlus, prisms: &mut Vec<Prism>) {
    for (k, &x) in CAMPUS_X.iter().enumerate() {
        for j in 0..2 {
            let open = false;
            street_furniture(rng, prisms, [x, CAMPUS_Y[j]], [x, CAMPUS_Y[j + 1]], open, k);
        }
    }
    for (k, &y) in CAMPUS_Y.iter().enumerate() {
        for i in 0..3 {
            // the park stretch: only sparse poles
            let open = k == 0 && i == 2;
            street_furniture(
                rng,
                prisms,
                [CAMPUS_X[i], y],
                [CAMPUS_X[i + 1], y],
                open,
                k + 7,
            );
        }
    }
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
/// The office's outer size (m): x from 0 to `OFFICE_W_M`, y from 0 to `OFFICE_H_M`.
const OFFICE_W_M: f64 = 40.0;
const OFFICE_H_M: f64 = 24.0;
/// The corridor runs along x between these y (m); rooms 8 m wide on both sides.
const CORRIDOR_Y_M: [f64; 2] = [10.5, 13.5];
/// Width of a room's door onto the corridor (m).
const DOOR_M: f64 = 1.2;

/// The humanoid's route, from its start: in the corridor heading +x, tour a south room, a
/// north room at the east end, walk back west and tour the first north room; rooms are
/// entered and left through their doors, around their tables.
const OFFICE_ROUTE: [[f64; 2]; 25] = [
    [6.0, 12.0],
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

pub(super) fn office() -> World {
    let (w, h) = (OFFICE_W_M, OFFICE_H_M);
    let [cy0, cy1] = CORRIDOR_Y_M;
    let mut prisms = Vec::new();
    // outer walls
    wall(&mut prisms, 0.0, 0.0, w, 0.0);
    wall(&mut prisms, 0.0, h, w, h);
    wall(&mut prisms, 0.0, 0.0, 0.0, h);
    wall(&mut prisms, w, 0.0, w, h);
    for k in 0..5 {
        let rx0 = 8.0 * k as f64;
        office_room_walls(&mut prisms, rx0, k > 0);
        office_room_furniture(&mut prisms, rx0);
    }
    // pillars in the corridor walls' line
    for x in [12.0, 28.0] {
        if let Some(p) = Prism::rect("pillar", [x, cy0 - 0.4], 0.5, 0.5, 0.0, 0.0, WALL_H_M) {
            prisms.push(p);
        }
    }
    let start = OFFICE_ROUTE[0];
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
        route: OFFICE_ROUTE.to_vec(),
    };
    w.translate(-start[0], -start[1]);
    w
}

/// An axis-aligned wall from (x0, y0) to (x1, y1), `WALL_T_M` thick.
fn wall(out: &mut Vec<Prism>, x0: f64, y0: f64, x1: f64, y1: f64) {
    let h = 0.5 * WALL_T_M;
    let (ax, bx) = (x0.min(x1) - h, x0.max(x1) + h);
    let (ay, by) = (y0.min(y1) - h, y0.max(y1) + h);
    if let Some(p) = Prism::new("wall", rect_poly(ax, ay, bx, by), 0.0, WALL_H_M) {
        out.push(p);
    }
}

/// The walls of the two rooms starting at x = `rx0`, south and north of the corridor: their
/// corridor walls with a door in the middle, and (`divider`) the wall west of them.
fn office_room_walls(prisms: &mut Vec<Prism>, rx0: f64, divider: bool) {
    let [cy0, cy1] = CORRIDOR_Y_M;
    let rx1 = rx0 + 8.0;
    let dx = rx0 + 4.0;
    wall(prisms, rx0, cy0, dx - 0.5 * DOOR_M, cy0);
    wall(prisms, dx + 0.5 * DOOR_M, cy0, rx1, cy0);
    wall(prisms, rx0, cy1, dx - 0.5 * DOOR_M, cy1);
    wall(prisms, dx + 0.5 * DOOR_M, cy1, rx1, cy1);
    if divider {
        wall(prisms, rx0, 0.0, rx0, cy0);
        wall(prisms, rx0, cy1, rx0, OFFICE_H_M);
    }
}

/// The furniture of the two rooms starting at x = `rx0`: desks (0.75 m) and a cabinet
/// (1.9 m) along the outer walls, and a table in the middle of each room, its top floating
/// on four legs.
fn office_room_furniture(prisms: &mut Vec<Prism>, rx0: f64) {
    let h = OFFICE_H_M;
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
