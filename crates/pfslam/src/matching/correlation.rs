//! Map correlation: how many of a scan's end points fall on occupied cells, searched over a
//! small grid of pose offsets (the seeds' `mapCorrelation`).
//!
//! The scan's body-frame end points are computed once per scan; per particle and yaw offset
//! they are transformed to integer cells once, and every x/y offset (one cell per step) is a
//! pure integer shift of those cells, so a 9x9 search costs 81 lookups per point and no
//! floating point.

use crate::geometry::Pose2;
use crate::map::{Cell, MapLimits, OccupancyGrid, PlanarScan};

/// What the correlation needs of a map: its cell frame and which cells are occupied. Cells
/// outside the map are free. Implemented by the occupancy grid; a per-particle map policy
/// hands each particle its own.
pub trait OccupancyLookup: Sync {
    /// World <-> cell.
    fn cell_limits(&self) -> MapLimits;
    /// True when `cell` is believed occupied.
    fn occupied(&self, cell: Cell) -> bool;
}

impl OccupancyLookup for OccupancyGrid {
    #[inline]
    fn cell_limits(&self) -> MapLimits {
        *self.limits()
    }
    #[inline]
    fn occupied(&self, cell: Cell) -> bool {
        self.is_occupied(cell)
    }
}

/// The search space around a particle.
#[derive(Debug, Clone, PartialEq)]
pub struct CorrelationSearch {
    /// Offsets `-r..=r` cells in x and in y (4 gives the seeds' 9x9 grid).
    pub xy_radius_cells: i32,
    /// Yaw offsets tried (rad); should contain 0.
    pub yaw_offsets_rad: Vec<f64>,
    /// Hits an x/y offset must gain per squared cell of offset to be taken (0 = the seeds:
    /// the plain maximum). A prior towards the predicted pose: near-ties along a street's
    /// walls no longer move the particle by whole cells.
    pub offset_penalty_hits_per_cell2: f64,
    /// A point counts as a hit when an occupied cell lies within this many cells
    /// (Chebyshev) of it (0 = the seeds: its own cell only).
    pub dilation_cells: i32,
}

/// The best offset found for one particle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanMatch {
    /// The particle's pose moved by the best offset.
    pub pose: Pose2,
    /// Occupied cells hit at that offset.
    pub score: u32,
}

/// Caller-owned buffers of [`best_match`], reused across particles.
#[derive(Debug, Clone, Default)]
pub struct CorrelationScratch {
    cells: Vec<Cell>,
    scores: Vec<u32>,
}

/// The returns of a preprocessed scan as correlation points (`hit` points only: "no return"
/// clearing rays say nothing about occupied cells), into a caller-owned buffer.
pub fn hit_points(scan: &PlanarScan, out: &mut Vec<[f64; 2]>) {
    out.clear();
    out.extend(scan.points.iter().filter(|p| p.hit).map(|p| [p.x_m, p.y_m]));
}

/// Occupied cells hit by `points_body` (body-frame end points, m) seen from
/// `world_from_body`.
pub fn correlation<M: OccupancyLookup + ?Sized>(
    map: &M,
    points_body: &[[f64; 2]],
    world_from_body: &Pose2,
) -> u32 {
    let frame = map.cell_limits();
    points_body
        .iter()
        .map(|p| {
            let (x, y) = world_from_body.transform_point(p[0], p[1]);
            u32::from(map.occupied(frame.cell_of(x, y)))
        })
        .sum()
}

/// True when an occupied cell lies within `d` cells (Chebyshev) of `c`.
#[inline]
fn occupied_near<M: OccupancyLookup + ?Sized>(map: &M, c: Cell, d: i32) -> bool {
    if d == 0 {
        return map.occupied(c);
    }
    (-d..=d).any(|j| (-d..=d).any(|i| map.occupied(Cell::new(c.i + i, c.j + j))))
}

/// Searches x/y offsets (one cell per step) and yaw offsets around `world_from_body` for the
/// pose whose transformed scan hits the most occupied cells. Ties go to the smallest yaw
/// offset, then the smallest x/y offset (so an uninformative map leaves the pose unchanged),
/// then the first in search order: the result is deterministic.
pub fn best_match<M: OccupancyLookup + ?Sized>(
    map: &M,
    points_body: &[[f64; 2]],
    world_from_body: &Pose2,
    search: &CorrelationSearch,
    scratch: &mut CorrelationScratch,
) -> ScanMatch {
    let frame = map.cell_limits();
    let d = search.dilation_cells.max(0);
    let r = search.xy_radius_cells.max(0);
    let side = (2 * r + 1) as usize;
    // (penalised score in milli-hits, -|yaw|, -(dx^2 + dy^2)) compared lexicographically,
    // in integers so ties compare exactly.
    let mut best: Option<((i64, i64, i64), u32, Pose2)> = None;
    let penalty_milli = (search.offset_penalty_hits_per_cell2.max(0.0) * 1000.0).round() as i64;
    let zero_yaw = [0.0];
    let yaws: &[f64] = if search.yaw_offsets_rad.is_empty() {
        &zero_yaw
    } else {
        &search.yaw_offsets_rad
    };
    for &dyaw in yaws {
        let pose = Pose2::new(
            world_from_body.x_m,
            world_from_body.y_m,
            world_from_body.yaw_rad + dyaw,
        );
        scratch.cells.clear();
        scratch.cells.extend(points_body.iter().map(|p| {
            let (x, y) = pose.transform_point(p[0], p[1]);
            frame.cell_of(x, y)
        }));
        scratch.scores.clear();
        scratch.scores.resize(side * side, 0);
        for &Cell { i: cx, j: cy } in &scratch.cells {
            for (iy, dy) in (-r..=r).enumerate() {
                let row = &mut scratch.scores[iy * side..(iy + 1) * side];
                for (slot, dx) in row.iter_mut().zip(-r..=r) {
                    *slot += u32::from(occupied_near(map, Cell::new(cx + dx, cy + dy), d));
                }
            }
        }
        // Rank yaw offsets by magnitude with a small integer so ties compare exactly.
        let yaw_rank = -((dyaw.abs() * 1e9).round() as i64);
        for (iy, dy) in (-r..=r).enumerate() {
            for (ix, dx) in (-r..=r).enumerate() {
                let score = scratch.scores[iy * side + ix];
                let d2 = i64::from(dx * dx + dy * dy);
                let key = (i64::from(score) * 1000 - penalty_milli * d2, yaw_rank, -d2);
                if best.as_ref().is_none_or(|(k, _, _)| key > *k) {
                    let moved = Pose2::new(
                        pose.x_m + f64::from(dx) * frame.resolution_m(),
                        pose.y_m + f64::from(dy) * frame.resolution_m(),
                        pose.yaw_rad,
                    );
                    best = Some((key, score, moved));
                }
            }
        }
    }
    match best {
        Some((_, score, pose)) => ScanMatch { pose, score },
        None => ScanMatch {
            pose: *world_from_body,
            score: 0,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense test grid.
    struct Dense {
        frame: MapLimits,
        w: i32,
        h: i32,
        occ: Vec<bool>,
    }

    impl OccupancyLookup for Dense {
        fn cell_limits(&self) -> MapLimits {
            self.frame
        }
        fn occupied(&self, c: Cell) -> bool {
            let (x, y) = (c.i, c.j);
            x >= 0 && y >= 0 && x < self.w && y < self.h && self.occ[(y * self.w + x) as usize]
        }
    }

    fn room() -> (Dense, Vec<[f64; 2]>) {
        let frame = MapLimits::new(0.1, -10.0, -10.0);
        let (w, h) = (200, 200);
        let mut occ = vec![false; (w * h) as usize];
        let mut pts = Vec::new();
        // An L-shaped pair of walls plus a pillar, seen from the origin.
        for i in 0..120 {
            let t = -6.0 + i as f64 * 0.1 + 0.05;
            pts.push([5.05, t]);
            pts.push([t, 4.05]);
        }
        pts.push([2.05, -2.05]);
        for p in &pts {
            let c = frame.cell_of(p[0], p[1]);
            occ[(c.j * w + c.i) as usize] = true;
        }
        (Dense { frame, w, h, occ }, pts)
    }

    #[test]
    fn search_recovers_offset() {
        let (map, pts) = room();
        let search = CorrelationSearch {
            xy_radius_cells: 4,
            yaw_offsets_rad: vec![-0.02, 0.0, 0.02],
            offset_penalty_hits_per_cell2: 0.0,
            dilation_cells: 0,
        };
        let truth = Pose2::IDENTITY;
        let full = correlation(&map, &pts, &truth);
        assert_eq!(full as usize, pts.len());
        let perturbed = Pose2::new(0.3, -0.2, 0.0);
        assert!(correlation(&map, &pts, &perturbed) < full / 4);
        let mut scratch = CorrelationScratch::default();
        let m = best_match(&map, &pts, &perturbed, &search, &mut scratch);
        assert_eq!(m.score, full);
        assert!(m.pose.x_m.abs() < 1e-9 && m.pose.y_m.abs() < 1e-9, "{m:?}");
    }

    #[test]
    fn empty_map_keeps_pose() {
        let (mut map, pts) = room();
        map.occ.fill(false);
        let search = CorrelationSearch {
            xy_radius_cells: 4,
            yaw_offsets_rad: vec![-0.02, 0.0, 0.02],
            offset_penalty_hits_per_cell2: 0.0,
            dilation_cells: 0,
        };
        let p = Pose2::new(0.31, -0.2, 0.1);
        let m = best_match(&map, &pts, &p, &search, &mut CorrelationScratch::default());
        assert_eq!(m.score, 0);
        assert_eq!(m.pose, p);
    }
}
