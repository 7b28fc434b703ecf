//! The `rbpf` observation model's log-likelihood of a scan in a particle's grid: the entry
//! point, the portable kernel (a point at a time) and what both share; the AVX2 kernel for
//! the default 3x3 search in `x86.rs`.

use super::nearest::{TilePoint, nearest_3x3};
use super::{TILE_SHIFT, TILE_SIZE};
use crate::geometry::Pose2;
use crate::geometry::cells::{Cell, MapLimits, floor_to_i32};

#[cfg(target_arch = "x86_64")]
mod x86;

const TS: i32 = TILE_SIZE as i32;
const MASK: i32 = TS - 1;

/// The smooth observation model on a log-odds grid, per point: `-d^2 / (2 sigma^2)` with `d`
/// the distance from the point to the centre of the nearest occupied cell within `kernel`
/// cells, floored at `no_hit` (also the value when none is found).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservationModel {
    /// Search half-width (cells).
    pub kernel: i32,
    /// Fixed-point log-odds above which a cell is occupied.
    pub occupied_fixed: i16,
    /// `resolution^2 / (2 sigma^2)`: converts squared cell distances to log-likelihood.
    pub res2_over_2s2: f64,
    /// Floor of a point's log-likelihood.
    pub no_hit: f64,
}

/// A candidate's bar in `scan_log_likelihood_above`: it wins only if
/// `log-likelihood - penalty > bar`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bar {
    /// Subtracted from the log-likelihood before the comparison (the prior's term).
    pub penalty: f64,
    /// The value to beat (strictly).
    pub bar: f64,
}

/// A particle's grid as the kernels read it: tiles of `TILE_SIZE x TILE_SIZE` fixed-point
/// log-odds (row-major), found by tile coordinates, unwritten tiles all 0. The map's grid
/// implements it; a trait rather than a view because the tile directory's layout is the
/// map's own.
pub trait TileGrid {
    /// The world <-> cell frame.
    fn limits(&self) -> &MapLimits;
    /// The cells of the tile at tile coordinates `(ti, tj)` (cell coordinates shifted right
    /// by `TILE_SHIFT`); `None` when never written.
    fn tile_cells(&self, ti: i32, tj: i32) -> Option<&[i16]>;
    /// A cell's fixed-point log-odds (0 when never written).
    fn logodds_fixed(&self, cell: Cell) -> i16;
}

/// The scan's log-likelihood with an optional bar (the `rbpf` observation model's
/// `scan_log_likelihood_above`): in AVX2 for the 3x3 kernel where the CPU has it, else
/// [`portable`]; the same bits either way.
pub fn scan_log_likelihood_above<G: TileGrid + ?Sized>(
    grid: &G,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
    bar: Option<Bar>,
) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if model.kernel == 1 && super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return unsafe { x86::likelihood_avx2(grid, model, points, pose, bar) };
    }
    portable(grid, model, points, pose, bar)
}

/// Up to four points' continuous cell coordinates `(u, v)` and cells `(i, j)`.
#[derive(Default)]
pub(super) struct Projected {
    u: [f64; 4],
    v: [f64; 4],
    i: [i32; 4],
    j: [i32; 4],
}

/// Maps the body-frame points of `chunk` (at most four) through `pose` (`sin_cos` of its
/// yaw) into `limits`' cell coordinates.
#[inline(always)]
fn project_scalar(
    limits: &MapLimits,
    pose: &Pose2,
    (s, c): (f64, f64),
    chunk: &[[f64; 2]],
    out: &mut Projected,
) {
    for (n, p) in chunk.iter().enumerate().take(4) {
        let (x, y) = pose.transform_point_with((s, c), p[0], p[1]);
        let (u, v) = limits.cell_coords(x, y);
        (out.u[n], out.v[n]) = (u, v);
        (out.i[n], out.j[n]) = (floor_to_i32(u), floor_to_i32(v));
    }
}

/// The tile of the last point looked up (most points fall in the same tile as their
/// predecessor): one directory lookup per change of tile.
struct TileCache<'a> {
    key: (i32, i32),
    tile: Option<&'a [i16]>,
}

impl<'a> TileCache<'a> {
    fn new() -> Self {
        TileCache {
            key: (i32::MIN, i32::MIN),
            tile: None,
        }
    }

    #[inline(always)]
    fn get<G: TileGrid + ?Sized>(&mut self, grid: &'a G, key: (i32, i32)) -> Option<&'a [i16]> {
        if key != self.key {
            self.key = key;
            self.tile = grid.tile_cells(key.0, key.1);
        }
        self.tile
    }
}

/// A point's log-likelihood term from its smallest squared distance `best` (cells).
#[inline(always)]
fn point_term(model: &ObservationModel, best: f64) -> f64 {
    if best.is_finite() {
        (-best * model.res2_over_2s2).max(model.no_hit)
    } else {
        model.no_hit
    }
}

/// The smallest squared distance (cells) from the point at `(u, v)` (cell `(i, j)`) to the
/// centre of an occupied cell within the kernel; infinity if none. `nearest` is the 3x3
/// kernel's minimum within one tile.
#[inline(always)]
fn point_best<'a, G: TileGrid + ?Sized>(
    grid: &'a G,
    model: &ObservationModel,
    (u, v, i, j): (f64, f64, i32, i32),
    cache: &mut TileCache<'a>,
    nearest: &impl Fn(&[i16], TilePoint, i16) -> f64,
) -> f64 {
    let (k, occ) = (model.kernel, model.occupied_fixed);
    let mut best = f64::INFINITY;
    let (li, lj) = (i & MASK, j & MASK);
    if li >= k && lj >= k && li < TS - k && lj < TS - k {
        // The whole kernel lies in one tile: one directory lookup.
        if let Some(cells) = cache.get(grid, (i >> TILE_SHIFT, j >> TILE_SHIFT)) {
            if k == 1 {
                let at = TilePoint {
                    u_cells: u,
                    v_cells: v,
                    i,
                    j,
                    local_i: li,
                    local_j: lj,
                };
                best = nearest(cells, at, occ);
            } else {
                for dj in -k..=k {
                    let row = ((lj + dj) as usize) << TILE_SHIFT;
                    let dv = v - (f64::from(j + dj) + 0.5);
                    for di in -k..=k {
                        if cells[row + (li + di) as usize] > occ {
                            let du = u - (f64::from(i + di) + 0.5);
                            best = best.min(du * du + dv * dv);
                        }
                    }
                }
            }
        } else if occ < 0 {
            // An unwritten tile is all log-odds 0.
            let (du, dv) = (u - (f64::from(i) + 0.5), v - (f64::from(j) + 0.5));
            best = du * du + dv * dv;
        }
    } else {
        for dj in -k..=k {
            let dv = v - (f64::from(j + dj) + 0.5);
            for di in -k..=k {
                if grid.logodds_fixed(Cell::new(i + di, j + dj)) > occ {
                    let du = u - (f64::from(i + di) + 0.5);
                    best = best.min(du * du + dv * dv);
                }
            }
        }
    }
    best
}

/// [`scan_log_likelihood_above`] without AVX2 (or for kernels other than 3x3): a point at a
/// time.
pub fn portable<G: TileGrid + ?Sized>(
    grid: &G,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
    bar: Option<Bar>,
) -> f64 {
    // Without a bar, a test that never stops (NaN compares false).
    let Bar { penalty, bar } = bar.unwrap_or(Bar {
        penalty: 0.0,
        bar: f64::NAN,
    });
    let limits = grid.limits();
    let (s, c) = pose.yaw_rad.sin_cos();
    let mut total = 0.0;
    let mut cache = TileCache::new();
    let mut at = Projected::default();
    for n in 0..points.len() {
        if n % 4 == 0 {
            project_scalar(limits, pose, (s, c), &points[n..], &mut at);
        }
        let point = (at.u[n % 4], at.v[n % 4], at.i[n % 4], at.j[n % 4]);
        total += point_term(
            model,
            point_best(grid, model, point, &mut cache, &nearest_3x3),
        );
        if total - penalty <= bar {
            return total;
        }
    }
    total
}
