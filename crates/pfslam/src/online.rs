//! The incremental API: odometry and scans pushed as they arrive, the pose after each scan,
//! the back end and the final map at the end.
//!
//! ```
//! use pfslam::geometry::Pose2;
//! use pfslam::sensors::LidarGeometry;
//! use pfslam::{Config, SensorSetup, Slam};
//!
//! # fn main() -> Result<(), pfslam::OnlineError> {
//! let lidar = LidarGeometry {
//!     angle_min_rad: -std::f64::consts::FRAC_PI_2,
//!     angle_increment_rad: std::f64::consts::PI / 180.0,
//!     beam_count: 181,
//!     range_min_m: 0.1,
//!     range_max_m: 30.0,
//! };
//! let mut slam = Slam::new(Config::default(), SensorSetup::planar("robot", lidar), 1)?;
//! slam.push_odometry(0, Pose2::new(0.0, 0.0, 0.0))?;
//! slam.push_odometry(100_000_000, Pose2::new(0.05, 0.0, 0.0))?;
//! if let Some(pose) = slam.push_scan(50_000_000, &[5.0_f32; 181])? {
//!     println!("{:.3} {:.3}", pose.pose.x_m, pose.pose.y_m);
//! }
//! let outcome = slam.finish()?;
//! println!("{} poses", outcome.result.trajectory.len());
//! # Ok(())
//! # }
//! ```
//!
//! A scan is handled once the odometry reaches its stamp (its pose is interpolated there),
//! so scans wait for the odometry that follows them. Fed a recording's odometry and scans in
//! any interleaving, the result is the batch run's ([`crate::pipeline::run_pipeline`]) bit
//! for bit: both hand each scan to the same front end through the same step.
//!
//! A run of the `rbpf` filter longer than `[session] consolidate_every_scans` scans is
//! consolidated window by window (`session::rolling`): it then holds the scans of one window
//! and the keyframes of the area mapped, whatever its length. `run_pipeline` keeps every scan;
//! [`Slam::with_recording`] consolidates as pushes do.

use crate::config::Config;
use crate::filter::odometry::OdometryCursor;
use crate::geometry::{Pose2, Rigid3, StampedPose2};
use crate::map::{MapError, OccupancyGrid};
use crate::pipeline::{PipelineError, PipelineOptions, PipelineResult, after_filter};
use crate::sensors::{LidarGeometry, Recording, ScanSet};
use crate::session::Rolling;
use crate::slam::{AnyFrontEnd, FrontEnd, SlamError, SlamEvent, feed_scan};
use std::time::Instant;

/// The sensors a [`Slam`] is fed, known before the first scan.
#[derive(Debug, Clone)]
pub struct SensorSetup {
    /// A short name for reports.
    pub name: String,
    /// The LiDAR's beams (each scan may bring its own, see [`ScanInput`]).
    pub lidar: LidarGeometry,
    /// The LiDAR's mount on the body.
    pub body_from_lidar: Rigid3,
    /// The LiDAR moves on the body (a head that turns): every scan brings its mount.
    pub lidar_moves: bool,
}

impl SensorSetup {
    /// A level LiDAR at the body's origin.
    pub fn planar(name: &str, lidar: LidarGeometry) -> Self {
        SensorSetup {
            name: name.to_string(),
            lidar,
            body_from_lidar: Rigid3::IDENTITY,
            lidar_moves: false,
        }
    }

    /// The sensors of `recording`.
    pub fn of(recording: &Recording) -> Self {
        SensorSetup {
            name: recording.name.clone(),
            lidar: recording.lidar,
            body_from_lidar: recording.body_from_lidar,
            lidar_moves: recording.body_from_lidar_per_scan.is_some(),
        }
    }
}

/// One scan for [`Slam::push_scan_with`].
#[derive(Debug, Clone, Copy)]
pub struct ScanInput<'a> {
    /// Its time (ns).
    pub stamp_ns: i64,
    /// One range per beam (m; 0, NaN or beyond the range limits: no return).
    pub ranges_m: &'a [f32],
    /// Its beams, when they differ from the setup's.
    pub lidar: Option<LidarGeometry>,
    /// Its mount, for a LiDAR that moves on the body (required then).
    pub body_from_lidar: Option<Rigid3>,
}

/// Errors of the incremental API.
#[derive(Debug, thiserror::Error)]
pub enum OnlineError {
    /// Odometry or scans must come in time order, each stream on its own.
    #[error("{what} at {stamp_ns} ns comes before the previous one at {last_ns} ns")]
    OutOfOrder {
        /// "odometry" or "scan".
        what: &'static str,
        /// Its stamp.
        stamp_ns: i64,
        /// The previous one's.
        last_ns: i64,
    },
    /// An odometry pose that cannot be used.
    #[error("odometry at {stamp_ns} ns: {message}")]
    Odometry {
        /// Its stamp.
        stamp_ns: i64,
        /// What is wrong.
        message: String,
    },
    /// An IMU sample that cannot be used.
    #[error("IMU yaw at {stamp_ns} ns: {message}")]
    Imu {
        /// Its stamp.
        stamp_ns: i64,
        /// What is wrong.
        message: String,
    },
    /// Bad `[session]` options.
    #[error("configuration [session]: {0}")]
    Session(String),
    /// A sensor setup that cannot be used.
    #[error("sensor setup: {0}")]
    Setup(String),
    /// A scan that cannot be used as given.
    #[error("scan at {stamp_ns} ns: {message}")]
    Scan {
        /// Its stamp.
        stamp_ns: i64,
        /// What is wrong.
        message: String,
    },
    /// The filter failed.
    #[error(transparent)]
    Slam(#[from] SlamError),
    /// The back end failed.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
}

/// Why an odometry `pose` at `stamp_ns`, after one at `last_ns`, cannot be pushed.
pub fn check_odometry(
    stamp_ns: i64,
    pose: &Pose2,
    last_ns: Option<i64>,
) -> Result<(), OnlineError> {
    let (x, y, yaw) = (pose.x_m, pose.y_m, pose.yaw_rad);
    if !(x.is_finite() && y.is_finite() && yaw.is_finite()) {
        let message = format!("x, y and yaw must be finite, not {x}, {y}, {yaw}");
        return Err(OnlineError::Odometry { stamp_ns, message });
    }
    check_order("odometry", stamp_ns, last_ns)
}

/// Why an IMU `yaw_rad` at `stamp_ns`, after one at `last_ns`, cannot be pushed.
pub fn check_imu_yaw(stamp_ns: i64, yaw_rad: f64, last_ns: Option<i64>) -> Result<(), OnlineError> {
    if !yaw_rad.is_finite() {
        let message = format!("yaw must be finite, not {yaw_rad}");
        return Err(OnlineError::Imu { stamp_ns, message });
    }
    check_order("IMU yaw", stamp_ns, last_ns)
}

fn check_order(what: &'static str, stamp_ns: i64, last_ns: Option<i64>) -> Result<(), OnlineError> {
    match last_ns {
        Some(last_ns) if stamp_ns <= last_ns => Err(OnlineError::OutOfOrder {
            what,
            stamp_ns,
            last_ns,
        }),
        _ => Ok(()),
    }
}

/// The filter fed as the data arrives (see the module docs).
pub struct Slam {
    config: Config,
    seed: u64,
    recording: Recording,
    running: Option<Running>,
    /// The next scan to hand to the front end.
    next_scan: usize,
    /// Wall seconds spent in the filter.
    filter_s: f64,
    /// The consolidated part of a long run (`[session] consolidate_every_scans`).
    rolling: Option<Rolling>,
}

/// The front end once the first scan within the odometry's span arrived.
struct Running {
    front: AnyFrontEnd,
    cursor: OdometryCursor,
    steps: Vec<(StampedPose2, StampedPose2)>,
    t_start: Instant,
}

impl Slam {
    /// A filter with `config` (checked here, before any data) for the sensors `setup`,
    /// drawing its random numbers from `seed`.
    pub fn new(config: Config, setup: SensorSetup, seed: u64) -> Result<Self, OnlineError> {
        if let Some(problem) = setup.lidar.problem() {
            return Err(OnlineError::Setup(problem));
        }
        config.filter.validate().map_err(SlamError::from)?;
        config.input.validate().map_err(SlamError::InputOptions)?;
        config.session.validate().map_err(OnlineError::Session)?;
        config
            .map
            .validate()
            .map_err(|e| SlamError::from(MapError::Options(e)))?;
        let recording = Recording {
            name: setup.name,
            scans: ScanSet::new(setup.lidar.beam_count),
            lidar: setup.lidar,
            body_from_lidar: setup.body_from_lidar,
            body_from_lidar_per_scan: setup.lidar_moves.then(Vec::new),
            ..Recording::default()
        };
        Ok(Slam {
            config,
            seed,
            recording,
            running: None,
            next_scan: 0,
            filter_s: 0.0,
            rolling: None,
        })
    }

    /// A filter over a whole `recording` already read, as `pfslam run` does with a file: its
    /// scans are handled by [`Self::finish_observed`] (or by the next push). A recording
    /// without odometry gets the odometry of its scans alone (LiDAR-only), as in
    /// [`crate::pipeline::run_pipeline`].
    pub fn with_recording(
        config: Config,
        mut recording: Recording,
        seed: u64,
    ) -> Result<Self, OnlineError> {
        let n = recording.scans.len();
        let lengths = [
            recording.body_from_lidar_per_scan.as_ref().map(Vec::len),
            recording.lidar_per_scan.as_ref().map(Vec::len),
        ];
        if lengths.iter().flatten().any(|&len| len != n) {
            return Err(SlamError::Input {
                name: recording.name.clone(),
                message: "per-scan LiDAR mounts or beams do not match the scans".into(),
            }
            .into());
        }
        crate::pipeline::ensure_odometry(&mut recording).map_err(SlamError::from)?;
        config.input.validate().map_err(SlamError::InputOptions)?;
        crate::pipeline::shift_odometry(
            &mut recording,
            config.input.odometry_shift_s.unwrap_or(0.0),
        );
        let mut slam = Slam::new(config, SensorSetup::of(&recording), seed)?;
        slam.recording = recording;
        Ok(slam)
    }

    /// The odometry's pose at `stamp_ns` (in its own frame); returns the pose of the latest
    /// scan when scans waiting for this odometry were handled.
    pub fn push_odometry(
        &mut self,
        stamp_ns: i64,
        pose: Pose2,
    ) -> Result<Option<StampedPose2>, OnlineError> {
        self.push_odometry_observed(stamp_ns, pose, &mut |_| {})
    }

    /// [`Self::push_odometry`], reporting the filter's events (a [`SlamEvent::Pose`] per scan
    /// handled, updates, snapshots) to `observer`.
    pub fn push_odometry_observed(
        &mut self,
        stamp_ns: i64,
        pose: Pose2,
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<Option<StampedPose2>, OnlineError> {
        let shift_s = self.config.input.odometry_shift_s.unwrap_or(0.0);
        let stamp_ns = stamp_ns + crate::motion::odometry_timing::shift_ns(shift_s);
        let poses = &mut self.recording.odometry.poses;
        check_odometry(stamp_ns, &pose, poses.last().map(|p| p.stamp_ns))?;
        poses.push(StampedPose2 { stamp_ns, pose });
        self.handle_ready(observer)
    }

    /// The IMU's absolute yaw (rad) at `stamp_ns`, for the motion models that take the turn
    /// from it (`[filter.odometry_model] model = "ese650"`). Once any is pushed, a scan also
    /// waits for the IMU to reach its stamp; push it from the start of the run.
    pub fn push_imu_yaw(
        &mut self,
        stamp_ns: i64,
        yaw_rad: f64,
    ) -> Result<Option<StampedPose2>, OnlineError> {
        self.push_imu_yaw_observed(stamp_ns, yaw_rad, &mut |_| {})
    }

    /// [`Self::push_imu_yaw`], reporting the filter's events to `observer`.
    pub fn push_imu_yaw_observed(
        &mut self,
        stamp_ns: i64,
        yaw_rad: f64,
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<Option<StampedPose2>, OnlineError> {
        let series = self.recording.imu_yaw.get_or_insert_with(Vec::new);
        check_imu_yaw(stamp_ns, yaw_rad, series.last().map(|s| s.0))?;
        series.push((stamp_ns, yaw_rad));
        self.handle_ready(observer)
    }

    /// A scan with the setup's beams and mount; returns the pose of the latest scan when
    /// the odometry already reaches it (else it waits for the odometry).
    pub fn push_scan(
        &mut self,
        stamp_ns: i64,
        ranges_m: &[f32],
    ) -> Result<Option<StampedPose2>, OnlineError> {
        self.push_scan_with(ScanInput {
            stamp_ns,
            ranges_m,
            lidar: None,
            body_from_lidar: None,
        })
    }

    /// [`Self::push_scan`] of a scan with its own beams or mount.
    pub fn push_scan_with(
        &mut self,
        scan: ScanInput<'_>,
    ) -> Result<Option<StampedPose2>, OnlineError> {
        self.push_scan_observed(scan, &mut |_| {})
    }

    /// [`Self::push_scan_with`], reporting the filter's events to `observer`.
    pub fn push_scan_observed(
        &mut self,
        scan: ScanInput<'_>,
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<Option<StampedPose2>, OnlineError> {
        self.append_scan(&scan)?;
        self.handle_ready(observer)
    }

    /// The pose of the latest scan handled (`None` before the first).
    pub fn pose(&self) -> Option<StampedPose2> {
        self.running.as_ref()?.front.latest_pose()
    }

    /// The filter's current map (its best particle's), `None` before the first scan.
    pub fn map(&mut self) -> Result<Option<&OccupancyGrid>, OnlineError> {
        match self.running.as_mut() {
            Some(r) => Ok(Some(r.front.current_map()?)),
            None => Ok(None),
        }
    }

    /// The data pushed so far: after a consolidation (`[session] consolidate_every_scans`)
    /// the scans since, and the odometry from the last one handled.
    pub fn recording(&self) -> &Recording {
        &self.recording
    }

    /// Ends the run: the scans still waiting are counted as beyond the odometry, then the
    /// back end (when `[graph] enabled`) and the final map, as `pfslam run` does.
    pub fn finish(self) -> Result<PipelineResult, OnlineError> {
        self.finish_with(&PipelineOptions::default())
    }

    /// [`Self::finish`] with pipeline `options`.
    pub fn finish_with(self, options: &PipelineOptions) -> Result<PipelineResult, OnlineError> {
        self.finish_observed(options, &mut |_| {})
            .map(|(result, _)| result)
    }

    /// [`Self::finish_with`], reporting the filter's events on the last scans to `observer`;
    /// also gives back the recording pushed (after a consolidation: the keyframes kept, with
    /// their scans).
    pub fn finish_observed(
        mut self,
        options: &PipelineOptions,
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<(PipelineResult, Recording), OnlineError> {
        // scans of a whole recording given at the start wait here
        self.handle_ready(observer)?;
        let t = Instant::now();
        let Some(mut running) = self.running.take() else {
            let message = if self.recording.odometry.is_empty() {
                "no odometry"
            } else {
                "no scan lies within the odometry's time span"
            };
            return Err(SlamError::Input {
                name: self.recording.name.clone(),
                message: message.into(),
            }
            .into());
        };
        let recording = &self.recording;
        for i in self.next_scan..recording.scans.len() {
            let feed = (&mut running.cursor, &mut running.steps);
            feed_scan(&mut running.front, recording, i, feed, observer)?;
        }
        let result = running.front.finish(recording, running.t_start)?;
        let filter_s = self.filter_s + t.elapsed().as_secs_f64();
        let (config, seed) = (&self.config, self.seed);
        if let Some(rolling) = self.rolling.take() {
            let last = std::mem::take(&mut self.recording);
            return Ok(rolling.finish(last, result, filter_s, config)?);
        }
        let pipeline = after_filter(recording, config, (seed, options), result, (filter_s, None))?;
        Ok((pipeline, self.recording))
    }

    /// True once the `rbpf` filter handled `[session] consolidate_every_scans` scans since
    /// the last consolidation.
    fn window_full(&self) -> bool {
        let every = self.config.session.consolidate_every_scans;
        let rbpf = matches!(
            self.running.as_ref().map(|r| &r.front),
            Some(AnyFrontEnd::Rbpf(_))
        );
        rbpf && every > 0 && self.next_scan >= every
    }

    /// Consolidates the scans handled so far ([`Rolling::add_window`]) and lets them go.
    fn consolidate(&mut self) -> Result<(), OnlineError> {
        let Some(running) = self.running.as_mut() else {
            return Ok(());
        };
        let let_go = self.next_scan;
        let Some(window) = running.front.take_window(&self.recording, let_go)? else {
            return Ok(());
        };
        let scans = self.recording.split_front(let_go);
        let passed = running.cursor.forget_passed();
        self.recording.odometry.poses.drain(..passed);
        let every = self.config.session.consolidate_every_scans;
        self.recording.scans.reserve_scans(every);
        self.next_scan = 0;
        let rolling = self.rolling.get_or_insert_with(Rolling::default);
        rolling.add_window(scans, window, &self.config)?;
        tracing::info!(
            "consolidated {} scans to {} keyframes (window {})",
            rolling.trajectory.len(),
            rolling.keyframes(),
            rolling.windows
        );
        Ok(())
    }

    /// Appends `scan` to the recording, checked.
    fn append_scan(&mut self, scan: &ScanInput<'_>) -> Result<(), OnlineError> {
        let rec = &mut self.recording;
        let err = |message: &str| OnlineError::Scan {
            stamp_ns: scan.stamp_ns,
            message: message.to_string(),
        };
        if let Some(&last_ns) = rec.scans.stamps_ns.last()
            && scan.stamp_ns < last_ns
        {
            return Err(OnlineError::OutOfOrder {
                what: "scan",
                stamp_ns: scan.stamp_ns,
                last_ns,
            });
        }
        let lidar = scan.lidar.unwrap_or(rec.lidar);
        if let Some(problem) = lidar.problem() {
            return Err(err(&problem));
        }
        if scan.ranges_m.len() != lidar.beam_count {
            return Err(err(&format!(
                "{} ranges for {} beams",
                scan.ranges_m.len(),
                lidar.beam_count
            )));
        }
        match (&mut rec.body_from_lidar_per_scan, scan.body_from_lidar) {
            (Some(mounts), Some(m)) => mounts.push(m),
            (Some(_), None) => return Err(err("the LiDAR moves on the body: give its mount")),
            (None, Some(_)) => return Err(err("a mount per scan needs `lidar_moves`")),
            (None, None) => {}
        }
        if scan.lidar.is_some() || rec.lidar_per_scan.is_some() {
            let n = rec.scans.len();
            let default = rec.lidar;
            let per_scan = rec.lidar_per_scan.get_or_insert_with(|| vec![default; n]);
            per_scan.push(lidar);
        }
        rec.scans.push_any(scan.stamp_ns, scan.ranges_m);
        Ok(())
    }

    /// Hands every waiting scan the odometry reaches to the front end (starting it at the
    /// first scan inside the odometry's span); the latest pose when any was handled.
    fn handle_ready(
        &mut self,
        observer: &mut dyn FnMut(SlamEvent<'_>),
    ) -> Result<Option<StampedPose2>, OnlineError> {
        let t = Instant::now();
        let mut handled = false;
        let mut rec = &self.recording;
        while self.next_scan < rec.scans.len() {
            let i = self.next_scan;
            let stamp_ns = rec.scans.stamps_ns[i];
            match rec.odometry.poses.last() {
                Some(last) if last.stamp_ns >= stamp_ns => {}
                _ => break,
            }
            if let Some(imu) = &rec.imu_yaw
                && imu.last().is_none_or(|&(last_ns, _)| last_ns < stamp_ns)
            {
                break;
            }
            if self.running.is_none() {
                let Some(cursor) = OdometryCursor::new(&rec.odometry, stamp_ns) else {
                    // Before the odometry's first pose: counted as skipped at the start.
                    self.next_scan += 1;
                    continue;
                };
                let start = (cursor.current().pose, i);
                self.running = Some(Running {
                    front: AnyFrontEnd::new(rec, &self.config, self.seed, start)?,
                    cursor,
                    steps: Vec::new(),
                    t_start: Instant::now(),
                });
            }
            if let Some(r) = self.running.as_mut() {
                let feed = (&mut r.cursor, &mut r.steps);
                feed_scan(&mut r.front, rec, i, feed, observer)?;
            }
            self.next_scan += 1;
            handled = true;
            if self.window_full() {
                self.consolidate()?;
            }
            rec = &self.recording;
        }
        self.filter_s += t.elapsed().as_secs_f64();
        Ok(if handled { self.pose() } else { None })
    }
}
