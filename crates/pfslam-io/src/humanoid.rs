//! The humanoid's dataset layout (THOR-like: odometry poses, IMU attitude, head joints and a
//! Hokuyo UTM-30LX on the head), defined by pfslam since the original files are not
//! obtainable.
//!
//! ```text
//! <dir>/calibration.txt  head/neck chain and LiDAR geometry, `key = value` lines:
//!     body_to_neck_m = X Y Z        neck yaw joint in the body frame (body origin on the
//!                                   floor under the torso, x forward, z up)
//!     neck_to_head_m = X Y Z        head pitch joint in the neck frame (after the yaw)
//!     head_to_lidar_m = X Y Z       LiDAR origin in the head frame (after the pitch)
//!     lidar_angle_min_rad = A       first beam, counter-clockwise from the head's x axis
//!     lidar_angle_increment_rad = D
//!     lidar_beam_count = N
//!     lidar_range_max_m = R
//! <dir>/odometry.csv    header `timestamp_ns,x_m,y_m,yaw_rad`: odometry poses (drifting)
//! <dir>/imu.csv         header `timestamp_ns,roll_rad,pitch_rad,yaw_rad`: attitude
//!                       (yaw drifts; roll/pitch are gravity-referenced)
//! <dir>/joints.csv      header `timestamp_ns,neck_yaw_rad,head_pitch_rad`: joint angles
//!                       (pitch positive = looking down)
//! <dir>/lidar.csv       header `timestamp_ns,ranges_m...`: one scan per row, N ranges in m,
//!                       0.0 = no return
//! ```
//!
//! The chain: `body_from_lidar = T(body_to_neck) Rz(neck_yaw) T(neck_to_head)
//! Ry(head_pitch) T(head_to_lidar)`; the body's attitude is `Rz(yaw) Ry(pitch) Rx(roll)` from
//! the IMU. `#` starts a comment in `calibration.txt`. Every reader error names `file:line`.
//! Floats are written in shortest round-trip form, so write -> read is exact.

use super::{IoError, parse_finite_f64, parse_i64, write_atomic};
use pfslam::geometry::{Pose2, StampedPose2};
pub use pfslam::sensors::humanoid::{
    HumanoidCalibration, HumanoidDataset, ImuSample, JointSample, humanoid_recording,
};
use pfslam::sensors::{LidarGeometry, ScanSet};
use std::io::Write;
use std::path::Path;

/// Calibration file name.
pub const CALIBRATION_FILE: &str = "calibration.txt";
/// Odometry file name.
pub const ODOMETRY_CSV: &str = "odometry.csv";
/// IMU file name.
pub const IMU_CSV: &str = "imu.csv";
/// Joint angles file name.
pub const JOINTS_CSV: &str = "joints.csv";
/// LiDAR file name.
pub const LIDAR_CSV: &str = "lidar.csv";

const ODOMETRY_HEADER: &str = "timestamp_ns,x_m,y_m,yaw_rad";
const IMU_HEADER: &str = "timestamp_ns,roll_rad,pitch_rad,yaw_rad";
const JOINTS_HEADER: &str = "timestamp_ns,neck_yaw_rad,head_pitch_rad";
const LIDAR_HEADER: &str = "timestamp_ns,ranges_m...";

fn write_vec3(w: &mut dyn Write, key: &str, v: &[f64; 3]) -> std::io::Result<()> {
    writeln!(w, "{key} = {} {} {}", v[0], v[1], v[2])
}

/// Writes the dataset into `dir` (created if needed), every file atomically.
pub fn write_humanoid_dataset(dir: &Path, ds: &HumanoidDataset) -> Result<(), IoError> {
    let c = &ds.calibration;
    write_atomic(&dir.join(CALIBRATION_FILE), |w| {
        writeln!(
            w,
            "# pfslam humanoid head/neck chain (see pfslam_io::humanoid)"
        )?;
        write_vec3(w, "body_to_neck_m", &c.body_to_neck_m)?;
        write_vec3(w, "neck_to_head_m", &c.neck_to_head_m)?;
        write_vec3(w, "head_to_lidar_m", &c.head_to_lidar_m)?;
        writeln!(w, "lidar_angle_min_rad = {}", c.lidar.angle_min_rad)?;
        writeln!(
            w,
            "lidar_angle_increment_rad = {}",
            c.lidar.angle_increment_rad
        )?;
        writeln!(w, "lidar_beam_count = {}", c.lidar.beam_count)?;
        writeln!(w, "lidar_range_max_m = {}", c.lidar.range_max_m)
    })?;
    write_atomic(&dir.join(ODOMETRY_CSV), |w| {
        writeln!(w, "{ODOMETRY_HEADER}")?;
        for p in &ds.odometry {
            writeln!(
                w,
                "{},{},{},{}",
                p.stamp_ns, p.pose.x_m, p.pose.y_m, p.pose.yaw_rad
            )?;
        }
        Ok(())
    })?;
    write_atomic(&dir.join(IMU_CSV), |w| {
        writeln!(w, "{IMU_HEADER}")?;
        for s in &ds.imu {
            writeln!(
                w,
                "{},{},{},{}",
                s.stamp_ns, s.roll_rad, s.pitch_rad, s.yaw_rad
            )?;
        }
        Ok(())
    })?;
    write_atomic(&dir.join(JOINTS_CSV), |w| {
        writeln!(w, "{JOINTS_HEADER}")?;
        for s in &ds.joints {
            writeln!(w, "{},{},{}", s.stamp_ns, s.neck_yaw_rad, s.head_pitch_rad)?;
        }
        Ok(())
    })?;
    write_atomic(&dir.join(LIDAR_CSV), |w| {
        writeln!(w, "{LIDAR_HEADER}")?;
        for i in 0..ds.lidar.len() {
            write!(w, "{}", ds.lidar.stamps_ns[i])?;
            for r in ds.lidar.ranges(i) {
                write!(w, ",{r}")?;
            }
            writeln!(w)?;
        }
        Ok(())
    })
}

fn read_text(path: &Path) -> Result<String, IoError> {
    if !path.exists() {
        return Err(IoError::Missing {
            path: path.to_path_buf(),
            what: "humanoid dataset file".to_string(),
        });
    }
    std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))
}

fn read_calibration(path: &Path, text: &str) -> Result<HumanoidCalibration, IoError> {
    let mut vec3: [Option<[f64; 3]>; 3] = [None; 3];
    let mut scalars: [Option<f64>; 4] = [None; 4];
    const VEC_KEYS: [&str; 3] = ["body_to_neck_m", "neck_to_head_m", "head_to_lidar_m"];
    const SCALAR_KEYS: [&str; 4] = [
        "lidar_angle_min_rad",
        "lidar_angle_increment_rad",
        "lidar_beam_count",
        "lidar_range_max_m",
    ];
    for (idx, raw) in text.lines().enumerate() {
        let line_no = idx + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let (key, value) = content
            .split_once('=')
            .ok_or_else(|| IoError::parse(path, line_no, "expected `key = value`"))?;
        let key = key.trim();
        if let Some(k) = VEC_KEYS.iter().position(|&v| v == key) {
            let parts: Vec<&str> = value.split_whitespace().collect();
            if parts.len() != 3 {
                return Err(IoError::parse(
                    path,
                    line_no,
                    format!("{key}: expected 3 numbers"),
                ));
            }
            let mut v = [0.0; 3];
            for (j, p) in parts.iter().enumerate() {
                v[j] = parse_finite_f64(path, line_no, key, p)?;
            }
            vec3[k] = Some(v);
        } else if let Some(k) = SCALAR_KEYS.iter().position(|&v| v == key) {
            scalars[k] = Some(parse_finite_f64(path, line_no, key, value)?);
        } else {
            return Err(IoError::parse(
                path,
                line_no,
                format!("unknown key {key:?}"),
            ));
        }
    }
    let missing = |k: &str| IoError::parse(path, 0, format!("missing key {k:?}"));
    let v = |k: usize| vec3[k].ok_or_else(|| missing(VEC_KEYS[k]));
    let s = |k: usize| scalars[k].ok_or_else(|| missing(SCALAR_KEYS[k]));
    let beam_count = s(2)?;
    if !(beam_count >= 1.0 && beam_count.fract() == 0.0 && beam_count <= 100_000.0) {
        return Err(IoError::parse(
            path,
            0,
            "lidar_beam_count must be a positive integer",
        ));
    }
    let range_max = s(3)?;
    if range_max <= 0.0 {
        return Err(IoError::parse(
            path,
            0,
            "lidar_range_max_m must be positive",
        ));
    }
    Ok(HumanoidCalibration {
        body_to_neck_m: v(0)?,
        neck_to_head_m: v(1)?,
        head_to_lidar_m: v(2)?,
        lidar: LidarGeometry {
            angle_min_rad: s(0)?,
            angle_increment_rad: s(1)?,
            beam_count: beam_count as usize,
            range_min_m: 2.0,
            range_max_m: range_max as f32,
        },
    })
}

/// Reads a CSV with the given header: calls `row(line_no, fields)` for every data row and
/// checks that stamps do not go backwards.
fn read_rows<F>(path: &Path, text: &str, header: &str, mut row: F) -> Result<(), IoError>
where
    F: FnMut(usize, i64, &[&str]) -> Result<(), IoError>,
{
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == header => {}
        _ => {
            return Err(IoError::parse(
                path,
                1,
                format!("expected the header {header:?}"),
            ));
        }
    }
    let mut prev: Option<i64> = None;
    let mut fields: Vec<&str> = Vec::new();
    for (idx, line) in lines {
        let line_no = idx + 1;
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        fields.clear();
        fields.extend(t.split(','));
        let stamp = parse_i64(path, line_no, "timestamp_ns", fields[0])?;
        if let Some(p) = prev
            && stamp < p
        {
            return Err(IoError::parse(path, line_no, "timestamp goes backwards"));
        }
        prev = Some(stamp);
        row(line_no, stamp, &fields[1..])?;
    }
    Ok(())
}

fn parse_fields<const N: usize>(
    path: &Path,
    line_no: usize,
    names: [&str; N],
    fields: &[&str],
) -> Result<[f64; N], IoError> {
    if fields.len() != N {
        return Err(IoError::parse(
            path,
            line_no,
            format!("expected {} fields, found {}", N + 1, fields.len() + 1),
        ));
    }
    let mut v = [0.0; N];
    for k in 0..N {
        v[k] = parse_finite_f64(path, line_no, names[k], fields[k])?;
    }
    Ok(v)
}

/// Reads a dataset written by [`write_humanoid_dataset`] (or by hand in that layout).
pub fn read_humanoid_dataset(dir: &Path) -> Result<HumanoidDataset, IoError> {
    read_humanoid_dataset_with(dir, read_text)
}

/// [`read_humanoid_dataset`] with each file's text from `read_file` (given the file's path).
pub fn read_humanoid_dataset_with(
    dir: &Path,
    read_file: impl Fn(&Path) -> Result<String, IoError>,
) -> Result<HumanoidDataset, IoError> {
    let p = dir.join(CALIBRATION_FILE);
    let calibration = read_calibration(&p, &read_file(&p)?)?;
    let mut odometry = Vec::new();
    let p = dir.join(ODOMETRY_CSV);
    read_rows(&p, &read_file(&p)?, ODOMETRY_HEADER, |ln, stamp_ns, f| {
        let [x, y, yaw] = parse_fields(&p, ln, ["x_m", "y_m", "yaw_rad"], f)?;
        odometry.push(StampedPose2 {
            stamp_ns,
            pose: Pose2 {
                x_m: x,
                y_m: y,
                yaw_rad: yaw,
            },
        });
        Ok(())
    })?;
    let mut imu = Vec::new();
    let p = dir.join(IMU_CSV);
    read_rows(&p, &read_file(&p)?, IMU_HEADER, |ln, stamp_ns, f| {
        let [roll_rad, pitch_rad, yaw_rad] =
            parse_fields(&p, ln, ["roll_rad", "pitch_rad", "yaw_rad"], f)?;
        imu.push(ImuSample {
            stamp_ns,
            roll_rad,
            pitch_rad,
            yaw_rad,
        });
        Ok(())
    })?;
    let mut joints = Vec::new();
    let p = dir.join(JOINTS_CSV);
    read_rows(&p, &read_file(&p)?, JOINTS_HEADER, |ln, stamp_ns, f| {
        let [neck_yaw_rad, head_pitch_rad] =
            parse_fields(&p, ln, ["neck_yaw_rad", "head_pitch_rad"], f)?;
        joints.push(JointSample {
            stamp_ns,
            neck_yaw_rad,
            head_pitch_rad,
        });
        Ok(())
    })?;
    let nb = calibration.lidar.beam_count;
    let mut lidar = ScanSet::new(nb);
    let p = dir.join(LIDAR_CSV);
    let mut buf: Vec<f32> = Vec::with_capacity(nb);
    read_rows(&p, &read_file(&p)?, LIDAR_HEADER, |ln, stamp_ns, f| {
        if f.len() != nb {
            return Err(IoError::parse(
                &p,
                ln,
                format!("expected {nb} ranges, found {}", f.len()),
            ));
        }
        buf.clear();
        for (k, t) in f.iter().enumerate() {
            let v: f32 = t
                .trim()
                .parse()
                .map_err(|_| IoError::parse(&p, ln, format!("range {k}: not a number: {t:?}")))?;
            if !v.is_finite() || v < 0.0 {
                return Err(IoError::parse(
                    &p,
                    ln,
                    format!("range {k}: must be finite and >= 0: {t:?}"),
                ));
            }
            buf.push(v);
        }
        lidar.push(stamp_ns, &buf);
        Ok(())
    })?;
    Ok(HumanoidDataset {
        calibration,
        odometry,
        imu,
        joints,
        lidar,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_files_name_line() {
        let dir = tempfile::tempdir().unwrap();
        let ds = HumanoidDataset {
            calibration: HumanoidCalibration::default(),
            odometry: vec![],
            imu: vec![],
            joints: vec![],
            lidar: ScanSet::new(1081),
        };
        write_humanoid_dataset(dir.path(), &ds).unwrap();
        assert_eq!(read_humanoid_dataset(dir.path()).unwrap(), ds);
        std::fs::write(
            dir.path().join(JOINTS_CSV),
            format!("{JOINTS_HEADER}\n1,0.1,0.2\n2,0.1\n"),
        )
        .unwrap();
        let e = read_humanoid_dataset(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("joints.csv:3") && e.contains("expected 3 fields"),
            "{e}"
        );
        std::fs::write(dir.path().join(JOINTS_CSV), format!("{JOINTS_HEADER}\n")).unwrap();
        std::fs::write(dir.path().join(CALIBRATION_FILE), "body_to_neck_m = 0 0\n").unwrap();
        let e = read_humanoid_dataset(dir.path()).unwrap_err().to_string();
        assert!(e.contains("calibration.txt:1"), "{e}");
    }
}
