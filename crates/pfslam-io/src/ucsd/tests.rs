use super::*;

#[test]
fn parse_int_cases() {
    let p = Path::new("x");
    assert_eq!(
        parse_int(p, 1, "t", b" 1544582648735140000 ").unwrap(),
        1544582648735140000
    );
    assert_eq!(parse_int(p, 1, "t", b"-12").unwrap(), -12);
    assert!(parse_int(p, 1, "t", b"1.5").is_err());
    assert!(parse_int(p, 1, "t", b"").is_err());
    assert!(parse_int(p, 1, "t", b"99999999999999999999").is_err());
}

/// Lines split, trimmed and numbered like `str::lines` would, whatever the block size
/// (refills mid-line, lines longer than the block), with the padding the vector parser
/// relies on.
#[test]
fn lines_are_found_across_refills() {
    let text = "a,1\r\n\n  \nbb , 2 \t\r\nlonger line than the block,3\n\nlast";
    let want: Vec<(usize, &str)> = text
        .split('\n')
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches(['\r', ' ', '\t'])))
        .filter(|(_, l)| !l.is_empty())
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.csv");
    std::fs::write(&path, text).unwrap();
    for block in [1, 2, 3, 7, 64, 1 << 20] {
        let mut lines = Lines::open_with_block(&path, "rows", block).unwrap();
        let mut got = Vec::new();
        while let Some(l) = lines.next_padded_line().unwrap() {
            assert!(l.start >= ranges::HEAD_PAD);
            assert!(l.buf.len() >= l.end + 1 + ranges::TAIL_PAD);
            assert_eq!(l.buf[l.end], b',');
            got.push((l.line_no, String::from_utf8(l.text().to_vec()).unwrap()));
        }
        let got: Vec<(usize, &str)> = got.iter().map(|(n, l)| (*n, l.as_str())).collect();
        assert_eq!(got, want, "block {block}");
    }
}

/// Rows through the reader's path (vector parser, scalar fallback) give exactly what the
/// scalar parser gives: the same stamp and range bits, or the same error. The fields mix
/// the plain form with every form the vector parser must refuse.
#[test]
fn vector_rows_equal_scalar_rows() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
    let odd = [
        "",
        ".",
        "12.",
        ".5",
        " 1.5",
        "1.5 ",
        "1e3",
        "-1",
        "+1",
        "nan",
        "inf",
        "1.2.3",
        "16777215",
        "16777216",
        "1677721.5",
        ".00000000000001",
        "0.000000000000001",
        "12345678901234",
        "123456789012345",
        "0x10",
        "1,5",
    ];
    let path = Path::new("lidar.csv");
    let (mut vector_rows, mut rows) = (0, 0);
    for _ in 0..20_000 {
        let beams = rng.random_range(1..40usize);
        let columns = match rng.random_range(0..20) {
            0 => beams - 1,
            1 => beams + 1,
            _ => beams,
        };
        let plain = rng.random_range(0..3) > 0;
        let fields: Vec<String> = (0..columns)
            .map(|_| match rng.random_range(0..8) {
                _ if !plain && rng.random_range(0..6) == 0 => {
                    odd[rng.random_range(0..odd.len())].to_string()
                }
                // shortest f32 text often has more digits than 2^24 allows
                _ if !plain && rng.random_range(0..6) == 0 => {
                    format!("{}", rng.random_range(0.0..80.0f32))
                }
                0 => "0".to_string(),
                1 => format!(
                    "{:.*}",
                    rng.random_range(0..5),
                    rng.random_range(0.0..1e3f64)
                ),
                _ => format!("{:.3}", rng.random_range(0.0..80.0f64)),
            })
            .collect();
        let line = format!("{},{}", rng.random_range(0..1_000_000i64), fields.join(","));
        // the line somewhere in a buffer of junk, as `Lines` leaves it
        let start = ranges::HEAD_PAD + rng.random_range(0..40);
        let mut buf: Vec<u8> = (0..start).map(|_| rng.random()).collect();
        buf.extend_from_slice(line.as_bytes());
        let end = buf.len();
        buf.push(b',');
        buf.extend((0..ranges::TAIL_PAD + rng.random_range(0..9)).map(|_| rng.random::<u8>()));

        let mut scans = ScanSet::new(beams);
        let mut row = Vec::new();
        let mut scratch = ranges::RangeScratch::default();
        let padded = PaddedLine {
            line_no: 3,
            buf: &buf,
            start,
            end,
        };
        let got = push_lidar_row(path, &padded, &mut scans, &mut row, &mut scratch);
        let mut want_row = Vec::new();
        let want = parse_lidar_row(path, 3, line.as_bytes(), beams, &mut want_row);
        match (got, want) {
            (Ok(g), Ok(w)) => {
                assert_eq!(g, w, "{line}");
                let bits = |r: &[f32]| r.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(scans.ranges(0)), bits(&want_row), "{line}");
                assert_eq!(scans.len(), 1);
                rows += 1;
                vector_rows += usize::from(row.is_empty());
            }
            (Err(g), Err(w)) => assert_eq!(g.to_string(), w.to_string(), "{line}"),
            (g, w) => panic!("{line}: {g:?} against {w:?}"),
        }
    }
    // Most good rows took the vector parser (where there is one).
    if ranges::vector_available() {
        assert!(vector_rows * 2 > rows, "{vector_rows} of {rows}");
    }
}

#[test]
fn plain_decimal_fast_path_equals_fast_float() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
    let mut texts: Vec<String> = [
        "0",
        "0.0",
        "1.",
        "000.5000",
        "80",
        "79.99999999999999999999",
        "1e3",
        "1.5e-2",
        "0.1",
        "16777217",
        "9007199254740993",
        "0.00000000000000000000001",
        "3.4028235e38",
        "123456789012345678901234",
        "1.00000005960464477539",
        "0.000000000000000000000001",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for _ in 0..200_000 {
        let v: f32 = rng.random_range(0.0..80.0);
        texts.push(format!("{v}"));
        texts.push(format!("{:.3}", rng.random_range(0.0..80.0f64)));
        texts.push(format!(
            "{:.*}",
            rng.random_range(0..14),
            rng.random_range(0.0..1e4f64)
        ));
        // halfway cases between two f32s, written exactly
        let h = f64::from(v) + f64::from(v.next_up() - v) / 2.0;
        texts.push(format!("{h}"));
    }
    let mut fast = 0;
    for t in &texts {
        for tail in ["", ",7", " ,1"] {
            let s = format!("{t}{tail}");
            let want = fast_float2::parse_partial::<f32, _>(s.as_bytes()).unwrap();
            if let Some((v, used)) = parse_plain_decimal_f32(s.as_bytes()) {
                fast += 1;
                assert_eq!(v.to_bits(), want.0.to_bits(), "{s:?}");
                assert_eq!(used, want.1, "{s:?}");
            }
        }
    }
    assert!(fast > texts.len() * 2, "fast path taken {fast} times");
}

/// True when `c` is an f32 nearest to `m / 10^k` (m > 0, k <= 15), decided in exact
/// integer arithmetic: each candidate `sig * 2^exp` and the quotient are scaled by
/// `10^k * 2^80`, which keeps both below 2^128 for quotients above 10^-15.
fn is_nearest_f32(m: u32, k: u32, c: f32) -> bool {
    let distance = |x: f32| -> u128 {
        let bits = x.to_bits();
        let (sig, exp) = (
            u128::from(bits & 0x7f_ffff | 0x80_0000),
            ((bits >> 23) & 0xff) as i32 - 150,
        );
        assert!((1..255).contains(&(bits >> 23)) && exp + 80 >= 0);
        let scaled_x = (sig * 10u128.pow(k)) << (exp + 80);
        (u128::from(m) << 80).abs_diff(scaled_x)
    };
    let d = distance(c);
    d <= distance(c.next_up()) && d <= distance(c.next_down())
}

/// The proof behind `small_decimal_f32`, for every mantissa below 2^24 at every decimal
/// count 0-15 (268M cases; a stride in unoptimised builds). The f64 quotient of two exact
/// f64s is correctly rounded, so rounding it to f32 gives the nearest f32 unless it lies
/// within a few f64 ulps of halfway between two f32s; the product must equal that. The
/// few quotients near halfway are decided exactly instead.
#[test]
fn small_decimals_are_correctly_rounded_for_every_mantissa() {
    let stride = if cfg!(debug_assertions) { 997 } else { 1 };
    let (mut cases, mut near_halfway) = (0u64, 0u64);
    for (k, &pow) in POW10.iter().enumerate().take(16) {
        for m in (0..1u32 << 24).step_by(stride) {
            let product = small_decimal_f32(m, k);
            let q = f64::from(m) / pow;
            if (q.to_bits() & ((1 << 29) - 1)).abs_diff(1 << 28) <= 8 {
                near_halfway += 1;
                assert!(is_nearest_f32(m, k as u32, product), "{m} / 10^{k}");
            } else {
                assert_eq!(product.to_bits(), (q as f32).to_bits(), "{m} / 10^{k}");
            }
            cases += 1;
        }
    }
    assert_eq!(cases, 16 * (1u64 << 24).div_ceil(stride as u64));
    // One quotient (13494369 / 10^13) lies that close to halfway; the exact check
    // decides it. Many would mean the window above is too wide to be meaningful.
    assert!(near_halfway < 100, "{near_halfway}");
}

#[test]
fn exact_nearest_check_tells_neighbours_apart() {
    for (m, k) in [
        (1u32, 1u32),
        (79_999, 3),
        (13_494_369, 13),
        (16_777_215, 15),
    ] {
        let q = (f64::from(m) / POW10[k as usize]) as f32;
        assert!(is_nearest_f32(m, k, q), "{m} / 10^{k}");
        assert!(!is_nearest_f32(m, k, q.next_up()), "{m} / 10^{k}");
        assert!(!is_nearest_f32(m, k, q.next_down()), "{m} / 10^{k}");
    }
}

#[test]
fn header_detection() {
    assert!(is_header(b"timestamp,left,right"));
    assert!(!is_header(b"abc,1,2"));
    assert!(!is_header(b"1,2,3"));
}
