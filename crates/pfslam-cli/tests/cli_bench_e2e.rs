//! `pfslam-dev bench-e2e` end to end on a short drive: it simulates, runs twice, reports medians
//! and the same trajectory as `pfslam run` (no timing is asserted).

use super::{pfslam, pfslam_dev, run_ok};

#[test]
fn bench_e2e_times_a_short_drive_and_matches_run() {
    let dir = tempfile::tempdir().unwrap();
    let work = dir.path().join("work");
    let json = dir.path().join("bench.json");
    let out = run_ok(
        pfslam_dev()
            .args([
                "--log",
                "warn",
                "bench-e2e",
                "--duration-s",
                "4",
                "--particles",
                "3",
            ])
            .args(["--runs", "2", "--work-dir"])
            .arg(&work)
            .arg("--json")
            .arg(&json),
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("median of 2 runs"), "{text}");
    assert_eq!(text.lines().filter(|l| l.starts_with("row: |")).count(), 1);
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["particles"], 3);
    assert_eq!(v["runs"], 2);
    let scans = v["scans"].as_u64().unwrap();
    assert!(scans > 350, "{scans} scans");
    for k in ["total_wall_s", "total_cpu_s", "slam_wall_s", "load_wall_s"] {
        let s = v["median"][k].as_f64().unwrap();
        assert!(s.is_finite() && s >= 0.0, "{k} = {s}");
    }
    // Both runs wrote the same trajectory, and `pfslam run` on the same files agrees.
    let a = std::fs::read(work.join("out_0/trajectory.tum")).unwrap();
    assert_eq!(a, std::fs::read(work.join("out_1/trajectory.tum")).unwrap());
    let run_out = dir.path().join("run");
    run_ok(
        pfslam()
            .args(["--log", "warn", "run"])
            .arg(work.join("dataset"))
            .args(["--particles", "3", "--out"])
            .arg(&run_out),
    );
    assert_eq!(a, std::fs::read(run_out.join("trajectory.tum")).unwrap());
    assert!(work.join("out_0/map.png").is_file() && work.join("out_0/map.yaml").is_file());
}

#[test]
fn developer_commands_are_not_in_the_users_tool() {
    for cmd in ["bench-e2e", "experiment"] {
        let out = pfslam().arg(cmd).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{cmd}");
        let out = pfslam_dev().args([cmd, "--help"]).output().unwrap();
        assert!(out.status.success(), "{cmd}");
    }
}
