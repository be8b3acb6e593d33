//! Line pre-processing and word splitting (reference §1 and §9), kept apart
//! from the controller so the byte-level rules are easy to check on their own.

/// Longest line Grbl accepts after stripping.
pub const MAX_LINE: usize = 79;
/// grblHAL's: a 257-byte line buffer.
pub const MAX_LINE_HAL: usize = 256;

/// Incremental line cleaner: fed raw bytes of one line, it applies Grbl's
/// pre-processing (drop bytes <= 0x20, comments, `/`, upper-case). It is
/// incremental because a line longer than the RX buffer is consumed in pieces.
#[derive(Debug, Clone)]
pub struct LineBuilder {
    text: String,
    in_paren: bool,
    in_semicolon: bool,
    too_long: bool,
    max: usize,
}

impl Default for LineBuilder {
    fn default() -> Self {
        LineBuilder::with_max(MAX_LINE)
    }
}

impl LineBuilder {
    /// A builder for lines of at most `max` characters after stripping.
    pub fn with_max(max: usize) -> LineBuilder {
        LineBuilder { text: String::new(), in_paren: false, in_semicolon: false, too_long: false, max }
    }

    pub fn push(&mut self, b: u8) {
        if self.in_semicolon || b <= 0x20 || b >= 0x7F {
            return;
        }
        if self.in_paren {
            if b == b')' {
                self.in_paren = false;
            }
            return;
        }
        match b {
            b'(' => self.in_paren = true,
            b';' => self.in_semicolon = true,
            b'/' => {}
            _ => {
                if self.text.len() >= self.max {
                    self.too_long = true;
                } else {
                    self.text.push(b.to_ascii_uppercase() as char);
                }
            }
        }
    }

    /// The cleaned line, or None if it was too long (error:11).
    pub fn finish(self) -> Option<String> {
        if self.too_long {
            None
        } else {
            Some(self.text)
        }
    }
}

/// One `letter value` word.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Word {
    pub letter: char,
    pub value: f64,
}

/// Splits a cleaned G-code line into words. Errors are Grbl status codes:
/// 1 = not a letter where one was expected, 2 = bad or missing number.
pub fn split_words(line: &str) -> Result<Vec<Word>, u16> {
    let b = line.as_bytes();
    let mut i = 0;
    let mut words = Vec::new();
    while i < b.len() {
        let letter = b[i];
        if !letter.is_ascii_uppercase() {
            return Err(1);
        }
        i += 1;
        let (value, used) = read_number(&b[i..]).ok_or(2u16)?;
        i += used;
        words.push(Word { letter: letter as char, value });
    }
    Ok(words)
}

/// Reads an optional sign, digits and at most one decimal point (no exponent,
/// like Grbl's read_float). Returns the value and bytes consumed.
fn read_number(b: &[u8]) -> Option<(f64, usize)> {
    let mut i = 0;
    if i < b.len() && (b[i] == b'-' || b[i] == b'+') {
        i += 1;
    }
    let mut digits = 0;
    let mut dot = false;
    while i < b.len() {
        match b[i] {
            b'0'..=b'9' => digits += 1,
            b'.' if !dot => dot = true,
            _ => break,
        }
        i += 1;
    }
    if digits == 0 {
        return None;
    }
    let s = std::str::from_utf8(&b[..i]).ok()?;
    let v: f64 = s.parse().ok()?;
    if v.is_finite() {
        Some((v, i))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clean(s: &str) -> Option<String> {
        let mut lb = LineBuilder::default();
        s.bytes().for_each(|b| lb.push(b));
        lb.finish()
    }

    #[test]
    fn cleaning() {
        assert_eq!(clean("g1 x1 (comment) y2 ; tail").unwrap(), "G1X1Y2");
        assert_eq!(clean("\t/G0  X-1.5").unwrap(), "G0X-1.5");
        assert_eq!(clean(&"X1".repeat(39)).unwrap().len(), 78);
        assert!(clean(&"X1".repeat(40)).is_none());
        assert!(clean(&format!("{}({})", "X1".repeat(39), "a".repeat(100))).is_some());
    }

    #[test]
    fn words() {
        assert_eq!(
            split_words("G1X-1.5F.5").unwrap(),
            vec![
                Word { letter: 'G', value: 1.0 },
                Word { letter: 'X', value: -1.5 },
                Word { letter: 'F', value: 0.5 }
            ]
        );
        assert_eq!(split_words("1X"), Err(1));
        assert_eq!(split_words("GX1"), Err(2));
        assert_eq!(split_words("X1.2.3"), Err(1));
        assert_eq!(split_words("X-"), Err(2));
    }
}
