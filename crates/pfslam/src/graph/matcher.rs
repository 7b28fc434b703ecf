//! Scan-to-submap matching for the pose graph's edges.
//!
//! A [`PointField`] is a dense window of a likelihood field built from submap points: each
//! cell holds `exp(-d^2 / 2 sigma^2)` of the distance `d` to the nearest point (0..1), plus
//! max-pooled copies (cell `c` of level `k` = the maximum over the `2^k x 2^k` cells from
//! `c`), the upper bounds of Olson's / Cartographer's branch-and-bound correlative search.
//! - [`PointField::search_bnb`]: the best pose over a large x/y/yaw window (loop closures),
//!   exact on the cell grid, optionally excluding a neighbourhood (to measure ambiguity).
//! - [`PointField::search_with_prior`]: a small exhaustive window with a Gaussian prior on the
//!   deviation from a prediction (sequential edges: along a corridor the prediction decides).
//! - [`PointField::refine`]: sub-cell pattern search on the bilinearly interpolated field.

use crate::filter::scanmatch::{LANES, mix_lanes};
use crate::geometry::{Pose2, wrap_angle};
use rayon::prelude::*;

/// Cells per side of a storage tile (a power of two).
const TILE: usize = 32;
const TILE_SHIFT: u32 = TILE.trailing_zeros();

/// A likelihood-field window with max-pooled levels.
///
/// Dense (`w x h` per level), but only the `TILE x TILE` tiles where some level can be
/// non-zero (near a submap point; a loop closure's submap touched ~16 % of its window's
/// tiles on the full-size car) are written: the buffers come from a per-thread pool, and a
/// reused buffer gets only the cells its last use wrote set back to zero.
#[derive(Debug, Clone)]
pub struct PointField {
    origin_x_m: f64,
    origin_y_m: f64,
    resolution_m: f64,
    w: usize,
    h: usize,
    /// `levels[0]` = the field, `levels[k]` = max over `2^k x 2^k` blocks.
    levels: Vec<Buffer>,
}

/// A level's cells (row-major, at least `w * h`; zero outside the written runs) and the runs
/// `(start, len)` written.
#[derive(Debug, Clone, Default)]
struct Buffer {
    cells: Vec<f32>,
    written: Vec<(usize, usize)>,
}

/// Buffers kept per thread for the next fields.
const POOL_BUFFERS: usize = 8;
/// ... each of at most this many cells (64 MB).
const POOL_MAX_CELLS: usize = 1 << 24;

thread_local! {
    static POOL: std::cell::RefCell<Vec<Buffer>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl Buffer {
    /// A buffer of at least `n` zeros: from the pool when it has one (the first large
    /// enough, else the largest, grown), else new.
    fn zeroed(n: usize) -> Buffer {
        let pooled = POOL
            .try_with(|p| {
                let mut p = p.borrow_mut();
                let at = p
                    .iter()
                    .position(|b| b.cells.len() >= n)
                    .or_else(|| (0..p.len()).max_by_key(|&i| p[i].cells.len()))?;
                Some(p.swap_remove(at))
            })
            .ok()
            .flatten();
        match pooled {
            Some(mut b) => {
                for &(start, len) in &b.written {
                    if let Some(run) = b.cells.get_mut(start..start + len) {
                        run.fill(0.0);
                    }
                }
                b.written.clear();
                if b.cells.len() < n {
                    b.cells.resize(n, 0.0);
                }
                b
            }
            None => Buffer {
                cells: vec![0.0; n],
                written: Vec::new(),
            },
        }
    }
}

impl Drop for PointField {
    fn drop(&mut self) {
        let levels = std::mem::take(&mut self.levels);
        // At thread exit the pool is gone: the buffers are freed.
        let _ = POOL.try_with(|p| {
            let mut p = p.borrow_mut();
            for b in levels {
                // A huge window's buffers are not kept.
                if p.len() < POOL_BUFFERS && b.cells.len() <= POOL_MAX_CELLS {
                    p.push(b);
                }
            }
        });
    }
}

/// A search window around a centre pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchWindow {
    /// Half-width in x and y (m).
    pub xy_m: f64,
    /// Half-width in yaw (rad).
    pub yaw_rad: f64,
    /// Yaw step (rad).
    pub yaw_step_rad: f64,
}

/// A Gaussian prior on the deviation from a predicted pose, in units of "points": the
/// objective is `sum(field) - 0.5 * (d_xy^2 / sigma_xy^2 + d_yaw^2 / sigma_yaw^2)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prior {
    /// The predicted pose.
    pub pose: Pose2,
    /// Standard deviation in x and y (m).
    pub sigma_xy_m: f64,
    /// Standard deviation in yaw (rad).
    pub sigma_yaw_rad: f64,
}

impl Prior {
    fn penalty(&self, p: &Pose2) -> f64 {
        let (dx, dy) = (p.x_m - self.pose.x_m, p.y_m - self.pose.y_m);
        let dyaw = wrap_angle(p.yaw_rad - self.pose.yaw_rad);
        0.5 * ((dx * dx + dy * dy) / (self.sigma_xy_m * self.sigma_xy_m)
            + dyaw * dyaw / (self.sigma_yaw_rad * self.sigma_yaw_rad))
    }
}

/// Poses scored in one pass by the refinement (a pattern-search iteration's candidates).
const PASS: usize = 6;

#[derive(Debug, Clone, Copy)]
struct Candidate {
    yaw_index: usize,
    dx: i64,
    dy: i64,
    level: usize,
    score: f64,
}

/// `floor(v)` as `i64` without the libm call (`f64::floor` on baseline x86-64); the same
/// value as `v.floor() as i64` for every finite `v` within +-2^53 (cells always are).
#[inline(always)]
fn floor_to_i64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// The larger of two field values, which are never NaN nor -0: the same value as
/// `f32::max` in one `maxps` (the field's pooling vectorises).
#[inline(always)]
fn max_f32(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `out = max(a0, a1)` elementwise (one pooling step over a run of cells).
#[inline]
fn pool_run(out: &mut [f32], a0: &[f32], a1: &[f32]) {
    for (o, (&p, &q)) in out.iter_mut().zip(a0.iter().zip(a1)) {
        *o = max_f32(p, q);
    }
}

/// `out = max(max(a.0, a.1), max(b.0, b.1))` elementwise (a pooling step of two rows).
#[inline]
fn pool_rows(out: &mut [f32], a: (&[f32], &[f32]), b: (&[f32], &[f32])) {
    let n = out.len();
    let (a0, a1, b0, b1) = (&a.0[..n], &a.1[..n], &b.0[..n], &b.1[..n]);
    for x in 0..n {
        out[x] = max_f32(max_f32(a0[x], a1[x]), max_f32(b0[x], b1[x]));
    }
}

/// The cells of a scan's points at one heading ([`PointField::cells_at`]), as two columns.
/// Stored in `i32`, clamped to `+-CELL_CLAMP`: a clamped cell lies outside any window (at
/// most 2^14 cells a side) for any offset under 2^29 cells, as the cell it stands for
/// (search windows are at most 10 m, 10^3 cells at 0.01 m).
#[derive(Debug, Clone, Default)]
struct PointCells {
    x: Vec<i32>,
    y: Vec<i32>,
}

/// See [`PointCells`].
const CELL_CLAMP: i64 = 1 << 30;

/// The prepared top level of a branch-and-bound search ([`PointField::bnb_start`]).
#[derive(Debug, Clone)]
pub struct BnbStart {
    centre: Pose2,
    yaws: Vec<f64>,
    cells: Vec<PointCells>,
    cands: Vec<Candidate>,
    n: i64,
    n_pts: f64,
}

impl PointField {
    /// Builds the field over `[min, max]` (world, m) from `points` (world, m), with cells of
    /// `resolution_m`, Gaussian `sigma_m` (truncated at 3 sigma) and `levels` pooled levels
    /// above the field.
    pub fn build(
        points: &[[f64; 2]],
        min: [f64; 2],
        max: [f64; 2],
        resolution_m: f64,
        sigma_m: f64,
        levels: usize,
    ) -> PointField {
        let w = (((max[0] - min[0]) / resolution_m).ceil().max(1.0) as usize).min(1 << 14);
        let h = (((max[1] - min[1]) / resolution_m).ceil().max(1.0) as usize).min(1 << 14);
        let sigma_cells = (sigma_m / resolution_m).max(0.25);
        let r = (3.0 * sigma_cells).ceil() as i64;
        // Per kernel row `dj = -r..=r`: the values above 0.01, a run `-a..=a` centred on the
        // point's column (the Gaussian falls with |di|).
        let kernel_rows: Vec<Vec<f32>> = (-r..=r)
            .map(|dj| {
                (-r..=r)
                    .map(|di| {
                        let d2 = (di * di + dj * dj) as f64;
                        (-0.5 * d2 / (sigma_cells * sigma_cells)).exp() as f32
                    })
                    .filter(|&v| v > 0.01)
                    .collect()
            })
            .collect();
        let (wi, hi) = (w as i64, h as i64);
        // The points' cells, each once, by row: a cell's value is the maximum over the
        // kernels stamped on it, which neither order nor repetition changes (a submap's
        // overlapping scans put many points in one cell), and each band of rows below
        // takes a contiguous run of them.
        let span = wi + 2 * r;
        let mut keys: Vec<u64> = points
            .iter()
            .filter_map(|p| {
                let ci = floor_to_i64((p[0] - min[0]) / resolution_m);
                let cj = floor_to_i64((p[1] - min[1]) / resolution_m);
                let outside = ci < -r || cj < -r || ci >= wi + r || cj >= hi + r;
                (!outside).then(|| ((cj + r) * span + (ci + r)) as u64)
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        let cells: Vec<(i64, i64)> = keys
            .iter()
            .map(|&key| {
                let key = key as i64;
                (key % span - r, key / span - r)
            })
            .collect();
        // The tiles a point's kernel touches hold level 0's non-zero cells; a pooled level
        // reaches `2^levels - 1` cells further left and down, so the tiles within that
        // many tiles left and down of them are stored too.
        let (tw, th) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut occupied = vec![false; tw * th];
        for &(ci, cj) in &cells {
            let (x0, x1) = ((ci - r).max(0), (ci + r).min(wi - 1));
            let (y0, y1) = ((cj - r).max(0), (cj + r).min(hi - 1));
            if x0 > x1 || y0 > y1 {
                continue;
            }
            for ty in (y0 >> TILE_SHIFT)..=(y1 >> TILE_SHIFT) {
                for tx in (x0 >> TILE_SHIFT)..=(x1 >> TILE_SHIFT) {
                    occupied[ty as usize * tw + tx as usize] = true;
                }
            }
        }
        let reach = 1usize
            .checked_shl(levels.min(31) as u32)
            .map_or(usize::MAX, |v| v - 1)
            .div_ceil(TILE);
        // Per tile row: the cell columns `x0..x1` of the tiles written, neighbours joined
        // into one run (long runs vectorise; a tile is 32 cells).
        let mut present: Vec<Vec<(usize, usize)>> = vec![Vec::new(); th];
        for (ty, row) in present.iter_mut().enumerate() {
            for tx in 0..tw {
                let (ty1, tx1) = (
                    ty.saturating_add(reach).min(th - 1),
                    tx.saturating_add(reach).min(tw - 1),
                );
                if (ty..=ty1).any(|uy| occupied[uy * tw + tx..=uy * tw + tx1].contains(&true)) {
                    let (x0, x1) = (tx * TILE, ((tx + 1) * TILE).min(w));
                    match row.last_mut() {
                        Some(run) if run.1 == x0 => run.1 = x1,
                        _ => row.push((x0, x1)),
                    }
                }
            }
        }
        // The row runs of the written tiles, the same for every level.
        let mut written = Vec::new();
        for (ty, row) in present.iter().enumerate() {
            for y in ty * TILE..((ty + 1) * TILE).min(h) {
                for &(x0, x1) in row {
                    written.push((y * w + x0, x1 - x0));
                }
            }
        }
        let mut field = Buffer::zeroed(w * h);
        // Bands of tile rows in parallel, each taking the kernel cells of every point that
        // fall in it: a cell's value is the maximum over the same values in any order.
        field.cells[..w * h]
            .par_chunks_mut(w * TILE)
            .enumerate()
            .for_each(|(ty, band)| {
                let y0 = (ty * TILE) as i64;
                let y1 = y0 + (band.len() / w) as i64;
                let first = cells.partition_point(|&(_, cj)| cj + r < y0);
                let end = cells.partition_point(|&(_, cj)| cj - r < y1);
                for &(ci, cj) in &cells[first..end.max(first)] {
                    for (dj, values) in (-r..=r).zip(&kernel_rows) {
                        let y = cj + dj;
                        if y < y0 || y >= y1 || values.is_empty() {
                            continue;
                        }
                        // The row's cells `ci - a ..= ci + a`, cut to the window.
                        let a = (values.len() / 2) as i64;
                        let (x, x_end) = ((ci - a).max(0), (ci + a).min(wi - 1));
                        if x > x_end {
                            continue;
                        }
                        let k = (y - y0) as usize * w + x as usize;
                        let len = (x_end - x + 1) as usize;
                        let from = (x - (ci - a)) as usize;
                        if let (Some(run), Some(vals)) =
                            (band.get_mut(k..k + len), values.get(from..from + len))
                        {
                            for (c, &v) in run.iter_mut().zip(vals) {
                                *c = max_f32(v, *c);
                            }
                        }
                    }
                }
            });
        field.written.clone_from(&written);
        let mut all = vec![field];
        for k in 1..=levels {
            let prev = &all[k - 1].cells[..];
            let s = 1usize << (k - 1);
            let mut next = Buffer::zeroed(w * h);
            next.cells[..w * h]
                .par_chunks_mut(w * TILE)
                .enumerate()
                .for_each(|(ty, band)| {
                    for (yy, out) in band.chunks_exact_mut(w).enumerate() {
                        let y = ty * TILE + yy;
                        let a = &prev[y * w..(y + 1) * w];
                        // Row `y + s` (none above the window: the maximum over the rest).
                        let b = prev.get((y + s) * w..(y + s + 1) * w).filter(|_| y + s < h);
                        for &(x0, x1) in &present[ty] {
                            // Cells whose right neighbour `x + s` lies in the window
                            // (none when the run lies in the last `s` columns).
                            let xm = x1.min(w.saturating_sub(s)).max(x0);
                            match b {
                                Some(b) => {
                                    if xm > x0 {
                                        pool_rows(
                                            &mut out[x0..xm],
                                            (&a[x0..xm], &a[x0 + s..xm + s]),
                                            (&b[x0..xm], &b[x0 + s..xm + s]),
                                        );
                                    }
                                    pool_run(&mut out[xm..x1], &a[xm..x1], &b[xm..x1]);
                                }
                                None => {
                                    if xm > x0 {
                                        pool_run(&mut out[x0..xm], &a[x0..xm], &a[x0 + s..xm + s]);
                                    }
                                    out[xm..x1].copy_from_slice(&a[xm..x1]);
                                }
                            }
                        }
                    }
                });
            next.written.clone_from(&written);
            all.push(next);
        }
        PointField {
            origin_x_m: min[0],
            origin_y_m: min[1],
            resolution_m,
            w,
            h,
            levels: all,
        }
    }

    /// Number of pooled levels above the field.
    pub fn pooled_levels(&self) -> usize {
        self.levels.len() - 1
    }

    #[inline]
    fn at(&self, level: usize, i: i64, j: i64) -> f32 {
        if i < 0 || j < 0 || i >= self.w as i64 || j >= self.h as i64 {
            return 0.0;
        }
        let k = j as usize * self.w + i as usize;
        self.levels[level].cells.get(k).copied().unwrap_or(0.0)
    }

    /// Bilinear interpolation between cell centres (0 outside).
    #[inline]
    fn bilinear(&self, x_m: f64, y_m: f64) -> f64 {
        let u = (x_m - self.origin_x_m) / self.resolution_m - 0.5;
        let v = (y_m - self.origin_y_m) / self.resolution_m - 0.5;
        self.bilinear_lane(u, v)
    }

    /// Mean interpolated field value (0..1) of `points_body` seen from `pose`.
    pub fn score(&self, points_body: &[[f64; 2]], pose: &Pose2) -> f64 {
        let (s, c) = pose.yaw_rad.sin_cos();
        self.score_rotated(points_body, pose, s, c)
    }

    /// [`Self::score`] with `(s, c)` = `pose.yaw_rad.sin_cos()` given.
    fn score_rotated(&self, points_body: &[[f64; 2]], pose: &Pose2, s: f64, c: f64) -> f64 {
        let [score] = self.scores_rotated(points_body, [*pose], [(s, c)]);
        score
    }

    /// [`Self::score_rotated`] of `K` poses (`sin_cos[k]` of `poses[k]`'s yaw) in one pass
    /// over the points. Each pose has its own accumulator and adds its own values in its
    /// own order, so each score is the bits of its [`Self::score_rotated`]; the independent
    /// chains of additions can overlap.
    fn scores_rotated<const K: usize>(
        &self,
        points_body: &[[f64; 2]],
        poses: [Pose2; K],
        sin_cos: [(f64, f64); K],
    ) -> [f64; K] {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked above).
            return unsafe { self.scores_rotated_avx2(points_body, poses, sin_cos) };
        }
        self.scores_rotated_with(points_body, poses, sin_cos, |u, v| {
            self.bilinear_lanes(u, v)
        })
    }

    /// [`Self::scores_rotated`] with the four lanes' interpolation in AVX2
    /// ([`Self::bilinear_lanes_avx2`]); the same bits.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn scores_rotated_avx2<const K: usize>(
        &self,
        points_body: &[[f64; 2]],
        poses: [Pose2; K],
        sin_cos: [(f64, f64); K],
    ) -> [f64; K] {
        // The closure inherits this function's AVX2.
        self.scores_rotated_with(points_body, poses, sin_cos, |u, v| {
            self.bilinear_lanes_avx2(u, v)
        })
    }

    /// The body of [`Self::scores_rotated`], with `lanes` the interpolation of four points.
    #[inline(always)]
    fn scores_rotated_with<const K: usize>(
        &self,
        points_body: &[[f64; 2]],
        poses: [Pose2; K],
        sin_cos: [(f64, f64); K],
        lanes: impl Fn(&[f64; LANES], &[f64; LANES]) -> [f64; LANES],
    ) -> [f64; K] {
        if points_body.is_empty() {
            return [0.0; K];
        }
        // The same left-to-right fold as `Iterator::sum` (from -0.0), four points at a time:
        // per lane the operations of `bilinear`, so the same bits, in vector registers.
        let mut sums = [-0.0; K];
        let mut values = [[0.0; LANES]; K];
        let mut chunks = points_body.chunks_exact(LANES);
        for quad in &mut chunks {
            for k in 0..K {
                let (pose, (s, c)) = (&poses[k], sin_cos[k]);
                let mut u = [0.0; LANES];
                let mut v = [0.0; LANES];
                for (l, p) in quad.iter().enumerate() {
                    let x = pose.x_m + c * p[0] - s * p[1];
                    let y = pose.y_m + s * p[0] + c * p[1];
                    u[l] = (x - self.origin_x_m) / self.resolution_m - 0.5;
                    v[l] = (y - self.origin_y_m) / self.resolution_m - 0.5;
                }
                values[k] = lanes(&u, &v);
            }
            // Apart from the loop above: unrolled, the accumulators stay in registers.
            for (sum, values) in sums.iter_mut().zip(&values) {
                for value in values {
                    *sum += value;
                }
            }
        }
        for p in chunks.remainder() {
            for k in 0..K {
                let (pose, (s, c)) = (&poses[k], sin_cos[k]);
                sums[k] += self.bilinear(
                    pose.x_m + c * p[0] - s * p[1],
                    pose.y_m + s * p[0] + c * p[1],
                );
            }
        }
        sums.map(|sum| sum / points_body.len() as f64)
    }

    /// [`Self::scores_rotated`] of any number of poses into `out`, up to [`PASS`] per pass (a
    /// pattern-search iteration's candidates).
    fn scores_batched(
        &self,
        points_body: &[[f64; 2]],
        poses: &[Pose2],
        sin_cos: &[(f64, f64)],
        out: &mut [f64],
    ) {
        let chunks = poses.chunks(PASS).zip(sin_cos.chunks(PASS));
        for ((p, sc), o) in chunks.zip(out.chunks_mut(PASS)) {
            crate::filter::scanmatch::by_count!(p.len().min(sc.len()).min(o.len()), K => {
                let scores = self.scores_rotated::<K>(
                    points_body,
                    std::array::from_fn(|i| p[i]),
                    std::array::from_fn(|i| sc[i]),
                );
                o.copy_from_slice(&scores);
            });
        }
    }

    /// [`Self::bilinear`] of `LANES` points given as cell coordinates minus one half (`u`,
    /// `v` of `bilinear`), lane-wise so that the arithmetic vectorises.
    #[inline(always)]
    fn bilinear_lanes(&self, u: &[f64; LANES], v: &[f64; LANES]) -> [f64; LANES] {
        let mut au = [0.0; LANES];
        let mut av = [0.0; LANES];
        let mut f = [[0.0; 4]; LANES];
        for k in 0..LANES {
            let (i, j) = (floor_to_i64(u[k]), floor_to_i64(v[k]));
            au[k] = u[k] - i as f64;
            av[k] = v[k] - j as f64;
            f[k] = self.corners(i, j).map(f64::from);
        }
        mix_lanes(&f, &au, &av)
    }

    /// [`Self::bilinear`] from cell coordinates minus one half (`u`, `v`); one lane of
    /// [`Self::bilinear_lanes`].
    #[inline(always)]
    fn bilinear_lane(&self, u: f64, v: f64) -> f64 {
        // `f64::floor` is a libm call on baseline x86-64; the integer floor is the same value.
        let (i, j) = (floor_to_i64(u), floor_to_i64(v));
        let (au, av) = (u - i as f64, v - j as f64);
        let [f00, f10, f01, f11] = self.corners(i, j).map(f64::from);
        let bottom = f00 * (1.0 - au) + f10 * au;
        let top = f01 * (1.0 - au) + f11 * au;
        bottom * (1.0 - av) + top * av
    }

    /// [`Self::bilinear_lanes`] in AVX2: the floors and fractions in vector registers, the
    /// two corner pairs of each point gathered (one 8-byte load per row) where its 2x2 block
    /// lies inside the field, the mix lane by lane in the scalar order (no fused
    /// multiply-add): the same bits. Points near or beyond the edges take
    /// [`Self::bilinear_lane`].
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    fn bilinear_lanes_avx2(&self, u: &[f64; LANES], v: &[f64; LANES]) -> [f64; LANES] {
        use std::arch::x86_64::*;
        let lv = &self.levels[0].cells[..];
        // SAFETY: unaligned loads of four f64 from arrays of four.
        let (uv, vv) = unsafe { (_mm256_loadu_pd(u.as_ptr()), _mm256_loadu_pd(v.as_ptr())) };
        let (fu, fv) = (_mm256_floor_pd(uv), _mm256_floor_pd(vv));
        // `u - i as f64` with `i` the floor: the floor itself for the lanes inside (below).
        let (au, av) = (_mm256_sub_pd(uv, fu), _mm256_sub_pd(vv, fv));
        // The floors in i32: exact inside the i32 range; beyond it, and for NaN, the
        // conversion gives i32::MIN, which the test below puts outside.
        let (i, j) = (_mm256_cvttpd_epi32(fu), _mm256_cvttpd_epi32(fv));
        // `i >= 0 && j >= 0 && i + 1 < w && j + 1 < h` (w, h at most 2^14).
        let (w, h) = (self.w as i32, self.h as i32);
        let minus_one = _mm_set1_epi32(-1);
        let inside = _mm_and_si128(
            _mm_and_si128(_mm_cmpgt_epi32(i, minus_one), _mm_cmpgt_epi32(j, minus_one)),
            _mm_and_si128(
                _mm_cmpgt_epi32(_mm_set1_epi32(w - 1), i),
                _mm_cmpgt_epi32(_mm_set1_epi32(h - 1), j),
            ),
        );
        // (A level shorter than `w * h` never happens; it would take the scalar way.)
        let inside_bits = match lv.len() >= self.w * self.h {
            true => _mm_movemask_ps(_mm_castsi128_ps(inside)),
            false => 0,
        };
        let mut out = [0.0f64; LANES];
        if inside_bits != 0 {
            let k = _mm_add_epi32(_mm_mullo_epi32(j, _mm_set1_epi32(w)), i);
            let mask = _mm256_cvtepi32_epi64(inside);
            // SAFETY: only lanes inside are read: `k + 1` and `k + w + 1` are cells of the
            // 2x2 block, below `w * h <= lv.len()`.
            let (row0, row1) = unsafe {
                (
                    _mm256_mask_i32gather_epi64::<4>(
                        _mm256_setzero_si256(),
                        lv.as_ptr().cast(),
                        k,
                        mask,
                    ),
                    _mm256_mask_i32gather_epi64::<4>(
                        _mm256_setzero_si256(),
                        lv.as_ptr().cast(),
                        _mm_add_epi32(k, _mm_set1_epi32(w)),
                        mask,
                    ),
                )
            };
            // [a0 b0 a1 b1 a2 b2 a3 b3] -> [a0 a1 a2 a3 | b0 b1 b2 b3], then to f64.
            let pick = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
            let split = |r| {
                let r = _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(r, pick));
                (
                    _mm256_cvtps_pd(_mm256_castps256_ps128(r)),
                    _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(r)),
                )
            };
            let ((f00, f10), (f01, f11)) = (split(row0), split(row1));
            let one = _mm256_set1_pd(1.0);
            let (nu, nv) = (_mm256_sub_pd(one, au), _mm256_sub_pd(one, av));
            let bottom = _mm256_add_pd(_mm256_mul_pd(f00, nu), _mm256_mul_pd(f10, au));
            let top = _mm256_add_pd(_mm256_mul_pd(f01, nu), _mm256_mul_pd(f11, au));
            let mix = _mm256_add_pd(_mm256_mul_pd(bottom, nv), _mm256_mul_pd(top, av));
            // SAFETY: a store into a local array of four f64.
            unsafe { _mm256_storeu_pd(out.as_mut_ptr(), mix) };
        }
        if inside_bits != 0b1111 {
            for l in 0..LANES {
                if inside_bits >> l & 1 == 0 {
                    out[l] = self.bilinear_lane(u[l], v[l]);
                }
            }
        }
        out
    }

    /// Level-0 values at `(i, j)`, `(i+1, j)`, `(i, j+1)`, `(i+1, j+1)` (0 outside): one
    /// bounds check when the 2x2 block lies inside (nearly always).
    #[inline(always)]
    fn corners(&self, i: i64, j: i64) -> [f32; 4] {
        let (w, h) = (self.w as i64, self.h as i64);
        let block = (i >= 0 && j >= 0 && i + 1 < w && j + 1 < h)
            .then(|| {
                let k = (j * w + i) as usize;
                let lv = &self.levels[0].cells;
                let row0 = lv.get(k..k + 2)?;
                let row1 = lv.get(k + w as usize..k + w as usize + 2)?;
                Some([row0[0], row0[1], row1[0], row1[1]])
            })
            .flatten();
        block.unwrap_or_else(|| {
            [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(di, dj)| self.at(0, i + di, j + dj))
        })
    }

    /// Curvature of the match objective `n * score` at `pose`: minus its Hessian with
    /// respect to world (x, y, yaw), by central differences with steps `h_xy_m`, `h_yaw_rad`.
    /// Large along directions the scan pins down, near zero along a corridor's axis.
    pub fn curvature(
        &self,
        points_body: &[[f64; 2]],
        pose: &Pose2,
        h_xy_m: f64,
        h_yaw_rad: f64,
    ) -> nalgebra::Matrix3<f64> {
        let n = points_body.len() as f64;
        let h = [h_xy_m, h_xy_m, h_yaw_rad];
        // The 19 displacements of the central differences, scored in parallel (each score
        // is computed alone, so the same bits as one after the other).
        let mut steps: Vec<[f64; 3]> = vec![[0.0; 3]];
        for i in 0..3 {
            for si in [1.0, -1.0] {
                let mut d = [0.0; 3];
                d[i] = si * h[i];
                steps.push(d);
            }
            for j in 0..i {
                for (si, sj) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                    let mut d = [0.0; 3];
                    d[i] = si * h[i];
                    d[j] = sj * h[j];
                    steps.push(d);
                }
            }
        }
        let values: Vec<f64> = steps
            .par_iter()
            .map(|d| {
                let p = Pose2::new(pose.x_m + d[0], pose.y_m + d[1], pose.yaw_rad + d[2]);
                n * self.score(points_body, &p)
            })
            .collect();
        let mut next = values[1..].iter();
        let mut take = || next.next().copied().unwrap_or(f64::NAN);
        let f0 = values[0];
        let mut m = nalgebra::Matrix3::zeros();
        for i in 0..3 {
            let fp = take();
            let fm = take();
            m[(i, i)] = -(fp - 2.0 * f0 + fm) / (h[i] * h[i]);
            for j in 0..i {
                let (pp, pm, mp, mm) = (take(), take(), take(), take());
                let v = -(pp - pm - mp + mm) / (4.0 * h[i] * h[j]);
                m[(i, j)] = v;
                m[(j, i)] = v;
            }
        }
        m
    }

    /// Cells of the points seen from `centre`'s position with heading `yaw`.
    fn cells_at(&self, points_body: &[[f64; 2]], centre: &Pose2, yaw: f64) -> PointCells {
        let (s, c) = yaw.sin_cos();
        let clamp = |v: i64| v.clamp(-CELL_CLAMP, CELL_CLAMP) as i32;
        let (x, y) = points_body
            .iter()
            .map(|p| {
                let x = centre.x_m + c * p[0] - s * p[1];
                let y = centre.y_m + s * p[0] + c * p[1];
                (
                    clamp(floor_to_i64((x - self.origin_x_m) / self.resolution_m)),
                    clamp(floor_to_i64((y - self.origin_y_m) / self.resolution_m)),
                )
            })
            .unzip();
        PointCells { x, y }
    }

    fn window_yaws(centre: &Pose2, win: &SearchWindow) -> Vec<f64> {
        let m = (win.yaw_rad / win.yaw_step_rad.max(1e-6)).ceil() as i64;
        (-m..=m)
            .map(|k| centre.yaw_rad + k as f64 * win.yaw_step_rad)
            .collect()
    }

    /// Sum of level `level` over `cells` shifted by `(dx, dy)` (0 outside).
    ///
    /// Exact in any order, so the point-order sum's bits: every field value is 0 or an
    /// `f32` above 0.01 ([`Self::build`] keeps only such kernel values; the pooled levels
    /// take maxima of them), that is, at most 1 and a multiple of 2^-30. A sum of up to
    /// 2^22 of them is a multiple of 2^-30 below 2^22, which `f64` holds exactly, and so
    /// is every partial sum. With AVX2, eight points at a time (gathered).
    fn cell_sum(&self, cells: &PointCells, level: usize, dx: i64, dy: i64) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if cells.x.len() <= 1 << 22 && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked above).
            return unsafe { self.cell_sum_avx2(cells, level, dx, dy) };
        }
        self.cell_sum_scalar((&cells.x, &cells.y), level, dx, dy)
    }

    /// [`Self::cell_sum`] a point at a time, in point order, over the columns `(x, y)`.
    fn cell_sum_scalar(&self, (xs, ys): (&[i32], &[i32]), level: usize, dx: i64, dy: i64) -> f64 {
        let lv = &self.levels[level].cells[..];
        let (w, h) = (self.w as u64, self.h as u64);
        // A pooled cell `c` covers `c ..= c + span`: one left of or below the window still
        // covers window cells up to `span` away, whose maximum cell 0 of that row or column
        // bounds (its block holds them). Level 0: `span` = 0, the plain lookup.
        let span = (1i64 << level) - 1;
        let (ws, hs) = (w + span as u64, h + span as u64);
        xs.iter()
            .zip(ys)
            .map(|(&i, &j)| {
                let (x, y) = (i64::from(i) + dx, i64::from(j) + dy);
                // One unsigned comparison per axis also rejects what lies beyond the reach.
                if ((x + span) as u64) < ws && ((y + span) as u64) < hs {
                    let (x, y) = (x.max(0) as u64, y.max(0) as u64);
                    f64::from(lv.get((y * w + x) as usize).copied().unwrap_or(0.0))
                } else {
                    0.0
                }
            })
            .sum()
    }

    /// [`Self::cell_sum`] eight points at a time: the offsets, the window test and the
    /// index in `i32` lanes, the values gathered where inside (the others not read), summed
    /// in two `f64` accumulators; the last points as [`Self::cell_sum_scalar`].
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn cell_sum_avx2(&self, cells: &PointCells, level: usize, dx: i64, dy: i64) -> f64 {
        use std::arch::x86_64::*;
        let lv = &self.levels[level].cells[..];
        let span = (1i64 << level) - 1;
        let n = cells.x.len().min(cells.y.len());
        // Offsets beyond any window (2^14 cells) and clamped cells (2^30) stay apart in i32:
        // such offsets go the scalar way.
        let small = |d: i64| d.abs() <= 1 << 20;
        // (No points: the scalar sum's -0.0.)
        if n == 0 || !(small(dx) && small(dy) && span < 1 << 20 && lv.len() >= self.w * self.h) {
            return self.cell_sum_scalar((&cells.x, &cells.y), level, dx, dy);
        }
        let (xs, ys) = (
            cells.x[..n].as_chunks::<8>().0,
            cells.y[..n].as_chunks::<8>().0,
        );
        let shift_x = _mm256_set1_epi32((dx + span) as i32);
        let shift_y = _mm256_set1_epi32((dy + span) as i32);
        let span_v = _mm256_set1_epi32(span as i32);
        // `ws`, `hs` of the scalar test: `0 <= x + span < w + span`, likewise y.
        let ws = _mm256_set1_epi32((self.w as i64 + span) as i32);
        let hs = _mm256_set1_epi32((self.h as i64 + span) as i32);
        let w = _mm256_set1_epi32(self.w as i32);
        let minus_one = _mm256_set1_epi32(-1);
        let zero = _mm256_setzero_si256();
        let (mut lo, mut hi) = (_mm256_setzero_pd(), _mm256_setzero_pd());
        for (x8, y8) in xs.iter().zip(ys) {
            // SAFETY: unaligned loads of eight i32 from arrays of eight.
            let (x, y) = unsafe {
                (
                    _mm256_loadu_si256(x8.as_ptr().cast()),
                    _mm256_loadu_si256(y8.as_ptr().cast()),
                )
            };
            let (xs_, ys_) = (_mm256_add_epi32(x, shift_x), _mm256_add_epi32(y, shift_y));
            let inside = _mm256_and_si256(
                _mm256_and_si256(
                    _mm256_cmpgt_epi32(xs_, minus_one),
                    _mm256_cmpgt_epi32(ws, xs_),
                ),
                _mm256_and_si256(
                    _mm256_cmpgt_epi32(ys_, minus_one),
                    _mm256_cmpgt_epi32(hs, ys_),
                ),
            );
            // `x.max(0)`, `y.max(0)` of `x = xs_ - span`; then `y * w + x` (< w * h).
            let x = _mm256_max_epi32(_mm256_sub_epi32(xs_, span_v), zero);
            let y = _mm256_max_epi32(_mm256_sub_epi32(ys_, span_v), zero);
            let index = _mm256_add_epi32(_mm256_mullo_epi32(y, w), x);
            // SAFETY: only lanes inside the window are read, at `y * w + x < w * h <=
            // lv.len()`; the others keep 0.
            let v = unsafe {
                _mm256_mask_i32gather_ps::<4>(
                    _mm256_setzero_ps(),
                    lv.as_ptr(),
                    index,
                    _mm256_castsi256_ps(inside),
                )
            };
            lo = _mm256_add_pd(lo, _mm256_cvtps_pd(_mm256_castps256_ps128(v)));
            hi = _mm256_add_pd(hi, _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v)));
        }
        let mut lanes = [0.0f64; 4];
        // SAFETY: a store into a local array of four f64.
        unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), _mm256_add_pd(lo, hi)) };
        let done = xs.len() * 8;
        let rest = (&cells.x[done..n], &cells.y[done..n]);
        lanes.iter().sum::<f64>() + self.cell_sum_scalar(rest, level, dx, dy)
    }

    /// Branch-and-bound search of the best pose within `win` around `centre` whose mean
    /// cell score exceeds `min_score`; poses within `exclude.1` (m) and `exclude.2` (rad) of
    /// `exclude.0` are not considered (whole branches at once when they lie inside). Returns the pose (on the cell grid) and its mean
    /// cell score.
    pub fn search_bnb(
        &self,
        points_body: &[[f64; 2]],
        centre: &Pose2,
        win: &SearchWindow,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
    ) -> Option<(Pose2, f64)> {
        let start = self.bnb_start(points_body, centre, win)?;
        self.search_bnb_from(&start, min_score, exclude)
    }

    /// The top level of [`Self::search_bnb`] (yaws, cells of the points per yaw, scored
    /// top-level candidates), to share between searches of one scan in one window (the best
    /// pose, then the ambiguity test). Scored in parallel over yaws, collected in yaw order:
    /// the same candidates whatever the thread count. `None` without points.
    pub fn bnb_start(
        &self,
        points_body: &[[f64; 2]],
        centre: &Pose2,
        win: &SearchWindow,
    ) -> Option<BnbStart> {
        if points_body.is_empty() {
            return None;
        }
        let n_pts = points_body.len() as f64;
        let yaws = Self::window_yaws(centre, win);
        let n = (win.xy_m / self.resolution_m).ceil() as i64;
        let top = self.pooled_levels();
        let step = 1i64 << top;
        type YawCells = (PointCells, Vec<Candidate>);
        let per_yaw: Vec<YawCells> = yaws
            .par_iter()
            .enumerate()
            .map(|(a, &yaw)| {
                let c = self.cells_at(points_body, centre, yaw);
                let mut cands = Vec::new();
                let mut dy = -n;
                while dy <= n {
                    let mut dx = -n;
                    while dx <= n {
                        cands.push(Candidate {
                            yaw_index: a,
                            dx,
                            dy,
                            level: top,
                            score: self.cell_sum(&c, top, dx, dy) / n_pts,
                        });
                        dx += step;
                    }
                    dy += step;
                }
                (c, cands)
            })
            .collect();
        let mut cells = Vec::with_capacity(per_yaw.len());
        let mut cands = Vec::new();
        for (c, k) in per_yaw {
            cells.push(c);
            cands.extend(k);
        }
        // Sorted as `branch` sorts them (stable, best first): each search's own sort then
        // finds one run, the same order.
        cands.sort_by(|a, b| b.score.total_cmp(&a.score));
        Some(BnbStart {
            centre: *centre,
            yaws,
            cells,
            cands,
            n,
            n_pts,
        })
    }

    /// Whether `pose` (a pose of the search's cell grid, as [`Self::search_bnb_from`]
    /// returns) lies on the edge of `start`'s window: its x or y offset the window's
    /// half-width in cells, or its yaw the first or last of the window's (a window without
    /// any offset in a dimension has no edge there).
    pub fn on_window_edge(&self, start: &BnbStart, pose: &Pose2) -> bool {
        let c = &start.centre;
        let cells = |d: f64| (d / self.resolution_m).round().abs() as i64;
        let n = start.n;
        let xy = n > 0 && (cells(pose.x_m - c.x_m) >= n || cells(pose.y_m - c.y_m) >= n);
        let last = start.yaws.len().saturating_sub(1);
        let yaw = last > 0
            && start
                .yaws
                .iter()
                .position(|&y| y.to_bits() == pose.yaw_rad.to_bits())
                .is_some_and(|a| a == 0 || a == last);
        xy || yaw
    }

    /// [`Self::search_bnb`] from a prepared top level.
    pub fn search_bnb_from(
        &self,
        start: &BnbStart,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
    ) -> Option<(Pose2, f64)> {
        self.bnb_from(start, min_score, exclude, false)
    }

    /// Whether [`Self::search_bnb_from`] would find a pose (its `is_some()`): the search
    /// stops at the first pose above `min_score` instead of looking for the best (the
    /// ambiguity test needs no more).
    pub fn any_bnb_from(
        &self,
        start: &BnbStart,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
    ) -> bool {
        self.bnb_from(start, min_score, exclude, true).is_some()
    }

    fn bnb_from(
        &self,
        start: &BnbStart,
        min_score: f64,
        exclude: Option<(Pose2, f64, f64)>,
        first_only: bool,
    ) -> Option<(Pose2, f64)> {
        let BnbStart {
            centre,
            yaws,
            cells,
            cands,
            n,
            n_pts,
        } = start;
        let mut best: Option<Candidate> = None;
        let mut best_score = min_score;
        let pose_of = |c: &Candidate| {
            Pose2::new(
                centre.x_m + c.dx as f64 * self.resolution_m,
                centre.y_m + c.dy as f64 * self.resolution_m,
                yaws[c.yaw_index],
            )
        };
        self.branch(
            cands.clone(),
            cells,
            (*n, *n_pts, first_only),
            &mut best,
            &mut best_score,
            // A node is excluded when every offset it covers is: its four corners are.
            &|c: &Candidate| {
                exclude.is_some_and(|(p, r, ryaw)| {
                    let span = (1i64 << c.level) - 1;
                    let q = pose_of(c);
                    wrap_angle(q.yaw_rad - p.yaw_rad).abs() < ryaw
                        && [(0, 0), (span, 0), (0, span), (span, span)]
                            .iter()
                            .all(|&(ox, oy)| {
                                let x = q.x_m + ox as f64 * self.resolution_m;
                                let y = q.y_m + oy as f64 * self.resolution_m;
                                (x - p.x_m).hypot(y - p.y_m) < r
                            })
                })
            },
        );
        best.map(|c| (pose_of(&c), c.score))
    }

    /// Depth first over `cands` (best bound first); `(n, n_pts, first_only)`: the window's
    /// half-width in cells, the point count, and whether to stop at the first leaf above
    /// `best_score`. Returns true when it stopped there.
    fn branch(
        &self,
        mut cands: Vec<Candidate>,
        cells: &[PointCells],
        (n, n_pts, first_only): (i64, f64, bool),
        best: &mut Option<Candidate>,
        best_score: &mut f64,
        excluded: &dyn Fn(&Candidate) -> bool,
    ) -> bool {
        cands.sort_by(|a, b| b.score.total_cmp(&a.score));
        for c in cands {
            if c.score <= *best_score {
                break;
            }
            if excluded(&c) {
                continue;
            }
            if c.level == 0 {
                *best_score = c.score;
                *best = Some(c);
                if first_only {
                    return true;
                }
                continue;
            }
            let half = 1i64 << (c.level - 1);
            let mut children = Vec::with_capacity(4);
            for (ox, oy) in [(0, 0), (half, 0), (0, half), (half, half)] {
                let (dx, dy) = (c.dx + ox, c.dy + oy);
                if dx > n || dy > n {
                    continue;
                }
                children.push(Candidate {
                    yaw_index: c.yaw_index,
                    dx,
                    dy,
                    level: c.level - 1,
                    score: self.cell_sum(&cells[c.yaw_index], c.level - 1, dx, dy) / n_pts,
                });
            }
            if self.branch(
                children,
                cells,
                (n, n_pts, first_only),
                best,
                best_score,
                excluded,
            ) {
                return true;
            }
        }
        false
    }

    /// Exhaustive search over `win` around `prior.pose` maximising the cell scores minus
    /// the prior's penalty; returns the best pose on the cell grid.
    pub fn search_with_prior(
        &self,
        points_body: &[[f64; 2]],
        prior: &Prior,
        win: &SearchWindow,
    ) -> Pose2 {
        let centre = prior.pose;
        let yaws = Self::window_yaws(&centre, win);
        let n = (win.xy_m / self.resolution_m).ceil() as i64;
        // Each yaw's first best in (dy, dx) order, in parallel; then the first strictly
        // better over yaws in order: the sequential scan's answer for any thread count.
        let per_yaw: Vec<(f64, Pose2)> = yaws
            .par_iter()
            .map(|&yaw| {
                let c = self.cells_at(points_body, &centre, yaw);
                let mut best = (f64::NEG_INFINITY, centre);
                for dy in -n..=n {
                    for dx in -n..=n {
                        let pose = Pose2::new(
                            centre.x_m + dx as f64 * self.resolution_m,
                            centre.y_m + dy as f64 * self.resolution_m,
                            yaw,
                        );
                        let obj = self.cell_sum(&c, 0, dx, dy) - prior.penalty(&pose);
                        if obj > best.0 {
                            best = (obj, pose);
                        }
                    }
                }
                best
            })
            .collect();
        let mut best = (f64::NEG_INFINITY, centre);
        for b in per_yaw {
            if b.0 > best.0 {
                best = b;
            }
        }
        best.1
    }

    /// Sub-cell pattern search from `start` on the interpolated field (step halving from half
    /// a cell and `yaw_step_rad / 2`, `levels` times), with an optional prior. Returns the
    /// pose and its mean interpolated score.
    pub fn refine(
        &self,
        points_body: &[[f64; 2]],
        start: &Pose2,
        yaw_step_rad: f64,
        levels: u32,
        prior: Option<&Prior>,
    ) -> (Pose2, f64) {
        let n_pts = points_body.len().max(1) as f64;
        // Most steps of the pattern search keep the yaw: its sine and cosine once per yaw.
        let mut kept_yaw = (f64::NAN.to_bits(), 0.0, 0.0);
        let mut sin_cos = |yaw: f64, keep: bool| {
            if kept_yaw.0 == yaw.to_bits() {
                return (kept_yaw.1, kept_yaw.2);
            }
            let (s, c) = yaw.sin_cos();
            if keep {
                kept_yaw = (yaw.to_bits(), s, c);
            }
            (s, c)
        };
        let value = |p: &Pose2, s: f64| (s * n_pts - prior.map_or(0.0, |q| q.penalty(p)), s);
        let (s, c) = sin_cos(start.yaw_rad, true);
        let first = value(start, self.score_rotated(points_body, start, s, c));
        let ([x_m, y_m, yaw_rad], (_, score)) = crate::filter::scanmatch::pattern_search(
            [start.x_m, start.y_m, start.yaw_rad],
            first,
            0.5 * self.resolution_m,
            0.5 * yaw_step_rad,
            levels,
            100,
            // An iteration's candidates scored in one pass.
            |cands, values| {
                for (cands, values) in cands.chunks(PASS).zip(values.chunks_mut(PASS)) {
                    let n = cands.len();
                    let mut poses = [Pose2::default(); PASS];
                    let mut sc = [(0.0, 0.0); PASS];
                    for ((p, sc), &(at, keep)) in poses.iter_mut().zip(&mut sc).zip(cands) {
                        *p = Pose2::new(at[0], at[1], at[2]);
                        *sc = sin_cos(p.yaw_rad, keep);
                    }
                    let mut scores = [0.0; PASS];
                    self.scores_batched(points_body, &poses[..n], &sc[..n], &mut scores[..n]);
                    for ((v, p), s) in values.iter_mut().zip(&poses).zip(scores) {
                        *v = value(p, s);
                    }
                }
            },
        );
        (Pose2::new(x_m, y_m, yaw_rad), score)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room_points() -> Vec<[f64; 2]> {
        // An L-shaped room with a pillar: walls every 2 cm.
        let mut pts = Vec::new();
        for k in 0..=400 {
            let t = f64::from(k) * 0.02;
            pts.push([t - 4.0, -3.0]);
            pts.push([t - 4.0, 3.0]);
            if t <= 6.0 {
                pts.push([-4.0, t - 3.0]);
                pts.push([4.0, t - 3.0]);
            }
        }
        for k in 0..60 {
            let a = f64::from(k) * std::f64::consts::TAU / 60.0;
            pts.push([1.5 + 0.3 * a.cos(), 1.0 + 0.3 * a.sin()]);
        }
        pts
    }

    /// Every 7th of `pts` in the body frame of a robot at `truth`.
    fn seen_from(pts: &[[f64; 2]], truth: &Pose2) -> Vec<[f64; 2]> {
        pts.iter()
            .step_by(7)
            .map(|p| {
                let q = truth.inverse().transform_point(p[0], p[1]);
                [q.0, q.1]
            })
            .collect()
    }

    /// The interpolated score written plainly (libm floor, bounds-checked lookups).
    fn score_plain(f: &PointField, points_body: &[[f64; 2]], pose: &Pose2) -> f64 {
        let (s, c) = pose.yaw_rad.sin_cos();
        let sum: f64 = points_body
            .iter()
            .map(|p| {
                let x = pose.x_m + c * p[0] - s * p[1];
                let y = pose.y_m + s * p[0] + c * p[1];
                let u = (x - f.origin_x_m) / f.resolution_m - 0.5;
                let v = (y - f.origin_y_m) / f.resolution_m - 0.5;
                let (fu, fv) = (u.floor(), v.floor());
                let (au, av) = (u - fu, v - fv);
                let (i, j) = (fu as i64, fv as i64);
                let g = |di, dj| f64::from(f.at(0, i + di, j + dj));
                let bottom = g(0, 0) * (1.0 - au) + g(1, 0) * au;
                let top = g(0, 1) * (1.0 - au) + g(1, 1) * au;
                bottom * (1.0 - av) + top * av
            })
            .sum();
        sum / points_body.len() as f64
    }

    #[test]
    fn fast_score_and_shared_bnb_start_give_the_plain_bits() {
        let pts = room_points();
        let f = PointField::build(&pts, [-6.0, -5.0], [6.0, 5.0], 0.05, 0.08, 3);
        let body: Vec<[f64; 2]> = pts.iter().step_by(5).copied().collect();
        for k in 0..200 {
            let t = f64::from(k);
            // Poses that push points across the field's edges (outside cells count 0).
            let pose = Pose2::new((t * 0.37).sin() * 3.0, (t * 0.23).cos() * 2.5, t * 0.05);
            // Every remainder of the four-point batches.
            let part = &body[..body.len() - k as usize % 4];
            let (fast, plain) = (f.score(part, &pose), score_plain(&f, part, &pose));
            assert_eq!(fast.to_bits(), plain.to_bits(), "{pose:?}");
        }
        for v in [
            -3.5, -3.0, -0.0, 0.0, 1e-300, -1e-300, 2.999_999, 1e12, -1e12,
        ] {
            assert_eq!(floor_to_i64(v), v.floor() as i64, "{v}");
        }
        let win = SearchWindow {
            xy_m: 0.4,
            yaw_rad: 0.1,
            yaw_step_rad: 0.02,
        };
        let centre = Pose2::new(0.1, -0.1, 0.03);
        let start = f.bnb_start(&body, &centre, &win).unwrap();
        for (min, ex) in [(0.0, None), (0.3, Some((centre, 0.2, 0.05)))] {
            let a = f.search_bnb(&body, &centre, &win, min, ex);
            let b = f.search_bnb_from(&start, min, ex);
            assert_eq!(a, b);
            assert!(a.is_some());
        }
        // The early-exit existence test answers as the full search does, on both sides of
        // the best score, with and without exclusions.
        let (_, top) = f.search_bnb_from(&start, 0.0, None).unwrap();
        for ratio in [0.0, 0.5, 0.8, 0.9, 0.95, 0.99, 1.0, 1.01] {
            for ex in [
                None,
                Some((centre, 0.05, 0.01)),
                Some((centre, 0.2, 0.05)),
                Some((centre, 1.0, 1.0)),
            ] {
                let full = f.search_bnb_from(&start, ratio * top, ex).is_some();
                assert_eq!(
                    f.any_bnb_from(&start, ratio * top, ex),
                    full,
                    "{ratio} {ex:?}"
                );
            }
        }
    }

    /// Level `level` of `f` as a dense row-major `w x h` grid.
    fn dense(f: &PointField, level: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(f.w * f.h);
        for j in 0..f.h as i64 {
            for i in 0..f.w as i64 {
                out.push(f.at(level, i, j));
            }
        }
        out
    }

    #[test]
    fn banded_build_equals_the_plain_splat() {
        let mut pts: Vec<[f64; 2]> = room_points().iter().step_by(3).copied().collect();
        // Points repeated (a submap's overlapping scans), mostly in the same cells, in
        // another order.
        let again: Vec<[f64; 2]> = pts
            .iter()
            .rev()
            .map(|p| [p[0] + 0.004, p[1] - 0.003])
            .collect();
        pts.extend(again);
        let cases = [
            ([-6.0, -5.0], [6.0, 5.0], 3),
            ([-1.3, -4.1], [2.2, 0.4], 1),
            ([3.9, -3.2], [4.4, 9.0], 0),
            // Mostly empty windows: many tiles absent, the pooled reach across tiles.
            ([-12.0, -9.0], [5.0, 4.0], 4),
            ([-3.0, -20.0], [14.0, 3.5], 6),
        ];
        // Twice, the second time in reverse: every field but the first reuses buffers of
        // other shapes from the pool.
        for &(min, max, levels) in cases.iter().chain(cases.iter().rev()) {
            let (res, sigma) = (0.05, 0.07);
            let f = PointField::build(&pts, min, max, res, sigma, levels);
            // Plain: every point splats the truncated Gaussian, cells keep the maximum.
            let sc: f64 = sigma / res;
            let r = (3.0 * sc).ceil() as i64;
            let mut plain = vec![0f32; f.w * f.h];
            for p in &pts {
                let ci = ((p[0] - min[0]) / res).floor() as i64;
                let cj = ((p[1] - min[1]) / res).floor() as i64;
                for dj in -r..=r {
                    for di in -r..=r {
                        let v = (-0.5 * (di * di + dj * dj) as f64 / (sc * sc)).exp() as f32;
                        let (x, y) = (ci + di, cj + dj);
                        let inside = x >= 0 && y >= 0 && x < f.w as i64 && y < f.h as i64;
                        if v > 0.01 && inside {
                            let slot = &mut plain[y as usize * f.w + x as usize];
                            *slot = slot.max(v);
                        }
                    }
                }
            }
            assert!(plain.iter().any(|&v| v > 0.5));
            assert_eq!(dense(&f, 0), plain);
            for k in 1..=levels {
                let s = 1usize << k;
                let got = dense(&f, k);
                for y in 0..f.h {
                    for x in 0..f.w {
                        let mut m = 0f32;
                        for yy in y..(y + s).min(f.h) {
                            for xx in x..(x + s).min(f.w) {
                                m = m.max(plain[yy * f.w + xx]);
                            }
                        }
                        assert_eq!(got[y * f.w + x], m, "level {k} ({x}, {y})");
                    }
                }
            }
        }
    }

    /// The refinement without batched scores (the oracle): the sequential pattern search,
    /// one plain score at a time.
    fn refine_sequential(
        f: &PointField,
        points_body: &[[f64; 2]],
        start: &Pose2,
        yaw_step_rad: f64,
        levels: u32,
        prior: Option<&Prior>,
    ) -> (Pose2, f64) {
        let n_pts = points_body.len().max(1) as f64;
        let objective = |p: &Pose2| {
            let s = score_plain(f, points_body, p);
            (s * n_pts - prior.map_or(0.0, |q| q.penalty(p)), s)
        };
        let ([x_m, y_m, yaw_rad], (_, score)) = crate::filter::scanmatch::pattern_search_sequential(
            [start.x_m, start.y_m, start.yaw_rad],
            objective(start),
            0.5 * f.resolution_m,
            0.5 * yaw_step_rad,
            levels,
            100,
            |at, _| objective(&Pose2::new(at[0], at[1], at[2])),
        );
        (Pose2::new(x_m, y_m, yaw_rad), score)
    }

    /// The batched scores (1..=6 poses per pass, and more over several passes) equal each
    /// pose's plain score, and `refine` (an iteration's candidates scored in one pass)
    /// returns the bits of the sequential refinement.
    #[test]
    fn batched_scores_and_refine_give_the_sequential_bits() {
        let pts = room_points();
        let f = PointField::build(&pts, [-6.0, -5.0], [6.0, 5.0], 0.05, 0.08, 3);
        let body: Vec<[f64; 2]> = pts.iter().step_by(5).copied().collect();
        for k in 0..160usize {
            let t = k as f64;
            // Poses that push points across the field's edges (outside cells count 0),
            // some sharing a yaw as the x/y moves do.
            let poses: Vec<Pose2> = (0..1 + k % 9)
                .map(|i| {
                    let u = t + i as f64;
                    let yaw = if i % 3 == 0 { t * 0.05 } else { u * 0.05 };
                    Pose2::new((u * 0.37).sin() * 3.0, (u * 0.23).cos() * 2.5, yaw)
                })
                .collect();
            let sc: Vec<(f64, f64)> = poses.iter().map(|p| p.yaw_rad.sin_cos()).collect();
            // Every remainder of the four-point batches; some with points beyond the i32
            // range of cells (~1.1e8 m at 0.05 m), whose vector conversion gives i32::MIN.
            let mut far = body.clone();
            if k % 5 == 0 {
                far[k % 7] = [2e8, -1.0];
                far[3 + k % 11] = [2.0, -3e8];
            }
            let part = &far[..far.len() - k % 4];
            let mut got = vec![0.0; poses.len()];
            f.scores_batched(part, &poses, &sc, &mut got);
            for (p, g) in poses.iter().zip(&got) {
                assert_eq!(g.to_bits(), score_plain(&f, part, p).to_bits(), "{k} {p:?}");
            }
        }
        for k in 0..40u32 {
            let t = f64::from(k);
            let start = Pose2::new(
                0.1 * (t * 0.7).sin(),
                0.1 * (t * 1.3).cos(),
                0.04 * (t * 0.9).sin(),
            );
            let prior = Prior {
                pose: Pose2::new(0.02, -0.01, 0.01),
                sigma_xy_m: 0.05 + 0.1 * t,
                sigma_yaw_rad: 0.02,
            };
            let prior = (k % 2 == 0).then_some(&prior);
            let (yaw_step, levels) = (0.01 + 0.001 * t, k % 5);
            let got = f.refine(&body, &start, yaw_step, levels, prior);
            let want = refine_sequential(&f, &body, &start, yaw_step, levels, prior);
            assert_eq!(got.0.x_m.to_bits(), want.0.x_m.to_bits(), "{k}");
            assert_eq!(got.0.y_m.to_bits(), want.0.y_m.to_bits(), "{k}");
            assert_eq!(got.0.yaw_rad.to_bits(), want.0.yaw_rad.to_bits(), "{k}");
            assert_eq!(got.1.to_bits(), want.1.to_bits(), "{k}");
        }
    }

    /// A window that cuts the scan (its points partly left of and below the field, as a
    /// loop candidate's field clipped to its submap leaves the scan's far points): the branch
    /// and bound still finds the exhaustive maximum for any number of pooled levels. A
    /// pooled cell left of or below the window covers window cells; counting it as 0 (before)
    /// made the bound too low and pruned the best pose with 4 or more levels.
    #[test]
    fn bnb_is_exact_where_the_scan_leaves_the_window() {
        let pts = room_points();
        let truth = Pose2::new(0.3, -0.2, 0.1);
        let body = seen_from(&pts, &truth);
        let win = SearchWindow {
            xy_m: 0.6,
            yaw_rad: 0.06,
            yaw_step_rad: 0.02,
        };
        let centre = Pose2::new(0.05, 0.1, 0.08);
        // The left wall (x = -4) and the bottom wall (y = -3) lie just outside.
        let (lo, hi) = ([-3.93, -2.91], [6.0, 5.0]);
        let n = (win.xy_m / 0.05f64).ceil() as i64;
        for levels in 0..=6 {
            let f = PointField::build(&pts, lo, hi, 0.05, 0.08, levels);
            let mut best = f64::NEG_INFINITY;
            for yaw in PointField::window_yaws(&centre, &win) {
                let cells = f.cells_at(&body, &centre, yaw);
                assert!(cells.x.iter().zip(&cells.y).any(|(&i, &j)| i < 0 || j < 0));
                for dy in -n..=n {
                    for dx in -n..=n {
                        best = best.max(f.cell_sum(&cells, 0, dx, dy) / body.len() as f64);
                    }
                }
            }
            let (_, score) = f.search_bnb(&body, &centre, &win, 0.0, None).unwrap();
            assert_eq!(score.to_bits(), best.to_bits(), "{levels} levels");
            let start = f.bnb_start(&body, &centre, &win).unwrap();
            assert!(f.any_bnb_from(&start, 0.999_999 * best, None), "{levels}");
            assert!(!f.any_bnb_from(&start, best, None), "{levels}");
        }
    }

    /// The eight-lane sum gives the point-order sum's bits: every level, offsets inside,
    /// across and far beyond the window, cells far out (clamped) and on every side.
    #[test]
    fn cell_sum_in_any_order_equals_the_point_order_sum() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let pts = room_points();
        let f = PointField::build(&pts, [-5.0, -4.0], [6.0, 5.0], 0.05, 0.08, 4);
        let (w, h) = (f.w as i32, f.h as i32);
        for trial in 0..200 {
            let len = rng.random_range(0..300usize);
            let mut cell = |side: i32| match rng.random_range(0..10) {
                0 => rng.random_range(-(1 << 30)..=(1 << 30)),
                1 => rng.random_range(-40..0),
                _ => rng.random_range(0..side + 40),
            };
            let x: Vec<i32> = (0..len).map(|_| cell(w)).collect();
            let y: Vec<i32> = (0..len).map(|_| cell(h)).collect();
            let cells = PointCells { x, y };
            for level in 0..=f.pooled_levels() {
                for (dx, dy) in [(0, 0), (-3, 7), (25, -40), (-(1 << 21), 5), (3, 1 << 25)] {
                    let fast = f.cell_sum(&cells, level, dx, dy);
                    let plain = f.cell_sum_scalar((&cells.x, &cells.y), level, dx, dy);
                    assert_eq!(fast.to_bits(), plain.to_bits(), "{trial} {level} {dx} {dy}");
                }
            }
        }
    }

    #[test]
    fn bnb_equals_exhaustive_on_the_cell_grid() {
        let pts = room_points();
        let f = PointField::build(&pts, [-6.0, -5.0], [6.0, 5.0], 0.05, 0.08, 4);
        let truth = Pose2::new(0.3, -0.2, 0.1);
        let body = seen_from(&pts, &truth);
        let win = SearchWindow {
            xy_m: 0.6,
            yaw_rad: 0.2,
            yaw_step_rad: 0.01,
        };
        let centre = Pose2::new(0.0, 0.0, 0.05);
        let (p, s) = f.search_bnb(&body, &centre, &win, 0.0, None).unwrap();
        // Exhaustive reference with a flat prior.
        let prior = Prior {
            pose: centre,
            sigma_xy_m: 1e9,
            sigma_yaw_rad: 1e9,
        };
        let q = f.search_with_prior(&body, &prior, &win);
        assert!(p.between(&q).translation_norm_m() < 1e-9, "{p:?} {q:?}");
        assert!((p.yaw_rad - q.yaw_rad).abs() < 1e-9);
        assert!(p.between(&truth).translation_norm_m() < 0.06, "{p:?}");
        assert!(s > 0.8, "{s}");
        let (r, rs) = f.refine(&body, &p, 0.01, 5, None);
        // The walls lie on cell boundaries, where the bilinear field is flat between the two
        // cell centres: sub-cell accuracy is about half a cell per axis there.
        assert!(
            r.between(&truth).translation_norm_m() < 0.75 * 0.05,
            "{r:?}"
        );
        assert!(wrap_angle(r.yaw_rad - truth.yaw_rad).abs() < 0.004, "{r:?}");
        assert!(rs >= f.score(&body, &p));
    }
}
