//! BRDF Explorer files (Disney's `.brdf` format, github wdas/brdf) read as lobe formulas.
//!
//! A file is recognised by its content ([`is_explorer`]): `analytic` as the first line that is not a `#`
//! comment, or a `::begin shader` block. Its `::begin parameters` block declares `float NAME MIN MAX DEFAULT`,
//! `bool NAME DEFAULT` and `color NAME R G B` (a colour is three consecutive parameters `NAME.r/.g/.b`);
//! parameter 0 is `n` as everywhere in lobe (the file's own `float n`, else an implicit `n` the shader cannot
//! see). Its `::begin shader` block is GLSL defining `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)`.
//!
//! Design: [`glsl`] parses the subset of GLSL the corpus is written in (hand-written lexer and recursive
//! descent, depth-capped) and [`exec`] lowers `BRDF` by symbolic execution into the scalar IR through
//! [`Values`](crate::front::values::Values): helpers are inlined per call, `if`/`else` and early returns become
//! exact selects, so an untaken branch's NaN or infinity never reaches the result. GLSL semantics are kept: no
//! input clamp, no root clamp (only the acos/asin argument clamp every lobe backend has).
//!
//! Why not naga's GLSL front end: it would add naga (and its dependency tree) to every build for one command
//! family, and its output is naga IR (typed SSA with pointers, loops, function calls, `Store`s) that still needs
//! this same symbolic execution to become lobe's straight-line scalar IR; what it saves is the parser and its
//! AST ([`glsl`], under 800 lines). Its build time was not measured (not cheap to fetch and build here). It also reports errors in its own spans, not with lobe's carets and hints, and it rejects
//! what BRDF Explorer's drivers accept (user functions named like builtins: `reflect`, `smoothstep`).
//!
//! Cost: linear in the file plus the inlined size of `BRDF` (each helper call re-lowers the helper; the
//! hash-consed arena shares what repeats). Lowering stops at [`exec::MAX_WORK`] expression evaluations so a file
//! whose helpers call each other twice per level cannot expand exponentially.

pub(crate) mod exec;
pub(crate) mod glsl;

use crate::base::diag::{Diagnostic, Diagnostics};
use crate::base::span::Span;
use crate::ir::{ParamDecl, ParamKind};

/// Whether `src` is a BRDF Explorer file rather than lobe's own language.
pub(crate) fn is_explorer(src: &str) -> bool {
    let first = src.lines().map(str::trim).find(|l| !l.is_empty() && !l.starts_with('#'));
    first == Some("analytic") || src.lines().any(|l| l.trim() == "::begin shader")
}

/// A declared parameter and, for a colour, its first index; `index` is into the formula's parameter list.
#[derive(Clone, Debug)]
pub(crate) struct Declared {
    pub name: String,
    pub span: Span,
    pub kind: glsl::Type,
    pub index: u16,
}

/// The parsed file: parameters (n first) and the shader block's byte range.
struct Sections {
    params: Vec<ParamDecl>,
    declared: Vec<Declared>,
    shader: (usize, usize),
}

/// Parses and lowers a BRDF Explorer file; on success also returns warnings (possibly none).
pub(crate) fn parse(file: &str, src: &str) -> Result<(crate::ir::Formula, Diagnostics), Diagnostics> {
    let mut warnings = Diagnostics::new(file, src);
    let fail = |d: Diagnostic| Diagnostics::single_in(file, src, d);
    let s = sections(src, &mut warnings).map_err(fail)?;
    let toks = glsl::lex(src, s.shader.0, s.shader.1).map_err(fail)?;
    let items = glsl::parse(&toks).map_err(fail)?;
    let f = exec::lower(file, src, s.params, &s.declared, &items, Span::new(s.shader.0, s.shader.1)).map_err(fail)?;
    Ok((f, warnings))
}

/// Lines with their byte offsets.
fn lines(src: &str) -> impl Iterator<Item = (usize, &str, usize)> {
    let mut off = 0;
    src.split_inclusive('\n').map(move |l| {
        let at = off;
        off += l.len();
        (at, l.trim_end_matches(['\n', '\r']), off)
    })
}

fn sections(src: &str, warnings: &mut Diagnostics) -> Result<Sections, Diagnostic> {
    let mut block: Option<(&str, usize, Span)> = None;
    let mut shader = None;
    let mut param_lines = Vec::new();
    let mut seen_params = false;
    for (at, line, next) in lines(src) {
        let t = line.trim();
        let lead = line.len() - line.trim_start().len();
        let span = Span::new(at + lead, at + lead + t.len());
        if let Some(rest) = t.strip_prefix("::begin") {
            if let Some((_, _, open)) = block {
                return Err(Diagnostic::error("a `::begin` inside another block")
                    .at(span, "nested")
                    .also(open, "this block is still open")
                    .hint("close the block above with `::end …` first"));
            }
            let kind = rest.trim();
            match kind {
                "parameters" if !seen_params => seen_params = true,
                "shader" if shader.is_none() => {}
                "parameters" | "shader" => {
                    return Err(Diagnostic::error(format!("a second `::begin {kind}` block"))
                        .at(span, "second block")
                        .hint("a BRDF Explorer file has one parameters block and one shader block"))
                }
                _ => {
                    return Err(Diagnostic::error(format!("unknown block `::begin {kind}`"))
                        .at(span, "unknown block")
                        .hint("lobe reads analytic BRDF files: `::begin parameters` and `::begin shader`"))
                }
            }
            block = Some((if kind == "shader" { "shader" } else { "parameters" }, next, span));
            continue;
        }
        if let Some(rest) = t.strip_prefix("::end") {
            let kind = rest.trim();
            match block {
                Some((open, start, _)) if open == kind => {
                    if kind == "shader" {
                        shader = Some((start, at));
                    }
                    block = None;
                }
                Some((open, _, ospan)) => {
                    return Err(Diagnostic::error(format!("`::end {kind}` closes the `{open}` block"))
                        .at(span, "mismatched")
                        .also(ospan, "opened here")
                        .hint(format!("write `::end {open}`")))
                }
                None => {
                    return Err(Diagnostic::error(format!("`::end {kind}` without a `::begin`"))
                        .at(span, "nothing to close")
                        .hint("remove it, or open the block with `::begin`"))
                }
            }
            continue;
        }
        match block {
            Some(("parameters", ..)) => param_lines.push((span, t)),
            Some(_) => {}
            None if t.is_empty() || t.starts_with('#') || t == "analytic" => {}
            None => {
                return Err(Diagnostic::error("text outside the `::begin`/`::end` blocks")
                    .at(span, "not in a block")
                    .hint("comments start with `#`; parameters and the shader go inside their blocks"))
            }
        }
    }
    if let Some((open, _, span)) = block {
        return Err(Diagnostic::error(format!("the `{open}` block is never closed"))
            .at(span, "opened here")
            .hint(format!("end it with `::end {open}`")));
    }
    let shader = shader.ok_or_else(|| {
        Diagnostic::error("no `::begin shader` block").hint(
            "a BRDF Explorer analytic file defines `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)` in a `::begin shader` … `::end shader` block",
        )
    })?;
    let (params, declared) = parameters(&param_lines, warnings)?;
    Ok(Sections { params, declared, shader })
}

/// The parameters block: one declaration a line; `#` starts a comment.
fn parameters(lines: &[(Span, &str)], warnings: &mut Diagnostics) -> Result<(Vec<ParamDecl>, Vec<Declared>), Diagnostic> {
    let mut params: Vec<ParamDecl> = Vec::new();
    let mut declared: Vec<Declared> = Vec::new();
    let has_n = lines.iter().any(|(_, l)| {
        let w: Vec<&str> = l.split_whitespace().collect();
        w.len() > 1 && w[1] == "n"
    });
    if !has_n {
        params.push(ParamDecl::float("n", 50.0, 1.0, 1000.0));
    }
    for (span, line) in lines {
        let text = line.split('#').next().unwrap_or("").trim();
        if text.is_empty() {
            continue;
        }
        // Spans of the words, for carets.
        let mut words: Vec<(&str, Span)> = Vec::new();
        let mut off = 0;
        for w in text.split_whitespace() {
            let k = text[off..].find(w).unwrap_or(0) + off;
            words.push((w, Span::new(span.start as usize + k, span.start as usize + k + w.len())));
            off = k + w.len();
        }
        let (kind, name, name_span) = match words.as_slice() {
            [(k, _), (n, s), ..] => (*k, *n, *s),
            _ => {
                return Err(Diagnostic::error("a parameter line needs a type and a name")
                    .at(*span, "incomplete")
                    .hint("write `float NAME MIN MAX DEFAULT`, `bool NAME DEFAULT` or `color NAME R G B`"))
            }
        };
        if !name.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        {
            return Err(Diagnostic::error(format!("`{name}` is not a valid parameter name"))
                .at(name_span, "not an identifier")
                .hint("names are letters, digits and `_`, not starting with a digit"));
        }
        if let Some(d) = declared.iter().find(|d| d.name == name) {
            return Err(Diagnostic::error(format!("parameter `{name}` is declared twice"))
                .at(name_span, "again here")
                .also(d.span, "first here")
                .hint("give each parameter one line"));
        }
        let count = match kind {
            "float" | "color" => 3,
            "bool" => 1,
            _ => {
                return Err(Diagnostic::error(format!("unknown parameter type `{kind}`"))
                    .at(words[0].1, "unknown type")
                    .hint("parameter types are float, bool and color"))
            }
        };
        let nums: Vec<f64> = words[2..]
            .iter()
            .map(|(w, s)| {
                let v = match (kind, *w) {
                    ("bool", "true") => Some(1.0),
                    ("bool", "false") => Some(0.0),
                    _ => w.parse::<f64>().ok().filter(|v| v.is_finite()),
                };
                v.ok_or_else(|| {
                    Diagnostic::error(format!("`{w}` is not a number"))
                        .at(*s, "expected a number")
                        .hint("write numbers like `0.5`, `.5` or `1e-3`")
                })
            })
            .collect::<Result<_, _>>()?;
        if nums.len() != count {
            let form = match kind {
                "float" => "float NAME MIN MAX DEFAULT",
                "bool" => "bool NAME DEFAULT (0 or 1)",
                _ => "color NAME R G B",
            };
            return Err(Diagnostic::error(format!("a {kind} parameter takes {count} number(s), found {}", nums.len()))
                .at(*span, "wrong count")
                .hint(format!("write `{form}`")));
        }
        if name == "n" && kind != "float" {
            return Err(Diagnostic::error("parameter `n` must be a float")
                .at(name_span, "not a float")
                .hint("lobe's parameter 0 is always the float `n`; rename this parameter"));
        }
        let decl = |name: String, default: f64, lo: f64, hi: f64, kind: ParamKind| ParamDecl {
            name,
            default,
            lo,
            hi,
            span: Some(name_span),
            kind,
        };
        let index = if name == "n" { 0 } else { params.len() as u16 };
        let (ty, new): (glsl::Type, Vec<ParamDecl>) = match kind {
            "float" => {
                let (lo, hi, d) = (nums[0], nums[1], nums[2]);
                if lo > hi {
                    return Err(Diagnostic::error(format!("`{name}`: the minimum {lo} is above the maximum {hi}"))
                        .at(*span, "empty range")
                        .hint("write `float NAME MIN MAX DEFAULT`"));
                }
                if d < lo || d > hi {
                    warnings.push(
                        Diagnostic::warning(format!("`{name}`: the default {d} is outside {lo}..{hi}; the range is widened"))
                            .at(*span, "default outside the range")
                            .hint("the order is `float NAME MIN MAX DEFAULT`"),
                    );
                }
                (glsl::Type::Float, vec![decl(name.into(), d, lo.min(d), hi.max(d), ParamKind::Float)])
            }
            "bool" => {
                let d = nums[0];
                if d != 0.0 && d != 1.0 {
                    return Err(Diagnostic::error(format!("`{name}`: a bool's default is 0 or 1, not {d}"))
                        .at(words[2].1, "not 0 or 1")
                        .hint("write `bool NAME 0` or `bool NAME 1`"));
                }
                (glsl::Type::Bool, vec![decl(name.into(), d, 0.0, 1.0, ParamKind::Bool)])
            }
            _ => (
                glsl::Type::Vec3,
                (0..3)
                    .map(|k| {
                        let c = nums[k];
                        decl(format!("{name}.{}", ["r", "g", "b"][k]), c, c.min(0.0), c.max(1.0), ParamKind::Color(k as u8))
                    })
                    .collect(),
            ),
        };
        if name == "n" {
            params.splice(0..0, new);
            for d in &mut declared {
                d.index += 1;
            }
        } else {
            params.extend(new);
        }
        declared.push(Declared { name: name.into(), span: name_span, kind: ty, index });
    }
    if params.len() > u16::MAX as usize {
        return Err(Diagnostic::error("too many parameters").hint("a formula has at most 65535 parameters"));
    }
    Ok((params, declared))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognises_explorer_files_by_content() {
        assert!(is_explorer("# c\n\nanalytic\n::begin parameters\n::end parameters\n"));
        assert!(is_explorer("::begin shader\nvec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { return L; }\n::end shader\n"));
        assert!(!is_explorer("# analytic\nparam a = 1\nNH^n\n"));
    }

    #[test]
    fn n_is_parameter_zero_and_colours_are_three() {
        let src = "analytic\n::begin parameters\ncolor c .1 .2 .3\nbool b 1\nfloat n 1 100 10\n::end parameters\n\
                   ::begin shader\nvec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { return b ? c * n : vec3(0); }\n::end shader\n";
        let (f, _) = parse("t.brdf", src).unwrap();
        let names: Vec<&str> = f.params.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["n", "c.r", "c.g", "c.b", "b"]);
        assert_eq!(f.params[2].kind, ParamKind::Color(1));
        assert_eq!(f.params[4].kind, ParamKind::Bool);
        assert!(f.is_rgb());
    }
}
