//! [`super::parse_plain_ranges`] in AVX2 (with BMI1, LZCNT and POPCNT).

use super::INV_POW10;

/// `CLOSE_DOT[16]` is the identity (no dot). `CLOSE_DOT[n]` for `n < 16` closes a dot with
/// `n` decimals after it in the top lanes: the lanes before the dot move one lane up, over
/// it, and lane 0 becomes zero.
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
const IN_FIELD: [u8; 32] = {
    let mut t = [0u8; 32];
    let mut i = 16;
    while i < 32 {
        t[i] = 0xff;
        i += 1;
    }
    t
};

/// [`super::parse_plain_ranges`] once its checks passed.
///
/// # Safety
/// The CPU has the enabled features; `HEAD_PAD <= start <= end`, `buf[end] == b','`,
/// `buf.len() >= end + 1 + TAIL_PAD` and `commas.len() >= end - start + 33`.
#[target_feature(enable = "avx2,bmi1,lzcnt,popcnt")]
pub(super) unsafe fn parse_plain_ranges_avx2(
    buf: &[u8],
    start: usize,
    end: usize,
    out: &mut [f32],
    commas: &mut [u32],
) -> bool {
    // SAFETY: the caller's guarantees are `find_commas`' own.
    let count = unsafe { find_commas(buf, start, end, commas) };
    if count != out.len() {
        return false;
    }
    // SAFETY: the caller's guarantees; `find_commas` wrote the first `count` positions, each
    // in `start..=end`, in increasing order, the last one `end`.
    unsafe { parse_fields(buf, start, commas, out) }
}

/// The first pass: the commas of `buf[start..=end]` into `commas` (their positions in `buf`, in order);
/// returns how many. Each 32-byte block writes eight positions whether or not they exist (a
/// block rarely holds more; then the rest follow one by one), so the count of commas per
/// block costs no branch.
///
/// # Safety
/// As [`parse_plain_ranges_avx2`].
#[target_feature(enable = "avx2,bmi1,lzcnt,popcnt")]
#[inline]
unsafe fn find_commas(buf: &[u8], start: usize, end: usize, commas: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let base = buf.as_ptr();
    let positions = commas.as_mut_ptr();
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
    count
}

/// The second pass: the fields, two per register (field a in the low half, b in the high half), into
/// `out`: the mantissa of each field's digits scaled by its decimals; false where a field is
/// not plain (then `out` holds garbage).
///
/// # Safety
/// As [`parse_plain_ranges_avx2`], and the first `out.len()` of `commas` are the
/// positions of the commas of `buf[start..=end]`, in order.
#[target_feature(enable = "avx2,bmi1,lzcnt,popcnt")]
#[inline]
unsafe fn parse_fields(buf: &[u8], start: usize, commas: &[u32], out: &mut [f32]) -> bool {
    use std::arch::x86_64::*;
    let base = buf.as_ptr();
    let positions = commas.as_ptr();
    let count = out.len();
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
    // SAFETY: called with a comma's position `e`, `start <= e <= end`: 16 bytes from
    // `e - 16 >= HEAD_PAD - 16 = 0` up to `e - 1 < buf.len()`.
    let field = |e: usize| unsafe { _mm_loadu_si128(base.add(e - 16).cast()) };
    // SAFETY: 16 bytes from `len & 15 <= 15` in the 32-byte table.
    let lanes = |len: usize| unsafe { _mm_loadu_si128(IN_FIELD.as_ptr().add(len & 15).cast()) };
    // SAFETY: a whole 16-byte row of the table (`n` is indexed with its bounds checked).
    let close = |n: usize| unsafe { _mm_loadu_si128(CLOSE_DOT[n].as_ptr().cast()) };

    let mut prev_comma = start - 1;
    let mut i = 0;
    while i < count {
        // An odd last field is paired with itself and stored once.
        let j = (i + 1).min(count - 1);
        // SAFETY: i, j < count = out.len(), positions `find_commas` wrote.
        let (ea, eb) = unsafe { (*positions.add(i) as usize, *positions.add(j) as usize) };
        let len_a = ea - prev_comma - 1;
        let len_b = if j == i { len_a } else { eb - ea - 1 };
        long |= len_a | len_b;
        // Both are commas' positions, in `start..=end` (as `field` needs).
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
}
