//! `pfslam run REC --resume STATE --out DIR`: continues a saved map with a new recording.

use super::dataset::{Dataset, load_dataset};
use super::run::Args;
use anyhow::Context;
use pfslam::config::Config;
use pfslam::geometry::Pose2;
use pfslam::session::{ResumeResult, SessionState, resume};
use pfslam_io::map_files::write_map_server;
use pfslam_io::tum::write_tum;
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, write_binary_png, write_map_png};
use std::path::Path;
use std::time::Instant;

/// Writes `state` to `path` in one step.
pub fn save_state(path: &Path, state: &SessionState) -> anyhow::Result<()> {
    let bytes = state.to_bytes()?;
    pfslam_io::write_bytes_atomic(path, &bytes)
        .with_context(|| format!("writing {}", path.display()))?;
    say!(
        "saved {} keyframes of {} session(s) to {}",
        state.keyframes.len(),
        state.sessions.len(),
        path.display()
    );
    Ok(())
}

/// Loads the state and the recording, resumes, writes the outputs.
pub fn run(args: &Args, config: &Config) -> anyhow::Result<()> {
    let Some(state_path) = args.resume.as_deref() else {
        anyhow::bail!("--resume is missing");
    };
    let state = SessionState::read(state_path)?;
    let initial_pose = match args.initial_pose.as_deref() {
        Some("last") => state.sessions.last().map(|s| s.end_pose),
        Some(text) => Some(super::localize::parse_pose(text)?),
        None => None,
    };
    let staging = super::output::Staging::new(&args.out)?;
    let t = Instant::now();
    let Dataset {
        recording, account, ..
    } = load_dataset(&args.dataset, config, args.sort_timestamps)
        .with_context(|| format!("loading {}", args.dataset.display()))?;
    super::input::report(&account);
    let load_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let r = resume(
        &state,
        &recording,
        config,
        args.seed,
        initial_pose,
        &mut |_| {},
    )
    .with_context(|| format!("continuing {}", state_path.display()))?;
    let run_s = t.elapsed().as_secs_f64();
    let out = staging.path();
    write_tum(&out.join("trajectory.tum"), &r.trajectory)?;
    write_tum(&out.join("front_end.tum"), &r.front_end)?;
    write_tum(&out.join("previous_sessions.tum"), &r.previous)?;
    write_maps(out, &r)?;
    let summary = serde_json::json!({
        "dataset": args.dataset.display().to_string(),
        "recording": recording.name,
        "resumed_from": state_path.display().to_string(),
        "input": account,
        "seed": args.seed,
        "config": config,
        "sessions": r.state.sessions,
        "keyframes": {
            "before": state.keyframes.len(),
            "after": r.state.keyframes.len(),
        },
        "start": {
            "stamp_s": r.start_ns as f64 * 1e-9,
            "scans_before": r.scans_before_start,
            "initial_pose_given": initial_pose.is_some(),
        },
        "quality": r.quality,
        "odometry_timing": r.odometry_timing,
        "timings_s": { "load": load_s, "resume": run_s },
    });
    super::report::write_summary_and_report(
        out,
        &summary,
        config,
        "the merged map, both sessions' paths",
    )?;
    staging.commit()?;
    say!(
        "{}: started at {:.1} s in the saved map ({} scans before posed by odometry), {} \
         saved keyframes, {} after; {:.1} s",
        recording.name,
        r.start_ns as f64 * 1e-9,
        r.scans_before_start,
        state.keyframes.len(),
        r.state.keyframes.len(),
        run_s
    );
    say!("wrote {}", args.out.display());
    if let Some(path) = &args.save_state {
        save_state(path, &r.state)?;
    }
    for reason in &r.quality.reasons {
        eprintln!("warning: suspect result: {reason}");
    }
    Ok(())
}

/// The merged map with both sessions' paths, its binary raster and the map_server pair.
fn write_maps(out: &Path, r: &ResumeResult) -> anyhow::Result<()> {
    let new: Vec<Pose2> = r.trajectory.iter().map(|p| p.pose).collect();
    let old: Vec<Pose2> = r.previous.iter().map(|p| p.pose).collect();
    let overlays = [
        TrajectoryOverlay {
            label: "this session",
            poses: &new,
        },
        TrajectoryOverlay {
            label: "saved keyframes",
            poses: &old,
        },
    ];
    write_map_png(
        &out.join("map.png"),
        &r.map,
        &overlays,
        None,
        &MapImageOptions::default(),
    )?;
    write_binary_png(&out.join("binary_map.png"), &r.map, None)?;
    write_map_server(&r.map.to_binary_map(None), &out.join("map.yaml"))?;
    Ok(())
}
