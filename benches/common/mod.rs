//! The benchmarked catalogue: formula text, a fasteval spelling, a hand-written Rust twin, and a hand-built
//! IR fallback (used only while the front end is not in the tree; the benches say which path they use).
//!
//! Twins implement the same domain policy as the lowering (inputs clamped to [0, 1], result `max(·, 0)`,
//! NaN-propagating) so that all contestants compute the same function. Squares are written as products, as
//! the simplifier rewrites `x^2`.
#![allow(dead_code)]

use lobe::builtins::Builtin;
use lobe::base::span::Span;
use lobe::ir::{BinOp, Formula, Input, Ir, Meta, NodeId, ParamDecl, N_INPUTS};
use lobe::{Backend, Kernel, Options};
use std::sync::Arc;

/// NaN-propagating max/min, the table's semantics, inlined (lobe's own are not `#[inline]`).
#[inline(always)]
pub fn fmax(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a > b || (a == b && a.is_sign_positive()) {
        a
    } else {
        b
    }
}
#[inline(always)]
pub fn fmin(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if a < b || (a == b && a.is_sign_negative()) {
        a
    } else {
        b
    }
}
#[inline(always)]
pub fn cl(x: f64) -> f64 {
    fmin(fmax(x, 0.0), 1.0)
}

pub type Twin = fn(&[f64; N_INPUTS], &[f64]) -> f64;

pub struct Entry {
    pub name: &'static str,
    /// lobe source text.
    pub text: &'static str,
    /// fasteval spelling (variables `NH`, `VR`, `n`, `a`); no domain policy (fasteval has no NaN-propagating
    /// max) — the cost of two clamps is small next to its per-node dispatch.
    pub fasteval: &'static str,
    pub twin: Twin,
    /// Whether the formula is arithmetic only (no libm call): the batched-vs-Rust-loop target applies.
    pub arithmetic: bool,
    pub params: &'static [f64],
    hand: fn() -> Formula,
}

pub fn catalogue() -> Vec<Entry> {
    vec![
        Entry {
            name: "phong",
            text: "@name \"Phong\"\nVR^n\n",
            fasteval: "VR^n",
            twin: |x, p| fmax(cl(x[3]).powf(p[0]), 0.0),
            arithmetic: false,
            params: &[50.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::VR);
                    let n = b.param(0);
                    b.call(Builtin::Pow, &[c, n])
                })
            },
        },
        Entry {
            name: "blinn",
            text: "@name \"Blinn\"\nNH^n\n",
            fasteval: "NH^n",
            twin: |x, p| fmax(cl(x[2]).powf(p[0]), 0.0),
            arithmetic: false,
            params: &[50.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::NH);
                    let n = b.param(0);
                    b.call(Builtin::Pow, &[c, n])
                })
            },
        },
        Entry {
            name: "schlick",
            text: "let c = NH\nc / (n - n*c + c)\n",
            fasteval: "NH / (n - n*NH + NH)",
            twin: |x, p| {
                let (c, n) = (cl(x[2]), p[0]);
                fmax(c / (n - n * c + c), 0.0)
            },
            arithmetic: true,
            params: &[50.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::NH);
                    let n = b.param(0);
                    let nc = b.bin(BinOp::Mul, n, c);
                    let d = b.bin(BinOp::Sub, n, nc);
                    let d = b.bin(BinOp::Add, d, c);
                    b.bin(BinOp::Div, c, d)
                })
            },
        },
        Entry {
            name: "modified_schlick",
            text: "let c = NH\n2*c / (1.25*(n - n*c + 1.25*c)^2)\n",
            fasteval: "2*NH / (1.25*(n - n*NH + 1.25*NH)^2)",
            twin: |x, p| {
                let (c, n) = (cl(x[2]), p[0]);
                let t = n - n * c + 1.25 * c;
                fmax(2.0 * c / (1.25 * (t * t)), 0.0)
            },
            arithmetic: true,
            params: &[50.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::NH);
                    let n = b.param(0);
                    let two = b.konst(2.0);
                    let q = b.konst(1.25);
                    let num = b.bin(BinOp::Mul, two, c);
                    let nc = b.bin(BinOp::Mul, n, c);
                    let qc = b.bin(BinOp::Mul, q, c);
                    let t = b.bin(BinOp::Sub, n, nc);
                    let t = b.bin(BinOp::Add, t, qc);
                    let sq = b.bin(BinOp::Mul, t, t);
                    let den = b.bin(BinOp::Mul, q, sq);
                    b.bin(BinOp::Div, num, den)
                })
            },
        },
        Entry {
            name: "scos2",
            text: "let c = NH\n((-1.1/(-n + n*c - 2*c))*n*(c - 1) + 1)^2\n",
            fasteval: "((-1.1/(-n + n*NH - 2*NH))*n*(NH - 1) + 1)^2",
            twin: |x, p| {
                let (c, n) = (cl(x[2]), p[0]);
                let t = (-1.1 / (-n + n * c - 2.0 * c)) * n * (c - 1.0) + 1.0;
                fmax(t * t, 0.0)
            },
            arithmetic: true,
            params: &[50.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::NH);
                    let n = b.param(0);
                    let k = b.konst(-1.1);
                    let two = b.konst(2.0);
                    let one = b.konst(1.0);
                    let nn = b.neg(n);
                    let nc = b.bin(BinOp::Mul, n, c);
                    let tc = b.bin(BinOp::Mul, two, c);
                    let d = b.bin(BinOp::Add, nn, nc);
                    let d = b.bin(BinOp::Sub, d, tc);
                    let q = b.bin(BinOp::Div, k, d);
                    let q = b.bin(BinOp::Mul, q, n);
                    let cm = b.bin(BinOp::Sub, c, one);
                    let q = b.bin(BinOp::Mul, q, cm);
                    let t = b.bin(BinOp::Add, q, one);
                    b.bin(BinOp::Mul, t, t)
                })
            },
        },
        Entry {
            name: "f_st",
            text: "param a = 16 in 1..1000\nlet c = NH\n(n/a*(c - 1) + 1)^a\n",
            fasteval: "(n/a*(NH - 1) + 1)^a",
            twin: |x, p| {
                let (c, n, a) = (cl(x[2]), p[0], p[1]);
                fmax((n / a * (c - 1.0) + 1.0).powf(a), 0.0)
            },
            arithmetic: false,
            params: &[50.0, 16.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::NH);
                    let n = b.param(0);
                    let a = b.param(1);
                    let one = b.konst(1.0);
                    let q = b.bin(BinOp::Div, n, a);
                    let cm = b.bin(BinOp::Sub, c, one);
                    let t = b.bin(BinOp::Mul, q, cm);
                    let t = b.bin(BinOp::Add, t, one);
                    b.call(Builtin::Pow, &[t, a])
                })
            },
        },
        Entry {
            name: "gaussian",
            text: "exp(-n*acos(NH)^2/2)\n",
            fasteval: "e()^(-n*acos(NH)^2/2)",
            twin: |x, p| {
                let (c, n) = (cl(x[2]), p[0]);
                let t = fmin(fmax(c, -1.0), 1.0).acos();
                fmax((-n * (t * t) / 2.0).exp(), 0.0)
            },
            arithmetic: false,
            params: &[50.0],
            hand: || {
                hand(|b| {
                    let c = b.input(Input::NH);
                    let n = b.param(0);
                    let two = b.konst(2.0);
                    let t = b.call(Builtin::Acos, &[c]);
                    let sq = b.bin(BinOp::Mul, t, t);
                    let nn = b.neg(n);
                    let q = b.bin(BinOp::Mul, nn, sq);
                    let q = b.bin(BinOp::Div, q, two);
                    b.call(Builtin::Exp, &[q])
                })
            },
        },
    ]
}

/// A small IR builder with the lowering's domain policy.
pub struct B {
    ir: Ir,
}
const S: Span = Span { start: 0, end: 0 };
impl B {
    pub fn input(&mut self, i: Input) -> NodeId {
        let x = self.ir.input(i, S);
        let (z, o) = (self.ir.konst(0.0, S), self.ir.konst(1.0, S));
        self.ir.call(Builtin::Clamp, &[x, z, o], S)
    }
    pub fn param(&mut self, p: u16) -> NodeId {
        self.ir.param(p, S)
    }
    pub fn konst(&mut self, v: f64) -> NodeId {
        self.ir.konst(v, S)
    }
    pub fn neg(&mut self, a: NodeId) -> NodeId {
        self.ir.neg(a, S)
    }
    pub fn bin(&mut self, op: BinOp, a: NodeId, b: NodeId) -> NodeId {
        self.ir.bin(op, a, b, S)
    }
    pub fn call(&mut self, f: Builtin, a: &[NodeId]) -> NodeId {
        self.ir.call(f, a, S)
    }
}

fn hand(build: impl FnOnce(&mut B) -> NodeId) -> Formula {
    let mut b = B { ir: Ir::new() };
    let raw = build(&mut b);
    let z = b.konst(0.0);
    let root = b.call(Builtin::Max, &[raw, z]);
    let p = |name: &str, default: f64| ParamDecl { name: name.into(), default, lo: 1.0, hi: 1000.0, span: None };
    Formula {
        meta: Meta::default(),
        params: vec![p("n", 50.0), p("a", 16.0)],
        ir: b.ir,
        root,
        file: "hand.brdf".into(),
        source: String::new(),
    }
}

impl Entry {
    /// The kernel from the formula text via `lobe::compile_source`, or (before the front end is merged) from the
    /// hand-built IR. The bool says whether the text path was used.
    pub fn kernel(&self, backend: Backend) -> (Kernel, bool) {
        let opts = Options { backend, ..Options::default() };
        match lobe::compile_source(self.name, self.text, &opts) {
            Ok(k) => (k, true),
            Err(_) => match lobe::compile_formula(self.hand_formula(), &opts) {
                Ok(k) => (k, false),
                Err(d) => panic!("{}: {}", self.name, d.render(false)),
            },
        }
    }

    /// The hand-built IR, declaring exactly the parameters the entry passes (`n`, and `a` for F_ST).
    pub fn hand_formula(&self) -> Formula {
        let mut f = (self.hand)();
        f.params.truncate(self.params.len());
        f
    }

    /// The Rust twin behind the same `Evaluator` interface as the JIT (same dispatch cost).
    pub fn twin_kernel(&self, like: &Kernel) -> Kernel {
        let twin = self.twin;
        Kernel::new(
            like.formula.clone(),
            Backend::Interp,
            Arc::new(lobe::backend::FnEvaluator(twin)),
            Default::default(),
        )
    }
}
