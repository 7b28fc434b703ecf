use super::*;
use crate::kernels::heights::{BinUpdater, update_bins};
use crate::kernels::mask::{
    fresh_cells, fresh_cells_portable, walk_mask_portable, walk_mask_vector,
};
use crate::map::ScanPoint;
use rand::{RngExt, SeedableRng};
use std::collections::BTreeMap;

/// The last cell the ray of `p` (ending in cell `end`) clears, and whether that falls short
/// of `end` (a ray cleared only part of the way).
fn cleared_to(g: &OccupancyGrid, scan: &PlanarScan, p: &ScanPoint, end: Cell) -> (Cell, bool) {
    if p.free_to < 1.0 {
        let t = f64::from(p.free_to.max(0.0));
        let x = scan.sensor_x_m + t * (p.x_m - scan.sensor_x_m);
        let y = scan.sensor_y_m + t * (p.y_m - scan.sensor_y_m);
        (g.cell_of(x, y), true)
    } else {
        (end, false)
    }
}

/// The per-scan rule of [`OccupancyGrid::insert_scan`] written plainly (a map of marks,
/// per-cell checks on every Bresenham cell): the optimised insertion must equal it.
fn insert_reference(g: &mut OccupancyGrid, scan: &PlanarScan) -> InsertStats {
    let origin = g.cell_of(scan.sensor_x_m, scan.sensor_y_m);
    let mut marks: BTreeMap<Cell, u8> = BTreeMap::new();
    for p in &scan.points {
        let end = g.cell_of(p.x_m, p.y_m);
        let margin = if p.hit { g.free_margin_cells } else { 0 };
        let (clear_end, partial) = cleared_to(g, scan, p, end);
        bresenham(origin, clear_end, |c| {
            if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin || (partial && c == clear_end)
            {
                return;
            }
            let m = marks.entry(c).or_insert(1);
            *m = (*m).max(1);
        });
        let m = marks.entry(end).or_insert(0);
        *m = (*m).max(if p.hit { 2 } else { 1 });
    }
    let f = g.fixed;
    let mut stats = InsertStats {
        rays: scan.points.len(),
        ..InsertStats::default()
    };
    for (c, m) in marks {
        let delta = if m == 2 {
            stats.occupied_cells += 1;
            f.hit
        } else {
            stats.free_cells += 1;
            f.miss
        };
        let v = g.logodds_fixed(c);
        g.set_fixed(c, f.apply(v, delta)).unwrap();
    }
    stats
}

/// The height-bin rule of [`OccupancyGrid::insert_scan`] written plainly: marks per
/// (cell, bin), bins kept in `bins`, the cell set to their projection.
fn insert_reference_heights(
    g: &mut OccupancyGrid,
    bins: &mut BTreeMap<Cell, Vec<i8>>,
    scan: &PlanarScan,
) -> InsertStats {
    let layer = g.height.clone().unwrap();
    let bin = |z: f32| layer.bit(z).trailing_zeros() as usize;
    let z0 = scan.sensor_z_m.unwrap() as f32;
    let origin = g.cell_of(scan.sensor_x_m, scan.sensor_y_m);
    // (cell, bin) -> 1 free, 2 occupied
    let mut marks: BTreeMap<(Cell, usize), u8> = BTreeMap::new();
    for p in &scan.points {
        let end = g.cell_of(p.x_m, p.y_m);
        let margin = if p.hit { g.free_margin_cells } else { 0 };
        let (clear_end, partial) = cleared_to(g, scan, p, end);
        let n_full = (end.i - origin.i).abs().max((end.j - origin.j).abs());
        let dz = if n_full > 0 {
            (p.z_m - z0) / n_full as f32
        } else {
            0.0
        };
        let mut step = 0;
        bresenham(origin, clear_end, |c| {
            let z = z0 + step as f32 * dz;
            step += 1;
            if (c.i - end.i).abs().max((c.j - end.j).abs()) <= margin || (partial && c == clear_end)
            {
                return;
            }
            let m = marks.entry((c, bin(z))).or_insert(1);
            *m = (*m).max(1);
        });
        let m = marks.entry((end, bin(p.z_m))).or_insert(0);
        *m = (*m).max(if p.hit { 2 } else { 1 });
    }
    let mut stats = InsertStats {
        rays: scan.points.len(),
        ..InsertStats::default()
    };
    let mut cells: BTreeMap<Cell, bool> = BTreeMap::new();
    for ((c, b), m) in marks {
        let col = bins.entry(c).or_insert_with(|| vec![0; layer.bins]);
        let d = if m == 2 {
            layer.model.hit
        } else {
            layer.model.miss
        };
        col[b] =
            (col[b] as i32 + d as i32).clamp(layer.model.min as i32, layer.model.max as i32) as i8;
        *cells.entry(c).or_insert(false) |= m == 2;
    }
    for (c, occ) in cells {
        if occ {
            stats.occupied_cells += 1;
        } else {
            stats.free_cells += 1;
        }
        let v = project_bins(&bins[&c], &layer.model, g.fixed.occupied);
        g.set_fixed(c, v).unwrap();
    }
    stats
}

/// [`project_bins`] as first written (signed bytes, one at a time).
fn project_bins_plain(bins: &[i8], model: &BinLogOdds, occupied: i16) -> i16 {
    let (mut lo, mut hi) = (i8::MAX, i8::MIN);
    for &v in bins {
        lo = lo.min(if v == 0 { i8::MAX } else { v });
        hi = hi.max(v);
    }
    let scale = (crate::map::logodds::LOGODDS_SCALE / BIN_SCALE) as i16;
    if hi >= model.occupied {
        (hi as i16 * scale).max(occupied)
    } else if lo == i8::MAX {
        0
    } else {
        lo as i16 * scale
    }
}

#[test]
fn column_projection_equals_project_bins() {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
    let edge = [i8::MIN, -127, -1, 0, 1, 13, 14, 15, 126, i8::MAX];
    for case in 0..20_000 {
        let model = BinLogOdds::new(
            &crate::map::LogOddsParams::ese650(),
            [0.55, 0.7, 0.9, 0.999][case % 4],
        );
        let mut bins = [0i8; MAX_BINS];
        let observed = rng.random_range(0..=MAX_BINS);
        for v in bins.iter_mut().take(observed) {
            *v = if rng.random_range(0..4) == 0 {
                edge[rng.random_range(0..edge.len())]
            } else {
                rng.random_range(-128..=127i32) as i8
            };
        }
        bins.swap(0, rng.random_range(0..MAX_BINS));
        for occupied in [1, 563, 25600] {
            let want = project_bins_plain(&bins, &model, occupied);
            assert_eq!(project_column(&bins, &model, occupied), want, "{bins:?}");
            let n = observed.max(1);
            let short = project_bins_plain(&bins[..n], &model, occupied);
            assert_eq!(
                project_bins(&bins[..n], &model, occupied),
                short,
                "{bins:?}"
            );
        }
    }
}

#[test]
fn mask_layout_splits_into_tile_and_row_major_cell() {
    // Every cell of a 3 x 3-tile mask: a distinct index below the mask's size, whose tile
    // and in-tile cell are the cell's (row-major, as `Tile`).
    let blocks = 3usize;
    let side = (blocks * TILE_SIZE) as u32;
    let mut seen = vec![false; blocks * blocks * TILE_CELLS];
    for r in 0..side {
        for c in 0..side {
            let k = (mask_x(c) + mask_y(r, blocks)) as usize;
            assert!(!std::mem::replace(&mut seen[k], true), "({c}, {r}) twice");
            let (tc, tr) = ((c >> TILE_SHIFT) as usize, (r >> TILE_SHIFT) as usize);
            assert_eq!(mask_tile(k), tr * blocks + tc);
            let (lc, lr) = (c as usize % TILE_SIZE, r as usize % TILE_SIZE);
            assert_eq!(local_of(k), lr * TILE_SIZE + lc);
        }
    }
}

#[test]
fn vectorised_walk_equals_the_scalar_walk() {
    // Random rays in masks of 1-30 tiles a side (every octant, axis-parallel and
    // diagonal ones, up to MAX_RAY_CELLS long), each prefix length from 8 to the whole
    // ray: the eight-lane walk writes the scalar walk's indices, and takes every ray
    // that fits in its mask.
    if crate::kernels::cpu().avx2() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(21);
        let (mut want, mut got) = (Vec::new(), Vec::new());
        let mut taken = 0;
        for case in 0..4000 {
            let blocks = if case % 50 == 0 {
                260
            } else {
                rng.random_range(1..=30usize)
            };
            let side = (blocks * TILE_SIZE) as u32;
            let xoff: Vec<u32> = (0..side).map(mask_x).collect();
            let yoff: Vec<u32> = (0..side).map(|r| mask_y(r, blocks)).collect();
            let (mi0, mj0) = (rng.random_range(-5000..5000), rng.random_range(-5000..5000));
            let layout = MaskLayout {
                xoff: &xoff,
                yoff: &yoff,
                mi0,
                mj0,
            };
            let side = side as i32;
            let max = side.min(MAX_RAY_CELLS + 1);
            let cell = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus| {
                Cell::new(
                    mi0 + rng.random_range(0..side),
                    mj0 + rng.random_range(0..side),
                )
            };
            let from = cell(&mut rng);
            let to = match case % 5 {
                // Axis-parallel, diagonal, or anywhere (steep and shallow alike).
                0 => Cell::new(from.i, mj0 + rng.random_range(0..side)),
                1 => Cell::new(mi0 + rng.random_range(0..side), from.j),
                2 => {
                    let d = rng.random_range(0..max);
                    let d = d
                        .min(side - 1 - (from.i - mi0))
                        .min(side - 1 - (from.j - mj0));
                    Cell::new(from.i + d, from.j + d)
                }
                _ => cell(&mut rng),
            };
            let n = (to.i - from.i).abs().max((to.j - from.j).abs()) as usize;
            if n + 1 < 8 {
                continue;
            }
            let len = if case % 3 == 0 {
                n + 1
            } else {
                rng.random_range(8..=n + 1)
            };
            want.resize(len, 0);
            got.resize(len, u32::MAX);
            walk_mask_portable(from, to, &layout, &mut want);
            let took = walk_mask_vector(from, to, &layout, &mut got);
            assert_eq!(took, Some(true), "case {case}");
            assert_eq!(got, want, "case {case}: {from:?} -> {to:?}, {len} cells");
            taken += 1;
        }
        assert!(taken > 3000, "{taken}");
        // A ray leaving the mask is left to the scalar walk.
        let xoff: Vec<u32> = (0..TILE_SIZE as u32).map(mask_x).collect();
        let yoff: Vec<u32> = (0..TILE_SIZE as u32).map(|r| mask_y(r, 1)).collect();
        let layout = MaskLayout {
            xoff: &xoff,
            yoff: &yoff,
            mi0: 0,
            mj0: 0,
        };
        let mut out = vec![0u32; 10];
        let took = walk_mask_vector(Cell::new(60, 0), Cell::new(70, 3), &layout, &mut out);
        assert_eq!(took, Some(false));
    }
}

#[test]
fn fresh_cells_are_the_cells_unlike_the_previous_rays() {
    // Lists of 0-100 cells, a share of them equal to the previous ray's at the same
    // place (none, some, all), the previous ray shorter, as long or longer: the
    // compaction keeps exactly the unequal ones, in order, on every path.
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(31);
    for case in 0..3000 {
        let len = rng.random_range(0..100usize);
        let same = [0.0, 0.5, 0.9, 1.0][case % 4];
        let ray: Vec<u32> = (0..len).map(|_| rng.random_range(0..50)).collect();
        let prev: Vec<u32> = ray
            .iter()
            .map(|&k| if rng.random_bool(same) { k } else { k + 1 })
            .collect();
        let common = rng.random_range(0..=len);
        let (ray, prev) = (&ray[..common], &prev[..common]);
        let want: Vec<u32> = ray
            .iter()
            .zip(prev)
            .filter(|(k, p)| k != p)
            .map(|(&k, _)| k)
            .collect();
        let mut out = vec![u32::MAX; common + 8];
        let n = fresh_cells(ray, prev, &mut out);
        assert_eq!(&out[..n], &want[..], "case {case}");
        let n = fresh_cells_portable(ray, prev, &mut out, 0, 0);
        assert_eq!(&out[..n], &want[..], "case {case}, scalar");
    }
}

#[test]
fn vectorised_bin_updates_equal_the_per_bin_rule() {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(13);
    for case in 0..200 {
        // Random models, extremes included: steps up to the whole range, bounds at
        // the `i8` limits and equal bounds.
        let mut model = BinLogOdds::new(&crate::map::LogOddsParams::ese650(), 0.7);
        if case % 2 == 1 {
            let lo = rng.random_range(-127..=0i8);
            let hi = if case % 10 == 3 {
                lo
            } else {
                rng.random_range(lo..=127i8)
            };
            model = BinLogOdds {
                hit: rng.random_range(1..=127),
                miss: rng.random_range(-127..=-1),
                min: lo,
                max: hi,
                occupied: rng.random_range(1..=127),
            };
        }
        let n = rng.random_range(0..300);
        let updates: Vec<u16> = (0..n)
            .map(|_| rng.random_range(0..TILE_CELLS as u16) | rng.random_range(0..16) << 12)
            .collect();
        let marks: Vec<u32> = (0..n)
            .map(|_| match rng.random_range(0..4) {
                0 => rng.random::<u32>(),
                1 => 1 << rng.random_range(0..32),
                2 => 0,
                _ => rng.random::<u32>() & rng.random::<u32>(),
            })
            .collect();
        let start = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus| -> Vec<[i8; MAX_BINS]> {
            (0..TILE_CELLS)
                .map(|_| std::array::from_fn(|_| rng.random_range(model.min..=model.max)))
                .collect()
        };
        let mut want = start(&mut rng);
        let mut got = want.clone();
        let (mut want_stale, mut got_stale) = ([false; TILE_CELLS], [false; TILE_CELLS]);
        for (&u, &m) in updates.iter().zip(&marks) {
            let local = usize::from(u) & (TILE_CELLS - 1);
            update_bins(&mut want[local], m, &model);
            want_stale[local] = true;
        }
        BinUpdater::new(&model).run(&mut got, &mut got_stale, &updates, &marks, &model);
        assert!(got == want, "case {case}: bins differ");
        assert!(got_stale == want_stale, "case {case}: stale cells differ");
        let one = BinUpdater::new(&model);
        let mut each = start(&mut rng);
        let mut plain = each.clone();
        for (&u, &m) in updates.iter().zip(&marks) {
            let local = usize::from(u) & (TILE_CELLS - 1);
            one.update(&mut each[local], m, &model);
            update_bins(&mut plain[local], m, &model);
        }
        assert!(each == plain, "case {case}: single updates differ");
        // The SSE4.1 path on its own (the updater above takes AVX-512 where it can).
        if let Some(sse41) = BinUpdater::sse41_only(&model) {
            let mut sse = start(&mut rng);
            let mut plain = sse.clone();
            for (&u, &m) in updates.iter().zip(&marks) {
                let local = usize::from(u) & (TILE_CELLS - 1);
                sse41.update(&mut sse[local], m, &model);
                update_bins(&mut plain[local], m, &model);
            }
            assert!(sse == plain, "case {case}: SSE4.1 updates differ");
        }
    }
}

#[test]
fn whole_scan_drain_equals_the_piece_drain() {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(14);
    for case in 0..40 {
        let opts = MapOptions {
            resolution_m: [0.05, 0.1, 0.37][case % 3],
            free_margin_m: [0.0, 0.3][(case / 3) % 2],
            ..MapOptions::default()
        };
        let grid = OccupancyGrid::new(&opts).unwrap();
        let mut scratch = InsertScratch::new();
        let centre = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
        let range_max = rng.random_range(0.5..40.0);
        let scan = random_scan(&mut rng, centre, range_max, true, [300, 5, 3]);
        let (mut whole, mut piece) = (ScanUpdates::new(), ScanUpdates::new());
        // Dirty buffers from a scan before: both must start afresh.
        let other = random_scan(&mut rng, (0.0, 0.0), 20.0, case % 2 == 0, [100, 5, 3]);
        grid.trace_updates(&other, &mut scratch, &mut whole)
            .unwrap();
        let a = grid.trace_updates(&scan, &mut scratch, &mut whole).unwrap();
        let b = grid
            .trace_updates_part(&scan, 0..scan.points.len(), &mut scratch, &mut piece)
            .unwrap();
        assert_eq!(a, b, "case {case}");
        assert!(
            whole.heights && piece.heights && !whole.continues,
            "case {case}"
        );
        assert_eq!(whole.tiles, piece.tiles, "case {case}");
        assert_eq!(whole.updates, piece.updates, "case {case}");
        assert_eq!(whole.bin_marks, piece.bin_marks, "case {case}");
        assert_eq!(whole.stats, piece.stats, "case {case}");
        assert!(
            scratch.hmask.iter().all(|&m| m == 0),
            "case {case}: mask left dirty"
        );
    }
}

#[test]
fn vectorised_ray_bins_equal_the_per_step_bin() {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
    let special = [
        0.0,
        -0.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        f32::MIN,
        1e-30,
        0.64,
        3.04,
        1.76,
    ];
    let mut out = Vec::new();
    for case in 0..4_000 {
        let bins = [2, 5, 8, 16][case % 4];
        let layer = HeightLayer {
            bins,
            model: BinLogOdds::new(&crate::map::LogOddsParams::ese650(), 0.7),
            z_min_m: [0.64, -1.0, 0.0][case % 3],
            bins_per_m: [bins as f32 / 2.4, 1e-3, 1e6][(case / 3) % 3],
            dir: TileDir::default(),
        };
        let pick = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus, scale: f32| {
            if rng.random_range(0..6) == 0 {
                special[rng.random_range(0..special.len())]
            } else {
                rng.random_range(-scale..scale)
            }
        };
        let z0 = pick(&mut rng, 5.0);
        let dz = pick(&mut rng, 0.1);
        let n = rng.random_range(0..40);
        out.clear();
        out.resize(n, 0);
        layer.fill_bits(z0, dz, &mut out);
        let mut portable = vec![0; n];
        crate::kernels::heights::fill_bits_portable(&layer.scale(), z0, dz, &mut portable);
        assert_eq!(out, portable, "{z0} {dz}");
        for (s, &b) in out.iter().enumerate() {
            assert_eq!(
                b,
                layer.bit(z0 + s as i32 as f32 * dz),
                "{z0} {dz} step {s}"
            );
        }
    }
}

#[test]
fn optimised_insertion_equals_the_plain_rule() {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
    for case in 0..40 {
        let res = [0.05, 0.1, 0.37, 1.0][case % 4];
        let opts = MapOptions {
            resolution_m: res,
            free_margin_m: [0.0, 0.0, 0.2, 1.0][(case / 4) % 4],
            ..MapOptions::default()
        };
        let mut fast = OccupancyGrid::new(&opts).unwrap();
        let mut slow = OccupancyGrid::new(&opts).unwrap();
        let mut scratch = InsertScratch::new();
        let mut slow_bins = BTreeMap::new();
        for _ in 0..4 {
            let (sx, sy) = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
            let range_max = rng.random_range(0.5..40.0);
            // Cases 16-31 carry heights (a tilted scanner): the height-bin insertion.
            let heights = (case / 16) % 2 == 1;
            let scan = random_scan(&mut rng, (sx, sy), range_max, heights, [200, 5, 3]);
            let a = fast.insert_scan(&scan, &mut scratch).unwrap();
            let b = if scan.sensor_z_m.is_some() {
                insert_reference_heights(&mut slow, &mut slow_bins, &scan)
            } else {
                insert_reference(&mut slow, &scan)
            };
            assert_eq!(a, b, "case {case}");
        }
        for (c, bins) in &slow_bins {
            assert_eq!(fast.height_bins(*c), Some(&bins[..]), "case {case}");
        }
        assert_same_cells(&fast, &slow, case);
        assert!(
            scratch.mask.iter().all(|&m| m == MARK_NONE),
            "mask left dirty"
        );
    }
}

/// Same observed bounds and the same cells in them.
fn assert_same_cells(fast: &OccupancyGrid, slow: &OccupancyGrid, case: usize) {
    let (ra, rb) = (fast.observed_bounds(), slow.observed_bounds());
    assert_eq!(ra, rb, "case {case}");
    if let Some(r) = ra {
        let (mut va, mut vb) = (Vec::new(), Vec::new());
        fast.copy_rect_fixed(&r, &mut va);
        slow.copy_rect_fixed(&r, &mut vb);
        assert!(va == vb, "case {case}: cells differ");
    }
}

#[test]
fn consecutive_rays_into_one_cell_insert_as_the_plain_rule() {
    // Runs of rays ending within a cell of each other (a densified wall), some partial,
    // some without a return, on the planar path.
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(12);
    let mut same_cell = false;
    for case in 0..24 {
        let opts = MapOptions {
            resolution_m: [0.1, 0.37][case % 2],
            free_margin_m: [0.0, 0.2, 1.0][(case / 2) % 3],
            ..MapOptions::default()
        };
        let mut fast = OccupancyGrid::new(&opts).unwrap();
        let mut slow = OccupancyGrid::new(&opts).unwrap();
        let mut scratch = InsertScratch::new();
        for _ in 0..3 {
            let (sx, sy) = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
            let mut scan = random_scan(&mut rng, (sx, sy), 20.0, false, [60, 6, 4]);
            let mut points = Vec::new();
            for p in &scan.points {
                for _ in 0..rng.random_range(1..5) {
                    let mut q = *p;
                    q.x_m += rng.random_range(-0.03..0.03);
                    q.y_m += rng.random_range(-0.03..0.03);
                    points.push(q);
                }
            }
            let lim = fast.limits();
            same_cell |= points.windows(2).any(|w| {
                w[0].hit == w[1].hit
                    && lim.cell_of(w[0].x_m, w[0].y_m) == lim.cell_of(w[1].x_m, w[1].y_m)
            });
            scan.points = points;
            let a = fast.insert_scan(&scan, &mut scratch).unwrap();
            let b = insert_reference(&mut slow, &scan);
            assert_eq!(a, b, "case {case}");
        }
        assert_same_cells(&fast, &slow, case);
    }
    assert!(same_cell);
}

/// A random world scan around `(sx, sy)`: below `points` points, one in `no_return`
/// without a return, one in `partial` clearing only part of its ray; heights on when
/// `heights` (a sensor at 1.76 m).
fn random_scan(
    rng: &mut rand_xoshiro::Xoshiro256PlusPlus,
    (sx, sy): (f64, f64),
    range_max: f64,
    heights: bool,
    [points, no_return, partial]: [i32; 3],
) -> PlanarScan {
    let points = (0..rng.random_range(0..points))
        .map(|_| {
            let a = rng.random_range(-3.2..3.2f64);
            let r = rng.random_range(0.0..range_max);
            ScanPoint {
                x_m: sx + r * a.cos(),
                y_m: sy + r * a.sin(),
                hit: rng.random_range(0..no_return) > 0,
                free_to: if rng.random_range(0..partial) == 0 {
                    rng.random_range(-0.1..1.0)
                } else {
                    1.0
                },
                z_m: rng.random_range(-1.0..5.0),
            }
        })
        .collect();
    PlanarScan {
        sensor_x_m: sx,
        sensor_y_m: sy,
        sensor_z_m: heights.then_some(1.76),
        points,
    }
}

/// Same directory (placement, allocated tiles), same cells, same bins.
fn assert_same_grid(a: &OccupancyGrid, b: &OccupancyGrid, label: &str) {
    fn same_dir<T>(a: &TileDir<T>, b: &TileDir<T>, eq: impl Fn(&T, &T) -> bool) -> bool {
        (a.ti0, a.tj0, a.w, a.h) == (b.ti0, b.tj0, b.w, b.h)
            && a.tiles.len() == b.tiles.len()
            && a.tiles.iter().zip(&b.tiles).all(|(x, y)| match (x, y) {
                (Some(x), Some(y)) => eq(x, y),
                (None, None) => true,
                _ => false,
            })
    }
    assert!(
        same_dir(&a.dir, &b.dir, |x, y| x.cells[..] == y.cells[..]),
        "{label}: cells or tiles differ"
    );
    match (&a.height, &b.height) {
        (Some(x), Some(y)) => assert!(
            same_dir(&x.dir, &y.dir, |x, y| x.bins == y.bins),
            "{label}: bins differ"
        ),
        (None, None) => {}
        _ => panic!("{label}: one grid has bins"),
    }
}

#[test]
fn scans_split_into_pieces_apply_as_sequential_insertion() {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(12);
    for case in 0..24 {
        let mut opts = MapOptions {
            resolution_m: [0.1, 0.37][case % 2],
            free_margin_m: [0.0, 0.3][(case / 2) % 2],
            ..MapOptions::default()
        };
        opts.height.enabled = case % 3 != 0;
        // Half the cases clamp hard: two updates reach a bound, so the order of a
        // cell's updates decides its value.
        if (case / 4) % 2 == 1 {
            opts.log_odds.hit = 20.0;
            opts.log_odds.miss = -20.0;
            opts.log_odds.clamp_min = -40.0;
            opts.log_odds.clamp_max = 40.0;
        }
        let scans: Vec<PlanarScan> = (0..30)
            .map(|_| {
                let centre = (rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
                let heights = rng.random_range(0..3) > 0;
                let range_max = rng.random_range(0.5..12.0);
                random_scan(&mut rng, centre, range_max, heights, [150, 3, 4])
            })
            .collect();
        let mut seq = OccupancyGrid::new(&opts).unwrap();
        let mut scratch = InsertScratch::new();
        for scan in &scans {
            seq.insert_scan(scan, &mut scratch).unwrap();
        }
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut par = OccupancyGrid::new(&opts).unwrap();
            let mut start = 0;
            while start < scans.len() {
                let end = (start + rng.random_range(1..7)).min(scans.len());
                // Each scan cut at up to 3 random rays (empty pieces included).
                let mut pieces = Vec::new();
                for scan in &scans[start..end] {
                    let n = scan.points.len();
                    let mut cuts: Vec<usize> = (0..rng.random_range(0..4))
                        .map(|_| rng.random_range(0..=n))
                        .collect();
                    cuts.sort_unstable();
                    let mut from = 0;
                    for cut in cuts.into_iter().chain([n]) {
                        let mut out = ScanUpdates::new();
                        par.trace_updates_part(scan, from..cut, &mut scratch, &mut out)
                            .unwrap();
                        pieces.push(out);
                        from = cut;
                    }
                }
                let refs: Vec<&ScanUpdates> = pieces.iter().collect();
                pool.install(|| par.apply_updates(&refs));
                start = end;
            }
            assert_same_grid(&seq, &par, &format!("case {case}, {threads} threads"));
            assert!(scratch.mask.iter().all(|&m| m == MARK_NONE));
            assert!(scratch.hmask.iter().all(|&m| m == 0));
        }
    }
}
