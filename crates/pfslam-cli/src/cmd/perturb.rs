//! `pfslam perturb RECORDING --out FILE.log --level L --seed N`: the recording with its
//! odometry degraded (scale and turning errors, yaw drift, random walk, slips;
//! `pfslam::motion::perturb`), written as a CARMEN log, and the reference trajectory it
//! came from beside it (`FILE.reference.tum`), to check that SLAM recovers the path.
//! `--keyframes-m` thins the scans to keyframes first.

use pfslam::motion::perturb::{OdometryErrors, perturb_odometry};
use pfslam::sensors::sync::poses_at_stamps;
use pfslam_io::carmen::write_carmen;
use pfslam_io::tum::write_tum;
use std::path::PathBuf;

/// Arguments of `perturb`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recording (any format `run` reads).
    pub recording: PathBuf,
    /// The CARMEN log to write (`.log` or `.clf`); the reference goes beside it as
    /// `<stem>.reference.tum`.
    #[arg(long)]
    pub out: PathBuf,
    /// Severity 0-3: 0 none, 1 a well-calibrated robot, 2 about the Intel recording's
    /// odometry, 3 worse.
    #[arg(long, default_value_t = 2)]
    pub level: u8,
    /// Seed of the errors.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Keep only keyframe scans: the first, then each after this much travel (m) or ten
    /// times as many degrees of turning since the last kept one, by the original odometry
    /// (as the Radish logs were thinned).
    #[arg(long)]
    pub keyframes_m: Option<f64>,
    /// TOML configuration (its `[input]` section applies).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Input selection and strictness.
    #[command(flatten)]
    pub input: super::input::InputArgs,
}

/// Writes the perturbed log and the reference.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.input.config(args.config.as_deref())?;
    config.validate()?;
    let errors = OdometryErrors::level(args.level)
        .ok_or_else(|| anyhow::anyhow!("--level must be 0, 1, 2 or 3, got {}", args.level))?;
    let name = args
        .out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let lower = name.to_lowercase();
    let stem_len = lower
        .strip_suffix(".log")
        .or_else(|| lower.strip_suffix(".clf"))
        .map(str::len);
    let Some(stem) = stem_len.map(|n| &name[..n]) else {
        anyhow::bail!(
            "--out {}: the log's name must end in .log or .clf",
            args.out.display()
        );
    };
    let reference_path = args.out.with_file_name(format!("{stem}.reference.tum"));
    let ds = super::dataset::load_dataset(&args.recording, &config, false)?;
    super::input::report(&ds.account);
    let mut rec = ds.recording;
    let (mut reference, _) = poses_at_stamps(&rec.odometry, &rec.scans.stamps_ns);
    if let Some(m) = args.keyframes_m {
        anyhow::ensure!(
            m.is_finite() && m > 0.0,
            "--keyframes-m must be positive, got {m}"
        );
        anyhow::ensure!(
            reference.len() == rec.scans.len(),
            "--keyframes-m: {} has no odometry to choose keyframes by",
            args.recording.display()
        );
        // the mapper's motion filter picks the keyframes
        let filter = pfslam::map::MapOptions {
            scan_step: 1,
            min_scan_travel_m: m,
            min_scan_turn_deg: 10.0 * m,
            ..Default::default()
        };
        let keep = pfslam::map::scans_to_map(&rec, &rec.odometry, &filter);
        say!(
            "keyframes: {} of {} scans (one per {m} m or {} deg)",
            keep.len(),
            rec.scans.len(),
            10.0 * m
        );
        rec.keep_scans(&keep);
        reference = keep.iter().map(|&i| reference[i]).collect();
    }
    let reference = pfslam::geometry::Trajectory::new(reference);
    rec.odometry = perturb_odometry(&rec.odometry, &errors, args.seed);
    let written = write_carmen(&args.out, &rec, Some(&reference))?;
    write_tum(&reference_path, &reference.poses)?;
    let ate_m = super::corpus::odometry_ate_m(&rec, &reference)?;
    say!(
        "wrote {} ({written} scans, odometry at level {}, seed {}: ATE {:.3} m RMSE against the reference) and {}",
        args.out.display(),
        args.level,
        args.seed,
        ate_m,
        reference_path.display()
    );
    Ok(())
}
