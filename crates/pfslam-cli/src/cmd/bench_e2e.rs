//! `pfslam bench-e2e`: the end-to-end speed benchmark.
//!
//! Simulates the car once (by default the full-size recording: 1160.5 s, 116k LiDAR scans,
//! 1.16M FOG rows) into a scratch directory, or takes `--dataset`, then times `--runs` times
//! the whole job as `pfslam run` does it: read the files (CSV parsing, dead reckoning), SLAM,
//! the `[graph]` back end when enabled (with the map rebuilt along its trajectory), write the maps (map.png, binary_map.png, map.pgm/.yaml) and the trajectory. Reports per run
//! and as medians: wall time and CPU time (user + system, all threads) per stage, the SLAM
//! loop's own stage timings, scans per second, the real-time factor and the peak resident
//! memory of the run (VmHWM, reset before each run through /proc/self/clear_refs).

use super::dataset::{Dataset, load_dataset};
use anyhow::Context;
use pfslam::config::Config;
use pfslam::geometry::Pose2;
use pfslam::pipeline::{PipelineOptions, process_cpu_s, run_pipeline};
use pfslam::slam::{SlamResult, StageTimings, anchor_odometry_to_ground_truth};
use pfslam_io::map_files::write_map_server;
use pfslam_io::tum::write_tum;
use pfslam_sim::{SimOptions, World};
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, write_binary_png, write_map_png};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `bench-e2e`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset to time (any `pfslam run` input); default: simulate the car first.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Length of the simulated drive (s); 1160.5 is the full-size recording.
    #[arg(long, default_value_t = 1160.5)]
    pub duration_s: f64,
    /// Seed of the simulation and of the filter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Particles (overrides `[filter] particles`; the full-size figures use 100).
    #[arg(long)]
    pub particles: Option<usize>,
    /// Map resolution (m; overrides `[map] resolution_m`).
    #[arg(long)]
    pub resolution: Option<f64>,
    /// TOML configuration over the defaults.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Timed runs (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Where the simulated dataset and the outputs go (kept); default: a scratch directory
    /// under the system's temporary directory, removed at the end.
    #[arg(long)]
    pub work_dir: Option<PathBuf>,
    /// Also write the medians as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Wall and CPU seconds of one stage.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
struct Cost {
    wall_s: f64,
    cpu_s: f64,
}

/// One timed run.
#[derive(Debug, Clone, Default, serde::Serialize)]
struct RunFigures {
    load: Cost,
    slam: Cost,
    /// The `[graph]` back end and the map rebuilt along its trajectory (zero when disabled),
    /// as `pfslam run` does.
    back_end: Cost,
    /// The map rebuild alone (part of `back_end`).
    rebuild: Cost,
    write: Cost,
    total: Cost,
    slam_stages: StageTimings,
    peak_rss_mb: Option<f64>,
}

/// Peak resident set size (MB) since the last reset; `None` off Linux.
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Resets the peak RSS to the current RSS (Linux >= 4.0); false when unsupported.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Times `f`: wall and process CPU seconds.
fn timed<T>(f: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<(T, Cost)> {
    let (t, c) = (Instant::now(), process_cpu_s());
    let v = f()?;
    let cost = Cost {
        wall_s: t.elapsed().as_secs_f64(),
        cpu_s: match (c, process_cpu_s()) {
            (Some(a), Some(b)) => b - a,
            _ => f64::NAN,
        },
    };
    Ok((v, cost))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// One run: read, SLAM, write.
fn one_run(dataset: &Path, config: &Config, seed: u64, out: &Path) -> anyhow::Result<RunFigures> {
    let rss_reset = reset_peak_rss();
    let t_all = (Instant::now(), process_cpu_s());
    let (mut recording, load) = timed(|| {
        let Dataset { recording, .. } = load_dataset(dataset, config, false)
            .with_context(|| format!("loading {}", dataset.display()))?;
        Ok(recording)
    })?;
    anchor_odometry_to_ground_truth(&mut recording);
    // Exactly the default pipeline of `pfslam run`: filter, back end, map rebuilt.
    let (pipeline, _) = timed(|| {
        Ok(run_pipeline(
            &recording,
            config,
            seed,
            &PipelineOptions::default(),
            &mut |_| {},
        )?)
    })?;
    let cost = |wall_s: f64, cpu_s: Option<f64>| Cost {
        wall_s,
        cpu_s: cpu_s.unwrap_or(f64::NAN),
    };
    let slam = cost(pipeline.filter_s, pipeline.filter_cpu_s);
    let back_end = cost(pipeline.back_end_s, pipeline.back_end_cpu_s);
    let rebuild = cost(pipeline.rebuild_s, pipeline.rebuild_cpu_s);
    let result = pipeline.result;
    let ((), write) = timed(|| write_outputs(out, &result))?;
    let total = Cost {
        wall_s: t_all.0.elapsed().as_secs_f64(),
        cpu_s: match (t_all.1, process_cpu_s()) {
            (Some(a), Some(b)) => b - a,
            _ => f64::NAN,
        },
    };
    Ok(RunFigures {
        load,
        slam,
        back_end,
        rebuild,
        write,
        total,
        slam_stages: result.stats.timings,
        peak_rss_mb: if rss_reset { peak_rss_mb() } else { None },
    })
}

/// Writes the trajectory and the maps as `pfslam run` does.
fn write_outputs(out: &Path, result: &SlamResult) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)?;
    write_tum(&out.join("trajectory.tum"), &result.trajectory)?;
    let poses: Vec<Pose2> = result.trajectory.iter().map(|p| p.pose).collect();
    let overlay = [TrajectoryOverlay {
        label: "SLAM",
        poses: &poses,
    }];
    write_map_png(
        &out.join("map.png"),
        &result.map,
        &overlay,
        None,
        &MapImageOptions::default(),
    )?;
    write_binary_png(&out.join("binary_map.png"), &result.map, None)?;
    write_map_server(&result.map.to_binary_map(None), &out.join("map.yaml"))?;
    Ok(())
}

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(p) => Config::from_toml_file(p)?,
        None => Config::default(),
    };
    if let Some(n) = args.particles {
        config.filter.particles = n;
    }
    if let Some(r) = args.resolution {
        config.map.resolution_m = r;
    }
    config.filter.validate()?;
    config.motion.validate()?;
    config.map.validate().map_err(anyhow::Error::msg)?;
    if args.runs == 0 {
        anyhow::bail!("--runs must be at least 1");
    }
    let (work, scratch) = match &args.work_dir {
        Some(d) => (d.clone(), false),
        None => (
            std::env::temp_dir().join(format!("pfslam-bench-e2e-{}", std::process::id())),
            true,
        ),
    };
    let result = bench(&args, &config, &work);
    if scratch {
        // Best effort: a leftover scratch directory is not worth failing the benchmark for.
        let _ = std::fs::remove_dir_all(&work);
    }
    result
}

/// The timed runs, with the recording's scan count and length for the rates.
struct Timed {
    runs: Vec<RunFigures>,
    scans: usize,
    span_s: f64,
}

/// Times the runs on the dataset (simulated first without `--dataset`) and reports them.
fn bench(args: &Args, config: &Config, work: &Path) -> anyhow::Result<()> {
    let dataset = match &args.dataset {
        Some(d) => d.clone(),
        None => simulate(args, config, work)?,
    };
    let input_mb = input_bytes(&dataset) as f64 / 1e6;
    let timed = timed_runs(args, config, &dataset, work)?;
    let summary = summary_json(&dataset, input_mb, config, &timed);
    print_medians(&timed, config, input_mb, &summary);
    if let Some(p) = &args.json {
        let text = serde_json::to_string_pretty(&summary)?;
        pfslam_io::write_bytes_atomic(p, text.as_bytes())?;
    }
    Ok(())
}

/// Simulates the car into `work/dataset` (untimed); returns that directory.
fn simulate(args: &Args, config: &Config, work: &Path) -> anyhow::Result<PathBuf> {
    let opts = SimOptions {
        duration_s: args.duration_s,
        seed: args.seed,
        ..config.sim.clone()
    };
    opts.validate()?;
    let world = World::from_name_or_file(opts.world_name())?;
    let dir = work.join("dataset");
    let t = Instant::now();
    let out = pfslam_sim::simulate_car(&world, &opts)?;
    pfslam_sim::dataset::write_car_sim(&dir, &out)
        .with_context(|| format!("writing {}", dir.display()))?;
    say!(
        "simulated {:.1} s ({} scans, {} FOG rows) into {} in {:.1} s (not timed below)",
        opts.duration_s,
        out.dataset.lidar.len(),
        out.dataset.fog.len(),
        dir.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(dir)
}

/// The `--runs` timed runs, each printed as it ends.
fn timed_runs(args: &Args, config: &Config, dataset: &Path, work: &Path) -> anyhow::Result<Timed> {
    let mut runs = Vec::with_capacity(args.runs);
    let mut scans = 0usize;
    let mut span_s = 0.0;
    for k in 0..args.runs {
        let out = work.join(format!("out_{k}"));
        let r = one_run(dataset, config, args.seed, &out)?;
        if k == 0 {
            // Scan count and recording length, for rates (from the trajectory written).
            let traj = pfslam_io::tum::read_tum(&out.join("trajectory.tum"))?;
            scans = traj.poses.len();
            if let (Some(a), Some(b)) = (traj.poses.first(), traj.poses.last()) {
                span_s = (b.stamp_ns - a.stamp_ns) as f64 * 1e-9;
            }
        }
        print_run(k, &r);
        runs.push(r);
    }
    Ok(Timed {
        runs,
        scans,
        span_s,
    })
}

/// One run's figures (`k` counts from 0).
fn print_run(k: usize, r: &RunFigures) {
    say!(
        "run {}: total {:.2} s wall / {:.2} s CPU; load {:.2} / {:.2}, SLAM {:.2} / {:.2} \
         (match {:.2}, map {:.2}, predict {:.2}), back end {:.2} / {:.2} (of which the map \
         rebuild {:.2} / {:.2}), write {:.2} / {:.2}; peak RSS {}",
        k + 1,
        r.total.wall_s,
        r.total.cpu_s,
        r.load.wall_s,
        r.load.cpu_s,
        r.slam.wall_s,
        r.slam.cpu_s,
        r.slam_stages.correlate_s,
        r.slam_stages.map_update_s,
        r.slam_stages.predict_s,
        r.back_end.wall_s,
        r.back_end.cpu_s,
        r.rebuild.wall_s,
        r.rebuild.cpu_s,
        r.write.wall_s,
        r.write.cpu_s,
        r.peak_rss_mb
            .map_or("n/a".to_string(), |m| format!("{m:.0} MB"))
    );
}

/// The benchmark's setting, the medians of the runs and every run's figures.
fn summary_json(
    dataset: &Path,
    input_mb: f64,
    config: &Config,
    timed: &Timed,
) -> serde_json::Value {
    let (runs, scans, span_s) = (&timed.runs, timed.scans, timed.span_s);
    let med = |f: &dyn Fn(&RunFigures) -> f64| median(runs.iter().map(f).collect());
    let total_wall = med(&|r| r.total.wall_s);
    let slam_wall = med(&|r| r.slam.wall_s);
    serde_json::json!({
        "dataset": dataset.display().to_string(),
        "input_mb": input_mb,
        "scans": scans,
        "recording_s": span_s,
        "particles": config.filter.particles,
        "resolution_m": config.map.resolution_m,
        "mode": config.filter.mode,
        "runs": runs.len(),
        "threads": threads(),
        "median": {
            "total_wall_s": total_wall,
            "total_cpu_s": med(&|r| r.total.cpu_s),
            "load_wall_s": med(&|r| r.load.wall_s),
            "load_cpu_s": med(&|r| r.load.cpu_s),
            "slam_wall_s": slam_wall,
            "slam_cpu_s": med(&|r| r.slam.cpu_s),
            "match_wall_s": med(&|r| r.slam_stages.correlate_s),
            "map_update_wall_s": med(&|r| r.slam_stages.map_update_s),
            "predict_wall_s": med(&|r| r.slam_stages.predict_s),
            "back_end_wall_s": med(&|r| r.back_end.wall_s),
            "back_end_cpu_s": med(&|r| r.back_end.cpu_s),
            "rebuild_wall_s": med(&|r| r.rebuild.wall_s),
            "rebuild_cpu_s": med(&|r| r.rebuild.cpu_s),
            "write_wall_s": med(&|r| r.write.wall_s),
            "peak_rss_mb": med(&|r| r.peak_rss_mb.unwrap_or(f64::NAN)),
            "scans_per_s": scans as f64 / slam_wall,
            "real_time_factor": span_s / total_wall,
        },
        "runs_figures": runs,
    })
}

/// The medians of [`summary_json`]: a sentence and one markdown row.
fn print_medians(timed: &Timed, config: &Config, input_mb: f64, summary: &serde_json::Value) {
    let m = &summary["median"];
    let f = |k: &str| m[k].as_f64().unwrap_or(f64::NAN);
    let total_wall = median(timed.runs.iter().map(|r| r.total.wall_s).collect());
    let slam_wall = median(timed.runs.iter().map(|r| r.slam.wall_s).collect());
    say!(
        "median of {} runs ({} scans, {} particles, {} m cells, {:.0} MB input, {} threads): \
         total {:.2} s wall / {:.2} s CPU (load {:.2}, SLAM {:.2}, write {:.2} s wall), \
         {:.0} scans/s, {:.1}x real time, peak RSS {:.0} MB",
        timed.runs.len(),
        timed.scans,
        config.filter.particles,
        config.map.resolution_m,
        input_mb,
        threads(),
        total_wall,
        f("total_cpu_s"),
        f("load_wall_s"),
        slam_wall,
        f("write_wall_s"),
        f("scans_per_s"),
        f("real_time_factor"),
        f("peak_rss_mb"),
    );
    // One markdown row for tables (scripts/scaling.sh collects them).
    say!(
        "row: | {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} | {:.0} |",
        timed.scans,
        config.filter.particles,
        config.map.resolution_m,
        total_wall,
        f("total_cpu_s"),
        slam_wall,
        f("slam_cpu_s"),
        f("match_wall_s"),
        f("scans_per_s"),
        f("peak_rss_mb"),
    );
}

/// Worker threads available (rayon's default pool uses one per logical CPU).
fn threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Bytes of the input: a file's size, or the sizes of a directory's files (recursively).
fn input_bytes(path: &Path) -> u64 {
    if path.is_file() {
        return std::fs::metadata(path).map_or(0, |m| m.len());
    }
    let Ok(entries) = std::fs::read_dir(path) else {
        return 0;
    };
    entries
        .flatten()
        .map(|e| {
            let p = e.path();
            if p.is_dir() {
                input_bytes(&p)
            } else {
                e.metadata().map_or(0, |m| m.len())
            }
        })
        .sum()
}
