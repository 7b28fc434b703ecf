//! `run -`: a CARMEN log read from standard input as it arrives gives each pose at once and,
//! at the end, the batch run's result bit for bit.

use super::{pfslam, run_ok};
use std::io::Write;
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

/// A simulated 20 s drive written as a CARMEN log (`perturb --level 1`); its path.
fn simulated_log(dir: &Path) -> std::path::PathBuf {
    let sim = dir.join("sim");
    run_ok(
        pfslam()
            .args(["simulate", "--duration-s", "20", "--seed", "3", "--out"])
            .arg(&sim),
    );
    let log = dir.join("drive.clf");
    run_ok(
        pfslam()
            .arg("perturb")
            .arg(&sim)
            .args(["--level", "1", "--out"])
            .arg(&log),
    );
    log
}

fn line_count(path: &Path) -> usize {
    std::fs::read_to_string(path).map_or(0, |t| t.lines().count())
}

/// Waits until `ready` holds (at most 60 s); false if it never did.
fn wait_for(mut ready: impl FnMut() -> bool) -> bool {
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(60) {
        if ready() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

/// Feeds the first half of `log` to `child`, checks the poses and the snapshot appear while
/// it still runs, then feeds the rest slowly and closes its input.
fn feed_in_two_halves(child: &mut Child, log: &str, poses: &Path, snapshot: &Path) {
    let mut stdin = child.stdin.take().unwrap();
    let lines: Vec<&str> = log.lines().collect();
    let half = lines.len() / 2;
    for l in &lines[..half] {
        writeln!(stdin, "{l}").unwrap();
    }
    stdin.flush().unwrap();
    assert!(
        wait_for(|| line_count(poses) > 10),
        "no pose written within 60 s of feeding half the log"
    );
    assert!(wait_for(|| snapshot.is_file()), "no live snapshot written");
    assert!(
        child.try_wait().unwrap().is_none(),
        "the run ended before its input"
    );
    for chunk in lines[half..].chunks(50) {
        for l in chunk {
            writeln!(stdin, "{l}").unwrap();
        }
        stdin.flush().unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn a_log_piped_in_gives_its_poses_at_once_and_the_batch_result() {
    let dir = tempfile::tempdir().unwrap();
    let log = simulated_log(dir.path());
    let batch = dir.path().join("batch");
    run_ok(pfslam().arg("run").arg(&log).arg("--out").arg(&batch));

    let (live, poses) = (dir.path().join("live"), dir.path().join("poses.tum"));
    let mut child = pfslam()
        .args(["run", "-", "--format", "carmen", "--snapshot-every-s", "2"])
        .arg("--out")
        .arg(&live)
        .arg("--poses-out")
        .arg(&poses)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let text = std::fs::read_to_string(&log).unwrap();
    feed_in_two_halves(&mut child, &text, &poses, &live.join("live_map.png"));
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "trajectory.tum",
        "front_end.tum",
        "dead_reckoning.tum",
        "map.pgm",
    ] {
        let a = std::fs::read(batch.join(f)).unwrap();
        let b = std::fs::read(live.join(f)).unwrap();
        assert!(a == b, "{f}: the live run differs from the batch run");
    }
    // a pose per scan handled; the snapshot gave way to the final maps
    assert_eq!(
        line_count(&poses),
        line_count(&live.join("front_end.tum")) - 1
    );
    assert!(!live.join("live_map.png").exists());
}

#[test]
fn poses_on_standard_output_leave_it_to_them() {
    let dir = tempfile::tempdir().unwrap();
    let log = simulated_log(dir.path());
    let out = pfslam()
        .args([
            "run",
            "-",
            "--format",
            "carmen",
            "--poses-out",
            "-",
            "--out",
        ])
        .arg(dir.path().join("out"))
        .stdin(std::fs::File::open(&log).unwrap())
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.lines().count() > 100);
    for l in text.lines() {
        assert_eq!(l.split_whitespace().count(), 8, "not a TUM line: {l}");
    }
    assert!(String::from_utf8_lossy(&out.stderr).contains("wrote"));
}

#[test]
fn live_input_flags_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&[&str], &str); 4] = [
        (&["run", "-"], "--format carmen"),
        (&["run", "x.clf", "--format", "carmen"], "give `-`"),
        (&["run", "x.clf", "--snapshot-every-s", "2"], "live input"),
        (
            &["run", "-", "--format", "carmen", "--start-s", "3"],
            "--start-s",
        ),
    ];
    for (args, expected) in cases {
        let out = pfslam()
            .args(args)
            .arg("--out")
            .arg(dir.path().join("o"))
            .stdin(Stdio::null())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(expected), "{args:?}: {err}");
    }
    let out = pfslam()
        .args(["run", "-", "--format", "carmen", "--out"])
        .arg(dir.path().join("o"))
        .stdin(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .and_then(|mut c| {
            c.stdin
                .take()
                .unwrap()
                .write_all(b"ODOM 0 0 0 0 0 0 1 h 1\nnonsense\n")?;
            c.wait_with_output()
        })
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("no scan"), "{err}");
}
