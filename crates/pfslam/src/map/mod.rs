//! The occupancy grid: world <-> cell conversion ([`MapLimits`]), a tiled, copy-on-write
//! log-odds grid ([`OccupancyGrid`]), scan preprocessing ([`scan`]), Bresenham ray insertion,
//! mapping with known poses ([`map_with_poses`]) and comparison with a true map
//! ([`compare`]).
//!
//! Conventions: cell `(i, j)` covers `[origin + i * res, origin + (i + 1) * res)` in x and y
//! (centre at `+0.5`), `i` along world x, `j` along world y, both unbounded (negative indices
//! are fine). Log-odds are stored in fixed point (`i16`, 1/256 units); a never-written cell is
//! 0 (p = 0.5, unknown). Occupied when `p >= occupied_prob`, free when `p <= free_prob`.
//!
//! Height bins ([`HeightOptions`], `[map.height]`, on by default): a scan from a tilted
//! mount carries the height of its sensor and returns, and is inserted per (cell, height bin)
//! — each free cell of a ray at the height the ray crosses it, each return at its own — with
//! `i8` log-odds per bin. The cell's 2-D log-odds, which every 2-D output (map.png,
//! pgm/yaml, logodds.npy, the binary map) and the SLAM matchers read, is the projection
//! ([`project_bins`]): occupied when any bin is occupied, else the most free observed bin,
//! unknown when none is observed. Level LiDARs produce no heights and keep the 2-D insertion.
pub mod binary;
pub mod compare;
pub mod consistency;
pub mod grid;
pub mod limits;
pub mod logodds;
pub mod ray;
pub mod scan;

pub use binary::BinaryMap;
pub use compare::{
    MapComparison, compare_maps, compare_maps_aligned, compare_maps_visible,
    compare_maps_visible_aligned,
};
pub use grid::{
    BATCH_SCANS, BIN_SCALE, BatchScratch, BinLogOdds, CellChange, ChangeLog, InsertScratch,
    InsertStats, OccupancyGrid, ScanUpdates, TILE_BYTES, TILE_SIZE, project_bins, split_rays,
};
pub use limits::{Cell, CellRect, MapLimits};
pub use logodds::{CellState, FixedLogOdds, LogOddsParams, LogOddsPreset, logit, sigmoid};
pub use ray::{bresenham, bresenham_cells};
pub use scan::{
    DensifyRays, NoReturnPolicy, PlanarScan, ScanOptions, ScanPoint, ScanProjector, to_world,
};

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
    /// Motion filter of mapping with known poses (Cartographer's `motion_filter`): of the
    /// `scan_step`-th scans, one is inserted only once the pose has moved this far (m) from
    /// the last inserted scan's, or turned [`MapOptions::min_scan_turn_deg`] (0 = every
    /// `scan_step`-th scan). Off by default: at 0.1 m it halves the car's rebuild (a 100 Hz
    /// LiDAR's scans lie centimetres apart) but costs precision and recall against the true
    /// map (docs/decisions/0017-every-scan-mapped-along-known-poses.md). The filter's own
    /// map is not affected.
    pub min_scan_travel_m: f64,
    /// The turn (deg) that also passes the motion filter (with `min_scan_travel_m > 0`).
    pub min_scan_turn_deg: f64,
    /// Log-odds increments, clamp bounds, thresholds.
    pub log_odds: LogOddsParams,
    /// Scan preprocessing.
    pub scan: ScanOptions,
    /// Cells within this distance (m, Chebyshev in cells) of a ray's return get no free
    /// update from that ray. Rays that graze a wall cross the wall's cells just before their
    /// end point; without a margin they erase the wall behind the vehicle between passes, so
    /// only the latest scan's hit spots stay occupied (0 = the seeds).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub free_margin_m: f64,
    /// Height-aware insertion for tilted mounts (`[map.height]`).
    pub height: HeightOptions,
}

/// Height-aware insertion (`[map.height]`). A tilted scanner (the car's LMS511: level
/// sideways, rising 37 deg forwards, dipping 3 deg at the fan's ends) sees the same cell at
/// different heights from different poses: a parked car's roof under the dipping beams and
/// free space above it under the level ones, a canopy's underside under the rising beams and
/// free space below it. One log-odds value per cell votes such cells free. With this on, each
/// cell touched by a scan that carries heights (a tilted mount, see
/// [`ScanProjector::to_body`]) keeps one log-odds value per height bin, updated by the rays
/// at the height they cross it; its 2-D value (every 2-D output, and what SLAM matches
/// against) is the projection: the largest observed bin ([`grid::project_bins`]), i.e.
/// occupied when any bin is, free when observed and no bin is. Level scanners produce no
/// heights and never use bins (their maps are unchanged).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HeightOptions {
    /// Use height bins for scans that carry heights (tilted mounts); false = one log-odds
    /// value per cell for every scan.
    pub enabled: bool,
    /// Number of height bins per cell (2-16). Storage is 16 bytes per visited cell whatever
    /// the count (one fixed column per cell; see `pfslam::map::grid`).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub bins: usize,
    /// Lower edge of the binned window (m, world z): the bins split `[z_min_m, z_max_m)`
    /// evenly; the first also takes everything below, the last everything above. Default
    /// 0.64-3.04 m in 0.15 m bins: the car LiDAR's height (1.76 m) is the middle of a bin, so
    /// its near-level beams share one bin and a roof 0.1-0.2 m below them gets its own
    /// (chosen by measurement among 8 layouts, see docs/decisions/0015-height-bins.md).
    pub z_min_m: f64,
    /// Upper edge of the binned window (m, world z).
    pub z_max_m: f64,
    /// A bin is occupied at this probability (`None` = `[map.log_odds] occupied_prob`).
    /// Default 0.7 = one net hit: a bin sees only the beams at its height, so its evidence is
    /// sparse (a parked car's roof is hit by one or two scans of the dipping edge beams) and
    /// no longer diluted by passes at other heights.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub occupied_prob: Option<f64>,
}

impl Default for HeightOptions {
    fn default() -> Self {
        HeightOptions {
            enabled: true,
            bins: 16,
            z_min_m: 0.64,
            z_max_m: 3.04,
            occupied_prob: Some(0.7),
        }
    }
}

impl HeightOptions {
    /// Checks every field; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        if !(2..=grid::MAX_BINS).contains(&self.bins) {
            return Err("map.height.bins must lie in [2, 16]".into());
        }
        if !(self.z_min_m.is_finite() && self.z_max_m.is_finite() && self.z_min_m < self.z_max_m) {
            return Err("map.height: need finite z_min_m < z_max_m".into());
        }
        if self
            .occupied_prob
            .is_some_and(|p| !(p.is_finite() && (0.5..1.0).contains(&p)))
        {
            return Err("map.height.occupied_prob must lie in [0.5, 1)".into());
        }
        Ok(())
    }
}

impl Default for MapOptions {
    fn default() -> Self {
        MapOptions {
            resolution_m: 0.1,
            origin_x_m: 0.0,
            origin_y_m: 0.0,
            scan_step: 1,
            min_scan_travel_m: 0.0,
            min_scan_turn_deg: 1.0,
            log_odds: LogOddsParams::ese650(),
            scan: ScanOptions::default(),
            free_margin_m: 0.0,
            height: HeightOptions::default(),
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
        if !(self.min_scan_travel_m.is_finite() && (0.0..=100.0).contains(&self.min_scan_travel_m))
        {
            return Err("map.min_scan_travel_m must lie in [0, 100]".into());
        }
        if !(self.min_scan_turn_deg.is_finite() && (0.0..=180.0).contains(&self.min_scan_turn_deg))
        {
            return Err("map.min_scan_turn_deg must lie in [0, 180]".into());
        }
        self.log_odds.validate()?;
        self.scan.validate()?;
        self.height.validate()?;
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

    /// [`Self::insert`]'s first half: preprocesses `ranges_m`, places it at `world_from_body`
    /// and traces it into `out` ([`OccupancyGrid::trace_updates`]) without changing `grid`.
    pub fn trace(
        &mut self,
        grid: &OccupancyGrid,
        ranges_m: &[f32],
        world_from_body: &Pose2,
        out: &mut ScanUpdates,
    ) -> Result<InsertStats, MapError> {
        out.clear();
        self.projector.to_body(ranges_m, &mut self.body)?;
        to_world(&self.body, world_from_body, &mut self.world);
        grid.trace_updates(&self.world, &mut self.scratch, out)
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

/// Scans traced per batch by [`map_with_poses`]: enough to keep both phases parallel and the
/// tiles hot while a batch's updates are applied, few enough that the batch's update lists
/// stay small (~40 MB at 75 m rays, 0.1 m cells).
pub const MAP_BATCH_SCANS: usize = 64;

/// Scans per parallel task within a batch (one scratch per running task).
const MAP_TASK_SCANS: usize = 4;

/// The scans [`map_with_poses`] inserts, in order: every `scan_step`-th, thinned by the
/// motion filter (`min_scan_travel_m`, `min_scan_turn_deg`) when it is on. Scans without a
/// pose are kept (they are counted as such).
pub fn scans_to_map(recording: &Recording, poses: &Trajectory, opts: &MapOptions) -> Vec<usize> {
    let stepped = (0..recording.scans.len()).step_by(opts.scan_step);
    if opts.min_scan_travel_m <= 0.0 {
        return stepped.collect();
    }
    let turn_rad = opts.min_scan_turn_deg.to_radians();
    let mut last: Option<Pose2> = None;
    stepped
        .filter(|&k| {
            let Some(pose) = poses.pose_at(recording.scans.stamps_ns[k]) else {
                return true;
            };
            let keep = last.is_none_or(|l| {
                let d = l.between(&pose);
                d.translation_norm_m() >= opts.min_scan_travel_m
                    || (turn_rad > 0.0 && d.yaw_rad.abs() >= turn_rad)
            });
            if keep {
                last = Some(pose);
            }
            keep
        })
        .collect()
}

/// What tracing one scan of a batch gave.
enum Traced {
    /// No pose covers the scan's time.
    NoPose,
    /// Traced; its updates are in the scan's slot.
    Inserted,
    /// Preprocessing or tracing failed.
    Failed(MapError),
}

/// Maps a recording with known poses (`world_from_body` at each scan time, interpolated from
/// `poses`): every `opts.scan_step`-th scan inside the poses' time span is inserted, in order.
/// Returns the grid, the world-frame last inserted scan and counts.
///
/// Parallel and deterministic: batches of [`MAP_BATCH_SCANS`] scans are preprocessed and
/// traced in parallel ([`OccupancyGrid::trace_updates`]), then applied tile by tile in scan
/// order ([`OccupancyGrid::apply_updates`]), so the grid is bit for bit the one of inserting
/// the scans one after another with [`ScanInserter::insert`], whatever the thread count.
pub fn map_with_poses(
    recording: &Recording,
    poses: &Trajectory,
    opts: &MapOptions,
) -> Result<(OccupancyGrid, PlanarScan, MappingStats), MapError> {
    use rayon::prelude::*;
    let mut grid = OccupancyGrid::new(opts)?;
    let projector = ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &opts.scan)?;
    let mut stats = MappingStats::default();
    let scans: Vec<usize> = scans_to_map(recording, poses, opts);
    // Scratches (a mask of megabytes each) are reused: at most one per running task.
    let pool: std::sync::Mutex<Vec<ScanInserter>> = std::sync::Mutex::new(Vec::new());
    let mut slots: Vec<(ScanUpdates, Traced)> = Vec::new();
    let mut last = None;
    for batch in scans.chunks(MAP_BATCH_SCANS) {
        slots.resize_with(batch.len(), || (ScanUpdates::new(), Traced::NoPose));
        let grid_ref = &grid;
        slots[..batch.len()]
            .par_chunks_mut(MAP_TASK_SCANS)
            .zip(batch.par_chunks(MAP_TASK_SCANS))
            .for_each(|(out, ks)| {
                let mut ins = pool
                    .lock()
                    .ok()
                    .and_then(|mut p| p.pop())
                    .unwrap_or_else(|| ScanInserter::new(projector.clone()));
                for ((updates, traced), &k) in out.iter_mut().zip(ks) {
                    updates.clear();
                    *traced = match poses.pose_at(recording.scans.stamps_ns[k]) {
                        None => Traced::NoPose,
                        Some(pose) => {
                            ins.projector.aim(recording, k);
                            let ranges = recording.scans.ranges(k);
                            match ins.trace(grid_ref, ranges, &pose, updates) {
                                Ok(_) => Traced::Inserted,
                                Err(e) => Traced::Failed(e),
                            }
                        }
                    };
                }
                if let Ok(mut p) = pool.lock() {
                    p.push(ins);
                }
            });
        // In scan order: the first failure is the one sequential insertion would report.
        let mut done = Vec::with_capacity(batch.len());
        for ((updates, traced), &k) in slots.iter_mut().zip(batch) {
            match std::mem::replace(traced, Traced::NoPose) {
                Traced::NoPose => stats.scans_without_pose += 1,
                Traced::Failed(e) => return Err(e),
                Traced::Inserted => {
                    stats.scans_inserted += 1;
                    stats.rays += updates.stats().rays;
                    last = Some(k);
                    done.push(&*updates);
                }
            }
        }
        grid.apply_updates(&done);
    }
    let Some(k) = last else {
        return Err(MapError::NoScanInserted);
    };
    tracing::debug!(
        "map_with_poses: batch buffers {:.1} MB, {} scratches of {:.1} MB",
        slots.iter().map(|s| s.0.capacity_bytes()).sum::<usize>() as f64 / 1e6,
        pool.lock().map_or(0, |p| p.len()),
        pool.lock()
            .map_or(0, |p| p.first().map_or(0, |i| i.scratch.memory_bytes())) as f64
            / 1e6
    );
    // The last inserted scan in the world frame (cheap to redo once).
    let mut ins = ScanInserter::new(projector);
    ins.projector.aim(recording, k);
    if let Some(pose) = poses.pose_at(recording.scans.stamps_ns[k]) {
        ins.projector
            .to_body(recording.scans.ranges(k), &mut ins.body)?;
        to_world(&ins.body, &pose, &mut ins.world);
    }
    Ok((grid, ins.world, stats))
}

#[cfg(test)]
mod tests;
