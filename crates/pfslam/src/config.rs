//! The resolved configuration: one options struct per component, one TOML section each.

use serde::{Deserialize, Serialize};

/// Every component's options. Missing sections and keys take their defaults; unknown keys
/// are errors.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Motion models and their noise (`[motion]`).
    pub motion: crate::motion::MotionOptions,
    /// Occupancy grid (`[map]`).
    pub map: crate::map::MapOptions,
    /// Particle filter (`[filter]`).
    pub filter: crate::filter::FilterOptions,
    /// Simulator (`[sim]`).
    pub sim: crate::sim::SimOptions,
    /// Stereo texture mapping (`[stereo]`).
    pub stereo: crate::stereo::StereoOptions,
}

/// Errors of loading a configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Read {
        /// The file.
        path: std::path::PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The TOML is malformed or has unknown keys.
    #[error("{path}: {message}")]
    Toml {
        /// The file.
        path: std::path::PathBuf,
        /// The parser's message (with line and column).
        message: String,
    },
}

impl Config {
    /// Loads a TOML file over the defaults.
    pub fn from_toml_file(path: &std::path::Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        toml::from_str(&text).map_err(|e| ConfigError::Toml {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }

    /// The configuration as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot serialise: {e}\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_roundtrips_through_toml() {
        let c = Config::default();
        let back: Config = toml::from_str(&c.to_toml()).unwrap();
        assert_eq!(c, back);
    }

    #[test]
    fn unknown_key_is_an_error() {
        assert!(toml::from_str::<Config>("nonsense = 1").is_err());
    }
}
