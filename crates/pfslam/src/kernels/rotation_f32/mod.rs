//! The scan-matching refinement's f32 kernel: a scan rotated for one yaw in f32
//! ([`RotationF32`], 8 points per AVX2 vector) and its field sums; the AVX2 kernels in
//! `x86.rs`.

pub use super::F32_LIM;
use super::FieldWindow;

#[cfg(target_arch = "x86_64")]
mod x86;

/// Points per block of the f32 kernel (one 256-bit vector of f32).
pub const LANES32: usize = 8;

/// The points of [`Rotation`](crate::kernels::rotation::Rotation) for the f32 kernel: per point its offset from the pose in
/// cells, `((c x - s y) / res, (s x + c y) / res)` rounded to f32, in blocks of
/// [`LANES32`] lane-wise; the last block padded with copies of its last point (masked out
/// of the sums).
#[derive(Debug, Clone, Default)]
pub struct RotationF32 {
    pub blocks: Vec<[[f32; LANES32]; 2]>,
    /// Points in the last block (1..=8; 8 without blocks).
    pub last_valid: usize,
}

impl RotationF32 {
    /// One block: the points of `chunk` (1..=8), the last repeated to fill the lanes.
    #[inline(always)]
    pub fn block(chunk: &[[f64; 2]], s: f64, c: f64, inv_res: f64) -> [[f32; LANES32]; 2] {
        let mut b = [[0.0f32; LANES32]; 2];
        for l in 0..LANES32 {
            let p = chunk[l.min(chunk.len() - 1)];
            b[0][l] = ((c * p[0] - s * p[1]) * inv_res) as f32;
            b[1][l] = ((s * p[0] + c * p[1]) * inv_res) as f32;
        }
        b
    }

    /// Rotates `points_body` by the yaw of sine `s` and cosine `c` into cells (`inv_res`:
    /// cells per metre).
    pub fn fill(&mut self, points_body: &[[f64; 2]], s: f64, c: f64, inv_res: f64) {
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
    pub fn fill_whole(
        blocks: &mut Vec<[[f32; LANES32]; 2]>,
        whole: std::slice::ChunksExact<'_, [f64; 2]>,
        s: f64,
        c: f64,
        inv_res: f64,
    ) {
        #[cfg(target_arch = "x86_64")]
        if super::cpu().avx2() {
            // SAFETY: the CPU has AVX2 (`cpu` detected it).
            return unsafe { RotationF32::fill_avx2(blocks, whole, s, c, inv_res) };
        }
        blocks.extend(whole.map(|chunk| RotationF32::block(chunk, s, c, inv_res)));
    }

    /// Lanes of block `b` (of `blocks`) that hold points.
    pub fn valid_in(&self, b: usize, blocks: usize) -> usize {
        if b + 1 == blocks {
            self.last_valid
        } else {
            LANES32
        }
    }

    /// Whole blocks every rotation of a batch has (see [`Rotation::common_blocks`](crate::kernels::rotation::Rotation::common_blocks)).
    pub fn common_blocks(rots: &[&RotationF32]) -> usize {
        debug_assert!(rots.iter().all(|r| {
            r.blocks.len() == rots[0].blocks.len() && r.last_valid == rots[0].last_valid
        }));
        rots.iter().map(|r| r.blocks.len()).min().unwrap_or(0)
    }

    /// The f32 twin of [`Rotation::sums`](crate::kernels::rotation::Rotation::sums): `at[k]` is candidate `k`'s position in the
    /// window's cell frame, less half a cell (the scan matcher's `f32_origin`); per
    /// point `at + offset` and [`FieldWindow::bilinear_f32`], summed per lane in f32
    /// (lane `l` holds the points `l`, `l + 8`, ...), the 8 lanes added in f64 at the end.
    /// Not the bits of the f64 kernel (the scan matcher's `KernelPrecision`); the portable and the AVX2
    /// versions give the same bits.
    pub fn sums<const K: usize>(
        rots: [&RotationF32; K],
        at: [[f32; 2]; K],
        field: &FieldWindow<'_>,
    ) -> [f64; K] {
        #[cfg(target_arch = "x86_64")]
        if field.vector_ok() && super::cpu().avx2() {
            // SAFETY: the CPU has AVX2 (`cpu` detected it) and the field is `vector_ok`.
            return unsafe { RotationF32::sums_avx2(rots, at, field) };
        }
        RotationF32::sums_portable(rots, at, field)
    }

    /// [`Self::sums`] without vector instructions: the portable twin.
    pub fn sums_portable<const K: usize>(
        rots: [&RotationF32; K],
        at: [[f32; 2]; K],
        field: &FieldWindow<'_>,
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
}

/// The lane sums of the f32 kernel added in f64, lane 0 first.
pub(super) fn reduce_lanes(lanes: [f32; LANES32]) -> f64 {
    let mut sum = 0.0;
    for l in lanes {
        sum += f64::from(l);
    }
    sum
}
