//! `pfslam dead-reckon`: outputs, printed summary, exit code 2 on bad input with nothing
//! written.

use super::pfslam;
use pfslam::sensors::{CarCalibration, CarDataset, EncoderSample, FogSample, ScanSet};
use pfslam_io::ucsd::write_car_dataset;
use std::path::Path;

/// A 20 s drive on a circle: 100 Hz encoder, 1 kHz FOG consistent with the wheels, 10 Hz
/// LiDAR.
fn circle_dataset() -> CarDataset {
    let cal = CarCalibration::ucsd();
    let p = cal.encoder;
    let k = std::f64::consts::PI / f64::from(p.resolution_ticks);
    let (dl, dr) = (40i64, 44i64);
    let dyaw = (k * p.right_wheel_diameter_m * dr as f64 - k * p.left_wheel_diameter_m * dl as f64)
        / p.wheel_base_m;
    let t0 = 1_000_000_000_000i64;
    let encoder: Vec<EncoderSample> = (0..2000)
        .map(|i| EncoderSample {
            stamp_ns: t0 + i * 10_000_000,
            left_count: i * dl,
            right_count: i * dr,
        })
        .collect();
    let fog: Vec<FogSample> = (-5..20_005)
        .map(|i| FogSample {
            stamp_ns: t0 + i * 1_000_000,
            delta_roll_rad: 0.0,
            delta_pitch_rad: 0.0,
            delta_yaw_rad: dyaw / 10.0,
        })
        .collect();
    let mut lidar = ScanSet::new(cal.lidar.beam_count);
    let row = vec![12.5f32; cal.lidar.beam_count];
    for i in 0..200 {
        lidar.push(t0 + i * 100_000_000 + 3, &row);
    }
    CarDataset {
        calibration: cal,
        encoder,
        fog,
        lidar,
        stereo_stamps_ns: Vec::new(),
    }
}

fn files_in(dir: &Path) -> Vec<String> {
    match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect(),
        Err(_) => Vec::new(),
    }
}

/// Writes the circle dataset, lets `spoil` alter it, runs `dead-reckon` on it.
fn run_dead_reckon(
    spoil: impl FnOnce(&Path),
    extra: &[&str],
) -> (std::process::Output, tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    write_car_dataset(&data, &circle_dataset()).unwrap();
    spoil(&data);
    let out = dir.path().join("out");
    let o = pfslam()
        .arg("dead-reckon")
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .args(extra)
        .output()
        .unwrap();
    (o, dir, out)
}

#[test]
fn dead_reckon_writes_outputs() {
    let (o, _dir, out) = run_dead_reckon(|_| {}, &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        stdout.contains("distance:") && stdout.contains("final pose"),
        "{stdout}"
    );
    let tum = pfslam_io::tum::read_tum(&out.join("trajectory.tum")).unwrap();
    assert_eq!(tum.len(), 200, "one pose per LiDAR scan");
    let csv = std::fs::read_to_string(out.join("trajectory.csv")).unwrap();
    assert_eq!(csv.lines().count(), 201);
    let png = std::fs::read(out.join("trajectory.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    let width = u32::from_be_bytes([png[16], png[17], png[18], png[19]]);
    assert!(width > 500, "{width}");
    // The circle's radius: every pose lies on it (dead reckoning is exact here).
    let p = CarCalibration::ucsd().encoder;
    let k = std::f64::consts::PI / 4096.0;
    let (sl, sr) = (
        k * p.left_wheel_diameter_m * 40.0,
        k * p.right_wheel_diameter_m * 44.0,
    );
    let r = 0.5 * (sl + sr) / ((sr - sl) / p.wheel_base_m);
    for sp in &tum.poses {
        let d = sp.pose.x_m.hypot(sp.pose.y_m - r);
        assert!((d - r).abs() < 1e-6 * r, "{d} vs {r}");
    }
}

fn run_bad(spoil: impl FnOnce(&Path), extra: &[&str]) -> (Option<i32>, String, Vec<String>) {
    let (o, _dir, out) = run_dead_reckon(spoil, extra);
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        files_in(&out),
    )
}

#[test]
fn bad_row_exits_2_and_writes_nothing() {
    let (code, err, files) = run_bad(
        |d| {
            let p = d.join("sensor_data/encoder.csv");
            let t = std::fs::read_to_string(&p).unwrap();
            let mut lines: Vec<String> = t.lines().map(String::from).collect();
            lines[41] = "1000000410000000,1640,abc".into();
            std::fs::write(&p, lines.join("\n")).unwrap();
        },
        &[],
    );
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("encoder.csv:42") && err.contains("right_count"),
        "{err}"
    );
    assert!(files.is_empty(), "{files:?}");
}

#[test]
fn missing_dataset_exits_2() {
    let (code, err, files) = run_bad(
        |d| std::fs::remove_file(d.join("param/lidar_param.txt")).unwrap(),
        &[],
    );
    assert_eq!(code, Some(2));
    assert!(
        err.contains("lidar_param.txt") && err.contains("missing"),
        "{err}"
    );
    assert!(files.is_empty());
}

#[test]
fn backwards_timestamps_rejected_or_sorted() {
    let swap = |d: &Path| {
        let p = d.join("sensor_data/lidar.csv");
        let t = std::fs::read_to_string(&p).unwrap();
        let mut lines: Vec<&str> = t.lines().collect();
        lines.swap(10, 11);
        std::fs::write(&p, lines.join("\n")).unwrap();
    };
    let (code, err, _) = run_bad(swap, &[]);
    assert_eq!(code, Some(2));
    assert!(
        err.contains("lidar.csv:12") && err.contains("backwards"),
        "{err}"
    );
    let (code, err, files) = run_bad(swap, &["--sort-timestamps"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("sorted"), "{err}");
    // the three outputs and the manifest listing them
    assert_eq!(files.len(), 4, "{files:?}");
    assert!(
        files.iter().any(|f| f.ends_with("manifest.json")),
        "{files:?}"
    );
}

#[test]
fn bad_config_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("c.toml");
    std::fs::write(&cfg, "[motion]\nstep = \"rk4\"\n").unwrap();
    let o = pfslam()
        .args(["dead-reckon", "nowhere", "--out"])
        .arg(dir.path().join("o"))
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("c.toml"));
}

#[test]
fn dead_reckon_takes_the_odometry_of_a_carmen_log() {
    let Some(data) = super::data_dir("dead_reckon_takes_the_odometry_of_a_carmen_log") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dr");
    super::run_ok(
        super::pfslam()
            .arg("dead-reckon")
            .arg(data.join("freiburg/mit-csail/mit-csail.clf"))
            .arg("--out")
            .arg(&out),
    );
    let traj = pfslam_io::tum::read_tum(&out.join("trajectory.tum")).unwrap();
    // one pose per scan (the data README's table: 1,988 scans), moving: the log's odometry, not zeros
    assert_eq!(traj.len(), 1988);
    assert!(traj.path_length_m() > 100.0, "{}", traj.path_length_m());
}

#[test]
fn run_maps_a_log_without_usable_stamps_and_accounts_for_every_scan() {
    let Some(data) =
        super::data_dir("run_maps_a_log_without_usable_stamps_and_accounts_for_every_scan")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    // every laser stamp of this log is 0: 237 laser lines (the data README's table)
    let o = super::run_ok(
        super::pfslam()
            .arg("run")
            .arg(data.join("carmen/orebro-corrected.log.gz"))
            .arg("--out")
            .arg(&out),
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("237 of 237 scans kept"), "{stdout}");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("warning:") && stderr.contains("file order"),
        "{stderr}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["input"]["scans_kept"], 237);
    assert_eq!(summary["input"]["format"], "carmen");
    let traj = pfslam_io::tum::read_tum(&out.join("trajectory.tum")).unwrap();
    assert_eq!(traj.len(), 237);
    assert!(traj.path_length_m() > 150.0, "{}", traj.path_length_m());
}

#[test]
fn info_describes_a_bag_and_names_the_layouts_looked_for() {
    let dir = tempfile::tempdir().unwrap();
    let o = super::pfslam()
        .arg("info")
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("no known layout") && e.contains("metadata.yaml"),
        "{e}"
    );
    let Some(data) = super::data_dir("info_describes_a_bag_and_names_the_layouts_looked_for")
    else {
        return;
    };
    let o = super::run_ok(
        super::pfslam()
            .arg("info")
            .arg(data.join("freiburg/mit-csail/mit-csail.bag")),
    );
    let s = String::from_utf8_lossy(&o.stdout);
    for want in [
        "format:     ros1_bag",
        "/scan",
        "1988 msgs",
        "sensor_msgs/LaserScan",
        "361 beams from  -90.000 deg step 0.5000 deg",
        "odometry:   1988 of 1988 poses from /odom",
        "mount:      /tf_static: base_link -> laser",
        "filter mode Rbpf",
    ] {
        assert!(s.contains(want), "{want:?} not in\n{s}");
    }
    // a topic asked for that is not there: exit 2, the topics listed
    let o = super::pfslam()
        .arg("info")
        .arg(data.join("freiburg/mit-csail/mit-csail.bag"))
        .args(["--scan-topic", "/base_scan"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("/odom (nav_msgs/Odometry, 1988 messages)"),
        "{e}"
    );
    // the CARMEN log: line types, the ODOM lines it does not need
    let o = super::run_ok(
        super::pfslam()
            .arg("info")
            .arg(data.join("carmen/intel-corrected.log.gz")),
    );
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.contains("14541 ODOM lines") && s.contains("910 of 910 kept"),
        "{s}"
    );
}

#[test]
fn a_span_of_the_recording_and_a_rosbag2_directory() {
    let Some(data) = super::data_dir("a_span_of_the_recording_and_a_rosbag2_directory") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dr");
    let clf = data.join("freiburg/mit-csail/mit-csail.clf");
    let o = super::run_ok(
        super::pfslam()
            .arg("dead-reckon")
            .arg(&clf)
            .args(["--start-s", "100", "--end-s", "200", "--out"])
            .arg(&out),
    );
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("outside the span asked for"), "{s}");
    let whole = pfslam_io::carmen::read_carmen(&clf, &Default::default()).unwrap();
    let t0 = whole.recording.scans.stamps_ns[0];
    let inside = whole
        .recording
        .scans
        .stamps_ns
        .iter()
        .filter(|&&t| t >= t0 + 100_000_000_000 && t <= t0 + 200_000_000_000)
        .count();
    let traj = pfslam_io::tum::read_tum(&out.join("trajectory.tum")).unwrap();
    assert_eq!(traj.len(), inside);
    assert!(inside > 100 && inside < 1988, "{inside}");
    for p in &traj.poses {
        assert!(p.stamp_ns >= t0 + 100_000_000_000 && p.stamp_ns <= t0 + 200_000_000_000);
    }
    // a rosbag2 directory: metadata.yaml beside one .mcap
    let bag2 = dir.path().join("rosbag2_run");
    std::fs::create_dir(&bag2).unwrap();
    std::fs::write(
        bag2.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n",
    )
    .unwrap();
    let opts = pfslam_io::options::ReaderOptions::default();
    pfslam_io::mcap::write_mcap(&bag2.join("rosbag2_run_0.mcap"), &whole.recording, &opts).unwrap();
    let o = super::run_ok(super::pfslam().arg("info").arg(&bag2));
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.contains("format:     mcap") && s.contains("1988 of 1988 kept"),
        "{s}"
    );
}

#[test]
fn perturb_writes_a_degraded_log_and_its_reference() {
    let Some(data) = super::data_dir("perturb_writes_a_degraded_log_and_its_reference") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let src = data.join("carmen/seattle-corrected.log.gz");
    let original = pfslam_io::carmen::read_carmen(&src, &Default::default()).unwrap();
    let mut ates = Vec::new();
    for level in ["0", "1", "2"] {
        let out = dir.path().join(format!("Seattle-L{level}.log"));
        let o = super::run_ok(
            super::pfslam()
                .arg("perturb")
                .arg(&src)
                .args(["--level", level, "--seed", "3", "--out"])
                .arg(&out),
        );
        let s = String::from_utf8_lossy(&o.stdout);
        assert!(s.contains("241 scans"), "{s}");
        // every scan, with the original ranges and stamps; the reference beside it
        let back = pfslam_io::carmen::read_carmen(&out, &Default::default()).unwrap();
        assert_eq!(back.recording.scans, original.recording.scans);
        let reference = dir.path().join(format!("Seattle-L{level}.reference.tum"));
        let r = pfslam_io::tum::read_tum(&reference).unwrap();
        assert_eq!(r.len(), 241);
        // the log is its own ground truth: its FLASER poses are the reference
        let o = super::run_ok(
            super::pfslam()
                .arg("eval")
                .arg("--json")
                .arg("--ground-truth")
                .arg(&out)
                .arg(&out),
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        ates.push(v["ate"]["aligned_m"]["rmse"].as_f64().unwrap());
    }
    assert!(
        ates[0] < 1e-6 && ates[0] < ates[1] && ates[1] < ates[2],
        "{ates:?}"
    );
    let bad = super::pfslam()
        .arg("perturb")
        .arg(&src)
        .args(["--level", "5", "--out"])
        .arg(dir.path().join("x.log"))
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}

/// `map` scores how well the scans agree with the map along the poses it is given: a log's
/// corrected poses far better than its degraded odometry.
#[test]
fn map_reports_how_consistent_the_poses_are() {
    let Some(data) = super::data_dir("map_reports_how_consistent_the_poses_are") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("seattle-L2.log");
    super::run_ok(
        super::pfslam()
            .arg("perturb")
            .arg(data.join("carmen/seattle-corrected.log.gz"))
            .args(["--level", "2", "--seed", "1", "--out"])
            .arg(&log),
    );
    let odometry = dir.path().join("odometry");
    super::run_ok(
        super::pfslam()
            .arg("dead-reckon")
            .arg(&log)
            .arg("--out")
            .arg(&odometry),
    );
    let share = |poses: &Path, name: &str| {
        let out_dir = dir.path().join(name);
        let o = super::run_ok(
            super::pfslam()
                .arg("map")
                .arg(&log)
                .arg("--poses")
                .arg(poses)
                .arg("--out")
                .arg(&out_dir),
        );
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(stdout.contains("consistency:"), "{stdout}");
        let stats: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out_dir.join("map_stats.json")).unwrap())
                .unwrap();
        stats["free_share"].as_f64().unwrap()
    };
    let corrected = share(&dir.path().join("seattle-L2.reference.tum"), "corrected");
    let degraded = share(&odometry.join("trajectory.tum"), "degraded");
    assert!((0.0..0.1).contains(&corrected), "{corrected}");
    assert!(
        degraded > corrected + 0.05,
        "{degraded} against {corrected}"
    );
}

/// `--keyframes-m`: the scans thinned to one per metre of travel (or 10 deg of turning),
/// each kept scan unchanged, the reference thinned alike.
#[test]
fn perturb_thins_a_recording_to_keyframes() {
    let Some(data) = super::data_dir("perturb_thins_a_recording_to_keyframes") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let src = data.join("freiburg/mit-csail/mit-csail.clf");
    let original = pfslam_io::carmen::read_carmen(&src, &Default::default()).unwrap();
    let out = dir.path().join("kf.log");
    let o = super::run_ok(
        super::pfslam()
            .arg("perturb")
            .arg(&src)
            .args(["--level", "0", "--keyframes-m", "1", "--out"])
            .arg(&out),
    );
    let kf = pfslam_io::carmen::read_carmen(&out, &Default::default()).unwrap();
    let (n, n0) = (kf.recording.scans.len(), original.recording.scans.len());
    assert!(n > 20 && 2 * n < n0, "{n} of {n0}");
    // the thinning is reported
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains(&format!("keyframes: {n} of {n0} scans")),
        "{text}"
    );
    let reference = pfslam_io::tum::read_tum(&dir.path().join("kf.reference.tum")).unwrap();
    assert_eq!(reference.len(), n);
    let o = &original.recording.scans;
    let mut j = 0;
    for (k, pair) in reference.poses.windows(2).enumerate() {
        let d = pair[0].pose.between(&pair[1].pose);
        assert!(
            d.translation_norm_m() >= 1.0 - 1e-9 || d.yaw_rad.abs() >= 10f64.to_radians() - 1e-9,
            "keyframes {k} and {} too close: {d:?}",
            k + 1
        );
    }
    for i in 0..n {
        let stamp = kf.recording.scans.stamps_ns[i];
        while o.stamps_ns[j] != stamp {
            j += 1;
        }
        assert_eq!(kf.recording.scans.ranges(i), o.ranges(j), "scan {i}");
    }
}

/// Staging directories of killed runs left in `dir`.
fn staging_dirs(dir: &std::path::Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".pfslam-staging-"))
        .collect()
}

#[test]
fn outputs_are_one_unit_and_checked_before_work() {
    let Some(data) = super::data_dir("outputs_are_one_unit_and_checked_before_work") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let log = data.join("carmen/orebro-corrected.log.gz");
    let out = dir.path().join("o");
    let run = |extra: &[&str], out: &std::path::Path| {
        super::pfslam()
            .arg("run")
            .arg(&log)
            .args(extra)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    // a bad [graph] key is refused before the recording is read, and nothing is written
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[graph]\nkeyframe_distance_m = -1\n").unwrap();
    let t = std::time::Instant::now();
    let o = run(&["--config", bad.to_str().unwrap()], &out);
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("[graph]") && e.contains("keyframe_distance_m"),
        "{e}"
    );
    assert!(
        !String::from_utf8_lossy(&o.stdout).contains("input:"),
        "refused before reading"
    );
    assert!(!out.exists() && t.elapsed().as_secs_f64() < 5.0);
    // a file in the way of --out, or of its parent
    let file = dir.path().join("file");
    std::fs::write(&file, "x").unwrap();
    for o in [run(&[], &file), run(&[], &file.join("o"))] {
        assert_eq!(o.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&o.stderr).contains("--out"));
    }
    // a second run without the back end removes the first run's front_end.tum, not the user's file
    super::assert_ok(&run(&[], &out));
    assert!(out.join("front_end.tum").is_file() && out.join("manifest.json").is_file());
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let off = dir.path().join("off.toml");
    std::fs::write(&off, "[graph]\nenabled = false\n").unwrap();
    super::assert_ok(&run(&["--config", off.to_str().unwrap()], &out));
    assert!(!out.join("front_end.tum").exists(), "stale output left");
    assert!(out.join("trajectory.tum").is_file() && out.join("notes.txt").is_file());
    let manifest = std::fs::read_to_string(out.join("manifest.json")).unwrap();
    assert!(
        manifest.contains("trajectory.tum") && !manifest.contains("front_end.tum"),
        "{manifest}"
    );
    // a run killed midway leaves the previous outputs as they were; the next run clears its
    // staging directory
    let before = std::fs::read(out.join("trajectory.tum")).unwrap();
    let spawn_intel = || {
        super::pfslam()
            .arg("run")
            .arg(data.join("freiburg/intel/intel.bag"))
            .arg("--out")
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap()
    };
    let mut child = spawn_intel();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(std::fs::read(out.join("trajectory.tum")).unwrap(), before);
    assert!(out.join("notes.txt").is_file());
    assert_eq!(
        staging_dirs(dir.path()).len(),
        1,
        "the killed run's staging directory"
    );
    super::assert_ok(&run(&[], &dir.path().join("o2")));
    assert!(
        staging_dirs(dir.path()).is_empty(),
        "{:?}",
        staging_dirs(dir.path())
    );
    // Ctrl-C or `kill` ends the run at once, with 128 + the signal, and takes its staging
    // directory with it
    #[cfg(unix)]
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let mut child = spawn_intel();
        let t = std::time::Instant::now();
        while staging_dirs(dir.path()).is_empty() && t.elapsed().as_secs() < 20 {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        assert_eq!(
            staging_dirs(dir.path()).len(),
            1,
            "the run's staging directory"
        );
        std::thread::sleep(std::time::Duration::from_millis(500));
        let kill = std::process::Command::new("kill")
            .arg(signal)
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(kill.success());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "{signal}");
        assert!(
            staging_dirs(dir.path()).is_empty(),
            "{signal}: {:?}",
            staging_dirs(dir.path())
        );
        assert_eq!(std::fs::read(out.join("trajectory.tum")).unwrap(), before);
    }
}

#[test]
fn benchmark_corpus_scores_logs_against_their_reference() {
    let Some(data) = super::data_dir("benchmark_corpus_scores_logs_against_their_reference") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let corpus = dir.path().join("corpus");
    std::fs::create_dir(&corpus).unwrap();
    std::fs::copy(
        data.join("carmen/seattle-corrected.log.gz"),
        corpus.join("seattle-corrected.log.gz"),
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = super::run_ok(
        super::pfslam()
            .args(["benchmark", "--levels", "0,1", "--seeds", "1,2", "--corpus"])
            .arg(&corpus)
            .arg("--out")
            .arg(&out),
    );
    let text = String::from_utf8_lossy(&o.stdout);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("corpus.json")).unwrap()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 4, "{text}");
    let f = |r: &serde_json::Value, k: &str| r[k].as_f64().unwrap();
    // level by level, seed by seed
    let seeds: Vec<u64> = rows.iter().map(|r| r["seed"].as_u64().unwrap()).collect();
    assert_eq!(seeds, [1, 2, 1, 2], "{text}");
    // the log's own odometry is its reference; level 1 is metres off
    assert!(
        f(&rows[0], "odometry_ate_m") < 1e-9 && f(&rows[2], "odometry_ate_m") > 0.5,
        "{text}"
    );
    assert!(["ok", "suspect"].contains(&rows[0]["verdict"].as_str().unwrap()));
    // seed 1 measured 0.040 / 0.058 m on this building
    for r in rows {
        assert!(f(r, "slam_ate_m") < 0.2, "{text}");
    }
}

/// `localize` in a map another tool could have written: the map_server pair rasterised from
/// a Radish log's corrected poses, the log's odometry degraded (level 2), the filter started
/// at the corrected first pose. Returns the unaligned ATE RMSE against the corrected poses
/// and the summary.
fn localize_in_corrected_map(data: &Path, name: &str) -> (f64, serde_json::Value) {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join(format!("{name}-L2.log"));
    let reference = dir.path().join(format!("{name}-L2.reference.tum"));
    super::run_ok(
        super::pfslam()
            .arg("perturb")
            .arg(data.join(format!("carmen/{name}-corrected.log.gz")))
            .args(["--level", "2", "--seed", "1", "--out"])
            .arg(&log),
    );
    let map_dir = dir.path().join("map");
    super::run_ok(
        super::pfslam()
            .arg("map")
            .arg(&log)
            .arg("--poses")
            .arg(&reference)
            .arg("--out")
            .arg(&map_dir),
    );
    let truth = pfslam_io::tum::read_tum(&reference).unwrap();
    let start = truth.poses[0].pose;
    let out_dir = dir.path().join("localized");
    let o = super::run_ok(
        super::pfslam()
            .arg("localize")
            .arg(&log)
            .arg("--map")
            .arg(map_dir.join("map.yaml"))
            .arg(format!(
                "--initial-pose={},{},{}",
                start.x_m,
                start.y_m,
                start.yaw_rad.to_degrees()
            ))
            .arg("--out")
            .arg(&out_dir),
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("real time"), "{stdout}");
    for f in ["trajectory.tum", "map.png", "updates.csv", "summary.json"] {
        assert!(out_dir.join(f).is_file(), "{f} missing");
    }
    let estimate = pfslam_io::tum::read_tum(&out_dir.join("trajectory.tum")).unwrap();
    let ate =
        pfslam::eval::ate::ate(&estimate, &truth, pfslam::eval::Association::default()).unwrap();
    assert_eq!(ate.pairs, truth.len());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert!(summary["realtime_factor"].as_f64().unwrap() > 1.0);
    // the reader's account travels with the result, as for `run`
    assert_eq!(
        summary["input"]["scans_kept"].as_u64(),
        Some(truth.len() as u64),
        "{summary}"
    );
    (ate.unaligned_m.rmse, summary)
}

#[test]
fn localize_follows_the_corrected_poses_in_a_map_made_from_them() {
    let Some(data) =
        super::data_dir("localize_follows_the_corrected_poses_in_a_map_made_from_them")
    else {
        return;
    };
    // seeds 1-3 measured 0.031 / 0.030 / 0.031 m (0.045 without refining the estimate)
    let (rmse, summary) = localize_in_corrected_map(&data, "seattle");
    assert!(rmse < 0.045, "seattle {rmse}");
    assert_eq!(summary["quality"]["status"], "ok", "{summary}");
    // seeds 1-3 measured 0.036 / 0.036 / 0.043 m (0.061-0.063 without)
    let (rmse, _) = localize_in_corrected_map(&data, "intel");
    assert!(rmse < 0.06, "intel {rmse}");
}

#[test]
fn localize_rejects_a_bad_pose_and_a_missing_map() {
    let dir = tempfile::tempdir().unwrap();
    let bad_pose = super::pfslam()
        .args([
            "localize",
            "x.log",
            "--map",
            "m.yaml",
            "--initial-pose",
            "1,2",
        ])
        .arg("--out")
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(bad_pose.status.code(), Some(2));
    let err = String::from_utf8_lossy(&bad_pose.stderr);
    assert!(
        err.contains("--initial-pose") && err.contains("X,Y,YAW_DEG"),
        "{err}"
    );
    let no_map = super::pfslam()
        .args(["localize", "x.log", "--map"])
        .arg(dir.path().join("missing.yaml"))
        .arg("--out")
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(no_map.status.code(), Some(2));
    let err = String::from_utf8_lossy(&no_map.stderr);
    assert!(err.contains("missing.yaml"), "{err}");
    assert!(!dir.path().join("o").exists());
}

/// `run --save-state`, then `run --resume` on the rest of the recording: both sessions'
/// outputs in one frame, the merged state saved; a file that is not a state exits 2.
#[test]
fn a_second_session_continues_a_saved_map() {
    let Some(data) = super::data_dir("a_second_session_continues_a_saved_map") else {
        return;
    };
    let log = data.join("carmen/seattle-corrected.log.gz");
    let dir = tempfile::tempdir().unwrap();
    let (first, second) = (dir.path().join("first"), dir.path().join("second"));
    let (state1, state2) = (dir.path().join("1.pfslam"), dir.path().join("2.pfslam"));
    let o = super::run_ok(
        super::pfslam()
            .arg("run")
            .arg(&log)
            .args(["--end-s", "500", "--out"])
            .arg(&first)
            .arg("--save-state")
            .arg(&state1),
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("keyframes of 1 session"));
    let o = super::run_ok(
        super::pfslam()
            .arg("run")
            .arg(&log)
            .args(["--start-s", "500", "--out"])
            .arg(&second)
            .arg("--resume")
            .arg(&state1)
            .arg("--save-state")
            .arg(&state2),
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("keyframes of 2 session"));
    for f in [
        "trajectory.tum",
        "previous_sessions.tum",
        "map.yaml",
        "map.png",
    ] {
        assert!(second.join(f).is_file(), "{f} missing");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(second.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["sessions"].as_array().map(Vec::len), Some(2));
    // both sessions together against the corrected poses (measured 0.100 m; one run: 0.04 m)
    let mut poses = pfslam_io::tum::read_tum(&first.join("trajectory.tum"))
        .unwrap()
        .poses;
    poses.extend(
        pfslam_io::tum::read_tum(&second.join("trajectory.tum"))
            .unwrap()
            .poses,
    );
    poses.sort_by_key(|p| p.stamp_ns);
    let options = pfslam_io::carmen::CarmenOptions::from_reader(
        &pfslam_io::recording::ReaderOptions::default(),
    );
    let truth = pfslam_io::carmen::read_carmen(&log, &options)
        .unwrap()
        .laser_poses;
    let est = pfslam::geometry::Trajectory::new(poses);
    let ate = pfslam::eval::ate::ate(&est, &truth, pfslam::eval::Association::default()).unwrap();
    assert_eq!(ate.pairs, truth.len());
    assert!(ate.aligned_m.rmse < 0.15, "{}", ate.aligned_m.rmse);
    let bad = dir.path().join("bad.pfslam");
    std::fs::write(&bad, "P5\n").unwrap();
    let out = super::pfslam()
        .arg("run")
        .arg(&log)
        .arg("--resume")
        .arg(&bad)
        .arg("--out")
        .arg(dir.path().join("third"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.pfslam") && err.contains("PFSLAMST"),
        "{err}"
    );
    assert!(!dir.path().join("third").exists());
}
