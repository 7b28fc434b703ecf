//! Scan preprocessing: ranges -> 2-D end points in the body frame (once per scan), then in
//! the world frame (once per pose hypothesis).
//!
//! Steps for beam `k` with range `r`:
//! 1. "no return": `r` not finite, `r <= 0`, or `r >= LidarGeometry::range_max_m`; readings
//!    above `ScanOptions::range_max_m` count as "no return" too (too far to trust). Policy
//!    [`NoReturnPolicy`]: skip the beam, or clear free space along it up to
//!    `no_return_clear_m` (the end cell gets the free update, not the occupied one).
//! 2. `r < range_min_m`: skipped (returns from the vehicle itself).
//! 3. Polar -> cartesian in the LiDAR frame (`LidarGeometry::beam_angle_rad`), then the 3-D
//!    `body_from_lidar`; z is dropped after the optional z window (in the body frame, which for
//!    a planar pose is the world frame's z: ground removal as in the ESE650 seed).
//! 4. [`to_world`]: the 2-D `world_from_body` pose.

use super::MapError;
use crate::geometry::{Pose2, Rigid3};
use crate::sensors::LidarGeometry;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// What to do with a beam that has no return (or a too-far one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum NoReturnPolicy {
    /// Ignore the beam.
    #[default]
    Skip,
    /// Mark the cells along the beam free up to `no_return_clear_m`.
    ClearFree,
}

/// How a joining point of the densification ([`ScanOptions::densify_max_gap_m`]) is
/// inserted into the map. Scan matching sees the joining points whatever this says.
/// It differs by map: see [`ScanOptions::densify_rays`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DensifyRays {
    /// A whole ray from the sensor, cleared all the way (`free_to` 1), even between two
    /// returns that clear only part of theirs.
    Full,
    /// Only its end cell, marked occupied: no free ray (`free_to` 0). The returns' own rays
    /// clear the space in front of the wall.
    HitOnly,
}

/// Scan preprocessing options (`[map.scan]`, a field of [`super::MapOptions`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanOptions {
    /// Shorter readings are dropped (m), on top of the sensor's own minimum
    /// ([`crate::sensors::LidarGeometry::range_min_m`]: 2 m for the seeds' car and humanoid).
    pub range_min_m: f32,
    /// Longer readings are treated as "no return" (m; seed 75).
    pub range_max_m: f32,
    /// Policy for "no return" beams.
    pub no_return: NoReturnPolicy,
    /// With `no_return = "clear_free"`: free space is cleared up to this distance (m).
    pub no_return_clear_m: f32,
    /// Points below this height are dropped (m, world/body frame; `None` = no bound).
    pub z_min_m: Option<f64>,
    /// Points above this height are dropped (m, world/body frame; `None` = no bound).
    pub z_max_m: Option<f64>,
    /// Ground removal for tilted scanners: when the scan plane is tilted by more than 1 deg
    /// (the car's LiDAR; a nodding head), returns lower than this above the body frame's
    /// z = 0 (the ground) are dropped. A level scanner cannot hit the ground, so planar
    /// recordings (z = 0 everywhere) keep every point. Off: a large negative value (TOML
    /// cannot write `None`; the seeds keep every point).
    pub ground_clearance_m: Option<f64>,
    /// Consecutive returns closer than this (m, in the plane) are joined by extra returns
    /// every `densify_step_m`: a wall sampled by beams a few decimetres apart becomes a line,
    /// in the map and in scan matching, so matching has no ripple that favours repeating the
    /// previous scan's beam pattern. 0 = off (the seeds).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub densify_max_gap_m: Option<f64>,
    /// Spacing of the joining returns (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub densify_step_m: f64,
    /// How the joining returns are inserted: end cells only in maps built along known poses
    /// (`pfslam map`, the rebuild along the back end's trajectory: a joining return is not a
    /// measured beam, and the rebuild costs a quarter), whole rays in the SLAM filter's map
    /// ([`Self::for_filter`]: its matching needs that clearing). Not a configuration key:
    /// `docs/decisions/0016-joining-returns-in-maps.md` has the measurements.
    #[serde(skip)]
    pub densify_rays: DensifyRays,
    /// A beam clears free space only up to where it climbs above this height (m, body
    /// frame); a large value = the whole ray (the seeds). The car's forward beams rise 37 deg: past
    /// a few metres they fly over parked vans and low buildings, and clearing their whole
    /// ray would erase those obstacles from the 2-D map.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub free_z_max_m: Option<f64>,
}

impl Default for ScanOptions {
    fn default() -> Self {
        ScanOptions {
            range_min_m: 0.0,
            range_max_m: 75.0,
            no_return: NoReturnPolicy::Skip,
            no_return_clear_m: 20.0,
            z_min_m: None,
            z_max_m: None,
            ground_clearance_m: Some(0.5),
            densify_max_gap_m: Some(1.0),
            densify_step_m: 0.1,
            densify_rays: DensifyRays::HitOnly,
            free_z_max_m: Some(2.5),
        }
    }
}

impl ScanOptions {
    /// Checks ranges and the z window; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.range_min_m.is_finite() && self.range_min_m >= 0.0) {
            return Err("map.scan.range_min_m must be >= 0".into());
        }
        if !(self.range_max_m.is_finite() && self.range_max_m > self.range_min_m) {
            return Err("map.scan.range_max_m must be finite and > range_min_m".into());
        }
        if !(self.no_return_clear_m.is_finite() && self.no_return_clear_m >= 0.0) {
            return Err("map.scan.no_return_clear_m must be finite and >= 0".into());
        }
        for (k, v) in [("z_min_m", self.z_min_m), ("z_max_m", self.z_max_m)] {
            if v.is_some_and(|z| !z.is_finite()) {
                return Err(format!("map.scan.{k} must be finite"));
            }
        }
        if self
            .densify_max_gap_m
            .is_some_and(|g| !(g.is_finite() && g >= 0.0))
        {
            return Err("map.scan.densify_max_gap_m must be finite and >= 0".into());
        }
        if !(self.densify_step_m.is_finite() && self.densify_step_m >= 0.01) {
            return Err("map.scan.densify_step_m must be at least 0.01".into());
        }
        if self.free_z_max_m.is_some_and(|z| !z.is_finite()) {
            return Err("map.scan.free_z_max_m must be finite".into());
        }
        if self.ground_clearance_m.is_some_and(|z| !z.is_finite()) {
            return Err("map.scan.ground_clearance_m must be finite".into());
        }
        if let (Some(a), Some(b)) = (self.z_min_m, self.z_max_m)
            && a >= b
        {
            return Err("map.scan: z_min_m must be < z_max_m".into());
        }
        Ok(())
    }

    /// These options for the SLAM filter's map: the joining returns as whole rays.
    pub fn for_filter(&self) -> ScanOptions {
        ScanOptions {
            densify_rays: DensifyRays::Full,
            ..*self
        }
    }

    /// The longest ray this preprocessing can produce (m).
    pub fn max_ray_m(&self) -> f32 {
        match self.no_return {
            NoReturnPolicy::Skip => self.range_max_m,
            NoReturnPolicy::ClearFree => self.range_max_m.max(self.no_return_clear_m),
        }
    }
}

/// One end point of a ray in a 2-D frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPoint {
    /// x (m).
    pub x_m: f64,
    /// y (m).
    pub y_m: f64,
    /// True for a return (the end cell is occupied); false for a free-space end point of a
    /// "no return" beam.
    pub hit: bool,
    /// Fraction of the ray (from the sensor) whose cells are cleared (1 = all of it). Less
    /// for a tilted beam that climbs above `free_z_max_m`: beyond that it flies over
    /// whatever is lower, so the plane below says nothing about those cells.
    pub free_to: f32,
    /// Height of the end point (m, body frame = world frame for a planar pose); meaningful
    /// only when the scan's `sensor_z_m` is set.
    pub z_m: f32,
}

/// A scan as 2-D rays from one sensor position, in one frame (body or world: the variable
/// name says which).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlanarScan {
    /// Sensor x (m).
    pub sensor_x_m: f64,
    /// Sensor y (m).
    pub sensor_y_m: f64,
    /// Sensor height (m) when the rays vary in height (a tilted mount): each point's `z_m` is
    /// then its height and the ray a 3-D segment; `None` for a level scanner (a planar scan).
    pub sensor_z_m: Option<f64>,
    /// Ray end points, in beam order.
    pub points: Vec<ScanPoint>,
}

impl PlanarScan {
    /// Number of returns (points with `hit`).
    pub fn hit_count(&self) -> usize {
        self.points.iter().filter(|p| p.hit).count()
    }

    /// A level scan from the origin with a return at each of `points` (x, y in m): the
    /// tests' hand-made scans.
    #[cfg(test)]
    pub(crate) fn hits_from_origin(points: &[[f64; 2]]) -> Self {
        PlanarScan {
            sensor_x_m: 0.0,
            sensor_y_m: 0.0,
            sensor_z_m: None,
            points: points
                .iter()
                .map(|p| ScanPoint {
                    x_m: p[0],
                    y_m: p[1],
                    hit: true,
                    free_to: 1.0,
                    z_m: 0.0,
                })
                .collect(),
        }
    }
}

/// Precomputed per-beam directions for one beam geometry and mount: turns ranges into a
/// body-frame [`PlanarScan`] without trigonometry.
#[derive(Debug, Clone)]
pub struct ScanProjector {
    opts: ScanOptions,
    sensor_range_max_m: f32,
    sensor_range_min_m: f32,
    /// LiDAR origin in the body frame.
    origin_body: Vector3<f64>,
    /// Unit beam directions in the body frame.
    dirs_body: Vec<Vector3<f64>>,
    /// The ground-removal height in force for this mount (`None` for a level scan plane).
    ground_z_m: Option<f64>,
    /// The scan plane is tilted: scans carry heights (`PlanarScan::sensor_z_m`).
    tilted: bool,
}

/// True when the scan plane is tilted by more than 1 deg (its rays vary in height).
fn is_tilted(body_from_lidar: &Rigid3) -> bool {
    let normal = body_from_lidar.rotation * Vector3::new(0.0, 0.0, 1.0);
    normal.z.abs() < 1f64.to_radians().cos()
}

/// The ground-removal height for a mount: `clearance` when the scan plane is tilted.
fn ground_z(body_from_lidar: &Rigid3, clearance: Option<f64>) -> Option<f64> {
    clearance.filter(|_| is_tilted(body_from_lidar))
}

impl ScanProjector {
    /// A projector for `geometry` mounted at `body_from_lidar`.
    pub fn new(
        geometry: &LidarGeometry,
        body_from_lidar: &Rigid3,
        opts: &ScanOptions,
    ) -> Result<Self, MapError> {
        opts.validate().map_err(MapError::Options)?;
        let dirs_body = (0..geometry.beam_count)
            .map(|k| {
                let (s, c) = geometry.beam_angle_rad(k).sin_cos();
                body_from_lidar.rotation * Vector3::new(c, s, 0.0)
            })
            .collect();
        Ok(ScanProjector {
            ground_z_m: ground_z(body_from_lidar, opts.ground_clearance_m),
            tilted: is_tilted(body_from_lidar),
            opts: *opts,
            sensor_range_max_m: geometry.range_max_m,
            sensor_range_min_m: geometry.range_min_m,
            origin_body: body_from_lidar.translation,
            dirs_body,
        })
    }

    /// Replaces the beam geometry and the mount (a LiDAR that moves on the body, or whose
    /// beam layout changes from scan to scan), keeping the options.
    pub fn set_mount(&mut self, geometry: &LidarGeometry, body_from_lidar: &Rigid3) {
        self.origin_body = body_from_lidar.translation;
        self.ground_z_m = ground_z(body_from_lidar, self.opts.ground_clearance_m);
        self.tilted = is_tilted(body_from_lidar);
        self.sensor_range_max_m = geometry.range_max_m;
        self.sensor_range_min_m = geometry.range_min_m;
        self.dirs_body.clear();
        self.dirs_body.extend((0..geometry.beam_count).map(|k| {
            let (s, c) = geometry.beam_angle_rad(k).sin_cos();
            body_from_lidar.rotation * Vector3::new(c, s, 0.0)
        }));
    }

    /// Aims the projector at scan `i` of `recording` when its sensor varies from scan to
    /// scan (mount or beam geometry); a no-op otherwise.
    #[inline]
    pub fn aim(&mut self, recording: &crate::sensors::Recording, i: usize) {
        if recording.sensor_varies() {
            self.set_mount(recording.lidar_at(i), recording.body_from_lidar_at(i));
        }
    }

    /// Number of beams expected per scan.
    pub fn beam_count(&self) -> usize {
        self.dirs_body.len()
    }

    /// The options in use.
    pub fn options(&self) -> &ScanOptions {
        &self.opts
    }

    /// Preprocesses one scan into `out` (body frame, cleared first). For a tilted mount the
    /// scan carries heights (`sensor_z_m` and every point's `z_m`; a joining point of the
    /// densification gets the height interpolated between its two returns).
    pub fn to_body(&self, ranges_m: &[f32], out: &mut PlanarScan) -> Result<(), MapError> {
        if ranges_m.len() != self.dirs_body.len() {
            return Err(MapError::BeamCount {
                expected: self.dirs_body.len(),
                got: ranges_m.len(),
            });
        }
        let o = &self.opts;
        out.sensor_x_m = self.origin_body.x;
        out.sensor_y_m = self.origin_body.y;
        out.sensor_z_m = self.tilted.then_some(self.origin_body.z);
        out.points.clear();
        for (&r, d) in ranges_m.iter().zip(&self.dirs_body) {
            let no_return =
                !r.is_finite() || r <= 0.0 || r >= self.sensor_range_max_m || r > o.range_max_m;
            let (dist_m, hit) = if no_return {
                match o.no_return {
                    NoReturnPolicy::Skip => continue,
                    NoReturnPolicy::ClearFree => (o.no_return_clear_m as f64, false),
                }
            } else if r < o.range_min_m || r < self.sensor_range_min_m {
                continue;
            } else {
                (r as f64, true)
            };
            let p = self.origin_body + d * dist_m;
            if o.z_min_m.is_some_and(|z| p.z < z)
                || o.z_max_m.is_some_and(|z| p.z > z)
                || (hit && self.ground_z_m.is_some_and(|z| p.z < z))
            {
                continue;
            }
            let free_to = match o.free_z_max_m {
                Some(zmax) if p.z > zmax && p.z > self.origin_body.z => {
                    ((zmax - self.origin_body.z) / (p.z - self.origin_body.z)).clamp(0.0, 1.0)
                        as f32
                }
                _ => 1.0,
            };
            if hit
                && let Some(gap) = o.densify_max_gap_m
                && let Some(prev) = out.points.last().copied()
                && prev.hit
            {
                let (dx, dy) = (p.x - prev.x_m, p.y - prev.y_m);
                let dz = p.z as f32 - prev.z_m;
                let d = dx.hypot(dy);
                if d <= gap && d > o.densify_step_m {
                    let n = (d / o.densify_step_m).ceil() as usize;
                    for k in 1..n {
                        let t = k as f64 / n as f64;
                        out.points.push(ScanPoint {
                            x_m: prev.x_m + t * dx,
                            y_m: prev.y_m + t * dy,
                            hit: true,
                            free_to: match o.densify_rays {
                                DensifyRays::Full => 1.0,
                                DensifyRays::HitOnly => 0.0,
                            },
                            z_m: prev.z_m + t as f32 * dz,
                        });
                    }
                }
            }
            out.points.push(ScanPoint {
                x_m: p.x,
                y_m: p.y,
                hit,
                free_to,
                z_m: p.z as f32,
            });
        }
        Ok(())
    }
}

/// Transforms a body-frame scan into the world frame with `world_from_body` (into `out`,
/// cleared first). This is the per-particle step.
#[inline]
pub fn to_world(body: &PlanarScan, world_from_body: &Pose2, out: &mut PlanarScan) {
    let (s, c) = world_from_body.yaw_rad.sin_cos();
    let (tx, ty) = (world_from_body.x_m, world_from_body.y_m);
    out.sensor_x_m = tx + c * body.sensor_x_m - s * body.sensor_y_m;
    out.sensor_y_m = ty + s * body.sensor_x_m + c * body.sensor_y_m;
    out.sensor_z_m = body.sensor_z_m;
    out.points.clear();
    out.points.extend(body.points.iter().map(|p| ScanPoint {
        x_m: tx + c * p.x_m - s * p.y_m,
        y_m: ty + s * p.x_m + c * p.y_m,
        hit: p.hit,
        free_to: p.free_to,
        z_m: p.z_m,
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geom4() -> LidarGeometry {
        LidarGeometry {
            angle_min_rad: 0.0,
            angle_increment_rad: std::f64::consts::FRAC_PI_2,
            beam_count: 4,
            range_min_m: 0.0,
            range_max_m: 80.0,
        }
    }

    #[test]
    fn window_and_no_return() {
        // a sensor that states a 2 m minimum
        let geom4 = || LidarGeometry {
            range_min_m: 2.0,
            ..geom4()
        };
        let p = ScanProjector::new(&geom4(), &Rigid3::IDENTITY, &ScanOptions::default()).unwrap();
        let mut out = PlanarScan::default();
        p.to_body(&[10.0, 0.0, 1.0, 80.0], &mut out).unwrap();
        assert_eq!(out.points.len(), 1);
        assert!((out.points[0].x_m - 10.0).abs() < 1e-9 && out.points[0].hit);

        let opts = ScanOptions {
            no_return: NoReturnPolicy::ClearFree,
            no_return_clear_m: 5.0,
            ..ScanOptions::default()
        };
        let p = ScanProjector::new(&geom4(), &Rigid3::IDENTITY, &opts).unwrap();
        p.to_body(&[10.0, 0.0, 1.0, 79.0], &mut out).unwrap();
        // beam 1 (+y, no return) cleared to 5 m; beam 2 below the sensor's minimum; beam 3
        // beyond 75 m
        assert_eq!(out.points.len(), 3);
        assert!((out.points[1].y_m - 5.0).abs() < 1e-9 && !out.points[1].hit);
        assert!((out.points[2].y_m + 5.0).abs() < 1e-9 && !out.points[2].hit);
        assert!(p.to_body(&[1.0], &mut out).is_err());
    }

    #[test]
    fn mount_pose_and_z_window() {
        // LiDAR 1 m forward, 2 m up, pitched down 30 deg: a 4 m beam ends 2 m below it.
        let mount = Rigid3::from_rpy(0.0, 30f64.to_radians(), 0.0, [1.0, 0.0, 2.0]);
        let opts = ScanOptions {
            z_min_m: Some(0.2),
            ..ScanOptions::default()
        };
        let p = ScanProjector::new(&geom4(), &mount, &opts).unwrap();
        let mut body = PlanarScan::default();
        p.to_body(&[4.0, 3.0, 0.0, 0.0], &mut body).unwrap();
        // beam 0 hits the ground (z = 0) and is removed; beam 1 (+y) is level
        assert_eq!(body.points.len(), 1);
        assert!((body.points[0].x_m - 1.0).abs() < 1e-9);
        assert!((body.points[0].y_m - 3.0).abs() < 1e-9);
        let mut world = PlanarScan::default();
        to_world(
            &body,
            &Pose2::new(10.0, 0.0, std::f64::consts::FRAC_PI_2),
            &mut world,
        );
        assert!((world.sensor_x_m - 10.0).abs() < 1e-9 && (world.sensor_y_m - 1.0).abs() < 1e-9);
        assert!((world.points[0].x_m - 7.0).abs() < 1e-9);
        assert!((world.points[0].y_m - 1.0).abs() < 1e-9);
    }

    #[test]
    fn ground_removal_only_for_tilted_mounts_and_densify_and_partial_clearing() {
        let opts = ScanOptions {
            range_min_m: 0.1,
            ..ScanOptions::default()
        };
        // Level scanner at z = 0 (a planar recording): nothing is ground, nothing dropped.
        let p = ScanProjector::new(&geom4(), &Rigid3::IDENTITY, &opts).unwrap();
        let mut out = PlanarScan::default();
        p.to_body(&[4.0, 3.0, 2.0, 1.0], &mut out).unwrap();
        assert_eq!(out.hit_count(), 4);
        assert!(out.points.iter().all(|q| q.free_to == 1.0));
        // Pitched down 30 deg at 2 m: beam 0 reaches the ground at 4 m and is dropped.
        let mount = Rigid3::from_rpy(0.0, 30f64.to_radians(), 0.0, [0.0, 0.0, 2.0]);
        let p = ScanProjector::new(&geom4(), &mount, &opts).unwrap();
        p.to_body(&[4.0, 3.0, 0.0, 0.0], &mut out).unwrap();
        assert_eq!(out.hit_count(), 1);
        // Pitched up 30 deg at 2 m: a 4 m return ends at 4 m height, cleared only up to
        // 2.5 m height (a quarter of the ray).
        let mount = Rigid3::from_rpy(0.0, -30f64.to_radians(), 0.0, [0.0, 0.0, 2.0]);
        let p = ScanProjector::new(&geom4(), &mount, &opts).unwrap();
        p.to_body(&[4.0, 0.0, 0.0, 0.0], &mut out).unwrap();
        assert_eq!(out.points.len(), 1);
        assert!(
            (out.points[0].free_to - 0.25).abs() < 1e-6,
            "{:?}",
            out.points[0]
        );
        // Densification: two returns 0.5 m apart on a wall get joining points every 0.1 m.
        let out = wall_pair_from(&Rigid3::IDENTITY, &opts);
        assert_eq!(out.points.len(), 6);
        assert!(
            out.points
                .iter()
                .all(|q| (q.x_m - 10.0).abs() < 1e-5 && q.hit)
        );
    }

    /// Two returns 0.5 m apart on a wall 10 m ahead of a sensor at (0, 0, `z`) looking along
    /// x, pitched up by `pitch_deg`: the densification joins them with 4 points.
    fn wall_pair(pitch_deg: f64, rays: DensifyRays) -> PlanarScan {
        let opts = ScanOptions {
            range_min_m: 0.1,
            densify_rays: rays,
            ..ScanOptions::default()
        };
        let mount = Rigid3::from_rpy(0.0, -pitch_deg.to_radians(), 0.0, [0.0, 0.0, 2.0]);
        wall_pair_from(&mount, &opts)
    }

    /// Two returns 0.5 m apart on a wall 10 m ahead of a LiDAR at `mount`, projected with
    /// `opts`.
    fn wall_pair_from(mount: &Rigid3, opts: &ScanOptions) -> PlanarScan {
        let g = LidarGeometry {
            angle_min_rad: 0.0,
            angle_increment_rad: (0.5f64 / 10.0).atan(),
            beam_count: 2,
            range_min_m: 0.0,
            range_max_m: 80.0,
        };
        let p = ScanProjector::new(&g, mount, opts).unwrap();
        let mut out = PlanarScan::default();
        p.to_body(&[10.0, (10.0f64.hypot(0.5)) as f32], &mut out)
            .unwrap();
        out
    }

    #[test]
    fn joining_points_are_end_cells_in_maps_and_whole_rays_in_the_filters_map() {
        assert_eq!(ScanOptions::default().densify_rays, DensifyRays::HitOnly);
        let o: ScanOptions = toml::from_str("ground_clearance_m = 0.2").unwrap();
        assert_eq!(o.densify_rays, DensifyRays::HitOnly);
        assert_eq!(o.for_filter().densify_rays, DensifyRays::Full);
        assert!(toml::from_str::<ScanOptions>("densify_rays = \"full\"").is_err());
        assert!(toml::from_str::<ScanOptions>("filter_densify_rays = \"full\"").is_err());
        let back: ScanOptions =
            toml::from_str(&toml::to_string(&ScanOptions::default().for_filter()).unwrap())
                .unwrap();
        assert_eq!(back, ScanOptions::default());
        // Level: the returns are cleared all the way; the joining points by the setting.
        for (rays, want) in [(DensifyRays::Full, 1.0), (DensifyRays::HitOnly, 0.0)] {
            let s = wall_pair(0.0, rays);
            assert_eq!(s.points.len(), 6, "{rays:?}");
            assert!(s.points.iter().all(|q| q.hit));
            let (ends, joining) = ([s.points[0].free_to, s.points[5].free_to], &s.points[1..5]);
            assert_eq!(ends, [1.0, 1.0], "{rays:?}");
            assert!(joining.iter().all(|q| q.free_to == want), "{rays:?}");
        }
        // Pitched up 10 deg at 2 m: the returns end ~3.7 m high, cleared up to 2.5 m only.
        let full = wall_pair(10.0, DensifyRays::Full);
        let ends = [full.points[0].free_to, full.points[5].free_to];
        assert!(ends.iter().all(|&f| f > 0.2 && f < 0.4), "{ends:?}");
        assert!(full.points[1..5].iter().all(|q| q.free_to == 1.0));
        // Matching sees the same points whatever the setting.
        let hit_only = wall_pair(10.0, DensifyRays::HitOnly);
        for (a, b) in full.points.iter().zip(&hit_only.points) {
            assert_eq!((a.x_m, a.y_m, a.z_m, a.hit), (b.x_m, b.y_m, b.z_m, b.hit));
        }
    }

    #[test]
    fn hit_only_joining_points_trace_no_free_cells() {
        use crate::map::{InsertScratch, MapOptions, OccupancyGrid};
        let mut mo = MapOptions::default();
        mo.height.enabled = false;
        let free_cells = |scan: &PlanarScan| {
            let mut g = OccupancyGrid::new(&mo).unwrap();
            g.insert_scan(scan, &mut InsertScratch::new()).unwrap();
            let mut free = Vec::new();
            for i in -20..130 {
                for j in -20..80 {
                    let c = crate::map::Cell { i, j };
                    if g.logodds(c) < 0.0 {
                        free.push(c);
                    }
                }
            }
            (free, g)
        };
        let level = wall_pair(0.0, DensifyRays::HitOnly);
        let returns = PlanarScan {
            points: vec![level.points[0], level.points[5]],
            ..level.clone()
        };
        let (free_returns, _) = free_cells(&returns);
        let (free_hit_only, g) = free_cells(&level);
        let (free_full, _) = free_cells(&wall_pair(0.0, DensifyRays::Full));
        // The joining points add no free cell (their end cells may turn a return's free
        // cell occupied), but do give their end cells the occupied update.
        assert!(free_hit_only.iter().all(|c| free_returns.contains(c)));
        for q in &level.points[1..5] {
            assert!(g.logodds(g.cell_of(q.x_m, q.y_m)) > 0.0, "{q:?}");
        }
        // Whole joining rays clear cells the returns' rays do not pass.
        assert!(free_full.iter().any(|c| !free_returns.contains(c)));
    }

    #[test]
    fn ucsd_mount_points_forward() {
        // The car's LiDAR: beam at 90 deg (the middle of its 190 deg fan) looks ahead.
        let cal = crate::sensors::CarCalibration::ucsd();
        let p =
            ScanProjector::new(&cal.lidar, &cal.body_from_lidar, &ScanOptions::default()).unwrap();
        let mut ranges = vec![0.0f32; 286];
        let mid = ((90.0 + 5.0) / 0.666f64).round() as usize;
        ranges[mid] = 10.0;
        let mut out = PlanarScan::default();
        p.to_body(&ranges, &mut out).unwrap();
        assert_eq!(out.points.len(), 1);
        assert!(out.points[0].x_m > 8.0, "{:?}", out.points[0]);
        assert!(out.points[0].y_m.abs() < 0.5);
    }
}
