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

/// Search parameters derived from the scan-matching mode's options once per run
/// ([`ScanMatchOptions::params`](crate::filter::scan_match::ScanMatchOptions::params)).
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
    /// The refinement's field-sum arithmetic (f32 from
    /// [`ScanMatchOptions::params`](crate::filter::scan_match::ScanMatchOptions::params)).
    pub kernel_precision: KernelPrecision,
}
