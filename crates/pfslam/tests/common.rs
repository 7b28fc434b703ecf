//! Helpers shared by the integration tests.

use std::path::PathBuf;

/// The real-data directory (`$PFSLAM_DATA` or `shared/data` beside the workspace root), or
/// `None` after printing a skip notice naming the test.
#[allow(dead_code)]
pub fn data_dir(test: &str) -> Option<PathBuf> {
    let d = pfslam_io::data_root(env!("CARGO_MANIFEST_DIR"));
    if d.is_none() {
        eprintln!("SKIP {test}: real data not found (set PFSLAM_DATA or provide ../shared/data)");
    }
    d
}

/// The car of `opts` simulated in its built-in world, and its recording with the default
/// motion options.
#[allow(dead_code)]
pub fn simulated_car(
    opts: &pfslam_sim::SimOptions,
) -> (pfslam_sim::CarSimOutput, pfslam::sensors::Recording) {
    let world = pfslam_sim::World::builtin(opts.world_name()).unwrap();
    let out = pfslam_sim::simulate_car(&world, opts).unwrap();
    let car = out
        .recording(&pfslam::motion::MotionOptions::default())
        .unwrap();
    (out, car)
}
