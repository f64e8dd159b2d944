//! IR → IR rewrites to a fixpoint: constant folding, exact algebraic identities, integer powers as
//! multiplication chains, range-based removal of redundant clamps, baked parameters, dead-input elimination.
//! The accuracy pass's candidate rewrites (overflow, underflow, cancellation) are in [`accuracy`]; they are
//! proposed here and chosen by measurement above the backends (`numerics::robust`).
//!
//! # Design
//! Like rhai's optimizer and OSL's `constfold.cpp`: a loop of passes until a pass fires no rewrite (capped at
//! [`MAX_PASSES`]; in practice two or three — the property tests check ≤ 3). A pass walks the arena in
//! topological order and rebuilds it bottom-up into a fresh hash-consed arena; each node is rewritten as it is
//! added, after its operands, and a rewrite's own new nodes go through the same rewriting, so most formulas
//! reach the fixpoint in one rewriting pass plus one confirming pass. Because the new arena hash-conses,
//! rewritten subgraphs re-intern: `pow(NH, 2)` and `NH*NH` end as one node. A rewritten node keeps the span of
//! the node it replaces (so notes point at the user's text), and the result is compacted ([`Ir::compact`]), so
//! a `let` used only in a branch that folded away, and any input only it read, disappear from
//! [`Formula::used_inputs`]. Each rewrite below is introduced by its pattern in a comment (`// x*1 → x`) and
//! counted by name in the [`Report`]. Cost: linear in the nodes per pass, dominated by hash-consing — perf
//! showed ~60 % of the time in SipHash inside `Ir::push`, which now hashes with FxHash (`benches/simplify.rs`
//! times every catalogue formula; before/after in BENCHMARKS.md).
//!
//! Constants fold through [`BinOp::apply`] and [`Builtin::eval`] — the functions every backend uses — so
//! folding never changes a value.
//!
//! # IEEE policy
//! Exact identities (the same bits for every input, NaN payloads aside), always on:
//! `x*1 → x`, `x/1 → x`, `x−0 → x`, `x+(−0) → x`, `(−0)−x → −x`, `−(−x) → x`, `x*(−1) → −x`, `x/(−1) → −x`,
//! `a+(−b) → a−b`, `a−(−b) → a+b`, `(−a)*(−b) → a*b`, `x/c → x*(1/c)` only for c = ±2^e with 1/c normal,
//! `pow(x, 1) → x`, `pow(x, 0) → 1` (C99 F.9.4.4: pow(x, ±0) = 1 for every x, NaN included — checked against
//! Rust's `powf`), `abs(−x) → abs(x)`, `abs(abs(x)) → abs(x)`, `min(x, x) → x`, `max(x, x) → x`,
//! `acos(clamp(x, ≤−1, ≥1)) → acos(x)` (the builtin clamps itself).
//!
//! Exact only on part of the domain, so guarded by interval analysis ([`range`]: bounds, NaN possible, −0
//! possible): `x+0 → x` when x cannot be −0 (−0+0 = +0); `x*0 → ±0` when x is finite with a known sign
//! (0·inf = NaN); `x−x → 0` when x is finite; `x/x → 1` when x is finite and non-zero; `0/x → 0` for x > 0;
//! `max(a, b) → a` / `min(a, b) → a` when the ranges order them and b is never NaN (this removes the
//! lowering's root `max(raw, 0)` when raw ≥ 0 — NaN passes through either way); `clamp(x, lo, hi) → x` (or
//! `→ min(x, hi)`, `→ max(x, lo)`) when a side is provably redundant; `abs(x) → x` for x ≥ +0.
//!
//! Refused (not exact under IEEE): `0*x → 0` for x that may be NaN or inf; `x+0 → x` for x that may be −0;
//! `x−x → 0` and `x/x → 1` for unbounded x; reassociation (`(2*x)*3 ≠ 6*x`, `(a+b)+c ≠ a+(b+c)`) and
//! distribution, which change rounding without a bound we could report; `sqrt(x*x) → abs(x)` (overflow);
//! `pow(x, 0.5) → sqrt(x)` where x may be −0 (pow: +0, sqrt: −0) or −inf (pow: +inf, sqrt: NaN).
//!
//! What the ranges assume is the [`Policy`]. The default follows the kernel contract: inputs are cosines, never
//! NaN (so `NL*0` is 0 and NL is no longer read; the lowering's `clamp(INPUT, 0, 1)` bounds them to [0, 1]), and
//! parameters stay in their declared ranges. [`Policy::exact`] assumes nothing and changes no rounding: the
//! property tests check it is bit-identical on NaN, inf and out-of-range inputs and parameters.
//!
//! # Rewrites that change rounding (listed in [`Report::rounding`]; off under [`Policy::exact`])
//! - `pow(x, k) → multiplication chain` for integer 2 ≤ |k| ≤ [`MAX_POW_CHAIN`] (shortest addition chains up
//!   to 16, binary above; negative k → `1/x^|k|`): ~5× faster than libm `pow` natively (BENCHMARKS.md), and
//!   the JIT needs it to match Rust. Error bound (k−1)·u. Measured against a double-double reference, x
//!   uniform in [0, 1], normal results (test `accuracy_pow_chain_vs_libm` in `tests/it/simplify.rs`; glibc
//!   `pow` itself measured ≤ 0.5 ulp, i.e. correctly rounded here):
//!
//!   | k | 2 | 3 | 4 | 5 | 8 | 10 | 12 | 15 | 16 | 50 | 268 | 1000 |
//!   |---|---|---|---|---|---|----|----|----|----|----|-----|------|
//!   | chain max ulp  | 0.50 | 1.23 | 1.86 | 2.84 | 4.64 | 5.71 | 7.21 | 8.97 | 10.45 | 32.6 | 182 | 490 |
//!   | chain mean ulp | 0.25 | 0.34 | 0.55 | 0.60 | 1.13 | 1.23 | 1.47 | 1.82 | 2.28 | 5.96 | 36.8 | 101 |
//!
//!   So x^268 is ~4·10⁻¹⁴ relative at worst — invisible in a BRDF, but not libm's 0.5 ulp; callers who want
//!   that lower [`Policy::max_chain`]. Below 2^−1022 (x^268 for x < 0.071) a chain through subnormal
//!   intermediates loses relative accuracy; the absolute error stays < 2^−1022.
//! - `pow(x, 0.5) → sqrt(x)` where x cannot be −0 or −inf: sqrt is correctly rounded; glibc's pow(x, 0.5)
//!   differs by 1 ulp on 81 of 10⁵ samples in [0, 1] and on 1 of the 1999 doubles below 1, sqrt always the
//!   closer (test `pow_half_vs_sqrt_differences` in `tests/it/simplify.rs`). ~7× faster. Fed into asin/acos
//!   near 1, that ulp becomes 1.5·10⁻⁸ absolute (asin(pow(1 − 2⁻⁵³, 0.5)): pow gives 1.0, sqrt the correctly
//!   rounded 1 − 2⁻⁵³).
//! - `a − a·x → a·(1 − x)` when a is finite and x ∈ [0, 1] (Schlick's `n − n·c`): 1 − x is exact for
//!   x ∈ [0.5, 1] (Sterbenz), so the product rounds once (≤ 0.5 ulp) where the original cancels. Measured
//!   (test `accuracy_factoring_near_one` in `tests/it/simplify.rs`, error in ulps of the exact a·(1 − x)):
//!
//!   | a | x range | a − a·x max / mean | a·(1 − x) max / mean |
//!   |---|---------|--------------------|----------------------|
//!   | 50 | [0.5, 1) | 16384 / 7.1 | 0.50 / 0.22 |
//!   | 50 | [0.99, 1) | 262144 / 232 | 0 / 0 |
//!   | 50 | [1 − 10⁻⁹, 1) | 3.8·10¹² / 2.6·10⁹ | 0 / 0 |
//!   | 268 | [0.99, 1) | 131072 / 321 | 0 / 0 |
//!   | 1000 | [1 − 10⁻⁹, 1) | 2.7·10¹¹ / 1.4·10⁹ | 0 / 0 |
//!
//!   (a = 1 is exact either way.) The one value it changes beyond rounding is the sign of a zero when a = −0.
//! - `sin(x) → sinnear(x)` where range analysis bounds |x| by 1.75 (F_kutlog's `sin(max(π/2 − arg, 0))`):
//!   one Taylor polynomial with −x³/6 in double-double instead of the reduction by π/2 and both kernels,
//!   within sin's bound (≤ 1 ulp of the truth measured, against sin's ≤ 1; 3.8 % of points 1 ulp off where sin
//!   has 2.0 %), 2.3× faster on the LLVM tier and on Cranelift.

pub mod accuracy;
pub mod derive;
pub(crate) mod rewrite;
pub(crate) mod emit;
mod powi;
pub(crate) mod range;

use crate::builtins::{math, Builtin};
use crate::base::span::Span;
use crate::ir::{BinOp, Formula, InputSet, Ir, Node, NodeId, ParamDecl};
use range::Range;
use std::collections::BTreeMap;
use std::fmt;

pub use powi::MAX_EXPONENT as MAX_POW_CHAIN;

/// Upper bound on rewrite passes; every pass so far converges in two (one that rewrites, one that confirms).
pub(crate) const MAX_PASSES: usize = 16;

/// What the simplifier may assume about run-time values, and whether it may change rounding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Policy {
    /// Inputs are never NaN (the kernel contract: callers pass cosines of unit vectors). Lets `NL*0` fold to 0
    /// so an input the formula only multiplies by zero disappears from the used-inputs set.
    pub inputs_not_nan: bool,
    /// Run-time parameter values lie in their declared `lo..hi` ranges (finite, never NaN).
    pub params_in_range: bool,
    /// Allow rewrites that may change the last bits of a value: integer `pow` as a multiplication chain,
    /// `pow(x, 0.5) → sqrt(x)`, `a − a·x → a·(1 − x)`, and sin of an argument range analysis bounds by 1.75
    /// without its reduction (`sinnear`). Each one that fires is listed in the [`Report`].
    pub rounding: bool,
    /// Largest |k| for which `pow(x, k)` becomes a multiplication chain (at most [`MAX_POW_CHAIN`]); the chain's
    /// error grows with k (≈ 0.1·k ulp mean, 0.7·k max, against libm's 0.5), so a caller that needs accuracy
    /// above speed can lower it. Only used when `rounding` is on.
    pub max_chain: u32,
}

impl Default for Policy {
    fn default() -> Policy {
        Policy { inputs_not_nan: true, params_in_range: true, rounding: true, max_chain: powi::MAX_EXPONENT }
    }
}

impl Policy {
    /// Only rewrites that are exact for every input bit pattern (NaN inputs and out-of-range parameters
    /// included): the simplified formula returns bit-identical results up to NaN payloads.
    pub fn exact() -> Policy {
        Policy { inputs_not_nan: false, params_in_range: false, rounding: false, max_chain: 0 }
    }
}

/// A rewrite that may change a value's rounding, with where it happened.
#[derive(Clone, Debug, PartialEq)]
pub struct RoundingChange {
    pub rule: &'static str,
    /// Span of the rewritten node in the source.
    pub span: Span,
    /// What changes, and the bound on how much.
    pub detail: String,
}

/// What the simplifier did, for `lobe check`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Report {
    /// Rewrite name → times it fired, summed over all passes.
    pub fired: BTreeMap<&'static str, usize>,
    /// Rewrites that may change a value's last bits (see [`Policy::rounding`]).
    pub rounding: Vec<RoundingChange>,
    /// Passes run, the confirming pass that changed nothing included.
    pub passes: usize,
    /// The pass cap was reached before a fixpoint (should not happen; reported rather than hidden).
    pub hit_cap: bool,
    pub nodes_before: usize,
    pub nodes_after: usize,
    pub inputs_before: InputSet,
    pub inputs_after: InputSet,
}

impl Report {
    /// How many times the rewrite `name` fired.
    pub fn count(&self, name: &str) -> usize {
        self.fired.get(name).copied().unwrap_or(0)
    }
    pub fn total(&self) -> usize {
        self.fired.values().sum()
    }
}

impl Report {
    /// The report with rounding notes located as `file:line:col` in `f`'s source (for `lobe check`).
    pub fn render(&self, f: &Formula) -> String {
        let mut out = self.to_string();
        for r in &self.rounding {
            let (line, col) = crate::base::span::line_col(&f.source, r.span.start as usize);
            let from = format!("at {}..{}", r.span.start, r.span.end);
            out = out.replacen(&from, &format!("at {}:{line}:{col}", f.file), 1);
        }
        out
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "simplified {} → {} nodes in {} pass{}{}; inputs used: {}{}",
            self.nodes_before,
            self.nodes_after,
            self.passes,
            if self.passes == 1 { "" } else { "es" },
            if self.hit_cap { " (pass cap reached)" } else { "" },
            if self.inputs_after.is_empty() { "none".to_string() } else { self.inputs_after.to_string() },
            if self.inputs_after != self.inputs_before {
                format!(" (was {})", self.inputs_before)
            } else {
                String::new()
            }
        )?;
        for (name, n) in &self.fired {
            writeln!(f, "  {name:<18} ×{n}")?;
        }
        for r in &self.rounding {
            writeln!(f, "  rounding: {} at {}..{}: {}", r.rule, r.span.start, r.span.end, r.detail)?;
        }
        Ok(())
    }
}

/// Replaces baked parameters by constants without any other rewrite.
pub fn bake_only(f: &Formula, bake: &[(usize, f64)]) -> Formula {
    let mut ir = crate::ir::Ir::new();
    let mut map = Vec::with_capacity(f.ir.len());
    for id in f.ir.ids() {
        let n = match *f.ir.node(id) {
            Node::Param(p) => match bake.iter().find(|(i, _)| *i == p as usize) {
                Some((_, v)) => Node::constant(*v),
                None => Node::Param(p),
            },
            n => n.map_args(|a| map[a.index()]),
        };
        map.push(ir.push(n, f.ir.span(id)));
    }
    let (ir, root) = ir.compact(map[f.root.index()]);
    if f.is_rgb() {
        return f.with_channels(&per_channel(f, |g| bake_only(g, bake)));
    }
    Formula { ir, root, ..f.clone() }
}

/// `op` on each colour channel of `f` (a colour formula): red, green, blue.
fn per_channel(f: &Formula, op: impl Fn(&Formula) -> Formula) -> [Formula; 3] {
    let c = f.channels();
    [op(&c[0]), op(&c[1]), op(&c[2])]
}

/// Simplifies with the default [`Policy`]; baked parameters (index, value) become constants first.
pub fn simplify(f: &Formula, bake: &[(usize, f64)]) -> Formula {
    simplify_with(f, bake, &Policy::default()).0
}

/// [`simplify`], and what it did.
pub fn simplify_report(f: &Formula, bake: &[(usize, f64)]) -> (Formula, Report) {
    simplify_with(f, bake, &Policy::default())
}

/// Simplifies under an explicit policy.
pub fn simplify_with(f: &Formula, bake: &[(usize, f64)], policy: &Policy) -> (Formula, Report) {
    let (mut ir, mut root) = f.ir.compact(f.root);
    let mut report = Report {
        nodes_before: ir.len(),
        inputs_before: ir.used_inputs(root),
        hit_cap: true,
        ..Report::default()
    };
    for _ in 0..MAX_PASSES {
        let mut rw = Rewriter::new(&f.params, bake, policy);
        let mut map: Vec<NodeId> = Vec::with_capacity(ir.len());
        for id in ir.ids() {
            let n = ir.node(id).map_args(|a| map[a.index()]);
            map.push(rw.node(n, ir.span(id)));
        }
        report.passes += 1;
        let fired: usize = rw.fired.values().sum();
        for (k, v) in rw.fired {
            *report.fired.entry(k).or_default() += v;
        }
        report.rounding.extend(rw.rounding);
        let (c, r) = rw.ir.compact(map[root.index()]);
        ir = c;
        root = r;
        if fired == 0 {
            report.hit_cap = false;
            break;
        }
    }
    report.nodes_after = ir.len();
    report.inputs_after = ir.used_inputs(root);
    let out = Formula { meta: f.meta.clone(), params: f.params.clone(), ir, root, file: f.file.clone(), source: f.source.clone(), rgb: None };
    if f.is_rgb() {
        // Each channel is simplified on its own; the report is the red channel's (the formula's own root).
        return (f.with_channels(&per_channel(f, |g| simplify_with(g, bake, policy).0)), report);
    }
    (out, report)
}

/// The sign of a formula's value by range analysis: what the accuracy pass must keep ([`keep_sign`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Sign {
    /// ≥ 0 (or NaN) everywhere.
    NonNeg,
    /// ≤ 0 (or NaN) everywhere.
    NonPos,
    Any,
}

/// The sign of `f` as written with `bake` folded (range analysis of the unsimplified formula: a clamp, a
/// square or a pow of a clamped base bound it even where the simplifier later drops the clamp as redundant).
pub(crate) fn sign_of(f: &Formula, bake: &[(usize, f64)]) -> Sign {
    range_sign(&bake_only(f, bake))
}

/// The sign of `g` by range analysis as it stands ([`sign_of`] once the values are baked).
pub(crate) fn range_sign(g: &Formula) -> Sign {
    let r = node_ranges(g, &Policy::default())[g.root.index()];
    if r.lo >= 0.0 {
        Sign::NonNeg
    } else if r.hi <= 0.0 {
        Sign::NonPos
    } else {
        Sign::Any
    }
}

/// `g` with its result clamped at 0 (`max`/`min`, which keep NaN) where `sign` bounds it and `g`'s own range
/// analysis does not: a rewrite moves roundings, never the sign (a compensated correction below a cut-off once
/// went below 0). Costs one node where it applies; nothing where the range already shows the sign.
pub(crate) fn keep_sign(sign: &Sign, g: Formula) -> Formula {
    let r = node_ranges(&g, &Policy::default())[g.root.index()];
    let (b, bad) = match sign {
        Sign::NonNeg => (Builtin::Max, r.lo < 0.0),
        Sign::NonPos => (Builtin::Min, r.hi > 0.0),
        Sign::Any => return g,
    };
    if !bad {
        return g;
    }
    let mut g = g;
    let sp = g.ir.span(g.root);
    let zero = g.ir.konst(0.0, sp);
    g.root = g.ir.call(b, &[g.root, zero], sp);
    g
}

/// The range of every node of `f` under `policy`, computed without rewriting (what the accuracy pass's
/// guards read). `f`'s arena is hash-consed, so its ids are kept.
pub(crate) fn node_ranges(f: &Formula, policy: &Policy) -> Vec<Range> {
    let mut rw = Rewriter::new(&f.params, &[], policy);
    for id in f.ir.ids() {
        rw.push(*f.ir.node(id), f.ir.span(id));
    }
    rw.ranges
}

/// One pass: builds a fresh arena bottom-up, rewriting each node as it is added.
struct Rewriter<'a> {
    ir: Ir,
    ranges: Vec<Range>,
    params: &'a [ParamDecl],
    bake: &'a [(usize, f64)],
    policy: &'a Policy,
    fired: BTreeMap<&'static str, usize>,
    rounding: Vec<RoundingChange>,
}

/// `Some(x)` if `id` is `Neg(x)`.
fn as_neg(ir: &Ir, id: NodeId) -> Option<NodeId> {
    match ir.node(id) {
        Node::Neg(x) => Some(*x),
        _ => None,
    }
}

/// Values in `ra` are ≤ those in `rb`, so `min(a, b)` returns `a` bit for bit (`b` never NaN; at a tie at zero
/// `b` is +0, and min(±0, +0) is the first).
fn min_first(ra: Range, rb: Range) -> bool {
    !rb.nan && ra.hi <= rb.lo && (ra.hi < 0.0 || rb.lo > 0.0 || !rb.negz)
}

/// `c` is ±2^e with 1/c also normal, so `x / c` and `x * (1/c)` round identically.
fn exact_reciprocal(c: f64) -> bool {
    c.is_normal() && (1.0 / c).is_normal() && c.to_bits() & ((1u64 << 52) - 1) == 0
}

impl<'a> Rewriter<'a> {
    fn new(params: &'a [ParamDecl], bake: &'a [(usize, f64)], policy: &'a Policy) -> Rewriter<'a> {
        Rewriter { ir: Ir::new(), ranges: vec![], params, bake, policy, fired: BTreeMap::new(), rounding: vec![] }
    }

    /// Adds `n` without rewriting it, computing its range.
    fn push(&mut self, n: Node, span: Span) -> NodeId {
        let id = self.ir.push(n, span);
        if id.index() == self.ranges.len() {
            let r = self.range_of(&n);
            self.ranges.push(r);
        }
        id
    }

    fn range_of(&self, n: &Node) -> Range {
        let r = |id: NodeId| self.ranges[id.index()];
        match *n {
            Node::Const(b) => Range::constant(f64::from_bits(b)),
            Node::Input(_) => Range { nan: !self.policy.inputs_not_nan, ..Range::TOP },
            Node::Column(_) => Range::TOP,
            Node::Param(p) => match self.params.get(p as usize) {
                Some(d) if self.policy.params_in_range => Range::new(d.lo, d.hi, false, d.lo <= 0.0),
                _ => Range::TOP,
            },
            Node::Neg(a) => -r(a),
            Node::Binary(op, a, b) => match op {
                BinOp::Add => r(a) + r(b),
                BinOp::Sub => r(a) - r(b),
                BinOp::Mul if a == b => r(a).square(),
                BinOp::Mul => r(a) * r(b),
                BinOp::Div => r(a) / r(b),
            },
            Node::Call(f, args) => {
                let k = f.arity();
                let rs: Vec<Range> = args[..k].iter().map(|a| r(*a)).collect();
                let cs: Vec<Option<f64>> = args[..k].iter().map(|a| self.konst(*a)).collect();
                Range::call(f, &rs, &cs)
            }
        }
    }

    fn range(&self, id: NodeId) -> Range {
        self.ranges[id.index()]
    }
    fn konst(&self, id: NodeId) -> Option<f64> {
        self.ir.node(id).as_const()
    }
    fn is_const(&self, id: NodeId, v: f64) -> bool {
        self.konst(id).is_some_and(|c| c.to_bits() == v.to_bits())
    }
    fn fire(&mut self, rule: &'static str) {
        *self.fired.entry(rule).or_default() += 1;
    }
    fn note(&mut self, rule: &'static str, span: Span, detail: String) {
        self.rounding.push(RoundingChange { rule, span, detail });
    }

    /// Adds `n` (operands already in this arena), rewritten to normal form; the result keeps `span`.
    fn node(&mut self, n: Node, span: Span) -> NodeId {
        match self.rewrite(n, span) {
            Some(id) => id,
            None => self.push(n, span),
        }
    }

    fn konst_node(&mut self, v: f64, span: Span) -> NodeId {
        self.push(Node::constant(v), span)
    }
    fn neg(&mut self, a: NodeId, span: Span) -> NodeId {
        self.node(Node::Neg(a), span)
    }
    fn bin(&mut self, op: BinOp, a: NodeId, b: NodeId, span: Span) -> NodeId {
        self.node(Node::Binary(op, a, b), span)
    }
    fn call(&mut self, f: Builtin, args: &[NodeId], span: Span) -> NodeId {
        let mut a = [args[0]; 3];
        a[..args.len()].copy_from_slice(args);
        self.node(Node::Call(f, a), span)
    }

    /// `a ≥ b` for every pair of values, with `max(a, b)` then returning `a` bit for bit (b never NaN).
    fn max_is_first(&self, a: NodeId, b: NodeId) -> bool {
        let (ra, rb) = (self.range(a), self.range(b));
        !rb.nan && ra.lo >= rb.hi && (ra.lo > 0.0 || rb.hi < 0.0 || !ra.negz)
    }
    /// `a ≤ b` for every pair, with `min(a, b)` then returning `a` bit for bit (b never NaN).
    fn min_is_first(&self, a: NodeId, b: NodeId) -> bool {
        min_first(self.range(a), self.range(b))
    }

    /// One rewrite of `n`, or `None` if no rule applies. Each rule is introduced by its pattern.
    fn rewrite(&mut self, n: Node, span: Span) -> Option<NodeId> {
        match n {
            // param p with a baked value → constant
            Node::Param(p) => {
                let v = self.bake.iter().find(|(i, _)| *i == p as usize)?.1;
                self.fire("bake");
                Some(self.konst_node(v, span))
            }
            Node::Const(_) | Node::Input(_) | Node::Column(_) => None,
            Node::Neg(a) => {
                // -c → constant
                if let Some(c) = self.konst(a) {
                    self.fire("const-fold");
                    return Some(self.konst_node(-c, span));
                }
                // -(-x) → x
                let x = as_neg(&self.ir, a)?;
                self.fire("neg-neg");
                Some(x)
            }
            Node::Binary(op, a, b) => self.rewrite_binary(op, a, b, span),
            Node::Call(f, args) => {
                let k = f.arity();
                // f(c1, c2, …) → constant, through the builtins table (the backends' own functions)
                let cs: Option<Vec<f64>> = args[..k].iter().map(|a| self.konst(*a)).collect();
                if let Some(cs) = cs {
                    self.fire("const-fold");
                    return Some(self.konst_node(f.eval(&cs), span));
                }
                self.rewrite_call(f, args, span)
            }
        }
    }

    fn rewrite_binary(&mut self, op: BinOp, a: NodeId, b: NodeId, span: Span) -> Option<NodeId> {
        let (ca, cb) = (self.konst(a), self.konst(b));
        // c1 op c2 → constant
        if let (Some(x), Some(y)) = (ca, cb) {
            self.fire("const-fold");
            return Some(self.konst_node(op.apply(x, y), span));
        }
        let (ra, rb) = (self.range(a), self.range(b));
        match op {
            BinOp::Add => {
                // x + (-0) → x, (-0) + x → x   (exact for every x: -0 is the additive identity)
                if self.is_const(b, -0.0) {
                    self.fire("add-zero");
                    return Some(a);
                }
                if self.is_const(a, -0.0) {
                    self.fire("add-zero");
                    return Some(b);
                }
                // x + 0 → x, 0 + x → x   only when x cannot be -0 (-0 + 0 = +0)
                if self.is_const(b, 0.0) && !ra.negz {
                    self.fire("add-zero");
                    return Some(a);
                }
                if self.is_const(a, 0.0) && !rb.negz {
                    self.fire("add-zero");
                    return Some(b);
                }
                // a + (-b) → a - b
                if let Some(nb) = as_neg(&self.ir, b) {
                    self.fire("add-neg");
                    return Some(self.bin(BinOp::Sub, a, nb, span));
                }
                // (-a) + b → b - a
                if let Some(na) = as_neg(&self.ir, a) {
                    self.fire("add-neg");
                    return Some(self.bin(BinOp::Sub, b, na, span));
                }
                None
            }
            BinOp::Sub => {
                // x - 0 → x   (exact: -0 - 0 = -0)
                if self.is_const(b, 0.0) {
                    self.fire("sub-zero");
                    return Some(a);
                }
                // (-0) - x → -x   (exact, zero signs included)
                if self.is_const(a, -0.0) {
                    self.fire("sub-zero");
                    return Some(self.neg(b, span));
                }
                // a - (-b) → a + b
                if let Some(nb) = as_neg(&self.ir, b) {
                    self.fire("sub-neg");
                    return Some(self.bin(BinOp::Add, a, nb, span));
                }
                // x - x → 0   only when x is finite (inf - inf and NaN - NaN are NaN); x - x is +0 in RN
                if a == b && ra.finite() {
                    self.fire("sub-self");
                    return Some(self.konst_node(0.0, span));
                }
                // a - a*x → a*(1 - x)   when a is finite and x in [0, 1]: avoids the cancellation near x = 1
                // (1 - x is exact for x in [0.5, 1] by Sterbenz); changes rounding (more accurate)
                if self.policy.rounding && ra.lo.is_finite() && ra.hi.is_finite() {
                    if let Node::Binary(BinOp::Mul, p, q) = *self.ir.node(b) {
                        let x = if p == a { Some(q) } else if q == a { Some(p) } else { None };
                        if let Some(x) = x.filter(|x| self.range(*x).within(0.0, 1.0)) {
                            self.fire("factor-1-minus-x");
                            self.note(
                                "factor-1-minus-x",
                                span,
                                "a - a*x computed as a*(1 - x): at most 1 rounding instead of a cancelling \
                                 subtraction near x = 1 (more accurate; zero may change sign)"
                                    .into(),
                            );
                            let one = self.konst_node(1.0, span);
                            let d = self.bin(BinOp::Sub, one, x, span);
                            return Some(self.bin(BinOp::Mul, a, d, span));
                        }
                    }
                }
                None
            }
            BinOp::Mul => {
                // x*1 → x, 1*x → x
                if self.is_const(b, 1.0) {
                    self.fire("mul-one");
                    return Some(a);
                }
                if self.is_const(a, 1.0) {
                    self.fire("mul-one");
                    return Some(b);
                }
                // x*(-1) → -x, (-1)*x → -x
                if self.is_const(b, -1.0) {
                    self.fire("mul-minus-one");
                    return Some(self.neg(a, span));
                }
                if self.is_const(a, -1.0) {
                    self.fire("mul-minus-one");
                    return Some(self.neg(b, span));
                }
                // x*(±0) → ±0   only when x is finite (0*inf = NaN) and its sign is known
                for (z, rx) in [(cb, ra), (ca, rb)] {
                    if let Some(z) = z.filter(|z| *z == 0.0) {
                        if rx.finite() && (rx.nonneg() || rx.hi < 0.0) {
                            let neg = z.is_sign_negative() != (rx.hi < 0.0);
                            self.fire("mul-zero");
                            return Some(self.konst_node(if neg { -0.0 } else { 0.0 }, span));
                        }
                    }
                }
                // (-a)*(-b) → a*b
                if let (Some(na), Some(nb)) = (as_neg(&self.ir, a), as_neg(&self.ir, b)) {
                    self.fire("neg-neg");
                    return Some(self.bin(BinOp::Mul, na, nb, span));
                }
                None
            }
            BinOp::Div => {
                if let Some(c) = cb {
                    // x/1 → x
                    if c == 1.0 {
                        self.fire("div-one");
                        return Some(a);
                    }
                    // x/(-1) → -x
                    if c == -1.0 {
                        self.fire("div-minus-one");
                        return Some(self.neg(a, span));
                    }
                    // x/c → x*(1/c)   only when c = ±2^e and 1/c is normal, so both round the same
                    if exact_reciprocal(c) {
                        self.fire("div-pow2");
                        let r = self.konst_node(1.0 / c, span);
                        return Some(self.bin(BinOp::Mul, a, r, span));
                    }
                }
                // x/x → 1   only when x is finite and non-zero (0/0, inf/inf and NaN/NaN are NaN)
                if a == b && ra.finite() && ra.excludes_zero() {
                    self.fire("div-self");
                    return Some(self.konst_node(1.0, span));
                }
                // 0/x → 0   when x is a non-zero number with a clear sign bit (0/inf = 0 too)
                if self.is_const(a, 0.0) && !rb.nan && rb.nonneg() && rb.excludes_zero() {
                    self.fire("zero-div");
                    return Some(a);
                }
                None
            }
        }
    }

    fn rewrite_call(&mut self, f: Builtin, args: [NodeId; 3], span: Span) -> Option<NodeId> {
        let [a, b, c] = args;
        match f {
            Builtin::Pow => self.rewrite_pow(a, b, span),
            // sin(x) → sinnear(x)   when range analysis bounds |x| by 1.75: no reduction by π/2 and one
            // kernel instead of two (the same stated bound; lanes beyond it, which the range excludes, would be
            // sin's anyway)
            Builtin::Sin => {
                let r = self.range(a);
                if !self.policy.rounding || r.lo < -math::SIN_NEAR_MAX || r.hi > math::SIN_NEAR_MAX {
                    return None;
                }
                self.fire("sin-near");
                self.note("sin-near", span, format!("sin(x) for |x| ≤ {}: one polynomial without reduction (within sin's bound)", math::SIN_NEAR_MAX));
                Some(self.call(Builtin::SinNear, &[a], span))
            }
            Builtin::Abs => {
                // abs(-x) → abs(x)
                if let Some(x) = as_neg(&self.ir, a) {
                    self.fire("abs-neg");
                    return Some(self.call(Builtin::Abs, &[x], span));
                }
                // abs(abs(x)) → abs(x)
                if matches!(self.ir.node(a), Node::Call(Builtin::Abs, _)) {
                    self.fire("abs-abs");
                    return Some(a);
                }
                // abs(x) → x   when every value of x has a clear sign bit
                if self.range(a).nonneg() {
                    self.fire("abs-nonneg");
                    return Some(a);
                }
                None
            }
            Builtin::Min | Builtin::Max => {
                // min(x, x) → x, max(x, x) → x
                if a == b {
                    self.fire("minmax-same");
                    return Some(a);
                }
                let first = |s: &Self, x, y| if f == Builtin::Max { s.max_is_first(x, y) } else { s.min_is_first(x, y) };
                // max(a, b) → a   when a ≥ b always and b is never NaN (range); e.g. the root max(raw, 0)
                // min(a, b) → a   likewise
                if first(self, a, b) {
                    self.fire(if f == Builtin::Max { "max-redundant" } else { "min-redundant" });
                    return Some(a);
                }
                if first(self, b, a) {
                    self.fire(if f == Builtin::Max { "max-redundant" } else { "min-redundant" });
                    return Some(b);
                }
                None
            }
            Builtin::Clamp => {
                // clamp(x, lo, hi) = min(max(x, lo), hi)
                let lo_ok = self.max_is_first(a, b);
                // clamp(x, lo, hi) → x   when x is provably in [lo, hi] (NaN passes through either way)
                if lo_ok && self.min_is_first(a, c) {
                    self.fire("clamp-redundant");
                    return Some(a);
                }
                // clamp(x, lo, hi) → min(x, hi)   when x ≥ lo always
                if lo_ok {
                    self.fire("clamp-redundant");
                    return Some(self.call(Builtin::Min, &[a, c], span));
                }
                // clamp(x, lo, hi) → max(x, lo)   when max(x, lo) ≤ hi always (hi never NaN; lo may exceed x)
                if min_first(self.range(a).max(self.range(b)), self.range(c)) {
                    self.fire("clamp-redundant");
                    return Some(self.call(Builtin::Max, &[a, b], span));
                }
                None
            }
            Builtin::Acos | Builtin::Asin => {
                // acos(clamp(x, lo, hi)) → acos(x)   when lo ≤ -1 and hi ≥ 1: the builtin clamps to [-1, 1] itself
                if let Node::Call(Builtin::Clamp, [x, lo, hi]) = *self.ir.node(a) {
                    if self.konst(lo).is_some_and(|l| l <= -1.0) && self.konst(hi).is_some_and(|h| h >= 1.0) {
                        self.fire("trig-clamp");
                        return Some(self.call(f, &[x], span));
                    }
                }
                None
            }
            _ => None,
        }
    }

    fn rewrite_pow(&mut self, x: NodeId, e: NodeId, span: Span) -> Option<NodeId> {
        let k = self.konst(e)?;
        // pow(x, 1) → x   (exact: pow(x, 1) = x for every x, NaN included)
        if k == 1.0 {
            self.fire("pow-one");
            return Some(x);
        }
        // pow(x, 0) → 1   (exact: C99 F.9.4.4 and IEEE 754 pown/pow give 1 for every x, NaN included)
        if k == 0.0 {
            self.fire("pow-zero");
            return Some(self.konst_node(1.0, span));
        }
        if !self.policy.rounding {
            return None;
        }
        let rx = self.range(x);
        // pow(x, 0.5) → sqrt(x)   except at -0 (pow: +0, sqrt: -0) and -inf (pow: +inf, sqrt: NaN)
        if k == 0.5 && !rx.negz && rx.lo > f64::NEG_INFINITY {
            self.fire("pow-half");
            self.note("pow-half", span, "pow(x, 0.5) as sqrt(x): sqrt is correctly rounded, libm pow within 1 ulp".into());
            return Some(self.call(Builtin::Sqrt, &[x], span));
        }
        // pow(x, k) → multiplication chain for integer 2 ≤ |k| ≤ 1024; negative k → 1/x^|k|
        if k.fract() == 0.0 && k.abs() <= f64::from(self.policy.max_chain.min(powi::MAX_EXPONENT)) {
            let m = k.abs() as u32;
            let mut pows: Vec<(u32, NodeId)> = vec![(1, x)];
            for (p, q) in powi::steps(m) {
                let find = |pows: &[(u32, NodeId)], e: u32| pows.iter().find(|(k, _)| *k == e).map(|(_, id)| *id);
                let (Some(u), Some(v)) = (find(&pows, p), find(&pows, q)) else { return None };
                let w = self.bin(BinOp::Mul, u, v, span);
                pows.push((p + q, w));
            }
            let mut r = pows.last().map(|(_, id)| *id)?;
            if k < 0.0 {
                let one = self.konst_node(1.0, span);
                r = self.bin(BinOp::Div, one, r, span);
            }
            self.fire("pow-int");
            let detail = if m <= 2 {
                // x*x, 1/x and 1/(x*x) (two roundings) are as accurate as libm pow's own < 1 ulp.
                let form = match (m, k < 0.0) {
                    (1, _) => "1/x",
                    (_, false) => "x*x",
                    (_, true) => "1/(x*x)",
                };
                format!("pow(x, {k}) as {form}: correctly rounded per operation, like libm pow")
            } else {
                format!(
                    "pow(x, {k}) as {} multiplications{}: relative error ≤ {}u (u = 2^-53) vs libm pow's ≤ 0.5 ulp",
                    powi::cost(m),
                    if k < 0.0 { " and a division" } else { "" },
                    m - 1 + u32::from(k < 0.0),
                )
            };
            self.note("pow-int", span, detail);
            return Some(r);
        }
        None
    }
}

#[cfg(test)]
mod tests;
