//! The occupancy grid: world <-> cell conversion ([`MapLimits`]), a tiled, copy-on-write
//! log-odds grid ([`OccupancyGrid`]), scan preprocessing ([`scan`]), Bresenham ray insertion,
//! mapping with known poses ([`map_with_poses`]) and comparison with a true map
//! ([`compare`]).
//!
//! Conventions: cell `(i, j)` covers `[origin + i * res, origin + (i + 1) * res)` in x and y
//! (centre at `+0.5`), `i` along world x, `j` along world y, both unbounded (negative indices
//! are fine). Log-odds are stored in fixed point (`i16`, 1/256 units); a never-written cell is
//! 0 (p = 0.5, unknown). Occupied when `p >= occupied_prob`, free when `p <= free_prob`.
pub mod binary;
pub mod compare;
pub mod grid;
pub mod limits;
pub mod logodds;
pub mod ray;
pub mod scan;

pub use binary::BinaryMap;
pub use compare::{MapComparison, compare_maps, compare_maps_visible};
pub use grid::{InsertScratch, InsertStats, OccupancyGrid, TILE_BYTES, TILE_SIZE};
pub use limits::{Cell, CellRect, MapLimits};
pub use logodds::{CellState, FixedLogOdds, LogOddsParams, LogOddsPreset, logit, sigmoid};
pub use ray::{bresenham, bresenham_cells};
pub use scan::{NoReturnPolicy, PlanarScan, ScanOptions, ScanPoint, ScanProjector, to_world};

use crate::geometry::{Pose2, Trajectory};
use crate::sensors::Recording;
use serde::{Deserialize, Serialize};

/// Errors of the map component.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// Invalid options (the message names the key).
    #[error("invalid map options: {0}")]
    Options(String),
    /// A scan has the wrong number of beams.
    #[error("scan has {got} beams, the LiDAR geometry says {expected}")]
    BeamCount {
        /// Beams in the geometry.
        expected: usize,
        /// Beams in the scan.
        got: usize,
    },
    /// A cell index beyond [`grid::MAX_CELL_INDEX`] (a pose far off the map).
    #[error("cell ({}, {}) is beyond the supported map extent", cell.i, cell.j)]
    OutOfRange {
        /// The offending cell.
        cell: Cell,
    },
    /// A ray longer than [`grid::MAX_RAY_CELLS`].
    #[error("ray of {cells} cells exceeds the limit of {max} cells")]
    RayTooLong {
        /// Its length (cells, Chebyshev).
        cells: i32,
        /// The limit.
        max: i32,
    },
    /// No scan could be inserted (no pose covers any scan's time).
    #[error("no scan lies within the time span of the poses")]
    NoScanInserted,
    /// Two maps cannot be compared.
    #[error("cannot compare maps: {0}")]
    Compare(String),
}

/// Options of the map component (`[map]` in the configuration). Scan preprocessing is the
/// nested section `[map.scan]`, the update model `[map.log_odds]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapOptions {
    /// Cell side (m).
    pub resolution_m: f64,
    /// World x of the corner of cell (0, 0) (m).
    pub origin_x_m: f64,
    /// World y of the corner of cell (0, 0) (m).
    pub origin_y_m: f64,
    /// Insert every `scan_step`-th scan when mapping with known poses (UCSD seed: 5).
    pub scan_step: usize,
    /// Log-odds increments, clamp bounds, thresholds.
    pub log_odds: LogOddsParams,
    /// Scan preprocessing.
    pub scan: ScanOptions,
    /// Cells within this distance (m, Chebyshev in cells) of a ray's return get no free
    /// update from that ray. Rays that graze a wall cross the wall's cells just before their
    /// end point; without a margin they erase the wall behind the vehicle between passes, so
    /// only the latest scan's hit spots stay occupied (0 = the seeds).
    pub free_margin_m: f64,
}

impl Default for MapOptions {
    fn default() -> Self {
        MapOptions {
            resolution_m: 0.1,
            origin_x_m: 0.0,
            origin_y_m: 0.0,
            scan_step: 1,
            log_odds: LogOddsParams::ese650(),
            scan: ScanOptions::default(),
            free_margin_m: 0.0,
        }
    }
}

impl MapOptions {
    /// The same options with a named log-odds preset (resolution and scan options kept).
    pub fn with_preset(mut self, preset: LogOddsPreset) -> Self {
        self.log_odds = LogOddsParams::preset(preset);
        self
    }

    /// World <-> cell conversion for these options.
    pub fn limits(&self) -> MapLimits {
        MapLimits::new(self.resolution_m, self.origin_x_m, self.origin_y_m)
    }

    /// Checks every field; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.resolution_m.is_finite() && self.resolution_m > 0.0) {
            return Err("map.resolution_m must be finite and > 0".into());
        }
        if !(self.origin_x_m.is_finite() && self.origin_y_m.is_finite()) {
            return Err("map.origin_x_m / origin_y_m must be finite".into());
        }
        if !(self.free_margin_m.is_finite() && (0.0..=10.0).contains(&self.free_margin_m)) {
            return Err("map.free_margin_m must lie in [0, 10]".into());
        }
        if self.scan_step == 0 {
            return Err("map.scan_step must be >= 1".into());
        }
        self.log_odds.validate()?;
        self.scan.validate()?;
        let ray_cells = self.scan.max_ray_m() as f64 / self.resolution_m;
        if ray_cells > grid::MAX_RAY_CELLS as f64 {
            return Err(format!(
                "map: rays of {:.0} m are {ray_cells:.0} cells at {} m; the limit is {} cells",
                self.scan.max_ray_m(),
                self.resolution_m,
                grid::MAX_RAY_CELLS
            ));
        }
        Ok(())
    }
}

/// Everything one thread needs to insert raw scans: the projector and reusable buffers.
#[derive(Debug, Clone)]
pub struct ScanInserter {
    /// Ranges -> body-frame points.
    pub projector: ScanProjector,
    /// Insertion scratch.
    pub scratch: InsertScratch,
    /// The last scan in the body frame.
    pub body: PlanarScan,
    /// The last scan in the world frame.
    pub world: PlanarScan,
}

impl ScanInserter {
    /// An inserter for a projector.
    pub fn new(projector: ScanProjector) -> Self {
        ScanInserter {
            projector,
            scratch: InsertScratch::new(),
            body: PlanarScan::default(),
            world: PlanarScan::default(),
        }
    }

    /// Preprocesses `ranges_m`, places it at `world_from_body` and inserts it.
    pub fn insert(
        &mut self,
        grid: &mut OccupancyGrid,
        ranges_m: &[f32],
        world_from_body: &Pose2,
    ) -> Result<InsertStats, MapError> {
        self.projector.to_body(ranges_m, &mut self.body)?;
        to_world(&self.body, world_from_body, &mut self.world);
        grid.insert_scan(&self.world, &mut self.scratch)
    }
}

/// Summary of [`map_with_poses`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MappingStats {
    /// Scans inserted.
    pub scans_inserted: usize,
    /// Scans skipped because no pose covers their time.
    pub scans_without_pose: usize,
    /// Rays traced.
    pub rays: usize,
}

/// Maps a recording with known poses (`world_from_body` at each scan time, interpolated from
/// `poses`): every `opts.scan_step`-th scan inside the poses' time span is inserted, in order.
/// Returns the grid, the world-frame last inserted scan and counts.
pub fn map_with_poses(
    recording: &Recording,
    poses: &Trajectory,
    opts: &MapOptions,
) -> Result<(OccupancyGrid, PlanarScan, MappingStats), MapError> {
    let mut grid = OccupancyGrid::new(opts)?;
    let projector = ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &opts.scan)?;
    let mut ins = ScanInserter::new(projector);
    let mut stats = MappingStats::default();
    let per_scan_mount = recording.body_from_lidar_per_scan.is_some();
    for k in (0..recording.scans.len()).step_by(opts.scan_step) {
        let Some(pose) = poses.pose_at(recording.scans.stamps_ns[k]) else {
            stats.scans_without_pose += 1;
            continue;
        };
        if per_scan_mount {
            ins.projector
                .set_mount(&recording.lidar, recording.body_from_lidar_at(k));
        }
        let s = ins.insert(&mut grid, recording.scans.ranges(k), &pose)?;
        stats.scans_inserted += 1;
        stats.rays += s.rays;
    }
    if stats.scans_inserted == 0 {
        return Err(MapError::NoScanInserted);
    }
    Ok((grid, ins.world, stats))
}

#[cfg(test)]
mod tests;
