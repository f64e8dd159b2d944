//! The lexer: a logos DFA over the source, then an adapter that turns its raw tokens into the `(start, tok,
//! end)` triples lalrpop reads.
//!
//! Design: the logos enum ([`Raw`]) is private and describes *spellings*, including the wrong ones (`.5`, `2.`,
//! `1e`, an unterminated string, stray characters), so every lexical mistake gets its own message and hint.
//! The adapter reports those mistakes as diagnostics and hands the parser a repaired token (`.5` becomes the
//! number 0.5, an unterminated string ends at the line end), so one typo costs one message, not a cascade.
//! Characters that cannot be repaired become [`Tok::Error`], which no grammar rule accepts; the parser
//! recovers at the statement and the front end drops its own report of that token.
//!
//! Newlines: the adapter decides which newlines end a statement, so the grammar sees `Newline` only as a
//! terminator (`;` is the same token). A newline is dropped at the file start, after another terminator,
//! after a binary operator (arithmetic, comparison, `&&`, `||`) / `!` / `=` / `,` / `(` / `in` / `..` / `.` /
//! `?` / `:` / `if` / `then` / `else`, before a line starting with `then` / `else` / `?` / `:` (none of
//! them can begin a statement), and inside parentheses. Inside parentheses a
//! newline followed by a new statement (`let`, `param`, `@key`) — or by an operand after an operand, where the
//! next line does not close the parenthesis — means the parenthesis was never closed: the adapter reports
//! "unterminated parenthesis" there and inserts the missing `)`s, so the statements that follow still parse.
//! Parentheses nested deeper than [`MAX_DEPTH`] stop the lexer at once (a 100 000-deep `((((…` is rejected
//! after 201 tokens).
//!
//! Cost: one logos pass plus one linear pass of the adapter, each filling a token `Vec`: linear in the input,
//! and the cheapest of the three front-end stages (measured times: BENCHMARKS.md).

use crate::base::diag::Diagnostic;
use crate::base::span::Span;
use logos::Logos;

/// Deepest parenthesis nesting accepted. Real formulas nest fewer than 10 levels; the limit keeps every later
/// recursive consumer (printers, other tools) far from the stack limit.
pub(crate) const MAX_DEPTH: usize = 200;

/// How a numeric literal is spelled, decided by [`number_tail`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum NumShape {
    Ok,
    /// `2.` — a point with no digits after it.
    TrailingDot,
    /// `1e`, `1e+` — an exponent with no digits.
    EmptyExponent,
}

/// Raw spellings recognised by the logos DFA.
#[derive(Logos, Clone, Copy, Debug, PartialEq)]
#[logos(skip r"[ \t\x0C]+")]
// A comment runs to the end of its line, by definition: the greedy repetition is the point.
#[logos(skip(r"#[^\r\n]*", allow_greedy = true))]
enum Raw {
    /// A line break: `\n`, `\r\n`, or a lone `\r` (old Mac files), as [`crate::base::span::line_col`] counts them.
    #[regex(r"\n|\r\n?")]
    Newline,
    #[token(";")]
    Semi,
    #[token("let")]
    Let,
    #[token("param")]
    Param,
    #[token("in")]
    In,
    #[token("+")]
    Plus,
    #[token("-")]
    Minus,
    #[token("*")]
    Star,
    #[token("/")]
    Slash,
    #[token("^")]
    Caret,
    #[token("(")]
    LParen,
    #[token(")")]
    RParen,
    #[token(",")]
    Comma,
    #[token("=")]
    Eq,
    #[token("..")]
    DotDot,
    #[token(".")]
    Dot,
    #[token("<")]
    Lt,
    #[token("<=")]
    Le,
    #[token(">")]
    Gt,
    #[token(">=")]
    Ge,
    #[token("==")]
    EqEq,
    #[token("!=")]
    Ne,
    #[token("&&")]
    AndAnd,
    #[token("||")]
    OrOr,
    #[token("!")]
    Bang,
    #[token("?")]
    Question,
    #[token(":")]
    Colon,
    #[token("fn")]
    Fn,
    #[token("if")]
    If,
    #[token("then")]
    Then,
    #[token("else")]
    Else,
    #[token("true")]
    True,
    #[token("false")]
    False,
    #[regex("[A-Za-z_][A-Za-z0-9_]*")]
    Ident,
    /// Digits; the callback takes the fraction and exponent by hand, because `1..1000` must lex as
    /// `1`, `..`, `1000` while `2.` alone is a mistake, which a DFA without lookahead cannot tell apart.
    #[regex("[0-9]+", |lex| number_tail(lex, false))]
    Number(NumSpelling),
    /// `.5` — a leading point: an error, repaired to 0.5.
    #[regex(r"\.[0-9]+", |lex| number_tail(lex, true))]
    LeadingDot(NumSpelling),
    #[regex(r#""[^"\r\n]*""#)]
    Str,
    #[regex(r#""[^"\r\n]*"#)]
    UnterminatedStr,
    #[regex("@[A-Za-z_][A-Za-z0-9_]*")]
    Meta,
}

/// How a numeric literal is spelled: its [`NumShape`], and whether `_` separates its digits (`1_000`, which
/// lobe does not accept: reported, and read without the `_`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct NumSpelling {
    shape: NumShape,
    separators: bool,
}

/// Consumes digit groups after separators, `(_+[0-9]+)*`, from `i`: the index after them and whether there
/// were any.
fn separated_digits(at: &impl Fn(usize) -> u8, mut i: usize) -> (usize, bool) {
    let mut any = false;
    loop {
        let mut j = i;
        while at(j) == b'_' {
            j += 1;
        }
        if j == i || !at(j).is_ascii_digit() {
            return (i, any);
        }
        while at(j).is_ascii_digit() {
            j += 1;
        }
        (i, any) = (j, true);
    }
}

/// Consumes the rest of a number after its leading digits (or leading `.digits`).
fn number_tail(lex: &mut logos::Lexer<Raw>, had_point: bool) -> NumSpelling {
    let rest = lex.remainder().as_bytes();
    let at = |i: usize| rest.get(i).copied().unwrap_or(0);
    let (mut i, mut separators) = separated_digits(&at, 0);
    let mut shape = NumShape::Ok;
    if !had_point && at(i) == b'.' {
        if at(i + 1).is_ascii_digit() {
            i += 1;
            while at(i).is_ascii_digit() {
                i += 1;
            }
            let (j, sep) = separated_digits(&at, i);
            (i, separators) = (j, separators || sep);
        } else if at(i + 1) != b'.' {
            // `2.` (but not `2..`, the range operator).
            i += 1;
            shape = NumShape::TrailingDot;
        }
    }
    if matches!(at(i), b'e' | b'E') {
        let mut j = i + 1;
        let signed = matches!(at(j), b'+' | b'-');
        if signed {
            j += 1;
        }
        if at(j).is_ascii_digit() {
            while at(j).is_ascii_digit() {
                j += 1;
            }
            i = j;
        } else if signed || !(at(i + 1).is_ascii_alphanumeric() || at(i + 1) == b'_') {
            // `1e`, `1e+`: an exponent was started and not finished. (`2exp(x)` is left alone: it is a number
            // followed by a name, which the parser reports as a missing operator.)
            i = j;
            shape = NumShape::EmptyExponent;
        }
    }
    lex.bump(i);
    NumSpelling { shape, separators }
}

/// A token as the grammar sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Tok<'s> {
    Let,
    Param,
    In,
    Plus,
    Minus,
    Star,
    Slash,
    Caret,
    LParen,
    RParen,
    Comma,
    Eq,
    DotDot,
    /// `.` before a component name (`v.x`).
    Dot,
    Lt,
    Le,
    Gt,
    Ge,
    EqEq,
    Ne,
    AndAnd,
    OrOr,
    Bang,
    Question,
    Colon,
    Fn,
    If,
    Then,
    Else,
    True,
    False,
    /// A statement terminator: a significant newline or `;`.
    Newline,
    Num(f64),
    Ident(&'s str),
    /// String contents, without the quotes.
    Str(&'s str),
    /// A metadata key, without the `@`.
    Meta(&'s str),
    /// Characters that are not part of the language (already reported); no rule accepts this token.
    Error,
}

impl Tok<'_> {
    /// Ends an operand: a following operand means an operator is missing.
    pub(crate) fn ends_operand(self) -> bool {
        matches!(self, Tok::Num(_) | Tok::Ident(_) | Tok::RParen | Tok::True | Tok::False)
    }
    /// Can start an operand (unary minus aside).
    pub(crate) fn starts_operand(self) -> bool {
        matches!(self, Tok::Num(_) | Tok::Ident(_) | Tok::LParen | Tok::True | Tok::False)
    }
    /// A token after which the line obviously continues.
    fn continues_line(self) -> bool {
        matches!(
            self,
            Tok::Plus
                | Tok::Minus
                | Tok::Star
                | Tok::Slash
                | Tok::Caret
                | Tok::LParen
                | Tok::Comma
                | Tok::Eq
                | Tok::In
                | Tok::DotDot
                | Tok::Dot
                | Tok::Bang
                | Tok::Question
                | Tok::Colon
                | Tok::If
                | Tok::Then
                | Tok::Else
        ) || self.is_comparison_or_logic()
    }
    /// A token that cannot begin a statement and only continues the previous line (`else` on its own line).
    fn continues_previous(self) -> bool {
        matches!(self, Tok::Then | Tok::Else | Tok::Question | Tok::Colon)
    }
    fn is_comparison_or_logic(self) -> bool {
        matches!(self, Tok::Lt | Tok::Le | Tok::Gt | Tok::Ge | Tok::EqEq | Tok::Ne | Tok::AndAnd | Tok::OrOr)
    }
    /// Starts a statement that can never continue an expression.
    fn starts_statement(self) -> bool {
        matches!(self, Tok::Let | Tok::Param | Tok::Fn | Tok::Meta(_))
    }
    pub(crate) fn is_binary_operator(self) -> bool {
        matches!(self, Tok::Plus | Tok::Minus | Tok::Star | Tok::Slash | Tok::Caret) || self.is_comparison_or_logic()
    }
}

/// The lexer's output: tokens for the parser and the lexical diagnostics.
#[derive(Debug, Default)]
pub(crate) struct Lexed<'s> {
    pub toks: Vec<(usize, Tok<'s>, usize)>,
    pub diags: Vec<Diagnostic>,
    /// Lexing stopped early (nesting too deep); the token list is incomplete and must not be parsed.
    pub fatal: bool,
}

/// Lexes `src` into parser tokens, reporting lexical mistakes.
pub(crate) fn lex(src: &str) -> Lexed<'_> {
    let mut diags = Vec::new();
    let toks = raw_tokens(src, &mut diags);
    let mut out = Lexed { toks: Vec::with_capacity(toks.len()), diags, fatal: false };
    layout(src, &toks, &mut out);
    out
}

/// Pass 1: logos tokens → parser tokens, repairing and reporting bad spellings.
fn raw_tokens<'s>(src: &'s str, diags: &mut Vec<Diagnostic>) -> Vec<(Tok<'s>, Span)> {
    let mut toks: Vec<(Tok<'s>, Span)> = Vec::new();
    // A run of adjacent unknown characters is reported once.
    let mut stray: Option<std::ops::Range<usize>> = None;
    let flush = |stray: &mut Option<std::ops::Range<usize>>, toks: &mut Vec<(Tok<'s>, Span)>, diags: &mut Vec<Diagnostic>| {
        if let Some(r) = stray.take() {
            diags.push(stray_diagnostic(&src[r.clone()], Span::new(r.start, r.end)));
            toks.push((Tok::Error, Span::new(r.start, r.end)));
        }
    };
    for (raw, r) in Raw::lexer(src).spanned() {
        let raw = match raw {
            Ok(t) => t,
            Err(()) => {
                stray = Some(match stray.take() {
                    Some(s) if s.end == r.start => s.start..r.end,
                    Some(s) => {
                        let mut s = Some(s);
                        flush(&mut s, &mut toks, diags);
                        r.clone()
                    }
                    None => r.clone(),
                });
                continue;
            }
        };
        flush(&mut stray, &mut toks, diags);
        let text = &src[r.clone()];
        let span = Span::new(r.start, r.end);
        let tok = match raw {
            Raw::Newline | Raw::Semi => Tok::Newline,
            Raw::Let => Tok::Let,
            Raw::Param => Tok::Param,
            Raw::In => Tok::In,
            Raw::Plus => Tok::Plus,
            Raw::Minus => Tok::Minus,
            Raw::Star => Tok::Star,
            Raw::Slash => Tok::Slash,
            Raw::Caret => Tok::Caret,
            Raw::LParen => Tok::LParen,
            Raw::RParen => Tok::RParen,
            Raw::Comma => Tok::Comma,
            Raw::Eq => Tok::Eq,
            Raw::DotDot => Tok::DotDot,
            Raw::Dot => Tok::Dot,
            Raw::Lt => Tok::Lt,
            Raw::Le => Tok::Le,
            Raw::Gt => Tok::Gt,
            Raw::Ge => Tok::Ge,
            Raw::EqEq => Tok::EqEq,
            Raw::Ne => Tok::Ne,
            Raw::AndAnd => Tok::AndAnd,
            Raw::OrOr => Tok::OrOr,
            Raw::Bang => Tok::Bang,
            Raw::Question => Tok::Question,
            Raw::Colon => Tok::Colon,
            Raw::Fn => Tok::Fn,
            Raw::If => Tok::If,
            Raw::Then => Tok::Then,
            Raw::Else => Tok::Else,
            Raw::True => Tok::True,
            Raw::False => Tok::False,
            Raw::Ident => Tok::Ident(text),
            Raw::Number(spelling) => Tok::Num(number(text, spelling, false, span, diags)),
            Raw::LeadingDot(spelling) => Tok::Num(number(text, spelling, true, span, diags)),
            Raw::Str => Tok::Str(&text[1..text.len() - 1]),
            Raw::UnterminatedStr => {
                diags.push(
                    Diagnostic::error("unterminated string")
                        .at(span, "this string has no closing `\"`")
                        .hint("end the string with `\"` on the same line; strings cannot span lines"),
                );
                Tok::Str(&text[1..])
            }
            Raw::Meta => Tok::Meta(&text[1..]),
        };
        toks.push((tok, span));
    }
    flush(&mut stray, &mut toks, diags);
    toks
}

/// The value of a number literal; bad spellings are reported and repaired to the evident intent.
fn number(text: &str, spelling: NumSpelling, leading_dot: bool, span: Span, diags: &mut Vec<Diagnostic>) -> f64 {
    let mut fixed = text.replace('_', "");
    if spelling.separators {
        diags.push(
            Diagnostic::error(format!("number `{text}` has `_` between its digits"))
                .at(span, "digit separators are not part of the language")
                .hint(format!("digit separators are not supported: write `{fixed}`")),
        );
    }
    if leading_dot {
        fixed.insert(0, '0');
        diags.push(
            Diagnostic::error(format!("number `{text}` has no digits before the decimal point"))
                .at(span, "a number cannot start with `.`")
                .hint(format!("write `{fixed}`")),
        );
    }
    match spelling.shape {
        NumShape::Ok => {}
        NumShape::TrailingDot => {
            let int = fixed.trim_end_matches('.').to_string();
            diags.push(
                Diagnostic::error(format!("number `{text}` has no digits after the decimal point"))
                    .at(span, "a number cannot end with `.`")
                    .hint(format!("write `{int}` or `{int}.0`")),
            );
            fixed = int;
        }
        NumShape::EmptyExponent => {
            diags.push(
                Diagnostic::error(format!("number `{text}` has an exponent with no digits"))
                    .at(span, "digits must follow the `e`")
                    .hint("write the exponent in full, like `1e-3` or `1.5E+2`"),
            );
            fixed = fixed.trim_end_matches(['+', '-']).trim_end_matches(['e', 'E']).to_string();
        }
    }
    match fixed.parse::<f64>() {
        Ok(v) if v.is_finite() => v,
        Ok(_) => {
            diags.push(
                Diagnostic::error(format!("number `{text}` is too large"))
                    .at(span, "this overflows a 64-bit float")
                    .hint("numbers must be below about 1.8e308"),
            );
            // Repaired to the largest float, so range checks downstream do not add a second message.
            f64::MAX
        }
        // Cannot happen for the shapes the lexer accepts; stay quiet rather than panic.
        Err(_) => 0.0,
    }
}

/// The message for characters outside the language, with a hint for the usual suspects.
fn stray_diagnostic(text: &str, span: Span) -> Diagnostic {
    let first = text.chars().next().unwrap_or(' ');
    let shown: String = if text.chars().count() > 12 {
        text.chars().take(12).flat_map(char::escape_debug).chain("…".chars()).collect()
    } else {
        text.chars().flat_map(char::escape_debug).collect()
    };
    let (msg, label) = if text.chars().count() == 1 {
        (format!("unexpected character `{shown}`"), "not part of the formula language")
    } else {
        (format!("unexpected characters `{shown}`"), "not part of the formula language")
    };
    let hint = match first {
        '√' => "write a square root as `sqrt(x)`",
        '×' | '·' | '⋅' | '∙' | '∗' => "write multiplication as `*`",
        '÷' => "write division as `/`",
        '−' | '–' | '—' => "write minus as the ASCII `-`",
        '²' => "write a square as `x^2`",
        '³' => "write a cube as `x^3`",
        'π' => "write π as `pi`",
        '“' | '”' | '„' => "strings use plain double quotes `\"`",
        '\'' | '`' => "strings use double quotes `\"`",
        '{' | '}' | '[' | ']' => "group with parentheses `(` `)`",
        '.' => "a number needs digits on both sides of the point, like `0.5`",
        '@' => "metadata is written `@name \"…\"` or `@cite \"…\"`",
        '&' => "logical and is written `&&`",
        '|' => "logical or is written `||`",
        '%' | '~' => "the operators are `+ - * / ^`, comparisons and `&& || !`; functions are called like `max(a, b)`",
        c if c.is_alphabetic() => "names use ASCII letters, digits and `_`; the inputs are NL, NV, NH, VR, VH",
        _ => "the formula language uses numbers, names, `+ - * / ^`, parentheses, `,` and `#` comments",
    };
    Diagnostic::error(msg).at(span, label).hint(hint)
}

/// Pass 2: decides which newlines terminate statements, tracks parentheses, and repairs unbalanced ones.
fn layout<'s>(src: &str, toks: &[(Tok<'s>, Span)], out: &mut Lexed<'s>) {
    let mut opens: Vec<Span> = Vec::new();
    // (index of the next non-newline token, whether it continues the previous line).
    let mut next_after = (0usize, false);
    for (k, &(tok, span)) in toks.iter().enumerate() {
        match tok {
            Tok::Newline => {
                let prev = out.toks.last().map(|t| t.1);
                let Some(prev) = prev else { continue };
                if prev == Tok::Newline || prev.continues_line() {
                    continue;
                }
                // The verdict for a run of newlines is found once (a run of blank lines stays linear).
                if next_after.0 <= k {
                    let j = (k + 1..toks.len()).find(|&j| toks[j].0 != Tok::Newline).unwrap_or(toks.len());
                    next_after = (j, toks.get(j).is_some_and(|t| t.0.continues_previous()));
                }
                if next_after.1 {
                    continue;
                }
                if !opens.is_empty() {
                    if !breaks_parenthesis(prev, &toks[k + 1..]) {
                        continue;
                    }
                    close_all(&mut opens, span.start as usize, out);
                }
                out.toks.push((span.start as usize, tok, span.end as usize));
            }
            Tok::LParen => {
                if opens.len() >= MAX_DEPTH {
                    out.diags.push(
                        Diagnostic::error(format!("parentheses nested more than {MAX_DEPTH} deep"))
                            .at(span, format!("this is level {}", MAX_DEPTH + 1))
                            .also(opens[0], "the outermost one opens here")
                            .hint("split the formula with `let` bindings"),
                    );
                    out.fatal = true;
                    return;
                }
                opens.push(span);
                out.toks.push((span.start as usize, tok, span.end as usize));
            }
            Tok::RParen => {
                if opens.pop().is_none() {
                    out.diags.push(
                        Diagnostic::error("unmatched `)`")
                            .at(span, "no `(` is open here")
                            .hint("remove this `)` or add the missing `(` before it"),
                    );
                    // An error token, not nothing: dropping it would glue `n)(x` into the call `n(x)`.
                    out.toks.push((span.start as usize, Tok::Error, span.end as usize));
                    continue;
                }
                out.toks.push((span.start as usize, tok, span.end as usize));
            }
            _ => out.toks.push((span.start as usize, tok, span.end as usize)),
        }
    }
    if !opens.is_empty() {
        // Point at the end of the last line with text, not after trailing comments and blank lines.
        let end = out.toks.last().map(|t| t.2).unwrap_or(src.len());
        close_all(&mut opens, end, out);
    }
}

/// Whether a newline inside parentheses (after `prev`, before `rest`) must end the statement because the
/// parenthesis was evidently never closed.
fn breaks_parenthesis(prev: Tok, rest: &[(Tok, Span)]) -> bool {
    let Some(&(next, _)) = rest.iter().find(|t| t.0 != Tok::Newline) else { return false };
    if next.starts_statement() {
        return true;
    }
    if prev.ends_operand() && next.starts_operand() {
        // `(a + b⏎ c)` closes on the next line: a missing operator, which the parser reports.
        let mut depth = 0i64;
        for &(t, _) in rest.iter().skip_while(|t| t.0 == Tok::Newline) {
            match t {
                Tok::Newline => break,
                Tok::LParen => depth += 1,
                Tok::RParen => depth -= 1,
                _ => {}
            }
            if depth < 0 {
                return false;
            }
        }
        return true;
    }
    false
}

/// Reports the open parentheses as unterminated and inserts the missing `)` (zero-width, at `at`).
fn close_all(opens: &mut Vec<Span>, at: usize, out: &mut Lexed) {
    let n = opens.len();
    let mut d = Diagnostic::error(if n == 1 {
        "unterminated parenthesis".to_string()
    } else {
        format!("{n} unterminated parentheses")
    })
    .at(Span::new(at, at), "expected `)` here");
    for o in opens.iter() {
        d = d.also(*o, "parenthesis opened here");
    }
    out.diags.push(d.hint(if n == 1 {
        "add the missing `)`".to_string()
    } else {
        format!("add the {n} missing `)`")
    }));
    for _ in 0..n {
        out.toks.push((at, Tok::RParen, at));
    }
    opens.clear();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toks(src: &str) -> Vec<Tok<'_>> {
        lex(src).toks.into_iter().map(|t| t.1).collect()
    }

    #[test]
    fn numbers_and_ranges() {
        assert_eq!(toks("1..1000"), vec![Tok::Num(1.0), Tok::DotDot, Tok::Num(1000.0)]);
        assert_eq!(toks("1.5E+2 1e-3 0.5"), vec![Tok::Num(150.0), Tok::Num(1e-3), Tok::Num(0.5)]);
        assert_eq!(toks("2exp"), vec![Tok::Num(2.0), Tok::Ident("exp")]);
    }

    #[test]
    fn bad_numbers_are_reported_and_repaired() {
        for (src, v) in [(".5", 0.5), ("2.", 2.0), ("1e", 1.0), ("1e+", 1.0), (".5e", 0.5)] {
            let l = lex(src);
            assert_eq!(l.diags.len(), if src == ".5e" { 2 } else { 1 }, "{src}");
            assert_eq!(l.toks[0].1, Tok::Num(v), "{src}");
        }
        assert_eq!(lex("1e999").diags.len(), 1);
        // Digit separators: one message naming the number without them, and that value.
        for (src, v, fixed) in [("1_0", 10.0, "`10`"), ("1_000.2_5", 1000.25, "`1000.25`"), ("1__0e2", 1000.0, "`10e2`")] {
            let l = lex(src);
            assert_eq!(l.toks.iter().map(|t| t.1).collect::<Vec<_>>(), [Tok::Num(v)], "{src}");
            assert_eq!(l.diags.len(), 1, "{src}: {:?}", l.diags);
            let d = &l.diags[0];
            assert!(d.message.contains(src) && d.hint_texts(&crate::base::diag::Plain)[0].contains(fixed), "{src}: {d}");
        }
        // A name that starts with `_` after a number is still a name (a missing operator, for the parser).
        assert_eq!(toks("2_x"), vec![Tok::Num(2.0), Tok::Ident("_x")]);
    }

    #[test]
    fn newline_rules() {
        use Tok::*;
        assert_eq!(toks("\n\na\n\n;b\n"), vec![Ident("a"), Newline, Ident("b"), Newline]);
        assert_eq!(toks("a +\n b"), vec![Ident("a"), Plus, Ident("b")]);
        assert_eq!(toks("(a\n+ b)"), vec![LParen, Ident("a"), Plus, Ident("b"), RParen]);
        assert_eq!(toks("f(a,\nb)"), vec![Ident("f"), LParen, Ident("a"), Comma, Ident("b"), RParen]);
        assert_eq!(toks("a\r\nb"), vec![Ident("a"), Newline, Ident("b")]);
        // A lone CR is a line break too, in code, after a comment and after a string.
        assert_eq!(toks("a\rb"), vec![Ident("a"), Newline, Ident("b")]);
        assert_eq!(toks("a # c\rb"), vec![Ident("a"), Newline, Ident("b")]);
        assert_eq!(toks("@name \"x\"\rb"), vec![Meta("name"), Str("x"), Newline, Ident("b")]);
        assert_eq!(toks("a\r\r\nb"), vec![Ident("a"), Newline, Ident("b")]);
        let l = lex("@cite \"abc\rNH");
        assert_eq!((l.diags.len(), l.toks[1].1), (1, Str("abc")));
    }

    #[test]
    fn unterminated_parenthesis_is_closed_before_the_next_statement() {
        use Tok::*;
        let l = lex("let a = (b\nlet c = 1");
        assert_eq!(l.diags.len(), 1);
        let t: Vec<_> = l.toks.iter().map(|t| t.1).collect();
        assert_eq!(t[..6], [Let, Ident("a"), Eq, LParen, Ident("b"), RParen]);
        assert_eq!(t[6], Newline);
    }

    #[test]
    fn stray_runs_merge_and_depth_is_limited() {
        let l = lex("a $$$ b");
        assert_eq!(l.diags.len(), 1);
        assert!(l.toks.iter().any(|t| t.1 == Tok::Error));
        let deep = "(".repeat(100_000);
        let l = lex(&deep);
        assert!(l.fatal);
        assert_eq!(l.diags.len(), 1);
    }

    #[test]
    fn strings_and_meta() {
        assert_eq!(toks("@name \"x y\""), vec![Tok::Meta("name"), Tok::Str("x y")]);
        let l = lex("@cite \"abc\nNH");
        assert_eq!(l.diags.len(), 1);
        assert_eq!(l.toks[1].1, Tok::Str("abc"));
    }
}
