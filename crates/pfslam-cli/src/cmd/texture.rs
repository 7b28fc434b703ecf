//! `pfslam texture DATASET --poses TRAJ.tum --out DIR`: the ground's colours from the car's
//! stereo pairs, accumulated per grid cell along a trajectory.
//!
//! Writes `texture.png` (coloured ground over the grey occupancy map when the dataset has
//! LiDAR scans, else over plain grey), `texture_rgb.npy` (float32 HxWx3 mean colour 0-255, NaN
//! where unobserved), `texture_count.npy` (float32 HxW samples per cell) and `texture.json`
//! (the raster's geometry). Row 0 of every raster is the largest world y. `pfslam run` writes
//! the same files along its SLAM trajectory ([`texture_after_run`]).

use anyhow::Context;
use pfslam::config::Config;
use pfslam::geometry::{StampedPose2, Trajectory};
use pfslam::map::{CellRect, CellState, OccupancyGrid, map_with_poses};
use pfslam::sensors::StereoCalibration;
use pfslam_io::map_files::write_npy_f32;
use pfslam_io::stereo_dataset::{TextureStats, texture_dataset};
use pfslam_io::tum::read_tum;
use pfslam_io::ucsd::{PARAM_DIR, STEREO_LEFT_DIR, read_car_calibration, read_stereo_stamps};
use pfslam_io::{write_atomic, write_bytes_atomic};
use pfslam_stereo::TextureMap;
use pfslam_stereo::image::{RgbImage, encode_rgb_png};
use std::path::{Path, PathBuf};

/// Longest side of `texture.png` (px); larger rasters are reduced by an integer factor.
const MAX_PNG_SIDE_PX: usize = 4000;

/// Arguments of `texture`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory: stereo_images/stereo_left|stereo_right/<stamp_ns>.png, param/
    /// (calibration; the built-in UCSD rig when absent), sensor_data/ (optional, for the map).
    pub dataset: PathBuf,
    /// Trajectory (TUM: `t x y z qx qy qz qw`, seconds) giving `world_from_body`.
    #[arg(long)]
    pub poses: PathBuf,
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// TOML configuration; its `[stereo]` and `[map]` (and `[motion]`) sections apply.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Use every n-th stereo pair.
    #[arg(long, default_value_t = 1)]
    pub every: usize,
}

/// Runs texture mapping.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(p) => Config::from_toml_file(p)?,
        None => Config::default(),
    };
    config.map.validate().map_err(anyhow::Error::msg)?;
    if args.every == 0 {
        anyhow::bail!("--every must be >= 1");
    }
    if args.out.exists() && !args.out.is_dir() {
        anyhow::bail!(
            "--out {}: exists and is not a directory",
            args.out.display()
        );
    }
    let calibration = load_calibration(&args.dataset)?;
    config.stereo.validate(calibration.left.width as usize)?;
    if read_stereo_stamps(&args.dataset)?.is_empty() {
        anyhow::bail!(
            "{}: no stereo images (expected {STEREO_LEFT_DIR}/<stamp_ns>.png)",
            args.dataset.display()
        );
    }
    let poses = read_tum(&args.poses)?;
    if poses.is_empty() {
        anyhow::bail!("{}: no poses", args.poses.display());
    }
    let grid = grey_map(&args.dataset, &poses, &config);
    write_texture(
        &args.dataset,
        &calibration,
        &poses,
        &config,
        args.every,
        grid.as_ref(),
        &args.out,
    )?;
    Ok(())
}

/// `pfslam run`'s texture: when the dataset directory has stereo images, colours the ground
/// along the SLAM `trajectory`, over the SLAM `map`, into `out` (the files of `texture`). The
/// texture is an extra of `run`, so a failure is a warning: the SLAM outputs and the exit
/// status stay.
pub fn texture_after_run(
    dataset: &Path,
    trajectory: &[StampedPose2],
    config: &Config,
    map: &OccupancyGrid,
    out: &Path,
) {
    if let Err(e) = try_texture_after_run(dataset, trajectory, config, map, out) {
        tracing::warn!("texture not written: {e:#}");
    }
}

/// [`texture_after_run`], with its error.
fn try_texture_after_run(
    dataset: &Path,
    trajectory: &[StampedPose2],
    config: &Config,
    map: &OccupancyGrid,
    out: &Path,
) -> anyhow::Result<()> {
    if !dataset.is_dir() || read_stereo_stamps(dataset)?.is_empty() {
        return Ok(());
    }
    let calibration = load_calibration(dataset)?;
    let poses = Trajectory::new(trajectory.to_vec());
    write_texture(dataset, &calibration, &poses, config, 1, Some(map), out)?;
    Ok(())
}

/// Accumulates every `every`-th pair along `poses` and writes `texture.png`, the `.npy`
/// rasters and `texture.json` into `out`.
fn write_texture(
    dataset: &Path,
    calibration: &StereoCalibration,
    poses: &Trajectory,
    config: &Config,
    every: usize,
    grid: Option<&OccupancyGrid>,
    out: &Path,
) -> anyhow::Result<TextureStats> {
    let (texture, stats) = texture_dataset(
        dataset,
        calibration,
        poses,
        &config.stereo,
        config.stereo.texture_limits(&config.map),
        every,
    )?;
    if stats.pairs_without_pose > 0 {
        tracing::warn!(
            "{} stereo pairs lie outside the trajectory's time span: skipped",
            stats.pairs_without_pose
        );
    }
    let rect = texture
        .bounds()
        .context("no ground point was coloured (no pair within the trajectory, or no match)")?;
    tracing::info!(
        "{} pairs, {} ground points, {} cells coloured",
        stats.pairs_used,
        stats.ground_points,
        texture.cells.len()
    );

    let (rgb, count) = texture.rasterize(&rect);
    let (w, h) = (rect.width(), rect.height());
    write_npy_f32(&out.join("texture_rgb.npy"), &[h, w, 3], &rgb)?;
    write_npy_f32(&out.join("texture_count.npy"), &[h, w], &count)?;
    let png = picture(&texture, &rect, grid);
    write_bytes_atomic(&out.join("texture.png"), &encode_rgb_png(&png)?)?;
    let limits = texture.limits();
    let (x0, y0) = limits.cell_corner(pfslam::map::Cell::new(rect.min_i, rect.min_j));
    let meta = serde_json::json!({
        "resolution_m": limits.resolution_m(),
        "lower_left_corner_m": [x0, y0],
        "width_cells": w,
        "height_cells": h,
        "row_0": "largest y",
        "png_cells_per_pixel": reduction(&rect),
        "background": if grid.is_some() { "occupancy map" } else { "plain grey (no LiDAR data)" },
        "pairs_used": stats.pairs_used,
        "pairs_without_pose": stats.pairs_without_pose,
        "ground_points": stats.ground_points,
        "cells_coloured": texture.cells.len(),
    });
    write_atomic(&out.join("texture.json"), |wr| {
        serde_json::to_writer_pretty(&mut *wr, &meta)?;
        wr.write_all(b"\n")
    })?;
    say!(
        "texture: {} pairs, {} cells coloured -> {}",
        stats.pairs_used,
        texture.cells.len(),
        out.join("texture.png").display()
    );
    Ok(stats)
}

/// The rig from `DATASET/param/` or, when that folder is absent, the built-in UCSD rig.
fn load_calibration(dataset: &Path) -> anyhow::Result<StereoCalibration> {
    let param = dataset.join(PARAM_DIR);
    if !param.is_dir() {
        tracing::warn!(
            "{}: no calibration folder: using the built-in UCSD stereo calibration",
            param.display()
        );
        return Ok(StereoCalibration::ucsd());
    }
    read_car_calibration(&param)?
        .stereo
        .with_context(|| format!("{}: no stereo calibration files", param.display()))
}

/// The occupancy map of the dataset's LiDAR along the poses, when the dataset has sensor data;
/// `None` (with a note) otherwise.
fn grey_map(
    dataset: &Path,
    poses: &pfslam::geometry::Trajectory,
    config: &Config,
) -> Option<OccupancyGrid> {
    if !dataset.join(pfslam_io::ucsd::LIDAR_CSV).is_file() {
        tracing::info!("no LiDAR data: texture.png has a plain grey background");
        return None;
    }
    let built = (|| -> anyhow::Result<OccupancyGrid> {
        let rec = super::dataset::load_dataset(dataset, config, false)?.recording;
        Ok(map_with_poses(&rec, poses, &config.map)?.0)
    })();
    match built {
        Ok(g) => Some(g),
        Err(e) => {
            tracing::warn!("occupancy map not built ({e:#}): plain grey background");
            None
        }
    }
}

fn reduction(rect: &CellRect) -> usize {
    rect.width()
        .max(rect.height())
        .div_ceil(MAX_PNG_SIDE_PX)
        .max(1)
}

/// Coloured cells over the map's greys (occupied dark, free light, unknown mid grey), north up,
/// `k x k` cells per pixel (the mean of the coloured cells of a block, else the map's grey at
/// the block's centre).
fn picture(texture: &TextureMap, rect: &CellRect, grid: Option<&OccupancyGrid>) -> RgbImage {
    let k = reduction(rect);
    let (w, h) = (rect.width().div_ceil(k), rect.height().div_ceil(k));
    let mut img = RgbImage::new(w, h);
    let limits = *texture.limits();
    for row in 0..h {
        for col in 0..w {
            let mut sum = [0.0f64; 3];
            let mut n = 0usize;
            for dj in 0..k {
                for di in 0..k {
                    let cell = pfslam::map::Cell::new(
                        rect.min_i + (col * k + di) as i32,
                        rect.max_j - (row * k + dj) as i32,
                    );
                    if let Some(c) = texture.get(cell) {
                        for (s, m) in sum.iter_mut().zip(c.mean) {
                            *s += m;
                        }
                        n += 1;
                    }
                }
            }
            let px = if n > 0 {
                sum.map(|s| (s / n as f64).round().clamp(0.0, 255.0) as u8)
            } else {
                let centre = pfslam::map::Cell::new(
                    rect.min_i + (col * k + k / 2) as i32,
                    rect.max_j - (row * k + k / 2) as i32,
                );
                let grey = match grid {
                    Some(g) => {
                        let (x, y) = limits.cell_centre(centre);
                        match g.state(g.cell_of(x, y)) {
                            CellState::Occupied => 40,
                            CellState::Free => 215,
                            CellState::Unknown => 128,
                        }
                    }
                    None => 128,
                };
                [grey; 3]
            };
            let i = 3 * (row * w + col);
            img.data[i..i + 3].copy_from_slice(&px);
        }
    }
    img
}
