//! Motion (placeholder: see ARCHITECTURE.md).

pub mod odometry_model;

use serde::{Deserialize, Serialize};

/// Options of the motion component (`[motion]` in the configuration).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotionOptions {}
