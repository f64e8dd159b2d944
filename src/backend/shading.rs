//! Shading programs: a material's whole shading, from per-pixel data columns to the pixel colour, as one lobe
//! IR with several outputs, run by the interpreter here and compiled by the JIT (`jit::shade`).
//!
//! The JIT's side is `jit::shade` (src/backend/jit/shade.rs); the renderer picks one of the two per material
//! (`render::shade::ProgramCode`).
//!
//! Design. The renderer fills a [`Spec`] per material (eye, lights, the colour uniforms, which geometric
//! quantities the formula reads, the cut-off) and [`Program::new`] writes, as IR over `Node::Column` leaves
//! (interpolated position, normal and, for formulas that read directions, tangent):
//! the view vector and its inverse length, 1/|n|, per light NL (lit = NL > 0, and the lobe cosine above the
//! cut-off), VL/NH/VH/VR and the local-frame components only when the formula reads what needs them, the
//! formula itself inlined with those nodes in place of its `Input`s (each channel of a colour formula, sharing
//! their common nodes through hash-consing), F non-finite → 0 and counted, and the colour sum
//! I = ka·Ia·C + Σ Il·(kd·NL⁺·C + ks·coef·F·Cs). Lights, colours and coefficients are constants; the formula's
//! parameters stay `Param` nodes, so changing them needs no recompilation.
//!
//! Outputs ([`Out`]): r, g, b, and three per-pixel counters (non-finite F, evaluations, cut-off skips), small
//! integers in f64 that the renderer sums exactly.
//!
//! Guarded regions. F of light k is computed only where some pixel is lit by k: the nodes reachable only
//! through light k's guarded values (`select(lit_k, F', 0)` per channel and its non-finite flag) form region k.
//! A backend evaluates a region when its lit value is non-zero (the interpreter per pixel, the JIT per vector
//! of lanes: a branch on `any(lit)`), and otherwise takes +0 for its outputs — exactly what the selects give
//! where nothing is lit, so skipping is invisible in the results and both backends agree bit for bit.
//!
//! Cost model (per pixel, before F): ~30 flops, two square roots and two divisions for the view step; per
//! light ~15 flops, one root and one division (point lights), ~10 more and one root for the half vector; the
//! frame adds ~45 flops and a root per pixel (work that several light regions need is computed once, outside
//! them). Measured (BENCHMARKS.md): the JIT program ~6 ns per pixel for one light and a cheap formula. The
//! loop is bound by its instruction count, not by the divider: without the inverse lengths' roots and divisions
//! it would be only ~16 % faster, and f32 ones (converted at the boundary) made it slower, so inverse lengths
//! are exact `1/sqrt` in f64 (an f32 geometry does not pay on 128-bit lanes: BENCHMARKS.md, shade5).

use crate::base::span::Span;
use crate::builtins::{Builtin, Mode};
use crate::ir::{BinOp, Formula, Input, Ir, Node, NodeId, N_INPUTS};

/// Most data columns a program reads: position, normal, tangent (3 each).
pub const MAX_COLUMNS: usize = 9;

/// The program's outputs, per pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Out {
    R,
    G,
    B,
    /// Non-finite F values (counted per channel and light; drawn as no light).
    NonFinite,
    /// F evaluations (lit pixel × light × channel).
    Evals,
    /// Lit pixel × light pairs the cut-off skipped.
    Cut,
}

pub const N_OUTPUTS: usize = 6;

/// One light of the scene, in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// A point light at `at`; else `at` is the unit direction towards the light.
    pub point: bool,
    pub at: [f64; 3],
    pub color: [f64; 3],
}

/// What a material's shading computes, as the renderer's plan decided it.
#[derive(Clone, Debug, PartialEq)]
pub struct Spec {
    pub eye: [f64; 3],
    pub lights: Vec<Light>,
    /// ka·Ia·C, kd·C, ks·coef·Cs.
    pub ambient: [f64; 3],
    pub diffuse: [f64; 3],
    pub spec: [f64; 3],
    /// F is evaluated at all (ks ≠ 0).
    pub specular: bool,
    /// F is multiplied by NL.
    pub times_nl: bool,
    /// (cos, sin) of the tangent angle, when the formula reads directions (columns 6..9 hold the tangent).
    pub tangent_rotation: Option<[f64; 2]>,
    /// F is not evaluated where this lobe cosine is below the value.
    pub cutoff: Option<(Input, f64)>,
}

/// A region of nodes evaluated only when `lit` is non-zero (module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    pub lit: NodeId,
    /// The values leaving the region (+0 when it is skipped).
    pub outputs: Vec<NodeId>,
    /// The region's nodes in order (those reachable from `outputs` that are neither invariant nor outer).
    pub nodes: Vec<NodeId>,
    /// Emitted when the walk over the arena reaches this node (the last of `outputs`).
    pub at: NodeId,
}

/// Where a node is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// Reads no column: computed once per call (constants, parameters, parameter-only work).
    Invariant,
    /// Computed for every pixel.
    Outer,
    /// Computed inside guarded regions only.
    Guarded,
}

/// A shading program: a compacted IR (every node live) with its outputs and guarded regions.
#[derive(Clone, Debug)]
pub struct Program {
    pub ir: Ir,
    pub outputs: [NodeId; N_OUTPUTS],
    pub regions: Vec<Region>,
    pub class: Vec<Class>,
    /// Data columns read: 6 (position, normal), or 9 with the tangent; fewer if the program ignores some.
    pub columns: usize,
    /// Parameter slots the formula declares.
    pub n_params: usize,
}

/// IR construction with the few folds that keep trivial nodes out (×1, +0 with a constant).
struct Builder {
    ir: Ir,
    s: Span,
}

impl Builder {
    fn k(&mut self, v: f64) -> NodeId {
        self.ir.konst(v, self.s)
    }
    fn bin(&mut self, op: BinOp, a: NodeId, b: NodeId) -> NodeId {
        if op == BinOp::Mul && self.ir.node(b).as_const() == Some(1.0) {
            return a;
        }
        self.ir.bin(op, a, b, self.s)
    }
    fn add(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.bin(BinOp::Add, a, b)
    }
    fn sub(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.bin(BinOp::Sub, a, b)
    }
    fn mul(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.bin(BinOp::Mul, a, b)
    }
    fn call(&mut self, f: Builtin, args: &[NodeId]) -> NodeId {
        self.ir.call(f, args, self.s)
    }
    fn dot(&mut self, a: [NodeId; 3], b: [NodeId; 3]) -> NodeId {
        let x = self.mul(a[0], b[0]);
        let y = self.mul(a[1], b[1]);
        let z = self.mul(a[2], b[2]);
        let xy = self.add(x, y);
        self.add(xy, z)
    }
    /// 1/√x.
    fn inv_len(&mut self, x: NodeId) -> NodeId {
        let one = self.k(1.0);
        let r = self.call(Builtin::Sqrt, &[x]);
        self.bin(BinOp::Div, one, r)
    }
    /// `c ? a : b` with `c` a 0/1 flag.
    fn select(&mut self, c: NodeId, a: NodeId, b: NodeId) -> NodeId {
        self.call(Builtin::Select, &[c, a, b])
    }
    fn lt(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.call(Builtin::Lt, &[a, b])
    }
    fn le(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.call(Builtin::Le, &[a, b])
    }
    fn splat(&mut self, v: [f64; 3]) -> [NodeId; 3] {
        v.map(|c| self.k(c))
    }
    fn sub3(&mut self, a: [NodeId; 3], b: [NodeId; 3]) -> [NodeId; 3] {
        [self.sub(a[0], b[0]), self.sub(a[1], b[1]), self.sub(a[2], b[2])]
    }

    /// Copies the compacted formula `f` in, with `inputs` in place of its inputs; returns its root.
    fn inline(&mut self, f: &Formula, inputs: &[Option<NodeId>; N_INPUTS]) -> Result<NodeId, String> {
        let (fir, root) = f.ir.compact(f.root);
        let mut map = Vec::with_capacity(fir.len());
        for id in fir.ids() {
            let n = match *fir.node(id) {
                Node::Input(i) => inputs[i.index()].ok_or_else(|| format!("the shading program has no value for input {}", i.name()))?,
                Node::Column(k) => return Err(format!("a formula reads data column {k}")),
                n => {
                    let m = n.map_args(|a| map[a.index()]);
                    self.ir.push(m, fir.span(id))
                }
            };
            map.push(n);
        }
        Ok(map[root.index()])
    }
}

impl Program {
    /// The program shading with `spec` and the formula's channels (one, or red, green, blue).
    pub fn new(spec: &Spec, channels: &[&Formula]) -> Result<Program, String> {
        if !(channels.len() == 1 || channels.len() == 3) {
            return Err(format!("a shading program takes 1 or 3 channels, not {}", channels.len()));
        }
        let mut b = Builder { ir: Ir::new(), s: Span::default() };
        let cols: Vec<NodeId> = (0..MAX_COLUMNS as u16).map(|k| b.ir.column(k, Span::default())).collect();
        let (p, n) = ([cols[0], cols[1], cols[2]], [cols[3], cols[4], cols[5]]);
        let zero = b.k(0.0);
        let one = b.k(1.0);
        let two = b.k(2.0);
        let eye = b.splat(spec.eye);
        // The view step: v = eye − p, 1/|n|, 1/|v|, NV.
        let v = b.sub3(eye, p);
        let nn = b.dot(n, n);
        let inv_n = b.inv_len(nn);
        let vv = b.dot(v, v);
        let inv_v = b.inv_len(vv);
        let nvr = b.dot(n, v);
        let nvn = b.mul(nvr, inv_n);
        let nv = b.mul(nvn, inv_v);
        let reads = channels.iter().map(|f| f.used_inputs()).collect::<crate::ir::InputSet>();
        let needs = |i: Input| reads.contains(i);
        let view_light = needs(Input::NH) || needs(Input::VH) || needs(Input::VR);
        // The frame step: T̂ = norm(t − N̂(N̂·t)) (Duff et al.'s tangent of N̂ where t ∥ n), B̂ = N̂ × T̂, turned.
        let frame = spec.tangent_rotation.map(|[c, s]| {
            let t = [cols[6], cols[7], cols[8]];
            let nh = [b.mul(n[0], inv_n), b.mul(n[1], inv_n), b.mul(n[2], inv_n)];
            let kk = b.dot(nh, t);
            let proj = [b.mul(nh[0], kk), b.mul(nh[1], kk), b.mul(nh[2], kk)];
            let u = b.sub3(t, proj);
            let l2 = b.dot(u, u);
            let eps = b.k(1e-20);
            let ok = b.lt(eps, l2);
            let neg = b.lt(nh[2], zero);
            let m1 = b.k(-1.0);
            let sign = b.select(neg, m1, one);
            let sd = b.add(sign, nh[2]);
            let q = b.bin(BinOp::Div, m1, sd);
            // Duff's tangent (1 + s·a²·q, s·a·b·q, −s·a), s·a built once.
            let sa = b.mul(sign, nh[0]);
            let saa = b.mul(sa, nh[0]);
            let saq = b.mul(saa, q);
            let ox = b.add(one, saq);
            let sab = b.mul(sa, nh[1]);
            let oy = b.mul(sab, q);
            let oz = b.ir.neg(sa, Span::default());
            let il = b.inv_len(l2);
            let il = b.select(ok, il, one);
            let un = [b.mul(u[0], il), b.mul(u[1], il), b.mul(u[2], il)];
            let u = [b.select(ok, un[0], ox), b.select(ok, un[1], oy), b.select(ok, un[2], oz)];
            let cross = |b: &mut Builder, i: usize, j: usize| {
                let x = b.mul(nh[i], u[j]);
                let y = b.mul(nh[j], u[i]);
                b.sub(x, y)
            };
            let w = [cross(&mut b, 1, 2), cross(&mut b, 2, 0), cross(&mut b, 0, 1)];
            let (ck, sk) = (b.k(c), b.k(s));
            let rot = |b: &mut Builder, x: NodeId, y: NodeId, sign: f64| {
                let cx = b.mul(ck, x);
                let sy = b.mul(sk, y);
                if sign > 0.0 { b.add(cx, sy) } else { b.sub(cx, sy) }
            };
            let tt = [rot(&mut b, u[0], w[0], 1.0), rot(&mut b, u[1], w[1], 1.0), rot(&mut b, u[2], w[2], 1.0)];
            let bb = [rot(&mut b, w[0], u[0], -1.0), rot(&mut b, w[1], u[1], -1.0), rot(&mut b, w[2], u[2], -1.0)];
            let vt = b.dot(v, tt);
            let vx = b.mul(vt, inv_v);
            let vb = b.dot(v, bb);
            let vy = b.mul(vb, inv_v);
            (tt, bb, vx, vy)
        });
        let mut acc = b.splat(spec.ambient);
        let mut counters: [Option<NodeId>; 3] = [None; 3];
        let count = |b: &mut Builder, c: &mut Option<NodeId>, x: NodeId| *c = Some(c.map_or(x, |c| b.add(c, x)));
        let mut regions: Vec<(NodeId, Vec<NodeId>)> = vec![];
        for light in &spec.lights {
            let (l, il) = if light.point {
                let lp = b.splat(light.at);
                let l = b.sub3(lp, p);
                let ll = b.dot(l, l);
                (l, b.inv_len(ll))
            } else {
                (b.splat(light.at), one)
            };
            let nlr = b.dot(n, l);
            let nln = b.mul(nlr, inv_n);
            let nl = b.mul(nln, il);
            let lit_nl = b.lt(zero, nl);
            let mut x: [Option<NodeId>; N_INPUTS] = [None; N_INPUTS];
            x[Input::NL.index()] = Some(nl);
            x[Input::Lz.index()] = Some(nl);
            x[Input::NV.index()] = Some(nv);
            x[Input::Vz.index()] = Some(nv);
            if view_light {
                let vlr = b.dot(v, l);
                let vln = b.mul(vlr, inv_v);
                let vl = b.mul(vln, il);
                if needs(Input::NH) || needs(Input::VH) {
                    // |L̂ + V̂|² = 2 + 2VL; H undefined (0) where L = −V.
                    let tvl = b.mul(two, vl);
                    let h2 = b.add(two, tvl);
                    let tiny = b.k(1e-300);
                    let ok = b.lt(tiny, h2);
                    let ih = b.inv_len(h2);
                    let ih = b.select(ok, ih, zero);
                    let s = b.add(nl, nv);
                    x[Input::NH.index()] = Some(b.mul(s, ih));
                    let s = b.add(one, vl);
                    x[Input::VH.index()] = Some(b.mul(s, ih));
                }
                if needs(Input::VR) {
                    let tn = b.mul(two, nl);
                    let tnv = b.mul(tn, nv);
                    x[Input::VR.index()] = Some(b.sub(tnv, vl));
                }
            }
            if let Some((tt, bb, vx, vy)) = frame {
                x[Input::Vx.index()] = Some(vx);
                x[Input::Vy.index()] = Some(vy);
                let lt = b.dot(l, tt);
                x[Input::Lx.index()] = Some(b.mul(lt, il));
                let lb = b.dot(l, bb);
                x[Input::Ly.index()] = Some(b.mul(lb, il));
            }
            let lit = match spec.cutoff {
                Some((input, cos)) => {
                    let lobe = x[input.index()].ok_or_else(|| format!("the cut-off's cosine {} is not computed", input.name()))?;
                    let c = b.k(cos);
                    let above = b.le(c, lobe);
                    b.select(lit_nl, above, zero)
                }
                None => lit_nl,
            };
            let n_pos = b.select(lit_nl, nl, zero);
            let mut f = [zero; 3];
            if spec.specular {
                let raw = channels.iter().map(|c| b.inline(c, &x)).collect::<Result<Vec<_>, _>>()?;
                let inf = b.k(f64::INFINITY);
                let mut outs = vec![];
                let mut flags = vec![];
                for r in &raw {
                    let a = b.call(Builtin::Abs, &[*r]);
                    let fin = b.lt(a, inf);
                    let fz = b.select(fin, *r, zero);
                    let bad = b.sub(one, fin);
                    outs.push(b.select(lit, fz, zero));
                    flags.push(b.select(lit, bad, zero));
                }
                for (c, g) in outs.iter().enumerate() {
                    f[c] = if spec.times_nl { b.mul(*g, nl) } else { *g };
                }
                if raw.len() == 1 {
                    f = [f[0]; 3];
                }
                for fl in &flags {
                    count(&mut b, &mut counters[0], *fl);
                }
                let nk = b.k(raw.len() as f64);
                let ev = b.mul(lit, nk);
                count(&mut b, &mut counters[1], ev);
                if spec.cutoff.is_some() {
                    let cut = b.sub(lit_nl, lit);
                    count(&mut b, &mut counters[2], cut);
                }
                regions.push((lit, outs.into_iter().chain(flags).collect()));
            }
            for c in 0..3 {
                let d = b.k(spec.diffuse[c]);
                let dn = b.mul(d, n_pos);
                let term = if spec.specular {
                    let s = b.k(spec.spec[c]);
                    let sf = b.mul(s, f[c]);
                    b.add(dn, sf)
                } else {
                    dn
                };
                let ilc = b.k(light.color[c]);
                let t = b.mul(ilc, term);
                acc[c] = b.add(acc[c], t);
            }
        }
        let [c0, c1, c2] = counters.map(|c| c.unwrap_or(zero));
        let outs = [acc[0], acc[1], acc[2], c0, c1, c2];
        // Compact everything live, keeping the regions' lit values and outputs.
        let mut roots: Vec<NodeId> = outs.to_vec();
        for (lit, o) in &regions {
            roots.push(*lit);
            roots.extend(o);
        }
        let (ir, map) = b.ir.compact_many(&roots);
        let outputs: [NodeId; N_OUTPUTS] = std::array::from_fn(|k| map[k]);
        let mut at = N_OUTPUTS;
        let mut guarded = vec![];
        for (_, o) in &regions {
            guarded.push((map[at], map[at + 1..at + 1 + o.len()].to_vec()));
            at += 1 + o.len();
        }
        // The columns the compacted program still reads (the tangent only when the formula reads directions).
        let columns = ir.nodes().iter().filter_map(|n| if let Node::Column(k) = n { Some(usize::from(*k) + 1) } else { None }).max().unwrap_or(0);
        let n_params = channels.iter().map(|c| c.params.len()).max().unwrap_or(0);
        Ok(Program::with_regions(ir, outputs, guarded, columns, n_params))
    }

    /// Classifies the nodes and builds the regions (dropping them all if their order does not allow guarding,
    /// which the construction above never produces).
    fn with_regions(ir: Ir, outputs: [NodeId; N_OUTPUTS], guarded: Vec<(NodeId, Vec<NodeId>)>, columns: usize, n_params: usize) -> Program {
        let len = ir.len();
        let inv = ir.invariant();
        // Deduplicated regions whose outputs all vary (a region of invariant values guards nothing).
        let mut guarded: Vec<(NodeId, Vec<NodeId>)> = guarded.into_iter().filter(|(_, o)| o.iter().all(|x| !inv[x.index()])).collect();
        guarded.sort_by_key(|(_, o)| o.iter().max().copied());
        guarded.dedup();
        let classify = |guarded: &[(NodeId, Vec<NodeId>)]| {
            let mut boundary = vec![false; len];
            let mut outer = vec![false; len];
            for (_, o) in guarded {
                o.iter().for_each(|x| boundary[x.index()] = true);
            }
            // Outer: reachable from the outputs (and the lit values) without entering a region's outputs.
            for r in outputs.iter().chain(guarded.iter().map(|(l, _)| l)) {
                if !boundary[r.index()] {
                    outer[r.index()] = true;
                }
            }
            for i in (0..len).rev() {
                if outer[i] {
                    ir.node(NodeId(i as u32)).for_each_arg(|a| {
                        if !boundary[a.index()] {
                            outer[a.index()] = true;
                        }
                    });
                }
            }
            let mut regions = vec![];
            // Nodes several regions need (the view step, the frame: light-independent work) are computed once
            // per pixel, outside the regions; their operands are then needed by the same regions, so the
            // outer set stays closed under operands.
            let mut needed_by = vec![0u32; len];
            for pass in 0..2 {
                regions.clear();
                for (lit, o) in guarded {
                    let mut mine = vec![false; len];
                o.iter().for_each(|x| mine[x.index()] = true);
                let top = o.iter().map(|x| x.index()).max().unwrap_or(0);
                for i in (0..=top).rev() {
                    if mine[i] {
                        ir.node(NodeId(i as u32)).for_each_arg(|a| {
                            if !outer[a.index()] && !inv[a.index()] {
                                mine[a.index()] = true;
                            }
                        });
                    }
                }
                let nodes: Vec<NodeId> = (0..=top).filter(|i| mine[*i]).map(|i| NodeId(i as u32)).collect();
                    nodes.iter().for_each(|n| needed_by[n.index()] += 1);
                    regions.push(Region { lit: *lit, outputs: o.clone(), nodes, at: NodeId(top as u32) });
                }
                if pass == 0 {
                    for (o, n) in outer.iter_mut().zip(&needed_by) {
                        *o |= *n > 1;
                    }
                }
            }
            (outer, regions)
        };
        let (mut outer, mut regions) = classify(&guarded);
        // Guarding needs every outer user of a region's outputs after the region's emission point, and the
        // lit value outer and before it.
        let ok = regions.iter().all(|r| {
            outer[r.lit.index()] && r.lit < r.at && {
                let mut fine = true;
                for (i, _) in outer.iter().enumerate().take(r.at.index()).filter(|(_, o)| **o) {
                    ir.node(NodeId(i as u32)).for_each_arg(|a| fine &= !r.outputs.contains(&a));
                }
                fine
            }
        });
        if !ok {
            (outer, regions) = classify(&[]);
        }
        let class = (0..len)
            .map(|i| if inv[i] { Class::Invariant } else if outer[i] { Class::Outer } else { Class::Guarded })
            .collect();
        Program { ir, outputs, regions, class, columns, n_params }
    }

    /// Every root a compiled program depends on (for the code cache key): outputs, then per region its lit
    /// value and outputs.
    pub fn roots(&self) -> Vec<NodeId> {
        let mut r = self.outputs.to_vec();
        for g in &self.regions {
            r.push(g.lit);
            r.extend(&g.outputs);
        }
        r
    }

    /// Nodes evaluated per pixel when every region runs (for reports).
    pub fn varying_nodes(&self) -> usize {
        self.class.iter().filter(|c| **c == Class::Outer).count() + self.regions.iter().map(|r| r.nodes.len()).sum::<usize>()
    }
}

#[derive(Clone, Copy, Debug)]
enum Step {
    /// Node `dst` = its IR node, evaluated in place (the node's operands are slots of earlier nodes).
    Op(u32, Node),
    /// If slot `lit` is zero: the slots `outs` (a range of `Interp::outs`) become +0 and the next `skip`
    /// steps are skipped.
    Guard { lit: u32, skip: u32, outs: (u32, u32) },
}

/// The reference interpreter of a [`Program`]: one loop over its steps per pixel, invariants once per call.
#[derive(Clone, Debug)]
pub struct Interp {
    invariant: Vec<(u32, Node)>,
    steps: Vec<Step>,
    outs: Vec<u32>,
    outputs: [u32; N_OUTPUTS],
    len: usize,
    columns: usize,
    mode: Mode,
}

impl Interp {
    pub fn new(p: &Program, mode: Mode) -> Interp {
        let mut invariant = vec![];
        let mut steps = vec![];
        let mut outs = vec![];
        let mut next = 0;
        for id in p.ir.ids() {
            match p.class[id.index()] {
                Class::Invariant => invariant.push((id.0, *p.ir.node(id))),
                Class::Outer => steps.push(Step::Op(id.0, *p.ir.node(id))),
                Class::Guarded => {}
            }
            while let Some(r) = p.regions.get(next).filter(|r| r.at == id) {
                let o0 = outs.len() as u32;
                outs.extend(r.outputs.iter().map(|o| o.0));
                steps.push(Step::Guard { lit: r.lit.0, skip: r.nodes.len() as u32, outs: (o0, outs.len() as u32) });
                steps.extend(r.nodes.iter().map(|n| Step::Op(n.0, *p.ir.node(*n))));
                next += 1;
            }
        }
        Interp { invariant, steps, outs, outputs: p.outputs.map(|o| o.0), len: p.ir.len(), columns: p.columns, mode }
    }

    /// The value of `node` for pixel `i`, its operands' values in `s` (the IR's semantics, as
    /// [`super::interp`]; programs have no `Input` leaves, which read as NaN like a missing input).
    fn op(&self, node: Node, s: &[f64], cols: &[&[f64]], i: usize, params: &[f64]) -> f64 {
        let v = |a: NodeId| s[a.index()];
        match node {
            Node::Const(b) => f64::from_bits(b),
            Node::Input(_) => f64::NAN,
            Node::Param(p) => params.get(p as usize).copied().unwrap_or(f64::NAN),
            Node::Column(k) => cols.get(k as usize).and_then(|c| c.get(i)).copied().unwrap_or(f64::NAN),
            Node::Neg(a) => -v(a),
            Node::Binary(op, a, b) => op.apply(v(a), v(b)),
            // Unused argument slots repeat the first argument, so all three reads are in bounds.
            Node::Call(f, [a, b, c]) => f.eval_in(self.mode, &[v(a), v(b), v(c)][..f.arity()]),
        }
    }

    /// Runs the program on `len` pixels: `cols` are the data columns, `outs` the [`N_OUTPUTS`] output columns
    /// (with fewer columns or shorter ones than the program reads, the outputs are NaN).
    pub fn run(&self, cols: &[&[f64]], params: &[f64], outs: &mut [&mut [f64]; N_OUTPUTS], len: usize) {
        if cols.len() < self.columns || cols[..self.columns].iter().any(|c| c.len() < len) {
            outs.iter_mut().for_each(|o| o.iter_mut().for_each(|x| *x = f64::NAN));
            return;
        }
        let mut s = vec![0.0; self.len];
        for &(d, op) in &self.invariant {
            s[d as usize] = self.op(op, &s, cols, 0, params);
        }
        for i in 0..len {
            let mut k = 0;
            while k < self.steps.len() {
                match self.steps[k] {
                    Step::Op(d, op) => s[d as usize] = self.op(op, &s, cols, i, params),
                    Step::Guard { lit, skip, outs: (a, b) } => {
                        if s[lit as usize] == 0.0 {
                            for o in &self.outs[a as usize..b as usize] {
                                s[*o as usize] = 0.0;
                            }
                            k += skip as usize;
                        }
                    }
                }
                k += 1;
            }
            for (o, &slot) in outs.iter_mut().zip(&self.outputs) {
                if let Some(x) = o.get_mut(i) {
                    *x = s[slot as usize];
                }
            }
        }
    }
}
