//! A log's lines, one parsed message at a time: malformed lines are dropped and counted in
//! the account (or, strict, refused). The batch reader, the streamed pose reader and the
//! live reader all read through [`Lines`].

use super::CarmenOptions;
use super::parse::{Message, parse_line};
use crate::IoError;
use crate::account::InputAccount;
use std::io::{BufRead, Read};
use std::path::Path;

/// Wraps a possibly gzipped byte source for buffered reading (gzip detected by its magic
/// bytes, read here and put back in front of the rest).
pub(super) fn maybe_gz<'a>(
    mut source: impl Read + 'a,
    path: &Path,
) -> Result<Box<dyn BufRead + 'a>, IoError> {
    let mut magic = [0u8; 2];
    let mut n = 0;
    while n < magic.len() {
        match source.read(&mut magic[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(IoError::io(path, e)),
        }
    }
    let whole = std::io::Cursor::new(magic).take(n as u64).chain(source);
    if n == 2 && magic == [0x1f, 0x8b] {
        Ok(Box::new(std::io::BufReader::with_capacity(
            1 << 16,
            flate2::read::MultiGzDecoder::new(whole),
        )))
    } else {
        Ok(Box::new(std::io::BufReader::with_capacity(1 << 16, whole)))
    }
}

/// The parsed lines of a byte source.
pub(super) struct Lines<'a> {
    reader: Box<dyn BufRead + 'a>,
    buf: Vec<u8>,
    /// The readings of the last laser line returned.
    pub ranges: Vec<f32>,
    /// Lines read so far.
    pub line_no: usize,
}

impl<'a> Lines<'a> {
    /// The lines of `reader` (see [`maybe_gz`]).
    pub fn new(reader: Box<dyn BufRead + 'a>) -> Self {
        Lines {
            reader,
            buf: Vec::new(),
            ranges: Vec::new(),
            line_no: 0,
        }
    }

    /// The next well-formed line's message (a laser line's readings in [`Self::ranges`]);
    /// `None` at the end of the source. Blocks until a whole line (or the end) arrives.
    pub fn next_message(
        &mut self,
        path: &Path,
        options: &CarmenOptions,
        acc: &mut InputAccount,
    ) -> Result<Option<Message>, IoError> {
        loop {
            self.buf.clear();
            let n = self
                .reader
                .read_until(b'\n', &mut self.buf)
                .map_err(|e| IoError::parse(path, self.line_no + 1, format!("read failed: {e}")))?;
            if n == 0 {
                return Ok(None);
            }
            self.line_no += 1;
            let parsed = std::str::from_utf8(&self.buf)
                .map_err(|_| "line is not valid UTF-8 text".to_string())
                .and_then(|t| parse_line(t, &mut self.ranges));
            match parsed {
                Ok(msg) => return Ok(Some(msg)),
                Err(why) if options.strict => {
                    return Err(IoError::parse(path, self.line_no, why));
                }
                Err(why) => self.count_malformed(path, &why, acc),
            }
        }
    }

    /// Counts the malformed line just read (a cut last line with a warning).
    fn count_malformed(&self, path: &Path, why: &str, acc: &mut InputAccount) {
        let line_no = self.line_no;
        let kind = first_word(&self.buf);
        let laser = ["FLASER", "RLASER", "ROBOTLASER1", "RAWLASER1", "RAWLASER2"];
        let what = if laser.contains(&kind.as_str()) {
            acc.scans_read += 1;
            "scans"
        } else {
            "lines"
        };
        if self.buf.last() != Some(&b'\n') {
            acc.warnings.push(format!(
                "{}:{line_no}: the last line is cut ({why}): dropped",
                path.display()
            ));
            acc.drop_one(what, "cut last line", || format!("line {line_no}"));
        } else {
            acc.drop_one(what, "malformed", || format!("line {line_no}: {why}"));
        }
    }
}

/// Calls `f` with every line's message and readings; malformed lines are dropped and counted
/// in `acc` (or, strict, refused).
pub(super) fn for_each_message(
    reader: Box<dyn BufRead + '_>,
    path: &Path,
    options: &CarmenOptions,
    acc: &mut InputAccount,
    mut f: impl FnMut(Message, &[f32], &mut InputAccount) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let mut lines = Lines::new(reader);
    while let Some(msg) = lines.next_message(path, options, acc)? {
        f(msg, &lines.ranges, acc)?;
    }
    acc.records_read = lines.line_no;
    Ok(())
}

fn first_word(buf: &[u8]) -> String {
    String::from_utf8_lossy(buf)
        .split_ascii_whitespace()
        .next()
        .unwrap_or("")
        .to_string()
}
