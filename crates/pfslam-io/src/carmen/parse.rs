//! One CARMEN line into a typed message; errors are plain messages that the reader turns
//! into a counted drop or, with `strict`, an error naming the file and line.

use crate::tum::parse_stamp_ns;
use pfslam::geometry::Pose2;

/// Which laser a laser line belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum LaserKind {
    /// `FLASER`.
    Front,
    /// `RLASER`.
    Rear,
    /// `ROBOTLASER1`.
    Robot,
    /// `RAWLASER1` (front) or `RAWLASER2` (rear): geometry but no pose.
    Raw { rear: bool },
}

/// A laser line's content (its readings are written into the caller's buffer).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct LaserLine {
    pub kind: LaserKind,
    /// `start_angle`, `angular_resolution` (rad) and `maximum_range` (m) when the line
    /// carries its geometry (ROBOTLASER1).
    pub geometry: Option<(f64, f64, f32)>,
    /// The odometry pose at the scan (FLASER/RLASER `odom_*`, ROBOTLASER1's robot pose;
    /// identity for RAWLASER lines, which carry none).
    pub odom: Pose2,
    /// The pose the line gives for the laser's robot (FLASER/RLASER `x y theta`: the corrected
    /// pose in corrected logs; ROBOTLASER1's laser pose).
    pub pose: Pose2,
    /// `ipc_timestamp` (ns).
    pub stamp_ns: i64,
    /// Readings that are not finite numbers (kept as "no return").
    pub non_finite: usize,
}

/// A parsed line.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Message {
    /// A blank or `#` line.
    Comment,
    /// A laser line.
    Laser(LaserLine),
    /// An `ODOM` line (its pose is the odometry only of logs whose laser lines carry none).
    Odom { stamp_ns: i64, pose: Pose2 },
    /// A `TRUEPOS` line (simulated logs).
    TruePos { stamp_ns: i64, pose: Pose2 },
    /// A `PARAM` line of a laser offset.
    Param { name: String, value: f64 },
    /// A line of another message type (a CARMEN keyword) that the reader does not use.
    Other(String),
}

/// Parses one line (without its newline); readings go into `ranges`.
pub(super) fn parse_line(t: &str, ranges: &mut Vec<f32>) -> Result<Message, String> {
    let t = t.trim();
    if t.is_empty() || t.starts_with('#') {
        return Ok(Message::Comment);
    }
    let f: Vec<&str> = t.split_ascii_whitespace().collect();
    match f[0] {
        "FLASER" => flaser(&f, LaserKind::Front, ranges),
        "RLASER" => flaser(&f, LaserKind::Rear, ranges),
        "ROBOTLASER1" => robotlaser(&f, ranges),
        "RAWLASER1" => rawlaser(&f, false, ranges),
        "RAWLASER2" => rawlaser(&f, true, ranges),
        "ODOM" => {
            need(
                &f,
                9,
                "ODOM",
                "x y theta tv rv accel ipc_timestamp host logger_timestamp",
            )?;
            Ok(Message::Odom {
                pose: pose(&f[1..4])?,
                stamp_ns: stamp(f[7])?,
            })
        }
        "TRUEPOS" => {
            need(
                &f,
                9,
                "TRUEPOS",
                "true_x true_y true_theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp",
            )?;
            Ok(Message::TruePos {
                pose: pose(&f[1..4])?,
                stamp_ns: stamp(f[7])?,
            })
        }
        "PARAM" => param(&f),
        kind if is_keyword(kind) => Ok(Message::Other(kind.to_string())),
        kind => Err(format!("not a CARMEN message: starts with {kind:?}")),
    }
}

fn is_keyword(s: &str) -> bool {
    s.len() <= 40
        && s.bytes().next().is_some_and(|b| b.is_ascii_uppercase())
        && s.bytes()
            .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_')
}

fn need(f: &[&str], fields: usize, kind: &str, names: &str) -> Result<(), String> {
    if f.len() - 1 < fields {
        return Err(format!(
            "{kind}: expected {fields} fields ({names}), found {}",
            f.len() - 1
        ));
    }
    Ok(())
}

fn finite(text: &str, name: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{name}: not a finite number: {text:?}")),
    }
}

fn pose(f: &[&str]) -> Result<Pose2, String> {
    Ok(Pose2::new(
        finite(f[0], "x")?,
        finite(f[1], "y")?,
        finite(f[2], "theta")?,
    ))
}

fn stamp(text: &str) -> Result<i64, String> {
    parse_stamp_ns(text).ok_or_else(|| format!("ipc_timestamp: not a time in seconds: {text:?}"))
}

fn count(text: Option<&&str>, kind: &str) -> Result<usize, String> {
    let text = text.ok_or_else(|| format!("{kind}: missing count"))?;
    let n: usize = text
        .parse()
        .map_err(|_| format!("{kind}: count is not a non-negative integer: {text:?}"))?;
    // a dense scanner has a few thousand beams; a larger count is a corrupt line
    if n > 100_000 {
        return Err(format!("{kind}: implausible count {n}"));
    }
    Ok(n)
}

/// Readings into `out`; a reading that is not a number is an error, a non-finite number is
/// kept (it means "no return") and counted.
fn readings(texts: &[&str], kind: &str, out: &mut Vec<f32>) -> Result<usize, String> {
    out.clear();
    let mut non_finite = 0;
    for (k, t) in texts.iter().enumerate() {
        let v: f32 = t
            .parse()
            .map_err(|_| format!("{kind}: reading {} is not a number: {t:?}", k + 1))?;
        non_finite += usize::from(!v.is_finite());
        out.push(v);
    }
    if out.is_empty() {
        return Err(format!("{kind}: laser line with 0 readings"));
    }
    Ok(non_finite)
}

/// `FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp`.
fn flaser(f: &[&str], kind: LaserKind, ranges: &mut Vec<f32>) -> Result<Message, String> {
    let name = f[0];
    let n = count(f.get(1), name)?;
    if f.len() != n + 11 {
        return Err(format!(
            "{name}: {n} readings need {} fields (n, readings, x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp), found {}",
            n + 10,
            f.len() - 1
        ));
    }
    let non_finite = readings(&f[2..2 + n], name, ranges)?;
    let o = 2 + n;
    Ok(Message::Laser(LaserLine {
        kind,
        geometry: None,
        pose: pose(&f[o..o + 3])?,
        odom: pose(&f[o + 3..o + 6])?,
        stamp_ns: stamp(f[o + 6])?,
        non_finite,
    }))
}

/// `ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1..r_n
/// m rem_1..rem_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
/// forward_safety side_safety turn_axis ipc_timestamp host logger_timestamp`.
fn robotlaser(f: &[&str], ranges: &mut Vec<f32>) -> Result<Message, String> {
    const KIND: &str = "ROBOTLASER1";
    if f.len() < 10 {
        return Err(format!("{KIND}: line too short ({} fields)", f.len() - 1));
    }
    let start = finite(f[2], "start_angle")?;
    let res = finite(f[4], "angular_resolution")?;
    let max_range = finite(f[5], "maximum_range")? as f32;
    let n = count(f.get(8), KIND)?;
    let m_at = 9 + n;
    let m = count(f.get(m_at), "num_remissions")?;
    let rest = m_at + 1 + m;
    if f.len() != rest + 14 {
        return Err(format!(
            "{KIND}: {n} readings and {m} remissions need {} fields, found {}",
            rest + 13,
            f.len() - 1
        ));
    }
    let non_finite = readings(&f[9..9 + n], KIND, ranges)?;
    Ok(Message::Laser(LaserLine {
        kind: LaserKind::Robot,
        geometry: Some((start, res, max_range)),
        pose: pose(&f[rest..rest + 3])?,
        odom: pose(&f[rest + 3..rest + 6])?,
        stamp_ns: stamp(f[rest + 11])?,
        non_finite,
    }))
}

/// `RAWLASERk laser_type start_angle fov resolution max_range accuracy remission_mode n
/// r_1..r_n m rem_1..rem_m ipc_timestamp host logger_timestamp`.
fn rawlaser(f: &[&str], rear: bool, ranges: &mut Vec<f32>) -> Result<Message, String> {
    let kind = f[0];
    if f.len() < 10 {
        return Err(format!("{kind}: line too short ({} fields)", f.len() - 1));
    }
    let start = finite(f[2], "start_angle")?;
    let res = finite(f[4], "angular_resolution")?;
    let max_range = finite(f[5], "maximum_range")? as f32;
    let n = count(f.get(8), kind)?;
    let m = count(f.get(9 + n), "num_remissions")?;
    let rest = 10 + n + m;
    if f.len() != rest + 3 {
        return Err(format!(
            "{kind}: {n} readings and {m} remissions need {} fields, found {}",
            rest + 2,
            f.len() - 1
        ));
    }
    let non_finite = readings(&f[9..9 + n], kind, ranges)?;
    Ok(Message::Laser(LaserLine {
        kind: LaserKind::Raw { rear },
        geometry: Some((start, res, max_range)),
        pose: Pose2::IDENTITY,
        odom: Pose2::IDENTITY,
        stamp_ns: stamp(f[rest])?,
        non_finite,
    }))
}

/// `PARAM name value [host stamp]`: only the laser offsets are used.
fn param(f: &[&str]) -> Result<Message, String> {
    const USED: [&str; 6] = [
        "robot_frontlaser_offset",
        "robot_frontlaser_side_offset",
        "robot_frontlaser_angular_offset",
        "robot_rearlaser_offset",
        "robot_rearlaser_side_offset",
        "robot_rearlaser_angular_offset",
    ];
    match (f.get(1), f.get(2)) {
        (Some(name), Some(value)) if USED.contains(name) => Ok(Message::Param {
            name: name.to_string(),
            value: finite(value, name)?,
        }),
        _ => Ok(Message::Other("PARAM".into())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_parse_or_say_why() {
        let mut r = Vec::new();
        let m = parse_line("FLASER 2 1.0 nan 1 2 3 4 5 6 7.5 h 0", &mut r).unwrap();
        let Message::Laser(l) = m else {
            panic!("{m:?}")
        };
        assert_eq!((l.stamp_ns, l.non_finite), (7_500_000_000, 1));
        assert_eq!(l.odom, Pose2::new(4.0, 5.0, 6.0));
        assert_eq!(l.pose, Pose2::new(1.0, 2.0, 3.0));
        assert_eq!(
            parse_line("NEFF 3 4", &mut r).unwrap(),
            Message::Other("NEFF".into())
        );
        assert_eq!(parse_line("  # c", &mut r).unwrap(), Message::Comment);
        for (line, why) in [
            ("FLASER 2 1.0", "need 12 fields"),
            ("FLASER 1 x 1 2 3 4 5 6 7.5 h 0", "not a number"),
            ("ODOM 1 2", "expected 9 fields"),
            ("ODOM 1 2 3 0 0 0 x1 h 0", "not a time"),
            ("garbage!", "not a CARMEN message"),
            ("FLASER 999999 1", "implausible count"),
            ("FLASER 0 1 2 3 4 5 6 7.5 h 0", "0 readings"),
            (
                "RAWLASER1 0 -1.5 3 0.5 30 0.01 0 2 1 2 0 7.5 h",
                "need 14 fields",
            ),
        ] {
            let e = parse_line(line, &mut r).unwrap_err();
            assert!(e.contains(why), "{line}: {e}");
        }
    }
}
