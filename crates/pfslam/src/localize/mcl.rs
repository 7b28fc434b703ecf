//! The particle set of Monte Carlo localisation and its three steps: move by the odometry,
//! weigh by the likelihood field, resample (KLD-adaptive, with augmented MCL's random
//! particles).
//!
//! Random streams: motion noise draws from one stream per fixed chunk of particles (the same
//! numbers whichever thread runs a chunk); resampling and initialisation draw from one
//! sequential stream. A run is bit-identical for any thread count.

use super::kld::{KldBins, kld_bound};
use crate::geometry::{Pose2, wrap_angle};
use crate::kernels::field_loglik::{self, CentrePose, POSES};
use crate::map::{BinaryMap, CellState};
use crate::matching::map_field::{LikelihoodField, Sharpness};
use crate::motion::odometry_model::{OdometryModelOptions, sample_odometry_motion};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

/// Particles per chunk: the unit of parallel work and of motion-noise streams.
pub const CHUNK: usize = 256;

/// The free cells of a map, to draw poses uniformly over the space a robot can stand in.
#[derive(Debug, Clone)]
pub struct FreeSpace<'a> {
    map: &'a BinaryMap,
    cells: Vec<(u32, u32)>,
}

impl<'a> FreeSpace<'a> {
    /// The free cells of `map` (none: `None`).
    pub fn new(map: &'a BinaryMap) -> Option<Self> {
        let cells: Vec<(u32, u32)> = (0..map.height)
            .flat_map(|j| (0..map.width).map(move |i| (i, j)))
            .filter(|&(i, j)| map.cells[j * map.width + i] == CellState::Free)
            .map(|(i, j)| (i as u32, j as u32))
            .collect();
        (!cells.is_empty()).then_some(FreeSpace { map, cells })
    }

    /// A pose in a free cell drawn about `centre` (normal, `sigma_m` per axis) with any
    /// heading; a pose over the whole free space when eight draws all miss it.
    pub fn sample_near(&self, centre: &Pose2, sigma_m: f64, rng: &mut Xoshiro256PlusPlus) -> Pose2 {
        for _ in 0..8 {
            let x = centre.x_m + sigma_m * rng.sample::<f64, _>(StandardNormal);
            let y = centre.y_m + sigma_m * rng.sample::<f64, _>(StandardNormal);
            if self.map.state_at(x, y) == CellState::Free {
                let yaw = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
                return Pose2::new(x, y, yaw);
            }
        }
        self.sample(rng)
    }

    /// A pose drawn uniformly over the free cells and all headings.
    pub fn sample(&self, rng: &mut Xoshiro256PlusPlus) -> Pose2 {
        let (i, j) = self.cells[rng.random_range(0..self.cells.len())];
        let limits = &self.map.limits;
        let res = limits.resolution_m();
        let x = limits.origin_x_m() + (i as f64 + rng.random::<f64>()) * res;
        let y = limits.origin_y_m() + (j as f64 + rng.random::<f64>()) * res;
        let yaw = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        Pose2::new(x, y, yaw)
    }
}

/// The random streams of a run.
#[derive(Debug, Clone)]
pub struct Streams {
    /// Initialisation and resampling.
    pub sequential: Xoshiro256PlusPlus,
    /// The next chunk stream's start (jumped past every stream handed out).
    next: Xoshiro256PlusPlus,
    /// One stream per chunk of [`CHUNK`] particles, grown as the set grows.
    chunks: Vec<Xoshiro256PlusPlus>,
}

impl Streams {
    /// The streams of `seed`.
    pub fn new(seed: u64) -> Self {
        let mut next = Xoshiro256PlusPlus::seed_from_u64(seed);
        let sequential = next.clone();
        next.jump();
        Streams {
            sequential,
            next,
            chunks: Vec::new(),
        }
    }

    fn chunks_for(&mut self, particles: usize) -> &mut [Xoshiro256PlusPlus] {
        let n = particles.div_ceil(CHUNK);
        while self.chunks.len() < n {
            self.chunks.push(self.next.clone());
            self.next.jump();
        }
        &mut self.chunks[..n]
    }
}

/// Weighted poses.
#[derive(Debug, Clone, Default)]
pub struct ParticleSet {
    /// The poses (world frame of the map).
    pub poses: Vec<Pose2>,
    /// Normalised weights.
    pub weights: Vec<f64>,
    /// Which particles the last resampling drew at random over the free space: they are
    /// left out of the fit, which would otherwise fall with every injection and call for
    /// more (a feedback that has any injection rate as its fixed point).
    pub injected: Vec<bool>,
}

/// The settings of one resampling.
#[derive(Debug, Clone, Copy)]
pub struct ResamplePlan {
    /// Probability of drawing a particle at random over the free space.
    pub inject_probability: f64,
    /// Lower bound of the count.
    pub min_particles: usize,
    /// Upper bound of the count.
    pub max_particles: usize,
    /// KLD sampling's error bound.
    pub kld_error: f64,
    /// KLD sampling's normal quantile.
    pub kld_z: f64,
    /// Half of the random particles are drawn about this pose with this spread (m): a robot
    /// lost by an odometry glitch is usually near where it was lost; the other half cover
    /// the whole free space (a robot carried elsewhere).
    pub near: (Pose2, f64),
}

impl ParticleSet {
    /// `count` poses drawn about `pose` with standard deviations `sigma_xy_m`, `sigma_yaw_rad`.
    pub fn around(
        pose: &Pose2,
        (sigma_xy_m, sigma_yaw_rad): (f64, f64),
        count: usize,
        rng: &mut Xoshiro256PlusPlus,
    ) -> Self {
        let mut g = || rng.sample::<f64, _>(StandardNormal);
        let poses: Vec<Pose2> = (0..count)
            .map(|_| {
                Pose2::new(
                    pose.x_m + sigma_xy_m * g(),
                    pose.y_m + sigma_xy_m * g(),
                    wrap_angle(pose.yaw_rad + sigma_yaw_rad * g()),
                )
            })
            .collect();
        Self::uniform(poses)
    }

    /// `count` poses drawn uniformly over the free space (global localisation).
    pub fn over(free: &FreeSpace, count: usize, rng: &mut Xoshiro256PlusPlus) -> Self {
        Self::uniform((0..count).map(|_| free.sample(rng)).collect())
    }

    fn uniform(poses: Vec<Pose2>) -> Self {
        let w = 1.0 / poses.len().max(1) as f64;
        ParticleSet {
            weights: vec![w; poses.len()],
            injected: vec![false; poses.len()],
            poses,
        }
    }

    /// Moves every particle by the odometry step `from -> to` with the motion model's noise.
    pub fn predict(
        &mut self,
        motion: &OdometryModelOptions,
        (from, to): (&Pose2, &Pose2),
        streams: &mut Streams,
    ) {
        let rngs = streams.chunks_for(self.poses.len());
        self.poses
            .par_chunks_mut(CHUNK)
            .zip(rngs.par_iter_mut())
            .for_each(|(poses, rng)| {
                for p in poses {
                    *p = sample_odometry_motion(motion, p, from, to, None, rng);
                }
            });
    }

    /// Multiplies the weights by the likelihood of the body-frame returns `points_body` and
    /// normalises them. With `neff_floor`, the likelihood is tempered (raised to `1 / T`, the
    /// smallest `T` of 1, 2, 4, ... that keeps the effective sample size at that share of the
    /// particles): while the particles are spread, the best of them sit decimetres and degrees
    /// from the truth, and the untempered likelihood would pick one of them at once instead of
    /// letting the evidence of several updates gather. Returns the log of the weighted mean
    /// likelihood, untempered (the fit augmented MCL tracks).
    pub fn weigh(
        &mut self,
        field: &LikelihoodField,
        sharpness: Sharpness,
        points_body: &[[f64; 2]],
        neff_floor: Option<f64>,
    ) -> f64 {
        let log_likelihood = log_likelihoods(field, sharpness, points_body, &self.poses);
        let prior: Vec<f64> = self.weights.iter().map(|w| w.ln()).collect();
        let fit = drawn_fit(&prior, &log_likelihood, &self.injected);
        normalise(&prior, &log_likelihood, 1.0, &mut self.weights);
        if let Some(floor) = neff_floor {
            let want = floor * self.poses.len() as f64;
            let mut temperature = 1.0;
            while self.neff() < want && temperature < MAX_TEMPERATURE {
                temperature *= 2.0;
                normalise(&prior, &log_likelihood, temperature, &mut self.weights);
            }
        }
        fit
    }

    /// Effective sample size of the weights.
    pub fn neff(&self) -> f64 {
        1.0 / self.weights.iter().map(|w| w * w).sum::<f64>()
    }

    /// Draws a new set: each particle at random over `free` with the plan's probability, else
    /// from the weights; it stops once the count reaches the KLD bound of the bins occupied
    /// (within the plan's bounds). Returns how many were drawn at random.
    pub fn resample(
        &mut self,
        plan: &ResamplePlan,
        bins: &mut KldBins,
        free: &FreeSpace,
        rng: &mut Xoshiro256PlusPlus,
    ) -> usize {
        let mut cumulative = Vec::with_capacity(self.weights.len());
        let mut acc = 0.0;
        for w in &self.weights {
            acc += w;
            cumulative.push(acc);
        }
        bins.clear();
        let mut out = Vec::with_capacity(self.poses.len());
        let mut flags = Vec::with_capacity(self.poses.len());
        let mut injected = 0;
        let inject_probability = if self.poses.is_empty() {
            1.0
        } else {
            plan.inject_probability
        };
        while out.len() < plan.max_particles {
            let random = rng.random::<f64>() < inject_probability;
            flags.push(random);
            let pose = if random {
                injected += 1;
                if rng.random::<bool>() {
                    free.sample_near(&plan.near.0, plan.near.1, rng)
                } else {
                    free.sample(rng)
                }
            } else {
                let u = rng.random::<f64>() * acc;
                let k = cumulative.partition_point(|&c| c < u);
                self.poses[k.min(self.poses.len() - 1)]
            };
            out.push(pose);
            let k = bins.add(&pose);
            if out.len() >= plan.min_particles
                && out.len() >= kld_bound(k, plan.kld_error, plan.kld_z)
            {
                break;
            }
        }
        *self = Self::uniform(out);
        self.injected = flags;
        injected
    }
}

/// The largest tempering of [`ParticleSet::weigh`].
const MAX_TEMPERATURE: f64 = 4096.0;

/// The log of the weighted mean likelihood over the particles not injected (all of them
/// when every one was).
fn drawn_fit(prior: &[f64], log_likelihood: &[f64], injected: &[bool]) -> f64 {
    let any_drawn = injected.iter().any(|i| !i);
    let kept = || (0..prior.len()).filter(move |&k| !any_drawn || !injected[k]);
    log_sum_exp(kept().map(|k| prior[k] + log_likelihood[k]))
        - log_sum_exp(kept().map(|k| prior[k]))
}

/// `ln(sum(exp(v)))` without overflow (negative infinity for nothing).
fn log_sum_exp(values: impl Iterator<Item = f64> + Clone) -> f64 {
    let top = values.clone().fold(f64::NEG_INFINITY, f64::max);
    if top == f64::NEG_INFINITY {
        return top;
    }
    top + values.map(|v| (v - top).exp()).sum::<f64>().ln()
}

/// `weights <- normalised exp(prior + log_likelihood / temperature)`.
fn normalise(prior: &[f64], log_likelihood: &[f64], temperature: f64, weights: &mut [f64]) {
    let top = prior
        .iter()
        .zip(log_likelihood)
        .map(|(p, l)| p + l / temperature)
        .fold(f64::NEG_INFINITY, f64::max);
    let mut sum = 0.0;
    for ((w, p), l) in weights.iter_mut().zip(prior).zip(log_likelihood) {
        *w = (p + l / temperature - top).exp();
        sum += *w;
    }
    for w in weights.iter_mut() {
        *w /= sum;
    }
}

/// [`scan_log_likelihood`] of every pose, in order: four poses at a time in the kernel
/// (the same bits as one at a time), chunked as the motion noise is.
pub fn log_likelihoods(
    field: &LikelihoodField,
    sharpness: Sharpness,
    points_body: &[[f64; 2]],
    poses: &[Pose2],
) -> Vec<f64> {
    let table = field.centre_table(sharpness);
    let off = |u: f64, v: f64| field.log_likelihood_at_centres(sharpness, u, v);
    poses
        .par_chunks(CHUNK)
        .flat_map_iter(|chunk| {
            let mut quads = chunk.chunks_exact(POSES);
            let mut out = Vec::with_capacity(chunk.len());
            for quad in &mut quads {
                let centred = std::array::from_fn(|k| centre_pose(field, &quad[k]));
                out.extend(field_loglik::sums4(&table, points_body, centred, off));
            }
            for p in quads.remainder() {
                out.push(scan_log_likelihood(field, sharpness, points_body, p));
            }
            out
        })
        .collect()
}

/// The log-likelihood of a scan's returns at `pose`. The pose is folded into the field's
/// cell-centre coordinates once, so each return costs two multiply-adds per axis.
#[inline]
pub fn scan_log_likelihood(
    field: &LikelihoodField,
    sharpness: Sharpness,
    points_body: &[[f64; 2]],
    pose: &Pose2,
) -> f64 {
    let off = |u: f64, v: f64| field.log_likelihood_at_centres(sharpness, u, v);
    let table = field.centre_table(sharpness);
    let [sum] = field_loglik::portable(&table, points_body, [centre_pose(field, pose)], off);
    sum
}

/// `pose` in the field's cell-centre coordinates.
fn centre_pose(field: &LikelihoodField, pose: &Pose2) -> CentrePose {
    let (scale, [ou, ov]) = field.centre_coordinates();
    let (s, c) = pose.yaw_rad.sin_cos();
    CentrePose {
        u0_cells: pose.x_m * scale - ou,
        v0_cells: pose.y_m * scale - ov,
        cs_per_m: c * scale,
        ss_per_m: s * scale,
    }
}
