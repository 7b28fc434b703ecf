//! How the filter keeps its maps: the [`MapPolicy`] trait and the seeds' single map
//! written by the best particle.

use super::*;

/// How maps are kept: the seeds' single map written by the best particle, or one map per
/// particle. The filter sees maps only through this trait.
pub trait MapPolicy: ParticleMaps {
    /// Integrates the body-frame scan at the particles' poses (`best` is the heaviest).
    fn integrate(
        &mut self,
        poses: &[Pose2],
        best: usize,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError>;
    /// Integrates a scan between updates at `world_from_body` (the output pose: the last
    /// estimate moved by odometry) into every map.
    fn integrate_at(
        &mut self,
        world_from_body: &Pose2,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError>;
    /// The particles were resampled: particle `k` is now a copy of old particle
    /// `ancestors[k]`.
    fn resampled(&mut self, ancestors: &[usize]);
    /// The map to report for particle `best`.
    fn map_for_output(&self, best: usize) -> &OccupancyGrid;
    /// Completes integrations a policy deferred (the loop calls it before every read of the
    /// maps). The default defers nothing.
    fn flush(&mut self) -> Result<(), MapError> {
        Ok(())
    }
    /// Logs the cells of the output map whose observed or wall status (`threshold`,
    /// fixed-point log-odds) insertions change, for [`Self::take_changes`]. The default logs
    /// nothing.
    fn log_changes(&mut self, _threshold: i16) {}
    /// Hands the map of particle `best` and the changes logged since the last call to
    /// `use_changes` (`None` when they are not known: nothing logged, or an insertion that
    /// did not log) and clears the log.
    fn take_changes<R>(
        &mut self,
        best: usize,
        use_changes: impl FnOnce(&OccupancyGrid, Option<&[CellChange]>) -> R,
    ) -> R {
        use_changes(self.map_for_output(best), None)
    }
}

/// The seeds' policy: one map, updated with the best particle's pose.
///
/// Scans are queued (in the world frame) and inserted at [`MapPolicy::flush`]: the rays of
/// the scans between two updates are cut into one run of about equal work per thread (a scan
/// may be split between two), traced in parallel and applied in scan order, tile by tile in
/// parallel, which leaves the grid exactly as inserting them one by one would: planar scans
/// as one batch ([`OccupancyGrid::insert_planar_batch`]: one mask with a mark per scan, each
/// cell visited once), scans with heights on a grid with bins scan by scan
/// ([`OccupancyGrid::trace_updates_part`] / [`OccupancyGrid::apply_updates`]). `grid` is
/// complete after a flush.
#[derive(Debug, Clone)]
pub struct BestParticleMap {
    /// The map.
    pub grid: OccupancyGrid,
    /// One scratch per tracing task (a mask of megabytes each: reused, never per scan).
    scratches: Vec<InsertScratch>,
    /// The same for batches of planar scans ([`OccupancyGrid::insert_planar_batch`]).
    batches: Vec<BatchScratch>,
    /// With [`Self::log_changes`]: the cells changed since the log was last taken, and
    /// whether the log is complete (false after an insertion that does not log).
    log: Option<(ChangeLog, bool)>,
    /// Queued world-frame scans: the first `queued` are pending (the rest keep allocations).
    pending: Vec<PlanarScan>,
    queued: usize,
    traced: Vec<ScanUpdates>,
    /// Where a scan cut between two threads may be cut, and the work before each place
    /// ([`split_rays`], [`OccupancyGrid::trace_cuts`]).
    weights: Vec<(usize, u64)>,
}

impl BestParticleMap {
    /// A policy around an (empty) grid.
    pub fn new(grid: OccupancyGrid) -> Self {
        BestParticleMap {
            grid,
            scratches: vec![InsertScratch::new()],
            batches: Vec::new(),
            log: None,
            pending: Vec::new(),
            queued: 0,
            traced: Vec::new(),
            weights: Vec::new(),
        }
    }
}

impl ParticleMaps for BestParticleMap {
    type Map = OccupancyGrid;
    fn map_of(&self, _i: usize) -> &OccupancyGrid {
        &self.grid
    }
}

impl MapPolicy for BestParticleMap {
    fn log_changes(&mut self, threshold: i16) {
        self.log = Some((
            ChangeLog {
                threshold,
                changes: Vec::new(),
            },
            true,
        ));
    }
    fn take_changes<R>(
        &mut self,
        _best: usize,
        use_changes: impl FnOnce(&OccupancyGrid, Option<&[CellChange]>) -> R,
    ) -> R {
        match &mut self.log {
            Some((log, complete)) => {
                let r = use_changes(&self.grid, complete.then_some(&log.changes[..]));
                log.changes.clear();
                *complete = true;
                r
            }
            None => use_changes(&self.grid, None),
        }
    }
    fn integrate(
        &mut self,
        poses: &[Pose2],
        best: usize,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError> {
        let pose = poses.get(best).copied().unwrap_or_default();
        if self.pending.len() <= self.queued {
            self.pending.push(PlanarScan::default());
        }
        to_world(body_scan, &pose, &mut self.pending[self.queued]);
        self.queued += 1;
        Ok(())
    }
    fn integrate_at(
        &mut self,
        world_from_body: &Pose2,
        body_scan: &PlanarScan,
    ) -> Result<(), MapError> {
        self.integrate(std::slice::from_ref(world_from_body), 0, body_scan)
    }
    fn resampled(&mut self, _ancestors: &[usize]) {}
    fn map_for_output(&self, _best: usize) -> &OccupancyGrid {
        &self.grid
    }
    fn flush(&mut self) -> Result<(), MapError> {
        let n = std::mem::take(&mut self.queued);
        if n == 0 {
            return Ok(());
        }
        let threads = rayon::current_num_threads().max(1);
        if n == 1 && threads == 1 && self.log.is_none() {
            self.grid
                .insert_scan(&self.pending[0], &mut self.scratches[0])?;
            return Ok(());
        }
        // Run on a pool thread: one hand-over to the pool per flush instead of one per
        // parallel phase (tracing, applying).
        if self.pending[..n].iter().any(|s| self.grid.uses_heights(s)) {
            // Not logged: whoever reads the log starts over.
            if let Some(log) = &mut self.log {
                log.1 = false;
            }
            rayon::scope(|_| self.flush_queued(n, threads))
        } else {
            let Self {
                grid,
                pending,
                batches,
                weights,
                log,
                ..
            } = self;
            let log = log.as_mut().map(|l| &mut l.0);
            rayon::scope(|_| {
                grid.insert_planar_batch(&pending[..n], threads, batches, weights, log)
            })
        }
    }
}

impl BestParticleMap {
    /// [`MapPolicy::flush`] of the `n` queued scans on `threads` threads, scan by scan (scans
    /// with heights on a grid with bins).
    fn flush_queued(&mut self, n: usize, threads: usize) -> Result<(), MapError> {
        // The scans' rays, in order, cut into one contiguous run per thread with about the
        // same number of cells to walk (a scan may be cut in two: its pieces are applied as
        // the whole scan). Tracing reads the grid's geometry only, so the runs are
        // independent; the updates are applied in scan order.
        let pieces = split_rays(&self.grid, &self.pending[..n], threads, &mut self.weights);
        if self.scratches.len() < pieces.len() {
            self.scratches.resize_with(pieces.len(), InsertScratch::new);
        }
        let total: usize = pieces.iter().map(Vec::len).sum();
        if self.traced.len() < total {
            self.traced.resize_with(total, ScanUpdates::new);
        }
        let mut outs: Vec<&mut [ScanUpdates]> = Vec::with_capacity(pieces.len());
        let mut rest = &mut self.traced[..total];
        for run in &pieces {
            let (head, tail) = rest.split_at_mut(run.len());
            outs.push(head);
            rest = tail;
        }
        let grid = &self.grid;
        let scans = &self.pending[..n];
        let traced: Result<(), MapError> = outs
            .into_par_iter()
            .zip(pieces.par_iter())
            .zip(self.scratches.par_iter_mut())
            .try_for_each(|((out, run), scratch)| {
                for (updates, (k, rays)) in out.iter_mut().zip(run) {
                    grid.trace_updates_part(&scans[*k], rays.clone(), scratch, updates)?;
                }
                Ok(())
            });
        traced?;
        let updates: Vec<&ScanUpdates> = self.traced[..total].iter().collect();
        self.grid.apply_updates(&updates);
        Ok(())
    }
}
