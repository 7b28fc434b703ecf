//! The back end: loop closure by pose-graph optimisation after any filter mode.
//!
//! 1. Keyframes every `keyframe_distance_m` / `keyframe_angle_deg` of the front end's path.
//! 2. Sequential edges: each keyframe's scan is matched against a submap of the preceding
//!    `submap_keyframes` keyframes (at their current, already corrected estimates) around
//!    the front end's relative motion, with a prior on the deviation from it; a poor front
//!    end still gives good local edges. For a tilted or moving LiDAR (the car) these matches
//!    are biased, so there the front end's relative motion alone ties consecutive keyframes,
//!    with a random-walk uncertainty (`sequential_matching`).
//! 3. Loop closures: earlier keyframes within `loop_search_radius_m` of the new keyframe's
//!    estimate but at least `loop_min_path_m` back along the path are candidates; the scan
//!    is matched by branch and bound over a window of `loop_window_m` / `loop_window_deg`
//!    against the candidate's neighbourhood submap, refined below a cell, and accepted only
//!    if the score is high, enough points fall on the submap, and no other pose outside
//!    `loop_ambiguity_radius_m` scores nearly as well (a corridor is ambiguous along its
//!    axis). Loop edges carry a Cauchy kernel; after the final optimisation edges with a large
//!    error are dropped and the graph is optimised again.
//! 4. The graph is optimised ([`optimize`]) whenever closures were accepted and at least
//!    `optimize_every_keyframes` keyframes passed, so the next search starts from corrected
//!    estimates, and once more at the end.
//! 5. Every scan's corrected pose = its keyframe's corrected pose composed with the front
//!    end's motion since that keyframe.

pub mod lidar_odometry;
pub mod matcher;
pub mod optimize;

use crate::geometry::{Pose2, StampedPose2};
use crate::map::{MapError, PlanarScan, ScanOptions, ScanProjector};
use crate::motion::calibration::CalibrationOptions;
use crate::sensors::Recording;
use matcher::{PointField, Prior, SearchWindow};
use optimize::{Edge, OptimizeOptions, PoseGraph};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Errors of the back end.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// Invalid options (the message names the key).
    #[error("invalid graph options: {0}")]
    Options(String),
    /// Scan preprocessing failed.
    #[error(transparent)]
    Map(#[from] MapError),
}

/// Options of the pose-graph back end (`[graph]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GraphOptions {
    /// Run the back end after the filter.
    pub enabled: bool,
    /// A new keyframe after this much travel along the front end's path (m).
    pub keyframe_distance_m: f64,
    /// ... or after this much rotation (deg).
    pub keyframe_angle_deg: f64,
    /// Cell size of the matching fields (m).
    pub resolution_m: f64,
    /// Standard deviation of the likelihood field around submap points (m).
    pub field_sigma_m: f64,
    /// Returns closer than this to the sensor are not matched (m).
    pub range_min_m: f64,
    /// Returns farther than this are not matched (m).
    pub range_max_m: f64,
    /// At most this many points of a scan are matched (evenly subsampled).
    pub max_points: usize,
    /// Keyframes before the new one that form the submap of a sequential edge.
    pub submap_keyframes: usize,
    /// Half-width of the sequential search in x and y (m).
    pub sequential_window_m: f64,
    /// Half-width of the sequential search in yaw (deg).
    pub sequential_window_deg: f64,
    /// Yaw step of the searches (deg; the sub-cell refinement goes below it).
    pub yaw_step_deg: f64,
    /// Prior on the deviation from the front end's relative motion: x/y (m).
    pub sequential_prior_sigma_m: f64,
    /// Prior on the deviation from the front end's relative motion: yaw (deg).
    pub sequential_prior_sigma_deg: f64,
    /// Smallest standard deviation of a matched sequential edge in x and y (m): its
    /// information is the curvature of the match objective, capped at this.
    pub sequential_sigma_m: f64,
    /// Smallest standard deviation of a matched sequential edge in yaw (deg).
    pub sequential_sigma_deg: f64,
    /// A sequential match scoring below this (mean field value, 0..1) is replaced by the
    /// front end's relative motion with the `fallback_sigma_*` uncertainty.
    pub sequential_min_score: f64,
    /// Standard deviation of the front-end edge (the front end's relative motion) beside
    /// every match, and alone where the match failed, in x and y (m).
    pub fallback_sigma_m: f64,
    /// Standard deviation of the front-end edge in yaw (deg).
    pub fallback_sigma_deg: f64,
    /// Loop-closure candidates lie within this distance of the keyframe's estimate (m).
    pub loop_search_radius_m: f64,
    /// ... and at least this far back along the path (m).
    pub loop_min_path_m: f64,
    /// At most this many candidates are tried per keyframe (the nearest first).
    pub loop_max_candidates: usize,
    /// Loop closures are searched from every k-th keyframe (no gaps after closures:
    /// `docs/decisions/0021-loop-closure-search.md`).
    pub loop_every_keyframes: usize,
    /// Keyframes on each side of the candidate that form its submap.
    pub loop_submap_keyframes: usize,
    /// Half-width of the loop-closure search in x and y (m).
    pub loop_window_m: f64,
    /// Half-width of the loop-closure search in yaw (deg).
    pub loop_window_deg: f64,
    /// Minimum mean field value (0..1) of an accepted closure.
    pub loop_min_score: f64,
    /// A closure is ambiguous (rejected) if a pose farther than `loop_ambiguity_radius_m`
    /// from the best scores at least this fraction of the best.
    pub loop_ambiguity_ratio: f64,
    /// See `loop_ambiguity_ratio` (m).
    pub loop_ambiguity_radius_m: f64,
    /// Local loop-closure searches (Cartographer's constraint builder searches a small
    /// window where the relative pose is already known): a candidate whose region the
    /// graph has already tied to the current pass is verified in the small window
    /// `loop_local_window_*` around its estimate instead of `loop_window_*`, with
    /// `loop_local_ambiguity_radius_m`; the full window is searched when no closure vouches
    /// for the estimate, and after a local search whose best pose lies on the window's edge
    /// or scores too low. Vouched: after the last optimisation, a loop edge with a whitened
    /// squared error of at most `optimize_chi2` ends at most `loop_local_vouch_path_m` of
    /// path before the keyframe, and one (the same or another) has an end within that much
    /// path of the candidate. `auto` = on when the back end is fed the odometry (the car,
    /// whose calibrated odometry drifts centimetres over that path), off otherwise; `on`,
    /// `off`.
    pub loop_local_search: Switch,
    /// Half-width of the local loop-closure search in x and y (m).
    pub loop_local_window_m: f64,
    /// Half-width of the local loop-closure search in yaw (deg).
    pub loop_local_window_deg: f64,
    /// The local search's ambiguity radius (m): a pose at least this far from the best that
    /// scores `loop_ambiguity_ratio` of it makes the closure ambiguous. Smaller than
    /// `loop_ambiguity_radius_m` in proportion to the window, so the test still sees a
    /// street along which the scan slides (at 0.15 m a point's field value falls to a tenth,
    /// at 0.5 m to nothing: the two tests ask about as many points to pin the slide down).
    pub loop_local_ambiguity_radius_m: f64,
    /// See `loop_local_search` (m).
    pub loop_local_vouch_path_m: f64,
    /// Local searches only once the last optimisation left at least this many consistent
    /// loop edges: they accept fewer closures than the full window (the smaller ambiguity
    /// radius rejects broad match peaks), which a route closed again and again does not
    /// miss (the full-size car: 0.051 -> 0.049 m ATE) but a back end with few closures does
    /// (the default drive, 59 closures: local searches kept 18 and cost 1 % ATE).
    pub loop_local_min_closures: usize,
    /// A scan needs at least this many matching points to be matched at all (sequential
    /// edge, closure, refinement); fewer points fit anywhere.
    pub min_points: usize,
    /// Standard deviation of a loop-closure edge in x and y (m).
    pub loop_sigma_m: f64,
    /// Standard deviation of a loop-closure edge in yaw (deg).
    pub loop_sigma_deg: f64,
    /// Width of the Cauchy kernel of loop edges (whitened error units; 0 = no kernel).
    pub loop_kernel_width: f64,
    /// After the final optimisation, loop edges with a whitened squared error above this
    /// are removed and the graph optimised again.
    pub loop_outlier_chi2: f64,
    /// Optimise after accepted closures at most every this many keyframes ...
    pub optimize_every_keyframes: usize,
    /// ... or at once when a new closure disagrees with the current estimates by more than
    /// this whitened squared error (a loop closing after drift).
    pub optimize_chi2: f64,
    /// Levenberg-Marquardt iterations per optimisation.
    pub max_iterations: usize,
    /// A periodic optimisation (`optimize_every_keyframes`) stops when an iteration lowers
    /// the cost by less than this fraction: every new closure agreed with the estimates
    /// within `optimize_chi2`, so the correction is small, and these optimisations only give
    /// the next loop searches corrected estimates. Urgent and final optimisations stop at
    /// 1e-6. The full-size car: 375 -> 245 iterations in all; the default drive's
    /// closures and ATE unchanged (one iteration at most instead: 1 % worse there).
    pub periodic_relative_tolerance: f64,
    /// A periodic optimisation moves only the keyframes from this many before the last
    /// optimisation on (the others held where they are; 0 = the whole graph): every new
    /// closure agreed with the estimates, so it corrects the recent path against the map
    /// already closed, at a cost that does not grow with the graph (the full-size car's
    /// 25,000 keyframes: ~400 instead). Urgent (a loop closing after drift) and final
    /// optimisations move the whole graph.
    pub periodic_free_keyframes: usize,
    /// After the optimisation, match every scan between keyframes against the corrected
    /// keyframes around it (a small window around the pose composed from its keyframe), so
    /// the scans between keyframes do not keep the front end's local errors: `auto` (on; off
    /// when the back end is fed the odometry, see `input`), `on`, `off` (`true` / `false`
    /// read as `on` / `off`). Off for the odometry: the car's calibrated odometry is locally
    /// smoother than these matches
    /// (`docs/decisions/0022-car-back-end-on-calibrated-odometry.md`).
    pub refine_scans: Switch,
    /// Half-width of that refinement search in x and y (m).
    pub refine_window_m: f64,
    /// Half-width of that refinement search in yaw (deg).
    pub refine_window_deg: f64,
    /// When no loop closure survives, return the front end's trajectory unchanged: without
    /// a closure the back end only re-matches scans. (On the simulated car with sequential
    /// matching on, that re-matching drifted to 6.7 m: see `sequential_matching`.)
    pub keep_front_end_without_closures: bool,
    /// The back end's trajectory replaces the front end's only when the share of scan
    /// returns that land in cells its own map calls free is at most this multiple of the
    /// front end's, or at most 2 points above it (0 = always replaces). A wrong closure
    /// lays corridors over each other and raises that share. A back end that fails it and
    /// matched consecutive keyframes itself runs again without (`sequential_matching`
    /// off), guarded alike; see `docs/decisions/0006-self-check-and-back-end-guard.md`.
    pub max_free_share_ratio: f64,
    /// Sequential scan-matching edges: `auto` (on for a level LiDAR fixed on the body, off
    /// for a tilted or moving one), `on`, `off`. A tilted LiDAR's scan is a 3-D surface, so
    /// consecutive scans see roofs, canopies and parked cars at different heights; their
    /// matches are biased along the street, and on the simulated car 3,175 such edges
    /// stiffer than the front end dragged the graph to 6.7 m ATE (the front end: 0.18 m).
    /// Off, consecutive keyframes are tied by the front end's relative motion alone, with the
    /// `front_end_*` uncertainty below.
    pub sequential_matching: Switch,
    /// Without sequential matching: standard deviation of the front end's relative motion
    /// in x and y per square root of the distance travelled (m per sqrt(m)); a random walk,
    /// so over `L` m it is `this * sqrt(L)`.
    pub front_end_sigma_m_per_sqrt_m: f64,
    /// ... and in yaw (deg per sqrt(m)).
    pub front_end_sigma_deg_per_sqrt_m: f64,
    /// Without sequential matching: consecutive keyframes are also tied by the recording's
    /// odometry yaw (the car's FOG: 0.09 deg off after 1.4 km), with this random-walk
    /// uncertainty (deg per sqrt(m); 0 = no such edge), so the front end's local heading
    /// errors do not survive the optimisation.
    pub odometry_yaw_sigma_deg_per_sqrt_m: f64,
    /// Whether those odometry-yaw edges are added (only ever without sequential matching):
    /// `auto` = for a LiDAR fixed on the body (the car, whose odometry yaw is its FOG), not
    /// for one moving on the body (the humanoid, whose odometry yaw is leg odometry: there
    /// they pulled the default 180 s walk from 0.130 to 0.369 m ATE, seed 1).
    pub odometry_yaw_edges: Switch,
    /// What the back end is fed (its keyframes' initial poses and relative motions):
    /// `auto` (default: `calibrated_odometry` for a tilted LiDAR fixed on the body, the car;
    /// `front_end` otherwise), `front_end` (the filter's trajectory), `odometry` (the raw
    /// odometry) or `calibrated_odometry` (the odometry with its distance scale and yaw-rate
    /// bias fitted to the filter's trajectory, `[graph.calibration]`: locally as smooth as the
    /// odometry, without its scale drift).
    pub input: BackEndInput,
    /// The odometry calibration of `input = "calibrated_odometry"`.
    pub calibration: CalibrationOptions,
}

/// What the back end is fed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum BackEndInput {
    /// Decided from the recording (see [`GraphOptions::input`]).
    #[default]
    Auto,
    /// The filter's trajectory.
    FrontEnd,
    /// The raw odometry at every processed scan (to measure the back end alone).
    Odometry,
    /// The odometry corrected by a fit to the filter's trajectory
    /// ([`crate::motion::calibration`]).
    CalibratedOdometry,
}

impl BackEndInput {
    /// `auto` decided for `recording`: the calibrated odometry for a tilted LiDAR fixed on
    /// the body (the car: FOG yaw and 4096-tick wheels, locally far smoother than its filter,
    /// off only by the wheels' scale), the front end otherwise (a level LiDAR's `rbpf` is
    /// locally as good as the odometry; a head-mounted LiDAR's walker has leg odometry,
    /// which calibrated gave the default walk 0.33-0.34 m ATE against 0.12-0.13 m, seeds 1-3).
    pub fn resolve(self, recording: &Recording) -> BackEndInput {
        match self {
            BackEndInput::Auto => {
                let level = crate::filter::FilterMode::Auto.resolve(recording)
                    == crate::filter::FilterMode::Rbpf;
                if !level && recording.body_from_lidar_per_scan.is_none() {
                    BackEndInput::CalibratedOdometry
                } else {
                    BackEndInput::FrontEnd
                }
            }
            other => other,
        }
    }
}

/// A three-way switch: decided from the recording, or forced. Written `"auto"`, `"on"` or
/// `"off"`; `true` and `false` are read as `"on"` and `"off"` (a switch that was a boolean
/// before keeps reading old configurations).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case", try_from = "SwitchRepr")]
pub enum Switch {
    /// Decided from the recording (see the option).
    #[default]
    Auto,
    /// Always on.
    On,
    /// Always off.
    Off,
}

/// What a [`Switch`] is read from: its name or a boolean.
#[derive(Deserialize)]
#[serde(untagged)]
enum SwitchRepr {
    Bool(bool),
    Name(String),
}

impl TryFrom<SwitchRepr> for Switch {
    type Error = String;
    fn try_from(repr: SwitchRepr) -> Result<Self, String> {
        match repr {
            SwitchRepr::Bool(true) => Ok(Switch::On),
            SwitchRepr::Bool(false) => Ok(Switch::Off),
            SwitchRepr::Name(name) => match name.as_str() {
                "auto" => Ok(Switch::Auto),
                "on" => Ok(Switch::On),
                "off" => Ok(Switch::Off),
                _ => Err(format!(
                    "unknown value `{name}`, expected `auto`, `on`, `off`, true or false"
                )),
            },
        }
    }
}

impl Switch {
    /// On or off, `auto` taking what the recording decided.
    pub fn is_on(self, auto: bool) -> bool {
        match self {
            Switch::Auto => auto,
            Switch::On => true,
            Switch::Off => false,
        }
    }
}

impl Default for GraphOptions {
    fn default() -> Self {
        GraphOptions {
            enabled: true,
            keyframe_distance_m: 0.3,
            keyframe_angle_deg: 10.0,
            resolution_m: 0.05,
            field_sigma_m: 0.07,
            range_min_m: 0.1,
            range_max_m: 30.0,
            max_points: 200,
            submap_keyframes: 10,
            sequential_window_m: 0.15,
            sequential_window_deg: 3.0,
            yaw_step_deg: 0.3,
            sequential_prior_sigma_m: 0.1,
            sequential_prior_sigma_deg: 2.0,
            sequential_sigma_m: 0.02,
            sequential_sigma_deg: 0.5,
            sequential_min_score: 0.3,
            fallback_sigma_m: 0.1,
            fallback_sigma_deg: 2.0,
            loop_search_radius_m: 8.0,
            loop_min_path_m: 10.0,
            loop_max_candidates: 2,
            loop_every_keyframes: 5,
            loop_submap_keyframes: 20,
            // +-1.5 m / 10 deg: the default front end (`rbpf` on level LiDARs) drifts
            // centimetres, not metres; half the window halves Intel's matching at the same
            // error (measured; the 3 m / 20 deg window was sized for `scan_match` on Intel).
            loop_window_m: 1.5,
            loop_window_deg: 10.0,
            loop_min_score: 0.55,
            loop_ambiguity_ratio: 0.9,
            loop_ambiguity_radius_m: 0.5,
            loop_local_search: Switch::Auto,
            loop_local_window_m: 0.3,
            loop_local_window_deg: 2.0,
            loop_local_ambiguity_radius_m: 0.15,
            loop_local_vouch_path_m: 100.0,
            loop_local_min_closures: 200,
            min_points: 50,
            loop_sigma_m: 0.05,
            loop_sigma_deg: 1.0,
            loop_kernel_width: 3.0,
            loop_outlier_chi2: 100.0,
            // Fewer periodic optimisations (Intel: 71 -> ~36, the error unchanged); a
            // disagreeing closure still optimises at once: with that trigger at 100 instead
            // of 25, Intel seed 5 took a wrong closure (2.0 m).
            optimize_every_keyframes: 200,
            optimize_chi2: 25.0,
            max_iterations: 20,
            periodic_relative_tolerance: 1e-4,
            periodic_free_keyframes: 3000,
            refine_scans: Switch::Auto,
            refine_window_m: 0.05,
            refine_window_deg: 1.0,
            keep_front_end_without_closures: true,
            max_free_share_ratio: 1.5,
            sequential_matching: Switch::Auto,
            front_end_sigma_m_per_sqrt_m: 0.005,
            front_end_sigma_deg_per_sqrt_m: 0.004,
            odometry_yaw_sigma_deg_per_sqrt_m: 0.002,
            odometry_yaw_edges: Switch::Auto,
            input: BackEndInput::Auto,
            calibration: CalibrationOptions::default(),
        }
    }
}

impl GraphOptions {
    /// These options for a back end fed the odometry itself (`input` other than the front
    /// end): no odometry-yaw edges (they would count its yaw twice), `refine_scans =
    /// "auto"` off (re-matching the scans between keyframes would replace the odometry's
    /// smooth local motion by noisier matches) and `loop_local_search = "auto"` on.
    pub fn for_odometry_input(&self) -> GraphOptions {
        let mut opts = self.clone();
        opts.odometry_yaw_edges = Switch::Off;
        if opts.refine_scans == Switch::Auto {
            opts.refine_scans = Switch::Off;
        }
        if opts.loop_local_search == Switch::Auto {
            opts.loop_local_search = Switch::On;
        }
        opts
    }

    /// Checks ranges; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        self.calibration
            .validate()
            .map_err(|m| format!("graph.calibration: {m}"))?;
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !(self.max_free_share_ratio.is_finite() && self.max_free_share_ratio >= 0.0) {
            return Err("graph.max_free_share_ratio must be finite and >= 0".into());
        }
        for (k, v) in [
            ("keyframe_distance_m", self.keyframe_distance_m),
            ("keyframe_angle_deg", self.keyframe_angle_deg),
            ("yaw_step_deg", self.yaw_step_deg),
            ("resolution_m", self.resolution_m),
            ("field_sigma_m", self.field_sigma_m),
            ("range_max_m", self.range_max_m),
            ("sequential_prior_sigma_m", self.sequential_prior_sigma_m),
            (
                "sequential_prior_sigma_deg",
                self.sequential_prior_sigma_deg,
            ),
            ("sequential_sigma_m", self.sequential_sigma_m),
            ("sequential_sigma_deg", self.sequential_sigma_deg),
            ("fallback_sigma_m", self.fallback_sigma_m),
            ("fallback_sigma_deg", self.fallback_sigma_deg),
            ("loop_sigma_m", self.loop_sigma_m),
            ("loop_local_window_m", self.loop_local_window_m),
            ("loop_local_window_deg", self.loop_local_window_deg),
            (
                "loop_local_ambiguity_radius_m",
                self.loop_local_ambiguity_radius_m,
            ),
            ("loop_local_vouch_path_m", self.loop_local_vouch_path_m),
            ("loop_sigma_deg", self.loop_sigma_deg),
            ("loop_outlier_chi2", self.loop_outlier_chi2),
            ("optimize_chi2", self.optimize_chi2),
            (
                "periodic_relative_tolerance",
                self.periodic_relative_tolerance,
            ),
            (
                "front_end_sigma_m_per_sqrt_m",
                self.front_end_sigma_m_per_sqrt_m,
            ),
            (
                "front_end_sigma_deg_per_sqrt_m",
                self.front_end_sigma_deg_per_sqrt_m,
            ),
        ] {
            if !pos(v) {
                return Err(format!("graph.{k} must be positive and finite"));
            }
        }
        for (k, v) in [
            ("range_min_m", self.range_min_m),
            ("sequential_window_m", self.sequential_window_m),
            ("sequential_window_deg", self.sequential_window_deg),
            ("loop_search_radius_m", self.loop_search_radius_m),
            ("loop_min_path_m", self.loop_min_path_m),
            ("loop_window_m", self.loop_window_m),
            ("loop_window_deg", self.loop_window_deg),
            ("loop_ambiguity_radius_m", self.loop_ambiguity_radius_m),
            ("loop_kernel_width", self.loop_kernel_width),
            ("refine_window_m", self.refine_window_m),
            ("refine_window_deg", self.refine_window_deg),
            (
                "odometry_yaw_sigma_deg_per_sqrt_m",
                self.odometry_yaw_sigma_deg_per_sqrt_m,
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("graph.{k} must be finite and >= 0"));
            }
        }
        for (k, v) in [
            ("sequential_min_score", self.sequential_min_score),
            ("loop_min_score", self.loop_min_score),
            ("loop_ambiguity_ratio", self.loop_ambiguity_ratio),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("graph.{k} must lie in [0, 1]"));
            }
        }
        if self.sequential_window_m > 2.0 || self.loop_window_m > 10.0 {
            return Err("graph: sequential_window_m <= 2 and loop_window_m <= 10".into());
        }
        if self.loop_window_deg > 180.0 || self.sequential_window_deg > 45.0 {
            return Err("graph: sequential_window_deg <= 45 and loop_window_deg <= 180".into());
        }
        if self.loop_local_window_m > self.loop_window_m
            || self.loop_local_window_deg > self.loop_window_deg
        {
            return Err(
                "graph: loop_local_window_m <= loop_window_m and loop_local_window_deg <= \
                 loop_window_deg"
                    .into(),
            );
        }
        for (k, v) in [
            ("max_points", self.max_points),
            ("submap_keyframes", self.submap_keyframes),
            ("loop_every_keyframes", self.loop_every_keyframes),
            ("optimize_every_keyframes", self.optimize_every_keyframes),
        ] {
            if v == 0 {
                return Err(format!("graph.{k} must be at least 1"));
            }
        }
        Ok(())
    }
}

/// Counts and timings of a back-end run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct GraphStats {
    /// Keyframes (nodes).
    pub nodes: usize,
    /// Edges in the final graph.
    pub edges: usize,
    /// Sequential edges from a scan match.
    pub sequential_matched: usize,
    /// Sequential edges from the front end (match too poor).
    pub sequential_fallback: usize,
    /// Sequential edges from the front end alone (`sequential_matching` off).
    pub sequential_front_end: usize,
    /// Odometry-yaw edges (`odometry_yaw_sigma_deg_per_sqrt_m`).
    pub odometry_yaw_edges: usize,
    /// Loop-closure candidates tried.
    pub loop_candidates: usize,
    /// Closures accepted by the matcher.
    pub loop_accepted: usize,
    /// Candidates rejected: score too low or too few points.
    pub loop_rejected_score: usize,
    /// Candidates rejected as ambiguous.
    pub loop_rejected_ambiguous: usize,
    /// Candidates verified in the local window (`loop_local_search`), those counted again
    /// in `loop_local_fallbacks` included.
    pub loop_local: usize,
    /// ... of which searched again in the full window (best pose on the local window's
    /// edge, or too low a score).
    pub loop_local_fallbacks: usize,
    /// Accepted closures removed as outliers after optimisation.
    pub loop_removed_outliers: usize,
    /// Optimisations run.
    pub optimizations: usize,
    /// Levenberg-Marquardt iterations in all.
    pub iterations: usize,
    /// Robust cost after the final optimisation.
    pub final_cost: f64,
    /// Seconds in scan matching (sequential and loop).
    pub matching_s: f64,
    /// Seconds in optimisation.
    pub optimize_s: f64,
    /// Seconds in the final per-scan refinement.
    pub refine_s: f64,
    /// Seconds in all.
    pub total_s: f64,
}

/// What the back end produced.
#[derive(Debug, Clone)]
pub struct GraphResult {
    /// A corrected pose for every pose of the input trajectory (same stamps).
    pub trajectory: Vec<StampedPose2>,
    /// The corrected keyframe poses.
    pub keyframes: Vec<StampedPose2>,
    /// Index pairs `(from, to)` of the accepted loop closures (keyframe indices).
    pub loop_edges: Vec<(usize, usize)>,
    /// Counts and timings.
    pub stats: GraphStats,
}

/// One keyframe: its input-trajectory index, front-end pose and matching points.
struct Keyframe {
    traj_index: usize,
    front_pose: Pose2,
    points_body: Vec<[f64; 2]>,
    path_m: f64,
}

/// Runs the back end on `trajectory` (a pose at some scans of `recording`, e.g.
/// [`crate::filter::slam::SlamResult::trajectory`]), using `scan_opts` for preprocessing.
pub fn optimize_trajectory(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
) -> Result<GraphResult, GraphError> {
    optimize_trajectory_look_ahead(recording, scan_opts, trajectory, opts, LOOK_AHEAD_SEARCHES)
}

/// [`optimize_trajectory`] verifying the loop searches of up to `look_ahead` keyframes in
/// one parallel batch (the default [`LOOK_AHEAD_SEARCHES`]; 1 = one keyframe at a time):
/// the same result for any value (tested).
#[doc(hidden)]
pub fn optimize_trajectory_look_ahead(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
    look_ahead: usize,
) -> Result<GraphResult, GraphError> {
    opts.validate().map_err(GraphError::Options)?;
    let t_start = Instant::now();
    let mut stats = GraphStats::default();
    let keyframes = select_keyframes(recording, scan_opts, trajectory, opts)?;
    let mut graph = PoseGraph::default();
    let mut loop_edges: Vec<usize> = Vec::new();
    let opt_opts = OptimizeOptions {
        max_iterations: opts.max_iterations,
        ..OptimizeOptions::default()
    };
    let periodic_opts = OptimizeOptions {
        relative_tolerance: opts.periodic_relative_tolerance,
        ..opt_opts
    };
    let seq_win = SearchWindow {
        xy_m: opts.sequential_window_m,
        yaw_rad: opts.sequential_window_deg.to_radians(),
        yaw_step_rad: opts.yaw_step_deg.to_radians(),
    };
    let loop_win = SearchWindow {
        xy_m: opts.loop_window_m,
        yaw_rad: opts.loop_window_deg.to_radians(),
        yaw_step_rad: seq_win.yaw_step_rad,
    };
    let local_win = SearchWindow {
        xy_m: opts.loop_local_window_m,
        yaw_rad: opts.loop_local_window_deg.to_radians(),
        yaw_step_rad: seq_win.yaw_step_rad,
    };
    // What the last optimisation vouches for (nothing before the first).
    let local_on = opts.loop_local_search.is_on(false);
    let mut vouches = Vouches::default();
    let mut closures_pending = false;
    let mut urgent = false;
    let mut last_opt = 0usize;
    let mut submap_pts: Vec<[f64; 2]> = Vec::new();
    // Loop searches verified ahead, valid while the graph is not optimised.
    let mut ahead: Option<LookAhead> = None;
    let mut generation = 0usize;
    // `auto`: sequential matching for a level LiDAR fixed on the body (the recordings `auto`
    // runs `rbpf` on); odometry-yaw edges for a LiDAR fixed on the body.
    let level_and_fixed =
        crate::filter::FilterMode::Auto.resolve(recording) == crate::filter::FilterMode::Rbpf;
    let seq_matching = opts.sequential_matching.is_on(level_and_fixed);
    let yaw_edges = !seq_matching
        && opts.odometry_yaw_sigma_deg_per_sqrt_m > 0.0
        && opts
            .odometry_yaw_edges
            .is_on(recording.body_from_lidar_per_scan.is_none());
    for k in 0..keyframes.len() {
        let kf = &keyframes[k];
        if k == 0 {
            graph.poses.push(kf.front_pose);
            continue;
        }
        let t = Instant::now();
        let prev = &keyframes[k - 1];
        let rel_front = prev.front_pose.between(&kf.front_pose);
        let predicted = graph.poses[k - 1].compose(&rel_front);
        // Sequential edge: match against the previous keyframes' submap.
        let first = k.saturating_sub(opts.submap_keyframes);
        gather_points(&keyframes, &graph.poses, first..k, &mut submap_pts);
        let margin = opts.sequential_window_m + 3.0 * opts.field_sigma_m + opts.resolution_m;
        let bounds = bounds_around(&kf.points_body, &predicted, margin)
            .and_then(|b| clip_to_points(b, &submap_pts, 3.0 * opts.field_sigma_m));
        let enough = seq_matching && kf.points_body.len() >= opts.min_points;
        let matched = bounds.filter(|_| enough).and_then(|(lo, hi)| {
            let field = PointField::build(
                &submap_pts,
                lo,
                hi,
                opts.resolution_m,
                opts.field_sigma_m,
                0,
            );
            let prior = Prior {
                pose: predicted,
                sigma_xy_m: opts.sequential_prior_sigma_m,
                sigma_yaw_rad: opts.sequential_prior_sigma_deg.to_radians(),
            };
            let coarse = field.search_with_prior(&kf.points_body, &prior, &seq_win);
            let (pose, score) = field.refine(
                &kf.points_body,
                &coarse,
                seq_win.yaw_step_rad,
                4,
                Some(&prior),
            );
            (score >= opts.sequential_min_score).then(|| {
                let curv = field.curvature(
                    &kf.points_body,
                    &pose,
                    0.5 * opts.resolution_m,
                    seq_win.yaw_step_rad,
                );
                (pose, curv)
            })
        });
        // The front end's relative motion always constrains the pair (weakly): where the
        // match pins nothing down (along a corridor) it decides. Without sequential matching
        // it is the only edge, with its random-walk uncertainty.
        let (sigma_m, sigma_deg) = match seq_matching {
            true => (opts.fallback_sigma_m, opts.fallback_sigma_deg),
            false => {
                let root = rel_front.translation_norm_m().max(0.01).sqrt();
                (
                    opts.front_end_sigma_m_per_sqrt_m * root,
                    opts.front_end_sigma_deg_per_sqrt_m * root,
                )
            }
        };
        let front_edge =
            Edge::with_sigmas(k - 1, k, rel_front, sigma_m, sigma_deg.to_radians(), None);
        let (pose, edge) = match matched {
            Some((pose, curv)) => {
                stats.sequential_matched += 1;
                let z = graph.poses[k - 1].between(&pose);
                let e = Edge {
                    from: k - 1,
                    to: k,
                    measurement: z,
                    information: capped_information(
                        &curv,
                        pose.yaw_rad,
                        opts.sequential_sigma_m,
                        opts.sequential_sigma_deg.to_radians(),
                    ),
                    robust_width: None,
                };
                graph.edges.push(front_edge);
                (pose, e)
            }
            None if seq_matching => {
                stats.sequential_fallback += 1;
                (predicted, front_edge)
            }
            None => {
                stats.sequential_front_end += 1;
                (predicted, front_edge)
            }
        };
        graph.poses.push(pose);
        graph.edges.push(edge);
        if yaw_edges {
            let odo = &recording.odometry;
            let stamp = |kf: &Keyframe| trajectory[kf.traj_index].stamp_ns;
            if let (Some(a), Some(b)) = (odo.pose_at(stamp(prev)), odo.pose_at(stamp(kf))) {
                // Yaw only: the x/y standard deviation is far beyond any error.
                let z = a.between(&b);
                let root = z.translation_norm_m().max(0.01).sqrt();
                let sigma_yaw_deg = opts.odometry_yaw_sigma_deg_per_sqrt_m * root;
                graph.edges.push(Edge::with_sigmas(
                    k - 1,
                    k,
                    z,
                    1e3,
                    sigma_yaw_deg.to_radians(),
                    None,
                ));
                stats.odometry_yaw_edges += 1;
            }
        }
        // Loop closures.
        let due = k % opts.loop_every_keyframes == 0 && kf.points_body.len() >= opts.min_points;
        if due {
            // A look-ahead job computed before any optimisation since, at the same pose:
            // the same candidates (the earlier keyframes' poses are the same bits).
            let cached = match &mut ahead {
                Some(a) if a.generation == generation => a
                    .jobs
                    .iter()
                    .position(|j| j.k == k && j.pose == pose)
                    .map(|at| a.jobs.swap_remove(at)),
                _ => None,
            };
            let (tried, verdicts) = match cached {
                Some(job) => (job.tried, job.verdicts),
                None => {
                    let tried = loop_candidates(&keyframes, &graph.poses, k, &pose, opts);
                    if tried.is_empty() {
                        (tried, Vec::new())
                    } else {
                        // The look-ahead's predicted poses go onto the graph's (removed
                        // after the batch): no copy of the whole path per batch.
                        let mut jobs = if !seq_matching && look_ahead > 1 {
                            // No periodic optimisation before `last_opt + every`: up to
                            // there the look-ahead cannot be overtaken by one.
                            let bound = last_opt + opts.optimize_every_keyframes;
                            let (searches, last) = if k < bound {
                                (look_ahead, bound)
                            } else {
                                (look_ahead.min(LOOK_AHEAD_UNBOUNDED), usize::MAX)
                            };
                            look_ahead_jobs(&keyframes, &mut graph.poses, k, searches, last, opts)
                        } else {
                            Vec::new()
                        };
                        jobs.insert(
                            0,
                            AheadJob {
                                k,
                                pose,
                                tried: tried.clone(),
                                verdicts: Vec::new(),
                            },
                        );
                        let poses: &[Pose2] = &graph.poses;
                        // All independent: verified in parallel, collected in order.
                        let pairs: Vec<(usize, usize)> = jobs
                            .iter()
                            .enumerate()
                            .flat_map(|(a, job)| job.tried.iter().map(move |&j| (a, j)))
                            .collect();
                        // Whether a candidate is searched locally depends only on the last
                        // optimisation, which the look-ahead's verdicts are valid for.
                        let vouches = &vouches;
                        let found: Vec<Checked> = pairs
                            .par_iter()
                            .map(|&(a, j)| {
                                let job = &jobs[a];
                                let local = (local_on && vouches.vouch(&keyframes, job.k, j, opts))
                                    .then_some(&local_win);
                                verify_candidate(
                                    &keyframes, poses, job.k, j, &job.pose, &loop_win, local, opts,
                                )
                            })
                            .collect();
                        for (&(a, _), v) in pairs.iter().zip(found) {
                            jobs[a].verdicts.push(v);
                        }
                        graph.poses.truncate(k + 1);
                        let own = jobs.swap_remove(0).verdicts;
                        ahead = Some(LookAhead { generation, jobs });
                        (tried, own)
                    }
                }
            };
            stats.loop_candidates += tried.len();
            for (&j, checked) in tried.iter().zip(verdicts) {
                stats.loop_local += usize::from(checked.search != Search::Full);
                stats.loop_local_fallbacks += usize::from(checked.search == Search::LocalThenFull);
                match checked.verdict {
                    Verdict::Accepted(found) => {
                        stats.loop_accepted += 1;
                        let z = graph.poses[j].between(&found);
                        let width =
                            (opts.loop_kernel_width > 0.0).then_some(opts.loop_kernel_width);
                        graph.edges.push(Edge::with_sigmas(
                            j,
                            k,
                            z,
                            opts.loop_sigma_m,
                            opts.loop_sigma_deg.to_radians(),
                            width,
                        ));
                        loop_edges.push(graph.edges.len() - 1);
                        closures_pending = true;
                        if graph.edge_chi2(graph.edges.len() - 1) > opts.optimize_chi2 {
                            urgent = true;
                        }
                    }
                    Verdict::LowScore => stats.loop_rejected_score += 1,
                    Verdict::Ambiguous => stats.loop_rejected_ambiguous += 1,
                }
            }
        }
        stats.matching_s += t.elapsed().as_secs_f64();
        if urgent || (closures_pending && k - last_opt >= opts.optimize_every_keyframes) {
            let t = Instant::now();
            let r = match urgent {
                true => graph.optimize(&opt_opts),
                // Keyframe 0 is always held: from keyframe 1 on is the whole graph.
                false
                    if opts.periodic_free_keyframes > 0
                        && last_opt > opts.periodic_free_keyframes + 1 =>
                {
                    let first = last_opt - opts.periodic_free_keyframes;
                    optimize_tail(&mut graph, first, &periodic_opts)
                }
                false => graph.optimize(&periodic_opts),
            };
            generation += 1;
            if local_on {
                vouches = Vouches::after_optimisation(&graph, &loop_edges, &keyframes, opts);
            }
            stats.optimizations += 1;
            stats.iterations += r.iterations;
            stats.optimize_s += t.elapsed().as_secs_f64();
            closures_pending = false;
            urgent = false;
            last_opt = k;
        }
    }
    // Final optimisation, outlier removal, again.
    let t = Instant::now();
    let r = graph.optimize(&opt_opts);
    stats.optimizations += 1;
    stats.iterations += r.iterations;
    let outliers: Vec<usize> = loop_edges
        .iter()
        .copied()
        .filter(|&e| graph.edge_chi2(e) > opts.loop_outlier_chi2)
        .collect();
    if !outliers.is_empty() {
        stats.loop_removed_outliers = outliers.len();
        let mut keep = vec![true; graph.edges.len()];
        for &e in &outliers {
            keep[e] = false;
        }
        let mut idx = 0;
        graph.edges.retain(|_| {
            idx += 1;
            keep[idx - 1]
        });
        let r = graph.optimize(&opt_opts);
        stats.optimizations += 1;
        stats.iterations += r.iterations;
    }
    stats.final_cost = graph.cost();
    stats.optimize_s += t.elapsed().as_secs_f64();
    stats.nodes = graph.poses.len();
    stats.edges = graph.edges.len();
    let loop_pairs = graph
        .edges
        .iter()
        .filter(|e| e.to != e.from + 1)
        .map(|e| (e.from, e.to))
        .collect();
    let t = Instant::now();
    let closed = stats.loop_accepted > stats.loop_removed_outliers;
    if !closed && opts.keep_front_end_without_closures {
        graph.poses = keyframes.iter().map(|kf| kf.front_pose).collect();
    }
    let mut out = correct_trajectory(trajectory, &keyframes, &graph.poses);
    if opts.refine_scans.is_on(true) && (closed || !opts.keep_front_end_without_closures) {
        refine_scans(
            recording,
            scan_opts,
            trajectory,
            &keyframes,
            &graph.poses,
            opts,
            &mut out,
        )?;
    }
    stats.refine_s = t.elapsed().as_secs_f64();
    let kf_out = keyframes
        .iter()
        .zip(&graph.poses)
        .map(|(kf, p)| StampedPose2 {
            stamp_ns: trajectory[kf.traj_index].stamp_ns,
            pose: *p,
        })
        .collect();
    stats.total_s = t_start.elapsed().as_secs_f64();
    Ok(GraphResult {
        trajectory: out,
        keyframes: kf_out,
        loop_edges: loop_pairs,
        stats,
    })
}

/// Optimises keyframes `first..` of `graph` (`first >= 1`) with the earlier ones held
/// fixed: a graph of those keyframes behind a fixed origin, each edge from a fixed keyframe
/// re-anchored at the origin (its measurement composed with the fixed pose: the same
/// error), edges between fixed keyframes left out (their error cannot change). Every edge
/// here runs from an earlier keyframe to a later one; should one run backwards into the
/// fixed part, the whole graph is optimised instead.
fn optimize_tail(
    graph: &mut PoseGraph,
    first: usize,
    opts: &OptimizeOptions,
) -> optimize::OptimizeReport {
    if first >= graph.poses.len() || graph.edges.iter().any(|e| e.from >= first && e.to < first) {
        return graph.optimize(opts);
    }
    let mut tail = PoseGraph {
        poses: Vec::with_capacity(graph.poses.len() - first + 1),
        edges: Vec::new(),
    };
    tail.poses.push(Pose2::IDENTITY);
    tail.poses.extend_from_slice(&graph.poses[first..]);
    let at = |v: usize| v + 1 - first;
    for e in graph.edges.iter().filter(|e| e.to >= first) {
        tail.edges.push(match e.from >= first {
            true => Edge {
                from: at(e.from),
                to: at(e.to),
                ..*e
            },
            false => Edge {
                from: 0,
                to: at(e.to),
                measurement: graph.poses[e.from].compose(&e.measurement),
                ..*e
            },
        });
    }
    let r = tail.optimize(opts);
    graph.poses[first..].copy_from_slice(&tail.poses[1..]);
    r
}

/// Keyframes due for a loop search verified in one parallel batch, up to the next periodic
/// optimisation: the loop-closure verifications of a keyframe with one candidate left a
/// core idle in the serial parts (branch and bound, refinement), and a small batch leaves
/// one idle at its end (the full-size car: 4 searches a batch, 900 batches; 16, 285).
pub const LOOK_AHEAD_SEARCHES: usize = 16;

/// ... but at most this many when an optimisation may come at any accepted closure (after
/// `optimize_every_keyframes` without one): a look-ahead past it is discarded.
const LOOK_AHEAD_UNBOUNDED: usize = 4;

/// One keyframe's loop search verified ahead.
struct AheadJob {
    k: usize,
    pose: Pose2,
    tried: Vec<usize>,
    verdicts: Vec<Checked>,
}

/// The look-ahead verdicts and the optimisation count they were computed at.
struct LookAhead {
    generation: usize,
    jobs: Vec<AheadJob>,
}

/// The loop searches of the keyframes after `k` (the graph's last pose, `poses` = keyframes
/// `0..=k`) up to keyframe `last` until `look_ahead - 1` of them have candidates, for a
/// graph without sequential matching: each later keyframe's pose follows from the previous
/// one by the front end's motion alone, composed exactly as
/// `optimize_trajectory_look_ahead` does, so until the next optimisation these are the bits
/// it will find. Returns the jobs (verdicts empty); `poses` is extended to the last
/// keyframe looked at.
fn look_ahead_jobs(
    keyframes: &[Keyframe],
    poses: &mut Vec<Pose2>,
    k: usize,
    look_ahead: usize,
    last: usize,
    opts: &GraphOptions,
) -> Vec<AheadJob> {
    let mut jobs = Vec::new();
    let mut p = poses[k];
    let mut searches = 1;
    for m in k + 1..keyframes.len().min(last.saturating_add(1)) {
        if searches >= look_ahead {
            break;
        }
        let rel = keyframes[m - 1]
            .front_pose
            .between(&keyframes[m].front_pose);
        p = p.compose(&rel);
        poses.push(p);
        if m % opts.loop_every_keyframes == 0 && keyframes[m].points_body.len() >= opts.min_points {
            let tried = loop_candidates(keyframes, poses, m, &p, opts);
            searches += usize::from(!tried.is_empty());
            jobs.push(AheadJob {
                k: m,
                pose: p,
                tried,
                verdicts: Vec::new(),
            });
        }
    }
    jobs
}

/// The loop-closure candidates of keyframe `k` at `pose`: earlier keyframes (at `poses`)
/// within `loop_search_radius_m` and at least `loop_min_path_m` back along the path, the
/// nearest first, at most `loop_max_candidates`, no two within `loop_submap_keyframes`.
fn loop_candidates(
    keyframes: &[Keyframe],
    poses: &[Pose2],
    k: usize,
    pose: &Pose2,
    opts: &GraphOptions,
) -> Vec<usize> {
    let path_m = keyframes[k].path_m;
    let radius = opts.loop_search_radius_m;
    let near = pose.x_m.abs() + pose.y_m.abs() + radius + 1.0;
    let mut cands: Vec<(f64, usize)> = (0..k)
        .filter(|&j| path_m - keyframes[j].path_m >= opts.loop_min_path_m)
        .filter_map(|j| {
            let q = &poses[j];
            // The distance is `between`'s (its rounding decides ties and the radius), but
            // only worth computing (a `sin_cos` and a `hypot`) near the radius: the plain
            // difference differs from it by rounding alone (~1e-15 of the coordinates),
            // far inside this margin. NaN never skips.
            let (dx, dy) = (pose.x_m - q.x_m, pose.y_m - q.y_m);
            let reach = radius + 1e-9 * (near + q.x_m.abs() + q.y_m.abs());
            if dx * dx + dy * dy > reach * reach {
                return None;
            }
            let d = q.between(pose).translation_norm_m();
            (d <= radius).then_some((d, j))
        })
        .collect();
    cands.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut tried: Vec<usize> = Vec::new();
    for &(_, j) in &cands {
        if tried.len() >= opts.loop_max_candidates {
            break;
        }
        // Candidates next to one already tried would test the same submap.
        if tried
            .iter()
            .any(|&t| t.abs_diff(j) <= opts.loop_submap_keyframes)
        {
            continue;
        }
        tried.push(j);
    }
    tried
}

/// Which windows a loop candidate was searched in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Search {
    /// The full window (`loop_window_*`).
    Full,
    /// The local window (`loop_local_window_*`).
    Local,
    /// The local window, then the full one (the best pose on the local window's edge, or
    /// too low a score).
    LocalThenFull,
}

/// A candidate's verdict and where it was searched.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Checked {
    verdict: Verdict,
    search: Search,
}

/// What the last optimisation vouches for: the loop edges it left consistent (whitened
/// squared error at most `optimize_chi2`), by the path lengths at their ends (see
/// `GraphOptions::loop_local_search`).
#[derive(Debug, Clone)]
struct Vouches {
    /// Path length (m) at the later end of the last consistent loop edge.
    last_path_m: f64,
    /// Path lengths (m) at both ends of every consistent loop edge, sorted (empty when
    /// fewer than `loop_local_min_closures`: no vouch).
    ends_path_m: Vec<f64>,
}

impl Default for Vouches {
    fn default() -> Self {
        Vouches {
            last_path_m: f64::NEG_INFINITY,
            ends_path_m: Vec::new(),
        }
    }
}

impl Vouches {
    /// After an optimisation of `graph`, whose loop edges are `graph.edges[loop_edges]`.
    fn after_optimisation(
        graph: &PoseGraph,
        loop_edges: &[usize],
        keyframes: &[Keyframe],
        opts: &GraphOptions,
    ) -> Vouches {
        let mut out = Vouches::default();
        for &e in loop_edges {
            if graph.edge_chi2(e) > opts.optimize_chi2 {
                continue;
            }
            let edge = &graph.edges[e];
            let (a, b) = (keyframes[edge.from].path_m, keyframes[edge.to].path_m);
            out.last_path_m = out.last_path_m.max(a.max(b));
            out.ends_path_m.extend([a, b]);
        }
        if out.ends_path_m.len() < 2 * opts.loop_local_min_closures {
            return Vouches::default();
        }
        out.ends_path_m.sort_by(f64::total_cmp);
        out
    }

    /// Whether candidate `j` of keyframe `k` is searched in the local window: a consistent
    /// loop edge ends at most `loop_local_vouch_path_m` before `k`, and one within that
    /// much of `j` (none vouches below `loop_local_min_closures`).
    fn vouch(&self, keyframes: &[Keyframe], k: usize, j: usize, opts: &GraphOptions) -> bool {
        let d = opts.loop_local_vouch_path_m;
        let (pk, pj) = (keyframes[k].path_m, keyframes[j].path_m);
        if pk - self.last_path_m > d {
            return false;
        }
        let at = self.ends_path_m.partition_point(|&p| p < pj - d);
        self.ends_path_m.get(at).is_some_and(|&p| p <= pj + d)
    }
}

/// Verifies keyframe `k` (at `pose`) against the submap around candidate `j` (keyframes at
/// `poses`, only those before `k`): in `local` when given, and in `loop_win` when not or
/// when the local search's best pose lies on its edge or scores too low.
#[allow(clippy::too_many_arguments)]
fn verify_candidate(
    keyframes: &[Keyframe],
    poses: &[Pose2],
    k: usize,
    j: usize,
    pose: &Pose2,
    loop_win: &SearchWindow,
    local: Option<&SearchWindow>,
    opts: &GraphOptions,
) -> Checked {
    let kf = &keyframes[k];
    let lo = j.saturating_sub(opts.loop_submap_keyframes);
    let hi = (j + opts.loop_submap_keyframes + 1).min(k);
    let mut submap = Vec::new();
    gather_points(keyframes, poses, lo..hi, &mut submap);
    // The local window's search is small beside building a pooled level: one level fewer
    // (+-0.3 m: 2 levels, 4 x 4 top-level nodes per yaw).
    let in_window = |win: &SearchWindow, ambiguity_radius_m: f64, edge_stops: bool| {
        let levels = match edge_stops {
            true => levels_for(win.xy_m, opts.resolution_m).saturating_sub(1),
            false => levels_for(win.xy_m, opts.resolution_m),
        };
        let margin = win.xy_m + 3.0 * opts.field_sigma_m + opts.resolution_m;
        let Some((blo, bhi)) = bounds_around(&kf.points_body, pose, margin)
            .and_then(|b| clip_to_points(b, &submap, 3.0 * opts.field_sigma_m))
        else {
            return Some(Verdict::LowScore);
        };
        let field = PointField::build(
            &submap,
            blo,
            bhi,
            opts.resolution_m,
            opts.field_sigma_m,
            levels,
        );
        let points = &kf.points_body;
        verify_closure_in(
            &field,
            points,
            pose,
            win,
            ambiguity_radius_m,
            edge_stops,
            opts,
        )
    };
    let mut search = Search::Full;
    if let Some(win) = local {
        match in_window(win, opts.loop_local_ambiguity_radius_m, true) {
            None | Some(Verdict::LowScore) => search = Search::LocalThenFull,
            Some(verdict) => {
                return Checked {
                    verdict,
                    search: Search::Local,
                };
            }
        }
    }
    let verdict = in_window(loop_win, opts.loop_ambiguity_radius_m, false);
    Checked {
        verdict: verdict.unwrap_or(Verdict::LowScore),
        search,
    }
}

/// The outcome of a loop-closure verification.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// The matched pose of the scan (world frame of the submap).
    Accepted(Pose2),
    /// Best score below `loop_min_score` (or too few points).
    LowScore,
    /// Another pose scores nearly as well.
    Ambiguous,
}

/// Matches `points_body` in `field` over `win` around `centre` and applies the acceptance
/// tests of `opts` (score, ambiguity); refines an accepted match below a cell.
pub fn verify_closure(
    field: &PointField,
    points_body: &[[f64; 2]],
    centre: &Pose2,
    win: &SearchWindow,
    opts: &GraphOptions,
) -> Verdict {
    let radius = opts.loop_ambiguity_radius_m;
    verify_closure_in(field, points_body, centre, win, radius, false, opts)
        .unwrap_or(Verdict::LowScore)
}

/// [`verify_closure`] with the ambiguity radius `ambiguity_radius_m`. With `edge_stops`,
/// `None` when the best pose on the cell grid lies on the window's edge (in x, y or yaw:
/// the best of a larger window may lie beyond it), before the ambiguity test.
pub fn verify_closure_in(
    field: &PointField,
    points_body: &[[f64; 2]],
    centre: &Pose2,
    win: &SearchWindow,
    ambiguity_radius_m: f64,
    edge_stops: bool,
    opts: &GraphOptions,
) -> Option<Verdict> {
    if points_body.len() < opts.min_points {
        return Some(Verdict::LowScore);
    }
    // Both searches start from the same top level: score it once.
    let Some(start) = field.bnb_start(points_body, centre, win) else {
        return Some(Verdict::LowScore);
    };
    let Some((best, score)) = field.search_bnb_from(&start, opts.loop_min_score, None) else {
        return Some(Verdict::LowScore);
    };
    if edge_stops && field.on_window_edge(&start, &best) {
        return None;
    }
    let exclusion = (best, ambiguity_radius_m, win.yaw_rad * 2.0 + 1.0);
    if field.any_bnb_from(&start, opts.loop_ambiguity_ratio * score, Some(exclusion)) {
        return Some(Verdict::Ambiguous);
    }
    let (pose, _) = field.refine(points_body, &best, win.yaw_step_rad, 4, None);
    Some(Verdict::Accepted(pose))
}

/// The information of a match edge: the match's curvature (world x, y, yaw) in the edge's
/// error frame (rotated into the matched pose's frame), its eigenvalues capped, after
/// whitening by `sigma_xy_m` / `sigma_yaw_rad`, at 1 (no direction more certain than those
/// standard deviations) and floored at 0.
fn capped_information(
    curvature_world: &nalgebra::Matrix3<f64>,
    yaw_rad: f64,
    sigma_xy_m: f64,
    sigma_yaw_rad: f64,
) -> nalgebra::Matrix3<f64> {
    let (s, c) = yaw_rad.sin_cos();
    let r = nalgebra::Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let local = r.transpose() * curvature_world * r;
    let w = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(
        sigma_xy_m,
        sigma_xy_m,
        sigma_yaw_rad,
    ));
    let m = w * local * w;
    let m = (m + m.transpose()) * 0.5;
    let eig = m.symmetric_eigen();
    let capped = eig.eigenvalues.map(|v| v.clamp(0.0, 1.0));
    let m =
        eig.eigenvectors * nalgebra::Matrix3::from_diagonal(&capped) * eig.eigenvectors.transpose();
    let winv = w.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
    winv * m * winv
}

/// Pooled levels of a branch-and-bound field for a window of half-width `window_m`: the
/// fewest whose top level's blocks (`2^levels` cells) are as wide as the half-width, at
/// most 6. The search's top level then has 2 x 2 nodes per yaw (+-1.5 m at 0.05 m: 5
/// levels); with 3 levels (the top level an eighth of the window, before) it had 8 x 8, and
/// scoring those was two fifths of the full-size car's back end. The answer is the same
/// for any number of levels (the branch and bound is exact on the cell grid).
fn levels_for(window_m: f64, resolution_m: f64) -> usize {
    let cells = (window_m / resolution_m).ceil().max(1.0);
    (cells.log2().ceil().max(0.0) as usize).min(6)
}

/// The world-frame bounding box of `points_body` seen from `pose`, grown by `margin_m`.
fn bounds_around(
    points_body: &[[f64; 2]],
    pose: &Pose2,
    margin_m: f64,
) -> Option<([f64; 2], [f64; 2])> {
    if points_body.is_empty() {
        return None;
    }
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in points_body {
        let (x, y) = pose.transform_point(p[0], p[1]);
        lo = [lo[0].min(x), lo[1].min(y)];
        hi = [hi[0].max(x), hi[1].max(y)];
    }
    Some((
        [lo[0] - margin_m, lo[1] - margin_m],
        [hi[0] + margin_m, hi[1] + margin_m],
    ))
}

/// `bounds` cut to the bounding box of `points` grown by `margin_m`; `None` if they do not
/// overlap.
fn clip_to_points(
    bounds: ([f64; 2], [f64; 2]),
    points: &[[f64; 2]],
    margin_m: f64,
) -> Option<([f64; 2], [f64; 2])> {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        lo = [lo[0].min(p[0]), lo[1].min(p[1])];
        hi = [hi[0].max(p[0]), hi[1].max(p[1])];
    }
    let lo = [
        bounds.0[0].max(lo[0] - margin_m),
        bounds.0[1].max(lo[1] - margin_m),
    ];
    let hi = [
        bounds.1[0].min(hi[0] + margin_m),
        bounds.1[1].min(hi[1] + margin_m),
    ];
    (lo[0] < hi[0] && lo[1] < hi[1]).then_some((lo, hi))
}

/// World-frame points of keyframes `range` at `poses` into `out`.
fn gather_points(
    keyframes: &[Keyframe],
    poses: &[Pose2],
    range: std::ops::Range<usize>,
    out: &mut Vec<[f64; 2]>,
) {
    out.clear();
    for j in range {
        let p = &poses[j];
        out.extend(keyframes[j].points_body.iter().map(|q| {
            let (x, y) = p.transform_point(q[0], q[1]);
            [x, y]
        }));
    }
}

/// Keyframes along `trajectory` with their matching points.
fn select_keyframes(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    opts: &GraphOptions,
) -> Result<Vec<Keyframe>, GraphError> {
    let mut pts = ScanPoints::new(recording, scan_opts, opts)?;
    let mut out: Vec<Keyframe> = Vec::new();
    let mut path_m = 0.0;
    let mut last_pose: Option<Pose2> = None;
    let mut last_kf: Option<Pose2> = None;
    for (t, sp) in trajectory.iter().enumerate() {
        if let Some(lp) = last_pose {
            path_m += lp.between(&sp.pose).translation_norm_m();
        }
        last_pose = Some(sp.pose);
        let due = match last_kf {
            None => true,
            Some(kp) => {
                let d = kp.between(&sp.pose);
                d.translation_norm_m() >= opts.keyframe_distance_m
                    || d.yaw_rad.abs() >= opts.keyframe_angle_deg.to_radians()
            }
        };
        // The last pose is always a keyframe, so every pose has one before it.
        if !due && t + 1 != trajectory.len() {
            continue;
        }
        let points_body = pts.at_stamp(sp.stamp_ns)?;
        if out.is_empty() || due || t + 1 == trajectory.len() {
            out.push(Keyframe {
                traj_index: t,
                front_pose: sp.pose,
                points_body,
                path_m,
            });
            last_kf = Some(sp.pose);
        }
    }
    Ok(out)
}

/// The matching points of a recording's scans, looked up by stamp.
#[derive(Clone)]
struct ScanPoints<'a> {
    recording: &'a Recording,
    projector: ScanProjector,
    body: PlanarScan,
    range_max_m: f64,
    max_points: usize,
}

impl<'a> ScanPoints<'a> {
    fn new(
        recording: &'a Recording,
        scan_opts: &ScanOptions,
        opts: &GraphOptions,
    ) -> Result<Self, GraphError> {
        // Matching takes every return in the range window; densification would only add
        // correlated points.
        let proj_opts = ScanOptions {
            range_min_m: opts.range_min_m as f32,
            range_max_m: scan_opts.range_max_m.max(opts.range_max_m as f32),
            densify_max_gap_m: None,
            ..*scan_opts
        };
        let projector =
            ScanProjector::new(&recording.lidar, &recording.body_from_lidar, &proj_opts)?;
        Ok(ScanPoints {
            recording,
            projector,
            body: PlanarScan::default(),
            range_max_m: opts.range_max_m,
            max_points: opts.max_points,
        })
    }

    /// Returns of the scan stamped `stamp_ns` within `range_max_m` of the sensor, evenly
    /// thinned to `max_points` (empty when no scan has that stamp).
    fn at_stamp(&mut self, stamp_ns: i64) -> Result<Vec<[f64; 2]>, GraphError> {
        let rec = self.recording;
        let stamps = &rec.scans.stamps_ns;
        let i = stamps.partition_point(|&s| s < stamp_ns);
        if i >= stamps.len() || stamps[i] != stamp_ns {
            return Ok(Vec::new());
        }
        self.projector.aim(rec, i);
        self.projector
            .to_body(rec.scans.ranges(i), &mut self.body)?;
        let mut pts = Vec::new();
        crate::filter::scanmatch::match_points(&self.body, self.range_max_m, 1, &mut pts);
        if pts.len() > self.max_points {
            let n = pts.len();
            pts = (0..self.max_points)
                .map(|k| pts[k * n / self.max_points])
                .collect();
        }
        Ok(pts)
    }
}

/// Matches every non-keyframe pose of `out` (already moved with its keyframe) against the
/// corrected keyframes around its keyframe (see `GraphOptions::refine_scans`).
fn refine_scans(
    recording: &Recording,
    scan_opts: &ScanOptions,
    trajectory: &[StampedPose2],
    keyframes: &[Keyframe],
    corrected: &[Pose2],
    opts: &GraphOptions,
    out: &mut [StampedPose2],
) -> Result<(), GraphError> {
    let pts = ScanPoints::new(recording, scan_opts, opts)?;
    let half = opts.submap_keyframes.div_ceil(2);
    let win = SearchWindow {
        xy_m: opts.refine_window_m,
        yaw_rad: opts.refine_window_deg.to_radians(),
        yaw_step_rad: opts.yaw_step_deg.to_radians(),
    };
    let current: &[StampedPose2] = out;
    // Keyframes are independent here: in parallel, each worker with its own projector.
    let moved: Vec<Result<Vec<(usize, Pose2)>, GraphError>> = (0..keyframes.len())
        .into_par_iter()
        .map_init(
            || (pts.clone(), Vec::new()),
            |(pts, submap), k| {
                let kf = &keyframes[k];
                let end = keyframes
                    .get(k + 1)
                    .map_or(trajectory.len(), |n| n.traj_index);
                let mut found = Vec::new();
                if end <= kf.traj_index + 1 {
                    return Ok(found);
                }
                let range = k.saturating_sub(half)..(k + half + 1).min(keyframes.len());
                gather_points(keyframes, corrected, range, submap);
                // The scans until the next keyframe stay within a keyframe step of this one.
                let margin = opts.keyframe_distance_m + win.xy_m + 3.0 * opts.field_sigma_m + 0.5;
                let Some((lo, hi)) = bounds_around(&kf.points_body, &corrected[k], margin)
                    .and_then(|b| clip_to_points(b, submap, 3.0 * opts.field_sigma_m))
                else {
                    return Ok(found);
                };
                let field =
                    PointField::build(submap, lo, hi, opts.resolution_m, opts.field_sigma_m, 0);
                for t in kf.traj_index + 1..end {
                    let body = pts.at_stamp(trajectory[t].stamp_ns)?;
                    if body.len() < opts.min_points {
                        continue;
                    }
                    let prior = Prior {
                        pose: current[t].pose,
                        sigma_xy_m: opts.sequential_prior_sigma_m,
                        sigma_yaw_rad: opts.sequential_prior_sigma_deg.to_radians(),
                    };
                    let coarse = field.search_with_prior(&body, &prior, &win);
                    let (pose, score) =
                        field.refine(&body, &coarse, win.yaw_step_rad, 4, Some(&prior));
                    if score >= opts.sequential_min_score {
                        found.push((t, pose));
                    }
                }
                Ok(found)
            },
        )
        .collect();
    for m in moved {
        for (t, pose) in m? {
            out[t].pose = pose;
        }
    }
    Ok(())
}

/// Every input pose moved with its keyframe: `corrected(kf) * front(kf)^-1 * front(t)`.
fn correct_trajectory(
    trajectory: &[StampedPose2],
    keyframes: &[Keyframe],
    corrected: &[Pose2],
) -> Vec<StampedPose2> {
    let mut out = Vec::with_capacity(trajectory.len());
    let mut k = 0;
    for (t, sp) in trajectory.iter().enumerate() {
        while k + 1 < keyframes.len() && keyframes[k + 1].traj_index <= t {
            k += 1;
        }
        let pose = match (keyframes.get(k), corrected.get(k)) {
            (Some(kf), Some(c)) => c.compose(&kf.front_pose.between(&sp.pose)),
            _ => sp.pose,
        };
        out.push(StampedPose2 {
            stamp_ns: sp.stamp_ns,
            pose,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// A 400-node lawnmower path: noisy odometry edges and loop edges from every 10th node
    /// of each later lane to the node beside it on the earlier lane; node 0 at the origin.
    fn lanes() -> PoseGraph {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let truth: Vec<Pose2> = (0..400)
            .map(|i| {
                let (lane, t) = (i / 50, (i % 50) as f64);
                let x = if lane % 2 == 0 { t } else { 49.0 - t };
                let yaw = if lane % 2 == 0 {
                    0.0
                } else {
                    std::f64::consts::PI
                };
                Pose2::new(x, 2.0 * lane as f64, yaw)
            })
            .collect();
        let mut g = PoseGraph::default();
        let mut noise = |s: f64| s * (rng.random::<f64>() - 0.5);
        for i in 0..truth.len() {
            g.poses.push(match i {
                0 => truth[0],
                _ => {
                    let z = truth[i - 1].between(&truth[i]);
                    let z = Pose2::new(
                        z.x_m + noise(0.05),
                        z.y_m + noise(0.05),
                        z.yaw_rad + noise(0.01),
                    );
                    g.edges
                        .push(Edge::with_sigmas(i - 1, i, z, 0.02, 0.005, None));
                    g.poses[i - 1].compose(&z)
                }
            });
        }
        for i in (60..400).step_by(10) {
            let (lane, t) = (i / 50, i % 50);
            let j = (lane - 1) * 50 + 49 - t;
            let z = truth[j].between(&truth[i]);
            g.edges
                .push(Edge::with_sigmas(j, i, z, 0.05, 0.02, Some(3.0)));
        }
        g
    }

    /// `optimize_tail`: from node 1 on (node 0 at the origin) the bits of `optimize`; from a
    /// later node, the earlier ones keep their bits and the rest is the optimum with them
    /// pinned (here: pinned by stiff edges from the origin instead).
    #[test]
    fn tail_optimisation_holds_the_head_fixed() {
        let opts = OptimizeOptions::default();
        let (mut a, mut b) = (lanes(), lanes());
        a.optimize(&opts);
        optimize_tail(&mut b, 1, &opts);
        assert_eq!(a.poses, b.poses);
        let first = 230;
        let mut tail = lanes();
        let before = tail.cost();
        optimize_tail(&mut tail, first, &opts);
        assert_eq!(tail.poses[..first], lanes().poses[..first]);
        assert!(tail.cost() < 0.7 * before, "{} -> {}", before, tail.cost());
        let mut pinned = lanes();
        for v in 1..first {
            let e = Edge::with_sigmas(0, v, pinned.poses[v], 1e-9, 1e-9, None);
            pinned.edges.push(e);
        }
        pinned.optimize(&opts);
        for (p, q) in tail.poses.iter().zip(&pinned.poses).skip(first) {
            assert!(p.between(q).translation_norm_m() < 1e-4, "{p:?} {q:?}");
            assert!(wrap_angle_abs(p.yaw_rad - q.yaw_rad) < 1e-5, "{p:?} {q:?}");
        }
    }

    fn wrap_angle_abs(a: f64) -> f64 {
        crate::geometry::wrap_angle(a).abs()
    }
}
