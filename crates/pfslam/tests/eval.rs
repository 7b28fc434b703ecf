//! Metrics: ATE/RPE on synthetic trajectories, the relations metric on built and perturbed
//! trajectories, and the raw odometry of the Freiburg recordings scored by the relations metric.

use crate::common::data_dir;
use pfslam::eval::Association;
use pfslam::eval::ate::ate;
use pfslam::eval::relations::{Relation, RelationsOptions, evaluate_relations, relation_errors};
use pfslam::eval::rpe::{RpeDelta, rpe};
use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
use pfslam_io::relations::read_relations;

fn wiggly(n: usize) -> Trajectory {
    let mut p = Pose2::IDENTITY;
    let mut poses = Vec::new();
    for i in 0..n {
        poses.push(StampedPose2 {
            stamp_ns: 1_000_000_000 + i as i64 * 100_000_000,
            pose: p,
        });
        p = p.compose(&Pose2::new(0.3, 0.0, 0.2 * (i as f64 * 0.1).sin()));
    }
    Trajectory::new(poses)
}

#[test]
fn ate_of_moved_copy_is_zero_aligned_large_unaligned() {
    let gt = wiggly(300);
    let t = Pose2::new(12.0, -7.0, 2.0);
    let moved = Trajectory::new(
        gt.poses
            .iter()
            .map(|s| StampedPose2 {
                stamp_ns: s.stamp_ns,
                pose: t.compose(&s.pose),
            })
            .collect(),
    );
    let r = ate(&moved, &gt, Association::Nearest { tolerance_ns: 0 }).unwrap();
    assert_eq!(r.pairs, 300);
    assert!(r.aligned_m.rmse < 1e-9, "{}", r.aligned_m.rmse);
    assert!(r.aligned_rot_deg.max < 1e-7);
    assert!(r.unaligned_m.rmse > 10.0, "{}", r.unaligned_m.rmse);
    // relative motion is untouched by a rigid move
    let e = rpe(&moved, &gt, Association::default(), RpeDelta::Frames(5)).unwrap();
    assert!(e.trans_m.max < 1e-9 && e.rot_deg.max < 1e-7);
    let e = rpe(&moved, &gt, Association::default(), RpeDelta::Metres(2.0)).unwrap();
    assert!(e.trans_m.count > 200);
}

#[test]
fn ate_with_noise_matches_the_noise() {
    let gt = wiggly(400);
    // every other pose 0.1 m off sideways: RMSE after alignment close to 0.1
    let est = Trajectory::new(
        gt.poses
            .iter()
            .enumerate()
            .map(|(i, s)| StampedPose2 {
                stamp_ns: s.stamp_ns + 300, // within the 1 us default tolerance
                pose: s
                    .pose
                    .compose(&Pose2::new(0.0, if i % 2 == 0 { 0.1 } else { -0.1 }, 0.0)),
            })
            .collect(),
    );
    let r = ate(&est, &gt, Association::default()).unwrap();
    assert_eq!(r.pairs, 400);
    assert!((r.unaligned_m.rmse - 0.1).abs() < 1e-9);
    assert!(r.aligned_m.rmse <= 0.1 + 1e-9 && r.aligned_m.rmse > 0.09);
    // too strict a tolerance: nothing associates
    assert!(ate(&est, &gt, Association::Nearest { tolerance_ns: 100 }).is_err());
}

fn relations_of(traj: &Trajectory, pairs: &[(usize, usize)]) -> Vec<Relation> {
    pairs
        .iter()
        .map(|&(i, j)| Relation {
            t1_ns: traj.poses[i].stamp_ns,
            t2_ns: traj.poses[j].stamp_ns,
            t1_tolerance_ns: 500,
            t2_tolerance_ns: 500,
            t1_from_t2: traj.poses[i].pose.between(&traj.poses[j].pose),
        })
        .collect()
}

#[test]
fn relations_exact_zero_and_perturbed_known() {
    let traj = wiggly(100);
    let pairs: Vec<(usize, usize)> = (0..90).map(|i| (i, i + 1 + i % 7)).collect();
    let rel = relations_of(&traj, &pairs);
    let r = evaluate_relations(&traj, &rel, &RelationsOptions::default()).unwrap();
    assert_eq!((r.relations, r.used, r.skipped), (90, 90, 0));
    assert!(r.trans_m.abs.mean < 1e-12 && r.rot_deg.abs.max < 1e-9);

    // perturb every relation by a known error: 0.2 m along x, 3 deg
    let bump = Pose2::new(0.2, 0.0, 3f64.to_radians());
    let perturbed: Vec<Relation> = rel
        .iter()
        .map(|r| Relation {
            t1_from_t2: r.t1_from_t2.compose(&bump),
            ..*r
        })
        .collect();
    let r = evaluate_relations(&traj, &perturbed, &RelationsOptions::default()).unwrap();
    assert!((r.trans_m.abs.mean - 0.2).abs() < 1e-9, "{:?}", r.trans_m);
    assert!(r.trans_m.abs.std < 1e-9);
    assert!((r.trans_m.squared.mean - 0.04).abs() < 1e-9);
    assert!((r.rot_deg.abs.mean - 3.0).abs() < 1e-9);
    assert!((r.rot_deg.squared.mean - 9.0).abs() < 1e-7);

    // a relation whose stamp is 600 ns off a pose is skipped with the 500 ns tolerance
    let mut off = rel.clone();
    off[0].t2_ns += 600;
    let r = evaluate_relations(&traj, &off, &RelationsOptions::default()).unwrap();
    assert_eq!((r.used, r.skipped), (89, 1));
    let loose = RelationsOptions {
        stamp_tolerance_ns: Some(1_000),
    };
    assert!(relation_errors(&traj, &off, &loose)[0].is_some());
}

#[test]
fn relations_file_errors_name_line() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.relations");
    std::fs::write(&p, "1.0 2.0 0 0 0 0 0 0\n1.0 2.0 0 0 0 0 0\n").unwrap();
    let e = read_relations(&p).unwrap_err().to_string();
    assert!(e.contains("bad.relations:2"), "{e}");
    std::fs::write(&p, "1.0 2.0 0 x 0 0 0 0\n").unwrap();
    let e = read_relations(&p).unwrap_err().to_string();
    assert!(e.contains("bad.relations:1") && e.contains("y"), "{e}");
}

/// The baseline the SLAM must beat: raw odometry, interpolated at the scan stamps, scored
/// with the relations metric.
#[test]
fn raw_odometry_relations_baseline() {
    use pfslam_io::options::ReaderOptions;
    use pfslam_io::ros1::read_ros1_bag;
    let Some(root) = data_dir("raw_odometry_relations_baseline") else {
        return;
    };
    let mut rows = Vec::new();
    for name in ["intel", "aces", "mit-csail"] {
        let dir = root.join("freiburg").join(name);
        let rec =
            read_ros1_bag(&dir.join(format!("{name}.bag")), &ReaderOptions::default()).unwrap();
        let traj = pfslam::geometry::Trajectory::new(
            pfslam::sensors::sync::poses_at_stamps(&rec.odometry, &rec.scans.stamps_ns).0,
        );
        let rel = read_relations(&dir.join(format!("{name}.relations"))).unwrap();
        let r = evaluate_relations(&traj, &rel, &RelationsOptions::default()).unwrap();
        eprintln!(
            "raw odometry {name} (bag): {} of {} relations, trans {:.4} +- {:.4} m (max {:.3}), rot {:.3} +- {:.3} deg (max {:.2})",
            r.used,
            r.relations,
            r.trans_m.abs.mean,
            r.trans_m.abs.std,
            r.trans_m.abs.max,
            r.rot_deg.abs.mean,
            r.rot_deg.abs.std,
            r.rot_deg.abs.max
        );
        let errs: Vec<f64> = relation_errors(&traj, &rel, &RelationsOptions::default())
            .iter()
            .flatten()
            .map(|d| d.translation_norm_m())
            .collect();
        let median = pfslam::eval::ErrorStats::from_values(&errs).median;
        eprintln!("  median translational error {median:.4} m");
        // most relations are short: their odometry error is small (conventions agree)
        assert!(median < 0.2, "{name}: median {median}");
        // all relations usable except those before the first odometry message
        assert!(
            r.used + 2 >= r.relations,
            "{name}: {} of {}",
            r.used,
            r.relations
        );
        // odometry is far from perfect, and far from absurd
        assert!(
            r.trans_m.abs.mean > 0.01 && r.trans_m.abs.mean < 100.0,
            "{name}"
        );
        rows.push((name, r));
    }
    // the original CARMEN log of MIT-CSAIL gives the same figures as its bag
    let dir = root.join("freiburg/mit-csail");
    let log = pfslam_io::carmen::read_carmen(
        &dir.join("mit-csail.clf"),
        &pfslam_io::carmen::CarmenOptions::default(),
    )
    .unwrap();
    let traj = pfslam::geometry::Trajectory::new(
        pfslam::sensors::sync::poses_at_stamps(
            &log.recording.odometry,
            &log.recording.scans.stamps_ns,
        )
        .0,
    );
    let rel = read_relations(&dir.join("mit-csail.relations")).unwrap();
    let r = evaluate_relations(&traj, &rel, &RelationsOptions::default()).unwrap();
    eprintln!(
        "raw odometry mit-csail (clf): trans {:.4} +- {:.4} m, rot {:.3} +- {:.3} deg",
        r.trans_m.abs.mean, r.trans_m.abs.std, r.rot_deg.abs.mean, r.rot_deg.abs.std
    );
    let bag = &rows[2].1;
    assert_eq!(r.used, bag.used);
    assert!((r.trans_m.abs.mean - bag.trans_m.abs.mean).abs() < 1e-4);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    // any rigid move of any trajectory aligns back to zero error
    #[test]
    fn alignment_undoes_any_rigid_move(
        steps in proptest::collection::vec((-1.0f64..1.0, -0.5f64..0.5), 3..60),
        tx in -100.0f64..100.0, ty in -100.0f64..100.0, yaw in -3.0f64..3.0,
    ) {
        let mut p = Pose2::IDENTITY;
        let mut gt = Vec::new();
        for (k, (d, r)) in steps.iter().enumerate() {
            gt.push(StampedPose2 { stamp_ns: k as i64, pose: p });
            p = p.compose(&Pose2::new(*d, 0.1, *r));
        }
        let t = Pose2::new(tx, ty, yaw);
        let est: Vec<StampedPose2> = gt.iter().map(|s| StampedPose2 { stamp_ns: s.stamp_ns, pose: t.compose(&s.pose) }).collect();
        let r = ate(&Trajectory::new(est), &Trajectory::new(gt), Association::Nearest { tolerance_ns: 0 }).unwrap();
        proptest::prop_assert!(r.aligned_m.rmse < 1e-6, "{}", r.aligned_m.rmse);
        proptest::prop_assert!(r.aligned_rot_deg.max < 1e-6);
    }
}
