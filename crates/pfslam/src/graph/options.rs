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
    /// What the back end is fed (its keyframes' initial poses and relative motions):
    /// `auto` (default: `calibrated_odometry` for a tilted LiDAR fixed on the body, the car;
    /// `front_end` otherwise), `front_end` (the filter's trajectory), `odometry` (the raw
    /// odometry) or `calibrated_odometry` (the odometry with its distance scale and yaw-rate
    /// bias fitted to the filter's trajectory, `[graph.calibration]`: locally as smooth as the
    /// odometry, without its scale drift).
    pub input: BackEndInput,
    /// A new keyframe after this much travel along the front end's path (m).
    pub keyframe_distance_m: f64,
    /// ... or after this much rotation (deg).
    pub keyframe_angle_deg: f64,
    /// Cell size of the matching fields (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub resolution_m: f64,
    /// Standard deviation of the likelihood field around submap points (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub field_sigma_m: f64,
    /// Returns closer than this to the sensor are not matched (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub range_min_m: f64,
    /// Returns farther than this are not matched (m).
    pub range_max_m: f64,
    /// At most this many points of a scan are matched (evenly subsampled).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_points: usize,
    /// A scan needs at least this many matching points to be matched at all (sequential
    /// edge, closure, refinement); fewer points fit anywhere.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub min_points: usize,
    /// Yaw step of the searches (deg; the sub-cell refinement goes below it).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub yaw_step_deg: f64,
    /// The back end's trajectory replaces the front end's only when the share of scan
    /// returns that land in cells its own map calls free is at most this multiple of the
    /// front end's, or at most 2 points above it (0 = always replaces). A wrong closure
    /// lays corridors over each other and raises that share. A back end that fails it and
    /// matched consecutive keyframes itself runs again without (`sequential.matching`
    /// off), guarded alike; see `docs/decisions/0006-self-check-and-back-end-guard.md`.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_free_share_ratio: f64,
    /// Edges between consecutive keyframes.
    pub sequential: SequentialOptions,
    /// Loop closures.
    pub loops: LoopOptions,
    /// The optimisations.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub optimize: OptimizeSchedule,
    /// The scans between keyframes re-matched after the optimisation.
    pub refine: ScanRefineOptions,
    /// The odometry calibration of `input = "calibrated_odometry"`.
    pub calibration: CalibrationOptions,
}

/// Edges between consecutive keyframes (`[graph.sequential]`): the sequential scan match
/// and the front end's relative motion beside it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SequentialOptions {
    /// Sequential scan-matching edges: `auto` (on for a level LiDAR fixed on the body, off
    /// for a tilted or moving one), `on`, `off`. A tilted LiDAR's scan is a 3-D surface, so
    /// consecutive scans see roofs, canopies and parked cars at different heights; their
    /// matches are biased along the street, and on the simulated car 3,175 such edges
    /// stiffer than the front end dragged the graph to 6.7 m ATE (the front end: 0.18 m).
    /// Off, consecutive keyframes are tied by the front end's relative motion alone, with the
    /// `sequential.front_end_*` uncertainty below.
    pub matching: Switch,
    /// Keyframes before the new one that form the submap of a sequential edge.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub submap_keyframes: usize,
    /// Half-width of the sequential search in x and y (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_m: f64,
    /// Half-width of the sequential search in yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_deg: f64,
    /// Prior on the deviation from the front end's relative motion: x/y (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub prior_sigma_m: f64,
    /// Prior on the deviation from the front end's relative motion: yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub prior_sigma_deg: f64,
    /// Smallest standard deviation of a matched sequential edge in x and y (m): its
    /// information is the curvature of the match objective, capped at this.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sigma_m: f64,
    /// Smallest standard deviation of a matched sequential edge in yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sigma_deg: f64,
    /// A sequential match scoring below this (mean field value, 0..1) is replaced by the
    /// front end's relative motion with the `sequential.fallback_sigma_*` uncertainty.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub min_score: f64,
    /// Standard deviation of the front-end edge (the front end's relative motion) beside
    /// every match, and alone where the match failed, in x and y (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub fallback_sigma_m: f64,
    /// Standard deviation of the front-end edge in yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub fallback_sigma_deg: f64,
    /// Without sequential matching: standard deviation of the front end's relative motion
    /// in x and y per square root of the distance travelled (m per sqrt(m)); a random walk,
    /// so over `L` m it is `this * sqrt(L)`.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub front_end_sigma_m_per_sqrt_m: f64,
    /// ... and in yaw (deg per sqrt(m)).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub front_end_sigma_deg_per_sqrt_m: f64,
    /// Without sequential matching: consecutive keyframes are also tied by the recording's
    /// odometry yaw (the car's FOG: 0.09 deg off after 1.4 km), with this random-walk
    /// uncertainty (deg per sqrt(m); 0 = no such edge), so the front end's local heading
    /// errors do not survive the optimisation.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub odometry_yaw_sigma_deg_per_sqrt_m: f64,
    /// Whether those odometry-yaw edges are added (only ever without sequential matching):
    /// `auto` = for a LiDAR fixed on the body (the car, whose odometry yaw is its FOG), not
    /// for one moving on the body (the humanoid, whose odometry yaw is leg odometry: there
    /// they pulled the default 180 s walk from 0.130 to 0.369 m ATE, seed 1).
    pub odometry_yaw_edges: Switch,
}

/// Loop closures (`[graph.loops]`): where candidates are looked for, how they are verified
/// and weighed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopOptions {
    /// Loop-closure candidates lie within this distance of the keyframe's estimate (m).
    pub search_radius_m: f64,
    /// ... and at least this far back along the path (m).
    pub min_path_m: f64,
    /// At most this many candidates are tried per keyframe (the nearest first).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_candidates: usize,
    /// Loop closures are searched from every k-th keyframe (no gaps after closures:
    /// `docs/decisions/0021-loop-closure-search.md`).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub every_keyframes: usize,
    /// Keyframes on each side of the candidate that form its submap.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub submap_keyframes: usize,
    /// Half-width of the loop-closure search in x and y (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_m: f64,
    /// Half-width of the loop-closure search in yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_deg: f64,
    /// Minimum mean field value (0..1) of an accepted closure.
    pub min_score: f64,
    /// A closure is ambiguous (rejected) if a pose farther than `loops.ambiguity_radius_m`
    /// from the best scores at least this fraction of the best.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub ambiguity_ratio: f64,
    /// See `loops.ambiguity_ratio` (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub ambiguity_radius_m: f64,
    /// Standard deviation of a loop-closure edge in x and y (m).
    pub sigma_m: f64,
    /// Standard deviation of a loop-closure edge in yaw (deg).
    pub sigma_deg: f64,
    /// Width of the Cauchy kernel of loop edges (whitened error units; 0 = no kernel).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub kernel_width: f64,
    /// After the final optimisation, loop edges with a whitened squared error above this
    /// are removed and the graph optimised again.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub outlier_chi2: f64,
    /// Local searches where the relative pose is already known.
    pub local: LocalLoopOptions,
}

/// Local loop-closure searches (`[graph.loops.local]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalLoopOptions {
    /// Local loop-closure searches (Cartographer's constraint builder searches a small
    /// window where the relative pose is already known): a candidate whose region the
    /// graph has already tied to the current pass is verified in the small window
    /// `loops.local.window_*` around its estimate instead of `loops.window_*`, with
    /// `loops.local.ambiguity_radius_m`; the full window is searched when no closure vouches
    /// for the estimate, and after a local search whose best pose lies on the window's edge
    /// or scores too low. Vouched: after the last optimisation, a loop edge with a whitened
    /// squared error of at most `optimize.chi2` ends at most `loops.local.vouch_path_m` of
    /// path before the keyframe, and one (the same or another) has an end within that much
    /// path of the candidate. `auto` = on when the back end is fed the odometry (the car,
    /// whose calibrated odometry drifts centimetres over that path), off otherwise; `on`,
    /// `off`.
    pub search: Switch,
    /// Half-width of the local loop-closure search in x and y (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_m: f64,
    /// Half-width of the local loop-closure search in yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_deg: f64,
    /// The local search's ambiguity radius (m): a pose at least this far from the best that
    /// scores `loops.ambiguity_ratio` of it makes the closure ambiguous. Smaller than
    /// `loops.ambiguity_radius_m` in proportion to the window, so the test still sees a
    /// street along which the scan slides (at 0.15 m a point's field value falls to a tenth,
    /// at 0.5 m to nothing: the two tests ask about as many points to pin the slide down).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub ambiguity_radius_m: f64,
    /// See `loops.local.search` (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub vouch_path_m: f64,
    /// Local searches only once the last optimisation left at least this many consistent
    /// loop edges: they accept fewer closures than the full window (the smaller ambiguity
    /// radius rejects broad match peaks), which a route closed again and again does not
    /// miss (the full-size car: 0.051 -> 0.049 m ATE) but a back end with few closures does
    /// (the default drive, 59 closures: local searches kept 18 and cost 1 % ATE).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub min_closures: usize,
}

/// When and how long the graph is optimised (`[graph.optimize]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimizeSchedule {
    /// Optimise after accepted closures at most every this many keyframes ...
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub every_keyframes: usize,
    /// ... or at once when a new closure disagrees with the current estimates by more than
    /// this whitened squared error (a loop closing after drift).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub chi2: f64,
    /// Levenberg-Marquardt iterations per optimisation.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_iterations: usize,
    /// A periodic optimisation (`optimize.every_keyframes`) stops when an iteration lowers
    /// the cost by less than this fraction: every new closure agreed with the estimates
    /// within `optimize.chi2`, so the correction is small, and these optimisations only give
    /// the next loop searches corrected estimates. Urgent and final optimisations stop at
    /// 1e-6. The full-size car: 375 -> 245 iterations in all; the default drive's
    /// closures and ATE unchanged (one iteration at most instead: 1 % worse there).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub periodic_relative_tolerance: f64,
    /// A periodic optimisation moves only the keyframes from this many before the last
    /// optimisation on (the others held where they are; 0 = the whole graph): every new
    /// closure agreed with the estimates, so it corrects the recent path against the map
    /// already closed, at a cost that does not grow with the graph (the full-size car's
    /// 25,000 keyframes: ~400 instead). Urgent (a loop closing after drift) and final
    /// optimisations move the whole graph.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub periodic_free_keyframes: usize,
}

/// The scans between keyframes re-matched after the optimisation (`[graph.refine]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanRefineOptions {
    /// After the optimisation, match every scan between keyframes against the corrected
    /// keyframes around it (a small window around the pose composed from its keyframe), so
    /// the scans between keyframes do not keep the front end's local errors: `auto` (on; off
    /// when the back end is fed the odometry, see `input`), `on`, `off` (`true` / `false`
    /// read as `on` / `off`). Off for the odometry: the car's calibrated odometry is locally
    /// smoother than these matches
    /// (`docs/decisions/0022-car-back-end-on-calibrated-odometry.md`).
    pub scans: Switch,
    /// Half-width of that refinement search in x and y (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_m: f64,
    /// Half-width of that refinement search in yaw (deg).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub window_deg: f64,
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
            input: BackEndInput::Auto,
            keyframe_distance_m: 0.3,
            keyframe_angle_deg: 10.0,
            resolution_m: 0.05,
            field_sigma_m: 0.07,
            range_min_m: 0.1,
            range_max_m: 30.0,
            max_points: 200,
            min_points: 50,
            yaw_step_deg: 0.3,
            max_free_share_ratio: 1.5,
            sequential: SequentialOptions::default(),
            loops: LoopOptions::default(),
            optimize: OptimizeSchedule::default(),
            refine: ScanRefineOptions::default(),
            calibration: CalibrationOptions::default(),
        }
    }
}

impl Default for SequentialOptions {
    fn default() -> Self {
        SequentialOptions {
            matching: Switch::Auto,
            submap_keyframes: 10,
            window_m: 0.15,
            window_deg: 3.0,
            prior_sigma_m: 0.1,
            prior_sigma_deg: 2.0,
            sigma_m: 0.02,
            sigma_deg: 0.5,
            min_score: 0.3,
            fallback_sigma_m: 0.1,
            fallback_sigma_deg: 2.0,
            front_end_sigma_m_per_sqrt_m: 0.005,
            front_end_sigma_deg_per_sqrt_m: 0.004,
            odometry_yaw_sigma_deg_per_sqrt_m: 0.002,
            odometry_yaw_edges: Switch::Auto,
        }
    }
}

impl Default for LoopOptions {
    fn default() -> Self {
        LoopOptions {
            search_radius_m: 8.0,
            min_path_m: 10.0,
            max_candidates: 2,
            every_keyframes: 5,
            submap_keyframes: 20,
            // +-1.5 m / 10 deg: the default front end (`rbpf` on level LiDARs) drifts
            // centimetres, not metres; half the window halves Intel's matching at the same
            // error (measured; the 3 m / 20 deg window was sized for `scan_match` on Intel).
            window_m: 1.5,
            window_deg: 10.0,
            min_score: 0.55,
            ambiguity_ratio: 0.9,
            ambiguity_radius_m: 0.5,
            sigma_m: 0.05,
            sigma_deg: 1.0,
            kernel_width: 3.0,
            outlier_chi2: 100.0,
            local: LocalLoopOptions::default(),
        }
    }
}

impl Default for LocalLoopOptions {
    fn default() -> Self {
        LocalLoopOptions {
            search: Switch::Auto,
            window_m: 0.3,
            window_deg: 2.0,
            ambiguity_radius_m: 0.15,
            vouch_path_m: 100.0,
            min_closures: 200,
        }
    }
}

impl Default for OptimizeSchedule {
    fn default() -> Self {
        OptimizeSchedule {
            // Fewer periodic optimisations (Intel: 71 -> ~36, the error unchanged); a
            // disagreeing closure still optimises at once: with that trigger at 100 instead
            // of 25, Intel seed 5 took a wrong closure (2.0 m).
            every_keyframes: 200,
            chi2: 25.0,
            max_iterations: 20,
            periodic_relative_tolerance: 1e-4,
            periodic_free_keyframes: 3000,
        }
    }
}

impl Default for ScanRefineOptions {
    fn default() -> Self {
        ScanRefineOptions {
            scans: Switch::Auto,
            window_m: 0.1,
            window_deg: 2.0,
        }
    }
}

impl GraphOptions {
    /// These options for a back end fed the odometry itself (`input` other than the front
    /// end): no odometry-yaw edges (they would count its yaw twice), `refine.scans =
    /// "auto"` off (re-matching the scans between keyframes would replace the odometry's
    /// smooth local motion by noisier matches) and `loops.local.search = "auto"` on.
    pub fn for_odometry_input(&self) -> GraphOptions {
        let mut opts = self.clone();
        opts.sequential.odometry_yaw_edges = Switch::Off;
        if opts.refine.scans == Switch::Auto {
            opts.refine.scans = Switch::Off;
        }
        if opts.loops.local.search == Switch::Auto {
            opts.loops.local.search = Switch::On;
        }
        opts
    }

    /// Checks ranges; the message names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        self.calibration
            .validate()
            .map_err(|m| format!("graph.calibration: {m}"))?;
        let (seq, loops, local, opt, refine) = (
            &self.sequential,
            &self.loops,
            &self.loops.local,
            &self.optimize,
            &self.refine,
        );
        check_all(
            &[
                ("keyframe_distance_m", self.keyframe_distance_m),
                ("keyframe_angle_deg", self.keyframe_angle_deg),
                ("yaw_step_deg", self.yaw_step_deg),
                ("resolution_m", self.resolution_m),
                ("field_sigma_m", self.field_sigma_m),
                ("range_max_m", self.range_max_m),
                ("sequential.prior_sigma_m", seq.prior_sigma_m),
                ("sequential.prior_sigma_deg", seq.prior_sigma_deg),
                ("sequential.sigma_m", seq.sigma_m),
                ("sequential.sigma_deg", seq.sigma_deg),
                ("sequential.fallback_sigma_m", seq.fallback_sigma_m),
                ("sequential.fallback_sigma_deg", seq.fallback_sigma_deg),
                (
                    "sequential.front_end_sigma_m_per_sqrt_m",
                    seq.front_end_sigma_m_per_sqrt_m,
                ),
                (
                    "sequential.front_end_sigma_deg_per_sqrt_m",
                    seq.front_end_sigma_deg_per_sqrt_m,
                ),
                ("loops.sigma_m", loops.sigma_m),
                ("loops.sigma_deg", loops.sigma_deg),
                ("loops.outlier_chi2", loops.outlier_chi2),
                ("loops.local.window_m", local.window_m),
                ("loops.local.window_deg", local.window_deg),
                ("loops.local.ambiguity_radius_m", local.ambiguity_radius_m),
                ("loops.local.vouch_path_m", local.vouch_path_m),
                ("optimize.chi2", opt.chi2),
                (
                    "optimize.periodic_relative_tolerance",
                    opt.periodic_relative_tolerance,
                ),
            ],
            |v| v.is_finite() && v > 0.0,
            "must be positive and finite",
        )?;
        check_all(
            &[
                ("range_min_m", self.range_min_m),
                ("max_free_share_ratio", self.max_free_share_ratio),
                ("sequential.window_m", seq.window_m),
                ("sequential.window_deg", seq.window_deg),
                (
                    "sequential.odometry_yaw_sigma_deg_per_sqrt_m",
                    seq.odometry_yaw_sigma_deg_per_sqrt_m,
                ),
                ("loops.search_radius_m", loops.search_radius_m),
                ("loops.min_path_m", loops.min_path_m),
                ("loops.window_m", loops.window_m),
                ("loops.window_deg", loops.window_deg),
                ("loops.ambiguity_radius_m", loops.ambiguity_radius_m),
                ("loops.kernel_width", loops.kernel_width),
                ("refine.window_m", refine.window_m),
                ("refine.window_deg", refine.window_deg),
            ],
            |v| v.is_finite() && v >= 0.0,
            "must be finite and >= 0",
        )?;
        check_all(
            &[
                ("sequential.min_score", seq.min_score),
                ("loops.min_score", loops.min_score),
                ("loops.ambiguity_ratio", loops.ambiguity_ratio),
            ],
            |v| (0.0..=1.0).contains(&v),
            "must lie in [0, 1]",
        )?;
        self.validate_windows()?;
        for (k, v) in [
            ("max_points", self.max_points),
            ("sequential.submap_keyframes", seq.submap_keyframes),
            ("loops.every_keyframes", loops.every_keyframes),
            ("optimize.every_keyframes", opt.every_keyframes),
        ] {
            if v == 0 {
                return Err(format!("graph.{k} must be at least 1"));
            }
        }
        Ok(())
    }

    /// The search windows' upper bounds, and the local window within the loop window.
    fn validate_windows(&self) -> Result<(), String> {
        let (seq, loops) = (&self.sequential, &self.loops);
        if seq.window_m > 2.0 || loops.window_m > 10.0 {
            return Err("graph: sequential.window_m <= 2 and loops.window_m <= 10".into());
        }
        if loops.window_deg > 180.0 || seq.window_deg > 45.0 {
            return Err("graph: sequential.window_deg <= 45 and loops.window_deg <= 180".into());
        }
        if loops.local.window_m > loops.window_m || loops.local.window_deg > loops.window_deg {
            return Err(
                "graph: loops.local.window_m <= loops.window_m and loops.local.window_deg <= \
                 loops.window_deg"
                    .into(),
            );
        }
        Ok(())
    }
}

/// The first of `keyed` (names under `graph.`) whose value fails `ok`, as an error saying
/// it `must`.
fn check_all(keyed: &[(&str, f64)], ok: impl Fn(f64) -> bool, must: &str) -> Result<(), String> {
    match keyed.iter().find(|(_, v)| !ok(*v)) {
        Some((k, _)) => Err(format!("graph.{k} {must}")),
        None => Ok(()),
    }
}
