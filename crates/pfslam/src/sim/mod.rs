//! Sim (placeholder: see ARCHITECTURE.md).

use serde::{Deserialize, Serialize};

/// Options of the sim component (`[sim]` in the configuration).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimOptions {}
