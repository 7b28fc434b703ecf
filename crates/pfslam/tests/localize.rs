//! Localisation on real recordings: in maps made from Radish logs' corrected poses (the map
//! another tool would have written), global localisation and recovery after a kidnapping;
//! and a Freiburg bag in the map pfslam's SLAM built of it.

use pfslam::config::Config;
use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
use pfslam::localize::{LocalizeResult, localize_timed};
use pfslam::map::{BinaryMap, map_with_poses};
use pfslam::motion::perturb::{OdometryErrors, perturb_odometry};
use pfslam::sensors::Recording;

/// A Radish log with its odometry perturbed at level 2 (seed 1), its corrected laser poses,
/// and the binary map rasterised along them.
fn log_and_map(test: &str, name: &str) -> Option<(Recording, Trajectory, BinaryMap)> {
    let data = crate::common::data_dir(test)?;
    let config = Config::default();
    let path = data.join(format!("carmen/{name}-corrected.log.gz"));
    let log = pfslam_io::carmen::read_carmen(
        &path,
        &pfslam_io::carmen::CarmenOptions::from_reader(&config.input),
    )
    .unwrap();
    let mut recording = log.recording;
    let errors = OdometryErrors::level(2).unwrap();
    recording.odometry = perturb_odometry(&recording.odometry, &errors, 1);
    let (grid, _, _) = map_with_poses(&recording, &log.laser_poses, &config.map).unwrap();
    let map = grid.to_binary_map(None);
    Some((recording, log.laser_poses, map))
}

/// Position errors (m) against the reference, by stamp, from `from_ns` on.
fn errors_m(result: &LocalizeResult, reference: &Trajectory, from_ns: i64) -> Vec<f64> {
    result
        .trajectory
        .iter()
        .filter(|p| p.stamp_ns >= from_ns)
        .filter_map(|p| {
            let r = reference.pose_exact(p.stamp_ns)?;
            Some((p.pose.x_m - r.x_m).hypot(p.pose.y_m - r.y_m))
        })
        .collect()
}

fn rms(e: &[f64]) -> f64 {
    (e.iter().map(|x| x * x).sum::<f64>() / e.len().max(1) as f64).sqrt()
}

/// Localisation with the defaults (the odometry's timing handled as `pfslam localize`
/// does), from `start` when given.
fn run(rec: &Recording, map: &BinaryMap, start: Option<Pose2>, seed: u64) -> LocalizeResult {
    let config = Config::default();
    let (scan, shift) = (&config.map.scan, config.input.odometry_shift_s);
    let timed = localize_timed(rec, map, &config.localize, scan, start, seed, shift);
    timed.unwrap().0
}

#[test]
fn global_localisation_finds_the_robot_within_a_minute() {
    let test = "global_localisation_finds_the_robot_within_a_minute";
    // seeds 1-3 measured: seattle converged at 6-11 s, then 0.030-0.031 m RMSE; intel at
    // 33-36 s, then 0.037-0.040 m
    for name in ["seattle", "intel"] {
        let Some((rec, reference, map)) = log_and_map(test, name) else {
            return;
        };
        for seed in 1..=3 {
            let r = run(&rec, &map, None, seed);
            let t0 = r.trajectory[0].stamp_ns;
            let from = r.first_converged_ns().expect("never converged");
            let after_s = (from - t0) as f64 * 1e-9;
            assert!(
                after_s <= 60.0,
                "{name} seed {seed}: converged after {after_s} s"
            );
            let e = errors_m(&r, &reference, from);
            assert!(
                rms(&e) < 0.10,
                "{name} seed {seed}: {} m after {after_s} s",
                rms(&e)
            );
        }
    }
}

#[test]
fn recovers_when_carried_elsewhere_without_the_odometry_knowing() {
    let Some((mut rec, reference, map)) = log_and_map(
        "recovers_when_carried_elsewhere_without_the_odometry_knowing",
        "intel",
    ) else {
        return;
    };
    // The robot is carried from where it is at 40 % of the scans to where it is at 60 %:
    // the scans between are cut, and the odometry continues from the first place as if
    // nothing had happened (its motion after the gap, re-expressed from there).
    let n = rec.scans.len();
    let (t1, t2) = (
        rec.scans.stamps_ns[n * 2 / 5],
        rec.scans.stamps_ns[n * 3 / 5],
    );
    let keep: Vec<usize> = (0..n)
        .filter(|&i| rec.scans.stamps_ns[i] <= t1 || rec.scans.stamps_ns[i] >= t2)
        .collect();
    rec.keep_scans(&keep);
    let (o1, o2) = (
        rec.odometry.pose_at(t1).unwrap(),
        rec.odometry.pose_at(t2).unwrap(),
    );
    let spliced: Vec<StampedPose2> = rec
        .odometry
        .poses
        .iter()
        .filter(|p| p.stamp_ns <= t1 || p.stamp_ns >= t2)
        .map(|p| StampedPose2 {
            stamp_ns: p.stamp_ns,
            pose: if p.stamp_ns >= t2 {
                o1.compose(&o2.between(&p.pose))
            } else {
                p.pose
            },
        })
        .collect();
    rec.odometry = Trajectory::new(spliced);
    let carried_m = {
        let (a, b) = (
            reference.pose_exact(t1).unwrap(),
            reference.pose_exact(t2).unwrap(),
        );
        (a.x_m - b.x_m).hypot(a.y_m - b.y_m)
    };
    assert!(carried_m > 2.0, "carried only {carried_m} m");
    for seed in 1..=3 {
        let r = run(&rec, &map, Some(reference.poses[0].pose), seed);
        let before = errors_m(&r, &reference, 0);
        let before: Vec<f64> = before[..keep.iter().filter(|&&i| i <= n * 2 / 5).count()].to_vec();
        assert!(rms(&before) < 0.10, "seed {seed} before: {}", rms(&before));
        assert!(
            r.updates.iter().any(|u| u.stamp_ns >= t2 && u.injected > 0),
            "seed {seed}: no random particles after being carried {carried_m} m"
        );
        let t_end = r.trajectory.last().unwrap().stamp_ns;
        let last_half = errors_m(&r, &reference, t_end - (t_end - t2) / 2);
        assert!(
            rms(&last_half) < 0.10,
            "seed {seed} after: {}",
            rms(&last_half)
        );
    }
}

#[test]
fn recovers_when_the_odometry_jumps_by_metres() {
    let Some((mut rec, reference, map)) =
        log_and_map("recovers_when_the_odometry_jumps_by_metres", "intel")
    else {
        return;
    };
    // Halfway, the odometry jumps 3.6 m and 90 deg in one step. The motion model's noise
    // grows with the motion the odometry reports, so the particles spread over the jump and
    // the scans pull them back.
    let half = rec.odometry.len() / 2;
    let pivot = rec.odometry.poses[half].pose;
    let kick = Pose2::new(3.0, -2.0, std::f64::consts::FRAC_PI_2);
    for p in &mut rec.odometry.poses[half..] {
        p.pose = pivot.compose(&kick).compose(&pivot.between(&p.pose));
    }
    let kicked_ns = rec.odometry.poses[half].stamp_ns;
    for seed in 1..=3 {
        let r = run(&rec, &map, Some(reference.poses[0].pose), seed);
        let at_jump = errors_m(&r, &reference, kicked_ns);
        assert!(
            at_jump[0] > 1.0,
            "seed {seed}: the jump did not move the estimate"
        );
        let t_end = r.trajectory.last().unwrap().stamp_ns;
        let last_quarter = errors_m(&r, &reference, t_end - (t_end - kicked_ns) / 4);
        assert!(
            rms(&last_quarter) < 0.10,
            "seed {seed} after: {}",
            rms(&last_quarter)
        );
    }
}

/// A Freiburg bag localised (seed 1) in the map of its own seed-1 SLAM run, against that
/// run's trajectory: from the true start within 0.05 m; with `global`, also without a start
/// pose, converged for good (the filter may first settle on a look-alike place and leave it
/// again) within a minute and then within 0.10 m.
fn localised_in_its_own_slam_map(test: &str, name: &str, global: bool) -> Option<LocalizeResult> {
    let data = crate::common::data_dir(test)?;
    let config = Config::default();
    let path = data.join(format!("freiburg/{name}/{name}.bag"));
    let rec = pfslam_io::recording::read_recording(&path, &config.input).unwrap();
    let options = pfslam::pipeline::PipelineOptions::default();
    let slam = pfslam::pipeline::run_pipeline(&rec, &config, 1, &options, &mut |_| {}).unwrap();
    let map = slam.result.map.to_binary_map(None);
    let reference = Trajectory::new(slam.result.trajectory);
    let start = reference.poses[0].pose;
    let tracked = run(&rec, &map, Some(start), 1);
    let e = rms(&errors_m(&tracked, &reference, i64::MIN));
    assert!(e < 0.05, "{name} from the start pose: {e} m");
    if global {
        let found = run(&rec, &map, None, 1);
        let from = found.converged_from_ns().expect("not converged at the end");
        let after_s = (from - found.trajectory[0].stamp_ns) as f64 * 1e-9;
        assert!(after_s <= 60.0, "{name} converged after {after_s} s");
        let e = rms(&errors_m(&found, &reference, from));
        assert!(e < 0.10, "{name}: {e} m after converging at {after_s} s");
    }
    Some(tracked)
}

/// MIT-CSAIL: measured 0.035 m from the start pose (seeds 1-3); globally converged after
/// 13 s, then 0.037-0.040 m.
#[test]
fn mit_csail_is_localised_in_its_own_slam_map() {
    localised_in_its_own_slam_map(
        "mit_csail_is_localised_in_its_own_slam_map",
        "mit-csail",
        true,
    );
}

/// ACES in the SLAM map of seed 1: measured 0.047 m from the start pose (localisation
/// seeds 1-3), no fix lost. At 466-481 s into the recording something beside the robot that
/// the map does not hold (people, most likely) hides up to 40 % of the scan; the estimate
/// stays right, and the recovery, which tracks the fit of the best-fitting 70 % of the
/// returns, does not scatter it.
#[test]
fn aces_is_localised_in_its_own_slam_map() {
    localised_in_its_own_slam_map("aces_is_localised_in_its_own_slam_map", "aces", true);
}

/// Intel, whose bag holds scans delivered again seconds later under a new stamp: they are
/// left out (about a hundred), and the rest tracks within 0.05 m (measured 0.046 m, seeds
/// 1-3). Global localisation is not asserted here: its convergence takes 59 s to half an
/// hour depending on the seed.
#[test]
fn intel_with_stale_scans_is_localised_in_its_own_slam_map() {
    let test = "intel_with_stale_scans_is_localised_in_its_own_slam_map";
    if let Some(tracked) = localised_in_its_own_slam_map(test, "intel", false) {
        assert!(
            (50..500).contains(&tracked.scans_stale),
            "stale scans: {}",
            tracked.scans_stale
        );
    }
}
