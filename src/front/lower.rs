//! Lowering: the AST → [`Formula`], resolving names and arity and writing the domain policy into the IR.
//!
//! Design: one pass over the statements in order. Metadata and `param`s are global (collected first, `n` is
//! always parameter 0, implicitly `param n = 50 in 1..1000`); `let`s are visible only after their own
//! statement. Expressions are lowered with an explicit stack (post-order), so a 500 000-deep spine costs a
//! `Vec`, not native stack. Every name error is reported — a subexpression that failed becomes *poison*,
//! which propagates silently upward, so one mistake yields one message. Each input reference lowers to
//! `clamp(INPUT, 0, 1)` and the root to `max(raw, 0)` (the decided domain policy; see `ir.rs`).
//! Warnings (unused `let`/`param`, no input read) are produced only for files without errors.

use super::ast::{Ast, BinOp as AstOp, ExprId, ExprKind, Ident, Lit, StmtKind};
use crate::base::diag::Diagnostic;
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Input, Ir, Meta, NodeId, ParamDecl, ParamKind};
use std::collections::HashMap;

/// Default and range of the implicit specular exponent `n`.
pub const N_DEFAULT: (f64, f64, f64) = (50.0, 1.0, 1000.0);

/// Inputs in the order suggestions prefer them (most common first: Blinn, Phong, then the rest).
const INPUT_PREFERENCE: [&str; 5] = ["NH", "VR", "NL", "NV", "VH"];

/// Common names from other languages and what to write instead.
const FUNCTION_ALIASES: [(&str, &str); 11] = [
    ("log", "ln"),
    ("arccos", "acos"),
    ("arcsin", "asin"),
    ("arctan", "atan"),
    ("power", "pow"),
    ("powf", "pow"),
    ("fabs", "abs"),
    ("fmin", "min"),
    ("fmax", "max"),
    ("saturate", "clamp"),
    ("exp2", "pow"),
];

#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    Todo,
    Done(NodeId),
    /// Failed (already reported); users of it fail silently.
    Poison,
}

struct Let<'s> {
    name: Ident<'s>,
    value: Slot,
    used: bool,
}

struct Lowerer<'a, 's> {
    ast: &'a Ast<'s>,
    ir: Ir,
    params: Vec<ParamDecl>,
    param_names: HashMap<&'s str, u16>,
    lets: Vec<Let<'s>>,
    /// Lets visible so far, by name.
    scope: HashMap<&'s str, usize>,
    /// Every `let` in the file (name → its name span), for "used before its `let`".
    all_lets: HashMap<&'s str, Span>,
    memo: Vec<Slot>,
    /// Operand buffer reused across nodes (one allocation per file, not per node).
    args: Vec<NodeId>,
    diags: Vec<Diagnostic>,
}

/// Lowers a parsed file. `syntax_failed` suppresses the structural errors a syntax error may have caused
/// (a formula line that failed to parse is not "missing"). Returns `None` when any error was reported.
pub fn lower(
    file: &str,
    src: &str,
    ast: &Ast<'_>,
    syntax_failed: bool,
    diags: &mut Vec<Diagnostic>,
) -> Option<Formula> {
    let mut lw = Lowerer {
        ast,
        ir: Ir::new(),
        params: vec![ParamDecl::float("n", N_DEFAULT.0, N_DEFAULT.1, N_DEFAULT.2)],
        param_names: HashMap::from([("n", 0u16)]),
        lets: vec![],
        scope: HashMap::new(),
        all_lets: HashMap::new(),
        memo: vec![Slot::Todo; ast.exprs.len()],
        args: vec![],
        diags: vec![],
    };
    let meta = lw.meta();
    lw.declare_params();
    for s in &ast.stmts {
        if let StmtKind::Let { name, .. } = &s.kind {
            lw.all_lets.entry(name.name).or_insert(name.span);
        }
    }
    let root = lw.statements(syntax_failed);
    let failed = syntax_failed || !lw.diags.is_empty();
    let formula = match root {
        Some((Slot::Done(raw), span)) if !failed => {
            let zero = lw.ir.konst(0.0, span);
            let root = lw.ir.call(Builtin::Max, &[raw, zero], span);
            lw.warnings(root, span);
            Some(Formula {
                meta,
                params: lw.params,
                ir: lw.ir,
                root,
                file: file.to_string(),
                source: src.to_string(),
                rgb: None,
            })
        }
        _ => None,
    };
    diags.append(&mut lw.diags);
    formula
}

/// `name(x, y)`-style signature of a builtin, for hints.
fn signature(b: Builtin) -> String {
    let args = match (b, b.arity()) {
        (Builtin::Clamp, _) => "x, lo, hi",
        (Builtin::Min | Builtin::Max, _) => "a, b",
        (_, 1) => "x",
        (_, 2) => "x, y",
        _ => "x, y, z",
    };
    format!("{}({args})", b.name())
}

fn plural(n: usize, one: &str) -> String {
    if n == 1 {
        format!("1 {one}")
    } else {
        format!("{n} {one}s")
    }
}

impl<'a, 's> Lowerer<'a, 's> {
    fn error(&mut self, d: Diagnostic) {
        self.diags.push(d);
    }

    /// `@name` and `@cite`.
    fn meta(&mut self) -> Meta {
        let mut meta = Meta::default();
        let mut seen: HashMap<&str, Span> = HashMap::new();
        for s in &self.ast.stmts {
            let StmtKind::Meta { key, value, .. } = &s.kind else { continue };
            let slot = match key.name {
                "name" => &mut meta.name,
                "cite" => &mut meta.citation,
                other => {
                    let mut d = Diagnostic::error(format!("unknown metadata key `@{other}`"))
                        .at(key.span, "not a metadata key");
                    let synonym = match other.to_ascii_lowercase().as_str() {
                        "title" | "label" | "display" | "model" => Some("name"),
                        "citation" | "ref" | "reference" | "source" | "eq" | "paper" => Some("cite"),
                        _ => None,
                    };
                    d = match synonym.or_else(|| super::suggest(other, ["name", "cite"])) {
                        Some(k) => d.hint(format!("did you mean `@{k}`? The keys are `@name` and `@cite`")),
                        None => d.hint("the keys are `@name \"display name\"` and `@cite \"source, equation\"`"),
                    };
                    self.error(d);
                    continue;
                }
            };
            if let Some(first) = seen.get(key.name) {
                let d = Diagnostic::error(format!("`@{}` is given twice", key.name))
                    .at(key.span, "second one here")
                    .also(*first, "first one here")
                    .hint("keep one of them");
                self.error(d);
                continue;
            }
            seen.insert(key.name, key.span);
            *slot = Some(value.to_string());
        }
        meta
    }

    /// What a name already means, if it is reserved (input, constant, builtin).
    fn reserved(name: &str) -> Option<String> {
        if let Some(i) = Input::from_name(name) {
            return Some(format!("the input {} ({})", i.name(), i.describe()));
        }
        if name == "pi" {
            return Some("the constant pi".into());
        }
        Builtin::from_name(name).map(|b| format!("the function {}", signature(b)))
    }

    fn declare_params(&mut self) {
        let mut declared: HashMap<&'s str, Span> = HashMap::new();
        for s in &self.ast.stmts {
            let StmtKind::Param { name, default, range } = &s.kind else { continue };
            if let Some(what) = Self::reserved(name.name) {
                self.error(
                    Diagnostic::error(format!("`param {}` would shadow {what}", name.name))
                        .at(name.span, "this name is taken")
                        .hint("choose another parameter name"),
                );
                continue;
            }
            if let Some(first) = declared.get(name.name) {
                self.error(
                    Diagnostic::error(format!("parameter `{}` is declared twice", name.name))
                        .at(name.span, "second declaration")
                        .also(*first, "first declared here")
                        .hint("keep one declaration"),
                );
                continue;
            }
            declared.insert(name.name, name.span);
            let (lo, hi) = match range {
                Some((lo, hi)) => (*lo, *hi),
                None if name.name == "n" => {
                    let at = Lit { value: 0.0, span: default.span };
                    (Lit { value: N_DEFAULT.1, ..at }, Lit { value: N_DEFAULT.2, ..at })
                }
                None => {
                    let at = Lit { value: 0.0, span: default.span };
                    (Lit { value: f64::NEG_INFINITY, ..at }, Lit { value: f64::INFINITY, ..at })
                }
            };
            // An invalid range is reported, but the parameter is still declared so its uses do not cascade.
            self.check_range(name, *default, lo, hi, range.is_some());
            let decl = ParamDecl {
                name: name.name.to_string(),
                default: default.value,
                lo: lo.value,
                hi: hi.value,
                span: Some(s.span),
                kind: ParamKind::Float,
            };
            if name.name == "n" {
                self.params[0] = decl;
            } else if self.params.len() >= u16::MAX as usize {
                self.error(Diagnostic::error("too many parameters").at(name.span, "here").hint("use fewer than 65535"));
            } else {
                self.param_names.insert(name.name, self.params.len() as u16);
                self.params.push(decl);
            }
        }
    }

    /// Validates `default in lo..hi`; reports and returns false when invalid.
    fn check_range(&mut self, name: &Ident, default: Lit, lo: Lit, hi: Lit, explicit: bool) -> bool {
        // The implicit range of a parameter other than `n` is unbounded on purpose; written numbers must be finite.
        let written: &[Lit] = if explicit { &[default, lo, hi] } else { &[default] };
        for &l in written {
            if !l.value.is_finite() {
                self.error(
                    Diagnostic::error(format!("parameter `{}` has a non-finite value", name.name))
                        .at(l.span, "not a finite number")
                        .hint("defaults and range bounds must be finite numbers"),
                );
                return false;
            }
        }
        if lo.value > hi.value {
            self.error(
                Diagnostic::error(format!(
                    "the range of `{}` is empty: {} is greater than {}",
                    name.name,
                    crate::ir::print::number(lo.value),
                    crate::ir::print::number(hi.value)
                ))
                .at(lo.span.join(hi.span), "lower bound above upper bound")
                .hint(format!(
                    "write the smaller bound first: `in {}..{}`",
                    crate::ir::print::number(hi.value),
                    crate::ir::print::number(lo.value)
                )),
            );
            return false;
        }
        if !(lo.value..=hi.value).contains(&default.value) {
            let range = format!("{}..{}", crate::ir::print::number(lo.value), crate::ir::print::number(hi.value));
            let mut d = Diagnostic::error(format!(
                "the default {} of `{}` is outside its range {range}",
                crate::ir::print::number(default.value),
                name.name
            ))
            .at(default.span, "outside the range");
            if explicit {
                d = d.also(lo.span.join(hi.span), "the range");
            }
            let hint = if explicit {
                "choose a default within the range, or widen the range".to_string()
            } else {
                format!("`{}` has the implicit range {range}; give a range with `in lo..hi` to change it", name.name)
            };
            self.error(d.hint(hint));
            return false;
        }
        true
    }

    /// Lets and the final expression, in order; returns the final expression's value and span.
    fn statements(&mut self, syntax_failed: bool) -> Option<(Slot, Span)> {
        let ast = self.ast;
        let mut formula: Option<(Slot, Span)> = None;
        let mut extra_reported = false;
        for s in &ast.stmts {
            if let (Some((_, fspan)), false) = (formula, matches!(s.kind, StmtKind::Expr(_) | StmtKind::Error)) {
                let what = match &s.kind {
                    StmtKind::Let { .. } => "`let`",
                    StmtKind::Param { .. } => "`param`",
                    _ => "metadata",
                };
                self.error(
                    Diagnostic::error(format!("{what} after the formula"))
                        .at(s.span, "this comes after the final expression")
                        .also(fspan, "the formula")
                        .hint("the formula must be the last statement; move this line above it"),
                );
            }
            match &s.kind {
                StmtKind::Let { name, value } => self.let_(*name, *value),
                StmtKind::Expr(e) => {
                    let v = self.expr(*e);
                    match formula {
                        None => formula = Some((v, s.span)),
                        Some((_, first)) => {
                            if !extra_reported {
                                self.error(
                                    Diagnostic::error("more than one final expression")
                                        .at(s.span, "a second expression")
                                        .also(first, "the first expression")
                                        .hint(
                                            "a file holds one formula: join the expressions with an operator, or \
                                             bind the first one with `let name = …`",
                                        ),
                                );
                                extra_reported = true;
                            }
                        }
                    }
                }
                StmtKind::Meta { .. } | StmtKind::Param { .. } | StmtKind::Error => {}
            }
        }
        if formula.is_none() && !syntax_failed {
            let last_let = ast.stmts.iter().rev().find_map(|s| match &s.kind {
                StmtKind::Let { name, .. } => Some((s.span, name.name)),
                _ => None,
            });
            let d = match last_let {
                Some((span, name)) => Diagnostic::error("`let` without a final expression")
                    .at(span, "the file ends with this `let`")
                    .hint(format!(
                        "a `let` only names a value; add the formula as the last line, e.g. `{name}`"
                    )),
                None => Diagnostic::error("the file has no formula").hint(
                    "write an expression such as `NH^n` (Blinn) or `VR^n` (Phong); lines starting with `#` are \
                     comments",
                ),
            };
            self.error(d);
        }
        formula
    }

    fn let_(&mut self, name: Ident<'s>, value: ExprId) {
        let mut ok = true;
        if let Some(what) = Self::reserved(name.name) {
            self.error(
                Diagnostic::error(format!("`let {}` would shadow {what}", name.name))
                    .at(name.span, "this name is taken")
                    .hint("choose another name for the binding"),
            );
            ok = false;
        } else if let Some(&p) = self.param_names.get(name.name) {
            let mut d = Diagnostic::error(format!("`{}` is already a parameter", name.name))
                .at(name.span, "this `let` reuses its name");
            if let Some(ps) = self.params[p as usize].span {
                d = d.also(ps, "declared here");
            }
            self.error(d.hint("choose another name for the binding"));
            ok = false;
        } else if name.name == "n" {
            self.error(
                Diagnostic::error("`let n` would shadow the parameter `n`")
                    .at(name.span, "this name is taken")
                    .hint("`n` is always the specular exponent; change its default with `param n = 100`"),
            );
            ok = false;
        } else if let Some(&first) = self.scope.get(name.name) {
            let first_span = self.lets[first].name.span;
            self.error(
                Diagnostic::error(format!("`{}` is defined twice", name.name))
                    .at(name.span, "second `let`")
                    .also(first_span, "first defined here")
                    .hint("a `let` cannot be reassigned; give the second one another name"),
            );
            ok = false;
        }
        let v = self.expr(value);
        if ok {
            self.scope.insert(name.name, self.lets.len());
            self.lets.push(Let { name, value: v, used: false });
        }
    }

    /// Lowers one expression with an explicit stack (children first).
    fn expr(&mut self, root: ExprId) -> Slot {
        let ast = self.ast;
        let mut stack = vec![(root, false)];
        while let Some((id, children_done)) = stack.pop() {
            if self.memo[id.index()] != Slot::Todo {
                continue;
            }
            let e = ast.expr(id);
            if !children_done {
                stack.push((id, true));
                e.for_each_child(|c| stack.push((c, false)));
                continue;
            }
            let mut args = std::mem::take(&mut self.args);
            args.clear();
            let mut poisoned = false;
            e.for_each_child(|c| match self.memo[c.index()] {
                Slot::Done(n) => args.push(n),
                _ => poisoned = true,
            });
            let span = e.span;
            let out = match &e.kind {
                ExprKind::Error => Slot::Poison,
                ExprKind::Name(n) => self.name(*n),
                ExprKind::Call(n, a) => match self.check_call(*n, a.len(), span) {
                    Some(b) if !poisoned => Slot::Done(self.ir.call(b, &args, span)),
                    _ => Slot::Poison,
                },
                _ if poisoned => Slot::Poison,
                ExprKind::Num(v) => Slot::Done(self.ir.konst(*v, span)),
                ExprKind::Paren(_) => Slot::Done(args[0]),
                ExprKind::Neg(_) => Slot::Done(self.ir.neg(args[0], span)),
                ExprKind::Binary(op, _, _) => {
                    let (a, b) = (args[0], args[1]);
                    Slot::Done(match op {
                        AstOp::Add => self.ir.bin(BinOp::Add, a, b, span),
                        AstOp::Sub => self.ir.bin(BinOp::Sub, a, b, span),
                        AstOp::Mul => self.ir.bin(BinOp::Mul, a, b, span),
                        AstOp::Div => self.ir.bin(BinOp::Div, a, b, span),
                        AstOp::Pow => self.ir.call(Builtin::Pow, &[a, b], span),
                    })
                }
            };
            self.memo[id.index()] = out;
            self.args = args;
        }
        self.memo[root.index()]
    }

    /// A name used as a value.
    fn name(&mut self, n: Ident<'s>) -> Slot {
        let span = n.span;
        if let Some(&i) = self.scope.get(n.name) {
            self.lets[i].used = true;
            return self.lets[i].value;
        }
        if let Some(&p) = self.param_names.get(n.name) {
            return Slot::Done(self.ir.param(p, span));
        }
        if let Some(input) = Input::from_name(n.name) {
            let x = self.ir.input(input, span);
            let zero = self.ir.konst(0.0, span);
            let one = self.ir.konst(1.0, span);
            return Slot::Done(self.ir.call(Builtin::Clamp, &[x, zero, one], span));
        }
        if n.name == "pi" {
            return Slot::Done(self.ir.konst(std::f64::consts::PI, span));
        }
        if let Some(b) = Builtin::from_name(n.name) {
            self.error(
                Diagnostic::error(format!("`{}` is a function, not a variable", n.name))
                    .at(span, "used without arguments")
                    .hint(format!("call it: `{}` — {}", signature(b), b.info().doc)),
            );
            return Slot::Poison;
        }
        let d = self.unknown_variable(n);
        self.error(d);
        Slot::Poison
    }

    fn unknown_variable(&self, n: Ident<'s>) -> Diagnostic {
        if let Some(&def) = self.all_lets.get(n.name) {
            if def.start > n.span.start {
                return Diagnostic::error(format!("`{}` is used before its `let`", n.name))
                    .at(n.span, "used here")
                    .also(def, "defined later, here")
                    .hint(format!("move `let {} = …` above this line", n.name));
            }
            // The only other way a known `let` is out of scope: its own value refers to it.
            return Diagnostic::error(format!("`{}` refers to itself", n.name))
                .at(n.span, "used inside its own definition")
                .also(def, "being defined here")
                .hint("a `let` cannot use its own name; use another name for the new value");
        }
        if self.diags.len() > super::MAX_ERRORS {
            // Past the display cap the message is not shown; skip the O(names) suggestion search.
            return Diagnostic::error(format!("unknown variable `{}`", n.name)).at(n.span, "not defined");
        }
        let mut cands: Vec<&str> = INPUT_PREFERENCE.to_vec();
        cands.extend(self.lets.iter().rev().map(|l| l.name.name));
        cands.extend(self.params.iter().map(|p| p.name.as_str()));
        cands.push("pi");
        let exact_ci = cands.iter().copied().find(|c| c.eq_ignore_ascii_case(n.name));
        let sugg = exact_ci.or_else(|| super::suggest(n.name, cands.iter().copied()));
        let msg = match sugg {
            Some(s) => format!("unknown variable `{}`; did you mean `{s}`?", n.name),
            None => format!("unknown variable `{}`", n.name),
        };
        let d = Diagnostic::error(msg).at(n.span, "not defined");
        if let Some(s) = sugg {
            return d.hint(match (exact_ci, Input::from_name(s)) {
                (Some(_), Some(i)) => format!("names are case-sensitive; `{}` is the {}", i.name(), i.describe()),
                (Some(_), None) => format!("names are case-sensitive: write `{s}`"),
                (None, Some(i)) => format!("`{}` is the {}", i.name(), i.describe()),
                (None, None) => format!("if `{}` is a new name, define it with `let` or `param` first", n.name),
            });
        }
        let hint = match n.name {
            "e" => "Euler's number is `exp(1)`".to_string(),
            "x" | "theta" | "angle" | "c" | "cos_theta" => {
                "the inputs are cosines NL, NV, NH, VR, VH; for the angle write `acos(NH)`, or bind a name with \
                 `let c = NH`"
                    .to_string()
            }
            _ => "the names available are the inputs NL, NV, NH, VR, VH, the constant pi, `n`, and names bound \
                  with `let` or declared with `param`"
                .to_string(),
        };
        d.hint(hint)
    }

    /// Resolves a call's function and checks its arity; reports and returns `None` on error.
    fn check_call(&mut self, n: Ident<'s>, nargs: usize, span: Span) -> Option<Builtin> {
        if let Some(b) = Builtin::from_name(n.name) {
            if b.arity() == nargs {
                return Some(b);
            }
            self.error(
                Diagnostic::error(format!(
                    "{} takes {}, found {nargs}",
                    n.name,
                    plural(b.arity(), "argument")
                ))
                .at(span, format!("called with {}", plural(nargs, "argument")))
                .hint(format!("`{}`: {}", signature(b), b.info().doc)),
            );
            return None;
        }
        let is_var = self.scope.contains_key(n.name)
            || self.param_names.contains_key(n.name)
            || Input::from_name(n.name).is_some()
            || n.name == "pi";
        if is_var {
            self.error(
                Diagnostic::error(format!("`{}` is a variable, not a function", n.name))
                    .at(span, "called like a function")
                    .hint(format!("to multiply, write the `*`: `{} * (…)`", n.name)),
            );
            return None;
        }
        let alias = FUNCTION_ALIASES.iter().find(|(a, _)| a.eq_ignore_ascii_case(n.name)).map(|(_, b)| *b);
        let names = Builtin::table().iter().map(|r| r.name);
        let sugg = alias.or_else(|| super::suggest(n.name, names.clone()));
        let msg = match sugg {
            Some(s) => format!("unknown function `{}`; did you mean `{s}`?", n.name),
            None => format!("unknown function `{}`", n.name),
        };
        let hint = match sugg.and_then(Builtin::from_name) {
            Some(b) => format!("`{}`: {}", signature(b), b.info().doc),
            None => format!("the functions are {}", names.collect::<Vec<_>>().join(", ")),
        };
        self.error(Diagnostic::error(msg).at(n.span, "not a builtin function").hint(hint));
        None
    }

    /// Unused `let`s and `param`s, and a formula that reads no input.
    fn warnings(&mut self, root: NodeId, span: Span) {
        for l in &self.lets {
            if !l.used && !l.name.name.starts_with('_') {
                self.diags.push(
                    Diagnostic::warning(format!("unused `let {}`", l.name.name))
                        .at(l.name.span, "never used")
                        .hint(format!("remove it, or name it `_{}` to keep it quietly", l.name.name)),
                );
            }
        }
        let used = self.ir.used_params(root);
        for (i, p) in self.params.iter().enumerate() {
            if let (Some(s), false) = (p.span, used.contains(&(i as u16))) {
                self.diags.push(
                    Diagnostic::warning(format!("parameter `{}` is never used", p.name))
                        .at(s, "declared here")
                        .hint(format!("remove the declaration, or use `{}` in the formula", p.name)),
                );
            }
        }
        if self.ir.used_inputs(root).is_empty() {
            self.diags.push(
                Diagnostic::warning("the formula reads no input")
                    .at(span, "the same value in every direction")
                    .hint("a lobe usually depends on NH (Blinn-style) or VR (Phong-style)"),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::builtins::Builtin;
    use crate::ir::{Input, Node};

    #[test]
    fn domain_policy_is_written_into_the_ir() {
        let f = crate::front::parse("t", "NH").expect("parses");
        let Node::Call(Builtin::Max, [raw, zero, _]) = *f.ir.node(f.root) else { panic!("root is max(raw, 0)") };
        assert_eq!(f.ir.node(zero).as_const(), Some(0.0));
        let Node::Call(Builtin::Clamp, [x, lo, hi]) = *f.ir.node(raw) else { panic!("an input is clamped") };
        assert_eq!(*f.ir.node(x), Node::Input(Input::NH));
        assert_eq!((f.ir.node(lo).as_const(), f.ir.node(hi).as_const()), (Some(0.0), Some(1.0)));
    }

    #[test]
    fn n_is_parameter_zero_and_lets_share_nodes() {
        let f = crate::front::parse("t", "param a = 2\nlet c = acos(NH)\nc * c + a * n").expect("parses");
        assert_eq!(f.params[0].name, "n");
        assert_eq!(f.params[1].name, "a");
        // `c` is lowered once: one acos node.
        let acos = f.ir.nodes().iter().filter(|n| matches!(n, Node::Call(Builtin::Acos, _))).count();
        assert_eq!(acos, 1);
        assert_eq!(f.ir.used_params(f.root), vec![0, 1]);
    }
}
