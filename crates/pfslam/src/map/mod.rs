//! The occupancy grid (placeholder: see ARCHITECTURE.md).

/// World <-> cell conversion (placeholder).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapLimits;

use serde::{Deserialize, Serialize};

/// Options of the map component (`[map]` in the configuration).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapOptions {}
