//! Reading the CSVs line by line: blocks, lines found in place, fields split and parsed
//! with errors naming file and line, and the stamp-order check.

use super::*;

/// A line inside the reader's buffer: the text is `buf[start..end]`, with
/// `ranges::HEAD_PAD` readable bytes before it, `buf[end] == b','` and `ranges::TAIL_PAD`
/// readable bytes after that.
pub(super) struct PaddedLine<'a> {
    pub(super) line_no: usize,
    pub(super) buf: &'a [u8],
    pub(super) start: usize,
    pub(super) end: usize,
}

impl PaddedLine<'_> {
    pub(super) fn text(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }
}

/// A streaming line reader over one reused block buffer: lines are found with `memchr` and
/// returned in place, without `\n`/`\r\n` or trailing blanks (blank lines are skipped but
/// counted). Every line has `ranges::HEAD_PAD` readable bytes before it and at least
/// `1 + ranges::TAIL_PAD` after it, which the vector parser of LiDAR rows needs.
pub(super) struct Lines<'a> {
    path: PathBuf,
    source: Box<dyn Read + 'a>,
    /// `HEAD_PAD` bytes, then the data space, then `TAIL` bytes that are never filled.
    buf: Vec<u8>,
    /// Start of the bytes not yet returned.
    pos: usize,
    /// End of the bytes read.
    filled: usize,
    eof: bool,
    line_no: usize,
}

impl<'a> Lines<'a> {
    /// Bytes read per call (the data space grows for longer lines).
    pub(super) const BLOCK: usize = 1 << 20;
    /// The sentinel byte and the tail padding.
    const TAIL: usize = 1 + ranges::TAIL_PAD;

    pub(super) fn open(path: &Path, what: &str) -> Result<Lines<'a>, IoError> {
        Self::open_with_block(path, what, Self::BLOCK)
    }

    /// [`Lines::open`] with `block` bytes of data space (tests use tiny ones).
    pub(super) fn open_with_block(
        path: &Path,
        what: &str,
        block: usize,
    ) -> Result<Lines<'a>, IoError> {
        let file = match std::fs::File::open(path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(IoError::Missing {
                    path: path.to_path_buf(),
                    what: what.to_string(),
                });
            }
            Err(e) => return Err(IoError::io(path, e)),
        };
        Ok(Self::from_reader(Box::new(file), path, block))
    }

    /// Lines of any byte source; `path` names it in errors.
    pub(super) fn from_reader(source: Box<dyn Read + 'a>, path: &Path, block: usize) -> Lines<'a> {
        Lines {
            path: path.to_path_buf(),
            source,
            buf: vec![0; ranges::HEAD_PAD + block.max(1) + Self::TAIL],
            pos: ranges::HEAD_PAD,
            filled: ranges::HEAD_PAD,
            eof: false,
            line_no: 0,
        }
    }

    /// The next non-blank line, or `None` at the end.
    pub(super) fn next_line(&mut self) -> Result<Option<(usize, &[u8])>, IoError> {
        Ok(self
            .advance()?
            .map(|(line_no, start, end)| (line_no, &self.buf[start..end])))
    }

    /// The next non-blank line, padded as [`ranges::parse_plain_ranges`] needs (a `,` is
    /// written over the byte after the line).
    pub(super) fn next_padded_line(&mut self) -> Result<Option<PaddedLine<'_>>, IoError> {
        let Some((line_no, start, end)) = self.advance()? else {
            return Ok(None);
        };
        self.buf[end] = b',';
        Ok(Some(PaddedLine {
            line_no,
            buf: &self.buf,
            start,
            end,
        }))
    }

    /// Finds the next non-blank line; returns `(line number, start, end)` in `buf`.
    pub(super) fn advance(&mut self) -> Result<Option<(usize, usize, usize)>, IoError> {
        loop {
            let (start, stop) = match memchr::memchr(b'\n', &self.buf[self.pos..self.filled]) {
                Some(i) => (self.pos, self.pos + i),
                None if self.eof && self.pos == self.filled => return Ok(None),
                None if self.eof => (self.pos, self.filled),
                None => {
                    self.refill()?;
                    continue;
                }
            };
            self.pos = (stop + 1).min(self.filled);
            self.line_no += 1;
            let mut end = stop;
            while end > start && matches!(self.buf[end - 1], b'\r' | b' ' | b'\t') {
                end -= 1;
            }
            if end > start {
                return Ok(Some((self.line_no, start, end)));
            }
        }
    }

    /// Moves the unreturned bytes to the front (after the head padding), doubles the data
    /// space if they fill it, and reads more; sets `eof` when nothing more comes.
    pub(super) fn refill(&mut self) -> Result<(), IoError> {
        let kept = self.filled - self.pos;
        self.buf
            .copy_within(self.pos..self.filled, ranges::HEAD_PAD);
        self.pos = ranges::HEAD_PAD;
        self.filled = ranges::HEAD_PAD + kept;
        let space = self.buf.len() - ranges::HEAD_PAD - Self::TAIL;
        if kept == space {
            self.buf.resize(self.buf.len() + space, 0);
        }
        let space_end = self.buf.len() - Self::TAIL;
        loop {
            match self.source.read(&mut self.buf[self.filled..space_end]) {
                Ok(0) => self.eof = true,
                Ok(n) => self.filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(IoError::io(&self.path, e)),
            }
            return Ok(());
        }
    }
}

#[inline]
pub(super) fn trim_field(f: &[u8]) -> &[u8] {
    let mut a = 0;
    let mut b = f.len();
    while a < b && (f[a] == b' ' || f[a] == b'\t') {
        a += 1;
    }
    while b > a && (f[b - 1] == b' ' || f[b - 1] == b'\t') {
        b -= 1;
    }
    &f[a..b]
}

pub(super) fn field_error(
    path: &Path,
    line: usize,
    name: &str,
    problem: &str,
    text: &[u8],
) -> IoError {
    IoError::parse(
        path,
        line,
        format!("{name}: {problem}: {:?}", String::from_utf8_lossy(text)),
    )
}

/// Parses a decimal integer (optional sign); rejects anything else and overflow.
#[inline]
pub(super) fn parse_int(path: &Path, line: usize, name: &str, f: &[u8]) -> Result<i64, IoError> {
    let t = trim_field(f);
    let (neg, digits) = match t.first() {
        Some(b'-') => (true, &t[1..]),
        Some(b'+') => (false, &t[1..]),
        _ => (false, t),
    };
    if digits.is_empty() {
        return Err(field_error(path, line, name, "not an integer", t));
    }
    let mut v: i64 = 0;
    for &b in digits {
        if !b.is_ascii_digit() {
            return Err(field_error(path, line, name, "not an integer", t));
        }
        v = v
            .checked_mul(10)
            .and_then(|v| v.checked_add(i64::from(b - b'0')))
            .ok_or_else(|| field_error(path, line, name, "integer overflow", t))?;
    }
    Ok(if neg { -v } else { v })
}

#[inline]
pub(super) fn parse_f64(path: &Path, line: usize, name: &str, f: &[u8]) -> Result<f64, IoError> {
    let t = trim_field(f);
    match fast_float2::parse::<f64, _>(t) {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(field_error(path, line, name, "not finite", t)),
        Err(_) => Err(field_error(path, line, name, "not a number", t)),
    }
}

/// True for a header line (`timestamp,...`) on the first line of a file.
pub(super) fn is_header(line: &[u8]) -> bool {
    let first = line.split(|&b| b == b',').next().unwrap_or(&[]);
    let first = trim_field(first);
    first.first().is_some_and(|b| b.is_ascii_alphabetic())
        && String::from_utf8_lossy(first)
            .to_ascii_lowercase()
            .contains("time")
}

/// Splits `line` into exactly `N` comma-separated fields.
#[inline]
pub(super) fn split_fixed<'a, const N: usize>(
    path: &Path,
    line_no: usize,
    line: &'a [u8],
    layout: &str,
) -> Result<[&'a [u8]; N], IoError> {
    let mut out: [&[u8]; N] = [&[]; N];
    let mut n = 0;
    for f in line.split(|&b| b == b',') {
        if n < N {
            out[n] = f;
        }
        n += 1;
    }
    if n != N {
        return Err(IoError::parse(
            path,
            line_no,
            format!("expected {N} columns ({layout}), found {n}"),
        ));
    }
    Ok(out)
}

/// Tracks time order while reading; with `Reject`, a non-increasing stamp is an error.
pub(super) struct OrderCheck {
    policy: TimestampPolicy,
    last: Option<i64>,
    pub(super) sorted: bool,
}

impl OrderCheck {
    pub(super) fn new(policy: TimestampPolicy) -> Self {
        OrderCheck {
            policy,
            last: None,
            sorted: true,
        }
    }

    pub(super) fn check(&mut self, path: &Path, line: usize, stamp_ns: i64) -> Result<(), IoError> {
        if let Some(prev) = self.last
            && stamp_ns <= prev
        {
            if self.policy == TimestampPolicy::Reject {
                let what = if stamp_ns == prev {
                    "repeats"
                } else {
                    "goes backwards from"
                };
                return Err(IoError::parse(
                    path,
                    line,
                    format!(
                        "timestamp {stamp_ns} {what} the previous row's {prev} \
                         (timestamp policy: reject; use sort_with_warning to sort instead)"
                    ),
                ));
            }
            self.sorted = false;
        }
        self.last = Some(stamp_ns);
        Ok(())
    }
}

/// A stable permutation sorting `stamps`.
pub(super) fn sort_permutation(stamps: &[i64]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..stamps.len()).collect();
    idx.sort_by_key(|&i| stamps[i]);
    idx
}
