//! The back end's exact cell sums: a scan's cells (at one heading) shifted by a whole-cell
//! offset, summed over a level of the point field ([`PointLevel`]); the AVX2 kernel in
//! `x86.rs`.

use super::PointLevel;

#[cfg(target_arch = "x86_64")]
mod x86;

/// The point field's exact cell sum over the cell columns `(xs, ys)` in `field`, its level
/// `level` (cells pooled over `2^level` blocks): eight points at a time in AVX2 where the
/// CPU has it, else [`portable`]; the same bits.
pub fn cell_sum(
    field: PointLevel<'_>,
    (xs, ys): (&[i32], &[i32]),
    level: usize,
    dx: i64,
    dy: i64,
) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if xs.len() <= 1 << 22 && super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return unsafe { x86::cell_sum_avx2(field, (xs, ys), level, dx, dy) };
    }
    portable(field, (xs, ys), level, dx, dy)
}

/// [`cell_sum`] a point at a time, in point order, over the columns `(x, y)`: the portable
/// twin.
pub fn portable(
    field: PointLevel<'_>,
    (xs, ys): (&[i32], &[i32]),
    level: usize,
    dx: i64,
    dy: i64,
) -> f64 {
    let lv = field.cells;
    let (w, h) = (field.w as u64, field.h as u64);
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
