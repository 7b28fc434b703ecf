//! `pfslam run` and `pfslam print-config` end to end.

use super::{pfslam, run_ok};
use std::process::Command;

#[test]
fn run_on_a_short_simulated_drive() {
    let dir = tempfile::tempdir().unwrap();
    let (data, cfg) = super::short_simulated_drive(dir.path());
    let res = dir.path().join("out");
    let out = pfslam()
        .arg("run")
        .arg(&data)
        .args(["--particles", "5", "--seed", "3", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&res)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("ATE RMSE"), "{stdout}");
    for f in [
        "trajectory.tum",
        "dead_reckoning.tum",
        "map.png",
        "binary_map.png",
        "map.pgm",
        "map.yaml",
        "summary.json",
    ] {
        assert!(res.join(f).is_file(), "{f} missing");
    }
    let snaps = std::fs::read_dir(res.join("snapshots")).unwrap().count();
    assert!(snaps >= 2, "{snaps} snapshots");
    let traj = pfslam_io::tum::read_tum(&res.join("trajectory.tum")).unwrap();
    let scans = std::fs::read_to_string(data.join("sensor_data/lidar.csv"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(traj.len(), scans, "a pose at every scan");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(res.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["config"]["filter"]["particles"], 5);
    assert_eq!(summary["seed"], 3);
    assert!(summary["slam_vs_ground_truth"]["ate"]["aligned_m"]["rmse"].is_number());
    assert!(summary["map_vs_true_map"]["precision"].is_number());
    // The same map through the trajectory's alignment: a separate figure with its transform.
    let aligned = &summary["map_vs_true_map_aligned"];
    assert!(aligned["recall"].is_number(), "{aligned}");
    assert!(
        aligned["ground_truth_from_map"]["yaw_rad"].is_number(),
        "{aligned}"
    );
    assert!(
        stdout.contains("through the ATE's SE(2) alignment"),
        "{stdout}"
    );
    assert!(summary["stats"]["timings"]["correlate_s"].is_number());
    assert!(summary["stats"]["neff_mean"].as_f64().unwrap() >= 1.0);
    // The self-check: a verdict, its reasons, and the free share it rests on.
    let quality = &summary["quality"];
    let status = quality["status"].as_str().unwrap_or_default();
    assert!(["ok", "suspect"].contains(&status), "{quality}");
    assert!(quality["reasons"].is_array(), "{quality}");
    let share = quality["signals"]["free_share"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&share), "{quality}");
    // One self-contained page: the pictures inline, the verdict, the accuracy against the
    // simulator's truth, the keys that differ from the defaults and no others.
    let report = std::fs::read_to_string(res.join("report.html")).unwrap();
    assert_eq!(
        report
            .matches("src=\"data:image/png;base64,iVBORw0KGgo")
            .count(),
        2
    );
    assert!(!report.contains("src=\"http") && !report.contains("href="));
    assert!(report.contains(&format!("class=\"{status}\">{status}</span>")));
    assert!(report.contains("Accuracy against the ground truth"));
    assert!(report.contains("filter.snapshot_every_scans") && report.contains("filter.particles"));
    assert!(!report.contains("filter.rbpf.likelihood.sigma_m"));
}

#[test]
fn run_rejects_bad_input_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = pfslam()
        .arg("run")
        .arg(dir.path().join("missing"))
        .arg("--out")
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, "[filter]\nparticles = 0\n").unwrap();
    let out = pfslam()
        .arg("run")
        .arg(dir.path())
        .arg("--config")
        .arg(&cfg)
        .arg("--out")
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("particles"));
}

#[test]
fn print_config_comments_every_key() {
    let out = pfslam().arg("print-config").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("# Number of particles"), "{text}");
    let parsed: pfslam::config::Config = toml::from_str(&text).unwrap();
    assert_eq!(parsed, pfslam::config::Config::default());
}

/// The effective user id, from `/proc/self/status` (`None` off Linux).
fn effective_uid() -> Option<u32> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("Uid:"))?;
    line.split_whitespace().nth(2)?.parse().ok()
}

/// `--out` inside a directory the user may not write to fails before the recording is read,
/// naming the directory. As root (whom permissions do not stop) the run is made as `nobody`
/// through `setpriv`; where that is impossible the test says so and stops.
#[test]
fn a_read_only_out_fails_before_any_work() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("sim");
    run_ok(
        pfslam()
            .args(["simulate", "--duration-s", "4", "--out"])
            .arg(&data),
    );
    let locked = dir.path().join("locked");
    std::fs::create_dir(&locked).unwrap();
    for (path, mode) in [(dir.path(), 0o755), (locked.as_path(), 0o555)] {
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
    }
    let bin = env!("CARGO_BIN_EXE_pfslam");
    let mut cmd = match effective_uid() {
        Some(0) => {
            let mut c = Command::new("setpriv");
            c.args(["--reuid=65534", "--regid=65534", "--clear-groups", bin]);
            c
        }
        _ => Command::new(bin),
    };
    let out = match cmd
        .arg("run")
        .arg(&data)
        .arg("--out")
        .arg(locked.join("out"))
        .output()
    {
        Ok(out) => out,
        Err(e) => {
            eprintln!("SKIP a_read_only_out_fails_before_any_work: cannot drop root ({e})");
            return;
        }
    };
    let err = String::from_utf8_lossy(&out.stderr);
    if err.contains("setpriv:") {
        eprintln!("SKIP a_read_only_out_fails_before_any_work: {err}");
        return;
    }
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("locked"), "{err}");
    // nothing was read or run: no account of the recording, no progress, no output
    assert!(!err.contains("scans") && out.stdout.is_empty(), "{err}");
    assert_eq!(std::fs::read_dir(&locked).unwrap().count(), 0);
}
