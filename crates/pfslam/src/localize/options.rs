//! Options of Monte Carlo localisation (`[localize]`, `[localize.likelihood]`,
//! `[localize.recovery]`).

use serde::{Deserialize, Serialize};

/// Monte Carlo localisation in a fixed map (`pfslam localize`). AMCL's structure: the
/// odometry motion model, a likelihood field, KLD-adaptive resampling and augmented MCL's
/// random particles when the fit collapses. The measurements behind the defaults are in
/// `docs/decisions/0044-localisation-in-a-saved-map.md`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalizeOptions {
    /// Fewest particles KLD sampling may keep.
    pub min_particles: usize,
    /// Most particles; also the count spread over the free space for global localisation.
    pub max_particles: usize,
    /// KLD sampling: the bound on the error between the sample and the true posterior.
    pub kld_error: f64,
    /// KLD sampling: the upper standard normal quantile of the bound's confidence (2.33: 99 %).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub kld_z: f64,
    /// KLD sampling: the histogram's cell side (m) and yaw bin (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub kld_bin: [f64; 2],
    /// The filter updates once the odometry moved this far (m) or turned this much (deg)
    /// since its last update; a robot at rest is not updated (AMCL's rule, which keeps
    /// repeated scans of one view from collapsing the particles).
    pub update_min: [f64; 2],
    /// Thrun's odometry motion model noise: rotation from rotation (rad²/rad²), rotation from
    /// translation (rad²/m²), translation from translation (m²/m²), translation from rotation
    /// (m²/rad²).
    pub motion_alphas: [f64; 4],
    /// The filter has converged when the heaviest cluster holds this share of the weight.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub converged_mass: f64,
    /// A cluster's extent about its centre: distance (m) and yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub cluster_radius: [f64; 2],
    /// With `--initial-pose`: the standard deviations of the initial particles about it
    /// (m, deg).
    pub initial_sigma: [f64; 2],
    /// Once converged, match every return of the update's scan in the field from the
    /// estimate (a local hill climb) and move the estimate and every particle by the
    /// correction (not taken beyond 0.25 m or 5 deg); between updates, match every scan
    /// the same way from the odometry's pose for the output alone.
    pub refine_estimate: bool,
    /// The observation model.
    pub likelihood: LikelihoodOptions,
    /// Recovery when the robot is lost.
    pub recovery: RecoveryOptions,
}

/// The likelihood field (`[localize.likelihood]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LikelihoodOptions {
    /// Standard deviation of a return about the nearest wall while tracking (m).
    pub sigma_hit_m: f64,
    /// The same while the filter has not converged (m): broad, so that particles near but
    /// not at the true pose still stand out during global localisation and recovery.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub global_sigma_hit_m: f64,
    /// While the filter has not converged (or holds random particles just injected), the
    /// likelihood is tempered so that this share of the particles stays effective after
    /// weighing: the evidence of several updates decides between candidate places, not one
    /// scan's noise.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub global_neff_share: f64,
    /// Weight of the hit model; the rest is a uniform floor over the range, which keeps
    /// returns off the map (people, furniture moved) from vetoing a pose.
    pub z_hit: f64,
    /// Distances to the nearest wall are clamped here (m): the field's reach.
    pub max_distance_m: f64,
    /// Returns used per update, evenly spaced over the scan.
    pub max_beams: usize,
}

/// Augmented MCL's recovery (`[localize.recovery]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecoveryOptions {
    /// Rates of the slow and the fast average of the fit (the geometric mean likelihood of a
    /// return).
    pub alphas: [f64; 2],
    /// Random particles are injected with probability `1 - fast / (ratio * slow)` once the
    /// fast average falls below this share of the slow one (a kidnapped robot). Thrun's
    /// ratio of 1 injects at every dip of the fit (a crowd, a fast turn), and a random
    /// particle that happens to fit a sharp likelihood better than a briefly disturbed
    /// cluster wins the estimate.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub fit_ratio: f64,
    /// The fit augmented MCL tracks is that of this share of the returns, the best-fitting
    /// ones, at the estimate: a person beside the robot can hide a third of a scan from the
    /// map while the estimate is right, and must not call for random particles, whereas a
    /// lost robot's scan misses the map nearly everywhere.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub core_share: f64,
    /// Half of the random particles are drawn about the last converged estimate that fitted
    /// well, with this standard deviation (m) plus the odometry's travel since, and any
    /// heading; the other half over the whole free space.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub local_sigma_m: f64,
}

impl Default for LocalizeOptions {
    fn default() -> Self {
        LocalizeOptions {
            min_particles: 600,
            max_particles: 20_000,
            kld_error: 0.02,
            kld_z: 2.33,
            kld_bin: [0.25, 10.0],
            update_min: [0.1, 5.0],
            motion_alphas: [0.1, 0.05, 0.05, 0.05],
            converged_mass: 0.9,
            cluster_radius: [1.0, 30.0],
            initial_sigma: [0.1, 3.0],
            refine_estimate: true,
            likelihood: LikelihoodOptions::default(),
            recovery: RecoveryOptions::default(),
        }
    }
}

impl Default for LikelihoodOptions {
    fn default() -> Self {
        LikelihoodOptions {
            sigma_hit_m: 0.1,
            global_sigma_hit_m: 0.3,
            global_neff_share: 0.1,
            z_hit: 0.9,
            max_distance_m: 2.0,
            max_beams: 60,
        }
    }
}

impl Default for RecoveryOptions {
    fn default() -> Self {
        RecoveryOptions {
            alphas: [0.001, 0.1],
            fit_ratio: 0.5,
            core_share: 0.7,
            local_sigma_m: 2.0,
        }
    }
}

fn positive(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

fn unit(v: f64) -> bool {
    v.is_finite() && v > 0.0 && v < 1.0
}

/// The first failed check's message.
fn first_failure(checks: &[(bool, &str)]) -> Result<(), String> {
    match checks.iter().find(|(ok, _)| !ok) {
        Some((_, message)) => Err((*message).to_string()),
        None => Ok(()),
    }
}

impl LocalizeOptions {
    /// Checks every option; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        first_failure(&[
            (self.min_particles >= 1, "min_particles must be at least 1"),
            (
                self.max_particles >= self.min_particles,
                "max_particles must be at least min_particles",
            ),
            (unit(self.kld_error), "kld_error must lie in (0, 1)"),
            (positive(self.kld_z), "kld_z must be positive"),
            (
                self.kld_bin.iter().all(|&v| positive(v)),
                "kld_bin must be positive",
            ),
            (
                self.update_min.iter().all(|&v| v.is_finite() && v >= 0.0)
                    && self
                        .motion_alphas
                        .iter()
                        .all(|&v| v.is_finite() && v >= 0.0),
                "update_min and motion_alphas must be finite and non-negative",
            ),
            (
                unit(self.converged_mass),
                "converged_mass must lie in (0, 1)",
            ),
            (
                self.cluster_radius.iter().all(|&v| positive(v))
                    && self
                        .initial_sigma
                        .iter()
                        .all(|&v| v.is_finite() && v >= 0.0),
                "cluster_radius must be positive and initial_sigma non-negative",
            ),
        ])?;
        self.likelihood.validate()?;
        self.recovery.validate()
    }
}

impl LikelihoodOptions {
    fn validate(&self) -> Result<(), String> {
        first_failure(&[
            (
                positive(self.sigma_hit_m),
                "likelihood.sigma_hit_m must be positive",
            ),
            (
                positive(self.global_sigma_hit_m),
                "likelihood.global_sigma_hit_m must be positive",
            ),
            (
                unit(self.global_neff_share),
                "likelihood.global_neff_share must lie in (0, 1)",
            ),
            (unit(self.z_hit), "likelihood.z_hit must lie in (0, 1)"),
            (
                positive(self.max_distance_m),
                "likelihood.max_distance_m must be positive",
            ),
            (
                self.max_beams >= 1,
                "likelihood.max_beams must be at least 1",
            ),
        ])
    }
}

impl RecoveryOptions {
    fn validate(&self) -> Result<(), String> {
        first_failure(&[
            (
                self.alphas[0] >= 0.0 && self.alphas[0] < self.alphas[1] && self.alphas[1] <= 1.0,
                "recovery.alphas must satisfy 0 <= slow < fast <= 1",
            ),
            (
                self.fit_ratio > 0.0 && self.fit_ratio <= 1.0,
                "recovery.fit_ratio must lie in (0, 1]",
            ),
            (
                positive(self.local_sigma_m),
                "recovery.local_sigma_m must be positive",
            ),
        ])
    }
}
