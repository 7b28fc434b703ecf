//! [`super::scan_log_likelihood_above`] for the 3x3 kernel in AVX2, four points at a time.

use super::{Bar, ObservationModel, TileGrid};
use super::{MASK, Projected, TS, TileCache, point_best, point_term, project_scalar};
use crate::geometry::Pose2;
use crate::geometry::cells::{MapLimits, floor_to_i32};
use crate::kernels::nearest::x86::nearest_3x3_avx2;
use crate::kernels::{TILE_SHIFT, TILE_SIZE};

/// [`super::scan_log_likelihood_above`] for the 3x3 kernel in AVX2, four points at a time:
/// projected ([`project4_avx2`]), their kernel rows gathered ([`gather4_avx2`]), their
/// minima taken across lanes ([`nearest4_avx2`]); then the sum in point order, the bar
/// tested after each point. The same bits. (Issuing the next four's gathers before this
/// four's minima measured no faster.)
#[target_feature(enable = "avx2")]
pub(super) fn likelihood_avx2<G: TileGrid + ?Sized>(
    grid: &G,
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

/// Four points' continuous cell coordinates and, where every lane is finite and under
/// 2^30 cells (the vector floor's exact range), their cells.
struct Projected4 {
    u: std::arch::x86_64::__m256d,
    v: std::arch::x86_64::__m256d,
    cells: Option<(std::arch::x86_64::__m128i, std::arch::x86_64::__m128i)>,
}

/// [`project_scalar`] four points at a time in AVX2: the same operations in the same order
/// per lane (no fused multiply-add), so the same bits; the floor in vector form where every
/// lane is finite and well inside the `i32` range (else none: the caller takes the scalar,
/// saturating one).
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
static NEVER_OCCUPIED: [i16; 2 * TILE_SIZE + 4] = [i16::MIN; 2 * TILE_SIZE + 4];

/// Four projected points with their kernels' rows gathered ([`gather4_avx2`]).
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
#[target_feature(enable = "avx2")]
#[inline]
fn gather4_avx2<'a, G: TileGrid + ?Sized>(
    grid: &'a G,
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

/// The 3x3 kernel's minimum ([`nearest_3x3`](crate::kernels::nearest::nearest_3x3)) of four gathered points at once: per row a
/// compare, and per cell a select and a minimum across the four lanes. The candidates are
/// the scalar rule's (`du^2 + dv^2` from the same products), and the minimum of finite
/// values does not depend on their order: the same bits. Points marked scalar take
/// [`point_best`].
#[target_feature(enable = "avx2")]
#[inline]
fn nearest4_avx2<'a, G: TileGrid + ?Sized>(
    grid: &'a G,
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
