//! The one-step pipeline (`pipeline::run_pipeline`: filter, `[graph]` back end, map rebuilt)
//! that `pfslam run`, `benchmark` and `bench-e2e` share.

use crate::filter::synthetic;
use pfslam::config::Config;
use pfslam::filter::FilterMode;
use pfslam::geometry::StampedPose2;
use pfslam::pipeline::{PipelineOptions, PipelineResult, run_pipeline};

fn config() -> Config {
    let mut config = Config::default();
    config.filter.mode = FilterMode::Rbpf;
    config.filter.particles = 10;
    config.filter.rbpf.resolution_m = 0.1;
    config
}

fn pipeline(rec: &pfslam::sensors::Recording, config: &Config, threads: usize) -> PipelineResult {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| run_pipeline(rec, config, 3, &PipelineOptions::default(), &mut |_| {}).unwrap())
}

/// The filter's output is the front end; the back end ran and rebuilt the map; everything is
/// bit-identical with 1 and 2 threads (per-particle matching and the parallel back end).
#[test]
fn pipeline_is_filter_then_back_end_and_thread_count_independent() {
    // 30 s at 3 m/s: more than one lap of the ellipse, so loops close.
    let rec = synthetic::recording(30.0, 5);
    let config = config();
    let a = pipeline(&rec, &config, 1);
    let b = pipeline(&rec, &config, 2);
    let stats = a.graph.as_ref().expect("the back end ran");
    assert!(stats.nodes > 10, "{stats:?}");
    assert_eq!(a.result.trajectory.len(), a.front_end.len());
    assert_eq!(a.result.trajectory, b.result.trajectory);
    assert_eq!(a.front_end, b.front_end);
    let (ga, gb) = (stats, b.graph.as_ref().unwrap());
    assert_eq!(
        (
            ga.nodes,
            ga.edges,
            ga.loop_accepted,
            ga.final_cost.to_bits()
        ),
        (
            gb.nodes,
            gb.edges,
            gb.loop_accepted,
            gb.final_cost.to_bits()
        )
    );
    assert!(a.result.map.tile_count() > 0);
    // Without the back end the pipeline is the filter alone, and its output is the front end
    // the back end was fed.
    let mut no_graph = config.clone();
    no_graph.graph.enabled = false;
    let c = pipeline(&rec, &no_graph, 2);
    assert!(c.graph.is_none());
    assert_eq!(c.result.trajectory, a.front_end);
    assert_ne!(a.result.trajectory, a.front_end, "the back end moved poses");
}

/// `[graph] input = "calibrated_odometry"` end to end: `synthetic::recording`'s odometry is
/// 2 % long and turns 0.01 rad/s too fast; both are fitted against the filter and the back end
/// is fed the corrected odometry. A fit that fails (here: any scale error refused) falls back
/// to the filter's trajectory, exactly as with `input = "front_end"`.
#[test]
fn pipeline_calibrates_the_odometry_or_falls_back_to_the_filter() {
    use pfslam::pipeline::BackEndInput;
    let rec = synthetic::recording(30.0, 5);
    let mut calibrated = config();
    calibrated.graph.input = BackEndInput::CalibratedOdometry;
    let a = pipeline(&rec, &calibrated, 2);
    assert_eq!(a.back_end_input, Some(BackEndInput::CalibratedOdometry));
    let fit = a.calibration.expect("the calibration was fitted");
    eprintln!("{fit:?}");
    assert!(
        (fit.calibration.scale - 1.0 / 1.02).abs() < 0.002,
        "{fit:?}"
    );
    assert!(
        (fit.calibration.yaw_rate_bias_rad_per_s - 0.01).abs() < 0.002,
        "{fit:?}"
    );
    assert!(fit.rms_m < fit.rms_uncorrected_m, "{fit:?}");

    let mut refused = calibrated.clone();
    refused.graph.calibration.max_scale_error = 1e-6;
    let b = pipeline(&rec, &refused, 2);
    assert_eq!(b.back_end_input, Some(BackEndInput::FrontEnd));
    assert!(b.calibration.is_none());
    let mut front = config();
    front.graph.input = BackEndInput::FrontEnd;
    let c = pipeline(&rec, &front, 2);
    assert_eq!(b.result.trajectory, c.result.trajectory);
    assert_ne!(a.result.trajectory, c.result.trajectory);

    // `[graph.refine] scans = "auto"`: off when the back end is fed the odometry (its smooth
    // local motion stays between keyframes), on when it is fed the front end.
    use pfslam::graph::Switch;
    let with = |base: &Config, switch: Switch| {
        let mut config = base.clone();
        config.graph.refine.scans = switch;
        pipeline(&rec, &config, 2).result.trajectory
    };
    assert_eq!(with(&calibrated, Switch::Off), a.result.trajectory);
    assert_ne!(with(&calibrated, Switch::On), a.result.trajectory);
    assert_eq!(with(&front, Switch::On), c.result.trajectory);
    assert_ne!(with(&front, Switch::Off), c.result.trajectory);
}

/// The self-check's signal: the share of returns landing in cells the map calls free is low
/// along the pipeline's trajectory and rises when half of the drive is laid 8 deg off the
/// other (corridors crossing, as a wrong loop closure lays them).
#[test]
fn free_share_rises_when_half_of_the_drive_is_turned_against_the_other() {
    use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
    use pfslam::map::consistency::consistency;
    use pfslam::map::map_with_poses;
    let rec = synthetic::recording(30.0, 5);
    let config = config();
    let out = pipeline(&rec, &config, 2);
    let share = |poses: &[StampedPose2]| {
        let poses = Trajectory::new(poses.to_vec());
        let grid = map_with_poses(&rec, &poses, &config.map).unwrap().0;
        consistency(&rec, &poses, &grid, &config.map.scan, 1)
            .unwrap()
            .free_share()
    };
    let good = share(&out.result.trajectory);
    let half = out.result.trajectory.len() / 2;
    let turn = Pose2::new(0.0, 0.0, 8f64.to_radians());
    let crossed: Vec<StampedPose2> = out
        .result
        .trajectory
        .iter()
        .enumerate()
        .map(|(i, p)| StampedPose2 {
            stamp_ns: p.stamp_ns,
            pose: if i < half {
                p.pose
            } else {
                turn.compose(&p.pose)
            },
        })
        .collect();
    let bad = share(&crossed);
    eprintln!("free share: {good:.4} along the result, {bad:.4} crossed");
    assert!(good < pfslam::quality::SUSPECT_FREE_SHARE, "{good}");
    assert!(bad > 1.5 * good, "{good} {bad}");
    assert_eq!(out.quality.signals.back_end_kept, Some(true));
    assert_eq!(out.quality.signals.free_share.to_bits(), good.to_bits());
}

/// The loop of [`synthetic::true_pose`] with the body weaving +-9 deg about its heading
/// (0.7 times a second): the turning rate changes all the time, as where a robot zigzags.
fn weaving_pose(t_s: f64, speed_mps: f64) -> pfslam::geometry::Pose2 {
    let mut pose = synthetic::true_pose(t_s, speed_mps);
    pose.yaw_rad += 0.15 * (1.4 * std::f64::consts::PI * t_s).sin();
    pose
}

/// RMS (rad) of the yaw change over each step between consecutive poses of `est` against
/// the same step of `truth` (both at the scans' stamps).
fn yaw_step_rms(est: &[StampedPose2], truth: &[StampedPose2]) -> f64 {
    let steps: Vec<f64> = est
        .windows(2)
        .zip(truth.windows(2))
        .map(|(e, t)| {
            let de = e[1].pose.yaw_rad - e[0].pose.yaw_rad;
            let dt = t[1].pose.yaw_rad - t[0].pose.yaw_rad;
            pfslam::geometry::wrap_angle(de - dt)
        })
        .collect();
    (steps.iter().map(|d| d * d).sum::<f64>() / steps.len() as f64).sqrt()
}

/// Odometry stamped 0.15 s early on a weaving robot: the run measures the lag from its
/// filter's yaw corrections and runs the filter again on the odometry shifted by it, whose
/// steps then follow the truth's turning (the filter itself copes with either here: its
/// errors stay near 1 cm); with `[input] odometry_shift_s = 0` it is not shifted, and the
/// same odometry on time is not run again.
#[test]
fn odometry_stamped_early_is_measured_and_shifted_back() {
    let on_time = synthetic::recording_along(30.0, 5, weaving_pose);
    let mut early = on_time.clone();
    pfslam::pipeline::shift_odometry(&mut early, -0.15);
    let auto = pipeline(&early, &config(), 2);
    let timing = auto.odometry_timing;
    let measured = timing.measured.expect("enough turning to measure");
    assert!(timing.rerun, "{timing:?}");
    assert!((measured.lag_s - 0.15).abs() < 0.03, "{timing:?}");
    assert_eq!(timing.shift_s, measured.lag_s);
    let left = timing.after_shift.expect("measured again");
    assert!(left.lag_s.abs() < 0.03 && !left.notable(), "{timing:?}");
    let mut off = config();
    off.input.odometry_shift_s = Some(0.0);
    let fixed = pipeline(&early, &off, 2);
    assert!(!fixed.odometry_timing.rerun);
    let truth = early.ground_truth.as_ref().expect("synthetic truth");
    let (rms_auto, rms_off) = (
        yaw_step_rms(&auto.result.dead_reckoning, truth),
        yaw_step_rms(&fixed.result.dead_reckoning, truth),
    );
    assert!(rms_auto < 0.5 * rms_off, "{rms_auto} against {rms_off}");
    let plain = pipeline(&on_time, &config(), 2);
    assert!(!plain.odometry_timing.rerun, "{:?}", plain.odometry_timing);
}

/// An odometry shift beyond a second (or not a number) is refused with the key's name by
/// the batch and the incremental entry points, before any stamp is moved.
#[test]
fn an_odometry_shift_out_of_range_is_refused() {
    let rec = synthetic::recording(5.0, 5);
    for shift_s in [5.0, f64::NAN, f64::INFINITY] {
        let mut bad = config();
        bad.input.odometry_shift_s = Some(shift_s);
        let options = PipelineOptions::default();
        let err = run_pipeline(&rec, &bad, 1, &options, &mut |_| {}).unwrap_err();
        assert!(err.to_string().contains("odometry_shift_s"), "{err}");
        let err = pfslam::Slam::with_recording(bad, rec.clone(), 1)
            .err()
            .unwrap();
        assert!(err.to_string().contains("odometry_shift_s"), "{err}");
    }
}
