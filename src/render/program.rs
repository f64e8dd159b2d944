//! The renderer's lighting model as a multi-output program: a material's whole shading, from per-pixel data
//! columns to the pixel colour, as one lobe IR ([`crate::backend::program::Program`]) that the interpreter
//! runs and the JIT compiles; the backends see only the IR, its outputs and its guarded regions.
//!
//! Design. The renderer fills a [`Spec`] per material from its [`ShadingPlan`] ([`spec`]) (eye, lights, the colour
//! uniforms, which geometric quantities the formula reads, the cut-off) and [`build`] writes, as IR over
//! `Node::Column` leaves (interpolated position, normal and, for formulas that read directions, tangent):
//! the view vector and its inverse length, 1/|n|, per light NL (lit = NL > 0, and the lobe cosine above the
//! cut-off), VL/NH/VH/VR and the local-frame components only when the formula reads what needs them, the
//! formula itself inlined with those nodes in place of its `Input`s (each channel of a colour formula, sharing
//! their common nodes through hash-consing), F non-finite → 0 and counted, and the colour sum
//! I = ka·Ia·C + Σ Il·(kd·NL⁺·C + ks·coef·F·Cs). Lights, colours and coefficients are constants; the formula's
//! parameters stay `Param` nodes, so changing them needs no recompilation.
//!
//! Outputs ([`N_OUTPUTS`]): r, g, b, and three per-pixel counters (non-finite F, evaluations, cut-off skips), small
//! integers in f64 that the renderer sums exactly.
//!
//! Guarded regions. F of light k is computed only where some pixel is lit by k: light k's guarded values
//! (`select(lit_k, F', 0)` per channel and its non-finite flag) are one region, +0 wherever `lit_k` is zero,
//! so a backend skipping the region where nothing is lit gives the same bits.
//!
//! Cost model (per pixel, before F): ~30 flops, two square roots and two divisions for the view step; per
//! light ~15 flops, one root and one division (point lights), ~10 more and one root for the half vector; the
//! frame adds ~45 flops and a root per pixel (work that several light regions need is computed once, outside
//! them). Measured (BENCHMARKS.md): the JIT program ~6 ns per pixel for one light and a cheap formula. The
//! loop is bound by its instruction count, not by the divider: without the inverse lengths' roots and divisions
//! it would be only ~16 % faster, and f32 ones (converted at the boundary) made it slower, so inverse lengths
//! are exact `1/sqrt` in f64 (an f32 geometry does not pay on 128-bit lanes: measured +0.7–1.1 ns/px on every
//! scene, and it moved pixels).

use super::plan::ShadingPlan;
use super::{LightKind, Material, Scene};
use crate::backend::interp::ProgramInterp;
use crate::backend::native::{NativeError, ShadeCode};
use crate::backend::program::Program;
use crate::backend::Backend;
use crate::base::span::Span;
use crate::builtins::{Builtin, Mode};
use std::sync::Arc;
use crate::builtins::dd::Arith;
use crate::frame::{dot, inv_len, world_axes, world_light_inputs, world_view, Compare};
use crate::ir::{BinOp, Formula, Input, Ir, Node, NodeId, N_INPUTS};

/// The data columns a lighting program reads: position, normal, tangent (3 each; the tangent only for
/// formulas that read directions).
pub const COLUMNS: usize = 9;

/// The program's outputs per pixel, in order: r, g, b, then three counters — non-finite F values (counted per
/// channel and light; drawn as no light), F evaluations (lit pixel × light × channel), and lit pixel × light
/// pairs the cut-off skipped.
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
    fn call(&mut self, f: Builtin, args: &[NodeId]) -> NodeId {
        self.ir.call(f, args, self.s)
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

/// The frame's input formulas ([`crate::frame`]) written into the program, with the builder's folds.
impl Arith for Builder {
    type V = NodeId;
    fn konst(&mut self, c: f64) -> NodeId {
        self.k(c)
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
    fn div(&mut self, a: NodeId, b: NodeId) -> NodeId {
        self.bin(BinOp::Div, a, b)
    }
    fn neg(&mut self, a: NodeId) -> NodeId {
        self.ir.neg(a, self.s)
    }
    fn sqrt(&mut self, a: NodeId) -> NodeId {
        self.call(Builtin::Sqrt, &[a])
    }
    fn fma(&mut self, a: NodeId, b: NodeId, c: NodeId) -> NodeId {
        self.call(Builtin::Fma, &[a, b, c])
    }
    fn positive_select(&mut self, c: NodeId, a: NodeId, b: NodeId) -> NodeId {
        let zero = self.k(0.0);
        self.less_select(zero, c, a, b)
    }
}

impl Compare for Builder {
    fn less_select(&mut self, a: NodeId, b: NodeId, x: NodeId, y: NodeId) -> NodeId {
        let m = self.lt(a, b);
        self.select(m, x, y)
    }
}

/// The program shading with `spec` and the formula's channels (one, or red, green, blue): outputs in the order of the
/// module docs, one guarded region per light where F is evaluated.
pub fn build(spec: &Spec, channels: &[&Formula]) -> Result<Program, String> {
    if !(channels.len() == 1 || channels.len() == 3) {
        return Err(format!("a shading program takes 1 or 3 channels, not {}", channels.len()));
    }
    let mut b = Builder { ir: Ir::new(), s: Span::default() };
    let cols: Vec<NodeId> = (0..COLUMNS as u16).map(|k| b.ir.column(k, Span::default())).collect();
    let (p, n) = ([cols[0], cols[1], cols[2]], [cols[3], cols[4], cols[5]]);
    let zero = b.k(0.0);
    let one = b.k(1.0);
    let eye = b.splat(spec.eye);
    // The view step (v = eye − p, 1/|n|, 1/|v|, NV) and, for formulas that read directions, the tangent frame:
    // the shading frame's definitions ([`crate::frame`]) written as nodes.
    let v = b.sub3(eye, p);
    let view = world_view(&mut b, n, v);
    let reads = channels.iter().map(|f| f.used_inputs()).collect::<crate::ir::InputSet>();
    let needs = |i: Input| reads.contains(i);
    let axes = spec.tangent_rotation.map(|rotation| world_axes(&mut b, &view, [cols[6], cols[7], cols[8]], rotation));
    let mut acc = b.splat(spec.ambient);
    let mut counters: [Option<NodeId>; 3] = [None; 3];
    let count = |b: &mut Builder, c: &mut Option<NodeId>, x: NodeId| *c = Some(c.map_or(x, |c| b.add(c, x)));
    let mut regions: Vec<(NodeId, Vec<NodeId>)> = vec![];
    for light in &spec.lights {
        let (l, il) = if light.point {
            let lp = b.splat(light.at);
            let l = b.sub3(lp, p);
            let ll = dot(&mut b, l, l);
            (l, inv_len(&mut b, ll))
        } else {
            (b.splat(light.at), one)
        };
        let x = world_light_inputs(&mut b, &view, axes.as_ref(), l, il, &needs);
        let nl = x[Input::NL.index()].ok_or("the frame did not compute NL")?;
        let lit_nl = b.lt(zero, nl);
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
                // Times NL inside the lit region: an unlit pixel adds 0, even where NL is NaN (a zero normal).
                let fz = if spec.times_nl { b.mul(fz, nl) } else { fz };
                let bad = b.sub(one, fin);
                outs.push(b.select(lit, fz, zero));
                flags.push(b.select(lit, bad, zero));
            }
            for (c, g) in outs.iter().enumerate() {
                f[c] = *g;
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
    let n_params = channels.iter().map(|c| c.params.len()).max().unwrap_or(0);
    // The compacted program reads the tangent only when the formula reads directions.
    Program::new(&b.ir, &outs, &regions, n_params)
}

/// A program ready to run: interpreted, or compiled by the JIT.
#[derive(Clone)]
pub enum ProgramCode {
    Interp(Arc<ProgramInterp>),
    Jit(Arc<ShadeCode>),
    /// A material of evaluators without formulas (a measured table), shaded in Rust.
    Evaluated(Arc<EvalShader>),
}

impl ProgramCode {
    /// Compiles `p` for `backend` in math mode `mode` (the JIT through its code cache).
    pub fn new(p: &Program, backend: Backend, mode: Mode) -> Result<ProgramCode, NativeError> {
        Ok(match backend {
            Backend::Interp => ProgramCode::Interp(Arc::new(ProgramInterp::new(p, mode))),
            Backend::Jit => ProgramCode::Jit(crate::backend::jit::shade_code(p, mode)?),
            #[cfg(feature = "llvm")]
            Backend::Llvm => ProgramCode::Jit(crate::backend::llvm::program_code(p, mode)?),
            #[cfg(not(feature = "llvm"))]
            Backend::Llvm => return Err(NativeError::Host("this build has no LLVM tier (cargo feature `llvm`)".into())),
            // Automatic tiering decides per render ([`program_backend`]); a program compiled outside a render
            // starts where kernels do, on Cranelift.
            Backend::Auto => ProgramCode::Jit(crate::backend::jit::shade_code(p, mode)?),
        })
    }

    /// The parameter-only work for `params`, computed once per render (the JIT's prepared block; empty for
    /// the interpreter, which does it per call).
    pub fn prepare(&self, params: &[f64]) -> Vec<f64> {
        match self {
            ProgramCode::Interp(_) | ProgramCode::Evaluated(_) => vec![],
            ProgramCode::Jit(c) => c.prepare(params),
        }
    }

    /// Runs the program on `len` pixels (every column and output at least `len` long; otherwise nothing
    /// runs and the outputs are NaN). `block` is [`ProgramCode::prepare`]'s result for `params`.
    pub fn run(&self, cols: &[&[f64]], params: &[f64], block: &[f64], outs: &mut [&mut [f64]], len: usize) {
        match self {
            ProgramCode::Interp(i) => i.run(cols, params, outs, len),
            ProgramCode::Evaluated(e) => e.run(cols, params, outs, len),
            ProgramCode::Jit(c) => {
                if c.run(cols, params, block, outs, len).is_err() {
                    outs.iter_mut().for_each(|o| o.iter_mut().for_each(|x| *x = f64::NAN));
                }
            }
        }
    }
}

/// A material's compiled shading program for one render, with its prepared parameter block.
pub(crate) struct ProgramRun {
    pub(super) code: ProgramCode,
    pub(super) block: Vec<f64>,
    pub(super) params: Vec<f64>,
    /// The program reads the tangent (columns 6..9).
    pub(super) tangent: bool,
}

impl ProgramRun {
    /// The program `plan` describes for `m` under `scene`'s eye and lights, compiled with the material's
    /// backend (for automatic tiering, by the render's `samples`: [`program_backend`]) and math mode; a material
    /// without formulas, or whose program would pass `budget` nodes
    /// ([`program_nodes`]), is shaded by [`EvalShader`] with its kernels instead.
    pub(crate) fn new(scene: &Scene, m: &Material, plan: &ShadingPlan, budget: usize, samples: usize) -> Result<ProgramRun, String> {
        let src = &m.program;
        let spec = spec(scene, plan);
        let channels: Vec<&Formula> = src.channels.iter().map(|f| f.as_ref()).collect();
        let kernels = match &src.evaluated {
            Some(evs) => Some(evs.to_vec()),
            None if program_nodes(&spec, &channels) > budget => {
                Some(std::iter::once(&m.evaluator).chain(m.green_blue.iter().flatten()).cloned().collect())
            }
            None => None,
        };
        if let Some(kernels) = kernels {
            let shader = EvalShader::new(spec, kernels)?;
            return Ok(ProgramRun { code: ProgramCode::Evaluated(Arc::new(shader)), block: vec![], params: m.params.clone(), tangent: true });
        }
        let program = build(&spec, &channels).map_err(|e| format!("material `{}`: {e}", m.name))?;
        let backend = program_backend(src.backend, samples);
        let code = ProgramCode::new(&program, backend, src.math).map_err(|e| format!("material `{}`: {e}", m.name))?;
        let block = code.prepare(&m.params);
        Ok(ProgramRun { code, block, params: m.params.clone(), tangent: program.columns > 6 })
    }
}

/// Shaded samples (pixels × supersamples) from which automatic tiering compiles a render's shading programs with
/// LLVM. Measured on the papers' sphere (LLVM build, 2 threads, a shared 2-core host): LLVM compiles the program
/// in 35–120 ms where Cranelift takes ~1 ms, and shades ~4.6 ns per pixel faster on one thread (BENCHMARKS.md,
/// the LLVM tier against Cranelift), so a 4096² render (16.8 million samples) took 289 ms on LLVM against 198 ms
/// on Cranelift. The compile is repaid from ~30 million samples (a 5500² image, or 2048² at 3×3 supersampling);
/// below that the render stays on Cranelift.
pub const AUTO_LLVM_SAMPLES: usize = 32 << 20;

/// The tier a render of `samples` shaded samples compiles its programs with: `backend`, except that automatic
/// tiering ([`Backend::Auto`]) is LLVM from [`AUTO_LLVM_SAMPLES`] and Cranelift below.
pub fn program_backend(backend: Backend, samples: usize) -> Backend {
    match backend {
        Backend::Auto if samples >= AUTO_LLVM_SAMPLES => Backend::Llvm,
        Backend::Auto => Backend::Jit,
        b => b,
    }
}

/// The largest shading program [`ProgramRun::new`] compiles as one function, in [`program_nodes`]. The code
/// generators' register allocation grows faster than linearly in a function's size: on this project's test
/// machine the papers' sphere with 100 point lights of modified Schlick (~5 000 nodes) compiled in 3 s, 250 lights
/// in 40 s, and 4 000 lights did not finish in 8.7 GB. Past the budget the per-light loop runs in Rust around
/// the compiled kernels ([`EvalShader`]): the same colours and counters, compile time independent of the
/// light count, ~5 ns of kernel per lit pixel and light.
pub const MAX_PROGRAM_NODES: usize = 4_000;

/// The size of the program [`build`] would write for `spec` and `channels`, estimated before it is built: per
/// light, the frame's and the lighting model's ~40 nodes and one inlined copy of every channel.
pub fn program_nodes(spec: &Spec, channels: &[&Formula]) -> usize {
    let per_light = 40 + if spec.specular { channels.iter().map(|f| f.ir.len() + 8).sum::<usize>() } else { 0 };
    spec.lights.len().saturating_mul(per_light)
}

/// The lighting model of [`build`] on f64, for materials whose channels are evaluators without formulas (a
/// measured table) and for programs past [`MAX_PROGRAM_NODES`]: per pixel the same frame definitions the
/// program is built from ([`world_view`], [`world_axes`], [`world_light_inputs`], evaluated on f64 instead of
/// written as nodes), each channel's value, the cut-off, and the same colour sum and counters, so its colours
/// have the program's bits where the channels do.
pub struct EvalShader {
    spec: Spec,
    /// One channel (a scalar formula: F is the same for red, green and blue) or three.
    channels: Vec<Arc<dyn crate::backend::Evaluator>>,
}

impl EvalShader {
    /// The shader of `spec` calling `channels` (one, or red, green, blue) for F.
    pub fn new(spec: Spec, channels: Vec<Arc<dyn crate::backend::Evaluator>>) -> Result<EvalShader, String> {
        if !(channels.len() == 1 || channels.len() == 3) {
            return Err(format!("a shader takes 1 or 3 channels, not {}", channels.len()));
        }
        Ok(EvalShader { spec, channels })
    }

    /// Shades `len` pixels: columns as [`build`]'s program reads them, outputs in order (r, g, b and the [`N_OUTPUTS`] − 3 counters).
    pub fn run(&self, cols: &[&[f64]], params: &[f64], outs: &mut [&mut [f64]], len: usize) {
        if cols.len() < COLUMNS || outs.len() < N_OUTPUTS || cols.iter().any(|c| c.len() < len) || outs.iter().any(|o| o.len() < len) {
            outs.iter_mut().for_each(|o| o.iter_mut().for_each(|x| *x = f64::NAN));
            return;
        }
        let s = &self.spec;
        let e = &mut crate::builtins::math::Direct;
        let sub3 = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let prepared: Vec<_> = self.channels.iter().map(|ev| ev.prepare(params)).collect();
        for i in 0..len {
            let col = |k: usize| [cols[k][i], cols[k + 1][i], cols[k + 2][i]];
            let (p, n, t) = (col(0), col(3), col(6));
            let view = world_view(e, n, sub3(s.eye, p));
            // A table is looked up by its directions: the tangent frame always (unturned without a rotation).
            let axes = world_axes(e, &view, t, s.tangent_rotation.unwrap_or([1.0, 0.0]));
            let mut acc = s.ambient;
            let mut counts = [0.0; 3];
            for light in &s.lights {
                let (l, il) = if light.point {
                    let l = sub3(light.at, p);
                    let ll = dot(e, l, l);
                    (l, inv_len(e, ll))
                } else {
                    (light.at, 1.0)
                };
                let x = world_light_inputs(e, &view, Some(&axes), l, il, &|_| true).map(|v| v.unwrap_or(0.0));
                let nl = x[Input::NL.index()];
                let lit_nl = 0.0 < nl;
                let lit = lit_nl && s.cutoff.is_none_or(|(input, cos)| cos <= x[input.index()]);
                let mut f = [0.0; 3];
                if s.specular {
                    if lit {
                        for (fc, ev) in f.iter_mut().zip(&prepared) {
                            let y = ev.eval(&x);
                            if y.abs() < f64::INFINITY {
                                *fc = if s.times_nl { y * nl } else { y };
                            } else {
                                counts[0] += 1.0;
                            }
                        }
                        counts[1] += prepared.len() as f64;
                    } else if lit_nl {
                        counts[2] += 1.0;
                    }
                    if prepared.len() == 1 {
                        f = [f[0]; 3];
                    }
                }
                let nl_pos = if lit_nl { nl } else { 0.0 };
                for k in 0..3 {
                    let term = if s.specular { s.diffuse[k] * nl_pos + s.spec[k] * f[k] } else { s.diffuse[k] * nl_pos };
                    acc[k] += light.color[k] * term;
                }
            }
            for k in 0..3 {
                outs[k][i] = acc[k];
                outs[3 + k][i] = counts[k];
            }
        }
    }
}

/// The lighting program's description from the plan (see [`Spec`]).
pub fn spec(scene: &Scene, plan: &ShadingPlan) -> Spec {
    let lights = scene
        .lights
        .iter()
        .map(|l| match l.kind {
            LightKind::Point(p) => Light { point: true, at: p.to_array(), color: l.color.to_array() },
            LightKind::Directional(d) => Light { point: false, at: (-d).to_array(), color: l.color.to_array() },
        })
        .collect();
    Spec {
        eye: scene.camera.position.to_array(),
        lights,
        ambient: plan.ambient,
        diffuse: plan.diffuse,
        spec: plan.spec,
        specular: plan.specular,
        times_nl: plan.times_nl,
        tangent_rotation: plan.directions.then_some(plan.tangent_rotation),
        cutoff: plan.cutoff.map(|c| (c.input, c.cos)),
    }
}
