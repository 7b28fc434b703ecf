//! Filter (placeholder: see ARCHITECTURE.md).

use serde::{Deserialize, Serialize};

/// Options of the filter component (`[filter]` in the configuration).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FilterOptions {}
