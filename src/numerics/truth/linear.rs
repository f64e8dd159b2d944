//! The truth's condition to first order, with a bound on the rest: at one point, how many ulps of the truth a
//! 1-ulp move of each read input and each live parameter moves it by, from one pass that carries beside every
//! node's exact value its change per variable (forward-mode derivatives times the variable's ulp) and a bound on
//! how far the node's actual change under that move can be from it (the second-order terms), instead of one
//! evaluation per move ([`super::eval_moves_with`]). What [`crate::numerics::robust`] reads to classify a
//! point (κ ≤ 16 or not) without moving anything where the answer is clear.
//!
//! The changes are computed from the exact node values (the truth's, not f64-rounded ones), in f64 with each
//! node's change scaled by that node's binary exponent, so nothing overflows or underflows where the truth's
//! unbounded exponent does not. The bound is exact algebra for `+ − × ÷` (a product's `Δa·Δb`, a quotient's
//! remainder) and a bound on the second derivative over the move for the functions, valid while the move
//! changes their argument by at most 2⁻⁶ (relatively for `ln`, `sqrt`, `pow`'s base; absolutely for `exp`,
//! `sin`, `cos`, `atan`; for `tan`, by at most 2⁻⁶/(1 + |tan|)). Where the first order and its bound do not describe a move, the variable is marked
//! *unsure*, for the caller to move exactly:
//! - a step within reach: a comparison, `floor` or a select's condition whose result the move may change (the
//!   distance to the step within the change and its bound, plus the operands' ulps where they are rounded: the
//!   truth decides steps on f64s). (Where a move may swap the sides of a `min`, `max`, `clamp` or `abs`, the
//!   function is continuous: the change lies between the two sides' changes, which the bound takes in.)
//! - a kink or an infinite slope at the point: `sqrt` or `pow` of an exact 0, `asin`/`acos` at ±1;
//! - a move too large for the bounds above, a non-finite node (a pole, 0/0), a cancellation of more than 1000
//!   binades, a change that does not fit an f64, and `expmuldiv` (which the accuracy pass writes, not users).
//!
//! A node's marks reach the nodes that read it, except through the side of a select, `min` or `max` that is not
//! taken (unless the move may swap the sides, which marks the variable anyway).

use super::{ldexp, node_value, Readers, Xf};
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, Node, N_INPUTS};

/// The largest change of a function's argument the second-derivative bounds allow (module docs).
const SMALL: f64 = 1.0 / 64.0;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Var {
    Input(usize),
    Param(usize),
}

/// A formula's first-order condition (module docs), set up once per formula: its variables (the read inputs,
/// then the parameters it reads, in [`Readers`]' order) and the variables each node depends on.
pub(crate) struct Linear {
    vars: Vec<Var>,
    deps: Vec<u64>,
    /// Each constant node's exact value (zero at the other nodes), converted once instead of at every point.
    consts: Vec<Xf>,
}

/// The buffers [`Linear::eval`] works in, kept from one point to the next (one per thread): the nodes' exact
/// values, their per-node state, their rows of changes and bounds.
#[derive(Default)]
pub(crate) struct Scratch {
    vals: Vec<Xf>,
    at: Vec<At>,
    rows: Vec<f64>,
    bounds: Vec<f64>,
}

impl Scratch {
    /// The exact value of every node at the last point [`Linear::eval`] was given (for
    /// [`super::eval_moves_from`]).
    pub(crate) fn values(&self) -> &[Xf] {
        &self.vals
    }
}

/// The first-order condition at one point.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Estimate {
    /// Per variable, in [`Linear`]'s order: bounds on what the exact condition over that variable is (the
    /// larger of the two 1-ulp moves, in ulps of the truth: [`crate::numerics::robust::condition_ulps`]'s
    /// count), from the first-order change and its bound, the spacing of the f64s the change spans, and one
    /// ulp of rounding at each end (two where the truth is subnormal, which rounds twice). `(0, 0)` for a
    /// variable that is not moved (an input or parameter at 0).
    pub ulps: Vec<(f64, f64)>,
    /// The variables the first order and its bound do not describe (bit k for variable k; module docs).
    pub unsure: u64,
}

/// 2^k as an f64: 0 below the subnormals, ∞ above the largest power.
fn p2(k: i64) -> f64 {
    if k > 1023 {
        f64::INFINITY
    } else if k >= -1022 {
        f64::from_bits(((k + 1023) as u64) << 52)
    } else if k >= -1074 {
        f64::from_bits(1u64 << (k + 1074))
    } else {
        0.0
    }
}

/// The larger of the steps to the f64 neighbours of `x` (finite).
fn step(x: f64) -> f64 {
    (x.next_up() - x).max(x - x.next_down())
}

/// The spacing of the f64s at and above |y| within its binade (2⁻¹⁰⁷⁴ for subnormals; ∞ past the largest).
fn spacing(y: f64) -> f64 {
    let y = y.abs();
    if y < f64::MIN_POSITIVE {
        return 5e-324;
    }
    if !y.is_finite() {
        return f64::INFINITY;
    }
    p2(((y.to_bits() >> 52) as i64 - 1023) - 52)
}

/// Bounds on the ulps between the truth `t` and the truth after a change of at least `lo` and at most `hi`
/// (absolute): the count runs over the f64s between, whose spacing is at least that at |t| − hi and at most
/// that at |t| + hi; each end rounds by at most an ulp (twice for a subnormal).
fn count(t: f64, lo: f64, hi: f64) -> (f64, f64) {
    let (fine, coarse) = (spacing((t.abs() - hi).max(0.0)), spacing(t.abs() + hi));
    let ends = if t.abs() < f64::MIN_POSITIVE { 3.0 } else { 2.0 };
    // The first order is computed in f64 over many nodes: a relative margin far above its rounding.
    ((lo * (1.0 - 1e-9) / coarse - ends).max(0.0), hi * (1.0 + 1e-9) / fine + ends)
}

impl Xf {
    /// The mantissa in [1, 2) with its sign; 0 for zero (special values are never read here).
    fn mant(self) -> f64 {
        self.hi
    }
    /// Finite and not zero.
    fn is_regular(self) -> bool {
        !self.is_special()
    }
    fn is_infinite_or_nan(self) -> bool {
        self.is_special() && !self.is_zero()
    }
    /// `self·2^-k` rounded to f64.
    fn scaled(self, k: i64) -> f64 {
        if self.is_special() {
            return self.hi;
        }
        Xf { e: self.e.saturating_sub(k), ..self }.to_f64()
    }
}

/// Per-node state of the pass: the exponent a node's changes are scaled by, the variables it is unsure of,
/// and whether every value it takes under a move is an f64 (an input, a parameter, a constant).
#[derive(Clone, Copy)]
struct At {
    e: i64,
    unsure: u64,
    exact: bool,
}

/// A node's change per variable and its bound, both scaled by 2^-e of the node: `W` entries, the variables
/// rounded up to a fixed width (8, 16, 32 or 64) so that arithmetic over a whole row is straight vector code;
/// 0 past the variables and outside the node's own.
#[derive(Clone, Copy)]
struct Rows<'a, const W: usize> {
    d: &'a [f64; W],
    b: &'a [f64; W],
}

impl<const W: usize> Rows<'_, W> {
    /// |change| + bound for variable `j`: the largest actual change.
    fn max(&self, j: usize) -> f64 {
        self.d[j].abs() + self.b[j]
    }
}

impl Linear {
    pub(crate) fn new(f: &Formula, readers: &Readers) -> Option<Linear> {
        let vars: Vec<Var> = readers.used.iter().map(|i| Var::Input(i.index())).chain(readers.params().map(Var::Param)).collect();
        if vars.len() > 64 {
            return None;
        }
        let bit = |v: Var| vars.iter().position(|&w| w == v).map_or(0, |k| 1u64 << k);
        let n = f.root.index() + 1;
        let mut deps: Vec<u64> = Vec::with_capacity(n);
        for id in f.ir.ids().take(n) {
            let node = f.ir.node(id);
            let mut m = match *node {
                Node::Input(i) => bit(Var::Input(i.index())),
                Node::Param(p) => bit(Var::Param(usize::from(p))),
                _ => 0,
            };
            node.for_each_arg(|a| m |= deps[a.index()]);
            deps.push(m);
        }
        let consts = f.ir.ids().take(n).map(|id| if let Node::Const(b) = *f.ir.node(id) { Xf::from_f64(f64::from_bits(b)) } else { Xf::ZERO }).collect();
        Some(Linear { vars, deps, consts })
    }

    /// Every variable (bit k for variable k).
    pub(crate) fn all(&self) -> u64 {
        if self.vars.len() == 64 {
            u64::MAX
        } else {
            (1u64 << self.vars.len()) - 1
        }
    }

    /// The truth of `f` at (`x`, `params`) rounded to f64 (as [`super::eval`]) and its first-order condition
    /// there (module docs), in one pass, working in `scratch`, which keeps the exact value of every node
    /// ([`Scratch::values`]).
    pub(crate) fn eval(&self, f: &Formula, x: &[f64; N_INPUTS], params: &[f64], scratch: &mut Scratch) -> (f64, Estimate) {
        match self.vars.len() {
            0..=8 => self.eval_in::<8>(f, x, params, scratch),
            9..=16 => self.eval_in::<16>(f, x, params, scratch),
            17..=32 => self.eval_in::<32>(f, x, params, scratch),
            _ => self.eval_in::<64>(f, x, params, scratch),
        }
    }

    /// [`Linear::eval`] with rows `W` wide (at least the count of variables).
    fn eval_in<const W: usize>(&self, f: &Formula, x: &[f64; N_INPUTS], params: &[f64], scratch: &mut Scratch) -> (f64, Estimate) {
        let n = f.root.index() + 1;
        let nv = self.vars.len();
        let xs = x.map(Xf::from_f64);
        let Scratch { vals, at, rows, bounds } = scratch;
        vals.clear();
        at.clear();
        // Row k (W entries) is node k's change per variable, times 2^-e of node k; 0 outside its deps (each row is
        // cleared when its node is reached). The bounds likewise.
        for r in [&mut *rows, &mut *bounds] {
            if r.len() < n * W {
                r.resize(n * W, 0.0);
            }
        }
        let (rows, _) = rows.as_chunks_mut::<W>();
        let (bounds, _) = bounds.as_chunks_mut::<W>();
        for id in f.ir.ids().take(n) {
            let k = id.index();
            let value = if let Node::Const(_) = f.ir.node(id) { self.consts[k] } else { node_value(f, id, vals, &xs, params) };
            vals.push(value);
            let dm = self.deps[k];
            let own = |default: i64| if value.is_regular() { value.e } else { default };
            let node = *f.ir.node(id);
            let exact = matches!(node, Node::Input(_) | Node::Param(_) | Node::Const(_)) || matches!(node, Node::Neg(a) if at[a.index()].exact);
            let (done_d, cur_d) = rows.split_at_mut(k);
            let (done_b, cur_b) = bounds.split_at_mut(k);
            let (cur_d, cur_b) = (&mut cur_d[0], &mut cur_b[0]);
            *cur_d = [0.0; W];
            *cur_b = [0.0; W];
            if dm == 0 {
                at.push(At { e: own(0), unsure: 0, exact });
                continue;
            }
            let mut unsure: u64 = 0;
            node.for_each_arg(|a| unsure |= at[a.index()].unsure);
            if value.is_infinite_or_nan() {
                // A pole or 0/0 on the way: nothing first-order about it.
                at.push(At { e: 0, unsure: unsure | dm, exact });
                continue;
            }
            let of = |a: usize| Rows { d: &done_d[a], b: &done_b[a] };
            let e = match node {
                Node::Input(_) | Node::Param(_) => {
                    let (var, v) = match node {
                        Node::Input(i) => (Var::Input(i.index()), x[i.index()]),
                        Node::Param(p) => (Var::Param(usize::from(p)), params.get(usize::from(p)).copied().unwrap_or(f64::NAN)),
                        _ => unreachable!(),
                    };
                    if let Some(j) = self.vars.iter().position(|&w| w == var) {
                        if v != 0.0 && v.is_finite() {
                            cur_d[j] = ldexp(step(v), -value.e);
                        }
                    }
                    own(0)
                }
                Node::Const(_) | Node::Column(_) => own(0),
                Node::Neg(a) => {
                    combine(cur_d, cur_b, dm, &[(of(a.index()), -1.0)]);
                    at[a.index()].e
                }
                Node::Binary(op, a, b) => {
                    let (a, b) = (a.index(), b.index());
                    let (va, vb, ea, eb) = (vals[a], vals[b], at[a].e, at[b].e);
                    let (ra, rb) = (of(a), of(b));
                    match op {
                        BinOp::Add | BinOp::Sub => {
                            let e = own(ea.max(eb));
                            if ea - e > 1000 || eb - e > 1000 {
                                unsure |= nonzero(ra.d, dm) | nonzero(rb.d, dm);
                            }
                            let sign = if op == BinOp::Sub { -1.0 } else { 1.0 };
                            combine(cur_d, cur_b, dm, &[(ra, p2(ea - e)), (rb, sign * p2(eb - e))]);
                            e
                        }
                        BinOp::Mul => {
                            let e = own(ea + eb);
                            product(cur_d, cur_b, dm, (va, ra), (vb, rb), p2(ea + eb - e));
                            e
                        }
                        BinOp::Div => {
                            let e = own(ea - eb);
                            let s = p2(ea - eb - e);
                            let (ma, mb) = (va.mant(), vb.mant());
                            combine(cur_d, cur_b, dm, &[(ra, s / mb), (rb, -ma * s / (mb * mb))]);
                            // (a + α)/(b + β) − a/b − (α/b − aβ/b²) = −(αb − aβ)β/(b²(b + β)).
                            // Only where β ≠ 0 (elsewhere the term is 0).
                            for j in bits(dm & (nonzero(rb.d, dm) | nonzero(rb.b, dm))) {
                                let (alpha, beta) = (ra.max(j), rb.max(j));
                                let rho = beta / mb.abs();
                                unsure |= u64::from(rho.is_nan() || rho > 0.5) << j;
                                cur_b[j] += s * (alpha * beta / (mb * mb) + ma.abs() * beta * beta / (mb * mb * mb).abs()) / (1.0 - rho);
                            }
                            e
                        }
                    }
                }
                Node::Call(b, args) => {
                    let ix = |i: usize| args[i].index();
                    let a = ix(0);
                    let (va, ea, ra) = (vals[a], at[a].e, of(a));
                    match b {
                        Builtin::Sqrt => {
                            if va.is_zero() {
                                unsure |= nonzero(ra.d, dm);
                                ea / 2
                            } else {
                                let e = own(0);
                                let s = p2(ea - 2 * e);
                                let (mv, ma) = (value.mant(), va.mant());
                                combine(cur_d, cur_b, dm, &[(ra, s / (2.0 * mv))]);
                                // |sqrt''| = 1/(4·a^(3/2)) ≤ 1.025/(4·v·a) while the argument moves by ≤ 2⁻⁶.
                                for j in bits(dm) {
                                    let m = ra.max(j);
                                    unsure |= over(m / ma, j);
                                    cur_b[j] += 0.5 * 1.025 / 4.0 * m * m * s / (mv * ma);
                                }
                                e
                            }
                        }
                        Builtin::Exp => {
                            let e = own(0);
                            let (mv, s) = (value.mant(), p2(ea));
                            combine(cur_d, cur_b, dm, &[(ra, mv * s)]);
                            // exp'' = exp ≤ 1.016·value while the argument moves by ≤ 2⁻⁶.
                            for j in bits(dm) {
                                let m = ra.max(j) * s;
                                unsure |= over(m, j);
                                cur_b[j] += 0.5 * 1.016 * mv * m * m;
                            }
                            e
                        }
                        Builtin::Ln => {
                            let e = own(0);
                            let (ma, s) = (va.mant(), p2(-e));
                            combine(cur_d, cur_b, dm, &[(ra, s / ma)]);
                            for j in bits(dm) {
                                let m = ra.max(j) / ma;
                                unsure |= over(m, j);
                                cur_b[j] += 0.5 * 1.032 * m * m * s;
                            }
                            e
                        }
                        Builtin::Pow => {
                            let (vy, ey, ry) = (vals[ix(1)], at[ix(1)].e, of(ix(1)));
                            let e = own(0);
                            if va.is_zero() || vy.is_infinite_or_nan() {
                                unsure |= nonzero(ra.d, dm) | nonzero(ry.d, dm);
                            } else {
                                // x^y = ±exp(y·ln|x|): the change of w = y·ln|x| and its bound, then exp's.
                                let (y, sy, ma) = (vy.to_f64(), p2(ey), va.mant());
                                let ln_x = ma.abs().ln() + va.e as f64 * std::f64::consts::LN_2;
                                if va.sign_negative() {
                                    // An integer power of a negative number: a move of the exponent leaves the integers.
                                    unsure |= nonzero(ry.d, dm);
                                }
                                let mv = value.mant();
                                for j in bits(dm) {
                                    let (dl, ml) = (ra.d[j] / ma, ra.max(j) / ma.abs());
                                    let bl = ra.b[j] / ma.abs() + 0.5 * 1.032 * ml * ml;
                                    let (dy, by) = (ry.d[j] * sy, ry.b[j] * sy);
                                    let dw = y * dl + ln_x * dy;
                                    let bw = y.abs() * bl + ln_x.abs() * by + (ml + bl) * (dy.abs() + by);
                                    let mw = dw.abs() + bw;
                                    unsure |= over(ml, j) | over(mw, j);
                                    cur_d[j] = mv * dw;
                                    cur_b[j] = mv.abs() * (bw + 0.5 * 1.016 * mw * mw);
                                }
                            }
                            e
                        }
                        Builtin::Sin | Builtin::SinNear | Builtin::Cos | Builtin::Atan => {
                            let e = own(ea);
                            let af = va.to_f64();
                            // The slope from the argument rounded to f64: off by at most ~2⁻⁵²·(1 + |a|) (counted
                            // in the bound); the second derivative at most 1 in magnitude.
                            let slope = match b {
                                Builtin::Cos => -af.sin(),
                                Builtin::Atan => 1.0 / (1.0 + af * af),
                                _ => af.cos(),
                            };
                            if af.abs() > 2f64.powi(40) {
                                unsure |= nonzero(ra.d, dm);
                            }
                            let (s, sa) = (p2(ea - e), p2(ea));
                            combine(cur_d, cur_b, dm, &[(ra, slope * s)]);
                            for j in bits(dm) {
                                let m = ra.max(j);
                                unsure |= over(m * sa, j);
                                cur_b[j] += m * s * 2f64.powi(-50) * (1.0 + af.abs()) + 0.5 * m * m * sa * s;
                            }
                            e
                        }
                        Builtin::Asin | Builtin::Acos => {
                            let e = own(ea);
                            // 1 − |a| exactly: the slope ±1/√(1 − a²), and how close a move comes to the clamp.
                            let w = Xf::ONE - va.abs();
                            let wf = w.to_f64();
                            if w.is_special() || w.sign_negative() || wf < 2f64.powi(-1000) {
                                unsure |= nonzero(ra.d, dm);
                            } else {
                                let slope = 1.0 / (wf * (2.0 - wf)).sqrt();
                                let (s, sa) = (p2(ea - e), p2(ea));
                                let sign = if b == Builtin::Acos { -1.0 } else { 1.0 };
                                combine(cur_d, cur_b, dm, &[(ra, sign * slope * s)]);
                                // |asin''| = |a|/(1 − a²)^(3/2), at most 1/(0.98w(2 − 1.02w))^(3/2) within 2⁻⁶·w.
                                let m2 = (0.98 * wf * (2.0 - 1.02 * wf)).powf(-1.5);
                                for j in bits(dm) {
                                    let m = ra.max(j) * sa;
                                    unsure |= over(m / wf, j);
                                    cur_b[j] += ra.max(j) * s * slope * 2f64.powi(-50) + 0.5 * m2 * m * m * p2(-e);
                                }
                            }
                            e
                        }
                        Builtin::Abs => {
                            combine(cur_d, cur_b, dm, &[(ra, if va.sign_negative() { -1.0 } else { 1.0 })]);
                            // A move that may reach 0: |a| changes by at most what a does (either way).
                            for j in bits(dm) {
                                let m = ra.max(j);
                                if m != 0.0 && (m.is_nan() || va.mant().abs() <= m) {
                                    cur_d[j] = 0.0;
                                    cur_b[j] = m;
                                }
                            }
                            ea
                        }
                        Builtin::Min | Builtin::Max => {
                            min_max(cur_d, cur_b, dm, (va, ea, ra), (vals[ix(1)], at[ix(1)].e, of(ix(1))), value)
                        }
                        Builtin::Clamp => {
                            let m = va.max(vals[ix(1)]);
                            let (mut tmp_d, mut tmp_b) = ([0.0; W], [0.0; W]);
                            let em = min_max(&mut tmp_d, &mut tmp_b, dm, (va, ea, ra), (vals[ix(1)], at[ix(1)].e, of(ix(1))), m);
                            let mid = Rows { d: &tmp_d, b: &tmp_b };
                            min_max(cur_d, cur_b, dm, (m, em, mid), (vals[ix(2)], at[ix(2)].e, of(ix(2))), value)
                        }
                        Builtin::Fma => {
                            let (vb, eb, rb) = (vals[ix(1)], at[ix(1)].e, of(ix(1)));
                            let (ec, rc) = (at[ix(2)].e, of(ix(2)));
                            let p = va * vb;
                            let ep = if p.is_regular() { p.e } else { ea + eb };
                            let (mut tmp_d, mut tmp_b) = ([0.0; W], [0.0; W]);
                            product(&mut tmp_d, &mut tmp_b, dm, (va, ra), (vb, rb), p2(ea + eb - ep));
                            let e = own(ep.max(ec));
                            if ep - e > 1000 || ec - e > 1000 {
                                unsure |= dm;
                            }
                            combine(cur_d, cur_b, dm, &[(Rows { d: &tmp_d, b: &tmp_b }, p2(ep - e)), (rc, p2(ec - e))]);
                            e
                        }
                        Builtin::Tan => {
                            let e = own(ea);
                            let t = value.to_f64();
                            // tan' = 1 + tan²; while the argument moves by at most 2⁻⁶/(1 + |tan|) (no closer
                            // to a pole), |tan| stays within 1.1·(1 + |tan|) and |tan''| = 2|tan|(1 + tan²) within
                            // 2.2·T·(1 + 1.3·T²), T = 1 + |tan|.
                            let (slope, big) = (1.0 + t * t, 1.0 + t.abs());
                            let m2 = 2.2 * big * (1.0 + 1.3 * big * big);
                            if va.to_f64().abs() > 2f64.powi(40) {
                                unsure |= nonzero(ra.d, dm);
                            }
                            let (s, sa) = (p2(ea - e), p2(ea));
                            combine(cur_d, cur_b, dm, &[(ra, slope * s)]);
                            for j in bits(dm) {
                                let m = ra.max(j);
                                unsure |= over(m * sa * big, j);
                                cur_b[j] += m * s * slope * 2f64.powi(-50) + 0.5 * m2 * m * m * sa * s;
                            }
                            e
                        }
                        // Written by the accuracy pass, not by hand (the truth is the formula as written).
                        Builtin::ExpMulDiv => {
                            unsure |= dm;
                            own(0)
                        }
                        // 0 in exact arithmetic wherever it is.
                        Builtin::AcosLo | Builtin::PowLo => {
                            unsure = 0;
                            0
                        }
                        Builtin::Floor => {
                            let af = va.to_f64();
                            let slack = if at[a].exact { 0.0 } else { step(af) };
                            if af.abs() >= 2f64.powi(50) {
                                unsure |= nonzero(ra.d, dm);
                            } else {
                                // floor(a) changes where the move takes a below the integer at or under it, or to
                                // the next one.
                                let below = (va - Xf::from_f64(af.floor())).scaled(ea);
                                let above = (Xf::from_f64(af.floor() + 1.0) - va).scaled(ea);
                                let slack = ldexp(slack, -ea);
                                for j in bits(dm) {
                                    let m = ra.max(j);
                                    if m != 0.0 && (below < m + slack || above <= m + slack) {
                                        unsure |= 1 << j;
                                    }
                                }
                            }
                            own(0)
                        }
                        Builtin::Lt | Builtin::Le | Builtin::Eq | Builtin::Ne => {
                            let (vb, eb, rb) = (vals[ix(1)], at[ix(1)].e, of(ix(1)));
                            if va.is_nan() || vb.is_nan() || (va.is_infinite_or_nan() && vb.is_infinite_or_nan()) {
                                unsure |= nonzero(ra.d, dm) | nonzero(rb.d, dm);
                            } else if !va.is_infinite_or_nan() && !vb.is_infinite_or_nan() {
                                let slack = if at[a].exact { 0.0 } else { step(va.to_f64()) } + if at[ix(1)].exact { 0.0 } else { step(vb.to_f64()) };
                                let ed = ea.max(eb);
                                let d = (va - vb).scaled(ed);
                                let slack = ldexp(slack, -ed);
                                let (sa, sb) = (p2(ea - ed), p2(eb - ed));
                                for j in bits(dm) {
                                    let change = (ra.d[j] * sa - rb.d[j] * sb).abs() + ra.b[j] * sa + rb.b[j] * sb;
                                    if change == 0.0 {
                                        continue;
                                    }
                                    let reach = change + slack;
                                    // The result changes where a − b may cross (or, for ≤, = and ≠, reach) 0; where
                                    // the operands are rounded, anywhere within their ulps.
                                    let flips = match b {
                                        Builtin::Lt if slack == 0.0 => if d < 0.0 { d + reach >= 0.0 } else { d - reach < 0.0 },
                                        Builtin::Le if slack == 0.0 => if d <= 0.0 { d + reach > 0.0 } else { d - reach <= 0.0 },
                                        _ => d.abs() <= reach,
                                    };
                                    if flips {
                                        unsure |= 1 << j;
                                    }
                                }
                            }
                            own(0)
                        }
                        Builtin::Select => {
                            let taken = if va.to_f64() != 0.0 { ix(1) } else { ix(2) };
                            // The side not taken matters only where the condition may change (marked below).
                            unsure = at[a].unsure | at[taken].unsure;
                            if va.is_nan() {
                                unsure |= nonzero(ra.d, dm);
                            } else {
                                let slack = if at[a].exact { 0.0 } else { ldexp(step(va.to_f64()), -ea) };
                                let c = va.scaled(ea).abs();
                                for j in bits(dm) {
                                    let m = ra.max(j);
                                    if m != 0.0 && c <= m + slack {
                                        unsure |= 1 << j;
                                    }
                                }
                            }
                            let et = at[taken].e;
                            let e = own(et);
                            combine(cur_d, cur_b, dm, &[(of(taken), p2(et - e))]);
                            e
                        }
                    }
                }
            };
            // (Over the variables' span, without an early exit: straight code.)
            let sp = span(dm);
            if !cur_d[sp.clone()].iter().chain(cur_b[sp].iter()).fold(true, |ok, v| ok & v.is_finite()) {
                for j in bits(dm) {
                    if !(cur_d[j].is_finite() && cur_b[j].is_finite()) {
                        unsure |= 1 << j;
                        cur_d[j] = 0.0;
                        cur_b[j] = 0.0;
                    }
                }
            }
            at.push(At { e, unsure: unsure & dm, exact });
        }
        let root = vals[n - 1];
        let t = root.to_f64();
        if !t.is_finite() || root.is_infinite_or_nan() {
            return (t, Estimate { ulps: vec![(f64::NAN, f64::NAN); nv], unsure: self.all() });
        }
        let e = at[n - 1].e;
        let (d, b) = (&rows[n - 1][..nv], &bounds[n - 1][..nv]);
        let ulps = d
            .iter()
            .zip(b)
            .map(|(d, b)| if *d == 0.0 && *b == 0.0 { (0.0, 0.0) } else { count(t, ldexp((d.abs() - b).max(0.0), e), ldexp(d.abs() + b, e)) })
            .collect();
        (t, Estimate { ulps, unsure: at[n - 1].unsure })
    }
}

/// The variables from the lowest to the highest set bit of `m` (a row is 0 outside its node's variables).
fn span(m: u64) -> std::ops::Range<usize> {
    if m == 0 {
        0..0
    } else {
        m.trailing_zeros() as usize..64 - m.leading_zeros() as usize
    }
}

/// The set bits of `m`, low first.
fn bits(mut m: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (m != 0).then(|| {
            let j = m.trailing_zeros() as usize;
            m &= m - 1;
            j
        })
    })
}

/// Bit `j` where `m` (a change of a function's argument) is beyond [`SMALL`] or not a number.
fn over(m: f64, j: usize) -> u64 {
    if m <= SMALL {
        0
    } else {
        1 << j
    }
}

/// `Σ c·rows` over the variables in `dm` (a term whose entry is 0 adds 0, whatever `c`), and `Σ |c|·bounds`.
/// With finite coefficients, over the whole row at once (a row is 0 outside its node's variables, which `dm`
/// holds); otherwise only the entries of `dm` are written (the others stay as they were: 0).
fn combine<const W: usize>(cur_d: &mut [f64; W], cur_b: &mut [f64; W], dm: u64, terms: &[(Rows<W>, f64)]) {
    match terms {
        [(r, c)] if c.is_finite() => {
            let a = c.abs();
            for j in 0..W {
                cur_d[j] = r.d[j] * c;
                cur_b[j] = r.b[j] * a;
            }
        }
        [(r, c), (q, e)] if c.is_finite() && e.is_finite() => {
            let (a, f) = (c.abs(), e.abs());
            for j in 0..W {
                cur_d[j] = r.d[j] * c + q.d[j] * e;
                cur_b[j] = r.b[j] * a + q.b[j] * f;
            }
        }
        _ => {
            for j in bits(dm) {
                let (mut d, mut b) = (0.0, 0.0);
                for (r, c) in terms {
                    if r.d[j] != 0.0 {
                        d += r.d[j] * c;
                    }
                    if r.b[j] != 0.0 {
                        b += r.b[j] * c.abs();
                    }
                }
                cur_d[j] = d;
                cur_b[j] = b;
            }
        }
    }
}

/// The change of a product `a·b` (scaled by `s` = 2^(ea + eb − e)) and its bound: |a|·β + |b|·α + the
/// product of the two largest changes.
fn product<const W: usize>(cur_d: &mut [f64; W], cur_b: &mut [f64; W], dm: u64, (va, ra): (Xf, Rows<W>), (vb, rb): (Xf, Rows<W>), s: f64) {
    let (ma, mb) = (va.mant(), vb.mant());
    combine(cur_d, cur_b, dm, &[(ra, mb * s), (rb, ma * s)]);
    if s.is_finite() {
        for (c, (((ad, ab), bd), bb)) in cur_b.iter_mut().zip(ra.d.iter().zip(ra.b).zip(rb.d).zip(rb.b)) {
            *c += (ad.abs() + ab) * (bd.abs() + bb) * s;
        }
    } else {
        for j in bits(dm) {
            let (x, y) = (ra.max(j), rb.max(j));
            if x != 0.0 && y != 0.0 {
                cur_b[j] += x * y * s;
            }
        }
    }
}

/// The variables in `dm` that change `row`'s node at all.
fn nonzero(row: &[f64], dm: u64) -> u64 {
    bits(dm).filter(|&j| row[j] != 0.0).fold(0, |m, j| m | 1 << j)
}

/// `min` or `max` of two sides (value, exponent, rows) whose result is `value`: the taken side's rows into
/// `cur`, and its exponent. Where a move may swap the sides (the truth compares exactly), the result's change
/// lies between the two sides' changes: `cur` holds the middle of that range and its half-width as the bound
/// (the function is continuous there, only its slope jumps).
fn min_max<const W: usize>(cur_d: &mut [f64; W], cur_b: &mut [f64; W], dm: u64, a: (Xf, i64, Rows<W>), b: (Xf, i64, Rows<W>), value: Xf) -> i64 {
    let taken = if value == a.0 { &a } else { &b };
    let e = if value.is_regular() { value.e } else { taken.1 };
    combine(cur_d, cur_b, dm, &[(taken.2, p2(taken.1 - e))]);
    if !a.0.is_infinite_or_nan() && !b.0.is_infinite_or_nan() {
        let ed = a.1.max(b.1);
        let d = (a.0 - b.0).scaled(ed).abs();
        let (sa, sb) = (p2(a.1 - ed), p2(b.1 - ed));
        let (ta, tb) = (p2(a.1 - e), p2(b.1 - e));
        for j in bits(dm) {
            let change = (a.2.d[j] * sa - b.2.d[j] * sb).abs() + a.2.b[j] * sa + b.2.b[j] * sb;
            if change != 0.0 && d < change {
                let (da, ba, db, bb) = (a.2.d[j] * ta, a.2.b[j] * ta, b.2.d[j] * tb, b.2.b[j] * tb);
                let (lo, hi) = ((da - ba).min(db - bb), (da + ba).max(db + bb));
                cur_d[j] = 0.5 * (lo + hi);
                cur_b[j] = 0.5 * (hi - lo);
            }
        }
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example files and formulas with every kind of node (steps, kinks, powers, quotients, functions
    /// near their singularities), each channel as the truth sees it (baked values folded).
    fn formulas() -> Vec<Formula> {
        let sources = [
            "param m = 0.3 in 0.01..1\nlet d = exp((NH^2 - 1)/(m*m*NH^2))\nNL <= 0 ? 0 : d*VH/(NL*NV + m) + NV^3",
            "param a = 0.5 in 0..1\nclamp(1 - VH, 0, 1)^5*(1 - a) + a*sqrt(1 - NL*NL)/max(NV, 0.001)",
            "param s = 25 in 0..90\nlet b = min(acos(NL), acos(NV))\nsin(max(acos(NL), acos(NV)))*tan(b)*s/90 + atan(NH/(VH + 0.1))",
            "param k = 2 in 0.1..10\nfloor(k*NH*4)/4 + ln(NL + 1e-3)*abs(NV - 0.5) + (NH < VH ? NL : NV) + fma(NL, k, -NV)",
            "param n = 50 in 1..1000\npow(NH, n)*(n + 2)/(2*pi) - asin(NV)*pow(-NL, 3)",
        ];
        let mut out: Vec<Formula> = sources.iter().map(|src| crate::front::parse("t.brdf", src).unwrap()).collect();
        for dir in ["examples/explorer", "examples/brdfs"] {
            let mut files: Vec<_> = std::fs::read_dir(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(dir)).unwrap().map(|e| e.unwrap().path()).collect();
            files.sort();
            for path in files.iter().filter(|p| p.extension().is_some_and(|e| e == "brdf")) {
                let f = crate::front::parse(&path.to_string_lossy(), &std::fs::read_to_string(path).unwrap()).unwrap();
                out.extend(f.channels());
            }
        }
        out.iter().map(|f| crate::simplify::bake_only(f, &[])).collect()
    }

    /// The rows' width changes nothing, nor do buffers kept from other points and other formulas: at the
    /// sample's points (edge classes included) of every formula of [`formulas`], the truth, the estimate and
    /// the nodes' values are bit for bit those of rows 64 wide in fresh buffers.
    #[test]
    fn any_width_and_kept_buffers_give_the_same_estimates() {
        let mut kept = Scratch::default();
        let mut checked = 0;
        for f in formulas() {
            let Some(l) = Linear::new(&f, &Readers::new(&f)) else { continue };
            for pt in crate::numerics::robust::sample(&f, &[], 1000, 5) {
                let got = l.eval(&f, &pt.x, &pt.p, &mut kept);
                let mut fresh = Scratch::default();
                let want = l.eval_in::<64>(&f, &pt.x, &pt.p, &mut fresh);
                // (Debug prints a NaN as itself and tells −0 from +0.)
                assert_eq!(format!("{got:?}"), format!("{want:?}"), "at {pt:?}");
                assert_eq!(format!("{:?}", kept.values()), format!("{:?}", fresh.values()), "at {pt:?}");
                checked += 1;
            }
        }
        assert!(checked >= 20_000, "{checked} points");
    }

    #[test]
    fn powers_and_spacings() {
        assert_eq!(p2(0), 1.0);
        assert_eq!(p2(-1074), 5e-324);
        assert_eq!(p2(-1075), 0.0);
        assert_eq!(p2(1024), f64::INFINITY);
        assert_eq!(spacing(1.0), f64::EPSILON);
        assert_eq!(spacing(-1.5), f64::EPSILON);
        assert_eq!(spacing(0.0), 5e-324);
        assert_eq!(spacing(f64::MIN_POSITIVE), 5e-324);
        assert_eq!(step(1.0), f64::EPSILON);
        // 16 ulps of 1.5 changed by 16·ε: between 14 and 18 ulps; across 2, the spacing doubles.
        let (lo, hi) = count(1.5, 16.0 * f64::EPSILON, 16.0 * f64::EPSILON);
        assert!((13.99..14.0).contains(&lo) && (18.0..18.01).contains(&hi), "{lo} {hi}");
        let (lo, hi) = count(2.0, 4.0 * f64::EPSILON, 4.0 * f64::EPSILON);
        assert!(lo < 2.0 - 1.99 && hi > 6.0, "{lo} {hi}");
    }
}
