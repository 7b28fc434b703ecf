//! Continuing a saved map with a new recording: localise, map on, close loops across
//! sessions, save the merged state.

use super::{SessionError, SessionState};
use crate::config::Config;
use crate::filter::FilterMode;
use crate::geometry::{Pose2, StampedPose2, Trajectory};
use crate::localize::localize;
use crate::map::{OccupancyGrid, map_with_poses};
use crate::motion::odometry_timing::{OdometryTimingReport, run_timed};
use crate::quality::Quality;
use crate::sensors::{LidarGeometry, Recording, ScanSet};
use crate::slam::{PriorMap, SlamEvent, run_rbpf_in};

/// What [`resume`] produced.
#[derive(Debug, Clone)]
pub struct ResumeResult {
    /// The new recording's trajectory in the saved map's frame, a pose per scan.
    pub trajectory: Vec<StampedPose2>,
    /// The filter's trajectory of the new recording (before the back end).
    pub front_end: Vec<StampedPose2>,
    /// The earlier sessions' keyframes at their poses after this run's back end (stamped
    /// with their own recordings' stamps).
    pub previous: Vec<StampedPose2>,
    /// The merged map: earlier keyframes and the new scans.
    pub map: OccupancyGrid,
    /// The stamp of the scan where the filter started, once localised.
    pub start_ns: i64,
    /// Scans before that, posed by the odometry from the start.
    pub scans_before_start: usize,
    /// The state with this session added.
    pub state: SessionState,
    /// The self-check.
    pub quality: Quality,
    /// The new recording's odometry timing, and the shift applied.
    pub odometry_timing: OdometryTimingReport,
}

/// Continues `state`'s map with `recording`: localises it in the map the saved keyframes
/// make (from `initial_pose` at the first scan, or globally, starting where the localisation
/// stays converged), runs the filter from there with that map in every particle, then the
/// back end over the saved keyframes and the new scans together. The odometry is shifted
/// as in [`crate::pipeline::run_pipeline`] (`[input] odometry_shift_s`, or the lag measured
/// on a first run when notable).
pub fn resume(
    state: &SessionState,
    recording: &Recording,
    config: &Config,
    seed: u64,
    initial_pose: Option<Pose2>,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<ResumeResult, SessionError> {
    check_supported(state, recording, config)?;
    let shift_s = config.input.odometry_shift_s;
    let once = |rec: &Recording, first: bool| match first {
        true => resume_once(state, rec, config, seed, initial_pose, &mut *observer),
        false => resume_once(state, rec, config, seed, initial_pose, &mut |_| {}),
    };
    let (result, odometry_timing) = run_timed(recording, shift_s, once, |r| &r.front_end)?;
    Ok(ResumeResult {
        odometry_timing,
        ..result
    })
}

/// [`resume`] with the odometry as it is in `recording`.
fn resume_once(
    state: &SessionState,
    recording: &Recording,
    config: &Config,
    seed: u64,
    initial_pose: Option<Pose2>,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<ResumeResult, SessionError> {
    let old = saved_recording(state, recording);
    let old_poses: Vec<Pose2> = state.keyframes.iter().map(|k| k.world_from_body).collect();
    let (world_from_odom, start_index) = place(&old, recording, config, seed, initial_pose)?;
    let mut new = recording.clone();
    let keep: Vec<usize> = (start_index..recording.scans.len()).collect();
    new.keep_scans(&keep);
    let prior = PriorMap {
        recording: &old,
        world_from_body: &old_poses,
        world_from_odom,
    };
    let filtered = run_rbpf_in(&new, config, seed, observer, Some(&prior))?;
    let front_end = filtered.trajectory.clone();
    let combined = combine(&old, &new, world_from_odom);
    let offset = old.scans.len();
    let mut input: Vec<StampedPose2> = old.odometry.poses.clone();
    input.extend_from_slice(&front_end);
    let chosen = crate::pipeline::back_end_over(&combined, config, &input, offset)?;
    let poses = chosen.trajectory.as_deref().unwrap_or(&input);
    let previous: Vec<StampedPose2> = state
        .keyframes
        .iter()
        .zip(poses)
        .map(|(k, p)| StampedPose2 {
            stamp_ns: k.stamp_ns,
            pose: p.pose,
        })
        .collect();
    let moved_old: Vec<Pose2> = poses[..offset].iter().map(|p| p.pose).collect();
    let mut trajectory = before_start(recording, start_index, poses.get(offset));
    trajectory.extend_from_slice(&poses[offset..]);
    let next =
        SessionState::after_session(Some((state, &moved_old)), recording, &trajectory, config);
    Ok(ResumeResult {
        trajectory,
        front_end,
        previous,
        map: chosen.grid,
        start_ns: recording.scans.stamps_ns[start_index],
        scans_before_start: start_index,
        state: next,
        quality: Quality::assess(chosen.signals),
        odometry_timing: OdometryTimingReport::default(),
    })
}

/// Sessions continue the Rao-Blackwellised filter of level LiDARs fixed on the body.
fn check_supported(
    state: &SessionState,
    recording: &Recording,
    config: &Config,
) -> Result<(), SessionError> {
    if state.keyframes.is_empty() {
        return Err(SessionError::Unsupported(
            "the saved state holds no keyframe to continue from".into(),
        ));
    }
    if config.filter.mode.resolve(recording) != FilterMode::Rbpf {
        return Err(SessionError::Unsupported(format!(
            "{}: continuing a session needs the `rbpf` filter (a level LiDAR fixed on the \
             body); this recording runs `{:?}`",
            recording.name,
            config.filter.mode.resolve(recording)
        )));
    }
    let saved = state.body_from_lidar();
    let mount = &recording.body_from_lidar;
    if (saved.translation - mount.translation).norm() > 1e-3
        || (saved.rotation - mount.rotation).norm() > 1e-3
    {
        return Err(SessionError::Unsupported(format!(
            "{}: the LiDAR mount differs from the saved session's",
            recording.name
        )));
    }
    if recording.odometry.is_empty() {
        return Err(SessionError::Unsupported(format!(
            "{}: no odometry to continue with",
            recording.name
        )));
    }
    Ok(())
}

/// The saved keyframes as a recording, stamped one second apart and ending one second
/// before `next`'s first scan; its odometry is the keyframes' poses.
pub(super) fn saved_recording(state: &SessionState, next: &Recording) -> Recording {
    let n = state.keyframes.len() as i64;
    let first_scan = next.scans.stamps_ns.first().copied().unwrap_or(0);
    let first_odometry = next
        .odometry
        .poses
        .first()
        .map_or(first_scan, |p| p.stamp_ns);
    let end = first_scan.min(first_odometry);
    let mut old = keyframe_scans(state, next.lidar, |k| end - (n - k as i64) * 1_000_000_000);
    let poses = (old.scans.stamps_ns.iter().zip(&state.keyframes))
        .map(|(&stamp_ns, kf)| StampedPose2 {
            stamp_ns,
            pose: kf.world_from_body,
        })
        .collect();
    old.name = "saved keyframes".into();
    old.odometry = Trajectory::new(poses);
    old
}

/// The scans of `state`'s keyframes, keyframe `k` stamped `stamp_of(k)`, with their beams
/// (per scan where they differ; `lidar` without keyframes) and the saved mount.
pub(super) fn keyframe_scans(
    state: &SessionState,
    lidar: LidarGeometry,
    stamp_of: impl Fn(usize) -> i64,
) -> Recording {
    let first = state.keyframes.first().map_or(lidar, |kf| kf.lidar);
    let mut scans = ScanSet::new(first.beam_count);
    let mut geometry: Vec<LidarGeometry> = Vec::with_capacity(state.keyframes.len());
    for (k, kf) in state.keyframes.iter().enumerate() {
        scans.push_any(stamp_of(k), &kf.ranges_m);
        geometry.push(kf.lidar);
    }
    let varies = geometry.iter().any(|g| *g != first);
    Recording {
        scans,
        lidar: first,
        body_from_lidar: state.body_from_lidar(),
        lidar_per_scan: varies.then_some(geometry),
        ..Recording::default()
    }
}

/// Where the new recording's odometry frame lies in the map, and the scan the filter starts
/// at: the first scan with `initial_pose`, else the first update from which the global
/// localisation stayed converged.
fn place(
    old: &Recording,
    recording: &Recording,
    config: &Config,
    seed: u64,
    initial_pose: Option<Pose2>,
) -> Result<(Pose2, usize), SessionError> {
    let scans = &recording.scans;
    let first = (0..scans.len())
        .find(|&i| recording.odometry.pose_at(scans.stamps_ns[i]).is_some())
        .ok_or_else(|| {
            SessionError::NotLocalised(format!(
                "{}: no scan lies within the odometry's time span",
                recording.name
            ))
        })?;
    let odom_at = |i: usize| recording.odometry.pose_at(scans.stamps_ns[i]);
    if let (Some(p), Some(o)) = (initial_pose, odom_at(first)) {
        return Ok((p.compose(&o.inverse()), first));
    }
    let (grid, _, _) = map_with_poses(old, &old.odometry, &config.map)?;
    let map = grid.to_binary_map(None);
    let found = localize(
        recording,
        &map,
        &config.localize,
        &config.map.scan,
        None,
        seed,
    )?;
    let not_found = || {
        SessionError::NotLocalised(format!(
            "{}: the localisation in the saved map did not converge; give the start pose \
             (--initial-pose)",
            recording.name
        ))
    };
    let from_ns = settled_from_ns(&found.updates).ok_or_else(not_found)?;
    let index = scans.stamps_ns.partition_point(|&s| s < from_ns);
    let world = found
        .trajectory
        .iter()
        .find(|p| p.stamp_ns == from_ns)
        .ok_or_else(not_found)?;
    let odom = odom_at(index).ok_or_else(not_found)?;
    Ok((world.pose.compose(&odom.inverse()), index))
}

/// Consecutive converged updates that make a start trustworthy.
const SETTLED_UPDATES: usize = 10;

/// The first update that begins [`SETTLED_UPDATES`] converged ones (fewer if the recording
/// ends first, but at least one).
fn settled_from_ns(updates: &[crate::localize::UpdateRecord]) -> Option<i64> {
    let mut run = 0;
    for (k, u) in updates.iter().enumerate() {
        run = if u.converged { run + 1 } else { 0 };
        if run == SETTLED_UPDATES || (run > 0 && k + 1 == updates.len()) {
            return Some(updates[k + 1 - run].stamp_ns);
        }
    }
    None
}

/// The saved keyframes followed by `new`'s scans, its odometry moved into the map frame.
pub(super) fn combine(old: &Recording, new: &Recording, world_from_odom: Pose2) -> Recording {
    let mut scans = old.scans.clone();
    let n_new = new.scans.len();
    for i in 0..n_new {
        scans.push_any(new.scans.stamps_ns[i], new.scans.ranges(i));
    }
    let mut odometry = old.odometry.poses.clone();
    odometry.extend(new.odometry.poses.iter().map(|p| StampedPose2 {
        stamp_ns: p.stamp_ns,
        pose: world_from_odom.compose(&p.pose),
    }));
    let geometry: Vec<LidarGeometry> = (0..old.scans.len())
        .map(|i| *old.lidar_at(i))
        .chain((0..n_new).map(|i| *new.lidar_at(i)))
        .collect();
    let varies = geometry.iter().any(|g| g != &geometry[0]);
    Recording {
        name: new.name.clone(),
        odometry: Trajectory::new(odometry),
        scans,
        lidar: geometry[0],
        body_from_lidar: new.body_from_lidar,
        lidar_per_scan: varies.then_some(geometry),
        ..Recording::default()
    }
}

/// Poses of the scans before `start` (not filtered: the localisation had not converged),
/// from the odometry relative to the first filtered pose.
fn before_start(
    recording: &Recording,
    start: usize,
    first: Option<&StampedPose2>,
) -> Vec<StampedPose2> {
    let scans = &recording.scans;
    let (Some(first), Some(odom_start)) =
        (first, recording.odometry.pose_at(scans.stamps_ns[start]))
    else {
        return Vec::new();
    };
    let world_from_odom = first.pose.compose(&odom_start.inverse());
    (0..start)
        .filter_map(|i| {
            let o = recording.odometry.pose_at(scans.stamps_ns[i])?;
            Some(StampedPose2 {
                stamp_ns: scans.stamps_ns[i],
                pose: world_from_odom.compose(&o),
            })
        })
        .collect()
}
