//! Mapping continued across sessions: a run saves its keyframes (scans and poses in the map
//! frame) to a state file; a later run on another recording localises in the map those
//! keyframes make, maps on from there, closes loops between old and new keyframes, and saves
//! the merged state.

mod keyframes;
mod resume;
mod rolling;
mod state;
#[cfg(test)]
mod tests;

pub use keyframes::{KeyframeIndex, select_keyframes};
pub use resume::{ResumeResult, resume};
pub(crate) use rolling::Rolling;
pub use state::{FORMAT_VERSION, MAGIC, SavedKeyframe, SessionInfo, SessionState};

pub use crate::config::session::SessionOptions;
use crate::geometry::{Pose2, StampedPose2};
use crate::sensors::Recording;

/// Errors of saving, reading and resuming sessions.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The state file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The file is not a state this build reads.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// Encoding the state failed.
    #[error("cannot encode the session state: {0}")]
    Encode(String),
    /// The recordings cannot be combined or continued.
    #[error("{0}")]
    Unsupported(String),
    /// The new recording could not be placed in the saved map.
    #[error("{0}")]
    NotLocalised(String),
    /// A stage failed.
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    /// Localisation failed.
    #[error(transparent)]
    Localize(#[from] crate::localize::LocalizeError),
    /// Mapping failed.
    #[error(transparent)]
    Map(#[from] crate::map::MapError),
    /// The filter failed.
    #[error(transparent)]
    Slam(#[from] crate::slam::SlamError),
}

impl SessionState {
    /// The state after a session: `previous`'s keyframes (at `previous_poses` when the run
    /// moved them, else where they were) and the keyframes [`select_keyframes`] picks from
    /// `trajectory` (a pose per scan of `recording`, matched by stamp).
    pub fn after_session(
        previous: Option<(&SessionState, &[Pose2])>,
        recording: &Recording,
        trajectory: &[StampedPose2],
        config: &crate::config::Config,
    ) -> SessionState {
        let mut state = match previous {
            Some((s, poses)) => {
                let mut s = s.clone();
                for (kf, p) in s.keyframes.iter_mut().zip(poses) {
                    kf.world_from_body = *p;
                }
                s
            }
            None => SessionState {
                sessions: Vec::new(),
                body_from_lidar: (
                    recording.body_from_lidar.rotation_row_major(),
                    recording.body_from_lidar.translation.into(),
                ),
                config_toml: String::new(),
                keyframes: Vec::new(),
            },
        };
        state.config_toml = config.to_toml();
        let session = state.sessions.len() as u32;
        state.sessions.push(SessionInfo {
            recording: recording.name.clone(),
            scans: recording.scans.len(),
            end_pose: trajectory.last().map_or(Pose2::IDENTITY, |p| p.pose),
        });
        let mut index = KeyframeIndex::new(&config.session);
        for kf in &state.keyframes {
            index.insert(kf.world_from_body);
        }
        let scan_of = scans_by_stamp(recording, trajectory);
        let poses: Vec<Pose2> = trajectory.iter().map(|p| p.pose).collect();
        for k in select_keyframes(&poses, &config.session, &mut index) {
            let Some(i) = scan_of[k] else { continue };
            state.keyframes.push(SavedKeyframe {
                session,
                stamp_ns: trajectory[k].stamp_ns,
                world_from_body: poses[k],
                ranges_m: recording.scans.ranges(i).to_vec(),
                lidar: *recording.lidar_at(i),
            });
        }
        state
    }
}

/// For each trajectory pose, the scan with its stamp (both in time order).
fn scans_by_stamp(recording: &Recording, trajectory: &[StampedPose2]) -> Vec<Option<usize>> {
    let stamps = &recording.scans.stamps_ns;
    let mut i = 0;
    trajectory
        .iter()
        .map(|p| {
            while i < stamps.len() && stamps[i] < p.stamp_ns {
                i += 1;
            }
            (i < stamps.len() && stamps[i] == p.stamp_ns).then_some(i)
        })
        .collect()
}
