//! The LiDAR's CSV: one scan per row, plain decimals parsed by a vector parser first.

use super::*;

/// Exact powers of ten as f64 (10^22 is the largest exactly representable one).
pub(super) const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Fast path for the common form of a range, `digits[.digits]` (no sign, no exponent):
/// `(value, bytes used)`, or `None` to leave the field to the general parser. Correctly
/// rounded, so bit-identical to `fast_float2`: the mantissa (< 2^53) and the power of ten
/// (<= 10^22) are exact f64s, their quotient is the correctly rounded f64 (Clinger's fast
/// path), and rounding that to f32 is the correctly rounded f32 unless the f64 lies exactly
/// halfway between two f32s (then double rounding could differ: the general parser decides).
/// Mantissas below 2^24 with at most 15 decimals take `small_decimal_f32` instead.
#[inline(always)]
pub(super) fn parse_plain_decimal_f32(s: &[u8]) -> Option<(f32, usize)> {
    let mut pos = 0;
    let mut mantissa: u64 = 0;
    while pos < s.len() && s[pos].is_ascii_digit() {
        mantissa = mantissa * 10 + u64::from(s[pos] - b'0');
        pos += 1;
        if mantissa >= 1 << 53 {
            return None;
        }
    }
    if pos == 0 {
        return None;
    }
    let mut frac_digits = 0usize;
    if pos < s.len() && s[pos] == b'.' {
        pos += 1;
        while pos < s.len() && s[pos].is_ascii_digit() {
            mantissa = mantissa * 10 + u64::from(s[pos] - b'0');
            pos += 1;
            frac_digits += 1;
            if mantissa >= 1 << 53 || frac_digits > 22 {
                return None;
            }
        }
    }
    // Anything but a field end (an exponent, a second dot, ...) goes to the general parser.
    if pos < s.len() && !matches!(s[pos], b',' | b' ' | b'\t') {
        return None;
    }
    if mantissa < 1 << 24 && frac_digits <= 15 {
        return Some((small_decimal_f32(mantissa as u32, frac_digits), pos));
    }
    let q = mantissa as f64 / POW10[frac_digits];
    const BEYOND_F32: u64 = (1 << 29) - 1;
    if q.to_bits() & BEYOND_F32 == 1 << 28 {
        return None;
    }
    Some((q as f32, pos))
}

/// Column count of a row (for error messages only).
pub(super) fn count_columns(line: &[u8]) -> usize {
    line.iter().filter(|&&b| b == b',').count() + 1
}

/// Parses one `lidar.csv` row into `row` (cleared first); returns the stamp. The hot path
/// parses each range in place with `parse_partial` (no separate split pass); the slow path
/// only builds error messages.
#[inline]
pub(super) fn parse_lidar_row(
    path: &Path,
    ln: usize,
    line: &[u8],
    beam_count: usize,
    row: &mut Vec<f32>,
) -> Result<i64, IoError> {
    row.clear();
    let columns_error = || {
        IoError::parse(
            path,
            ln,
            format!(
                "expected {} columns (timestamp_ns + {beam_count} ranges), found {}",
                beam_count + 1,
                count_columns(line)
            ),
        )
    };
    let comma = line.iter().position(|&b| b == b',').unwrap_or(line.len());
    let stamp_ns = parse_int(path, ln, "timestamp_ns", &line[..comma])?;
    if comma == line.len() {
        return Err(columns_error());
    }
    let mut pos = comma + 1;
    let len = line.len();
    loop {
        let n = row.len();
        let start = pos;
        while pos < len && (line[pos] == b' ' || line[pos] == b'\t') {
            pos += 1;
        }
        if let Some((v, used)) = parse_plain_decimal_f32(&line[pos..]) {
            // The common case: a plain non-negative decimal, then a comma or the end.
            let after = pos + used;
            if after == len || line[after] == b',' {
                if n == beam_count {
                    return Err(columns_error());
                }
                row.push(v);
                if after == len {
                    break;
                }
                pos = after + 1;
                continue;
            }
        }
        let parsed = fast_float2::parse_partial::<f32, _>(&line[pos..]);
        let field_text = || {
            let end = line[start..]
                .iter()
                .position(|&b| b == b',')
                .map_or(len, |e| start + e);
            trim_field(&line[start..end])
        };
        let name = || format!("range {n} (column {})", n + 2);
        let v = match parsed {
            Ok((v, used)) => {
                pos += used;
                while pos < len && (line[pos] == b' ' || line[pos] == b'\t') {
                    pos += 1;
                }
                if pos < len && line[pos] != b',' {
                    return Err(field_error(path, ln, &name(), "not a number", field_text()));
                }
                if !v.is_finite() {
                    return Err(field_error(path, ln, &name(), "not finite", field_text()));
                }
                if v < 0.0 {
                    return Err(field_error(path, ln, &name(), "negative", field_text()));
                }
                v
            }
            Err(_) => return Err(field_error(path, ln, &name(), "not a number", field_text())),
        };
        if n == beam_count {
            return Err(columns_error());
        }
        row.push(v);
        if pos >= len {
            break;
        }
        pos += 1; // the comma
    }
    if row.len() != beam_count {
        return Err(columns_error());
    }
    Ok(stamp_ns)
}

/// Parses a padded line (see [`Lines::next_padded_line`]) into a new scan of `scans`;
/// returns its stamp. Plain rows take the vector parser, straight into the scan set; any
/// other row, including every malformed one, goes through [`parse_lidar_row`] and `row`.
#[inline]
pub(super) fn push_lidar_row(
    path: &Path,
    padded: &PaddedLine<'_>,
    scans: &mut ScanSet,
    row: &mut Vec<f32>,
    scratch: &mut ranges::RangeScratch,
) -> Result<i64, IoError> {
    let (ln, line) = (padded.line_no, padded.text());
    let beam_count = scans.beam_count;
    if let Some(comma) = memchr::memchr(b',', line) {
        let filled = scans.ranges_m.len();
        scans.ranges_m.resize(filled + beam_count, 0.0);
        let first_range = padded.start + comma + 1;
        let out = &mut scans.ranges_m[filled..];
        if ranges::parse_plain_ranges(padded.buf, first_range, padded.end, out, scratch) {
            let stamp_ns = parse_int(path, ln, "timestamp_ns", &line[..comma])?;
            scans.stamps_ns.push(stamp_ns);
            return Ok(stamp_ns);
        }
        scans.ranges_m.truncate(filled);
    }
    let stamp_ns = parse_lidar_row(path, ln, line, beam_count, row)?;
    scans.push(stamp_ns, row);
    Ok(stamp_ns)
}

/// Reads `lidar.csv` with `beam_count` ranges per row.
pub fn read_lidar_csv(
    path: &Path,
    beam_count: usize,
    opts: &ReadOptions,
) -> Result<ScanSet, IoError> {
    let lines = Lines::open(path, "LiDAR rows (timestamp_ns,r_0,...)")?;
    lidar_rows(lines, path, beam_count, opts)
}

/// [`read_lidar_csv`] from any byte source; `path` names it in errors.
pub fn read_lidar_csv_from<'a>(
    source: impl Read + 'a,
    path: &Path,
    beam_count: usize,
    opts: &ReadOptions,
) -> Result<ScanSet, IoError> {
    let lines = Lines::from_reader(Box::new(source), path, Lines::BLOCK);
    lidar_rows(lines, path, beam_count, opts)
}

fn lidar_rows(
    mut lines: Lines<'_>,
    path: &Path,
    beam_count: usize,
    opts: &ReadOptions,
) -> Result<ScanSet, IoError> {
    let mut scans = ScanSet::new(beam_count);
    let mut row: Vec<f32> = Vec::with_capacity(beam_count);
    let mut scratch = ranges::RangeScratch::default();
    let mut order = OrderCheck::new(opts.timestamp_policy);
    while let Some(padded) = lines.next_padded_line()? {
        let ln = padded.line_no;
        if ln == 1 && is_header(padded.text()) {
            continue;
        }
        let stamp_ns = push_lidar_row(path, &padded, &mut scans, &mut row, &mut scratch)?;
        order.check(path, ln, stamp_ns)?;
    }
    if scans.is_empty() {
        return Err(IoError::parse(path, 0, "empty file: no LiDAR rows"));
    }
    if !order.sorted {
        let perm = sort_permutation(&scans.stamps_ns);
        let mut sorted = ScanSet::new(beam_count);
        let mut dropped = 0usize;
        for i in perm {
            if sorted.stamps_ns.last() == Some(&scans.stamps_ns[i]) {
                dropped += 1;
                continue;
            }
            sorted.push(scans.stamps_ns[i], scans.ranges(i));
        }
        tracing::warn!(
            "{}: rows out of time order: sorted by timestamp ({dropped} rows with a repeated stamp dropped)",
            path.display()
        );
        scans = sorted;
    }
    Ok(scans)
}
