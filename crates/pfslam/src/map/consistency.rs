//! How well a trajectory's scans agree with the map built from them: the share of scan
//! returns that land in cells the map calls free. A wrong loop closure lays one corridor
//! over another, and the walls seen from one pass then fall into the other's free space;
//! drift alone blurs walls but leaves few returns in free cells.

use super::{CellState, MapError, OccupancyGrid, PlanarScan, ScanOptions, ScanProjector, to_world};
use crate::geometry::Trajectory;
use crate::sensors::Recording;

/// Returns scored and those landing in free cells.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Consistency {
    /// Returns (hits) looked up in the map.
    pub returns: usize,
    /// Of those, returns in cells the map calls free.
    pub in_free: usize,
}

impl Consistency {
    /// `in_free / returns` (0 without returns).
    pub fn free_share(&self) -> f64 {
        if self.returns == 0 {
            0.0
        } else {
            self.in_free as f64 / self.returns as f64
        }
    }
}

/// Scores every `scan_step`-th scan of `recording` posed by `poses` against `grid`.
pub fn consistency(
    recording: &Recording,
    poses: &Trajectory,
    grid: &OccupancyGrid,
    scan_opts: &ScanOptions,
    scan_step: usize,
) -> Result<Consistency, MapError> {
    let mut projector =
        ScanProjector::new(&recording.lidar, &recording.body_from_lidar, scan_opts)?;
    let (mut body, mut world) = (PlanarScan::default(), PlanarScan::default());
    let mut out = Consistency::default();
    for k in (0..recording.scans.len()).step_by(scan_step.max(1)) {
        let Some(pose) = poses.pose_at(recording.scans.stamps_ns[k]) else {
            continue;
        };
        projector.aim(recording, k);
        projector.to_body(recording.scans.ranges(k), &mut body)?;
        to_world(&body, &pose, &mut world);
        for p in world.points.iter().filter(|p| p.hit) {
            out.returns += 1;
            if grid.state(grid.cell_of(p.x_m, p.y_m)) == CellState::Free {
                out.in_free += 1;
            }
        }
    }
    Ok(out)
}
