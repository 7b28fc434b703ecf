//! Comparing an estimated map with a true map.
//!
//! Definitions (cells are compared through world coordinates, so resolutions and origins may
//! differ; `tol` is the tolerance in cells of the map being searched):
//! - **precision**: estimated occupied cells with a true occupied cell within `tol` cells
//!   (Chebyshev) of their centre, over all estimated occupied cells;
//! - **recall**: *observed* true occupied cells with an estimated occupied cell within `tol`
//!   cells, over all observed true occupied cells. A true occupied cell is observed when the
//!   estimate has an opinion about it: an estimated occupied cell lies within `tol`, or its
//!   estimated state is free while no true free cell lies within `tol` (a wall the map calls
//!   free is a miss, except on the wall's boundary, which is within the tolerance). Cells the
//!   sensor never reached (the inside of buildings, walls behind others, walls only grazed
//!   by rays) stay unknown and are not expected. `recall_all` gives the same ratio over every
//!   true occupied cell inside the estimate's extent;
//! - **free agreement**: estimated free cells whose centre is free in the true map, or lies
//!   within `tol` cells of a true free cell (a wall's boundary), over all estimated free
//!   cells ("free space is where the true map is free"). `estimated_free_truly_occupied`
//!   counts, without tolerance, the estimated free cells whose centre is truly occupied.
//!
//! [`compare_maps_visible`] judges against a truth that says what the sensor could observe
//! (the simulator's scan-surface truth, `pfslam_sim::ScanSurfaceTruth`): besides the occupancy
//! truth (precision, as above) a *visibility* raster whose occupied cells are the surfaces a
//! beam could reach first within range and whose free cells are where a beam could pass
//! freely. Recall is then counted over every visible surface cell (an estimated occupied cell
//! within `tol`), whatever the estimate says or leaves unknown there, and free agreement
//! counts estimated free cells whose centre is free in the visibility raster or lies within
//! `tol` cells of such a cell.
//!
//! A SLAM map lives in its own frame (anchored at its first pose). The `_aligned` variants
//! take the rigid transform `truth_from_estimate` (for instance the SE(2) alignment of the
//! trajectory that the ATE reports, [`crate::eval::ate::AteResult::alignment`]) and compare each
//! cell through it: estimated cells are looked up in the truth at their transformed centre,
//! true cells in the estimate at their inversely transformed centre. The identity gives the
//! plain comparison.

use super::MapError;
use super::binary::BinaryMap;
use super::logodds::CellState;
use crate::geometry::Pose2;
use rayon::prelude::*;

/// The figures of one comparison.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapComparison {
    /// Tolerance used (cells).
    pub tolerance_cells: u32,
    /// Estimated occupied cells.
    pub estimated_occupied: usize,
    /// Of those, with a true occupied cell within tolerance.
    pub estimated_occupied_matched: usize,
    /// Observed true occupied cells (see the module docs).
    pub true_occupied_observed: usize,
    /// Of those, with an estimated occupied cell within tolerance.
    pub true_occupied_observed_matched: usize,
    /// True occupied cells inside the estimate's extent.
    pub true_occupied_in_extent: usize,
    /// Of those, with an estimated occupied cell within tolerance.
    pub true_occupied_in_extent_matched: usize,
    /// Estimated free cells.
    pub estimated_free: usize,
    /// Of those, free in the true map or within tolerance of a true free cell.
    pub estimated_free_truly_free: usize,
    /// Of those, occupied in the true map (strictly, no tolerance).
    pub estimated_free_truly_occupied: usize,
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 { 1.0 } else { a as f64 / b as f64 }
}

impl MapComparison {
    /// Occupied-cell precision (1 when nothing is estimated occupied).
    pub fn precision(&self) -> f64 {
        ratio(self.estimated_occupied_matched, self.estimated_occupied)
    }

    /// Occupied-cell recall over observed true walls.
    pub fn recall(&self) -> f64 {
        ratio(
            self.true_occupied_observed_matched,
            self.true_occupied_observed,
        )
    }

    /// Occupied-cell recall over every true wall inside the estimate's extent.
    pub fn recall_all(&self) -> f64 {
        ratio(
            self.true_occupied_in_extent_matched,
            self.true_occupied_in_extent,
        )
    }

    /// Fraction of estimated free cells that are free in the true map.
    pub fn free_agreement(&self) -> f64 {
        ratio(self.estimated_free_truly_free, self.estimated_free)
    }
}

impl std::fmt::Display for MapComparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "precision {:.4} ({}/{}), recall {:.4} ({}/{} observed), recall_all {:.4}, free agreement {:.4} ({}/{}, {} on true walls), tolerance {} cell(s)",
            self.precision(),
            self.estimated_occupied_matched,
            self.estimated_occupied,
            self.recall(),
            self.true_occupied_observed_matched,
            self.true_occupied_observed,
            self.recall_all(),
            self.free_agreement(),
            self.estimated_free_truly_free,
            self.estimated_free,
            self.estimated_free_truly_occupied,
            self.tolerance_cells
        )
    }
}

/// True when `map` has a cell in `state` within `tol` cells of the cell containing `(x, y)`.
fn state_near(map: &BinaryMap, x_m: f64, y_m: f64, tol: i64, state: CellState) -> bool {
    let c = map.limits.cell_of(x_m, y_m);
    let (ci, cj) = (c.i as i64, c.j as i64);
    for j in cj - tol..=cj + tol {
        for i in ci - tol..=ci + tol {
            if map.get(i, j) == state {
                return true;
            }
        }
    }
    false
}

/// Compares `estimate` with `truth` (see the module docs for the definitions).
pub fn compare_maps(
    estimate: &BinaryMap,
    truth: &BinaryMap,
    tolerance_cells: u32,
) -> Result<MapComparison, MapError> {
    compare_impl(estimate, truth, None, tolerance_cells, None)
}

/// Compares `estimate` with an occupancy truth and a visibility truth (see the module docs):
/// precision against `truth`'s occupied cells, recall over `visible`'s occupied cells, free
/// agreement against `visible`'s free cells.
pub fn compare_maps_visible(
    estimate: &BinaryMap,
    truth: &BinaryMap,
    visible: &BinaryMap,
    tolerance_cells: u32,
) -> Result<MapComparison, MapError> {
    compare_impl(estimate, truth, Some(visible), tolerance_cells, None)
}

/// [`compare_maps`] with the estimate moved by `truth_from_estimate` (see the module docs).
pub fn compare_maps_aligned(
    estimate: &BinaryMap,
    truth: &BinaryMap,
    tolerance_cells: u32,
    truth_from_estimate: &Pose2,
) -> Result<MapComparison, MapError> {
    compare_impl(
        estimate,
        truth,
        None,
        tolerance_cells,
        Some(*truth_from_estimate),
    )
}

/// [`compare_maps_visible`] with the estimate moved by `truth_from_estimate` (see the module
/// docs).
pub fn compare_maps_visible_aligned(
    estimate: &BinaryMap,
    truth: &BinaryMap,
    visible: &BinaryMap,
    tolerance_cells: u32,
    truth_from_estimate: &Pose2,
) -> Result<MapComparison, MapError> {
    compare_impl(
        estimate,
        truth,
        Some(visible),
        tolerance_cells,
        Some(*truth_from_estimate),
    )
}

/// A rigid transform with its yaw's sine and cosine computed once: mapping every cell
/// through [`Pose2::transform_point`] spent more time in `sin_cos` than in the comparison.
#[derive(Clone, Copy)]
struct Through {
    pose: Pose2,
    sin_cos: (f64, f64),
}

impl Through {
    fn new(pose: Pose2) -> Self {
        Through {
            pose,
            sin_cos: pose.yaw_rad.sin_cos(),
        }
    }
}

/// Maps a point through an optional rigid transform (`None`: unchanged, the same bits).
#[inline]
fn through(t: Option<&Through>, x_m: f64, y_m: f64) -> (f64, f64) {
    t.map_or((x_m, y_m), |t| {
        t.pose.transform_point_with(t.sin_cos, x_m, y_m)
    })
}

fn compare_impl(
    estimate: &BinaryMap,
    truth: &BinaryMap,
    visible: Option<&BinaryMap>,
    tolerance_cells: u32,
    truth_from_estimate: Option<Pose2>,
) -> Result<MapComparison, MapError> {
    if visible.is_some_and(|v| v.width == 0 || v.height == 0) {
        return Err(MapError::Compare("the visibility truth is empty".into()));
    }
    let truth_from_estimate = truth_from_estimate.map(Through::new);
    let estimate_from_truth = truth_from_estimate.map(|t| Through::new(t.pose.inverse()));
    if estimate.width == 0 || estimate.height == 0 {
        return Err(MapError::Compare("the estimated map is empty".into()));
    }
    if truth.width == 0 || truth.height == 0 {
        return Err(MapError::Compare("the true map is empty".into()));
    }
    let pair = MapPair {
        estimate,
        truth,
        visible,
        tol: tolerance_cells as i64,
        to_truth: truth_from_estimate.as_ref(),
        to_estimate: estimate_from_truth.as_ref(),
    };
    let est = pair.estimate_counts();
    let tru = pair.truth_counts();
    let tru = match visible {
        None => tru,
        Some(v) => {
            let seen = pair.visible_counts(v);
            [tru[0], tru[1], seen[0], seen[1]]
        }
    };
    Ok(MapComparison {
        tolerance_cells,
        estimated_occupied: est[0],
        estimated_occupied_matched: est[1],
        estimated_free: est[2],
        estimated_free_truly_free: est[3],
        estimated_free_truly_occupied: est[4],
        true_occupied_in_extent: tru[0],
        true_occupied_in_extent_matched: tru[1],
        true_occupied_observed: tru[2],
        true_occupied_observed_matched: tru[3],
    })
}

/// The two maps of a comparison, how far a match may be, and the transforms between them.
struct MapPair<'a> {
    estimate: &'a BinaryMap,
    truth: &'a BinaryMap,
    visible: Option<&'a BinaryMap>,
    tol: i64,
    to_truth: Option<&'a Through>,
    to_estimate: Option<&'a Through>,
}

impl MapPair<'_> {
    /// The estimate's cells: occupied, occupied near a true wall, free, free where truly
    /// free (or visible), free where truly occupied. Rows in parallel; integer sums are
    /// order-independent.
    fn estimate_counts(&self) -> [usize; 5] {
        cell_sums(self.estimate, None, self.to_truth, |n, s, _, at| {
            self.count_estimate_cell(s, at, n)
        })
    }

    /// One estimated cell in state `s` at `(x, y)` in the truth's frame, counted into `n`.
    #[inline]
    fn count_estimate_cell(&self, s: CellState, (x, y): (f64, f64), n: &mut [usize; 5]) {
        let (truth, tol) = (self.truth, self.tol);
        match s {
            CellState::Occupied => {
                n[0] += 1;
                if state_near(truth, x, y, tol, CellState::Occupied) {
                    n[1] += 1;
                }
            }
            CellState::Free => {
                n[2] += 1;
                if let Some(v) = self.visible {
                    if state_near(v, x, y, tol, CellState::Free) {
                        n[3] += 1;
                    } else if truth.state_at(x, y) == CellState::Occupied {
                        n[4] += 1;
                    }
                    return;
                }
                match truth.state_at(x, y) {
                    CellState::Free => n[3] += 1,
                    CellState::Occupied => {
                        n[4] += 1;
                        // A wall-boundary cell (true free within tolerance) is not counted
                        // as wrong.
                        if state_near(truth, x, y, tol, CellState::Free) {
                            n[3] += 1;
                        }
                    }
                    CellState::Unknown => {}
                }
            }
            CellState::Unknown => {}
        }
    }

    /// The true walls inside the estimate's extent: all, matched, observed (without a
    /// visibility truth), observed and matched.
    fn truth_counts(&self) -> [usize; 4] {
        let (estimate, truth, tol) = (self.estimate, self.truth, self.tol);
        let er = estimate.limits.resolution_m();
        let (ex0, ey0) = (estimate.limits.origin_x_m(), estimate.limits.origin_y_m());
        let (ex1, ey1) = (
            ex0 + estimate.width as f64 * er,
            ey0 + estimate.height as f64 * er,
        );
        let walls = Some(CellState::Occupied);
        cell_sums(truth, walls, self.to_estimate, |n, _, (tx, ty), (x, y)| {
            if !(x >= ex0 && x < ex1 && y >= ey0 && y < ey1) {
                return;
            }
            let matched = state_near(estimate, x, y, tol, CellState::Occupied);
            n[0] += 1;
            n[1] += matched as usize;
            if self.visible.is_some() {
                // recall is counted over the visibility truth
                return;
            }
            let observed = matched
                || match estimate.state_at(x, y) {
                    CellState::Occupied => true,
                    // Free on a wall's boundary cell is within the tolerance.
                    CellState::Free => !state_near(truth, tx, ty, tol, CellState::Free),
                    CellState::Unknown => false,
                };
            if observed {
                n[2] += 1;
                n[3] += matched as usize;
            }
        })
    }

    /// The walls of the visibility truth `v`: all, and those the estimate matched.
    fn visible_counts(&self, v: &BinaryMap) -> [usize; 2] {
        let walls = Some(CellState::Occupied);
        cell_sums(v, walls, self.to_estimate, |n, _, _, (x, y)| {
            n[0] += 1;
            n[1] += state_near(self.estimate, x, y, self.tol, CellState::Occupied) as usize;
        })
    }
}

/// Sums `count(n, state, centre, centre through to)` over the cells of `map` (those in
/// state `only` when given): rows in parallel; integer sums are order-independent.
fn cell_sums<const N: usize>(
    map: &BinaryMap,
    only: Option<CellState>,
    to: Option<&Through>,
    count: impl Fn(&mut [usize; N], CellState, (f64, f64), (f64, f64)) + Sync + Send,
) -> [usize; N] {
    (0..map.height)
        .into_par_iter()
        .map(|j| {
            let mut n = [0usize; N];
            for i in 0..map.width {
                let s = map.cells[j * map.width + i];
                if only.is_some_and(|only| s != only) {
                    continue;
                }
                let (x, y) = map.limits.cell_centre(super::Cell::new(i as i32, j as i32));
                count(&mut n, s, (x, y), through(to, x, y));
            }
            n
        })
        .reduce(|| [0; N], |a, b| std::array::from_fn(|k| a[k] + b[k]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::MapLimits;

    /// A 10 x 10 m room at (0, 0)-(10, 10), walls three cells thick, free inside.
    fn square_room(res: f64) -> BinaryMap {
        let n = (10.0 / res).round() as i64;
        let mut m = BinaryMap::filled(
            MapLimits::new(res, 0.0, 0.0),
            n as usize,
            n as usize,
            CellState::Free,
        );
        for j in 0..n {
            for i in 0..n {
                if i.min(j) < 3 || i.max(j) >= n - 3 {
                    m.set(i, j, CellState::Occupied);
                }
            }
        }
        m
    }

    #[test]
    fn identical_maps_are_perfect() {
        let t = square_room(0.1);
        let c = compare_maps(&t, &t, 1).unwrap();
        assert_eq!(c.precision(), 1.0);
        assert_eq!(c.recall(), 1.0);
        assert_eq!(c.recall_all(), 1.0);
        assert_eq!(c.free_agreement(), 1.0);
        assert_eq!(c.estimated_occupied, 10000 - 94 * 94);
        assert_eq!(c.true_occupied_observed, 10000 - 94 * 94);
    }

    #[test]
    fn shifted_walls_need_tolerance_and_missing_walls_cut_recall() {
        let t = square_room(0.1);
        let mut e = t.clone();
        e.limits = MapLimits::new(0.1, 0.2, 0.0); // two cells to the right
        let strict = compare_maps(&e, &t, 0).unwrap();
        assert!(strict.precision() < 0.95, "{strict}");
        let tol = compare_maps(&e, &t, 2).unwrap();
        assert_eq!(tol.precision(), 1.0, "{tol}");
        // the estimate calls the top wall free: that wall is observed and missed
        let mut e = t.clone();
        for j in 97..100 {
            for i in 0..100 {
                e.set(i, j, CellState::Free);
            }
        }
        let c = compare_maps(&e, &t, 1).unwrap();
        assert_eq!(c.precision(), 1.0);
        assert!(c.recall() < 0.9, "{c}");
        assert!(c.free_agreement() < 0.98, "{c}");
        // an estimate that never reached the top half does not expect its walls
        let mut e = t.clone();
        for j in 50..100 {
            for i in 0..100 {
                e.set(i, j, CellState::Unknown);
            }
        }
        let c = compare_maps(&e, &t, 1).unwrap();
        assert_eq!(c.recall(), 1.0, "{c}");
        assert!(c.recall_all() < 0.8, "{c}");
    }

    /// The room seen from a frame `truth_from_estimate` (rotated 3 deg, shifted by 1.2 m):
    /// as written its walls miss; through the transform they match.
    #[test]
    fn aligned_comparison_undoes_a_rigid_offset() {
        let t = square_room(0.1);
        let truth_from_estimate = Pose2::new(1.0, -0.7, 3f64.to_radians());
        let mut e = BinaryMap::filled(
            MapLimits::new(0.1, -2.0, -2.0),
            140,
            140,
            CellState::Unknown,
        );
        for j in 0..140 {
            for i in 0..140 {
                let (x, y) = e.limits.cell_centre(crate::map::Cell::new(i, j));
                let (x, y) = truth_from_estimate.transform_point(x, y);
                e.set(i as i64, j as i64, t.state_at(x, y));
            }
        }
        let plain = compare_maps(&e, &t, 1).unwrap();
        assert!(plain.recall() < 0.9 && plain.precision() < 0.9, "{plain}");
        let aligned = compare_maps_aligned(&e, &t, 1, &truth_from_estimate).unwrap();
        assert!(aligned.precision() > 0.999, "{aligned}");
        assert!(aligned.recall() > 0.999, "{aligned}");
        assert!(aligned.free_agreement() > 0.999, "{aligned}");
        // The identity is the plain comparison, and the visible variant agrees.
        let id = compare_maps_aligned(&e, &t, 1, &Pose2::IDENTITY).unwrap();
        assert_eq!(id, plain);
        let v = compare_maps_visible_aligned(&e, &t, &t, 1, &truth_from_estimate).unwrap();
        assert!(v.recall() > 0.999 && v.precision() > 0.999, "{v}");
    }

    #[test]
    fn free_on_walls_is_counted_except_on_boundaries() {
        let t = square_room(0.1);
        let e = BinaryMap::filled(t.limits, 100, 100, CellState::Free);
        let c = compare_maps(&e, &t, 1).unwrap();
        assert_eq!(c.estimated_free_truly_occupied, 10000 - 94 * 94);
        // the innermost ring of wall cells (96 * 4 - 4 cells) touches the free room
        let ok = 94 * 94 + 96 * 4 - 4;
        assert_eq!(c.estimated_free_truly_free, ok, "{c}");
        assert_eq!(c.recall(), 0.0, "{c}");
        let empty = BinaryMap::filled(t.limits, 0, 0, CellState::Free);
        assert!(compare_maps(&empty, &t, 1).is_err());
    }
}
