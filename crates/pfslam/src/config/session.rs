//! Options of saved sessions (`[session]` in the configuration): which scans a session keeps
//! as keyframes, and how often a long run is consolidated to them. The sessions themselves (state files, resuming) are in [`crate::session`];
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
    /// A run of the `rbpf` filter is consolidated every this many scans: the back end
    /// places them with the keyframes kept so far, and only keyframes stay (0: never).
    /// Memory then follows the mapped area, not the run's length.
    pub consolidate_every_scans: usize,
}

impl Default for SessionOptions {
    fn default() -> Self {
        SessionOptions {
            keyframe_distance_m: 0.3,
            keyframe_angle_deg: 10.0,
            prune_radius_m: 0.3,
            prune_angle_deg: 20.0,
            consolidate_every_scans: DEFAULT_CONSOLIDATE_EVERY_SCANS,
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
        let every = self.consolidate_every_scans;
        if every != 0 && every < MIN_CONSOLIDATE_EVERY_SCANS {
            return Err(format!(
                "consolidate_every_scans must be 0 (never) or at least \
                 {MIN_CONSOLIDATE_EVERY_SCANS}, got {every}"
            ));
        }
        Ok(())
    }
}

/// The default window: over half an hour of a 10 Hz LiDAR runs as one.
pub const DEFAULT_CONSOLIDATE_EVERY_SCANS: usize = 20_000;

/// The shortest window: the back end needs a stretch long enough to match along.
pub const MIN_CONSOLIDATE_EVERY_SCANS: usize = 100;
