//! The incremental API ([`pfslam::Slam`]): fed a recording's odometry and scans in any
//! interleaving it gives the batch pipeline's result bit for bit; bad input is refused with
//! a message naming the problem.

use crate::filter::synthetic;
use pfslam::config::Config;
use pfslam::filter::FilterMode;
use pfslam::geometry::Pose2;
use pfslam::pipeline::{PipelineOptions, PipelineResult, run_pipeline};
use pfslam::sensors::{LidarGeometry, Recording};
use pfslam::{OnlineError, ScanInput, SensorSetup, Slam};

/// How the data reach the filter.
#[derive(Clone, Copy, Debug)]
enum Order {
    /// Odometry and scans merged by stamp, as a live robot delivers them.
    Interleaved,
    /// Every scan first (each waits for its odometry), then all the odometry.
    ScansFirst,
}

fn scan_input(rec: &Recording, i: usize) -> ScanInput<'_> {
    ScanInput {
        stamp_ns: rec.scans.stamps_ns[i],
        ranges_m: rec.scans.ranges(i),
        lidar: rec.lidar_per_scan.as_ref().map(|g| g[i]),
        body_from_lidar: rec.body_from_lidar_per_scan.as_ref().map(|m| m[i]),
    }
}

/// `rec` pushed into a [`Slam`] in `order`; also counts the pushes that returned a pose.
fn incremental(rec: &Recording, config: &Config, seed: u64, order: Order) -> PipelineResult {
    let mut slam = Slam::new(config.clone(), SensorSetup::of(rec), seed).unwrap();
    let odometry = &rec.odometry.poses;
    let n_scans = rec.scans.len();
    let mut returned = 0;
    match order {
        Order::Interleaved => {
            let (mut o, mut s) = (0, 0);
            while o < odometry.len() || s < n_scans {
                let scan_next = s < n_scans
                    && (o == odometry.len() || rec.scans.stamps_ns[s] < odometry[o].stamp_ns);
                let pose = if scan_next {
                    s += 1;
                    slam.push_scan_with(scan_input(rec, s - 1)).unwrap()
                } else {
                    o += 1;
                    let p = odometry[o - 1];
                    slam.push_odometry(p.stamp_ns, p.pose).unwrap()
                };
                returned += usize::from(pose.is_some());
            }
        }
        Order::ScansFirst => {
            for i in 0..n_scans {
                assert!(slam.push_scan_with(scan_input(rec, i)).unwrap().is_none());
            }
            assert!(slam.pose().is_none());
            for p in odometry {
                returned += usize::from(slam.push_odometry(p.stamp_ns, p.pose).unwrap().is_some());
            }
        }
    }
    assert!(returned > 0, "no push reported a pose");
    assert!(slam.map().unwrap().is_some_and(|m| m.tile_count() > 0));
    slam.finish().unwrap()
}

fn batch(rec: &Recording, config: &Config, seed: u64) -> PipelineResult {
    run_pipeline(rec, config, seed, &PipelineOptions::default(), &mut |_| {}).unwrap()
}

fn assert_same(a: &PipelineResult, b: &PipelineResult) {
    assert_eq!(a.front_end, b.front_end, "the filters differ");
    assert_eq!(
        a.result.trajectory, b.result.trajectory,
        "the final trajectories differ"
    );
    assert_eq!(a.result.dead_reckoning, b.result.dead_reckoning);
    assert_eq!(a.result.stats.scans_skipped, b.result.stats.scans_skipped);
    assert_eq!(a.result.stats.scans_total, b.result.stats.scans_total);
    assert_eq!(a.result.stats.updates, b.result.stats.updates);
    assert_eq!(a.result.map.tile_count(), b.result.map.tile_count());
    assert_eq!(
        a.graph
            .as_ref()
            .map(|g| (g.nodes, g.loop_accepted, g.final_cost.to_bits())),
        b.graph
            .as_ref()
            .map(|g| (g.nodes, g.loop_accepted, g.final_cost.to_bits()))
    );
}

#[test]
fn incremental_runs_equal_the_batch_run_in_every_mode() {
    let rec = synthetic::recording(20.0, 5);
    for mode in [FilterMode::Rbpf, FilterMode::ScanMatch] {
        let mut config = Config::default();
        config.filter.mode = mode;
        config.filter.particles = 10;
        config.filter.rbpf.resolution_m = 0.1;
        let reference = batch(&rec, &config, 3);
        assert!(reference.result.trajectory.len() > 100);
        for order in [Order::Interleaved, Order::ScansFirst] {
            eprintln!("{mode:?}, {order:?}");
            assert_same(&incremental(&rec, &config, 3, order), &reference);
        }
        let whole = Slam::with_recording(config.clone(), rec.clone(), 3).unwrap();
        assert_same(&whole.finish().unwrap(), &reference);
    }
}

#[test]
fn a_whole_recording_with_per_scan_beams_and_mounts_gives_the_batch_run() {
    let mut rec = synthetic::recording(10.0, 2);
    let n = rec.scans.len();
    let mut narrow = rec.lidar;
    narrow.range_max_m *= 0.5;
    rec.lidar_per_scan = Some(
        (0..n)
            .map(|i| if i % 3 == 0 { narrow } else { rec.lidar })
            .collect(),
    );
    let mut config = Config::default();
    config.filter.particles = 8;
    let reference = batch(&rec, &config, 2);
    let whole = Slam::with_recording(config.clone(), rec.clone(), 2).unwrap();
    assert_same(&whole.finish().unwrap(), &reference);
    rec.body_from_lidar_per_scan = Some(vec![rec.body_from_lidar; n - 1]);
    let err = Slam::with_recording(config, rec, 2)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("per-scan LiDAR mounts"), "{err}");
}

/// A real log with the default configuration: the whole pipeline, back end included.
#[test]
fn incremental_run_of_mit_csail_equals_the_batch_run() {
    let Some(data) = crate::common::data_dir("incremental_run_of_mit_csail_equals_the_batch_run")
    else {
        return;
    };
    let path = data.join("freiburg/mit-csail/mit-csail.clf");
    let rec = pfslam_io::recording::read_recording(&path, &Default::default()).unwrap();
    let config = Config::default();
    let reference = batch(&rec, &config, 1);
    assert!(reference.graph.is_some());
    assert_same(
        &incremental(&rec, &config, 1, Order::Interleaved),
        &reference,
    );
}

#[test]
fn bad_input_is_refused_with_its_reason() {
    let rec = synthetic::recording(2.0, 1);
    let mut slam = Slam::new(Config::default(), SensorSetup::of(&rec), 1).unwrap();
    slam.push_odometry(1_000, Pose2::IDENTITY).unwrap();
    let late = slam.push_odometry(500, Pose2::IDENTITY).unwrap_err();
    assert!(
        matches!(
            late,
            OnlineError::OutOfOrder {
                what: "odometry",
                ..
            }
        ),
        "{late}"
    );
    let short = slam.push_scan(2_000, &[1.0; 3]).unwrap_err();
    assert!(short.to_string().contains("3 ranges for"), "{short}");
    let mount = slam
        .push_scan_with(ScanInput {
            body_from_lidar: Some(rec.body_from_lidar),
            ..scan_input(&rec, 0)
        })
        .unwrap_err();
    assert!(mount.to_string().contains("lidar_moves"), "{mount}");
    let mut inverted = rec.lidar;
    inverted.range_max_m = -1.0;
    let beams = slam
        .push_scan_with(ScanInput {
            lidar: Some(inverted),
            ..scan_input(&rec, 0)
        })
        .unwrap_err();
    assert!(
        beams.to_string().contains("0 <= range_min < range_max"),
        "{beams}"
    );
    let nan = slam.push_odometry(3_000, Pose2::new(f64::NAN, 0.0, 0.0));
    assert!(nan.unwrap_err().to_string().contains("must be finite"));
    // Scans that never meet the odometry: no filter ran.
    let ended = slam.finish().unwrap_err();
    assert!(ended.to_string().contains("no scan lies within"), "{ended}");
    let mut config = Config::default();
    config.filter.particles = 0;
    assert!(Slam::new(config, SensorSetup::of(&rec), 1).is_err());
    let no_beams = SensorSetup::planar(
        "x",
        LidarGeometry {
            beam_count: 0,
            ..rec.lidar
        },
    );
    let setup = Slam::new(Config::default(), no_beams, 1).err().unwrap();
    assert!(setup.to_string().contains("no ranges"), "{setup}");
}

/// A humanoid: odometry, IMU yaw and scans with the head's mount, merged by stamp.
#[test]
fn a_humanoid_fed_its_imu_yaw_and_head_mounts_gives_the_batch_run() {
    use pfslam::filter::prediction::PredictionModel;
    use pfslam::motion::odometry_model::OdometryModelOptions;
    use pfslam_sim::{SimOptions, Vehicle, World, simulate_humanoid};
    let opts = SimOptions {
        vehicle: Vehicle::Humanoid,
        duration_s: 30.0,
        ..SimOptions::default()
    };
    let sim = simulate_humanoid(&World::builtin("office").unwrap(), &opts).unwrap();
    let rec = sim.recording();
    let imu = rec.imu_yaw.clone().expect("the humanoid has an IMU");
    assert!(rec.body_from_lidar_per_scan.is_some());
    let mut config = Config::default();
    // the seed's filter, whose prediction takes the turn from the IMU
    config.filter.mode = FilterMode::Seed;
    config.filter.motion_model = PredictionModel::Odometry;
    config.filter.odometry_model = OdometryModelOptions::ese650();
    config.filter.particles = 20;
    let reference = batch(&rec, &config, 1);
    let without_imu = Recording {
        imu_yaw: None,
        ..rec.clone()
    };
    assert_ne!(
        batch(&without_imu, &config, 1).front_end,
        reference.front_end,
        "the IMU makes no difference: the test would prove nothing"
    );
    // (stamp, kind, index): odometry 0, IMU 1, scan 2
    let mut messages: Vec<(i64, u8, usize)> = Vec::new();
    messages.extend(
        rec.odometry
            .poses
            .iter()
            .enumerate()
            .map(|(i, p)| (p.stamp_ns, 0, i)),
    );
    messages.extend(imu.iter().enumerate().map(|(i, s)| (s.0, 1, i)));
    messages.extend((0..rec.scans.len()).map(|i| (rec.scans.stamps_ns[i], 2, i)));
    messages.sort();
    let mut slam = Slam::new(config, SensorSetup::of(&rec), 1).unwrap();
    for (_, kind, i) in messages {
        match kind {
            0 => slam.push_odometry(rec.odometry.poses[i].stamp_ns, rec.odometry.poses[i].pose),
            1 => slam.push_imu_yaw(imu[i].0, imu[i].1),
            _ => slam.push_scan_with(scan_input(&rec, i)),
        }
        .unwrap();
    }
    assert_same(&slam.finish().unwrap(), &reference);
    let late = Slam::new(Config::default(), SensorSetup::of(&rec), 1)
        .and_then(|mut s| {
            s.push_imu_yaw(10, 0.0)?;
            s.push_imu_yaw(5, 0.0)
        })
        .unwrap_err();
    assert!(
        late.to_string().contains("IMU yaw at 5 ns comes before"),
        "{late}"
    );
}
