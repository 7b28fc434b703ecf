//! `pfslam benchmark [--data DIR]`: SLAM on every Freiburg recording found with its relations,
//! scored with the Kümmerle et al. 2009 metric, in one table beside the published results.
//!
//! A recording is `<data>/freiburg/<name>/<name>.bag` (or `<name>.clf`) with
//! `<name>.relations` beside it. All recordings run with the same configuration (the defaults,
//! or `--config`): no per-dataset tuning.

use anyhow::Context;
use pfslam::Slam;
use pfslam::config::Config;
use pfslam::eval::relations::{RelationsOptions, evaluate_relations};
use pfslam::geometry::Trajectory;
use pfslam::pipeline::{BackEndInput, PipelineOptions, PipelineResult};
use pfslam_io::relations::read_relations;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `benchmark`.
#[derive(Debug, Default, clap::Args)]
pub struct Args {
    /// The data directory holding `freiburg/` (default: `$PFSLAM_DATA`, else `shared/data`
    /// beside the workspace, else `../shared/data`).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Only these recordings (comma separated, e.g. `intel,aces`).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// TOML configuration over the defaults (one for all recordings).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seed of the filter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also write each trajectory and the table (`benchmark.md`, `benchmark.json`) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Feed the pose-graph back end (when `[graph] enabled`) the raw odometry at every scan
    /// instead of the filter's trajectory (to measure the back end alone).
    #[arg(long)]
    pub graph_on_odometry: bool,
    /// Instead of the Freiburg recordings: every CARMEN log in this directory whose laser
    /// lines carry reference poses (corrected logs), scored by ATE against them.
    #[arg(long)]
    pub corpus: Option<PathBuf>,
    /// With `--corpus`: the odometry perturbation levels to run each log at (0 = as it is).
    #[arg(long, value_delimiter = ',', default_value = "0,1,2")]
    pub levels: Vec<u8>,
    /// With `--corpus`: run every log and level with each of these seeds (of the filter and
    /// of the perturbation; default: `--seed`).
    #[arg(long, value_delimiter = ',')]
    pub seeds: Vec<u64>,
}

/// Published mean translational (m) / rotational (deg) errors on the relations (from
/// `shared/data/freiburg/README.md`): graph mapping, RBPF (GMapping, 50 particles),
/// Cartographer. `None` where no figure is published.
type Published = [(&'static str, f64, Option<f64>); 3];

fn published(name: &str) -> Option<Published> {
    Some(match name {
        "intel" => [
            ("graph", 0.031, Some(1.3)),
            ("RBPF", 0.070, None),
            ("Cartographer", 0.0229, Some(0.453)),
        ],
        "aces" => [
            ("graph", 0.044, Some(0.4)),
            ("RBPF", 0.060, None),
            ("Cartographer", 0.0375, Some(0.373)),
        ],
        "mit-csail" => [
            ("graph", 0.004, Some(0.05)),
            ("RBPF", 0.049, None),
            ("Cartographer", 0.0319, Some(0.369)),
        ],
        _ => return None,
    })
}

/// One row of the table.
#[derive(Debug, serde::Serialize)]
pub struct Row {
    /// Recording name.
    pub name: String,
    /// Scans in the recording.
    pub scans: usize,
    /// Wall time of SLAM (s), loading excluded.
    pub wall_s: f64,
    /// Recording duration / wall time.
    pub realtime_factor: f64,
    /// Mean ± std translational error (m).
    pub trans_mean_m: f64,
    /// Std of the translational error (m).
    pub trans_std_m: f64,
    /// Mean rotational error (deg).
    pub rot_mean_deg: f64,
    /// Std of the rotational error (deg).
    pub rot_std_deg: f64,
    /// Relations used / total.
    pub relations_used: usize,
    /// Relations in the file.
    pub relations_total: usize,
    /// The same metric on the raw odometry.
    pub odometry_trans_mean_m: f64,
    /// The same metric on the front end's trajectory (before the back end).
    pub front_end_trans_mean_m: f64,
    /// Back-end statistics, when it ran.
    pub graph: Option<pfslam::graph::GraphStats>,
}

fn default_data_dir() -> Option<PathBuf> {
    pfslam_io::data_root(env!("CARGO_MANIFEST_DIR")).or_else(|| {
        let p = PathBuf::from("../shared/data");
        p.is_dir().then_some(p)
    })
}

/// Finds `(name, recording, relations)` under `data/freiburg`, sorted by name.
pub fn find_recordings(data: &Path) -> anyhow::Result<Vec<(String, PathBuf, PathBuf)>> {
    let root = data.join("freiburg");
    let entries = std::fs::read_dir(&root).with_context(|| root.display().to_string())?;
    let mut found = Vec::new();
    for e in entries {
        let dir = e?.path();
        let Some(name) = dir.file_name().map(|n| n.to_string_lossy().into_owned()) else {
            continue;
        };
        let rel = dir.join(format!("{name}.relations"));
        let rec = ["bag", "clf", "mcap", "log", "log.gz"]
            .iter()
            .map(|ext| dir.join(format!("{name}.{ext}")))
            .find(|p| p.is_file());
        if let (true, Some(rec)) = (rel.is_file(), rec) {
            found.push((name, rec, rel));
        }
    }
    found.sort();
    Ok(found)
}

/// Runs the benchmark.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(p) => Config::from_toml_file(p)?,
        None => Config::default(),
    };
    config.validate()?;
    if let Some(dir) = &args.corpus {
        return run_corpus(&args, dir, &config);
    }
    let recordings = select_recordings(&args)?;
    let mut rows = Vec::new();
    for recording in &recordings {
        let row = bench_recording(&args, &config, recording)?;
        print_row(&row)?;
        rows.push(row);
    }
    let table = render_table(&rows);
    print!("{table}");
    if let Some(out) = &args.out {
        pfslam_io::write_bytes_atomic(&out.join("benchmark.md"), table.as_bytes())?;
        let json = serde_json::to_string_pretty(&rows)?;
        pfslam_io::write_bytes_atomic(&out.join("benchmark.json"), json.as_bytes())?;
    }
    Ok(())
}

/// `--corpus`: every corrected CARMEN log in `dir`, at each level and seed.
fn run_corpus(args: &Args, dir: &Path, config: &Config) -> anyhow::Result<()> {
    if let Some(out) = &args.out {
        std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
    }
    let seeds = if args.seeds.is_empty() {
        vec![args.seed]
    } else {
        args.seeds.clone()
    };
    super::corpus::run_corpus(dir, &args.levels, config, &seeds, args.out.as_deref())?;
    Ok(())
}

/// The recordings to run: those found under the data directory, narrowed by `--only`.
fn select_recordings(args: &Args) -> anyhow::Result<Vec<(String, PathBuf, PathBuf)>> {
    let data = match &args.data {
        Some(d) => d.clone(),
        None => default_data_dir().ok_or_else(|| {
            anyhow::anyhow!("no data directory: pass --data DIR or set PFSLAM_DATA")
        })?,
    };
    let mut recordings = find_recordings(&data)?;
    if !args.only.is_empty() {
        for o in &args.only {
            if !recordings.iter().any(|(n, _, _)| n == o) {
                anyhow::bail!(
                    "--only {o}: no such recording with relations under {}",
                    data.display()
                );
            }
        }
        recordings.retain(|(n, _, _)| args.only.contains(n));
    }
    if recordings.is_empty() {
        anyhow::bail!(
            "{}: no recording with relations found (expected freiburg/<name>/<name>.bag and <name>.relations)",
            data.display()
        );
    }
    Ok(recordings)
}

/// SLAM on one `(name, recording, relations)`, scored on its relations; with `--out` also
/// writes its trajectory.
fn bench_recording(
    args: &Args,
    config: &Config,
    (name, rec_path, rel_path): &(String, PathBuf, PathBuf),
) -> anyhow::Result<Row> {
    let relations = read_relations(rel_path)?;
    let recording = pfslam_io::recording::read_recording(rec_path, &Default::default())
        .with_context(|| rec_path.display().to_string())?;
    let t = Instant::now();
    let options = PipelineOptions {
        back_end_input: args.graph_on_odometry.then_some(BackEndInput::Odometry),
        // The metric needs the trajectory only.
        rebuild_map: false,
    };
    let PipelineResult {
        result,
        front_end,
        graph,
        ..
    } = Slam::with_recording(config.clone(), recording.clone(), args.seed)
        .and_then(|slam| slam.finish_observed(&options, &mut |_| {}))
        .map(|(result, _)| result)
        .with_context(|| format!("SLAM on {}", rec_path.display()))?;
    let wall_s = t.elapsed().as_secs_f64();
    let opts = RelationsOptions::default();
    let front = evaluate_relations(&Trajectory::new(front_end), &relations, &opts)?;
    let est = Trajectory::new(result.trajectory.clone());
    let r = evaluate_relations(&est, &relations, &opts)?;
    let dead_reckoning = Trajectory::new(result.dead_reckoning.clone());
    let odo = evaluate_relations(&dead_reckoning, &relations, &opts)?;
    let stamps = &recording.scans.stamps_ns;
    let duration_s = match (stamps.first(), stamps.last()) {
        (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
        _ => 0.0,
    };
    if let Some(out) = &args.out {
        pfslam_io::tum::write_tum(&out.join(format!("{name}.tum")), &result.trajectory)?;
    }
    Ok(Row {
        name: name.clone(),
        scans: recording.scans.len(),
        wall_s,
        realtime_factor: duration_s / wall_s.max(1e-9),
        trans_mean_m: r.trans_m.abs.mean,
        trans_std_m: r.trans_m.abs.std,
        rot_mean_deg: r.rot_deg.abs.mean,
        rot_std_deg: r.rot_deg.abs.std,
        relations_used: r.used,
        relations_total: r.relations,
        odometry_trans_mean_m: odo.trans_m.abs.mean,
        front_end_trans_mean_m: front.trans_m.abs.mean,
        graph,
    })
}

/// One recording's figures on standard error, as they come.
fn print_row(row: &Row) -> anyhow::Result<()> {
    let name = &row.name;
    eprintln!(
        "{name}: {:.4} m, {:.3} deg, {:.1} s ({:.0}x real time); front end {:.4} m",
        row.trans_mean_m,
        row.rot_mean_deg,
        row.wall_s,
        row.realtime_factor,
        row.front_end_trans_mean_m
    );
    if let Some(g) = &row.graph {
        eprintln!("{name}: back end {}", serde_json::to_string(g)?);
    }
    Ok(())
}

/// The markdown table: our figures, then the published ones.
pub fn render_table(rows: &[Row]) -> String {
    let mut s = Vec::new();
    let _ = writeln!(
        s,
        "| dataset | scans | wall (s) | x real time | trans. error (m) | rot. error (deg) | relations | front end (m) | raw odometry (m) | graph mapping | RBPF (50 p.) | Cartographer |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        let pubs = published(&r.name);
        let cell = |k: usize| match &pubs {
            Some(p) => match p[k].2 {
                Some(rot) => format!("{:.4} m / {rot:.3} deg", p[k].1),
                None => format!("{:.4} m", p[k].1),
            },
            None => "-".to_string(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} | {:.0} | {:.4} ± {:.4} | {:.3} ± {:.3} | {}/{} | {:.3} | {:.3} | {} | {} | {} |",
            r.name,
            r.scans,
            r.wall_s,
            r.realtime_factor,
            r.trans_mean_m,
            r.trans_std_m,
            r.rot_mean_deg,
            r.rot_std_deg,
            r.relations_used,
            r.relations_total,
            r.front_end_trans_mean_m,
            r.odometry_trans_mean_m,
            cell(0),
            cell(1),
            cell(2)
        );
    }
    String::from_utf8_lossy(&s).into_owned()
}
