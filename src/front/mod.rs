//! The front end: .brdf text → [`crate::ir::Formula`], or diagnostics. Knows nothing of backends.
//!
//! Pipeline: [`lex`] (logos DFA + an adapter that decides statement-ending newlines and repairs bad
//! spellings) → [`parse()`] (lalrpop LR(1), table-driven, builds the arena [`ast`] with a span on every node,
//! recovers at each statement) → [`lower`] (names, types, arity, function inlining, `n` as parameter 0, domain
//! policy → `ir::Formula`).
//! Every stage reports into one list, so a file with several mistakes gets all of them, sorted by position.
//!
//! The language, in brief (grammar/formula.lalrpop is the definition; docs/language.md has the reference):
//!
//! ```text
//! # comment                                  statements end at a newline or `;`
//! @name "Modified Schlick"                   metadata: @name, @cite (strings), @domain raw|brdf
//! param a = 16 in 1..1000                    a float parameter: default, optional range (none = unbounded);
//!                                            `n` is always parameter 0 (implicitly 50 in 1..1000)
//! param aniso = true                         a bool parameter; `param base = rgb(0.8, 0.6, 0.2)` a colour
//! fn sqr(x) = x * x                          a function, inlined at each call
//! let c = NH                                 bindings, visible after their own line; no shadowing
//! 2*c / (1.25*(n - n*c + 1.25*c)^2)          exactly one final expression, last: a float or a vec3 (RGB)
//! ```
//!
//! Values are floats, bools and vec3s (the frame `L V N X Y`, `vec3(…)`/`rgb(…)`, `.x`/`.r` components),
//! lowered through [`values::Values`] into scalar IR. Precedence, loosest first: `?:` and `if c then a else
//! b` (right-associative); `||`; `&&`; comparisons (non-associative); `+ -`; `* /`; unary `-` `!`; `^`
//! (right-associative; `2^-x` allowed; `-x^2 = -(x^2)`); postfix `.x`, calls and parentheses. A newline
//! continues the statement inside parentheses, after a binary operator, `!`, `=`, `,`, `(`, `?`, `:`, `if`,
//! `then`, `else`, and before a line that starts with `then`, `else`, `?` or `:`. Numbers: `2`, `0.5`, `1e-3`.
//!
//! Robustness: nothing here recurses on the input's depth (the parser's stack and the AST are `Vec`s;
//! lowering uses an explicit stack), parentheses deeper than [`lex::MAX_DEPTH`] are refused at once, and at
//! most [`MAX_ERRORS`] errors are shown; function inlining is bounded in depth and size ([`lower`]). Cost is
//! linear in the input (plus the inlined bodies); lowering dominates (most of it
//! `Ir::push` hash-consing), then parsing, then lexing, and over-deep nesting is rejected after
//! [`lex::MAX_DEPTH`] + 1 tokens. Measured times: BENCHMARKS.md.

pub(crate) mod ast;
pub(crate) mod explorer;
pub(crate) mod lex;
pub(crate) mod lower;
pub mod parse;
pub mod values;

use crate::base::diag::{Diagnostic, Diagnostics, Severity};
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::Formula;

/// At most this many errors are rendered; the rest are summarised in one line.
pub const MAX_ERRORS: usize = 25;

/// Parses and lowers one .brdf source file. Warnings are dropped; use [`parse_with_warnings`] to show them.
pub fn parse(file: &str, src: &str) -> Result<Formula, Diagnostics> {
    parse_with_warnings(file, src).map(|(f, _)| f)
}

/// Parses and lowers one .brdf source file; on success also returns the warnings (unused `let`/`param`, a
/// formula that reads no input), possibly empty. On failure the diagnostics hold every error found.
pub fn parse_with_warnings(file: &str, src: &str) -> Result<(Formula, Diagnostics), Diagnostics> {
    read(file, src, false)
}

/// [`parse()`] that also accepts the passes' internal builtins (`expmuldiv`, `acoslo`, `powlo`, `sinnear`:
/// [`Builtin::is_internal`]); for tests and for reading back the pass's own output. Their names are then
/// reserved, as every builtin's is. A BRDF Explorer file is read as [`parse()`] reads it.
pub fn parse_internal(file: &str, src: &str) -> Result<Formula, Diagnostics> {
    read(file, src, true).map(|(f, _)| f)
}

/// The error for user text that calls (or names) an internal builtin, at `span`, with the table's hint of what
/// to write instead.
pub(crate) fn internal_builtin(b: Builtin, span: Span) -> Diagnostic {
    Diagnostic::error(format!("`{}` is internal to {}, not a function of the language", b.name(), b.formed_by()))
        .at(span, format!("only {} forms this", b.formed_by()))
        .hint(b.info().internal.unwrap_or("write the formula with the language's functions"))
}

/// The parse path behind [`parse_with_warnings`] and [`parse_internal`]: `internal` lets the text call the
/// internal builtins.
fn read(file: &str, src: &str, internal: bool) -> Result<(Formula, Diagnostics), Diagnostics> {
    if explorer::is_explorer(src) {
        return explorer::parse(file, src);
    }
    let mut items: Vec<Diagnostic> = Vec::new();
    let lexed = lex::lex(src);
    items.extend(lexed.diags.iter().cloned());
    let formula = if lexed.fatal {
        None
    } else {
        let ast = parse::parse(src, &lexed, &mut items);
        let syntax_failed = !items.is_empty();
        lower::lower(file, src, &ast, syntax_failed, internal, &mut items)
    };
    // Reading order; diagnostics without a location (a missing formula) come first.
    items.sort_by_key(|d| d.primary.as_ref().map(|p| (p.0.start, p.0.end)));
    let n_errors = items.iter().filter(|d| d.severity == Severity::Error).count();
    if n_errors > MAX_ERRORS {
        let mut kept = 0;
        items.retain(|d| {
            kept += usize::from(d.severity == Severity::Error);
            kept <= MAX_ERRORS && d.severity == Severity::Error
        });
        items.push(
            Diagnostic::error(format!("{} more errors not shown", n_errors - MAX_ERRORS))
                .hint("fix the errors above first; is this really a .brdf file?"),
        );
    }
    let mut ds = Diagnostics::new(file, src);
    ds.items = items;
    if formula.is_none() && !ds.has_errors() {
        // Lowering fails only after reporting; this keeps a bug here from becoming a silent rejection.
        ds.push(Diagnostic::error("internal error: the formula was rejected without a reason").hint(
            "please report this file to the lobe developers",
        ));
    }
    match formula {
        Some(f) if !ds.has_errors() => Ok((f, ds)),
        _ => Err(ds),
    }
}

/// The hint for `name`, which is none of `known`: the closest of them, or else `intro` and the whole list.
pub fn did_you_mean(name: &str, known: &[&str], intro: &str) -> String {
    match suggest(name, known.iter().copied()) {
        Some(s) => format!("did you mean `{s}`?"),
        None => format!("{intro}{}", known.join(", ")),
    }
}

/// Names longer than this get no suggestion: no typo makes one, and comparing them costs time in their length.
const MAX_SUGGESTED_NAME: usize = 64;

/// The closest candidate by edit distance, if close enough to be a plausible typo. Linear in the length of `name`
/// and of the candidates: a candidate whose length differs by more than the accepted distance is skipped unmeasured,
/// and names longer than [`MAX_SUGGESTED_NAME`] are not compared at all.
pub(crate) fn suggest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let len = name.chars().count();
    if len > MAX_SUGGESTED_NAME {
        return None;
    }
    let lname = name.to_lowercase();
    // Close enough to be a typo, and not a rewrite of the whole name (`c` → `d` is no suggestion).
    let bound = |c: &str| (c.len().max(name.len()) / 3).max(1);
    candidates
        .into_iter()
        // The edit distance is at least the difference in length.
        .filter(|c| c.chars().count().abs_diff(len) <= bound(c))
        .map(|c| (levenshtein(&lname, &c.to_lowercase()), c))
        .filter(|(d, c)| *d <= bound(c) && (*d == 0 || *d < len))
        // Ties go to the candidate as long as the name (`NX` → `NH`, not `n`), then to the earlier one.
        .min_by_key(|(d, c)| (*d, c.chars().count().abs_diff(len)))
        .map(|(_, c)| c)
}

fn levenshtein(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1];
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != *cb);
            cur.push(sub.min(prev[j + 1] + 1).min(cur[j] + 1));
        }
        prev = cur;
    }
    prev[b.len()]
}

/// Parses `name=value,name=value` (parameter values given for a run, as the CLI and the page take them); names are
/// identifiers, or a colour channel `base.r`; values finite numbers, or `true`/`false` (1/0, for bool
/// parameters); each name once.
pub fn parse_assignments(s: &str) -> Result<Vec<(String, f64)>, String> {
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (k, v) = part
            .split_once('=')
            .ok_or_else(|| format!("`{part}` is not of the form name=value (e.g. n=50)"))?;
        let k = k.trim();
        let ident = |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        let valid = match k.split_once('.') {
            Some((base, ch)) => ident(base) && matches!(ch, "r" | "g" | "b"),
            None => ident(k),
        };
        if !valid {
            return Err(format!("`{k}` is not a valid name in `{part}` (a name, or a colour channel like `base.r`)"));
        }
        let v: f64 = match v.trim() {
            "true" => 1.0,
            "false" => 0.0,
            t => t.parse().map_err(|_| format!("`{t}` is not a number (or true/false) in `{part}`"))?,
        };
        if !v.is_finite() {
            return Err(format!("`{part}`: the value must be finite"));
        }
        if out.iter().any(|(j, _)| j == k) {
            return Err(format!("`{k}` is given twice in `{s}`; give each name once"));
        }
        out.push((k.to_string(), v));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    #[test]
    fn suggests_close_names() {
        assert_eq!(super::suggest("NX", ["NH", "NL", "NV", "VR"]), Some("NH"));
        assert_eq!(super::suggest("NX", ["n", "NH"]), Some("NH"));
        assert_eq!(super::suggest("nh", ["n", "NH"]), Some("NH"));
        assert_eq!(super::suggest("c", ["d", "n"]), None);
        assert_eq!(super::suggest("acoss", ["acos", "cos"]), Some("acos"));
        assert_eq!(super::suggest("zzzzzz", ["acos", "cos"]), None);
        // A name no typo makes gets no suggestion, even against itself misspelt (that comparison was quadratic).
        let long = "a".repeat(500_000);
        assert_eq!(super::suggest(&long, [long[1..].to_string().as_str(), "acos"]), None);
        // A candidate whose length alone rules it out is not measured, and does not change the answer.
        assert_eq!(super::suggest("acoss", ["acos", &"x".repeat(100)]), Some("acos"));
    }

    #[test]
    fn a_lone_cr_breaks_lines_like_lf_and_crlf() {
        for src in ["let a = NH\na^n", "let a = NH\r\na^n", "let a = NH\ra^n"] {
            let f = super::parse("f.brdf", src).unwrap_or_else(|d| panic!("{src:?}: {d}"));
            assert_eq!(f.used_inputs().iter().map(|i| i.name()).collect::<Vec<_>>(), ["NH"], "{src:?}");
        }
        // Errors after a lone CR are placed on the next line, and the caret text shows the line alone.
        let d = super::parse("f.brdf", "let a = NH\ra ^^ n").unwrap_err();
        let text = d.render(false);
        assert!(text.contains("f.brdf:2:4"), "{text}");
        assert!(!text.contains('\r'), "{text:?}");
        assert_eq!(d.to_json()[0]["line"], 2);
    }
}
