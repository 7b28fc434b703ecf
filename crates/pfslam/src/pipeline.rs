//! The default SLAM pipeline in one step: the filter ([`run_slam`]), then the `[graph]` back
//! end when enabled, then the map rebuilt along the corrected trajectory, for a recording
//! already read. [`crate::Slam::finish`] runs the same stages after its filter
//! (`after_filter`), and both hand each scan to the same per-scan step, so `pfslam run` and
//! `pfslam benchmark` (through `Slam`) and `pfslam bench-e2e` (through [`run_pipeline`], for
//! its per-stage CPU seconds) compute the same result.

use crate::config::Config;
use crate::geometry::{Pose2, StampedPose2, Trajectory};
pub use crate::graph::BackEndInput;
use crate::graph::{GraphError, GraphStats, optimize_after_saved, optimize_trajectory};
use crate::map::consistency::consistency;
use crate::map::{MapError, OccupancyGrid, map_with_poses};
use crate::motion::calibration::{CalibrationFit, fit_odometry_calibration};
pub use crate::motion::odometry_timing::{OdometryTimingReport, shift_odometry};
use crate::motion::odometry_timing::{fixed_shift, rerun_if_lagged};
use crate::quality::{Quality, QualitySignals, SUSPECT_FREE_SHARE};
use crate::sensors::Recording;
use crate::slam::{SlamError, SlamEvent, SlamResult, run_slam};
use std::time::Instant;

/// Errors of the pipeline: the failing stage's error.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The filter failed.
    #[error(transparent)]
    Slam(#[from] SlamError),
    /// The back end failed.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// Rebuilding the map failed.
    #[error(transparent)]
    Map(#[from] MapError),
}

/// Gives a recording without odometry the odometry of its scans alone
/// ([`crate::graph::lidar_odometry`]: LiDAR-only mode); true when it did.
pub fn ensure_odometry(recording: &mut Recording) -> Result<bool, MapError> {
    if !recording.odometry.is_empty() || recording.scans.is_empty() {
        return Ok(false);
    }
    recording.odometry = crate::graph::lidar_odometry::lidar_odometry(recording)?;
    Ok(true)
}

/// Options of one pipeline run beyond the [`Config`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PipelineOptions {
    /// What the back end is fed, overriding `[graph] input` (`None`: the configuration's).
    pub back_end_input: Option<BackEndInput>,
    /// Rebuild the map along the back end's trajectory (off when only the trajectory is
    /// wanted, e.g. for the relations metric; the map is then the filter's).
    pub rebuild_map: bool,
}

impl Default for PipelineOptions {
    fn default() -> Self {
        PipelineOptions {
            back_end_input: None,
            rebuild_map: true,
        }
    }
}

/// What [`run_pipeline`] produced.
#[derive(Debug, Clone)]
pub struct PipelineResult {
    /// The final trajectory and map (after the back end when it ran), dead reckoning and the
    /// filter's statistics.
    pub result: SlamResult,
    /// The filter's own trajectory (before the back end).
    pub front_end: Vec<StampedPose2>,
    /// The back end's statistics, when it ran.
    pub graph: Option<GraphStats>,
    /// What the back end was fed (`auto` resolved), when it ran.
    pub back_end_input: Option<BackEndInput>,
    /// The odometry calibration, when the back end was fed the calibrated odometry.
    pub calibration: Option<CalibrationFit>,
    /// How far the odometry's stamps are off the scans', and the shift applied.
    pub odometry_timing: OdometryTimingReport,
    /// Wall seconds of the filter.
    pub filter_s: f64,
    /// Wall seconds of the back end and the map rebuild (0 when disabled).
    pub back_end_s: f64,
    /// CPU seconds (user + system, all threads) of the filter; `None` off Linux.
    pub filter_cpu_s: Option<f64>,
    /// CPU seconds of the back end and the map rebuild; `None` off Linux.
    pub back_end_cpu_s: Option<f64>,
    /// Wall seconds of the maps built along the front end's and the back end's trajectories,
    /// and of the back end's second run when the guard asked for it (part of `back_end_s`;
    /// 0 without a back end).
    pub rebuild_s: f64,
    /// CPU seconds of the same; `None` off Linux.
    pub rebuild_cpu_s: Option<f64>,
    /// The self-check.
    pub quality: Quality,
    /// The two ends of each loop closure of the back end, when its trajectory was kept.
    pub loop_closures: Vec<(Pose2, Pose2)>,
}

/// CPU seconds (user + system, all threads) of this process so far; `None` where
/// `/proc/self/stat` is unavailable (off Linux).
pub fn process_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may contain spaces) start at state (field 3);
    // utime and stime are fields 14 and 15, in clock ticks (100 per second on Linux).
    let rest = &stat[stat.rfind(')')? + 2..];
    let mut fields = rest.split_whitespace().skip(11);
    let utime: f64 = fields.next()?.parse().ok()?;
    let stime: f64 = fields.next()?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// Wall clock and process CPU clock together.
struct Clock(Instant, Option<f64>);

impl Clock {
    fn start() -> Clock {
        Clock(Instant::now(), process_cpu_s())
    }

    /// (wall, CPU) seconds since `start`.
    fn elapsed(&self) -> (f64, Option<f64>) {
        let cpu = match (self.1, process_cpu_s()) {
            (Some(a), Some(b)) => Some(b - a),
            _ => None,
        };
        (self.0.elapsed().as_secs_f64(), cpu)
    }
}

/// Runs the filter, then the `[graph]` back end when `config.graph.enabled` (and the map
/// rebuilt along its trajectory when `options.rebuild_map`).
pub fn run_pipeline(
    recording: &Recording,
    config: &Config,
    seed: u64,
    options: &PipelineOptions,
    observer: &mut dyn FnMut(SlamEvent<'_>),
) -> Result<PipelineResult, PipelineError> {
    if recording.odometry.is_empty() && !recording.scans.is_empty() {
        let mut with = recording.clone();
        ensure_odometry(&mut with)?;
        return run_pipeline(&with, config, seed, options, observer);
    }
    config.input.validate().map_err(SlamError::InputOptions)?;
    let shifted = fixed_shift(recording, config.input.odometry_shift_s);
    let recording = shifted.as_ref().unwrap_or(recording);
    let t = Clock::start();
    let result = run_slam(recording, config, seed, observer)?;
    after_filter(recording, config, (seed, options), result, t.elapsed())
}

/// The stages after the filter's `result` on `recording` (which took `filter_time`, wall
/// and CPU seconds): the filter again on shifted odometry when the odometry's lag is
/// notable ([`rerun_if_lagged`]), the back end when `[graph] enabled`, guarded by the
/// self-check, and the map rebuilt along its trajectory when `options.rebuild_map`.
pub(crate) fn after_filter(
    recording: &Recording,
    config: &Config,
    (seed, options): (u64, &PipelineOptions),
    result: SlamResult,
    (filter_s, filter_cpu_s): (f64, Option<f64>),
) -> Result<PipelineResult, PipelineError> {
    let t = Clock::start();
    let shift_s = config.input.odometry_shift_s;
    let again = |rec: &Recording| run_slam(rec, config, seed, &mut |_| {});
    let (odometry_timing, rerun) =
        rerun_if_lagged(recording, shift_s, &result, |r| &r.trajectory, again)?;
    let (rerun_s, rerun_cpu_s) = t.elapsed();
    let filter_s = filter_s + rerun_s;
    let filter_cpu_s = filter_cpu_s.zip(rerun_cpu_s).map(|(a, b)| a + b);
    let (shifted, mut result) = match rerun {
        Some((shifted, again)) => (Some(shifted), again),
        None => (None, result),
    };
    let recording = shifted.as_ref().unwrap_or(recording);
    let t = Clock::start();
    let front_end = result.trajectory.clone();
    let mut calibration = None;
    let mut back_end_input = None;
    let mut rebuild = (0.0, Some(0.0));
    let mut signals = QualitySignals::default();
    let mut loop_closures = Vec::new();
    let graph = if config.graph.enabled {
        let which = options
            .back_end_input
            .unwrap_or(config.graph.input)
            .resolve(recording);
        let (which, calibrated, fit) = calibrated_input(which, &result, config);
        calibration = fit;
        back_end_input = Some(which);
        let input = match which {
            BackEndInput::FrontEnd | BackEndInput::Auto => &result.trajectory,
            BackEndInput::Odometry => &result.dead_reckoning,
            BackEndInput::CalibratedOdometry => &calibrated,
        };
        let graph_opts = if which == BackEndInput::FrontEnd {
            config.graph.clone()
        } else {
            config.graph.for_odometry_input()
        };
        let g = optimize_trajectory(recording, &config.map.scan, input, &graph_opts)?;
        let t = Clock::start();
        let chosen = choose_trajectory(recording, config, &front_end, input, &graph_opts, g, 0)?;
        if let Some(trajectory) = chosen.trajectory {
            result.trajectory = trajectory;
        }
        signals = chosen.signals;
        loop_closures = chosen.loop_closures;
        if options.rebuild_map {
            result.map = chosen.grid;
        }
        rebuild = t.elapsed();
        Some(chosen.stats)
    } else {
        let poses = Trajectory::new(result.trajectory.clone());
        signals.free_share = free_share(recording, &poses, &result.map, config)?;
        None
    };
    let (back_end_s, back_end_cpu_s) = t.elapsed();
    Ok(PipelineResult {
        result,
        front_end,
        graph,
        back_end_input,
        calibration,
        odometry_timing,
        filter_s,
        back_end_s,
        filter_cpu_s,
        back_end_cpu_s,
        rebuild_s: rebuild.0,
        rebuild_cpu_s: rebuild.1,
        quality: Quality::assess(signals),
        loop_closures,
    })
}

/// The back end's input `which` with the odometry calibrated against the filter's
/// trajectory for `CalibratedOdometry` (the poses and the fit); the filter's trajectory when
/// the fit fails.
fn calibrated_input(
    which: BackEndInput,
    result: &SlamResult,
    config: &Config,
) -> (BackEndInput, Vec<StampedPose2>, Option<CalibrationFit>) {
    if which != BackEndInput::CalibratedOdometry {
        return (which, Vec::new(), None);
    }
    match fit_odometry_calibration(
        &result.dead_reckoning,
        &result.trajectory,
        &config.graph.calibration,
    ) {
        Ok(fit) => {
            tracing::info!(
                "odometry calibration: scale {:.5}, yaw-rate bias {:.3e} rad/s; the filter's \
                 increments differ from it by {:.4} m RMS ({:.4} m uncorrected; {} increments)",
                fit.calibration.scale,
                fit.calibration.yaw_rate_bias_rad_per_s,
                fit.rms_m,
                fit.rms_uncorrected_m,
                fit.increments
            );
            // Starts at the odometry's first pose, as the filter does: the map frame is the
            // start pose (aligning it to the filter's whole path instead would carry the
            // filter's global heading error into it: 0.18 deg on seed 3 of the default
            // drive, 0.9 m at its far end).
            let calibrated = fit.calibration.apply(&result.dead_reckoning);
            (which, calibrated, Some(fit))
        }
        Err(e) => {
            // A filter that lost its way (or too short a recording) must not stop the run:
            // the back end then takes the filter's trajectory as it is.
            tracing::warn!("{e}; the back end is fed the filter's trajectory instead");
            (BackEndInput::FrontEnd, Vec::new(), None)
        }
    }
}

/// What [`choose_trajectory`] kept.
pub(crate) struct Chosen {
    /// The back end's trajectory, or `None` for the front end's.
    pub(crate) trajectory: Option<Vec<StampedPose2>>,
    /// The map along the kept trajectory.
    pub(crate) grid: OccupancyGrid,
    /// The self-check's signals.
    pub(crate) signals: QualitySignals,
    /// The statistics of the back end that ran last (default without a back end).
    pub(crate) stats: GraphStats,
    /// The two ends of each loop closure of the kept back end (none when the front end is
    /// kept).
    pub(crate) loop_closures: Vec<(Pose2, Pose2)>,
}

impl Chosen {
    /// The back end `g` kept, with `grid`, the map along its trajectory.
    fn back_end(
        g: crate::graph::GraphResult,
        grid: OccupancyGrid,
        signals: QualitySignals,
    ) -> Self {
        Chosen {
            loop_closures: closure_ends(&g),
            trajectory: Some(g.trajectory),
            grid,
            signals,
            stats: g.stats,
        }
    }
}

/// The two ends of each accepted loop closure of `g`, at their corrected poses.
fn closure_ends(g: &crate::graph::GraphResult) -> Vec<(Pose2, Pose2)> {
    let at = |k: usize| g.keyframes.get(k).map(|p| p.pose);
    g.loop_edges
        .iter()
        .filter_map(|&(a, b)| Some((at(a)?, at(b)?)))
        .collect()
}

/// The back end over `recording` fed `front_end` (a pose per scan), guarded as in
/// [`run_pipeline`]; without `[graph] enabled`, the map along `front_end`.
pub(crate) fn back_end_over(
    recording: &Recording,
    config: &Config,
    front_end: &[StampedPose2],
    saved: usize,
) -> Result<Chosen, PipelineError> {
    if !config.graph.enabled {
        let (grid, share) = map_and_free_share(recording, front_end, config)?;
        return Ok(Chosen {
            trajectory: None,
            grid,
            signals: QualitySignals {
                free_share: share,
                ..QualitySignals::default()
            },
            stats: GraphStats::default(),
            loop_closures: Vec::new(),
        });
    }
    let g = optimize_after_saved(recording, &config.map.scan, front_end, &config.graph, saved)?;
    choose_trajectory(
        recording,
        config,
        front_end,
        front_end,
        &config.graph,
        g,
        saved,
    )
}

/// The back end's trajectory unless its map is much less consistent than the front end's
/// (`[graph] max_free_share_ratio`), or crosses the self-check's limit
/// ([`SUSPECT_FREE_SHARE`]) that the front end's stays under (decision 0059). Then, when it
/// matched consecutive keyframes itself, it runs again tied by the front end's motion alone (`sequential.matching = "off"`, no
/// odometry-yaw edges): on Intel its own sequential matches led its closures astray on half
/// of the seeds (decision 0006). The front end's trajectory when that fails too. The first
/// `saved` poses of `input` are a saved session's keyframes, kept rigid in the second run too.
fn choose_trajectory(
    recording: &Recording,
    config: &Config,
    front_end: &[StampedPose2],
    input: &[StampedPose2],
    graph_opts: &crate::graph::GraphOptions,
    g: crate::graph::GraphResult,
    saved: usize,
) -> Result<Chosen, PipelineError> {
    let (back_grid, back_share) = map_and_free_share(recording, &g.trajectory, config)?;
    let ratio = config.graph.max_free_share_ratio;
    let mut signals = QualitySignals {
        free_share: back_share,
        free_share_back_end: Some(back_share),
        back_end_kept: Some(true),
        ..QualitySignals::default()
    };
    if ratio <= 0.0 {
        return Ok(Chosen::back_end(g, back_grid, signals));
    }
    let (front_grid, front_share) = map_and_free_share(recording, front_end, config)?;
    signals.free_share_front_end = Some(front_share);
    let acceptable = |share: f64| back_end_acceptable(share, front_share, ratio);
    if acceptable(back_share) {
        return Ok(Chosen::back_end(g, back_grid, signals));
    }
    tracing::warn!(
        "the back end's map is less consistent than the front end's ({:.1} % of returns in \
         free cells against {:.1} %)",
        100.0 * back_share,
        100.0 * front_share
    );
    let mut stats = g.stats;
    if stats.sequential_matched > 0 {
        let mut retry = graph_opts.clone();
        retry.sequential.matching = crate::graph::Switch::Off;
        retry.sequential.odometry_yaw_edges = crate::graph::Switch::Off;
        let g2 = optimize_after_saved(recording, &config.map.scan, input, &retry, saved)?;
        let (grid, share) = map_and_free_share(recording, &g2.trajectory, config)?;
        signals.back_end_retried = true;
        signals.free_share_back_end = Some(share);
        if acceptable(share) {
            tracing::warn!(
                "the back end tied by the front end's motion alone: {:.1} % of returns in free \
                 cells; its trajectory is used",
                100.0 * share
            );
            signals.free_share = share;
            return Ok(Chosen::back_end(g2, grid, signals));
        }
        stats = g2.stats;
    }
    tracing::warn!("the front end's trajectory is used");
    signals.free_share = front_share;
    signals.back_end_kept = Some(false);
    Ok(Chosen {
        trajectory: None,
        grid: front_grid,
        signals,
        stats,
        loop_closures: Vec::new(),
    })
}

/// Whether a back end whose map has `back_share` of its returns in free cells may replace a
/// front end with `front_share`: not much less consistent (`ratio` times the share, and at
/// least [`MIN_FREE_SHARE_RISE`] more), and not carried past the self-check's limit that the
/// front end's map stays under (however small the ratio).
fn back_end_acceptable(back_share: f64, front_share: f64, ratio: f64) -> bool {
    let rise = back_share > front_share + MIN_FREE_SHARE_RISE;
    let turns_suspect =
        rise && back_share > SUSPECT_FREE_SHARE && front_share <= SUSPECT_FREE_SHARE;
    back_share <= (ratio * front_share).max(front_share + MIN_FREE_SHARE_RISE) && !turns_suspect
}

/// The back end is rejected only when its free share also exceeds the front end's by this
/// much: between correct solutions the share moves by up to ~1 point (decision 0006), and on
/// a clean map (a simulator's, ~0.3 %) a ratio alone would reject noise.
const MIN_FREE_SHARE_RISE: f64 = 0.02;

/// At most this many scans are scored for the free share (evenly spaced).
pub const FREE_SHARE_SCANS: usize = 2000;

/// The map along `poses` and the share of returns landing in its free cells.
fn map_and_free_share(
    recording: &Recording,
    poses: &[StampedPose2],
    config: &Config,
) -> Result<(OccupancyGrid, f64), PipelineError> {
    let poses = Trajectory::new(poses.to_vec());
    let grid = map_with_poses(recording, &poses, &config.map)?.0;
    let share = free_share(recording, &poses, &grid, config)?;
    Ok((grid, share))
}

/// The share of returns of (at most [`FREE_SHARE_SCANS`]) scans posed by `poses` that land
/// in cells `grid` calls free: the self-check's consistency signal.
pub fn free_share(
    recording: &Recording,
    poses: &Trajectory,
    grid: &OccupancyGrid,
    config: &Config,
) -> Result<f64, PipelineError> {
    let step = recording.scans.len().div_ceil(FREE_SHARE_SCANS).max(1);
    Ok(consistency(recording, poses, grid, &config.map.scan, step)?.free_share())
}

#[cfg(test)]
mod tests {
    use super::back_end_acceptable;

    #[test]
    fn a_back_end_that_makes_the_map_suspect_is_not_taken_as_it_is() {
        // Within the ratio, both under the self-check's limit: taken.
        assert!(back_end_acceptable(0.12, 0.10, 1.5));
        // Within the ratio of 1.5 but past the 15 % limit the front end stays under (a
        // resumed session's back end bent at a weave: 15.2 % against 11.0 %).
        assert!(!back_end_acceptable(0.152, 0.110, 1.5));
        // Past the limit by less than the least rise between correct solutions: taken.
        assert!(back_end_acceptable(0.155, 0.149, 1.5));
        // Both past the limit: the ratio alone decides.
        assert!(back_end_acceptable(0.20, 0.16, 1.5));
        assert!(!back_end_acceptable(0.30, 0.16, 1.5));
    }
}
