//! The particle filter of the seeds: N pose hypotheses predicted with a noisy motion model,
//! weighted by map correlation (best of a small offset search), resampled when the effective
//! sample size drops.
//!
//! - [`particles`]: the weighted set; [`weights`]: log-space softmax and Neff;
//!   [`resample`]: stratified, systematic and multinomial resampling;
//!   [`rng`]: per-chunk random streams, so results do not depend on the thread count;
//!   [`scan_match`]: the scan-matching mode's options; [`rbpf`]: the Rao-Blackwellised
//!   mode (options, particles with their own maps, paths);
//! - the scan matchers the modes weigh and move particles with are in [`crate::matching`]:
//!   the seeds' map correlation ([`crate::matching::correlation`]), the scan-matching mode's
//!   likelihood field and proposal ([`crate::matching::likelihood_field`]), the
//!   Rao-Blackwellised mode's match in a particle's own map
//!   ([`crate::matching::nearest_occupied`]);
//! - [`ParticleFilter`] ties them together; the map is reached only through
//!   [`ParticleMaps`], so one shared map (the seeds) and per-particle maps fit the same code.

pub mod odometry;
pub mod particles;
pub mod prediction;
pub mod rbpf;
pub mod resample;
pub mod rng;
pub mod scan_match;
pub mod weights;

use crate::geometry::{Pose2, StampedPose2};
use crate::matching::correlation::{
    self, CorrelationScratch, CorrelationSearch, OccupancyLookup, ScanMatch,
};
use crate::matching::likelihood_field;
use crate::motion::odometry_model::OdometryModelOptions;
use particles::ParticleSet;
use prediction::{MotionModel, PredictionModel};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use resample::ResampleMethod;
use rng::{CHUNK_PARTICLES, FilterRng};
use serde::{Deserialize, Serialize};

/// Below this many particle moves (particles x odometry steps) the chunks run on the calling
/// thread: cheaper than a round trip through the thread pool, same result.
const SERIAL_BELOW_PARTICLE_STEPS: usize = 2048;

/// Which filter runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FilterMode {
    /// The seeds: hit-count correlation over a small offset grid, best offset taken.
    Seed,
    /// Likelihood-field scan matching with an odometry prior (`[filter.scan_match]`).
    ScanMatch,
    /// Rao-Blackwellised: per-particle maps, scan matching against each particle's own map,
    /// output the final best particle's ancestral path (`[filter.rbpf]`).
    Rbpf,
    /// Chosen from the recording by [`FilterMode::resolve`]: `rbpf` for a level LiDAR
    /// (a planar indoor robot: its scans see walls, its wheel odometry needs the
    /// per-particle maps' freedom), `scan_match` for a tilted or moving LiDAR (the car, the
    /// humanoid: the scan surface changes height with range, so walls are seen at different
    /// spots from pose to pose, and the tight odometry prior of `scan_match` holds it).
    #[default]
    Auto,
}

/// A LiDAR whose scan axis is within this angle of the body's vertical counts as level.
const LEVEL_LIDAR_MAX_TILT_RAD: f64 = 1.0 * std::f64::consts::PI / 180.0;

impl FilterMode {
    /// The mode that runs on `recording`: `self`, or for [`FilterMode::Auto`] the choice
    /// described there.
    pub fn resolve(self, recording: &crate::sensors::Recording) -> FilterMode {
        if self != FilterMode::Auto {
            return self;
        }
        // Tilt of the scan plane: angle between the LiDAR's z axis and the body's.
        let lidar_z_in_body = recording.body_from_lidar.rotation.column(2).into_owned();
        let cos_tilt = lidar_z_in_body.z / lidar_z_in_body.norm().max(f64::MIN_POSITIVE);
        let level = cos_tilt.clamp(-1.0, 1.0).abs().acos() <= LEVEL_LIDAR_MAX_TILT_RAD;
        if level && recording.body_from_lidar_per_scan.is_none() {
            FilterMode::Rbpf
        } else {
            FilterMode::ScanMatch
        }
    }
}

/// Options of the filter component (`[filter]` in the configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FilterOptions {
    /// "auto" (default: "rbpf" when the LiDAR is mounted level, "scan_match" when it is
    /// tilted or moves on the body, as the car's and the humanoid's), "scan_match"
    /// (likelihood field + scan-matching proposal with a tight odometry prior, see
    /// `[filter.scan_match]`), "seed" (the seeds' map correlation; the keys below up to
    /// `temperature` and `resample_threshold` apply to it) or "rbpf" (Rao-Blackwellised:
    /// per-particle maps, see `[filter.rbpf]`; uses `particles` and `resample_method`).
    pub mode: FilterMode,
    /// Number of particles (the UCSD seed's best runs use 40, the ESE650 seed 100).
    pub particles: usize,
    /// Update (correlate, reweight, map) with every k-th scan; the seeds use 5.
    pub update_every_scans: usize,
    /// Also insert the scans between updates into the map, at the output pose (the last
    /// estimate moved by odometry). The seeds map only at updates (false).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub map_between_updates: bool,
    /// Half-width of the x/y correlation search in cells (4 = the seeds' 9x9 grid).
    pub xy_search_radius_cells: u32,
    /// Yaw offsets tried by the correlation search (deg); should contain 0.
    pub yaw_offsets_deg: Vec<f64>,
    /// Hits an x/y search offset must gain per squared cell of offset to be preferred over the
    /// particle's own pose (0 = the seeds' plain maximum).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub offset_penalty_hits_per_cell2: f64,
    /// A scan point counts as a hit when an occupied cell lies within this many cells of it
    /// (0 = the seeds: its own cell).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub dilation_cells: u32,
    /// Move each particle to its best search offset (true: the particle takes the offset's
    /// pose) or only score it with the best offset's correlation (false: the seeds'
    /// `mapCorrelation` maximum as the weight, the pose stays).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub move_to_best_offset: bool,
    /// Divisor of the correlations in the softmax (1 = UCSD seed, 10 = ESE650 seed).
    pub temperature: f64,
    /// Resample when Neff < this fraction of the particle count (ESE650 seed: 0.1).
    pub resample_threshold: f64,
    /// Resampling scheme: "stratified" (ESE650 seed), "systematic" or "multinomial".
    pub resample_method: ResampleMethod,
    /// Write a map snapshot every this many scans (0 = never; the UCSD seed: 10000).
    pub snapshot_every_scans: usize,
    /// Prediction: "velocity" (UCSD seed; noise in `[motion.noise]`) or "odometry" (relative
    /// motion between odometry poses; noise in `[filter.odometry_model]`).
    pub motion_model: PredictionModel,
    /// The odometry model when `motion_model = "odometry"` ("ese650": the ESE650 seed's
    /// sigmas `[0.005, 0.005, 0.005]`; "thrun": four alphas).
    pub odometry_model: OdometryModelOptions,
    /// The scan-matching mode's options.
    pub scan_match: scan_match::ScanMatchOptions,
    /// The Rao-Blackwellised mode's options.
    pub rbpf: rbpf::RbpfOptions,
}

impl Default for FilterOptions {
    fn default() -> Self {
        FilterOptions {
            particles: 40,
            update_every_scans: 5,
            map_between_updates: false,
            xy_search_radius_cells: 4,
            yaw_offsets_deg: vec![-0.5, 0.0, 0.5],
            offset_penalty_hits_per_cell2: 0.0,
            dilation_cells: 0,
            move_to_best_offset: true,
            temperature: 10.0,
            resample_threshold: 0.1,
            resample_method: ResampleMethod::Stratified,
            snapshot_every_scans: 10_000,
            motion_model: PredictionModel::Velocity,
            odometry_model: OdometryModelOptions::ese650(),
            mode: FilterMode::default(),
            scan_match: scan_match::ScanMatchOptions::default(),
            rbpf: rbpf::RbpfOptions::default(),
        }
    }
}

/// Errors of the filter.
#[derive(Debug, thiserror::Error)]
pub enum FilterError {
    /// An option is out of range.
    #[error("invalid filter option {name}: {message}")]
    InvalidOption {
        /// The option's key in `[filter]`.
        name: &'static str,
        /// What is wrong.
        message: String,
    },
}

impl FilterOptions {
    /// Checks ranges; returns the first problem.
    pub fn validate(&self) -> Result<(), FilterError> {
        let bad = |name, message: &str| {
            Err(FilterError::InvalidOption {
                name,
                message: message.to_string(),
            })
        };
        if self.particles == 0 {
            return bad("particles", "must be at least 1");
        }
        if self.update_every_scans == 0 {
            return bad("update_every_scans", "must be at least 1");
        }
        if self.dilation_cells > 8 {
            return bad("dilation_cells", "must be at most 8");
        }
        if self.xy_search_radius_cells > 64 {
            return bad("xy_search_radius_cells", "must be at most 64");
        }
        if self.yaw_offsets_deg.iter().any(|d| !d.is_finite()) {
            return bad("yaw_offsets_deg", "must be finite");
        }
        if !(self.offset_penalty_hits_per_cell2.is_finite()
            && self.offset_penalty_hits_per_cell2 >= 0.0)
        {
            return bad("offset_penalty_hits_per_cell2", "must be finite and >= 0");
        }
        if !(self.temperature.is_finite() && self.temperature > 0.0) {
            return bad("temperature", "must be positive and finite");
        }
        if !(0.0..=1.0).contains(&self.resample_threshold) {
            return bad("resample_threshold", "must lie in [0, 1]");
        }
        self.scan_match
            .validate()
            .map_err(|message| FilterError::InvalidOption {
                name: "scan_match",
                message,
            })?;
        self.rbpf
            .validate()
            .map_err(|message| FilterError::InvalidOption {
                name: "rbpf",
                message,
            })?;
        Ok(())
    }

    /// The correlation search these options describe.
    pub fn search(&self) -> CorrelationSearch {
        CorrelationSearch {
            xy_radius_cells: self.xy_search_radius_cells as i32,
            yaw_offsets_rad: self
                .yaw_offsets_deg
                .iter()
                .map(|d| d.to_radians())
                .collect(),
            offset_penalty_hits_per_cell2: self.offset_penalty_hits_per_cell2,
            dilation_cells: self.dilation_cells as i32,
        }
    }
}

/// The map each particle is weighed against. One shared map (the seeds) returns the same map
/// for every particle; per-particle maps return each particle's own.
pub trait ParticleMaps: Sync {
    /// The map type.
    type Map: OccupancyLookup + ?Sized;
    /// The map of particle `i`.
    fn map_of(&self, i: usize) -> &Self::Map;
}

/// One map for all particles (the seeds' behaviour).
#[derive(Debug, Clone, Copy)]
pub struct SharedMap<'a, M: ?Sized>(pub &'a M);

impl<M: OccupancyLookup + ?Sized> ParticleMaps for SharedMap<'_, M> {
    type Map = M;
    fn map_of(&self, _i: usize) -> &M {
        self.0
    }
}

/// What one update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateReport {
    /// Neff after reweighting, before any resampling.
    pub neff: f64,
    /// Whether the particles were resampled.
    pub resampled: bool,
    /// The heaviest particle after the update.
    pub best: usize,
    /// Its correlation score.
    pub best_score: u32,
}

/// The particle filter state: particles, random streams and reusable buffers.
#[derive(Debug, Clone)]
pub struct ParticleFilter {
    /// The particles.
    pub particles: ParticleSet,
    rng: FilterRng,
    scores: Vec<f64>,
    matches: Vec<ScanMatch>,
    ancestors: Vec<usize>,
    pose_scratch: Vec<Pose2>,
}

impl ParticleFilter {
    /// `n` particles at `start`, weights `1/n`, random streams from `seed`.
    pub fn new(n: usize, start: Pose2, seed: u64) -> Self {
        ParticleFilter {
            particles: ParticleSet::new(n, start),
            rng: FilterRng::new(seed, n),
            scores: Vec::with_capacity(n),
            matches: Vec::with_capacity(n),
            ancestors: Vec::with_capacity(n),
            pose_scratch: Vec::with_capacity(n),
        }
    }

    /// Moves every particle with `step(pose, rng)` (a noisy motion model), in parallel over
    /// fixed chunks, each with its own random stream: deterministic for any thread count.
    pub fn predict<F>(&mut self, step: F)
    where
        F: Fn(&mut Pose2, &mut Xoshiro256PlusPlus) + Sync,
    {
        self.predict_chunks(|poses, rng| {
            for p in poses {
                step(p, rng);
            }
        });
    }

    /// Runs `work(chunk, rng)` on each fixed chunk of [`CHUNK_PARTICLES`] particle poses with
    /// that chunk's random stream, in parallel; results do not depend on the thread count.
    pub fn predict_chunks<F>(&mut self, work: F)
    where
        F: Fn(&mut [Pose2], &mut Xoshiro256PlusPlus) + Sync,
    {
        self.par_chunks(true, work);
    }

    /// Applies the odometry steps `(from, to)` in order to every particle with `motion`, in
    /// parallel over fixed chunks (deterministic for any thread count).
    pub fn predict_steps(
        &mut self,
        steps: &[(StampedPose2, StampedPose2)],
        motion: &dyn MotionModel,
    ) {
        let parallel = self.particles.len() * steps.len() >= SERIAL_BELOW_PARTICLE_STEPS;
        self.par_chunks(parallel, |poses, rng| {
            for (from, to) in steps {
                for p in poses.iter_mut() {
                    *p = motion.sample(p, from, to, rng);
                }
            }
        });
    }

    /// Composes every particle with the odometry steps `(from, to)` in order, without
    /// noise: [`Self::predict_steps`] with exact odometry, each step's increment computed
    /// once for all particles instead of per particle (the same bits: the increment is a pure
    /// function of the step; the per-particle `between` cost two of its three `sin_cos`).
    /// `increments` is a reusable buffer.
    pub fn predict_exact(
        &mut self,
        steps: &[(StampedPose2, StampedPose2)],
        increments: &mut Vec<Pose2>,
    ) {
        increments.clear();
        increments.extend(steps.iter().map(|(from, to)| from.pose.between(&to.pose)));
        let increments = &*increments;
        let parallel = self.particles.len() * steps.len() >= SERIAL_BELOW_PARTICLE_STEPS;
        self.par_chunks(parallel, |poses, _| {
            for d in increments {
                for p in poses.iter_mut() {
                    *p = p.compose(d);
                }
            }
        });
    }

    /// [`Self::predict_chunks`], in parallel only when `parallel`: the chunks and their
    /// streams are the same either way, so is the result. Waking the thread pool costs more
    /// than moving a hundred particles by one odometry step, which the scan-matching mode does
    /// at every scan.
    fn par_chunks<F>(&mut self, parallel: bool, work: F)
    where
        F: Fn(&mut [Pose2], &mut Xoshiro256PlusPlus) + Sync,
    {
        if parallel {
            self.particles
                .poses
                .par_chunks_mut(CHUNK_PARTICLES)
                .zip(self.rng.chunks.par_iter_mut())
                .for_each(|(poses, rng)| work(poses, rng));
        } else {
            let chunks = self.particles.poses.chunks_mut(CHUNK_PARTICLES);
            for (poses, rng) in chunks.zip(self.rng.chunks.iter_mut()) {
                work(poses, rng);
            }
        }
    }

    /// Correlates every particle's view of `points_body` with its map over `search`, moves it
    /// to its best offset when `move_to_best`, and multiplies its weight by `exp(score / temperature)` (log space).
    /// Returns Neff after reweighting and the best particle; does not resample.
    pub fn reweight<P: ParticleMaps>(
        &mut self,
        maps: &P,
        points_body: &[[f64; 2]],
        search: &CorrelationSearch,
        temperature: f64,
        move_to_best: bool,
    ) -> UpdateReport {
        let n = self.particles.len();
        self.matches.clear();
        self.matches.resize(
            n,
            ScanMatch {
                pose: Pose2::IDENTITY,
                score: 0,
            },
        );
        // One particle per work item; scratch buffers are per rayon job and only hold
        // intermediate values, so results do not depend on scheduling.
        self.matches
            .par_iter_mut()
            .zip(self.particles.poses.par_iter())
            .enumerate()
            .for_each_init(CorrelationScratch::default, |scratch, (i, (m, pose))| {
                *m = correlation::best_match(maps.map_of(i), points_body, pose, search, scratch);
            });
        self.scores.clear();
        self.scores
            .extend(self.matches.iter().map(|m| f64::from(m.score)));
        if move_to_best {
            for (p, m) in self.particles.poses.iter_mut().zip(&self.matches) {
                *p = m.pose;
            }
        }
        weigh(&mut self.particles, &self.scores, temperature, |best| {
            self.matches.get(best).map_or(0, |m| m.score)
        })
    }

    /// Resamples with `method` when Neff < `threshold_fraction * n`; returns the ancestors'
    /// indices when it did (for per-particle state such as maps to follow).
    pub fn resample_if_needed(
        &mut self,
        threshold_fraction: f64,
        method: ResampleMethod,
    ) -> Option<&[usize]> {
        let n = self.particles.len();
        if self.particles.neff() >= threshold_fraction * n as f64 {
            return None;
        }
        resample::resample(
            &self.particles.weights,
            method,
            &mut self.rng.master,
            &mut self.ancestors,
        );
        self.particles
            .apply_resample(&self.ancestors, &mut self.pose_scratch);
        Some(&self.ancestors)
    }

    /// Scan-matching update: every particle is matched against `field` around its pose
    /// (see [`likelihood_field`]), moved to the optimum, and its log-weight grows by the objective /
    /// `temperature`. Returns Neff after reweighting and the best particle; does not resample.
    pub fn scan_match_update(
        &mut self,
        field: &likelihood_field::LikelihoodField,
        points_body: &[[f64; 2]],
        params: &likelihood_field::MatchParams,
        temperature: f64,
    ) -> UpdateReport {
        let n = self.particles.len();
        let mut results = vec![
            likelihood_field::MatchResult {
                pose: Pose2::IDENTITY,
                objective: 0.0,
                fit: 0.0,
            };
            n
        ];
        likelihood_field::match_particles(
            field,
            points_body,
            &self.particles.poses,
            params,
            &mut results,
        );
        self.scores.clear();
        self.scores.extend(results.iter().map(|m| m.objective));
        for (p, m) in self.particles.poses.iter_mut().zip(&results) {
            *p = m.pose;
        }
        weigh(&mut self.particles, &self.scores, temperature, |best| {
            results
                .get(best)
                .map_or(0, |m| (m.fit * points_body.len() as f64).round() as u32)
        })
    }

    /// Adds zero-mean Gaussian noise (`sigma_xy_m` in x and y, `sigma_yaw_rad` in yaw) to
    /// every particle, per chunk with its own stream (deterministic for any thread count).
    pub fn jitter(&mut self, sigma_xy_m: f64, sigma_yaw_rad: f64) {
        use rand::RngExt;
        use rand_distr::StandardNormal;
        let parallel = self.particles.len() >= SERIAL_BELOW_PARTICLE_STEPS;
        self.par_chunks(parallel, |poses, rng| {
            for p in poses {
                let (a, b, c): (f64, f64, f64) = (
                    rng.sample(StandardNormal),
                    rng.sample(StandardNormal),
                    rng.sample(StandardNormal),
                );
                p.x_m += sigma_xy_m * a;
                p.y_m += sigma_xy_m * b;
                p.yaw_rad = crate::geometry::wrap_angle(p.yaw_rad + sigma_yaw_rad * c);
            }
        });
    }

    /// The heaviest particle's pose.
    pub fn best_pose(&self) -> Pose2 {
        self.particles
            .poses
            .get(self.particles.best_index())
            .copied()
            .unwrap_or_default()
    }
}

/// Multiplies the weights by `exp(score / temperature)` (log space) and reports Neff and the
/// heaviest particle, whose score `best_score` gives; no resampling.
fn weigh(
    particles: &mut ParticleSet,
    scores: &[f64],
    temperature: f64,
    best_score: impl FnOnce(usize) -> u32,
) -> UpdateReport {
    weights::update_log_space(&mut particles.weights, scores, temperature);
    let best = particles.best_index();
    UpdateReport {
        neff: particles.neff(),
        resampled: false,
        best,
        best_score: best_score(best),
    }
}

#[cfg(test)]
mod tests;
