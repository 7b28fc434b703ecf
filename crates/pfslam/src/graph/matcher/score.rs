//! The interpolated score of a scan in a [`PointField`] (bilinear between cell centres,
//! several poses per pass, with an AVX2 twin giving the same bits) and the curvature of
//! the match objective.

use super::{PointField, floor_to_i64};
use crate::filter::scanmatch::{LANES, mix_lanes};
use crate::geometry::Pose2;
use rayon::prelude::*;

/// Poses scored in one pass by the refinement (a pattern-search iteration's candidates).
pub(super) const PASS: usize = 6;

impl PointField {
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
    pub(super) fn score_rotated(
        &self,
        points_body: &[[f64; 2]],
        pose: &Pose2,
        s: f64,
        c: f64,
    ) -> f64 {
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
    pub(super) fn scores_batched(
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
}
