//! The resolved expression every backend consumes.
//!
//! Design: a hash-consed arena. Nodes live in a `Vec` in topological order (every operand has a smaller
//! index than its user), so the interpreter is one forward loop, the JIT emits one Cranelift value per node in
//! order, and the GLSL export writes one `float tN = …;` per shared node. Pushing a node that already exists
//! returns the existing id, so common subexpressions are shared by construction (`acos(NH)` written twice is
//! one node). Every node carries the byte span of the source text it came from, so later stages (the
//! stability sweep, the simplifier's notes) can point at the user's text.
//!
//! Semantics (the interpreter in `interp.rs` is the reference):
//! - all arithmetic is IEEE f64; `Div` by zero gives ±inf or NaN as IEEE says;
//! - `min`/`max`/`clamp` propagate NaN (IEEE 754-2019 minimum/maximum, as Cranelift's `fmin`/`fmax`), and
//!   order −0 below +0, so the JIT and the interpreter agree bit for bit;
//! - the domain policy (inputs clamped to [0, 1], acos/asin arguments clamped to [−1, 1], the result clamped
//!   at 0) is written into the IR by the lowering, not hidden in a backend, so every backend obeys it.

use crate::builtins::Builtin;
use crate::base::span::Span;
use rustc_hash::FxHashMap;
use std::collections::HashMap;
use std::fmt;

/// Index of a node in an [`Ir`] arena.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(pub u32);

impl NodeId {
    pub(crate) fn index(self) -> usize {
        self.0 as usize
    }
}

/// The geometric inputs of a BRDF: cosines between unit vectors, and the light and view directions in the
/// local shading frame.
///
/// VH (view·half, equal to LH) is an input because Cook–Torrance's geometry term needs it and it cannot be
/// recovered from the other four without the full vectors. The direction components are expressed in the local
/// frame, where the normal is N = +z and the tangent and bitangent are X = +x and Y = +y: so N, X and Y are
/// constants, `dot(N, L)` is `Lz`, and a formula that reads directions needs only these six numbers. A renderer
/// computes only the inputs a formula reads ([`Ir::used_inputs`]); cosine formulas never pay for a tangent frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Input {
    NL,
    NV,
    NH,
    VR,
    VH,
    Lx,
    Ly,
    Lz,
    Vx,
    Vy,
    Vz,
}

/// Number of geometric inputs; kernels take them as `[f64; N_INPUTS]` in [`Input::ALL`] order.
pub const N_INPUTS: usize = 11;

impl Input {
    pub const ALL: [Input; N_INPUTS] = [
        Input::NL,
        Input::NV,
        Input::NH,
        Input::VR,
        Input::VH,
        Input::Lx,
        Input::Ly,
        Input::Lz,
        Input::Vx,
        Input::Vy,
        Input::Vz,
    ];
    /// The direction components in the local frame (never clamped: they range over [−1, 1]).
    pub(crate) const DIRECTIONS: [Input; 6] = [Input::Lx, Input::Ly, Input::Lz, Input::Vx, Input::Vy, Input::Vz];

    pub fn index(self) -> usize {
        self as usize
    }

    /// Whether this is a component of L or V rather than a cosine.
    pub fn is_direction(self) -> bool {
        self.index() >= Input::Lx.index()
    }

    pub fn name(self) -> &'static str {
        match self {
            Input::NL => "NL",
            Input::NV => "NV",
            Input::NH => "NH",
            Input::VR => "VR",
            Input::VH => "VH",
            Input::Lx => "Lx",
            Input::Ly => "Ly",
            Input::Lz => "Lz",
            Input::Vx => "Vx",
            Input::Vy => "Vy",
            Input::Vz => "Vz",
        }
    }

    pub fn from_name(s: &str) -> Option<Input> {
        Input::ALL.iter().copied().find(|i| i.name() == s)
    }

    /// What the input means, for hints and reports.
    pub(crate) fn describe(self) -> &'static str {
        match self {
            Input::NL => "cosine between the normal and the light direction",
            Input::NV => "cosine between the normal and the view direction",
            Input::NH => "cosine between the normal and the half vector H = norm(L + V)",
            Input::VR => "cosine between the view direction and the mirrored light R = 2(N·L)N − L",
            Input::VH => "cosine between the view direction and the half vector (equals L·H)",
            Input::Lx => "light direction, component along the tangent X (local frame)",
            Input::Ly => "light direction, component along the bitangent Y (local frame)",
            Input::Lz => "light direction, component along the normal N (local frame; equals N·L unclamped)",
            Input::Vx => "view direction, component along the tangent X (local frame)",
            Input::Vy => "view direction, component along the bitangent Y (local frame)",
            Input::Vz => "view direction, component along the normal N (local frame; equals N·V unclamped)",
        }
    }
}

/// A set of inputs, as a bit mask; what a formula reads, so callers skip computing the rest.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct InputSet(pub u16);

impl InputSet {
    pub fn contains(self, i: Input) -> bool {
        self.0 & (1 << i.index()) != 0
    }
    pub fn insert(&mut self, i: Input) {
        self.0 |= 1 << i.index();
    }
    pub fn iter(self) -> impl Iterator<Item = Input> {
        Input::ALL.into_iter().filter(move |i| self.contains(*i))
    }
    pub fn len(self) -> usize {
        self.0.count_ones() as usize
    }
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// Whether any component of L or V is read (then a caller needs the tangent frame).
    pub fn reads_directions(self) -> bool {
        Input::DIRECTIONS.iter().any(|i| self.contains(*i))
    }
}

/// The union of the sets: what several kernels or roots read together.
impl std::iter::FromIterator<InputSet> for InputSet {
    fn from_iter<I: IntoIterator<Item = InputSet>>(it: I) -> InputSet {
        InputSet(it.into_iter().fold(0, |a, s| a | s.0))
    }
}

impl fmt::Display for InputSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<_> = self.iter().map(|i| i.name()).collect();
        write!(f, "{}", names.join(", "))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
}

impl BinOp {
    pub(crate) fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
        }
    }
    pub(crate) fn apply(self, a: f64, b: f64) -> f64 {
        match self {
            BinOp::Add => a + b,
            BinOp::Sub => a - b,
            BinOp::Mul => a * b,
            BinOp::Div => a / b,
        }
    }
}

/// One operation. Constants are stored as bit patterns so nodes can be hashed (and so −0 and +0, or two NaN
/// payloads, are distinct constants, as they are to IEEE).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Node {
    Const(u64),
    Input(Input),
    /// Index into [`Formula::params`].
    Param(u16),
    Neg(NodeId),
    Binary(BinOp, NodeId, NodeId),
    /// A builtin from the one table; unused argument slots hold the first argument and are ignored.
    Call(Builtin, [NodeId; 3]),
    /// Per-element data column k of a multi-output program ([`crate::backend::program`]): a varying leaf like an
    /// `Input`, but not a BRDF input. Front ends never produce it, so formulas never contain it.
    Column(u16),
}

impl Node {
    pub(crate) fn constant(v: f64) -> Node {
        Node::Const(v.to_bits())
    }

    pub(crate) fn as_const(&self) -> Option<f64> {
        match self {
            Node::Const(b) => Some(f64::from_bits(*b)),
            _ => None,
        }
    }

    /// Calls `f` on every operand, in order.
    pub(crate) fn for_each_arg(&self, mut f: impl FnMut(NodeId)) {
        match self {
            Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_) => {}
            Node::Neg(a) => f(*a),
            Node::Binary(_, a, b) => {
                f(*a);
                f(*b);
            }
            Node::Call(b, args) => args[..b.arity()].iter().for_each(|a| f(*a)),
        }
    }

    /// The same node with every operand mapped through `m`.
    pub(crate) fn map_args(&self, mut m: impl FnMut(NodeId) -> NodeId) -> Node {
        match *self {
            Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_) => *self,
            Node::Neg(a) => Node::Neg(m(a)),
            Node::Binary(op, a, b) => Node::Binary(op, m(a), m(b)),
            Node::Call(f, args) => {
                let mut out = args;
                for (i, a) in args.iter().enumerate().take(f.arity()) {
                    out[i] = m(*a);
                }
                // Unused slots mirror the first argument so that equal calls hash equally.
                for i in f.arity()..3 {
                    out[i] = out[0];
                }
                Node::Call(f, out)
            }
        }
    }
}

/// A hash-consed expression arena; see the module docs.
#[derive(Clone, Debug, Default)]
pub struct Ir {
    nodes: Vec<Node>,
    spans: Vec<Span>,
    /// Hash-consing: FxHash, not std's SipHash (no untrusted keys here; hashing dominated the simplifier's time).
    intern: FxHashMap<Node, NodeId>,
}

impl Ir {
    pub fn new() -> Ir {
        Ir::default()
    }

    /// Adds `node` (whose operands must already be in the arena) or returns the identical existing node.
    pub fn push(&mut self, node: Node, span: Span) -> NodeId {
        if let Some(&id) = self.intern.get(&node) {
            return id;
        }
        let id = NodeId(self.nodes.len() as u32);
        node.for_each_arg(|a| debug_assert!(a < id, "IR operands must precede their users"));
        self.nodes.push(node);
        self.spans.push(span);
        self.intern.insert(node, id);
        id
    }

    pub fn konst(&mut self, v: f64, span: Span) -> NodeId {
        self.push(Node::constant(v), span)
    }
    pub fn input(&mut self, i: Input, span: Span) -> NodeId {
        self.push(Node::Input(i), span)
    }
    pub fn param(&mut self, p: u16, span: Span) -> NodeId {
        self.push(Node::Param(p), span)
    }
    pub fn column(&mut self, k: u16, span: Span) -> NodeId {
        self.push(Node::Column(k), span)
    }
    pub fn neg(&mut self, a: NodeId, span: Span) -> NodeId {
        self.push(Node::Neg(a), span)
    }
    pub fn bin(&mut self, op: BinOp, a: NodeId, b: NodeId, span: Span) -> NodeId {
        self.push(Node::Binary(op, a, b), span)
    }
    pub fn call(&mut self, f: Builtin, args: &[NodeId], span: Span) -> NodeId {
        assert_eq!(args.len(), f.arity(), "arity is checked by the front end before lowering");
        let mut a = [args[0]; 3];
        a[..args.len()].copy_from_slice(args);
        self.push(Node::Call(f, a), span)
    }

    pub fn node(&self, id: NodeId) -> &Node {
        &self.nodes[id.index()]
    }
    pub fn span(&self, id: NodeId) -> Span {
        self.spans[id.index()]
    }
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }
    pub fn len(&self) -> usize {
        self.nodes.len()
    }
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }
    pub fn ids(&self) -> impl Iterator<Item = NodeId> {
        (0..self.nodes.len() as u32).map(NodeId)
    }

    /// Copies the nodes reachable from `root` into a fresh arena (dropping dead nodes, renumbering in
    /// topological order); returns the arena and the new root.
    pub fn compact(&self, root: NodeId) -> (Ir, NodeId) {
        let (out, roots) = self.compact_many(&[root]);
        (out, roots[0])
    }

    /// [`Ir::compact`] for several roots (a program with several outputs); returns the new roots in order.
    pub(crate) fn compact_many(&self, roots: &[NodeId]) -> (Ir, Vec<NodeId>) {
        let top = roots.iter().map(|r| r.index() + 1).max().unwrap_or(0);
        let mut live = vec![false; top];
        for r in roots {
            live[r.index()] = true;
        }
        for i in (0..top).rev() {
            if live[i] {
                self.nodes[i].for_each_arg(|a| live[a.index()] = true);
            }
        }
        let mut out = Ir::new();
        let mut map = vec![NodeId(u32::MAX); top];
        for i in 0..top {
            if live[i] {
                let n = self.nodes[i].map_args(|a| map[a.index()]);
                map[i] = out.push(n, self.spans[i]);
            }
        }
        let r = roots.iter().map(|r| map[r.index()]).collect();
        (out, r)
    }

    /// Per node, whether it reads no input and no column, directly or through its operands: constants,
    /// parameters and work on them only, which the kernels compute once per parameter set.
    pub(crate) fn invariant(&self) -> Vec<bool> {
        let mut inv = vec![false; self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate() {
            let mut all = !matches!(n, Node::Input(_) | Node::Column(_));
            n.for_each_arg(|a| all &= inv[a.index()]);
            inv[i] = all;
        }
        inv
    }

    /// Per node, the inputs its value reads (one pass in arena order: operands come first).
    pub(crate) fn input_sets(&self) -> Vec<InputSet> {
        let mut sets: Vec<InputSet> = Vec::with_capacity(self.nodes.len());
        for n in &self.nodes {
            let mut s = InputSet::default();
            if let Node::Input(i) = n {
                s.insert(*i);
            }
            n.for_each_arg(|a| s.0 |= sets[a.index()].0);
            sets.push(s);
        }
        sets
    }

    /// Inputs read by the expression rooted at `root`.
    pub(crate) fn used_inputs(&self, root: NodeId) -> InputSet {
        let mut set = InputSet::default();
        self.walk(root, |n| {
            if let Node::Input(i) = n {
                set.insert(*i)
            }
        });
        set
    }

    /// Parameters read by the expression rooted at `root` (indices into `Formula::params`).
    pub fn used_params(&self, root: NodeId) -> Vec<u16> {
        let mut v = Vec::new();
        self.walk(root, |n| {
            if let Node::Param(p) = n {
                v.push(*p)
            }
        });
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Visits every node reachable from `root` once.
    pub fn walk(&self, root: NodeId, mut f: impl FnMut(&Node)) {
        let mut seen = vec![false; root.index() + 1];
        seen[root.index()] = true;
        for i in (0..=root.index()).rev() {
            if seen[i] {
                let n = &self.nodes[i];
                n.for_each_arg(|a| seen[a.index()] = true);
                f(n);
            }
        }
    }

    /// How many times each node is used as an operand within the graph rooted at `root` (the root counts 1).
    pub(crate) fn use_counts(&self, root: NodeId) -> Vec<u32> {
        self.use_counts_of(&[root])
    }

    /// [`Ir::use_counts`] over the union of the graphs rooted at `roots` (each root counts 1 per listing).
    pub(crate) fn use_counts_of(&self, roots: &[NodeId]) -> Vec<u32> {
        let mut counts = vec![0u32; self.nodes.len()];
        let mut seen = vec![false; self.nodes.len()];
        for r in roots {
            counts[r.index()] += 1;
            seen[r.index()] = true;
        }
        let top = roots.iter().map(|r| r.index()).max().unwrap_or(0);
        for i in (0..=top.min(self.nodes.len().saturating_sub(1))).rev() {
            if seen[i] {
                self.nodes[i].for_each_arg(|a| {
                    counts[a.index()] += 1;
                    seen[a.index()] = true;
                });
            }
        }
        counts
    }
}

/// A declared parameter: `param NAME = DEFAULT in LO..HI`. `n` is always parameter 0.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamDecl {
    pub name: String,
    pub default: f64,
    pub lo: f64,
    pub hi: f64,
    /// Where it was declared; `None` for the implicit `n`.
    pub span: Option<Span>,
    pub kind: ParamKind,
}

/// What a parameter is to the person editing it. Every parameter is one f64 to the kernels; the kind decides
/// how it is shown, edited and exported (a slider, a check box, a colour picker).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ParamKind {
    #[default]
    Float,
    /// 0 (false) or 1 (true); range 0..1.
    Bool,
    /// Channel 0, 1 or 2 (r, g, b) of a colour parameter; the three are consecutive parameters named
    /// `NAME.r`, `NAME.g`, `NAME.b`, each in 0..1.
    Color(u8),
}

impl ParamDecl {
    /// A float parameter declared nowhere in the source (the implicit `n`, tests, generated formulas).
    pub fn float(name: &str, default: f64, lo: f64, hi: f64) -> ParamDecl {
        ParamDecl { name: name.into(), default, lo, hi, span: None, kind: ParamKind::Float }
    }

    /// Whether `v` is an allowed value: finite and inside the declared range. The one range check every
    /// caller uses (a run's parameter values, scene `params`, checks that vary parameters).
    pub fn admits(&self, v: f64) -> bool {
        v.is_finite() && v >= self.lo && v <= self.hi
    }
}

/// Display metadata from `@name "…"` and `@cite "…"` lines.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Meta {
    pub name: Option<String>,
    pub citation: Option<String>,
}

/// A whole lowered .brdf file: what every stage after the front end consumes.
#[derive(Clone, Debug)]
pub struct Formula {
    pub meta: Meta,
    pub params: Vec<ParamDecl>,
    pub ir: Ir,
    pub root: NodeId,
    /// File name for diagnostics and reports.
    pub file: String,
    /// The source text, kept so later stages can quote it.
    pub source: String,
    /// For a formula with a colour result: its red, green and blue channels over one arena ([`Channels`]). The
    /// formula itself is then the red channel. Every stage below the front end works on scalar formulas; what
    /// shows colour (eval, render, energy) asks for [`Formula::channels`] before it compiles.
    pub rgb: Option<Box<Channels>>,
}

/// A colour formula's red, green and blue channels as one multi-output arena — the model a shading program's
/// outputs use ([`crate::backend::program::Program`]): the channels' common nodes are stored once, each
/// channel's own nodes after the earlier channels' (so printing or emitting them together shares what they
/// have in common).
#[derive(Clone, Debug)]
pub struct Channels {
    pub ir: Ir,
    /// Red, green, blue.
    pub roots: [NodeId; 3],
}

impl Channels {
    /// The roots of `formulas` (each a scalar formula) in one arena of live nodes only, channel by channel.
    fn merge(formulas: &[Formula]) -> (Ir, Vec<NodeId>) {
        let mut ir = Ir::new();
        let mut roots = Vec::with_capacity(formulas.len());
        for c in formulas {
            let (cir, croot) = c.ir.compact(c.root);
            let mut map: Vec<NodeId> = Vec::with_capacity(cir.len());
            for id in cir.ids() {
                map.push(ir.push(cir.node(id).map_args(|a| map[a.index()]), cir.span(id)));
            }
            roots.push(map[croot.index()]);
        }
        (ir, roots)
    }
}

impl Formula {
    /// The scalar formulas to compile: the formula itself, or its three colour channels (each compacted out of
    /// the shared arena).
    pub fn channels(&self) -> Vec<Formula> {
        match &self.rgb {
            None => vec![self.clone()],
            Some(c) => c.roots.iter().map(|&r| self.scalar(&c.ir, r)).collect(),
        }
    }

    /// The scalar formula of `root` in `ir`, with this formula's declarations.
    fn scalar(&self, ir: &Ir, root: NodeId) -> Formula {
        let (ir, root) = ir.compact(root);
        Formula { meta: self.meta.clone(), params: self.params.clone(), ir, root, file: self.file.clone(), source: self.source.clone(), rgb: None }
    }

    /// [`Formula::channels`] for reports per formula: a colour formula's channels are named `NAME (red)`,
    /// `NAME (green)`, `NAME (blue)`.
    pub fn named_channels(&self) -> Vec<Formula> {
        let mut chans = self.channels();
        if chans.len() == 3 {
            for (c, name) in chans.iter_mut().zip(["red", "green", "blue"]) {
                c.meta.name = Some(format!("{} ({name})", self.display_name()));
            }
        }
        chans
    }

    /// A colour formula from one arena with three channel roots; the result is the red channel, carrying all
    /// three in [`Formula::rgb`].
    pub fn from_channels(meta: Meta, params: Vec<ParamDecl>, ir: &Ir, roots: [NodeId; 3], file: String, source: String) -> Formula {
        let red = Formula { meta, params, ir: Ir::new(), root: NodeId(0), file, source, rgb: None };
        let chans = roots.map(|r| red.scalar(ir, r));
        red.with_channels(&chans)
    }

    /// This formula's declarations with `chans` (red, green, blue; each a scalar formula over them) as its
    /// colour channels: what a stage that works per channel (baking, simplifying) returns for a colour formula.
    pub fn with_channels(&self, chans: &[Formula; 3]) -> Formula {
        let (ir, r) = Channels::merge(chans);
        let rgb = Channels { ir, roots: [r[0], r[1], r[2]] };
        Formula { rgb: Some(Box::new(rgb)), ..chans[0].clone() }
    }

    /// The roots to print or emit together, in one arena of live nodes only: the formula's own, or its three
    /// colour channels' (hash-consing shares what the channels have in common).
    pub(crate) fn merged_roots(&self) -> (Ir, Vec<NodeId>) {
        match &self.rgb {
            Some(c) => (c.ir.clone(), c.roots.to_vec()),
            None => Channels::merge(std::slice::from_ref(self)),
        }
    }

    pub fn is_rgb(&self) -> bool {
        self.rgb.is_some()
    }

    /// This formula with each builtin that only recodes a language function written as that function
    /// ([`Builtin::language_form`]: the simplifier's `sinnear` as `sin`): what text and shaders for people and
    /// other tools show.
    pub fn in_language(&self) -> Formula {
        if self.is_rgb() {
            let c = self.channels();
            return self.with_channels(&[c[0].in_language(), c[1].in_language(), c[2].in_language()]);
        }
        let mut ir = Ir::new();
        let mut map: Vec<NodeId> = Vec::with_capacity(self.ir.len());
        for id in self.ir.ids() {
            let n = match *self.ir.node(id) {
                Node::Call(b, a) => Node::Call(b.language_form(), a),
                n => n,
            };
            let n = n.map_args(|a| map[a.index()]);
            map.push(ir.push(n, self.ir.span(id)));
        }
        Formula { ir, root: map[self.root.index()], ..self.clone() }
    }

    /// Default parameter values, in declaration order.
    pub fn default_params(&self) -> Vec<f64> {
        self.params.iter().map(|p| p.default).collect()
    }

    pub fn param_index(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| p.name == name)
    }

    pub fn used_inputs(&self) -> InputSet {
        self.ir.used_inputs(self.root)
    }

    /// A display name: the `@name` metadata, else the file stem.
    pub fn display_name(&self) -> String {
        if let Some(n) = &self.meta.name {
            return n.clone();
        }
        std::path::Path::new(&self.file)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.file.clone())
    }

    /// The expression as text with the usual precedence, shared nodes printed inline — unless inlining would
    /// print more than [`MAX_INLINE_NODES`] nodes (a DAG that shares much, such as repeated `fn` calls, can
    /// stand for a tree of 2^40 nodes): then as [`Formula::to_program_text`]'s `let` lines, whose size is
    /// the formula's own.
    pub fn to_text(&self) -> String {
        let mut tree: Vec<u64> = Vec::with_capacity(self.ir.len());
        for id in self.ir.ids() {
            let mut n = 1u64;
            self.ir.node(id).for_each_arg(|a| n = n.saturating_add(tree[a.index()]));
            tree.push(n);
        }
        if tree.get(self.root.index()).is_some_and(|&n| n > MAX_INLINE_NODES) {
            return self.to_program_text();
        }
        crate::ir::print::expr(self, self.root)
    }

    /// The formula as `let` lines naming each shared subexpression, then the final expression
    /// (see [`print::with_lets`]); what `lobe check` shows for a simplified formula.
    pub fn to_program_text(&self) -> String {
        crate::ir::print::with_lets(self)
    }
}

/// The largest tree [`Formula::to_text`] prints inline.
pub const MAX_INLINE_NODES: u64 = 100_000;

pub mod print {
    //! Pretty printer: the simplified formula as `lobe check` shows it.
    use super::*;

    /// Binding strength in the .brdf grammar, loosest first: `?:` 1, `||` 2, `&&` 3, comparisons 4, `+ -` 5,
    /// `* /` 6, unary 7, atoms and calls 8. Comparisons and selects print in operator form (see [`write`]).
    fn prec(n: &Node) -> u8 {
        use crate::builtins::Builtin as B;
        match n {
            Node::Call(B::Select, _) => 1,
            Node::Call(B::Lt | B::Le | B::Eq | B::Ne, _) => 4,
            Node::Binary(BinOp::Add | BinOp::Sub, ..) => 5,
            Node::Binary(BinOp::Mul | BinOp::Div, ..) => 6,
            Node::Neg(_) => 7,
            Node::Const(b) if f64::from_bits(*b) < 0.0 => 7,
            _ => 8,
        }
    }

    /// A constant as the language reads it back: `number`, except that the non-finite values, which have no
    /// literal, print as the divisions that make them.
    fn literal(v: f64) -> String {
        match v {
            _ if v.is_nan() => "(0/0)".into(),
            f64::INFINITY => "(1/0)".into(),
            f64::NEG_INFINITY => "(-1/0)".into(),
            _ => number(v),
        }
    }

    /// A number for people: `pi`, `inf`, `nan`, or the shortest decimal that reads back exactly.
    pub(crate) fn number(v: f64) -> String {
        if v.is_nan() {
            return "nan".into();
        }
        if v.is_infinite() {
            return if v > 0.0 { "inf".into() } else { "-inf".into() };
        }
        if v == std::f64::consts::PI {
            return "pi".into();
        }
        let s = format!("{v}");
        if s.len() > 18 {
            format!("{v:e}")
        } else {
            s
        }
    }

    pub(crate) fn expr(f: &Formula, id: NodeId) -> String {
        let mut out = String::new();
        write(f, id, &mut out, &HashMap::new());
        out
    }

    /// The formula with every shared non-leaf subexpression named once, as the .brdf language writes it:
    /// `let nh = clamp(NH, 0, 1)` for a clamped input read several times, `let t1 = …` otherwise, then the
    /// final expression. A chain like x^4 prints as `let t1 = x * x` and `t1 * t1`, showing what is computed.
    pub(crate) fn with_lets(f: &Formula) -> String {
        let (mut out, roots) = with_lets_of(f, &[f.root]);
        out.push_str(&roots[0]);
        out
    }

    /// [`with_lets`] for several roots of `f.ir` (the channels of a colour formula, say): the `let` lines shared
    /// by all of them, then each root's expression.
    pub(crate) fn with_lets_of(f: &Formula, roots: &[NodeId]) -> (String, Vec<String>) {
        let counts = f.ir.use_counts_of(roots);
        let mut names: HashMap<NodeId, String> = HashMap::new();
        // The names given so far, for the uniqueness check (a scan of `names` made printing quadratic).
        let mut given: std::collections::HashSet<String> = std::collections::HashSet::new();
        let mut out = String::new();
        let taken = |s: &str| f.params.iter().any(|p| p.name == s) || s == "pi";
        let mut k = 0;
        let top = roots.iter().map(|r| r.index()).max().unwrap_or(0);
        for id in f.ir.ids().take(top) {
            let n = f.ir.node(id);
            if counts[id.index()] < 2 || roots.contains(&id) || matches!(n, Node::Const(_) | Node::Input(_) | Node::Param(_) | Node::Column(_)) {
                continue;
            }
            let mut name = match n {
                Node::Call(crate::builtins::Builtin::Clamp, [x, ..]) => match f.ir.node(*x) {
                    Node::Input(i) => i.name().to_lowercase(),
                    _ => String::new(),
                },
                _ => String::new(),
            };
            while name.is_empty() || taken(&name) || given.contains(&name) {
                k += 1;
                name = format!("t{k}");
            }
            out.push_str("let ");
            out.push_str(&name);
            out.push_str(" = ");
            write(f, id, &mut out, &names);
            out.push('\n');
            given.insert(name.clone());
            names.insert(id, name);
        }
        let exprs = roots
            .iter()
            .map(|r| {
                let mut e = String::new();
                write(f, *r, &mut e, &names);
                e
            })
            .collect();
        (out, exprs)
    }

    /// The formula as a source file of lobe's language, for people to read and edit (`lobe import`): `@name`,
    /// the parameters (`param x = 0.5 in 0..1`, `param flag = true`, `param c = rgb(…)`), `@domain raw` (the
    /// expression is taken as written: no input or result clamp added), the shared subexpressions as `let`s and
    /// the final expression, or `rgb(r, g, b)` for a colour formula. The implicit `n` is not declared.
    pub fn source(f: &Formula, header: &str) -> String {
        let mut out = String::new();
        for line in header.lines() {
            out.push_str("# ");
            out.push_str(line);
            out.push('\n');
        }
        out.push_str(&format!("@name \"{}\"\n", f.display_name().replace('"', "'")));
        for p in &f.params {
            match p.kind {
                _ if p.span.is_none() && p.name == "n" => {}
                ParamKind::Float => out.push_str(&format!("param {} = {} in {}..{}\n", p.name, number(p.default), number(p.lo), number(p.hi))),
                ParamKind::Bool => out.push_str(&format!("param {} = {}\n", p.name, p.default != 0.0)),
                ParamKind::Color(0) => {
                    let base = p.name.strip_suffix(".r").unwrap_or(&p.name);
                    let ch: Vec<String> = ["r", "g", "b"]
                        .iter()
                        .map(|c| f.params.iter().find(|q| q.name == format!("{base}.{c}")).map_or(0.0, |q| q.default))
                        .map(number)
                        .collect();
                    out.push_str(&format!("param {base} = rgb({})\n", ch.join(", ")));
                }
                ParamKind::Color(_) => {}
            }
        }
        out.push_str("@domain raw\n");
        let (ir, roots) = f.merged_roots();
        let merged = Formula { ir, root: roots[roots.len() - 1], rgb: None, ..f.clone() };
        let (lets, exprs) = with_lets_of(&merged, &roots);
        out.push_str(&lets);
        if exprs.len() == 3 {
            out.push_str(&format!("rgb({})\n", exprs.join(", ")));
        } else {
            out.push_str(&exprs.concat());
            out.push('\n');
        }
        out
    }

    /// Writes the expression at `id`. Iterative (an explicit stack of pending pieces), so a 500 000-deep chain
    /// that the front end accepts prints instead of overflowing the stack.
    ///
    /// Comparisons print as `a < b`, selects as `c ? a : b` (`c && a` and `c || b` for the selects `&&` and
    /// `||` lower to, `!c` for `c == 0` on a bool), so the text parses back to the same values. The language
    /// types what the IR does not: a node is a bool when it is a comparison, a bool parameter, or a select of
    /// bools; each operand is printed for the type its place needs, a bool where a number is needed as
    /// `c ? 1 : 0`, a number where a bool is needed as `x != 0` (the select's own test), 0 and 1 as `false` and
    /// `true`. Cost: linear in the printed nodes (bool-ness is memoised per call).
    fn write(f: &Formula, id: NodeId, out: &mut String, names: &HashMap<NodeId, String>) {
        use crate::builtins::Builtin as B;
        enum Item {
            /// A node to print; `min` is the precedence below which it needs parentheses (`None`: top level);
            /// `want_bool`: the place needs a bool.
            Node(NodeId, Option<u8>, bool),
            Text(&'static str),
        }
        let mut memo: HashMap<NodeId, bool> = HashMap::new();
        let top = is_bool(f, id, &mut memo);
        let mut stack = vec![Item::Node(id, None, top)];
        while let Some(item) = stack.pop() {
            let (id, min, want) = match item {
                Item::Text(t) => {
                    out.push_str(t);
                    continue;
                }
                Item::Node(id, min, want) => (id, min, want),
            };
            let n = f.ir.node(id);
            let natural = is_bool(f, id, &mut memo);
            let open = |out: &mut String, stack: &mut Vec<Item>, p: u8| {
                if min.is_some_and(|m| p < m) {
                    out.push('(');
                    stack.push(Item::Text(")"));
                }
            };
            // Conversions between the node's type and the place's. A select takes the place's type (its branches
            // are printed for it) unless it is named, and a name has the type it was printed with.
            let named = min.is_some() && names.contains_key(&id);
            let fixed = named || !matches!(n, Node::Call(B::Select, _));
            if want && !natural && fixed {
                match n.as_const() {
                    Some(c) if c == 0.0 && c.is_sign_positive() => out.push_str("false"),
                    Some(1.0) => out.push_str("true"),
                    _ => {
                        open(out, &mut stack, 4);
                        stack.push(Item::Text(" != 0"));
                        stack.push(Item::Node(id, Some(5), false));
                    }
                }
                continue;
            }
            if !want && natural && fixed {
                open(out, &mut stack, 1);
                stack.push(Item::Text(" ? 1 : 0"));
                stack.push(Item::Node(id, Some(2), true));
                continue;
            }
            if min.is_some() {
                if let Some(name) = names.get(&id) {
                    out.push_str(name);
                    continue;
                }
            }
            let p = prec(n);
            match n {
                Node::Call(B::Select, [c, a, b]) => {
                    let (bool_a, bool_b) = (is_bool(f, *a, &mut memo), is_bool(f, *b, &mut memo));
                    if want && bool_a && f.ir.node(*b) == &Node::constant(0.0) {
                        open(out, &mut stack, 3);
                        stack.push(Item::Node(*a, Some(4), true));
                        stack.push(Item::Text(" && "));
                        stack.push(Item::Node(*c, Some(3), true));
                    } else if want && bool_b && f.ir.node(*a) == &Node::constant(1.0) {
                        open(out, &mut stack, 2);
                        stack.push(Item::Node(*b, Some(3), true));
                        stack.push(Item::Text(" || "));
                        stack.push(Item::Node(*c, Some(2), true));
                    } else {
                        open(out, &mut stack, 1);
                        stack.push(Item::Node(*b, Some(1), want));
                        stack.push(Item::Text(" : "));
                        stack.push(Item::Node(*a, Some(0), want));
                        stack.push(Item::Text(" ? "));
                        stack.push(Item::Node(*c, Some(2), true));
                    }
                    continue;
                }
                Node::Call(op @ (B::Lt | B::Le | B::Eq | B::Ne), [a, b, _]) => {
                    // `==` on bools when both sides are bools or 0/1 constants, at least one a bool.
                    let mut boolish = |x: NodeId| {
                        let c = f.ir.node(x).as_const();
                        (c.is_some_and(|c| c == 1.0 || c.to_bits() == 0), is_bool(f, x, &mut memo))
                    };
                    let ((ca, ba), (cb, bb)) = (boolish(*a), boolish(*b));
                    let on_bools = matches!(op, B::Eq | B::Ne) && (ca || ba) && (cb || bb) && (ba || bb);
                    if on_bools && *op == B::Eq && f.ir.node(*b) == &Node::constant(0.0) {
                        open(out, &mut stack, 7);
                        out.push('!');
                        stack.push(Item::Node(*a, Some(7), true));
                        continue;
                    }
                    open(out, &mut stack, 4);
                    stack.push(Item::Node(*b, Some(5), on_bools));
                    stack.push(Item::Text(match op {
                        B::Lt => " < ",
                        B::Le => " <= ",
                        B::Eq => " == ",
                        _ => " != ",
                    }));
                    stack.push(Item::Node(*a, Some(5), on_bools));
                    continue;
                }
                _ => {}
            }
            open(out, &mut stack, p);
            match n {
                Node::Const(b) => out.push_str(&literal(f64::from_bits(*b))),
                Node::Input(i) => out.push_str(i.name()),
                Node::Param(p) => out.push_str(&f.params[*p as usize].name),
                // Not in the language: printed as the shading program's column, for dumps only.
                Node::Column(k) => out.push_str(&format!("column{k}")),
                Node::Neg(a) => {
                    out.push('-');
                    stack.push(Item::Node(*a, Some(7), false));
                }
                Node::Binary(op, a, b) => {
                    // The right operand needs parentheses at equal precedence: for - and / by algebra, and for
                    // + and * because floating-point addition and multiplication are not associative
                    // (a + (b + c) differs from a + b + c), so the text shows the evaluation order the IR has.
                    stack.push(Item::Node(*b, Some(p + 1), false));
                    stack.push(Item::Text(match op {
                        BinOp::Add => " + ",
                        BinOp::Sub => " - ",
                        BinOp::Mul => " * ",
                        BinOp::Div => " / ",
                    }));
                    stack.push(Item::Node(*a, Some(p), false));
                }
                Node::Call(b, args) => {
                    out.push_str(b.name());
                    out.push('(');
                    stack.push(Item::Text(")"));
                    for (k, a) in args[..b.arity()].iter().enumerate().rev() {
                        stack.push(Item::Node(*a, Some(0), false));
                        if k > 0 {
                            stack.push(Item::Text(", "));
                        }
                    }
                }
            }
        }
    }

    /// Whether `id` is a bool to the language: a comparison, a bool parameter, or a select whose branches are
    /// bools (or the constants 0 and 1, with at least one bool). Iterative over chains of selects.
    fn is_bool(f: &Formula, id: NodeId, memo: &mut HashMap<NodeId, bool>) -> bool {
        use crate::builtins::Builtin as B;
        // `None`: a select, decided from its branches.
        let direct = |n: &Node| match n {
            Node::Call(B::Lt | B::Le | B::Eq | B::Ne, _) => Some(true),
            Node::Param(p) => Some(f.params[*p as usize].kind == ParamKind::Bool),
            Node::Call(B::Select, _) => None,
            _ => Some(false),
        };
        let mut stack = vec![id];
        while let Some(&top) = stack.last() {
            if memo.contains_key(&top) {
                stack.pop();
                continue;
            }
            let n = f.ir.node(top);
            let Node::Call(B::Select, [_, a, b]) = *n else {
                memo.insert(top, direct(n).unwrap_or(false));
                stack.pop();
                continue;
            };
            let pending: Vec<NodeId> =
                [a, b].into_iter().filter(|x| direct(f.ir.node(*x)).is_none() && !memo.contains_key(x)).collect();
            if !pending.is_empty() {
                stack.extend(pending);
                continue;
            }
            let kind = |x: NodeId, memo: &HashMap<NodeId, bool>| {
                let n = f.ir.node(x);
                if let Some(c) = n.as_const() {
                    return (c == 1.0 || c.to_bits() == 0).then_some(false);
                }
                direct(n).unwrap_or_else(|| memo.get(&x).copied().unwrap_or(false)).then_some(true)
            };
            // Each branch: Some(true) a bool, Some(false) a 0/1 constant, None a number.
            let (ka, kb) = (kind(a, memo), kind(b, memo));
            let v = ka.is_some() && kb.is_some() && (ka == Some(true) || kb == Some(true));
            memo.insert(top, v);
            stack.pop();
        }
        memo[&id]
    }
}


#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_consing_shares_equal_nodes() {
        let mut ir = Ir::new();
        let s = Span::default();
        let nh = ir.input(Input::NH, s);
        let a = ir.call(Builtin::Acos, &[nh], s);
        let b = ir.call(Builtin::Acos, &[nh], s);
        assert_eq!(a, b);
        assert_eq!(ir.len(), 2);
    }

    #[test]
    fn compact_drops_dead_nodes() {
        let mut ir = Ir::new();
        let s = Span::default();
        let nh = ir.input(Input::NH, s);
        let _dead = ir.input(Input::NL, s);
        let two = ir.konst(2.0, s);
        let root = ir.bin(BinOp::Mul, two, nh, s);
        let (c, r) = ir.compact(root);
        assert_eq!(c.len(), 3);
        assert_eq!(c.used_inputs(r).iter().collect::<Vec<_>>(), vec![Input::NH]);
    }
}
