//! A LiDAR row's ranges parsed with vector instructions, two fields per AVX2 register.
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
pub(super) const HEAD_PAD: usize = 16;
/// Readable bytes the line buffer holds after the `,` sentinel that follows the line.
pub(super) const TAIL_PAD: usize = 32;

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
pub(super) fn small_decimal_f32(mantissa: u32, frac_digits: usize) -> f32 {
    (f64::from(mantissa) * INV_POW10[frac_digits]) as f32
}

/// Caller-owned buffer of [`parse_plain_ranges`]: the row's comma positions.
#[derive(Debug, Default)]
pub(super) struct RangeScratch {
    commas: Vec<u32>,
}

/// Parses `out.len()` comma-separated ranges from `buf[start..end]` into `out`. The caller
/// pads the line: `start >= HEAD_PAD`, `buf[end] == b','` and `TAIL_PAD` bytes follow it;
/// where that does not hold, or the row is not all plain fields, or it has another column
/// count, this returns `false` (and `out` holds garbage) so the scalar parser decides.
pub(super) fn parse_plain_ranges(
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
        // SAFETY: the features were detected; the padding and the scratch length were
        // checked above.
        return unsafe { parse_plain_ranges_avx2(buf, start, end, out, &mut scratch.commas) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = scratch;
    false
}

/// True when this CPU runs the vector parser (AVX2, BMI1, LZCNT, POPCNT).
pub(super) fn vector_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("bmi1")
        && std::arch::is_x86_feature_detected!("lzcnt")
        && std::arch::is_x86_feature_detected!("popcnt")
    {
        return true;
    }
    false
}

/// `CLOSE_DOT[16]` is the identity (no dot). `CLOSE_DOT[n]` for `n < 16` closes a dot with
/// `n` decimals after it in the top lanes: the lanes before the dot move one lane up, over
/// it, and lane 0 becomes zero.
#[cfg(target_arch = "x86_64")]
const CLOSE_DOT: [[u8; 16]; 17] = {
    let mut t = [[0u8; 16]; 17];
    let mut n = 0;
    while n < 17 {
        let mut j = 0;
        while j < 16 {
            t[n][j] = if n == 16 || j + n >= 16 {
                j as u8
            } else if j >= 1 {
                j as u8 - 1
            } else {
                0x80 // zero
            };
            j += 1;
        }
        n += 1;
    }
    t
};

/// `IN_FIELD[len..len + 16]` has its top `len` lanes set (`len < 16`).
#[cfg(target_arch = "x86_64")]
const IN_FIELD: [u8; 32] = {
    let mut t = [0u8; 32];
    let mut i = 16;
    while i < 32 {
        t[i] = 0xff;
        i += 1;
    }
    t
};

/// [`parse_plain_ranges`] once its checks passed.
///
/// # Safety
/// The CPU has the enabled features; `HEAD_PAD <= start <= end`, `buf[end] == b','`,
/// `buf.len() >= end + 1 + TAIL_PAD` and `commas.len() >= end - start + 33`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,lzcnt,popcnt")]
unsafe fn parse_plain_ranges_avx2(
    buf: &[u8],
    start: usize,
    end: usize,
    out: &mut [f32],
    commas: &mut [u32],
) -> bool {
    use std::arch::x86_64::*;
    let base = buf.as_ptr();
    let positions = commas.as_mut_ptr();

    // 1. The commas of buf[start..=end]. Each 32-byte block writes eight positions whether
    //    or not they exist (a block rarely holds more; then the rest follow one by one), so
    //    the count of commas per block costs no branch.
    let comma32 = _mm256_set1_epi8(b',' as i8);
    let mut count = 0usize;
    let mut block = start;
    while block <= end {
        // SAFETY: block <= end and TAIL_PAD = 32 bytes follow buf[end], so 32 are readable.
        let bytes = unsafe { _mm256_loadu_si256(base.add(block).cast()) };
        let mut mask = _mm256_movemask_epi8(_mm256_cmpeq_epi8(bytes, comma32)) as u32;
        if block + 32 > end + 1 {
            mask &= u32::MAX >> (31 - (end - block)); // nothing past the sentinel
        }
        let found = mask.count_ones() as usize;
        for k in 0..8 {
            // SAFETY: count <= block - start (one byte per comma before this block), so
            // count + k < end - start + 8 < commas.len() (at least end - start + 33).
            unsafe {
                *positions.add(count + k) = (block as u32).wrapping_add(mask.trailing_zeros())
            };
            mask &= mask.wrapping_sub(1);
        }
        let mut k = 8;
        while mask != 0 {
            // SAFETY: count + k < count + found <= end - start + 1 < commas.len().
            unsafe { *positions.add(count + k) = block as u32 + mask.trailing_zeros() };
            mask &= mask.wrapping_sub(1);
            k += 1;
        }
        count += found;
        block += 32;
    }
    if count != out.len() {
        return false;
    }

    // 2. The fields, two per register: field a in the low half, b in the high half.
    let ascii_zero = _mm256_set1_epi8(b'0' as i8);
    let dot = _mm256_set1_epi8(b'.' as i8);
    let nine = _mm256_set1_epi8(9);
    let top_lane = _mm256_setr_epi8(
        0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
        0, -1,
    );
    let tens = _mm256_setr_epi8(
        10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1, 10, 1,
        10, 1, 10, 1, 10, 1,
    );
    let hundreds = _mm256_setr_epi16(
        100, 1, 100, 1, 100, 1, 100, 1, 100, 1, 100, 1, 100, 1, 100, 1,
    );
    let ten_thousands = _mm256_setr_epi16(
        10000, 1, 10000, 1, 10000, 1, 10000, 1, 10000, 1, 10000, 1, 10000, 1, 10000, 1,
    );
    // The eight-digit sums sit in dwords 0-1 (a) and 4-5 (b): the high sums must be zero
    // and the low ones below 2^24.
    let too_large = _mm256_setr_epi32(-1, -(1 << 24), 0, 0, -1, -(1 << 24), 0, 0);
    let low_sums = _mm256_setr_epi32(1, 5, 1, 5, 1, 5, 1, 5);
    let mut bad = _mm256_setzero_si256();
    let mut long = 0usize;
    let field = |e: usize| unsafe { _mm_loadu_si128(base.add(e - 16).cast()) };
    let lanes = |len: usize| unsafe { _mm_loadu_si128(IN_FIELD.as_ptr().add(len & 15).cast()) };
    let close = |n: usize| unsafe { _mm_loadu_si128(CLOSE_DOT[n].as_ptr().cast()) };

    let mut prev_comma = start - 1;
    let mut i = 0;
    while i < count {
        // An odd last field is paired with itself and stored once.
        let j = (i + 1).min(count - 1);
        // SAFETY: i, j < count, all written above.
        let (ea, eb) = unsafe { (*positions.add(i) as usize, *positions.add(j) as usize) };
        let len_a = ea - prev_comma - 1;
        let len_b = if j == i { len_a } else { eb - ea - 1 };
        long |= len_a | len_b;
        // SAFETY: start <= e <= end, so e - 16 >= HEAD_PAD - 16 = 0 and e - 1 < buf.len().
        let w = _mm256_set_m128i(field(eb), field(ea));
        let in_field = _mm256_set_m128i(lanes(len_b), lanes(len_a));
        let digit = _mm256_sub_epi8(w, ascii_zero);
        let dots =
            _mm256_movemask_epi8(_mm256_and_si256(_mm256_cmpeq_epi8(w, dot), in_field)) as u32;
        // The last dot's decimals, or 16 for none.
        let na = (dots & 0xffff).leading_zeros() as usize - 16;
        let nb = (dots >> 16).leading_zeros() as usize - 16;
        let kept = _mm256_and_si256(digit, in_field);
        let closed = _mm256_shuffle_epi8(kept, _mm256_set_m128i(close(nb), close(na)));
        // Anything but a digit left in the field (a second dot, a sign, a space, ...), or a
        // field that does not end in a digit (also an empty one).
        bad = _mm256_or_si256(bad, _mm256_subs_epu8(closed, nine));
        bad = _mm256_or_si256(
            bad,
            _mm256_and_si256(_mm256_subs_epu8(digit, nine), top_lane),
        );
        let pairs = _mm256_maddubs_epi16(closed, tens);
        let fours = _mm256_madd_epi16(pairs, hundreds);
        let eights = _mm256_madd_epi16(_mm256_packus_epi32(fours, fours), ten_thousands);
        bad = _mm256_or_si256(bad, _mm256_and_si256(eights, too_large));
        let mantissas = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(eights, low_sums));
        let scales = _mm_setr_pd(INV_POW10[na & 15], INV_POW10[nb & 15]);
        let values = _mm_cvtpd_ps(_mm_mul_pd(_mm_cvtepi32_pd(mantissas), scales));
        // SAFETY: i < count == out.len(), and i + 1 < out.len() when j != i.
        unsafe {
            if j != i {
                _mm_storel_epi64(out.as_mut_ptr().add(i).cast(), _mm_castps_si128(values));
            } else {
                *out.as_mut_ptr().add(i) = _mm_cvtss_f32(values);
            }
        }
        prev_comma = eb;
        i += 2;
    }
    _mm256_testz_si256(bad, bad) == 1 && long < 16
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
    fn close_dot_table() {
        assert_eq!(CLOSE_DOT[16][5], 5);
        // "12.5" in lanes 12..16 with one decimal: lane 15 stays, lanes 1..=14 take j - 1.
        assert_eq!(CLOSE_DOT[1][15], 15);
        assert_eq!(CLOSE_DOT[1][14], 13);
        assert_eq!(CLOSE_DOT[1][0], 0x80);
        // a dot in the top lane ("12."): everything moves up.
        assert_eq!(CLOSE_DOT[0][15], 14);
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
