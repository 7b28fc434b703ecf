//! The cells of a scan's points at one heading and their exact sums over a level of a
//! [`PointField`] (portable and AVX2, the same bits): the scores of the grid searches.

use super::{PointField, SearchWindow, floor_to_i64};
use crate::geometry::Pose2;

/// The cells of a scan's points at one heading ([`PointField::cells_at`]), as two columns.
/// Stored in `i32`, clamped to `+-CELL_CLAMP`: a clamped cell lies outside any window (at
/// most 2^14 cells a side) for any offset under 2^29 cells, as the cell it stands for
/// (search windows are at most 10 m, 10^3 cells at 0.01 m).
#[derive(Debug, Clone, Default)]
pub(super) struct PointCells {
    pub(super) x: Vec<i32>,
    pub(super) y: Vec<i32>,
}

/// See [`PointCells`].
const CELL_CLAMP: i64 = 1 << 30;

impl PointField {
    /// Cells of the points seen from `centre`'s position with heading `yaw`.
    pub(super) fn cells_at(
        &self,
        points_body: &[[f64; 2]],
        centre: &Pose2,
        yaw: f64,
    ) -> PointCells {
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

    pub(super) fn window_yaws(centre: &Pose2, win: &SearchWindow) -> Vec<f64> {
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
    pub(super) fn cell_sum(&self, cells: &PointCells, level: usize, dx: i64, dy: i64) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if cells.x.len() <= 1 << 22 && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked above).
            return unsafe { self.cell_sum_avx2(cells, level, dx, dy) };
        }
        self.cell_sum_scalar((&cells.x, &cells.y), level, dx, dy)
    }

    /// [`Self::cell_sum`] a point at a time, in point order, over the columns `(x, y)`.
    pub(super) fn cell_sum_scalar(
        &self,
        (xs, ys): (&[i32], &[i32]),
        level: usize,
        dx: i64,
        dy: i64,
    ) -> f64 {
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
}
