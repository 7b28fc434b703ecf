//! A grid built from a short simulated car drive at its true poses, shared by the benches
//! that match a scan against a map.

use pfslam::config::Config;
use pfslam::geometry::Pose2;
use pfslam::map::{InsertScratch, OccupancyGrid, PlanarScan, ScanProjector, to_world};
use pfslam_sim::{SimOptions, World, simulate_car};

/// An 8 s simulated drive mapped with the true poses (every `step`-th scan but the last)
/// with `config`; returns the grid, the last scan in the body frame and the true last pose.
pub fn mapped_drive(config: &Config, step: usize) -> (OccupancyGrid, PlanarScan, Pose2) {
    let opts = SimOptions {
        duration_s: 8.0,
        ..SimOptions::default()
    };
    let world = World::builtin(opts.world_name()).expect("campus");
    let out = simulate_car(&world, &opts).expect("simulation");
    let rec = pfslam::motion::car_recording(&out.dataset, &config.motion, "bench").expect("rec");
    let proj = ScanProjector::new(&rec.lidar, &rec.body_from_lidar, &config.map.scan).expect("p");
    let mut grid = OccupancyGrid::new(&config.map).expect("grid");
    let (mut body, mut world_scan) = (PlanarScan::default(), PlanarScan::default());
    let mut ins = InsertScratch::new();
    let n = rec.scans.len();
    for k in (0..n - 1).step_by(step) {
        proj.to_body(rec.scans.ranges(k), &mut body).expect("scan");
        to_world(&body, &out.ground_truth[k].pose, &mut world_scan);
        grid.insert_scan(&world_scan, &mut ins).expect("insert");
    }
    proj.to_body(rec.scans.ranges(n - 1), &mut body)
        .expect("scan");
    (grid, body, out.ground_truth[n - 1].pose)
}
