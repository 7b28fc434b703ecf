//! `pfslam simulate` end to end.

use super::{pfslam, run_ok};

#[test]
fn simulate_car_writes_dataset_and_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("car");
    run_ok(
        pfslam()
            .args(["simulate", "--duration-s", "3", "--seed", "5", "--out"])
            .arg(&out),
    );
    for f in [
        "sensor_data/encoder.csv",
        "sensor_data/fog.csv",
        "sensor_data/lidar.csv",
        "param/EncoderParameter.txt",
        "ground_truth.tum",
        "true_map.png",
        "true_map.pgm",
        "true_map.yaml",
        "sim.toml",
        "world.world",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let ds = pfslam_io::ucsd::read_car_dataset(&out, &Default::default()).unwrap();
    assert_eq!(ds.encoder.len(), 301);
    // info on the car's layout: its rows, the LMS511's layout, the filter it would run
    let o = run_ok(pfslam().arg("info").arg(&out));
    let s = String::from_utf8_lossy(&o.stdout);
    for want in [
        "format:     ucsd_car",
        "286 beams from   -5.000 deg",
        "filter mode ScanMatch",
    ] {
        assert!(s.contains(want), "{want:?} not in\n{s}");
    }
    // sim.toml reproduces the run, byte for byte
    let again = dir.path().join("again");
    let o = pfslam()
        .args(["simulate", "--config"])
        .arg(out.join("sim.toml"))
        .arg("--out")
        .arg(&again)
        .output()
        .unwrap();
    assert!(o.status.success());
    for f in ["sensor_data/lidar.csv", "ground_truth.tum", "sim.toml"] {
        assert_eq!(
            std::fs::read(out.join(f)).unwrap(),
            std::fs::read(again.join(f)).unwrap(),
            "{f}"
        );
    }
}

#[test]
fn simulate_humanoid_writes_its_layout() {
    let dir = tempfile::tempdir().unwrap();
    run_ok(
        pfslam()
            .args([
                "simulate",
                "--vehicle",
                "humanoid",
                "--duration-s",
                "2",
                "--noise-free",
                "--out",
            ])
            .arg(dir.path()),
    );
    let ds = pfslam_io::humanoid::read_humanoid_dataset(dir.path()).unwrap();
    assert_eq!(ds.lidar.beam_count, 1081);
    let o = run_ok(pfslam().arg("info").arg(dir.path()));
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.contains("format:     humanoid") && s.contains("1081 beams"),
        "{s}"
    );
    assert!(dir.path().join("beam_labels.csv").is_file());
}

#[test]
fn simulate_bad_input_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.world");
    std::fs::write(&bad, "name x\nprism building 0 5 0 0 1 1\n").unwrap();
    let o = pfslam()
        .args(["simulate", "--world"])
        .arg(&bad)
        .arg("--out")
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.world:2"), "{err}");
    for args in [
        vec!["simulate", "--duration-s", "-1"],
        vec!["simulate", "--world", "atlantis"],
        vec!["simulate", "--vehicle", "boat"],
    ] {
        let o = pfslam()
            .args(&args)
            .arg("--out")
            .arg(dir.path().join("o"))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
    }
}
