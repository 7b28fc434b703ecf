//! The wheel encoders' and the fibre-optic gyro's CSVs.

use super::*;

/// Reads `encoder.csv`. Counts are checked against `params` and `opts`: a change larger
/// than 2^30 ticks is reported as a counter wrap, one implying a wheel speed above
/// `opts.max_wheel_speed_mps` as a count jump.
pub fn read_encoder_csv(
    path: &Path,
    params: &EncoderParams,
    opts: &ReadOptions,
) -> Result<Vec<EncoderSample>, IoError> {
    let lines = Lines::open(path, "encoder rows (timestamp_ns,left_count,right_count)")?;
    encoder_rows(lines, path, params, opts)
}

/// [`read_encoder_csv`] from any byte source; `path` names it in errors.
pub fn read_encoder_csv_from<'a>(
    source: impl Read + 'a,
    path: &Path,
    params: &EncoderParams,
    opts: &ReadOptions,
) -> Result<Vec<EncoderSample>, IoError> {
    let lines = Lines::from_reader(Box::new(source), path, Lines::BLOCK);
    encoder_rows(lines, path, params, opts)
}

fn encoder_rows(
    mut lines: Lines<'_>,
    path: &Path,
    params: &EncoderParams,
    opts: &ReadOptions,
) -> Result<Vec<EncoderSample>, IoError> {
    let mut rows: Vec<EncoderSample> = Vec::new();
    let mut line_nos: Vec<usize> = Vec::new();
    let mut order = OrderCheck::new(opts.timestamp_policy);
    while let Some((ln, line)) = lines.next_line()? {
        if ln == 1 && is_header(line) {
            continue;
        }
        let [t, l, r] = split_fixed::<3>(path, ln, line, "timestamp_ns,left_count,right_count")?;
        let stamp_ns = parse_int(path, ln, "timestamp_ns", t)?;
        let left_count = parse_int(path, ln, "left_count", l)?;
        let right_count = parse_int(path, ln, "right_count", r)?;
        order.check(path, ln, stamp_ns)?;
        rows.push(EncoderSample {
            stamp_ns,
            left_count,
            right_count,
        });
        line_nos.push(ln);
    }
    if rows.is_empty() {
        return Err(IoError::parse(path, 0, "empty file: no encoder rows"));
    }
    if !order.sorted {
        let perm = sort_permutation(&rows.iter().map(|r| r.stamp_ns).collect::<Vec<_>>());
        let (mut r2, mut l2) = (
            Vec::with_capacity(rows.len()),
            Vec::with_capacity(rows.len()),
        );
        let mut dropped = 0usize;
        for i in perm {
            if r2
                .last()
                .is_some_and(|p: &EncoderSample| p.stamp_ns == rows[i].stamp_ns)
            {
                dropped += 1;
                continue;
            }
            r2.push(rows[i]);
            l2.push(line_nos[i]);
        }
        tracing::warn!(
            "{}: rows out of time order: sorted by timestamp ({dropped} rows with a repeated stamp dropped)",
            path.display()
        );
        rows = r2;
        line_nos = l2;
    }
    check_encoder_counts(path, &rows, &line_nos, params, opts)?;
    Ok(rows)
}

pub(super) fn check_encoder_counts(
    path: &Path,
    rows: &[EncoderSample],
    line_nos: &[usize],
    params: &EncoderParams,
    opts: &ReadOptions,
) -> Result<(), IoError> {
    const WRAP_TICKS: i64 = 1 << 30;
    let res = f64::from(params.resolution_ticks);
    for k in 1..rows.len() {
        let (a, b) = (&rows[k - 1], &rows[k]);
        let dt_s = (b.stamp_ns - a.stamp_ns) as f64 * 1e-9;
        for (name, d_ticks, diameter) in [
            (
                "left_count",
                b.left_count - a.left_count,
                params.left_wheel_diameter_m,
            ),
            (
                "right_count",
                b.right_count - a.right_count,
                params.right_wheel_diameter_m,
            ),
        ] {
            if d_ticks.abs() >= WRAP_TICKS {
                return Err(IoError::parse(
                    path,
                    line_nos[k],
                    format!(
                        "{name}: counter wrap or reset (count changed by {d_ticks} ticks since line {})",
                        line_nos[k - 1]
                    ),
                ));
            }
            let speed = std::f64::consts::PI * diameter * d_ticks.abs() as f64 / res / dt_s;
            if speed > opts.max_wheel_speed_mps {
                return Err(IoError::parse(
                    path,
                    line_nos[k],
                    format!(
                        "{name}: count jump of {d_ticks} ticks in {:.6} s since line {} \
                         ({speed:.1} m/s > max_wheel_speed_mps {})",
                        dt_s,
                        line_nos[k - 1],
                        opts.max_wheel_speed_mps
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Reads `fog.csv`.
pub fn read_fog_csv(path: &Path, opts: &ReadOptions) -> Result<Vec<FogSample>, IoError> {
    let lines = Lines::open(
        path,
        "FOG rows (timestamp_ns,delta_roll,delta_pitch,delta_yaw)",
    )?;
    fog_rows(lines, path, opts)
}

/// [`read_fog_csv`] from any byte source; `path` names it in errors.
pub fn read_fog_csv_from<'a>(
    source: impl Read + 'a,
    path: &Path,
    opts: &ReadOptions,
) -> Result<Vec<FogSample>, IoError> {
    let lines = Lines::from_reader(Box::new(source), path, Lines::BLOCK);
    fog_rows(lines, path, opts)
}

fn fog_rows(
    mut lines: Lines<'_>,
    path: &Path,
    opts: &ReadOptions,
) -> Result<Vec<FogSample>, IoError> {
    let mut rows: Vec<FogSample> = Vec::new();
    let mut order = OrderCheck::new(opts.timestamp_policy);
    while let Some((ln, line)) = lines.next_line()? {
        if ln == 1 && is_header(line) {
            continue;
        }
        let [t, r, p, y] = split_fixed::<4>(
            path,
            ln,
            line,
            "timestamp_ns,delta_roll,delta_pitch,delta_yaw",
        )?;
        let stamp_ns = parse_int(path, ln, "timestamp_ns", t)?;
        let s = FogSample {
            stamp_ns,
            delta_roll_rad: parse_f64(path, ln, "delta_roll", r)?,
            delta_pitch_rad: parse_f64(path, ln, "delta_pitch", p)?,
            delta_yaw_rad: parse_f64(path, ln, "delta_yaw", y)?,
        };
        order.check(path, ln, stamp_ns)?;
        rows.push(s);
    }
    if rows.is_empty() {
        return Err(IoError::parse(path, 0, "empty file: no FOG rows"));
    }
    if !order.sorted {
        let perm = sort_permutation(&rows.iter().map(|r| r.stamp_ns).collect::<Vec<_>>());
        let mut sorted: Vec<FogSample> = Vec::with_capacity(rows.len());
        let mut merged = 0usize;
        for i in perm {
            let s = rows[i];
            match sorted.last_mut() {
                // Increments with one stamp cover the same interval: they add up.
                Some(last) if last.stamp_ns == s.stamp_ns => {
                    last.delta_roll_rad += s.delta_roll_rad;
                    last.delta_pitch_rad += s.delta_pitch_rad;
                    last.delta_yaw_rad += s.delta_yaw_rad;
                    merged += 1;
                }
                _ => sorted.push(s),
            }
        }
        tracing::warn!(
            "{}: rows out of time order: sorted by timestamp ({merged} rows with a repeated stamp merged)",
            path.display()
        );
        rows = sorted;
    }
    Ok(rows)
}
