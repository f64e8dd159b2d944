//! The syntax tree of a .brdf file, as an arena.
//!
//! Design: expressions live in one `Vec` and refer to their operands by [`ExprId`], so building, walking and
//! dropping a tree never recurses: a 1 MiB `1+1+1+…` (a left spine 500 000 deep) drops as one `Vec` and is
//! lowered with an explicit stack. The parser builds bottom-up, so every operand has a smaller id than its
//! user. Every node carries the byte span of its source text. Names borrow from the source.

use super::values::Cmp;
use crate::base::span::Span;

/// Index of an expression in [`Ast::exprs`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct ExprId(pub u32);

impl ExprId {
    pub(crate) fn index(self) -> usize {
        self.0 as usize
    }
}

/// A name as written, with its span.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Ident<'s> {
    pub name: &'s str,
    pub span: Span,
}

/// A binary operator as written (`^` is lowered to the `pow` builtin, comparisons to the exact comparison
/// builtins, `&&`/`||` to selects).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BinOp {
    /// `+ - * /`: the IR's own operators.
    Arith(crate::ir::BinOp),
    Pow,
    Cmp(Cmp),
    And,
    Or,
}


#[derive(Clone, Debug, PartialEq)]
pub(crate) enum ExprKind<'s> {
    Num(f64),
    /// `true` / `false`.
    Bool(bool),
    Name(Ident<'s>),
    Neg(ExprId),
    /// `!a`.
    Not(ExprId),
    /// `c ? a : b` and `if c then a else b`.
    Select(ExprId, ExprId, ExprId),
    /// `v.x`: a component (`x y z` or `r g b`).
    Field(ExprId, Ident<'s>),
    Binary(BinOp, ExprId, ExprId),
    Call(Ident<'s>, Vec<ExprId>),
    /// `( e )`: kept so the span covers the parentheses.
    Paren(ExprId),
    /// Where the parser recovered from a syntax error (already reported); lowers to nothing, silently.
    Error,
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Expr<'s> {
    pub kind: ExprKind<'s>,
    pub span: Span,
}

impl Expr<'_> {
    /// Calls `f` on every operand, in order.
    pub(crate) fn for_each_child(&self, mut f: impl FnMut(ExprId)) {
        match &self.kind {
            ExprKind::Num(_) | ExprKind::Bool(_) | ExprKind::Name(_) | ExprKind::Error => {}
            ExprKind::Neg(a) | ExprKind::Not(a) | ExprKind::Paren(a) | ExprKind::Field(a, _) => f(*a),
            ExprKind::Select(c, a, b) => {
                f(*c);
                f(*a);
                f(*b);
            }
            ExprKind::Binary(_, a, b) => {
                f(*a);
                f(*b);
            }
            ExprKind::Call(_, args) => args.iter().for_each(|a| f(*a)),
        }
    }
}

/// A number in a `param` declaration (an optional `-` and a literal).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Lit {
    pub value: f64,
    pub span: Span,
}

/// The default of a `param`, which also decides its kind.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum ParamDefault<'s> {
    /// `param k = 0.5`: a float.
    Num(Lit),
    /// `param aniso = true`: a bool (0 or 1).
    Bool(bool, Span),
    /// `param base = rgb(0.8, 0.6, 0.2)` (or `vec3(…)`): a colour, three parameters in 0..1. The name is the
    /// constructor as written, checked by the lowering.
    Color(Ident<'s>, [Lit; 3], Span),
}

impl ParamDefault<'_> {
    pub(crate) fn span(&self) -> Span {
        match self {
            ParamDefault::Num(l) => l.span,
            ParamDefault::Bool(_, s) | ParamDefault::Color(_, _, s) => *s,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) enum StmtKind<'s> {
    /// `@key "value"`, or `@key word` (`quoted` false; only `@domain raw` takes a bare word).
    Meta { key: Ident<'s>, value: &'s str, value_span: Span, quoted: bool },
    /// `param name = default [in lo..hi]`.
    Param { name: Ident<'s>, default: ParamDefault<'s>, range: Option<(Lit, Lit)> },
    /// `fn name(a, b) = body`: a function inlined at each call.
    Fn { name: Ident<'s>, args: Vec<Ident<'s>>, body: ExprId },
    /// `let name = value`.
    Let { name: Ident<'s>, value: ExprId },
    /// The formula (there must be exactly one, last).
    Expr(ExprId),
    /// A statement the parser could not read (already reported).
    Error,
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Stmt<'s> {
    pub kind: StmtKind<'s>,
    pub span: Span,
}

/// A parsed file: statements in source order over one expression arena.
#[derive(Clone, Debug, Default)]
pub(crate) struct Ast<'s> {
    pub exprs: Vec<Expr<'s>>,
    pub stmts: Vec<Stmt<'s>>,
}

impl<'s> Ast<'s> {
    pub(crate) fn push(&mut self, kind: ExprKind<'s>, span: Span) -> ExprId {
        let id = ExprId(self.exprs.len() as u32);
        self.exprs.push(Expr { kind, span });
        id
    }
    pub(crate) fn expr(&self, id: ExprId) -> &Expr<'s> {
        &self.exprs[id.index()]
    }
    pub(crate) fn span(&self, id: ExprId) -> Span {
        self.exprs[id.index()].span
    }
}

/// The operator as the language spells it (the parser's tests print trees with it).
#[cfg(test)]
impl BinOp {
    pub(crate) fn symbol(self) -> &'static str {
        match self {
            BinOp::Arith(op) => op.symbol(),
            BinOp::Pow => "^",
            BinOp::Cmp(c) => c.symbol(),
            BinOp::And => "&&",
            BinOp::Or => "||",
        }
    }
}
