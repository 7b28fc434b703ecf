//! The observation model: a scan's log-likelihood in a particle's own map, with its
//! AVX2 kernels and their portable twins.

use crate::geometry::Pose2;
use crate::map::TILE_SIZE;
use crate::map::grid::TILE_SHIFT;
use crate::map::limits::{MapLimits, floor_to_i32};
use crate::map::{Cell, OccupancyGrid};

#[cfg(target_arch = "x86_64")]
use super::nearest::nearest_3x3_avx2;
use super::nearest::{TilePoint, nearest_3x3};

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

const TS: i32 = TILE_SIZE as i32;
const MASK: i32 = TS - 1;

/// Log-likelihood of the body-frame `points` seen from `pose` in `grid` (sum over points).
///
/// Per point, the same arithmetic as the plain rule (`tests::scan_log_likelihood_plain`), so
/// the same bits: squared distances `du^2 + dv^2` from the same products (the per-row and
/// per-column squares are computed once), the minimum taken exactly, the sum in point order.
/// Faster: an integer floor (`f64::floor` is a libm call on baseline x86-64), the tile of the
/// previous point reused, and for the default 3x3 kernel a branch-free minimum. With AVX2
/// (the default kernel): four points at a time, projected together, their kernel rows
/// gathered (one 8-byte load per point and row) and their minima taken across lanes.
pub fn scan_log_likelihood(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
) -> f64 {
    scan_log_likelihood_above(grid, model, points, pose, None)
}

/// A candidate's bar in [`scan_log_likelihood_above`]: it wins only if
/// `log-likelihood - penalty > bar`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bar {
    /// Subtracted from the log-likelihood before the comparison (the prior's term).
    pub penalty: f64,
    /// The value to beat (strictly).
    pub bar: f64,
}

/// [`scan_log_likelihood`], but with a `bar` it may stop early: every point's term is <= 0,
/// so the running sum only falls (rounding is monotonic) and once `sum - penalty <= bar`
/// the candidate cannot win. Then it returns that partial sum, for which `sum - penalty >
/// bar` is false, as it would be for the full sum. Otherwise (and without a bar) the
/// full sum, the same bits as [`scan_log_likelihood`].
pub fn scan_log_likelihood_above(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
    bar: Option<Bar>,
) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if model.kernel == 1 && std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is present (checked above).
        return unsafe { likelihood_avx2(grid, model, points, pose, bar) };
    }
    likelihood_scalar(grid, model, points, pose, bar)
}

/// [`scan_log_likelihood_above`] for the 3x3 kernel in AVX2, four points at a time:
/// projected ([`project4_avx2`]), their kernel rows gathered ([`gather4_avx2`]), their
/// minima taken across lanes ([`nearest4_avx2`]); then the sum in point order, the bar
/// tested after each point. The same bits. (Issuing the next four's gathers before this
/// four's minima measured no faster.)
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn likelihood_avx2(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
    bar: Option<Bar>,
) -> f64 {
    let Bar { penalty, bar } = bar.unwrap_or(Bar {
        penalty: 0.0,
        bar: f64::NAN,
    });
    let limits = grid.limits();
    let (s, c) = pose.yaw_rad.sin_cos();
    // The closure inherits this function's AVX2.
    let nearest = |cells: &[i16], at, occ| nearest_3x3_avx2(cells, at, occ);
    let mut cache = TileCache::new();
    let mut total = 0.0;
    let (quads, rest) = points.as_chunks::<4>();
    for four in quads {
        let rows = gather4_avx2(grid, project4_avx2(limits, pose, (s, c), four), &mut cache);
        for b in nearest4_avx2(grid, model, rows, &mut cache) {
            total += point_term(model, b);
            if total - penalty <= bar {
                return total;
            }
        }
    }
    let mut at = Projected::default();
    project_scalar(limits, pose, (s, c), rest, &mut at);
    for n in 0..rest.len() {
        let point = (at.u[n], at.v[n], at.i[n], at.j[n]);
        total += point_term(model, point_best(grid, model, point, &mut cache, &nearest));
        if total - penalty <= bar {
            return total;
        }
    }
    total
}

/// Up to four points' continuous cell coordinates `(u, v)` and cells `(i, j)`.
#[derive(Default)]
struct Projected {
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

/// Four points' continuous cell coordinates and, where every lane is finite and under
/// 2^30 cells (the vector floor's exact range), their cells.
#[cfg(target_arch = "x86_64")]
struct Projected4 {
    u: std::arch::x86_64::__m256d,
    v: std::arch::x86_64::__m256d,
    cells: Option<(std::arch::x86_64::__m128i, std::arch::x86_64::__m128i)>,
}

/// [`project_scalar`] four points at a time in AVX2: the same operations in the same order
/// per lane (no fused multiply-add), so the same bits; the floor in vector form where every
/// lane is finite and well inside the `i32` range (else none: the caller takes the scalar,
/// saturating one).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn project4_avx2(
    limits: &MapLimits,
    pose: &Pose2,
    (s, c): (f64, f64),
    four: &[[f64; 2]; 4],
) -> Projected4 {
    use std::arch::x86_64::*;
    let flat = four.as_flattened();
    // SAFETY: unaligned loads of 4 + 4 f64 from an 8-element array.
    let (a, b) = unsafe {
        (
            _mm256_loadu_pd(flat.as_ptr()),
            _mm256_loadu_pd(flat[4..].as_ptr()),
        )
    };
    // [x0 y0 x1 y1], [x2 y2 x3 y3] -> [x0 x1 x2 x3], [y0 y1 y2 y3].
    let px = _mm256_permute4x64_pd::<0b1101_1000>(_mm256_unpacklo_pd(a, b));
    let py = _mm256_permute4x64_pd::<0b1101_1000>(_mm256_unpackhi_pd(a, b));
    let (sv, cv) = (_mm256_set1_pd(s), _mm256_set1_pd(c));
    let x = _mm256_sub_pd(
        _mm256_add_pd(_mm256_set1_pd(pose.x_m), _mm256_mul_pd(cv, px)),
        _mm256_mul_pd(sv, py),
    );
    let y = _mm256_add_pd(
        _mm256_add_pd(_mm256_set1_pd(pose.y_m), _mm256_mul_pd(sv, px)),
        _mm256_mul_pd(cv, py),
    );
    let inv = _mm256_set1_pd(limits.inv_resolution());
    let u = _mm256_mul_pd(_mm256_sub_pd(x, _mm256_set1_pd(limits.origin_x_m())), inv);
    let v = _mm256_mul_pd(_mm256_sub_pd(y, _mm256_set1_pd(limits.origin_y_m())), inv);
    // |u|, |v| < 2^30 in every lane (false for NaN): the floor is exact in i32.
    let lim = _mm256_set1_pd(1073741824.0);
    let abs = _mm256_castsi256_pd(_mm256_set1_epi64x(i64::MAX));
    let inside = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_and_pd(u, abs), lim),
        _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_and_pd(v, abs), lim),
    );
    let cells = (_mm256_movemask_pd(inside) == 0b1111).then(|| {
        (
            _mm256_cvttpd_epi32(_mm256_floor_pd(u)),
            _mm256_cvttpd_epi32(_mm256_floor_pd(v)),
        )
    });
    Projected4 { u, v, cells }
}

/// Read by the row gathers of points that take the scalar path instead: three rows at a
/// tile's stride, no cell above any threshold.
#[cfg(target_arch = "x86_64")]
static NEVER_OCCUPIED: [i16; 2 * TILE_SIZE + 4] = [i16::MIN; 2 * TILE_SIZE + 4];

/// Four projected points with their kernels' rows gathered ([`gather4_avx2`]).
#[cfg(target_arch = "x86_64")]
struct Gathered4 {
    u: std::arch::x86_64::__m256d,
    v: std::arch::x86_64::__m256d,
    /// The cells (zero when the vector floor was not taken: then every point is scalar).
    i: std::arch::x86_64::__m128i,
    j: std::arch::x86_64::__m128i,
    /// Each point's three kernel rows, four cells per point (the fourth never used).
    rows: [std::arch::x86_64::__m256i; 3],
    /// Bit n: point n takes the scalar path ([`point_best`]).
    scalar: u32,
}

/// Gathers four projected points' 3x3 kernel rows: per row one 8-byte load per point
/// (three cells and one never used). Points whose kernel leaves its tile, whose tile is
/// unwritten, or whose cells the vector floor could not give are marked for the scalar
/// path instead (their rows read never-occupied cells).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn gather4_avx2<'a>(
    grid: &'a OccupancyGrid,
    at: Projected4,
    cache: &mut TileCache<'a>,
) -> Gathered4 {
    use std::arch::x86_64::*;
    let Some((i, j)) = at.cells else {
        return Gathered4 {
            u: at.u,
            v: at.v,
            i: _mm_setzero_si128(),
            j: _mm_setzero_si128(),
            rows: [_mm256_set1_epi16(i16::MIN); 3],
            scalar: 0b1111,
        };
    };
    let one = _mm_set1_epi32(1);
    let mask = _mm_set1_epi32(MASK);
    let (li, lj) = (_mm_and_si128(i, mask), _mm_and_si128(j, mask));
    // 1 <= l <= TS - 2 on both axes: the kernel lies in the tile. And not the tile's last
    // kernel (both at TS - 2), whose last 8-byte row would read one cell past the tile.
    let last = _mm_set1_epi32(TS - 1);
    let inside = |l| {
        _mm_and_si128(
            _mm_cmpgt_epi32(l, _mm_setzero_si128()),
            _mm_cmpgt_epi32(last, l),
        )
    };
    let corner = _mm_and_si128(
        _mm_cmpeq_epi32(li, _mm_set1_epi32(TS - 2)),
        _mm_cmpeq_epi32(lj, _mm_set1_epi32(TS - 2)),
    );
    let ok = _mm_andnot_si128(corner, _mm_and_si128(inside(li), inside(lj)));
    let ok_bits = _mm_movemask_ps(_mm_castsi128_ps(ok));
    let ti = _mm_srai_epi32::<{ TILE_SHIFT as i32 }>(i);
    let tj = _mm_srai_epi32::<{ TILE_SHIFT as i32 }>(j);
    // Each point's first kernel cell within its tile (cells, then bytes).
    let first = _mm_add_epi32(
        _mm_slli_epi32::<{ TILE_SHIFT as i32 }>(_mm_sub_epi32(lj, one)),
        _mm_sub_epi32(li, one),
    );
    let first = _mm256_slli_epi64::<1>(_mm256_cvtepi32_epi64(first));
    let same = _mm_and_si128(
        _mm_cmpeq_epi32(ti, _mm_set1_epi32(cache.key.0)),
        _mm_cmpeq_epi32(tj, _mm_set1_epi32(cache.key.1)),
    );
    let mut scalar = 0u32;
    let (base, offsets) = match cache.tile {
        Some(cells) if ok_bits == 0b1111 && _mm_movemask_ps(_mm_castsi128_ps(same)) == 0b1111 => {
            (cells.as_ptr(), first)
        }
        _ => {
            // Offsets from the never-occupied rows (to another allocation: the gather
            // adds them as plain addresses).
            let base = NEVER_OCCUPIED.as_ptr();
            let mut tis = [0i32; 4];
            let mut tjs = [0i32; 4];
            let mut firsts = [0i64; 4];
            // SAFETY: stores into local arrays of four i32 / i64.
            unsafe {
                _mm_storeu_si128(tis.as_mut_ptr().cast(), ti);
                _mm_storeu_si128(tjs.as_mut_ptr().cast(), tj);
                _mm256_storeu_si256(firsts.as_mut_ptr().cast(), first);
            }
            let mut offsets = [0i64; 4];
            for n in 0..4 {
                let tile = match ok_bits >> n & 1 {
                    1 => cache.get(grid, (tis[n], tjs[n])),
                    _ => None,
                };
                match tile {
                    Some(cells) => {
                        offsets[n] = (cells.as_ptr() as i64)
                            .wrapping_sub(base as i64)
                            .wrapping_add(firsts[n]);
                    }
                    None => scalar |= 1 << n,
                }
            }
            // SAFETY: a load from a local array of four i64.
            (base, unsafe { _mm256_loadu_si256(offsets.as_ptr().cast()) })
        }
    };
    let row = |r: i64| {
        let row_offsets = _mm256_add_epi64(offsets, _mm256_set1_epi64x(2 * TS as i64 * r));
        // SAFETY: every lane reads 8 bytes inside a tile (the kernel's row and one more
        // cell, which the corner test keeps inside) or inside `NEVER_OCCUPIED`.
        unsafe { _mm256_i64gather_epi64::<1>(base.cast(), row_offsets) }
    };
    Gathered4 {
        u: at.u,
        v: at.v,
        i,
        j,
        rows: [row(0), row(1), row(2)],
        scalar,
    }
}

/// The 3x3 kernel's minimum ([`nearest_3x3`]) of four gathered points at once: per row a
/// compare, and per cell a select and a minimum across the four lanes. The candidates are
/// the scalar rule's (`du^2 + dv^2` from the same products), and the minimum of finite
/// values does not depend on their order: the same bits. Points marked scalar take
/// [`point_best`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn nearest4_avx2<'a>(
    grid: &'a OccupancyGrid,
    model: &ObservationModel,
    at: Gathered4,
    cache: &mut TileCache<'a>,
) -> [f64; 4] {
    use std::arch::x86_64::*;
    let (i, j) = (at.i, at.j);
    let half = _mm256_set1_pd(0.5);
    // `f64::from(i + d) + 0.5`, then the squared distance, per lane.
    let sq = |x, c, d| {
        let dx = _mm256_sub_pd(
            x,
            _mm256_add_pd(
                _mm256_cvtepi32_pd(_mm_add_epi32(c, _mm_set1_epi32(d))),
                half,
            ),
        );
        _mm256_mul_pd(dx, dx)
    };
    let du2 = [sq(at.u, i, -1), sq(at.u, i, 0), sq(at.u, i, 1)];
    let occ = _mm256_set1_epi16(model.occupied_fixed);
    let inf = _mm256_set1_pd(f64::INFINITY);
    let mut best = inf;
    for (row, d) in at.rows.into_iter().zip(-1..=1) {
        let dv2 = sq(at.v, j, d);
        let occupied = _mm256_cmpgt_epi16(row, occ);
        // Column c's 16-bit flag moved to the top of its lane, where the blend reads it.
        let flags = [
            _mm256_slli_epi64::<48>(occupied),
            _mm256_slli_epi64::<32>(occupied),
            _mm256_slli_epi64::<16>(occupied),
        ];
        for (du2, flag) in du2.iter().zip(flags) {
            let d = _mm256_blendv_pd(inf, _mm256_add_pd(*du2, dv2), _mm256_castsi256_pd(flag));
            // `minpd(d, best)` is `d < best ? d : best`, the scalar rule.
            best = _mm256_min_pd(d, best);
        }
    }
    let mut out = [0.0f64; 4];
    // SAFETY: a store into a local array of four f64.
    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), best) };
    if at.scalar != 0 {
        let nearest = |cells: &[i16], at, occ| nearest_3x3_avx2(cells, at, occ);
        let mut us = [0.0f64; 4];
        let mut vs = [0.0f64; 4];
        // SAFETY: stores into local arrays of four f64.
        unsafe {
            _mm256_storeu_pd(us.as_mut_ptr(), at.u);
            _mm256_storeu_pd(vs.as_mut_ptr(), at.v);
        }
        for n in 0..4 {
            if at.scalar >> n & 1 == 1 {
                // The scalar, saturating floor (the vector one's value where it was taken).
                let point = (us[n], vs[n], floor_to_i32(us[n]), floor_to_i32(vs[n]));
                out[n] = point_best(grid, model, point, cache, &nearest);
            }
        }
    }
    out
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
    fn get(&mut self, grid: &'a OccupancyGrid, key: (i32, i32)) -> Option<&'a [i16]> {
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
fn point_best<'a>(
    grid: &'a OccupancyGrid,
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
pub(super) fn likelihood_scalar(
    grid: &OccupancyGrid,
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
