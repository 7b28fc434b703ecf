//! The parameters one match takes: the search window, the prior and the arithmetic.

/// The arithmetic of the refinement's field sums: f32 (see
/// `docs/decisions/0018-f32-and-f64-in-the-kernels.md`); f64 for windows beyond the f32 kernel's
/// bound, and the tests' reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KernelPrecision {
    /// f64 throughout: the reference bits.
    F64,
    /// Window-relative f32 coordinates, f32 mix and per-lane sums (8 points per vector).
    F32,
}

/// The parameters of one match ([`MatchParams::new`] of a [`MatchSearch`]; the
/// scan-matching mode's options give theirs once per run,
/// [`ScanMatchOptions::params`](crate::filter::scan_match::ScanMatchOptions::params)).
#[derive(Debug, Clone, PartialEq)]
pub struct MatchParams {
    /// Map cell size (m).
    pub resolution_m: f64,
    /// Coarse x/y half-width (cells).
    pub xy_radius_cells: i32,
    /// Coarse yaw offsets (rad), 0 first.
    pub yaw_offsets_rad: Vec<f64>,
    /// Coarse yaw step (rad); the refinement starts at half of it.
    pub yaw_step_rad: f64,
    /// `1 / sigma_xy^2` of the prior (1/m^2).
    pub inv_var_xy: f64,
    /// `1 / sigma_yaw^2` of the prior (1/rad^2).
    pub inv_var_yaw: f64,
    /// Log-likelihood per unit of field value (field values run 0..=255).
    pub gain_per_unit: f64,
    /// Step halvings of the refinement.
    pub refine_levels: u32,
    /// The refinement's field-sum arithmetic (f32 from [`MatchParams::new`]).
    pub kernel_precision: KernelPrecision,
}

/// A match's search in the units of the options that describe it (`[filter.scan_match]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchSearch {
    /// Coarse x/y half-width (cells).
    pub xy_radius_cells: u32,
    /// Coarse yaw half-width (deg).
    pub yaw_search_deg: f64,
    /// Coarse yaw step (deg).
    pub yaw_step_deg: f64,
    /// Standard deviation of the prior in x and y (m).
    pub prior_sigma_xy_m: f64,
    /// Standard deviation of the prior in yaw (deg).
    pub prior_sigma_yaw_deg: f64,
    /// Log-likelihood of a point on a wall (field value 255).
    pub point_gain: f64,
    /// Step halvings of the refinement.
    pub refine_levels: u32,
}

impl MatchParams {
    /// The parameters of `search` on maps of `resolution_m` cells, with the f32 refinement.
    pub fn new(resolution_m: f64, search: &MatchSearch) -> Self {
        MatchParams {
            resolution_m,
            xy_radius_cells: search.xy_radius_cells as i32,
            yaw_offsets_rad: crate::matching::yaw_offsets_rad(
                search.yaw_search_deg,
                search.yaw_step_deg,
            ),
            yaw_step_rad: search.yaw_step_deg.to_radians(),
            inv_var_xy: 1.0 / (search.prior_sigma_xy_m * search.prior_sigma_xy_m),
            inv_var_yaw: 1.0 / search.prior_sigma_yaw_deg.to_radians().powi(2),
            gain_per_unit: search.point_gain / 255.0,
            refine_levels: search.refine_levels,
            kernel_precision: KernelPrecision::F32,
        }
    }
}
