use super::*;
use crate::config::Config;
use crate::sensors::{LidarGeometry, ScanSet};

fn recording_along(poses: &[Pose2]) -> (Recording, Vec<StampedPose2>) {
    let lidar = LidarGeometry::ucsd_lms511();
    let mut scans = ScanSet::new(lidar.beam_count);
    let mut trajectory = Vec::new();
    for (k, p) in poses.iter().enumerate() {
        let stamp_ns = k as i64 * 100_000_000;
        scans.push(stamp_ns, &vec![5.0; lidar.beam_count]);
        trajectory.push(StampedPose2 { stamp_ns, pose: *p });
    }
    let rec = Recording {
        name: "loop".into(),
        scans,
        lidar,
        ..Recording::default()
    };
    (rec, trajectory)
}

/// A 10 m straight line driven `laps` times, a pose every 5 cm.
fn laps(laps: usize) -> Vec<Pose2> {
    (0..laps)
        .flat_map(|_| (0..200).map(|i| Pose2::new(i as f64 * 0.05, 0.0, 0.0)))
        .collect()
}

#[test]
fn state_round_trips_and_refuses_other_files() {
    let (rec, traj) = recording_along(&laps(1));
    let state = SessionState::after_session(None, &rec, &traj, &Config::default());
    assert_eq!(state.sessions.len(), 1);
    assert!(state.keyframes.len() >= 30, "{}", state.keyframes.len());
    let bytes = state.to_bytes().unwrap();
    assert_eq!(&bytes[..8], MAGIC);
    assert_eq!(SessionState::from_bytes(&bytes, "s").unwrap(), state);
    let mut other = bytes.clone();
    other[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    let e = SessionState::from_bytes(&other, "s.pfslam")
        .unwrap_err()
        .to_string();
    assert!(e.contains("s.pfslam") && e.contains("version 2"), "{e}");
    let e = SessionState::from_bytes(b"P5\n1 1\n255\n0", "m.pgm")
        .unwrap_err()
        .to_string();
    assert!(e.contains("m.pgm") && e.contains("PFSLAMST"), "{e}");
    let e = SessionState::from_bytes(&bytes[..bytes.len() / 2], "cut")
        .unwrap_err()
        .to_string();
    assert!(e.contains("corrupt"), "{e}");
}

#[test]
fn driving_a_mapped_place_again_adds_no_keyframes() {
    let config = Config::default();
    let (once, traj_once) = recording_along(&laps(1));
    let (twice, traj_twice) = recording_along(&laps(2));
    let one = SessionState::after_session(None, &once, &traj_once, &config);
    let two = SessionState::after_session(None, &twice, &traj_twice, &config);
    assert_eq!(one.keyframes.len(), two.keyframes.len());
    // the same lap as a second session, 10 cm to the side: nothing new either
    let shifted: Vec<Pose2> = laps(1)
        .iter()
        .map(|p| Pose2::new(p.x_m, 0.1, p.yaw_rad))
        .collect();
    let (again, traj_again) = recording_along(&shifted);
    let poses: Vec<Pose2> = one.keyframes.iter().map(|k| k.world_from_body).collect();
    let next = SessionState::after_session(Some((&one, &poses)), &again, &traj_again, &config);
    assert_eq!(next.sessions.len(), 2);
    assert_eq!(next.keyframes.len(), one.keyframes.len());
    // driven the other way, the views are new
    let back: Vec<Pose2> = laps(1)
        .iter()
        .map(|p| Pose2::new(p.x_m, 0.0, std::f64::consts::PI))
        .collect();
    let (reverse, traj_reverse) = recording_along(&back);
    let next = SessionState::after_session(Some((&one, &poses)), &reverse, &traj_reverse, &config);
    assert_eq!(next.keyframes.len(), 2 * one.keyframes.len());
}

#[test]
fn options_are_checked() {
    let bad = SessionOptions {
        keyframe_distance_m: 0.0,
        ..SessionOptions::default()
    };
    assert!(bad.validate().unwrap_err().contains("keyframe_distance_m"));
    let bad = SessionOptions {
        prune_radius_m: f64::NAN,
        ..SessionOptions::default()
    };
    assert!(bad.validate().unwrap_err().contains("prune_radius_m"));
}
