//! Symbolic execution of a BRDF Explorer shader into lobe's scalar IR.
//!
//! `BRDF(L, V, N, X, Y)` runs once over symbolic values ([`Val`]): L and V are the direction inputs, N, X, Y the
//! constants of the local frame, parameters are `Param` nodes. Straight-line code builds nodes through
//! [`Values`]; helper functions are inlined at each call (arguments by value, as GLSL passes them).
//!
//! Control flow becomes selects. An `if` runs both branches from the same variables and merges every variable
//! either changed with `select(cond, then, else)`. A `return` sets the frame's "returned" flag and result; a
//! later `return` on a path not yet returned selects `select(returned, earlier, this)`, and a branch that has
//! returned on every path hands the other branch's variables on unmerged. So Disney's
//! `if (NdotL < 0) return vec3(0);` yields `select(NdotL < 0, 0, rest)`: the rest's NaN below the horizon never
//! reaches the result. A condition that folds to a constant runs one branch only.
//!
//! Scoping follows GLSL: a declaration is visible after its initializer (`float G = G(x);` calls the function
//! `G`), inner blocks shadow outer ones, function names and variable names live apart, and a user function
//! shadows a GLSL builtin of the same name (the corpus redefines `reflect` and `smoothstep`). Parameters and
//! globals are read-only inside functions. Cost: linear in the inlined program, capped at [`MAX_WORK`].

use super::glsl::{Declarator, Expr, ExprKind, Func, Item, Op, Stmt, Target, Type, Unary};
use super::Declared;
use crate::base::diag::Diagnostic;
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::front::values::{Ty, Val, Values};
use crate::ir::{BinOp, Formula, Ir, Meta, NodeId, ParamDecl};

/// Most expression evaluations (counting every inlined copy) one file may take.
pub(crate) const MAX_WORK: u64 = 2_000_000;
/// Deepest chain of helper calls (GLSL has no recursion; this bounds the Rust stack).
const MAX_CALLS: usize = 64;
/// Deepest recursion of the lowering (nested expressions and blocks, summed over inlined calls): the parser
/// caps each function's nesting, this caps their sum, so the Rust stack stays within about a megabyte.
const MAX_NEST: u32 = 1500;

type R<T> = Result<T, Diagnostic>;

/// The GLSL functions lobe evaluates, besides user functions: (GLSL name, what it lowers to).
const GLSL_FUNCTIONS: [&str; 34] = [
    "pow", "cos", "sin", "tan", "acos", "asin", "atan", "exp", "log", "sqrt", "abs", "min", "max", "clamp",
    "floor", "dot", "cross", "length", "normalize", "reflect", "distance", "mix", "smoothstep", "step", "sign",
    "fract", "radians", "degrees", "inversesqrt", "ceil", "mod", "exp2", "log2", "fma",
];

fn ty_of(v: Val) -> Type {
    match v.ty() {
        Ty::Float => Type::Float,
        Ty::Bool => Type::Bool,
        Ty::Vec3 => Type::Vec3,
    }
}

#[derive(Clone, Debug)]
struct Var {
    name: String,
    ty: Type,
    /// `None` until assigned.
    val: Option<Val>,
    konst: bool,
}

/// One inlined function's state.
struct Frame {
    scopes: Vec<Vec<Var>>,
    /// (returned flag as a bool node, result) once some path has returned.
    ret: Option<(NodeId, Val)>,
    ret_ty: Type,
    /// User functions visible to this body: those defined before it.
    visible: usize,
}

struct Exec<'a> {
    vb: Values<'a>,
    funcs: Vec<&'a Func>,
    /// Globals and parameters (read-only), searched after the frame's scopes, latest first.
    globals: Vec<Var>,
    work: u64,
    calls: usize,
    nest: u32,
}

fn err(span: Span, msg: impl Into<String>, hint: &str) -> Diagnostic {
    Diagnostic::error(msg).at(span, "here").hint(hint)
}

/// Lowers `BRDF` of the parsed shader into a formula with `params` (n first).
pub(crate) fn lower(file: &str, src: &str, params: Vec<ParamDecl>, declared: &[Declared], items: &[Item], shader: Span) -> R<Formula> {
    let mut ir = Ir::new();
    let mut ex = Exec { vb: Values::new(&mut ir, shader), funcs: vec![], globals: vec![], work: 0, calls: 0, nest: 0 };
    for d in declared {
        ex.vb.span = d.span;
        let p = |ex: &mut Exec, k: u16| ex.vb.ir.param(d.index + k, d.span);
        let val = match d.kind {
            Type::Bool => Val::B(p(&mut ex, 0)),
            Type::Vec3 => Val::V([p(&mut ex, 0), p(&mut ex, 1), p(&mut ex, 2)]),
            _ => Val::F(p(&mut ex, 0)),
        };
        ex.globals.push(Var { name: d.name.clone(), ty: d.kind, val: Some(val), konst: true });
    }
    for item in items {
        match item {
            Item::Func(f) => {
                if let Some(g) = ex.funcs.iter().find(|g| g.name == f.name && same_params(g, f)) {
                    return Err(Diagnostic::error(format!("function `{}` is defined twice", f.name))
                        .at(f.name_span, "again here")
                        .also(g.name_span, "first here")
                        .hint("rename one of them"));
                }
                if f.ret == Type::Void {
                    return Err(err(f.name_span, format!("`{}` returns void", f.name), "a void function has no effect here (globals and `out` parameters are not supported); return a value"));
                }
                ex.funcs.push(f);
            }
            Item::Global { ty, konst, vars } => {
                let mut fr = Frame { scopes: vec![vec![]], ret: None, ret_ty: Type::Void, visible: ex.funcs.len() };
                ex.declare(&mut fr, *ty, *konst, vars)?;
                let new = fr.scopes.pop().unwrap_or_default();
                ex.globals.extend(new);
            }
        }
    }
    let Some(brdf) = ex.funcs.iter().rposition(|f| f.name == "BRDF") else {
        return Err(Diagnostic::error("the shader defines no `BRDF` function")
            .at(Span::new(shader.start as usize, shader.start as usize), "in this shader")
            .hint("define `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { … }`"));
    };
    let f = ex.funcs[brdf];
    if f.ret != Type::Vec3 || f.params.len() != 5 || f.params.iter().any(|p| p.0 != Type::Vec3) {
        return Err(err(f.name_span, "`BRDF` must be `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y)`", "BRDF Explorer calls BRDF with the light, view, normal, tangent and bitangent, and reads a vec3"));
    }
    ex.vb.span = f.name_span;
    let args: Vec<Val> = ["L", "V", "N", "X", "Y"].iter().map(|n| ex.vb.frame(n).unwrap_or(Val::F(NodeId(0)))).collect();
    let out = ex.call_user(brdf, args, f.name_span)?;
    let Val::V(rgb) = out else {
        return Err(err(f.name_span, "`BRDF` must return a vec3", "return vec3(value)"));
    };
    let (file, source) = (file.to_string(), src.to_string());
    if rgb[0] == rgb[1] && rgb[1] == rgb[2] {
        let (ir, root) = ir.compact(rgb[0]);
        Ok(Formula { meta: Meta::default(), params, ir, root, file, source, rgb: None })
    } else {
        Ok(Formula::from_channels(Meta::default(), params, &ir, rgb, file, source))
    }
}

fn same_params(a: &Func, b: &Func) -> bool {
    a.params.len() == b.params.len() && a.params.iter().zip(&b.params).all(|(x, y)| x.0 == y.0)
}

impl Frame {
    /// Whether every path has returned (the rest of the body is dead).
    fn dead(&self, ir: &Ir) -> bool {
        self.ret.is_some_and(|(f, _)| ir.node(f).as_const() == Some(1.0))
    }
}

impl<'a> Exec<'a> {
    fn tick(&mut self, span: Span) -> R<()> {
        self.work += 1;
        if self.work > MAX_WORK {
            return Err(err(span, format!("the shader expands to more than {MAX_WORK} operations once its helper functions are inlined"), "lobe inlines every call; call expensive helpers once and keep the result in a variable"));
        }
        Ok(())
    }

    fn find_var<'f>(&'f self, fr: &'f Frame, name: &str) -> Option<&'f Var> {
        fr.scopes.iter().rev().flat_map(|s| s.iter().rev()).chain(self.globals.iter().rev()).find(|v| v.name == name)
    }

    fn declare(&mut self, fr: &mut Frame, ty: Type, konst: bool, vars: &[Declarator]) -> R<()> {
        for d in vars {
            let val = match &d.init {
                Some(e) => {
                    let v = self.expr(fr, e)?;
                    check_ty(ty, v, e.span, "the initial value")?;
                    Some(v)
                }
                None if konst => return Err(err(d.span, format!("const `{}` needs a value", d.name), "write `const float NAME = value;`")),
                None => None,
            };
            let scope = fr.scopes.last_mut().expect("a frame always has a scope");
            if scope.iter().any(|v| v.name == d.name) {
                return Err(err(d.span, format!("`{}` is declared twice in this block", d.name), "rename it, or assign without the type"));
            }
            scope.push(Var { name: d.name.clone(), ty, val, konst });
        }
        Ok(())
    }

    /// Runs `f` one level deeper, refusing past [`MAX_NEST`].
    fn nested<T>(&mut self, span: Span, f: impl FnOnce(&mut Self) -> R<T>) -> R<T> {
        if self.nest >= MAX_NEST {
            return Err(err(span, format!("helper calls and nesting together go deeper than {MAX_NEST} levels"), "flatten the helpers or split expressions with local variables"));
        }
        self.nest += 1;
        let r = f(self);
        self.nest -= 1;
        r
    }

    fn block(&mut self, fr: &mut Frame, body: &[Stmt]) -> R<()> {
        let span = self.vb.span;
        self.nested(span, |s| s.block_inner(fr, body))
    }

    fn block_inner(&mut self, fr: &mut Frame, body: &[Stmt]) -> R<()> {
        fr.scopes.push(vec![]);
        for s in body {
            if fr.dead(self.vb.ir) {
                break;
            }
            self.stmt(fr, s)?;
        }
        fr.scopes.pop();
        Ok(())
    }

    fn stmt(&mut self, fr: &mut Frame, s: &Stmt) -> R<()> {
        match s {
            Stmt::Decl { ty, konst, vars } => self.declare(fr, *ty, *konst, vars),
            Stmt::Block(b) => self.block(fr, b),
            Stmt::Expr(e) => self.expr(fr, e).map(|_| ()),
            Stmt::Assign { target, op, value, span } => self.assign(fr, target, *op, value, *span),
            Stmt::Return { value, span } => {
                let v = match value {
                    Some(e) => self.expr(fr, e)?,
                    None => return Err(err(*span, "`return` without a value", "return a value of the function's type")),
                };
                check_ty(fr.ret_ty, v, value.as_ref().map_or(*span, |e| e.span), "the returned value")?;
                self.vb.span = *span;
                let one = self.vb.konst(1.0);
                let v = match fr.ret {
                    None => v,
                    Some((flag, old)) => self.select(Val::B(flag), old, v, *span)?,
                };
                fr.ret = Some((one, v));
                Ok(())
            }
            Stmt::If { cond, then, els } => {
                let c = self.expr(fr, cond)?;
                let Val::B(cn) = c else {
                    return Err(err(cond.span, format!("an `if` condition must be a bool, not {}", c.ty().name()), "compare it, e.g. `if (x > 0.0)`"));
                };
                if let Some(k) = self.vb.ir.node(cn).as_const() {
                    return match (k != 0.0, els) {
                        (true, _) => self.block(fr, then),
                        (false, Some(e)) => self.block(fr, e),
                        (false, None) => Ok(()),
                    };
                }
                let saved = (fr.scopes.clone(), fr.ret);
                self.block(fr, then)?;
                let a_scopes = std::mem::replace(&mut fr.scopes, saved.0);
                let a_ret = std::mem::replace(&mut fr.ret, saved.1);
                let a_dead = a_ret.is_some_and(|(f, _)| self.vb.ir.node(f).as_const() == Some(1.0));
                if let Some(e) = els {
                    self.block(fr, e)?;
                }
                let b_dead = fr.dead(self.vb.ir);
                self.vb.span = cond.span;
                if b_dead && !a_dead {
                    fr.scopes = a_scopes;
                } else if !a_dead {
                    for (sa, sb) in a_scopes.iter().zip(fr.scopes.iter_mut()) {
                        for (va, vb) in sa.iter().zip(sb.iter_mut()) {
                            vb.val = match (va.val, vb.val) {
                                (Some(x), Some(y)) => Some(self.select(c, x, y, cond.span)?),
                                (x, y) => x.or(y),
                            };
                        }
                    }
                }
                let zero = self.vb.konst(0.0);
                fr.ret = match (a_ret, fr.ret) {
                    (None, None) => None,
                    (Some((fa, va)), None) => Some((self.sel_node(cn, fa, zero), va)),
                    (None, Some((fb, vb))) => Some((self.sel_node(cn, zero, fb), vb)),
                    (Some((fa, va)), Some((fb, vb))) => Some((self.sel_node(cn, fa, fb), self.select(c, va, vb, cond.span)?)),
                };
                Ok(())
            }
        }
    }

    /// `select(c, a, b)` of returned flags; `select(c, 1, 0)` is `c` itself (a flag is 0 or 1).
    fn sel_node(&mut self, c: NodeId, a: NodeId, b: NodeId) -> NodeId {
        let k = |s: &Self, x: NodeId| s.vb.ir.node(x).as_const();
        if k(self, a) == Some(1.0) && k(self, b) == Some(0.0) {
            return c;
        }
        match self.vb.select(Val::B(c), Val::B(a), Val::B(b)) {
            Ok(Val::B(x)) => x,
            _ => unreachable!("a select of two bools is a bool"),
        }
    }

    fn select(&mut self, c: Val, a: Val, b: Val, span: Span) -> R<Val> {
        self.vb.select(c, a, b).map_err(|m| err(span, m, "GLSL needs both sides of `?:` to have one type"))
    }

    fn assign(&mut self, fr: &mut Frame, t: &Target, op: Option<Op>, value: &Expr, span: Span) -> R<()> {
        let k = match &t.component {
            Some(k) => Some(self.const_index(fr, k)?),
            None => None,
        };
        let rhs = self.expr(fr, value)?;
        let Some(var) = fr.scopes.iter().rev().flat_map(|s| s.iter().rev()).find(|v| v.name == t.name).cloned() else {
            let hint = if self.globals.iter().any(|g| g.name == t.name) {
                "parameters and globals are read-only here; copy into a local: `float x = name;`"
            } else {
                "declare it first: `float name = …;`"
            };
            return Err(err(t.span, format!("cannot assign to `{}`", t.name), hint));
        };
        if var.konst {
            return Err(err(t.span, format!("`{}` is const", t.name), "declare it without `const` to change it"));
        }
        self.vb.span = span;
        let old = match (var.val, op, k) {
            (Some(v), _, _) => Some(v),
            (None, None, None) => None,
            _ => return Err(self.unassigned(&t.name, t.span)),
        };
        let part = |v: Val, k: Option<usize>| -> Val {
            match (v, k) {
                (Val::V(c), Some(k)) => Val::F(c[k]),
                _ => v,
            }
        };
        if k.is_some() && var.ty != Type::Vec3 {
            return Err(err(t.span, format!("`{}` is a {}, not a vec3", t.name, var.ty.name()), "only a vec3 has components"));
        }
        let mut new = match op {
            None => rhs,
            Some(op) => {
                let cur = part(old.ok_or_else(|| self.unassigned(&t.name, t.span))?, k);
                self.binary(op, cur, rhs, span)?
            }
        };
        if let (Some(k), Some(Val::V(mut c))) = (k, old) {
            let Val::F(x) = new else {
                return Err(err(value.span, format!("a component is a float, not {}", new.ty().name()), "assign a float"));
            };
            c[k] = x;
            new = Val::V(c);
        }
        check_ty(var.ty, new, value.span, "the assigned value")?;
        if let Some(slot) = fr.scopes.iter_mut().rev().flat_map(|s| s.iter_mut().rev()).find(|v| v.name == t.name) {
            slot.val = Some(new);
        }
        Ok(())
    }

    fn unassigned(&self, name: &str, span: Span) -> Diagnostic {
        err(span, format!("`{name}` is read before it is given a value"), "give it a value where it is declared")
    }

    fn const_index(&mut self, fr: &mut Frame, k: &Expr) -> R<usize> {
        let v = self.expr(fr, k)?;
        match v {
            Val::F(n) => match self.vb.ir.node(n).as_const() {
                Some(c) if c == 0.0 || c == 1.0 || c == 2.0 => Ok(c as usize),
                Some(c) => Err(err(k.span, format!("index {c} is out of range"), "a vec3 has components 0, 1 and 2")),
                None => Err(err(k.span, "an index must be a constant", "write v[0], v[1] or v[2]")),
            },
            _ => Err(err(k.span, "an index must be a number", "write v[0], v[1] or v[2]")),
        }
    }

    fn binary(&mut self, op: Op, a: Val, b: Val, span: Span) -> R<Val> {
        self.vb.span = span;
        let res = match op {
            Op::Arith(o) => self.vb.arith(o, a, b),
            Op::Cmp(c) => self.vb.compare(c, a, b),
            Op::And => self.vb.and(a, b),
            Op::Or => self.vb.or(a, b),
        };
        res.map_err(|m| err(span, m, "GLSL types: float, bool, vec3; convert explicitly"))
    }

    fn expr(&mut self, fr: &mut Frame, e: &Expr) -> R<Val> {
        self.nested(e.span, |s| s.expr_inner(fr, e))
    }

    fn expr_inner(&mut self, fr: &mut Frame, e: &Expr) -> R<Val> {
        self.tick(e.span)?;
        match &e.kind {
            ExprKind::Num(v, _) => {
                self.vb.span = e.span;
                Ok(self.vb.num(*v))
            }
            ExprKind::Bool(b) => {
                self.vb.span = e.span;
                Ok(self.vb.boolean(*b))
            }
            ExprKind::Name(n) => match self.find_var(fr, n) {
                Some(v) => v.val.ok_or_else(|| self.unassigned(n, e.span)),
                None => {
                    let known: Vec<&str> = fr.scopes.iter().flatten().chain(&self.globals).map(|v| v.name.as_str()).collect();
                    let hint = crate::front::did_you_mean(n, &known, "the names here are: ");
                    let msg = if self.funcs[..fr.visible].iter().any(|f| f.name == *n) {
                        format!("`{n}` is a function; call it with arguments")
                    } else {
                        format!("unknown name `{n}`")
                    };
                    Err(err(e.span, msg, &hint))
                }
            },
            ExprKind::Unary(op, a) => {
                let x = self.expr(fr, a)?;
                self.vb.span = e.span;
                let r = match op {
                    Unary::Neg => self.vb.neg(x),
                    Unary::Plus => self.vb.neg(x).map(|_| x),
                    Unary::Not => self.vb.not(x),
                };
                r.map_err(|m| err(e.span, m, "check the operand's type"))
            }
            ExprKind::Binary(..) if int_const(e, 0).is_some() => {
                self.vb.span = e.span;
                Ok(self.vb.num(int_const(e, 0).unwrap_or(0) as f64))
            }
            ExprKind::Binary(op, a, b) => {
                let x = self.expr(fr, a)?;
                let y = self.expr(fr, b)?;
                self.binary(*op, x, y, e.span)
            }
            ExprKind::Cond(c, a, b) => {
                let cv = self.expr(fr, c)?;
                if !matches!(cv, Val::B(_)) {
                    return Err(err(c.span, format!("the condition of `?:` must be a bool, not {}", cv.ty().name()), "compare it, e.g. `x > 0.0 ? a : b`"));
                }
                let x = self.expr(fr, a)?;
                let y = self.expr(fr, b)?;
                self.vb.span = e.span;
                self.select(cv, x, y, e.span)
            }
            ExprKind::Index(a, k) => {
                let v = self.expr(fr, a)?;
                let k = self.const_index(fr, k)?;
                self.component(v, k, e.span)
            }
            ExprKind::Field(a, letters, lsp) => {
                let v = self.expr(fr, a)?;
                let ks = letters.chars().map(|c| super::glsl::component_of(&c.to_string(), *lsp)).collect::<R<Vec<usize>>>()?;
                match ks.as_slice() {
                    [k] => self.component(v, *k, e.span),
                    [a, b, c] => {
                        let x = self.component(v, *a, e.span)?;
                        let y = self.component(v, *b, e.span)?;
                        let z = self.component(v, *c, e.span)?;
                        match (x, y, z) {
                            (Val::F(x), Val::F(y), Val::F(z)) => Ok(Val::V([x, y, z])),
                            _ => unreachable!("components are floats"),
                        }
                    }
                    _ => Err(err(*lsp, format!("`.{letters}` would make a vec{}", ks.len()), "lobe's shaders use float and vec3; take one component or three")),
                }
            }
            ExprKind::Call(name, nsp, args) => {
                let mut vals = Vec::with_capacity(args.len());
                for a in args {
                    vals.push(self.expr(fr, a)?);
                }
                self.call(fr, name, *nsp, vals, e.span)
            }
        }
    }

    fn component(&mut self, v: Val, k: usize, span: Span) -> R<Val> {
        self.vb.component(v, k).map_err(|m| err(span, m, "only a vec3 has components"))
    }

    fn call(&mut self, fr: &Frame, name: &str, nsp: Span, args: Vec<Val>, span: Span) -> R<Val> {
        let types: Vec<Type> = args.iter().map(|a| ty_of(*a)).collect();
        let visible = &self.funcs[..fr.visible];
        if let Some(i) = visible.iter().rposition(|f| f.name == name && f.params.iter().map(|p| p.0).eq(types.iter().copied())) {
            return self.call_user(i, args, span);
        }
        if let Some(f) = visible.iter().rev().find(|f| f.name == name) {
            let want: Vec<&str> = f.params.iter().map(|p| p.0.name()).collect();
            let got: Vec<&str> = types.iter().map(|t| t.name()).collect();
            return Err(err(nsp, format!("`{name}` takes ({}), but is called with ({})", want.join(", "), got.join(", ")), "GLSL does not convert between float, bool and vec3; convert the arguments")
                .also(f.name_span, "defined here"));
        }
        if fr.visible < self.funcs.len() && self.funcs[fr.visible..].iter().any(|f| f.name == name) && !GLSL_FUNCTIONS.contains(&name) {
            return Err(err(nsp, format!("`{name}` is called before it is defined (or calls itself)"), "GLSL needs a function defined before its first use, and has no recursion"));
        }
        self.vb.span = span;
        let bad = |m: String| err(span, m, "check the arguments' number and types");
        let floats = |args: &[Val]| args.iter().all(|a| matches!(a, Val::F(_)));
        match (name, args.as_slice()) {
            ("vec3", _) => return self.vb.function("vec3", &args).unwrap_or_else(|| Err("vec3".into())).map_err(bad),
            ("float", [Val::F(x) | Val::B(x)]) => return Ok(Val::F(*x)),
            ("bool", [Val::B(x)]) => return Ok(Val::B(*x)),
            ("bool", [Val::F(x)]) => {
                let zero = self.vb.konst(0.0);
                return Ok(Val::B(self.vb.call(Builtin::Ne, &[*x, zero])));
            }
            ("atan", [_, _]) => {
                return Err(err(nsp, "`atan(y, x)` with two arguments is not supported", "use atan(y / x) and a `?:` for the quadrant"))
            }
            _ => {}
        }
        if let Some(b) = Builtin::from_name(name).filter(|b| b.is_internal()) {
            return Err(crate::front::internal_builtin(b, nsp));
        }
        if !GLSL_FUNCTIONS.contains(&name) {
            let mut known: Vec<&str> = GLSL_FUNCTIONS.to_vec();
            known.extend(visible.iter().map(|f| f.name.as_str()));
            known.push("vec3");
            let hint = crate::front::did_you_mean(name, &known, "the functions are: ");
            return Err(err(nsp, format!("unknown function `{name}`"), &hint));
        }
        let one = |s: &mut Self, f: Builtin, a: Val| s.vb.builtin(f, &[a]).map_err(bad);
        match (name, args.as_slice()) {
            ("log", [a]) => one(self, Builtin::Ln, *a),
            ("inversesqrt", [a]) => {
                let r = one(self, Builtin::Sqrt, *a)?;
                let u = self.vb.num(1.0);
                self.vb.arith(BinOp::Div, u, r).map_err(bad)
            }
            ("ceil", [a]) => {
                let m = self.vb.neg(*a).map_err(bad)?;
                let f = one(self, Builtin::Floor, m)?;
                self.vb.neg(f).map_err(bad)
            }
            ("mod", [a, b]) if floats(&args) || matches!(a, Val::V(_)) => {
                let q = self.vb.arith(BinOp::Div, *a, *b).map_err(bad)?;
                let f = one(self, Builtin::Floor, q)?;
                let p = self.vb.arith(BinOp::Mul, *b, f).map_err(bad)?;
                self.vb.arith(BinOp::Sub, *a, p).map_err(bad)
            }
            ("exp2", [a]) => {
                let two = self.vb.num(2.0);
                self.vb.builtin(Builtin::Pow, &[two, *a]).map_err(bad)
            }
            ("log2", [a]) => {
                let l = one(self, Builtin::Ln, *a)?;
                let k = self.vb.num(std::f64::consts::LN_2);
                self.vb.arith(BinOp::Div, l, k).map_err(bad)
            }
            ("inversesqrt" | "ceil" | "mod" | "exp2" | "log2" | "log", _) => {
                Err(bad(format!("`{name}` takes {} argument(s), got {}", if name == "mod" { 2 } else { 1 }, args.len())))
            }
            _ => match self.vb.function(name, &args) {
                Some(r) => r.map_err(bad),
                None => Err(err(nsp, format!("unknown function `{name}`"), "internal: listed but not lowered")),
            },
        }
    }

    fn call_user(&mut self, i: usize, args: Vec<Val>, span: Span) -> R<Val> {
        let f = self.funcs[i];
        if self.calls >= MAX_CALLS {
            return Err(err(span, format!("helper calls nest deeper than {MAX_CALLS}"), "flatten the helpers"));
        }
        let params: Vec<Var> = f
            .params
            .iter()
            .zip(args)
            .map(|((ty, name, _), v)| Var { name: name.clone(), ty: *ty, val: Some(v), konst: false })
            .collect();
        let mut fr = Frame { scopes: vec![params], ret: None, ret_ty: f.ret, visible: i };
        self.calls += 1;
        let r = self.block(&mut fr, &f.body);
        self.calls -= 1;
        r?;
        match fr.ret {
            Some((_, v)) if fr.dead(self.vb.ir) => Ok(v),
            Some(_) => Err(err(f.name_span, format!("not every path through `{}` returns a value", f.name), "end the function with a `return`")),
            None => Err(err(f.name_span, format!("`{}` never returns a value", f.name), "end the function with a `return`")),
        }
    }
}

/// The value of an integer constant expression (GLSL's `1/2` is 0: integer literals divide as integers), or
/// `None` when `e` is not one. Bounded by the parser's depth cap.
fn int_const(e: &Expr, depth: u32) -> Option<i64> {
    if depth > super::glsl::MAX_DEPTH {
        return None;
    }
    match &e.kind {
        ExprKind::Num(v, true) if *v < 9.0e15 => Some(*v as i64),
        ExprKind::Unary(Unary::Neg, a) => int_const(a, depth + 1)?.checked_neg(),
        ExprKind::Unary(Unary::Plus, a) => int_const(a, depth + 1),
        ExprKind::Binary(op, a, b) => {
            let (x, y) = (int_const(a, depth + 1)?, int_const(b, depth + 1)?);
            match op {
                Op::Arith(BinOp::Add) => x.checked_add(y),
                Op::Arith(BinOp::Sub) => x.checked_sub(y),
                Op::Arith(BinOp::Mul) => x.checked_mul(y),
                Op::Arith(BinOp::Div) => x.checked_div(y),
                _ => None,
            }
        }
        _ => None,
    }
}

fn check_ty(want: Type, v: Val, span: Span, what: &str) -> R<()> {
    let got = ty_of(v);
    if got == want {
        return Ok(());
    }
    let hint = match (want, got) {
        (Type::Vec3, Type::Float) => "make a vector with vec3(x)",
        (Type::Float, Type::Vec3) => "take a component (v.x) or a dot product",
        _ => "GLSL does not convert between float, bool and vec3 implicitly",
    };
    Err(Diagnostic::error(format!("{what} is a {}, but a {} is expected", got.name(), want.name()))
        .at(span, format!("this is a {}", got.name()))
        .hint(hint))
}
