//! The Rao-Blackwellised particle filter (`[filter] mode = "rbpf"`), after GMapping
//! (Grisetti, Stachniss, Burgard 2007).
//!
//! - Every particle carries its own [`OccupancyGrid`]. Grids are tiled with `Arc` tiles and
//!   copy-on-write, so a resampled copy shares all tiles with its ancestor and memory grows
//!   with the tiles particles actually changed, not with the particle count.
//! - Updates happen only once the odometry moved `linear_update_m` or turned
//!   `angular_update_deg` since the last one. At an update each particle composes the
//!   odometry increment onto its pose (no noise), scan-matches from there against its OWN
//!   map (coarse yaw/x/y search, then a hill climb with step halving on a smooth observation
//!   model, see [`scan_log_likelihood`]; the prior's sigmas are GMapping's four-parameter
//!   motion noise for the increment), then samples its pose around the match
//!   (`jitter_xy_m`, `jitter_yaw_deg`); its log-weight grows by the match log-likelihood /
//!   `weight_temperature`. (`match_from_prediction = false`: GMapping's order, the motion
//!   noise sampled first and the match started from the sample.) Maps are updated
//!   with the particle's pose; resampling is selective (Neff below a fraction of N).
//! - Each particle's trajectory is a chain of [`PathNode`]s with `Arc` parent links, one per
//!   update, so resampled copies share their history. The output is the FINAL best
//!   particle's whole ancestral path: loop closures found late correct the whole past. Scans
//!   between updates get the previous node's pose composed with the odometry increment, so
//!   every scan has a pose.
//! - Randomness: one `jump()`ed stream per fixed chunk of particles (`filter::rng`), the
//!   master stream for resampling: results do not depend on the thread count.

use super::resample;
use super::rng::{CHUNK_PARTICLES, FilterRng};
use super::scanmatch::match_points;
use super::slam::{SlamError, SlamEvent, SlamResult, SlamStats};
use super::weights;
use crate::config::Config;
use crate::geometry::{Pose2, StampedPose2, wrap_angle};
use crate::map::TILE_SIZE;
use crate::map::grid::TILE_SHIFT;
use crate::map::limits::{MapLimits, floor_to_i32};
use crate::map::{
    Cell, InsertScratch, MapError, OccupancyGrid, PlanarScan, ScanProjector, to_world,
};
use crate::sensors::Recording;
use rand::RngExt;
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

/// Options of the Rao-Blackwellised mode (`[filter.rbpf]`). The particle count is
/// `[filter] particles`, the resampling scheme `[filter] resample_method`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfOptions {
    /// Cell side of the particles' maps (m); 0 = `[map] resolution_m`.
    pub resolution_m: f64,
    /// Update (match, reweight, map) once the odometry moved this far since the last
    /// update (m; GMapping: 0.5-1).
    pub linear_update_m: f64,
    /// ... or turned this much (deg; GMapping: 0.5 rad).
    pub angular_update_deg: f64,
    /// Odometry noise: translation sigma per metre travelled (GMapping `srr`).
    pub srr: f64,
    /// Translation sigma per radian turned (m/rad; GMapping `str`).
    pub str_m_per_rad: f64,
    /// Rotation sigma per metre travelled (rad/m; GMapping `srt`).
    pub srt_rad_per_m: f64,
    /// Rotation sigma per radian turned (GMapping `stt`).
    pub stt: f64,
    /// Use every k-th return for matching and weighting (1 = all; mapping uses all).
    pub beam_decimation: usize,
    /// Returns farther than this are neither matched nor mapped (m; GMapping `maxUrange`).
    pub range_max_m: f64,
    /// Returns nearer than this are dropped; replaces `[map.scan] range_min_m` in this mode
    /// (whose 2 m default is the car seed's; indoor robots see walls closer than that).
    pub range_min_m: f64,
    /// Keep `[map.scan]`'s densification of walls (joining returns); off matches and maps
    /// the real beams only.
    pub densify: bool,
    /// Standard deviation of the observation model: a point at distance d from the nearest
    /// occupied cell centre scores `-d^2 / (2 sigma^2)` (m).
    pub sigma_m: f64,
    /// Occupied cells are looked for within this many cells of a point (Chebyshev).
    pub kernel_cells: u32,
    /// Log-likelihood of a point with no occupied cell within the kernel (a floor; negative).
    pub no_hit_log_likelihood: f64,
    /// A cell counts as occupied for matching above this log-odds (0 = p > 0.5, one hit).
    pub occupied_logodds: f64,
    /// Half-width of the coarse yaw search around each particle's sampled pose (deg).
    pub coarse_yaw_deg: f64,
    /// Step of the coarse yaw search (deg).
    pub coarse_yaw_step_deg: f64,
    /// Half-width of the coarse x/y search (cells of the particles' maps).
    pub coarse_xy_cells: u32,
    /// Initial x/y step of the hill climb (m; GMapping `lstep`).
    pub step_xy_m: f64,
    /// Initial yaw step of the hill climb (deg; GMapping `astep` = 0.05 rad).
    pub step_yaw_deg: f64,
    /// Step halvings of the hill climb (GMapping `iterations`).
    pub refine_levels: u32,
    /// Divisor of the match log-likelihood in the log-weight update (GMapping: `ogain` times
    /// the particle count).
    pub weight_temperature: f64,
    /// Resample when Neff < this fraction of the particle count.
    pub resample_threshold: f64,
    /// The matcher's prior on the deviation from each particle's predicted pose (the sample,
    /// with `match_from_prediction = false`): a Gaussian with the motion model's sigmas for
    /// this update times this factor (0 = no prior, the match may go anywhere the search
    /// reaches). Keeps matches from sliding along corridors.
    pub prior_scale: f64,
    /// Smallest x/y sigma of that prior (m).
    pub prior_min_xy_m: f64,
    /// Smallest yaw sigma of that prior (deg).
    pub prior_min_yaw_deg: f64,
    /// After the run, re-match every output pose against the final best particle's map
    /// (hill climb from the path's pose): corrects the odometry composed between updates.
    pub final_refine: bool,
    /// x/y sigma of that re-match's prior around the path's pose (m).
    pub refine_sigma_xy_m: f64,
    /// Yaw sigma of that re-match's prior (deg).
    pub refine_sigma_yaw_deg: f64,
    /// The proposal. `true`: each particle is matched from its noise-free prediction (the
    /// prior centred there) and then sampled around its match (`jitter_*`). `false`
    /// (GMapping's order): the motion noise is sampled first and the match starts from the
    /// sample, the prior centred on it; with noise sized for poor odometry the samples land
    /// in other basins of the likelihood and good odometry is made worse. See
    /// `docs/decisions/0005-proposal-from-prediction.md`.
    pub match_from_prediction: bool,
    /// x/y sigma of the sample around the match (m).
    pub jitter_xy_m: f64,
    /// Yaw sigma of the sample around the match (deg).
    pub jitter_yaw_deg: f64,
}

impl Default for RbpfOptions {
    fn default() -> Self {
        RbpfOptions {
            resolution_m: 0.05,
            linear_update_m: 0.3,
            angular_update_deg: 15.0,
            srr: 0.1,
            str_m_per_rad: 0.1,
            srt_rad_per_m: 0.2,
            stt: 0.2,
            beam_decimation: 2,
            range_max_m: 30.0,
            range_min_m: 0.1,
            densify: false,
            sigma_m: 0.05,
            kernel_cells: 1,
            no_hit_log_likelihood: -2.0,
            occupied_logodds: 0.0,
            coarse_yaw_deg: 3.0,
            coarse_yaw_step_deg: 1.0,
            coarse_xy_cells: 0,
            step_xy_m: 0.05,
            step_yaw_deg: 2.865,
            refine_levels: 4,
            weight_temperature: 30.0,
            resample_threshold: 0.5,
            prior_scale: 1.0,
            prior_min_xy_m: 0.02,
            prior_min_yaw_deg: 1.0,
            final_refine: true,
            refine_sigma_xy_m: 0.03,
            refine_sigma_yaw_deg: 3.0,
            match_from_prediction: true,
            jitter_xy_m: 0.01,
            jitter_yaw_deg: 0.25,
        }
    }
}

impl RbpfOptions {
    /// Checks ranges; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if !(nonneg(self.resolution_m) && self.resolution_m <= 10.0) {
            return Err("filter.rbpf.resolution_m must lie in [0, 10]".into());
        }
        for (k, v) in [
            ("range_min_m", self.range_min_m),
            ("linear_update_m", self.linear_update_m),
            ("angular_update_deg", self.angular_update_deg),
            ("srr", self.srr),
            ("str_m_per_rad", self.str_m_per_rad),
            ("srt_rad_per_m", self.srt_rad_per_m),
            ("stt", self.stt),
            ("coarse_yaw_deg", self.coarse_yaw_deg),
            ("step_xy_m", self.step_xy_m),
            ("step_yaw_deg", self.step_yaw_deg),
            ("prior_scale", self.prior_scale),
            ("jitter_xy_m", self.jitter_xy_m),
            ("jitter_yaw_deg", self.jitter_yaw_deg),
        ] {
            if !nonneg(v) {
                return Err(format!("filter.rbpf.{k} must be finite and >= 0"));
            }
        }
        for (k, v) in [
            ("range_max_m", self.range_max_m),
            ("sigma_m", self.sigma_m),
            ("coarse_yaw_step_deg", self.coarse_yaw_step_deg),
            ("weight_temperature", self.weight_temperature),
            ("prior_min_xy_m", self.prior_min_xy_m),
            ("prior_min_yaw_deg", self.prior_min_yaw_deg),
            ("refine_sigma_xy_m", self.refine_sigma_xy_m),
            ("refine_sigma_yaw_deg", self.refine_sigma_yaw_deg),
        ] {
            if !pos(v) {
                return Err(format!("filter.rbpf.{k} must be positive and finite"));
            }
        }
        if self.beam_decimation == 0 {
            return Err("filter.rbpf.beam_decimation must be at least 1".into());
        }
        if self.kernel_cells > 8 {
            return Err("filter.rbpf.kernel_cells must be at most 8".into());
        }
        if self.coarse_xy_cells > 16 {
            return Err("filter.rbpf.coarse_xy_cells must be at most 16".into());
        }
        if self.coarse_yaw_deg > 45.0 || self.coarse_yaw_deg / self.coarse_yaw_step_deg > 200.0 {
            return Err("filter.rbpf.coarse_yaw_deg must be at most 45 and 200 steps".into());
        }
        if self.refine_levels > 12 {
            return Err("filter.rbpf.refine_levels must be at most 12".into());
        }
        if !(self.no_hit_log_likelihood.is_finite() && self.no_hit_log_likelihood <= 0.0) {
            return Err("filter.rbpf.no_hit_log_likelihood must be finite and <= 0".into());
        }
        if !(self.occupied_logodds.is_finite() && self.occupied_logodds.abs() <= 100.0) {
            return Err("filter.rbpf.occupied_logodds must lie in [-100, 100]".into());
        }
        if !(0.0..=1.0).contains(&self.resample_threshold) {
            return Err("filter.rbpf.resample_threshold must lie in [0, 1]".into());
        }
        Ok(())
    }

    /// The observation model these options describe, for maps of `resolution_m`.
    pub fn observation(&self, resolution_m: f64) -> ObservationModel {
        ObservationModel {
            kernel: self.kernel_cells as i32,
            occupied_fixed: (self.occupied_logodds * 256.0).round() as i16,
            res2_over_2s2: resolution_m * resolution_m / (2.0 * self.sigma_m * self.sigma_m),
            no_hit: self.no_hit_log_likelihood,
        }
    }

    /// Odometry noise sigmas `[srr, str, srt, stt]`.
    fn noise(&self) -> [f64; 4] {
        [self.srr, self.str_m_per_rad, self.srt_rad_per_m, self.stt]
    }
}

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
    let nearest =
        |cells: &[i16], li, lj, u, v, i, j, occ| nearest_3x3_avx2(cells, li, lj, u, v, i, j, occ);
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
        let nearest = |cells: &[i16], li, lj, u, v, i, j, occ| {
            nearest_3x3_avx2(cells, li, lj, u, v, i, j, occ)
        };
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
    nearest: &impl Fn(&[i16], i32, i32, f64, f64, i32, i32, i16) -> f64,
) -> f64 {
    let (k, occ) = (model.kernel, model.occupied_fixed);
    let mut best = f64::INFINITY;
    let (li, lj) = (i & MASK, j & MASK);
    if li >= k && lj >= k && li < TS - k && lj < TS - k {
        // The whole kernel lies in one tile: one directory lookup.
        if let Some(cells) = cache.get(grid, (i >> TILE_SHIFT, j >> TILE_SHIFT)) {
            if k == 1 {
                best = nearest(cells, li, lj, u, v, i, j, occ);
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
fn likelihood_scalar(
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

/// The smallest squared distance (cells) from `(u, v)` to the centre of an occupied cell of
/// the 3x3 block around local cell `(li, lj)` (global `(i, j)`) of one tile; infinity if none.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn nearest_3x3(cells: &[i16], li: i32, lj: i32, u: f64, v: f64, i: i32, j: i32, occ: i16) -> f64 {
    let du2 = [-1, 0, 1].map(|d| {
        let du = u - (f64::from(i + d) + 0.5);
        du * du
    });
    let mut best = f64::INFINITY;
    for dj in -1..=1 {
        let dv = v - (f64::from(j + dj) + 0.5);
        let dv2 = dv * dv;
        let start = (((lj + dj) as usize) << TILE_SHIFT) + (li - 1) as usize;
        let Some(row) = cells.get(start..start + 3) else {
            continue;
        };
        for (cell, du2) in row.iter().zip(du2) {
            let d = if *cell > occ {
                du2 + dv2
            } else {
                f64::INFINITY
            };
            // `d` is never NaN where `best` could be replaced (finite inputs; a NaN point
            // compares false and keeps infinity, as `f64::min` would): a plain compare-select.
            best = if d < best { d } else { best };
        }
    }
    best
}

/// [`nearest_3x3`] in AVX2: a row's three cells and squared distances in one vector each
/// (a fourth lane never occupied), a compare-select per row. The minimum of the same
/// values, taken in the same way (a candidate replaces the best only when smaller, so a NaN
/// never does): the same bits.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2")]
#[inline]
fn nearest_3x3_avx2(
    cells: &[i16],
    li: i32,
    lj: i32,
    u: f64,
    v: f64,
    i: i32,
    j: i32,
    occ: i16,
) -> f64 {
    use std::arch::x86_64::*;
    // Columns i - 1, i, i + 1 (and i + 2, masked off): `f64::from(i + d) + 0.5` exactly.
    let columns = _mm_add_epi32(_mm_set1_epi32(i), _mm_setr_epi32(-1, 0, 1, 2));
    let du = _mm256_sub_pd(
        _mm256_set1_pd(u),
        _mm256_add_pd(_mm256_cvtepi32_pd(columns), _mm256_set1_pd(0.5)),
    );
    let du2 = _mm256_mul_pd(du, du);
    let occ_v = _mm_set1_epi16(occ);
    let inf = _mm256_set1_pd(f64::INFINITY);
    let mut best = inf;
    for dj in -1..=1 {
        let dv = v - (f64::from(j + dj) + 0.5);
        let dv2 = dv * dv;
        let start = (((lj + dj) as usize) << TILE_SHIFT) + (li - 1) as usize;
        let Some(row) = cells.get(start..start + 3) else {
            continue;
        };
        // The fourth lane is i16::MIN, which no threshold is below.
        let four = [row[0], row[1], row[2], i16::MIN];
        // SAFETY: an unaligned 8-byte load from a local array of four i16.
        let row_v = unsafe { _mm_loadl_epi64(four.as_ptr().cast()) };
        let occupied = _mm256_castsi256_pd(_mm256_cvtepi16_epi64(_mm_cmpgt_epi16(row_v, occ_v)));
        let d = _mm256_blendv_pd(inf, _mm256_add_pd(du2, _mm256_set1_pd(dv2)), occupied);
        // `minpd(a, b)` is `a < b ? a : b`: the scalar rule `if d < best { d } else { best }`.
        best = _mm256_min_pd(d, best);
    }
    let mut lanes = [0.0f64; 4];
    // SAFETY: a store into a local array of four f64.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), best) };
    let mut m = f64::INFINITY;
    for l in lanes {
        m = if l < m { l } else { m };
    }
    m
}

/// Search parameters of [`match_in_own_map`].
#[derive(Debug, Clone, PartialEq)]
pub struct SearchParams {
    /// Coarse yaw offsets (rad), 0 first.
    pub yaw_offsets_rad: Vec<f64>,
    /// Coarse x/y half-width (cells).
    pub xy_cells: i32,
    /// Cell side (m).
    pub resolution_m: f64,
    /// Initial hill-climb steps (m, rad).
    pub step_xy_m: f64,
    /// Initial hill-climb yaw step (rad).
    pub step_yaw_rad: f64,
    /// Step halvings.
    pub refine_levels: u32,
    /// Prior on the deviation from the sampled pose (set per update from the motion).
    pub prior: Option<MatchPrior>,
}

impl SearchParams {
    /// From the options, for maps of `resolution_m`.
    pub fn new(o: &RbpfOptions, resolution_m: f64) -> Self {
        let steps = (o.coarse_yaw_deg / o.coarse_yaw_step_deg).floor() as i32;
        let mut yaw_offsets_rad = vec![0.0];
        for k in 1..=steps {
            let d = (f64::from(k) * o.coarse_yaw_step_deg).to_radians();
            yaw_offsets_rad.push(-d);
            yaw_offsets_rad.push(d);
        }
        SearchParams {
            yaw_offsets_rad,
            xy_cells: o.coarse_xy_cells as i32,
            resolution_m,
            step_xy_m: o.step_xy_m,
            step_yaw_rad: o.step_yaw_deg.to_radians(),
            refine_levels: o.refine_levels,
            prior: None,
        }
    }
}

/// Scan-matches `points` against `grid` around `start`: coarse search over the yaw offsets
/// and x/y cells, then a hill climb (six moves, step halving). Returns the pose and its
/// log-likelihood. Deterministic: fixed order, strict improvements only.
pub fn match_in_own_map(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    start: &Pose2,
    search: &SearchParams,
) -> (Pose2, f64) {
    let prior = search.prior;
    // The objective `ll - penalty` (`ll` alone without a prior: `x - 0.0` is `x`). Given
    // the value to beat, the likelihood may stop early; the result then does not beat it.
    let eval = |p: &Pose2, bar: Option<f64>| {
        let penalty = match prior {
            Some(pr) => {
                let (dx, dy) = (p.x_m - start.x_m, p.y_m - start.y_m);
                let da = wrap_angle(p.yaw_rad - start.yaw_rad);
                0.5 * ((dx * dx + dy * dy) * pr.inv_var_xy + da * da * pr.inv_var_yaw)
            }
            None => 0.0,
        };
        let bar = bar.map(|bar| Bar { penalty, bar });
        let ll = scan_log_likelihood_above(grid, model, points, p, bar);
        let objective = match prior {
            Some(_) => ll - penalty,
            None => ll,
        };
        (objective, ll)
    };
    // Every pose evaluated so far has an objective <= the current value to beat (which
    // only rises: a candidate either lost against it or raised it), so a candidate equal
    // to one of them bit for bit cannot win and is not evaluated again.
    let bits = |p: &Pose2| [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits);
    let mut seen: Vec<[u64; 3]> = Vec::with_capacity(64);
    let mut best = *start;
    // `best_raw`: the best pose's log-likelihood without the prior (always a full sum: a
    // winner never stopped early).
    let (mut best_ll, mut best_raw) = eval(&best, None);
    seen.push(bits(&best));
    let r = search.xy_cells;
    for &dyaw in &search.yaw_offsets_rad {
        for oy in -r..=r {
            for ox in -r..=r {
                if dyaw == 0.0 && ox == 0 && oy == 0 {
                    continue;
                }
                let cand = Pose2::new(
                    start.x_m + f64::from(ox) * search.resolution_m,
                    start.y_m + f64::from(oy) * search.resolution_m,
                    start.yaw_rad + dyaw,
                );
                let (ll, raw) = eval(&cand, Some(best_ll));
                seen.push(bits(&cand));
                if ll > best_ll {
                    best_ll = ll;
                    best_raw = raw;
                    best = cand;
                }
            }
        }
    }
    let (mut sxy, mut syaw) = (search.step_xy_m, search.step_yaw_rad);
    let mut level = 0;
    let mut iterations = 0;
    // (Not `scanmatch::pattern_search`: this climb wraps the yaw at every step.)
    while level < search.refine_levels && iterations < 200 {
        iterations += 1;
        let mut moved: Option<(Pose2, f64, f64)> = None;
        for (ex, ey, ea) in [
            (sxy, 0.0, 0.0),
            (-sxy, 0.0, 0.0),
            (0.0, sxy, 0.0),
            (0.0, -sxy, 0.0),
            (0.0, 0.0, syaw),
            (0.0, 0.0, -syaw),
        ] {
            let cand = Pose2::new(best.x_m + ex, best.y_m + ey, best.yaw_rad + ea);
            let key = bits(&cand);
            if seen.contains(&key) {
                continue;
            }
            seen.push(key);
            let to_beat = moved.map_or(best_ll, |m| m.1);
            let (ll, raw) = eval(&cand, Some(to_beat));
            if ll > to_beat {
                moved = Some((cand, ll, raw));
            }
        }
        match moved {
            Some((p, ll, raw)) => {
                best = p;
                best_ll = ll;
                best_raw = raw;
            }
            None => {
                sxy *= 0.5;
                syaw *= 0.5;
                level += 1;
            }
        }
    }
    let wrapped = wrap_angle(best.yaw_rad);
    // The weight is the observation's likelihood, without the prior: the one computed for
    // this pose, unless wrapping the yaw changed the pose (then recomputed, with a prior).
    let ll = if prior.is_none() || wrapped.to_bits() == best.yaw_rad.to_bits() {
        best_raw
    } else {
        scan_log_likelihood(
            grid,
            model,
            points,
            &Pose2 {
                yaw_rad: wrapped,
                ..best
            },
        )
    };
    best.yaw_rad = wrapped;
    (best, ll)
}

/// Gaussian prior of the matcher on the deviation from the sampled pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchPrior {
    /// `1 / sigma_xy^2` (1/m^2).
    pub inv_var_xy: f64,
    /// `1 / sigma_yaw^2` (1/rad^2).
    pub inv_var_yaw: f64,
}

/// GMapping's odometry noise: the increment `delta` (in the old body frame) gets Gaussian
/// noise whose sigmas grow with the distance and angle travelled; returns `pose ⊕ noisy`.
fn sample_motion(
    pose: &Pose2,
    delta: &Pose2,
    noise: [f64; 4],
    rng: &mut Xoshiro256PlusPlus,
) -> Pose2 {
    let [srr, str_, srt, stt] = noise;
    let sxy = 0.3 * srr;
    let (dx, dy, dt) = (delta.x_m.abs(), delta.y_m.abs(), delta.yaw_rad.abs());
    let (a, b, c): (f64, f64, f64) = (
        rng.sample(StandardNormal),
        rng.sample(StandardNormal),
        rng.sample(StandardNormal),
    );
    let noisy = Pose2::new(
        delta.x_m + a * (srr * dx + str_ * dt + sxy * dy),
        delta.y_m + b * (srr * dy + str_ * dt + sxy * dx),
        delta.yaw_rad + c * (stt * dt + srt * dx.hypot(dy)),
    );
    let mut out = pose.compose(&noisy);
    out.yaw_rad = wrap_angle(out.yaw_rad);
    out
}

/// One node of a particle's trajectory tree: its pose at an update, the odometry pose there,
/// and the node of the previous update. Resampled copies share their parents.
#[derive(Debug)]
pub struct PathNode {
    /// The particle's pose at this update.
    pub pose: Pose2,
    /// The odometry pose at this update (the increments to later scans start here).
    pub odom: Pose2,
    /// Index of the update's scan among the processed scans.
    pub scan: usize,
    /// The previous update's node (`None` at the start).
    pub parent: Option<Arc<PathNode>>,
}

impl Drop for PathNode {
    /// Iterative: a long chain must not recurse once per node (stack overflow).
    fn drop(&mut self) {
        let mut next = self.parent.take();
        while let Some(node) = next {
            match Arc::try_unwrap(node) {
                Ok(mut n) => next = n.parent.take(),
                Err(_) => break,
            }
        }
    }
}

/// The nodes from the root to `leaf`, in time order.
pub fn ancestry(leaf: &Arc<PathNode>) -> Vec<&PathNode> {
    let mut out = Vec::new();
    let mut cur: Option<&PathNode> = Some(leaf);
    while let Some(n) = cur {
        out.push(n);
        cur = n.parent.as_deref();
    }
    out.reverse();
    out
}

/// Poses of every processed scan along the path ending at `leaf`: each scan takes the last
/// node at or before it, composed with the odometry increment from that node to the scan.
/// `odometry[k]` is the odometry pose of processed scan `k`.
pub fn path_poses(leaf: &Arc<PathNode>, odometry: &[StampedPose2]) -> Vec<StampedPose2> {
    let nodes = ancestry(leaf);
    let mut out = Vec::with_capacity(odometry.len());
    let mut n = 0;
    for (k, o) in odometry.iter().enumerate() {
        while n + 1 < nodes.len() && nodes[n + 1].scan <= k {
            n += 1;
        }
        let node = nodes[n];
        out.push(StampedPose2 {
            stamp_ns: o.stamp_ns,
            pose: node.pose.compose(&node.odom.between(&o.pose)),
        });
    }
    out
}

/// One particle: pose, own map and trajectory node.
#[derive(Debug, Clone)]
pub struct RbParticle {
    /// Current pose (at the last update, before the odometry since).
    pub pose: Pose2,
    /// The particle's own map.
    pub map: OccupancyGrid,
    /// The last node of its trajectory.
    pub node: Arc<PathNode>,
}

/// Per-chunk state: the chunk's random stream.
#[derive(Debug, Clone)]
struct ChunkState {
    rng: Xoshiro256PlusPlus,
}

/// Map-insertion buffers, one per worker thread (filled on first use). A clone starts empty:
/// buffers hold no state that matters.
#[derive(Debug, Default)]
struct InsertBuffers(Vec<std::sync::Mutex<(PlanarScan, InsertScratch)>>);

impl Clone for InsertBuffers {
    fn clone(&self) -> Self {
        InsertBuffers::default()
    }
}

/// Number of distinct tiles held by `maps` (shared tiles counted once).
pub fn distinct_tiles<'a, I: IntoIterator<Item = &'a OccupancyGrid>>(maps: I) -> usize {
    let mut ids: Vec<usize> = maps.into_iter().flat_map(|m| m.tile_ids()).collect();
    ids.sort_unstable();
    ids.dedup();
    ids.len()
}

/// Memory figures of the particles' maps at the end of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct MapMemory {
    /// Distinct tiles over all particles.
    pub distinct_tiles: usize,
    /// Sum of every particle's tile count (what unshared maps would hold).
    pub total_tiles: usize,
    /// Bytes of the distinct tiles.
    pub distinct_bytes: usize,
}

/// The filter's state, exposed for tests: particles, weights, random streams.
#[derive(Debug, Clone)]
pub struct Rbpf {
    /// The particles.
    pub particles: Vec<RbParticle>,
    /// Normalised weights.
    pub weights: Vec<f64>,
    chunks: Vec<ChunkState>,
    scratch: InsertBuffers,
    master: Xoshiro256PlusPlus,
    options: RbpfOptions,
    model: ObservationModel,
    search: SearchParams,
    ancestors: Vec<usize>,
    lls: Vec<f64>,
}

/// What one update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RbpfUpdate {
    /// Neff after reweighting.
    pub neff: f64,
    /// Whether the particles were resampled.
    pub resampled: bool,
    /// Mean per-point log-likelihood of the best particle's match.
    pub best_ll_per_point: f64,
    /// Wall time of motion sampling and matching (s).
    pub match_s: f64,
    /// Wall time of the map updates (s).
    pub map_s: f64,
}

impl Rbpf {
    /// `n` particles at `start`, each with a clone of `map` (sharing its tiles), the first
    /// node at processed scan 0 with odometry pose `odom`.
    pub fn new(
        n: usize,
        start: Pose2,
        odom: Pose2,
        map: OccupancyGrid,
        options: &RbpfOptions,
        seed: u64,
    ) -> Self {
        let res = map.limits().resolution_m();
        let root = Arc::new(PathNode {
            pose: start,
            odom,
            scan: 0,
            parent: None,
        });
        let rng = FilterRng::new(seed, n);
        Rbpf {
            particles: (0..n)
                .map(|_| RbParticle {
                    pose: start,
                    map: map.clone(),
                    node: root.clone(),
                })
                .collect(),
            weights: vec![1.0 / n.max(1) as f64; n],
            chunks: rng
                .chunks
                .into_iter()
                .map(|rng| ChunkState { rng })
                .collect(),
            scratch: InsertBuffers::default(),
            master: rng.master,
            model: options.observation(res),
            search: SearchParams::new(options, res),
            options: options.clone(),
            ancestors: Vec::with_capacity(n),
            lls: vec![0.0; n],
        }
    }

    /// Index of the heaviest particle (lowest index on ties).
    pub fn best(&self) -> usize {
        let mut best = 0;
        for (i, w) in self.weights.iter().enumerate() {
            if *w > self.weights[best] {
                best = i;
            }
        }
        best
    }

    /// One update at processed scan `scan` with odometry pose `odom`: motion `delta` (odometry
    /// increment since the last update, old body frame), matching `points` (body frame),
    /// reweighting, mapping `body` into every particle's map, new path nodes, selective
    /// resampling. With `first`, the scan is only mapped (nothing to match against yet).
    #[allow(clippy::too_many_arguments)]
    pub fn update(
        &mut self,
        scan: usize,
        odom: Pose2,
        delta: &Pose2,
        points: &[[f64; 2]],
        body: &PlanarScan,
        first: bool,
        method: resample::ResampleMethod,
    ) -> Result<RbpfUpdate, MapError> {
        let noise = self.options.noise();
        let o = &self.options;
        self.search.prior = (o.prior_scale > 0.0).then(|| {
            let [srr, str_, srt, stt] = noise;
            let (d, a) = (delta.translation_norm_m(), delta.yaw_rad.abs());
            let sxy = (o.prior_scale * (srr * d + str_ * a)).max(o.prior_min_xy_m);
            let syaw = (o.prior_scale * (stt * a + srt * d)).max(o.prior_min_yaw_deg.to_radians());
            MatchPrior {
                inv_var_xy: 1.0 / (sxy * sxy),
                inv_var_yaw: 1.0 / (syaw * syaw),
            }
        });
        let (model, search) = (&self.model, &self.search);
        let n = self.particles.len();
        let t = Instant::now();
        let from_prediction = o.match_from_prediction;
        let jitter_sigma = [o.jitter_xy_m, o.jitter_xy_m, o.jitter_yaw_deg.to_radians()];
        // Per particle, drawn before the parallel pass: the jitter added to its match.
        let mut jitters: Vec<[f64; 3]> = Vec::new();
        if !first {
            // Motion draws per chunk, from the chunk's stream in particle order (cheap).
            for (parts, st) in self
                .particles
                .chunks_mut(CHUNK_PARTICLES)
                .zip(self.chunks.iter_mut())
            {
                for p in parts.iter_mut() {
                    if from_prediction {
                        p.pose = p.pose.compose(delta);
                        p.pose.yaw_rad = wrap_angle(p.pose.yaw_rad);
                        jitters.push(
                            jitter_sigma.map(|s| s * st.rng.sample::<f64, _>(StandardNormal)),
                        );
                    } else {
                        p.pose = sample_motion(&p.pose, delta, noise, &mut st.rng);
                    }
                }
            }
        }
        let jitters = &jitters;
        // Then every particle on its own (the threads balance whatever the particle count;
        // 5 chunks of 40 particles would split 3:2 over two threads): match in its map, then
        // map the scan into it, in one pass (a particle's match reads only its own map, and
        // copy-on-write tiles keep the others' maps apart, so the same maps as matching all
        // first). Mapped before resampling, so copies share the tiles this update wrote.
        // Each worker thread has its own insertion scratch (a mask of megabytes: never per
        // particle); the scratch does not affect results.
        let threads = rayon::current_num_threads().max(1);
        if self.scratch.0.len() < threads {
            self.scratch.0.resize_with(threads, Default::default);
        }
        let scratch = &self.scratch.0;
        let results: Vec<Result<f64, MapError>> = self
            .particles
            .par_iter_mut()
            .zip(self.lls.par_iter_mut())
            .enumerate()
            .with_max_len(1)
            .map(|(i, (p, ll))| {
                if !first {
                    let (mut pose, l) = match_in_own_map(&p.map, model, points, &p.pose, search);
                    if let Some(j) = jitters.get(i) {
                        pose = Pose2::new(
                            pose.x_m + j[0],
                            pose.y_m + j[1],
                            wrap_angle(pose.yaw_rad + j[2]),
                        );
                    }
                    p.pose = pose;
                    *ll = l;
                }
                let t_map = Instant::now();
                let slot = rayon::current_thread_index().unwrap_or(0) % scratch.len();
                let mut guard = scratch[slot]
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                let (world, insert) = &mut *guard;
                to_world(body, &p.pose, world);
                p.map.insert_scan(world, insert)?;
                p.node = Arc::new(PathNode {
                    pose: p.pose,
                    odom,
                    scan,
                    parent: Some(p.node.clone()),
                });
                Ok(t_map.elapsed().as_secs_f64())
            })
            .collect();
        let elapsed = t.elapsed().as_secs_f64();
        // The first error in particle order.
        let mut map_thread_s = 0.0;
        for r in results {
            map_thread_s += r?;
        }
        // Wall times of the two parts: the pass's wall time split by the threads' time
        // spent mapping (an estimate: the parts now overlap).
        let map_s = (map_thread_s / threads as f64).min(elapsed);
        let match_s = elapsed - map_s;
        if first {
            return Ok(RbpfUpdate {
                neff: n as f64,
                resampled: false,
                best_ll_per_point: 0.0,
                match_s,
                map_s,
            });
        }
        weights::update_log_space(
            &mut self.weights,
            &self.lls,
            self.options.weight_temperature,
        );
        let neff = weights::neff(&self.weights);
        let best = self.best();
        let best_ll_per_point = self.lls[best] / points.len().max(1) as f64;
        let resampled = neff < self.options.resample_threshold * n as f64;
        if resampled {
            resample::resample(&self.weights, method, &mut self.master, &mut self.ancestors);
            let old = std::mem::take(&mut self.particles);
            self.particles = self.ancestors.iter().map(|&a| old[a].clone()).collect();
            self.weights.iter_mut().for_each(|w| *w = 1.0 / n as f64);
        }
        Ok(RbpfUpdate {
            neff,
            resampled,
            best_ll_per_point,
            match_s,
            map_s,
        })
    }

    /// Memory held by the particles' maps.
    pub fn map_memory(&self) -> MapMemory {
        let distinct = distinct_tiles(self.particles.iter().map(|p| &p.map));
        MapMemory {
            distinct_tiles: distinct,
            total_tiles: self.particles.iter().map(|p| p.map.tile_count()).sum(),
            distinct_bytes: distinct * crate::map::TILE_BYTES,
        }
    }
}

/// Runs the Rao-Blackwellised filter on `recording` (see the module docs).
pub fn run_rbpf(
    recording: &Recording,
    config: &Config,
    seed: u64,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<SlamResult, SlamError> {
    let opts = &config.filter;
    let ro = &opts.rbpf;
    let t_start = Instant::now();
    let (first, mut cursor) = super::slam::check_and_start(recording, config)?;
    let scans = &recording.scans;
    let total = scans.len();
    let start = cursor.current().pose;
    let mut map_opts = config.map.clone();
    if ro.resolution_m > 0.0 {
        map_opts.resolution_m = ro.resolution_m;
    }
    let grid = OccupancyGrid::new(&map_opts)?;
    let mut scan_opts = config.map.scan.for_filter();
    scan_opts.range_min_m = ro.range_min_m as f32;
    if !ro.densify {
        scan_opts.densify_max_gap_m = None;
    }
    scan_opts.validate().map_err(MapError::Options)?;
    let mut projector =
        ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &scan_opts)?;
    let mut stats = SlamStats {
        particles: opts.particles,
        mode: super::FilterMode::Rbpf,
        seed,
        scans_total: total,
        scans_skipped: first,
        neff_min: f64::INFINITY,
        ..SlamStats::default()
    };
    let mut pf = Rbpf::new(opts.particles, start, start, grid, ro, seed);
    let mut dead_reckoning: Vec<StampedPose2> = Vec::with_capacity(total - first);
    let mut scan_index: Vec<usize> = Vec::with_capacity(total - first);
    let mut body = PlanarScan::default();
    let mut pts: Vec<[f64; 2]> = Vec::new();
    let mut last_update_odom = start;
    let (mut neff_sum, mut ll_sum) = (0.0, 0.0);
    let angular = ro.angular_update_deg.to_radians();
    let mut have_first = false;
    for i in first..total {
        let stamp_ns = scans.stamps_ns[i];
        let Some(odom) = cursor.advance_to(stamp_ns, |_, _| {}) else {
            stats.scans_skipped += 1;
            continue;
        };
        let k = dead_reckoning.len();
        dead_reckoning.push(odom);
        scan_index.push(i);
        let delta = last_update_odom.between(&odom.pose);
        let due = !have_first
            || delta.translation_norm_m() >= ro.linear_update_m
            || delta.yaw_rad.abs() >= angular;
        if due {
            let t = Instant::now();
            projector.aim(recording, i);
            projector.to_body(scans.ranges(i), &mut body)?;
            clip_scan(&mut body, ro.range_max_m);
            match_points(&body, ro.range_max_m, ro.beam_decimation, &mut pts);
            stats.timings.preprocess_s += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let report = pf.update(
                k,
                odom.pose,
                &delta,
                &pts,
                &body,
                !have_first,
                opts.resample_method,
            )?;
            stats.timings.correlate_s += report.match_s;
            stats.timings.map_update_s += report.map_s;
            stats.timings.resample_s += t.elapsed().as_secs_f64() - report.match_s - report.map_s;
            if have_first {
                stats.updates += 1;
                neff_sum += report.neff;
                ll_sum += report.best_ll_per_point;
                stats.neff_min = stats.neff_min.min(report.neff);
                stats.neff_last = report.neff;
                stats.resamples += usize::from(report.resampled);
            }
            have_first = true;
            last_update_odom = odom.pose;
        }
        stats.scans_processed += 1;
        let done = i + 1;
        if super::slam::report_progress(observer, done, total, &stats, opts.snapshot_every_scans) {
            let best = &pf.particles[pf.best()];
            let trajectory = path_poses(&best.node, &dead_reckoning);
            observer(SlamEvent::Snapshot {
                scans_done: done,
                map: &best.map,
                trajectory: &trajectory,
            });
        }
    }
    stats.odometry_steps = dead_reckoning.len();
    stats.finish_means(neff_sum, ll_sum);
    let best = &pf.particles[pf.best()];
    let mut trajectory = path_poses(&best.node, &dead_reckoning);
    if ro.final_refine && recording.body_from_lidar_per_scan.is_none() {
        let t = Instant::now();
        refine_in_final_map(
            &mut trajectory,
            &scan_index,
            recording,
            &projector,
            &best.map,
            ro,
        )?;
        stats.timings.correlate_s += t.elapsed().as_secs_f64();
    }
    stats.timings.total_s = t_start.elapsed().as_secs_f64();
    stats.map_memory = Some(pf.map_memory());
    Ok(SlamResult {
        trajectory,
        dead_reckoning,
        map: best.map.clone(),
        stats,
    })
}

/// Re-matches every output pose against the final best map (hill climb only, with a tight
/// prior around the path's pose): the poses between updates come from odometry composed onto
/// the last node, and the odometry's yaw errs most while turning. In parallel over scans;
/// each result depends only on its scan, so any thread count gives the same output.
fn refine_in_final_map(
    trajectory: &mut [StampedPose2],
    scan_index: &[usize],
    recording: &Recording,
    projector: &ScanProjector,
    map: &OccupancyGrid,
    ro: &RbpfOptions,
) -> Result<(), MapError> {
    let res = map.limits().resolution_m();
    let model = ro.observation(res);
    let mut search = SearchParams::new(ro, res);
    search.yaw_offsets_rad = vec![0.0];
    search.xy_cells = 0;
    search.step_xy_m = 0.5 * ro.step_xy_m;
    search.step_yaw_rad = 0.5 * ro.step_yaw_deg.to_radians();
    search.prior = Some(MatchPrior {
        inv_var_xy: 1.0 / ro.refine_sigma_xy_m.powi(2),
        inv_var_yaw: 1.0 / ro.refine_sigma_yaw_deg.to_radians().powi(2),
    });
    trajectory
        .par_iter_mut()
        .zip(scan_index.par_iter())
        .try_for_each_init(
            || (projector.clone(), PlanarScan::default(), Vec::new()),
            |(projector, body, pts), (sp, &i)| {
                projector.aim(recording, i);
                projector.to_body(recording.scans.ranges(i), body)?;
                clip_scan(body, ro.range_max_m);
                match_points(body, ro.range_max_m, ro.beam_decimation, pts);
                if pts.len() >= 10 {
                    sp.pose = match_in_own_map(map, &model, pts, &sp.pose, &search).0;
                }
                Ok(())
            },
        )
}

/// Turns returns beyond `range_max_m` from the sensor into no-returns (they are neither
/// matched nor mapped: far returns carry more angular error than they help).
fn clip_scan(scan: &mut PlanarScan, range_max_m: f64) {
    let r2 = range_max_m * range_max_m;
    let (sx, sy) = (scan.sensor_x_m, scan.sensor_y_m);
    scan.points.retain(|p| {
        let (dx, dy) = (p.x_m - sx, p.y_m - sy);
        !p.hit || dx * dx + dy * dy <= r2
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(pose: Pose2, odom: Pose2, scan: usize, parent: &Arc<PathNode>) -> Arc<PathNode> {
        Arc::new(PathNode {
            pose,
            odom,
            scan,
            parent: Some(parent.clone()),
        })
    }

    #[test]
    fn output_path_is_the_survivors_history_with_odometry_between_nodes() {
        let o = |x: f64| Pose2::new(x, 0.0, 0.0);
        let root = Arc::new(PathNode {
            pose: o(0.0),
            odom: o(0.0),
            scan: 0,
            parent: None,
        });
        // Two particles branch at scan 2: A thinks it is at y = +1, B at y = -1.
        let a = node(Pose2::new(2.0, 1.0, 0.0), o(2.0), 2, &root);
        let b = node(Pose2::new(2.0, -1.0, 0.0), o(2.0), 2, &root);
        // Resampling keeps only B (two copies); they extend B's history.
        let b1 = node(Pose2::new(4.0, -1.0, 0.0), o(4.0), 4, &b);
        let b2 = node(Pose2::new(4.0, -1.2, 0.0), o(4.0), 4, &b);
        drop(a);
        let odometry: Vec<StampedPose2> = (0..6)
            .map(|k| StampedPose2 {
                stamp_ns: k as i64,
                pose: o(k as f64),
            })
            .collect();
        let path = path_poses(&b2, &odometry);
        let ys: Vec<f64> = path.iter().map(|p| p.pose.y_m).collect();
        let xs: Vec<f64> = path.iter().map(|p| p.pose.x_m).collect();
        assert_eq!(ys, vec![0.0, 0.0, -1.0, -1.0, -1.2, -1.2]);
        assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!(path_poses(&b1, &odometry)[5].pose.y_m, -1.0);
        assert_eq!(ancestry(&b2).len(), 3);
    }

    #[test]
    fn dropping_a_long_path_does_not_recurse() {
        let mut leaf = Arc::new(PathNode {
            pose: Pose2::IDENTITY,
            odom: Pose2::IDENTITY,
            scan: 0,
            parent: None,
        });
        for k in 1..1_000_000 {
            leaf = node(Pose2::IDENTITY, Pose2::IDENTITY, k, &leaf);
        }
        drop(leaf);
    }

    /// The observation model written plainly (the kernel before it was optimised).
    fn scan_log_likelihood_plain(
        grid: &OccupancyGrid,
        model: &ObservationModel,
        points: &[[f64; 2]],
        pose: &Pose2,
    ) -> f64 {
        let (s, c) = pose.yaw_rad.sin_cos();
        let k = model.kernel;
        let mut total = 0.0;
        for p in points {
            let x = pose.x_m + c * p[0] - s * p[1];
            let y = pose.y_m + s * p[0] + c * p[1];
            let (u, v) = grid.limits().cell_coords(x, y);
            let (i, j) = (u.floor() as i32, v.floor() as i32);
            let mut best = f64::INFINITY;
            for dj in -k..=k {
                let dv = v - (f64::from(j + dj) + 0.5);
                for di in -k..=k {
                    if grid.logodds_fixed(Cell::new(i + di, j + dj)) > model.occupied_fixed {
                        let du = u - (f64::from(i + di) + 0.5);
                        best = best.min(du * du + dv * dv);
                    }
                }
            }
            total += if best.is_finite() {
                (-best * model.res2_over_2s2).max(model.no_hit)
            } else {
                model.no_hit
            };
        }
        total
    }

    #[test]
    fn optimised_likelihood_equals_the_plain_rule_bit_for_bit() {
        use crate::map::{MapOptions, ScanPoint};
        use rand::SeedableRng;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let mut uni = |a: f64, b: f64| a + (b - a) * rng.random::<f64>();
        for trial in 0..12 {
            let res = [0.05, 0.1, 0.03][trial % 3];
            let mut grid = OccupancyGrid::new(&MapOptions {
                resolution_m: res,
                ..MapOptions::default()
            })
            .unwrap();
            // Random walls seen from a few poses: occupied, free and unwritten cells, tile
            // borders crossed everywhere.
            let mut scratch = InsertScratch::new();
            for _ in 0..4 {
                let (sx, sy) = (uni(-2.0, 2.0), uni(-2.0, 2.0));
                let points = (0..120)
                    .map(|_| {
                        let (a, r) = (uni(-3.2, 3.2), uni(0.5, 6.0));
                        ScanPoint {
                            x_m: sx + r * a.cos(),
                            y_m: sy + r * a.sin(),
                            hit: uni(0.0, 1.0) < 0.9,
                            free_to: 1.0,
                            z_m: 0.0,
                        }
                    })
                    .collect();
                let scan = PlanarScan {
                    sensor_x_m: sx,
                    sensor_y_m: sy,
                    sensor_z_m: None,
                    points,
                };
                grid.insert_scan(&scan, &mut scratch).unwrap();
            }
            let mut body: Vec<[f64; 2]> =
                (0..200).map(|_| [uni(-7.0, 7.0), uni(-7.0, 7.0)]).collect();
            // Points ~5e7 m out: beyond 2^30 cells at 0.03 m, where the chunks holding them
            // take the scalar floor (the vector floor's range ends there), and inside the i32
            // range at every resolution here (so `i + di` cannot overflow).
            for (at, far) in [(37, [5e7, 1.0]), (38, [-2.0, -5e7]), (121, [-3.5e7, 3.5e7])] {
                body.insert(at, far);
            }
            for kernel in [0, 1, 2] {
                for occupied_logodds in [0.0, -0.5, 0.7] {
                    let o = RbpfOptions {
                        kernel_cells: kernel,
                        occupied_logodds,
                        ..RbpfOptions::default()
                    };
                    let model = o.observation(res);
                    for _ in 0..10 {
                        let pose = Pose2::new(uni(-1.0, 1.0), uni(-1.0, 1.0), uni(-3.2, 3.2));
                        let fast = scan_log_likelihood(&grid, &model, &body, &pose);
                        let plain = scan_log_likelihood_plain(&grid, &model, &body, &pose);
                        assert_eq!(fast.to_bits(), plain.to_bits(), "{trial} {kernel} {pose:?}");
                        // The path taken without AVX2, whatever this machine has.
                        let scalar = likelihood_scalar(&grid, &model, &body, &pose, None);
                        assert_eq!(
                            scalar.to_bits(),
                            plain.to_bits(),
                            "{trial} {kernel} {pose:?}"
                        );
                    }
                }
            }
        }
    }

    /// The matcher without the early stop and the memo of evaluated poses: every candidate
    /// fully evaluated, only the pose just left skipped, the weight recomputed.
    fn match_in_own_map_plain(
        grid: &OccupancyGrid,
        model: &ObservationModel,
        points: &[[f64; 2]],
        start: &Pose2,
        search: &SearchParams,
    ) -> (Pose2, f64) {
        let prior = search.prior;
        let eval = |p: &Pose2| {
            let ll = scan_log_likelihood_plain(grid, model, points, p);
            match prior {
                Some(pr) => {
                    let (dx, dy) = (p.x_m - start.x_m, p.y_m - start.y_m);
                    let da = wrap_angle(p.yaw_rad - start.yaw_rad);
                    ll - 0.5 * ((dx * dx + dy * dy) * pr.inv_var_xy + da * da * pr.inv_var_yaw)
                }
                None => ll,
            }
        };
        let mut best = *start;
        let mut best_ll = eval(&best);
        let r = search.xy_cells;
        for &dyaw in &search.yaw_offsets_rad {
            for oy in -r..=r {
                for ox in -r..=r {
                    if dyaw == 0.0 && ox == 0 && oy == 0 {
                        continue;
                    }
                    let cand = Pose2::new(
                        start.x_m + f64::from(ox) * search.resolution_m,
                        start.y_m + f64::from(oy) * search.resolution_m,
                        start.yaw_rad + dyaw,
                    );
                    let ll = eval(&cand);
                    if ll > best_ll {
                        best_ll = ll;
                        best = cand;
                    }
                }
            }
        }
        let (mut sxy, mut syaw) = (search.step_xy_m, search.step_yaw_rad);
        let (mut level, mut iterations) = (0, 0);
        while level < search.refine_levels && iterations < 200 {
            iterations += 1;
            let mut moved: Option<(Pose2, f64)> = None;
            for (ex, ey, ea) in [
                (sxy, 0.0, 0.0),
                (-sxy, 0.0, 0.0),
                (0.0, sxy, 0.0),
                (0.0, -sxy, 0.0),
                (0.0, 0.0, syaw),
                (0.0, 0.0, -syaw),
            ] {
                let cand = Pose2::new(best.x_m + ex, best.y_m + ey, best.yaw_rad + ea);
                let ll = eval(&cand);
                if ll > moved.map_or(best_ll, |m| m.1) {
                    moved = Some((cand, ll));
                }
            }
            match moved {
                Some((p, ll)) => {
                    best = p;
                    best_ll = ll;
                }
                None => {
                    sxy *= 0.5;
                    syaw *= 0.5;
                    level += 1;
                }
            }
        }
        best.yaw_rad = wrap_angle(best.yaw_rad);
        let ll = if prior.is_some() {
            scan_log_likelihood_plain(grid, model, points, &best)
        } else {
            best_ll
        };
        (best, ll)
    }

    #[test]
    fn matcher_with_early_stops_equals_the_plain_climb_bit_for_bit() {
        use crate::map::{MapOptions, ScanPoint};
        use rand::SeedableRng;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let mut uni = |a: f64, b: f64| a + (b - a) * rng.random::<f64>();
        let mut grid = OccupancyGrid::new(&MapOptions {
            resolution_m: 0.05,
            ..MapOptions::default()
        })
        .unwrap();
        // Walls of a room and a few posts, seen from its middle.
        let mut wall: Vec<[f64; 2]> = Vec::new();
        for k in 0..160 {
            let t = f64::from(k) * 0.05 - 4.0;
            wall.extend([[t, 3.0], [t, -2.5], [4.0, 0.7 * t], [-4.0, 0.6 * t]]);
        }
        for k in 0..24 {
            let a = f64::from(k) * 15f64.to_radians();
            wall.extend([
                [1.0 + 0.2 * a.cos(), 1.0 + 0.2 * a.sin()],
                [-2.0 + 0.3 * a.cos(), -1.0 + 0.15 * a.sin()],
            ]);
        }
        let scan = PlanarScan {
            sensor_x_m: 0.0,
            sensor_y_m: 0.0,
            sensor_z_m: None,
            points: wall
                .iter()
                .map(|p| ScanPoint {
                    x_m: p[0],
                    y_m: p[1],
                    hit: true,
                    free_to: 1.0,
                    z_m: 0.0,
                })
                .collect(),
        };
        grid.insert_scan(&scan, &mut InsertScratch::new()).unwrap();
        let body: Vec<[f64; 2]> = wall.iter().step_by(3).copied().collect();
        let o = RbpfOptions::default();
        let model = o.observation(0.05);
        let mut checked = 0;
        for trial in 0..60 {
            let mut search = SearchParams::new(&o, 0.05);
            search.xy_cells = (trial % 3) / 2;
            search.prior = (trial % 4 != 0).then(|| MatchPrior {
                inv_var_xy: 1.0 / uni(0.01, 0.2).powi(2),
                inv_var_yaw: 1.0 / uni(0.01, 0.1).powi(2),
            });
            // Starts off the truth, some near +-pi (the climb wraps the yaw).
            let yaw = if trial % 5 == 0 {
                std::f64::consts::PI - uni(0.0, 0.03)
            } else {
                uni(-0.08, 0.08)
            };
            let start = Pose2::new(uni(-0.15, 0.15), uni(-0.15, 0.15), yaw);
            let (fast, ll) = match_in_own_map(&grid, &model, &body, &start, &search);
            let (plain, plain_ll) = match_in_own_map_plain(&grid, &model, &body, &start, &search);
            let b = |p: &Pose2| [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits);
            assert_eq!(b(&fast), b(&plain), "{trial} {start:?}");
            assert_eq!(ll.to_bits(), plain_ll.to_bits(), "{trial}");
            checked += usize::from(b(&fast) != b(&start));
        }
        // Most searches moved away from their start.
        assert!(checked > 40, "{checked}");
    }

    #[test]
    fn likelihood_peaks_at_the_true_pose_and_the_matcher_finds_it() {
        use crate::map::{MapOptions, ScanPoint};
        let mut grid = OccupancyGrid::new(&MapOptions {
            resolution_m: 0.05,
            ..MapOptions::default()
        })
        .unwrap();
        // An L-shaped room corner (walls through cell centres) plus a pillar.
        let mut points = Vec::new();
        for k in 0..200 {
            let t = f64::from(k) * 0.05 - 5.0;
            points.push([t, 3.025]);
            points.push([4.025, t]);
        }
        for k in 0..36 {
            let a = f64::from(k) * 10f64.to_radians();
            points.push([1.5 + 0.3 * a.cos(), -1.0 + 0.3 * a.sin()]);
        }
        let scan = PlanarScan {
            sensor_x_m: 0.0,
            sensor_y_m: 0.0,
            sensor_z_m: None,
            points: points
                .iter()
                .map(|p| ScanPoint {
                    x_m: p[0],
                    y_m: p[1],
                    hit: true,
                    free_to: 1.0,
                    z_m: 0.0,
                })
                .collect(),
        };
        grid.insert_scan(&scan, &mut InsertScratch::new()).unwrap();
        let o = RbpfOptions::default();
        let model = o.observation(0.05);
        let search = SearchParams::new(&o, 0.05);
        let at_truth = scan_log_likelihood(&grid, &model, &points, &Pose2::IDENTITY);
        let off = scan_log_likelihood(&grid, &model, &points, &Pose2::new(0.1, 0.0, 0.0));
        assert!(at_truth > off, "{at_truth} {off}");
        for start in [
            Pose2::new(0.04, -0.03, 2f64.to_radians()),
            Pose2::new(-0.05, 0.04, -2.5f64.to_radians()),
        ] {
            let (pose, _) = match_in_own_map(&grid, &model, &points, &start, &search);
            assert!(pose.translation_norm_m() < 0.02, "{pose:?} from {start:?}");
            assert!(pose.yaw_rad.abs() < 0.3f64.to_radians(), "{pose:?}");
        }
    }
}
