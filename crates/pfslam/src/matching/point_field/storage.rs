//! The storage of a [`PointField`]'s levels: buffers of `TILE x TILE` tiles taken from and
//! given back to a per-thread pool, so that a reused buffer needs only the cells its last
//! use wrote set back to zero.

use super::PointField;

/// Cells per side of a storage tile (a power of two).
pub(super) const TILE: usize = 32;
pub(super) const TILE_SHIFT: u32 = TILE.trailing_zeros();

/// A level's cells (row-major, at least `w * h`; zero outside the written runs) and the runs
/// `(start, len)` written.
#[derive(Debug, Clone, Default)]
pub(crate) struct Buffer {
    pub(crate) cells: Vec<f32>,
    pub(super) written: Vec<(usize, usize)>,
}

/// Buffers kept per thread for the next fields.
const POOL_BUFFERS: usize = 8;
/// ... each of at most this many cells (64 MB).
const POOL_MAX_CELLS: usize = 1 << 24;

thread_local! {
    static POOL: std::cell::RefCell<Vec<Buffer>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl Buffer {
    /// A buffer of at least `n` zeros: from the pool when it has one (the first large
    /// enough, else the largest, grown), else new.
    pub(super) fn zeroed(n: usize) -> Buffer {
        let pooled = POOL
            .try_with(|p| {
                let mut p = p.borrow_mut();
                let at = p
                    .iter()
                    .position(|b| b.cells.len() >= n)
                    .or_else(|| (0..p.len()).max_by_key(|&i| p[i].cells.len()))?;
                Some(p.swap_remove(at))
            })
            .ok()
            .flatten();
        match pooled {
            Some(mut b) => {
                for &(start, len) in &b.written {
                    if let Some(run) = b.cells.get_mut(start..start + len) {
                        run.fill(0.0);
                    }
                }
                b.written.clear();
                if b.cells.len() < n {
                    b.cells.resize(n, 0.0);
                }
                b
            }
            None => Buffer {
                cells: vec![0.0; n],
                written: Vec::new(),
            },
        }
    }
}

impl Drop for PointField {
    fn drop(&mut self) {
        let levels = std::mem::take(&mut self.levels);
        // At thread exit the pool is gone: the buffers are freed.
        let _ = POOL.try_with(|p| {
            let mut p = p.borrow_mut();
            for b in levels {
                // A huge window's buffers are not kept.
                if p.len() < POOL_BUFFERS && b.cells.len() <= POOL_MAX_CELLS {
                    p.push(b);
                }
            }
        });
    }
}
