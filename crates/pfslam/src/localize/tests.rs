//! Localisation in a synthetic building: scans ray-cast in the map itself, odometry that
//! drifts away from the true path.

use super::*;
use crate::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
use crate::map::{BinaryMap, CellState, MapLimits, ScanOptions};
use crate::matching::map_field;
use crate::sensors::{LidarGeometry, Recording, ScanSet};

const RES_M: f64 = 0.05;

/// A 24 x 14 m floor with rooms of different sizes and a few pillars: no two places look
/// alike from everywhere.
fn building() -> BinaryMap {
    let (w, h) = ((24.0 / RES_M) as usize, (14.0 / RES_M) as usize);
    let mut m = BinaryMap::filled(MapLimits::new(RES_M, -2.0, -2.0), w, h, CellState::Free);
    let mut wall = |x0: f64, y0: f64, x1: f64, y1: f64| {
        let n = ((x1 - x0).hypot(y1 - y0) / (RES_M / 2.0)).ceil() as usize;
        for k in 0..=n {
            let t = k as f64 / n.max(1) as f64;
            let c = m.limits.cell_of(x0 + t * (x1 - x0), y0 + t * (y1 - y0));
            m.set(c.i as i64, c.j as i64, CellState::Occupied);
        }
    };
    // outer walls
    wall(-1.5, -1.5, 21.5, -1.5);
    wall(21.5, -1.5, 21.5, 11.5);
    wall(21.5, 11.5, -1.5, 11.5);
    wall(-1.5, 11.5, -1.5, -1.5);
    // a corridor wall with doors, rooms behind it
    wall(-1.5, 4.0, 3.0, 4.0);
    wall(4.5, 4.0, 12.0, 4.0);
    wall(13.5, 4.0, 21.5, 4.0);
    wall(7.0, 4.0, 7.0, 11.5);
    wall(16.0, 4.0, 16.0, 8.0);
    // pillars and a cupboard
    for (x, y) in [(5.0, 1.0), (10.0, 2.0), (17.5, 0.5), (2.0, 8.0)] {
        wall(x - 0.2, y, x + 0.2, y);
        wall(x, y - 0.2, x, y + 0.2);
    }
    wall(10.0, 8.0, 12.0, 8.0);
    wall(12.0, 8.0, 12.0, 9.0);
    m
}

/// [`localize`] with the default options.
fn localize_by_default(
    rec: &Recording,
    map: &BinaryMap,
    start: Option<Pose2>,
    seed: u64,
) -> Result<LocalizeResult, LocalizeError> {
    localize(
        rec,
        map,
        &LocalizeOptions::default(),
        &ScanOptions::default(),
        start,
        seed,
    )
}

fn lidar() -> LidarGeometry {
    LidarGeometry {
        angle_min_rad: -std::f64::consts::FRAC_PI_2,
        angle_increment_rad: std::f64::consts::PI / 180.0,
        beam_count: 181,
        range_min_m: 0.0,
        range_max_m: 30.0,
    }
}

/// Ranges seen from `pose` by marching each beam through the map.
fn cast(map: &BinaryMap, pose: &Pose2, geometry: &LidarGeometry) -> Vec<f32> {
    (0..geometry.beam_count)
        .map(|k| {
            let a = pose.yaw_rad + geometry.beam_angle_rad(k);
            let (s, c) = a.sin_cos();
            let step = RES_M / 4.0;
            let mut r = 0.0;
            while r < geometry.range_max_m as f64 {
                r += step;
                let c = map.limits.cell_of(pose.x_m + r * c, pose.y_m + r * s);
                if map.get(c.i as i64, c.j as i64) == CellState::Occupied {
                    return r as f32;
                }
            }
            0.0
        })
        .collect()
}

/// The true path: along the corridor, into the big room and back, 10 scans per second at
/// 0.5 m/s. Odometry overestimates distance by 3 % and turns 2 deg/m too far left.
fn recording(map: &BinaryMap) -> (Recording, Vec<StampedPose2>) {
    let waypoints: [(f64, f64); 10] = [
        (0.0, 1.5),
        (8.0, 1.5),
        (13.0, 2.5),
        (19.0, 1.5),
        (18.5, 6.0),
        (14.0, 6.5),
        (13.0, 2.5),
        (5.0, 2.0),
        (4.0, 7.5),
        (3.0, 9.5),
    ];
    let mut truth = Vec::new();
    let dt_ns = 100_000_000i64;
    let mut stamp_ns = 0;
    for w in waypoints.windows(2) {
        let (a, b) = (w[0], w[1]);
        let yaw = (b.1 - a.1).atan2(b.0 - a.0);
        let n = ((b.0 - a.0).hypot(b.1 - a.1) / 0.05).ceil() as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            truth.push(StampedPose2 {
                stamp_ns,
                pose: Pose2::new(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), yaw),
            });
            stamp_ns += dt_ns;
        }
    }
    let geometry = lidar();
    let mut scans = ScanSet::new(geometry.beam_count);
    let mut odometry = vec![StampedPose2 {
        stamp_ns: 0,
        pose: Pose2::new(100.0, -50.0, 1.0),
    }];
    for (k, t) in truth.iter().enumerate() {
        scans.push(t.stamp_ns, &cast(map, &t.pose, &geometry));
        if k > 0 {
            let step = truth[k - 1].pose.between(&t.pose);
            let d = step.translation_norm_m();
            let drifted = Pose2::new(1.03 * step.x_m, 1.03 * step.y_m, step.yaw_rad + d * 0.035);
            let last = odometry[k - 1].pose;
            odometry.push(StampedPose2 {
                stamp_ns: t.stamp_ns,
                pose: last.compose(&drifted),
            });
        }
    }
    let rec = Recording {
        name: "building".into(),
        odometry: Trajectory::new(odometry),
        scans,
        lidar: geometry,
        body_from_lidar: Rigid3::IDENTITY,
        ..Recording::default()
    };
    (rec, truth)
}

/// Position errors against the truth, by stamp.
fn errors_m(result: &LocalizeResult, truth: &[StampedPose2]) -> Vec<(i64, f64)> {
    result
        .trajectory
        .iter()
        .map(|e| {
            let k = truth.partition_point(|t| t.stamp_ns < e.stamp_ns);
            let t = &truth[k];
            assert_eq!(e.stamp_ns, t.stamp_ns);
            (
                e.stamp_ns,
                (e.pose.x_m - t.pose.x_m).hypot(e.pose.y_m - t.pose.y_m),
            )
        })
        .collect()
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), e| (s + e * e, n + 1));
    (s / n.max(1) as f64).sqrt()
}

#[test]
fn tracks_from_the_given_start_despite_drifting_odometry() {
    let map = building();
    let (rec, truth) = recording(&map);
    let start = truth[0].pose;
    let opts = LocalizeOptions::default();
    let r = localize(&rec, &map, &opts, &ScanOptions::default(), Some(start), 1).unwrap();
    // The path crosses two walls: the scans from inside a wall (every beam ends at once)
    // are alike there and then, so the second crossing's are stale and have no pose.
    assert_eq!(r.trajectory.len() + r.scans_stale, truth.len());
    assert!(r.scans_stale <= 2, "{} stale scans", r.scans_stale);
    let e = errors_m(&r, &truth);
    let rmse = rms(e.iter().map(|x| x.1));
    let worst = e.iter().map(|x| x.1).fold(0.0, f64::max);
    assert!(rmse < 0.05 && worst < 0.15, "rmse {rmse} worst {worst}");
    // the odometry alone ends metres away
    let odom_end = rec.odometry.poses.last().unwrap().pose;
    let first = rec.odometry.poses[0].pose;
    let dr = start.compose(&first.between(&odom_end));
    let t_end = truth.last().unwrap().pose;
    assert!((dr.x_m - t_end.x_m).hypot(dr.y_m - t_end.y_m) > 1.0);
    assert!(r.updates.iter().all(|u| u.particles >= opts.min_particles));
    assert!(r.off_wall_share < 0.01, "{}", r.off_wall_share);
    assert_eq!(r.convergence_losses(), 0);
}

#[test]
fn finds_itself_without_a_start_pose() {
    let map = building();
    let (rec, truth) = recording(&map);
    let r = localize_by_default(&rec, &map, None, 2).unwrap();
    let from = r.converged_from_ns().expect("never converged");
    assert!(
        from <= 20_000_000_000,
        "converged only at {} s",
        from as f64 * 1e-9
    );
    let after: Vec<f64> = errors_m(&r, &truth)
        .into_iter()
        .filter(|(t, _)| *t >= from)
        .map(|x| x.1)
        .collect();
    let rmse = rms(after.iter().copied());
    let worst = after.iter().copied().fold(0.0, f64::max);
    assert!(
        rmse < 0.05,
        "from {} s: rmse {rmse} worst {worst}",
        from as f64 * 1e-9
    );
    // the global phase used many more particles than tracking
    assert!(r.updates[0].particles > 10 * r.updates.last().unwrap().particles);
}

/// For a third of the path a person walks beside the robot and hides a third of every
/// scan (the beams on its right end 0.6 m away, where the map is free): the estimate stays
/// right, so no random particles are drawn. Tracking the fit of every return instead, the
/// same disturbance calls for them.
#[test]
fn a_person_hiding_a_third_of_the_scan_calls_for_no_random_particles() {
    let map = building();
    let (mut rec, truth) = recording(&map);
    let (n, beams) = (rec.scans.len(), rec.scans.beam_count);
    for i in n / 3..2 * n / 3 {
        for r in &mut rec.scans.ranges_m[i * beams..i * beams + beams / 3] {
            *r = 0.6;
        }
    }
    let injected = |options: &LocalizeOptions| {
        let r = localize(
            &rec,
            &map,
            options,
            &ScanOptions::default(),
            Some(truth[0].pose),
            1,
        )
        .unwrap();
        let rmse = rms(errors_m(&r, &truth).iter().map(|x| x.1));
        (r.updates.iter().map(|u| u.injected).sum::<usize>(), rmse)
    };
    let (core, rmse) = injected(&LocalizeOptions::default());
    assert_eq!(core, 0, "random particles drawn (rmse {rmse})");
    assert!(rmse < 0.05, "{rmse}");
    let mut every_return = LocalizeOptions::default();
    every_return.recovery.core_share = 1.0;
    let (whole, rmse) = injected(&every_return);
    assert!(
        whole > 0,
        "the whole scan's fit called for none either (rmse {rmse})"
    );
}

/// The core fit of a scan 30 % hidden is nearly that of the whole scan seen, where the fit
/// of every return falls by half; at a wrong pose it falls.
#[test]
fn core_fit_ignores_the_hidden_share_of_a_scan() {
    let map = building();
    let truth = Pose2::new(9.0, 1.5, 0.3);
    let (field, points) = field_and_scan(&map, &truth);
    let fit = |points: &[[f64; 2]], pose: &Pose2, share: f64| {
        run::core_fit(&field, map_field::Sharpness::Tracking, points, pose, share)
    };
    let clean = fit(&points, &truth, 0.7);
    let mut hidden = points.clone();
    let hidden_count = hidden.len() * 3 / 10;
    for p in &mut hidden[..hidden_count] {
        *p = [0.6 * p[0] / p[0].hypot(p[1]), 0.6 * p[1] / p[0].hypot(p[1])];
    }
    let with_person = fit(&hidden, &truth, 0.7);
    assert!(with_person > 0.8 * clean, "{with_person} against {clean}");
    assert!(fit(&hidden, &truth, 1.0) < 0.5 * clean);
    let elsewhere = Pose2::new(14.0, 2.5, 1.2);
    assert!(fit(&points, &elsewhere, 0.7) < 0.3 * clean);
}

/// A shift of the odometry beyond a second is refused, not applied.
#[test]
fn localize_timed_refuses_an_odometry_shift_out_of_range() {
    let map = building();
    let (rec, truth) = recording(&map);
    let (options, scan) = (LocalizeOptions::default(), ScanOptions::default());
    let start = Some(truth[0].pose);
    for shift_s in [5.0, -1.5, f64::NAN] {
        let err = localize_timed(&rec, &map, &options, &scan, start, 1, Some(shift_s));
        assert!(matches!(err, Err(LocalizeError::Shift(_))), "{shift_s}");
    }
}

#[test]
fn recovers_when_carried_elsewhere() {
    let map = building();
    let (mut rec, truth) = recording(&map);
    // halfway, the odometry jumps by 4 m and 90 deg without the robot moving: it now
    // believes itself elsewhere, and its later motion is rotated accordingly.
    let half = rec.odometry.len() / 2;
    let kick = Pose2::new(4.0, -3.0, std::f64::consts::FRAC_PI_2);
    let pivot = rec.odometry.poses[half].pose;
    for p in &mut rec.odometry.poses[half..] {
        p.pose = pivot.compose(&kick).compose(&pivot.between(&p.pose));
    }
    // the kick is a jump of the recorded odometry, not a motion: the scans still come from
    // the true path, so the filter must relocalise. Its prediction moves particles by the
    // jump, which leaves them in the wrong place.
    let r = localize_by_default(&rec, &map, Some(truth[0].pose), 3).unwrap();
    let e = errors_m(&r, &truth);
    let before = rms(e[..half].iter().map(|x| x.1));
    assert!(before < 0.05, "{before}");
    let kicked_at = truth[half].stamp_ns;
    assert!(
        r.updates
            .iter()
            .any(|u| u.stamp_ns >= kicked_at && u.injected > 0)
    );
    let last_third = rms(e[e.len() * 5 / 6..].iter().map(|x| x.1));
    assert!(last_third < 0.05, "after recovery {last_third}");
    let wrong = e[half + 5].1;
    assert!(
        wrong > 1.0,
        "the jump did not mislead the filter ({wrong} m)"
    );
}

#[test]
fn same_seed_same_trajectory_on_any_thread_count() {
    let map = building();
    let (rec, _) = recording(&map);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| localize_by_default(&rec, &map, None, 4).unwrap())
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.trajectory, b.trajectory);
    assert_eq!(a.updates, b.updates);
}

#[test]
fn rejects_bad_options_and_a_map_without_free_space() {
    let map = building();
    let (rec, _) = recording(&map);
    let bad = LocalizeOptions {
        max_particles: 10,
        ..LocalizeOptions::default()
    };
    let e = localize(&rec, &map, &bad, &ScanOptions::default(), None, 1).unwrap_err();
    assert!(e.to_string().contains("max_particles"), "{e}");
    let solid = BinaryMap::filled(map.limits, 10, 10, CellState::Occupied);
    let e = localize_by_default(&rec, &solid, None, 1).unwrap_err();
    assert!(matches!(e, LocalizeError::NoFreeSpace), "{e}");
}

/// A tracking field over the test building and the points of a scan cast from `truth`.
fn field_and_scan(map: &BinaryMap, truth: &Pose2) -> (map_field::LikelihoodField, Vec<[f64; 2]>) {
    let field = map_field::LikelihoodField::new(
        map,
        &map_field::FieldModel {
            sigma_hit_m: [0.1, 0.3],
            z_hit: 0.9,
            max_distance_m: 2.0,
            range_max_m: 30.0,
        },
    );
    let geometry = lidar();
    let points: Vec<[f64; 2]> = cast(map, truth, &geometry)
        .iter()
        .enumerate()
        .filter(|(_, r)| **r > 0.0)
        .map(|(k, r)| {
            let (s, c) = geometry.beam_angle_rad(k).sin_cos();
            [f64::from(*r) * c, f64::from(*r) * s]
        })
        .collect();
    (field, points)
}

/// The Gauss-Newton tracking match lands where the hill climb does, from poses a few
/// centimetres and degrees off, in a handful of passes; beyond its reach it leaves the
/// pose as it was.
#[test]
fn tracking_match_reaches_the_hill_climbs_answer() {
    let map = building();
    let truth = Pose2::new(9.0, 1.5, 0.3);
    let (field, points) = field_and_scan(&map, &truth);
    let best = map_field::refine_pose(&field, &points, &truth);
    for off in [
        Pose2::new(9.04, 1.47, 0.3 + 1.0f64.to_radians()),
        Pose2::new(8.97, 1.53, 0.3 - 2.0f64.to_radians()),
        Pose2::new(9.0, 1.5, 0.3),
    ] {
        let tracked = map_field::track_pose(&field, &points, &off);
        let err = (tracked.x_m - best.x_m).hypot(tracked.y_m - best.y_m);
        assert!(err < 0.01, "from {off:?}: {tracked:?} against {best:?}");
        assert!((tracked.yaw_rad - best.yaw_rad).abs() < 0.2f64.to_radians());
    }
    let far = Pose2::new(14.0, 2.5, 0.3);
    assert_eq!(map_field::track_pose(&field, &points, &far), far);
}

/// A scan seen from the true pose, matched from a pose a few centimetres and a degree off,
/// comes back to it; from a pose in another basin, the estimate is left as it was.
#[test]
fn refinement_pulls_a_nearby_estimate_onto_the_scan() {
    let map = building();
    let truth = Pose2::new(9.0, 1.5, 0.3);
    let (field, points) = field_and_scan(&map, &truth);
    // The cast stops at a wall cell's near edge, half a cell before the centre the field is
    // drawn from: the best match lies within that of the truth.
    let best = map_field::refine_pose(&field, &points, &truth);
    let bias = (best.x_m - truth.x_m).hypot(best.y_m - truth.y_m);
    assert!(bias < 0.03, "{best:?}");
    let off = Pose2::new(9.06, 1.46, 0.3 + 1.5f64.to_radians());
    let refined = map_field::refine_pose(&field, &points, &off);
    let err = (refined.x_m - best.x_m).hypot(refined.y_m - best.y_m);
    assert!(err < 0.01, "{refined:?} against {best:?}");
    assert!((refined.yaw_rad - best.yaw_rad).abs() < 0.2f64.to_radians());
    let far = Pose2::new(14.0, 2.5, 0.3);
    assert_eq!(map_field::refine_pose(&field, &points, &far), far);
}

/// The particles' log-likelihoods, four at a time in the kernel, have the bits of the
/// field's scalar rule summed point by point, for poses on, across and off the map.
#[test]
fn particle_log_likelihoods_have_the_scalar_rules_bits() {
    let map = building();
    let (field, points) = field_and_scan(&map, &Pose2::new(9.0, 1.5, 0.3));
    let poses: Vec<Pose2> = (0..2 * mcl::CHUNK + 7)
        .map(|k| {
            let t = k as f64;
            Pose2::new(
                9.0 + 12.0 * (t * 0.37).sin(),
                1.5 + 6.0 * (t * 0.23).cos(),
                (t * 0.71).sin() * 3.1,
            )
        })
        .collect();
    let (scale, [ou, ov]) = field.centre_coordinates();
    for sharpness in [map_field::Sharpness::Tracking, map_field::Sharpness::Global] {
        let got = mcl::log_likelihoods(&field, sharpness, &points, &poses);
        for (pose, got) in poses.iter().zip(&got) {
            let (s, c) = pose.yaw_rad.sin_cos();
            let (cs, ss) = (c * scale, s * scale);
            let (u0, v0) = (pose.x_m * scale - ou, pose.y_m * scale - ov);
            let want: f64 = points
                .iter()
                .map(|p| {
                    let u = u0 + cs * p[0] - ss * p[1];
                    let v = v0 + ss * p[0] + cs * p[1];
                    field.log_likelihood_at_centres(sharpness, u, v) as f64
                })
                .sum();
            assert_eq!(got.to_bits(), want.to_bits(), "{pose:?}");
        }
    }
}
