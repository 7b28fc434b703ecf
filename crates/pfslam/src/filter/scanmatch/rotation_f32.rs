//! A scan rotated for one yaw in f32 (8 points per AVX2 vector) and its field sums.

use super::*;

/// Points per block of the f32 kernel (one 256-bit vector of f32).
pub(super) const LANES32: usize = 8;

/// The f32 kernel's coordinate bound (cells, 2^23): below it a coordinate's floor and
/// fraction are exact in f32, and a point beyond it lies outside every window the kernel
/// takes (`LikelihoodField::f32_ok`).
pub(super) const F32_LIM: f32 = 8_388_608.0;

/// The points of [`Rotation`] for the f32 kernel: per point its offset from the pose in
/// cells, `((c x - s y) / res, (s x + c y) / res)` rounded to f32, in blocks of
/// [`LANES32`] lane-wise; the last block padded with copies of its last point (masked out
/// of the sums).
#[derive(Debug, Clone, Default)]
pub(super) struct RotationF32 {
    pub(super) blocks: Vec<[[f32; LANES32]; 2]>,
    /// Points in the last block (1..=8; 8 without blocks).
    pub(super) last_valid: usize,
}

impl RotationF32 {
    /// One block: the points of `chunk` (1..=8), the last repeated to fill the lanes.
    #[inline(always)]
    pub(super) fn block(chunk: &[[f64; 2]], s: f64, c: f64, inv_res: f64) -> [[f32; LANES32]; 2] {
        let mut b = [[0.0f32; LANES32]; 2];
        for l in 0..LANES32 {
            let p = chunk[l.min(chunk.len() - 1)];
            b[0][l] = ((c * p[0] - s * p[1]) * inv_res) as f32;
            b[1][l] = ((s * p[0] + c * p[1]) * inv_res) as f32;
        }
        b
    }

    pub(super) fn fill(&mut self, points_body: &[[f64; 2]], s: f64, c: f64, inv_res: f64) {
        self.blocks.clear();
        let whole = points_body.chunks_exact(LANES32);
        let rest = whole.remainder();
        RotationF32::fill_whole(&mut self.blocks, whole, s, c, inv_res);
        if !rest.is_empty() {
            self.blocks.push(RotationF32::block(rest, s, c, inv_res));
        }
        self.last_valid = match points_body.len() % LANES32 {
            0 => LANES32,
            r => r,
        };
    }

    /// [`Self::block`] of each whole chunk, appended; in AVX2 where the CPU has it.
    pub(super) fn fill_whole(
        blocks: &mut Vec<[[f32; LANES32]; 2]>,
        whole: std::slice::ChunksExact<'_, [f64; 2]>,
        s: f64,
        c: f64,
        inv_res: f64,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked above).
            return unsafe { RotationF32::fill_avx2(blocks, whole, s, c, inv_res) };
        }
        blocks.extend(whole.map(|chunk| RotationF32::block(chunk, s, c, inv_res)));
    }

    /// [`Self::block`] of whole chunks in AVX2, four points per f64 vector: the same
    /// products, difference, sum and scaling in the same order (no fused multiply-add), then
    /// rounded to f32 as `as f32` does, so the same bits. The scalar loop was ~6 % of the
    /// car's CPU (a rotation per yaw the refinement tries).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) fn fill_avx2(
        blocks: &mut Vec<[[f32; LANES32]; 2]>,
        whole: std::slice::ChunksExact<'_, [f64; 2]>,
        s: f64,
        c: f64,
        inv_res: f64,
    ) {
        use std::arch::x86_64::*;
        let (sv, cv, iv) = (
            _mm256_set1_pd(s),
            _mm256_set1_pd(c),
            _mm256_set1_pd(inv_res),
        );
        // Four points [x0 y0 x1 y1], [x2 y2 x3 y3] -> the rotated x and y of the four, each
        // rounded to four f32.
        let quad = |a: __m256d, b: __m256d| {
            // unpack gives [x0 x2 x1 x3]; the permute restores the point order.
            let x = _mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_unpacklo_pd(a, b));
            let y = _mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_unpackhi_pd(a, b));
            let rx = _mm256_mul_pd(
                _mm256_sub_pd(_mm256_mul_pd(cv, x), _mm256_mul_pd(sv, y)),
                iv,
            );
            let ry = _mm256_mul_pd(
                _mm256_add_pd(_mm256_mul_pd(sv, x), _mm256_mul_pd(cv, y)),
                iv,
            );
            (_mm256_cvtpd_ps(rx), _mm256_cvtpd_ps(ry))
        };
        blocks.reserve(whole.len());
        for chunk in whole {
            let Some(p) = chunk.as_flattened().first_chunk::<16>() else {
                continue;
            };
            // SAFETY: unaligned 32-byte loads from a checked 16-element slice.
            let (a0, a1, a2, a3) = unsafe {
                (
                    _mm256_loadu_pd(p.as_ptr()),
                    _mm256_loadu_pd(p.as_ptr().add(4)),
                    _mm256_loadu_pd(p.as_ptr().add(8)),
                    _mm256_loadu_pd(p.as_ptr().add(12)),
                )
            };
            let (x_lo, y_lo) = quad(a0, a1);
            let (x_hi, y_hi) = quad(a2, a3);
            let mut b = [[0.0f32; LANES32]; 2];
            // SAFETY: unaligned 32-byte stores into local arrays of eight f32.
            unsafe {
                _mm256_storeu_ps(b[0].as_mut_ptr(), _mm256_set_m128(x_hi, x_lo));
                _mm256_storeu_ps(b[1].as_mut_ptr(), _mm256_set_m128(y_hi, y_lo));
            }
            blocks.push(b);
        }
    }

    /// Lanes of block `b` (of `blocks`) that hold points.
    pub(super) fn valid_in(&self, b: usize, blocks: usize) -> usize {
        if b + 1 == blocks {
            self.last_valid
        } else {
            LANES32
        }
    }

    /// Whole blocks every rotation of a batch has (see [`Rotation::common_blocks`]).
    pub(super) fn common_blocks(rots: &[&RotationF32]) -> usize {
        debug_assert!(rots.iter().all(|r| {
            r.blocks.len() == rots[0].blocks.len() && r.last_valid == rots[0].last_valid
        }));
        rots.iter().map(|r| r.blocks.len()).min().unwrap_or(0)
    }

    /// The f32 twin of [`Rotation::sums`]: `at[k]` is candidate `k`'s position in the
    /// window's cell frame, less half a cell (see [`LikelihoodField::f32_origin`]); per
    /// point `at + offset` and [`LikelihoodField::bilinear_f32`], summed per lane in f32
    /// (lane `l` holds the points `l`, `l + 8`, ...), the 8 lanes added in f64 at the end.
    /// Not the bits of the f64 kernel (see [`KernelPrecision`]); the portable and the AVX2
    /// versions give the same bits.
    pub(super) fn sums<const K: usize>(
        rots: [&RotationF32; K],
        at: [[f32; 2]; K],
        field: &LikelihoodField,
    ) -> [f64; K] {
        #[cfg(target_arch = "x86_64")]
        if field.vector_ok() && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked above).
            return unsafe { RotationF32::sums_avx2(rots, at, field) };
        }
        RotationF32::sums_portable(rots, at, field)
    }

    pub(super) fn sums_portable<const K: usize>(
        rots: [&RotationF32; K],
        at: [[f32; 2]; K],
        field: &LikelihoodField,
    ) -> [f64; K] {
        let mut acc = [[0.0f32; LANES32]; K];
        let blocks = RotationF32::common_blocks(&rots);
        for b in 0..blocks {
            let valid = rots[0].valid_in(b, blocks);
            for k in 0..K {
                let [rx, ry] = &rots[k].blocks[b];
                for l in 0..LANES32 {
                    let value = field.bilinear_f32(at[k][0] + rx[l], at[k][1] + ry[l]);
                    acc[k][l] += if l < valid { value } else { 0.0 };
                }
            }
        }
        acc.map(reduce_lanes)
    }

    /// [`Self::sums_portable`] in AVX2 (8 lanes of f32): the same IEEE operations per lane,
    /// so the same bits; a block with a lane beyond [`F32_LIM`] (or NaN) or a corner outside
    /// the window takes [`LikelihoodField::bilinear_f32`] per lane.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sums_avx2<const K: usize>(
        rots: [&RotationF32; K],
        at: [[f32; 2]; K],
        field: &LikelihoodField,
    ) -> [f64; K] {
        use std::arch::x86_64::*;
        let lim = _mm256_set1_ps(F32_LIM);
        let sign = _mm256_set1_ps(-0.0);
        let one = _mm256_set1_ps(1.0);
        // `vector_ok` guarantees these fit in i32.
        let (w, h) = (field.w as i32, field.h as i32);
        let (vw, wm1, hm1) = (
            _mm256_set1_epi32(w),
            _mm256_set1_epi32(w - 1),
            _mm256_set1_epi32(h - 1),
        );
        let minus1 = _mm256_set1_epi32(-1);
        let byte = _mm256_set1_epi32(0xff);
        let base = field.values.as_ptr();
        let fw = field.w;
        let bx: [__m256; K] = std::array::from_fn(|k| _mm256_set1_ps(at[k][0]));
        let by: [__m256; K] = std::array::from_fn(|k| _mm256_set1_ps(at[k][1]));
        let mut acc = [_mm256_setzero_ps(); K];
        let blocks = RotationF32::common_blocks(&rots);
        let lane_ids = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        for b in 0..blocks {
            let valid = rots[0].valid_in(b, blocks) as i32;
            let mask = _mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_set1_epi32(valid), lane_ids));
            for k in 0..K {
                let [rx, ry] = &rots[k].blocks[b];
                // SAFETY: unaligned loads of whole `[f32; 8]` arrays.
                let (rx, ry) =
                    unsafe { (_mm256_loadu_ps(rx.as_ptr()), _mm256_loadu_ps(ry.as_ptr())) };
                let x = _mm256_add_ps(bx[k], rx);
                let y = _mm256_add_ps(by[k], ry);
                let ok = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_andnot_ps(sign, x), lim),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_andnot_ps(sign, y), lim),
                );
                let mut fast = None;
                if _mm256_movemask_ps(ok) == 0xff {
                    let fx = _mm256_floor_ps(x);
                    let fy = _mm256_floor_ps(y);
                    let (i, j) = (_mm256_cvttps_epi32(fx), _mm256_cvttps_epi32(fy));
                    let inside = _mm256_and_si256(
                        _mm256_and_si256(_mm256_cmpgt_epi32(i, minus1), _mm256_cmpgt_epi32(wm1, i)),
                        _mm256_and_si256(_mm256_cmpgt_epi32(j, minus1), _mm256_cmpgt_epi32(hm1, j)),
                    );
                    if _mm256_movemask_ps(_mm256_castsi256_ps(inside)) == 0xff {
                        let cell = _mm256_add_epi32(_mm256_mullo_epi32(j, vw), i);
                        let mut ka = [0i32; LANES32];
                        // SAFETY: a store into a local array of 32 bytes.
                        unsafe { _mm256_storeu_si256(ka.as_mut_ptr().cast(), cell) };
                        // Per point the two corner pairs as scalar u16 loads, as in the f64
                        // kernel (8-lane gathers and lane extracts measured no faster).
                        // SAFETY: all four corners of every lane lie inside the window.
                        let d = unsafe {
                            _mm256_setr_epi32(
                                corner_pairs(base, ka[0], fw),
                                corner_pairs(base, ka[1], fw),
                                corner_pairs(base, ka[2], fw),
                                corner_pairs(base, ka[3], fw),
                                corner_pairs(base, ka[4], fw),
                                corner_pairs(base, ka[5], fw),
                                corner_pairs(base, ka[6], fw),
                                corner_pairs(base, ka[7], fw),
                            )
                        };
                        let byte_at = |d| _mm256_cvtepi32_ps(_mm256_and_si256(d, byte));
                        let f00 = byte_at(d);
                        let f10 = byte_at(_mm256_srli_epi32::<8>(d));
                        let f01 = byte_at(_mm256_srli_epi32::<16>(d));
                        let f11 = _mm256_cvtepi32_ps(_mm256_srli_epi32::<24>(d));
                        let ax = _mm256_sub_ps(x, fx);
                        let ay = _mm256_sub_ps(y, fy);
                        // As `bilinear_f32`.
                        let omx = _mm256_sub_ps(one, ax);
                        let bottom = _mm256_add_ps(_mm256_mul_ps(f00, omx), _mm256_mul_ps(f10, ax));
                        let top = _mm256_add_ps(_mm256_mul_ps(f01, omx), _mm256_mul_ps(f11, ax));
                        fast = Some(_mm256_add_ps(
                            _mm256_mul_ps(bottom, _mm256_sub_ps(one, ay)),
                            _mm256_mul_ps(top, ay),
                        ));
                    }
                }
                let value = fast.unwrap_or_else(|| {
                    let mut xa = [0.0f32; LANES32];
                    let mut ya = [0.0f32; LANES32];
                    // SAFETY: stores into local arrays.
                    unsafe {
                        _mm256_storeu_ps(xa.as_mut_ptr(), x);
                        _mm256_storeu_ps(ya.as_mut_ptr(), y);
                    }
                    let v: [f32; LANES32] =
                        std::array::from_fn(|l| field.bilinear_f32(xa[l], ya[l]));
                    // SAFETY: a load from a local array.
                    unsafe { _mm256_loadu_ps(v.as_ptr()) }
                });
                acc[k] = _mm256_add_ps(acc[k], _mm256_and_ps(value, mask));
            }
        }
        acc.map(|a| {
            let mut lanes = [0.0f32; LANES32];
            // SAFETY: a store into a local array.
            unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), a) };
            reduce_lanes(lanes)
        })
    }
}

/// The lane sums of the f32 kernel added in f64, lane 0 first.
pub(super) fn reduce_lanes(lanes: [f32; LANES32]) -> f64 {
    let mut sum = 0.0;
    for l in lanes {
        sum += f64::from(l);
    }
    sum
}

/// The sums of [`RotationF32::sums`] for any number of candidates, as [`sums_batched`].
pub(super) fn sums_batched_f32(
    rots: &[&RotationF32],
    at: &[[f32; 2]],
    field: &LikelihoodField,
    out: &mut [f64],
) {
    let chunks = rots.chunks(NEIGHBOURS).zip(at.chunks(NEIGHBOURS));
    for ((r, a), o) in chunks.zip(out.chunks_mut(NEIGHBOURS)) {
        by_count!(r.len().min(a.len()).min(o.len()), K => {
            let sums = RotationF32::sums::<K>(
                std::array::from_fn(|i| r[i]),
                std::array::from_fn(|i| a[i]),
                field,
            );
            o.copy_from_slice(&sums);
        });
    }
}
