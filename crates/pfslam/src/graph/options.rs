//! The back end's options (`[graph]`): [`GraphOptions`], its defaults and checks, and the
//! [`BackEndInput`] and [`Switch`] choices they hold.

use crate::motion::calibration::CalibrationOptions;
use crate::sensors::Recording;
use serde::{Deserialize, Serialize};

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
        if !(self.max_free_share_ratio.is_finite() && self.max_free_share_ratio >= 0.0) {
            return Err("graph.max_free_share_ratio must be finite and >= 0".into());
        }
        self.validate_positive()?;
        self.validate_non_negative()?;
        self.validate_unit_interval()?;
        self.validate_windows()?;
        self.validate_counts()
    }

    /// The lengths, angles, sigmas and thresholds that must be positive and finite.
    fn validate_positive(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
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
        Ok(())
    }

    /// The ranges, windows, radii and widths that may be 0 (off or unbounded).
    fn validate_non_negative(&self) -> Result<(), String> {
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
        Ok(())
    }

    /// The scores and ratios, in [0, 1].
    fn validate_unit_interval(&self) -> Result<(), String> {
        for (k, v) in [
            ("sequential_min_score", self.sequential_min_score),
            ("loop_min_score", self.loop_min_score),
            ("loop_ambiguity_ratio", self.loop_ambiguity_ratio),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("graph.{k} must lie in [0, 1]"));
            }
        }
        Ok(())
    }

    /// The search windows' upper bounds, and the local window within the loop window.
    fn validate_windows(&self) -> Result<(), String> {
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
        Ok(())
    }

    /// The counts that must be at least 1.
    fn validate_counts(&self) -> Result<(), String> {
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
