//! `pfslam map DATASET --poses TRAJ.tum --out DIR`: occupancy mapping with known poses
//! (ground truth, dead reckoning or any trajectory).
//!
//! Writes `map.png` (occupied black, free white, unknown grey, the trajectory and the last
//! scan, legend, scale bar), `binary_map.png`, the map_server pair `map.pgm` + `map.yaml`,
//! `logodds.npy` and `map_stats.json`; with `--truth TRUE_MAP.yaml` also the comparison with
//! that map (in `map_stats.json` and on stdout).

use anyhow::{Context, bail};
use pfslam::config::Config;
use pfslam::geometry::{Pose2, Trajectory};
use pfslam::map::{
    CellRect, LogOddsPreset, MapComparison, MappingStats, OccupancyGrid, PlanarScan, map_with_poses,
};
use pfslam::sensors::Recording;
use pfslam_io::account::InputAccount;
use pfslam_io::map_files::{write_logodds_npy, write_map_server};
use pfslam_io::tum::read_tum;
use pfslam_io::write_bytes_atomic;
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, render_map, write_binary_png};
use std::path::{Path, PathBuf};

/// Log-odds presets selectable on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// UCSD seed: +-ln 4, clamp +-10 ln 4.
    Ucsd,
    /// ESE650 seed: +0.85 / -0.42, bound 100, thresholds p = 0.9 / 0.2.
    Ese650,
}

/// Arguments of `map`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset: a car or humanoid dataset directory, or a recording file (CARMEN log, ROS bag,
    /// MCAP).
    pub dataset: PathBuf,
    /// Poses of the body in the map frame (TUM); scans outside their time span are skipped.
    #[arg(long)]
    pub poses: PathBuf,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML configuration; its `[map]` section (and `[map.scan]`, `[map.log_odds]`) applies.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Cell size (m), overriding the configuration.
    #[arg(long)]
    pub resolution: Option<f64>,
    /// Log-odds preset, overriding the configuration's `[map.log_odds]`.
    #[arg(long, value_enum)]
    pub preset: Option<Preset>,
    /// Keep only returns at or above this height (m, body/world frame).
    #[arg(long, allow_hyphen_values = true)]
    pub z_min: Option<f64>,
    /// Keep only returns at or below this height (m, body/world frame).
    #[arg(long, allow_hyphen_values = true)]
    pub z_max: Option<f64>,
    /// Extra trajectory drawn on map.png, as LABEL=FILE.tum (repeatable).
    #[arg(long = "overlay", value_name = "LABEL=FILE")]
    pub overlays: Vec<String>,
    /// A true map (map_server yaml) to compare with: precision, recall, free agreement (with
    /// a `<stem>_visible.yaml` beside it, the simulator's scan-surface truth: recall over the
    /// visible surfaces, free agreement over the passed-free cells).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Tolerance of the comparison (cells).
    #[arg(long, default_value_t = 1)]
    pub tolerance_cells: u32,
    /// Input selection and strictness.
    #[command(flatten)]
    pub input: super::input::InputArgs,
}

fn file_label(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "poses".into())
}

/// The grid built along the poses, with its figures.
struct Mapped {
    grid: OccupancyGrid,
    last_scan: PlanarScan,
    stats: MappingStats,
    mapping_s: f64,
    /// CPU seconds of all threads (the wall time depends on the machine's load).
    mapping_cpu_s: Option<f64>,
}

/// Runs the mapping.
pub fn run(args: Args) -> anyhow::Result<()> {
    // Validate everything before any work.
    let config = map_config(&args)?;
    let staging = super::output::Staging::new(&args.out)?;
    let out = staging.path().to_path_buf();
    let poses = read_tum(&args.poses)?;
    if poses.is_empty() {
        bail!("{}: no poses", args.poses.display());
    }
    let overlays = read_overlays(&args.overlays)?;
    let truth = match &args.truth {
        Some(p) => Some(super::dataset::TrueMaps::read(p)?),
        None => None,
    };

    let ds = super::dataset::load_dataset(&args.dataset, &config, false)?;
    super::input::report(&ds.account);
    let rec = ds.recording;
    let mapped = map_timed(&rec, &poses, &config)?;
    let grid = &mapped.grid;

    // How well the scans agree with the map along these poses: the self-check's signal,
    // so trajectories can be compared without ground truth.
    let free_share = pfslam::pipeline::free_share(&rec, &poses, grid, &config)?;
    say!(
        "consistency: {:.1} % of the scan returns land in cells the map calls free",
        100.0 * free_share
    );

    // Render first: a drawing failure must not leave the other files behind.
    let png = render_png(&args.poses, &poses, &overlays, &mapped)?;
    let rect = grid
        .observed_bounds()
        .context("the map is empty: no scan produced a ray")?;
    let comparison: Option<MapComparison> = match &truth {
        Some(t) => Some(t.compare(&grid.to_binary_map(Some(rect)), args.tolerance_cells)?),
        None => None,
    };

    write_map_files(&out, grid, rect, &png)?;
    let mut report = map_stats_json(&args, &ds.account, &config, &mapped, rect, free_share);
    if let Some(c) = &comparison {
        report["comparison"] = comparison_json(args.truth.as_deref(), c);
        say!("{c}");
    }
    let text = serde_json::to_string_pretty(&report)? + "\n";
    write_bytes_atomic(&out.join("map_stats.json"), text.as_bytes())?;
    staging.commit()?;
    say!(
        "map: {} scans, {} x {} cells at {} m -> {}",
        mapped.stats.scans_inserted,
        rect.width(),
        rect.height(),
        config.map.resolution_m,
        args.out.display()
    );
    Ok(())
}

/// The configuration with the command line's map overrides, validated.
fn map_config(args: &Args) -> anyhow::Result<Config> {
    let mut config = args.input.config(args.config.as_deref())?;
    if let Some(r) = args.resolution {
        config.map.resolution_m = r;
    }
    if let Some(p) = args.preset {
        config.map = config.map.clone().with_preset(match p {
            Preset::Ucsd => LogOddsPreset::Ucsd,
            Preset::Ese650 => LogOddsPreset::Ese650,
        });
    }
    if args.z_min.is_some() {
        config.map.scan.z_min_m = args.z_min;
    }
    if args.z_max.is_some() {
        config.map.scan.z_max_m = args.z_max;
    }
    config.validate()?;
    Ok(config)
}

/// The `--overlay LABEL=FILE.tum` trajectories, read.
fn read_overlays(specs: &[String]) -> anyhow::Result<Vec<(String, Vec<Pose2>)>> {
    let mut overlays = Vec::new();
    for o in specs {
        let Some((label, file)) = o.split_once('=') else {
            bail!("--overlay {o:?}: expected LABEL=FILE.tum");
        };
        let t = read_tum(Path::new(file))?;
        overlays.push((
            label.to_string(),
            t.poses.iter().map(|p| p.pose).collect::<Vec<Pose2>>(),
        ));
    }
    Ok(overlays)
}

/// Maps the recording along the poses, timed, and logs the figures.
fn map_timed(rec: &Recording, poses: &Trajectory, config: &Config) -> anyhow::Result<Mapped> {
    let t0 = std::time::Instant::now();
    let cpu0 = pfslam::pipeline::process_cpu_s();
    let (grid, last_scan, stats) = map_with_poses(rec, poses, &config.map)?;
    let mapping_s = t0.elapsed().as_secs_f64();
    let mapping_cpu_s = cpu0
        .zip(pfslam::pipeline::process_cpu_s())
        .map(|(a, b)| b - a);
    tracing::info!(
        "mapped {} scans ({} rays) in {mapping_s:.2} s ({:.2} s CPU); {} scans had no pose; {} tiles, {:.1} MB",
        stats.scans_inserted,
        stats.rays,
        mapping_cpu_s.unwrap_or(f64::NAN),
        stats.scans_without_pose,
        grid.tile_count(),
        grid.memory_bytes() as f64 / 1e6
    );
    Ok(Mapped {
        grid,
        last_scan,
        stats,
        mapping_s,
        mapping_cpu_s,
    })
}

/// `map.png` as PNG bytes: the map with the poses (labelled by their file), the overlays and
/// the last scan.
fn render_png(
    poses_path: &Path,
    poses: &Trajectory,
    overlays: &[(String, Vec<Pose2>)],
    mapped: &Mapped,
) -> anyhow::Result<Vec<u8>> {
    let main_poses: Vec<Pose2> = poses.poses.iter().map(|p| p.pose).collect();
    let main_label = file_label(poses_path);
    let mut drawn = vec![TrajectoryOverlay {
        label: &main_label,
        poses: &main_poses,
    }];
    drawn.extend(
        overlays
            .iter()
            .map(|(l, p)| TrajectoryOverlay { label: l, poses: p }),
    );
    let options = MapImageOptions::default();
    let picture =
        render_map(&mapped.grid, &drawn, Some(&mapped.last_scan), &options).context("map.png")?;
    picture.to_png().context("map.png")
}

/// Writes `map.png`, `binary_map.png`, `map.pgm` + `map.yaml` and `logodds.npy` over `rect`.
fn write_map_files(
    out: &Path,
    grid: &OccupancyGrid,
    rect: CellRect,
    png: &[u8],
) -> anyhow::Result<()> {
    write_bytes_atomic(&out.join("map.png"), png)?;
    write_binary_png(&out.join("binary_map.png"), grid, Some(rect)).context("binary_map.png")?;
    write_map_server(&grid.to_binary_map(Some(rect)), &out.join("map.yaml"))?;
    write_logodds_npy(grid, &rect, &out.join("logodds.npy"))?;
    Ok(())
}

/// `map_stats.json` without the comparison.
fn map_stats_json(
    args: &Args,
    account: &InputAccount,
    config: &Config,
    mapped: &Mapped,
    rect: CellRect,
    free_share: f64,
) -> serde_json::Value {
    let (grid, stats) = (&mapped.grid, &mapped.stats);
    serde_json::json!({
        "dataset": args.dataset.display().to_string(),
        "poses": args.poses.display().to_string(),
        "input": account,
        "resolution_m": config.map.resolution_m,
        "scans_inserted": stats.scans_inserted,
        "scans_without_pose": stats.scans_without_pose,
        "rays": stats.rays,
        "mapping_s": mapped.mapping_s,
        "mapping_cpu_s": mapped.mapping_cpu_s,
        "tiles": grid.tile_count(),
        "memory_bytes": grid.memory_bytes(),
        "extent_cells": [rect.width(), rect.height()],
        "free_share": free_share,
    })
}

/// The comparison with the true map in `truth`, for `map_stats.json`.
fn comparison_json(truth: Option<&Path>, c: &MapComparison) -> serde_json::Value {
    serde_json::json!({
        "truth": truth.map(|p| p.display().to_string()),
        "tolerance_cells": c.tolerance_cells,
        "precision": c.precision(),
        "recall": c.recall(),
        "recall_all": c.recall_all(),
        "free_agreement": c.free_agreement(),
        "estimated_occupied": c.estimated_occupied,
        "true_occupied_observed": c.true_occupied_observed,
        "estimated_free": c.estimated_free,
        "estimated_free_truly_occupied": c.estimated_free_truly_occupied,
    })
}
