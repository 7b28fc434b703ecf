//! A LiDAR row's ranges parsed with vector instructions, two fields per AVX2 register (the
//! kernel in `x86.rs`; the car's scalar parser in `crate::ucsd` is its portable twin).
//!
//! The scalar reader spent most of its time in mispredicted branches: where a field's digits,
//! its dot and its comma fall changes from field to field. Here every field costs the same
//! straight-line code. A first pass lists the row's commas (32 bytes per compare). Then each
//! field is loaded so that it ends in the top lane of a 16-byte half; a table shuffle closes
//! the gap left by its dot, two multiply-adds sum its digits, and the mantissa is scaled by
//! `10^-decimals` in f64. Every check is ORed into one flag tested once per row.
//!
//! Only the plain form the writers produce takes this path: digits with at most one dot, at
//! most 15 bytes, ending in a digit, with a mantissa below 2^24. Its value is then
//! `small_decimal_f32` of the same mantissa and decimal count, the correctly rounded f32
//! that the scalar parser also computes, so the result is bit-identical. A row with anything
//! else (spaces, signs, exponents, empty or long fields, another column count) returns
//! `false`, and the caller re-parses it with the scalar parser, which also writes the errors.

/// Readable bytes the line buffer holds before a line's first byte (a field's load ends at
/// its comma and may start up to 16 bytes earlier).
pub(crate) const HEAD_PAD: usize = 16;
/// Readable bytes the line buffer holds after the `,` sentinel that follows the line.
pub(crate) const TAIL_PAD: usize = 32;

/// `INV_POW10[k]` is the f64 nearest `10^-k`; see [`small_decimal_f32`].
const INV_POW10: [f64; 16] = [
    1e0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 1e-14,
    1e-15,
];

/// `mantissa / 10^frac_digits` correctly rounded to f32, for a mantissa below 2^24 and at
/// most 15 decimals: the product with the f64 reciprocal, rounded to f32 (an f32 division
/// would reach only 10 decimals and measures no faster; see
/// docs/decisions/0012-lidar-csv-reader.md). The product is within two f64 ulps of the
/// quotient, so it is the correctly rounded f32 unless the quotient lies
/// that close to halfway between two f32s; `small_decimals_are_correctly_rounded_for_every_mantissa`
/// checks all 268M inputs, the one near halfway exactly.
#[inline(always)]
pub(crate) fn small_decimal_f32(mantissa: u32, frac_digits: usize) -> f32 {
    (f64::from(mantissa) * INV_POW10[frac_digits]) as f32
}

/// Caller-owned buffer of [`parse_plain_ranges`]: the row's comma positions.
#[derive(Debug, Default)]
pub(crate) struct RangeScratch {
    commas: Vec<u32>,
}

#[cfg(target_arch = "x86_64")]
mod x86;

/// Parses `out.len()` comma-separated ranges from `buf[start..end]` into `out`. The caller
/// pads the line: `start >= HEAD_PAD`, `buf[end] == b','` and `TAIL_PAD` bytes follow it;
/// where that does not hold, or the row is not all plain fields, or it has another column
/// count, this returns `false` (and `out` holds garbage) so the scalar parser decides.
pub(crate) fn parse_plain_ranges(
    buf: &[u8],
    start: usize,
    end: usize,
    out: &mut [f32],
    scratch: &mut RangeScratch,
) -> bool {
    let padded = start >= HEAD_PAD
        && start <= end
        && end < u32::MAX as usize
        && end
            .checked_add(1 + TAIL_PAD)
            .is_some_and(|n| n <= buf.len())
        && buf[end] == b',';
    if !padded || out.is_empty() {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    if vector_available() {
        // Room for every byte being a comma, plus the pass's unconditional writes.
        let room = end - start + 1 + 32;
        if scratch.commas.len() < room {
            scratch.commas.resize(room, 0);
        }
        // SAFETY: the CPU has the features (`vector_available`); the padding and the
        // scratch length were checked above.
        return unsafe { x86::parse_plain_ranges_avx2(buf, start, end, out, &mut scratch.commas) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = scratch;
    false
}

/// True when this CPU runs the vector parser (AVX2, BMI1, LZCNT, POPCNT), as
/// `pfslam::kernels::cpu` detected them.
pub(crate) fn vector_available() -> bool {
    pfslam::kernels::cpu().avx2_bit_ops()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn padded(line: &str) -> (Vec<u8>, usize, usize) {
        let mut buf = vec![0u8; HEAD_PAD];
        buf.extend_from_slice(line.as_bytes());
        let end = buf.len();
        buf.push(b',');
        buf.resize(end + 1 + TAIL_PAD, 0);
        (buf, HEAD_PAD, end)
    }

    #[test]
    fn plain_fields_parse_and_others_are_refused() {
        let cases: &[(&str, Option<&[f32]>)] = &[
            ("1.5,2,0,79.999", Some(&[1.5, 2.0, 0.0, 79.999])),
            ("1.5,2,0,79.999,8", None), // too many columns
            ("1.5,2,0", None),          // too few
            (
                "007,.5,.00000000000001,16777215",
                Some(&[7.0, 0.5, 1e-14, 16_777_215.0]),
            ),
            ("1677721.5,12345678901234,1,2", None), // a 14-digit mantissa
            ("1,2,3,16777216", None),               // mantissa 2^24
            ("1,2,3,0.0000000000000001", None),     // 16 decimals: too long
            // 16 bytes and more: the lanes would lose the leading digits (giving 0 and 0.5)
            ("1,10000000000000.5,3,4", None),
            ("1,1000000000000000000.5,3,4", None),
            ("1,,3,4", None),
            ("1,.,3,4", None),
            ("1, 2,3,4", None),
            ("1,-2,3,4", None),
            ("1,2e3,3,4", None),
            ("1,2.3.4,3,4", None),
            ("1,2,3,4.", None), // ends in a dot: the scalar parser takes it
        ];
        for (line, want) in cases {
            let (buf, start, end) = padded(line);
            let mut out = vec![0f32; 4];
            let ok = parse_plain_ranges(&buf, start, end, &mut out, &mut RangeScratch::default());
            if !vector_available() {
                assert!(!ok);
                continue;
            }
            match want {
                Some(w) => {
                    assert!(ok, "{line:?}");
                    assert_eq!(&out[..], *w, "{line:?}");
                }
                None => assert!(!ok, "{line:?}"),
            }
        }
    }
}
