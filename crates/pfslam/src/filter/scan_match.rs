//! The options of the scan-matching mode (`[filter.scan_match]`) and the parameters one match
//! takes, derived from them ([`ScanMatchOptions::params`]); the matcher is
//! [`crate::matching::likelihood_field`].

use crate::matching::likelihood_field::{MatchParams, MatchSearch};
use serde::{Deserialize, Serialize};

/// Options of the scan-matching mode (`[filter.scan_match]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanMatchOptions {
    /// Use every k-th return of a scan for matching (1 = all; mapping always uses all).
    pub beam_decimation: usize,
    /// Returns farther than this from the sensor are not matched (m; they are still mapped).
    pub match_range_max_m: f64,
    /// Standard deviation of the likelihood field's Gaussian (m).
    pub field_sigma_m: f64,
    /// Half-width of the coarse x/y search in cells.
    pub xy_search_radius_cells: u32,
    /// Half-width of the coarse yaw search (deg). Beyond a few prior sigmas a yaw candidate
    /// pays more prior penalty than a scan's fit can win back; the refinement still moves in
    /// yaw (`docs/decisions/0019-scan-match-refinement.md`).
    pub yaw_search_deg: f64,
    /// Step of the coarse yaw search (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub yaw_step_deg: f64,
    /// Standard deviation of the prior on the x/y deviation from the predicted pose (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub prior_sigma_xy_m: f64,
    /// Standard deviation of the prior on the yaw deviation from the predicted pose (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub prior_sigma_yaw_deg: f64,
    /// Field value (0..1) of never-observed cells: a point that lands there neither fits nor
    /// contradicts the map. Matters at the frontier: the far end of a wall seen by the
    /// previous scan ends just short of this scan's, and scoring the unknown beyond it as
    /// empty would pull every match back along the street.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub unknown_value: f64,
    /// Log-likelihood of one scan point lying exactly on an occupied cell (field value 1).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub point_gain: f64,
    /// Divisor of the match objective in the log-weight update.
    pub weight_temperature: f64,
    /// Resample when Neff < this fraction of the particle count (selective resampling).
    pub resample_threshold: f64,
    /// Halvings of the step in the sub-cell refinement (0 = coarse search only).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub refine_levels: u32,
    /// Particles are sampled around their match with this standard deviation in x and y
    /// (m); the prediction itself composes the odometry without noise (the match is the
    /// proposal). Small: each change of best particle is a jump of this order, which the
    /// car's odometry calibration reads as travel
    /// (`docs/decisions/0022-car-back-end-on-calibrated-odometry.md`).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub proposal_sigma_xy_m: f64,
    /// Standard deviation of the yaw sampled around the match (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub proposal_sigma_yaw_deg: f64,
}

impl Default for ScanMatchOptions {
    fn default() -> Self {
        ScanMatchOptions {
            beam_decimation: 2,
            match_range_max_m: 40.0,
            field_sigma_m: 0.15,
            xy_search_radius_cells: 3,
            yaw_search_deg: 0.25,
            yaw_step_deg: 0.25,
            prior_sigma_xy_m: 0.02,
            prior_sigma_yaw_deg: 0.05,
            unknown_value: 0.5,
            point_gain: 1.0,
            weight_temperature: 10.0,
            resample_threshold: 0.5,
            refine_levels: 3,
            proposal_sigma_xy_m: 0.003,
            proposal_sigma_yaw_deg: 0.02,
        }
    }
}

impl ScanMatchOptions {
    /// Checks ranges; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if self.beam_decimation == 0 {
            return Err("filter.scan_match.beam_decimation must be at least 1".into());
        }
        for (k, v) in [
            ("match_range_max_m", self.match_range_max_m),
            ("field_sigma_m", self.field_sigma_m),
            ("yaw_step_deg", self.yaw_step_deg),
            ("prior_sigma_xy_m", self.prior_sigma_xy_m),
            ("prior_sigma_yaw_deg", self.prior_sigma_yaw_deg),
            ("point_gain", self.point_gain),
            ("weight_temperature", self.weight_temperature),
        ] {
            if !pos(v) {
                return Err(format!("filter.scan_match.{k} must be positive and finite"));
            }
        }
        if !(self.yaw_search_deg.is_finite() && (0.0..=45.0).contains(&self.yaw_search_deg)) {
            return Err("filter.scan_match.yaw_search_deg must lie in [0, 45]".into());
        }
        if self.xy_search_radius_cells > 32 {
            return Err("filter.scan_match.xy_search_radius_cells must be at most 32".into());
        }
        if self.refine_levels > 8 {
            return Err("filter.scan_match.refine_levels must be at most 8".into());
        }
        if !(0.0..=1.0).contains(&self.resample_threshold) {
            return Err("filter.scan_match.resample_threshold must lie in [0, 1]".into());
        }
        Ok(())
    }

    /// The per-update search parameters for a map of `resolution_m`.
    pub fn params(&self, resolution_m: f64) -> MatchParams {
        let search = MatchSearch {
            xy_radius_cells: self.xy_search_radius_cells,
            yaw_search_deg: self.yaw_search_deg,
            yaw_step_deg: self.yaw_step_deg,
            prior_sigma_xy_m: self.prior_sigma_xy_m,
            prior_sigma_yaw_deg: self.prior_sigma_yaw_deg,
            point_gain: self.point_gain,
            refine_levels: self.refine_levels,
        };
        MatchParams::new(resolution_m, &search)
    }
}
