//! Readers of real recordings: CARMEN logs, ROS 1 bags, MCAP; malformed input.

use crate::common::data_dir;
use pfslam::eval::relations::{RelationsOptions, pose_for_stamp, read_relations};
use pfslam::io::carmen::{CarmenOptions, read_carmen};
use std::path::Path;

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn carmen_mit_csail_counts_and_relation_stamps() {
    let Some(root) = data_dir("carmen_mit_csail_counts_and_relation_stamps") else {
        return;
    };
    let dir = root.join("freiburg/mit-csail");
    let log = read_carmen(&dir.join("mit-csail.clf"), &CarmenOptions::default()).unwrap();
    let rec = &log.recording;
    assert_eq!(rec.name, "mit-csail");
    assert_eq!(rec.scans.len(), 1988);
    assert_eq!(rec.scans.beam_count, 361);
    assert_eq!(rec.lidar.beam_count, 361);
    assert!((rec.lidar.angle_increment_rad - 0.5f64.to_radians()).abs() < 1e-15);
    assert!(log.stats.odometry_from_laser);
    assert_eq!(log.stats.odom_lines, 0);
    assert_eq!(log.stats.laser_out_of_order, 0);
    // odometry from the laser lines: one pose per scan, same stamps
    assert_eq!(rec.odometry.len(), 1988);
    assert_eq!(rec.odometry.poses[0].stamp_ns, rec.scans.stamps_ns[0]);
    assert_eq!(rec.scans.stamps_ns[0], 1_134_864_629_895_182_000);
    // every relation stamp is a scan stamp (ipc_timestamp), within half a unit of the last
    // printed decimal
    let scans = pfslam::geometry::Trajectory::new(
        rec.scans
            .stamps_ns
            .iter()
            .map(|&s| pfslam::geometry::StampedPose2 {
                stamp_ns: s,
                pose: pfslam::geometry::Pose2::IDENTITY,
            })
            .collect(),
    );
    let rel = read_relations(&dir.join("mit-csail.relations")).unwrap();
    assert_eq!(rel.len(), 1172);
    let _ = RelationsOptions::default();
    for r in &rel {
        assert!(
            pose_for_stamp(&scans, r.t1_ns, r.t1_tolerance_ns).is_some(),
            "t1 {}",
            r.t1_ns
        );
        assert!(
            pose_for_stamp(&scans, r.t2_ns, r.t2_tolerance_ns).is_some(),
            "t2 {}",
            r.t2_ns
        );
    }
}

#[test]
fn carmen_intel_corrected_gz_backwards_stamps() {
    let Some(root) = data_dir("carmen_intel_corrected_gz_backwards_stamps") else {
        return;
    };
    let log = read_carmen(
        &root.join("carmen/intel-corrected.log.gz"),
        &CarmenOptions::default(),
    )
    .unwrap();
    let s = &log.stats;
    let rec = &log.recording;
    assert_eq!(rec.name, "intel-corrected");
    assert_eq!(s.odom_lines, 14_541);
    assert_eq!(s.laser_lines, 910);
    assert_eq!(rec.scans.beam_count, 180);
    assert!(!s.odometry_from_laser);
    // the corrected keyframe poses written as ODOM lines with stamp 0 (841 "0", 22 like 1e-42)
    assert_eq!(s.odom_zero_stamp, 863);
    assert!(s.odom_out_of_order > 0);
    assert_eq!(
        rec.odometry.len() + s.odom_zero_stamp + s.odom_out_of_order,
        s.odom_lines
    );
    assert!(rec.scans.len() <= 910 && rec.scans.len() >= 906);
    for w in rec.odometry.poses.windows(2) {
        assert!(w[0].stamp_ns < w[1].stamp_ns);
    }
    for w in rec.scans.stamps_ns.windows(2) {
        assert!(w[0] < w[1]);
    }
    // the odometry is a plausible drive: metres, not kilometres
    let len = rec.odometry.path_length_m();
    assert!(len > 100.0 && len < 1000.0, "{len}");
}

#[test]
fn carmen_malformed_inputs_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "trunc.clf",
            "# c\nFLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.5 h 1.5\nFLASER 3 1.0 2.0\n",
            ":3:",
        ),
        (
            "nan.clf",
            "FLASER 3 1.0 abc 3.0 0 0 0 0 0 0 1.5 h 1.5\n",
            ":1:",
        ),
        ("stamp.clf", "ODOM 0 0 0 0 0 0 x1.5 h 1.5\n", ":1:"),
        ("count.clf", "FLASER -3 1.0\n", ":1:"),
        (
            "odomshort.clf",
            "FLASER 1 1.0 0 0 0 0 0 0 1.5 h 1.5\nODOM 1 2\n",
            ":2:",
        ),
        (
            "beams.clf",
            "FLASER 1 1.0 0 0 0 0 0 0 1.5 h 1.5\nFLASER 2 1.0 1.0 0 0 0 0 0 0 1.6 h 1.6\n",
            ":2:",
        ),
        ("empty.clf", "# nothing\n", ":0:"),
    ];
    for (name, text, pos) in cases {
        let p = write(dir.path(), name, text);
        let e = read_carmen(&p, &CarmenOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains(name) && e.contains(pos), "{name}: {e}");
    }
    // truncated gzip stream
    let gz = {
        use std::io::Write;
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        for i in 0..2000 {
            writeln!(enc, "FLASER 2 1.0 2.0 0 0 0 0 0 0 {}.5 h 0", i + 1).unwrap();
        }
        enc.finish().unwrap()
    };
    let p = dir.path().join("cut.log.gz");
    std::fs::write(&p, &gz[..gz.len() / 2]).unwrap();
    let e = read_carmen(&p, &CarmenOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("cut.log.gz:"), "{e}");
    std::fs::write(&p, &gz).unwrap();
    let ok = read_carmen(&p, &CarmenOptions::default()).unwrap();
    assert_eq!(ok.recording.scans.len(), 2000);
}

fn relation_stamps_found(rec: &pfslam::sensors::Recording, relations: &Path) -> usize {
    let scans = pfslam::geometry::Trajectory::new(
        rec.scans
            .stamps_ns
            .iter()
            .map(|&s| pfslam::geometry::StampedPose2 {
                stamp_ns: s,
                pose: pfslam::geometry::Pose2::IDENTITY,
            })
            .collect(),
    );
    let rel = read_relations(relations).unwrap();
    for r in &rel {
        for (t, tol) in [(r.t1_ns, r.t1_tolerance_ns), (r.t2_ns, r.t2_tolerance_ns)] {
            assert!(
                pose_for_stamp(&scans, t, tol).is_some(),
                "{}: relation stamp {t} ns has no scan within {tol} ns",
                relations.display()
            );
        }
    }
    rel.len()
}

#[test]
fn ros1_bags_counts_geometry_and_relation_stamps() {
    use pfslam::io::ros_msgs::{BeamGeometry, RosOptions};
    use pfslam::io::ros1::read_ros1_bag;
    let Some(root) = data_dir("ros1_bags_counts_geometry_and_relation_stamps") else {
        return;
    };
    // name, scans, beams, relations
    for (name, scans, beams, relations) in [
        ("intel", 13_631, 180, 2_984),
        ("aces", 7_374, 180, 1_279),
        ("mit-csail", 1_988, 361, 1_172),
    ] {
        let dir = root.join("freiburg").join(name);
        let rec = read_ros1_bag(&dir.join(format!("{name}.bag")), &RosOptions::default()).unwrap();
        assert_eq!(rec.name, name);
        assert_eq!(rec.scans.len(), scans, "{name} scans");
        assert_eq!(rec.scans.beam_count, beams, "{name} beams");
        // default geometry: the CARMEN convention
        let step = if beams == 180 { 1.0f64 } else { 0.5 };
        assert!((rec.lidar.angle_increment_rad - step.to_radians()).abs() < 1e-12);
        assert!((rec.lidar.angle_min_rad + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!(
            rec.odometry.len() > 1000,
            "{name} odometry {}",
            rec.odometry.len()
        );
        eprintln!(
            "{name}: {} scans, {} odometry poses, body_from_lidar t = {:?}",
            rec.scans.len(),
            rec.odometry.len(),
            rec.body_from_lidar.translation
        );
        assert_eq!(
            relation_stamps_found(&rec, &dir.join(format!("{name}.relations"))),
            relations
        );
        if name == "intel" {
            let raw = RosOptions {
                beam_geometry: BeamGeometry::AsRecorded,
                ..RosOptions::default()
            };
            let rec = read_ros1_bag(&dir.join("intel.bag"), &raw).unwrap();
            assert!((rec.lidar.angle_increment_rad - (180.0f64 / 179.0).to_radians()).abs() < 1e-6);
        }
    }
}
