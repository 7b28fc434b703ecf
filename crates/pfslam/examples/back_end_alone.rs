//! The back end alone on a car-layout dataset and a saved run (to profile and compare it):
//! `cargo run --release -p pfslam --example back_end_alone -- DATASET RUN_DIR [OUT.tum]`
//! with `RUN_DIR` holding a `pfslam run`'s `front_end.tum` and `dead_reckoning.tum`. The
//! back end is fed the odometry calibrated against the front end, as `pfslam run` does for
//! the car (from the TUM files' rounded poses, so not `run`'s exact bits). Prints the stats,
//! the wall and process CPU seconds, and a hash of the trajectory's bits. `DATASET` may also
//! be a recording file (`intel.bag`): its back end is fed `RUN_DIR/front_end.tum` itself
//! (`[graph] input = "auto"`), again from the TUM file's rounded poses. `PFSLAM_CONFIG=FILE`
//! reads the configuration from a TOML file instead of the defaults.

use pfslam::config::Config;
use pfslam::graph::{BackEndInput, optimize_trajectory};
use pfslam::motion::calibration::fit_odometry_calibration;
use pfslam::pipeline::process_cpu_s;
use pfslam_io::tum::{read_tum, write_tum};
use pfslam_io::ucsd::{ReadOptions, read_car_dataset};
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: back_end_alone DATASET RUN_DIR [OUT.tum]".into());
    }
    let (data, run) = (PathBuf::from(&args[1]), PathBuf::from(&args[2]));
    // `PFSLAM_CONFIG=FILE.toml`: another configuration (e.g. `[graph]` options to compare).
    let config = match std::env::var_os("PFSLAM_CONFIG") {
        Some(path) => Config::from_toml_file(std::path::Path::new(&path))?,
        None => Config::default(),
    };
    // A file is a recording (CARMEN log, ROS 1 bag, MCAP: Freiburg), a directory the car.
    let recording = if data.is_file() {
        pfslam_io::recording::read_recording(&data, &Default::default())?
    } else {
        let mut ds = read_car_dataset(&data, &ReadOptions::default())?;
        pfslam::motion::car_recording_taking_scans(&mut ds, &config.motion, "d")?
    };
    let front = read_tum(&run.join("front_end.tum"))?.poses;
    let odo = read_tum(&run.join("dead_reckoning.tum"))?.poses;
    let mut opts = config.graph.clone();
    let which = opts.input.resolve(&recording);
    let input = if which == BackEndInput::CalibratedOdometry {
        let fit = fit_odometry_calibration(&odo, &front, &opts.calibration)?;
        opts = opts.for_odometry_input();
        fit.calibration.apply(&odo)
    } else {
        front
    };
    let (t, cpu) = (Instant::now(), process_cpu_s());
    let g = optimize_trajectory(&recording, &config.map.scan, &input, &opts)?;
    let wall = t.elapsed().as_secs_f64();
    let cpu = process_cpu_s().zip(cpu).map(|(b, a)| b - a);
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for p in &g.trajectory {
        (p.stamp_ns, p.pose.x_m.to_bits()).hash(&mut h);
        (p.pose.y_m.to_bits(), p.pose.yaw_rad.to_bits()).hash(&mut h);
    }
    for p in &g.keyframes {
        (p.pose.x_m.to_bits(), p.pose.y_m.to_bits()).hash(&mut h);
    }
    g.loop_edges.hash(&mut h);
    g.stats.final_cost.to_bits().hash(&mut h);
    println!("{:?}", g.stats);
    println!(
        "back end: {wall:.2} s wall, {:.2} s CPU, bits {:016x}",
        cpu.unwrap_or(f64::NAN),
        h.finish()
    );
    if let Some(out) = args.get(3) {
        write_tum(&PathBuf::from(out), &g.trajectory)?;
    }
    Ok(())
}
