//! Lowering: the AST → [`Formula`], resolving names, types and arity and writing the domain policy into the IR.
//!
//! Design: one pass over the statements in order. Metadata and `param`s are global (collected first, `n` is
//! always parameter 0, implicitly `param n = 50 in 1..1000`); `let`s and `fn`s are visible only after their own
//! statement. Every value is typed (float, bool, vec3: [`Val`]) and every operation goes through
//! [`Values`], which expands vectors and booleans into scalar IR; a bool is a 0/1 node, a select never blends
//! its branches, so an infinite untaken branch cannot reach the result. Expressions are lowered with an
//! explicit stack (post-order), so a 500 000-deep spine costs a `Vec`, not native stack. Every name or type
//! error is reported at its span with a hint — a subexpression that failed becomes *poison*, which propagates
//! silently upward, so one mistake yields one message.
//!
//! Functions (`fn f(x) = body`) are inlined at each call with the argument types of the call. A body is
//! checked once at its definition (names, arity, recursion — with its arguments as poison, so only what does
//! not depend on them can fail there); type errors that depend on the arguments are reported at the body, with
//! the call as a second label, once per distinct message. A call with the same argument nodes reuses the
//! earlier expansion (hash-consing makes it the same IR anyway); nesting is capped at [`MAX_INLINE_DEPTH`]
//! (the only recursion on the native stack) and the total inlined body size at [`MAX_INLINED`], so a file of
//! functions that each call the previous one twice is refused rather than expanded 2^n times.
//!
//! Domain policy (`@domain brdf`, the default): each cosine input lowers to `clamp(INPUT, 0, 1)` and each
//! result channel to `max(raw, 0)`. `@domain raw` (GLSL semantics, what `lobe import` writes) adds neither.
//! Direction components and vectors are never clamped. Warnings (unused `let`/`param`/`fn`, no input read) are
//! produced only for files without errors. Cost: linear in the source plus the inlined bodies; the IR is
//! compacted once at the end (dropping what unused `let`s and function checks built).

use super::ast::{Ast, BinOp as AstOp, ExprId, ExprKind, Ident, Lit, ParamDefault, StmtKind};
use super::values::{Val, Values, DERIVED};
use crate::base::diag::Diagnostic;
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{Formula, Input, Ir, Meta, NodeId, ParamDecl, ParamKind};
use std::collections::{HashMap, HashSet};

mod decls;

/// Default and range of the implicit specular exponent `n`.
pub(crate) const N_DEFAULT: (f64, f64, f64) = (50.0, 1.0, 1000.0);

/// Deepest chain of function calls inside function bodies that is inlined.
pub(crate) const MAX_INLINE_DEPTH: usize = 64;

/// Most expression nodes inlined from function bodies in one file (about 8× the nodes of a 1 MB file).
pub(crate) const MAX_INLINED: usize = 4_000_000;

/// Inputs in the order suggestions prefer them (most common first: Blinn, Phong, then the rest).
const INPUT_PREFERENCE: [&str; 5] = ["NH", "VR", "NL", "NV", "VH"];

/// The frame vectors (see [`Values::frame`]).
const FRAME: [&str; 5] = ["L", "V", "N", "X", "Y"];

/// Named shorthands computed from the directions (see [`Values::shorthand`]); never clamped.
const SHORTHANDS: [&str; 7] = ["LV", "HX", "HY", "LX", "LY", "VX", "VY"];

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
    Done(Val),
    /// Failed (already reported); users of it fail silently.
    Poison,
}

struct Let<'s> {
    name: Ident<'s>,
    value: Slot,
    used: bool,
}

/// A user function: `fn name(args) = body`.
struct FnDef<'s> {
    name: Ident<'s>,
    args: Vec<Ident<'s>>,
    body: ExprId,
    /// Smallest expression id in the body (the body is the contiguous id range `lo..=body`).
    lo: usize,
    /// Its definition checked without errors (calls of a broken function are poison, silently).
    ok: bool,
    used: bool,
}

/// What a parameter name reads as.
#[derive(Clone, Copy, Debug, PartialEq)]
enum ParamRef {
    Float(u16),
    Bool(u16),
    /// The first of three consecutive parameters `NAME.r`, `.g`, `.b`.
    Color(u16),
}

/// Where an expression is lowered: the top level, or a function body with its arguments bound.
struct Ctx<'c, 's> {
    /// Functions with an index below this are callable.
    visible_fns: usize,
    /// The function whose body this is, while checking its definition (a call to it is recursion).
    defining: Option<&'s str>,
    args: &'c [(&'s str, Slot)],
    depth: usize,
    /// The top-level call being inlined, for messages about errors inside bodies.
    call: Option<Span>,
}

struct Lowerer<'a, 's> {
    ast: &'a Ast<'s>,
    ir: Ir,
    /// `@domain raw`: no input clamps and no root clamp.
    raw: bool,
    params: Vec<ParamDecl>,
    param_names: HashMap<&'s str, ParamRef>,
    lets: Vec<Let<'s>>,
    /// Lets visible so far, by name.
    scope: HashMap<&'s str, usize>,
    /// Every `let` in the file (name → its name span), for "used before its `let`".
    all_lets: HashMap<&'s str, Span>,
    fns: Vec<FnDef<'s>>,
    fn_names: HashMap<&'s str, usize>,
    /// Every `fn` in the file (name → its name span), for "used before its definition".
    all_fns: HashMap<&'s str, Span>,
    /// Expansions already made: (function, argument values) → result.
    inlined: HashMap<(usize, Vec<Val>), Slot>,
    inlined_nodes: usize,
    memo: Vec<Slot>,
    diags: Vec<Diagnostic>,
    /// Errors inside function bodies already reported (message, span start), so each shows once.
    reported: HashSet<(String, u32)>,
    /// The text may call the accuracy pass's internal builtins ([`super::parse_internal`]).
    internal: bool,
}

/// Lowers a parsed file. `syntax_failed` suppresses the structural errors a syntax error may have caused
/// (a formula line that failed to parse is not "missing"); `internal` lets it call the internal builtins
/// ([`Builtin::is_internal`]). Returns `None` when any error was reported.
pub(crate) fn lower(
    file: &str,
    src: &str,
    ast: &Ast<'_>,
    syntax_failed: bool,
    internal: bool,
    diags: &mut Vec<Diagnostic>,
) -> Option<Formula> {
    let mut lw = Lowerer {
        ast,
        ir: Ir::new(),
        raw: false,
        params: vec![ParamDecl::float("n", N_DEFAULT.0, N_DEFAULT.1, N_DEFAULT.2)],
        param_names: HashMap::from([("n", ParamRef::Float(0))]),
        lets: vec![],
        scope: HashMap::new(),
        all_lets: HashMap::new(),
        fns: vec![],
        fn_names: HashMap::new(),
        all_fns: HashMap::new(),
        inlined: HashMap::new(),
        inlined_nodes: 0,
        memo: vec![Slot::Todo; ast.exprs.len()],
        diags: vec![],
        reported: HashSet::new(),
        internal,
    };
    let meta = lw.meta();
    lw.declare_params();
    for s in &ast.stmts {
        match &s.kind {
            StmtKind::Let { name, .. } => {
                lw.all_lets.entry(name.name).or_insert(name.span);
            }
            StmtKind::Fn { name, .. } => {
                lw.all_fns.entry(name.name).or_insert(name.span);
            }
            _ => {}
        }
    }
    let root = lw.statements(syntax_failed);
    let failed = syntax_failed || !lw.diags.is_empty();
    let formula = match root {
        Some((Slot::Done(v), span)) if !failed => lw.finish(v, span, meta, file, src),
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
        (Builtin::Select, _) => "c, a, b",
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

/// The derived function `name` (or `rgb`, an alias of `vec3`): its arity and doc.
fn derived(name: &str) -> Option<(usize, &'static str)> {
    let name = if name == "rgb" { "vec3" } else { name };
    DERIVED.iter().find(|d| d.0 == name).map(|d| (d.1, d.2))
}

/// The component index of `.x .y .z` / `.r .g .b`.
fn component(name: &str) -> Option<usize> {
    match name {
        "x" | "r" => Some(0),
        "y" | "g" => Some(1),
        "z" | "b" => Some(2),
        _ => None,
    }
}

/// A hint for a type error, by the construct that failed and the types it met.
fn type_hint(what: &str, tys: &[Val]) -> String {
    let has = |t: fn(&Val) -> bool| tys.iter().any(t);
    let is_bool = |v: &Val| matches!(v, Val::B(_));
    let is_vec = |v: &Val| matches!(v, Val::V(_));
    match what {
        "cond" => "a condition is a bool: compare a number, like `x > 0`, or use a bool parameter".into(),
        "cmp" if has(is_vec) => "compare components (`L.z < 0.5`) or lengths (`length(v) < 1`)".into(),
        "cmp" => "`<`, `<=`, `>`, `>=` compare numbers; `==` and `!=` compare two numbers or two bools".into(),
        "branches" => "give both branches one type; `vec3(x)` makes a float a vector, `c ? 1 : 0` a bool a number".into(),
        "field" => "components belong to vectors: `L.x`, `H.z`, `base.r`".into(),
        _ if has(is_bool) => "a bool is not a number: write `c ? 1 : 0` for 0 or 1".into(),
        _ => "check the argument types".into(),
    }
}

impl<'a, 's> Lowerer<'a, 's> {
    fn error(&mut self, d: Diagnostic) {
        self.diags.push(d);
    }

    /// A type error at `span`; inside an inlined body, labelled with the call and reported once.
    fn type_error(&mut self, msg: String, span: Span, hint: String, ctx: &Ctx) {
        let mut d = Diagnostic::error(msg).at(span, "here");
        if let Some(call) = ctx.call {
            if !self.reported.insert((d.message.clone(), span.start)) {
                return;
            }
            d = d.also(call, "in the function called here");
        }
        self.error(d.hint(hint));
    }

    /// The result: a float is a scalar formula, a vec3 a colour formula, a bool an error.
    fn finish(&mut self, v: Val, span: Span, meta: Meta, file: &str, src: &str) -> Option<Formula> {
        let channels: Vec<NodeId> = match v {
            Val::F(x) => vec![x],
            Val::V(c) => c.to_vec(),
            Val::B(_) => {
                self.error(
                    Diagnostic::error("the formula is a bool, not a number")
                        .at(span, "this is true or false")
                        .hint("a BRDF is a number or a colour: write `c ? value : 0`, or `c ? 1 : 0` for 0 or 1"),
                );
                return None;
            }
        };
        let roots: Vec<NodeId> = channels
            .iter()
            .map(|&raw| {
                if self.raw {
                    raw
                } else {
                    let zero = self.ir.konst(0.0, span);
                    self.ir.call(Builtin::Max, &[raw, zero], span)
                }
            })
            .collect();
        self.warnings(&roots, span);
        let (file, source) = (file.to_string(), src.to_string());
        let ir = std::mem::take(&mut self.ir);
        let params = std::mem::take(&mut self.params);
        Some(match roots[..] {
            [r, g, b] => Formula::from_channels(meta, params, &ir, [r, g, b], file, source),
            _ => {
                let (ir, root) = ir.compact(roots[0]);
                Formula { meta, params, ir, root, file, source, rgb: None }
            }
        })
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
                    StmtKind::Fn { .. } => "`fn`",
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
                StmtKind::Fn { name, args, body } => self.fn_def(*name, args, *body),
                StmtKind::Expr(e) => {
                    let v = self.top_expr(*e);
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

    fn defined_twice(&mut self, msg: String, second: (Span, &str), first: Span, hint: &str) {
        self.error(Diagnostic::error(msg).at(second.0, second.1).also(first, "first defined here").hint(hint));
    }

    /// A parameter or function of this name (what it is, where it was declared).
    fn global_name(&self, name: &str) -> Option<(&'static str, Option<Span>)> {
        if let Some(&p) = self.param_names.get(name) {
            let (ParamRef::Float(i) | ParamRef::Bool(i) | ParamRef::Color(i)) = p;
            return Some(("a parameter", self.params[i as usize].span));
        }
        self.fn_names.get(name).map(|&f| ("a function", Some(self.fns[f].name.span)))
    }

    fn let_(&mut self, name: Ident<'s>, value: ExprId) {
        let mut ok = true;
        if let Some(what) = self.reserved(name.name) {
            self.error(
                Diagnostic::error(format!("`let {}` would shadow {what}", name.name))
                    .at(name.span, "this name is taken")
                    .hint("choose another name for the binding"),
            );
            ok = false;
        } else if let Some((what, at)) = self.global_name(name.name) {
            let mut d = Diagnostic::error(format!("`{}` is already {what}", name.name))
                .at(name.span, "this `let` reuses its name");
            if let Some(at) = at {
                d = d.also(at, "declared here");
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
            let first = self.lets[first].name.span;
            let msg = format!("`{}` is defined twice", name.name);
            self.defined_twice(msg, (name.span, "second `let`"), first, "a `let` cannot be reassigned; give the second one another name");
            ok = false;
        }
        let v = self.top_expr(value);
        if ok {
            self.scope.insert(name.name, self.lets.len());
            self.lets.push(Let { name, value: v, used: false });
        }
    }

    /// `fn name(args) = body`: checks the name, the arguments and the body (with the arguments as poison),
    /// then makes the function callable by the statements below it.
    fn fn_def(&mut self, name: Ident<'s>, args: &[Ident<'s>], body: ExprId) {
        let before = self.diags.len();
        let taken = self.reserved(name.name).or_else(|| {
            if self.param_names.contains_key(name.name) {
                Some(format!("the parameter `{}`", name.name))
            } else if self.scope.contains_key(name.name) {
                Some(format!("the `let {}`", name.name))
            } else {
                None
            }
        });
        if let Some(what) = taken {
            self.error(
                Diagnostic::error(format!("`fn {}` would shadow {what}", name.name))
                    .at(name.span, "this name is taken")
                    .hint("choose another function name"),
            );
        } else if let Some(&first) = self.fn_names.get(name.name) {
            let first = self.fns[first].name.span;
            let msg = format!("function `{}` is defined twice", name.name);
            self.defined_twice(msg, (name.span, "second definition"), first, "give the second function another name");
        }
        let mut bound: Vec<(&'s str, Slot)> = Vec::with_capacity(args.len());
        for a in args {
            if let Some(what) = self.reserved(a.name) {
                self.error(
                    Diagnostic::error(format!("argument `{}` would shadow {what}", a.name))
                        .at(a.span, "this name is taken")
                        .hint("choose another argument name"),
                );
            } else if bound.iter().any(|b| b.0 == a.name) {
                self.error(
                    Diagnostic::error(format!("argument `{}` is named twice", a.name))
                        .at(a.span, "second argument of this name")
                        .hint("give each argument its own name"),
                );
            }
            bound.push((a.name, Slot::Poison));
        }
        let ctx = Ctx { visible_fns: self.fns.len(), defining: Some(name.name), args: &bound, depth: 0, call: None };
        let lo = self.lowest_id(body);
        let mut memo = vec![Slot::Todo; body.index() + 1 - lo];
        self.tree(body, &mut memo, lo, &ctx);
        let ok = self.diags.len() == before;
        if self.fn_names.contains_key(name.name) || self.reserved(name.name).is_some() {
            return;
        }
        self.fn_names.insert(name.name, self.fns.len());
        self.fns.push(FnDef { name, args: args.to_vec(), body, lo, ok, used: false });
    }

    /// The smallest expression id under `root` (a statement's expressions are one contiguous id range).
    fn lowest_id(&self, root: ExprId) -> usize {
        let mut lo = root.index();
        let mut stack = vec![root];
        while let Some(id) = stack.pop() {
            lo = lo.min(id.index());
            self.ast.expr(id).for_each_child(|c| stack.push(c));
        }
        lo
    }

    /// Lowers a top-level expression (a `let` value or the formula).
    fn top_expr(&mut self, root: ExprId) -> Slot {
        let mut memo = std::mem::take(&mut self.memo);
        let ctx = Ctx { visible_fns: self.fns.len(), defining: None, args: &[], depth: 0, call: None };
        let v = self.tree(root, &mut memo, 0, &ctx);
        self.memo = memo;
        v
    }

    /// Lowers one expression with an explicit stack (children first); `memo[id - base]` holds each result.
    fn tree(&mut self, root: ExprId, memo: &mut [Slot], base: usize, ctx: &Ctx<'_, 's>) -> Slot {
        let ast = self.ast;
        let mut stack = vec![(root, false)];
        let mut args: Vec<Val> = Vec::new();
        while let Some((id, children_done)) = stack.pop() {
            if memo[id.index() - base] != Slot::Todo {
                continue;
            }
            let e = ast.expr(id);
            if !children_done {
                stack.push((id, true));
                e.for_each_child(|c| stack.push((c, false)));
                continue;
            }
            args.clear();
            let mut poisoned = false;
            e.for_each_child(|c| match memo[c.index() - base] {
                Slot::Done(v) => args.push(v),
                _ => poisoned = true,
            });
            let span = e.span;
            let out = match &e.kind {
                ExprKind::Error => Slot::Poison,
                ExprKind::Name(n) => self.name(*n, ctx),
                ExprKind::Call(n, a) => self.call(*n, &args, a.len(), poisoned, span, ctx),
                _ if poisoned => Slot::Poison,
                ExprKind::Num(v) => Slot::Done(Val::F(self.ir.konst(*v, span))),
                ExprKind::Bool(b) => Slot::Done(Values::new(&mut self.ir, span).boolean(*b)),
                ExprKind::Paren(_) => Slot::Done(args[0]),
                ExprKind::Neg(_) => {
                    let r = Values::new(&mut self.ir, span).neg(args[0]);
                    self.typed(r, span, "arith", &args, ctx)
                }
                ExprKind::Not(_) => {
                    let r = Values::new(&mut self.ir, span).not(args[0]);
                    self.typed(r, span, "cond", &args, ctx)
                }
                ExprKind::Select(..) => {
                    let (c, a, b) = (args[0], args[1], args[2]);
                    let r = Values::new(&mut self.ir, span).select(c, a, b);
                    let what = if matches!(c, Val::B(_)) { "branches" } else { "cond" };
                    self.typed(r, span, what, &args, ctx)
                }
                ExprKind::Field(_, n) => match component(n.name) {
                    Some(k) => {
                        let r = Values::new(&mut self.ir, span).component(args[0], k);
                        self.typed(r, span, "field", &args, ctx)
                    }
                    None => {
                        self.type_error(
                            format!("`.{}` is not a component", n.name),
                            n.span,
                            "a vec3 has the components `.x .y .z` (or `.r .g .b`)".into(),
                            ctx,
                        );
                        Slot::Poison
                    }
                },
                ExprKind::Binary(op, _, _) => {
                    let (a, b) = (args[0], args[1]);
                    let mut vs = Values::new(&mut self.ir, span);
                    let (r, what) = match op {
                        AstOp::Arith(op) => (vs.arith(*op, a, b), "arith"),
                        AstOp::Pow => (vs.builtin(Builtin::Pow, &[a, b]), "arith"),
                        AstOp::Cmp(c) => (vs.compare(*c, a, b), "cmp"),
                        AstOp::And => (vs.and(a, b), "cond"),
                        AstOp::Or => (vs.or(a, b), "cond"),
                    };
                    let r = r.map_err(|m| if *op == AstOp::Pow { m.replace("`pow`", "`^`") } else { m });
                    self.typed(r, span, what, &args, ctx)
                }
            };
            memo[id.index() - base] = out;
        }
        memo[root.index() - base]
    }

    /// A [`Values`] result as a slot, reporting its error as a type error at `span`.
    fn typed(&mut self, r: Result<Val, String>, span: Span, what: &str, args: &[Val], ctx: &Ctx) -> Slot {
        match r {
            Ok(v) => Slot::Done(v),
            Err(m) => {
                self.type_error(m, span, type_hint(what, args), ctx);
                Slot::Poison
            }
        }
    }

    /// A name used as a value.
    fn name(&mut self, n: Ident<'s>, ctx: &Ctx) -> Slot {
        let span = n.span;
        if let Some(&(_, v)) = ctx.args.iter().find(|a| a.0 == n.name) {
            return v;
        }
        if ctx.defining.is_none() && ctx.call.is_none() {
            if let Some(&i) = self.scope.get(n.name) {
                self.lets[i].used = true;
                return self.lets[i].value;
            }
        } else if self.scope.contains_key(n.name) {
            self.error(
                Diagnostic::error(format!("a function cannot read the `let {}`", n.name))
                    .at(span, "a `let` outside the function")
                    .hint(format!(
                        "a function body sees its arguments, the parameters and the inputs; pass `{}` as an argument",
                        n.name
                    )),
            );
            return Slot::Poison;
        }
        let mut vs = Values::new(&mut self.ir, span);
        if let Some(&p) = self.param_names.get(n.name) {
            return Slot::Done(match p {
                ParamRef::Float(i) => Val::F(vs.ir.param(i, span)),
                ParamRef::Bool(i) => Val::B(vs.ir.param(i, span)),
                ParamRef::Color(i) => Val::V([i, i + 1, i + 2].map(|k| vs.ir.param(k, span))),
            });
        }
        if let Some(v) = vs.frame(n.name) {
            return Slot::Done(v);
        }
        if let Some(input) = Input::from_name(n.name) {
            let x = vs.ir.input(input, span);
            if self.raw || input.is_direction() {
                return Slot::Done(Val::F(x));
            }
            let zero = vs.ir.konst(0.0, span);
            let one = vs.ir.konst(1.0, span);
            return Slot::Done(Val::F(vs.ir.call(Builtin::Clamp, &[x, zero, one], span)));
        }
        if let Some(v) = vs.shorthand(n.name) {
            return Slot::Done(v);
        }
        if n.name == "pi" {
            return Slot::Done(Val::F(vs.konst(std::f64::consts::PI)));
        }
        if let Some(b) = self.builtin(n.name) {
            self.error(
                Diagnostic::error(format!("`{}` is a function, not a variable", n.name))
                    .at(span, "used without arguments")
                    .hint(format!("call it: `{}` — {}", signature(b), b.info().doc)),
            );
            return Slot::Poison;
        }
        if let Some((_, doc)) = derived(n.name) {
            self.error(
                Diagnostic::error(format!("`{}` is a function, not a variable", n.name))
                    .at(span, "used without arguments")
                    .hint(format!("call it: {doc}")),
            );
            return Slot::Poison;
        }
        if self.all_fns.contains_key(n.name) {
            self.error(
                Diagnostic::error(format!("`{}` is a function, not a variable", n.name))
                    .at(span, "used without arguments")
                    .hint(format!("call it with its arguments: `{}(…)`", n.name)),
            );
            return Slot::Poison;
        }
        if let Some(b) = Builtin::from_name(n.name).filter(|_| !self.all_lets.contains_key(n.name)) {
            // An internal builtin (the language's were taken above).
            self.error(super::internal_builtin(b, span));
            return Slot::Poison;
        }
        let d = self.unknown_variable(n, ctx);
        self.error(d);
        Slot::Poison
    }

    fn unknown_variable(&self, n: Ident<'s>, ctx: &Ctx) -> Diagnostic {
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
        cands.extend(ctx.args.iter().map(|a| a.0));
        if ctx.args.is_empty() {
            cands.extend(self.lets.iter().rev().map(|l| l.name.name));
        }
        cands.extend(SHORTHANDS);
        cands.extend(Input::DIRECTIONS.iter().map(|i| i.name()));
        cands.extend(self.params.iter().filter_map(|p| match p.kind {
            ParamKind::Color(0) => p.name.strip_suffix(".r"),
            ParamKind::Color(_) => None,
            _ => Some(p.name.as_str()),
        }));
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
            _ => "the names available are the inputs NL, NV, NH, VR, VH, the vectors L, V, N, X, Y, the constant pi, \
                  `n`, and names bound with `let` or declared with `param`"
                .to_string(),
        };
        d.hint(hint)
    }

    /// A call: a user function (inlined), a builtin (per component on vectors) or a derived function. The
    /// function and its arity are checked even when an argument failed, so those mistakes are reported too.
    fn call(&mut self, n: Ident<'s>, args: &[Val], nargs: usize, poisoned: bool, span: Span, ctx: &Ctx<'_, 's>) -> Slot {
        if let Some(&f) = self.fn_names.get(n.name).filter(|&&f| f < ctx.visible_fns) {
            let want = self.fns[f].args.len();
            self.fns[f].used = true;
            if want != nargs {
                let def = self.fns[f].name.span;
                self.error(
                    Diagnostic::error(format!("{} takes {}, found {nargs}", n.name, plural(want, "argument")))
                        .at(span, format!("called with {}", plural(nargs, "argument")))
                        .also(def, "defined here")
                        .hint(format!("`{}`", self.fn_signature(f))),
                );
                return Slot::Poison;
            }
            if poisoned {
                return Slot::Poison;
            }
            return self.inline(f, args, span, ctx);
        }
        if ctx.defining == Some(n.name) {
            self.error(
                Diagnostic::error(format!("`{}` calls itself", n.name))
                    .at(span, "a recursive call")
                    .hint("functions are inlined, so they cannot recurse; write the repetition out, or use a loop-free formula"),
            );
            return Slot::Poison;
        }
        if let Some(&def) = self.all_fns.get(n.name) {
            self.error(
                Diagnostic::error(format!("`{}` is called before its definition", n.name))
                    .at(span, "called here")
                    .also(def, "defined later, here")
                    .hint(format!("move `fn {} … = …` above this line (a function may call only those defined above it)", n.name)),
            );
            return Slot::Poison;
        }
        if let Some(b) = self.builtin(n.name) {
            if b.arity() != nargs {
                self.error(
                    Diagnostic::error(format!("{} takes {}, found {nargs}", n.name, plural(b.arity(), "argument")))
                        .at(span, format!("called with {}", plural(nargs, "argument")))
                        .hint(format!("`{}`: {}", signature(b), b.info().doc)),
                );
                return Slot::Poison;
            }
            if poisoned {
                return Slot::Poison;
            }
            let r = Values::new(&mut self.ir, span).builtin(b, args);
            return self.typed(r, span, "arith", args, ctx);
        }
        if let Some((arity, doc)) = derived(n.name) {
            let ok = if arity == 3 && derived(n.name) == derived("vec3") { nargs == 1 || nargs == 3 } else { nargs == arity };
            if !ok {
                self.error(
                    Diagnostic::error(format!("{} takes {}, found {nargs}", n.name, plural(arity, "argument")))
                        .at(span, format!("called with {}", plural(nargs, "argument")))
                        .hint(doc),
                );
                return Slot::Poison;
            }
            if poisoned {
                return Slot::Poison;
            }
            let name = if n.name == "rgb" { "vec3" } else { n.name };
            let r = Values::new(&mut self.ir, span).function(name, args);
            let r = r.unwrap_or_else(|| Err(format!("internal: `{name}` is not a function")));
            return match r {
                Ok(v) => Slot::Done(v),
                Err(m) => {
                    self.type_error(m, span, doc.to_string(), ctx);
                    Slot::Poison
                }
            };
        }
        let is_var = ctx.args.iter().any(|a| a.0 == n.name)
            || self.scope.contains_key(n.name)
            || self.param_names.contains_key(n.name)
            || Input::from_name(n.name).is_some()
            || FRAME.contains(&n.name)
            || SHORTHANDS.contains(&n.name)
            || n.name == "pi";
        if is_var {
            self.error(
                Diagnostic::error(format!("`{}` is a variable, not a function", n.name))
                    .at(span, "called like a function")
                    .hint(format!("to multiply, write the `*`: `{} * (…)`", n.name)),
            );
            return Slot::Poison;
        }
        if let Some(b) = Builtin::from_name(n.name) {
            // An internal builtin (the language's were taken above): refused, with what to write instead.
            self.error(super::internal_builtin(b, n.span));
            return Slot::Poison;
        }
        let alias = FUNCTION_ALIASES.iter().find(|(a, _)| a.eq_ignore_ascii_case(n.name)).map(|(_, b)| *b);
        let mut names: Vec<&str> = Builtin::language().map(|r| r.name).collect();
        names.extend(DERIVED.iter().map(|d| d.0));
        names.push("rgb");
        names.extend(self.fns[..ctx.visible_fns].iter().map(|f| f.name.name));
        let sugg = alias.or_else(|| super::suggest(n.name, names.iter().copied()));
        let msg = match sugg {
            Some(s) => format!("unknown function `{}`; did you mean `{s}`?", n.name),
            None => format!("unknown function `{}`", n.name),
        };
        let hint = match sugg {
            Some(s) => match (Builtin::from_name(s), derived(s), self.fn_names.get(s)) {
                (Some(b), _, _) => format!("`{}`: {}", signature(b), b.info().doc),
                (_, Some((_, doc)), _) => doc.to_string(),
                (_, _, Some(&f)) => format!("`{}`", self.fn_signature(f)),
                _ => String::new(),
            },
            None => format!(
                "the functions are {}, and those defined with `fn name(x) = …` above this line",
                names[..names.len() - self.fns[..ctx.visible_fns].len()].join(", ")
            ),
        };
        let label = if self.fns.is_empty() { "not a builtin function" } else { "not a known function" };
        self.error(Diagnostic::error(msg).at(n.span, label).hint(hint));
        Slot::Poison
    }

    fn fn_signature(&self, f: usize) -> String {
        let d = &self.fns[f];
        let args: Vec<&str> = d.args.iter().map(|a| a.name).collect();
        format!("fn {}({})", d.name.name, args.join(", "))
    }

    /// Expands the body of function `f` with its arguments bound to `args`.
    fn inline(&mut self, f: usize, args: &[Val], span: Span, ctx: &Ctx<'_, 's>) -> Slot {
        if !self.fns[f].ok {
            return Slot::Poison;
        }
        let key = (f, args.to_vec());
        if let Some(&v) = self.inlined.get(&key) {
            return v;
        }
        let call = ctx.call.unwrap_or(span);
        if ctx.depth >= MAX_INLINE_DEPTH {
            if self.reported.insert(("depth".into(), call.start)) {
                self.error(
                    Diagnostic::error(format!("function calls nested more than {MAX_INLINE_DEPTH} deep"))
                        .at(call, "this call expands too deeply")
                        .hint("call fewer functions from inside functions"),
                );
            }
            return Slot::Poison;
        }
        let (body, lo) = (self.fns[f].body, self.fns[f].lo);
        self.inlined_nodes += body.index() + 1 - lo;
        if self.inlined_nodes > MAX_INLINED {
            if self.reported.insert(("size".into(), 0)) {
                self.error(
                    Diagnostic::error("the functions expand to too large a formula")
                        .at(call, "expanding this call passes the limit")
                        .hint(format!(
                            "inlining stops after {MAX_INLINED} nodes; a function that calls another several times \
                             multiplies its size — bind repeated calls with `let`"
                        )),
                );
            }
            return Slot::Poison;
        }
        let bound: Vec<(&'s str, Slot)> =
            self.fns[f].args.iter().zip(args).map(|(a, v)| (a.name, Slot::Done(*v))).collect();
        let inner = Ctx { visible_fns: f, defining: None, args: &bound, depth: ctx.depth + 1, call: Some(call) };
        let mut memo = vec![Slot::Todo; body.index() + 1 - lo];
        let v = self.tree(body, &mut memo, lo, &inner);
        self.inlined.insert(key, v);
        v
    }

    /// Unused `let`s, `fn`s and `param`s (a colour counts as used when any channel is), and a formula that
    /// reads no input.
    fn warnings(&mut self, roots: &[NodeId], span: Span) {
        let unused = self.fns.iter().filter(|f| !f.used).map(|f| ("fn", f.name, "never called"));
        let unused = unused.chain(self.lets.iter().filter(|l| !l.used).map(|l| ("let", l.name, "never used")));
        for (kw, name, label) in unused.filter(|u| !u.1.name.starts_with('_')) {
            self.diags.push(
                Diagnostic::warning(format!("unused `{kw} {}`", name.name))
                    .at(name.span, label)
                    .hint(format!("remove it, or name it `_{}` to keep it quietly", name.name)),
            );
        }
        let mut used: Vec<u16> = roots.iter().flat_map(|r| self.ir.used_params(*r)).collect();
        let inputs: crate::ir::InputSet = roots.iter().map(|r| self.ir.used_inputs(*r)).collect();
        // A colour parameter is used when any of its channels is.
        for (i, p) in self.params.iter().enumerate() {
            if let ParamKind::Color(k) = p.kind {
                let first = i - k as usize;
                if (first..first + 3).any(|j| used.contains(&(j as u16))) {
                    used.push(i as u16);
                }
            }
        }
        for (i, p) in self.params.iter().enumerate() {
            if matches!(p.kind, ParamKind::Color(1 | 2)) {
                continue;
            }
            if let (Some(s), false) = (p.span, used.contains(&(i as u16))) {
                let name = p.name.strip_suffix(".r").filter(|_| p.kind != ParamKind::Float).unwrap_or(&p.name);
                self.diags.push(
                    Diagnostic::warning(format!("parameter `{name}` is never used"))
                        .at(s, "declared here")
                        .hint(format!("remove the declaration, or use `{name}` in the formula")),
                );
            }
        }
        if inputs.is_empty() {
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
