//! A long run consolidated window by window, so that its memory follows the mapped area
//! rather than its length: every `[session] consolidate_every_scans` scans the filter hands
//! over its window ([`crate::slam::Window`]), the back end places it together with the
//! keyframes kept so far (closing loops between them, as a resumed session does), and only
//! the keyframes the sessions' rule keeps stay; the window's scans are then let go.

use super::{SessionState, resume};
use crate::config::Config;
use crate::geometry::{Pose2, StampedPose2};
use crate::pipeline::{
    BackEndInput, Chosen, OdometryTimingReport, PipelineError, PipelineResult, back_end_over,
};
use crate::quality::Quality;
use crate::sensors::Recording;
use crate::slam::{SlamResult, Window};
use std::time::Instant;

/// The consolidated part of a run: its keyframes and the final poses of its scans.
#[derive(Debug, Default)]
pub(crate) struct Rolling {
    /// The keyframes kept so far, at their latest poses.
    state: Option<SessionState>,
    /// Takes the front end's later poses into the consolidated frame (the correction of
    /// the last consolidated pose).
    world_from_front: Pose2,
    /// The final pose of every consolidated scan.
    pub(crate) trajectory: Vec<StampedPose2>,
    /// The front end's pose of every consolidated scan.
    pub(crate) front_end: Vec<StampedPose2>,
    /// The odometry's pose of every consolidated scan.
    pub(crate) dead_reckoning: Vec<StampedPose2>,
    /// The ends of every window's loop closures, at their poses then.
    pub(crate) loop_closures: Vec<(Pose2, Pose2)>,
    /// Windows consolidated.
    pub(crate) windows: usize,
    /// Wall seconds spent consolidating.
    pub(crate) back_end_s: f64,
}

impl Rolling {
    /// Places `window` (its scans in `scans`) with the keyframes kept so far: the back end
    /// over both (the kept keyframes may move), its poses appended to the consolidated
    /// trajectory, and the keyframes the sessions' rule keeps. Returns the back end's choice
    /// (its map holds the kept keyframes and the window's scans).
    pub(crate) fn add_window(
        &mut self,
        scans: Recording,
        window: Window,
        config: &Config,
    ) -> Result<Chosen, PipelineError> {
        let t = Instant::now();
        let placed: Vec<StampedPose2> = window
            .trajectory
            .iter()
            .map(|p| StampedPose2 {
                stamp_ns: p.stamp_ns,
                pose: self.world_from_front.compose(&p.pose),
            })
            .collect();
        // The window's scans go into the back end's recording and are let go there.
        let (recording, input, offset) = match &self.state {
            None => (scans, placed, 0),
            Some(state) => {
                let old = resume::saved_recording(state, &scans);
                let world_from_odom = placed
                    .first()
                    .and_then(|p| {
                        Some(
                            p.pose
                                .compose(&scans.odometry.pose_at(p.stamp_ns)?.inverse()),
                        )
                    })
                    .unwrap_or(Pose2::IDENTITY);
                let combined = resume::combine(&old, &scans, world_from_odom);
                drop(scans);
                let mut input = old.odometry.poses.clone();
                input.extend_from_slice(&placed);
                (combined, input, old.scans.len())
            }
        };
        let chosen = back_end_over(&recording, config, &input, offset)?;
        let poses = chosen.trajectory.as_deref().unwrap_or(&input);
        let moved_old: Vec<Pose2> = poses[..offset].iter().map(|p| p.pose).collect();
        let corrected = &poses[offset..];
        let previous = self.state.as_ref().map(|s| (s, moved_old.as_slice()));
        let next = SessionState::after_session(previous, &recording, corrected, config);
        if let (Some(c), Some(f)) = (corrected.last(), window.trajectory.last()) {
            self.world_from_front = c.pose.compose(&f.pose.inverse());
        }
        // Grown a window at a time, without a doubling's spare capacity: these are what a
        // long run's memory still grows by.
        self.trajectory.reserve_exact(corrected.len());
        self.front_end.reserve_exact(window.trajectory.len());
        self.dead_reckoning
            .reserve_exact(window.dead_reckoning.len());
        self.trajectory.extend_from_slice(corrected);
        self.front_end.extend_from_slice(&window.trajectory);
        self.dead_reckoning
            .extend_from_slice(&window.dead_reckoning);
        self.loop_closures.extend_from_slice(&chosen.loop_closures);
        self.state = Some(next);
        self.windows += 1;
        self.back_end_s += t.elapsed().as_secs_f64();
        Ok(chosen)
    }

    /// How many keyframes are kept.
    pub(crate) fn keyframes(&self) -> usize {
        self.state.as_ref().map_or(0, |s| s.keyframes.len())
    }

    /// The run's result once the filter's `last` window (its scans in `scans`) is
    /// consolidated too: every scan's pose, the map of the kept keyframes and the last
    /// window's scans, and a recording of the keyframes kept (what the run holds then).
    /// The filter took `filter_s` wall seconds.
    pub(crate) fn finish(
        mut self,
        scans: Recording,
        last: SlamResult,
        filter_s: f64,
        config: &Config,
    ) -> Result<(PipelineResult, Recording), PipelineError> {
        let SlamResult {
            trajectory,
            dead_reckoning,
            stats,
            ..
        } = last;
        let window = Window {
            trajectory,
            dead_reckoning,
        };
        // What the returned recording keeps of the last window's.
        let sensors = Recording {
            name: scans.name.clone(),
            lidar: scans.lidar,
            body_from_lidar: scans.body_from_lidar,
            ground_truth: scans.ground_truth.clone(),
            ..Recording::default()
        };
        let chosen = self.add_window(scans, window, config)?;
        let kept = match &self.state {
            Some(state) => Recording {
                name: sensors.name,
                ground_truth: sensors.ground_truth,
                ..resume::keyframe_scans(state, sensors.lidar, |k| state.keyframes[k].stamp_ns)
            },
            None => sensors,
        };
        let odometry_timing = OdometryTimingReport {
            shift_s: config.input.odometry_shift_s.unwrap_or(0.0),
            ..OdometryTimingReport::default()
        };
        let result = PipelineResult {
            result: SlamResult {
                trajectory: self.trajectory,
                dead_reckoning: self.dead_reckoning,
                map: chosen.grid,
                stats,
            },
            front_end: self.front_end,
            graph: config.graph.enabled.then_some(chosen.stats),
            back_end_input: Some(BackEndInput::FrontEnd),
            calibration: None,
            odometry_timing,
            filter_s: (filter_s - self.back_end_s).max(0.0),
            back_end_s: self.back_end_s,
            filter_cpu_s: None,
            back_end_cpu_s: None,
            rebuild_s: 0.0,
            rebuild_cpu_s: None,
            quality: Quality::assess(chosen.signals),
            loop_closures: self.loop_closures,
        };
        Ok((result, kept))
    }
}
