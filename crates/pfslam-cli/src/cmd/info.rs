//! `pfslam info PATH`: what a recording holds and what `run` would use, like `rosbag info`
//! for every supported format.

use pfslam::sensors::Recording;
use pfslam_io::account::InputAccount;
use pfslam_io::recording::{RecordingFormat, detect_format, resolve_rosbag2};
use pfslam_io::ros_assemble::TopicInfo;
use std::path::{Path, PathBuf};

/// Arguments of `info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A recording: CARMEN log, ROS 1 bag, MCAP file, rosbag2 directory, car or humanoid
    /// dataset directory.
    pub path: PathBuf,
    /// TOML configuration (its `[input]` section applies).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Input selection and strictness.
    #[command(flatten)]
    pub input: super::input::InputArgs,
    /// Print the account as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Prints the description.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.input.config(args.config.as_deref())?;
    config.validate()?;
    let topics = topics_of(&args.path)?;
    let ds = super::dataset::load_dataset(&args.path, &config, true)?;
    let mode = config.filter.mode.resolve(&ds.recording);
    if args.json {
        let v = serde_json::json!({
            "account": ds.account,
            "topics": topics.as_ref().map(|t| &t.0),
            "duration_s": duration_s(&ds.recording),
            "filter_mode": mode,
        });
        return super::print_stdout(&serde_json::to_string_pretty(&v)?);
    }
    let text = describe(
        &ds.account,
        &ds.recording,
        topics.as_ref(),
        &format!("{mode:?}"),
    );
    super::print_stdout(&text)
}

/// The topics of a bag or MCAP file with the time they span (s).
fn topics_of(path: &Path) -> anyhow::Result<Option<(Vec<TopicInfo>, f64)>> {
    let file = resolve_rosbag2(path)?;
    let path = file.as_deref().unwrap_or(path);
    if path.is_dir() {
        return Ok(None);
    }
    let span_s = |s: Option<(i64, i64)>| s.map_or(0.0, |(a, b)| (b - a) as f64 * 1e-9);
    Ok(match detect_format(path)? {
        Some(RecordingFormat::Ros1Bag) => {
            let t = pfslam_io::ros1::ros1_topics(path)?;
            Some((t.topics, span_s(t.span_ns)))
        }
        Some(RecordingFormat::Mcap) => {
            let t = pfslam_io::mcap::mcap_topics(path)?;
            Some((t.topics, span_s(t.span_ns)))
        }
        _ => None,
    })
}

fn duration_s(rec: &Recording) -> f64 {
    match (rec.scans.stamps_ns.first(), rec.scans.stamps_ns.last()) {
        (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
        _ => 0.0,
    }
}

/// The text `info` prints.
fn describe(
    a: &InputAccount,
    rec: &Recording,
    topics: Option<&(Vec<TopicInfo>, f64)>,
    mode: &str,
) -> String {
    let mut s = String::new();
    let dur = duration_s(rec);
    s += &format!("path:       {}\n", a.path);
    s += &format!(
        "format:     {} ({} {})\n",
        a.format, a.records_read, a.records_unit
    );
    s += &format!("duration:   {dur:.1} s (first to last scan)\n");
    if let Some((list, span)) = topics {
        s += "topics:\n";
        for t in list {
            let rate = if *span > 0.0 {
                t.count as f64 / span
            } else {
                0.0
            };
            s += &format!(
                "  {:<28} {:>8} msgs {:>8.2} Hz  {}\n",
                t.topic, t.count, rate, t.type_name
            );
        }
    }
    if !a.ignored.is_empty() {
        s += "not used:\n";
        for t in &a.ignored {
            s += &format!("  {:>8} {} {}\n", t.count, t.reason, t.what);
        }
    }
    let rate = if dur > 0.0 {
        a.scans_kept as f64 / dur
    } else {
        0.0
    };
    s += &format!(
        "scans:      {} of {} kept ({rate:.2} Hz)\n",
        a.scans_kept, a.scans_read
    );
    s += "layouts:\n";
    for l in &a.beam_layouts {
        s += &format!(
            "  {:>5} beams from {:8.3} deg step {:.4} deg, no return at {} m: {} scans\n",
            l.beams, l.angle_min_deg, l.angle_increment_deg, l.range_max_m, l.scans
        );
    }
    s += &format!(
        "odometry:   {} of {} poses from {} ({:.1} m of travel)\n",
        a.odometry_kept,
        a.odometry_read,
        a.odometry_source,
        rec.odometry.path_length_m()
    );
    s += &format!("clock:      {}\n", a.clock);
    s += &format!("mount:      {}\n", a.mount_source);
    for (label, list) in [("dropped", &a.dropped), ("repaired", &a.repaired)] {
        for t in list.iter() {
            let at = t
                .first_at
                .as_deref()
                .map(|x| format!(" (first at {x})"))
                .unwrap_or_default();
            s += &format!("{label}:    {} {} {}{at}\n", t.count, t.what, t.reason);
        }
    }
    for w in a.all_warnings() {
        s += &format!("warning:    {w}\n");
    }
    s += &format!(
        "run would use: {} scans, {} odometry poses, filter mode {mode}, ground truth {}\n",
        a.scans_kept,
        a.odometry_kept,
        if rec.ground_truth.is_some() {
            "yes"
        } else {
            "no"
        }
    );
    s
}
