//! Splitting the program into lines for [`super::Program::index`]: the pieces of
//! `source.split('\n')`, found eight bytes at a time.
//!
//! A G-code line is some 30 bytes; `str::split` looks for each line end with a call of
//! `memchr` (whose set-up outweighs so short a search) and compares the match with a
//! call of `memcmp`: about half the time of the index in a profile of arcspiral.ngc.
//! Here the bytes are loaded eight at a time and a carry-free test tells whether any
//! of them is a line feed (and which is the first).
//!
//! Invariants: the pieces are exactly those of `source.split('\n')` (the last one,
//! after the last line feed, included even when empty); no byte past the end is read.

/// The lines of a text, as [`str::split`] at `'\n'` yields them.
pub(super) struct Lines<'s> {
    source: &'s str,
    /// Where the next line starts; `None` once the last one is out.
    next: Option<usize>,
}

impl<'s> Lines<'s> {
    /// The lines of `source`.
    pub(super) fn new(source: &'s str) -> Self {
        Self {
            source,
            next: Some(0),
        }
    }
}

impl<'s> Iterator for Lines<'s> {
    type Item = &'s str;

    #[inline]
    fn next(&mut self) -> Option<&'s str> {
        let start = self.next?;
        let end = line_feed(self.source.as_bytes(), start);
        self.next = (end < self.source.len()).then_some(end + 1);
        // A line feed is a character boundary: the slice always exists.
        self.source.get(start..end)
    }
}

/// The index of the first `\n` in `b` at or after `from`, or `b.len()`.
#[inline]
fn line_feed(b: &[u8], from: usize) -> usize {
    const ONES: u64 = u64::from_le_bytes([0x01; 8]);
    const HIGHS: u64 = u64::from_le_bytes([0x80; 8]);
    const FEEDS: u64 = u64::from_le_bytes([b'\n'; 8]);
    let mut i = from;
    while let Some(chunk) = b.get(i..).and_then(<[u8]>::first_chunk::<8>) {
        // Zero bytes where the line feeds are; the lowest flag below marks the first
        // zero byte exactly (a borrow can only flag bytes above a zero byte).
        let x = u64::from_le_bytes(*chunk) ^ FEEDS;
        let found = x.wrapping_sub(ONES) & !x & HIGHS;
        if found != 0 {
            return i + (found.trailing_zeros() / 8) as usize;
        }
        i += 8;
    }
    let tail = b.get(i..).unwrap_or_default();
    tail.iter()
        .position(|&c| c == b'\n')
        .map_or(b.len(), |p| i + p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lines_are_those_of_str_split() {
        let texts = [
            "",
            "\n",
            "\n\n",
            "g1 x1",
            "g1 x1\n",
            "g0 z1\r\ng1 x1.5 y-2 (°)\n\ng2 r1.997999 x1.613302 y-1.178668\nm2",
            "0123456\n01234567\n012345678\n\u{e9}\u{e9}\u{e9}\u{e9}\u{e9}\n",
        ];
        for text in texts {
            let ours: Vec<&str> = Lines::new(text).collect();
            let std: Vec<&str> = text.split('\n').collect();
            assert_eq!(ours, std, "{text:?}");
        }
        // A line feed at every offset within and across eight-byte chunks.
        for at in 0..40 {
            let mut text = "x".repeat(40);
            text.replace_range(at..=at, "\n");
            let ours: Vec<&str> = Lines::new(&text).collect();
            assert_eq!(ours, text.split('\n').collect::<Vec<_>>(), "feed at {at}");
        }
    }

    #[test]
    fn bytes_that_differ_from_a_line_feed_by_one_bit_or_a_borrow_are_not_one() {
        for c in (0..=255u8).filter(|&c| c != b'\n') {
            let b = [c, c, b'\n', c, c, c, c, c, c, b'\n', c];
            assert_eq!(line_feed(&b, 0), 2, "byte {c:#04x}");
            assert_eq!(line_feed(&b, 3), 9, "byte {c:#04x}");
            assert_eq!(line_feed(&b, 10), 11, "byte {c:#04x}");
        }
    }
}
