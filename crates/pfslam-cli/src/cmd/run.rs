//! `pfslam run DATASET --out DIR`: the seeds' particle-filter SLAM on a dataset.
//!
//! Writes `trajectory.tum` (best particle at every scan), `dead_reckoning.tum`, `map.png`
//! (map with the SLAM, dead-reckoning and ground-truth paths), `binary_map.png`, `map.pgm` +
//! `map.yaml`, `summary.json` and map snapshots in `snapshots/`; when the dataset has stereo
//! images, the texture along the SLAM path (the files of `pfslam texture`).

use anyhow::Context;
use pfslam::config::Config;
use pfslam::eval::{Association, ate::ate, rpe::RpeDelta, rpe::rpe};
use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
use pfslam::graph::GraphStats;
use pfslam::pipeline::{BackEndInput, PipelineOptions, PipelineResult};
use pfslam::quality::Quality;
use pfslam::sensors::Recording;
use pfslam::session::SessionState;
use pfslam::slam::{SlamResult, anchor_odometry_to_ground_truth};
use pfslam_io::account::InputAccount;
use pfslam_io::map_files::write_map_server;
use pfslam_io::tum::write_tum;
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, write_binary_png, write_map_png};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `run`.
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// Dataset: a car dataset directory (sensor_data/, param/; a simulator output directory
    /// also brings `ground_truth.tum` and `true_map.yaml`), or a recording file (ROS bag,
    /// MCAP, CARMEN log); `-` reads a CARMEN log from standard input as it arrives (with
    /// `--format carmen`).
    pub dataset: PathBuf,
    /// The format of standard input (`-`): `carmen`.
    #[arg(long, value_enum)]
    pub format: Option<LiveFormat>,
    /// Write each scan's pose as a TUM line to this file (`-`: standard output, the messages
    /// then go to standard error) as soon as the filter handled the scan.
    #[arg(long)]
    pub poses_out: Option<PathBuf>,
    /// With `-`: write the map so far to `--out`'s `live_map.png` each time this many seconds
    /// of the recording passed (removed when the final outputs are in place).
    #[arg(long)]
    pub snapshot_every_s: Option<f64>,
    /// TOML configuration over the defaults (see `pfslam print-config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Number of particles (overrides `[filter] particles`).
    #[arg(long)]
    pub particles: Option<usize>,
    /// Seed of the filter's random streams.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Sort car CSV rows whose timestamps go backwards instead of rejecting them.
    #[arg(long)]
    pub sort_timestamps: bool,
    /// Feed the `[graph]` back end the dead reckoning instead of the filter's trajectory (to
    /// measure the back end alone). With the back end, `front_end.tum` is its input.
    #[arg(long)]
    pub graph_on_odometry: bool,
    /// Also write what a later session needs to continue this map (keyframes with their
    /// scans and poses, the sensor mount, the configuration) to this file.
    #[arg(long)]
    pub save_state: Option<PathBuf>,
    /// Continue the map of this saved state: localise the recording in it, map on, close
    /// loops between old and new keyframes. Writes the merged map, `trajectory.tum` (this
    /// recording) and `previous_sessions.tum` (the saved keyframes, moved by this run's
    /// back end) in the saved map's frame.
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// With `--resume`: the pose of the first scan in the saved map, `X,Y,YAW_DEG`, or
    /// `last` for where the last saved session ended (else found by global localisation,
    /// which a symmetric building can fool).
    #[arg(long, requires = "resume")]
    pub initial_pose: Option<String>,
    /// Also write the run as an MCAP file that Foxglove opens: the map over time, each scan
    /// in the world, the particle cloud, the trajectories and the loop closures.
    #[arg(long, conflicts_with = "resume")]
    pub record: Option<PathBuf>,
    /// Input selection and strictness.
    #[command(flatten)]
    pub input: super::input::InputArgs,
}

/// The formats `run -` reads from standard input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LiveFormat {
    /// CARMEN log lines.
    Carmen,
}

use super::dataset::{Dataset, TrueMaps, load_dataset};
use super::record::Recorder;

/// A finished SLAM run on a loaded recording, before its outputs are written.
pub(super) struct Slammed {
    pub recording: Recording,
    pub true_map: Option<TrueMaps>,
    pub account: InputAccount,
    pub load_s: f64,
    /// Whether the odometry starts at the ground truth's first pose.
    pub anchored: bool,
    pub pipeline: PipelineResult,
    pub recorder: Option<Recorder>,
}

/// Runs SLAM and writes the outputs.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = args.input.config(args.config.as_deref())?;
    if let Some(n) = args.particles {
        config.filter.particles = n;
    }
    // every check before reading the recording
    config.validate()?;
    let live = super::live::check_args(&args, &config)?;
    if args.resume.is_some() {
        return super::resume::run(&args, &config);
    }
    let staging = super::output::Staging::new(&args.out)?;
    let out_dir = staging.path().to_path_buf();
    let recorder = match &args.record {
        Some(path) => Some(Recorder::create(path)?),
        None => None,
    };
    let observer = observer(&args, &out_dir, recorder)?;
    let slammed = match live {
        true => super::live::read_and_slam(&args, &config, observer)?,
        false => load_and_slam(&args, &config, observer)?,
    };
    write_and_commit(&args, &config, staging, slammed)?;
    if live {
        super::live::remove_snapshot(&args.out);
    }
    Ok(())
}

/// The run's observer: snapshots in the staging directory, the recorder, `--poses-out`.
fn observer(
    args: &Args,
    out_dir: &Path,
    recorder: Option<Recorder>,
) -> anyhow::Result<super::observer::RunObserver> {
    let observer = super::observer::RunObserver::new(out_dir.join("snapshots"), recorder);
    Ok(match &args.poses_out {
        None => observer,
        Some(p) if p.as_os_str() == "-" => {
            super::MESSAGES_TO_STDERR.store(true, std::sync::atomic::Ordering::Relaxed);
            observer.with_poses_out(Box::new(std::io::stdout()))
        }
        Some(p) => {
            let file = std::fs::File::create(p)
                .with_context(|| format!("--poses-out {}: cannot create it", p.display()))?;
            observer.with_poses_out(Box::new(std::io::BufWriter::new(file)))
        }
    })
}

/// Loads the dataset (timed) and runs the pipeline on it, snapshots and recording included.
fn load_and_slam(
    args: &Args,
    config: &Config,
    mut observer: super::observer::RunObserver,
) -> anyhow::Result<Slammed> {
    let t_load = Instant::now();
    let Dataset {
        mut recording,
        true_map,
        account,
        ..
    } = load_dataset(&args.dataset, config, args.sort_timestamps)
        .with_context(|| format!("loading {}", args.dataset.display()))?;
    let load_s = t_load.elapsed().as_secs_f64();
    super::input::report(&account);
    // With ground truth, start at the true pose so maps and paths overlay without alignment.
    let anchored = anchor_odometry_to_ground_truth(&mut recording);
    observer.set_total(recording.scans.len());
    // the incremental API's one driver loop, as for live input
    let slam = pfslam::Slam::with_recording(config.clone(), recording, args.seed)?;
    let (pipeline, recording) =
        slam.finish_observed(&pipeline_options(args), &mut |ev| observer.on_event(ev))?;
    let recorder = observer.finish()?;
    Ok(Slammed {
        recording,
        true_map,
        account,
        load_s,
        anchored,
        pipeline,
        recorder,
    })
}

/// The stages after the filter as the flags ask.
pub(super) fn pipeline_options(args: &Args) -> PipelineOptions {
    PipelineOptions {
        back_end_input: args.graph_on_odometry.then_some(BackEndInput::Odometry),
        ..PipelineOptions::default()
    }
}

/// Writes the outputs into the staging directory and commits them.
fn write_and_commit(
    args: &Args,
    config: &Config,
    staging: super::output::Staging,
    s: Slammed,
) -> anyhow::Result<()> {
    let (recording, pipeline, out_dir) = (&s.recording, s.pipeline, staging.path());
    // The back end's figures: its statistics, the wall time of the map rebuilt along its
    // trajectory, and its input (the filter's trajectory, or the dead reckoning).
    let odometry_timing = pipeline.odometry_timing;
    let result = pipeline.result;
    let rebuild_s = pipeline.rebuild_s;
    let front_end = match args.graph_on_odometry {
        true => result.dead_reckoning.clone(),
        false => pipeline.front_end,
    };
    // What the back end was fed and, for the calibrated odometry, the fitted errors.
    let back_end_input = serde_json::json!({
        "input": pipeline.back_end_input,
        "odometry_calibration": pipeline.calibration,
    });
    let record = match s.recorder {
        None => None,
        Some(r) => Some(r.finish(&super::record::Finished {
            recording,
            trajectory: &result.trajectory,
            front_end: &front_end,
            map: &result.map,
            loop_closures: &pipeline.loop_closures,
        })?),
    };
    let graph = pipeline.graph.map(|g| (g, rebuild_s, front_end));
    write_outputs(&RunOutputs {
        args,
        config,
        recording,
        true_map: s.true_map.as_ref(),
        result: &result,
        load_s: s.load_s,
        anchored: s.anchored,
        graph: graph.as_ref(),
        back_end_input,
        odometry_timing,
        account: &s.account,
        quality: &pipeline.quality,
        out: out_dir,
    })?;
    // The ground's colours along the SLAM path, when the dataset has stereo images.
    let (traj, map) = (&result.trajectory, &result.map);
    super::texture::texture_after_run(&args.dataset, traj, config, map, out_dir);
    let state = args.save_state.as_ref().map(|path| {
        let s = SessionState::after_session(None, recording, &result.trajectory, config);
        (path, s)
    });
    commit_and_save(args, staging, record, state, &pipeline.quality)
}

/// Moves the outputs into `--out`, then writes the recording and the saved state (which lie
/// outside it) and warns of a suspect result.
fn commit_and_save(
    args: &Args,
    staging: super::output::Staging,
    record: Option<super::record::Written>,
    state: Option<(&PathBuf, SessionState)>,
    quality: &Quality,
) -> anyhow::Result<()> {
    staging.commit()?;
    say!("wrote {}", args.out.display());
    if let Some(r) = record {
        r.persist()?;
    }
    if let Some((path, state)) = state {
        super::resume::save_state(path, &state)?;
    }
    for reason in &quality.reasons {
        eprintln!("warning: suspect result: {reason}");
    }
    Ok(())
}

fn metrics(
    estimate: &[StampedPose2],
    ground_truth: &[StampedPose2],
) -> anyhow::Result<serde_json::Value> {
    Ok(metrics_and_alignment(estimate, ground_truth)?.0)
}

/// [`metrics`] and the ATE's SE(2) alignment `ground_truth_from_estimate`.
fn metrics_and_alignment(
    estimate: &[StampedPose2],
    ground_truth: &[StampedPose2],
) -> anyhow::Result<(serde_json::Value, Pose2)> {
    let est = Trajectory::new(estimate.to_vec());
    let gt = Trajectory::new(ground_truth.to_vec());
    let assoc = Association::Interpolate {
        max_gap_ns: 1_000_000_000,
    };
    let a = ate(&est, &gt, assoc)?;
    let r = rpe(&est, &gt, assoc, RpeDelta::Metres(10.0)).ok();
    let alignment = a.alignment;
    Ok((serde_json::json!({ "ate": a, "rpe_10m": r }), alignment))
}

/// What `run` writes its outputs from.
struct RunOutputs<'a> {
    args: &'a Args,
    config: &'a Config,
    recording: &'a Recording,
    true_map: Option<&'a TrueMaps>,
    result: &'a SlamResult,
    load_s: f64,
    anchored: bool,
    /// The back end's statistics, the map rebuild's seconds and its input, when it ran.
    graph: Option<&'a (GraphStats, f64, Vec<StampedPose2>)>,
    back_end_input: serde_json::Value,
    /// How far the odometry's stamps look off the scans'.
    odometry_timing: pfslam::pipeline::OdometryTimingReport,
    account: &'a InputAccount,
    quality: &'a Quality,
    out: &'a Path,
}

/// Writes the trajectories, the maps, `summary.json` and `report.html`, and prints the
/// figures.
fn write_outputs(o: &RunOutputs<'_>) -> anyhow::Result<()> {
    let t = Instant::now();
    let binary = write_paths_and_maps(o)?;
    let write_s = t.elapsed().as_secs_f64();
    let summary = summary_json(o, &binary, write_s)?;
    super::report::write_summary_and_report(o.out, &summary, o.config, "map with the paths")?;
    print_figures(o, &summary, write_s);
    Ok(())
}

/// The TUM files and the map pictures; returns the binary map.
fn write_paths_and_maps(o: &RunOutputs<'_>) -> anyhow::Result<pfslam::map::BinaryMap> {
    let (out, result, recording, graph, anchored) =
        (o.out, o.result, o.recording, o.graph, o.anchored);
    write_tum(&out.join("trajectory.tum"), &result.trajectory)?;
    if let Some((_, _, front)) = graph {
        write_tum(&out.join("front_end.tum"), front)?;
    }
    write_tum(&out.join("dead_reckoning.tum"), &result.dead_reckoning)?;
    let slam: Vec<Pose2> = result.trajectory.iter().map(|p| p.pose).collect();
    let dr: Vec<Pose2> = result.dead_reckoning.iter().map(|p| p.pose).collect();
    let gt: Vec<Pose2> = recording
        .ground_truth
        .iter()
        .flatten()
        .map(|p| p.pose)
        .collect();
    let mut overlays = vec![
        TrajectoryOverlay {
            label: "SLAM",
            poses: &slam,
        },
        TrajectoryOverlay {
            label: "dead reckoning",
            poses: &dr,
        },
    ];
    if anchored {
        overlays.push(TrajectoryOverlay {
            label: "ground truth",
            poses: &gt,
        });
    }
    write_map_png(
        &out.join("map.png"),
        &result.map,
        &overlays,
        None,
        &MapImageOptions::default(),
    )?;
    write_binary_png(&out.join("binary_map.png"), &result.map, None)?;
    let binary = result.map.to_binary_map(None);
    write_map_server(&binary, &out.join("map.yaml"))?;
    Ok(binary)
}

/// `summary.json`: the run's figures, and the metrics when there is ground truth.
fn summary_json(
    o: &RunOutputs<'_>,
    binary: &pfslam::map::BinaryMap,
    write_s: f64,
) -> anyhow::Result<serde_json::Value> {
    let (args, config, recording, result, graph) =
        (o.args, o.config, o.recording, o.result, o.graph);
    let (account, quality, load_s) = (o.account, o.quality, o.load_s);
    let mut summary = serde_json::json!({
        "dataset": args.dataset.display().to_string(),
        "recording": recording.name,
        "input": account,
        "seed": args.seed,
        "config": config,
        "stats": result.stats,
        "quality": quality,
        "odometry_timing": o.odometry_timing,
        "timings_s": {
            "load": load_s,
            "slam": result.stats.timings.total_s,
            "write_outputs": write_s,
        },
    });
    if let Some((stats, remap_s, _)) = graph {
        summary["graph"] = serde_json::to_value(stats)?;
        summary["graph_input"] = o.back_end_input.clone();
        summary["timings_s"]["graph"] = stats.total_s.into();
        summary["timings_s"]["graph_remap"] = (*remap_s).into();
    }
    let mut slam_alignment = None;
    if let Some(gt) = &recording.ground_truth {
        if let Some((_, _, front)) = graph {
            summary["front_end_vs_ground_truth"] = metrics(front, gt)?;
        }
        let (m, alignment) = metrics_and_alignment(&result.trajectory, gt)?;
        summary["slam_vs_ground_truth"] = m;
        slam_alignment = Some(alignment);
        summary["dead_reckoning_vs_ground_truth"] = metrics(&result.dead_reckoning, gt)?;
    }
    if let Some(truth) = o.true_map
        && o.anchored
        && binary.width > 0
    {
        map_vs_true_map(&mut summary, truth, binary, slam_alignment)?;
    }
    Ok(summary)
}

/// Adds the map against the true map to `summary`: as written and, with the SLAM
/// trajectory's ATE alignment, through it.
fn map_vs_true_map(
    summary: &mut serde_json::Value,
    truth: &TrueMaps,
    binary: &pfslam::map::BinaryMap,
    slam_alignment: Option<Pose2>,
) -> anyhow::Result<()> {
    let figures = |c: pfslam::map::MapComparison| {
        serde_json::json!({
            "tolerance_cells": c.tolerance_cells,
            "precision": c.precision(),
            "recall": c.recall(),
            "recall_all": c.recall_all(),
            "free_agreement": c.free_agreement(),
        })
    };
    // As written: the map in the frame of the true start pose.
    summary["map_vs_true_map"] = figures(truth.compare(binary, 1)?);
    // Through the ATE's alignment: the map's shape, without the drift of its frame.
    if let Some(a) = slam_alignment {
        let mut v = figures(truth.compare_aligned(binary, 1, &a)?);
        v["ground_truth_from_map"] =
            serde_json::json!({ "x_m": a.x_m, "y_m": a.y_m, "yaw_rad": a.yaw_rad });
        summary["map_vs_true_map_aligned"] = v;
    }
    Ok(())
}

/// The run's figures on standard output.
fn print_figures(o: &RunOutputs<'_>, summary: &serde_json::Value, write_s: f64) {
    let (recording, result, load_s) = (o.recording, o.result, o.load_s);
    let s = &result.stats;
    say!(
        "{}: {} of {} scans, {} particles, {} updates, {} resamples, Neff mean {:.1} min {:.1}",
        recording.name,
        s.scans_processed,
        s.scans_total,
        s.particles,
        s.updates,
        s.resamples,
        s.neff_mean,
        s.neff_min
    );
    say!(
        "time: load {load_s:.2} s, SLAM {:.2} s (predict {:.2}, correlate {:.2} of which fields {:.2}, resample {:.3}, map {:.2}), outputs {write_s:.2} s",
        s.timings.total_s,
        s.timings.predict_s,
        s.timings.correlate_s,
        s.timings.field_s,
        s.timings.resample_s,
        s.timings.map_update_s
    );
    print_back_end(o.graph, summary);
    print_accuracy(summary);
}

/// The back end's figures and the calibration of the odometry fed to it, when it ran.
fn print_back_end(
    graph: Option<&(GraphStats, f64, Vec<StampedPose2>)>,
    summary: &serde_json::Value,
) {
    if let Some((g, remap_s, _)) = graph {
        say!(
            "graph: {} keyframes, {} loop closures kept ({} candidates, {} removed as outliers), \
             {:.2} s (matching {:.2}, refinement {:.2}, optimiser {:.2}); map rebuilt along it \
             in {:.2} s",
            g.nodes,
            g.loop_accepted - g.loop_removed_outliers,
            g.loop_candidates,
            g.loop_removed_outliers,
            g.total_s,
            g.matching_s,
            g.refine_s,
            g.optimize_s,
            remap_s
        );
    }
    if let Some(c) = summary
        .get("graph_input")
        .map(|v| &v["odometry_calibration"])
        && !c.is_null()
    {
        say!(
            "back end fed the odometry calibrated against the filter: scale {:.5}, yaw-rate bias {:.2e} rad/s",
            c["calibration"]["scale"].as_f64().unwrap_or(f64::NAN),
            c["calibration"]["yaw_rate_bias_rad_per_s"]
                .as_f64()
                .unwrap_or(f64::NAN)
        );
    }
}

/// The accuracy against ground truth and the true map, when there are.
fn print_accuracy(summary: &serde_json::Value) {
    if let Some(f) = summary.get("front_end_vs_ground_truth") {
        say!(
            "ATE RMSE (SE(2)-aligned) of the filter before the back end: {:.3} m",
            f["ate"]["aligned_m"]["rmse"].as_f64().unwrap_or(f64::NAN)
        );
    }
    if let Some(v) = summary.get("slam_vs_ground_truth") {
        let d = &summary["dead_reckoning_vs_ground_truth"];
        say!(
            "ATE RMSE (SE(2)-aligned): SLAM {:.3} m, dead reckoning {:.3} m",
            v["ate"]["aligned_m"]["rmse"].as_f64().unwrap_or(f64::NAN),
            d["ate"]["aligned_m"]["rmse"].as_f64().unwrap_or(f64::NAN)
        );
    }
    if let Some(m) = summary.get("map_vs_true_map") {
        say!(
            "map vs true map (1 cell tolerance), as written: precision {:.3}, recall {:.3}",
            m["precision"].as_f64().unwrap_or(f64::NAN),
            m["recall"].as_f64().unwrap_or(f64::NAN)
        );
    }
    if let Some(m) = summary.get("map_vs_true_map_aligned") {
        say!(
            "map vs true map (1 cell tolerance), through the ATE's SE(2) alignment: precision {:.3}, recall {:.3}",
            m["precision"].as_f64().unwrap_or(f64::NAN),
            m["recall"].as_f64().unwrap_or(f64::NAN)
        );
    }
}
