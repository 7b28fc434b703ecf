//! Batched mapping: batches of scans inserted in parallel give the grid sequential insertion
//! gives, whatever the thread count; the motion filter's choice of scans. On the simulated
//! car with its true poses.

use pfslam::geometry::{Rigid3, StampedPose2, Trajectory};
use pfslam::map::{
    Cell, HeightOptions, MAP_BATCH_SCANS, MapOptions, MappingStats, OccupancyGrid, PlanarScan,
    ScanInserter, ScanProjector, map_with_poses, scans_to_map,
};
use pfslam::sensors::Recording;
use pfslam_sim::{CarSimOutput, SimOptions};

/// [`map_with_poses`] without batches: each scan inserted in turn (the oracle).
fn map_with_poses_sequential(
    recording: &Recording,
    poses: &Trajectory,
    opts: &MapOptions,
) -> (OccupancyGrid, PlanarScan, MappingStats) {
    let mut grid = OccupancyGrid::new(opts).unwrap();
    let projector =
        ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &opts.scan).unwrap();
    let mut ins = ScanInserter::new(projector);
    let mut stats = MappingStats::default();
    for k in scans_to_map(recording, poses, opts) {
        let Some(pose) = poses.pose_at(recording.scans.stamps_ns[k]) else {
            stats.scans_without_pose += 1;
            continue;
        };
        ins.projector.aim(recording, k);
        let ranges = recording.scans.ranges(k);
        stats.rays += ins.insert(&mut grid, ranges, &pose).unwrap().rays;
        stats.scans_inserted += 1;
    }
    (grid, ins.world, stats)
}

/// Every observable of two grids: tiles, directory size, cells and height bins.
fn assert_same_grid(a: &OccupancyGrid, b: &OccupancyGrid, what: &str) {
    assert_eq!(a.tile_count(), b.tile_count(), "{what}");
    assert_eq!(a.height_tile_count(), b.height_tile_count(), "{what}");
    assert_eq!(a.memory_bytes(), b.memory_bytes(), "{what}");
    let r = a.allocated_bounds().unwrap();
    assert_eq!(Some(r), b.allocated_bounds(), "{what}");
    let (mut va, mut vb) = (Vec::new(), Vec::new());
    a.copy_rect_fixed(&r, &mut va);
    b.copy_rect_fixed(&r, &mut vb);
    assert!(va == vb, "{what}: cells differ");
    assert!(va.iter().filter(|&&v| v != 0).count() > 10_000, "{what}");
    let mut binned = 0;
    for j in r.min_j..=r.max_j {
        for i in r.min_i..=r.max_i {
            let c = Cell::new(i, j);
            assert_eq!(a.height_bins(c), b.height_bins(c), "{what}: bins of {c:?}");
            binned += usize::from(a.height_bins(c).is_some_and(|s| s.iter().any(|&v| v != 0)));
        }
    }
    if a.height_tile_count() > 0 {
        assert!(binned > 10_000, "{what}: {binned} binned cells");
    }
}

/// The noise-free simulated car driving `duration_s` seconds: its output and recording.
fn simulated_car(duration_s: f64) -> (CarSimOutput, Recording) {
    crate::common::simulated_car(&SimOptions {
        duration_s,
        ..SimOptions::noise_free()
    })
}

#[test]
fn batched_parallel_mapping_equals_sequential_insertion_for_any_thread_count() {
    let (out, car) = simulated_car(14.0);
    // A LiDAR moving on the body, level on even scans and tilted on odd ones: one grid gets
    // 2-D and height-bin updates, whose order per cell matters.
    let level = Rigid3::from_rpy(0.0, 0.0, std::f64::consts::FRAC_PI_2, [0.8, 0.0, 1.5]);
    let mut nodding = car.clone();
    nodding.body_from_lidar_per_scan = Some(
        (0..car.scans.len())
            .map(|k| {
                if k % 2 == 0 {
                    level
                } else {
                    car.body_from_lidar
                }
            })
            .collect(),
    );
    // Poses covering all but the first and last second of scans (some scans have none).
    let truth: Vec<StampedPose2> = out.ground_truth[100..out.ground_truth.len() - 100].to_vec();
    let poses = Trajectory::new(truth);
    let flat = MapOptions {
        height: HeightOptions {
            enabled: false,
            ..HeightOptions::default()
        },
        ..MapOptions::default()
    };
    let margin = MapOptions {
        free_margin_m: 0.3,
        scan_step: 3,
        ..MapOptions::default()
    };
    let thinned = MapOptions {
        min_scan_travel_m: 0.15,
        ..MapOptions::default()
    };
    let cases = [
        ("heights", &car, MapOptions::default()),
        ("flat", &car, flat),
        ("margin, step 3", &car, margin),
        ("motion filter", &car, thinned),
        ("moving mount", &nodding, MapOptions::default()),
    ];
    for (name, rec, opts) in cases {
        let (want, want_last, want_stats) = map_with_poses_sequential(rec, &poses, &opts);
        assert!(want_stats.scans_inserted > 2 * MAP_BATCH_SCANS, "{name}");
        assert!(want_stats.scans_without_pose > 0, "{name}");
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let (got, last, stats) = pool.install(|| map_with_poses(rec, &poses, &opts)).unwrap();
            let what = format!("{name}, {threads} threads");
            assert_eq!(stats, want_stats, "{what}");
            assert_eq!(last, want_last, "{what}");
            assert_same_grid(&got, &want, &what);
        }
    }
}

#[test]
fn motion_filter_keeps_scans_spaced_by_travel_or_turn() {
    let (out, car) = simulated_car(20.0);
    let poses = Trajectory::new(out.ground_truth.clone());
    let n = car.scans.len();
    let every = MapOptions::default();
    assert_eq!(
        scans_to_map(&car, &poses, &every),
        (0..n).collect::<Vec<_>>()
    );
    let step = MapOptions {
        scan_step: 3,
        ..MapOptions::default()
    };
    assert_eq!(
        scans_to_map(&car, &poses, &step),
        (0..n).step_by(3).collect::<Vec<_>>()
    );
    for (travel_m, turn_deg) in [(0.1, 1.0), (0.3, 0.0), (0.3, 2.0)] {
        let opts = MapOptions {
            min_scan_travel_m: travel_m,
            min_scan_turn_deg: turn_deg,
            ..MapOptions::default()
        };
        let kept = scans_to_map(&car, &poses, &opts);
        assert!(
            kept.len() > 10 && kept.len() < n / 2,
            "{travel_m}: {}",
            kept.len()
        );
        assert_eq!(kept[0], 0);
        let pose = |k: usize| poses.pose_at(car.scans.stamps_ns[k]).unwrap();
        let passes = |from: usize, to: usize| {
            let d = pose(from).between(&pose(to));
            d.translation_norm_m() >= travel_m
                || (turn_deg > 0.0 && d.yaw_rad.abs() >= turn_deg.to_radians())
        };
        // Every kept scan passes the filter against the previous kept one, and every
        // dropped scan fails it against the last kept one before it.
        for w in kept.windows(2) {
            assert!(passes(w[0], w[1]), "{travel_m}: scan {}", w[1]);
            for k in w[0] + 1..w[1] {
                assert!(!passes(w[0], k), "{travel_m}: scan {k} dropped");
            }
        }
    }
}
