//! A scan rotated for one yaw, in f64, and the field sums over it (AVX2 kernels with
//! portable twins), plus the lane helpers shared with the back end's matcher.

use super::*;
use crate::geometry::Pose2;
use crate::map::MapLimits;

/// Body-frame points rotated by one yaw: `(c x, s y, s x, c y)` per point, whole blocks of
/// [`LANES`] points lane-wise (so a vector kernel loads each product of a block at once),
/// the last `n % LANES` points apart.
#[derive(Debug, Clone, Default)]
pub(super) struct Rotation {
    blocks: Vec<[[f64; LANES]; 4]>,
    tail: Vec<[f64; 4]>,
}

impl Rotation {
    pub(super) fn fill(&mut self, points_body: &[[f64; 2]], s: f64, c: f64) {
        let rot = |p: &[f64; 2]| [c * p[0], s * p[1], s * p[0], c * p[1]];
        let chunks = points_body.chunks_exact(LANES);
        self.tail.clear();
        self.tail.extend(chunks.remainder().iter().map(rot));
        self.blocks.clear();
        self.blocks.extend(chunks.map(|quad| {
            let mut b = [[0.0; LANES]; 4];
            for (k, p) in quad.iter().enumerate() {
                for (lane, r) in b.iter_mut().zip(rot(p)) {
                    lane[k] = r;
                }
            }
            b
        }));
    }

    /// Sums of bilinear field values of the points seen from `at[k]` (x m, y m) with the
    /// rotation `rots[k]`, `K` candidates in one pass over the points: per point
    /// `x_m + c * p[0] - s * p[1]` evaluated left to right as written, then `cell_coords`
    /// and `bilinear`; summed left to right from -0.0 (as `Iterator::sum`). Each candidate
    /// has its own accumulator and adds its own values in its own order, so each result is
    /// the bits of the candidate summed alone (`K = 1`); the independent chains of
    /// additions can overlap. The rotations hold the same points (of different yaws, or one
    /// rotation repeated).
    pub(super) fn sums<const K: usize>(
        rots: [&Rotation; K],
        at: [[f64; 2]; K],
        field: &LikelihoodField,
        limits: &MapLimits,
    ) -> [f64; K] {
        #[cfg(target_arch = "x86_64")]
        if field.vector_ok() && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked above).
            return unsafe { Rotation::sums_avx2(rots, at, field, limits) };
        }
        Rotation::sums_portable(rots, at, field, limits)
    }

    /// Whole blocks every rotation of a batch has (all the same: they rotate the same
    /// points; the minimum keeps a mismatch from indexing out of bounds).
    pub(super) fn common_blocks(rots: &[&Rotation]) -> usize {
        debug_assert!(rots.iter().all(|r| {
            r.blocks.len() == rots[0].blocks.len() && r.tail.len() == rots[0].tail.len()
        }));
        rots.iter().map(|r| r.blocks.len()).min().unwrap_or(0)
    }

    pub(super) fn sums_portable<const K: usize>(
        rots: [&Rotation; K],
        at: [[f64; 2]; K],
        field: &LikelihoodField,
        limits: &MapLimits,
    ) -> [f64; K] {
        let mut sums = [-0.0; K];
        let mut values = [[0.0; LANES]; K];
        for b in 0..Rotation::common_blocks(&rots) {
            for k in 0..K {
                let [r0, r1, r2, r3] = &rots[k].blocks[b];
                let [x_m, y_m] = at[k];
                // Per lane the same operations in the same order as `sum_tail`.
                let mut u = [0.0; LANES];
                let mut v = [0.0; LANES];
                for l in 0..LANES {
                    (u[l], v[l]) = limits.cell_coords(x_m + r0[l] - r1[l], y_m + r2[l] + r3[l]);
                }
                values[k] = field.bilinear_lanes(&u, &v);
            }
            for (sum, values) in sums.iter_mut().zip(&values) {
                for value in values {
                    *sum += value;
                }
            }
        }
        std::array::from_fn(|k| rots[k].sum_tail(field, limits, at[k][0], at[k][1], sums[k]))
    }

    /// The single-candidate portable sum, written plainly (no batching):
    /// the reference the batched ones must equal.
    #[cfg(test)]
    pub(super) fn sum_portable(
        &self,
        field: &LikelihoodField,
        limits: &MapLimits,
        x_m: f64,
        y_m: f64,
    ) -> f64 {
        let mut sum = -0.0;
        for [r0, r1, r2, r3] in &self.blocks {
            let mut u = [0.0; LANES];
            let mut v = [0.0; LANES];
            for k in 0..LANES {
                (u[k], v[k]) = limits.cell_coords(x_m + r0[k] - r1[k], y_m + r2[k] + r3[k]);
            }
            for b in field.bilinear_lanes(&u, &v) {
                sum += b;
            }
        }
        self.sum_tail(field, limits, x_m, y_m, sum)
    }

    /// The AVX2 kernel for one candidate.
    #[cfg(all(test, target_arch = "x86_64"))]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sum_avx2(
        &self,
        field: &LikelihoodField,
        limits: &MapLimits,
        x_m: f64,
        y_m: f64,
    ) -> f64 {
        // SAFETY: the caller guarantees AVX2.
        let [sum] = unsafe { Rotation::sums_avx2([self], [[x_m, y_m]], field, limits) };
        sum
    }

    pub(super) fn sum_tail(
        &self,
        field: &LikelihoodField,
        limits: &MapLimits,
        x_m: f64,
        y_m: f64,
        mut sum: f64,
    ) -> f64 {
        for r in &self.tail {
            let (u, v) = limits.cell_coords(x_m + r[0] - r[1], y_m + r[2] + r[3]);
            sum += field.bilinear(u, v);
        }
        sum
    }

    /// [`Self::sums_portable`] in AVX2: the same IEEE operations per lane (no FMA: Rust
    /// never contracts), so the same bits; the four corner bytes of a point come from two
    /// scalar u16 loads (two 4-lane 32-bit gathers before: ~10 % slower on this Zen 4).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sums_avx2<const K: usize>(
        rots: [&Rotation; K],
        at: [[f64; 2]; K],
        field: &LikelihoodField,
        limits: &MapLimits,
    ) -> [f64; K] {
        use std::arch::x86_64::*;
        let (ox, oy) = (limits.origin_x_m(), limits.origin_y_m());
        // The same division `MapLimits::new` caches for `cell_coords`: the same bits.
        let inv = 1.0 / limits.resolution_m();
        let (vox, voy, vinv) = (_mm256_set1_pd(ox), _mm256_set1_pd(oy), _mm256_set1_pd(inv));
        let half = _mm256_set1_pd(0.5);
        let one = _mm256_set1_pd(1.0);
        let lim = _mm256_set1_pd(1e9);
        let sign = _mm256_set1_pd(-0.0);
        let (i0, j0) = (_mm_set1_epi32(field.i0), _mm_set1_epi32(field.j0));
        // `vector_ok` guarantees these fit in i32.
        let (w, h) = (field.w as i32, field.h as i32);
        let (vw, wm1, hm1) = (
            _mm_set1_epi32(w),
            _mm_set1_epi32(w - 1),
            _mm_set1_epi32(h - 1),
        );
        let minus1 = _mm_set1_epi32(-1);
        let byte = _mm_set1_epi32(0xff);
        let base = field.values.as_ptr();
        let fw = field.w;
        let vx: [__m256d; K] = std::array::from_fn(|k| _mm256_set1_pd(at[k][0]));
        let vy: [__m256d; K] = std::array::from_fn(|k| _mm256_set1_pd(at[k][1]));
        let mut sums = [-0.0; K];
        let mut values = [[0.0; LANES]; K];
        for b in 0..Rotation::common_blocks(&rots) {
            for k in 0..K {
                let [r0, r1, r2, r3] = &rots[k].blocks[b];
                // SAFETY: unaligned loads of whole `[f64; 4]` arrays.
                let (r0, r1, r2, r3) = unsafe {
                    (
                        _mm256_loadu_pd(r0.as_ptr()),
                        _mm256_loadu_pd(r1.as_ptr()),
                        _mm256_loadu_pd(r2.as_ptr()),
                        _mm256_loadu_pd(r3.as_ptr()),
                    )
                };
                let wx = _mm256_sub_pd(_mm256_add_pd(vx[k], r0), r1);
                let wy = _mm256_add_pd(_mm256_add_pd(vy[k], r2), r3);
                let u = _mm256_mul_pd(_mm256_sub_pd(wx, vox), vinv);
                let v = _mm256_mul_pd(_mm256_sub_pd(wy, voy), vinv);
                let x = _mm256_sub_pd(u, half);
                let y = _mm256_sub_pd(v, half);
                let ok = _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, x), lim),
                    _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, y), lim),
                );
                let out = if _mm256_movemask_pd(ok) != 0xf {
                    // A lane beyond the fast path's range (or NaN): the scalar path per lane.
                    let mut ua = [0.0; LANES];
                    let mut va = [0.0; LANES];
                    // SAFETY: stores into local arrays.
                    unsafe {
                        _mm256_storeu_pd(ua.as_mut_ptr(), u);
                        _mm256_storeu_pd(va.as_mut_ptr(), v);
                    }
                    std::array::from_fn(|l| field.bilinear(ua[l], va[l]))
                } else {
                    // `floor_to_i32` as a float: the same value (the lanes are finite and
                    // within 1e9; `x`, `y` are never -0.0, as `u - 0.5` cannot be).
                    let fx = _mm256_floor_pd(x);
                    let fy = _mm256_floor_pd(y);
                    let ax = _mm256_sub_pd(x, fx);
                    let ay = _mm256_sub_pd(y, fy);
                    let (i, j) = (_mm256_cvttpd_epi32(fx), _mm256_cvttpd_epi32(fy));
                    let (li, lj) = (_mm_sub_epi32(i, i0), _mm_sub_epi32(j, j0));
                    let inside = _mm_and_si128(
                        _mm_and_si128(_mm_cmpgt_epi32(li, minus1), _mm_cmpgt_epi32(wm1, li)),
                        _mm_and_si128(_mm_cmpgt_epi32(lj, minus1), _mm_cmpgt_epi32(hm1, lj)),
                    );
                    let (f00, f10, f01, f11) = if _mm_movemask_ps(_mm_castsi128_ps(inside)) == 0xf {
                        let k = _mm_add_epi32(_mm_mullo_epi32(lj, vw), li);
                        // Per point the two corner pairs as scalar u16 loads, packed
                        // `f00 f10 f01 f11` into one 32-bit lane (on this Zen, cheaper
                        // than two 4-lane gathers).
                        // SAFETY: all four corners lie inside the window (checked above).
                        let d = unsafe {
                            _mm_setr_epi32(
                                corner_pairs(base, _mm_extract_epi32::<0>(k), fw),
                                corner_pairs(base, _mm_extract_epi32::<1>(k), fw),
                                corner_pairs(base, _mm_extract_epi32::<2>(k), fw),
                                corner_pairs(base, _mm_extract_epi32::<3>(k), fw),
                            )
                        };
                        let byte_at = |d| _mm256_cvtepi32_pd(_mm_and_si128(d, byte));
                        (
                            byte_at(d),
                            byte_at(_mm_srli_epi32::<8>(d)),
                            byte_at(_mm_srli_epi32::<16>(d)),
                            _mm256_cvtepi32_pd(_mm_srli_epi32::<24>(d)),
                        )
                    } else {
                        // A corner outside the window: `corners`' slow path per lane.
                        let mut ia = [0i32; LANES];
                        let mut ja = [0i32; LANES];
                        // SAFETY: stores into local arrays.
                        unsafe {
                            _mm_storeu_si128(ia.as_mut_ptr().cast(), i);
                            _mm_storeu_si128(ja.as_mut_ptr().cast(), j);
                        }
                        let f: [[f64; 4]; LANES] =
                            std::array::from_fn(|l| field.corners(ia[l], ja[l]));
                        let col = |c: usize| _mm256_setr_pd(f[0][c], f[1][c], f[2][c], f[3][c]);
                        (col(0), col(1), col(2), col(3))
                    };
                    // `f00 * (1 - ax) + f10 * ax` etc., as `mix_lanes`.
                    let omx = _mm256_sub_pd(one, ax);
                    let bottom = _mm256_add_pd(_mm256_mul_pd(f00, omx), _mm256_mul_pd(f10, ax));
                    let top = _mm256_add_pd(_mm256_mul_pd(f01, omx), _mm256_mul_pd(f11, ax));
                    let mixed = _mm256_add_pd(
                        _mm256_mul_pd(bottom, _mm256_sub_pd(one, ay)),
                        _mm256_mul_pd(top, ay),
                    );
                    let mut out = [0.0; LANES];
                    // SAFETY: a store into a local array.
                    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), mixed) };
                    out
                };
                values[k] = out;
            }
            // Apart from the loop above (which stays a loop): unrolled, so that the
            // accumulators stay in registers and the chains overlap.
            for (sum, values) in sums.iter_mut().zip(&values) {
                for value in values {
                    *sum += value;
                }
            }
        }
        std::array::from_fn(|k| rots[k].sum_tail(field, limits, at[k][0], at[k][1], sums[k]))
    }
}

/// The field bytes at `k`, `k + 1` (low half) and `k + w`, `k + w + 1` (high half) as one
/// little-endian 32-bit value.
///
/// # Safety
/// `base + k + w + 1` lies inside the field's values (`k` non-negative).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) unsafe fn corner_pairs(base: *const u8, k: i32, w: usize) -> i32 {
    let k = k as usize;
    // SAFETY: the caller guarantees both 2-byte reads lie inside the values.
    let (row0, row1) = unsafe {
        (
            base.add(k).cast::<u16>().read_unaligned(),
            base.add(k + w).cast::<u16>().read_unaligned(),
        )
    };
    (u32::from(row0) | (u32::from(row1) << 16)) as i32
}

/// The sums of [`Rotation::sums`] for any number of candidates (`rots[i]` seen from
/// `at[i]`, into `out[i]`), [`NEIGHBOURS`] per pass at most.
pub(super) fn sums_batched(
    rots: &[&Rotation],
    at: &[[f64; 2]],
    field: &LikelihoodField,
    limits: &MapLimits,
    out: &mut [f64],
) {
    let chunks = rots.chunks(NEIGHBOURS).zip(at.chunks(NEIGHBOURS));
    for ((r, a), o) in chunks.zip(out.chunks_mut(NEIGHBOURS)) {
        by_count!(r.len().min(a.len()).min(o.len()), K => {
            let sums = Rotation::sums::<K>(
                std::array::from_fn(|i| r[i]),
                std::array::from_fn(|i| a[i]),
                field,
                limits,
            );
            o.copy_from_slice(&sums);
        });
    }
}

/// Runs `$body` with the const `$k` = `$n` (1..=6; larger counts as 6): a batched kernel's
/// candidate count as a const generic.
macro_rules! by_count {
    ($n:expr, $k:ident => $body:block) => {
        match $n {
            1 => {
                const $k: usize = 1;
                $body
            }
            2 => {
                const $k: usize = 2;
                $body
            }
            3 => {
                const $k: usize = 3;
                $body
            }
            4 => {
                const $k: usize = 4;
                $body
            }
            5 => {
                const $k: usize = 5;
                $body
            }
            _ => {
                const $k: usize = 6;
                $body
            }
        }
    };
}
pub(crate) use by_count;

/// Caller-owned buffers of [`RotatedPoints`].
#[derive(Debug, Clone, Default)]
pub(super) struct RotationBuffers {
    kept: Rotation,
    once: [Rotation; 2],
    kept32: RotationF32,
    once32: [RotationF32; 2],
}

/// The rotation the refinement's x/y moves reuse (`kept`, of the yaw `yaw_bits`) and two
/// scratch ones for one-off yaws (a pattern-search iteration's two yaw candidates, summed
/// in the same pass as its x/y moves), of the yaws `once_bits`. All are kept across calls
/// (for the same points, as the refinement makes them): after an x/y move the next
/// iteration tries the same two yaws, and after a yaw move its x/y moves use a yaw a
/// one-off buffer holds.
pub(super) struct RotatedPoints {
    yaw_bits: Option<u64>,
    once_bits: [Option<u64>; 2],
    buf: RotationBuffers,
    /// Sum with the f32 kernel ([`KernelPrecision::F32`]).
    f32: bool,
}

impl RotatedPoints {
    pub(super) fn take(buf: &mut RotationBuffers, precision: KernelPrecision) -> Self {
        RotatedPoints {
            yaw_bits: None,
            once_bits: [None; 2],
            buf: std::mem::take(buf),
            f32: precision == KernelPrecision::F32,
        }
    }

    pub(super) fn give_back(self, buf: &mut RotationBuffers) {
        *buf = self.buf;
    }

    /// Sum of bilinear field values of `points_body` seen from `pose` (see
    /// [`Rotation::sums`]). `keep`: cache this yaw's rotation (the yaw the x/y moves will
    /// reuse).
    pub(super) fn field_sum(
        &mut self,
        field: &LikelihoodField,
        limits: &MapLimits,
        points_body: &[[f64; 2]],
        pose: &Pose2,
        keep: bool,
    ) -> f64 {
        let mut sum = [0.0];
        self.field_sums(field, limits, points_body, &[(*pose, keep)], &mut sum);
        sum[0]
    }

    /// [`Self::field_sum`] of several candidates (pose, `keep`) into `sums`, in as few
    /// passes over the points as the rotation buffers allow: a candidate's sum is a pure
    /// function of its pose (its rotation depends on the yaw's bits only), so each is the
    /// bits of its own [`Self::field_sum`].
    pub(super) fn field_sums(
        &mut self,
        field: &LikelihoodField,
        limits: &MapLimits,
        points_body: &[[f64; 2]],
        cands: &[(Pose2, bool)],
        sums: &mut [f64],
    ) {
        // The f32 kernel's window-relative coordinates need sides below its bound.
        let f32 = self.f32 && field.f32_ok();
        let inv_res = 1.0 / limits.resolution_m();
        let fill = |rot: &mut Rotation, rot32: &mut RotationF32, yaw: f64| {
            let (s, c) = yaw.sin_cos();
            if f32 {
                rot32.fill(points_body, s, c, inv_res);
            } else {
                rot.fill(points_body, s, c);
            }
        };
        let mut start = 0;
        while start < cands.len().min(sums.len()) {
            // One pass: candidates while a rotation buffer is free for their yaw. Slot 0
            // is `kept`, 1 and 2 the one-off buffers; a buffer is refilled only before this
            // pass uses it.
            let mut slot = [0usize; NEIGHBOURS];
            let mut once_used = [false; 2];
            let mut kept_used = false;
            let mut end = start;
            while end < cands.len().min(sums.len()) && end - start < NEIGHBOURS {
                let (pose, keep) = &cands[end];
                let bits = pose.yaw_rad.to_bits();
                slot[end - start] = if self.yaw_bits == Some(bits) {
                    kept_used = true;
                    0
                } else if let Some(k) = self.once_bits.iter().position(|&b| b == Some(bits)) {
                    once_used[k] = true;
                    k + 1
                } else if *keep && !kept_used {
                    fill(&mut self.buf.kept, &mut self.buf.kept32, pose.yaw_rad);
                    self.yaw_bits = Some(bits);
                    kept_used = true;
                    0
                } else if let Some(k) = once_used.iter().position(|&used| !used) {
                    fill(&mut self.buf.once[k], &mut self.buf.once32[k], pose.yaw_rad);
                    self.once_bits[k] = Some(bits);
                    once_used[k] = true;
                    k + 1
                } else {
                    break;
                };
                end += 1;
            }
            let n = end - start;
            let buf = &self.buf;
            if f32 {
                let rot_of = |s: usize| {
                    if s == 0 {
                        &buf.kept32
                    } else {
                        &buf.once32[s - 1]
                    }
                };
                let rots: [&RotationF32; NEIGHBOURS] = std::array::from_fn(|i| rot_of(slot[i]));
                let at: [[f32; 2]; NEIGHBOURS] = std::array::from_fn(|i| {
                    cands
                        .get(start + i)
                        .map_or([0.0; 2], |(p, _)| field.f32_origin(limits, p.x_m, p.y_m))
                });
                sums_batched_f32(&rots[..n], &at[..n], field, &mut sums[start..end]);
                start = end;
                continue;
            }
            let rot_of = |s: usize| if s == 0 { &buf.kept } else { &buf.once[s - 1] };
            let rots: [&Rotation; NEIGHBOURS] = std::array::from_fn(|i| rot_of(slot[i]));
            let at: [[f64; 2]; NEIGHBOURS] = std::array::from_fn(|i| {
                cands
                    .get(start + i)
                    .map_or([0.0; 2], |(p, _)| [p.x_m, p.y_m])
            });
            sums_batched(&rots[..n], &at[..n], field, limits, &mut sums[start..end]);
            start = end;
        }
    }
}

/// Candidates of one pattern-search iteration (+-x, +-y, +-yaw): the most one batched
/// pass sums.
pub(super) const NEIGHBOURS: usize = 6;

/// Points per batch of the interpolations (here and in the back end's matcher).
pub(crate) const LANES: usize = 4;

/// The bilinear mix per lane of corners `[f00, f10, f01, f11]` at fractions `(ax, ay)`, in
/// the order of the scalar interpolations (so the same bits).
#[inline(always)]
pub(crate) fn mix_lanes(
    f: &[[f64; 4]; LANES],
    ax: &[f64; LANES],
    ay: &[f64; LANES],
) -> [f64; LANES] {
    let mut out = [0.0; LANES];
    for k in 0..LANES {
        let [f00, f10, f01, f11] = f[k];
        let bottom = f00 * (1.0 - ax[k]) + f10 * ax[k];
        let top = f01 * (1.0 - ax[k]) + f11 * ax[k];
        out[k] = bottom * (1.0 - ay[k]) + top * ay[k];
    }
    out
}
