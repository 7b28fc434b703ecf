//! The scan matcher's likelihood field kept up to date with the map instead of rebuilt at
//! every update ([`super::LikelihoodField::build_cached`]).
//!
//! A field value depends on the map through two things only: whether the cell was ever
//! observed (log-odds not 0) and, for the Gaussian part, which cells within the kernel's
//! reach are walls (observed, log-odds at least the threshold). Between two updates the
//! filter inserts ~5 scans, which touch ~25,000 cells on the car but change the observed or
//! wall status of a few hundred; rebuilding the field over its whole window (a 40 m scan's
//! bounding box, ~10^5 cells) cost about as much as a third of the matching. The cache keeps,
//! per 64 x 64 tile of the map, the observed flags and the maximum of the wall kernels (exactly
//! what a build computes), computes a tile from the grid the first time a window needs it,
//! and afterwards follows the grid's logged changes ([`crate::map::ChangeLog`]): a new wall
//! raises the kernel maxima around it, a removed wall has its reach recomputed from the walls
//! around it. Filling a window is then a copy. The values are those of a build, bit for bit.

use crate::map::{Cell, CellChange, CellRect, OccupancyGrid, TILE_SIZE};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

const SIDE: i32 = TILE_SIZE as i32;
const CELLS: usize = TILE_SIZE * TILE_SIZE;

/// One tile of the cache: per cell (row-major) the maximum kernel value of the walls within
/// reach, and 0xff when observed.
#[derive(Debug, Clone)]
struct CacheTile {
    kmax: Box<[u8; CELLS]>,
    seen: Box<[u8; CELLS]>,
}

/// The cached parts of the likelihood field (see the module docs). Keyed by what they were
/// computed with (kernel, wall threshold); a different key starts over.
#[derive(Debug, Clone, Default)]
pub struct FieldCache {
    kernel: Vec<(i32, i32, u8)>,
    radius: i32,
    threshold: i16,
    tiles: HashMap<(i32, i32), CacheTile, BuildHasherDefault<TileKeyHasher>>,
    /// Removed walls of the current [`Self::apply`].
    removed: Vec<Cell>,
}

/// A multiply-rotate hash of tile keys (two i32), FxHash style: the map is looked up once per
/// logged cell change, and SipHash (the default, built against flooding attacks that do not
/// apply to tile indices) was most of that cost. Nothing iterates the map, so its order never
/// reaches a result.
#[derive(Debug, Clone, Copy, Default)]
struct TileKeyHasher(u64);

impl TileKeyHasher {
    const K: u64 = 0x517c_c1b7_2722_0a95;

    #[inline]
    fn add(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(Self::K);
    }
}

impl Hasher for TileKeyHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.add(u64::from(b));
        }
    }

    #[inline]
    fn write_i32(&mut self, i: i32) {
        self.add(u64::from(i as u32));
    }

    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
}

fn tile_of(c: Cell) -> (i32, i32) {
    (c.i.div_euclid(SIDE), c.j.div_euclid(SIDE))
}

/// The tiles overlapping `rect`, row by row.
fn tiles_over(rect: &CellRect) -> impl Iterator<Item = (i32, i32)> + use<> {
    let (t0, t1) = (
        tile_of(Cell::new(rect.min_i, rect.min_j)),
        tile_of(Cell::new(rect.max_i, rect.max_j)),
    );
    (t0.1..=t1.1).flat_map(move |tj| (t0.0..=t1.0).map(move |ti| (ti, tj)))
}

/// The cells of tile `(ti, tj)`.
fn tile_rect(ti: i32, tj: i32) -> CellRect {
    CellRect {
        min_i: ti * SIDE,
        min_j: tj * SIDE,
        max_i: ti * SIDE + SIDE - 1,
        max_j: tj * SIDE + SIDE - 1,
    }
}

impl FieldCache {
    /// An empty cache.
    pub fn new() -> Self {
        FieldCache::default()
    }

    /// Forgets every tile (the grid changed in a way that was not logged).
    pub fn reset(&mut self) {
        self.tiles.clear();
    }

    /// Uses `kernel` (offsets and values, within `radius`) and walls from `threshold`; a
    /// change of either forgets every tile.
    pub fn configure(&mut self, kernel: &[(i32, i32, u8)], radius: i32, threshold: i16) {
        if self.kernel != kernel || self.radius != radius || self.threshold != threshold {
            self.kernel.clear();
            self.kernel.extend_from_slice(kernel);
            self.radius = radius;
            self.threshold = threshold;
            self.tiles.clear();
        }
    }

    fn wall(&self, v: i16) -> bool {
        v != 0 && v >= self.threshold
    }

    /// Stamps the kernel around `wall` into the held tiles, clipped to `clip` when given.
    fn stamp(&mut self, wall: Cell, clip: Option<&CellRect>) {
        for (ti, tj) in tiles_over(&CellRect::around(wall).expanded(self.radius)) {
            let Some(tile) = self.tiles.get_mut(&(ti, tj)) else {
                continue;
            };
            let (oi, oj) = (ti * SIDE, tj * SIDE);
            for &(di, dj, v) in &self.kernel {
                let c = Cell::new(wall.i + di, wall.j + dj);
                let (li, lj) = (c.i - oi, c.j - oj);
                if li < 0 || lj < 0 || li >= SIDE || lj >= SIDE {
                    continue;
                }
                if clip.is_some_and(|k| !k.contains(c)) {
                    continue;
                }
                let slot = &mut tile.kmax[(lj * SIDE + li) as usize];
                if v > *slot {
                    *slot = v;
                }
            }
        }
    }

    /// Follows the grid's logged `changes` (the grid is already in its new state).
    pub fn apply(&mut self, grid: &OccupancyGrid, changes: &[CellChange]) {
        self.removed.clear();
        for ch in changes {
            if let Some(tile) = self.tiles.get_mut(&tile_of(ch.cell)) {
                let (ti, tj) = tile_of(ch.cell);
                let k = ((ch.cell.j - tj * SIDE) * SIDE + ch.cell.i - ti * SIDE) as usize;
                tile.seen[k] = if ch.new != 0 { 0xff } else { 0 };
            }
            match (self.wall(ch.old), self.wall(ch.new)) {
                (false, true) => self.stamp(ch.cell, None),
                (true, false) => self.removed.push(ch.cell),
                _ => {}
            }
        }
        // A removed wall's reach: every cell within it recomputed from the walls that reach
        // it now (the grid's final state, so stamps above are redone where needed).
        let removed = std::mem::take(&mut self.removed);
        let r = self.radius;
        let mut walls = Vec::new();
        for &w in &removed {
            let reach = CellRect::around(w).expanded(r);
            let mut any = false;
            for (ti, tj) in tiles_over(&reach) {
                let Some(tile) = self.tiles.get_mut(&(ti, tj)) else {
                    continue;
                };
                any = true;
                let (t, (oi, oj)) = (tile_rect(ti, tj), (ti * SIDE, tj * SIDE));
                let (i0, i1) = (reach.min_i.max(t.min_i), reach.max_i.min(t.max_i));
                for j in reach.min_j.max(t.min_j)..=reach.max_j.min(t.max_j) {
                    let start = ((j - oj) * SIDE + i0 - oi) as usize;
                    tile.kmax[start..=start + (i1 - i0) as usize].fill(0);
                }
            }
            if !any {
                continue;
            }
            walls.clear();
            let threshold = self.threshold;
            grid.for_each_observed_in(&reach.expanded(r), |c, v| {
                if v >= threshold {
                    walls.push(c);
                }
            });
            for &c in &walls {
                self.stamp(c, Some(&reach));
            }
        }
        self.removed = removed;
    }

    /// Computes tile `(ti, tj)` from the grid.
    fn compute(&self, grid: &OccupancyGrid, ti: i32, tj: i32) -> CacheTile {
        let mut tile = CacheTile {
            kmax: Box::new([0; CELLS]),
            seen: Box::new([0; CELLS]),
        };
        let (oi, oj) = (ti * SIDE, tj * SIDE);
        grid.for_each_observed_in(&tile_rect(ti, tj).expanded(self.radius), |c, v| {
            let (li, lj) = (c.i - oi, c.j - oj);
            if li >= 0 && lj >= 0 && li < SIDE && lj < SIDE {
                tile.seen[(lj * SIDE + li) as usize] = 0xff;
            }
            if v >= self.threshold {
                for &(di, dj, kv) in &self.kernel {
                    let (x, y) = (li + di, lj + dj);
                    if x < 0 || y < 0 || x >= SIDE || y >= SIDE {
                        continue;
                    }
                    let slot = &mut tile.kmax[(y * SIDE + x) as usize];
                    if kv > *slot {
                        *slot = kv;
                    }
                }
            }
        });
        tile
    }

    /// Writes the field over `rect` into `out` (row-major, `rect`'s width, row 0 =
    /// `rect.min_j`): observed cells their kernel maximum, others at least `unknown`.
    /// Computes the tiles it has not seen.
    pub fn fill(&mut self, grid: &OccupancyGrid, rect: &CellRect, unknown: u8, out: &mut [u8]) {
        let w = rect.width();
        for (ti, tj) in tiles_over(rect) {
            if !self.tiles.contains_key(&(ti, tj)) {
                let tile = self.compute(grid, ti, tj);
                self.tiles.insert((ti, tj), tile);
            }
            let Some(tile) = self.tiles.get(&(ti, tj)) else {
                continue;
            };
            let (t, (oi, oj)) = (tile_rect(ti, tj), (ti * SIDE, tj * SIDE));
            let (i0, i1) = (rect.min_i.max(t.min_i), rect.max_i.min(t.max_i));
            let n = (i1 - i0 + 1) as usize;
            for j in rect.min_j.max(t.min_j)..=rect.max_j.min(t.max_j) {
                let src = ((j - oj) * SIDE + i0 - oi) as usize;
                let dst = (j - rect.min_j) as usize * w + (i0 - rect.min_i) as usize;
                let (kmax, seen) = (&tile.kmax[src..src + n], &tile.seen[src..src + n]);
                for ((o, &k), &s) in out[dst..dst + n].iter_mut().zip(kmax).zip(seen) {
                    *o = k.max(unknown & !s);
                }
            }
        }
    }
}
