//! Map files: the ROS map_server pair (`map.pgm` + `map.yaml`) written and read, and the
//! log-odds as a NumPy `.npy` array.
//!
//! map_server conventions: the pgm is binary P5, 8 bits, top row first (highest y);
//! `origin: [x, y, yaw]` is the lower-left corner of the lower-left pixel; we write
//! `mode: trinary` with occupied = 0, free = 254, unknown = 205 and map_saver's thresholds
//! (`occupied_thresh: 0.65`, `free_thresh: 0.196`), which decode those three values exactly
//! (`p = (255 - v) / 255`; occupied when `p > occupied_thresh`, free when `p < free_thresh`).
//!
//! `.npy`: format version 1.0, `<f4`, C order, shape `(rows, cols)`, row 0 = top (highest y),
//! the same pixel layout as the pgm, so the yaml's origin and resolution apply to both.

use super::{IoError, write_atomic, write_bytes_atomic};
use pfslam::map::{BinaryMap, Cell, CellRect, CellState, MapLimits, OccupancyGrid};
use std::path::{Path, PathBuf};

/// Pixel value of occupied cells in the pgm.
pub const PGM_OCCUPIED: u8 = 0;
/// Pixel value of free cells in the pgm.
pub const PGM_FREE: u8 = 254;
/// Pixel value of unknown cells in the pgm.
pub const PGM_UNKNOWN: u8 = 205;

/// Writes `map` as a map_server pair: `yaml_path` and the pgm beside it (same stem, `.pgm`).
/// Returns the pgm's path.
pub fn write_map_server(map: &BinaryMap, yaml_path: &Path) -> Result<PathBuf, IoError> {
    let pgm_path = yaml_path.with_extension("pgm");
    let pgm_name = pgm_path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "map.pgm".into());
    let (w, h) = (map.width, map.height);
    let mut bytes = format!(
        "P5\n# pfslam occupancy map, {} m/cell\n{w} {h}\n255\n",
        map.limits.resolution_m()
    )
    .into_bytes();
    bytes.reserve(w * h);
    for row in (0..h).rev() {
        bytes.extend(map.cells[row * w..(row + 1) * w].iter().map(|s| match s {
            CellState::Occupied => PGM_OCCUPIED,
            CellState::Free => PGM_FREE,
            CellState::Unknown => PGM_UNKNOWN,
        }));
    }
    write_bytes_atomic(&pgm_path, &bytes)?;
    let yaml = format!(
        "image: {pgm_name}\nmode: trinary\nresolution: {}\norigin: [{}, {}, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
        map.limits.resolution_m(),
        map.limits.origin_x_m(),
        map.limits.origin_y_m()
    );
    write_bytes_atomic(yaml_path, yaml.as_bytes())?;
    Ok(pgm_path)
}

/// The fields of a map_server yaml that this reader understands.
#[derive(Debug, Clone, PartialEq)]
pub struct MapServerYaml {
    /// The image file, resolved relative to the yaml's directory.
    pub image: PathBuf,
    /// Cell side (m).
    pub resolution_m: f64,
    /// Lower-left corner of the lower-left pixel and yaw (m, m, rad).
    pub origin: [f64; 3],
    /// Whether white means occupied.
    pub negate: bool,
    /// Occupied when `p > occupied_thresh`.
    pub occupied_thresh: f64,
    /// Free when `p < free_thresh`.
    pub free_thresh: f64,
    /// `trinary` (default), `scale` or `raw`.
    pub mode: String,
}

fn parse_yaml(path: &Path, text: &str) -> Result<MapServerYaml, IoError> {
    let mut image = None;
    let mut resolution = None;
    let mut origin = None;
    let mut negate = false;
    let mut occ = 0.65;
    let mut free = 0.196;
    let mut mode = "trinary".to_string();
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            return Err(IoError::parse(
                path,
                line_no,
                format!("expected `key: value`, got {raw:?}"),
            ));
        };
        let value = value.trim().trim_matches(|c| c == '"' || c == '\'');
        match key.trim() {
            "image" => image = Some(value.to_string()),
            "resolution" => {
                resolution = Some(super::parse_finite_f64(path, line_no, "resolution", value)?)
            }
            "origin" => {
                let inner = value.trim_start_matches('[').trim_end_matches(']');
                let parts: Vec<&str> = inner.split(',').map(str::trim).collect();
                if parts.len() != 3 {
                    return Err(IoError::parse(
                        path,
                        line_no,
                        "origin: expected [x, y, yaw]",
                    ));
                }
                let mut o = [0.0; 3];
                for (k, p) in parts.iter().enumerate() {
                    o[k] = super::parse_finite_f64(path, line_no, "origin", p)?;
                }
                origin = Some(o);
            }
            "negate" => {
                negate = match value {
                    "0" | "false" => false,
                    "1" | "true" => true,
                    _ => {
                        return Err(IoError::parse(
                            path,
                            line_no,
                            format!("negate: expected 0 or 1, got {value:?}"),
                        ));
                    }
                }
            }
            "occupied_thresh" => {
                occ = super::parse_finite_f64(path, line_no, "occupied_thresh", value)?
            }
            "free_thresh" => free = super::parse_finite_f64(path, line_no, "free_thresh", value)?,
            "mode" => mode = value.to_string(),
            // Other keys (e.g. map_server 2's `cost_translation_table`) are not needed here.
            _ => {}
        }
    }
    let missing = |what: &str| IoError::parse(path, 0, format!("missing key `{what}`"));
    let image = image.ok_or_else(|| missing("image"))?;
    let resolution_m = resolution.ok_or_else(|| missing("resolution"))?;
    let origin = origin.ok_or_else(|| missing("origin"))?;
    if resolution_m <= 0.0 {
        return Err(IoError::parse(path, 0, "resolution must be > 0"));
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    Ok(MapServerYaml {
        image: dir.join(image),
        resolution_m,
        origin,
        negate,
        occupied_thresh: occ,
        free_thresh: free,
        mode,
    })
}

/// Reads the header tokens of a P5/P2 pgm; returns (magic, width, height, maxval, data start).
fn pgm_header(path: &Path, bytes: &[u8]) -> Result<(Vec<u8>, usize, usize, usize, usize), IoError> {
    let mut pos = 0;
    let mut tokens: Vec<Vec<u8>> = Vec::new();
    while tokens.len() < 4 {
        while pos < bytes.len() && (bytes[pos].is_ascii_whitespace() || bytes[pos] == b'#') {
            if bytes[pos] == b'#' {
                while pos < bytes.len() && bytes[pos] != b'\n' {
                    pos += 1;
                }
            } else {
                pos += 1;
            }
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos {
            return Err(IoError::parse(path, 0, "truncated pgm header"));
        }
        tokens.push(bytes[start..pos].to_vec());
    }
    // Exactly one whitespace byte separates the header from binary data.
    pos += 1;
    let num = |t: &[u8], what: &str| -> Result<usize, IoError> {
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| IoError::parse(path, 0, format!("pgm header: bad {what}")))
    };
    let w = num(&tokens[1], "width")?;
    let h = num(&tokens[2], "height")?;
    let maxval = num(&tokens[3], "maxval")?;
    Ok((tokens[0].clone(), w, h, maxval, pos))
}

/// Reads a map_server pair given its yaml. Supports P5 (binary) and P2 (ASCII) 8-bit pgm,
/// `mode` trinary or scale (both thresholded as map_server does), origin yaw 0.
pub fn read_map_server(yaml_path: &Path) -> Result<BinaryMap, IoError> {
    let text = std::fs::read_to_string(yaml_path).map_err(|e| IoError::io(yaml_path, e))?;
    parse_map_server(&text, yaml_path, |pgm| std::fs::read(pgm))
}

/// [`read_map_server`] on the yaml's text, with the image's bytes from `read_image` (given
/// the image's path as the yaml resolves it).
pub fn parse_map_server(
    text: &str,
    yaml_path: &Path,
    read_image: impl FnOnce(&Path) -> std::io::Result<Vec<u8>>,
) -> Result<BinaryMap, IoError> {
    let y = parse_yaml(yaml_path, text)?;
    if y.origin[2].abs() > 1e-12 {
        return Err(IoError::parse(
            yaml_path,
            0,
            "origin yaw != 0 is not supported",
        ));
    }
    if y.mode != "trinary" && y.mode != "scale" {
        return Err(IoError::parse(
            yaml_path,
            0,
            format!("mode {:?} is not supported (trinary, scale)", y.mode),
        ));
    }
    let pgm = &y.image;
    let bytes = read_image(pgm).map_err(|e| IoError::io(pgm, e))?;
    let (magic, w, h, maxval, start) = pgm_header(pgm, &bytes)?;
    if maxval == 0 || maxval > 255 {
        return Err(IoError::parse(
            pgm,
            0,
            format!("maxval {maxval}: only 8-bit pgm is supported"),
        ));
    }
    let n = w
        .checked_mul(h)
        .ok_or_else(|| IoError::parse(pgm, 0, "image too large"))?;
    let pixels: Vec<u8> = match magic.as_slice() {
        b"P5" => {
            let data = bytes.get(start..start + n).ok_or_else(|| {
                IoError::parse(
                    pgm,
                    0,
                    format!("expected {n} pixel bytes, file is truncated"),
                )
            })?;
            data.to_vec()
        }
        b"P2" => {
            let text = std::str::from_utf8(&bytes[start.min(bytes.len())..])
                .map_err(|_| IoError::parse(pgm, 0, "P2 data is not text"))?;
            let v: Result<Vec<u8>, _> = text
                .split_ascii_whitespace()
                .take(n)
                .map(|t| t.parse::<u8>())
                .collect();
            let v = v.map_err(|_| IoError::parse(pgm, 0, "P2: bad pixel value"))?;
            if v.len() != n {
                return Err(IoError::parse(pgm, 0, "P2: too few pixels"));
            }
            v
        }
        _ => return Err(IoError::parse(pgm, 1, "not a P5 or P2 pgm")),
    };
    let mut map = BinaryMap::filled(
        MapLimits::new(y.resolution_m, y.origin[0], y.origin[1]),
        w,
        h,
        CellState::Unknown,
    );
    for row in 0..h {
        let j = h - 1 - row;
        for i in 0..w {
            let v = pixels[row * w + i] as f64 / maxval as f64;
            let p = if y.negate { v } else { 1.0 - v };
            let s = if p > y.occupied_thresh {
                CellState::Occupied
            } else if p < y.free_thresh {
                CellState::Free
            } else {
                CellState::Unknown
            };
            map.cells[j * w + i] = s;
        }
    }
    Ok(map)
}

/// Writes the log-odds of `rect` as `.npy` (`<f4`, shape `(rows, cols)`, row 0 = highest y).
pub fn write_logodds_npy(
    grid: &OccupancyGrid,
    rect: &CellRect,
    path: &Path,
) -> Result<(), IoError> {
    let (w, h) = (rect.width(), rect.height());
    let mut data = Vec::with_capacity(w * h);
    for j in (rect.min_j..=rect.max_j).rev() {
        for i in rect.min_i..=rect.max_i {
            data.push(grid.logodds(Cell::new(i, j)) as f32);
        }
    }
    write_npy_f32(path, &[h, w], &data)
}

/// Writes a little-endian f32 array in NPY format 1.0, C order.
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<(), IoError> {
    let shape_txt = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_txt}, }}");
    // magic (6) + version (2) + length (2) + header + '\n' must be a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    write_atomic(path, |w| {
        w.write_all(b"\x93NUMPY\x01\x00")?;
        w.write_all(&(header.len() as u16).to_le_bytes())?;
        w.write_all(header.as_bytes())?;
        for v in data {
            w.write_all(&v.to_le_bytes())?;
        }
        Ok(())
    })
}

/// Reads an NPY 1.0/2.0 `<f4` C-order array: (shape, data).
pub fn read_npy_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>), IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    parse_npy_f32(&bytes, path)
}

/// [`read_npy_f32`] on the file's bytes; `path` names it in errors.
pub fn parse_npy_f32(bytes: &[u8], path: &Path) -> Result<(Vec<usize>, Vec<f32>), IoError> {
    let bad = |m: &str| IoError::parse(path, 0, m.to_string());
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("not an npy file"));
    }
    let (hlen, hstart) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(bad("unsupported npy version")),
    };
    let header = bytes
        .get(hstart..hstart + hlen)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad("bad npy header"))?;
    if !header.contains("'descr': '<f4'") {
        return Err(bad("npy dtype is not <f4"));
    }
    if !header.contains("'fortran_order': False") {
        return Err(bad("npy array is not C order"));
    }
    let shape_txt = header
        .split("'shape':")
        .nth(1)
        .and_then(|s| s.split('(').nth(1))
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad("npy header has no shape"))?;
    let shape: Result<Vec<usize>, _> = shape_txt
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>())
        .collect();
    let shape = shape.map_err(|_| bad("bad npy shape"))?;
    // the shape comes from the file: its product may overflow
    let bytes_expected = shape.iter().try_fold(4usize, |acc, &d| acc.checked_mul(d));
    let body = &bytes[hstart + hlen..];
    if bytes_expected != Some(body.len()) {
        return Err(bad("npy data size does not match its shape"));
    }
    let data = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((shape, data))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pfslam::map::LogOddsParams;

    #[test]
    fn map_server_roundtrip() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = BinaryMap::filled(MapLimits::new(0.1, -3.25, 7.5), 5, 3, CellState::Unknown);
        m.set(0, 0, CellState::Occupied);
        m.set(4, 2, CellState::Free);
        m.set(1, 2, CellState::Occupied);
        let yaml = dir.path().join("true_map.yaml");
        let pgm = write_map_server(&m, &yaml).unwrap();
        assert_eq!(pgm, dir.path().join("true_map.pgm"));
        let bytes = std::fs::read(&pgm).unwrap();
        assert!(bytes.starts_with(b"P5\n"));
        // top row first: the lower-left cell (0, 0) is the first pixel of the last row
        assert_eq!(bytes[bytes.len() - 5], PGM_OCCUPIED);
        assert_eq!(bytes[bytes.len() - 15 + 4], PGM_FREE);
        let text = std::fs::read_to_string(&yaml).unwrap();
        assert!(text.contains("image: true_map.pgm"));
        assert!(text.contains("origin: [-3.25, 7.5, 0.0]"));
        let back = read_map_server(&yaml).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn reads_p2_negate_and_reports_errors() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.pgm"), "P2\n# c\n2 1\n255\n0 255\n").unwrap();
        std::fs::write(
            dir.path().join("m.yaml"),
            "image: m.pgm\nresolution: 0.5\norigin: [0, 0, 0]\nnegate: 1\n",
        )
        .unwrap();
        let m = read_map_server(&dir.path().join("m.yaml")).unwrap();
        assert_eq!(m.cells, vec![CellState::Free, CellState::Occupied]);
        std::fs::write(
            dir.path().join("b.yaml"),
            "image: m.pgm\norigin: [0, 0, 0]\n",
        )
        .unwrap();
        let e = read_map_server(&dir.path().join("b.yaml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("resolution"), "{e}");
        std::fs::write(
            dir.path().join("c.yaml"),
            "image: m.pgm\nresolution: x\norigin: [0, 0, 0]\n",
        )
        .unwrap();
        let e = read_map_server(&dir.path().join("c.yaml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.yaml:2"), "{e}");
        std::fs::write(dir.path().join("t.pgm"), "P5\n4 4\n255\n\0\0").unwrap();
        std::fs::write(
            dir.path().join("t.yaml"),
            "image: t.pgm\nresolution: 1\norigin: [0, 0, 0]\n",
        )
        .unwrap();
        assert!(read_map_server(&dir.path().join("t.yaml")).is_err());
    }

    #[test]
    fn npy_roundtrip_and_layout() {
        let dir = tempfile::tempdir().unwrap();
        let mut g =
            OccupancyGrid::with_params(MapLimits::new(1.0, 0.0, 0.0), LogOddsParams::ucsd());
        g.update_occupied(Cell::new(0, 1)).unwrap();
        g.update_free(Cell::new(2, 0)).unwrap();
        let rect = CellRect {
            min_i: 0,
            min_j: 0,
            max_i: 2,
            max_j: 1,
        };
        let p = dir.path().join("logodds.npy");
        write_logodds_npy(&g, &rect, &p).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let (shape, data) = read_npy_f32(&p).unwrap();
        assert_eq!(shape, vec![2, 3]);
        let l4 = 4f32.ln();
        // row 0 is the top row (j = 1)
        assert!((data[0] - l4).abs() < 0.01);
        assert!((data[5] + l4).abs() < 0.01);
        assert_eq!(data[1], 0.0);
    }

    #[test]
    fn an_npy_shape_whose_size_overflows_is_refused() {
        // found by fuzzing: the product of the shape overflowed
        let header =
            "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296, 2), }";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        bytes.extend_from_slice(&[0; 8]);
        let e = parse_npy_f32(&bytes, Path::new("m.npy"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("m.npy") && e.contains("does not match its shape"),
            "{e}"
        );
    }
}
