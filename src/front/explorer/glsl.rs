//! The GLSL subset of BRDF Explorer shaders: a hand-written lexer and recursive-descent parser into a small
//! AST with byte spans into the whole .brdf file.
//!
//! Recursion is bounded: every nested expression, statement and block counts against [`MAX_DEPTH`], and every
//! expression records its height, so a long left-associative chain (`a+a+…`) is refused at
//! [`MAX_DEPTH`] too (the lowering walks the tree recursively). Constructs outside the subset (loops, structs,
//! arrays, `out` parameters, preprocessor lines, other types) are refused where they appear, with a hint.
//! Cost: one pass over the bytes, one over the tokens; linear in the shader.

use crate::base::diag::Diagnostic;
use crate::base::span::Span;
use crate::front::values::Cmp;
use crate::ir::BinOp;

/// Deepest nesting of expressions, statements and blocks accepted (the corpus needs under 20).
pub(crate) const MAX_DEPTH: u32 = 200;

#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Tok {
    /// A number and whether it is an integer literal (no `.`, no exponent): GLSL divides integers exactly.
    Num(f64, bool),
    Ident(String),
    Punct(&'static str),
    Eof,
}

#[derive(Clone, Debug)]
pub(crate) struct Token {
    pub tok: Tok,
    pub span: Span,
}

/// Longest first, so `<=` wins over `<`.
const PUNCT: [&str; 37] = [
    "+=", "-=", "*=", "/=", "<=", ">=", "==", "!=", "&&", "||", "++", "--", "(", ")", "{", "}", "[", "]", ",",
    ";", "?", ":", ".", "+", "-", "*", "/", "<", ">", "=", "!", "%", "&", "|", "^", "~", "#",
];

/// Tokens of `src[start..end]`, spans absolute in `src`.
pub(crate) fn lex(src: &str, start: usize, end: usize) -> Result<Vec<Token>, Diagnostic> {
    let b = src.as_bytes();
    let mut i = start;
    let mut out = Vec::new();
    while i < end {
        let c = b[i];
        if c.is_ascii_whitespace() {
            i += 1;
        } else if b[i..end].starts_with(b"//") {
            while i < end && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..end].starts_with(b"/*") {
            let close = src[i + 2..end].find("*/").ok_or_else(|| {
                Diagnostic::error("unterminated `/*` comment")
                    .at(Span::new(i, i + 2), "opened here")
                    .hint("close it with `*/`")
            })?;
            i += 2 + close + 2;
        } else if c.is_ascii_alphabetic() || c == b'_' {
            let s = i;
            while i < end && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            out.push(Token { tok: Tok::Ident(src[s..i].to_string()), span: Span::new(s, i) });
        } else if c.is_ascii_digit() || (c == b'.' && i + 1 < end && b[i + 1].is_ascii_digit()) {
            let s = i;
            while i < end && b[i].is_ascii_digit() {
                i += 1;
            }
            if i < end && b[i] == b'.' {
                i += 1;
                while i < end && b[i].is_ascii_digit() {
                    i += 1;
                }
            }
            if i < end && (b[i] == b'e' || b[i] == b'E') {
                let mut j = i + 1;
                if j < end && (b[j] == b'+' || b[j] == b'-') {
                    j += 1;
                }
                if j < end && b[j].is_ascii_digit() {
                    i = j;
                    while i < end && b[i].is_ascii_digit() {
                        i += 1;
                    }
                }
            }
            let text = &src[s..i];
            let is_int = text.bytes().all(|c| c.is_ascii_digit());
            // GLSL's float suffixes: `1.0f`, `1.0lf`.
            for suffix in ["lf", "LF", "f", "F"] {
                if src[i..end].starts_with(suffix) {
                    i += suffix.len();
                    break;
                }
            }
            if i < end && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                return Err(Diagnostic::error("malformed number")
                    .at(Span::new(s, i + 1), "not a number")
                    .hint("numbers are written `1`, `.5`, `1.`, `1e-3`"));
            }
            let v: f64 = text.parse().map_err(|_| {
                Diagnostic::error("malformed number").at(Span::new(s, i), "not a number").hint("write e.g. `0.5`")
            })?;
            out.push(Token { tok: Tok::Num(v, is_int), span: Span::new(s, i) });
        } else if let Some(p) = PUNCT.iter().find(|p| b[i..end].starts_with(p.as_bytes())) {
            out.push(Token { tok: Tok::Punct(p), span: Span::new(i, i + p.len()) });
            i += p.len();
        } else {
            let ch = src[i..].chars().next().unwrap_or('?');
            return Err(Diagnostic::error(format!("unexpected character `{ch}` in the shader"))
                .at(Span::new(i, i + ch.len_utf8()), "not GLSL")
                .hint("the shader block holds GLSL; check for a stray character"));
        }
    }
    out.push(Token { tok: Tok::Eof, span: Span::new(end, end) });
    Ok(out)
}

/// The value types of the subset; `Void` only as a function's result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Type {
    Float,
    Bool,
    Vec3,
    Void,
}

impl Type {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Type::Float => "float",
            Type::Bool => "bool",
            Type::Vec3 => "vec3",
            Type::Void => "void",
        }
    }
}

/// A binary operator: arithmetic and comparisons as [`Values`](crate::front::values::Values) names them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Op {
    Arith(BinOp),
    Cmp(Cmp),
    And,
    Or,
}

/// The binary operators with their precedence (higher binds tighter); all are left-associative.
const BINARY: [(&str, Op, u8); 12] = [
    ("||", Op::Or, 1),
    ("&&", Op::And, 2),
    ("==", Op::Cmp(Cmp::Eq), 3),
    ("!=", Op::Cmp(Cmp::Ne), 3),
    ("<", Op::Cmp(Cmp::Lt), 4),
    ("<=", Op::Cmp(Cmp::Le), 4),
    (">", Op::Cmp(Cmp::Gt), 4),
    (">=", Op::Cmp(Cmp::Ge), 4),
    ("+", Op::Arith(BinOp::Add), 5),
    ("-", Op::Arith(BinOp::Sub), 5),
    ("*", Op::Arith(BinOp::Mul), 6),
    ("/", Op::Arith(BinOp::Div), 6),
];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Unary {
    Neg,
    Plus,
    Not,
}

#[derive(Clone, Debug)]
pub(crate) struct Expr {
    pub kind: ExprKind,
    pub span: Span,
    /// Height of the tree below (a leaf is 1); bounded by [`MAX_DEPTH`].
    pub height: u32,
}

#[derive(Clone, Debug)]
pub(crate) enum ExprKind {
    /// A literal and whether it is an integer.
    Num(f64, bool),
    Bool(bool),
    Name(String),
    /// A call: the name, its span, the arguments.
    Call(String, Span, Vec<Expr>),
    Unary(Unary, Box<Expr>),
    Binary(Op, Box<Expr>, Box<Expr>),
    Cond(Box<Expr>, Box<Expr>, Box<Expr>),
    Index(Box<Expr>, Box<Expr>),
    /// A swizzle: the component letters and their span.
    Field(Box<Expr>, String, Span),
}

/// What an assignment writes: a variable or one component of it.
#[derive(Clone, Debug)]
pub(crate) struct Target {
    pub name: String,
    pub span: Span,
    pub component: Option<Box<Expr>>,
}

#[derive(Clone, Debug)]
pub(crate) struct Declarator {
    pub name: String,
    pub span: Span,
    pub init: Option<Expr>,
}

#[derive(Clone, Debug)]
pub(crate) enum Stmt {
    Decl { ty: Type, konst: bool, vars: Vec<Declarator> },
    Assign { target: Target, op: Option<Op>, value: Expr, span: Span },
    If { cond: Expr, then: Vec<Stmt>, els: Option<Vec<Stmt>> },
    Return { value: Option<Expr>, span: Span },
    Expr(Expr),
    Block(Vec<Stmt>),
}

#[derive(Clone, Debug)]
pub(crate) struct Func {
    pub name: String,
    pub name_span: Span,
    pub ret: Type,
    pub params: Vec<(Type, String, Span)>,
    pub body: Vec<Stmt>,
}

#[derive(Clone, Debug)]
pub(crate) enum Item {
    Global { ty: Type, konst: bool, vars: Vec<Declarator> },
    Func(Func),
}

type R<T> = Result<T, Diagnostic>;

/// Parses the shader's tokens into items (globals and functions, in source order).
pub(crate) fn parse(toks: &[Token]) -> R<Vec<Item>> {
    let mut p = Parser { toks, pos: 0, depth: 0 };
    let mut items = Vec::new();
    while p.peek() != &Tok::Eof {
        items.push(p.item()?);
    }
    Ok(items)
}

struct Parser<'t> {
    toks: &'t [Token],
    pos: usize,
    depth: u32,
}

fn unsupported(span: Span, what: &str, hint: &str) -> Diagnostic {
    Diagnostic::error(format!("{what} are not supported in BRDF Explorer shaders read by lobe"))
        .at(span, "not supported")
        .hint(hint)
}

/// A diagnostic for a keyword or type outside the subset, or `None` for an ordinary name.
fn refused(word: &str, span: Span) -> Option<Diagnostic> {
    Some(match word {
        "for" | "while" | "do" => unsupported(
            span,
            "loops",
            "unroll the loop by hand, or write the sum in closed form (lobe compiles straight-line code)",
        ),
        "struct" => unsupported(span, "structs", "pass the fields as separate float/vec3 arguments"),
        "out" | "inout" => unsupported(span, "`out` parameters", "return the value instead (a vec3 can carry three)"),
        "uniform" | "varying" | "attribute" | "in" | "layout" | "precision" => unsupported(
            span,
            "global qualifiers",
            "declare parameters in the `::begin parameters` block; the shader sees them by name",
        ),
        "switch" | "case" | "break" | "continue" | "discard" => {
            unsupported(span, "`switch`, `break`, `continue` and `discard`", "use `if`/`else` and `return`")
        }
        "int" | "uint" | "double" => unsupported(span, "integer and double types", "use `float`"),
        w if w.starts_with("vec") || w.starts_with("mat") || w.starts_with("ivec") || w.starts_with("bvec") || w.starts_with("dvec") => {
            if w == "vec3" {
                return None;
            }
            unsupported(span, "types other than float, bool and vec3", "lobe's BRDFs work on float, bool and vec3")
        }
        w if w.starts_with("sampler") || w.starts_with("texture") => {
            unsupported(span, "textures", "an analytic BRDF cannot read textures")
        }
        _ => return None,
    })
}

fn type_of(word: &str) -> Option<Type> {
    Some(match word {
        "float" => Type::Float,
        "bool" => Type::Bool,
        "vec3" => Type::Vec3,
        "void" => Type::Void,
        _ => return None,
    })
}

impl<'t> Parser<'t> {
    fn peek(&self) -> &Tok {
        &self.toks[self.pos.min(self.toks.len() - 1)].tok
    }
    fn peek_at(&self, k: usize) -> &Tok {
        &self.toks[(self.pos + k).min(self.toks.len() - 1)].tok
    }
    fn span(&self) -> Span {
        self.toks[self.pos.min(self.toks.len() - 1)].span
    }
    fn prev_span(&self) -> Span {
        self.toks[self.pos.saturating_sub(1).min(self.toks.len() - 1)].span
    }
    fn bump(&mut self) -> Token {
        let t = self.toks[self.pos.min(self.toks.len() - 1)].clone();
        if self.pos < self.toks.len() - 1 {
            self.pos += 1;
        }
        t
    }
    fn is(&self, p: &str) -> bool {
        matches!(self.peek(), Tok::Punct(q) if *q == p)
    }
    fn eat(&mut self, p: &str) -> bool {
        if self.is(p) {
            self.bump();
            true
        } else {
            false
        }
    }
    fn found(&self) -> String {
        match self.peek() {
            Tok::Num(..) => "a number".into(),
            Tok::Ident(s) => format!("`{s}`"),
            Tok::Punct(p) => format!("`{p}`"),
            Tok::Eof => "the end of the shader".into(),
        }
    }
    fn expect(&mut self, p: &str) -> R<Span> {
        if self.is(p) {
            return Ok(self.bump().span);
        }
        if let Tok::Ident(w) = self.peek() {
            if let Some(d) = refused(w, self.span()) {
                return Err(d);
            }
        }
        Err(Diagnostic::error(format!("expected `{p}`, found {}", self.found()))
            .at(self.span(), format!("expected `{p}`"))
            .hint(match p {
                ";" => "end each statement with `;`",
                ")" => "check the parentheses",
                "}" => "close the block with `}`",
                _ => "check the GLSL syntax here",
            }))
    }
    fn ident(&mut self, what: &str) -> R<(String, Span)> {
        match self.peek().clone() {
            Tok::Ident(s) => {
                if let Some(d) = refused(&s, self.span()) {
                    return Err(d);
                }
                let sp = self.bump().span;
                Ok((s, sp))
            }
            _ => Err(Diagnostic::error(format!("expected {what}, found {}", self.found()))
                .at(self.span(), format!("expected {what}"))
                .hint("check the GLSL syntax here")),
        }
    }
    fn enter(&mut self) -> R<()> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(Diagnostic::error(format!("the shader nests deeper than {MAX_DEPTH} levels"))
                .at(self.span(), "too deep")
                .hint("split the expression with local variables"));
        }
        Ok(())
    }
    fn leave(&mut self) {
        self.depth -= 1;
    }

    /// A type keyword here, or `None`; a refused keyword is an error.
    fn ty(&self) -> R<Option<Type>> {
        match self.peek() {
            Tok::Ident(w) => {
                if let Some(d) = refused(w, self.span()) {
                    return Err(d);
                }
                Ok(type_of(w))
            }
            _ => Ok(None),
        }
    }

    fn item(&mut self) -> R<Item> {
        if matches!(self.peek(), Tok::Punct("#")) {
            return Err(unsupported(self.span(), "preprocessor directives", "write constants as `const float NAME = …;`"));
        }
        let konst = matches!(self.peek(), Tok::Ident(w) if w == "const");
        if konst {
            self.bump();
        }
        let ty_span = self.span();
        let Some(ty) = self.ty()? else {
            return Err(self.not_a_type("a global declaration or a function"));
        };
        self.bump();
        if !konst && matches!(self.peek_at(1), Tok::Punct("(")) {
            return Ok(Item::Func(self.func(ty)?));
        }
        if ty == Type::Void {
            return Err(Diagnostic::error("a variable cannot be `void`").at(ty_span, "void").hint("use float, bool or vec3"));
        }
        let vars = self.declarators()?;
        Ok(Item::Global { ty, konst, vars })
    }

    fn not_a_type(&self, what: &str) -> Diagnostic {
        let sp = self.span();
        match self.peek() {
            Tok::Ident(w) => Diagnostic::error(format!("unknown type `{w}`"))
                .at(sp, "not a type")
                .hint(format!("expected {what}; the types are float, bool and vec3 (structs are not supported)")),
            _ => Diagnostic::error(format!("expected {what}, found {}", self.found()))
                .at(sp, "unexpected")
                .hint("the shader holds constants and functions such as `vec3 BRDF(vec3 L, vec3 V, vec3 N, vec3 X, vec3 Y) { … }`"),
        }
    }

    fn func(&mut self, ret: Type) -> R<Func> {
        let (name, name_span) = self.ident("a function name")?;
        self.expect("(")?;
        let mut params = Vec::new();
        if matches!(self.peek(), Tok::Ident(w) if w == "void") && matches!(self.peek_at(1), Tok::Punct(")")) {
            self.bump();
        }
        while !self.is(")") {
            if !params.is_empty() {
                self.expect(",")?;
            }
            while matches!(self.peek(), Tok::Ident(w) if w == "const" || w == "in") {
                self.bump();
            }
            let Some(ty) = self.ty()? else {
                return Err(self.not_a_type("a parameter type"));
            };
            if ty == Type::Void {
                return Err(self.not_a_type("a parameter type"));
            }
            self.bump();
            let (pname, psp) = self.ident("a parameter name")?;
            if self.is("[") {
                return Err(unsupported(self.span(), "arrays", "use separate variables or a vec3"));
            }
            params.push((ty, pname, psp));
        }
        self.expect(")")?;
        if self.is(";") {
            return Err(Diagnostic::error("function prototypes are not supported")
                .at(self.span(), "prototype")
                .hint("define the function before its first use"));
        }
        let body = self.block()?;
        Ok(Func { name, name_span, ret, params, body })
    }

    fn block(&mut self) -> R<Vec<Stmt>> {
        self.expect("{")?;
        self.enter()?;
        let mut out = Vec::new();
        while !self.is("}") {
            if self.peek() == &Tok::Eof {
                return Err(Diagnostic::error("unclosed block")
                    .at(self.span(), "the shader ends here")
                    .hint("close every `{` with `}`"));
            }
            out.push(self.stmt()?);
        }
        self.bump();
        self.leave();
        Ok(out)
    }

    fn declarators(&mut self) -> R<Vec<Declarator>> {
        let mut vars = Vec::new();
        loop {
            let (name, span) = self.ident("a variable name")?;
            if self.is("[") {
                return Err(unsupported(self.span(), "arrays", "use separate variables or a vec3"));
            }
            let init = if self.eat("=") { Some(self.expr()?) } else { None };
            vars.push(Declarator { name, span, init });
            if !self.eat(",") {
                break;
            }
        }
        self.expect(";")?;
        Ok(vars)
    }

    fn stmt(&mut self) -> R<Stmt> {
        self.enter()?;
        let s = self.stmt_inner();
        self.leave();
        s
    }

    fn stmt_inner(&mut self) -> R<Stmt> {
        if self.is("{") {
            return Ok(Stmt::Block(self.block()?));
        }
        if self.eat(";") {
            return Ok(Stmt::Block(vec![]));
        }
        if let Tok::Ident(w) = self.peek().clone() {
            match w.as_str() {
                "if" => {
                    self.bump();
                    self.expect("(")?;
                    let cond = self.expr()?;
                    self.expect(")")?;
                    let then = self.branch()?;
                    let els = if matches!(self.peek(), Tok::Ident(e) if e == "else") {
                        self.bump();
                        Some(self.branch()?)
                    } else {
                        None
                    };
                    return Ok(Stmt::If { cond, then, els });
                }
                "return" => {
                    let span = self.bump().span;
                    let value = if self.is(";") { None } else { Some(self.expr()?) };
                    self.expect(";")?;
                    return Ok(Stmt::Return { value, span });
                }
                _ => {}
            }
            let konst = w == "const";
            if konst {
                self.bump();
            }
            if let Some(ty) = self.ty()? {
                // `vec3(...)` at the start of a statement is an expression, not a declaration.
                if konst || !matches!(self.peek_at(1), Tok::Punct("(")) {
                    self.bump();
                    if ty == Type::Void {
                        return Err(Diagnostic::error("a variable cannot be `void`").at(self.prev_span(), "void"));
                    }
                    return Ok(Stmt::Decl { ty, konst, vars: self.declarators()? });
                }
            } else if konst || matches!(self.peek_at(1), Tok::Ident(_)) {
                return Err(self.not_a_type("a declaration"));
            }
        }
        let start = self.span();
        let e = self.expr()?;
        let op = match self.peek() {
            Tok::Punct("=") => Some(None),
            Tok::Punct("+=") => Some(Some(Op::Arith(BinOp::Add))),
            Tok::Punct("-=") => Some(Some(Op::Arith(BinOp::Sub))),
            Tok::Punct("*=") => Some(Some(Op::Arith(BinOp::Mul))),
            Tok::Punct("/=") => Some(Some(Op::Arith(BinOp::Div))),
            Tok::Punct("++" | "--") => {
                return Err(unsupported(self.span(), "`++` and `--`", "write `x += 1.0;`"));
            }
            _ => None,
        };
        let Some(op) = op else {
            self.expect(";")?;
            return Ok(Stmt::Expr(e));
        };
        self.bump();
        let target = match e.kind {
            ExprKind::Name(name) => Target { name, span: e.span, component: None },
            ExprKind::Index(base, k) => match base.kind {
                ExprKind::Name(name) => Target { name, span: base.span, component: Some(k) },
                _ => return Err(not_assignable(e.span)),
            },
            ExprKind::Field(base, letters, lsp) => match base.kind {
                ExprKind::Name(name) if letters.len() == 1 => {
                    let k = Expr { kind: ExprKind::Num(component_of(&letters, lsp)? as f64, true), span: lsp, height: 1 };
                    Target { name, span: base.span, component: Some(Box::new(k)) }
                }
                _ => return Err(not_assignable(e.span)),
            },
            _ => return Err(not_assignable(e.span)),
        };
        let value = self.expr()?;
        let span = start.join(value.span);
        self.expect(";")?;
        Ok(Stmt::Assign { target, op, value, span })
    }

    /// The body of an `if` or `else`: a block or one statement.
    fn branch(&mut self) -> R<Vec<Stmt>> {
        Ok(match self.stmt()? {
            Stmt::Block(b) => b,
            s => vec![s],
        })
    }

    fn expr(&mut self) -> R<Expr> {
        self.enter()?;
        let e = self.ternary();
        self.leave();
        e
    }

    fn ternary(&mut self) -> R<Expr> {
        let c = self.binary(0)?;
        if !self.eat("?") {
            return Ok(c);
        }
        let a = self.expr()?;
        self.expect(":")?;
        let b = self.expr()?;
        mk(c.span.join(b.span), ExprKind::Cond(Box::new(c), Box::new(a), Box::new(b)))
    }

    /// Precedence climbing over the binary operators (all left-associative).
    fn binary(&mut self, min: u8) -> R<Expr> {
        let mut lhs = self.unary()?;
        loop {
            let (op, prec) = match self.peek() {
                Tok::Punct(p @ ("%" | "&" | "|" | "^")) => {
                    let hint = if *p == "%" { "use mod(x, y)" } else { "bitwise operators need integers; use && or ||" };
                    return Err(Diagnostic::error(format!("operator `{p}` is not supported"))
                        .at(self.span(), "not supported")
                        .hint(hint));
                }
                Tok::Punct(p) => match BINARY.iter().find(|b| b.0 == *p) {
                    Some(&(_, op, prec)) => (op, prec),
                    None => return Ok(lhs),
                },
                _ => return Ok(lhs),
            };
            if prec <= min {
                return Ok(lhs);
            }
            self.bump();
            self.enter()?;
            let rhs = self.binary(prec);
            self.leave();
            let rhs = rhs?;
            let span = lhs.span.join(rhs.span);
            lhs = mk(span, ExprKind::Binary(op, Box::new(lhs), Box::new(rhs)))?;
        }
    }

    fn unary(&mut self) -> R<Expr> {
        let op = match self.peek() {
            Tok::Punct("-") => Unary::Neg,
            Tok::Punct("+") => Unary::Plus,
            Tok::Punct("!") => Unary::Not,
            Tok::Punct(p @ ("++" | "--" | "~")) => {
                return Err(Diagnostic::error(format!("operator `{p}` is not supported")).at(self.span(), "not supported"))
            }
            _ => return self.postfix(),
        };
        let s = self.bump().span;
        self.enter()?;
        let a = self.unary();
        self.leave();
        let a = a?;
        mk(s.join(a.span), ExprKind::Unary(op, Box::new(a)))
    }

    fn postfix(&mut self) -> R<Expr> {
        let mut e = self.primary()?;
        loop {
            if self.eat("[") {
                let k = self.expr()?;
                let close = self.expect("]")?;
                e = mk(e.span.join(close), ExprKind::Index(Box::new(e), Box::new(k)))?;
            } else if self.eat(".") {
                let (letters, sp) = self.ident("a component (x, y, z or r, g, b)")?;
                e = mk(e.span.join(sp), ExprKind::Field(Box::new(e), letters, sp))?;
            } else {
                return Ok(e);
            }
        }
    }

    fn primary(&mut self) -> R<Expr> {
        let sp = self.span();
        match self.peek().clone() {
            Tok::Num(v, int) => {
                self.bump();
                mk(sp, ExprKind::Num(v, int))
            }
            Tok::Ident(w) => {
                if let Some(d) = refused(&w, sp) {
                    return Err(d);
                }
                self.bump();
                match w.as_str() {
                    "true" => return mk(sp, ExprKind::Bool(true)),
                    "false" => return mk(sp, ExprKind::Bool(false)),
                    _ => {}
                }
                if !self.eat("(") {
                    return mk(sp, ExprKind::Name(w));
                }
                let mut args = Vec::new();
                while !self.is(")") {
                    if !args.is_empty() {
                        self.expect(",")?;
                    }
                    args.push(self.expr()?);
                }
                let close = self.expect(")")?;
                let h = args.iter().map(|a| a.height).max().unwrap_or(0);
                mk_h(sp.join(close), ExprKind::Call(w, sp, args), h)
            }
            Tok::Punct("(") => {
                self.bump();
                let e = self.expr()?;
                self.expect(")")?;
                Ok(e)
            }
            _ => Err(Diagnostic::error(format!("expected an expression, found {}", self.found()))
                .at(sp, "expected an expression")
                .hint("check the GLSL syntax here")),
        }
    }
}

fn not_assignable(span: Span) -> Diagnostic {
    Diagnostic::error("this cannot be assigned to").at(span, "not a variable").hint("assign to a variable or one component (`v.x = …`)")
}

/// The component index of a one-letter swizzle (`x`/`r`/`s` → 0, …).
pub(crate) fn component_of(letter: &str, span: Span) -> R<usize> {
    match letter {
        "x" | "r" | "s" => Ok(0),
        "y" | "g" | "t" => Ok(1),
        "z" | "b" | "p" => Ok(2),
        _ => Err(Diagnostic::error(format!("`.{letter}` is not a component of a vec3"))
            .at(span, "unknown component")
            .hint("a vec3 has x, y, z (or r, g, b)")),
    }
}

fn mk(span: Span, kind: ExprKind) -> R<Expr> {
    let h = match &kind {
        ExprKind::Unary(_, a) | ExprKind::Index(a, _) | ExprKind::Field(a, _, _) => a.height,
        ExprKind::Binary(_, a, b) => a.height.max(b.height),
        ExprKind::Cond(a, b, c) => a.height.max(b.height).max(c.height),
        _ => 0,
    };
    mk_h(span, kind, h)
}

fn mk_h(span: Span, kind: ExprKind, below: u32) -> R<Expr> {
    let height = below + 1;
    if height > MAX_DEPTH {
        return Err(Diagnostic::error(format!("this expression nests deeper than {MAX_DEPTH} levels"))
            .at(span, "too deep")
            .hint("split it with local variables"));
    }
    Ok(Expr { kind, span, height })
}
