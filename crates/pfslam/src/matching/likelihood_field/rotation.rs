//! The refinement's rotations of a scan, cached per yaw ([`RotatedPoints`]), their field sums
//! in batches (the kernels in `crate::kernels::rotation` and `crate::kernels::rotation_f32`).

use super::*;
use crate::geometry::Pose2;
use crate::kernels::rotation::Rotation;
use crate::kernels::rotation_f32::RotationF32;
use crate::map::MapLimits;

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
                &field.window(),
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
                &field.window(),
            );
            o.copy_from_slice(&sums);
        });
    }
}
