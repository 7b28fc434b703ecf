//! The options of the Rao-Blackwellised filter (`[filter.rbpf]` and its tables
//! `odometry_noise`, `likelihood`, `search`, `final_refine`).

use crate::matching::nearest_occupied::{ObservationModel, SearchParams};
use serde::{Deserialize, Serialize};

/// Options of the Rao-Blackwellised mode (`[filter.rbpf]`). The particle count is
/// `[filter] particles`, the resampling scheme `[filter] resample_method`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfOptions {
    /// Cell side of the particles' maps (m); 0 = `[map] resolution_m`.
    pub resolution_m: f64,
    /// Update (match, reweight, map) once the odometry moved this far since the last
    /// update (m; GMapping: 0.5-1).
    pub linear_update_m: f64,
    /// ... or turned this much (deg; GMapping: 0.5 rad).
    pub angular_update_deg: f64,
    /// Use every k-th return for matching and weighting (1 = all; mapping uses all).
    pub beam_decimation: usize,
    /// Returns farther than this are neither matched nor mapped (m; GMapping `maxUrange`).
    pub range_max_m: f64,
    /// Returns nearer than this are dropped; replaces `[map.scan] range_min_m` in this mode
    /// (whose 2 m default is the car seed's; indoor robots see walls closer than that).
    pub range_min_m: f64,
    /// Keep `[map.scan]`'s densification of walls (joining returns); off matches and maps
    /// the real beams only.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub densify: bool,
    /// Divisor of the match log-likelihood in the log-weight update (GMapping: `ogain` times
    /// the particle count).
    pub weight_temperature: f64,
    /// Resample when Neff < this fraction of the particle count.
    pub resample_threshold: f64,
    /// The motion model's noise, GMapping's four parameters.
    pub odometry_noise: RbpfOdometryNoise,
    /// The observation model the particles are matched and weighted with.
    pub likelihood: RbpfLikelihood,
    /// Each particle's scan match at an update, and the sample drawn around it.
    pub search: RbpfSearch,
    /// The re-match of every output pose in the final map.
    pub final_refine: RbpfFinalRefine,
}

/// Odometry noise of the motion model (`[filter.rbpf.odometry_noise]`): the sigmas of an
/// update's increment grow with the distance travelled and the angle turned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfOdometryNoise {
    /// Translation sigma per metre travelled (GMapping `srr`).
    pub srr: f64,
    /// Translation sigma per radian turned (m/rad; GMapping `str`).
    pub str_m_per_rad: f64,
    /// Rotation sigma per metre travelled (rad/m; GMapping `srt`).
    pub srt_rad_per_m: f64,
    /// Rotation sigma per radian turned (GMapping `stt`).
    pub stt: f64,
}

/// The observation model (`[filter.rbpf.likelihood]`): how a scan scores in a particle's
/// map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfLikelihood {
    /// Standard deviation of the observation model: a point at distance d from the nearest
    /// occupied cell centre scores `-d^2 / (2 sigma^2)` (m).
    pub sigma_m: f64,
    /// Occupied cells are looked for within this many cells of a point (Chebyshev).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub kernel_cells: u32,
    /// Log-likelihood of a point with no occupied cell within the kernel (a floor; negative).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub no_hit_log_likelihood: f64,
    /// A cell counts as occupied for matching above this log-odds (0 = p > 0.5, one hit).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub occupied_logodds: f64,
}

/// The proposal (`[filter.rbpf.search]`): each particle's scan match in its own map (a
/// coarse search, then a hill climb, under a prior from the motion model) and the sample
/// drawn around the match.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfSearch {
    /// Half-width of the coarse yaw search around each particle's sampled pose (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub coarse_yaw_deg: f64,
    /// Step of the coarse yaw search (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub coarse_yaw_step_deg: f64,
    /// Initial x/y step of the hill climb (m; GMapping `lstep`).
    pub step_xy_m: f64,
    /// Initial yaw step of the hill climb (deg; GMapping `astep` = 0.05 rad).
    pub step_yaw_deg: f64,
    /// Step halvings of the hill climb (GMapping `iterations`).
    pub refine_levels: u32,
    /// Smallest x/y sigma of the matcher's prior (m). The prior is a Gaussian on the
    /// deviation from each particle's noise-free predicted pose (decision 0005) with the
    /// motion model's sigmas (`odometry_noise`) for the update: it keeps matches from
    /// sliding along corridors.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub prior_min_xy_m: f64,
    /// Smallest yaw sigma of that prior (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub prior_min_yaw_deg: f64,
    /// x/y sigma of the sample around the match (m): each particle is matched from its
    /// noise-free prediction, then sampled around its match
    /// (`docs/decisions/0005-proposal-from-prediction.md`).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub jitter_xy_m: f64,
    /// Yaw sigma of the sample around the match (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub jitter_yaw_deg: f64,
}

/// The re-match of the output poses (`[filter.rbpf.final_refine]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RbpfFinalRefine {
    /// After the run, re-match every output pose against the final best particle's map
    /// (hill climb from the path's pose): corrects the odometry composed between updates.
    pub enabled: bool,
    /// x/y sigma of that re-match's prior around the path's pose (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sigma_xy_m: f64,
    /// Yaw sigma of that re-match's prior (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sigma_yaw_deg: f64,
}

impl Default for RbpfOptions {
    fn default() -> Self {
        RbpfOptions {
            resolution_m: 0.05,
            linear_update_m: 0.3,
            angular_update_deg: 15.0,
            beam_decimation: 2,
            range_max_m: 30.0,
            range_min_m: 0.1,
            densify: false,
            weight_temperature: 30.0,
            resample_threshold: 0.5,
            odometry_noise: RbpfOdometryNoise::default(),
            likelihood: RbpfLikelihood::default(),
            search: RbpfSearch::default(),
            final_refine: RbpfFinalRefine::default(),
        }
    }
}

impl Default for RbpfOdometryNoise {
    fn default() -> Self {
        RbpfOdometryNoise {
            srr: 0.1,
            str_m_per_rad: 0.1,
            srt_rad_per_m: 0.2,
            stt: 0.2,
        }
    }
}

impl Default for RbpfLikelihood {
    fn default() -> Self {
        RbpfLikelihood {
            sigma_m: 0.05,
            kernel_cells: 1,
            no_hit_log_likelihood: -2.0,
            occupied_logodds: 0.0,
        }
    }
}

impl Default for RbpfSearch {
    fn default() -> Self {
        RbpfSearch {
            coarse_yaw_deg: 3.0,
            coarse_yaw_step_deg: 1.0,
            step_xy_m: 0.05,
            step_yaw_deg: 2.865,
            refine_levels: 4,
            prior_min_xy_m: 0.02,
            prior_min_yaw_deg: 1.0,
            jitter_xy_m: 0.01,
            jitter_yaw_deg: 0.25,
        }
    }
}

impl Default for RbpfFinalRefine {
    fn default() -> Self {
        RbpfFinalRefine {
            enabled: true,
            sigma_xy_m: 0.03,
            sigma_yaw_deg: 3.0,
        }
    }
}

impl RbpfOptions {
    /// Checks ranges; the message names the bad key by its path under `filter.rbpf.`.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        let (noise, lik, search, fin) = (
            &self.odometry_noise,
            &self.likelihood,
            &self.search,
            &self.final_refine,
        );
        if !(nonneg(self.resolution_m) && self.resolution_m <= 10.0) {
            return Err("filter.rbpf.resolution_m must lie in [0, 10]".into());
        }
        for (k, v) in [
            ("range_min_m", self.range_min_m),
            ("linear_update_m", self.linear_update_m),
            ("angular_update_deg", self.angular_update_deg),
            ("odometry_noise.srr", noise.srr),
            ("odometry_noise.str_m_per_rad", noise.str_m_per_rad),
            ("odometry_noise.srt_rad_per_m", noise.srt_rad_per_m),
            ("odometry_noise.stt", noise.stt),
            ("search.coarse_yaw_deg", search.coarse_yaw_deg),
            ("search.step_xy_m", search.step_xy_m),
            ("search.step_yaw_deg", search.step_yaw_deg),
            ("search.jitter_xy_m", search.jitter_xy_m),
            ("search.jitter_yaw_deg", search.jitter_yaw_deg),
        ] {
            if !nonneg(v) {
                return Err(format!("filter.rbpf.{k} must be finite and >= 0"));
            }
        }
        for (k, v) in [
            ("range_max_m", self.range_max_m),
            ("likelihood.sigma_m", lik.sigma_m),
            ("search.coarse_yaw_step_deg", search.coarse_yaw_step_deg),
            ("weight_temperature", self.weight_temperature),
            ("search.prior_min_xy_m", search.prior_min_xy_m),
            ("search.prior_min_yaw_deg", search.prior_min_yaw_deg),
            ("final_refine.sigma_xy_m", fin.sigma_xy_m),
            ("final_refine.sigma_yaw_deg", fin.sigma_yaw_deg),
        ] {
            if !pos(v) {
                return Err(format!("filter.rbpf.{k} must be positive and finite"));
            }
        }
        if self.beam_decimation == 0 {
            return Err("filter.rbpf.beam_decimation must be at least 1".into());
        }
        if lik.kernel_cells > 8 {
            return Err("filter.rbpf.likelihood.kernel_cells must be at most 8".into());
        }
        if search.coarse_yaw_deg > 45.0
            || search.coarse_yaw_deg / search.coarse_yaw_step_deg > 200.0
        {
            return Err(
                "filter.rbpf.search.coarse_yaw_deg must be at most 45 and 200 steps".into(),
            );
        }
        if search.refine_levels > 12 {
            return Err("filter.rbpf.search.refine_levels must be at most 12".into());
        }
        if !(lik.no_hit_log_likelihood.is_finite() && lik.no_hit_log_likelihood <= 0.0) {
            return Err(
                "filter.rbpf.likelihood.no_hit_log_likelihood must be finite and <= 0".into(),
            );
        }
        if !(lik.occupied_logodds.is_finite() && lik.occupied_logodds.abs() <= 100.0) {
            return Err("filter.rbpf.likelihood.occupied_logodds must lie in [-100, 100]".into());
        }
        if !(0.0..=1.0).contains(&self.resample_threshold) {
            return Err("filter.rbpf.resample_threshold must lie in [0, 1]".into());
        }
        Ok(())
    }

    /// The observation model these options describe, for maps of `resolution_m`.
    pub fn observation(&self, resolution_m: f64) -> ObservationModel {
        let lik = &self.likelihood;
        ObservationModel {
            kernel: lik.kernel_cells as i32,
            occupied_fixed: (lik.occupied_logodds * 256.0).round() as i16,
            res2_over_2s2: resolution_m * resolution_m / (2.0 * lik.sigma_m * lik.sigma_m),
            no_hit: lik.no_hit_log_likelihood,
        }
    }

    /// The matcher's search parameters these options describe, for maps of `resolution_m`.
    pub fn search_params(&self, resolution_m: f64) -> SearchParams {
        let o = &self.search;
        SearchParams {
            yaw_offsets_rad: crate::matching::yaw_offsets_rad(
                o.coarse_yaw_deg,
                o.coarse_yaw_step_deg,
            ),
            xy_cells: 0,
            resolution_m,
            step_xy_m: o.step_xy_m,
            step_yaw_rad: o.step_yaw_deg.to_radians(),
            refine_levels: o.refine_levels,
            prior: None,
        }
    }

    /// Odometry noise sigmas `[srr, str, srt, stt]`.
    pub(super) fn noise(&self) -> [f64; 4] {
        let n = &self.odometry_noise;
        [n.srr, n.str_m_per_rad, n.srt_rad_per_m, n.stt]
    }
}
