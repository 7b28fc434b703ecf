//! Acceptance on real recordings with the default configuration: the three Freiburg bags
//! against their recorded relations errors, and Radish logs with degraded odometry against
//! their corrected poses. Each test skips when the data is absent.

use pfslam::config::Config;
use pfslam::eval::Association;
use pfslam::eval::ate::ate;
use pfslam::eval::relations::{RelationsOptions, evaluate_relations};
use pfslam::geometry::Trajectory;
use pfslam::motion::perturb::{OdometryErrors, perturb_odometry};
use pfslam::pipeline::{PipelineOptions, run_pipeline};
use pfslam_io::relations::read_relations;

fn options() -> PipelineOptions {
    PipelineOptions {
        rebuild_map: false,
        ..PipelineOptions::default()
    }
}

/// Mean translational relations error (m) of the default pipeline, seed 1.
fn freiburg_relations_m(name: &str) -> Option<f64> {
    freiburg_run(name, 1).map(|(e, _)| e)
}

/// Mean translational relations error (m) of the default pipeline with `seed`, and whether
/// the back end ran a second time tied by the front end's motion.
fn freiburg_run(name: &str, seed: u64) -> Option<(f64, bool)> {
    freiburg_run_degraded(name, seed, None)
}

/// [`freiburg_run`] with the odometry degraded at `level` (with `seed`) when given.
fn freiburg_run_degraded(name: &str, seed: u64, level: Option<u8>) -> Option<(f64, bool)> {
    let dir = crate::common::data_dir(&format!("acceptance_freiburg_{name}"))?
        .join("freiburg")
        .join(name);
    let mut rec =
        pfslam_io::recording::read_recording(&dir.join(format!("{name}.bag")), &Default::default())
            .unwrap();
    if let Some(level) = level {
        let errors = OdometryErrors::level(level).unwrap();
        rec.odometry = perturb_odometry(&rec.odometry, &errors, seed);
    }
    let relations = read_relations(&dir.join(format!("{name}.relations"))).unwrap();
    let out = run_pipeline(&rec, &Config::default(), seed, &options(), &mut |_| {}).unwrap();
    let retried = out.quality.signals.back_end_retried;
    let r = evaluate_relations(
        &Trajectory::new(out.result.trajectory),
        &relations,
        &RelationsOptions::default(),
    )
    .unwrap();
    assert_eq!(r.used, r.relations, "every relation stamp has a pose");
    eprintln!("{name} seed {seed}: {:.4} m", r.trans_m.abs.mean);
    Some((r.trans_m.abs.mean, retried))
}

/// Intel seed 5: the back end's own sequential matches lead its closures astray (1.79 m;
/// its map's free share 34 % against the front end's 12.5 %); the guard sees it and the
/// back end tied by the front end's motion alone gives 0.0256 m.
#[test]
fn a_back_end_gone_astray_is_rerun_tied_by_the_front_end() {
    if let Some((e, retried)) = freiburg_run("intel", 5) {
        assert!(retried, "the guard did not trigger ({e:.4} m)");
        assert!(e < 0.03, "{e:.4} m");
    }
}

/// MIT-CSAIL's odometry is stamped ~0.11 s early and its robot weaves at up to 60 deg/s;
/// degraded further (level 3, seed 2), the filter's heading slipped 26 deg at 57 s and the
/// run ended 1.31 m off. The lag measured on the first run and the filter run again on the
/// shifted odometry keep it as good as the undegraded bag.
#[test]
fn a_weaving_robot_with_early_odometry_keeps_its_heading() {
    if let Some((e, _)) = freiburg_run_degraded("mit-csail", 2, Some(3)) {
        assert!(e < 0.035, "{e:.4} m");
    }
}

/// Each bag's seed-1 error may not rise above its recorded figure by more than the spread of
/// seeds 1-3 (`docs/benchmarks.md`).
#[test]
fn freiburg_bags_stay_within_their_recorded_errors() {
    for (name, recorded_m, spread_m) in [
        ("aces", 0.0357, 0.0007),
        ("intel", 0.0208, 0.0009),
        ("mit-csail", 0.0297, 0.0011),
    ] {
        if let Some(e) = freiburg_relations_m(name) {
            assert!(
                e <= recorded_m + spread_m,
                "{name}: {e:.4} m > {recorded_m} + {spread_m}"
            );
        }
    }
}

/// ATE RMSE (m) against the corrected poses of a Radish log whose odometry is degraded at
/// `level` (seed 1), with the default pipeline.
fn radish_ate_m(name: &str, level: u8) -> Option<f64> {
    let dir = crate::common::data_dir(&format!("acceptance_radish_{name}"))?.join("carmen");
    let path = dir.join(format!("{name}-corrected.log.gz"));
    let log = pfslam_io::carmen::read_carmen(&path, &Default::default()).unwrap();
    let mut rec = log.recording;
    rec.odometry = perturb_odometry(&rec.odometry, &OdometryErrors::level(level).unwrap(), 1);
    let out = run_pipeline(&rec, &Config::default(), 1, &options(), &mut |_| {}).unwrap();
    let a = ate(
        &Trajectory::new(out.result.trajectory),
        &log.laser_poses,
        Association::Nearest { tolerance_ns: 0 },
    )
    .unwrap();
    eprintln!("{name} level {level}: {:.3} m", a.aligned_m.rmse);
    Some(a.aligned_m.rmse)
}

/// Keyframe logs (one scan every ~0.5-1 m) with odometry as poor as Intel's: the filter
/// matches from the odometry's prediction, so it neither diverges (the proposal drawn from
/// GMapping's motion noise first: orebro 4.5 m, fhw 7.7 m) nor strays from good odometry.
#[test]
fn radish_keyframe_logs_with_poor_odometry_stay_near_their_corrected_poses() {
    for (name, bound_m) in [("orebro", 0.11), ("seattle", 0.07), ("fhw", 0.24)] {
        if let Some(e) = radish_ate_m(name, 2) {
            assert!(e <= bound_m, "{name}: {e:.3} m > {bound_m} m");
        }
    }
}
