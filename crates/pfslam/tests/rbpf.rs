//! The Rao-Blackwellised mode (`[filter] mode = "rbpf"`): tile sharing between the particles'
//! maps, loop closure on a synthetic room, thread-count independence. (The Freiburg bags run
//! through the whole pipeline in `acceptance.rs`.)

use crate::filter::{ate_rmse, synthetic};
use pfslam::config::Config;
use pfslam::filter::FilterMode;
use pfslam::slam::{SlamResult, run_slam};

fn rbpf_config(particles: usize) -> Config {
    let mut config = Config::default();
    config.filter.mode = FilterMode::Rbpf;
    config.filter.particles = particles;
    config
}

fn run(rec: &pfslam::sensors::Recording, config: &Config, seed: u64) -> SlamResult {
    run_slam(rec, config, seed, &mut |_| {}).unwrap()
}

fn ring(radius_m: f64, n: usize) -> pfslam::map::PlanarScan {
    use pfslam::map::{PlanarScan, ScanPoint};
    PlanarScan {
        sensor_x_m: 0.0,
        sensor_y_m: 0.0,
        sensor_z_m: None,
        points: (0..n)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / n as f64;
                ScanPoint {
                    x_m: radius_m * a.cos(),
                    y_m: radius_m * a.sin(),
                    hit: true,
                    free_to: 1.0,
                    z_m: 0.0,
                }
            })
            .collect(),
    }
}

/// Per-particle maps share the tiles they did not change: 30 particles start from one map
/// (its tiles held once), and an update that writes a few tiles adds only those per
/// particle, not a copy of the whole map.
#[test]
fn per_particle_maps_share_tiles() {
    use pfslam::filter::rbpf::{Rbpf, RbpfOptions, UpdateScan};
    use pfslam::geometry::Pose2;
    use pfslam::map::{InsertScratch, MapOptions, OccupancyGrid};
    let mut grid = OccupancyGrid::new(&MapOptions {
        resolution_m: 0.05,
        ..MapOptions::default()
    })
    .unwrap();
    grid.insert_scan(&ring(15.0, 2000), &mut InsertScratch::new())
        .unwrap();
    let base = grid.tile_count();
    assert!(base > 80, "{base}");
    let start = Pose2::IDENTITY;
    let mut pf = Rbpf::new(30, start, start, grid, &RbpfOptions::default(), 1);
    let m0 = pf.map_memory();
    assert_eq!((m0.distinct_tiles, m0.total_tiles), (base, 30 * base));
    // A short-range scan (1 m ring): each particle writes the few tiles around the origin.
    let small = ring(1.0, 90);
    let pts: Vec<[f64; 2]> = small.points.iter().map(|p| [p.x_m, p.y_m]).collect();
    let delta = Pose2::new(0.3, 0.0, 0.0);
    let input = UpdateScan {
        scan_index: 1,
        odom_pose: delta,
        odom_delta: &delta,
        match_points_m: &pts,
        body_scan: &small,
        map_only: false,
    };
    pf.update(&input, Default::default()).unwrap();
    let m1 = pf.map_memory();
    eprintln!("tiles: base {base}, {m0:?} -> {m1:?}");
    assert!(m1.total_tiles >= 30 * base);
    assert!(
        m1.distinct_tiles <= base + 30 * 9,
        "distinct {} of {}",
        m1.distinct_tiles,
        m1.total_tiles
    );
    assert!(m1.distinct_tiles * 5 < m1.total_tiles, "{m1:?}");
}

/// 1.25 laps of a room with drifting odometry (2 % scale, 0.57 deg/s yaw drift): the filter
/// closes the loop (the final pose and the whole path stay near the truth) while dead
/// reckoning is metres off; every scan has a pose.
#[test]
fn loop_closes_in_a_synthetic_room() {
    let rec = synthetic::recording(30.0, 5);
    // 0.1 m cells and 20 particles keep the test fast (every scan sees the whole room, so
    // every update copies every tile of every particle's map).
    let mut config = rbpf_config(20);
    config.filter.rbpf.resolution_m = 0.1;
    let res = run(&rec, &config, 1);
    let gt = rec.ground_truth.as_ref().unwrap();
    assert_eq!(res.trajectory.len(), rec.scans.len());
    let slam = ate_rmse(&res.trajectory, gt);
    let dr = ate_rmse(&res.dead_reckoning, gt);
    let last = res.trajectory.last().unwrap().pose;
    let last_gt = gt.last().unwrap().pose;
    let end_err = (last.x_m - last_gt.x_m).hypot(last.y_m - last_gt.y_m);
    let end_err_dr = {
        let p = res.dead_reckoning.last().unwrap().pose;
        (p.x_m - last_gt.x_m).hypot(p.y_m - last_gt.y_m)
    };
    eprintln!(
        "synthetic loop: ATE slam {slam:.3} m, dead reckoning {dr:.3} m; end error {end_err:.3} m (dr {end_err_dr:.3} m); {:?}",
        res.stats
    );
    assert!(
        dr > 0.5 && end_err_dr > 1.0,
        "the odometry drifts: {dr} {end_err_dr}"
    );
    assert!(slam < 0.05, "ATE {slam}");
    assert!(end_err < 0.15, "end error {end_err}");
}

/// Bit-identical with 1 and 2 threads (per-chunk random streams), resampling exercised; the
/// seed matters.
#[test]
fn rbpf_is_bit_identical_with_1_and_2_threads() {
    let rec = synthetic::recording(12.0, 9);
    let mut config = rbpf_config(20);
    config.filter.rbpf.resolution_m = 0.1;
    let on = |threads: usize, seed: u64| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run(&rec, &config, seed))
    };
    let a = on(1, 77);
    let b = on(2, 77);
    assert!(a.stats.resamples > 0, "{:?}", a.stats);
    assert_eq!(a.trajectory, b.trajectory);
    assert_eq!(a.stats.neff_mean.to_bits(), b.stats.neff_mean.to_bits());
    assert_ne!(a.trajectory, on(2, 78).trajectory, "the seed matters");
}

#[test]
fn auto_mode_picks_rbpf_for_a_level_lidar_and_scan_match_for_the_car() {
    use pfslam::filter::FilterMode;
    use pfslam::geometry::Rigid3;
    let mut rec = synthetic::recording(5.0, 5);
    rec.body_from_lidar = Rigid3::IDENTITY;
    assert_eq!(FilterMode::Auto.resolve(&rec), FilterMode::Rbpf);
    // An explicit mode is kept.
    assert_eq!(FilterMode::ScanMatch.resolve(&rec), FilterMode::ScanMatch);
    assert_eq!(FilterMode::Seed.resolve(&rec), FilterMode::Seed);
    // The car's LMS511 mount (tilted, equation 8 of the UCSD report).
    rec.body_from_lidar = pfslam::sensors::CarCalibration::ucsd().body_from_lidar;
    assert_eq!(FilterMode::Auto.resolve(&rec), FilterMode::ScanMatch);
    // A level mount that moves on the body (a humanoid's head).
    rec.body_from_lidar = Rigid3::IDENTITY;
    rec.body_from_lidar_per_scan = Some(vec![Rigid3::IDENTITY; rec.scans.len()]);
    assert_eq!(FilterMode::Auto.resolve(&rec), FilterMode::ScanMatch);
    // 2 degrees of pitch is not level.
    rec.body_from_lidar_per_scan = None;
    rec.body_from_lidar = Rigid3::from_rpy(0.0, 2f64.to_radians(), 0.0, [0.0; 3]);
    assert_eq!(FilterMode::Auto.resolve(&rec), FilterMode::ScanMatch);
}
