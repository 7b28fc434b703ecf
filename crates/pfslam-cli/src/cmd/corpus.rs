//! `pfslam benchmark --corpus DIR`: SLAM on every CARMEN log in a directory whose laser lines
//! carry reference poses (Radish's corrected logs), as it is and with its odometry perturbed
//! at each `--levels` severity (`pfslam::motion::perturb`), scored by ATE against the
//! reference: one table, to judge a configuration on buildings, lasers and odometry it was
//! not tuned on.

use anyhow::Context;
use pfslam::Slam;
use pfslam::config::Config;
use pfslam::eval::{Association, ate::ate};
use pfslam::geometry::Trajectory;
use pfslam::motion::perturb::{OdometryErrors, perturb_odometry};
use pfslam::pipeline::PipelineOptions;
use pfslam::sensors::Recording;
use pfslam::sensors::sync::poses_at_stamps;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One row: a log at one perturbation level.
#[derive(Debug, serde::Serialize)]
pub struct CorpusRow {
    /// The log's name.
    pub name: String,
    /// Perturbation severity (0 = the log's own odometry).
    pub level: u8,
    /// Seed of the perturbation and of the filter.
    pub seed: u64,
    /// Scans.
    pub scans: usize,
    /// ATE RMSE (SE(2)-aligned) of the odometry against the reference (m).
    pub odometry_ate_m: f64,
    /// ATE RMSE (SE(2)-aligned) of SLAM against the reference (m).
    pub slam_ate_m: f64,
    /// Share of scan returns in cells the final map calls free (the self-check's signal).
    pub free_share: f64,
    /// The self-check's verdict.
    pub verdict: pfslam::quality::QualityStatus,
    /// Wall time of SLAM (s).
    pub wall_s: f64,
}

/// The CARMEN logs in `dir`, sorted.
fn logs_in(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut logs: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("--corpus {}", dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let n = p
                .file_name()
                .map(|n| n.to_string_lossy().to_lowercase())
                .unwrap_or_default();
            let base = n.strip_suffix(".gz").unwrap_or(&n);
            base.ends_with(".log") || base.ends_with(".clf")
        })
        .collect();
    logs.sort();
    if logs.is_empty() {
        anyhow::bail!(
            "--corpus {}: no CARMEN log (.log, .clf, optionally .gz)",
            dir.display()
        );
    }
    Ok(logs)
}

/// ATE RMSE (SE(2)-aligned) of a recording's odometry at its scans against `reference`.
pub(crate) fn odometry_ate_m(rec: &Recording, reference: &Trajectory) -> anyhow::Result<f64> {
    let (at_scans, _) = poses_at_stamps(&rec.odometry, &rec.scans.stamps_ns);
    ate_rmse(&Trajectory::new(at_scans), reference)
}

/// ATE RMSE (SE(2)-aligned) of `estimate` against `reference`, paired by stamp.
fn ate_rmse(estimate: &Trajectory, reference: &Trajectory) -> anyhow::Result<f64> {
    Ok(ate(
        estimate,
        reference,
        Association::Nearest { tolerance_ns: 0 },
    )?
    .aligned_m
    .rmse)
}

/// Runs every log at every level and prints (and with `out`, writes) the table.
pub fn run_corpus(
    dir: &Path,
    levels: &[u8],
    config: &Config,
    seeds: &[u64],
    out: Option<&Path>,
) -> anyhow::Result<Vec<CorpusRow>> {
    let errors: Vec<(u8, OdometryErrors)> = levels
        .iter()
        .map(|&l| {
            OdometryErrors::level(l)
                .map(|e| (l, e))
                .ok_or_else(|| anyhow::anyhow!("--levels: {l} is not 0-3"))
        })
        .collect::<anyhow::Result<_>>()?;
    let mut rows = Vec::new();
    say!(
        "| log | level | seed | scans | odometry ATE (m) | SLAM ATE (m) | free share | verdict | wall (s) |"
    );
    say!("|---|---|---|---|---|---|---|---|---|");
    for path in logs_in(dir)? {
        let log = pfslam_io::carmen::read_carmen(
            &path,
            &pfslam_io::carmen::CarmenOptions::from_reader(&config.input),
        )?;
        let mut rec = log.recording;
        let original = rec.odometry.clone();
        for &(level, e) in &errors {
            for &seed in seeds {
                rec.odometry = perturb_odometry(&original, &e, seed);
                let row = corpus_row(&rec, &log.laser_poses, config, level, seed)
                    .with_context(|| format!("SLAM on {} at level {level}", path.display()))?;
                say!(
                    "| {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {} | {:.1} |",
                    row.name,
                    row.level,
                    row.seed,
                    row.scans,
                    row.odometry_ate_m,
                    row.slam_ate_m,
                    row.free_share,
                    row.verdict.as_str(),
                    row.wall_s
                );
                rows.push(row);
            }
        }
    }
    if let Some(out) = out {
        let text =
            serde_json::to_string_pretty(&serde_json::json!({ "seeds": seeds, "rows": rows }))?;
        pfslam_io::write_bytes_atomic(&out.join("corpus.json"), text.as_bytes())?;
    }
    Ok(rows)
}

/// One log at one level and seed: SLAM with the default pipeline, scored against `reference`.
fn corpus_row(
    rec: &Recording,
    reference: &Trajectory,
    config: &Config,
    level: u8,
    seed: u64,
) -> anyhow::Result<CorpusRow> {
    let odometry_ate_m = odometry_ate_m(rec, reference)?;
    let t = Instant::now();
    let options = PipelineOptions {
        rebuild_map: false,
        ..PipelineOptions::default()
    };
    // The recording handed to the incremental API, as `pfslam run` does.
    let slam = Slam::with_recording(config.clone(), rec.clone(), seed)?;
    let (result, _) = slam.finish_observed(&options, &mut |_| {})?;
    let wall_s = t.elapsed().as_secs_f64();
    Ok(CorpusRow {
        name: rec.name.clone(),
        level,
        seed,
        scans: rec.scans.len(),
        odometry_ate_m,
        slam_ate_m: ate_rmse(&Trajectory::new(result.result.trajectory), reference)?,
        free_share: result.quality.signals.free_share,
        verdict: result.quality.status,
        wall_s,
    })
}
