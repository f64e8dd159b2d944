//! Per-tile shading in structure-of-arrays columns: I = ka·Ia·C + Σ_lights Il·(kd·NL·C + ks·coef·F·Cs).
//!
//! Design: one scan of the tile's G-buffer cuts its pixels into runs covered by one triangle (empty pixels get
//! the background there), grouped by material; each material's runs fill spans of up to [`SPAN`] pixels. In a
//! span every quantity is a column of f64 with one entry per pixel. Position and normal (and the tangent, for
//! formulas that read directions) are interpolated run by run straight from the G-buffer's barycentrics (the
//! triangle's attributes are loop constants there); two-sided triangles turn the normal to the viewer. The
//! colours go back to the tile run by run (contiguous pixels), so no per-pixel index list is built.
//!
//! Then, for a material whose kernels are lobe formulas, one call of its shading program ([`ProgramRun`]:
//! [`crate::backend::shading`], compiled once per render) takes those columns to the colour and the counters
//! — the JIT's batched function or the interpreter running the same program. Otherwise (kernels that are Rust
//! closures, or `RenderOptions::program` off) every step of the material's [`ShadingPlan`] is one branch-free
//! loop over the columns, which LLVM vectorises (SSE2 f64x2; the inverse lengths take an f32 estimate and one
//! f64 Newton step); per light the lit pixels (NL > 0, lobe cosine above the cut-off) are compacted into the
//! kernel's columns and the kernel is called once for the span with [`Evaluator::eval_batch`], F scattered
//! back (a NaN or ±inf counted and 0: no light). Both end in the 8-bit conversion. Nothing here
//! allocates in the steady state ([`Scratch`] is per thread).
//!
//! Cost model: see [`super::plan`] and [`crate::backend::shading`]; measured numbers: BENCHMARKS.md.

use super::image::Transfer;
use super::plan::ShadingPlan;
use super::raster::{GBuffer, ScreenTri, Setup, EMPTY};
use super::{LightKind, Scene};
use super::Material;
use crate::backend::shading::{self, N_OUTPUTS};
use crate::backend::{Columns, Evaluator};
use crate::ir::Input;
use std::sync::Arc;
use std::time::Instant;

/// A shading program ready to run: interpreted, or compiled by the JIT.
#[derive(Clone)]
pub enum ProgramCode {
    Interp(Arc<shading::Interp>),
    Jit(Arc<crate::backend::jit::ShadeCode>),
}

impl ProgramCode {
    /// Compiles `p` for `backend` in math mode `mode` (the JIT through its code cache).
    pub fn new(p: &shading::Program, backend: crate::backend::Backend, mode: crate::Mode) -> Result<ProgramCode, crate::backend::jit::JitError> {
        Ok(match backend {
            crate::backend::Backend::Interp => ProgramCode::Interp(Arc::new(shading::Interp::new(p, mode))),
            crate::backend::Backend::Jit => ProgramCode::Jit(crate::backend::jit::shade_code(p, mode)?),
        })
    }

    /// The parameter-only work for `params`, computed once per render (the JIT's prepared block; empty for
    /// the interpreter, which does it per call).
    pub fn prepare(&self, params: &[f64]) -> Vec<f64> {
        match self {
            ProgramCode::Interp(_) => vec![],
            ProgramCode::Jit(c) => c.prepare(params),
        }
    }

    /// Runs the program on `len` pixels (every column and output at least `len` long; otherwise nothing
    /// runs and the outputs are NaN). `block` is [`ProgramCode::prepare`]'s result for `params`.
    pub fn run(&self, cols: &[&[f64]], params: &[f64], block: &[f64], outs: &mut [&mut [f64]; N_OUTPUTS], len: usize) {
        match self {
            ProgramCode::Interp(i) => i.run(cols, params, outs, len),
            ProgramCode::Jit(c) => {
                if c.run(cols, params, block, outs, len).is_err() {
                    outs.iter_mut().for_each(|o| o.iter_mut().for_each(|x| *x = f64::NAN));
                }
            }
        }
    }
}

/// A material's compiled shading program for one render, with its prepared parameter block.
pub struct ProgramRun {
    code: ProgramCode,
    block: Vec<f64>,
    params: Vec<f64>,
    /// The program reads the tangent (columns 6..9).
    tangent: bool,
}

impl ProgramRun {
    /// The program `plan` describes for `m` under `scene`'s eye and lights, compiled with the material's
    /// backend and math mode; `None` when the material's kernels are not lobe formulas or compilation failed
    /// (then the span loops shade it, with the same result within rounding).
    pub fn new(scene: &Scene, m: &Material, plan: &ShadingPlan) -> Option<ProgramRun> {
        let src = m.program.as_ref()?;
        let spec = spec(scene, plan);
        let channels: Vec<&crate::ir::Formula> = src.channels.iter().map(|f| f.as_ref()).collect();
        let program = shading::Program::new(&spec, &channels).ok()?;
        let code = ProgramCode::new(&program, src.backend, src.math).ok()?;
        let block = code.prepare(&m.params);
        Some(ProgramRun { code, block, params: m.params.clone(), tangent: program.columns > 6 })
    }
}

/// The shading program's description from the plan (see [`shading::Spec`]).
pub fn spec(scene: &Scene, plan: &ShadingPlan) -> shading::Spec {
    let lights = scene
        .lights
        .iter()
        .map(|l| match l.kind {
            LightKind::Point(p) => shading::Light { point: true, at: p.to_array(), color: l.color.to_array() },
            LightKind::Directional(d) => shading::Light { point: false, at: (-d).to_array(), color: l.color.to_array() },
        })
        .collect();
    shading::Spec {
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

/// Pixels shaded together: every column of a span (~25 of them, 2 KiB each) stays in the L1 cache between
/// the steps, and the kernel call per span and light (~50 ns of dispatch) is well amortised.
pub const SPAN: usize = 256;

/// Reusable per-thread buffers, so shading a tile allocates nothing in the steady state.
#[derive(Default)]
pub struct Scratch {
    pub gb: GBuffer,
    /// The tile's runs of pixels covered by one triangle, in pixel order (by material, then pixel, in a tile
    /// of several materials).
    runs: Vec<Run>,
    g: Group,
    /// The tile's 8-bit pixels (row-major, `tw × th × 3`).
    pub rgb: Vec<u8>,
}

/// Consecutive tile pixels (row-major, possibly across rows) covered by one triangle: its attributes are
/// loop constants for the whole run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Run {
    material: u32,
    start: u32,
    len: u32,
    tri: u32,
}

/// The columns of one span of one material's pixels. The surface columns (p, n, t) are [`SPAN`] long and
/// filled run by run; the others are resized to the span's size.
#[derive(Default)]
struct Group {
    /// Pixels in the span.
    len: usize,
    /// Where the span's pixels go: (span position, tile pixel, count) per piece of a run.
    segs: Vec<(u32, u32, u32)>,
    p: [Vec<f64>; 3],
    n: [Vec<f64>; 3],
    v: [Vec<f64>; 3],
    inv_n: Vec<f64>,
    inv_v: Vec<f64>,
    nv: Vec<f64>,
    /// The tangent frame (formulas that read directions only): the interpolated tangent, then the unit
    /// tangent and bitangent of the local frame; the view and light directions' components in it.
    t: [Vec<f64>; 3],
    bt: [Vec<f64>; 3],
    vx: Vec<f64>,
    vy: Vec<f64>,
    lx: Vec<f64>,
    ly: Vec<f64>,
    nl: Vec<f64>,
    vl: Vec<f64>,
    nh: Vec<f64>,
    vh: Vec<f64>,
    vr: Vec<f64>,
    /// F per pixel and channel for the current light (0 where not evaluated); a scalar formula fills only
    /// channel 0, which the colour step then reads for all three.
    f: [Vec<f64>; 3],
    acc: [Vec<f64>; 3],
    /// Each pixel's 8-bit colour, packed (r | g << 8 | b << 16).
    levels: Vec<u32>,
    /// The shading program's counters per pixel (non-finite F, evaluations, cut-off skips).
    cnt: [Vec<f64>; 3],
    /// The kernel batch: group positions of the evaluated pixels, their inputs, and F.
    idx: Vec<u32>,
    cols: [Vec<f64>; crate::N_INPUTS],
    out: Vec<f64>,
}

/// Counters for one tile, summed over tiles (integers, so the sum is independent of thread count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadeCounts {
    pub visible: u64,
    pub evals: u64,
    pub kernel_calls: u64,
    pub nan: u64,
    /// Lit pixel × light pairs whose kernel evaluation the cut-off skipped.
    pub cut: u64,
}

impl std::ops::AddAssign for ShadeCounts {
    fn add_assign(&mut self, o: ShadeCounts) {
        self.visible += o.visible;
        self.evals += o.evals;
        self.kernel_calls += o.kernel_calls;
        self.nan += o.nan;
        self.cut += o.cut;
    }
}

/// Shades the tile whose G-buffer is in `sc.gb` (`tw × th` pixels) with the per-material `plans`; the 8-bit
/// result (background where nothing is visible) is left in `sc.rgb`. Returns the counters and the time
/// spent inside the kernel, in nanoseconds.
pub fn shade_tile(scene: &Scene, plans: &[(ShadingPlan, Option<ProgramRun>)], s: &Setup, n: usize, sc: &mut Scratch, transfer: Transfer, bg: [u8; 3]) -> (ShadeCounts, u64) {
    let mut counts = ShadeCounts::default();
    let mut kernel_ns = 0;
    sc.rgb.resize(n * 3, 0);
    counts.visible = runs(&sc.gb.tri[..n], s, &mut sc.runs, &mut sc.rgb[..n * 3], bg);
    let eye = scene.camera.position.to_array();
    let g = &mut sc.g;
    for c in 0..3 {
        fit(&mut g.p[c], SPAN);
        fit(&mut g.n[c], SPAN);
        fit(&mut g.t[c], SPAN);
    }
    let mut start = 0;
    while start < sc.runs.len() {
        let m = sc.runs[start].material;
        let end = start + sc.runs[start..].iter().take_while(|r| r.material == m).count();
        let runs = &sc.runs[start..end];
        start = end;
        let (plan, program) = &plans[m as usize];
        if let Some(pr) = program {
            for_each_span(g, runs, s, &sc.gb, eye, pr.tangent, |g| {
                kernel_ns += run_program(g, pr, &mut counts);
                encode(g, &mut sc.rgb, transfer);
            });
            continue;
        }
        let mat = &scene.materials[m as usize];
        // The material's kernels (one, or red, green, blue), without allocating.
        let mut kernels: [&dyn Evaluator; 3] = [mat.evaluator.as_ref(); 3];
        let mut nk = 0;
        for k in mat.kernels() {
            kernels[nk] = k;
            nk += 1;
        }
        for_each_span(g, runs, s, &sc.gb, eye, plan.directions, |g| {
            view(g, eye);
            if plan.directions {
                frame(g, plan.tangent_rotation);
            }
            for (c, a) in g.acc.iter_mut().enumerate() {
                a.clear();
                a.resize(g.len, plan.ambient[c]);
            }
            for light in &scene.lights {
                light_step(g, light.kind, plan.view_light, plan.directions);
                if plan.half {
                    half(g);
                }
                if plan.reflect {
                    reflect(g);
                }
                if plan.specular {
                    kernel_ns += kernel(g, plan, &kernels[..nk], &mat.params, &mut counts);
                }
                colour(g, plan, light.color.to_array());
            }
            encode(g, &mut sc.rgb, transfer);
        });
    }
    (counts, kernel_ns)
}

/// Splits the tile's pixels (`tri`: each pixel's triangle or [`EMPTY`]) into runs of one triangle, in pixel
/// order, or sorted by material when the tile has several; empty pixels get the background in `rgb` (so every
/// pixel is written once, by this or by [`encode`]). Returns the number of visible pixels.
fn runs(tri: &[u32], s: &Setup, runs: &mut Vec<Run>, rgb: &mut [u8], bg: [u8; 3]) -> u64 {
    runs.clear();
    let mut visible = 0;
    let mut mixed = false;
    let mut o = 0;
    while o < tri.len() {
        let t = tri[o];
        // Eight pixels per test (one vector compare) while the run lasts, then one by one.
        let mut e = o + 1;
        while tri.get(e..e + 8).is_some_and(|c| c.iter().all(|&x| x == t)) {
            e += 8;
        }
        e += tri[e..].iter().take_while(|&&x| x == t).count();
        if t == EMPTY {
            for p in rgb[o * 3..e * 3].chunks_exact_mut(3) {
                p.copy_from_slice(&bg);
            }
        } else {
            let material = s.tris[t as usize].material;
            mixed |= runs.first().is_some_and(|f: &Run| f.material != material);
            runs.push(Run { material, start: o as u32, len: (e - o) as u32, tri: t });
            visible += (e - o) as u64;
        }
        o = e;
    }
    // Runs are found in pixel order, so one material needs no sort; the order within a material stays the
    // pixel order either way (starts are distinct).
    if mixed {
        runs.sort_unstable();
    }
    visible
}

/// Fills `g`'s surface columns from `runs` (one material's) span by span — each run's pixels interpolated
/// straight from the G-buffer's barycentrics, cut where a span is full — and calls `shade` on each span.
#[allow(clippy::too_many_arguments)]
fn for_each_span(g: &mut Group, runs: &[Run], s: &Setup, gb: &GBuffer, eye: [f64; 3], tangent: bool, mut shade: impl FnMut(&mut Group)) {
    g.segs.clear();
    let mut k = 0;
    for r in runs {
        let tri = &s.tris[r.tri as usize];
        let (mut o, mut left) = (r.start as usize, r.len as usize);
        while left > 0 {
            let take = left.min(SPAN - k);
            let bary = &gb.bary[o..o + take];
            if tangent {
                surface::<true>(g, k, tri, bary, eye);
            } else {
                surface::<false>(g, k, tri, bary, eye);
            }
            g.segs.push((k as u32, o as u32, take as u32));
            (k, o, left) = (k + take, o + take, left - take);
            if k == SPAN {
                g.len = k;
                shade(g);
                g.segs.clear();
                k = 0;
            }
        }
    }
    if k > 0 {
        g.len = k;
        shade(g);
    }
}

/// Runs the span's shading program: columns p, n (and t) in, colours into `acc`, counters summed. Returns
/// the nanoseconds spent in the program.
fn run_program(g: &mut Group, pr: &ProgramRun, counts: &mut ShadeCounts) -> u64 {
    let m = g.len;
    let ([px, py, pz], [nx, ny, nz], [tx, ty, tz]) = (&g.p, &g.n, &g.t);
    let tk = if pr.tangent { m } else { 0 };
    let cols: [&[f64]; shading::MAX_COLUMNS] = [&px[..m], &py[..m], &pz[..m], &nx[..m], &ny[..m], &nz[..m], &tx[..tk], &ty[..tk], &tz[..tk]];
    let [r, gg, b] = &mut g.acc;
    let [c0, c1, c2] = &mut g.cnt;
    let mut outs: [&mut [f64]; N_OUTPUTS] = [fit(r, m), fit(gg, m), fit(b, m), fit(c0, m), fit(c1, m), fit(c2, m)];
    let t = Instant::now();
    pr.code.run(&cols, &pr.params, &pr.block, &mut outs, m);
    let ns = t.elapsed().as_nanos() as u64;
    counts.kernel_calls += 1;
    // Small non-negative integers in f64, so the f64 sums are exact (two partial sums per counter, one pass:
    // LLVM vectorises it); a NaN, from a failed call, counts 0.
    let (c0, c1, c2) = (&g.cnt[0][..m], &g.cnt[1][..m], &g.cnt[2][..m]);
    let mut acc = [[0.0f64; 2]; 3];
    let pairs = m / 2;
    for i in 0..pairs {
        for (a, c) in acc.iter_mut().zip([c0, c1, c2]) {
            a[0] += c[2 * i];
            a[1] += c[2 * i + 1];
        }
    }
    let total = |a: [f64; 2], c: &[f64]| (a[0] + a[1] + c[2 * pairs..].iter().sum::<f64>()) as u64;
    counts.nan += total(acc[0], c0);
    counts.evals += total(acc[1], c1);
    counts.cut += total(acc[2], c2);
    ns
}

fn fit<T: Copy + Default>(v: &mut Vec<T>, m: usize) -> &mut [T] {
    v.resize(m, T::default());
    &mut v[..m]
}

/// 1/√x to ~1e-14 relative without an f64 square root or division, which the f64 loops would otherwise
/// queue three times per pixel on the divider: an f32 estimate (four lanes per instruction), then one
/// Newton step in f64. x = 0, or beyond the f32 range (lengths over ~1e19), gives NaN or 0: no light.
#[inline(always)]
fn rsqrt(x: f64) -> f64 {
    let y = f64::from(1.0 / (x as f32).sqrt());
    y * (1.5 - 0.5 * x * y * y)
}

/// The surface step for one piece of a run of triangle `tri`: p and n (and with `TAN` the tangent) at span
/// positions `k..`, interpolated from the pixels' barycentrics with the triangle's vertices as loop constants:
/// a = v2 + b0·(v0 − v2) + b1·(v1 − v2). Two-sided triangles turn n towards the viewer.
fn surface<const TAN: bool>(g: &mut Group, k: usize, tri: &ScreenTri, bary: &[[f64; 2]], eye: [f64; 3]) {
    let e = k + bary.len();
    let (a, d0, d1) = (tri.pos[2], tri.pos[0] - tri.pos[2], tri.pos[1] - tri.pos[2]);
    let (na, n0, n1) = (tri.normal[2], tri.normal[0] - tri.normal[2], tri.normal[1] - tri.normal[2]);
    let [px, py, pz] = &mut g.p;
    let [nx, ny, nz] = &mut g.n;
    let (px, py, pz, nx, ny, nz) = (&mut px[k..e], &mut py[k..e], &mut pz[k..e], &mut nx[k..e], &mut ny[k..e], &mut nz[k..e]);
    for (i, &[u, w]) in bary.iter().enumerate() {
        px[i] = a.x + u * d0.x + w * d1.x;
        py[i] = a.y + u * d0.y + w * d1.y;
        pz[i] = a.z + u * d0.z + w * d1.z;
        nx[i] = na.x + u * n0.x + w * n1.x;
        ny[i] = na.y + u * n0.y + w * n1.y;
        nz[i] = na.z + u * n0.z + w * n1.z;
    }
    if TAN {
        let (ta, t0, t1) = (tri.tangent[2], tri.tangent[0] - tri.tangent[2], tri.tangent[1] - tri.tangent[2]);
        let [tx, ty, tz] = &mut g.t;
        let (tx, ty, tz) = (&mut tx[k..e], &mut ty[k..e], &mut tz[k..e]);
        for (i, &[u, w]) in bary.iter().enumerate() {
            tx[i] = ta.x + u * t0.x + w * t1.x;
            ty[i] = ta.y + u * t0.y + w * t1.y;
            tz[i] = ta.z + u * t0.z + w * t1.z;
        }
    }
    if tri.two_sided {
        for i in 0..bary.len() {
            if nx[i] * (eye[0] - px[i]) + ny[i] * (eye[1] - py[i]) + nz[i] * (eye[2] - pz[i]) < 0.0 {
                nx[i] = -nx[i];
                ny[i] = -ny[i];
                nz[i] = -nz[i];
            }
        }
    }
}

/// The view step: v = eye − p, 1/|n|, 1/|v|, NV.
fn view(g: &mut Group, eye: [f64; 3]) {
    let m = g.len;
    let (inv_n, inv_v, nv) = (fit(&mut g.inv_n, m), fit(&mut g.inv_v, m), fit(&mut g.nv, m));
    let [vx, vy, vz] = &mut g.v;
    let (vx, vy, vz) = (fit(vx, m), fit(vy, m), fit(vz, m));
    let [px, py, pz] = &g.p;
    let [nx, ny, nz] = &g.n;
    let (px, py, pz, nx, ny, nz) = (&px[..m], &py[..m], &pz[..m], &nx[..m], &ny[..m], &nz[..m]);
    for i in 0..m {
        let (x, y, z) = (eye[0] - px[i], eye[1] - py[i], eye[2] - pz[i]);
        let inn = rsqrt(nx[i] * nx[i] + ny[i] * ny[i] + nz[i] * nz[i]);
        let ivv = rsqrt(x * x + y * y + z * z);
        vx[i] = x;
        vy[i] = y;
        vz[i] = z;
        inv_n[i] = inn;
        inv_v[i] = ivv;
        nv[i] = (nx[i] * x + ny[i] * y + nz[i] * z) * inn * ivv;
    }
}

/// The frame step (formulas that read directions): the interpolated tangent made orthogonal to the normal
/// and unit (Gram–Schmidt; where it is parallel to the normal, Duff et al.'s frame of the normal instead),
/// the bitangent N̂ × T̂, both turned about N̂ by the material's tangent angle (`rot` = (cos, sin)), and the
/// view direction's components Vx = V̂·T̂, Vy = V̂·B̂ (Vz is NV).
fn frame(g: &mut Group, rot: [f64; 2]) {
    let m = g.len;
    let (vxo, vyo) = (fit(&mut g.vx, m), fit(&mut g.vy, m));
    let [bx, by, bz] = &mut g.bt;
    let (bx, by, bz) = (fit(bx, m), fit(by, m), fit(bz, m));
    let [tx, ty, tz] = &mut g.t;
    let (tx, ty, tz) = (&mut tx[..m], &mut ty[..m], &mut tz[..m]);
    let [nx, ny, nz] = &g.n;
    let [vx, vy, vz] = &g.v;
    let (nx, ny, nz, vx, vy, vz) = (&nx[..m], &ny[..m], &nz[..m], &vx[..m], &vy[..m], &vz[..m]);
    let (inv_n, inv_v) = (&g.inv_n[..m], &g.inv_v[..m]);
    let [c, s] = rot;
    for i in 0..m {
        let (a, b, d) = (nx[i] * inv_n[i], ny[i] * inv_n[i], nz[i] * inv_n[i]);
        let k = a * tx[i] + b * ty[i] + d * tz[i];
        let (ux, uy, uz) = (tx[i] - a * k, ty[i] - b * k, tz[i] - d * k);
        let l2 = ux * ux + uy * uy + uz * uz;
        let ok = l2 > 1e-20;
        // Duff et al. 2017's tangent of (a, b, d) for the degenerate case (see mesh::onb_tangent).
        let sign = if d < 0.0 { -1.0 } else { 1.0 };
        let q = -1.0 / (sign + d);
        let (ox, oy, oz) = (1.0 + sign * a * a * q, sign * a * b * q, -sign * a);
        let il = if ok { rsqrt(l2) } else { 1.0 };
        let (ux, uy, uz) = if ok { (ux * il, uy * il, uz * il) } else { (ox, oy, oz) };
        // B̂ = N̂ × T̂, then the rotation by the tangent angle in the tangent plane.
        let (wx, wy, wz) = (b * uz - d * uy, d * ux - a * uz, a * uy - b * ux);
        let (t0, t1, t2) = (c * ux + s * wx, c * uy + s * wy, c * uz + s * wz);
        let (b0, b1, b2) = (c * wx - s * ux, c * wy - s * uy, c * wz - s * uz);
        tx[i] = t0;
        ty[i] = t1;
        tz[i] = t2;
        bx[i] = b0;
        by[i] = b1;
        bz[i] = b2;
        vxo[i] = (vx[i] * t0 + vy[i] * t1 + vz[i] * t2) * inv_v[i];
        vyo[i] = (vx[i] * b0 + vy[i] * b1 + vz[i] * b2) * inv_v[i];
    }
}

/// The light step (NL; VL if the plan needs it; Lx, Ly if the formula reads directions) for one light.
fn light_step(g: &mut Group, kind: LightKind, view_light: bool, dirs: bool) {
    let (p, d) = match kind {
        LightKind::Point(lp) => (true, lp.to_array()),
        LightKind::Directional(dir) => (false, (-dir).to_array()),
    };
    match (p, view_light, dirs) {
        (true, true, true) => light_loop::<true, true, true>(g, d),
        (true, true, false) => light_loop::<true, true, false>(g, d),
        (true, false, true) => light_loop::<true, false, true>(g, d),
        (true, false, false) => light_loop::<true, false, false>(g, d),
        (false, true, true) => light_loop::<false, true, true>(g, d),
        (false, true, false) => light_loop::<false, true, false>(g, d),
        (false, false, true) => light_loop::<false, false, true>(g, d),
        (false, false, false) => light_loop::<false, false, false>(g, d),
    }
}

/// `POINT`: `l` is the light's position (l = pos − p, normalised here); else `l` is the unit direction
/// towards the light. `VL`: also compute V̂·L̂. `DIR`: also L̂·T̂ and L̂·B̂ (the frame step ran).
fn light_loop<const POINT: bool, const VL: bool, const DIR: bool>(g: &mut Group, l: [f64; 3]) {
    let m = g.len;
    let (nl, vl) = (fit(&mut g.nl, m), fit(&mut g.vl, m));
    let (lx, ly) = if DIR { (fit(&mut g.lx, m), fit(&mut g.ly, m)) } else { (&mut g.lx[..0], &mut g.ly[..0]) };
    let ([tx, ty, tz], [bx, by, bz]) = (&g.t, &g.bt);
    let k = if DIR { m } else { 0 };
    let (tx, ty, tz, bx, by, bz) = (&tx[..k], &ty[..k], &tz[..k], &bx[..k], &by[..k], &bz[..k]);
    let [px, py, pz] = &g.p;
    let [nx, ny, nz] = &g.n;
    let [vx, vy, vz] = &g.v;
    let (px, py, pz, nx, ny, nz) = (&px[..m], &py[..m], &pz[..m], &nx[..m], &ny[..m], &nz[..m]);
    let (vx, vy, vz, inv_n, inv_v) = (&vx[..m], &vy[..m], &vz[..m], &g.inv_n[..m], &g.inv_v[..m]);
    for i in 0..m {
        let (x, y, z, il) = if POINT {
            let (x, y, z) = (l[0] - px[i], l[1] - py[i], l[2] - pz[i]);
            (x, y, z, rsqrt(x * x + y * y + z * z))
        } else {
            (l[0], l[1], l[2], 1.0)
        };
        nl[i] = (nx[i] * x + ny[i] * y + nz[i] * z) * inv_n[i] * il;
        if VL {
            vl[i] = (vx[i] * x + vy[i] * y + vz[i] * z) * inv_v[i] * il;
        }
        if DIR {
            lx[i] = (tx[i] * x + ty[i] * y + tz[i] * z) * il;
            ly[i] = (bx[i] * x + by[i] * y + bz[i] * z) * il;
        }
    }
}

/// The half step: |L̂ + V̂|² = 2 + 2VL, so NH = (NL + NV)/|L̂ + V̂| and VH = (1 + VL)/|L̂ + V̂| (both 0 where
/// L = −V and H is undefined, as a zero half vector gives).
fn half(g: &mut Group) {
    let m = g.len;
    let (nh, vh) = (fit(&mut g.nh, m), fit(&mut g.vh, m));
    let (nl, nv, vl) = (&g.nl[..m], &g.nv[..m], &g.vl[..m]);
    for i in 0..m {
        let h2 = 2.0 + 2.0 * vl[i];
        let ih = if h2 > 1e-300 { 1.0 / h2.sqrt() } else { 0.0 };
        nh[i] = (nl[i] + nv[i]) * ih;
        vh[i] = (1.0 + vl[i]) * ih;
    }
}

/// The reflect step: V̂·R̂ = 2·NL·NV − VL.
fn reflect(g: &mut Group) {
    let m = g.len;
    let vr = fit(&mut g.vr, m);
    let (nl, nv, vl) = (&g.nl[..m], &g.nv[..m], &g.vl[..m]);
    for i in 0..m {
        vr[i] = 2.0 * nl[i] * nv[i] - vl[i];
    }
}

/// The kernel step: compacts the pixels to evaluate, calls each channel's kernel once (one for a scalar
/// formula, three for a colour one, on the same columns), scatters F back into `g.f` (0 where not evaluated,
/// and where F is NaN or ±inf — counted per channel: an infinite lobe is a defect, not a highlight).
/// Returns the nanoseconds spent in the kernels.
fn kernel(g: &mut Group, plan: &ShadingPlan, kernels: &[&dyn Evaluator], params: &[f64], counts: &mut ShadeCounts) -> u64 {
    let m = g.len;
    let nl = &g.nl[..m];
    let idx = fit(&mut g.idx, m);
    let mut lit = 0;
    let mut count = 0;
    match plan.cutoff {
        None => {
            for (i, &c) in nl.iter().enumerate() {
                idx[count] = i as u32;
                count += usize::from(c > 0.0);
            }
            lit = count;
        }
        Some(cut) => {
            let lobe = if cut.input == Input::NH { &g.nh[..m] } else { &g.vr[..m] };
            for (i, (&c, &x)) in nl.iter().zip(lobe).enumerate() {
                idx[count] = i as u32;
                lit += usize::from(c > 0.0);
                count += usize::from(c > 0.0 && x >= cut.cos);
            }
        }
    }
    counts.cut += (lit - count) as u64;
    for f in &mut g.f[..kernels.len()] {
        fit(f, m).fill(0.0);
    }
    if count == 0 {
        return 0;
    }
    let idx = &g.idx[..count];
    // In Input::ALL order; Lz is NL and Vz is NV (both unclamped).
    let sources: [&[f64]; crate::N_INPUTS] = [&g.nl, &g.nv, &g.nh, &g.vr, &g.vh, &g.lx, &g.ly, &g.nl, &g.vx, &g.vy, &g.nv];
    for (k, (col, src)) in g.cols.iter_mut().zip(sources).enumerate() {
        col.clear();
        if k == Input::NL.index() || plan.reads.contains(Input::ALL[k]) {
            col.extend(idx.iter().map(|&i| src[i as usize]));
        }
    }
    let out = fit(&mut g.out, count);
    let cols = Columns::new(std::array::from_fn(|k| g.cols[k].as_slice()));
    let mut ns = 0;
    for (ev, f) in kernels.iter().zip(&mut g.f) {
        let t = Instant::now();
        ev.eval_batch(&cols, params, out);
        ns += t.elapsed().as_nanos() as u64;
        counts.kernel_calls += 1;
        counts.evals += count as u64;
        for (&i, &v) in idx.iter().zip(out.iter()) {
            if v.is_finite() {
                f[i as usize] = v;
            } else {
                counts.nan += 1;
            }
        }
        if plan.times_nl {
            for &i in idx {
                f[i as usize] *= g.nl[i as usize];
            }
        }
    }
    ns
}

/// The colour step for one light: acc += Il·(kd·C·max(NL, 0) + ks·coef·Cs·F). Unlit pixels add exactly +0
/// (F is 0 there and NL is clamped), so the sum equals skipping them.
fn colour(g: &mut Group, plan: &ShadingPlan, il: [f64; 3]) {
    let m = g.len;
    let nl = &g.nl[..m];
    let [r, gg, b] = &mut g.acc;
    let (r, gg, b) = (&mut r[..m], &mut gg[..m], &mut b[..m]);
    let (d, s) = (plan.diffuse, plan.spec);
    if plan.specular && plan.channels == 3 {
        // Filled by the kernel step for this light, one column per channel.
        let [f0, f1, f2] = &g.f;
        let (fr, fg, fb) = (&f0[..m], &f1[..m], &f2[..m]);
        for i in 0..m {
            let n = if nl[i] > 0.0 { nl[i] } else { 0.0 };
            r[i] += il[0] * (d[0] * n + s[0] * fr[i]);
            gg[i] += il[1] * (d[1] * n + s[1] * fg[i]);
            b[i] += il[2] * (d[2] * n + s[2] * fb[i]);
        }
    } else if plan.specular {
        // A scalar formula: one F for the three channels (one load per pixel).
        let f = &g.f[0][..m];
        for i in 0..m {
            let n = if nl[i] > 0.0 { nl[i] } else { 0.0 };
            r[i] += il[0] * (d[0] * n + s[0] * f[i]);
            gg[i] += il[1] * (d[1] * n + s[1] * f[i]);
            b[i] += il[2] * (d[2] * n + s[2] * f[i]);
        }
    } else {
        for i in 0..m {
            let n = if nl[i] > 0.0 { nl[i] } else { 0.0 };
            r[i] += il[0] * (d[0] * n);
            gg[i] += il[1] * (d[1] * n);
            b[i] += il[2] * (d[2] * n);
        }
    }
}

/// Converts the span's colours to 8 bits into the tile: first every pixel's three levels packed in a u32
/// (one branch-free pass over the columns, which LLVM vectorises for the linear transfer; sRGB through
/// [`Transfer::encode`]), then each piece of a run stored to its contiguous pixels.
fn encode(g: &mut Group, rgb: &mut [u8], transfer: Transfer) {
    let m = g.len;
    let [r, gg, b] = &g.acc;
    let (r, gg, b) = (&r[..m], &gg[..m], &b[..m]);
    let lv = fit(&mut g.levels, m);
    let pack = |r: u8, g: u8, b: u8| u32::from(r) | u32::from(g) << 8 | u32::from(b) << 16;
    match transfer {
        Transfer::Linear => {
            for i in 0..m {
                lv[i] = linear_pixel(r[i], gg[i], b[i]);
            }
        }
        Transfer::Srgb => {
            for i in 0..m {
                lv[i] = pack(transfer.encode(r[i]), transfer.encode(gg[i]), transfer.encode(b[i]));
            }
        }
    }
    for &(k, o, len) in &g.segs {
        let (k, o, len) = (k as usize, o as usize, len as usize);
        for (px, v) in rgb[o * 3..(o + len) * 3].chunks_exact_mut(3).zip(&lv[k..k + len]) {
            px.copy_from_slice(&v.to_le_bytes()[..3]);
        }
    }
}

/// A pixel's three linear levels packed: each level sits in the low byte of its [`linear_bits`], so shifted
/// and added in 64-bit lanes the low 32 bits are the packed pixel (no shuffle per channel).
#[inline(always)]
fn linear_pixel(r: f64, g: f64, b: f64) -> u32 {
    linear_bits(r).wrapping_add(linear_bits(g) << 8).wrapping_add(linear_bits(b) << 16) as u32
}

/// [`Transfer::encode`]'s linear branch, bit for bit, without branches or a float-to-int conversion, as the
/// low byte of the result (the bits above it are junk to discard): the comparisons turn NaN into 0, and
/// floor(y) comes from adding 1.5·2^52 (which rounds y to an integer in the low mantissa bits) and stepping
/// down where that rounded up.
#[inline(always)]
fn linear_bits(x: f64) -> u64 {
    const M: f64 = 6_755_399_441_055_744.0;
    let c = if x > 0.0 { x } else { 0.0 };
    let c = if c < 1.0 { c } else { 1.0 };
    let y = c * 255.0 + 0.5;
    let t = y + M;
    t.to_bits().wrapping_sub(u64::from(t - M > y))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectorised_linear_encoding_is_transfer_encode_bit_for_bit() {
        let mut vals: Vec<f64> = (0..=5100).map(|k| k as f64 / 5100.0).collect();
        // Exact half levels, values just around them, out of range, NaN, ±inf.
        for k in 0..=255 {
            let h = (k as f64 + 0.5) / 255.0;
            vals.extend([h, h.next_up(), h.next_down()]);
        }
        vals.extend([-1.0, -0.0, 1.0 + 1e-12, 7.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e-300]);
        // Each channel its own order of the values, so a level packed into the wrong byte shows.
        let n = vals.len();
        let chans: [Vec<f64>; 3] = [vals.clone(), vals.iter().rev().copied().collect(), (0..n).map(|i| vals[(i * 7 + 3) % n]).collect()];
        let mut g = Group { len: n, segs: vec![(0, 0, n as u32)], acc: chans.clone(), ..Group::default() };
        let mut rgb = vec![0u8; n * 3];
        encode(&mut g, &mut rgb, Transfer::Linear);
        for i in 0..n {
            for (c, ch) in chans.iter().enumerate() {
                assert_eq!(rgb[i * 3 + c], Transfer::Linear.encode(ch[i]), "channel {c}: {}", ch[i]);
            }
        }
    }
}
