//! Occupancy mapping: synthetic worlds with exact poses, the simulator's car world with its
//! ground-truth poses, and the map files.

use pfslam::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
use pfslam::map::{
    BinaryMap, Cell, CellState, InsertScratch, MapLimits, MapOptions, OccupancyGrid, ScanOptions,
    ScanProjector, compare_maps, map_with_poses, to_world,
};
use pfslam::sensors::{LidarGeometry, Recording, ScanSet};
use pfslam_io::map_files::{read_map_server, read_npy_f32, write_logodds_npy, write_map_server};

/// Distance from `(x, y)` along `(dx, dy)` to the walls of the axis-aligned box
/// `[0, 20] x [0, 10]` seen from inside, and to a 1 m pillar at (14..15, 4..5).
fn cast(x: f64, y: f64, dx: f64, dy: f64) -> f64 {
    let mut best = f64::INFINITY;
    let mut slab = |lo: [f64; 2], hi: [f64; 2], inside: bool| {
        // Ray/box intersection: entry (outside) or exit (inside) distance.
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        for (o, d, l, h) in [(x, dx, lo[0], hi[0]), (y, dy, lo[1], hi[1])] {
            if d.abs() < 1e-12 {
                if o < l || o > h {
                    return;
                }
                continue;
            }
            let (a, b) = ((l - o) / d, (h - o) / d);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        if t0 > t1 {
            return;
        }
        let t = if inside { t1 } else { t0 };
        if t > 0.0 {
            best = best.min(t);
        }
    };
    slab([0.0, 0.0], [20.0, 10.0], true);
    slab([14.0, 4.0], [15.0, 5.0], false);
    best
}

fn synthetic_truth(res: f64) -> BinaryMap {
    let limits = MapLimits::new(res, -1.0, -1.0);
    let (w, h) = ((22.0 / res).round() as usize, (12.0 / res).round() as usize);
    let mut m = BinaryMap::filled(limits, w, h, CellState::Unknown);
    for j in 0..h as i32 {
        for i in 0..w as i32 {
            let (x, y) = limits.cell_centre(Cell::new(i, j));
            let wall = !(0.0..20.0).contains(&x) || !(0.0..10.0).contains(&y);
            let pillar = (14.0..15.0).contains(&x) && (4.0..5.0).contains(&y);
            let outside = x < -res || x > 20.0 + res || y < -res || y > 10.0 + res;
            let s = if outside {
                CellState::Unknown
            } else if wall || pillar {
                CellState::Occupied
            } else {
                CellState::Free
            };
            m.set(i as i64, j as i64, s);
        }
    }
    m
}

/// A 360-beam planar scanner mounted 0.5 m ahead of the body origin.
fn scanner() -> (LidarGeometry, Rigid3) {
    let geometry = LidarGeometry {
        angle_min_rad: -std::f64::consts::PI,
        angle_increment_rad: 1f64.to_radians(),
        beam_count: 360,
        range_min_m: 0.0,
        range_max_m: 30.0,
    };
    (geometry, Rigid3::from_rpy(0.0, 0.0, 0.0, [0.5, 0.0, 0.3]))
}

fn synthetic_recording(poses: &[Pose2]) -> Recording {
    let (geometry, mount) = scanner();
    let mut scans = ScanSet::new(geometry.beam_count);
    for (k, p) in poses.iter().enumerate() {
        let (sx, sy) = p.transform_point(0.5, 0.0);
        let ranges: Vec<f32> = (0..geometry.beam_count)
            .map(|b| {
                let a = p.yaw_rad + geometry.beam_angle_rad(b);
                let r = cast(sx, sy, a.cos(), a.sin());
                if r < geometry.range_max_m as f64 {
                    r as f32
                } else {
                    0.0
                }
            })
            .collect();
        scans.push(k as i64 * 100_000_000, &ranges);
    }
    Recording {
        name: "synthetic".into(),
        scans,
        lidar: geometry,
        body_from_lidar: mount,
        ..Recording::default()
    }
}

/// The UCSD log-odds over returns from 0.1 m on, without densification.
fn plain_map_options() -> MapOptions {
    MapOptions {
        scan: ScanOptions {
            range_min_m: 0.1,
            densify_max_gap_m: None,
            ..ScanOptions::default()
        },
        log_odds: pfslam::map::LogOddsParams::ucsd(),
        ..MapOptions::default()
    }
}

#[test]
fn one_known_scan_marks_walls_and_free_space() {
    let pose = Pose2::new(4.0, 3.0, 0.3);
    let rec = synthetic_recording(&[pose]);
    let opts = plain_map_options();
    let mut grid = OccupancyGrid::new(&opts).unwrap();
    let projector = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &opts.scan).unwrap();
    let (mut body, mut world) = Default::default();
    projector.to_body(rec.scans.ranges(0), &mut body).unwrap();
    to_world(&body, &pose, &mut world);
    let stats = grid.insert_scan(&world, &mut InsertScratch::new()).unwrap();
    assert_eq!(stats.rays, 360);
    // Every return's end cell is occupied and lies on a wall or the pillar.
    let truth = synthetic_truth(0.1);
    for p in &world.points {
        let c = grid.cell_of(p.x_m, p.y_m);
        assert_eq!(grid.state(c), CellState::Occupied);
        let (x, y) = grid.limits().cell_centre(c);
        let near_wall = [(0.0, 0.0), (0.1, 0.0), (-0.1, 0.0), (0.0, 0.1), (0.0, -0.1)]
            .iter()
            .any(|(dx, dy)| truth.state_at(x + dx, y + dy) == CellState::Occupied);
        assert!(near_wall, "end cell {c:?} at ({x}, {y}) is not on a wall");
    }
    // The space between the sensor and the wall ahead is free; behind the pillar unknown.
    let sensor = grid.cell_of(world.sensor_x_m, world.sensor_y_m);
    assert_eq!(grid.state(sensor), CellState::Free);
    assert_eq!(grid.state(grid.cell_of(8.0, 3.0)), CellState::Free);
    assert_eq!(grid.state(grid.cell_of(17.0, 4.9)), CellState::Unknown);
    let c = compare_maps(&grid.to_binary_map(None), &truth, 1).unwrap();
    assert!(c.precision() > 0.99, "{c}");
    assert!(c.free_agreement() > 0.99, "{c}");
}

#[test]
fn synthetic_drive_with_exact_poses_matches_the_truth() {
    // A loop around the pillar, 0.1 m apart.
    let mut poses = Vec::new();
    let waypoints: [(f64, f64); 5] = [(3.0, 2.0), (17.0, 2.0), (17.0, 8.0), (3.0, 8.0), (3.0, 2.0)];
    for w in waypoints.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        let yaw = (y1 - y0).atan2(x1 - x0);
        let n = ((x1 - x0).hypot(y1 - y0) / 0.25) as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            poses.push(Pose2::new(x0 + t * (x1 - x0), y0 + t * (y1 - y0), yaw));
        }
    }
    let rec = synthetic_recording(&poses);
    let traj = Trajectory::new(
        poses
            .iter()
            .enumerate()
            .map(|(k, p)| StampedPose2 {
                stamp_ns: k as i64 * 100_000_000,
                pose: *p,
            })
            .collect(),
    );
    let opts = plain_map_options();
    let (grid, last, stats) = map_with_poses(&rec, &traj, &opts).unwrap();
    assert_eq!(stats.scans_inserted, poses.len());
    assert_eq!(last.points.len(), 360);
    let c = compare_maps(&grid.to_binary_map(None), &synthetic_truth(0.1), 1).unwrap();
    eprintln!("synthetic drive: {c}");
    assert!(c.precision() >= 0.99, "{c}");
    assert!(c.recall() >= 0.99, "{c}");
    // Unmatched true walls: only the pillar's interior (never reachable), <= 8 x 8 cells.
    let unmatched = c.true_occupied_in_extent - c.true_occupied_in_extent_matched;
    assert!(unmatched <= 64, "{unmatched}: {c}");
    assert!(c.free_agreement() >= 0.999, "{c}");
    // Memory follows the visited area: 22 x 12 m at 0.1 m is a few 6.4 m tiles.
    assert!(grid.tile_count() <= 16, "{}", grid.tile_count());
}

/// Maps the simulator's default car world (`campus`, noise-free car) with its ground-truth
/// poses and compares with true maps written and read back as map_server files.
///
/// Two deviations from "the whole default drive against the default true map", both stated
/// in the report:
/// - only the second leg of the route (north along the inner street x = 120 m) is mapped: on
///   the first leg the car drives through the outer row of buildings (the simulator's
///   `facade_row` places the outer rows on the outer streets: 1,350 of the first 3,600 true
///   poses lie inside a building footprint);
/// - the map keeps returns between 2.1 and 2.5 m above the ground, and the true map used for
///   the assertions shows the obstacles in that same band (`TrueMap::rasterize` with that
///   band). The car's LiDAR sits at 1.76 m and is tilted (its centre beam rises 37 deg): a
///   2-D map of a 3-D world is only well defined for a height band in which every obstacle
///   is full height. In 2.1-2.5 m no obstacle of the campus starts or ends (parked cars are
///   at most 2.1 m, tree canopies start at 2.6 m), so a ray to a return in the band is free
///   where the band is free. The default band (1-4 m) contains car roofs and canopy bottoms
///   that rays pass over or under; the figures against it are printed too.
fn campus_leg(z_window_m: [f64; 2], band_m: [f64; 2]) -> (OccupancyGrid, BinaryMap, BinaryMap) {
    use pfslam_sim::{SimOptions, TrueMap, World, simulate_car};
    let sim_opts = SimOptions {
        duration_s: 36.0,
        ..SimOptions::noise_free()
    };
    let world = World::builtin(sim_opts.world_name()).unwrap();
    let out = simulate_car(&world, &sim_opts).unwrap();
    let rec = Recording {
        name: "campus".into(),
        scans: out.dataset.lidar.clone(),
        lidar: out.dataset.calibration.lidar,
        body_from_lidar: out.dataset.calibration.body_from_lidar,
        ..Recording::default()
    };
    let leg: Vec<StampedPose2> = out
        .ground_truth
        .iter()
        .filter(|g| (g.pose.yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 0.02)
        .copied()
        .collect();
    assert!(leg.len() > 1000, "{}", leg.len());
    assert!(leg.iter().all(|g| {
        !world
            .prisms
            .iter()
            .any(|p| p.contains_xy(g.pose.x_m, g.pose.y_m))
    }));
    let opts = MapOptions {
        scan: ScanOptions {
            z_min_m: Some(z_window_m[0]),
            z_max_m: Some(z_window_m[1]),
            ..ScanOptions::default()
        },
        ..MapOptions::default()
    };
    let (grid, _, stats) = map_with_poses(&rec, &Trajectory::new(leg), &opts).unwrap();
    assert!(stats.scans_inserted > 1000);
    let dir = tempfile::tempdir().unwrap();
    let read = |band: [f64; 2], stem: &str| {
        let t = TrueMap::rasterize(&world, sim_opts.truth_map_resolution_m, band, 20.0);
        pfslam_sim::dataset::write_true_map(&t, dir.path(), stem).unwrap();
        read_map_server(&dir.path().join(format!("{stem}.yaml"))).unwrap()
    };
    let matched = read(band_m, "true_map_band");
    let default = read(
        [sim_opts.truth_band_min_m, sim_opts.truth_band_max_m],
        "true_map",
    );
    (grid, matched, default)
}

#[test]
fn simulated_campus_with_ground_truth_matches_the_true_map() {
    let (grid, truth, default_truth) = campus_leg([2.1, 2.5], [2.1, 2.5]);
    let est = grid.to_binary_map(None);
    let c = compare_maps(&est, &truth, 1).unwrap();
    let d = compare_maps(&est, &default_truth, 1).unwrap();
    eprintln!("campus leg, band 2.1-2.5 m: {c}");
    eprintln!("campus leg vs default true map (1-4 m): {d}");
    if let Ok(d) = std::env::var("PFSLAM_MAP_DEBUG_DIR") {
        write_diff_png(&est, &truth, &std::path::Path::new(&d).join("diff.png"));
    }
    assert!(c.precision() >= 0.95, "{c}");
    assert!(c.recall() >= 0.95, "{c}");
    assert!(c.free_agreement() >= 0.95, "{c}");
}

/// Debugging aid: estimate vs truth (black: estimated occupied, white: free on true free,
/// red: free on a true wall, blue: true wall not estimated, grey: unknown).
fn write_diff_png(est: &BinaryMap, truth: &BinaryMap, path: &std::path::Path) {
    let mut img = image::RgbImage::new(est.width as u32, est.height as u32);
    for j in 0..est.height {
        for i in 0..est.width {
            let (x, y) = est.limits.cell_centre(Cell::new(i as i32, j as i32));
            let c = match (est.get(i as i64, j as i64), truth.state_at(x, y)) {
                (CellState::Occupied, _) => [0, 0, 0],
                (CellState::Free, CellState::Occupied) => [255, 0, 0],
                (CellState::Free, _) => [255, 255, 255],
                (_, CellState::Occupied) => [0, 0, 160],
                _ => [128, 128, 128],
            };
            img.put_pixel(i as u32, (est.height - 1 - j) as u32, image::Rgb(c));
        }
    }
    img.save(path).unwrap();
}

#[test]
fn map_files_roundtrip_for_a_mapped_grid() {
    let pose = Pose2::new(4.0, 3.0, 0.3);
    let rec = synthetic_recording(&[pose]);
    let traj = Trajectory::new(vec![StampedPose2 { stamp_ns: 0, pose }]);
    let opts = MapOptions::default().with_preset(pfslam::map::LogOddsPreset::Ucsd);
    let (grid, _, _) = map_with_poses(&rec, &traj, &opts).unwrap();
    let rect = grid.observed_bounds().unwrap();
    let bin = grid.to_binary_map(Some(rect));
    let dir = tempfile::tempdir().unwrap();
    write_map_server(&bin, &dir.path().join("map.yaml")).unwrap();
    let back = read_map_server(&dir.path().join("map.yaml")).unwrap();
    assert_eq!(back.width, bin.width);
    assert_eq!(back.cells, bin.cells);
    assert!((back.limits.origin_x_m() - bin.limits.origin_x_m()).abs() < 1e-9);
    write_logodds_npy(&grid, &rect, &dir.path().join("logodds.npy")).unwrap();
    let (shape, data) = read_npy_f32(&dir.path().join("logodds.npy")).unwrap();
    assert_eq!(shape, vec![rect.height(), rect.width()]);
    // Spot-check: pixel (row, col) is cell (min_i + col, max_j - row).
    for (row, col) in [(0, 0), (5, 17), (rect.height() - 1, rect.width() - 1)] {
        let c = Cell::new(rect.min_i + col as i32, rect.max_j - row as i32);
        assert_eq!(data[row * rect.width() + col], grid.logodds(c) as f32);
    }
    assert!(data.iter().any(|&v| v > 1.0) && data.iter().any(|&v| v < -1.0));
}

/// Mapping the whole default drive (180 s, default simulated errors) with the true poses,
/// judged by the simulator's scan-surface truth (`pfslam_sim::scan_truth`: what the tilted
/// LiDAR's beams can face with line of sight within 75 m, traced from the world's solids and
/// the true poses, never from the simulated ranges). Measured with the default `[map.height]`
/// bins and the default truth (the sensor's 286 beams from every 10th pose): precision
/// 0.9996, free agreement 1.000, recall 0.9855 of 30,721 visible surface cells. The same
/// beams from every 2nd pose: recall 0.958 of 43,741; from every pose 0.937 of 50,951 (cells
/// a single grazing beam reached once are outvoted by the passes at their height). One
/// log-odds value per cell (bins off) against the older 0.1 deg uniform-ray truth: 0.681.
#[test]
fn whole_default_drive_with_ground_truth_vs_scan_surface_truth() {
    use pfslam_sim::{SimOptions, World, simulate_car};
    let sim_opts = SimOptions::default();
    let world = World::builtin(sim_opts.world_name()).unwrap();
    let out = simulate_car(&world, &sim_opts).unwrap();
    let rec = out.recording(&Default::default()).unwrap();
    let gt = Trajectory::new(out.ground_truth.clone());
    let (grid, _, stats) = map_with_poses(&rec, &gt, &MapOptions::default()).unwrap();
    assert_eq!(stats.scans_without_pose, 0);
    let est = grid.to_binary_map(None);
    let c = out.scan_truth.compare(&est, 1).unwrap();
    let band = compare_maps(&est, &out.true_map.to_binary_map(), 1).unwrap();
    eprintln!("whole drive vs scan-surface truth: {c}");
    eprintln!("whole drive vs fixed-band truth (1.7-4 m): {band}");
    assert!(c.true_occupied_observed > 30_000, "{c}");
    assert!(c.precision() >= 0.995, "{c}");
    assert!(c.free_agreement() >= 0.99, "{c}");
    assert!(c.recall() >= 0.95, "{c}");
}
