//! OpenCV calibration YAML (`%YAML:1.0`, `!!opencv-matrix` with a possibly multi-line
//! `data: [ ... ]`), as the car's `left_camera.yaml` / `right_camera.yaml` are written.
//!
//! Only the subset those files use is understood: top-level `key: scalar` lines and
//! `key: !!opencv-matrix` blocks with `rows`, `cols`, `dt` and `data`. Numbers are written
//! with 17 significant digits (`%.16e`, as OpenCV does), so a round trip is exact.

use super::{IoError, parse_finite_f64, write_atomic};
use pfslam::sensors::CameraInfo;
use std::io::Write;
use std::path::Path;

/// One value of the file.
enum Value {
    Scalar(usize, String),
    Matrix {
        line: usize,
        rows: usize,
        cols: usize,
        data: Vec<f64>,
    },
}

/// Parses the file into (key, value) pairs in file order.
fn parse_entries(path: &Path, text: &str) -> Result<Vec<(String, Value)>, IoError> {
    let lines: Vec<&str> = text.lines().map(|l| l.trim_end_matches('\r')).collect();
    match lines.first() {
        Some(l) if l.trim_start().starts_with("%YAML") => {}
        _ => {
            return Err(IoError::parse(
                path,
                1,
                "not an OpenCV YAML file (first line must be %YAML:1.0)",
            ));
        }
    }
    let mut out: Vec<(String, Value)> = Vec::new();
    let mut i = 1;
    while i < lines.len() {
        let line_no = i + 1;
        let raw = lines[i];
        let t = raw.trim();
        i += 1;
        if t.is_empty() || t == "---" || t.starts_with('#') {
            continue;
        }
        if raw.starts_with(' ') || raw.starts_with('\t') {
            return Err(IoError::parse(
                path,
                line_no,
                format!("unexpected indented line {t:?}"),
            ));
        }
        let Some((key, value)) = t.split_once(':') else {
            return Err(IoError::parse(
                path,
                line_no,
                format!("expected `key: value`, found {t:?}"),
            ));
        };
        let key = key.trim().to_string();
        let value = value.trim();
        if value != "!!opencv-matrix" {
            out.push((key, Value::Scalar(line_no, value.to_string())));
            continue;
        }
        let value = parse_matrix(path, &key, (&lines, &mut i), line_no)?;
        out.push((key, value));
    }
    Ok(out)
}

/// The matrix block of `key` (declared at line `line_no`) from line `*i` on: its indented
/// `rows`, `cols`, `dt` and `data: [ ... ]`; `*i` ends past the block.
fn parse_matrix(
    path: &Path,
    key: &str,
    (lines, i): (&[&str], &mut usize),
    line_no: usize,
) -> Result<Value, IoError> {
    let mut rows: Option<usize> = None;
    let mut cols: Option<usize> = None;
    let mut data: Option<Vec<f64>> = None;
    while *i < lines.len() && (lines[*i].starts_with(' ') || lines[*i].starts_with('\t')) {
        let ln = *i + 1;
        let t = lines[*i].trim();
        *i += 1;
        let Some((k, v)) = t.split_once(':') else {
            return Err(IoError::parse(
                path,
                ln,
                format!("{key}: expected `name: value` in matrix, found {t:?}"),
            ));
        };
        match k.trim() {
            "rows" | "cols" => {
                let n: usize = v.trim().parse().map_err(|_| {
                    IoError::parse(path, ln, format!("{key}.{}: not an integer", k.trim()))
                })?;
                if k.trim() == "rows" {
                    rows = Some(n);
                } else {
                    cols = Some(n);
                }
            }
            "dt" => {
                if v.trim() != "d" && v.trim() != "f" {
                    return Err(IoError::parse(
                        path,
                        ln,
                        format!("{key}.dt: unsupported element type {:?}", v.trim()),
                    ));
                }
            }
            "data" => data = Some(matrix_data(path, key, v, (lines, i), ln)?),
            other => {
                return Err(IoError::parse(
                    path,
                    ln,
                    format!("{key}: unknown matrix field {other:?}"),
                ));
            }
        }
    }
    let (Some(rows), Some(cols), Some(data)) = (rows, cols, data) else {
        return Err(IoError::parse(
            path,
            line_no,
            format!("{key}: matrix needs rows, cols and data"),
        ));
    };
    // rows and cols come from the file: their product may overflow
    if rows.checked_mul(cols) != Some(data.len()) {
        return Err(IoError::parse(
            path,
            line_no,
            format!(
                "{key}: a {rows}x{cols} matrix cannot have {} values",
                data.len()
            ),
        ));
    }
    Ok(Value::Matrix {
        line: line_no,
        rows,
        cols,
        data,
    })
}

/// The values of a matrix's `data: [ ... ]` starting with `v` on line `ln`, continued on
/// the lines from `*i` until the `]` (`*i` ends past them).
fn matrix_data(
    path: &Path,
    key: &str,
    v: &str,
    (lines, i): (&[&str], &mut usize),
    ln: usize,
) -> Result<Vec<f64>, IoError> {
    let mut body = v.trim().to_string();
    if !body.starts_with('[') {
        return Err(IoError::parse(
            path,
            ln,
            format!("{key}.data: expected '['"),
        ));
    }
    while !body.contains(']') {
        if *i >= lines.len() {
            return Err(IoError::parse(
                path,
                ln,
                format!("{key}.data: unterminated '['"),
            ));
        }
        body.push(' ');
        body.push_str(lines[*i].trim());
        *i += 1;
    }
    let inner = body.trim_start_matches('[').split(']').next().unwrap_or("");
    let mut vals = Vec::new();
    for f in inner.split(',') {
        let f = f.trim();
        if f.is_empty() {
            continue;
        }
        vals.push(parse_finite_f64(path, ln, &format!("{key}.data"), f)?);
    }
    Ok(vals)
}

fn find<'a>(entries: &'a [(String, Value)], key: &str) -> Option<&'a Value> {
    entries.iter().find(|(k, _)| k == key).map(|(_, v)| v)
}

fn missing(path: &Path, key: &str) -> IoError {
    IoError::parse(path, 0, format!("missing key {key:?}"))
}

fn scalar_u32(path: &Path, entries: &[(String, Value)], key: &str) -> Result<u32, IoError> {
    match find(entries, key) {
        Some(Value::Scalar(line, v)) => v.parse().map_err(|_| {
            IoError::parse(path, *line, format!("{key}: not a positive integer: {v:?}"))
        }),
        Some(Value::Matrix { line, .. }) => Err(IoError::parse(
            path,
            *line,
            format!("{key}: expected a number, found a matrix"),
        )),
        None => Err(missing(path, key)),
    }
}

fn matrix<const N: usize>(
    path: &Path,
    entries: &[(String, Value)],
    key: &str,
    shape: (usize, usize),
) -> Result<[f64; N], IoError> {
    match find(entries, key) {
        Some(Value::Matrix {
            line,
            rows,
            cols,
            data,
        }) => {
            if (*rows, *cols) != shape {
                return Err(IoError::parse(
                    path,
                    *line,
                    format!(
                        "{key}: expected a {}x{} matrix, found {rows}x{cols}",
                        shape.0, shape.1
                    ),
                ));
            }
            let mut out = [0.0; N];
            out.copy_from_slice(data);
            Ok(out)
        }
        Some(Value::Scalar(line, _)) => Err(IoError::parse(
            path,
            *line,
            format!("{key}: expected an !!opencv-matrix"),
        )),
        None => Err(missing(path, key)),
    }
}

/// Parses camera intrinsics from OpenCV YAML text (`path` names the source in errors).
pub fn parse_camera_yaml(path: &Path, text: &str) -> Result<CameraInfo, IoError> {
    let entries = parse_entries(path, text)?;
    let distortion_model = match find(&entries, "distortion_model") {
        Some(Value::Scalar(_, v)) => v.clone(),
        Some(Value::Matrix { line, .. }) => {
            return Err(IoError::parse(
                path,
                *line,
                "distortion_model: expected a name",
            ));
        }
        None => return Err(missing(path, "distortion_model")),
    };
    let distortion = match find(&entries, "distortion_coefficients") {
        Some(Value::Matrix { data, .. }) => data.clone(),
        Some(Value::Scalar(line, _)) => {
            return Err(IoError::parse(
                path,
                *line,
                "distortion_coefficients: expected an !!opencv-matrix",
            ));
        }
        None => return Err(missing(path, "distortion_coefficients")),
    };
    Ok(CameraInfo {
        width: scalar_u32(path, &entries, "image_width")?,
        height: scalar_u32(path, &entries, "image_height")?,
        camera_matrix: matrix::<9>(path, &entries, "camera_matrix", (3, 3))?,
        distortion_model,
        distortion,
        rectification: matrix::<9>(path, &entries, "rectification_matrix", (3, 3))?,
        projection: matrix::<12>(path, &entries, "projection_matrix", (3, 4))?,
    })
}

/// Reads a camera YAML file.
pub fn read_camera_yaml(path: &Path) -> Result<CameraInfo, IoError> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(IoError::Missing {
                path: path.to_path_buf(),
                what: "camera calibration (OpenCV YAML)".to_string(),
            });
        }
        Err(e) => return Err(IoError::io(path, e)),
    };
    parse_camera_yaml(path, &text)
}

/// Formats a number as OpenCV does: `0.`/`1.` for small integers, else `%.16e` with a signed
/// two-digit exponent (`8.1690378992770002e+02`).
pub fn format_opencv_number(v: f64) -> String {
    if v == v.trunc() && v.abs() < 1e15 {
        return format!("{}.", v as i64);
    }
    let s = format!("{v:.16e}");
    match s.split_once('e') {
        Some((mant, exp)) => {
            let (sign, digits) = match exp.strip_prefix('-') {
                Some(d) => ('-', d),
                None => ('+', exp),
            };
            format!("{mant}e{sign}{digits:0>2}")
        }
        None => s,
    }
}

fn write_matrix(
    w: &mut dyn Write,
    key: &str,
    rows: usize,
    cols: usize,
    data: &[f64],
) -> std::io::Result<()> {
    writeln!(w, "{key}: !!opencv-matrix")?;
    writeln!(w, "   rows: {rows}")?;
    writeln!(w, "   cols: {cols}")?;
    writeln!(w, "   dt: d")?;
    write!(w, "   data: [ ")?;
    for (k, v) in data.iter().enumerate() {
        if k > 0 {
            // OpenCV wraps long lists; three values per line keeps lines short.
            if k % 3 == 0 {
                write!(w, ",\n       ")?;
            } else {
                write!(w, ", ")?;
            }
        }
        write!(w, "{}", format_opencv_number(*v))?;
    }
    writeln!(w, " ]")
}

/// Writes camera intrinsics as OpenCV YAML, atomically.
pub fn write_camera_yaml(path: &Path, camera_name: &str, cam: &CameraInfo) -> Result<(), IoError> {
    write_atomic(path, |w| {
        writeln!(w, "%YAML:1.0")?;
        writeln!(w, "---")?;
        writeln!(w, "image_width: {}", cam.width)?;
        writeln!(w, "image_height: {}", cam.height)?;
        writeln!(w, "camera_name: {camera_name}")?;
        write_matrix(w, "camera_matrix", 3, 3, &cam.camera_matrix)?;
        writeln!(w, "distortion_model: {}", cam.distortion_model)?;
        write_matrix(
            w,
            "distortion_coefficients",
            1,
            cam.distortion.len(),
            &cam.distortion,
        )?;
        write_matrix(w, "rectification_matrix", 3, 3, &cam.rectification)?;
        write_matrix(w, "projection_matrix", 3, 4, &cam.projection)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pfslam::sensors::StereoCalibration;

    #[test]
    #[allow(clippy::excessive_precision)]
    fn number_format_like_opencv() {
        assert_eq!(format_opencv_number(0.0), "0.");
        assert_eq!(format_opencv_number(1.0), "1.");
        assert_eq!(
            format_opencv_number(8.1690378992770002e+02),
            "8.1690378992770002e+02"
        );
        assert_eq!(
            format_opencv_number(-1.2155906999999999e-03),
            "-1.2155906999999999e-03"
        );
    }

    #[test]
    fn roundtrip_exact() {
        let dir = tempfile::tempdir().unwrap();
        let cal = StereoCalibration::ucsd();
        let p = dir.path().join("left.yaml");
        write_camera_yaml(&p, "/stereo/left", &cal.left).unwrap();
        assert_eq!(read_camera_yaml(&p).unwrap(), cal.left);
    }

    #[test]
    fn bad_matrix_size_names_line() {
        let text = "%YAML:1.0\n---\nimage_width: 2\nimage_height: 2\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 2. ]\n";
        let e = parse_camera_yaml(Path::new("c.yaml"), text)
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.yaml:5") && e.contains("camera_matrix"), "{e}");
        // found by fuzzing: rows x cols overflowed
        let huge = text.replace("rows: 3", "rows: 1111111111111111111");
        let huge = huge.replace("cols: 3", "cols: 55555");
        let e = parse_camera_yaml(Path::new("c.yaml"), &huge)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("c.yaml:5") && e.contains("cannot have 2 values"),
            "{e}"
        );
    }
}
