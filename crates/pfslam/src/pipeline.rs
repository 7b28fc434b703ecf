//! The default SLAM pipeline in one step: the filter ([`run_slam`]), then the `[graph]` back
//! end when enabled, then the map rebuilt along the corrected trajectory. `pfslam run`,
//! `pfslam benchmark` and `pfslam bench-e2e` all call [`run_pipeline`], so the benchmarks
//! time exactly what `run` does.

use crate::config::Config;
use crate::filter::slam::{SlamError, SlamEvent, SlamResult, run_slam};
use crate::geometry::{StampedPose2, Trajectory};
pub use crate::graph::BackEndInput;
use crate::graph::{GraphError, GraphStats, optimize_trajectory};
use crate::map::{MapError, map_with_poses};
use crate::motion::calibration::{CalibrationFit, fit_odometry_calibration};
use crate::sensors::Recording;
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
    /// Wall seconds of the filter.
    pub filter_s: f64,
    /// Wall seconds of the back end and the map rebuild (0 when disabled).
    pub back_end_s: f64,
    /// CPU seconds (user + system, all threads) of the filter; `None` off Linux.
    pub filter_cpu_s: Option<f64>,
    /// CPU seconds of the back end and the map rebuild; `None` off Linux.
    pub back_end_cpu_s: Option<f64>,
    /// Wall seconds of the map rebuild alone (part of `back_end_s`; 0 when not rebuilt).
    pub rebuild_s: f64,
    /// CPU seconds of the map rebuild alone; `None` off Linux.
    pub rebuild_cpu_s: Option<f64>,
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
    let t = Clock::start();
    let mut result = run_slam(recording, config, seed, observer)?;
    let (filter_s, filter_cpu_s) = t.elapsed();
    let t = Clock::start();
    let front_end = result.trajectory.clone();
    let mut calibration = None;
    let mut back_end_input = None;
    let mut rebuild = (0.0, Some(0.0));
    let graph = if config.graph.enabled {
        let mut which = options
            .back_end_input
            .unwrap_or(config.graph.input)
            .resolve(recording);
        let mut calibrated = Vec::new();
        if which == BackEndInput::CalibratedOdometry {
            match fit_odometry_calibration(
                &result.dead_reckoning,
                &result.trajectory,
                &config.graph.calibration,
            ) {
                Ok(fit) => {
                    tracing::info!(
                        "odometry calibration: scale {:.5}, yaw-rate bias {:.3e} rad/s; the \
                         filter's increments differ from it by {:.4} m RMS ({:.4} m uncorrected; \
                         {} of {} increments kept)",
                        fit.calibration.scale,
                        fit.calibration.yaw_rate_bias_rad_per_s,
                        fit.rms_m,
                        fit.rms_uncorrected_m,
                        fit.increments - fit.trimmed,
                        fit.increments
                    );
                    // Starts at the odometry's first pose, as the filter does: the map frame
                    // is the start pose (aligning it to the filter's whole path instead would
                    // carry the filter's global heading error into it: 0.18 deg on seed 3 of
                    // the default drive, 0.9 m at its far end).
                    calibrated = fit.calibration.apply(&result.dead_reckoning);
                    calibration = Some(fit);
                }
                Err(e) => {
                    // A filter that lost its way (or too short a recording) must not stop
                    // the run: the back end then takes the filter's trajectory as it is.
                    tracing::warn!("{e}; the back end is fed the filter's trajectory instead");
                    which = BackEndInput::FrontEnd;
                }
            }
        }
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
        if options.rebuild_map {
            let t = Clock::start();
            let poses = Trajectory::new(g.trajectory.clone());
            result.map = map_with_poses(recording, &poses, &config.map)?.0;
            rebuild = t.elapsed();
        }
        result.trajectory = g.trajectory;
        Some(g.stats)
    } else {
        None
    };
    let (back_end_s, back_end_cpu_s) = t.elapsed();
    Ok(PipelineResult {
        result,
        front_end,
        graph,
        back_end_input,
        calibration,
        filter_s,
        back_end_s,
        filter_cpu_s,
        back_end_cpu_s,
        rebuild_s: rebuild.0,
        rebuild_cpu_s: rebuild.1,
    })
}
