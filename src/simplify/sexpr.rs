//! A tiny s-expression reader that builds IR directly, for tests that bypass the front end.
//!
//! `(op arg …)` with op one of `+ - * /` (n-ary, left-associative; `(- x)` is negation), `neg`, or a builtin
//! name; atoms are numbers, `pi`, `-0`, `nan`, `inf`, input names and parameter names. [`formula`] mirrors the
//! lowering's shape (each input read is `clamp(INPUT, 0, 1)`, the root is `max(raw, 0)`); [`formula_literal`]
//! builds exactly what is written (input names are raw inputs).

use crate::builtins::Builtin;
use crate::base::span::Span;
use crate::ir::{BinOp, Formula, Input, Ir, Meta, Node, NodeId, ParamDecl, ParamKind};

/// Parameters beyond the implicit `n` (`n = 50 in 1..1000` unless listed): `(name, default, lo, hi)`.
pub type ParamSpec<'a> = (&'a str, f64, f64, f64);

/// Builds a formula in the lowering's shape (clamped inputs, `max(raw, 0)` root).
pub fn formula(src: &str, params: &[ParamSpec]) -> Result<Formula, String> {
    build(src, params, true)
}

/// Builds exactly the written expression.
pub fn formula_literal(src: &str, params: &[ParamSpec]) -> Result<Formula, String> {
    build(src, params, false)
}

fn build(src: &str, params: &[ParamSpec], lowered: bool) -> Result<Formula, String> {
    let mut decls = vec![ParamDecl { name: "n".into(), default: 50.0, lo: 1.0, hi: 1000.0, span: None, kind: ParamKind::Float }];
    for &(name, default, lo, hi) in params {
        let d = ParamDecl { name: name.into(), default, lo, hi, span: None, kind: ParamKind::Float };
        match decls.iter_mut().find(|p| p.name == name) {
            Some(p) => *p = d,
            None => decls.push(d),
        }
    }
    let toks = tokens(src);
    let mut b = Builder { ir: Ir::new(), toks, pos: 0, params: &decls, lowered };
    let raw = b.expr()?;
    if b.pos != b.toks.len() {
        return Err(format!("unexpected `{}` after the expression", b.toks[b.pos].0));
    }
    let root = if lowered {
        let z = b.ir.konst(0.0, Span::default());
        b.ir.call(Builtin::Max, &[raw, z], Span::default())
    } else {
        raw
    };
    let ir = b.ir;
    Ok(Formula { meta: Meta::default(), params: decls, ir, root, file: "sexpr".into(), source: src.into(), rgb: None })
}

fn tokens(src: &str) -> Vec<(String, Span)> {
    let mut out = vec![];
    let mut cur = String::new();
    let mut start = 0;
    for (i, ch) in src.char_indices() {
        if ch == '(' || ch == ')' || ch.is_whitespace() {
            if !cur.is_empty() {
                out.push((std::mem::take(&mut cur), Span::new(start, i)));
            }
            if !ch.is_whitespace() {
                out.push((ch.to_string(), Span::new(i, i + 1)));
            }
        } else {
            if cur.is_empty() {
                start = i;
            }
            cur.push(ch);
        }
    }
    if !cur.is_empty() {
        out.push((cur, Span::new(start, src.len())));
    }
    out
}

struct Builder<'a> {
    ir: Ir,
    toks: Vec<(String, Span)>,
    pos: usize,
    params: &'a [ParamDecl],
    lowered: bool,
}

impl Builder<'_> {
    fn next(&mut self) -> Result<(String, Span), String> {
        let t = self.toks.get(self.pos).cloned().ok_or("unexpected end of input")?;
        self.pos += 1;
        Ok(t)
    }

    fn expr(&mut self) -> Result<NodeId, String> {
        let (t, s) = self.next()?;
        if t == "(" {
            let (op, os) = self.next()?;
            let mut args = vec![];
            while self.toks.get(self.pos).map(|t| t.0.as_str()) != Some(")") {
                args.push(self.expr()?);
            }
            let (_, close) = self.next()?;
            let span = os.join(s).join(close);
            return self.apply(&op, &args, span);
        }
        if t == ")" {
            return Err("unexpected `)`".into());
        }
        self.atom(&t, s)
    }

    fn atom(&mut self, t: &str, s: Span) -> Result<NodeId, String> {
        if let Some(i) = Input::from_name(t) {
            let x = self.ir.input(i, s);
            if !self.lowered {
                return Ok(x);
            }
            let (z, one) = (self.ir.konst(0.0, s), self.ir.konst(1.0, s));
            return Ok(self.ir.call(Builtin::Clamp, &[x, z, one], s));
        }
        if let Some(p) = self.params.iter().position(|p| p.name == t) {
            return Ok(self.ir.param(p as u16, s));
        }
        let v = match t {
            "pi" => std::f64::consts::PI,
            "nan" => f64::NAN,
            "inf" => f64::INFINITY,
            _ => t.parse::<f64>().map_err(|_| format!("unknown name `{t}`"))?,
        };
        Ok(self.ir.konst(v, s))
    }

    fn apply(&mut self, op: &str, args: &[NodeId], s: Span) -> Result<NodeId, String> {
        let bin = match op {
            "+" => Some(BinOp::Add),
            "-" => Some(BinOp::Sub),
            "*" => Some(BinOp::Mul),
            "/" => Some(BinOp::Div),
            _ => None,
        };
        if op == "neg" || (op == "-" && args.len() == 1) {
            let [a] = args else { return Err("neg takes one argument".into()) };
            return Ok(self.ir.push(Node::Neg(*a), s));
        }
        if let Some(bop) = bin {
            let (first, rest) = args.split_first().ok_or(format!("`{op}` needs arguments"))?;
            if rest.is_empty() {
                return Err(format!("`{op}` needs two or more arguments"));
            }
            return Ok(rest.iter().fold(*first, |acc, b| self.ir.bin(bop, acc, *b, s)));
        }
        let f = Builtin::from_name(op).ok_or(format!("unknown function `{op}`"))?;
        if args.len() != f.arity() {
            return Err(format!("`{op}` takes {} arguments, got {}", f.arity(), args.len()));
        }
        Ok(self.ir.call(f, args, s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builds_the_lowered_shape() {
        let f = formula("(pow NH n)", &[]).unwrap();
        assert_eq!(f.to_text(), "max(pow(clamp(NH, 0, 1), n), 0)");
        let g = formula_literal("(- (* 2 NL) (neg a))", &[("a", 1.0, 0.0, 2.0)]).unwrap();
        assert_eq!(g.to_text(), "2 * NL - -a");
        assert!(formula("(pow NH)", &[]).is_err());
        assert!(formula("(foo 1)", &[]).is_err());
        assert!(formula("(+ 1 2", &[]).is_err());
    }
}
