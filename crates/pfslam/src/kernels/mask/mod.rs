//! The grid's ray walk into the insertion mask ([`walk_mask`]) and the cells of a ray unlike
//! the previous ray's ([`fresh_cells`]); the AVX2 kernels in `x86.rs`.

use crate::geometry::cells::Cell;

#[cfg(target_arch = "x86_64")]
mod x86;

/// Cells -> mask indices of the mask placed with its first cell at `(mi0, mj0)`.
#[derive(Clone, Copy)]
pub(crate) struct MaskLayout<'a> {
    pub(crate) xoff: &'a [u32],
    pub(crate) yoff: &'a [u32],
    pub(crate) mi0: i32,
    pub(crate) mj0: i32,
}

impl MaskLayout<'_> {
    #[inline(always)]
    pub(crate) fn index(&self, c: Cell) -> usize {
        (self.xoff[(c.i - self.mi0) as usize] + self.yoff[(c.j - self.mj0) as usize]) as usize
    }
}

/// Writes the first `out.len()` cells of the Bresenham line `(from, to)` (the map's
/// `bresenham`) as mask indices into `out`: the same cells, in the same order, as the callback form. The mask is marked from
/// this list in a second loop, which keeps both loops' state in registers. Eight cells at a
/// time in AVX2 where the CPU has it (`x86::walk_mask_avx2`).
#[inline(always)]
pub fn walk_mask(from: Cell, to: Cell, layout: &MaskLayout<'_>, out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if out.len() >= 8 && super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        if unsafe { x86::walk_mask_avx2(from, to, layout, out) } {
            return;
        }
    }
    walk_mask_portable(from, to, layout, out);
}

/// [`walk_mask`] one cell at a time: the reference, and the path without AVX2.
#[inline(always)]
pub fn walk_mask_portable(from: Cell, to: Cell, layout: &MaskLayout<'_>, out: &mut [u32]) {
    let (dx, dy) = ((to.i - from.i).abs(), (to.j - from.j).abs());
    let step_x: isize = if to.i >= from.i { 1 } else { -1 };
    let step_y: isize = if to.j >= from.j { 1 } else { -1 };
    let x = (from.i - layout.mi0) as isize;
    let y = (from.j - layout.mj0) as isize;
    // Major axis: one step per cell; minor axis: when the error crosses half a cell. The
    // index is the sum of the two axes' offsets, whichever is major.
    let (mut major, mut minor, d_major, d_minor, s_major, s_minor, off_major, off_minor) =
        if dx >= dy {
            (x, y, dx, dy, step_x, step_y, layout.xoff, layout.yoff)
        } else {
            (y, x, dy, dx, step_y, step_x, layout.yoff, layout.xoff)
        };
    let mut err = 2 * d_minor - d_major;
    for o in out.iter_mut() {
        *o = off_major[major as usize] + off_minor[minor as usize];
        if err > 0 {
            minor += s_minor;
            err -= 2 * d_major;
        }
        err += 2 * d_minor;
        major += s_major;
    }
}

/// The eight-lane walk of [`walk_mask`] alone (its test compares it with
/// [`walk_mask_portable`]): none without AVX2, else whether it took the ray (nothing is
/// written when it did not).
#[cfg(test)]
pub fn walk_mask_vector(
    from: Cell,
    to: Cell,
    layout: &MaskLayout<'_>,
    out: &mut [u32],
) -> Option<bool> {
    #[cfg(target_arch = "x86_64")]
    if super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return Some(unsafe { x86::walk_mask_avx2(from, to, layout, out) });
    }
    let _ = (from, to, layout, out);
    None
}

/// Writes the `ray` cells that differ from `prev`'s at the same place to the front of `out`
/// (which has room for `ray.len() + 8`), in order; returns how many.
#[inline(always)]
pub fn fresh_cells(ray: &[u32], prev: &[u32], out: &mut [u32]) -> usize {
    #[cfg(target_arch = "x86_64")]
    if super::cpu().avx2() {
        // SAFETY: the CPU has AVX2 (`cpu` detected it).
        return unsafe { x86::fresh_cells_avx2(ray, prev, out) };
    }
    fresh_cells_portable(ray, prev, out, 0, 0)
}

/// [`fresh_cells`] from `ray[at..]`, `n` written so far: branch-free, one cell at a time.
#[inline(always)]
pub fn fresh_cells_portable(
    ray: &[u32],
    prev: &[u32],
    out: &mut [u32],
    at: usize,
    mut n: usize,
) -> usize {
    for (&k, &p) in ray[at..].iter().zip(&prev[at..]) {
        out[n] = k;
        n += usize::from(k != p);
    }
    n
}
