//! `run --record FILE`: the run as an MCAP file that Foxglove opens (the map over time, each
//! scan in the world, the particle cloud, the trajectories, the loop closures; see
//! [`pfslam_viz::record`]). It is written beside `FILE` and renamed into place at the end,
//! so a failed run leaves no half-written record.

use anyhow::Context;
use pfslam::geometry::{Pose2, StampedPose2};
use pfslam::sensors::Recording;
use pfslam::slam::SlamEvent;
use pfslam_viz::record::{RunRecord, Topic};
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// The map is written at most once per this much recording time (and at the end).
const MAP_EVERY_NS: i64 = 5_000_000_000;

/// A record being written during a run.
pub struct Recorder {
    path: PathBuf,
    temp: tempfile::TempPath,
    record: RunRecord<BufWriter<std::fs::File>>,
    last_map_ns: Option<i64>,
    error: Option<anyhow::Error>,
}

/// What the record holds of a finished run.
pub struct Finished<'a> {
    /// The recording run.
    pub recording: &'a Recording,
    /// The final trajectory (a pose per scan used).
    pub trajectory: &'a [StampedPose2],
    /// The filter's trajectory.
    pub front_end: &'a [StampedPose2],
    /// The final map.
    pub map: &'a pfslam::map::OccupancyGrid,
    /// The two ends of each loop closure.
    pub loop_closures: &'a [(Pose2, Pose2)],
}

impl Recorder {
    /// Starts the record of `path` (checked before any work: its folder must accept files).
    pub fn create(path: &Path) -> anyhow::Result<Recorder> {
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        // as any file the user writes: 0666 less the umask (a temporary file's default is 0600)
        let mode = std::os::unix::fs::PermissionsExt::from_mode(0o666);
        let named = tempfile::Builder::new()
            .prefix(".pfslam-record-")
            .permissions(mode)
            .tempfile_in(parent)
            .with_context(|| {
                format!(
                    "--record {}: cannot write in {}",
                    path.display(),
                    parent.display()
                )
            })?;
        let (file, temp) = named.into_parts();
        let record = RunRecord::new(BufWriter::with_capacity(1 << 20, file), path)?;
        Ok(Recorder {
            path: path.to_path_buf(),
            temp,
            record,
            last_map_ns: None,
            error: None,
        })
    }

    /// Records a filter event: the particles at each update, the map now and then.
    pub fn on_event(&mut self, event: &SlamEvent<'_>) {
        if self.error.is_some() {
            return;
        }
        let res = match event {
            SlamEvent::Update {
                stamp_ns,
                particles,
                map,
            } => {
                let res = self
                    .record
                    .poses(Topic::Particles, *stamp_ns, particles.iter().copied());
                match map {
                    Some(m) if self.map_due(*stamp_ns) => {
                        res.and_then(|()| self.record.map(*stamp_ns, m))
                    }
                    _ => res,
                }
            }
            SlamEvent::Snapshot {
                map, trajectory, ..
            } => {
                let stamp_ns = trajectory.last().map_or(0, |p| p.stamp_ns);
                self.last_map_ns = Some(stamp_ns);
                self.record.map(stamp_ns, map)
            }
            SlamEvent::Progress { .. } | SlamEvent::Pose(_) => Ok(()),
        };
        if let Err(e) = res {
            self.error = Some(e.into());
        }
    }

    fn map_due(&mut self, stamp_ns: i64) -> bool {
        let due = self
            .last_map_ns
            .is_none_or(|t| stamp_ns.saturating_sub(t) >= MAP_EVERY_NS);
        if due {
            self.last_map_ns = Some(stamp_ns);
        }
        due
    }

    /// Adds the scans along the final trajectory, the trajectories, the final map and the
    /// loop closures; [`Written::persist`] then moves the record into place.
    pub fn finish(mut self, run: &Finished<'_>) -> anyhow::Result<Written> {
        if let Some(e) = self.error.take() {
            return Err(e.context(format!("--record {}", self.path.display())));
        }
        let rec = run.recording;
        let stamps = &rec.scans.stamps_ns;
        for p in run.trajectory {
            let Ok(i) = stamps.binary_search(&p.stamp_ns) else {
                continue;
            };
            let world_from_lidar = p.pose.compose(&rec.body_from_lidar_at(i).to_pose2());
            let (geometry, ranges) = (rec.lidar_at(i), rec.scans.ranges(i));
            self.record
                .scan(p.stamp_ns, &world_from_lidar, geometry, ranges)?;
        }
        let end_ns = run.trajectory.last().map_or(0, |p| p.stamp_ns);
        self.record.map(end_ns, run.map)?;
        self.record.trajectory(Topic::FrontEnd, run.front_end)?;
        self.record.trajectory(Topic::Trajectory, run.trajectory)?;
        self.record.loop_closures(end_ns, run.loop_closures)?;
        let mut out = self.record.finish()?;
        std::io::Write::flush(&mut out)
            .with_context(|| format!("--record {}", self.path.display()))?;
        drop(out);
        Ok(Written {
            temp: self.temp,
            path: self.path,
        })
    }
}

/// A complete record beside its place.
pub struct Written {
    temp: tempfile::TempPath,
    path: PathBuf,
}

impl Written {
    /// Renames the record into place.
    pub fn persist(self) -> anyhow::Result<()> {
        self.temp
            .persist(&self.path)
            .with_context(|| format!("--record {}", self.path.display()))?;
        Ok(())
    }
}
