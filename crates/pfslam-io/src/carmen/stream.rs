//! The scans' poses of a CARMEN log in memory independent of its length: two passes over the
//! file, the first choosing the laser and checking its clock, the second handing each scan's
//! stamp and odometry pose to the caller. It gives what [`read_carmen`] gives for the same
//! scans (stamps, odometry, layouts and account), without holding any scan.
//!
//! Only logs whose chosen laser lines carry their pose (FLASER, RLASER, ROBOTLASER1) and whose
//! stamps are all positive and increasing are streamed: their clock needs no repair. For the
//! others (`RAWLASER` lines, whose odometry comes from the `ODOM` lines, or stamps to repair,
//! which needs every stamp at once) the answer is `None` and the whole-file reader is the way.

use super::lines::{for_each_message, maybe_gz};
use super::parse::Message;
use super::{
    CarmenOptions, KINDS, account_laser, account_laser_clock, account_pose_odometry, candidates,
    kind_index, line_geometry,
};
use crate::IoError;
use crate::account::InputAccount;
use pfslam::geometry::Pose2;
use pfslam::sensors::LidarGeometry;
use std::path::Path;

/// One scan of a streamed log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPose {
    /// The scan's stamp (ns).
    pub stamp_ns: i64,
    /// The odometry pose its line carries.
    pub odom: Pose2,
    /// Its beam layout.
    pub geometry: LidarGeometry,
}

/// What the first pass learns, in memory independent of the log's length.
struct Survey {
    /// Laser lines of each type ([`KINDS`]).
    lines: [usize; 5],
    /// Whether every stamp of a type so far is positive and above the one before.
    increasing: [bool; 5],
    last_stamp_ns: [i64; 5],
    odom_lines: usize,
}

impl Survey {
    fn new() -> Survey {
        Survey {
            lines: [0; 5],
            increasing: [true; 5],
            last_stamp_ns: [0; 5],
            odom_lines: 0,
        }
    }

    /// Counts one message as [`super::LogContent::add`] does.
    fn add(&mut self, msg: Message, acc: &mut InputAccount) {
        match msg {
            Message::Laser(l) => {
                acc.repair("readings", "not finite, taken as no return", l.non_finite);
                let k = kind_index(l.kind);
                self.increasing[k] &= l.stamp_ns > 0 && l.stamp_ns > self.last_stamp_ns[k];
                self.last_stamp_ns[k] = l.stamp_ns;
                self.lines[k] += 1;
            }
            Message::Odom { .. } => self.odom_lines += 1,
            Message::Other(kind) => acc.ignore_one(&kind, "lines"),
            Message::Comment | Message::TruePos { .. } | Message::Param { .. } => {}
        }
    }
}

/// Streams the scans of the CARMEN log at `path` to `sink` in file order and returns the
/// account [`read_carmen`](super::read_carmen) gives, or `None` (before any call to `sink`)
/// when the log must be read whole (see the module docs). The file is read twice.
pub fn stream_scan_poses(
    path: &Path,
    options: &CarmenOptions,
    mut sink: impl FnMut(ScanPose) -> Result<(), IoError>,
) -> Result<Option<InputAccount>, IoError> {
    let open = || {
        let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        maybe_gz(file, path)
    };
    let mut acc = InputAccount::new("carmen", path, "lines");
    let mut survey = Survey::new();
    for_each_message(open()?, path, options, &mut acc, |msg, _, acc| {
        survey.add(msg, acc);
        Ok(())
    })?;
    let chosen = candidates(options.laser)
        .iter()
        .copied()
        .find(|&k| survey.lines[k] > 0);
    let Some(k) = chosen else {
        account_laser(path, options, &mut acc, survey.lines, "", 0)?;
        return Ok(None);
    };
    if KINDS[k].starts_with("RAWLASER") || !survey.increasing[k] {
        return Ok(None);
    }
    let n = survey.lines[k];
    let mut others = survey.lines;
    others[k] = 0;
    account_laser(path, options, &mut acc, others, KINDS[k], n)?;
    let mut layouts = InputAccount::new("carmen", path, "lines");
    for_each_message(
        open()?,
        path,
        options,
        &mut layouts,
        |msg, ranges, layouts| {
            let Message::Laser(l) = msg else {
                return Ok(());
            };
            if kind_index(l.kind) != k {
                return Ok(());
            }
            let geometry = line_geometry(&l, ranges.len(), options);
            layouts.add_layout(&geometry);
            sink(ScanPose {
                stamp_ns: l.stamp_ns,
                odom: l.odom,
                geometry,
            })
        },
    )?;
    acc.beam_layouts = layouts.beam_layouts;
    account_laser_clock(&mut acc, 0);
    account_pose_odometry(&mut acc, KINDS[k], n, survey.odom_lines);
    Ok(Some(acc))
}
