//! The scan-surface truth: what a (tilted) 2-D scanner driven along the true path can
//! observe, computed from the world's solids and the true poses only — never from the
//! simulated ranges — so it stays an independent judge of the mapping pipeline (mount
//! transform, projection, ray insertion, log-odds, thresholds).
//!
//! # Rule
//!
//! A 2-D map of a 3-D world is only defined relative to the surface the scanner sweeps. The
//! car's LMS511 is tilted: its beams run level sideways and rise 37 deg forwards (and dip 3 deg
//! at the two ends of the fan), so over a cell the scan surface lies at a height that depends
//! on where the cell is relative to the car. A fixed height band is therefore unfair both
//! ways: beams pass under tree canopies and over vans the band contains, and hit car roofs
//! and canopy bottoms it may exclude. Instead, for every `pose_step`-th true pose:
//!
//! 1. the scan surface is traced as rays (by default the sensor's own beam directions;
//!    `rays = "uniform"`: every `angle_step_deg` over the fan), in the LiDAR's own plane
//!    placed by the true pose and the mount, on the truth raster. In
//!    each cell a ray crosses, its height spans `[z_in, z_out]` (exact: the ray's height is
//!    linear in its horizontal distance);
//! 2. the first cell where that height span meets the vertical extent `[z_min, z_max]` of a
//!    solid whose footprint covers the cell is a **visible surface** cell: the scanner can
//!    face that solid there, with line of sight, at the height where its surface crosses it
//!    (a wall face, a van's side, a canopy's underside, a car roof under the dipping edge
//!    beams);
//! 3. the cells before it are **passed free**: some beam can cross them without meeting a
//!    solid at the height it crosses them. A ray ends without a hit at the ground (`z < 0`),
//!    above the highest solid while climbing, or at `range_max_m` (3-D range).
//!
//! The two rasters written:
//! - **occupancy truth** (`true_map.{png,pgm,yaml}`): occupied = the footprint of every solid
//!   with at least one visible surface cell (a vertical extrusion's cross-section at any height
//!   it is seen at is its whole footprint, so every cell of it is occupied at the height the
//!   scan surface meets it); free = passed-free cells outside those footprints; unknown = cells
//!   no traced beam reached. Precision is counted against it: a mapped occupied cell must lie
//!   within one cell of a solid the scanner can see;
//! - **visibility truth** (`true_map_visible.{pgm,yaml}`): occupied = visible surface cells,
//!   free = passed-free cells (a cell can be both — e.g. under a canopy at 1.76 m seen from
//!   the side, in the canopy when the rising forward beams reach it; it is then occupied),
//!   unknown = the rest. Recall is counted over its occupied cells (every surface the scanner
//!   could face within range, whatever the map says there) and free agreement over its free
//!   cells ([`pfslam::map::compare_maps_visible`]).
//!
//! Why it is fair: it asks the map for exactly what the sensor geometry allows — surfaces a
//! beam can reach first and space a beam can cross — at the heights the beams really have,
//! with 1-cell tolerance; it never looks at a simulated range, so a wrong mount, a projection
//! or insertion bug, bad log-odds or thresholds still show. The rays are the real beams
//! (0.666 deg apart on the LMS511): finer uniform rays (the first rule, 0.1 deg) also count
//! surfaces between the beams, and those are not swept as the car moves. A beam at a fixed
//! angle traces one line along a surface parallel to the drive (a parked car, a canopy's
//! underside), so on the default drive ~2,800 such cells were reached by no real beam from
//! any pose; with uniform rays recall was capped by the sampling, not by the map.

use super::truth::for_each_footprint_cell;
use super::world::World;
use super::{ScanTruthOptions, SimError, SimOptions, TruthRays};
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::map::{
    BinaryMap, CellState, MapComparison, MapLimits, compare_maps_visible,
    compare_maps_visible_aligned,
};
use pfslam::sensors::LidarGeometry;
use rayon::prelude::*;
use std::collections::HashMap;

/// The two rasters of the rule (module docs), on the same cells.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanSurfaceTruth {
    /// Occupied: footprints of the solids the scanner sees; free: passed-free cells outside
    /// them; unknown: never reached.
    pub occupancy: BinaryMap,
    /// Occupied: visible surface cells; free: passed-free cells; unknown: the rest.
    pub visible: BinaryMap,
}

/// Which solids cover each cell of a raster: `stack[cell]` indexes `stacks`, the distinct sets
/// of prism indices (0 = none).
struct Coverage {
    stack: Vec<u16>,
    stacks: Vec<Vec<u32>>,
}

/// A bit per cell.
#[derive(Clone)]
struct Bits(Vec<u64>);

impl Bits {
    fn new(n: usize) -> Self {
        Bits(vec![0; n.div_ceil(64)])
    }
    #[inline]
    fn set(&mut self, i: usize) {
        self.0[i >> 6] |= 1 << (i & 63);
    }
    #[inline]
    fn get(&self, i: usize) -> bool {
        self.0[i >> 6] >> (i & 63) & 1 == 1
    }
    fn or(mut self, other: &Bits) -> Self {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a |= b;
        }
        self
    }
}

/// What the traces of a set of poses marked.
#[derive(Clone)]
struct Marks {
    free: Bits,
    surface: Bits,
    seen: Vec<bool>,
}

impl Marks {
    fn new(cells: usize, prisms: usize) -> Self {
        Marks {
            free: Bits::new(cells),
            surface: Bits::new(cells),
            seen: vec![false; prisms],
        }
    }
    fn merge(self, other: Marks) -> Marks {
        Marks {
            free: self.free.or(&other.free),
            surface: self.surface.or(&other.surface),
            seen: self
                .seen
                .iter()
                .zip(&other.seen)
                .map(|(a, b)| *a || *b)
                .collect(),
        }
    }
}

impl ScanSurfaceTruth {
    /// Computes the truth of `world` for a scanner of `geometry` mounted at `body_from_lidar`
    /// on a vehicle at the true `poses` (body frame on the ground, z = 0), on cells of
    /// `resolution_m` covering every traced ray.
    pub fn compute(
        world: &World,
        poses: &[Pose2],
        body_from_lidar: &Rigid3,
        geometry: &LidarGeometry,
        resolution_m: f64,
        opts: &ScanTruthOptions,
    ) -> Result<ScanSurfaceTruth, SimError> {
        opts.validate()?;
        if !(0.01..=10.0).contains(&resolution_m) {
            return Err(SimError::BadOption(
                "truth resolution must be in [0.01, 10] m".into(),
            ));
        }
        let res = resolution_m;
        let sampled: Vec<Pose2> = poses.iter().step_by(opts.pose_step).copied().collect();
        let o_body = body_from_lidar.translation;
        let margin = opts.range_max_m + 2.0 * res;
        let (origin, [width, height]) = raster_around(world, &sampled, o_body, margin, res);
        let coverage = coverage(world, origin, res, [width, height])?;
        let z_range: Vec<[f64; 2]> = world
            .prisms
            .iter()
            .map(|p| [p.z_min_m, p.z_max_m])
            .collect();
        let top_z = z_range.iter().map(|z| z[1]).fold(0.0, f64::max);
        let dirs = ray_directions(geometry, body_from_lidar, opts);
        let tracer = Tracer {
            origin,
            res,
            width,
            height,
            coverage: &coverage,
            z_range: &z_range,
            top_z,
            range_max_m: opts.range_max_m,
        };
        let marks = tracer.trace_poses(&sampled, o_body, &dirs, world.prisms.len());
        Ok(truth_from_marks(
            world,
            &marks,
            origin,
            res,
            [width, height],
        ))
    }

    /// The truth of a simulated car drive: the car's calibration and its true poses.
    pub fn for_car(
        world: &World,
        ground_truth: &[pfslam::geometry::StampedPose2],
        calibration: &pfslam::sensors::CarCalibration,
        opts: &SimOptions,
    ) -> Result<ScanSurfaceTruth, SimError> {
        let poses: Vec<Pose2> = ground_truth.iter().map(|g| g.pose).collect();
        Self::compute(
            world,
            &poses,
            &calibration.body_from_lidar,
            &calibration.lidar,
            opts.truth_map_resolution_m,
            &opts.scan_truth,
        )
    }

    /// Precision (vs the occupancy truth), recall (over the visible surfaces) and free
    /// agreement (vs the passed-free cells) of `estimate`, with `tolerance_cells`.
    pub fn compare(
        &self,
        estimate: &BinaryMap,
        tolerance_cells: u32,
    ) -> Result<MapComparison, pfslam::map::MapError> {
        compare_maps_visible(estimate, &self.occupancy, &self.visible, tolerance_cells)
    }

    /// [`Self::compare`] with the estimate moved by `truth_from_estimate` (for a SLAM map,
    /// the SE(2) alignment of its trajectory onto the ground truth).
    pub fn compare_aligned(
        &self,
        estimate: &BinaryMap,
        tolerance_cells: u32,
        truth_from_estimate: &Pose2,
    ) -> Result<MapComparison, pfslam::map::MapError> {
        compare_maps_visible_aligned(
            estimate,
            &self.occupancy,
            &self.visible,
            tolerance_cells,
            truth_from_estimate,
        )
    }
}

/// The truth raster: its origin (a multiple of `res`) and size in cells, covering every
/// sensor position of `sampled` plus `margin` (so every traced cell fits), or the world's
/// bounds plus `margin` without poses.
fn raster_around(
    world: &World,
    sampled: &[Pose2],
    o_body: nalgebra::Vector3<f64>,
    margin: f64,
    res: f64,
) -> ([f64; 2], [usize; 2]) {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in sampled {
        let (x, y) = p.transform_point(o_body.x, o_body.y);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    if sampled.is_empty() {
        let b = world.bounds();
        (x0, y0, x1, y1) = (b[0], b[1], b[2], b[3]);
    }
    let origin = [
        ((x0 - margin) / res).floor() * res,
        ((y0 - margin) / res).floor() * res,
    ];
    let width = ((x1 + margin - origin[0]) / res).ceil().max(1.0) as usize;
    let height = ((y1 + margin - origin[1]) / res).ceil().max(1.0) as usize;
    (origin, [width, height])
}

/// The traced rays' directions in the body frame: the sensor's beams, or every
/// `angle_step_deg` over its fan, turned by the mount.
fn ray_directions(
    geometry: &LidarGeometry,
    body_from_lidar: &Rigid3,
    opts: &ScanTruthOptions,
) -> Vec<[f64; 3]> {
    let angles: Vec<f64> = match opts.rays {
        TruthRays::SensorBeams => (0..geometry.beam_count)
            .map(|k| geometry.beam_angle_rad(k))
            .collect(),
        TruthRays::Uniform => {
            let a0 = geometry.angle_min_rad;
            let a1 = geometry.beam_angle_rad(geometry.beam_count.saturating_sub(1));
            let step = opts.angle_step_deg.to_radians();
            let n_rays = ((a1 - a0) / step).floor().max(0.0) as usize + 1;
            (0..n_rays).map(|k| a0 + k as f64 * step).collect()
        }
    };
    angles
        .iter()
        .map(|&a| {
            let d = body_from_lidar.rotation * nalgebra::Vector3::new(a.cos(), a.sin(), 0.0);
            [d.x, d.y, d.z]
        })
        .collect()
}

/// The two rasters of the rule from what the traces marked: visible surface and passed-free
/// cells as they are; for the occupancy truth, every reached cell free first, then the whole
/// footprint of each solid seen occupied.
fn truth_from_marks(
    world: &World,
    marks: &Marks,
    origin: [f64; 2],
    res: f64,
    [width, height]: [usize; 2],
) -> ScanSurfaceTruth {
    let limits = MapLimits::new(res, origin[0], origin[1]);
    let mut occupancy = BinaryMap::filled(limits, width, height, CellState::Unknown);
    let mut visible = occupancy.clone();
    for i in 0..width * height {
        if marks.surface.get(i) {
            visible.cells[i] = CellState::Occupied;
        } else if marks.free.get(i) {
            visible.cells[i] = CellState::Free;
        }
        if marks.free.get(i) || marks.surface.get(i) {
            occupancy.cells[i] = CellState::Free;
        }
    }
    for (p, seen) in world.prisms.iter().zip(&marks.seen) {
        if *seen {
            for_each_footprint_cell(p, origin, res, [width, height], |i| {
                occupancy.cells[i] = CellState::Occupied;
            });
        }
    }
    ScanSurfaceTruth { occupancy, visible }
}

/// Rasterises which prisms cover each cell (footprint interior and outline).
fn coverage(
    world: &World,
    origin: [f64; 2],
    res: f64,
    size: [usize; 2],
) -> Result<Coverage, SimError> {
    let mut cov = Coverage {
        stack: vec![0; size[0] * size[1]],
        stacks: vec![Vec::new()],
    };
    let mut index: HashMap<Vec<u32>, u16> = HashMap::new();
    let mut overflow = false;
    for (pi, p) in world.prisms.iter().enumerate() {
        let pi = pi as u32;
        // The stack of this prism alone: most cells are covered by one prism only.
        let single = match index.get(&vec![pi]) {
            Some(&k) => k,
            None => {
                let Ok(k) = u16::try_from(cov.stacks.len()) else {
                    overflow = true;
                    break;
                };
                index.insert(vec![pi], k);
                cov.stacks.push(vec![pi]);
                k
            }
        };
        // Cells are visited at most a few times per prism; adding twice is a no-op.
        for_each_footprint_cell(p, origin, res, size, |i| {
            let cur = cov.stack[i] as usize;
            if cur == 0 {
                cov.stack[i] = single;
                return;
            }
            if cov.stacks[cur].contains(&pi) {
                return;
            }
            let mut set = cov.stacks[cur].clone();
            set.push(pi);
            let next = match index.get(&set) {
                Some(&k) => k,
                None => {
                    let Ok(k) = u16::try_from(cov.stacks.len()) else {
                        overflow = true;
                        return;
                    };
                    index.insert(set.clone(), k);
                    cov.stacks.push(set);
                    k
                }
            };
            cov.stack[i] = next;
        });
    }
    if overflow {
        return Err(SimError::BadOption(
            "the world has more than 65535 distinct overlaps of obstacles".into(),
        ));
    }
    Ok(cov)
}

/// Traces the scan surface on the truth raster.
struct Tracer<'a> {
    origin: [f64; 2],
    res: f64,
    width: usize,
    height: usize,
    coverage: &'a Coverage,
    z_range: &'a [[f64; 2]],
    top_z: f64,
    range_max_m: f64,
}

impl Tracer<'_> {
    /// Traces `dirs` from every pose of `sampled` (the sensor at `o_body` in the body frame)
    /// in parallel over chunks of poses; the marks of `n_prisms` solids merged (an OR, so the
    /// result does not depend on the split).
    fn trace_poses(
        &self,
        sampled: &[Pose2],
        o_body: nalgebra::Vector3<f64>,
        dirs: &[[f64; 3]],
        n_prisms: usize,
    ) -> Marks {
        let cells = self.width * self.height;
        sampled
            .par_chunks(16)
            .fold(
                || Marks::new(cells, n_prisms),
                |mut m, chunk| {
                    for pose in chunk {
                        self.trace_pose(pose, o_body, dirs, &mut m);
                    }
                    m
                },
            )
            .reduce(|| Marks::new(cells, n_prisms), Marks::merge)
    }

    fn trace_pose(
        &self,
        pose: &Pose2,
        o_body: nalgebra::Vector3<f64>,
        dirs: &[[f64; 3]],
        m: &mut Marks,
    ) {
        let (s, c) = pose.yaw_rad.sin_cos();
        let (ox, oy) = pose.transform_point(o_body.x, o_body.y);
        for d in dirs {
            let dx = c * d[0] - s * d[1];
            let dy = s * d[0] + c * d[1];
            self.trace_ray([ox, oy, o_body.z], [dx, dy, d[2]], m);
        }
    }

    /// One ray from `o` along the unit 3-D direction `d` (world frame).
    fn trace_ray(&self, o: [f64; 3], d: [f64; 3], m: &mut Marks) {
        let hn = d[0].hypot(d[1]);
        if hn < 1e-9 {
            return;
        }
        let (ux, uy) = (d[0] / hn, d[1] / hn);
        let slope = d[2] / hn;
        // Horizontal distance at which the 3-D range reaches the limit.
        let t_end = self.range_max_m * hn;
        let res = self.res;
        let fx = (o[0] - self.origin[0]) / res;
        let fy = (o[1] - self.origin[1]) / res;
        let (mut cx, mut cy) = (fx.floor() as i64, fy.floor() as i64);
        let (step_x, t_delta_x, mut t_max_x) = dda_axis(fx, ux, res);
        let (step_y, t_delta_y, mut t_max_y) = dda_axis(fy, uy, res);
        let mut t_in = 0.0f64;
        loop {
            if cx < 0 || cy < 0 || cx >= self.width as i64 || cy >= self.height as i64 {
                return;
            }
            let t_out = t_max_x.min(t_max_y).min(t_end);
            let z_in = o[2] + slope * t_in;
            let z_out = o[2] + slope * t_out;
            let (z_lo, z_hi) = (z_in.min(z_out), z_in.max(z_out));
            if z_hi < 0.0 || (slope > 0.0 && z_lo > self.top_z) {
                // Below the ground (the return is ground, not an obstacle) or above
                // everything.
                return;
            }
            let i = cy as usize * self.width + cx as usize;
            let stack = &self.coverage.stacks[self.coverage.stack[i] as usize];
            let mut hit = false;
            for &pi in stack {
                let [a, b] = self.z_range[pi as usize];
                if z_lo.max(0.0) <= b && z_hi >= a {
                    m.seen[pi as usize] = true;
                    hit = true;
                }
            }
            if hit {
                m.surface.set(i);
                return;
            }
            if z_lo < 0.0 {
                // The ray reaches the ground inside this cell.
                return;
            }
            m.free.set(i);
            if t_out >= t_end {
                return;
            }
            if t_max_x < t_max_y {
                cx += step_x;
                t_max_x += t_delta_x;
            } else {
                cy += step_y;
                t_max_y += t_delta_y;
            }
            t_in = t_out;
        }
    }
}

/// Grid walk along one axis for a ray at cell coordinate `f` with horizontal direction
/// component `u`: the cell step, the distance between cell boundaries and the distance to
/// the first boundary (m).
fn dda_axis(f: f64, u: f64, res: f64) -> (i64, f64, f64) {
    let step = if u > 0.0 { 1 } else { -1 };
    if u == 0.0 {
        return (step, f64::INFINITY, f64::INFINITY);
    }
    let t_delta = res / u.abs();
    let first = if u > 0.0 {
        f.floor() + 1.0 - f
    } else {
        f - f.floor()
    };
    (step, t_delta, first * t_delta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Prism;

    /// The truth seen from one pose at the origin, 0.1 deg rays up to 20 m, 0.1 m cells.
    fn from_origin(w: &World, geometry: &LidarGeometry, mount: &Rigid3) -> ScanSurfaceTruth {
        let opts = ScanTruthOptions {
            pose_step: 1,
            rays: TruthRays::Uniform,
            angle_step_deg: 0.1,
            range_max_m: 20.0,
        };
        ScanSurfaceTruth::compute(w, &[Pose2::IDENTITY], mount, geometry, 0.1, &opts).unwrap()
    }

    fn world(prisms: Vec<Prism>) -> World {
        World {
            name: "t".into(),
            prisms,
            ground: Default::default(),
            route: vec![],
        }
    }

    /// A level 360-deg scanner at 1 m: walls it faces are visible, the one behind a taller
    /// wall is not, a floating slab above the scan plane is passed under, a low box under it
    /// is passed over.
    #[test]
    fn level_scanner_sees_faces_with_line_of_sight() {
        let w = world(vec![
            Prism::rect("wall", [10.0, 0.0], 1.0, 10.0, 0.0, 0.0, 3.0).unwrap(),
            Prism::rect("hidden", [14.0, 0.0], 1.0, 4.0, 0.0, 0.0, 3.0).unwrap(),
            Prism::rect("slab", [0.0, 8.0], 2.0, 2.0, 0.0, 2.0, 4.0).unwrap(),
            Prism::rect("low", [-8.0, 0.0], 2.0, 2.0, 0.0, 0.0, 0.5).unwrap(),
        ]);
        let geometry = LidarGeometry {
            angle_min_rad: -std::f64::consts::PI,
            angle_increment_rad: 1f64.to_radians(),
            beam_count: 360,
            range_min_m: 0.0,
            range_max_m: 30.0,
        };
        let mount = Rigid3::from_rpy(0.0, 0.0, 0.0, [0.0, 0.0, 1.0]);
        let t = from_origin(&w, &geometry, &mount);
        let v = &t.visible;
        // The face cell is the one just before or at x = 9.5 (rounding of the outline).
        let face = |y: f64| {
            [9.45, 9.55]
                .iter()
                .any(|&x| v.state_at(x, y) == CellState::Occupied)
        };
        assert!(face(0.0) && face(4.0), "wall face");
        assert_eq!(v.state_at(10.0, 0.0), CellState::Unknown, "inside the wall");
        assert_eq!(
            v.state_at(13.55, 0.0),
            CellState::Unknown,
            "behind the wall"
        );
        assert_eq!(v.state_at(5.0, 0.0), CellState::Free);
        assert_eq!(v.state_at(0.0, 8.0), CellState::Free, "under the slab");
        assert_eq!(v.state_at(-8.0, 0.0), CellState::Free, "over the low box");
        assert_eq!(v.state_at(-19.0, 8.0), CellState::Unknown, "beyond range");
        assert_eq!(v.state_at(-17.0, 8.0), CellState::Free);
        let o = &t.occupancy;
        assert_eq!(
            o.state_at(10.0, 0.0),
            CellState::Occupied,
            "seen solid: footprint"
        );
        assert_eq!(
            o.state_at(14.0, 0.0),
            CellState::Unknown,
            "hidden: not seen"
        );
        assert_eq!(o.state_at(0.0, 8.0), CellState::Free);
        assert_eq!(o.state_at(-8.0, 0.0), CellState::Free);
        // A perfect estimate (the visible faces) scores 1 / 1 / 1.
        let est = t.visible.clone();
        let c = t.compare(&est, 1).unwrap();
        assert_eq!(c.precision(), 1.0, "{c}");
        assert_eq!(c.recall(), 1.0, "{c}");
        assert_eq!(c.free_agreement(), 1.0, "{c}");
        // Missing one face halves recall about; free paint over the wall is disagreement.
        let mut est2 = est.clone();
        for j in 0..est2.height as i64 {
            for i in 0..est2.width as i64 {
                let (x, _) = est2
                    .limits
                    .cell_centre(pfslam::map::Cell::new(i as i32, j as i32));
                if (9.0..11.0).contains(&x) {
                    est2.set(i, j, CellState::Free);
                }
            }
        }
        let c = t.compare(&est2, 1).unwrap();
        assert!(c.recall() < 0.8, "{c}");
        assert!(c.free_agreement() < 1.0, "{c}");
    }

    /// A rising scan plane (pitched up 30 deg) meets a floating canopy from below: its
    /// underside is visible inside the footprint, and a wall beyond it is behind it.
    #[test]
    fn tilted_plane_hits_canopy_underside() {
        let w = world(vec![
            Prism::rect("canopy", [6.0, 0.0], 4.0, 4.0, 0.0, 3.0, 6.0).unwrap(),
        ]);
        let geometry = LidarGeometry {
            angle_min_rad: -0.3,
            angle_increment_rad: 0.01,
            beam_count: 61,
            range_min_m: 0.0,
            range_max_m: 30.0,
        };
        let pitch = -30f64.to_radians();
        let mount = Rigid3::from_rpy(0.0, pitch, 0.0, [0.0, 0.0, 1.0]);
        let t = from_origin(&w, &geometry, &mount);
        // Straight ahead the beam reaches z = 3 at x = 2 / tan 30 = 3.46 m: outside the
        // canopy (x in 4..8), so it enters through the side face at x = 4 (z = 3.31).
        assert_eq!(t.visible.state_at(4.05, 0.0), CellState::Occupied);
        assert_eq!(t.visible.state_at(3.0, 0.0), CellState::Free);
        assert_eq!(t.occupancy.state_at(6.0, 0.0), CellState::Occupied);
    }
}
