//! Worlds: extruded polygons with heights on a ground plane `z = 0`, an optional ground
//! texture, and the route a vehicle drives.
//!
//! # World-file format (`*.world`, plain text)
//!
//! One item per line; `#` starts a comment; blank lines are ignored; tokens are separated by
//! white space; lengths in metres, angles in degrees, colours as 0-255 integers. Every error
//! names `file:line`.
//!
//! ```text
//! name <NAME>                                   # optional, default: the file stem
//! prism <KIND> <Z_MIN> <Z_MAX> <X1> <Y1> <X2> <Y2> <X3> <Y3> [<X> <Y> ...]
//!                                               # vertical extrusion of a simple polygon
//!                                               # (>= 3 vertices, any orientation) from
//!                                               # Z_MIN to Z_MAX (Z_MIN >= 0 < Z_MAX)
//! box <KIND> <CX> <CY> <LENGTH> <WIDTH> <YAW_DEG> <Z_MIN> <Z_MAX>
//!                                               # rotated rectangle (shorthand for a prism)
//! ground <R> <G> <B>                            # default ground colour (default 90 90 90)
//! region <R> <G> <B> <X1> <Y1> <X2> <Y2> <X3> <Y3> [...]
//!                                               # coloured ground polygon (grass, asphalt)
//! marking <R> <G> <B> <WIDTH> <X1> <Y1> <X2> <Y2> [...]
//!                                               # painted polyline on the ground (road lines)
//! route <X1> <Y1> <X2> <Y2> [<X> <Y> ...]       # waypoints of the closed route driven in
//!                                               # order, repeatedly (several `route` lines
//!                                               # append); corners are rounded
//! ```
//!
//! `KIND` is a free word kept for information (`building`, `car`, `pole`, `tree`, `wall`,
//! `desk`, ...). A prism with `Z_MIN > 0` floats (a tree canopy, a table top): rays pass
//! under it. Later regions and markings paint over earlier ones. Obstacles are solid: rays
//! stop at their walls and at their top and bottom faces. See `crates/pfslam-sim/worlds/` for an
//! example.

use super::SimError;
use std::path::Path;

mod builtin;
mod ground;
mod prism;
mod text;

use builtin::{campus, office};

pub use ground::*;
pub use prism::*;

/// A world: obstacles, ground texture and route.
#[derive(Debug, Clone, PartialEq)]
pub struct World {
    /// Name (built-in name or file stem).
    pub name: String,
    /// Obstacles.
    pub prisms: Vec<Prism>,
    /// Ground appearance.
    pub ground: GroundTexture,
    /// Closed route (waypoints, m) driven in order, repeatedly.
    pub route: Vec<[f64; 2]>,
}

/// Names of the built-in worlds.
pub const BUILTIN_WORLDS: [&str; 2] = ["campus", "office"];

impl World {
    /// A built-in world: `campus` (car) or `office` (humanoid).
    pub fn builtin(name: &str) -> Result<World, SimError> {
        match name {
            "campus" => Ok(campus()),
            "office" => Ok(office()),
            _ => Err(SimError::UnknownWorld(name.to_string())),
        }
    }

    /// A built-in name or else a world file.
    pub fn from_name_or_file(name_or_path: &str) -> Result<World, SimError> {
        if BUILTIN_WORLDS.contains(&name_or_path) {
            World::builtin(name_or_path)
        } else if !Path::new(name_or_path).exists() {
            Err(SimError::UnknownWorld(name_or_path.to_string()))
        } else {
            World::from_file(Path::new(name_or_path))
        }
    }

    /// Reads a world file (format in the module documentation).
    pub fn from_file(path: &Path) -> Result<World, SimError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SimError::Io(pfslam::files::IoError::io(path, e)))?;
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "world".to_string());
        World::parse(&text, path, &stem)
    }

    /// Shifts everything (obstacles, ground, route) by `(dx_m, dy_m)`.
    pub fn translate(&mut self, dx_m: f64, dy_m: f64) {
        let shift = |p: &mut [f64; 2]| {
            p[0] += dx_m;
            p[1] += dy_m;
        };
        self.prisms
            .iter_mut()
            .flat_map(|p| p.footprint.iter_mut())
            .for_each(shift);
        self.ground
            .regions
            .iter_mut()
            .flat_map(|r| r.polygon.iter_mut())
            .for_each(shift);
        self.ground
            .markings
            .iter_mut()
            .flat_map(|m| m.points.iter_mut())
            .for_each(shift);
        self.route.iter_mut().for_each(shift);
    }

    /// Axis-aligned bounds of obstacles and route: `[x_min, y_min, x_max, y_max]`.
    pub fn bounds(&self) -> [f64; 4] {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let pts = self
            .prisms
            .iter()
            .flat_map(|p| p.footprint.iter())
            .chain(self.route.iter());
        for p in pts {
            b[0] = b[0].min(p[0]);
            b[1] = b[1].min(p[1]);
            b[2] = b[2].max(p[0]);
            b[3] = b[3].max(p[1]);
        }
        if !b[0].is_finite() {
            return [-1.0, -1.0, 1.0, 1.0];
        }
        b
    }
}

#[cfg(test)]
mod tests;
