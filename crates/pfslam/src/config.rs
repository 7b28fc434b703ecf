//! The resolved configuration: one options struct per component, one TOML section each.

pub mod session;
pub mod sim;
pub mod stereo;

use serde::{Deserialize, Serialize};

/// Every component's options. Missing sections and keys take their defaults; unknown keys
/// are errors.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Recording readers: topics, frames, beam geometry, strictness, span (`[input]`).
    pub input: crate::sensors::reader_options::ReaderOptions,
    /// Motion models and their noise (`[motion]`).
    pub motion: crate::motion::MotionOptions,
    /// Occupancy grid (`[map]`).
    pub map: crate::map::MapOptions,
    /// Particle filter (`[filter]`).
    pub filter: crate::filter::FilterOptions,
    /// Simulator (`[sim]`).
    pub sim: sim::SimOptions,
    /// Stereo texture mapping (`[stereo]`).
    pub stereo: stereo::StereoOptions,
    /// Pose-graph back end: loop closure after the filter (`[graph]`).
    pub graph: crate::graph::GraphOptions,
    /// Monte Carlo localisation in a fixed map (`[localize]`, `pfslam localize`).
    pub localize: crate::localize::LocalizeOptions,
    /// Saved sessions: which scans are kept as keyframes (`[session]`, `--save-state`).
    pub session: session::SessionOptions,
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

/// A configuration value out of range, found by [`Config::validate`] before any work.
#[derive(Debug, thiserror::Error)]
#[error("configuration [{section}]: {message}")]
pub struct OptionError {
    /// The section (`input`, `motion`, `map`, `filter`, `graph`, `sim`).
    pub section: &'static str,
    /// What is wrong, naming the key.
    pub message: String,
}

impl Config {
    /// Checks every section's values (before any work: a bad `[graph]` key must not wait
    /// for the filter to finish).
    pub fn validate(&self) -> Result<(), OptionError> {
        let err = |section: &'static str| move |message: String| OptionError { section, message };
        self.input.validate().map_err(err("input"))?;
        self.motion
            .validate()
            .map_err(|e| err("motion")(e.to_string()))?;
        self.map.validate().map_err(err("map"))?;
        self.filter
            .validate()
            .map_err(|e| err("filter")(e.to_string()))?;
        self.graph.validate().map_err(err("graph"))?;
        self.sim.validate().map_err(|e| err("sim")(e.to_string()))?;
        self.localize.validate().map_err(err("localize"))?;
        self.session.validate().map_err(err("session"))?;
        Ok(())
    }

    /// Loads a TOML file over the defaults.
    pub fn from_toml_file(path: &std::path::Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text, path)
    }

    /// Parses TOML text over the defaults; `path` names it in errors.
    pub fn from_toml_str(text: &str, path: &std::path::Path) -> Result<Config, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Toml {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }

    /// The configuration as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot serialise: {e}\n"))
    }
}

mod sources {
    include!(concat!(env!("OUT_DIR"), "/config_sources.rs"));
}

/// One documented field of an options struct, as found in the library's source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FieldDoc {
    /// The struct declaring the field.
    pub struct_name: String,
    /// The field (= TOML key).
    pub field: String,
    /// The field's type, last path segment without generics (`MotionOptions`).
    pub type_name: String,
    /// Its doc comment, one entry per line.
    pub doc: Vec<String>,
    /// Marked `#[serde(skip)]`: not a key of the configuration file.
    pub skipped: bool,
}

/// The doc comments of every `pub` field of every `pub struct` in the library's source
/// (embedded at build time), in source order.
pub fn field_docs() -> Vec<FieldDoc> {
    let mut out = Vec::new();
    for src in sources::SOURCES {
        let mut pending: Vec<String> = Vec::new();
        let mut skipped = false;
        let mut current: Option<String> = None;
        for line in src.lines() {
            let t = line.trim();
            if let Some(d) = t.strip_prefix("///") {
                pending.push(d.strip_prefix(' ').unwrap_or(d).to_string());
                continue;
            }
            if t.starts_with("#[") {
                skipped |= t == "#[serde(skip)]";
                continue;
            }
            if let Some(rest) = t.strip_prefix("pub struct ") {
                let name: String = rest
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                current = t.ends_with('{').then_some(name);
            } else if t == "}" {
                current = None;
            } else if let (Some(s), Some(rest)) = (&current, t.strip_prefix("pub "))
                && let Some((field, ty)) = rest.split_once(':')
            {
                let ty = ty.trim().trim_end_matches(',');
                let base = ty.split('<').next().unwrap_or(ty);
                let type_name = base.rsplit("::").next().unwrap_or(base).trim();
                out.push(FieldDoc {
                    struct_name: s.clone(),
                    field: field.trim().to_string(),
                    type_name: type_name.to_string(),
                    doc: std::mem::take(&mut pending),
                    skipped,
                });
            }
            pending.clear();
            skipped = false;
        }
    }
    out
}

/// `toml` (a serialised [`Config`]) with each key's and section's doc comment as `#` lines
/// above it. Keys whose doc cannot be found are left bare.
pub fn annotate_toml(toml: &str) -> String {
    let docs = field_docs();
    let find = |s: &str, f: &str| docs.iter().find(|d| d.struct_name == s && d.field == f);
    // Struct of the table being printed.
    let mut table: Option<String> = Some("Config".to_string());
    let mut out = String::with_capacity(toml.len() * 3);
    let push_doc = |out: &mut String, d: Option<&FieldDoc>| {
        if let Some(d) = d {
            for l in &d.doc {
                if l.is_empty() {
                    out.push_str("#\n");
                } else {
                    out.push_str("# ");
                    out.push_str(l);
                    out.push('\n');
                }
            }
        }
    };
    // Optional keys left out of the TOML (`None`) are listed as comments at the end of their
    // table, so every option is visible.
    let flush_unset = |out: &mut String, table: Option<&str>, printed: &[String]| {
        let Some(t) = table else { return };
        for d in docs
            .iter()
            .filter(|d| d.struct_name == t && d.type_name == "Option" && !d.skipped)
        {
            if !printed.contains(&d.field) {
                push_doc(out, Some(d));
                out.push_str(&format!("# {} = (unset)\n", d.field));
            }
        }
    };
    let mut printed: Vec<String> = Vec::new();
    for line in toml.lines() {
        let t = line.trim();
        if t.starts_with('[') && !line.starts_with(' ') {
            flush_unset(&mut out, table.as_deref(), &printed);
            printed.clear();
            let path = t.trim_matches(|c| c == '[' || c == ']');
            let mut s = Some("Config".to_string());
            let mut last = None;
            for seg in path.split('.') {
                last = s.as_deref().and_then(|st| find(st, seg));
                s = last.map(|d| d.type_name.clone());
            }
            if !out.is_empty() && !out.ends_with("\n\n") {
                out.push('\n');
            }
            push_doc(&mut out, last);
            table = s;
        } else if let Some((key, _)) = line.split_once(" = ")
            && !line.starts_with(' ')
            && key.chars().all(|c| c.is_alphanumeric() || c == '_')
        {
            push_doc(&mut out, table.as_deref().and_then(|s| find(s, key)));
            printed.push(key.to_string());
        } else if t.is_empty() {
            // Section spacing is handled at headers.
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    flush_unset(&mut out, table.as_deref(), &printed);
    out
}

impl Config {
    /// The configuration as TOML with every key's doc comment (`pfslam print-config`).
    pub fn to_annotated_toml(&self) -> String {
        annotate_toml(&self.to_toml())
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
    fn every_key_is_documented() {
        let text = Config::default().to_annotated_toml();
        let back: Config = toml::from_str(&text).unwrap();
        assert_eq!(back, Config::default());
        let lines: Vec<&str> = text.lines().collect();
        for (k, l) in lines.iter().enumerate() {
            let keyed =
                (l.split_once(" = ").is_some() && !l.starts_with([' ', '#'])) || l.starts_with('[');
            if keyed {
                assert!(
                    k > 0 && lines[k - 1].starts_with('#'),
                    "no comment above `{l}`:\n{text}"
                );
            }
        }
    }

    #[test]
    fn unknown_key_is_an_error() {
        assert!(toml::from_str::<Config>("nonsense = 1").is_err());
        // A back-end key outside its part is unknown (the flat form before the nesting).
        let err = toml::from_str::<Config>("[graph]\nloop_window_m = 1.0")
            .unwrap_err()
            .to_string();
        assert!(err.contains("loop_window_m"), "{err}");
        // The filter's and the simulator's keys are refused outside their own tables too:
        // a key of a part in the parent table, or in a sibling part.
        for (text, key) in [
            ("[filter.rbpf]\nsrr = 0.1", "srr"),
            (
                "[filter.rbpf]\nrefine_sigma_xy_m = 0.03",
                "refine_sigma_xy_m",
            ),
            ("[filter.rbpf]\njitter_xy_m = 0.01", "jitter_xy_m"),
            ("[filter.rbpf.search]\nsigma_m = 0.05", "sigma_m"),
            ("[sim.car]\nwheel_slip_std = 0.0", "wheel_slip_std"),
            (
                "[sim.humanoid]\nhead_pitch_max_rad = 0.5",
                "head_pitch_max_rad",
            ),
            (
                "[sim.humanoid]\nimu_noise_std_rad = 0.0",
                "imu_noise_std_rad",
            ),
        ] {
            let err = toml::from_str::<Config>(text).unwrap_err().to_string();
            assert!(err.contains(&format!("unknown field `{key}`")), "{err}");
        }
        // `final_refine` is a table: a boolean in its place is refused.
        assert!(toml::from_str::<Config>("[filter.rbpf]\nfinal_refine = false").is_err());
        let c: Config = toml::from_str(
            "[filter.rbpf.final_refine]\nenabled = false\n[sim.car.errors]\nwheel_slip_std = 0.0",
        )
        .unwrap();
        assert!(!c.filter.rbpf.final_refine.enabled);
        assert_eq!(c.sim.car.errors.wheel_slip_std, 0.0);
    }

    /// A bad value in a nested back-end table is reported with its whole path; the
    /// method's constants are not keys.
    #[test]
    fn nested_graph_keys_are_checked_by_path() {
        let c: Config = toml::from_str("[graph.loops]\nsigma_m = -1.0").unwrap();
        let err = c.validate().unwrap_err().to_string();
        assert!(
            err.contains("graph.loops.sigma_m must be positive"),
            "{err}"
        );
        for (text, key) in [
            ("[graph.loops.local]\nwindow_m = 5.0", "window_m"),
            ("[graph.optimize]\nchi2 = 1.0", "optimize"),
            ("[graph.sequential]\nprior_sigma_m = 1.0", "prior_sigma_m"),
        ] {
            let err = toml::from_str::<Config>(text).unwrap_err().to_string();
            assert!(err.contains(&format!("unknown field `{key}`")), "{err}");
        }
    }

    /// A bad value in a nested table of the filter or the simulator is reported with its
    /// whole path.
    #[test]
    fn nested_filter_and_sim_keys_are_checked_by_path() {
        for (text, want) in [
            (
                "[filter.rbpf.search]\nstep_xy_m = -1.0",
                "filter.rbpf.search.step_xy_m must be finite and >= 0",
            ),
            (
                "[filter.rbpf.search]\nrefine_levels = 13",
                "filter.rbpf.search.refine_levels must be at most 12",
            ),
            (
                "[filter.rbpf.odometry_noise]\nstt = -0.1",
                "filter.rbpf.odometry_noise.stt must be finite and >= 0",
            ),
            (
                "[sim.car.errors]\nlidar_dropout_prob = 2.0",
                "sim.car.errors.lidar_dropout_prob must be in [0, 1]",
            ),
            (
                "[sim.humanoid.errors]\nstamp_jitter_std_ns = -1.0",
                "sim.humanoid.errors.stamp_jitter_std_ns must be >= 0",
            ),
        ] {
            let c: Config = toml::from_str(text).unwrap();
            let err = c.validate().unwrap_err().to_string();
            assert!(err.contains(want), "{text}: {err}");
        }
        for text in [
            "[filter.rbpf.search]\njitter_xy_m = 0.0",
            "[filter.rbpf.likelihood]\nkernel_cells = 2",
            "[sim.humanoid.head]\npitch_period_s = 1.0",
        ] {
            assert!(toml::from_str::<Config>(text).is_err(), "{text}");
        }
    }

    /// A `Switch` reads its names and, for switches that were booleans, `true` / `false`;
    /// anything else is an error naming the accepted values.
    #[test]
    fn switches_read_names_and_booleans() {
        use crate::graph::Switch;
        for (text, want) in [
            ("\"auto\"", Switch::Auto),
            ("\"on\"", Switch::On),
            ("\"off\"", Switch::Off),
            ("true", Switch::On),
            ("false", Switch::Off),
        ] {
            let c: Config = toml::from_str(&format!("[graph.refine]\nscans = {text}")).unwrap();
            assert_eq!(c.graph.refine.scans, want, "{text}");
            let c: Config =
                toml::from_str(&format!("[graph.sequential]\nmatching = {text}")).unwrap();
            assert_eq!(c.graph.sequential.matching, want, "{text}");
        }
        let err = toml::from_str::<Config>("[graph.refine]\nscans = \"sometimes\"")
            .unwrap_err()
            .to_string();
        assert!(err.contains("expected `auto`, `on`, `off`"), "{err}");
        assert!(toml::from_str::<Config>("[graph.refine]\nscans = 1").is_err());
    }
}
