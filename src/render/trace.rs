//! The ray-traced renderer: environment light with multiple importance sampling, and shadows.
//!
//! A scene with an `[environment]` (or `shadows = true`) renders here instead of through the rasteriser: per
//! pixel, `spp` camera rays jittered over the pixel (a box filter) find the nearest triangle through the
//! [`Bvh`]; at the hit the interpolated normal and tangent give the shading frame (two-sided: a back face turns
//! to the viewer), and the outgoing radiance is estimated by Monte Carlo.
//!
//! # Lighting model (docs/scenes.md states it for users)
//! Under an environment of radiance Le(ω), with V the direction to the camera and cos = N·ω:
//!
//! Lo = ∫ Le(ω) · [kd·C·cos⁺/π + ks·coef·Cs·F(ω, V)·(cos if `times_nl`)] dω  +  Σ_lights Il·(kd·NL·C + ks·coef·F·Cs)
//!
//! — the point-light model's two terms with the diffuse term a Lambertian BRDF of albedo kd·C (so a white
//! `kd = 1` surface under a white sky is 1), F as in the point-light model (the papers' formulas include their
//! cosine; a BRDF proper sets `times_nl`), the ambient term off, and the cut-off not applied (it is a shortcut
//! for point lights). A ray that misses everything sees the environment. Without an environment (a scene that
//! only asks for `shadows`) misses see `background` and the ambient term ka·Ia·C is added, as in the rasteriser.
//! Point and directional lights are evaluated at every camera sample, with a shadow ray when `shadows = true`.
//!
//! # Estimator
//! Multiple importance sampling with the power heuristic (Veach 1997, ch. 9): each camera sample draws one
//! direction, from the environment or from the material, so that a share c of a pixel's samples (⌊c·spp⌋ or
//! ⌈c·spp⌉, in a random phase per pixel: each sample's chance is c) come from the environment — Veach's
//! multi-sample model with those counts, at one direction per camera sample whatever c. A direction drawn by
//! strategy t has the factor wₜ/(cₜ·pₜ), wₜ = (cₜ·pₜ)²/Σₛ(cₛ·pₛ)² ([`power_weight`]). The material's density is a
//! mixture: cosine with probability α = kd·lum(C) / (kd·lum(C) + ks·lum(coef·Cs)), else the formula's
//! [`Sampler`] (which samples the incident direction given V as its `wi`: exact for reciprocal formulas, still
//! unbiased for the others since every weight uses that sampler's own `pdf`). c is chosen per material by a pilot
//! ([`env_fractions`]) that estimates, from a few samples drawn at c = ½, the estimator's second moment at every
//! candidate c; the cost per camera sample is the same for every c, so the least second moment is the least
//! noise at equal time. [`Strategy::Bsdf`] (c = 0) and [`Strategy::Env`] (c = 1) keep one of the two (for
//! measurements). Occlusion: a shadow ray per direction against the same BVH.
//!
//! Determinism: sample k of pixel p draws the uniforms `counter_unit(seed(p), 8k + j)`, whoever computes it,
//! and each pixel is summed in sample order by one thread, so 1 and N threads give the same bytes; the pilot
//! has seeds of its own and sums in pixel order.
//!
//! Cost: per camera sample one ray through the BVH, one shadow ray per direction and light, one evaluation of
//! F per direction and light, and both densities of the direction; the pilot adds about 1/32 of the samples.
//! Measured numbers in BENCHMARKS.md.

use super::bvh::Bvh;
use super::mesh::onb_tangent;
use super::{LightKind, Material, RenderOptions, RenderStats, Scene};
use crate::backend::Evaluator;
use std::sync::Arc;
use crate::base::rng::counter_unit;
use crate::bsdf::{Options as SamplerOptions, Sampler, LUMINANCE};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Most samples per pixel ([`Scene::spp`], or the command line's samples per pixel).
pub const MAX_SPP: usize = 1 << 16;

/// The spp of a progressive series ending at `spp` (`lobe watch` and the page refine through it): spp,
/// ⌊spp/4⌋, ⌊spp/16⌋, … while ≥ 1, smallest first — `levels(64)` is 1, 4, 16, 64. Each level is a whole render
/// at its spp, and a pixel's samples are the same whoever renders them, so the last level's image is the image of
/// one render at `spp`, byte for byte; the series' samples add up to at most 4/3 of that one render's
/// (1 + 1/4 + 1/16 + … < 4/3).
pub fn levels(spp: usize) -> Vec<usize> {
    let mut v: Vec<usize> = std::iter::successors(Some(spp.max(1)), |&s| Some(s / 4)).take_while(|&s| s >= 1).collect();
    v.reverse();
    v
}

/// Which directions the environment estimator draws.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Strategy {
    /// Both, one direction per camera sample from either, combined by the power heuristic, each material's
    /// share chosen by a pilot.
    #[default]
    Mis,
    /// The material's density only.
    Bsdf,
    /// The environment's density only.
    Env,
}

impl std::str::FromStr for Strategy {
    type Err = String;
    fn from_str(s: &str) -> Result<Strategy, String> {
        match s {
            "mis" => Ok(Strategy::Mis),
            "bsdf" => Ok(Strategy::Bsdf),
            "env" => Ok(Strategy::Env),
            _ => Err(format!("unknown strategy `{s}`; expected `mis`, `bsdf` or `env`")),
        }
    }
}

/// A linear-light frame: RGB per pixel (row-major, row 0 at the top) and which pixel centres see a surface.
#[derive(Clone, Debug)]
pub struct HdrFrame {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<[f32; 3]>,
    pub covered: Vec<bool>,
}

/// Whether `scene` renders through this module (an environment, or shadows).
pub fn traced(scene: &Scene) -> bool {
    scene.environment.is_some() || scene.shadows
}

/// A material prepared for tracing.
struct Shading {
    sampler: Option<Sampler>,
    diffuse: DVec3,
    spec: DVec3,
    times_nl: bool,
    /// cos and sin of the tangent angle.
    rot: (f64, f64),
    /// Probability of the cosine part of the material's density.
    alpha: f64,
    channels: usize,
}

fn lum(c: DVec3) -> f64 {
    c.x * LUMINANCE[0] + c.y * LUMINANCE[1] + c.z * LUMINANCE[2]
}

fn prepare(m: &Material) -> Result<Shading, String> {
    // The channels as the material evaluates them (a formula's compiled kernels, or a measured table's lookups),
    // sampled by their own tables.
    let evaluators: Vec<Arc<dyn Evaluator>> = std::iter::once(m.evaluator.clone()).chain(m.green_blue.iter().flat_map(|gb| gb.iter().cloned())).collect();
    let diffuse = m.kd * m.color;
    let spec = m.ks * m.coef * m.specular;
    let sampler = if lum(spec) > 0.0 {
        Some(Sampler::build_evaluators(&evaluators, m.used, &m.params, &SamplerOptions::default()).map_err(|d| format!("material `{}`: {d}", m.name))?)
    } else {
        None
    };
    let (wd, ws) = (lum(diffuse).max(0.0), if sampler.is_some() { lum(spec).max(0.0) } else { 0.0 });
    let alpha = if wd + ws > 0.0 { wd / (wd + ws) } else { 1.0 };
    let (s, c) = m.tangent_angle_deg.to_radians().sin_cos();
    Ok(Shading { sampler, diffuse, spec, times_nl: m.times_nl, rot: (c, s), alpha, channels: evaluators.len() })
}

/// A camera sample's surface point.
#[derive(Clone, Copy)]
struct Surface {
    material: usize,
    /// Offset origin for rays leaving the surface.
    origin: DVec3,
    ng: DVec3,
    /// The shading frame: X, Y, N.
    x: DVec3,
    y: DVec3,
    n: DVec3,
    /// V in the local frame.
    v: [f64; 3],
}

impl Surface {
    fn local(&self, w: DVec3) -> [f64; 3] {
        [w.dot(self.x), w.dot(self.y), w.dot(self.n)]
    }
    fn world(&self, l: [f64; 3]) -> DVec3 {
        self.x * l[0] + self.y * l[1] + self.n * l[2]
    }
}

/// One direction to evaluate at a surface: local L, its world direction, what to multiply f·Li by.
struct Job {
    sample: usize,
    l: [f64; 3],
    world: DVec3,
    /// Incident radiance times the estimator's weight (MIS weight / pdf, or 1 for a light).
    scale: DVec3,
    /// Needs a shadow ray, up to this distance (a point light's).
    shadow: bool,
    tmax: f64,
    /// A light's direct term: also kd·NL·C without the 1/π of the environment's Lambertian term.
    light: bool,
    /// The environment's and the material's densities of the direction (0 for a light).
    dens: (f64, f64),
    /// The estimator's factor in `scale` ([`power_weight`]; 1 for a light).
    weight: f64,
}

/// Renders `scene` with the ray tracer into linear RGB.
pub fn render_hdr(scene: &Scene, opts: &RenderOptions) -> Result<(HdrFrame, RenderStats), String> {
    render_hdr_observed(scene, opts, &|_, _| {})
}

/// [`render_hdr`], calling `progress(done, total)` (rows) from the worker threads after each row.
pub fn render_hdr_observed(scene: &Scene, opts: &RenderOptions, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<(HdrFrame, RenderStats), String> {
    if opts.threads > super::MAX_THREADS {
        return Err(format!("{} worker threads is more than {}; 0 uses one per core", opts.threads, super::MAX_THREADS));
    }
    let spp = opts.spp.unwrap_or(scene.spp);
    if !(1..=MAX_SPP).contains(&spp) {
        return Err(format!("{spp} samples per pixel is outside 1..={MAX_SPP}"));
    }
    let run = || render_in_pool(scene, opts, spp, progress);
    if opts.threads == 0 {
        run()
    } else {
        rayon::ThreadPoolBuilder::new()
            .num_threads(opts.threads)
            .build()
            .map_err(|e| format!("cannot start {} threads: {e}", opts.threads))?
            .install(run)
    }
}

fn render_in_pool(scene: &Scene, opts: &RenderOptions, spp: usize, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<(HdrFrame, RenderStats), String> {
    let t0 = Instant::now();
    let bvh = Bvh::build(&scene.objects);
    let setup = t0.elapsed();
    let tc = Instant::now();
    let shading: Vec<Shading> = scene.materials.iter().map(prepare).collect::<Result<_, _>>()?;
    let program_compile = tc.elapsed();
    let (w, h) = (scene.width, scene.height);
    let cam = CameraRays::new(scene);
    // The pilot's CPU time counts as shading: it is part of the estimator's cost.
    let shade_cpu = AtomicU64::new(0);
    let pilot = match (opts.strategy, scene.environment.as_deref().filter(|e| e.emits())) {
        (Strategy::Mis, Some(env)) => Some(env_fractions(scene, &bvh, &shading, &cam, env, spp, &shade_cpu)),
        _ => None,
    };
    let single = if opts.strategy == Strategy::Env { 1.0 } else { 0.0 };
    let fractions = pilot.clone().unwrap_or_else(|| vec![single; shading.len()]);
    let evals = AtomicU64::new(0);
    let nan = AtomicU64::new(0);
    let visible = AtomicU64::new(0);
    let rows_done = AtomicU64::new(0);
    let mut rgb = vec![[0f32; 3]; w * h];
    let mut covered = vec![false; w * h];
    rgb.par_chunks_mut(w).zip(covered.par_chunks_mut(w)).enumerate().try_for_each(|(y, (row, cov))| {
        if opts.cancel.is_cancelled() {
            return Err(());
        }
        let c0 = super::thread_cpu();
        let mut counts = Counts::default();
        for x in 0..w {
            let (c, hit) = pixel(scene, &bvh, &shading, &cam, &fractions, x, y, spp, &mut counts);
            row[x] = [c.x as f32, c.y as f32, c.z as f32];
            cov[x] = hit;
        }
        evals.fetch_add(counts.evals, Ordering::Relaxed);
        nan.fetch_add(counts.nan, Ordering::Relaxed);
        visible.fetch_add(counts.visible, Ordering::Relaxed);
        shade_cpu.fetch_add(super::thread_cpu().saturating_sub(c0), Ordering::Relaxed);
        progress(rows_done.fetch_add(1, Ordering::Relaxed) + 1, h as u64);
        Ok(())
    })
    .map_err(|_| format!("the render stopped: {}", opts.cancel.check().err().map(|c| c.to_string()).unwrap_or_default()))?;
    opts.cancel.check().map_err(|c| format!("the render stopped: {c}"))?;
    let stats = RenderStats {
        width: w,
        height: h,
        threads: rayon::current_num_threads(),
        triangles: bvh.len(),
        visible_pixels: visible.into_inner(),
        evals: evals.into_inner(),
        nan: nan.into_inner(),
        setup,
        shade_cpu: Duration::from_nanos(shade_cpu.into_inner()),
        program_compile,
        render_wall: t0.elapsed(),
        env_fractions: pilot.unwrap_or_default(),
        ..RenderStats::default()
    };
    Ok((HdrFrame { width: w, height: h, rgb, covered }, stats))
}

#[derive(Default)]
struct Counts {
    evals: u64,
    nan: u64,
    /// Camera samples that hit a surface.
    visible: u64,
}

/// Camera rays: the pinhole of [`super::camera::Camera`] (the rasteriser's projection).
struct CameraRays {
    eye: DVec3,
    f: DVec3,
    s: DVec3,
    u: DVec3,
    tan_y: f64,
    aspect: f64,
    w: f64,
    h: f64,
}

impl CameraRays {
    fn new(scene: &Scene) -> CameraRays {
        let c = &scene.camera;
        let f = (c.look_at - c.position).normalize();
        let s = f.cross(c.up).normalize();
        let u = s.cross(f);
        let (w, h) = (scene.width as f64, scene.height as f64);
        CameraRays { eye: c.position, f, s, u, tan_y: (c.fov_deg.to_radians() / 2.0).tan(), aspect: w / h, w, h }
    }
    /// The ray through image point (px, py) in pixels from the top-left corner.
    fn dir(&self, px: f64, py: f64) -> DVec3 {
        let sx = (2.0 * px / self.w - 1.0) * self.tan_y * self.aspect;
        let sy = (1.0 - 2.0 * py / self.h) * self.tan_y;
        (self.f + self.s * sx + self.u * sy).normalize()
    }
}

fn pixel_seed(x: usize, y: usize, w: usize) -> u64 {
    (y * w + x) as u64 ^ 0x6C6F_6265_656E_7600
}

/// The surface a camera ray hits, with its shading frame; `None` on a miss.
fn surface(scene: &Scene, bvh: &Bvh, shading: &[Shading], o: DVec3, d: DVec3) -> Option<Option<Surface>> {
    let hit = bvh.intersect(o, d, f64::INFINITY)?;
    let obj = &scene.objects[hit.tri.object as usize];
    let mesh = &obj.mesh;
    let t = mesh.triangles[hit.tri.tri as usize].map(|i| i as usize);
    let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
    let p = o + d * hit.t;
    let mut ng = (mesh.positions[t[1]] - mesh.positions[t[0]]).cross(mesh.positions[t[2]] - mesh.positions[t[0]]).normalize_or_zero();
    let mut n = (mesh.normals[t[0]] * b[0] + mesh.normals[t[1]] * b[1] + mesh.normals[t[2]] * b[2]).normalize_or_zero();
    if n == DVec3::ZERO {
        n = ng;
    }
    let v = -d;
    if ng.dot(v) < 0.0 {
        ng = -ng;
        n = -n;
    }
    // V below the interpolated normal's horizon (a silhouette of a tessellated surface): shade with the
    // geometric normal there, which faces the viewer.
    if n.dot(v) <= 1e-6 {
        n = ng;
    }
    if n.dot(v) <= 1e-9 {
        return Some(None);
    }
    let sh = &shading[obj.material];
    let tan = if mesh.tangents.len() == mesh.positions.len() {
        mesh.tangents[t[0]] * b[0] + mesh.tangents[t[1]] * b[1] + mesh.tangents[t[2]] * b[2]
    } else {
        onb_tangent(n)
    };
    let u = (tan - n * n.dot(tan)).try_normalize().unwrap_or_else(|| onb_tangent(n));
    let bt = n.cross(u);
    let (c, s) = sh.rot;
    let (x, y) = (u * c + bt * s, bt * c - u * s);
    let eps = 1e-9 * bvh.extent.max(1.0) + 1e-9 * p.abs().max_element();
    let mut surf = Surface { material: obj.material, origin: p + ng * eps, ng, x, y, n, v: [0.0; 3] };
    surf.v = surf.local(v);
    Some(Some(surf))
}

/// The uniforms of camera sample `k` of the pixel seeded `seed`: `j` = 0, 1 the position in the pixel, 2 the
/// material's cosine-or-sampler choice, 3–4 the material's direction, 5–6 the environment's; (0, 7) the phase of
/// the pixel's choice between the two.
fn uniforms(seed: u64) -> impl Fn(usize, usize) -> f64 {
    move |k, j| counter_unit(seed, (8 * k + j) as u64)
}

/// The camera samples of pixel (x, y): the radiance of those that miss (and the ambient term of those that hit
/// where there is no environment), the surfaces hit, and whether the pixel's centre sees a surface.
#[allow(clippy::too_many_arguments)]
fn camera_samples(
    scene: &Scene,
    bvh: &Bvh,
    shading: &[Shading],
    cam: &CameraRays,
    uni: &impl Fn(usize, usize) -> f64,
    x: usize,
    y: usize,
    spp: usize,
    counts: &mut Counts,
) -> (DVec3, Vec<(usize, Surface)>, bool) {
    let miss = |d: DVec3| match scene.environment.as_deref() {
        Some(e) => e.radiance(d),
        None => scene.background,
    };
    let covered = bvh.intersect(cam.eye, cam.dir(x as f64 + 0.5, y as f64 + 0.5), f64::INFINITY).is_some();
    let mut sum = DVec3::ZERO;
    let mut surfs: Vec<(usize, Surface)> = Vec::with_capacity(spp);
    for k in 0..spp {
        let d = cam.dir(x as f64 + uni(k, 0), y as f64 + uni(k, 1));
        match surface(scene, bvh, shading, cam.eye, d) {
            None => sum += miss(d),
            Some(None) => counts.visible += 1,
            Some(Some(s)) => {
                counts.visible += 1;
                if scene.environment.is_none() {
                    let m = &scene.materials[s.material];
                    sum += m.ka * scene.ambient * m.color;
                }
                surfs.push((k, s));
            }
        }
    }
    (sum, surfs, covered)
}

/// The camera samples of each material present (usually one), in material order.
fn by_material(surfs: &[(usize, Surface)]) -> Vec<(usize, Vec<&(usize, Surface)>)> {
    let mut mats: Vec<usize> = surfs.iter().map(|(_, s)| s.material).collect();
    mats.sort_unstable();
    mats.dedup();
    mats.into_iter().map(|mi| (mi, surfs.iter().filter(|(_, s)| s.material == mi).collect())).collect()
}

/// Estimates pixel (x, y): its colour and whether its centre sees a surface. `fractions[m]`: the probability that
/// a camera sample of material m draws its direction from the environment (MIS).
#[allow(clippy::too_many_arguments)]
fn pixel(scene: &Scene, bvh: &Bvh, shading: &[Shading], cam: &CameraRays, fractions: &[f64], x: usize, y: usize, spp: usize, counts: &mut Counts) -> (DVec3, bool) {
    let uni = uniforms(pixel_seed(x, y, scene.width));
    let env = scene.environment.as_deref().filter(|e| e.emits());
    let (mut sum, surfs, covered) = camera_samples(scene, bvh, shading, cam, &uni, x, y, spp, counts);
    for (mi, group) in by_material(&surfs) {
        let sh = &shading[mi];
        let mut jobs = env.map(|env| env_jobs(env, sh, &group, fractions[mi], &uni)).unwrap_or_default();
        light_jobs(scene, &group, &mut jobs);
        sum += shade_jobs(bvh, sh, &group, &jobs, counts).iter().sum::<DVec3>();
    }
    ((sum / spp as f64), covered)
}

/// One direction per camera sample of `group` for the environment term: from the environment's density for a
/// share `c` of the pixel's samples, else from the material's (the cosine part or the sampler), with the power
/// heuristic's factor ([`power_weight`]). c = 0 and c = 1 are the single strategies, weighted 1/p of their own.
fn env_jobs(env: &super::envmap::EnvMap, sh: &Shading, group: &[&(usize, Surface)], c: f64, uni: &impl Fn(usize, usize) -> f64) -> Vec<Job> {
    // Each sample's direction (local, world) and, when the environment drew it, its density there.
    type Drawn = ([f64; 3], DVec3, Option<f64>);
    let mut dirs: Vec<Option<Drawn>> = vec![None; group.len()];
    let mut from_sampler: Vec<usize> = vec![];
    // Which strategy: sample k draws from the environment when ⌊(k + 1)·c + φ⌋ > ⌊k·c + φ⌋ (φ uniform per pixel),
    // so each sample does with probability c and a pixel's spp samples hold ⌊c·spp⌋ or ⌈c·spp⌉ of them: the
    // multi-sample model's counts, without the noise of choosing at random per sample.
    let phase = uni(0, 7);
    let from_env = |k: usize| c >= 1.0 || ((k + 1) as f64 * c + phase).floor() > (k as f64 * c + phase).floor();
    for (gi, (k, s)) in group.iter().enumerate() {
        if from_env(*k) {
            dirs[gi] = env.sample([uni(*k, 5), uni(*k, 6)]).map(|(wd, pe)| (s.local(wd), wd, Some(pe)));
        } else if uni(*k, 2) < sh.alpha || sh.sampler.is_none() {
            let l = cosine(uni(*k, 3), uni(*k, 4));
            dirs[gi] = Some((l, s.world(l), None));
        } else {
            from_sampler.push(gi);
        }
    }
    if let (Some(smp), false) = (&sh.sampler, from_sampler.is_empty()) {
        let wi: Vec<[f64; 3]> = from_sampler.iter().map(|&gi| group[gi].1.v).collect();
        let u: Vec<[f64; 2]> = from_sampler.iter().map(|&gi| [uni(group[gi].0, 3), uni(group[gi].0, 4)]).collect();
        // Every V here is above the horizon (`surface`), so the sampler accepts it.
        if let Ok(smp) = smp.sample_many(&wi, &u) {
            for (j, &gi) in from_sampler.iter().enumerate() {
                let l = smp.wo[j];
                dirs[gi] = Some((l, group[gi].1.world(l), None));
            }
        }
    }
    let need: Vec<(usize, [f64; 3])> = dirs.iter().enumerate().filter_map(|(gi, d)| d.filter(|(l, _, _)| l[2] > 0.0).map(|(l, _, _)| (gi, l))).collect();
    let pb = if c < 1.0 { material_pdfs(sh, group, &need) } else { vec![0.0; need.len()] };
    let mut jobs = Vec::with_capacity(need.len());
    for ((gi, l), pb) in need.into_iter().zip(pb) {
        let Some((_, world, drawn)) = dirs[gi] else { continue };
        let pe = match drawn {
            Some(pe) => pe,
            None if c > 0.0 => env.pdf(world),
            None => 0.0,
        };
        let weight = power_weight(c, pe, pb, drawn.is_some());
        if weight > 0.0 {
            jobs.push(Job { sample: gi, l, world, scale: env.radiance(world) * weight, shadow: true, tmax: f64::INFINITY, light: false, dens: (pe, pb), weight });
        }
    }
    jobs
}

/// The power heuristic's factor for a direction the environment (`from_env`) or the material drew, at
/// environment share c: wₜ/(cₜ·pₜ) with wₜ = (cₜ·pₜ)² / Σₛ (cₛ·pₛ)², which is a/(a² + b²) or b/(a² + b²) with
/// a = c·p_env and b = (1 − c)·p_material (0 when both are 0). c = 1 gives 1/p_env, c = 0 gives 1/p_material.
fn power_weight(c: f64, pe: f64, pb: f64, from_env: bool) -> f64 {
    let (a, b) = (c * pe, (1.0 - c) * pb);
    let den = a * a + b * b;
    if den > 0.0 {
        (if from_env { a } else { b }) / den
    } else {
        0.0
    }
}

/// Σₜ wₜ²/(cₜ·pₜ) = (a³ + b³)/(a² + b²)² (a, b as in [`power_weight`]): a direction's share of the power-heuristic
/// estimator's second moment at share c, per g² of its integrand.
fn power_moment(c: f64, pe: f64, pb: f64) -> f64 {
    let (a, b) = (c * pe, (1.0 - c) * pb);
    let den = a * a + b * b;
    if den > 0.0 {
        (a * a * a + b * b * b) / (den * den)
    } else {
        0.0
    }
}

/// The point and directional lights' jobs for every camera sample of `group`.
fn light_jobs(scene: &Scene, group: &[&(usize, Surface)], jobs: &mut Vec<Job>) {
    for (gi, (_, s)) in group.iter().enumerate() {
        for light in &scene.lights {
            let (world, dist) = match light.kind {
                LightKind::Point(p) => {
                    let d = p - s.origin;
                    (d.normalize_or_zero(), d.length())
                }
                LightKind::Directional(d) => (-d, f64::INFINITY),
            };
            let l = s.local(world);
            if l[2] > 0.0 {
                jobs.push(Job { sample: gi, l, world, scale: light.color, shadow: scene.shadows, tmax: dist, light: true, dens: (0.0, 0.0), weight: 1.0 });
            }
        }
    }
}

/// Candidate environment fractions for [`Strategy::Mis`]: 0.02, 0.04, …, 0.98 (never a single strategy, so
/// every direction where the integrand is not 0 keeps a density).
const FRACTIONS: usize = 49;

fn fraction(i: usize) -> f64 {
    (i + 1) as f64 / (FRACTIONS + 1) as f64
}

/// Pixels and samples a pilot takes at most.
const PILOT_PIXELS: usize = 1024;
const PILOT_SPP: usize = 4;
/// Samples a pilot takes at least, where the render has four times as many: fewer decide little.
const PILOT_MIN: usize = 4096;

/// How many standard errors of the pilot's estimate a candidate's advantage over c = ½ must clear.
const PILOT_Z: f64 = 2.0;

/// Each material's environment fraction for [`Strategy::Mis`], chosen by a pilot. On a grid of at most
/// [`PILOT_PIXELS`] pixels, [`PILOT_SPP`] camera samples each at most (about a 32nd of the render's samples, but
/// up to [`PILOT_MIN`] in a small render, and at least one per pilot pixel), directions drawn at c = ½ give, for
/// every candidate c, an unbiased estimate of the second moment of a sample drawn at share c with the power
/// heuristic's factor, E_q[g²/q · [`power_moment`]] (g the integrand, q the pilot's density; choosing each sample's
/// strategy at random, an upper bound of the stratified choice the render makes). Every candidate costs the same
/// per sample, so the least second moment is the least noise at equal time. The choice is the candidate with the
/// least upper bound: the estimate plus [`PILOT_Z`] standard errors of its paired difference from c = ½ (whose
/// bound is its estimate). A pilot of few samples, or one whose advantage rests on a few large values — the heavy
/// tails of a narrow lobe under a small sun — keeps c near ½, drawing from both strategies alike. The pilot's
/// seeds differ from the render's (its choice does not bias the render), and its sums are taken in pixel order,
/// so the choice is the same on any number of threads.
#[allow(clippy::too_many_arguments)]
fn env_fractions(scene: &Scene, bvh: &Bvh, shading: &[Shading], cam: &CameraRays, env: &super::envmap::EnvMap, spp: usize, cpu: &AtomicU64) -> Vec<f64> {
    let (w, h) = (scene.width, scene.height);
    let stride = ((w * h) as f64 / PILOT_PIXELS as f64).sqrt().ceil().max(1.0) as usize;
    let pixels: Vec<(usize, usize)> = (stride / 2..h).step_by(stride).flat_map(|y| (stride / 2..w).step_by(stride).map(move |x| (x, y))).collect();
    let total = w * h * spp;
    let budget = (total / 32).max((total / 4).min(PILOT_MIN));
    let pilot_spp = (budget / pixels.len().max(1)).clamp(1, PILOT_SPP);
    let half = FRACTIONS / 2;
    debug_assert_eq!(fraction(half), 0.5);
    // Per material: the camera samples, and per candidate c the sums of x = g²/q · power_moment(c) and of
    // d² = (x − x at ½)².
    #[derive(Clone)]
    struct Sums {
        n: usize,
        x: [f64; FRACTIONS],
        d2: [f64; FRACTIONS],
    }
    let zero = Sums { n: 0, x: [0.0; FRACTIONS], d2: [0.0; FRACTIONS] };
    let per_pixel: Vec<Vec<(usize, Sums)>> = pixels
        .par_iter()
        .map(|&(x, y)| {
            let c0 = super::thread_cpu();
            let mut counts = Counts::default();
            let uni = uniforms(pixel_seed(x, y, w) ^ 0x7069_6C6F_7400_0000);
            let (_, surfs, _) = camera_samples(scene, bvh, shading, cam, &uni, x, y, pilot_spp, &mut counts);
            let r = by_material(&surfs)
                .into_iter()
                .map(|(mi, group)| {
                    let sh = &shading[mi];
                    let jobs = env_jobs(env, sh, &group, 0.5, &uni);
                    let contrib = shade_jobs(bvh, sh, &group, &jobs, &mut counts);
                    let mut s = Sums { n: group.len(), ..zero.clone() };
                    for (j, g) in jobs.iter().zip(&contrib) {
                        // g²/q with g the integrand (the contribution over its factor) and q the density the
                        // pilot drew from, ½·(p_env + p_material); times Σₜ wₜ²/(cₜ·pₜ) it is an unbiased
                        // estimate of the second moment at share c.
                        let (pe, pb) = j.dens;
                        let g2q = g.length_squared() / 3.0 / (j.weight * j.weight) / (0.5 * (pe + pb));
                        if g2q > 0.0 && g2q.is_finite() {
                            let at_half = g2q * power_moment(0.5, pe, pb);
                            for i in 0..FRACTIONS {
                                let x = g2q * power_moment(fraction(i), pe, pb);
                                s.x[i] += x;
                                s.d2[i] += (x - at_half) * (x - at_half);
                            }
                        }
                    }
                    (mi, s)
                })
                .collect::<Vec<_>>();
            cpu.fetch_add(super::thread_cpu().saturating_sub(c0), Ordering::Relaxed);
            r
        })
        .collect();
    let mut total = vec![zero; shading.len()];
    for (mi, s) in per_pixel.into_iter().flatten() {
        let t = &mut total[mi];
        t.n += s.n;
        for i in 0..FRACTIONS {
            t.x[i] += s.x[i];
            t.d2[i] += s.d2[i];
        }
    }
    total
        .iter()
        .map(|t| {
            if t.n < 2 {
                return 0.5;
            }
            let n = t.n as f64;
            let bound = |i: usize| {
                let mean_d = (t.x[i] - t.x[half]) / n;
                let var_d = ((t.d2[i] - n * mean_d * mean_d) / (n - 1.0)).max(0.0);
                t.x[i] / n + PILOT_Z * (var_d / n).sqrt()
            };
            fraction((0..FRACTIONS).min_by(|&a, &b| bound(a).total_cmp(&bound(b))).unwrap_or(half))
        })
        .collect()
}

/// Shades the jobs of one material: visibility, F, the lighting model; returns each job's contribution (zero
/// for a direction under the geometric surface or occluded).
fn shade_jobs(bvh: &Bvh, sh: &Shading, group: &[&(usize, Surface)], jobs: &[Job], counts: &mut Counts) -> Vec<DVec3> {
    // Drop directions under the geometric surface (the shading normal's hemisphere can reach below it) and
    // occluded ones; for a point light the shadow ray stops at the light.
    let mut live: Vec<usize> = vec![];
    for (i, j) in jobs.iter().enumerate() {
        let s = &group[j.sample].1;
        if j.world.dot(s.ng) <= 0.0 {
            continue;
        }
        if j.shadow && bvh.occluded(s.origin, j.world, j.tmax) {
            continue;
        }
        live.push(i);
    }
    let mut f = vec![];
    if let Some(smp) = &sh.sampler {
        if !live.is_empty() {
            let wi: Vec<[f64; 3]> = live.iter().map(|&i| jobs[i].l).collect();
            let wo: Vec<[f64; 3]> = live.iter().map(|&i| group[jobs[i].sample].1.v).collect();
            f = smp.eval_many(&wi, &wo).unwrap_or_default();
            counts.evals += live.len() as u64;
        }
    }
    let mut out = vec![DVec3::ZERO; jobs.len()];
    for (k, &i) in live.iter().enumerate() {
        let j = &jobs[i];
        let cos = j.l[2];
        let mut fv = DVec3::ZERO;
        if !f.is_empty() {
            let c = sh.channels;
            let ch = |q: usize| f[k * c + if c == 1 { 0 } else { q }];
            fv = DVec3::new(ch(0), ch(1), ch(2));
            if !fv.is_finite() {
                counts.nan += 1;
                fv = DVec3::ZERO;
            }
            if sh.times_nl {
                fv *= cos;
            }
        }
        let diffuse = if j.light { sh.diffuse * cos } else { sh.diffuse * (cos / PI) };
        out[i] = (diffuse + sh.spec * fv) * j.scale;
    }
    out
}

/// The material's density (cosine mixture and sampler) of each needed direction.
fn material_pdfs(sh: &Shading, group: &[&(usize, Surface)], need: &[(usize, [f64; 3])]) -> Vec<f64> {
    let cos: Vec<f64> = need.iter().map(|(_, l)| l[2].max(0.0) / PI).collect();
    match &sh.sampler {
        Some(smp) if sh.alpha < 1.0 && !need.is_empty() => {
            let wi: Vec<[f64; 3]> = need.iter().map(|(gi, _)| group[*gi].1.v).collect();
            let wo: Vec<[f64; 3]> = need.iter().map(|(_, l)| *l).collect();
            match smp.pdf_many(&wi, &wo) {
                Ok(p) => cos.iter().zip(p).map(|(c, p)| sh.alpha * c + (1.0 - sh.alpha) * p).collect(),
                Err(_) => cos,
            }
        }
        _ => cos,
    }
}

/// A cosine-distributed local direction.
fn cosine(u1: f64, u2: f64) -> [f64; 3] {
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    [r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt()]
}

/// The HDR frame as 8-bit pixels through `transfer` (the PNG path).
pub fn to_image(f: &HdrFrame, transfer: super::image::Transfer) -> super::image::Image {
    let rgb = f.rgb.iter().flat_map(|p| p.map(|c| transfer.encode(f64::from(c)))).collect();
    super::image::Image { width: f.width, height: f.height, rgb }
}

/// An OpenEXR file of the frame (linear 32-bit float RGB, its layer named `lobe`).
pub fn encode_exr(f: &HdrFrame) -> Result<Vec<u8>, String> {
    super::envmap::encode_exr(f.width, f.height, &f.rgb)
}

/// Whether the first bytes of a file are an OpenEXR image lobe wrote (its header names the layer `lobe`), so
/// an output may replace it without being forced.
pub fn is_lobe_exr(bytes: &[u8]) -> bool {
    const NAME: &[u8] = b"name\0string\0";
    let head = &bytes[..bytes.len().min(4096)];
    head.starts_with(&[0x76, 0x2f, 0x31, 0x01])
        && head.windows(NAME.len()).position(|w| w == NAME).is_some_and(|i| head[i + NAME.len()..].get(..8) == Some(b"\x04\0\0\0lobe"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lobes_exr_files_are_recognised_and_others_are_not() {
        let f = HdrFrame { width: 3, height: 2, rgb: vec![[0.5, 1.0, 2.0]; 6], covered: vec![true; 6] };
        let bytes = encode_exr(&f).unwrap();
        assert!(is_lobe_exr(&bytes));
        let other = crate::render::envmap::encode_exr(3, 2, &f.rgb).unwrap().iter().map(|&b| if b == b'l' { b'x' } else { b }).collect::<Vec<u8>>();
        assert!(!is_lobe_exr(&other));
        assert!(!is_lobe_exr(b"\x89PNG"));
    }

    #[test]
    fn progressive_levels_grow_by_four_and_cost_at_most_four_thirds() {
        assert_eq!(levels(64), vec![1, 4, 16, 64]);
        assert_eq!(levels(100), vec![1, 6, 25, 100]);
        assert_eq!(levels(1), vec![1]);
        assert_eq!(levels(3), vec![3]);
        for spp in [1, 2, 5, 16, 17, 1000, MAX_SPP] {
            let l = levels(spp);
            assert_eq!(*l.last().unwrap(), spp);
            assert!(l.windows(2).all(|w| w[0] < w[1]) && l[0] >= 1);
            assert!(3 * l.iter().sum::<usize>() <= 4 * spp, "{spp}: {l:?}");
        }
    }

    #[test]
    fn cosine_directions_are_unit_and_above_the_horizon() {
        for k in 0..100 {
            let l = cosine((k as f64 + 0.5) / 100.0, (k * 37 % 100) as f64 / 100.0);
            assert!((l[0] * l[0] + l[1] * l[1] + l[2] * l[2] - 1.0).abs() < 1e-12 && l[2] > 0.0);
        }
    }
}
