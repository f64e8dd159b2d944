//! Rendering and energy of formulas that read directions in the local frame and of colour formulas (issue
//! 13): anisotropic highlights stretch along the tangent, colour renders have distinct channels, the local
//! frame's inputs are unit vectors, NaN is counted per channel, energy integrates over the azimuth.
//!
//! The test formulas are built in code through `front::values::Values` (an anisotropic Ward and a
//! principled-like colour model), compiled by a [`BrdfCompiler`] of this file; the example scenes
//! `aniso_ward.toml` and `principled.toml` name BRDF Explorer files that another branch adds, so they are
//! loaded here with this compiler in place of the file's formula — and, once those files exist, also with
//! the real one.

use lobe::backend::Evaluator;
use lobe::base::span::Span;
use lobe::builtins::Builtin;
use lobe::front::values::{Cmp, Val, Values};
use lobe::ir::{BinOp, Formula, Input, Ir, Meta, ParamDecl, ParamKind};
use lobe::numerics::energy::{albedo_at, full_energy_for};
use lobe::render::scene::{self, compile_channels, BrdfCompiler, CompiledBrdf, LoadOptions, LobeCompiler};
use lobe::render::{self as r, RenderOptions};
use lobe::{Backend, Diagnostics};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn f(v: Val) -> lobe::ir::NodeId {
    match v {
        Val::F(x) | Val::B(x) => x,
        Val::V(_) => panic!("a float expected"),
    }
}

/// `name(args…)` through the shared value builder.
fn call(b: &mut Values, name: &str, args: &[Val]) -> Val {
    b.function(name, args).expect("known function").expect("well typed")
}

fn ar(b: &mut Values, op: BinOp, x: Val, y: Val) -> Val {
    b.arith(op, x, y).unwrap()
}

/// `((x op₁ y₁) op₂ y₂) …`, left to right.
fn fold(b: &mut Values, x: Val, steps: &[(BinOp, Val)]) -> Val {
    steps.iter().fold(x, |acc, &(op, y)| ar(b, op, acc, y))
}

/// `cond ? x : 0` with cond = L·N > 0 && V·N > 0: the upper hemisphere only.
fn upper(b: &mut Values, x: Val) -> Val {
    let (l, v) = (b.frame("L").unwrap(), b.frame("V").unwrap());
    let (lz, vz) = (b.component(l, 2).unwrap(), b.component(v, 2).unwrap());
    let zero = b.num(0.0);
    let cl = b.compare(Cmp::Gt, lz, zero).unwrap();
    let cv = b.compare(Cmp::Gt, vz, zero).unwrap();
    let c = b.and(cl, cv).unwrap();
    let zeros = match x {
        Val::V(_) => Val::V([f(zero); 3]),
        _ => zero,
    };
    b.select(c, x, zeros).unwrap()
}

/// Ward's anisotropic BRDF: exp(−((H·X/αx)² + (H·Y/αy)²)/(H·N)²) / (4π·αx·αy·√(N·L N·V)), with H unnormalised
/// (the ratios do not need it).
fn ward(ax: f64, ay: f64) -> Formula {
    let mut ir = Ir::new();
    let s = Span::default();
    let mut b = Values::new(&mut ir, s);
    let (l, v) = (b.frame("L").unwrap(), b.frame("V").unwrap());
    let h = ar(&mut b, BinOp::Add, l, v);
    let (hx, hy, hz) = (b.component(h, 0).unwrap(), b.component(h, 1).unwrap(), b.component(h, 2).unwrap());
    let (pax, pay) = (Val::F(b.ir.param(0, s)), Val::F(b.ir.param(1, s)));
    let tx = ar(&mut b, BinOp::Div, hx, pax);
    let ty = ar(&mut b, BinOp::Div, hy, pay);
    let ty2 = ar(&mut b, BinOp::Mul, ty, ty);
    let q = fold(&mut b, tx, &[(BinOp::Mul, tx), (BinOp::Add, ty2), (BinOp::Div, hz), (BinOp::Div, hz)]);
    let e = b.neg(q).unwrap();
    let num = call(&mut b, "exp", &[e]);
    let (lz, vz) = (b.component(l, 2).unwrap(), b.component(v, 2).unwrap());
    let lv = ar(&mut b, BinOp::Mul, lz, vz);
    let root = call(&mut b, "sqrt", &[lv]);
    let k = b.num(4.0 * std::f64::consts::PI);
    let den = fold(&mut b, k, &[(BinOp::Mul, pax), (BinOp::Mul, pay), (BinOp::Mul, root)]);
    let w = ar(&mut b, BinOp::Div, num, den);
    let r = f(upper(&mut b, w));
    let params = vec![ParamDecl::float("alpha_x", ax, 0.001, 1.0), ParamDecl::float("alpha_y", ay, 0.001, 1.0)];
    Formula { meta: Meta { name: Some("ward_anisotropic".into()), citation: None }, params, ir, root: r, file: "ward_anisotropic.brdf".into(), source: String::new(), rgb: None }
}

/// A principled-like colour BRDF: baseColor/π·(1 − metallic) + D·F·G, GGX D with α = roughness², Schlick F
/// from F0 = mix(0.04, baseColor, metallic), Smith G folded with 1/(4 N·L N·V).
fn principled() -> Formula {
    let mut ir = Ir::new();
    let s = Span::default();
    let mut b = Values::new(&mut ir, s);
    let (l, v, n) = (b.frame("L").unwrap(), b.frame("V").unwrap(), b.frame("N").unwrap());
    let base = Val::V([0, 1, 2].map(|k| b.ir.param(k, s)));
    let (rough, metal) = (Val::F(b.ir.param(3, s)), Val::F(b.ir.param(4, s)));
    let sum = ar(&mut b, BinOp::Add, l, v);
    let h = b.normalize(sum).unwrap();
    let (nl, nv, nh) = (b.dot(n, l).unwrap(), b.dot(n, v).unwrap(), b.dot(n, h).unwrap());
    let lh = b.dot(l, h).unwrap();
    let (one, pi) = (b.num(1.0), b.num(std::f64::consts::PI));
    let r2 = ar(&mut b, BinOp::Mul, rough, rough);
    let floor = b.num(0.001);
    let a = call(&mut b, "max", &[r2, floor]);
    let a2 = ar(&mut b, BinOp::Mul, a, a);
    // D = a²/(π (NH²(a² − 1) + 1)²)
    let am1 = ar(&mut b, BinOp::Sub, a2, one);
    let t = fold(&mut b, nh, &[(BinOp::Mul, nh), (BinOp::Mul, am1), (BinOp::Add, one)]);
    let pt = fold(&mut b, pi, &[(BinOp::Mul, t), (BinOp::Mul, t)]);
    let d = ar(&mut b, BinOp::Div, a2, pt);
    // G = 1/((NL + √(a² + NL² − a²NL²))(NV + √(…)))
    let g1 = |b: &mut Values, c: Val| {
        let c2 = ar(b, BinOp::Mul, c, c);
        let ac2 = ar(b, BinOp::Mul, a2, c2);
        let y = fold(b, a2, &[(BinOp::Add, c2), (BinOp::Sub, ac2)]);
        let sq = call(b, "sqrt", &[y]);
        ar(b, BinOp::Add, c, sq)
    };
    let (gl, gv) = (g1(&mut b, nl), g1(&mut b, nv));
    let gg = ar(&mut b, BinOp::Mul, gl, gv);
    let g = ar(&mut b, BinOp::Div, one, gg);
    // F = F0 + (1 − F0)(1 − LH)^5
    let f004 = b.num(0.04);
    let f0 = call(&mut b, "mix", &[Val::V([f(f004); 3]), base, metal]);
    let omlh = ar(&mut b, BinOp::Sub, one, lh);
    let five = b.num(5.0);
    let fh = call(&mut b, "pow", &[omlh, five]);
    let fr = fold(&mut b, one, &[(BinOp::Sub, f0), (BinOp::Mul, fh)]);
    let fresnel = ar(&mut b, BinOp::Add, f0, fr);
    let spec = fold(&mut b, d, &[(BinOp::Mul, g), (BinOp::Mul, fresnel)]);
    let kd = fold(&mut b, one, &[(BinOp::Sub, metal), (BinOp::Div, pi)]);
    let total = fold(&mut b, base, &[(BinOp::Mul, kd), (BinOp::Add, spec)]);
    let Val::V(roots) = upper(&mut b, total) else { panic!("colour") };
    let colour = |c: u8, name: &str, d: f64| ParamDecl { kind: ParamKind::Color(c), ..ParamDecl::float(name, d, 0.0, 1.0) };
    let params = vec![
        colour(0, "baseColor.r", 0.82),
        colour(1, "baseColor.g", 0.67),
        colour(2, "baseColor.b", 0.16),
        ParamDecl::float("roughness", 0.5, 0.0, 1.0),
        ParamDecl::float("metallic", 0.0, 0.0, 1.0),
    ];
    let meta = Meta { name: Some("principled".into()), citation: None };
    Formula::from_channels(meta, params, &ir, roots, "principled.brdf".into(), String::new())
}

/// Compiles the formula `make` builds, whatever file the scene names (through the same channel compilation
/// as [`LobeCompiler`]).
struct Fixed(fn() -> Formula);

impl BrdfCompiler for Fixed {
    fn declare(&self, _file: &str, _src: &str) -> Result<Vec<ParamDecl>, Diagnostics> {
        Ok((self.0)().params)
    }
    fn build(&self, _file: &str, _src: &str, values: &[(String, f64)], math: Option<lobe::Mode>) -> Result<CompiledBrdf, Diagnostics> {
        let opts = lobe::Options { backend: Backend::Jit, bake: values.to_vec(), math: math.unwrap_or_default(), ..Default::default() };
        compile_channels((self.0)(), &opts)
    }
}

fn ward_default() -> Formula {
    ward(0.4, 0.05)
}

fn scene_with(src: &str, make: fn() -> Formula) -> r::Scene {
    let opts = LoadOptions { formula_override: Some(("test.brdf".into(), String::new())), ..LoadOptions::default() };
    scene::parse_scene("t.toml", src, Path::new("."), &opts, &Fixed(make)).unwrap_or_else(|d| panic!("{}", d.render(false)))
}

fn render(s: &r::Scene, threads: usize) -> (r::Frame, r::RenderStats) {
    r::render(s, &RenderOptions { threads, tile: 32, ..RenderOptions::default() }).expect("render")
}

/// A unit sphere seen head-on, lit from the camera's direction, specular only: the highlight sits at the
/// centre, where the sphere's tangent is +x on screen and the bitangent +y.
fn highlight_scene(params: &str, extra: &str) -> String {
    format!(
        "width = 200\nheight = 200\nambient = [0, 0, 0]\n[camera]\nposition = [0, 0, 6]\nfov = 25\n\
         [[light]]\nkind = \"point\"\nposition = [0, 0, 10]\n\
         [materials.m]\nformula = \"x\"\nparams = {{ {params} }}\nka = 0\nkd = 0\nks = 0.1\n{extra}\n\
         [[object]]\nshape = \"sphere\"\nmaterial = \"m\"\ntessellation = 64\n"
    )
}

/// The highlight's extent in pixels along the image's x and y: the bounding box of the pixels at least half
/// as bright (red channel) as the brightest.
fn highlight_extent(im: &lobe::base::image::Image) -> (usize, usize) {
    let max = im.rgb.chunks_exact(3).map(|p| p[0]).max().unwrap();
    assert!(max > 20 && max < 255, "the highlight must be visible and not clipped (max {max})");
    let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
    for (i, p) in im.rgb.chunks_exact(3).enumerate() {
        if u16::from(p[0]) * 2 >= u16::from(max) {
            let (x, y) = (i % im.width, i / im.width);
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
        }
    }
    (x1 - x0 + 1, y1 - y0 + 1)
}

#[test]
fn anisotropic_highlights_stretch_along_the_tangent() {
    let stretched = scene_with(&highlight_scene("alpha_x = 0.4, alpha_y = 0.05", ""), ward_default);
    let (fr, st) = render(&stretched, 2);
    assert_eq!(st.nan, 0);
    let (wx, wy) = highlight_extent(&fr.image);
    assert!(wx as f64 > 2.0 * wy as f64, "extent along the tangent {wx} px vs the bitangent {wy} px");
    // The tangent turned by 90°: the highlight turns with it.
    let turned = scene_with(&highlight_scene("alpha_x = 0.4, alpha_y = 0.05", "tangent_angle_deg = 90"), ward_default);
    let (tx, ty) = highlight_extent(&render(&turned, 2).0.image);
    assert!(ty as f64 > 2.0 * tx as f64, "turned: {tx} px along x, {ty} along y");
    // Equal roughnesses: round.
    let round = scene_with(&highlight_scene("alpha_x = 0.2, alpha_y = 0.2", ""), ward_default);
    let (rx, ry) = highlight_extent(&render(&round, 2).0.image);
    assert!(rx.abs_diff(ry) <= 2, "isotropic: {rx} vs {ry}");
    // Determinism with the frame steps.
    assert_eq!(fr.image.rgb, render(&stretched, 1).0.image.rgb);
}

/// A formula of the local frame that is 0.5 where L and V are unit vectors and NaN (counted) anywhere else.
const UNIT_FRAME: &str = "select(lt(abs(Lx*Lx + Ly*Ly + Lz*Lz - 1), 1e-9) * lt(abs(Vx*Vx + Vy*Vy + Vz*Vz - 1), 1e-9), 0.5, 0/0)";

#[test]
fn the_local_frame_gives_unit_directions_on_every_shape() {
    let src = std::fs::read_to_string(root().join("examples/scenes/torus.toml")).unwrap();
    let opts = LoadOptions { size: Some((96, 96)), formula_override: Some(("frame.brdf".into(), UNIT_FRAME.into())), ..Default::default() };
    let mut s = scene::parse_scene("torus.toml", &src, &root().join("examples/scenes"), &opts, &LobeCompiler::plain(Backend::Jit, lobe::Mode::Precise)).unwrap_or_else(|d| panic!("{}", d.render(false)));
    // Torus, sphere and an OBJ with UVs in one frame.
    let mesh = lobe::render::mesh::load_obj(&root().join("examples/meshes/uv_roof.obj")).unwrap();
    s.objects.push(r::Object { mesh: Arc::new(mesh), material: 0, cull_backfaces: false });
    let mut sphere = lobe::render::mesh::Mesh::sphere(0.4, 12, 24);
    sphere.transform(&lobe::render::mesh::transform_matrix(glam::DVec3::new(0.0, 0.8, 1.0), glam::DVec3::ZERO, glam::DVec3::ONE));
    s.objects.push(r::Object { mesh: Arc::new(sphere), material: 0, cull_backfaces: true });
    for m in &mut s.materials {
        assert!(m.used.reads_directions() && m.used.contains(Input::Lz) && m.used.contains(Input::Vz));
        m.tangent_angle_deg = 33.0;
    }
    let (_, st) = render(&s, 2);
    assert!(st.evals > 1000, "{}", st.evals);
    assert_eq!(st.nan, 0, "a non-unit direction in the local frame");
}

#[test]
fn colour_formulas_render_each_channel() {
    let src = "width = 128\nheight = 128\nambient = [0, 0, 0]\n[camera]\nposition = [0, 0, 6]\nfov = 30\n\
               [[light]]\nkind = \"point\"\nposition = [4, 4, 10]\ncolor = [2, 2, 2]\n\
               [materials.m]\nformula = \"x\"\nparams = { roughness = 0.4 }\nka = 0\nkd = 0\nks = 1\ntimes_nl = true\n\
               [[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n";
    let s = scene_with(src, principled);
    assert!(s.materials[0].green_blue.is_some());
    let (fr, st) = render(&s, 2);
    assert_eq!(st.nan, 0);
    // One kernel call per channel: evaluations come in threes.
    assert_eq!(st.evals % 3, 0);
    assert_eq!(st.kernel_calls % 3, 0);
    let mean = |c: usize| {
        let (sum, n) = fr.image.rgb.chunks_exact(3).zip(&fr.covered).filter(|(_, c)| **c).fold((0u64, 0u64), |(s, n), (p, _)| (s + p[c] as u64, n + 1));
        sum as f64 / n as f64
    };
    let (mr, mg, mb) = (mean(0), mean(1), mean(2));
    // A gold base colour (0.82, 0.67, 0.16): red over green over blue, each clearly apart.
    assert!(mr > mg + 5.0 && mg > mb + 20.0, "means r {mr:.1} g {mg:.1} b {mb:.1}");
    assert_eq!(fr.image.rgb, render(&s, 1).0.image.rgb, "1 and N threads");
    // Blue set to zero changes only the blue channel's diffuse part (green and red stay byte for byte).
    let grey = scene_with(&src.replace("roughness = 0.4", "roughness = 0.4, \"baseColor.b\" = 0"), principled);
    let g = render(&grey, 2).0.image;
    for (p, q) in fr.image.rgb.chunks_exact(3).zip(g.rgb.chunks_exact(3)) {
        assert_eq!((p[0], p[1]), (q[0], q[1]));
        assert!(q[2] <= p[2]);
    }
}

/// Red is Ward; green is NaN everywhere; blue is Ward again.
fn nan_green() -> Formula {
    let w = ward(0.3, 0.3);
    let mut ir = w.ir.clone();
    let s = Span::default();
    let m1 = ir.konst(-1.0, s);
    let nan = ir.call(Builtin::Sqrt, &[m1], s);
    let lx = ir.input(Input::Lx, s);
    let g = ir.bin(BinOp::Add, nan, lx, s);
    Formula::from_channels(w.meta.clone(), w.params.clone(), &ir, [w.root, g, w.root], "nan.brdf".into(), String::new())
}

#[test]
fn nan_is_counted_per_channel() {
    let s = scene_with(&highlight_scene("alpha_x = 0.3, alpha_y = 0.3", ""), nan_green);
    let (fr, st) = render(&s, 2);
    assert!(st.evals > 0);
    assert_eq!(st.nan * 3, st.evals, "the green channel's evaluations, and only those");
    assert!(fr.image.rgb.chunks_exact(3).all(|p| p[1] == 0 && p[0] == p[2]));
}

#[test]
fn example_scenes_load_with_the_formulas_they_name() {
    // The example scenes name BRDF Explorer files by path; with a stand-in formula of the same parameters they
    // load and render the documented look. Where the real files exist, they are loaded as well.
    for (name, make, real) in [("aniso_ward.toml", ward_default as fn() -> Formula, "ward_anisotropic.brdf"), ("principled.toml", principled, "principled.brdf")] {
        let path = root().join("examples/scenes").join(name);
        let src = std::fs::read_to_string(&path).unwrap();
        assert!(src.contains(&format!("brdf = \"../explorer/{real}\"")), "{name} names {real}");
        let opts = LoadOptions { size: Some((96, 96)), formula_override: Some((real.into(), String::new())), ..LoadOptions::default() };
        let s = scene::parse_scene(name, &src, &root().join("examples/scenes"), &opts, &Fixed(make)).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let (fr, st) = render(&s, 2);
        assert!(st.visible_pixels > 1000 && st.nan == 0, "{name}: {st:?}");
        assert_eq!(fr.image.rgb, render(&s, 1).0.image.rgb, "{name}: determinism");
        if root().join("examples/explorer").join(real).exists() {
            let jit = LobeCompiler::plain(Backend::Jit, lobe::Mode::Precise);
            let s = scene::load_scene(&path, &LoadOptions { size: Some((96, 96)), ..LoadOptions::default() }, &jit).unwrap_or_else(|d| panic!("{}", d.render(false)));
            assert!(render(&s, 2).1.visible_pixels > 1000);
        }
    }
}

#[test]
fn full_energy_integrates_over_the_azimuth_for_direction_formulas() {
    let k = lobe::compile_formula(ward(0.4, 0.05), &lobe::Options { backend: Backend::Jit, ..Default::default() }).unwrap();
    let p = k.default_params();
    // Light grazing along the tangent sees a different albedo than along the bitangent.
    let t = 70f64.to_radians();
    let along_x = albedo_at(&k, &p, t, Some(0.0)).unwrap();
    let along_y = albedo_at(&k, &p, t, Some(std::f64::consts::FRAC_PI_2)).unwrap();
    assert!((along_x - along_y).abs() > 0.02 * along_x, "{along_x} vs {along_y}");
    // The full circle equals the symmetric half circle where the problem is symmetric (φᵢ = 0 here).
    let half = lobe::numerics::energy::albedo(&k, &p, t).unwrap();
    assert!((half - along_x).abs() < 1e-6 * half, "{half} vs {along_x}");
    let e = full_energy_for(&k, k.used_inputs(), &p).unwrap();
    assert_eq!(e.albedo_phi.len(), e.albedo.len() * 24);
    let at = e.phi_i_at_max_deg.expect("azimuth of the maximum");
    let best = e.albedo_phi.iter().map(|c| c.2).fold(0.0, f64::max);
    assert_eq!(best, e.albedo_max);
    assert!(e.albedo_phi.iter().any(|c| c.0 == e.theta_i_at_max_deg && c.1 == at && c.2 == best));
    // Ward is reciprocal, whatever the azimuth.
    assert!(e.reciprocity.max_rel < 1e-12, "{:?}", e.reciprocity);
    // Against a brute-force midpoint rule over the hemisphere (θₒ, φₒ in 300 × 600 cells).
    let brute = |t: f64, ph: f64| {
        let l = lobe::numerics::dir(t, ph);
        let (nt, np) = (300, 600);
        let (dt, dp) = (std::f64::consts::FRAC_PI_2 / nt as f64, 2.0 * std::f64::consts::PI / np as f64);
        let mut sum = 0.0;
        for i in 0..nt {
            let to = (i as f64 + 0.5) * dt;
            for j in 0..np {
                let v = lobe::numerics::dir(to, (j as f64 + 0.5) * dp);
                sum += k.eval(&lobe::numerics::inputs_from_dirs(l, v), &p) * to.cos() * to.sin();
            }
        }
        sum * dt * dp
    };
    for (td, pd) in [(0.0, 0.0), (30.0, 45.0), (60.0, 90.0), (75.0, 20.0)] {
        let (t, ph) = (f64::to_radians(td), f64::to_radians(pd));
        let (a, b) = (albedo_at(&k, &p, t, Some(ph)).unwrap(), brute(t, ph));
        assert!((a - b).abs() < 5e-3 * b, "θᵢ = {td}°, φᵢ = {pd}°: {a} vs brute force {b}");
    }
    // The same formula with equal roughnesses is isotropic although it reads directions: flat in φᵢ.
    for d in [0.0, 40.0, 80.0] {
        let a = albedo_at(&k, &[0.2, 0.2], f64::to_radians(d), Some(0.0)).unwrap();
        let b = albedo_at(&k, &[0.2, 0.2], f64::to_radians(d), Some(1.1)).unwrap();
        assert!((a - b).abs() < 1e-6 * a, "θ = {d}: {a} vs {b}");
    }
    // So the full mode sees it turn with the frame and integrates one azimuth, with the sweep's maximum; the
    // anisotropic one it does not.
    use lobe::numerics::energy::turns_with_the_frame;
    assert!(!turns_with_the_frame(&k, &p) && e.isotropic == Some(false));
    assert!(turns_with_the_frame(&k, &[0.2, 0.2]));
    let iso = full_energy_for(&k, k.used_inputs(), &[0.2, 0.2]).unwrap();
    assert_eq!((iso.isotropic, iso.albedo_phi.len(), iso.phi_i_at_max_deg), (Some(true), iso.albedo.len(), Some(0.0)));
    let t = f64::to_radians(iso.theta_i_at_max_deg);
    let swept = (0..24).map(|j| albedo_at(&k, &[0.2, 0.2], t, Some(f64::to_radians(15.0 * j as f64))).unwrap()).fold(0.0, f64::max);
    assert!((swept - iso.albedo_max).abs() < 1e-9 * swept, "{swept} vs {}", iso.albedo_max);
}

fn channel_kernels(f: Formula) -> Vec<lobe::Kernel> {
    f.channels().into_iter().map(|c| lobe::compile_formula(c, &lobe::Options { backend: Backend::Jit, ..Default::default() }).unwrap()).collect()
}

#[test]
fn energy_reports_each_channel_of_a_colour_formula() {
    use lobe::base::json::Named;
    use lobe::numerics::energy::{FullReport, PerChannel};
    let ks = channel_kernels(principled());
    assert_eq!(ks.len(), 3);
    let reports: Vec<FullReport> = ks
        .iter()
        .map(|k| {
            let p = k.default_params();
            let named = Named::new(k.formula.params.iter().zip(&p).map(|(d, v)| (d.name.as_str(), *v)));
            FullReport::new(named, &full_energy_for(k, k.used_inputs(), &p).unwrap())
        })
        .collect();
    let v = serde_json::to_value(PerChannel::new(reports)).unwrap();
    let ch = v["channels"].as_array().expect("channels");
    assert_eq!(ch.len(), 3);
    // The top-level keys are the red channel's.
    assert_eq!(v["albedo_max"], ch[0]["albedo_max"]);
    let rho = |c: usize| ch[c]["albedo_max"].as_f64().unwrap();
    // Gold (0.82, 0.67, 0.16), dielectric: the diffuse albedo follows the base colour, plus a white specular part.
    assert!(rho(0) > rho(1) && rho(1) > rho(2) + 0.2, "{} {} {}", rho(0), rho(1), rho(2));
    // At normal incidence: the diffuse albedo (1 − metallic)·baseColor plus a small specular part (F0 = 0.04).
    for (c, base) in [0.82, 0.67, 0.16].into_iter().enumerate() {
        let r0 = ch[c]["albedo"][0]["rho"].as_f64().unwrap();
        assert!(r0 > base + 0.01 && r0 < base + 0.1, "channel {c}: ρ(0) = {r0}");
    }
    assert!(ch.iter().all(|c| c["phi_i_at_max_deg"].is_number() && c["albedo_phi"].is_array()));
    // The command's text (lobe mode, the papers' coefficient): one section per channel.
    let colour = "vec3(NH^n, 0.5*NH^n, 0.25*NH^n)";
    let o = crate::cli::lobe(&["energy", "--expr", colour], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let t = String::from_utf8_lossy(&o.stdout);
    for c in ["channel r:", "channel g:", "channel b:"] {
        assert!(t.contains(c), "{c}: {t}");
    }
    assert_eq!(t.matches("coef = 1/(2π·Int)").count(), 3, "{t}");
    let o = crate::cli::lobe(&["energy", "--expr", colour, "--range", "1..2"], None);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("scalar formulas only"));
    // A scalar formula's output has no channels.
    let o = crate::cli::lobe(&["energy", "examples/brdfs/blinn.brdf", "--json"], None);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["channels"].is_null() && v["coef"].is_number());
    // The library's report of one channel has no channels either.
    let w = channel_kernels(ward_default());
    let p = w[0].default_params();
    let one = PerChannel::new(vec![FullReport::new(Named::default(), &full_energy_for(&w[0], w[0].used_inputs(), &p).unwrap())]);
    let v = serde_json::to_value(one).unwrap();
    assert!(v["channels"].is_null() && v["coef"].is_number());
}

/// Not a check: renders the example scenes with the stand-in formulas to `target/explorer-render/` and prints
/// the highlight extents, for looking at (`cargo test --test it explorer_render -- --ignored --nocapture`).
#[test]
#[ignore = "report, not a check: writes PNGs"]
fn explorer_render_report() {
    let out = root().join("target/explorer-render");
    std::fs::create_dir_all(&out).unwrap();
    for (name, make, real) in [("aniso_ward.toml", ward_default as fn() -> Formula, "ward_anisotropic.brdf"), ("principled.toml", principled, "principled.brdf")] {
        let src = std::fs::read_to_string(root().join("examples/scenes").join(name)).unwrap();
        let opts = LoadOptions { formula_override: Some((real.into(), String::new())), ..LoadOptions::default() };
        let s = scene::parse_scene(name, &src, &root().join("examples/scenes"), &opts, &Fixed(make)).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let (fr, st) = render(&s, 0);
        let png = out.join(name.replace(".toml", ".png"));
        std::fs::write(&png, fr.image.encode_png().unwrap()).unwrap();
        println!("{}: {} visible px, {} evals, {} NaN", png.display(), st.visible_pixels, st.evals, st.nan);
    }
    for (label, params, extra) in [("stretched", "alpha_x = 0.4, alpha_y = 0.05", ""), ("turned 90°", "alpha_x = 0.4, alpha_y = 0.05", "tangent_angle_deg = 90"), ("isotropic", "alpha_x = 0.2, alpha_y = 0.2", "")] {
        let (fr, _) = render(&scene_with(&highlight_scene(params, extra), ward_default), 0);
        let (wx, wy) = highlight_extent(&fr.image);
        println!("highlight {label}: {wx} px along the tangent (x), {wy} px along the bitangent (y), ratio {:.2}", wx as f64 / wy as f64);
        std::fs::write(out.join(format!("highlight_{}.png", label.split(' ').next().unwrap())), fr.image.encode_png().unwrap()).unwrap();
    }
    // `lobe energy --mode full` on both models (the same code path: full_energy_for per channel kernel).
    for (label, f) in [("ward αx = 0.4, αy = 0.05", ward(0.4, 0.05)), ("principled (defaults)", principled())] {
        for (c, k) in channel_kernels(f).iter().enumerate() {
            let t = std::time::Instant::now();
            let e = full_energy_for(k, k.used_inputs(), &k.default_params()).unwrap();
            let at0 = e.albedo_phi.iter().filter(|c| c.0 == 0.0).map(|c| c.2).fold(0.0, f64::max);
            let spread = e.albedo.iter().map(|&(th, _)| {
                let row: Vec<f64> = e.albedo_phi.iter().filter(|c| c.0 == th).map(|c| c.2).collect();
                row.iter().fold(0.0f64, |m, v| m.max(*v)) / row.iter().fold(f64::INFINITY, |m, v| m.min(*v))
            }).fold(1.0, f64::max);
            println!(
                "energy {label} channel {c}: ρ(0) = {at0:.4}, max ρ = {:.4} at θᵢ = {}°, φᵢ = {:?}°; max over θᵢ of maxφ/minφ = {spread:.3}; reciprocity {:.1e}; {} integrals in {:.1} s wall",
                e.albedo_max, e.theta_i_at_max_deg, e.phi_i_at_max_deg, e.reciprocity.max_rel, e.albedo_phi.len(), t.elapsed().as_secs_f64()
            );
        }
    }
}

/// NH^50, NH^10, NH^200 as red, green, blue.
fn three_powers() -> Formula {
    let mut ir = Ir::new();
    let s = Span::default();
    let nh = ir.input(Input::NH, s);
    let (z, o) = (ir.konst(0.0, s), ir.konst(1.0, s));
    let c = ir.call(Builtin::Clamp, &[nh, z, o], s);
    let roots = [50.0, 10.0, 200.0].map(|n| {
        let k = ir.konst(n, s);
        ir.call(Builtin::Pow, &[c, k], s)
    });
    Formula::from_channels(Meta::default(), vec![ParamDecl::float("n", 1.0, 1.0, 1.0)], &ir, roots, "powers.brdf".into(), String::new())
}

#[test]
fn a_colour_cutoff_keeps_the_widest_channel() {
    let src = highlight_scene("", "cutoff = 8");
    let s = scene_with(&src, three_powers);
    let c = s.materials[0].cutoff.expect("a cut-off");
    // NH^10 < 2^-8 beyond acos(2^(-8/10)): the green channel's angle, the widest of the three.
    let green = (-8.0f64 / 10.0).exp2().acos().to_degrees();
    assert!(c.angle_deg() > green && c.angle_deg() < green + 0.05, "{} vs {green}", c.angle_deg());
    let (cut, st) = render(&s, 2);
    assert!(st.cut > 0 && st.nan == 0);
    // No channel changes by more than one level against the render without the cut-off.
    let full = r::render(&s, &RenderOptions { threads: 2, tile: 32, cutoff: false, ..RenderOptions::default() }).unwrap().0;
    assert!(cut.image.rgb.iter().zip(&full.image.rgb).all(|(a, b)| a.abs_diff(*b) <= 1));
}
