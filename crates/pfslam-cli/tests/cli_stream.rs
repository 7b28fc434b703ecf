//! `dead-reckon` streams CARMEN logs: the same outputs as reading them whole, and peak memory
//! that does not grow with the log's length (a generated log of several GB).

use super::{assert_ok, pfslam};
use std::io::Write;
use std::path::Path;

/// Writes a CARMEN log of about `bytes` bytes: 361-beam FLASER lines 25 ms apart, the robot
/// driving a slow arc; returns the number of laser lines.
fn write_log(path: &Path, bytes: u64) -> u64 {
    let file = std::fs::File::create(path).unwrap();
    let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
    let ranges: String = (0..361)
        .map(|i| format!(" {:.3}", 1.0 + (i % 97) as f64 * 0.07))
        .collect();
    writeln!(w, "# generated\nPARAM robot_frontlaser_offset 0.1 host 0").unwrap();
    let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
    let mut written = 0u64;
    let mut lines = 0u64;
    while written < bytes {
        let t = 1000.0 + lines as f64 * 0.025;
        let line = format!(
            "FLASER 361{ranges} {x:.6} {y:.6} {yaw:.6} {x:.6} {y:.6} {yaw:.6} {t:.6} host {t:.6}\n"
        );
        w.write_all(line.as_bytes()).unwrap();
        written += line.len() as u64;
        lines += 1;
        x += 0.01 * yaw.cos();
        y += 0.01 * yaw.sin();
        yaw = (yaw + 1e-4 + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
    }
    w.flush().unwrap();
    lines
}

/// Runs `pfslam dead-reckon LOG --out OUT`; returns its peak resident memory (KiB): the
/// largest `VmHWM` of `/proc/PID/status` while the process is `pfslam`. (A `wait4` figure
/// would also count the test process it may have been forked from before its `exec`.)
fn dead_reckon_peak_kib(log: &Path, out: &Path) -> i64 {
    let mut child = pfslam()
        .arg("dead-reckon")
        .arg(log)
        .arg("--out")
        .arg(out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let status_path = format!("/proc/{}/status", child.id());
    let mut peak_kib = 0;
    loop {
        if let Ok(status) = std::fs::read_to_string(&status_path)
            && status
                .lines()
                .any(|l| l.split_whitespace().eq(["Name:", "pfslam"]))
            && let Some(kib) = status
                .lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.split_whitespace().next())
                .and_then(|v| v.parse::<i64>().ok())
        {
            peak_kib = peak_kib.max(kib);
        }
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "dead-reckon {}: {status}", log.display());
            return peak_kib;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

#[test]
fn a_streamed_log_gives_what_reading_it_whole_gives() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("drive.clf");
    let lines = write_log(&log, 3_000_000);
    let streamed = dir.path().join("streamed");
    let whole = dir.path().join("whole");
    let o = pfslam()
        .arg("dead-reckon")
        .arg(&log)
        .arg("--out")
        .arg(&streamed)
        .output()
        .unwrap();
    assert_ok(&o);
    // a span, even the whole one, makes the reader read the log whole
    let args = ["--start-s", "0"];
    let o = pfslam()
        .arg("dead-reckon")
        .arg(&log)
        .arg("--out")
        .arg(&whole)
        .args(args)
        .output()
        .unwrap();
    assert_ok(&o);
    for f in ["trajectory.tum", "trajectory.csv"] {
        let a = std::fs::read(streamed.join(f)).unwrap();
        assert_eq!(a, std::fs::read(whole.join(f)).unwrap(), "{f}");
        assert_eq!(
            a.iter().filter(|&&b| b == b'\n').count() as u64,
            lines + 1,
            "{f}"
        );
    }
    assert!(streamed.join("trajectory.png").is_file());
}

/// Size of the long log (GB): `PFSLAM_LONG_LOG_GB`, default 5.
fn long_log_bytes() -> u64 {
    let gb: f64 = std::env::var("PFSLAM_LONG_LOG_GB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5.0);
    (gb * 1e9) as u64
}

#[test]
fn peak_memory_does_not_grow_with_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.clf");
    write_log(&short, 50_000_000);
    let short_kib = dead_reckon_peak_kib(&short, &dir.path().join("short-out"));
    std::fs::remove_file(&short).unwrap();
    let long = dir.path().join("long.clf");
    let bytes = long_log_bytes();
    let lines = write_log(&long, bytes);
    let out = dir.path().join("long-out");
    let long_kib = dead_reckon_peak_kib(&long, &out);
    std::fs::remove_file(&long).unwrap();
    let tum = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
    assert_eq!(tum.lines().count() as u64, lines + 1);
    eprintln!(
        "dead-reckon peak memory: {short_kib} KiB on 50 MB, {long_kib} KiB on {:.1} GB ({lines} scans)",
        bytes as f64 * 1e-9
    );
    // a whole-file read would hold ~1.5 KB per scan: hundreds of MB here
    assert!(
        long_kib <= short_kib + 8 * 1024,
        "peak memory grew from {short_kib} KiB to {long_kib} KiB"
    );
}
