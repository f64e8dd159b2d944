//! Renderer integration tests: golden images, determinism across thread counts, an analytic pixel, scene
//! errors (file, line, key; nothing written), NaN accounting, used-input pruning, and the shape of the
//! papers' table 4.2.
//!
//! Golden images: tests/golden/*.png, 96×96, compared with a tolerance of max channel difference ≤ 1 and at
//! most 0.1 % of the pixels differing at all (libm differences across machines move a few pixels by one
//! level). `LOBE_BLESS=1 cargo test --test it render::` rewrites them.

use glam::DVec3;
use lobe::ir::{Input, InputSet};
use lobe::render::compare::{self, CompareJob};
use lobe::base::image::Image;
use lobe::render::image::Transfer;
use lobe::render::scene::{self, LoadOptions, LobeCompiler};

const JIT: LobeCompiler = LobeCompiler::plain(lobe::Backend::Jit, lobe::Mode::Precise);
use lobe::render::{self as r, RenderOptions};
use std::path::{Path, PathBuf};
use std::sync::Arc;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scene_file(name: &str) -> PathBuf {
    root().join("examples/scenes").join(name)
}

fn load(name: &str, opts: &LoadOptions) -> r::Scene {
    match scene::load_scene(&scene_file(name), opts, &JIT) {
        Ok(s) => s,
        Err(d) => panic!("{}", d.render(false)),
    }
}

fn sized(w: usize, h: usize) -> LoadOptions {
    LoadOptions { size: Some((w, h)), ..LoadOptions::default() }
}

fn render(s: &r::Scene, threads: usize) -> (r::Frame, r::RenderStats) {
    r::render(s, &RenderOptions { threads, tile: 32, ..RenderOptions::default() }).expect("render")
}

/// Compares with the golden file, or writes it when LOBE_BLESS=1.
pub(crate) fn golden(name: &str, im: &Image) {
    let path = root().join("tests/golden").join(name);
    if std::env::var_os("LOBE_BLESS").is_some() {
        std::fs::write(&path, im.encode_png().unwrap()).unwrap();
        return;
    }
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e} (run with LOBE_BLESS=1 to create it)", path.display()));
    let g = Image::decode_png(&bytes).unwrap();
    assert_eq!((g.width, g.height), (im.width, im.height), "{name}: size");
    let mut differing = 0;
    for (p, q) in im.rgb.chunks_exact(3).zip(g.rgb.chunks_exact(3)) {
        let d = p.iter().zip(q).map(|(a, b)| a.abs_diff(*b)).max().unwrap_or(0);
        assert!(d <= 1, "{name}: a channel differs by {d} > 1");
        differing += usize::from(d > 0);
    }
    assert!(differing * 1000 <= im.width * im.height, "{name}: {differing} pixels differ (> 0.1 %)");
}

#[test]
fn golden_paper_sphere_phong_and_modified_schlick() {
    // The scene's own material is modified Schlick (VR); Phong replaces it for the second image.
    let s = load("paper_sphere.toml", &sized(96, 96));
    golden("paper_sphere_modschlick_n50.png", &render(&s, 2).0.image);
    let src = std::fs::read_to_string(root().join("examples/brdfs/phong.brdf")).unwrap();
    let opts = LoadOptions { formula_override: Some(("phong.brdf".into(), src)), ..sized(96, 96) };
    let s = load("paper_sphere.toml", &opts);
    golden("paper_sphere_phong_n50.png", &render(&s, 2).0.image);
}

#[test]
fn golden_torus_and_mesh() {
    golden("torus.png", &render(&load("torus.toml", &sized(96, 72)), 2).0.image);
    golden("mesh.png", &render(&load("mesh.toml", &sized(96, 96)), 2).0.image);
}

#[test]
fn one_and_many_threads_are_byte_identical() {
    for name in ["paper_sphere.toml", "torus.toml", "mesh.toml"] {
        let s = load(name, &sized(150, 110));
        let (a, sa) = render(&s, 1);
        let (b, sb) = render(&s, 3);
        assert_eq!(sa.threads, 1);
        assert_eq!(sb.threads, 3);
        assert!(a.image == b.image, "{name}: images differ between 1 and 3 threads");
        assert_eq!(a.covered, b.covered);
        assert_eq!((sa.evals, sa.kernel_calls, sa.visible_pixels), (sb.evals, sb.kernel_calls, sb.visible_pixels));
    }
}

/// The centre pixel of an odd-sized paper render looks exactly at the sphere vertex (0, 0, 1), whose normal is
/// (0, 0, 1); its colour is computed here from the lighting equation directly.
#[test]
fn centre_pixel_matches_the_lighting_equation() {
    let s = load("paper_sphere.toml", &sized(97, 97));
    let (f, _) = render(&s, 2);
    let p = DVec3::new(0.0, 0.0, 1.0);
    let n = DVec3::Z;
    let l = (DVec3::new(10.0, 0.0, 10.0) - p).normalize();
    let v = (DVec3::new(0.0, 0.0, 6.0) - p).normalize();
    let nl = n.dot(l);
    let vr = v.dot(n * (2.0 * nl) - l);
    let spec = 0.5 * vr.max(0.0).powf(50.0);
    let expect = [0.4 * 1.0 + 0.5 * nl + spec, 0.5 * nl + spec, 0.5 * nl + spec].map(|c| Transfer::Linear.encode(c));
    let got = f.image.pixel(48, 48);
    for k in 0..3 {
        assert!(got[k].abs_diff(expect[k]) <= 1, "channel {k}: {got:?} vs {expect:?}");
    }
    // A corner is background.
    assert_eq!(f.image.pixel(0, 0), [0, 0, 0]);
}

/// The sphere's silhouette covers about π·r² pixels, r = tan(asin(1/6)) / tan(fov/2) · H/2 (the inscribed
/// polyhedron a little less).
#[test]
fn coverage_matches_the_projected_sphere() {
    let s = load("paper_sphere.toml", &sized(200, 200));
    let (f, st) = render(&s, 2);
    let rad = (1.0f64 / 6.0).asin().tan() / 22.5f64.to_radians().tan() * 100.0;
    let expect = std::f64::consts::PI * rad * rad;
    let got = f.covered.iter().filter(|c| **c).count() as f64;
    assert_eq!(got as u64, st.visible_pixels);
    assert!(got < expect && got > 0.97 * expect, "{got} vs {expect}");
}

/// Input pruning and batching through the shading program: a formula of NH alone gets a program that reads
/// no tangent column and computes no reflection (VR) or frame, and each span of a material's pixels is one
/// program call.
#[test]
fn only_read_inputs_are_computed_and_each_span_calls_the_program_once() {
    let opts = LoadOptions { formula_override: Some(("nh.brdf".into(), "NH^20".into())), ..sized(160, 120) };
    let s = load("torus.toml", &opts);
    let mut used = InputSet::default();
    used.insert(Input::NH);
    for m in &s.materials {
        assert_eq!(m.used, used);
        let plan = r::plan::ShadingPlan::new(m, s.ambient, true);
        let ch: Vec<&lobe::ir::Formula> = m.program.channels.iter().map(|f| f.as_ref()).collect();
        let p = r::program::build(&r::program::spec(&s, &plan), &ch).unwrap();
        assert_eq!(p.columns, 6, "position and normal only");
        // Per light: NL, VL (for the half vector), NH, VH would be one more; no 2·NL·NV − VL (VR).
        let text = format!("{:?}", p.ir.nodes());
        assert!(!plan.reflect && !plan.directions, "{text}");
    }
    let (_, st) = render(&s, 2);
    // One material: at most one call per span of visible pixels (per tile).
    let spans = st.tiles_touched as u64 + st.visible_pixels / r::shade::SPAN as u64;
    assert!(st.kernel_calls <= spans, "{} calls for {spans} spans", st.kernel_calls);
    assert!(st.kernel_calls > 0 && st.evals > st.kernel_calls * 10);
}

#[test]
fn nan_from_the_kernel_is_shaded_as_zero_and_counted() {
    let src = "width = 64\nheight = 64\nambient = [0, 0, 0]\n[camera]\nposition = [0, 0, 6]\nfov = 30\n\
               [[light]]\nkind = \"point\"\nposition = [10, 0, 10]\n\
               [materials.bad]\nformula = \"0/0\"\nka = 0\nkd = 0\nks = 1\n\
               [[object]]\nshape = \"sphere\"\nmaterial = \"bad\"\n";
    let s = scene::parse_scene("nan.toml", src, Path::new("."), &LoadOptions::default(), &JIT).unwrap();
    let (f, st) = render(&s, 2);
    assert!(st.nan > 0);
    assert_eq!(st.nan, st.evals);
    assert!(f.image.rgb.iter().all(|&c| c == 0), "NaN must shade as black here");
}

#[test]
fn cutoff_skips_evaluations_below_the_level_and_reports_what_it_changes() {
    // Phong (VR^50) with the papers' q = 8: F < 2^-8 beyond acos(2^(-8/50)) ≈ 31.7°.
    let src = std::fs::read_to_string(scene_file("paper_sphere.toml")).unwrap().replace("modified_schlick_vr.brdf", "phong.brdf");
    let cut_src = src.replace("\nks = 0.5\n", "\nks = 0.5\ncutoff = 8\n");
    let opts = sized(128, 128);
    let full = scene::parse_scene("p.toml", &src, &scene_file(""), &opts, &JIT).unwrap();
    let cut = scene::parse_scene("p.toml", &cut_src, &scene_file(""), &opts, &JIT).unwrap();
    let c = cut.materials[0].cutoff.expect("a cut-off");
    assert_eq!(c.input, Input::VR);
    let exact = (-8.0f64 / 50.0).exp2().acos().to_degrees();
    assert!((c.angle_deg() - exact).abs() < 0.05, "{} vs {exact}", c.angle_deg());
    let (f_full, st_full) = render(&full, 2);
    let (f_cut, st_cut) = render(&cut, 2);
    assert!(st_cut.cut > 0 && st_cut.evals + st_cut.cut == st_full.evals, "{} + {} vs {}", st_cut.evals, st_cut.cut, st_full.evals);
    assert_eq!(st_full.cut, 0);
    // What was skipped is below 2^-8·ks·255 = 0.5 levels: at most one level anywhere.
    let ropts = RenderOptions { threads: 2, tile: 32, ..RenderOptions::default() };
    let eff = r::cutoff_effect(&cut, &ropts, &f_cut, &st_cut).unwrap().expect("an effect");
    assert_eq!(eff.skipped, st_cut.cut);
    assert!(eff.max_channel_diff <= 1, "{eff:?}");
    let differing = f_cut.image.rgb.chunks_exact(3).zip(f_full.image.rgb.chunks_exact(3)).filter(|(a, b)| a != b).count() as u64;
    assert_eq!(eff.pixels_differing, differing);
    assert!(r::cutoff_effect(&full, &ropts, &f_full, &st_full).unwrap().is_none());
    // With the cut-off off, the frame is the full one.
    let (f_off, st_off) = r::render(&cut, &RenderOptions { cutoff: false, ..ropts }).unwrap();
    assert_eq!((f_off.image.rgb == f_full.image.rgb, st_off.evals), (true, st_full.evals));
    // A formula of several cosines has no one lobe angle: a scene error at the key.
    let ct = src.replace("phong.brdf", "cook_torrance.brdf").replace("params = { n = 50 }", "cutoff = 8");
    let msg = match scene::parse_scene("ct.toml", &ct, &scene_file(""), &opts, &JIT) {
        Ok(_) => panic!("a cut-off on Cook–Torrance must be refused"),
        Err(d) => d.render(false),
    };
    assert!(msg.contains("materials.glossy.cutoff") && msg.contains("one lobe cosine") && msg.contains("ct.toml:"), "{msg}");
}

#[test]
fn normalize_bakes_the_energy_coefficient() {
    let src = std::fs::read_to_string(scene_file("paper_sphere.toml")).unwrap().replace("\nks = 0.5\n", "\nks = 0.5\nnormalize = true\n").replace("modified_schlick_vr.brdf", "phong.brdf");
    let s = scene::parse_scene("p.toml", &src, &scene_file(""), &LoadOptions::default(), &JIT).unwrap();
    let exact = 52.0 / (2.0 * std::f64::consts::PI); // Phong: (n + 2) / 2π at n = 50
    assert!((s.materials[0].coef.x - exact).abs() / exact < 1e-6, "{}", s.materials[0].coef.x);
}

fn scene_err(src: &str) -> String {
    match scene::parse_scene("bad.toml", src, &scene_file(""), &LoadOptions::default(), &JIT) {
        Ok(_) => panic!("accepted:\n{src}"),
        Err(d) => d.render(false),
    }
}

const GOOD: &str = "[camera]\nposition = [0, 0, 6]\n[[light]]\nkind = \"point\"\nposition = [10, 0, 10]\n\
                    [materials.m]\nformula = \"VR^n\"\n[[object]]\nshape = \"sphere\"\nmaterial = \"m\"\n";

#[test]
fn scene_errors_name_file_line_and_key() {
    assert!(scene::parse_scene("ok.toml", GOOD, Path::new("."), &LoadOptions::default(), &JIT).is_ok());
    // Unknown key, line 2.
    let e = scene_err(&GOOD.replace("position = [0, 0, 6]", "position = [0, 0, 6]\nfocus = 3"));
    assert!(e.contains("bad.toml:3:") && e.contains("focus"), "{e}");
    // Wrong type.
    let e = scene_err(&GOOD.replace("position = [0, 0, 6]", "position = \"far\""));
    assert!(e.contains("bad.toml:2:") && e.contains("invalid type") && e.contains("`camera.position`"), "{e}");
    // Unknown material, with a suggestion.
    let e = scene_err(&GOOD.replace("material = \"m\"", "material = \"mm\""));
    assert!(e.contains("bad.toml:10:") && e.contains("unknown material `mm`") && e.contains("did you mean `m`"), "{e}");
    // Unknown parameter, and one out of range.
    let e = scene_err(&GOOD.replace("formula = \"VR^n\"", "formula = \"VR^n\"\nparams = { m = 3 }"));
    assert!(e.contains("bad.toml:8:") && e.contains("no parameter `m`"), "{e}");
    let e = scene_err(&GOOD.replace("formula = \"VR^n\"", "formula = \"VR^n\"\nparams = { n = 5000 }"));
    assert!(e.contains("bad.toml:8:") && e.contains("outside"), "{e}");
    // Missing .brdf file.
    let e = scene_err(&GOOD.replace("formula = \"VR^n\"", "brdf = \"nope.brdf\""));
    assert!(e.contains("bad.toml:7:") && e.contains("materials.m.brdf") && e.contains("nope.brdf"), "{e}");
    // Image too large.
    let e = scene_err(&format!("width = 5000\n{GOOD}"));
    assert!(e.contains("bad.toml:1:") && e.contains("width"), "{e}");
    // A formula with errors: its own diagnostics plus where the scene used it.
    let e = scene_err(&GOOD.replace("VR^n", "VR^^n"));
    assert!(e.contains("expected an operand after `^`") && e.contains("used by [materials.m] at bad.toml:7:"), "{e}");
    // An unknown math mode, at its key.
    let e = scene_err(&GOOD.replace("formula = \"VR^n\"", "formula = \"VR^n\"\nmath = \"turbo\""));
    assert!(e.contains("bad.toml:8:") && e.contains("materials.m.math") && e.contains("`precise` or `fast`"), "{e}");
    // Shape-specific keys on the wrong shape.
    let e = scene_err(&GOOD.replace("shape = \"sphere\"", "shape = \"torus\"\nradius = 2"));
    assert!(e.contains("bad.toml:9:") && e.contains("`radius` applies only to shape = \"sphere\""), "{e}");
}

#[test]
fn broken_and_missing_obj_files_are_reported_with_their_line() {
    let dir = std::env::temp_dir().join(format!("lobe-render-it-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("broken.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n").unwrap();
    let src = GOOD.replace("shape = \"sphere\"", "shape = \"mesh\"\npath = \"broken.obj\"");
    let e = match scene::parse_scene("bad.toml", &src, &dir, &LoadOptions::default(), &JIT) {
        Ok(_) => panic!("broken OBJ accepted"),
        Err(d) => d.render(false),
    };
    assert!(e.contains("bad.toml:10:") && e.contains("broken.obj:4"), "{e}");
    let src = GOOD.replace("shape = \"sphere\"", "shape = \"mesh\"\npath = \"missing.obj\"");
    let e = match scene::parse_scene("bad.toml", &src, &dir, &LoadOptions::default(), &JIT) {
        Ok(_) => panic!("missing OBJ accepted"),
        Err(d) => d.render(false),
    };
    assert!(e.contains("bad.toml:10:") && e.contains("missing.obj"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The CLI writes nothing when the scene is bad, and leaves an existing output untouched.
#[test]
fn cli_writes_nothing_on_error() {
    let dir = std::env::temp_dir().join(format!("lobe-render-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("bad.toml");
    std::fs::write(&scene, GOOD.replace("fov", "x").replace("[0, 0, 6]", "[0, 0, 6]\nzoom = 2")).unwrap();
    let out = dir.join("out.png");
    let run = |out: &Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_lobe"))
            .args(["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--quiet"])
            .output()
            .unwrap()
    };
    let o = run(&out);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.toml:3:") && err.contains("zoom"), "{err}");
    assert!(!out.exists());
    // An existing file keeps its bytes.
    let prior = Image::new(2, 2).encode_png().unwrap();
    std::fs::write(&out, &prior).unwrap();
    assert!(!run(&out).status.success());
    assert_eq!(std::fs::read(&out).unwrap(), prior);
    // A foreign file is refused before anything else happens.
    let notes = dir.join("notes.txt");
    std::fs::write(&notes, "keep me").unwrap();
    let o = run(&notes);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("refusing to overwrite"));
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "keep me");
    // No stray temporary files.
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
    assert_eq!(left.len(), 3, "{left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The papers' table 4.2 in shape: Phong vs Schlick is further apart than Phong vs modified Schlick at every
/// n, and both distances shrink as n grows from 5 to 500 (the highlight shrinks).
#[test]
fn table_4_2_shape() {
    let read = |f: &str| std::fs::read_to_string(root().join("examples/brdfs").join(f)).unwrap();
    let (phong, schlick, msh) = (read("phong.brdf"), read("schlick_vr.brdf"), read("modified_schlick_vr.brdf"));
    let scene_src = std::fs::read_to_string(scene_file("paper_sphere.toml")).unwrap();
    let base = scene_file("");
    let ropts = RenderOptions { tile: 32, ..RenderOptions::default() };
    let run = |b: &str, n: f64| {
        let job = CompareJob { scene_name: "paper", scene_src: &scene_src, base: &base, a: ("phong", &phong), b: ("b", b), size: Some((128, 128)), tint: [[1.0; 3]; 2] };
        compare::compare_formulas(&job, &[("n".into(), n)], &JIT, &ropts).unwrap().metrics
    };
    let mut prev = (f64::INFINITY, f64::INFINITY);
    for n in [5.0, 20.0, 100.0, 500.0] {
        let (s, m) = (run(&schlick, n), run(&msh, n));
        println!("n={n}: phong–schlick {:.3}, phong–modified {:.3}", s.manhattan, m.manhattan);
        assert!(s.manhattan > m.manhattan, "n={n}: {} vs {}", s.manhattan, m.manhattan);
        assert!(s.manhattan < prev.0 && m.manhattan < prev.1, "n={n}: distances should shrink with n");
        prev = (s.manhattan, m.manhattan);
    }
}

/// JIT vs interpreter within 1/255 on the paper scene.
#[test]
fn jit_and_interpreter_render_within_one_level() {
    use lobe::render::scene::LobeCompiler;
    let opts = sized(96, 96);
    for brdf in ["phong.brdf", "schlick_vr.brdf", "modified_schlick_vr.brdf", "blinn.brdf"] {
        let src = std::fs::read_to_string(root().join("examples/brdfs").join(brdf)).unwrap();
        let o = LoadOptions { formula_override: Some((brdf.into(), src)), ..opts.clone() };
        let load = |b| scene::load_scene(&scene_file("paper_sphere.toml"), &o, &LobeCompiler::plain(b, lobe::Mode::Precise)).map_err(|d| d.render(false));
        let (j, i) = (load(lobe::Backend::Jit).unwrap(), load(lobe::Backend::Interp).unwrap());
        let (fj, fi) = (render(&j, 2).0, render(&i, 2).0);
        assert!(fj.image.rgb.iter().zip(&fi.image.rgb).all(|(a, b)| a.abs_diff(*b) <= 1), "{brdf}");
    }
}

/// Prints the full table 4.2 reproduction at the paper scene's own 512×512 framing (Rust twins; with the
/// front end merged, `lobe compare phong.brdf schlick.brdf --sweep-n …` prints the same) and writes the
/// sweep images to target/. Run: `cargo test --test it table_4_2_report -- --ignored --nocapture`.
#[test]
#[ignore = "report, not a check: prints the table"]
fn table_4_2_report() {
    let read = |f: &str| std::fs::read_to_string(root().join("examples/brdfs").join(f)).unwrap();
    let phong = read("phong.brdf");
    let scene_src = std::fs::read_to_string(scene_file("paper_sphere.toml")).unwrap();
    let base = scene_file("");
    let ropts = RenderOptions::default();
    let published = [(5.0, 1.22, 0.65), (10.0, 1.24, 0.52), (15.0, 0.77, 0.19), (20.0, 0.71, 0.17), (50.0, 0.41, 0.07), (100.0, 0.26, 0.04), (250.0, 0.14, 0.02), (500.0, 0.08, 0.01)];
    for (label, b) in [("schlick", read("schlick_vr.brdf")), ("modified_schlick", read("modified_schlick_vr.brdf"))] {
        let mut rows = vec![];
        for (n, ps, pm) in published {
            let job = CompareJob { scene_name: "paper", scene_src: &scene_src, base: &base, a: ("phong", &phong), b: (label, &b), size: None, tint: [[1.0; 3]; 2] };
            let c = compare::compare_formulas(&job, &[("n".into(), n)], &JIT, &ropts).unwrap();
            let m = &c.metrics;
            let publ = if label == "schlick" { ps } else { pm };
            println!(
                "phong vs {label:16} n={n:>4}: manhattan {:.4} (published {publ:.2}), over sphere px {:.4}, max {:.1}, rmse {:.4}, psnr {:.2}",
                m.manhattan, m.manhattan_covered, m.max_gray_diff, m.rmse, m.psnr
            );
            rows.push(c);
        }
        let scale = rows.iter().map(|c| c.metrics.max_gray_diff).fold(1.0, f64::max);
        let png = compare::sweep_image(&rows, scale).encode_png().unwrap();
        std::fs::write(root().join(format!("target/table42_{label}.png")), png).unwrap();
    }
}

/// Prints `--stats` for the paper sphere at 1024² and 4096² with 1 and 2 threads (Rust-twin Phong kernel).
/// Run in release for meaningful numbers: `cargo test --release --test it render_stats_report -- --ignored
/// --nocapture`.
#[test]
#[ignore = "report, not a check: prints timings"]
fn render_stats_report() {
    for size in [1024, 4096] {
        let s = load("paper_sphere.toml", &sized(size, size));
        for threads in [1, 2] {
            // Best of 3 wall times.
            let mut best: Option<r::RenderStats> = None;
            for _ in 0..3 {
                let (_, st) = r::render(&s, &RenderOptions { threads, ..RenderOptions::default() }).unwrap();
                if best.as_ref().is_none_or(|b| st.render_wall < b.render_wall) {
                    best = Some(st);
                }
            }
            let st = best.unwrap();
            let t = std::time::Instant::now();
            let (f, _) = r::render(&s, &RenderOptions { threads, ..RenderOptions::default() }).unwrap();
            let _ = t;
            let t = std::time::Instant::now();
            let png = f.image.encode_png().unwrap();
            print!("{}", lobe::report::render::stats_text(&st, t.elapsed()));
            println!("  ({} bytes PNG)", png.len());
        }
    }
}

/// `lobe render` and `lobe compare` end to end (also through the hidden Rust-twin compiler): a decodable PNG of
/// the requested size, the stats line, and the JSON keys.
#[test]
fn cli_render_and_compare_end_to_end() {
    let dir = std::env::temp_dir().join(format!("lobe-render-e2e-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let lobe = |args: &[&str]| std::process::Command::new(env!("CARGO_BIN_EXE_lobe")).args(args).output().unwrap();
    let out = dir.join("p.png");
    let scene = scene_file("paper_sphere.toml");
    let o = lobe(&["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--size", "80x60", "--stats", "--threads", "2"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("Mpixel/s") && err.contains("2 thread(s)") && err.contains("encode"), "{err}");
    let im = Image::decode_png(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!((im.width, im.height), (80, 60));
    // --stats --json: one object on stdout with the stage split.
    let o = lobe(&["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--size", "64", "--stats", "--json", "--threads", "1", "--backend", "interp"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for k in ["visible_px", "shade_ns_per_px", "geometry_ns_per_px", "kernel_ns_per_eval", "raster_ms", "encode_ms", "wall_ms"] {
        assert!(v[k].as_f64().is_some_and(|x| x >= 0.0), "{k}: {v}");
    }
    assert!(v["visible_px"].as_u64().unwrap() > 0 && v["evals"].as_u64().unwrap() > 0);
    assert_eq!((v["threads"].as_u64(), v["backend"].as_str(), v["math"].as_str()), (Some(1), Some("interp"), Some("precise")));
    assert!(v["cutoff"].is_null());
    assert_eq!(v["shading"].as_str(), Some("program"));
    // --shading program (the only way, and the default) draws the same image; anything else is refused.
    let spans = dir.join("spans.png");
    let o = lobe(&["render", scene.to_str().unwrap(), "-o", spans.to_str().unwrap(), "--size", "64", "--stats", "--json", "--threads", "1", "--backend", "interp", "--shading", "program"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["shading"].as_str(), Some("program"));
    assert_eq!(std::fs::read(&spans).unwrap(), std::fs::read(&out).unwrap());
    for other in ["spans", "fused"] {
        let o = lobe(&["render", scene.to_str().unwrap(), "-o", spans.to_str().unwrap(), "--shading", other]);
        assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("program"), "{}", String::from_utf8_lossy(&o.stderr));
    }
    // Re-rendering over our own PNG is allowed.
    assert!(lobe(&["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap(), "--size", "16", "-q"]).status.success());

    let b = |f: &str| root().join("examples/brdfs").join(f).to_str().unwrap().to_string();
    let cmp = dir.join("cmp.png");
    let o = lobe(&[
        "compare", &b("phong.brdf"), &b("modified_schlick_vr.brdf"), "--sweep-n", "5,50", "--size", "64", "-o", cmp.to_str().unwrap(), "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = v.as_array().expect("an array per n");
    assert_eq!(rows.len(), 2);
    for (row, n) in rows.iter().zip([5.0, 50.0]) {
        assert_eq!(row["n"].as_f64(), Some(n));
        assert!(row["manhattan"].as_f64().unwrap() > 0.0 && row["rmse"].as_f64().unwrap() > 0.0);
        assert!(row["psnr"].as_f64().unwrap() > 20.0);
    }
    let im = Image::decode_png(&std::fs::read(&cmp).unwrap()).unwrap();
    // Three 64² columns per n, inside a figure with headings, row labels and the colour bar.
    assert!(im.width >= 3 * 64 + 40 && im.height >= 2 * 64 + 20, "{}×{}", im.width, im.height);
    std::fs::remove_dir_all(&dir).unwrap();
}

// ---- Geometry once: stage 1 (parse, check, tessellate) shared by many material builds ----

/// `compare_sweep` (one parse and tessellation, materials rebuilt per n) gives the same images and metrics as
/// loading the whole scene afresh for each formula and n, the way each comparison was made before.
#[test]
fn sweep_matches_rendering_each_n_separately() {
    let read = |f: &str| std::fs::read_to_string(root().join("examples/brdfs").join(f)).unwrap();
    let (phong, msh) = (read("phong.brdf"), read("modified_schlick_vr.brdf"));
    let scene_src = std::fs::read_to_string(scene_file("paper_sphere.toml")).unwrap();
    let base = scene_file("");
    let ropts = RenderOptions { tile: 32, ..RenderOptions::default() };
    let job = CompareJob { scene_name: "paper", scene_src: &scene_src, base: &base, a: ("phong", &phong), b: ("msh", &msh), size: Some((80, 64)), tint: [[1.0; 3]; 2] };
    let ns = [5.0, 50.0, 500.0];
    let sets: Vec<Vec<(String, f64)>> = ns.iter().map(|&n| vec![("n".to_string(), n)]).collect();
    let rows = compare::compare_sweep(&job, &sets, &JIT, &ropts).unwrap();
    assert_eq!(rows.len(), ns.len());
    for (row, set) in rows.iter().zip(&sets) {
        let alone = |(file, src): (&str, &str)| {
            let opts = LoadOptions { size: job.size, set: set.clone(), formula_override: Some((file.into(), src.into())), ..LoadOptions::default() };
            let s = scene::parse_scene("paper", &scene_src, &base, &opts, &JIT).unwrap();
            r::render(&s, &ropts).unwrap()
        };
        let ((fa, sa), (fb, sb)) = (alone(job.a), alone(job.b));
        assert!(row.a.image == fa.image && row.b.image == fb.image, "n={:?}: images differ", row.n);
        let covered: Vec<bool> = fa.covered.iter().zip(&fb.covered).map(|(x, y)| *x || *y).collect();
        assert_eq!(row.metrics, compare::metrics(&fa.image, &fb.image, &covered).unwrap());
        assert_eq!(row.nan, [sa.nan, sb.nan]);
        assert_eq!(row.n, Some(set[0].1));
        // And a one-row comparison is the same row.
        assert_eq!(compare::compare_formulas(&job, set, &JIT, &ropts).unwrap().metrics, row.metrics);
    }
    assert!(rows[0].metrics.manhattan > rows[2].metrics.manhattan);
}

/// Scenes made from one geometry share its meshes, differ only in their materials, and render exactly as a
/// full load does.
#[test]
fn geometry_is_loaded_once_and_shared_by_its_scenes() {
    let g = scene::load_geometry(&scene_file("torus.toml"), Some((90, 70)), &Default::default()).unwrap_or_else(|d| panic!("{}", d.render(false)));
    assert_eq!((g.scene.width, g.scene.height), (90, 70));
    let s1 = g.with_materials(&[], None, &JIT).unwrap();
    let s2 = g.with_materials(&[("n".into(), 7.0)], None, &JIT).unwrap();
    for ((o, p), q) in g.scene.objects.iter().zip(&s1.objects).zip(&s2.objects) {
        assert!(Arc::ptr_eq(&o.mesh, &p.mesh) && Arc::ptr_eq(&o.mesh, &q.mesh), "meshes are copied");
    }
    assert_eq!(s2.materials[0].params[0], 7.0);
    assert_ne!(s1.materials[0].params, s2.materials[0].params);
    assert!(render(&s1, 2).0.image == render(&load("torus.toml", &sized(90, 70)), 2).0.image);
    let set7 = LoadOptions { set: vec![("n".into(), 7.0)], ..sized(90, 70) };
    assert!(render(&s2, 2).0.image == render(&load("torus.toml", &set7), 2).0.image);
}

/// The two stages report what the single pass did: a full load lists size/camera/light errors, then material
/// errors, then object errors; `parse_geometry` alone reports the first and last groups; `lobe compare`'s
/// path reports exactly what a full load with the replacement formula does.
#[test]
fn staged_loading_keeps_the_diagnostics() {
    let src = GOOD
        .replace("position = [0, 0, 6]", "position = [0, 0, 0]")
        .replace("formula = \"VR^n\"", "formula = \"VR^n\"\nparams = { m = 3 }")
        .replace("material = \"m\"", "material = \"mm\"");
    let full = scene_err(&src);
    let (cam, mat, obj) = (full.find("[camera]").unwrap(), full.find("no parameter `m`").unwrap(), full.find("unknown material `mm`").unwrap());
    assert!(cam < mat && mat < obj, "{full}");
    let geo = match scene::parse_geometry("bad.toml", &src, &scene_file(""), None, &Default::default()) {
        Ok(_) => panic!("accepted"),
        Err(d) => d.render(false),
    };
    assert!(geo.contains("[camera]") && geo.contains("unknown material `mm`") && !geo.contains("no parameter"), "{geo}");
    assert!(geo.contains("bad.toml:1:1") && geo.contains("bad.toml:11:12"), "{geo}");

    // compare: geometry errors and an out-of-range --set together, as one full load reports them.
    let phong = std::fs::read_to_string(root().join("examples/brdfs/phong.brdf")).unwrap();
    let base = scene_file("");
    let job = CompareJob { scene_name: "bad.toml", scene_src: &src, base: &base, a: ("phong.brdf", &phong), b: ("b", "VR^n"), size: None, tint: [[1.0; 3]; 2] };
    let set = vec![("n".to_string(), 1e9)];
    let cmp = match compare::compare_sweep(&job, std::slice::from_ref(&set), &JIT, &RenderOptions::default()) {
        Ok(_) => panic!("accepted"),
        Err(d) => d.render(false),
    };
    let opts = LoadOptions { set, formula_override: Some(("phong.brdf".into(), phong.clone())), ..LoadOptions::default() };
    let alone = match scene::parse_scene("bad.toml", &src, &base, &opts, &JIT) {
        Ok(_) => panic!("accepted"),
        Err(d) => d.render(false),
    };
    assert_eq!(cmp, alone);
    assert!(cmp.contains("[camera]") && cmp.contains("set n=1000000000") && cmp.contains("unknown material `mm`"), "{cmp}");
}

/// `math = "fast"` on a material (and `--math` through `LobeCompiler`): the kernel runs fast math, and the
/// image stays within one level of the precise one on formulas with exp, acos, sin and pow.
#[test]
fn fast_math_materials_render_within_one_level_of_precise() {
    let opts = sized(128, 128);
    for brdf in ["kutlog.brdf", "gaussian.brdf", "cook_torrance.brdf", "fst.brdf"] {
        let src = std::fs::read_to_string(root().join("examples/brdfs").join(brdf)).unwrap();
        let o = LoadOptions { formula_override: Some((brdf.into(), src)), ..opts.clone() };
        let load = |math| {
            let c = LobeCompiler::plain(lobe::Backend::Jit, math);
            scene::load_scene(&scene_file("paper_sphere.toml"), &o, &c).map_err(|d| d.render(false)).unwrap()
        };
        let (p, f) = (load(lobe::Mode::Precise), load(lobe::Mode::Fast));
        assert!(f.materials.iter().all(|m| m.math == lobe::Mode::Fast) && p.materials.iter().all(|m| m.math == lobe::Mode::Precise));
        let (fp, ff) = (render(&p, 2).0, render(&f, 2).0);
        let worst = fp.image.rgb.iter().zip(&ff.image.rgb).map(|(a, b)| a.abs_diff(*b)).max().unwrap_or(0);
        assert!(worst <= 1, "{brdf}: fast math moved a channel by {worst} levels");
    }
    // The scene key overrides the compiler's default.
    let src = GOOD.replace("formula = \"VR^n\"", "formula = \"exp(-n * acos(VR)^2)\"\nmath = \"fast\"");
    let sc = scene::parse_scene("m.toml", &src, Path::new("."), &LoadOptions::default(), &JIT).map_err(|d| d.render(false)).unwrap();
    assert_eq!(sc.materials[0].math, lobe::Mode::Fast);
}

#[test]
fn past_the_program_budget_materials_shade_per_light_with_the_programs_colours() {
    // The per-light shader (every material forced past a budget of 0 nodes) against the compiled programs: the
    // same bytes and counters on scalar, colour, direction-reading and anisotropic materials, with a cut-off.
    let phong = std::fs::read_to_string(scene_file("paper_sphere.toml")).unwrap().replace("modified_schlick_vr.brdf", "phong.brdf");
    let lights = "[[light]]\nkind = \"directional\"\ndirection = [-1, 0.5, 1]\ncolor = [0.3, 0.6, 0.2]\n\n[[light]]\nkind = \"point\"\nposition = [-3, -4, 5]\ncolor = [0.5, 0.2, 0.9]\n\n[materials.glossy]";
    let cases = [
        ("cut-off", phong.replace("\nks = 0.5\n", "\nks = 0.5\ncutoff = 8\n").replace("[materials.glossy]", lights)),
        ("aniso_ward", std::fs::read_to_string(scene_file("aniso_ward.toml")).unwrap()),
        ("principled", std::fs::read_to_string(scene_file("principled.toml")).unwrap()),
        ("torus", std::fs::read_to_string(scene_file("torus.toml")).unwrap()),
    ];
    for (name, src) in cases {
        let s = scene::parse_scene(&format!("{name}.toml"), &src, &scene_file(""), &sized(96, 96), &JIT).unwrap_or_else(|d| panic!("{}", d.render(false)));
        let ropts = RenderOptions { threads: 2, tile: 32, ..RenderOptions::default() };
        let (fp, sp) = r::render(&s, &ropts).unwrap();
        let (fe, se) = r::render(&s, &RenderOptions { program_budget: 0, ..ropts }).unwrap();
        assert!(sp.evals > 0, "{name}: nothing evaluated");
        assert_eq!((sp.evals, sp.cut, sp.nan), (se.evals, se.cut, se.nan), "{name}: counters");
        let differing = fp.image.rgb.iter().zip(&fe.image.rgb).filter(|(a, b)| a != b).count();
        assert_eq!(differing, 0, "{name}: {differing} channel values differ between the program and the per-light shader");
    }
}
