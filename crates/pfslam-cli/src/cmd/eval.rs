//! `pfslam eval`: accuracy of a trajectory (TUM file) against ground truth (ATE and RPE) or
//! against the relations of the Freiburg benchmark (Kümmerle et al. 2009).

use anyhow::Context;
use pfslam::eval::ate::{AteResult, ate_of_pairs};
use pfslam::eval::relations::{AbsSquared, RelationsOptions, RelationsResult, evaluate_relations};
use pfslam::eval::rpe::{RpeDelta, RpeResult, rpe_of_pairs};
use pfslam::eval::{Association, ErrorStats, associate};
use pfslam::geometry::Trajectory;
use pfslam::sensors::sync::poses_at_stamps;
use pfslam_io::recording::{ReaderOptions, detect_format, read_recording};
use pfslam_io::relations::read_relations;
use pfslam_io::tum::read_tum;
use std::path::{Path, PathBuf};

/// Arguments of `eval`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("reference").required(true).args(["ground_truth", "relations"])))]
pub struct Args {
    /// The estimated trajectory (TUM: `stamp_s x y z qx qy qz qw`), or a recording (CARMEN
    /// log, ROS 1 bag, MCAP), whose raw odometry at its scan stamps is then scored: the
    /// baseline a SLAM result must beat.
    pub trajectory: PathBuf,
    /// Ground-truth trajectory (TUM), or a CARMEN log whose laser lines carry corrected poses
    /// (their `x y theta`, at the stamps the reader gives its scans): prints ATE (aligned and
    /// unaligned) and RPE.
    #[arg(long, value_name = "GT.tum|LOG")]
    pub ground_truth: Option<PathBuf>,
    /// Relations file (`t1 t2 x y z roll pitch yaw`): prints the relations metric.
    #[arg(long, value_name = "FILE")]
    pub relations: Option<PathBuf>,
    /// Print JSON instead of text: one object with `ate` and `rpe` (ground truth) and/or
    /// `relations`.
    #[arg(long)]
    pub json: bool,
    /// Stamp tolerance (ns). Ground truth: nearest pose within it (default 1000). Relations:
    /// overrides the default of half a unit of the last decimal printed in the file.
    #[arg(long, value_name = "NS")]
    pub tolerance_ns: Option<i64>,
    /// Ground truth: interpolate it at the estimate's stamps when its two poses around a stamp
    /// are at most this many seconds apart (instead of nearest-stamp matching).
    #[arg(long, value_name = "S")]
    pub interpolate_max_gap_s: Option<f64>,
    /// RPE step in frames (default 1).
    #[arg(long, value_name = "N", conflicts_with = "rpe_metres")]
    pub rpe_frames: Option<usize>,
    /// RPE step as a distance travelled (m).
    #[arg(long, value_name = "M")]
    pub rpe_metres: Option<f64>,
}

/// A reference trajectory: a TUM file, or the laser poses of a CARMEN log.
fn read_reference(path: &std::path::Path) -> anyhow::Result<pfslam::geometry::Trajectory> {
    if detect_format(path)? == Some(pfslam_io::recording::RecordingFormat::Carmen) {
        let opts = pfslam_io::carmen::CarmenOptions::from_reader(&ReaderOptions::default());
        return Ok(pfslam_io::carmen::read_carmen(path, &opts)?.laser_poses);
    }
    Ok(read_tum(path)?)
}

fn stats_line(s: &ErrorStats, unit: &str) -> String {
    format!(
        "rmse {:.4} {unit}, mean {:.4}, median {:.4}, std {:.4}, max {:.4} ({} values)",
        s.rmse, s.mean, s.median, s.std, s.max, s.count
    )
}

/// Runs `eval`.
pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(t) = args.tolerance_ns
        && t < 0
    {
        anyhow::bail!("--tolerance-ns must be >= 0, got {t}");
    }
    let delta = rpe_delta(&args)?;
    let association = association(&args)?;
    let estimate = read_estimate(&args)?;
    // with --json, one object holding every metric asked for
    let mut json = serde_json::Map::new();
    if let Some(gt_path) = &args.ground_truth {
        let (ate, rpe) = versus_ground_truth(&args, &estimate, gt_path, association, delta)?;
        if args.json {
            json.insert("ate".into(), serde_json::to_value(&ate)?);
            json.insert("rpe".into(), serde_json::to_value(&rpe)?);
        } else {
            print_ate_rpe(&ate, &rpe);
        }
    }
    if let Some(rel_path) = &args.relations {
        let rel = read_relations(rel_path)?;
        let options = RelationsOptions {
            stamp_tolerance_ns: args.tolerance_ns,
        };
        let r = evaluate_relations(&estimate, &rel, &options)
            .with_context(|| format!("{} vs {}", args.trajectory.display(), rel_path.display()))?;
        if args.json {
            json.insert("relations".into(), serde_json::to_value(&r)?);
        } else {
            print_relations(&r);
        }
    }
    if args.json {
        say!("{}", serde_json::to_string_pretty(&json)?);
    }
    Ok(())
}

/// The RPE step from `--rpe-frames` / `--rpe-metres` (one frame by default).
fn rpe_delta(args: &Args) -> anyhow::Result<RpeDelta> {
    Ok(match (args.rpe_frames, args.rpe_metres) {
        (_, Some(m)) if !(m > 0.0 && m.is_finite()) => {
            anyhow::bail!("--rpe-metres must be a positive distance, got {m}")
        }
        (_, Some(m)) => RpeDelta::Metres(m),
        (Some(0), _) => anyhow::bail!("--rpe-frames must be >= 1"),
        (Some(k), _) => RpeDelta::Frames(k),
        (None, None) => RpeDelta::Frames(1),
    })
}

/// How estimate and ground truth are paired: interpolated with `--interpolate-max-gap-s`,
/// else nearest stamp within `--tolerance-ns`.
fn association(args: &Args) -> anyhow::Result<Association> {
    Ok(match args.interpolate_max_gap_s {
        Some(g) if !(g >= 0.0 && g.is_finite()) => {
            anyhow::bail!("--interpolate-max-gap-s must be >= 0, got {g}")
        }
        Some(g) => Association::Interpolate {
            max_gap_ns: (g * 1e9).round() as i64,
        },
        None => Association::Nearest {
            tolerance_ns: args.tolerance_ns.unwrap_or(1_000),
        },
    })
}

/// The trajectory to score: a TUM file, or a recording's raw odometry at its scan stamps.
fn read_estimate(args: &Args) -> anyhow::Result<Trajectory> {
    Ok(match detect_format(&args.trajectory)? {
        Some(_) => {
            let rec = read_recording(&args.trajectory, &ReaderOptions::default())?;
            let (poses, clamped) = poses_at_stamps(&rec.odometry, &rec.scans.stamps_ns);
            if !args.json {
                say!(
                    "raw odometry of {} at its {} scan stamps ({clamped} outside the odometry's time span, given its first/last pose)",
                    args.trajectory.display(),
                    rec.scans.len(),
                );
            }
            Trajectory::new(poses)
        }
        None => read_tum(&args.trajectory)?,
    })
}

/// ATE and RPE of `estimate` against the ground truth in `gt_path`.
fn versus_ground_truth(
    args: &Args,
    estimate: &Trajectory,
    gt_path: &Path,
    association: Association,
    delta: RpeDelta,
) -> anyhow::Result<(AteResult, RpeResult)> {
    let gt = read_reference(gt_path)?;
    let pairs = associate(estimate, &gt, association);
    let ate = ate_of_pairs(&pairs, estimate.len() - pairs.len())
        .with_context(|| format!("{} vs {}", args.trajectory.display(), gt_path.display()))?;
    let rpe = rpe_of_pairs(&pairs, delta)?;
    Ok((ate, rpe))
}

/// The ATE and RPE figures as text.
fn print_ate_rpe(ate: &AteResult, rpe: &RpeResult) {
    say!(
        "associated poses: {} ({} estimate poses without ground truth)",
        ate.pairs,
        ate.unmatched
    );
    say!("ATE aligned (SE(2)):   {}", stats_line(&ate.aligned_m, "m"));
    say!(
        "ATE unaligned:         {}",
        stats_line(&ate.unaligned_m, "m")
    );
    say!(
        "heading aligned:       {}",
        stats_line(&ate.aligned_rot_deg, "deg")
    );
    say!(
        "alignment gt_from_estimate: x {:.4} m, y {:.4} m, yaw {:.4} deg",
        ate.alignment.x_m,
        ate.alignment.y_m,
        ate.alignment.yaw_rad.to_degrees()
    );
    let d = match rpe.delta {
        RpeDelta::Frames(k) => format!("{k} frame(s)"),
        RpeDelta::Metres(m) => format!("{m} m"),
    };
    say!(
        "RPE over {d}: translation {}",
        stats_line(&rpe.trans_m, "m")
    );
    say!(
        "RPE over {d}: rotation    {}",
        stats_line(&rpe.rot_deg, "deg")
    );
}

/// The relations metric as text.
fn print_relations(r: &RelationsResult) {
    say!(
        "relations: {} used of {} ({} skipped: a stamp without pose)",
        r.used,
        r.relations,
        r.skipped
    );
    print_abs_squared("translational error:", &r.trans_m, "m", 5);
    print_abs_squared("rotational error:   ", &r.rot_deg, "deg", 4);
}

/// One error of the relations metric as a line: mean, spread and maximum, plain and squared
/// (the squared mean and spread to `digits` decimals).
fn print_abs_squared(label: &str, e: &AbsSquared, unit: &str, digits: usize) {
    let (a, s) = (&e.abs, &e.squared);
    say!(
        "{label} {:.4} +- {:.4} {unit} (max {:.4}); squared {:.digits$} +- {:.digits$} {unit}^2 (max {:.4})",
        a.mean,
        a.std,
        a.max,
        s.mean,
        s.std,
        s.max
    );
}
