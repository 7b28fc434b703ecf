//! The simulator: geometry against closed form, dead reckoning on simulated data, ground
//! truth consistency, determinism, the humanoid layout round trip.

use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
use pfslam::motion::{MotionOptions, dead_reckon};
use pfslam::sensors::CarCalibration;
use pfslam_io::humanoid::read_humanoid_dataset;
use pfslam_sim::dataset::{read_beam_labels, write_car_sim, write_humanoid_sim};
use pfslam_sim::humanoid::{BEAM_FLOOR, BEAM_OBSTACLE};
use pfslam_sim::{
    HitKind, Prism, RayCaster, SimOptions, TrueMap, Vehicle, World, simulate_car, simulate_humanoid,
};
use std::path::Path;

fn wall_world(wall_x_m: f64, height_m: f64) -> World {
    World {
        name: "wall".into(),
        // 1 m thick, 200 m wide wall whose face is the plane x = wall_x_m
        prisms: vec![
            Prism::new(
                "wall",
                vec![
                    [wall_x_m, -100.0],
                    [wall_x_m + 1.0, -100.0],
                    [wall_x_m + 1.0, 100.0],
                    [wall_x_m, 100.0],
                ],
                0.0,
                height_m,
            )
            .unwrap(),
        ],
        ground: Default::default(),
        // the car stands at the first point, on a straight heading +x (initial standstill
        // longer than the run)
        route: vec![[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [-5.0, 5.0], [-5.0, 0.0]],
    }
}

/// Closed form for the car at the origin (yaw 0): plane x = D with 0 <= z <= H, |y| <= 100,
/// and the ground z = 0; 0.0 when neither is within 80 m. With what was hit: 0 nothing,
/// 1 wall, 2 ground.
fn analytic_ranges(wall_x_m: f64, height_m: f64) -> Vec<(f64, u8)> {
    let cal = CarCalibration::ucsd();
    let bl = cal.body_from_lidar;
    let o = bl.translation;
    (0..cal.lidar.beam_count)
        .map(|i| {
            let a = cal.lidar.beam_angle_rad(i);
            let d = bl.rotation * nalgebra::Vector3::new(a.cos(), a.sin(), 0.0);
            let d = d / d.norm();
            let mut best = (f64::INFINITY, 0u8);
            if d[0] > 0.0 {
                let t = (wall_x_m - o[0]) / d[0];
                let z = o[2] + t * d[2];
                let y = o[1] + t * d[1];
                if (0.0..=height_m).contains(&z) && y.abs() <= 100.0 {
                    best = (t, 1);
                }
            }
            if d[2] < 0.0 && -o[2] / d[2] < best.0 {
                best = (-o[2] / d[2], 2);
            }
            if best.0 < 80.0 { best } else { (0.0, 0) }
        })
        .collect()
}

fn standing_options(duration_s: f64) -> SimOptions {
    let mut o = SimOptions::noise_free();
    o.duration_s = duration_s;
    o.car.initial_standstill_s = duration_s + 10.0;
    o
}

#[test]
fn tilted_lidar_against_closed_form() {
    let mut wall_beams = Vec::new();
    for (wall_x, height) in [(15.0, 10.0), (15.0, 40.0), (6.0, 8.0)] {
        let world = wall_world(wall_x, height);
        let out = simulate_car(&world, &standing_options(0.05)).unwrap();
        assert_eq!(out.ground_truth[0].pose, Pose2::IDENTITY);
        let expected = analytic_ranges(wall_x, height);
        let scan = out.dataset.lidar.ranges(0);
        let mut counts = [0usize; 3];
        for (i, (&r, &(e, kind))) in scan.iter().zip(&expected).enumerate() {
            assert!(
                (f64::from(r) - e).abs() < 1e-4,
                "wall {wall_x} m x {height} m, beam {i}: simulated {r}, closed form {e}"
            );
            counts[kind as usize] += 1;
        }
        eprintln!("wall at {wall_x} m, {height} m high: [none, wall, ground] beams = {counts:?}");
        assert!(counts[2] > 0, "{counts:?}");
        wall_beams.push(counts[1]);
    }
    // The scan plane rises ~37 deg forward: it meets a wall 15 m ahead ~12.5 m up, so a 10 m
    // wall there is invisible, a 40 m one is seen by most forward beams, a 8 m wall 6 m ahead
    // is seen.
    assert_eq!(wall_beams[0], 0, "{wall_beams:?}");
    assert!(wall_beams[1] > 100 && wall_beams[2] > 100, "{wall_beams:?}");
    // ground only: the downward edge beams hit the ground at the closed-form distance
    let world = wall_world(500.0, 1.0);
    let caster = RayCaster::new(&world, 4.0, 100.0);
    let cal = CarCalibration::ucsd();
    let o = cal.body_from_lidar.translation;
    let d = cal.body_from_lidar.rotation
        * nalgebra::Vector3::new(
            (-5.0f64).to_radians().cos(),
            (-5.0f64).to_radians().sin(),
            0.0,
        );
    let hit = caster
        .cast([o[0], o[1], o[2]], [d[0], d[1], d[2]], 80.0)
        .unwrap();
    assert_eq!(hit.kind, HitKind::Ground);
    let p = o + d * hit.range_m;
    assert!(p[2].abs() < 1e-9);
    // beam 0 (-5 deg) points left (lidar x = body +y) and slightly down: ~33 m left
    assert!(p[1] > 25.0 && p[1] < 40.0 && p[0].abs() < 3.0, "{p:?}");
}

/// Dead reckoning at the ground-truth stamps (linear interpolation between encoder stamps).
fn position_errors(dr: &Trajectory, gt: &[StampedPose2]) -> Vec<f64> {
    gt.iter()
        .filter_map(|g| {
            let p = dr.pose_at(g.stamp_ns)?;
            Some((p.x_m - g.pose.x_m).hypot(p.y_m - g.pose.y_m))
        })
        .collect()
}

#[test]
fn noise_free_dead_reckoning_matches_ground_truth_over_1km() {
    let world = World::builtin("campus").unwrap();
    let mut opts = SimOptions::noise_free();
    opts.duration_s = 135.0;
    let out = simulate_car(&world, &opts).unwrap();
    let gt_len = Trajectory::new(out.ground_truth.clone()).path_length_m();
    assert!(gt_len > 1000.0, "drove {gt_len} m");
    assert_eq!(out.ground_truth[0].pose, Pose2::IDENTITY);
    let dr = dead_reckon(&out.dataset, &MotionOptions::default()).unwrap();
    let errs = position_errors(&dr, &out.ground_truth);
    assert!(errs.len() + 2 >= out.ground_truth.len());
    let rec = out.recording(&MotionOptions::default()).unwrap();
    assert_eq!(rec.odometry, dr);
    assert_eq!(rec.ground_truth.as_deref(), Some(&out.ground_truth[..]));
    let max = errs.iter().cloned().fold(0.0, f64::max);
    eprintln!("noise-free dead reckoning over {gt_len:.0} m: max position error {max:.5} m");
    assert!(max < 0.01, "max error {max} m");
    let g = &out.ground_truth[out.ground_truth.len() - 3];
    let dyaw =
        pfslam::geometry::wrap_angle(dr.pose_at(g.stamp_ns).unwrap().yaw_rad - g.pose.yaw_rad);
    assert!(dyaw.abs() < 1e-4, "{dyaw}");
}

#[test]
fn default_errors_make_dead_reckoning_drift_by_metres() {
    let world = World::builtin("campus").unwrap();
    let opts = SimOptions {
        duration_s: 180.0,
        ..SimOptions::default()
    };
    let out = simulate_car(&world, &opts).unwrap();
    let dr = dead_reckon(&out.dataset, &MotionOptions::default()).unwrap();
    let errs = position_errors(&dr, &out.ground_truth);
    let max = errs.iter().cloned().fold(0.0, f64::max);
    let last = *errs.last().unwrap();
    eprintln!(
        "default errors, {:.0} m driven: dead reckoning max error {max:.2} m, final {last:.2} m",
        out.distance_m
    );
    assert!(max > 1.0 && max < 50.0, "max error {max} m");
}

pub(crate) fn assert_same_files(a: &Path, b: &Path) {
    let mut names: Vec<_> = walk(a);
    names.sort();
    assert!(names.len() > 8);
    for rel in names {
        let x = std::fs::read(a.join(&rel)).unwrap();
        let y = std::fs::read(b.join(&rel)).unwrap_or_default();
        assert!(x == y, "{} differs", rel.display());
    }
}

fn walk(root: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    out
}

#[test]
fn same_seed_gives_byte_identical_files() {
    let dir = tempfile::tempdir().unwrap();
    let world = World::builtin("campus").unwrap();
    let mut opts = SimOptions {
        duration_s: 8.0,
        seed: 42,
        ..SimOptions::default()
    };
    for k in ["a", "b"] {
        let out = simulate_car(&world, &opts).unwrap();
        write_car_sim(&dir.path().join(k), &out).unwrap();
    }
    assert_same_files(&dir.path().join("a"), &dir.path().join("b"));
    opts.seed = 43;
    let other = simulate_car(&world, &opts).unwrap();
    let first = simulate_car(
        &world,
        &SimOptions {
            seed: 42,
            ..opts.clone()
        },
    )
    .unwrap();
    assert_ne!(other.dataset.lidar, first.dataset.lidar);
    // sim.toml reproduces the run
    let cfg = pfslam::config::Config::from_toml_file(&dir.path().join("a/sim.toml")).unwrap();
    assert_eq!(
        cfg.sim,
        SimOptions {
            seed: 42,
            ..opts.clone()
        }
    );

    let h = SimOptions {
        vehicle: Vehicle::Humanoid,
        duration_s: 3.0,
        ..SimOptions::default()
    };
    let office = World::builtin("office").unwrap();
    for k in ["c", "d"] {
        let out = simulate_humanoid(&office, &h).unwrap();
        write_humanoid_sim(&dir.path().join(k), &out).unwrap();
    }
    assert_same_files(&dir.path().join("c"), &dir.path().join("d"));
}

#[test]
fn obstacle_hits_lie_on_the_true_map() {
    let world = World::builtin("campus").unwrap();
    let mut opts = SimOptions::noise_free();
    opts.duration_s = 40.0;
    let out = simulate_car(&world, &opts).unwrap();
    let cal = &out.dataset.calibration;
    let scans = &out.dataset.lidar;
    // every obstacle's footprint, whatever its height
    let all = TrueMap::rasterize(&world, 0.1, [0.0, 1e9], 20.0);
    let near = |m: &TrueMap, x: f64, y: f64| {
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                m.is_occupied_at(
                    x + f64::from(dx) * m.resolution_m,
                    y + f64::from(dy) * m.resolution_m,
                )
            })
        })
    };
    let (mut on_any, mut on_truth, mut total, mut ground) = (0usize, 0usize, 0usize, 0usize);
    for (i, g) in out.ground_truth.iter().enumerate().step_by(7) {
        let wb = pfslam::geometry::Rigid3::from_pose2(&g.pose).compose(&cal.body_from_lidar);
        for (b, &r) in scans.ranges(i).iter().enumerate() {
            if r <= 0.0 || r >= 80.0 {
                continue;
            }
            let a = cal.lidar.beam_angle_rad(b);
            let p = wb.transform_point(&nalgebra::Vector3::new(
                f64::from(r) * a.cos(),
                f64::from(r) * a.sin(),
                0.0,
            ));
            if p[2] < 0.01 {
                ground += 1;
                continue;
            }
            total += 1;
            on_any += usize::from(near(&all, p[0], p[1]));
            on_truth += usize::from(near(&out.true_map, p[0], p[1]));
        }
    }
    let (f_any, f_truth) = (on_any as f64 / total as f64, on_truth as f64 / total as f64);
    eprintln!(
        "{total} obstacle hits, {ground} ground hits; on an obstacle footprint {f_any:.4}, on the true map (band rule) {f_truth:.4}"
    );
    assert!(total > 10_000 && ground > 100);
    // the geometry, the mount and the ground truth agree: hits lie on obstacles
    assert!(f_any > 0.9999, "{f_any}");
    // the band rule keeps what the LiDAR sees: only the dipping edge beams reach the parked
    // cars below the LiDAR, which the true map leaves out
    assert!(f_truth > 0.98, "{f_truth}");
}

#[test]
fn humanoid_round_trip_and_floor_labels() {
    let dir = tempfile::tempdir().unwrap();
    let world = World::builtin("office").unwrap();
    let mut opts = SimOptions::noise_free();
    opts.vehicle = Vehicle::Humanoid;
    opts.duration_s = 12.0;
    let out = simulate_humanoid(&world, &opts).unwrap();
    write_humanoid_sim(dir.path(), &out).unwrap();
    let back = read_humanoid_dataset(dir.path()).unwrap();
    assert_eq!(back, out.dataset);
    let nb = back.calibration.lidar.beam_count;
    assert_eq!(nb, 1081);
    let (stamps, labels) = read_beam_labels(&dir.path().join("beam_labels.csv"), nb).unwrap();
    assert_eq!(stamps, out.dataset.lidar.stamps_ns);
    assert_eq!(labels, out.beam_labels);
    assert!(
        out.ground_beam_count() > 1000,
        "{}",
        out.ground_beam_count()
    );
    // With the recording's per-scan mounts (joints + IMU roll/pitch), floor-labelled beams
    // end at z = 0 and obstacle beams above it: a z filter separates them.
    let rec = out.recording();
    let gt = rec.ground_truth.as_ref().unwrap();
    let (mut floor, mut obstacle) = (0, 0);
    for i in (0..rec.scans.len()).step_by(5) {
        let wl =
            pfslam::geometry::Rigid3::from_pose2(&gt[i].pose).compose(rec.body_from_lidar_at(i));
        for (b, &r) in rec.scans.ranges(i).iter().enumerate() {
            if r <= 0.0 {
                continue;
            }
            let a = rec.lidar.beam_angle_rad(b);
            let p = wl.transform_point(&nalgebra::Vector3::new(
                f64::from(r) * a.cos(),
                f64::from(r) * a.sin(),
                0.0,
            ));
            match labels[i * nb + b] {
                BEAM_FLOOR => {
                    floor += 1;
                    // joints and IMU are sampled at 100 Hz and interpolated: mm-level error
                    assert!(
                        p[2].abs() < 0.02,
                        "scan {i} beam {b}: floor hit at z {}",
                        p[2]
                    );
                }
                BEAM_OBSTACLE => {
                    obstacle += 1;
                    assert!(
                        p[2] > -0.02,
                        "scan {i} beam {b}: obstacle hit at z {}",
                        p[2]
                    );
                }
                l => panic!("label {l} with a return"),
            }
        }
    }
    assert!(floor > 100 && obstacle > 1000, "{floor} {obstacle}");
}

#[test]
fn example_world_file_simulates() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("worlds/example.world");
    let world = World::from_file(&path).unwrap();
    assert_eq!(world.name, "example");
    assert!(world.prisms.len() >= 10 && !world.ground.markings.is_empty());
    let opts = SimOptions {
        duration_s: 5.0,
        ..SimOptions::default()
    };
    let out = simulate_car(&world, &opts).unwrap();
    assert_eq!(out.dataset.encoder.len(), 501);
}
