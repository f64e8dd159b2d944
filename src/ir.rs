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
    #[inline]
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

    /// Whether any channel reads the parameter `name` (a declared parameter may go unread: every formula
    /// declares the papers' `n`).
    pub fn reads_param(&self, name: &str) -> bool {
        self.param_index(name).is_some_and(|i| self.channels().iter().any(|c| c.ir.used_params(c.root).contains(&(i as u16))))
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

pub mod print;


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
