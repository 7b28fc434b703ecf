//! What `run` does with the filter's events: a progress bar on a terminal (log lines
//! otherwise), map snapshots in `snapshots/`, the `--record` file, and each scan's pose as a
//! TUM line at once (`--poses-out`).

use pfslam::geometry::Pose2;
use pfslam::slam::SlamEvent;
use pfslam_viz::map_image::{MapImageOptions, TrajectoryOverlay, write_map_png};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

/// The observer of one run.
pub struct RunObserver {
    bar: Option<indicatif::ProgressBar>,
    last_logged: usize,
    t_start: Instant,
    snapshots: PathBuf,
    write_error: Option<anyhow::Error>,
    /// The `--record` file being written.
    pub recorder: Option<super::record::Recorder>,
    /// `--poses-out`: each scan's pose, flushed at once.
    poses_out: Option<Box<dyn std::io::Write>>,
    /// The scans' poses so far, thinned, when kept (live snapshots draw them).
    pub poses: Option<super::thinned::Thinned<Pose2>>,
}

impl RunObserver {
    /// An observer writing snapshots into `snapshots`.
    pub fn new(snapshots: PathBuf, recorder: Option<super::record::Recorder>) -> RunObserver {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = indicatif::ProgressBar::new(0);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{bar:40} {pos}/{len} scans  {per_sec}  ETA {eta}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        RunObserver {
            bar,
            last_logged: 0,
            t_start: Instant::now(),
            snapshots,
            write_error: None,
            recorder,
            poses_out: None,
            poses: None,
        }
    }

    /// The run to come has `total` scans: the progress bar's length; the clock of its rate
    /// starts.
    pub fn set_total(&mut self, total: usize) {
        if let Some(b) = &self.bar {
            b.set_length(total as u64);
        }
        self.t_start = Instant::now();
    }

    /// Also writes each scan's pose to `out` as a TUM line, flushed at once.
    pub fn with_poses_out(mut self, out: Box<dyn std::io::Write>) -> RunObserver {
        self.poses_out = Some(out);
        self
    }

    /// Live input: no progress bar (the scan count is unknown), the poses kept.
    pub fn live(mut self) -> RunObserver {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        self.poses = Some(super::thinned::Thinned::default());
        self
    }

    /// Handles one event of the filter.
    pub fn on_event(&mut self, ev: SlamEvent<'_>) {
        if let Some(r) = self.recorder.as_mut() {
            r.on_event(&ev);
        }
        match ev {
            SlamEvent::Update { .. } => {}
            SlamEvent::Pose(p) => self.pose(&p),
            SlamEvent::Progress { done, total } => self.progress(done, total),
            SlamEvent::Snapshot {
                scans_done,
                map,
                trajectory,
            } => {
                if self.write_error.is_some() {
                    return;
                }
                let poses: Vec<Pose2> = trajectory.iter().map(|p| p.pose).collect();
                let snapshots = &self.snapshots;
                let res = std::fs::create_dir_all(snapshots)
                    .map_err(anyhow::Error::from)
                    .and_then(|()| {
                        write_map_png(
                            &snapshots.join(format!("map_{scans_done:07}.png")),
                            map,
                            &[TrajectoryOverlay {
                                label: "SLAM",
                                poses: &poses,
                            }],
                            None,
                            &MapImageOptions::default(),
                        )
                        .map_err(anyhow::Error::from)
                    });
                if let Err(e) = res {
                    self.write_error = Some(e.context("writing a snapshot"));
                }
            }
        }
    }

    fn pose(&mut self, p: &pfslam::geometry::StampedPose2) {
        if let Some(poses) = self.poses.as_mut() {
            poses.push(p.pose);
        }
        let Some(out) = self.poses_out.as_mut() else {
            return;
        };
        let res = pfslam_io::tum::write_tum_line(out.as_mut(), p).and_then(|()| out.flush());
        if let Err(e) = res {
            self.poses_out = None;
            if self.write_error.is_none() {
                self.write_error = Some(anyhow::Error::from(e).context("writing --poses-out"));
            }
        }
    }

    fn progress(&mut self, done: usize, total: usize) {
        if self.poses.is_some() {
            return; // live: the total is not known
        }
        if let Some(b) = &self.bar {
            b.set_position(done as u64);
        } else if done * 10 / total.max(1) > self.last_logged * 10 / total.max(1) || done == total {
            self.last_logged = done;
            let s = self.t_start.elapsed().as_secs_f64();
            tracing::info!(
                "{done}/{total} scans ({:.0} scans/s)",
                done as f64 / s.max(1e-9)
            );
        }
    }

    /// Clears the progress bar; the first snapshot error, if any; the recorder.
    pub fn finish(self) -> anyhow::Result<Option<super::record::Recorder>> {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
        match self.write_error {
            Some(e) => Err(e),
            None => Ok(self.recorder),
        }
    }
}
