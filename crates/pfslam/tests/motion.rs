//! Dead reckoning of constructed sequences against closed forms.

use pfslam::geometry::{Pose2, wrap_angle};
use pfslam::motion::{MotionOptions, StepModel, VelocityNoise, YawSource, dead_reckon};
use pfslam::sensors::{CarCalibration, CarDataset, EncoderSample, FogSample, ScanSet};
use std::f64::consts::PI;

const T0: i64 = 1_544_582_648_735_140_000;
const ENC_DT_NS: i64 = 10_000_000;

/// One segment of constant tick rates: `steps` encoder intervals with `(dl, dr)` ticks each.
struct Segment {
    steps: i64,
    dl: i64,
    dr: i64,
}

/// Builds encoder rows (uniform 100 Hz) from segments, and FOG rows (~1 kHz, jittered, some
/// dropped) whose increments equal the wheel-consistent yaw rate of each segment, with a FOG
/// stamp exactly on every segment boundary so the true cumulative yaw is piecewise linear
/// through the FOG knots.
fn build(segments: &[Segment]) -> CarDataset {
    let cal = CarCalibration::ucsd();
    let p = cal.encoder;
    let k = PI / f64::from(p.resolution_ticks);
    let mut encoder = vec![EncoderSample {
        stamp_ns: T0,
        left_count: 1000,
        right_count: -2000,
    }];
    // (start, end, yaw rate rad/ns)
    let mut pieces: Vec<(i64, i64, f64)> = Vec::new();
    for s in segments {
        let start = encoder.last().unwrap().stamp_ns;
        for _ in 0..s.steps {
            let last = *encoder.last().unwrap();
            encoder.push(EncoderSample {
                stamp_ns: last.stamp_ns + ENC_DT_NS,
                left_count: last.left_count + s.dl,
                right_count: last.right_count + s.dr,
            });
        }
        let dyaw = (k * p.right_wheel_diameter_m * s.dr as f64
            - k * p.left_wheel_diameter_m * s.dl as f64)
            / p.wheel_base_m;
        pieces.push((
            start,
            encoder.last().unwrap().stamp_ns,
            dyaw / ENC_DT_NS as f64,
        ));
    }
    let true_yaw = |t: i64| -> f64 {
        let mut y = 0.0;
        for &(a, b, rate) in &pieces {
            if t > a {
                y += rate * (t.min(b) - a) as f64;
            }
        }
        y
    };
    // FOG stamps: from 5 ms before the first encoder row to 5 ms after the last, ~1 ms apart
    // with jitter, every 97th row dropped, and the segment boundaries (where the yaw rate
    // changes) included.
    let end = encoder.last().unwrap().stamp_ns + 5_000_000;
    let mut stamps: Vec<i64> = Vec::new();
    let mut t = T0 - 5_000_000;
    let mut i = 0i64;
    while t <= end {
        if i % 97 != 50 {
            stamps.push(t);
        }
        t += 1_000_000 + ((i * 7919) % 301 - 150) * 1000;
        i += 1;
    }
    stamps.extend(pieces.iter().flat_map(|p| [p.0, p.1]));
    stamps.sort_unstable();
    stamps.dedup();
    let mut fog = Vec::with_capacity(stamps.len());
    for (j, &s) in stamps.iter().enumerate() {
        let prev = if j == 0 { s - 1_000_000 } else { stamps[j - 1] };
        fog.push(FogSample {
            stamp_ns: s,
            delta_roll_rad: 0.0,
            delta_pitch_rad: 0.0,
            delta_yaw_rad: true_yaw(s) - true_yaw(prev),
        });
    }
    CarDataset {
        calibration: cal,
        encoder,
        fog,
        lidar: ScanSet::new(286),
        stereo_stamps_ns: Vec::new(),
    }
}

fn opts(step: StepModel) -> MotionOptions {
    MotionOptions {
        step,
        yaw_source: YawSource::Fog,
        noise: VelocityNoise::OFF,
    }
}

/// Largest position error relative to path length, and largest yaw error.
fn max_errors(ds: &CarDataset, step: StepModel, truth: impl Fn(usize) -> Pose2) -> (f64, f64) {
    let traj = dead_reckon(ds, &opts(step)).unwrap();
    assert_eq!(traj.len(), ds.encoder.len());
    let length = traj.path_length_m();
    let mut pos = 0.0f64;
    let mut yaw = 0.0f64;
    for (k, p) in traj.poses.iter().enumerate() {
        let t = truth(k);
        pos = pos.max((p.pose.x_m - t.x_m).hypot(p.pose.y_m - t.y_m));
        yaw = yaw.max(wrap_angle(p.pose.yaw_rad - t.yaw_rad).abs());
    }
    (pos / length, yaw)
}

fn wheel_m(ticks: i64, diameter: f64) -> f64 {
    PI * diameter * ticks as f64 / 4096.0
}

/// Distance and yaw change of one encoder interval with `(dl, dr)` ticks on the real car.
fn step_motion(dl: i64, dr: i64) -> (f64, f64) {
    let p = CarCalibration::ucsd().encoder;
    let (sl, sr) = (
        wheel_m(dl, p.left_wheel_diameter_m),
        wheel_m(dr, p.right_wheel_diameter_m),
    );
    (0.5 * (sl + sr), (sr - sl) / p.wheel_base_m)
}

#[test]
fn straight_line_equal_ticks() {
    let ds = build(&[Segment {
        steps: 3000,
        dl: 60,
        dr: 60,
    }]);
    let p = CarCalibration::ucsd().encoder;
    // Equal ticks on wheels of different diameters still turn a little: the FOG (built
    // consistent with the wheels) says so too; the closed form is then a circle. With
    // FOG yaw set to zero the path is straight: check that case.
    let mut straight = ds.clone();
    for f in &mut straight.fog {
        f.delta_yaw_rad = 0.0;
    }
    let d = 0.5 * (wheel_m(60, p.left_wheel_diameter_m) + wheel_m(60, p.right_wheel_diameter_m));
    for step in [StepModel::ExactArc, StepModel::Euler] {
        let (rel, yaw) = max_errors(&straight, step, |k| Pose2::new(k as f64 * d, 0.0, 0.0));
        assert!(rel < 1e-9 && yaw == 0.0, "{step:?}: {rel} {yaw}");
    }
    let traj = dead_reckon(&straight, &opts(StepModel::ExactArc)).unwrap();
    assert!((traj.path_length_m() - 3000.0 * d).abs() < 1e-6);
}

/// Constant tick ratio + matching FOG yaw rate: a circle of radius R = d / dyaw.
#[test]
fn circle_of_known_radius() {
    let (dl, dr) = (50i64, 58i64);
    let (d, dyaw) = step_motion(dl, dr);
    let radius = d / dyaw;
    // One and a half turns.
    let steps = (3.0 * PI / dyaw).round() as i64;
    let ds = build(&[Segment { steps, dl, dr }]);
    let truth = |k: usize| {
        let th = k as f64 * dyaw;
        Pose2::new(radius * th.sin(), radius * (1.0 - th.cos()), th)
    };
    let (rel, yaw) = max_errors(&ds, StepModel::ExactArc, truth);
    assert!(rel < 1e-6, "exact arc: relative position error {rel}");
    assert!(yaw < 1e-9, "exact arc: yaw error {yaw}");
    // The seed's Euler step drifts outwards; it is first order in the step's turn.
    let (rel_euler, _) = max_errors(&ds, StepModel::Euler, truth);
    eprintln!(
        "circle R = {radius:.3} m, {steps} steps: relative position error exact arc {rel:.2e}, Euler {rel_euler:.2e}"
    );
    assert!(rel_euler > 10.0 * rel);
}

/// A figure eight: one full turn left, then one full turn right, back to the start.
#[test]
fn figure_eight() {
    let (dl, dr) = (50i64, 58i64);
    let (d1, w1) = step_motion(dl, dr);
    // Mirror: swap the tick counts (the diameters differ, so the radius differs slightly).
    let (d2, w2) = step_motion(dr, dl);
    let n1 = (2.0 * PI / w1).round() as usize;
    let n2 = (2.0 * PI / w2.abs()).round() as usize;
    let ds = build(&[
        Segment {
            steps: n1 as i64,
            dl,
            dr,
        },
        Segment {
            steps: n2 as i64,
            dl: dr,
            dr: dl,
        },
    ]);
    let (r1, r2) = (d1 / w1, d2 / w2);
    let truth = |k: usize| {
        if k <= n1 {
            let th = k as f64 * w1;
            Pose2::new(r1 * th.sin(), r1 * (1.0 - th.cos()), th)
        } else {
            // Start of loop 2: the pose after n1 steps.
            let th0 = n1 as f64 * w1;
            let start = Pose2::new(r1 * th0.sin(), r1 * (1.0 - th0.cos()), th0);
            let th = (k - n1) as f64 * w2;
            let local = Pose2::new(r2 * th.sin(), r2 * (1.0 - th.cos()), th);
            start.compose(&local)
        }
    };
    let (rel, yaw) = max_errors(&ds, StepModel::ExactArc, truth);
    assert!(rel < 1e-6, "exact arc: relative position error {rel}");
    assert!(yaw < 1e-9, "exact arc: yaw error {yaw}");
    let traj = dead_reckon(&ds, &opts(StepModel::ExactArc)).unwrap();
    // Back near the start (within the rounding of the step counts to whole turns).
    let end = traj.poses.last().unwrap().pose;
    assert!(end.translation_norm_m() < 0.1, "{end:?}");
    let (rel_euler, _) = max_errors(&ds, StepModel::Euler, truth);
    eprintln!("figure eight: relative position error exact arc {rel:.2e}, Euler {rel_euler:.2e}");
}

/// The wheels-only yaw source gives the same circle (the FOG was built consistent with it).
#[test]
fn wheel_yaw_matches_fog_yaw() {
    let ds = build(&[Segment {
        steps: 500,
        dl: 40,
        dr: 47,
    }]);
    let a = dead_reckon(&ds, &opts(StepModel::ExactArc)).unwrap();
    let mut o = opts(StepModel::ExactArc);
    o.yaw_source = YawSource::Wheels;
    let b = dead_reckon(&ds, &o).unwrap();
    for (p, q) in a.poses.iter().zip(&b.poses) {
        assert!((p.pose.x_m - q.pose.x_m).abs() < 1e-9);
        assert!((p.pose.y_m - q.pose.y_m).abs() < 1e-9);
    }
}

/// The FOG at 1 kHz with dropped rows and an encoder stamp inside a FOG row: yaw is split by
/// time, not by row count (the seed's "every 11 rows" would be off here).
#[test]
fn fog_rows_dropped_and_straddling() {
    let mut ds = build(&[Segment {
        steps: 100,
        dl: 40,
        dr: 47,
    }]);
    // Drop a run of 30 FOG rows in the middle: the next row carries their rotation.
    let mid = ds.fog.len() / 2;
    let dropped: f64 = ds.fog[mid..mid + 30].iter().map(|f| f.delta_yaw_rad).sum();
    ds.fog[mid + 30].delta_yaw_rad += dropped;
    ds.fog.drain(mid..mid + 30);
    let (_, dyaw) = step_motion(40, 47);
    let traj = dead_reckon(&ds, &opts(StepModel::ExactArc)).unwrap();
    for (k, sp) in traj.poses.iter().enumerate() {
        assert!(
            wrap_angle(sp.pose.yaw_rad - k as f64 * dyaw).abs() < 1e-9,
            "step {k}"
        );
    }
}

/// Encoder intervals outside the FOG's time span take their yaw from the wheels; the result
/// is unchanged here because the FOG was built consistent with the wheels.
#[test]
fn fog_missing_at_the_start_falls_back_to_wheels() {
    let full = build(&[Segment {
        steps: 400,
        dl: 40,
        dr: 47,
    }]);
    let mut late = full.clone();
    let cut = late.encoder[200].stamp_ns;
    late.fog.retain(|f| f.stamp_ns > cut);
    let a = dead_reckon(&full, &opts(StepModel::ExactArc)).unwrap();
    let b = dead_reckon(&late, &opts(StepModel::ExactArc)).unwrap();
    for (p, q) in a.poses.iter().zip(&b.poses) {
        assert!((p.pose.x_m - q.pose.x_m).abs() < 1e-9);
        assert!(wrap_angle(p.pose.yaw_rad - q.pose.yaw_rad).abs() < 1e-9);
    }
    // No FOG at all with the FOG as yaw source is an error, not a silent fallback.
    let mut none = full.clone();
    none.fog.clear();
    assert!(dead_reckon(&none, &opts(StepModel::ExactArc)).is_err());
}

#[test]
fn car_recording_has_odometry_scans_and_mount() {
    let mut ds = build(&[Segment {
        steps: 100,
        dl: 40,
        dr: 47,
    }]);
    for i in 0..10 {
        ds.lidar.push(T0 + i * 100_000_000 + 7, &[5.0f32; 286]);
    }
    let rec = pfslam::motion::car_recording(&ds, &opts(StepModel::ExactArc), "circle").unwrap();
    assert_eq!(rec.name, "circle");
    assert_eq!(rec.odometry.len(), ds.encoder.len());
    assert_eq!(rec.scans, ds.lidar);
    assert_eq!(rec.body_from_lidar, ds.calibration.body_from_lidar);
    assert_eq!(rec.lidar, ds.calibration.lidar);
    let imu = rec.imu_yaw.unwrap();
    assert_eq!(imu.len(), ds.encoder.len());
    // FOG yaw relative to the first encoder stamp equals the odometry's yaw (unwrapped).
    let (_, dyaw) = step_motion(40, 47);
    assert!((imu[100].1 - 100.0 * dyaw).abs() < 1e-9);
    // Poses at scan stamps by interpolation.
    let (poses, clamped) =
        pfslam::sensors::sync::poses_at_stamps(&rec.odometry, &rec.scans.stamps_ns);
    assert_eq!((poses.len(), clamped), (10, 0));
    // Moving the scans instead of copying them gives the same recording.
    let mut moved = ds.clone();
    let rec2 = pfslam::motion::car_recording_taking_scans(
        &mut moved,
        &opts(StepModel::ExactArc),
        "circle",
    )
    .unwrap();
    assert_eq!(rec2.scans, rec.scans);
    assert_eq!(rec2.odometry.poses, rec.odometry.poses);
    assert!(moved.lidar.is_empty());
}
