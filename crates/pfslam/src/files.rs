//! What every file reader and writer shares, independent of any format: [`IoError`] naming the
//! file, the line (1-based) and the problem; atomic writes ([`write_atomic`]: a temporary file
//! in the target directory renamed into place, so a failed or interrupted write leaves no
//! half-written file); number fields parsed with precise errors; and where the real recordings
//! live ([`data_root`]). The formats themselves are the `pfslam-io` crate's.

use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Errors of reading and writing files.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// A file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The content of a file is malformed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number (0 when the problem concerns the whole file).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A required file is missing.
    #[error("{path}: missing file ({what})")]
    Missing {
        /// The file that should exist.
        path: PathBuf,
        /// What it should contain.
        what: String,
    },
}

impl IoError {
    /// A parse error at `path:line`.
    pub fn parse(path: &Path, line: usize, message: impl fmt::Display) -> Self {
        IoError::Parse {
            path: path.to_path_buf(),
            line,
            message: message.to_string(),
        }
    }

    /// An operating-system error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Writes a file atomically: the bytes go to a temporary file beside `path`, which is then
/// renamed over `path`. `fill` writes the content into the buffered writer it is given.
pub fn write_atomic<F>(path: &Path, fill: F) -> Result<(), IoError>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|e| IoError::io(&dir, e))?;
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".to_string());
    let tmp = dir.join(format!(".{file_name}.tmp{}", std::process::id()));
    let result = (|| -> std::io::Result<()> {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        w.flush()?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(IoError::io(path, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        IoError::io(path, e)
    })
}

/// Writes bytes atomically (see [`write_atomic`]).
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// Where the real recordings live: `$PFSLAM_DATA` if set, else `shared/data` beside the
/// workspace root, found from a crate's `CARGO_MANIFEST_DIR` (`<root>/crates/<crate>`).
/// Returns `None` when the directory does not exist.
pub fn data_root(manifest_dir: &str) -> Option<PathBuf> {
    let dir = match std::env::var_os("PFSLAM_DATA") {
        Some(d) => PathBuf::from(d),
        None => Path::new(manifest_dir).join("../../../shared/data"),
    };
    dir.is_dir().then_some(dir)
}

/// Parses a float field, rejecting NaN and infinities, with a precise error.
pub fn parse_finite_f64(path: &Path, line: usize, field: &str, text: &str) -> Result<f64, IoError> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| IoError::parse(path, line, format!("{field}: not a number: {text:?}")))?;
    if !v.is_finite() {
        return Err(IoError::parse(
            path,
            line,
            format!("{field}: not finite: {text:?}"),
        ));
    }
    Ok(v)
}

/// Parses an integer field with a precise error.
pub fn parse_i64(path: &Path, line: usize, field: &str, text: &str) -> Result<i64, IoError> {
    text.trim()
        .parse()
        .map_err(|_| IoError::parse(path, line, format!("{field}: not an integer: {text:?}")))
}
