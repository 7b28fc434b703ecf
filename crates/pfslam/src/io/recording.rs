//! Opens any supported recording file as a [`Recording`], choosing the reader from the file's
//! first bytes (ROS 1 bag, MCAP) or its name (CARMEN `.clf` / `.log`, optionally `.gz`).

use super::IoError;
use super::carmen::{CarmenOptions, read_carmen};
use super::mcap::read_mcap;
use super::ros_msgs::{RosError, RosOptions};
use super::ros1::read_ros1_bag;
use crate::sensors::Recording;
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

/// Options of all recording readers.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReaderOptions {
    /// CARMEN logs.
    pub carmen: CarmenOptions,
    /// ROS 1 bags and MCAP files.
    pub ros: RosOptions,
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
    match detect_format(path)? {
        Some(RecordingFormat::Carmen) => Ok(read_carmen(path, &options.carmen)?.recording),
        Some(RecordingFormat::Ros1Bag) => Ok(read_ros1_bag(path, &options.ros)?),
        Some(RecordingFormat::Mcap) => Ok(read_mcap(path, &options.ros)?),
        None => Err(ReadError::Unsupported {
            path: path.to_path_buf(),
        }),
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
