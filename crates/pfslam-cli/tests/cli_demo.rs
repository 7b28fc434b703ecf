//! The demo end to end on a short drive.

use super::pfslam;

#[test]
fn demo_runs_every_stage_and_reports_accuracy() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = pfslam()
        .args(["demo", "--duration-s", "15", "--particles", "5", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    for f in [
        "sim/ground_truth.tum",
        "sim/true_map.png",
        "dead_reckoning/trajectory.tum",
        "dead_reckoning/trajectory.png",
        "map_ground_truth/map.png",
        "slam/trajectory.tum",
        "slam/map.png",
        "slam/summary.json",
        "slam/texture.png",
        "slam/texture_rgb.npy",
    ] {
        assert!(out.join(f).is_file(), "missing {f}\n{stdout}");
    }
    assert!(stdout.contains("ATE RMSE vs ground truth"), "{stdout}");
}

#[test]
fn demo_rejects_bad_duration() {
    let dir = tempfile::tempdir().unwrap();
    let o = pfslam()
        .args(["demo", "--duration-s", "-3", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(!dir.path().join("sim").exists());
}
