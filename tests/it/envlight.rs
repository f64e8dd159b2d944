//! Environment light and the ray tracer (lobe::render::trace): the white furnace, image mean against
//! `energy --mode full`'s albedo, determinism over thread counts, self-shadowing, and bad input (maps, spp,
//! keys) as scene diagnostics.

use lobe::render::envmap::{self, EnvMap, Pixels};
use lobe::render::scene::{self, LoadOptions, LobeCompiler};
use lobe::render::trace::{self, HdrFrame, Strategy};
use lobe::render::{self as r, RenderOptions};
use std::path::Path;

const JIT: LobeCompiler = LobeCompiler::plain(lobe::Backend::Jit, lobe::Mode::Precise);

fn parse(dir: &Path, src: &str) -> Result<r::Scene, String> {
    scene::parse_scene("scene.toml", src, dir, &LoadOptions::default(), &JIT).map_err(|d| d.render(false))
}

fn hdr(s: &r::Scene, threads: usize, strategy: Strategy) -> HdrFrame {
    trace::render_hdr(s, &RenderOptions { threads, strategy, ..RenderOptions::default() }).expect("render").0
}

/// Through the OpenEXR file the command writes, read back.
fn via_exr(f: &HdrFrame) -> Vec<[f32; 3]> {
    let back = envmap::decode(&trace::encode_exr(f).unwrap()).unwrap();
    assert_eq!((back.width, back.height), (f.width, f.height));
    back.rgb
}

const FURNACE: &str = r#"
width = 40
height = 40
spp = 1024
[environment]
color = [1, 1, 1]
[camera]
position = [0, 0, 6]
fov = 25
[materials.white]
formula = "1/pi"
kd = 0
ks = 1
times_nl = true
[[object]]
shape = "sphere"
material = "white"
tessellation = 40
"#;

#[test]
fn white_furnace_is_one_at_every_sphere_pixel() {
    // What the tessellation's shadow terminator (below) takes from a pixel's expectation, at most.
    const TERMINATOR: f64 = 1e-3;
    let dir = crate::scratch_dir("envlight", "furnace");
    for strategy in [Strategy::Mis, Strategy::Env, Strategy::Bsdf] {
        let s = parse(&dir, FURNACE).unwrap();
        let f = hdr(&s, 2, strategy);
        let px = via_exr(&f);
        let vals: Vec<f64> = px.iter().zip(&f.covered).filter(|(_, c)| **c).map(|(p, _)| f64::from(p[1])).collect();
        assert!(vals.len() > 300, "{} sphere pixels", vals.len());
        let n = vals.len() as f64;
        let mean = vals.iter().sum::<f64>() / n;
        let sigma = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        if strategy == Strategy::Bsdf {
            // The cosine-proportional sampler alone is exact under a constant sky, but for the directions between
            // the interpolated normal's horizon and the facet's plane, which go into the sphere (the tessellation's
            // shadow terminator): a sample in a few hundred, so the mean is 1 to 10⁻³ and σ is tiny.
            assert!((mean - 1.0).abs() < TERMINATOR && sigma < 0.01, "{strategy:?}: mean {mean}, σ {sigma}");
            continue;
        }
        // Every pixel has expectation 1 (less the terminator's share above, under 10⁻³): their spread is the
        // per-pixel σ. The mean is within 3σ/√n of 1, and every pixel within 1 ± zσ with z the two-sided Šidák
        // quantile for α = 1 % over n pixels (≈ 4.2 for n ≈ 600). A pixel is a mean of 1 024 samples, so it is
        // near normal even where MIS's samples are skewed (under this sky MIS draws ~1 % of its directions from
        // the sphere, half of them below the horizon: weight 0).
        assert!((mean - 1.0).abs() <= 3.0 * sigma / n.sqrt() + TERMINATOR, "{strategy:?}: mean {mean}, σ {sigma}");
        let z = 4.2 + 0.25 * (n / 600.0).ln().max(0.0);
        for (i, v) in vals.iter().enumerate() {
            assert!((v - 1.0).abs() <= z * sigma + TERMINATOR, "{strategy:?}: pixel {i} = {v}, σ {sigma}");
        }
        // Uniform sphere sampling (env-only) wastes half its samples below the horizon: noisier, still bounded;
        // MIS with the cosine-proportional sampler is much better.
        let bound = if strategy == Strategy::Env { 0.3 } else { 0.1 };
        assert!(sigma < bound, "{strategy:?}: σ {sigma}");
        // The R and B channels equal G (a white sky and a scalar formula).
        assert!(px.iter().all(|p| p[0] == p[1] && p[2] == p[1]));
    }
}

/// A 4 × 4 quad at the origin facing +z, as an OBJ file.
fn quad(dir: &Path) {
    std::fs::write(
        dir.join("quad.obj"),
        "v -2 -2 0\nv 2 -2 0\nv 2 2 0\nv -2 2 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 1//1 3//1 4//1\n",
    )
    .unwrap();
}

/// The fair comparison with `lobe energy --mode full`: its albedo ρ(θᵢ) integrates f(L, V)·cosθᵥ over V with L
/// fixed; a pixel integrates f(L, V)·cosθₗ over L with V fixed. For a reciprocal BRDF (normalised Blinn–Phong
/// here, `times_nl`) the two agree at equal angles, so a flat quad seen head-on from far away (every pixel at
/// θᵥ < 0.6°) under a white sky has image mean ρ(0).
#[test]
fn image_mean_matches_energy_full_albedo() {
    let dir = crate::scratch_dir("envlight", "albedo");
    quad(&dir);
    let src = r#"
width = 32
height = 32
spp = 64
[environment]
color = [1, 1, 1]
[camera]
position = [0, 0, 100]
fov = 1
[materials.blinn]
formula = "param n = 20; (n + 2) / (8 * pi) * NH^n"
kd = 0
ks = 1
times_nl = true
[[object]]
shape = "mesh"
path = "quad.obj"
material = "blinn"
"#;
    let s = parse(&dir, src).unwrap();
    let f = hdr(&s, 2, Strategy::Mis);
    assert!(f.covered.iter().all(|c| *c));
    let px = via_exr(&f);
    let mean = px.iter().map(|p| f64::from(p[0])).sum::<f64>() / px.len() as f64;
    let m = &s.materials[0];
    let albedo = lobe::numerics::energy::albedo(m.evaluator.as_ref(), &m.params, 0.0).unwrap();
    assert!(albedo > 0.5 && albedo < 1.0, "albedo {albedo}");
    assert!((mean / albedo - 1.0).abs() < 0.01, "image mean {mean} vs albedo {albedo}");
}

/// A generated map with a bright sun and a blue sky.
fn sky(w: usize, h: usize) -> Pixels {
    let rgb = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if y < h / 2 {
                if (x as i64 - w as i64 / 3).abs() < 2 && (y as i64 - h as i64 / 5).abs() < 2 {
                    [400.0, 380.0, 300.0]
                } else {
                    [0.3, 0.5, 1.0]
                }
            } else {
                [0.2, 0.15, 0.1]
            }
        })
        .collect();
    Pixels { width: w, height: h, rgb }
}

fn write_map(dir: &Path, name: &str, p: &Pixels) {
    let bytes = if name.ends_with(".exr") { envmap::encode_exr(p.width, p.height, &p.rgb).unwrap() } else { envmap::encode_hdr(p, true) };
    std::fs::write(dir.join(name), bytes).unwrap();
}

const TORUS: &str = r#"
width = 48
height = 36
spp = 8
shadows = true
[environment]
path = "sky.exr"
rotate = 40
intensity = 0.5
[camera]
position = [0, 3, 5]
fov = 40
[[light]]
kind = "directional"
direction = [-1, -0.15, 0]
color = [2, 2, 2]
[materials.shiny]
brdf = "../../examples/brdfs/phong.brdf"
params = { n = 30 }
kd = 0.4
ks = 0.6
[[object]]
shape = "torus"
material = "shiny"
major_radius = 1
minor_radius = 0.4
"#;

#[test]
fn one_and_many_threads_give_the_same_bits_and_png_through_render() {
    let dir = crate::scratch_dir("envlight", "threads");
    write_map(&dir, "sky.exr", &sky(64, 32));
    let src = TORUS.replace("../../examples", &format!("{}/examples", env!("CARGO_MANIFEST_DIR")));
    let s = parse(&dir, &src).unwrap();
    let a = hdr(&s, 1, Strategy::Mis);
    let b = hdr(&s, 3, Strategy::Mis);
    assert_eq!(a.rgb, b.rgb);
    assert_eq!(a.covered, b.covered);
    assert!(a.rgb.iter().all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0)));
    // `render` goes the same way for such a scene (8-bit through the transfer).
    let (frame, stats) = r::render(&s, &RenderOptions { threads: 2, ..RenderOptions::default() }).unwrap();
    assert_eq!(frame.image.rgb, trace::to_image(&a, r::image::Transfer::Linear).rgb);
    assert!(stats.visible_pixels > 0 && stats.evals > 0);
    // The same map as Radiance .hdr gives the same image up to RGBE's 8-bit mantissas.
    write_map(&dir, "sky.hdr", &sky(64, 32));
    let c = hdr(&parse(&dir, &src.replace("sky.exr", "sky.hdr")).unwrap(), 2, Strategy::Mis);
    let rel = a.rgb.iter().zip(&c.rgb).map(|(p, q)| (p[1] - q[1]).abs() / p[1].max(1e-3)).fold(0.0f32, f32::max);
    assert!(rel < 0.02, "exr vs hdr: {rel}");
}

#[test]
fn the_torus_shadows_itself() {
    let dir = crate::scratch_dir("envlight", "shadow");
    write_map(&dir, "sky.exr", &sky(64, 32));
    let src = TORUS.replace("../../examples", &format!("{}/examples", env!("CARGO_MANIFEST_DIR")));
    // Only the light, so shadows are all that differs: the environment emits nothing (intensity 0).
    let only_light = src.replace("intensity = 0.5", "intensity = 0");
    let lit = hdr(&parse(&dir, &only_light.replace("shadows = true", "shadows = false")).unwrap(), 2, Strategy::Mis);
    let shadowed = hdr(&parse(&dir, &only_light).unwrap(), 2, Strategy::Mis);
    let mut darker = 0;
    for (p, q) in lit.rgb.iter().zip(&shadowed.rgb) {
        assert!(q[1] <= p[1] + 1e-6, "a shadow ray added light");
        darker += usize::from(q[1] < p[1] - 1e-3);
    }
    assert!(darker > 10, "{darker} pixels in shadow");
}

#[test]
fn mis_is_as_good_as_the_better_strategy_under_a_map() {
    // A diffuse-plus-glossy sphere under the generated sky (a sun and a sky). At equal spp (one direction per
    // camera sample for all three) MIS is within 10 % of the better single strategy's RMSE against a 1024-spp
    // reference (here environment sampling, which MIS leans on: the pilot's choice), and under half the worse one's.
    let dir = crate::scratch_dir("envlight", "strategies");
    write_map(&dir, "sky.exr", &sky(64, 32));
    let src = r#"
width = 24
height = 24
spp = 16
[environment]
path = "sky.exr"
[camera]
position = [0, 0, 4]
fov = 35
[materials.m]
formula = "param n = 40; (n + 2) / (2 * pi) * VR^n"
kd = 0.3
ks = 0.7
times_nl = true
[[object]]
shape = "sphere"
material = "m"
tessellation = 30
"#;
    let s = parse(&dir, src).unwrap();
    let reference = trace::render_hdr(&s, &RenderOptions { threads: 2, spp: Some(1024), ..RenderOptions::default() }).unwrap().0;
    let rmse = |f: &HdrFrame| {
        let n = f.rgb.len() as f64;
        (f.rgb.iter().zip(&reference.rgb).map(|(p, q)| (f64::from(p[1]) - f64::from(q[1])).powi(2)).sum::<f64>() / n).sqrt()
    };
    let e: Vec<f64> = [Strategy::Mis, Strategy::Bsdf, Strategy::Env].iter().map(|st| rmse(&hdr(&s, 2, *st))).collect();
    let (better, worse) = (e[1].min(e[2]), e[1].max(e[2]));
    assert!(e[0] <= 1.1 * better && e[0] < 0.5 * worse, "RMSE mis {} bsdf {} env {}", e[0], e[1], e[2]);
}

/// The pilot's share of environment directions follows where the light comes from: a white diffuse sphere under a
/// constant sky (its cosine sampling is exact) draws almost none from the sky; the same sphere under a small sun
/// draws most from the map; a narrow lobe under that sun, whose pilot sees few and heavy-tailed values, draws at
/// least half from itself. `--stats --json` reports it.
#[test]
fn the_pilot_draws_from_what_carries_the_light() {
    let dir = crate::scratch_dir("envlight", "pilot");
    write_map(&dir, "sun.exr", &sky(64, 32));
    let fraction = |src: &str| {
        let s = parse(&dir, src).unwrap();
        let (_, st) = trace::render_hdr(&s, &RenderOptions { threads: 2, spp: Some(16), ..RenderOptions::default() }).unwrap();
        assert_eq!(st.env_fractions.len(), 1);
        st.env_fractions[0]
    };
    let furnace = fraction(FURNACE);
    assert!(furnace <= 0.1, "white diffuse under a constant sky: {furnace}");
    let under_sun = |formula: &str, kd: f64, ks: f64| {
        FURNACE.replace("color = [1, 1, 1]", "path = \"sun.exr\"").replace("formula = \"1/pi\"", &format!("formula = \"{formula}\"")).replace(
            "kd = 0\nks = 1",
            &format!("kd = {kd}\nks = {ks}"),
        )
    };
    let diffuse = fraction(&under_sun("1/pi", 0.0, 1.0));
    assert!(diffuse >= 0.6, "diffuse under a sun: {diffuse}");
    let narrow = fraction(&under_sun("param n = 1000; (n + 2) / (2 * pi) * VR^n", 0.0, 1.0));
    assert!(narrow <= 0.5, "a narrow lobe under a sun: {narrow}");
    // Through the command: the text and the JSON name the share.
    std::fs::write(dir.join("scene.toml"), under_sun("1/pi", 0.0, 1.0).replace("spp = 1024", "spp = 4")).unwrap();
    let scene = dir.join("scene.toml");
    let out = dir.join("out.exr");
    let o = lobe_cmd(&["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--stats", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let c = j["env_fraction"]["white"].as_f64().unwrap_or_else(|| panic!("no env_fraction.white in {j}"));
    assert!((0.0..=1.0).contains(&c), "{j}");
}

fn scene_with_env(env: &str) -> String {
    format!("width = 8\nheight = 8\n[environment]\n{env}\n[camera]\nposition = [0, 0, 5]\n[materials.m]\nformula = \"1\"\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n")
}

#[test]
fn bad_maps_and_keys_are_scene_errors_with_the_file_and_a_hint() {
    let dir = crate::scratch_dir("envlight", "bad");
    let err = |env: &str| parse(&dir, &scene_with_env(env)).unwrap_err();
    // Missing.
    let e = err("path = \"nope.exr\"");
    assert!(e.contains("nope.exr") && e.contains("cannot read") && e.contains("help:") && e.contains("scene.toml:4:"), "{e}");
    // Truncated OpenEXR and Radiance files.
    let good = envmap::encode_exr(8, 4, &[[1.0, 1.0, 1.0]; 32]).unwrap();
    std::fs::write(dir.join("cut.exr"), &good[..good.len() - 40]).unwrap();
    let e = err("path = \"cut.exr\"");
    assert!(e.contains("cut.exr"), "{e}");
    let hdr_bytes = envmap::encode_hdr(&sky(16, 8), true);
    std::fs::write(dir.join("cut.hdr"), &hdr_bytes[..hdr_bytes.len() - 9]).unwrap();
    assert!(err("path = \"cut.hdr\"").contains("truncated"));
    // NaN and negative pixels.
    for (name, bad, what) in [("nan.exr", f32::NAN, "NaN"), ("neg.exr", -2.0, "negative")] {
        let mut px = vec![[1.0f32; 3]; 32];
        px[9] = [0.5, bad, 0.5];
        std::fs::write(dir.join(name), envmap::encode_exr(8, 4, &px).unwrap()).unwrap();
        let e = err(&format!("path = \"{name}\""));
        assert!(e.contains(what) && e.contains("pixel (1, 1)") && e.contains(name), "{e}");
    }
    // Absurdly large: refused from the header, before decoding the pixels.
    let wide = envmap::encode_exr(envmap::MAX_WIDTH + 1, 1, &vec![[0.0; 3]; envmap::MAX_WIDTH + 1]).unwrap();
    std::fs::write(dir.join("wide.exr"), wide).unwrap();
    assert!(err("path = \"wide.exr\"").contains("outside"));
    std::fs::write(dir.join("huge.hdr"), b"#?RADIANCE\n\n-Y 1000000000 +X 1000000000\n").unwrap();
    assert!(err("path = \"huge.hdr\"").contains("outside"));
    // Not a map at all, both or neither source, bad numbers.
    std::fs::write(dir.join("text.exr"), b"hello").unwrap();
    assert!(err("path = \"text.exr\"").contains("neither OpenEXR"));
    assert!(err("path = \"a.exr\"\ncolor = [1, 1, 1]").contains("exactly one"));
    assert!(err("rotate = 10").contains("exactly one"));
    assert!(err("color = [1, -1, 1]").contains("finite numbers ≥ 0"));
    assert!(err("color = [1, 1, 1]\nintensity = -1").contains("intensity"));
    assert!(err("color = [1, 1, 1]\nsize = 3").contains("unknown field"));
    // spp 0 and 10⁹.
    for bad in ["0", "1000000000"] {
        let e = parse(&dir, &format!("spp = {bad}\n{}", scene_with_env("color = [1, 1, 1]"))).unwrap_err();
        assert!(e.contains("`spp`") && e.contains("outside") && e.contains("help:"), "{e}");
    }
    assert!(trace::render_hdr(&parse(&dir, &scene_with_env("color = [1, 1, 1]")).unwrap(), &RenderOptions { spp: Some(0), ..RenderOptions::default() }).is_err());
}

#[test]
fn a_map_of_zeros_is_a_black_sky_not_an_error() {
    let dir = crate::scratch_dir("envlight", "zeros");
    std::fs::write(dir.join("zero.exr"), envmap::encode_exr(8, 4, &[[0.0; 3]; 32]).unwrap()).unwrap();
    let s = parse(&dir, &scene_with_env("path = \"zero.exr\"")).unwrap();
    assert!(!s.environment.as_ref().unwrap().emits());
    let f = hdr(&s, 1, Strategy::Mis);
    assert!(f.rgb.iter().all(|p| *p == [0.0; 3]));
}

/// Debian's blender-data maps (CC0, DWAB-compressed); `.ci/run` installs the package, so CI fails rather than
/// skips when it is missing.
/// blender-data's forest.exr, or `None` (skip, with a message) when it is not installed and
/// `LOBE_REQUIRE_BLENDER_DATA` is not set (then missing is a failure).
pub(crate) fn forest_map() -> Option<std::path::PathBuf> {
    let found = ["/usr/share/blender/datafiles/studiolights/world/forest.exr"]
        .into_iter()
        .map(std::path::PathBuf::from)
        .chain(std::fs::read_dir("/usr/share/blender").into_iter().flatten().flatten().map(|e| e.path().join("datafiles/studiolights/world/forest.exr")))
        .find(|p| p.is_file());
    if found.is_none() {
        assert!(std::env::var_os("LOBE_REQUIRE_BLENDER_DATA").is_none(), "blender-data's forest.exr is not installed");
        eprintln!("skipped: blender-data's forest.exr is not installed");
    }
    found
}

#[test]
fn blenders_forest_map_loads() {
    let Some(path) = forest_map() else { return };
    let m = EnvMap::load(&path, &lobe::base::source::Files::any(), 1.0, 0.0).unwrap();
    assert!(m.emits());
    let (rows, cols) = m.grid();
    assert!(rows >= 64 && cols >= 128, "{rows}×{cols}");
    // Sky above is brighter than the ground below, and sampling is consistent with the density.
    let up = (0..64).map(|i| m.radiance(glam::DVec3::new((i as f64).cos() * 0.3, 0.9, (i as f64).sin() * 0.3).normalize()).y).sum::<f64>();
    let down = (0..64).map(|i| m.radiance(glam::DVec3::new((i as f64).cos() * 0.3, -0.9, (i as f64).sin() * 0.3).normalize()).y).sum::<f64>();
    assert!(up > down, "up {up} down {down}");
    for k in 0..100 {
        let (d, pdf) = m.sample([(k as f64 + 0.5) / 100.0, ((k * 37 % 100) as f64 + 0.5) / 100.0]).unwrap();
        assert!((pdf - m.pdf(d)).abs() <= 1e-9 * pdf);
    }
}

/// BENCHMARKS.md's environment-light numbers (a report, not a check: `cargo test --release --test it
/// envlight::report -- --ignored --nocapture`; needs blender-data's forest.exr). Equal-time RMSE of MIS,
/// BSDF-only and environment-only against a 4096-spp MIS reference for a shiny and a rough GGX sphere; camera
/// samples per second on 2 threads for the papers' sphere under forest.exr; BVH build times.
#[test]
#[ignore = "report, not a check: prints timings"]
fn report() {
    let forest = "/usr/share/blender/datafiles/studiolights/world/forest.exr";
    assert!(Path::new(forest).is_file(), "install blender-data");
    let root = env!("CARGO_MANIFEST_DIR");
    let dir = crate::scratch_dir("envlight", "report");
    let cpu = |s: &r::RenderStats| s.shade_cpu.as_secs_f64();
    for (name, alpha) in [("shiny", 0.05), ("rough", 0.5)] {
        let src = format!(
            "width = 64\nheight = 64\n[environment]\npath = \"{forest}\"\n[camera]\nposition = [0, 0, 4]\nfov = 32\n\
             [materials.m]\nbrdf = \"{root}/examples/explorer/ggx.brdf\"\nparams = {{ alpha = {alpha}, f0 = 0.5 }}\nka = 0\nkd = 0.2\nks = 0.8\ntimes_nl = true\n\
             [[object]]\nshape = \"sphere\"\nmaterial = \"m\"\ntessellation = 40\n"
        );
        let s = parse(&dir, &src).unwrap();
        let go = |spp: usize, strategy: Strategy| trace::render_hdr(&s, &RenderOptions { threads: 2, spp: Some(spp), strategy, ..RenderOptions::default() }).unwrap();
        let (reference, _) = go(4096, Strategy::Mis);
        let rmse = |f: &HdrFrame| {
            let (mut e, mut n) = (0.0, 0);
            for ((p, q), c) in f.rgb.iter().zip(&reference.rgb).zip(&reference.covered) {
                if *c {
                    e += (0..3).map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2)).sum::<f64>() / 3.0;
                    n += 1;
                }
            }
            (e / n as f64).sqrt()
        };
        // Equal time: RMSE scales as 1/√time, so RMSE·√(CPU seconds) is the RMSE one CPU-second buys.
        for strategy in [Strategy::Bsdf, Strategy::Env, Strategy::Mis] {
            let (f, st) = go(64, strategy);
            let (e, t) = (rmse(&f), cpu(&st));
            println!("{name} (GGX α = {alpha}) {strategy:?}: 64 spp RMSE {e:.5} in {t:.3} s CPU → RMSE at 1 CPU-s {:.5}", e * t.sqrt());
        }
    }
    // The papers' sphere under forest.exr.
    let paper = std::fs::read_to_string(format!("{root}/examples/scenes/paper_sphere.toml"))
        .unwrap()
        .replace("../brdfs/", &format!("{root}/examples/brdfs/"))
        .replace("[camera]", &format!("spp = 16\n[environment]\npath = \"{forest}\"\n[camera]"));
    let s = parse(&dir, &paper).unwrap();
    let t = std::time::Instant::now();
    let (_, st) = trace::render_hdr(&s, &RenderOptions { threads: 2, ..RenderOptions::default() }).unwrap();
    let wall = t.elapsed().as_secs_f64();
    let samples = (s.width * s.height * 16) as f64;
    println!(
        "paper sphere under forest.exr, {}×{} at 16 spp, 2 threads: {:.2} s wall, {:.2} M camera samples/s ({:.2} M/s per CPU-second; {} of them hit the sphere)",
        s.width,
        s.height,
        wall,
        samples / wall / 1e6,
        samples / cpu(&st) / 1e6,
        st.visible_pixels
    );
    for tess in [20u32, 200] {
        let mesh = std::sync::Arc::new(lobe::render::mesh::Mesh::sphere(1.0, tess, 2 * tess));
        let objects = vec![r::Object { mesh: mesh.clone(), material: 0, cull_backfaces: true }];
        let t = std::time::Instant::now();
        let bvh = lobe::render::bvh::Bvh::build(&objects);
        println!("BVH build: {} triangles in {:.2} ms", bvh.len(), t.elapsed().as_secs_f64() * 1e3);
    }
}

fn lobe_cmd(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_lobe")).args(args).current_dir(env!("CARGO_MANIFEST_DIR")).output().unwrap()
}

#[test]
fn render_writes_linear_exr_and_refuses_what_it_cannot_do() {
    let dir = crate::scratch_dir("envlight", "cli");
    let out = dir.join("env.exr");
    let o = out.to_str().unwrap();
    for _ in 0..2 {
        // The second run replaces the file without --force: lobe wrote it.
        let r = lobe_cmd(&["render", "examples/scenes/environment.toml", "--size", "24", "--spp", "2", "-q", "-o", o]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let bytes = std::fs::read(&out).unwrap();
    assert!(trace::is_lobe_exr(&bytes));
    let px = envmap::decode(&bytes).unwrap();
    assert_eq!((px.width, px.height), (24, 24));
    // Linear, unclamped radiance: the sky's sun is far above 1 somewhere only if seen; the sphere's pixels are > 0.
    assert!(px.rgb.iter().all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0)) && px.rgb[12 * 24 + 12][0] > 0.0);
    // A rasterised scene has no float image to write.
    let r = lobe_cmd(&["render", "examples/scenes/paper_sphere.toml", "--size", "8", "-o", dir.join("p.exr").to_str().unwrap()]);
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && e.contains("OpenEXR output needs the ray tracer") && e.contains("[environment]"), "{e}");
    assert!(!dir.join("p.exr").exists());
    for bad in ["0", "1000000000"] {
        let r = lobe_cmd(&["render", "examples/scenes/environment.toml", "--spp", bad, "-o", dir.join("x.png").to_str().unwrap()]);
        let e = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && e.contains("outside 1..=65536"), "{e}");
    }
    // A foreign .exr is not overwritten without --force.
    std::fs::write(dir.join("theirs.exr"), envmap::encode_exr(2, 2, &[[1.0; 3]; 4]).unwrap().iter().map(|&b| if b == b'l' { b'L' } else { b }).collect::<Vec<u8>>()).unwrap();
    let r = lobe_cmd(&["render", "examples/scenes/environment.toml", "--size", "8", "--spp", "1", "-o", dir.join("theirs.exr").to_str().unwrap()]);
    assert!(!r.status.success(), "overwrote a foreign file");
}

/// A measured table under an environment and with shadows: sampled by its own tables (the sampler built from
/// the table's lookups), it renders as the formula it was tabulated from — explorer GGX written by `lobe
/// tabulate`, on a sphere under the generated sky, both with multiple importance sampling: the image means
/// within 1 % and the sphere's pixels within a few percent of each other (the table's resolution and the two
/// samplers' noise).
#[test]
fn a_measured_table_renders_under_an_environment_as_its_formula() {
    let dir = crate::scratch_dir("envlight", "measured");
    write_map(&dir, "sky.exr", &sky(64, 32));
    let table = dir.join("ggx.binary");
    let r = lobe_cmd(&["tabulate", "examples/explorer/ggx.brdf", "--set", "alpha=0.3,f0=0.5", "-o", table.to_str().unwrap()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let scene = |material: &str| {
        format!(
            r#"
width = 48
height = 48
spp = 256
shadows = true
[environment]
path = "sky.exr"
rotate = 30
[camera]
position = [0, 0.6, 4]
look_at = [0, 0, 0]
fov = 35
[materials.m]
{material}
ka = 0
kd = 0.2
ks = 0.8
times_nl = true
[[object]]
shape = "sphere"
material = "m"
tessellation = 40
"#
        )
    };
    let ggx = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/explorer/ggx.brdf");
    let formula = parse(&dir, &scene(&format!("brdf = {:?}\nparams = {{ alpha = 0.3, f0 = 0.5 }}", ggx.to_str().unwrap()))).unwrap();
    let measured = parse(&dir, &scene("brdf = \"ggx.binary\"")).unwrap();
    assert!(measured.materials[0].program.channels.is_empty(), "the table is a measured material");
    let (a, b) = (hdr(&formula, 2, Strategy::Mis), hdr(&measured, 2, Strategy::Mis));
    let (pa, pb) = (via_exr(&a), via_exr(&b));
    let lum = |p: &[f32; 3]| 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]);
    let sphere: Vec<(f64, f64)> = pa.iter().zip(&pb).zip(&a.covered).filter(|(_, c)| **c).map(|((x, y), _)| (lum(x), lum(y))).collect();
    assert!(sphere.len() > 500, "{} sphere pixels", sphere.len());
    let n = sphere.len() as f64;
    let (ma, mb) = (sphere.iter().map(|s| s.0).sum::<f64>() / n, sphere.iter().map(|s| s.1).sum::<f64>() / n);
    let mad = sphere.iter().map(|(x, y)| (x - y).abs()).sum::<f64>() / n / ma;
    eprintln!("formula mean {ma:.5}, table mean {mb:.5}, mean |difference| {:.2} % of the mean", 100.0 * mad);
    assert!(ma > 0.01, "a dark image ({ma}) proves nothing");
    assert!((mb / ma - 1.0).abs() < 0.01, "image means {ma} (formula) and {mb} (table)");
    assert!(mad < 0.05, "mean |difference| {:.2} % of the mean", 100.0 * mad);
}
