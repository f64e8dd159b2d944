//! lalrpop glue: runs the generated LR parser over the lexer's tokens and turns its errors into diagnostics.
//!
//! Design: the parser is table-driven (lalrpop's default LR(1) machine keeps its stack in a `Vec`), so deep
//! input cannot overflow the native stack while parsing; the actions build the arena AST in [`State`].
//! Errors recovered with `!` (at each statement, and after `let name =`) are converted here, where the token
//! list is at hand, so a message can name the previous token ("expected an operand after `+`") and detect
//! the common shapes: a missing operator between two operands, a trailing operator, `**` for powers, `()`.
//! Errors at a [`Tok::Error`] token are dropped: the lexer has already reported that character.

use super::ast::{Ast, BinOp, ExprId, ExprKind, Stmt, StmtKind};
use crate::base::diag::Diagnostic;
use super::lex::{Lexed, Tok};
use crate::base::span::Span;
use lalrpop_util::{ErrorRecovery, ParseError};
use std::convert::Infallible;

lalrpop_util::lalrpop_mod!(
    #[allow(clippy::all, clippy::pedantic, unused_parens, unused_imports, dead_code)]
    grammar,
    "/formula.rs"
);

type Recovered<'s> = ErrorRecovery<usize, Tok<'s>, Infallible>;

/// What the grammar's actions write to.
#[derive(Debug, Default)]
pub(crate) struct State<'s> {
    pub ast: Ast<'s>,
    pub recovered: Vec<Recovered<'s>>,
}

impl<'s> State<'s> {
    pub(crate) fn stmt(&mut self, kind: StmtKind<'s>, l: usize, r: usize) {
        self.ast.stmts.push(Stmt { kind, span: Span::new(l, r) });
    }
    pub(crate) fn bin(&mut self, op: BinOp, a: ExprId, b: ExprId) -> ExprId {
        let span = self.ast.span(a).join(self.ast.span(b));
        self.ast.push(ExprKind::Binary(op, a, b), span)
    }
    pub(crate) fn neg(&mut self, a: ExprId, l: usize) -> ExprId {
        let span = Span::new(l, self.ast.span(a).end as usize);
        self.ast.push(ExprKind::Neg(a), span)
    }
    pub(crate) fn not(&mut self, a: ExprId, l: usize) -> ExprId {
        let span = Span::new(l, self.ast.span(a).end as usize);
        self.ast.push(ExprKind::Not(a), span)
    }
    pub(crate) fn select(&mut self, c: ExprId, a: ExprId, b: ExprId) -> ExprId {
        let span = self.ast.span(c).join(self.ast.span(b));
        self.ast.push(ExprKind::Select(c, a, b), span)
    }
    /// Widens the span of `e` leftwards to `l` (to cover a leading keyword).
    pub(crate) fn extend_left(&mut self, e: ExprId, l: usize) -> ExprId {
        let s = &mut self.ast.exprs[e.index()].span;
        *s = Span::new(l, s.end as usize);
        e
    }
}

/// Parses the tokens into an AST; syntax errors are appended to `diags`.
pub(crate) fn parse<'s>(src: &str, lexed: &Lexed<'s>, diags: &mut Vec<Diagnostic>) -> Ast<'s> {
    let mut st = State::default();
    let toks = &lexed.toks;
    let result = grammar::FileParser::new().parse(&mut st, toks.iter().copied().map(Ok::<_, Infallible>));
    let mut errors: Vec<ParseError<usize, Tok<'s>, Infallible>> =
        std::mem::take(&mut st.recovered).into_iter().map(|r| r.error).collect();
    if let Err(e) = result {
        errors.push(e);
        // The statements parsed so far stand; mark the rest unreadable so no "missing formula" follows.
        st.stmt(StmtKind::Error, src.len(), src.len());
    }
    for e in &errors {
        if let Some(d) = syntax_error(src, toks, e) {
            diags.push(d);
        }
    }
    st.ast
}

/// Index of the token `(l, tok, r)` in `toks`.
fn index_of(toks: &[(usize, Tok, usize)], l: usize, tok: Tok, r: usize) -> Option<usize> {
    let first = toks.partition_point(|t| t.0 < l);
    (first..toks.len()).take_while(|&i| toks[i].0 == l).find(|&i| toks[i].1 == tok && toks[i].2 == r)
}

/// Source text as a message quotes it: on one line (control characters such as a newline escaped, never
/// raw) and at most [`QUOTED_CHARS`] characters.
fn quoted(text: &str) -> String {
    let mut out = String::new();
    for (i, c) in text.chars().enumerate() {
        if i == QUOTED_CHARS {
            out.push('…');
            break;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// Longest piece of source a syntax error's message quotes.
const QUOTED_CHARS: usize = 40;

/// How a token reads in a message.
fn describe(src: &str, tok: Tok, l: usize, r: usize) -> String {
    let text = quoted(src.get(l..r).unwrap_or(""));
    match tok {
        Tok::Newline if text == ";" => "`;`".into(),
        Tok::Newline => "the end of the line".into(),
        _ if l == r => "the end of the line".into(),
        Tok::Num(_) => format!("number `{text}`"),
        Tok::Ident(_) => format!("name `{text}`"),
        Tok::Str(_) => "a string".into(),
        _ => format!("`{text}`"),
    }
}

/// "an expression, `)` or `,`" from lalrpop's list of expected terminals.
fn expected_phrase(expected: &[String]) -> String {
    let has = |s: &str| expected.iter().any(|e| e.trim_matches('"') == s);
    let mut parts: Vec<String> = vec![];
    if has("number") && has("name") {
        parts.push("an expression".into());
    } else {
        if has("number") {
            parts.push("a number".into());
        }
        if has("name") {
            parts.push("a name".into());
        }
    }
    if has("+") && has("*") {
        parts.push("an operator".into());
    }
    for (t, p) in [(")", "`)`"), (",", "`,`"), ("=", "`=`"), ("in", "`in`"), ("..", "`..`")] {
        if has(t) {
            parts.push(p.into());
        }
    }
    if has("string") {
        parts.push("a string in double quotes".into());
    }
    if has("newline") {
        parts.push("the end of the statement".into());
    }
    match parts.len() {
        0 => "something else".into(),
        1 => parts.remove(0),
        _ => {
            let last = parts.pop().unwrap_or_default();
            format!("{} or {}", parts.join(", "), last)
        }
    }
}

/// The error for a `param` whose default is not a constant (`param a = NH`), when the syntax error at token
/// `idx` lies between the statement's `=` and its `in` (or its end); `None` otherwise.
fn param_default_error(src: &str, toks: &[(usize, Tok, usize)], stmt_start: usize, idx: usize) -> Option<Diagnostic> {
    if toks.get(stmt_start).map(|t| t.1) != Some(Tok::Param) {
        return None;
    }
    let eq = (stmt_start..idx.min(toks.len())).find(|&i| toks[i].1 == Tok::Eq)?;
    if toks[eq + 1..idx.min(toks.len())].iter().any(|t| t.1 == Tok::In) {
        return None;
    }
    // The default as written: from after `=` to the end of the statement (or its `in`).
    let end = (idx..toks.len()).find(|&i| matches!(toks[i].1, Tok::Newline | Tok::In)).unwrap_or(toks.len());
    let name = match toks.get(stmt_start + 1) {
        Some(&(l, Tok::Ident(_), r)) => src.get(l..r).unwrap_or("a"),
        _ => "a",
    };
    let example = format!("param {name} = 16 in 1..1000");
    let hint = |default: &str| {
        format!(
            "write a number, like `{example}` (a bool parameter takes `true` or `false`, a colour `rgb(0.8, 0.6, 0.2)`); \
             a value computed from the inputs is a `let`: `let {name} = {default}`"
        )
    };
    let d = if end > eq + 1 {
        let (l, r) = (toks[eq + 1].0, toks[end - 1].2);
        let text = quoted(src.get(l..r).unwrap_or(""));
        Diagnostic::error(format!("a parameter's default must be a constant number, not `{text}`"))
            .at(Span::new(l, r), "not a constant")
            .hint(hint(&text))
    } else {
        let (l, r) = (toks[eq].0, toks[eq].2);
        Diagnostic::error("a parameter needs a default value after `=`")
            .at(Span::new(l, r), "no value follows")
            .hint(hint("…"))
    };
    Some(d)
}

/// A syntax error as a diagnostic; `None` when the lexer already reported the cause.
fn syntax_error(src: &str, toks: &[(usize, Tok, usize)], e: &ParseError<usize, Tok, Infallible>) -> Option<Diagnostic> {
    let (cur, expected, at) = match e {
        ParseError::UnrecognizedToken { token: (l, t, r), expected } => (Some((*l, *t, *r)), expected.as_slice(), *l),
        ParseError::UnrecognizedEof { location, expected } => (None, expected.as_slice(), *location),
        ParseError::ExtraToken { token: (l, t, r) } => (Some((*l, *t, *r)), &[][..], *l),
        ParseError::InvalidToken { location } => (None, &[][..], *location),
        ParseError::User { error } => match *error {},
    };
    if let Some((_, Tok::Error, _)) = cur {
        return None;
    }
    let idx = match cur {
        Some((l, t, r)) => index_of(toks, l, t, r).unwrap_or(toks.partition_point(|t| t.0 < l)),
        None => toks.len(),
    };
    let prev = idx.checked_sub(1).and_then(|i| toks.get(i)).copied();
    let found = match cur {
        Some((l, t, r)) => describe(src, t, l, r),
        None => "the end of the file".into(),
    };
    let cur_span = match cur {
        Some((l, _, r)) => Span::new(l, r),
        None => Span::new(at, at),
    };
    // The first token of the statement, for a syntax hint.
    let stmt_start = toks[..idx.min(toks.len())]
        .iter()
        .rposition(|t| t.1 == Tok::Newline)
        .map(|i| i + 1)
        .unwrap_or(0);
    let stmt_kind = toks.get(stmt_start).map(|t| t.1).filter(|_| stmt_start < idx);

    // `for i in 0..4`, `while …`: loops from other languages.
    if let (Some(&(fl, Tok::Ident(kw @ ("for" | "while" | "loop" | "do")), fr)), true) =
        (toks.get(stmt_start), idx == stmt_start + 1)
    {
        return Some(
            Diagnostic::error(format!("`{kw}` loops are not part of the formula language"))
                .at(Span::new(fl, fr), "a loop")
                .hint("a formula is one expression: write the terms out, like `f(0) + f(1) + f(2)` with \
                       `fn f(i) = …` for the repeated term"),
        );
    }
    if let (Some((pl, pt, pr)), Some((_, ct, _))) = (prev, cur) {
        if pt == Tok::Error {
            return None;
        }
        let (ptext, ctext) = (src.get(pl..pr).unwrap_or(""), cur.and_then(|(l, _, r)| src.get(l..r)).unwrap_or(""));
        let (pshown, cshown) = (quoted(ptext), quoted(ctext));
        // `2 NH`, `a (b)`, `) (`: two operands in a row.
        let operator_expected = expected.iter().any(|e| e.trim_matches('"') == "*");
        // `0x10`, `0b101`: other bases are not numbers in lobe (not a missing `*`).
        let radix = match ctext.as_bytes().first() {
            Some(b'x' | b'X') => Some(16),
            Some(b'b' | b'B') => Some(2),
            Some(b'o' | b'O') => Some(8),
            _ => None,
        };
        if let (Some(radix), true) = (radix, ptext == "0" && pr == cur_span.start as usize) {
            let value = i64::from_str_radix(&ctext[1..], radix).ok();
            return Some(
                Diagnostic::error(format!("`{pshown}{cshown}` is not a number: lobe's numbers are decimal"))
                    .at(Span::new(pl, cur_span.end as usize), "written here")
                    .hint(match value {
                        Some(v) => format!("write `{v}`"),
                        None => "write the value in decimal".to_string(),
                    }),
            );
        }
        if pt.ends_operand() && ct.starts_operand() && !ctext.is_empty() && operator_expected {
            return Some(
                Diagnostic::error(format!("missing operator between `{pshown}` and `{cshown}`"))
                    .at(cur_span, "expected an operator before this")
                    .also(Span::new(pl, pr), "this operand ends here")
                    .hint(format!("did you mean `{pshown} * {cshown}`? Multiplication needs an explicit `*`")),
            );
        }
        if pt == Tok::Star && ct == Tok::Star {
            return Some(
                Diagnostic::error("`**` is not an operator")
                    .at(Span::new(pl, cur_span.end as usize), "written here")
                    .hint("write powers with `^`, like `NH^n`"),
            );
        }
        if pt == Tok::LParen && ct == Tok::RParen {
            return Some(
                Diagnostic::error("empty parentheses")
                    .at(Span::new(pl, cur_span.end as usize), "nothing inside")
                    .hint("put an expression between `(` and `)`, or remove them"),
            );
        }
    }
    if let Some((pl, pt, pr)) = prev {
        if pt.is_binary_operator() && !cur.is_some_and(|c| c.1.starts_operand() || c.1 == Tok::Minus) {
            let op = quoted(src.get(pl..pr).unwrap_or(""));
            let mut d = Diagnostic::error(format!("expected an operand after `{op}`, found {found}"));
            d = if cur.is_none_or(|c| c.1 == Tok::Newline || c.0 == c.2) {
                d.at(Span::new(pl, pr), "nothing follows this operator")
            } else {
                d.at(cur_span, "expected an operand here").also(Span::new(pl, pr), "after this operator")
            };
            return Some(d.hint(format!("complete the expression after `{op}`, or remove the trailing `{op}`")));
        }
    }
    if let Some(d) = param_default_error(src, toks, stmt_start, idx) {
        return Some(d);
    }
    let what = expected_phrase(expected);
    // What came before, unless the statement starts here (after a line end, or a `)` the lexer inserted).
    let after = prev.filter(|&(pl, pt, pr)| pt != Tok::Newline && pl < pr).map(|(pl, _, pr)| quoted(src.get(pl..pr).unwrap_or("")));
    let mut d = match after {
        Some(ptext) => Diagnostic::error(format!("expected {what} after `{ptext}`, found {found}")),
        None => Diagnostic::error(format!("expected {what}, found {found}")),
    };
    d = d.at(cur_span, format!("expected {what}"));
    let hint = match stmt_kind {
        Some(Tok::Param) => "a parameter is declared as `param a = 16 in 1..1000` (the range is optional)".to_string(),
        Some(Tok::Let) => "a binding is written `let name = expression`".to_string(),
        Some(Tok::Meta(k)) => {
            if expected.iter().any(|e| e.trim_matches('"') == "string") {
                format!("metadata takes a string in double quotes: `@{k} \"…\"`")
            } else {
                "write each `@key \"…\"` on its own line".to_string()
            }
        }
        _ if cur.is_some_and(|c| c.1 == Tok::RParen) => "remove this `)` or complete the expression before it".into(),
        _ => "a statement is `let name = …`, `param name = …`, `@name \"…\"`, or the formula itself".to_string(),
    };
    Some(d.hint(hint))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::front::lex::lex;

    fn parse_ok(src: &str) -> Ast<'_> {
        let l = lex(src);
        let mut d = vec![];
        let ast = parse(src, &l, &mut d);
        assert!(d.is_empty() && l.diags.is_empty(), "{src}: {d:?}");
        ast
    }

    /// The tree as fully parenthesised text, to check precedence without evaluating.
    fn show(ast: &Ast, id: ExprId) -> String {
        match &ast.expr(id).kind {
            ExprKind::Num(v) => format!("{v}"),
            ExprKind::Name(n) => n.name.to_string(),
            ExprKind::Neg(a) => format!("(-{})", show(ast, *a)),
            ExprKind::Binary(op, a, b) => format!("({} {} {})", show(ast, *a), op.symbol(), show(ast, *b)),
            ExprKind::Call(n, args) => {
                format!("{}({})", n.name, args.iter().map(|a| show(ast, *a)).collect::<Vec<_>>().join(", "))
            }
            ExprKind::Paren(a) => show(ast, *a),
            ExprKind::Error => "<error>".into(),
            ExprKind::Bool(b) => format!("{b}"),
            ExprKind::Not(a) => format!("(!{})", show(ast, *a)),
            ExprKind::Select(c, a, b) => format!("({} ? {} : {})", show(ast, *c), show(ast, *a), show(ast, *b)),
            ExprKind::Field(a, n) => format!("{}.{}", show(ast, *a), n.name),
        }
    }

    fn expr(src: &str) -> String {
        let ast = parse_ok(src);
        match ast.stmts.last().map(|s| &s.kind) {
            Some(StmtKind::Expr(e)) => show(&ast, *e),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn precedence_and_associativity() {
        for (src, want) in [
            ("-x^2", "(-(x ^ 2))"),
            ("2^3^2", "(2 ^ (3 ^ 2))"),
            ("a-b-c", "((a - b) - c)"),
            ("a/b/c", "((a / b) / c)"),
            ("a+b*c^d", "(a + (b * (c ^ d)))"),
            ("2^-x", "(2 ^ (-x))"),
            ("--x", "(-(-x))"),
            ("-a*b", "((-a) * b)"),
            ("max(a, b,)", "max(a, b)"),
            ("a || b && c", "(a || (b && c))"),
            ("a && b || c && d", "((a && b) || (c && d))"),
            ("a + 1 < b * 2 && !c", "(((a + 1) < (b * 2)) && (!c))"),
            ("c ? a : d ? e : f", "(c ? a : (d ? e : f))"),
            ("c ? x ? 1 : 2 : 3", "(c ? (x ? 1 : 2) : 3)"),
            ("if a < b then 1 else if c then 2 else 3", "((a < b) ? 1 : (c ? 2 : 3))"),
            ("-L.x^2", "(-(L.x ^ 2))"),
            ("normalize(L + V).z", "normalize((L + V)).z"),
            ("!a == b", "((!a) == b)"),
            ("true || false", "(true || false)"),
            ("c ?\n1 :\n2", "(c ? 1 : 2)"),
            ("if c\nthen 1\nelse 2", "(c ? 1 : 2)"),
        ] {
            assert_eq!(expr(src), want, "{src:?}");
        }
    }

    #[test]
    fn comparisons_do_not_chain() {
        let src = "a < b < c";
        let l = lex(src);
        let mut d = vec![];
        parse(src, &l, &mut d);
        assert_eq!(d.len(), 1, "{d:?}");
    }

    #[test]
    fn spans_cover_the_source() {
        let src = "let c = (NH + 1)\n2 * c";
        let ast = parse_ok(src);
        let StmtKind::Let { value, .. } = ast.stmts[0].kind else { panic!() };
        assert_eq!(&src[ast.span(value).range()], "(NH + 1)");
        assert_eq!(&src[ast.stmts[1].span.range()], "2 * c");
    }

    /// Every diagnostic of `src`, lexer's and parser's.
    fn diagnostics(src: &str) -> Vec<Diagnostic> {
        let l = lex(src);
        let mut d = l.diags.clone();
        parse(src, &l, &mut d);
        d
    }

    #[test]
    fn messages_quote_no_raw_line_breaks() {
        for src in ["@name \"abc\n= 3\nNH", "\"abc\n\"\nNH", "@name \"abc\r= 3\rNH", "NH\n= 2", "a\r\n)\r\n= 1"] {
            let ds = diagnostics(src);
            assert!(!ds.is_empty(), "{src:?}");
            for d in &ds {
                let shown = format!("{d} {:?}", d.primary.as_ref().map(|p| &p.1));
                assert!(!shown.contains(['\n', '\r']), "{src:?}: {shown:?}");
            }
        }
        // The statement after a line end starts there: no "after" the line end.
        let ds = diagnostics("@name \"abc\n= 3\nNH");
        assert!(ds.iter().any(|d| d.message == "expected an expression, found `=`"), "{ds:#?}");
    }

    #[test]
    fn a_parameter_default_that_is_not_a_number_says_so() {
        for (src, quoted) in [("param a = NH\nNH^a", "`NH`"), ("param k = 2*NL in 0..4\nNH^k", "`2*NL`"), ("param a = sqrt(2)\nNH^a", "`sqrt(2)`")] {
            let ds = diagnostics(src);
            assert_eq!(ds.len(), 1, "{src:?}: {ds:#?}");
            let d = &ds[0];
            assert_eq!(d.message, format!("a parameter's default must be a constant number, not {quoted}"), "{src:?}");
            let hint = d.hint_texts(&crate::base::diag::Plain).join(" ");
            assert!(hint.contains("write a number") && hint.contains(&format!("= {}", quoted.trim_matches('`'))), "{src:?}: {hint}");
            // The name is still bound (to an error value): its use below adds no "unknown variable".
            let all = crate::front::parse("p.brdf", src).unwrap_err().items;
            assert_eq!(all.len(), 1, "{src:?}: {all:#?}");
        }
        let ds = diagnostics("param a =");
        assert_eq!(ds[0].message, "a parameter needs a default value after `=`", "{ds:#?}");
        // A bad range is still a range error, and good defaults parse.
        assert!(diagnostics("param a = 2 in NH..3\nNH^a").iter().all(|d| !d.message.contains("default")));
        parse_ok("param a = -2 in -4..4\nparam b = true\nparam c = rgb(1, 0.5, 0)\nNH");
    }

    #[test]
    fn recovers_at_each_statement() {
        let src = "let a = 2 3\nlet b = * 3\nc d\nNH";
        let l = lex(src);
        let mut d = vec![];
        let ast = parse(src, &l, &mut d);
        assert_eq!(d.len(), 3, "{d:#?}");
        assert_eq!(ast.stmts.len(), 4);
    }
}
