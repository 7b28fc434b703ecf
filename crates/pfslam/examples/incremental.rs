//! SLAM fed one message at a time, as a robot delivers them: the odometry and scans of a
//! recording (any format `pfslam run` reads) merged by time and pushed into a
//! [`pfslam::Slam`]; each pose the filter reports is printed as a TUM line at once, and the
//! back end runs at the end. Copy it to feed your own driver's messages instead.
//!
//! `cargo run --release -p pfslam --example incremental -- RECORDING [SEED] > poses.tum`

use pfslam::{Config, ScanInput, SensorSetup, Slam};
use pfslam_io::recording::read_recording;
use std::io::Write;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        return Err("usage: incremental RECORDING [SEED]".into());
    };
    let seed: u64 = args.get(2).map_or(Ok(1), |s| s.parse())?;
    let rec = read_recording(path.as_ref(), &Default::default())?;
    let mut slam = Slam::new(Config::default(), SensorSetup::of(&rec), seed)?;
    let out = std::io::stdout();
    let mut out = out.lock();
    let odometry = &rec.odometry.poses;
    let (mut o, mut s) = (0, 0);
    while o < odometry.len() || s < rec.scans.len() {
        let scan_first = s < rec.scans.len()
            && (o == odometry.len() || rec.scans.stamps_ns[s] < odometry[o].stamp_ns);
        let pose = if scan_first {
            s += 1;
            slam.push_scan_with(ScanInput {
                stamp_ns: rec.scans.stamps_ns[s - 1],
                ranges_m: rec.scans.ranges(s - 1),
                lidar: rec.lidar_per_scan.as_ref().map(|g| g[s - 1]),
                body_from_lidar: rec.body_from_lidar_per_scan.as_ref().map(|m| m[s - 1]),
            })?
        } else {
            o += 1;
            slam.push_odometry(odometry[o - 1].stamp_ns, odometry[o - 1].pose)?
        };
        if let Some(p) = pose {
            let (sz, cz) = (0.5 * p.pose.yaw_rad).sin_cos();
            let t = p.stamp_ns as f64 * 1e-9;
            writeln!(out, "{t:.9} {} {} 0 0 0 {sz} {cz}", p.pose.x_m, p.pose.y_m)?;
            out.flush()?;
        }
    }
    let outcome = slam.finish()?;
    eprintln!(
        "{} scans, {} poses after the back end, self-check: {}",
        rec.scans.len(),
        outcome.result.trajectory.len(),
        outcome.quality.status.as_str()
    );
    Ok(())
}
