//! `pfslam map`: end to end on a short noise-free simulation.

use super::{pfslam, run_ok};
use std::path::Path;

/// Simulates 12 s of the car (noise free) into `dir`.
fn simulate(dir: &Path) {
    run_ok(
        pfslam()
            .args(["simulate", "--noise-free", "--duration-s", "12", "--out"])
            .arg(dir),
    );
}

#[test]
fn map_with_ground_truth_writes_all_files() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    simulate(&ds);
    let out_dir = tmp.path().join("out");
    let out = pfslam()
        .arg("map")
        .arg(&ds)
        .arg("--poses")
        .arg(ds.join("ground_truth.tum"))
        .arg("--out")
        .arg(&out_dir)
        .args(["--resolution", "0.2", "--z-min", "2.1", "--z-max", "2.5"])
        .arg("--truth")
        .arg(ds.join("true_map.yaml"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("precision"), "{stdout}");
    for f in [
        "map.png",
        "binary_map.png",
        "map.pgm",
        "map.yaml",
        "logodds.npy",
        "map_stats.json",
    ] {
        assert!(out_dir.join(f).is_file(), "{f} missing");
    }
    let m = pfslam_io::map_files::read_map_server(&out_dir.join("map.yaml")).unwrap();
    assert_eq!(m.limits.resolution_m(), 0.2);
    let (occ, free, _) = m.counts();
    assert!(occ > 50 && free > 1000, "{occ} {free}");
    let (shape, _) = pfslam_io::map_files::read_npy_f32(&out_dir.join("logodds.npy")).unwrap();
    assert_eq!(shape, vec![m.height, m.width]);
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("map_stats.json")).unwrap())
            .unwrap();
    assert_eq!(stats["scans_without_pose"], 0);
    assert!(stats["comparison"]["precision"].as_f64().unwrap() > 0.9);
    let png = std::fs::read(out_dir.join("map.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"));
    let w = u32::from_be_bytes([png[16], png[17], png[18], png[19]]);
    let h = u32::from_be_bytes([png[20], png[21], png[22], png[23]]);
    assert!(w >= 600 || h >= 600, "{w} x {h}");
}

#[test]
fn map_bad_input_exits_2_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = tmp.path().join("ds");
    simulate(&ds);
    let run = |extra: &[&str], poses: &Path| {
        let out_dir = tmp.path().join("bad_out");
        let out = pfslam()
            .arg("map")
            .arg(&ds)
            .arg("--poses")
            .arg(poses)
            .arg("--out")
            .arg(&out_dir)
            .args(extra)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
            out_dir.exists(),
        )
    };
    let gt = ds.join("ground_truth.tum");
    let (code, err, wrote) = run(&["--resolution", "0"], &gt);
    assert_eq!(code, Some(2));
    assert!(err.contains("resolution_m"), "{err}");
    assert!(!wrote);
    let (code, err, wrote) = run(&[], &tmp.path().join("none.tum"));
    assert_eq!(code, Some(2));
    assert!(err.contains("none.tum"), "{err}");
    assert!(!wrote);
    let bad = tmp.path().join("bad.tum");
    std::fs::write(&bad, "1.0 0 0 0 0 0 0 1\nxyz\n").unwrap();
    let (code, err, _) = run(&[], &bad);
    assert_eq!(code, Some(2));
    assert!(err.contains("bad.tum:2"), "{err}");
    let (code, err, _) = run(&["--overlay", "nolabel"], &gt);
    assert_eq!(code, Some(2));
    assert!(err.contains("LABEL=FILE"), "{err}");
}
