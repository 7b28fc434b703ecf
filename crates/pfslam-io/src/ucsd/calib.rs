//! The car's calibration files, parsed exactly as the course distributed them (free-text
//! headers, `key: value` lines, `RPY:`/`R:`/`T:` lines, a stereo baseline in millimetres with
//! a CRLF line end), and written back in the same layout.

use crate::opencv_yaml::{read_camera_yaml, write_camera_yaml};
use crate::{IoError, parse_finite_f64, write_atomic};
use pfslam::geometry::Rigid3;
use pfslam::sensors::{CarCalibration, EncoderParams, LidarGeometry, StereoCalibration};
use std::path::{Path, PathBuf};

/// `param/EncoderParameter.txt`.
pub const ENCODER_PARAM_FILE: &str = "EncoderParameter.txt";
/// `param/Vehicle2FOG.txt`.
pub const VEHICLE2FOG_FILE: &str = "Vehicle2FOG.txt";
/// `param/Vehicle2Lidar.txt`.
pub const VEHICLE2LIDAR_FILE: &str = "Vehicle2Lidar.txt";
/// `param/lidar_param.txt`.
pub const LIDAR_PARAM_FILE: &str = "lidar_param.txt";
/// `param/Vehicle2Stereo.txt`.
pub const VEHICLE2STEREO_FILE: &str = "Vehicle2Stereo.txt";
/// `param/stereo_param.txt`.
pub const STEREO_PARAM_FILE: &str = "stereo_param.txt";
/// `param/left_camera.yaml`.
pub const LEFT_CAMERA_FILE: &str = "left_camera.yaml";
/// `param/right_camera.yaml`.
pub const RIGHT_CAMERA_FILE: &str = "right_camera.yaml";

/// Most beams a LiDAR row may hold: far above any planar LiDAR's, low enough that a typo
/// cannot make the readers allocate gigabytes per row.
pub const MAX_BEAM_COUNT: usize = 1 << 16;

/// The `key: value` lines of a calibration file (lines without a colon are free text).
struct KeyValues {
    path: PathBuf,
    /// (lower-case key, 1-based line, value text)
    entries: Vec<(String, usize, String)>,
}

impl KeyValues {
    fn parse(text: &str, path: &Path) -> Result<KeyValues, IoError> {
        let mut entries: Vec<(String, usize, String)> = Vec::new();
        for (idx, raw) in text.lines().enumerate() {
            let line = raw.trim_end_matches('\r').trim();
            // Free-text lines ("* The encoder data is stored as ...") carry no key.
            if line.is_empty() || line.starts_with('*') {
                continue;
            }
            let Some((key, value)) = line.split_once(':') else {
                continue;
            };
            let key = key.trim().to_ascii_lowercase();
            if entries.iter().any(|(k, _, _)| *k == key) {
                return Err(IoError::parse(
                    path,
                    idx + 1,
                    format!("key {key:?} appears twice"),
                ));
            }
            entries.push((key, idx + 1, value.trim().to_string()));
        }
        Ok(KeyValues {
            path: path.to_path_buf(),
            entries,
        })
    }

    fn get(&self, key: &str) -> Option<(usize, &str)> {
        let key = key.to_ascii_lowercase();
        self.entries
            .iter()
            .find(|(k, _, _)| *k == key)
            .map(|(_, l, v)| (*l, v.as_str()))
    }

    fn require(&self, key: &str) -> Result<(usize, &str), IoError> {
        self.get(key).ok_or_else(|| {
            IoError::parse(&self.path, 0, format!("missing calibration key {key:?}"))
        })
    }

    /// The first number of a value such as `190 (degree)`.
    fn number(&self, key: &str) -> Result<(f64, &str), IoError> {
        let (line, value) = self.require(key)?;
        let first = value.split_whitespace().next().unwrap_or("");
        Ok((parse_finite_f64(&self.path, line, key, first)?, first))
    }

    /// Exactly `n` whitespace-separated numbers.
    fn numbers(&self, key: &str, n: usize) -> Result<Option<Vec<f64>>, IoError> {
        let Some((line, value)) = self.get(key) else {
            return Ok(None);
        };
        let fields: Vec<&str> = value.split_whitespace().collect();
        if fields.len() != n {
            return Err(IoError::parse(
                &self.path,
                line,
                format!("{key}: expected {n} numbers, found {}", fields.len()),
            ));
        }
        fields
            .iter()
            .map(|f| parse_finite_f64(&self.path, line, key, f))
            .collect::<Result<Vec<_>, _>>()
            .map(Some)
    }
}

fn read_text(path: &Path, what: &str) -> Result<String, IoError> {
    match std::fs::read(path) {
        Ok(bytes) => String::from_utf8(bytes)
            .map_err(|e| IoError::parse(path, 0, format!("not UTF-8 text: {e}"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(IoError::Missing {
            path: path.to_path_buf(),
            what: what.to_string(),
        }),
        Err(e) => Err(IoError::io(path, e)),
    }
}

/// Parses `EncoderParameter.txt`.
pub fn read_encoder_params(path: &Path) -> Result<EncoderParams, IoError> {
    parse_encoder_params(&read_text(path, "encoder calibration")?, path)
}

/// [`read_encoder_params`] on a file's text; `path` names it in errors.
pub fn parse_encoder_params(text: &str, path: &Path) -> Result<EncoderParams, IoError> {
    let kv = KeyValues::parse(text, path)?;
    let (line, res_text) = kv.require("Encoder resolution")?;
    let resolution_ticks: u32 = res_text.trim().parse().map_err(|_| {
        IoError::parse(
            path,
            line,
            format!("Encoder resolution: not a positive integer: {res_text:?}"),
        )
    })?;
    if resolution_ticks == 0 {
        return Err(IoError::parse(path, line, "Encoder resolution is 0"));
    }
    let positive = |key: &str| -> Result<f64, IoError> {
        let (v, _) = kv.number(key)?;
        if v <= 0.0 {
            let (line, _) = kv.require(key)?;
            return Err(IoError::parse(path, line, format!("{key}: must be > 0")));
        }
        Ok(v)
    };
    Ok(EncoderParams {
        resolution_ticks,
        left_wheel_diameter_m: positive("Encoder left wheel diameter")?,
        right_wheel_diameter_m: positive("Encoder right wheel diameter")?,
        wheel_base_m: positive("Encoder wheel base")?,
    })
}

/// Parses a `Vehicle2*.txt` extrinsic file into `body_from_sensor`. The `R:` line
/// (row-major) is authoritative; without it the `RPY:` line (degrees, XYZ extrinsic) is used.
pub fn read_extrinsic(path: &Path) -> Result<Rigid3, IoError> {
    parse_extrinsic(&read_text(path, "extrinsic calibration")?, path)
}

/// [`read_extrinsic`] on a file's text; `path` names it in errors.
pub fn parse_extrinsic(text: &str, path: &Path) -> Result<Rigid3, IoError> {
    let kv = KeyValues::parse(text, path)?;
    let t = kv
        .numbers("T", 3)?
        .ok_or_else(|| IoError::parse(path, 0, "missing calibration key \"T\""))?;
    let translation = [t[0], t[1], t[2]];
    let rpy = kv.numbers("RPY", 3)?;
    if let Some(r) = kv.numbers("R", 9)? {
        let mut rot = [0.0; 9];
        rot.copy_from_slice(&r);
        return Ok(Rigid3::from_row_major(rot, translation));
    }
    match rpy {
        Some(a) => Ok(Rigid3::from_rpy(
            a[0].to_radians(),
            a[1].to_radians(),
            a[2].to_radians(),
            translation,
        )),
        None => Err(IoError::parse(
            path,
            0,
            "missing calibration key \"R\" (and no \"RPY\")",
        )),
    }
}

/// Parses `lidar_param.txt`. The beam count is `Beam count:` when present (written by
/// [`write_car_calibration`]), else `floor(FOV / resolution) + 1` (286 for the real file).
pub fn read_lidar_params(path: &Path) -> Result<LidarGeometry, IoError> {
    parse_lidar_params(&read_text(path, "LiDAR parameters")?, path)
}

/// [`read_lidar_params`] on a file's text; `path` names it in errors.
pub fn parse_lidar_params(text: &str, path: &Path) -> Result<LidarGeometry, IoError> {
    let kv = KeyValues::parse(text, path)?;
    let (start_deg, _) = kv.number("Start angle")?;
    let (res_deg, _) = kv.number("Angular resolution")?;
    let (fov_deg, _) = kv.number("FOV")?;
    let (max_m, _) = kv.number("Max range")?;
    let (res_line, _) = kv.require("Angular resolution")?;
    if res_deg <= 0.0 {
        return Err(IoError::parse(
            path,
            res_line,
            "Angular resolution must be > 0",
        ));
    }
    if max_m <= 0.0 {
        let (l, _) = kv.require("Max range")?;
        return Err(IoError::parse(path, l, "Max range must be > 0"));
    }
    let beam_count = match kv.get("Beam count") {
        Some((line, text)) => match text.trim().parse::<usize>() {
            Ok(n) if (1..=MAX_BEAM_COUNT).contains(&n) => n,
            _ => {
                return Err(IoError::parse(
                    path,
                    line,
                    format!("Beam count: not an integer in 1..={MAX_BEAM_COUNT}: {text:?}"),
                ));
            }
        },
        None => {
            let (l, _) = kv.require("FOV")?;
            if fov_deg <= 0.0 {
                return Err(IoError::parse(path, l, "FOV must be > 0"));
            }
            let intervals = (fov_deg / res_deg + 1e-9).floor();
            if intervals >= MAX_BEAM_COUNT as f64 {
                return Err(IoError::parse(
                    path,
                    l,
                    format!("FOV / Angular resolution gives over {MAX_BEAM_COUNT} beams"),
                ));
            }
            intervals as usize + 1
        }
    };
    Ok(LidarGeometry {
        angle_min_rad: start_deg.to_radians(),
        angle_increment_rad: res_deg.to_radians(),
        beam_count,
        range_min_m: 2.0,
        range_max_m: max_m as f32,
    })
}

/// Parses `stereo_param.txt`: the baseline in millimetres, returned in metres. The
/// conversion shifts the decimal point in the text, so no rounding is added.
pub fn read_stereo_baseline_m(path: &Path) -> Result<f64, IoError> {
    parse_stereo_baseline_m(&read_text(path, "stereo baseline")?, path)
}

/// [`read_stereo_baseline_m`] on a file's text; `path` names it in errors.
pub fn parse_stereo_baseline_m(text: &str, path: &Path) -> Result<f64, IoError> {
    let kv = KeyValues::parse(text, path)?;
    let key = "Baseline of stereo cameras";
    let (line, value) = kv.require(key)?;
    let first = value.split_whitespace().next().unwrap_or("");
    let mm = parse_finite_f64(path, line, key, first)?;
    if mm <= 0.0 {
        return Err(IoError::parse(path, line, "baseline must be > 0"));
    }
    let shifted = shift_decimal(first, -3).unwrap_or_else(|| (mm / 1000.0).to_string());
    parse_finite_f64(path, line, key, &shifted)
}

/// Moves the decimal point of a plain decimal number `by` places (negative: divide by 10^k),
/// as text. `None` for exponent notation or anything unusual.
fn shift_decimal(text: &str, by: i32) -> Option<String> {
    let t = text.trim();
    let (sign, t) = match t.strip_prefix('-') {
        Some(r) => ("-", r),
        None => ("", t.strip_prefix('+').unwrap_or(t)),
    };
    let (int, frac) = t.split_once('.').unwrap_or((t, ""));
    if int.is_empty() && frac.is_empty()
        || !int.bytes().all(|b| b.is_ascii_digit())
        || !frac.bytes().all(|b| b.is_ascii_digit())
    {
        return None;
    }
    let digits: String = format!("{int}{frac}");
    let point = int.len() as i64 + i64::from(by);
    let padded: String;
    let (digits, point) = if point <= 0 {
        padded = format!("{}{}", "0".repeat((1 - point) as usize), digits);
        (padded.as_str(), 1)
    } else if point as usize > digits.len() {
        padded = format!("{}{}", digits, "0".repeat(point as usize - digits.len()));
        (padded.as_str(), point)
    } else {
        (digits.as_str(), point)
    };
    let (i, f) = digits.split_at(point as usize);
    let i = i.trim_start_matches('0');
    let i = if i.is_empty() { "0" } else { i };
    Some(if f.is_empty() {
        format!("{sign}{i}")
    } else {
        format!("{sign}{i}.{f}")
    })
}

/// Reads every calibration file of a `param/` directory. The stereo files are optional as a
/// group: absent together gives `stereo: None`; some present and some missing is an error.
pub fn read_car_calibration(param_dir: &Path) -> Result<CarCalibration, IoError> {
    let encoder = read_encoder_params(&param_dir.join(ENCODER_PARAM_FILE))?;
    let body_from_fog = read_extrinsic(&param_dir.join(VEHICLE2FOG_FILE))?;
    let body_from_lidar = read_extrinsic(&param_dir.join(VEHICLE2LIDAR_FILE))?;
    let lidar = read_lidar_params(&param_dir.join(LIDAR_PARAM_FILE))?;
    let stereo_files = [
        VEHICLE2STEREO_FILE,
        STEREO_PARAM_FILE,
        LEFT_CAMERA_FILE,
        RIGHT_CAMERA_FILE,
    ];
    let present = stereo_files
        .iter()
        .filter(|f| param_dir.join(f).exists())
        .count();
    let stereo = if present == 0 {
        None
    } else {
        if let Some(missing) = stereo_files.iter().find(|f| !param_dir.join(f).exists()) {
            return Err(IoError::Missing {
                path: param_dir.join(missing),
                what: "stereo calibration (the other stereo files are present)".to_string(),
            });
        }
        Some(StereoCalibration {
            left: read_camera_yaml(&param_dir.join(LEFT_CAMERA_FILE))?,
            right: read_camera_yaml(&param_dir.join(RIGHT_CAMERA_FILE))?,
            baseline_m: read_stereo_baseline_m(&param_dir.join(STEREO_PARAM_FILE))?,
            body_from_camera: read_extrinsic(&param_dir.join(VEHICLE2STEREO_FILE))?,
        })
    };
    Ok(CarCalibration {
        encoder,
        body_from_fog,
        body_from_lidar,
        lidar,
        stereo,
    })
}

/// Shortest decimal text for `value` converted by `to_file`, such that `from_file` of the
/// parsed text gives `value` back bit for bit when a nearby representation allows it
/// (degrees <-> radians are not exact inverses in floating point).
fn lossless_text(value: f64, to_file: fn(f64) -> f64, from_file: fn(f64) -> f64) -> String {
    let guess = to_file(value);
    let mut candidate = guess;
    let mut up = guess;
    let mut down = guess;
    for _ in 0..16 {
        for c in [candidate, up, down] {
            let text = format!("{c}");
            if text.parse::<f64>().map(from_file) == Ok(value) {
                return text;
            }
        }
        up = up.next_up();
        down = down.next_down();
        candidate = up;
    }
    format!("{guess}")
}

fn deg_text(rad: f64) -> String {
    lossless_text(rad, f64::to_degrees, f64::to_radians)
}

fn write_extrinsic(
    path: &Path,
    header: &str,
    t_unit: &str,
    body_from_sensor: &Rigid3,
) -> Result<(), IoError> {
    let rot = nalgebra::Rotation3::from_matrix_unchecked(body_from_sensor.rotation);
    let (roll, pitch, yaw) = rot.euler_angles();
    let r = body_from_sensor.rotation_row_major();
    let t = body_from_sensor.translation;
    write_atomic(path, |w| {
        writeln!(w, "{header}")?;
        writeln!(
            w,
            "RPY(roll/pitch/yaw = XYZ extrinsic, degree), R(rotation matrix), T(translation matrix{t_unit})"
        )?;
        writeln!(
            w,
            "RPY: {} {} {}",
            roll.to_degrees(),
            pitch.to_degrees(),
            yaw.to_degrees()
        )?;
        write!(w, "R:")?;
        for v in r {
            write!(w, " {v}")?;
        }
        writeln!(w, " ")?;
        writeln!(w, "T: {} {} {}", t[0], t[1], t[2])
    })
}

/// Writes every calibration file into `param_dir` in the layout of the real files (camera
/// YAML and baseline only when `cal.stereo` is `Some`).
pub fn write_car_calibration(param_dir: &Path, cal: &CarCalibration) -> Result<(), IoError> {
    let e = &cal.encoder;
    write_atomic(&param_dir.join(ENCODER_PARAM_FILE), |w| {
        writeln!(w, "Encoder calibrated parameter")?;
        writeln!(w, "Encoder resolution: {}", e.resolution_ticks)?;
        writeln!(
            w,
            "Encoder left wheel diameter: {}",
            e.left_wheel_diameter_m
        )?;
        writeln!(
            w,
            "Encoder right wheel diameter: {}",
            e.right_wheel_diameter_m
        )?;
        writeln!(w, "Encoder wheel base: {}", e.wheel_base_m)?;
        writeln!(w)?;
        writeln!(
            w,
            "* The encoder data is stored as [timestamp, left count, right count]."
        )
    })?;
    write_extrinsic(
        &param_dir.join(VEHICLE2FOG_FILE),
        "FOG (Fiber Optic Gyro) extrinsic calibration parameter from vehicle",
        ", meter",
        &cal.body_from_fog,
    )?;
    write_extrinsic(
        &param_dir.join(VEHICLE2LIDAR_FILE),
        "Lidar sensor (LMS511) extrinsic calibration parameter from vehicle",
        "",
        &cal.body_from_lidar,
    )?;
    let l = &cal.lidar;
    let start = deg_text(l.angle_min_rad);
    let res = deg_text(l.angle_increment_rad);
    let fov_deg = (l.beam_count.saturating_sub(1)) as f64 * l.angle_increment_rad.to_degrees();
    write_atomic(&param_dir.join(LIDAR_PARAM_FILE), |w| {
        writeln!(w, "FOV: {} (degree)", fov_deg)?;
        writeln!(w, "Start angle: {start} (degree)")?;
        writeln!(
            w,
            "End angle: {} (degree)",
            l.angle_min_rad.to_degrees() + fov_deg
        )?;
        writeln!(w, "Angular resolution: {res} (degree)")?;
        writeln!(w, "Max range: {} (meter)", l.range_max_m)?;
        writeln!(w, "Beam count: {}", l.beam_count)?;
        writeln!(w)?;
        writeln!(
            w,
            "* LiDAR rays with value 0.0 represent infinite range observations."
        )
    })?;
    if let Some(s) = &cal.stereo {
        write_extrinsic(
            &param_dir.join(VEHICLE2STEREO_FILE),
            "Stereo camera (based on left camera) extrinsic calibration parameter from vehicle",
            "",
            &s.body_from_camera,
        )?;
        let m_text = format!("{}", s.baseline_m);
        let mm_text =
            shift_decimal(&m_text, 3).unwrap_or_else(|| format!("{}", s.baseline_m * 1e3));
        // The real file ends its only line with CRLF.
        write_atomic(&param_dir.join(STEREO_PARAM_FILE), |w| {
            write!(w, "Baseline of stereo cameras: {mm_text} (mm)\r\n")
        })?;
        write_camera_yaml(&param_dir.join(LEFT_CAMERA_FILE), "/stereo/left", &s.left)?;
        write_camera_yaml(
            &param_dir.join(RIGHT_CAMERA_FILE),
            "/stereo/right",
            &s.right,
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shift_decimal_cases() {
        assert_eq!(
            shift_decimal("475.143600050775", -3).unwrap(),
            "0.475143600050775"
        );
        assert_eq!(
            shift_decimal("0.475143600050775", 3).unwrap(),
            "475.143600050775"
        );
        assert_eq!(shift_decimal("5", -3).unwrap(), "0.005");
        assert_eq!(shift_decimal("0.5", 3).unwrap(), "500");
        assert_eq!(shift_decimal("-12.5", -1).unwrap(), "-1.25");
        assert!(shift_decimal("1e3", 1).is_none());
    }

    #[test]
    fn a_beam_count_beyond_any_lidar_is_refused() {
        let path = Path::new("lidar_param.txt");
        let text = |fov: &str, count: &str| {
            format!(
                "FOV: {fov} (degree)\nStart angle: -5 (degree)\nAngular resolution: 0.666 (degree)\nMax range: 80 (m)\n{count}"
            )
        };
        let ok = parse_lidar_params(&text("190", ""), path).unwrap();
        assert_eq!(ok.beam_count, 286);
        // found by fuzzing: the count computed from a huge FOV overflowed
        let huge_fov = parse_lidar_params(&text("1111111111111111111111111190", ""), path);
        let msg = huge_fov.unwrap_err().to_string();
        assert!(
            msg.contains("lidar_param.txt:1") && msg.contains("beams"),
            "{msg}"
        );
        let huge_count = parse_lidar_params(&text("190", "Beam count: 4000000000\n"), path);
        let msg = huge_count.unwrap_err().to_string();
        assert!(
            msg.contains("lidar_param.txt:5") && msg.contains("Beam count"),
            "{msg}"
        );
    }

    #[test]
    fn degree_text_is_lossless() {
        for d in [-5.0f64, 0.666, 185.0, 0.1, 142.759, 1e-3, 33.3333] {
            let r = d.to_radians();
            let t = deg_text(r);
            assert_eq!(t.parse::<f64>().unwrap().to_radians(), r, "{d} -> {t}");
        }
    }
}
