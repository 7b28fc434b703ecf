//! `pfslam eval`: ATE/RPE against ground truth, the relations metric, bad input.

use super::{assert_ok, pfslam};
use pfslam::geometry::{Pose2, StampedPose2};
use pfslam_io::tum::{format_stamp_s, write_tum};
use std::ffi::OsStr;

/// Runs `pfslam eval ARGS...`.
fn eval(args: &[&dyn AsRef<OsStr>]) -> std::process::Output {
    pfslam()
        .arg("eval")
        .args(args.iter().map(|a| a.as_ref()))
        .output()
        .unwrap()
}

fn drive(n: usize) -> Vec<StampedPose2> {
    let mut p = Pose2::IDENTITY;
    (0..n)
        .map(|i| {
            let s = StampedPose2 {
                stamp_ns: 976_052_905_167_303_000 + i as i64 * 200_000_000,
                pose: p,
            };
            p = p.compose(&Pose2::new(0.25, 0.0, 0.15 * (i as f64 * 0.05).cos()));
            s
        })
        .collect()
}

#[test]
fn eval_ground_truth_text_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let gt = drive(200);
    let t = Pose2::new(5.0, 3.0, -1.0);
    let est: Vec<StampedPose2> = gt
        .iter()
        .map(|s| StampedPose2 {
            stamp_ns: s.stamp_ns,
            pose: t.compose(&s.pose),
        })
        .collect();
    let gt_path = dir.path().join("gt.tum");
    let est_path = dir.path().join("est.tum");
    write_tum(&gt_path, &gt).unwrap();
    write_tum(&est_path, &est).unwrap();
    let out = eval(&[&"--ground-truth", &gt_path, &est_path]);
    assert_ok(&out);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("ATE aligned (SE(2)):   rmse 0.0000 m"),
        "{text}"
    );
    assert!(text.contains("RPE over 1 frame(s)"), "{text}");
    let out = eval(&[
        &"--json",
        &"--rpe-metres",
        &"2",
        &"--ground-truth",
        &gt_path,
        &est_path,
    ]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["ate"]["pairs"], 200);
    assert!(v["ate"]["aligned_m"]["rmse"].as_f64().unwrap() < 1e-6);
    assert!(v["ate"]["unaligned_m"]["rmse"].as_f64().unwrap() > 1.0);
    assert!(v["rpe"]["trans_m"]["max"].as_f64().unwrap() < 1e-6);
    assert_eq!(v["rpe"]["delta"]["metres"], 2.0);
    assert!(v.get("relations").is_none());
}

#[test]
fn eval_relations_json() {
    let dir = tempfile::tempdir().unwrap();
    let traj = drive(100);
    let path = dir.path().join("traj.tum");
    write_tum(&path, &traj).unwrap();
    // relations satisfied exactly, except the last one, off by 0.5 m along x
    let mut text = String::new();
    for i in 0..50 {
        let (a, b) = (traj[i], traj[i + 3]);
        let mut rel = a.pose.between(&b.pose);
        if i == 49 {
            rel = rel.compose(&Pose2::new(0.5, 0.0, 0.0));
        }
        // 6 decimals as in the Freiburg files
        let s1 = format_stamp_s(a.stamp_ns);
        let s2 = format_stamp_s(b.stamp_ns);
        text += &format!(
            "{} {} {:.9} {:.9} 0 0 0 {:.9}\n",
            &s1[..s1.len() - 3],
            &s2[..s2.len() - 3],
            rel.x_m,
            rel.y_m,
            rel.yaw_rad
        );
    }
    text += "1.000000 2.000000 1 0 0 0 0 0\n"; // no pose at these stamps
    let rel_path = dir.path().join("t.relations");
    std::fs::write(&rel_path, text).unwrap();
    let out = eval(&[&"--json", &"--relations", &rel_path, &path]);
    assert_ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let v = &v["relations"];
    assert_eq!(v["relations"], 51);
    assert_eq!(v["used"], 50);
    assert_eq!(v["skipped"], 1);
    let mean = v["trans_m"]["abs"]["mean"].as_f64().unwrap();
    assert!((mean - 0.01).abs() < 1e-6, "{mean}");
    assert!((v["trans_m"]["abs"]["max"].as_f64().unwrap() - 0.5).abs() < 1e-6);
    let out = eval(&[&"--relations", &rel_path, &path]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("relations: 50 used of 51 (1 skipped"),
        "{text}"
    );
    assert!(text.contains("translational error: 0.0100 +-"), "{text}");
}

#[test]
fn eval_bad_input_exits_2_with_position() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.tum");
    std::fs::write(&bad, "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 x 1\n").unwrap();
    let out = eval(&[&"--ground-truth", &bad, &bad]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.tum:2"), "{err}");
    // neither --ground-truth nor --relations
    let out = eval(&[&bad]);
    assert_eq!(out.status.code(), Some(2));
    // a relations file that matches nothing
    let good = dir.path().join("good.tum");
    write_tum(&good, &drive(10)).unwrap();
    let rel = dir.path().join("r.relations");
    std::fs::write(&rel, "1.000000 2.000000 1 0 0 0 0 0\n").unwrap();
    let out = eval(&[&"--relations", &rel, &good]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("none of the 1 relations"));
}

#[test]
fn eval_relations_of_raw_odometry_on_real_data() {
    use pfslam::eval::relations::{RelationsOptions, evaluate_relations};
    use pfslam_io::relations::read_relations;
    let Some(root) = super::data_dir("eval_relations_of_raw_odometry_on_real_data") else {
        return;
    };
    let dir = root.join("freiburg/aces");
    let rec = pfslam_io::recording::read_recording(
        &dir.join("aces.bag"),
        &pfslam_io::recording::ReaderOptions::default(),
    )
    .unwrap();
    let traj = pfslam::geometry::Trajectory::new(
        pfslam::sensors::sync::poses_at_stamps(&rec.odometry, &rec.scans.stamps_ns).0,
    );
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("odometry.tum");
    write_tum(&path, &traj.poses).unwrap();
    let rel_path = dir.join("aces.relations");
    let out = eval(&[&"--json", &"--relations", &rel_path, &path]);
    assert_ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let v = &v["relations"];
    // the TUM round trip (9 decimals) keeps the figures of the library
    let lib = evaluate_relations(
        &traj,
        &read_relations(&rel_path).unwrap(),
        &RelationsOptions::default(),
    )
    .unwrap();
    assert_eq!(v["used"], 1279);
    let mean = v["trans_m"]["abs"]["mean"].as_f64().unwrap();
    assert!((mean - lib.trans_m.abs.mean).abs() < 1e-6, "{mean}");
    // the recording itself as the trajectory: its raw odometry, the same figures
    let out = eval(&[&"--relations", &rel_path, &dir.join("aces.bag")]);
    assert_ok(&out);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("raw odometry of"), "{text}");
    let want = format!("translational error: {:.4} +-", lib.trans_m.abs.mean);
    assert!(text.contains(&want), "{text}");
}
