//! What `run` does with the filter's events: a progress bar on a terminal (log lines
//! otherwise), map snapshots in `snapshots/`, and the `--record` file.

use pfslam::filter::slam::SlamEvent;
use pfslam::geometry::Pose2;
use pfslam::viz::map_image::{MapImageOptions, TrajectoryOverlay, write_map_png};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

/// The observer of one run.
pub struct RunObserver {
    bar: Option<indicatif::ProgressBar>,
    last_logged: usize,
    t_start: Instant,
    snapshots: PathBuf,
    snapshot_error: Option<anyhow::Error>,
    /// The `--record` file being written.
    pub recorder: Option<super::record::Recorder>,
}

impl RunObserver {
    /// An observer of `total` scans writing snapshots into `snapshots`.
    pub fn new(
        total: usize,
        snapshots: PathBuf,
        recorder: Option<super::record::Recorder>,
    ) -> RunObserver {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = indicatif::ProgressBar::new(total as u64);
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
            snapshot_error: None,
            recorder,
        }
    }

    /// Handles one event of the filter.
    pub fn on_event(&mut self, ev: SlamEvent<'_>) {
        if let Some(r) = self.recorder.as_mut() {
            r.on_event(&ev);
        }
        match ev {
            SlamEvent::Update { .. } => {}
            SlamEvent::Progress { done, total } => self.progress(done, total),
            SlamEvent::Snapshot {
                scans_done,
                map,
                trajectory,
            } => {
                if self.snapshot_error.is_some() {
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
                    self.snapshot_error = Some(e.context("writing a snapshot"));
                }
            }
        }
    }

    fn progress(&mut self, done: usize, total: usize) {
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
        match self.snapshot_error {
            Some(e) => Err(e),
            None => Ok(self.recorder),
        }
    }
}
