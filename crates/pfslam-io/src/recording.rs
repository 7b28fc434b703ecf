//! Opens any supported recording file as a [`Recording`] with its [`InputAccount`], choosing
//! the reader from the file's first bytes (ROS 1 bag, MCAP) or its name (CARMEN `.clf` /
//! `.log`, optionally `.gz`); a rosbag2 directory is read through its `.mcap` file.

use super::IoError;
use super::account::InputAccount;
use super::carmen::{CarmenOptions, read_carmen};
use super::mcap::read_mcap_with_account;
pub use super::options::ReaderOptions;
use super::ros_msgs::RosError;
use super::ros1::read_ros1_bag_with_account;
use pfslam::sensors::Recording;
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};

/// The recording file formats pfslam reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RecordingFormat {
    /// CARMEN log (`.clf`, `.log`, optionally gzipped).
    Carmen,
    /// ROS 1 bag (`.bag`).
    Ros1Bag,
    /// ROS 2 MCAP (`.mcap`).
    Mcap,
}

/// A recording and the account of its reading.
#[derive(Debug, Clone)]
pub struct Opened {
    /// The recording.
    pub recording: Recording,
    /// What was read, kept, dropped and repaired.
    pub account: InputAccount,
}

/// Errors of [`read_recording`].
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// A text file is unreadable or malformed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A binary file is malformed.
    #[error(transparent)]
    Ros(#[from] RosError),
    /// The format is not recognised.
    #[error("{}: not a recognised recording (CARMEN .clf/.log[.gz], ROS 1 .bag, .mcap)", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
    },
}

/// The format of `path`, from its magic bytes or else its name; `None` if unrecognised.
pub fn detect_format(path: &Path) -> Result<Option<RecordingFormat>, IoError> {
    let head = read_head(path, 13)?;
    if head.starts_with(b"#ROSBAG V2.0") {
        return Ok(Some(RecordingFormat::Ros1Bag));
    }
    if head.starts_with(b"\x89MCAP") {
        return Ok(Some(RecordingFormat::Mcap));
    }
    let name = path
        .file_name()
        .map(|s| s.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let base = name.strip_suffix(".gz").unwrap_or(&name);
    Ok(if base.ends_with(".clf") || base.ends_with(".log") {
        Some(RecordingFormat::Carmen)
    } else if name.ends_with(".bag") {
        Some(RecordingFormat::Ros1Bag)
    } else if name.ends_with(".mcap") {
        Some(RecordingFormat::Mcap)
    } else {
        None
    })
}

/// The first `n` bytes of a file (fewer if it is shorter).
pub(crate) fn read_head(path: &Path, n: usize) -> Result<Vec<u8>, IoError> {
    let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut head = Vec::with_capacity(n);
    f.take(n as u64)
        .read_to_end(&mut head)
        .map_err(|e| IoError::io(path, e))?;
    Ok(head)
}

/// Reads a recording in any supported format.
pub fn read_recording(path: &Path, options: &ReaderOptions) -> Result<Recording, ReadError> {
    open_recording(path, options).map(|o| o.recording)
}

/// Reads a recording in any supported format, with the account of its reading. A rosbag2
/// directory (`metadata.yaml` beside one `.mcap` file) is read as that file.
pub fn open_recording(path: &Path, options: &ReaderOptions) -> Result<Opened, ReadError> {
    let file = resolve_rosbag2(path)?;
    let path = file.as_deref().unwrap_or(path);
    let (recording, account) = match detect_format(path)? {
        Some(RecordingFormat::Carmen) => {
            let log = read_carmen(path, &CarmenOptions::from_reader(options))?;
            (log.recording, log.account)
        }
        Some(RecordingFormat::Ros1Bag) => read_ros1_bag_with_account(path, options)?,
        Some(RecordingFormat::Mcap) => read_mcap_with_account(path, options)?,
        None => {
            return Err(ReadError::Unsupported {
                path: path.to_path_buf(),
            });
        }
    };
    let mut opened = Opened { recording, account };
    opened.keep_span(options.start_s, options.end_s);
    Ok(opened)
}

impl Opened {
    /// Keeps the scans from `start_s` to `end_s` seconds after the first scan (and the
    /// odometry around them); the others are counted in the account as left out on request.
    pub fn keep_span(&mut self, start_s: Option<f64>, end_s: Option<f64>) {
        if start_s.is_none() && end_s.is_none() {
            return;
        }
        let rec = &mut self.recording;
        let Some(&t0) = rec.scans.stamps_ns.first() else {
            return;
        };
        let lo = t0.saturating_add(start_s.map_or(i64::MIN / 2, |s| (s * 1e9) as i64));
        let hi = t0.saturating_add(end_s.map_or(i64::MAX / 2, |s| (s * 1e9) as i64));
        let keep: Vec<usize> = (0..rec.scans.len())
            .filter(|&i| (lo..=hi).contains(&rec.scans.stamps_ns[i]))
            .collect();
        let outside = rec.scans.len() - keep.len();
        rec.keep_scans(&keep);
        // the odometry around the kept scans: one pose on either side for interpolation
        let (a, b) = match (rec.scans.stamps_ns.first(), rec.scans.stamps_ns.last()) {
            (Some(&a), Some(&b)) => (a, b),
            _ => (lo, hi),
        };
        let p = &rec.odometry.poses;
        let first = p.partition_point(|q| q.stamp_ns <= a).saturating_sub(1);
        let last = p
            .partition_point(|q| q.stamp_ns < b)
            .min(p.len().saturating_sub(1));
        let kept: Vec<_> = p.get(first..=last).map(<[_]>::to_vec).unwrap_or_default();
        self.account.odometry_kept = kept.len();
        rec.odometry = pfslam::geometry::Trajectory::new(kept);
        if let Some(gt) = &mut rec.ground_truth {
            gt.retain(|q| (lo..=hi).contains(&q.stamp_ns));
        }
        self.account.scans_outside_span = outside;
        self.account.scans_kept = rec.scans.len();
    }
}

/// The `.mcap` file of a rosbag2 directory; `None` for a file.
pub fn resolve_rosbag2(path: &Path) -> Result<Option<PathBuf>, IoError> {
    if !path.is_dir() {
        return Ok(None);
    }
    if !path.join("metadata.yaml").is_file() {
        return Ok(None);
    }
    let mut found: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| IoError::io(path, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    found.sort();
    match found.len() {
        1 => Ok(found.pop()),
        0 => Err(IoError::parse(
            path,
            0,
            "a rosbag2 directory (metadata.yaml) without a .mcap file (only MCAP storage is read)",
        )),
        n => Err(IoError::parse(
            path,
            0,
            format!(
                "a rosbag2 directory with {n} .mcap files: split bags are not read, pass one file"
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detection() {
        let dir = tempfile::tempdir().unwrap();
        let cases: [(&str, &[u8], Option<RecordingFormat>); 5] = [
            ("a.bin", b"#ROSBAG V2.0\n", Some(RecordingFormat::Ros1Bag)),
            ("a.x", b"\x89MCAP0\r\n", Some(RecordingFormat::Mcap)),
            ("intel.log.gz", b"\x1f\x8b", Some(RecordingFormat::Carmen)),
            ("m.clf", b"FLASER", Some(RecordingFormat::Carmen)),
            ("m.txt", b"FLASER", None),
        ];
        for (name, bytes, want) in cases {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            assert_eq!(detect_format(&p).unwrap(), want, "{name}");
        }
        let p = dir.path().join("m.txt");
        let e = read_recording(&p, &ReaderOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.txt: not a recognised recording"), "{e}");
    }
}
