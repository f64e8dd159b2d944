//! The tile-based software renderer: scene → triangles → screen tiles → shaded pixels → 8-bit image.
//!
//! Pipeline (one frame):
//! 1. setup (serial): project and clip every triangle, snap to 1/256 pixel, bin into 64×64 tiles
//!    ([`raster::setup`]);
//! 2. per band of tiles (bands in parallel with rayon, the band's tiles in order on one thread, each written
//!    straight from the thread's scratch into the frame): rasterise the tile's bin into a tile-sized G-buffer
//!    (integer edge functions, top-left rule, 1/w depth test), then shade the visible pixels in
//!    structure-of-arrays spans of up to [`shade::SPAN`] pixels, following each material's [`plan::ShadingPlan`] (computed once
//!    per frame: which cosines the formula reads, the uniforms, the cut-off) compiled into a shading program
//!    (one call per span: [`shade::shade_tile`], [`program`]), and convert to 8 bits into the
//!    frame; tiles no triangle touches are filled with the background and cost nothing else;
//! 3. PNG encoding and atomic output ([`image`]).
//!
//! A scene with an `[environment]` (or `shadows = true`) renders through the ray tracer instead ([`trace`]:
//! camera rays and occlusion through a BVH, [`envmap`]'s importance sampling combined with the formulas'
//! samplers by MIS), into linear float RGB; [`render`] converts it with the same transfer.
//!
//! A measured material (a MERL table, [`crate::measured`]) has no formula: its three channels are evaluators
//! that [`program::EvalShader`] calls per lit pixel and light, with the same lighting model in Rust.
//!
//! Materials are the simplified lobe formulas ([`ProgramSource`]: one, or three for a colour formula) with
//! their kernels (`Arc<dyn Evaluator>`, for the numerical checks: normalisation, cut-off) and the set of
//! inputs the formula reads (a tangent frame per pixel only if it reads direction components). Every
//! material shades through its program: each render builds it from the formulas ([`program::build`]) and
//! compiles it with the material's backend, so "JIT vs interpreter" compares the same program (geometry, F
//! and colour sum) compiled or interpreted.
//!
//! Determinism: every tile is computed from its own bin in scene order and written to its own pixels, and
//! all counters are integers, so 1 thread and N threads give byte-identical images and equal counts.
//!
//! Cost model: shading dominates — per visible pixel the tile scan into triangle runs, interpolation and 8-bit
//! conversion in Rust (~5 ns), then the shading program (the inverse lengths, the cosines the formula reads, F where lit, the
//! colour sum: JIT ~7 ns for one light and a cheap formula, plus F's own cost per lit pixel and light; the
//! interpreter 15–30× that) — then rasterisation (a few edge-function steps per
//! covered pixel, ~5 ns); setup and binning are per triangle and small; tiles the scene does not touch cost
//! only the background fill. PNG encoding is a separate, serial stage. Stage times are thread CPU time
//! (`cpu-time`), so a loaded machine does not inflate them; the programs' share (`kernel_cpu`: their calls,
//! F included) is its wall time scaled by the tile's
//! CPU/wall ratio — inside a fused program F's own time is not separable, so benches report the batched
//! kernel's ns/element measured beside it. Measured numbers: BENCHMARKS.md.

pub mod bvh;
pub(crate) mod camera;
pub mod compare;
pub mod envmap;
pub mod image;
pub mod mesh;
pub mod plan;
pub mod program;
pub mod raster;
pub mod scene;
pub mod shade;
pub mod trace;

use crate::ir::InputSet;
use crate::backend::Evaluator;
use camera::Camera;
use glam::DVec3;
use image::{Image, Transfer};
use mesh::Mesh;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Largest image side accepted.
pub(crate) const MAX_SIZE: usize = 4096;

/// Most supersamples per pixel side ([`RenderOptions::aa`], a scene's `aa`): 8×8 = 64 renders of the frame.
pub const MAX_AA: usize = 8;

/// An image size `N` (square) or `WxH`, each 1..=[`MAX_SIZE`] (the image size a front end asks for).
pub fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let one = |t: &str| -> Result<usize, String> {
        let v: usize = t.trim().parse().map_err(|_| format!("`{t}` is not a whole number"))?;
        if (1..=MAX_SIZE).contains(&v) {
            Ok(v)
        } else {
            Err(format!("{v} is outside 1..={}", MAX_SIZE))
        }
    };
    match s.split_once(['x', 'X']) {
        Some((w, h)) => Ok((one(w)?, one(h)?)),
        None => one(s).map(|v| (v, v)),
    }
}

/// A light source. Lights do not fall off with distance (the papers' program did not attenuate).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    Point(DVec3),
    /// Direction the light travels (towards the scene), unit length.
    Directional(DVec3),
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub kind: LightKind,
    pub color: DVec3,
}

/// A surface's reflectance: the BRDF kernel(s) and the classic ka/kd/ks weights.
#[derive(Clone)]
pub struct Material {
    pub name: String,
    /// The scalar formula's kernel, or the red channel's of a colour formula.
    pub evaluator: Arc<dyn Evaluator>,
    /// A colour formula's green and blue kernels (`None`: scalar, F is the same for the three channels).
    pub green_blue: Option<[Arc<dyn Evaluator>; 2]>,
    /// Inputs the formula reads (all channels); the shader computes only these (NL is always computed: it
    /// decides "lit"), and the tangent frame only if a direction component is among them.
    pub used: InputSet,
    /// Parameter values in declaration order (`n` first).
    pub params: Vec<f64>,
    pub ka: f64,
    pub kd: f64,
    pub ks: f64,
    /// Multiplies the ambient and diffuse terms.
    pub color: DVec3,
    /// Multiplies the specular term.
    pub specular: DVec3,
    /// Energy normalisation factor applied to F, per channel (1 when `normalize` is off; the same three for
    /// a scalar formula).
    pub coef: DVec3,
    /// Turns the tangent (and bitangent) about the normal by this angle, degrees (scene key
    /// `tangent_angle_deg`): the direction an anisotropic highlight stretches along. 0 keeps the shape's frame.
    pub tangent_angle_deg: f64,
    /// Multiply F by NL (scene key `times_nl`): the rendering equation's cosine, for formulas that are a BRDF
    /// proper (BRDF Explorer's `BRDF(L, V, N, X, Y)` returns f without it); the papers' models include
    /// whatever cosine they want in F, so the default is off.
    pub times_nl: bool,
    /// The papers' cut-off (scene key `cutoff = q`): F is not evaluated where the lobe is below 2^−q.
    pub cutoff: Option<plan::Cutoff>,
    /// The math mode of the material's kernel (for reports).
    pub math: crate::Mode,
    /// What the shading program is built from (the kernels above are the same formulas, for the numerical
    /// checks: normalisation, cut-off).
    pub program: ProgramSource,
}

/// The compiled formula's channels and backend, from which each render builds the material's shading program.
#[derive(Clone)]
pub struct ProgramSource {
    /// The simplified formula of each channel (one, or red, green, blue), parameters baked as compiled.
    pub channels: Vec<Arc<crate::ir::Formula>>,
    /// A material without formulas (a measured table): its channels' evaluators (red, green, blue), shaded by
    /// [`program::EvalShader`]'s Rust-side calls instead of a compiled program; `channels` is then empty.
    pub evaluated: Option<[Arc<dyn Evaluator>; 3]>,
    pub backend: crate::backend::Backend,
    pub math: crate::Mode,
}

impl Material {
    /// The channels' kernels: one, or red, green, blue.
    pub fn kernels(&self) -> impl Iterator<Item = &dyn Evaluator> {
        std::iter::once(self.evaluator.as_ref()).chain(self.green_blue.iter().flat_map(|gb| gb.iter().map(|e| e.as_ref())))
    }
}

impl std::fmt::Debug for Material {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Material")
            .field("name", &self.name)
            .field("used", &self.used)
            .field("params", &self.params)
            .field("ka", &self.ka)
            .field("kd", &self.kd)
            .field("ks", &self.ks)
            .field("coef", &self.coef)
            .field("colour", &self.green_blue.is_some())
            .field("tangent_angle_deg", &self.tangent_angle_deg)
            .field("cutoff", &self.cutoff)
            .finish()
    }
}

/// A mesh in world space with its material.
#[derive(Clone, Debug)]
pub struct Object {
    /// Shared: scenes made from one [`scene::Geometry`] (e.g. each row of a comparison over several n) use the
    /// same mesh.
    pub mesh: Arc<Mesh>,
    pub material: usize,
    pub cull_backfaces: bool,
}

/// A resolved scene, ready to render.
#[derive(Clone, Debug)]
pub struct Scene {
    pub width: usize,
    pub height: usize,
    /// Supersampling from the scene file: `aa`×`aa` samples per pixel (1: none); [`RenderOptions::aa`] overrides it.
    pub aa: usize,
    pub camera: Camera,
    pub background: DVec3,
    pub ambient: DVec3,
    pub lights: Vec<Light>,
    pub materials: Vec<Material>,
    pub objects: Vec<Object>,
    /// The scene's `[environment]`: the scene then renders through the ray tracer ([`trace`]).
    pub environment: Option<Arc<envmap::EnvMap>>,
    /// Samples per pixel of the ray tracer (scene key `spp`; [`RenderOptions::spp`] overrides it).
    pub spp: usize,
    /// Shadow rays for point and directional lights (scene key `shadows`; renders through [`trace`]).
    pub shadows: bool,
}

/// How to render.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Worker threads; 0 = rayon's default (one per core).
    pub threads: usize,
    /// Tile side in pixels (32 or 64 are sensible).
    pub tile: usize,
    pub transfer: Transfer,
    /// Apply the materials' cut-offs (off: evaluate F everywhere, to measure what the cut-off changes).
    pub cutoff: bool,
    /// Supersampling: `aa`×`aa` samples per pixel, 1..=[`MAX_AA`]; `None` takes the scene's [`Scene::aa`].
    /// The frame is rendered once per sample, each time sampled at the centre of one cell of an `aa`×`aa`
    /// grid over the pixel, and the 8-bit samples are averaged (in linear light for [`Transfer::Srgb`]);
    /// 1 is the plain render, byte for byte. The counters of [`RenderStats`] then count samples.
    pub aa: Option<usize>,
    /// Stops the render between tiles once it trips ([`render`] then fails); the default never does.
    pub cancel: crate::base::cancel::Cancel,
    /// The largest shading program compiled as one function, in estimated IR nodes
    /// ([`program::MAX_PROGRAM_NODES`] by default); a material past it is shaded per light by
    /// [`program::EvalShader`] with its compiled kernels (the same colours).
    pub program_budget: usize,
    /// Samples per pixel for the ray tracer, 1..=[`trace::MAX_SPP`]; `None` takes the scene's [`Scene::spp`].
    pub spp: Option<usize>,
    /// Which directions the ray tracer's environment estimator draws.
    pub strategy: trace::Strategy,
}

impl Default for RenderOptions {
    fn default() -> RenderOptions {
        RenderOptions {
            threads: 0,
            tile: 64,
            transfer: Transfer::Linear,
            cutoff: true,
            aa: None,
            cancel: Default::default(),
            program_budget: program::MAX_PROGRAM_NODES,
            spp: None,
            strategy: trace::Strategy::Mis,
        }
    }
}

/// What a render measured. Times named `*_cpu` are thread CPU time summed over threads; with supersampling
/// the counts (visible pixels, evaluations, NaN, cut-off skips) and stage times are summed over the samples.
#[derive(Clone, Debug, Default)]
pub struct RenderStats {
    pub width: usize,
    pub height: usize,
    pub threads: usize,
    pub triangles: usize,
    pub tiles: usize,
    pub tiles_touched: usize,
    pub visible_pixels: u64,
    /// Kernel evaluations (lit visible pixels × lights).
    pub evals: u64,
    pub kernel_calls: u64,
    /// Kernel results that were NaN or ±inf (shaded as no light).
    pub nan: u64,
    /// Lit pixel × light pairs whose kernel evaluation a material's cut-off skipped.
    pub cut: u64,
    pub setup: Duration,
    pub raster_cpu: Duration,
    /// Shading, including the kernel time and the conversion to 8 bits.
    pub shade_cpu: Duration,
    /// The part of `shade_cpu` spent inside the shading programs' calls (which include F and all the geometry
    /// after interpolation).
    pub kernel_cpu: Duration,
    /// Building and compiling the shading programs (wall, before the tiles; ~0 on a code-cache hit).
    pub program_compile: Duration,
    /// Wall time of setup + tiles (excludes encoding).
    pub render_wall: Duration,
    /// Under an environment with [`trace::Strategy::Mis`]: per material, the probability that a camera sample
    /// draws its direction from the environment, chosen by the tracer's pilot (empty otherwise).
    pub env_fractions: Vec<f64>,
}

impl RenderStats {
    pub(crate) fn mpixels_per_s(&self) -> f64 {
        (self.width * self.height) as f64 / self.render_wall.as_secs_f64().max(1e-12) / 1e6
    }
    /// Shading CPU time per visible pixel, ns.
    pub fn shade_ns_per_px(&self) -> f64 {
        self.shade_cpu.as_nanos() as f64 / self.visible_pixels.max(1) as f64
    }
    /// Shading CPU time outside the shading programs per visible pixel, ns: interpolation, grouping and the
    /// 8-bit conversion.
    pub fn geometry_ns_per_px(&self) -> f64 {
        (self.shade_cpu.saturating_sub(self.kernel_cpu)).as_nanos() as f64 / self.visible_pixels.max(1) as f64
    }
    /// Shading-program CPU time per evaluation of F, ns (0 when nothing was evaluated): this includes the
    /// geometry and colour sum around F.
    pub fn kernel_ns_per_eval(&self) -> f64 {
        if self.evals == 0 { 0.0 } else { self.kernel_cpu.as_nanos() as f64 / self.evals as f64 }
    }
}

/// A rendered frame: the 8-bit image and which pixels some triangle covers.
#[derive(Clone, Debug)]
pub struct Frame {
    pub image: Image,
    pub covered: Vec<bool>,
}

/// Most worker threads a render starts (more only adds scheduling cost on any machine lobe targets).
pub const MAX_THREADS: usize = 256;

/// Renders `scene`. Fails only if the thread count is over [`MAX_THREADS`], the supersampling is outside
/// 1..=[`MAX_AA`], the pool cannot be built, or a material's shading program cannot be built.
pub fn render(scene: &Scene, opts: &RenderOptions) -> Result<(Frame, RenderStats), String> {
    render_observed(scene, opts, &|_, _| {})
}

/// [`render`], calling `progress(done, total)` (tiles) from the worker threads after each tile, so a front end
/// can draw progress; the renderer draws nothing itself.
pub fn render_observed(scene: &Scene, opts: &RenderOptions, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<(Frame, RenderStats), String> {
    if opts.threads > MAX_THREADS {
        return Err(format!("{} worker threads is more than {MAX_THREADS}; 0 uses one per core", opts.threads));
    }
    let aa = opts.aa.unwrap_or(scene.aa);
    if !(1..=MAX_AA).contains(&aa) {
        return Err(format!("supersampling {aa}×{aa} is outside 1..={MAX_AA} samples per pixel side"));
    }
    if trace::traced(scene) {
        // The ray tracer: supersampling is its samples per pixel, so `aa` does not apply.
        let (hdr, stats) = trace::render_hdr_observed(scene, opts, progress)?;
        let image = trace::to_image(&hdr, opts.transfer);
        return Ok((Frame { image, covered: hdr.covered }, stats));
    }
    if opts.threads == 0 {
        render_in_pool(scene, opts, progress)
    } else {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(opts.threads)
            .build()
            .map_err(|e| format!("cannot start {} threads: {e}", opts.threads))?;
        pool.install(|| render_in_pool(scene, opts, progress))
    }
}

fn render_in_pool(scene: &Scene, opts: &RenderOptions, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<(Frame, RenderStats), String> {
    let t0 = Instant::now();
    let (w, h) = (scene.width, scene.height);
    let tile = opts.tile.clamp(8, 256);
    let aa = opts.aa.unwrap_or(scene.aa).clamp(1, MAX_AA);
    let items: Vec<raster::DrawItem> = scene
        .objects
        .iter()
        .map(|o| raster::DrawItem { mesh: &o.mesh, material: o.material as u32, cull_backfaces: o.cull_backfaces })
        .collect();
    let xf = scene.camera.clip_transform(w as f64 / h as f64);
    // Sample k of the aa×aa grid: the centre of its cell, in pixels from the pixel's centre (0, 0 for aa = 1).
    let offset = |k: usize| {
        let cell = |i: usize| if aa == 1 { 0.0 } else { (i as f64 + 0.5) / aa as f64 - 0.5 };
        [cell(k % aa), cell(k / aa)]
    };
    let first = raster::setup(&items, &xf, w, h, tile, offset(0));
    let mut setup_time = t0.elapsed();

    let bg = scene.background.to_array().map(|c| opts.transfer.encode(c));
    let tc = Instant::now();
    let programs: Vec<program::ProgramRun> = scene
        .materials
        .iter()
        .map(|m| program::ProgramRun::new(scene, m, &plan::ShadingPlan::new(m, scene.ambient, opts.cutoff), opts.program_budget, w * h * aa * aa))
        .collect::<Result<_, _>>()?;
    let program_compile = tc.elapsed();
    let timers = Timers::default();
    let samples = aa * aa;
    let (tiles_done, tiles) = (AtomicU64::new(0), first.bins.len() as u64);
    let pass = |setup: &raster::Setup| {
        let r = frame_pass(scene, &programs, setup, opts.transfer, bg, &timers, &opts.cancel, &|| {
            progress(tiles_done.fetch_add(1, Ordering::Relaxed) + 1, tiles * samples as u64)
        });
        opts.cancel.check().map(|_| r).map_err(|c| format!("the render stopped: {c}"))
    };
    let (mut rgb, mut covered, mut counts) = pass(&first)?;
    if samples > 1 {
        // Sum the samples' levels (sRGB ones decoded to linear light first), then the mean of each pixel.
        let linear = SampleSum::new(opts.transfer);
        let mut sum: Vec<u32> = rgb.iter().map(|&v| linear.add(v)).collect();
        for k in 1..samples {
            let ts = Instant::now();
            let setup = raster::setup(&items, &xf, w, h, tile, offset(k));
            setup_time += ts.elapsed();
            let (rgb_k, covered_k, counts_k) = pass(&setup)?;
            for (s, &v) in sum.iter_mut().zip(&rgb_k) {
                *s += linear.add(v);
            }
            for (c, &ck) in covered.iter_mut().zip(&covered_k) {
                *c |= ck;
            }
            counts += counts_k;
        }
        for (v, &s) in rgb.iter_mut().zip(&sum) {
            *v = linear.mean(s, samples as u32);
        }
    }
    let stats = RenderStats {
        width: w,
        height: h,
        threads: rayon::current_num_threads(),
        triangles: first.tris.len(),
        tiles: first.bins.len(),
        tiles_touched: first.bins.iter().filter(|b| !b.is_empty()).count(),
        visible_pixels: counts.visible,
        evals: counts.evals,
        kernel_calls: counts.kernel_calls,
        nan: counts.nan,
        cut: counts.cut,
        setup: setup_time,
        raster_cpu: Duration::from_nanos(timers.raster.load(Ordering::Relaxed)),
        shade_cpu: Duration::from_nanos(timers.shade.load(Ordering::Relaxed)),
        kernel_cpu: Duration::from_nanos(timers.kernel.load(Ordering::Relaxed)),
        program_compile,
        render_wall: t0.elapsed(),
        env_fractions: vec![],
    };
    Ok((Frame { image: Image { width: w, height: h, rgb }, covered }, stats))
}

/// One rendering of the whole frame from its binned triangles: the 8-bit pixels, the coverage and the
/// counters; `tile_done` is called after each tile. Once `cancel` trips the remaining tiles are skipped
/// (the caller discards the frame).
#[allow(clippy::too_many_arguments)]
fn frame_pass(
    scene: &Scene,
    programs: &[program::ProgramRun],
    setup: &raster::Setup,
    transfer: Transfer,
    bg: [u8; 3],
    timers: &Timers,
    cancel: &crate::base::cancel::Cancel,
    tile_done: &(dyn Fn() + Sync),
) -> (Vec<u8>, Vec<bool>, shade::ShadeCounts) {
    let (w, h, tile) = (setup.width, setup.height, setup.tile);
    let mut rgb = vec![0u8; w * h * 3];
    let mut covered = vec![false; w * h];
    // One task per band of tiles: its tiles are shaded in order into the thread's scratch and copied straight
    // into the frame (no per-tile buffers).
    let band_counts: Vec<shade::ShadeCounts> = rgb
        .par_chunks_mut(w * 3 * tile)
        .zip(covered.par_chunks_mut(w * tile))
        .enumerate()
        .map_init(shade::Scratch::default, |sc, (ty, (band, band_cov))| {
            // Background everywhere first (one row built, then copied); empty tiles need nothing more.
            let (first, rest) = band.split_at_mut((w * 3).min(band.len()));
            for p in first.chunks_exact_mut(3) {
                p.copy_from_slice(&bg);
            }
            for row in rest.chunks_exact_mut(w * 3) {
                row.copy_from_slice(first);
            }
            let mut counts = shade::ShadeCounts::default();
            for tx in 0..setup.tiles_x {
                if cancel.is_cancelled() {
                    break;
                }
                let t = ty * setup.tiles_x + tx;
                let shaded = tile_pixels(scene, programs, setup, t, sc, transfer, bg, timers);
                tile_done();
                let Some(c) = shaded else { continue };
                counts += c;
                let (x0, _, tw, th) = raster::tile_rect(setup, t);
                for y in 0..th {
                    band[(y * w + x0) * 3..(y * w + x0 + tw) * 3].copy_from_slice(&sc.rgb[y * tw * 3..(y + 1) * tw * 3]);
                    let cov = &mut band_cov[y * w + x0..y * w + x0 + tw];
                    for (c, &t) in cov.iter_mut().zip(&sc.gb.tri[y * tw..(y + 1) * tw]) {
                        *c = t != raster::EMPTY;
                    }
                }
            }
            counts
        })
        .collect();
    let mut counts = shade::ShadeCounts::default();
    for c in band_counts {
        counts += c;
    }
    (rgb, covered, counts)
}

/// How supersamples' 8-bit levels are summed and averaged: linear levels as they are; sRGB levels decoded to
/// linear light in units of 2^−24 (a sum of 64 fits a u32), averaged there and encoded again.
struct SampleSum {
    /// The decoded value of each sRGB level; `None` for the linear transfer.
    srgb: Option<Box<[u32; 256]>>,
}

impl SampleSum {
    const UNIT: f64 = (1u32 << 24) as f64;

    fn new(transfer: Transfer) -> SampleSum {
        let srgb = (transfer == Transfer::Srgb).then(|| {
            Box::new(std::array::from_fn(|v| {
                let c = v as f64 / 255.0;
                let lin = if c <= 0.040_45 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
                (lin * Self::UNIT).round() as u32
            }))
        });
        SampleSum { srgb }
    }
    fn add(&self, level: u8) -> u32 {
        match &self.srgb {
            None => u32::from(level),
            Some(t) => t[level as usize],
        }
    }
    /// The level of the mean of `n` samples summing to `sum`, rounded half up.
    fn mean(&self, sum: u32, n: u32) -> u8 {
        match &self.srgb {
            None => ((sum + n / 2) / n) as u8,
            Some(_) => Transfer::Srgb.encode(f64::from(sum) / f64::from(n) / Self::UNIT),
        }
    }
}

/// This thread's CPU time in ns (the wall clock where the platform has no thread clock): stage times are CPU
/// time, so a shared machine does not inflate them.
fn thread_cpu() -> u64 {
    static START: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    match cpu_time::ThreadTime::try_now() {
        Ok(t) => t.as_duration().as_nanos() as u64,
        Err(_) => START.get_or_init(Instant::now).elapsed().as_nanos() as u64,
    }
}

/// CPU time per stage, summed over threads (ns).
#[derive(Default)]
struct Timers {
    raster: AtomicU64,
    shade: AtomicU64,
    kernel: AtomicU64,
}

/// Rasterises and shades tile `t` into `sc` (its 8-bit pixels in `sc.rgb`, its coverage in `sc.gb.tri`, both
/// row-major and tile-sized); returns its counters, or `None` for a tile no triangle touches.
#[allow(clippy::too_many_arguments)]
fn tile_pixels(
    scene: &Scene,
    programs: &[program::ProgramRun],
    setup: &raster::Setup,
    t: usize,
    sc: &mut shade::Scratch,
    transfer: Transfer,
    bg: [u8; 3],
    timers: &Timers,
) -> Option<shade::ShadeCounts> {
    let (_, _, tw, th) = raster::tile_rect(setup, t);
    let n = tw * th;
    if setup.bins[t].is_empty() {
        return None;
    }
    let c0 = thread_cpu();
    raster::raster_tile(setup, t, &mut sc.gb);
    let c1 = thread_cpu();
    let t1 = Instant::now();
    let (counts, kernel_wall) = shade::shade_tile(scene, programs, setup, n, sc, transfer, bg);
    let (c2, wall) = (thread_cpu(), t1.elapsed().as_nanos().max(1) as u64);
    let shade_cpu = c2.saturating_sub(c1);
    // The kernel is timed by the wall clock (a thread-CPU clock read costs ~0.3 µs, too much per call);
    // scaled by this tile's CPU/wall ratio, it is the kernel's share of the CPU time.
    let kernel_cpu = (kernel_wall as u128 * shade_cpu as u128 / wall as u128) as u64;
    timers.raster.fetch_add(c1.saturating_sub(c0), Ordering::Relaxed);
    timers.shade.fetch_add(shade_cpu, Ordering::Relaxed);
    timers.kernel.fetch_add(kernel_cpu.min(shade_cpu), Ordering::Relaxed);
    Some(counts)
}

/// What the materials' cut-offs change in a frame: the frame rendered again without them, compared.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CutoffEffect {
    /// Kernel evaluations the cut-off skipped (lit pixel × light pairs).
    pub skipped: u64,
    /// Largest difference of one channel, in 8-bit levels.
    pub max_channel_diff: u8,
    /// Pixels with any channel different.
    pub pixels_differing: u64,
    /// The papers' grayscale metrics of the difference.
    pub metrics: compare::Metrics,
}

/// Renders `scene` again with every cut-off off and compares with `frame` (rendered with them); `None` if no
/// material has a cut-off. Costs one more render.
pub fn cutoff_effect(scene: &Scene, opts: &RenderOptions, frame: &Frame, stats: &RenderStats) -> Result<Option<CutoffEffect>, String> {
    // The ray tracer applies no cut-off.
    if !opts.cutoff || trace::traced(scene) || scene.materials.iter().all(|m| m.cutoff.is_none()) {
        return Ok(None);
    }
    let (full, _) = render(scene, &RenderOptions { cutoff: false, ..opts.clone() })?;
    let (a, b) = (&frame.image.rgb, &full.image.rgb);
    let mut max = 0u8;
    let mut differing = 0u64;
    for (p, q) in a.chunks_exact(3).zip(b.chunks_exact(3)) {
        let d = p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
        max = max.max(d);
        differing += u64::from(d > 0);
    }
    let metrics = compare::metrics(&frame.image, &full.image, &frame.covered)?;
    Ok(Some(CutoffEffect { skipped: stats.cut, max_channel_diff: max, pixels_differing: differing, metrics }))
}


#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averaging_equal_samples_keeps_the_level() {
        for transfer in [Transfer::Linear, Transfer::Srgb] {
            let s = SampleSum::new(transfer);
            for n in [4u32, 9, 64] {
                for v in 0..=255u8 {
                    assert_eq!(s.mean(s.add(v) * n, n), v, "{transfer:?}: {n} samples of {v}");
                }
            }
        }
        // Half black, half white: linear 127.5 rounds up; sRGB averages light, so it is brighter than 128.
        let lin = SampleSum::new(Transfer::Linear);
        assert_eq!(lin.mean(2 * lin.add(255), 4), 128);
        let srgb = SampleSum::new(Transfer::Srgb);
        assert_eq!(srgb.mean(2 * srgb.add(255), 4), Transfer::Srgb.encode(0.5));
    }
}
