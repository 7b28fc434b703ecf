use super::*;
use crate::map::{MapOptions, ScanPoint};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

fn random_body_scan(rng: &mut Xoshiro256PlusPlus, points: usize, heights: bool) -> PlanarScan {
    let range_max = rng.random_range(0.5..12.0);
    PlanarScan {
        sensor_x_m: 0.3,
        sensor_y_m: 0.0,
        sensor_z_m: heights.then_some(1.5),
        points: (0..points)
            .map(|_| {
                let a = rng.random_range(-3.2..3.2f64);
                let r = rng.random_range(0.0..range_max);
                ScanPoint {
                    x_m: 0.3 + r * a.cos(),
                    y_m: r * a.sin(),
                    hit: rng.random_range(0..3) > 0,
                    free_to: if rng.random_range(0..4) == 0 {
                        rng.random_range(0.0..1.0)
                    } else {
                        1.0
                    },
                    z_m: rng.random_range(-1.0..4.0),
                }
            })
            .collect(),
    }
}

/// Same allocated tiles, cells and bins (not the same directory: its slack depends on
/// the order tiles are created, and a batch creates them in its mask's order).
fn assert_same_grid(a: &OccupancyGrid, b: &OccupancyGrid, label: &str) {
    assert_eq!(a.tile_count(), b.tile_count(), "{label}");
    assert_eq!(a.height_tile_count(), b.height_tile_count(), "{label}");
    let r = a.allocated_bounds();
    assert_eq!(r, b.allocated_bounds(), "{label}");
    let Some(r) = r else { return };
    let (mut va, mut vb) = (Vec::new(), Vec::new());
    a.copy_rect_fixed(&r, &mut va);
    b.copy_rect_fixed(&r, &mut vb);
    assert!(va == vb, "{label}: cells differ");
    for j in r.min_j..=r.max_j {
        for i in r.min_i..=r.max_i {
            let c = crate::map::Cell { i, j };
            assert_eq!(a.height_bins(c), b.height_bins(c), "{label}: bins of {c:?}");
        }
    }
}

#[test]
fn split_rays_cover_every_ray_once_in_order() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let grid = OccupancyGrid::new(&MapOptions::default()).unwrap();
    let mut cum = Vec::new();
    for case in 0..200 {
        let n = rng.random_range(0..8);
        let scans: Vec<PlanarScan> = (0..n)
            .map(|_| {
                let k = rng.random_range(0..40);
                random_body_scan(&mut rng, k, false)
            })
            .collect();
        let parts = rng.random_range(1..5);
        let runs = split_rays(&grid, &scans, parts, &mut cum);
        assert!(runs.len() <= parts, "case {case}");
        let mut flat = Vec::new();
        for run in &runs {
            assert!(!run.is_empty(), "case {case}");
            for (k, rays) in run {
                assert!(!rays.is_empty(), "case {case}");
                flat.extend(rays.clone().map(|r| (*k, r)));
            }
        }
        let want: Vec<(usize, usize)> = scans
            .iter()
            .enumerate()
            .flat_map(|(k, s)| (0..s.points.len()).map(move |r| (k, r)))
            .collect();
        assert_eq!(flat, want, "case {case}");
    }
    // Five like scans on two threads: two and a half each, the middle scan cut.
    let scan = random_body_scan(&mut rng, 100, false);
    let scans = vec![scan; 5];
    let runs = split_rays(&grid, &scans, 2, &mut cum);
    assert_eq!(runs.len(), 2);
    assert_eq!(runs[0].len(), 3);
    assert_eq!(runs[1].len(), 3);
    assert_eq!(runs[0][2].0, 2);
    assert_eq!(runs[1][0].0, 2);
    assert_eq!(runs[0][2].1.end, runs[1][0].1.start);
}

#[test]
fn flush_equals_inserting_the_scans_one_by_one_for_any_thread_count() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
    for case in 0..12 {
        let mut opts = MapOptions {
            resolution_m: [0.1, 0.25][case % 2],
            free_margin_m: [0.0, 0.2][(case / 2) % 2],
            ..MapOptions::default()
        };
        opts.height.enabled = (case / 4) % 3 == 1;
        // Clamping-heavy cases: a cell reaches a bound in two updates, so the order of
        // its updates decides its value.
        if (case / 4) % 3 == 2 {
            opts.log_odds.hit = 20.0;
            opts.log_odds.miss = -20.0;
            opts.log_odds.clamp_min = -40.0;
            opts.log_odds.clamp_max = 40.0;
        }
        let heights = opts.height.enabled;
        // Flushes of 1 to 7 scans from poses near each other (as between two updates).
        let mut flushes = Vec::new();
        for _ in 0..8 {
            let k = rng.random_range(1..8);
            let scans: Vec<(Pose2, PlanarScan)> = (0..k)
                .map(|_| {
                    let pose = Pose2::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-3.0..3.0),
                    );
                    let points = rng.random_range(0..120);
                    (pose, random_body_scan(&mut rng, points, heights))
                })
                .collect();
            flushes.push(scans);
        }
        let mut want = OccupancyGrid::new(&opts).unwrap();
        let mut scratch = InsertScratch::new();
        let mut world = PlanarScan::default();
        for (pose, scan) in flushes.iter().flatten() {
            to_world(scan, pose, &mut world);
            want.insert_scan(&world, &mut scratch).unwrap();
        }
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut policy = BestParticleMap::new(OccupancyGrid::new(&opts).unwrap());
            for scans in &flushes {
                for (pose, scan) in scans {
                    policy.integrate_at(pose, scan).unwrap();
                }
                pool.install(|| policy.flush()).unwrap();
            }
            assert_same_grid(
                &want,
                &policy.grid,
                &format!("case {case}, {threads} threads"),
            );
        }
    }
}
