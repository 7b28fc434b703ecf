//! The back end's interpolated score: a scan's mean bilinear field value in a
//! the point field's level 0 ([`PointLevel`]) for several poses in one pass; the AVX2
//! interpolation in `x86.rs`.

use super::{LANES, PointLevel, mix_lanes};
use crate::geometry::Pose2;
use crate::geometry::cells::floor_to_i64;

#[cfg(target_arch = "x86_64")]
mod x86;

/// The point field's score (the mean interpolated value of the points) of `K` poses (`sin_cos[k]` of `poses[k]`'s yaw) in one pass over
/// the points: the four lanes' interpolation in AVX2 where the CPU has it, else
/// [`portable`]; the same bits. Each pose has its own accumulator and adds its own values in
/// its own order, so each score is the bits of the pose scored alone; the independent
/// chains of additions can overlap.
pub fn scores<const K: usize>(
    field: &PointLevel<'_>,
    points_body: &[[f64; 2]],
    poses: [Pose2; K],
    sin_cos: [(f64, f64); K],
) -> [f64; K] {
    #[cfg(target_arch = "x86_64")]
    if super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return unsafe { x86::scores_avx2(field, points_body, poses, sin_cos) };
    }
    portable(field, points_body, poses, sin_cos)
}

/// [`scores`] without vector instructions: the portable twin.
pub fn portable<const K: usize>(
    field: &PointLevel<'_>,
    points_body: &[[f64; 2]],
    poses: [Pose2; K],
    sin_cos: [(f64, f64); K],
) -> [f64; K] {
    scores_with(field, points_body, poses, sin_cos, |u, v| {
        bilinear_lanes(field, u, v)
    })
}

/// The body of [`scores`] and [`portable`], with `lanes` the interpolation of four points.
#[inline(always)]
pub(super) fn scores_with<const K: usize>(
    field: &PointLevel<'_>,
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
                u[l] = (x - field.origin_x_m) / field.resolution_m - 0.5;
                v[l] = (y - field.origin_y_m) / field.resolution_m - 0.5;
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
            sums[k] += bilinear(
                field,
                pose.x_m + c * p[0] - s * p[1],
                pose.y_m + s * p[0] + c * p[1],
            );
        }
    }
    sums.map(|sum| sum / points_body.len() as f64)
}

/// Bilinear interpolation between cell centres (0 outside).
#[inline]
fn bilinear(field: &PointLevel<'_>, x_m: f64, y_m: f64) -> f64 {
    let u = (x_m - field.origin_x_m) / field.resolution_m - 0.5;
    let v = (y_m - field.origin_y_m) / field.resolution_m - 0.5;
    bilinear_lane(field, u, v)
}

/// [`bilinear`] of `LANES` points given as cell coordinates minus one half (`u`,
/// `v` of `bilinear`), lane-wise so that the arithmetic vectorises.
#[inline(always)]
fn bilinear_lanes(field: &PointLevel<'_>, u: &[f64; LANES], v: &[f64; LANES]) -> [f64; LANES] {
    let mut au = [0.0; LANES];
    let mut av = [0.0; LANES];
    let mut f = [[0.0; 4]; LANES];
    for k in 0..LANES {
        let (i, j) = (floor_to_i64(u[k]), floor_to_i64(v[k]));
        au[k] = u[k] - i as f64;
        av[k] = v[k] - j as f64;
        f[k] = corners(field, i, j).map(f64::from);
    }
    mix_lanes(&f, &au, &av)
}

/// [`bilinear`] from cell coordinates minus one half (`u`, `v`); one lane of
/// [`bilinear_lanes`].
#[inline(always)]
pub(super) fn bilinear_lane(field: &PointLevel<'_>, u: f64, v: f64) -> f64 {
    // `f64::floor` is a libm call on baseline x86-64; the integer floor is the same value.
    let (i, j) = (floor_to_i64(u), floor_to_i64(v));
    let (au, av) = (u - i as f64, v - j as f64);
    let [f00, f10, f01, f11] = corners(field, i, j).map(f64::from);
    let bottom = f00 * (1.0 - au) + f10 * au;
    let top = f01 * (1.0 - au) + f11 * au;
    bottom * (1.0 - av) + top * av
}

/// Level-0 values at `(i, j)`, `(i+1, j)`, `(i, j+1)`, `(i+1, j+1)` (0 outside): one
/// bounds check when the 2x2 block lies inside (nearly always).
#[inline(always)]
fn corners(field: &PointLevel<'_>, i: i64, j: i64) -> [f32; 4] {
    let (w, h) = (field.w as i64, field.h as i64);
    let block = (i >= 0 && j >= 0 && i + 1 < w && j + 1 < h)
        .then(|| {
            let k = (j * w + i) as usize;
            let lv = field.cells;
            let row0 = lv.get(k..k + 2)?;
            let row1 = lv.get(k + w as usize..k + w as usize + 2)?;
            Some([row0[0], row0[1], row1[0], row1[1]])
        })
        .flatten();
    block.unwrap_or_else(|| {
        [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(di, dj)| field.at(i + di, j + dj))
    })
}
