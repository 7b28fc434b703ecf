//! The Freiburg `.relations` files of the relations metric (`pfslam::eval::relations`): `t1 t2
//! x y z roll pitch yaw` per line, `#` comments allowed. Each stamp's matching tolerance is
//! half a unit of its last printed decimal.

use crate::tum::parse_stamp_ns;
use crate::{IoError, parse_finite_f64};
use pfslam::eval::relations::Relation;
use pfslam::geometry::Pose2;
use std::io::BufRead;
use std::path::Path;

fn decimals_tolerance_ns(text: &str) -> i64 {
    let d = text
        .split_once('.')
        .map(|(_, f)| f.bytes().take_while(|b| b.is_ascii_digit()).count())
        .unwrap_or(0)
        .min(9);
    // half a unit of the last printed decimal
    5 * 10i64.pow(8 - d.min(8) as u32) / if d == 9 { 10 } else { 1 }
}

/// Reads a `.relations` file: `t1 t2 x y z roll pitch yaw` per line (`#` comments allowed).
pub fn read_relations(path: &Path) -> Result<Vec<Relation>, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    read_relations_from(std::io::BufReader::new(file), path)
}

/// [`read_relations`] from any reader; `path` names the source in errors.
pub fn read_relations_from(reader: impl BufRead, path: &Path) -> Result<Vec<Relation>, IoError> {
    let mut out = Vec::new();
    for (idx, line) in reader.lines().enumerate() {
        let line_no = idx + 1;
        let line = line.map_err(|e| IoError::parse(path, line_no, format!("read failed: {e}")))?;
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = t.split_whitespace().collect();
        if f.len() != 8 {
            return Err(IoError::parse(
                path,
                line_no,
                format!(
                    "expected 8 fields (t1 t2 x y z roll pitch yaw), found {}",
                    f.len()
                ),
            ));
        }
        let stamp = |k: usize, name: &str| {
            parse_stamp_ns(f[k]).ok_or_else(|| {
                IoError::parse(path, line_no, format!("{name}: not a time: {:?}", f[k]))
            })
        };
        let t1_ns = stamp(0, "t1")?;
        let t2_ns = stamp(1, "t2")?;
        let x = parse_finite_f64(path, line_no, "x", f[2])?;
        let y = parse_finite_f64(path, line_no, "y", f[3])?;
        for (k, name) in [(4, "z"), (5, "roll"), (6, "pitch")] {
            parse_finite_f64(path, line_no, name, f[k])?;
        }
        let yaw = parse_finite_f64(path, line_no, "yaw", f[7])?;
        out.push(Relation {
            t1_ns,
            t2_ns,
            t1_tolerance_ns: decimals_tolerance_ns(f[0]),
            t2_tolerance_ns: decimals_tolerance_ns(f[1]),
            t1_from_t2: Pose2::new(x, y, yaw),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tolerance_from_decimals() {
        assert_eq!(decimals_tolerance_ns("976052905.167303"), 500);
        assert_eq!(decimals_tolerance_ns("1134864645.90321"), 5_000);
        assert_eq!(decimals_tolerance_ns("12"), 500_000_000);
        assert_eq!(decimals_tolerance_ns("1.123456789"), 0);
    }
}
