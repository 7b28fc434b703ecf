//! `pfslam run - --format carmen`: SLAM on a CARMEN log read from standard input as its lines
//! arrive, through the incremental API ([`pfslam::Slam`]). Each scan's pose goes to
//! `--poses-out` at once, the map so far to `live_map.png` every `--snapshot-every-s`; at the
//! end of the input the back end and the outputs of a batch run follow. On a log with
//! increasing stamps the result is the batch run's bit for bit (see
//! [`pfslam_io::carmen::CarmenLive`] for where the live reader's rules differ).

use super::observer::RunObserver;
use super::run::{Args, LiveFormat, Slammed};
use anyhow::Context;
use pfslam::config::Config;
use pfslam::geometry::StampedPose2;
use pfslam::slam::SlamEvent;
use pfslam::{ScanInput, SensorSetup, Slam};
use pfslam_io::carmen::{CarmenLive, LiveMessage, LiveScan};
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, write_map_png};
use std::path::Path;
use std::time::{Duration, Instant};

/// The file `--snapshot-every-s` writes in `--out`.
pub const LIVE_MAP: &str = "live_map.png";

/// Whether `args` ask for live input (`-`), and their checks: `--format` goes with `-` only,
/// as do `--snapshot-every-s`; a span, `--resume` and car-layout flags do not.
pub fn check_args(args: &Args, config: &Config) -> anyhow::Result<bool> {
    let live = args.dataset.as_os_str() == "-";
    if !live {
        if args.format.is_some() {
            anyhow::bail!("--format is the format of standard input: give `-` as the dataset");
        }
        if args.snapshot_every_s.is_some() {
            anyhow::bail!("--snapshot-every-s goes with live input (`-`)");
        }
        return Ok(false);
    }
    if args.format != Some(LiveFormat::Carmen) {
        anyhow::bail!("reading standard input (`-`) needs its format: --format carmen");
    }
    if let Some(s) = args.snapshot_every_s
        && !(s.is_finite() && s > 0.0)
    {
        anyhow::bail!("--snapshot-every-s {s}: must be a positive number of seconds");
    }
    let refused = [
        (args.resume.is_some(), "--resume"),
        (args.sort_timestamps, "--sort-timestamps"),
        (
            config.input.start_s.is_some(),
            "--start-s / [input] start_s",
        ),
        (config.input.end_s.is_some(), "--end-s / [input] end_s"),
    ];
    if let Some((_, flag)) = refused.iter().find(|(given, _)| *given) {
        anyhow::bail!("{flag} does not go with live input (`-`)");
    }
    Ok(true)
}

/// Reads standard input to its end, feeding the filter as lines arrive; then the back end.
pub(super) fn read_and_slam(
    args: &Args,
    config: &Config,
    observer: RunObserver,
) -> anyhow::Result<Slammed> {
    let name = Path::new("<stdin>");
    let stdin = std::io::stdin().lock();
    let mut reader = CarmenLive::new(
        stdin,
        name,
        &pfslam_io::carmen::CarmenOptions::from_reader(&config.input),
    )?;
    let mut run = LiveRun {
        args,
        config,
        observer: observer.live(),
        slam: None,
        early_odometry: Vec::new(),
        next_snapshot_ns: None,
        read_time: Duration::ZERO,
    };
    loop {
        let t = Instant::now();
        let msg = reader.next_message()?;
        run.read_time += t.elapsed();
        match msg {
            None => break,
            Some(LiveMessage::Odometry(p)) => run.odometry(p)?,
            Some(LiveMessage::Scan(scan)) => run.scan(&scan)?,
        }
    }
    let account = reader.into_account();
    super::input::report(&account);
    let LiveRun {
        slam,
        mut observer,
        read_time,
        ..
    } = run;
    let slam = slam.context("standard input: no scan of the chosen laser")?;
    let options = super::run::pipeline_options(args);
    let (pipeline, recording) = slam.finish_observed(&options, &mut |ev| observer.on_event(ev))?;
    let recorder = observer.finish()?;
    Ok(Slammed {
        recording,
        true_map: None,
        account,
        load_s: read_time.as_secs_f64(),
        anchored: false,
        pipeline,
        recorder,
    })
}

/// Removes `live_map.png` from `out` once the final outputs are in place.
pub fn remove_snapshot(out: &Path) {
    let _ = std::fs::remove_file(out.join(LIVE_MAP));
}

/// The state of a live run between messages.
struct LiveRun<'a> {
    args: &'a Args,
    config: &'a Config,
    observer: RunObserver,
    /// Started at the first scan (its beams and mount are the setup).
    slam: Option<Slam>,
    /// Odometry before the first scan.
    early_odometry: Vec<StampedPose2>,
    next_snapshot_ns: Option<i64>,
    /// Wall time spent waiting for and parsing lines.
    read_time: Duration,
}

impl LiveRun<'_> {
    fn odometry(&mut self, p: StampedPose2) -> anyhow::Result<()> {
        let observer = &mut self.observer;
        match self.slam.as_mut() {
            Some(slam) => {
                slam.push_odometry_observed(p.stamp_ns, p.pose, &mut |ev| observer.on_event(ev))?;
            }
            None => self.early_odometry.push(p),
        }
        Ok(())
    }

    fn scan(&mut self, scan: &LiveScan<'_>) -> anyhow::Result<()> {
        if self.slam.is_none() {
            self.start(scan)?;
        }
        let Some(slam) = self.slam.as_mut() else {
            return Ok(());
        };
        let observer = &mut self.observer;
        let on_event = &mut |ev: SlamEvent<'_>| observer.on_event(ev);
        if let Some(pose) = scan.odometry {
            slam.push_odometry_observed(scan.stamp_ns, pose, on_event)?;
        }
        let setup_lidar = slam.recording().lidar;
        let input = ScanInput {
            stamp_ns: scan.stamp_ns,
            ranges_m: scan.ranges_m,
            lidar: (scan.lidar != setup_lidar).then_some(scan.lidar),
            body_from_lidar: None,
        };
        slam.push_scan_observed(input, on_event)?;
        self.snapshot_if_due(scan.stamp_ns)
    }

    /// The filter, set up with the first scan's beams and mount; the odometry read before.
    fn start(&mut self, scan: &LiveScan<'_>) -> anyhow::Result<()> {
        let setup = SensorSetup {
            name: "stdin".into(),
            lidar: scan.lidar,
            body_from_lidar: scan.body_from_lidar,
            lidar_moves: false,
        };
        self.slam = Some(Slam::new(self.config.clone(), setup, self.args.seed)?);
        for p in std::mem::take(&mut self.early_odometry) {
            self.odometry(p)?;
        }
        Ok(())
    }

    /// Writes `live_map.png` when `--snapshot-every-s` of recording time passed since the last.
    fn snapshot_if_due(&mut self, stamp_ns: i64) -> anyhow::Result<()> {
        let Some(every_s) = self.args.snapshot_every_s else {
            return Ok(());
        };
        let due = self.next_snapshot_ns.get_or_insert(stamp_ns);
        if stamp_ns < *due {
            return Ok(());
        }
        *due = stamp_ns.saturating_add((every_s * 1e9) as i64);
        let (Some(slam), Some(poses)) = (self.slam.as_mut(), self.observer.poses.as_ref()) else {
            return Ok(());
        };
        let Some(map) = slam.map()? else {
            return Ok(());
        };
        std::fs::create_dir_all(&self.args.out)
            .with_context(|| format!("--out {}: cannot create it", self.args.out.display()))?;
        let overlay = TrajectoryOverlay {
            label: "SLAM",
            poses: &poses.poses,
        };
        let path = self.args.out.join(LIVE_MAP);
        write_map_png(&path, map, &[overlay], None, &MapImageOptions::default())
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(())
    }
}
