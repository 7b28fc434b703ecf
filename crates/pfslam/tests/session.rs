//! Mapping continued across sessions on real recordings: a Freiburg bag split in two, the
//! second half resumed from the first's saved state, scored like one run over the whole;
//! and a recording driven twice, whose saved map may not grow much the second time.

use pfslam::config::Config;
use pfslam::eval::relations::{RelationsOptions, evaluate_relations};
use pfslam::geometry::{StampedPose2, Trajectory};
use pfslam::pipeline::{PipelineOptions, run_pipeline};
use pfslam::sensors::Recording;
use pfslam::session::{SessionState, resume};
use pfslam_io::recording::{ReaderOptions, read_recording};
use pfslam_io::relations::read_relations;
use std::path::PathBuf;

fn bag(test: &str, name: &str) -> Option<PathBuf> {
    Some(crate::common::data_dir(test)?.join("freiburg").join(name))
}

fn read_span(
    dir: &std::path::Path,
    name: &str,
    start_s: Option<f64>,
    end_s: Option<f64>,
) -> Recording {
    let options = ReaderOptions {
        start_s,
        end_s,
        ..ReaderOptions::default()
    };
    read_recording(&dir.join(format!("{name}.bag")), &options).unwrap()
}

/// The first session: the default pipeline, its state saved through the file format.
fn first_session(rec: &Recording, config: &Config) -> (Vec<StampedPose2>, SessionState) {
    let out = run_pipeline(rec, config, 1, &PipelineOptions::default(), &mut |_| {}).unwrap();
    let trajectory = out.result.trajectory;
    let state = SessionState::after_session(None, rec, &trajectory, config);
    let bytes = state.to_bytes().unwrap();
    (
        trajectory,
        SessionState::from_bytes(&bytes, "state").unwrap(),
    )
}

fn relations_m(dir: &std::path::Path, name: &str, poses: Vec<StampedPose2>) -> f64 {
    let relations = read_relations(&dir.join(format!("{name}.relations"))).unwrap();
    let r = evaluate_relations(
        &Trajectory::new(poses),
        &relations,
        &RelationsOptions::default(),
    )
    .unwrap();
    r.trans_m.abs.mean
}

/// `name` split at `split_s`: the first half's state saved, the second half resumed from it
/// (at `start`, or placed by global localisation); the relations error of both together.
fn two_sessions(
    dir: &std::path::Path,
    name: &str,
    split_s: f64,
    start_at_last: bool,
) -> (f64, usize) {
    let config = Config::default();
    let first = read_span(dir, name, None, Some(split_s));
    let (mut poses, state) = first_session(&first, &config);
    let second = read_span(dir, name, Some(split_s), None);
    let start = start_at_last
        .then(|| state.sessions.last().map(|s| s.end_pose))
        .flatten();
    let r = resume(&state, &second, &config, 1, start, &mut |_| {}).unwrap();
    assert_eq!(r.state.sessions.len(), 2);
    poses.extend_from_slice(&r.trajectory);
    poses.sort_by_key(|p| p.stamp_ns);
    let e = relations_m(dir, name, poses);
    eprintln!("{name} in two sessions: {e:.4} m");
    (e, r.scans_before_start)
}

/// Intel split at 1,350 s; the second half placed by global localisation in the first's map.
/// One run over the whole bag scores 0.0208 m (`docs/benchmarks.md`); the two sessions
/// together must stay within 1.5x of that (measured 0.0239 m).
#[test]
fn a_recording_split_in_two_sessions_scores_like_one_run() {
    let Some(dir) = bag("session_split_intel", "intel") else {
        return;
    };
    let (e, before) = two_sessions(&dir, "intel", 1350.0, false);
    assert!(before < 100, "placed late: {before} scans");
    assert!(e <= 1.5 * 0.0208, "{e:.4} m");
}

/// ACES split at 680 s: global localisation can pick the building's symmetric twin, so the
/// second session starts where the first ended (`--initial-pose last`; measured 0.0377 m
/// against 0.0358 m for one run).
#[test]
fn a_session_starts_where_the_last_one_ended() {
    let Some(dir) = bag("session_split_aces", "aces") else {
        return;
    };
    let (e, before) = two_sessions(&dir, "aces", 680.0, true);
    assert_eq!(before, 0);
    assert!(e <= 1.5 * 0.0358, "{e:.4} m");
}

/// `name`'s first `end_s` seconds driven again as a second session (seed 1), once the
/// state after two passes is found to hold at most 1.3x the keyframes of one: the first
/// pass's trajectory and the second's.
struct DrivenTwice {
    first: Vec<StampedPose2>,
    second: Vec<StampedPose2>,
}

fn driven_twice(dir: &std::path::Path, name: &str, end_s: f64) -> DrivenTwice {
    let config = Config::default();
    let span = read_span(dir, name, None, Some(end_s));
    let (first, state) = first_session(&span, &config);
    let r = resume(&state, &span, &config, 1, None, &mut |_| {}).unwrap();
    let (once, twice) = (state.keyframes.len(), r.state.keyframes.len());
    eprintln!("{name}, first {end_s} s: {once} keyframes after one pass, {twice} after two");
    assert!(twice as f64 <= 1.3 * once as f64, "{once} -> {twice}");
    DrivenTwice {
        first,
        second: r.trajectory,
    }
}

/// The Intel bag's first half driven again as a second session: at most 1.3x the keyframes
/// of one pass (measured 726 -> 732), and the second pass, in the known map, no worse.
#[test]
fn a_place_driven_twice_keeps_the_map_of_one_pass() {
    let Some(dir) = bag("session_twice_intel", "intel") else {
        return;
    };
    let run = driven_twice(&dir, "intel", 1350.0);
    let (e1, e2) = (
        relations_m(&dir, "intel", run.first),
        relations_m(&dir, "intel", run.second),
    );
    eprintln!("intel half: {e1:.4} m, driven again {e2:.4} m");
    assert!(e2 <= e1 * 1.1, "{e1:.4} -> {e2:.4} m");
}

/// MIT-CSAIL's first 210 s driven again: where the robot weaves, the second session's back
/// end bends (its own sequential matches) and would map a second copy of the corridors (789
/// keyframes after 440); the guard refuses that back end and the map stays within 1.3x of one
/// pass (measured 544; the 1.3x is asserted by `driven_twice`).
#[test]
fn a_bent_back_end_does_not_double_the_map_of_a_place_driven_twice() {
    let Some(dir) = bag("session_twice_mit_csail", "mit-csail") else {
        return;
    };
    driven_twice(&dir, "mit-csail", 210.0);
}
