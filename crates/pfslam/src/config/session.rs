//! Options of saved sessions (`[session]` in the configuration): which scans a session keeps
//! as keyframes. The sessions themselves (state files, resuming) are in [`crate::session`];
//! the options live here so [`crate::Config`] holds them without depending on that module.

use serde::{Deserialize, Serialize};

/// Options of saved sessions (`[session]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SessionOptions {
    /// A scan becomes a keyframe once the body moved this far since the last one (m)...
    pub keyframe_distance_m: f64,
    /// ... or turned this much (deg).
    pub keyframe_angle_deg: f64,
    /// Unless a keyframe already lies within this distance (m) ...
    pub prune_radius_m: f64,
    /// ... and this heading difference (deg): the map holds that view already, so driving a
    /// mapped place again adds no keyframes.
    pub prune_angle_deg: f64,
}

impl Default for SessionOptions {
    fn default() -> Self {
        SessionOptions {
            keyframe_distance_m: 0.3,
            keyframe_angle_deg: 10.0,
            prune_radius_m: 0.3,
            prune_angle_deg: 20.0,
        }
    }
}

impl SessionOptions {
    /// Checks every value.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("keyframe_distance_m", self.keyframe_distance_m),
            ("keyframe_angle_deg", self.keyframe_angle_deg),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{key} must be positive, got {v}"));
            }
        }
        let non_negative = [
            ("prune_radius_m", self.prune_radius_m),
            ("prune_angle_deg", self.prune_angle_deg),
        ];
        for (key, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{key} must be >= 0, got {v}"));
            }
        }
        Ok(())
    }
}
