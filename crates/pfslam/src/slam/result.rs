//! What a run produced and reports: the trajectory and map, statistics, stage timings and
//! progress events.

use super::*;

/// Wall-clock seconds spent per stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageTimings {
    /// Ranges -> body-frame points.
    pub preprocess_s: f64,
    /// Motion model sampling.
    pub predict_s: f64,
    /// Correlation search and reweighting.
    pub correlate_s: f64,
    /// Of `correlate_s`: the likelihood fields (`scan_match`).
    pub field_s: f64,
    /// Resampling.
    pub resample_s: f64,
    /// Map insertion.
    pub map_update_s: f64,
    /// The whole loop.
    pub total_s: f64,
}

/// Counts and statistics of a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SlamStats {
    /// Particles.
    pub particles: usize,
    /// The filter mode that ran (`auto` resolved).
    pub mode: FilterMode,
    /// Seed of the random streams.
    pub seed: u64,
    /// Scans in the recording.
    pub scans_total: usize,
    /// Scans with a pose in the output (inside the odometry's time span).
    pub scans_processed: usize,
    /// Scans skipped because the odometry does not cover them.
    pub scans_skipped: usize,
    /// Odometry steps predicted.
    pub odometry_steps: usize,
    /// Update steps (correlation + reweight + map).
    pub updates: usize,
    /// Resampling events.
    pub resamples: usize,
    /// Neff after reweighting: minimum over updates.
    pub neff_min: f64,
    /// Neff after reweighting: mean over updates.
    pub neff_mean: f64,
    /// Neff after reweighting at the last update.
    pub neff_last: f64,
    /// Mean correlation score (occupied cells hit) of the best particle.
    pub best_score_mean: f64,
    /// Time per stage.
    pub timings: StageTimings,
    /// Tiles held by the particles' maps at the end (`rbpf` mode only).
    pub map_memory: Option<crate::filter::rbpf::MapMemory>,
}

impl SlamStats {
    /// Turns the sums over updates into means (Neff = the particle count without updates).
    pub(crate) fn finish_means(&mut self, neff_sum: f64, score_sum: f64) {
        if self.updates > 0 {
            self.neff_mean = neff_sum / self.updates as f64;
            self.best_score_mean = score_sum / self.updates as f64;
        } else {
            let n = self.particles as f64;
            (self.neff_min, self.neff_mean, self.neff_last) = (n, n, n);
        }
    }
}

/// What a run produced.
#[derive(Debug, Clone)]
pub struct SlamResult {
    /// The best particle's pose at every processed scan (odometry composed onto the last
    /// estimate between updates).
    pub trajectory: Vec<StampedPose2>,
    /// The odometry pose at every processed scan (dead reckoning, same frame).
    pub dead_reckoning: Vec<StampedPose2>,
    /// The final map.
    pub map: OccupancyGrid,
    /// Counts, Neff and timings.
    pub stats: SlamStats,
}

/// Progress reports of [`run_slam`].
#[derive(Debug)]
pub enum SlamEvent<'a> {
    /// `done` of `total` scans handled.
    Progress {
        /// Scans handled.
        done: usize,
        /// Scans in the recording.
        total: usize,
    },
    /// A filter update at the scan stamped `stamp_ns`: every particle's `world_from_body`
    /// pose, and the best particle's map where the mode keeps one per particle (`rbpf`).
    Update {
        /// The scan's stamp (ns).
        stamp_ns: i64,
        /// The particles' poses after the update.
        particles: &'a [crate::geometry::Pose2],
        /// The best particle's map, when it is at hand without work.
        map: Option<&'a OccupancyGrid>,
    },
    /// The estimate of the scan just handled (the best particle now: the final trajectory,
    /// chosen at the end, may differ).
    Pose(StampedPose2),
    /// A map snapshot after `scan_index` scans (every `filter.snapshot_every_scans`).
    Snapshot {
        /// Number of scans handled so far.
        scans_done: usize,
        /// The current map.
        map: &'a OccupancyGrid,
        /// The trajectory so far.
        trajectory: &'a [StampedPose2],
    },
}
