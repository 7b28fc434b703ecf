//! CARMEN logs streamed scan by scan (`stream_scan_poses`) give what the whole-file reader
//! gives: the same stamps, odometry poses, layouts and account.

use crate::common::data_dir;
use pfslam_io::carmen::{CarmenLaser, CarmenOptions, ScanPose, read_carmen, stream_scan_poses};
use std::path::Path;

/// Streams `path`; `None` when the log must be read whole.
fn streamed(path: &Path, options: &CarmenOptions) -> Option<(Vec<ScanPose>, String)> {
    let mut scans = Vec::new();
    let account = stream_scan_poses(path, options, |s| {
        scans.push(s);
        Ok(())
    })
    .unwrap()?;
    Some((scans, serde_json::to_string(&account).unwrap()))
}

/// Whether streaming `path` agrees with reading it whole; `false` when it is not streamed.
fn agrees_with_whole_read(path: &Path, options: &CarmenOptions) -> bool {
    let Some((scans, account)) = streamed(path, options) else {
        return false;
    };
    let log = read_carmen(path, options).unwrap();
    let rec = &log.recording;
    assert_eq!(
        account,
        serde_json::to_string(&log.account).unwrap(),
        "{}",
        path.display()
    );
    assert_eq!(scans.len(), rec.scans.len());
    assert_eq!(rec.odometry.len(), rec.scans.len());
    for (i, s) in scans.iter().enumerate() {
        assert_eq!(s.stamp_ns, rec.scans.stamps_ns[i], "scan {i}");
        assert_eq!(s.stamp_ns, rec.odometry.poses[i].stamp_ns, "scan {i}");
        assert_eq!(s.odom, rec.odometry.poses[i].pose, "scan {i}");
        assert_eq!(&s.geometry, rec.lidar_at(i), "scan {i}");
    }
    true
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn a_clean_log_streams_as_it_reads_whole() {
    let dir = tempfile::tempdir().unwrap();
    // PARAM, comments, an ignored line type, ODOM lines, a malformed line, a second laser,
    // mixed beam counts, a non-finite reading and a cut last line
    let text = "# log\nPARAM robot_frontlaser_offset 0.25 h 0\n\
FLASER 2 1.0 2.0 0 0 0 5 6 0.1 1.0 h 1\n\
ODOM 5 6 0.1 0 0 0 1.05 h 1\n\
NEFF 3 1 1.0 h 1\n\
RLASER 2 3.0 4.0 0 0 0 5 6 0.1 1.1 h 1\n\
FLASER 3 1.5 nan 2.5 0 0 0 7 6 0.2 2.0 h 2\n\
FLASER 2 oops 0 0 0 7 6 0.2 2.5 h 2\n\
FLASER 2 1.5 2.5 0 0 0 8 6 0.3 3.0 h 3\n\
FLASER 2 1.5 2.5 0 0 0 9 6";
    let p = write(dir.path(), "clean.clf", text);
    assert!(agrees_with_whole_read(&p, &CarmenOptions::default()));
    let rear = CarmenOptions {
        laser: CarmenLaser::Rear,
        ..CarmenOptions::default()
    };
    assert!(agrees_with_whole_read(&p, &rear));
    let gz = dir.path().join("clean.clf.gz");
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut enc, text.as_bytes()).unwrap();
    std::fs::write(&gz, enc.finish().unwrap()).unwrap();
    assert!(agrees_with_whole_read(&gz, &CarmenOptions::default()));
}

#[test]
fn logs_that_need_the_whole_file_are_not_streamed() {
    let dir = tempfile::tempdir().unwrap();
    let options = CarmenOptions::default();
    // a zero stamp: the clock repair needs every stamp at once
    let zero = "FLASER 2 1 2 0 0 0 5 6 0.1 1.0 h 1\nFLASER 2 1 2 0 0 0 5 6 0.1 0 h 1\n\
FLASER 2 1 2 0 0 0 5 6 0.1 3.0 h 1\n";
    let p = write(dir.path(), "zero.clf", zero);
    assert!(streamed(&p, &options).is_none());
    assert_eq!(read_carmen(&p, &options).unwrap().recording.scans.len(), 3);
    // RAWLASER lines carry no pose: their odometry is the ODOM lines on their own clock
    let raw = "ODOM 0 0 0 0 0 0 1.0 h 1\n\
RAWLASER1 0 -1.5 3.0 1.5 30 0.01 0 3 1 2 3 0 1.5 h 1\nODOM 1 0 0 0 0 0 2.0 h 2\n";
    let p = write(dir.path(), "raw.clf", raw);
    assert!(streamed(&p, &options).is_none());
    // no laser line: the same error as the whole-file reader
    let p = write(dir.path(), "none.clf", "ODOM 0 0 0 0 0 0 1.0 h 1\n");
    let whole = read_carmen(&p, &options).unwrap_err().to_string();
    let stream = stream_scan_poses(&p, &options, |_| Ok(()))
        .unwrap_err()
        .to_string();
    assert_eq!(stream, whole);
}

#[test]
fn a_sink_error_stops_the_stream() {
    let dir = tempfile::tempdir().unwrap();
    let text = "FLASER 2 1 2 0 0 0 5 6 0.1 1.0 h 1\nFLASER 2 1 2 0 0 0 5 6 0.1 2.0 h 1\n";
    let p = write(dir.path(), "two.clf", text);
    let mut calls = 0;
    let e = stream_scan_poses(&p, &CarmenOptions::default(), |_| {
        calls += 1;
        Err(pfslam_io::IoError::parse(
            Path::new("out.tum"),
            1,
            "disk full",
        ))
    })
    .unwrap_err();
    assert_eq!(calls, 1);
    assert!(e.to_string().contains("disk full"), "{e}");
}

#[test]
fn real_logs_stream_as_they_read_whole() {
    let Some(root) = data_dir("real_logs_stream_as_they_read_whole") else {
        return;
    };
    let mut logs: Vec<_> = std::fs::read_dir(root.join("carmen"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    logs.push(root.join("freiburg/mit-csail/mit-csail.clf"));
    logs.sort();
    let mut streamed_logs = Vec::new();
    for p in logs.iter().filter(|p| p.is_file()) {
        if agrees_with_whole_read(p, &CarmenOptions::default()) {
            streamed_logs.push(p.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    eprintln!("streamed: {streamed_logs:?} of {} logs", logs.len());
    assert!(!streamed_logs.is_empty(), "no log at hand was streamed");
}
