//! A G-code file read line by line, in constant memory whatever its size or
//! content.

use crate::error::{Error, Result};

/// The longest line of a G-code file the sender reads: far beyond any G-code a
/// controller takes (Grbl: 80 characters; grblHAL: 256) even with long
/// comments, and a bound on memory for a file that is no text at all
/// (`/dev/zero`).
pub const MAX_FILE_LINE: usize = 64 * 1024;

/// How far an over-long line is read to tell its length: a line without end
/// (`/dev/zero`) is not read for ever.
const MEASURE_LIMIT: usize = 16 << 20;

/// The lines of a G-code file (`\n` or `\r\n` ends), each at most
/// `MAX_FILE_LINE` bytes kept: a longer one is an error naming it, quoting
/// its start and giving its length (its rest is read past, never kept).
pub struct FileLines<R> {
    reader: R,
    shown: String,
    number: usize,
    /// A line went on beyond `MEASURE_LIMIT`: nothing more is read.
    ended: bool,
}

impl<R: std::io::BufRead> FileLines<R> {
    /// Lines of `reader`, named `shown` in errors.
    pub fn new(reader: R, shown: &str) -> Self {
        FileLines { reader, shown: shown.to_string(), number: 0, ended: false }
    }

    /// Reads one line into `kept` (up to the cap); its full length, or the
    /// length read and `true` if it goes on beyond `MEASURE_LIMIT`; `None`
    /// at the end.
    fn read_line(&mut self, kept: &mut Vec<u8>) -> std::io::Result<Option<(usize, bool)>> {
        let mut length = 0;
        loop {
            if length > MEASURE_LIMIT {
                return Ok(Some((length, true)));
            }
            let available = self.reader.fill_buf()?;
            if available.is_empty() {
                return Ok((length > 0).then_some((length, false)));
            }
            let end = available.iter().position(|&b| b == b'\n');
            let chunk = &available[..end.unwrap_or(available.len())];
            let room = (MAX_FILE_LINE + 1).saturating_sub(kept.len());
            kept.extend_from_slice(&chunk[..chunk.len().min(room)]);
            length += chunk.len();
            let used = end.map_or(chunk.len(), |i| i + 1);
            self.reader.consume(used);
            if end.is_some() {
                return Ok(Some((length, false)));
            }
        }
    }
}

impl<R: std::io::BufRead> Iterator for FileLines<R> {
    type Item = Result<String>;

    fn next(&mut self) -> Option<Result<String>> {
        if self.ended {
            return None;
        }
        let mut kept = Vec::new();
        let (length, endless) = match self.read_line(&mut kept) {
            Ok(line) => line?,
            Err(e) => return Some(Err(Error::Io(format!("{}: {e}", self.shown)))),
        };
        self.number += 1;
        let text = String::from_utf8_lossy(&kept);
        let text = text.strip_suffix('\r').unwrap_or(&text);
        if length > MAX_FILE_LINE {
            // A line not read to its end leaves no place to go on from.
            self.ended = endless;
            let more = if endless { "more than " } else { "" };
            return Some(Err(Error::Io(format!(
                "{}:{} `{}… ({more}{length} bytes)`: longer than any G-code line ({MAX_FILE_LINE} bytes at most)",
                self.shown,
                self.number,
                super::sender::quoted_start(text)
            ))));
        }
        Some(Ok(text.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(bytes: &[u8]) -> Vec<std::result::Result<String, String>> {
        FileLines::new(bytes, "job.nc").map(|l| l.map_err(|e| e.to_string())).collect()
    }

    #[test]
    fn lines_end_at_lf_or_crlf_and_the_last_needs_no_end() {
        assert_eq!(lines(b"G21\r\n\nG1X1"), vec![Ok("G21".into()), Ok(String::new()), Ok("G1X1".into())]);
        assert!(lines(b"").is_empty());
    }

    #[test]
    fn a_line_beyond_the_cap_is_an_error_quoting_its_start_and_length() {
        let mut file = b"G21\nG1X".to_vec();
        file.extend(std::iter::repeat_n(b'1', 3 * MAX_FILE_LINE));
        file.extend_from_slice(b"\nG1X2\n");
        let read = lines(&file);
        assert_eq!(read.len(), 3);
        let err = read[1].clone().unwrap_err();
        let length = 3 * MAX_FILE_LINE + 3;
        assert!(err.starts_with(&format!("job.nc:2 `G1X{}… ({length} bytes)`", "1".repeat(77))), "{err}");
        assert!(err.len() < 300, "{err}");
        // The rest of the file reads on.
        assert_eq!(read[2], Ok("G1X2".into()));
    }

    #[test]
    fn a_line_without_end_is_not_read_for_ever() {
        let endless = std::io::BufReader::new(std::io::repeat(b'0'));
        let mut read = FileLines::new(endless, "/dev/zero");
        let err = read.next().unwrap().unwrap_err().to_string();
        assert!(err.starts_with(&format!("/dev/zero:1 `{}… (more than ", "0".repeat(80))), "{err}");
        assert!(read.next().is_none());
    }
}
