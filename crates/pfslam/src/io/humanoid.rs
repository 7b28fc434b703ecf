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
use crate::geometry::{Pose2, Rigid3, StampedPose2, Trajectory};
use crate::sensors::{LidarGeometry, Recording, ScanSet};
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

/// The head/neck chain and the head LiDAR.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HumanoidCalibration {
    /// Neck yaw joint in the body frame (m).
    pub body_to_neck_m: [f64; 3],
    /// Head pitch joint in the neck frame (m).
    pub neck_to_head_m: [f64; 3],
    /// LiDAR origin in the head frame (m).
    pub head_to_lidar_m: [f64; 3],
    /// LiDAR beams.
    pub lidar: LidarGeometry,
}

impl Default for HumanoidCalibration {
    /// A THOR-like head: neck at 1.25 m, a Hokuyo UTM-30LX (1081 beams over 270 deg, 30 m)
    /// 12 cm above and 5 cm in front of the pitch axis.
    fn default() -> Self {
        HumanoidCalibration {
            body_to_neck_m: [0.0, 0.0, 1.25],
            neck_to_head_m: [0.0, 0.0, 0.08],
            head_to_lidar_m: [0.05, 0.0, 0.12],
            lidar: LidarGeometry {
                angle_min_rad: (-135.0f64).to_radians(),
                angle_increment_rad: 0.25f64.to_radians(),
                beam_count: 1081,
                range_min_m: 2.0,
                range_max_m: 30.0,
            },
        }
    }
}

impl HumanoidCalibration {
    /// The LiDAR in the body frame for these joint angles.
    pub fn body_from_lidar(&self, neck_yaw_rad: f64, head_pitch_rad: f64) -> Rigid3 {
        let neck = Rigid3::from_rpy(0.0, 0.0, neck_yaw_rad, self.body_to_neck_m);
        let head = Rigid3::from_rpy(0.0, head_pitch_rad, 0.0, self.neck_to_head_m);
        let lidar = Rigid3::from_rpy(0.0, 0.0, 0.0, self.head_to_lidar_m);
        neck.compose(&head).compose(&lidar)
    }
}

/// One row of `joints.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointSample {
    /// Time (ns).
    pub stamp_ns: i64,
    /// Neck yaw (rad, counter-clockwise).
    pub neck_yaw_rad: f64,
    /// Head pitch (rad, positive = looking down).
    pub head_pitch_rad: f64,
}

/// One row of `imu.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Time (ns).
    pub stamp_ns: i64,
    /// Roll (rad).
    pub roll_rad: f64,
    /// Pitch (rad).
    pub pitch_rad: f64,
    /// Yaw (rad).
    pub yaw_rad: f64,
}

/// A humanoid recording.
#[derive(Debug, Clone, PartialEq)]
pub struct HumanoidDataset {
    /// Head chain and LiDAR.
    pub calibration: HumanoidCalibration,
    /// Odometry poses.
    pub odometry: Vec<StampedPose2>,
    /// IMU attitude.
    pub imu: Vec<ImuSample>,
    /// Head joint angles.
    pub joints: Vec<JointSample>,
    /// LiDAR scans.
    pub lidar: ScanSet,
}

fn write_vec3(w: &mut dyn Write, key: &str, v: &[f64; 3]) -> std::io::Result<()> {
    writeln!(w, "{key} = {} {} {}", v[0], v[1], v[2])
}

/// Writes the dataset into `dir` (created if needed), every file atomically.
pub fn write_humanoid_dataset(dir: &Path, ds: &HumanoidDataset) -> Result<(), IoError> {
    let c = &ds.calibration;
    write_atomic(&dir.join(CALIBRATION_FILE), |w| {
        writeln!(
            w,
            "# pfslam humanoid head/neck chain (see pfslam::io::humanoid)"
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

/// Linear interpolation of a sampled signal at `stamp_ns` (clamped at the ends); `None` when
/// there is no sample.
fn interpolate<T, const N: usize>(
    samples: &[T],
    stamp_ns: i64,
    get: impl Fn(&T) -> (i64, [f64; N]),
) -> Option<[f64; N]> {
    let first = samples.first()?;
    let i = samples.partition_point(|s| get(s).0 <= stamp_ns);
    if i == 0 {
        return Some(get(first).1);
    }
    let (ta, a) = get(&samples[i - 1]);
    if i == samples.len() || ta == stamp_ns {
        return Some(a);
    }
    let (tb, b) = get(&samples[i]);
    let f = (stamp_ns - ta) as f64 / (tb - ta) as f64;
    let mut out = [0.0; N];
    for k in 0..N {
        out[k] = a[k] + f * (b[k] - a[k]);
    }
    Some(out)
}

/// The common [`Recording`] of a humanoid dataset: odometry poses, IMU yaw, scans, and a
/// per-scan LiDAR mount from the joint angles (interpolated at each scan stamp) tilted by the
/// IMU's roll and pitch — i.e. the LiDAR in the gravity-levelled body frame, so a `z` filter
/// on the mapped points removes floor hits. No ground truth (the simulator adds it).
pub fn humanoid_recording(ds: &HumanoidDataset, name: &str) -> Recording {
    let cal = &ds.calibration;
    let per_scan: Vec<Rigid3> = ds
        .lidar
        .stamps_ns
        .iter()
        .map(|&t| {
            let [yaw, pitch] = interpolate(&ds.joints, t, |j| {
                (j.stamp_ns, [j.neck_yaw_rad, j.head_pitch_rad])
            })
            .unwrap_or([0.0, 0.0]);
            let [roll_b, pitch_b] =
                interpolate(&ds.imu, t, |s| (s.stamp_ns, [s.roll_rad, s.pitch_rad]))
                    .unwrap_or([0.0, 0.0]);
            let level_from_body = Rigid3::from_rpy(roll_b, pitch_b, 0.0, [0.0, 0.0, 0.0]);
            level_from_body.compose(&cal.body_from_lidar(yaw, pitch))
        })
        .collect();
    Recording {
        name: name.to_string(),
        odometry: Trajectory::new(ds.odometry.clone()),
        imu_yaw: Some(ds.imu.iter().map(|s| (s.stamp_ns, s.yaw_rad)).collect()),
        scans: ds.lidar.clone(),
        lidar: cal.lidar,
        body_from_lidar: cal.body_from_lidar(0.0, 0.0),
        body_from_lidar_per_scan: Some(per_scan),
        lidar_per_scan: None,
        ground_truth: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chain_looks_down_when_pitched() {
        let c = HumanoidCalibration::default();
        let t = c.body_from_lidar(0.0, 0.3);
        // beam 540 points straight ahead in the LiDAR frame
        let d = t.rotation * nalgebra::Vector3::new(1.0, 0.0, 0.0);
        assert!((d[2] + 0.3f64.sin()).abs() < 1e-12);
        let t = c.body_from_lidar(std::f64::consts::FRAC_PI_2, 0.0);
        let d = t.rotation * nalgebra::Vector3::new(1.0, 0.0, 0.0);
        assert!((d[1] - 1.0).abs() < 1e-12);
        let o = t.translation;
        assert!((o[2] - 1.45).abs() < 1e-12 && (o[1] - 0.05).abs() < 1e-12);
    }

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
