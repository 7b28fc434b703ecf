//! The saved state of a mapping session and its file format.
//!
//! A state file is the 8-byte magic `PFSLAMST`, a little-endian `u32` format version, then
//! the [`SessionState`] encoded with postcard (serde's compact binary form: varint integers,
//! little-endian floats, length-prefixed sequences and strings, fields in declaration order).
//! A reader refuses another magic or version with an error naming both.

use super::SessionError;
use crate::geometry::{Pose2, Rigid3};
use crate::sensors::LidarGeometry;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The first bytes of every state file.
pub const MAGIC: &[u8; 8] = b"PFSLAMST";

/// The format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;

/// One keyframe: a scan and its pose in the map frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SavedKeyframe {
    /// The session that recorded it (index into [`SessionState::sessions`]).
    pub session: u32,
    /// The scan's stamp in its own recording (ns).
    pub stamp_ns: i64,
    /// The body's pose in the map frame.
    pub world_from_body: Pose2,
    /// The scan's ranges (m; 0 or non-finite = no return).
    pub ranges_m: Vec<f32>,
    /// The scan's beam geometry.
    pub lidar: LidarGeometry,
}

/// One session that contributed keyframes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    /// The recording's name.
    pub recording: String,
    /// Scans the session processed.
    pub scans: usize,
    /// The body's pose at the session's last scan, in the map frame (where a robot that
    /// stopped there starts the next session).
    pub end_pose: Pose2,
}

/// What a later session needs: the sensor mount, the configuration, and the keyframes with
/// their scans. The map and the pose graph are rebuilt from the keyframes on resume, at the
/// resolution the resuming run is configured with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionState {
    /// The sessions, oldest first.
    pub sessions: Vec<SessionInfo>,
    /// The LiDAR mount in the body frame: rotation (row-major) and translation (m).
    pub body_from_lidar: ([f64; 9], [f64; 3]),
    /// The configuration of the last session, as TOML.
    pub config_toml: String,
    /// The keyframes, session after session, in recording order within each.
    pub keyframes: Vec<SavedKeyframe>,
}

impl SessionState {
    /// The LiDAR mount.
    pub fn body_from_lidar(&self) -> Rigid3 {
        Rigid3::from_row_major(self.body_from_lidar.0, self.body_from_lidar.1)
    }

    /// Encodes the state with its magic and version.
    pub fn to_bytes(&self) -> Result<Vec<u8>, SessionError> {
        let mut out = Vec::with_capacity(16 + self.keyframes.len() * 2048);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        postcard::to_io(self, &mut out).map_err(|e| SessionError::Encode(e.to_string()))?;
        Ok(out)
    }

    /// Decodes a state written by [`SessionState::to_bytes`]; `name` is used in errors.
    pub fn from_bytes(bytes: &[u8], name: &str) -> Result<SessionState, SessionError> {
        let bad = |message: String| SessionError::Format {
            path: name.to_string(),
            message,
        };
        if bytes.len() < 12 || &bytes[..8] != MAGIC {
            return Err(bad(
                "not a pfslam state file (it does not start with `PFSLAMST`)".into(),
            ));
        }
        let mut version = [0u8; 4];
        version.copy_from_slice(&bytes[8..12]);
        let version = u32::from_le_bytes(version);
        if version != FORMAT_VERSION {
            return Err(bad(format!(
                "format version {version}; this build reads version {FORMAT_VERSION}"
            )));
        }
        let state: SessionState = postcard::from_bytes(&bytes[12..])
            .map_err(|e| bad(format!("corrupt after byte 12: {e}")))?;
        state.check().map_err(bad)?;
        Ok(state)
    }

    /// Reads a state file.
    pub fn read(path: &Path) -> Result<SessionState, SessionError> {
        let bytes = std::fs::read(path).map_err(|source| SessionError::Io {
            path: path.display().to_string(),
            source,
        })?;
        SessionState::from_bytes(&bytes, &path.display().to_string())
    }

    /// Internal consistency: session indices in range, beam counts matching the geometry.
    fn check(&self) -> Result<(), String> {
        for (k, kf) in self.keyframes.iter().enumerate() {
            if kf.session as usize >= self.sessions.len() {
                return Err(format!(
                    "keyframe {k} names session {} of {}",
                    kf.session,
                    self.sessions.len()
                ));
            }
            if kf.ranges_m.len() != kf.lidar.beam_count {
                return Err(format!(
                    "keyframe {k} holds {} ranges for a {}-beam scanner",
                    kf.ranges_m.len(),
                    kf.lidar.beam_count
                ));
            }
            let p = &kf.world_from_body;
            if !(p.x_m.is_finite() && p.y_m.is_finite() && p.yaw_rad.is_finite()) {
                return Err(format!("keyframe {k} has a non-finite pose"));
            }
        }
        Ok(())
    }
}
