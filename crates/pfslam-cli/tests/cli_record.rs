//! `run --record FILE`: an MCAP file of Foxglove schemas, read back with the `mcap` crate
//! (the reader Foxglove maintains).

use super::{pfslam, run_ok};
use std::collections::BTreeMap;
use std::path::Path;

/// Messages per topic, each topic's schema, and the messages of `topic` parsed.
fn read_back(
    path: &Path,
    topic: &str,
) -> (BTreeMap<String, (String, usize)>, Vec<serde_json::Value>) {
    let bytes = std::fs::read(path).unwrap();
    let mut topics: BTreeMap<String, (String, usize)> = BTreeMap::new();
    let mut parsed = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(
            (
                schema.encoding.as_str(),
                m.channel.message_encoding.as_str()
            ),
            ("jsonschema", "json")
        );
        let e = topics
            .entry(m.channel.topic.clone())
            .or_insert((schema.name.clone(), 0));
        e.1 += 1;
        if m.channel.topic == topic {
            parsed.push(serde_json::from_slice(&m.data).unwrap());
        }
    }
    (topics, parsed)
}

#[test]
fn a_simulated_run_is_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let (data, cfg) = super::short_simulated_drive(dir.path());
    let record = dir.path().join("run.mcap");
    let out = dir.path().join("out");
    run_ok(
        pfslam()
            .arg("run")
            .arg(&data)
            .args(["--particles", "5", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out)
            .arg("--record")
            .arg(&record),
    );
    let (topics, scans) = read_back(&record, "/scan");
    let count = |t: &str| topics.get(t).map_or(0, |(_, n)| *n);
    let traj = pfslam_io::tum::read_tum(&out.join("trajectory.tum")).unwrap();
    assert_eq!(count("/scan"), traj.len(), "{topics:?}");
    assert!(
        count("/map") >= 2 && count("/particles") >= 10,
        "{topics:?}"
    );
    assert_eq!(
        (
            count("/trajectory"),
            count("/front_end"),
            count("/loop_closures")
        ),
        (1, 1, 1)
    );
    assert_eq!(topics["/map"].0, "foxglove.Grid");
    assert_eq!(topics["/scan"].0, "foxglove.LaserScan");
    // the scans are stamped and placed as the trajectory says
    let last = &scans[scans.len() - 1];
    let p = traj.poses.last().unwrap();
    let t = last["timestamp"]["sec"].as_i64().unwrap() * 1_000_000_000
        + last["timestamp"]["nsec"].as_i64().unwrap();
    assert_eq!(t, p.stamp_ns);
    assert!(last["ranges"].as_array().unwrap().len() > 100);
    // no temporary file left beside the record
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(left.len(), 4, "{left:?}");
}

#[test]
fn a_record_where_nothing_can_be_written_fails_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let o = pfslam()
        .args(["run", "no-such-recording.clf", "--out"])
        .arg(dir.path().join("out"))
        .arg("--record")
        .arg(dir.path().join("missing/run.mcap"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--record") && err.contains("missing"), "{err}");
}

#[test]
fn a_real_log_is_recorded_with_its_loop_closures() {
    let Some(data) = super::data_dir("a_real_log_is_recorded_with_its_loop_closures") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let record = dir.path().join("seattle.mcap");
    run_ok(
        pfslam()
            .arg("run")
            .arg(data.join("carmen/seattle-corrected.log.gz"))
            .arg("--out")
            .arg(dir.path().join("out"))
            .arg("--record")
            .arg(&record),
    );
    let (topics, closures) = read_back(&record, "/loop_closures");
    let lines = &closures[0]["entities"][0]["lines"][0];
    assert_eq!(lines["type"], 2);
    let points = lines["points"].as_array().unwrap().len();
    assert!(points >= 2 && points % 2 == 0, "{points}");
    // the rbpf filter hands its map over at updates: several maps over the drive
    assert!(topics["/map"].1 >= 5, "{topics:?}");
}
