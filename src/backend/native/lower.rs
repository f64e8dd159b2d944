//! IR nodes → a tier's values, written once over the math library's [`Emit`]: the node dispatch, the call of a
//! builtin (inline, the math library's code, or a call of its compiled function), the inline builtins with the
//! single-instruction forms of `min`/`max`/`clamp` against a constant and their −0/NaN repairs, and the walk of
//! a multi-output program's step. A tier implements [`Lower`] (where inputs, parameters and columns come from,
//! IEEE `minimum`/`maximum`, a per-lane library call, its table of translated nodes) and [`Emit`]'s
//! arithmetic; everything here then runs in its lanes with the same instructions' semantics, so every tier
//! computes the interpreter's bits.

use super::NativeError;
use crate::backend::program::{Class, Program, Region};
use crate::builtins::math::Emit;
use crate::builtins::{Builtin, Lowering, Mode};
use crate::ir::{BinOp, Input, Ir, Node, NodeId};

/// What a translator translates and how, whatever the tier.
#[derive(Clone, Copy)]
pub(crate) struct Scope<'a> {
    /// The arena.
    pub ir: &'a Ir,
    /// The math library's mode.
    pub mode: Mode,
    /// Math builtins are calls of the compiled library, not inline code ([`super::outlines`]).
    pub outline: bool,
    /// The host has a fused multiply-add (exact two-products in two instructions).
    pub fma: bool,
}

/// A tier's translator of IR nodes into its values (one function, one lane shape): the primitives the
/// lowering below needs besides [`Emit`]'s. Errors inside [`Emit`] methods (which cannot return one) are
/// recorded and handed over by [`Lower::take_error`].
pub(crate) trait Lower: Emit + Sized {
    /// What is translated and how.
    fn scope(&self) -> Scope<'_>;
    /// The arena being translated.
    fn ir(&self) -> &Ir {
        self.scope().ir
    }
    /// The math library's mode.
    fn mode(&self) -> Mode {
        self.scope().mode
    }
    /// Whether math builtins are calls of the compiled library rather than inline code ([`super::outlines`]).
    fn outline(&self) -> bool {
        self.scope().outline
    }
    /// The value of each translated node, indexed by node.
    fn table(&mut self) -> &mut [Option<Self::V>];
    /// The value of an already translated node.
    fn value(&mut self, id: NodeId) -> Result<Self::V, NativeError> {
        self.table().get(id.index()).copied().flatten().ok_or_else(|| NativeError::Internal(format!("operand t{} used before it was translated", id.0)))
    }
    /// Records the value of node `id`.
    fn set(&mut self, id: NodeId, v: Self::V) -> Result<(), NativeError> {
        let slot = self.table().get_mut(id.index()).ok_or_else(|| NativeError::Internal(format!("node t{} outside the arena", id.0)))?;
        *slot = Some(v);
        Ok(())
    }
    /// Input `i` of the current element(s).
    fn input(&mut self, i: Input) -> Result<Self::V, NativeError>;
    /// Parameter slot `p` in every lane.
    fn param(&mut self, p: u16) -> Result<Self::V, NativeError>;
    /// A program's data column `k` for the current element(s).
    fn column(&mut self, k: u16) -> Result<Self::V, NativeError>;
    /// IEEE 754-2019 `minimum` (NaN-propagating, −0 < +0: [`crate::builtins::fmin`]).
    fn minimum(&mut self, a: Self::V, b: Self::V) -> Self::V;
    /// IEEE 754-2019 `maximum`.
    fn maximum(&mut self, a: Self::V, b: Self::V) -> Self::V;
    /// `f`'s compiled library function ([`Builtin::outlined`]) called on each lane of `args`.
    fn library(&mut self, f: Builtin, args: &[Self::V]) -> Result<Self::V, NativeError>;
    /// The first error an [`Emit`] method recorded, if any.
    fn take_error(&mut self) -> Option<NativeError>;
}

/// Translates node `id` and records its value.
pub(crate) fn node<T: Lower>(t: &mut T, id: NodeId) -> Result<T::V, NativeError> {
    let node = *t.ir().nodes().get(id.index()).ok_or_else(|| NativeError::Internal(format!("node t{} outside the arena", id.0)))?;
    let v = match node {
        Node::Const(bits) => t.konst(f64::from_bits(bits)),
        Node::Input(i) => t.input(i)?,
        Node::Param(p) => t.param(p)?,
        Node::Column(k) => t.column(k)?,
        Node::Neg(a) => {
            let a = t.value(a)?;
            t.neg(a)
        }
        Node::Binary(op, a, b) => {
            let (a, b) = (t.value(a)?, t.value(b)?);
            match op {
                BinOp::Add => t.add(a, b),
                BinOp::Sub => t.sub(a, b),
                BinOp::Mul => t.mul(a, b),
                BinOp::Div => t.div(a, b),
            }
        }
        Node::Call(f, args) => call(t, f, args)?,
    };
    t.set(id, v)?;
    Ok(v)
}

/// Translates, in order, every node among the first `n` for which `pick` holds.
pub(crate) fn nodes<T: Lower>(t: &mut T, n: usize, pick: impl Fn(NodeId) -> bool) -> Result<(), NativeError> {
    for id in (0..n.min(t.ir().len())).map(|i| NodeId(i as u32)) {
        if pick(id) {
            node(t, id)?;
        }
    }
    Ok(())
}

/// A builtin: a native instruction ([`Lowering::Inline`]), a call of the compiled library (outlined), or the
/// math library's code emitted in `t`'s lanes.
fn call<T: Lower>(t: &mut T, f: Builtin, args: [NodeId; 3]) -> Result<T::V, NativeError> {
    if f.info().lowering == Lowering::Inline {
        return inline(t, f, args);
    }
    let vals = args[..f.arity()].iter().map(|a| t.value(*a)).collect::<Result<Vec<_>, _>>()?;
    if t.outline() && f.info().lowering == Lowering::Math {
        return t.library(f, &vals);
    }
    let mode = t.mode();
    let v = f.emit(t, mode, &vals);
    if let Some(e) = t.take_error() {
        return Err(e);
    }
    v.ok_or_else(|| NativeError::Internal(format!("builtin `{}` has no library code", f.name())))
}

/// sqrt, abs, min, max, clamp, fma: native instructions with exactly the builtins table's semantics.
fn inline<T: Lower>(t: &mut T, f: Builtin, args: [NodeId; 3]) -> Result<T::V, NativeError> {
    let x = t.value(args[0])?;
    Ok(match f {
        Builtin::Sqrt => t.sqrt(x),
        Builtin::Abs => t.abs(x),
        Builtin::Min => min(t, args[0], args[1])?,
        Builtin::Max => max(t, args[0], args[1])?,
        // clamp(x, lo, hi) = min(max(x, lo), hi)
        Builtin::Clamp => {
            let m = max(t, args[0], args[1])?;
            min_value(t, m, args[2])?
        }
        // One rounding, as Rust's `mul_add` (the interpreter's).
        Builtin::Fma => {
            let (y, z) = (t.value(args[1])?, t.value(args[2])?);
            t.fma(x, y, z)
        }
        other => return Err(NativeError::Internal(format!("builtin `{}` is not an inline lowering", other.name()))),
    })
}

/// A non-NaN constant operand, if `id` is one (for the min/max specialisations below).
fn ordered_const(ir: &Ir, id: NodeId) -> Option<f64> {
    ir.nodes().get(id.index()).and_then(|n| n.as_const()).filter(|c| !c.is_nan())
}

/// IEEE-2019 `maximum(a, b)`. Against a non-NaN constant `c` (the lowering's `clamp(INPUT, 0, 1)` and
/// `max(raw, 0)`), a single `maxsd`/`maxpd` replaces the general sequence (a compare, a blend and a repair of
/// the zeros' signs): `v < c ? c : v` (x86 pseudo-max, operands ordered so that a NaN `v` is returned) equals
/// `maximum(v, c)` for every `v` except `v = −0, c = +0`, which `+ 0.0` repairs (−0 + 0 = +0, and it is the
/// identity on everything else, NaN included).
fn max<T: Lower>(t: &mut T, a: NodeId, b: NodeId) -> Result<T::V, NativeError> {
    let (va, vb) = (t.value(a)?, t.value(b)?);
    let (v, c, cv) = match (ordered_const(t.ir(), b), ordered_const(t.ir(), a)) {
        (Some(c), _) => (va, c, vb),
        (None, Some(c)) => (vb, c, va),
        (None, None) => return Ok(t.maximum(va, vb)),
    };
    // pmax(c, v) = v < c ? c : v  (one maxsd / maxpd)
    let lt = t.lt(v, cv);
    let m = t.select(lt, cv, v);
    Ok(if c.to_bits() == 0 {
        let z = t.konst(0.0);
        t.add(m, z)
    } else {
        m
    })
}

/// IEEE-2019 `minimum(a, b)`; against a non-NaN constant `c ≠ −0`, `c < v ? c : v` (one `minsd`, a NaN `v`
/// returned) is exact; `c = −0` keeps the general sequence (`v = +0` would give +0).
fn min<T: Lower>(t: &mut T, a: NodeId, b: NodeId) -> Result<T::V, NativeError> {
    if ordered_const(t.ir(), a).is_some() && ordered_const(t.ir(), b).is_none() {
        let vb = t.value(b)?;
        return min_value(t, vb, a);
    }
    let va = t.value(a)?;
    min_value(t, va, b)
}

/// `minimum(v, b)` with `v` already translated.
fn min_value<T: Lower>(t: &mut T, v: T::V, b: NodeId) -> Result<T::V, NativeError> {
    let vb = t.value(b)?;
    Ok(match ordered_const(t.ir(), b) {
        Some(c) if c.to_bits() != (-0.0f64).to_bits() => {
            // pmin(c, v) = c < v ? c : v  (one minsd / minpd)
            let lt = t.lt(vb, v);
            t.select(lt, vb, v)
        }
        _ => t.minimum(v, vb),
    })
}

/// What a multi-output program's step translates, in order.
pub(crate) enum Walk<'p> {
    /// An outer node (computed for every element).
    Outer(NodeId),
    /// A guarded region (its index in `Program::regions`), where the walk reaches its last output.
    Region(usize, &'p Region),
}

/// One step of a multi-output program, in the order both tiers emit it: the outer nodes in arena order, each
/// guarded region where the walk reaches its last output (`Region::at`).
pub(crate) fn program_step(p: &Program) -> impl Iterator<Item = Walk<'_>> {
    let mut next = 0;
    p.ir.ids().flat_map(move |id| {
        let outer = (p.class[id.index()] == Class::Outer).then_some(Walk::Outer(id));
        let first = next;
        while p.regions.get(next).is_some_and(|r| r.at == id) {
            next += 1;
        }
        outer.into_iter().chain(p.regions[first..next].iter().enumerate().map(move |(k, r)| Walk::Region(first + k, r)))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::span::Span;
    use crate::builtins::dd::Arith;
    use crate::builtins::math::Direct;
    use crate::builtins::{clamp, fmax, fmin};

    /// A one-lane tier on plain `f64` (the math library's [`Direct`] primitives), so the shared lowering's own
    /// choices — the constant-operand forms of min/max/clamp and their repairs — are checked apart from any
    /// compiler: `select(lt(..))` here is exactly the `maxsd`/`minsd` semantics the tiers emit.
    struct Scalar {
        ir: Ir,
        table: Vec<Option<f64>>,
        x: f64,
    }

    impl Arith for Scalar {
        type V = f64;
        fn konst(&mut self, c: f64) -> f64 {
            c
        }
        fn add(&mut self, a: f64, b: f64) -> f64 {
            Direct.add(a, b)
        }
        fn sub(&mut self, a: f64, b: f64) -> f64 {
            Direct.sub(a, b)
        }
        fn mul(&mut self, a: f64, b: f64) -> f64 {
            Direct.mul(a, b)
        }
        fn div(&mut self, a: f64, b: f64) -> f64 {
            Direct.div(a, b)
        }
        fn neg(&mut self, a: f64) -> f64 {
            Direct.neg(a)
        }
        fn sqrt(&mut self, a: f64) -> f64 {
            Direct.sqrt(a)
        }
        fn fma(&mut self, a: f64, b: f64, c: f64) -> f64 {
            Direct.fma(a, b, c)
        }
        fn positive_select(&mut self, c: f64, a: f64, b: f64) -> f64 {
            Direct.positive_select(c, a, b)
        }
    }

    impl Emit for Scalar {
        type M = bool;
        fn abs(&mut self, a: f64) -> f64 {
            Direct.abs(a)
        }
        fn lt(&mut self, a: f64, b: f64) -> bool {
            Direct.lt(a, b)
        }
        fn le(&mut self, a: f64, b: f64) -> bool {
            Direct.le(a, b)
        }
        fn eq(&mut self, a: f64, b: f64) -> bool {
            Direct.eq(a, b)
        }
        fn and(&mut self, a: bool, b: bool) -> bool {
            a & b
        }
        fn or(&mut self, a: bool, b: bool) -> bool {
            a | b
        }
        fn not(&mut self, a: bool) -> bool {
            !a
        }
        fn select(&mut self, m: bool, a: f64, b: f64) -> f64 {
            Direct.select(m, a, b)
        }
        fn mask_bits(&mut self, x: f64, and: u64, or: u64) -> f64 {
            Direct.mask_bits(x, and, or)
        }
        fn pow2i(&mut self, k: f64) -> f64 {
            Direct.pow2i(k)
        }
        fn exponent_field(&mut self, x: f64) -> f64 {
            Direct.exponent_field(x)
        }
        fn lookup_pair(&mut self, table: &'static [[f64; 2]], x: f64) -> (f64, f64) {
            Direct.lookup_pair(table, x)
        }
        fn rare(&mut self, m: bool, r: f64, slow: &mut dyn FnMut(&mut Self) -> f64) -> f64 {
            if m {
                slow(self)
            } else {
                r
            }
        }
        fn fallback(&mut self, m: bool, x: f64, r: f64, f: Builtin) -> f64 {
            Direct.fallback(m, x, r, f)
        }
        fn lanes(&self) -> u32 {
            1
        }
    }

    impl Lower for Scalar {
        fn scope(&self) -> Scope<'_> {
            Scope { ir: &self.ir, mode: Mode::Precise, outline: false, fma: true }
        }
        fn table(&mut self) -> &mut [Option<f64>] {
            &mut self.table
        }
        fn input(&mut self, _: Input) -> Result<f64, NativeError> {
            Ok(self.x)
        }
        fn param(&mut self, p: u16) -> Result<f64, NativeError> {
            Err(NativeError::internal(format!("no parameter {p} here")))
        }
        fn column(&mut self, k: u16) -> Result<f64, NativeError> {
            Err(NativeError::internal(format!("no column {k} here")))
        }
        fn minimum(&mut self, a: f64, b: f64) -> f64 {
            fmin(a, b)
        }
        fn maximum(&mut self, a: f64, b: f64) -> f64 {
            fmax(a, b)
        }
        fn library(&mut self, f: Builtin, _: &[f64]) -> Result<f64, NativeError> {
            Err(NativeError::internal(format!("`{}` is not outlined here", f.name())))
        }
        fn take_error(&mut self) -> Option<NativeError> {
            None
        }
    }

    /// `f(NH, consts…)` lowered and run on `x`, with the constants in the order given (`None`: the input).
    fn run(f: Builtin, args: &[Option<f64>], x: f64) -> f64 {
        let s = Span::default();
        let mut ir = Ir::new();
        let mut ids = vec![];
        for a in args {
            ids.push(match *a {
                Some(c) => ir.konst(c, s),
                None => ir.input(Input::NH, s),
            });
        }
        let root = ir.call(f, &ids, s);
        let mut t = Scalar { table: vec![None; ir.len()], ir, x };
        nodes(&mut t, root.index() + 1, |_| true).expect("lowers");
        t.value(root).expect("translated")
    }

    fn same(got: f64, want: f64) -> bool {
        got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan())
    }

    const XS: [f64; 9] = [0.0, -0.0, f64::NAN, 0.5, -1.0, 2.0, 1.0, f64::INFINITY, f64::NEG_INFINITY];
    const CS: [f64; 6] = [0.0, -0.0, 1.0, -1.0, 0.5, f64::INFINITY];

    /// min/max against a constant on either side take the one-instruction forms; with the −0 repair (max
    /// against +0) and the general sequence kept for min against −0, every signed zero and NaN is IEEE
    /// `minimum`/`maximum`'s, as the interpreter computes them.
    #[test]
    fn min_and_max_against_constants_are_ieee_minimum_and_maximum() {
        for x in XS {
            for c in CS {
                for (f, want) in [(Builtin::Max, fmax(x, c)), (Builtin::Min, fmin(x, c))] {
                    for args in [[None, Some(c)], [Some(c), None]] {
                        let got = run(f, &args, x);
                        assert!(same(got, want), "{}({args:?}) at x = {x:?}: {got:?}, want {want:?}", f.name());
                    }
                }
            }
        }
    }

    /// `clamp(x, lo, hi)` against constant bounds (the lowering's `clamp(INPUT, 0, 1)` among them) is the
    /// interpreter's `min(max(x, lo), hi)`, signed zeros and NaN included.
    #[test]
    fn clamp_against_constants_is_the_interpreters() {
        for x in XS {
            for (lo, hi) in [(0.0, 1.0), (-0.0, 1.0), (-1.0, 0.0), (-1.0, -0.0), (0.5, 0.5)] {
                let got = run(Builtin::Clamp, &[None, Some(lo), Some(hi)], x);
                assert!(same(got, clamp(x, lo, hi)), "clamp({x:?}, {lo:?}, {hi:?}) = {got:?}");
            }
        }
    }

    /// A node outside the arena, or an operand used before it was translated, is an internal error, not a
    /// panic.
    #[test]
    fn broken_arenas_are_errors() {
        let s = Span::default();
        let mut ir = Ir::new();
        let x = ir.input(Input::NH, s);
        let y = ir.neg(x, s);
        let mut t = Scalar { table: vec![None; ir.len()], ir, x: 1.0 };
        assert!(matches!(node(&mut t, NodeId(9)), Err(NativeError::Internal(m)) if m.contains("outside the arena")));
        assert!(matches!(node(&mut t, y), Err(NativeError::Internal(m)) if m.contains("before it was translated")));
        assert_eq!(node(&mut t, x).ok(), Some(1.0));
        assert_eq!(node(&mut t, y).ok(), Some(-1.0));
    }
}
