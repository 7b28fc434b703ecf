//! A CARMEN log read as it arrives (standard input, a pipe): each line's odometry or scan is
//! handed on as soon as the line is whole, for the incremental API ([`pfslam::Slam`]).
//!
//! The whole-file reader ([`super::read_carmen`]) chooses the laser and the clock from every
//! line at once; a live reader cannot look ahead, so its rules differ where a log needs it:
//! - the scans come from the **first laser line type seen** among those of the chosen laser
//!   (FLASER, ROBOTLASER1 or RAWLASER1 for the front one); lines of the others are counted as
//!   ignored, with a warning when the whole-file reader would have preferred them;
//! - a scan or `ODOM` line whose stamp is zero or does not increase is **dropped** and counted
//!   (the whole-file reader places such stamps between their neighbours);
//! - the laser mount comes from the `PARAM` lines before the first scan (later ones are
//!   counted as ignored); `TRUEPOS` lines are counted as ignored (no ground truth).
//!
//! On a log with increasing stamps and one laser line type, the messages are the recording
//! the whole-file reader gives, in file order.

use super::lines::{Lines, maybe_gz};
use super::parse::{LaserLine, Message};
use super::{
    CarmenOptions, KINDS, candidates, kind_index, laser_mount, line_geometry, pose_to_rigid,
    set_offset,
};
use crate::IoError;
use crate::account::InputAccount;
use pfslam::geometry::{Pose2, Rigid3, StampedPose2};
use pfslam::sensors::LidarGeometry;
use std::collections::VecDeque;
use std::io::Read;
use std::path::{Path, PathBuf};

/// One message of a live CARMEN log.
#[derive(Debug, Clone, Copy)]
pub enum LiveMessage<'a> {
    /// An `ODOM` line's pose (logs whose laser lines carry no pose).
    Odometry(StampedPose2),
    /// A scan.
    Scan(LiveScan<'a>),
}

/// A scan of a live CARMEN log.
#[derive(Debug, Clone, Copy)]
pub struct LiveScan<'a> {
    /// Its stamp (ns).
    pub stamp_ns: i64,
    /// One range per beam (m).
    pub ranges_m: &'a [f32],
    /// Its beams.
    pub lidar: LidarGeometry,
    /// The laser mount (fixed at the first scan).
    pub body_from_lidar: Rigid3,
    /// The odometry pose the line carries at the scan (none for `RAWLASER` lines: the `ODOM`
    /// lines bring the odometry).
    pub odometry: Option<Pose2>,
}

/// A CARMEN log read line by line as it arrives (see the module docs).
pub struct CarmenLive<'a> {
    lines: Lines<'a>,
    path: PathBuf,
    options: CarmenOptions,
    account: InputAccount,
    offsets: [[f64; 3]; 2],
    /// The laser line type read (an index into [`KINDS`]), once the first scan came.
    kind: Option<usize>,
    mount: Rigid3,
    last_scan_ns: i64,
    last_odom_ns: i64,
    /// `ODOM` lines before the first scan (whether they are the odometry depends on it).
    early_odometry: Vec<StampedPose2>,
    /// Odometry to hand on before the scan held in `held`.
    pending: VecDeque<StampedPose2>,
    held: Option<(LaserLine, LidarGeometry)>,
    warned_preferred: bool,
}

impl<'a> CarmenLive<'a> {
    /// A live reader of `source` (plain or gzipped); `path` names it in errors and in the
    /// account (`-` for standard input).
    pub fn new(
        source: impl Read + 'a,
        path: &Path,
        options: &CarmenOptions,
    ) -> Result<Self, IoError> {
        let mut account = InputAccount::new("carmen", path, "lines");
        account.clock =
            "the laser lines' stamps (live input: a stamp that does not increase drops its line)"
                .into();
        Ok(CarmenLive {
            lines: Lines::new(maybe_gz(source, path)?),
            path: path.to_path_buf(),
            options: options.clone(),
            account,
            offsets: [[0.0; 3]; 2],
            kind: None,
            mount: Rigid3::IDENTITY,
            last_scan_ns: 0,
            last_odom_ns: 0,
            early_odometry: Vec::new(),
            pending: VecDeque::new(),
            held: None,
            warned_preferred: false,
        })
    }

    /// What was read, dropped and ignored so far.
    pub fn account(&self) -> &InputAccount {
        &self.account
    }

    /// The account once the source ended.
    pub fn into_account(mut self) -> InputAccount {
        self.account.records_read = self.lines.line_no;
        self.account
            .ignore_many("ODOM", ODOM_UNUSED, self.early_odometry.len());
        self.account
    }

    /// The next odometry pose or scan, `None` at the end of the source; blocks until a whole
    /// line arrives.
    pub fn next_message(&mut self) -> Result<Option<LiveMessage<'_>>, IoError> {
        loop {
            if let Some(odom) = self.pending.pop_front() {
                return Ok(Some(LiveMessage::Odometry(odom)));
            }
            if self.held.is_some() {
                break;
            }
            let path = self.path.as_path();
            let Some(msg) = self
                .lines
                .next_message(path, &self.options, &mut self.account)?
            else {
                return Ok(None);
            };
            match msg {
                Message::Laser(l) => self.laser(l),
                Message::Odom { stamp_ns, pose } => self.odom(StampedPose2 { stamp_ns, pose }),
                Message::Param { name, value } if self.kind.is_none() => {
                    set_offset(&mut self.offsets, &name, value)
                }
                Message::Param { .. } => self
                    .account
                    .ignore_one("PARAM", "lines (after the first scan)"),
                Message::TruePos { .. } => self
                    .account
                    .ignore_one("TRUEPOS", "lines (live input keeps no ground truth)"),
                Message::Other(kind) => self.account.ignore_one(&kind, "lines"),
                Message::Comment => {}
            }
        }
        let Some((l, lidar)) = self.held.take() else {
            return Ok(None);
        };
        let carries_pose = !KINDS[kind_index(l.kind)].starts_with("RAWLASER");
        Ok(Some(LiveMessage::Scan(LiveScan {
            stamp_ns: l.stamp_ns,
            ranges_m: &self.lines.ranges,
            lidar,
            body_from_lidar: self.mount,
            odometry: carries_pose.then_some(l.odom),
        })))
    }

    /// A laser line: held as the next scan when it is of the laser read and its stamp
    /// increases; counted otherwise.
    fn laser(&mut self, l: LaserLine) {
        let k = kind_index(l.kind);
        let preference = candidates(self.options.laser).iter().position(|&c| c == k);
        let Some(rank) = preference else {
            self.account.ignore_one(KINDS[k], "lines (another laser)");
            return;
        };
        match self.kind {
            None => {
                self.kind = Some(k);
                self.start(&l, k);
            }
            Some(chosen) if chosen != k => return self.other_laser_type(k, chosen, rank),
            Some(_) => {}
        }
        self.account.scans_read += 1;
        if l.stamp_ns <= self.last_scan_ns {
            let line = self.lines.line_no;
            self.account
                .drop_one("scans", STAMP_DROP, || format!("line {line}"));
            return;
        }
        self.last_scan_ns = l.stamp_ns;
        let lidar = line_geometry(&l, self.lines.ranges.len(), &self.options);
        let acc = &mut self.account;
        acc.scans_kept += 1;
        acc.add_layout(&lidar);
        acc.repair("readings", "not finite, taken as no return", l.non_finite);
        if !KINDS[k].starts_with("RAWLASER") {
            acc.odometry_read += 1;
            acc.odometry_kept += 1;
        }
        self.held = Some((l, lidar));
    }

    /// The first scan of type `k`: the mount, the odometry's source and the `ODOM` lines
    /// read before it.
    fn start(&mut self, l: &LaserLine, k: usize) {
        let robot_mount = (k == 2).then(|| l.odom.between(&l.pose));
        self.mount = pose_to_rigid(&laser_mount(&self.offsets, robot_mount, k));
        let acc = &mut self.account;
        acc.mount_source = match k {
            2 => "the first ROBOTLASER1 line's laser and robot poses".into(),
            _ => "PARAM laser offsets before the first scan (zero when absent)".into(),
        };
        if KINDS[k].starts_with("RAWLASER") {
            acc.odometry_source = "the ODOM lines (the RAWLASER lines carry no pose)".into();
            for odom in std::mem::take(&mut self.early_odometry) {
                self.odom(odom);
            }
        } else {
            acc.odometry_source = format!("the {} lines' odometry poses", KINDS[k]);
        }
    }

    /// A laser line of another type than the one read.
    fn other_laser_type(&mut self, k: usize, chosen: usize, rank: usize) {
        self.account
            .ignore_one(KINDS[k], "lines (another laser type than the first scan's)");
        let chosen_rank = candidates(self.options.laser)
            .iter()
            .position(|&c| c == chosen)
            .unwrap_or(usize::MAX);
        if rank < chosen_rank && !self.warned_preferred {
            self.warned_preferred = true;
            self.account.warnings.push(format!(
                "{}: {} lines come after the first {} line; live input reads the first laser type seen (the whole-file reader would read {})",
                self.path.display(),
                KINDS[k],
                KINDS[chosen],
                KINDS[k]
            ));
        }
    }

    /// An `ODOM` line: the odometry of `RAWLASER` logs, kept until the first scan tells.
    fn odom(&mut self, odom: StampedPose2) {
        match self.kind {
            None => self.early_odometry.push(odom),
            Some(k) if !KINDS[k].starts_with("RAWLASER") => {
                self.account.ignore_one("ODOM", ODOM_UNUSED)
            }
            Some(_) => {
                self.account.odometry_read += 1;
                if odom.stamp_ns <= self.last_odom_ns {
                    let line = self.lines.line_no;
                    self.account
                        .drop_one("odometry", STAMP_DROP, || format!("line {line}"));
                    return;
                }
                self.last_odom_ns = odom.stamp_ns;
                self.account.odometry_kept += 1;
                self.pending.push_back(odom);
            }
        }
    }
}

const STAMP_DROP: &str = "stamp zero, repeated or out of order (live input cannot place it)";
const ODOM_UNUSED: &str = "lines (the laser lines carry the odometry)";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::carmen::read_carmen_from;

    const LOG: &str = "# a log\n\
        PARAM robot_frontlaser_offset 0.2 host 0\n\
        ODOM 0 0 0 0 0 0 0.5 host 0.5\n\
        FLASER 3 1.0 2.0 3.0 9 9 9 0.1 0.0 0.0 1.0 host 1.0\n\
        FLASER 3 1.0 2.0 3.0 9 9 9 0.2 0.0 0.0 1.0 host 1.0\n\
        RLASER 3 1.0 2.0 3.0 9 9 9 0.2 0.0 0.0 1.5 host 1.5\n\
        TRUEPOS 0 0 0 0 0 0 1.5 host 1.5\n\
        FLASER 3 1.5 2.5 3.5 9 9 9 0.3 0.0 0.1 2.0 host 2.0\n\
        garbage here\n\
        PARAM robot_frontlaser_offset 0.5 host 0\n\
        FLASER 3 1.5 2.5 nan 9 9 9 0.4 0.0 0.2 3.0 host 3.0\n";

    /// A scan as read: stamp, ranges, beams, mount.
    type Scan = (i64, Vec<f32>, LidarGeometry, Rigid3);

    fn read_all(log: &str) -> (Vec<String>, Vec<Scan>, InputAccount) {
        let mut live = CarmenLive::new(
            log.as_bytes(),
            Path::new("t.log"),
            &CarmenOptions::default(),
        )
        .unwrap();
        let (mut order, mut scans) = (Vec::new(), Vec::new());
        while let Some(m) = live.next_message().unwrap() {
            match m {
                LiveMessage::Odometry(p) => order.push(format!("odom {}", p.stamp_ns)),
                LiveMessage::Scan(s) => {
                    order.push(format!(
                        "scan {} {:?}",
                        s.stamp_ns,
                        s.odometry.map(|p| p.x_m)
                    ));
                    scans.push((s.stamp_ns, s.ranges_m.to_vec(), s.lidar, s.body_from_lidar));
                }
            }
        }
        (order, scans, live.into_account())
    }

    #[test]
    fn scans_come_in_file_order_and_every_line_left_out_is_counted() {
        let (order, scans, acc) = read_all(LOG);
        assert_eq!(
            order,
            [
                "scan 1000000000 Some(0.1)",
                "scan 2000000000 Some(0.3)",
                "scan 3000000000 Some(0.4)"
            ]
        );
        assert_eq!(scans[0].1, [1.0, 2.0, 3.0]);
        assert!(
            (scans[0].3.to_pose2().x_m - 0.2).abs() < 1e-12,
            "mount from the early PARAM"
        );
        assert_eq!(acc.records_read, 11);
        assert_eq!(
            (acc.scans_read, acc.scans_kept, acc.scans_dropped()),
            (4, 3, 1)
        );
        let count = |v: &[crate::account::Tally], what: &str| {
            v.iter()
                .filter(|t| t.what.contains(what) || t.reason.contains(what))
                .map(|t| t.count)
                .sum::<usize>()
        };
        assert_eq!(count(&acc.dropped, "scans"), 1, "{:?}", acc.dropped);
        assert_eq!(count(&acc.dropped, "lines"), 1, "{:?}", acc.dropped);
        for kind in ["ODOM", "RLASER", "TRUEPOS", "PARAM"] {
            assert_eq!(count(&acc.ignored, kind), 1, "{kind}: {:?}", acc.ignored);
        }
        assert_eq!(count(&acc.repaired, "readings"), 1, "{:?}", acc.repaired);
    }

    #[test]
    fn a_clean_log_gives_the_whole_file_readers_recording() {
        let clean: String = LOG
            .lines()
            .filter(|l| !l.contains("0.2 0.0 0.0 1.0") && !l.contains("offset 0.5"))
            .map(|l| format!("{l}\n"))
            .collect();
        let batch = read_carmen_from(
            clean.as_bytes(),
            Path::new("t.log"),
            &CarmenOptions::default(),
        )
        .unwrap();
        let rec = batch.recording;
        let (_, scans, _) = read_all(&clean);
        assert_eq!(scans.len(), rec.scans.len());
        for (i, (stamp_ns, ranges, lidar, mount)) in scans.iter().enumerate() {
            assert_eq!(*stamp_ns, rec.scans.stamps_ns[i]);
            let bits = |r: &[f32]| r.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(ranges), bits(rec.scans.ranges(i)));
            assert_eq!(lidar, rec.lidar_at(i));
            assert_eq!(*mount, rec.body_from_lidar);
        }
    }

    #[test]
    fn rawlaser_logs_take_the_odom_lines_in_file_order() {
        let log = "ODOM 0 0 0 0 0 0 0.5 host 0.5\n\
            RAWLASER1 0 -1.5708 3.1416 1.5708 30 0.01 0 3 1 2 3 0 1.0 host 1.0\n\
            ODOM 1 0 0 0 0 0 1.5 host 1.5\n\
            ODOM 1 0 0 0 0 0 1.5 host 1.5\n\
            RAWLASER1 0 -1.5708 3.1416 1.5708 30 0.01 0 3 1 2 3 0 2.0 host 2.0\n\
            ODOM 2 0 0 0 0 0 2.5 host 2.5\n";
        let (order, _, acc) = read_all(log);
        assert_eq!(
            order,
            [
                "odom 500000000",
                "scan 1000000000 None",
                "odom 1500000000",
                "scan 2000000000 None",
                "odom 2500000000"
            ]
        );
        assert_eq!((acc.odometry_read, acc.odometry_kept), (4, 3));
    }

    #[test]
    fn the_first_laser_type_is_read_and_a_preferred_later_one_warned_of() {
        let log = "ROBOTLASER1 0 -1.5708 3.1416 1.5708 30 0.01 0 3 1 2 3 0 0 0 0 0 0 0 0 0 0 0 0 1.0 host 1.0\n\
            FLASER 3 1.0 2.0 3.0 9 9 9 0.1 0.0 0.0 2.0 host 2.0\n";
        let (order, _, acc) = read_all(log);
        assert_eq!(order, ["scan 1000000000 Some(0.0)"]);
        assert!(
            acc.warnings
                .iter()
                .any(|w| w.contains("FLASER lines come after")),
            "{:?}",
            acc.warnings
        );
    }

    /// Hands out one line per read, counting the bytes.
    struct Trickle<'a> {
        rest: &'a [u8],
        given: std::rc::Rc<std::cell::Cell<usize>>,
    }

    impl Read for Trickle<'_> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let line = self
                .rest
                .iter()
                .position(|&b| b == b'\n')
                .map_or(self.rest.len(), |i| i + 1);
            let n = line.min(buf.len());
            buf[..n].copy_from_slice(&self.rest[..n]);
            self.rest = &self.rest[n..];
            self.given.set(self.given.get() + n);
            Ok(n)
        }
    }

    #[test]
    fn a_scan_is_handed_on_before_the_rest_of_the_source_is_read() {
        let given = std::rc::Rc::new(std::cell::Cell::new(0));
        let source = Trickle {
            rest: LOG.as_bytes(),
            given: given.clone(),
        };
        let mut live = CarmenLive::new(source, Path::new("-"), &CarmenOptions::default()).unwrap();
        let first = live.next_message().unwrap();
        assert!(matches!(first, Some(LiveMessage::Scan(_))));
        let upto = LOG.find("FLASER 3 1.0 2.0 3.0 9 9 9 0.2").unwrap();
        assert!(
            given.get() <= upto,
            "read {} bytes, the first scan ends at {upto}",
            given.get()
        );
    }
}
