//! Byte spans into the user's source text.

/// A half-open byte range `start..end` in one source file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Span {
    pub start: u32,
    pub end: u32,
}

impl Span {
    pub fn new(start: usize, end: usize) -> Span {
        Span { start: start as u32, end: end as u32 }
    }
    /// The smallest span covering both.
    pub fn join(self, other: Span) -> Span {
        Span { start: self.start.min(other.start), end: self.end.max(other.end) }
    }
    pub fn range(self) -> std::ops::Range<usize> {
        self.start as usize..self.end as usize
    }
}

/// Whether byte `i` of `b` ends a line: a `\n`, or a `\r` not followed by `\n` (a lone CR, as old Mac files
/// break lines; the `\r` of a CRLF pair does not end the line, its `\n` does).
pub(crate) fn is_line_break(b: &[u8], i: usize) -> bool {
    match b.get(i) {
        Some(b'\n') => true,
        Some(b'\r') => b.get(i + 1) != Some(&b'\n'),
        _ => false,
    }
}

/// 1-based line and column (in characters) of a byte offset, for messages that do not use carets. Lines end
/// at `\n`, `\r\n` and a lone `\r` ([`is_line_break`]), as the lexer splits them.
pub fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = floor_char_boundary(src, offset.min(src.len()));
    let b = src.as_bytes();
    let (mut line, mut start) = (1, 0);
    for i in 0..offset {
        if is_line_break(b, i) {
            line += 1;
            start = i + 1;
        }
    }
    (line, src[start..offset].chars().count() + 1)
}

/// `src` with every lone `\r` replaced by `\n` (the same length, so byte spans stay valid), for tools that
/// only know `\n` and `\r\n` line ends (the caret renderer).
pub(crate) fn lone_cr_as_lf(src: &str) -> std::borrow::Cow<'_, str> {
    let b = src.as_bytes();
    if !(0..b.len()).any(|i| b[i] == b'\r' && is_line_break(b, i)) {
        return std::borrow::Cow::Borrowed(src);
    }
    let fixed: String = src
        .char_indices()
        .map(|(i, c)| if c == '\r' && is_line_break(b, i) { '\n' } else { c })
        .collect();
    std::borrow::Cow::Owned(fixed)
}

fn floor_char_boundary(s: &str, mut i: usize) -> usize {
    while i > 0 && !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

#[cfg(test)]
mod tests {
    #[test]
    fn line_col_counts_from_one() {
        assert_eq!(super::line_col("ab\ncd", 4), (2, 2));
        assert_eq!(super::line_col("ab", 0), (1, 1));
    }

    #[test]
    fn a_lone_cr_ends_a_line_and_a_crlf_ends_one() {
        use super::{line_col, lone_cr_as_lf};
        assert_eq!(line_col("ab\rcd", 4), (2, 2));
        assert_eq!(line_col("a\rb\rc", 4), (3, 1));
        assert_eq!(line_col("ab\r\ncd", 5), (2, 2));
        // At the `\n` of a CRLF the line has not ended yet.
        assert_eq!(line_col("ab\r\ncd", 3), (1, 4));
        assert_eq!(line_col("a\r\r\nb", 4), (3, 1));
        assert_eq!(lone_cr_as_lf("a\rb\r\nc\r"), "a\nb\r\nc\n");
        assert!(matches!(lone_cr_as_lf("a\r\nb"), std::borrow::Cow::Borrowed(_)));
    }
}
