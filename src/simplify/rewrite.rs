//! What the accuracy pass's rules share: one [`Analysis`] of the formula they rewrite (ranges, guards, product
//! lists, parameter-only nodes — computed once per formula, on first use, and handed to every rule and every
//! site of a rule) and the tree builders they rebuild it with.
//!
//! Below both rule modules ([`super::accuracy`], [`super::cancel`]), so neither imports the other's helpers.

use super::range::Range;
use super::{node_ranges, Policy};
use crate::base::span::Span;
use crate::builtins::Builtin;
use crate::ir::{BinOp, Formula, InputSet, Ir, Node, NodeId};
use std::cell::OnceCell;

/// The facts about one formula the rules read. Each is computed the first time a rule asks for it.
pub(crate) struct Analysis {
    pub(crate) f: Formula,
    ranges: OnceCell<Vec<Range>>,
    invariant: OnceCell<Vec<bool>>,
    guards: OnceCell<Vec<Option<Vec<NodeId>>>>,
    lists: OnceCell<Lists>,
    wide_lists: OnceCell<Lists>,
    reads: OnceCell<Vec<InputSet>>,
}

impl Analysis {
    pub(crate) fn new(f: Formula) -> Analysis {
        Analysis {
            f,
            ranges: OnceCell::new(),
            invariant: OnceCell::new(),
            guards: OnceCell::new(),
            lists: OnceCell::new(),
            wide_lists: OnceCell::new(),
            reads: OnceCell::new(),
        }
    }

    /// Every node's range under the default policy ([`node_ranges`]).
    pub(crate) fn ranges(&self) -> &[Range] {
        self.ranges.get_or_init(|| node_ranges(&self.f, &Policy::default()))
    }

    /// Per node, whether it reads no input (parameters and constants only: the kernel's prepared block).
    pub(crate) fn invariant(&self) -> &[bool] {
        self.invariant.get_or_init(|| self.f.ir.invariant())
    }

    /// Per node, the nodes known to be > 0 wherever it is used ([`positive_guards`]).
    pub(crate) fn guards(&self) -> &[Option<Vec<NodeId>>] {
        self.guards.get_or_init(|| positive_guards(&self.f))
    }

    /// Per node, its factor lists of at most [`MAX_FACTORS`] ([`product_lists`]).
    pub(crate) fn lists(&self) -> &Lists {
        self.lists.get_or_init(|| product_lists(&self.f, MAX_FACTORS))
    }

    /// Per node, the inputs its value reads ([`Ir::input_sets`]).
    pub(crate) fn reads(&self) -> &[InputSet] {
        self.reads.get_or_init(|| self.f.ir.input_sets())
    }

    /// [`Analysis::lists`] of up to twice as many factors (cancel-min's products, which carry a min's terms).
    pub(crate) fn wide_lists(&self) -> &Lists {
        self.wide_lists.get_or_init(|| product_lists(&self.f, 2 * MAX_FACTORS))
    }
}

/// Rebuilds `f` node by node through `rw`, which returns the new node for an old one given the map so far.
pub(crate) fn rebuild(f: &Formula, mut rw: impl FnMut(&mut Ir, &[NodeId], NodeId, Node) -> Option<NodeId>) -> (Ir, NodeId, bool) {
    let mut ir = Ir::new();
    let mut map: Vec<NodeId> = Vec::with_capacity(f.ir.len());
    let mut fired = false;
    for id in f.ir.ids() {
        let span = f.ir.span(id);
        let old = *f.ir.node(id);
        let new = match rw(&mut ir, &map, id, old) {
            Some(n) => {
                fired = true;
                n
            }
            None => ir.push(old.map_args(|a| map[a.index()]), span),
        };
        map.push(new);
    }
    let (ir, root) = ir.compact(map[f.root.index()]);
    (ir, root, fired)
}

/// Per node, the nodes known to be > 0 (or NaN) wherever its value is used: it is reached only through the
/// else branch of selects `x <= 0 ? … : …` (and `x <= 0 || y <= 0`, which the front end writes as
/// `select(x <= 0, 1, y <= 0)`). An explorer BRDF's `if (NdotL <= 0.0 || NdotV <= 0.0) return 0` guards its
/// body this way, while the inputs' own ranges include negative cosines. `None`: not reachable from the root.
pub(crate) fn positive_guards(f: &Formula) -> Vec<Option<Vec<NodeId>>> {
    let ir = &f.ir;
    // Nodes `x` with `x > 0` (or NaN) wherever `cond` is false.
    fn falses(ir: &Ir, cond: NodeId, out: &mut Vec<NodeId>) {
        crate::base::stack::deep(|| {
            match *ir.node(cond) {
                Node::Call(Builtin::Le, [x, z, _]) if ir.node(z).as_const() == Some(0.0) => out.push(x),
                Node::Call(Builtin::Select, [p, one, q]) if ir.node(one).as_const().is_some_and(|v| v != 0.0 && !v.is_nan()) => {
                    falses(ir, p, out);
                    falses(ir, q, out);
                }
                _ => {}
            }
        })
    }
    let mut g: Vec<Option<Vec<NodeId>>> = vec![None; ir.len()];
    g[f.root.index()] = Some(vec![]);
    // Parents have larger ids than their operands: a reverse sweep sees every parent before its children.
    for i in (0..=f.root.index()).rev() {
        let Some(mine) = g[i].clone() else { continue };
        let id = NodeId(i as u32);
        let node = *ir.node(id);
        let mut give = |child: NodeId, extra: &[NodeId]| {
            let mut set = mine.clone();
            set.extend_from_slice(extra);
            let slot = &mut g[child.index()];
            *slot = Some(match slot.take() {
                None => set,
                Some(old) => old.into_iter().filter(|x| set.contains(x)).collect(),
            });
        };
        if let Node::Call(Builtin::Select, [c, t, e]) = node {
            let mut pos = vec![];
            falses(ir, c, &mut pos);
            give(c, &[]);
            give(t, &[]);
            give(e, &pos);
        } else {
            node.for_each_arg(|a| give(a, &[]));
        }
    }
    g
}

/// Most factors a flattened product keeps; a longer one (a long power chain) stays one factor.
pub(crate) const MAX_FACTORS: usize = 12;

pub(crate) fn safe(r: Range) -> bool {
    let (lo, hi) = (2f64.powi(-300), 2f64.powi(300));
    !r.nan && ((r.lo >= lo && r.hi <= hi) || (r.hi <= -lo && r.lo >= -hi))
}

/// Per node, its (numerator, denominator) factor lists of atomic nodes when it is a short tree of `*` and `/`.
pub(crate) type Lists = Vec<Option<(Vec<NodeId>, Vec<NodeId>)>>;

/// The nodes that are an operand of a flattened product/quotient (`lists`' `*` or `/` node): a rule that rewrites
/// whole product trees skips them, since the tree above rebuilds them with it.
pub(crate) fn list_operands(ir: &Ir, lists: &Lists) -> Vec<bool> {
    let mut inner = vec![false; ir.len()];
    for id in ir.ids() {
        if let (Some(_), Node::Binary(BinOp::Mul | BinOp::Div, a, b)) = (&lists[id.index()], ir.node(id)) {
            inner[a.index()] = true;
            inner[b.index()] = true;
        }
    }
    inner
}

pub(crate) fn product_lists(f: &Formula, max: usize) -> Lists {
    let mut lists: Lists = Vec::with_capacity(f.ir.len());
    for id in f.ir.ids() {
        let of = |x: NodeId, lists: &Lists| match &lists[x.index()] {
            Some(l) => l.clone(),
            None if f.ir.node(x).as_const() == Some(1.0) => (vec![], vec![]),
            None => (vec![x], vec![]),
        };
        let l = match *f.ir.node(id) {
            Node::Binary(op @ (BinOp::Mul | BinOp::Div), a, b) => {
                let (mut n, mut d) = of(a, &lists);
                let (mut n2, mut d2) = of(b, &lists);
                if op == BinOp::Div {
                    std::mem::swap(&mut n2, &mut d2);
                }
                n.extend(n2);
                d.extend(d2);
                Some((n, d))
            }
            _ => None,
        };
        lists.push(l.filter(|(n, d)| n.len() + d.len() <= max));
    }
    lists
}

/// The product of `xs` (mapped to the new arena), `None` when empty.
pub(crate) fn product(ir: &mut Ir, map: &[NodeId], xs: &[NodeId], s: Span) -> Option<NodeId> {
    let mut it = xs.iter().map(|x| map[x.index()]);
    let first = it.next()?;
    Some(it.fold(first, |acc, x| ir.bin(BinOp::Mul, acc, x, s)))
}

/// The product of `xs` (non-empty, mapped to the new arena) as a balanced tree, `x·x` first, so its latency is
/// log₂ of the count and the simplifier shares each square (NH⁴ as t1·t1, t1 = NH·NH, the exponent's own).
pub(crate) fn balanced_product(ir: &mut Ir, map: &[NodeId], xs: &[NodeId], s: Span) -> NodeId {
    let mut sorted = xs.to_vec();
    sorted.sort();
    let mut level: Vec<NodeId> = sorted.iter().map(|x| map[x.index()]).collect();
    while level.len() > 1 {
        level = level.chunks(2).map(|c| if c.len() == 2 { ir.bin(BinOp::Mul, c[0], c[1], s) } else { c[0] }).collect();
    }
    level[0]
}

/// `num / safe_den / unsafe_den₁ / …` (new-arena nodes): the whole numerator first (in a BRDF the factor that
/// vanishes, exp(−1/x²), is there, and it must meet the divisions as 0, not as ∞·0), then the safe divisors at
/// once, then each divisor that may be tiny or huge on its own.
pub(crate) fn divide_apart(ir: &mut Ir, map: &[NodeId], num: &[NodeId], safe_den: &[NodeId], unsafe_den: &[NodeId], s: Span) -> NodeId {
    let v = product(ir, map, num, s).unwrap_or_else(|| ir.konst(1.0, s));
    divide_by(ir, map, v, safe_den, unsafe_den, s)
}

/// [`divide_apart`] for a numerator already built (`v`, a new-arena node).
pub(crate) fn divide_by(ir: &mut Ir, map: &[NodeId], mut v: NodeId, safe_den: &[NodeId], unsafe_den: &[NodeId], s: Span) -> NodeId {
    if let Some(d) = product(ir, map, safe_den, s) {
        v = ir.bin(BinOp::Div, v, d, s);
    }
    for d in unsafe_den {
        v = ir.bin(BinOp::Div, v, map[d.index()], s);
    }
    v
}

pub(crate) fn add_opt(ir: &mut Ir, a: Option<NodeId>, b: Option<NodeId>, sp: Span) -> Option<NodeId> {
    match (a, b) {
        (Some(a), Some(b)) => Some(ir.bin(BinOp::Add, a, b, sp)),
        (a, b) => a.or(b),
    }
}

