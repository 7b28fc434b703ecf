//! TUM trajectory files: one pose per line, `stamp_s x y z qx qy qz qw`; `#` starts a comment.
//!
//! Planar poses are written with z = 0 and the yaw as a rotation about z. Stamps are seconds
//! with nanosecond precision (9 decimals), so `stamp_ns` survives a round trip exactly.

use super::{IoError, parse_finite_f64, write_atomic};
use pfslam::geometry::{Pose2, StampedPose2, Trajectory};
use std::io::{BufRead, Write};
use std::path::Path;

/// Formats a nanosecond stamp as seconds with 9 decimals, exactly.
pub fn format_stamp_s(stamp_ns: i64) -> String {
    let sign = if stamp_ns < 0 { "-" } else { "" };
    let a = stamp_ns.unsigned_abs();
    format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000)
}

/// Parses seconds (decimal text) into nanoseconds exactly (no float rounding) when there are at
/// most 9 decimals; more decimals are rounded to the nanosecond.
pub fn parse_stamp_ns(text: &str) -> Option<i64> {
    let t = text.trim();
    let (neg, t) = match t.strip_prefix('-') {
        Some(r) => (true, r),
        None => (false, t),
    };
    let (int, frac) = match t.split_once('.') {
        Some((i, f)) => (i, f),
        None => (t, ""),
    };
    if int.is_empty() && frac.is_empty() {
        return None;
    }
    if !int.bytes().all(|b| b.is_ascii_digit()) || !frac.bytes().all(|b| b.is_ascii_digit()) {
        // scientific notation etc.: fall back to float
        let v: f64 = text.trim().parse().ok()?;
        if !v.is_finite() {
            return None;
        }
        return Some((v * 1e9).round() as i64);
    }
    let secs: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let mut frac_ns: i64 = 0;
    for (k, b) in frac.bytes().enumerate() {
        if k == 9 {
            if b >= b'5' {
                frac_ns += 1;
            }
            break;
        }
        frac_ns = frac_ns * 10 + i64::from(b - b'0');
    }
    for _ in frac.len()..9 {
        frac_ns *= 10;
    }
    let ns = secs.checked_mul(1_000_000_000)?.checked_add(frac_ns)?;
    Some(if neg { -ns } else { ns })
}

/// Reads a TUM file. Poses must be in non-decreasing time order; the yaw is extracted from
/// the quaternion (roll and pitch are ignored).
pub fn read_tum(path: &Path) -> Result<Trajectory, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    read_tum_from(std::io::BufReader::new(file), path)
}

/// [`read_tum`] from any reader; `path` names the source in errors.
pub fn read_tum_from(reader: impl BufRead, path: &Path) -> Result<Trajectory, IoError> {
    let mut poses: Vec<StampedPose2> = Vec::new();
    for (idx, line) in reader.lines().enumerate() {
        let line_no = idx + 1;
        let line = line.map_err(|e| IoError::io(path, e))?;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = t.split_whitespace().collect();
        if fields.len() != 8 {
            return Err(IoError::parse(
                path,
                line_no,
                format!(
                    "expected 8 fields (stamp_s x y z qx qy qz qw), found {}",
                    fields.len()
                ),
            ));
        }
        let stamp_ns = parse_stamp_ns(fields[0]).ok_or_else(|| {
            IoError::parse(
                path,
                line_no,
                format!("stamp: not a number: {:?}", fields[0]),
            )
        })?;
        let mut v = [0.0f64; 7];
        let names = ["x", "y", "z", "qx", "qy", "qz", "qw"];
        for k in 0..7 {
            v[k] = parse_finite_f64(path, line_no, names[k], fields[k + 1])?;
        }
        let (qx, qy, qz, qw) = (v[3], v[4], v[5], v[6]);
        let norm = (qx * qx + qy * qy + qz * qz + qw * qw).sqrt();
        if norm < 1e-9 {
            return Err(IoError::parse(path, line_no, "quaternion has zero norm"));
        }
        let yaw = (2.0 * (qw * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz));
        if let Some(prev) = poses.last()
            && stamp_ns < prev.stamp_ns
        {
            return Err(IoError::parse(
                path,
                line_no,
                format!(
                    "timestamp goes backwards ({} after {})",
                    format_stamp_s(stamp_ns),
                    format_stamp_s(prev.stamp_ns)
                ),
            ));
        }
        poses.push(StampedPose2 {
            stamp_ns,
            pose: Pose2::new(v[0], v[1], yaw),
        });
    }
    if poses.is_empty() {
        return Err(IoError::parse(path, 0, "no pose in file"));
    }
    Ok(Trajectory::new(poses))
}

/// Writes one TUM line for a planar pose.
pub fn write_tum_line(w: &mut dyn Write, p: &StampedPose2) -> std::io::Result<()> {
    let half = 0.5 * p.pose.yaw_rad;
    writeln!(
        w,
        "{} {:.9} {:.9} 0 0 0 {:.12} {:.12}",
        format_stamp_s(p.stamp_ns),
        p.pose.x_m,
        p.pose.y_m,
        half.sin(),
        half.cos()
    )
}

/// Writes a trajectory as a TUM file, atomically.
pub fn write_tum(path: &Path, poses: &[StampedPose2]) -> Result<(), IoError> {
    write_atomic(path, |w| write_tum_to(w, poses))
}

/// Writes a trajectory as TUM text (the header line, then [`write_tum_line`] per pose): what
/// [`write_tum`] puts in the file.
pub fn write_tum_to(w: &mut dyn Write, poses: &[StampedPose2]) -> std::io::Result<()> {
    writeln!(w, "# stamp_s x y z qx qy qz qw")?;
    for p in poses {
        write_tum_line(w, p)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamp_roundtrip() {
        for ns in [
            0i64,
            1,
            999_999_999,
            1_544_582_648_735_140_000,
            -5,
            123_456_789_012,
        ] {
            assert_eq!(parse_stamp_ns(&format_stamp_s(ns)), Some(ns));
        }
        assert_eq!(parse_stamp_ns("1.5"), Some(1_500_000_000));
        assert_eq!(parse_stamp_ns("abc"), None);
    }

    #[test]
    fn tum_roundtrip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.tum");
        let poses: Vec<StampedPose2> = (0..50)
            .map(|i| StampedPose2 {
                stamp_ns: 1_000_000_000 + i * 12_345_678,
                pose: Pose2::new(i as f64 * 0.3, -(i as f64) * 0.1, i as f64 * 0.2),
            })
            .collect();
        write_tum(&path, &poses).unwrap();
        let back = read_tum(&path).unwrap();
        assert_eq!(back.len(), poses.len());
        for (a, b) in poses.iter().zip(&back.poses) {
            assert_eq!(a.stamp_ns, b.stamp_ns);
            assert!((a.pose.x_m - b.pose.x_m).abs() < 1e-8);
            assert!(pfslam::geometry::wrap_angle(a.pose.yaw_rad - b.pose.yaw_rad).abs() < 1e-9);
        }
    }

    #[test]
    fn tum_bad_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.tum");
        std::fs::write(&path, "0 0 0 0 0 0 0 1\n1 0 0 nan 0 0 0 1\n").unwrap();
        let e = read_tum(&path).unwrap_err().to_string();
        assert!(e.contains("bad.tum:2") && e.contains("z"), "{e}");
    }
}
