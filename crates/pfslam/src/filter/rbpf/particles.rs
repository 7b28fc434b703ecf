//! The particle set and its update: predict, match, map, reweight, resample.

use super::*;
use crate::filter::resample;
use crate::filter::rng::{CHUNK_PARTICLES, FilterRng};
use crate::filter::weights;
use crate::geometry::{Pose2, wrap_angle};
use crate::map::{InsertScratch, MapError, OccupancyGrid, PlanarScan, to_world};
use crate::matching::nearest_occupied::{
    MatchPrior, ObservationModel, SearchParams, match_in_own_map,
};
use rand::RngExt;
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// One particle: pose, own map and trajectory node.
#[derive(Debug, Clone)]
pub struct RbParticle {
    /// Current pose (at the last update, before the odometry since).
    pub pose: Pose2,
    /// The particle's own map.
    pub map: OccupancyGrid,
    /// The last node of its trajectory.
    pub node: Arc<PathNode>,
}

/// Per-chunk state: the chunk's random stream.
#[derive(Debug, Clone)]
struct ChunkState {
    rng: Xoshiro256PlusPlus,
}

/// Map-insertion buffers, one per worker thread (filled on first use). A clone starts empty:
/// buffers hold no state that matters.
#[derive(Debug, Default)]
struct InsertBuffers(Vec<std::sync::Mutex<(PlanarScan, InsertScratch)>>);

impl Clone for InsertBuffers {
    fn clone(&self) -> Self {
        InsertBuffers::default()
    }
}

/// Number of distinct tiles held by `maps` (shared tiles counted once).
pub fn distinct_tiles<'a, I: IntoIterator<Item = &'a OccupancyGrid>>(maps: I) -> usize {
    let mut ids: Vec<usize> = maps.into_iter().flat_map(|m| m.tile_ids()).collect();
    ids.sort_unstable();
    ids.dedup();
    ids.len()
}

/// Memory figures of the particles' maps at the end of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct MapMemory {
    /// Distinct tiles over all particles.
    pub distinct_tiles: usize,
    /// Sum of every particle's tile count (what unshared maps would hold).
    pub total_tiles: usize,
    /// Bytes of the distinct tiles.
    pub distinct_bytes: usize,
}

/// The filter's state, exposed for tests: particles, weights, random streams.
#[derive(Debug, Clone)]
pub struct Rbpf {
    /// The particles.
    pub particles: Vec<RbParticle>,
    /// Normalised weights.
    pub weights: Vec<f64>,
    chunks: Vec<ChunkState>,
    scratch: InsertBuffers,
    master: Xoshiro256PlusPlus,
    options: RbpfOptions,
    model: ObservationModel,
    search: SearchParams,
    ancestors: Vec<usize>,
    lls: Vec<f64>,
}

/// One scan's input to [`Rbpf::update`].
#[derive(Debug, Clone, Copy)]
pub struct UpdateScan<'a> {
    /// The index of the processed scan (recorded in the path nodes).
    pub scan_index: usize,
    /// The odometry pose at the scan.
    pub odom_pose: Pose2,
    /// The odometry increment since the last update, in the old body frame.
    pub odom_delta: &'a Pose2,
    /// The points matched against each particle's map (body frame, m).
    pub match_points_m: &'a [[f64; 2]],
    /// The scan mapped into every particle's map (body frame).
    pub body_scan: &'a PlanarScan,
    /// The first scan: only mapped (nothing to match against yet).
    pub map_only: bool,
}

/// What one update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RbpfUpdate {
    /// Neff after reweighting.
    pub neff: f64,
    /// Whether the particles were resampled.
    pub resampled: bool,
    /// Mean per-point log-likelihood of the best particle's match.
    pub best_ll_per_point: f64,
    /// Wall time of motion sampling and matching (s).
    pub match_s: f64,
    /// Wall time of the map updates (s).
    pub map_s: f64,
}

impl Rbpf {
    /// `n` particles at `start`, each with a clone of `map` (sharing its tiles), the first
    /// node at processed scan 0 with odometry pose `odom`.
    pub fn new(
        n: usize,
        start: Pose2,
        odom: Pose2,
        map: OccupancyGrid,
        options: &RbpfOptions,
        seed: u64,
    ) -> Self {
        let res = map.limits().resolution_m();
        let root = Arc::new(PathNode {
            pose: start,
            odom,
            scan: 0,
            parent: None,
        });
        let rng = FilterRng::new(seed, n);
        Rbpf {
            particles: (0..n)
                .map(|_| RbParticle {
                    pose: start,
                    map: map.clone(),
                    node: root.clone(),
                })
                .collect(),
            weights: vec![1.0 / n.max(1) as f64; n],
            chunks: rng
                .chunks
                .into_iter()
                .map(|rng| ChunkState { rng })
                .collect(),
            scratch: InsertBuffers::default(),
            master: rng.master,
            model: options.observation(res),
            search: options.search_params(res),
            options: options.clone(),
            ancestors: Vec::with_capacity(n),
            lls: vec![0.0; n],
        }
    }

    /// Index of the heaviest particle (lowest index on ties).
    pub fn best(&self) -> usize {
        let mut best = 0;
        for (i, w) in self.weights.iter().enumerate() {
            if *w > self.weights[best] {
                best = i;
            }
        }
        best
    }

    /// One update with `input` (see [`UpdateScan`]): motion, matching, reweighting, mapping
    /// the scan into every particle's map, new path nodes, selective resampling by `method`.
    pub fn update(
        &mut self,
        input: &UpdateScan<'_>,
        method: resample::ResampleMethod,
    ) -> Result<RbpfUpdate, MapError> {
        let first = input.map_only;
        self.set_prior(input.odom_delta);
        let n = self.particles.len();
        let t = Instant::now();
        let jitters = if first {
            Vec::new()
        } else {
            self.move_particles(input.odom_delta)
        };
        let map_thread_s = self.match_and_map(input, &jitters)?;
        let elapsed = t.elapsed().as_secs_f64();
        // Wall times of the two parts: the pass's wall time split by the threads' time
        // spent mapping (an estimate: the parts now overlap).
        let threads = rayon::current_num_threads().max(1);
        let map_s = (map_thread_s / threads as f64).min(elapsed);
        let match_s = elapsed - map_s;
        if first {
            return Ok(RbpfUpdate {
                neff: n as f64,
                resampled: false,
                best_ll_per_point: 0.0,
                match_s,
                map_s,
            });
        }
        weights::update_log_space(
            &mut self.weights,
            &self.lls,
            self.options.weight_temperature,
        );
        let neff = weights::neff(&self.weights);
        let best = self.best();
        let best_ll_per_point = self.lls[best] / input.match_points_m.len().max(1) as f64;
        let resampled = neff < self.options.resample_threshold * n as f64;
        if resampled {
            resample::resample(&self.weights, method, &mut self.master, &mut self.ancestors);
            let old = std::mem::take(&mut self.particles);
            self.particles = self.ancestors.iter().map(|&a| old[a].clone()).collect();
            self.weights.iter_mut().for_each(|w| *w = 1.0 / n as f64);
        }
        Ok(RbpfUpdate {
            neff,
            resampled,
            best_ll_per_point,
            match_s,
            map_s,
        })
    }

    /// The matcher's prior for an update after the odometry moved by `delta`: the motion
    /// model's sigmas for it, floored (`[filter.rbpf.search]`).
    fn set_prior(&mut self, delta: &Pose2) {
        let noise = self.options.noise();
        let o = &self.options.search;
        let [srr, str_, srt, stt] = noise;
        let (d, a) = (delta.translation_norm_m(), delta.yaw_rad.abs());
        let sxy = (srr * d + str_ * a).max(o.prior_min_xy_m);
        let syaw = (stt * a + srt * d).max(o.prior_min_yaw_deg.to_radians());
        self.search.prior = Some(MatchPrior {
            inv_var_xy: 1.0 / (sxy * sxy),
            inv_var_yaw: 1.0 / (syaw * syaw),
        });
    }

    /// Moves every particle by `delta` to its noise-free prediction; returns the jitter
    /// each adds to its match, drawn now per chunk from the chunk's stream in particle order
    /// (cheap, and the same for any thread count).
    fn move_particles(&mut self, delta: &Pose2) -> Vec<[f64; 3]> {
        let o = &self.options.search;
        let jitter_sigma = [o.jitter_xy_m, o.jitter_xy_m, o.jitter_yaw_deg.to_radians()];
        let mut jitters: Vec<[f64; 3]> = Vec::new();
        for (parts, st) in self
            .particles
            .chunks_mut(CHUNK_PARTICLES)
            .zip(self.chunks.iter_mut())
        {
            for p in parts.iter_mut() {
                p.pose = p.pose.compose(delta);
                p.pose.yaw_rad = wrap_angle(p.pose.yaw_rad);
                jitters.push(jitter_sigma.map(|s| s * st.rng.sample::<f64, _>(StandardNormal)));
            }
        }
        jitters
    }

    /// Every particle on its own (the threads balance whatever the particle count; 5
    /// chunks of 40 particles would split 3:2 over two threads): matched in its map (unless
    /// `map_only`), moved by its jitter, then the scan mapped into it, in one pass (a
    /// particle's match reads only its own map, and copy-on-write tiles keep the others'
    /// maps apart, so the same maps as matching all first). Mapped before resampling, so
    /// copies share the tiles this update wrote. Each worker thread has its own insertion
    /// scratch (a mask of megabytes: never per particle); the scratch does not affect
    /// results. Returns the threads' seconds spent mapping; the first error in particle
    /// order.
    fn match_and_map(
        &mut self,
        input: &UpdateScan<'_>,
        jitters: &[[f64; 3]],
    ) -> Result<f64, MapError> {
        let first = input.map_only;
        let (points, body) = (input.match_points_m, input.body_scan);
        let threads = rayon::current_num_threads().max(1);
        if self.scratch.0.len() < threads {
            self.scratch.0.resize_with(threads, Default::default);
        }
        let (model, search, scratch) = (&self.model, &self.search, &self.scratch.0);
        let results: Vec<Result<f64, MapError>> = self
            .particles
            .par_iter_mut()
            .zip(self.lls.par_iter_mut())
            .enumerate()
            .with_max_len(1)
            .map(|(i, (p, ll))| {
                if !first {
                    let (mut pose, l) = match_in_own_map(&p.map, model, points, &p.pose, search);
                    if let Some(j) = jitters.get(i) {
                        pose = Pose2::new(
                            pose.x_m + j[0],
                            pose.y_m + j[1],
                            wrap_angle(pose.yaw_rad + j[2]),
                        );
                    }
                    p.pose = pose;
                    *ll = l;
                }
                let t_map = Instant::now();
                let slot = rayon::current_thread_index().unwrap_or(0) % scratch.len();
                let mut guard = scratch[slot]
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                let (world, insert) = &mut *guard;
                to_world(body, &p.pose, world);
                p.map.insert_scan(world, insert)?;
                p.node = Arc::new(PathNode {
                    pose: p.pose,
                    odom: input.odom_pose,
                    scan: input.scan_index,
                    parent: Some(p.node.clone()),
                });
                Ok(t_map.elapsed().as_secs_f64())
            })
            .collect();
        let mut map_thread_s = 0.0;
        for r in results {
            map_thread_s += r?;
        }
        Ok(map_thread_s)
    }

    /// Memory held by the particles' maps.
    pub fn map_memory(&self) -> MapMemory {
        let distinct = distinct_tiles(self.particles.iter().map(|p| &p.map));
        MapMemory {
            distinct_tiles: distinct,
            total_tiles: self.particles.iter().map(|p| p.map.tile_count()).sum(),
            distinct_bytes: distinct * crate::map::TILE_BYTES,
        }
    }
}
