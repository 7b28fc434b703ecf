//! A long run consolidated every `[session] consolidate_every_scans` scans: it holds at
//! most a window of scans, keeps the keyframes of the area it mapped (not of every pass),
//! stays as accurate as one run, and gives the same result fed live or whole.

use crate::filter::{ate_rmse, synthetic};
use pfslam::config::Config;
use pfslam::pipeline::PipelineResult;
use pfslam::sensors::Recording;
use pfslam::{ScanInput, SensorSetup, Slam};

/// One lap of the synthetic loop takes about 25 s (250 scans).
const WINDOW_SCANS: usize = 120;

fn config(every: usize) -> Config {
    let mut config = Config::default();
    config.filter.particles = 10;
    config.session.consolidate_every_scans = every;
    config
}

/// The same without consolidation: the whole run is one window.
fn config_never() -> Config {
    config(0)
}

/// What a run fed message by message gave.
struct Live {
    result: PipelineResult,
    /// The recording the run kept at its end.
    kept: Recording,
    /// The most scans it held at any time.
    held: usize,
    /// The pushes that returned a pose.
    poses: usize,
}

/// `rec` pushed message by message (merged by stamp).
fn live(rec: &Recording, config: &Config) -> Live {
    let mut slam = Slam::new(config.clone(), SensorSetup::of(rec), 1).unwrap();
    let odometry = &rec.odometry.poses;
    let (mut o, mut s, mut held, mut poses) = (0, 0, 0, 0);
    while o < odometry.len() || s < rec.scans.len() {
        if s < rec.scans.len()
            && (o == odometry.len() || rec.scans.stamps_ns[s] < odometry[o].stamp_ns)
        {
            let scan = ScanInput {
                stamp_ns: rec.scans.stamps_ns[s],
                ranges_m: rec.scans.ranges(s),
                lidar: rec.lidar_per_scan.as_ref().map(|g| g[s]),
                body_from_lidar: None,
            };
            poses += usize::from(slam.push_scan_with(scan).unwrap().is_some());
            s += 1;
        } else {
            let p = odometry[o];
            poses += usize::from(slam.push_odometry(p.stamp_ns, p.pose).unwrap().is_some());
            o += 1;
        }
        held = held.max(slam.recording().scans.len());
    }
    let (result, kept) = slam
        .finish_observed(&Default::default(), &mut |_| {})
        .unwrap();
    Live {
        result,
        kept,
        held,
        poses,
    }
}

#[test]
fn a_long_run_holds_a_window_of_scans_and_the_keyframes_of_its_area() {
    let config = config(WINDOW_SCANS);
    let two = live(&synthetic::recording(50.0, 4), &config);
    let rec = synthetic::recording(150.0, 4);
    let Live {
        result: six,
        kept: kept_six,
        held,
        ..
    } = live(&rec, &config);
    assert_eq!(six.result.trajectory.len(), rec.scans.len());
    assert_eq!(six.front_end.len(), rec.scans.len());
    assert_eq!(six.result.stats.scans_total, rec.scans.len());
    // A scan waits for the odometry after it: one more than the window at most.
    assert!(held <= WINDOW_SCANS + 1, "held {held} scans");
    let (k2, k6) = (two.kept.scans.len(), kept_six.scans.len());
    eprintln!("kept keyframes: {k2} after two laps, {k6} after six");
    assert!(k2 > 0 && k6 as f64 <= 1.3 * k2 as f64, "{k2} -> {k6}");
    let gt = rec.ground_truth.as_deref().unwrap();
    let (rolled, dead_reckoning) = (
        ate_rmse(&six.result.trajectory, gt),
        ate_rmse(&six.result.dead_reckoning, gt),
    );
    let whole = Slam::with_recording(config_never(), rec.clone(), 1)
        .unwrap()
        .finish()
        .unwrap();
    let once = ate_rmse(&whole.result.trajectory, gt);
    eprintln!(
        "ATE: consolidated {rolled:.4} m, one window {once:.4} m, odometry {dead_reckoning:.3} m"
    );
    assert!(
        rolled <= 0.05 && rolled <= 2.0 * once.max(0.01),
        "{rolled} against {once}"
    );
    assert!(two.result.result.trajectory.len() < six.result.trajectory.len());
}

/// With two lasers' beams in turn, so that the consolidated windows carry per-scan beams.
#[test]
fn a_consolidated_run_fed_live_gives_the_run_of_the_whole_recording() {
    let mut rec = synthetic::recording(60.0, 6);
    let mut narrow = rec.lidar;
    narrow.range_max_m *= 0.5;
    let n = rec.scans.len();
    rec.lidar_per_scan = Some(
        (0..n)
            .map(|i| if i % 3 == 0 { narrow } else { rec.lidar })
            .collect(),
    );
    let config = config(WINDOW_SCANS);
    let fed = live(&rec, &config);
    // Every push that handled a scan reports its pose, consolidating or not.
    assert_eq!(fed.poses, live(&rec, &config_never()).poses);
    let fed = fed.result;
    let (whole, kept) = Slam::with_recording(config, rec.clone(), 1)
        .unwrap()
        .finish_observed(&Default::default(), &mut |_| {})
        .unwrap();
    assert!(kept.scans.len() < rec.scans.len() / 2, "not consolidated");
    assert_eq!(fed.front_end, whole.front_end);
    assert_eq!(fed.result.trajectory, whole.result.trajectory);
    assert_eq!(fed.result.dead_reckoning, whole.result.dead_reckoning);
    assert_eq!(fed.result.map.tile_count(), whole.result.map.tile_count());
}

#[test]
fn a_window_too_short_to_match_along_is_refused() {
    let rec = synthetic::recording(5.0, 1);
    let err = Slam::new(config(50), SensorSetup::of(&rec), 1)
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("[session]") && err.contains("consolidate_every_scans"),
        "{err}"
    );
    let err = config(50).validate().unwrap_err().to_string();
    assert!(err.contains("consolidate_every_scans"), "{err}");
}
